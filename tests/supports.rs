//! Invariant: roller supports (a point held on a world line) and slider supports (a point held
//! on a world plane) hold exactly the directions they name and nothing else.
//! - A beam on a pin and a roller carries the textbook reactions `W/2 + P (L - x)/L` and
//!   `W/2 + P x/L`, the roller none along its line, in a planar and a 3-D scene.
//! - A node on a slider finds the equilibrium under its anchor, off the plane by nothing, the
//!   plane carrying what the cable leaves of its weight.
//! - A node released on a frictionless incline (a slider) slides down at `g sin(theta)`, with the
//!   implicit integrator (dense and sparse Newton systems) and the explicit one (which solves the
//!   joints through their Schur complement); statics agrees dense and sparse.
//! - The analytic Jacobian of the supports' rows matches finite differences.
//! - Redundant supports are refused naming the joint and the ones it repeats; careless fields are
//!   refused naming the field.

mod common;

use common::*;
use tensegrity::evaluate::{evaluate, Tangents, Workspace};
use tensegrity::sim::{SimSettings, Simulator};
use tensegrity::solve::dynamics::Integrator;
use tensegrity::solve::linear::LinearBackend;
use tensegrity::solve::statics::StaticSolver;
use tensegrity::{Model, State};

fn equilibrium(model: &Model) -> State {
    equilibrium_with(model, false)
}

/// Statics with the dense or the sparse (large-scene) Newton systems.
fn equilibrium_with(model: &Model, sparse: bool) -> State {
    let mut state = State::initial(model);
    let mut ws = Workspace::new(model);
    let report = StaticSolver::new(model)
        .with_sparse_kkt(model, sparse)
        .equilibrate(model, &mut state, &mut ws, &model.solver)
        .expect("equilibrium");
    assert_eq!(report.negative_modes, 0, "{}", report.stability_words());
    state
}

/// The world force joint `j`'s rows carry (`D^T lambda`): what holds the body is its negative.
fn support_force(model: &Model, state: &State, j: usize) -> nalgebra::Vector3<f64> {
    tensegrity::constraints::joint_reaction(model, &state.poses, &model.joints[j], &state.multipliers)
}

/// A beam of length 4 m and 10 kg from (0,0,0) to (4,0,0), pinned at `a`, on a roller along x at
/// `b`, carrying a 6 kg node joined at 1 m from `a`.
fn beam(planar: bool) -> Model {
    model_from_toml(&format!(
        r#"
planar = {planar}
gravity = [0.0, -9.81, 0.0]
[[bodies]]
name = "beam"
kind = "bar"
mass = 10.0
ends = [[0.0, 0.0, 0.0], [4.0, 0.0, 0.0]]
points = {{ load = 0.25 }}
[[bodies]]
name = "load"
kind = "node"
mass = 6.0
position = [1.0, 0.0, 0.0]
[[joints]]
kind = "pin"
a = "beam.a"
[[joints]]
kind = "roller"
a = "beam.b"
direction = [1.0, 0.0, 0.0]
[[joints]]
kind = "ball"
a = "load"
b = "beam.load"
"#
    ))
}

#[test]
fn a_beam_on_a_pin_and_a_roller_carries_the_textbook_reactions() {
    let (w, p, l, x) = (10.0 * 9.81, 6.0 * 9.81, 4.0, 1.0);
    for (planar, sparse) in [(true, false), (false, false), (true, true), (false, true)] {
        let model = beam(planar);
        assert_eq!(model.joints[1].rows, if planar { 1 } else { 2 });
        let state = equilibrium_with(&model, sparse);
        // the supports hold the beam up: their forces on it are the negatives of what they carry
        let (pin, roller) = (-support_force(&model, &state, 0), -support_force(&model, &state, 1));
        let (ra, rb) = (w / 2.0 + p * (l - x) / l, w / 2.0 + p * x / l);
        assert!((pin.y - ra).abs() < 1e-9 * ra, "planar {planar}: pin {pin} against {ra}");
        assert!((roller.y - rb).abs() < 1e-9 * rb, "planar {planar}: roller {roller} against {rb}");
        assert!(roller.x.abs() < 1e-12 && pin.x.abs() < 1e-9 * ra, "no horizontal load: {pin} {roller}");
    }
}

