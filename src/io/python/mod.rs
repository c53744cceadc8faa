//! The Python extension `tensegrity._native` (feature `python`, pyo3 + numpy, built by maturin
//! from `python/` into the package `tensegrity`): takes a scene and node parameters from Python,
//! gives `Simulator`, the node core (`NodeCore`) stepped in the caller's process, so a learning
//! loop pays no round trip between processes; the library's whole commands (statics, modes,
//! deployments, studies, bags, generators) are in `library`.
//!
//! It is the shared-memory lockstep without the transport: the same core, the same command
//! checks (`shm::check_command`, `commands::check_entry`), the same seeded resets, sensors and
//! bag recording (`record`), and its state comes out as the same `#[repr(C)]` samples the shared-
//! memory transport sends (`StateSample`, `MeasuredSample`, `ContactsSample`), which the Python
//! kit reads with the same `ctypes` mirrors. A run in process and a run over shared memory from
//! the same seed and actions give the same numbers to the bit (python/tests/test_gym_env.py).
//!
//! A learning environment's step is one call (`Simulator::act`): its action mapped onto the
//! actuators' limits, the steps, the observation and the default tension reward, all here, so the
//! Python side of a step is a few hundred nanoseconds (`TensegrityEnv` with `backend="inprocess"`).

use std::collections::HashMap;
use std::mem::MaybeUninit;
use std::sync::Mutex;
use std::time::Instant;

use numpy::{PyArray1, PyArrayMethods, PyReadonlyArrayDyn};
use pyo3::exceptions::{PyRuntimeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::{PyBytes, PyDict};

use crate::control::ActuatorCommand;
use crate::io::commands;
use crate::io::msg::{result_code, SimResult};
use crate::io::node::params::NodeParams;
use crate::io::node::NodeCore;
use crate::io::record::BagRecorder;
use crate::io::shm::{
    check_capacity, check_command, fill_contacts, fill_measured, fill_state, zeroed, CommandSample,
    ContactsSample, MeasuredSample, StateSample, ZeroValid,
};
use crate::io::sink::{NodeSink, NodeView, PublishError};
use crate::io::topics::Topic;
use crate::model::{ActuatorId, Model};
use crate::task::{LearningTask, ObservationField, TaskSizes};

mod library;
use library::{CommandRefused, PhysicsFailure};

/// Steps of a `Simulator::lockstep` request taken between two checks for Ctrl-C (about 10 ms of
/// a small scene's physics).
pub const LOCKSTEP_PIECE: u64 = 2000;

/// The core's outgoing side in process: the bag recorder (with `record`; in a mutex only so the
/// simulator may be shared between Python threads: the core reaches it through `&mut`, which
/// needs no lock) and the answer to the step request under way.
struct Outputs {
    recorder: Option<Mutex<BagRecorder>>,
    done: Option<SimResult>,
}

impl Outputs {
    fn recorder(&mut self) -> Option<&mut BagRecorder> {
        // a poisoned recorder (a panic while recording) still records what it can
        self.recorder.as_mut().map(|r| r.get_mut().unwrap_or_else(|e| e.into_inner()))
    }
}

impl NodeSink for Outputs {
    fn publish(&mut self, topic: Topic, view: &NodeView<'_>) -> Result<(), PublishError> {
        match self.recorder() {
            Some(r) => r.publish(topic, view),
            None => Ok(()),
        }
    }

    fn step_request_done(&mut self, _ticket: u64, result: SimResult, _view: &NodeView<'_>) {
        // one request at a time: whatever is answered is the one under way
        self.done = Some(result);
    }

    fn commands_applied(&mut self, time: f64, step: u64, applied: &[(ActuatorId, ActuatorCommand)]) {
        if let Some(r) = self.recorder() {
            r.commands_applied(time, step, applied);
        }
    }

    fn simulation_reset(&mut self, time: f64, step: u64, seed: Option<u64>) {
        if let Some(r) = self.recorder() {
            r.simulation_reset(time, step, seed);
        }
    }
}

/// A boxed all-zero payload (large ones never pass through the stack).
fn boxed_zeroed<T: ZeroValid>() -> Box<T> {
    let mut slot: Box<MaybeUninit<T>> = Box::new_uninit();
    zeroed(&mut slot);
    // SAFETY: `zeroed` initialized it (all-zero bytes are a valid `T`: `ZeroValid`)
    #[allow(unsafe_code)]
    unsafe {
        slot.assume_init()
    }
}

/// The bytes of a payload, for Python's `ctypes` mirror (`from_buffer_copy`).
fn payload_bytes<'py, T: ZeroValid>(py: Python<'py>, payload: &T) -> Bound<'py, PyBytes> {
    // SAFETY: `T` is a `#[repr(C)]` struct of integers and floats (`ZeroValid`), fully
    // initialized, so every byte of it may be read
    #[allow(unsafe_code)]
    let bytes =
        unsafe { std::slice::from_raw_parts((payload as *const T).cast::<u8>(), std::mem::size_of::<T>()) };
    PyBytes::new(py, bytes)
}

