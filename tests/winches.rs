//! Winch motors and command delays (`tensegrity::forces::winch`, `tensegrity::control`): the
//! hoist's steady speed and first-order lag against the closed forms, stall with and without a
//! back-drivable gear, the motors' energy balance, the tangents against finite differences, the
//! explicit integrators, a delay that shifts the rest-length history by whole steps, and careless
//! input.

mod common;

use common::{fd_damping, fd_stiffness, model_from_toml, rel_err};
use tensegrity::control::ActuatorCommand;
use tensegrity::evaluate::{evaluate, Tangents, Workspace};
use tensegrity::model::Model;
use tensegrity::sim::{SimSettings, Simulator};
use tensegrity::solve::dynamics::Integrator;
use tensegrity::state::State;

const G: f64 = 9.81;

fn hoist_text() -> String {
    std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/config/examples/hoist.toml")).unwrap()
}

/// The hoist example (`config/examples/hoist.toml`) with a `load` kg load and `winch_extra`
/// appended to its `[actuators.winch]` table.
fn hoist(load: f64, winch_extra: &str) -> Model {
    let text = hoist_text()
        .replace("mass = 10.0", &format!("mass = {load:?}"))
        .replace("rotor_inertia = 1e-5\n", &format!("rotor_inertia = 1e-5\n{winch_extra}"));
    model_from_toml(&text)
}

fn hoist_sim(model: Model, dt: f64, integrator: Integrator) -> Simulator {
    Simulator::at_equilibrium(model, SimSettings { dt, integrator, ..SimSettings::default() }).unwrap()
}

/// Commands the hoist to change its rest length at `rate` m/s (negative reels in).
fn at_rate(sim: &mut Simulator, rate: f64) {
    sim.command("hoist", ActuatorCommand { rest_length: None, rate: Some(rate) }).unwrap();
}

/// Mean reel-in speed (m/s) of the hoist's rest length over `steps` more steps.
fn mean_speed(sim: &mut Simulator, steps: usize) -> f64 {
    let (t0, l0) = (sim.state().time, sim.state().rest_lengths[0]);
    for _ in 0..steps {
        sim.step().unwrap();
    }
    (l0 - sim.state().rest_lengths[0]) / (sim.state().time - t0)
}

#[test]
fn the_hoist_reaches_its_torque_speed_line_as_a_first_order_lag() {
    let (m, r, stall, v0, j) = (10.0, 0.02, 200.0, 0.1, 1e-5);
    let v_ss = v0 * (1.0 - m * G / stall);
    let tau = (j + m * r * r) / (stall * r * r / v0);
    assert!((v_ss - 0.050950).abs() < 1e-12 && (tau - 5.0125e-3).abs() < 1e-12);
    let dt = 1e-5;
    let mut sim = hoist_sim(hoist(m, ""), dt, SimSettings::default().integrator);
    at_rate(&mut sim, -v0);
    // the drum's speed along the lag: v(t) = v_ss (1 - exp(-t / tau))
    let mut speeds = Vec::new();
    for _ in 0..(12.0 * tau / dt).round() as usize {
        sim.step().unwrap();
        speeds.push((sim.state().time, sim.state().winches[0].speed));
    }
    let at = |t: f64| speeds.iter().min_by(|a, b| (a.0 - t).abs().total_cmp(&(b.0 - t).abs())).unwrap().1;
    let lag = at(5.0 * tau) / (v_ss * (1.0 - (-5.0f64).exp()));
    assert!((lag - 1.0).abs() < 0.01, "v(5 tau) / closed form = {lag}");
    // the time constant from the slope of ln(v_ss - v) between tau and 5 tau
    let (ta, tb) = (tau, 5.0 * tau);
    let fitted = (tb - ta) / ((v_ss - at(ta)).ln() - (v_ss - at(tb)).ln());
    assert!((fitted / tau - 1.0).abs() < 0.01, "time constant {fitted} s, closed form {tau} s");
    // and the load rises with the drum
    let steady = mean_speed(&mut sim, 2000);
    assert!((steady / v_ss - 1.0).abs() < 1e-4, "steady speed {steady} m/s, closed form {v_ss} m/s");
    let rise = sim.state().velocities[2];
    assert!((rise / v_ss - 1.0).abs() < 1e-4, "the load rises at {rise} m/s");
}

