//! Semi-implicit (symplectic) Euler: one explicit step of `Dynamics`, its velocity solve through
//! the joints' Schur complement on the dense backend (`joint_schur::JointSchur`).
//!
//! **Semi-implicit (symplectic) Euler**: `v_(n+1) = v_n + h M^-1 (Q(q_n, v_n, t_n) - gyro - Phi_q^T lambda)`
//! with the constraints imposed on the new velocity (`Phi_q v_(n+1) = -Phi(q_n) / h`, which also
//! removes position drift), then `q_(n+1) = q_n exp(h v_(n+1))`. First order, cheap, explicit in
//! the forces; stable only for `h < 2 / omega_max` (`omega_max` the highest natural frequency of
//! the linearized system, see `stability_limit`); stiff or damped cables shrink that limit. Its
//! linear system is solved through the joints' Schur complement on the dense backend
//! (`JointSchur`) and by the exact sparse `LDL^T` on the sparse one.

use crate::evaluate::evaluate_forces;
use crate::model::Model;
use crate::state::{retract, State};

use crate::solve::dynamics::system::{add_gyroscopic, AttemptStats, Dynamics};

impl Dynamics {
    pub(super) fn symplectic_euler(
        &mut self,
        model: &Model,
        state: &mut State,
        rest_now: &[f64],
        rest_next: &[f64],
        h: f64,
    ) -> Option<AttemptStats> {
        let n = model.dof_count;
        let nc = model.constraint_count;
        self.trial.time = state.time;
        self.trial.poses.copy_from_slice(&state.poses);
        self.trial.velocities.copy_from(&state.velocities);
        self.trial.multipliers.copy_from(&state.multipliers);
        self.trial.rest_lengths.copy_from_slice(rest_now);
        self.trial.segment_rest_lengths.copy_from_slice(&state.segment_rest_lengths);
        self.trial.winches.copy_from_slice(&state.winches);
        self.trial.contact_anchors.copy_from_slice(&state.contact_anchors);
        // the force at the start sees a winch's cable at its rest length now: its motor moves it
        // over the step, against the tension at the end (`crate::forces::winch`)
        for w in &mut self.trial.winches {
            w.step = 0.0;
        }
        evaluate_forces(model, &self.trial, &mut self.ws);
        // f = Q - gyro (in `residual`), M v_n (in `vdot`)
        self.v.fill(0.0);
        add_gyroscopic(model, &state.velocities, &mut self.v);
        self.residual.copy_from(&self.ws.force);
        self.residual -= &self.v;
        let mut mv = std::mem::take(&mut self.vdot);
        self.mass_times(model, &state.velocities, &mut mv);
        self.vdot = mv;
        // [M Phi_q^T; Phi_q 0] [v+; h lambda] = [M v + h f; -Phi / h]
        self.rhs.fill(0.0);
        self.rhs.rows_mut(0, n).copy_from(&self.vdot);
        self.rhs.rows_mut(0, n).axpy(h, &self.residual, 1.0);
        self.rhs.rows_mut(n, nc).axpy(-1.0 / h, &self.ws.constraint, 0.0);
        if self.uses_joint_schur(model) {
            // small scenes: the joints' Schur complement (nc x nc) instead of the whole matrix
            if !self.schur.solve(model, &self.ws, &mut self.rhs) {
                return None;
            }
        } else {
            self.assemble_mass_and_joints(model);
            self.factored_for = None;
            // the matrix is symmetric: its LDL^T (where the backend has one) is exact
            if !(self.kkt.factor_symmetric() && self.kkt.solve_factored(&mut self.rhs)) {
                return None;
            }
        }
        self.v.copy_from(&self.rhs.rows(0, n));
        retract(model, &mut self.trial.poses, &self.v, h);
        if self.trial.poses.iter().any(|p| !p.position.iter().all(|x| x.is_finite())) {
            return None;
        }
        // commit
        self.vdot.copy_from(&self.v);
        self.vdot.axpy(-1.0 / h, &state.velocities, 1.0 / h);
        state.poses.copy_from_slice(&self.trial.poses);
        state.velocities.copy_from(&self.v);
        for r in 0..nc {
            state.multipliers[r] = self.rhs[n + r] / h;
        }
        state.rest_lengths.copy_from_slice(rest_next);
        state.time += h;
        self.acceleration.copy_from(&self.vdot);
        self.pseudo_acceleration.copy_from(&self.vdot);
        Some(AttemptStats {
            iterations: 0,
            residual: 0.0,
            factorizations: 1,
            evaluations: 1,
            error: None,
            error_ratio: None,
        })
    }
}
