//! `tensegrity`: command-line front end of the library (argument parsing and wiring only).

use std::io::{IsTerminal, Write};
use std::path::{Path, PathBuf};
use std::process::ExitCode;

use clap::{Parser, Subcommand};
use indicatif::{ProgressBar, ProgressStyle};
use serde::Serialize;
use tensegrity::forces::{evaluate, Tangents, Workspace};
use tensegrity::io::bag::{self, BagOptions};
use tensegrity::io::node::{NodeCore, NodeSink, NodeView, PublishError, Topic};
use tensegrity::io::params::NodeParams;
use tensegrity::io::record;
use tensegrity::report;
use tensegrity::report::Num;
use tensegrity::scene::{self, generate};
use tensegrity::sim::SimSettings;
use tensegrity::solve::dynamics::Integrator;
use tensegrity::solve::statics::{deploy_quasi_static, EquilibriumReport, StaticSolver};
use tensegrity::study;
use tensegrity::{Model, State};

#[derive(Parser)]
#[command(name = "tensegrity", version, about = "Clustered tensegrity multibody simulator")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Print the scene-file field reference (every table and field: format, unit, default,
    /// range) as a Markdown table.
    Fields,
    /// Validate a scene and print counts of bodies, coordinates, constraints, cables and pulleys.
    Check {
        /// Scene file (TOML).
        scene: PathBuf,
    },
    /// Solve for the equilibrium of a scene at its initial rest lengths.
    Statics {
        /// Scene file (TOML).
        scene: PathBuf,
        /// Print JSON instead of tables.
        #[arg(long)]
        json: bool,
    },
    /// Natural frequencies and mode shapes at the equilibrium (small free oscillations, no damping).
    Modes {
        /// Scene file (TOML).
        scene: PathBuf,
        /// Print JSON instead of a table.
        #[arg(long)]
        json: bool,
        /// How many modes to list, lowest first (zero-frequency modes are listed besides).
        #[arg(long, default_value_t = 10)]
        count: usize,
        /// Also draw the shapes of the lowest vibrating modes (at most 6 of the listed ones) to
        /// PLOT.png and PLOT.svg.
        #[arg(long, value_name = "PLOT")]
        plot: Option<PathBuf>,
    },
    /// Follow the scene's deployment schedule: a path of equilibria (--quasi-static, one CSV row per
    /// load step) or a time history (--dynamic, one CSV row per step).
    #[command(group(clap::ArgGroup::new("mode").required(true).args(["quasi_static", "dynamic"])))]
    Deploy {
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
        #[arg(long)]
        duration: Option<f64>,
        /// Output CSV file (`-`: standard output).
        #[arg(long, required_unless_present = "record")]
        out: Option<PathBuf>,
        /// Also record a rosbag2 bag (MCAP) into this new directory: the topics the node
        /// publishes, the run record for `tensegrity replay`.
        #[arg(long, value_name = "DIR")]
        record: Option<PathBuf>,
    },
    /// Run a recorded bag again (its scene, settings and applied commands at their recorded
    /// steps) and compare every recorded message bit for bit: prints "identical" or the first
    /// difference (exit status 1).
    Replay {
        /// The bag directory (or its .mcap file).
        bag: PathBuf,
        /// Run this scene instead of the recorded one.
        #[arg(long)]
        scene: Option<PathBuf>,
        /// Write the re-run as a new bag into this directory.
        #[arg(long, value_name = "DIR")]
        out: Option<PathBuf>,
    },
    /// Bags: what one holds, and repairing one whose writer was killed.
    Bag {
        #[command(subcommand)]
        kind: BagCommand,
    },
    /// Quasi-static path and dynamic deployments at several actuation times: CSVs, a summary
    /// table, and plots (PNG and SVG) of the deviation and of the time histories.
    Study {
        /// Scene file (TOML) with a deployment schedule.
        scene: PathBuf,
        /// Actuation times, s (the whole schedule is time-scaled to end at each). Default: the
        /// scene's own actuation time T0 times 0.02, 0.05, 0.1, 0.2, 0.5, 1, 2 and 5.
        #[arg(long, value_delimiter = ',')]
        ramp_times: Option<Vec<f64>>,
        /// Point whose displacement is tracked (default: the one that moves most along the
        /// quasi-static path).
        #[arg(long)]
        point: Option<String>,
        /// Time simulated after the schedule ends, s.
        #[arg(long, default_value_t = 1.0)]
        settle: f64,
        #[command(flatten)]
        dynamics: DynamicArgs,
        /// Threads for the dynamic runs (default: one per core); the results are the same
        /// whatever the count.
        #[arg(long, default_value_t = 0)]
        jobs: usize,
        /// Output directory.
        #[arg(long)]
        out: PathBuf,
    },
    /// Benchmarks.
    Bench {
        #[command(subcommand)]
        kind: BenchKind,
    },
    /// Write a generated scene as TOML.
    Generate {
        #[command(subcommand)]
        kind: GenerateKind,
        /// Output file (default: standard output).
        #[arg(long, global = true)]
        out: Option<PathBuf>,
    },
}

