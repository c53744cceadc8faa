//! Offline runs with the node's meaning: takes a model, its simulator settings and an optional
//! bag directory, gives a dynamic deployment driven by the node's own core with no clock
//! (`OfflineRun`: the bag holds what a node following the schedule would publish with its state
//! every step, and `replay` runs it again the same way), and the recorder of a quasi-static path
//! (`quasi_static_recorder`, fed by a `PathPublisher`). The CLI's `deploy` drives both.

use std::path::{Path, PathBuf};
use std::time::Duration;

use crate::control::ActuatorCommand;
use crate::io::msg::SimResult;
use crate::io::node::params::NodeParams;
use crate::io::node::NodeCore;
use crate::io::record::bag::{BagError, BagOptions, BagSummary};
use crate::io::record::recorder::BagRecorder;
use crate::io::record::run::{run_info, LogTime, KIND_DYNAMIC, KIND_QUASI_STATIC};
use crate::io::sink::{NodeSink, NodeView, PublishError};
use crate::io::topics::Topic;
use crate::model::{ActuatorId, Model};
use crate::sim::{SimSettings, Simulator, StepStats};

/// A dynamic deployment run offline by the node's core: the actuators follow the schedule
/// (`follow_schedule`), one `step` is one core tick at the simulation's own time, and with a bag
/// every step's state is recorded (`state_publish_rate = 0`) with the simulation time as log time.
pub struct OfflineRun {
    core: NodeCore,
    recorder: Option<BagRecorder>,
}

impl OfflineRun {
    /// Starts the run of `model` with `settings`, from the scene's pose or (`from_equilibrium`)
    /// at rest in its static equilibrium (`Simulator::start`); `scene_label` names the scene in
    /// the run record and in errors; with `record`, a new bag is created in that directory. Publishes the
    /// start-up outputs (structure, static transforms, the state at t = 0) to the bag.
    pub fn start(
        model: &Model,
        scene_label: &str,
        settings: SimSettings,
        from_equilibrium: bool,
        record: Option<&Path>,
    ) -> Result<Self, String> {
        let params = NodeParams {
            follow_schedule: true,
            real_time_factor: 0.0,
            state_publish_rate: 0.0,
            start_from_equilibrium: from_equilibrium,
            ..NodeParams::default()
        };
        let sim = Simulator::start(model.clone(), settings, from_equilibrium)
            .map_err(|e| format!("{scene_label}: {e}"))?;
        let recorder = match record {
            Some(dir) => {
                let run = run_info(KIND_DYNAMIC, model, scene_label, &settings, &params);
                let options = BagOptions::default();
                Some(
                    BagRecorder::create(dir, model, &params, &run, LogTime::SimTime, &options)
                        .map_err(|e| e.to_string())?,
                )
            }
            None => None,
        };
        let mut run = Self { core: NodeCore::with_simulator(sim, params), recorder };
        let mut sink = OptionalSink(run.recorder.as_mut());
        run.core.start(&mut sink);
        Ok(run)
    }

    /// The simulator (its state after the last step).
    pub fn simulator(&self) -> &Simulator {
        self.core.simulator()
    }

    /// What the scene's sensors report after the last step (`crate::sensors`).
    pub fn sensors(&self) -> &crate::sensors::Sensors {
        self.core.sensors()
    }

    /// Takes one step (the core's tick at the current simulation time) and returns its
    /// statistics, or the core's fault (the step failed even at the smallest sub-step, or its
    /// state was not finite).
    pub fn step(&mut self) -> Result<StepStats, String> {
        let now = Duration::from_secs_f64(self.core.simulator().state().time);
        let mut sink = OptionalSink(self.recorder.as_mut());
        self.core.tick(now, &mut sink);
        match self.core.fault() {
            Some(fault) => Err(fault.to_string()),
            None => Ok(self.core.last_step()),
        }
    }

    /// Ends the run: closes the bag (when there is one) and returns its directory and summary.
    pub fn finish(self) -> Result<Option<(PathBuf, BagSummary)>, BagError> {
        match self.recorder {
            Some(r) => {
                let dir = r.dir().to_path_buf();
                Ok(Some((dir, r.finish()?)))
            }
            None => Ok(None),
        }
    }
}

/// The recorder of a quasi-static path of `model` in `steps` load steps into a new bag in `dir`
/// (log time: 1 ms per row), for a `PathPublisher` to feed; `scene_label` names the scene in the
/// run record.
pub fn quasi_static_recorder(
    dir: &Path,
    model: &Model,
    scene_label: &str,
    steps: usize,
) -> Result<BagRecorder, BagError> {
    let params = NodeParams::default();
    let mut run = run_info(KIND_QUASI_STATIC, model, scene_label, &SimSettings::default(), &params);
    run.insert("steps".into(), steps.to_string());
    BagRecorder::create(dir, model, &params, &run, LogTime::Step, &BagOptions::default())
}

/// A sink that passes everything to a recorder when there is one.
struct OptionalSink<'a>(Option<&'a mut BagRecorder>);

impl NodeSink for OptionalSink<'_> {
    fn publish(&mut self, topic: Topic, view: &NodeView<'_>) -> Result<(), PublishError> {
        self.0.as_mut().map_or(Ok(()), |r| r.publish(topic, view))
    }
    fn step_request_done(&mut self, _ticket: u64, _result: SimResult, _view: &NodeView<'_>) {}
    fn commands_applied(&mut self, time: f64, step: u64, commands: &[(ActuatorId, ActuatorCommand)]) {
        if let Some(r) = self.0.as_mut() {
            r.commands_applied(time, step, commands);
        }
    }
}
