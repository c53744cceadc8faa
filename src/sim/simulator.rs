//! The simulator: takes a `Model` and `SimSettings`, gives a `Simulator` that owns the model, its
//! `State`, the integrator's memory, the workspace, the command queue and the energy account;
//! here its construction (from the scene's pose, the static equilibrium or a given state),
//! commands and reset. Its step is `crate::sim::substep`'s.

use crate::control::{ActuatorCommand, CommandError, Control};
use crate::evaluate::{evaluate_forces, Workspace};
use crate::model::{ActuatorId, Model};
use crate::sim::energy::EnergyAccount;
use crate::sim::guards::Guards;
use crate::sim::settings::{SimSettings, StepError};
use crate::sim::step_size::{EXPLICIT_STEP_CAP, INITIAL_STEP_FRACTION};
use crate::solve::dynamics::{explicit_stability_limit, stability_region_limit, Dynamics};
use crate::solve::linear::LinearBackend;
use crate::state::State;

/// Owns a model and advances it in time.
#[derive(Debug, Clone)]
pub struct Simulator {
    pub(super) model: Model,
    pub(super) state: State,
    pub(super) settings: SimSettings,
    pub(super) dynamics: Dynamics,
    pub(super) ws: Workspace,
    pub(super) energy: EnergyAccount,
    pub(super) rest_now: Vec<f64>,
    pub(super) rest_next: Vec<f64>,
    pub(super) rest_rate: Vec<f64>,
    pub(super) initial: State,
    pub(super) control: Control,
    pub(super) rejected_commands: usize,
    /// With a tolerance: the sub-step the error estimate proposes next, s.
    pub(super) next_h: f64,
    /// With a tolerance: running mean of the accepted sub-steps, s.
    pub(super) mean_h: f64,
    /// An explicit integrator under error control: the largest sub-step it may take,
    /// `EXPLICIT_STEP_CAP` times its stability limit at the start (`stability_region_limit`),
    /// s; infinite otherwise.
    pub(super) step_cap: f64,
    /// The checks that accept, retry or fail a sub-step or a step (`crate::sim::guards`): only
    /// those the model and settings need are armed.
    pub(super) guards: Guards,
    /// Per winch, `dV/dL0` of its cable at the start of the sub-step under way (N), for the
    /// trapezoidal work of the rest length the motor moves; empty without winches.
    pub(super) winch_rest_force: Vec<f64>,
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
        if model.dof_count == 0 {
            return Err(StepError::NothingToMove);
        }
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
        let anchored_pairs = if model.has_stick_friction() { model.ground_pairs() } else { 0 };
        if state.contact_anchors.len() != anchored_pairs {
            // a state made for another scene, or by hand: its contacts stick where they stand
            state.contact_anchors = crate::forces::contact::initial_anchors(&model, &state.poses);
        }
        // an explicit integrator at a fixed step must stay below its stability limit (with a
        // tolerance the error estimate cuts the step where it would not)
        if settings.integrator.is_explicit() && settings.tolerance.is_none() {
            let limit = explicit_stability_limit(&model, &state, settings.integrator);
            if settings.dt > limit {
                return Err(StepError::UnstableExplicitStep {
                    integrator: settings.integrator.name(),
                    dt: settings.dt,
                    limit,
                    cause: contact_limit_cause(&model, &state, settings, limit),
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
        let control = Control::new(&model, settings.dt);
        let guards = Guards::arm(&model, &settings, &state, &ws, &energy);
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
            guards,
            winch_rest_force: vec![0.0; model_winches],
        })
    }

    /// What the scene's delays say at this simulator's physics step (`Model::delay_warnings`):
    /// step-counted fields and delays in seconds rounded to whole steps, one line each.
    pub fn delay_warnings(&self) -> Vec<String> {
        self.model.delay_warnings(self.settings.dt)
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
}

/// Why an explicit step's stability `limit` (s) is what it is, when the contacts set it: the
/// limit without them, if it is more than twice as long (the contacts count as pressed in, with
/// their normal stiffness and their stuck friction at the structure's weight); else empty.
fn contact_limit_cause(model: &Model, state: &State, settings: SimSettings, limit: f64) -> String {
    if model.contact_pairs() == 0 {
        return String::new();
    }
    let mut free = model.clone();
    free.grounds.clear();
    free.contact_spheres.clear();
    free.strut_pairs.clear();
    let without = explicit_stability_limit(&free, state, settings.integrator);
    if without > 2.0 * limit {
        let free_limit = if without.is_finite() {
            format!("{without:.3e} s without them")
        } else {
            "none without them".into()
        };
        format!(
            " (set by the contacts' normal stiffness and stuck friction, counted pressed in: {free_limit}; \
             a softer ground or a smaller mu raises it)"
        )
    } else {
        String::new()
    }
}
