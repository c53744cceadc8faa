//! Generalized-alpha: one implicit step of `Dynamics` (Newton on the analytic tangent, modified
//! Newton with reused factors) and its Newton matrix.
//!
//! **Generalized-alpha** (Chung & Hulbert 1993; Lie-group form of Bruls, Cardona & Arnold 2012,
//! constraints at position level as in Arnold & Bruls 2007). With spectral radius at infinity
//! `rho` in [0, 1]: `alpha_m = (2 rho - 1)/(rho + 1)`, `alpha_f = rho/(rho + 1)`,
//! `gamma = 1/2 + alpha_f - alpha_m`, `beta = (gamma + 1/2)^2 / 4`; the pseudo-acceleration `a`
//! obeys `(1 - alpha_m) a_(n+1) + alpha_m a_n = (1 - alpha_f) vdot_(n+1) + alpha_f vdot_n`,
//! `q_(n+1) = q_n exp(h v_n + h^2 (1/2 - beta) a_n + h^2 beta a_(n+1))`,
//! `v_(n+1) = v_n + h (1 - gamma) a_n + h gamma a_(n+1)`, and the equations hold at `t_(n+1)`.
//! Newton on the increment `delta` uses the analytic tangent
//! `S = M beta' + (C + C_gyro) gamma' + K + H_lambda`, `beta' = (1 - alpha_m)/(h^2 beta (1 - alpha_f))`,
//! `gamma' = gamma/(h beta)` (the exponential map's tangent operator is taken as identity, which
//! costs Newton a little speed, never accuracy), with the constraint rows scaled by `beta'`.
//! Second order, A-stable, `rho = 1` has no numerical dissipation, `rho = 0` annihilates the
//! highest frequencies in one step.
//!
//! Modified Newton: the factors of the Newton matrix are kept across iterations and steps while
//! they contract the residual by at least `1 / REFACTOR_CONTRACTION` per iteration; on the sparse
//! backend they are the `LDL^T` of the matrix's symmetric part, replaced by the exact LU for the
//! rest of a step when fresh symmetric factors contract poorly (`crate::solve::linear`); a step
//! that needed `SLOW_STEP_ITERATIONS` iterations on old factors makes the next one start with
//! fresh factors. The convergence test is the residual test above either way. The workspace of
//! the last (converged) evaluation is handed to the caller (`take_final_evaluation`), so a step
//! evaluates the forces once per Newton iteration plus once to confirm convergence, no more.
//!
use nalgebra::Matrix6;

use crate::constraints::{add_multiplier_hessian_to, add_reaction_force};
use crate::evaluate::{add_workspace_tangents, evaluate_forces, Workspace};
use crate::forces::contact::contact_point;
use crate::model::Model;
use crate::solve::linear::{FactorKind, KktSystem};
use crate::state::{retract, State};

use crate::solve::dynamics::error_control::{
    damped_mode_relief, jerk_decay_rate, jerk_envelope, ENVELOPE_HOLD,
};
use crate::solve::dynamics::integrator::AlphaCoefficients;
use crate::solve::dynamics::system::{
    add_gyroscopic, add_gyroscopic_damping, all_finite, assemble_mass_and_joints, force_floor, force_scale,
    AttemptFailure, AttemptStats, Dynamics, NewtonSettings, MAX_STALE_ITERATIONS, REFACTOR_CONTRACTION,
    SLOW_STEP_ITERATIONS,
};

