//! Recording runs into bags and replaying them: takes the node core's outputs (`BagRecorder`, a
//! `Transport` of the node's loop, so it sees exactly what the core published and applied) or an
//! offline run's (the CLI's `deploy --dynamic` drives the same core; `PathPublisher` publishes a
//! quasi-static path), gives a rosbag2 bag (`io::bag`) with every published topic, the applied
//! commands on `~/applied_commands` (`tensegrity_msgs/msg/AppliedCommands`) and the run record;
//! takes such a bag back (`replay`) and runs it again with the recorded commands (and resets) at
//! their recorded steps, comparing every recorded message bit for bit.
//!
//! On the node's thread a step's `/clock` and state topics cost a few hundred nanoseconds: the
//! state's numbers are appended to a batch (`StepBatch`: poses, rest lengths, cable responses,
//! segment lengths, rates, and point positions when the markers go) that is handed to the
//! bag's writer thread every `BATCH_RECORDS` records; that thread builds and serializes their
//! messages (`bag::Compose`). When its queue is full a batch is dropped whole (counted as a
//! publish failure); the structure, the static transforms and the applied commands never are
//! (`droppable`), and they hand the batch over first, so messages keep their order.
//!
//! Each message's MCAP `sequence` is the simulator's step count when it was published (steps
//! since the start, resets included; modulo 2^32), its log time the wall clock for the node and
//! the simulation time for offline runs (a quasi-static path: 1 ms per row).
//!
//! What is reproducible: the same scene, settings and commands at the same steps give the same
//! bits (the physics has no wall-clock, thread-count or hash-order dependence), so a run's
//! real-time overruns, its machine's load and its transports do not matter. `/diagnostics` holds
//! wall-clock figures (real-time factor, overruns) and is recorded but not compared.

use std::collections::VecDeque;
use std::path::{Path, PathBuf};
use std::time::{Duration, SystemTime, UNIX_EPOCH};

use crate::control::ActuatorCommand;
use crate::forces::cable::CableResponse;
use crate::forces::Workspace;
use crate::io::bag::{
    BagError, BagOptions, BagReader, BagSummary, BagTopic, BagWriter, Compose, RunInfo, TopicQos, TopicSpec,
};
use crate::io::msg::{self, AppliedCommands, TopicMessage};
use crate::io::node::{ConstantsId, NodeCore, NodeSink, NodeStats, NodeView, PublishError, Topic};
use crate::io::params::NodeParams;
use crate::io::runner::Transport;
use crate::model::{ActuatorId, Model};
use crate::sim::{SimSettings, Simulator};
use crate::solve::dynamics::{Integrator, NewtonSettings};
use crate::solve::linear::LinearBackend;
use crate::state::State;
use nalgebra::{Quaternion, UnitQuaternion, Vector3};

/// Name of the applied-commands topic in the node's private namespace.
pub const APPLIED_COMMANDS: &str = "applied_commands";
/// `RunInfo` key of the run's kind: `KIND_NODE`, `KIND_DYNAMIC` or `KIND_QUASI_STATIC`.
pub const KEY_KIND: &str = "kind";
/// A node run.
pub const KIND_NODE: &str = "node";
/// `tensegrity deploy --dynamic`.
pub const KIND_DYNAMIC: &str = "deploy-dynamic";
/// `tensegrity deploy --quasi-static`.
pub const KIND_QUASI_STATIC: &str = "deploy-quasi-static";

/// The ROS type and offered QoS of a topic; `None` for the shared-memory whole-state sample. The
/// one table of them: the DDS transport creates its topics and writers from it, the bags
/// declare their channels with it and the Python kit's `msgs.TOPICS` is generated from it.
pub fn topic_type(topic: Topic) -> Option<(&'static str, TopicQos)> {
    let q = |depth, transient_local| TopicQos { depth, transient_local };
    // volatile writers keep at least 16 samples (io::ros2::MIN_WRITER_DEPTH)
    Some(match topic {
        Topic::Clock => ("rosgraph_msgs/msg/Clock", q(16, false)),
        Topic::Tf => ("tf2_msgs/msg/TFMessage", q(100, false)),
        Topic::TfStatic => ("tf2_msgs/msg/TFMessage", q(1, true)),
        Topic::BodyPoses => ("geometry_msgs/msg/PoseArray", q(16, false)),
        Topic::CableStates => ("tensegrity_msgs/msg/CableStates", q(16, false)),
        Topic::ActuatorStates => ("sensor_msgs/msg/JointState", q(16, false)),
        Topic::Structure => ("tensegrity_msgs/msg/Structure", q(1, true)),
        Topic::Diagnostics => ("diagnostic_msgs/msg/DiagnosticArray", q(16, false)),
        Topic::Markers => ("visualization_msgs/msg/MarkerArray", q(16, false)),
        Topic::State => return None,
    })
}

/// The node's input topics: name (`~/` is the node's private namespace), type and QoS, as the DDS
/// transport subscribes them.
pub const INPUT_TOPICS: [(&str, &str, TopicQos); 2] = [
    (
        "~/actuator_commands",
        "tensegrity_msgs/msg/ActuatorCommand",
        TopicQos { depth: 1, transient_local: false },
    ),
    ("~/joint_commands", "sensor_msgs/msg/JointState", TopicQos { depth: 1, transient_local: false }),
];

/// The full name of `topic` for a node with `params` (`~/x` is `<ns>/<node>/x`).
pub fn topic_name(topic_short: &str, params: &NodeParams) -> String {
    match topic_short.strip_prefix("~/") {
        Some(rest) => format!("{}/{rest}", params.private_namespace()),
        None => topic_short.to_string(),
    }
}

/// The name a bag gives the applied-commands topic of a node with `params`.
pub fn applied_commands_topic(params: &NodeParams) -> String {
    topic_name(&format!("~/{APPLIED_COMMANDS}"), params)
}

/// Where a recorded message's log time comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LogTime {
    /// The wall clock (ns since the Unix epoch), as `ros2 bag record` stamps: the node.
    Wall,
    /// The simulation time, ns: offline dynamic runs.
    SimTime,
    /// 1 ms per step of the sequence: quasi-static paths (whose time may go back on a traced
    /// branch).
    Step,
}

fn f64_text(x: f64) -> String {
    // Debug prints the shortest text that parses back to the same bits
    format!("{x:?}")
}

fn linear_name(l: LinearBackend) -> &'static str {
    match l {
        LinearBackend::Dense => "dense",
        LinearBackend::Sparse => "sparse",
        LinearBackend::SparseLu => "sparse-lu",
        LinearBackend::Auto => "auto",
    }
}

