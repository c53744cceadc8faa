//! Invariant: the node's logic survives whatever its transports and peers do, with no middleware
//! in the loop (a fake clock and an in-memory sink). A writer that refuses every sample never stops
//! the steps; a flood of malformed commands costs each step a bounded number of messages, every one
//! is counted (`received = accepted + rejected`) and reported at most 10 times a second with short
//! excerpts; the newest command per actuator wins at a step boundary; StepSimulation steps one per
//! turn so a request of 10^12 steps leaves pause, reset and shutdown working; a physics failure
//! pauses with an ERROR status and reset recovers; late steps are counted as overruns, never caught
//! up in bursts; and nothing non-finite ever reaches a sink.

mod common;
use common::bundled;

use std::time::Duration;

use tensegrity::control::ActuatorCommand;
use tensegrity::io::commands::MAX_COMMANDS_PER_STEP;
use tensegrity::io::msg::{self, result_code, DiagnosticStatus};
use tensegrity::io::node::params::NodeParams;
use tensegrity::io::node::{NodeCore, MAX_REJECTION_REPORTS_PER_SECOND};
use tensegrity::io::sink::{NodeSink, NodeView, PublishError};
use tensegrity::io::topics::Topic;
use tensegrity::model::ActuatorId;
use tensegrity::sim::{SimSettings, Simulator};
use tensegrity::solve::dynamics::NewtonSettings;

/// Remembers what the core published and answered; refuses topics in `refuse`.
#[derive(Default)]
struct MemorySink {
    refuse: Vec<Topic>,
    published: Vec<(Topic, f64)>,
    statuses: Vec<DiagnosticStatus>,
    answers: Vec<(u64, msg::SimResult)>,
    applied: Vec<(f64, Vec<(ActuatorId, ActuatorCommand)>)>,
}

impl NodeSink for MemorySink {
    fn publish(&mut self, topic: Topic, v: &NodeView<'_>) -> Result<(), PublishError> {
        assert!(v.state.is_finite(), "a non-finite state reached the sink");
        assert!(v.workspace.cables.iter().all(|c| c.tension.is_finite() && c.length.is_finite()));
        assert!(v.rates.iter().all(|r| r.is_finite()));
        if self.refuse.contains(&topic) {
            return Err(PublishError::WouldBlock);
        }
        if topic == Topic::Diagnostics {
            self.statuses.extend(v.diagnostics.iter().cloned());
        }
        self.published.push((topic, v.state.time));
        Ok(())
    }
    fn step_request_done(&mut self, ticket: u64, result: msg::SimResult, _view: &NodeView<'_>) {
        self.answers.push((ticket, result));
    }
    fn commands_applied(&mut self, time: f64, _step: u64, commands: &[(ActuatorId, ActuatorCommand)]) {
        self.applied.push((time, commands.to_vec()));
    }
}

impl MemorySink {
    fn count(&self, topic: Topic) -> usize {
        self.published.iter().filter(|(t, _)| *t == topic).count()
    }
    fn value(status: &DiagnosticStatus, key: &str) -> Option<String> {
        status.values.iter().find(|kv| kv.key == key).map(|kv| kv.value.clone())
    }
}

fn core(params: NodeParams) -> NodeCore {
    NodeCore::new(bundled("prism3.toml"), params).unwrap()
}

const MS: Duration = Duration::from_millis(1);

