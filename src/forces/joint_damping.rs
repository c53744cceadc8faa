//! Rotational damping at joints: takes a joint's two bodies' poses and velocities and its
//! coefficient `c` (N m s/rad), gives the damping torques, their generalized forces, their
//! tangent stiffness `K = -dQ/dq` and damping matrix `C = -dQ/dv`, and the power they dissipate.
//!
//! A body's world angular velocity is `omega = R w`, with `w` the rotation part of its local
//! increment `B v_b` (body frame) and `R` its rotation. The joint's relative spin is
//! `s = omega_a - omega_b` (`omega_b = 0` for a pin or a fixed body); the torques are
//! `tau_a = -c s` on body `a` and `tau_b = c s` on body `b`, whose generalized forces are
//! `Q_a = B_a^T [0; R_a^T tau_a]` (and `b` alike), dissipating `c |s|^2`. With the body-frame
//! retraction `R <- R exp([dtheta]x)`:
//! - `C = c G^T G`, `G_a = [0 | R_a] B_a`, `G_b = -[0 | R_b] B_b`;
//! - `dQ_a/dtheta_a = [R_a^T tau_a]x + c [w_a]x`, `dQ_a/dtheta_b = -c R_a^T R_b [w_b]x`, and with
//!   `a` and `b` swapped for body `b` (its torque `tau_b`), `K = -dQ/dq` of those.
//!
//! Bodies without rotation coordinates (nodes) have no spin: a joint may be damped only between
//! bodies that turn (bars, rigid bodies) or between one and the ground (scene validation).

use nalgebra::{DVector, Matrix3, Matrix6, Vector3, Vector6};

use crate::assembly::{add_vector, TangentSink};
use crate::model::{BodyId, JointModel, JointTarget, Model, Pose};

/// One side of a damped joint: its body (`None`: the ground, or a body without coordinates), its
/// rotation and its body-frame spin `w`.
struct Side {
    body: Option<BodyId>,
    rotation: Matrix3<f64>,
    spin: Vector3<f64>,
}

fn side(model: &Model, poses: &[Pose], v: &DVector<f64>, body: Option<BodyId>) -> Side {
    match body.filter(|b| model.bodies[b.0].dof_count > 0) {
        None => Side { body: None, rotation: Matrix3::identity(), spin: Vector3::zeros() },
        Some(b) => {
            let local = model.bodies[b.0].local_increment(v.as_slice(), 1.0);
            Side {
                body: Some(b),
                rotation: poses[b.0].rotation.to_rotation_matrix().into_inner(),
                spin: Vector3::new(local[3], local[4], local[5]),
            }
        }
    }
}

/// The joint's two sides.
fn sides(model: &Model, poses: &[Pose], v: &DVector<f64>, joint: &JointModel) -> [Side; 2] {
    let a = model.points[joint.point.0].body;
    let b = match joint.target {
        JointTarget::Point(p) => Some(model.points[p.0].body),
        JointTarget::World(_) => None,
    };
    [side(model, poses, v, Some(a)), side(model, poses, v, b)]
}

/// A 6 x 6 local block with `m` in its rotation corner.
fn rotation_block(m: &Matrix3<f64>) -> Matrix6<f64> {
    let mut out = Matrix6::zeros();
    out.fixed_view_mut::<3, 3>(3, 3).copy_from(m);
    out
}

/// Adds every damped joint's generalized forces into `force` (N, N m); returns the power they
/// dissipate, `sum c |s|^2` (W).
pub fn add_joint_damping_force(
    model: &Model,
    poses: &[Pose],
    v: &DVector<f64>,
    force: &mut DVector<f64>,
) -> f64 {
    let mut loss = 0.0;
    for joint in model.joints.iter().filter(|j| j.damping > 0.0) {
        let [a, b] = sides(model, poses, v, joint);
        let s = a.rotation * a.spin - b.rotation * b.spin;
        let tau_a = -joint.damping * s;
        loss += joint.damping * s.norm_squared();
        for (side, tau) in [(&a, tau_a), (&b, -tau_a)] {
            if let Some(body) = side.body {
                let t = side.rotation.transpose() * tau;
                let f6 = Vector6::new(0.0, 0.0, 0.0, t.x, t.y, t.z);
                add_vector(model, body, &(model.bodies[body.0].basis.transpose() * f6), 1.0, force);
            }
        }
    }
    loss
}

/// Adds every damped joint's tangent stiffness and damping matrix (module docs) into `sink`.
pub fn add_joint_damping_tangents<S: TangentSink + ?Sized>(
    model: &Model,
    poses: &[Pose],
    v: &DVector<f64>,
    sink: &mut S,
) {
    for joint in model.joints.iter().filter(|j| j.damping > 0.0) {
        let c = joint.damping;
        let sides = sides(model, poses, v, joint);
        let s = sides[0].rotation * sides[0].spin - sides[1].rotation * sides[1].spin;
        // body i's torque is sign_i * (-c s); sign_0 = 1, sign_1 = -1
        for (i, me) in sides.iter().enumerate() {
            let Some(body_i) = me.body else { continue };
            let sign_i = if i == 0 { 1.0 } else { -1.0 };
            let basis_i = &model.bodies[body_i.0].basis;
            let tau = -c * s * sign_i;
            for (j, other) in sides.iter().enumerate() {
                let Some(body_j) = other.body else { continue };
                let sign_j = if j == 0 { 1.0 } else { -1.0 };
                let basis_j = &model.bodies[body_j.0].basis;
                // C_ij = c sign_i sign_j R_i^T R_j
                let rr = me.rotation.transpose() * other.rotation;
                let damping = basis_i.transpose() * rotation_block(&(rr * (c * sign_i * sign_j))) * basis_j;
                sink.damping(body_i, body_j, &damping, 1.0);
                // dQ_i/dtheta_j: the torque's own turn (i = j) and the spin's
                let mut dq = rr * (-c * sign_i * sign_j) * -other.spin.cross_matrix();
                if i == j {
                    dq = (me.rotation.transpose() * tau).cross_matrix() + c * me.spin.cross_matrix();
                }
                let stiffness = basis_i.transpose() * rotation_block(&dq) * basis_j;
                sink.stiffness(body_i, body_j, &stiffness, -1.0);
            }
        }
    }
}
