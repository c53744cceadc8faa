//! Per-cable and per-body outputs of an evaluated state: takes `Model`, `State` and the evaluated
//! `Workspace`, gives `CableReport` (tension, length, rest length, strain, slack flag, segment
//! lengths, pulley slip), `ContactReport` (per contact sphere and ground: in contact, gap,
//! forces, slip) and body poses, plus the JSON/CSV writers the CLI uses.

use serde::Serialize;

use crate::evaluate::Workspace;
use crate::forces::contact::FrictionState;
use crate::model::Model;
use crate::state::State;

/// What one cable is doing, for output.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct CableReport {
    /// Cable name.
    pub name: String,
    /// Tension, N.
    pub tension: f64,
    /// Total length, m.
    pub length: f64,
    /// Rest length, m.
    pub rest_length: f64,
    /// Strain `(L - L0) / L0`.
    pub strain: f64,
    /// True when `L <= L0`.
    pub slack: bool,
    /// True for a member compressed past its buckling load (`forces::cable::is_buckled`).
    pub buckled: bool,
    /// Segment lengths, m, from the first anchor.
    pub segment_lengths: Vec<f64>,
    /// Cable passed through each pulley since `reference` (m, positive towards the last anchor):
    /// under uniform strain the rest length between the first anchor and pulley `i` is
    /// `s_i = L0 sum_(k<=i) l_k / L`; slip is the change of `s_i` (the cable is taken as reeled at
    /// its last anchor). With pulley friction: `PulleyReport::slip_m` (since t = 0).
    pub pulley_slip: Vec<f64>,
    /// Each pulley's friction state, for a cable whose pulleys have friction (empty otherwise;
    /// then `tension` is the tension of the segment at the cable's winch end).
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub pulleys: Vec<PulleyReport>,
}

/// What one pulley with friction does (`crate::forces::pulley`), for output.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct PulleyReport {
    /// The route point the pulley is.
    pub point: String,
    /// `stick`, `slip-start` (the cable slips toward the route's first anchor), `slip-end`,
    /// `free` (mu = 0) or `slack`.
    pub state: &'static str,
    /// True when its tension ratio is at the capstan bound `exp(mu theta)` (within 1e-9): a
    /// pulley that has just slipped into an equilibrium sticks there at its limit.
    pub at_limit: bool,
    /// Friction coefficient.
    pub mu: f64,
    /// Wrap angle, rad.
    pub wrap_angle_rad: f64,
    /// Tension of the segment before the pulley (toward the first anchor), N.
    pub tension_before_n: f64,
    /// Tension of the segment after it, N.
    pub tension_after_n: f64,
    /// Cable that ran through it since t = 0, m (positive toward the last anchor, as
    /// `CableReport::pulley_slip`; what the winch wound in or paid out is not slip).
    pub slip_m: f64,
    /// Its rate over the last accepted step, m/s (positive toward the last anchor; 0 after a
    /// static solve).
    pub slip_speed_m_s: f64,
}

impl PulleyReport {
    /// Tension after the pulley over tension before it (`crate::forces::pulley::tension_ratio`).
    pub fn tension_ratio(&self) -> f64 {
        crate::forces::pulley::tension_ratio(self.tension_before_n, self.tension_after_n)
    }
}

/// The pulley reports of cable `c` (empty when its pulleys have no friction).
pub fn pulley_reports(model: &Model, state: &State, ws: &Workspace, c: usize) -> Vec<PulleyReport> {
    let Some(f) = model.cables[c].friction else {
        return Vec::new();
    };
    let f = &model.pulley_friction[f];
    let route = model.route(crate::model::CableId(c));
    let (now, initial) = (&state.segment_rest_lengths, &model.initial_segment_rest_lengths);
    let wound = state.rest_lengths[c] - model.initial_rest_lengths[c];
    let mut crossed = 0.0;
    (0..f.mu.len())
        .map(|i| {
            let p = ws.friction.pulley(f, i);
            crossed += now[f.segment_offset + i] - initial[f.segment_offset + i];
            let (before, after) = (p.tension_before, p.tension_after);
            let bound = (f.mu[i] * p.wrap_angle).exp();
            let ratio = if before > 0.0 && after > 0.0 { (before / after).max(after / before) } else { 0.0 };
            PulleyReport {
                point: model.points[route[i + 1].0].name.clone(),
                state: p.state.as_str(),
                at_limit: f.mu[i] > 0.0 && (ratio - bound).abs() <= 1e-9 * bound,
                mu: f.mu[i],
                wrap_angle_rad: p.wrap_angle,
                tension_before_n: before,
                tension_after_n: after,
                // (0.0 - x: no negative zero in the outputs)
                slip_m: 0.0 - (crossed - if f.fed_segment <= i { wound } else { 0.0 }),
                slip_speed_m_s: p.slip_speed,
            }
        })
        .collect()
}

