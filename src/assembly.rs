//! Assembly into generalized coordinates: takes body-local 6-vectors and 6 x 6 blocks (from the
//! cable element and the joints), gives their sums in the model's coordinate rows and columns:
//! `add_vector`, `add_block`, and the `TangentSink` that the same element code fills a dense `K`
//! and `C` with (`DenseTangents`) or a Newton matrix (`crate::solve::linear::KktSystem`). Both
//! `forces` and `constraints` assemble through here, so neither imports the other.

use nalgebra::{DMatrix, DVector, Matrix6, Vector6};

use crate::kinematics::PointKinematics;
use crate::model::{BodyId, CableId, Model, PointId};

/// Receives tangent matrices body block by body block, so that the same element code fills a
/// dense `K` and `C` (statics, modes) or scatters scaled blocks straight into a Newton matrix
/// (`crate::solve::linear::KktSystem`). Blocks of bodies without coordinates must be ignored.
pub trait TangentSink {
    /// `K[a, b] += scale * blk` (the bodies' `k_a x k_b` corner of `blk`).
    fn stiffness(&mut self, a: BodyId, b: BodyId, blk: &Matrix6<f64>, scale: f64);
    /// `C[a, b] += scale * blk`.
    fn damping(&mut self, a: BodyId, b: BodyId, blk: &Matrix6<f64>, scale: f64);
    /// The rank-one terms of cable `cable`: `K += g (axial g + damping h)^T` and
    /// `C += damping g g^T`, where `g = sum_i grad[i]` and `h = sum_i rate_grad[i]`, each
    /// `grad[i]` (a body-local 6-vector) placed on the body of route point `i`
    /// (`kin[route[i].0].body`). `rate_grad` is `None` when `damping` is 0. `axial = EA/L0` (N/m),
    /// `damping = c` (N s/m).
    #[allow(clippy::too_many_arguments)]
    fn cable_rank_one(
        &mut self,
        cable: CableId,
        route: &[PointId],
        kin: &[PointKinematics],
        grad: &[Vector6<f64>],
        rate_grad: Option<&[Vector6<f64>]>,
        axial: f64,
        damping: f64,
    );
}

/// A `TangentSink` into dense `n x n` matrices: `K` always, `C` when given.
pub struct DenseTangents<'a> {
    /// The model whose coordinates index the matrices.
    pub model: &'a Model,
    /// `K = -dQ/dq`.
    pub stiffness: &'a mut DMatrix<f64>,
    /// `C = -dQ/dv`, when wanted.
    pub damping: Option<&'a mut DMatrix<f64>>,
}

impl TangentSink for DenseTangents<'_> {
    fn stiffness(&mut self, a: BodyId, b: BodyId, blk: &Matrix6<f64>, scale: f64) {
        add_block(self.model, a, b, blk, scale, self.stiffness);
    }
    fn damping(&mut self, a: BodyId, b: BodyId, blk: &Matrix6<f64>, scale: f64) {
        if let Some(c) = self.damping.as_deref_mut() {
            add_block(self.model, a, b, blk, scale, c);
        }
    }
    fn cable_rank_one(
        &mut self,
        _cable: CableId,
        route: &[PointId],
        kin: &[PointKinematics],
        grad: &[Vector6<f64>],
        rate_grad: Option<&[Vector6<f64>]>,
        axial: f64,
        damping: f64,
    ) {
        for i in 0..grad.len() {
            let a = kin[route[i].0].body;
            for j in 0..grad.len() {
                let b = kin[route[j].0].body;
                let mut w = grad[j] * axial;
                if let Some(h) = rate_grad {
                    w += h[j] * damping;
                }
                add_block(self.model, a, b, &(grad[i] * w.transpose()), 1.0, self.stiffness);
                if damping > 0.0 {
                    if let Some(c) = self.damping.as_deref_mut() {
                        add_block(self.model, a, b, &(grad[i] * grad[j].transpose()), damping, c);
                    }
                }
            }
        }
    }
}

/// Adds the first `dof_count` entries of `v * scale` into the body's rows of `out`.
pub fn add_vector(model: &Model, body: BodyId, v: &Vector6<f64>, scale: f64, out: &mut DVector<f64>) {
    let b = &model.bodies[body.0];
    let rows = &mut out.as_mut_slice()[b.dof_offset..b.dof_offset + b.dof_count];
    for (o, x) in rows.iter_mut().zip(v.iter()) {
        *o += scale * x;
    }
}

/// Adds `scale * blk` (the bodies' `k_a x k_b` corner of a 6 x 6) at the bodies' rows/columns.
pub fn add_block(
    model: &Model,
    a: BodyId,
    b: BodyId,
    blk: &Matrix6<f64>,
    scale: f64,
    out: &mut DMatrix<f64>,
) {
    let (ba, bb) = (&model.bodies[a.0], &model.bodies[b.0]);
    for r in 0..ba.dof_count {
        for c in 0..bb.dof_count {
            out[(ba.dof_offset + r, bb.dof_offset + c)] += scale * blk[(r, c)];
        }
    }
}