#[test]
fn a_writer_that_refuses_every_sample_never_stops_the_steps() {
    let mut node = core(NodeParams { real_time_factor: 0.0, state_publish_rate: 0.0, ..Default::default() });
    let mut sink = MemorySink { refuse: Topic::ALL.to_vec(), ..Default::default() };
    node.start(&mut sink);
    for k in 0..1500u64 {
        node.tick(k as u32 * MS, &mut sink);
    }
    let s = node.stats();
    assert_eq!(s.steps, 1500, "every turn stepped although every publish failed");
    assert_eq!(s.publish_failures_on(Topic::Clock), 1500);
    assert_eq!(s.publish_failures_on(Topic::CableStates), 1501, "initial state + every step");
    assert_eq!(s.publish_failures_on(Topic::Structure), 1);
    assert!(s.publish_failures_on(Topic::Diagnostics) >= 1);
    // the writers recover: publishing resumes and the failures are reported per topic
    sink.refuse.clear();
    for k in 1500..2600u64 {
        node.tick(k as u32 * MS, &mut sink);
    }
    assert_eq!(sink.count(Topic::Clock), 1100);
    let periodic = sink.statuses.iter().rfind(|s| s.name.ends_with("simulation")).expect("a periodic status");
    assert_eq!(MemorySink::value(periodic, "publish_failures /clock").as_deref(), Some("1500"));
    assert_eq!(periodic.level, 1, "transport trouble is a warning");
}

/// Every kind of malformed command a careless controller sends, with why it must be refused.
fn malformed_commands() -> Vec<(&'static str, msg::ActuatorCommand)> {
    let cmd = |name: Vec<&str>, rest_length: Vec<f64>, rate: Vec<f64>| msg::ActuatorCommand {
        name: name.into_iter().map(String::from).collect(),
        rest_length,
        rate,
        ..Default::default()
    };
    let huge_name = "x".repeat(100_000);
    let mib_name = "y".repeat(1 << 20);
    let mut many = cmd(vec![], vec![], vec![]);
    many.name = vec!["ring_winch".to_string(); 2000];
    let mut big_frame = cmd(vec!["ring_winch"], vec![1.0], vec![]);
    big_frame.header.frame_id = "f".repeat(10_000);
    vec![
        ("NaN rest length", cmd(vec!["ring_winch"], vec![f64::NAN], vec![])),
        ("infinite rest length", cmd(vec!["ring_winch"], vec![f64::INFINITY], vec![])),
        ("infinite rate", cmd(vec!["ring_winch"], vec![], vec![f64::NEG_INFINITY])),
        ("huge rest length", cmd(vec!["ring_winch"], vec![1e300], vec![])),
        ("negative rest length", cmd(vec!["ring_winch"], vec![-1.0], vec![])),
        ("unknown name", cmd(vec!["no_such_winch"], vec![1.0], vec![])),
        ("mismatched lengths", cmd(vec!["ring_winch"], vec![1.0, 2.0], vec![])),
        ("empty arrays", cmd(vec![], vec![], vec![])),
        ("a name and no value", cmd(vec!["ring_winch"], vec![], vec![])),
        ("the same actuator twice", cmd(vec!["ring_winch", "ring_winch"], vec![1.0, 1.0], vec![])),
        ("a 100 kB name", cmd(vec![&huge_name], vec![1.0], vec![])),
        ("a 1 MiB name", cmd(vec![&mib_name], vec![1.0], vec![])),
        ("2000 entries", many),
        ("a 10 kB frame id", big_frame),
    ]
}

#[test]
fn every_malformed_command_is_rejected_counted_and_reported_briefly() {
    let model = bundled("prism3.toml");
    let l0 = model.initial_rest_lengths[model.cable_id("ring").unwrap().0];
    let mut node = NodeCore::new(model, NodeParams { real_time_factor: 0.0, ..Default::default() }).unwrap();
    let mut sink = MemorySink::default();
    for (why, m) in malformed_commands() {
        let before = node.stats();
        node.offer_command(&m);
        let after = node.stats();
        assert_eq!(after.commands_rejected, before.commands_rejected + 1, "{why} was not rejected");
        assert_eq!(after.commands_accepted, before.commands_accepted, "{why} was accepted");
    }
    node.tick(Duration::ZERO, &mut sink);
    assert!(sink.applied.is_empty(), "nothing malformed reached the actuators");
    assert_eq!(
        node.simulator().state().rest_lengths[node.simulator().model().cable_id("ring").unwrap().0],
        l0
    );
    let report = sink.statuses.iter().find(|s| s.name.ends_with("commands")).expect("a rejection report");
    assert_eq!(MemorySink::value(report, "rejected_since_last_report").as_deref(), Some("14"));
    assert!(
        report.message.len() < 400,
        "the report repeats at most an excerpt: {} bytes",
        report.message.len()
    );
}

