//! The evaluation stage: takes a `Model`, a `State` and a preallocated `Workspace`, gives every
//! point's kinematics, the total applied force `Q` (cables, contacts, gravity, Rayleigh and joint damping, `crate::forces`), its
//! tangents `K = -dQ/dq` and `C = -dQ/dv` (through an `assembly::TangentSink`), the joints'
//! values and Jacobian (`crate::constraints`), every cable's response and the energies. The
//! solvers read everything from the workspace.

use nalgebra::{DMatrix, DVector, Vector3, Vector6};

use crate::assembly::{add_vector, DenseTangents, TangentSink};
use crate::constraints;
use crate::forces::cable::{self, add_cable_force, add_cable_tangents, CableResponse, CableScratch};
use crate::forces::collision::{add_collision_force, add_collision_tangents, ClosestPoints};
use crate::forces::contact::{add_contact_force, add_contact_tangents, ContactResponse};
use crate::forces::pulley::{add_friction_cable_force, add_friction_cable_tangents, FrictionWork};
use crate::kinematics::{point_kinematics_into, PointKinematics};
use crate::model::{BodyId, CableId, Model, PointId, Pose};
use crate::state::State;

/// Which tangent matrices an evaluation fills.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Tangents {
    /// Forces and responses only.
    None,
    /// Also `K = -dQ/dq`.
    Stiffness,
    /// Also `K` and `C = -dQ/dv`.
    StiffnessAndDamping,
}

/// Energies of a configuration, J.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Energies {
    /// Elastic energy stored in taut cables and in contacts (pressed into a ground, or struts
    /// pressed into each other).
    pub elastic: f64,
    /// Gravitational potential `-sum_b m_b g . x_b`.
    pub gravitational: f64,
    /// Kinetic energy `v^T M v / 2`.
    pub kinetic: f64,
}

/// Everything an evaluation derives from (Model, State), allocated once per model.
#[derive(Debug, Clone)]
pub struct Workspace {
    /// Kinematics of every point (position dependent, velocity dependent).
    pub points: Vec<PointKinematics>,
    /// Total applied generalized force `Q` (N, N m).
    pub force: DVector<f64>,
    /// `K = -dQ/dq` of the applied forces.
    pub stiffness: DMatrix<f64>,
    /// `C = -dQ/dv` of the applied forces.
    pub damping: DMatrix<f64>,
    /// Joint constraint values `Phi(q)` (m).
    pub constraint: DVector<f64>,
    /// Joint constraint Jacobian `Phi_q` (rows x coordinates).
    pub constraint_jacobian: DMatrix<f64>,
    /// Every cable's response, parallel to `Model::cables`.
    pub cables: Vec<CableResponse>,
    /// Every contact's response (`Model::contact_pairs`: the ground pairs, sphere `s` against
    /// ground `g` at `s * grounds + g`, then the strut pairs).
    pub contacts: Vec<ContactResponse>,
    /// Per strut pair, the closest points of the two axes (`ClosestPoints::side` tells which
    /// side of the second bar's axis the first passes: +1, -1, or 0 when that is not defined).
    pub strut_closest: Vec<ClosestPoints>,
    /// Power dissipated by all contacts (normal damping and friction), W.
    pub contact_loss_power: f64,
    /// Power dissipated by the joints' rotational damping, W.
    pub joint_loss_power: f64,
    /// Segment lengths of all cables, concatenated (cable `c` starts at `route_start - c`).
    pub segment_lengths: Vec<f64>,
    /// Energies of the evaluated state (kinetic included).
    pub energies: Energies,
    /// The poses of the last evaluation, kept only in scenes whose joints hold axes (hinge,
    /// planar: `JointModel::alignment`), whose constraint rows turn with the bodies; empty
    /// otherwise. What the constraint solvers that see the workspace alone pass as `poses`.
    pub poses: Vec<Pose>,
    /// Per-route scratch (public so that callers can pass it to `add_tangents`).
    pub scratch: CableScratch,
    /// What the pulleys with friction do (`crate::forces::pulley`; empty without). Boxed: the
    /// integrators swap whole workspaces every step, and a scene without friction should not
    /// pay for copying its bookkeeping.
    pub friction: Box<FrictionWork>,
}

impl Workspace {
    /// A workspace sized for `model`.
    pub fn new(model: &Model) -> Self {
        Self::new_sized(model, true)
    }

