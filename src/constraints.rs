//! Joint constraints (ball joints between bodies, pins to the ground): takes point kinematics,
//! gives `Phi(q)` (m), its Jacobian `Phi_q`, and the multiplier-weighted second derivative
//! `d(Phi_q^T lambda)/dq` that the statics and implicit dynamics tangents need.
//!
//! A ball joint holds point `a` on point `b` (or on a world position): `Phi = r_a - r_b`, 3 rows,
//! or the x and y rows only in planar scenes (where z is not a coordinate). A roller or slider
//! support holds only some world directions `D` (`JointModel::directions`): `Phi = D (r_a - x0)`,
//! `Phi_q = D J`, and its multipliers push along `D^T lambda`.
//!
//! The axis rows of a hinge or planar joint (`JointModel::alignment`, `crate::model::Alignment`)
//! hold orientations: `Phi_k = e_k . w - offset` with `e_k = R_a n_k` and the axis `w` (`R_b u`,
//! or the world's `u`); two rows, or one (the bar's angle to the axis) when a bar is on one side
//! and the axis is not along it (`crate::model::Alignment`). Their rows have the same shape as a
//! point joint's, `D G` per side, with `D = [a_1; a_2]`, `a_k = e_k x w` (world, changing with
//! the poses) and `G = [0 | R] B` the body's spin Jacobian (`spin_jacobian`); their multipliers
//! carry the moment `D^T lambda` (N m).
//! With the body-frame retraction `R <- R exp([d]x)`, `w'_a = R_a^T w`, `e'_k = R_b^T e_k`, the
//! rotation blocks of `d(Phi_q^T lambda)/dq` are
//! `sum_k lambda_k [n_k]x [w'_a]x` (a, a), `-sum_k lambda_k [n_k]x R_a^T R_b [u]x` (a, b),
//! `sum_k lambda_k [u]x [e'_k]x` (b, b) and `-sum_k lambda_k [u]x R_b^T R_a [n_k]x` (b, a).
//!
//! The point row of a planar joint between two moving bodies (`JointModel::plane_normal`) holds
//! point `a` in a plane that turns with body `b`: `Phi = n . d`, `n = R_b u`, `d = r_a - r_b`.
//! Its rows are `n^T J_a` on `a` and `-(n^T J_b + (d x n)^T G_b)` on `b`, its multiplier the
//! force `n lambda` on `a`, and with `f = lambda n`, `w = lambda (d x n)` its derivative
//! `d(Phi_q^T lambda)/dq` has the blocks `d(J_a^T f)/dq_a` (a, a), `-lambda J_a^T [n]x G_b`
//! (a, b), `lambda G_b^T [n]x J_a` (b, a) and `-(d(J_b^T f)/dq_b - lambda J_b^T [n]x G_b +
//! B_r^T [R_b^T w]x B_r + lambda G_b^T ([n]x J_b - [d]x [n]x G_b))` (b, b) (`add_plane_hessian`).

use nalgebra::{DMatrix, DVector, Matrix3, Matrix6, Vector3};

use crate::assembly::{add_vector, DenseTangents, TangentSink};
use crate::kinematics::{
    centripetal, force_jacobian_derivative, point_jacobian, point_kinematics, world_spin, PointJacobian,
    PointKinematics,
};
use crate::model::{skew, Alignment, BodyId, JointModel, JointTarget, Model, PointId, Pose};

