//! The ground contact element: takes a contact sphere's point kinematics and a half-space ground,
//! gives the compliant normal force and the friction force, the generalized force `Q = J^T F`,
//! its tangent stiffness `K = -dQ/dq` and damping `C = -dQ/dv`, the contact's stored energy and
//! the power it dissipates.
//!
//! A sphere of radius `rho` centred at the body point `r` (velocity `rdot`) meets the ground
//! `n . x >= h` (unit normal `n`) at its lowest point `c = r + a`, `a = -rho n` (a world-fixed
//! offset: as the body turns, other material points of the sphere come to touch). The material
//! point at `c` moves at `v_c = rdot + omega x a` (`omega` the body's world angular velocity), so
//! `v_c = J_c v` with `J_c = J + [a]x^T R B_r` (the centre's Jacobian and, per rotation column, the
//! lever `a`). With
//! - penetration `delta = h + rho - n . r` and its rate `delta_dot = -n . rdot = -n . v_c`;
//! - normal force (Hunt-Crossley, linear spring): `F_n = max(0, k delta (1 + alpha delta_dot))`
//!   while `delta > 0`, else 0. The force grows from zero at touchdown (no jump for the
//!   integrators to resolve), the loss per impact grows with the impact speed, and the ground
//!   never pulls: a sphere leaving faster than `1 / alpha` feels nothing;
//! - friction (Coulomb, regularized): `F_t = -mu F_n u / s`, with the contact point's slip
//!   `u = P v_c`, `P = I - n n^T`, and `s = sqrt(|u|^2 + v_s^2)`. Below `v_s` the law is a stiff
//!   viscous stick, above it Coulomb's `mu F_n` against the slip. A tangential load at a fraction
//!   `r < 1` of `mu F_n` creeps at `v_s r / sqrt(1 - r^2)` (reported as the slip speed). A
//!   sphere (or a rigid body on spheres) rolls without slipping when friction allows: its
//!   contact point is still, the friction's lever `a` turns it;
//! - `F = F_n n + F_t = F_n w`, `w = n - mu u / s`, applied at `c`: `Q = J_c^T F`;
//! - stored energy `k delta^2 / 2` while `delta > 0`, and the dissipated power
//!   `(F_n - k delta) delta_dot + mu F_n |u|^2 / s >= 0` (what the normal force does beyond the
//!   spring, plus the friction's), so that the energy account closes.
//!
//! With `dF_n/dr = a_r n^T`, `a_r = -k (1 + alpha delta_dot)`, and `dF_n/dv_c = a_v n^T`,
//! `a_v = -k alpha delta`:
//! - `A_r = dF/dr = w a_r n^T`,
//! - `A_v = dF/dv_c = w a_v n^T - mu F_n (P - u u^T / s^2) / s`,
//! - `D_c = d(v_c)/dq = D + [a]x R [omega_b]x B_r`, with `D = d(rdot)/dq`
//!   (`kinematics::velocity_derivative`) and `omega_b` the body-frame angular velocity,
//! - `K = -J_c^T A_r J - J_c^T A_v D_c - d(J^T F)/dq - B_r^T [R^T (a x F)]x B_r`, the last two the
//!   geometric terms at fixed `F` (the centre's, `kinematics::force_jacobian_derivative`, and the
//!   lever's),
//! - `C = -J_c^T A_v J_c`.
//!
//! In statics (`v = 0`) only the spring acts: `K = k J^T n n^T J` plus the geometric terms; the
//! ground holds a structure up but not sideways, so its free sliding and turning on the ground
//! are zero-stiffness (rigid-body) modes. `tests/contact.rs` checks `K` and `C` against finite
//! differences of `Q`.

use nalgebra::{Matrix3, Matrix6, Vector3};

use crate::assembly::{add_vector, TangentSink};
use crate::kinematics::{force_jacobian_derivative, velocity_derivative, PointJacobian, PointKinematics};
use crate::model::{ContactSphere, GroundModel, Model, Pose};
use nalgebra::DVector;

/// What one sphere is doing against one ground at one instant.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct ContactResponse {
    /// Signed distance of the sphere's surface from the ground, m: negative while it presses in
    /// (`-delta`).
    pub gap: f64,
    /// Rate of the penetration `delta_dot`, m/s (positive while pressing in).
    pub penetration_rate: f64,
    /// Normal force `F_n`, N (>= 0).
    pub normal_force: f64,
    /// Friction force on the body, world frame, N (in the ground's plane).
    pub friction: Vector3<f64>,
    /// Slip velocity `u` of the sphere's contact point along the ground, world frame, m/s (0
    /// for a sphere that rolls without slipping).
    pub slip: Vector3<f64>,
    /// The contact point: the sphere's centre projected on the ground (for two struts, the
    /// middle of their axes' closest points), world frame, m.
    pub position: Vector3<f64>,
    /// Unit contact normal, world frame: the ground's outward normal (for two struts, from the
    /// second toward the first).
    pub normal: Vector3<f64>,
    /// Stored energy `k delta^2 / 2`, J.
    pub energy: f64,
    /// Power dissipated by the normal damping and the friction, W (>= 0).
    pub loss_power: f64,
}

