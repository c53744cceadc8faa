//! The ROS 2 transport (feature `ros2`): takes `NodeParams`, gives `DdsTransport`, the
//! transport-free `NodeCore`'s DDS face (ros2-client) in the node's loop (`io::runner`): its
//! publishers, subscriptions and services, the mapping of the core's outputs to ROS message
//! types, and QoS. Everything the node *means* (pacing,
//! pause/step/reset, command checks and keep-last intake, diagnostics, faults) lives in
//! `io::node`; this file only moves samples.
//!
//! Writers are reliable with `WhenFull::Fail`: a reader that stops acknowledging (a frozen `ros2
//! topic echo`, a stuck recorder) fills the writer's window and further samples on that topic are
//! dropped and counted, never waited for, so the step loop keeps its pace. RustDDS shares one
//! window among a writer's readers, so the other readers of *that* topic get nothing new until the
//! stuck reader acknowledges again or its participant's lease expires (50 s for RustDDS peers,
//! typically 10 s for Cyclone DDS); other topics are not affected. Incoming samples that cannot be
//! read are counted (`malformed_incoming`); a StepSimulation request whose payload does not have the
//! configured service mapping's layout is refused, not obeyed. At most `MAX_COMMANDS_PER_STEP`
//! command messages are taken per step.

use std::net::Ipv4Addr;
use std::time::Duration;

use ros2_client::dds::rustdds::DomainParticipantBuilder;
use ros2_client::qos::{Durability, History, WhenFull};
use ros2_client::service::RmwRequestId;
use ros2_client::{
    Context, ContextOptions, Message, MessageTypeName, Name, Node, NodeName, NodeOptions, Publisher,
    QosProfile, Server, ServiceMapping, ServiceTypeName, Subscription,
};

use crate::io::msg;
use crate::io::node::params::NodeParams;
use crate::io::node::runner::{Transport, With};
use crate::io::node::NodeCore;
use crate::io::sink::{NodeSink, NodeView, PublishError};
use crate::io::topics;
use crate::io::topics::Topic;
use crate::io::topics::TopicQos;

/// Why the DDS transport could not start.
#[derive(Debug, thiserror::Error)]
pub enum NodeError {
    /// DDS or ROS entity creation failed.
    #[error("ROS 2: {0}")]
    Ros(String),
}

fn ros<E: std::fmt::Debug>(e: E) -> NodeError {
    NodeError::Ros(format!("{e:?}"))
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
    /// `~/contacts`: its topic, and its writer once a scene with contacts publishes on it (a
    /// scene without has no writer).
    contacts_topic: ros2_client::dds::rustdds::Topic,
    contacts: Option<Publisher<msg::ContactStates>>,
    contacts_qos: TopicQos,
    /// `~/ground_truth/body_poses` and `~/ground_truth/cable_states`: their topics, and their
    /// writers once a scene with sensors publishes on them (a scene without has none).
    truth_topics: [ros2_client::dds::rustdds::Topic; 2],
    truth: Option<(Publisher<msg::PoseArray>, Publisher<msg::CableStates>)>,
    /// `~/imu` and `~/ground_truth/imu`: their topics, and their writers once a scene with a gyro
    /// or an accelerometer publishes on them.
    imu_topics: [ros2_client::dds::rustdds::Topic; 2],
    imu: Option<(Publisher<msg::ImuStates>, Publisher<msg::ImuStates>)>,
    /// `~/sensor_readings`: its topic, and its writer once a scene with sensors publishes on it.
    readings_topic: ros2_client::dds::rustdds::Topic,
    readings: Option<Publisher<msg::SensorReadings>>,
}

impl Message for msg::Empty {}
impl Message for msg::StepSimulationRequest {}
impl Message for msg::StepSimulationWire {}
impl Message for msg::ResultResponse {}
impl Message for msg::ResetSimulationRequest {}
impl Message for msg::GetSimulationStateResponse {}
impl Message for msg::SetSimulationStateRequest {}
impl Message for msg::GetSimulatorFeaturesResponse {}

struct Services {
    step: Server<msg::StepSimulationWire, msg::ResultResponse>,
    reset: Server<msg::ResetSimulationRequest, msg::ResultResponse>,
    get_state: Server<msg::Empty, msg::GetSimulationStateResponse>,
    set_state: Server<msg::SetSimulationStateRequest, msg::ResultResponse>,
    features: Server<msg::Empty, msg::GetSimulatorFeaturesResponse>,
    pause: Server<msg::Empty, msg::Empty>,
    unpause: Server<msg::Empty, msg::Empty>,
    reset_empty: Server<msg::Empty, msg::Empty>,
}