    fn new_sized(model: &Model, dense: bool) -> Self {
        let n = if dense { model.dof_count } else { 0 };
        let max_route = model.cables.iter().map(|c| c.route_len).max().unwrap_or(2);
        Self {
            points: vec![
                PointKinematics {
                    body: BodyId(0),
                    position: Vector3::zeros(),
                    velocity: Vector3::zeros(),
                    jacobian: Default::default(),
                };
                model.points.len()
            ],
            force: DVector::zeros(model.dof_count),
            stiffness: DMatrix::zeros(n, n),
            damping: DMatrix::zeros(n, n),
            constraint: DVector::zeros(model.constraint_count),
            constraint_jacobian: DMatrix::zeros(if dense { model.constraint_count } else { 0 }, n),
            cables: vec![CableResponse::default(); model.cables.len()],
            contacts: vec![ContactResponse::default(); model.contact_pairs()],
            strut_closest: vec![ClosestPoints::default(); model.strut_pairs.len()],
            contact_loss_power: 0.0,
            joint_loss_power: 0.0,
            segment_lengths: vec![0.0; model.route_points.len() - model.cables.len()],
            energies: Energies::default(),
            poses: if model.joints.iter().any(|j| j.alignment.is_some() || j.plane_normal.is_some()) {
                Vec::with_capacity(model.bodies.len())
            } else {
                Vec::new()
            },
            scratch: CableScratch::new(max_route),
            friction: Box::new(FrictionWork::new(model)),
        }
    }

    /// A workspace for `evaluate_forces` only: the dense `K`, `C` and `Phi_q` are left empty
    /// (`0 x 0`) and sized by the first `evaluate` that needs them, so that stepping a large scene
    /// never holds `n x n` matrices.
    pub fn for_forces(model: &Model) -> Self {
        Self::new_sized(model, false)
    }

    /// Segment lengths of cable `c` from the last evaluation, m.
    pub fn cable_segments(&self, model: &Model, c: usize) -> &[f64] {
        let cable = &model.cables[c];
        let start = cable.route_start - c;
        &self.segment_lengths[start..start + cable.segment_count()]
    }
}

/// Evaluates all position- and velocity-dependent quantities of `state` into `ws`:
/// point kinematics, `Q`, the requested tangents, constraints and their Jacobian, cable responses
/// and energies.
pub fn evaluate(model: &Model, state: &State, ws: &mut Workspace, tangents: Tangents) {
    evaluate_forces(model, state, ws);
    let (n, nc) = (model.dof_count, model.constraint_count);
    if ws.constraint_jacobian.shape() != (nc, n) {
        ws.constraint_jacobian = DMatrix::zeros(nc, n);
    }
    if tangents != Tangents::None && ws.stiffness.nrows() != n {
        ws.stiffness = DMatrix::zeros(n, n);
        ws.damping = DMatrix::zeros(n, n);
    }
    let want_k = tangents != Tangents::None;
    let want_c = tangents == Tangents::StiffnessAndDamping;
    if want_k {
        ws.stiffness.fill(0.0);
        if want_c {
            ws.damping.fill(0.0);
        }
        let mut sink = DenseTangents {
            model,
            stiffness: &mut ws.stiffness,
            damping: if want_c { Some(&mut ws.damping) } else { None },
        };
        let contacts = (ws.contacts.as_slice(), ws.strut_closest.as_slice());
        let scratch = (&mut ws.scratch, &mut *ws.friction);
        add_tangents(model, state, &ws.points, &ws.cables, contacts, scratch, &mut sink);
    }
    constraints::evaluate_jacobian(model, &state.poses, &ws.points, &mut ws.constraint_jacobian);
}

