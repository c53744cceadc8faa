//! The transport-free node core: takes a `Model`, `NodeParams`, incoming commands and service
//! requests (from any transport) and the wall-clock time, gives paced physics steps and tells a
//! `NodeSink` what to publish and which deferred requests to answer.
//!
//! It owns what the node *means*, so every transport (DDS, shared memory, a bag recorder) behaves
//! the same:
//! - **Pacing**: one step per `tick` while playing, due at `anchor + (t_sim - t_anchor) / rtf`;
//!   a step that ends more than one step late counts as an overrun and re-anchors (no bursts).
//!   `real_time_factor = 0` runs as fast as possible.
//! - **Pause, step, reset**: `StepSimulation` only while paused; its steps are taken one per
//!   `tick`, so a request of 10^12 steps never blocks pause, reset, other services or shutdown,
//!   and a second request while one is under way is refused. Unpause, reset, quit and shutdown
//!   answer a pending request with a failure that says why.
//! - **Commands**: every message is checked (sizes first, then names, duplicates, values; see
//!   `commands::check_command`) and counted (`received = accepted + rejected`); accepted entries are
//!   kept per actuator, the newest wins, and applied together at the next step boundary.
//!   Rejections are reported in `/diagnostics` at most `MAX_REJECTION_REPORTS_PER_SECOND` times a
//!   second, with the count since the last report and a short excerpt of the latest reason.
//! - **Faults**: no publish or receive failure stops the core; it is counted per topic and
//!   reported at most once a second. A physics step that fails even at the smallest sub-step, or
//!   a state that is not finite, pauses the simulation (`faulted`), publishes an ERROR diagnostic
//!   naming the step and the cause, answers a pending step request with a failure, and keeps
//!   serving: reset clears the fault. Nothing non-finite is ever handed to a sink.
//!
//! The core never reads a clock or sleeps: `tick(now)` takes the time since any fixed epoch and
//! returns when it wants to be called again, so tests drive it with a fake clock.

pub mod params;
pub mod runner;

use crate::sensors::Sensors;
use std::time::Duration;

use crate::control::ActuatorCommand;
use crate::evaluate::Workspace;
use crate::io::commands::{self, CommandArrays, MessageError, MAX_COMMANDS_PER_STEP};
use crate::io::msg::{self, result_code, sim_state, DiagnosticStatus, KeyValue, SimResult};
use crate::io::node::params::NodeParams;
use crate::io::sink::{ConstantsId, NodeSink, NodeStats, NodeView};
use crate::io::topics::Topic;
use crate::model::{ActuatorId, Model};
use crate::report;
use crate::sim::{SimSettings, Simulator, StepError, StepStats};
use crate::solve::dynamics::Integrator;

/// Most rejection reports in `/diagnostics` per second of wall time.
pub const MAX_REJECTION_REPORTS_PER_SECOND: u32 = 10;
/// Interval of the periodic `/diagnostics` status and of transport-failure reports.
pub const DIAGNOSTICS_PERIOD: Duration = Duration::from_secs(1);
/// Longest `tick` asks to sleep while there is nothing to step (paused or faulted): the turn after
/// it publishes the periodic status. Inputs that arrive meanwhile are taken by the transports,
/// and a runner turns the core at once when they give it work (`NodeCore::idle_turn_due`).
pub const IDLE_PERIOD: Duration = DIAGNOSTICS_PERIOD;

/// A StepSimulation request under way.
#[derive(Debug, Clone, Copy, PartialEq)]
struct StepRequest {
    ticket: u64,
    requested: u64,
    remaining: u64,
}

/// The node's logic with no transport: see the module docs.
pub struct NodeCore {
    sim: Simulator,
    params: NodeParams,
    reference: Vec<Vec<f64>>,
    /// Names `reference`, `params.frame_id` and `params.node_name` in views (never changed).
    constants: ConstantsId,
    previous_rest: Vec<f64>,
    rates: Vec<f64>,
    paused: bool,
    fault: Option<String>,
    quit: bool,
    stats: NodeStats,
    /// Steps since the start or the last reset.
    steps_since_reset: u64,
    /// Accepted, not yet applied commands, keep-last per actuator.
    unapplied: Vec<Option<ActuatorCommand>>,
    /// Scratch for checking one message.
    checked: Vec<(ActuatorId, ActuatorCommand)>,
    /// Scratch for the applied commands of one boundary.
    applied: Vec<(ActuatorId, ActuatorCommand)>,
    step_request: Option<StepRequest>,
    next_ticket: u64,
    last_state_publish: Option<f64>,
    last_markers: Option<f64>,
    last_command: Option<f64>,
    timed_out: bool,
    /// Wall time and sim time the pacing is anchored at.
    anchor: Option<(Duration, f64)>,
    /// Start of the current real-time-factor window (wall, sim) and the last periodic report.
    window: Option<(Duration, f64)>,
    last_rejection_report: Option<Duration>,
    rejections_unreported: u64,
    latest_rejection: String,
    commands_this_step: usize,
    statuses: Vec<DiagnosticStatus>,
    last_step: StepStats,
    /// The scene's sensor models (`crate::sensors`), measured after every step; empty without.
    sensors: Sensors,
}