/// What `Simulator::act` returns: (observation, reward, faulted, time s, steps since reset).
type Transition<'py> = (Bound<'py, PyArray1<f64>>, f64, bool, f64, u64);

/// The simulator in the caller's process: see the module docs.
///
/// `Simulator(scene=None, params=None)`: `scene` is a scene file, `bundled:NAME` or `None` (the
/// bundled prism3); `params` the node's parameters by name (`{"physics_dt": 0.001, "record":
/// "run_bag"}`, values as the node's `-p name:=value` takes them; the transport ones are moot).
/// The simulation is paused: it moves only when asked (`lockstep`, `act`).
#[pyclass(module = "tensegrity._native")]
pub struct Simulator {
    core: NodeCore,
    out: Outputs,
    /// The core's wall clock (diagnostics only: lockstep is not paced).
    epoch: Instant,
    task: Option<LearningTask>,
    /// Scratch of `act`: the action's values, then the commands.
    action: Vec<f64>,
    /// Scratch of `act`: the observation.
    observation: Vec<f64>,
    /// Scratch of `render`: the frame's RGB bytes.
    frame: Vec<u8>,
    /// The browser viewer of this simulator (`start_viewer`), if started.
    viewer: Option<InProcessViewer>,
}

/// A browser viewer serving a simulator's frames from a thread of its own (`io::view`).
struct InProcessViewer {
    url: String,
    geometry: crate::io::view::ViewGeometry,
    store: std::sync::Arc<crate::io::view::FrameStore>,
    stop: std::sync::Arc<std::sync::atomic::AtomicBool>,
    serving: Option<std::thread::JoinHandle<()>>,
}

impl Drop for InProcessViewer {
    fn drop(&mut self) {
        self.stop.store(true, std::sync::atomic::Ordering::Relaxed);
        if let Some(t) = self.serving.take() {
            let _ = t.join();
        }
    }
}

impl Simulator {
    /// Takes `steps` steps (the core paused) and answers how the request ended.
    fn run(&mut self, steps: u64) -> Result<(), String> {
        self.out.done = None;
        self.core.request_steps(steps, &mut self.out).map_err(|r| r.error_message)?;
        while self.out.done.is_none() {
            let now = self.epoch.elapsed();
            self.core.tick(now, &mut self.out);
        }
        match self.out.done.take() {
            Some(r) if r.result == result_code::OK => Ok(()),
            Some(r) => Err(r.error_message),
            None => Err("no answer".into()),
        }
    }
}

/// Offers one command message to `core` (`parse` as in `NodeCore::offer_parsed`); a refused one
/// is a `CommandRefused` (a `PhysicsFailure`) naming why, as a refused lockstep command is over
/// shared memory.
fn offer(
    core: &mut NodeCore,
    parse: impl FnOnce(&Model, &mut Vec<(ActuatorId, ActuatorCommand)>) -> Result<(), commands::MessageError>,
) -> PyResult<()> {
    core.offer_parsed(parse).map_err(|e| CommandRefused::new_err(format!("command rejected: {e}")))
}

