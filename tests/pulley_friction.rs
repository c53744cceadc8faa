//! Pulley friction (`tensegrity::forces::pulley`): the return map's tangents against finite
//! differences in stick and slip, the capstan closed forms (an Atwood machine over one pulley, a
//! block pulled over a table edge, a cable over five pulleys in statics), the energy account,
//! and `pulley_friction = 0` being the frictionless element.

mod common;

use common::{fd_damping, fd_stiffness, model_from_toml, rel_err};
use proptest::prelude::*;
use tensegrity::evaluate::{evaluate, evaluate_forces, Tangents, Workspace};
use tensegrity::forces::pulley::PulleyState;
use tensegrity::model::Model;
use tensegrity::sim::{SimSettings, Simulator};
use tensegrity::solve::dynamics::Integrator;
use tensegrity::solve::statics::StaticSolver;
use tensegrity::state::State;

const G: f64 = 9.81;

/// An Atwood machine: `m1` and `m2` (kg) hang on one cable over a pulley with friction `mu`,
/// both straight below it (wrap angle pi), the rope taut at zero tension at the start.
fn atwood(m1: f64, m2: f64, mu: f64) -> Model {
    model_from_toml(&atwood_text(m1, m2, mu, "ea = 1e5\ndamping_ratio = 0.5"))
}

/// The Atwood machine's scene text (`atwood`), its rope's `ea` and damping given by `rope`.
fn atwood_text(m1: f64, m2: f64, mu: f64, rope: &str) -> String {
    format!(
        r#"
gravity = [0.0, 0.0, -9.81]
[[bodies]]
name = "ceiling"
kind = "fixed"
points = {{ wheel = [0.0, 0.0, 0.0] }}
[[bodies]]
name = "m1"
kind = "node"
mass = {m1}
position = [0.0, 0.0, -1.0]
[[bodies]]
name = "m2"
kind = "node"
mass = {m2}
position = [0.0, 0.0, -1.5]
[[cables]]
name = "rope"
route = ["m1", "ceiling.wheel", "m2"]
{rope}
rest_length = 2.5
pulley_friction = {mu}
"#
    )
}

/// A 1 kg block on a frictionless table (a slider) pulled by a hanging 1 kg mass over the
/// table's edge (wrap angle pi/2), pulley friction `mu`.
fn table_edge(mu: f64) -> Model {
    model_from_toml(&format!(
        r#"
gravity = [0.0, 0.0, -9.81]
[[bodies]]
name = "table"
kind = "fixed"
points = {{ edge = [0.0, 0.0, 0.0] }}
[[bodies]]
name = "block"
kind = "node"
mass = 1.0
position = [-1.0, 0.0, 0.0]
[[bodies]]
name = "weight"
kind = "node"
mass = 1.0
position = [0.0, 0.0, -1.0]
[[joints]]
kind = "slider"
a = "block"
normal = [0.0, 0.0, 1.0]
[[cables]]
name = "rope"
route = ["block", "table.edge", "weight"]
ea = 1e5
damping_ratio = 0.5
rest_length = 2.0
pulley_friction = {mu}
"#
    ))
}

fn run(model: Model, integrator: Integrator, dt: f64, until: f64) -> Simulator {
    let settings = SimSettings { dt, integrator, ..SimSettings::default() };
    let mut sim = Simulator::new(model, settings).unwrap();
    while sim.state().time < until - 0.5 * dt {
        sim.step().unwrap();
    }
    sim
}

/// Vertical velocity of point `name` at the simulator's state, m/s.
fn point_velocity(sim: &Simulator, name: &str) -> nalgebra::Vector3<f64> {
    let id = sim.model().point_id(name).unwrap();
    sim.workspace().points[id.0].velocity
}

