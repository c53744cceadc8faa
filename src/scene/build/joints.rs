//! Joints and supports: takes `[[joints]]` and the bodies, gives `JointModel`s (held directions,
//! hinge and planar axes) and refuses redundant ones.

use std::collections::{BTreeMap, BTreeSet};

use nalgebra::{Matrix3, Vector3};

use super::context::{bounded3, in_range, Ctx};
use crate::error::SceneError;
use crate::model::{BodyKind, BodyModel, JointModel, JointTarget, Model, PointId, PointModel};
use crate::scene::spec::{self, limits, JointKindSpec, SceneSpec};

/// What a joint spec holds, checked: its kind, held world directions
/// (`JointModel::directions`), point rows, and the unit world axis its alignment keeps (a
/// hinge's axis or a planar joint's normal; none for a hinge in a planar scene, whose bodies
/// turn about z only).
pub(super) struct HeldDirections {
    kind: crate::model::JointKind,
    directions: Option<Matrix3<f64>>,
    rows: usize,
    aligned_axis: Option<Vector3<f64>>,
}

/// A joint's kind, held world directions, rows and aligned axis: ball joints and pins hold
/// every direction (`rows`: 3, or 2 in a planar scene); a roller the directions across its
/// line, a slider its plane's normal; a hinge and a planar joint also keep an axis. On error,
/// the field and the reason.
pub(super) fn support_directions(
    j: &spec::JointSpec,
    rows: usize,
) -> Result<HeldDirections, (&'static str, String)> {
    use crate::model::JointKind;
    let planar = rows == 2;
    let unit = |v: Option<[f64; 3]>,
                field: &'static str,
                what: &str|
     -> Result<Vector3<f64>, (&'static str, String)> {
        let v = v.ok_or_else(|| (field, format!("missing: a {what} needs its {field}")))?;
        bounded3(&v, limits::MAX_COORDINATE, "").map_err(|r| (field, r))?;
        let v = Vector3::from(v);
        if v.norm() <= 1e-12 {
            return Err((field, format!("must not be zero, got {v:?}")));
        }
        if planar && v.z != 0.0 {
            return Err((field, "a planar scene moves in the xy plane: z must be 0".into()));
        }
        Ok(v.normalize())
    };
    let stray = |field: &'static str, given: bool| -> Result<(), (&'static str, String)> {
        let owners = match field {
            "normal" => "slider or a planar joint",
            "axis" => "hinge",
            _ => "roller",
        };
        if given {
            Err((field, format!("only a {owners} takes `{field}`")))
        } else {
            Ok(())
        }
    };
    if j.kind != spec::JointKindSpec::Hinge {
        stray("axis", j.axis.is_some())?;
    }
    match j.kind {
        spec::JointKindSpec::Ball | spec::JointKindSpec::Pin => {
            stray("direction", j.direction.is_some())?;
            stray("normal", j.normal.is_some())?;
            let kind = if j.kind == spec::JointKindSpec::Ball { JointKind::Ball } else { JointKind::Pin };
            Ok(HeldDirections { kind, directions: None, rows, aligned_axis: None })
        }
        spec::JointKindSpec::Hinge => {
            stray("direction", j.direction.is_some())?;
            stray("normal", j.normal.is_some())?;
            let aligned_axis = if planar {
                let axis = j.axis.ok_or(("axis", "missing: a hinge needs its axis".to_string()))?;
                if axis[0] != 0.0 || axis[1] != 0.0 || axis[2] == 0.0 {
                    return Err((
                        "axis",
                        "a planar scene turns about z only: a hinge's axis must be [0, 0, 1]".into(),
                    ));
                }
                None
            } else {
                Some(unit(j.axis, "axis", "hinge")?)
            };
            Ok(HeldDirections { kind: JointKind::Hinge, directions: None, rows, aligned_axis })
        }
        spec::JointKindSpec::Slider | spec::JointKindSpec::Planar => {
            stray("direction", j.direction.is_some())?;
            let (kind, what) = match j.kind {
                spec::JointKindSpec::Slider => (JointKind::Slider, "slider"),
                _ => (JointKind::Planar, "planar joint"),
            };
            if planar && kind == JointKind::Planar {
                return Err((
                    "kind",
                    "a planar scene already keeps its bodies in the xy plane: use a slider or a roller"
                        .into(),
                ));
            }
            let n = unit(j.normal, "normal", what)?;
            let mut d = Matrix3::zeros();
            d.set_row(0, &n.transpose());
            let aligned_axis = (kind == JointKind::Planar).then_some(n);
            Ok(HeldDirections { kind, directions: Some(d), rows: 1, aligned_axis })
        }
        spec::JointKindSpec::Roller => {
            stray("normal", j.normal.is_some())?;
            let t = unit(j.direction, "direction", "roller")?;
            let mut d = Matrix3::zeros();
            if planar {
                // the line's normal in the plane
                d.set_row(0, &Vector3::new(-t.y, t.x, 0.0).transpose());
                return Ok(HeldDirections {
                    kind: JointKind::Roller,
                    directions: Some(d),
                    rows: 1,
                    aligned_axis: None,
                });
            }
            // two unit vectors across the line
            let helper = if t.x.abs() < 0.9 { Vector3::x() } else { Vector3::y() };
            let u = t.cross(&helper).normalize();
            let w = t.cross(&u);
            d.set_row(0, &u.transpose());
            d.set_row(1, &w.transpose());
            Ok(HeldDirections { kind: JointKind::Roller, directions: Some(d), rows: 2, aligned_axis: None })
        }
    }
}

