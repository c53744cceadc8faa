//! The learning task (`tensegrity::task`): the action mapping onto the actuators' limits, careless
//! tasks and actions refused with the reason, the observation layout against what `observe`
//! writes, orientations in ROS order, and the default reward.

use tensegrity::evaluate::{evaluate_forces, Workspace};
use tensegrity::scene;
use tensegrity::state::State;
use tensegrity::task::{quaternion_xyzw, xyzw_of_wxyz, LearningTask, ObservationField, TaskSizes};

fn fields(names: &[&str]) -> Vec<String> {
    names.iter().map(|s| s.to_string()).collect()
}

/// prism3's ring winch as a rate task observing `observed`.
fn prism_task(observed: &[&str], normalize: bool) -> (tensegrity::Model, LearningTask) {
    let model = scene::bundled("prism3").unwrap();
    let sizes = TaskSizes::of(&model);
    let task = LearningTask::new(
        &sizes,
        vec![0],
        true,
        &[-0.02],
        &[0.02],
        normalize,
        &fields(observed),
        false,
        vec![(0, 300.0)],
    )
    .unwrap();
    (model, task)
}

#[test]
fn actions_map_onto_the_limits_and_careless_ones_are_refused() {
    let (_, task) = prism_task(&["cable_tension"], true);
    let mut action = [-1.0];
    task.map_action(&mut action).unwrap();
    assert_eq!(action, [-0.02]);
    let mut action = [1.0];
    task.map_action(&mut action).unwrap();
    assert_eq!(action, [0.02]);
    let mut action = [0.0];
    task.map_action(&mut action).unwrap();
    assert_eq!(action, [0.0]);
    let mut action = [7.0]; // outside the space: clipped
    task.map_action(&mut action).unwrap();
    assert_eq!(action, [0.02]);

    let mut nan = [f64::NAN];
    let why = task.map_action(&mut nan).unwrap_err();
    assert!(why.contains("not finite"), "{why}");
    assert!(nan[0].is_nan(), "a refused action is left as it was");
    let why = task.map_action(&mut [0.0, 0.0]).unwrap_err();
    assert!(why.contains("2 values for 1 actuators"), "{why}");

    let (_, raw) = prism_task(&["cable_tension"], false);
    let mut action = [0.5];
    raw.map_action(&mut action).unwrap();
    assert_eq!(action, [0.02], "in SI units, clipped to the limits");
}

#[test]
fn careless_tasks_are_refused_with_the_reason() {
    let model = scene::bundled("prism3").unwrap();
    let sizes = TaskSizes::of(&model);
    let new =
        |actuators: Vec<usize>, low: &[f64], high: &[f64], observed: &[&str], targets: Vec<(usize, f64)>| {
            LearningTask::new(&sizes, actuators, true, low, high, true, &fields(observed), false, targets)
                .unwrap_err()
        };
    let ok_fields = ["cable_tension"];
    assert!(new(vec![], &[], &[], &ok_fields, vec![(0, 1.0)]).contains("at least one"));
    assert!(new(vec![5], &[0.0], &[1.0], &ok_fields, vec![(0, 1.0)]).contains("actuator index 5"));
    assert!(new(vec![0], &[1.0], &[0.0], &ok_fields, vec![(0, 1.0)]).contains("low <= high"));
    assert!(new(vec![0], &[f64::NAN], &[0.0], &ok_fields, vec![(0, 1.0)]).contains("finite"));
    let why = new(vec![0], &[0.0], &[1.0], &["cable_tensoin"], vec![(0, 1.0)]);
    assert!(why.contains("unknown field \"cable_tensoin\"") && why.contains("cable_tension"), "{why}");
    assert!(new(vec![0], &[0.0], &[1.0], &[], vec![(0, 1.0)]).contains("at least one field"));
    assert!(new(vec![0], &[0.0], &[1.0], &ok_fields, vec![(99, 1.0)]).contains("cable index"));
    assert!(new(vec![0], &[0.0], &[1.0], &ok_fields, vec![(0, -1.0)]).contains("tension > 0"));
    assert!(new(vec![0], &[0.0], &[1.0], &ok_fields, vec![]).contains("at least one target"));
}

#[test]
fn the_observation_has_the_layout_it_declares() {
    let model = scene::bundled("sixbar").unwrap();
    let sizes = TaskSizes::of(&model);
    let every: Vec<String> = ObservationField::ALL.iter().map(|f| f.name().to_string()).collect();
    let task =
        LearningTask::new(&sizes, vec![0], true, &[-0.1], &[0.1], true, &every, false, vec![(0, 20.0)])
            .unwrap();
    let layout = task.layout(&sizes);
    let expected = [
        ("cable_tension", 24, 1),
        ("cable_length", 24, 1),
        ("cable_rest_length", 24, 1),
        ("actuator_rest_length", 1, 1),
        ("actuator_rate", 1, 1),
        ("body_position", 6, 3),
        ("body_orientation", 6, 4),
    ];
    let got: Vec<_> = layout.iter().map(|(f, n, w)| (f.name(), *n, *w)).collect();
    assert_eq!(got, expected);

    let state = State::initial(&model);
    let mut ws = Workspace::for_forces(&model);
    evaluate_forces(&model, &state, &mut ws);
    let rates = vec![0.0; model.cables.len()];
    let mut out = Vec::new();
    task.observe(&model, &state, &ws, &rates, &[], &mut out);
    assert_eq!(out.len(), task.observation_size(&sizes));
    // the tensions first, then the orientations last, each x, y, z, w
    assert_eq!(out[..24], ws.cables.iter().map(|c| c.tension).collect::<Vec<_>>()[..]);
    let q = quaternion_xyzw(&state.poses[5]);
    assert_eq!(out[out.len() - 4..], q);
    let u = state.poses[5].rotation.quaternion();
    assert_eq!(q, [u.i, u.j, u.k, u.w]);
    assert_eq!(xyzw_of_wxyz(&[1.0, 2.0, 3.0, 4.0]), [2.0, 3.0, 4.0, 1.0]);
}

#[test]
fn the_default_reward_is_minus_the_mean_relative_tension_error() {
    let model = scene::bundled("prism3").unwrap();
    let sizes = TaskSizes::of(&model);
    let task = LearningTask::new(
        &sizes,
        vec![0],
        true,
        &[-0.02],
        &[0.02],
        true,
        &fields(&["cable_tension"]),
        false,
        vec![(0, 100.0), (1, 200.0)],
    )
    .unwrap();
    let tensions = [150.0, 100.0];
    assert_eq!(task.tension_reward(|c| tensions[c]), -(0.5 + 0.5) / 2.0);
    assert_eq!(task.tension_reward(|c| [100.0, 200.0][c]), 0.0);
}