/// The steady acceleration of point `name` between `t0` and `t1` (s), m/s^2, and the
/// simulator at `t1`.
fn acceleration(
    model: Model,
    integrator: Integrator,
    dt: f64,
    name: &str,
    (t0, t1): (f64, f64),
) -> (f64, Simulator) {
    let mut sim = run(model, integrator, dt, t0);
    let v0 = point_velocity(&sim, name);
    while sim.state().time < t1 - 0.5 * dt {
        sim.step().unwrap();
    }
    let v1 = point_velocity(&sim, name);
    ((v1 - v0).norm() / (t1 - t0), sim)
}

#[test]
fn an_atwood_machine_slips_at_the_capstan_ratio_and_holds_past_it() {
    let ga = Integrator::GeneralizedAlpha { rho_inf: 0.8 };
    for (mu, a_exact, tensions) in [(0.1, 3.661858, Some((18.444426, 13.471858))), (0.2, 2.265193, None)] {
        for integrator in [ga, Integrator::Rk4, Integrator::DormandPrince, Integrator::SymplecticEuler] {
            let (a, sim) = acceleration(atwood(3.0, 1.0, mu), integrator, 2e-4, "m2", (0.2, 0.4));
            assert!((a - a_exact).abs() < 1e-4 * a_exact, "mu {mu} {integrator:?}: a = {a}, exact {a_exact}");
            let f = &sim.workspace().friction;
            assert_eq!(f.states[0], PulleyState::SlipTowardStart, "the heavy side pulls the rope its way");
            let ratio = f.tensions[0] / f.tensions[1];
            assert!((ratio - (mu * std::f64::consts::PI).exp()).abs() < 1e-9, "ratio {ratio}");
            if let Some((t1, t2)) = tensions {
                assert!((f.tensions[0] - t1).abs() < 1e-4 * t1, "T1 {}", f.tensions[0]);
                assert!((f.tensions[1] - t2).abs() < 1e-4 * t2, "T2 {}", f.tensions[1]);
            }
            assert!(f.slip_speeds[0] > 0.0, "material runs toward the heavy side");
        }
    }
    // the threshold: ln 3 / pi = 0.349699; above it the machine holds (once the start's
    // transient, where both sides pick up tension from zero, has settled)
    let mut sim = run(atwood(3.0, 1.0, 0.4), ga, 2e-4, 0.3);
    let settled = sim.state().segment_rest_lengths.clone();
    while sim.state().time < 0.5 {
        sim.step().unwrap();
    }
    let v = point_velocity(&sim, "m2").norm();
    assert!(v < 1e-6, "held at mu 0.4, moving at {v} m/s");
    let f = &sim.workspace().friction;
    assert_eq!(f.states[0], PulleyState::Stick);
    assert_eq!(sim.state().segment_rest_lengths, settled, "no material crossed a sticking pulley");
    let ratio = f.tensions[0] / f.tensions[1];
    assert!((ratio - 3.0).abs() < 1e-6, "a held Atwood machine carries each weight: ratio {ratio}");
}

#[test]
fn a_block_pulled_over_a_table_edge_accelerates_as_the_capstan_says() {
    let ga = Integrator::GeneralizedAlpha { rho_inf: 0.8 };
    for (mu, a_exact) in [(0.2, 4.140799), (0.5, 3.072076)] {
        let (a, _) = acceleration(table_edge(mu), ga, 2e-4, "block", (0.15, 0.3));
        assert!((a - a_exact).abs() < 1e-4 * a_exact, "mu {mu}: a = {a}, exact {a_exact}");
    }
}