#[pymethods]
impl Simulator {
    #[new]
    #[pyo3(signature = (scene=None, params=None))]
    fn new(
        py: Python<'_>,
        scene: Option<&str>,
        params: Option<HashMap<String, Bound<'_, PyAny>>>,
    ) -> PyResult<Self> {
        let model = library::model_of(py, scene, None)?;
        let mut p = NodeParams::default();
        for (name, value) in params.unwrap_or_default() {
            // Python's words for booleans are the node's too
            let text = match value.extract::<bool>() {
                Ok(b) if value.is_instance_of::<pyo3::types::PyBool>() => b.to_string(),
                _ => value.str()?.to_string(),
            };
            p.set(&name, &text).map_err(|e| PyValueError::new_err(e.to_string()))?;
        }
        check_capacity(&model, &p.frame_id).map_err(|e| PyValueError::new_err(e.to_string()))?;
        let record = p.record.clone();
        let mut core = NodeCore::new(model, p).map_err(|e| PyValueError::new_err(e.to_string()))?;
        let recorder = match &record {
            Some(dir) => {
                Some(BagRecorder::for_node(&core, dir).map_err(|e| PyValueError::new_err(e.to_string()))?)
            }
            None => None,
        };
        let mut out = Outputs { recorder: recorder.map(Mutex::new), done: None };
        core.set_paused(true, &mut out);
        core.start(&mut out);
        Ok(Self {
            core,
            out,
            epoch: Instant::now(),
            task: None,
            action: Vec::new(),
            observation: Vec::new(),
            frame: Vec::new(),
            viewer: None,
        })
    }

    /// What the scene's delays say at this simulator's physics step, one line each
    /// (`crate::sim::Simulator::delay_warnings`); the kit raises them as Python warnings.
    fn delay_warnings(&self) -> Vec<String> {
        self.core.simulator().delay_warnings()
    }

