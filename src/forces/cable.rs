//! The classical and sliding cable element (docs/architecture.md, "The classical and the sliding cable"): takes a route's point kinematics and a
//! rest length, gives the tension, the generalized force `Q = -T g`, the tangent stiffness
//! `K = -dQ/dq` and the damping matrix `C = -dQ/dv`.
//!
//! A cable runs through points `P_0 .. P_m` (`m = 1`: classical cable; interior points are
//! frictionless pulleys). With segment `k` from `P_(k-1)` to `P_k`:
//! - `d_k = r_k - r_(k-1)`, `l_k = |d_k|`, `e_k = d_k / l_k`, `L = sum_k l_k`;
//! - `dL/dr_i = n_i = e_i - e_(i+1)` (with `e_0 = e_(m+1) = 0`), so `g = dL/dq = sum_i J_i^T n_i`
//!   and a pulley receives the force `T (e_(i+1) - e_i)`, zero when the cable runs straight;
//! - `Ldot = g^T v = sum_i n_i . rdot_i`;
//! - tension (Kelvin-Voigt, tension only): `T = max(0, (EA/L0)(L - L0) + c Ldot)` if `L > L0`,
//!   else `T = 0`; elastic energy `V = EA/(2 L0) (L - L0)^2` while taut;
//! - an elastic member (`CableModel::tension_only` false, two points) keeps the law unclamped:
//!   `T = (EA/L0)(L - L0) + c Ldot` pushes (`T < 0`) when compressed, `V = EA/(2 L0) (L - L0)^2`
//!   always, and the matrices below hold at every `T`, negative and zero included;
//! - a member with a buckling load `P` (`CableModel::buckling_load`) follows, once its
//!   compression passes `P` (shortening `s = L0 - L` beyond `s_cr = P L0 / EA`), the initial
//!   post-buckling path of the pinned Euler column in series with its axial compliance: the
//!   elastica's `P_b = P (1 + delta / (2 L0))` for a bow shortening `delta`, so the compression is
//!   `N = P + k_b (s - s_cr)` with `k_b = 1 / (L0/EA + 2 L0/P)`, its energy
//!   `V = P^2 L0 / (2 EA) + P (s - s_cr) + k_b (s - s_cr)^2 / 2`, and `EA/L0` in `K` becomes
//!   `k_b` (`axial_tangent`);
//! - `K = (EA/L0) g g^T + T [sum_k G_k^T P_k G_k + sum_i d(J_i^T n_i)/dq] + c g h^T`, with
//!   `G_k = J_k - J_(k-1)`, `P_k = (I - e_k e_k^T)/l_k`, and
//!   `h = dLdot/dq = sum_k G_k^T P_k (rdot_k - rdot_(k-1)) + sum_i (d rdot_i/dq)^T n_i`;
//! - `C = c g g^T`.
//!
//! While `T = 0` (slack, or the damper would push) a cable gives no force and no matrices; a
//! member always gives both. A rest length of `DISENGAGED` takes either out (no force, no energy):
//! form finding and the mixed statics put their unknown elements' forces in by other means.
//! A segment shorter than `SEGMENT_LENGTH_FLOOR` has no direction: it contributes its length but
//! no force direction and no geometric stiffness, so coincident points never produce NaN.

use nalgebra::{DVector, Matrix3, Vector3, Vector6};

use crate::assembly::{add_vector, TangentSink};

use crate::kinematics::{force_jacobian_derivative, velocity_derivative, PointKinematics};
use crate::model::{CableId, CableModel, Model, PointId, Pose};

/// Segments shorter than this (m) are treated as a point: no direction, no geometric stiffness.
pub const SEGMENT_LENGTH_FLOOR: f64 = 1e-9;

/// The rest length that disengages an element, cable or member: no force, no energy.
pub const DISENGAGED: f64 = f64::MAX;

