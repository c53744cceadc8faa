//! The library's whole commands for Python: takes a scene (a file, `bundled:NAME`, or TOML text)
//! or a bag and the command line's options, gives what the command line writes for them, as text
//! or flat arrays the Python package `tensegrity` turns into its results: `check_json`,
//! `statics_json`, `modes_json`, `quasi_static_csv`, `dynamic_csv`, `study_markdown`,
//! `work_precision_markdown`, `generate_toml`, `field_reference`, `read_bag`, `replay_report`,
//! `reindex_bag`, `step_times`, `scaling_markdown`; with the exceptions `SceneError`, `NoEquilibrium` and `PhysicsFailure`. Each
//! calls the code the command line calls, so the numbers are the same to the bit. Long calls run
//! without the GIL and return at Ctrl-C (`KeyboardInterrupt`).

use pyo3::exceptions::{PyRuntimeError, PyValueError};
use std::collections::HashMap;

use pyo3::prelude::*;
use pyo3::types::PyDict;

use crate::io::record::offline::DynamicDeployment;
use crate::model::Model;

pyo3::create_exception!(
    tensegrity._native,
    SceneError,
    PyValueError,
    "A scene that cannot be read or is invalid: `file`, `line` (or None), `field` and `reason`."
);
pyo3::create_exception!(
    tensegrity._native,
    NoEquilibrium,
    PyRuntimeError,
    "The static solver stopped without an equilibrium: `iterations`, `residual_n`, `stop_reason`."
);

pyo3::create_exception!(
    tensegrity._native,
    PhysicsFailure,
    PyRuntimeError,
    "A step failed even at the smallest sub-step, or a request was refused (faulted until reset)."
);
pyo3::create_exception!(
    tensegrity._native,
    CommandRefused,
    PhysicsFailure,
    "A command the node core refused (an unknown actuator, a value out of its limits): no step was taken."
);

/// The model of `scene` (a file, `bundled:NAME`, or None for the bundled prism3) or of the TOML
/// `text` (named `file` in its errors), as a Python `SceneError` when it cannot be had.
pub(super) fn model_of(py: Python<'_>, scene: Option<&str>, text: Option<&str>) -> PyResult<Model> {
    let loaded = match (scene, text) {
        (Some(_), Some(_)) => return Err(PyValueError::new_err("give a scene or its text, not both")),
        (None, Some(t)) => crate::scene::from_toml(t, "<text>"),
        (Some(s), None) => match s.strip_prefix("bundled:") {
            Some(name) => crate::scene::bundled(name),
            None => crate::scene::load(std::path::Path::new(s)),
        },
        (None, None) => crate::scene::bundled("prism3"),
    };
    loaded.map_err(|e| {
        let err = SceneError::new_err(e.to_string());
        let value = err.value(py);
        let _ = value.setattr("file", &e.file);
        let _ = value.setattr("line", e.line);
        let _ = value.setattr("field", &e.field);
        let _ = value.setattr("reason", &e.reason);
        err
    })
}

/// A model the static solver can take: every body held.
fn held_model(py: Python<'_>, scene: Option<&str>, text: Option<&str>) -> PyResult<Model> {
    let model = model_of(py, scene, text)?;
    match crate::report::unheld_bodies_note(&model) {
        Some(note) => Err(PyValueError::new_err(format!("{}: {note}", scene.unwrap_or("<text>")))),
        None => Ok(model),
    }
}

fn no_equilibrium(py: Python<'_>, f: crate::summary::NoEquilibrium) -> PyErr {
    let err = NoEquilibrium::new_err(format!(
        "no equilibrium found: residual {:.3e} N after {} Newton iterations ({})",
        f.residual, f.iterations, f.stop_words
    ));
    let value = err.value(py);
    let _ = value.setattr("iterations", f.iterations);
    let _ = value.setattr("residual_n", f.residual);
    let _ = value.setattr("stop_reason", f.stop_words);
    err
}

/// Runs `work` on a thread of its own, without the GIL, and looks for Ctrl-C every 50 ms: a
/// `KeyboardInterrupt` (or any signal handler's exception) returns at once, and the work is left
/// to finish on its own with its result dropped (the library's solves take no cancellation). The
/// calls whose work has no natural pieces (a solve, a study) run through this; a dynamic
/// deployment instead looks between pieces of steps and stops.
fn interruptible<T: Send + 'static>(
    py: Python<'_>,
    work: impl FnOnce() -> T + Send + 'static,
) -> PyResult<T> {
    use std::sync::mpsc::RecvTimeoutError;
    let (tx, mut rx) = std::sync::mpsc::channel();
    std::thread::Builder::new()
        .name("tensegrity-solve".into())
        .stack_size(SOLVE_STACK_BYTES)
        .spawn(move || {
            let _ = tx.send(work());
        })
        .map_err(|e| PyRuntimeError::new_err(format!("cannot start the solve's thread: {e}")))?;
    loop {
        // the receiver goes into the GIL-free closure and comes back (it is `Send`, not `Sync`)
        let (received, back) = py.detach(move || (rx.recv_timeout(std::time::Duration::from_millis(50)), rx));
        rx = back;
        match received {
            Ok(value) => return Ok(value),
            Err(RecvTimeoutError::Timeout) => py.check_signals()?,
            Err(RecvTimeoutError::Disconnected) => {
                return Err(PyRuntimeError::new_err("the solve stopped without a result (it panicked)"))
            }
        }
    }
}