    /// A picture of the current state (`crate::render`): a `(height, width, 3)` uint8 array, RGB,
    /// rows top to bottom, from the camera that frames the structure; made in software, the same
    /// pixels for the same state. `width` and `height` in 1 to 4096.
    #[pyo3(signature = (width=320, height=240))]
    fn render<'py>(
        &mut self,
        py: Python<'py>,
        width: usize,
        height: usize,
    ) -> PyResult<Bound<'py, numpy::PyArray3<u8>>> {
        if !(1..=4096).contains(&width) || !(1..=4096).contains(&height) {
            return Err(PyValueError::new_err(format!(
                "render: width and height must be in 1 to 4096 pixels, got {width} x {height}"
            )));
        }
        let sim = self.core.simulator();
        let (model, state, ws) = (sim.model(), sim.state(), sim.workspace());
        let camera = crate::render::Camera::framing(model, ws, width as f64 / height as f64);
        crate::render::render_rgb(model, state, ws, &camera, (width, height), &mut self.frame);
        numpy::PyArray1::from_slice(py, &self.frame).reshape([height, width, 3])
    }

    /// The scene's names and limits, as the shared-memory client's `structure()` gives them:
    /// scene_name, physics_dt, body_names, cable_names, actuator_names, actuator_cable,
    /// actuator_min_rest_length, actuator_max_rest_length, actuator_max_rate, contacts.
    fn names<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let m = self.core.simulator().model();
        let d = PyDict::new(py);
        d.set_item("scene_name", &m.name)?;
        d.set_item("physics_dt", self.core.simulator().settings().dt)?;
        d.set_item("body_names", m.bodies.iter().map(|b| b.name.clone()).collect::<Vec<_>>())?;
        d.set_item("cable_names", &m.cable_names)?;
        d.set_item("actuator_names", &m.actuator_names)?;
        d.set_item("actuator_cable", m.actuators.iter().map(|a| a.cable.0).collect::<Vec<_>>())?;
        d.set_item(
            "actuator_min_rest_length",
            m.actuators.iter().map(|a| a.min_rest_length).collect::<Vec<_>>(),
        )?;
        d.set_item(
            "actuator_max_rest_length",
            m.actuators.iter().map(|a| a.max_rest_length).collect::<Vec<_>>(),
        )?;
        d.set_item("actuator_max_rate", m.actuators.iter().map(|a| a.max_rate).collect::<Vec<_>>())?;
        let contacts: Vec<(String, String)> =
            m.contact_labels().map(|(p, w)| (p.to_string(), w.to_string())).collect();
        d.set_item("contacts", contacts)?;
        Ok(d)
    }

    /// A lockstep request, as over shared memory (`LockstepRequest`): with `reset`, back to the
    /// start (the episode drawn from `seed` when given); then `command` (the bytes of a
    /// `CommandSample`, checked like any command: a rejected one takes no step), then `steps`
    /// steps. Raises `PhysicsFailure` when the command is rejected, the core is faulted or a
    /// step fails (the state is then the last good one), `ValueError` on malformed input.
    ///
    /// Long requests run without the GIL (other Python threads go on) and in pieces of
    /// `LOCKSTEP_PIECE` steps, between which Ctrl-C (`KeyboardInterrupt`) stops them.
    #[pyo3(signature = (steps, command=None, reset=false, seed=None))]
    fn lockstep(
        &mut self,
        py: Python<'_>,
        steps: u64,
        command: Option<&[u8]>,
        reset: bool,
        seed: Option<u64>,
    ) -> PyResult<()> {
        if seed.is_some() && !reset {
            return Err(PyValueError::new_err("a seed is for a reset: lockstep(..., reset=True, seed=...)"));
        }
        if reset {
            self.core.reset_seeded(seed, &mut self.out);
        }
        if let Some(bytes) = command {
            if bytes.len() != std::mem::size_of::<CommandSample>() {
                return Err(PyValueError::new_err(format!(
                    "a command is the {} bytes of a CommandSample, got {}",
                    std::mem::size_of::<CommandSample>(),
                    bytes.len()
                )));
            }
            let mut sample = boxed_zeroed::<CommandSample>();
            // SAFETY: as many bytes as a `CommandSample`, which any bytes form (integers and floats)
            #[allow(unsafe_code)]
            unsafe {
                std::ptr::copy_nonoverlapping(
                    bytes.as_ptr(),
                    (&mut *sample as *mut CommandSample).cast::<u8>(),
                    bytes.len(),
                );
            }
            if sample.count > 0 {
                offer(&mut self.core, |model, out| check_command(model, &sample, out))?;
            }
        }
        let mut left = steps;
        loop {
            let piece = left.min(LOCKSTEP_PIECE);
            py.detach(|| self.run(piece)).map_err(PhysicsFailure::new_err)?;
            left -= piece;
            if left == 0 {
                return Ok(());
            }
            py.check_signals()?;
        }
    }

    /// The bytes of the `StateSample` of now (`shm.StateSample.from_buffer_copy`).
    fn state_sample<'py>(&self, py: Python<'py>) -> Bound<'py, PyBytes> {
        let mut s = boxed_zeroed::<StateSample>();
        fill_state(&mut s, &self.core.view(), 0);
        payload_bytes(py, &*s)
    }

    /// The bytes of the `MeasuredSample` of now, `None` for a scene without sensors.
    fn measured_sample<'py>(&self, py: Python<'py>) -> Option<Bound<'py, PyBytes>> {
        let view = self.core.view();
        if view.measured.is_empty() {
            return None;
        }
        let mut s = boxed_zeroed::<MeasuredSample>();
        fill_measured(&mut s, &view);
        Some(payload_bytes(py, &*s))
    }

    /// The bytes of the `ContactsSample` of now, `None` for a scene without contacts.
    fn contacts_sample<'py>(&self, py: Python<'py>) -> Option<Bound<'py, PyBytes>> {
        let view = self.core.view();
        if view.model.contact_pairs() == 0 {
            return None;
        }
        let mut s = boxed_zeroed::<ContactsSample>();
        fill_contacts(&mut s, &view);
        Some(payload_bytes(py, &*s))
    }

    /// Serves the browser viewer of this simulator (`tensegrity view`'s page) on
    /// 127.0.0.1:`port` (0: a free port) from a thread of its own, and returns its address; the
    /// page shows the current state, then follows the frames `view_frame` hands it (the newest
    /// 3600 of them). Once started,
    /// later calls return the same address. A port in use is an `OSError`.
    #[pyo3(signature = (port=0))]
    fn start_viewer(&mut self, port: u16) -> PyResult<String> {
        use crate::io::view::{FrameStore, ViewGeometry, ViewServer, ViewSource, ViewStatus};
        if let Some(v) = &self.viewer {
            return Ok(v.url.clone());
        }
        let sim = self.core.simulator();
        let model = sim.model();
        let geometry = ViewGeometry::new(model);
        let scene =
            geometry.scene_json(model, &sim.state().poses, ViewSource::Node, "in-process simulator (Python)");
        let status = ViewStatus { state: "waiting".into(), message: String::new() };
        let store = std::sync::Arc::new(FrameStore::new(3600, status));
        let server = ViewServer::bind(port, scene, store.clone())
            .map_err(|e| pyo3::exceptions::PyOSError::new_err(e.to_string()))?;
        let url = server.url();
        let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
        let serving = {
            let stop = stop.clone();
            std::thread::spawn(move || server.serve_until(&stop))
        };
        self.viewer =
            Some(InProcessViewer { url: url.clone(), geometry, store, stop, serving: Some(serving) });
        self.view_frame()?;
        Ok(url)
    }

    /// Hands the current state to the browser viewer as its newest frame (nothing before
    /// `start_viewer`). The page says `faulted` while a physics failure holds the simulator.
    fn view_frame(&mut self) -> PyResult<()> {
        let Some(v) = &self.viewer else { return Ok(()) };
        let sim = self.core.simulator();
        let frame = crate::io::view::Frame::of_state(sim.model(), &v.geometry, sim.state(), sim.workspace());
        v.store.push(&frame);
        match self.core.fault() {
            Some(why) => v.store.set_status("faulted", &format!("{why} (held until reset)")),
            None => v.store.set_status("playing", ""),
        }
        Ok(())
    }

    /// Closes the bag being recorded (with `record`), which is complete from then on; later
    /// steps are not recorded. Also done when the simulator is dropped. Stops the viewer.
    fn close(&mut self) -> PyResult<()> {
        self.viewer = None;
        if let Some(r) = self.out.recorder.take() {
            let r = r.into_inner().unwrap_or_else(|e| e.into_inner());
            r.finish().map_err(|e| PyRuntimeError::new_err(e.to_string()))?;
        }
        Ok(())
    }

    /// Sets the learning task `act` steps (a `Task`, built for this simulator's model: its
    /// cable, actuator and body counts must be the model's, else `ValueError`).
    fn configure(&mut self, task: PyRef<'_, PyTask>) -> PyResult<()> {
        let sizes = TaskSizes::of(self.core.simulator().model());
        if task.sizes != sizes {
            return Err(PyValueError::new_err(format!(
                "the task is for {} cables, {} actuators and {} bodies; this model has {}, {} and {}",
                task.sizes.cables,
                task.sizes.actuators,
                task.sizes.bodies,
                sizes.cables,
                sizes.actuators,
                sizes.bodies
            )));
        }
        self.task = Some(task.task.clone());
        Ok(())
    }

    /// One step of the learning task (`configure` first): `action` (a float64 array or a
    /// sequence, one value per actuator) held for `steps` physics steps. Returns (observation,
    /// reward, faulted, time, step). A value that is not finite, or the wrong count of them,
    /// raises `ValueError` and takes no step; a failed step raises `PhysicsFailure`.
    fn act<'py>(
        &mut self,
        py: Python<'py>,
        action: &Bound<'py, PyAny>,
        steps: u64,
    ) -> PyResult<Transition<'py>> {
        read_action(action, &mut self.action)?;
        self.offer_action()?;
        let outcome = self.advance(steps).map_err(PhysicsFailure::new_err)?;
        Ok(self.transition(py, outcome))
    }
}