/// Tension law of docs/architecture.md ("The classical and the sliding cable"): the elastic
/// force of `cable` (EA, its law, a member's buckling load; `elastic_force`) at rest length
/// `rest_length` (m, > 0) and length `length` (m), plus its damping `c` (N s/m) times
/// `length_rate` (m/s). Returns the tension (N): `>= 0` for a cable (`tension_only`), of either
/// sign for a member; 0 at a `DISENGAGED` rest length.
#[inline]
pub fn tension(cable: &CableModel, rest_length: f64, length: f64, length_rate: f64) -> f64 {
    if rest_length == DISENGAGED || (cable.tension_only && length <= rest_length) {
        return 0.0;
    }
    let law = elastic_force(cable, rest_length, length) + cable.damping * length_rate;
    if cable.tension_only {
        law.max(0.0)
    } else {
        law
    }
}

/// Whether a member is compressed past its buckling load `P` at rest length `l0` and length `l`
/// (m): `EA (L0 - L) > P L0`. Never for a cable, nor a member without a buckling load.
#[inline]
pub fn is_buckled(cable: &CableModel, l0: f64, l: f64) -> bool {
    cable.buckling_load != f64::INFINITY && cable.axial_stiffness * (l0 - l) > cable.buckling_load * l0
}

/// The elastic part of the law, N (module docs): `(EA/L0)(L - L0)`, or, for a buckled member,
/// `-(P + k_b (s - s_cr))` with `s = L0 - L`, `s_cr = P L0 / EA`, `k_b = 1 / (L0/EA + 2 L0/P)`.
/// The caller clamps a cable at zero.
#[inline]
pub fn elastic_force(cable: &CableModel, l0: f64, l: f64) -> f64 {
    let ea = cable.axial_stiffness;
    if !is_buckled(cable, l0, l) {
        return (ea / l0) * (l - l0);
    }
    let p = cable.buckling_load;
    -(p + buckled_stiffness(cable, l0) * (l0 - l - p * l0 / ea))
}

/// `k_b = 1 / (L0/EA + 2 L0/P)`, N/m: a buckled member's axial stiffness at rest length `l0`.
fn buckled_stiffness(cable: &CableModel, l0: f64) -> f64 {
    1.0 / (l0 / cable.axial_stiffness + 2.0 * l0 / cable.buckling_load)
}

/// `EA_t` such that `EA_t / L0 = dT/dL` of the elastic law (N): `EA` itself, except for a
/// buckled member, whose `k_b L0` it is. What `add_cable_tangents` takes as `ea`.
#[inline]
pub fn tangent_axial_stiffness(cable: &CableModel, l0: f64, l: f64) -> f64 {
    if is_buckled(cable, l0, l) {
        buckled_stiffness(cable, l0) * l0
    } else {
        cable.axial_stiffness
    }
}

/// `dV/dL0` at a fixed length `l` (N) of a buckled member at rest length `l0` (m): with
/// `u = s - s_cr`, `P^2/(2 EA) + (P + k_b u)(1 - P/EA) - k_b u^2 / (2 L0)`. What an actuator
/// changing the rest length works against (`elastic_energy`; the unbuckled law's is
/// `-T (L + L0) / (2 L0)`).
pub fn buckled_energy_rest_derivative(cable: &CableModel, l0: f64, l: f64) -> f64 {
    let (ea, p) = (cable.axial_stiffness, cable.buckling_load);
    let k_b = buckled_stiffness(cable, l0);
    let u = l0 - l - p * l0 / ea;
    p * p / (2.0 * ea) + (p + k_b * u) * (1.0 - p / ea) - 0.5 * k_b * u * u / l0
}

/// `dV/dL0` at a fixed length `l` (N) for rest length `l0` (m): the force an actuator changing
/// the rest length works against, its power `dV/dL0 dL0/dt`. `-T_el (L + L0) / (2 L0)` with
/// `T_el = (EA/L0)(L - L0)` (a member in compression too), a buckled member's
/// `buckled_energy_rest_derivative`, 0 for a slack cable or a `DISENGAGED` rest length.
pub fn elastic_energy_rest_derivative(cable: &CableModel, l0: f64, l: f64) -> f64 {
    if l0 == DISENGAGED || (cable.tension_only && l <= l0) {
        0.0
    } else if is_buckled(cable, l0, l) {
        buckled_energy_rest_derivative(cable, l0, l)
    } else {
        let t_el = cable.axial_stiffness / l0 * (l - l0);
        -(t_el * (l + l0) / (2.0 * l0))
    }
}