/// Stack of an `interruptible` solve's thread, bytes (the main thread's usual 8 MiB, and more).
const SOLVE_STACK_BYTES: usize = 32 << 20;

/// `statics_json(scene=None, *, text=None)`: the equilibrium of the scene at its initial rest
/// lengths, as the JSON text `tensegrity statics --json` prints (the same numbers to the bit).
/// The solve runs without the GIL.
#[pyfunction]
#[pyo3(signature = (scene=None, *, text=None))]
fn statics_json(py: Python<'_>, scene: Option<&str>, text: Option<&str>) -> PyResult<String> {
    let model = held_model(py, scene, text)?;
    let solved =
        interruptible(py, move || crate::summary::statics(&model))?.map_err(|f| no_equilibrium(py, f))?;
    serde_json::to_string(&solved.summary).map_err(|e| PyRuntimeError::new_err(e.to_string()))
}

/// What `modes_json` returns: the JSON, the shapes, the point displacements, the point names.
type ListedModes<'py> =
    (String, Bound<'py, numpy::PyArray1<f64>>, Bound<'py, numpy::PyArray1<f64>>, Vec<String>);

/// Step along a mode shape over which its point displacements are taken, per unit amplitude
/// (a difference quotient of the poses' retraction; the shapes are linear at this size).
const MODE_SHAPE_STEP: f64 = 1e-7;

/// `modes_json(scene=None, count=10, *, text=None)`: the natural modes at the equilibrium, as
/// `(json, shapes, displacements, point_names)`: the JSON text `tensegrity modes --json --count COUNT` prints
/// (every zero-frequency mode, then the lowest `count` others), and for those modes in that
/// order their shapes over the generalized coordinates (flat, `modes x coordinates`: mass-
/// normalized eigenvectors) and each named point's displacement per unit modal amplitude (flat,
/// `modes x points x 3`, m), with the points' names.
#[pyfunction]
#[pyo3(signature = (scene=None, count=10, *, text=None))]
fn modes_json<'py>(
    py: Python<'py>,
    scene: Option<&str>,
    count: usize,
    text: Option<&str>,
) -> PyResult<ListedModes<'py>> {
    let model = held_model(py, scene, text)?;
    let point_names: Vec<String> = model.points.iter().map(|p| p.name.clone()).collect();
    refuse_nothing_to_move(&model, scene)?;
    let listed = interruptible(py, move || {
        crate::summary::modes(&model).map(|(state, _, modes)| {
            let summaries = crate::summary::mode_summaries(&model, &modes, count);
            let (mut shapes, mut displacements) = (Vec::new(), Vec::new());
            let mut ws = crate::evaluate::Workspace::new(&model);
            crate::evaluate::evaluate_forces(&model, &state, &mut ws);
            let rest: Vec<_> = ws.points.iter().map(|p| p.position).collect();
            for i in crate::summary::listed_modes(&modes, count) {
                let shape = &modes[i].shape;
                shapes.extend(shape.iter());
                let mut moved = state.clone();
                crate::state::retract(&model, &mut moved.poses, shape, MODE_SHAPE_STEP);
                crate::evaluate::evaluate_forces(&model, &moved, &mut ws);
                for (p, r) in ws.points.iter().zip(&rest) {
                    displacements.extend(((p.position - r) / MODE_SHAPE_STEP).iter());
                }
            }
            (summaries, shapes, displacements)
        })
    })?
    .map_err(|f| match f {
        crate::summary::ModesFailure::NoEquilibrium(f) => no_equilibrium(py, f),
        crate::summary::ModesFailure::SingularMass => {
            PyRuntimeError::new_err("the mass matrix is singular on the joints' null space")
        }
    })?;
    let (summaries, shapes, displacements) = listed;
    let json = serde_json::to_string(&summaries).map_err(|e| PyRuntimeError::new_err(e.to_string()))?;
    Ok((
        json,
        numpy::PyArray1::from_vec(py, shapes),
        numpy::PyArray1::from_vec(py, displacements),
        point_names,
    ))
}