/// Most requests taken from one service server per turn of the loop.
const MAX_REQUESTS_PER_TURN: usize = 16;

/// How long after start the node looks for another node of its name (DDS discovery on loopback
/// takes well under a second; on a network, a few seconds).
const TWIN_WATCH: Duration = Duration::from_secs(30);

/// The node's DDS face: its publishers, services and subscriptions (ros2-client), as a
/// `Transport` of the node's loop (`io::runner::SimNode`).
pub struct DdsTransport {
    publishers: Publishers,
    services: Services,
    commands: Subscription<msg::ActuatorCommand>,
    joint_commands: Subscription<msg::JointState>,
    tension_commands: Subscription<msg::TensionCommand>,
    /// StepSimulation requests under way: the core's ticket and the DDS request id.
    tickets: Vec<(u64, RmwRequestId)>,
    /// The last `serve` left requests unread (a server gave `MAX_REQUESTS_PER_TURN`).
    more_requests: bool,
    /// Looks for another node of the same name on the domain (its ~/structure) for
    /// `TWIN_WATCH` after start: ROS tools warn of such twins, whose topics mix with ours.
    twin_watch: Option<(Subscription<msg::Structure>, std::time::Instant)>,
    /// Our own ~/structure writer, which the watch also hears.
    own_structure: ros2_client::Gid,
    /// The node's full name and domain, for the warning.
    full_name: String,
    domain_id: u16,
    // keep the DDS entities alive as long as the transport
    _node: Node,
    _context: Context,
}

/// The writers of two topics that only some scenes publish (`Topic::published_by`), made on
/// first use, with the QoS the topic table offers for `like` (both topics offer the same).
fn writer_pair<A: serde::Serialize, B: serde::Serialize>(
    node: &mut Node,
    topics: &[ros2_client::dds::rustdds::Topic; 2],
    like: Topic,
    what: &str,
) -> Result<(Publisher<A>, Publisher<B>), PublishError> {
    let offered = topics::topic_type(like).expect("a ROS topic").1;
    let qos = Some(writer_qos(offered.depth as usize, offered.transient_local));
    let failed = |e| PublishError::Failed(format!("{what} writer: {e:?}"));
    let first = node.create_publisher(&topics[0], qos.clone()).map_err(failed)?;
    let second = node.create_publisher(&topics[1], qos).map_err(failed)?;
    Ok((first, second))
}

fn sent<D>(r: ros2_client::error::WriteResult<(), D>) -> Result<(), PublishError> {
    r.map_err(|e| match e {
        ros2_client::error::WriteError::WouldBlock { .. } => PublishError::WouldBlock,
        // Display names the failure without the sample itself
        other => PublishError::Failed(other.to_string()),
    })
}

