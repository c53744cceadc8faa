//! Deployment studies and the work-precision benchmark: take a model, ramp times or integrator and
//! step lists, give CSV tables, Markdown summaries and plots (PNG and SVG) in an output directory.
//!
//! - `deployment_study`: the quasi-static path and one dynamic deployment per actuation time (the
//!   whole schedule time-scaled so that it ends at that time, then `settle` seconds at rest); per
//!   run the peak tension over all cables and the peak displacement of a chosen point, their
//!   deviation from the quasi-static path, and the actuation time below which the deviation
//!   exceeds 1 %. For a free-floating structure (`Model::is_free_floating`) displacements are
//!   measured after removing the rigid-body motion (`rigidly_aligned`): its shape is compared, not
//!   its drift, and the summary says so.
//! - `work_precision`: one deployment over integrators, step sizes and error tolerances; each
//!   run's error is the largest distance of any point from a converged reference run (much smaller
//!   step) over regular samples, against its median wall time; the error runs go on all cores, the
//!   timed runs one at a time.
//! - `deployment_study` runs its dynamic deployments on all cores too (`jobs`), with the same
//!   results as one at a time.

use std::fmt::Write as _;
use std::io::Write as _;
use std::path::Path;
use std::time::{Duration, Instant};

use nalgebra::Vector3;

use crate::forces::Workspace;
use crate::model::Model;
use crate::plot::{self, Chart, Series};
use crate::report;
use crate::report::Num;
use crate::sim::{SimSettings, Simulator, StepStats};
use crate::solve::dynamics::Integrator;
use crate::solve::statics::deploy_quasi_static;
use crate::state::State;

/// `now` moved by the rigid motion (rotation and translation) that brings it closest to `start`
/// in the least-squares sense (Kabsch: `H = sum (p_i - p_c)(s_i - s_c)^T = U S V^T`,
/// `R = V diag(1, 1, det(V U^T)) U^T`, `p'_i = R (p_i - p_c) + s_c`). Equal lengths required.
pub fn rigidly_aligned(now: &[Vector3<f64>], start: &[Vector3<f64>]) -> Vec<Vector3<f64>> {
    let n = now.len().max(1) as f64;
    let pc = now.iter().sum::<Vector3<f64>>() / n;
    let sc = start.iter().sum::<Vector3<f64>>() / n;
    let mut h = nalgebra::Matrix3::zeros();
    for (p, q) in now.iter().zip(start) {
        h += (p - pc) * (q - sc).transpose();
    }
    let Some(svd) =
        crate::solve::linear::ThinSvd::new(&nalgebra::DMatrix::from_column_slice(3, 3, h.as_slice()))
    else {
        return now.to_vec();
    };
    let u = nalgebra::Matrix3::from_column_slice(svd.u.as_slice());
    let v = nalgebra::Matrix3::from_column_slice(svd.v.as_slice());
    let d = (v * u.transpose()).determinant().signum();
    let r = v * nalgebra::Matrix3::from_diagonal(&Vector3::new(1.0, 1.0, d)) * u.transpose();
    now.iter().map(|p| r * (p - pc) + sc).collect()
}

/// Scales every ramp of the schedule in time so that the schedule ends at `ramp_time` (s).
pub fn scale_schedule(model: &mut Model, ramp_time: f64) {
    let end = model.schedule.end_time();
    if end <= 0.0 {
        return;
    }
    let s = ramp_time / end;
    for r in &mut model.schedule.ramps {
        r.start *= s;
        r.duration *= s;
    }
}

/// True when every ramp respects its actuator's `max_rate`.
pub fn within_rate_limits(model: &Model) -> bool {
    let mut rest = model.initial_rest_lengths.clone();
    let mut ok = true;
    for r in &model.schedule.ramps {
        let act = model.actuators[r.actuator.0];
        model.scheduled_rest_lengths(r.start, &mut rest);
        let from = rest[act.cable.0];
        ok &= (r.target - from).abs() / r.duration <= act.max_rate * (1.0 + 1e-12);
    }
    ok
}

/// Totals of a dynamic run.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct RunTotals {
    /// Steps taken.
    pub steps: usize,
    /// Newton iterations over all steps.
    pub newton_iterations: usize,
    /// Rejected attempts.
    pub rejected: usize,
    /// Accepted sub-steps (equal to `steps` for fixed steps without rejections).
    pub substeps: usize,
    /// Wall time of the stepping (callbacks excluded).
    pub wall_time: Duration,
}

impl RunTotals {
    /// Counts one step that cost `stats`.
    pub fn add(&mut self, stats: &StepStats) {
        self.steps += 1;
        self.newton_iterations += stats.newton_iterations;
        self.rejected += stats.rejected;
        self.substeps += stats.substeps;
        self.wall_time += stats.wall_time;
    }
}

/// Runs `model` for `duration` s with `settings`, calling `each` after every step.
pub fn run_dynamic(
    model: &Model,
    settings: SimSettings,
    duration: f64,
    mut each: impl FnMut(&Simulator, &StepStats) -> Result<(), String>,
) -> Result<RunTotals, String> {
    let mut sim = Simulator::new(model.clone(), settings).map_err(|e| e.to_string())?;
    let steps = (duration / settings.dt).round().max(1.0) as usize;
    let mut totals = RunTotals::default();
    for _ in 0..steps {
        let stats = sim.step().map_err(|e| e.to_string())?;
        totals.add(&stats);
        each(&sim, &stats)?;
    }
    Ok(totals)
}