/// Checks and builds `joints` (points that coincide at the start, no repeated constraint);
/// `rows` is 2 in planar scenes, else 3.
pub(super) fn build_joints(
    spec: &SceneSpec,
    cx: &Ctx,
    bodies: &[BodyModel],
    points: &[PointModel],
    point_names: &BTreeMap<String, PointId>,
    rows: usize,
) -> Result<Vec<JointModel>, SceneError> {
    let point_pos = |p: PointId| {
        let pm = &points[p.0];
        bodies[pm.body.0].initial_pose.transform_point(&pm.local)
    };
    let lookup = |name: &str| point_names.get(name).copied();
    let length_scale =
        points.iter().enumerate().map(|(i, _)| point_pos(PointId(i)).norm()).fold(1.0, f64::max);

    let mut joints = Vec::new();
    let mut row_offset = 0;
    let mut joint_keys: BTreeMap<(usize, usize), usize> = BTreeMap::new();
    for (i, j) in spec.joints.iter().enumerate() {
        let e = |field: &str, reason: String| cx.err("joints", i, field, reason);
        let a = lookup(&j.a).ok_or_else(|| e("a", format!("unknown point '{}'", j.a)))?;
        let body_a = points[a.0].body;
        let target = match j.kind {
            JointKindSpec::Ball | JointKindSpec::Hinge | JointKindSpec::Planar
                if j.kind == JointKindSpec::Ball || j.b.is_some() =>
            {
                let bname =
                    j.b.as_ref()
                        .ok_or_else(|| e("b", "missing: a ball joint joins point a to point b".into()))?;
                let b = lookup(bname).ok_or_else(|| e("b", format!("unknown point '{bname}'")))?;
                if points[b.0].body == body_a {
                    return Err(e("b", "both points are on the same body".into()));
                }
                if j.at.is_some() {
                    return Err(e(
                        "at",
                        "a joint between two bodies sits where its points meet; only supports (pin, roller, slider, planar, hinge without b) take `at`".into(),
                    ));
                }
                if bodies[body_a.0].dof_count == 0 && bodies[points[b.0].body.0].dof_count == 0 {
                    return Err(e("a", "both bodies are fixed: the joint holds nothing".into()));
                }
                JointTarget::Point(b)
            }
            JointKindSpec::Ball
            | JointKindSpec::Hinge
            | JointKindSpec::Pin
            | JointKindSpec::Roller
            | JointKindSpec::Slider
            | JointKindSpec::Planar => {
                if j.b.is_some() {
                    return Err(e(
                        "b",
                        "a pin, roller or slider holds one point to the ground; use kind = \"ball\", \"hinge\" or \"planar\" to join two bodies".into(),
                    ));
                }
                if bodies[body_a.0].dof_count == 0 {
                    return Err(e("a", "the point is on a fixed body: nothing to pin".into()));
                }
                let at = match j.at {
                    Some(v) => {
                        bounded3(&v, limits::MAX_COORDINATE, "m").map_err(|r| e("at", r))?;
                        Vector3::from(v)
                    }
                    None => point_pos(a),
                };
                JointTarget::World(at)
            }
        };
        let held = support_directions(j, rows).map_err(|(f, r)| e(f, r))?;
        let (kind, directions, joint_rows) = (held.kind, held.directions, held.rows);
        let gap = match target {
            JointTarget::Point(b) => point_pos(a) - point_pos(b),
            JointTarget::World(x) => point_pos(a) - x,
        };
        // a roller or slider needs its point on its line or plane, not at `at`
        let held_gap = match &directions {
            None => gap.norm(),
            Some(d) => (d * gap).rows(0, joint_rows).norm(),
        };
        if held_gap > 1e-9 * length_scale {
            let reason = match kind {
                crate::model::JointKind::Roller => format!(
                    "the point is {held_gap:.3e} m off the roller's line at the start; it must lie on it"
                ),
                crate::model::JointKind::Slider => format!(
                    "the point is {held_gap:.3e} m off the slider's plane at the start; it must lie in it"
                ),
                crate::model::JointKind::Planar => format!(
                    "the point is {held_gap:.3e} m off the planar joint's plane (through {}, normal `normal`) at the start; it must lie in it",
                    j.b.as_deref().or(j.at.map(|_| "`at`")).unwrap_or("the point's start")
                ),
                _ => {
                    format!("the joint's points are {held_gap:.3e} m apart at the start; they must coincide")
                }
            };
            return Err(e("a", reason));
        }
        // the same pin, or the same pair of points joined again, only repeats constraint rows: the
        // equations become singular (and a long list of repeats makes every solve slow)
        // (a roller and a slider on one point may be meant; the rank test below judges them)
        let key = match (target, j.kind) {
            (JointTarget::Point(b), _) => Some((a.0.min(b.0), a.0.max(b.0))),
            (JointTarget::World(_), JointKindSpec::Pin | JointKindSpec::Hinge) => Some((a.0, usize::MAX)),
            _ => None,
        };
        if let Some(first) = key.and_then(|key| joint_keys.insert(key, i)) {
            return Err(e(
                "a",
                format!("joints[{first}] already holds these points: the constraint would be repeated (redundant)"),
            ));
        }
        // a planar joint's plane turns with a moving body b: its normal is kept in b's frame
        let (directions, plane_normal) = match (target, held.aligned_axis) {
            (JointTarget::Point(b), Some(n))
                if kind == crate::model::JointKind::Planar && bodies[points[b.0].body.0].dof_count > 0 =>
            {
                let body_b = &bodies[points[b.0].body.0];
                if bar_across(bodies, points[b.0].body, &n).is_some() {
                    return Err(e(
                        "normal",
                        "a plane through a bar's point turns with the bar, which turns freely about its own axis: only a plane normal to the bar is held (normal along the bar); make the body kind = \"rigid\" (with an inertia)".into(),
                    ));
                }
                (None, Some(body_b.initial_pose.rotation.inverse() * n))
            }
            _ => (directions, None),
        };
        let damping = match j.damping {
            None => 0.0,
            Some(c) => {
                let c = in_range(c, limits::DAMPING, "N m s/rad").map_err(|r| e("damping", r))?;
                let turns =
                    |b: crate::model::BodyId| matches!(bodies[b.0].kind, BodyKind::Bar | BodyKind::Rigid);
                let other = match target {
                    JointTarget::Point(b) => Some(points[b.0].body),
                    JointTarget::World(_) => None,
                };
                let still = |b: crate::model::BodyId| bodies[b.0].kind == BodyKind::Fixed;
                if !turns(body_a) || other.is_some_and(|b| !turns(b) && !still(b)) {
                    return Err(e(
                        "damping",
                        "joint damping resists the relative spin of two bodies that turn (bar, rigid) or of one and the ground; a node has no spin".into(),
                    ));
                }
                c
            }
        };
        let other_body = match target {
            JointTarget::Point(b) => Some(points[b.0].body),
            JointTarget::World(_) => None,
        };
        // a hinge's or planar joint's axis rows
        let alignment = match held.aligned_axis {
            None => None,
            Some(axis) => {
                let orients = |b: crate::model::BodyId| {
                    matches!(bodies[b.0].kind, BodyKind::Bar | BodyKind::Rigid | BodyKind::Fixed)
                };
                if !orients(body_a) || other_body.is_some_and(|b| !orients(b)) {
                    return Err(e(
                        "a",
                        format!(
                            "a {} holds the orientation of bodies that turn (bar, rigid) or are fixed; a node has none",
                            if j.kind == JointKindSpec::Hinge { "hinge" } else { "planar joint" }
                        ),
                    ));
                }
                Some(axis_alignment(&axis, bodies, body_a, other_body).map_err(|r| e("b", r))?)
            }
        };
        let base = JointModel {
            point: a,
            target,
            row_offset,
            rows: joint_rows,
            directions,
            kind,
            damping,
            alignment: None,
            plane_normal,
            scene_index: i,
        };
        joints.push(base);
        row_offset += joint_rows;
        if let Some((alignment, rows)) = alignment {
            joints.push(JointModel {
                row_offset,
                rows,
                directions: None,
                damping: 0.0,
                alignment: Some(alignment),
                plane_normal: None,
                ..base
            });
            row_offset += rows;
        }
    }

    Ok(joints)
}

