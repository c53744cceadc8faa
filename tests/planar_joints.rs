//! Invariant: a planar joint between two bodies (`kind = "planar"` with `b`) holds point `a` in a
//! plane that turns with body `b` and lets the bodies turn relative to each other about the
//! plane's normal only; it holds exactly that and nothing else.
//! - The point row's Jacobian (whose `b` side carries the plane's turning), the derivative of its
//!   reaction `d(Phi_q^T lambda)/dq` and its acceleration bias match finite differences, off the
//!   constraint manifold too.
//! - Statics: a sled on a tilted deck (the deck itself on a hinge, held by a cable) carries
//!   `m g cos(theta)` in the joint and `m g sin(theta)` in the cable that holds it up the slope.
//! - Dynamics: two free bodies joined by a planar joint, tumbling in zero gravity, keep the joint
//!   (to 1e-9), their energy and their linear and angular momentum, under generalized-alpha (dense
//!   and sparse Newton systems), RK4 and Dormand-Prince.
//! - Careless planar joints are refused naming the field.

mod common;

use common::*;
use nalgebra::{UnitQuaternion, Vector3};
use tensegrity::evaluate::{evaluate, Tangents, Workspace};
use tensegrity::sim::{SimSettings, Simulator};
use tensegrity::solve::dynamics::Integrator;
use tensegrity::solve::linear::LinearBackend;
use tensegrity::solve::statics::StaticSolver;
use tensegrity::{Model, State};

/// A skewed rigid deck, free; a rigid sled and a bar on planar joints to it (oblique normals),
/// each joint's point in its plane but away from the plane's point on the deck.
fn tumbling(gravity: f64, arm_kind: &str) -> Model {
    let deck_rotation = UnitQuaternion::from_scaled_axis(Vector3::new(0.2, -0.4, 0.3));
    let (pad, rail) = (Vector3::new(0.3, -0.2, 0.1), Vector3::new(-0.4, 0.5, -0.2));
    let (n1, n2) = (Vector3::new(0.2, -0.3, 1.0), Vector3::new(0.9, 0.1, 0.3));
    // a point of the plane through `p` (world) with normal `n`, moved along it
    let in_plane = |p: Vector3<f64>, n: Vector3<f64>, along: Vector3<f64>| {
        let n = n.normalize();
        p + along - n * along.dot(&n)
    };
    let foot = in_plane(deck_rotation * pad, n1, Vector3::new(0.25, 0.1, 0.0));
    let bar_a = in_plane(deck_rotation * rail, n2, Vector3::new(0.0, 0.3, -0.2));
    let bar_b = bar_a + Vector3::new(-0.6, 0.4, 0.5);
    let v = |x: Vector3<f64>| format!("[{:.17e}, {:.17e}, {:.17e}]", x.x, x.y, x.z);
    model_from_toml(&format!(
        r#"
gravity = [0.0, 0.0, {gravity}]
[[bodies]]
name = "deck"
kind = "rigid"
mass = 3.0
position = [0.0, 0.0, 0.0]
rotation = [0.2, -0.4, 0.3]
inertia = [0.5, 0.7, 0.9, 0.05, -0.03, 0.02]
points = {{ pad = {pad}, rail = {rail} }}
[[bodies]]
name = "sled"
kind = "rigid"
mass = 1.0
position = {foot}
rotation = [-0.1, 0.3, 0.2]
inertia = [0.1, 0.12, 0.15, 0.01, 0.0, -0.02]
points = {{ foot = [0.0, 0.0, 0.0] }}
{arm}
[[joints]]
kind = "planar"
a = "sled.foot"
b = "deck.pad"
normal = {n1}
[[joints]]
kind = "planar"
a = "bar.a"
b = "deck.rail"
normal = {n2}
"#,
        pad = v(pad),
        rail = v(rail),
        foot = v(foot),
        n1 = v(n1),
        n2 = v(n2),
        arm = if arm_kind == "bar" {
            format!(
                "[[bodies]]\nname = \"bar\"\nkind = \"bar\"\nmass = 0.5\nends = [{}, {}]",
                v(bar_a),
                v(bar_b)
            )
        } else {
            let middle = (bar_a + bar_b) / 2.0;
            format!(
                "[[bodies]]\nname = \"bar\"\nkind = \"rigid\"\nmass = 0.5\nposition = {}\ninertia = [0.02, 0.03, 0.04]\npoints = {{ a = {} }}",
                v(middle),
                v(bar_a - middle)
            )
        },
    ))
}