/// `quasi_static_csv(scene=None, steps=None, *, text=None)`: the equilibrium path along the
/// scene's deployment schedule (`steps` load steps, default the scene's), as the CSV text
/// `tensegrity deploy --quasi-static --out -` writes (the same header, rows and digits). The
/// solve runs without the GIL; a path that ends without an equilibrium raises `NoEquilibrium`.
#[pyfunction]
#[pyo3(signature = (scene=None, steps=None, *, text=None))]
fn quasi_static_csv(
    py: Python<'_>,
    scene: Option<&str>,
    steps: Option<usize>,
    text: Option<&str>,
) -> PyResult<String> {
    let mut model = held_model(py, scene, text)?;
    if let Some(n) = steps {
        let max = crate::scene::limits::MAX_LOAD_STEPS;
        if n == 0 || n > max {
            return Err(PyValueError::new_err(format!("steps must be in [1, {max}], got {n}")));
        }
        model.schedule.steps = n;
    }
    let (csv, path) = interruptible(py, move || {
        let mut csv = crate::report::path_csv_header(&model);
        csv.push('\n');
        let mut state = crate::State::initial(&model);
        let mut ws = crate::evaluate::Workspace::new(&model);
        let path = crate::solve::deploy::deploy_quasi_static(&model, &mut state, &mut ws, |step, st, w| {
            csv.push_str(&crate::report::path_csv_row(&model, st, w, step));
            csv.push('\n');
        });
        (csv, path.map(|_| ()).map_err(|e| e.to_string()))
    })?;
    path.map_err(NoEquilibrium::new_err)?;
    Ok(csv)
}

/// `field_reference()`: the scene-file field reference (every table and field: format, unit,
/// default, range) as the Markdown table `tensegrity fields` prints.
#[pyfunction]
fn field_reference() -> String {
    crate::scene::reference::markdown()
}

/// Steps a dynamic run takes between two looks for Ctrl-C (`KeyboardInterrupt`).
const STEPS_BETWEEN_SIGNAL_CHECKS: u64 = 200;

/// `dynamic_csv(scene=None, *, text=None, integrator="generalized-alpha", dt=None, rho_inf=0.8,
/// tol=None, newton_tol=None, duration=None, from_equilibrium=False, record=None)`: the dynamic
/// deployment `tensegrity deploy --dynamic` runs with the same options (`--integrator`, `--dt`,
/// ...), as `(csv, summary)`: the CSV text it writes (the same header, rows and digits) and a dict
/// (`steps`, `newton_iterations`, `rejected`, `substeps`, `wall_time_s`, `struts_collided`,
/// `bag`). With `record`, a bag is written into that new directory. The steps run without the
/// GIL; Ctrl-C stops the run within a few hundred steps (`KeyboardInterrupt`). A step that fails
/// raises `PhysicsFailure` naming the time.
#[pyfunction]
#[pyo3(signature = (scene=None, *, text=None, integrator="generalized-alpha", dt=None, rho_inf=0.8,
                    tol=None, newton_tol=None, duration=None, from_equilibrium=false, record=None,
                    global_error=false))]
#[allow(clippy::too_many_arguments)] // the command line's options, by keyword
fn dynamic_csv<'py>(
    py: Python<'py>,
    scene: Option<&str>,
    text: Option<&str>,
    integrator: &str,
    dt: Option<f64>,
    rho_inf: f64,
    tol: Option<f64>,
    newton_tol: Option<f64>,
    duration: Option<f64>,
    from_equilibrium: bool,
    record: Option<std::path::PathBuf>,
    global_error: bool,
) -> PyResult<(String, Bound<'py, PyDict>)> {
    let model = moving_model(py, scene, text)?;
    let label = scene.unwrap_or("<text>");
    let mut settings = dynamic_settings(&model, integrator, dt, rho_inf, tol, newton_tol)?;
    let steps = crate::io::record::offline::dynamic_steps(&model, duration, settings.dt, "duration")
        .map_err(PyValueError::new_err)?;
    // global error control first finds the local tolerance; the run returned is the one made at it
    let global = match global_error {
        false => None,
        true if tol.is_none() => {
            return Err(PyValueError::new_err("global_error needs tol (the global tolerance, m)"))
        }
        true => {
            let (m, l) = (model.clone(), label.to_string());
            let found = interruptible(py, move || {
                crate::io::record::offline::global_tolerance(&m, &l, settings, from_equilibrium, steps, || {})
            })?;
            Some(found.map_err(PhysicsFailure::new_err)?)
        }
    };
    if let Some(g) = &global {
        settings.tolerance = Some(g.tolerance);
    }
    let mut run = DynamicDeployment::start(&model, label, settings, from_equilibrium, record.as_deref())
        .map_err(PhysicsFailure::new_err)?;
    for w in run.warnings() {
        PyErr::warn(py, &py.get_type::<pyo3::exceptions::PyUserWarning>(), &std::ffi::CString::new(w)?, 1)?;
    }
    let mut csv = run.header();
    csv.push('\n');
    csv.push_str(&run.row(&Default::default()));
    csv.push('\n');
    let mut done = 0;
    while done < steps {
        let chunk = STEPS_BETWEEN_SIGNAL_CHECKS.min(steps - done);
        py.detach(|| -> Result<(), String> {
            for _ in 0..chunk {
                csv.push_str(&run.step().map_err(|fault| format!("{label}: {fault}"))?);
                csv.push('\n');
            }
            Ok(())
        })
        .map_err(PhysicsFailure::new_err)?;
        done += chunk;
        py.check_signals()?;
    }
    let summary = run.finish().map_err(|e| PyRuntimeError::new_err(e.to_string()))?;
    let t = &summary.totals;
    let out = PyDict::new(py);
    out.set_item("steps", t.steps)?;
    out.set_item("newton_iterations", t.newton_iterations)?;
    out.set_item("rejected", t.rejected)?;
    out.set_item("substeps", t.substeps)?;
    out.set_item("wall_time_s", t.wall_time.as_secs_f64())?;
    out.set_item("struts_collided", summary.struts_collided)?;
    out.set_item("bag", summary.bag.map(|(dir, _)| dir))?;
    if let Some(g) = global {
        let d = PyDict::new(py);
        d.set_item("requested", g.requested)?;
        d.set_item("local_tolerance", g.tolerance)?;
        d.set_item("estimate", g.estimate)?;
        d.set_item("runs", g.runs)?;
        out.set_item("global_error", d)?;
    }
    Ok((csv, out))
}

