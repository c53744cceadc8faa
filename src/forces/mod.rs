//! Generalized forces and their tangents: takes a `Model`, a `State` and a preallocated
//! `Workspace`, gives the total applied force `Q` (cables + gravity), `K = -dQ/dq`, `C = -dQ/dv`,
//! every cable's response and the energies. Joints are in `crate::constraints`.

pub mod cable;

use nalgebra::{DMatrix, DVector, Vector3, Vector6};

use crate::constraints;
use crate::kinematics::{point_kinematics, PointKinematics};
use crate::model::{BodyId, Model, PointId};
use crate::state::State;
use cable::{add_cable_terms, CableResponse, CableScratch};

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
    /// Elastic energy stored in taut cables.
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
    /// Segment lengths of all cables, concatenated (cable `c` starts at `route_start - c`).
    pub segment_lengths: Vec<f64>,
    /// Energies of the evaluated state (kinetic included).
    pub energies: Energies,
    scratch: CableScratch,
}

impl Workspace {
    /// A workspace sized for `model`.
    pub fn new(model: &Model) -> Self {
        let n = model.dof_count;
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
            force: DVector::zeros(n),
            stiffness: DMatrix::zeros(n, n),
            damping: DMatrix::zeros(n, n),
            constraint: DVector::zeros(model.constraint_count),
            constraint_jacobian: DMatrix::zeros(model.constraint_count, n),
            cables: vec![CableResponse::default(); model.cables.len()],
            segment_lengths: vec![0.0; model.route_points.len() - model.cables.len()],
            energies: Energies::default(),
            scratch: CableScratch::new(max_route),
        }
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
    let v = &state.velocities;
    for (i, p) in ws.points.iter_mut().enumerate() {
        *p = point_kinematics(model, &state.poses, v, PointId(i));
    }
    ws.force.fill(0.0);
    let want_k = tangents != Tangents::None;
    let want_c = tangents == Tangents::StiffnessAndDamping;
    if want_k {
        ws.stiffness.fill(0.0);
    }
    if want_c {
        ws.damping.fill(0.0);
    }

    // gravity: m g on the translation rows of each body (origin = centre of mass)
    let mut gravitational = 0.0;
    for (b, body) in model.bodies.iter().enumerate() {
        if body.dof_count == 0 || body.mass == 0.0 {
            continue;
        }
        let w = model.gravity * body.mass;
        gravitational -= w.dot(&state.poses[b].position);
        let f6 = Vector6::new(w.x, w.y, w.z, 0.0, 0.0, 0.0);
        cable::add_vector(model, BodyId(b), &(body.basis.transpose() * f6), 1.0, &mut ws.force);
    }

    // cables
    let mut elastic = 0.0;
    for (c, cable) in model.cables.iter().enumerate() {
        let route = model.route(crate::model::CableId(c));
        let response = add_cable_terms(
            model,
            &state.poses,
            v,
            route,
            cable.axial_stiffness,
            cable.damping,
            state.rest_lengths[c],
            &ws.points,
            &mut ws.scratch,
            &mut ws.force,
            if want_k { Some(&mut ws.stiffness) } else { None },
            if want_c { Some(&mut ws.damping) } else { None },
        );
        elastic += response.energy;
        ws.cables[c] = response;
        let start = cable.route_start - c;
        let m = cable.segment_count();
        ws.segment_lengths[start..start + m].copy_from_slice(&ws.scratch.segment_lengths[..m]);
    }

    constraints::evaluate(model, &ws.points, &mut ws.constraint, &mut ws.constraint_jacobian);
    ws.energies = Energies { elastic, gravitational, kinetic: kinetic_energy(model, v) };
}

/// Kinetic energy `v^T M v / 2` (J) of local velocities `v`.
pub fn kinetic_energy(model: &Model, v: &DVector<f64>) -> f64 {
    let mut e = 0.0;
    for body in &model.bodies {
        if body.dof_count == 0 {
            continue;
        }
        let m = body.mass_matrix();
        let k = body.dof_count;
        let vb = v.rows(body.dof_offset, k);
        for r in 0..k {
            for c in 0..k {
                e += 0.5 * vb[r] * m[(r, c)] * vb[c];
            }
        }
    }
    e
}
