//! Joint constraints (ball joints between bodies, pins to the ground): takes point kinematics,
//! gives `Phi(q)` (m), its Jacobian `Phi_q`, and the multiplier-weighted second derivative
//! `d(Phi_q^T lambda)/dq` that the statics and implicit dynamics tangents need.
//!
//! A ball joint holds point `a` on point `b` (or on a world position): `Phi = r_a - r_b`, 3 rows,
//! or the x and y rows only in planar scenes (where z is not a coordinate). A roller or slider
//! support holds only some world directions `D` (`JointModel::directions`): `Phi = D (r_a - x0)`,
//! `Phi_q = D J`, and its multipliers push along `D^T lambda`.

use nalgebra::{DMatrix, DVector, Vector3};

use crate::assembly::{add_vector, DenseTangents, TangentSink};
use crate::kinematics::{force_jacobian_derivative, PointJacobian, PointKinematics};
use crate::model::{JointModel, JointTarget, Model, PointId, Pose};

/// Fills `phi` (rows, m) for all joints.
pub fn evaluate_values(model: &Model, kin: &[PointKinematics], phi: &mut DVector<f64>) {
    for joint in &model.joints {
        let ra = kin[joint.point.0].position;
        let rb = match joint.target {
            JointTarget::Point(p) => kin[p.0].position,
            JointTarget::World(x) => x,
        };
        let gap = joint.project(&(ra - rb));
        for r in 0..joint.rows {
            phi[joint.row_offset + r] = gap[r];
        }
    }
}

/// Fills the dense `phi_q` (rows x coordinates) for all joints.
pub fn evaluate_jacobian(model: &Model, kin: &[PointKinematics], phi_q: &mut DMatrix<f64>) {
    if model.joints.is_empty() {
        return;
    }
    phi_q.fill(0.0);
    for joint in &model.joints {
        add_jacobian_entries(model, kin, joint, |r, c, x| phi_q[(joint.row_offset + r, c)] += x);
    }
}

/// Calls `add(row, coordinate, value)` for each term of `joint`'s rows of `Phi_q` at the point
/// kinematics `kin` (`row` counted from the joint's first, `0..joint.rows`; a coordinate
/// may come twice, once per point, and the terms add up), so that a caller can assemble them
/// into any layout (`evaluate_jacobian`'s dense matrix, a block of some joints and bodies).
pub fn add_jacobian_entries(
    model: &Model,
    kin: &[PointKinematics],
    joint: &JointModel,
    mut add: impl FnMut(usize, usize, f64),
) {
    for (pid, sign) in joint_points(joint) {
        let p = &kin[pid.0];
        let body = &model.bodies[p.body.0];
        let jacobian = joint_jacobian(joint, &p.jacobian);
        for r in 0..joint.rows {
            for c in 0..body.dof_count {
                add(r, body.dof_offset + c, sign * jacobian[(r, c)]);
            }
        }
    }
}

/// The joint's rows of a point Jacobian: `D J` (`J` itself for ball joints and pins).
pub fn joint_jacobian(joint: &JointModel, jacobian: &PointJacobian) -> PointJacobian {
    match &joint.directions {
        None => *jacobian,
        Some(d) => d * jacobian,
    }
}

/// The points a joint ties, with the sign of their position in `Phi`: `(a, +1)` and, for a
/// joint between two points, `(b, -1)`.
pub fn joint_points(joint: &JointModel) -> impl Iterator<Item = (PointId, f64)> {
    let b = match joint.target {
        JointTarget::Point(p) => Some((p, -1.0)),
        JointTarget::World(_) => None,
    };
    std::iter::once((joint.point, 1.0)).chain(b)
}

/// A joint's multipliers as a world force `D^T lambda` (N; z is 0 in planar scenes).
pub fn joint_reaction(joint: &JointModel, lambda: &DVector<f64>) -> Vector3<f64> {
    let mut f = Vector3::zeros();
    for r in 0..joint.rows {
        f[r] = lambda[joint.row_offset + r];
    }
    joint.force(&f)
}

/// `out += scale * Phi_q^T lambda` (N, N m): the joint reactions as generalized forces, without
/// forming `Phi_q`.
pub fn add_reaction_force(
    model: &Model,
    kin: &[PointKinematics],
    lambda: &DVector<f64>,
    scale: f64,
    out: &mut DVector<f64>,
) {
    for joint in &model.joints {
        let f = joint_reaction(joint, lambda);
        for (pid, sign) in joint_points(joint) {
            let p = &kin[pid.0];
            add_vector(model, p.body, &(p.jacobian.transpose() * f), sign * scale, out);
        }
    }
}

/// `Phi_q v` (m/s): each joint's relative velocity, from the point velocities in `kin`.
pub fn evaluate_rates(model: &Model, kin: &[PointKinematics], out: &mut DVector<f64>) {
    for joint in &model.joints {
        let mut rate = Vector3::zeros();
        for (pid, sign) in joint_points(joint) {
            rate += kin[pid.0].velocity * sign;
        }
        let rate = joint.project(&rate);
        for r in 0..joint.rows {
            out[joint.row_offset + r] = rate[r];
        }
    }
}

/// Adds `d(Phi_q^T lambda)/dq` (multipliers `lambda`, N) into `out`.
pub fn add_multiplier_hessian(model: &Model, poses: &[Pose], lambda: &DVector<f64>, out: &mut DMatrix<f64>) {
    let mut sink = DenseTangents { model, stiffness: out, damping: None };
    add_multiplier_hessian_to(model, poses, lambda, 1.0, &mut sink);
}

/// Adds `scale * d(Phi_q^T lambda)/dq` into the stiffness blocks of `sink`.
pub fn add_multiplier_hessian_to<S: TangentSink + ?Sized>(
    model: &Model,
    poses: &[Pose],
    lambda: &DVector<f64>,
    scale: f64,
    sink: &mut S,
) {
    for joint in &model.joints {
        let f = joint_reaction(joint, lambda);
        for (pid, sign) in joint_points(joint) {
            let body = model.points[pid.0].body;
            if model.bodies[body.0].dof_count == 0 {
                continue;
            }
            sink.stiffness(body, body, &force_jacobian_derivative(model, poses, pid, &f), sign * scale);
        }
    }
}

/// Orthonormal basis (columns) of the null space of `phi_q` (rows x n): the directions the joints
/// allow. The identity without joints; `None` when the joints leave no freedom.
pub fn null_space(phi_q: &DMatrix<f64>, n: usize) -> Option<DMatrix<f64>> {
    if phi_q.nrows() == 0 {
        return Some(DMatrix::identity(n, n));
    }
    let jtj = phi_q.transpose() * phi_q;
    let eig = nalgebra::SymmetricEigen::new(jtj);
    let tol = 1e-10 * eig.eigenvalues.amax().max(1e-300);
    let cols: Vec<DVector<f64>> = (0..n)
        .filter(|&i| eig.eigenvalues[i] <= tol)
        .map(|i| eig.eigenvectors.column(i).into_owned())
        .collect();
    if cols.is_empty() {
        None
    } else {
        Some(DMatrix::from_columns(&cols))
    }
}