/// The fraction `alpha <= 1` of the Newton update `dd` at the iterate `state` (local coordinates,
/// its velocity change `gamma' dd`) that leaves every contact (against a ground, or between two
/// struts) that slips now (slip speed above
/// `SLIP_LIMIT_ZONE` times its `stiction_speed`) no further than the stick zone when the update
/// would reverse its slip: `alpha = -u . du / |du|^2` for the slip `u` and its change `du`, the
/// point of the update's line closest to zero slip. The friction law changes sign across a zone
/// of width `v_s`, thousands of times smaller than the velocity a step changes by: a full Newton
/// update from one side lands on the other, and back. 1 when nothing reverses.
fn slip_reversal_limit(
    model: &Model,
    state: &State,
    ws: &Workspace,
    dd: nalgebra::DVectorView<'_, f64>,
    gamma_p: f64,
) -> f64 {
    let mut alpha: f64 = 1.0;
    for (k, sphere, ground) in model.contact_pair_list() {
        let c = &ws.contacts[k];
        let v_s = ground.material.stiction_speed;
        if c.normal_force <= 0.0
            || ground.material.friction == 0.0
            || ground.material.stick.is_some()
            || c.slip.norm() <= SLIP_LIMIT_ZONE * v_s
        {
            continue;
        }
        // the slip is the contact point's: its velocity change is J_c gamma' dd
        let kin = &ws.points[sphere.point.0];
        let j_c = contact_point(model, &state.poses, &state.velocities, ground, sphere, kin).jacobian;
        let body = &model.bodies[kin.body.0];
        let mut dv = nalgebra::Vector3::zeros();
        for k in 0..body.dof_count {
            dv += j_c.column(k) * (gamma_p * dd[body.dof_offset + k]);
        }
        let du = dv - ground.normal * ground.normal.dot(&dv);
        if (c.slip + du).dot(&c.slip) < 0.0 {
            alpha = alpha.min(-c.slip.dot(&du) / du.norm_squared());
        }
    }
    // strut pairs: the slip is the closest points' relative velocity, shared between each bar's
    // ends as the force is (`forces::collision`)
    let m = &model.strut_material;
    if m.friction > 0.0 {
        let first = model.ground_pairs();
        for (i, pair) in model.strut_pairs.iter().enumerate() {
            let c = &ws.contacts[first + i];
            if c.normal_force <= 0.0 || c.slip.norm() <= SLIP_LIMIT_ZONE * m.stiction_speed {
                continue;
            }
            let cp = &ws.strut_closest[i];
            let mut dv = nalgebra::Vector3::zeros();
            for (p, share) in pair.ends.iter().zip([1.0 - cp.s, cp.s, cp.t - 1.0, -cp.t]) {
                let kin = &ws.points[p.0];
                let body = &model.bodies[kin.body.0];
                for k in 0..body.dof_count {
                    dv += kin.jacobian.column(k) * (share * gamma_p * dd[body.dof_offset + k]);
                }
            }
            let du = dv - c.normal * c.normal.dot(&dv);
            if (c.slip + du).dot(&c.slip) < 0.0 {
                alpha = alpha.min(-c.slip.dot(&du) / du.norm_squared());
            }
        }
    }
    alpha
}

/// Slip speeds above this many times a contact's `stiction_speed` count as slipping for
/// `slip_reversal_limit`.
pub const SLIP_LIMIT_ZONE: f64 = 2.0;