#[test]
fn the_energy_account_books_friction() {
    let ga = Integrator::GeneralizedAlpha { rho_inf: 1.0 };
    let sim = run(atwood(3.0, 1.0, 0.1), ga, 1e-4, 0.3);
    let e = sim.energy();
    // over 0.3 s the rope slips ~0.16 m at T_high - T_low ~ 5 N: ~0.8 J
    assert!(e.friction_loss > 0.5, "friction loss {}", e.friction_loss);
    let unexplained = e.numerical_loss().abs();
    assert!(
        unexplained < 1e-3 * e.friction_loss,
        "unexplained {unexplained} J of {} J friction",
        e.friction_loss
    );
    // step by step, friction's power is (T_high - T_low) times the slip speed, to the strain
    let mut sim = sim;
    for _ in 0..100 {
        let before = sim.energy().friction_loss;
        sim.step().unwrap();
        let power = (sim.energy().friction_loss - before) / 1e-4;
        let f = &sim.workspace().friction;
        let capstan = (f.tensions[0] - f.tensions[1]) * f.slip_speeds[0];
        assert!(capstan > 0.0);
        assert!((power - capstan).abs() < 1e-3 * capstan, "friction power {power} W, capstan {capstan} W");
    }
}

/// A cable from an anchor over five fixed pulleys, each turning it through 90 degrees, down to
/// a hanging mass.
fn five_pulleys(mu: f64) -> Model {
    model_from_toml(&format!(
        r#"
gravity = [0.0, 0.0, -9.81]
[[bodies]]
name = "frame"
kind = "fixed"
points = {{ anchor = [-1.0, 0.0, 0.0], p1 = [0.0, 0.0, 0.0], p2 = [0.0, 1.0, 0.0], p3 = [1.0, 1.0, 0.0], p4 = [1.0, 0.0, 0.0], p5 = [2.0, 0.0, 0.0] }}
[[bodies]]
name = "load"
kind = "node"
mass = 2.0
position = [2.0, 0.0, -1.0]
[[cables]]
name = "rope"
route = ["frame.anchor", "frame.p1", "frame.p2", "frame.p3", "frame.p4", "frame.p5", "load"]
ea = 1e4
rest_length = 6.0
pulley_friction = {mu}
"#
    ))
}

#[test]
fn a_cable_slipping_over_five_quarter_turns_keeps_the_capstan_ratio_in_statics() {
    let model = five_pulleys(0.1);
    let mut state = State::initial(&model);
    let mut ws = Workspace::new(&model);
    StaticSolver::new(&model).equilibrate(&model, &mut state, &mut ws, &model.solver).unwrap();
    // the workspace holds the last solve's return map: what slipped since the start
    let f = &ws.friction;
    for (i, s) in f.states.iter().enumerate() {
        assert_eq!(*s, PulleyState::SlipTowardEnd, "pulley {i} slips toward the load");
    }
    let ratio = f.tensions[5] / f.tensions[0];
    let exact = (0.1f64 * 5.0 * std::f64::consts::FRAC_PI_2).exp();
    assert!((exact - 2.193280).abs() < 1e-6);
    assert!((ratio - exact).abs() < 1e-9 * exact, "T_out/T_in = {ratio}, capstan {exact}");
    assert!((f.tensions[5] - 2.0 * G).abs() < 1e-9 * 2.0 * G, "the load's tension {}", f.tensions[5]);
    // a second solve from there stays put: the material was committed
    let before = state.segment_rest_lengths.clone();
    StaticSolver::new(&model).equilibrate(&model, &mut state, &mut ws, &model.solver).unwrap();
    for (a, b) in state.segment_rest_lengths.iter().zip(&before) {
        assert!((a - b).abs() < 1e-12, "the equilibrium moved its material: {a} vs {b}");
    }
}

