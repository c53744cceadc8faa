//! Form finding: takes a model at its initial geometry and, per cable, a given rest length, a
//! target tension (prestress) or nothing; gives the rest lengths that make the initial geometry an
//! equilibrium.
//!
//! With `g_c = dL_c/dq`, gravity `Q_g` and joint Jacobian `Phi_q`, equilibrium is
//! `Q_g - sum_c T_c g_c - Phi_q^T lambda = 0`. Cables with a given rest length have known tensions;
//! the others (`U`) and the reactions are unknowns of the linear system `A x = b`,
//! `A = [-g_U, -Phi_q^T]`. Among its solutions we take the one closest (least squares) to the
//! targets (a prestress `T*`, or a force density `q*` meaning `T* = q* L`). The result is refused when the geometry admits no equilibrium, when a
//! target cannot be met, when a cable would have to push, or when some tension is left undetermined.
//! Rest lengths then follow from the tension law: `L0 = EA L / (EA + T)`.

use nalgebra::{DMatrix, DVector};

use crate::forces::cable::{add_length_gradient, route_geometry, tension, CableScratch};
use crate::forces::{evaluate, Tangents, Workspace};
use crate::model::{CableId, Model};
use crate::state::State;

/// How a cable's rest length is specified in the scene.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum RestLengthSpec {
    /// Given rest length, m.
    Given(f64),
    /// Target tension at the initial geometry, N.
    Prestress(f64),
    /// Target force density `T / L` at the initial geometry, N/m.
    ForceDensity(f64),
    /// To be determined by equilibrium.
    Free,
}

/// Rest lengths (m) for every cable, or `(cable index if one is to blame, reason)`.
pub fn find_rest_lengths(
    model: &Model,
    specs: &[RestLengthSpec],
) -> Result<Vec<f64>, (Option<usize>, String)> {
    let unknown: Vec<usize> =
        (0..specs.len()).filter(|&c| !matches!(specs[c], RestLengthSpec::Given(_))).collect();
    let mut state = State::initial(model);
    state.rest_lengths.iter_mut().for_each(|l| *l = f64::MAX);
    let mut ws = Workspace::new(model);
    evaluate(model, &state, &mut ws, Tangents::None);
    let lengths: Vec<f64> = ws.cables.iter().map(|c| c.length).collect();
    for (c, l) in lengths.iter().enumerate() {
        if *l <= 1e-12 {
            return Err((Some(c), "the cable has zero length at the initial geometry".into()));
        }
    }
    if unknown.is_empty() {
        return Ok(specs
            .iter()
            .map(|s| if let RestLengthSpec::Given(l) = s { *l } else { unreachable!() })
            .collect());
    }

    let n = model.dof_count;
    let nc = model.constraint_count;
    let nu = unknown.len();
    let max_route = model.cables.iter().map(|c| c.route_len).max().unwrap_or(2);
    let mut scratch = CableScratch::new(max_route);
    let gradient = |c: usize, scratch: &mut CableScratch| {
        let route = model.route(CableId(c));
        route_geometry(route, &ws.points, scratch);
        let mut g = DVector::zeros(n);
        add_length_gradient(model, route, &ws.points, scratch, 1.0, &mut g);
        g
    };

    let p = nu + nc;
    let rows = n.max(p);
    let mut a = DMatrix::zeros(rows, p);
    let mut b = DVector::zeros(rows);
    b.rows_mut(0, n).copy_from(&(-&ws.force));
    for (c, spec) in specs.iter().enumerate() {
        let g = gradient(c, &mut scratch);
        match unknown.iter().position(|&u| u == c) {
            Some(col) => a.view_mut((0, col), (n, 1)).copy_from(&(-g)),
            None => {
                let l0 = if let RestLengthSpec::Given(l) = spec { *l } else { unreachable!() };
                let t = tension(model.cables[c].axial_stiffness, 0.0, l0, lengths[c], 0.0);
                b.rows_mut(0, n).axpy(t, &g, 1.0);
            }
        }
    }
    if nc > 0 {
        a.view_mut((0, nu), (n, nc)).copy_from(&(-ws.constraint_jacobian.transpose()));
    }

    let targets: Vec<(usize, f64)> = unknown
        .iter()
        .enumerate()
        .filter_map(|(col, &c)| match specs[c] {
            RestLengthSpec::Prestress(t) => Some((col, t)),
            RestLengthSpec::ForceDensity(q) => Some((col, q * lengths[c])),
            _ => None,
        })
        .collect();
    let scale = targets.iter().map(|t| t.1.abs()).fold(b.amax(), f64::max).max(1e-12);

    let svd = a.clone().svd(true, true);
    let smax = svd.singular_values.max();
    let tol = 1e-10 * smax.max(1e-300);
    let x_p = svd.solve(&b, tol).map_err(|e| (None, format!("form finding failed: {e}")))?;
    let residual = (&a * &x_p - &b).amax();
    if residual > 1e-8 * scale {
        return Err((None, format!("the initial geometry is not an equilibrium for any cable tensions (force residual {residual:.3e} N); move the bodies or give rest lengths")));
    }
    let v_t = svd.v_t.as_ref().expect("requested");
    let null: Vec<DVector<f64>> =
        (0..p).filter(|&i| svd.singular_values[i] <= tol).map(|i| v_t.row(i).transpose()).collect();
    let mut x = x_p;
    if !null.is_empty() {
        let nb = DMatrix::from_columns(&null);
        let mut sn = DMatrix::zeros(targets.len().max(null.len()), null.len());
        let mut rhs = DVector::zeros(sn.nrows());
        for (r, (col, t)) in targets.iter().enumerate() {
            sn.row_mut(r).copy_from(&nb.row(*col));
            rhs[r] = t - x[*col];
        }
        let svd2 = sn.clone().svd(true, true);
        let tol2 = 1e-10 * svd2.singular_values.max().max(1.0);
        let y = svd2.solve(&rhs, tol2).map_err(|e| (None, format!("form finding failed: {e}")))?;
        x += &nb * &y;
        // directions that the targets leave open must not change any tension
        let v2 = svd2.v_t.as_ref().expect("requested");
        for i in 0..null.len() {
            if svd2.singular_values[i] > tol2 {
                continue;
            }
            let dir = &nb * v2.row(i).transpose();
            let open: Vec<&str> = (0..nu)
                .filter(|&col| dir[col].abs() > 1e-8)
                .map(|col| model.cable_names[unknown[col]].as_str())
                .collect();
            if !open.is_empty() {
                return Err((None, format!("form finding cannot determine the tensions of cables {}: give one of them a prestress or a rest_length", open.join(", "))));
            }
        }
    }
    for (col, t) in &targets {
        if (x[*col] - t).abs() > 1e-6 * scale {
            return Err((Some(unknown[*col]), format!("prestress target {t} N is not compatible with equilibrium at this geometry (nearest equilibrium has {:.6} N)", x[*col])));
        }
    }
    let mut out = vec![0.0; specs.len()];
    for (c, spec) in specs.iter().enumerate() {
        out[c] = match (spec, unknown.iter().position(|&u| u == c)) {
            (RestLengthSpec::Given(l), _) => *l,
            (_, Some(col)) => {
                let t = x[col];
                if t < -1e-9 * scale {
                    return Err((
                        Some(c),
                        format!("equilibrium needs this cable to push (T = {t:.6} N); a cable can only pull"),
                    ));
                }
                let ea = model.cables[c].axial_stiffness;
                ea * lengths[c] / (ea + t.max(0.0))
            }
            _ => unreachable!(),
        };
    }
    Ok(out)
}
