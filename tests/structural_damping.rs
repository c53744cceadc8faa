//! Invariant: Rayleigh damping (`[damping] alpha, beta`: `C = alpha M + beta K0`) damps a mode
//! whose stiffness is material at the ratio `(alpha / omega + beta omega) / 2` (within 0.2 %),
//! measured from the free decay of a dynamic run; `alpha` settles the 3-prism's lowest mode, held
//! by prestress, which hardly stretches a cable and so keeps 99.9 % of its energy over 6 cycles
//! against the cables' 5 % damping ratio; the energy account books what it dissipates; and bad
//! coefficients are refused naming the field. Rotational damping at joints (`damping` on a
//! joint): its stiffness and damping matrices match finite differences, and a pendulum on a
//! damped pin decays at the closed-form ratio `c / (2 sqrt(I m g l / 2))`.

mod common;

use common::*;
use tensegrity::evaluate::Workspace;
use tensegrity::sim::{SimSettings, Simulator};
use tensegrity::solve::dynamics::Integrator;
use tensegrity::solve::modes::natural_modes;
use tensegrity::solve::statics::StaticSolver;
use tensegrity::state::retract;
use tensegrity::State;

fn undamped_integrator(dt: f64) -> SimSettings {
    SimSettings { dt, integrator: Integrator::GeneralizedAlpha { rho_inf: 1.0 }, ..Default::default() }
}

/// The damping ratio of the knot's axial oscillation between two prestressed cables, from the
/// logarithmic decrement of its successive positive peaks; the ratio expected; and the worst
/// energy-balance misfit relative to the initial energy.
fn measured_ratio(alpha: f64, beta: f64) -> (f64, f64, f64) {
    let mut model = knot_between_cables(1.0, 1.0, 1e3, 0.0, "prestress = 10.0", "prestress = 10.0");
    // the model as a scene would build it with [damping]: alpha as is, beta on each cable's EA/L0
    model.rayleigh.alpha = alpha;
    for (c, cable) in model.cables.iter_mut().enumerate() {
        cable.damping += beta * cable.axial_stiffness / model.initial_rest_lengths[c];
    }
    let k: f64 = (0..2).map(|c| model.cables[c].axial_stiffness / model.initial_rest_lengths[c]).sum();
    let omega = k.sqrt(); // mass 1 kg
    let mut state = State::initial(&model);
    state.poses[1].position.x = 1e-3;
    let period = 2.0 * std::f64::consts::PI / omega;
    let mut sim = Simulator::from_state(model, state, undamped_integrator(period / 2000.0)).unwrap();
    let (mut x, mut peaks) = ([1e-3f64; 3], Vec::new());
    let e0 = sim.energy().total();
    let mut worst_balance = 0.0f64;
    for _ in 0..(2000 * 6) {
        sim.step().unwrap();
        x = [x[1], x[2], sim.state().poses[1].position.x];
        if x[1] > x[0] && x[1] >= x[2] && x[1] > 0.0 {
            // the parabola through the three samples places the peak between them
            let (a, b) = (0.5 * (x[0] + x[2]) - x[1], 0.5 * (x[2] - x[0]));
            peaks.push(x[1] - b * b / (4.0 * a));
        }
        let e = sim.energy();
        worst_balance = worst_balance.max(e.numerical_loss().abs() / e0);
    }
    assert!(peaks.len() >= 4, "peaks {peaks:?}");
    let decrement = (peaks[0] / peaks[peaks.len() - 1]).ln() / (peaks.len() - 1) as f64;
    let zeta = decrement / (4.0 * std::f64::consts::PI.powi(2) + decrement * decrement).sqrt();
    (zeta, (alpha / omega + beta * omega) / 2.0, worst_balance)
}

#[test]
fn rayleigh_damping_gives_a_material_mode_its_damping_ratio() {
    for (alpha, beta) in [(2.0, 0.0), (0.0, 1e-3), (1.0, 5e-4)] {
        let (zeta, expected, balance) = measured_ratio(alpha, beta);
        assert!(
            (zeta - expected).abs() < 2e-3 * expected,
            "alpha {alpha} beta {beta}: measured zeta {zeta:.6} against (alpha/omega + beta omega)/2 = {expected:.6}"
        );
        assert!(
            balance < 1e-4,
            "alpha {alpha} beta {beta}: the energy account misses {balance:e} of the energy"
        );
    }
}

