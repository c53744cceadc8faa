//! `tensegrity deploy SCENE`: follows the scene's deployment schedule as a path of equilibria
//! (`--quasi-static`) or a time history (`--dynamic`, the node's core driven offline by
//! `io::record::offline`), to a CSV and optionally a bag.

use std::io::Write;
use std::path::{Path, PathBuf};

use tensegrity::evaluate::Workspace;
use tensegrity::io::node::params::NodeParams;
use tensegrity::io::record;
use tensegrity::report;
use tensegrity::sim::SimSettings;
use tensegrity::solve::deploy::deploy_quasi_static;
use tensegrity::study;
use tensegrity::SolveError;
use tensegrity::{Model, State};

use crate::output::*;

/// The options of `deploy` (`Command::Deploy`).
#[derive(clap::Args)]
#[command(group(clap::ArgGroup::new("mode").required(true).args(["quasi_static", "dynamic"])))]
pub struct DeployArgs {
    /// Scene file (TOML).
    scene: PathBuf,
    /// Quasi-static deployment: a path of equilibria (load stepping).
    #[arg(long)]
    quasi_static: bool,
    /// Dynamic deployment: implicit or explicit time integration.
    #[arg(long)]
    dynamic: bool,
    /// Number of load steps (quasi-static; default: the scene's `deployment.steps`).
    #[arg(long)]
    steps: Option<usize>,
    #[command(flatten)]
    dynamics: DynamicArgs,
    /// Simulated time, s (dynamic; default: the schedule's end + 1 s).
    #[arg(long, allow_hyphen_values = true)]
    duration: Option<f64>,
    /// Dynamic: start at rest in the static equilibrium at t = 0 (where a quasi-static
    /// deployment starts). Without it the run starts from the scene's pose as written, at
    /// rest, and first swings toward the equilibrium.
    #[arg(long, conflicts_with = "quasi_static")]
    from_equilibrium: bool,
    /// Dynamic, with --tol: global error control. Runs again at a tenth of the tolerance until
    /// two runs agree to within ten times --tol, then writes the run at the last local
    /// tolerance, whose error (a tenth of the disagreement) is at most --tol: for runs through
    /// instabilities (a robot tipping over an edge), which amplify what a local estimate keeps
    /// small. Costs 3 to 5 runs.
    #[arg(long, requires = "dynamic")]
    global_error: bool,
    /// Output CSV file (`-`: standard output).
    #[arg(long, required_unless_present = "record")]
    out: Option<PathBuf>,
    /// Also record a rosbag2 bag (MCAP) into this new directory: the topics the node
    /// publishes, the run record for `tensegrity replay`.
    #[arg(long, value_name = "DIR")]
    record: Option<PathBuf>,
}