#[test]
fn zero_friction_is_the_frictionless_element() {
    let with_zero = atwood(3.0, 1.0, 0.0);
    assert!(with_zero.pulley_friction.is_empty() && with_zero.cables[0].friction.is_none());
    assert!(with_zero.initial_segment_rest_lengths.is_empty());
    // bit for bit the run of a scene that never mentions friction
    let text = std::fs::read_to_string(
        std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("config/scenes/atwood.toml"),
    )
    .unwrap();
    let runs: Vec<Vec<u64>> = [text.clone(), format!("pulley_friction = 0.0\n{text}")]
        .iter()
        .map(|t| {
            let mut sim =
                Simulator::new(model_from_toml(t), SimSettings { dt: 1e-3, ..SimSettings::default() })
                    .unwrap();
            let mut bits = Vec::new();
            for _ in 0..300 {
                sim.step().unwrap();
                bits.extend(sim.state().poses.iter().map(|p| p.position.z.to_bits()));
                bits.push(sim.workspace().cables[0].tension.to_bits());
            }
            bits
        })
        .collect();
    assert_eq!(runs[0], runs[1]);
}

#[test]
fn the_atwood_machine_holds_just_above_its_threshold_and_slips_just_below() {
    // ln 3 / pi = 0.349699
    let ga = Integrator::GeneralizedAlpha { rho_inf: 0.8 };
    let below = run(atwood(3.0, 1.0, 0.34), ga, 2e-4, 0.6);
    assert!(point_velocity(&below, "m2").norm() > 0.01, "slips at mu 0.34");
    let above = run(atwood(3.0, 1.0, 0.36), ga, 2e-4, 0.6);
    assert!(point_velocity(&above, "m2").norm() < 1e-6, "holds at mu 0.36");
}

#[test]
fn careless_friction_is_refused_naming_the_field() {
    let base = r#"
[[bodies]]
name = "f"
kind = "fixed"
points = { a = [0.0, 0.0, 0.0], b = [1.0, 0.0, 0.0], c = [1.0, 1.0, 0.0] }
[[cables]]
name = "r"
ea = 1e3
rest_length = 1.0
"#;
    for (line, field, reason) in [
        ("route = [\"f.a\", \"f.b\"]\npulley_friction = 0.2", "pulley_friction", "no pulleys"),
        ("route = [\"f.a\", \"f.b\", \"f.c\"]\npulley_friction = -0.1", "pulley_friction", ">="),
        (
            "route = [\"f.a\", \"f.b\", \"f.c\"]\npulley_friction = [0.1, 0.2]",
            "pulley_friction",
            "per pulley",
        ),
        ("route = [\"f.a\", \"f.b\", \"f.c\"]\npulley_friction = nan", "pulley_friction", ""),
        ("route = [\"f.a\", \"f.b\", \"f.c\"]\nwinch_end = \"last\"", "winch_end", "friction"),
        (
            "route = [\"f.a\", \"f.b\", \"f.c\"]\npulley_friction = 0.1\nwinch_end = \"middle\"",
            "winch_end",
            "",
        ),
    ] {
        let text = format!("{base}{line}\n");
        let err = tensegrity::scene::from_toml(&text, "careless.toml").expect_err(line).to_string();
        assert!(err.contains("careless.toml"), "{err}");
        assert!(err.contains(field), "{line}: {err}");
        assert!(err.contains(reason), "{line}: {err}");
    }
}

