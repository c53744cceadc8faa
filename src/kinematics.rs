//! Point kinematics: from body poses and local velocities to each attachment point's world position
//! `r`, velocity `rdot`, Jacobian `J = dr/dq`, and the two derivatives the tangent matrices need:
//! the contraction `d(J^T f)/dq` at fixed world force `f` and `d(rdot)/dq` at fixed velocities.
//!
//! For a point with body coordinates `p` on a body with pose `(x, R)` and basis `B`
//! (see `crate::model`), with `[a]x` the cross-product matrix:
//! - `r = x + R p`, `J = [I, -R [p]x] B` (3 x k),
//! - `rdot = J v`,
//! - `d(J^T f)/dq = B^T [[0, 0], [0, [p]x [R^T f]x]] B` (k x k, not symmetric in general; its
//!   symmetric part is the Hessian of `f . r` in exponential coordinates),
//! - `d(rdot)/dq = [0, -R [w x p]x] B` with `w` the body-frame angular velocity `(B v)_rot`.
//!
//! All derivatives are with respect to the local increments of `crate::state::retract`, so a
//! finite difference of the same quantities along `retract` reproduces them exactly.

use nalgebra::{DVector, Matrix3, Matrix6, SMatrix, Vector3};

use crate::model::{skew, BodyId, Model, PointId, Pose};

/// A 3 x 6 Jacobian block; only the first `dof_count` columns of the point's body are meaningful.
pub type PointJacobian = SMatrix<f64, 3, 6>;

/// Position, velocity and Jacobian of one attachment point.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PointKinematics {
    /// Body the point is on.
    pub body: BodyId,
    /// World position, m.
    pub position: Vector3<f64>,
    /// World velocity, m/s.
    pub velocity: Vector3<f64>,
    /// `dr/dq_b` for the point's body coordinates (3 x 6, unused columns zero).
    pub jacobian: PointJacobian,
}

/// The body-frame translation/rotation basis `[I, -R[p]x]` of a point (3 x 6, before `B`).
fn raw_jacobian(pose: &Pose, p: &Vector3<f64>) -> PointJacobian {
    let mut j = PointJacobian::zeros();
    j.fixed_view_mut::<3, 3>(0, 0).copy_from(&Matrix3::identity());
    let rot = pose.rotation.to_rotation_matrix();
    j.fixed_view_mut::<3, 3>(0, 3).copy_from(&(-(rot.matrix() * skew(p))));
    j
}

/// Kinematics of point `pid` at `poses`, with local velocities `v` (length `model.dof_count`).
pub fn point_kinematics(model: &Model, poses: &[Pose], v: &DVector<f64>, pid: PointId) -> PointKinematics {
    let point = &model.points[pid.0];
    let body = &model.bodies[point.body.0];
    let pose = &poses[point.body.0];
    let jacobian = raw_jacobian(pose, &point.local) * body.basis;
    let mut velocity = Vector3::zeros();
    for c in 0..body.dof_count {
        velocity += jacobian.column(c) * v[body.dof_offset + c];
    }
    PointKinematics { body: point.body, position: pose.transform_point(&point.local), velocity, jacobian }
}

/// `d(J^T f)/dq_b` for point `pid` at a fixed world force `f` (N): the point's share of the
/// geometric stiffness (k x k block of the returned 6 x 6, N m).
pub fn force_jacobian_derivative(
    model: &Model,
    poses: &[Pose],
    pid: PointId,
    f_world: &Vector3<f64>,
) -> Matrix6<f64> {
    let point = &model.points[pid.0];
    let body = &model.bodies[point.body.0];
    let f_body = poses[point.body.0].rotation.inverse() * f_world;
    let mut d = Matrix6::zeros();
    d.fixed_view_mut::<3, 3>(3, 3).copy_from(&(skew(&point.local) * skew(&f_body)));
    body.basis.transpose() * d * body.basis
}

/// `d(rdot)/dq_b` of point `pid` at fixed local velocities `v` (3 x 6, 1/s).
pub fn velocity_derivative(model: &Model, poses: &[Pose], v: &DVector<f64>, pid: PointId) -> PointJacobian {
    let point = &model.points[pid.0];
    let body = &model.bodies[point.body.0];
    if body.dof_count == 0 {
        return PointJacobian::zeros();
    }
    let local = body.local_increment(v.as_slice(), 1.0);
    let omega = Vector3::new(local[3], local[4], local[5]);
    let rot = poses[point.body.0].rotation.to_rotation_matrix();
    let mut d = PointJacobian::zeros();
    d.fixed_view_mut::<3, 3>(0, 3).copy_from(&(-(rot.matrix() * skew(&omega.cross(&point.local)))));
    d * body.basis
}
