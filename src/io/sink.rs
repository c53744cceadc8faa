//! What a transport's outgoing side sees: takes the node core's state after a step (`NodeView`:
//! model, evaluated state, derived outputs and counters), gives it to each `NodeSink` to publish,
//! and builds the ROS message a `Topic` carries from it (`TopicMessage`, for every sink that
//! speaks ROS types: DDS, the bag recorder).

use serde::Serialize;

use crate::control::ActuatorCommand;
use crate::evaluate::Workspace;
use crate::io::msg::{
    CableStates, Clock, ContactStates, DiagnosticArray, DiagnosticStatus, Header, ImuStates, JointState,
    MarkerArray, PoseArray, SensorReadings, SimResult, Structure, TfMessage, Time,
};
use crate::io::topics::Topic;
use crate::model::{ActuatorId, Model};
use crate::state::State;

/// Why a sink could not publish. Never fatal: counted per topic and reported.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum PublishError {
    /// The writer's queue is full (a reliable reader is not keeping up).
    #[error("writer full (a reliable reader is not keeping up)")]
    WouldBlock,
    /// Any other failure, with the transport's words.
    #[error("{0}")]
    Failed(String),
}

/// What a sink may read when it publishes: the model, the evaluated state, and the node's derived
/// outputs. Every number in it is finite when the core hands it over.
pub struct NodeView<'a> {
    /// The model.
    pub model: &'a Model,
    /// The current state.
    pub state: &'a State,
    /// The workspace evaluated at `state` (tensions, lengths, points).
    pub workspace: &'a Workspace,
    /// Each cable's rest-length rate over the last step, m/s.
    pub rates: &'a [f64],
    /// Pulley coordinates at the start, for pulley slips.
    pub reference: &'a [Vec<f64>],
    /// Fixed frame of poses and transforms.
    pub frame_id: &'a str,
    /// Node name (for diagnostics' names and hardware ids).
    pub node_name: &'a str,
    /// Names this view's `reference`, `frame_id` and `node_name`: views with the same id carry
    /// equal ones, so a sink that keeps them (a recorder's batch) compares the id, not the values.
    pub constants: ConstantsId,
    /// The statuses to publish on `/diagnostics` (when the topic is `Diagnostics`).
    pub diagnostics: &'a [DiagnosticStatus],
    /// Steps taken since the start or the last reset (the state is the one after this many).
    pub step: u64,
    /// `sim_state` code: PLAYING or PAUSED (also while faulted).
    pub simulation_state: u8,
    /// True while a physics failure holds the simulation paused (until reset).
    pub faulted: bool,
    /// The node's counters.
    pub stats: NodeStats,
    /// The node's step (one `tick`), s.
    pub dt: f64,
    /// What the scene's sensors report now (`crate::sensors::Sensors::measured`; empty without
    /// sensors): the state topics carry these values, `~/ground_truth/...` the exact ones.
    pub measured: &'a [f64],
    /// Per value of `measured`: held after a lost update (`crate::sensors::Sensors::lost`).
    pub lost: &'a [bool],
    /// The true IMU values (`crate::sensors::Sensors::imu_truth`; empty without a gyro or an
    /// accelerometer, and in views that have no step before them, such as a quasi-static path).
    pub imu_truth: &'a [f64],
}

/// Names one set of a view's constants (`NodeView::reference`, `frame_id`, `node_name`).
///
/// Whoever builds views takes a `fresh` id for each set and keeps it while the set is unchanged
/// (a `NodeCore` takes one when built: its constants never change). Two sets with different ids
/// may still be equal: a sink comparing ids only ever sees "different" too often, never too
/// rarely.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ConstantsId(u64);

impl ConstantsId {
    /// An id no other call in this process returned.
    pub fn fresh() -> Self {
        static NEXT: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);
        Self(NEXT.fetch_add(1, std::sync::atomic::Ordering::Relaxed))
    }
}