/// The initial direction `d` of `body`'s axis (its body z) when it is a bar not along `axis`
/// (`|d x axis| > 1e-6`): a bar turns freely about its own axis, so a joint turning about `axis`
/// can hold only its angle to it (and a plane that turns with it only when normal to it).
pub(super) fn bar_across(
    bodies: &[BodyModel],
    body: crate::model::BodyId,
    axis: &Vector3<f64>,
) -> Option<Vector3<f64>> {
    let b = &bodies[body.0];
    let d = b.initial_pose.rotation * Vector3::z();
    (b.kind == BodyKind::Bar && d.cross(axis).norm() > 1e-6).then_some(d)
}

/// The alignment that keeps world axis `axis` (unit, at the initial poses) common to body `a`
/// and body `b` (or the ground), and its row count (`crate::model::Alignment`): two unit normals
/// to it in `a`'s frame and the axis in `b`'s (2 rows); with a bar on one side and the axis not
/// along it (`|d x axis| > 1e-6`), the bar's angle to the axis (1 row). Two bars are refused:
/// each turns freely about its own axis, so together they hold no axis a ball joint does not.
pub(super) fn axis_alignment(
    axis: &Vector3<f64>,
    bodies: &[BodyModel],
    a: crate::model::BodyId,
    b: Option<crate::model::BodyId>,
) -> Result<(crate::model::Alignment, usize), String> {
    let to_body =
        |body: crate::model::BodyId, v: &Vector3<f64>| bodies[body.0].initial_pose.rotation.inverse() * v;
    let in_b = |v: &Vector3<f64>| match b {
        Some(b) => to_body(b, v),
        None => *v,
    };
    let is_bar = |body: crate::model::BodyId| bodies[body.0].kind == BodyKind::Bar;
    if is_bar(a) && b.is_some_and(is_bar) {
        return Err("a bar turns freely about its own axis, so between two bars this joint holds no axis (it would be a ball joint); make one of them kind = \"rigid\" (with an inertia), or use kind = \"ball\"".into());
    }
    // a bar along the joint's axis keeps both rows, whose moments are normal to it
    if let Some(d) = bar_across(bodies, a, axis) {
        let normals = [Vector3::z(), Vector3::zeros()];
        return Ok((crate::model::Alignment { normals, axis: in_b(axis), offset: d.dot(axis) }, 1));
    }
    if let Some(d) = b.and_then(|b| bar_across(bodies, b, axis)) {
        let normals = [to_body(a, axis), Vector3::zeros()];
        return Ok((crate::model::Alignment { normals, axis: Vector3::z(), offset: d.dot(axis) }, 1));
    }
    let helper = if axis.x.abs() < 0.9 { Vector3::x() } else { Vector3::y() };
    let n1 = axis.cross(&helper).normalize();
    let n2 = axis.cross(&n1);
    Ok((
        crate::model::Alignment {
            normals: [to_body(a, &n1), to_body(a, &n2)],
            axis: in_b(axis),
            offset: 0.0,
        },
        2,
    ))
}