#[test]
fn the_point_row_matches_finite_differences() {
    let model = tumbling(-9.81, "bar");
    // per planar joint: 1 point row + 2 axis rows (the sled) or 1 (the bar: its angle to the
    // normal)
    assert_eq!(model.constraint_count, 5);
    assert!(model.joints.iter().filter(|j| j.plane_normal.is_some()).count() == 2);
    let start = State::initial(&model);
    let mut state = moved(&model, &start, &wiggle(model.dof_count, 1), 0.05);
    state.velocities = wiggle(model.dof_count, 2);
    let mut ws = Workspace::new(&model);
    evaluate(&model, &state, &mut ws, Tangents::None);
    assert!(ws.constraint.amax() > 1e-3, "the test state is off the manifold");
    let fd = check_joint_rows_by_finite_differences(&model, &state);
    for joint in model.joints.iter().filter(|j| j.plane_normal.is_some()) {
        let u = joint.plane_normal.unwrap();
        let bias = tensegrity::constraints::plane_bias(&model, &state.poses, &state.velocities, joint, &u);
        let want = fd[joint.row_offset];
        assert!((bias - want).abs() < 1e-7 * (1.0 + want.abs()), "bias {bias} against {want}");
    }
}

/// Linear and angular momentum (about the origin) of every body at `state`: `sum m v` and
/// `sum x x m v + R J w`.
fn momenta(model: &Model, state: &State) -> (Vector3<f64>, Vector3<f64>) {
    let (mut p, mut l) = (Vector3::zeros(), Vector3::zeros());
    for (b, body) in model.bodies.iter().enumerate() {
        let local = body.local_increment(state.velocities.as_slice(), 1.0);
        let v = Vector3::new(local[0], local[1], local[2]) * body.mass;
        let w = Vector3::new(local[3], local[4], local[5]);
        p += v;
        l += state.poses[b].position.cross(&v) + state.poses[b].rotation * (body.inertia * w);
    }
    (p, l)
}

#[test]
fn bodies_on_a_planar_joint_tumble_keeping_the_joint_energy_and_momenta() {
    // the arm a rigid body (2 axis rows) and a bar (1 axis row, its angle to the normal: it
    // turns freely about its own axis, so the joint puts no moment along it)
    for arm in ["rigid", "bar"] {
        tumble_keeping_the_joint_energy_and_momenta(tumbling(0.0, arm), arm);
    }
}

fn tumble_keeping_the_joint_energy_and_momenta(model: Model, arm: &str) {
    let mut state = State::initial(&model);
    // random velocities the joints allow: v - Phi_q^T (Phi_q Phi_q^T)^-1 Phi_q v
    let mut ws = Workspace::new(&model);
    evaluate(&model, &state, &mut ws, Tangents::None);
    let j = &ws.constraint_jacobian;
    let v = wiggle(model.dof_count, 7) * 2.0;
    let lagrange = (j * j.transpose()).lu().solve(&(j * &v)).unwrap();
    state.velocities = &v - j.transpose() * lagrange;
    let (p0, l0) = momenta(&model, &state);
    let cases = [
        (Integrator::GeneralizedAlpha { rho_inf: 1.0 }, LinearBackend::Dense, 1e-3, None, 1e-4),
        (Integrator::GeneralizedAlpha { rho_inf: 1.0 }, LinearBackend::Sparse, 1e-3, None, 1e-4),
        (Integrator::Rk4, LinearBackend::Dense, 2e-4, None, 1e-8),
        (Integrator::Rk4, LinearBackend::Sparse, 2e-4, None, 1e-8),
        (Integrator::DormandPrince, LinearBackend::Dense, 1e-2, Some(1e-9), 1e-8),
    ];
    for (integrator, linear, dt, tolerance, energy_tolerance) in cases {
        let settings = SimSettings { dt, integrator, linear, tolerance, ..Default::default() };
        let mut sim = Simulator::from_state(model.clone(), state.clone(), settings).unwrap();
        let e0 = sim.energy().total();
        let steps = (1.0 / dt).round() as usize;
        for _ in 0..steps {
            sim.step().unwrap();
        }
        let s = sim.state();
        let mut w = Workspace::new(&model);
        evaluate(&model, s, &mut w, Tangents::None);
        let label = format!("{arm} arm, {integrator:?} {linear:?}");
        assert!(w.constraint.amax() < 1e-9, "{label}: the joints drifted by {}", w.constraint.amax());
        let drift = (sim.energy().total() - e0).abs() / e0;
        assert!(drift < energy_tolerance, "{label}: energy drifted by {drift:e} of {e0} J");
        let (p, l) = momenta(&model, s);
        assert!((p - p0).norm() < 1e-9 * (1.0 + p0.norm()), "{label}: momentum {p} from {p0}");
        assert!((l - l0).norm() < 1e-6 * (1.0 + l0.norm()), "{label}: angular momentum {l} from {l0}");
        // the sled turned relative to the deck, about the normal only: it moved
        let turned = (s.poses[1].rotation * s.poses[0].rotation.inverse()).angle();
        assert!(turned > 0.05, "{label}: the sled hardly moved ({turned} rad)");
    }
}