/// Header of a dynamic time-history CSV.
pub fn dynamic_csv_header(model: &Model) -> String {
    let mut cols: Vec<String> = vec!["time_s".into()];
    for name in &model.cable_names {
        for q in ["tension_N", "length_m", "rest_length_m"] {
            cols.push(format!("{name}_{q}"));
        }
    }
    for p in &model.points {
        for ax in ["x", "y", "z"] {
            cols.push(format!("{}_{ax}_m", p.name));
        }
    }
    for e in
        ["kinetic_J", "elastic_J", "gravitational_J", "actuator_work_J", "damping_loss_J", "numerical_loss_J"]
    {
        cols.push(e.into());
    }
    for s in ["newton_iterations", "residual_N", "rejected", "substeps", "wall_us"] {
        cols.push(s.into());
    }
    cols.join(",")
}

/// One row of a dynamic time-history CSV.
pub fn dynamic_csv_row(sim: &Simulator, stats: &StepStats) -> String {
    let ws = sim.workspace();
    let mut row = format!("{:.9}", sim.state().time);
    for c in &ws.cables {
        let _ = write!(row, ",{:.9},{:.12},{:.12}", Num(c.tension), c.length, c.rest_length);
    }
    for p in &ws.points {
        let _ = write!(row, ",{:.12},{:.12},{:.12}", Num(p.position.x), Num(p.position.y), Num(p.position.z));
    }
    let e = sim.energy();
    let _ = write!(
        row,
        ",{:.9},{:.9},{:.9},{:.9},{:.9},{:.3e}",
        e.kinetic,
        e.elastic,
        e.gravitational,
        e.actuator_work,
        e.damping_loss,
        e.numerical_loss()
    );
    let _ = write!(
        row,
        ",{},{:.3e},{},{},{:.1}",
        stats.newton_iterations,
        stats.residual,
        stats.rejected,
        stats.substeps,
        stats.wall_time.as_secs_f64() * 1e6
    );
    row
}

fn create(path: &Path) -> Result<std::io::BufWriter<std::fs::File>, String> {
    std::fs::File::create(path).map(std::io::BufWriter::new).map_err(|e| format!("{}: {e}", path.display()))
}

/// One row of the study summary.
#[derive(Debug, Clone, PartialEq)]
pub struct StudyRow {
    /// Actuation (schedule) time, s.
    pub ramp_time: f64,
    /// Largest tension over all cables and the whole run, N.
    pub peak_tension: f64,
    /// `(peak - quasi-static peak) / quasi-static peak`.
    pub tension_deviation: f64,
    /// Largest displacement of the chosen point from its start, m.
    pub peak_displacement: f64,
    /// `(peak - quasi-static peak) / quasi-static peak`.
    pub displacement_deviation: f64,
    /// Whether the time-scaled schedule respects every actuator's `max_rate`.
    pub within_rate: bool,
    /// Wall time of the run, s.
    pub wall_time: f64,
}

/// What a deployment study found.
#[derive(Debug, Clone, PartialEq)]
pub struct StudyResult {
    /// The point whose displacement is tracked.
    pub point: String,
    /// Quasi-static peak tension, N.
    pub qs_peak_tension: f64,
    /// Quasi-static peak displacement of the point, m.
    pub qs_peak_displacement: f64,
    /// One row per actuation time, in increasing time.
    pub rows: Vec<StudyRow>,
    /// Displacements were measured after removing the rigid-body motion (free-floating scene).
    pub rigid_motion_removed: bool,
    /// Actuation time below which the deviation exceeds 1 % (interpolated in log-log between
    /// the bracketing runs); `None` when no run exceeds 1 %; `Some(inf)` when all do.
    pub threshold: Option<f64>,
}

impl StudyResult {
    /// Markdown table of the summary.
    pub fn markdown(&self) -> String {
        let mut s = format!(
            "Quasi-static peak tension {:.4} N, peak displacement of `{}` {:.6} m{}.\n\n| actuation time s | peak tension N | deviation % | peak displacement m | deviation % | within max_rate | wall time s |\n| ---: | ---: | ---: | ---: | ---: | :---: | ---: |\n",
            self.qs_peak_tension,
            self.point,
            self.qs_peak_displacement,
            if self.rigid_motion_removed {
                " (free-floating scene: displacements after removing the rigid-body motion by optimal rigid alignment)"
            } else {
                ""
            }
        );
        for r in &self.rows {
            let _ = writeln!(
                s,
                "| {} | {:.4} | {:+.3} | {:.6} | {:+.3} | {} | {:.2} |",
                r.ramp_time,
                r.peak_tension,
                100.0 * r.tension_deviation,
                r.peak_displacement,
                100.0 * r.displacement_deviation,
                if r.within_rate { "yes" } else { "no" },
                r.wall_time
            );
        }
        let _ = match self.threshold {
            None => writeln!(s, "\nNo run deviates by more than 1 % from the quasi-static path."),
            Some(t) if t.is_infinite() => {
                writeln!(s, "\nEvery run deviates by more than 1 %; slower actuation is needed.")
            }
            Some(t) => writeln!(s, "\nThe deviation exceeds 1 % for actuation times below about {t:.3} s."),
        };
        s
    }
}

/// Deviation threshold: the actuation time where `dev` crosses 1 % (see `StudyResult::threshold`).
pub fn one_percent_threshold(times: &[f64], dev: &[f64]) -> Option<f64> {
    let over: Vec<bool> = dev.iter().map(|d| d.abs() > 0.01).collect();
    if !over.iter().any(|o| *o) {
        return None;
    }
    let last_over = over.iter().rposition(|o| *o).expect("some over");
    if last_over + 1 == times.len() {
        return Some(f64::INFINITY);
    }
    let (t0, t1) = (times[last_over], times[last_over + 1]);
    let (d0, d1) = (dev[last_over].abs(), dev[last_over + 1].abs().max(1e-12));
    let f = (0.01f64.ln() - d0.ln()) / (d1.ln() - d0.ln());
    Some((t0.ln() + f * (t1.ln() - t0.ln())).exp())
}

