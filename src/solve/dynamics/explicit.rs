//! Explicit Runge-Kutta integrators for non-stiff scenes: takes a model, a state and a step; gives
//! the state one step later by the classical 4th-order Runge-Kutta method or the Dormand-Prince
//! 5(4) embedded pair (with its local error estimate), or refuses the step.
//!
//! # Equations
//! The state is `(x_b, R_b, v)`: body positions, body rotations and the local velocities of
//! `crate::model`. Per body `(dx, w) = B v_b` (world translation rate, body-frame angular
//! velocity); then `xdot_b = dx`, and the rotation is integrated as a quaternion,
//! `qdot = q (0, w) / 2`, in the embedding space R^4: Runge-Kutta on the embedded ODE keeps its
//! order, and normalizing the quaternion after the step is a projection that changes the result
//! at the order of the local error only. Accelerations solve
//!
//! ```text
//! [ M      Phi_q^T ] [ vdot   ]   [ Q(q, v, t) - w x J w ]
//! [ Phi_q  0       ] [ lambda ] = [ -Jdot v              ]
//! ```
//!
//! (the joints at acceleration level; `Jdot v = R (w x (w x p))`, the centripetal acceleration of
//! a joint point `p`), through the joints' Schur complement on the dense backend and the sparse
//! `LDL^T` on the sparse one. The constraint drift this leaves at `O(h^(p+1))` per step is removed
//! after every step: positions are moved back onto `Phi = 0` by the mass-weighted smallest
//! correction (Gauss-Newton, `|Phi| <= 1e-12` of the length scale), velocities onto
//! `Phi_q v = 0` (`[M, Phi_q^T; Phi_q, 0] [v'; mu] = [M v; 0]`). Rest lengths move linearly
//! within a step, as the actuators move them.
//!
//! # Methods and stability
//! `RK4`: 4 stages, order 4. Dormand-Prince 5(4) (Dormand & Prince 1980): 7 stages, the 5th-order
//! solution propagated, `y5 - y4` the local error estimate; first-same-as-last reuses the last
//! stage when no projection moved the state (scenes without joints). Both are explicit, so they
//! are stable only for `h |lambda| <= r` over the linearized eigenvalues `lambda`: `r` is the
//! radius of the left half-disk inside the method's stability region, 2.615 for RK4 and 0.997 for
//! Dormand-Prince (whose region leaves the imaginary axis early: an undamped mode with
//! `h omega = 2` grows 3 % per step), and `|lambda| <= max(omega_max, c_max)`
//! (`crate::solve::dynamics::spectral_bounds`).

use nalgebra::{DVector, Quaternion, Vector3, Vector4};

use crate::evaluate::evaluate_forces;
use crate::model::Model;
use crate::solve::dynamics::system::{add_gyroscopic, assemble_mass_and_joints, Dynamics};
use crate::solve::dynamics::tableaus::{ExplicitBuffers, ExplicitStep};
use crate::state::State;

pub use crate::solve::dynamics::tableaus::{
    local_tolerance, Tableau, DOPRI5, DOPRI5_STABILITY_RADIUS, LOCAL_TOLERANCE_SHARE, RK4,
    RK4_STABILITY_RADIUS, TIGHT_EXPONENT, TIGHT_TOLERANCE,
};

impl Dynamics {
    /// `out = (xdot, qdot, vdot)` at `state` (poses, velocities, rest lengths, time): evaluates the
    /// forces into `self.ws` and solves the acceleration system of the module docs.
    fn explicit_rates(&mut self, model: &Model, state: &State, out_index: usize) -> bool {
        let n = model.dof_count;
        let nc = model.constraint_count;
        evaluate_forces(model, state, &mut self.ws);
        // [Q - gyro; -Jdot v]
        self.residual.fill(0.0);
        add_gyroscopic(model, &state.velocities, &mut self.residual);
        let work = &mut self.explicit.work;
        work.fill(0.0);
        for i in 0..n {
            work[i] = self.ws.force[i] - self.residual[i];
        }
        if nc > 0 {
            for joint in &model.joints {
                if joint.alignment.is_some() || joint.plane_normal.is_some() {
                    continue; // alignment_biases
                }
                let mut bias = Vector3::zeros();
                for (p, sign) in crate::constraints::joint_points(joint) {
                    bias += crate::kinematics::centripetal(model, &state.poses, &state.velocities, p) * sign;
                }
                let bias = joint.project(&bias);
                for r in 0..joint.rows {
                    work[n + joint.row_offset + r] = -bias[r];
                }
            }
            if !self.ws.poses.is_empty() {
                alignment_biases(model, state, n, work);
            }
        }
        if !self.solve_mass_and_joints(model) {
            return false;
        }
        let k = &mut self.explicit.k[out_index];
        for (b, body) in model.bodies.iter().enumerate() {
            let local = body.local_increment(state.velocities.as_slice(), 1.0);
            k.positions[b] = Vector3::new(local[0], local[1], local[2]);
            let w = Quaternion::new(0.0, local[3], local[4], local[5]);
            k.rotations[b] = (state.poses[b].rotation.quaternion() * w).coords * 0.5;
        }
        k.velocities.copy_from(&self.explicit.work.rows(0, n));
        k.velocities.iter().all(|x| x.is_finite())
    }