impl NodeSink for DdsTransport {
    fn publish(&mut self, topic: Topic, v: &NodeView<'_>) -> Result<(), PublishError> {
        use crate::io::sink::TopicMessage as M;
        if topic == Topic::Contacts && self.publishers.contacts.is_none() {
            let (depth, transient) =
                (self.publishers.contacts_qos.depth, self.publishers.contacts_qos.transient_local);
            let writer = self
                ._node
                .create_publisher(
                    &self.publishers.contacts_topic,
                    Some(writer_qos(depth as usize, transient)),
                )
                .map_err(|e| PublishError::Failed(format!("~/contacts writer: {e:?}")))?;
            self.publishers.contacts = Some(writer);
        }
        let truth = matches!(topic, Topic::GroundTruthPoses | Topic::GroundTruthCables);
        if truth && self.publishers.truth.is_none() {
            let topics = &self.publishers.truth_topics;
            let pair = writer_pair(&mut self._node, topics, Topic::GroundTruthPoses, "~/ground_truth")?;
            self.publishers.truth = Some(pair);
        }
        if matches!(topic, Topic::Imu | Topic::GroundTruthImu) && self.publishers.imu.is_none() {
            let pair = writer_pair(&mut self._node, &self.publishers.imu_topics, Topic::Imu, "~/imu")?;
            self.publishers.imu = Some(pair);
        }
        if topic == Topic::SensorReadings && self.publishers.readings.is_none() {
            let offered = topics::topic_type(topic).expect("a ROS topic").1;
            let qos = Some(writer_qos(offered.depth as usize, offered.transient_local));
            let writer = (self._node.create_publisher(&self.publishers.readings_topic, qos))
                .map_err(|e| PublishError::Failed(format!("~/sensor_readings writer: {e:?}")))?;
            self.publishers.readings = Some(writer);
        }
        let p = &self.publishers;
        match (topic, M::build(topic, v)?) {
            (Topic::GroundTruthPoses, Some(M::Poses(m))) => match &p.truth {
                Some((w, _)) => sent(w.publish(m)),
                None => Ok(()),
            },
            (Topic::GroundTruthCables, Some(M::Cables(m))) => match &p.truth {
                Some((_, w)) => sent(w.publish(m)),
                None => Ok(()),
            },
            (_, Some(M::Clock(m))) => sent(p.clock.publish(m)),
            (Topic::TfStatic, Some(M::Tf(m))) => sent(p.tf_static.publish(m)),
            (_, Some(M::Tf(m))) => sent(p.tf.publish(m)),
            (_, Some(M::Poses(m))) => sent(p.poses.publish(m)),
            (_, Some(M::Cables(m))) => sent(p.cables.publish(m)),
            (_, Some(M::Actuators(m))) => sent(p.actuators.publish(m)),
            (_, Some(M::Structure(m))) => sent(p.structure.publish(m)),
            (_, Some(M::Diagnostics(m))) => sent(p.diagnostics.publish(m)),
            (_, Some(M::Markers(m))) => sent(p.markers.publish(m)),
            (Topic::Imu, Some(M::Imu(m))) => match &p.imu {
                Some((w, _)) => sent(w.publish(m)),
                None => Ok(()),
            },
            (_, Some(M::Imu(m))) => match &p.imu {
                Some((_, w)) => sent(w.publish(m)),
                None => Ok(()),
            },
            (_, Some(M::Sensors(m))) => match &p.readings {
                Some(w) => sent(w.publish(m)),
                None => Ok(()),
            },
            (_, Some(M::Contacts(m))) => match &p.contacts {
                Some(w) => sent(w.publish(m)),
                None => Ok(()),
            },
            // the whole-state sample: the same state goes out on the topics above
            (_, None) => Ok(()),
        }
    }

    fn step_request_done(&mut self, ticket: u64, result: msg::SimResult, _view: &NodeView<'_>) {
        if let Some(k) = self.tickets.iter().position(|(t, _)| *t == ticket) {
            let (_, id) = self.tickets.swap_remove(k);
            // a client that went away cannot be answered; nothing to do about it
            let _ = self.services.step.send_response(id, msg::ResultResponse { result });
        }
    }
}