/// A transport's outgoing side, as the core sees it.
pub trait NodeSink {
    /// Publishes `topic` from `view`.
    fn publish(&mut self, topic: Topic, view: &NodeView<'_>) -> Result<(), PublishError>;
    /// Answers the deferred StepSimulation request `ticket` (see `NodeCore::request_steps`);
    /// `view` is the state it ends at (a lockstep transport sends it back with the answer). A sink
    /// ignores tickets it did not issue.
    fn step_request_done(&mut self, ticket: u64, result: SimResult, view: &NodeView<'_>);
    /// The commands applied at the boundary before step `step` (sim time `time`), in the order
    /// they were applied. For recorders; default: nothing.
    fn commands_applied(&mut self, _time: f64, _step: u64, _commands: &[(ActuatorId, ActuatorCommand)]) {}
    /// The simulation was just reset to its initial state (sim time `time`) after `step` steps
    /// since the start, its episode drawn from `seed` where the reset gave one
    /// (`NodeCore::reset_seeded`); the reset state is published next. For recorders; default:
    /// nothing.
    fn simulation_reset(&mut self, _time: f64, _step: u64, _seed: Option<u64>) {}
}

/// A sink that publishes nothing and answers no request: for driving a `NodeCore` where only its
/// state matters (tests, benchmarks, the allocation check).
#[derive(Debug, Clone, Copy, Default)]
pub struct DiscardSink;

impl NodeSink for DiscardSink {
    fn publish(&mut self, _topic: Topic, _view: &NodeView<'_>) -> Result<(), PublishError> {
        Ok(())
    }
    fn step_request_done(&mut self, _ticket: u64, _result: SimResult, _view: &NodeView<'_>) {}
}

/// Counters reported in `/diagnostics`.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct NodeStats {
    /// Physics steps taken.
    pub steps: u64,
    /// Steps that ended later than real-time pacing allowed.
    pub overruns: u64,
    /// Command messages received (`= commands_accepted + commands_rejected`).
    pub commands_received: u64,
    /// Command messages accepted (entries of a later accepted message for the same actuator
    /// before the next step replace them).
    pub commands_accepted: u64,
    /// Command messages rejected (too large, non-finite, out of range, unknown or repeated name,
    /// wrong length, empty).
    pub commands_rejected: u64,
    /// Newton iterations of the last step.
    pub last_newton_iterations: usize,
    /// The longest physics step so far, its simulator work alone (`StepStats::wall_time`, no
    /// publishing or pacing): what a real-time period must hold.
    pub longest_step: std::time::Duration,
    /// Rejected step attempts so far.
    pub rejected_attempts: usize,
    /// Times the command timeout fired.
    pub command_timeouts: u64,
    /// Failed publishes per topic, in `Topic::ALL` order.
    pub publish_failures: [u64; Topic::ALL.len()],
    /// Incoming samples a transport could not read (malformed, wrong layout).
    pub malformed_incoming: u64,
    /// StepSimulation requests refused or interrupted.
    pub step_requests_failed: u64,
    /// Physics failures (each paused the simulation).
    pub physics_failures: u64,
}

impl NodeStats {
    /// Failed publishes on `topic`.
    pub fn publish_failures_on(&self, topic: Topic) -> u64 {
        self.publish_failures[topic.index()]
    }
}

/// One published message of the node, built from the core's view: what every transport that
/// speaks ROS message types (DDS, the bag recorder) sends for a `Topic`. Serializes as the
/// message it holds.
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(untagged)]
pub enum TopicMessage {
    /// `/clock`.
    Clock(Clock),
    /// `/tf` or `/tf_static`.
    Tf(TfMessage),
    /// `~/body_poses`.
    Poses(PoseArray),
    /// `~/cable_states`.
    Cables(CableStates),
    /// `~/actuator_states`.
    Actuators(JointState),
    /// `~/structure`.
    Structure(Structure),
    /// `/diagnostics`.
    Diagnostics(DiagnosticArray),
    /// `~/markers`.
    Markers(MarkerArray),
    /// `~/contacts`.
    Contacts(ContactStates),
    /// `~/imu` or `~/ground_truth/imu`.
    Imu(ImuStates),
    /// `tensegrity_msgs/msg/SensorReadings`.
    Sensors(SensorReadings),
}

impl TopicMessage {
    /// The message of `topic` from `view`; `None` for topics that have no ROS message
    /// (`Topic::State`, the shared-memory sample); an error for non-finite cable states.
    pub fn build(
        topic: crate::io::topics::Topic,
        view: &crate::io::sink::NodeView<'_>,
    ) -> Result<Option<Self>, crate::io::sink::PublishError> {
        use crate::io::topics::Topic;
        let (model, state, ws, frame) = (view.model, view.state, view.workspace, view.frame_id);
        Ok(Some(match topic {
            Topic::Clock => Self::Clock(Clock { clock: Time::from_seconds(state.time) }),
            Topic::Tf => Self::Tf(TfMessage::from_state(model, state, frame, false)),
            Topic::TfStatic => Self::Tf(TfMessage::from_state(model, state, frame, true)),
            Topic::BodyPoses => {
                let mut poses = PoseArray::from_state(state, frame);
                poses.measure(model, view.measured);
                Self::Poses(poses)
            }
            Topic::GroundTruthPoses => Self::Poses(PoseArray::from_state(state, frame)),
            Topic::CableStates | Topic::GroundTruthCables => {
                let mut cables = CableStates::from_state(model, state, ws, view.reference, frame);
                if topic == Topic::CableStates {
                    cables.measure(model, view.measured);
                }
                if !cables.is_finite() {
                    return Err(crate::io::sink::PublishError::Failed(
                        "refusing to publish non-finite cable states".into(),
                    ));
                }
                Self::Cables(cables)
            }
            Topic::ActuatorStates => {
                let mut actuators = JointState::actuators(model, state, ws, view.rates);
                if let Some(l0) =
                    crate::sensors::reading(model, view.measured, crate::sensors::SensorKind::RestLength)
                {
                    actuators.position.copy_from_slice(l0);
                }
                Self::Actuators(actuators)
            }
            Topic::Structure => Self::Structure(Structure::from_model(model, frame)),
            Topic::Diagnostics => {
                let header = Header { stamp: Time::from_seconds(state.time), frame_id: frame.to_string() };
                Self::Diagnostics(DiagnosticArray { header, status: view.diagnostics.to_vec() })
            }
            Topic::Markers => Self::Markers(MarkerArray::from_state(model, state, ws, frame)),
            Topic::Contacts => {
                let contacts = ContactStates::from_state(model, state, ws, frame);
                if !contacts.is_finite() {
                    return Err(crate::io::sink::PublishError::Failed(
                        "refusing to publish non-finite contact states".into(),
                    ));
                }
                Self::Contacts(contacts)
            }
            Topic::Imu | Topic::GroundTruthImu => {
                // a view with no IMU values (a quasi-static path) has nothing to say
                if view.imu_truth.is_empty() {
                    return Ok(None);
                }
                let measured = if topic == Topic::Imu { view.measured } else { &[] };
                let imu = ImuStates::from_imu(model, state.time, view.imu_truth, measured, frame);
                if !imu.is_finite() {
                    return Err(crate::io::sink::PublishError::Failed(
                        "refusing to publish non-finite IMU states".into(),
                    ));
                }
                Self::Imu(imu)
            }
            Topic::SensorReadings => {
                if view.measured.is_empty() {
                    return Ok(None);
                }
                let readings =
                    SensorReadings::from_sensors(model, state.time, view.measured, view.lost, frame);
                if !readings.is_finite() {
                    return Err(crate::io::sink::PublishError::Failed(
                        "refusing to publish non-finite sensor readings".into(),
                    ));
                }
                Self::Sensors(readings)
            }
            Topic::State => return Ok(None),
        }))
    }
}