/// Elastic energy (J): `EA/(2 L0) (L - L0)^2`, a cable's while taut (else 0), a member's
/// always, a buckled member's `P^2 L0 / (2 EA) + P (s - s_cr) + k_b (s - s_cr)^2 / 2` (module
/// docs); 0 at a `DISENGAGED` rest length.
pub fn elastic_energy(cable: &CableModel, rest_length: f64, length: f64) -> f64 {
    let ea = cable.axial_stiffness;
    if rest_length == DISENGAGED || (cable.tension_only && length <= rest_length) {
        0.0
    } else if is_buckled(cable, rest_length, length) {
        let p = cable.buckling_load;
        let beyond = rest_length - length - p * rest_length / ea;
        p * p * rest_length / (2.0 * ea)
            + p * beyond
            + 0.5 * buckled_stiffness(cable, rest_length) * beyond * beyond
    } else {
        0.5 * ea / rest_length * (length - rest_length).powi(2)
    }
}

/// What one cable is doing at one instant.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct CableResponse {
    /// Total length `L`, m.
    pub length: f64,
    /// Length rate `Ldot`, m/s.
    pub length_rate: f64,
    /// Rest length used, m.
    pub rest_length: f64,
    /// Tension, N (>= 0 for a cable; a member's is negative in compression).
    pub tension: f64,
    /// True when a cable is no longer than its rest length (`L <= L0`); never for a member.
    pub slack: bool,
    /// Elastic energy, J.
    pub energy: f64,
}

/// Per-route scratch, sized once for the longest route so evaluation never allocates.
#[derive(Debug, Clone, Default)]
pub struct CableScratch {
    /// Segment lengths `l_k` (index k-1 for segment k).
    pub segment_lengths: Vec<f64>,
    seg_dir: Vec<Vector3<f64>>,
    net_dir: Vec<Vector3<f64>>,
    grad: Vec<Vector6<f64>>,
    rate_grad: Vec<Vector6<f64>>,
}

impl CableScratch {
    /// Unit direction `e_k` of segment `k` (from route point `k - 1` to `k`, `k >= 1`) of the
    /// route `route_geometry` last computed (zero for a segment shorter than
    /// `SEGMENT_LENGTH_FLOOR`).
    pub fn segment_direction(&self, k: usize) -> Vector3<f64> {
        self.seg_dir[k - 1]
    }

    /// Scratch for routes of up to `max_route_len` points.
    pub fn new(max_route_len: usize) -> Self {
        Self {
            segment_lengths: vec![0.0; max_route_len],
            seg_dir: vec![Vector3::zeros(); max_route_len],
            net_dir: vec![Vector3::zeros(); max_route_len],
            grad: vec![Vector6::zeros(); max_route_len],
            rate_grad: vec![Vector6::zeros(); max_route_len],
        }
    }
}

/// Fills the scratch with segment lengths and directions and each point's `n_i` and
/// `J_i^T n_i`; returns `(L, Ldot)`.
pub fn route_geometry(route: &[PointId], kin: &[PointKinematics], scratch: &mut CableScratch) -> (f64, f64) {
    let m = route.len() - 1;
    let mut length = 0.0;
    for k in 1..=m {
        let d = kin[route[k].0].position - kin[route[k - 1].0].position;
        let l = d.norm();
        scratch.segment_lengths[k - 1] = l;
        scratch.seg_dir[k - 1] = if l > SEGMENT_LENGTH_FLOOR { d / l } else { Vector3::zeros() };
        length += l;
    }
    let mut rate = 0.0;
    for i in 0..=m {
        let incoming = if i > 0 { scratch.seg_dir[i - 1] } else { Vector3::zeros() };
        let outgoing = if i < m { scratch.seg_dir[i] } else { Vector3::zeros() };
        let n = incoming - outgoing;
        let p = &kin[route[i].0];
        scratch.net_dir[i] = n;
        scratch.grad[i] = p.jacobian.transpose() * n;
        rate += n.dot(&p.velocity);
    }
    (length, rate)
}