/// Takes up to `MAX_REQUESTS_PER_TURN` requests from `server`, counting unreadable ones; sets
/// `more` when it stopped at that limit (more may wait, and no new arrival will announce them).
fn requests<Req: Message + 'static, Resp: Message + 'static>(
    server: &Server<Req, Resp>,
    core: &mut NodeCore,
    more: &mut bool,
) -> Vec<(RmwRequestId, Req)> {
    let mut out = Vec::new();
    for _ in 0..MAX_REQUESTS_PER_TURN {
        match server.receive_request() {
            Ok(Some(r)) => out.push(r),
            Ok(None) => return out,
            Err(_) => core.incoming_malformed(),
        }
    }
    *more = true;
    out
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

/// QoS: reliable, keep last `depth`, volatile or transient local (a writer with it waits up to
/// 20 ms for a full window; the node's own writers use `writer_qos`).
pub fn qos(depth: usize, transient_local: bool) -> QosProfile {
    QosProfile::publisher_default()
        .reliability_reliable(WhenFull::Wait(Duration::from_millis(20)))
        .durability(if transient_local { Durability::TransientLocal } else { Durability::Volatile })
        .history(History::KeepLast { depth })
}

/// Smallest writer history (and so reliable window) of the node's volatile topics: room for a
/// healthy reader's acknowledgements to arrive a few steps late without a drop.
pub const MIN_WRITER_DEPTH: usize = 16;

/// The node's writers: like `qos`, but a full window fails at once (`WhenFull::Fail`) and volatile
/// topics keep at least `MIN_WRITER_DEPTH` samples. Readers' own depths are unaffected.
pub fn writer_qos(depth: usize, transient_local: bool) -> QosProfile {
    let depth = if transient_local { depth } else { depth.max(MIN_WRITER_DEPTH) };
    qos(depth, transient_local).reliability_reliable(WhenFull::Fail)
}

impl DdsTransport {
    /// Opens the DDS participant (`params.domain_id`, localhost only if asked), the node and its
    /// topics, services and subscriptions. Nothing is published until the node starts.
    pub fn new(params: &NodeParams) -> Result<Self, NodeError> {
        let context = context(params.domain_id, params.localhost_only)?;
        let mut node = context
            .new_node(NodeName::new(&params.namespace, &params.node_name).map_err(ros)?, NodeOptions::new())
            .map_err(ros)?;
        let private = params.private_namespace();
        // every topic as the bags and the Python kit declare it (`topics::topic_type`,
        // `topics::INPUT_TOPICS`): one table of names, types and QoS
        let declare = |short: &str, type_name: &str, offered: TopicQos| {
            // `~/a/b` is topic `b` in the namespace `<private>/a`
            let (ns, name) = match short.strip_prefix("~/") {
                Some(rest) => match rest.rsplit_once('/') {
                    Some((sub, base)) => (format!("{private}/{sub}"), base),
                    None => (private.clone(), rest),
                },
                None => ("/".to_string(), short.trim_start_matches('/')),
            };
            let ns = ns.as_str();
            let (pkg, ty) = type_name.split_once("/msg/").ok_or_else(|| {
                NodeError::Ros(format!("topic {short}: type '{type_name}' is not pkg/msg/Type"))
            })?;
            node.create_topic(
                &Name::new(ns, name).map_err(ros)?,
                MessageTypeName::new(pkg, ty),
                &qos(offered.depth as usize, offered.transient_local),
            )
            .map_err(ros)
        };
        let mut outputs = Vec::new();
        for t in Topic::ALL {
            if let Some((type_name, offered)) = topics::topic_type(t) {
                outputs.push((t, declare(t.name(), type_name, offered)?, offered));
            }
        }
        let [(cmd_name, cmd_type, cmd_qos), (joint_name, joint_type, joint_qos), (tension_name, tension_type, tension_qos)] =
            topics::INPUT_TOPICS;
        let t_cmd = declare(cmd_name, cmd_type, cmd_qos)?;
        let t_joint_cmd = declare(joint_name, joint_type, joint_qos)?;
        let t_tension_cmd = declare(tension_name, tension_type, tension_qos)?;
        macro_rules! publisher {
            ($topic:expr) => {{
                let (_, t, offered) =
                    outputs.iter().find(|(t, _, _)| *t == $topic).expect("every ROS topic is declared");
                node.create_publisher(t, Some(writer_qos(offered.depth as usize, offered.transient_local)))
                    .map_err(ros)?
            }};
        }
        let publishers = Publishers {
            clock: publisher!(Topic::Clock),
            poses: publisher!(Topic::BodyPoses),
            cables: publisher!(Topic::CableStates),
            actuators: publisher!(Topic::ActuatorStates),
            structure: publisher!(Topic::Structure),
            tf: publisher!(Topic::Tf),
            tf_static: publisher!(Topic::TfStatic),
            diagnostics: publisher!(Topic::Diagnostics),
            markers: publisher!(Topic::Markers),
            contacts_topic: outputs
                .iter()
                .find(|(t, _, _)| *t == Topic::Contacts)
                .expect("every ROS topic is declared")
                .1
                .clone(),
            contacts: None,
            contacts_qos: topics::topic_type(Topic::Contacts).expect("a ROS topic").1,
            truth_topics: [Topic::GroundTruthPoses, Topic::GroundTruthCables].map(|topic| {
                outputs.iter().find(|(t, _, _)| *t == topic).expect("every ROS topic is declared").1.clone()
            }),
            truth: None,
            imu_topics: [Topic::Imu, Topic::GroundTruthImu].map(|topic| {
                outputs.iter().find(|(t, _, _)| *t == topic).expect("every ROS topic is declared").1.clone()
            }),
            imu: None,
            readings_topic: (outputs.iter().find(|(t, _, _)| *t == Topic::SensorReadings))
                .expect("every ROS topic is declared")
                .1
                .clone(),
            readings: None,
        };
        let mapping = match params.service_mapping.as_str() {
            "cyclone" => ServiceMapping::Cyclone,
            "basic" => ServiceMapping::Basic,
            _ => ServiceMapping::Enhanced,
        };
        let service_qos = writer_qos(10, false);
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
        let structure_topic =
            &outputs.iter().find(|(t, _, _)| *t == Topic::Structure).expect("structure is declared").1;
        let twin_watch = node.create_subscription::<msg::Structure>(structure_topic, Some(qos(1, true))).ok();
        let commands = node.create_subscription(&t_cmd, None).map_err(ros)?;
        let joint_commands = node.create_subscription(&t_joint_cmd, None).map_err(ros)?;
        let tension_commands = node.create_subscription(&t_tension_cmd, None).map_err(ros)?;
        let own_structure = publishers.structure.gid();
        Ok(Self {
            twin_watch: twin_watch.map(|s| (s, std::time::Instant::now())),
            own_structure,
            full_name: params.private_namespace(),
            domain_id: params.domain_id,
            publishers,
            services,
            commands,
            joint_commands,
            tension_commands,
            tickets: Vec::new(),
            more_requests: false,
            _node: node,
            _context: context,
        })
    }

    /// Answers pending service requests (at most `MAX_REQUESTS_PER_TURN` per service).
    fn serve(&mut self, core: &mut NodeCore, others: &mut dyn NodeSink) {
        let sv = &self.services;
        let more = &mut self.more_requests;
        *more = false;
        let steps = requests(&sv.step, core, more);
        let resets = requests(&sv.reset, core, more);
        let gets = requests(&sv.get_state, core, more);
        let sets = requests(&sv.set_state, core, more);
        let feats = requests(&sv.features, core, more);
        let pauses = requests(&sv.pause, core, more);
        let unpauses = requests(&sv.unpause, core, more);
        let empties = requests(&sv.reset_empty, core, more);
        macro_rules! sink {
            () => {
                &mut With { own: &mut *self, others: &mut *others }
            };
        }
        for (id, req) in steps {
            if !req.layout_matches() {
                // another mapping's layout: `steps` would be a header field. Not obeyed, and not
                // answerable either (the request id is not where this mapping looks for it).
                core.incoming_malformed();
                continue;
            }
            match core.request_steps(req.steps, sink!()) {
                Ok(ticket) => {
                    if core.steps_remaining() > 0 {
                        self.tickets.push((ticket, id));
                    } else {
                        let result = msg::SimResult::ok();
                        let _ = self.services.step.send_response(id, msg::ResultResponse { result });
                    }
                }
                Err(result) => {
                    let _ = self.services.step.send_response(id, msg::ResultResponse { result });
                }
            }
        }
        for (id, _) in resets {
            core.reset(sink!());
            let result = msg::SimResult::ok();
            let _ = self.services.reset.send_response(id, msg::ResultResponse { result });
        }
        for (id, _) in gets {
            let state = msg::SimulationState { state: core.simulation_state() };
            let response = msg::GetSimulationStateResponse { state, result: msg::SimResult::ok() };
            let _ = self.services.get_state.send_response(id, response);
        }
        for (id, req) in sets {
            let result = core.set_simulation_state(req.state.state, sink!());
            let _ = self.services.set_state.send_response(id, msg::ResultResponse { result });
        }
        for (id, _) in feats {
            let features = NodeCore::features();
            let _ = self.services.features.send_response(id, msg::GetSimulatorFeaturesResponse { features });
        }
        for (id, _) in pauses {
            core.set_paused(true, sink!());
            let _ = self.services.pause.send_response(id, msg::Empty::default());
        }
        for (id, _) in unpauses {
            core.set_paused(false, sink!());
            let _ = self.services.unpause.send_response(id, msg::Empty::default());
        }
        for (id, _) in empties {
            core.reset(sink!());
            let _ = self.services.reset_empty.send_response(id, msg::Empty::default());
        }
    }
}

impl DdsTransport {
    /// Warns once, on stderr, when another writer publishes this node's ~/structure: a second node
    /// with the same name on the same domain, whose topics and services mix with ours.
    fn watch_for_twin(&mut self) {
        let Some((reader, since)) = &self.twin_watch else { return };
        let mut twin = false;
        while let Ok(Some((_, info))) = reader.take() {
            twin |= info.publisher_gid() != self.own_structure;
        }
        if twin {
            eprintln!(
                "warning: another node named {} is on DDS domain {} (it publishes {}/structure too): \
                 the two mix their topics and services. Give one another name (-r __node:=NAME or \
                 -r __ns:=/NAMESPACE) or another domain (ROS_DOMAIN_ID)",
                self.full_name, self.domain_id, self.full_name
            );
        }
        if twin || since.elapsed() > TWIN_WATCH {
            self.twin_watch = None;
        }
    }
}

impl Transport for DdsTransport {
    fn name(&self) -> &'static str {
        "dds"
    }

    /// Takes pending command messages (at most the core's per-step budget) and answers pending
    /// service requests (at most `MAX_REQUESTS_PER_TURN` per service).
    fn take_inputs(&mut self, core: &mut NodeCore, others: &mut dyn NodeSink) {
        while core.wants_commands() {
            match self.commands.take() {
                Ok(Some((m, _))) => core.offer_command(&m),
                Ok(None) => break,
                Err(_) => core.incoming_malformed(),
            }
        }
        while core.wants_commands() {
            match self.joint_commands.take() {
                Ok(Some((m, _))) => core.offer_joint_command(&m),
                Ok(None) => break,
                Err(_) => core.incoming_malformed(),
            }
        }
        while core.wants_commands() {
            match self.tension_commands.take() {
                Ok(Some((m, _))) => core.offer_tension_command(&m),
                Ok(None) => break,
                Err(_) => core.incoming_malformed(),
            }
        }
        self.serve(core, others);
        self.watch_for_twin();
    }

    /// Registers the three command subscriptions and every service server: each signals an arriving sample or
    /// request through a socket that reading it empties (`take`, `receive_request`).
    fn register_wake(&mut self, registry: &mio::Registry, token: mio::Token) -> std::io::Result<bool> {
        let readable = mio::Interest::READABLE;
        registry.register(&mut self.commands, token, readable)?;
        registry.register(&mut self.joint_commands, token, readable)?;
        registry.register(&mut self.tension_commands, token, readable)?;
        let sv = &mut self.services;
        registry.register(&mut sv.step, token, readable)?;
        registry.register(&mut sv.reset, token, readable)?;
        registry.register(&mut sv.get_state, token, readable)?;
        registry.register(&mut sv.set_state, token, readable)?;
        registry.register(&mut sv.features, token, readable)?;
        registry.register(&mut sv.pause, token, readable)?;
        registry.register(&mut sv.unpause, token, readable)?;
        registry.register(&mut sv.reset_empty, token, readable)?;
        Ok(true)
    }

    /// Requests left over from a full turn are not announced again: do not block on them.
    fn before_wait(&mut self, _deadline: std::time::Instant) -> bool {
        self.more_requests
    }

    fn answering(&self) -> bool {
        !self.tickets.is_empty()
    }
}

