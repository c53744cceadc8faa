//! The joints' Schur complement for the explicit integrators' velocity solve on the dense backend
//! (`JointSchur`).

use nalgebra::{DVector, Matrix6};

use crate::constraints::{joint_points, side_jacobian};
use crate::evaluate::Workspace;
use crate::kinematics::PointJacobian;
use crate::model::Model;

/// The explicit integrator's velocity step by the joints' Schur complement (dense backend): with
/// the block-diagonal mass matrix inverted once per model,
/// `[M, Phi_q^T; Phi_q, 0] [v; mu] = [p; c]` becomes `S mu = Phi_q M^-1 p - c` with
/// `S = Phi_q M^-1 Phi_q^T` (nc x nc, symmetric positive definite for independent joints, which
/// scenes guarantee), then `v = M^-1 (p - Phi_q^T mu)`: an `nc x nc` Cholesky per step instead of
/// an `(n + nc)` LU, assembled from 3 x 3 blocks of the joint sides that share a body.
pub(super) struct JointSchur {
    /// Per body: the inverse of its local mass matrix (top-left `k x k`).
    mass_inverse: Vec<Matrix6<f64>>,
    /// Per body: the joint sides on it, `(joint, point, sign)`.
    sides: Vec<Vec<(usize, crate::model::PointId, f64)>>,
    /// `S`, column-major, and its Cholesky factor in place.
    s: Vec<f64>,
    /// Per joint side in `sides` order: `M_b^-1 J^T` (k x 3 in a 6 x 3).
    weighted: Vec<nalgebra::Matrix6x3<f64>>,
    /// Per joint side in `sides` order: its rows `J` of `Phi_q` at the last `factor`'s kinematics
    /// (`constraints::side_jacobian`), which `solve_factored` reuses.
    rows: Vec<PointJacobian>,
    u: DVector<f64>,
    b: DVector<f64>,
    mem: faer::dyn_stack::MemBuffer,
}

impl std::fmt::Debug for JointSchur {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("JointSchur").field("rows", &self.b.len()).finish()
    }
}

impl Clone for JointSchur {
    fn clone(&self) -> Self {
        Self {
            mass_inverse: self.mass_inverse.clone(),
            sides: self.sides.clone(),
            s: self.s.clone(),
            weighted: self.weighted.clone(),
            rows: self.rows.clone(),
            u: self.u.clone(),
            b: self.b.clone(),
            mem: Self::scratch(self.b.len()),
        }
    }
}

impl JointSchur {
    fn scratch(nc: usize) -> faer::dyn_stack::MemBuffer {
        use faer::linalg::cholesky::llt;
        faer::dyn_stack::MemBuffer::new(faer::dyn_stack::StackReq::or(
            llt::factor::cholesky_in_place_scratch::<f64>(nc, faer::Par::Seq, Default::default()),
            llt::solve::solve_in_place_scratch::<f64>(nc, 1, faer::Par::Seq),
        ))
    }

    pub(super) fn new(model: &Model) -> Self {
        let nc = model.constraint_count;
        let mass_inverse = model
            .bodies
            .iter()
            .map(|b| {
                let k = b.dof_count;
                let m = b.mass_matrix();
                let block = m.view((0, 0), (k, k)).into_owned().try_inverse();
                let mut inv = Matrix6::zeros();
                if let Some(block) = block {
                    inv.view_mut((0, 0), (k, k)).copy_from(&block);
                }
                inv
            })
            .collect();
        let mut sides = vec![Vec::new(); model.bodies.len()];
        for (j, joint) in model.joints.iter().enumerate() {
            for (p, sign) in joint_points(joint) {
                let body = model.points[p.0].body;
                if model.bodies[body.0].dof_count > 0 {
                    sides[body.0].push((j, p, sign));
                }
            }
        }
        let count = sides.iter().map(|s: &Vec<_>| s.len()).sum();
        Self {
            mass_inverse,
            sides,
            s: vec![0.0; nc * nc],
            weighted: vec![nalgebra::Matrix6x3::zeros(); count],
            rows: vec![PointJacobian::zeros(); count],
            u: DVector::zeros(model.dof_count),
            b: DVector::zeros(nc),
            mem: Self::scratch(nc),
        }
    }

    /// Solves `[M, Phi_q^T; Phi_q, 0] x = rhs` in place at the point kinematics in `ws`. False
    /// when `S` is not positive definite or the result is not finite.
    pub(super) fn solve(&mut self, model: &Model, ws: &Workspace, rhs: &mut DVector<f64>) -> bool {
        self.factor(model, ws) && self.solve_factored(model, rhs)
    }