/// Why the core could not be built.
#[derive(Debug, thiserror::Error)]
pub enum CoreError {
    /// A parameter does not fit the model.
    #[error("{0}")]
    Params(String),
    /// The simulation could not start.
    #[error(transparent)]
    Step(#[from] StepError),
}

impl NodeCore {
    /// Builds the simulator from `model` and `params` (`physics_dt`, else the scene's, else 1 ms;
    /// the integrator; actuators held at their initial rest lengths unless `follow_schedule`).
    pub fn new(model: Model, params: NodeParams) -> Result<Self, CoreError> {
        let integrator = Integrator::parse(&params.integrator, params.rho_inf)
            .ok_or_else(|| CoreError::Params(format!("unknown integrator '{}'", params.integrator)))?;
        let dt = params.physics_dt.or(model.physics_dt).unwrap_or(crate::sim::DEFAULT_PHYSICS_DT);
        let tolerance = (params.tolerance > 0.0).then_some(params.tolerance);
        let mut settings = SimSettings { dt, integrator, tolerance, ..Default::default() };
        settings.newton.tolerance = params.newton_tolerance;
        let sim = Simulator::start(model, settings, params.start_from_equilibrium)?;
        Ok(Self::with_simulator(sim, params))
    }

    /// A core around a simulator built by the caller (its settings are used as they are).
    pub fn with_simulator(sim: Simulator, params: NodeParams) -> Self {
        let reference = report::all_pulley_coordinates(sim.model(), sim.state(), sim.workspace());
        let n_cables = sim.state().rest_lengths.len();
        let n_actuators = sim.model().actuators.len();
        let mut sensors = Sensors::new(sim.model(), params.sensor_seed, sim.settings().dt);
        sensors.update(sim.model(), sim.state(), sim.workspace());
        let mut core = Self {
            paused: params.start_paused,
            previous_rest: sim.state().rest_lengths.clone(),
            sim,
            params,
            reference,
            constants: ConstantsId::fresh(),
            rates: vec![0.0; n_cables],
            fault: None,
            quit: false,
            stats: NodeStats::default(),
            steps_since_reset: 0,
            unapplied: vec![None; n_actuators],
            checked: Vec::with_capacity(n_actuators),
            applied: Vec::with_capacity(n_actuators),
            step_request: None,
            next_ticket: 1,
            last_state_publish: None,
            last_markers: None,
            last_command: None,
            timed_out: false,
            anchor: None,
            window: None,
            last_rejection_report: None,
            rejections_unreported: 0,
            latest_rejection: String::new(),
            commands_this_step: 0,
            statuses: Vec::new(),
            last_step: StepStats::default(),
            sensors,
        };
        if !core.params.follow_schedule {
            core.command_every_actuator(false);
        }
        core
    }