/// Runs `deploy`.
pub fn run(args: DeployArgs) -> Result<(), String> {
    // --quasi-static is the mode without --dynamic (the group requires one of them)
    let DeployArgs {
        scene,
        quasi_static: _,
        dynamic,
        steps,
        dynamics,
        duration,
        from_equilibrium,
        global_error,
        out,
        record: bag_dir,
    } = args;
    let mut model = load(&scene)?;
    let out = out.unwrap_or_default();
    if dynamic {
        crate::output::refuse_nothing_to_move(&model, &scene)?;
        let settings = dynamics.settings(&model)?;
        if global_error && settings.tolerance.is_none() {
            return Err("--global-error needs --tol (the global tolerance, m)".into());
        }
        let run = DynamicRun { duration, from_equilibrium, global_error };
        return deploy_dynamic(&model, &scene, settings, run, &out, bag_dir.as_deref());
    }
    if let Some(note) = report::unheld_bodies_note(&model) {
        return Err(crate::output::input_error(format!("{}: {note}", scene.display())));
    }
    if let Some(n) = steps {
        let max = tensegrity::scene::limits::MAX_LOAD_STEPS;
        if n == 0 || n > max {
            return Err(format!("--steps must be in [1, {max}], got {n}"));
        }
        model.schedule.steps = n;
    }
    let mut file = csv_output(&out)?;
    writeln!(file, "{}", report::path_csv_header(&model)).map_err(|e| e.to_string())?;
    let what = format!("deploy {}", scene.display());
    let bar = Progress::new(what, &["load steps"], Some(model.schedule.steps as u64)).observe();
    let mut state = State::initial(&model);
    let mut ws = Workspace::new(&model);
    let mut io_error = None;
    let params = NodeParams::default();
    let mut recorder = match &bag_dir {
        Some(dir) => Some(
            record::offline::quasi_static_recorder(
                dir,
                &model,
                &scene.display().to_string(),
                model.schedule.steps,
            )
            .map_err(|e| e.to_string())?,
        ),
        None => None,
    };
    let mut publisher: Option<record::PathPublisher> = None;
    let path = deploy_quasi_static(&model, &mut state, &mut ws, |step, st, w| {
        let row = report::path_csv_row(&model, st, w, step);
        if let Err(e) = writeln!(file, "{row}") {
            io_error.get_or_insert(e);
        }
        if let Some(r) = recorder.as_mut() {
            publisher
                .get_or_insert_with(|| record::PathPublisher::new(&model, st, w, &params))
                .row(r, &model, st, w);
        }
    });
    bar.finish();
    let path = path.map_err(|e| {
        // a robot on the ground loses its equilibrium where it tips over or slides: statics sees
        // the grounds' normal springs, and friction only where a ground has stick-slip friction
        let hint = match (
            model.contact_pairs() > 0 && matches!(e, SolveError::NoEquilibrium { .. }),
            model.has_stick_friction(),
        ) {
            (false, _) => "",
            (true, false) => {
                "; with contacts a structure has no equilibrium once it tips over or slides (statics \
                 sees the normal springs, not the regularized friction): follow the deployment with --dynamic"
            }
            (true, true) => {
                "; with contacts a structure has no equilibrium once it tips over (or slides where a \
                 ground has no stick-slip friction): follow the deployment with --dynamic"
            }
        };
        format!("{}: {e}{hint}", scene.display())
    })?;
    if let Some(e) = io_error {
        return Err(write_error(&out, e));
    }
    file.flush().map_err(|e| e.to_string())?;
    if let Some(r) = recorder {
        let dir = r.dir().to_path_buf();
        let summary = r.finish().map_err(|e| e.to_string())?;
        say_closing(
            &out,
            format!(
                "bag {}: {} messages, {} bytes",
                dir.display(),
                summary.counts.iter().sum::<u64>(),
                summary.file_bytes
            ),
        );
    }
    let outputs: Vec<_> = path.output_steps().collect();
    let unstable = outputs.iter().filter(|p| !p.report.stable).count();
    let worst = path.steps.iter().map(|p| p.report.residual / p.report.force_scale).fold(0.0, f64::max);
    let traced = path.steps.len() - outputs.len();
    say_closing(
        &out,
        format!(
            "{}: {} equilibria written to {} (worst relative residual {worst:.2e}, {} Newton iterations, {unstable} not stable{})",
            model.name,
            outputs.len(),
            out.display(),
            path.steps.iter().map(|p| p.report.iterations).sum::<usize>(),
            if traced > 0 { format!("; {traced} more traced by arc length") } else { String::new() }
        ),
    );
    for snap in &path.snaps {
        let landing = &path.steps[snap.landing_row];
        say_closing(
            &out,
            format!(
                "snap-through: limit point at t = {:.6} s (the stiffness loses definiteness there); \
                 the structure jumps {:.6} m to another stable equilibrium at t = {:.6} s ({}; rows {}..{} of the CSV)",
                snap.limit_time,
                snap.jump,
                landing.time,
                if snap.followed_path {
                    format!("path traced through the unstable branch, {} points", snap.traced_points)
                } else {
                    "the traced branch ends; landing found by descending the energy from the limit point".into()
                },
                snap.from_row + 1,
                snap.landing_row + 1,
            ),
        );
    }
    Ok(())
}

/// How `deploy --dynamic` runs besides the simulator settings.
struct DynamicRun {
    /// Simulated time, s (`None`: the schedule's end + 1 s).
    duration: Option<f64>,
    /// Start at rest in the static equilibrium.
    from_equilibrium: bool,
    /// Global error control (`--global-error`).
    global_error: bool,
}

