//! The work-precision benchmark: one deployment over integrators, step sizes and tolerances,
//! each run's error against a converged reference and its median wall time (table and plot).

use std::fmt::Write as _;
use std::io::Write as _;
use std::path::Path;
use std::time::Instant;

use crate::model::Model;
use crate::plot::{self, Chart, Series};
use crate::sim::SimSettings;
use crate::solve::dynamics::Integrator;
use crate::state::State;

use super::{create, parallel_map, run_dynamic, RunTotals};

/// One run of the work-precision benchmark: an integrator at a fixed step, or under error
/// control with a tolerance (then it steps between samples as its estimate decides), local or
/// global (`globally_controlled`: reruns at a tenth of the tolerance until two runs agree).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RunConfig {
    /// Integrator.
    pub integrator: Integrator,
    /// Fixed step, s (`None`: error-controlled).
    pub dt: Option<f64>,
    /// Error tolerance, m (error-controlled runs): local, or global with `global`.
    pub tolerance: Option<f64>,
    /// Global error control (`globally_controlled`); its cost counts every run it makes.
    pub global: bool,
    /// Newton tolerance (`NewtonSettings::tolerance`); `None`: the default.
    pub newton_tolerance: Option<f64>,
}

impl RunConfig {
    /// A fixed-step run.
    pub fn fixed(integrator: Integrator, dt: f64) -> Self {
        Self { integrator, dt: Some(dt), tolerance: None, global: false, newton_tolerance: None }
    }
    /// An error-controlled run.
    pub fn controlled(integrator: Integrator, tolerance: f64) -> Self {
        Self { integrator, dt: None, tolerance: Some(tolerance), global: false, newton_tolerance: None }
    }
    /// A run under global error control.
    pub fn globally_controlled(integrator: Integrator, tolerance: f64) -> Self {
        Self { global: true, ..Self::controlled(integrator, tolerance) }
    }
    /// The same run with Newton stopped at `tolerance` (relative, `NEWTON_TOLERANCE_RANGE`).
    pub fn with_newton_tolerance(self, tolerance: f64) -> Self {
        Self { newton_tolerance: Some(tolerance), ..self }
    }
    /// Simulator settings with `sample` (s) the output interval of an error-controlled run.
    fn settings(&self, sample: f64) -> SimSettings {
        let mut settings = SimSettings {
            dt: self.dt.unwrap_or(sample),
            integrator: self.integrator,
            tolerance: self.tolerance,
            ..Default::default()
        };
        if let Some(t) = self.newton_tolerance {
            settings.newton.tolerance = t;
        }
        settings
    }
    /// The row's name: the integrator, `(tol)` or `(global)` when error-controlled, and a Newton
    /// tolerance other than the default.
    fn label(&self) -> String {
        let mut name = match (self.tolerance, self.global) {
            (Some(_), true) => format!("{} (global)", self.integrator.name()),
            (Some(_), false) => format!("{} (tol)", self.integrator.name()),
            (None, _) => self.integrator.name(),
        };
        if let Some(t) = self.newton_tolerance {
            name.push_str(&format!(" newton {t:e}"));
        }
        name
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

/// Every point's position every `sample` seconds of a run of `duration` s with `settings`
/// (`run_dynamic`; `sample` a whole number of `settings.dt`, the output interval of an
/// error-controlled run), and the run's totals.
pub fn sampled_positions(
    model: &Model,
    settings: SimSettings,
    duration: f64,
    sample: f64,
) -> Result<(super::PointSamples, RunTotals), String> {
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

/// The looser Newton tolerance `bench work-precision` gives rows of its own (generalized-alpha at
/// every fixed step): the speed a user may trade for it on a robot on the ground.
pub const LOOSE_NEWTON_TOLERANCE: f64 = 1e-6;

/// The runs `bench work-precision` makes on `model` (the command line and the Python library
/// both take them from here): generalized-alpha (rho_inf 0.8 and 0, and 0.8 at the looser Newton
/// tolerance) at fixed steps from 10 ms to 0.25 ms; symplectic Euler, RK4 and Dormand-Prince at
/// the fixed steps where each can be stable; Dormand-Prince (scenes without contacts: its error
/// estimate does not see impacts) and generalized-alpha at each of `tolerances` (m); and with
/// `global`, generalized-alpha under global error control at each.
pub fn work_precision_runs(model: &Model, tolerances: &[f64], global: bool) -> Vec<RunConfig> {
    let steps = [1e-2, 5e-3, 2e-3, 1e-3, 5e-4, 2.5e-4];
    let ga = Integrator::GeneralizedAlpha { rho_inf: 0.8 };
    let fixed =
        |i: Integrator, dts: &[f64]| dts.iter().map(move |&dt| RunConfig::fixed(i, dt)).collect::<Vec<_>>();
    let mut configs = fixed(ga, &steps);
    configs.extend(fixed(Integrator::GeneralizedAlpha { rho_inf: 0.0 }, &steps));
    configs.extend(fixed(ga, &steps).into_iter().map(|c| c.with_newton_tolerance(LOOSE_NEWTON_TOLERANCE)));
    configs.extend(fixed(Integrator::SymplecticEuler, &[5e-3, 2e-3, 1e-3, 5e-4, 2.5e-4, 1e-4, 5e-5, 2.5e-5]));
    configs.extend(fixed(Integrator::Rk4, &[1e-2, 5e-3, 4e-3, 2e-3, 1e-3, 5e-4, 2.5e-4]));
    configs.extend(fixed(Integrator::DormandPrince, &[5e-3, 2e-3, 1e-3, 5e-4, 2.5e-4]));
    if model.contact_pairs() == 0 {
        configs.extend(tolerances.iter().map(|&t| RunConfig::controlled(Integrator::DormandPrince, t)));
    }
    configs.extend(tolerances.iter().map(|&t| RunConfig::controlled(ga, t)));
    if global {
        configs.extend(tolerances.iter().map(|&t| RunConfig::globally_controlled(ga, t)));
    }
    configs
}

/// Work-precision settings besides the runs.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WorkPrecisionSettings {
    /// Fixed step of the reference run, s.
    pub reference_dt: f64,
    /// Integrator of the reference run: Dormand-Prince for smooth motion; generalized-alpha where
    /// an explicit step that small is refused (ground contact: every contact pressed in counts
    /// for the stability limit).
    pub reference_integrator: Integrator,
    /// Simulated time, s.
    pub duration: f64,
    /// Sample interval of the error (and output interval of error-controlled runs), s.
    pub sample: f64,
    /// Timed repeats per run (the median is reported).
    pub repeats: usize,
    /// Threads for the error runs (0: one per core); timing runs one at a time.
    pub jobs: usize,
}

/// Runs the work-precision benchmark: every run of `configs` against a fixed-step reference
/// (`reference_integrator` at `reference_dt`); error = largest point distance from the reference over the samples (after
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
    let WorkPrecisionSettings { reference_dt, reference_integrator, duration, sample, repeats, jobs } = bench;
    if !(sample > 0.0 && reference_dt > 0.0 && reference_dt <= sample && duration >= sample) {
        return Err(format!(
            "the reference step ({reference_dt} s) must be positive and at most the sample interval ({sample} s), itself at most the duration ({duration} s)"
        ));
    }
    let reference_settings =
        SimSettings { dt: reference_dt, integrator: reference_integrator, ..Default::default() };
    let (reference, _) = sampled_positions(model, reference_settings, duration, sample)
        .map_err(|e| format!("reference run ({} at {reference_dt} s): {e}", reference_integrator.name()))?;
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
    // a structure held by nothing drifts differently under each integrator: compare shapes,
    // after the optimal rigid alignment onto the reference
    let free = model.is_free_floating();
    let run = |c: &RunConfig| match (c.global, c.tolerance) {
        (true, Some(tolerance)) => super::globally_controlled(tolerance, free, |t| {
            sampled_positions(
                model,
                RunConfig { tolerance: Some(t), ..*c }.settings(sample),
                duration,
                sample,
            )
        })
        .map(|g| (g.samples, g.totals)),
        _ => sampled_positions(model, c.settings(sample), duration, sample),
    };
    // errors on all cores
    let accuracy = parallel_map(&runs, jobs, |c| {
        let (samples, totals) = run(c).map_err(|e| format!("{}: {e}", c.label()))?;
        Ok((super::largest_distance(&samples, &reference, free), totals))
    })?;
    // timings one at a time
    let mut rows = Vec::new();
    for (c, (error, totals)) in runs.iter().zip(accuracy) {
        let mut walls = Vec::new();
        for _ in 0..repeats.max(1) {
            let begin = Instant::now();
            run(c)?;
            walls.push(begin.elapsed().as_secs_f64());
        }
        walls.sort_by(f64::total_cmp);
        rows.push(WorkPrecisionRow {
            integrator: c.label(),
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
    let WorkPrecisionSettings { reference_dt, reference_integrator, duration, sample, repeats, .. } = bench;
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
        "Reference: {} at dt = {reference_dt:e} s; error = largest distance of any point from the reference{}, sampled every {sample} s over {duration} s; wall time = median of {repeats} runs, one at a time; error-controlled runs (tol) step between samples as their estimate decides. Stability limits of the explicit integrators at the start: {}.\n\n| integrator | dt s | tolerance m | max point error m | median wall time s | steps | rejected | Newton iterations / step |\n| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: |\n",
        reference_integrator.name(),
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
            ordered: false,
        },
        &out_dir.join("work_precision"),
    )?;
    Ok(())
}