#[test]
fn the_scene_table_sets_both_coefficients_and_refuses_bad_ones() {
    let text = |damping: &str| {
        format!(
            r#"
[damping]
{damping}
[[bodies]]
name = "ground"
kind = "fixed"
[[bodies]]
name = "n"
kind = "node"
mass = 1.0
position = [1.0, 0.0, 0.0]
[[cables]]
name = "c"
route = ["ground", "n"]
ea = 1e3
rest_length = 0.5
damping = 2.0
"#
        )
    };
    let model = model_from_toml(&text("alpha = 0.5\nbeta = 1e-3"));
    assert_eq!((model.rayleigh.alpha, model.rayleigh.beta), (0.5, 1e-3));
    // beta EA / L0 joins the cable's own damping
    assert!((model.cables[0].damping - (2.0 + 1e-3 * 1e3 / 0.5)).abs() < 1e-12);
    for (bad, field) in
        [("alpha = -1.0", "damping.alpha"), ("beta = 1e9", "damping.beta"), ("gamma = 1.0", "gamma")]
    {
        let err = tensegrity::scene::from_toml(&text(bad), "bad.toml").expect_err(bad).to_string();
        assert!(err.contains("bad.toml") && err.contains(field), "{bad}: {err}");
    }
}

#[test]
fn alpha_settles_the_prisms_prestress_mode_which_cable_damping_leaves_ringing() {
    // the bundled prism's lowest mode, excited from its equilibrium: held by prestress, it
    // hardly stretches a cable, so the cables' 5 % damping ratio hardly touches it; with alpha
    // the energy above equilibrium falls as exp(-alpha t) more (dE/dt = -alpha v^T M v, whose
    // mean over a cycle is -alpha E)
    let mut base = bundled("prism3.toml");
    base.schedule.ramps.clear(); // no deployment: free vibration about the equilibrium
    let mut eq = State::initial(&base);
    StaticSolver::new(&base).equilibrate(&base, &mut eq, &mut Workspace::new(&base), &base.solver).unwrap();
    let modes = natural_modes(&base, &eq).unwrap();
    let lowest = modes.iter().find(|m| !m.zero).unwrap();
    // nearly inextensional: it stretches the cables hundreds of times less than the stiff modes
    let stretch =
        |m: &tensegrity::solve::modes::Mode| m.cable_stretch.iter().fold(0.0f64, |a, s| a.max(s.abs()));
    let stiffest = stretch(modes.last().unwrap());
    assert!(stretch(lowest) < 1e-2 * stiffest, "{} against {stiffest}", stretch(lowest));
    let period = 1.0 / lowest.frequency_hz;
    // the energy above equilibrium after the first cycle (which carries away the start's
    // high-frequency content) and after 7
    let decay = |alpha: f64| {
        let mut model = base.clone();
        model.rayleigh.alpha = alpha;
        let mut start = eq.clone();
        retract(&model, &mut start.poses, &lowest.shape, 0.02);
        // rho_inf 0.9, not 1: with joints (index-3) the undamped method lets the reactions ring
        // and feeds energy in; at 400 steps a period its damping of this mode is negligible
        let settings = SimSettings {
            dt: period / 400.0,
            integrator: Integrator::GeneralizedAlpha { rho_inf: 0.9 },
            ..Default::default()
        };
        let mut sim = Simulator::from_state(model.clone(), start, settings).unwrap();
        let floor = Simulator::from_state(model, eq.clone(), settings).unwrap().energy().total();
        let mut at_cycle = Vec::new();
        for k in 0..(400 * 7) {
            sim.step().unwrap();
            if k % 400 == 399 {
                at_cycle.push(sim.energy().total() - floor);
            }
        }
        at_cycle[6] / at_cycle[0]
    };
    let ringing = decay(0.0);
    assert!(ringing > 0.99, "without alpha the mode keeps {ringing} of its energy over 6 cycles");
    let alpha = 0.5;
    let settling = decay(alpha);
    // rates add: alpha's exp(-alpha t) on top of what the cables take
    let expected = ringing * (-alpha * 6.0 * period).exp();
    assert!(
        (settling.ln() - expected.ln()).abs() < 0.05 * expected.ln().abs(),
        "with alpha {alpha}: energy ratio {settling} over 6 cycles against {expected}"
    );
    println!("the prism's lowest mode ({:.3} Hz) keeps {ringing:.3} of its energy over 6 cycles; with alpha {alpha}, {settling:.4} (expected {expected:.4})", lowest.frequency_hz);
}