impl Dynamics {
    #[allow(clippy::too_many_arguments)]
    pub(super) fn generalized_alpha(
        &mut self,
        model: &Model,
        c: AlphaCoefficients,
        newton: &NewtonSettings,
        state: &mut State,
        rest_next: &[f64],
        h: f64,
        tolerance: Option<f64>,
    ) -> Result<AttemptStats, AttemptFailure> {
        self.explicit.invalidate();
        let n = model.dof_count;
        let nc = model.constraint_count;
        let beta_p = (1.0 - c.alpha_m) / (h * h * c.beta * (1.0 - c.alpha_f));
        let gamma_p = c.gamma / (h * c.beta);

        // predictor: constant acceleration
        self.vdot.copy_from(&self.acceleration);
        self.update_pseudo_acceleration(&c);
        self.v.copy_from(&state.velocities);
        self.v.axpy(h * (1.0 - c.gamma), &self.pseudo_acceleration, 1.0);
        self.v.axpy(h * c.gamma, &self.a_next, 1.0);
        self.delta.copy_from(&state.velocities);
        self.delta.axpy(h * h * (0.5 - c.beta), &self.pseudo_acceleration, h);
        self.delta.axpy(h * h * c.beta, &self.a_next, 1.0);
        self.lambda.copy_from(&state.multipliers);

        self.trial.time = state.time + h;
        self.trial.rest_lengths.copy_from_slice(rest_next);
        self.trial.segment_rest_lengths.copy_from_slice(&state.segment_rest_lengths);
        self.trial.winches.copy_from_slice(&state.winches);
        self.trial.contact_anchors.copy_from_slice(&state.contact_anchors);
        let mut stats = AttemptStats::default();
        let coefficients = (beta_p, gamma_p);
        // with regularized friction, full Newton: its slope changes by orders of magnitude
        // between slip and stick, and old factors then point the wrong way (on the six-bar
        // robot's roll at stiction speeds 1e-3 to 1e-5 m/s, modified Newton had 15 to 92 steps
        // rejected in 4 s, full Newton none). Stick-slip friction's slope stays within its
        // spring's, and modified Newton keeps its factors through most steps
        let contacts =
            model.contact_pairs() > 0 && (model.has_regularized_friction() || !model.has_stick_friction());
        let mut reuse = newton.reuse_factorization
            && !contacts
            && self.factored_for == Some(coefficients)
            && !self.refresh;
        let mut previous = f64::INFINITY;
        let mut stale = 0;
        let mut factorizations = 0;
        // full Newton factors the exact matrix; modified Newton starts from the symmetric part's
        // LDL^T and turns to the exact LU for the rest of the step when fresh symmetric factors
        // do not contract the residual well enough
        let mut exact = !newton.reuse_factorization || contacts;
        let mut fresh = false;
        for iter in 0..=newton.max_iterations {
            self.trial.poses.copy_from_slice(&state.poses);
            retract(model, &mut self.trial.poses, &self.delta, 1.0);
            self.trial.velocities.copy_from(&self.v);
            self.trial.multipliers.copy_from(&self.lambda);
            evaluate_forces(model, &self.trial, &mut self.ws);

            // residual r = M vdot + gyro - Q + Phi_q^T lambda
            let mut residual = std::mem::take(&mut self.residual);
            self.mass_times(model, &self.vdot, &mut residual);
            let inertial = residual.amax();
            add_gyroscopic(model, &self.v, &mut residual);
            residual -= &self.ws.force;
            add_reaction_force(model, &self.trial.poses, &self.ws.points, &self.lambda, 1.0, &mut residual);
            self.residual = residual;
            if !all_finite(&self.residual) {
                return Err(AttemptFailure::Diverged);
            }
            let r_norm = self.residual.amax();
            let phi_norm = if nc > 0 { self.ws.constraint.amax() } else { 0.0 };
            let scale = force_scale(model, &self.ws, inertial);
            let length_scale = self.ws.cables.iter().map(|c| c.length).fold(1e-3, f64::max);
            stats = AttemptStats {
                iterations: iter,
                residual: r_norm,
                factorizations,
                evaluations: iter + 1,
                error: None,
                error_ratio: None,
            };
            if r_norm <= (newton.tolerance * scale).max(force_floor(model, &self.ws))
                && phi_norm <= JOINT_TOLERANCE * length_scale
            {
                break;
            }
            if iter == newton.max_iterations {
                self.factored_for = None;
                return Err(AttemptFailure::Diverged);
            }
            let contraction = r_norm.max(phi_norm * scale / length_scale);
            if reuse && (contraction > REFACTOR_CONTRACTION * previous || stale >= MAX_STALE_ITERATIONS) {
                reuse = false;
                exact |= fresh && self.kkt.factor_kind() == FactorKind::SymmetricLdlt;
            }
            previous = contraction;
            // [M + (gamma' C + K + H_lambda)/beta', Phi_q^T; Phi_q, 0] [d delta; d lambda / beta'] = [-r / beta'; -Phi]
            self.rhs.fill(0.0);
            self.rhs.rows_mut(0, n).axpy(-1.0 / beta_p, &self.residual, 0.0);
            self.rhs.rows_mut(n, nc).axpy(-1.0, &self.ws.constraint, 0.0);
            if reuse && self.kkt.solve_factored(&mut self.rhs) {
                stale += 1;
                fresh = false;
            } else {
                self.assemble_newton_matrix(model, beta_p, gamma_p);
                factorizations += 1;
                self.factored_for = None;
                let factored = if exact { self.kkt.factor() } else { self.kkt.factor_symmetric() };
                if !factored {
                    return Err(AttemptFailure::Diverged);
                }
                fresh = true;
                self.factored_for = Some(coefficients);
                if reuse {
                    // the failed solve on the old factors overwrote the right-hand side
                    self.rhs.fill(0.0);
                    self.rhs.rows_mut(0, n).axpy(-1.0 / beta_p, &self.residual, 0.0);
                    self.rhs.rows_mut(n, nc).axpy(-1.0, &self.ws.constraint, 0.0);
                }
                if !self.kkt.solve_factored(&mut self.rhs) {
                    self.factored_for = None;
                    return Err(AttemptFailure::Diverged);
                }
                reuse = newton.reuse_factorization && !contacts;
                stale = 0;
            }
            if contacts {
                // a contact slipping one way must not be sent through stick to slip the other
                let alpha = slip_reversal_limit(model, &self.trial, &self.ws, self.rhs.rows(0, n), gamma_p);
                if alpha < 1.0 {
                    self.rhs *= alpha;
                }
            }
            let dd = self.rhs.rows(0, n);
            self.delta += dd;
            self.v.axpy(gamma_p, &dd, 1.0);
            self.vdot.axpy(beta_p, &dd, 1.0);
            if nc > 0 {
                self.lambda.axpy(beta_p, &self.rhs.rows(n, nc), 1.0);
            }
        }
        // local error estimate (after Zienkiewicz & Xie 1991): the displacement's truncation
        // error (beta - 1/6) h^3 (jerk), with the jerk's envelope (`jerk_envelope`) in place of
        // the jerk, so that an oscillation gets the same step through its cycle. The jerk is the
        // central difference of the accelerations over this and the previous step,
        // `(vdot_(n+1) - vdot_(n-1)) / (h + h_prev)`: a jump of the acceleration (an actuator
        // starting) rings in generalized-alpha's spurious mode, which alternates in sign from
        // step to step and cancels in this difference, where the plain `vdot_(n+1) - vdot_n` would
        // keep the steps small long after. First step after a restart: the one-step difference,
        // no envelope. A rotation's error counts times the body's reach. The largest envelope is
        // held over the next steps (`ENVELOPE_HOLD`).
        let weight = h * h * h * (c.beta - 1.0 / 6.0).abs();
        let length_scale = self.ws.cables.iter().map(|c| c.length).fold(1e-3, f64::max);
        // the joints hold to 1e-12 of the length scale at position level, Newton's residual to
        // `newton.tolerance` of the forces: the accelerations' noise (see below)
        // with joints, under a tolerance within `JOINT_NOISE_MARGIN` of the floor that the joints'
        // misfit puts under the estimate (`2 |beta - 1/6| / beta 1e-12 L`, below), the
        // accelerations are taken along the joints (`project_onto_joint_tangents`): the misfit
        // lies across them, and so does its noise
        let floor = 2.0 * (c.beta - 1.0 / 6.0).abs() / c.beta * JOINT_TOLERANCE * length_scale;
        let tangent = nc > 0
            && tolerance.is_some_and(|tol| floor > JOINT_NOISE_MARGIN * tol)
            && self.project_onto_joint_tangents(model);
        let joint_noise =
            if nc > 0 && !tangent { JOINT_TOLERANCE * length_scale / (c.beta * h * h) } else { 0.0 };
        let mut largest: f64 = 0.0;
        for (b, body) in model.bodies.iter().enumerate() {
            for k in 0..body.dof_count {
                let j = body.dof_offset + k;
                let lever =
                    if body.basis.column(k).fixed_rows::<3>(3).norm() > 0.0 { self.reach[b] } else { 1.0 };
                let (before, now, next) = if tangent {
                    let [b, a, n] = &self.tangent_accelerations;
                    (b[j], a[j], n[j])
                } else {
                    (self.previous_acceleration[j], self.acceleration[j], self.vdot[j])
                };
                let envelope = match self.previous_step {
                    Some(h_prev) => {
                        let noise = joint_noise + newton.tolerance * now.abs().max(next.abs());
                        jerk_envelope(before, now, next, h_prev, h, noise)
                    }
                    None => (next - now).abs() / h,
                };
                largest = largest.max(envelope * lever);
            }
        }
        let held = if largest.is_finite() { self.held_envelope.max(largest) } else { largest };
        // the joints' noise in the accelerations, `joint_noise` at each of two samples, is a
        // floor of 2 |beta - 1/6| / beta 1e-12 L in the jerk term whatever the step: below it the
        // estimate says nothing
        let noise = 2.0 * weight * joint_noise / h;
        let error = (weight * held - noise).max(0.0);
        stats.error = Some(error);
        if let Some(tol) = tolerance {
            // the caller's per-step share of the tolerance (`Simulator::step`), more where the
            // error goes into damped modes and dies out (`damped_mode_relief`)
            let mut relief = 1.0;
            if let Some(h_prev) = self.previous_step {
                self.jerk.copy_from(&self.vdot);
                self.jerk -= &self.previous_acceleration;
                self.jerk /= h + h_prev;
                let rate = jerk_decay_rate(model, &mut self.ws, &self.jerk);
                if rate.is_finite() {
                    self.largest_decay_rate = self.largest_decay_rate.max(rate);
                    relief = damped_mode_relief(rate, self.largest_decay_rate);
                }
            }
            let allowed = tol * relief;
            stats.error_ratio = Some(error / allowed);
            if error > allowed || error.is_nan() {
                // a refused attempt measured the envelope too, over a longer step
                if held.is_finite() {
                    self.held_envelope = held;
                }
                return Err(if error.is_finite() {
                    AttemptFailure::ErrorTooLarge(error / allowed)
                } else {
                    AttemptFailure::Diverged
                });
            }
        }
        // commit (the workspace holds the evaluation of exactly the committed state)
        self.final_evaluation = true;
        self.refresh = stats.iterations >= SLOW_STEP_ITERATIONS && factorizations == 0;
        self.update_pseudo_acceleration(&c);
        state.poses.copy_from_slice(&self.trial.poses);
        state.velocities.copy_from(&self.v);
        state.multipliers.copy_from(&self.lambda);
        state.rest_lengths.copy_from_slice(rest_next);
        state.time = self.trial.time;
        self.previous_acceleration.copy_from(&self.acceleration);
        self.previous_step = Some(h);
        self.held_envelope = if held.is_finite() { ENVELOPE_HOLD * held } else { 0.0 };
        self.acceleration.copy_from(&self.vdot);
        self.pseudo_acceleration.copy_from(&self.a_next);
        Ok(stats)
    }

