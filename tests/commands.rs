//! Invariant: actuator commands are validated, applied at step boundaries and held. A non-finite,
//! out-of-range, empty or unknown-name command is rejected, counted and changes nothing, and the
//! simulation keeps running; a target is approached at the commanded rate and then held; a rate
//! stops at the actuator's limit; and shortening a cable by command raises its tension to what
//! statics predicts (on average, once the commanded motion is over).

mod common;
use common::bundled;

use tensegrity::control::{ActuatorCommand, ActuatorMode, CommandError};
use tensegrity::evaluate::{evaluate, Tangents, Workspace};
use tensegrity::sim::{SimSettings, Simulator};
use tensegrity::solve::statics::StaticSolver;
use tensegrity::State;

#[test]
fn bad_commands_are_rejected_counted_and_change_nothing() {
    let mut sim = Simulator::new(bundled("prism3.toml"), SimSettings::default()).unwrap();
    let id = sim.model().actuator_id("ring_winch").unwrap();
    let act = sim.model().actuators[id.0];
    let cases = [
        ("ring_winch", ActuatorCommand::target(f64::NAN)),
        ("ring_winch", ActuatorCommand::rate(f64::INFINITY)),
        ("ring_winch", ActuatorCommand::target(act.max_rest_length * 2.0)),
        ("ring_winch", ActuatorCommand::target(0.0)),
        ("ring_winch", ActuatorCommand::rate(-2.0 * act.max_rate)),
        (
            "ring_winch",
            ActuatorCommand { rest_length: Some(act.min_rest_length), rate: Some(0.0), tension: None },
        ),
        ("ring_winch", ActuatorCommand::default()),
        ("no_such_winch", ActuatorCommand::target(act.min_rest_length)),
    ];
    for (i, (name, cmd)) in cases.iter().enumerate() {
        let err = sim.command(name, *cmd).unwrap_err();
        match (i, &err) {
            (0 | 1, CommandError::NonFinite { .. }) => {}
            (2..=5, CommandError::OutOfRange { .. }) => {}
            (6, CommandError::Empty(_)) => {}
            (7, CommandError::UnknownActuator(_)) => {}
            _ => panic!("case {i}: unexpected {err}"),
        }
        assert!(!err.to_string().is_empty());
        assert_eq!(sim.control().mode(id), ActuatorMode::Schedule, "case {i} changed the mode");
        sim.step().unwrap();
        assert!(sim.state().is_finite());
    }
    assert_eq!(sim.rejected_commands(), cases.len());
}

#[test]
fn a_target_is_approached_at_the_commanded_rate_and_held() {
    let mut sim = Simulator::new(bundled("tbar.toml"), SimSettings::default()).unwrap();
    let cable = sim.model().cable_id("lower_left").unwrap().0;
    let l0 = sim.state().rest_lengths[cable];
    sim.command(
        "lower_winch",
        ActuatorCommand { rest_length: Some(l0 - 0.05), rate: Some(0.1), tension: None },
    )
    .unwrap();
    for k in 1..=1000 {
        sim.step().unwrap();
        let expected = (l0 - 0.1 * k as f64 * 1e-3).max(l0 - 0.05);
        assert!((sim.state().rest_lengths[cable] - expected).abs() < 1e-12, "step {k}");
    }
}

#[test]
fn a_rate_stops_at_the_actuator_limit() {
    let mut sim =
        Simulator::new(bundled("tbar.toml"), SimSettings { dt: 2e-3, ..Default::default() }).unwrap();
    let id = sim.model().actuator_id("lower_winch").unwrap();
    let act = sim.model().actuators[id.0];
    sim.command("lower_winch", ActuatorCommand::rate(act.max_rate)).unwrap();
    // lengthening at max rate: the lower string goes slack, the structure stays finite
    for _ in 0..600 {
        sim.step().unwrap();
        assert!(sim.state().is_finite());
    }
    assert_eq!(sim.state().rest_lengths[act.cable.0], act.max_rest_length);
}

#[test]
fn shortening_a_cable_by_command_raises_its_tension_to_the_static_value() {
    let model = bundled("prism3.toml");
    let ring = model.cable_id("ring").unwrap().0;
    let l_target = 0.95 * model.initial_rest_lengths[ring];
    let mut sim = Simulator::new(model.clone(), SimSettings::default()).unwrap();
    let t0 = sim.workspace().cables[ring].tension;
    sim.command("ring_winch", ActuatorCommand::target(l_target)).unwrap();
    // the prestress-stabilized twist mode hardly stretches any cable, so cable damping barely
    // touches it: compare the mean over the last 3 s (equal to the equilibrium value to second
    // order in the amplitude)
    let (mut sum, mut count) = (0.0, 0);
    while sim.state().time < 8.0 {
        sim.step().unwrap();
        if sim.state().time > 5.0 {
            sum += sim.workspace().cables[ring].tension;
            count += 1;
        }
    }
    let t_dynamic = sum / count as f64;
    // statics at the same rest length
    let mut state = State::initial(&model);
    state.rest_lengths[ring] = l_target;
    let mut ws = Workspace::new(&model);
    StaticSolver::new(&model).equilibrate(&model, &mut state, &mut ws, &model.solver).unwrap();
    evaluate(&model, &state, &mut ws, Tangents::None);
    let t_static = ws.cables[ring].tension;
    assert!(t_dynamic > 2.0 * t0, "tension rose from {t0} to {t_dynamic} N");
    assert!(
        (t_dynamic - t_static).abs() < 1e-3 * t_static,
        "settled at {t_dynamic} N, statics says {t_static} N"
    );
}
