//! A recorder's batch of states: takes what the node core's views publish on the node's thread
//! (the numbers the state messages read, packed into one flat vector of fixed capacity), gives
//! the bag's writer thread the same messages, bit for bit, built and serialized there
//! (`StepBatch`, a `bag::Compose`).

use crate::evaluate::Workspace;
use crate::forces::cable::CableResponse;
use crate::forces::contact::ContactResponse;
use crate::io::record::bag::{BagTopic, Compose};
use crate::io::sink::TopicMessage;
use crate::io::sink::{ConstantsId, NodeStats, NodeView};
use crate::io::topics::Topic;
use crate::model::Model;
use crate::state::State;
use nalgebra::{Quaternion, UnitQuaternion, Vector3};

/// The topics whose messages the writer thread builds from a `StepBatch`'s states. `/clock`
/// goes in the batch too (its time alone); the others are built on the node's thread: those
/// sent once or rarely.
pub(super) const DEFERRED: [Topic; 11] = [
    Topic::Tf,
    Topic::BodyPoses,
    Topic::CableStates,
    Topic::ActuatorStates,
    Topic::Markers,
    Topic::Contacts,
    Topic::GroundTruthPoses,
    Topic::GroundTruthCables,
    Topic::Imu,
    Topic::GroundTruthImu,
    Topic::SensorReadings,
];

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
pub(super) enum BatchRecord {
    /// `/clock` at sim time `time`, s, after `steps` steps (`NodeStats::steps`, the MCAP
    /// sequence).
    Clock { time: f64, steps: u64, log_time: u64 },
    /// A state packed in `StepBatch::numbers`.
    State(StateRecord),
}

/// A packed state's header: where its numbers are, its counters, and its topics.
#[derive(Debug, Clone, Copy)]
pub(super) struct StateRecord {
    /// Offset of the state's numbers in `StepBatch::numbers` (`pack_state`).
    pub(super) start: usize,
    /// Offset of its point positions there, when packed (`pack_points`).
    pub(super) points: Option<usize>,
    /// Sim time, s, and the node's step count (`NodeStats::steps`, the MCAP sequence): to
    /// tell whether a view is this state (`StepBatch::latest_state_of`).
    pub(super) time: f64,
    pub(super) steps: u64,
    /// The log time of this state's messages.
    pub(super) log_time: u64,
    /// The topics published from this state, in order.
    pub(super) topics: [Topic; DEFERRED.len()],
    pub(super) topic_count: u8,
}

/// The view the writer thread builds a batch's messages from: the unpacked state and the
/// batch's constants. The state messages (`DEFERRED`, `/clock`) read no counters, so those are
/// zero but the step count (`NodeStats::steps`).
pub(super) fn rebuilt_view<'a>(
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
        measured: &unpacked.measured,
        lost: &unpacked.lost,
        imu_truth: &unpacked.imu_truth,
    }
}

/// The states (and `/clock` messages) of up to `BATCH_RECORDS` steps as the recorder hands
/// them to the bag's writer thread, which builds and serializes their messages (`Compose`).
/// On the node's thread recording a step appends the numbers its messages read to one flat
/// vector (`pack_state`, and `pack_points` with the markers) and a small header: a few hundred
/// nanoseconds, no allocation once the batch is sized, no queue operation but every
/// `BATCH_RECORDS` records. The writer thread unpacks each state into `view` (`unpack_state`,
/// the same bits) to build its messages.
pub(super) struct StepBatch {
    pub(super) records: Vec<BatchRecord>,
    /// The states' numbers (capacity fixed at creation, `full`).
    pub(super) numbers: Vec<f64>,
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
    handles: [Option<BagTopic>; Topic::ALL.len()],
    /// The writer thread's unpacked state, to build messages from.
    view: UnpackedState,
    /// Reused serialization buffer.
    buffer: Vec<u8>,
}

/// A state as `unpack_state` rebuilds it on the writer thread: only what the messages read.
pub(super) struct UnpackedState {
    model: std::sync::Arc<Model>,
    state: State,
    /// Points (positions only), cable responses and segment lengths.
    workspace: Workspace,
    rates: Vec<f64>,
    /// What the sensors reported (`NodeView::measured`; empty without sensors).
    measured: Vec<f64>,
    /// Their lost flags (`NodeView::lost`).
    lost: Vec<bool>,
    /// The true IMU values (`NodeView::imu_truth`; empty without a gyro or accelerometer).
    imu_truth: Vec<f64>,
}