#[test]
fn a_flood_costs_each_step_a_bounded_amount_and_the_counts_add_up() {
    let mut node = core(NodeParams { real_time_factor: 0.0, ..Default::default() });
    let mut sink = MemorySink::default();
    let bad = malformed_commands();
    let good = |k: usize| msg::ActuatorCommand {
        name: vec!["ring_winch".into()],
        rate: vec![if k % 2 == 0 { -0.001 } else { 0.001 }],
        ..Default::default()
    };
    let (mut sent, mut sent_good, mut sent_bad) = (0u64, 0u64, 0u64);
    let steps = 3000u64;
    for step in 0..steps {
        // a transport hands over messages while the core wants them (10 000 a second would be 10 a
        // step; this flood offers as many as the core takes)
        let mut taken = 0;
        while node.wants_commands() {
            if sent % 3 == 0 {
                node.offer_command(&good(sent as usize));
                sent_good += 1;
            } else {
                node.offer_command(&bad[sent as usize % bad.len()].1);
                sent_bad += 1;
            }
            sent += 1;
            taken += 1;
        }
        assert_eq!(taken, MAX_COMMANDS_PER_STEP, "bounded intake per step");
        node.tick(Duration::from_micros(step * 1000), &mut sink);
    }
    let s = node.stats();
    assert_eq!(s.steps, steps);
    assert_eq!(s.commands_received, sent);
    assert_eq!(s.commands_received, s.commands_accepted + s.commands_rejected);
    assert_eq!(s.commands_accepted, sent_good);
    assert_eq!(s.commands_rejected, sent_bad);
    // rejection reports: at most 10 per (fake) second, each with the count since the last
    let reports: Vec<_> = sink.statuses.iter().filter(|s| s.name.ends_with("commands")).collect();
    let seconds = steps as f64 * 1e-3;
    assert!(
        reports.len() as f64 <= seconds * MAX_REJECTION_REPORTS_PER_SECOND as f64 + 1.0,
        "{}",
        reports.len()
    );
    let reported: u64 = reports
        .iter()
        .map(|r| MemorySink::value(r, "rejected_since_last_report").unwrap().parse::<u64>().unwrap())
        .sum();
    assert!(reported <= s.commands_rejected && reported + 64 * 100 >= s.commands_rejected, "{reported}");
    assert!(sink.statuses.iter().all(|s| s.message.len() < 400));
    // one application per step boundary: the newest valid command of each step
    assert_eq!(sink.applied.len() as u64, steps);
    // the longest step's own time, for a real-time period to hold: counted and in /diagnostics
    assert!(s.longest_step > Duration::ZERO);
    let reported = sink.statuses.iter().rev().find_map(|st| MemorySink::value(st, "longest_step_us"));
    let reported: f64 = reported.expect("longest_step_us in /diagnostics").parse().unwrap();
    assert!(reported > 0.0 && reported <= 1e6 * s.longest_step.as_secs_f64() + 0.05, "{reported} us");
}

#[test]
fn the_newest_command_per_actuator_wins_at_the_step_boundary() {
    let model = bundled("tower.toml");
    let names = model.actuator_names[..2].to_vec();
    let mut node = NodeCore::new(model, NodeParams { real_time_factor: 0.0, ..Default::default() }).unwrap();
    let mut sink = MemorySink::default();
    let both = msg::ActuatorCommand { name: names.clone(), rate: vec![0.001, 0.002], ..Default::default() };
    let first_again =
        msg::ActuatorCommand { name: vec![names[0].clone()], rate: vec![-0.003], ..Default::default() };
    node.offer_command(&both);
    node.offer_command(&first_again);
    node.tick(Duration::ZERO, &mut sink);
    let (_, applied) = &sink.applied[0];
    let rate = |k: usize| applied.iter().find(|(id, _)| id.0 == k).unwrap().1.rate;
    assert_eq!(rate(0), Some(-0.003), "the newer entry for the first winch wins");
    assert_eq!(rate(1), Some(0.002), "the second winch keeps the entry it was given");
    node.tick(MS, &mut sink);
    assert_eq!(sink.applied.len(), 1, "applied once, then held by the actuators");
}

