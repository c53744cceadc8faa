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
    sim.command("hoist", ActuatorCommand::rate(rate)).unwrap();
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
    sim.command("hoist", ActuatorCommand { rest_length: Some(0.98), rate: Some(0.02), tension: None })
        .unwrap();
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
    // `command_delay_s` in seconds at two physics steps, and the step-counted field kept for one
    // release: each shifts the history by whole steps
    let text = hoist_text();
    let ideal = |field: &str| {
        let t = text.replace("max_rate = 0.1\n", &format!("max_rate = 0.1\n{field}\n"));
        let end = t.find("[actuators.winch]").unwrap();
        model_from_toml(&t[..end])
    };
    let history = |field: &str, dt: f64| {
        let mut sim = hoist_sim(ideal(field), dt, SimSettings::default().integrator);
        sim.command("hoist", ActuatorCommand { rest_length: Some(0.99), rate: Some(0.001), tension: None })
            .unwrap();
        let warnings = sim.delay_warnings();
        let rest = (0..40)
            .map(|_| {
                sim.step().unwrap();
                sim.state().rest_lengths[0]
            })
            .collect::<Vec<f64>>();
        (rest, warnings)
    };
    for dt in [1e-3, 5e-4] {
        let (now, quiet) = history("", dt);
        assert!(now[0] < 1.0, "an undelayed command acts in the next step");
        assert!(quiet.is_empty(), "{quiet:?}");
        for k in [1, 3, 7] {
            let (late, warnings) = history(&format!("command_delay_s = {}", k as f64 * dt), dt);
            assert!(late[..k].iter().all(|l| *l == 1.0), "dt {dt}, delay {k}: {:?}", &late[..k]);
            assert_eq!(&late[k..], &now[..40 - k], "dt {dt}, delay {k}");
            assert!(warnings.is_empty(), "a whole number of steps is not warned about: {warnings:?}");
            let (stepped, warnings) = history(&format!("command_delay = {k}"), dt);
            assert_eq!(stepped, late, "the step-counted field, {k} steps");
            assert_eq!(warnings.len(), 1, "{warnings:?}");
            assert!(
                warnings[0].contains("actuators[0].command_delay")
                    && warnings[0].contains("counts physics steps")
                    && warnings[0].contains(&format!(
                        "command_delay_s = {}",
                        tensegrity::error::readable_number(k as f64 * dt)
                    )),
                "{}",
                warnings[0]
            );
        }
    }
    // 2.5 ms at 1 ms steps: rounded (half away from zero) to 3 steps, with a warning that says so
    let (rounded, warnings) = history("command_delay_s = 0.0025", 1e-3);
    let (three, _) = history("command_delay_s = 0.003", 1e-3);
    assert_eq!(rounded, three);
    assert_eq!(warnings.len(), 1, "{warnings:?}");
    assert!(
        warnings[0].contains("not a whole number") && warnings[0].contains("rounded to 3 steps"),
        "{}",
        warnings[0]
    );
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
        ("max_rate = 0.1\n", "max_rate = 0.1\ncommand_delay_s = -0.001\n", "command_delay_s", ">= 0"),
        ("max_rate = 0.1\n", "max_rate = 0.1\ncommand_delay_s = nan\n", "command_delay_s", "finite"),
        ("max_rate = 0.1\n", "max_rate = 0.1\ncommand_delay_s = 5.0\n", "command_delay_s", "[0, 1] s"),
        ("max_rate = 0.1\n", "max_rate = 0.1\ncommand_delay_s = 3\n", "command_delay_s", "[0, 1] s"),
        (
            "max_rate = 0.1\n",
            "max_rate = 0.1\ncommand_delay_s = 0.001\ncommand_delay = 1\n",
            "command_delay",
            "not both",
        ),
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
        ActuatorCommand::rate(f64::NAN),
        ActuatorCommand::rate(5.0),
        ActuatorCommand::target(-1.0),
        ActuatorCommand::default(),
    ] {
        assert!(sim.command("hoist", cmd).is_err(), "{cmd:?}");
    }
    for _ in 0..100 {
        sim.step().unwrap();
    }
    assert!(sim.state().is_finite() && sim.rejected_commands() == 4);
}

