//! The ROS 2 node (feature `ros2`): takes a `Model` and `NodeParams`, gives a node that steps the
//! simulation in real time (or as fast as possible, or only on request while paused), applies
//! actuator commands at step boundaries, and publishes the clock, body poses, transforms, cable
//! and actuator states, the structure and diagnostics over DDS (ros2-client).
//!
//! Every message of a step carries that step's simulation time, and state is published before the
//! clock tick. Commands are validated as whole messages; a rejected one is counted, reported in
//! `/diagnostics`, and changes nothing. Overruns (steps that finish later than real time allows)
//! are counted, never caught up in bursts. Nothing non-finite is ever published: the physics never
//! lets a NaN into its state, and the cable message is checked again before it leaves.

use std::net::Ipv4Addr;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use ros2_client::dds::rustdds::DomainParticipantBuilder;
use ros2_client::qos::{Durability, History, WhenFull};
use ros2_client::{
    Context, ContextOptions, MessageTypeName, Name, Node, NodeName, NodeOptions, Publisher, QosProfile,
    Subscription,
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
    // keep the DDS entities alive as long as the node
    _node: Node,
    _context: Context,
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
        let mut sim =
            Simulator::new(model, SimSettings { dt: params.physics_dt, integrator, ..Default::default() })?;
        if !params.follow_schedule {
            // hold every actuator at its initial rest length until a controller commands it
            let holds: Vec<(String, f64)> = (0..sim.model().actuators.len())
                .map(|i| {
                    let m = sim.model();
                    (m.actuator_names[i].clone(), m.initial_rest_lengths[m.actuators[i].cable.0])
                })
                .collect();
            for (name, l0) in holds {
                sim.command(&name, Command { rest_length: Some(l0), rate: None })
                    .map_err(|e| NodeError::Ros(format!("holding {name}: {e}")))?;
            }
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
        let status = msg::DiagnosticStatus {
            level: 1,
            name: format!("{}: commands", self.params.node_name),
            message: format!("rejected command: {reason}"),
            hardware_id: self.params.node_name.clone(),
            values: vec![msg::KeyValue {
                key: "commands_rejected".into(),
                value: self.stats.commands_rejected.to_string(),
            }],
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
        let dt = self.params.physics_dt;
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
        self.publishers.clock.publish(msg::Clock { clock: Time::from_seconds(t) }).map_err(ros)?;
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
        let dt = self.params.physics_dt;
        let mut anchor_wall = Instant::now();
        let mut anchor_sim = self.sim.state().time;
        let mut window = (Instant::now(), self.sim.state().time);
        while !stop.load(Ordering::Relaxed) {
            self.take_commands();
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