/// What a step of the task ended with (`Simulator::advance`).
#[derive(Debug, Clone, Copy)]
struct Outcome {
    reward: f64,
    faulted: bool,
    time: f64,
    step: u64,
}

/// The task, once `values` (an action's) are one per actuator and finite: mapped in place onto
/// the actuators' rates or rest lengths (`LearningTask::map_action`).
fn mapped_action<'a>(task: &'a Option<LearningTask>, values: &mut [f64]) -> PyResult<&'a LearningTask> {
    let task = task.as_ref().ok_or_else(|| PyRuntimeError::new_err("configure the task before act"))?;
    task.map_action(values).map_err(PyValueError::new_err)?;
    Ok(task)
}

/// Reads `action` (a float64 array of any shape, or a sequence of numbers) into `out`.
fn read_action(action: &Bound<'_, PyAny>, out: &mut Vec<f64>) -> PyResult<()> {
    out.clear();
    if let Ok(a) = action.extract::<PyReadonlyArrayDyn<'_, f64>>() {
        match a.as_slice() {
            Ok(s) => out.extend_from_slice(s),
            Err(_) => out.extend(a.as_array().iter().copied()),
        }
    } else {
        out.extend(action.extract::<Vec<f64>>()?);
    }
    Ok(())
}

impl Simulator {
    /// Checks the action values in `self.action` and maps them onto the actuators' limits
    /// (`mapped_action`), and offers them as one command message (applied at the next step).
    /// Takes no step.
    fn offer_action(&mut self) -> PyResult<()> {
        let Self { core, task, action, .. } = self;
        let task = mapped_action(task, action)?;
        offer(core, |model, out| {
            for (&id, &x) in task.actuators.iter().zip(action.iter()) {
                let c = if task.rate { ActuatorCommand::rate(x) } else { ActuatorCommand::target(x) };
                commands::check_entry(model, ActuatorId(id), c, out)?;
            }
            Ok(())
        })
    }

