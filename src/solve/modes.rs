//! Natural frequencies and modes: takes a model and an equilibrium state, gives the small free
//! oscillations about it, from the constrained generalized eigenproblem `K phi = omega^2 M phi` on
//! the joints' null space (`K` the symmetric tangent stiffness including the joints' geometric
//! term `H_lambda`, `M` the mass matrix; damping ignored).
//!
//! With `Z` spanning the null space of `Phi_q`, `Z^T M Z = L L^T` and `S = L^-1 Z^T K Z L^-T =
//! V diag(omega^2) V^T`, the mode shapes are `phi = Z L^-T v`, normalized to `phi^T M phi = 1`
//! (so each body's share of the kinetic energy is `phi_b^T M_bb phi_b`). Zero-frequency modes
//! (`omega^2` within `1e-9` of the largest) are listed apart: rigid-body motions and mechanisms.
//! For every mode the change of each cable's length and of each of its segments per unit modal
//! amplitude is reported (central differences along the retraction): a clustered cable's sliding
//! shows as segments that change while the total length does not.

use nalgebra::{DMatrix, SymmetricEigen};

use crate::constraints::add_multiplier_hessian;
use crate::evaluate::{evaluate, Tangents, Workspace};
use crate::forces::cable::{route_geometry, CableScratch};
use crate::model::{CableId, Model};
use crate::solve::dynamics::mass_matrix;
use crate::state::{retract, State};

/// One natural mode.
#[derive(Debug, Clone, PartialEq)]
pub struct Mode {
    /// `omega^2`, 1/s^2 (negative: the equilibrium is unstable in this mode).
    pub omega_squared: f64,
    /// Frequency `sqrt(omega^2) / (2 pi)`, Hz (0 for zero and negative modes).
    pub frequency_hz: f64,
    /// True for a zero-frequency mode (rigid-body motion or mechanism).
    pub zero: bool,
    /// Mass-normalized shape in local coordinates (`phi^T M phi = 1`).
    pub shape: nalgebra::DVector<f64>,
    /// Each body's share of the mode's kinetic energy (sums to 1), in body order.
    pub kinetic_share: Vec<f64>,
    /// Each cable's length change per unit modal amplitude, m, in cable order.
    pub cable_stretch: Vec<f64>,
    /// Each cable's largest segment-length change per unit modal amplitude, m (larger than the
    /// total change for a cable sliding through its pulleys).
    pub segment_change: Vec<f64>,
}

/// The modes at `state` (an equilibrium with its multipliers), lowest `omega^2` first; none when
/// nothing can move (no free coordinate, or joints that hold every one). `None` when the mass
/// matrix on the joints' null space is singular (a massless free coordinate).
pub fn natural_modes(model: &Model, state: &State) -> Option<Vec<Mode>> {
    let n = model.dof_count;
    if n == 0 {
        return Some(Vec::new());
    }
    let mut ws = Workspace::new(model);
    evaluate(model, state, &mut ws, Tangents::Stiffness);
    let mut k = ws.stiffness.clone();
    if model.constraint_count > 0 {
        add_multiplier_hessian(model, &state.poses, &state.multipliers, &mut k);
    }
    let k = (&k + k.transpose()) * 0.5;
    let m = mass_matrix(model);
    let Some(z) = crate::constraints::null_space(&ws.constraint_jacobian, n) else {
        return Some(Vec::new()); // the joints hold every coordinate
    };
    let l = (z.transpose() * &m * &z).cholesky()?.l();
    let l_inv = l.try_inverse()?;
    let s = &l_inv * (z.transpose() * &k * &z) * l_inv.transpose();
    let eig = SymmetricEigen::new((&s + s.transpose()) * 0.5);
    let shapes: DMatrix<f64> = &z * l_inv.transpose() * &eig.eigenvectors;
    let tol = 1e-9 * eig.eigenvalues.amax().max(1e-300);
    let mut order: Vec<usize> = (0..eig.eigenvalues.len()).collect();
    order.sort_by(|a, b| eig.eigenvalues[*a].total_cmp(&eig.eigenvalues[*b]));
    let max_route = model.cables.iter().map(|c| c.route_len).max().unwrap_or(2);
    let mut scratch = CableScratch::new(max_route);
    let size = crate::solve::statics::body_size(model);
    let mut modes = Vec::with_capacity(order.len());
    for i in order {
        let w2 = eig.eigenvalues[i];
        let shape = shapes.column(i).into_owned();
        let kinetic_share = model
            .bodies
            .iter()
            .map(|b| {
                let r = b.dof_offset..b.dof_offset + b.dof_count;
                let phi = shape.rows(r.start, b.dof_count);
                (phi.transpose() * m.view((r.start, r.start), (b.dof_count, b.dof_count)) * phi)[(0, 0)]
            })
            .collect();
        // length changes by central differences along the retraction, step 1e-6 of the size
        let h = 1e-6 * size / shape.amax().max(1e-300);
        let mut lengths = [vec![], vec![]];
        for (side, sign) in [(0, 1.0), (1, -1.0)] {
            let mut p = state.clone();
            retract(model, &mut p.poses, &shape, sign * h);
            let mut w = Workspace::new(model);
            evaluate(model, &p, &mut w, Tangents::None);
            lengths[side] = (0..model.cables.len())
                .map(|c| {
                    route_geometry(model.route(CableId(c)), &w.points, &mut scratch);
                    scratch.segment_lengths[..model.cables[c].route_len - 1].to_vec()
                })
                .collect::<Vec<_>>();
        }
        let d = |c: usize, k: usize| (lengths[0][c][k] - lengths[1][c][k]) / (2.0 * h);
        let cable_stretch = (0..model.cables.len())
            .map(|c| (0..model.cables[c].route_len - 1).map(|k| d(c, k)).sum())
            .collect();
        let segment_change = (0..model.cables.len())
            .map(|c| (0..model.cables[c].route_len - 1).map(|k| d(c, k).abs()).fold(0.0, f64::max))
            .collect();
        modes.push(Mode {
            omega_squared: w2,
            frequency_hz: if w2 > tol { w2.sqrt() / (2.0 * std::f64::consts::PI) } else { 0.0 },
            zero: w2.abs() <= tol,
            shape,
            kinetic_share,
            cable_stretch,
            segment_change,
        });
    }
    Some(modes)
}
