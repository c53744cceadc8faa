//! The simulator: owns a `Model`, its `State`, the integrator memory and the workspace; takes a
//! step size and an integrator, gives fixed-size steps (`step`) with step statistics and a running
//! energy account. A step whose Newton iteration fails, or that produces a non-finite number, is
//! rejected and retried in halves down to `min_dt`; below that a typed `StepError` comes out and the
//! state is left at the last good step. No NaN or infinity ever enters the state. The explicit
//! integrator is refused at start-up when the step exceeds its stability limit (checked at the
//! initial state; tension changes during a run move the limit, so keep a margin).

use std::time::{Duration, Instant};

use crate::control::{ActuatorCommand, CommandError, Control};
use crate::forces::{evaluate_forces, Workspace};
use crate::model::{ActuatorId, Model};
use crate::solve::dynamics::{cable_powers, stability_limit, Dynamics, Integrator, NewtonSettings};
use crate::solve::linear::LinearBackend;
use crate::state::State;

/// How the simulator steps.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SimSettings {
    /// Physics step, s.
    pub dt: f64,
    /// Integrator.
    pub integrator: Integrator,
    /// Newton settings of the implicit integrator.
    pub newton: NewtonSettings,
    /// Smallest sub-step a rejected step may be cut to, s.
    pub min_dt: f64,
    /// Factorization of the Newton systems.
    pub linear: LinearBackend,
}

impl Default for SimSettings {
    fn default() -> Self {
        Self {
            dt: 1e-3,
            integrator: Integrator::GeneralizedAlpha { rho_inf: 0.8 },
            newton: NewtonSettings::default(),
            min_dt: 1e-9,
            linear: LinearBackend::Auto,
        }
    }
}

/// What one call to `Simulator::step` cost.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct StepStats {
    /// Newton iterations over all accepted sub-steps.
    pub newton_iterations: usize,
    /// Newton-matrix factorizations over all accepted sub-steps (fewer than the iterations when
    /// `NewtonSettings::reuse_factorization` reuses older factors).
    pub factorizations: usize,
    /// Largest final Newton residual of the accepted sub-steps, N.
    pub residual: f64,
    /// Rejected attempts (each followed by a halved retry).
    pub rejected: usize,
    /// Accepted sub-steps (1 when nothing was rejected).
    pub substeps: usize,
    /// Wall-clock time spent in the step.
    pub wall_time: Duration,
}

/// Why a step could not be taken. The state is left at the last accepted step.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum StepError {
    /// Even the smallest allowed sub-step failed.
    #[error(
        "step failed at t = {time} s: sub-step cut to {dt:.3e} s (minimum {min_dt:.3e} s) without convergence; last residual {residual:.3e} N"
    )]
    StepTooSmall {
        /// Time of the last accepted state, s.
        time: f64,
        /// The sub-step that failed, s.
        dt: f64,
        /// The minimum sub-step, s.
        min_dt: f64,
        /// Residual of the last attempt (NaN if it diverged).
        residual: f64,
    },
    /// Consistent initial accelerations could not be computed (singular mass/constraint system).
    #[error("cannot start the dynamics: the mass and constraint matrix is singular or not finite")]
    Initialization,
    /// The step size is not positive and finite.
    #[error("invalid step size {0} s")]
    InvalidStep(f64),
    /// The explicit integrator would be unstable at this step size.
    #[error(
        "symplectic Euler is unstable at dt = {dt:.3e} s: its stability limit here is {limit:.3e} s (2/omega_max); use a smaller step or generalized-alpha"
    )]
    UnstableExplicitStep {
        /// Requested step, s.
        dt: f64,
        /// Stability limit at the initial state, s.
        limit: f64,
    },
}