/// Actuation-time factors of `default_ramp_times`.
pub const DEFAULT_RAMP_FACTORS: [f64; 8] = [0.02, 0.05, 0.1, 0.2, 0.5, 1.0, 2.0, 5.0];

/// A span of actuation times around the scene's own (the end of its schedule, `T0`):
/// `T0 x (0.02, 0.05, 0.1, 0.2, 0.5, 1, 2, 5)` s, each to 3 significant digits. Err when the
/// scene has no deployment schedule.
pub fn default_ramp_times(model: &Model) -> Result<Vec<f64>, String> {
    let t0 = model.schedule.end_time();
    if model.schedule.ramps.is_empty() || t0.is_nan() || t0 <= 0.0 {
        return Err(format!("scene '{}' has no deployment schedule to study", model.name));
    }
    Ok(DEFAULT_RAMP_FACTORS
        .iter()
        .map(|f| {
            let t = f * t0;
            let scale = 10f64.powi(2 - t.log10().floor() as i32);
            (t * scale).round() / scale
        })
        .collect())
}

/// Runs the deployment study (see the module docs) and writes into `out_dir`. `point` defaults to
/// the point that moves most along the quasi-static path. Files:
/// `quasi_static.csv`, `dynamic_T<time>.csv`, `summary.csv`, `summary.md`, `deviation.{png,svg}`,
/// `histories.{png,svg}`.
pub fn deployment_study(
    model: &Model,
    ramp_times: &[f64],
    point: Option<&str>,
    settings: SimSettings,
    settle: f64,
    jobs: usize,
    out_dir: &Path,
) -> Result<StudyResult, String> {
    std::fs::create_dir_all(out_dir).map_err(|e| format!("{}: {e}", out_dir.display()))?;
    if let Some(p) = point {
        model.point_id(p).ok_or_else(|| format!("unknown point '{p}'"))?;
    }
    if model.schedule.ramps.is_empty() {
        return Err(format!("scene '{}' has no deployment schedule to study", model.name));
    }
    let mut times: Vec<f64> = ramp_times.to_vec();
    times.sort_by(f64::total_cmp);
    if times.iter().any(|t| !(t.is_finite() && *t > 0.0)) {
        return Err("ramp times must be positive".into());
    }

    // quasi-static path (parameterized by the fraction of the schedule done)
    let mut state = State::initial(model);
    let mut ws = Workspace::new(model);
    let mut qs_file = create(&out_dir.join("quasi_static.csv"))?;
    writeln!(qs_file, "{}", report::path_csv_header(model)).map_err(|e| e.to_string())?;
    let end = model.schedule.end_time();
    let mut qs_tension: Vec<(f64, f64)> = Vec::new();
    let mut qs_peak_tension: f64 = 0.0;
    let mut start_pos: Vec<Vector3<f64>> = Vec::new();
    let mut qs_disp = vec![0.0f64; model.points.len()];
    let free = model.is_free_floating();
    // positions to compare with the start: as they are, or rigidly aligned onto the start
    let shape = |now: Vec<Vector3<f64>>, start: &[Vector3<f64>]| {
        if free {
            rigidly_aligned(&now, start)
        } else {
            now
        }
    };
    deploy_quasi_static(model, &mut state, &mut ws, |step, st, w| {
        let row = report::path_csv_row(model, st, w, step);
        let _ = writeln!(qs_file, "{row}");
        if step.kind == crate::solve::statics::PathKind::ArcLength {
            // points traced through a limit point are not states the structure rests in
            return;
        }
        let t_max = w.cables.iter().map(|c| c.tension).fold(0.0, f64::max);
        qs_peak_tension = qs_peak_tension.max(t_max);
        if start_pos.is_empty() {
            start_pos = w.points.iter().map(|p| p.position).collect();
        }
        let now = shape(w.points.iter().map(|p| p.position).collect(), &start_pos);
        for (i, p) in now.iter().enumerate() {
            qs_disp[i] = qs_disp[i].max((p - start_pos[i]).norm());
        }
        qs_tension.push((st.time / end, t_max));
    })
    .map_err(|e| e.to_string())?;
    qs_file.flush().map_err(|e| e.to_string())?;
    let pid = match point {
        Some(p) => model.point_id(p).expect("checked above"),
        // the first point (in file order) within 1e-9 of the largest displacement: symmetric
        // points tie, and round-off must not pick between them
        None => {
            let top = qs_disp.iter().copied().fold(0.0, f64::max);
            crate::model::PointId((0..qs_disp.len()).find(|&i| qs_disp[i] >= top * (1.0 - 1e-9)).unwrap_or(0))
        }
    };
    let point = model.points[pid.0].name.as_str();
    let qs_peak_disp = qs_disp[pid.0];

    // every time-scaled run starts from the model's initial state: one start position for all
    let dynamic_start: Vec<Vector3<f64>> = {
        let mut s0 = Workspace::new(model);
        crate::forces::evaluate(model, &State::initial(model), &mut s0, crate::forces::Tangents::None);
        s0.points.iter().map(|p| p.position).collect()
    };
    // one dynamic deployment per actuation time, on `jobs` threads (each run is independent and
    // deterministic: the same rows whatever the thread count)
    let run_one = |&t_ramp: &f64| -> Result<(StudyRow, Series), String> {
        let mut m = model.clone();
        scale_schedule(&mut m, t_ramp);
        let within_rate = within_rate_limits(&m);
        let mut file = create(&out_dir.join(format!("dynamic_T{t_ramp}.csv")))?;
        writeln!(file, "{}", dynamic_csv_header(&m)).map_err(|e| e.to_string())?;
        let mut peak_t: f64 = 0.0;
        let mut peak_d: f64 = 0.0;
        let mut history = Vec::new();
        let totals = run_dynamic(&m, settings, t_ramp + settle, |sim, stats| {
            writeln!(file, "{}", dynamic_csv_row(sim, stats)).map_err(|e| e.to_string())?;
            let w = sim.workspace();
            let t_max = w.cables.iter().map(|c| c.tension).fold(0.0, f64::max);
            peak_t = peak_t.max(t_max);
            let d = if free {
                let now = shape(w.points.iter().map(|p| p.position).collect(), &dynamic_start);
                (now[pid.0] - dynamic_start[pid.0]).norm()
            } else {
                (w.points[pid.0].position - dynamic_start[pid.0]).norm()
            };
            peak_d = peak_d.max(d);
            if sim.state().time <= 2.5 * t_ramp {
                history.push((sim.state().time / t_ramp, t_max));
            }
            Ok(())
        })
        .map_err(|e| format!("actuation time {t_ramp} s: {e}"))?;
        file.flush().map_err(|e| e.to_string())?;
        let row = StudyRow {
            ramp_time: t_ramp,
            peak_tension: peak_t,
            tension_deviation: (peak_t - qs_peak_tension) / qs_peak_tension,
            peak_displacement: peak_d,
            displacement_deviation: if qs_peak_disp > 0.0 {
                (peak_d - qs_peak_disp) / qs_peak_disp
            } else {
                0.0
            },
            within_rate,
            wall_time: totals.wall_time.as_secs_f64(),
        };
        Ok((row, Series::new(format!("T = {t_ramp} s"), history, false)))
    };
    let runs = parallel_map(&times, jobs, run_one)?;
    let mut histories = vec![Series { reference: true, ..Series::new("quasi-static", qs_tension, false) }];
    let mut rows = Vec::new();
    for (row, history) in runs {
        rows.push(row);
        histories.push(history);
    }
    let worst: Vec<f64> =
        rows.iter().map(|r| r.tension_deviation.abs().max(r.displacement_deviation.abs())).collect();
    let result = StudyResult {
        point: point.to_string(),
        qs_peak_tension,
        qs_peak_displacement: qs_peak_disp,
        threshold: one_percent_threshold(&times, &worst),
        rows,
        rigid_motion_removed: free,
    };

    let mut summary = create(&out_dir.join("summary.csv"))?;
    let _ = writeln!(summary, "ramp_time_s,peak_tension_N,tension_deviation_percent,peak_displacement_m,displacement_deviation_percent,within_max_rate,wall_time_s");
    for r in &result.rows {
        let _ = writeln!(
            summary,
            "{},{:.9},{:.6e},{:.9},{:.6e},{},{:.4}",
            r.ramp_time,
            r.peak_tension,
            100.0 * r.tension_deviation,
            r.peak_displacement,
            100.0 * r.displacement_deviation,
            r.within_rate,
            r.wall_time
        );
    }
    summary.flush().map_err(|e| e.to_string())?;
    std::fs::write(out_dir.join("summary.md"), result.markdown()).map_err(|e| e.to_string())?;

    let dev_series = |name: &str, f: &dyn Fn(&StudyRow) -> f64| {
        Series::new(
            name,
            result.rows.iter().map(|r| (r.ramp_time, 100.0 * f(r).abs().max(1e-6))).collect(),
            true,
        )
    };
    plot::write(
        &Chart {
            title: format!("{}: dynamic vs quasi-static deployment", model.name),
            x_label: "actuation time (s)".into(),
            y_label: "|deviation| (%)".into(),
            log_x: true,
            log_y: true,
            series: vec![
                dev_series("peak tension", &|r| r.tension_deviation),
                dev_series(&format!("peak displacement of {point}"), &|r| r.displacement_deviation),
            ],
            reference: Some((1.0, "1 %".into())),
        },
        &out_dir.join("deviation"),
    )?;
    plot::write(
        &Chart {
            title: format!("{}: largest cable tension during deployment (to 2.5 T)", model.name),
            x_label: "time / actuation time".into(),
            y_label: "largest tension (N)".into(),
            log_x: false,
            log_y: false,
            series: histories,
            reference: None,
        },
        &out_dir.join("histories"),
    )?;
    Ok(result)
}

