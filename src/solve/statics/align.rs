//! Rigid alignment onto the contacts' anchors: takes a model, a state whose stick-slip contacts
//! are anchored (`State::contact_anchors`) and the contacts evaluated at it; gives the state with
//! each free group of bodies moved rigidly in its ground's plane so that its touching contacts
//! best fit their anchors.
//!
//! A structure settled on frictionless normal springs may have turned or slid as a whole (its
//! free rigid motions on the ground are zero-stiffness modes, the weight works along a twist).
//! Holding its contacts where it stood from there starts Newton with every contact stretched
//! beyond its cone, all slipping the same way round, which leaves the turn without stiffness.
//! Moved back rigidly first, the contacts stretch only by the structure's own deformation.
//!
//! A group is the bodies that cables, members and joints connect; one held by a joint to the
//! world, or with a fixed body, or whose touching contacts are on grounds of different normals,
//! is left where it is. For a group with touching contacts at in-plane points `p_k` (the sphere
//! centres projected onto the ground) and anchors `a_k`, the turn about the ground's normal `n`
//! is the two-dimensional Kabsch angle `theta = atan2(sum p_k x a_k . n, sum p_k . a_k)` of the
//! centred points, and the shift moves the centroid of the `p_k` onto that of the `a_k` in the
//! plane (one contact: the shift alone).

use nalgebra::{UnitQuaternion, Vector3};

use crate::evaluate::Workspace;
use crate::model::{BodyGroups, BodyKind, CableId, JointTarget, Model};
use crate::state::State;

/// The group (root body index, `BodyGroups`) of every body: bodies joined by a cable, member
/// or joint share one.
fn groups(model: &Model) -> Vec<usize> {
    let mut groups = BodyGroups::new(model.bodies.len());
    for c in 0..model.cables.len() {
        let route = model.route(CableId(c));
        for pair in route.windows(2) {
            groups.join(model.points[pair[0].0].body.0, model.points[pair[1].0].body.0);
        }
    }
    for joint in &model.joints {
        if let JointTarget::Point(p) = joint.target {
            groups.join(model.points[joint.point.0].body.0, model.points[p.0].body.0);
        }
    }
    (0..model.bodies.len()).map(|b| groups.root(b)).collect()
}

/// Moves every free group of bodies rigidly in its ground's plane so that its touching
/// stick-slip contacts (normal force > 0 in `ws.contacts`, evaluated at `state`) best fit their
/// anchors (module docs). Velocities and multipliers are left as they are. Returns whether any
/// group moved.
pub(crate) fn align_onto_anchors(model: &Model, state: &mut State, ws: &Workspace) -> bool {
    if state.contact_anchors.is_empty() {
        return false;
    }
    let group = groups(model);
    let mut held = vec![false; model.bodies.len()];
    for (b, body) in model.bodies.iter().enumerate() {
        held[group[b]] |= body.kind == BodyKind::Fixed;
    }
    for joint in &model.joints {
        if let JointTarget::World(_) = joint.target {
            held[group[model.points[joint.point.0].body.0]] = true;
        }
    }
    // per group: the ground normal, and the touching contacts' points and anchors
    struct Fit {
        normal: Vector3<f64>,
        mixed: bool,
        points: Vec<(Vector3<f64>, Vector3<f64>)>,
    }
    let mut fits: Vec<Option<Fit>> = (0..model.bodies.len()).map(|_| None).collect();
    for ((k, sphere, ground), anchor) in model.contact_pair_list().zip(&state.contact_anchors) {
        let contact = &ws.contacts[k];
        if ground.material.stick.is_none() || contact.normal_force <= 0.0 {
            continue;
        }
        let g = group[model.points[sphere.point.0].body.0];
        if held[g] {
            continue;
        }
        let fit =
            fits[g].get_or_insert_with(|| Fit { normal: ground.normal, mixed: false, points: Vec::new() });
        fit.mixed |= (fit.normal - ground.normal).norm() > 1e-12;
        fit.points.push((contact.position, anchor.anchor));
    }
    let mut moved = false;
    for (g, fit) in fits.iter().enumerate() {
        let Some(fit) = fit.as_ref().filter(|f| !f.mixed) else { continue };
        let n = fit.normal;
        let count = fit.points.len() as f64;
        let pc = fit.points.iter().map(|(p, _)| p).sum::<Vector3<f64>>() / count;
        let ac = fit.points.iter().map(|(_, a)| a).sum::<Vector3<f64>>() / count;
        let (mut cross, mut dot) = (0.0, 0.0);
        for (p, a) in &fit.points {
            let (p, a) = (p - pc, a - ac);
            let (p, a) = (p - n * n.dot(&p), a - n * n.dot(&a));
            cross += p.cross(&a).dot(&n);
            dot += p.dot(&a);
        }
        let angle = if fit.points.len() > 1 { cross.atan2(dot) } else { 0.0 };
        let shift = (ac - pc) - n * n.dot(&(ac - pc));
        if angle == 0.0 && shift.norm() == 0.0 {
            continue;
        }
        let turn = UnitQuaternion::from_axis_angle(&nalgebra::Unit::new_normalize(n), angle);
        for (b, pose) in state.poses.iter_mut().enumerate() {
            if group[b] == g && model.bodies[b].kind != BodyKind::Fixed {
                pose.position = pc + shift + turn * (pose.position - pc);
                pose.rotation = turn * pose.rotation;
            }
        }
        moved = true;
    }
    moved
}
