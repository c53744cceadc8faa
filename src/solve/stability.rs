//! Stability of an equilibrium: takes the tangent stiffness (dense, or the sparse KKT system) and
//! the joints' Jacobian, gives the reduced stiffness's smallest eigenvalue and its negative and
//! zero modes, with the structure's free rigid-body motions told apart (`rigid_body_motions`).

use nalgebra::{DMatrix, DVector, SymmetricEigen};

use crate::constraints::add_multiplier_hessian;
use crate::evaluate::{evaluate, Tangents, Workspace};
use crate::model::{CableId, Model};
use crate::solve::linear::KktSystem;
use crate::solve::statics::kkt::assemble_sparse;
use crate::state::State;

/// The free rigid-body motions of the whole structure at the evaluated configuration
/// (`ws.points`, `state.poses`), as columns of generalized velocities (local coordinates): among
/// the world motions `v(r) = t + w x (r - c)` (3 translations and 3 rotations about the centroid
/// `c` of the moving points; in a planar scene `t` in the plane and `w` about z), those that leave
/// every anchor still (`v(F) = 0` for each fixed point a cable segment or joint ties the structure
/// to: only then are lengths to it kept at every order, not just the first), and that move some
/// body. 6 columns for a structure held by nothing, 3 in a planar scene, fewer
/// with partial supports. Linear in the scene size (6 x 6 Gram matrices).
pub fn rigid_body_motions(model: &Model, state: &State, ws: &Workspace) -> DMatrix<f64> {
    use nalgebra::{Matrix6, Vector3};
    let n = model.dof_count;
    let moving = |p: usize| model.bodies[model.points[p].body.0].dof_count > 0;
    let moving_points: Vec<usize> = (0..model.points.len()).filter(|&p| moving(p)).collect();
    if moving_points.is_empty() {
        return DMatrix::zeros(n, 0);
    }
    let c = moving_points.iter().map(|&p| ws.points[p].position).sum::<Vector3<f64>>()
        / moving_points.len() as f64;
    let generators: Vec<(Vector3<f64>, Vector3<f64>)> = if model.planar {
        vec![
            (Vector3::x(), Vector3::zeros()),
            (Vector3::y(), Vector3::zeros()),
            (Vector3::zeros(), Vector3::z()),
        ]
    } else {
        (0..6)
            .map(|k| {
                if k < 3 {
                    (Vector3::ith(k, 1.0), Vector3::zeros())
                } else {
                    (Vector3::zeros(), Vector3::ith(k - 3, 1.0))
                }
            })
            .collect()
    };
    // Gram matrix of the generators' velocities at the anchors (must vanish)
    let g = generators.len();
    let mut broken = Matrix6::<f64>::zeros();
    let add = |m: &mut Matrix6<f64>, row: &[f64]| {
        for i in 0..g {
            for j in 0..g {
                m[(i, j)] += row[i] * row[j];
            }
        }
    };
    // a rigid motion of the moving bodies keeps every length between them; it keeps a length to a
    // fixed point at every order only if that point would not move (it lies on the motion's axis)
    let mut anchors: Vec<Vector3<f64>> = Vec::new();
    for cable in 0..model.cables.len() {
        let route = model.route(crate::model::CableId(cable));
        for k in 1..route.len() {
            let (a, b) = (route[k - 1].0, route[k].0);
            if moving(a) != moving(b) {
                anchors.push(ws.points[if moving(a) { b } else { a }].position);
            }
        }
    }
    let mut row = [0.0; 6];
    for anchor in &anchors {
        for axis in 0..3 {
            for (i, (t, w)) in generators.iter().enumerate() {
                row[i] = (t + w.cross(&(anchor - c)))[axis];
            }
            add(&mut broken, &row[..g]);
        }
    }
    // a joint to the ground holds its point along its held directions only (a roller, a slider)
    for joint in &model.joints {
        let anchor = match joint.target {
            crate::model::JointTarget::World(x) => x,
            crate::model::JointTarget::Point(q) if !moving(q.0) => ws.points[q.0].position,
            crate::model::JointTarget::Point(_) => continue,
        };
        // an axis held to the ground turns with no rigid motion but about itself
        let held = joint
            .alignment
            .map(|al| crate::constraints::alignment_directions(model, &state.poses, joint, &al));
        for r in 0..joint.rows {
            for (i, (t, w)) in generators.iter().enumerate() {
                row[i] = match &held {
                    None => joint.project(&(t + w.cross(&(anchor - c))))[r],
                    Some(d) => (d * w)[r],
                };
            }
            add(&mut broken, &row[..g]);
        }
    }
    // each generator as generalized velocities: per body `(dx_world, dtheta_body)` through the
    // body's orthonormal basis columns (a spin that moves no point still turns a rigid body)
    let mut local = DMatrix::zeros(n, g);
    for (i, (t, w)) in generators.iter().enumerate() {
        for (b, body) in model.bodies.iter().enumerate() {
            let pose = &state.poses[b];
            let dx = t + w.cross(&(pose.position - c));
            let dtheta = pose.rotation.inverse() * w;
            let motion = nalgebra::Vector6::new(dx.x, dx.y, dx.z, dtheta.x, dtheta.y, dtheta.z);
            for k in 0..body.dof_count {
                local[(body.dof_offset + k, i)] = body.basis.column(k).dot(&motion);
            }
        }
    }
    let gram = local.transpose() * &local;
    let mut moved = Matrix6::<f64>::zeros();
    moved.view_mut((0, 0), (g, g)).copy_from(&gram);
    // free combinations: the null space of `broken`, restricted to those that move something
    let broken = broken.view((0, 0), (g, g)).into_owned();
    let moved = moved.view((0, 0), (g, g)).into_owned();
    let scale = moved.amax().max(1e-300);
    let eig = SymmetricEigen::new(broken);
    let free: Vec<DVector<f64>> = (0..g)
        .filter(|&i| eig.eigenvalues[i] <= 1e-10 * scale)
        .map(|i| eig.eigenvectors.column(i).into_owned())
        .collect();
    if free.is_empty() {
        return DMatrix::zeros(n, 0);
    }
    let basis = DMatrix::from_columns(&free);
    let effect = SymmetricEigen::new(basis.transpose() * moved * &basis);
    let combos: Vec<DVector<f64>> = (0..free.len())
        .filter(|&i| effect.eigenvalues[i] > 1e-10 * scale)
        .map(|i| &basis * effect.eigenvectors.column(i))
        .collect();
    if combos.is_empty() {
        // free combinations that move nothing: a node on the line through its anchors spinning
        // about that line
        return DMatrix::zeros(n, 0);
    }
    DMatrix::from_columns(&combos.iter().map(|a| &local * a).collect::<Vec<_>>())
}

