//! Replay: takes a bag recorded by the node or an offline run, runs it again with the recorded
//! commands (and resets) at their recorded steps, and compares every recorded message with the
//! re-run's, bit for bit (`replay`, `ReplayReport`, the first `Difference`).

use std::collections::VecDeque;
use std::path::{Path, PathBuf};
use std::time::Duration;

use crate::control::ActuatorCommand;
use crate::evaluate::Workspace;
use crate::io::commands;
use crate::io::msg::{self, AppliedCommands};
use crate::io::node::NodeCore;
use crate::io::record::bag::{BagError, BagOptions, BagReader};
use crate::io::record::recorder::{droppable, BagRecorder, PathPublisher};
use crate::io::record::run::{
    node_topics, record_err, run_info, settings_of, LogTime, KEY_KIND, KIND_QUASI_STATIC,
};
use crate::io::sink::TopicMessage;
use crate::io::sink::{NodeSink, NodeView, PublishError};
use crate::io::topics::Topic;
use crate::io::topics::{applied_commands_topic, topic_name};
use crate::model::{ActuatorId, Model};
use crate::sim::Simulator;
use crate::state::State;

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
    names: [Option<String>; Topic::ALL.len()],
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
        crate::io::record::bag::encode_cdr(&mut data, &message)
            .map_err(|e| PublishError::Failed(e.to_string()))?;
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
    fn simulation_reset(&mut self, time: f64, step: u64, seed: Option<u64>) {
        if let Some(out) = &mut self.out {
            out.simulation_reset(time, step, seed);
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
    let mut names: [Option<String>; Topic::ALL.len()] = Default::default();
    for (topic, spec) in node_topics(&params, &model) {
        if let Some(t) = topic {
            names[t.index()] = Some(spec.name);
        }
    }
    let applied_topic = applied_commands_topic(&params.private_namespace());
    let diagnostics = topic_name(Topic::Diagnostics.name(), &params.private_namespace());
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
        let result = crate::solve::deploy::deploy_quasi_static(&model, &mut state, &mut ws, |_, st, w| {
            publisher
                .get_or_insert_with(|| PathPublisher::new(&model, st, w, &params))
                .row(&mut sink, &model, st, w);
        });
        if let Err(e) = result {
            return Err(run_err(format!("the re-run's quasi-static path fails: {e}")));
        }
        rerun = Rerun::Path;
    } else {
        let sim = Simulator::start(model, settings, params.start_from_equilibrium)
            .map_err(|e| run_err(format!("the re-run cannot start: {e}")))?;
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
            let a = applied_commands(&recorded).map_err(run_err)?;
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
                core.reset_seeded(a.reset_seeded.then_some(a.reset_seed), &mut sink);
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
                    commands.iter().try_for_each(|(id, cmd)| commands::check_entry(model, *id, *cmd, out))
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
fn first_field_difference(recorded: &crate::io::record::bag::RecordedMessage, rerun: &[u8]) -> Difference {
    let other = crate::io::record::bag::RecordedMessage { data: rerun.to_vec(), ..recorded.clone() };
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

/// `AppliedCommands` as bags written before tension commands stored it (no `tension` array).
#[derive(serde::Deserialize)]
struct AppliedCommandsWithoutTension {
    header: msg::Header,
    step: u64,
    reset: bool,
    name: Vec<String>,
    rest_length: Vec<f64>,
    rate: Vec<f64>,
}

/// A recorded `AppliedCommands`, from a bag of today's layout or of the one before tension
/// commands and seeded resets (whose `tension` comes back empty: none given; no reset seeded).
pub fn applied_commands(m: &crate::io::record::bag::RecordedMessage) -> Result<AppliedCommands, String> {
    m.decode::<AppliedCommands>().or_else(|why| {
        let old: AppliedCommandsWithoutTension = m.decode().map_err(|_| why)?;
        Ok(AppliedCommands {
            header: old.header,
            step: old.step,
            reset: old.reset,
            name: old.name,
            rest_length: old.rest_length,
            rate: old.rate,
            ..AppliedCommands::default()
        })
    })
}

/// A recorded message decoded by its type into JSON (for field-by-field comparison and display).
pub fn decode_json(m: &crate::io::record::bag::RecordedMessage) -> Result<serde_json::Value, String> {
    fn json<M: serde::de::DeserializeOwned + serde::Serialize>(
        m: &crate::io::record::bag::RecordedMessage,
    ) -> Result<serde_json::Value, String> {
        serde_json::to_value(m.decode::<M>()?).map_err(|e| e.to_string())
    }
    match m.type_name.as_str() {
        "rosgraph_msgs/msg/Clock" => json::<msg::Clock>(m),
        "tf2_msgs/msg/TFMessage" => json::<msg::TfMessage>(m),
        "geometry_msgs/msg/PoseArray" => json::<msg::PoseArray>(m),
        "tensegrity_msgs/msg/CableStates" => json::<msg::CableStates>(m),
        "tensegrity_msgs/msg/ContactStates" => json::<msg::ContactStates>(m),
        "tensegrity_msgs/msg/ImuStates" => json::<msg::ImuStates>(m),
        "tensegrity_msgs/msg/SensorReadings" => json::<msg::SensorReadings>(m),
        "sensor_msgs/msg/JointState" => json::<msg::JointState>(m),
        "tensegrity_msgs/msg/Structure" => json::<msg::Structure>(m),
        "diagnostic_msgs/msg/DiagnosticArray" => json::<msg::DiagnosticArray>(m),
        "visualization_msgs/msg/MarkerArray" => json::<msg::MarkerArray>(m),
        "tensegrity_msgs/msg/AppliedCommands" => {
            serde_json::to_value(applied_commands(m)?).map_err(|e| e.to_string())
        }
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
