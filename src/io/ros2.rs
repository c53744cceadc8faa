//! The ROS 2 node (feature `ros2`): takes a `Model` and `NodeParams`, gives a node that steps the
//! simulation in real time (or as fast as possible, or only on request while paused), applies
//! actuator commands at step boundaries, and publishes the clock, body poses, transforms, cable
//! and actuator states, the structure and diagnostics over DDS (ros2-client).
//!
//! Every message of a step carries that step's simulation time, and state is published before the
//! clock tick. Commands are validated as whole messages; a rejected one is counted, reported in
//! `/diagnostics`, and changes nothing. Services (in the node's private namespace):
//! simulation_interfaces 2.1 StepSimulation (only while paused; responds after the steps),
//! ResetSimulation, GetSimulationState, SetSimulationState, GetSimulatorFeatures, and std_srvs
//! Empty `pause`, `unpause`, `reset`. Overruns (steps that finish later than real time allows)
//! are counted, never caught up in bursts. Nothing non-finite is ever published: the physics never
//! lets a NaN into its state, and the cable message is checked again before it leaves.

use std::net::Ipv4Addr;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use ros2_client::dds::rustdds::DomainParticipantBuilder;
use ros2_client::qos::{Durability, History, WhenFull};
use ros2_client::{
    Context, ContextOptions, Message, MessageTypeName, Name, Node, NodeName, NodeOptions, Publisher,
    QosProfile, Server, ServiceMapping, ServiceTypeName, Subscription,
};

use crate::control::ActuatorCommand as Command;
use crate::io::msg::{self, Header, Time};
use crate::io::params::NodeParams;
use crate::model::Model;
use crate::report;
use crate::sim::{SimSettings, Simulator, StepError};
use crate::solve::dynamics::Integrator;

/// Why the node could not start or stopped.
#[derive(Debug, thiserror::Error)]
pub enum NodeError {
    /// DDS or ROS entity creation failed.
    #[error("ROS 2: {0}")]
    Ros(String),
    /// The simulation could not start or step.
    #[error(transparent)]
    Step(#[from] StepError),
}

fn ros<E: std::fmt::Debug>(e: E) -> NodeError {
    NodeError::Ros(format!("{e:?}"))
}

/// Counters reported in `/diagnostics`.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct NodeStats {
    /// Physics steps taken.
    pub steps: u64,
    /// Steps that ended later than real-time pacing allowed.
    pub overruns: u64,
    /// Command messages received.
    pub commands_received: u64,
    /// Command messages rejected (non-finite, out of range, unknown name, wrong length).
    pub commands_rejected: u64,
    /// Newton iterations of the last step.
    pub last_newton_iterations: usize,
    /// Rejected step attempts so far.
    pub rejected_attempts: usize,
    /// Times the command timeout fired.
    pub command_timeouts: u64,
}

struct Publishers {
    clock: Publisher<msg::Clock>,
    poses: Publisher<msg::PoseArray>,
    cables: Publisher<msg::CableStates>,
    actuators: Publisher<msg::JointState>,
    structure: Publisher<msg::Structure>,
    tf: Publisher<msg::TfMessage>,
    tf_static: Publisher<msg::TfMessage>,
    diagnostics: Publisher<msg::DiagnosticArray>,
    markers: Publisher<msg::MarkerArray>,
}

impl Message for msg::Empty {}
impl Message for msg::StepSimulationRequest {}
impl Message for msg::ResultResponse {}
impl Message for msg::ResetSimulationRequest {}
impl Message for msg::GetSimulationStateResponse {}
impl Message for msg::SetSimulationStateRequest {}
impl Message for msg::GetSimulatorFeaturesResponse {}

/// `SimulationState` codes.
const STOPPED: u8 = 0;
const PLAYING: u8 = 1;
const PAUSED: u8 = 2;
const QUITTING: u8 = 3;
/// `Result` codes.
const INCORRECT_STATE: u8 = 3;
const OPERATION_FAILED: u8 = 4;
const ALREADY_IN_TARGET_STATE: u8 = 101;