/// The run record of a run of `model` with `settings` and the node parameters that decide what
/// the core does and publishes (`params`); `kind` is one of the `KIND_` names.
pub fn run_info(
    kind: &str,
    model: &Model,
    scene_label: &str,
    settings: &SimSettings,
    params: &NodeParams,
) -> RunInfo {
    let mut r = RunInfo::new();
    let mut put = |k: &str, v: String| {
        r.insert(k.to_string(), v);
    };
    put(KEY_KIND, kind.into());
    put("tensegrity_version", env!("CARGO_PKG_VERSION").into());
    put("scene", model.source.to_string());
    put("scene_file", scene_label.into());
    put("scene_name", model.name.clone());
    put("dt", f64_text(settings.dt));
    let (integrator, rho) = match settings.integrator {
        Integrator::GeneralizedAlpha { rho_inf } => ("generalized-alpha", rho_inf),
        Integrator::SymplecticEuler => ("symplectic-euler", params.rho_inf),
        Integrator::Rk4 => ("rk4", params.rho_inf),
        Integrator::DormandPrince => ("dormand-prince", params.rho_inf),
    };
    put("integrator", integrator.into());
    put("rho_inf", f64_text(rho));
    put("tolerance", settings.tolerance.map_or("none".into(), f64_text));
    put("min_dt", f64_text(settings.min_dt));
    put("linear", linear_name(settings.linear).into());
    put("newton_tolerance", f64_text(settings.newton.tolerance));
    put("newton_max_iterations", settings.newton.max_iterations.to_string());
    put("newton_reuse_factorization", settings.newton.reuse_factorization.to_string());
    put("follow_schedule", params.follow_schedule.to_string());
    put("state_publish_rate", f64_text(params.state_publish_rate));
    put("markers_rate", f64_text(params.markers_rate));
    put("command_timeout", f64_text(params.command_timeout));
    put("command_timeout_action", params.command_timeout_action.clone());
    put("frame_id", params.frame_id.clone());
    put("node_name", params.node_name.clone());
    put("namespace", params.namespace.clone());
    r
}

/// Why a run record cannot be run again.
fn record_err(key: &str, why: impl std::fmt::Display) -> String {
    format!("run record: {key}: {why}")
}

/// The simulator settings and node parameters of a run record (the inverse of `run_info`).
pub fn settings_of(run: &RunInfo) -> Result<(SimSettings, NodeParams), String> {
    let get = |k: &str| run.get(k).map(String::as_str).ok_or_else(|| record_err(k, "missing"));
    let num = |k: &str| -> Result<f64, String> { get(k)?.parse::<f64>().map_err(|e| record_err(k, e)) };
    let integrator = Integrator::parse(get("integrator")?, num("rho_inf")?)
        .ok_or_else(|| record_err("integrator", "unknown"))?;
    let linear = match get("linear")? {
        "dense" => LinearBackend::Dense,
        "sparse" => LinearBackend::Sparse,
        "sparse-lu" => LinearBackend::SparseLu,
        "auto" => LinearBackend::Auto,
        other => return Err(record_err("linear", format!("unknown '{other}'"))),
    };
    let newton = NewtonSettings {
        tolerance: num("newton_tolerance")?,
        max_iterations: get("newton_max_iterations")?
            .parse()
            .map_err(|e| record_err("newton_max_iterations", e))?,
        reuse_factorization: get("newton_reuse_factorization")? == "true",
    };
    let tolerance = match get("tolerance")? {
        "none" => None,
        _ => Some(num("tolerance")?),
    };
    let settings =
        SimSettings { dt: num("dt")?, integrator, newton, min_dt: num("min_dt")?, linear, tolerance };
    let mut params = NodeParams {
        node_name: get("node_name")?.into(),
        namespace: get("namespace")?.into(),
        real_time_factor: 0.0,
        start_paused: true,
        ..NodeParams::default()
    };
    for k in [
        "follow_schedule",
        "state_publish_rate",
        "markers_rate",
        "command_timeout",
        "command_timeout_action",
        "frame_id",
    ] {
        params.set(k, get(k)?).map_err(|e| record_err(k, e))?;
    }
    Ok((settings, params))
}

/// The topics a node with `params` publishes, and the applied commands, as bag topics: the
/// `Topic` each comes from (`None`: applied commands).
pub fn node_topics(params: &NodeParams) -> Vec<(Option<Topic>, TopicSpec)> {
    let mut out = Vec::new();
    for topic in Topic::ALL {
        if topic == Topic::Markers && params.markers_rate <= 0.0 {
            continue;
        }
        if let Some((type_name, qos)) = topic_type(topic) {
            let spec = TopicSpec { name: topic_name(topic.name(), params), type_name: type_name.into(), qos };
            out.push((Some(topic), spec));
        }
    }
    let applied = TopicSpec {
        name: applied_commands_topic(params),
        type_name: "tensegrity_msgs/msg/AppliedCommands".into(),
        qos: TopicQos { depth: 100, transient_local: false },
    };
    out.push((None, applied));
    out
}

/// Records a `StepBatch` holds before the recorder hands it to the bag's writer thread (a
/// record is one step's `/clock` or one state, whatever topics it is published on): one queue
/// operation per batch instead of two per step. A node stepping at 1 kHz with its state every
/// step hands over a batch every 20 ms; the writer's work on it (about 17 us per prism3 step,
/// 40 us per tower step: `record_overhead`'s CPU per step of all threads less the node
/// thread's) is then 0.3-0.8 ms. Each hand-over costs the node's next turns (queue, recycled
/// batch, lines the writer read): at 10 records (5 ms) recording added 14-23 % to prism3's mean
/// turn in four interleaved runs (`record_overhead`, 100 ms blocks), at 40 records 10-18 %
/// alternated with them (tower 9-12 % and 7-8 %); 100 records was no better than 40. Until then
/// its records wait on the node's thread: a process killed with SIGKILL loses them (20 ms at
/// 1 kHz) with the chunk the writer had open.
pub const BATCH_RECORDS: usize = 40;

/// The most numbers a `StepBatch` has room for (128 KiB; `BATCH_RECORDS` states when those
/// take less, one state when it takes more): a batch of large states (a 64-stage tower packs
/// about 5000 numbers) is handed over before it holds `BATCH_RECORDS` records.
pub const BATCH_NUMBERS: usize = 16 * 1024;

/// One record of a `StepBatch`: what the writer thread builds the messages of.
#[derive(Debug, Clone, Copy)]
enum BatchRecord {
    /// `/clock` at sim time `time`, s, after `steps` steps (`NodeStats::steps`, the MCAP
    /// sequence).
    Clock { time: f64, steps: u64, log_time: u64 },
    /// A state packed in `StepBatch::numbers`.
    State(StateRecord),
}

/// A packed state's header: where its numbers are, its counters, and its topics.
#[derive(Debug, Clone, Copy)]
struct StateRecord {
    /// Offset of the state's numbers in `StepBatch::numbers` (`pack_state`).
    start: usize,
    /// Offset of its point positions there, when packed (`pack_points`).
    points: Option<usize>,
    /// Sim time, s, and the node's step count (`NodeStats::steps`, the MCAP sequence): to
    /// tell whether a view is this state (`StepBatch::latest_state_of`).
    time: f64,
    steps: u64,
    /// The log time of this state's messages.
    log_time: u64,
    /// The topics published from this state, in order.
    topics: [Topic; DEFERRED.len()],
    topic_count: u8,
}

/// The view the writer thread builds a batch's messages from: the unpacked state and the
/// batch's constants. The state messages (`DEFERRED`, `/clock`) read no counters, so those are
/// zero but the step count (`NodeStats::steps`).
fn rebuilt_view<'a>(
    unpacked: &'a UnpackedState,
    reference: &'a [Vec<f64>],
    frame_id: &'a str,
    node_name: &'a str,
    constants: ConstantsId,
    steps: u64,
) -> NodeView<'a> {
    NodeView {
        model: &unpacked.model,
        state: &unpacked.state,
        workspace: &unpacked.workspace,
        rates: &unpacked.rates,
        reference,
        frame_id,
        node_name,
        constants,
        diagnostics: &[],
        step: 0,
        simulation_state: 0,
        faulted: false,
        stats: NodeStats { steps, ..NodeStats::default() },
        dt: 0.0,
    }
}