    /// The simulator (read-only).
    pub fn simulator(&self) -> &Simulator {
        &self.sim
    }
    /// The sensors (what the state topics report where the scene declares sensor models).
    pub fn sensors(&self) -> &Sensors {
        &self.sensors
    }
    /// What the last physics step cost.
    pub fn last_step(&self) -> StepStats {
        self.last_step
    }
    /// The parameters.
    pub fn params(&self) -> &NodeParams {
        &self.params
    }
    /// Counters.
    pub fn stats(&self) -> NodeStats {
        self.stats
    }
    /// True while paused (also while faulted).
    pub fn paused(&self) -> bool {
        self.paused
    }
    /// The physics failure that paused the simulation, until reset.
    pub fn fault(&self) -> Option<&str> {
        self.fault.as_deref()
    }
    /// True once SetSimulationState asked for QUITTING.
    pub fn quit_requested(&self) -> bool {
        self.quit
    }
    /// Steps still to take for the StepSimulation request under way.
    pub fn steps_remaining(&self) -> u64 {
        self.step_request.map_or(0, |r| r.remaining)
    }
    /// Whether a transport may hand over another command message this step
    /// (`MAX_COMMANDS_PER_STEP`).
    pub fn wants_commands(&self) -> bool {
        self.commands_this_step < MAX_COMMANDS_PER_STEP
    }
    /// True while there is nothing to step: paused (or faulted) with no StepSimulation request
    /// under way. Its `tick` then asks for the next turn only `IDLE_PERIOD` later.
    pub fn idle(&self) -> bool {
        self.paused && self.step_request.is_none()
    }
    /// True when a turn now would do something that a turn asked for while idle would not wait
    /// for: the core is no longer idle (unpaused, a StepSimulation request), or it holds commands
    /// to apply or rejections to report. A runner that slept because the core was idle turns it
    /// at once when this becomes true after taking inputs.
    pub fn idle_turn_due(&self) -> bool {
        !self.idle() || self.rejections_unreported > 0 || self.unapplied.iter().any(Option::is_some)
    }

    /// The `SimulationState` code: PAUSED or PLAYING.
    pub fn simulation_state(&self) -> u8 {
        if self.paused {
            sim_state::PAUSED
        } else {
            sim_state::PLAYING
        }
    }

    /// Publishes what a late joiner needs once (structure, static transforms) and the initial state.
    pub fn start(&mut self, sink: &mut dyn NodeSink) {
        self.publish(sink, Topic::Structure);
        self.publish(sink, Topic::TfStatic);
        self.publish_state(sink);
        let status = self.modes_status();
        self.statuses.push(status);
        self.publish(sink, Topic::Diagnostics);
        self.statuses.clear();
    }

    /// The lowest natural frequencies at the equilibrium of the initial rest lengths, once, as an
    /// OK status `<node>: modes` (`mode_1_hz` ... up to 5, `zero_frequency_modes`); a WARN status
    /// saying why when there is no equilibrium, nothing holds some body, or the scene is larger
    /// than `statics::MAX_CONVEXITY_CHECK` coordinates (not computed at start-up).
    fn modes_status(&self) -> DiagnosticStatus {
        use crate::solve::{modes::natural_modes, statics::StaticSolver};
        let model = self.sim.model();
        let warn = |why: String| self.status(1, "modes", why, vec![]);
        if model.dof_count > crate::solve::statics::MAX_CONVEXITY_CHECK {
            return warn(format!(
                "natural frequencies not computed at start-up: {} coordinates",
                model.dof_count
            ));
        }
        if let Some(note) = report::unheld_bodies_note(model) {
            return warn(format!("natural frequencies not computed: {note}"));
        }
        let mut state = crate::state::State::initial(model);
        let mut ws = Workspace::new(model);
        let Ok(eq) = StaticSolver::new(model).equilibrate(model, &mut state, &mut ws, &model.solver) else {
            return warn(
                "natural frequencies not computed: no equilibrium at the initial rest lengths".into(),
            );
        };
        let Some(modes) = natural_modes(model, &state) else {
            return warn("natural frequencies not computed: singular mass matrix".into());
        };
        let kv = |k: String, v: String| KeyValue { key: k, value: v };
        let zero = modes.iter().filter(|m| m.zero).count();
        let mut values = vec![kv("zero_frequency_modes".into(), zero.to_string())];
        for (i, m) in modes.iter().filter(|m| !m.zero).take(5).enumerate() {
            values.push(kv(format!("mode_{}_hz", i + 1), format!("{:.6}", m.frequency_hz)));
        }
        let message =
            format!("lowest natural frequencies at the initial equilibrium ({})", eq.stability_words());
        self.status(0, "modes", message, values)
    }

    // ----- inputs -------------------------------------------------------------------------------

    /// Takes one `ActuatorCommand` message (see `commands::check_command`): counts it, and either keeps
    /// its entries for the next step boundary or rejects it whole.
    pub fn offer_command(&mut self, m: &msg::ActuatorCommand) {
        let values = CommandArrays { rest_length: &m.rest_length, rate: &m.rate, tension: &[] };
        self.offer_arrays(&m.header.frame_id, &m.name, values);
    }

