//! Invariant: a hinge holds two bodies (or a body and the ground) on a common point and a common
//! axis, and a planar joint holds a body on a ground plane turning about its normal; each holds
//! exactly that and nothing else.
//! - The axis rows' Jacobian, the derivative of their reactions `d(Phi_q^T lambda)/dq` and their
//!   acceleration bias match finite differences, off the constraint manifold too (where the rows
//!   turn with the bodies).
//! - Statics: a door on a hinge held by a vertical cable at its tip carries its weight's moment
//!   about the horizontal normal to the hinge (`m g d`) in the hinge and its weight in the cable,
//!   the moment about the axis being zero.
//! - Dynamics: a rigid body with a skewed inertia tensor on a horizontal hinge swings as a
//!   physical pendulum of period `4 sqrt(I / (m g d)) K(sin(theta0 / 2))`, with the implicit
//!   integrator (dense and sparse Newton systems) and an explicit one (the joints' Schur
//!   complement, or the sparse joint system, and the axis rows' bias), its axis held to 1e-9.
//! - A rigid body on a tilted planar support slides at `g sin(theta)` and keeps spinning about the
//!   normal at its initial rate.
//! - A bar turns freely about its own axis: hinged across it, it keeps one axis row (its angle to
//!   the axis) and swings as the compound pendulum, `omega^2 = 3 g / (2 L)`, in one plane.
//! - Careless hinges are refused naming the field; a second hinge on the same axis is redundant;
//!   a hinge between two bars, and a plane turning with a bar that is not normal to it, are
//!   refused (a bar's free spin leaves them nothing to hold).

mod common;

use common::*;
use nalgebra::Vector3;
use tensegrity::evaluate::{evaluate, Tangents, Workspace};
use tensegrity::sim::{SimSettings, Simulator};
use tensegrity::solve::dynamics::Integrator;
use tensegrity::solve::linear::LinearBackend;
use tensegrity::solve::modes::natural_modes;
use tensegrity::solve::statics::StaticSolver;
use tensegrity::{Model, State};

/// A bar hinged to a skewed rigid box (axis oblique), the box on a tilted planar support, a
/// second bar hinged to the ground and a third hinged to the box with the bar as body `b`: every
/// kind of axis row (two rows; one, a bar's angle to the axis, on either side), turned away from
/// the coordinate axes.
fn mixed() -> Model {
    model_from_toml(
        r#"
gravity = [0.0, 0.0, -9.81]
[[bodies]]
name = "bar"
kind = "bar"
mass = 1.0
ends = [[0.1, 0.2, 0.3], [1.1, 0.7, 0.9]]
[[bodies]]
name = "box"
kind = "rigid"
mass = 2.0
position = [1.1, 0.7, 0.9]
rotation = [0.3, -0.2, 0.5]
inertia = [0.2, 0.25, 0.3, 0.01, -0.02, 0.015]
points = { knuckle = [0.0, 0.0, 0.0], foot = [0.1, -0.1, -0.3] }
[[bodies]]
name = "arm"
kind = "bar"
mass = 0.5
ends = [[-1.0, 0.0, 0.0], [-1.5, 0.4, 0.2]]
[[joints]]
kind = "hinge"
a = "bar.b"
b = "box.knuckle"
axis = [0.2, 0.9, -0.4]
[[joints]]
kind = "planar"
a = "box.foot"
normal = [0.3, -0.2, 1.0]
[[joints]]
kind = "hinge"
a = "arm.a"
axis = [0.0, 0.6, 0.8]
[[bodies]]
name = "rod"
kind = "bar"
mass = 0.4
ends = [[1.1, 0.7, 0.9], [1.5, 1.2, 0.4]]
[[joints]]
kind = "hinge"
a = "box.knuckle"
b = "rod.a"
axis = [0.5, -0.3, 0.8]
"#,
    )
}

/// A state of `mixed()` off its constraints (the joints' rows no longer zero) with velocities.
fn off_manifold(model: &Model) -> State {
    let start = State::initial(model);
    let mut s = moved(model, &start, &wiggle(model.dof_count, 1), 0.05);
    s.velocities = wiggle(model.dof_count, 2);
    s
}

