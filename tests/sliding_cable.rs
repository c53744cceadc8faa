//! Invariant: the multibody sliding cable is the finite-element sliding cable in disguise.
//! With point-mass bodies its generalized force and tangent stiffness equal the nodal FE sliding
//! cable (written out independently below, after Aufaure's cable-pulley element generalised to m
//! segments); a pulley the cable runs straight through receives no force; and the two-point cable
//! (m = 1) applies equal and opposite forces `T e` at its ends, with the matching body torques.

mod common;

use common::*;
use nalgebra::{DMatrix, DVector, Matrix3, Vector3};
use proptest::prelude::*;
use tensegrity::evaluate::{evaluate, Tangents, Workspace};
use tensegrity::state::State;

/// Nodal FE sliding cable through nodes `x` (no damping): returns (internal force on the nodes,
/// tangent stiffness), with `f_i = T (e_(i+1) - e_i)` and
/// `K = (EA/L0) b b^T + T sum_k A_k^T (I - e_k e_k^T)/l_k A_k`, `b_i = e_i - e_(i+1)`.
fn fe_sliding_cable(x: &[Vector3<f64>], ea: f64, l0: f64) -> (DVector<f64>, DMatrix<f64>) {
    let m = x.len() - 1;
    let n = 3 * x.len();
    let e: Vec<Vector3<f64>> = (1..=m).map(|k| (x[k] - x[k - 1]).normalize()).collect();
    let l: Vec<f64> = (1..=m).map(|k| (x[k] - x[k - 1]).norm()).collect();
    let length: f64 = l.iter().sum();
    let t = ea / l0 * (length - l0);
    let mut b = DVector::zeros(n);
    for k in 1..=m {
        for a in 0..3 {
            b[3 * k + a] += e[k - 1][a];
            b[3 * (k - 1) + a] -= e[k - 1][a];
        }
    }
    let f = -t * &b;
    let mut kmat = ea / l0 * &b * b.transpose();
    for k in 1..=m {
        let p = (Matrix3::identity() - e[k - 1] * e[k - 1].transpose()) * (t / l[k - 1]);
        for (r, sr) in [(k, 1.0), (k - 1, -1.0)] {
            for (c, sc) in [(k, 1.0), (k - 1, -1.0)] {
                for i in 0..3 {
                    for j in 0..3 {
                        kmat[(3 * r + i, 3 * c + j)] += sr * sc * p[(i, j)];
                    }
                }
            }
        }
    }
    (f, kmat)
}

fn nodes_scene(x: &[[f64; 3]], l0: f64) -> String {
    let mut s = String::new();
    for (i, p) in x.iter().enumerate() {
        s += &format!(
            "[[bodies]]\nname = \"n{i}\"\nkind = \"node\"\nmass = 1.0\nposition = [{}, {}, {}]\n\n",
            p[0], p[1], p[2]
        );
    }
    let route: Vec<String> = (0..x.len()).map(|i| format!("\"n{i}\"")).collect();
    s += &format!(
        "[[cables]]\nname = \"c\"\nroute = [{}]\nea = 2000.0\nrest_length = {l0}\n",
        route.join(", ")
    );
    s
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 64, ..ProptestConfig::default() })]
    #[test]
    fn point_body_sliding_cable_equals_nodal_fe_element(
        x in proptest::collection::vec([-2.0..2.0f64, -2.0..2.0f64, -2.0..2.0f64], 2..=7),
        shrink in 0.5..0.95f64,
    ) {
        let pts: Vec<Vector3<f64>> = x.iter().map(|p| Vector3::from(*p)).collect();
        prop_assume!(pts.windows(2).all(|w| (w[1] - w[0]).norm() > 0.05));
        let length: f64 = pts.windows(2).map(|w| (w[1] - w[0]).norm()).sum();
        let l0 = shrink * length;
        let model = model_from_toml(&nodes_scene(&x, l0));
        let state = State::initial(&model);
        let mut ws = Workspace::new(&model);
        evaluate(&model, &state, &mut ws, Tangents::Stiffness);
        let (f, k) = fe_sliding_cable(&pts, 2000.0, l0);
        let scale = ws.cables[0].tension.max(1.0);
        prop_assert!((&ws.force - &f).amax() <= 1e-10 * scale);
        prop_assert!((&ws.stiffness - &k).amax() <= 1e-9 * k.amax().max(scale), "K differs:\n{}\n{}", ws.stiffness, k);
    }
}

#[test]
fn pulley_on_a_straight_cable_receives_no_force() {
    // anchors on the ground, a pulley on a node exactly between them and one on a rotated rigid
    // body further along the same line
    let text = r#"
[[bodies]]
name = "ground"
kind = "fixed"
points = { a = [0.0, 0.0, 0.0], b = [4.0, 2.0, 1.0] }

[[bodies]]
name = "n"
kind = "node"
mass = 1.0
position = [1.0, 0.5, 0.25]

[[bodies]]
name = "r"
kind = "rigid"
mass = 2.0
position = [3.0, 1.0, 1.0]
rotation = [0.3, -0.2, 0.9]
inertia = [0.1, 0.2, 0.25]
points = { p = [0.0, 0.0, 0.0] }

[[cables]]
name = "c"
route = ["ground.a", "n", "r.p", "ground.b"]
ea = 1000.0
rest_length = 4.0
"#;
    // put r.p on the line: body origin r = (3, 1.5, 0.75) with p at the origin
    let text = text.replace("position = [3.0, 1.0, 1.0]", "position = [3.0, 1.5, 0.75]");
    let model = model_from_toml(&text);
    let state = State::initial(&model);
    let mut ws = Workspace::new(&model);
    evaluate(&model, &state, &mut ws, Tangents::None);
    assert!(ws.cables[0].tension > 10.0);
    assert!(ws.force.amax() <= 1e-12 * ws.cables[0].tension, "force on pulleys: {}", ws.force);

    // the same cable without the pulleys has the same length and tension
    let straight =
        model_from_toml(&text.replace(
            r#"route = ["ground.a", "n", "r.p", "ground.b"]"#,
            r#"route = ["ground.a", "ground.b"]"#,
        ));
    let mut ws2 = Workspace::new(&straight);
    evaluate(&straight, &State::initial(&straight), &mut ws2, Tangents::None);
    assert!((ws2.cables[0].length - ws.cables[0].length).abs() < 1e-12);
    assert!((ws2.cables[0].tension - ws.cables[0].tension).abs() < 1e-9);
}

