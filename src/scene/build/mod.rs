//! Validation and model building: takes a parsed `SceneSpec`, gives a `Model` (bodies, points,
//! routes, joints, actuators, schedule, rest lengths) or the first `SceneError` found. This file
//! holds only the order of the stages; each concern's checks and building live in their own file.

mod actuators;
mod bodies;
mod cables;
mod contact;
mod context;
mod joints;
mod options;

use nalgebra::Vector3;

use crate::error::SceneError;
use crate::model::{Model, Schedule};
use crate::scene::spec::{self, limits, SceneSpec};
use actuators::{attach_winches, build_actuators, build_schedule, Actuators};
use bodies::{build_bodies, check_mass_on_free_coordinates, Bodies};
use cables::{
    build_cables, lump_member_masses, set_buckling_loads, set_pulley_friction, set_rest_lengths, Cables,
};
use contact::{build_contact_spheres, build_grounds, build_strut_pairs, check_contacts};
use context::{bounded3, in_range, Ctx};
use joints::{build_joints, check_redundant_joints};
use options::{build_randomization, build_rayleigh, build_sensors, build_solver};

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
        friction_holds_sketch: false,
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
            None => spec::to_toml(spec).into(),
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