#[test]
fn axis_rows_match_finite_differences() {
    let model = mixed();
    // 3 + 1 (hinge, a bar across its axis: its angle to it), 1 + 2 (planar), 3 + 1 (hinge to the
    // ground, a bar), 3 + 1 (hinge, the bar on side b)
    assert_eq!(model.constraint_count, 15);
    assert_eq!(model.joints.iter().filter(|j| j.alignment.is_some() && j.rows == 1).count(), 3);
    let start = State::initial(&model);
    let mut ws = Workspace::new(&model);
    evaluate(&model, &start, &mut ws, Tangents::None);
    assert!(ws.constraint.amax() < 1e-12, "the joints hold at the start: {}", ws.constraint.amax());

    let state = off_manifold(&model);
    evaluate(&model, &state, &mut ws, Tangents::None);
    assert!(ws.constraint.amax() > 1e-3, "the test state is off the manifold");
    let fd = check_joint_rows_by_finite_differences(&model, &state);
    for joint in model.joints.iter().filter(|j| j.alignment.is_some()) {
        let al = joint.alignment.unwrap();
        let bias =
            tensegrity::constraints::alignment_bias(&model, &state.poses, &state.velocities, joint, &al);
        for r in 0..joint.rows {
            let want = fd[joint.row_offset + r];
            assert!(
                (bias[r] - want).abs() < 1e-7 * (1.0 + want.abs()),
                "bias row {r}: {} against {want}",
                bias[r]
            );
        }
    }
}

/// A 3 kg door hinged at the origin about y, its centre of mass at (1, d, 0), held horizontal by
/// a stiff vertical cable from its tip (1, 0, 0) to (1, 0, 2).
fn door(d: f64, kind: &str) -> Model {
    model_from_toml(&format!(
        r#"
gravity = [0.0, 0.0, -9.81]
[[bodies]]
name = "door"
kind = "rigid"
mass = 3.0
position = [1.0, {d}, 0.0]
inertia = [0.4, 0.3, 0.6]
points = {{ hinge = [-1.0, {md}, 0.0], tip = [0.0, {md}, 0.0] }}
[[bodies]]
name = "hook"
kind = "fixed"
position = [1.0, 0.0, 2.0]
[[cables]]
name = "stay"
route = ["door.tip", "hook"]
ea = 1e7
rest_length = 2.0
[[joints]]
kind = "{kind}"
a = "door.hinge"
{axis}
"#,
        md = -d,
        axis = if kind == "hinge" { "axis = [0.0, 1.0, 0.0]" } else { "" }
    ))
}

#[test]
fn a_door_on_a_hinge_carries_the_moment_its_cable_cannot() {
    let (m, g, d) = (3.0, 9.81, 0.3);
    let model = door(d, "hinge");
    let mut state = State::initial(&model);
    let mut ws = Workspace::new(&model);
    let report = StaticSolver::new(&model)
        .equilibrate(&model, &mut state, &mut ws, &model.solver)
        .expect("equilibrium");
    assert_eq!(report.negative_modes, 0, "{}", report.stability_words());
    let joints = tensegrity::report::joint_reports(&model, &state);
    assert_eq!(joints.len(), 1, "one report per scene joint");
    assert_eq!(joints[0].kind, "hinge");
    let moment = Vector3::from(joints[0].moment_nm);
    let force = Vector3::from(joints[0].force_n);
    let tension = ws.cables[0].tension;
    assert!((tension - m * g).abs() < 1e-8 * m * g, "the cable carries the weight: {tension}");
    assert!(
        (moment.x - m * g * d).abs() < 1e-8 * m * g * d,
        "moment about x {} against {}",
        moment.x,
        m * g * d
    );
    assert!(moment.y.abs() < 1e-9 && moment.z.abs() < 1e-6, "no moment about the axis: {moment}");
    assert!(force.norm() < 1e-6, "nothing left for the hinge's point: {force}");
    // the same door on a pin (a ball joint to the ground) cannot hold that moment: it turns
    // about x until its centre of mass is under the hinge-tip line
    let pinned = door(d, "pin");
    let mut s = State::initial(&pinned);
    let mut w = Workspace::new(&pinned);
    let r = StaticSolver::new(&pinned)
        .equilibrate(&pinned, &mut s, &mut w, &pinned.solver)
        .expect("pinned equilibrium");
    assert_eq!(r.negative_modes, 0, "{}", r.stability_words());
    let c = s.poses[0].position;
    assert!(c.y.abs() < 1e-6 && c.z < -0.29, "pinned, the door hangs under the hinge-tip line: {c}");
}

/// `K(k)`, the complete elliptic integral of the first kind (modulus `k`), by the
/// arithmetic-geometric mean.
fn elliptic_k(k: f64) -> f64 {
    let (mut a, mut b) = (1.0, (1.0 - k * k).sqrt());
    for _ in 0..30 {
        (a, b) = (0.5 * (a + b), (a * b).sqrt());
    }
    std::f64::consts::PI / (2.0 * a)
}