/// A scene whose cable runs from the ground over a bar, a rigid body and a node to the ground,
/// with friction `mu` at its pulleys, velocities `v` and the segments' accepted rest lengths at
/// strains `strain` below their lengths (so that some pulleys stick and others slip).
fn tangled(mu: [f64; 3], v: &[f64], strain: &[f64]) -> (Model, State) {
    let model = model_from_toml(&format!(
        r#"
gravity = [0.0, 0.0, -9.81]
[[bodies]]
name = "g"
kind = "fixed"
points = {{ a = [-1.0, 0.0, 0.0], b = [1.5, 0.2, 0.3] }}
[[bodies]]
name = "bar"
kind = "bar"
ends = [[-0.3, 0.8, 0.1], [0.2, 1.1, 0.6]]
mass = 1.0
[[bodies]]
name = "box"
kind = "rigid"
position = [0.6, 0.1, 1.0]
rotation = [0.3, -0.2, 0.4]
mass = 2.0
inertia = [0.3, 0.4, 0.5, 0.02, 0.0, 0.01]
points = {{ p = [0.1, 0.2, -0.1] }}
[[bodies]]
name = "n"
kind = "node"
mass = 0.5
position = [1.2, -0.6, 0.4]
[[cables]]
name = "rope"
route = ["g.a", "bar.b", "box.p", "n", "g.b"]
ea = 1e3
damping = 3.0
rest_length = 5.0
pulley_friction = [{}, {}, {}]
"#,
        mu[0], mu[1], mu[2]
    ));
    let mut state = State::initial(&model);
    for (x, y) in state.velocities.iter_mut().zip(v) {
        *x = *y;
    }
    let mut ws = Workspace::new(&model);
    evaluate_forces(&model, &state, &mut ws);
    for (k, s) in state.segment_rest_lengths.iter_mut().enumerate() {
        *s = ws.friction.lengths[k] * (1.0 - strain[k]);
    }
    state.rest_lengths[0] = state.segment_rest_lengths.iter().sum();
    (model, state)
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 48, ..ProptestConfig::default() })]

    #[test]
    fn friction_cable_tangents_match_finite_differences(
        mu in [0.0..0.6f64, 0.0..0.6f64, 0.0..0.6f64],
        v in proptest::collection::vec(-0.5..0.5f64, 16),
        strain in proptest::collection::vec(0.002..0.05f64, 4),
    ) {
        let (model, state) = tangled(mu, &v, &strain);
        let mut ws = Workspace::new(&model);
        evaluate(&model, &state, &mut ws, Tangents::StiffnessAndDamping);
        let f = ws.friction.clone();
        // away from the switching surfaces: no pulley within 1e-3 of its bound or of zero flow
        for i in 0..3 {
            let (a, b) = (f.tensions[i], f.tensions[i + 1]);
            prop_assume!(a > 1.0 && b > 1.0);
            let bound = (mu[i] * f.wrap_angles[i]).exp();
            let r = (a / b).max(b / a);
            prop_assume!(f.states[i] != PulleyState::Stick || r < bound * (1.0 - 1e-3));
            prop_assume!(f.states[i] == PulleyState::Stick || f.flows[i].abs() > 1e-4);
        }
        let k_fd = fd_stiffness(&model, &state, 1e-6);
        let scale = f.tensions.iter().fold(0.0f64, |m, t| m.max(*t));
        let ek = rel_err(&ws.stiffness, &k_fd, scale);
        prop_assert!(ek < 1e-5, "K rel err {ek}, states {:?}\nK - K_fd = {:.3e}", f.states, &ws.stiffness - &k_fd);
        let c_fd = fd_damping(&model, &state, 1e-6);
        let ec = rel_err(&ws.damping, &c_fd, 1.0);
        prop_assert!(ec < 1e-5, "C rel err {ec}, states {:?}", f.states);
    }
}

