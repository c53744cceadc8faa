//! What every subcommand shares: writing to standard output (a reader that went away ends the
//! program quietly), CSV destinations, progress bars, loading scenes, and the integrator options
//! of the dynamic commands (`DynamicArgs`).

use std::io::Write;
use std::path::Path;

use tensegrity::report;
use tensegrity::scene::{self};
use tensegrity::sim::{DynamicOptions, SimSettings};
use tensegrity::solve::dynamics::{Integrator, NewtonSettings};
use tensegrity::Model;

use clap::ValueEnum;
use indicatif::{ProgressBar, ProgressStyle};
use std::io::IsTerminal;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

/// "1 ramp", "2 ramps", "0 ramps".
pub(crate) fn counted(n: usize, what: &str) -> String {
    format!("{n} {what}{}", if n == 1 { "" } else { "s" })
}

/// Writes to standard output; a closed pipe (`| head`) is not an error.
/// Writes to standard output; a reader that went away (`| head`) ends the program quietly, as
/// it would a C tool, instead of a panic from `println!`.
pub(crate) fn emit(text: &str) {
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
    ($($arg:tt)*) => { $crate::output::emit(&(format!($($arg)*) + "\n")) };
}
pub(crate) use say;

/// How long work runs before it shows progress (the environment's `TENSEGRITY_PROGRESS_AFTER_S`
/// when set, in seconds: 0 shows it at once).
const PROGRESS_AFTER: Duration = Duration::from_secs(1);

fn progress_after() -> Duration {
    std::env::var("TENSEGRITY_PROGRESS_AFTER_S")
        .ok()
        .and_then(|s| s.parse::<f64>().ok())
        .and_then(|s| Duration::try_from_secs_f64(s).ok())
        .unwrap_or(PROGRESS_AFTER)
}
/// Time between two plain progress lines (standard error not a terminal).
const PROGRESS_LINE_EVERY: Duration = Duration::from_secs(5);

/// Progress of one command's long work on standard error, shown once it has run
/// `progress_after()`: a bar on a terminal, a plain line every `PROGRESS_LINE_EVERY` otherwise
/// (a log, a CI job), so that no long run is silent. Fed by the command (`inc`) or by the
/// library's reports (`Progress::observe`), of the units it was made for.
#[derive(Clone)]
pub(crate) struct Progress {
    inner: Arc<ProgressInner>,
}

struct ProgressInner {
    /// What runs: `statics config/scenes/sixbar.toml`.
    what: String,
    /// The units this progress counts (the first is the command's own).
    units: Vec<&'static str>,
    start: Instant,
    /// `progress_after()`.
    after: Duration,
    /// The bar on a terminal (hidden until shown), `None` for plain lines.
    bar: Option<ProgressBar>,
    /// Latest count, total, unit and residual; when the last plain line went out.
    latest: Mutex<ProgressLatest>,
}

