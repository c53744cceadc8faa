//! The step: takes a `Simulator` and advances it by its output interval in sub-steps (fixed, or
//! of the size the integrator's error estimate proposes), each judged by the armed guards
//! (`crate::sim::guards`: accepted, retried smaller from its start, or failed), with the works
//! of each accepted sub-step booked in the energy account.

use std::time::Instant;

use crate::control::Control;
use crate::evaluate::{evaluate_forces, Workspace};
use crate::model::Model;
use crate::sim::guards::{SubStepOutcome, Verdict};
use crate::sim::settings::{StepError, StepStats};
use crate::sim::simulator::Simulator;
use crate::sim::step_size::{quantized, smallest_controlled_step, EXPLICIT_ERROR_STEP, GROWTH_THRESHOLD};
use crate::solve::dynamics::{cable_powers, AttemptFailure, Dynamics};
use crate::state::State;

impl Simulator {
    /// Advances by `settings.dt`. Fixed steps: an attempt that fails is retried in halves (then
    /// grown back). With a tolerance: sub-steps of the size the local error estimate proposes,
    /// `h_new = h min(5, max(0.2, 0.9 ratio^(-e)))` with `ratio` the error over what the
    /// tolerance allows (`AttemptStats::error_ratio`) and `e = Integrator::error_exponent`; a
    /// sub-step whose ratio exceeds 1 is rejected and retried smaller, the last one clipped to end
    /// exactly at `t + dt`.
    pub fn step(&mut self) -> Result<StepStats, StepError> {
        if let Some(guard) = &mut self.guards.divergence {
            guard.before.copy_from(&self.state);
            guard.energy = self.energy;
        }
        let start = Instant::now();
        self.control.tick();
        let mut stats = StepStats::default();
        let dt = self.settings.dt;
        let target = self.state.time + dt;
        let tolerance = self.settings.tolerance;
        let exponent = self.settings.integrator.error_exponent();
        let implicit = !self.settings.integrator.is_explicit();
        let mut h = if tolerance.is_some() { self.next_h.min(dt) } else { dt };
        let smallest = smallest_controlled_step(dt, tolerance);
        while self.state.time < target - 1e-12 * dt {
            let remaining = target - self.state.time;
            // a sub-step that would leave a sliver shares the rest with the next one instead
            // (a fixed step is the whole interval, whatever the rounding of `target - time`)
            let h_try = if h >= remaining * (1.0 - 1e-9) {
                remaining
            } else if h > 0.8 * remaining {
                0.5 * remaining
            } else {
                h
            };
            self.guards.remember(&self.state, &self.ws, &self.energy);
            if !self.model.winches.is_empty() {
                self.prepare_winches(h_try);
            }
            self.rest_now.copy_from_slice(&self.state.rest_lengths);
            self.control.advance(&self.model, self.state.time, h_try, &self.rest_now, &mut self.rest_next);
            Control::rates(&self.model, &self.rest_now, &self.rest_next, h_try, &mut self.rest_rate);
            // power at the start of the sub-step (the workspace holds the current state)
            let (p_act0, p_loss0) = cable_powers(&self.model, &self.ws, &self.rest_rate);
            // at the smallest error-controlled sub-step the tolerance is not enforced: a jump of
            // the acceleration (a cable going slack) would otherwise shrink the step without end
            let forced = tolerance.is_some() && h_try <= smallest;
            // generalized-alpha gets the same share of the tolerance every step, scaled by the
            // running mean step (`dynamics::TOLERANCE_TIME`; the step raises it where its error
            // goes into damped modes, `dynamics::damped_mode_relief`); Dormand-Prince takes it
            // per step, scaled down when its steps are shorter than `EXPLICIT_ERROR_STEP`
            let step_tolerance = match (tolerance, implicit) {
                (Some(tol), true) => {
                    Some(tol * (self.mean_h / crate::solve::dynamics::TOLERANCE_TIME).min(1.0))
                }
                (Some(tol), false) => Some(tol * (self.mean_h / EXPLICIT_ERROR_STEP).min(1.0)),
                (None, _) => None,
            };
            let attempt = self.dynamics.step(
                &self.model,
                self.settings.integrator,
                &self.settings.newton,
                &mut self.state,
                &self.rest_now,
                &self.rest_next,
                h_try,
                if forced { None } else { step_tolerance },
            );
            match attempt {
                Ok(a) => {
                    debug_assert!(self.state.is_finite());
                    stats.forced += usize::from(forced);
                    // running mean of the accepted sub-steps (a clipped last one says little)
                    if h_try >= 0.5 * h {
                        self.mean_h += 0.1 * (h_try - self.mean_h);
                    }
                    if forced && implicit {
                        // restart from consistent accelerations: the jump would otherwise ring in
                        // generalized-alpha's spurious acceleration mode, decaying by rho_inf a
                        // step, and keep the error estimate above the tolerance
                        if !self.dynamics.initialize(&self.model, &mut self.state) {
                            return Err(StepError::Initialization);
                        }
                    }
                    if !self.dynamics.take_final_evaluation(&mut self.ws) {
                        evaluate_forces(&self.model, &self.state, &mut self.ws);
                    }
                    let (p_act1, p_loss1) = cable_powers(&self.model, &self.ws, &self.rest_rate);
                    self.energy.actuator_work += 0.5 * h_try * (p_act0 + p_act1);
                    self.energy.damping_loss += 0.5 * h_try * (p_loss0 + p_loss1);
                    if let Some((before, energy_before)) = &self.guards.start {
                        let outcome = SubStepOutcome {
                            model: &self.model,
                            ws: &self.ws,
                            energy: &self.energy,
                            time: before.time,
                            h: h_try,
                            forced,
                            smallest,
                            settings: &self.settings,
                        };
                        let verdict = self.guards.judge(&outcome);
                        if verdict != Verdict::Accept {
                            // undo the sub-step (its works too) and restart from consistent
                            // accelerations at the restored state
                            self.energy = *energy_before;
                            undo_sub_step(
                                &self.model,
                                &mut self.dynamics,
                                &mut self.state,
                                &mut self.ws,
                                before,
                            )?;
                            stats.rejected += 1;
                            stats.newton_iterations += a.iterations;
                            match verdict {
                                Verdict::Retry { h: retry, pass_through } => {
                                    stats.pass_throughs += usize::from(pass_through);
                                    h = retry;
                                    continue;
                                }
                                Verdict::Fail(error) => return Err(error),
                                Verdict::Accept => unreachable!("accepted sub-steps are kept"),
                            }
                        }
                    }
                    if !self.model.pulley_friction.is_empty() {
                        self.commit_pulley_friction(h_try);
                    }
                    if !self.model.winches.is_empty() {
                        self.commit_winches(h_try);
                    }
                    if !self.state.contact_anchors.is_empty() {
                        self.commit_contact_anchors();
                    }
                    stats.newton_iterations += a.iterations;
                    stats.factorizations += a.factorizations;
                    stats.evaluations += a.evaluations;
                    stats.residual = stats.residual.max(a.residual);
                    stats.error = stats.error.max(a.error.unwrap_or(0.0));
                    stats.substeps += 1;
                    h = match a.error_ratio {
                        Some(ratio) => {
                            let factor = if ratio > 0.0 { 0.9 * ratio.powf(-exponent) } else { 5.0 };
                            let proposal = h_try * factor.clamp(0.2, 5.0);
                            if implicit {
                                // whole fractions of the interval, and no change for less than
                                // GROWTH_THRESHOLD x
                                // growth: every new step size costs the implicit integrator a
                                // factorization
                                if proposal >= GROWTH_THRESHOLD * h {
                                    quantized(dt, proposal)
                                } else {
                                    h
                                }
                            } else if h_try < h {
                                // a clipped sub-step says little about the step size
                                proposal.max(h).min(self.step_cap)
                            } else {
                                proposal.min(self.step_cap)
                            }
                        }
                        // after a cut, try to grow back
                        _ => (2.0 * h_try).min(dt).min(self.step_cap),
                    };
                }
                Err(failure) => {
                    stats.rejected += 1;
                    h = match failure {
                        AttemptFailure::ErrorTooLarge(ratio) => {
                            h_try * (0.9 * ratio.powf(-exponent)).clamp(0.1, 0.9)
                        }
                        AttemptFailure::Diverged => 0.5 * h_try,
                    };
                    if implicit && tolerance.is_some() {
                        h = quantized(dt, h);
                    }
                    if tolerance.is_some() {
                        h = h.max(smallest);
                    }
                    if h < self.settings.min_dt
                        && !(tolerance.is_some() && matches!(failure, AttemptFailure::ErrorTooLarge(_)))
                    {
                        return Err(StepError::StepTooSmall {
                            time: self.state.time,
                            dt: h_try,
                            min_dt: self.settings.min_dt,
                            residual: f64::NAN,
                        });
                    }
                }
            }
        }
        if tolerance.is_some() {
            self.next_h = h;
        }
        let e = self.ws.energies;
        self.energy.kinetic = e.kinetic;
        self.energy.elastic = e.elastic;
        self.energy.gravitational = e.gravitational;
        if let Some(guard) = &self.guards.divergence {
            if let Verdict::Fail(error) = guard.judge(&self.energy, &self.settings) {
                self.state.copy_from(&guard.before);
                self.energy = guard.energy;
                evaluate_forces(&self.model, &self.state, &mut self.ws);
                return Err(error);
            }
        }
        stats.wall_time = start.elapsed();
        Ok(stats)
    }
}

/// Undoes a sub-step: `state` back to `before`, `ws` evaluated there (`evaluate_forces`), and the
/// integrator restarted from consistent accelerations (its history is the undone sub-step's).
fn undo_sub_step(
    model: &Model,
    dynamics: &mut Dynamics,
    state: &mut State,
    ws: &mut Workspace,
    before: &State,
) -> Result<(), StepError> {
    state.copy_from(before);
    evaluate_forces(model, state, ws);
    if dynamics.initialize(model, state) {
        Ok(())
    } else {
        Err(StepError::Initialization)
    }
}