#[test]
fn a_dc_motor_with_a_gear_is_the_same_torque_speed_line() {
    // T_s = N k_t V / (R r) = 10 * 0.02 * 12 / (0.6 * 0.02) = 200 N, v0 = r V / (N k_t) = 1.2 m/s
    let dc = hoist_text().replace("stall_tension = 200.0\n", "").replace(
        "no_load_speed = 0.1\n",
        "torque_constant = 0.02\nresistance = 0.6\nvoltage = 12.0\ngear_ratio = 10.0\n",
    );
    let model = model_from_toml(&dc);
    let w = model.winches[0];
    assert!((w.stall_tension - 200.0).abs() < 1e-9 && (w.no_load_speed - 1.2).abs() < 1e-12, "{w:?}");
    let mut sim = hoist_sim(model, 1e-5, SimSettings::default().integrator);
    at_rate(&mut sim, -0.1);
    for _ in 0..80000 {
        sim.step().unwrap();
    }
    // drive u = 0.1 / 1.2 against 98.1 N: v = v0 (u - m g / T_s), below zero: the load wins
    let v = mean_speed(&mut sim, 10000);
    let closed = 1.2 * (0.1 / 1.2 - 98.1 / 200.0);
    assert!((v / closed - 1.0).abs() < 1e-4, "{v} vs {closed}");
}

#[test]
fn a_stalled_winch_holds_when_self_locking_and_pays_out_along_its_line_when_not() {
    let m = 30.0; // m g = 294.3 N > 200 N
    let mut held = hoist_sim(hoist(m, "back_drivable = false\n"), 1e-5, SimSettings::default().integrator);
    let l0 = held.state().rest_lengths[0];
    let z0 = held.state().poses[1].position.z;
    at_rate(&mut held, -0.1);
    for _ in 0..20000 {
        held.step().unwrap();
        assert_eq!(held.state().rest_lengths[0], l0, "a self-locking winch holds exactly");
    }
    assert!(held.state().poses[1].position.z <= z0 + 1e-9, "the load is not lifted");
    let mut free = hoist_sim(hoist(m, ""), 1e-5, SimSettings::default().integrator);
    at_rate(&mut free, -0.1);
    for _ in 0..20000 {
        free.step().unwrap();
    }
    let v = mean_speed(&mut free, 10000);
    let closed = 0.1 * (1.0 - m * G / 200.0); // -0.04715: paid out
    assert!((v / closed - 1.0).abs() < 1e-4, "back-driven at {v} m/s, line says {closed} m/s");
    // driven to pay out, the self-locking winch pays out at its own no-load speed
    at_rate(&mut held, 0.05);
    for _ in 0..10000 {
        held.step().unwrap();
    }
    let v = mean_speed(&mut held, 10000);
    assert!((v + 0.05).abs() < 1e-6, "a self-locking winch driven out pays out at {v} m/s");
}

#[test]
fn the_motors_energy_balance_closes() {
    // with drum friction b = 1e-4 N m s/rad (0.25 N s/m on the rope) the line gives
    // v = (T_s - m g) / (T_s / v0 + b / r^2)
    let mut sim =
        hoist_sim(hoist(10.0, "viscous_friction = 1e-4\n"), 1e-5, SimSettings::default().integrator);
    at_rate(&mut sim, -0.1);
    let v = {
        for _ in 0..5000 {
            sim.step().unwrap();
        }
        mean_speed(&mut sim, 2000)
    };
    let closed = (200.0 - 98.1) / (2000.0 + 0.25);
    assert!((v / closed - 1.0).abs() < 1e-4, "{v} vs {closed}");
    let e = *sim.energy();
    // what the motor gave, less the drum's friction and the rotor's energy, went into the rope
    let drum = e.motor_work - e.winch_friction_loss - e.winch_kinetic;
    assert!(e.winch_friction_loss > 0.0 && e.winch_kinetic > 0.0, "{e:?}");
    assert!((drum / e.actuator_work - 1.0).abs() < 1e-3, "drum {drum} J, rope {} J", e.actuator_work);
    // and the rope's work lifted the load: the structure's balance closes too
    let lift = e.gravitational + e.kinetic - e.initial_total;
    assert!(lift > 0.5 * e.actuator_work, "the load gained {lift} J");
    assert!(e.numerical_loss().abs() < 1e-3 * e.actuator_work, "{e:?}");
}