impl StepBatch {
    pub(super) fn new(model: std::sync::Arc<Model>, handles: [Option<BagTopic>; Topic::ALL.len()]) -> Self {
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
                measured: vec![0.0; crate::sensors::layout(&model).map(|(_, _, n)| n).sum()],
                lost: vec![false; crate::sensors::layout(&model).map(|(_, _, n)| n).sum()],
                imu_truth: vec![0.0; imu_len(&model)],
                model,
            },
            buffer: Vec::new(),
        }
    }

    /// True when a new record might not fit: `BATCH_RECORDS` records, or numbers within one
    /// state (with its points) of their capacity, so that a batch never grows once sized.
    pub(super) fn full(&self) -> bool {
        self.records.len() >= BATCH_RECORDS
            || self.numbers.len() + self.packed_len + self.points_len > self.numbers.capacity()
    }

    /// True when the batch is empty or its constants (pulley reference, frame, node name) are
    /// `view`'s, known by their id (`NodeView::constants`): one comparison, where comparing the
    /// values on every state cost the node's turn a few cold cache lines per pulley.
    pub(super) fn accepts(&self, view: &NodeView<'_>) -> bool {
        self.records.is_empty() || self.constants == Some(view.constants)
    }

    /// Copies `view`'s constants into the batch, which must be empty (its records would
    /// otherwise change constants).
    pub(super) fn take_constants(&mut self, view: &NodeView<'_>) {
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
    pub(super) fn latest_state_of(&mut self, view: &NodeView<'_>) -> Option<&mut StateRecord> {
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
    pub(super) fn push_state(&mut self, view: &NodeView<'_>, log_time: u64) {
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
    pub(super) fn clear(&mut self) {
        self.records.clear();
        self.numbers.clear();
    }
}

/// Appends what the state messages read from `view` to `out` (`len` numbers, `packed_len` of
/// its model), in the order `unpack_state` reads it back: time; per body position (3) and
/// rotation quaternion (i, j, k, w); rest lengths; per cable length, rest length, tension and
/// slack (1 or 0); segment lengths; rates; per contact pair gap, normal force, friction (3),
/// slip (3), contact point (3) and normal (3).
/// Sizes are the model's. Point positions, which the markers alone read, are appended by
/// `pack_points` when a state is published on `~/markers`. What no message reads (velocities,
/// multipliers, length rates, energies) is not copied: a message that comes to read more must
/// be packed here too (the replay tests compare every recorded message with the live one).
/// `out` has room for `len` more numbers (`StepBatch::full`): nothing is allocated.
pub(super) fn pack_state(view: &NodeView<'_>, len: usize, out: &mut Vec<f64>) {
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
    for c in &ws.contacts {
        out.extend_from_slice(&[c.gap, c.normal_force]);
        out.extend_from_slice(c.friction.as_slice());
        out.extend_from_slice(c.slip.as_slice());
        out.extend_from_slice(c.position.as_slice());
        out.extend_from_slice(c.normal.as_slice());
    }
    // pulley friction: the material per segment, the tensions, and per pulley its state
    let f = &ws.friction;
    out.extend_from_slice(&state.segment_rest_lengths);
    out.extend_from_slice(&f.tensions);
    for ((s, theta), speed) in f.states.iter().zip(&f.wrap_angles).zip(&f.slip_speeds) {
        out.extend_from_slice(&[s.code(), *theta, *speed]);
    }
    // what the sensors reported, and the IMU's truth
    out.extend_from_slice(view.measured);
    out.extend(view.lost.iter().map(|l| if *l { 1.0 } else { 0.0 }));
    out.extend_from_slice(view.imu_truth);
    debug_assert_eq!(out.len() - start, len, "packed_len is what pack_state packs");
}

/// How many numbers `pack_state` packs for a state of `model`.
pub(super) fn packed_len(model: &Model) -> usize {
    let segments: usize = model.cables.iter().map(|c| c.segment_count()).sum();
    1 + 7 * model.bodies.len()
        + 5 * model.cables.len()
        + segments
        + model.cables.len()
        + 14 * model.contact_pairs()
        + 2 * model.initial_segment_rest_lengths.len()
        + 3 * model.pulley_friction.iter().map(|f| f.mu.len()).sum::<usize>()
        + 2 * crate::sensors::layout(model).map(|(_, _, n)| n).sum::<usize>()
        + imu_len(model)
}

/// How many true IMU values a view of `model` carries (`NodeView::imu_truth`).
fn imu_len(model: &Model) -> usize {
    if crate::sensors::has_imu(model) {
        6 * model.bodies.len()
    } else {
        0
    }
}

/// Appends every point's position (3 each) of `view` to `out`.
pub(super) fn pack_points(view: &NodeView<'_>, out: &mut Vec<f64>) {
    for p in &view.workspace.points {
        out.extend_from_slice(p.position.as_slice());
    }
}

/// Reads a state packed by `pack_state` from `numbers` into `to` (sized for the same model),
/// bit for bit, and the point positions from `points` when given (`pack_points`).
pub(super) fn unpack_state(numbers: &[f64], points: Option<&[f64]>, to: &mut UnpackedState) {
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
    for c in &mut ws.contacts {
        let v = take(14);
        *c = ContactResponse {
            gap: v[0],
            normal_force: v[1],
            friction: Vector3::new(v[2], v[3], v[4]),
            slip: Vector3::new(v[5], v[6], v[7]),
            position: Vector3::new(v[8], v[9], v[10]),
            normal: Vector3::new(v[11], v[12], v[13]),
            // not read by any message (`pack_state`)
            ..Default::default()
        };
    }
    let n = state.segment_rest_lengths.len();
    state.segment_rest_lengths.copy_from_slice(take(n));
    let f = &mut ws.friction;
    let n = f.tensions.len();
    f.tensions.copy_from_slice(take(n));
    for i in 0..f.states.len() {
        let v = take(3);
        f.states[i] = crate::forces::pulley::PulleyState::from_code(v[0]);
        f.wrap_angles[i] = v[1];
        f.slip_speeds[i] = v[2];
    }
    let n = to.measured.len();
    to.measured.copy_from_slice(take(n));
    for (l, v) in to.lost.iter_mut().zip(take(n)) {
        *l = *v != 0.0;
    }
    let n = to.imu_truth.len();
    to.imu_truth.copy_from_slice(take(n));
    if let Some(points) = points {
        for (p, xyz) in ws.points.iter_mut().zip(points.chunks_exact(3)) {
            p.position = Vector3::from_column_slice(xyz);
        }
    }
}

impl Compose for StepBatch {
    fn compose(&mut self, out: &mut crate::io::record::bag::MessageOut<'_>) {
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
                    if crate::io::record::bag::encode_cdr(buffer, &message).is_ok() {
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

#[cfg(test)]
mod tests {
    use std::path::Path;
    use std::time::Duration;

    use super::*;
    use crate::io::msg;
    use crate::io::node::params::NodeParams;
    use crate::io::node::NodeCore;
    use crate::io::record::BagRecorder;

    /// The CDR of `topic`'s message from `view`; `None` where the view has none (`~/imu` of a
    /// scene without an IMU).
    fn cdr(topic: Topic, view: &NodeView<'_>) -> Option<Vec<u8>> {
        let message = TopicMessage::build(topic, view).unwrap()?;
        let mut out = Vec::new();
        crate::io::record::bag::encode_cdr(&mut out, &message).unwrap();
        Some(out)
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
            core.start(&mut crate::io::sink::DiscardSink);
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
        let frames: Vec<String> = crate::io::record::bag::BagReader::open(&dir)
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
        core.start(&mut crate::io::sink::DiscardSink);
        core.offer_command(&msg::ActuatorCommand {
            name: vec!["ring_winch".into()],
            rest_length: vec![4.0],
            rate: vec![0.5],
            ..Default::default()
        });
        for k in 0..40 {
            core.tick(Duration::from_millis(k), &mut crate::io::sink::DiscardSink);
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
        let mut unpacked = StepBatch::new(std::sync::Arc::new(model.clone()), [None; Topic::ALL.len()]).view;
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
