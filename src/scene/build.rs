//! Validation and model building: takes a parsed `SceneSpec`, gives a `Model` (bodies, points,
//! routes, joints, actuators, schedule, rest lengths) or the first `SceneError` found.

use std::collections::{BTreeMap, BTreeSet};

use nalgebra::{Matrix3, Matrix6, SymmetricEigen, UnitQuaternion, Vector3};

use super::{BodyKindSpec, JointKindSpec, PointSpec, SceneSpec};
use crate::error::SceneError;
use crate::model::{
    ActuatorModel, BodyId, BodyKind, BodyModel, CableModel, JointModel, JointTarget, Model, PointId,
    PointModel, Pose, Ramp, Schedule, SolverSettings,
};
use crate::solve::formfind::{find_rest_lengths, RestLengthSpec};

struct Ctx<'a> {
    file: &'a str,
    text: Option<&'a str>,
}

impl Ctx<'_> {
    fn err(&self, array: &str, index: usize, field: &str, reason: impl Into<String>) -> SceneError {
        let path =
            if field.is_empty() { format!("{array}[{index}]") } else { format!("{array}[{index}].{field}") };
        SceneError {
            file: self.file.to_string(),
            line: self.text.and_then(|t| super::locate(t, array, index, field)),
            field: path,
            reason: reason.into(),
        }
    }
    fn top(&self, field: &str, reason: impl Into<String>) -> SceneError {
        let line =
            self.text.and_then(|t| t.lines().position(|l| l.trim_start().starts_with(field)).map(|i| i + 1));
        SceneError { file: self.file.into(), line, field: field.into(), reason: reason.into() }
    }
}

fn finite3(v: &[f64; 3]) -> bool {
    v.iter().all(|x| x.is_finite())
}

fn positive(x: Option<f64>) -> Result<f64, String> {
    match x {
        None => Err("missing (required for this kind)".into()),
        Some(m) if !m.is_finite() => Err(format!("must be finite, got {m}")),
        Some(m) if m <= 0.0 => Err(format!("must be positive, got {m}")),
        Some(m) => Ok(m),
    }
}