    /// Takes one `TensionCommand` message (winch actuators' tension mode), checked like an
    /// `ActuatorCommand`; `tension` must be parallel to `name`.
    pub fn offer_tension_command(&mut self, m: &msg::TensionCommand) {
        if m.tension.len() != m.name.len() {
            // an empty array would otherwise read as "nothing commanded"
            let e = MessageError::WrongLength { field: "tension", got: m.tension.len(), names: m.name.len() };
            let _ = self.offer_parsed(|_, _| Err(e));
            return;
        }
        let values = CommandArrays { tension: &m.tension, ..CommandArrays::default() };
        self.offer_arrays(&m.header.frame_id, &m.name, values);
    }

    /// Takes one `sensor_msgs/JointState` command, checked like an `ActuatorCommand`: position =
    /// target rest length, velocity = rate, effort ignored; with position and velocity both
    /// empty, effort = tension (winch actuators' tension mode, the ros2_control effort
    /// convention).
    pub fn offer_joint_command(&mut self, m: &msg::JointState) {
        let values = if m.position.is_empty() && m.velocity.is_empty() && !m.effort.is_empty() {
            CommandArrays { tension: &m.effort, ..CommandArrays::default() }
        } else {
            CommandArrays { rest_length: &m.position, rate: &m.velocity, tension: &[] }
        };
        self.offer_arrays(&m.header.frame_id, &m.name, values);
    }

    fn offer_arrays(&mut self, frame: &str, names: &[String], values: CommandArrays<'_>) {
        // counted and reported inside; the DDS paths have no one to tell
        let _ = self.offer_parsed(|model, out| commands::check_command(model, frame, names, values, out));
    }

    /// Takes one command message from a transport that reads its own wire format: `parse` fills
    /// `out` (empty on entry) with the message's checked entries (resolving actuators and then
    /// `commands::check_entry` for each, so every transport judges a command the same way) or says why
    /// the whole message is refused. Counted and reported like `offer_command`; accepted entries
    /// apply at the next step boundary. Returns the refusal, for transports that answer it.
    pub fn offer_parsed(
        &mut self,
        parse: impl FnOnce(&Model, &mut Vec<(ActuatorId, ActuatorCommand)>) -> Result<(), MessageError>,
    ) -> Result<(), MessageError> {
        self.stats.commands_received += 1;
        self.commands_this_step += 1;
        self.checked.clear();
        let result = parse(self.sim.model(), &mut self.checked);
        match &result {
            Ok(()) => {
                self.stats.commands_accepted += 1;
                for (id, cmd) in &self.checked {
                    self.unapplied[id.0] = Some(*cmd);
                }
            }
            Err(e) => {
                self.stats.commands_rejected += 1;
                self.rejections_unreported += 1;
                self.latest_rejection = commands::excerpt(&e.to_string(), 2 * commands::EXCERPT_CHARS);
            }
        }
        self.checked.clear();
        result
    }

    /// Counts an incoming sample that a transport could not read (malformed, wrong layout).
    pub fn incoming_malformed(&mut self) {
        self.stats.malformed_incoming += 1;
    }

    /// StepSimulation: `Ok(ticket)` when `steps` steps are queued (answered later through
    /// `NodeSink::step_request_done`, or at once if `steps` is 0), `Err(result)` to answer now
    /// (not paused, a request under way, or faulted).
    pub fn request_steps(&mut self, steps: u64, sink: &mut dyn NodeSink) -> Result<u64, SimResult> {
        let refuse = |code, why: &str| Err(SimResult::err(code, why));
        let r = if !self.paused {
            refuse(result_code::INCORRECT_STATE, "StepSimulation needs the simulation paused")
        } else if let Some(fault) = &self.fault {
            refuse(result_code::OPERATION_FAILED, &format!("physics failure (reset first): {fault}"))
        } else if self.step_request.is_some() {
            refuse(result_code::INCORRECT_STATE, "a StepSimulation request is still under way")
        } else {
            let ticket = self.next_ticket;
            self.next_ticket += 1;
            if steps == 0 {
                sink.step_request_done(ticket, SimResult::ok(), &self.view());
            } else {
                self.step_request = Some(StepRequest { ticket, requested: steps, remaining: steps });
            }
            Ok(ticket)
        };
        if r.is_err() {
            self.stats.step_requests_failed += 1;
        }
        r
    }

    /// Answers the request under way with a failure saying `why`.
    fn interrupt_step_request(&mut self, sink: &mut dyn NodeSink, why: &str) {
        if let Some(r) = self.step_request.take() {
            self.stats.step_requests_failed += 1;
            let done =
                format!("{why} after {} of {} requested steps", r.requested - r.remaining, r.requested);
            let result = SimResult::err(result_code::OPERATION_FAILED, done);
            sink.step_request_done(r.ticket, result, &self.view());
        }
    }

