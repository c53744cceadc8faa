//! The KKT helpers of the static solver: takes a model, a state and its evaluation, gives the
//! joints' least-squares reactions, projections back onto the joints, the convexity shift of an
//! indefinite tangent, and the dense (regularized) and sparse solves of the KKT system.

use nalgebra::{DMatrix, DVector, SymmetricEigen};

use crate::constraints::add_multiplier_hessian_to;
use crate::evaluate::{add_workspace_tangents, evaluate, evaluate_forces, Tangents, Workspace};
use crate::model::Model;
use crate::solve::linear::KktSystem;
use crate::solve::statics::residual::Residual;
use crate::state::{retract, State};

/// At an equilibrium found: the pulleys' return map (`crate::forces::pulley`) becomes the
/// state's segment rest lengths, and the stick-slip contacts' anchors follow what slipped
/// (`crate::forces::contact::commit_anchors`), so the next solve (a deployment's next load
/// step) starts from the material and the anchors where this one left them.
pub(crate) fn commit_friction(model: &Model, state: &mut State, ws: &mut Workspace) {
    if !model.pulley_friction.is_empty() {
        crate::forces::pulley::commit(model, &mut ws.friction, &mut state.segment_rest_lengths, 0.0);
    }
    if !state.contact_anchors.is_empty() {
        let (poses, anchors) = (&state.poses, &mut state.contact_anchors);
        // (statics keeps no energy account: what slipping removed goes unbooked)
        crate::forces::contact::commit_anchors(model, poses, &ws.points, &ws.contacts, anchors);
    }
}

/// Largest translation of a body per Newton iteration, as a fraction of the length scale.
pub const STEP_CAP: f64 = 1.0;

/// Largest system (coordinates) for which the reduced tangent's definiteness is checked each
/// iteration (a dense eigenproblem); larger systems take plain Newton steps.
pub const MAX_CONVEXITY_CHECK: usize = 600;

/// Smallest system (coordinates) that `StaticSolver` solves on the sparse KKT system: its
/// stability test by shifted sparse factorizations (`sparse_stability`) instead of a dense
/// eigenproblem, and, without stiff cables, plain Newton steps (no convexity check) by a
/// sparse LU instead of a dense one. `tensegrity bench scaling` put the dynamics' crossover
/// between 100 and 200 unknowns; the dense statics path's eigenproblems cost more per unknown.
pub const SPARSE_STATICS_MIN: usize = 200;

/// The joint reactions that best balance the current forces: `lambda = argmin |Q - Phi_q^T lambda|`,
/// i.e. `(Phi_q Phi_q^T) lambda = Phi_q Q`. Exact at an equilibrium; elsewhere it gives the joints'
/// geometric stiffness `H_lambda` its right sign and size from the first iteration on (a hanging
/// pendulum started with `lambda = 0` has no stiffness at all). Left unchanged when `Phi_q` is
/// rank deficient.
pub(crate) fn least_squares_multipliers(model: &Model, state: &mut State, ws: &mut Workspace) {
    if model.constraint_count == 0 {
        return;
    }
    evaluate(model, state, ws, Tangents::None);
    fit_multipliers(model, &mut state.multipliers, ws);
}

/// `least_squares_multipliers` on the sparse `kkt`: the reactions from the symmetric
/// quasi-definite system `[[I, Phi_q^T], [Phi_q, 0]] [x; lambda] = [Q; 0]`, whose solution has
/// `Phi_q Phi_q^T lambda = Phi_q Q` (its exact sparse `LDL^T`, no dense `nc x nc` matrix).
pub(crate) fn sparse_least_squares_multipliers(
    kkt: &mut KktSystem,
    model: &Model,
    state: &mut State,
    ws: &mut Workspace,
) {
    let (n, nc) = (model.dof_count, model.constraint_count);
    if nc == 0 {
        return;
    }
    evaluate_forces(model, state, ws);
    kkt.clear();
    kkt.add_to_coordinate_diagonal(1.0);
    kkt.add_joints(model, &state.poses, &ws.points);
    let mut x = DVector::zeros(kkt.size());
    x.rows_mut(0, n).copy_from(&ws.force);
    if kkt.factor_symmetric() && kkt.solve_factored(&mut x) {
        state.multipliers.copy_from(&x.rows(n, nc));
    }
}

