//! Invariant: the quasi-static deployment path is a path of converged, stable equilibria: at every
//! load step the force residual is below 1e-9 of the largest tension; shrinking `prism3`'s clustered
//! ring raises every tension monotonically; a path that drives a cable slack and taut again crosses
//! the non-smooth switch without losing convergence.

mod common;

use common::*;
use tensegrity::evaluate::Workspace;
use tensegrity::solve::deploy::deploy_quasi_static;
use tensegrity::State;

/// Runs the schedule, checking the residual bound at every step; returns every step's tensions.
fn run(model: &tensegrity::Model) -> Vec<Vec<f64>> {
    let mut state = State::initial(model);
    let mut ws = Workspace::new(model);
    let mut tensions = Vec::new();
    deploy_quasi_static(model, &mut state, &mut ws, |step, _, w| {
        let t_max = w.cables.iter().map(|c| c.tension).fold(0.0, f64::max);
        assert!(
            step.report.residual <= 1e-9 * t_max,
            "step {}: residual {} vs max tension {t_max}",
            step.index,
            step.report.residual
        );
        tensions.push(w.cables.iter().map(|c| c.tension).collect());
    })
    .unwrap_or_else(|e| panic!("{e}"));
    tensions
}

#[test]
fn prism3_deployment_raises_every_tension_monotonically() {
    let model = bundled("prism3.toml");
    assert!(model.cables.iter().any(|c| c.pulley_count() > 0), "prism3 has a clustered cable");
    let tensions = run(&model);
    assert_eq!(tensions.len(), model.schedule.steps + 1);
    for w in tensions.windows(2) {
        for (c, (a, b)) in w[0].iter().zip(&w[1]).enumerate() {
            assert!(b > a, "tension of {} fell from {a} to {b}", model.cable_names[c]);
        }
    }
    // the ring's rest length reached the schedule's target
    let ring = model.cable_id("ring").unwrap().0;
    let ramp = model.schedule.ramps[0];
    let mut rest = vec![0.0; model.cables.len()];
    model.scheduled_rest_lengths(model.schedule.end_time(), &mut rest);
    assert_eq!(rest[ring], ramp.target);
}

#[test]
fn tbar_and_tower_deployments_converge_at_every_step() {
    for scene in ["tbar.toml", "tower.toml"] {
        let model = bundled(scene);
        let tensions = run(&model);
        assert_eq!(tensions.len(), model.schedule.steps + 1, "{scene}");
    }
}

#[test]
fn path_through_slack_and_back_converges() {
    // a mass hanging in a V from two cables; the winch pays one cable out until it is slack, then
    // hauls it back in until it carries load again
    let text = r#"
gravity = [0.0, 0.0, -9.81]
[solver]
max_iterations = 80

[[bodies]]
name = "ceiling"
kind = "fixed"
points = { l = [-1.0, 0.0, 0.0], r = [1.0, 0.0, 0.0] }

[[bodies]]
name = "m"
kind = "node"
mass = 2.0
position = [0.0, 0.0, -1.0]

[[cables]]
name = "left"
route = ["ceiling.l", "m"]
ea = 5000.0

[[cables]]
name = "right"
route = ["ceiling.r", "m"]
ea = 5000.0

[[actuators]]
name = "w"
cable = "left"
min_rest_length = 1.0
max_rest_length = 3.0
max_rate = 2.0

[deployment]
steps = 60

[[deployment.ramps]]
actuator = "w"
duration = 1.0
rest_length = 2.6

[[deployment.ramps]]
actuator = "w"
start = 1.0
duration = 1.0
rest_length = 1.3
"#;
    let model = model_from_toml(text);
    let tensions = run(&model);
    let slack_steps = tensions.iter().filter(|t| t[0] == 0.0).count();
    assert!(slack_steps > 5, "the left cable went slack ({slack_steps} steps)");
    assert!(tensions[0][0] > 0.0 && tensions.last().unwrap()[0] > 0.0, "taut at both ends of the path");
    // while slack the mass hangs from the right cable alone: tension = weight
    for t in tensions.iter().filter(|t| t[0] == 0.0) {
        assert!((t[1] - 2.0 * 9.81).abs() < 1e-9 * t[1]);
    }
}

#[test]
fn a_path_without_equilibrium_ends_in_a_typed_error() {
    // the 2 kg / 1 kg Atwood machine has no static equilibrium
    let model = bundled("atwood.toml");
    let mut state = State::initial(&model);
    let before = state.clone();
    let mut ws = Workspace::new(&model);
    match deploy_quasi_static(&model, &mut state, &mut ws, |_, _, _| {}) {
        Err(tensegrity::SolveError::NoEquilibrium { load_step, residual, iterations, .. }) => {
            assert_eq!(load_step, 0);
            assert!(residual.is_finite() && residual > 1.0);
            assert!(iterations > 0);
        }
        other => panic!("expected NoEquilibrium, got {other:?}"),
    }
    assert_eq!(state, before, "a failed solve leaves the state unchanged");
}