/// The states (and `/clock` messages) of up to `BATCH_RECORDS` steps as the recorder hands
/// them to the bag's writer thread, which builds and serializes their messages (`Compose`).
/// On the node's thread recording a step appends the numbers its messages read to one flat
/// vector (`pack_state`, and `pack_points` with the markers) and a small header: a few hundred
/// nanoseconds, no allocation once the batch is sized, no queue operation but every
/// `BATCH_RECORDS` records. The writer thread unpacks each state into `view` (`unpack_state`,
/// the same bits) to build its messages.
struct StepBatch {
    records: Vec<BatchRecord>,
    /// The states' numbers (capacity fixed at creation, `full`).
    numbers: Vec<f64>,
    /// The numbers `pack_state` packs for one state of the model (`packed_len`), and those of
    /// its points (`pack_points`).
    packed_len: usize,
    points_len: usize,
    /// Constant over a batch (a view with other constants starts a new batch), named by
    /// `constants` (`None` until the batch takes a view's).
    reference: Vec<Vec<f64>>,
    frame_id: String,
    node_name: String,
    constants: Option<ConstantsId>,
    /// Bag topic of each `Topic`, in `Topic::ALL` order (the recorder's).
    handles: [Option<BagTopic>; 10],
    /// The writer thread's unpacked state, to build messages from.
    view: UnpackedState,
    /// Reused serialization buffer.
    buffer: Vec<u8>,
}

/// A state as `unpack_state` rebuilds it on the writer thread: only what the messages read.
struct UnpackedState {
    model: std::sync::Arc<Model>,
    state: State,
    /// Points (positions only), cable responses and segment lengths.
    workspace: Workspace,
    rates: Vec<f64>,
}

impl StepBatch {
    fn new(model: std::sync::Arc<Model>, handles: [Option<BagTopic>; 10]) -> Self {
        let (packed_len, points_len) = (packed_len(&model), 3 * model.points.len());
        let state_len = packed_len + points_len;
        Self {
            handles,
            records: Vec::with_capacity(BATCH_RECORDS),
            numbers: Vec::with_capacity((BATCH_RECORDS * state_len).min(BATCH_NUMBERS).max(state_len)),
            packed_len,
            points_len,
            reference: Vec::new(),
            frame_id: String::new(),
            node_name: String::new(),
            constants: None,
            view: UnpackedState {
                state: State::initial(&model),
                workspace: Workspace::for_forces(&model),
                rates: vec![0.0; model.cables.len()],
                model,
            },
            buffer: Vec::new(),
        }
    }

    /// True when a new record might not fit: `BATCH_RECORDS` records, or numbers within one
    /// state (with its points) of their capacity, so that a batch never grows once sized.
    fn full(&self) -> bool {
        self.records.len() >= BATCH_RECORDS
            || self.numbers.len() + self.packed_len + self.points_len > self.numbers.capacity()
    }

    /// True when the batch is empty or its constants (pulley reference, frame, node name) are
    /// `view`'s, known by their id (`NodeView::constants`): one comparison, where comparing the
    /// values on every state cost the node's turn a few cold cache lines per pulley.
    fn accepts(&self, view: &NodeView<'_>) -> bool {
        self.records.is_empty() || self.constants == Some(view.constants)
    }

    /// Copies `view`'s constants into the batch, which must be empty (its records would
    /// otherwise change constants).
    fn take_constants(&mut self, view: &NodeView<'_>) {
        debug_assert!(self.records.is_empty(), "a batch's constants hold for all its records");
        if self.constants == Some(view.constants) {
            return;
        }
        self.reference.resize_with(view.reference.len(), Vec::new);
        for (to, from) in self.reference.iter_mut().zip(view.reference) {
            to.clear();
            to.extend_from_slice(from);
        }
        self.frame_id.clear();
        self.frame_id.push_str(view.frame_id);
        self.node_name.clear();
        self.node_name.push_str(view.node_name);
        self.constants = Some(view.constants);
    }

    /// The latest record when it is a state, and `view`'s state.
    fn latest_state_of(&mut self, view: &NodeView<'_>) -> Option<&mut StateRecord> {
        match self.records.last_mut() {
            // (room for one more topic: a topic published twice makes a new record)
            Some(BatchRecord::State(r))
                if r.steps == view.stats.steps
                    && r.time.to_bits() == view.state.time.to_bits()
                    && usize::from(r.topic_count) < r.topics.len() =>
            {
                Some(r)
            }
            _ => None,
        }
    }

    /// Appends `view`'s state, to be logged at `log_time` (`accepts(view)` first, and
    /// `take_constants(view)` when the batch is empty).
    fn push_state(&mut self, view: &NodeView<'_>, log_time: u64) {
        let start = self.numbers.len();
        pack_state(view, self.packed_len, &mut self.numbers);
        self.records.push(BatchRecord::State(StateRecord {
            start,
            points: None,
            time: view.state.time,
            steps: view.stats.steps,
            log_time,
            topics: [Topic::Clock; DEFERRED.len()],
            topic_count: 0,
        }));
    }

    /// Empties the batch for reuse (its capacity stays).
    fn clear(&mut self) {
        self.records.clear();
        self.numbers.clear();
    }
}

/// Appends what the state messages read from `view` to `out` (`len` numbers, `packed_len` of
/// its model), in the order `unpack_state` reads it back: time; per body position (3) and
/// rotation quaternion (i, j, k, w); rest lengths; per cable length, rest length, tension and
/// slack (1 or 0); segment lengths; rates.
/// Sizes are the model's. Point positions, which the markers alone read, are appended by
/// `pack_points` when a state is published on `~/markers`. What no message reads (velocities,
/// multipliers, length rates, energies) is not copied: a message that comes to read more must
/// be packed here too (the replay tests compare every recorded message with the live one).
/// `out` has room for `len` more numbers (`StepBatch::full`): nothing is allocated.
fn pack_state(view: &NodeView<'_>, len: usize, out: &mut Vec<f64>) {
    let (state, ws) = (view.state, view.workspace);
    let start = out.len();
    out.push(state.time);
    for pose in &state.poses {
        out.extend_from_slice(pose.position.as_slice());
        out.extend_from_slice(pose.rotation.coords.as_slice());
    }
    out.extend_from_slice(&state.rest_lengths);
    for c in &ws.cables {
        out.extend_from_slice(&[c.length, c.rest_length, c.tension, if c.slack { 1.0 } else { 0.0 }]);
    }
    out.extend_from_slice(&ws.segment_lengths);
    out.extend_from_slice(view.rates);
    debug_assert_eq!(out.len() - start, len, "packed_len is what pack_state packs");
}

/// How many numbers `pack_state` packs for a state of `model`.
fn packed_len(model: &Model) -> usize {
    let segments: usize = model.cables.iter().map(|c| c.segment_count()).sum();
    1 + 7 * model.bodies.len() + 5 * model.cables.len() + segments + model.cables.len()
}

/// Appends every point's position (3 each) of `view` to `out`.
fn pack_points(view: &NodeView<'_>, out: &mut Vec<f64>) {
    for p in &view.workspace.points {
        out.extend_from_slice(p.position.as_slice());
    }
}