/// The part of `evaluate` that is linear in the scene size: point kinematics, `Q`, cable
/// responses and segment lengths, joint constraint values `Phi` and energies. Leaves
/// `ws.stiffness`, `ws.damping` and `ws.constraint_jacobian` untouched.
pub fn evaluate_forces(model: &Model, state: &State, ws: &mut Workspace) {
    let v = &state.velocities;
    for (i, p) in ws.points.iter_mut().enumerate() {
        point_kinematics_into(model, &state.poses, v, PointId(i), p);
    }
    if ws.poses.capacity() > 0 {
        ws.poses.clear();
        ws.poses.extend_from_slice(&state.poses);
    }
    ws.force.fill(0.0);

    // gravity: m g on the translation rows of each body (origin = centre of mass)
    let mut gravitational = 0.0;
    for (b, body) in model.bodies.iter().enumerate() {
        if body.dof_count == 0 || body.mass == 0.0 {
            continue;
        }
        let w = model.gravity * body.mass;
        gravitational -= w.dot(&state.poses[b].position);
        let f6 = Vector6::new(w.x, w.y, w.z, 0.0, 0.0, 0.0);
        add_vector(model, BodyId(b), &(body.basis.transpose() * f6), 1.0, &mut ws.force);
    }

    // Rayleigh's mass-proportional damping: -alpha M_b v_b on every body
    let alpha = model.rayleigh.alpha;
    if alpha > 0.0 {
        for (b, body) in model.bodies.iter().enumerate() {
            if body.dof_count == 0 {
                continue;
            }
            // M_b v_b = B^T diag(m I, J) B v_b, as `kinetic_energy` weighs it
            let local = body.local_increment(v.as_slice(), 1.0);
            let (dx, w) = (local.fixed_rows::<3>(0), local.fixed_rows::<3>(3));
            let momentum = body.inertia * w;
            let f6 = Vector6::new(
                body.mass * dx[0],
                body.mass * dx[1],
                body.mass * dx[2],
                momentum.x,
                momentum.y,
                momentum.z,
            );
            add_vector(model, BodyId(b), &(body.basis.transpose() * f6), -alpha, &mut ws.force);
        }
        model.add_mass_coupling_times(v.as_slice(), -alpha, ws.force.as_mut_slice());
    }

    // rotational damping at joints that declare it
    ws.joint_loss_power = if model.damped_joints {
        crate::forces::joint_damping::add_joint_damping_force(model, &state.poses, v, &mut ws.force)
    } else {
        0.0
    };

    // cables
    let mut elastic = 0.0;
    for (c, cable) in model.cables.iter().enumerate() {
        let route = model.route(CableId(c));
        let response = match cable.friction {
            None => match cable.winch {
                Some(w) if state.winches[w].step > 0.0 => crate::forces::winch::add_winch_cable_force(
                    model,
                    route,
                    cable,
                    &model.winches[w],
                    &state.winches[w],
                    state.rest_lengths[c],
                    &ws.points,
                    &mut ws.scratch,
                    &mut ws.force,
                ),
                _ => add_cable_force(
                    model,
                    route,
                    cable,
                    state.rest_lengths[c],
                    &ws.points,
                    &mut ws.scratch,
                    &mut ws.force,
                ),
            },
            Some(f) => {
                let friction = &model.pulley_friction[f];
                let o = friction.segment_offset;
                add_friction_cable_force(
                    model,
                    route,
                    cable,
                    friction,
                    state.rest_lengths[c],
                    &state.segment_rest_lengths[o..o + cable.segment_count()],
                    &ws.points,
                    &mut ws.scratch,
                    &mut ws.friction,
                    &mut ws.force,
                )
            }
        };
        elastic += response.energy;
        ws.cables[c] = response;
        let start = cable.route_start - c;
        let m = cable.segment_count();
        ws.segment_lengths[start..start + m].copy_from_slice(&ws.scratch.segment_lengths[..m]);
    }

    // contacts: every sphere against every ground
    let mut loss = 0.0;
    for (k, sphere, ground) in model.contact_pair_list() {
        let kin = &ws.points[sphere.point.0];
        let anchor = state.contact_anchors.get(k);
        let response = add_contact_force(model, &state.poses, v, ground, sphere, kin, anchor, &mut ws.force);
        elastic += response.energy;
        loss += response.loss_power;
        ws.contacts[k] = response;
    }
    // strut pairs: capsule against capsule
    let first = model.ground_pairs();
    for (i, pair) in model.strut_pairs.iter().enumerate() {
        let (response, closest) =
            add_collision_force(model, &ws.points, pair, &model.strut_material, &mut ws.force);
        elastic += response.energy;
        loss += response.loss_power;
        ws.contacts[first + i] = response;
        ws.strut_closest[i] = closest;
    }
    ws.contact_loss_power = loss;

    constraints::evaluate_values(model, &state.poses, &ws.points, &mut ws.constraint);
    ws.energies = Energies { elastic, gravitational, kinetic: kinetic_energy(model, v) };
}

/// `add_tangents` with everything it reads taken from `ws` (what `evaluate_forces` left there
/// for `state`), for sinks that do not borrow the workspace (the Newton systems).
pub fn add_workspace_tangents<S: TangentSink + ?Sized>(
    model: &Model,
    state: &State,
    ws: &mut Workspace,
    sink: &mut S,
) {
    let contacts = (ws.contacts.as_slice(), ws.strut_closest.as_slice());
    let scratch = (&mut ws.scratch, &mut *ws.friction);
    add_tangents(model, state, &ws.points, &ws.cables, contacts, scratch, sink);
}