    /// Pauses or resumes. Resuming interrupts a StepSimulation request under way; resuming while
    /// faulted tries to step again from the last good state.
    pub fn set_paused(&mut self, paused: bool, sink: &mut dyn NodeSink) {
        if !paused {
            self.interrupt_step_request(sink, "unpaused");
            self.fault = None;
        }
        self.paused = paused;
    }

    /// Back to the initial state and time (actuators held again unless following the schedule,
    /// pending commands dropped, the fault cleared), and publishes that state and clock.
    pub fn reset(&mut self, sink: &mut dyn NodeSink) {
        self.reset_seeded(None, sink);
    }

    /// `reset`, with the new episode drawn from `seed` where given (a learning environment's
    /// `reset(seed)`): a randomized scene draws its model from it (`crate::scene::redraw_seeded`:
    /// seed `seed`, episode 0), whether it redraws per reset or not, and the sensors' streams
    /// start from it. Without a seed, a scene randomized per reset draws its next episode (after
    /// a seeded reset, `seed + 1`, `seed + 2`, ...), any other starts its current episode over,
    /// and the sensors start over with the node's seed.
    pub fn reset_seeded(&mut self, seed: Option<u64>, sink: &mut dyn NodeSink) {
        self.interrupt_step_request(sink, "reset");
        // a scene randomized per reset draws its next episode's model; any other starts over
        let redrawn = match (self.sim.model().randomization, seed) {
            (Some(_), Some(seed)) => {
                Some(self.redraw_from(crate::scene::redraw_seeded(self.sim.model(), seed)))
            }
            (Some(r), None) if r.per_reset => Some(self.redraw(r.episode + 1)),
            _ => None,
        };
        // a redrawn scene publishes its structure again: the new episode's draws
        let drew = redrawn.is_some();
        let redraw_failure = match redrawn {
            Some(Ok(sim)) => {
                self.sim = sim;
                self.reference =
                    report::all_pulley_coordinates(self.sim.model(), self.sim.state(), self.sim.workspace());
                self.constants = ConstantsId::fresh();
                None
            }
            Some(Err(e)) => {
                self.sim.reset();
                Some(e)
            }
            None => {
                self.sim.reset();
                None
            }
        };
        // the sensors start over with the same seed (a reset run reports what a fresh one does),
        // or with the episode's
        self.sensors =
            Sensors::new(self.sim.model(), seed.or(self.params.sensor_seed), self.sim.settings().dt);
        self.sensors.update(self.sim.model(), self.sim.state(), self.sim.workspace());
        sink.simulation_reset(self.sim.state().time, self.stats.steps, seed);
        self.steps_since_reset = 0;
        self.fault = None;
        if !self.params.follow_schedule {
            self.command_every_actuator(false);
        }
        self.unapplied.fill(None);
        self.previous_rest.copy_from_slice(&self.sim.state().rest_lengths);
        self.rates.fill(0.0);
        self.last_state_publish = None;
        self.last_markers = None;
        self.last_command = None;
        self.timed_out = false;
        self.anchor = None;
        if drew {
            self.publish(sink, Topic::Structure);
        }
        self.publish_state(sink);
        self.publish(sink, Topic::Clock);
        if let Some(e) = redraw_failure {
            self.physics_failure(sink, format!("the next episode's randomized scene: {e}"));
        }
    }

    /// The simulator of episode `episode` of a scene randomized per reset
    /// (`crate::scene::redraw`), started as the first was.
    fn redraw(&self, episode: u64) -> Result<Simulator, String> {
        self.redraw_from(crate::scene::redraw(self.sim.model(), episode))
    }

    /// The simulator of a model drawn anew (`drawn`), started as the first was.
    fn redraw_from(
        &self,
        drawn: Result<crate::model::Model, crate::error::SceneError>,
    ) -> Result<Simulator, String> {
        let model = drawn.map_err(|e| e.to_string())?;
        Simulator::start(model, *self.sim.settings(), self.params.start_from_equilibrium)
            .map_err(|e| e.to_string())
    }

