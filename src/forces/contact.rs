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
//! **Stick-slip friction** (a ground with `StickFriction`, in place of the regularized law): each
//! contact carries an anchor (`State::contact_anchors`), the material point of the sphere that
//! touched (its lever `l = R b`, `b` body-fixed) and the ground point it stuck to, `x_a`. With the
//! material point `x_m = r + l`, its velocity `u_m = rdot + omega x l` (Jacobian `J_m`, the lever
//! columns as `J_c`'s with `l` for `a`), the spring's extension `d = P (x_m - x_a)` and slip
//! `u = P u_m`:
//! - `F_trial = -(k_t d + c_t u)`; stuck while `|F_trial| <= mu F_n`: `F_t = F_trial`; else
//!   slipping: `F_t = mu F_n t`, `t = F_trial / |F_trial|`;
//! - `Q = J^T F_n n + J_m^T F_t`: the normal force through the centre (along `n` a lever turns
//!   nothing, and a lever that turned with the body would make the normal spring do work it
//!   does not store), the friction at the held material point;
//! - the extension kept (`ContactResponse::stick_extension`): `d`, shortened while slipping to
//!   `d mu F_n / (k_t |d|)` where the spring alone pulls beyond the cone (never lengthened, so a
//!   fast slip's damper leaves no energy in the spring); after an accepted step the anchor
//!   moves to keep exactly that extension from the new lowest point (`commit_anchors`), so a
//!   sphere rolls freely and a stuck one never creeps;
//! - stored energy `k_t |d|^2 / 2`, dissipated power `-(F_t + k_t d) . u` (the damper's
//!   `c_t |u|^2` while stuck); the spring energy the shortening to `d_kept` removes,
//!   `k_t (|d|^2 - |d_kept|^2) / 2`, is booked as lost where the anchors are committed, so the
//!   energy account closes.
//!
//! With `G = dF_t/dF_trial` (`I` stuck, `mu F_n (I - t t^T) / |F_trial|` slipping),
//! `w = dF/dF_n` (`n` stuck, `n + mu t` slipping), `D` and `D_m = D - R [omega_b x b]x B_r` the
//! velocity derivatives of the centre and the material point:
//! `dF_n/dq = a_r n^T J + a_v n^T D`, `dF_n/dv = a_v n^T J`,
//! `dF_t/dq = (w - n) dF_n/dq - G (k_t P J_m + c_t P D_m)`, `dF_t/dv = (w - n) dF_n/dv - c_t G P J_m`,
//! `K = -J^T n dF_n/dq - J_m^T dF_t/dq - d(J^T F)/dq - L`, `C = -J^T n dF_n/dv - J_m^T dF_t/dv`,
//! with the lever's geometric term `L` row by row `(x_c x R^T F_t)^T B_r`, `x_c = b_r,c x b`.
//! The anchors make the law depend on the path, as the pulleys' return map does; within a step
//! it is a smooth function of the state but for the kink at the cone, and its stiffness does
//! not change by orders of magnitude between stick and slip, which is what Newton needs.
//!
//! In statics with the regularized law (`v = 0`) only the spring acts: `K = k J^T n n^T J` plus the geometric terms; the
//! ground holds a structure up but not sideways, so its free sliding and turning on the ground
//! are zero-stiffness (rigid-body) modes. `tests/contact.rs` checks `K` and `C` against finite
//! differences of `Q`.

use nalgebra::{Matrix3, Matrix6, Vector3};

use crate::assembly::{add_vector, TangentSink};
use crate::kinematics::{force_jacobian_derivative, velocity_derivative, PointJacobian, PointKinematics};
use crate::model::{BodyKind, ContactSphere, GroundModel, Model, Pose, StickFriction};
use nalgebra::DVector;