    /// Forms `S = Phi_q M^-1 Phi_q^T` at the point kinematics in `ws` (from the 3 x 3 blocks of
    /// the joint sides that share a body) and its Cholesky factor, for `solve_factored`. False
    /// when `S` is not positive definite.
    pub(super) fn factor(&mut self, model: &Model, ws: &Workspace) -> bool {
        use faer::linalg::cholesky::llt;
        let nc = model.constraint_count;
        if nc == 0 {
            return true;
        }
        self.s.fill(0.0);
        let mut w = 0;
        for (b, body) in model.bodies.iter().enumerate() {
            let k = body.dof_count;
            let first = w;
            for &(j, p, sign) in &self.sides[b] {
                let joint = &model.joints[j];
                let point = &ws.points[p.0];
                self.rows[w] = match (&joint.alignment, &joint.directions) {
                    _ if joint.plane_normal.is_some() => side_jacobian(model, &ws.poses, joint, point),
                    (None, None) => point.jacobian,
                    (None, Some(d)) => d * point.jacobian,
                    (Some(_), _) => side_jacobian(model, &ws.poses, joint, point),
                };
                let jac = &self.rows[w];
                let mut m = nalgebra::Matrix6x3::zeros();
                for r in 0..k {
                    for c in 0..joint.rows {
                        m[(r, c)] =
                            sign * (0..k).map(|i| self.mass_inverse[b][(r, i)] * jac[(c, i)]).sum::<f64>();
                    }
                }
                self.weighted[w] = m;
                w += 1;
            }
            for (x, &(ja, _, sa)) in self.sides[b].iter().enumerate() {
                let jac = &self.rows[first + x];
                let (ra, rows_a) = (model.joints[ja].row_offset, model.joints[ja].rows);
                for (y, &(jb, _, _)) in self.sides[b].iter().enumerate() {
                    let (rb, rows_b) = (model.joints[jb].row_offset, model.joints[jb].rows);
                    let wb = &self.weighted[first + y];
                    for r in 0..rows_a {
                        for c in 0..rows_b {
                            let v: f64 = (0..k).map(|i| jac[(r, i)] * wb[(i, c)]).sum();
                            self.s[(rb + c) * nc + ra + r] += sa * v;
                        }
                    }
                }
            }
        }
        let s = faer::MatMut::from_column_major_slice_mut(&mut self.s, nc, nc);
        llt::factor::cholesky_in_place(
            s,
            Default::default(),
            faer::Par::Seq,
            faer::dyn_stack::MemStack::new(&mut self.mem),
            Default::default(),
        )
        .is_ok()
    }

    /// Solves `[M, Phi_q^T; Phi_q, 0] x = rhs` in place with the factor of the last `factor`
    /// (and its joint rows): `S mu = Phi_q M^-1 p - c`, then
    /// `v = M^-1 (p - Phi_q^T mu)`. False when the result is not finite.
    pub(super) fn solve_factored(&mut self, model: &Model, rhs: &mut DVector<f64>) -> bool {
        use faer::linalg::cholesky::llt;
        let n = model.dof_count;
        let nc = model.constraint_count;
        // u = M^-1 p
        for (b, body) in model.bodies.iter().enumerate() {
            let (o, k) = (body.dof_offset, body.dof_count);
            for r in 0..k {
                self.u[o + r] = (0..k).map(|c| self.mass_inverse[b][(r, c)] * rhs[o + c]).sum();
            }
        }
        if nc > 0 {
            // b = Phi_q u - c
            self.b.copy_from(&rhs.rows(n, nc));
            self.b.neg_mut();
            let mut w = 0;
            for (b, body) in model.bodies.iter().enumerate() {
                let (o, k) = (body.dof_offset, body.dof_count);
                for &(j, _, sign) in &self.sides[b] {
                    let jac = &self.rows[w];
                    w += 1;
                    let row0 = model.joints[j].row_offset;
                    for r in 0..model.joints[j].rows {
                        self.b[row0 + r] += sign * (0..k).map(|c| jac[(r, c)] * self.u[o + c]).sum::<f64>();
                    }
                }
            }
            let s = faer::MatRef::from_column_major_slice(&self.s, nc, nc);
            let mu = faer::MatMut::from_column_major_slice_mut(self.b.as_mut_slice(), nc, 1);
            llt::solve::solve_in_place_with_conj(
                s,
                faer::Conj::No,
                mu,
                faer::Par::Seq,
                faer::dyn_stack::MemStack::new(&mut self.mem),
            );
            // v = u - M^-1 Phi_q^T mu (the weighted sides carry their signs)
            let mut w = 0;
            for (b, body) in model.bodies.iter().enumerate() {
                let o = body.dof_offset;
                for &(j, _, _) in &self.sides[b] {
                    let (row0, rows) = (model.joints[j].row_offset, model.joints[j].rows);
                    for r in 0..body.dof_count {
                        self.u[o + r] -=
                            (0..rows).map(|c| self.weighted[w][(r, c)] * self.b[row0 + c]).sum::<f64>();
                    }
                    w += 1;
                }
            }
            rhs.rows_mut(n, nc).copy_from(&self.b);
        }
        rhs.rows_mut(0, n).copy_from(&self.u);
        rhs.iter().all(|x| x.is_finite())
    }
}