#[test]
fn step_simulation_steps_one_per_turn_and_never_blocks_pause_reset_or_shutdown() {
    let mut node = core(NodeParams { start_paused: true, state_publish_rate: 0.0, ..Default::default() });
    let mut sink = MemorySink::default();
    node.start(&mut sink);
    // nothing steps while paused and idle
    for k in 0..10 {
        node.tick(k * MS, &mut sink);
    }
    assert_eq!(node.stats().steps, 0);
    // zero steps: answered at once
    let t0 = node.request_steps(0, &mut sink).unwrap();
    assert_eq!(sink.answers.pop(), Some((t0, msg::SimResult::ok())));
    // 25 steps: exactly 25 clock ticks, answered after the last
    let t1 = node.request_steps(25, &mut sink).unwrap();
    for k in 0..40 {
        node.tick(k * MS, &mut sink);
    }
    assert_eq!(node.stats().steps, 25);
    assert_eq!(sink.count(Topic::Clock), 25);
    assert_eq!(sink.answers.pop(), Some((t1, msg::SimResult::ok())));
    // 10^12 steps: one per turn, a second request is refused, reset interrupts it with an answer
    let big = node.request_steps(1_000_000_000_000, &mut sink).unwrap();
    for k in 0..100 {
        node.tick(k * MS, &mut sink);
    }
    assert_eq!(node.steps_remaining(), 1_000_000_000_000 - 100);
    let refused = node.request_steps(5, &mut sink).unwrap_err();
    assert_eq!(refused.result, result_code::INCORRECT_STATE);
    node.reset(&mut sink);
    let (ticket, answer) = sink.answers.pop().unwrap();
    assert_eq!(ticket, big);
    assert_eq!(answer.result, result_code::OPERATION_FAILED);
    assert!(answer.error_message.contains("reset after 100 of 1000000000000"), "{}", answer.error_message);
    assert_eq!(node.simulator().state().time, 0.0);
    assert!(node.paused());
    // unpausing interrupts a request too; StepSimulation while playing is refused
    node.request_steps(1_000_000, &mut sink).unwrap();
    node.tick(Duration::ZERO, &mut sink);
    node.set_paused(false, &mut sink);
    assert_eq!(sink.answers.pop().unwrap().1.result, result_code::OPERATION_FAILED);
    assert_eq!(node.request_steps(1, &mut sink).unwrap_err().result, result_code::INCORRECT_STATE);
    // shutdown answers a request under way
    node.set_paused(true, &mut sink);
    let last = node.request_steps(u64::MAX, &mut sink).unwrap();
    node.tick(Duration::ZERO, &mut sink);
    node.shutdown(&mut sink);
    let (ticket, answer) = sink.answers.pop().unwrap();
    assert_eq!(ticket, last);
    assert!(answer.error_message.contains("shutting down"), "{}", answer.error_message);
}

