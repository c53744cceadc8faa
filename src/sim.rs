//! The simulator: owns a `Model`, its `State`, the integrator memory and the workspace; takes a
//! step size and an integrator, gives fixed-size steps (`step`) with step statistics and a running
//! energy account. A step whose Newton iteration fails, or that produces a non-finite number, is
//! rejected and retried in halves down to `min_dt`; below that a typed `StepError` comes out and the
//! state is left at the last good step. No NaN or infinity ever enters the state. The explicit
//! integrator is refused at start-up when the step exceeds its stability limit (checked at the
//! initial state; tension changes during a run move the limit, so keep a margin).

use std::time::{Duration, Instant};

use crate::control::{ActuatorCommand, CommandError, Control};
use crate::evaluate::{evaluate_forces, Workspace};
use crate::model::{ActuatorId, Model};
use crate::solve::dynamics::{
    cable_powers, explicit_stability_limit, stability_region_limit, AttemptFailure, Dynamics, Integrator,
    NewtonSettings,
};
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
    /// Local error tolerance, m (`None`: fixed steps). With a tolerance, `dt` is the output
    /// interval: each `step` reaches `t + dt` exactly in sub-steps whose size the integrator's
    /// local error estimate chooses (generalized-alpha and Dormand-Prince only).
    pub tolerance: Option<f64>,
}

impl Default for SimSettings {
    fn default() -> Self {
        Self {
            dt: 1e-3,
            integrator: Integrator::GeneralizedAlpha { rho_inf: 0.8 },
            newton: NewtonSettings::default(),
            min_dt: 1e-9,
            linear: LinearBackend::Auto,
            tolerance: None,
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
    /// Accepted sub-steps (1 when nothing was rejected and the step is fixed).
    pub substeps: usize,
    /// Force evaluations over all attempts.
    pub evaluations: usize,
    /// Largest local error estimate of the accepted sub-steps, m (0 without an estimate).
    pub error: f64,
    /// Sub-steps accepted at the smallest error-controlled step (`MIN_CONTROLLED_STEP` of the
    /// interval) without meeting the tolerance: where the motion jumps (a cable goes slack).
    pub forced: usize,
    /// Sub-steps undone and retried in halves because one bar passed through another
    /// (`[collisions]`: the side one axis passes the other on flipped within the sub-step).
    pub pass_throughs: usize,
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
    /// A bar passed through another within even the smallest allowed sub-step.
    #[error(
        "bar '{first}' passed through bar '{second}' at t = {time} s within a sub-step of {dt:.3e} s (the smallest allowed): stiffen [collisions] or give the bars larger contact_radius"
    )]
    PassThrough {
        /// The first bar of the pair.
        first: String,
        /// The second bar.
        second: String,
        /// Time of the last accepted state, s.
        time: f64,
        /// The sub-step that let it through, s.
        dt: f64,
    },
    /// Consistent initial accelerations could not be computed (singular mass/constraint system).
    #[error("cannot start the dynamics: the mass and constraint matrix is singular or not finite")]
    Initialization,
    /// The step size is not positive and finite.
    #[error("invalid step size {0} s")]
    InvalidStep(f64),
    /// The explicit integrator would be unstable at this step size.
    #[error(
        "{integrator} is unstable at dt = {dt:.3e} s: its stability limit here is {limit:.3e} s; use a smaller step, an error tolerance (dormand-prince) or generalized-alpha"
    )]
    UnstableExplicitStep {
        /// The integrator's name.
        integrator: String,
        /// Requested step, s.
        dt: f64,
        /// Stability limit at the initial state, s.
        limit: f64,
    },
    /// An explicit integrator's run diverged although its step was below the stability limit at
    /// the start (the structure stiffened since): the energy it made up is far above any the
    /// run was given. The state is left as it was before the step.
    #[error(
        "{integrator} diverged at t = {time} s: the step made up {gain:.3e} J of energy, against {scale:.3e} J the run holds; use a smaller step, an error tolerance (dormand-prince) or generalized-alpha"
    )]
    Diverged {
        /// The integrator's name.
        integrator: String,
        /// Time of the last good state, s.
        time: f64,
        /// Energy the run has made up (`-EnergyAccount::numerical_loss`), J.
        gain: f64,
        /// The run's energy scale (`divergence_scale`), J.
        scale: f64,
    },
    /// A run asked to start from the static equilibrium (`Simulator::at_equilibrium`), and
    /// statics found none from the scene's pose.
    #[error(
        "no static equilibrium to start from: the residual is {residual:.3e} N after {iterations} Newton iterations from the scene's pose (start from the scene's pose instead, or see `tensegrity statics`)"
    )]
    NoEquilibrium {
        /// Newton iterations taken.
        iterations: usize,
        /// Residual at the end, N.
        residual: f64,
    },
    /// An error tolerance was given to an explicit integrator in a scene with contacts: its error
    /// estimate measures positions, and through an impact (milliseconds in which the velocity
    /// turns over while the position hardly moves) it lets the rebound velocity go wrong
    /// (Dormand-Prince at 1 mm came off a bouncing ball's reference by 43 mm, `tests/contact.rs`).
    #[error("{integrator} cannot take a tolerance in a scene with ground contact (its error estimate does not see the velocity jumps of impacts); use generalized-alpha, whose error control resolves impacts, or a fixed step")]
    ToleranceWithContact {
        /// The integrator's name.
        integrator: String,
    },
    /// An error tolerance was given to an integrator that cannot estimate its error.
    #[error("{integrator} has no error estimate, so it cannot take a tolerance; use generalized-alpha or dormand-prince, or a fixed step")]
    ToleranceNotSupported {
        /// The integrator's name.
        integrator: String,
    },
    /// The tolerance is not positive and finite.
    #[error("invalid error tolerance {0} m")]
    InvalidTolerance(f64),
}