/// `generate_toml(kind, options)`: the scene `tensegrity generate KIND` writes with the options
/// (a dict by the command line's names, with `_` for `-`: `n`, `cluster`, `prestress`,
/// `nodal_strut_ea`, `consistent_mass`; `n`, `stages`; `hinged_hub`, ...; `m1`, `m2`; `mu`,
/// `all_winches`, `robots`), as TOML text. An unknown kind or option, a value of the wrong type or
/// out of range raises `ValueError` or `TypeError` naming it.
#[pyfunction]
fn generate_toml(kind: &str, options: HashMap<String, Bound<'_, PyAny>>) -> PyResult<String> {
    use crate::scene::generate::{Generator, GENERATOR_KINDS};
    let allowed: &[&str] = match kind {
        "prism" => &["n", "cluster", "prestress", "nodal_strut_ea", "consistent_mass"],
        "tower" => &["n", "stages"],
        "tbar" => &["hinged_hub", "nodal_strut_ea", "consistent_mass"],
        "atwood" => &["m1", "m2"],
        "sixbar" => &["mu", "all_winches", "robots"],
        _ => {
            return Err(PyValueError::new_err(format!(
                "no generator {kind:?} (generators: {})",
                GENERATOR_KINDS.join(", ")
            )))
        }
    };
    let mut names: Vec<&String> = options.keys().collect();
    names.sort();
    if let Some(unknown) = names.into_iter().find(|k| !allowed.contains(&k.as_str())) {
        return Err(PyValueError::new_err(format!(
            "{kind} takes no option {unknown:?} (its options: {})",
            allowed.join(", ")
        )));
    }
    let int = |name: &str, default: usize| -> PyResult<usize> {
        match options.get(name) {
            None => Ok(default),
            Some(v)
                if v.is_instance_of::<pyo3::types::PyBool>() || !v.is_instance_of::<pyo3::types::PyInt>() =>
            {
                Err(pyo3::exceptions::PyTypeError::new_err(format!("{name} must be an int, got {v}")))
            }
            Some(v) => v
                .extract()
                .map_err(|_| PyValueError::new_err(format!("{name} must be a non-negative int, got {v}"))),
        }
    };
    let number = |name: &str, default: f64| -> PyResult<f64> {
        match options.get(name) {
            None => Ok(default),
            Some(v) if v.is_instance_of::<pyo3::types::PyBool>() => {
                Err(pyo3::exceptions::PyTypeError::new_err(format!("{name} must be a number, got {v}")))
            }
            Some(v) => v.extract().map_err(|_| {
                pyo3::exceptions::PyTypeError::new_err(format!("{name} must be a number, got {v}"))
            }),
        }
    };
    let flag = |name: &str| -> PyResult<bool> {
        match options.get(name) {
            None => Ok(false),
            Some(v) => v.extract().map_err(|_| {
                pyo3::exceptions::PyTypeError::new_err(format!("{name} must be a bool, got {v}"))
            }),
        }
    };
    let optional = |name: &str| -> PyResult<Option<f64>> {
        match options.get(name) {
            Some(v) if !v.is_none() => number(name, 0.0).map(Some),
            _ => Ok(None),
        }
    };
    let generator = match kind {
        "prism" => Generator::Prism {
            n: int("n", 3)?,
            cluster: flag("cluster")?,
            prestress: number("prestress", 100.0)?,
            nodal_strut_ea: optional("nodal_strut_ea")?,
            consistent_mass: flag("consistent_mass")?,
        },
        "tower" => Generator::Tower { n: int("n", 3)?, stages: int("stages", 3)? },
        "tbar" => Generator::Tbar {
            hinged_hub: flag("hinged_hub")?,
            nodal_strut_ea: optional("nodal_strut_ea")?,
            consistent_mass: flag("consistent_mass")?,
        },
        "atwood" => Generator::Atwood { m1: number("m1", 2.0)?, m2: number("m2", 1.0)? },
        _ => Generator::Sixbar {
            mu: number("mu", 0.8)?,
            all_winches: flag("all_winches")?,
            robots: int("robots", 1)?,
        },
    };
    if matches!(generator, Generator::Prism { nodal_strut_ea: None, consistent_mass: true, .. })
        || matches!(generator, Generator::Tbar { nodal_strut_ea: None, consistent_mass: true, .. })
    {
        return Err(PyValueError::new_err("consistent_mass needs nodal_strut_ea (the nodal form)"));
    }
    generator.toml().map_err(PyValueError::new_err)
}