#[test]
fn a_physics_failure_pauses_with_an_error_status_and_reset_recovers() {
    // a Newton budget of one iteration and no step cutting: a fast winch cannot be followed
    let model = bundled("prism3.toml");
    let settings = SimSettings {
        newton: NewtonSettings { max_iterations: 1, ..Default::default() },
        min_dt: 1e-3,
        ..Default::default()
    };
    let sim = Simulator::new(model, settings).unwrap();
    let mut node = NodeCore::with_simulator(sim, NodeParams { real_time_factor: 0.0, ..Default::default() });
    let mut sink = MemorySink::default();
    node.start(&mut sink);
    for k in 0..5 {
        node.tick(k * MS, &mut sink);
    }
    assert_eq!(node.stats().steps, 5, "at rest one iteration is enough");
    let fast =
        msg::ActuatorCommand { name: vec!["ring_winch".into()], rate: vec![-5.0], ..Default::default() };
    node.offer_command(&fast);
    for k in 5..200 {
        node.tick(k * MS, &mut sink);
        if node.fault().is_some() {
            break;
        }
    }
    let fault = node.fault().expect("the fast winch defeats a one-iteration Newton").to_string();
    assert!(node.paused());
    assert_eq!(node.stats().physics_failures, 1);
    let error = sink.statuses.iter().find(|s| s.level == 2).expect("an ERROR status");
    assert!(
        error.message.contains("physics failure at step") && error.message.contains("reset"),
        "{}",
        error.message
    );
    assert_eq!(error.message, fault);
    // still serving: StepSimulation is refused with the cause, reset recovers and steps again
    let refused = node.request_steps(1, &mut sink).unwrap_err();
    assert!(refused.error_message.contains("physics failure"), "{}", refused.error_message);
    let steps_before = node.stats().steps;
    node.reset(&mut sink);
    assert!(node.fault().is_none());
    assert_eq!(node.simulator().state().time, 0.0);
    node.set_paused(false, &mut sink);
    for k in 0..5 {
        node.tick((300 + k) * MS, &mut sink);
    }
    assert_eq!(node.stats().steps, steps_before + 5);
}

#[test]
fn late_steps_are_overruns_and_never_caught_up_in_bursts() {
    let mut node = core(NodeParams { real_time_factor: 1.0, ..Default::default() });
    let mut sink = MemorySink::default();
    // on time: each turn asks for the next one a step (1 ms) later
    let mut now = Duration::ZERO;
    for _ in 0..10 {
        let wake = node.tick(now, &mut sink).expect("paced");
        assert!(wake > now && wake <= now + 2 * MS, "{wake:?} after {now:?}");
        now = wake;
    }
    assert_eq!(node.stats().overruns, 0);
    // 50 ms late (a stalled machine): one overrun, and the next turn is due a step later, not at once
    now += 50 * MS;
    let wake = node.tick(now, &mut sink);
    assert_eq!(node.stats().overruns, 1);
    let next = node.tick(wake.unwrap_or(now), &mut sink).expect("paced again");
    assert!(next > now, "no burst to catch up");
    assert_eq!(node.stats().overruns, 1);
}

#[test]
fn the_command_timeout_holds_the_winches_and_says_so() {
    let mut node = core(NodeParams { real_time_factor: 0.0, command_timeout: 0.05, ..Default::default() });
    let mut sink = MemorySink::default();
    let pull =
        msg::ActuatorCommand { name: vec!["ring_winch".into()], rate: vec![-0.001], ..Default::default() };
    node.offer_command(&pull);
    for k in 0..100 {
        node.tick(k * MS, &mut sink);
    }
    assert_eq!(node.stats().command_timeouts, 1);
    let status = sink.statuses.iter().find(|s| s.message.contains("command timeout")).expect("reported");
    assert_eq!(status.level, 1);
}

#[test]
fn the_lowest_natural_frequencies_are_reported_once_at_start_up() {
    let mut node = core(NodeParams::default());
    let mut sink = MemorySink::default();
    node.start(&mut sink);
    let modes = sink.statuses.iter().find(|s| s.name.ends_with("modes")).expect("a modes status");
    assert_eq!(modes.level, 0, "{}", modes.message);
    let f1: f64 = MemorySink::value(modes, "mode_1_hz").unwrap().parse().unwrap();
    assert!((f1 - 1.1603).abs() < 1e-3, "prism3's lowest mode is 1.1603 Hz (tensegrity modes): {f1}");
    assert_eq!(MemorySink::value(modes, "zero_frequency_modes").as_deref(), Some("0"));
}