/// An implicit integrator under error control grows its step only when the error estimate
/// allows this factor or more (every new step size costs it a factorization).
pub const GROWTH_THRESHOLD: f64 = 1.2;

/// The smallest sub-step error control takes, as a fraction of the output interval, down to
/// tolerances of `TIGHT_CONTROLLED_TOLERANCE`; a sub-step this small is accepted whatever its
/// error estimate (and counted, `StepStats::forced`). See `smallest_controlled_step`.
pub const MIN_CONTROLLED_STEP: f64 = 1e-5;

/// Below this tolerance (m) the smallest controlled sub-step shrinks with the tolerance
/// (`smallest_controlled_step`).
pub const TIGHT_CONTROLLED_TOLERANCE: f64 = 1e-8;

/// The smallest sub-step error control takes for output interval `dt` (s) and `tolerance` (m):
/// `MIN_CONTROLLED_STEP dt`, times `tol / TIGHT_CONTROLLED_TOLERANCE` below that tolerance. The
/// floor keeps a jump of the acceleration (a cable going slack) from shrinking the step without
/// end; a kink's local error falls with the step, so a tighter tolerance needs a lower floor:
/// a block bouncing on a stiff ground (tests/contact.rs) at 1e-9 m with 10 ms outputs sat at a
/// 1e-7 s floor through each impact for 51857 forced sub-steps and delivered 357 times the
/// tolerance; at 1e-8 s it is never forced.
pub fn smallest_controlled_step(dt: f64, tolerance: Option<f64>) -> f64 {
    let tight = tolerance.map_or(1.0, |t| (t / TIGHT_CONTROLLED_TOLERANCE).min(1.0));
    dt * MIN_CONTROLLED_STEP * tight
}

/// The first sub-step of an error-controlled run, as a fraction of the output interval. Small,
/// because the first step's estimate has one difference of accelerations and no envelope
/// (`dynamics::jerk_envelope`): a structure released from rest has no jerk yet, and a first
/// step of the whole interval was accepted where the next ones were not (on the elastic Atwood
/// machine at 1e-6 m that first step's error set the run's). Growth by up to 5 times a sub-step
/// reaches the size the estimate proposes in a few sub-steps.
pub const INITIAL_STEP_FRACTION: f64 = 1.0 / 256.0;

