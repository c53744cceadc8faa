//! The ground contact element: takes a contact sphere's point kinematics and a half-space ground,
//! gives the compliant normal force and the friction force, the generalized force `Q = J^T F`,
//! its tangent stiffness `K = -dQ/dq` and damping `C = -dQ/dv`, the contact's stored energy and
//! the power it dissipates.
//!
//! A sphere of radius `rho` centred at the body point `r` (velocity `rdot = J v`) meets the ground
//! `n . x >= h` (unit normal `n`) with
//! - penetration `delta = h + rho - n . r` and its rate `delta_dot = -n . rdot`;
//! - normal force (Hunt-Crossley, linear spring): `F_n = max(0, k delta (1 + alpha delta_dot))`
//!   while `delta > 0`, else 0. The force grows from zero at touchdown (no jump for the
//!   integrators to resolve), the loss per impact grows with the impact speed, and the ground
//!   never pulls: a sphere leaving faster than `1 / alpha` feels nothing;
//! - friction (Coulomb, regularized): `F_t = -mu F_n u / s`, with the slip velocity
//!   `u = P rdot`, `P = I - n n^T`, and `s = sqrt(|u|^2 + v_s^2)`. Below `v_s` the law is a
//!   viscous stick, above it Coulomb's `mu F_n` against the slip. A tangential load at a fraction
//!   `r < 1` of `mu F_n` creeps at `v_s r / sqrt(1 - r^2)` (reported as the slip speed);
//! - `F = F_n n + F_t = F_n w`, `w = n - mu u / s`, applied at the sphere's centre (the sphere
//!   slides, it does not roll: exact for `rho -> 0`, and a bar cannot spin about its own axis);
//! - stored energy `k delta^2 / 2` while `delta > 0`, and the dissipated power
//!   `(F_n - k delta) delta_dot + mu F_n |u|^2 / s >= 0` (what the normal force does beyond the
//!   spring, plus the friction's), so that the energy account closes.
//!
//! With `dF_n/dr = a_r n^T`, `a_r = -k (1 + alpha delta_dot)`, and `dF_n/drdot = a_v n^T`,
//! `a_v = -k alpha delta`:
//! - `A_r = dF/dr = w a_r n^T`,
//! - `A_v = dF/drdot = w a_v n^T - mu F_n (P - u u^T / s^2) / s`,
//! - `K = -J^T A_r J - J^T A_v D - d(J^T F)/dq`, with `D = d(rdot)/dq`
//!   (`kinematics::velocity_derivative`) and the geometric term at fixed `F`
//!   (`kinematics::force_jacobian_derivative`),
//! - `C = -J^T A_v J`.
//!
//! In statics (`v = 0`) only the spring acts: `K = k J^T n n^T J - d(J^T F)/dq`; the ground
//! holds a structure up but not sideways, so its free sliding and turning on the ground are
//! zero-stiffness (rigid-body) modes. `tests/contact.rs` checks `K` and `C` against finite
//! differences of `Q`.

use nalgebra::{Matrix3, Matrix6, Vector3};

use crate::assembly::{add_vector, TangentSink};
use crate::kinematics::{force_jacobian_derivative, velocity_derivative, PointKinematics};
use crate::model::{BodyKind, ContactSphere, GroundModel, Model, Pose};
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
    /// Slip velocity `u` of the sphere's centre along the ground, world frame, m/s.
    pub slip: Vector3<f64>,
    /// The contact point: the sphere's centre projected on the ground, world frame, m.
    pub position: Vector3<f64>,
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
    /// The whole force on the body, world frame, N: `F_n n + F_t`.
    pub fn force(&self, normal: &Vector3<f64>) -> Vector3<f64> {
        normal * self.normal_force + self.friction
    }
}

/// The response of `sphere` (centre kinematics `kin`) against `ground`; no allocation.
pub fn contact_response(
    ground: &GroundModel,
    sphere: &ContactSphere,
    kin: &PointKinematics,
) -> ContactResponse {
    let n = &ground.normal;
    let m = &ground.material;
    let height = n.dot(&kin.position);
    let delta = ground.offset + sphere.radius - height;
    let position = kin.position - n * (height - ground.offset);
    if delta.is_nan() || delta <= 0.0 {
        return ContactResponse { gap: -delta, position, ..Default::default() };
    }
    let delta_dot = -n.dot(&kin.velocity);
    let spring = m.stiffness * delta;
    let normal_force = (spring * (1.0 + m.dissipation * delta_dot)).max(0.0);
    let slip = kin.velocity + n * delta_dot;
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
        energy: 0.5 * spring * delta,
        loss_power,
    }
}

/// Evaluates one sphere against one ground and adds the generalized force `J^T F` into `force`
/// (length `model.dof_count`).
pub fn add_contact_force(
    model: &Model,
    ground: &GroundModel,
    sphere: &ContactSphere,
    kin: &PointKinematics,
    force: &mut DVector<f64>,
) -> ContactResponse {
    let response = contact_response(ground, sphere, kin);
    if response.normal_force > 0.0 {
        let f = response.force(&ground.normal);
        add_vector(model, kin.body, &(kin.jacobian.transpose() * f), 1.0, force);
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
    let j = &kin.jacobian;
    let body = kin.body;
    let mut k: Matrix6<f64> = -(j.transpose() * a_pos * j);
    if model.bodies[body.0].kind != BodyKind::Node {
        let d = velocity_derivative(model, poses, v, sphere.point);
        k -= j.transpose() * a_vel * d;
        k -= force_jacobian_derivative(model, poses, sphere.point, &response.force(&n));
    }
    sink.stiffness(body, body, &k, 1.0);
    sink.damping(body, body, &(j.transpose() * a_vel * j), -1.0);
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
    points: &[PointKinematics],
    stiffness: &mut nalgebra::DMatrix<f64>,
    damping: &mut nalgebra::DMatrix<f64>,
) {
    if model.contact_pairs() == 0 {
        return;
    }
    let weight = model.bodies.iter().map(|b| b.mass).sum::<f64>() * model.gravity.norm();
    let load = weight.max(1.0);
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
            let c6 = kin.jacobian.transpose() * c3 * kin.jacobian;
            crate::assembly::add_block(model, kin.body, kin.body, &c6, 1.0, damping);
        }
    }
}