/// What the reduced tangent stiffness's eigenvalues say.
pub(crate) struct Modes {
    pub(crate) min_eigenvalue: f64,
    pub(crate) negative: usize,
    pub(crate) zero: usize,
    /// Free rigid-body motions (`rigid_body_motions`) that also have zero stiffness.
    pub(crate) rigid: usize,
}

/// The symmetric reduced tangent stiffness's smallest eigenvalue and its counts of negative and
/// zero eigenvalues (relative to the largest, `1e-9`), from the dense tangent last evaluated into
/// `ws`: the reduced tangent `Z^T K_sym Z` over an orthonormal null-space basis `Z` of `Phi_q`,
/// all its eigenvalues (`sparse_stability` counts them without forming `Z`).
///
/// The stiff members `stiff_members` (the mixed form's, `stiff_cables`) are judged in their
/// inextensible limit: `Z` also spans only motions that keep their lengths, on which their
/// material stiffness `(EA/L0) g g^T` vanishes, so the tolerance scales with the structure's own
/// stiffness and not with theirs (a strut of EA 1e12 N would otherwise make every mode below
/// 1e-9 of its `EA/L0` count as zero). Along their lengths they only add stiffness.
pub(crate) fn dense_stability(
    model: &Model,
    state: &State,
    ws: &Workspace,
    stiff_members: &[usize],
) -> Modes {
    let n = model.dof_count;
    if n == 0 {
        return Modes { min_eigenvalue: 0.0, negative: 0, zero: 0, rigid: 0 };
    }
    let mut k = ws.stiffness.clone();
    if model.constraint_count > 0 {
        add_multiplier_hessian(model, &state.poses, &state.multipliers, &mut k);
    }
    let k_sym = (&k + k.transpose()) * 0.5;
    let held = if stiff_members.is_empty() {
        None
    } else {
        let nc = model.constraint_count;
        let mut j = DMatrix::zeros(nc + stiff_members.len(), n);
        if nc > 0 {
            j.view_mut((0, 0), (nc, n)).copy_from(&ws.constraint_jacobian);
        }
        let mut scratch = crate::forces::cable::CableScratch::new(2);
        for (k, &c) in stiff_members.iter().enumerate() {
            let route = model.route(CableId(c));
            crate::forces::cable::route_geometry(route, &ws.points, &mut scratch);
            let mut g = DVector::zeros(n);
            crate::forces::cable::add_length_gradient(model, route, &ws.points, &scratch, 1.0, &mut g);
            j.view_mut((nc + k, 0), (1, n)).copy_from(&g.transpose());
        }
        Some(j)
    };
    let Some(z) = crate::constraints::null_space(held.as_ref().unwrap_or(&ws.constraint_jacobian), n) else {
        return Modes { min_eigenvalue: f64::INFINITY, negative: 0, zero: 0, rigid: 0 };
    };
    let reduced = z.transpose() * &k_sym * z;
    let eig = SymmetricEigen::new(reduced).eigenvalues;
    let tol = 1e-9 * eig.amax().max(1e-300);
    // the free rigid motions, orthonormalized, and how many of them cost no energy
    let motions = rigid_body_motions(model, state, ws);
    let rigid = if motions.ncols() == 0 {
        0
    } else {
        let q = motions.qr().q();
        let on_rigid = SymmetricEigen::new(q.transpose() * &k_sym * &q).eigenvalues;
        on_rigid.iter().filter(|e| e.abs() <= tol).count()
    };
    Modes {
        min_eigenvalue: eig.min(),
        negative: eig.iter().filter(|e| **e < -tol).count(),
        zero: eig.iter().filter(|e| e.abs() <= tol).count(),
        rigid,
    }
}