/// Adds the cables' and contacts' tangent stiffness and damping at `state` into `sink`, using the
/// point kinematics `points` and cable responses `cables` that `evaluate_forces` left for this
/// state (and the contact responses `contacts`, one per `Model::contact_pairs`, and the pulleys'
/// return map in `friction`).
pub fn add_tangents<S: TangentSink + ?Sized>(
    model: &Model,
    state: &State,
    points: &[PointKinematics],
    cables: &[CableResponse],
    (contacts, strut_closest): (&[ContactResponse], &[ClosestPoints]),
    (scratch, friction): (&mut CableScratch, &mut FrictionWork),
    sink: &mut S,
) {
    if model.rayleigh.alpha > 0.0 {
        for (b, body) in model.bodies.iter().enumerate() {
            if body.dof_count > 0 {
                sink.damping(BodyId(b), BodyId(b), &body.mass_matrix(), model.rayleigh.alpha);
            }
        }
        model.for_each_mass_coupling_block(|a, b, blk| sink.damping(a, b, blk, model.rayleigh.alpha));
    }
    if model.damped_joints {
        crate::forces::joint_damping::add_joint_damping_tangents(
            model,
            &state.poses,
            &state.velocities,
            sink,
        );
    }
    for (k, sphere, ground) in model.contact_pair_list() {
        let (poses, v, kin) = (&state.poses, &state.velocities, &points[sphere.point.0]);
        let anchor = state.contact_anchors.get(k);
        add_contact_tangents(model, poses, v, ground, sphere, kin, anchor, &contacts[k], sink);
    }
    let first = model.ground_pairs();
    for (i, pair) in model.strut_pairs.iter().enumerate() {
        let response = &contacts[first + i];
        if response.normal_force > 0.0 {
            let (poses, v, m) = (&state.poses, &state.velocities, &model.strut_material);
            add_collision_tangents(model, poses, v, points, pair, m, (response, &strut_closest[i]), sink);
        }
    }
    for (c, cable) in model.cables.iter().enumerate() {
        let route = model.route(CableId(c));
        if let Some(f) = cable.friction {
            let (poses, v, l0) = (&state.poses, &state.velocities, state.rest_lengths[c]);
            let f = &model.pulley_friction[f];
            add_friction_cable_tangents(
                model, poses, v, route, cable, f, l0, points, scratch, friction, sink,
            );
            continue;
        }
        let t = cables[c].tension;
        // the rest length the response was evaluated at: the state's, or where a winch under
        // way takes it, with the winch's series compliance scaling EA and c
        let (l0, scale) = match cable.winch {
            Some(w) if state.winches[w].step > 0.0 => {
                let (winch, s) = (&model.winches[w], &state.winches[w]);
                let (l0, slope) =
                    crate::forces::winch::rest_length_at(model, winch, s, state.rest_lengths[c], t);
                (l0, crate::forces::winch::tangent_scale(cable, cables[c].length, l0, slope))
            }
            _ => (state.rest_lengths[c], 1.0),
        };
        if !cable::is_engaged(cable, l0, t) {
            continue;
        }
        cable::route_geometry(route, points, scratch);
        add_cable_tangents(
            model,
            &state.poses,
            &state.velocities,
            CableId(c),
            route,
            scale * cable::tangent_axial_stiffness(cable, l0, cables[c].length),
            scale * cable.damping,
            l0,
            t,
            points,
            scratch,
            sink,
        );
    }
}

/// The consistent-mass corrections' share of the kinetic energy, `-(m/12) |dx_a - dx_b|^2` per
/// member (J); kept out of line, so that `kinetic_energy` of a scene with lumped mass only
/// never runs it.
#[cold]
#[inline(never)]
fn coupled_kinetic_energy(model: &Model, v: &DVector<f64>) -> f64 {
    let mut e = 0.0;
    for coupling in &model.mass_couplings {
        let [a, b] = coupling.ends.map(|x| {
            let local = model.bodies[x.0].local_increment(v.as_slice(), 1.0);
            Vector3::new(local[0], local[1], local[2])
        });
        e -= 0.5 * coupling.coefficient * (a - b).norm_squared();
    }
    e
}

/// Kinetic energy `v^T M v / 2` (J) of local velocities `v`: per body
/// `(m |dx|^2 + w^T J w) / 2` with `(dx, w) = B v_b` (translation and body-frame rotation rates),
/// plus, for each member with a consistent mass matrix, `-(m/12) |dx_a - dx_b|^2`
/// (`crate::model::MassCoupling`).
pub fn kinetic_energy(model: &Model, v: &DVector<f64>) -> f64 {
    let mut e = 0.0;
    for body in &model.bodies {
        if body.dof_count == 0 {
            continue;
        }
        let local = body.local_increment(v.as_slice(), 1.0);
        let dx = Vector3::new(local[0], local[1], local[2]);
        let w = Vector3::new(local[3], local[4], local[5]);
        e += 0.5 * (body.mass * dx.norm_squared() + w.dot(&(body.inertia * w)));
    }
    if !model.mass_couplings.is_empty() {
        e += coupled_kinetic_energy(model, v);
    }
    e
}
