//! `tensegrity`: command-line front end of the library (argument parsing and wiring only).

use std::io::{IsTerminal, Write};
use std::path::{Path, PathBuf};
use std::process::ExitCode;

use clap::{Parser, Subcommand};
use indicatif::{ProgressBar, ProgressStyle};
use serde::Serialize;
use tensegrity::forces::{evaluate, Tangents, Workspace};
use tensegrity::report;
use tensegrity::scene::{self, generate};
use tensegrity::solve::statics::{deploy_quasi_static, EquilibriumReport, StaticSolver};
use tensegrity::{Model, State};

#[derive(Parser)]
#[command(name = "tensegrity", version, about = "Clustered tensegrity multibody simulator")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
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
    /// Follow the scene's deployment schedule and write one CSV row per step.
    Deploy {
        /// Scene file (TOML).
        scene: PathBuf,
        /// Quasi-static deployment: a path of equilibria (load stepping).
        #[arg(long, required = true)]
        quasi_static: bool,
        /// Number of load steps (default: the scene's `deployment.steps`).
        #[arg(long)]
        steps: Option<usize>,
        /// Output CSV file.
        #[arg(long)]
        out: PathBuf,
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
        #[arg(long, default_value_t = 100.0)]
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
        #[arg(long, default_value_t = 2.0)]
        m1: f64,
        /// Second mass, kg.
        #[arg(long, default_value_t = 1.0)]
        m2: f64,
    },
}

/// Writes to standard output; a closed pipe (`| head`) is not an error.
fn emit(text: &str) {
    let _ = std::io::stdout().write_all(text.as_bytes());
}

fn load(path: &Path) -> Result<Model, String> {
    scene::load(path).map_err(|e| e.to_string())
}