/// `dense_stability` without forming the null space or any dense matrix: the inertia of
/// the sparse statics KKT matrix shifted by `sigma` (`KktSystem::symmetric_inertia`) counts the
/// reduced tangent's eigenvalues below `sigma`. With `B` the Gershgorin bound of the tangent
/// (`KktSystem::coordinate_bound`, which bounds every reduced eigenvalue) and `tol = 1e-9 B`
/// (the dense test's `1e-9` of the largest eigenvalue, with the bound in its place): negative
/// modes are those below `-tol`, zero modes those in `[-tol, tol]`. The smallest eigenvalue is
/// bracketed by bisection on the counts (geometric where the bracket has one sign) to 1e-3 and
/// then found by inverse iteration from the bracket's lower end (to 1e-12). Rigid-body modes are
/// counted on the 6 x 6 (at most) tangent over `rigid_body_motions`. Every factorization is a
/// sparse `LDL^T` of the same pattern, so the cost grows with the structure. Falls back to the
/// dense test when a shift hits a zero pivot.
pub(crate) fn sparse_stability(
    kkt: &mut KktSystem,
    model: &Model,
    state: &State,
    ws: &mut Workspace,
) -> Modes {
    let n = model.dof_count;
    if n == 0 {
        return Modes { min_eigenvalue: 0.0, negative: 0, zero: 0, rigid: 0 };
    }
    assemble_sparse(kkt, model, state, ws);
    let offset = model.constraint_count + kkt.bordered_cables();
    let bound = kkt.coordinate_bound().unwrap_or(0.0).max(1e-300);
    let tol = 1e-9 * bound;
    // eigenvalues of the reduced tangent below `shift`; a shift on an eigenvalue of a leading
    // block (a zero pivot) is moved by a part in 1e6 of the bracket scale
    let below = |kkt: &mut KktSystem, shift: f64| -> Option<usize> {
        for k in 0..4 {
            let nudged = shift + k as f64 * 1e-6 * tol;
            if let Some(i) = kkt.symmetric_inertia(nudged) {
                return Some(i.negative.saturating_sub(offset));
            }
        }
        None
    };
    let counts = below(kkt, -tol).zip(below(kkt, tol)).zip(below(kkt, 2.0 * bound + tol));
    let Some(((negative, not_positive), reduced)) = counts else {
        return dense_stability_fallback(model, state, ws);
    };
    let zero = not_positive - negative;
    if reduced == 0 {
        // every coordinate is held by a joint
        return Modes { min_eigenvalue: f64::INFINITY, negative: 0, zero: 0, rigid: 0 };
    }
    // bracket the smallest eigenvalue: nothing below `lo`, something below `hi`
    let (mut lo, mut hi) = if negative > 0 {
        (-2.0 * bound - tol, -tol)
    } else if zero > 0 {
        (-tol, tol)
    } else {
        (tol, 2.0 * bound + tol)
    };
    for _ in 0..80 {
        if hi - lo <= 1e-3 * lo.abs().max(hi.abs()) {
            break;
        }
        let mid = if lo > 0.0 {
            (lo * hi).sqrt()
        } else if hi < 0.0 {
            -(lo * hi).sqrt()
        } else {
            0.5 * (lo + hi)
        };
        match below(kkt, mid) {
            Some(0) => lo = mid,
            Some(_) => hi = mid,
            None => break,
        }
    }
    // inverse iteration with the shift `lo`, below every eigenvalue: converges to the smallest
    let mut min_eigenvalue = 0.5 * (lo + hi);
    if kkt.symmetric_inertia(lo).is_some() {
        let mut x = DVector::zeros(kkt.size());
        let mut v: DVector<f64> = DVector::from_iterator(
            n,
            (0..n).map(|i| 1.0 + 0.5 * ((i as f64 * 0.618_033_988_7).fract() - 0.5)),
        );
        v /= v.norm();
        for _ in 0..30 {
            x.fill(0.0);
            x.rows_mut(0, n).copy_from(&v);
            if !kkt.solve_factored(&mut x) {
                break;
            }
            let y = x.rows(0, n).into_owned();
            let (theta, norm) = (v.dot(&y), y.norm());
            if !(norm > 0.0 && theta.is_finite()) {
                break;
            }
            let estimate = lo + 1.0 / theta;
            let settled = (estimate - min_eigenvalue).abs() <= 1e-12 * estimate.abs().max(tol);
            min_eigenvalue = estimate;
            v = y / norm;
            if settled {
                break;
            }
        }
        min_eigenvalue = min_eigenvalue.clamp(lo, hi);
    }
    // the free rigid motions, orthonormalized, and how many of them cost no energy
    let motions = rigid_body_motions(model, state, ws);
    let rigid = if motions.ncols() == 0 {
        0
    } else {
        let q = motions.qr().q();
        let g = q.ncols();
        let mut on_rigid = DMatrix::zeros(g, g);
        for i in 0..g {
            for j in 0..=i {
                let (a, b) = (q.column(i), q.column(j));
                let v = kkt.coordinate_form(a.as_slice(), b.as_slice()).unwrap_or(0.0);
                on_rigid[(i, j)] = v;
                on_rigid[(j, i)] = v;
            }
        }
        SymmetricEigen::new(on_rigid).eigenvalues.iter().filter(|e| e.abs() <= tol).count()
    };
    Modes { min_eigenvalue, negative, zero, rigid }
}

/// The dense stability test for a sparse solver whose shifted factorizations failed: evaluates
/// the dense tangent at `state` first.
pub(crate) fn dense_stability_fallback(model: &Model, state: &State, ws: &mut Workspace) -> Modes {
    evaluate(model, state, ws, Tangents::Stiffness);
    dense_stability(model, state, ws, &[])
}