    /// The error estimate's three accelerations (before the last step, at its end, at this
    /// attempt's end) projected onto the joints' tangent space at the attempt's end, into
    /// `tangent_accelerations`: `P a = a - M^-1 Phi_q^T (Phi_q M^-1 Phi_q^T)^-1 Phi_q a`, the part
    /// of `a` M-orthogonal to the joints' normals, from `[M, Phi_q^T; Phi_q, 0] [x; mu] = [M a; 0]`.
    /// Newton holds the joints to `1e-12 L` at position level, and that misfit divided by
    /// `beta h^2` is noise in the accelerations, lying along `M^-1 Phi_q^T` (a joint correction
    /// is a step across the joints): it is a floor of the estimate that does not shrink with the
    /// step (about `1e-12 L` per step), so that at tight tolerances the step controller, which
    /// allows `tol h` per step, refused most attempts without the error following (prism3 took
    /// 173 times the requested 1e-9 m). Position errors across the joints are corrected by them,
    /// so the estimate loses nothing it needs. Costs one factorization of the mass matrix and
    /// joints (the joints' Schur complement on the dense backend) and three solves per
    /// error-controlled attempt; on the sparse backend it replaces the held Newton factors.
    /// False when the solve fails (the estimate then takes the plain accelerations).
    fn project_onto_joint_tangents(&mut self, model: &Model) -> bool {
        let n = model.dof_count;
        if !self.factor_mass_and_joints(model) {
            return false;
        }
        for which in 0..3 {
            let mut out = std::mem::take(&mut self.tangent_accelerations[which]);
            let source = match which {
                0 => &self.previous_acceleration,
                1 => &self.acceleration,
                _ => &self.vdot,
            };
            self.mass_times(model, source, &mut out);
            self.explicit.work.fill(0.0);
            self.explicit.work.rows_mut(0, n).copy_from(&out);
            let solved = self.solve_factored_mass_and_joints(model);
            out.copy_from(&self.explicit.work.rows(0, n));
            self.tangent_accelerations[which] = out;
            if !solved {
                return false;
            }
        }
        true
    }