    /// Solves `[M, Phi_q^T; Phi_q, 0] x = work` in place of `self.explicit.work` at the point
    /// kinematics in `self.ws`.
    fn solve_mass_and_joints(&mut self, model: &Model) -> bool {
        self.factor_mass_and_joints(model) && self.solve_factored_mass_and_joints(model)
    }

    /// Factors `[M, Phi_q^T; Phi_q, 0]` at the point kinematics in `self.ws` for
    /// `solve_factored_mass_and_joints` (the sparse backend's factors replace the Newton
    /// matrix's: the next implicit step refactors).
    pub(super) fn factor_mass_and_joints(&mut self, model: &Model) -> bool {
        if self.uses_joint_schur(model) {
            return self.schur.factor(model, &self.ws);
        }
        assemble_mass_and_joints(model, &self.ws, &self.mass, &mut self.kkt);
        self.factored_for = None;
        self.kkt.factor_symmetric()
    }

    /// Solves `[M, Phi_q^T; Phi_q, 0] x = work` in place of `self.explicit.work` with the
    /// factors of the last `factor_mass_and_joints`.
    pub(super) fn solve_factored_mass_and_joints(&mut self, model: &Model) -> bool {
        if self.uses_joint_schur(model) {
            return self.schur.solve_factored(model, &mut self.explicit.work);
        }
        let size = self.kkt.size();
        self.rhs.fill(0.0);
        let m = self.explicit.work.len().min(size);
        self.rhs.rows_mut(0, m).copy_from(&self.explicit.work.rows(0, m));
        if !self.kkt.solve_factored(&mut self.rhs) {
            return false;
        }
        self.explicit.work.rows_mut(0, m).copy_from(&self.rhs.rows(0, m));
        true
    }

    /// One explicit Runge-Kutta step of `tableau` from `state` to `state.time + h`, rest lengths
    /// moving linearly from `rest_now` to `rest_next`, constraints projected afterwards. With
    /// `tolerance` (m) and an embedded pair, a step whose local error exceeds it is refused
    /// (`Err(ratio)`, error / tolerance) and the state left unchanged. `Err(f64::INFINITY)` when
    /// a stage is not finite or a solve fails.
    #[allow(clippy::too_many_arguments)]
    pub(super) fn explicit_step(
        &mut self,
        model: &Model,
        tableau: &Tableau,
        state: &mut State,
        rest_now: &[f64],
        rest_next: &[f64],
        h: f64,
        tolerance: Option<f64>,
    ) -> Result<ExplicitStep, f64> {
        let stages = tableau.c.len();
        self.explicit.start.load(state);
        self.trial.copy_from(state);
        let mut evaluations = 0;
        for i in 0..stages {
            if i == 0 && tableau.fsal && self.explicit.fsal_valid {
                // the previous step's last stage was evaluated at exactly this state
                self.explicit.k.swap(0, stages - 1);
                continue;
            }
            let ExplicitBuffers { start, stage, k, .. } = &mut self.explicit;
            stage.combine(start, h, tableau.a[i], k);
            stage.store(&mut self.trial);
            let c = tableau.c[i];
            self.trial.time = state.time + c * h;
            for (r, (a, b)) in self.trial.rest_lengths.iter_mut().zip(rest_now.iter().zip(rest_next)) {
                *r = a + c * (b - a);
            }
            // a winch's motor has run for the stage's share of the step (none at c = 0)
            for w in &mut self.trial.winches {
                w.step = c * h;
            }
            // the stage state leaves `self` while the rates borrow it (no allocation)
            let trial = std::mem::take(&mut self.trial);
            let ok = self.explicit_rates(model, &trial, i);
            self.trial = trial;
            evaluations += 1;
            if !ok {
                self.explicit.fsal_valid = false;
                return Err(f64::INFINITY);
            }
        }
        let error = tableau.error.map(|e| self.embedded_error(model, e, h));
        if let (Some(err), Some(tol)) = (error, tolerance) {
            if err > tol || err.is_nan() {
                self.explicit.fsal_valid = false;
                return Err(if err.is_finite() { err / tol } else { f64::INFINITY });
            }
        }
        // the propagated solution
        let ExplicitBuffers { start, stage, k, .. } = &mut self.explicit;
        stage.combine(start, h, tableau.b, k);
        stage.store(&mut self.trial);
        self.trial.time = state.time + h;
        self.trial.rest_lengths.copy_from_slice(rest_next);
        self.trial.multipliers.copy_from(&state.multipliers);
        self.trial.winches.copy_from_slice(&state.winches);
        if !self.trial.is_finite() {
            self.explicit.fsal_valid = false;
            return Err(f64::INFINITY);
        }
        let Some(moved) = self.project_onto_joints(model) else {
            self.explicit.fsal_valid = false;
            return Err(f64::INFINITY);
        };
        // commit; the acceleration is the last stage's (at the end point for first-same-as-last)
        self.vdot.copy_from(&self.explicit.k[stages - 1].velocities);
        self.acceleration.copy_from(&self.vdot);
        self.pseudo_acceleration.copy_from(&self.vdot);
        state.copy_from(&self.trial);
        // a winch's rest length moves when the step is committed: its last stage is stale
        self.explicit.fsal_valid = tableau.fsal && !moved && model.winches.is_empty();
        Ok(ExplicitStep { error, evaluations })
    }