/// A 2 kg body with a skewed inertia tensor on a hinge about world y through the origin, its
/// centre of mass `d` = 0.4 m from the axis, released at `theta0` from hanging straight down.
fn pendulum(theta0: f64) -> Model {
    let d = 0.4;
    let c = [d * theta0.sin(), 0.0, -d * theta0.cos()];
    // the hinge point in the body frame: the body is turned by `rotation`
    let rot = nalgebra::Rotation3::new(Vector3::new(0.2, -0.3, 0.4));
    let local = rot.inverse() * -Vector3::from(c);
    model_from_toml(&format!(
        r#"
gravity = [0.0, 0.0, -9.81]
[[bodies]]
name = "bob"
kind = "rigid"
mass = 2.0
position = [{}, {}, {}]
rotation = [0.2, -0.3, 0.4]
inertia = [0.05, 0.06, 0.04, 0.005, -0.003, 0.004]
points = {{ pivot = [{}, {}, {}] }}
[[joints]]
kind = "hinge"
a = "bob.pivot"
axis = [0.0, 1.0, 0.0]
"#,
        c[0], c[1], c[2], local.x, local.y, local.z
    ))
}

#[test]
fn a_body_on_a_hinge_swings_as_a_physical_pendulum() {
    let theta0: f64 = 0.3;
    let (m, g, d) = (2.0, 9.81, 0.4);
    let model = pendulum(theta0);
    // the moment of inertia about the axis: the body's, turned to the world, plus m d^2
    let body = &model.bodies[0];
    let r = body.initial_pose.rotation.to_rotation_matrix().into_inner();
    let i_world = r * body.inertia * r.transpose();
    let i_axis = i_world[(1, 1)] + m * d * d;
    let period = 4.0 * (i_axis / (m * g * d)).sqrt() * elliptic_k((theta0 / 2.0).sin());
    let cases = [
        (Integrator::GeneralizedAlpha { rho_inf: 0.9 }, LinearBackend::Dense, 1e-3, 2e-5),
        (Integrator::GeneralizedAlpha { rho_inf: 0.9 }, LinearBackend::Sparse, 1e-3, 2e-5),
        (Integrator::Rk4, LinearBackend::Auto, 1e-3, 2e-5),
        (Integrator::Rk4, LinearBackend::Sparse, 1e-3, 2e-5),
    ];
    for (integrator, linear, dt, tolerance) in cases {
        let settings = SimSettings { dt, integrator, linear, ..Default::default() };
        let mut sim = Simulator::new(model.clone(), settings).unwrap();
        // the angle from hanging: x of the centre of mass; its first upward zero crossing after
        // the start is at a quarter period, the next downward one at three quarters
        let mut crossings = Vec::new();
        let mut last = (0.0, sim.state().poses[0].position.x);
        let mut worst_axis: f64 = 0.0;
        while crossings.len() < 2 && last.0 < 3.0 * period {
            sim.step().unwrap();
            let t = sim.state().time;
            let x = sim.state().poses[0].position.x;
            if last.1 * x < 0.0 {
                crossings.push(last.0 + (t - last.0) * last.1 / (last.1 - x));
            }
            last = (t, x);
            let ws = sim.workspace();
            worst_axis = worst_axis.max(ws.constraint.amax());
            let c = sim.state().poses[0].position;
            assert!(c.y.abs() < 1e-9, "{integrator:?}: the centre left the swing plane by {}", c.y);
        }
        assert_eq!(crossings.len(), 2, "{integrator:?}: it swings");
        let measured = 2.0 * (crossings[1] - crossings[0]);
        assert!(
            (measured - period).abs() < tolerance * period,
            "{integrator:?}: period {measured} s against {period} s"
        );
        assert!(worst_axis < 1e-9, "{integrator:?}: the joint drifted by {worst_axis}");
    }
}

