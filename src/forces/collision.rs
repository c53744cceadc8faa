//! The strut-strut collision element: takes two bars' capsules (their axis end points' kinematics
//! and the sum of their radii), gives the closest points of the two axes, the compliant normal
//! force and the friction between them, the generalized force, its tangent stiffness
//! `K = -dQ/dq` and damping `C = -dQ/dv`, the stored energy and the dissipated power.
//!
//! The first bar's axis runs `x(s) = r_a + s e1` (`e1 = r_b - r_a`, `0 <= s <= 1`), the
//! second's `y(t) = r_c + t e2`. The closest points `p1 = x(s)`, `p2 = y(t)` (clamped to the
//! segments; for parallel axes, the middle of their overlap) are `d = |w|` apart, `w = p1 - p2`,
//! with unit normal `n = w / d` from the second bar to the first. With `R` the sum of the radii:
//! - penetration `delta = R - d`, its rate `delta_dot = -n . v_rel`, `v_rel = v(p1) - v(p2)` the
//!   velocity of the material point at `p1` relative to that at `p2` (on a rigid bar the velocity
//!   along the axis is linear in `s`: `v(p1) = (1 - s) v_a + s v_b`);
//! - the same law as against a ground (`crate::forces::contact`): Hunt-Crossley normal force
//!   `F_n = max(0, k delta (1 + alpha delta_dot))` and regularized Coulomb friction
//!   `-mu F_n u / sqrt(|u|^2 + v_s^2)` on the slip `u = P v_rel`, `P = I - n n^T`;
//! - the force `F = F_n n - mu F_n u / s_r` acts on the first bar at `p1` and `-F` on the second
//!   at `p2`, shared between each bar's ends as `(1 - s) F` and `s F` (`(1 - t)`, `t`): in
//!   end-point forces `f = G^T F`, `G = [(1-s) I, s I, -(1-t) I, -t I]`, and `Q = sum_i J_i^T f_i`;
//! - stored energy `k delta^2 / 2`, dissipated power `(F_n - k delta) delta_dot + mu F_n |u|^2 /
//!   s_r >= 0`.
//!
//! The tangents follow the closest points: where `s` is interior it satisfies `w . e1 = 0` (and
//! `t`, `w . e2 = 0`), and differentiating those equations gives `ds/dX` and `dt/dX` for the
//! twelve end coordinates `X` (zero where a parameter sits clamped at an end). From them `dw/dX`,
//! `dn/dX = P (dw/dX) / d`, the derivatives of `delta`, `delta_dot`, `u` and `F`, and finally
//! `df/dX`, `df/dV` (`V` the ends' velocities). Then, with `D_j = d(v_j)/dq` at fixed `v`
//! (`kinematics::velocity_derivative`), `K = -sum_ij J_i^T (df_i/dX_j J_j + df_i/dV_j D_j) -
//! sum_i d(J_i^T f_i)/dq|f` and `C = -sum_ij J_i^T (df_i/dV_j) J_j`. For (nearly) parallel axes
//! the closest points are not unique and `ds/dX` is taken as zero there. `tests/collision.rs`
//! checks `K` and `C` against finite differences of `Q`.
//!
//! Friction acts on the axis points (no lever of the radius): the power it dissipates is exactly
//! what it takes from the motion, so the energy account closes; a bar rolling along another
//! (rather than sliding) is not modelled.

use nalgebra::{DVector, Matrix3, Matrix6, SMatrix, Vector3};

use crate::assembly::{add_vector, TangentSink};
use crate::forces::contact::ContactResponse;
use crate::kinematics::{force_jacobian_derivative, velocity_derivative, PointKinematics};
use crate::model::{ContactMaterial, Model, Pose, StrutPair};

type Row12 = SMatrix<f64, 1, 12>;
type Mat3x12 = SMatrix<f64, 3, 12>;
type Mat12 = SMatrix<f64, 12, 12>;

