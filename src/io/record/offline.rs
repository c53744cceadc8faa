//! Offline runs with the node's meaning: takes a model, its simulator settings and an optional
//! bag directory, gives a dynamic deployment driven by the node's own core with no clock
//! (`OfflineRun`: the bag holds what a node following the schedule would publish with its state
//! every step, and `replay` runs it again the same way), and the recorder of a quasi-static path
//! (`quasi_static_recorder`, fed by a `PathPublisher`); and `DynamicDeployment`, that run as
//! the CSV rows `tensegrity deploy --dynamic` writes, which the CLI and the Python library both
//! take from it.

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
use crate::study::RunTotals;

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

/// A dynamic deployment as CSV rows: an `OfflineRun` whose every step gives the row `tensegrity
/// deploy --dynamic` writes (`study::dynamic_csv_row`, then the scene's exact IMU values, what its
/// sensors report and their dropout flags, where it declares sensors), with the run's totals and
/// the strut pairs that touched. The caller writes the rows (a file, a Python string).
pub struct DynamicDeployment {
    run: OfflineRun,
    totals: RunTotals,
    struts_touched: Vec<bool>,
}

/// What a finished `DynamicDeployment` did.
pub struct DynamicDeploymentSummary {
    /// Steps, Newton iterations, rejected attempts, sub-steps and wall time.
    pub totals: RunTotals,
    /// The `[collisions]` strut pairs (labels `first-second`) that touched at some step.
    pub struts_collided: Vec<String>,
    /// The bag's directory and summary, when the run was recorded.
    pub bag: Option<(PathBuf, BagSummary)>,
}

impl DynamicDeployment {
    /// Starts `OfflineRun::start(model, scene_label, settings, from_equilibrium, record)`.
    pub fn start(
        model: &Model,
        scene_label: &str,
        settings: SimSettings,
        from_equilibrium: bool,
        record: Option<&Path>,
    ) -> Result<Self, String> {
        let run = OfflineRun::start(model, scene_label, settings, from_equilibrium, record)?;
        Ok(Self { run, totals: RunTotals::default(), struts_touched: vec![false; model.strut_pairs.len()] })
    }

    /// The run's warnings about sensor delays shorter than a step (`Simulator::delay_warnings`).
    pub fn warnings(&self) -> Vec<String> {
        self.run.simulator().delay_warnings()
    }

    /// The CSV header: `study::dynamic_csv_header`, then the sensors' columns.
    pub fn header(&self) -> String {
        let model = self.run.simulator().model();
        let mut header = crate::study::dynamic_csv_header(model);
        for c in crate::sensors::imu_truth_csv_columns(model)
            .into_iter()
            .chain(crate::sensors::csv_columns(model))
            .chain(crate::sensors::lost_csv_columns(model))
        {
            header.push(',');
            header.push_str(&c);
        }
        header
    }

    /// The row of the current state after a step that cost `stats` (the row of t = 0, before
    /// any step, with `StepStats::default()`).
    pub fn row(&self, stats: &StepStats) -> String {
        let run = &self.run;
        let mut row = crate::study::dynamic_csv_row(run.simulator(), stats);
        for v in run.sensors().imu_truth().iter().chain(run.sensors().measured()) {
            let _ = std::fmt::Write::write_fmt(&mut row, format_args!(",{v:.12}"));
        }
        for lost in crate::sensors::lost_csv_flags(run.simulator().model(), run.sensors().lost()) {
            row.push_str(if lost { ",1" } else { ",0" });
        }
        row
    }

    /// Takes one step and returns its row, or the core's fault.
    pub fn step(&mut self) -> Result<String, String> {
        let stats = self.run.step()?;
        self.totals.add(&stats);
        let model = self.run.simulator().model();
        let contacts = &self.run.simulator().workspace().contacts[model.ground_pairs()..];
        for (touched, c) in self.struts_touched.iter_mut().zip(contacts) {
            *touched |= c.in_contact();
        }
        Ok(self.row(&stats))
    }

    /// Ends the run: closes the bag and says what the run did.
    pub fn finish(self) -> Result<DynamicDeploymentSummary, BagError> {
        let model = self.run.simulator().model();
        let struts_collided = model
            .contact_labels()
            .skip(model.ground_pairs())
            .zip(&self.struts_touched)
            .filter(|(_, t)| **t)
            .map(|((a, b), _)| format!("{a}-{b}"))
            .collect();
        let bag = self.run.finish()?;
        Ok(DynamicDeploymentSummary { totals: self.totals, struts_collided, bag })
    }
}

/// The steps a dynamic deployment of `model` takes for `duration` s (`None`: one second past the
/// schedule's end) at the output interval `dt` s (at least one), or why the duration cannot be
/// used, naming it as `option` spells it (`--duration`, `duration`).
pub fn dynamic_steps(model: &Model, duration: Option<f64>, dt: f64, option: &str) -> Result<u64, String> {
    let duration = duration.unwrap_or(model.schedule.end_time() + 1.0);
    if !(duration.is_finite() && duration > 0.0) {
        return Err(format!("{option} must be positive, got {}", crate::error::readable_number(duration)));
    }
    Ok((duration / dt).round().max(1.0) as u64)
}

/// The local tolerance at which a dynamic run of `model` over `steps` steps meets
/// `settings.tolerance` (which must be set) as a global tolerance: runs again at a tenth of the
/// tolerance until two runs agree to within ten times it (`study::globally_controlled` over runs
/// of the node's core), calling `stepped` after every step of every run. The run made at the
/// tolerance found is the one `deploy --dynamic --global-error` writes (runs are deterministic).
pub fn global_tolerance(
    model: &Model,
    label: &str,
    settings: SimSettings,
    from_equilibrium: bool,
    steps: u64,
    mut stepped: impl FnMut(),
) -> Result<crate::study::GlobalRun, String> {
    let Some(requested) = settings.tolerance else {
        return Err("global error control needs a tolerance (the global tolerance, m)".into());
    };
    let found = crate::study::globally_controlled(requested, model.is_free_floating(), |tolerance| {
        let settings = SimSettings { tolerance: Some(tolerance), ..settings };
        let mut run = OfflineRun::start(model, label, settings, from_equilibrium, None)?;
        let (mut samples, mut totals) = (Vec::new(), RunTotals::default());
        for _ in 0..steps {
            totals.add(
                &run.step()
                    .map_err(|fault| format!("{label}: at local tolerance {tolerance:e} m: {fault}"))?,
            );
            samples.push(run.simulator().workspace().points.iter().map(|p| p.position).collect());
            stepped();
        }
        Ok((samples, totals))
    });
    found.map_err(|e| format!("{label}: {e}"))
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