struct Services {
    step: Server<msg::StepSimulationRequest, msg::ResultResponse>,
    reset: Server<msg::ResetSimulationRequest, msg::ResultResponse>,
    get_state: Server<msg::Empty, msg::GetSimulationStateResponse>,
    set_state: Server<msg::SetSimulationStateRequest, msg::ResultResponse>,
    features: Server<msg::Empty, msg::GetSimulatorFeaturesResponse>,
    pause: Server<msg::Empty, msg::Empty>,
    unpause: Server<msg::Empty, msg::Empty>,
    reset_empty: Server<msg::Empty, msg::Empty>,
}

/// The simulator as a ROS 2 node. Start it in-process with `SimNode::new` and drive it with
/// `run` (paced loop) or `spin_once` / `step_and_publish` (tests, lockstep).
pub struct SimNode {
    sim: Simulator,
    params: NodeParams,
    reference: Vec<Vec<f64>>,
    previous_rest: Vec<f64>,
    rates: Vec<f64>,
    paused: bool,
    stats: NodeStats,
    last_state_publish: Option<f64>,
    last_diagnostics: Instant,
    publishers: Publishers,
    commands: Subscription<msg::ActuatorCommand>,
    joint_commands: Subscription<msg::JointState>,
    services: Services,
    quit: bool,
    last_markers: Option<f64>,
    last_command: Option<f64>,
    timed_out: bool,
    // keep the DDS entities alive as long as the node
    _node: Node,
    _context: Context,
}

/// Commands every actuator to a rest-length target: its initial rest length when `to_initial`,
/// else the rest length it has now (the winch holds where it is). `why` names the cause in errors.
fn command_every_actuator(sim: &mut Simulator, to_initial: bool, why: &str) -> Result<(), NodeError> {
    let targets: Vec<(String, f64)> = (0..sim.model().actuators.len())
        .map(|i| {
            let m = sim.model();
            let c = m.actuators[i].cable.0;
            let l = if to_initial { m.initial_rest_lengths[c] } else { sim.state().rest_lengths[c] };
            (m.actuator_names[i].clone(), l)
        })
        .collect();
    for (name, l) in targets {
        sim.command(&name, Command { rest_length: Some(l), rate: None })
            .map_err(|e| NodeError::Ros(format!("{why} {name}: {e}")))?;
    }
    Ok(())
}

/// A DDS context on `domain_id`, bound to 127.0.0.1 when `localhost_only`.
pub fn context(domain_id: u16, localhost_only: bool) -> Result<Context, NodeError> {
    if localhost_only {
        let participant = DomainParticipantBuilder::new(domain_id)
            .with_only_networks([Ipv4Addr::LOCALHOST])
            .build()
            .map_err(ros)?;
        Context::from_domain_participant(participant).map_err(ros)
    } else {
        Context::with_options(ContextOptions::new().domain_id(domain_id)).map_err(ros)
    }
}

/// QoS: reliable, keep last `depth`, volatile or transient local.
pub fn qos(depth: usize, transient_local: bool) -> QosProfile {
    QosProfile::publisher_default()
        .reliability_reliable(WhenFull::Wait(Duration::from_millis(20)))
        .durability(if transient_local { Durability::TransientLocal } else { Durability::Volatile })
        .history(History::KeepLast { depth })
}

/// The namespace of the node's private (`~/`) topics: `<ns>/<node>`.
pub fn private_namespace(params: &NodeParams) -> String {
    format!("{}/{}", params.namespace.trim_end_matches('/'), params.node_name)
}

