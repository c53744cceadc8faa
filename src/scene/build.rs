//! Validation and model building: takes a parsed `SceneSpec`, gives a `Model` (bodies, points,
//! routes, joints, actuators, schedule, rest lengths) or the first `SceneError` found.

use std::collections::{BTreeMap, BTreeSet};

use nalgebra::{Matrix3, Matrix6, SymmetricEigen, UnitQuaternion, Vector3};

use super::{
    limits, BodyKindSpec, CableSpec, CollisionPairsSpec, JointKindSpec, MassMatrixSpec, PointSpec, SceneSpec,
    WinchSpec,
};
use crate::error::{readable_number, SceneError};
use crate::forces::winch::{PositionGains, WinchModel};
use crate::model::{
    ActuatorModel, BodyId, BodyKind, BodyModel, CableModel, ContactMaterial, ContactSphere, GroundModel,
    JointModel, JointTarget, MassCoupling, Model, PointId, PointModel, Pose, Ramp, Schedule, SolverSettings,
    StrutPair,
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
        // the key itself, else the table it names (`[deployment]`, `[solver]`)
        let line = self.text.and_then(|t| {
            let top = field.split('.').next().unwrap_or(field);
            t.lines()
                .position(|l| l.trim_start().starts_with(field))
                .or_else(|| t.lines().position(|l| l.trim() == format!("[{top}]")))
                .map(|i| i + 1)
        });
        SceneError { file: self.file.into(), line, field: field.into(), reason: reason.into() }
    }
}

/// `x` when it lies in `[lo, hi]`, else the reason (with the unit `unit`).
fn in_range(x: f64, (lo, hi): (f64, f64), unit: &str) -> Result<f64, String> {
    if !x.is_finite() {
        Err(format!("must be finite, got {x}"))
    } else if lo > 0.0 && x <= 0.0 {
        Err(format!("must be positive, got {}", readable_number(x)))
    } else if lo == 0.0 && x < 0.0 {
        Err(format!("must be >= 0, got {}", readable_number(x)))
    } else if x < lo || x > hi {
        Err(format!(
            "must be in [{}, {}]{}, got {}",
            readable_number(lo),
            readable_number(hi),
            if unit.is_empty() { String::new() } else { format!(" {unit}") },
            readable_number(x)
        ))
    } else {
        Ok(x)
    }
}

/// `v` when every entry is finite and within `max` in magnitude.
fn bounded3(v: &[f64; 3], max: f64, unit: &str) -> Result<(), String> {
    match v.iter().find(|x| !(x.is_finite() && x.abs() <= max)) {
        None => Ok(()),
        Some(x) if !x.is_finite() => Err(format!("must be finite, got {v:?}")),
        Some(x) => Err(format!(
            "entries must be within +-{} {unit}, got {}",
            readable_number(max),
            readable_number(*x)
        )),
    }
}

fn mass(x: Option<f64>) -> Result<f64, String> {
    match x {
        None => Err("missing (required for this kind)".into()),
        Some(m) => in_range(m, limits::MASS, "kg"),
    }
}

/// Validates `spec` and builds the model. `file` names the source in errors; `text` (the TOML
/// source, when there is one) lets errors carry line numbers.
pub fn build_model(spec: &SceneSpec, file: &str, text: Option<&str>) -> Result<Model, SceneError> {
    let cx = Ctx { file, text };
    bounded3(&spec.gravity, limits::MAX_GRAVITY, "m/s^2").map_err(|r| cx.top("gravity", r))?;
    if spec.planar && spec.gravity[2] != 0.0 {
        return Err(cx.top("gravity", "a planar scene moves in the xy plane: gravity z must be 0"));
    }
    if spec.bodies.is_empty() {
        return Err(cx.top("bodies", "a scene needs at least one body"));
    }
    let Bodies { bodies, points, point_names, dof } = build_bodies(spec, &cx)?;
    let rows = if spec.planar { 2 } else { 3 };
    let joints = build_joints(spec, &cx, &bodies, &points, &point_names, rows)?;
    let constraint_count = joints.iter().map(|j| j.rows).sum();
    let damped_joints = joints.iter().any(|j| j.damping > 0.0);
    let Cables { cables, cable_names, route_points, rest_specs, damping_ratios } =
        build_cables(spec, &cx, &point_names)?;
    let Actuators { actuators, actuator_names, winches } = build_actuators(spec, &cx, &cable_names)?;
    let solver = build_solver(spec, &cx)?;
    let contact_spheres = build_contact_spheres(spec, &cx, &bodies, &point_names)?;
    let grounds = build_grounds(spec, &cx, &bodies, &points)?;
    let (strut_pairs, strut_material) =
        build_strut_pairs(spec, &cx, &bodies, &points, &point_names, &joints)?;
    let mut bodies = bodies;
    let mass_couplings = lump_member_masses(spec, &cx, &mut bodies, &points, &point_names)?;
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
        grounds,
        contact_spheres,
        strut_pairs,
        strut_material,
        schedule: Schedule::default(),
        gravity: Vector3::from(spec.gravity),
        planar: spec.planar,
        dof_count: dof,
        constraint_count,
        initial_rest_lengths: vec![1.0; spec.cables.len() + spec.members.len()],
        pulley_friction: Vec::new(),
        initial_segment_rest_lengths: Vec::new(),
        winches,
        solver,
        rayleigh: build_rayleigh(spec, &cx)?,
        sensors: build_sensors(spec, &cx)?,
        randomized: Vec::new(),
        randomization: None,
        damped_joints,
        mass_couplings,
        physics_dt: match spec.physics_dt {
            Some(dt) => Some(in_range(dt, limits::PHYSICS_DT, "s").map_err(|r| cx.top("physics_dt", r))?),
            None => None,
        },
        source: match text {
            Some(t) => t.into(),
            None => super::to_toml(spec).into(),
        },
    };
    check_mass_on_free_coordinates(&model, &cx)?;
    check_redundant_joints(&model, &cx)?;
    check_contacts(spec, &model, &cx)?;

    set_rest_lengths(&mut model, &rest_specs, &damping_ratios, spec.cables.len(), &cx)?;
    set_buckling_loads(spec, &mut model, &cx)?;
    set_pulley_friction(spec, &mut model, &cx)?;
    if let Some(r) = &spec.randomize {
        let per_reset = match r.per.as_deref() {
            None | Some("run") => false,
            Some("reset") => true,
            Some(other) => return Err(cx.top("randomize.per", format!("'{other}' is not run or reset"))),
        };
        let randomization = build_randomization(r, &model, &cx)?;
        model.randomized = crate::randomize::apply(&mut model, &randomization, r.seed);
        model.randomization =
            Some(crate::randomize::RandomizationRun { seed: r.seed, per_reset, episode: 0 });
    }
    attach_winches(&mut model, &cx)?;
    model.schedule = build_schedule(spec, &model, &cx)?;
    Ok(model)
}

/// Gives the cables whose pulleys have friction (`pulley_friction`, the cable's or the
/// scene's) their `PulleyFriction` and their segments' initial rest lengths (the initial rest
/// length at uniform strain). A cable whose coefficients are all 0 stays the frictionless
/// element. Refused: a coefficient out of range, a list whose length is not the cable's pulley
/// count, friction on a cable without pulleys, `winch_end` on an element that cannot use it.
fn set_pulley_friction(spec: &SceneSpec, model: &mut Model, cx: &Ctx) -> Result<(), SceneError> {
    use super::{PulleyFrictionSpec, WinchEndSpec};
    let default = match spec.pulley_friction {
        Some(mu) => in_range(mu, limits::FRICTION, "").map_err(|r| cx.top("pulley_friction", r))?,
        None => 0.0,
    };
    let (mut segment_offset, mut pulley_offset) = (0, 0);
    for (i, c) in spec.cables.iter().enumerate() {
        let e = |field: &str, reason: String| cx.err("cables", i, field, reason);
        let pulleys = c.route.len() - 2;
        let mu = match &c.pulley_friction {
            Some(_) if pulleys == 0 => {
                return Err(e("pulley_friction", "a cable between two points has no pulleys".into()))
            }
            Some(PulleyFrictionSpec::All(mu)) => {
                vec![in_range(*mu, limits::FRICTION, "").map_err(|r| e("pulley_friction", r))?; pulleys]
            }
            Some(PulleyFrictionSpec::Each(list)) => {
                if list.len() != pulleys {
                    return Err(e(
                        "pulley_friction",
                        format!(
                            "one coefficient per pulley: the route has {pulleys}, the list {}",
                            list.len()
                        ),
                    ));
                }
                for mu in list {
                    in_range(*mu, limits::FRICTION, "").map_err(|r| e("pulley_friction", r))?;
                }
                list.clone()
            }
            None => vec![default; pulleys],
        };
        let with_friction = mu.iter().any(|m| *m > 0.0);
        if c.winch_end.is_some() && !with_friction {
            return Err(e(
                "winch_end",
                "only a cable with pulley friction has a winch end (without, the material runs freely)"
                    .into(),
            ));
        }
        if !with_friction {
            continue;
        }
        let segments = pulleys + 1;
        model.cables[i].friction = Some(model.pulley_friction.len());
        model.pulley_friction.push(crate::model::PulleyFriction {
            cable: crate::model::CableId(i),
            mu,
            segment_offset,
            pulley_offset,
            fed_segment: match c.winch_end {
                Some(WinchEndSpec::Last) => segments - 1,
                _ => 0,
            },
        });
        segment_offset += segments;
        pulley_offset += pulleys;
    }
    if !model.pulley_friction.is_empty() {
        let state = crate::state::State::initial(model);
        let kin: Vec<_> = (0..model.points.len())
            .map(|p| crate::kinematics::point_kinematics(model, &state.poses, &state.velocities, PointId(p)))
            .collect();
        model.initial_segment_rest_lengths =
            crate::forces::pulley::shared_rest_lengths(model, &kin, &model.initial_rest_lengths);
    }
    Ok(())
}

