//! Ground contact and strut-strut collision: takes `[[grounds]]`, the bodies' contact spheres and
//! `[collisions]`, gives `GroundModel`s, `ContactSphere`s and `StrutPair`s, and refuses a start
//! pressed too deep.

use std::collections::BTreeMap;

use nalgebra::Vector3;

use super::context::{bounded3, in_range, Ctx};
use crate::error::{readable_number, SceneError};
use crate::model::{
    BodyId, BodyKind, BodyModel, ContactMaterial, ContactSphere, GroundModel, JointModel, JointTarget, Model,
    PointId, PointModel, StickFriction, StrutPair,
};
use crate::scene::spec::{self, limits, BodyKindSpec, CollisionPairsSpec, SceneSpec};

/// The contact spheres the bodies declare (`contact_radius`, `contact_points`), in body order.
pub(super) fn build_contact_spheres(
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
pub(super) fn build_grounds(
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
        let mut material = contact_material(law, default_stiffness, 1.0, &e)?;
        material.stick = match (g.stick_stiffness, g.stick_damping) {
            (None, None) => None,
            (None, Some(_)) => {
                return Err(e(
                    "stick_damping",
                    "needs stick_stiffness: the damping acts with the stick-slip friction's spring".into(),
                ))
            }
            (Some(k), c) => Some(StickFriction {
                stiffness: in_range(k, limits::STICK_STIFFNESS, "N/m")
                    .map_err(|r| e("stick_stiffness", r))?,
                damping: c
                    .map(|c| in_range(c, limits::STICK_DAMPING, "N s/m").map_err(|r| e("stick_damping", r)))
                    .transpose()?,
            }),
        };
        grounds.push(GroundModel { name, normal, offset: normal.dot(&point), material });
    }
    Ok(grounds)
}

/// Default friction coefficient between struts (`[collisions] mu`).
pub(super) const STRUT_FRICTION: f64 = 0.3;

/// A contact law from a table's optional `[stiffness, dissipation, mu, stiction_speed]`, each
/// checked against its range, with the defaults (`default_stiffness`, 1 s/m, `default_mu`,
/// 1e-5 m/s); `e(field, reason)` makes the error that names the field.
pub(super) fn contact_material(
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
        stick: None,
    })
}

/// The default penalty stiffness of grounds and strut collisions, N/m: the structure's whole
/// weight on one contact presses it in by a thousandth of the scene's size (at least 1e3).
pub(super) fn default_contact_stiffness(
    spec: &SceneSpec,
    bodies: &[BodyModel],
    points: &[PointModel],
) -> f64 {
    let weight = bodies.iter().map(|b| b.mass).sum::<f64>() * Vector3::from(spec.gravity).norm();
    (1000.0 * weight / scene_size(bodies, points)).max(1e3)
}

/// The strut pairs of `[collisions]` and their contact law (none and an unused default without
/// the table). A pair's bars both need a `contact_radius`; `all` leaves out pairs a joint joins
/// (they touch at the joint by design); no pair may start with its capsules pressed into each
/// other by more than `START_PENETRATION` of the scene's size.
pub(super) fn build_strut_pairs(
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
pub(super) fn all_bar_pairs(
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
pub(super) fn scene_size(bodies: &[BodyModel], points: &[PointModel]) -> f64 {
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
pub(super) fn check_contacts(spec: &SceneSpec, model: &Model, cx: &Ctx) -> Result<(), SceneError> {
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
    let stranded = |b: &spec::BodySpec| {
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