impl SimNode {
    /// Builds the simulator and the node, and publishes the structure and static transforms.
    pub fn new(model: Model, params: NodeParams) -> Result<Self, NodeError> {
        let integrator = Integrator::parse(&params.integrator, params.rho_inf)
            .ok_or_else(|| NodeError::Ros(format!("unknown integrator '{}'", params.integrator)))?;
        let dt = params.physics_dt.or(model.physics_dt).unwrap_or(1e-3);
        let mut sim = Simulator::new(model, SimSettings { dt, integrator, ..Default::default() })?;
        if !params.follow_schedule {
            command_every_actuator(&mut sim, false, "holding")?;
        }
        let context = context(params.domain_id, params.localhost_only)?;
        let mut node = context
            .new_node(NodeName::new(&params.namespace, &params.node_name).map_err(ros)?, NodeOptions::new())
            .map_err(ros)?;
        let private = private_namespace(&params);
        let topic = |ns: &str, name: &str, pkg: &str, ty: &str, q: &QosProfile| {
            node.create_topic(&Name::new(ns, name).map_err(ros)?, MessageTypeName::new(pkg, ty), q)
                .map_err(ros)
        };
        let t_clock = topic("/", "clock", "rosgraph_msgs", "Clock", &qos(1, false))?;
        let t_tf = topic("/", "tf", "tf2_msgs", "TFMessage", &qos(100, false))?;
        let t_tf_static = topic("/", "tf_static", "tf2_msgs", "TFMessage", &qos(1, true))?;
        let t_poses = topic(&private, "body_poses", "geometry_msgs", "PoseArray", &qos(10, false))?;
        let t_cables = topic(&private, "cable_states", "tensegrity_msgs", "CableStates", &qos(10, false))?;
        let t_actuators = topic(&private, "actuator_states", "sensor_msgs", "JointState", &qos(10, false))?;
        let t_structure = topic(&private, "structure", "tensegrity_msgs", "Structure", &qos(1, true))?;
        let t_markers = topic(&private, "markers", "visualization_msgs", "MarkerArray", &qos(1, false))?;
        let t_diag = topic("/", "diagnostics", "diagnostic_msgs", "DiagnosticArray", &qos(10, false))?;
        let t_cmd =
            topic(&private, "actuator_commands", "tensegrity_msgs", "ActuatorCommand", &qos(1, false))?;
        let t_joint_cmd = topic(&private, "joint_commands", "sensor_msgs", "JointState", &qos(1, false))?;
        let publishers = Publishers {
            clock: node.create_publisher(&t_clock, None).map_err(ros)?,
            poses: node.create_publisher(&t_poses, None).map_err(ros)?,
            cables: node.create_publisher(&t_cables, None).map_err(ros)?,
            actuators: node.create_publisher(&t_actuators, None).map_err(ros)?,
            structure: node.create_publisher(&t_structure, None).map_err(ros)?,
            tf: node.create_publisher(&t_tf, None).map_err(ros)?,
            tf_static: node.create_publisher(&t_tf_static, None).map_err(ros)?,
            diagnostics: node.create_publisher(&t_diag, None).map_err(ros)?,
            markers: node.create_publisher(&t_markers, None).map_err(ros)?,
        };
        let mapping = match params.service_mapping.as_str() {
            "cyclone" => ServiceMapping::Cyclone,
            "basic" => ServiceMapping::Basic,
            _ => ServiceMapping::Enhanced,
        };
        let service_qos = qos(10, false);
        macro_rules! server {
            ($name:expr, $pkg:expr, $ty:expr) => {
                node.create_server(
                    mapping,
                    &Name::new(&private, $name).map_err(ros)?,
                    &ServiceTypeName::new($pkg, $ty),
                    service_qos.clone(),
                    service_qos.clone(),
                )
                .map_err(ros)?
            };
        }
        let services = Services {
            step: server!("step_simulation", "simulation_interfaces", "StepSimulation"),
            reset: server!("reset_simulation", "simulation_interfaces", "ResetSimulation"),
            get_state: server!("get_simulation_state", "simulation_interfaces", "GetSimulationState"),
            set_state: server!("set_simulation_state", "simulation_interfaces", "SetSimulationState"),
            features: server!("get_simulator_features", "simulation_interfaces", "GetSimulatorFeatures"),
            pause: server!("pause", "std_srvs", "Empty"),
            unpause: server!("unpause", "std_srvs", "Empty"),
            reset_empty: server!("reset", "std_srvs", "Empty"),
        };
        let commands = node.create_subscription(&t_cmd, None).map_err(ros)?;
        let joint_commands = node.create_subscription(&t_joint_cmd, None).map_err(ros)?;
        let reference = report::all_pulley_coordinates(sim.model(), sim.state(), sim.workspace());
        let previous_rest = sim.state().rest_lengths.clone();
        let n_cables = previous_rest.len();
        let mut this = Self {
            paused: params.start_paused,
            sim,
            params,
            reference,
            previous_rest,
            rates: vec![0.0; n_cables],
            stats: NodeStats::default(),
            last_state_publish: None,
            last_diagnostics: Instant::now(),
            publishers,
            commands,
            joint_commands,
            services,
            quit: false,
            last_markers: None,
            last_command: None,
            timed_out: false,
            _node: node,
            _context: context,
        };
        let structure = msg::Structure::from_model(this.sim.model(), &this.params.frame_id);
        this.publishers.structure.publish(structure).map_err(ros)?;
        let fixed =
            msg::TfMessage::from_state(this.sim.model(), this.sim.state(), &this.params.frame_id, true);
        this.publishers.tf_static.publish(fixed).map_err(ros)?;
        this.publish_state()?;
        Ok(this)
    }

