//! Deployment studies and the work-precision benchmark: take a model, ramp times or integrator and
//! step lists, give CSV tables, Markdown summaries and plots (PNG and SVG) in an output directory.
//!
//! - `deployment_study`: the quasi-static path and one dynamic deployment per actuation time (the
//!   whole schedule time-scaled so that it ends at that time, then `settle` seconds at rest),
//!   each starting at rest in the path's first equilibrium (its contacts anchored as there); per
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
//! - `friction_study`: the quasi-static deployment at several pulley-friction coefficients; how
//!   far a point moves, how much rope runs over the pulleys, the tension along a clustered
//!   cable's route at the end: where a deployment stalls.

//!
//! - `globally_controlled`: global error control, for runs through instabilities that amplify
//!   what a local estimate keeps small: reruns at a tenth of the tolerance until two runs agree.
//!
//! Files: `deployment` (the study), `friction`, `work_precision`, `global`, `scaling` (step time against size); this
//! module holds what they share (dynamic runs, their CSV rows and totals, schedule scaling).

use std::fmt::Write as _;
use std::path::Path;
use std::time::Duration;

use nalgebra::Vector3;

use crate::model::Model;
use crate::report::Num;
use crate::sim::{SimSettings, Simulator, StepStats};

mod deployment;
mod friction;
mod global;
mod scaling;
mod work_precision;

pub use deployment::*;
pub use friction::*;
pub use global::*;
pub use scaling::*;
pub use work_precision::*;

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
    /// Sub-steps retried because one bar passed through another (`StepStats::pass_throughs`).
    pub pass_throughs: usize,
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
        self.pass_throughs += stats.pass_throughs;
        self.wall_time += stats.wall_time;
    }

    /// Counts every step of another run's `totals`.
    pub fn add_totals(&mut self, totals: &RunTotals) {
        self.steps += totals.steps;
        self.newton_iterations += totals.newton_iterations;
        self.rejected += totals.rejected;
        self.substeps += totals.substeps;
        self.pass_throughs += totals.pass_throughs;
        self.wall_time += totals.wall_time;
    }
}

/// Runs `model` for `duration` s with `settings`, calling `each` after every step.
pub fn run_dynamic(
    model: &Model,
    settings: SimSettings,
    duration: f64,
    each: impl FnMut(&Simulator, &StepStats) -> Result<(), String>,
) -> Result<RunTotals, String> {
    run_dynamic_from(model, None, settings, duration, each)
}

/// `run_dynamic` from `start` (a state of `model`, e.g. a static equilibrium; `None`: the
/// scene's pose at rest, `Simulator::new`).
pub fn run_dynamic_from(
    model: &Model,
    start: Option<&crate::state::State>,
    settings: SimSettings,
    duration: f64,
    mut each: impl FnMut(&Simulator, &StepStats) -> Result<(), String>,
) -> Result<RunTotals, String> {
    let mut sim = match start {
        Some(state) => Simulator::from_state(model.clone(), state.clone(), settings),
        None => Simulator::new(model.clone(), settings),
    }
    .map_err(|e| e.to_string())?;
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
    cols.extend(crate::report::contact_csv_columns(model));
    if !model.pulley_friction.is_empty() {
        cols.extend(crate::report::pulley_csv_columns(model));
        cols.push("friction_loss_J".into());
    }
    if !model.winches.is_empty() {
        for w in &model.winches {
            let name = &model.actuator_names[w.actuator.0];
            for q in ["winch_speed_m_s", "winch_setpoint_m_s", "winch_drive"] {
                cols.push(format!("{name}_{q}"));
            }
        }
        cols.extend(["motor_work_J", "winch_friction_loss_J", "winch_kinetic_J"].map(String::from));
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
    crate::report::push_contact_csv(ws, &mut row);
    if !sim.model().pulley_friction.is_empty() {
        crate::report::push_pulley_csv(sim.model(), sim.state(), ws, &mut row);
        let _ = write!(row, ",{:.9}", e.friction_loss);
    }
    if !sim.model().winches.is_empty() {
        for w in &sim.state().winches {
            let _ = write!(row, ",{:.12},{:.12},{:.9}", w.speed, w.setpoint, w.drive);
        }
        let _ = write!(row, ",{:.9},{:.9},{:.9}", e.motor_work, e.winch_friction_loss, e.winch_kinetic);
    }
    row
}

fn create(path: &Path) -> Result<std::io::BufWriter<std::fs::File>, String> {
    std::fs::File::create(path).map(std::io::BufWriter::new).map_err(|e| format!("{}: {e}", path.display()))
}

/// Runs `f` over `items` on `jobs` threads (0: one per core), results in the items' order;
/// reports each finished item (`crate::progress`, in `"runs"`).
fn parallel_map<T: Sync, R: Send>(
    items: &[T],
    jobs: usize,
    f: impl Fn(&T) -> Result<R, String> + Sync,
) -> Result<Vec<R>, String> {
    use rayon::prelude::*;
    use std::sync::atomic::{AtomicU64, Ordering};
    let pool = rayon::ThreadPoolBuilder::new().num_threads(jobs).build().map_err(|e| e.to_string())?;
    let done = AtomicU64::new(0);
    let total = Some(items.len() as u64);
    let counted = |item: &T| {
        let r = f(item);
        let done = done.fetch_add(1, Ordering::Relaxed) + 1;
        crate::progress::report(crate::progress::Report { unit: "runs", done, total, residual_n: None });
        r
    };
    crate::progress::report(crate::progress::Report { unit: "runs", done: 0, total, residual_n: None });
    pool.install(|| items.par_iter().map(counted).collect())
}