/// Below this `|e1 x e2|^2 / (|e1|^2 |e2|^2)` (the squared sine of the angle between the axes)
/// two axes count as parallel.
const PARALLEL: f64 = 1e-12;

/// The closest points of two capsule axes.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct ClosestPoints {
    /// Parameter of `p1` on the first axis, in `[0, 1]`.
    pub s: f64,
    /// Parameter of `p2` on the second axis, in `[0, 1]`.
    pub t: f64,
    /// `s` lies strictly inside `(0, 1)` and is found by `w . e1 = 0` (not parallel axes).
    pub s_free: bool,
    /// `t` lies strictly inside `(0, 1)` and is found by `w . e2 = 0`.
    pub t_free: bool,
    /// `w = p1 - p2`, m.
    pub w: Vector3<f64>,
    /// Which side of the second axis the first passes: the sign of `w . (e1 x e2)` while both
    /// closest points are interior and the axes are not parallel, else 0. A sub-step that flips
    /// it from `+1` to `-1` (or back) carried one bar through the other.
    pub side: f64,
}

/// The closest points of the axes `r_a + s (r_b - r_a)` and `r_c + t (r_d - r_c)`, both
/// parameters in `[0, 1]` (Ericson, Real-Time Collision Detection, 5.1.9; parallel axes: the
/// middle of their overlap along the first, or its nearest end). Preconditions: both axes have
/// positive length.
pub fn closest_points(
    r_a: &Vector3<f64>,
    r_b: &Vector3<f64>,
    r_c: &Vector3<f64>,
    r_d: &Vector3<f64>,
) -> ClosestPoints {
    let (e1, e2, r) = (r_b - r_a, r_d - r_c, r_a - r_c);
    let (a, e, b) = (e1.norm_squared(), e2.norm_squared(), e1.dot(&e2));
    let (c, f) = (e1.dot(&r), e2.dot(&r));
    let denom = a * e - b * b;
    let parallel = denom <= PARALLEL * a * e;
    let mut s = if parallel {
        // the second axis's ends projected on the first: the middle of the overlap
        let (s0, s1) = (-c / a, (b - c) / a);
        let (lo, hi) = (s0.min(s1).max(0.0), s0.max(s1).min(1.0));
        if lo <= hi {
            0.5 * (lo + hi)
        } else {
            0.5 * (s0 + s1).clamp(0.0, 1.0)
        }
    } else {
        ((b * f - c * e) / denom).clamp(0.0, 1.0)
    };
    let mut t = (b * s + f) / e;
    if t < 0.0 {
        t = 0.0;
        s = (-c / a).clamp(0.0, 1.0);
    } else if t > 1.0 {
        t = 1.0;
        s = ((b - c) / a).clamp(0.0, 1.0);
    }
    let w = r_a + e1 * s - r_c - e2 * t;
    let (s_free, t_free) = (!parallel && s > 0.0 && s < 1.0, t > 0.0 && t < 1.0);
    let cross = e1.cross(&e2);
    let across = w.dot(&cross);
    let side = if !(s_free && t_free) || across.abs() <= 1e-9 * w.norm() * cross.norm() {
        0.0
    } else {
        across.signum()
    };
    ClosestPoints { s, t, s_free, t_free, w, side }
}

/// Below this distance of their axes, m, two capsules' normal is not `w / |w|` but
/// `crossing_normal`'s, and their tangents are left out (the axes meet: no direction to
/// differentiate).
pub const AXIS_DISTANCE_FLOOR: f64 = 1e-12;

/// A unit normal for axes that meet: across both (`e1 x e2`), or for parallel ones any direction
/// normal to the first.
fn crossing_normal(e1: &Vector3<f64>, e2: &Vector3<f64>) -> Vector3<f64> {
    let across = e1.cross(e2);
    if across.norm() > 1e-9 * e1.norm() * e2.norm() {
        return across.normalize();
    }
    let e = e1.normalize();
    let helper = if e.x.abs() < 0.9 { Vector3::x() } else { Vector3::y() };
    e.cross(&helper).normalize()
}