/// One run of the work-precision benchmark: an integrator at a fixed step, or under error
/// control with a tolerance (then it steps between samples as its estimate decides).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RunConfig {
    /// Integrator.
    pub integrator: Integrator,
    /// Fixed step, s (`None`: error-controlled).
    pub dt: Option<f64>,
    /// Local error tolerance, m (error-controlled runs).
    pub tolerance: Option<f64>,
}

impl RunConfig {
    /// A fixed-step run.
    pub fn fixed(integrator: Integrator, dt: f64) -> Self {
        Self { integrator, dt: Some(dt), tolerance: None }
    }
    /// An error-controlled run.
    pub fn controlled(integrator: Integrator, tolerance: f64) -> Self {
        Self { integrator, dt: None, tolerance: Some(tolerance) }
    }
    /// Simulator settings with `sample` (s) the output interval of an error-controlled run.
    fn settings(&self, sample: f64) -> SimSettings {
        SimSettings {
            dt: self.dt.unwrap_or(sample),
            integrator: self.integrator,
            tolerance: self.tolerance,
            ..Default::default()
        }
    }
}

/// One row of the work-precision table.
#[derive(Debug, Clone, PartialEq)]
pub struct WorkPrecisionRow {
    /// Integrator name.
    pub integrator: String,
    /// The run.
    pub config: RunConfig,
    /// Step, s (fixed runs).
    pub dt: f64,
    /// Largest point distance from the reference over the samples, m.
    pub error: f64,
    /// Median wall time over the repeats, s.
    pub wall_time: f64,
    /// Newton iterations per step.
    pub newton_per_step: f64,
    /// Steps taken (sub-steps of an error-controlled run).
    pub steps: usize,
    /// Rejected attempts in the run.
    pub rejected: usize,
}