/// The local tolerance at which a run of `steps` steps meets `settings.tolerance` as a global
/// tolerance (`record::offline::global_tolerance`), with a progress bar.
fn global_tolerance(
    model: &Model,
    label: &str,
    settings: SimSettings,
    from_equilibrium: bool,
    steps: u64,
) -> Result<study::GlobalRun, String> {
    let bar = Progress::new(format!("deploy --global-error {label}"), &["steps"], None);
    let found =
        record::offline::global_tolerance(model, label, settings, from_equilibrium, steps, || bar.inc(1));
    bar.finish();
    found
}

/// `deploy --dynamic`: the node's core driven offline (`record::offline::OfflineRun`), one CSV
/// row per step; under global error control, at the local tolerance `global_tolerance` found.
fn deploy_dynamic(
    model: &Model,
    scene: &Path,
    mut settings: SimSettings,
    DynamicRun { duration, from_equilibrium, global_error }: DynamicRun,
    out: &Path,
    record: Option<&Path>,
) -> Result<(), String> {
    let steps = record::offline::dynamic_steps(model, duration, settings.dt, "--duration")?;
    let label = scene.display().to_string();
    // global error control first finds the local tolerance; the run written is the one made at
    // it (the same numbers: runs are deterministic)
    let global = match global_error {
        true => Some(global_tolerance(model, &label, settings, from_equilibrium, steps)?),
        false => None,
    };
    if let Some(g) = &global {
        settings.tolerance = Some(g.tolerance);
    }
    let mut run =
        record::offline::DynamicDeployment::start(model, &label, settings, from_equilibrium, record)?;
    for w in run.warnings() {
        eprintln!("warning: {w}");
    }
    let mut file = csv_output(out)?;
    writeln!(file, "{}", run.header()).map_err(|e| e.to_string())?;
    // the row of t = 0: the start, before any step
    writeln!(file, "{}", run.row(&Default::default())).map_err(|e| e.to_string())?;
    let bar = Progress::new(format!("deploy --dynamic {label}"), &["steps"], Some(steps));
    for _ in 0..steps {
        let row = run.step().map_err(|fault| format!("{label}: {fault}"))?;
        bar.inc(1);
        writeln!(file, "{row}").map_err(|e| write_error(out, e))?;
    }
    bar.finish();
    file.flush().map_err(|e| write_error(out, e))?;
    let summary = run.finish().map_err(|e| e.to_string())?;
    let totals = summary.totals;
    let bag = match summary.bag {
        Some((dir, summary)) => format!(
            "; bag {} ({} messages, {} bytes)",
            dir.display(),
            summary.counts.iter().sum::<u64>(),
            summary.file_bytes
        ),
        None => String::new(),
    };
    let collisions = if model.strut_pairs.is_empty() {
        String::new()
    } else {
        let names = &summary.struts_collided;
        format!(
            "; struts that collided: {} (sub-steps retried for passing through: {})",
            if names.is_empty() { "none".to_string() } else { names.join(", ") },
            totals.pass_throughs
        )
    };
    let global = match global {
        Some(g) => format!(
            "; global error control: local tolerance {:.3e} m, estimated error {:.3e} m of the {:e} m asked ({} runs, {} sub-steps in all)",
            g.tolerance, g.estimate, g.requested, g.runs, g.totals.substeps
        ),
        None => String::new(),
    };
    say_closing(
        out,
        format!(
            "{}: {} steps of {} s with {} from {}{} ({} Newton iterations, {} rejected attempts, {:.3} s wall){collisions}{global}{bag}",
            model.name,
            totals.steps,
            settings.dt,
            settings.integrator.name(),
            if from_equilibrium { "the static equilibrium" } else { "the scene's pose (--from-equilibrium would start at rest in its equilibrium)" },
            if out.as_os_str().is_empty() { String::new() } else { format!(" written to {}", out.display()) },
            totals.newton_iterations,
            totals.rejected,
            totals.wall_time.as_secs_f64()
        ),
    );
    Ok(())
}
