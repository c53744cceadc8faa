//! The mixed form of the static solver: takes a model whose stiff cables have their tensions as
//! unknowns, gives the equilibrium by Newton's method on positions, reactions and those
//! tensions (`StaticSolver::equilibrate_mixed`).

use nalgebra::{DMatrix, DVector};

use crate::assembly::DenseTangents;
use crate::constraints::add_multiplier_hessian;
use crate::evaluate::{evaluate, Tangents, Workspace};
use crate::model::{CableId, Model, SolverSettings};
use crate::solve::statics::kkt::{convexity_correction, fit_multipliers, solve_regularized, STEP_CAP};
use crate::solve::statics::line_search::{line_search, LineSearch, Searched};
use crate::solve::statics::residual::{EquilibriumReport, Residual, StopReason};
use crate::solve::statics::solver::{Start, StaticSolver};
use crate::solve::statics::stiff::{MixedResidual, StiffCables};
use crate::state::{retract, State};

impl StaticSolver {
    /// Evaluates `work` (the state with the stiff cables made slack, `slack_rest_lengths`) and
    /// adds the stiff cables' forces `-T g` and, with `tangents`, their geometric stiffness
    /// `T sum_k G_k^T P_k G_k + T sum_i d(J_i^T n_i)/dq` (no material term: their stretch is
    /// the length equation's) for the tension unknowns of `stiff`; records their lengths and
    /// gradients.
    pub(crate) fn mixed_evaluate(
        model: &Model,
        work: &State,
        ws: &mut Workspace,
        stiff: &mut StiffCables,
        tangents: bool,
    ) {
        evaluate(model, work, ws, if tangents { Tangents::Stiffness } else { Tangents::None });
        let Workspace { points, scratch, stiffness, force, .. } = ws;
        for (i, &c) in stiff.ids.iter().enumerate() {
            let route = model.route(CableId(c));
            let (length, _) = crate::forces::cable::route_geometry(route, points, scratch);
            stiff.length[i] = length;
            stiff.gradient[i].fill(0.0);
            crate::forces::cable::add_length_gradient(
                model,
                route,
                points,
                scratch,
                1.0,
                &mut stiff.gradient[i],
            );
            let t = stiff.tension[i];
            if !stiff.active[i] || (t <= 0.0 && !stiff.push[i]) {
                continue;
            }
            force.axpy(-t, &stiff.gradient[i], 1.0);
            if tangents {
                let mut sink = DenseTangents { model, stiffness: &mut *stiffness, damping: None };
                crate::forces::cable::add_cable_tangents(
                    model,
                    &work.poses,
                    &work.velocities,
                    CableId(c),
                    route,
                    0.0,
                    0.0,
                    1.0,
                    t,
                    points,
                    scratch,
                    &mut sink,
                );
            }
        }
    }

    /// The residual of a mixed evaluation (`mixed_evaluate` just ran): force balance with the
    /// tension unknowns, joints, and the stiff cables' length equations (`rest` the true rest
    /// lengths). Fills `rhs` (`[r; -Phi; -h_active]`) when given.
    fn mixed_residual(
        model: &Model,
        state: &State,
        ws: &Workspace,
        stiff: &StiffCables,
        rest: &[f64],
        rhs: Option<&mut DVector<f64>>,
    ) -> MixedResidual {
        let n = model.dof_count;
        let nc = model.constraint_count;
        let mut r = ws.force.clone_owned();
        if nc > 0 {
            r -= ws.constraint_jacobian.transpose() * &state.multipliers;
        }
        let cable = (0..stiff.ids.len())
            .map(|i| stiff.length_residual(i, rest[stiff.ids[i]]).abs())
            .fold(0.0, f64::max);
        if let Some(rhs) = rhs {
            rhs.rows_mut(0, n).copy_from(&r);
            if nc > 0 {
                rhs.rows_mut(n, nc).copy_from(&(-&ws.constraint));
            }
            for (k, i) in stiff.active_ids().into_iter().enumerate() {
                rhs[n + nc + k] = -stiff.length_residual(i, rest[stiff.ids[i]]);
            }
        }
        MixedResidual { force: r.amax(), constraint: ws.constraint.amax(), cable }
    }

