//! Joint constraints (ball joints between bodies, pins to the ground): takes point kinematics,
//! gives `Phi(q)` (m), its Jacobian `Phi_q`, and the multiplier-weighted second derivative
//! `d(Phi_q^T lambda)/dq` that the statics and implicit dynamics tangents need.
//!
//! A ball joint holds point `a` on point `b` (or on a world position): `Phi = r_a - r_b`, 3 rows,
//! or the x and y rows only in planar scenes (where z is not a coordinate).

use nalgebra::{DMatrix, DVector, Vector3};

use crate::forces::cable::add_block;
use crate::kinematics::{force_jacobian_derivative, PointKinematics};
use crate::model::{JointTarget, Model, Pose};

/// Fills `phi` (rows) and `phi_q` (rows x coordinates) for all joints.
pub fn evaluate(model: &Model, kin: &[PointKinematics], phi: &mut DVector<f64>, phi_q: &mut DMatrix<f64>) {
    if model.joints.is_empty() {
        return;
    }
    phi_q.fill(0.0);
    let rows = model.joint_rows();
    for joint in &model.joints {
        let pa = &kin[joint.point.0];
        let (rb, pb) = match joint.target {
            JointTarget::Point(p) => (kin[p.0].position, Some(&kin[p.0])),
            JointTarget::World(x) => (x, None),
        };
        for r in 0..rows {
            let row = joint.row_offset + r;
            phi[row] = pa.position[r] - rb[r];
            let ba = &model.bodies[pa.body.0];
            for c in 0..ba.dof_count {
                phi_q[(row, ba.dof_offset + c)] += pa.jacobian[(r, c)];
            }
            if let Some(pb) = pb {
                let bb = &model.bodies[pb.body.0];
                for c in 0..bb.dof_count {
                    phi_q[(row, bb.dof_offset + c)] -= pb.jacobian[(r, c)];
                }
            }
        }
    }
}

/// Adds `d(Phi_q^T lambda)/dq` (multipliers `lambda`, N) into `out`.
pub fn add_multiplier_hessian(model: &Model, poses: &[Pose], lambda: &DVector<f64>, out: &mut DMatrix<f64>) {
    let rows = model.joint_rows();
    for joint in &model.joints {
        let mut f = Vector3::zeros();
        for r in 0..rows {
            f[r] = lambda[joint.row_offset + r];
        }
        let a = model.points[joint.point.0].body;
        add_block(model, a, a, &force_jacobian_derivative(model, poses, joint.point, &f), 1.0, out);
        if let JointTarget::Point(p) = joint.target {
            let b = model.points[p.0].body;
            add_block(model, b, b, &force_jacobian_derivative(model, poses, p, &f), -1.0, out);
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