#[derive(clap::Args, Clone, Copy)]
struct DynamicArgs {
    /// Integrator: generalized-alpha (ga; implicit, any step), symplectic-euler (euler), rk4 or
    /// dormand-prince (dopri5) (explicit: refused above their stability limit).
    #[arg(long, default_value = "generalized-alpha")]
    integrator: IntegratorName,
    /// Physics step, s (default: the scene's physics_dt, else 0.001); with --tol the output
    /// interval, the sub-steps inside it chosen by the error estimate.
    #[arg(long)]
    dt: Option<f64>,
    /// Spectral radius at infinity of generalized-alpha, in [0, 1].
    #[arg(long, default_value_t = 0.8)]
    rho_inf: f64,
    /// Local error tolerance per step, m: error-controlled steps (generalized-alpha,
    /// dormand-prince).
    #[arg(long)]
    tol: Option<f64>,
}

#[derive(clap::ValueEnum, Clone, Copy)]
enum IntegratorName {
    #[value(name = "generalized-alpha", alias = "ga")]
    GeneralizedAlpha,
    #[value(name = "symplectic-euler", alias = "euler")]
    SymplecticEuler,
    #[value(name = "rk4")]
    Rk4,
    #[value(name = "dormand-prince", alias = "dopri5")]
    DormandPrince,
}

impl IntegratorName {
    fn integrator(self, rho_inf: f64) -> Integrator {
        match self {
            IntegratorName::GeneralizedAlpha => Integrator::GeneralizedAlpha { rho_inf },
            IntegratorName::SymplecticEuler => Integrator::SymplecticEuler,
            IntegratorName::Rk4 => Integrator::Rk4,
            IntegratorName::DormandPrince => Integrator::DormandPrince,
        }
    }
}

impl DynamicArgs {
    fn settings(&self, model: &Model) -> Result<SimSettings, String> {
        let dt = self.dt.or(model.physics_dt).unwrap_or(1e-3);
        if !(self.rho_inf.is_finite() && (0.0..=1.0).contains(&self.rho_inf)) {
            return Err(format!("--rho-inf must be in [0, 1], got {}", self.rho_inf));
        }
        if !(dt.is_finite() && dt > 0.0) {
            return Err(format!("--dt must be positive, got {dt}"));
        }
        if let Some(tol) = self.tol {
            if !(tol.is_finite() && tol > 0.0) {
                return Err(format!("--tol must be positive, got {tol}"));
            }
        }
        let integrator = self.integrator.integrator(self.rho_inf);
        Ok(SimSettings { dt, integrator, tolerance: self.tol, ..Default::default() })
    }
}

#[derive(Subcommand)]
enum BagCommand {
    /// Topics, types, message counts, duration and the recorded run, like `ros2 bag info`
    /// (also for a bag cut short: counted up to where it can be read).
    Info {
        /// The bag directory (or its .mcap file).
        bag: PathBuf,
    },
    /// Rewrite a bag whose writer was killed (no summary, no end magic) as a complete one that
    /// every reader opens: the messages up to the last complete chunk (the original is kept as
    /// `.mcap.cut`).
    Reindex {
        /// The bag directory.
        bag: PathBuf,
    },
}

#[derive(Subcommand)]
enum BenchKind {
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
        #[arg(long, default_value_t = 1e-3)]
        dt: f64,
        /// Steps timed (after 10 untimed ones).
        #[arg(long, default_value_t = 5000)]
        steps: usize,
    },
    /// Whether this machine can keep a real-time node on time: how late a loop sleeping to
    /// each period's deadline wakes (the node's loop without its step) and how long a thread
    /// that never sleeps is kept off its core. Run it where the node runs (e.g. under the same
    /// `taskset` and `chrt`).
    Machine {
        /// Period, s (the node's physics_dt over its real-time factor).
        #[arg(long, default_value_t = 1e-3)]
        period: f64,
        /// Seconds for each of the two measurements.
        #[arg(long, default_value_t = 10.0)]
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
        /// Step of the reference run (dormand-prince, fixed), s.
        #[arg(long, default_value_t = 1e-5)]
        reference_dt: f64,
        /// Timed repeats per run (the median is reported).
        #[arg(long, default_value_t = 3)]
        repeats: usize,
        /// Simulated time, s (default: the schedule's end + 0.5 s).
        #[arg(long)]
        duration: Option<f64>,
        /// Sample interval of the error, s (also the output interval of error-controlled runs).
        #[arg(long, default_value_t = 0.01)]
        sample: f64,
        /// Threads for the error runs (default: one per core); the timed runs go one at a time.
        #[arg(long, default_value_t = 0)]
        jobs: usize,
        /// Output directory.
        #[arg(long)]
        out: PathBuf,
    },
}

#[derive(Subcommand)]
enum GenerateKind {
    /// Regular n-strut prism on pinned supports.
    Prism {
        /// Number of struts.
        #[arg(long, default_value_t = 3)]
        n: usize,
        /// Cluster the top ring into one actuated cable.
        #[arg(long)]
        cluster: bool,
        /// Side-string prestress, N.
        #[arg(long, allow_negative_numbers = true, default_value_t = 100.0)]
        prestress: f64,
    },
    /// Tower of stacked prisms with clustered side cables.
    Tower {
        /// Struts per stage.
        #[arg(long, default_value_t = 3)]
        n: usize,
        /// Number of stages.
        #[arg(long, default_value_t = 3)]
        stages: usize,
    },
    /// Planar clustered T-bar.
    Tbar,
    /// Elastic Atwood machine.
    Atwood {
        /// First mass, kg.
        #[arg(long, allow_negative_numbers = true, default_value_t = 2.0)]
        m1: f64,
        /// Second mass, kg.
        #[arg(long, allow_negative_numbers = true, default_value_t = 1.0)]
        m2: f64,
    },
}

