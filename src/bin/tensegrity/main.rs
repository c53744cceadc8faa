//! `tensegrity`: command-line front end of the library: argument parsing and dispatch only; each
//! subcommand lives in its own module (`check`, `statics`, `modes`, `deploy`, `study`, `bench`,
//! `bag`, `generate`, `fields`, `view`), what they share in `output`.

mod bag;
mod bench;
mod check;
mod deploy;
mod fields;
mod generate;
mod modes;
mod output;
mod statics;
mod study;
mod view;

use output::Progress;

use std::path::PathBuf;
use std::process::ExitCode;

use clap::{Parser, Subcommand};

use crate::bag::BagCommand;
use crate::bench::BenchKind;
use crate::generate::GenerateKind;
use crate::output::{DynamicArgs, CLOSED_PIPE};

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
    Deploy(deploy::DeployArgs),
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
        /// Instead of the actuation times: the quasi-static deployment with each of these pulley
        /// friction coefficients at every pulley (how far the point moves, how much rope runs
        /// over the pulleys, the tension along the driven clustered cable at the end).
        #[arg(long, value_delimiter = ',', conflicts_with = "ramp_times")]
        friction: Option<Vec<f64>>,
        /// Time simulated after the schedule ends, s.
        #[arg(long, allow_hyphen_values = true, default_value_t = 1.0)]
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
    /// Watch a scene (its equilibrium, or its modes), a recorded bag or a running node in the
    /// browser: serves a page on 127.0.0.1 and prints its address.
    View(view::ViewArgs),
    /// Write a generated scene as TOML.
    Generate {
        #[command(subcommand)]
        kind: GenerateKind,
        /// Output file (default: standard output).
        #[arg(long, global = true)]
        out: Option<PathBuf>,
    },
}

fn main() -> ExitCode {
    match run(Cli::parse()) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) if e == CLOSED_PIPE => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::from(output::exit_status())
        }
    }
}

/// Runs one subcommand.
fn run(cli: Cli) -> Result<(), String> {
    match cli.command {
        Command::Fields => fields::run(),
        Command::Check { scene } => check::run(&scene),
        Command::Statics { scene, json } => {
            let progress =
                Progress::new(format!("statics {}", scene.display()), &["Newton iterations"], None);
            statics::run(&scene, json, progress.observe())
        }
        Command::Modes { scene, json, count, plot } => {
            let what = format!("modes {}", scene.display());
            modes::run(&scene, json, count, plot, Progress::new(what, &["Newton iterations"], None).observe())
        }
        Command::Deploy(args) => deploy::run(args),
        Command::Replay { bag, scene, out } => bag::replay(&bag, scene.as_deref(), out.as_deref()),
        Command::Bag { kind } => bag::run(kind),
        Command::Study { scene, ramp_times, point, friction, settle, dynamics, jobs, out } => {
            let what = format!("study {}", scene.display());
            let progress = Progress::new(what, &["runs", "load steps"], None).observe();
            let result = study::run(study::StudyArgs {
                scene,
                ramp_times,
                point,
                friction,
                settle,
                dynamics,
                jobs,
                out,
            });
            progress.finish();
            result
        }
        Command::Bench { kind } => {
            let progress = Progress::new("bench", &["steps", "runs"], None).observe();
            let result = bench::run(kind);
            progress.finish();
            result
        }
        Command::Generate { kind, out } => generate::run(kind, out),
        Command::View(args) => view::run(args),
    }
}