/// A 4 kg deck hinged to the ground about x at its lower edge, tilted by `theta` and held by a
/// stiff vertical cable at its upper edge; a 2 kg sled on a planar joint to the deck, held up the
/// slope by a cable from its nose to a point higher on the deck.
fn sled_on_deck(theta: f64) -> Model {
    let s = Vector3::new(0.0, theta.cos(), theta.sin());
    let v = |x: Vector3<f64>| format!("[{:.17e}, {:.17e}, {:.17e}]", x.x, x.y, x.z);
    model_from_toml(&format!(
        r#"
gravity = [0.0, 0.0, -9.81]
[[bodies]]
name = "ground"
kind = "fixed"
points = {{ hook = {hook} }}
[[bodies]]
name = "deck"
kind = "rigid"
mass = 4.0
position = {centre}
rotation = [{theta:.17e}, 0.0, 0.0]
inertia = [1.4, 0.1, 1.5]
points = {{ edge = [0.0, -1.0, 0.0], tip = [0.0, 1.0, 0.0], mid = [0.0, 0.0, 0.0], top = [0.0, 0.8, 0.0] }}
[[bodies]]
name = "sled"
kind = "rigid"
mass = 2.0
position = {centre}
rotation = [{theta:.17e}, 0.0, 0.0]
inertia = [0.02, 0.01, 0.03]
points = {{ foot = [0.0, 0.0, 0.0], nose = [0.0, 0.1, 0.0] }}
[[joints]]
kind = "hinge"
a = "deck.edge"
axis = [1.0, 0.0, 0.0]
[[joints]]
kind = "planar"
a = "sled.foot"
b = "deck.mid"
normal = {normal}
[[cables]]
name = "stay"
route = ["deck.tip", "ground.hook"]
ea = 1e6
rest_length = 0.999
[[cables]]
name = "tether"
route = ["sled.nose", "deck.top"]
ea = 1e3
rest_length = 0.65
"#,
        hook = v(s * 2.0 + Vector3::z()),
        centre = v(s),
        normal = v(Vector3::new(0.0, -theta.sin(), theta.cos())),
    ))
}