#[test]
fn a_body_on_a_tilted_planar_support_slides_and_keeps_its_spin() {
    let theta: f64 = 0.35;
    let n = Vector3::new(theta.sin(), 0.0, theta.cos());
    let model = model_from_toml(&format!(
        r#"
gravity = [0.0, 0.0, -9.81]
[[bodies]]
name = "puck"
kind = "rigid"
mass = 1.2
position = [0.0, 0.0, 0.0]
rotation = [0.1, 0.4, -0.2]
inertia = [0.03, 0.035, 0.04, 0.002, 0.001, -0.003]
points = {{ centre = [0.0, 0.0, 0.0] }}
[[joints]]
kind = "planar"
a = "puck.centre"
normal = [{}, {}, {}]
"#,
        n.x, n.y, n.z
    ));
    let spin = 3.0;
    for (integrator, linear, tolerance) in [
        (Integrator::GeneralizedAlpha { rho_inf: 0.9 }, LinearBackend::Dense, 1e-6),
        (Integrator::GeneralizedAlpha { rho_inf: 0.9 }, LinearBackend::Sparse, 1e-6),
        (Integrator::Rk4, LinearBackend::Auto, 1e-6),
    ] {
        let mut state = State::initial(&model);
        let r = state.poses[0].rotation;
        let w_body = r.inverse() * (n * spin);
        for k in 0..3 {
            state.velocities[3 + k] = w_body[k];
        }
        let settings = SimSettings { dt: 1e-3, integrator, linear, ..Default::default() };
        let mut sim = Simulator::from_state(model.clone(), state, settings).unwrap();
        for _ in 0..500 {
            sim.step().unwrap();
        }
        let s = sim.state();
        let x = s.poses[0].position;
        let downhill = Vector3::new(theta.cos(), 0.0, -theta.sin());
        let want = 0.5 * 9.81 * theta.sin() * 0.5f64.powi(2);
        assert!(n.dot(&x).abs() < 1e-9, "{integrator:?}: off the plane by {}", n.dot(&x));
        let along = downhill.dot(&x);
        assert!((along - want).abs() < tolerance * want, "{integrator:?}: slid {along} m against {want}");
        let omega = s.poses[0].rotation * Vector3::new(s.velocities[3], s.velocities[4], s.velocities[5]);
        assert!((omega - n * spin).norm() < 1e-6 * spin, "{integrator:?}: spin {omega} against {}", n * spin);
    }
}

#[test]
fn careless_hinges_are_refused_naming_the_field() {
    // "bar" is a rigid body here: a bar's own axis rows are tested below
    let scene = |joint: &str| {
        format!(
            r#"
[[bodies]]
name = "bar"
kind = "rigid"
mass = 1.0
position = [1.0, 0.0, 0.0]
inertia = [0.01, 0.3, 0.3]
points = {{ b = [1.0, 0.0, 0.0], c = [1.0, 0.0, 1.0] }}
[[bodies]]
name = "box"
kind = "rigid"
mass = 1.0
position = [2.0, 0.0, 0.0]
inertia = [0.1, 0.1, 0.1]
points = {{ p = [0.0, 0.0, 0.0], q = [1.0, 0.0, 0.0], r = [0.0, 0.0, 1.0] }}
[[bodies]]
name = "n"
kind = "node"
mass = 1.0
position = [3.0, 0.0, 0.0]
[[joints]]
kind = "hinge"
a = "bar.b"
b = "box.p"
axis = [0.0, 0.0, 1.0]
[[joints]]
{joint}
"#
        )
    };
    let cases = [
        // the same axis again, at another point of it: everything it holds is held already
        (
            "kind = \"hinge\"\na = \"box.r\"\nb = \"bar.c\"\naxis = [0.0, 0.0, 1.0]",
            "joints[1].a",
            "redundant",
        ),
        ("kind = \"hinge\"\na = \"box.q\"", "joints[1].axis", "missing"),
        ("kind = \"hinge\"\na = \"box.q\"\naxis = [0.0, 0.0, 0.0]", "joints[1].axis", "zero"),
        (
            "kind = \"hinge\"\na = \"box.q\"\nb = \"n\"\naxis = [0.0, 0.0, 1.0]",
            "joints[1].a",
            "a node has none",
        ),
        ("kind = \"pin\"\na = \"box.q\"\naxis = [0.0, 0.0, 1.0]", "joints[1].axis", "only a hinge"),
        // a planar joint may join two bodies, but a node has no orientation to hold
        (
            "kind = \"planar\"\na = \"box.q\"\nb = \"n\"\nnormal = [0.0, 0.0, 1.0]",
            "joints[1].a",
            "a node has none",
        ),
        (
            "kind = \"slider\"\na = \"box.q\"\nb = \"n\"\nnormal = [0.0, 0.0, 1.0]",
            "joints[1].b",
            "slider holds one point to the ground",
        ),
        ("kind = \"planar\"\na = \"box.q\"", "joints[1].normal", "missing"),
        ("kind = \"planar\"\na = \"n\"\nnormal = [0.0, 0.0, 1.0]", "joints[1].a", "a node has none"),
    ];
    for (joint, field, words) in cases {
        let text = scene(joint);
        let err = tensegrity::scene::from_toml(&text, "hinge.toml").expect_err(joint).to_string();
        assert!(err.contains(field) && err.contains(words), "{joint}: {err}");
    }
    // a planar scene turns about z only
    let planar = r#"
planar = true
[[bodies]]
name = "bar"
kind = "bar"
mass = 1.0
ends = [[0.0, 0.0, 0.0], [2.0, 0.0, 0.0]]
[[joints]]
kind = "hinge"
a = "bar.a"
axis = [1.0, 0.0, 0.0]
"#;
    let err =
        tensegrity::scene::from_toml(planar, "p.toml").expect_err("axis x in a planar scene").to_string();
    assert!(err.contains("joints[0].axis") && err.contains("about z only"), "{err}");
}

