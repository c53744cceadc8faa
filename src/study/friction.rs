//! The friction study: takes a scene with a deployment schedule and clustered cables, and
//! friction coefficients; gives, per coefficient, the quasi-static deployment of the scene with
//! that `pulley_friction` at every pulley: how far a tracked point moves, how much rope runs
//! over the pulleys, and the tension along each clustered cable's route at the end (CSVs, a
//! summary table, plots). Where the winch cannot pull rope over the pulleys the deployment
//! stalls, and the plots show it.

use std::fmt::Write as _;
use std::io::Write as _;
use std::path::Path;

use crate::evaluate::Workspace;
use crate::model::Model;
use crate::plot::{self, Chart, Series};
use crate::report;
use crate::solve::deploy::{deploy_quasi_static, PathKind};
use crate::state::State;

use super::create;

/// One friction coefficient's deployment.
#[derive(Debug, Clone, PartialEq)]
pub struct FrictionRow {
    /// The coefficient at every pulley.
    pub mu: f64,
    /// The tracked point's distance from its start at the end of the schedule, m.
    pub final_displacement: f64,
    /// The most rope that ran over any pulley since the start, at any load step, m.
    pub largest_slip: f64,
    /// Tension of each segment of the studied cable at the end, from its first anchor, N.
    pub route_tension: Vec<f64>,
    /// Newton iterations of the whole path.
    pub newton_iterations: usize,
}

/// What a friction study found.
#[derive(Debug, Clone, PartialEq)]
pub struct FrictionStudy {
    /// The tracked point.
    pub point: String,
    /// The clustered cable whose route tensions are reported (the first one an actuator drives,
    /// else the first clustered cable).
    pub cable: String,
    /// One row per coefficient, in the order given.
    pub rows: Vec<FrictionRow>,
}

impl FrictionStudy {
    /// Markdown table of the summary.
    pub fn markdown(&self) -> String {
        let mut s = format!(
            "Deployment with pulley friction: point `{}`, tensions along cable `{}` at the end.\n\n| mu | final displacement m | largest slip m | tension along the route N | Newton iterations |\n| ---: | ---: | ---: | --- | ---: |\n",
            self.point, self.cable
        );
        for r in &self.rows {
            let tensions: Vec<String> = r.route_tension.iter().map(|t| format!("{t:.3}")).collect();
            let _ = writeln!(
                s,
                "| {} | {:.6} | {:.6} | {} | {} |",
                r.mu,
                r.final_displacement,
                r.largest_slip,
                tensions.join(", "),
                r.newton_iterations
            );
        }
        s
    }
}

/// `model`'s scene with `pulley_friction = mu` at every pulley (the cables' own coefficients
/// replaced; a winch end kept only with friction).
fn with_friction(model: &Model, mu: f64) -> Result<Model, String> {
    let mut spec = crate::scene::parse(&model.source, &model.name).map_err(|e| e.to_string())?;
    spec.pulley_friction = Some(mu);
    for c in &mut spec.cables {
        c.pulley_friction = None;
        if mu == 0.0 {
            c.winch_end = None;
        }
    }
    crate::scene::build_model(&spec, &model.name, None).map_err(|e| e.to_string())
}