/// What one contact sphere is doing against one ground (or one bar against another), for
/// output.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ContactReport {
    /// The sphere's centre point (`body.point`, or `body` for a node); for two struts, the first
    /// bar.
    pub point: String,
    /// The ground's name; for two struts, the second bar.
    pub ground: String,
    /// True while the sphere presses into the ground (the capsules into each other).
    pub in_contact: bool,
    /// Signed distance of the sphere's surface from the ground (between the capsules' surfaces),
    /// m (negative: pressed in).
    pub gap_m: f64,
    /// Contact point: the sphere's centre projected on the ground (the middle of the two axes'
    /// closest points), m.
    pub position_m: [f64; 3],
    /// The ground's outward normal (from the second bar toward the first).
    pub normal: [f64; 3],
    /// Normal force on the body (the first bar), N (>= 0).
    pub normal_force_n: f64,
    /// Friction force on the body (the first bar), N, world frame.
    pub friction_n: [f64; 3],
    /// Slip speed of the contact point along the ground (of one bar along the other), m/s (0
    /// while rolling on a ground).
    pub slip_speed_m_s: f64,
    /// What the friction does (`FrictionState::as_str`): `open` (not pressed in),
    /// `frictionless` (mu = 0), `regularized` (the regularized law: no stuck state, no friction
    /// in statics), and under stick-slip friction `stick` or `slip`.
    pub friction_state: &'static str,
    /// On the cone's edge, stick-slip law: `|F_t|` within 1e-9 of `mu F_n` (a contact that has
    /// just slipped into an equilibrium sits there; round-off decides whether its return map
    /// then says `stick` or `slip`), as a pulley's `at_limit`.
    pub at_limit: bool,
    /// The friction cone's radius `mu F_n`, N.
    pub friction_limit_n: f64,
}

/// Every contact of `model` (`Model::contact_pairs` order: ground pairs sphere-major, then strut
/// pairs) from the evaluated `ws`.
pub fn contact_reports(model: &Model, ws: &Workspace) -> Vec<ContactReport> {
    let mut out = Vec::with_capacity(model.contact_pairs());
    for (((point, ground), c), mu) in
        model.contact_labels().zip(&ws.contacts).zip(model.contact_friction_coefficients())
    {
        let limit = mu * c.normal_force;
        out.push(ContactReport {
            point: point.to_string(),
            ground: ground.to_string(),
            in_contact: c.in_contact(),
            gap_m: c.gap,
            position_m: c.position.into(),
            normal: c.normal.into(),
            normal_force_n: c.normal_force,
            friction_n: c.friction.into(),
            slip_speed_m_s: c.slip.norm(),
            friction_state: c.friction_state.as_str(),
            at_limit: matches!(c.friction_state, FrictionState::Stuck | FrictionState::Slipping)
                && limit > 0.0
                && (c.friction.norm() - limit).abs() <= 1e-9 * limit,
            friction_limit_n: limit,
        });
    }
    out
}

/// Column names of the contacts in a CSV: per pair `{point}@{ground}_normal_force_N`,
/// `_friction_N` (magnitude) and `_slip_m_s` (slip speed), for strut pairs `{bar}@{bar}_...`;
/// none without contacts.
pub fn contact_csv_columns(model: &Model) -> Vec<String> {
    let mut cols = Vec::new();
    for (point, ground) in model.contact_labels() {
        let pair = format!("{point}@{ground}");
        for what in ["normal_force_N", "friction_N", "slip_m_s"] {
            cols.push(format!("{pair}_{what}"));
        }
    }
    cols
}

/// CSV columns of the pulleys with friction, four per pulley `{cable}@{point}`: `_slipping`
/// (+1 slipping toward the last anchor, -1 toward the first, 0 otherwise), `_tension_ratio`
/// (after over before; 0 when either side is slack), `_slip_m` (since t = 0, positive toward the
/// last anchor) and `_slip_m_s`; none without friction.
pub fn pulley_csv_columns(model: &Model) -> Vec<String> {
    let mut cols = Vec::new();
    for f in &model.pulley_friction {
        let route = model.route(f.cable);
        for i in 0..f.mu.len() {
            let pulley = format!("{}@{}", model.cable_names[f.cable.0], model.points[route[i + 1].0].name);
            for what in ["slipping", "tension_ratio", "slip_m", "slip_m_s"] {
                cols.push(format!("{pulley}_{what}"));
            }
        }
    }
    cols
}