    /// The simulator (read-only).
    pub fn simulator(&self) -> &Simulator {
        &self.sim
    }
    /// Counters.
    pub fn stats(&self) -> NodeStats {
        self.stats
    }
    /// True while paused.
    pub fn paused(&self) -> bool {
        self.paused
    }
    /// Pauses or resumes real-time stepping.
    pub fn set_paused(&mut self, paused: bool) {
        self.paused = paused;
    }

    /// Back to the initial state and time (actuators held again unless following the schedule),
    /// and publishes that state.
    pub fn reset(&mut self) -> Result<(), NodeError> {
        self.sim.reset();
        if !self.params.follow_schedule {
            command_every_actuator(&mut self.sim, false, "holding")?;
        }
        self.previous_rest.copy_from_slice(&self.sim.state().rest_lengths);
        self.rates.fill(0.0);
        self.last_state_publish = None;
        self.last_markers = None;
        self.last_command = None;
        self.timed_out = false;
        self.publish_state()?;
        self.publishers
            .clock
            .publish(msg::Clock { clock: Time::from_seconds(self.sim.state().time) })
            .map_err(ros)
    }

    /// True once SetSimulationState asked for QUITTING.
    pub fn quit_requested(&self) -> bool {
        self.quit
    }

    /// Answers every pending service request: StepSimulation (only while paused; steps, publishes,
    /// then responds), ResetSimulation, Get/SetSimulationState, GetSimulatorFeatures, and the
    /// std_srvs pause/unpause/reset.
    pub fn serve(&mut self) -> Result<(), NodeError> {
        let sv = &self.services;
        let steps: Vec<_> = std::iter::from_fn(|| sv.step.receive_request().ok().flatten()).collect();
        let resets: Vec<_> = std::iter::from_fn(|| sv.reset.receive_request().ok().flatten()).collect();
        let gets: Vec<_> = std::iter::from_fn(|| sv.get_state.receive_request().ok().flatten()).collect();
        let sets: Vec<_> = std::iter::from_fn(|| sv.set_state.receive_request().ok().flatten()).collect();
        let feats: Vec<_> = std::iter::from_fn(|| sv.features.receive_request().ok().flatten()).collect();
        let pauses: Vec<_> = std::iter::from_fn(|| sv.pause.receive_request().ok().flatten()).collect();
        let unpauses: Vec<_> = std::iter::from_fn(|| sv.unpause.receive_request().ok().flatten()).collect();
        let empties: Vec<_> =
            std::iter::from_fn(|| sv.reset_empty.receive_request().ok().flatten()).collect();
        for (id, req) in steps {
            let result = if !self.paused {
                msg::SimResult::err(INCORRECT_STATE, "StepSimulation needs the simulation paused")
            } else {
                let mut r = msg::SimResult::ok();
                for _ in 0..req.steps {
                    if let Err(e) = self.step_and_publish() {
                        r = msg::SimResult::err(OPERATION_FAILED, e.to_string());
                        break;
                    }
                }
                r
            };
            let _ = self.services.step.send_response(id, msg::ResultResponse { result });
        }
        for (id, _) in resets {
            let result = match self.reset() {
                Ok(()) => msg::SimResult::ok(),
                Err(e) => msg::SimResult::err(OPERATION_FAILED, e.to_string()),
            };
            let _ = self.services.reset.send_response(id, msg::ResultResponse { result });
        }
        for (id, _) in gets {
            let state = msg::SimulationState { state: if self.paused { PAUSED } else { PLAYING } };
            let response = msg::GetSimulationStateResponse { state, result: msg::SimResult::ok() };
            let _ = self.services.get_state.send_response(id, response);
        }
        for (id, req) in sets {
            let current = if self.paused { PAUSED } else { PLAYING };
            let result = match req.state.state {
                s if s == current => msg::SimResult::err(ALREADY_IN_TARGET_STATE, "already in that state"),
                PLAYING => {
                    self.paused = false;
                    msg::SimResult::ok()
                }
                PAUSED => {
                    self.paused = true;
                    msg::SimResult::ok()
                }
                STOPPED => {
                    self.paused = true;
                    match self.reset() {
                        Ok(()) => msg::SimResult::ok(),
                        Err(e) => msg::SimResult::err(OPERATION_FAILED, e.to_string()),
                    }
                }
                QUITTING => {
                    self.quit = true;
                    msg::SimResult::ok()
                }
                other => msg::SimResult::err(OPERATION_FAILED, format!("unknown state {other}")),
            };
            let _ = self.services.set_state.send_response(id, msg::ResultResponse { result });
        }
        for (id, _) in feats {
            let features = msg::SimulatorFeatures {
                features: vec![20, 21, 22, 24, 25, 26, 31, 32],
                spawn_formats: vec![],
                custom_info: "tensegrity: clustered tensegrity multibody simulator".into(),
            };
            let _ = self.services.features.send_response(id, msg::GetSimulatorFeaturesResponse { features });
        }
        for (id, _) in pauses {
            self.paused = true;
            let _ = self.services.pause.send_response(id, msg::Empty::default());
        }
        for (id, _) in unpauses {
            self.paused = false;
            let _ = self.services.unpause.send_response(id, msg::Empty::default());
        }
        for (id, _) in empties {
            self.reset()?;
            let _ = self.services.reset_empty.send_response(id, msg::Empty::default());
        }
        Ok(())
    }