/// `multipliers = argmin |Q - Phi_q^T lambda|` for the force `Q` and joint Jacobian evaluated
/// into `ws` (the displacement form's, or a mixed evaluation's with the stiff cables' tensions
/// held: those are not fitted, since a prestressed structure's self-stress is not decided by its
/// loads and a fit would drop it). Left unchanged without joints or when `Phi_q` is rank
/// deficient.
pub(crate) fn fit_multipliers(model: &Model, multipliers: &mut DVector<f64>, ws: &Workspace) {
    if model.constraint_count == 0 {
        return;
    }
    let j = &ws.constraint_jacobian;
    if let Some(lambda) = (j * j.transpose()).lu().solve(&(j * &ws.force)) {
        if lambda.iter().all(|x| x.is_finite()) {
            *multipliers = lambda;
        }
    }
}

/// Moves the poses back onto the joints' manifold `Phi(q) = 0` by Gauss-Newton steps
/// `dq = -Phi_q^T (Phi_q Phi_q^T)^-1 Phi` (the smallest correction), until `|Phi|_inf` is below
/// `1e-12 length_scale` or after 8 steps. Leaves the workspace evaluated (no tangents).
pub(crate) fn project_onto_joints(model: &Model, state: &mut State, ws: &mut Workspace, length_scale: f64) {
    if model.constraint_count == 0 {
        return;
    }
    for _ in 0..8 {
        evaluate(model, state, ws, Tangents::None);
        if ws.constraint.amax() <= 1e-12 * length_scale {
            return;
        }
        let j = &ws.constraint_jacobian;
        let Some(y) = (j * j.transpose()).lu().solve(&ws.constraint) else { return };
        let dq = -(j.transpose() * y);
        if !dq.iter().all(|x| x.is_finite()) {
            return;
        }
        retract(model, &mut state.poses, &dq, 1.0);
    }
    evaluate(model, state, ws, Tangents::None);
}

/// A positive-definite modification of the tangent on the null space of `jacobian` (the joints'
/// `Phi_q`, with the stiff cables' length gradients in the mixed iteration: "saddle-free"
/// Newton). With `Z` spanning the null space of `jacobian`, `Z^T M Z = L L^T` and the mass-normalized
/// reduced tangent `S = L^-1 Z^T A Z L^-T = V diag(e) V^T` (`A` the symmetric part of `tangent`),
/// each eigenvalue at or below `1e-8 max|e|` (negative: heading for a maximum or saddle; zero: a
/// neutral or slack direction) becomes `max(|e|, delta)`, `delta = max(1e-2 max|e|, 1e-3 (|g| +
/// F_scale / m_max) / L_scale)` (1/s^2); the others are kept, so Newton stays quadratic where the
/// tangent is fine. Returns the correction `M Z L^-T V diag(e' - e) V^T L^-1 Z^T M` to add to the
/// tangent, and whether the residual has a significant part along the modified directions (then
/// the step is a descent step of the energy, and the line search measures the energy). `None`
/// when nothing needs modifying or the system is too large to check.
pub(crate) fn convexity_correction(
    model: &Model,
    tangent: &DMatrix<f64>,
    jacobian: &DMatrix<f64>,
    mass: &DMatrix<f64>,
    res: &Residual,
    residual: &DVector<f64>,
) -> Option<(DMatrix<f64>, bool)> {
    let n = model.dof_count;
    if n == 0 || n > MAX_CONVEXITY_CHECK {
        return None;
    }
    let z = crate::constraints::null_space(jacobian, n)?;
    let a = (tangent + tangent.transpose()) * 0.5;
    let chol = (z.transpose() * mass * &z).cholesky()?;
    let l_inv = chol.l().try_inverse()?;
    let s = &l_inv * (z.transpose() * a * &z) * l_inv.transpose();
    let eig = SymmetricEigen::new((&s + s.transpose()) * 0.5);
    let e_max = eig.eigenvalues.amax();
    let m_max = model.bodies.iter().map(|b| b.mass).fold(0.0, f64::max).max(1e-300);
    let floor = (model.gravity.norm() + res.force_scale / m_max) / res.length_scale;
    let delta = (1e-2 * e_max).max(1e-3 * floor);
    let modified: Vec<usize> =
        (0..eig.eigenvalues.len()).filter(|&i| eig.eigenvalues[i] <= 1e-8 * e_max).collect();
    if modified.is_empty() {
        return None;
    }
    // residual in the mass-normalized eigenbasis
    let c = eig.eigenvectors.transpose() * (&l_inv * (z.transpose() * residual));
    let along: f64 = modified.iter().map(|&i| c[i] * c[i]).sum();
    let descent = along > 1e-12 * c.norm_squared().max(1e-300) && along.sqrt() > 1e-14 * res.force_scale;
    let mut d = DVector::zeros(eig.eigenvalues.len());
    for &i in &modified {
        let e = eig.eigenvalues[i];
        d[i] = e.abs().max(delta) - e;
    }
    let v = &eig.eigenvectors;
    let ds = v * DMatrix::from_diagonal(&d) * v.transpose();
    let b = mass * &z * l_inv.transpose();
    Some((&b * ds * b.transpose(), descent))
}