/// Energies and cumulative works, J. With no numerical dissipation,
/// `total() - initial_total = actuator_work - damping_loss` up to the integrator's error.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct EnergyAccount {
    /// Kinetic energy `v^T M v / 2`.
    pub kinetic: f64,
    /// Elastic energy of taut cables.
    pub elastic: f64,
    /// Gravitational potential.
    pub gravitational: f64,
    /// Work done by the actuators on the cables since the start (trapezoidal in time).
    pub actuator_work: f64,
    /// Energy dissipated by the cable dampers since the start (trapezoidal in time).
    pub damping_loss: f64,
    /// Total energy at the start.
    pub initial_total: f64,
}

impl EnergyAccount {
    /// Kinetic + elastic + gravitational.
    pub fn total(&self) -> f64 {
        self.kinetic + self.elastic + self.gravitational
    }
    /// Energy the balance does not explain: `initial + work - loss - total` (the integrator's
    /// numerical dissipation plus its error).
    pub fn numerical_loss(&self) -> f64 {
        self.initial_total + self.actuator_work - self.damping_loss - self.total()
    }
}

/// Owns a model and advances it in time.
#[derive(Debug, Clone)]
pub struct Simulator {
    model: Model,
    state: State,
    settings: SimSettings,
    dynamics: Dynamics,
    ws: Workspace,
    energy: EnergyAccount,
    rest_now: Vec<f64>,
    rest_next: Vec<f64>,
    rest_rate: Vec<f64>,
    initial: State,
    control: Control,
    rejected_commands: usize,
}

impl Simulator {
    /// A simulator at the model's initial state.
    pub fn new(model: Model, settings: SimSettings) -> Result<Self, StepError> {
        let state = State::initial(&model);
        Self::from_state(model, state, settings)
    }

    /// A simulator starting at `state` (e.g. a quasi-static equilibrium).
    pub fn from_state(model: Model, mut state: State, settings: SimSettings) -> Result<Self, StepError> {
        if !(settings.dt.is_finite() && settings.dt > 0.0) {
            return Err(StepError::InvalidStep(settings.dt));
        }
        let mut dynamics = Dynamics::new(&model, settings.linear);
        model.scheduled_rest_lengths(state.time, &mut state.rest_lengths);
        if settings.integrator == Integrator::SymplecticEuler {
            let limit = stability_limit(&model, &state);
            if settings.dt > limit {
                return Err(StepError::UnstableExplicitStep { dt: settings.dt, limit });
            }
        }
        if !dynamics.initialize(&model, &mut state) {
            return Err(StepError::Initialization);
        }
        let mut ws = Workspace::for_forces(&model);
        evaluate_forces(&model, &state, &mut ws);
        let e = ws.energies;
        let energy = EnergyAccount {
            kinetic: e.kinetic,
            elastic: e.elastic,
            gravitational: e.gravitational,
            initial_total: e.kinetic + e.elastic + e.gravitational,
            ..Default::default()
        };
        let nc = model.cables.len();
        let control = Control::new(&model);
        Ok(Self {
            initial: state.clone(),
            model,
            state,
            settings,
            dynamics,
            ws,
            energy,
            rest_now: vec![0.0; nc],
            rest_next: vec![0.0; nc],
            rest_rate: vec![0.0; nc],
            control,
            rejected_commands: 0,
        })
    }

    /// The model.
    pub fn model(&self) -> &Model {
        &self.model
    }
    /// The current state.
    pub fn state(&self) -> &State {
        &self.state
    }
    /// The workspace evaluated at the current state by `forces::evaluate_forces`: point
    /// kinematics, generalized force, cable responses, segment lengths, joint values, energies
    /// (no tangent matrices or joint Jacobian: stepping never forms them densely).
    pub fn workspace(&self) -> &Workspace {
        &self.ws
    }
    /// Energies and works so far.
    pub fn energy(&self) -> &EnergyAccount {
        &self.energy
    }
    /// Step settings.
    pub fn settings(&self) -> &SimSettings {
        &self.settings
    }
    /// The linear-solver backend in use (dense or sparse).
    pub fn linear_backend(&self) -> LinearBackend {
        self.dynamics.linear_backend()
    }
    /// The Newton system of the implicit integrator (size, nonzeros, factor entries).
    pub fn newton_system(&self) -> &crate::solve::linear::KktSystem {
        self.dynamics.kkt()
    }
    /// Current true acceleration (local coordinates).
    pub fn acceleration(&self) -> &nalgebra::DVector<f64> {
        &self.dynamics.acceleration
    }