/// Marks each winch's cable (`CableModel::winch`) and refuses a winch on an element that cannot
/// take one: a member (it pushes; a drum only pulls) or a cable with pulley friction.
fn attach_winches(model: &mut Model, cx: &Ctx) -> Result<(), SceneError> {
    for (w, winch) in model.winches.iter().enumerate() {
        let i = winch.actuator.0;
        let cable = &mut model.cables[winch.cable.0];
        if !cable.tension_only {
            return Err(cx.err("actuators", i, "winch", "a winch drives a cable, not a member that pushes"));
        }
        if cable.friction.is_some() {
            return Err(cx.err(
                "actuators",
                i,
                "winch",
                "a winch on a cable with pulley friction is not modelled yet (use the ideal actuator)",
            ));
        }
        cable.winch = Some(w);
    }
    Ok(())
}

/// Sets each member's buckling load (`buckling_load`, or `pi^2 EI / L0^2` of its initial rest
/// length from `bending_stiffness`) once the rest lengths are known, and refuses a member whose
/// target force (`force`, `form_find`) already compresses it past that load: form finding
/// solves the unbuckled law.
fn set_buckling_loads(spec: &SceneSpec, model: &mut Model, cx: &Ctx) -> Result<(), SceneError> {
    let first = spec.cables.len();
    let state = crate::state::State::initial(model);
    let mut ws = None;
    for (i, m) in spec.members.iter().enumerate() {
        let e = |field: &str, reason: String| cx.err("members", i, field, reason);
        let c = first + i;
        let l0 = model.initial_rest_lengths[c];
        let load = match (m.bending_stiffness, m.buckling_load) {
            (None, None) => continue,
            (Some(_), Some(_)) => {
                return Err(e("buckling_load", "give bending_stiffness or buckling_load, not both".into()))
            }
            (Some(ei), None) => {
                let ei = in_range(ei, limits::BENDING_STIFFNESS, "N m^2")
                    .map_err(|r| e("bending_stiffness", r))?;
                std::f64::consts::PI.powi(2) * ei / (l0 * l0)
            }
            (None, Some(p)) => in_range(p, limits::BUCKLING_LOAD, "N").map_err(|r| e("buckling_load", r))?,
        };
        if m.force.is_some() || m.form_find {
            let ws = ws.get_or_insert_with(|| {
                let mut w = crate::evaluate::Workspace::for_forces(model);
                crate::evaluate::evaluate_forces(model, &state, &mut w);
                w
            });
            let t = ws.cables[c].tension;
            if -t > load {
                return Err(e(
                    if m.form_find { "form_find" } else { "force" },
                    format!("the member starts compressed by {:.6e} N, past its buckling load {load:.6e} N: form finding solves the unbuckled law; give a rest_length instead", -t),
                ));
            }
        }
        model.cables[c].buckling_load = load;
    }
    Ok(())
}

/// The bodies and their points, in scene order (`build_bodies`).
struct Bodies {
    bodies: Vec<BodyModel>,
    points: Vec<PointModel>,
    point_names: BTreeMap<String, PointId>,
    /// Coordinates of all bodies.
    dof: usize,
}