/// Assembles the statics KKT matrix `[[K + H_lambda, Phi_q^T], [Phi_q, 0]]` into the sparse
/// `kkt` at `state` (clustered cables bordered, `crate::solve::linear`), from the point
/// kinematics, cable and contact responses last evaluated into `ws` (no dense tangent needed).
pub(crate) fn assemble_sparse(kkt: &mut KktSystem, model: &Model, state: &State, ws: &mut Workspace) {
    kkt.clear();
    kkt.add_joints(model, &state.poses, &ws.points);
    let mut sink = kkt.tangents(1.0, 0.0);
    add_workspace_tangents(model, state, ws, &mut sink);
    if model.constraint_count > 0 {
        add_multiplier_hessian_to(model, &state.poses, &state.multipliers, 1.0, &mut sink);
    }
}

/// `solve_regularized` on the sparse `kkt` (assembled by `assemble_sparse`): its exact sparse LU,
/// with the Levenberg term `mu I` on the coordinates grown from `1e-14` of the Gershgorin bound
/// (`KktSystem::coordinate_bound`) while the factorization fails or the solution is not finite
/// or misses the equations by more than `1e-6` of the right-hand side.
/// `rhs` has the `n + nc` rows of the unknowns `[dq; dlambda]`; so has the answer.
pub(crate) fn solve_sparse(kkt: &mut KktSystem, rhs: &DVector<f64>) -> Option<DVector<f64>> {
    let rows = rhs.len();
    let scale = kkt.coordinate_bound()?.max(1e-12);
    let mut mu = 1e-14 * scale;
    let mut added = 0.0;
    let (mut x, mut b, mut check) =
        (DVector::zeros(kkt.size()), DVector::zeros(kkt.size()), DVector::zeros(kkt.size()));
    for _ in 0..8 {
        kkt.add_to_coordinate_diagonal(mu - added);
        added = mu;
        b.fill(0.0);
        b.rows_mut(0, rows).copy_from(rhs);
        x.copy_from(&b);
        if kkt.factor() && kkt.solve_factored(&mut x) {
            kkt.multiply(&x, &mut check);
            if (&check - &b).amax() <= 1e-6 * b.amax().max(1e-300) {
                return Some(x.rows(0, rows).into_owned());
            }
        }
        mu *= 1000.0;
    }
    None
}

/// Solves the KKT system with a Levenberg term `mu I` on the coordinate block, starting from
/// `mu = 1e-14 max|K_ii|` (negligible for a regular system, but it turns an exactly neutral
/// direction, such as an equal-mass Atwood machine's sliding mode, into a zero step instead of a
/// round-off one) and growing it while the LU fails or gives non-finite values.
pub(crate) fn solve_regularized(kkt: &DMatrix<f64>, rhs: &DVector<f64>, n: usize) -> Option<DVector<f64>> {
    let diag = (0..n).map(|i| kkt[(i, i)].abs()).fold(0.0, f64::max).max(1e-12);
    let mut mu = 1e-14 * diag;
    for _ in 0..8 {
        let mut a = kkt.clone();
        for i in 0..n {
            a[(i, i)] += mu;
        }
        if let Some(x) = a.clone().lu().solve(rhs) {
            if x.iter().all(|v| v.is_finite()) && (&a * &x - rhs).amax() <= 1e-6 * rhs.amax().max(1e-300) {
                return Some(x);
            }
        }
        mu *= 1000.0;
    }
    None
}
