//! Bodies and their points: takes `[[bodies]]`, gives `BodyModel`s, `PointModel`s and the point
//! names, and checks that every free coordinate carries mass.

use std::collections::BTreeMap;

use nalgebra::{Matrix3, Matrix6, SymmetricEigen, UnitQuaternion, Vector3};

use super::context::{bounded3, in_range, mass, Ctx};
use crate::error::SceneError;
use crate::model::{BodyId, BodyKind, BodyModel, Model, PointId, PointModel, Pose};
use crate::scene::spec::{limits, BodyKindSpec, PointSpec, SceneSpec};

/// The bodies and their points, in scene order (`build_bodies`).
pub(super) struct Bodies {
    pub(super) bodies: Vec<BodyModel>,
    pub(super) points: Vec<PointModel>,
    pub(super) point_names: BTreeMap<String, PointId>,
    /// Coordinates of all bodies.
    pub(super) dof: usize,
}

/// Checks and builds `bodies` (names, poses, masses, inertias, points, coordinate bases).
pub(super) fn build_bodies(spec: &SceneSpec, cx: &Ctx) -> Result<Bodies, SceneError> {
    let mut bodies = Vec::new();
    let mut points: Vec<PointModel> = Vec::new();
    let mut point_names: BTreeMap<String, PointId> = BTreeMap::new();
    let mut dof = 0;
    for (i, b) in spec.bodies.iter().enumerate() {
        let e = |field: &str, reason: String| cx.err("bodies", i, field, reason);
        if b.name.is_empty() || b.name.contains('.') || b.name.contains(char::is_whitespace) {
            return Err(e(
                "name",
                format!("'{}' is not a valid name (non-empty, no dots or spaces)", b.name),
            ));
        }
        if bodies.iter().any(|o: &BodyModel| o.name == b.name) {
            return Err(e("name", format!("duplicate body name '{}'", b.name)));
        }
        if let Some(v) = &b.position {
            bounded3(v, limits::MAX_COORDINATE, "m").map_err(|r| e("position", r))?;
        }
        if let Some(v) = &b.rotation {
            bounded3(v, limits::MAX_ROTATION, "rad").map_err(|r| e("rotation", r))?;
        }
        let rotation = UnitQuaternion::from_scaled_axis(Vector3::from(b.rotation.unwrap_or([0.0; 3])));
        let position = b.position.map(Vector3::from);
        let mut local_points: Vec<(String, Vector3<f64>)> = Vec::new();
        let (kind, mass, inertia, pose, bar_len) = match b.kind {
            BodyKindSpec::Node => {
                // a node may take all its mass from the members that end on it
                let lumped = spec.members.iter().any(|m| {
                    m.mass.is_some() && m.ends.iter().any(|p| p.split('.').next() == Some(b.name.as_str()))
                });
                let mass = match b.mass {
                    None if lumped => 0.0,
                    given => mass(given).map_err(|r| e("mass", r))?,
                };
                let x = position.ok_or_else(|| e("position", "missing (required for a node)".into()))?;
                if b.rotation.is_some() || b.ends.is_some() || b.inertia.is_some() || !b.points.is_empty() {
                    return Err(e(
                        "kind",
                        "a node takes only name, mass and position (its point is the node itself)".into(),
                    ));
                }
                (
                    BodyKind::Node,
                    mass,
                    Matrix3::zeros(),
                    Pose { position: x, rotation: UnitQuaternion::identity() },
                    0.0,
                )
            }
            BodyKindSpec::Bar => {
                let mass = mass(b.mass).map_err(|r| e("mass", r))?;
                let ends = b
                    .ends
                    .ok_or_else(|| e("ends", "missing (a bar is given by its two end positions)".into()))?;
                for end in &ends {
                    bounded3(end, limits::MAX_COORDINATE, "m").map_err(|r| e("ends", r))?;
                }
                if b.position.is_some() || b.rotation.is_some() {
                    return Err(e("position", "a bar is placed by `ends`, not by position/rotation".into()));
                }
                let (a, bb) = (Vector3::from(ends[0]), Vector3::from(ends[1]));
                let len = (bb - a).norm();
                if len <= 1e-9 {
                    return Err(e("ends", "the two ends coincide: a bar needs a positive length".into()));
                }
                let u = (bb - a) / len;
                if spec.planar && u.z.abs() > 1e-9 {
                    return Err(e("ends", "in a planar scene a bar must lie in the xy plane".into()));
                }
                let rot = UnitQuaternion::rotation_between(&Vector3::z(), &u)
                    .unwrap_or_else(|| UnitQuaternion::from_scaled_axis(Vector3::x() * std::f64::consts::PI));
                let it = match b.inertia.as_deref() {
                    None => mass * len * len / 12.0,
                    Some([it]) => in_range(*it, limits::INERTIA, "kg m^2").map_err(|r| e("inertia", r))?,
                    Some(v) => {
                        return Err(e(
                            "inertia",
                            format!("a bar takes one positive transverse inertia, got {v:?}"),
                        ))
                    }
                };
                local_points.push(("a".into(), Vector3::new(0.0, 0.0, -len / 2.0)));
                local_points.push(("b".into(), Vector3::new(0.0, 0.0, len / 2.0)));
                (
                    BodyKind::Bar,
                    mass,
                    Matrix3::from_diagonal(&Vector3::new(it, it, 0.0)),
                    Pose { position: (a + bb) / 2.0, rotation: rot },
                    len,
                )
            }
            BodyKindSpec::Rigid => {
                let mass = mass(b.mass).map_err(|r| e("mass", r))?;
                let x =
                    position.ok_or_else(|| e("position", "missing (required for a rigid body)".into()))?;
                let j = match b.inertia.as_deref() {
                    Some([a, bb, c]) => Matrix3::from_diagonal(&Vector3::new(*a, *bb, *c)),
                    Some([a, bb, c, xy, xz, yz]) => Matrix3::new(*a, *xy, *xz, *xy, *bb, *yz, *xz, *yz, *c),
                    Some(v) => return Err(e("inertia", format!("expected 3 or 6 values, got {}", v.len()))),
                    None => return Err(e("inertia", "missing (required for a rigid body)".into())),
                };
                if let Some(x) = j.iter().find(|x| !(x.is_finite() && x.abs() <= limits::INERTIA.1)) {
                    return Err(e(
                        "inertia",
                        format!(
                            "entries must be finite and within {:e} kg m^2, got {x:e}",
                            limits::INERTIA.1
                        ),
                    ));
                }
                let eig = SymmetricEigen::new(j).eigenvalues;
                let (mn, sum) = (eig.min(), eig.sum());
                if mn <= 0.0 || eig.iter().any(|l| 2.0 * l > sum * (1.0 + 1e-12)) {
                    return Err(e("inertia", format!("every rotation of a rigid body is a free coordinate and needs inertia: principal moments {:?} must be positive and obey the triangle inequality", eig.as_slice())));
                }
                (BodyKind::Rigid, mass, j, Pose { position: x, rotation }, 0.0)
            }
            BodyKindSpec::Fixed => {
                if b.mass.is_some() || b.inertia.is_some() || b.ends.is_some() {
                    return Err(e("mass", "a fixed body takes no mass, inertia or ends".into()));
                }
                (
                    BodyKind::Fixed,
                    0.0,
                    Matrix3::zeros(),
                    Pose { position: position.unwrap_or_else(Vector3::zeros), rotation },
                    0.0,
                )
            }
        };
        for (pname, p) in &b.points {
            let field = format!("points.{pname}");
            if pname.is_empty() || pname.contains('.') {
                return Err(e(&field, "invalid point name".into()));
            }
            if local_points.iter().any(|(n, _)| n == pname) {
                return Err(e(&field, format!("duplicate point name '{pname}' (bars define 'a' and 'b')")));
            }
            let local = match (kind, p) {
                (BodyKind::Bar, PointSpec::Along(s)) if s.is_finite() && s.abs() <= 1e3 => {
                    Vector3::new(0.0, 0.0, (s - 0.5) * bar_len)
                }
                (BodyKind::Bar, PointSpec::Local(_)) => {
                    return Err(e(
                        &field,
                        "a bar's points lie on its axis: give the fraction along the bar from a (0) to b (1)"
                            .into(),
                    ))
                }
                (_, PointSpec::Local(v)) => {
                    bounded3(v, limits::MAX_COORDINATE, "m").map_err(|r| e(&field, r))?;
                    Vector3::from(*v)
                }
                (BodyKind::Bar, PointSpec::Along(_)) => {
                    return Err(e(&field, "a fraction along the bar must be finite and within +-1000".into()))
                }
                (_, PointSpec::Along(_)) => {
                    return Err(e(
                        &field,
                        "expected body coordinates [x, y, z] (every key after a [bodies.points] header \
                         belongs to that table: write top-level keys before the first table)"
                            .into(),
                    ))
                }
            };
            local_points.push((pname.clone(), local));
        }
        // basis
        let mut basis = Matrix6::zeros();
        let mut cols = Vec::new();
        let trans_axes = if spec.planar { 2 } else { 3 };
        if kind != BodyKind::Fixed {
            for a in 0..trans_axes {
                let mut c = nalgebra::Vector6::zeros();
                c[a] = 1.0;
                cols.push(c);
            }
        }
        let rot_axes: Vec<Vector3<f64>> = match (kind, spec.planar) {
            (BodyKind::Node | BodyKind::Fixed, _) => vec![],
            (_, true) => vec![pose.rotation.inverse() * Vector3::z()],
            (BodyKind::Bar, false) => vec![Vector3::x(), Vector3::y()],
            (BodyKind::Rigid, false) => vec![Vector3::x(), Vector3::y(), Vector3::z()],
        };
        for ax in rot_axes {
            cols.push(nalgebra::Vector6::new(0.0, 0.0, 0.0, ax.x, ax.y, ax.z));
        }
        for (k, c) in cols.iter().enumerate() {
            basis.set_column(k, c);
        }
        let id = BodyId(bodies.len());
        let origin_name = b.name.clone();
        point_names.insert(origin_name.clone(), PointId(points.len()));
        points.push(PointModel { name: origin_name, body: id, local: Vector3::zeros() });
        for (pname, local) in local_points {
            let q = format!("{}.{}", b.name, pname);
            point_names.insert(q.clone(), PointId(points.len()));
            points.push(PointModel { name: q, body: id, local });
        }
        bodies.push(BodyModel {
            name: b.name.clone(),
            kind,
            mass,
            inertia,
            basis,
            dof_count: cols.len(),
            dof_offset: dof,
            initial_pose: pose,
        });
        dof += cols.len();
    }
    Ok(Bodies { bodies, points, point_names, dof })
}

/// Every free coordinate must carry mass: the body mass matrix must be positive definite.
pub(super) fn check_mass_on_free_coordinates(model: &Model, cx: &Ctx) -> Result<(), SceneError> {
    for (i, b) in model.bodies.iter().enumerate() {
        if b.dof_count == 0 {
            continue;
        }
        let m = b.mass_matrix();
        let k = b.dof_count;
        let sub = m.view((0, 0), (k, k)).into_owned();
        let eig = SymmetricEigen::new(sub).eigenvalues;
        if eig.min() <= 1e-12 * eig.max().max(1e-300) {
            return Err(cx.err(
                "bodies",
                i,
                "mass",
                format!("body '{}' has a free coordinate without mass or inertia", b.name),
            ));
        }
    }
    Ok(())
}