/// Reads a state packed by `pack_state` from `numbers` into `to` (sized for the same model),
/// bit for bit, and the point positions from `points` when given (`pack_points`).
fn unpack_state(numbers: &[f64], points: Option<&[f64]>, to: &mut UnpackedState) {
    let mut at = 0;
    let mut take = |n: usize| {
        let part = &numbers[at..at + n];
        at += n;
        part
    };
    let state = &mut to.state;
    state.time = take(1)[0];
    for pose in &mut state.poses {
        pose.position = Vector3::from_column_slice(take(3));
        let q = take(4);
        pose.rotation = UnitQuaternion::new_unchecked(Quaternion::new(q[3], q[0], q[1], q[2]));
    }
    let n = state.rest_lengths.len();
    state.rest_lengths.copy_from_slice(take(n));
    let ws = &mut to.workspace;
    for c in &mut ws.cables {
        let v = take(4);
        *c = CableResponse {
            length: v[0],
            rest_length: v[1],
            tension: v[2],
            slack: v[3] != 0.0,
            // not read by any message (`pack_state`)
            length_rate: 0.0,
            energy: 0.0,
        };
    }
    let n = ws.segment_lengths.len();
    ws.segment_lengths.copy_from_slice(take(n));
    let n = to.rates.len();
    to.rates.copy_from_slice(take(n));
    if let Some(points) = points {
        for (p, xyz) in ws.points.iter_mut().zip(points.chunks_exact(3)) {
            p.position = Vector3::from_column_slice(xyz);
        }
    }
}

impl Compose for StepBatch {
    fn compose(&mut self, out: &mut crate::io::bag::MessageOut<'_>) {
        let Self {
            records,
            numbers,
            reference,
            frame_id,
            node_name,
            constants,
            handles,
            view: unpacked,
            buffer,
            points_len,
            ..
        } = self;
        for record in records.iter() {
            let (topics, steps, log_time): (&[Topic], _, _) = match record {
                BatchRecord::Clock { time, steps, log_time } => {
                    // `/clock` reads the time alone
                    unpacked.state.time = *time;
                    (&[Topic::Clock], *steps, *log_time)
                }
                BatchRecord::State(r) => {
                    let points = r.points.map(|at| &numbers[at..at + *points_len]);
                    unpack_state(&numbers[r.start..], points, unpacked);
                    (&r.topics[..usize::from(r.topic_count)], r.steps, r.log_time)
                }
            };
            let constants = constants.expect("a batch with records took their constants");
            let view = rebuilt_view(unpacked, reference, frame_id, node_name, constants, steps);
            for &topic in topics {
                let Some(handle) = handles[topic.index()] else { continue };
                // finiteness was checked on the node's thread (`BagRecorder::publish`)
                if let Ok(Some(message)) = TopicMessage::build(topic, &view) {
                    if crate::io::bag::encode_cdr(buffer, &message).is_ok() {
                        out(handle, steps as u32, log_time, buffer);
                    }
                }
            }
        }
    }

    fn items(&self) -> u64 {
        self.records.len() as u64
    }

    fn into_any(self: Box<Self>) -> Box<dyn std::any::Any + Send> {
        self
    }
}

/// The bag options of a node's recording: the defaults with the writer thread in the
/// background (`BagOptions::background`), as the node steps in real time.
pub fn node_bag_options() -> BagOptions {
    BagOptions { background: true, ..BagOptions::default() }
}

/// Records what the core publishes and applies: a `NodeSink` and a `Transport` (with no inputs)
/// of the node's loop, or a sink of an offline run.
pub struct BagRecorder {
    /// The bag (taken by `finish`).
    writer: Option<BagWriter>,
    model: std::sync::Arc<Model>,
    /// The latest states and clocks, not yet handed to the writer thread (they go when the
    /// batch is full, any other message comes, or the bag closes).
    batch: Option<Box<StepBatch>>,
    /// Bag topic of each `Topic`, in `Topic::ALL` order.
    topics: [Option<BagTopic>; 10],
    applied: BagTopic,
    actuator_names: Vec<String>,
    log_time: LogTime,
    /// The latest state stamped (steps, time bits) and its log time (`stamp_of`).
    latest_stamp: Option<((u64, u64), u64)>,
}

impl BagRecorder {
    /// Creates the bag `dir` for a run of `model` whose outputs a core with `params` publishes;
    /// `run` is its run record (`run_info`, plus any keys of the run's own). `options.queue`
    /// counts records (states, clocks, messages): the writer's queue holds that many divided by
    /// `BATCH_RECORDS` jobs, at least one.
    pub fn create(
        dir: &Path,
        model: &Model,
        params: &NodeParams,
        run: &RunInfo,
        log_time: LogTime,
        options: &BagOptions,
    ) -> Result<Self, BagError> {
        let specs = node_topics(params);
        // the queue holds batches of states: as many states as `options.queue` messages
        let options = BagOptions { queue: options.queue.div_ceil(BATCH_RECORDS), ..options.clone() };
        let writer = BagWriter::create(dir, specs.iter().map(|(_, s)| s.clone()).collect(), run, &options)?;
        let mut topics = [None; 10];
        let mut applied = BagTopic(0);
        for (k, (topic, _)) in specs.iter().enumerate() {
            match topic {
                Some(t) => topics[t.index()] = Some(BagTopic(k)),
                None => applied = BagTopic(k),
            }
        }
        Ok(Self {
            writer: Some(writer),
            model: std::sync::Arc::new(model.clone()),
            batch: None,
            topics,
            applied,
            actuator_names: model.actuator_names.clone(),
            log_time,
            latest_stamp: None,
        })
    }

    /// A recorder for the node `core` will serve, into `dir` (the node's `record` parameter).
    pub fn for_node(core: &NodeCore, dir: &Path) -> Result<Self, BagError> {
        let params = core.params();
        let label = params.scene.as_ref().map_or("<bundled prism3>".into(), |p| p.display().to_string());
        let sim = core.simulator();
        let run = run_info(KIND_NODE, sim.model(), &label, sim.settings(), params);
        Self::create(dir, sim.model(), params, &run, LogTime::Wall, &node_bag_options())
    }

    /// The bag directory.
    pub fn dir(&self) -> &Path {
        self.writer.as_ref().expect("open until finished").dir()
    }

    fn writer(&mut self) -> &mut BagWriter {
        self.writer.as_mut().expect("open until finished")
    }

    /// Hands the batch of states and clocks to the writer thread (dropped whole, and an error,
    /// when its queue is full).
    fn send_pending(&mut self) -> Result<(), BagError> {
        match self.batch.take_if(|b| !b.records.is_empty()) {
            Some(batch) => self.writer().compose(batch, true),
            None => Ok(()),
        }
    }

    /// The batch to append a record of `view` to: the current one unless it is full or (when
    /// `constants` is true, for a state) holds other constants, in which case it is handed over
    /// first and the result says whether that worked; else one the writer gave back, else a new
    /// one.
    fn batch_for(&mut self, view: &NodeView<'_>, constants: bool) -> (&mut StepBatch, Result<(), BagError>) {
        let mut sent = Ok(());
        if self.batch.as_mut().is_some_and(|b| b.full() || (constants && !b.accepts(view))) {
            sent = self.send_pending();
        }
        let (model, writer, topics) = (&self.model, &self.writer, self.topics);
        let batch = self.batch.get_or_insert_with(|| {
            let mut batch = writer
                .as_ref()
                .and_then(BagWriter::recycled::<StepBatch>)
                .unwrap_or_else(|| Box::new(StepBatch::new(model.clone(), topics)));
            batch.clear();
            batch
        });
        if batch.records.is_empty() {
            batch.take_constants(view);
        }
        (batch, sent)
    }