    /// `equilibrate` with the tensions of the stiff cables `ids` as unknowns (a mixed, or
    /// perturbed-Lagrangian, formulation): Newton on
    /// `[Q - sum_s T_s g_s - Phi_q^T lambda; Phi; L_s - L0_s - c_s T_s] = 0` (`c = L0/EA`) for
    /// every taut stiff cable `s`, whose matrix
    /// `[[K' + H_lambda, Phi_q^T, G], [Phi_q, 0, 0], [G^T, 0, -diag(c)]]` stays well conditioned
    /// as `c -> 0` (`K'` the tangent of the other cables and gravity plus the stiff cables'
    /// geometric stiffness at `T`, `G` their length gradients). Its residual measures a stiff
    /// cable's misfit as a length, where the displacement form measures `EA/L0` times it as a
    /// force: a step that swings a bar about its pin stretches a cable tied to it to second
    /// order, which the displacement form's line search sees as a force `EA/L0` times that
    /// stretch and refuses, so its iteration count grew with EA until the cap (1e6 N on a bar
    /// held over a pulley); here the tension follows the step linearly. A cable whose tension
    /// falls to zero while its length is below its rest length goes slack (its equation is
    /// dropped), and a slack one is taken up again as soon as it is stretched. Convergence is
    /// tested on the displacement form's residual, as in `equilibrate`.
    pub(crate) fn equilibrate_mixed(
        &mut self,
        model: &Model,
        state: &mut State,
        ws: &mut Workspace,
        settings: &SolverSettings,
        ids: Vec<usize>,
        bilateral: bool,
    ) -> Result<EquilibriumReport, (usize, f64)> {
        let n = model.dof_count;
        let nc = model.constraint_count;
        state.velocities.fill(0.0);
        let start_poses = state.poses.clone();
        let start_multipliers = state.multipliers.clone();
        let rest = state.rest_lengths.clone();
        let fresh = state.multipliers.iter().all(|l| *l == 0.0);
        // the work state: the stiff cables made slack, their forces added from the unknowns
        let mut work = state.clone();
        for &c in &ids {
            work.rest_lengths[c] = crate::forces::cable::DISENGAGED;
        }
        evaluate(model, state, ws, Tangents::None);
        let m = ids.len();
        let mut stiff = StiffCables {
            tension: ids.iter().map(|&c| ws.cables[c].tension).collect(),
            compliance: ids.iter().map(|&c| rest[c] / model.cables[c].axial_stiffness).collect(),
            push: ids.iter().map(|&c| bilateral || !model.cables[c].tension_only).collect(),
            active: ids
                .iter()
                .map(|&c| bilateral || ws.cables[c].tension > 0.0 || !model.cables[c].tension_only)
                .collect(),
            length: vec![0.0; m],
            gradient: vec![DVector::zeros(n); m],
            ids,
        };
        if fresh {
            work.poses.copy_from_slice(&state.poses);
            Self::mixed_evaluate(model, &work, ws, &mut stiff, false);
            least_squares_tensions(model, &mut work, ws, &mut stiff, &rest);
            state.multipliers.copy_from(&work.multipliers);
        }
        let mut best = f64::INFINITY;
        let mut iterations = 0;
        let mut check_convexity = true;
        let mut previous_merit = f64::INFINITY;
        loop {
            // converged in the displacement form, as `equilibrate` tests it
            let res = match self.start_iteration(model, state, ws, settings, iterations, &mut best) {
                Start::Go(res) => res,
                Start::Converged(report) => return Ok(report),
                Start::Stop => break,
            };
            iterations += 1;

            // the active set: taut where the cable carries tension or is stretched
            work.poses.copy_from_slice(&state.poses);
            work.multipliers.copy_from(&state.multipliers);
            Self::mixed_evaluate(model, &work, ws, &mut stiff, false);
            for i in 0..m {
                // taut while it carries tension or is stretched (a member always)
                stiff.active[i] =
                    stiff.push[i] || stiff.tension[i] > 0.0 || stiff.length[i] > rest[stiff.ids[i]];
                if !stiff.active[i] {
                    stiff.tension[i] = 0.0;
                }
            }
            Self::mixed_evaluate(model, &work, ws, &mut stiff, true);
            let active = stiff.active_ids();
            let ma = active.len();
            let size = n + nc + ma;
            let mut rhs = DVector::zeros(size);
            let mres = Self::mixed_residual(model, &work, ws, &stiff, &rest, Some(&mut rhs));
            let f_scale = model
                .bodies
                .iter()
                .map(|b| b.mass * model.gravity.norm())
                .chain(ws.cables.iter().map(|c| c.tension.abs()))
                .chain(stiff.tension.iter().map(|t| t.abs()))
                .fold(1e-12, f64::max);
            let l_scale = res.length_scale;

            // [[K' + H, Phi_q^T, G], [Phi_q, 0, 0], [G^T, 0, -c]]
            let mut kkt = DMatrix::zeros(size, size);
            kkt.view_mut((0, 0), (n, n)).copy_from(&ws.stiffness);
            if nc > 0 {
                let mut h = DMatrix::zeros(n, n);
                add_multiplier_hessian(model, &work.poses, &work.multipliers, &mut h);
                let mut top = kkt.view_mut((0, 0), (n, n));
                top += &h;
                kkt.view_mut((0, n), (n, nc)).copy_from(&ws.constraint_jacobian.transpose());
                kkt.view_mut((n, 0), (nc, n)).copy_from(&ws.constraint_jacobian);
            }
            let mut jacobian = DMatrix::zeros(nc + ma, n);
            if nc > 0 {
                jacobian.view_mut((0, 0), (nc, n)).copy_from(&ws.constraint_jacobian);
            }
            for (k, &i) in active.iter().enumerate() {
                let g = &stiff.gradient[i];
                kkt.view_mut((0, n + nc + k), (n, 1)).copy_from(g);
                kkt.view_mut((n + nc + k, 0), (1, n)).copy_from(&g.transpose());
                kkt[(n + nc + k, n + nc + k)] = -stiff.compliance[i];
                jacobian.view_mut((nc + k, 0), (1, n)).copy_from(&g.transpose());
            }
            // saddle-free on the null space of the joints and the stiff cables' lengths
            let tangent = kkt.view((0, 0), (n, n)).into_owned();
            let residual_force = rhs.rows(0, n).into_owned();
            let merit_now = mres.merit(f_scale, l_scale);
            check_convexity |= merit_now > 0.25 * previous_merit;
            previous_merit = merit_now;
            let mut energy_mode = false;
            // not while a contact slips: its friction is not the gradient of an energy (the
            // tangent's coupling `mu t (dF_n/dq)` is not symmetric, so the symmetric part reads
            // as indefinite) and a descent step of the energy is no step towards equilibrium
            // (the spring energy grows as the contact slips along the cone): Newton's own step
            // on the consistent tangent, judged by the residual
            let checked = check_convexity && self.slipping.is_empty();
            check_convexity = false;
            if checked {
                let scales = Residual { force_scale: f_scale, length_scale: l_scale, ..res };
                if let Some((correction, descent)) =
                    convexity_correction(model, &tangent, &jacobian, &self.mass, &scales, &residual_force)
                {
                    check_convexity = true;
                    let mut top = kkt.view_mut((0, 0), (n, n));
                    top += &correction;
                    energy_mode = descent;
                }
            }
            let Some(step) = solve_regularized(&kkt, &rhs, n) else {
                self.stop = StopReason::Singular;
                break;
            };
            self.dq.copy_from(&step.rows(0, n));
            let limit = self.step_limit(model, l_scale);
            let dlambda = step.rows(n, nc).into_owned();
            let mut dt = vec![0.0; m];
            for (k, &i) in active.iter().enumerate() {
                dt[i] = step[n + nc + k];
            }

            // line search, as in `equilibrate`, on the mixed residual or the energy
            let penalty = 10.0
                * ((&state.multipliers + &dlambda).amax()
                    + (0..m).map(|i| (stiff.tension[i] + dt[i]).abs()).fold(0.0, f64::max)
                    + f_scale);
            let energy_of = |ws: &Workspace, stiff: &StiffCables, cable: f64| {
                let stiff_energy: f64 = (0..m)
                    .filter(|&i| stiff.active[i])
                    .map(|i| 0.5 * stiff.compliance[i] * stiff.tension[i].powi(2))
                    .sum();
                ws.energies.elastic
                    + ws.energies.gravitational
                    + stiff_energy
                    + penalty * (ws.constraint.amax() + cable)
            };
            let search = LineSearch {
                limit,
                merit0: merit_now,
                energy0: energy_of(ws, &stiff, mres.cable),
                energy_mode,
            };
            let base_multipliers = state.multipliers.clone();
            let base_tension = stiff.tension.clone();
            let searched = line_search(&search, |alpha| {
                work.poses.copy_from_slice(&state.poses);
                retract(model, &mut work.poses, &self.dq, alpha);
                work.multipliers = &base_multipliers + &dlambda * alpha;
                for i in 0..m {
                    stiff.tension[i] = stiff.next_tension(i, base_tension[i], alpha * dt[i]);
                }
                if energy_mode {
                    Self::mixed_evaluate(model, &work, ws, &mut stiff, false);
                    project_onto_mixed(model, &mut work, ws, &mut stiff, &rest, l_scale);
                }
                Self::mixed_evaluate(model, &work, ws, &mut stiff, false);
                let trial_res = Self::mixed_residual(model, &work, ws, &stiff, &rest, None);
                (trial_res.merit(f_scale, l_scale), energy_of(ws, &stiff, trial_res.cable))
            });
            let Some(Searched { alpha, .. }) = searched else {
                stiff.tension.copy_from_slice(&base_tension);
                self.stop = StopReason::Diverged;
                break;
            };
            check_convexity |= alpha < limit.min(1.0);
            retract(model, &mut state.poses, &self.dq, alpha);
            state.multipliers = &base_multipliers + &dlambda * alpha;
            for i in 0..m {
                stiff.tension[i] = stiff.next_tension(i, base_tension[i], alpha * dt[i]);
            }
            if energy_mode {
                // a descent step moves the poses, not towards the reactions: take them afresh
                work.poses.copy_from_slice(&state.poses);
                work.multipliers.copy_from(&state.multipliers);
                Self::mixed_evaluate(model, &work, ws, &mut stiff, false);
                project_onto_mixed(model, &mut work, ws, &mut stiff, &rest, l_scale);
                fit_multipliers(model, &mut work.multipliers, ws);
                state.poses.copy_from_slice(&work.poses);
                state.multipliers.copy_from(&work.multipliers);
            }
        }
        state.poses.copy_from_slice(&start_poses);
        state.multipliers.copy_from(&start_multipliers);
        Err((iterations, best))
    }