#[test]
fn two_point_cable_applies_equal_and_opposite_forces_and_their_torques() {
    let text = r#"
[[bodies]]
name = "a"
kind = "rigid"
mass = 1.0
position = [0.0, 0.0, 0.0]
rotation = [0.4, 0.1, -0.3]
inertia = [0.1, 0.2, 0.25]
points = { p = [0.1, 0.2, -0.3] }

[[bodies]]
name = "b"
kind = "rigid"
mass = 1.0
position = [2.0, 0.5, 0.3]
rotation = [-1.0, 0.5, 2.0]
inertia = [0.1, 0.2, 0.25]
points = { p = [-0.2, 0.1, 0.05] }

[[cables]]
name = "c"
route = ["a.p", "b.p"]
ea = 1000.0
rest_length = 1.5
"#;
    let model = model_from_toml(text);
    let state = State::initial(&model);
    let mut ws = Workspace::new(&model);
    evaluate(&model, &state, &mut ws, Tangents::None);
    let t = ws.cables[0].tension;
    let (ra, rb) = (
        ws.points[model.point_id("a.p").unwrap().0].position,
        ws.points[model.point_id("b.p").unwrap().0].position,
    );
    let e = (rb - ra).normalize();
    for (body, f, r) in [(0usize, t * e, ra), (1, -t * e, rb)] {
        let pose = state.poses[body];
        let q = ws.force.rows(6 * body, 6);
        let torque_body = pose.rotation.inverse() * (r - pose.position).cross(&f);
        assert!((q.fixed_rows::<3>(0) - f).norm() < 1e-10 * t);
        assert!((q.fixed_rows::<3>(3) - torque_body).norm() < 1e-10 * t);
    }
}

#[test]
fn zero_length_segments_give_finite_forces_and_matrices() {
    // a node sitting exactly on a fixed pulley point, and a route that starts where a body is
    let text = r#"
[[bodies]]
name = "ground"
kind = "fixed"
points = { a = [0.0, 0.0, 0.0], p = [1.0, 0.0, 0.0], b = [2.0, 1.0, 0.0] }

[[bodies]]
name = "n"
kind = "node"
mass = 1.0
position = [1.0, 0.0, 0.0]

[[bodies]]
name = "r"
kind = "rigid"
mass = 1.0
position = [2.0, 1.0, 0.0]
inertia = [0.1, 0.1, 0.1]

[[cables]]
name = "c"
route = ["ground.a", "ground.p", "n", "r", "ground.b"]
ea = 1000.0
damping = 3.0
rest_length = 1.5
"#;
    let model = model_from_toml(text);
    let mut state = State::initial(&model);
    state.velocities.iter_mut().enumerate().for_each(|(i, v)| *v = 0.1 * i as f64);
    let mut ws = Workspace::new(&model);
    evaluate(&model, &state, &mut ws, Tangents::StiffnessAndDamping);
    let c = ws.cables[0];
    assert!(c.tension > 0.0 && c.tension.is_finite());
    assert_eq!(ws.cable_segments(&model, 0)[1], 0.0);
    assert!(ws.force.iter().chain(ws.stiffness.iter()).chain(ws.damping.iter()).all(|x| x.is_finite()));
}

#[test]
fn pulley_slip_follows_the_uniform_strain_rule() {
    // a trolley node on a cable between two anchors: moving it shifts cable through the pulley
    let text = r#"
[[bodies]]
name = "ground"
kind = "fixed"
points = { a = [0.0, 0.0, 0.0], b = [2.0, 0.0, 0.0] }

[[bodies]]
name = "trolley"
kind = "node"
mass = 1.0
position = [1.0, 0.0, -0.5]

[[cables]]
name = "c"
route = ["ground.a", "trolley", "ground.b"]
ea = 1000.0
rest_length = 2.0
"#;
    let model = model_from_toml(text);
    let mut state = State::initial(&model);
    let mut ws = Workspace::new(&model);
    evaluate(&model, &state, &mut ws, Tangents::None);
    let reference = tensegrity::report::all_pulley_coordinates(&model, &state, &ws);
    state.poses[1].position = Vector3::new(0.5, 0.0, -0.5);
    evaluate(&model, &state, &mut ws, Tangents::None);
    let report = &tensegrity::report::cable_reports(&model, &state, &ws, &reference)[0];
    let (l1, l2) = (0.5f64.hypot(0.5), 1.5f64.hypot(0.5));
    let expected = 2.0 * l1 / (l1 + l2) - 1.0;
    assert!((report.pulley_slip[0] - expected).abs() < 1e-12, "{} vs {expected}", report.pulley_slip[0]);
    assert_eq!(report.segment_lengths.len(), 2);
    assert!((report.strain - ((l1 + l2) - 2.0) / 2.0).abs() < 1e-12);
}