/// The end points' positions and velocities of a pair: `[a, b, c, d]`.
fn ends(points: &[PointKinematics], pair: &StrutPair) -> ([Vector3<f64>; 4], [Vector3<f64>; 4]) {
    let k = pair.ends.map(|p| points[p.0]);
    (k.map(|p| p.position), k.map(|p| p.velocity))
}

/// `G = [(1-s) I, s I, -(1-t) I, -t I]` (3 x 12).
fn share_matrix(s: f64, t: f64) -> Mat3x12 {
    let mut g = Mat3x12::zeros();
    for (block, w) in [1.0 - s, s, t - 1.0, -t].into_iter().enumerate() {
        for i in 0..3 {
            g[(i, 3 * block + i)] = w;
        }
    }
    g
}

/// The response of a pair from its ends' positions `x` and velocities `v` (module docs), with
/// the closest points; no allocation.
fn pair_response(
    x: &[Vector3<f64>; 4],
    v: &[Vector3<f64>; 4],
    radius: f64,
    m: &ContactMaterial,
) -> (ContactResponse, ClosestPoints) {
    let cp = closest_points(&x[0], &x[1], &x[2], &x[3]);
    let d = cp.w.norm();
    let n = if d > AXIS_DISTANCE_FLOOR { cp.w / d } else { crossing_normal(&(x[1] - x[0]), &(x[3] - x[2])) };
    let p1 = x[0] + (x[1] - x[0]) * cp.s;
    let delta = radius - d;
    let mut response =
        ContactResponse { gap: -delta, normal: n, position: p1 - n * (0.5 * d), ..Default::default() };
    if delta.is_nan() || delta <= 0.0 {
        return (response, cp);
    }
    let v_rel = v[0] * (1.0 - cp.s) + v[1] * cp.s - v[2] * (1.0 - cp.t) - v[3] * cp.t;
    let delta_dot = -n.dot(&v_rel);
    let spring = m.stiffness * delta;
    let normal_force = (spring * (1.0 + m.dissipation * delta_dot)).max(0.0);
    let slip = v_rel - n * n.dot(&v_rel);
    let s_r = (slip.norm_squared() + m.stiction_speed * m.stiction_speed).sqrt();
    response.penetration_rate = delta_dot;
    response.normal_force = normal_force;
    response.friction = slip * (-m.friction * normal_force / s_r);
    response.slip = slip;
    response.energy = 0.5 * spring * delta;
    response.loss_power =
        (normal_force - spring) * delta_dot + m.friction * normal_force * slip.norm_squared() / s_r;
    response.friction_state = if m.friction > 0.0 {
        crate::forces::contact::FrictionState::Regularized
    } else {
        crate::forces::contact::FrictionState::Frictionless
    };
    (response, cp)
}

/// Evaluates the pair and adds its generalized force into `force` (length `model.dof_count`).
/// The response's `friction` is the force on the first bar, its `normal` points from the second
/// bar to the first, its `position` is the middle of the two closest points. Also returns the
/// closest points, for `add_collision_tangents` at the same state.
pub fn add_collision_force(
    model: &Model,
    points: &[PointKinematics],
    pair: &StrutPair,
    material: &ContactMaterial,
    force: &mut DVector<f64>,
) -> (ContactResponse, ClosestPoints) {
    let (x, v) = ends(points, pair);
    let (response, cp) = pair_response(&x, &v, pair.radius, material);
    if response.normal_force > 0.0 {
        let f = response.force();
        let shares = [1.0 - cp.s, cp.s, cp.t - 1.0, -cp.t];
        for (p, share) in pair.ends.iter().zip(shares) {
            let kin = &points[p.0];
            add_vector(model, kin.body, &(kin.jacobian.transpose() * f), share, force);
        }
    }
    (response, cp)
}

