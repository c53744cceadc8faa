//! The checks that judge a sub-step after it was taken: takes the workspace before and after it
//! (contact gaps, strut sides) and the energy account, gives a `Verdict` per sub-step (accept,
//! retry with a smaller sub-step, or fail) from one ordered list of guards (`SubStepGuard`), and
//! per step from the explicit integrators' divergence guard (`DivergenceGuard`). A scene arms
//! only the guards its model and settings need (`Guards::arm`); with none armed a sub-step pays
//! nothing for them.
//!
//! Adding an event: a variant of `SubStepGuard` with what it remembers from the sub-step's start
//! (`SubStepGuard::remember`), its check (`SubStepGuard::judge`), and its arming condition in
//! `Guards::arm`; the sub-step loop (`crate::sim::substep`) undoes and retries for it.

use crate::evaluate::Workspace;
use crate::model::Model;
use crate::sim::energy::EnergyAccount;
use crate::sim::settings::{SimSettings, StepError};
use crate::state::State;

/// Under error control, a sub-step that ends more than this many times the tolerance past a
/// contact's touchdown (pressed in) or lift-off (above the ground) is retried to end half as far
/// past it: the force's kink there is seen by the error estimate only after the fact (an
/// error-controlled drop of a ball bouncing on a ground took Dormand-Prince 69 mm off its
/// reference at a tolerance of 1 mm). At 1.0 generalized-alpha's error on that drop was 4.3
/// times the tolerance at 1e-4 m; at 0.25, 0.81 times, for 0.2-0.6 % more Newton iterations on
/// the six-bar robot's roll under error control (`tensegrity deploy config/scenes/sixbar.toml
/// --dynamic --dt 0.01 --tol 1e-3`, 1e-4 and 1e-5; the drop: `tests/contact.rs`).
pub const CONTACT_EVENT_DEPTH: f64 = 0.25;

/// A generalized-alpha sub-step at a fixed step is undone and retried in halves when the energy
/// the run holds exceeds its start and the actuators' work by this many times its energy scale
/// (`Guards::arm`): the method dissipates, so a run that gains that much is being pumped by
/// cables snapping taut and slack within a step, not moving.
pub const IMPLICIT_GAIN_FACTOR: f64 = 1.0;

/// An explicit run stops (`StepError::Diverged`) when the energy it made up exceeds this many
/// times its energy scale (`Guards::arm`, plus the actuator work and damping loss so far): a
/// stable run's energy error stays a fraction of the energy it holds, an unstable one grows
/// without bound (8.8e105 J on the atwood scene at 0.1 s before the limit counted the rope's
/// taut stiffness).
pub const DIVERGENCE_FACTOR: f64 = 10.0;

/// What a guard answers about a sub-step (or, for `DivergenceGuard`, a step) just taken.
#[derive(Debug, Clone, PartialEq)]
pub(crate) enum Verdict {
    /// Keep it.
    Accept,
    /// Undo it and try again from its start with a sub-step of `h` (s).
    Retry {
        /// The next sub-step to try, s.
        h: f64,
        /// Whether a bar passed through another (counted in `StepStats::pass_throughs`).
        pass_through: bool,
    },
    /// Undo it and stop: the step cannot be taken.
    Fail(StepError),
}

/// One check of the sub-step loop, with what it remembers from the start of the sub-step under
/// way. The list is checked in order; the first answer other than `Accept` is the verdict.
#[derive(Debug, Clone)]
pub(crate) enum SubStepGuard {
    /// With strut pairs (`[collisions]`): every pair's side (`ClosestPoints::side` in
    /// `Workspace::strut_closest`) at the start; a sub-step that carries one bar through another
    /// (the penalty force never saw it, or could not stop it) is retried in halves.
    PassThrough {
        /// Per strut pair, the side one axis passes the other on at the start.
        sides: Vec<f64>,
    },
    /// With a tolerance and contacts: every contact pair's gap at the start; a sub-step that
    /// steps more than `CONTACT_EVENT_DEPTH` times the tolerance past a touchdown or a lift-off
    /// is retried to end half that far past it (the gap taken linear over the sub-step).
    ContactEvent {
        /// Per contact pair, the gap at the start, m.
        gaps: Vec<f64>,
        /// The run's tolerance, m.
        tolerance: f64,
    },
    /// Generalized-alpha at a fixed step: a sub-step after which the run holds more than
    /// `IMPLICIT_GAIN_FACTOR` times `scale` beyond its start and all the actuators' work is
    /// retried in halves (a tension-only cable snapping taut and slack faster than the step can
    /// pump energy into the run, where the linear analysis promises stability).
    EnergyGain {
        /// The run's energy scale, J (`Guards::arm`).
        scale: f64,
    },
}