/// Largest number of joint equations of one group of joined bodies whose independence
/// `check_redundant_joints` checks (a dense rank-revealing QR of the group's block of `Phi_q^T`,
/// about `2 n rows^2` flops: 40 ms for the 576 rows of a 64-stage tower on the development
/// machine).
pub const MAX_REDUNDANCY_CHECK_ROWS: usize = 4000;

/// True when the joint equations are independent at the point kinematics `kin`: a rank check per
/// group of bodies the joints tie together (bodies with coordinates joined by ball joints, found
/// by union-find; a pin ties one body to the ground and joins nothing), each the column-pivoted QR
/// of that group's block of `Phi_q^T` (its joints' rows, its bodies' coordinates), with the
/// relative tolerance `1e-10` of the largest row norm of `Phi_q`. Joints of different groups
/// share no coordinate, so `Phi_q` has full row rank exactly when every block has, and no dense
/// `Phi_q` is formed: a prism of 999 pinned struts is 999 blocks of 3 rows and 5 coordinates,
/// where one QR of the whole `Phi_q^T` (5000 x 3000) took 13.6 s; a tower's stages joined by ball
/// joints are one block, as before. On failure, the joints of every deficient group, in scene
/// order.
pub(super) fn joints_independent(
    model: &Model,
    poses: &[crate::model::Pose],
    kin: &[crate::kinematics::PointKinematics],
) -> Result<(), Vec<usize>> {
    let mut groups_of = crate::model::BodyGroups::new(model.bodies.len());
    let body_of = |p: PointId| model.points[p.0].body.0;
    let moving = |b: usize| model.bodies[b].dof_count > 0;
    for joint in &model.joints {
        if let JointTarget::Point(b) = joint.target {
            let (x, y) = (body_of(joint.point), body_of(b));
            // a fixed body has no coordinates: joining through it would merge what is independent
            if moving(x) && moving(y) {
                groups_of.join(x, y);
            }
        }
    }
    // each group: its joints and its bodies
    let mut groups: BTreeMap<usize, (Vec<usize>, Vec<usize>)> = BTreeMap::new();
    for (j, joint) in model.joints.iter().enumerate() {
        let first = body_of(joint.point);
        let body = match joint.target {
            _ if moving(first) => first,
            JointTarget::Point(b) if moving(body_of(b)) => body_of(b),
            _ => return Err(vec![j]), // a joint on fixed bodies alone holds nothing: a zero row
        };
        let group = groups_of.root(body);
        groups.entry(group).or_default().0.push(j);
    }
    for b in 0..model.bodies.len() {
        if moving(b) {
            let group = groups_of.root(b);
            if let Some((_, bodies)) = groups.get_mut(&group) {
                bodies.push(b);
            }
        }
    }
    // each group's block of Phi_q^T (coordinates x rows)
    let blocks: Vec<faer::Mat<f64>> = groups
        .values()
        .map(|(joints, bodies)| {
            let mut column_of = BTreeMap::new();
            for &b in bodies {
                let body = &model.bodies[b];
                for c in 0..body.dof_count {
                    column_of.insert(body.dof_offset + c, column_of.len());
                }
            }
            let total: usize = joints.iter().map(|&j| model.joints[j].rows).sum();
            let mut block = faer::Mat::<f64>::zeros(column_of.len(), total);
            let mut first = 0;
            for &j in joints {
                crate::constraints::add_jacobian_entries(model, poses, kin, &model.joints[j], |r, c, x| {
                    block[(column_of[&c], first + r)] += x;
                });
                first += model.joints[j].rows;
            }
            block
        })
        .collect();
    let scale = blocks
        .iter()
        .flat_map(|b| {
            (0..b.ncols()).map(move |r| (0..b.nrows()).map(|i| b[(i, r)].powi(2)).sum::<f64>().sqrt())
        })
        .fold(0.0, f64::max)
        .max(1e-300);
    let tol = 1e-10 * scale;
    let mut deficient: Vec<usize> = Vec::new();
    for (block, (joints, _)) in blocks.iter().zip(groups.values()) {
        let independent = if block.ncols() > block.nrows() {
            false // more equations than coordinates
        } else if block.ncols() > MAX_REDUNDANCY_CHECK_ROWS {
            true // too large to check (a dense QR)
        } else {
            let qr = block.col_piv_qr();
            let r = qr.thin_R();
            (0..block.ncols()).all(|i| r[(i, i)].abs() > tol)
        };
        if !independent {
            deficient.extend(joints);
        }
    }
    if deficient.is_empty() {
        Ok(())
    } else {
        deficient.sort_unstable();
        Err(deficient)
    }
}