/// Appends the columns of `pulley_csv_columns` to a CSV row.
pub fn push_pulley_csv(model: &Model, state: &State, ws: &Workspace, row: &mut String) {
    use std::fmt::Write;
    for f in &model.pulley_friction {
        for p in pulley_reports(model, state, ws, f.cable.0) {
            let slipping = match p.state {
                "slip-end" => 1,
                "slip-start" => -1,
                _ => 0,
            };
            let ratio = p.tension_ratio();
            let _ = write!(row, ",{slipping},{:.12},{:.12e},{:.9e}", ratio, p.slip_m, p.slip_speed_m_s);
        }
    }
}

/// Appends the contact columns of `contact_csv_columns` to a CSV row.
pub fn push_contact_csv(ws: &Workspace, row: &mut String) {
    use std::fmt::Write;
    for c in &ws.contacts {
        let _ = write!(row, ",{:.9e},{:.9e},{:.9e}", c.normal_force, c.friction.norm(), c.slip.norm());
    }
}

/// Displays a number as `f64` does (honouring width, alignment, precision and `+`), except that a
/// value that rounds to zero never shows a sign: `-0.000000` and `+0.000` print as `0.000000` and
/// `0.000`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Num(pub f64);

impl std::fmt::Display for Num {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let mut s = match (f.precision(), f.sign_plus()) {
            (Some(p), false) => format!("{:.*}", p, self.0),
            (Some(p), true) => format!("{:+.*}", p, self.0),
            (None, false) => format!("{}", self.0),
            (None, true) => format!("{:+}", self.0),
        };
        if s.starts_with(['-', '+']) && s[1..].chars().all(|c| c == '0' || c == '.') {
            s.remove(0);
        }
        match (f.width(), f.align()) {
            (Some(w), Some(std::fmt::Alignment::Left)) => write!(f, "{s:<w$}"),
            (Some(w), Some(std::fmt::Alignment::Center)) => write!(f, "{s:^w$}"),
            (Some(w), _) => write!(f, "{s:>w$}"),
            (None, _) => f.write_str(&s),
        }
    }
}

/// Rest-length material coordinate `s_i` of each pulley of cable `c` (see `CableReport`).
pub fn pulley_coordinates(model: &Model, ws: &Workspace, rest_length: f64, c: usize) -> Vec<f64> {
    let seg = ws.cable_segments(model, c);
    let total: f64 = seg.iter().sum();
    let mut acc = 0.0;
    let mut out = Vec::with_capacity(seg.len().saturating_sub(1));
    for l in &seg[..seg.len() - 1] {
        acc += l;
        out.push(if total > 0.0 { rest_length * acc / total } else { 0.0 });
    }
    out
}

/// Reports of every cable. `reference` holds each cable's pulley coordinates at the start
/// (from `pulley_coordinates`), for the slip.
pub fn cable_reports(
    model: &Model,
    state: &State,
    ws: &Workspace,
    reference: &[Vec<f64>],
) -> Vec<CableReport> {
    (0..model.cables.len())
        .map(|c| {
            let r = &ws.cables[c];
            let now = pulley_coordinates(model, ws, state.rest_lengths[c], c);
            let pulleys = pulley_reports(model, state, ws, c);
            let pulley_slip = if pulleys.is_empty() {
                now.iter().zip(&reference[c]).map(|(a, b)| a - b).collect()
            } else {
                // with friction the material on each segment is known: no uniform-strain guess
                pulleys.iter().map(|p| p.slip_m).collect()
            };
            CableReport {
                name: model.cable_names[c].clone(),
                tension: r.tension,
                length: r.length,
                rest_length: r.rest_length,
                strain: (r.length - r.rest_length) / r.rest_length,
                slack: r.slack,
                buckled: crate::forces::cable::is_buckled(&model.cables[c], r.rest_length, r.length),
                segment_lengths: ws.cable_segments(model, c).to_vec(),
                pulley_slip,
                pulleys,
            }
        })
        .collect()
}

/// Pulley coordinates of every cable (the slip reference).
pub fn all_pulley_coordinates(model: &Model, state: &State, ws: &Workspace) -> Vec<Vec<f64>> {
    (0..model.cables.len()).map(|c| pulley_coordinates(model, ws, state.rest_lengths[c], c)).collect()
}