/// What a guard needs to judge the sub-step just taken.
pub(crate) struct SubStepOutcome<'a> {
    /// The model.
    pub model: &'a Model,
    /// The workspace evaluated at the sub-step's end.
    pub ws: &'a Workspace,
    /// The energy account with the sub-step's works booked and the workspace's energies.
    pub energy: &'a EnergyAccount,
    /// Time at the sub-step's start, s.
    pub time: f64,
    /// The sub-step taken, s.
    pub h: f64,
    /// Whether it was accepted at the smallest error-controlled sub-step whatever its error.
    pub forced: bool,
    /// The smallest error-controlled sub-step, s (`smallest_controlled_step`).
    pub smallest: f64,
    /// The run's settings.
    pub settings: &'a SimSettings,
}

impl SubStepGuard {
    /// Remembers what the check needs from the start of the sub-step under way (`ws` evaluated
    /// there).
    fn remember(&mut self, ws: &Workspace) {
        match self {
            SubStepGuard::PassThrough { sides } => {
                for (side, closest) in sides.iter_mut().zip(&ws.strut_closest) {
                    *side = closest.side;
                }
            }
            SubStepGuard::ContactEvent { gaps, .. } => {
                for (g, c) in gaps.iter_mut().zip(&ws.contacts) {
                    *g = c.gap;
                }
            }
            SubStepGuard::EnergyGain { .. } => {}
        }
    }

    /// The verdict on the sub-step `outcome` describes.
    fn judge(&self, outcome: &SubStepOutcome) -> Verdict {
        let SubStepOutcome { model, ws, h, smallest, settings, .. } = *outcome;
        match self {
            SubStepGuard::PassThrough { sides } => {
                let Some(i) = sides.iter().zip(&ws.strut_closest).position(|(a, b)| a * b.side < 0.0) else {
                    return Verdict::Accept;
                };
                let retry = 0.5 * h;
                if retry < settings.min_dt.max(smallest) {
                    let pair = &model.strut_pairs[i];
                    return Verdict::Fail(StepError::PassThrough {
                        first: model.bodies[pair.bars[0].0].name.clone(),
                        second: model.bodies[pair.bars[1].0].name.clone(),
                        time: outcome.time,
                        dt: h,
                    });
                }
                Verdict::Retry { h: retry, pass_through: true }
            }
            SubStepGuard::ContactEvent { gaps, tolerance } => {
                if outcome.forced {
                    return Verdict::Accept;
                }
                // a touchdown or lift-off inside the sub-step is a kink of the force that the
                // error estimate sees only after the fact
                let depth = CONTACT_EVENT_DEPTH * tolerance;
                let mut fraction: f64 = 1.0;
                for (g0, c) in gaps.iter().zip(&ws.contacts) {
                    let g1 = c.gap;
                    if *g0 > 0.0 && g1 < -depth {
                        fraction = fraction.min((g0 + 0.5 * depth) / (g0 - g1));
                    } else if *g0 < 0.0 && g1 > depth {
                        fraction = fraction.min((0.5 * depth - g0) / (g1 - g0));
                    }
                }
                let retry = fraction * h;
                if fraction < 1.0 && retry >= smallest {
                    Verdict::Retry { h: retry, pass_through: false }
                } else {
                    Verdict::Accept
                }
            }
            SubStepGuard::EnergyGain { scale } => {
                let e = ws.energies;
                let now = EnergyAccount {
                    kinetic: e.kinetic,
                    elastic: e.elastic,
                    gravitational: e.gravitational,
                    ..*outcome.energy
                };
                // what the run holds beyond its start and all the actuators' work: the dampers'
                // loss is left out, as a diverging run's dampers book a loss as wild as its
                // motion and would hide the gain
                let gain = now.total() - now.initial_total - now.actuator_work.abs();
                let scale = scale + now.actuator_work.abs();
                if !(gain.is_nan() || gain > IMPLICIT_GAIN_FACTOR * scale) {
                    return Verdict::Accept;
                }
                // retried in halves, from consistent accelerations at the restored state
                let retry = 0.5 * h;
                if retry < settings.min_dt {
                    return Verdict::Fail(StepError::Diverged {
                        integrator: settings.integrator.name(),
                        time: outcome.time,
                        gain,
                        scale,
                    });
                }
                Verdict::Retry { h: retry, pass_through: false }
            }
        }
    }
}