#[derive(Default)]
struct ProgressLatest {
    done: u64,
    total: Option<u64>,
    unit: &'static str,
    residual: Option<f64>,
    shown: bool,
    /// When the last plain line went out, and of which unit.
    last_line: Option<(Instant, &'static str)>,
}

impl Progress {
    /// Progress of `what`, counting `units` (`total` of the first when known).
    pub(crate) fn new(what: impl Into<String>, units: &[&'static str], total: Option<u64>) -> Self {
        let bar = std::io::stderr()
            .is_terminal()
            .then(|| ProgressBar::with_draw_target(total, indicatif::ProgressDrawTarget::hidden()));
        let latest = ProgressLatest { total, unit: units[0], ..Default::default() };
        Self {
            inner: Arc::new(ProgressInner {
                what: what.into(),
                units: units.to_vec(),
                start: Instant::now(),
                after: progress_after(),
                bar,
                latest: Mutex::new(latest),
            }),
        }
    }

    /// Makes this progress the observer of the library's reports of its units
    /// (`tensegrity::progress`) until `finish`.
    pub(crate) fn observe(self) -> Self {
        let me = self.clone();
        tensegrity::progress::observe(move |r| {
            if me.inner.units.contains(&r.unit) {
                me.update(r.done, r.total, r.unit, r.residual_n);
            }
        });
        self
    }

    /// One more of the first unit.
    pub(crate) fn inc(&self, n: u64) {
        let (done, total, unit) = {
            let l = self.inner.latest.lock().unwrap_or_else(|e| e.into_inner());
            (l.done + n, l.total, self.inner.units[0])
        };
        self.update(done, total, unit, None);
    }

    /// `done` of `total` `unit`, with the latest residual (N) where there is one.
    pub(crate) fn update(&self, done: u64, total: Option<u64>, unit: &'static str, residual: Option<f64>) {
        let elapsed = self.inner.start.elapsed();
        let mut l = self.inner.latest.lock().unwrap_or_else(|e| e.into_inner());
        (l.done, l.total, l.unit, l.residual) = (done, total, unit, residual.or(l.residual));
        if elapsed < self.inner.after {
            return;
        }
        let residual = l.residual.map(|r| format!(", residual {r:.3e} N")).unwrap_or_default();
        match &self.inner.bar {
            Some(bar) => {
                if !l.shown {
                    let template = match total {
                        Some(_) => "{prefix} {bar:40} {pos}/{len} {msg} ({elapsed})",
                        None => "{prefix} {spinner} {pos} {msg} ({elapsed})",
                    };
                    bar.set_style(ProgressStyle::with_template(template).expect("valid template"));
                    bar.set_prefix(self.inner.what.clone());
                    bar.set_draw_target(indicatif::ProgressDrawTarget::stderr());
                }
                bar.set_length(total.unwrap_or(0));
                bar.set_position(done);
                bar.set_message(format!("{unit}{residual}"));
            }
            None => {
                // a line every PROGRESS_LINE_EVERY, and one when the work turns to another unit
                if l.last_line.is_none_or(|(t, u)| t.elapsed() >= PROGRESS_LINE_EVERY || u != unit) {
                    let of = total.map(|t| format!("/{t}")).unwrap_or_default();
                    eprintln!(
                        "{}: {done}{of} {unit}{residual} ({:.0} s)",
                        self.inner.what,
                        elapsed.as_secs_f64()
                    );
                    l.last_line = Some((Instant::now(), unit));
                }
            }
        }
        l.shown = true;
    }

    /// Ends the progress: the bar goes; after plain lines, one that says the work is done. The
    /// library's reports go nowhere again.
    pub(crate) fn finish(&self) {
        tensegrity::progress::stop_observing();
        if let Some(bar) = &self.inner.bar {
            bar.finish_and_clear();
        }
        let l = self.inner.latest.lock().unwrap_or_else(|e| e.into_inner());
        if l.shown && self.inner.bar.is_none() {
            eprintln!("{}: done in {:.1} s", self.inner.what, self.inner.start.elapsed().as_secs_f64());
        }
    }
}

/// Where a CSV goes: the file `out`, standard output for `-`, nowhere for an empty path (no
/// `--out`).
pub(crate) fn csv_output(out: &Path) -> Result<Box<dyn Write>, String> {
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
pub(crate) fn say_closing(out: &Path, text: String) {
    if out == Path::new("-") {
        eprintln!("{text}");
    } else {
        say!("{text}");
    }
}

pub(crate) fn load(path: &Path) -> Result<Model, String> {
    scene::load(path).map_err(|e| input_error(e.to_string()))
}

/// Like `load`, but refuses scenes with bodies that nothing holds (they have no equilibrium).
pub(crate) fn load_for_statics(path: &Path) -> Result<Model, String> {
    let model = load(path)?;
    match report::unheld_bodies_note(&model) {
        Some(note) => Err(input_error(format!("{}: {note}", path.display()))),
        None => Ok(model),
    }
}

/// Like `load`, but refuses a scene with nothing to move (every body fixed: no free
/// coordinate), for the commands that move it (`deploy --dynamic`, `modes`, `study`).
pub(crate) fn load_moving(path: &Path) -> Result<Model, String> {
    let model = load(path)?;
    refuse_nothing_to_move(&model, path)?;
    Ok(model)
}

/// The input error of a scene with no free coordinate, for the commands that move it.
pub(crate) fn refuse_nothing_to_move(model: &Model, path: &Path) -> Result<(), String> {
    if model.dof_count == 0 {
        return Err(input_error(format!(
            "{}: {}; `tensegrity statics` and `check` still report its tensions",
            path.display(),
            tensegrity::sim::StepError::NothingToMove
        )));
    }
    Ok(())
}

/// Exit status of a run that failed (no equilibrium, a step that failed, a replay that differs).
pub(crate) const STATUS_FAILED: u8 = 1;
/// Exit status of a command whose input cannot be used: a scene (or bag, or option file) that
/// cannot be read, is invalid, or has nothing to do for the command. Clap's usage errors exit 2.
pub(crate) const STATUS_INPUT: u8 = 3;

/// The exit status `main` returns for the error that ended the run (`STATUS_FAILED` unless
/// `input_error` set it).
static EXIT_STATUS: std::sync::atomic::AtomicU8 = std::sync::atomic::AtomicU8::new(STATUS_FAILED);

/// `message` as the error of an input that cannot be used: the run exits with `STATUS_INPUT`.
pub(crate) fn input_error(message: String) -> String {
    EXIT_STATUS.store(STATUS_INPUT, std::sync::atomic::Ordering::Relaxed);
    message
}

/// The exit status of the error that ended the run.
pub(crate) fn exit_status() -> u8 {
    EXIT_STATUS.load(std::sync::atomic::Ordering::Relaxed)
}

/// What `run` returns when its standard output was closed by the reader (`| head`): not an error.
pub(crate) const CLOSED_PIPE: &str = "standard output closed";

/// A write error on `out`, or `CLOSED_PIPE` when the reader of standard output went away.
pub(crate) fn write_error(out: &Path, e: std::io::Error) -> String {
    if out == Path::new("-") && e.kind() == std::io::ErrorKind::BrokenPipe {
        CLOSED_PIPE.into()
    } else {
        format!("{}: {e}", out.display())
    }
}

#[derive(clap::Args, Clone, Copy)]
pub(crate) struct DynamicArgs {
    /// Integrator: generalized-alpha (ga; implicit, any step), symplectic-euler (euler), rk4 or
    /// dormand-prince (dopri5) (explicit: refused above their stability limit).
    #[arg(long, default_value = "generalized-alpha")]
    integrator: IntegratorName,
    /// Physics step, s (default: the scene's physics_dt, else 0.001); with --tol the output
    /// interval, the sub-steps inside it chosen by the error estimate.
    #[arg(long, allow_hyphen_values = true)]
    dt: Option<f64>,
    /// Spectral radius at infinity of generalized-alpha, in [0, 1].
    #[arg(long, allow_hyphen_values = true, default_value_t = 0.8)]
    rho_inf: f64,
    /// Local error tolerance per step, m: error-controlled steps (generalized-alpha,
    /// dormand-prince).
    #[arg(long, allow_hyphen_values = true)]
    tol: Option<f64>,
    /// Newton tolerance of generalized-alpha, relative to the forces, 1e-12 to 1e-3 (default
    /// 1e-9): a looser one takes fewer iterations per step (docs/benchmarks.md).
    #[arg(long, allow_hyphen_values = true)]
    newton_tol: Option<f64>,
}

/// The Newton settings for `--newton-tol` (`flag`) when it lies in `NEWTON_TOLERANCE_RANGE`, else
/// the reason.
pub(crate) fn newton_settings(flag: &str, tolerance: Option<f64>) -> Result<NewtonSettings, String> {
    tensegrity::sim::checked_newton(flag, tolerance)
}

#[derive(ValueEnum, Clone, Copy)]
pub(crate) enum IntegratorName {
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
    pub(crate) fn integrator(self, rho_inf: f64) -> Integrator {
        match self {
            IntegratorName::GeneralizedAlpha => Integrator::GeneralizedAlpha { rho_inf },
            IntegratorName::SymplecticEuler => Integrator::SymplecticEuler,
            IntegratorName::Rk4 => Integrator::Rk4,
            IntegratorName::DormandPrince => Integrator::DormandPrince,
        }
    }
}

/// `dt` when it lies in the physics step range every part accepts, else the reason naming `flag`.
pub(crate) fn check_dt(flag: &str, dt: f64) -> Result<f64, String> {
    tensegrity::sim::checked_dt(flag, dt)
}

impl DynamicArgs {
    /// The options as the library takes them.
    pub(crate) fn options(&self) -> DynamicOptions {
        DynamicOptions {
            integrator: self.integrator.integrator(self.rho_inf),
            dt: self.dt,
            rho_inf: self.rho_inf,
            tolerance: self.tol,
            newton_tolerance: self.newton_tol,
        }
    }

    pub(crate) fn settings(&self, model: &Model) -> Result<SimSettings, String> {
        self.options().settings(model.physics_dt, |name| format!("--{}", name.replace('_', "-")))
    }
}