#[test]
fn a_node_on_a_slider_comes_to_rest_under_its_anchor() {
    // a 2 kg node on the plane z = 0 (slider), a cable of EA 1e3 N and rest length 0.9 m up to
    // an anchor at (1, 0, 1): it slides to (1, 0, 0), where the cable (L = 1 m) pulls 111.1 N up
    let model = model_from_toml(
        r#"
gravity = [0.0, 0.0, -9.81]
[[bodies]]
name = "ground"
kind = "fixed"
points = { hook = [1.0, 0.0, 1.0] }
[[bodies]]
name = "puck"
kind = "node"
mass = 2.0
position = [0.3, 0.4, 0.0]
[[joints]]
kind = "slider"
a = "puck"
normal = [0.0, 0.0, 2.0]
[[cables]]
name = "line"
route = ["ground.hook", "puck"]
ea = 1e3
rest_length = 0.9
"#,
    );
    let state = equilibrium(&model);
    let at = state.poses[1].position;
    assert!((at - nalgebra::Vector3::new(1.0, 0.0, 0.0)).norm() < 1e-10, "{at}");
    let tension = 1e3 * (1.0 - 0.9) / 0.9;
    let plane = -support_force(&model, &state, 0);
    // the plane pushes down: the cable pulls harder than the weight
    assert!((plane.z - (2.0 * 9.81 - tension)).abs() < 1e-9 * tension, "{plane}");
    assert!(plane.x.abs() + plane.y.abs() < 1e-12, "a frictionless plane holds nothing in itself: {plane}");
}

#[test]
fn a_node_slides_down_a_frictionless_incline_at_g_sin_theta() {
    let theta: f64 = 0.4;
    let normal = [-theta.sin(), 0.0, theta.cos()];
    let text = format!(
        r#"
gravity = [0.0, 0.0, -9.81]
[[bodies]]
name = "block"
kind = "node"
mass = 1.5
position = [0.0, 0.0, 0.0]
[[joints]]
kind = "slider"
a = "block"
normal = [{}, {}, {}]
"#,
        normal[0], normal[1], normal[2]
    );
    let cases = [
        (Integrator::GeneralizedAlpha { rho_inf: 0.8 }, LinearBackend::Dense),
        (Integrator::GeneralizedAlpha { rho_inf: 0.8 }, LinearBackend::Sparse),
        (Integrator::SymplecticEuler, LinearBackend::Auto),
    ];
    for (integrator, linear) in cases {
        let model = model_from_toml(&text);
        let settings = SimSettings { dt: 1e-3, integrator, linear, ..Default::default() };
        let mut sim = Simulator::new(model, settings).unwrap();
        for _ in 0..500 {
            sim.step().unwrap();
        }
        let x = sim.state().poses[0].position;
        let down = nalgebra::Vector3::new(-theta.cos(), 0.0, -theta.sin()); // along the plane, downhill
        let s = 0.5 * 9.81 * theta.sin() * 0.5f64.powi(2);
        let n = nalgebra::Vector3::from(normal);
        assert!(n.dot(&x).abs() < 1e-9, "{integrator:?}: off the plane by {}", n.dot(&x));
        let along = down.dot(&x);
        // symplectic Euler's position lags by h v / 2 at constant acceleration
        let tolerance = if matches!(integrator, Integrator::SymplecticEuler) { 3e-3 } else { 1e-6 };
        assert!((along - s).abs() < tolerance * s, "{integrator:?}: slid {along} m against {s}");
        assert!(x.y.abs() < 1e-12, "{integrator:?}: drifted sideways {}", x.y);
    }
}