/// Runs the quasi-static deployment of `model` with each coefficient of `mus` (>= 0) and writes
/// `friction_path.csv` (mu, schedule time, displacement of `point`, largest slip so far),
/// `friction_route_tension.csv` (mu, segment, tension at the end) and the plots
/// `friction_deployment` and `friction_route_tension` (PNG and SVG) into `out_dir`. `point`
/// defaults to the point that moves most without friction.
pub fn friction_study(
    model: &Model,
    mus: &[f64],
    point: Option<&str>,
    out_dir: &Path,
) -> Result<FrictionStudy, String> {
    std::fs::create_dir_all(out_dir).map_err(|e| format!("{}: {e}", out_dir.display()))?;
    if model.schedule.ramps.is_empty() {
        return Err(format!("scene '{}' has no deployment schedule to study", model.name));
    }
    if mus.is_empty() || mus.iter().any(|m| !(m.is_finite() && *m >= 0.0)) {
        return Err("friction coefficients must be finite and >= 0".into());
    }
    let clustered: Vec<usize> =
        (0..model.cables.len()).filter(|&c| model.cables[c].pulley_count() > 0).collect();
    let cable = clustered
        .iter()
        .copied()
        .find(|&c| model.actuators.iter().any(|a| a.cable.0 == c))
        .or(clustered.first().copied())
        .ok_or_else(|| format!("scene '{}' has no cable with pulleys", model.name))?;
    let point = match point {
        Some(p) => model.point_id(p).ok_or_else(|| format!("unknown point '{p}'"))?,
        None => most_moving_point(&with_friction(model, 0.0)?)?,
    };
    let end = model.schedule.end_time();
    let mut path_csv = create(&out_dir.join("friction_path.csv"))?;
    writeln!(path_csv, "mu,time_s,displacement_m,largest_slip_m").map_err(|e| e.to_string())?;
    let mut tension_csv = create(&out_dir.join("friction_route_tension.csv"))?;
    writeln!(tension_csv, "mu,segment,tension_N").map_err(|e| e.to_string())?;
    let (mut rows, mut paths, mut routes) = (Vec::new(), Vec::new(), Vec::new());
    for &mu in mus {
        let m = with_friction(model, mu)?;
        let mut state = State::initial(&m);
        let mut ws = Workspace::new(&m);
        let mut start = None;
        let (mut path, mut slip, mut displacement) = (Vec::new(), 0.0f64, 0.0);
        let result = deploy_quasi_static(&m, &mut state, &mut ws, |step, st, w| {
            if step.kind == PathKind::ArcLength {
                return;
            }
            let at = w.points[point.0].position;
            let from = *start.get_or_insert(at);
            displacement = (at - from).norm();
            for c in 0..m.cables.len() {
                for p in report::pulley_reports(&m, st, w, c) {
                    slip = slip.max(p.slip_m.abs());
                }
            }
            let _ = writeln!(path_csv, "{mu},{:.9},{:.12},{:.12e}", st.time, displacement, slip);
            path.push((st.time / end, displacement));
        })
        .map_err(|e| format!("mu {mu}: {e}"))?;
        crate::evaluate::evaluate_forces(&m, &state, &mut ws);
        let route_tension: Vec<f64> = match m.cables[cable].friction {
            Some(f) => {
                let o = m.pulley_friction[f].segment_offset;
                ws.friction.tensions[o..o + m.cables[cable].segment_count()].to_vec()
            }
            None => vec![ws.cables[cable].tension; m.cables[cable].segment_count()],
        };
        for (k, t) in route_tension.iter().enumerate() {
            let _ = writeln!(tension_csv, "{mu},{},{t:.9}", k + 1);
        }
        paths.push(Series::new(format!("mu = {mu}"), path, false));
        let points = route_tension.iter().enumerate().map(|(k, t)| ((k + 1) as f64, *t)).collect();
        routes.push(Series::new(format!("mu = {mu}"), points, true));
        rows.push(FrictionRow {
            mu,
            final_displacement: displacement,
            largest_slip: if slip > 1e-12 * m.initial_rest_lengths[cable] { slip } else { 0.0 },
            route_tension,
            newton_iterations: result.steps.iter().map(|s| s.report.iterations).sum(),
        });
    }
    path_csv.flush().map_err(|e| e.to_string())?;
    tension_csv.flush().map_err(|e| e.to_string())?;
    let name = &model.points[point.0].name;
    let chart = |title: String, x: &str, y: &str, series: Vec<Series>| Chart {
        title,
        x_label: x.into(),
        y_label: y.into(),
        log_x: false,
        log_y: false,
        series,
        reference: None,
        ordered: true,
    };
    plot::write(
        &chart(
            format!("{}: quasi-static deployment with pulley friction", model.name),
            "fraction of the schedule",
            &format!("displacement of {name}, m"),
            paths,
        ),
        &out_dir.join("friction_deployment"),
    )?;
    plot::write(
        &chart(
            format!("{}: tension along '{}' at the end", model.name, model.cable_names[cable]),
            "segment, from the first anchor",
            "tension, N",
            routes,
        ),
        &out_dir.join("friction_route_tension"),
    )?;
    Ok(FrictionStudy { point: name.clone(), cable: model.cable_names[cable].clone(), rows })
}

/// The point that moves most along `model`'s quasi-static deployment.
fn most_moving_point(model: &Model) -> Result<crate::model::PointId, String> {
    let mut state = State::initial(model);
    let mut ws = Workspace::new(model);
    let mut start: Vec<nalgebra::Vector3<f64>> = Vec::new();
    let mut moved = vec![0.0f64; model.points.len()];
    deploy_quasi_static(model, &mut state, &mut ws, |step, _, w| {
        if step.kind == PathKind::ArcLength {
            return;
        }
        if start.is_empty() {
            start = w.points.iter().map(|p| p.position).collect();
        }
        for (i, p) in w.points.iter().enumerate() {
            moved[i] = moved[i].max((p.position - start[i]).norm());
        }
    })
    .map_err(|e| e.to_string())?;
    let best = (0..moved.len()).max_by(|&a, &b| moved[a].total_cmp(&moved[b])).unwrap_or(0);
    Ok(crate::model::PointId(best))
}