/// Positions of every point at one sample time, m.
type PointSample = Vec<Vector3<f64>>;

/// Point positions every `sample` seconds (from `run_dynamic`), flattened.
fn sampled_positions(
    model: &Model,
    settings: SimSettings,
    duration: f64,
    sample: f64,
) -> Result<(Vec<PointSample>, RunTotals), String> {
    let every = (sample / settings.dt).round().max(1.0) as usize;
    let mut out = Vec::new();
    let mut k = 0;
    let totals = run_dynamic(model, settings, duration, |sim, _| {
        k += 1;
        if k % every == 0 {
            out.push(sim.workspace().points.iter().map(|p| p.position).collect());
        }
        Ok(())
    })?;
    Ok((out, totals))
}

/// Runs `f` over `items` on `jobs` threads (0: one per core), results in the items' order.
fn parallel_map<T: Sync, R: Send>(
    items: &[T],
    jobs: usize,
    f: impl Fn(&T) -> Result<R, String> + Sync,
) -> Result<Vec<R>, String> {
    use rayon::prelude::*;
    let pool = rayon::ThreadPoolBuilder::new().num_threads(jobs).build().map_err(|e| e.to_string())?;
    pool.install(|| items.par_iter().map(&f).collect())
}

/// Work-precision settings besides the runs.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WorkPrecisionSettings {
    /// Fixed step of the Dormand-Prince reference run, s.
    pub reference_dt: f64,
    /// Simulated time, s.
    pub duration: f64,
    /// Sample interval of the error (and output interval of error-controlled runs), s.
    pub sample: f64,
    /// Timed repeats per run (the median is reported).
    pub repeats: usize,
    /// Threads for the error runs (0: one per core); timing runs one at a time.
    pub jobs: usize,
}

/// Runs the work-precision benchmark: every run of `configs` against a Dormand-Prince reference
/// at `reference_dt`; error = largest point distance from the reference over the samples (after
/// the optimal rigid alignment onto it for a free-floating structure). The error runs go on
/// `jobs` threads, then each run is timed `repeats` times one at a time (so that the timings do
/// not share the cores); results are the same whatever `jobs` is. Fixed-step explicit runs
/// above their stability limit, and fixed steps that do not divide the sample interval, are left
/// out. Writes `work_precision.csv`, `work_precision.md`
/// (with, for each accuracy of 1e-4 and 1e-6 m, the cheapest run that meets it, and for each
/// error-controlled run its cost against the cheapest fixed-step run at least as accurate) and
/// `work_precision.{png,svg}`.
pub fn work_precision(
    model: &Model,
    configs: &[RunConfig],
    bench: WorkPrecisionSettings,
    out_dir: &Path,
) -> Result<Vec<WorkPrecisionRow>, String> {
    std::fs::create_dir_all(out_dir).map_err(|e| format!("{}: {e}", out_dir.display()))?;
    let WorkPrecisionSettings { reference_dt, duration, sample, repeats, jobs } = bench;
    if !(sample > 0.0 && reference_dt > 0.0 && reference_dt <= sample && duration >= sample) {
        return Err(format!(
            "the reference step ({reference_dt} s) must be positive and at most the sample interval ({sample} s), itself at most the duration ({duration} s)"
        ));
    }
    let reference_settings =
        SimSettings { dt: reference_dt, integrator: Integrator::DormandPrince, ..Default::default() };
    let (reference, _) = sampled_positions(model, reference_settings, duration, sample)
        .map_err(|e| format!("reference run (Dormand-Prince at {reference_dt} s): {e}"))?;
    let start = State::initial(model);
    let limit = |i: Integrator| crate::solve::dynamics::explicit_stability_limit(model, &start, i);
    let runs: Vec<RunConfig> = configs
        .iter()
        .copied()
        .filter(|c| match c.dt {
            // a step must divide the sample interval, so that samples fall at the reference's times
            Some(dt) => {
                let per_sample = sample / dt;
                dt <= sample * (1.0 + 1e-9)
                    && (per_sample - per_sample.round()).abs() <= 1e-6 * per_sample
                    && !(c.integrator.is_explicit() && dt > limit(c.integrator))
            }
            None => true,
        })
        .collect();
    let free = model.is_free_floating();
    let error_of = |samples: &[PointSample]| {
        samples
            .iter()
            .zip(&reference)
            .flat_map(|(a, b)| {
                // a structure held by nothing drifts differently under each integrator: compare
                // shapes, after the optimal rigid alignment onto the reference
                let a = if free { rigidly_aligned(a, b) } else { a.clone() };
                a.iter().zip(b).map(|(p, q)| (p - q).norm()).collect::<Vec<_>>()
            })
            .fold(0.0, f64::max)
    };
    // errors on all cores
    let accuracy = parallel_map(&runs, jobs, |c| {
        let (samples, totals) = sampled_positions(model, c.settings(sample), duration, sample)
            .map_err(|e| format!("{}: {e}", c.integrator.name()))?;
        Ok((error_of(&samples), totals))
    })?;
    // timings one at a time
    let mut rows = Vec::new();
    for (c, (error, totals)) in runs.iter().zip(accuracy) {
        let mut walls = Vec::new();
        for _ in 0..repeats.max(1) {
            let begin = Instant::now();
            sampled_positions(model, c.settings(sample), duration, sample)?;
            walls.push(begin.elapsed().as_secs_f64());
        }
        walls.sort_by(f64::total_cmp);
        rows.push(WorkPrecisionRow {
            integrator: match c.tolerance {
                Some(_) => format!("{} (tol)", c.integrator.name()),
                None => c.integrator.name(),
            },
            config: *c,
            dt: c.dt.unwrap_or(0.0),
            error,
            wall_time: walls[walls.len() / 2],
            newton_per_step: totals.newton_iterations as f64 / totals.substeps.max(1) as f64,
            steps: totals.substeps,
            rejected: totals.rejected,
        });
    }
    write_work_precision(model, &rows, bench, free, out_dir)?;
    Ok(rows)
}