/// Checks and builds `bodies` (names, poses, masses, inertias, points, coordinate bases).
fn build_bodies(spec: &SceneSpec, cx: &Ctx) -> Result<Bodies, SceneError> {
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
        if let Some(v) = &b.position {
            bounded3(v, limits::MAX_COORDINATE, "m").map_err(|r| e("position", r))?;
        }
        if let Some(v) = &b.rotation {
            bounded3(v, limits::MAX_ROTATION, "rad").map_err(|r| e("rotation", r))?;
        }
        let rotation = UnitQuaternion::from_scaled_axis(Vector3::from(b.rotation.unwrap_or([0.0; 3])));
        let position = b.position.map(Vector3::from);
        let mut local_points: Vec<(String, Vector3<f64>)> = Vec::new();
        let (kind, mass, inertia, pose, bar_len) = match b.kind {
            BodyKindSpec::Node => {
                // a node may take all its mass from the members that end on it
                let lumped = spec.members.iter().any(|m| {
                    m.mass.is_some() && m.ends.iter().any(|p| p.split('.').next() == Some(b.name.as_str()))
                });
                let mass = match b.mass {
                    None if lumped => 0.0,
                    given => mass(given).map_err(|r| e("mass", r))?,
                };
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
                let mass = mass(b.mass).map_err(|r| e("mass", r))?;
                let ends = b
                    .ends
                    .ok_or_else(|| e("ends", "missing (a bar is given by its two end positions)".into()))?;
                for end in &ends {
                    bounded3(end, limits::MAX_COORDINATE, "m").map_err(|r| e("ends", r))?;
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
                    Some([it]) => in_range(*it, limits::INERTIA, "kg m^2").map_err(|r| e("inertia", r))?,
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
                let mass = mass(b.mass).map_err(|r| e("mass", r))?;
                let x =
                    position.ok_or_else(|| e("position", "missing (required for a rigid body)".into()))?;
                let j = match b.inertia.as_deref() {
                    Some([a, bb, c]) => Matrix3::from_diagonal(&Vector3::new(*a, *bb, *c)),
                    Some([a, bb, c, xy, xz, yz]) => Matrix3::new(*a, *xy, *xz, *xy, *bb, *yz, *xz, *yz, *c),
                    Some(v) => return Err(e("inertia", format!("expected 3 or 6 values, got {}", v.len()))),
                    None => return Err(e("inertia", "missing (required for a rigid body)".into())),
                };
                if let Some(x) = j.iter().find(|x| !(x.is_finite() && x.abs() <= limits::INERTIA.1)) {
                    return Err(e(
                        "inertia",
                        format!(
                            "entries must be finite and within {:e} kg m^2, got {x:e}",
                            limits::INERTIA.1
                        ),
                    ));
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
            let local = match (kind, p) {
                (BodyKind::Bar, PointSpec::Along(s)) if s.is_finite() && s.abs() <= 1e3 => {
                    Vector3::new(0.0, 0.0, (s - 0.5) * bar_len)
                }
                (BodyKind::Bar, PointSpec::Local(_)) => {
                    return Err(e(
                        &field,
                        "a bar's points lie on its axis: give the fraction along the bar from a (0) to b (1)"
                            .into(),
                    ))
                }
                (_, PointSpec::Local(v)) => {
                    bounded3(v, limits::MAX_COORDINATE, "m").map_err(|r| e(&field, r))?;
                    Vector3::from(*v)
                }
                (BodyKind::Bar, PointSpec::Along(_)) => {
                    return Err(e(&field, "a fraction along the bar must be finite and within +-1000".into()))
                }
                (_, PointSpec::Along(_)) => {
                    return Err(e(
                        &field,
                        "expected body coordinates [x, y, z] (every key after a [bodies.points] header \
                         belongs to that table: write top-level keys before the first table)"
                            .into(),
                    ))
                }
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
    Ok(Bodies { bodies, points, point_names, dof })
}

/// What a joint spec holds, checked: its kind, held world directions
/// (`JointModel::directions`), point rows, and the unit world axis its alignment keeps (a
/// hinge's axis or a planar joint's normal; none for a hinge in a planar scene, whose bodies
/// turn about z only).
struct HeldDirections {
    kind: crate::model::JointKind,
    directions: Option<Matrix3<f64>>,
    rows: usize,
    aligned_axis: Option<Vector3<f64>>,
}

/// A joint's kind, held world directions, rows and aligned axis: ball joints and pins hold
/// every direction (`rows`: 3, or 2 in a planar scene); a roller the directions across its
/// line, a slider its plane's normal; a hinge and a planar joint also keep an axis. On error,
/// the field and the reason.
fn support_directions(j: &super::JointSpec, rows: usize) -> Result<HeldDirections, (&'static str, String)> {
    use crate::model::JointKind;
    let planar = rows == 2;
    let unit = |v: Option<[f64; 3]>,
                field: &'static str,
                what: &str|
     -> Result<Vector3<f64>, (&'static str, String)> {
        let v = v.ok_or_else(|| (field, format!("missing: a {what} needs its {field}")))?;
        bounded3(&v, limits::MAX_COORDINATE, "").map_err(|r| (field, r))?;
        let v = Vector3::from(v);
        if v.norm() <= 1e-12 {
            return Err((field, format!("must not be zero, got {v:?}")));
        }
        if planar && v.z != 0.0 {
            return Err((field, "a planar scene moves in the xy plane: z must be 0".into()));
        }
        Ok(v.normalize())
    };
    let stray = |field: &'static str, given: bool| -> Result<(), (&'static str, String)> {
        let owners = match field {
            "normal" => "slider or a planar joint",
            "axis" => "hinge",
            _ => "roller",
        };
        if given {
            Err((field, format!("only a {owners} takes `{field}`")))
        } else {
            Ok(())
        }
    };
    if j.kind != super::JointKindSpec::Hinge {
        stray("axis", j.axis.is_some())?;
    }
    match j.kind {
        super::JointKindSpec::Ball | super::JointKindSpec::Pin => {
            stray("direction", j.direction.is_some())?;
            stray("normal", j.normal.is_some())?;
            let kind = if j.kind == super::JointKindSpec::Ball { JointKind::Ball } else { JointKind::Pin };
            Ok(HeldDirections { kind, directions: None, rows, aligned_axis: None })
        }
        super::JointKindSpec::Hinge => {
            stray("direction", j.direction.is_some())?;
            stray("normal", j.normal.is_some())?;
            let aligned_axis = if planar {
                let axis = j.axis.ok_or(("axis", "missing: a hinge needs its axis".to_string()))?;
                if axis[0] != 0.0 || axis[1] != 0.0 || axis[2] == 0.0 {
                    return Err((
                        "axis",
                        "a planar scene turns about z only: a hinge's axis must be [0, 0, 1]".into(),
                    ));
                }
                None
            } else {
                Some(unit(j.axis, "axis", "hinge")?)
            };
            Ok(HeldDirections { kind: JointKind::Hinge, directions: None, rows, aligned_axis })
        }
        super::JointKindSpec::Slider | super::JointKindSpec::Planar => {
            stray("direction", j.direction.is_some())?;
            let (kind, what) = match j.kind {
                super::JointKindSpec::Slider => (JointKind::Slider, "slider"),
                _ => (JointKind::Planar, "planar joint"),
            };
            if planar && kind == JointKind::Planar {
                return Err((
                    "kind",
                    "a planar scene already keeps its bodies in the xy plane: use a slider or a roller"
                        .into(),
                ));
            }
            let n = unit(j.normal, "normal", what)?;
            let mut d = Matrix3::zeros();
            d.set_row(0, &n.transpose());
            let aligned_axis = (kind == JointKind::Planar).then_some(n);
            Ok(HeldDirections { kind, directions: Some(d), rows: 1, aligned_axis })
        }
        super::JointKindSpec::Roller => {
            stray("normal", j.normal.is_some())?;
            let t = unit(j.direction, "direction", "roller")?;
            let mut d = Matrix3::zeros();
            if planar {
                // the line's normal in the plane
                d.set_row(0, &Vector3::new(-t.y, t.x, 0.0).transpose());
                return Ok(HeldDirections {
                    kind: JointKind::Roller,
                    directions: Some(d),
                    rows: 1,
                    aligned_axis: None,
                });
            }
            // two unit vectors across the line
            let helper = if t.x.abs() < 0.9 { Vector3::x() } else { Vector3::y() };
            let u = t.cross(&helper).normalize();
            let w = t.cross(&u);
            d.set_row(0, &u.transpose());
            d.set_row(1, &w.transpose());
            Ok(HeldDirections { kind: JointKind::Roller, directions: Some(d), rows: 2, aligned_axis: None })
        }
    }
}

/// Checks and builds `joints` (points that coincide at the start, no repeated constraint);
/// `rows` is 2 in planar scenes, else 3.
fn build_joints(
    spec: &SceneSpec,
    cx: &Ctx,
    bodies: &[BodyModel],
    points: &[PointModel],
    point_names: &BTreeMap<String, PointId>,
    rows: usize,
) -> Result<Vec<JointModel>, SceneError> {
    let point_pos = |p: PointId| {
        let pm = &points[p.0];
        bodies[pm.body.0].initial_pose.transform_point(&pm.local)
    };
    let lookup = |name: &str| point_names.get(name).copied();
    let length_scale =
        points.iter().enumerate().map(|(i, _)| point_pos(PointId(i)).norm()).fold(1.0, f64::max);

    let mut joints = Vec::new();
    let mut row_offset = 0;
    let mut joint_keys: BTreeMap<(usize, usize), usize> = BTreeMap::new();
    for (i, j) in spec.joints.iter().enumerate() {
        let e = |field: &str, reason: String| cx.err("joints", i, field, reason);
        let a = lookup(&j.a).ok_or_else(|| e("a", format!("unknown point '{}'", j.a)))?;
        let body_a = points[a.0].body;
        let target = match j.kind {
            JointKindSpec::Ball | JointKindSpec::Hinge | JointKindSpec::Planar
                if j.kind == JointKindSpec::Ball || j.b.is_some() =>
            {
                let bname =
                    j.b.as_ref()
                        .ok_or_else(|| e("b", "missing: a ball joint joins point a to point b".into()))?;
                let b = lookup(bname).ok_or_else(|| e("b", format!("unknown point '{bname}'")))?;
                if points[b.0].body == body_a {
                    return Err(e("b", "both points are on the same body".into()));
                }
                if j.at.is_some() {
                    return Err(e(
                        "at",
                        "a joint between two bodies sits where its points meet; only supports (pin, roller, slider, planar, hinge without b) take `at`".into(),
                    ));
                }
                if bodies[body_a.0].dof_count == 0 && bodies[points[b.0].body.0].dof_count == 0 {
                    return Err(e("a", "both bodies are fixed: the joint holds nothing".into()));
                }
                JointTarget::Point(b)
            }
            JointKindSpec::Ball
            | JointKindSpec::Hinge
            | JointKindSpec::Pin
            | JointKindSpec::Roller
            | JointKindSpec::Slider
            | JointKindSpec::Planar => {
                if j.b.is_some() {
                    return Err(e(
                        "b",
                        "a pin, roller or slider holds one point to the ground; use kind = \"ball\", \"hinge\" or \"planar\" to join two bodies".into(),
                    ));
                }
                if bodies[body_a.0].dof_count == 0 {
                    return Err(e("a", "the point is on a fixed body: nothing to pin".into()));
                }
                let at = match j.at {
                    Some(v) => {
                        bounded3(&v, limits::MAX_COORDINATE, "m").map_err(|r| e("at", r))?;
                        Vector3::from(v)
                    }
                    None => point_pos(a),
                };
                JointTarget::World(at)
            }
        };
        let held = support_directions(j, rows).map_err(|(f, r)| e(f, r))?;
        let (kind, directions, joint_rows) = (held.kind, held.directions, held.rows);
        let gap = match target {
            JointTarget::Point(b) => point_pos(a) - point_pos(b),
            JointTarget::World(x) => point_pos(a) - x,
        };
        // a roller or slider needs its point on its line or plane, not at `at`
        let held_gap = match &directions {
            None => gap.norm(),
            Some(d) => (d * gap).rows(0, joint_rows).norm(),
        };
        if held_gap > 1e-9 * length_scale {
            let reason = match kind {
                crate::model::JointKind::Roller => format!(
                    "the point is {held_gap:.3e} m off the roller's line at the start; it must lie on it"
                ),
                crate::model::JointKind::Slider => format!(
                    "the point is {held_gap:.3e} m off the slider's plane at the start; it must lie in it"
                ),
                crate::model::JointKind::Planar => format!(
                    "the point is {held_gap:.3e} m off the planar joint's plane (through {}, normal `normal`) at the start; it must lie in it",
                    j.b.as_deref().or(j.at.map(|_| "`at`")).unwrap_or("the point's start")
                ),
                _ => {
                    format!("the joint's points are {held_gap:.3e} m apart at the start; they must coincide")
                }
            };
            return Err(e("a", reason));
        }
        // the same pin, or the same pair of points joined again, only repeats constraint rows: the
        // equations become singular (and a long list of repeats makes every solve slow)
        // (a roller and a slider on one point may be meant; the rank test below judges them)
        let key = match (target, j.kind) {
            (JointTarget::Point(b), _) => Some((a.0.min(b.0), a.0.max(b.0))),
            (JointTarget::World(_), JointKindSpec::Pin | JointKindSpec::Hinge) => Some((a.0, usize::MAX)),
            _ => None,
        };
        if let Some(first) = key.and_then(|key| joint_keys.insert(key, i)) {
            return Err(e(
                "a",
                format!("joints[{first}] already holds these points: the constraint would be repeated (redundant)"),
            ));
        }
        // a planar joint's plane turns with a moving body b: its normal is kept in b's frame
        let (directions, plane_normal) = match (target, held.aligned_axis) {
            (JointTarget::Point(b), Some(n))
                if kind == crate::model::JointKind::Planar && bodies[points[b.0].body.0].dof_count > 0 =>
            {
                let body_b = &bodies[points[b.0].body.0];
                if bar_across(bodies, points[b.0].body, &n).is_some() {
                    return Err(e(
                        "normal",
                        "a plane through a bar's point turns with the bar, which turns freely about its own axis: only a plane normal to the bar is held (normal along the bar); make the body kind = \"rigid\" (with an inertia)".into(),
                    ));
                }
                (None, Some(body_b.initial_pose.rotation.inverse() * n))
            }
            _ => (directions, None),
        };
        let damping = match j.damping {
            None => 0.0,
            Some(c) => {
                let c = in_range(c, limits::DAMPING, "N m s/rad").map_err(|r| e("damping", r))?;
                let turns =
                    |b: crate::model::BodyId| matches!(bodies[b.0].kind, BodyKind::Bar | BodyKind::Rigid);
                let other = match target {
                    JointTarget::Point(b) => Some(points[b.0].body),
                    JointTarget::World(_) => None,
                };
                let still = |b: crate::model::BodyId| bodies[b.0].kind == BodyKind::Fixed;
                if !turns(body_a) || other.is_some_and(|b| !turns(b) && !still(b)) {
                    return Err(e(
                        "damping",
                        "joint damping resists the relative spin of two bodies that turn (bar, rigid) or of one and the ground; a node has no spin".into(),
                    ));
                }
                c
            }
        };
        let other_body = match target {
            JointTarget::Point(b) => Some(points[b.0].body),
            JointTarget::World(_) => None,
        };
        // a hinge's or planar joint's axis rows
        let alignment = match held.aligned_axis {
            None => None,
            Some(axis) => {
                let orients = |b: crate::model::BodyId| {
                    matches!(bodies[b.0].kind, BodyKind::Bar | BodyKind::Rigid | BodyKind::Fixed)
                };
                if !orients(body_a) || other_body.is_some_and(|b| !orients(b)) {
                    return Err(e(
                        "a",
                        format!(
                            "a {} holds the orientation of bodies that turn (bar, rigid) or are fixed; a node has none",
                            if j.kind == JointKindSpec::Hinge { "hinge" } else { "planar joint" }
                        ),
                    ));
                }
                Some(axis_alignment(&axis, bodies, body_a, other_body).map_err(|r| e("b", r))?)
            }
        };
        let base = JointModel {
            point: a,
            target,
            row_offset,
            rows: joint_rows,
            directions,
            kind,
            damping,
            alignment: None,
            plane_normal,
            scene_index: i,
        };
        joints.push(base);
        row_offset += joint_rows;
        if let Some((alignment, rows)) = alignment {
            joints.push(JointModel {
                row_offset,
                rows,
                directions: None,
                damping: 0.0,
                alignment: Some(alignment),
                plane_normal: None,
                ..base
            });
            row_offset += rows;
        }
    }

    Ok(joints)
}

/// The initial direction `d` of `body`'s axis (its body z) when it is a bar not along `axis`
/// (`|d x axis| > 1e-6`): a bar turns freely about its own axis, so a joint turning about `axis`
/// can hold only its angle to it (and a plane that turns with it only when normal to it).
fn bar_across(bodies: &[BodyModel], body: crate::model::BodyId, axis: &Vector3<f64>) -> Option<Vector3<f64>> {
    let b = &bodies[body.0];
    let d = b.initial_pose.rotation * Vector3::z();
    (b.kind == BodyKind::Bar && d.cross(axis).norm() > 1e-6).then_some(d)
}

/// The alignment that keeps world axis `axis` (unit, at the initial poses) common to body `a`
/// and body `b` (or the ground), and its row count (`crate::model::Alignment`): two unit normals
/// to it in `a`'s frame and the axis in `b`'s (2 rows); with a bar on one side and the axis not
/// along it (`|d x axis| > 1e-6`), the bar's angle to the axis (1 row). Two bars are refused:
/// each turns freely about its own axis, so together they hold no axis a ball joint does not.
fn axis_alignment(
    axis: &Vector3<f64>,
    bodies: &[BodyModel],
    a: crate::model::BodyId,
    b: Option<crate::model::BodyId>,
) -> Result<(crate::model::Alignment, usize), String> {
    let to_body =
        |body: crate::model::BodyId, v: &Vector3<f64>| bodies[body.0].initial_pose.rotation.inverse() * v;
    let in_b = |v: &Vector3<f64>| match b {
        Some(b) => to_body(b, v),
        None => *v,
    };
    let is_bar = |body: crate::model::BodyId| bodies[body.0].kind == BodyKind::Bar;
    if is_bar(a) && b.is_some_and(is_bar) {
        return Err("a bar turns freely about its own axis, so between two bars this joint holds no axis (it would be a ball joint); make one of them kind = \"rigid\" (with an inertia), or use kind = \"ball\"".into());
    }
    // a bar along the joint's axis keeps both rows, whose moments are normal to it
    if let Some(d) = bar_across(bodies, a, axis) {
        let normals = [Vector3::z(), Vector3::zeros()];
        return Ok((crate::model::Alignment { normals, axis: in_b(axis), offset: d.dot(axis) }, 1));
    }
    if let Some(d) = b.and_then(|b| bar_across(bodies, b, axis)) {
        let normals = [to_body(a, axis), Vector3::zeros()];
        return Ok((crate::model::Alignment { normals, axis: Vector3::z(), offset: d.dot(axis) }, 1));
    }
    let helper = if axis.x.abs() < 0.9 { Vector3::x() } else { Vector3::y() };
    let n1 = axis.cross(&helper).normalize();
    let n2 = axis.cross(&n1);
    Ok((
        crate::model::Alignment {
            normals: [to_body(a, &n1), to_body(a, &n2)],
            axis: in_b(axis),
            offset: 0.0,
        },
        2,
    ))
}

/// The contact spheres the bodies declare (`contact_radius`, `contact_points`), in body order.
fn build_contact_spheres(
    spec: &SceneSpec,
    cx: &Ctx,
    bodies: &[BodyModel],
    point_names: &BTreeMap<String, PointId>,
) -> Result<Vec<ContactSphere>, SceneError> {
    let mut spheres = Vec::new();
    for (i, b) in spec.bodies.iter().enumerate() {
        let e = |field: &str, reason: String| cx.err("bodies", i, field, reason);
        let Some(radius) = b.contact_radius else {
            if b.contact_points.is_some() {
                return Err(e("contact_points", "contact points need a contact_radius (m, may be 0)".into()));
            }
            continue;
        };
        let radius = in_range(radius, limits::CONTACT_RADIUS, "m").map_err(|r| e("contact_radius", r))?;
        let names: Vec<String> = match (bodies[i].kind, &b.contact_points) {
            (BodyKind::Fixed, _) => {
                return Err(e(
                    "contact_radius",
                    "a fixed body does not move: model the ground as a [[grounds]] half-space".into(),
                ))
            }
            (BodyKind::Node, Some(_)) => {
                return Err(e(
                    "contact_points",
                    "a node's contact sphere is centred on the node itself".into(),
                ))
            }
            (BodyKind::Node, None) => vec![String::new()],
            (BodyKind::Bar, None) => vec!["a".into(), "b".into()],
            (BodyKind::Rigid, None) => {
                return Err(e(
                    "contact_points",
                    "missing: name the rigid body's points that carry contact spheres".into(),
                ))
            }
            (_, Some(list)) if list.is_empty() => {
                return Err(e("contact_points", "empty: name at least one point".into()))
            }
            (_, Some(list)) => list.clone(),
        };
        for name in names {
            let qualified = if name.is_empty() { b.name.clone() } else { format!("{}.{}", b.name, name) };
            let point = point_names
                .get(&qualified)
                .copied()
                .ok_or_else(|| e("contact_points", format!("body '{}' has no point '{name}'", b.name)))?;
            if spheres.iter().any(|s: &ContactSphere| s.point == point) {
                return Err(e("contact_points", format!("point '{name}' is listed twice")));
            }
            spheres.push(ContactSphere { point, radius });
        }
    }
    Ok(spheres)
}

/// The grounds (`[[grounds]]`): unit normals, offsets, contact laws with their defaults.
fn build_grounds(
    spec: &SceneSpec,
    cx: &Ctx,
    bodies: &[BodyModel],
    points: &[PointModel],
) -> Result<Vec<GroundModel>, SceneError> {
    let default_stiffness = default_contact_stiffness(spec, bodies, points);
    let mut grounds: Vec<GroundModel> = Vec::new();
    for (i, g) in spec.grounds.iter().enumerate() {
        let e = |field: &str, reason: String| cx.err("grounds", i, field, reason);
        let name = match &g.name {
            Some(n) if n.is_empty() || n.contains(char::is_whitespace) => {
                return Err(e("name", format!("'{n}' is not a valid name (non-empty, no spaces)")))
            }
            Some(n) => n.clone(),
            None if i == 0 => "ground".into(),
            None => format!("ground{i}"),
        };
        if grounds.iter().any(|o| o.name == name) {
            return Err(e("name", format!("duplicate ground name '{name}'")));
        }
        let gravity = Vector3::from(spec.gravity);
        let normal = match g.normal {
            Some(v) => {
                bounded3(&v, limits::MAX_COORDINATE, "").map_err(|r| e("normal", r))?;
                let n = Vector3::from(v);
                if n.norm() < 1e-12 {
                    return Err(e("normal", "must not be zero: the direction the free side lies in".into()));
                }
                n.normalize()
            }
            None if gravity.norm() > 0.0 => (-gravity.normalize()).map(|x| x + 0.0),
            None if spec.planar => Vector3::y(),
            None => Vector3::z(),
        };
        if spec.planar && normal.z.abs() > 1e-12 {
            return Err(e("normal", "in a planar scene a ground's normal lies in the xy plane".into()));
        }
        let point = match g.point {
            Some(v) => {
                bounded3(&v, limits::MAX_COORDINATE, "m").map_err(|r| e("point", r))?;
                Vector3::from(v)
            }
            None => Vector3::zeros(),
        };
        let law = [g.stiffness, g.dissipation, g.mu, g.stiction_speed];
        let material = contact_material(law, default_stiffness, 1.0, &e)?;
        grounds.push(GroundModel { name, normal, offset: normal.dot(&point), material });
    }
    Ok(grounds)
}

/// Default friction coefficient between struts (`[collisions] mu`).
const STRUT_FRICTION: f64 = 0.3;

/// A contact law from a table's optional `[stiffness, dissipation, mu, stiction_speed]`, each
/// checked against its range, with the defaults (`default_stiffness`, 1 s/m, `default_mu`,
/// 1e-5 m/s); `e(field, reason)` makes the error that names the field.
fn contact_material(
    [stiffness, dissipation, mu, stiction_speed]: [Option<f64>; 4],
    default_stiffness: f64,
    default_mu: f64,
    e: &dyn Fn(&str, String) -> SceneError,
) -> Result<ContactMaterial, SceneError> {
    let number = |x: Option<f64>, default: f64, range, unit, field: &str| match x {
        None => Ok(default),
        Some(x) => in_range(x, range, unit).map_err(|r| e(field, r)),
    };
    Ok(ContactMaterial {
        stiffness: number(stiffness, default_stiffness, limits::CONTACT_STIFFNESS, "N/m", "stiffness")?,
        dissipation: number(dissipation, 1.0, limits::CONTACT_DISSIPATION, "s/m", "dissipation")?,
        friction: number(mu, default_mu, limits::FRICTION, "", "mu")?,
        stiction_speed: number(stiction_speed, 1e-5, limits::STICTION_SPEED, "m/s", "stiction_speed")?,
    })
}

/// The default penalty stiffness of grounds and strut collisions, N/m: the structure's whole
/// weight on one contact presses it in by a thousandth of the scene's size (at least 1e3).
fn default_contact_stiffness(spec: &SceneSpec, bodies: &[BodyModel], points: &[PointModel]) -> f64 {
    let weight = bodies.iter().map(|b| b.mass).sum::<f64>() * Vector3::from(spec.gravity).norm();
    (1000.0 * weight / scene_size(bodies, points)).max(1e3)
}

/// The strut pairs of `[collisions]` and their contact law (none and an unused default without
/// the table). A pair's bars both need a `contact_radius`; `all` leaves out pairs a joint joins
/// (they touch at the joint by design); no pair may start with its capsules pressed into each
/// other by more than `START_PENETRATION` of the scene's size.
fn build_strut_pairs(
    spec: &SceneSpec,
    cx: &Ctx,
    bodies: &[BodyModel],
    points: &[PointModel],
    point_names: &BTreeMap<String, PointId>,
    joints: &[JointModel],
) -> Result<(Vec<StrutPair>, ContactMaterial), SceneError> {
    let default_stiffness = default_contact_stiffness(spec, bodies, points);
    let Some(c) = &spec.collisions else {
        let unused = contact_material([None; 4], default_stiffness, STRUT_FRICTION, &|_, _| unreachable!())
            .expect("the defaults are in range");
        return Ok((Vec::new(), unused));
    };
    let e = |field: &str, reason: String| cx.top(&format!("collisions.{field}"), reason);
    let law = [c.stiffness, c.dissipation, c.mu, c.stiction_speed];
    let material = contact_material(law, default_stiffness, STRUT_FRICTION, &e)?;
    let capsule = |b: usize| -> Option<(PointId, PointId, f64)> {
        let body = &spec.bodies[b];
        let radius = body.contact_radius?;
        if bodies[b].kind != BodyKind::Bar {
            return None;
        }
        let end = |x: &str| point_names.get(&format!("{}.{x}", body.name)).copied();
        Some((end("a")?, end("b")?, radius))
    };
    let joined = |a: usize, b: usize| {
        joints.iter().any(|j| {
            let body_of = |p: PointId| points[p.0].body.0;
            match j.target {
                JointTarget::Point(q) => {
                    let pair = (body_of(j.point), body_of(q));
                    pair == (a, b) || pair == (b, a)
                }
                JointTarget::World(_) => false,
            }
        })
    };
    let mut chosen: Vec<(usize, usize)> = Vec::new();
    match &c.pairs {
        None => {
            chosen = all_bar_pairs(spec, bodies, &joined, &capsule);
        }
        Some(CollisionPairsSpec::Word(w)) if w == "all" => {
            chosen = all_bar_pairs(spec, bodies, &joined, &capsule);
        }
        Some(CollisionPairsSpec::Word(w)) => {
            return Err(e(
                "pairs",
                format!("'{w}' is neither \"all\" nor a list of bar pairs like [[\"s1\", \"s2\"]]"),
            ))
        }
        Some(CollisionPairsSpec::List(list)) => {
            if list.is_empty() {
                return Err(e("pairs", "empty: name at least one pair of bars, or write \"all\"".into()));
            }
            for [x, y] in list {
                let find = |name: &str| {
                    let b = bodies
                        .iter()
                        .position(|b| b.name == name)
                        .ok_or_else(|| e("pairs", format!("no body called '{name}'")))?;
                    if bodies[b].kind != BodyKind::Bar {
                        return Err(e(
                            "pairs",
                            format!(
                                "'{name}' is a {}: only bars collide (capsules)",
                                bodies[b].kind.as_str()
                            ),
                        ));
                    }
                    if capsule(b).is_none() {
                        return Err(e(
                            "pairs",
                            format!("bar '{name}' has no contact_radius (its capsule's radius, m)"),
                        ));
                    }
                    Ok(b)
                };
                let (a, b) = (find(x)?, find(y)?);
                if a == b {
                    return Err(e("pairs", format!("['{x}', '{y}'] names one bar twice")));
                }
                if joined(a, b) {
                    return Err(e(
                        "pairs",
                        format!("'{x}' and '{y}' are joined by a joint, where their capsules always touch"),
                    ));
                }
                if chosen.iter().any(|&(p, q)| (p, q) == (a, b) || (q, p) == (a, b)) {
                    return Err(e("pairs", format!("['{x}', '{y}'] is listed twice")));
                }
                chosen.push((a, b));
            }
        }
    }
    if chosen.is_empty() {
        return Err(e(
            "pairs",
            "no pair of bars can collide: give at least two bars (not joined by a joint) a contact_radius (m)".into(),
        ));
    }
    let allowance = START_PENETRATION * scene_size(bodies, points);
    let mut pairs = Vec::with_capacity(chosen.len());
    for (a, b) in chosen {
        let ((pa, pb, ra), (pc, pd, rb)) = (capsule(a).expect("checked"), capsule(b).expect("checked"));
        let at = |p: PointId| bodies[points[p.0].body.0].initial_pose.transform_point(&points[p.0].local);
        let cp = crate::forces::collision::closest_points(&at(pa), &at(pb), &at(pc), &at(pd));
        let depth = ra + rb - cp.w.norm();
        if depth > allowance {
            return Err(e(
                "pairs",
                format!(
                    "bars '{}' and '{}' start with their capsules {} m into each other: move them apart, or leave \
                     the pair out with a list of pairs",
                    bodies[a].name,
                    bodies[b].name,
                    readable_number(depth)
                ),
            ));
        }
        pairs.push(StrutPair { bars: [BodyId(a), BodyId(b)], ends: [pa, pb, pc, pd], radius: ra + rb });
    }
    Ok((pairs, material))
}

/// Every two bars with a capsule that no joint joins, in scene order.
fn all_bar_pairs(
    spec: &SceneSpec,
    bodies: &[BodyModel],
    joined: &dyn Fn(usize, usize) -> bool,
    capsule: &dyn Fn(usize) -> Option<(PointId, PointId, f64)>,
) -> Vec<(usize, usize)> {
    let bars: Vec<usize> =
        (0..bodies.len().min(spec.bodies.len())).filter(|&b| capsule(b).is_some()).collect();
    let mut out = Vec::new();
    for (i, &a) in bars.iter().enumerate() {
        for &b in &bars[i + 1..] {
            if !joined(a, b) {
                out.push((a, b));
            }
        }
    }
    out
}

/// The diagonal of the box around every point at the start, m (at least 1 mm).
fn scene_size(bodies: &[BodyModel], points: &[PointModel]) -> f64 {
    let at = |p: &PointModel| bodies[p.body.0].initial_pose.transform_point(&p.local);
    let (mut lo, mut hi) = (Vector3::repeat(f64::INFINITY), Vector3::repeat(f64::NEG_INFINITY));
    for p in points {
        lo = lo.inf(&at(p));
        hi = hi.sup(&at(p));
    }
    (hi - lo).norm().max(1e-3)
}

/// Pressed into a ground by more than this fraction of the scene's size beyond its radius, a
/// contact sphere's start is refused as a misplaced structure.
pub const START_PENETRATION: f64 = 0.01;

/// Grounds and contact spheres come together, and no sphere starts deep inside a ground (more
/// than `START_PENETRATION` of the scene's size beyond its radius: a structure placed under the
/// floor would be thrown out by springs pressed far beyond anything they model).
fn check_contacts(spec: &SceneSpec, model: &Model, cx: &Ctx) -> Result<(), SceneError> {
    if !model.grounds.is_empty() && model.contact_spheres.is_empty() {
        return Err(cx.err(
            "grounds",
            0,
            "",
            "no body declares contact geometry, so nothing would touch this ground: give the bodies \
             that should a contact_radius (m)",
        ));
    }
    // without grounds, only bars in [collisions] may carry contact geometry
    let stranded = |b: &super::BodySpec| {
        b.contact_radius.is_some() && (spec.collisions.is_none() || b.kind != BodyKindSpec::Bar)
    };
    if model.grounds.is_empty() && spec.bodies.iter().any(stranded) {
        let i = spec.bodies.iter().position(stranded).unwrap_or(0);
        return Err(cx.err(
            "bodies",
            i,
            "contact_radius",
            "there is no [[grounds]] table for the contact spheres to meet",
        ));
    }
    let allowance = START_PENETRATION * scene_size(&model.bodies, &model.points);
    for sphere in &model.contact_spheres {
        let p = &model.points[sphere.point.0];
        let at = model.bodies[p.body.0].initial_pose.transform_point(&p.local);
        for (g, ground) in model.grounds.iter().enumerate() {
            let height = ground.normal.dot(&at) - ground.offset;
            if height < -allowance {
                return Err(cx.err(
                    "grounds",
                    g,
                    "",
                    format!(
                        "'{}' starts {} m inside ground '{}' (its contact sphere's centre is below \
                         the plane by more than a hundredth of the scene's size): place the \
                         structure on or above the ground",
                        p.name,
                        readable_number(-height),
                        ground.name
                    ),
                ));
            }
        }
    }
    Ok(())
}

/// Adds half of each member's mass to each of its ends' bodies: nodes take it, fixed bodies
/// carry it to the ground; a member with mass may not end on a bar or rigid body (its lumped
/// mass would move their centre of mass and inertia). Returns the consistent-mass corrections
/// of the members that ask for them (`MassCoupling`).
fn lump_member_masses(
    spec: &SceneSpec,
    cx: &Ctx,
    bodies: &mut [BodyModel],
    points: &[PointModel],
    point_names: &BTreeMap<String, PointId>,
) -> Result<Vec<MassCoupling>, SceneError> {
    let mut couplings = Vec::new();
    for (i, m) in spec.members.iter().enumerate() {
        let e = |field: &str, reason: String| cx.err("members", i, field, reason);
        let Some(mass) = m.mass else {
            if m.mass_matrix == MassMatrixSpec::Consistent {
                return Err(e("mass_matrix", "a consistent mass matrix needs the member's `mass`".into()));
            }
            continue;
        };
        let mass = in_range(mass, limits::MASS, "kg").map_err(|r| e("mass", r))?;
        let ends = m.ends.each_ref().map(|end| point_names.get(end).map(|p| points[p.0].body));
        if let (MassMatrixSpec::Consistent, [Some(a), Some(b)]) = (m.mass_matrix, ends) {
            if a != b && mass > 0.0 {
                couplings.push(MassCoupling { ends: [a, b], coefficient: mass / 6.0 });
            }
        }
        for end in &m.ends {
            // unknown points are reported by `build_cables` with the route's wording
            let Some(pid) = point_names.get(end) else { continue };
            let body = &mut bodies[points[pid.0].body.0];
            match body.kind {
                BodyKind::Node => body.mass += 0.5 * mass,
                BodyKind::Fixed => {}
                kind => {
                    return Err(e(
                        "mass",
                        format!(
                            "a member's mass is lumped on its ends, which must be nodes or fixed; '{end}' is on the {} '{}'",
                            kind.as_str(),
                            body.name
                        ),
                    ))
                }
            }
        }
    }
    Ok(couplings)
}

/// The cables, their routes, and what sets their rest lengths and damping (`build_cables`).
struct Cables {
    cables: Vec<CableModel>,
    cable_names: Vec<String>,
    route_points: Vec<PointId>,
    rest_specs: Vec<RestLengthSpec>,
    damping_ratios: Vec<Option<f64>>,
}

/// A member as the two-point cable that pushes, and whether it asks for form finding.
fn member_as_cable(m: &super::MemberSpec) -> (CableSpec, bool) {
    let cable = CableSpec {
        name: m.name.clone(),
        route: m.ends.to_vec(),
        ea: m.ea,
        damping: m.damping,
        damping_ratio: m.damping_ratio,
        rest_length: m.rest_length,
        prestress: m.force,
        force_density: None,
        tension_only: false,
        pulley_friction: None,
        winch_end: None,
    };
    (cable, m.form_find)
}

/// Checks and builds `cables` and then `members` (names, routes through known points, EA, rest
/// length or prestress (a member's force) or force density, damping or damping ratio).
fn build_cables(
    spec: &SceneSpec,
    cx: &Ctx,
    point_names: &BTreeMap<String, PointId>,
) -> Result<Cables, SceneError> {
    let lookup = |name: &str| point_names.get(name).copied();

    let mut cables = Vec::new();
    let mut cable_names: Vec<String> = Vec::new();
    let mut route_points = Vec::new();
    let mut rest_specs = Vec::new();
    let mut damping_ratios = Vec::new();
    // members are cables that push: one list, cables first
    let members: Vec<(CableSpec, bool)> = spec.members.iter().map(member_as_cable).collect();
    let elements = spec
        .cables
        .iter()
        .enumerate()
        .map(|(i, c)| ("cables", i, c, false))
        .chain(members.iter().enumerate().map(|(i, (c, form_find))| ("members", i, c, *form_find)));
    for (array, i, c, form_find) in elements {
        let e = |field: &str, reason: String| cx.err(array, i, field, reason);
        let member = array == "members";
        let route_field = if member { "ends" } else { "route" };
        if c.name.is_empty() {
            return Err(e("name", "must not be empty".into()));
        }
        if cable_names.contains(&c.name) {
            let what = if member { "member name (members and cables share one list)" } else { "cable name" };
            return Err(e("name", format!("duplicate {what} '{}'", c.name)));
        }
        if !c.tension_only && c.route.len() != 2 {
            return Err(e(
                "tension_only",
                format!("only a two-point cable may push; this route has {} points (pulleys)", c.route.len()),
            ));
        }
        if c.route.len() < 2 {
            return Err(e(route_field, format!("a cable needs at least two points, got {}", c.route.len())));
        }
        if c.route.len() > limits::MAX_ROUTE_POINTS {
            return Err(e(
                "route",
                format!("a route has at most {} points, got {}", limits::MAX_ROUTE_POINTS, c.route.len()),
            ));
        }
        let start = route_points.len();
        for (k, pname) in c.route.iter().enumerate() {
            let p = lookup(pname).ok_or_else(|| {
                let body = pname.split('.').next().unwrap_or("");
                if spec.bodies.iter().any(|b| b.name == body) {
                    e(route_field, format!("body '{body}' has no point '{pname}'"))
                } else {
                    e(route_field, format!("unknown body in '{pname}'"))
                }
            })?;
            if k > 0 && route_points[start + k - 1] == p {
                return Err(e(route_field, format!("the route visits '{pname}' twice in a row")));
            }
            route_points.push(p);
        }
        in_range(c.ea, limits::EA, "N").map_err(|r| e("ea", format!("EA {r}")))?;
        let given = [c.rest_length.is_some(), c.prestress.is_some(), c.force_density.is_some()];
        if given.iter().filter(|g| **g).count() > 1 {
            let field = if c.force_density.is_some() { "force_density" } else { "prestress" };
            return Err(e(
                if member { "force" } else { field },
                if member {
                    "give at most one of rest_length and force, not both".into()
                } else {
                    "give at most one of rest_length, prestress and force_density, not both".into()
                },
            ));
        }
        if form_find && given.iter().any(|g| *g) {
            return Err(e(
                "form_find",
                "form_find sets the rest length: give no rest_length or force".into(),
            ));
        }
        let prestress_field = if member { "force" } else { "prestress" };
        let rest = match (c.rest_length, c.prestress, c.force_density) {
            (Some(l), _, _) => {
                RestLengthSpec::Given(in_range(l, limits::LENGTH, "m").map_err(|r| e("rest_length", r))?)
            }
            (_, Some(t), _) if t.is_finite() && t.abs() > limits::PRESTRESS.1 => {
                return Err(e(prestress_field, in_range(t.abs(), limits::PRESTRESS, "N").unwrap_err()))
            }
            (_, _, Some(q)) if q.is_finite() && q > limits::FORCE_DENSITY.1 => {
                return Err(e("force_density", in_range(q, limits::FORCE_DENSITY, "N/m").unwrap_err()))
            }
            (_, Some(t), _) if t.is_finite() && (t >= 0.0 || !c.tension_only) => {
                if t <= -c.ea {
                    return Err(e(
                        prestress_field,
                        format!("a compression of {} N is at least EA ({} N): no rest length gives it", -t, c.ea),
                    ));
                }
                RestLengthSpec::Prestress(t)
            }
            (_, Some(t), _) if t.is_finite() => {
                return Err(e(
                    "prestress",
                    format!("a cable can only pull: prestress must be >= 0, got {t} (tension_only = false lets a two-point cable push)"),
                ))
            }
            (_, Some(t), _) => return Err(e(prestress_field, format!("must be a finite number, got {t}"))),
            (_, _, Some(q)) if q.is_finite() && q >= 0.0 => RestLengthSpec::ForceDensity(q),
            (_, _, Some(q)) => {
                return Err(e(
                    "force_density",
                    format!("a cable can only pull: force density must be >= 0, got {q}"),
                ))
            }
            (None, None, None) if member && !form_find => RestLengthSpec::Unstressed,
            (None, None, None) => RestLengthSpec::Free,
        };
        let (damping, ratio) = match (c.damping, c.damping_ratio) {
            (Some(_), Some(_)) => {
                return Err(e("damping_ratio", "give damping or damping_ratio, not both".into()))
            }
            (Some(d), None) => (in_range(d, limits::DAMPING, "N s/m").map_err(|r| e("damping", r))?, None),
            (None, Some(z)) => {
                (0.0, Some(in_range(z, limits::DAMPING_RATIO, "").map_err(|r| e("damping_ratio", r))?))
            }
            (None, None) => (0.0, None),
        };
        rest_specs.push(rest);
        damping_ratios.push(ratio);
        cables.push(CableModel {
            route_start: start,
            route_len: c.route.len(),
            axial_stiffness: c.ea,
            damping,
            tension_only: c.tension_only,
            buckling_load: f64::INFINITY,
            friction: None,
            winch: None,
        });
        cable_names.push(c.name.clone());
    }

    Ok(Cables { cables, cable_names, route_points, rest_specs, damping_ratios })
}

/// Checks and builds `actuators` (one per cable, length and rate limits): the actuators and
/// their names.
fn build_actuators(spec: &SceneSpec, cx: &Ctx, cable_names: &[String]) -> Result<Actuators, SceneError> {
    let mut winches = Vec::new();
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
        in_range(a.min_rest_length, limits::LENGTH, "m").map_err(|r| e("min_rest_length", r))?;
        in_range(a.max_rest_length, limits::LENGTH, "m").map_err(|r| e("max_rest_length", r))?;
        if a.max_rest_length < a.min_rest_length {
            return Err(e(
                "max_rest_length",
                format!("must be >= min_rest_length, got {}", a.max_rest_length),
            ));
        }
        in_range(a.max_rate, limits::RATE, "m/s").map_err(|r| e("max_rate", r))?;
        if a.command_delay > limits::COMMAND_DELAY {
            return Err(e(
                "command_delay",
                format!("must be at most {} steps, got {}", limits::COMMAND_DELAY, a.command_delay),
            ));
        }
        let winch = match &a.winch {
            Some(w) => {
                let id = crate::model::ActuatorId(actuators.len());
                winches.push(build_winch(w, id, crate::model::CableId(cable), &e)?);
                Some(winches.len() - 1)
            }
            None => None,
        };
        actuators.push(ActuatorModel {
            cable: crate::model::CableId(cable),
            min_rest_length: a.min_rest_length,
            max_rest_length: a.max_rest_length,
            max_rate: a.max_rate,
            command_delay: a.command_delay,
            winch,
        });
        actuator_names.push(a.name.clone());
    }

    Ok(Actuators { actuators, actuator_names, winches })
}

/// What `build_actuators` gives: the actuators, their names, and the winch motors of those that
/// have one.
struct Actuators {
    actuators: Vec<ActuatorModel>,
    actuator_names: Vec<String>,
    winches: Vec<WinchModel>,
}

/// Checks one `[actuators.winch]` table and gives its model: the torque-speed line in rope units
/// from `stall_tension` and `no_load_speed`, or from a DC motor (`T_s = N k_t V / (R r)`,
/// `v0 = r V / (N k_t)`), never both; `e(field, reason)` names the actuator.
fn build_winch(
    w: &WinchSpec,
    actuator: crate::model::ActuatorId,
    cable: crate::model::CableId,
    e: &dyn Fn(&str, String) -> SceneError,
) -> Result<WinchModel, SceneError> {
    let positive = |x: f64, field: &str, unit: &str| {
        in_range(x, limits::WINCH, unit).map_err(|r| e(&format!("winch.{field}"), r))
    };
    let r = positive(w.drum_radius, "drum_radius", "m")?;
    let dc = [w.torque_constant, w.resistance, w.voltage];
    let (stall_tension, no_load_speed) = match (w.stall_tension, w.no_load_speed, dc) {
        (Some(t), Some(v), [None, None, None]) if w.gear_ratio.is_none() => {
            (positive(t, "stall_tension", "N")?, positive(v, "no_load_speed", "m/s")?)
        }
        (None, None, [Some(kt), Some(res), Some(volt)]) => {
            let kt = positive(kt, "torque_constant", "N m/A")?;
            let res = positive(res, "resistance", "ohm")?;
            let volt = positive(volt, "voltage", "V")?;
            let n = positive(w.gear_ratio.unwrap_or(1.0), "gear_ratio", "")?;
            (n * kt * volt / (res * r), r * volt / (n * kt))
        }
        _ => {
            return Err(e(
                "winch",
                "give either stall_tension and no_load_speed, or torque_constant, resistance and \
                 voltage (with an optional gear_ratio)"
                    .into(),
            ))
        }
    };
    let nonnegative = |x: f64, field: &str, unit: &str| {
        in_range(x, (0.0, limits::WINCH.1), unit).map_err(|r| e(&format!("winch.{field}"), r))
    };
    let rotor_inertia = nonnegative(w.rotor_inertia, "rotor_inertia", "kg m^2")?;
    let viscous_friction = nonnegative(w.viscous_friction, "viscous_friction", "N m s/rad")?;
    let max_acceleration = match w.max_acceleration {
        Some(a) => positive(a, "max_acceleration", "m/s^2")?,
        None => f64::INFINITY,
    };
    let [kp, ki, kd] = w.position_gains.unwrap_or([20.0, 100.0, 0.0]);
    for (g, name) in [(kp, "kp"), (ki, "ki"), (kd, "kd")] {
        nonnegative(g, &format!("position_gains.{name}"), "")?;
    }
    Ok(WinchModel {
        actuator,
        cable,
        drum_radius: r,
        stall_tension,
        no_load_speed,
        rotor_inertia,
        viscous_friction,
        back_drivable: w.back_drivable,
        max_acceleration,
        gains: PositionGains { kp, ki, kd },
    })
}

/// The `[damping]` coefficients, checked.
/// Checks `[sensors]` and gives the sensor model: each channel's noise, bias and resolution
/// (`>= 0`, bias of either sign), delay, rate (> 0) and dropout (`[0, 1)`); an orientation takes
/// no bias or resolution.
fn build_sensors(spec: &SceneSpec, cx: &Ctx) -> Result<crate::sensors::SensorModel, SceneError> {
    use crate::sensors::{ChannelModel, SensorKind, SensorModel};
    let Some(s) = &spec.sensors else {
        return Ok(SensorModel::default());
    };
    let declared =
        [&s.tension, &s.length, &s.rest_length, &s.position, &s.orientation, &s.gyro, &s.accelerometer];
    let mut channels = Vec::new();
    for (kind, c) in SensorKind::ALL.into_iter().zip(declared) {
        let Some(c) = c else { continue };
        let table = format!("sensors.{}", kind.name());
        let e = |field: &str, r: String| cx.top(&format!("{table}.{field}"), r);
        let value = |x: f64, field: &str| in_range(x, limits::SENSOR_VALUE, "").map_err(|r| e(field, r));
        let sigma = value(c.sigma, "sigma")?;
        let resolution = value(c.resolution, "resolution")?;
        let bias = if c.bias.is_finite() && c.bias.abs() <= limits::SENSOR_VALUE.1 {
            c.bias
        } else {
            return Err(e("bias", format!("must be finite, within +-1e12, got {}", c.bias)));
        };
        if kind == SensorKind::Orientation && (bias != 0.0 || resolution != 0.0) {
            return Err(e(
                "bias",
                "an orientation sensor has noise (sigma, rad) but no bias or resolution".into(),
            ));
        }
        if c.delay > limits::COMMAND_DELAY {
            return Err(e(
                "delay",
                format!("must be at most {} steps, got {}", limits::COMMAND_DELAY, c.delay),
            ));
        }
        let period = match c.rate {
            Some(r) => 1.0 / in_range(r, limits::SENSOR_RATE, "Hz").map_err(|r| e("rate", r))?,
            None => 0.0,
        };
        if !(c.dropout >= 0.0 && c.dropout < 1.0) {
            return Err(e("dropout", format!("must be in [0, 1), got {}", c.dropout)));
        }
        channels.push((
            kind,
            ChannelModel { sigma, bias, resolution, delay: c.delay, period, dropout: c.dropout },
        ));
    }
    Ok(SensorModel { seed: s.seed, channels })
}

/// Checks `[randomize]` against `model` (built as written) and gives the declarations: a known
/// parameter, elements that have it (a cable for `ea`, `damping`, `rest_length` and
/// `pulley_friction`, a body with mass for `mass`; every such one by default), a distribution with
/// its fields, factors that stay positive and rest lengths that stay above zero within six
/// standard deviations, and no `rest_length` on a cable with pulley friction.
fn build_randomization(
    r: &super::RandomizeSpec,
    model: &Model,
    cx: &Ctx,
) -> Result<crate::randomize::Randomization, SceneError> {
    use crate::randomize::{DrawDistribution, Parameter, RandomParameter};
    let mut parameters = Vec::new();
    for (i, p) in r.parameters.iter().enumerate() {
        let e = |field: &str, reason: String| cx.err("randomize.parameters", i, field, reason);
        let parameter = Parameter::parse(&p.parameter).ok_or_else(|| {
            e(
                "parameter",
                format!("'{}' is not ea, damping, mass, rest_length or pulley_friction", p.parameter),
            )
        })?;
        let finite = |x: Option<f64>, field: &str| match x {
            Some(x) if x.is_finite() => Ok(x),
            Some(x) => Err(e(field, format!("must be finite, got {x}"))),
            None => Err(e(field, format!("a {} distribution needs {field}", p.distribution))),
        };
        let distribution = match p.distribution.as_str() {
            "uniform" => {
                let (low, high) = (finite(p.low, "low")?, finite(p.high, "high")?);
                if high <= low {
                    return Err(e("high", format!("must be above low ({low}), got {high}")));
                }
                DrawDistribution::Uniform { low, high }
            }
            "normal" | "lognormal" => {
                let (mean, sigma) = (finite(p.mean, "mean")?, finite(p.sigma, "sigma")?);
                if sigma <= 0.0 {
                    return Err(e("sigma", format!("must be positive, got {sigma}")));
                }
                if p.distribution == "normal" {
                    DrawDistribution::Normal { mean, sigma }
                } else {
                    DrawDistribution::LogNormal { mean, sigma }
                }
            }
            other => {
                return Err(e("distribution", format!("'{other}' is not uniform, normal or lognormal")));
            }
        };
        let names: Vec<&String> = if parameter == Parameter::Mass {
            model.bodies.iter().map(|b| &b.name).collect()
        } else {
            model.cable_names.iter().collect()
        };
        let has = |k: usize| match parameter {
            Parameter::Mass => model.bodies[k].mass > 0.0 && model.bodies[k].dof_count > 0,
            Parameter::PulleyFriction => model.cables[k].friction.is_some(),
            _ => true,
        };
        let elements: Vec<usize> = match &p.elements {
            None => (0..names.len()).filter(|&k| has(k)).collect(),
            Some(list) => {
                let mut out = Vec::new();
                for name in list {
                    let k = names.iter().position(|n| *n == name).ok_or_else(|| {
                        let what = if parameter == Parameter::Mass { "body" } else { "cable" };
                        e("elements", format!("unknown {what} '{name}'"))
                    })?;
                    if !has(k) {
                        let why = match parameter {
                            Parameter::Mass => "has no mass that moves",
                            _ => "has no pulley friction",
                        };
                        return Err(e("elements", format!("'{name}' {why}")));
                    }
                    out.push(k);
                }
                out
            }
        };
        let low = distribution.practical_minimum();
        if parameter.is_factor() && low <= 0.0 && !matches!(distribution, DrawDistribution::LogNormal { .. })
        {
            return Err(e(
                "distribution",
                format!("a factor on {} must stay positive: the draws reach {low}", parameter.name()),
            ));
        }
        if parameter == Parameter::RestLength {
            for &k in &elements {
                if model.cables[k].friction.is_some() {
                    return Err(e(
                        "elements",
                        format!("'{}' has pulley friction: its rest length is shared by segments", names[k]),
                    ));
                }
                let l0 = model.initial_rest_lengths[k];
                if l0 + low <= limits::LENGTH.0 {
                    return Err(e(
                        "distribution",
                        format!("'{}': its rest length {l0} m would reach {} m", names[k], l0 + low),
                    ));
                }
            }
        }
        parameters.push(RandomParameter { parameter, elements, distribution });
    }
    Ok(crate::randomize::Randomization { seed: r.seed, parameters })
}

fn build_rayleigh(spec: &SceneSpec, cx: &Ctx) -> Result<crate::model::RayleighDamping, SceneError> {
    let Some(d) = &spec.damping else { return Ok(Default::default()) };
    let alpha = match d.alpha {
        Some(a) => in_range(a, limits::RAYLEIGH_ALPHA, "1/s").map_err(|r| cx.top("damping.alpha", r))?,
        None => 0.0,
    };
    let beta = match d.beta {
        Some(b) => in_range(b, limits::RAYLEIGH_BETA, "s").map_err(|r| cx.top("damping.beta", r))?,
        None => 0.0,
    };
    Ok(crate::model::RayleighDamping { alpha, beta })
}

/// The `[solver]` settings, checked.
fn build_solver(spec: &SceneSpec, cx: &Ctx) -> Result<SolverSettings, SceneError> {
    let mut solver = SolverSettings::default();
    if let Some(s) = &spec.solver {
        if let Some(t) = s.tolerance {
            if !(t.is_finite() && t > 0.0 && t < 1.0) {
                return Err(cx.top("solver", format!("tolerance must be in (0, 1), got {t}")));
            }
            solver.tolerance = t;
        }
        if let Some(n) = s.max_iterations {
            if n == 0 || n > limits::MAX_SOLVER_ITERATIONS {
                return Err(cx.top(
                    "solver",
                    format!("max_iterations must be in [1, {}], got {n}", limits::MAX_SOLVER_ITERATIONS),
                ));
            }
            solver.max_iterations = n;
        }
    }

    Ok(solver)
}

/// Sets the initial rest lengths (form finding where a cable gives a prestress or a force
/// density), the damping of cables given a damping ratio plus Rayleigh's `beta EA / L0`, and checks each actuator's cable
/// starts within its limits. Elements from `spec_cables` on are the scene's members.
fn set_rest_lengths(
    model: &mut Model,
    rest_specs: &[RestLengthSpec],
    damping_ratios: &[Option<f64>],
    spec_cables: usize,
    cx: &Ctx,
) -> Result<(), SceneError> {
    model.initial_rest_lengths = find_rest_lengths(model, rest_specs).map_err(|(cable, reason)| {
        let route = reason == crate::solve::formfind::ZERO_LENGTH;
        match cable {
            Some(c) if c >= spec_cables => {
                cx.err("members", c - spec_cables, if route { "ends" } else { "force" }, reason)
            }
            Some(c) => cx.err("cables", c, if route { "route" } else { "prestress" }, reason),
            None => cx
                .top(if spec_cables == 0 && !model.cables.is_empty() { "members" } else { "cables" }, reason),
        }
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
    // Rayleigh's stiffness-proportional part: each element's material stiffness EA / L0
    let beta = model.rayleigh.beta;
    if beta > 0.0 {
        for (c, cable) in model.cables.iter_mut().enumerate() {
            cable.damping += beta * cable.axial_stiffness / model.initial_rest_lengths[c];
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

    Ok(())
}

/// The `[deployment]` schedule, checked against the actuators' limits (one load step when the
/// scene has none).
fn build_schedule(spec: &SceneSpec, model: &Model, cx: &Ctx) -> Result<Schedule, SceneError> {
    if let Some(d) = &spec.deployment {
        if d.steps == 0 || d.steps > limits::MAX_LOAD_STEPS {
            return Err(cx.top(
                "deployment",
                format!("steps must be in [1, {}], got {}", limits::MAX_LOAD_STEPS, d.steps),
            ));
        }
        let mut ramps = Vec::new();
        for (i, r) in d.ramps.iter().enumerate() {
            let e = |field: &str, reason: String| cx.err("deployment.ramps", i, field, reason);
            let id = model
                .actuator_id(&r.actuator)
                .ok_or_else(|| e("actuator", format!("unknown actuator '{}'", r.actuator)))?;
            in_range(r.start, limits::TIME, "s").map_err(|r| e("start", r))?;
            if in_range(r.duration, limits::TIME, "s").map_err(|r| e("duration", r))? == 0.0 {
                return Err(e("duration", "must be positive, got 0".into()));
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
        Ok(Schedule { ramps: ramps.into_iter().map(|(_, r)| r).collect(), steps: d.steps })
    } else {
        Ok(Schedule { steps: 1, ..Schedule::default() })
    }
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

/// Largest number of joint equations of one group of joined bodies whose independence
/// `check_redundant_joints` checks (a dense rank-revealing QR of the group's block of `Phi_q^T`,
/// about `2 n rows^2` flops: 40 ms for the 576 rows of a 64-stage tower on the development
/// machine).
pub const MAX_REDUNDANCY_CHECK_ROWS: usize = 4000;

/// True when the joint equations are independent at the point kinematics `kin`: a rank check per
/// group of bodies the joints tie together (bodies with coordinates joined by ball joints, found
/// by union-find; a pin ties one body to the ground and joins nothing), each the column-pivoted QR
/// of that group's block of `Phi_q^T` (its joints' rows, its bodies' coordinates), with the
/// relative tolerance `1e-10` of the largest row norm of `Phi_q`. Joints of different groups
/// share no coordinate, so `Phi_q` has full row rank exactly when every block has, and no dense
/// `Phi_q` is formed: a prism of 999 pinned struts is 999 blocks of 3 rows and 5 coordinates,
/// where one QR of the whole `Phi_q^T` (5000 x 3000) took 13.6 s; a tower's stages joined by ball
/// joints are one block, as before. On failure, the joints of every deficient group, in scene
/// order.
fn joints_independent(
    model: &Model,
    poses: &[crate::model::Pose],
    kin: &[crate::kinematics::PointKinematics],
) -> Result<(), Vec<usize>> {
    let mut parent: Vec<usize> = (0..model.bodies.len()).collect();
    fn root(parent: &mut [usize], mut b: usize) -> usize {
        while parent[b] != b {
            parent[b] = parent[parent[b]];
            b = parent[b];
        }
        b
    }
    let body_of = |p: PointId| model.points[p.0].body.0;
    let moving = |b: usize| model.bodies[b].dof_count > 0;
    for joint in &model.joints {
        if let JointTarget::Point(b) = joint.target {
            let (x, y) = (body_of(joint.point), body_of(b));
            // a fixed body has no coordinates: joining through it would merge what is independent
            if moving(x) && moving(y) {
                let (rx, ry) = (root(&mut parent, x), root(&mut parent, y));
                parent[rx] = ry;
            }
        }
    }
    // each group: its joints and its bodies
    let mut groups: BTreeMap<usize, (Vec<usize>, Vec<usize>)> = BTreeMap::new();
    for (j, joint) in model.joints.iter().enumerate() {
        let first = body_of(joint.point);
        let body = match joint.target {
            _ if moving(first) => first,
            JointTarget::Point(b) if moving(body_of(b)) => body_of(b),
            _ => return Err(vec![j]), // a joint on fixed bodies alone holds nothing: a zero row
        };
        let group = root(&mut parent, body);
        groups.entry(group).or_default().0.push(j);
    }
    for b in 0..model.bodies.len() {
        if moving(b) {
            let group = root(&mut parent, b);
            if let Some((_, bodies)) = groups.get_mut(&group) {
                bodies.push(b);
            }
        }
    }
    // each group's block of Phi_q^T (coordinates x rows)
    let blocks: Vec<faer::Mat<f64>> = groups
        .values()
        .map(|(joints, bodies)| {
            let mut column_of = BTreeMap::new();
            for &b in bodies {
                let body = &model.bodies[b];
                for c in 0..body.dof_count {
                    column_of.insert(body.dof_offset + c, column_of.len());
                }
            }
            let total: usize = joints.iter().map(|&j| model.joints[j].rows).sum();
            let mut block = faer::Mat::<f64>::zeros(column_of.len(), total);
            let mut first = 0;
            for &j in joints {
                crate::constraints::add_jacobian_entries(model, poses, kin, &model.joints[j], |r, c, x| {
                    block[(column_of[&c], first + r)] += x;
                });
                first += model.joints[j].rows;
            }
            block
        })
        .collect();
    let scale = blocks
        .iter()
        .flat_map(|b| {
            (0..b.ncols()).map(move |r| (0..b.nrows()).map(|i| b[(i, r)].powi(2)).sum::<f64>().sqrt())
        })
        .fold(0.0, f64::max)
        .max(1e-300);
    let tol = 1e-10 * scale;
    let mut deficient: Vec<usize> = Vec::new();
    for (block, (joints, _)) in blocks.iter().zip(groups.values()) {
        let independent = if block.ncols() > block.nrows() {
            false // more equations than coordinates
        } else if block.ncols() > MAX_REDUNDANCY_CHECK_ROWS {
            true // too large to check (a dense QR)
        } else {
            let qr = block.col_piv_qr();
            let r = qr.thin_R();
            (0..block.ncols()).all(|i| r[(i, i)].abs() > tol)
        };
        if !independent {
            deficient.extend(joints);
        }
    }
    if deficient.is_empty() {
        Ok(())
    } else {
        deficient.sort_unstable();
        Err(deficient)
    }
}

/// Refuses joints whose equations repeat what earlier joints already impose at the initial pose
/// (a bar pinned at both ends and at its middle; a bar pinned at both ends, whose length already
/// fixes the distance between the pins): the joint Jacobian `Phi_q` loses rank, no solver can
/// tell the joints' reactions apart, and the dynamics cannot start. The rank comes from faer's
/// column-pivoted QR of `Phi_q^T`, group by group of joined bodies (`joints_independent`,
/// relative tolerance `1e-10`); only when it is deficient are the
/// rows taken in scene order (Gram-Schmidt) to find the first joint with an equation implied by
/// earlier ones, and a least-squares fit of that equation on the earlier ones names the joints
/// it repeats.
fn check_redundant_joints(model: &Model, cx: &Ctx) -> Result<(), SceneError> {
    use nalgebra::{DMatrix, DVector};
    let n = model.dof_count;
    if model.constraint_count == 0 {
        return Ok(());
    }
    let state = crate::state::State::initial(model);
    let kin: Vec<_> = (0..model.points.len())
        .map(|p| crate::kinematics::point_kinematics(model, &state.poses, &state.velocities, PointId(p)))
        .collect();
    let Err(suspects) = joints_independent(model, &state.poses, &kin) else { return Ok(()) };
    // the deficient groups' rows only (other groups share no coordinate with them)
    // each row's joint (its index in `suspects`) and each joint's first row
    let mut row_joint = Vec::new();
    let mut first_row = Vec::new();
    for (k, &j) in suspects.iter().enumerate() {
        first_row.push(row_joint.len());
        row_joint.extend(std::iter::repeat_n(k, model.joints[j].rows));
    }
    let mut phi_q = DMatrix::zeros(row_joint.len(), n);
    for (k, &j) in suspects.iter().enumerate() {
        crate::constraints::add_jacobian_entries(model, &state.poses, &kin, &model.joints[j], |r, c, x| {
            phi_q[(first_row[k] + r, c)] += x;
        });
    }
    let scale = phi_q.row_iter().map(|r| r.norm()).fold(0.0, f64::max).max(1e-300);
    let tol = 1e-10 * scale;
    let nc = phi_q.nrows();
    // in scene order: the first row that earlier rows already span
    let mut basis: Vec<DVector<f64>> = Vec::new();
    let mut independent: Vec<usize> = Vec::new();
    let mut dependent: Vec<usize> = Vec::new();
    for r in 0..nc {
        let row = phi_q.row(r).transpose();
        let mut v = row.clone();
        for _ in 0..2 {
            for u in &basis {
                let c = u.dot(&v);
                v.axpy(-c, u, 1.0);
            }
        }
        if v.norm() <= 1e-8 * row.norm().max(tol) {
            dependent.push(r);
        } else {
            basis.push(&v / v.norm());
            independent.push(r);
        }
        // report the first joint with a dependent equation once all its rows are seen
        if let Some(&first) = dependent.first() {
            let local = row_joint[first];
            let joint = suspects[local];
            let rows = model.joints[joint].rows;
            if r + 1 == first_row[local] + rows {
                let own: Vec<usize> = dependent.iter().copied().filter(|&d| row_joint[d] == local).collect();
                let earlier: Vec<usize> =
                    independent.iter().copied().filter(|&i| row_joint[i] < local).collect();
                // which earlier joints the dependent equations are combinations of
                let mut named = BTreeSet::new();
                if !earlier.is_empty() {
                    let a = DMatrix::from_fn(n, earlier.len(), |i, k| phi_q[(earlier[k], i)]);
                    if let Some(svd) = crate::solve::linear::ThinSvd::new(&a) {
                        for &d in &own {
                            let c = svd.solve(&phi_q.row(d).transpose(), 1e-10 * svd.s.amax());
                            let big = c.amax();
                            for (k, &e) in earlier.iter().enumerate() {
                                let other = model.joints[suspects[row_joint[e]]].scene_index;
                                if c[k].abs() > 1e-8 * big && other != model.joints[joint].scene_index {
                                    named.insert(other);
                                }
                            }
                        }
                    }
                }
                let names: Vec<String> = named.iter().map(|j| format!("joints[{j}]")).collect();
                let by = match names.len() {
                    0 => "the other joints".to_string(),
                    1 => names[0].clone(),
                    _ => format!("{} and {}", names[..names.len() - 1].join(", "), names[names.len() - 1]),
                };
                let what = if own.len() == 1 && rows == 1 {
                    "its equation is".to_string()
                } else if own.len() == 1 {
                    format!("1 of its {rows} equations is")
                } else {
                    format!("{} of its {rows} equations are", own.len())
                };
                return Err(cx.err(
                    "joints",
                    model.joints[joint].scene_index,
                    "a",
                    format!(
                        "redundant: {what} implied by {by} at the initial pose (together they fix more \
                         than the bodies' coordinates can move), so no solver can tell their reactions \
                         apart; remove this joint, or make a body that must not move kind = \"fixed\""
                    ),
                ));
            }
        }
    }
    Ok(())
}