/// Adds the library's functions and exceptions to the module.
pub(super) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("PhysicsFailure", m.py().get_type::<PhysicsFailure>())?;
    m.add("CommandRefused", m.py().get_type::<CommandRefused>())?;
    m.add("SceneError", m.py().get_type::<SceneError>())?;
    m.add("NoEquilibrium", m.py().get_type::<NoEquilibrium>())?;
    m.add_function(pyo3::wrap_pyfunction!(statics_json, m)?)?;
    m.add_function(pyo3::wrap_pyfunction!(modes_json, m)?)?;
    m.add_function(pyo3::wrap_pyfunction!(quasi_static_csv, m)?)?;
    m.add_function(pyo3::wrap_pyfunction!(dynamic_csv, m)?)?;
    m.add_function(pyo3::wrap_pyfunction!(generate_toml, m)?)?;
    m.add_function(pyo3::wrap_pyfunction!(field_reference, m)?)?;
    m.add_function(pyo3::wrap_pyfunction!(check_json, m)?)?;
    m.add_function(pyo3::wrap_pyfunction!(study_markdown, m)?)?;
    m.add_function(pyo3::wrap_pyfunction!(work_precision_markdown, m)?)?;
    m.add_function(pyo3::wrap_pyfunction!(read_bag, m)?)?;
    m.add_function(pyo3::wrap_pyfunction!(replay_report, m)?)?;
    m.add_function(pyo3::wrap_pyfunction!(reindex_bag, m)?)?;
    m.add_function(pyo3::wrap_pyfunction!(step_times, m)?)?;
    m.add_function(pyo3::wrap_pyfunction!(scaling_markdown, m)?)?;
    Ok(())
}

/// `check_json(scene=None, *, text=None)`: the counts `tensegrity check` prints
/// (`report::summary`: bodies by kind `[node, bar, rigid, fixed]`, coordinates, constraints,
/// cables, sliding cables, members, pulleys, actuators, ramps, planar, grounds, contact spheres)
/// and the names of the bodies, cables and actuators, as JSON text; `SceneError` for a scene
/// that cannot be read or is invalid.
#[pyfunction]
#[pyo3(signature = (scene=None, *, text=None))]
fn check_json(py: Python<'_>, scene: Option<&str>, text: Option<&str>) -> PyResult<String> {
    let model = model_of(py, scene, text)?;
    let mut value = serde_json::to_value(crate::report::summary(&model))
        .map_err(|e| PyRuntimeError::new_err(e.to_string()))?;
    let names = |it: Vec<&str>| serde_json::Value::from(it);
    value["body_names"] = names(model.bodies.iter().map(|b| b.name.as_str()).collect());
    value["cable_names"] = names(model.cable_names.iter().map(String::as_str).collect());
    value["actuator_names"] = names(model.actuator_names.iter().map(String::as_str).collect());
    Ok(value.to_string())
}

/// The model of a scene that has something to move (not every body fixed), else a `ValueError`.
fn moving_model(py: Python<'_>, scene: Option<&str>, text: Option<&str>) -> PyResult<Model> {
    let model = model_of(py, scene, text)?;
    refuse_nothing_to_move(&model, scene)?;
    Ok(model)
}

/// A `ValueError` for a model with no free coordinate (every body fixed), naming the scene.
fn refuse_nothing_to_move(model: &Model, scene: Option<&str>) -> PyResult<()> {
    match model.dof_count {
        0 => Err(PyValueError::new_err(format!(
            "{}: {}",
            scene.unwrap_or("<text>"),
            crate::sim::StepError::NothingToMove
        ))),
        _ => Ok(()),
    }
}

/// The settings the command line's integrator options give, named as Python spells them.
fn dynamic_settings(
    model: &Model,
    integrator: &str,
    dt: Option<f64>,
    rho_inf: f64,
    tol: Option<f64>,
    newton_tol: Option<f64>,
) -> PyResult<crate::sim::SimSettings> {
    let Some(integrator) = crate::solve::dynamics::Integrator::parse(integrator, rho_inf) else {
        return Err(PyValueError::new_err(format!(
            "integrator must be generalized-alpha (ga), symplectic-euler (euler), rk4 or dormand-prince (dopri5), got {integrator:?}"
        )));
    };
    let options =
        crate::sim::DynamicOptions { integrator, dt, rho_inf, tolerance: tol, newton_tolerance: newton_tol };
    options.settings(model.physics_dt, str::to_string).map_err(PyValueError::new_err)
}

/// `study_markdown(scene=None, out, *, text=None, ramp_times=None, point=None, friction=None,
/// settle=1.0, jobs=0, integrator=..., dt=None, rho_inf=0.8, tol=None, newton_tol=None)`: `tensegrity
/// study` with the same options, writing the same files into `out` (CSVs, `summary.md`, plots),
/// and returning the summary table it prints (Markdown). Runs without the GIL.
#[pyfunction]
#[pyo3(signature = (scene, out, *, text=None, ramp_times=None, point=None, friction=None, settle=1.0, jobs=0,
                    integrator="generalized-alpha", dt=None, rho_inf=0.8, tol=None, newton_tol=None))]