/// The work-precision table, its verdicts and its plot.
fn write_work_precision(
    model: &Model,
    rows: &[WorkPrecisionRow],
    bench: WorkPrecisionSettings,
    free: bool,
    out_dir: &Path,
) -> Result<(), String> {
    let WorkPrecisionSettings { reference_dt, duration, sample, repeats, .. } = bench;
    let start = State::initial(model);
    let mut csv = create(&out_dir.join("work_precision.csv"))?;
    let _ = writeln!(
        csv,
        "integrator,dt_s,tolerance_m,max_point_error_m,median_wall_time_s,steps,rejected,newton_per_step"
    );
    let limits: Vec<String> = [Integrator::SymplecticEuler, Integrator::Rk4, Integrator::DormandPrince]
        .iter()
        .map(|&i| {
            format!(
                "{} {:.3e} s",
                i.name(),
                crate::solve::dynamics::explicit_stability_limit(model, &start, i)
            )
        })
        .collect();
    let mut md = format!(
        "Reference: dormand-prince at dt = {reference_dt:e} s; error = largest distance of any point from the reference{}, sampled every {sample} s over {duration} s; wall time = median of {repeats} runs, one at a time; error-controlled runs (tol) step between samples as their estimate decides. Stability limits of the explicit integrators at the start: {}.\n\n| integrator | dt s | tolerance m | max point error m | median wall time s | steps | rejected | Newton iterations / step |\n| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: |\n",
        if free {
            " after the optimal rigid alignment of each sample onto it (the structure floats free: shapes are compared, not drift)"
        } else {
            ""
        },
        limits.join(", ")
    );
    let fmt_opt = |x: Option<f64>| x.map(|v| format!("{v:e}")).unwrap_or_else(|| "-".into());
    for r in rows {
        let _ = writeln!(
            csv,
            "{},{},{},{:.6e},{:.6},{},{},{:.3}",
            r.integrator,
            r.config.dt.map(|d| d.to_string()).unwrap_or_default(),
            r.config.tolerance.map(|t| t.to_string()).unwrap_or_default(),
            r.error,
            r.wall_time,
            r.steps,
            r.rejected,
            r.newton_per_step
        );
        let _ = writeln!(
            md,
            "| {} | {} | {} | {:.3e} | {:.4} | {} | {} | {:.2} |",
            r.integrator,
            fmt_opt(r.config.dt),
            fmt_opt(r.config.tolerance),
            r.error,
            r.wall_time,
            r.steps,
            r.rejected,
            r.newton_per_step
        );
    }
    // verdicts: the cheapest run at each accuracy, and each error-controlled run's cost
    md.push('\n');
    for target in [1e-4, 1e-6] {
        match rows.iter().filter(|r| r.error <= target).min_by(|a, b| a.wall_time.total_cmp(&b.wall_time)) {
            Some(best) => {
                let _ = writeln!(
                    md,
                    "Cheapest run with at most {target:e} m error: {} at {}, {:.3e} m in {:.4} s.  ",
                    best.integrator,
                    best.config
                        .dt
                        .map(|d| format!("dt = {d} s"))
                        .unwrap_or_else(|| format!("tolerance {} m", fmt_opt(best.config.tolerance))),
                    best.error,
                    best.wall_time
                );
            }
            None => {
                let _ = writeln!(md, "No run reached {target:e} m.  ");
            }
        }
    }
    for r in rows.iter().filter(|r| r.config.tolerance.is_some()) {
        let cheapest = |same: bool| {
            rows.iter()
                .filter(|f| f.config.tolerance.is_none() && f.error <= r.error)
                .filter(|f| !same || f.config.integrator == r.config.integrator)
                .min_by(|a, b| a.wall_time.total_cmp(&b.wall_time))
        };
        let versus = |f: Option<&WorkPrecisionRow>, what: &str| match f {
            Some(f) => format!(
                "{:.2} x the cheapest fixed-step run of {what} at least as accurate ({} at dt = {} s)",
                r.wall_time / f.wall_time,
                f.integrator,
                f.dt
            ),
            None => format!("no fixed-step run of {what} here is as accurate"),
        };
        let tol = r.config.tolerance.unwrap_or(0.0);
        let _ = writeln!(
            md,
            "{} at tolerance {tol:e} m: error {:.2} x the tolerance; wall time {}; {}.  ",
            r.integrator,
            r.error / tol,
            versus(cheapest(true), "the same integrator"),
            versus(cheapest(false), "any integrator"),
        );
    }
    csv.flush().map_err(|e| e.to_string())?;
    std::fs::write(out_dir.join("work_precision.md"), &md).map_err(|e| e.to_string())?;
    let mut series: Vec<Series> = Vec::new();
    for r in rows {
        match series.iter_mut().find(|s| s.name == r.integrator) {
            Some(s) => s.points.push((r.wall_time, r.error.max(1e-16))),
            None => {
                series.push(Series::new(r.integrator.clone(), vec![(r.wall_time, r.error.max(1e-16))], true))
            }
        }
    }
    plot::write(
        &Chart {
            title: format!("{}: work-precision", model.name),
            x_label: "wall time (s)".into(),
            y_label: "max point error (m)".into(),
            log_x: true,
            log_y: true,
            series,
            reference: None,
        },
        &out_dir.join("work_precision"),
    )?;
    Ok(())
}

/// Side strings of a scaling-benchmark tower (`crate::scene::generate::TowerParams`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TowerFamily {
    /// Helical clustered side cables through every stage (each couples a bar of every stage).
    Helical,
    /// One clustered cable per stage through its side strings (MuJoCo's peer towers).
    PerStage,
    /// Classical two-point side strings.
    Classical,
}