#[test]
fn support_rows_match_finite_differences() {
    // a bar on a tilted roller and a rigid body on a tilted slider, turned away from the axes
    let model = model_from_toml(
        r#"
[[bodies]]
name = "bar"
kind = "bar"
mass = 1.0
ends = [[0.1, 0.2, 0.3], [1.1, 0.7, 0.9]]
[[bodies]]
name = "box"
kind = "rigid"
mass = 2.0
position = [2.0, 1.0, 0.5]
rotation = [0.3, -0.2, 0.5]
inertia = [0.1, 0.2, 0.3]
points = { corner = [0.2, -0.1, 0.3] }
[[joints]]
kind = "roller"
a = "bar.b"
direction = [0.3, -1.0, 0.4]
[[joints]]
kind = "slider"
a = "box.corner"
normal = [0.5, 0.5, -1.0]
"#,
    );
    let state = State::initial(&model);
    let mut ws = Workspace::new(&model);
    evaluate(&model, &state, &mut ws, Tangents::None);
    assert_eq!(model.constraint_count, 3);
    assert!(ws.constraint.amax() < 1e-12, "the supports hold at the start");
    let h = 1e-6;
    for j in 0..model.dof_count {
        let mut wp = Workspace::new(&model);
        evaluate(&model, &perturbed(&model, &state, j, h), &mut wp, Tangents::None);
        let mut wm = Workspace::new(&model);
        evaluate(&model, &perturbed(&model, &state, j, -h), &mut wm, Tangents::None);
        let fd = (&wp.constraint - &wm.constraint) / (2.0 * h);
        let analytic = ws.constraint_jacobian.column(j);
        assert!((fd - analytic).amax() < 1e-8, "column {j}");
    }
}

#[test]
fn redundant_and_careless_supports_are_refused_naming_the_field() {
    let bar = r#"
[[bodies]]
name = "bar"
kind = "bar"
mass = 1.0
ends = [[0.0, 0.0, 0.0], [2.0, 0.0, 0.0]]
[[joints]]
kind = "pin"
a = "bar.a"
"#;
    let cases = [
        // the bar's length already fixes b's distance from the pin: holding b along x repeats it
        (
            "kind = \"roller\"\na = \"bar.b\"\ndirection = [0.0, 1.0, 0.0]",
            "joints[1].a",
            "redundant: 1 of its 2 equations is implied by joints[0]",
        ),
        (
            "kind = \"slider\"\na = \"bar.b\"\nnormal = [1.0, 0.0, 0.0]",
            "joints[1].a",
            "redundant: its equation is implied by joints[0]",
        ),
        ("kind = \"roller\"\na = \"bar.b\"", "joints[1].direction", "missing"),
        ("kind = \"roller\"\na = \"bar.b\"\ndirection = [0.0, 0.0, 0.0]", "joints[1].direction", "zero"),
        (
            "kind = \"slider\"\na = \"bar.b\"\nnormal = [0.0, 0.0, 1.0]\ndirection = [1.0, 0.0, 0.0]",
            "joints[1].direction",
            "only a roller",
        ),
        ("kind = \"pin\"\na = \"bar.b\"\nnormal = [0.0, 0.0, 1.0]", "joints[1].normal", "only a slider"),
        (
            "kind = \"slider\"\na = \"bar.b\"\nnormal = [0.0, 0.0, 1.0]\nat = [0.0, 0.0, 0.5]",
            "joints[1].a",
            "off the slider's plane",
        ),
        (
            "kind = \"roller\"\na = \"bar.b\"\ndirection = [1.0, 0.0, 0.0]\nat = [0.0, 0.3, 0.0]",
            "joints[1].a",
            "off the roller's line",
        ),
        (
            "kind = \"roller\"\na = \"bar.b\"\nb = \"bar.a\"\ndirection = [1.0, 0.0, 0.0]",
            "joints[1].b",
            "holds one point to the ground",
        ),
    ];
    for (joint, field, reason) in cases {
        let text = format!("{bar}[[joints]]\n{joint}\n");
        let err = tensegrity::scene::from_toml(&text, "careless.toml").expect_err(joint).to_string();
        assert!(
            err.contains("careless.toml") && err.contains(field) && err.contains(reason),
            "{joint}: {err}"
        );
    }
    // a planar slider's normal lies in the plane
    let planar = "planar = true\n[[bodies]]\nname = \"n\"\nkind = \"node\"\nmass = 1.0\nposition = [0.0, 0.0, 0.0]\n[[joints]]\nkind = \"slider\"\na = \"n\"\nnormal = [0.0, 1.0, 1.0]\n";
    let err = tensegrity::scene::from_toml(planar, "planar.toml").expect_err("z normal").to_string();
    assert!(err.contains("joints[0].normal") && err.contains("z must be 0"), "{err}");
}