#[allow(clippy::too_many_arguments)] // the command line's options, by keyword
fn study_markdown(
    py: Python<'_>,
    scene: Option<&str>,
    out: std::path::PathBuf,
    text: Option<&str>,
    ramp_times: Option<Vec<f64>>,
    point: Option<&str>,
    friction: Option<Vec<f64>>,
    settle: f64,
    jobs: usize,
    integrator: &str,
    dt: Option<f64>,
    rho_inf: f64,
    tol: Option<f64>,
    newton_tol: Option<f64>,
) -> PyResult<String> {
    let model = moving_model(py, scene, text)?;
    if friction.is_some() && ramp_times.is_some() {
        return Err(PyValueError::new_err("give ramp_times or friction, not both"));
    }
    if let Some(mus) = friction {
        let point = point.map(str::to_string);
        let result = interruptible(py, move || {
            crate::study::friction_study(&model, &mus, point.as_deref(), &out).map(|r| r.markdown())
        })?;
        return result.map_err(PyValueError::new_err);
    }
    let settings = dynamic_settings(&model, integrator, dt, rho_inf, tol, newton_tol)?;
    let ramp_times = match ramp_times {
        Some(t) => t,
        None => crate::study::default_ramp_times(&model).map_err(PyValueError::new_err)?,
    };
    let point = point.map(str::to_string);
    let result = interruptible(py, move || {
        crate::study::deployment_study(&model, &ramp_times, point.as_deref(), settings, settle, jobs, &out)
            .map(|r| r.markdown())
    })?;
    result.map_err(PyValueError::new_err)
}

/// `work_precision_markdown(scene, out, *, text=None, reference_dt=1e-5,
/// reference_integrator="dormand-prince", repeats=3, duration=None, sample=0.01, jobs=0,
/// tolerances=[1e-3, ..., 1e-9], global_control=False)`: `tensegrity bench work-precision` with the
/// same options and runs, writing `work_precision.{csv,md,png,svg}` into `out` and returning the
/// table it prints. Runs without the GIL (minutes at the defaults).
#[pyfunction]
#[pyo3(signature = (scene, out, *, text=None, reference_dt=1e-5, reference_integrator="dormand-prince", repeats=3,
                    duration=None, sample=0.01, jobs=0, tolerances=None, global_control=false))]
#[allow(clippy::too_many_arguments)] // the command line's options, by keyword
fn work_precision_markdown(
    py: Python<'_>,
    scene: Option<&str>,
    out: std::path::PathBuf,
    text: Option<&str>,
    reference_dt: f64,
    reference_integrator: &str,
    repeats: usize,
    duration: Option<f64>,
    sample: f64,
    jobs: usize,
    tolerances: Option<Vec<f64>>,
    global_control: bool,
) -> PyResult<String> {
    let model = moving_model(py, scene, text)?;
    let reference = match reference_integrator {
        "dormand-prince" | "dopri5" => crate::solve::dynamics::Integrator::DormandPrince,
        "generalized-alpha" | "ga" => crate::solve::dynamics::Integrator::GeneralizedAlpha { rho_inf: 0.8 },
        other => {
            return Err(PyValueError::new_err(format!(
                "reference_integrator must be dormand-prince or generalized-alpha, got {other:?}"
            )))
        }
    };
    let tolerances = tolerances.unwrap_or_else(|| vec![1e-3, 1e-4, 1e-5, 1e-6, 1e-7, 1e-8, 1e-9]);
    if let Some(t) = tolerances.iter().find(|t| !(t.is_finite() && **t > 0.0)) {
        return Err(PyValueError::new_err(format!("tolerances must be positive, got {t}")));
    }
    if repeats == 0 {
        return Err(PyValueError::new_err("repeats must be at least 1"));
    }
    let duration = duration.unwrap_or(model.schedule.end_time() + 0.5);
    let configs = crate::study::work_precision_runs(&model, &tolerances, global_control);
    let settings = crate::study::WorkPrecisionSettings {
        reference_dt,
        reference_integrator: reference,
        duration,
        sample,
        repeats,
        jobs,
    };
    let table = out.join("work_precision.md");
    interruptible(py, move || crate::study::work_precision(&model, &configs, settings, &out))?
        .map_err(PyValueError::new_err)?;
    std::fs::read_to_string(table).map_err(|e| PyRuntimeError::new_err(e.to_string()))
}