/// Commands the hoist's motor to hold the line force `tension` (N).
fn at_tension(sim: &mut Simulator, tension: f64) {
    sim.command("hoist", ActuatorCommand::tension(tension)).unwrap();
}

#[test]
fn a_tension_command_accelerates_the_load_by_the_force_it_sets() {
    // a torque loop holding 150 N on 10 kg: the load and the rotor (M = J / r^2 = 0.025 kg)
    // accelerate together at a = (T* - m g) / (m + M) until the drive saturates at
    // v = v0 (1 - T* / T_s) = 0.025 m/s (t = 4.8 ms)
    let (m, tension) = (10.0, 150.0);
    let a = (tension - m * G) / (m + 1e-5 / 0.02f64.powi(2));
    let mut errors = Vec::new();
    for dt in [2e-5, 1e-5, 5e-6] {
        let mut sim = hoist_sim(hoist(m, ""), dt, SimSettings::default().integrator);
        let z0 = sim.state().poses[1].position.z;
        at_tension(&mut sim, tension);
        let steps = (4e-3 / dt).round() as usize;
        for _ in 0..steps {
            sim.step().unwrap();
        }
        let t = sim.state().time;
        let rise = sim.state().poses[1].position.z - z0;
        errors.push(rise / (0.5 * a * t * t) - 1.0);
        let drum = sim.state().winches[0].drive;
        assert!(drum < 1.0, "dt {dt}: the drive saturated early ({drum})");
    }
    // the loop acts once per sub-step (its lag adds h T_s / v0, 0.02 kg at 1e-5 s, to the
    // inertia): a first-order error, which Richardson extrapolation removes
    assert!(errors[1].abs() < 5e-3, "{errors:?}");
    for pair in errors.windows(2) {
        let ratio = pair[0] / pair[1];
        assert!((ratio - 2.0).abs() < 0.1, "not first order: {errors:?}");
    }
    let extrapolated = 2.0 * errors[2] - errors[1];
    assert!(extrapolated.abs() < 1e-4, "at zero step {extrapolated} from the closed form: {errors:?}");
}

#[test]
fn a_tension_command_sets_the_static_tension_against_a_spring() {
    // config/examples/tensioner.toml: a 1 kg node between the winch's rope and a damped elastic
    // cable (EA 1000 N, rest 0.9 m), no gravity. Held at T* = 30 N, the node settles where the
    // spring carries 30 N: its length 0.9 (1 + 30 / 1000) = 0.927 m, the node at x = 1.073 m
    let text =
        std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/config/examples/tensioner.toml"))
            .unwrap();
    let model = model_from_toml(&text);
    let settings = SimSettings { dt: model.physics_dt.unwrap(), ..SimSettings::default() };
    let mut sim = Simulator::at_equilibrium(model, settings).unwrap();
    let start = sim.workspace().cables[1].tension;
    assert!((start - 111.0).abs() < 1.0, "the spring starts at {start} N");
    sim.command("tensioner", ActuatorCommand::tension(30.0)).unwrap();
    for _ in 0..3000 {
        sim.step().unwrap();
    }
    let x = sim.state().poses[1].position.x;
    assert!((x - 1.073).abs() < 1e-6, "the node settled at x = {x} m");
    let ws = sim.workspace();
    for (c, name) in [(0, "rope"), (1, "spring")] {
        let t = ws.cables[c].tension;
        assert!((t / 30.0 - 1.0).abs() < 1e-6, "{name} carries {t} N");
    }
    assert!(sim.state().winches[0].speed.abs() < 1e-9, "the drum still turns");
}