/// A body's pose, for output.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct BodyReport {
    /// Body name.
    pub name: String,
    /// Centre of mass, m.
    pub position: [f64; 3],
    /// Orientation quaternion `[w, x, y, z]`.
    pub orientation: [f64; 4],
}

/// Poses of every body.
pub fn body_reports(model: &Model, state: &State) -> Vec<BodyReport> {
    model
        .bodies
        .iter()
        .zip(&state.poses)
        .map(|(b, p)| {
            let q = p.rotation.quaternion();
            BodyReport {
                name: b.name.clone(),
                position: p.position.into(),
                orientation: [q.w, q.i, q.j, q.k],
            }
        })
        .collect()
}

/// What a joint does to the structure at a state, for output.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct JointReport {
    /// `ball`, `pin`, `roller`, `slider`, `hinge` or `planar`.
    pub kind: &'static str,
    /// The joint's point `a`.
    pub point: String,
    /// For a ball joint, the point `b` it holds `a` on (empty for supports).
    pub other: String,
    /// The force the joint exerts on the body of `a`, N, world frame (`-D^T lambda`): for a
    /// support, its reaction; a roller's has no part along its line, a slider's none in its plane.
    pub force_n: [f64; 3],
    /// The moment the joint exerts on the body of `a`, N m, world frame: a hinge's or planar
    /// joint's axis rows (`-D^T lambda`, normal to the axis); zero for joints that hold no axis.
    pub moment_nm: [f64; 3],
}

/// Every scene joint's force and moment on its first point's body at `state` (its
/// multipliers): one report per `[[joints]]` entry (a hinge's axis rows join its point's).
pub fn joint_reports(model: &Model, state: &State) -> Vec<JointReport> {
    let mut out: Vec<JointReport> = Vec::new();
    // which report each scene joint has: a hinge's or planar joint's axis rows are a second
    // `JointModel` with its point rows' `scene_index`, and add the moment to that report
    let mut report_of = vec![usize::MAX; model.joints.iter().map(|j| j.scene_index + 1).max().unwrap_or(0)];
    for j in &model.joints {
        if j.alignment.is_some() {
            if let Some(report) = out.get_mut(report_of[j.scene_index]) {
                report.moment_nm =
                    (-crate::constraints::joint_moment(model, &state.poses, j, &state.multipliers)).into();
            }
            continue;
        }
        report_of[j.scene_index] = out.len();
        out.push(JointReport {
            kind: j.kind.as_str(),
            point: model.points[j.point.0].name.clone(),
            other: match j.target {
                crate::model::JointTarget::Point(p) => model.points[p.0].name.clone(),
                crate::model::JointTarget::World(_) => String::new(),
            },
            force_n: (-crate::constraints::joint_reaction(model, &state.poses, j, &state.multipliers)).into(),
            moment_nm: [0.0; 3],
        });
    }
    out
}

/// Named point positions (every point of every body), m.
pub fn point_positions(model: &Model, ws: &Workspace) -> Vec<(String, [f64; 3])> {
    model.points.iter().zip(&ws.points).map(|(p, k)| (p.name.clone(), k.position.into())).collect()
}

/// CSV header of a deployment path: step, time, solver columns, every actuated cable's rest
/// length, every cable's tension, every point's position.
pub fn path_csv_header(model: &Model) -> String {
    let mut cols: Vec<String> = ["step", "time_s", "point", "newton_iterations", "residual_N", "stable"]
        .iter()
        .map(|s| s.to_string())
        .collect();
    for a in &model.actuators {
        cols.push(format!("{}_rest_length_m", model.cable_names[a.cable.0]));
    }
    for name in &model.cable_names {
        cols.push(format!("{name}_tension_N"));
    }
    for p in &model.points {
        for ax in ["x", "y", "z"] {
            cols.push(format!("{}_{ax}_m", p.name));
        }
    }
    cols.extend(contact_csv_columns(model));
    cols.extend(pulley_csv_columns(model));
    cols.join(",")
}