/// `read_bag(path)`: a bag (a rosbag2 directory or its `.mcap` file) as `(info, series)`. `info`:
/// `path`, `file_bytes`, `start_ns`, `end_ns`, `messages`, `topics` (name -> (type, count)),
/// `run` (the run record: scene, settings; empty without one) and `cut_short` (why reading
/// stopped early, or None). `series`: the exact state over time (the `ground_truth` topics where
/// the run had sensors), flat float64 arrays with their names: `time_s` `(n,)`, `body_names`,
/// `body_position` `(n*b*3,)`, `body_orientation` `(n*b*4,)`, `cable_time_s` `(m,)`,
/// `cable_names`, `cable_tension`, `cable_length`, `cable_rest_length` `(m*c,)`, `cable_slack`.
#[pyfunction]
fn read_bag<'py>(
    py: Python<'py>,
    path: std::path::PathBuf,
) -> PyResult<(Bound<'py, PyDict>, Bound<'py, PyDict>)> {
    use crate::io::msg::{CableStates, PoseArray};
    use numpy::PyArray1;
    let reader =
        crate::io::record::bag::BagReader::open(&path).map_err(|e| PyValueError::new_err(e.to_string()))?;
    let info = reader.info();
    let topics: Vec<&str> = info.topics.iter().map(|(t, _)| t.name.as_str()).collect();
    let pick = |suffix: &str| -> Option<String> {
        let exact = topics.iter().find(|t| t.ends_with(&format!("/ground_truth/{suffix}")));
        exact.or_else(|| topics.iter().find(|t| t.ends_with(&format!("/{suffix}")))).map(|t| t.to_string())
    };
    let (poses_topic, cables_topic) = (pick("body_poses"), pick("cable_states"));
    let (mut time, mut position, mut orientation) = (Vec::new(), Vec::new(), Vec::new());
    let (mut cable_time, mut tension, mut length, mut rest) =
        (Vec::<f64>::new(), Vec::<f64>::new(), Vec::<f64>::new(), Vec::<f64>::new());
    let mut slack = Vec::<bool>::new();
    let (mut body_names, mut cable_names) = (Vec::new(), Vec::new());
    let mut cut_short = info.cut_short.clone();
    for message in reader.messages() {
        let message = match message {
            Ok(m) => m,
            Err(e) => {
                cut_short.get_or_insert(e);
                break;
            }
        };
        let here = |e: String| PyValueError::new_err(format!("{}: {}: {e}", path.display(), message.topic));
        if Some(&message.topic) == poses_topic.as_ref() {
            let poses: PoseArray = message.decode().map_err(here)?;
            time.push(poses.header.stamp.seconds());
            for p in &poses.poses {
                position.extend([p.position.x, p.position.y, p.position.z]);
                orientation.extend([p.orientation.x, p.orientation.y, p.orientation.z, p.orientation.w]);
            }
        } else if Some(&message.topic) == cables_topic.as_ref() {
            let cables: CableStates = message.decode().map_err(here)?;
            cable_time.push(cables.header.stamp.seconds());
            if cable_names.is_empty() {
                cable_names = cables.name.clone();
            }
            tension.extend(&cables.tension);
            length.extend(&cables.length);
            rest.extend(&cables.rest_length);
            slack.extend(&cables.slack);
        }
    }
    if let Some(run) = &info.run {
        if let Some(text) = run.get("scene") {
            if let Ok(model) = crate::scene::from_toml(text, "<recorded>") {
                body_names = model.bodies.iter().map(|b| b.name.clone()).collect();
            }
        }
    }
    let out_info = PyDict::new(py);
    out_info.set_item("path", &info.path)?;
    out_info.set_item("file_bytes", info.file_bytes)?;
    let (start, end) = info.time_range.unwrap_or((0, 0));
    out_info.set_item("start_ns", start)?;
    out_info.set_item("end_ns", end)?;
    out_info.set_item("messages", info.topics.iter().map(|(_, n)| n).sum::<u64>())?;
    let by_topic = PyDict::new(py);
    for (t, n) in &info.topics {
        by_topic.set_item(&t.name, (&t.type_name, n))?;
    }
    out_info.set_item("topics", by_topic)?;
    out_info.set_item("run", info.run.clone().unwrap_or_default())?;
    out_info.set_item("cut_short", cut_short)?;
    let series = PyDict::new(py);
    series.set_item("time_s", PyArray1::from_vec(py, time))?;
    series.set_item("body_names", body_names)?;
    series.set_item("body_position", PyArray1::from_vec(py, position))?;
    series.set_item("body_orientation", PyArray1::from_vec(py, orientation))?;
    series.set_item("cable_time_s", PyArray1::from_vec(py, cable_time))?;
    series.set_item("cable_names", cable_names)?;
    series.set_item("cable_tension", PyArray1::from_vec(py, tension))?;
    series.set_item("cable_length", PyArray1::from_vec(py, length))?;
    series.set_item("cable_rest_length", PyArray1::from_vec(py, rest))?;
    series.set_item("cable_slack", slack)?;
    Ok((out_info, series))
}