    /// SetSimulationState: PLAYING, PAUSED, STOPPED (reset and pause) or QUITTING.
    pub fn set_simulation_state(&mut self, state: u8, sink: &mut dyn NodeSink) -> SimResult {
        if state == self.simulation_state() {
            return SimResult::err(result_code::ALREADY_IN_TARGET_STATE, "already in that state");
        }
        match state {
            sim_state::PLAYING => self.set_paused(false, sink),
            sim_state::PAUSED => self.set_paused(true, sink),
            sim_state::STOPPED => {
                self.paused = true;
                self.reset(sink);
            }
            sim_state::QUITTING => {
                self.interrupt_step_request(sink, "quitting");
                self.quit = true;
            }
            other => return SimResult::err(result_code::OPERATION_FAILED, format!("unknown state {other}")),
        }
        SimResult::ok()
    }

    /// What GetSimulatorFeatures answers.
    pub fn features() -> msg::SimulatorFeatures {
        msg::SimulatorFeatures {
            features: vec![20, 21, 22, 24, 25, 26, 31, 32],
            spawn_formats: vec![],
            custom_info: "tensegrity: clustered tensegrity multibody simulator".into(),
        }
    }

    /// The node is stopping (SIGINT, SIGTERM): answers a pending StepSimulation request.
    pub fn shutdown(&mut self, sink: &mut dyn NodeSink) {
        self.interrupt_step_request(sink, "the node is shutting down");
    }

    // ----- the loop -----------------------------------------------------------------------------

    /// One turn of the node's loop at wall time `now` (since any fixed epoch): applies the
    /// commands taken since the last turn, takes one step if playing or a StepSimulation request
    /// is under way, publishes what is due, and returns the wall time at which it wants the next
    /// turn (`None`: at once).
    pub fn tick(&mut self, now: Duration, sink: &mut dyn NodeSink) -> Option<Duration> {
        self.commands_this_step = 0;
        self.window.get_or_insert((now, self.sim.state().time));
        self.apply_commands(sink);
        let wake = if self.paused && self.step_request.is_none() {
            self.anchor = None;
            Some(now + IDLE_PERIOD)
        } else if self.paused {
            // lockstep: one requested step per turn, no pacing
            if self.step(sink) {
                if let Some(r) = &mut self.step_request {
                    r.remaining -= 1;
                    if r.remaining == 0 {
                        let ticket = r.ticket;
                        self.step_request = None;
                        sink.step_request_done(ticket, SimResult::ok(), &self.view());
                    }
                }
            }
            None
        } else if !self.step(sink) {
            Some(now + IDLE_PERIOD)
        } else {
            self.pace(now)
        };
        self.report(now, sink);
        wake
    }

    /// Real-time pacing after a step taken at wall time `now`.
    fn pace(&mut self, now: Duration) -> Option<Duration> {
        let rtf = self.params.real_time_factor;
        if rtf <= 0.0 {
            return None;
        }
        let dt = self.sim.settings().dt;
        let t = self.sim.state().time;
        let (wall0, sim0) = *self.anchor.get_or_insert((now, t - dt));
        let due = wall0 + Duration::from_secs_f64(((t - sim0) / rtf).max(0.0));
        if now > due + Duration::from_secs_f64(dt / rtf) {
            // late by more than a step: count it and re-anchor instead of bursting
            self.stats.overruns += 1;
            self.anchor = Some((now, t));
            None
        } else {
            Some(due)
        }
    }

    fn apply_commands(&mut self, sink: &mut dyn NodeSink) {
        self.applied.clear();
        for (i, slot) in self.unapplied.iter_mut().enumerate() {
            if let Some(cmd) = slot.take() {
                self.applied.push((ActuatorId(i), cmd));
            }
        }
        if self.applied.is_empty() {
            return;
        }
        for &(id, cmd) in &self.applied {
            // checked against the same model when it arrived: cannot fail
            let applied = self.sim.command_actuator(id, cmd);
            debug_assert!(applied.is_ok());
        }
        self.last_command = Some(self.sim.state().time);
        self.timed_out = false;
        sink.commands_applied(self.sim.state().time, self.stats.steps, &self.applied);
    }