    /// Applies an actuator command by actuator name (see `crate::control`), effective from the
    /// next step. A rejected command is counted (`rejected_commands`) and changes nothing.
    pub fn command(&mut self, actuator: &str, cmd: ActuatorCommand) -> Result<(), CommandError> {
        let r = self.control.command_by_name(&self.model, actuator, cmd);
        if r.is_err() {
            self.rejected_commands += 1;
        }
        r
    }

    /// Like `command`, by actuator id.
    pub fn command_actuator(
        &mut self,
        actuator: ActuatorId,
        cmd: ActuatorCommand,
    ) -> Result<(), CommandError> {
        let r = self.control.command(&self.model, actuator, cmd);
        if r.is_err() {
            self.rejected_commands += 1;
        }
        r
    }

    /// Number of commands rejected since the start (or the last reset).
    pub fn rejected_commands(&self) -> usize {
        self.rejected_commands
    }

    /// The actuators' current modes.
    pub fn control(&self) -> &Control {
        &self.control
    }

    /// Back to the state the simulator started from.
    pub fn reset(&mut self) {
        let settings = self.settings;
        let fresh = Self::from_state(self.model.clone(), self.initial.clone(), settings)
            .expect("the initial state was accepted before");
        *self = fresh;
    }

    /// Advances by `settings.dt`, cutting the step in halves where an attempt fails.
    pub fn step(&mut self) -> Result<StepStats, StepError> {
        let start = Instant::now();
        let mut stats = StepStats::default();
        let target = self.state.time + self.settings.dt;
        let mut h = self.settings.dt;
        while self.state.time < target - 1e-12 * self.settings.dt {
            let h_try = h.min(target - self.state.time);
            self.rest_now.copy_from_slice(&self.state.rest_lengths);
            self.control.advance(&self.model, self.state.time, h_try, &self.rest_now, &mut self.rest_next);
            Control::rates(&self.model, &self.rest_now, &self.rest_next, h_try, &mut self.rest_rate);
            // power at the start of the sub-step (the workspace holds the current state)
            let (p_act0, p_loss0) = cable_powers(&self.model, &self.ws, &self.rest_rate);
            let attempt = self.dynamics.step(
                &self.model,
                self.settings.integrator,
                &self.settings.newton,
                &mut self.state,
                &self.rest_now,
                &self.rest_next,
                h_try,
            );
            match attempt {
                Some(a) => {
                    debug_assert!(self.state.is_finite());
                    if !self.dynamics.take_final_evaluation(&mut self.ws) {
                        evaluate_forces(&self.model, &self.state, &mut self.ws);
                    }
                    let (p_act1, p_loss1) = cable_powers(&self.model, &self.ws, &self.rest_rate);
                    self.energy.actuator_work += 0.5 * h_try * (p_act0 + p_act1);
                    self.energy.damping_loss += 0.5 * h_try * (p_loss0 + p_loss1);
                    stats.newton_iterations += a.iterations;
                    stats.factorizations += a.factorizations;
                    stats.residual = stats.residual.max(a.residual);
                    stats.substeps += 1;
                    // after a cut, try to grow back
                    h = (2.0 * h_try).min(self.settings.dt);
                }
                None => {
                    stats.rejected += 1;
                    h = 0.5 * h_try;
                    if h < self.settings.min_dt {
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
        let e = self.ws.energies;
        self.energy.kinetic = e.kinetic;
        self.energy.elastic = e.elastic;
        self.energy.gravitational = e.gravitational;
        stats.wall_time = start.elapsed();
        Ok(stats)
    }
}