#[test]
fn a_sled_on_a_hinged_deck_carries_its_weight_in_the_joint_and_the_tether() {
    for theta in [0.3f64, 0.5, 0.9] {
        let model = sled_on_deck(theta);
        let mut ws = Workspace::new(&model);
        // dense and sparse Newton systems find the same equilibrium
        let solve = |sparse: bool, ws: &mut Workspace| {
            let mut state = State::initial(&model);
            StaticSolver::new(&model)
                .with_sparse_kkt(&model, sparse)
                .equilibrate(&model, &mut state, ws, &model.solver)
                .expect("equilibrium");
            state
        };
        let (state, sparse) = (solve(false, &mut ws), solve(true, &mut ws));
        for (a, b) in state.poses.iter().zip(&sparse.poses) {
            assert!((a.position - b.position).norm() < 1e-10, "dense and sparse statics differ");
        }
        evaluate(&model, &state, &mut ws, Tangents::None);
        // the deck has turned a little as its stay stretched: the slope where it came to rest
        let slope = state.poses[1].rotation * Vector3::y();
        let normal = state.poses[1].rotation * Vector3::z();
        let angle = slope.z.atan2(slope.y);
        assert!((angle - theta).abs() < 1e-2, "the deck stays near {theta} rad: {angle}");
        let weight = 2.0 * 9.81;
        let tether = model.cable_names.iter().position(|n| n == "tether").unwrap();
        let tension = ws.cables[tether].tension;
        assert!(
            (tension - weight * angle.sin()).abs() < 1e-9 * weight,
            "theta {theta}: tether {tension} N, m g sin = {}",
            weight * angle.sin()
        );
        let reports = tensegrity::report::joint_reports(&model, &state);
        let planar = reports.iter().find(|r| r.kind == "planar").expect("the planar joint's report");
        let force = Vector3::from(planar.force_n);
        assert!(
            (force.dot(&normal).abs() - weight * angle.cos()).abs() < 1e-9 * weight
                && (force - normal * force.dot(&normal)).norm() < 1e-9 * weight,
            "theta {theta}: joint force {force}, m g cos = {} along {normal}",
            weight * angle.cos()
        );
        // the sled sits on the deck's plane, where the stretched tether (L = L0 + T L0 / EA)
        // holds its nose: 0.7 m up the slope from the deck's middle, less the tether
        let gap = ws.points[model.point_id("sled.foot").unwrap().0].position
            - ws.points[model.point_id("deck.mid").unwrap().0].position;
        let tether_length = 0.65 + tension * 0.65 / 1e3;
        assert!(
            gap.dot(&normal).abs() < 1e-12 && (gap.dot(&slope) - (0.7 - tether_length)).abs() < 1e-9,
            "the sled rests at {gap}"
        );
    }
}

#[test]
fn careless_planar_joints_are_refused_naming_the_field() {
    let scene = |joint: &str| {
        format!(
            r#"
[[bodies]]
name = "deck"
kind = "rigid"
mass = 1.0
position = [0.0, 0.0, 0.0]
inertia = [0.1, 0.1, 0.1]
points = {{ pad = [0.0, 0.0, 0.1] }}
[[bodies]]
name = "sled"
kind = "rigid"
mass = 1.0
position = [0.5, 0.0, 0.1]
inertia = [0.1, 0.1, 0.1]
[[bodies]]
name = "bead"
kind = "node"
mass = 1.0
position = [0.0, 0.5, 0.1]
[[joints]]
{joint}
"#
        )
    };
    for (joint, field, reason) in [
        ("kind = \"planar\"\na = \"sled\"\nb = \"deck.pad\"", "joints[0].normal", "missing"),
        (
            "kind = \"planar\"\na = \"sled\"\nb = \"deck.pad\"\nnormal = [1.0, 0.0, 0.0]",
            "joints[0].a",
            "off the planar joint's plane",
        ),
        ("kind = \"planar\"\na = \"sled\"\nb = \"sled\"\nnormal = [0.0, 0.0, 1.0]", "joints[0].b", "same body"),
        (
            "kind = \"planar\"\na = \"bead\"\nb = \"deck.pad\"\nnormal = [0.0, 0.0, 1.0]",
            "joints[0].a",
            "a node has none",
        ),
        (
            "kind = \"planar\"\na = \"sled\"\nb = \"deck.pad\"\nnormal = [0.0, 0.0, 1.0]\nat = [0.5, 0.0, 0.1]",
            "joints[0].at",
            "two bodies",
        ),
        ("kind = \"planar\"\na = \"sled\"\nb = \"deck.pad\"\nnormal = [0.0, 0.0, 0.0]", "joints[0].normal", "zero"),
    ] {
        let err = tensegrity::scene::from_toml(&scene(joint), "careless.toml").expect_err(joint).to_string();
        assert!(
            err.contains("careless.toml") && err.contains(field) && err.contains(reason),
            "{joint}: {err}"
        );
    }
    // the same sled on the same plane, written well, is taken
    tensegrity::scene::from_toml(
        &scene("kind = \"planar\"\na = \"sled\"\nb = \"deck.pad\"\nnormal = [0.0, 0.0, 1.0]"),
        "careful.toml",
    )
    .expect("a planar joint between two bodies");
}