    /// Closes the bag (see `BagWriter::finish`), after handing over the last batch (dropped,
    /// like any batch, when the queue is full; `dropped` counts its records).
    pub fn finish(mut self) -> Result<BagSummary, BagError> {
        let _ = self.send_pending();
        self.writer.take().expect("open until finished").finish()
    }

    /// Records (states, clocks) and messages refused because the writer's queue was full.
    pub fn dropped(&self) -> u64 {
        self.writer.as_ref().map_or(0, BagWriter::dropped)
    }

    fn stamp(&self, time: f64, step: u64) -> u64 {
        match self.log_time {
            LogTime::Wall => SystemTime::now().duration_since(UNIX_EPOCH).map_or(0, |d| d.as_nanos() as u64),
            LogTime::SimTime => (time.max(0.0) * 1e9).round() as u64,
            LogTime::Step => step.saturating_mul(1_000_000),
        }
    }

    /// The log time of `view`'s messages: that of the first message of the same state (one
    /// clock reading per step, not one per topic).
    fn stamp_of(&mut self, view: &NodeView<'_>) -> u64 {
        let key = (view.stats.steps, view.state.time.to_bits());
        match self.latest_stamp {
            Some((k, log_time)) if k == key => log_time,
            _ => {
                let log_time = self.stamp(view.state.time, view.stats.steps);
                self.latest_stamp = Some((key, log_time));
                log_time
            }
        }
    }

    fn write_applied(&mut self, m: &AppliedCommands) {
        let log_time = self.stamp(m.header.stamp.seconds(), m.step);
        // never dropped: a bag without its commands cannot be replayed
        // a state dropped for want of room is counted by the writer; the commands still go
        let _ = self.send_pending();
        let applied = self.applied;
        if let Err(e) = self.writer().write(applied, m.step as u32, log_time, m, false) {
            eprintln!("bag {}: applied commands at step {} not recorded: {e}", self.dir().display(), m.step);
        }
    }
}

impl NodeSink for BagRecorder {
    fn publish(&mut self, topic: Topic, view: &NodeView<'_>) -> Result<(), PublishError> {
        let Some(handle) = self.topics[topic.index()] else {
            return Ok(());
        };
        let step = view.stats.steps;
        let failed = |e: BagError| PublishError::Failed(format!("bag: {e}"));
        if topic == Topic::Clock {
            let log_time = self.stamp_of(view);
            let (batch, sent) = self.batch_for(view, false);
            batch.records.push(BatchRecord::Clock { time: view.state.time, steps: step, log_time });
            // a dropped batch is reported with this message, which still goes
            return sent.map_err(failed);
        }
        if DEFERRED.contains(&topic) {
            if topic == Topic::CableStates && !cables_finite(view.workspace) {
                return Err(PublishError::Failed("refusing to publish non-finite cable states".into()));
            }
            // a further topic of the state recorded last (known by its step count and time)
            // joins its record, whose constants were checked when it was pushed
            let held = self.batch.as_mut().is_some_and(|b| b.latest_state_of(view).is_some());
            let mut sent = Ok(());
            if !held {
                let log_time = self.stamp_of(view);
                let (batch, result) = self.batch_for(view, true);
                batch.push_state(view, log_time);
                sent = result;
            }
            let batch = self.batch.as_mut().expect("holds the state");
            let at = batch.numbers.len();
            let record = batch.latest_state_of(view).expect("the latest record is this state");
            record.topics[usize::from(record.topic_count)] = topic;
            record.topic_count += 1;
            if topic == Topic::Markers && record.points.is_none() {
                record.points = Some(at);
                pack_points(view, &mut batch.numbers);
            }
            return sent.map_err(failed);
        }
        let log_time = self.stamp_of(view);
        // the batch goes first (in order); if it was dropped, this message still goes and the
        // failure is reported with it
        let pending = self.send_pending();
        let Some(message) = TopicMessage::build(topic, view)? else { return pending.map_err(failed) };
        self.writer().write(handle, step as u32, log_time, &message, droppable(topic)).map_err(failed)?;
        pending.map_err(failed)
    }

    fn step_request_done(&mut self, _ticket: u64, _result: msg::SimResult, _view: &NodeView<'_>) {}

    fn commands_applied(&mut self, time: f64, step: u64, commands: &[(ActuatorId, ActuatorCommand)]) {
        let m = AppliedCommands::new(&self.actuator_names, time, step, commands);
        self.write_applied(&m);
    }

    fn simulation_reset(&mut self, time: f64, step: u64) {
        let m = AppliedCommands {
            header: msg::Header { stamp: msg::Time::from_seconds(time), frame_id: String::new() },
            step,
            reset: true,
            ..Default::default()
        };
        self.write_applied(&m);
    }
}

/// True when a full writer queue may drop `topic`'s messages from a bag: every topic but what a
/// late joiner needs (the structure, the static transforms). Applied commands are never dropped.
fn droppable(topic: Topic) -> bool {
    !matches!(topic, Topic::Structure | Topic::TfStatic)
}

/// The topics whose messages the writer thread builds from a `StepBatch`'s states. `/clock`
/// goes in the batch too (its time alone); the others are built on the node's thread: those
/// sent once or rarely.
const DEFERRED: [Topic; 5] =
    [Topic::Tf, Topic::BodyPoses, Topic::CableStates, Topic::ActuatorStates, Topic::Markers];

/// True when every cable number the cable-states message carries is finite (what
/// `TopicMessage::build` refuses otherwise, checked before the message is deferred).
fn cables_finite(ws: &Workspace) -> bool {
    ws.cables.iter().all(|c| c.tension.is_finite() && c.length.is_finite() && c.rest_length.is_finite())
        && ws.segment_lengths.iter().all(|l| l.is_finite())
}

impl Drop for BagRecorder {
    /// Hands over the last batch; the bag itself closes when its writer drops.
    fn drop(&mut self) {
        if self.writer.is_some() {
            let _ = self.send_pending();
        }
    }
}

impl Transport for BagRecorder {
    fn name(&self) -> &'static str {
        "record"
    }
    fn take_inputs(&mut self, _core: &mut NodeCore, _others: &mut dyn NodeSink) {}
    fn takes_inputs(&self) -> bool {
        false
    }
}

/// Publishes a quasi-static path (rows of equilibria, no core) to a sink as the node would
/// publish states: structure and static transforms first, then per row the state topics and
/// the clock, stamped with the row's schedule time; the sequence is the row index.
pub struct PathPublisher {
    reference: Vec<Vec<f64>>,
    previous: Option<(f64, Vec<f64>)>,
    rates: Vec<f64>,
    rows: u64,
    frame_id: String,
    node_name: String,
    constants: ConstantsId,
}

impl PathPublisher {
    /// A publisher for a path of `model` that starts at `state` (evaluated in `ws`).
    pub fn new(model: &Model, state: &State, ws: &Workspace, params: &NodeParams) -> Self {
        Self {
            reference: crate::report::all_pulley_coordinates(model, state, ws),
            previous: None,
            rates: vec![0.0; model.cables.len()],
            rows: 0,
            frame_id: params.frame_id.clone(),
            node_name: params.node_name.clone(),
            constants: ConstantsId::fresh(),
        }
    }

    fn view<'a>(&'a self, model: &'a Model, state: &'a State, ws: &'a Workspace) -> NodeView<'a> {
        NodeView {
            model,
            state,
            workspace: ws,
            rates: &self.rates,
            reference: &self.reference,
            frame_id: &self.frame_id,
            node_name: &self.node_name,
            constants: self.constants,
            diagnostics: &[],
            step: self.rows,
            simulation_state: crate::io::node::sim_state::PLAYING,
            faulted: false,
            stats: NodeStats { steps: self.rows, ..Default::default() },
            dt: 0.0,
        }
    }