/// Waits until a participant of its own on `domain` has received the transient-local `~/structure`
/// of the node with `params`: a controller started now finds the node. `Ok(false)` when `timeout`
/// passed first; an error says which DDS step failed ("DDS readiness check (...): why").
pub fn structure_received(domain: u16, params: &NodeParams, timeout: Duration) -> Result<bool, String> {
    use ros2_client::{MessageTypeName, Name, NodeName, NodeOptions};
    let fail = |what: &str, e: String| format!("DDS readiness check ({what}): {e}");
    let ctx = context(domain, params.localhost_only).map_err(|e| fail("participant", e.to_string()))?;
    let mut probe = ctx
        .new_node(
            NodeName::new("/", "tensegrity_kit_probe").map_err(|e| fail("name", format!("{e:?}")))?,
            NodeOptions::new(),
        )
        .map_err(|e| fail("node", format!("{e:?}")))?;
    let name = Name::new(&params.private_namespace(), "structure")
        .map_err(|e| fail("topic name", format!("{e:?}")))?;
    let topic = probe
        .create_topic(&name, MessageTypeName::new("tensegrity_msgs", "Structure"), &qos(1, true))
        .map_err(|e| fail("topic", format!("{e:?}")))?;
    let reader = probe
        .create_subscription::<msg::Structure>(&topic, None)
        .map_err(|e| fail("subscription", format!("{e:?}")))?;
    let start = std::time::Instant::now();
    while start.elapsed() < timeout {
        if let Ok(Some(_)) = reader.take() {
            return Ok(true);
        }
        std::thread::sleep(Duration::from_millis(5));
    }
    Ok(false)
}