    /// Takes every pending command message and applies the valid ones (at this step boundary).
    pub fn take_commands(&mut self) {
        let mut messages = Vec::new();
        while let Ok(Some((m, _))) = self.commands.take() {
            messages.push(m);
        }
        while let Ok(Some((m, _))) = self.joint_commands.take() {
            messages.push(m.as_command());
        }
        for m in messages {
            self.stats.commands_received += 1;
            match m.commands(self.sim.model()) {
                Ok(cmds) => {
                    self.last_command = Some(self.sim.state().time);
                    self.timed_out = false;
                    for (name, cmd) in cmds {
                        // validated above against the same model: cannot fail
                        let _ = self.sim.command(&name, cmd);
                    }
                }
                Err(e) => {
                    self.stats.commands_rejected += 1;
                    self.report_rejection(&e.to_string());
                }
            }
        }
    }

    fn report_rejection(&mut self, reason: &str) {
        let count = msg::KeyValue {
            key: "commands_rejected".into(),
            value: self.stats.commands_rejected.to_string(),
        };
        self.warn_commands(format!("rejected command: {reason}"), vec![count]);
    }

    /// Publishes a WARN `/diagnostics` status about commands at once (best effort).
    fn warn_commands(&mut self, message: String, values: Vec<msg::KeyValue>) {
        let status = msg::DiagnosticStatus {
            level: 1,
            name: format!("{}: commands", self.params.node_name),
            message,
            hardware_id: self.params.node_name.clone(),
            values,
        };
        let _ = self
            .publishers
            .diagnostics
            .publish(msg::DiagnosticArray { header: self.header(), status: vec![status] });
    }