/// `df/dX` and `df/dV` of the end-point forces `f = G^T F` (module docs) for the `response` and
/// closest points `cp` that `pair_response` found at the ends' positions `x` and velocities `v`,
/// or None while the pair exerts no force.
fn end_force_derivatives(
    x: &[Vector3<f64>; 4],
    v: &[Vector3<f64>; 4],
    m: &ContactMaterial,
    response: &ContactResponse,
    cp: &ClosestPoints,
) -> Option<(Mat12, Mat12, [Vector3<f64>; 4])> {
    let f_n = response.normal_force;
    if f_n <= 0.0 || cp.w.norm() <= AXIS_DISTANCE_FLOOR {
        return None;
    }
    let (s, t, w) = (cp.s, cp.t, cp.w);
    let (e1, e2) = (x[1] - x[0], x[3] - x[2]);
    let g = share_matrix(s, t);
    // d(w . e1)/dX and d(w . e2)/dX at fixed s, t
    let mut c1 = e1.transpose() * g;
    let mut c2 = e2.transpose() * g;
    for i in 0..3 {
        c1[3 + i] += w[i];
        c1[i] -= w[i];
        c2[9 + i] += w[i];
        c2[6 + i] -= w[i];
    }
    let (aa, bb, ee) = (e1.norm_squared(), e1.dot(&e2), e2.norm_squared());
    let (sx, tx) = match (cp.s_free, cp.t_free) {
        (true, true) => {
            // [aa, -bb; bb, -ee] [ds; dt] = -[c1; c2]
            let det = -aa * ee + bb * bb;
            let ds = (c1 * ee - c2 * bb) * (1.0 / det);
            let dt = (c1 * bb - c2 * aa) * (1.0 / det);
            (ds, dt)
        }
        (true, false) => (-c1 / aa, Row12::zeros()),
        (false, true) => (Row12::zeros(), c2 / ee),
        (false, false) => (Row12::zeros(), Row12::zeros()),
    };
    let d = w.norm();
    let n = response.normal;
    let p = Matrix3::identity() - n * n.transpose();
    let wx = g + e1 * sx - e2 * tx;
    let nx = p * wx / d;
    let delta_x = -(n.transpose() * wx);
    let v_rel = g * SMatrix::<f64, 12, 1>::from_iterator(v.iter().flat_map(|a| a.iter().copied()));
    let v_rel_x = (v[1] - v[0]) * sx - (v[3] - v[2]) * tx;
    let delta_dot = response.penetration_rate;
    let delta_dot_x = -(v_rel.transpose() * nx + n.transpose() * v_rel_x);
    let delta_dot_v = -(n.transpose() * g);
    let delta = -response.gap;
    let f_n_x = delta_x * (m.stiffness * (1.0 + m.dissipation * delta_dot))
        + delta_dot_x * (m.stiffness * m.dissipation * delta);
    let f_n_v = delta_dot_v * (m.stiffness * m.dissipation * delta);
    let u = response.slip;
    let s_r = (u.norm_squared() + m.stiction_speed * m.stiction_speed).sqrt();
    let dir = n - u * (m.friction / s_r);
    let mut force_x = dir * f_n_x + nx * f_n;
    let mut force_v = dir * f_n_v;
    if m.friction > 0.0 {
        let u_x = p * v_rel_x - (n * v_rel.transpose() + Matrix3::identity() * n.dot(&v_rel)) * nx;
        let u_v = p * g;
        let slope = (Matrix3::identity() - u * u.transpose() / (s_r * s_r)) * (m.friction * f_n / s_r);
        force_x -= slope * u_x;
        force_v -= slope * u_v;
    }
    let force = response.force();
    let mut f_x = g.transpose() * force_x;
    let f_v = g.transpose() * force_v;
    for i in 0..3 {
        for j in 0..12 {
            // d(G^T)/ds F = [-F; F; 0; 0], d(G^T)/dt F = [0; 0; F; -F]
            f_x[(i, j)] -= force[i] * sx[j];
            f_x[(3 + i, j)] += force[i] * sx[j];
            f_x[(6 + i, j)] += force[i] * tx[j];
            f_x[(9 + i, j)] -= force[i] * tx[j];
        }
    }
    let shares = [1.0 - s, s, t - 1.0, -t];
    Some((f_x, f_v, shares.map(|a| force * a)))
}