fn main() -> ExitCode {
    match run(Cli::parse()) {
        Ok(()) => ExitCode::SUCCESS,
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
    min_stiffness_eigenvalue: f64,
    bodies: Vec<report::BodyReport>,
    points: Vec<(String, [f64; 3])>,
    cables: Vec<report::CableReport>,
}

fn run(cli: Cli) -> Result<(), String> {
    match cli.command {
        Command::Check { scene } => {
            let model = load(&scene)?;
            let s = report::summary(&model);
            println!("{}: valid scene '{}'", scene.display(), s.name);
            println!(
                "bodies: {} ({} node, {} bar, {} rigid, {} fixed)",
                s.bodies.iter().sum::<usize>(),
                s.bodies[0],
                s.bodies[1],
                s.bodies[2],
                s.bodies[3]
            );
            println!("coordinates: {}", s.coordinates);
            println!("constraints: {}", s.constraints);
            println!("cables: {} ({} sliding)", s.cables, s.sliding_cables);
            println!("pulleys: {}", s.pulleys);
            println!("actuators: {} (schedule: {} ramps)", s.actuators, s.ramps);
            if s.planar {
                println!("planar: yes (xy plane)");
            }
            Ok(())
        }
        Command::Statics { scene, json } => {
            let model = load(&scene)?;
            let mut state = State::initial(&model);
            let mut ws = Workspace::new(&model);
            evaluate(&model, &state, &mut ws, Tangents::None);
            let reference = report::all_pulley_coordinates(&model, &state, &ws);
            let r = StaticSolver::new(&model)
                .equilibrate(&model, &mut state, &mut ws, &model.solver)
                .map_err(|(it, res)| {
                    format!(
                        "{}: no equilibrium found: residual {res:.3e} N after {it} Newton iterations",
                        scene.display()
                    )
                })?;
            evaluate(&model, &state, &mut ws, Tangents::None);
            let cables = report::cable_reports(&model, &state, &ws, &reference);
            if json {
                let out = StaticsJson {
                    scene: model.name.clone(),
                    iterations: r.iterations,
                    residual_n: r.residual,
                    force_scale_n: r.force_scale,
                    stable: r.stable,
                    min_stiffness_eigenvalue: r.min_stiffness_eigenvalue,
                    bodies: report::body_reports(&model, &state),
                    points: report::point_positions(&model, &ws),
                    cables,
                };
                emit(&(serde_json::to_string_pretty(&out).map_err(|e| e.to_string())? + "\n"));
            } else {
                emit(&format_statics(&model, &state, &ws, &r, &cables));
            }
            Ok(())
        }
        Command::Deploy { scene, quasi_static: _, steps, out } => {
            let mut model = load(&scene)?;
            if let Some(n) = steps {
                if n == 0 {
                    return Err("--steps must be >= 1".into());
                }
                model.schedule.steps = n;
            }
            let mut file = std::io::BufWriter::new(
                std::fs::File::create(&out).map_err(|e| format!("{}: {e}", out.display()))?,
            );
            writeln!(file, "{}", report::path_csv_header(&model)).map_err(|e| e.to_string())?;
            let bar = if std::io::stderr().is_terminal() {
                let b = ProgressBar::new(model.schedule.steps as u64 + 1);
                b.set_style(
                    ProgressStyle::with_template("{bar:40} {pos}/{len} steps {msg}").expect("valid template"),
                );
                b
            } else {
                ProgressBar::hidden()
            };
            let mut state = State::initial(&model);
            let mut ws = Workspace::new(&model);
            let mut io_error = None;
            let path = deploy_quasi_static(&model, &mut state, &mut ws, |step, st, w| {
                let row = report::path_csv_row(
                    &model,
                    st,
                    w,
                    step.index,
                    step.report.iterations,
                    step.report.residual,
                    step.report.stable,
                );
                if let Err(e) = writeln!(file, "{row}") {
                    io_error.get_or_insert(e);
                }
                bar.inc(1);
            })
            .map_err(|e| format!("{}: {e}", scene.display()))?;
            bar.finish_and_clear();
            if let Some(e) = io_error {
                return Err(format!("{}: {e}", out.display()));
            }
            file.flush().map_err(|e| e.to_string())?;
            let unstable = path.iter().filter(|p| !p.report.stable).count();
            let worst = path.iter().map(|p| p.report.residual / p.report.force_scale).fold(0.0, f64::max);
            println!(
                "{}: {} equilibria written to {} (worst relative residual {worst:.2e}, {} Newton iterations, {unstable} not stable)",
                model.name,
                path.len(),
                out.display(),
                path.iter().map(|p| p.report.iterations).sum::<usize>()
            );
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
) -> String {
    use std::fmt::Write as _;
    let mut out = String::new();
    let _ = writeln!(
        out,
        "{}: equilibrium after {} Newton iterations, residual {:.3e} N ({:.1e} of {:.4} N), {} (min reduced stiffness eigenvalue {:.4e})",
        model.name,
        r.iterations,
        r.residual,
        r.residual / r.force_scale,
        r.force_scale,
        if r.stable { "stable" } else { "NOT stable" },
        r.min_stiffness_eigenvalue
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
            c.tension,
            c.length,
            c.rest_length,
            c.strain,
            c.segment_lengths.len() - 1,
            if c.slack { "yes" } else { "no" }
        );
    }
    let _ =
        writeln!(out, "\n{:<14} {:>12} {:>12} {:>12}   quaternion (w x y z)", "body", "x m", "y m", "z m");
    for b in report::body_reports(model, state) {
        let q = b.orientation;
        let _ = writeln!(
            out,
            "{:<14} {:>12.6} {:>12.6} {:>12.6}   {:.6} {:.6} {:.6} {:.6}",
            b.name, b.position[0], b.position[1], b.position[2], q[0], q[1], q[2], q[3]
        );
    }
    let _ = writeln!(out, "\n{:<20} {:>12} {:>12} {:>12}", "point", "x m", "y m", "z m");
    for (name, p) in report::point_positions(model, ws) {
        let _ = writeln!(out, "{:<20} {:>12.6} {:>12.6} {:>12.6}", name, p[0], p[1], p[2]);
    }
    out
}