#[test]
fn joint_damping_derivatives_match_finite_differences() {
    // a rigid body pinned with damping, and a bar joined to it by a damped ball joint, turned
    // away from the axes and spinning
    let model = model_from_toml(
        r#"
[[bodies]]
name = "hub"
kind = "rigid"
mass = 2.0
position = [0.0, 0.0, 0.0]
rotation = [0.4, -0.3, 0.8]
inertia = [0.2, 0.3, 0.4, 0.01, 0.02, -0.03]
points = { tip = [0.1, 0.2, 0.5] }
[[bodies]]
name = "arm"
kind = "bar"
mass = 1.0
ends = [[0.0, 0.0, 0.0], [1.0, 0.6, -0.4]]
[[joints]]
kind = "pin"
a = "hub.tip"
damping = 0.7
[[joints]]
kind = "ball"
a = "arm.a"
b = "hub"
damping = 1.3
"#,
    );
    let mut state = State::initial(&model);
    let mut ws = Workspace::new(&model);
    for (k, v) in state.velocities.iter_mut().enumerate() {
        *v = 0.3 * (1.0 + k as f64).sin();
    }
    tensegrity::evaluate::evaluate(
        &model,
        &state,
        &mut ws,
        tensegrity::evaluate::Tangents::StiffnessAndDamping,
    );
    let k_fd = fd_stiffness(&model, &state, 1e-6);
    let c_fd = fd_damping(&model, &state, 1e-3);
    assert!(k_fd.amax() > 0.1 && c_fd.amax() > 0.5, "the joints damp: {k_fd} {c_fd}");
    assert!(rel_err(&ws.stiffness, &k_fd, 1.0) < 1e-6, "K = {}\nK_fd = {k_fd}", ws.stiffness);
    assert!(rel_err(&ws.damping, &c_fd, 1.0) < 1e-9, "C = {}\nC_fd = {c_fd}", ws.damping);
}

#[test]
fn a_pendulum_with_a_damped_pin_decays_at_its_closed_form_ratio() {
    // a bar of mass m and length l hanging from a damped pin (planar): I theta'' + c theta' +
    // m g (l/2) theta = 0 with I = m l^2 / 3, so omega = sqrt(3 g / (2 l)) and
    // zeta = c / (2 sqrt(I m g l / 2))
    let (m, l, c, g): (f64, f64, f64, f64) = (2.0, 1.5, 0.2, 9.81);
    let text = format!(
        "planar = true\ngravity = [0.0, -{g}, 0.0]\n[[bodies]]\nname = \"bar\"\nkind = \"bar\"\nmass = {m}\nends = [[0.0, 0.0, 0.0], [{}, {}, 0.0]]\n[[joints]]\nkind = \"pin\"\na = \"bar.a\"\ndamping = {c}\n",
        l * 0.05f64.sin(),
        -l * 0.05f64.cos()
    );
    let model = model_from_toml(&text);
    let inertia = m * l * l / 3.0;
    let omega = (3.0 * g / (2.0 * l)).sqrt();
    let expected = c / (2.0 * (inertia * m * g * l / 2.0).sqrt());
    let period = 2.0 * std::f64::consts::PI / omega;
    let settings = SimSettings {
        dt: period / 2000.0,
        integrator: Integrator::GeneralizedAlpha { rho_inf: 0.9 },
        ..Default::default()
    };
    let mut sim = Simulator::new(model, settings).unwrap();
    let e0 = sim.energy().total();
    let x0 = sim.state().poses[0].position.x;
    let (mut x, mut peaks) = ([x0; 3], Vec::new());
    for _ in 0..(2000 * 5) {
        sim.step().unwrap();
        x = [x[1], x[2], sim.state().poses[0].position.x];
        if x[1] > x[0] && x[1] >= x[2] && x[1] > 0.0 {
            let (a, b) = (0.5 * (x[0] + x[2]) - x[1], 0.5 * (x[2] - x[0]));
            peaks.push(x[1] - b * b / (4.0 * a));
        }
    }
    assert!(peaks.len() >= 4, "peaks {peaks:?}");
    let decrement = (peaks[0] / peaks[peaks.len() - 1]).ln() / (peaks.len() - 1) as f64;
    let zeta = decrement / (4.0 * std::f64::consts::PI.powi(2) + decrement * decrement).sqrt();
    // small angles (0.05 rad): the pendulum's nonlinearity shifts the ratio by about 1e-4
    assert!((zeta - expected).abs() < 5e-3 * expected, "measured zeta {zeta:.6} against {expected:.6}");
    let e = sim.energy();
    assert!(e.damping_loss > 0.5 * (e0 - e.total()).abs(), "the account books the pin's loss: {e:?}");
    assert!(e.numerical_loss().abs() < 1e-3 * e.damping_loss, "energy balance misses {e:?}");
}

#[test]
fn joint_damping_on_a_node_is_refused() {
    let text = "[[bodies]]\nname = \"n\"\nkind = \"node\"\nmass = 1.0\nposition = [0.0, 0.0, 0.0]\n[[joints]]\nkind = \"pin\"\na = \"n\"\ndamping = 1.0\n";
    let err = tensegrity::scene::from_toml(text, "node.toml").expect_err("a node has no spin").to_string();
    assert!(err.contains("joints[0].damping") && err.contains("no spin"), "{err}");
}