/// Where one contact of a ground with stick-slip friction is anchored
/// (`crate::forces::contact`): the material point of the sphere that touched, and the ground
/// point it stuck to. Its tangential spring's extension is `d = P (r + R lever - anchor)` for the
/// sphere's centre `r` and the body's rotation `R`, `P` projecting onto the ground.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct ContactAnchor {
    /// From the sphere's centre to its material point that touched, body frame, m (`R^T a` for
    /// the lowest point `a = -rho n` when the anchor was set).
    pub lever: Vector3<f64>,
    /// The ground point the material point is held to, world frame, m.
    pub anchor: Vector3<f64>,
}

/// What a contact's friction is doing (`ContactResponse::friction_state`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum FrictionState {
    /// The sphere does not press in: no force at all.
    #[default]
    Open,
    /// Pressed in, with a friction coefficient of zero.
    Frictionless,
    /// Pressed in, under the regularized law (`F_t = -mu F_n u / s`): no stuck state, and no
    /// friction at rest (statics).
    Regularized,
    /// Stick-slip law, inside the cone: `|F_t| <= mu F_n`, the anchor holds.
    Stuck,
    /// Stick-slip law, the trial force beyond the cone: `F_t` on it, the contact slides.
    Slipping,
}

impl FrictionState {
    /// `open`, `frictionless`, `regularized`, `stick` or `slip` (the pulleys' words for the last
    /// two, `crate::report::PulleyReport::state`).
    pub fn as_str(self) -> &'static str {
        match self {
            FrictionState::Open => "open",
            FrictionState::Frictionless => "frictionless",
            FrictionState::Regularized => "regularized",
            FrictionState::Stuck => "stick",
            FrictionState::Slipping => "slip",
        }
    }
}

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
    /// Stick-slip friction only (zero otherwise): the tangential spring's extension `d` that
    /// the anchor keeps after this instant (module docs), world frame, m.
    pub stick_extension: Vector3<f64>,
    /// Whether the friction sticks, slips, or has no such state.
    pub friction_state: FrictionState,
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
    lever_point(model, poses, v, ground.normal * -sphere.radius, sphere, kin)
}

