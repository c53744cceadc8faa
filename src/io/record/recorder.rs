//! The recorder: takes what the node core publishes and applies (`BagRecorder`, a `NodeSink` and
//! a `Transport` of the node's loop) or a quasi-static path (`PathPublisher`), gives a rosbag2
//! bag through `bag::BagWriter`.

use std::path::Path;
use std::time::{SystemTime, UNIX_EPOCH};

use crate::control::ActuatorCommand;
use crate::evaluate::Workspace;
use crate::io::msg::{self, AppliedCommands};
use crate::io::node::params::NodeParams;
use crate::io::node::runner::Transport;
use crate::io::node::NodeCore;
use crate::io::record::bag::{BagError, BagOptions, BagSummary, BagTopic, BagWriter, RunInfo};
use crate::io::record::batch::{pack_points, BatchRecord, StepBatch, BATCH_RECORDS, DEFERRED};
use crate::io::record::run::{node_bag_options, node_topics, run_info, LogTime, KIND_NODE};
use crate::io::sink::TopicMessage;
use crate::io::sink::{ConstantsId, NodeSink, NodeStats, NodeView, PublishError};
use crate::io::topics::Topic;
use crate::model::{ActuatorId, Model};
use crate::state::State;

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
    topics: [Option<BagTopic>; Topic::ALL.len()],
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
        let specs = node_topics(params, model);
        // the queue holds batches of states: as many states as `options.queue` messages
        let options = BagOptions { queue: options.queue.div_ceil(BATCH_RECORDS), ..options.clone() };
        let writer = BagWriter::create(dir, specs.iter().map(|(_, s)| s.clone()).collect(), run, &options)?;
        let mut topics = [None; Topic::ALL.len()];
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

    fn simulation_reset(&mut self, time: f64, step: u64, seed: Option<u64>) {
        let m = AppliedCommands {
            header: msg::Header { stamp: msg::Time::from_seconds(time), frame_id: String::new() },
            step,
            reset: true,
            reset_seeded: seed.is_some(),
            reset_seed: seed.unwrap_or(0),
            ..Default::default()
        };
        self.write_applied(&m);
    }
}

/// True when a full writer queue may drop `topic`'s messages from a bag: every topic but what a
/// late joiner needs (the structure, the static transforms). Applied commands are never dropped.
pub(super) fn droppable(topic: Topic) -> bool {
    !matches!(topic, Topic::Structure | Topic::TfStatic)
}

/// True when every cable number the cable-states message carries is finite (what
/// `TopicMessage::build` refuses otherwise, checked before the message is deferred).
pub(super) fn cables_finite(ws: &Workspace) -> bool {
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
            simulation_state: crate::io::msg::sim_state::PLAYING,
            faulted: false,
            stats: NodeStats { steps: self.rows, ..Default::default() },
            dt: 0.0,
            measured: &[],
            lost: &[],
            imu_truth: &[],
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
        for t in Topic::STATE.into_iter().chain([Topic::Clock]).filter(|t| t.published_by(model)) {
            let _ = sink.publish(t, &view);
        }
        self.previous = Some((state.time, state.rest_lengths.clone()));
        self.rows += 1;
    }
}