/// Validates `spec` and builds the model. `file` names the source in errors; `text` (the TOML
/// source, when there is one) lets errors carry line numbers.
pub fn build_model(spec: &SceneSpec, file: &str, text: Option<&str>) -> Result<Model, SceneError> {
    let cx = Ctx { file, text };
    if !finite3(&spec.gravity) {
        return Err(cx.top("gravity", "must be finite"));
    }
    if spec.planar && spec.gravity[2] != 0.0 {
        return Err(cx.top("gravity", "a planar scene moves in the xy plane: gravity z must be 0"));
    }
    if spec.bodies.is_empty() {
        return Err(cx.top("bodies", "a scene needs at least one body"));
    }

    // ---- bodies and points
    let mut bodies = Vec::new();
    let mut points: Vec<PointModel> = Vec::new();
    let mut point_names: BTreeMap<String, PointId> = BTreeMap::new();
    let mut dof = 0;
    for (i, b) in spec.bodies.iter().enumerate() {
        let e = |field: &str, reason: String| cx.err("bodies", i, field, reason);
        if b.name.is_empty() || b.name.contains('.') || b.name.contains(char::is_whitespace) {
            return Err(e(
                "name",
                format!("'{}' is not a valid name (non-empty, no dots or spaces)", b.name),
            ));
        }
        if bodies.iter().any(|o: &BodyModel| o.name == b.name) {
            return Err(e("name", format!("duplicate body name '{}'", b.name)));
        }
        for (f, v) in [("position", b.position), ("rotation", b.rotation)] {
            if let Some(v) = v {
                if !finite3(&v) {
                    return Err(e(f, "must be finite".into()));
                }
            }
        }
        let rotation = UnitQuaternion::from_scaled_axis(Vector3::from(b.rotation.unwrap_or([0.0; 3])));
        let position = b.position.map(Vector3::from);
        let mut local_points: Vec<(String, Vector3<f64>)> = Vec::new();
        let (kind, mass, inertia, pose, bar_len) = match b.kind {
            BodyKindSpec::Node => {
                let mass = positive(b.mass).map_err(|r| e("mass", r))?;
                let x = position.ok_or_else(|| e("position", "missing (required for a node)".into()))?;
                if b.rotation.is_some() || b.ends.is_some() || b.inertia.is_some() || !b.points.is_empty() {
                    return Err(e(
                        "kind",
                        "a node takes only name, mass and position (its point is the node itself)".into(),
                    ));
                }
                (
                    BodyKind::Node,
                    mass,
                    Matrix3::zeros(),
                    Pose { position: x, rotation: UnitQuaternion::identity() },
                    0.0,
                )
            }
            BodyKindSpec::Bar => {
                let mass = positive(b.mass).map_err(|r| e("mass", r))?;
                let ends = b
                    .ends
                    .ok_or_else(|| e("ends", "missing (a bar is given by its two end positions)".into()))?;
                if !finite3(&ends[0]) || !finite3(&ends[1]) {
                    return Err(e("ends", "must be finite".into()));
                }
                if b.position.is_some() || b.rotation.is_some() {
                    return Err(e("position", "a bar is placed by `ends`, not by position/rotation".into()));
                }
                let (a, bb) = (Vector3::from(ends[0]), Vector3::from(ends[1]));
                let len = (bb - a).norm();
                if len <= 1e-9 {
                    return Err(e("ends", "the two ends coincide: a bar needs a positive length".into()));
                }
                let u = (bb - a) / len;
                if spec.planar && u.z.abs() > 1e-9 {
                    return Err(e("ends", "in a planar scene a bar must lie in the xy plane".into()));
                }
                let rot = UnitQuaternion::rotation_between(&Vector3::z(), &u)
                    .unwrap_or_else(|| UnitQuaternion::from_scaled_axis(Vector3::x() * std::f64::consts::PI));
                let it = match b.inertia.as_deref() {
                    None => mass * len * len / 12.0,
                    Some([it]) if it.is_finite() && *it > 0.0 => *it,
                    Some(v) => {
                        return Err(e(
                            "inertia",
                            format!("a bar takes one positive transverse inertia, got {v:?}"),
                        ))
                    }
                };
                local_points.push(("a".into(), Vector3::new(0.0, 0.0, -len / 2.0)));
                local_points.push(("b".into(), Vector3::new(0.0, 0.0, len / 2.0)));
                (
                    BodyKind::Bar,
                    mass,
                    Matrix3::from_diagonal(&Vector3::new(it, it, 0.0)),
                    Pose { position: (a + bb) / 2.0, rotation: rot },
                    len,
                )
            }
            BodyKindSpec::Rigid => {
                let mass = positive(b.mass).map_err(|r| e("mass", r))?;
                let x =
                    position.ok_or_else(|| e("position", "missing (required for a rigid body)".into()))?;
                let j = match b.inertia.as_deref() {
                    Some([a, bb, c]) => Matrix3::from_diagonal(&Vector3::new(*a, *bb, *c)),
                    Some([a, bb, c, xy, xz, yz]) => Matrix3::new(*a, *xy, *xz, *xy, *bb, *yz, *xz, *yz, *c),
                    Some(v) => return Err(e("inertia", format!("expected 3 or 6 values, got {}", v.len()))),
                    None => return Err(e("inertia", "missing (required for a rigid body)".into())),
                };
                if j.iter().any(|x| !x.is_finite()) {
                    return Err(e("inertia", "must be finite".into()));
                }
                let eig = SymmetricEigen::new(j).eigenvalues;
                let (mn, sum) = (eig.min(), eig.sum());
                if mn <= 0.0 || eig.iter().any(|l| 2.0 * l > sum * (1.0 + 1e-12)) {
                    return Err(e("inertia", format!("every rotation of a rigid body is a free coordinate and needs inertia: principal moments {:?} must be positive and obey the triangle inequality", eig.as_slice())));
                }
                (BodyKind::Rigid, mass, j, Pose { position: x, rotation }, 0.0)
            }
            BodyKindSpec::Fixed => {
                if b.mass.is_some() || b.inertia.is_some() || b.ends.is_some() {
                    return Err(e("mass", "a fixed body takes no mass, inertia or ends".into()));
                }
                (
                    BodyKind::Fixed,
                    0.0,
                    Matrix3::zeros(),
                    Pose { position: position.unwrap_or_else(Vector3::zeros), rotation },
                    0.0,
                )
            }
        };
        for (pname, p) in &b.points {
            let field = format!("points.{pname}");
            if pname.is_empty() || pname.contains('.') {
                return Err(e(&field, "invalid point name".into()));
            }
            if local_points.iter().any(|(n, _)| n == pname) {
                return Err(e(&field, format!("duplicate point name '{pname}' (bars define 'a' and 'b')")));
            }
            let local =
                match (kind, p) {
                    (BodyKind::Bar, PointSpec::Along(s)) if s.is_finite() => {
                        Vector3::new(0.0, 0.0, (s - 0.5) * bar_len)
                    }
                    (BodyKind::Bar, PointSpec::Local(_)) => return Err(e(
                        &field,
                        "a bar's points lie on its axis: give the fraction along the bar from a (0) to b (1)"
                            .into(),
                    )),
                    (_, PointSpec::Local(v)) if finite3(v) => Vector3::from(*v),
                    (_, PointSpec::Along(_)) => {
                        return Err(e(&field, "expected body coordinates [x, y, z]".into()))
                    }
                    _ => return Err(e(&field, "must be finite".into())),
                };
            local_points.push((pname.clone(), local));
        }
        // basis
        let mut basis = Matrix6::zeros();
        let mut cols = Vec::new();
        let trans_axes = if spec.planar { 2 } else { 3 };
        if kind != BodyKind::Fixed {
            for a in 0..trans_axes {
                let mut c = nalgebra::Vector6::zeros();
                c[a] = 1.0;
                cols.push(c);
            }
        }
        let rot_axes: Vec<Vector3<f64>> = match (kind, spec.planar) {
            (BodyKind::Node | BodyKind::Fixed, _) => vec![],
            (_, true) => vec![pose.rotation.inverse() * Vector3::z()],
            (BodyKind::Bar, false) => vec![Vector3::x(), Vector3::y()],
            (BodyKind::Rigid, false) => vec![Vector3::x(), Vector3::y(), Vector3::z()],
        };
        for ax in rot_axes {
            cols.push(nalgebra::Vector6::new(0.0, 0.0, 0.0, ax.x, ax.y, ax.z));
        }
        for (k, c) in cols.iter().enumerate() {
            basis.set_column(k, c);
        }
        let id = BodyId(bodies.len());
        let origin_name = b.name.clone();
        point_names.insert(origin_name.clone(), PointId(points.len()));
        points.push(PointModel { name: origin_name, body: id, local: Vector3::zeros() });
        for (pname, local) in local_points {
            let q = format!("{}.{}", b.name, pname);
            point_names.insert(q.clone(), PointId(points.len()));
            points.push(PointModel { name: q, body: id, local });
        }
        bodies.push(BodyModel {
            name: b.name.clone(),
            kind,
            mass,
            inertia,
            basis,
            dof_count: cols.len(),
            dof_offset: dof,
            initial_pose: pose,
        });
        dof += cols.len();
    }
    let point_pos = |p: PointId| {
        let pm = &points[p.0];
        bodies[pm.body.0].initial_pose.transform_point(&pm.local)
    };
    let lookup = |name: &str| point_names.get(name).copied();
    let length_scale =
        points.iter().enumerate().map(|(i, _)| point_pos(PointId(i)).norm()).fold(1.0, f64::max);

    // ---- joints
    let rows = if spec.planar { 2 } else { 3 };
    let mut joints = Vec::new();
    for (i, j) in spec.joints.iter().enumerate() {
        let e = |field: &str, reason: String| cx.err("joints", i, field, reason);
        let a = lookup(&j.a).ok_or_else(|| e("a", format!("unknown point '{}'", j.a)))?;
        let body_a = points[a.0].body;
        let target = match j.kind {
            JointKindSpec::Ball => {
                let bname =
                    j.b.as_ref()
                        .ok_or_else(|| e("b", "missing: a ball joint joins point a to point b".into()))?;
                let b = lookup(bname).ok_or_else(|| e("b", format!("unknown point '{bname}'")))?;
                if points[b.0].body == body_a {
                    return Err(e("b", "both points are on the same body".into()));
                }
                if j.at.is_some() {
                    return Err(e("at", "only pins take `at`".into()));
                }
                if bodies[body_a.0].dof_count == 0 && bodies[points[b.0].body.0].dof_count == 0 {
                    return Err(e("a", "both bodies are fixed: the joint holds nothing".into()));
                }
                JointTarget::Point(b)
            }
            JointKindSpec::Pin => {
                if j.b.is_some() {
                    return Err(e(
                        "b",
                        "a pin holds one point to the ground; use kind = \"ball\" to join two bodies".into(),
                    ));
                }
                if bodies[body_a.0].dof_count == 0 {
                    return Err(e("a", "the point is on a fixed body: nothing to pin".into()));
                }
                let at = match j.at {
                    Some(v) if finite3(&v) => Vector3::from(v),
                    Some(_) => return Err(e("at", "must be finite".into())),
                    None => point_pos(a),
                };
                JointTarget::World(at)
            }
        };
        let gap = match target {
            JointTarget::Point(b) => point_pos(a) - point_pos(b),
            JointTarget::World(x) => point_pos(a) - x,
        };
        if gap.norm() > 1e-9 * length_scale {
            return Err(e(
                "a",
                format!("the joint's points are {:.3e} m apart at the start; they must coincide", gap.norm()),
            ));
        }
        joints.push(JointModel { point: a, target, row_offset: i * rows });
    }

    // ---- cables
    let mut cables = Vec::new();
    let mut cable_names: Vec<String> = Vec::new();
    let mut route_points = Vec::new();
    let mut rest_specs = Vec::new();
    let mut damping_ratios = Vec::new();
    for (i, c) in spec.cables.iter().enumerate() {
        let e = |field: &str, reason: String| cx.err("cables", i, field, reason);
        if c.name.is_empty() {
            return Err(e("name", "must not be empty".into()));
        }
        if cable_names.contains(&c.name) {
            return Err(e("name", format!("duplicate cable name '{}'", c.name)));
        }
        if c.route.len() < 2 {
            return Err(e("route", format!("a cable needs at least two points, got {}", c.route.len())));
        }
        let start = route_points.len();
        for (k, pname) in c.route.iter().enumerate() {
            let p = lookup(pname).ok_or_else(|| {
                let body = pname.split('.').next().unwrap_or("");
                if spec.bodies.iter().any(|b| b.name == body) {
                    e("route", format!("body '{body}' has no point '{pname}'"))
                } else {
                    e("route", format!("unknown body in '{pname}'"))
                }
            })?;
            if k > 0 && route_points[start + k - 1] == p {
                return Err(e("route", format!("the route visits '{pname}' twice in a row")));
            }
            route_points.push(p);
        }
        if !(c.ea.is_finite() && c.ea > 0.0) {
            return Err(e("ea", format!("EA must be positive and finite, got {}", c.ea)));
        }
        let given = [c.rest_length.is_some(), c.prestress.is_some(), c.force_density.is_some()];
        if given.iter().filter(|g| **g).count() > 1 {
            let field = if c.force_density.is_some() { "force_density" } else { "prestress" };
            return Err(e(
                field,
                "give at most one of rest_length, prestress and force_density, not both".into(),
            ));
        }
        let rest = match (c.rest_length, c.prestress, c.force_density) {
            (Some(l), _, _) if l.is_finite() && l > 0.0 => RestLengthSpec::Given(l),
            (Some(l), _, _) => return Err(e("rest_length", format!("must be positive and finite, got {l}"))),
            (_, Some(t), _) if t.is_finite() && t >= 0.0 => RestLengthSpec::Prestress(t),
            (_, Some(t), _) => {
                return Err(e("prestress", format!("a cable can only pull: prestress must be >= 0, got {t}")))
            }
            (_, _, Some(q)) if q.is_finite() && q >= 0.0 => RestLengthSpec::ForceDensity(q),
            (_, _, Some(q)) => {
                return Err(e(
                    "force_density",
                    format!("a cable can only pull: force density must be >= 0, got {q}"),
                ))
            }
            (None, None, None) => RestLengthSpec::Free,
        };
        let (damping, ratio) = match (c.damping, c.damping_ratio) {
            (Some(_), Some(_)) => {
                return Err(e("damping_ratio", "give damping or damping_ratio, not both".into()))
            }
            (Some(d), None) if d.is_finite() && d >= 0.0 => (d, None),
            (Some(d), None) => return Err(e("damping", format!("must be >= 0 and finite, got {d}"))),
            (None, Some(z)) if z.is_finite() && z >= 0.0 => (0.0, Some(z)),
            (None, Some(z)) => return Err(e("damping_ratio", format!("must be >= 0 and finite, got {z}"))),
            (None, None) => (0.0, None),
        };
        rest_specs.push(rest);
        damping_ratios.push(ratio);
        cables.push(CableModel {
            route_start: start,
            route_len: c.route.len(),
            axial_stiffness: c.ea,
            damping,
        });
        cable_names.push(c.name.clone());
    }

    // ---- actuators
    let mut actuators = Vec::new();
    let mut actuator_names: Vec<String> = Vec::new();
    for (i, a) in spec.actuators.iter().enumerate() {
        let e = |field: &str, reason: String| cx.err("actuators", i, field, reason);
        if a.name.is_empty() || actuator_names.contains(&a.name) {
            return Err(e("name", format!("empty or duplicate actuator name '{}'", a.name)));
        }
        let cable = cable_names
            .iter()
            .position(|n| *n == a.cable)
            .ok_or_else(|| e("cable", format!("unknown cable '{}'", a.cable)))?;
        if actuators.iter().any(|o: &ActuatorModel| o.cable.0 == cable) {
            return Err(e("cable", format!("cable '{}' already has an actuator", a.cable)));
        }
        if !(a.min_rest_length.is_finite() && a.min_rest_length > 0.0) {
            return Err(e("min_rest_length", format!("must be positive, got {}", a.min_rest_length)));
        }
        if !(a.max_rest_length.is_finite() && a.max_rest_length >= a.min_rest_length) {
            return Err(e(
                "max_rest_length",
                format!("must be >= min_rest_length, got {}", a.max_rest_length),
            ));
        }
        if !(a.max_rate.is_finite() && a.max_rate > 0.0) {
            return Err(e("max_rate", format!("must be positive, got {}", a.max_rate)));
        }
        actuators.push(ActuatorModel {
            cable: crate::model::CableId(cable),
            min_rest_length: a.min_rest_length,
            max_rest_length: a.max_rest_length,
            max_rate: a.max_rate,
        });
        actuator_names.push(a.name.clone());
    }

    let mut solver = SolverSettings::default();
    if let Some(s) = &spec.solver {
        if let Some(t) = s.tolerance {
            if !(t.is_finite() && t > 0.0 && t < 1.0) {
                return Err(cx.top("solver", format!("tolerance must be in (0, 1), got {t}")));
            }
            solver.tolerance = t;
        }
        if let Some(n) = s.max_iterations {
            if n == 0 {
                return Err(cx.top("solver", "max_iterations must be >= 1"));
            }
            solver.max_iterations = n;
        }
    }

    let mut model = Model {
        name: if spec.name.is_empty() { file.to_string() } else { spec.name.clone() },
        bodies,
        points,
        cables,
        cable_names,
        route_points,
        joints,
        actuators,
        actuator_names,
        schedule: Schedule::default(),
        gravity: Vector3::from(spec.gravity),
        planar: spec.planar,
        dof_count: dof,
        constraint_count: spec.joints.len() * rows,
        initial_rest_lengths: vec![1.0; spec.cables.len()],
        solver,
        physics_dt: match spec.physics_dt {
            Some(dt) if dt.is_finite() && dt > 0.0 => Some(dt),
            Some(dt) => return Err(cx.top("physics_dt", format!("must be positive and finite, got {dt}"))),
            None => None,
        },
    };
    check_mass_on_free_coordinates(&model, &cx)?;

    // ---- rest lengths (form finding where asked)
    model.initial_rest_lengths =
        find_rest_lengths(&model, &rest_specs).map_err(|(cable, reason)| match cable {
            Some(c) => cx.err("cables", c, "prestress", reason),
            None => cx.top("cables", reason),
        })?;
    for (c, ratio) in damping_ratios.iter().enumerate() {
        if let Some(zeta) = ratio {
            let inv_m: f64 = model
                .route(crate::model::CableId(c))
                .iter()
                .map(|p| model.points[p.0].body)
                .collect::<BTreeSet<_>>()
                .iter()
                .filter(|b| model.bodies[b.0].dof_count > 0)
                .map(|b| 1.0 / model.bodies[b.0].mass)
                .sum();
            if inv_m > 0.0 {
                let k = model.cables[c].axial_stiffness / model.initial_rest_lengths[c];
                model.cables[c].damping = 2.0 * zeta * (k / inv_m).sqrt();
            }
        }
    }
    for (i, a) in model.actuators.iter().enumerate() {
        let l0 = model.initial_rest_lengths[a.cable.0];
        if l0 < a.min_rest_length || l0 > a.max_rest_length {
            return Err(cx.err(
                "actuators",
                i,
                "min_rest_length",
                format!(
                    "the cable's initial rest length {l0:.6} m is outside [{}, {}]",
                    a.min_rest_length, a.max_rest_length
                ),
            ));
        }
    }

    // ---- deployment schedule
    if let Some(d) = &spec.deployment {
        if d.steps == 0 {
            return Err(cx.top("deployment", "steps must be >= 1"));
        }
        let mut ramps = Vec::new();
        for (i, r) in d.ramps.iter().enumerate() {
            let e = |field: &str, reason: String| cx.err("deployment.ramps", i, field, reason);
            let id = model
                .actuator_id(&r.actuator)
                .ok_or_else(|| e("actuator", format!("unknown actuator '{}'", r.actuator)))?;
            if !(r.start.is_finite() && r.start >= 0.0) {
                return Err(e("start", format!("must be >= 0, got {}", r.start)));
            }
            if !(r.duration.is_finite() && r.duration > 0.0) {
                return Err(e("duration", format!("must be positive, got {}", r.duration)));
            }
            let act = model.actuators[id.0];
            if !(r.rest_length >= act.min_rest_length && r.rest_length <= act.max_rest_length) {
                return Err(e(
                    "rest_length",
                    format!(
                        "{} m is outside the actuator's range [{}, {}]",
                        r.rest_length, act.min_rest_length, act.max_rest_length
                    ),
                ));
            }
            ramps.push((
                i,
                Ramp { actuator: id, start: r.start, duration: r.duration, target: r.rest_length },
            ));
        }
        ramps.sort_by(|a, b| {
            (a.1.actuator, a.1.start).partial_cmp(&(b.1.actuator, b.1.start)).expect("finite")
        });
        let mut prev: Option<Ramp> = None;
        for (i, r) in &ramps {
            let e = |field: &str, reason: String| cx.err("deployment.ramps", *i, field, reason);
            let from = match prev {
                Some(p) if p.actuator == r.actuator => {
                    if r.start < p.start + p.duration - 1e-12 {
                        return Err(e("start", "overlaps the previous ramp of the same actuator".into()));
                    }
                    p.target
                }
                _ => model.initial_rest_lengths[model.actuators[r.actuator.0].cable.0],
            };
            let rate = (r.target - from).abs() / r.duration;
            let max_rate = model.actuators[r.actuator.0].max_rate;
            if rate > max_rate * (1.0 + 1e-12) {
                return Err(e(
                    "duration",
                    format!("needs {rate:.4} m/s, above the actuator's max_rate {max_rate} m/s"),
                ));
            }
            prev = Some(*r);
        }
        model.schedule = Schedule { ramps: ramps.into_iter().map(|(_, r)| r).collect(), steps: d.steps };
    } else {
        model.schedule.steps = 1;
    }
    Ok(model)
}

/// Every free coordinate must carry mass: the body mass matrix must be positive definite.
fn check_mass_on_free_coordinates(model: &Model, cx: &Ctx) -> Result<(), SceneError> {
    for (i, b) in model.bodies.iter().enumerate() {
        if b.dof_count == 0 {
            continue;
        }
        let m = b.mass_matrix();
        let k = b.dof_count;
        let sub = m.view((0, 0), (k, k)).into_owned();
        let eig = SymmetricEigen::new(sub).eigenvalues;
        if eig.min() <= 1e-12 * eig.max().max(1e-300) {
            return Err(cx.err(
                "bodies",
                i,
                "mass",
                format!("body '{}' has a free coordinate without mass or inertia", b.name),
            ));
        }
    }
    Ok(())
}