#[derive(Serialize)]
struct ModeJson {
    index: usize,
    frequency_hz: f64,
    omega_squared: f64,
    zero_frequency: bool,
    kinetic_share: Vec<(String, f64)>,
    cable_stretch_m: Vec<(String, f64)>,
    largest_segment_change_m: Vec<(String, f64)>,
}

/// The `modes` output: a table (or JSON) of the zero-frequency modes and the lowest `count`
/// others, each with its largest kinetic-energy shares and the cables it stretches.
fn format_modes(
    model: &Model,
    r: &EquilibriumReport,
    modes: &[tensegrity::solve::modes::Mode],
    count: usize,
    json: bool,
) -> Result<String, String> {
    use std::fmt::Write as _;
    let zero: Vec<usize> = (0..modes.len()).filter(|&i| modes[i].zero).collect();
    let listed: Vec<usize> =
        zero.iter().copied().chain((0..modes.len()).filter(|&i| !modes[i].zero).take(count)).collect();
    let named =
        |v: &[f64], names: &mut dyn Iterator<Item = String>| names.zip(v.iter().copied()).collect::<Vec<_>>();
    if json {
        let out: Vec<ModeJson> = listed
            .iter()
            .map(|&i| {
                let m = &modes[i];
                ModeJson {
                    index: i + 1,
                    frequency_hz: m.frequency_hz,
                    omega_squared: m.omega_squared,
                    zero_frequency: m.zero,
                    kinetic_share: named(&m.kinetic_share, &mut model.bodies.iter().map(|b| b.name.clone())),
                    cable_stretch_m: named(&m.cable_stretch, &mut model.cable_names.iter().cloned()),
                    largest_segment_change_m: named(
                        &m.segment_change,
                        &mut model.cable_names.iter().cloned(),
                    ),
                }
            })
            .collect();
        return serde_json::to_string_pretty(&out).map(|s| s + "\n").map_err(|e| e.to_string());
    }
    let mut out = String::new();
    let _ = writeln!(
        out,
        "{}: {} at the equilibrium ({}); {} zero-frequency",
        model.name,
        counted(modes.len(), "mode"),
        r.stability_words(),
        zero.len()
    );
    let _ = writeln!(
        out,
        "\n{:>4} {:>14} {:>12}  {:<40} cables stretched, m per unit amplitude",
        "mode", "frequency Hz", "period s", "kinetic energy"
    );
    for &i in &listed {
        let m = &modes[i];
        let mut shares: Vec<(usize, f64)> = m.kinetic_share.iter().copied().enumerate().collect();
        shares.sort_by(|a, b| b.1.total_cmp(&a.1));
        let ke: Vec<String> = shares
            .iter()
            .take(3)
            .filter(|(_, f)| *f >= 0.005)
            .map(|(b, f)| format!("{} {:.0}%", model.bodies[*b].name, 100.0 * f))
            .collect();
        let top = m.segment_change.iter().copied().fold(0.0, f64::max).max(1e-300);
        let mut cables: Vec<(usize, f64)> =
            (0..m.cable_stretch.len()).map(|c| (c, m.segment_change[c])).collect();
        cables.sort_by(|a, b| b.1.total_cmp(&a.1));
        let stretched: Vec<String> = cables
            .iter()
            .take(3)
            .filter(|(_, s)| *s >= 1e-3 * top)
            .map(|&(c, seg)| {
                let total = m.cable_stretch[c];
                let total = format!("{:+.3}", Num(total));
                if seg > 2.0 * m.cable_stretch[c].abs() + 1e-9 * top {
                    format!("{} {total} (slides: segments {seg:.3})", model.cable_names[c])
                } else {
                    format!("{} {total}", model.cable_names[c])
                }
            })
            .collect();
        let (freq, period) = if m.zero {
            ("0 (zero)".to_string(), "-".to_string())
        } else if m.omega_squared < 0.0 {
            ("unstable".to_string(), "-".to_string())
        } else {
            (format!("{:.4}", m.frequency_hz), format!("{:.4}", 1.0 / m.frequency_hz))
        };
        let _ = writeln!(
            out,
            "{:>4} {:>14} {:>12}  {:<40} {}",
            i + 1,
            freq,
            period,
            ke.join(", "),
            stretched.join(", ")
        );
    }
    Ok(out)
}

/// "1 ramp", "2 ramps", "0 ramps".
fn counted(n: usize, what: &str) -> String {
    format!("{n} {what}{}", if n == 1 { "" } else { "s" })
}

/// Writes to standard output; a closed pipe (`| head`) is not an error.
/// Writes to standard output; a reader that went away (`| head`) ends the program quietly, as
/// it would a C tool, instead of a panic from `println!`.
fn emit(text: &str) {
    let mut out = std::io::stdout().lock();
    if let Err(e) = out.write_all(text.as_bytes()).and_then(|()| out.flush()) {
        if e.kind() == std::io::ErrorKind::BrokenPipe {
            std::process::exit(0);
        }
        eprintln!("error: cannot write to standard output: {e}");
        std::process::exit(1);
    }
}

/// `println!` through `emit`.
macro_rules! say {
    ($($arg:tt)*) => { emit(&(format!($($arg)*) + "\n")) };
}