#[test]
fn thousands_of_stick_slip_switches_stay_finite_and_keep_newton_short() {
    // an Atwood machine held just past its threshold (mu 0.36 > ln 3 / pi) with a winch at the
    // heavy mass shaking its end: each swing drives the pulley from stick into slip and back
    let text = |mu: f64| {
        atwood_text(3.0, 1.0, mu, "ea = 1e6\ndamping_ratio = 0.2")
            + "[[actuators]]\nname = \"winch\"\ncable = \"rope\"\nmin_rest_length = 1.5\nmax_rest_length = 3.5\nmax_rate = 1.0\n"
    };
    for (settings, label, duration, least) in [
        (SimSettings { dt: 1e-3, ..SimSettings::default() }, "fixed step", 20.0, 1000),
        (SimSettings { dt: 5e-3, tolerance: Some(1e-6), ..SimSettings::default() }, "error control", 1.0, 40),
    ] {
        let dt = settings.dt;
        let mut sim = Simulator::new(model_from_toml(&text(0.36)), settings).unwrap();
        let (mut switches, mut last, mut newton, mut steps) = (0, PulleyState::Stick, 0, 0);
        let omega = 300.0;
        while sim.state().time < duration && switches < 2 * least {
            let rate = 0.02 * (omega * sim.state().time).sin();
            sim.command("winch", tensegrity::control::ActuatorCommand::rate(rate)).unwrap();
            let stats = sim.step().unwrap();
            newton += stats.newton_iterations;
            steps += stats.substeps;
            let now = sim.workspace().friction.states[0];
            if now != last {
                switches += 1;
                last = now;
            }
            assert!(sim.state().is_finite());
            assert!(sim.workspace().friction.tensions.iter().all(|t| t.is_finite()));
        }
        assert!(switches >= least, "{label}: only {switches} switches");
        let per_step = newton as f64 / steps as f64;
        assert!(per_step < 4.0, "{label}: {per_step} Newton iterations per sub-step");
        let e = sim.energy();
        assert!(e.friction_loss > 0.0);
        eprintln!("{label}: dt {dt}, {switches} switches, {per_step:.2} Newton iterations per sub-step, {steps} sub-steps");
    }
}

#[test]
fn a_load_pulled_into_its_pulley_keeps_the_run_going() {
    // the light mass of the slipping Atwood machine reaches the wheel after 0.9 s and is held
    // there: its segment vanishes, and the wrap angle fades out (`WRAP_FADE`) instead of flipping
    for (integrator, dt) in [(Integrator::GeneralizedAlpha { rho_inf: 0.8 }, 1e-3), (Integrator::Rk4, 1e-4)] {
        let mut sim =
            Simulator::new(atwood(3.0, 1.0, 0.1), SimSettings { dt, integrator, ..SimSettings::default() })
                .unwrap();
        while sim.state().time < 2.5 {
            if let Err(e) = sim.step() {
                panic!("{integrator:?}: {e}");
            }
        }
        let z2 = sim.state().poses[2].position.z;
        assert!(z2.abs() < 0.05, "{integrator:?}: the light mass sits at the wheel, z = {z2}");
        assert!(sim.workspace().friction.tensions.iter().all(|t| t.is_finite()));
    }
}

#[test]
fn the_faded_wrap_angle_keeps_the_tangent_exact() {
    // the light mass 0.5 mm from the wheel and a little aside: the pulley's wrap angle is faded
    let model = model_from_toml(
        r#"
gravity = [0.0, 0.0, -9.81]
[[bodies]]
name = "ceiling"
kind = "fixed"
points = { wheel = [0.0, 0.0, 0.0] }
[[bodies]]
name = "m1"
kind = "node"
mass = 3.0
position = [0.1, 0.0, -1.0]
[[bodies]]
name = "m2"
kind = "node"
mass = 1.0
position = [0.0003, 0.0001, -0.0004]
[[cables]]
name = "rope"
route = ["m1", "ceiling.wheel", "m2"]
ea = 1e4
damping = 2.0
rest_length = 0.95
pulley_friction = 0.3
"#,
    );
    let mut state = State::initial(&model);
    for (j, v) in state.velocities.iter_mut().enumerate() {
        *v = 0.1 * (j as f64 + 1.0).sin();
    }
    let mut ws = Workspace::new(&model);
    evaluate_forces(&model, &state, &mut ws);
    let (l0, l1) = (ws.friction.lengths[0], ws.friction.lengths[1]);
    state.segment_rest_lengths = vec![0.98 * l0, 0.999 * l1];
    state.rest_lengths[0] = state.segment_rest_lengths.iter().sum();
    evaluate(&model, &state, &mut ws, Tangents::StiffnessAndDamping);
    let f = ws.friction.clone();
    assert!(l1 < 1e-3 * (l0 + l1), "the fade is on: l1 = {l1}");
    assert_eq!(f.states[0], PulleyState::SlipTowardStart, "{f:?}");
    let k_fd = fd_stiffness(&model, &state, 1e-8);
    let ek = rel_err(&ws.stiffness, &k_fd, f.tensions[0]);
    assert!(ek < 1e-5, "K rel err {ek}\nK - K_fd = {:.3e}", &ws.stiffness - &k_fd);
}