#[test]
fn a_bar_hinged_across_its_axis_swings_as_the_compound_pendulum_and_keeps_no_spin_row() {
    // a 2 m, 1.5 kg bar hinged at one end about a horizontal axis normal to it: one axis row (its
    // angle to the axis); it hangs straight down and swings in one plane only, at the compound
    // pendulum's omega^2 = 3 g / (2 L) (a ball joint would give two such modes)
    let (length, g) = (2.0, 9.81);
    let model = model_from_toml(&format!(
        "gravity = [0.0, 0.0, -{g}]\n[[bodies]]\nname = \"bar\"\nkind = \"bar\"\nmass = 1.5\nends = [[0.0, 0.0, 0.0], [{length}, 0.0, 0.0]]\n[[joints]]\nkind = \"hinge\"\na = \"bar.a\"\naxis = [0.0, 1.0, 0.0]\n"
    ));
    assert_eq!(model.constraint_count, 4, "3 point rows and the bar's angle to the axis");
    let mut state = State::initial(&model);
    let mut ws = Workspace::new(&model);
    let report = StaticSolver::new(&model).equilibrate(&model, &mut state, &mut ws, &model.solver).unwrap();
    assert!(report.stable, "{}", report.stability_words());
    evaluate(&model, &state, &mut ws, Tangents::None);
    let tip = ws.points[model.point_id("bar.b").unwrap().0].position;
    assert!((tip - Vector3::new(0.0, 0.0, -length)).norm() < 1e-9, "hangs straight down: {tip}");
    let modes = natural_modes(&model, &state).expect("modes");
    let swinging: Vec<f64> = modes.iter().filter(|m| !m.zero).map(|m| m.omega_squared).collect();
    let want = 3.0 * g / (2.0 * length);
    assert_eq!(swinging.len(), 1, "one swinging mode: {swinging:?}");
    assert!((swinging[0] - want).abs() < 1e-9 * want, "omega^2 {} against {want}", swinging[0]);
}

#[test]
fn turning_joints_a_bar_cannot_hold_are_refused_naming_the_field() {
    let two_bars = r#"
[[bodies]]
name = "left"
kind = "bar"
mass = 1.0
ends = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]]
[[bodies]]
name = "right"
kind = "bar"
mass = 1.0
ends = [[1.0, 0.0, 0.0], [2.0, 0.0, 1.0]]
[[joints]]
kind = "hinge"
a = "left.b"
b = "right.a"
axis = [0.0, 1.0, 0.0]
"#;
    let err = tensegrity::scene::from_toml(two_bars, "bars.toml").expect_err("two bars hinged").to_string();
    assert!(err.contains("bars.toml") && err.contains("joints[0].b") && err.contains("ball joint"), "{err}");
    // a plane through a bar's point turns with the bar's (free) spin unless it is normal to it
    let plane_on_bar = r#"
[[bodies]]
name = "bar"
kind = "bar"
mass = 1.0
ends = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]]
[[bodies]]
name = "box"
kind = "rigid"
mass = 1.0
position = [0.5, 0.0, 0.3]
inertia = [0.1, 0.1, 0.1]
points = { foot = [0.0, 0.0, -0.3] }
[[joints]]
kind = "planar"
a = "box.foot"
b = "bar"
normal = [0.0, 0.0, 1.0]
"#;
    let err =
        tensegrity::scene::from_toml(plane_on_bar, "plane.toml").expect_err("plane on a bar").to_string();
    assert!(err.contains("joints[0].normal") && err.contains("normal to the bar"), "{err}");
    // a plane normal to the bar is held: it is the bar's own direction
    let along = plane_on_bar.replace("normal = [0.0, 0.0, 1.0]", "normal = [1.0, 0.0, 0.0]");
    tensegrity::scene::from_toml(&along, "plane.toml").expect("a plane normal to the bar");
}