/// `replay_report(bag, scene=None, out=None)`: `tensegrity replay` (runs the bag's run again
/// from its scene, settings and recorded commands, and compares every recorded message bit for
/// bit), as a dict: `identical`, `difference` (the first, in words, or None), `compared`,
/// `steps`, `command_batches`, `resets`, `missing`, `cut_short`. With `scene`, that scene file
/// instead of the recorded one; with `out`, the re-run is written as a bag there. Runs without
/// the GIL.
#[pyfunction]
#[pyo3(signature = (bag, scene=None, out=None))]
fn replay_report<'py>(
    py: Python<'py>,
    bag: std::path::PathBuf,
    scene: Option<std::path::PathBuf>,
    out: Option<std::path::PathBuf>,
) -> PyResult<Bound<'py, PyDict>> {
    let scene_text = match &scene {
        Some(p) => Some((
            std::fs::read_to_string(p).map_err(|e| PyValueError::new_err(format!("{}: {e}", p.display())))?,
            p.display().to_string(),
        )),
        None => None,
    };
    let report = py
        .detach(|| {
            crate::io::record::replay(
                &bag,
                scene_text.as_ref().map(|(t, l)| (t.as_str(), l.as_str())),
                out.as_deref(),
            )
        })
        .map_err(|e| PyValueError::new_err(e.to_string()))?;
    let d = PyDict::new(py);
    d.set_item("identical", report.difference.is_none())?;
    d.set_item("difference", report.difference.as_ref().map(|x| x.to_string()))?;
    d.set_item("compared", report.compared)?;
    d.set_item("steps", report.steps)?;
    d.set_item("command_batches", report.command_batches)?;
    d.set_item("resets", report.resets)?;
    d.set_item("missing", report.missing)?;
    d.set_item("cut_short", report.cut_short)?;
    Ok(d)
}

/// `reindex_bag(path)`: `tensegrity bag reindex`: a bag whose writer was killed is rewritten
/// with every message that can be read, and its summary and end magic. Returns None when the bag
/// was complete (left as it is), else `(messages, why)`: the messages kept and why the original
/// stopped (or None).
#[pyfunction]
fn reindex_bag(py: Python<'_>, path: std::path::PathBuf) -> PyResult<Option<(u64, Option<String>)>> {
    let done = py.detach(|| {
        crate::io::record::bag::reindex(&path, &crate::io::record::bag::BagOptions::default())
            .map_err(|e| e.to_string())
    });
    let done = done.map_err(PyValueError::new_err)?;
    Ok(done.map(|(summary, why)| (summary.counts.iter().sum::<u64>(), why)))
}

/// `step_times(scene=None, *, text=None, integrator="generalized-alpha", dt=None, rho_inf=0.8,
/// newton_tol=None, steps=2000)`: `tensegrity bench steps`: the wall time of `steps` steps of the
/// scene after 10 untimed ones, as a dict: `median_s`, `mean_s`, `max_s` (s per step),
/// `newton_per_step`, `factorizations_per_step`, `unknowns`, `nonzeros`, `backend`. Runs without
/// the GIL.
#[pyfunction]
#[pyo3(signature = (scene=None, *, text=None, integrator="generalized-alpha", dt=None, rho_inf=0.8, newton_tol=None,
                    steps=2000))]
#[allow(clippy::too_many_arguments)] // the command line's options, by keyword
fn step_times<'py>(
    py: Python<'py>,
    scene: Option<&str>,
    text: Option<&str>,
    integrator: &str,
    dt: Option<f64>,
    rho_inf: f64,
    newton_tol: Option<f64>,
    steps: usize,
) -> PyResult<Bound<'py, PyDict>> {
    let model = moving_model(py, scene, text)?;
    if steps == 0 {
        return Err(PyValueError::new_err("steps must be at least 1"));
    }
    let settings = dynamic_settings(&model, integrator, dt, rho_inf, None, newton_tol)?;
    let t = interruptible(py, move || crate::study::step_times(&model, settings, steps))?
        .map_err(PhysicsFailure::new_err)?;
    let d = PyDict::new(py);
    d.set_item("median_s", t.median)?;
    d.set_item("mean_s", t.mean)?;
    d.set_item("max_s", t.max)?;
    d.set_item("newton_per_step", t.newton_per_step)?;
    d.set_item("factorizations_per_step", t.factorizations_per_step)?;
    d.set_item("unknowns", t.unknowns)?;
    d.set_item("nonzeros", t.nonzeros)?;
    d.set_item("backend", format!("{:?}", t.backend))?;
    Ok(d)
}

/// `scaling_markdown(stages, steps, out)`: `tensegrity bench scaling`: the step cost of the
/// generated towers (three families) at each number of `stages` (1 to 256), `steps` steps each,
/// writing `scaling.{csv,md,png,svg}` into `out` and returning the table it prints.
#[pyfunction]
fn scaling_markdown(
    py: Python<'_>,
    stages: Vec<usize>,
    steps: usize,
    out: std::path::PathBuf,
) -> PyResult<String> {
    if stages.is_empty() || stages.iter().any(|s| !(1..=256).contains(s)) || steps == 0 {
        return Err(PyValueError::new_err("stages must be in [1, 256] and steps at least 1"));
    }
    let table = out.join("scaling.md");
    interruptible(py, move || crate::study::scaling(&stages, steps, &out))?.map_err(PyValueError::new_err)?;
    std::fs::read_to_string(table).map_err(|e| PyRuntimeError::new_err(e.to_string()))
}