    fn header(&self) -> Header {
        Header { stamp: Time::from_seconds(self.sim.state().time), frame_id: self.params.frame_id.clone() }
    }

    /// One physics step, then (at the state publish rate) the state, then the clock.
    pub fn step_and_publish(&mut self) -> Result<(), NodeError> {
        self.previous_rest.copy_from_slice(&self.sim.state().rest_lengths);
        let stats = self.sim.step()?;
        self.stats.steps += 1;
        self.stats.last_newton_iterations = stats.newton_iterations;
        self.stats.rejected_attempts += stats.rejected;
        let dt = self.sim.settings().dt;
        for (r, (now, before)) in
            self.rates.iter_mut().zip(self.sim.state().rest_lengths.iter().zip(&self.previous_rest))
        {
            *r = (now - before) / dt;
        }
        let t = self.sim.state().time;
        let due = match (self.params.state_publish_rate, self.last_state_publish) {
            (r, Some(last)) if r > 0.0 => t - last >= 1.0 / r - 1e-9 * dt,
            _ => true,
        };
        if due {
            self.publish_state()?;
        }
        let markers_due = match (self.params.markers_rate, self.last_markers) {
            (r, _) if r <= 0.0 => false,
            (r, Some(last)) => t - last >= 1.0 / r - 1e-9 * dt,
            (_, None) => true,
        };
        if markers_due {
            let (model, state, ws) = (self.sim.model(), self.sim.state(), self.sim.workspace());
            let markers = msg::MarkerArray::from_state(model, state, ws, &self.params.frame_id);
            self.publishers.markers.publish(markers).map_err(ros)?;
            self.last_markers = Some(t);
        }
        self.check_command_timeout()?;
        self.publishers.clock.publish(msg::Clock { clock: Time::from_seconds(t) }).map_err(ros)?;
        Ok(())
    }

    /// Takes the configured action once no command has been accepted for `command_timeout`
    /// seconds of sim time (after the first command): `hold` stops every winch where it is,
    /// `initial` sends them back to their initial rest lengths. Counted and reported.
    fn check_command_timeout(&mut self) -> Result<(), NodeError> {
        let timeout = self.params.command_timeout;
        let Some(last) = self.last_command else { return Ok(()) };
        if timeout <= 0.0 || self.timed_out || self.sim.state().time - last < timeout {
            return Ok(());
        }
        self.timed_out = true;
        self.stats.command_timeouts += 1;
        let initial = self.params.command_timeout_action == "initial";
        command_every_actuator(&mut self.sim, initial, "command timeout on")?;
        let message = format!("command timeout after {timeout} s: {}", self.params.command_timeout_action);
        self.warn_commands(message, vec![]);
        Ok(())
    }