    /// Publishes one row (the first also publishes the structure and static transforms).
    pub fn row(&mut self, sink: &mut dyn NodeSink, model: &Model, state: &State, ws: &Workspace) {
        match &self.previous {
            Some((t, rest)) if state.time != *t => {
                for (r, (now, before)) in self.rates.iter_mut().zip(state.rest_lengths.iter().zip(rest)) {
                    *r = (now - before) / (state.time - t);
                }
            }
            _ => self.rates.fill(0.0),
        }
        let view = self.view(model, state, ws);
        let first = self.previous.is_none();
        // a sink's failure is its own to report (a recorder prints it when it closes)
        if first {
            let _ = sink.publish(Topic::Structure, &view);
            let _ = sink.publish(Topic::TfStatic, &view);
        }
        for t in Topic::STATE.into_iter().chain([Topic::Clock]) {
            let _ = sink.publish(t, &view);
        }
        self.previous = Some((state.time, state.rest_lengths.clone()));
        self.rows += 1;
    }
}

// ----- replay -----------------------------------------------------------------------------------

/// The first difference between a bag and its re-run.
#[derive(Debug, Clone, PartialEq)]
pub struct Difference {
    /// The step count (MCAP sequence) of the recorded message.
    pub step: u64,
    /// The topic.
    pub topic: String,
    /// The first field that differs (`tension[3]`), or what differs about the messages.
    pub field: String,
    /// The recorded value.
    pub recorded: String,
    /// The re-run's value.
    pub rerun: String,
    /// |recorded - rerun| for numbers.
    pub by: Option<f64>,
}

impl std::fmt::Display for Difference {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "first difference at step {} on {}: {}: recorded {}, re-run {}",
            self.step, self.topic, self.field, self.recorded, self.rerun
        )?;
        if let Some(by) = self.by {
            write!(f, " (differs by {by:.3e})")?;
        }
        Ok(())
    }
}

/// What a replay found.
#[derive(Debug, Clone, PartialEq)]
pub struct ReplayReport {
    /// Recorded messages compared bit for bit (diagnostics are not compared).
    pub compared: u64,
    /// Steps re-run.
    pub steps: u64,
    /// Command batches and resets applied from the bag.
    pub command_batches: u64,
    /// Resets applied from the bag.
    pub resets: u64,
    /// Messages of the re-run that the bag lacks because its writer dropped them (a full queue
    /// drops whole states, `BagWriter::write`): skipped, the rest is compared.
    pub missing: u64,
    /// The first difference, if any.
    pub difference: Option<Difference>,
    /// Why the bag stopped before its end (a cut bag: compared up to there), if it did.
    pub cut_short: Option<String>,
}