/// Adds `scale * g` (g = dL/dq) into `out` (length `model.dof_count`), using the geometry last
/// computed by `route_geometry` for this route.
pub fn add_length_gradient(
    model: &Model,
    route: &[PointId],
    kin: &[PointKinematics],
    scratch: &CableScratch,
    scale: f64,
    out: &mut DVector<f64>,
) {
    for (i, pid) in route.iter().enumerate() {
        add_vector(model, kin[pid.0].body, &scratch.grad[i], scale, out);
    }
}

/// `dL/dq v`, the route's length rate for the coordinate rates `v` (length `model.dof_count`),
/// using the geometry last computed by `route_geometry` for this route (the dot product that
/// `add_length_gradient` adds up as a vector).
pub fn length_gradient_dot(
    model: &Model,
    route: &[PointId],
    kin: &[PointKinematics],
    scratch: &CableScratch,
    v: &DVector<f64>,
) -> f64 {
    let mut rate = 0.0;
    for (i, pid) in route.iter().enumerate() {
        let b = &model.bodies[kin[pid.0].body.0];
        rate += (0..b.dof_count).map(|r| scratch.grad[i][r] * v[b.dof_offset + r]).sum::<f64>();
    }
    rate
}

/// Pushes `(row, dL/dq_row)` for every coordinate the route's points move, using the geometry
/// last computed by `route_geometry` (rows repeat when a route passes a body twice; sum them).
pub fn length_gradient_entries(
    model: &Model,
    route: &[PointId],
    kin: &[PointKinematics],
    scratch: &CableScratch,
    out: &mut Vec<(usize, f64)>,
) {
    for (i, pid) in route.iter().enumerate() {
        let b = &model.bodies[kin[pid.0].body.0];
        out.extend((0..b.dof_count).map(|r| (b.dof_offset + r, scratch.grad[i][r])));
    }
}

/// Evaluates one cable or member (route geometry, tension, energy) and adds its generalized
/// force `-T g` into `force`; leaves the route's geometry in `scratch` for `add_cable_tangents`.
///
/// `kin` holds every point's kinematics; `cable` gives EA (N), damping (N s/m) and the law
/// (`tension_only`), `rest_length` (m, > 0) the current rest length.
pub fn add_cable_force(
    model: &Model,
    route: &[PointId],
    cable: &CableModel,
    rest_length: f64,
    kin: &[PointKinematics],
    scratch: &mut CableScratch,
    force: &mut DVector<f64>,
) -> CableResponse {
    let only = cable.tension_only;
    let (length, length_rate) = route_geometry(route, kin, scratch);
    let t = tension(cable, rest_length, length, length_rate);
    if t != 0.0 {
        add_length_gradient(model, route, kin, scratch, -t, force);
    }
    CableResponse {
        length,
        length_rate,
        rest_length,
        tension: t,
        slack: only && length <= rest_length,
        energy: elastic_energy(cable, rest_length, length),
    }
}

/// True when the element gives matrices at tension `t` (N) and rest length `rest_length` (m):
/// a taut cable (`t > 0`), or a member at any tension (not `DISENGAGED`).
pub fn is_engaged(cable: &CableModel, rest_length: f64, t: f64) -> bool {
    if cable.tension_only {
        t > 0.0
    } else {
        rest_length != DISENGAGED
    }
}