    /// Takes `steps` steps and observes the task's fields into `self.observation` (touches no
    /// Python object: `act_all` runs it without the GIL, simulators in parallel).
    fn advance(&mut self, steps: u64) -> Result<Outcome, String> {
        self.run(steps)?;
        let task = self.task.as_ref().ok_or("configure the task before act")?;
        let view = self.core.view();
        self.observation.clear();
        task.observe(
            view.model,
            view.state,
            view.workspace,
            view.rates,
            view.measured,
            &mut self.observation,
        );
        Ok(Outcome {
            reward: task.tension_reward(|c| view.workspace.cables[c].tension),
            faulted: view.faulted,
            time: view.state.time,
            step: view.step,
        })
    }

    /// `act`'s answer after `outcome`.
    fn transition<'py>(&self, py: Python<'py>, o: Outcome) -> Transition<'py> {
        (PyArray1::from_slice(py, &self.observation), o.reward, o.faulted, o.time, o.step)
    }
}

/// `act` on every simulator of `sims` at once, with its row of `actions`, the simulators
/// stepping in parallel on the machine's cores (rayon) while Python waits without the GIL.
/// Every action is checked before any simulator steps (a bad one raises `ValueError`, nothing
/// steps). Returns one entry per simulator: `act`'s tuple, or the `PhysicsFailure` it raised
/// (not raised here: the others' steps stand).
#[pyfunction]
fn act_all<'py>(
    py: Python<'py>,
    mut sims: Vec<PyRefMut<'py, Simulator>>,
    actions: Vec<Bound<'py, PyAny>>,
    steps: u64,
) -> PyResult<Vec<Bound<'py, PyAny>>> {
    if actions.len() != sims.len() {
        return Err(PyValueError::new_err(format!(
            "{} actions for {} simulators",
            actions.len(),
            sims.len()
        )));
    }
    for (sim, action) in sims.iter_mut().zip(&actions) {
        read_action(action, &mut sim.action)?;
        let task =
            sim.task.as_ref().ok_or_else(|| PyRuntimeError::new_err("configure the task before act"))?;
        task.check_action(&sim.action).map_err(PyValueError::new_err)?;
    }
    let mut offered = Vec::with_capacity(sims.len());
    for sim in sims.iter_mut() {
        offered.push(sim.offer_action().err());
    }
    let mut each: Vec<&mut Simulator> = sims.iter_mut().map(|s| &mut **s).collect();
    let mut outcomes: Vec<Result<Outcome, String>> = vec![Err(String::new()); each.len()];
    py.detach(|| {
        // this thread steps the first simulator itself while the pool's threads take the others:
        // a pool thread's wake-up then overlaps work instead of adding to it
        rayon::in_place_scope(|scope| {
            // a simulator whose command was refused takes no step, as in `act`
            let mut pairs = each
                .iter_mut()
                .zip(outcomes.iter_mut())
                .zip(&offered)
                .filter(|(_, refused)| refused.is_none())
                .map(|(pair, _)| pair);
            let first = pairs.next();
            for (sim, outcome) in pairs {
                scope.spawn(move |_| *outcome = sim.advance(steps));
            }
            if let Some((sim, outcome)) = first {
                *outcome = sim.advance(steps);
            }
        })
    });
    let mut out = Vec::with_capacity(sims.len());
    for ((sim, outcome), refused) in sims.iter().zip(outcomes).zip(offered) {
        out.push(match (refused, outcome) {
            (Some(e), _) => e.into_value(py).into_bound(py).into_any(),
            (None, Ok(o)) => sim.transition(py, o).into_pyobject(py)?.into_any(),
            (None, Err(why)) => PhysicsFailure::new_err(why).into_value(py).into_bound(py).into_any(),
        });
    }
    Ok(out)
}