    /// The largest fraction of the Newton step `self.dq` that moves no body by more than 0.5 rad
    /// or `STEP_CAP` length scales.
    pub(crate) fn step_limit(&self, model: &Model, length_scale: f64) -> f64 {
        let mut limit: f64 = 1.0;
        for b in &model.bodies {
            for c in 0..b.dof_count {
                let col = b.basis.column(c);
                let x = self.dq[b.dof_offset + c].abs();
                let cap = if col.fixed_rows::<3>(3).norm() > 0.0 { 0.5 } else { STEP_CAP * length_scale };
                if x > cap {
                    limit = limit.min(cap / x);
                }
            }
        }
        limit
    }
}

/// The joint reactions and stiff-cable tensions that best balance the other forces, the tensions
/// kept near their current values along any self-stress the forces do not decide:
/// `[lambda; T] = argmin |Q_other - Phi_q^T lambda - G T|^2 + eps |T - T_now|^2` over the joints
/// and the stiff cables that are stretched or just taut (`L >= L0`, `rest` the true rest
/// lengths), tensions clamped at zero, `eps` a 1e-8 part of the largest diagonal entry. `ws` and
/// `stiff` come from `mixed_evaluate` at `work` (`Q_other` is its force with the stiff cables'
/// tensions added back). A fresh start's tensions so balance the loads instead of following an
/// overstretched sketch (1e5 N for a 1 kg mass on a cable of EA 1e6 N drawn 10 % too long).
/// Left unchanged when the system is singular.
pub(crate) fn least_squares_tensions(
    model: &Model,
    work: &mut State,
    ws: &Workspace,
    stiff: &mut StiffCables,
    rest: &[f64],
) {
    let n = model.dof_count;
    let nc = model.constraint_count;
    let mut q = ws.force.clone_owned();
    for i in 0..stiff.ids.len() {
        if stiff.active[i] && (stiff.tension[i] > 0.0 || stiff.push[i]) {
            q.axpy(stiff.tension[i], &stiff.gradient[i], 1.0);
        }
    }
    let taut: Vec<usize> =
        (0..stiff.ids.len()).filter(|&i| stiff.push[i] || stiff.length[i] >= rest[stiff.ids[i]]).collect();
    let rows = nc + taut.len();
    if rows == 0 {
        return;
    }
    let mut j = DMatrix::zeros(rows, n);
    if nc > 0 {
        j.view_mut((0, 0), (nc, n)).copy_from(&ws.constraint_jacobian);
    }
    for (k, &i) in taut.iter().enumerate() {
        j.view_mut((nc + k, 0), (1, n)).copy_from(&stiff.gradient[i].transpose());
    }
    let mut normal = &j * j.transpose();
    let mut rhs = &j * &q;
    let eps = 1e-8 * (0..rows).map(|r| normal[(r, r)]).fold(0.0, f64::max);
    for (k, &i) in taut.iter().enumerate() {
        normal[(nc + k, nc + k)] += eps;
        rhs[nc + k] += eps * stiff.tension[i];
    }
    let Some(y) = normal.lu().solve(&rhs) else { return };
    if !y.iter().all(|x| x.is_finite()) {
        return;
    }
    if nc > 0 {
        work.multipliers.copy_from(&y.rows(0, nc));
    }
    for (k, &i) in taut.iter().enumerate() {
        stiff.tension[i] = if stiff.push[i] { y[nc + k] } else { y[nc + k].max(0.0) };
        stiff.active[i] = true;
    }
}

