//! `tensegrity bench steps|machine|scaling|work-precision`: step times, whether this machine
//! keeps a real-time node on time, step time against size, and error against wall time.

use std::path::{Path, PathBuf};

use tensegrity::sim::SimSettings;
use tensegrity::solve::dynamics::Integrator;
use tensegrity::study;

use crate::output::*;

use clap::Subcommand;

#[derive(Subcommand)]
pub enum BenchKind {
    /// Wall time per step of one scene: median, mean and largest over the timed steps, Newton
    /// iterations and factorizations per step (what a controller waits for).
    Steps {
        /// Scene file (TOML), or a generated tower `tower:FAMILY:STAGES` with FAMILY one of
        /// classical, per-stage, helical.
        target: String,
        /// Integrator.
        #[arg(long, default_value = "generalized-alpha")]
        integrator: IntegratorName,
        /// Physics step, s.
        #[arg(long, allow_hyphen_values = true, default_value_t = 1e-3)]
        dt: f64,
        /// Steps timed (after 10 untimed ones).
        #[arg(long, default_value_t = 5000)]
        steps: usize,
        /// Newton tolerance of generalized-alpha, relative, 1e-12 to 1e-3 (default 1e-9).
        #[arg(long, allow_hyphen_values = true)]
        newton_tol: Option<f64>,
    },
    /// Wall time of a software-rendered frame (`tensegrity::render`, Gymnasium's `rgb_array`):
    /// median and largest over `frames` frames of the scene's run from its pose, one frame
    /// every 10 steps.
    Render {
        /// Scene file (TOML).
        scene: PathBuf,
        /// Frame width, pixels.
        #[arg(long, default_value_t = 320)]
        width: usize,
        /// Frame height, pixels.
        #[arg(long, default_value_t = 240)]
        height: usize,
        /// Frames timed.
        #[arg(long, default_value_t = 500)]
        frames: usize,
    },
    /// Whether this machine can keep a real-time node on time: how late a loop sleeping to
    /// each period's deadline wakes (the node's loop without its step) and how long a thread
    /// that never sleeps is kept off its core. Run it where the node runs (e.g. under the same
    /// `taskset` and `chrt`).
    Machine {
        /// Period, s (the node's physics_dt over its real-time factor).
        #[arg(long, allow_hyphen_values = true, default_value_t = 1e-3)]
        period: f64,
        /// Seconds for each of the two measurements.
        #[arg(long, allow_hyphen_values = true, default_value_t = 10.0)]
        seconds: f64,
    },
    /// Step time against structure size (towers of stacked prisms), dense vs sparse LU.
    Scaling {
        /// Tower stages to run.
        #[arg(long, value_delimiter = ',', default_value = "1,2,3,4,6,8,12,16")]
        stages: Vec<usize>,
        /// Steps timed per run.
        #[arg(long, default_value_t = 200)]
        steps: usize,
        /// Output directory.
        #[arg(long)]
        out: PathBuf,
    },
    /// One deployment over integrators and step sizes: error against a converged reference vs
    /// wall time (table and plot).
    WorkPrecision {
        /// Scene file (TOML).
        scene: PathBuf,
        /// Step of the reference run (fixed), s.
        #[arg(long, allow_hyphen_values = true, default_value_t = 1e-5)]
        reference_dt: f64,
        /// Integrator of the reference run: dormand-prince, or generalized-alpha (rho_inf 0.8)
        /// where an explicit step that small is refused (ground contact).
        #[arg(long, value_enum, default_value = "dormand-prince")]
        reference_integrator: IntegratorName,
        /// Timed repeats per run (the median is reported).
        #[arg(long, default_value_t = 3)]
        repeats: usize,
        /// Simulated time, s (default: the schedule's end + 0.5 s).
        #[arg(long, allow_hyphen_values = true)]
        duration: Option<f64>,
        /// Sample interval of the error, s (also the output interval of error-controlled runs).
        #[arg(long, allow_hyphen_values = true, default_value_t = 0.01)]
        sample: f64,
        /// Threads for the error runs (default: one per core); the timed runs go one at a time.
        #[arg(long, default_value_t = 0)]
        jobs: usize,
        /// Tolerances of the error-controlled runs, m.
        #[arg(long, value_delimiter = ',', default_values_t = [1e-3, 1e-4, 1e-5, 1e-6, 1e-7, 1e-8, 1e-9])]
        tolerances: Vec<f64>,
        /// Also run generalized-alpha under global error control at each tolerance (rows
        /// "(global)": reruns at a tenth of the tolerance until two runs agree; for runs through
        /// instabilities, which amplify what a local estimate keeps small).
        #[arg(long)]
        global: bool,
        /// Output directory.
        #[arg(long)]
        out: PathBuf,
    },
}