/// The bundled prism with friction `mu` at its ring's two pulleys (`None`: as bundled).
fn prism_with_friction(mu: Option<f64>) -> Model {
    let path = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("config/scenes/prism3.toml");
    let text = std::fs::read_to_string(path).unwrap();
    match mu {
        Some(mu) => model_from_toml(&format!("pulley_friction = {mu}\n{text}")),
        None => model_from_toml(&text),
    }
}

#[test]
fn a_deployment_stalls_at_the_far_pulleys_once_friction_holds_them() {
    // the ring's winch winds at its first anchor: with enough friction its pulleys never slip,
    // only the first segment shortens, and the prism ends in another shape than without
    let deploy = |mu: Option<f64>| {
        let model = prism_with_friction(mu);
        let mut state = State::initial(&model);
        let mut ws = Workspace::new(&model);
        // the most rope that ran through a pulley since the start, at any load step (round-off
        // aside)
        let mut slipped: f64 = 0.0;
        tensegrity::solve::deploy::deploy_quasi_static(&model, &mut state, &mut ws, |_, s, w| {
            for c in 0..model.cables.len() {
                for p in tensegrity::report::pulley_reports(&model, s, w, c) {
                    slipped = slipped.max(p.slip_m.abs());
                }
            }
        })
        .unwrap();
        evaluate_forces(&model, &state, &mut ws);
        let tip = ws.points[model.point_id("bar0_1.b").unwrap().0].position;
        (tip, slipped > 1e-9, ws.friction.tensions.clone())
    };
    let (free, _, _) = deploy(None);
    let (low, low_slipped, _) = deploy(Some(0.05));
    let (held, held_slipped, tensions) = deploy(Some(0.3));
    let (stuck, _, _) = deploy(Some(1.0));
    assert!(low_slipped, "at mu 0.05 the winch pulls rope over the pulleys");
    assert!(!held_slipped, "at mu 0.3 no pulley ever slips");
    assert!(
        (held - stuck).norm() < 1e-9,
        "once the pulleys hold, more friction changes nothing: {held} vs {stuck}"
    );
    assert!((held - free).norm() > 0.01, "the stalled deployment ends elsewhere: {held} vs {free}");
    assert!((low - free).norm() < (held - free).norm());
    // tension along the ring: the wound first segment carries the most
    assert!(tensions[0] > tensions[1] && tensions[0] > tensions[2], "{tensions:?}");
}

#[test]
fn modes_about_an_equilibrium_hold_the_pulleys_that_stick() {
    // the load on the rope over five quarter turns: with friction its pulleys stick in a small
    // vibration, so the load bounces on its own segment, `k = EA / s_5`; without, on the whole
    // rope, `k = EA / L0`
    let two_pi = 2.0 * std::f64::consts::PI;
    for mu in [0.1, 0.0] {
        let model = five_pulleys(mu);
        let mut state = State::initial(&model);
        let mut ws = Workspace::new(&model);
        StaticSolver::new(&model).equilibrate(&model, &mut state, &mut ws, &model.solver).unwrap();
        let modes = tensegrity::solve::modes::natural_modes(&model, &state).unwrap();
        let rest = if mu > 0.0 { state.segment_rest_lengths[5] } else { state.rest_lengths[0] };
        let bounce = (1e4 / rest / 2.0).sqrt() / two_pi;
        let top = modes.last().unwrap().frequency_hz;
        assert!((top - bounce).abs() < 1e-6 * bounce, "mu {mu}: {top} Hz, closed form {bounce} Hz");
    }
}