/// Fills `phi` (rows, m; an alignment's rows are dimensionless) for all joints.
pub fn evaluate_values(model: &Model, poses: &[Pose], kin: &[PointKinematics], phi: &mut DVector<f64>) {
    for joint in &model.joints {
        if let Some(u) = &joint.plane_normal {
            let (n, d) = plane_vectors(model, poses, joint, u);
            phi[joint.row_offset] = n.dot(&d);
            continue;
        }
        if let Some(al) = &joint.alignment {
            let (e, w) = alignment_vectors(model, poses, joint, al);
            for (r, e) in e.iter().take(joint.rows).enumerate() {
                phi[joint.row_offset + r] = e.dot(&w) - al.offset;
            }
            continue;
        }
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
pub fn evaluate_jacobian(model: &Model, poses: &[Pose], kin: &[PointKinematics], phi_q: &mut DMatrix<f64>) {
    if model.joints.is_empty() {
        return;
    }
    phi_q.fill(0.0);
    for joint in &model.joints {
        add_jacobian_entries(model, poses, kin, joint, |r, c, x| phi_q[(joint.row_offset + r, c)] += x);
    }
}

/// Calls `add(row, coordinate, value)` for each term of `joint`'s rows of `Phi_q` at the point
/// kinematics `kin` (`row` counted from the joint's first, `0..joint.rows`; a coordinate
/// may come twice, once per point, and the terms add up), so that a caller can assemble them
/// into any layout (`evaluate_jacobian`'s dense matrix, a block of some joints and bodies).
pub fn add_jacobian_entries(
    model: &Model,
    poses: &[Pose],
    kin: &[PointKinematics],
    joint: &JointModel,
    mut add: impl FnMut(usize, usize, f64),
) {
    for (pid, sign) in joint_points(joint) {
        let p = &kin[pid.0];
        let body = &model.bodies[p.body.0];
        let jacobian = side_jacobian(model, poses, joint, p);
        for r in 0..joint.rows {
            for c in 0..body.dof_count {
                add(r, body.dof_offset + c, sign * jacobian[(r, c)]);
            }
        }
    }
}

/// The joint's rows of a point Jacobian: `D J` (`J` itself for ball joints and pins). For point
/// rows only; `side_jacobian` serves every joint.
#[inline]
pub fn joint_jacobian(joint: &JointModel, jacobian: &PointJacobian) -> PointJacobian {
    match &joint.directions {
        None => *jacobian,
        Some(d) => d * jacobian,
    }
}

/// The joint's rows of `Phi_q` on the body of `p` (one of `joint_points(joint)`), without that
/// side's sign: `D J` for point rows (`joint_jacobian`), `D G` for an alignment
/// (`alignment_directions`, `spin_jacobian`). The first `joint.rows` rows count.
#[inline]
pub fn side_jacobian(
    model: &Model,
    poses: &[Pose],
    joint: &JointModel,
    p: &PointKinematics,
) -> PointJacobian {
    if let Some(u) = &joint.plane_normal {
        let (n, d) = plane_vectors(model, poses, joint, u);
        let mut row = n.transpose() * p.jacobian;
        if p.body != model.points[joint.point.0].body {
            row += d.cross(&n).transpose() * spin_jacobian(model, poses, p.body);
        }
        let mut out = PointJacobian::zeros();
        out.set_row(0, &row);
        return out;
    }
    match &joint.alignment {
        None => joint_jacobian(joint, &p.jacobian),
        Some(al) => alignment_directions(model, poses, joint, al) * spin_jacobian(model, poses, p.body),
    }
}

/// The world normal `n = R_b u` and the gap `d = r_a - r_b` (m) of a planar joint's point row
/// between two bodies (`JointModel::plane_normal`, `u` its normal in body `b`'s frame).
pub fn plane_vectors(
    model: &Model,
    poses: &[Pose],
    joint: &JointModel,
    u: &Vector3<f64>,
) -> (Vector3<f64>, Vector3<f64>) {
    let at = |p: PointId| {
        let point = &model.points[p.0];
        (poses[point.body.0].transform_point(&point.local), point.body)
    };
    let (ra, _) = at(joint.point);
    let JointTarget::Point(pb) = joint.target else { return (*u, Vector3::zeros()) };
    let (rb, body_b) = at(pb);
    (poses[body_b.0].rotation * u, ra - rb)
}

/// `G = [0 | R] B` of `body` (3 x 6, unused columns zero): its world angular velocity is `G v_b`.
pub fn spin_jacobian(model: &Model, poses: &[Pose], body: BodyId) -> PointJacobian {
    let b = &model.bodies[body.0];
    let rot = poses[body.0].rotation.to_rotation_matrix();
    let mut g = PointJacobian::zeros();
    for c in 0..b.dof_count {
        let col = b.basis.column(c);
        g.set_column(c, &(rot * Vector3::new(col[3], col[4], col[5])));
    }
    g
}

/// `body`'s coordinates' share of `v` as a 6-vector (zero past its `dof_count`).
fn body_velocity(model: &Model, body: BodyId, v: &DVector<f64>) -> nalgebra::Vector6<f64> {
    let b = &model.bodies[body.0];
    nalgebra::Vector6::from_fn(|c, _| if c < b.dof_count { v[b.dof_offset + c] } else { 0.0 })
}

/// The rotations `R_a` and `R_b` of an alignment's two sides (`R_b = I` for the ground).
fn alignment_rotations(model: &Model, poses: &[Pose], joint: &JointModel) -> (Matrix3<f64>, Matrix3<f64>) {
    let rot = |p: PointId| poses[model.points[p.0].body.0].rotation.to_rotation_matrix().into_inner();
    let rb = match joint.target {
        JointTarget::Point(b) => rot(b),
        JointTarget::World(_) => Matrix3::identity(),
    };
    (rot(joint.point), rb)
}

/// An alignment's world vectors at `poses`: `e_k = R_a n_k` and the axis `w`.
pub fn alignment_vectors(
    model: &Model,
    poses: &[Pose],
    joint: &JointModel,
    al: &Alignment,
) -> ([Vector3<f64>; 2], Vector3<f64>) {
    let (ra, rb) = alignment_rotations(model, poses, joint);
    (al.normals.map(|n| ra * n), rb * al.axis)
}

/// An alignment's `D` at `poses`: rows `a_k = e_k x w` (world; the rows past `joint.rows` zero).
pub fn alignment_directions(
    model: &Model,
    poses: &[Pose],
    joint: &JointModel,
    al: &Alignment,
) -> Matrix3<f64> {
    let (e, w) = alignment_vectors(model, poses, joint, al);
    let mut d = Matrix3::zeros();
    for (r, e) in e.iter().take(joint.rows).enumerate() {
        d.set_row(r, &e.cross(&w).transpose());
    }
    d
}

/// The world moment an alignment's multipliers `lambda` put on its first body, `D^T lambda`
/// (N m; the second body takes its opposite). Zero for point rows.
pub fn joint_moment(
    model: &Model,
    poses: &[Pose],
    joint: &JointModel,
    lambda: &DVector<f64>,
) -> Vector3<f64> {
    let Some(al) = &joint.alignment else { return Vector3::zeros() };
    let d = alignment_directions(model, poses, joint, al);
    let mut l = Vector3::zeros();
    for r in 0..joint.rows {
        l[r] = lambda[joint.row_offset + r];
    }
    d.transpose() * l
}

/// `d/dt(Phi_q) v` of an alignment (1/s²): with `omega` the world angular velocities,
/// `(d a_k/dt) . (omega_a - omega_b)`, `d a_k/dt = (omega_a x e_k) x w + e_k x (omega_b x w)`.
pub fn alignment_bias(
    model: &Model,
    poses: &[Pose],
    v: &DVector<f64>,
    joint: &JointModel,
    al: &Alignment,
) -> Vector3<f64> {
    let (e, w) = alignment_vectors(model, poses, joint, al);
    // world angular velocity R (B v)_spin
    let omega = |p: PointId| world_spin(model, poses, v, model.points[p.0].body);
    let wa = omega(joint.point);
    let wb = match joint.target {
        JointTarget::Point(b) => omega(b),
        JointTarget::World(_) => Vector3::zeros(),
    };
    let mut out = Vector3::zeros();
    for (r, e) in e.iter().take(joint.rows).enumerate() {
        let rate = wa.cross(e).cross(&w) + e.cross(&wb.cross(&w));
        out[r] = rate.dot(&(wa - wb));
    }
    out
}

/// `d/dt(Phi_q) v` of a planar joint's point row between two bodies (m/s^2): with `n = R_b u`,
/// `d = r_a - r_b` (`plane_vectors`) and `omega_b` body b's world angular velocity,
/// `(omega_b x (omega_b x n)) . d + 2 (omega_b x n) . (v_a - v_b) + n . (c_a - c_b)`, `c` the
/// points' centripetal accelerations `R (w x (w x p))` (`w` body-frame angular velocity).
pub fn plane_bias(
    model: &Model,
    poses: &[Pose],
    v: &DVector<f64>,
    joint: &JointModel,
    u: &Vector3<f64>,
) -> f64 {
    let JointTarget::Point(pb) = joint.target else { return 0.0 };
    let (n, d) = plane_vectors(model, poses, joint, u);
    let velocity = |p: PointId| point_kinematics(model, poses, v, p).velocity;
    let relative = velocity(joint.point) - velocity(pb);
    let centripetal_gap = centripetal(model, poses, v, joint.point) - centripetal(model, poses, v, pb);
    let omega = world_spin(model, poses, v, model.points[pb.0].body);
    let turning = omega.cross(&n);
    omega.cross(&turning).dot(&d) + 2.0 * turning.dot(&relative) + n.dot(&centripetal_gap)
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

/// A joint's multipliers as a world force `D^T lambda` (N; z is 0 in planar scenes; a planar
/// joint's between two bodies `n lambda`, `plane_vectors`). Zero for an alignment's rows, which
/// carry a moment (`joint_moment`).
pub fn joint_reaction(
    model: &Model,
    poses: &[Pose],
    joint: &JointModel,
    lambda: &DVector<f64>,
) -> Vector3<f64> {
    if let Some(u) = &joint.plane_normal {
        return plane_vectors(model, poses, joint, u).0 * lambda[joint.row_offset];
    }
    point_reaction(joint, lambda)
}

/// `joint_reaction` of a joint whose rows turn with no body (point rows with fixed directions),
/// or zero for an alignment's.
#[inline]
fn point_reaction(joint: &JointModel, lambda: &DVector<f64>) -> Vector3<f64> {
    if joint.alignment.is_some() {
        return Vector3::zeros();
    }
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
    poses: &[Pose],
    kin: &[PointKinematics],
    lambda: &DVector<f64>,
    scale: f64,
    out: &mut DVector<f64>,
) {
    for joint in &model.joints {
        if joint.alignment.is_some() {
            let m = joint_moment(model, poses, joint, lambda);
            for (pid, sign) in joint_points(joint) {
                let body = model.points[pid.0].body;
                let g = spin_jacobian(model, poses, body);
                add_vector(model, body, &(g.transpose() * m), sign * scale, out);
            }
            continue;
        }
        if joint.plane_normal.is_some() {
            // the plane's side also turns: the rows themselves, not a force at the points
            for (pid, sign) in joint_points(joint) {
                let p = &kin[pid.0];
                let row = side_jacobian(model, poses, joint, p).row(0).transpose();
                let f6 = nalgebra::Vector6::from_fn(|c, _| row[c] * lambda[joint.row_offset]);
                add_vector(model, p.body, &f6, sign * scale, out);
            }
            continue;
        }
        let f = point_reaction(joint, lambda);
        for (pid, sign) in joint_points(joint) {
            let p = &kin[pid.0];
            add_vector(model, p.body, &(p.jacobian.transpose() * f), sign * scale, out);
        }
    }
}

/// `Phi_q v` (m/s): each joint's relative velocity, from the point velocities in `kin` (an
/// alignment's: `a_k . (omega_a - omega_b)`, 1/s, from the local velocities `v`).
pub fn evaluate_rates(
    model: &Model,
    poses: &[Pose],
    v: &DVector<f64>,
    kin: &[PointKinematics],
    out: &mut DVector<f64>,
) {
    for joint in &model.joints {
        if joint.alignment.is_some() || joint.plane_normal.is_some() {
            let mut rate = Vector3::zeros();
            for (pid, sign) in joint_points(joint) {
                let p = &kin[pid.0];
                let jac = side_jacobian(model, poses, joint, p);
                rate += sign * (jac * body_velocity(model, p.body, v));
            }
            for r in 0..joint.rows {
                out[joint.row_offset + r] = rate[r];
            }
            continue;
        }
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
        if let Some(al) = &joint.alignment {
            add_alignment_hessian(model, poses, joint, al, lambda, scale, sink);
            continue;
        }
        if let Some(u) = &joint.plane_normal {
            add_plane_hessian(model, poses, joint, u, lambda[joint.row_offset], scale, sink);
            continue;
        }
        let f = point_reaction(joint, lambda);
        for (pid, sign) in joint_points(joint) {
            let body = model.points[pid.0].body;
            if model.bodies[body.0].dof_count == 0 {
                continue;
            }
            sink.stiffness(body, body, &force_jacobian_derivative(model, poses, pid, &f), sign * scale);
        }
    }
}

/// Adds `scale * d(Phi_q^T lambda)/dq` of one alignment (the module docs' four blocks).
fn add_alignment_hessian<S: TangentSink + ?Sized>(
    model: &Model,
    poses: &[Pose],
    joint: &JointModel,
    al: &Alignment,
    lambda: &DVector<f64>,
    scale: f64,
    sink: &mut S,
) {
    let (ra, rb) = alignment_rotations(model, poses, joint);
    let body_a = model.points[joint.point.0].body;
    let body_b = match joint.target {
        JointTarget::Point(p) => Some(model.points[p.0].body),
        JointTarget::World(_) => None,
    }
    .filter(|b| model.bodies[b.0].dof_count > 0);
    let w_a = ra.transpose() * rb * al.axis;
    let (rab, rba) = (ra.transpose() * rb, rb.transpose() * ra);
    let u = skew(&al.axis);
    let (mut aa, mut ab, mut bb, mut ba) =
        (Matrix3::zeros(), Matrix3::zeros(), Matrix3::zeros(), Matrix3::zeros());
    for (k, n) in al.normals.iter().take(joint.rows).enumerate() {
        let l = lambda[joint.row_offset + k];
        let nx = skew(n);
        aa += l * nx * skew(&w_a);
        ab -= l * nx * rab * u;
        bb += l * u * skew(&(rba * n));
        ba -= l * u * rba * nx;
    }
    let block = |b_i: BodyId, m: &Matrix3<f64>, b_j: BodyId| {
        let mut six = Matrix6::zeros();
        six.fixed_view_mut::<3, 3>(3, 3).copy_from(m);
        model.bodies[b_i.0].basis.transpose() * six * model.bodies[b_j.0].basis
    };
    if model.bodies[body_a.0].dof_count > 0 {
        sink.stiffness(body_a, body_a, &block(body_a, &aa, body_a), scale);
        if let Some(b) = body_b {
            sink.stiffness(body_a, b, &block(body_a, &ab, b), scale);
            sink.stiffness(b, body_a, &block(b, &ba, body_a), scale);
        }
    }
    if let Some(b) = body_b {
        sink.stiffness(b, b, &block(b, &bb, b), scale);
    }
}

/// Adds `scale * d(Phi_q^T lambda)/dq` of a planar joint's point row between two bodies (the
/// module docs' four blocks; `lambda` its multiplier, N).
#[allow(clippy::too_many_arguments)]
fn add_plane_hessian<S: TangentSink + ?Sized>(
    model: &Model,
    poses: &[Pose],
    joint: &JointModel,
    u: &Vector3<f64>,
    lambda: f64,
    scale: f64,
    sink: &mut S,
) {
    let JointTarget::Point(pb) = joint.target else { return };
    let pa = joint.point;
    let (body_a, body_b) = (model.points[pa.0].body, model.points[pb.0].body);
    let (n, d) = plane_vectors(model, poses, joint, u);
    let (ja, jb) = (point_jacobian(model, poses, pa), point_jacobian(model, poses, pb));
    let gb = spin_jacobian(model, poses, body_b);
    let nx = skew(&n);
    let f = n * lambda;
    let moving = |b: BodyId| model.bodies[b.0].dof_count > 0;
    if moving(body_a) {
        sink.stiffness(body_a, body_a, &force_jacobian_derivative(model, poses, pa, &f), scale);
        if moving(body_b) {
            sink.stiffness(body_a, body_b, &(ja.transpose() * nx * gb), -lambda * scale);
            sink.stiffness(body_b, body_a, &(gb.transpose() * nx * ja), lambda * scale);
        }
    }
    if moving(body_b) {
        let b = &model.bodies[body_b.0];
        let rb = poses[body_b.0].rotation.to_rotation_matrix().into_inner();
        let w = d.cross(&n) * lambda;
        let mut turn = Matrix6::zeros();
        turn.fixed_view_mut::<3, 3>(3, 3).copy_from(&skew(&(rb.transpose() * w)));
        let mut bb = force_jacobian_derivative(model, poses, pb, &f) + b.basis.transpose() * turn * b.basis;
        bb += (gb.transpose() * (nx * jb - skew(&d) * nx * gb) - jb.transpose() * nx * gb) * lambda;
        sink.stiffness(body_b, body_b, &bb, -scale);
    }
}

/// Orthonormal basis (columns) of the null space of `phi_q` (rows x n): the directions the joints
/// allow. The identity without joints; `None` when the joints leave no freedom.
pub fn null_space(phi_q: &DMatrix<f64>, n: usize) -> Option<DMatrix<f64>> {
    if n == 0 {
        return None;
    }
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