fn progress(len: u64, unit: &str) -> ProgressBar {
    if std::io::stderr().is_terminal() {
        let b = ProgressBar::new(len);
        b.set_style(
            ProgressStyle::with_template(&format!("{{bar:40}} {{pos}}/{{len}} {unit} {{msg}}"))
                .expect("valid template"),
        );
        b
    } else {
        ProgressBar::hidden()
    }
}

fn deploy_dynamic(
    model: &Model,
    scene: &Path,
    settings: SimSettings,
    duration: Option<f64>,
    out: &Path,
    record: Option<&Path>,
) -> Result<(), String> {
    let duration = duration.unwrap_or(model.schedule.end_time() + 1.0);
    if !(duration.is_finite() && duration > 0.0) {
        return Err(format!("--duration must be positive, got {duration}"));
    }
    // the node's core, following the schedule with no clock: the bag holds what the node would
    // publish with state every step, and `replay` runs it again the same way
    let sim = tensegrity::sim::Simulator::new(model.clone(), settings)
        .map_err(|e| format!("{}: {e}", scene.display()))?;
    let params = NodeParams {
        follow_schedule: true,
        real_time_factor: 0.0,
        state_publish_rate: 0.0,
        ..NodeParams::default()
    };
    let mut recorder = match record {
        Some(dir) => {
            let run = record::run_info(
                record::KIND_DYNAMIC,
                model,
                &scene.display().to_string(),
                &settings,
                &params,
            );
            Some(
                record::BagRecorder::create(
                    dir,
                    model,
                    &params,
                    &run,
                    record::LogTime::SimTime,
                    &BagOptions::default(),
                )
                .map_err(|e| e.to_string())?,
            )
        }
        None => None,
    };
    let mut core = NodeCore::with_simulator(sim, params);
    let mut sink = OptionalSink(recorder.as_mut());
    core.start(&mut sink);
    let mut file = csv_output(out)?;
    writeln!(file, "{}", study::dynamic_csv_header(model)).map_err(|e| e.to_string())?;
    // the row of t = 0: the start, before any step
    writeln!(file, "{}", study::dynamic_csv_row(core.simulator(), &Default::default()))
        .map_err(|e| e.to_string())?;
    let steps = (duration / settings.dt).round().max(1.0) as u64;
    let bar = progress(steps, "steps");
    let mut totals = study::RunTotals::default();
    for _ in 0..steps {
        let now = std::time::Duration::from_secs_f64(core.simulator().state().time);
        core.tick(now, &mut sink);
        if let Some(fault) = core.fault() {
            return Err(format!("{}: {fault}", scene.display()));
        }
        let stats = core.last_step();
        totals.add(&stats);
        bar.inc(1);
        writeln!(file, "{}", study::dynamic_csv_row(core.simulator(), &stats))
            .map_err(|e| write_error(out, e))?;
    }
    bar.finish_and_clear();
    file.flush().map_err(|e| write_error(out, e))?;
    let bag = match recorder {
        Some(r) => {
            let dir = r.dir().to_path_buf();
            let summary = r.finish().map_err(|e| e.to_string())?;
            format!(
                "; bag {} ({} messages, {} bytes)",
                dir.display(),
                summary.counts.iter().sum::<u64>(),
                summary.file_bytes
            )
        }
        None => String::new(),
    };
    say(
        out,
        format!(
            "{}: {} steps of {} s with {}{} ({} Newton iterations, {} rejected attempts, {:.3} s wall){bag}",
            model.name,
            totals.steps,
            settings.dt,
            settings.integrator.name(),
            if out.as_os_str().is_empty() { String::new() } else { format!(" written to {}", out.display()) },
            totals.newton_iterations,
            totals.rejected,
            totals.wall_time.as_secs_f64()
        ),
    );
    Ok(())
}

/// `tensegrity replay`: exit status 1 (an error) when the re-run differs.
fn replay(bag: &Path, scene: Option<&Path>, out: Option<&Path>) -> Result<(), String> {
    let scene_text = match scene {
        Some(p) => Some((
            std::fs::read_to_string(p).map_err(|e| format!("{}: {e}", p.display()))?,
            p.display().to_string(),
        )),
        None => None,
    };
    let report = record::replay(bag, scene_text.as_ref().map(|(t, l)| (t.as_str(), l.as_str())), out)
        .map_err(|e| e.to_string())?;
    let what = format!(
        "{} messages compared over {} steps ({} command batches, {} resets applied from the bag; /diagnostics not compared)",
        report.compared, report.steps, report.command_batches, report.resets
    );
    if let Some(cut) = &report.cut_short {
        say!("note: the bag stops early ({cut}); compared up to there");
    }
    if report.missing > 0 {
        say!(
            "note: {} messages of the re-run are missing from the bag (its writer dropped them on a full queue); skipped",
            report.missing
        );
    }
    if let Some(out) = out {
        say!("re-run written to {}", out.display());
    }
    match report.difference {
        None => {
            say!("identical: {what}");
            Ok(())
        }
        Some(d) => Err(format!("{d}; {what} before it")),
    }
}