/// The sphere's point at `offset` (world frame, m) from its centre, moving with the body: its
/// velocity `rdot + omega x offset` and Jacobian (the lever columns `(R b_r) x offset`).
fn lever_point(
    model: &Model,
    poses: &[Pose],
    v: &DVector<f64>,
    offset: Vector3<f64>,
    sphere: &ContactSphere,
    kin: &PointKinematics,
) -> ContactPoint {
    let body = &model.bodies[kin.body.0];
    let mut jacobian = kin.jacobian;
    let mut velocity = kin.velocity;
    if sphere.radius > 0.0 && body.kind != BodyKind::Node {
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

/// The normal part of a sphere's contact with a ground (module docs): penetration `delta`, m,
/// its rate, m/s, the spring's force `k delta` and the normal force, N, and the contact point.
struct NormalContact {
    delta: f64,
    delta_dot: f64,
    spring: f64,
    normal_force: f64,
    position: Vector3<f64>,
}

impl NormalContact {
    /// The response of the contact when the sphere does not press in (`delta <= 0` or NaN).
    fn open(&self, ground: &GroundModel) -> Option<ContactResponse> {
        if self.delta.is_nan() || self.delta <= 0.0 {
            Some(ContactResponse {
                gap: -self.delta,
                position: self.position,
                normal: ground.normal,
                ..Default::default()
            })
        } else {
            None
        }
    }
}

/// The sphere (centre `kin`) against `ground`: the rates and forces are zero where it does not
/// press in (`NormalContact::open`).
fn normal_contact(ground: &GroundModel, sphere: &ContactSphere, kin: &PointKinematics) -> NormalContact {
    let n = &ground.normal;
    let m = &ground.material;
    let height = n.dot(&kin.position);
    let delta = ground.offset + sphere.radius - height;
    let position = kin.position - n * (height - ground.offset);
    if delta.is_nan() || delta <= 0.0 {
        return NormalContact { delta, delta_dot: 0.0, spring: 0.0, normal_force: 0.0, position };
    }
    let delta_dot = -n.dot(&kin.velocity);
    let spring = m.stiffness * delta;
    let normal_force = (spring * (1.0 + m.dissipation * delta_dot)).max(0.0);
    NormalContact { delta, delta_dot, spring, normal_force, position }
}

/// The response of `sphere` (centre kinematics `kin`, contact point `point`) against `ground`
/// with regularized friction; no allocation.
pub fn contact_response(
    ground: &GroundModel,
    sphere: &ContactSphere,
    kin: &PointKinematics,
    point: &ContactPoint,
) -> ContactResponse {
    let contact = normal_contact(ground, sphere, kin);
    contact.open(ground).unwrap_or_else(|| respond_pressed(ground, kin, contact, point, None))
}

/// What holds a stick-slip contact: the ground's law, the pair's anchor and the damping `c_t`
/// (`stick_damping`), N s/m.
struct StickHold<'a> {
    law: &'a StickFriction,
    anchor: &'a ContactAnchor,
    damping: f64,
}

/// The response of a sphere (centre `kin`) that presses into `ground` (`contact`, not
/// `NormalContact::open`), its friction regularized at the contact point `point` (`stick` none),
/// or stick-slip at the anchored material point `point` (`anchored_point`) held by `stick`
/// (module docs).
fn respond_pressed(
    ground: &GroundModel,
    kin: &PointKinematics,
    contact: NormalContact,
    point: &ContactPoint,
    stick: Option<StickHold<'_>>,
) -> ContactResponse {
    let n = &ground.normal;
    let m = &ground.material;
    let NormalContact { delta, delta_dot, spring, normal_force, position } = contact;
    let slip = point.velocity - n * n.dot(&point.velocity);
    // the friction force, the energy its spring stores, the power it dissipates and the
    // extension the anchor keeps
    let (friction, friction_energy, friction_loss, kept, friction_state) = match stick {
        None => {
            let s = (slip.norm_squared() + m.stiction_speed * m.stiction_speed).sqrt();
            let friction = slip * (-m.friction * normal_force / s);
            let state =
                if m.friction > 0.0 { FrictionState::Regularized } else { FrictionState::Frictionless };
            (friction, 0.0, m.friction * normal_force * slip.norm_squared() / s, Vector3::zeros(), state)
        }
        Some(StickHold { law, anchor, damping }) => {
            let d = extension(ground, kin, &point.offset, anchor);
            let limit = m.friction * normal_force;
            let (_, friction, slipping) = stick_slip(law, &d, &slip, damping, limit);
            if limit <= 0.0 {
                let state =
                    if m.friction > 0.0 { FrictionState::Slipping } else { FrictionState::Frictionless };
                (friction, 0.0, 0.0, Vector3::zeros(), state)
            } else {
                // the power the friction takes from the bodies beyond what its spring stores,
                // -(F_t + k_t d) . u: the damper's, c_t |u|^2, while stuck
                let loss = -(friction + d * law.stiffness).dot(&slip);
                let pull = law.stiffness * d.norm();
                // slipping, the spring alone shortened to the cone, never stretched: a fast
                // slip's damper must not leave energy in it
                let kept = if slipping && pull > limit { d * (limit / pull) } else { d };
                let state = if slipping { FrictionState::Slipping } else { FrictionState::Stuck };
                (friction, 0.5 * law.stiffness * d.norm_squared(), loss, kept, state)
            }
        }
    };
    ContactResponse {
        gap: -delta,
        penetration_rate: delta_dot,
        normal_force,
        friction,
        slip,
        position,
        normal: *n,
        energy: 0.5 * spring * delta + friction_energy,
        loss_power: (normal_force - spring) * delta_dot + friction_loss,
        stick_extension: kept,
        friction_state,
    }
}

/// Evaluates one sphere against one ground and adds the generalized force `J_c^T F` into `force`
/// (length `model.dof_count`); `poses` and `v` are the state's, `anchor` the pair's
/// (`State::contact_anchors`; read only when the ground has stick-slip friction).
#[allow(clippy::too_many_arguments)]
pub fn add_contact_force(
    model: &Model,
    poses: &[Pose],
    v: &DVector<f64>,
    ground: &GroundModel,
    sphere: &ContactSphere,
    kin: &PointKinematics,
    anchor: Option<&ContactAnchor>,
    force: &mut DVector<f64>,
) -> ContactResponse {
    // the contact point and its Jacobian only where the sphere presses in
    let contact = normal_contact(ground, sphere, kin);
    if let Some(open) = contact.open(ground) {
        return open;
    }
    if let (Some(stick), Some(anchor)) = (&ground.material.stick, anchor) {
        let point = anchored_point(model, poses, v, sphere, kin, anchor);
        let hold = StickHold { law: stick, anchor, damping: stick_damping(model, stick, kin) };
        let response = respond_pressed(ground, kin, contact, &point, Some(hold));
        if response.normal_force > 0.0 {
            // the normal force at the centre (its lever along n turns nothing), the friction at
            // the held material point
            let q = kin.jacobian.transpose() * (ground.normal * response.normal_force)
                + point.jacobian.transpose() * response.friction;
            add_vector(model, kin.body, &q, 1.0, force);
        }
        return response;
    }
    let point = contact_point(model, poses, v, ground, sphere, kin);
    let response = respond_pressed(ground, kin, contact, &point, None);
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
    anchor: Option<&ContactAnchor>,
    response: &ContactResponse,
    sink: &mut S,
) {
    let f_n = response.normal_force;
    if f_n <= 0.0 {
        return;
    }
    if let (Some(stick), Some(anchor)) = (&ground.material.stick, anchor) {
        add_stick_tangents(model, poses, v, ground, stick, sphere, kin, anchor, response, sink);
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
    if model_body.kind != BodyKind::Node {
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

/// The material point an anchor holds (`ContactAnchor::lever`, turned with the body): a node's
/// or a point sphere's is its centre.
fn anchored_point(
    model: &Model,
    poses: &[Pose],
    v: &DVector<f64>,
    sphere: &ContactSphere,
    kin: &PointKinematics,
    anchor: &ContactAnchor,
) -> ContactPoint {
    lever_point(model, poses, v, held_lever(model, poses, kin, anchor), sphere, kin)
}

/// The held material point's lever `R lever`, world frame, m (zero on a node).
fn held_lever(model: &Model, poses: &[Pose], kin: &PointKinematics, anchor: &ContactAnchor) -> Vector3<f64> {
    if model.bodies[kin.body.0].kind == BodyKind::Node {
        Vector3::zeros()
    } else {
        poses[kin.body.0].rotation * anchor.lever
    }
}

/// The spring's extension `d = P (r + l - x_a)` of a contact held by `anchor`, its centre at
/// `kin`, its held lever `lever` (`held_lever`), against `ground`, m.
fn extension(
    ground: &GroundModel,
    kin: &PointKinematics,
    lever: &Vector3<f64>,
    anchor: &ContactAnchor,
) -> Vector3<f64> {
    let offset = kin.position + lever - anchor.anchor;
    offset - ground.normal * ground.normal.dot(&offset)
}

/// `c_t`, N s/m: the ground's, or critical for the mass `m` of the body the sphere is on,
/// `2 sqrt(k_t m)`.
fn stick_damping(model: &Model, stick: &StickFriction, kin: &PointKinematics) -> f64 {
    stick.damping.unwrap_or_else(|| 2.0 * (stick.stiffness * model.bodies[kin.body.0].mass).sqrt())
}

/// The stick-slip friction's trial force and what it becomes (module docs): `(F_trial, F_t,
/// slipping)` for the extension `d`, slip `u`, damping `c_t` and cone `mu F_n`.
fn stick_slip(
    stick: &StickFriction,
    d: &Vector3<f64>,
    u: &Vector3<f64>,
    c_t: f64,
    limit: f64,
) -> (Vector3<f64>, Vector3<f64>, bool) {
    let trial = -(d * stick.stiffness + u * c_t);
    let size = trial.norm();
    if size <= limit {
        (trial, trial, false)
    } else {
        (trial, trial * (limit / size), true)
    }
}

/// `add_contact_tangents` for a ground with stick-slip friction (module docs).
#[allow(clippy::too_many_arguments)]
fn add_stick_tangents<S: TangentSink + ?Sized>(
    model: &Model,
    poses: &[Pose],
    v: &DVector<f64>,
    ground: &GroundModel,
    stick: &StickFriction,
    sphere: &ContactSphere,
    kin: &PointKinematics,
    anchor: &ContactAnchor,
    response: &ContactResponse,
    sink: &mut S,
) {
    let n = ground.normal;
    let m = &ground.material;
    let f_n = response.normal_force;
    let delta = -response.gap;
    let point = anchored_point(model, poses, v, sphere, kin, anchor);
    let p = Matrix3::identity() - n * n.transpose();
    let d = extension(ground, kin, &point.offset, anchor);
    let u = response.slip;
    let c_t = stick_damping(model, stick, kin);
    let limit = m.friction * f_n;
    let (trial, _, slipping) = stick_slip(stick, &d, &u, c_t, limit);
    // G = dF_t/dF_trial and w = dF/dF_n
    let (g, w) = if limit <= 0.0 {
        (Matrix3::zeros(), n)
    } else if slipping {
        let t = trial / trial.norm();
        ((Matrix3::identity() - t * t.transpose()) * (limit / trial.norm()), n + t * m.friction)
    } else {
        (Matrix3::identity(), n)
    };
    let a_r = -m.stiffness * (1.0 + m.dissipation * response.penetration_rate);
    let a_v = -m.stiffness * m.dissipation * delta;
    let (j, j_m) = (&kin.jacobian, &point.jacobian);
    let gp = g * p;
    let w_t = w - n; // dF_t/dF_n
    let jn = j.transpose() * n;
    // the normal force's part, through the centre: dF_n/dv = a_v n^T J, dF_n/dq = a_r n^T J + a_v n^T D
    let mut c6 = jn * (jn.transpose() * a_v);
    let mut k: Matrix6<f64> = -(jn * (jn.transpose() * a_r));
    // the friction's, through the material point: dF_t/dv = w_t a_v n^T J - c_t G P J_m
    let df_dv = w_t * (n.transpose() * j) * a_v - gp * j_m * c_t;
    c6 += j_m.transpose() * df_dv;
    // dF_t/dq at fixed velocities: the normal force's and the tangential spring's and damper's
    let mut df_dq = w_t * (n.transpose() * j) * a_r - gp * j_m * stick.stiffness;
    let body = kin.body;
    let model_body = &model.bodies[body.0];
    if model_body.kind != BodyKind::Node {
        let f = response.force();
        let d_centre = velocity_derivative(model, poses, v, sphere.point);
        let mut d_m = d_centre;
        let b_r = model_body.basis.fixed_view::<3, 6>(3, 0);
        let rot = poses[body.0].rotation.to_rotation_matrix();
        if sphere.radius > 0.0 {
            // the lever's part of d(u_m)/dq: -R [omega_b x b]x B_r
            let local = model_body.local_increment(v.as_slice(), 1.0);
            let omega = Vector3::new(local[3], local[4], local[5]);
            d_m -= rot.matrix() * omega.cross(&anchor.lever).cross_matrix() * b_r;
            // the lever's geometric term: row c is (x_c x R^T F_t)^T B_r, x_c = b_r,c x b
            let f_b = rot.inverse() * response.friction;
            for c in 0..model_body.dof_count {
                let x_c = b_r.column(c).cross(&anchor.lever);
                let g_c = x_c.cross(&f_b);
                let mut row = k.row_mut(c);
                row -= g_c.transpose() * b_r;
            }
        }
        k -= jn * (n.transpose() * d_centre) * a_v;
        df_dq += w_t * (n.transpose() * d_centre) * a_v - gp * d_m * c_t;
        k -= force_jacobian_derivative(model, poses, sphere.point, &f);
    }
    k -= j_m.transpose() * df_dq;
    sink.stiffness(body, body, &k, 1.0);
    sink.damping(body, body, &c6, -1.0);
}

/// Every ground pair's anchor at `poses` with the tangential springs unstretched: the sphere's
/// lowest point held where it is (the state at t = 0, and wherever a state is set from
/// outside). Empty when no ground has stick-slip friction.
pub fn initial_anchors(model: &Model, poses: &[Pose]) -> Vec<ContactAnchor> {
    if !model.has_stick_friction() {
        return Vec::new();
    }
    model
        .contact_pair_list()
        .map(|(_, sphere, ground)| {
            let point = &model.points[sphere.point.0];
            let pose = &poses[point.body.0];
            let centre = pose.position + pose.rotation * point.local;
            anchor_at(model, pose, sphere, ground, centre, Vector3::zeros())
        })
        .collect()
}

/// After an accepted step (statics: an accepted equilibrium), at its `poses`, sphere centres
/// `points` and `contacts` (the workspace's evaluation of exactly that state): every ground
/// pair's anchor moves to keep the extension the step ended with
/// (`ContactResponse::stick_extension`) from the sphere's lowest point now, whose material
/// point becomes the one held (module docs).
/// Returns what the commit changes in the energy account: the spring energy the slipping
/// contacts' shortening removed, J (>= 0: friction's loss, `k_t (|d|^2 - |d_kept|^2) / 2` summed,
/// module docs), and the change of the contacts' dissipated power, W, from the extensions `d` to
/// the kept ones (at the same slip velocities), so that the next step's power starts from the
/// committed anchors.
pub fn commit_anchors(
    model: &Model,
    poses: &[Pose],
    points: &[PointKinematics],
    contacts: &[ContactResponse],
    anchors: &mut [ContactAnchor],
) -> (f64, f64) {
    let (mut removed, mut power) = (0.0, 0.0);
    for ((k, sphere, ground), anchor) in model.contact_pair_list().zip(anchors.iter_mut()) {
        let kin = &points[sphere.point.0];
        let pose = &poses[kin.body.0];
        let c = &contacts[k];
        if let Some(stick) = &ground.material.stick {
            if c.normal_force > 0.0 && ground.material.friction > 0.0 {
                let d = extension(ground, kin, &held_lever(model, poses, kin, anchor), anchor);
                let kept = c.stick_extension;
                removed += 0.5 * stick.stiffness * (d.norm_squared() - kept.norm_squared());
                let c_t = stick_damping(model, stick, kin);
                let (_, friction, _) =
                    stick_slip(stick, &kept, &c.slip, c_t, ground.material.friction * c.normal_force);
                power += -(friction + kept * stick.stiffness).dot(&c.slip)
                    + (c.friction + d * stick.stiffness).dot(&c.slip);
            }
        }
        *anchor = anchor_at(model, pose, sphere, ground, kin.position, c.stick_extension);
    }
    (removed, power)
}

/// The anchor that holds the lowest point of `sphere` (centre `centre`, body at `pose`) against
/// `ground` with the extension `extension`.
fn anchor_at(
    model: &Model,
    pose: &Pose,
    sphere: &ContactSphere,
    ground: &GroundModel,
    centre: Vector3<f64>,
    extension: Vector3<f64>,
) -> ContactAnchor {
    let a = ground.normal * -sphere.radius;
    let body = &model.bodies[model.points[sphere.point.0].body.0];
    let lever = if body.kind == BodyKind::Node { Vector3::zeros() } else { pose.rotation.inverse() * a };
    ContactAnchor { lever, anchor: centre + a - extension }
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
            let j_c = contact_point(model, poses, &still, ground, sphere, kin).jacobian;
            let c3 = match &m.stick {
                None => nn * (m.dissipation * load) + p * (m.friction * load / m.stiction_speed),
                Some(stick) => {
                    let jt = j_c.transpose() * p * j_c;
                    crate::assembly::add_block(model, kin.body, kin.body, &jt, stick.stiffness, stiffness);
                    nn * (m.dissipation * load) + p * stick_damping(model, stick, kin)
                }
            };
            let c6 = j_c.transpose() * c3 * j_c;
            crate::assembly::add_block(model, kin.body, kin.body, &c6, 1.0, damping);
        }
    }
}
