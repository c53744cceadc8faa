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

use nalgebra::{DVector, Matrix6, Rotation3, SMatrix, Vector3};

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

/// Kinematics of point `pid` at `poses`, with local velocities `v` (length `model.dof_count`).
///
/// Column by column, `J = [I, -R [p]x] B` is `b_t + R (b_r x p)` for the basis column
/// `(b_t, b_r)`: a pure translation column is copied, a rotation column costs one cross product
/// and one rotation (the same numbers as the product, without the 3 x 6 times 6 x 6 one).
pub fn point_kinematics(model: &Model, poses: &[Pose], v: &DVector<f64>, pid: PointId) -> PointKinematics {
    let mut out = PointKinematics {
        body: model.points[pid.0].body,
        position: Vector3::zeros(),
        velocity: Vector3::zeros(),
        jacobian: PointJacobian::zeros(),
    };
    point_kinematics_into(model, poses, v, pid, &mut out);
    out
}

/// `point_kinematics` written into `out` (the evaluation's own slot: no copy of the 3 x 6
/// Jacobian on the way).
pub fn point_kinematics_into(
    model: &Model,
    poses: &[Pose],
    v: &DVector<f64>,
    pid: PointId,
    out: &mut PointKinematics,
) {
    let point = &model.points[pid.0];
    let body = &model.bodies[point.body.0];
    let pose = &poses[point.body.0];
    let rot = pose.rotation.to_rotation_matrix();
    out.body = point.body;
    let mut velocity = Vector3::zeros();
    let jacobian = &mut out.jacobian;
    let rates = &v.as_slice()[body.dof_offset..body.dof_offset + body.dof_count];
    for_each_jacobian_column(model, &rot, pid, |c, col| {
        jacobian.set_column(c, &col);
        velocity += col * rates[c];
    });
    for c in body.dof_count..6 {
        jacobian.set_column(c, &Vector3::zeros());
    }
    out.velocity = velocity;
    out.position = pose.position + rot * point.local;
}

/// `dr/dq_b` of point `pid` at `poses` alone (`PointKinematics::jacobian`, without its position
/// and velocity), 3 x 6.
pub fn point_jacobian(model: &Model, poses: &[Pose], pid: PointId) -> PointJacobian {
    let rot = poses[model.points[pid.0].body.0].rotation.to_rotation_matrix();
    let mut jacobian = PointJacobian::zeros();
    for_each_jacobian_column(model, &rot, pid, |c, col| jacobian.set_column(c, &col));
    jacobian
}

/// Calls `f(c, column)` for each column `c` of the point Jacobian `[I, -R [p]x] B`
/// (`point_kinematics`), its body's rotation `rot` given.
#[inline(always)]
fn for_each_jacobian_column(
    model: &Model,
    rot: &Rotation3<f64>,
    pid: PointId,
    mut f: impl FnMut(usize, Vector3<f64>),
) {
    let point = &model.points[pid.0];
    let body = &model.bodies[point.body.0];
    for c in 0..body.dof_count {
        let b = body.basis.column(c);
        let mut col = Vector3::new(b[0], b[1], b[2]);
        let b_r = Vector3::new(b[3], b[4], b[5]);
        if b_r != Vector3::zeros() {
            col += rot * b_r.cross(&point.local);
        }
        f(c, col);
    }
}

/// `Jdot v` of point `pid`: the centripetal acceleration `R (w x (w x p))` of a point `p` on a
/// rotating body (body-frame angular velocity `w` from the local velocities `v`), m/s^2.
#[inline]
pub fn centripetal(model: &Model, poses: &[Pose], v: &DVector<f64>, pid: PointId) -> Vector3<f64> {
    let point = &model.points[pid.0];
    let body = &model.bodies[point.body.0];
    if body.dof_count == 0 {
        return Vector3::zeros();
    }
    let local = body.local_increment(v.as_slice(), 1.0);
    let w = Vector3::new(local[3], local[4], local[5]);
    poses[point.body.0].rotation * w.cross(&w.cross(&point.local))
}

/// World angular velocity `R w` of `body` (`w` its body-frame rate from the local velocities
/// `v`), rad/s; zero for a fixed body.
pub fn world_spin(model: &Model, poses: &[Pose], v: &DVector<f64>, body: BodyId) -> Vector3<f64> {
    let local = model.bodies[body.0].local_increment(v.as_slice(), 1.0);
    poses[body.0].rotation * Vector3::new(local[3], local[4], local[5])
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
    // only the rotation rows of the basis meet the rotation block: B_r^T ([p]x [f]x) B_r
    let d3 = skew(&point.local) * skew(&f_body);
    let b_r = body.basis.fixed_view::<3, 6>(3, 0);
    let d3_b = d3 * b_r;
    let mut out = Matrix6::zeros();
    for c in 0..body.dof_count {
        let col = b_r.column(c);
        if col[0] == 0.0 && col[1] == 0.0 && col[2] == 0.0 {
            continue;
        }
        for r in 0..body.dof_count {
            out[(c, r)] = col.dot(&d3_b.column(r));
        }
    }
    out
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
    let x = -(rot.matrix() * skew(&omega.cross(&point.local)));
    x * body.basis.fixed_view::<3, 6>(3, 0)
}