#[test]
fn explicit_integrators_drive_the_winch_too() {
    let v_ss = 0.1 * (1.0 - 98.1 / 200.0);
    for integrator in [Integrator::Rk4, Integrator::SymplecticEuler] {
        let mut sim = hoist_sim(hoist(10.0, ""), 1e-5, integrator);
        at_rate(&mut sim, -0.1);
        for _ in 0..3000 {
            sim.step().unwrap();
        }
        let v = mean_speed(&mut sim, 2000);
        assert!((v / v_ss - 1.0).abs() < 1e-3, "{integrator:?}: {v} vs {v_ss}");
    }
    // and error-controlled generalized-alpha, at 1 ms output steps
    for integrator in [SimSettings::default().integrator] {
        let settings = SimSettings { dt: 1e-3, integrator, tolerance: Some(1e-8), ..SimSettings::default() };
        let mut sim = Simulator::at_equilibrium(hoist(10.0, ""), settings).unwrap();
        at_rate(&mut sim, -0.1);
        for _ in 0..60 {
            sim.step().unwrap();
        }
        let v = mean_speed(&mut sim, 20);
        assert!((v / v_ss - 1.0).abs() < 1e-3, "{integrator:?} with a tolerance: {v} vs {v_ss}");
    }
}

#[test]
fn a_position_command_with_integral_action_settles_on_its_target() {
    let mut sim = hoist_sim(
        hoist(10.0, "position_gains = [40.0, 400.0, 0.0]\n"),
        1e-5,
        SimSettings::default().integrator,
    );
    sim.command("hoist", ActuatorCommand { rest_length: Some(0.98), rate: Some(0.02) }).unwrap();
    for _ in 0..300000 {
        sim.step().unwrap();
    }
    let l0 = sim.state().rest_lengths[0];
    assert!((l0 - 0.98).abs() < 1e-6, "rest length {l0}");
}

/// The Atwood machine's rope driven by a winch at the first anchor, in the middle of a sub-step:
/// masses moved and moving, the drum turning, the drive `drive`.
fn winched_atwood(back_drivable: bool, drive: f64) -> (Model, State) {
    let text = std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/config/scenes/atwood.toml"))
        .unwrap()
        .replace(
            "route = [\"m1\", \"ceiling.left\", \"ceiling.right\", \"m2\"]",
            "route = [\"ceiling.left\", \"m1\", \"ceiling.right\", \"m2\"]",
        )
        + &format!(
            "damping = 3.0\n[[actuators]]\nname = \"w\"\ncable = \"rope\"\nmin_rest_length = 1.0\n\
             max_rest_length = 4.0\nmax_rate = 1.0\n[actuators.winch]\ndrum_radius = 0.05\n\
             stall_tension = 40.0\nno_load_speed = 0.5\nrotor_inertia = 2e-4\nviscous_friction = 1e-3\n\
             back_drivable = {back_drivable}\n"
        );
    let model = model_from_toml(&text);
    let mut state = State::initial(&model);
    state.poses[1].position += nalgebra::Vector3::new(0.02, -0.03, -0.25);
    state.poses[2].position += nalgebra::Vector3::new(-0.01, 0.04, -0.2);
    for (k, v) in state.velocities.iter_mut().enumerate() {
        *v = 0.3 * ((k as f64) * 1.7).sin();
    }
    let s = &mut state.winches[0];
    s.speed = 0.2;
    s.drive = drive;
    s.step = 1e-3;
    s.floor = if back_drivable { f64::NEG_INFINITY } else { 0.0 };
    (model, state)
}

#[test]
fn winch_cable_tangents_match_finite_differences() {
    for (back_drivable, drive) in [(true, 0.7), (true, -0.4), (false, 0.2)] {
        let (model, state) = winched_atwood(back_drivable, drive);
        let mut ws = Workspace::new(&model);
        evaluate(&model, &state, &mut ws, Tangents::StiffnessAndDamping);
        let r = ws.cables[0];
        assert!(r.tension > 1.0, "{r:?}");
        // a back-drivable drum gives way to the tension, a self-locking one holds
        assert_eq!(r.rest_length == state.rest_lengths[0], !back_drivable, "{r:?}");
        let k_fd = fd_stiffness(&model, &state, 1e-6);
        let ek = rel_err(&ws.stiffness, &k_fd, r.tension);
        assert!(ek < 1e-6, "{back_drivable} {drive}: K rel err {ek}");
        let c_fd = fd_damping(&model, &state, 1e-6);
        let ec = rel_err(&ws.damping, &c_fd, 1.0);
        assert!(ec < 1e-6, "{back_drivable} {drive}: C rel err {ec}");
    }
}