/// The table of `tensegrity bag info`.
fn format_bag_info(info: &bag::BagInfo) -> String {
    use std::fmt::Write as _;
    let mut s = String::new();
    let (start, end) = info.time_range.unwrap_or((0, 0));
    let total: u64 = info.topics.iter().map(|(_, n)| n).sum();
    let _ = writeln!(s, "Files:             {}", info.path.display());
    let _ = writeln!(s, "Bag size:          {} bytes", info.file_bytes);
    let _ = writeln!(s, "Storage id:        mcap");
    let _ = writeln!(s, "Duration:          {:.9} s", (end - start) as f64 * 1e-9);
    let _ = writeln!(s, "Start:             {:.9} s", start as f64 * 1e-9);
    let _ = writeln!(s, "End:               {:.9} s", end as f64 * 1e-9);
    let _ = writeln!(s, "Messages:          {total}");
    if let Some(cut) = &info.cut_short {
        let _ = writeln!(s, "Cut short:         {cut} (`tensegrity bag reindex` repairs it)");
    }
    if let Some(run) = &info.run {
        let get = |k: &str| run.get(k).map_or("?", String::as_str);
        let _ = writeln!(
            s,
            "Run:               {} of '{}' ({}), dt {} s, {}",
            get(record::KEY_KIND),
            get("scene_name"),
            get("scene_file"),
            get("dt"),
            get("integrator")
        );
    }
    let width = info.topics.iter().map(|(t, _)| t.name.len()).max().unwrap_or(0);
    let _ = writeln!(s, "Topic information:");
    for (t, n) in &info.topics {
        let _ = writeln!(
            s,
            "  Topic: {:<width$} | Type: {} | Count: {n} | Serialization Format: cdr",
            t.name, t.type_name
        );
    }
    s
}

/// A sink that passes everything to a recorder when there is one.
struct OptionalSink<'a>(Option<&'a mut record::BagRecorder>);

impl NodeSink for OptionalSink<'_> {
    fn publish(&mut self, topic: Topic, view: &NodeView<'_>) -> Result<(), PublishError> {
        self.0.as_mut().map_or(Ok(()), |r| r.publish(topic, view))
    }
    fn step_request_done(
        &mut self,
        _ticket: u64,
        _result: tensegrity::io::msg::SimResult,
        _view: &NodeView<'_>,
    ) {
    }
    fn commands_applied(
        &mut self,
        time: f64,
        step: u64,
        commands: &[(tensegrity::model::ActuatorId, tensegrity::control::ActuatorCommand)],
    ) {
        if let Some(r) = self.0.as_mut() {
            r.commands_applied(time, step, commands);
        }
    }
}

/// Where a CSV goes: the file `out`, standard output for `-`, nowhere for an empty path (no
/// `--out`).
fn csv_output(out: &Path) -> Result<Box<dyn Write>, String> {
    if out.as_os_str().is_empty() {
        Ok(Box::new(std::io::sink()))
    } else if out == Path::new("-") {
        Ok(Box::new(std::io::BufWriter::new(std::io::stdout())))
    } else {
        let file = std::fs::File::create(out).map_err(|e| format!("{}: {e}", out.display()))?;
        Ok(Box::new(std::io::BufWriter::new(file)))
    }
}

/// A closing summary: on standard output, or on standard error when the CSV went there (`-`).
fn say(out: &Path, text: String) {
    if out == Path::new("-") {
        eprintln!("{text}");
    } else {
        say!("{text}");
    }
}

fn load(path: &Path) -> Result<Model, String> {
    scene::load(path).map_err(|e| e.to_string())
}

/// Like `load`, but refuses scenes with bodies that nothing holds (they have no equilibrium).
fn load_for_statics(path: &Path) -> Result<Model, String> {
    let model = load(path)?;
    match report::unheld_bodies_note(&model) {
        Some(note) => Err(format!("{}: {note}", path.display())),
        None => Ok(model),
    }
}

/// What `run` returns when its standard output was closed by the reader (`| head`): not an error.
const CLOSED_PIPE: &str = "standard output closed";

/// A write error on `out`, or `CLOSED_PIPE` when the reader of standard output went away.
fn write_error(out: &Path, e: std::io::Error) -> String {
    if out == Path::new("-") && e.kind() == std::io::ErrorKind::BrokenPipe {
        CLOSED_PIPE.into()
    } else {
        format!("{}: {e}", out.display())
    }
}

fn main() -> ExitCode {
    match run(Cli::parse()) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) if e == CLOSED_PIPE => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::FAILURE
        }
    }
}

#[derive(Serialize)]
struct StaticsJson {
    scene: String,
    iterations: usize,
    residual_n: f64,
    force_scale_n: f64,
    stable: bool,
    negative_stiffness_modes: usize,
    zero_stiffness_modes: usize,
    min_stiffness_eigenvalue: f64,
    potential_energy_j: f64,
    largest_move_from_scene_m: f64,
    bodies: Vec<report::BodyReport>,
    points: Vec<(String, [f64; 3])>,
    cables: Vec<report::CableReport>,
}