/// The largest whole fraction `dt / k` of the output interval that is at most `h` (s).
fn quantized(dt: f64, h: f64) -> f64 {
    dt / (dt / h * (1.0 - 1e-12)).ceil().max(1.0)
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
    /// Energy dissipated since the start (trapezoidal in time) by the cable and member dampers
    /// (Rayleigh's `beta` included), the contacts, the joints' rotational damping and Rayleigh's
    /// mass-proportional `alpha`.
    pub damping_loss: f64,
    /// Energy dissipated since the start by friction at the pulleys, booked per accepted step
    /// (`crate::forces::pulley::commit`).
    pub friction_loss: f64,
    /// Work of the winch motors' line forces since the start, `sum h F_m v`
    /// (`crate::forces::winch`); 0 without winches.
    pub motor_work: f64,
    /// Energy lost in the winch drums' viscous friction since the start.
    pub winch_friction_loss: f64,
    /// Kinetic energy of the winch rotors now, `sum J omega^2 / 2`. Outside `total()`: the
    /// motors' balance is `motor_work - winch_friction_loss - winch_kinetic ~ ` the work the
    /// drums do on their cables (part of `actuator_work`).
    pub winch_kinetic: f64,
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
        self.initial_total + self.actuator_work - self.damping_loss - self.friction_loss - self.total()
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
    /// With a tolerance: the sub-step the error estimate proposes next, s.
    next_h: f64,
    /// With a tolerance: running mean of the accepted sub-steps, s.
    mean_h: f64,
    /// An explicit integrator under error control: the largest sub-step it may take,
    /// `EXPLICIT_STEP_CAP` times its stability limit at the start (`stability_region_limit`),
    /// s; infinite otherwise.
    step_cap: f64,
    /// An explicit integrator at a fixed step: the state before the step under way, restored when
    /// the step diverges (`StepError::Diverged`), and the energy scale that tells it
    /// (`divergence_scale`). `None` for every other integrator and setting, which pay nothing.
    guard: Option<(State, EnergyAccount, f64)>,
    /// The state before the sub-step under way, kept when a guard below may undo it (one copy
    /// per sub-step serves them all). `None` when no guard is armed.
    sub_step_start: Option<State>,
    /// Generalized-alpha at a fixed step: the energy account before the sub-step under way and
    /// the energy scale; a sub-step that makes up more than `IMPLICIT_GAIN_FACTOR` times the
    /// scale is undone and retried in halves (a tension-only cable snapping taut and slack faster
    /// than the step can pump energy into the run, where the linear analysis promises
    /// stability). `None` otherwise.
    implicit_guard: Option<(EnergyAccount, f64)>,
    /// With a tolerance and contacts: every contact pair's gap before the sub-step under way, to
    /// retry a sub-step that steps too far past a touchdown or a lift-off
    /// (`CONTACT_EVENT_DEPTH`). `None` otherwise.
    contact_events: Option<Vec<f64>>,
    /// With strut pairs (`[collisions]`): every pair's side (`ClosestPoints::side` in `Workspace::strut_closest`) before
    /// the sub-step under way, to undo a sub-step that carries one bar through another. `None`
    /// otherwise.
    pass_through_guard: Option<Vec<f64>>,
    /// Per winch, `dV/dL0` of its cable at the start of the sub-step under way (N), for the
    /// trapezoidal work of the rest length the motor moves; empty without winches.
    winch_rest_force: Vec<f64>,
}

impl Simulator {
    /// A simulator at the model's initial state.
    pub fn new(model: Model, settings: SimSettings) -> Result<Self, StepError> {
        let state = State::initial(&model);
        Self::from_state(model, state, settings)
    }