#[test]
fn a_command_delay_shifts_the_rest_length_history_by_whole_steps() {
    let text = hoist_text();
    let ideal = |delay: usize| {
        let t = text.replace("max_rate = 0.1\n", &format!("max_rate = 0.1\ncommand_delay = {delay}\n"));
        let end = t.find("[actuators.winch]").unwrap();
        model_from_toml(&t[..end])
    };
    let history = |delay: usize| {
        let mut sim = hoist_sim(ideal(delay), 1e-3, SimSettings::default().integrator);
        sim.command("hoist", ActuatorCommand { rest_length: Some(0.99), rate: Some(0.001) }).unwrap();
        (0..40)
            .map(|_| {
                sim.step().unwrap();
                sim.state().rest_lengths[0]
            })
            .collect::<Vec<f64>>()
    };
    let now = history(0);
    assert!(now[0] < 1.0, "an undelayed command acts in the next step");
    for k in [1, 3, 7] {
        let late = history(k);
        assert!(late[..k].iter().all(|l| *l == 1.0), "delay {k}: {:?}", &late[..k]);
        assert_eq!(&late[k..], &now[..40 - k], "delay {k}");
    }
}

#[test]
fn a_scene_without_winches_follows_the_same_path() {
    // the hoist's rope without its winch, and with a winch that is never stepped (statics):
    // equilibria identical to the bit
    let text = hoist_text();
    let end = text.find("[actuators.winch]").unwrap();
    let plain = model_from_toml(&text[..end]);
    let winched = model_from_toml(&text);
    assert!(plain.winches.is_empty() && plain.cables[0].winch.is_none());
    let a = Simulator::at_equilibrium(plain, SimSettings::default()).unwrap();
    let b = Simulator::at_equilibrium(winched, SimSettings::default()).unwrap();
    assert_eq!(a.state().poses, b.state().poses);
}

#[test]
fn careless_winches_are_refused_naming_the_field() {
    let text = hoist_text();
    for (from, to, field, reason) in [
        ("drum_radius = 0.02", "drum_radius = -0.02", "winch.drum_radius", "positive"),
        ("drum_radius = 0.02", "drum_radius = nan", "winch.drum_radius", "finite"),
        ("stall_tension = 200.0\n", "", "winch", "either stall_tension"),
        ("rotor_inertia = 1e-5", "rotor_inertia = 1e-5\nvoltage = 12.0", "winch", "either"),
        ("rotor_inertia = 1e-5", "rotor_inertia = -1.0", "winch.rotor_inertia", ">= 0"),
        ("rotor_inertia = 1e-5", "rotor_inertia = 1e-5\nposition_gains = [1.0, -2.0, 0.0]", "ki", ">= 0"),
        (
            "rotor_inertia = 1e-5",
            "rotor_inertia = 1e-5\nmax_acceleration = 0.0",
            "max_acceleration",
            "positive",
        ),
        ("rotor_inertia = 1e-5", "rotor_inertia = 1e-5\nbrake = true", "", "brake"),
        ("max_rate = 0.1\n", "max_rate = 0.1\ncommand_delay = -1\n", "command_delay", ""),
        ("max_rate = 0.1\n", "max_rate = 0.1\ncommand_delay = 10000000\n", "command_delay", "at most"),
        ("ea = 1e9\n", "ea = 1e9\ntension_only = false\n", "winch", "member"),
    ] {
        assert!(text.contains(from), "{from}");
        let bad = text.replacen(from, to, 1);
        let err = tensegrity::scene::from_toml(&bad, "careless.toml").expect_err(to).to_string();
        assert!(err.contains("careless.toml"), "{err}");
        assert!(err.contains(field), "{to}: {err}");
        assert!(err.contains(reason), "{to}: {err}");
    }
    // commands a careless controller sends to a winch are refused and change nothing
    let mut sim = hoist_sim(hoist(10.0, ""), 1e-3, SimSettings::default().integrator);
    for cmd in [
        ActuatorCommand { rest_length: None, rate: Some(f64::NAN) },
        ActuatorCommand { rest_length: None, rate: Some(5.0) },
        ActuatorCommand { rest_length: Some(-1.0), rate: None },
        ActuatorCommand::default(),
    ] {
        assert!(sim.command("hoist", cmd).is_err(), "{cmd:?}");
    }
    for _ in 0..100 {
        sim.step().unwrap();
    }
    assert!(sim.state().is_finite() && sim.rejected_commands() == 4);
}