    /// Assembles the generalized-alpha Newton matrix at the trial state.
    fn assemble_newton_matrix(&mut self, model: &Model, beta_p: f64, gamma_p: f64) {
        assemble_newton_matrix(model, &self.trial, &mut self.ws, &self.mass, &mut self.kkt, beta_p, gamma_p);
    }

    /// `a_next = (alpha_f vdot_n - alpha_m a_n + (1 - alpha_f) vdot) / (1 - alpha_m)`, in place.
    fn update_pseudo_acceleration(&mut self, c: &AlphaCoefficients) {
        self.a_next.copy_from(&self.acceleration);
        self.a_next.axpy(-c.alpha_m, &self.pseudo_acceleration, c.alpha_f);
        self.a_next.axpy(1.0 - c.alpha_f, &self.vdot, 1.0);
        self.a_next /= 1.0 - c.alpha_m;
    }
}

/// How closely Newton holds the joints at position level, `|Phi|_inf`, relative to the length
/// scale (the longest cable).
pub const JOINT_TOLERANCE: f64 = 1e-12;

/// Generalized-alpha takes its error estimate's accelerations along the joints
/// (`Dynamics::project_onto_joint_tangents`) when the floor the joints' misfit puts under the
/// estimate exceeds this fraction of the step's share of the tolerance: on prism3 that is from
/// about 1e-7 m down; looser tolerances keep the plain estimate and its cost.
pub const JOINT_NOISE_MARGIN: f64 = 0.1;

/// Assembles the generalized-alpha Newton matrix
/// `[M + (gamma' C + K + H_lambda)/beta', Phi_q^T; Phi_q, 0]` into `kkt` at `state` (its
/// velocities and multipliers are the iterate's), with `ws` evaluated there by
/// `evaluate::evaluate_forces`. `beta'` (1/s^2) and `gamma'` (1/s) as in the module docs.
pub fn assemble_newton_matrix(
    model: &Model,
    state: &State,
    ws: &mut Workspace,
    mass: &[Matrix6<f64>],
    kkt: &mut KktSystem,
    beta_p: f64,
    gamma_p: f64,
) {
    assemble_mass_and_joints(model, ws, mass, kkt);
    let mut sink = kkt.tangents(1.0 / beta_p, gamma_p / beta_p);
    add_workspace_tangents(model, state, ws, &mut sink);
    add_gyroscopic_damping(model, &state.velocities, &mut sink);
    if model.constraint_count > 0 {
        add_multiplier_hessian_to(model, &state.poses, &state.multipliers, 1.0, &mut sink);
    }
}