impl ContactResponse {
    /// True while the sphere presses into the ground (`gap < 0`).
    pub fn in_contact(&self) -> bool {
        self.gap < 0.0
    }
    /// The whole force on the body (for two struts, on the first), world frame, N: `F_n n + F_t`.
    pub fn force(&self) -> Vector3<f64> {
        self.normal * self.normal_force + self.friction
    }
}

/// The contact point of a sphere against a ground: its offset from the centre, velocity and
/// Jacobian (module docs).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ContactPoint {
    /// `a = -rho n`, from the sphere's centre to its lowest point, world frame, m.
    pub offset: Vector3<f64>,
    /// `v_c = rdot + omega x a`, m/s.
    pub velocity: Vector3<f64>,
    /// `J_c = dv_c/dv` (3 x 6, the body's first `dof_count` columns).
    pub jacobian: PointJacobian,
}

/// The contact point of `sphere` (centre kinematics `kin`, on a body at `poses` with local
/// velocities `v`) against `ground`.
pub fn contact_point(
    model: &Model,
    poses: &[Pose],
    v: &DVector<f64>,
    ground: &GroundModel,
    sphere: &ContactSphere,
    kin: &PointKinematics,
) -> ContactPoint {
    let offset = ground.normal * -sphere.radius;
    let body = &model.bodies[kin.body.0];
    let mut jacobian = kin.jacobian;
    let mut velocity = kin.velocity;
    if sphere.radius > 0.0 && body.kind != crate::model::BodyKind::Node {
        let rot = poses[kin.body.0].rotation;
        for c in 0..body.dof_count {
            let b = body.basis.column(c);
            let b_r = Vector3::new(b[3], b[4], b[5]);
            if b_r != Vector3::zeros() {
                let lever = (rot * b_r).cross(&offset);
                let mut column = jacobian.column_mut(c);
                column += lever;
                velocity += lever * v[body.dof_offset + c];
            }
        }
    }
    ContactPoint { offset, velocity, jacobian }
}

/// The response of `sphere` (centre kinematics `kin`, contact point `point`) against `ground`;
/// no allocation.
pub fn contact_response(
    ground: &GroundModel,
    sphere: &ContactSphere,
    kin: &PointKinematics,
    point: &ContactPoint,
) -> ContactResponse {
    let n = &ground.normal;
    let m = &ground.material;
    let height = n.dot(&kin.position);
    let delta = ground.offset + sphere.radius - height;
    let position = kin.position - n * (height - ground.offset);
    if delta.is_nan() || delta <= 0.0 {
        return ContactResponse { gap: -delta, position, normal: *n, ..Default::default() };
    }
    let delta_dot = -n.dot(&kin.velocity);
    let spring = m.stiffness * delta;
    let normal_force = (spring * (1.0 + m.dissipation * delta_dot)).max(0.0);
    let slip = point.velocity - n * n.dot(&point.velocity);
    let s = (slip.norm_squared() + m.stiction_speed * m.stiction_speed).sqrt();
    let friction = slip * (-m.friction * normal_force / s);
    let loss_power =
        (normal_force - spring) * delta_dot + m.friction * normal_force * slip.norm_squared() / s;
    ContactResponse {
        gap: -delta,
        penetration_rate: delta_dot,
        normal_force,
        friction,
        slip,
        position,
        normal: *n,
        energy: 0.5 * spring * delta,
        loss_power,
    }
}

/// Evaluates one sphere against one ground and adds the generalized force `J_c^T F` into `force`
/// (length `model.dof_count`); `poses` and `v` are the state's.
pub fn add_contact_force(
    model: &Model,
    poses: &[Pose],
    v: &DVector<f64>,
    ground: &GroundModel,
    sphere: &ContactSphere,
    kin: &PointKinematics,
    force: &mut DVector<f64>,
) -> ContactResponse {
    let point = contact_point(model, poses, v, ground, sphere, kin);
    let response = contact_response(ground, sphere, kin, &point);
    if response.normal_force > 0.0 {
        let f = response.force();
        add_vector(model, kin.body, &(point.jacobian.transpose() * f), 1.0, force);
    }
    response
}