/// One CSV row matching `path_csv_header`: the output step the row belongs to, the schedule
/// time, what the row is (`load`, `arc` or `snap`, `crate::solve::deploy::PathKind`), the
/// solve's iterations, residual and stability, then the state.
pub fn path_csv_row(
    model: &Model,
    state: &State,
    ws: &Workspace,
    step: &crate::solve::deploy::PathStep,
) -> String {
    use std::fmt::Write;
    let mut row = format!(
        "{},{:.9},{},{},{:.3e},{}",
        step.index,
        state.time,
        step.kind.as_str(),
        step.report.iterations,
        step.report.residual,
        step.report.stable as u8
    );
    for a in &model.actuators {
        let _ = write!(row, ",{:.12}", state.rest_lengths[a.cable.0]);
    }
    for c in &ws.cables {
        let _ = write!(row, ",{:.12}", Num(c.tension));
    }
    for k in &ws.points {
        let _ = write!(row, ",{:.12},{:.12},{:.12}", Num(k.position.x), Num(k.position.y), Num(k.position.z));
    }
    push_contact_csv(ws, &mut row);
    push_pulley_csv(model, state, ws, &mut row);
    row
}

/// Counts printed by `tensegrity check`.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ModelSummary {
    /// Scene name.
    pub name: String,
    /// Bodies per kind: node, bar, rigid, fixed.
    pub bodies: [usize; 4],
    /// Generalized coordinates.
    pub coordinates: usize,
    /// Constraint equations.
    pub constraints: usize,
    /// Cables (tension only).
    pub cables: usize,
    /// Elastic members (and cables with `tension_only = false`): they push as well as pull.
    pub members: usize,
    /// Sliding cables (with at least one pulley).
    pub sliding_cables: usize,
    /// Pulleys over all cables.
    pub pulleys: usize,
    /// Actuators.
    pub actuators: usize,
    /// Ramps in the deployment schedule.
    pub ramps: usize,
    /// Planar scene.
    pub planar: bool,
    /// Half-space grounds.
    pub grounds: usize,
    /// Contact spheres on bodies (a bar's capsule counts two).
    pub contact_spheres: usize,
}

/// Summary of `model`.
pub fn summary(model: &Model) -> ModelSummary {
    use crate::model::BodyKind;
    let count = |k: BodyKind| model.bodies.iter().filter(|b| b.kind == k).count();
    ModelSummary {
        name: model.name.clone(),
        bodies: [count(BodyKind::Node), count(BodyKind::Bar), count(BodyKind::Rigid), count(BodyKind::Fixed)],
        coordinates: model.dof_count,
        constraints: model.constraint_count,
        cables: model.cables.iter().filter(|c| c.tension_only).count(),
        members: model.cables.iter().filter(|c| !c.tension_only).count(),
        sliding_cables: model.cables.iter().filter(|c| c.pulley_count() > 0).count(),
        pulleys: model.pulley_count(),
        actuators: model.actuators.len(),
        ramps: model.schedule.ramps.len(),
        planar: model.planar,
        grounds: model.grounds.len(),
        contact_spheres: model.contact_spheres.len(),
    }
}

/// A sentence naming the bodies nothing holds (`Model::unheld_bodies`, at most 5 by name), or
/// `None` when every body with coordinates has a cable or joint on it.
pub fn unheld_bodies_note(model: &Model) -> Option<String> {
    let unheld = model.unheld_bodies();
    if unheld.is_empty() {
        return None;
    }
    let names: Vec<String> = unheld.iter().take(5).map(|b| format!("'{}'", model.bodies[b.0].name)).collect();
    let more = if unheld.len() > 5 { format!(" and {} more", unheld.len() - 5) } else { String::new() };
    Some(format!(
        "{} bod{} {}{more} ha{} no cable, joint or support: free-floating, so there is no equilibrium for {}",
        unheld.len(),
        if unheld.len() == 1 { "y" } else { "ies" },
        names.join(", "),
        if unheld.len() == 1 { "s" } else { "ve" },
        if unheld.len() == 1 { "it" } else { "them" },
    ))
}

#[cfg(test)]
mod tests {
    use super::Num;

    #[test]
    fn zero_never_shows_a_sign() {
        assert_eq!(format!("{:.6}", Num(-1e-9)), "0.000000");
        assert_eq!(format!("{:>10.3}|", Num(-1e-9)), "     0.000|");
        assert_eq!(format!("{:+.3}", Num(4e-4)), "0.000");
        assert_eq!(format!("{:+.3}", Num(-4e-4)), "0.000");
        assert_eq!(format!("{:+.3}", Num(0.25)), "+0.250");
        assert_eq!(format!("{:+.3}", Num(-0.25)), "-0.250");
        assert_eq!(format!("{:<8.2}|", Num(-1.5)), "-1.50   |");
    }
}
