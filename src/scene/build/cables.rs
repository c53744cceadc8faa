//! Cables and elastic members: takes `[[cables]]` and `[[members]]`, gives `CableModel`s with their
//! routes, rest lengths (given or form-found), buckling loads, pulley friction and the members'
//! lumped or consistent masses.

use std::collections::{BTreeMap, BTreeSet};

use super::context::{in_range, Ctx};
use crate::error::SceneError;
use crate::model::{BodyKind, BodyModel, CableModel, MassCoupling, Model, PointId, PointModel};
use crate::scene::spec::{self, limits, CableSpec, MassMatrixSpec, SceneSpec};
use crate::solve::formfind::{find_rest_lengths_with, Blame, FormFindingMethod, RestLengthSpec};

/// Adds half of each member's mass to each of its ends' bodies: nodes take it, fixed bodies
/// carry it to the ground; a member with mass may not end on a bar or rigid body (its lumped
/// mass would move their centre of mass and inertia). Returns the consistent-mass corrections
/// of the members that ask for them (`MassCoupling`).
pub(super) fn lump_member_masses(
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
pub(super) struct Cables {
    pub(super) cables: Vec<CableModel>,
    pub(super) cable_names: Vec<String>,
    pub(super) route_points: Vec<PointId>,
    pub(super) rest_specs: Vec<RestLengthSpec>,
    pub(super) damping_ratios: Vec<Option<f64>>,
}

/// A member as the two-point cable that pushes, and whether it asks for form finding.
pub(super) fn member_as_cable(m: &spec::MemberSpec) -> (CableSpec, bool) {
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
pub(super) fn build_cables(
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

/// Sets the initial rest lengths (form finding where a cable gives a prestress or a force
/// density), the damping of cables given a damping ratio plus Rayleigh's `beta EA / L0`, and checks each actuator's cable
/// starts within its limits. Elements from `spec_cables` on are the scene's members.
pub(super) fn set_rest_lengths(
    model: &mut Model,
    rest_specs: &[RestLengthSpec],
    damping_ratios: &[Option<f64>],
    spec_cables: usize,
    cx: &Ctx,
) -> Result<(), SceneError> {
    let found =
        find_rest_lengths_with(model, rest_specs, FormFindingMethod::Auto).map_err(|(blame, reason)| {
            let route = reason == crate::solve::formfind::ZERO_LENGTH;
            // a geometry that no tensions hold is named at the first target that asked for them
            let target = rest_specs
                .iter()
                .position(|s| matches!(s, RestLengthSpec::Prestress(_) | RestLengthSpec::ForceDensity(_)));
            let blame = match (blame, target) {
                (Blame::Equilibrium, Some(c)) => Blame::Cable(c),
                (Blame::Equilibrium, None) => Blame::Geometry,
                (blame, _) => blame,
            };
            match blame {
                Blame::Cable(c) if c >= spec_cables => {
                    let field = if route { "ends" } else { "force" };
                    cx.err("members", c - spec_cables, field, reason)
                }
                Blame::Cable(c) => {
                    let field = match rest_specs[c] {
                        _ if route => "route",
                        RestLengthSpec::ForceDensity(_) => "force_density",
                        _ => "prestress",
                    };
                    cx.err("cables", c, field, reason)
                }
                Blame::Ground(g, field) => cx.err("grounds", g, field, reason),
                Blame::Geometry | Blame::Equilibrium => cx.top(
                    if spec_cables == 0 && !model.cables.is_empty() { "members" } else { "cables" },
                    reason,
                ),
            }
        })?;
    model.friction_holds_sketch = found.reactions.iter().any(|r| r.friction > 0.0);
    model.initial_rest_lengths = found.rest_lengths;
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

/// Sets each member's buckling load (`buckling_load`, or `pi^2 EI / L0^2` of its initial rest
/// length from `bending_stiffness`) once the rest lengths are known, and refuses a member whose
/// target force (`force`, `form_find`) already compresses it past that load: form finding
/// solves the unbuckled law.
pub(super) fn set_buckling_loads(spec: &SceneSpec, model: &mut Model, cx: &Ctx) -> Result<(), SceneError> {
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

/// Gives the cables whose pulleys have friction (`pulley_friction`, the cable's or the
/// scene's) their `PulleyFriction` and their segments' initial rest lengths (the initial rest
/// length at uniform strain). A cable whose coefficients are all 0 stays the frictionless
/// element. Refused: a coefficient out of range, a list whose length is not the cable's pulley
/// count, friction on a cable without pulleys, `winch_end` on an element that cannot use it.
pub(super) fn set_pulley_friction(spec: &SceneSpec, model: &mut Model, cx: &Ctx) -> Result<(), SceneError> {
    use crate::scene::spec::{PulleyFrictionSpec, WinchEndSpec};
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