#[test]
fn a_tension_below_the_load_is_held_by_a_self_locking_gear_and_pays_out_when_not() {
    let (m, tension) = (10.0, 50.0);
    let mut held = hoist_sim(hoist(m, "back_drivable = false\n"), 1e-5, SimSettings::default().integrator);
    let l0 = held.state().rest_lengths[0];
    at_tension(&mut held, tension);
    for _ in 0..5000 {
        held.step().unwrap();
        assert_eq!(held.state().rest_lengths[0], l0, "a self-locking winch holds exactly");
    }
    // back-drivable, the load sinks at a = (m g - T*) / (m + M) while the drive is within [-1, 1]
    let mut free = hoist_sim(hoist(m, ""), 1e-5, SimSettings::default().integrator);
    let z0 = free.state().poses[1].position.z;
    at_tension(&mut free, tension);
    for _ in 0..400 {
        free.step().unwrap();
    }
    let t = free.state().time;
    let a = (m * G - tension) / (m + 0.025);
    let drop = z0 - free.state().poses[1].position.z;
    assert!((drop / (0.5 * a * t * t) - 1.0).abs() < 0.01, "dropped {drop} m in {t} s, a = {a}");
}

#[test]
fn a_position_command_after_a_tension_command_starts_where_the_drum_is() {
    let mut sim = hoist_sim(
        hoist(10.0, "position_gains = [40.0, 400.0, 0.0]\n"),
        1e-5,
        SimSettings::default().integrator,
    );
    // lift at 120 N for 60 ms, then hold where the rope is
    at_tension(&mut sim, 120.0);
    for _ in 0..6000 {
        sim.step().unwrap();
    }
    let there = sim.state().rest_lengths[0];
    assert!(there < 1.0 - 1e-3, "the tension phase reeled in only to {there} m");
    // the position controller's reference followed the drum (bumpless transfer)
    let reference = sim.state().winches[0].reference;
    assert!((reference - there).abs() < 1e-3 * (1.0 - there), "reference {reference}, rope {there}");
    sim.command("hoist", ActuatorCommand::target(there)).unwrap();
    let mut furthest: f64 = 0.0;
    for _ in 0..200000 {
        sim.step().unwrap();
        furthest = furthest.max((sim.state().rest_lengths[0] - there).abs());
    }
    // the drum overshoots a little while it stops, then returns
    assert!(furthest < 1.5e-3, "the rope wandered {furthest} m from the hold");
    let l0 = sim.state().rest_lengths[0];
    assert!((l0 - there).abs() < 1e-6, "held at {l0} m, asked {there} m");
}

#[test]
fn careless_tension_commands_are_refused_and_change_nothing() {
    use tensegrity::control::CommandError;
    let mut sim = hoist_sim(hoist(10.0, ""), 1e-3, SimSettings::default().integrator);
    let refused = |sim: &mut Simulator, cmd: ActuatorCommand| sim.command("hoist", cmd).unwrap_err();
    assert!(matches!(refused(&mut sim, ActuatorCommand::tension(f64::NAN)), CommandError::NonFinite { .. }));
    assert!(matches!(
        refused(&mut sim, ActuatorCommand::tension(-1.0)),
        CommandError::OutOfRange { field: "tension", .. }
    ));
    // above what the motor gives at stall
    assert!(matches!(
        refused(&mut sim, ActuatorCommand::tension(200.5)),
        CommandError::OutOfRange { field: "tension", max, .. } if max == 200.0
    ));
    let mixed = ActuatorCommand { rest_length: Some(0.9), ..ActuatorCommand::tension(100.0) };
    assert!(matches!(refused(&mut sim, mixed), CommandError::TensionWithLength(_)));
    for _ in 0..100 {
        sim.step().unwrap();
    }
    assert!(sim.state().is_finite() && sim.rejected_commands() == 4);
    let mode = sim.control().mode(tensegrity::model::ActuatorId(0));
    assert_eq!(mode, tensegrity::control::ActuatorMode::Schedule, "a refused command changed the mode");
    // an ideal actuator has no force to set
    let text = hoist_text();
    let ideal = model_from_toml(&text[..text.find("[actuators.winch]").unwrap()]);
    let mut sim = hoist_sim(ideal, 1e-3, SimSettings::default().integrator);
    let err = sim.command("hoist", ActuatorCommand::tension(50.0)).unwrap_err();
    assert!(matches!(err, CommandError::NoWinch(_)) && err.to_string().contains("winch"), "{err}");
}