    /// Publishes poses, transforms, cable and actuator states for the current step.
    pub fn publish_state(&mut self) -> Result<(), NodeError> {
        let (model, state, ws) = (self.sim.model(), self.sim.state(), self.sim.workspace());
        let frame = &self.params.frame_id;
        let cables = msg::CableStates::from_state(model, state, ws, &self.reference, frame);
        if !cables.is_finite() {
            return Err(NodeError::Ros("refusing to publish non-finite cable states".into()));
        }
        self.publishers.poses.publish(msg::PoseArray::from_state(state, frame)).map_err(ros)?;
        self.publishers.tf.publish(msg::TfMessage::from_state(model, state, frame, false)).map_err(ros)?;
        self.publishers.cables.publish(cables).map_err(ros)?;
        self.publishers
            .actuators
            .publish(msg::JointState::actuators(model, state, ws, &self.rates))
            .map_err(ros)?;
        self.last_state_publish = Some(state.time);
        Ok(())
    }

    /// Publishes `/diagnostics` now: real-time factor over the last interval, counters, solver.
    pub fn publish_diagnostics(&mut self, real_time_factor: f64) -> Result<(), NodeError> {
        let s = self.stats;
        let kv = |k: &str, v: String| msg::KeyValue { key: k.into(), value: v };
        let status = msg::DiagnosticStatus {
            level: if s.commands_rejected > 0 || s.overruns > 0 { 1 } else { 0 },
            name: format!("{}: simulation", self.params.node_name),
            message: if self.paused { "paused".into() } else { "running".into() },
            hardware_id: self.params.node_name.clone(),
            values: vec![
                kv("sim_time", format!("{:.6}", self.sim.state().time)),
                kv("real_time_factor", format!("{real_time_factor:.3}")),
                kv("steps", s.steps.to_string()),
                kv("overruns", s.overruns.to_string()),
                kv("commands_received", s.commands_received.to_string()),
                kv("commands_rejected", s.commands_rejected.to_string()),
                kv("newton_iterations_last_step", s.last_newton_iterations.to_string()),
                kv("rejected_step_attempts", s.rejected_attempts.to_string()),
                kv("command_timeouts", s.command_timeouts.to_string()),
            ],
        };
        self.publishers
            .diagnostics
            .publish(msg::DiagnosticArray { header: self.header(), status: vec![status] })
            .map_err(ros)
    }

    /// Runs until `stop` is set: takes commands at every step boundary, steps (unless paused),
    /// paces to `real_time_factor` (0 = as fast as possible), counts overruns without catching up,
    /// and publishes diagnostics at 1 Hz.
    pub fn run(&mut self, stop: &AtomicBool) -> Result<(), NodeError> {
        let dt = self.sim.settings().dt;
        let mut anchor_wall = Instant::now();
        let mut anchor_sim = self.sim.state().time;
        let mut window = (Instant::now(), self.sim.state().time);
        while !stop.load(Ordering::Relaxed) && !self.quit {
            self.take_commands();
            self.serve()?;
            if self.paused {
                std::thread::sleep(Duration::from_millis(2));
                anchor_wall = Instant::now();
                anchor_sim = self.sim.state().time;
            } else {
                self.step_and_publish()?;
                let rtf = self.params.real_time_factor;
                if rtf > 0.0 {
                    let due =
                        anchor_wall + Duration::from_secs_f64((self.sim.state().time - anchor_sim) / rtf);
                    let now = Instant::now();
                    if now > due + Duration::from_secs_f64(dt / rtf) {
                        // late by more than a step: count it and re-anchor instead of bursting
                        self.stats.overruns += 1;
                        anchor_wall = now;
                        anchor_sim = self.sim.state().time;
                    } else if due > now {
                        std::thread::sleep(due - now);
                    }
                }
            }
            if self.last_diagnostics.elapsed() >= Duration::from_secs(1) {
                let wall = window.0.elapsed().as_secs_f64();
                let rtf = if wall > 0.0 { (self.sim.state().time - window.1) / wall } else { 0.0 };
                self.publish_diagnostics(rtf)?;
                self.last_diagnostics = Instant::now();
                window = (Instant::now(), self.sim.state().time);
            }
        }
        Ok(())
    }
}