/// Adds one contact's tangent stiffness `K` and damping `C` (module docs) into `sink`, for the
/// `response` that `add_contact_force` found at `kin` (poses `poses`, local velocities `v`).
/// Nothing while the normal force is zero.
#[allow(clippy::too_many_arguments)]
pub fn add_contact_tangents<S: TangentSink + ?Sized>(
    model: &Model,
    poses: &[Pose],
    v: &DVector<f64>,
    ground: &GroundModel,
    sphere: &ContactSphere,
    kin: &PointKinematics,
    response: &ContactResponse,
    sink: &mut S,
) {
    let f_n = response.normal_force;
    if f_n <= 0.0 {
        return;
    }
    let n = ground.normal;
    let m = &ground.material;
    let delta = -response.gap;
    let u = response.slip;
    let s = (u.norm_squared() + m.stiction_speed * m.stiction_speed).sqrt();
    let w = n - u * (m.friction / s);
    let a_r = -m.stiffness * (1.0 + m.dissipation * response.penetration_rate);
    let a_v = -m.stiffness * m.dissipation * delta;
    let a_pos = w * n.transpose() * a_r;
    let p = Matrix3::identity() - n * n.transpose();
    let mut a_vel = w * n.transpose() * a_v;
    if m.friction > 0.0 {
        a_vel -= (p - u * u.transpose() / (s * s)) * (m.friction * f_n / s);
    }
    let point = contact_point(model, poses, v, ground, sphere, kin);
    let (j, j_c) = (&kin.jacobian, &point.jacobian);
    let body = kin.body;
    let mut k: Matrix6<f64> = -(j_c.transpose() * a_pos * j);
    let model_body = &model.bodies[body.0];
    if model_body.kind != crate::model::BodyKind::Node {
        let f = response.force();
        let mut d = velocity_derivative(model, poses, v, sphere.point);
        let b_r = model_body.basis.fixed_view::<3, 6>(3, 0);
        let rot = poses[body.0].rotation.to_rotation_matrix();
        if sphere.radius > 0.0 {
            // the lever's part of d(v_c)/dq: [a]x R [omega_b]x B_r
            let local = model_body.local_increment(v.as_slice(), 1.0);
            let omega = Vector3::new(local[3], local[4], local[5]);
            d += point.offset.cross_matrix() * rot.matrix() * omega.cross_matrix() * b_r;
        }
        k -= j_c.transpose() * a_vel * d;
        k -= force_jacobian_derivative(model, poses, sphere.point, &f);
        if sphere.radius > 0.0 {
            // the lever's geometric term: B_r^T [R^T (a x F)]x B_r
            let torque = rot.inverse() * point.offset.cross(&f);
            k -= b_r.transpose() * torque.cross_matrix() * b_r;
        }
    }
    sink.stiffness(body, body, &k, 1.0);
    sink.damping(body, body, &(j_c.transpose() * a_vel * j_c), -1.0);
}

/// Adds to dense `K` and `C` (`n x n`, `n = model.dof_count`) what every contact pair would
/// contribute pressed into its ground, for explicit integrators' stability limits
/// (`crate::solve::dynamics::spectral_bounds`): a contact that is open now has its stiffness as
/// soon as it touches, as a slack cable has. Per pair, with `F` the structure's whole weight
/// (`sum m |g|`, at least 1 N: one sphere may carry it all): stiffness `k J^T n n^T J`, and
/// damping `J^T (alpha F n n^T + (mu F / v_s) P) J`, the normal damper's and the stuck
/// friction's slopes at that load.
pub fn add_contact_bounds(
    model: &Model,
    poses: &[Pose],
    points: &[PointKinematics],
    stiffness: &mut nalgebra::DMatrix<f64>,
    damping: &mut nalgebra::DMatrix<f64>,
) {
    if model.ground_pairs() == 0 {
        return;
    }
    let weight = model.bodies.iter().map(|b| b.mass).sum::<f64>() * model.gravity.norm();
    let load = weight.max(1.0);
    let still = DVector::zeros(model.dof_count);
    for sphere in &model.contact_spheres {
        let kin = &points[sphere.point.0];
        for ground in &model.grounds {
            let n = ground.normal;
            let m = &ground.material;
            let nn = n * n.transpose();
            let p = Matrix3::identity() - nn;
            let jn = kin.jacobian.transpose() * n;
            crate::assembly::add_block(
                model,
                kin.body,
                kin.body,
                &(jn * jn.transpose()),
                m.stiffness,
                stiffness,
            );
            let c3 = nn * (m.dissipation * load) + p * (m.friction * load / m.stiction_speed);
            let j_c = contact_point(model, poses, &still, ground, sphere, kin).jacobian;
            let c6 = j_c.transpose() * c3 * j_c;
            crate::assembly::add_block(model, kin.body, kin.body, &c6, 1.0, damping);
        }
    }
}