/// Why a bag could not be replayed at all.
#[derive(Debug, thiserror::Error)]
pub enum ReplayError {
    /// The bag could not be read.
    #[error(transparent)]
    Bag(#[from] BagError),
    /// The bag holds no run record, or one that cannot be run.
    #[error("{path}: {reason}")]
    Run {
        /// The bag.
        path: PathBuf,
        /// Why.
        reason: String,
    },
}

/// A message of the re-run: topic name, sequence (step), serialized bytes, and whether a bag
/// may lack it (`droppable`).
struct Produced {
    topic: String,
    sequence: u32,
    data: Vec<u8>,
    droppable: bool,
}

/// Collects what a re-run publishes, serialized as the recorder would, and passes it on to an
/// optional recorder (`--out`).
struct RerunSink {
    names: [Option<String>; 10],
    produced: VecDeque<Produced>,
    applied: u64,
    out: Option<BagRecorder>,
}

impl NodeSink for RerunSink {
    fn publish(&mut self, topic: Topic, view: &NodeView<'_>) -> Result<(), PublishError> {
        if let Some(out) = &mut self.out {
            let _ = out.publish(topic, view);
        }
        let (Some(name), false) = (&self.names[topic.index()], topic == Topic::Diagnostics) else {
            return Ok(());
        };
        let Some(message) = TopicMessage::build(topic, view)? else { return Ok(()) };
        let mut data = Vec::new();
        crate::io::bag::encode_cdr(&mut data, &message).map_err(|e| PublishError::Failed(e.to_string()))?;
        self.produced.push_back(Produced {
            topic: name.clone(),
            sequence: view.stats.steps as u32,
            data,
            droppable: droppable(topic),
        });
        Ok(())
    }
    fn step_request_done(&mut self, _ticket: u64, _result: msg::SimResult, _view: &NodeView<'_>) {}
    fn commands_applied(&mut self, time: f64, step: u64, commands: &[(ActuatorId, ActuatorCommand)]) {
        self.applied += 1;
        if let Some(out) = &mut self.out {
            out.commands_applied(time, step, commands);
        }
    }
    fn simulation_reset(&mut self, time: f64, step: u64) {
        if let Some(out) = &mut self.out {
            out.simulation_reset(time, step);
        }
    }
}

/// Steps the re-run has taken (since the start).
fn steps_of(rerun: &Rerun) -> u64 {
    match rerun {
        Rerun::Core { core, .. } => core.stats().steps,
        Rerun::Path => 0,
    }
}

/// The re-run: a core (dynamic runs) or a precomputed list (quasi-static paths).
enum Rerun {
    Core { core: Box<NodeCore>, clock: Duration },
    Path,
}

/// Runs the bag `bag` again: its recorded scene (or `scene`, text and label, to try another),
/// settings and parameters, with its applied commands and resets at their recorded steps, and
/// compares every recorded message except `/diagnostics` with the re-run's, bit for bit. `out`
/// writes the re-run as a new bag.
pub fn replay(
    bag: &Path,
    scene: Option<(&str, &str)>,
    out: Option<&Path>,
) -> Result<ReplayReport, ReplayError> {
    let reader = BagReader::open(bag)?;
    let run_err = |reason: String| ReplayError::Run { path: reader.path.clone(), reason };
    let run = reader
        .run()
        .ok_or_else(|| run_err("no run record (metadata 'tensegrity'): not recorded by tensegrity".into()))?;
    let (settings, params) = settings_of(&run).map_err(run_err)?;
    let kind = run.get(KEY_KIND).cloned().unwrap_or_default();
    let (text, label) = match scene {
        Some((text, label)) => (text.to_string(), label.to_string()),
        None => (
            run.get("scene").cloned().ok_or_else(|| run_err("the run record has no scene".into()))?,
            format!("{} (recorded)", run.get("scene_file").map_or("scene", String::as_str)),
        ),
    };
    let mut model = crate::scene::from_toml(&text, &label).map_err(|e| run_err(e.to_string()))?;
    let out_recorder = |model: &Model| -> Result<Option<BagRecorder>, ReplayError> {
        let Some(dir) = out else { return Ok(None) };
        let log = if kind == KIND_QUASI_STATIC { LogTime::Step } else { LogTime::SimTime };
        let mut record = run_info(&kind, model, &label, &settings, &params);
        if let Some(steps) = run.get("steps") {
            record.insert("steps".into(), steps.clone());
        }
        Ok(Some(BagRecorder::create(dir, model, &params, &record, log, &BagOptions::default())?))
    };
    let mut names: [Option<String>; 10] = Default::default();
    for (topic, spec) in node_topics(&params) {
        if let Some(t) = topic {
            names[t.index()] = Some(spec.name);
        }
    }
    let applied_topic = applied_commands_topic(&params);
    let diagnostics = topic_name(Topic::Diagnostics.name(), &params);
    let mut rerun;
    let mut sink;
    if kind == KIND_QUASI_STATIC {
        if let Some(steps) = run.get("steps") {
            model.schedule.steps = steps.parse().map_err(|e| run_err(record_err("steps", e)))?;
        }
        sink = RerunSink { names, produced: VecDeque::new(), applied: 0, out: out_recorder(&model)? };
        let mut state = State::initial(&model);
        let mut ws = Workspace::new(&model);
        let mut publisher: Option<PathPublisher> = None;
        let result = crate::solve::statics::deploy_quasi_static(&model, &mut state, &mut ws, |_, st, w| {
            publisher
                .get_or_insert_with(|| PathPublisher::new(&model, st, w, &params))
                .row(&mut sink, &model, st, w);
        });
        if let Err(e) = result {
            return Err(run_err(format!("the re-run's quasi-static path fails: {e}")));
        }
        rerun = Rerun::Path;
    } else {
        let sim =
            Simulator::new(model, settings).map_err(|e| run_err(format!("the re-run cannot start: {e}")))?;
        let recorder = out_recorder(sim.model())?;
        let mut core = NodeCore::with_simulator(sim, params.clone());
        sink = RerunSink { names, produced: VecDeque::new(), applied: 0, out: recorder };
        core.start(&mut sink);
        rerun = Rerun::Core { core: Box::new(core), clock: Duration::ZERO };
    }
    let mut report = ReplayReport {
        compared: 0,
        steps: 0,
        command_batches: 0,
        resets: 0,
        missing: 0,
        difference: None,
        cut_short: None,
    };
    let differ = |step: u64, topic: &str, field: &str, recorded: String, rerun: String| Difference {
        step,
        topic: topic.to_string(),
        field: field.to_string(),
        recorded,
        rerun,
        by: None,
    };
    // one more step of the re-run (nothing for a path: it was computed whole)
    let advance =
        |rerun: &mut Rerun, sink: &mut RerunSink, report: &mut ReplayReport| -> Result<(), String> {
            let Rerun::Core { core, clock } = rerun else {
                return Err("the re-run's path has no more rows".into());
            };
            core.request_steps(1, sink).map_err(|r| r.error_message)?;
            *clock += Duration::from_millis(1);
            core.tick(*clock, sink);
            if let Some(f) = core.fault() {
                return Err(f.to_string());
            }
            report.steps += 1;
            Ok(())
        };
    for recorded in reader.messages() {
        let recorded = match recorded {
            Ok(m) => m,
            Err(why) => {
                report.cut_short = Some(why);
                break;
            }
        };
        if recorded.topic == diagnostics {
            continue;
        }
        if recorded.topic == applied_topic {
            let a: AppliedCommands = recorded.decode().map_err(run_err)?;
            if matches!(rerun, Rerun::Path) {
                continue;
            }
            loop {
                // what the re-run published before these commands and the bag lacks was dropped
                // by its writer (a full queue): skipped, unless it is never dropped
                while sink.produced.front().is_some_and(|m| m.droppable) {
                    sink.produced.pop_front();
                    report.missing += 1;
                }
                if steps_of(&rerun) >= a.step || !sink.produced.is_empty() {
                    break;
                }
                if let Err(why) = advance(&mut rerun, &mut sink, &mut report) {
                    report.difference = Some(differ(
                        a.step,
                        &recorded.topic,
                        "re-run",
                        "commands".into(),
                        format!("fails: {why}"),
                    ));
                    return Ok(report);
                }
            }
            let Rerun::Core { core, clock } = &mut rerun else { continue };
            if let Some(m) = sink.produced.front() {
                report.difference = Some(differ(
                    m.sequence as u64,
                    &m.topic,
                    "message",
                    "none (the bag has the applied commands next)".into(),
                    "one more".into(),
                ));
                return Ok(report);
            }
            if a.reset {
                core.reset(&mut sink);
                report.resets += 1;
            } else {
                let commands = match a.commands(core.simulator().model()) {
                    Ok(c) => c,
                    Err(e) => {
                        report.difference = Some(differ(
                            a.step,
                            &recorded.topic,
                            "commands",
                            "applied".into(),
                            format!("refused: {e}"),
                        ));
                        return Ok(report);
                    }
                };
                let before = sink.applied;
                // checked as the node checked them when they arrived (the scene may differ)
                let offered = core.offer_parsed(|model, out| {
                    commands.iter().try_for_each(|(id, cmd)| msg::check_entry(model, *id, *cmd, out))
                });
                *clock += Duration::from_millis(1);
                core.tick(*clock, &mut sink);
                let refused = match offered {
                    Err(e) => Some(e.to_string()),
                    Ok(()) if sink.applied == before => Some("not applied".into()),
                    Ok(()) => None,
                };
                if let Some(why) = refused {
                    report.difference = Some(differ(
                        a.step,
                        &recorded.topic,
                        "commands",
                        "applied".into(),
                        format!("refused: {why}"),
                    ));
                    return Ok(report);
                }
                report.command_batches += 1;
            }
            continue;
        }
        let Produced { topic, sequence, data, .. } = loop {
            while sink.produced.is_empty() {
                if let Err(why) = advance(&mut rerun, &mut sink, &mut report) {
                    report.difference = Some(differ(
                        recorded.sequence as u64,
                        &recorded.topic,
                        "message",
                        "present".into(),
                        format!("missing: {why}"),
                    ));
                    return Ok(report);
                }
            }
            let next = sink.produced.pop_front().expect("not empty");
            // a message the bag lacks from a step before the recorded one, or from the same step
            // before it, is one its writer dropped (publishing is deterministic): skipped
            let earlier = next.sequence < recorded.sequence
                || (next.sequence == recorded.sequence && next.topic != recorded.topic);
            if earlier && next.droppable {
                report.missing += 1;
                continue;
            }
            break next;
        };
        if topic != recorded.topic || sequence != recorded.sequence {
            report.difference = Some(differ(
                recorded.sequence as u64,
                &recorded.topic,
                "next message",
                format!("{} at step {}", recorded.topic, recorded.sequence),
                format!("{topic} at step {sequence}"),
            ));
            return Ok(report);
        }
        if data != recorded.data {
            report.difference = Some(first_field_difference(&recorded, &data));
            return Ok(report);
        }
        report.compared += 1;
    }
    if let Some(out) = sink.out.take() {
        out.finish()?;
    }
    Ok(report)
}

/// The first field that differs between a recorded message and the re-run's bytes of the same
/// topic (decoded by type), with the size of the difference for numbers.
fn first_field_difference(recorded: &crate::io::bag::RecordedMessage, rerun: &[u8]) -> Difference {
    let other = crate::io::bag::RecordedMessage { data: rerun.to_vec(), ..recorded.clone() };
    let mut d = Difference {
        step: recorded.sequence as u64,
        topic: recorded.topic.clone(),
        field: "bytes".into(),
        recorded: format!("{} bytes", recorded.data.len()),
        rerun: format!("{} bytes", rerun.len()),
        by: None,
    };
    if let (Ok(a), Ok(b)) = (decode_json(recorded), decode_json(&other)) {
        if let Some((path, x, y)) = first_json_difference("", &a, &b) {
            d.field = path;
            d.by = match (x.as_f64(), y.as_f64()) {
                (Some(p), Some(q)) => Some((p - q).abs()),
                _ => None,
            };
            d.recorded = x.to_string();
            d.rerun = y.to_string();
        }
    }
    d
}

/// A recorded message decoded by its type into JSON (for field-by-field comparison and display).
pub fn decode_json(m: &crate::io::bag::RecordedMessage) -> Result<serde_json::Value, String> {
    fn json<M: serde::de::DeserializeOwned + serde::Serialize>(
        m: &crate::io::bag::RecordedMessage,
    ) -> Result<serde_json::Value, String> {
        serde_json::to_value(m.decode::<M>()?).map_err(|e| e.to_string())
    }
    match m.type_name.as_str() {
        "rosgraph_msgs/msg/Clock" => json::<msg::Clock>(m),
        "tf2_msgs/msg/TFMessage" => json::<msg::TfMessage>(m),
        "geometry_msgs/msg/PoseArray" => json::<msg::PoseArray>(m),
        "tensegrity_msgs/msg/CableStates" => json::<msg::CableStates>(m),
        "sensor_msgs/msg/JointState" => json::<msg::JointState>(m),
        "tensegrity_msgs/msg/Structure" => json::<msg::Structure>(m),
        "diagnostic_msgs/msg/DiagnosticArray" => json::<msg::DiagnosticArray>(m),
        "visualization_msgs/msg/MarkerArray" => json::<msg::MarkerArray>(m),
        "tensegrity_msgs/msg/AppliedCommands" => json::<msg::AppliedCommands>(m),
        other => Err(format!("no decoder for {other}")),
    }
}

/// The first leaf (depth first, in field order) where `a` and `b` differ: its path and values.
fn first_json_difference(
    path: &str,
    a: &serde_json::Value,
    b: &serde_json::Value,
) -> Option<(String, serde_json::Value, serde_json::Value)> {
    use serde_json::Value;
    match (a, b) {
        (Value::Object(x), Value::Object(y)) => {
            for (k, v) in x {
                let p = if path.is_empty() { k.clone() } else { format!("{path}.{k}") };
                match y.get(k) {
                    Some(w) => {
                        if let Some(d) = first_json_difference(&p, v, w) {
                            return Some(d);
                        }
                    }
                    None => return Some((p, v.clone(), Value::Null)),
                }
            }
            None
        }
        (Value::Array(x), Value::Array(y)) => {
            for (i, (v, w)) in x.iter().zip(y).enumerate() {
                if let Some(d) = first_json_difference(&format!("{path}[{i}]"), v, w) {
                    return Some(d);
                }
            }
            (x.len() != y.len())
                .then(|| (format!("{path}.len()"), Value::from(x.len()), Value::from(y.len())))
        }
        // bit for bit: 0.1 + 0.2 and 0.3 differ here too
        (Value::Number(x), Value::Number(y))
            if x.as_f64().map(f64::to_bits) == y.as_f64().map(f64::to_bits) =>
        {
            None
        }
        _ if a == b => None,
        _ => Some((path.to_string(), a.clone(), b.clone())),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    struct Nowhere;

    impl NodeSink for Nowhere {
        fn publish(&mut self, _topic: Topic, _view: &NodeView<'_>) -> Result<(), PublishError> {
            Ok(())
        }
        fn step_request_done(&mut self, _ticket: u64, _result: msg::SimResult, _view: &NodeView<'_>) {}
    }

    fn cdr(topic: Topic, view: &NodeView<'_>) -> Vec<u8> {
        let message = TopicMessage::build(topic, view).unwrap().unwrap();
        let mut out = Vec::new();
        crate::io::bag::encode_cdr(&mut out, &message).unwrap();
        out
    }

    /// One recorder fed the states of two cores with different frames, turn about: each
    /// state's messages carry its own core's frame (a batch holds one set of constants, known by
    /// its id, and a view with another id starts a new batch).
    #[test]
    fn states_with_other_constants_keep_their_own_frame() {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("config/scenes/prism3.toml");
        let model = crate::scene::load(&path).unwrap();
        let core = |frame: &str| {
            let params = NodeParams {
                real_time_factor: 0.0,
                state_publish_rate: 0.0,
                frame_id: frame.into(),
                ..NodeParams::default()
            };
            let mut core = NodeCore::new(model.clone(), params).unwrap();
            core.start(&mut Nowhere);
            core
        };
        let (mut world, mut lab) = (core("world"), core("lab"));
        assert_ne!(world.view().constants, lab.view().constants);
        let dir = std::env::temp_dir().join(format!("tensegrity-record-constants-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let mut recorder = BagRecorder::for_node(&world, &dir).unwrap();
        for k in 0..25 {
            world.tick(Duration::from_millis(k), &mut recorder);
            lab.tick(Duration::from_millis(k), &mut recorder);
        }
        recorder.finish().unwrap();
        let frames: Vec<String> = crate::io::bag::BagReader::open(&dir)
            .unwrap()
            .messages()
            .map(Result::unwrap)
            .filter(|m| m.type_name == "geometry_msgs/msg/PoseArray")
            .map(|m| m.decode::<msg::PoseArray>().unwrap().header.frame_id)
            .collect();
        let expected: Vec<&str> = (0..25).flat_map(|_| ["world", "lab"]).collect();
        assert_eq!(frames, expected);
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// A state packed on the node's thread and unpacked on the writer's gives every deferred
    /// topic's message bit for bit, slack flags and markers included, for a prism whose ring
    /// cable is being wound in (moving poses, nonzero rates, pulley slip).
    #[test]
    fn a_packed_state_gives_the_same_messages_as_the_live_one() {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("config/scenes/prism3.toml");
        let model = crate::scene::load(&path).unwrap();
        let params = NodeParams { real_time_factor: 0.0, state_publish_rate: 0.0, ..NodeParams::default() };
        let mut core = NodeCore::new(model.clone(), params).unwrap();
        core.start(&mut Nowhere);
        core.offer_command(&msg::ActuatorCommand {
            name: vec!["ring_winch".into()],
            rest_length: vec![4.0],
            rate: vec![0.5],
            ..Default::default()
        });
        for k in 0..40 {
            core.tick(Duration::from_millis(k), &mut Nowhere);
        }
        let live = core.view();
        assert!(live.rates.iter().any(|r| *r != 0.0), "the winch moves");
        // one cable slack, as a live one may be
        let mut workspace = live.workspace.clone();
        workspace.cables[0].slack = true;
        let live = NodeView { workspace: &workspace, ..live };

        let mut numbers = vec![f64::NAN; 3]; // a state need not start the batch
        let start = numbers.len();
        pack_state(&live, packed_len(&model), &mut numbers);
        let points = numbers.len();
        pack_points(&live, &mut numbers);
        let mut unpacked = StepBatch::new(std::sync::Arc::new(model.clone()), [None; 10]).view;
        let point_numbers = &numbers[points..];
        assert_eq!(point_numbers.len(), 3 * model.points.len());
        unpack_state(&numbers[start..], Some(point_numbers), &mut unpacked);
        let rebuilt = rebuilt_view(
            &unpacked,
            live.reference,
            live.frame_id,
            live.node_name,
            live.constants,
            live.stats.steps,
        );
        for topic in DEFERRED.into_iter().chain([Topic::Clock]) {
            assert_eq!(cdr(topic, &rebuilt), cdr(topic, &live), "{topic:?}");
        }
    }
}