impl TowerFamily {
    /// Name used in tables.
    pub fn name(self) -> &'static str {
        match self {
            TowerFamily::Helical => "helical clustered",
            TowerFamily::PerStage => "clustered per stage",
            TowerFamily::Classical => "classical",
        }
    }

    /// The tower of `stages` stages of this family: the helical tower deploys by its side
    /// cables, the others by their clustered top ring.
    pub fn model(self, stages: usize) -> Result<Model, String> {
        use crate::scene::generate::{tower, TowerParams};
        let spec = tower(&TowerParams {
            stages,
            cluster_sides: self == TowerFamily::Helical,
            cluster_per_stage: self == TowerFamily::PerStage,
            cluster_top_ring: self != TowerFamily::Helical,
            ..Default::default()
        });
        crate::scene::build_model(&spec, &format!("<{} tower {stages}>", self.name()), None)
            .map_err(|e| e.to_string())
    }
}

/// One row of the scaling benchmark.
#[derive(Debug, Clone, PartialEq)]
pub struct ScalingRow {
    /// Which side strings.
    pub family: TowerFamily,
    /// Tower stages.
    pub stages: usize,
    /// Generalized coordinates.
    pub coordinates: usize,
    /// Constraint rows.
    pub constraints: usize,
    /// Unknowns of the sparse Newton system (coordinates, constraint rows, bordered cables).
    pub sparse_size: usize,
    /// Structural nonzeros of the sparse Newton matrix.
    pub nonzeros: usize,
    /// Median wall time per step with the dense LU, s (`None`: not run, too large).
    pub dense_step: Option<f64>,
    /// Median wall time per step with the sparse backend (`LDL^T` of the symmetric part, LU when that does not contract), s.
    pub sparse_step: f64,
    /// Newton iterations per step (sparse run).
    pub newton_per_step: f64,
    /// Factorizations per step (sparse run).
    pub factorizations_per_step: f64,
}

/// Largest system the scaling benchmark also times with the dense LU.
pub const SCALING_DENSE_MAX_SIZE: usize = 800;

/// Median wall time per step (s), Newton iterations and factorizations per step of `steps`
/// generalized-alpha steps of `model` (dt 1 ms).
pub fn median_step_time(
    model: &Model,
    linear: crate::solve::linear::LinearBackend,
    steps: usize,
) -> Result<(f64, f64, f64), String> {
    let settings = SimSettings { dt: 1e-3, linear, ..Default::default() };
    let mut times = Vec::with_capacity(steps);
    let mut factorizations = 0;
    let totals = run_dynamic(model, settings, steps as f64 * 1e-3, |_, stats| {
        times.push(stats.wall_time.as_secs_f64());
        factorizations += stats.factorizations;
        Ok(())
    })?;
    times.sort_by(f64::total_cmp);
    let per = |k: usize| k as f64 / totals.steps.max(1) as f64;
    Ok((times[times.len() / 2], per(totals.newton_iterations), per(factorizations)))
}

/// Step-time statistics of one run (`step_times`).
#[derive(Debug, Clone, PartialEq)]
pub struct StepTimes {
    /// Median wall time per step, s.
    pub median: f64,
    /// Mean wall time per step, s.
    pub mean: f64,
    /// Largest wall time of one step, s.
    pub max: f64,
    /// Newton iterations per step.
    pub newton_per_step: f64,
    /// Newton-matrix factorizations per step.
    pub factorizations_per_step: f64,
    /// The linear-solver backend `Auto` chose.
    pub backend: crate::solve::linear::LinearBackend,
    /// Unknowns of the Newton system (coordinates, joint rows, bordered cables).
    pub unknowns: usize,
    /// Stored entries of the Newton matrix (`unknowns^2` when dense).
    pub nonzeros: usize,
    /// Stored entries of the sparse symmetric factor `L`, when the backend has one.
    pub factor_entries: Option<usize>,
}

/// Times `steps` steps of `model` with `settings` after 10 untimed warm-up steps.
pub fn step_times(model: &Model, settings: SimSettings, steps: usize) -> Result<StepTimes, String> {
    let mut sim = Simulator::new(model.clone(), settings).map_err(|e| e.to_string())?;
    for _ in 0..10 {
        sim.step().map_err(|e| e.to_string())?;
    }
    let mut times = Vec::with_capacity(steps);
    let (mut newton, mut factorizations) = (0, 0);
    for _ in 0..steps {
        let s = sim.step().map_err(|e| e.to_string())?;
        times.push(s.wall_time.as_secs_f64());
        newton += s.newton_iterations;
        factorizations += s.factorizations;
    }
    let mean = times.iter().sum::<f64>() / steps as f64;
    times.sort_by(f64::total_cmp);
    Ok(StepTimes {
        median: times[steps / 2],
        mean,
        max: times[steps - 1],
        newton_per_step: newton as f64 / steps as f64,
        factorizations_per_step: factorizations as f64 / steps as f64,
        backend: sim.linear_backend(),
        unknowns: sim.newton_system().size(),
        nonzeros: sim.newton_system().nonzeros(),
        factor_entries: sim.newton_system().symmetric_factor_entries(),
    })
}

/// Least-squares slope of `log y` against `log x`: the exponent `p` of `y ~ x^p`.
pub fn growth_exponent(points: &[(f64, f64)]) -> f64 {
    let logs: Vec<(f64, f64)> = points.iter().map(|(x, y)| (x.ln(), y.ln())).collect();
    let k = logs.len() as f64;
    let (mx, my) = (logs.iter().map(|p| p.0).sum::<f64>() / k, logs.iter().map(|p| p.1).sum::<f64>() / k);
    let sxy: f64 = logs.iter().map(|p| (p.0 - mx) * (p.1 - my)).sum();
    let sxx: f64 = logs.iter().map(|p| (p.0 - mx).powi(2)).sum();
    sxy / sxx
}