/// Runs one benchmark.
pub fn run(kind: BenchKind) -> Result<(), String> {
    match kind {
        BenchKind::Steps { target, integrator, dt, steps, newton_tol } => {
            steps_bench(&target, integrator, (dt, newton_tol), steps)
        }
        BenchKind::Machine { period, seconds } => machine(period, seconds),
        BenchKind::Render { scene, width, height, frames } => render(&scene, (width, height), frames),
        BenchKind::Scaling { stages, steps, out } => scaling(&stages, steps, &out),
        BenchKind::WorkPrecision {
            scene,
            reference_dt,
            reference_integrator,
            repeats,
            duration,
            sample,
            jobs,
            tolerances,
            global,
            out,
        } => {
            let reference = reference_integrator.integrator(0.8);
            let runs = RunChoice { tolerances, global, repeats, jobs };
            work_precision(&scene, (reference, reference_dt), runs, duration, sample, &out)
        }
    }
}

/// `bench steps`.
fn steps_bench(
    target: &str,
    integrator: IntegratorName,
    (dt, newton_tol): (f64, Option<f64>),
    steps: usize,
) -> Result<(), String> {
    let model = match target.strip_prefix("tower:") {
        Some(rest) => {
            let (family, stages) = rest.split_once(':').ok_or("expected tower:FAMILY:STAGES")?;
            let family = match family {
                "classical" => study::TowerFamily::Classical,
                "per-stage" => study::TowerFamily::PerStage,
                "helical" => study::TowerFamily::Helical,
                f => return Err(format!("unknown tower family {f:?} (classical, per-stage, helical)")),
            };
            let stages: usize =
                stages.parse().ok().filter(|s| (1..=256).contains(s)).ok_or("stages must be in [1, 256]")?;
            family.model(stages)?
        }
        None => crate::output::load_moving(Path::new(&target))?,
    };
    crate::output::check_dt("--dt", dt)?;
    if steps == 0 {
        return Err("--steps must be at least 1".into());
    }
    let integrator = integrator.integrator(0.8);
    let newton = crate::output::newton_settings("--newton-tol", newton_tol)?;
    let t = study::step_times(&model, SimSettings { dt, integrator, newton, ..Default::default() }, steps)?;
    let newton_note = newton_tol.map_or(String::new(), |t| format!(" newton {t:e}"));
    say!(
        "{}: {}{newton_note} dt {dt} s, {} unknowns ({}): median {:.2} us/step, mean {:.2}, max {:.1}; Newton {:.2}/step, factorizations {:.3}/step",
        model.name,
        integrator.name(),
        t.unknowns,
        match (t.backend, t.factor_entries) {
            (tensegrity::solve::linear::LinearBackend::Dense, _) => "dense LU".to_string(),
            (_, Some(l)) => format!("sparse, {} nonzeros, LDL^T factor {l} entries", t.nonzeros),
            (_, None) => format!("sparse LU, {} nonzeros", t.nonzeros),
        },
        1e6 * t.median,
        1e6 * t.mean,
        1e6 * t.max,
        t.newton_per_step,
        t.factorizations_per_step
    );
    Ok(())
}