fn run(cli: Cli) -> Result<(), String> {
    match cli.command {
        Command::Fields => {
            emit(&scene::reference::markdown());
            Ok(())
        }
        Command::Check { scene } => {
            let model = load(&scene)?;
            let s = report::summary(&model);
            say!("{}: valid scene '{}'", scene.display(), s.name);
            say!(
                "bodies: {} ({} node, {} bar, {} rigid, {} fixed)",
                s.bodies.iter().sum::<usize>(),
                s.bodies[0],
                s.bodies[1],
                s.bodies[2],
                s.bodies[3]
            );
            say!("coordinates: {}", s.coordinates);
            say!("constraints: {}", s.constraints);
            say!("cables: {} ({} sliding)", s.cables, s.sliding_cables);
            say!("pulleys: {}", s.pulleys);
            say!("actuators: {} (schedule: {})", s.actuators, counted(s.ramps, "ramp"));
            if s.planar {
                say!("planar: yes (xy plane)");
            }
            if let Some(note) = report::unheld_bodies_note(&model) {
                say!("warning: {note} (dynamics lets them drift or fall)");
            }
            Ok(())
        }
        Command::Modes { scene, json, count, plot } => {
            let model = load_for_statics(&scene)?;
            let mut state = State::initial(&model);
            let mut ws = Workspace::new(&model);
            let r = StaticSolver::new(&model)
                .equilibrate(&model, &mut state, &mut ws, &model.solver)
                .map_err(|(it, res)| {
                    format!(
                        "{}: no equilibrium found: residual {res:.3e} N after {it} Newton iterations",
                        scene.display()
                    )
                })?;
            let modes = tensegrity::solve::modes::natural_modes(&model, &state).ok_or_else(|| {
                format!("{}: the mass matrix is singular on the joints' null space", scene.display())
            })?;
            emit(&format_modes(&model, &r, &modes, count, json)?);
            if let Some(base) = plot {
                let panels = tensegrity::solve::modes::mode_panels(&model, &state, &modes, count.min(6));
                if panels.is_empty() {
                    return Err(format!("{}: no vibrating mode to draw", scene.display()));
                }
                let title = format!("{}: mode shapes (grey: equilibrium)", model.name);
                tensegrity::plot::write_structure_panels(&title, &panels, &base)?;
                say!(
                    "mode shapes drawn to {} and {}",
                    base.with_extension("png").display(),
                    base.with_extension("svg").display()
                );
            }
            Ok(())
        }
        Command::Statics { scene, json } => {
            let model = load_for_statics(&scene)?;
            let mut state = State::initial(&model);
            let mut ws = Workspace::new(&model);
            evaluate(&model, &state, &mut ws, Tangents::None);
            let reference = report::all_pulley_coordinates(&model, &state, &ws);
            let r = StaticSolver::new(&model)
                .equilibrate(&model, &mut state, &mut ws, &model.solver)
                .map_err(|(it, res)| {
                    format!(
                        "{}: no equilibrium found: residual {res:.3e} N after {}",
                        scene.display(),
                        counted(it, "Newton iteration")
                    )
                })?;
            evaluate(&model, &state, &mut ws, Tangents::None);
            let cables = report::cable_reports(&model, &state, &ws, &reference);
            // how far the equilibrium lies from the pose the scene sketched, and where
            let sketched = State::initial(&model);
            let largest_move = model
                .points
                .iter()
                .map(|p| {
                    let at = |s: &State| s.poses[p.body.0].transform_point(&p.local);
                    ((at(&state) - at(&sketched)).norm(), p.name.as_str())
                })
                .fold((0.0, ""), |a, b| if b.0 > a.0 { b } else { a });
            if json {
                let out = StaticsJson {
                    scene: model.name.clone(),
                    iterations: r.iterations,
                    residual_n: r.residual,
                    force_scale_n: r.force_scale,
                    stable: r.stable,
                    negative_stiffness_modes: r.negative_modes,
                    zero_stiffness_modes: r.zero_modes,
                    min_stiffness_eigenvalue: r.min_stiffness_eigenvalue,
                    potential_energy_j: r.potential_energy,
                    largest_move_from_scene_m: largest_move.0,
                    bodies: report::body_reports(&model, &state),
                    points: report::point_positions(&model, &ws),
                    cables,
                };
                emit(&(serde_json::to_string_pretty(&out).map_err(|e| e.to_string())? + "\n"));
            } else {
                emit(&format_statics(&model, &state, &ws, &r, &cables, largest_move));
            }
            Ok(())
        }
        Command::Deploy {
            scene,
            quasi_static: _,
            dynamic,
            steps,
            dynamics,
            duration,
            out,
            record: bag_dir,
        } => {
            let mut model = load(&scene)?;
            let out = out.unwrap_or_default();
            if dynamic {
                return deploy_dynamic(
                    &model,
                    &scene,
                    dynamics.settings(&model)?,
                    duration,
                    &out,
                    bag_dir.as_deref(),
                );
            }
            if let Some(note) = report::unheld_bodies_note(&model) {
                return Err(format!("{}: {note}", scene.display()));
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
            let bar = progress(model.schedule.steps as u64 + 1, "steps");
            let mut state = State::initial(&model);
            let mut ws = Workspace::new(&model);
            let mut io_error = None;
            let params = NodeParams::default();
            let mut recorder = match &bag_dir {
                Some(dir) => {
                    let label = scene.display().to_string();
                    let mut run = record::run_info(
                        record::KIND_QUASI_STATIC,
                        &model,
                        &label,
                        &SimSettings::default(),
                        &params,
                    );
                    run.insert("steps".into(), model.schedule.steps.to_string());
                    let log = record::LogTime::Step;
                    Some(
                        record::BagRecorder::create(dir, &model, &params, &run, log, &BagOptions::default())
                            .map_err(|e| e.to_string())?,
                    )
                }
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
                bar.inc(1);
            })
            .map_err(|e| format!("{}: {e}", scene.display()))?;
            bar.finish_and_clear();
            if let Some(e) = io_error {
                return Err(write_error(&out, e));
            }
            file.flush().map_err(|e| e.to_string())?;
            if let Some(r) = recorder {
                let dir = r.dir().to_path_buf();
                let summary = r.finish().map_err(|e| e.to_string())?;
                say(
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
            let worst =
                path.steps.iter().map(|p| p.report.residual / p.report.force_scale).fold(0.0, f64::max);
            let traced = path.steps.len() - outputs.len();
            say(
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
                say(
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
        Command::Replay { bag, scene, out } => replay(&bag, scene.as_deref(), out.as_deref()),
        Command::Bag { kind: BagCommand::Info { bag } } => {
            let reader = bag::BagReader::open(&bag).map_err(|e| e.to_string())?;
            emit(&format_bag_info(&reader.info()));
            Ok(())
        }
        Command::Bag { kind: BagCommand::Reindex { bag } } => {
            let Some((summary, why)) =
                bag::reindex(&bag, &BagOptions::default()).map_err(|e| e.to_string())?
            else {
                say!("{}: already complete (summary and end magic): left as it is", bag.display());
                return Ok(());
            };
            say!(
                "{}: rewritten with {} messages{}",
                bag.display(),
                summary.counts.iter().sum::<u64>(),
                why.map_or(String::new(), |w| format!(" (the original stopped: {w})"))
            );
            Ok(())
        }
        Command::Study { scene, ramp_times, point, settle, dynamics, jobs, out } => {
            let model = load(&scene)?;
            let ramp_times = match ramp_times {
                Some(t) => t,
                None => study::default_ramp_times(&model)?,
            };
            let result = study::deployment_study(
                &model,
                &ramp_times,
                point.as_deref(),
                dynamics.settings(&model)?,
                settle,
                jobs,
                &out,
            )?;
            emit(&result.markdown());
            say!("written to {}", out.display());
            Ok(())
        }
        Command::Bench { kind: BenchKind::Steps { target, integrator, dt, steps } } => {
            let model = match target.strip_prefix("tower:") {
                Some(rest) => {
                    let (family, stages) = rest.split_once(':').ok_or("expected tower:FAMILY:STAGES")?;
                    let family = match family {
                        "classical" => study::TowerFamily::Classical,
                        "per-stage" => study::TowerFamily::PerStage,
                        "helical" => study::TowerFamily::Helical,
                        f => {
                            return Err(format!("unknown tower family {f:?} (classical, per-stage, helical)"))
                        }
                    };
                    let stages: usize = stages
                        .parse()
                        .ok()
                        .filter(|s| (1..=256).contains(s))
                        .ok_or("stages must be in [1, 256]")?;
                    family.model(stages)?
                }
                None => load(Path::new(&target))?,
            };
            if !(dt.is_finite() && dt > 0.0) || steps == 0 {
                return Err("--dt must be positive and --steps >= 1".into());
            }
            let integrator = integrator.integrator(0.8);
            let t = study::step_times(&model, SimSettings { dt, integrator, ..Default::default() }, steps)?;
            say!(
                "{}: {} dt {dt} s, {} unknowns ({}): median {:.2} us/step, mean {:.2}, max {:.1}; Newton {:.2}/step, factorizations {:.3}/step",
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
        Command::Bench { kind: BenchKind::Machine { period, seconds } } => {
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
        Command::Bench { kind: BenchKind::Scaling { stages, steps, out } } => {
            if stages.contains(&0) || steps == 0 {
                return Err("stages and steps must be >= 1".into());
            }
            study::scaling(&stages, steps, &out)?;
            emit(&std::fs::read_to_string(out.join("scaling.md")).map_err(|e| e.to_string())?);
            say!("written to {}", out.display());
            Ok(())
        }
        Command::Bench {
            kind: BenchKind::WorkPrecision { scene, reference_dt, repeats, duration, sample, jobs, out },
        } => {
            let model = load(&scene)?;
            let duration = duration.unwrap_or(model.schedule.end_time() + 0.5);
            let steps = [1e-2, 5e-3, 2e-3, 1e-3, 5e-4, 2.5e-4];
            let ga = Integrator::GeneralizedAlpha { rho_inf: 0.8 };
            let fixed = |i: Integrator, dts: &[f64]| {
                dts.iter().map(move |&dt| study::RunConfig::fixed(i, dt)).collect::<Vec<_>>()
            };
            let mut configs = fixed(ga, &steps);
            configs.extend(fixed(Integrator::GeneralizedAlpha { rho_inf: 0.0 }, &steps));
            configs.extend(fixed(
                Integrator::SymplecticEuler,
                &[5e-3, 2e-3, 1e-3, 5e-4, 2.5e-4, 1e-4, 5e-5, 2.5e-5],
            ));
            configs.extend(fixed(Integrator::Rk4, &[1e-2, 5e-3, 4e-3, 2e-3, 1e-3, 5e-4, 2.5e-4]));
            configs.extend(fixed(Integrator::DormandPrince, &[5e-3, 2e-3, 1e-3, 5e-4, 2.5e-4]));
            configs.extend(
                [1e-3, 1e-4, 1e-5, 1e-6, 1e-7, 1e-8, 1e-9]
                    .map(|t| study::RunConfig::controlled(Integrator::DormandPrince, t)),
            );
            configs.extend([1e-3, 1e-4, 1e-5, 1e-6].map(|t| study::RunConfig::controlled(ga, t)));
            let settings = study::WorkPrecisionSettings { reference_dt, duration, sample, repeats, jobs };
            let rows = study::work_precision(&model, &configs, settings, &out)?;
            emit(&std::fs::read_to_string(out.join("work_precision.md")).map_err(|e| e.to_string())?);
            say!("{} runs written to {}", rows.len(), out.display());
            Ok(())
        }
        Command::Generate { kind, out } => {
            let spec = match kind {
                GenerateKind::Prism { n, cluster, prestress } => {
                    if n < 3 {
                        return Err("a prism needs n >= 3".into());
                    }
                    generate::prism(&generate::PrismParams {
                        n,
                        cluster_top_ring: cluster,
                        side_prestress: prestress,
                        deploy_shortening: if cluster { 0.1 } else { 0.0 },
                        ..Default::default()
                    })
                }
                GenerateKind::Tower { n, stages } => {
                    if n < 3 || stages < 1 {
                        return Err("a tower needs n >= 3 and stages >= 1".into());
                    }
                    generate::tower(&generate::TowerParams { n, stages, ..Default::default() })
                }
                GenerateKind::Tbar => generate::tbar(&Default::default()),
                GenerateKind::Atwood { m1, m2 } => {
                    generate::atwood(&generate::AtwoodParams { m1, m2, ..Default::default() })
                }
            };
            // a generator's arguments are scene fields: refuse what `check` would refuse
            let label = format!("<generated {}>", spec.name);
            scene::build_model(&spec, &label, None).map_err(|e| format!("cannot generate: {e}"))?;
            let text = format!("# generated by `tensegrity generate`\n{}", scene::to_toml(&spec));
            match out {
                Some(p) => std::fs::write(&p, text).map_err(|e| format!("{}: {e}", p.display()))?,
                None => emit(&text),
            }
            Ok(())
        }
    }
}

fn format_statics(
    model: &Model,
    state: &State,
    ws: &Workspace,
    r: &EquilibriumReport,
    cables: &[report::CableReport],
    (moved, moved_point): (f64, &str),
) -> String {
    use std::fmt::Write as _;
    let mut out = String::new();
    let _ = writeln!(
        out,
        "{}: equilibrium after {}, residual {:.3e} N ({:.1e} of {:.4} N), {} (min reduced stiffness eigenvalue {:.4e})",
        model.name,
        counted(r.iterations, "Newton iteration"),
        r.residual,
        r.residual / r.force_scale,
        r.force_scale,
        r.stability_words(),
        r.min_stiffness_eigenvalue
    );
    let _ = writeln!(
        out,
        "potential energy {:.6} J (elastic + gravitational); largest move from the scene's pose {:.6} m{}",
        Num(r.potential_energy),
        Num(moved),
        if moved > 0.0 { format!(" ({moved_point})") } else { String::new() }
    );
    let _ = writeln!(
        out,
        "\n{:<14} {:>12} {:>12} {:>12} {:>12} {:>12}  slack",
        "cable", "tension N", "length m", "rest m", "strain", "pulleys"
    );
    for c in cables {
        let _ = writeln!(
            out,
            "{:<14} {:>12.6} {:>12.6} {:>12.6} {:>12.4e} {:>12}  {}",
            c.name,
            Num(c.tension),
            c.length,
            c.rest_length,
            c.strain,
            c.segment_lengths.len() - 1,
            if c.slack { "yes" } else { "no" }
        );
    }
    // sliding cables: where the cable runs and how far it has passed through each pulley
    let sliding: Vec<&report::CableReport> = cables.iter().filter(|c| c.segment_lengths.len() > 1).collect();
    if !sliding.is_empty() {
        let _ =
            writeln!(out, "\n{:<14} {:>8}  {:>12} {:>12}", "sliding cable", "segment", "length m", "slip m");
        const SHOWN: usize = 12;
        for c in sliding {
            let m = c.segment_lengths.len();
            for (k, l) in c.segment_lengths.iter().enumerate().take(SHOWN) {
                // slip is at the pulley that ends segment k (the last segment ends at the anchor)
                let slip = c.pulley_slip.get(k).map_or("-".to_string(), |s| format!("{:.6}", Num(*s)));
                let name = if k == 0 { c.name.as_str() } else { "" };
                let _ = writeln!(out, "{:<14} {:>8} {:>12.6} {:>12}", name, k + 1, l, slip);
            }
            if m > SHOWN {
                let _ = writeln!(
                    out,
                    "{:<14} {:>8}  ({} more segments: --json lists them all)",
                    "",
                    "...",
                    m - SHOWN
                );
            }
        }
    }
    let _ =
        writeln!(out, "\n{:<14} {:>12} {:>12} {:>12}   quaternion (w x y z)", "body", "x m", "y m", "z m");
    for b in report::body_reports(model, state) {
        let (p, q) = (b.position, b.orientation);
        let _ = writeln!(
            out,
            "{:<14} {:>12.6} {:>12.6} {:>12.6}   {:.6} {:.6} {:.6} {:.6}",
            b.name,
            Num(p[0]),
            Num(p[1]),
            Num(p[2]),
            Num(q[0]),
            Num(q[1]),
            Num(q[2]),
            Num(q[3])
        );
    }
    let _ = writeln!(out, "\n{:<20} {:>12} {:>12} {:>12}", "point", "x m", "y m", "z m");
    for (name, p) in report::point_positions(model, ws) {
        let _ = writeln!(out, "{:<20} {:>12.6} {:>12.6} {:>12.6}", name, Num(p[0]), Num(p[1]), Num(p[2]));
    }
    out
}
