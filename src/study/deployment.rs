//! The deployment study: the quasi-static path and one dynamic deployment per actuation time,
//! their peak tensions and displacements and how far they depart from the path (CSVs, a summary
//! table, plots).

use std::fmt::Write as _;
use std::io::Write as _;
use std::path::Path;

use nalgebra::Vector3;

use crate::evaluate::Workspace;
use crate::model::Model;
use crate::plot::{self, Chart, Series};
use crate::report;
use crate::sim::SimSettings;
use crate::solve::deploy::deploy_quasi_static;
use crate::state::State;

use super::{
    create, dynamic_csv_header, dynamic_csv_row, parallel_map, rigidly_aligned, run_dynamic_from,
    scale_schedule, within_rate_limits,
};

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
    /// Where the quasi-static path ends before the schedule does (a robot that tips over has no
    /// equilibrium past its limit point): the fraction of the schedule it reached and why it
    /// stopped. The runs are then compared up to that fraction of their own schedules, and
    /// their peaks are taken there. `None` when the path reaches the schedule's end. A path
    /// that gave up holding its contacts (`contacts_released`) ends at its last load step that
    /// held them.
    pub path_end: Option<PathEnd>,
    /// Schedule time (s) of the first load step at which the quasi-static path could not hold
    /// its stick-slip contacts (`PathStep::contacts_held`): from there on it slides where the
    /// dynamic runs' feet stick, so the comparison ends before it (`path_end`). `None` when it
    /// held them throughout (or has none).
    pub contacts_released: Option<f64>,
}

/// Where a study's quasi-static path stopped short of the schedule's end.
#[derive(Debug, Clone, PartialEq)]
pub struct PathEnd {
    /// Fraction of the schedule (time over the schedule's end) at the last equilibrium, in
    /// (0, 1).
    pub fraction: f64,
    /// The solve's error at the next load step.
    pub reason: String,
}