/// Moves `work`'s poses onto `Phi = 0` and the active stiff cables' `L = L0 + c T` (tensions
/// held) by Gauss-Newton steps of the smallest correction, like `project_onto_joints`; leaves
/// `ws` and `stiff` evaluated at the result (no tangents).
pub(crate) fn project_onto_mixed(
    model: &Model,
    work: &mut State,
    ws: &mut Workspace,
    stiff: &mut StiffCables,
    rest: &[f64],
    length_scale: f64,
) {
    let n = model.dof_count;
    let nc = model.constraint_count;
    for _ in 0..8 {
        StaticSolver::mixed_evaluate(model, work, ws, stiff, false);
        let active = stiff.active_ids();
        let rows = nc + active.len();
        if rows == 0 {
            return;
        }
        let mut j = DMatrix::zeros(rows, n);
        let mut phi = DVector::zeros(rows);
        if nc > 0 {
            j.view_mut((0, 0), (nc, n)).copy_from(&ws.constraint_jacobian);
            phi.rows_mut(0, nc).copy_from(&ws.constraint);
        }
        for (k, &i) in active.iter().enumerate() {
            j.view_mut((nc + k, 0), (1, n)).copy_from(&stiff.gradient[i].transpose());
            phi[nc + k] = stiff.length_residual(i, rest[stiff.ids[i]]);
        }
        if phi.amax() <= 1e-12 * length_scale {
            return;
        }
        let Some(y) = (&j * j.transpose()).lu().solve(&phi) else { return };
        let dq = -(j.transpose() * y);
        if !dq.iter().all(|x| x.is_finite()) {
            return;
        }
        retract(model, &mut work.poses, &dq, 1.0);
    }
    StaticSolver::mixed_evaluate(model, work, ws, stiff, false);
}