    /// A simulator at rest in the static equilibrium of the model at t = 0: statics
    /// (`StaticSolver::equilibrate` with the scene's `[solver]` settings) from the scene's pose,
    /// the rest lengths of the schedule at t = 0. A run started here stays put until an actuator
    /// moves, where one started from the scene's pose (`new`) first swings toward it. `reset`
    /// comes back here.
    pub fn at_equilibrium(model: Model, settings: SimSettings) -> Result<Self, StepError> {
        let mut state = State::initial(&model);
        model.scheduled_rest_lengths(state.time, &mut state.rest_lengths);
        let mut ws = Workspace::new(&model);
        let mut solver = crate::solve::statics::StaticSolver::new(&model);
        solver
            .equilibrate(&model, &mut state, &mut ws, &model.solver)
            .map_err(|(iterations, residual)| StepError::NoEquilibrium { iterations, residual })?;
        Self::from_state(model, state, settings)
    }

    /// Like `new`, or `at_equilibrium` when `from_equilibrium`.
    pub fn start(model: Model, settings: SimSettings, from_equilibrium: bool) -> Result<Self, StepError> {
        if from_equilibrium {
            Self::at_equilibrium(model, settings)
        } else {
            Self::new(model, settings)
        }
    }

    /// A simulator starting at `state` (e.g. a quasi-static equilibrium).
    pub fn from_state(model: Model, mut state: State, settings: SimSettings) -> Result<Self, StepError> {
        if !(settings.dt.is_finite() && settings.dt > 0.0) {
            return Err(StepError::InvalidStep(settings.dt));
        }
        if let Some(tol) = settings.tolerance {
            if !(tol.is_finite() && tol > 0.0) {
                return Err(StepError::InvalidTolerance(tol));
            }
            if !settings.integrator.estimates_error() {
                return Err(StepError::ToleranceNotSupported { integrator: settings.integrator.name() });
            }
            if settings.integrator.is_explicit() && model.contact_pairs() > 0 {
                return Err(StepError::ToleranceWithContact { integrator: settings.integrator.name() });
            }
        }
        let mut dynamics = Dynamics::new(&model, settings.linear);
        model.scheduled_rest_lengths(state.time, &mut state.rest_lengths);
        // an explicit integrator at a fixed step must stay below its stability limit (with a
        // tolerance the error estimate cuts the step where it would not)
        if settings.integrator.is_explicit() && settings.tolerance.is_none() {
            let limit = explicit_stability_limit(&model, &state, settings.integrator);
            if settings.dt > limit {
                return Err(StepError::UnstableExplicitStep {
                    integrator: settings.integrator.name(),
                    dt: settings.dt,
                    limit,
                });
            }
        }
        // under error control an explicit step stays below its stability limit too: above it
        // a barely excited stiff mode grows until the error estimate sees it, and the run then
        // carries that mode at about the tolerance's amplitude (the nodal prism's members
        // delivered ten times the tolerance that way)
        let step_cap = if settings.integrator.is_explicit() && settings.tolerance.is_some() {
            EXPLICIT_STEP_CAP * stability_region_limit(&model, &state, settings.integrator)
        } else {
            f64::INFINITY
        };
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
        let model_winches = model.winches.len();
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
            next_h: (settings.dt * INITIAL_STEP_FRACTION).min(step_cap),
            mean_h: settings.dt,
            step_cap,
            guard: None,
            sub_step_start: None,
            implicit_guard: None,
            contact_events: None,
            pass_through_guard: None,
            winch_rest_force: vec![0.0; model_winches],
        }
        .with_divergence_guard())
    }

    /// The model.
    pub fn model(&self) -> &Model {
        &self.model
    }
    /// The current state.
    pub fn state(&self) -> &State {
        &self.state
    }
    /// The workspace evaluated at the current state by `evaluate::evaluate_forces`: point
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

    /// Advances by `settings.dt`. Fixed steps: an attempt that fails is retried in halves (then
    /// grown back). With a tolerance: sub-steps of the size the local error estimate proposes,
    /// `h_new = h min(5, max(0.2, 0.9 ratio^(-e)))` with `ratio` the error over what the
    /// tolerance allows (`AttemptStats::error_ratio`) and `e = Integrator::error_exponent`; a
    /// sub-step whose ratio exceeds 1 is rejected and retried smaller, the last one clipped to end
    /// exactly at `t + dt`.
    pub fn step(&mut self) -> Result<StepStats, StepError> {
        if let Some((before, energy, _)) = &mut self.guard {
            before.copy_from(&self.state);
            *energy = self.energy;
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
            if let Some(before) = &mut self.sub_step_start {
                before.copy_from(&self.state);
            }
            if let Some((energy, _)) = &mut self.implicit_guard {
                *energy = self.energy;
            }
            if let Some(gaps) = &mut self.contact_events {
                for (g, c) in gaps.iter_mut().zip(&self.ws.contacts) {
                    *g = c.gap;
                }
            }
            if let Some(sides) = &mut self.pass_through_guard {
                for (side, closest) in sides.iter_mut().zip(&self.ws.strut_closest) {
                    *side = closest.side;
                }
            }
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
                    if let (Some(sides), Some(before)) = (&self.pass_through_guard, &self.sub_step_start) {
                        // a bar whose axis changed sides of another's within the sub-step went
                        // through it (the penalty force never saw it, or could not stop it):
                        // undo and retry in halves
                        let crossed =
                            sides.iter().zip(&self.ws.strut_closest).position(|(a, b)| a * b.side < 0.0);
                        if let Some(i) = crossed {
                            undo_sub_step(
                                &self.model,
                                &mut self.dynamics,
                                &mut self.state,
                                &mut self.ws,
                                before,
                            )?;
                            stats.rejected += 1;
                            stats.pass_throughs += 1;
                            stats.newton_iterations += a.iterations;
                            h = 0.5 * h_try;
                            if h < self.settings.min_dt.max(smallest) {
                                let pair = &self.model.strut_pairs[i];
                                return Err(StepError::PassThrough {
                                    first: self.model.bodies[pair.bars[0].0].name.clone(),
                                    second: self.model.bodies[pair.bars[1].0].name.clone(),
                                    time: self.state.time,
                                    dt: h_try,
                                });
                            }
                            continue;
                        }
                    }
                    if let (Some(gaps), Some(before), Some(tol), false) =
                        (&self.contact_events, &self.sub_step_start, tolerance, forced)
                    {
                        // a touchdown or lift-off inside the sub-step is a kink of the force
                        // that the error estimate sees only after the fact: a sub-step that
                        // ends more than CONTACT_EVENT_DEPTH x tol past one is retried to end
                        // half that far past it (the gap taken linear over the sub-step)
                        let depth = CONTACT_EVENT_DEPTH * tol;
                        let mut fraction: f64 = 1.0;
                        for (g0, c) in gaps.iter().zip(&self.ws.contacts) {
                            let g1 = c.gap;
                            if *g0 > 0.0 && g1 < -depth {
                                fraction = fraction.min((g0 + 0.5 * depth) / (g0 - g1));
                            } else if *g0 < 0.0 && g1 > depth {
                                fraction = fraction.min((0.5 * depth - g0) / (g1 - g0));
                            }
                        }
                        let retry = fraction * h_try;
                        if fraction < 1.0 && retry >= smallest {
                            undo_sub_step(
                                &self.model,
                                &mut self.dynamics,
                                &mut self.state,
                                &mut self.ws,
                                before,
                            )?;
                            stats.rejected += 1;
                            stats.newton_iterations += a.iterations;
                            h = retry;
                            continue;
                        }
                    }
                    let (p_act1, p_loss1) = cable_powers(&self.model, &self.ws, &self.rest_rate);
                    self.energy.actuator_work += 0.5 * h_try * (p_act0 + p_act1);
                    self.energy.damping_loss += 0.5 * h_try * (p_loss0 + p_loss1);
                    if let (Some((energy_before, scale)), Some(before)) =
                        (&self.implicit_guard, &self.sub_step_start)
                    {
                        let e = self.ws.energies;
                        let now = EnergyAccount {
                            kinetic: e.kinetic,
                            elastic: e.elastic,
                            gravitational: e.gravitational,
                            ..self.energy
                        };
                        // what the run holds beyond its start and all the actuators' work: the
                        // dampers' loss is left out, as a diverging run's dampers book a loss
                        // as wild as its motion and would hide the gain
                        let gain = now.total() - now.initial_total - now.actuator_work.abs();
                        let scale = scale + now.actuator_work.abs();
                        if gain.is_nan() || gain > IMPLICIT_GAIN_FACTOR * scale {
                            // undo the sub-step and retry it in halves, from consistent
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
                            h = 0.5 * h_try;
                            if h < self.settings.min_dt {
                                return Err(StepError::Diverged {
                                    integrator: self.settings.integrator.name(),
                                    time: self.state.time,
                                    gain,
                                    scale,
                                });
                            }
                            continue;
                        }
                    }
                    if !self.model.pulley_friction.is_empty() {
                        self.commit_pulley_friction(h_try);
                    }
                    if !self.model.winches.is_empty() {
                        self.commit_winches(h_try);
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
        if let Some((before, energy, scale)) = &self.guard {
            let gain = -self.energy.numerical_loss();
            let scale = scale + self.energy.actuator_work.abs() + self.energy.damping_loss;
            if gain.is_nan() || gain > DIVERGENCE_FACTOR * scale {
                let time = before.time;
                self.state.copy_from(before);
                self.energy = *energy;
                evaluate_forces(&self.model, &self.state, &mut self.ws);
                return Err(StepError::Diverged {
                    integrator: self.settings.integrator.name(),
                    time,
                    gain,
                    scale,
                });
            }
        }
        stats.wall_time = start.elapsed();
        Ok(stats)
    }

    /// After an accepted sub-step of `h` (s): the pulleys' return map at the accepted state
    /// becomes the state (`crate::forces::pulley::commit`), and friction's loss is booked. Out
    /// of line: scenes without friction never run it.
    #[cold]
    #[inline(never)]
    fn commit_pulley_friction(&mut self, h: f64) {
        self.energy.friction_loss += crate::forces::pulley::commit(
            &self.model,
            &mut self.ws.friction,
            &mut self.state.segment_rest_lengths,
            h,
        );
    }

    /// Before a sub-step of `h` (s): each winch's controller sets its drive for the sub-step
    /// (`crate::forces::winch::prepare`, from its command in `Control`), and the work factor
    /// `dV/dL0` of its cable now is kept for `commit_winches`. Out of line: scenes without
    /// winches never run it.
    #[cold]
    #[inline(never)]
    fn prepare_winches(&mut self, h: f64) {
        for (w, winch) in self.model.winches.iter().enumerate() {
            let c = winch.cable.0;
            let s = &mut self.state.winches[w];
            let command =
                self.control.winch_command(&self.model, winch.actuator, self.state.time, h, s.reference);
            crate::forces::winch::prepare(&self.model, winch, s, command, self.state.rest_lengths[c], h);
            self.winch_rest_force[w] = rest_force(&self.model, &self.ws.cables[c], c);
        }
    }

    /// After an accepted sub-step of `h` (s): each winch's cable takes the rest length its motor
    /// reached (`crate::forces::winch::commit`), and the motors' work, friction and rotor energy
    /// and the work the drums did on their cables (trapezoidal, into `actuator_work`) are
    /// booked.
    #[cold]
    #[inline(never)]
    fn commit_winches(&mut self, h: f64) {
        let mut kinetic = 0.0;
        for (w, winch) in self.model.winches.iter().enumerate() {
            let c = winch.cable.0;
            let (l0_start, l0_end) = (self.state.rest_lengths[c], self.ws.cables[c].rest_length);
            let work = crate::forces::winch::commit(winch, &mut self.state.winches[w], l0_start, l0_end);
            self.energy.motor_work += work.motor;
            self.energy.winch_friction_loss += work.friction;
            let rate = (l0_end - l0_start) / h;
            let end = rest_force(&self.model, &self.ws.cables[c], c);
            self.energy.actuator_work -= 0.5 * h * (self.winch_rest_force[w] + end) * rate;
            self.state.rest_lengths[c] = l0_end;
            kinetic += crate::forces::winch::rotor_energy(winch, self.state.winches[w].speed);
        }
        self.energy.winch_kinetic = kinetic;
    }

    /// Arms the divergence guard of an integrator at a fixed step (`guard` for an explicit one,
    /// which stops the run; `implicit_guard` for generalized-alpha, which retries the sub-step in
    /// halves): the energy
    /// scale is the kinetic and elastic energy at the start plus the potential energy the
    /// structure's weight releases over its own size (`sum_b m_b |g| L`, `L` the largest body
    /// size or cable length), J.
    fn with_divergence_guard(mut self) -> Self {
        if self.settings.tolerance.is_some() && self.model.contact_pairs() > 0 {
            self.contact_events = Some(vec![0.0; self.model.contact_pairs()]);
        }
        if !self.model.strut_pairs.is_empty() {
            self.pass_through_guard = Some(vec![0.0; self.model.strut_pairs.len()]);
        }
        if self.settings.tolerance.is_none() {
            let size = crate::solve::statics::body_size(&self.model)
                .max(self.ws.cables.iter().map(|c| c.length).fold(0.0, f64::max));
            let weight: f64 = self.model.bodies.iter().map(|b| b.mass * self.model.gravity.norm()).sum();
            let scale = self.energy.kinetic + self.energy.elastic + weight * size;
            if self.settings.integrator.is_explicit() {
                self.guard = Some((self.state.clone(), self.energy, scale.max(1e-9)));
            } else {
                self.implicit_guard = Some((self.energy, scale.max(1e-9)));
            }
        }
        let undoable = self.implicit_guard.is_some()
            || self.contact_events.is_some()
            || self.pass_through_guard.is_some();
        if undoable {
            self.sub_step_start = Some(self.state.clone());
        }
        self
    }
}

/// `-dV/dL0` of cable `c` (N) at its response `r`, at a fixed length: `T_el (L + L0) / (2 L0)`
/// while taut, 0 slack: the force an actuator moving its rest length works against
/// (`crate::forces::cable::elastic_energy_rest_derivative`).
fn rest_force(model: &Model, r: &crate::forces::cable::CableResponse, c: usize) -> f64 {
    if r.slack {
        return 0.0;
    }
    -crate::forces::cable::elastic_energy_rest_derivative(&model.cables[c], r.rest_length, r.length)
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

/// Dormand-Prince's local errors add up over a run in proportion to its number of steps: a run
/// whose steps are held below this (s) by its stability limit (`EXPLICIT_STEP_CAP`) makes each
/// step's error smaller in proportion, `tol h_mean / EXPLICIT_ERROR_STEP`, so that it delivers
/// what the tolerance asks of runs at this step. The bundled scenes' runs step above it from
/// 1e-3 down to 1e-8 m (prism3 at 1e-8 m: 3.3e-3 s); the nodal prism's members hold its steps
/// at 6.2e-4 s, where without this its error reached 3.3 times the tolerance at 1e-8 m.
pub const EXPLICIT_ERROR_STEP: f64 = 2e-3;

/// An explicit integrator under error control takes sub-steps of at most this fraction of its
/// stability limit at the start (`crate::solve::dynamics::stability_region_limit`): the margin
/// covers the limit's drift as the structure moves.
pub const EXPLICIT_STEP_CAP: f64 = 0.9;

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
/// (`Simulator::with_divergence_guard`): the method dissipates, so a run that gains that much is
/// being pumped by cables snapping taut and slack within a step, not moving.
pub const IMPLICIT_GAIN_FACTOR: f64 = 1.0;

/// An explicit run stops (`StepError::Diverged`) when the energy it made up exceeds this many
/// times its energy scale (`Simulator::with_divergence_guard`, plus the actuator work and damping
/// loss so far): a stable run's energy error stays a fraction of the energy it holds, an
/// unstable one grows without bound (8.8e105 J on the atwood scene at 0.1 s before the limit
/// counted the rope's taut stiffness).
pub const DIVERGENCE_FACTOR: f64 = 10.0;