/// Adds segment `k`'s (from route point `k - 1` to `k`) share of the geometric stiffness at
/// tension `t` (N), `t G_k^T P_k G_k` with `P_k = (I - e_k e_k^T) / l_k` (module docs), using
/// the geometry `route_geometry` left in `scratch`. Nothing for a segment shorter than
/// `SEGMENT_LENGTH_FLOOR`.
pub fn add_segment_geometric_stiffness<S: TangentSink + ?Sized>(
    route: &[PointId],
    k: usize,
    kin: &[PointKinematics],
    scratch: &CableScratch,
    t: f64,
    sink: &mut S,
) {
    let l = scratch.segment_lengths[k - 1];
    if l <= SEGMENT_LENGTH_FLOOR {
        return;
    }
    let body_of = |i: usize| kin[route[i].0].body;
    let e = scratch.seg_dir[k - 1];
    let p = (Matrix3::identity() - e * e.transpose()) / l;
    let (ji, jj) = (&kin[route[k - 1].0].jacobian, &kin[route[k].0].jacobian);
    let (pji, pjj) = (p * ji, p * jj);
    let cross = jj.transpose() * pji; // its transpose is ji^T P jj (P is symmetric)
    sink.stiffness(body_of(k), body_of(k), &(jj.transpose() * pjj), t);
    sink.stiffness(body_of(k - 1), body_of(k - 1), &(ji.transpose() * pji), t);
    sink.stiffness(body_of(k), body_of(k - 1), &cross, -t);
    sink.stiffness(body_of(k - 1), body_of(k), &cross.transpose(), -t);
}

/// Adds one cable's tangent stiffness `K` and damping matrix `C` (module docs) into `sink`, for
/// the tension `t` (N) found by `add_cable_force` and the route geometry it left in `scratch`
/// (call `route_geometry` again when the scratch was reused since). The caller skips elements
/// that are not engaged (`is_engaged`); the geometric terms take `t` of either sign.
#[allow(clippy::too_many_arguments)]
pub fn add_cable_tangents<S: TangentSink + ?Sized>(
    model: &Model,
    poses: &[Pose],
    v: &DVector<f64>,
    cable: CableId,
    route: &[PointId],
    ea: f64,
    damping_coeff: f64,
    rest_length: f64,
    t: f64,
    kin: &[PointKinematics],
    scratch: &mut CableScratch,
    sink: &mut S,
) {
    let m = route.len() - 1;
    let body_of = |i: usize| kin[route[i].0].body;
    // T sum_k G_k^T P_k G_k
    for k in 1..=m {
        add_segment_geometric_stiffness(route, k, kin, scratch, t, sink);
    }
    // T sum_i d(J_i^T n_i)/dq
    for i in 0..=m {
        if model.bodies[body_of(i).0].kind == crate::model::BodyKind::Node {
            continue; // a point mass's Jacobian does not depend on its configuration
        }
        let d2 = force_jacobian_derivative(model, poses, route[i], &scratch.net_dir[i]);
        sink.stiffness(body_of(i), body_of(i), &d2, t);
    }
    // h = dLdot/dq: how the damper's share of T changes with the configuration
    let rate_grad = if damping_coeff > 0.0 {
        for i in 0..=m {
            let dv = velocity_derivative(model, poses, v, route[i]);
            scratch.rate_grad[i] = dv.transpose() * scratch.net_dir[i];
        }
        for k in 1..=m {
            let l = scratch.segment_lengths[k - 1];
            if l <= SEGMENT_LENGTH_FLOOR {
                continue;
            }
            let e = scratch.seg_dir[k - 1];
            let (pi, pj) = (&kin[route[k - 1].0], &kin[route[k].0]);
            let w = (pj.velocity - pi.velocity - e * e.dot(&(pj.velocity - pi.velocity))) / l;
            scratch.rate_grad[k] += pj.jacobian.transpose() * w;
            scratch.rate_grad[k - 1] -= pi.jacobian.transpose() * w;
        }
        Some(&scratch.rate_grad[..=m])
    } else {
        None
    };
    // (EA/L0) g g^T + c g h^T into K, c g g^T into C
    sink.cable_rank_one(cable, route, kin, &scratch.grad[..=m], rate_grad, ea / rest_length, damping_coeff);
}