/// An explicit integrator at a fixed step: the state and energy account before the step under
/// way, restored when the step diverges (`StepError::Diverged`), and the energy scale that tells
/// it.
#[derive(Debug, Clone)]
pub(crate) struct DivergenceGuard {
    /// The state at the start of the step under way.
    pub before: State,
    /// The energy account at the start of the step under way.
    pub energy: EnergyAccount,
    /// The run's energy scale, J (`Guards::arm`).
    scale: f64,
}

impl DivergenceGuard {
    /// The verdict on the step whose energy account is now `energy` (the workspace's energies
    /// taken in): `Fail` when it made up more than `DIVERGENCE_FACTOR` times the energy scale
    /// (plus the actuator work and damping loss so far), else `Accept`.
    pub fn judge(&self, energy: &EnergyAccount, settings: &SimSettings) -> Verdict {
        let gain = -energy.numerical_loss();
        let scale = self.scale + energy.actuator_work.abs() + energy.damping_loss;
        if gain.is_nan() || gain > DIVERGENCE_FACTOR * scale {
            Verdict::Fail(StepError::Diverged {
                integrator: settings.integrator.name(),
                time: self.before.time,
                gain,
                scale,
            })
        } else {
            Verdict::Accept
        }
    }
}

/// The guards a run arms (`Guards::arm`): the sub-step list, the state at the start of the
/// sub-step under way (one copy serves every guard that may undo it), and the step-level
/// divergence guard.
#[derive(Debug, Clone)]
pub(crate) struct Guards {
    /// In the order they are checked: pass-through, contact event, energy gain.
    pub sub_step: Vec<SubStepGuard>,
    /// The state and energy account at the start of the sub-step under way; `None` when no
    /// sub-step guard is armed.
    pub start: Option<(State, EnergyAccount)>,
    /// An explicit integrator at a fixed step; `None` otherwise.
    pub divergence: Option<DivergenceGuard>,
}

impl Guards {
    /// The guards `model` and `settings` need, at `state` (evaluated into `ws`, with the energy
    /// account `energy`). The energy scale of the divergence guards is the kinetic and elastic
    /// energy at the start plus the potential energy the structure's weight releases over its
    /// own size (`sum_b m_b |g| L`, `L` the largest body size or cable length), J.
    pub fn arm(
        model: &Model,
        settings: &SimSettings,
        state: &State,
        ws: &Workspace,
        energy: &EnergyAccount,
    ) -> Self {
        let mut guards = Guards { sub_step: Vec::new(), start: None, divergence: None };
        if !model.strut_pairs.is_empty() {
            guards.sub_step.push(SubStepGuard::PassThrough { sides: vec![0.0; model.strut_pairs.len()] });
        }
        if let Some(tolerance) = settings.tolerance.filter(|_| model.contact_pairs() > 0) {
            guards
                .sub_step
                .push(SubStepGuard::ContactEvent { gaps: vec![0.0; model.contact_pairs()], tolerance });
        }
        if settings.tolerance.is_none() {
            let size = crate::solve::statics::body_size(model)
                .max(ws.cables.iter().map(|c| c.length).fold(0.0, f64::max));
            let weight: f64 = model.bodies.iter().map(|b| b.mass * model.gravity.norm()).sum();
            let scale = (energy.kinetic + energy.elastic + weight * size).max(1e-9);
            if settings.integrator.is_explicit() {
                guards.divergence = Some(DivergenceGuard { before: state.clone(), energy: *energy, scale });
            } else {
                guards.sub_step.push(SubStepGuard::EnergyGain { scale });
            }
        }
        if !guards.sub_step.is_empty() {
            guards.start = Some((state.clone(), *energy));
        }
        guards
    }

    /// At the start of a sub-step from `state` (evaluated into `ws`, energy account `energy`):
    /// every armed sub-step guard remembers what it checks.
    pub fn remember(&mut self, state: &State, ws: &Workspace, energy: &EnergyAccount) {
        if let Some((before, energy_before)) = &mut self.start {
            before.copy_from(state);
            *energy_before = *energy;
            for guard in &mut self.sub_step {
                guard.remember(ws);
            }
        }
    }

    /// The verdict on the sub-step `outcome` describes: the first guard's answer that is not
    /// `Accept`, in the list's order.
    pub fn judge(&self, outcome: &SubStepOutcome) -> Verdict {
        for guard in &self.sub_step {
            let verdict = guard.judge(outcome);
            if verdict != Verdict::Accept {
                return verdict;
            }
        }
        Verdict::Accept
    }
}