impl StudyResult {
    /// Markdown table of the summary.
    pub fn markdown(&self) -> String {
        let mut s = format!(
            "Quasi-static peak tension {:.4} N, peak displacement of `{}` {:.6} m{}.\n\n",
            self.qs_peak_tension,
            self.point,
            self.qs_peak_displacement,
            if self.rigid_motion_removed {
                " (free-floating scene: displacements after removing the rigid-body motion by optimal rigid alignment)"
            } else {
                ""
            }
        );
        if let Some(t) = self.contacts_released {
            let _ = writeln!(
                s,
                "From t = {} s on, the quasi-static path could not hold its contacts (statics did not converge with them sticking and slipping) and solved each load step with them set down afresh: its feet slide where the dynamic runs' stick, so the study compares up to the last load step that held them.\n",
                rounded(t)
            );
        }
        if let Some(end) = &self.path_end {
            let _ = writeln!(
                s,
                "The quasi-static path ends at {:.1} % of the schedule ({}): every run is compared with it up to that fraction of its own schedule, and its peaks are taken there.\n",
                100.0 * end.fraction,
                end.reason
            );
        }
        s.push_str("| actuation time s | peak tension N | deviation % | peak displacement m | deviation % | within max_rate | wall time s |\n| ---: | ---: | ---: | ---: | ---: | :---: | ---: |\n");
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
    let mut contacts_released = None;
    let mut equilibrium_start: Option<State> = None;
    // the last load step compared (time, stable), and its ground contacts' normal forces
    let mut last_held: Option<(f64, bool)> = None;
    let mut last_normal_forces: Vec<f64> = Vec::new();
    let path = deploy_quasi_static(model, &mut state, &mut ws, |step, st, w| {
        if equilibrium_start.is_none() {
            equilibrium_start = Some(st.clone());
        }
        if !step.contacts_held && contacts_released.is_none() {
            contacts_released = Some(step.time);
        }
        let row = report::path_csv_row(model, st, w, step);
        let _ = writeln!(qs_file, "{row}");
        if step.kind == crate::solve::deploy::PathKind::ArcLength || !step.contacts_held {
            // points traced through a limit point are not states the structure rests in, and
            // a path that set its contacts down afresh slides where held feet stick: the
            // comparison ends at the last load step that held them
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
        last_held = Some((st.time, step.report.stable));
        last_normal_forces.clear();
        last_normal_forces.extend(w.contacts[..model.ground_pairs()].iter().map(|c| c.normal_force));
    });
    qs_file.flush().map_err(|e| e.to_string())?;
    // a path that stops short (a robot tips over its edge: no equilibrium past the limit
    // point) is compared up to where it got; one that found no first equilibrium is an error
    let unloading = unloading_contacts(model, &last_normal_forces);
    let cause = match (path, contacts_released) {
        (Ok(_), None) => None,
        (_, Some(_)) => Some(
            "statics found no equilibrium holding the stick-slip contacts, even in the smallest load step"
                .to_string(),
        ),
        (Err(e), None) => Some(e.to_string()),
    };
    let reason = cause.map(|cause| match last_held {
        Some((t, _)) if !unloading.is_empty() => format!(
            "{cause}; at its last load step (t = {} s) {unloading}: past it the structure tips over its other contacts",
            rounded(t)
        ),
        Some((t, stable)) if contacts_released.is_some() => format!(
            "past t = {} s {cause}{}",
            rounded(t),
            if stable { "" } else { "; the equilibrium there is unstable: a limit point, where the structure tips" }
        ),
        _ => cause,
    });
    let path_end = match reason {
        None => None,
        Some(reason) => match qs_tension.last() {
            Some(&(fraction, _)) if fraction > 0.0 => Some(PathEnd { fraction, reason }),
            _ => return Err(format!("the quasi-static path has no load step to compare with: {reason}")),
        },
    };
    let compared = path_end.as_ref().map_or(f64::INFINITY, |p| p.fraction);
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

    // every time-scaled run starts at rest where the quasi-static path starts (its first
    // equilibrium, with its contacts' anchors): one start position for all
    let dynamic_start: &[Vector3<f64>] = &start_pos;
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
        // a path that ends short: the run up to there, and no settling (past the quasi-static
        // path's end the robot tips over)
        let duration = if compared.is_finite() { compared * t_ramp } else { t_ramp + settle };
        let totals = run_dynamic_from(&m, equilibrium_start.as_ref(), settings, duration, |sim, stats| {
            writeln!(file, "{}", dynamic_csv_row(sim, stats)).map_err(|e| e.to_string())?;
            let w = sim.workspace();
            let t_max = w.cables.iter().map(|c| c.tension).fold(0.0, f64::max);
            peak_t = peak_t.max(t_max);
            let d = if free {
                let now = shape(w.points.iter().map(|p| p.position).collect(), dynamic_start);
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
        path_end,
        contacts_released,
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
            title: match &result.path_end {
                None => format!("{}: dynamic vs quasi-static deployment", model.name),
                Some(end) => format!(
                    "{}: dynamic vs quasi-static deployment, up to {:.1} % of the schedule (the path's end)",
                    model.name,
                    100.0 * end.fraction
                ),
            },
            x_label: "actuation time (s)".into(),
            y_label: "|deviation| (%)".into(),
            log_x: true,
            log_y: true,
            series: vec![
                dev_series("peak tension", &|r| r.tension_deviation),
                dev_series(&format!("peak displacement of {point}"), &|r| r.displacement_deviation),
            ],
            reference: Some((1.0, "1 %".into())),
            ordered: false,
        },
        &out_dir.join("deviation"),
    )?;
    plot::write(
        &Chart {
            title: format!("{}: largest cable tension, one run per actuation time T", model.name),
            x_label: "time / actuation time T (shown to 2.5)".into(),
            y_label: "largest tension (N)".into(),
            log_x: false,
            log_y: false,
            series: histories,
            reference: None,
            ordered: true,
        },
        &out_dir.join("histories"),
    )?;
    Ok(result)
}

/// `t` to 9 decimals, without the round-off digits of a sum of load steps (1.826, not
/// 1.8260000000000003).
fn rounded(t: f64) -> f64 {
    (t * 1e9).round() / 1e9
}

/// The ground contacts (`normal_forces` in `Model::contact_labels` order, N) that carry under 2 %
/// of the most loaded one's normal force, but something (a foot about to lift: past it a robot
/// tips over its other feet), as `` `y0.b@floor` carries 0.079 N (the most loaded 11.265 N) ``;
/// empty when none.
fn unloading_contacts(model: &Model, normal_forces: &[f64]) -> String {
    let most = normal_forces.iter().copied().fold(0.0, f64::max);
    let light: Vec<String> = normal_forces
        .iter()
        .zip(model.contact_labels())
        .filter(|(f, _)| **f > 0.0 && **f < 0.02 * most)
        .map(|(f, (point, ground))| format!("`{point}@{ground}` carries {f:.3} N"))
        .collect();
    if light.is_empty() {
        return String::new();
    }
    format!("{} (the most loaded {most:.3} N)", light.join(", "))
}