    /// One physics step and what it publishes; false (and faulted) when it failed.
    fn step(&mut self, sink: &mut dyn NodeSink) -> bool {
        self.previous_rest.copy_from_slice(&self.sim.state().rest_lengths);
        match self.sim.step() {
            Ok(stats) => {
                self.last_step = stats;
                self.stats.last_newton_iterations = stats.newton_iterations;
                self.stats.longest_step = self.stats.longest_step.max(stats.wall_time);
                self.stats.rejected_attempts += stats.rejected;
            }
            Err(e) => {
                self.physics_failure(sink, e.to_string());
                return false;
            }
        }
        if !self.outputs_finite() {
            self.physics_failure(sink, "the state is not finite".into());
            return false;
        }
        if !self.sensors.is_empty() {
            self.sensors.update(self.sim.model(), self.sim.state(), self.sim.workspace());
        }
        self.stats.steps += 1;
        self.steps_since_reset += 1;
        let dt = self.sim.settings().dt;
        for (r, (now, before)) in
            self.rates.iter_mut().zip(self.sim.state().rest_lengths.iter().zip(&self.previous_rest))
        {
            *r = (now - before) / dt;
        }
        let t = self.sim.state().time;
        let due = |rate: f64, last: Option<f64>| match last {
            Some(last) if rate > 0.0 => t - last >= 1.0 / rate - 1e-9 * dt,
            _ => true,
        };
        if due(self.params.state_publish_rate, self.last_state_publish) {
            self.publish_state(sink);
        }
        if self.params.markers_rate > 0.0 && due(self.params.markers_rate, self.last_markers) {
            self.publish(sink, Topic::Markers);
            self.last_markers = Some(t);
        }
        self.check_command_timeout();
        self.publish(sink, Topic::Clock);
        true
    }

    /// True when every number a sink may read is finite.
    fn outputs_finite(&self) -> bool {
        self.sim.state().is_finite()
            && self.sim.workspace().cables.iter().all(|c| c.tension.is_finite() && c.length.is_finite())
    }

    fn physics_failure(&mut self, sink: &mut dyn NodeSink, cause: String) {
        self.stats.physics_failures += 1;
        let step = self.stats.steps + 1;
        let message = format!(
            "physics failure at step {step} (t = {:.6} s): {cause}; paused at the last good state, reset to recover",
            self.sim.state().time
        );
        self.paused = true;
        self.interrupt_step_request(sink, "physics failure");
        self.fault = Some(message.clone());
        let status = self.status(2, "simulation", message, vec![]);
        self.statuses.push(status);
        self.publish(sink, Topic::Diagnostics);
        self.statuses.clear();
    }

    /// Once no command has been accepted for `command_timeout` s of sim time (after the first
    /// one): `hold` stops every winch where it is, `initial` sends them back. Counted, reported.
    fn check_command_timeout(&mut self) {
        let timeout = self.params.command_timeout;
        let Some(last) = self.last_command else { return };
        if timeout <= 0.0 || self.timed_out || self.sim.state().time - last < timeout {
            return;
        }
        self.timed_out = true;
        self.stats.command_timeouts += 1;
        let initial = self.params.command_timeout_action == "initial";
        self.command_every_actuator(initial);
        self.latest_rejection.clear();
        let message = format!("command timeout after {timeout} s: {}", self.params.command_timeout_action);
        let status = self.status(1, "commands", message, vec![]);
        self.pending_status(status);
    }

    /// Commands every actuator to its initial rest length (`to_initial`) or to where it is now.
    fn command_every_actuator(&mut self, to_initial: bool) {
        for i in 0..self.sim.model().actuators.len() {
            let m = self.sim.model();
            let c = m.actuators[i].cable.0;
            let l = if to_initial { m.initial_rest_lengths[c] } else { self.sim.state().rest_lengths[c] };
            // a rest length inside the limits, at the default rate: always valid
            let _ = self.sim.command_actuator(ActuatorId(i), ActuatorCommand::target(l));
        }
    }

    // ----- outputs ------------------------------------------------------------------------------

    /// What a sink may read now (also for transports answering requests outside `tick`).
    pub fn view(&self) -> NodeView<'_> {
        NodeView {
            model: self.sim.model(),
            state: self.sim.state(),
            workspace: self.sim.workspace(),
            rates: &self.rates,
            reference: &self.reference,
            frame_id: &self.params.frame_id,
            node_name: &self.params.node_name,
            constants: self.constants,
            diagnostics: &self.statuses,
            step: self.steps_since_reset,
            simulation_state: self.simulation_state(),
            faulted: self.fault.is_some(),
            stats: self.stats,
            dt: self.sim.settings().dt,
            measured: self.sensors.measured(),
            lost: self.sensors.lost(),
            imu_truth: self.sensors.imu_truth(),
        }
    }

    /// Publishes `topic`; a failure is counted, never fatal.
    fn publish(&mut self, sink: &mut dyn NodeSink, topic: Topic) {
        if sink.publish(topic, &self.view()).is_err() {
            self.stats.publish_failures[topic.index()] += 1;
        }
    }