/// With `-p tolerance:=...` the node takes error-controlled sub-steps inside every physics step:
/// its clock and its outputs stay on the regular physics_dt grid, sub-steps the error estimate
/// rejects never show, and nothing non-finite is published, even while a winch is driven back and
/// forth as fast as it goes (the sink asserts finiteness on every sample).
#[test]
fn error_controlled_sub_steps_keep_the_publish_times_regular_and_finite() {
    for integrator in ["generalized-alpha", "dormand-prince"] {
        let params = NodeParams {
            real_time_factor: 0.0,
            state_publish_rate: 0.0,
            integrator: integrator.into(),
            tolerance: 1e-7,
            physics_dt: Some(0.005),
            ..Default::default()
        };
        let mut node = core(params);
        let mut sink = MemorySink::default();
        node.start(&mut sink);
        for step in 0..400u64 {
            if step % 50 == 0 {
                let rate = if step % 100 == 0 { -0.5 } else { 0.5 };
                node.offer_command(&msg::ActuatorCommand {
                    name: vec!["ring_winch".into()],
                    rate: vec![rate],
                    ..Default::default()
                });
            }
            node.tick(Duration::from_micros(step * 5000), &mut sink);
        }
        let times: Vec<f64> =
            sink.published.iter().filter(|(t, _)| *t == Topic::CableStates).map(|(_, time)| *time).collect();
        assert_eq!(times.len(), 401, "{integrator}: the start and every step");
        for (k, t) in times.iter().enumerate() {
            assert!((t - 0.005 * k as f64).abs() < 1e-12, "{integrator}: sample {k} at {t} s");
        }
        let s = node.stats();
        assert!(s.physics_failures == 0, "{integrator}: {s:?}");
        assert!(s.rejected_attempts > 0, "{integrator}: the error estimate rejected sub-steps on the way");
    }
}

#[test]
fn tension_commands_arrive_on_their_own_message_or_as_a_joint_effort_and_careless_ones_are_refused() {
    let scene = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("config/examples/tensioner.toml");
    let model = tensegrity::scene::load(&scene).unwrap();
    let mut node = NodeCore::new(model, NodeParams { real_time_factor: 0.0, ..Default::default() }).unwrap();
    let mut sink = MemorySink::default();
    let name = vec!["tensioner".to_string()];
    let tension = |t: Vec<f64>| msg::TensionCommand { name: name.clone(), tension: t, ..Default::default() };
    let joint = |position: Vec<f64>, effort: Vec<f64>| msg::JointState {
        name: name.clone(),
        position,
        effort,
        ..Default::default()
    };
    // refused whole: no tension, two for one name, NaN, negative, over the stall tension
    for bad in [vec![], vec![1.0, 2.0], vec![f64::NAN], vec![-1.0], vec![100.5]] {
        node.offer_tension_command(&tension(bad));
    }
    assert_eq!(node.stats().commands_rejected, 5);
    node.offer_tension_command(&tension(vec![30.0]));
    node.tick(Duration::ZERO, &mut sink);
    assert_eq!(sink.applied[0].1[0].1, tensegrity::control::ActuatorCommand::tension(30.0));
    // a JointState's effort is a tension only when it carries neither position nor velocity
    node.offer_joint_command(&joint(vec![], vec![40.0]));
    node.tick(MS, &mut sink);
    assert_eq!(sink.applied[1].1[0].1, tensegrity::control::ActuatorCommand::tension(40.0));
    node.offer_joint_command(&joint(vec![1.1], vec![40.0]));
    node.tick(2 * MS, &mut sink);
    assert_eq!(sink.applied[2].1[0].1, tensegrity::control::ActuatorCommand::target(1.1));
    assert_eq!(node.stats().commands_rejected, 5);
    assert_eq!(node.stats().commands_accepted, 3);
}