/// Refuses joints whose equations repeat what earlier joints already impose at the initial pose
/// (a bar pinned at both ends and at its middle; a bar pinned at both ends, whose length already
/// fixes the distance between the pins): the joint Jacobian `Phi_q` loses rank, no solver can
/// tell the joints' reactions apart, and the dynamics cannot start. The rank comes from faer's
/// column-pivoted QR of `Phi_q^T`, group by group of joined bodies (`joints_independent`,
/// relative tolerance `1e-10`); only when it is deficient are the
/// rows taken in scene order (Gram-Schmidt) to find the first joint with an equation implied by
/// earlier ones, and a least-squares fit of that equation on the earlier ones names the joints
/// it repeats.
pub(super) fn check_redundant_joints(model: &Model, cx: &Ctx) -> Result<(), SceneError> {
    use nalgebra::{DMatrix, DVector};
    let n = model.dof_count;
    if model.constraint_count == 0 {
        return Ok(());
    }
    let state = crate::state::State::initial(model);
    let kin: Vec<_> = (0..model.points.len())
        .map(|p| crate::kinematics::point_kinematics(model, &state.poses, &state.velocities, PointId(p)))
        .collect();
    let Err(suspects) = joints_independent(model, &state.poses, &kin) else { return Ok(()) };
    // the deficient groups' rows only (other groups share no coordinate with them)
    // each row's joint (its index in `suspects`) and each joint's first row
    let mut row_joint = Vec::new();
    let mut first_row = Vec::new();
    for (k, &j) in suspects.iter().enumerate() {
        first_row.push(row_joint.len());
        row_joint.extend(std::iter::repeat_n(k, model.joints[j].rows));
    }
    let mut phi_q = DMatrix::zeros(row_joint.len(), n);
    for (k, &j) in suspects.iter().enumerate() {
        crate::constraints::add_jacobian_entries(model, &state.poses, &kin, &model.joints[j], |r, c, x| {
            phi_q[(first_row[k] + r, c)] += x;
        });
    }
    let scale = phi_q.row_iter().map(|r| r.norm()).fold(0.0, f64::max).max(1e-300);
    let tol = 1e-10 * scale;
    let nc = phi_q.nrows();
    // in scene order: the first row that earlier rows already span
    let mut basis: Vec<DVector<f64>> = Vec::new();
    let mut independent: Vec<usize> = Vec::new();
    let mut dependent: Vec<usize> = Vec::new();
    for r in 0..nc {
        let row = phi_q.row(r).transpose();
        let mut v = row.clone();
        for _ in 0..2 {
            for u in &basis {
                let c = u.dot(&v);
                v.axpy(-c, u, 1.0);
            }
        }
        if v.norm() <= 1e-8 * row.norm().max(tol) {
            dependent.push(r);
        } else {
            basis.push(&v / v.norm());
            independent.push(r);
        }
        // report the first joint with a dependent equation once all its rows are seen
        if let Some(&first) = dependent.first() {
            let local = row_joint[first];
            let joint = suspects[local];
            let rows = model.joints[joint].rows;
            if r + 1 == first_row[local] + rows {
                let own: Vec<usize> = dependent.iter().copied().filter(|&d| row_joint[d] == local).collect();
                let earlier: Vec<usize> =
                    independent.iter().copied().filter(|&i| row_joint[i] < local).collect();
                // which earlier joints the dependent equations are combinations of
                let mut named = BTreeSet::new();
                if !earlier.is_empty() {
                    let a = DMatrix::from_fn(n, earlier.len(), |i, k| phi_q[(earlier[k], i)]);
                    if let Some(svd) = crate::solve::linear::ThinSvd::new(&a) {
                        for &d in &own {
                            let c = svd.solve(&phi_q.row(d).transpose(), 1e-10 * svd.s.amax());
                            let big = c.amax();
                            for (k, &e) in earlier.iter().enumerate() {
                                let other = model.joints[suspects[row_joint[e]]].scene_index;
                                if c[k].abs() > 1e-8 * big && other != model.joints[joint].scene_index {
                                    named.insert(other);
                                }
                            }
                        }
                    }
                }
                let names: Vec<String> = named.iter().map(|j| format!("joints[{j}]")).collect();
                let by = match names.len() {
                    0 => "the other joints".to_string(),
                    1 => names[0].clone(),
                    _ => format!("{} and {}", names[..names.len() - 1].join(", "), names[names.len() - 1]),
                };
                let what = if own.len() == 1 && rows == 1 {
                    "its equation is".to_string()
                } else if own.len() == 1 {
                    format!("1 of its {rows} equations is")
                } else {
                    format!("{} of its {rows} equations are", own.len())
                };
                return Err(cx.err(
                    "joints",
                    model.joints[joint].scene_index,
                    "a",
                    format!(
                        "redundant: {what} implied by {by} at the initial pose (together they fix more \
                         than the bodies' coordinates can move), so no solver can tell their reactions \
                         apart; remove this joint, or make a body that must not move kind = \"fixed\""
                    ),
                ));
            }
        }
    }
    Ok(())
}