/// Adds the pair's tangent stiffness `K` and damping `C` (module docs) into `sink`, at the
/// point kinematics `points` of the state `poses`, `v`, for the `response` and closest points
/// `closest` that `add_collision_force` found there. Nothing while the pair is apart.
#[allow(clippy::too_many_arguments)]
pub fn add_collision_tangents<S: TangentSink + ?Sized>(
    model: &Model,
    poses: &[Pose],
    v: &DVector<f64>,
    points: &[PointKinematics],
    pair: &StrutPair,
    material: &ContactMaterial,
    (response, closest): (&ContactResponse, &ClosestPoints),
    sink: &mut S,
) {
    let (x, vel) = ends(points, pair);
    let Some((f_x, f_v, f)) = end_force_derivatives(&x, &vel, material, response, closest) else {
        return;
    };
    let kin = pair.ends.map(|p| points[p.0]);
    let rate = pair.ends.map(|p| velocity_derivative(model, poses, v, p));
    let mut k = [[Matrix6::zeros(); 2]; 2];
    let mut c = [[Matrix6::zeros(); 2]; 2];
    for i in 0..4 {
        for j in 0..4 {
            let fx = f_x.fixed_view::<3, 3>(3 * i, 3 * j);
            let fv = f_v.fixed_view::<3, 3>(3 * i, 3 * j);
            let ji_t = kin[i].jacobian.transpose();
            k[i / 2][j / 2] -= ji_t * (fx * kin[j].jacobian + fv * rate[j]);
            c[i / 2][j / 2] -= ji_t * fv * kin[j].jacobian;
        }
        k[i / 2][i / 2] -= force_jacobian_derivative(model, poses, pair.ends[i], &f[i]);
    }
    for a in 0..2 {
        for b in 0..2 {
            sink.stiffness(pair.bars[a], pair.bars[b], &k[a][b], 1.0);
            sink.damping(pair.bars[a], pair.bars[b], &c[a][b], 1.0);
        }
    }
}

/// Adds to dense `K` and `C` (`n x n`) a bound on what every strut pair would contribute in
/// contact, for explicit integrators' stability limits: with `J(s)` the Jacobian of a bar's
/// axis point, `(J1 - J2)^T B (J1 - J2) <= 2 (J1^T B J1 + J2^T B J2)` for a positive `B`, and
/// `B <= b I` for any contact direction; `b = k` for the stiffness, and `alpha F + mu F / v_s`
/// for the damping at the load `F` (the structure's weight, at least 1 N), as
/// `forces::contact::add_contact_bounds` does for grounds. Both bars' Jacobians are taken at
/// their ends (the largest `|J(s)|`).
pub fn add_collision_bounds(
    model: &Model,
    points: &[PointKinematics],
    stiffness: &mut nalgebra::DMatrix<f64>,
    damping: &mut nalgebra::DMatrix<f64>,
) {
    if model.strut_pairs.is_empty() {
        return;
    }
    let weight = model.bodies.iter().map(|b| b.mass).sum::<f64>() * model.gravity.norm();
    let load = weight.max(1.0);
    let m = &model.strut_material;
    let k_bound = 2.0 * m.stiffness;
    let c_bound = 2.0 * (m.dissipation * load + m.friction * load / m.stiction_speed);
    for pair in &model.strut_pairs {
        for p in pair.ends {
            let kin = &points[p.0];
            let jtj = kin.jacobian.transpose() * kin.jacobian;
            crate::assembly::add_block(model, kin.body, kin.body, &jtj, k_bound, stiffness);
            crate::assembly::add_block(model, kin.body, kin.body, &jtj, c_bound, damping);
        }
    }
}