    /// The state topics (`Topic::STATE`).
    fn publish_state(&mut self, sink: &mut dyn NodeSink) {
        for topic in Topic::STATE {
            if topic.published_by(self.sim.model()) {
                self.publish(sink, topic);
            }
        }
        self.last_state_publish = Some(self.sim.state().time);
    }

    fn status(&self, level: u8, what: &str, message: String, values: Vec<KeyValue>) -> DiagnosticStatus {
        DiagnosticStatus {
            level,
            name: format!("{}: {what}", self.params.node_name),
            message,
            hardware_id: self.params.node_name.clone(),
            values,
        }
    }

    fn pending_status(&mut self, status: DiagnosticStatus) {
        self.statuses.push(status);
    }

    /// Rate-limited rejection reports, queued statuses, and the periodic status.
    fn report(&mut self, now: Duration, sink: &mut dyn NodeSink) {
        let min_gap = DIAGNOSTICS_PERIOD / MAX_REJECTION_REPORTS_PER_SECOND;
        let rejection_due = self.rejections_unreported > 0
            && self.last_rejection_report.is_none_or(|last| now >= last + min_gap);
        if rejection_due {
            let n = self.rejections_unreported;
            let message = format!(
                "{n} command{} rejected since the last report; latest: {}",
                if n == 1 { "" } else { "s" },
                self.latest_rejection
            );
            let values = vec![
                KeyValue { key: "commands_rejected".into(), value: self.stats.commands_rejected.to_string() },
                KeyValue { key: "rejected_since_last_report".into(), value: n.to_string() },
            ];
            let status = self.status(1, "commands", message, values);
            self.pending_status(status);
            self.rejections_unreported = 0;
            self.last_rejection_report = Some(now);
        }
        let (wall0, sim0) = *self.window.get_or_insert((now, self.sim.state().time));
        let periodic = now >= wall0 + DIAGNOSTICS_PERIOD;
        if periodic {
            let wall = (now - wall0).as_secs_f64();
            let rtf = if wall > 0.0 { (self.sim.state().time - sim0) / wall } else { 0.0 };
            let status = self.periodic_status(rtf);
            self.pending_status(status);
            self.window = Some((now, self.sim.state().time));
        }
        if !self.statuses.is_empty() {
            self.publish(sink, Topic::Diagnostics);
            self.statuses.clear();
        }
    }

    /// The 1 Hz status: real-time factor over the last period, counters, solver effort, faults.
    fn periodic_status(&self, real_time_factor: f64) -> DiagnosticStatus {
        let s = &self.stats;
        let kv = |k: &str, v: String| KeyValue { key: k.into(), value: v };
        let mut values = vec![
            kv("sim_time", format!("{:.6}", self.sim.state().time)),
            kv("real_time_factor", format!("{real_time_factor:.3}")),
            kv("steps", s.steps.to_string()),
            kv("overruns", s.overruns.to_string()),
            kv("commands_received", s.commands_received.to_string()),
            kv("commands_accepted", s.commands_accepted.to_string()),
            kv("commands_rejected", s.commands_rejected.to_string()),
            kv("newton_iterations_last_step", s.last_newton_iterations.to_string()),
            kv("longest_step_us", format!("{:.1}", 1e6 * s.longest_step.as_secs_f64())),
            kv("rejected_step_attempts", s.rejected_attempts.to_string()),
            kv("command_timeouts", s.command_timeouts.to_string()),
            kv("malformed_incoming", s.malformed_incoming.to_string()),
            kv("step_requests_failed", s.step_requests_failed.to_string()),
            kv("physics_failures", s.physics_failures.to_string()),
            kv("steps_remaining", self.steps_remaining().to_string()),
        ];
        for topic in Topic::ALL {
            let n = s.publish_failures_on(topic);
            if n > 0 {
                values.push(kv(&format!("publish_failures {}", topic.name()), n.to_string()));
            }
        }
        let transport_trouble = s.publish_failures.iter().any(|n| *n > 0) || s.malformed_incoming > 0;
        let (level, message) = match &self.fault {
            Some(f) => (2, f.clone()),
            None => (
                u8::from(s.commands_rejected > 0 || s.overruns > 0 || transport_trouble),
                if self.step_request.is_some() {
                    "stepping on request".into()
                } else if self.paused {
                    "paused".into()
                } else {
                    "running".into()
                },
            ),
        };
        self.status(level, "simulation", message, values)
    }
}