/// Scaling benchmark: towers of 3-strut prisms with `stages` stages in the three
/// `TowerFamily`s, `steps` generalized-alpha steps each with the sparse backend and (up to
/// `SCALING_DENSE_MAX_SIZE` unknowns) the dense LU; writes `scaling.csv`, `scaling.md` (with the
/// fitted growth exponent of the sparse step time over the runs with 8 or more stages) and
/// `scaling.{png,svg}`.
pub fn scaling(stages: &[usize], steps: usize, out_dir: &Path) -> Result<Vec<ScalingRow>, String> {
    use crate::solve::linear::{KktSystem, LinearBackend};
    std::fs::create_dir_all(out_dir).map_err(|e| format!("{}: {e}", out_dir.display()))?;
    let mut rows = Vec::new();
    for family in [TowerFamily::Classical, TowerFamily::PerStage, TowerFamily::Helical] {
        for &s in stages {
            let model = family.model(s)?;
            let kkt = KktSystem::new(&model, LinearBackend::Sparse);
            let (sparse_step, newton_per_step, factorizations_per_step) =
                median_step_time(&model, LinearBackend::Sparse, steps)?;
            let size = model.dof_count + model.constraint_count;
            let dense_step = if size <= SCALING_DENSE_MAX_SIZE {
                Some(median_step_time(&model, LinearBackend::Dense, steps)?.0)
            } else {
                None
            };
            rows.push(ScalingRow {
                family,
                stages: s,
                coordinates: model.dof_count,
                constraints: model.constraint_count,
                sparse_size: kkt.size(),
                nonzeros: kkt.nonzeros(),
                dense_step,
                sparse_step,
                newton_per_step,
                factorizations_per_step,
            });
        }
    }
    let mut csv = create(&out_dir.join("scaling.csv"))?;
    let _ = writeln!(
        csv,
        "side_strings,stages,coordinates,constraints,sparse_unknowns,sparse_nonzeros,newton_per_step,factorizations_per_step,dense_step_us,sparse_step_us"
    );
    let mut md = format!(
        "Towers of 3-strut prisms, generalized-alpha (rho_inf 0.8) at dt = 1 ms, median wall time per step over {steps} steps.\n\n| side strings | stages | coordinates | constraints | sparse unknowns | sparse nonzeros | Newton / step | factorizations / step | dense LU µs/step | sparse µs/step |\n| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |\n"
    );
    for r in &rows {
        let dense = r.dense_step.map(|d| format!("{:.1}", 1e6 * d)).unwrap_or_else(|| "-".into());
        let _ = writeln!(
            csv,
            "{},{},{},{},{},{},{:.3},{:.3},{},{:.2}",
            r.family.name(),
            r.stages,
            r.coordinates,
            r.constraints,
            r.sparse_size,
            r.nonzeros,
            r.newton_per_step,
            r.factorizations_per_step,
            r.dense_step.map(|d| format!("{:.2}", 1e6 * d)).unwrap_or_default(),
            1e6 * r.sparse_step
        );
        let _ = writeln!(
            md,
            "| {} | {} | {} | {} | {} | {} | {:.2} | {:.2} | {dense} | {:.1} |",
            r.family.name(),
            r.stages,
            r.coordinates,
            r.constraints,
            r.sparse_size,
            r.nonzeros,
            r.newton_per_step,
            r.factorizations_per_step,
            1e6 * r.sparse_step
        );
    }
    md.push('\n');
    let mut series = Vec::new();
    for family in [TowerFamily::Classical, TowerFamily::PerStage, TowerFamily::Helical] {
        let points: Vec<(f64, f64)> =
            rows.iter().filter(|r| r.family == family).map(|r| (r.stages as f64, r.sparse_step)).collect();
        let fit: Vec<(f64, f64)> = points.iter().copied().filter(|p| p.0 >= 8.0).collect();
        if fit.len() >= 2 {
            let _ = writeln!(
                md,
                "{}: sparse step time ~ stages^{:.2} (fitted over {} runs with 8+ stages)  ",
                family.name(),
                growth_exponent(&fit),
                fit.len()
            );
        }
        series.push(Series::new(format!("{} (sparse)", family.name()), points, true));
        if family == TowerFamily::Helical {
            // the helical tower's cost beside the per-stage one's, at each size both ran
            let per_stage = |s: usize| {
                rows.iter()
                    .find(|r| r.family == TowerFamily::PerStage && r.stages == s)
                    .map(|r| r.sparse_step)
            };
            let ratios: Vec<String> = rows
                .iter()
                .filter(|r| r.family == family && r.stages >= 8)
                .filter_map(|r| {
                    per_stage(r.stages).map(|p| format!("{:.2} at {}", r.sparse_step / p, r.stages))
                })
                .collect();
            if !ratios.is_empty() {
                let _ = writeln!(md, "helical / per-stage step time: {} stages  ", ratios.join(", "));
            }
        }
        let dense: Vec<(f64, f64)> = rows
            .iter()
            .filter(|r| r.family == family)
            .filter_map(|r| r.dense_step.map(|d| (r.stages as f64, d)))
            .collect();
        if !dense.is_empty() {
            series.push(Series::new(format!("{} (dense LU)", family.name()), dense, true));
        }
    }
    csv.flush().map_err(|e| e.to_string())?;
    std::fs::write(out_dir.join("scaling.md"), &md).map_err(|e| e.to_string())?;
    plot::write(
        &Chart {
            title: "generalized-alpha step time vs tower size".into(),
            x_label: "stages".into(),
            y_label: "median wall time per step (s)".into(),
            log_x: true,
            log_y: true,
            series,
            reference: None,
        },
        &out_dir.join("scaling"),
    )?;
    Ok(rows)
}