/// The learning task's observation fields (`crate::task::ObservationField`), as the Gymnasium
/// environment reads them: one dict per field, in order, with `name` (the `State` attribute),
/// `element` (`cable`, `actuator` or `body`: what it has one entry per), `width` (numbers per
/// entry) and `sensor` (the `State.measured` key of the channel that reports it instead, or
/// `None`).
#[pyfunction]
fn observation_fields<'py>(py: Python<'py>) -> PyResult<Vec<Bound<'py, PyDict>>> {
    ObservationField::ALL
        .iter()
        .map(|f| {
            let d = PyDict::new(py);
            d.set_item("name", f.name())?;
            d.set_item("element", f.element().name())?;
            d.set_item("width", f.width())?;
            d.set_item("sensor", f.sensor().map(|k| k.name()))?;
            Ok(d)
        })
        .collect()
}

/// A learning task (`crate::task::LearningTask`) outside a `Simulator`: the action mapping, the
/// observation layout and the default reward, for an environment whose simulator runs in a node
/// (`TensegrityEnv(backend="node")`), so that both backends compute them with the same code.
#[pyclass(name = "Task", module = "tensegrity._native")]
pub struct PyTask {
    task: LearningTask,
    sizes: TaskSizes,
    /// Scratch of `values`.
    action: Vec<f64>,
}

#[pymethods]
impl PyTask {
    /// The task for a model of `cables`, `actuators_count` and `bodies`: `actuators` (indices)
    /// driven by `rate` (m/s) or rest-length targets, each action value within
    /// `low[k]..high[k]` (SI), given in [-1, 1] when `normalize`; `fields` observed
    /// (`observation_fields()` names, concatenated; what the sensors report where declared, with
    /// `measured`); `targets` the default reward's (cable index, tension N > 0) pairs
    /// (`tensegrity::task::LearningTask::new`). Raises `ValueError` naming what is wrong.
    #[new]
    #[allow(clippy::too_many_arguments)]
    fn new(
        cables: usize,
        actuators_count: usize,
        bodies: usize,
        actuators: Vec<usize>,
        rate: bool,
        low: Vec<f64>,
        high: Vec<f64>,
        normalize: bool,
        fields: Vec<String>,
        measured: bool,
        targets: Vec<(usize, f64)>,
    ) -> PyResult<Self> {
        let sizes = TaskSizes { cables, actuators: actuators_count, bodies };
        let task =
            LearningTask::new(&sizes, actuators, rate, &low, &high, normalize, &fields, measured, targets)
                .map_err(PyValueError::new_err)?;
        Ok(Self { task, sizes, action: Vec::new() })
    }

    /// The rates (m/s) or rest lengths (m) `action` (a float64 array or a sequence, one value per
    /// actuator) asks for, a list. A value that is not finite, or the wrong count of them, raises
    /// `ValueError`.
    fn values(&mut self, action: &Bound<'_, PyAny>) -> PyResult<Vec<f64>> {
        read_action(action, &mut self.action)?;
        self.task.map_action(&mut self.action).map_err(PyValueError::new_err)?;
        Ok(self.action.clone())
    }

    /// The default reward of `tensions` (indexable by cable, N): minus the mean of
    /// `|T - T*| / T*` over the targets.
    fn reward(&self, tensions: &Bound<'_, PyAny>) -> PyResult<f64> {
        let mut read = Vec::with_capacity(self.task.targets.len());
        for &(c, _) in &self.task.targets {
            read.push((c, tensions.get_item(c)?.extract::<f64>()?));
        }
        Ok(self.task.tension_reward(|c| read.iter().find(|(k, _)| *k == c).map_or(f64::NAN, |(_, t)| *t)))
    }

    /// Where each observed field sits in an observation: (name, entries, numbers per entry), in
    /// order.
    fn layout(&self) -> Vec<(&'static str, usize, usize)> {
        self.task.layout(&self.sizes).into_iter().map(|(f, n, w)| (f.name(), n, w)).collect()
    }
}

/// The module `tensegrity._native` (re-exported by the Python package `tensegrity`).
#[pymodule]
#[pyo3(name = "_native")]
fn native_module(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<Simulator>()?;
    m.add_class::<PyTask>()?;
    m.add_function(pyo3::wrap_pyfunction!(observation_fields, m)?)?;
    m.add_function(pyo3::wrap_pyfunction!(act_all, m)?)?;
    library::register(m)?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    Ok(())
}