/// `bench render`.
fn render(scene: &Path, (width, height): (usize, usize), frames: usize) -> Result<(), String> {
    if !(1..=4096).contains(&width) || !(1..=4096).contains(&height) || frames == 0 {
        return Err(format!(
            "--width and --height must be in 1 to 4096 pixels and --frames at least 1, got {width} x {height}, {frames}"
        ));
    }
    let model = crate::output::load_moving(scene)?;
    let mut sim =
        tensegrity::sim::Simulator::new(model, SimSettings::default()).map_err(|e| e.to_string())?;
    let mut rgb = Vec::new();
    let mut times = Vec::with_capacity(frames);
    for k in 0..frames {
        for _ in 0..10 {
            sim.step().map_err(|e| format!("{}: step {}: {e}", scene.display(), 10 * k))?;
        }
        let (m, state, ws) = (sim.model(), sim.state(), sim.workspace());
        let start = std::time::Instant::now();
        let camera = tensegrity::render::Camera::framing(m, ws, width as f64 / height as f64);
        tensegrity::render::render_rgb(m, state, ws, &camera, (width, height), &mut rgb);
        times.push(start.elapsed().as_secs_f64());
        tensegrity::progress::report(tensegrity::progress::Report {
            unit: "runs",
            done: k as u64 + 1,
            total: Some(frames as u64),
            residual_n: None,
        });
    }
    times.sort_by(f64::total_cmp);
    say!(
        "{}: {width} x {height} frames: median {:.1} us, largest {:.1} us over {frames} frames",
        sim.model().name,
        1e6 * times[frames / 2],
        1e6 * times[frames - 1]
    );
    Ok(())
}

/// `bench machine`.
fn machine(period: f64, seconds: f64) -> Result<(), String> {
    // a NaN fails both range checks
    if !(1e-6..=1.0).contains(&period) {
        return Err(format!("--period must be in [1e-6, 1] s, got {period}"));
    }
    if !(seconds > 0.0 && seconds <= 3600.0) {
        return Err(format!("--seconds must be in (0, 3600], got {seconds}"));
    }
    if seconds < period {
        return Err(format!("--seconds ({seconds}) must cover at least one --period ({period} s)"));
    }
    let (period, duration) =
        (std::time::Duration::from_secs_f64(period), std::time::Duration::from_secs_f64(seconds));
    let us = |s: f64| 1e6 * s;
    let timer = tensegrity::machine::timer_lateness(period, duration);
    say!(
        "sleeping to deadlines {:.0} us apart for {seconds} s: {} wake-ups, late by p50 {:.1} us, p99 {:.1} us, max {:.1} us; {} later than a period (a node would count each as an overrun)",
        us(period.as_secs_f64()),
        timer.wakeups,
        us(timer.lateness.p50),
        us(timer.lateness.p99),
        us(timer.lateness.max),
        timer.later_than_period
    );
    let stalls = tensegrity::machine::run_stalls(period, duration);
    say!(
        "never sleeping for {seconds} s: kept off the core {} times for more than {:.0} us, {} times for more than a period; longest {:.1} us",
        stalls.over_threshold,
        us(tensegrity::machine::RunStalls::THRESHOLD.as_secs_f64()),
        stalls.over_period,
        us(stalls.longest)
    );
    Ok(())
}

/// `bench scaling`.
fn scaling(stages: &[usize], steps: usize, out: &Path) -> Result<(), String> {
    if stages.contains(&0) || steps == 0 {
        return Err("stages and steps must be >= 1".into());
    }
    study::scaling(stages, steps, out)?;
    emit(&std::fs::read_to_string(out.join("scaling.md")).map_err(|e| e.to_string())?);
    say!("written to {}", out.display());
    Ok(())
}

/// Which runs `bench work-precision` makes and how.
struct RunChoice {
    /// Tolerances of the error-controlled runs, m.
    tolerances: Vec<f64>,
    /// Generalized-alpha under global error control too.
    global: bool,
    /// Timed repeats per run.
    repeats: usize,
    /// Threads for the error runs (0: one per core).
    jobs: usize,
}

/// `bench work-precision`.
fn work_precision(
    scene: &Path,
    (reference_integrator, reference_dt): (Integrator, f64),
    RunChoice { tolerances, global, repeats, jobs }: RunChoice,
    duration: Option<f64>,
    sample: f64,
    out: &Path,
) -> Result<(), String> {
    if let Some(t) = tolerances.iter().find(|t| !(t.is_finite() && **t > 0.0)) {
        return Err(format!("--tolerances must be positive, got {t}"));
    }
    let model = crate::output::load_moving(scene)?;
    let duration = duration.unwrap_or(model.schedule.end_time() + 0.5);
    let configs = study::work_precision_runs(&model, &tolerances, global);
    let settings =
        study::WorkPrecisionSettings { reference_dt, reference_integrator, duration, sample, repeats, jobs };
    let rows = study::work_precision(&model, &configs, settings, out)?;
    emit(&std::fs::read_to_string(out.join("work_precision.md")).map_err(|e| e.to_string())?);
    say!("{} runs written to {}", rows.len(), out.display());
    Ok(())
}