    /// The local error estimate `h sum_i e_i k_i` of an embedded pair, m: translations as they
    /// are, rotations (quaternion differences, twice their size in radians) times the body's
    /// reach, velocities times the step.
    fn embedded_error(&self, model: &Model, e: &[f64], h: f64) -> f64 {
        let k = &self.explicit.k;
        let mut err: f64 = 0.0;
        for (b, body) in model.bodies.iter().enumerate() {
            if body.dof_count == 0 {
                continue;
            }
            let mut dx = Vector3::zeros();
            let mut dq = Vector4::zeros();
            for (i, &w) in e.iter().enumerate() {
                dx += k[i].positions[b] * (h * w);
                dq += k[i].rotations[b] * (h * w);
            }
            err = err.max(dx.norm()).max(2.0 * dq.norm() * self.reach[b]);
            for c in 0..body.dof_count {
                let j = body.dof_offset + c;
                let dv: f64 = e.iter().enumerate().map(|(i, &w)| k[i].velocities[j] * (h * w)).sum();
                let lever =
                    if body.basis.column(c).fixed_rows::<3>(3).norm() > 0.0 { self.reach[b] } else { 1.0 };
                err = err.max(dv.abs() * h * lever);
            }
        }
        err
    }

    /// Moves `self.trial` back onto the joints: positions by mass-weighted Gauss-Newton
    /// corrections until `|Phi| <= 1e-12` of the length scale (at most 5), velocities onto
    /// `Phi_q v = 0`. Returns whether anything moved; `None` when a solve failed.
    fn project_onto_joints(&mut self, model: &Model) -> Option<bool> {
        let n = model.dof_count;
        let nc = model.constraint_count;
        if nc == 0 {
            return Some(false);
        }
        let length_scale = self.reach.iter().copied().fold(1e-3, f64::max);
        let mut dq = std::mem::take(&mut self.delta);
        for _ in 0..5 {
            evaluate_forces(model, &self.trial, &mut self.ws);
            if self.ws.constraint.amax() <= 1e-12 * length_scale {
                break;
            }
            self.explicit.work.fill(0.0);
            for r in 0..nc {
                self.explicit.work[n + r] = -self.ws.constraint[r];
            }
            if !self.solve_mass_and_joints(model) {
                self.delta = dq;
                return None;
            }
            dq.copy_from(&self.explicit.work.rows(0, n));
            crate::state::retract(model, &mut self.trial.poses, &dq, 1.0);
        }
        self.delta = dq;
        // velocities: [M, Phi_q^T; Phi_q, 0] [v'; mu] = [M v; 0]
        let mut mv = std::mem::take(&mut self.v);
        self.mass_times(model, &self.trial.velocities, &mut mv);
        self.explicit.work.fill(0.0);
        self.explicit.work.rows_mut(0, n).copy_from(&mv);
        self.v = mv;
        if !self.solve_mass_and_joints(model) {
            return None;
        }
        self.trial.velocities.copy_from(&self.explicit.work.rows(0, n));
        Some(true)
    }
}

/// Writes `-d/dt(Phi_q) v` of every hinge's and planar joint's axis rows into `work` (rows from
/// `n`): apart from the point joints' loop, which it would otherwise weigh down.
#[cold]
#[inline(never)]
fn alignment_biases(model: &Model, state: &State, n: usize, work: &mut DVector<f64>) {
    for joint in &model.joints {
        if let Some(u) = &joint.plane_normal {
            work[n + joint.row_offset] =
                -crate::constraints::plane_bias(model, &state.poses, &state.velocities, joint, u);
            continue;
        }
        if let Some(al) = &joint.alignment {
            let bias = crate::constraints::alignment_bias(model, &state.poses, &state.velocities, joint, al);
            for r in 0..joint.rows {
                work[n + joint.row_offset + r] = -bias[r];
            }
        }
    }
}
