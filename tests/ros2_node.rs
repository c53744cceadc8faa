//! Invariant: the ROS 2 node, started in-process with no launch file, talks DDS the way ROS 2
//! controllers expect. A controller on a second `Context` receives body poses and cable states
//! stamped with simulation time, a `/clock` that only moves forward, and (as a late joiner) the
//! transient-local structure; shortening a cable by command raises its tension as statics
//! predicts; a NaN or unknown-name command is rejected, reported in `/diagnostics`, and the node
//! keeps publishing; StepSimulation while paused advances exactly N steps and reset restores the
//! start; a command timeout stops the winches; and an Eclipse Cyclone DDS controller (Python)
//! reads the state and drives the node.
//!
//! Network rule: every DDS socket must stay on this machine, so each test first re-executes
//! itself inside a private network namespace that has only a loopback interface (with multicast
//! on, for discovery), the same set-up as `loopback-net`; each test uses its own domain id.

#![cfg(feature = "ros2")]

mod common;
use common::{bundled, netns, peer, running_node};

use std::time::{Duration, Instant};

use ros2_client::{MessageTypeName, Name, NodeName, NodeOptions};
use tensegrity::io::msg;
use tensegrity::io::node::params::NodeParams;
use tensegrity::io::ros2::{context, qos};

use peer::wait_for;

use running_node::RunningNode;

fn isolated_or_rerun(test: &str) -> bool {
    netns::isolated_or_rerun(&["--exact", test, "--nocapture", "--test-threads=1"])
}

#[test]
fn controller_sees_state_drives_a_cable_and_bad_commands_are_rejected() {
    if !isolated_or_rerun("controller_sees_state_drives_a_cable_and_bad_commands_are_rejected") {
        return;
    }
    let domain = 61;
    let params = NodeParams {
        domain_id: domain,
        real_time_factor: 1.0,
        state_publish_rate: 100.0,
        ..Default::default()
    };
    let model = bundled("prism3.toml");
    let ring = model.cable_id("ring").unwrap().0;
    let l0 = model.initial_rest_lengths[ring];
    let node = RunningNode::start(model, params);

    // the controller: a second Context on the same domain
    let ctx = context(domain, false).unwrap();
    let mut ctl = ctx.new_node(NodeName::new("/", "controller").unwrap(), NodeOptions::new()).unwrap();
    let topic = |ns: &str, name: &str, pkg: &str, ty: &str, q| {
        ctl.create_topic(&Name::new(ns, name).unwrap(), MessageTypeName::new(pkg, ty), &q).unwrap()
    };
    let t_cables = topic("/tensegrity_sim", "cable_states", "tensegrity_msgs", "CableStates", qos(10, false));
    let t_poses = topic("/tensegrity_sim", "body_poses", "geometry_msgs", "PoseArray", qos(10, false));
    let t_clock = topic("/", "clock", "rosgraph_msgs", "Clock", qos(1, false));
    let t_diag = topic("/", "diagnostics", "diagnostic_msgs", "DiagnosticArray", qos(10, false));
    let t_cmd =
        topic("/tensegrity_sim", "actuator_commands", "tensegrity_msgs", "ActuatorCommand", qos(1, false));
    let t_structure = topic("/tensegrity_sim", "structure", "tensegrity_msgs", "Structure", qos(1, true));
    let cables = ctl.create_subscription::<msg::CableStates>(&t_cables, None).unwrap();
    let poses = ctl.create_subscription::<msg::PoseArray>(&t_poses, None).unwrap();
    let clock = ctl.create_subscription::<msg::Clock>(&t_clock, None).unwrap();
    let diagnostics = ctl.create_subscription::<msg::DiagnosticArray>(&t_diag, None).unwrap();
    let commands = ctl.create_publisher::<msg::ActuatorCommand>(&t_cmd, None).unwrap();

    // poses and cable states arrive, stamped with sim time; the clock only moves forward
    let first =
        wait_for(Duration::from_secs(10), || cables.take().ok().flatten()).expect("cable states arrive").0;
    assert_eq!(first.name.len(), 4);
    assert!(first.is_finite());
    let p = wait_for(Duration::from_secs(5), || poses.take().ok().flatten()).expect("poses arrive").0;
    assert_eq!(p.poses.len(), 3);
    assert_eq!(p.header.frame_id, "world");
    let mut last = 0.0;
    let mut ticks = 0;
    let mut stamps_ok = 0;
    let start = Instant::now();
    while ticks < 200 && start.elapsed() < Duration::from_secs(10) {
        if let Ok(Some((c, _))) = clock.take() {
            let t = c.clock.seconds();
            assert!(t > last, "clock went from {last} to {t}");
            last = t;
            ticks += 1;
        }
        if let Ok(Some((m, _))) = cables.take() {
            // sim-time stamps on the physics grid (1 ms)
            let t = m.header.stamp.seconds();
            assert!((t * 1000.0 - (t * 1000.0).round()).abs() < 1e-6, "stamp {t} is not a step time");
            stamps_ok += 1;
        }
        std::thread::sleep(Duration::from_micros(200));
    }
    assert!(ticks >= 200 && stamps_ok > 5, "{ticks} clock ticks, {stamps_ok} cable messages");

    // shorten the ring by 5 %: its tension rises towards the static value (811 N from 100 N)
    let t0 = first.tension[ring];
    commands
        .publish(msg::ActuatorCommand {
            name: vec!["ring_winch".into()],
            rest_length: vec![0.95 * l0],
            ..Default::default()
        })
        .unwrap();
    let raised = wait_for(Duration::from_secs(10), || {
        cables
            .take()
            .ok()
            .flatten()
            .filter(|(m, _)| (m.rest_length[ring] - 0.95 * l0).abs() < 1e-9 && m.tension[ring] > 5.0 * t0)
            .map(|(m, _)| m)
    });
    assert!(raised.is_some(), "the commanded shortening reaches its target and raises the ring tension");

    // a NaN command is rejected and reported; the node keeps publishing
    commands
        .publish(msg::ActuatorCommand {
            name: vec!["ring_winch".into()],
            rest_length: vec![f64::NAN],
            ..Default::default()
        })
        .unwrap();
    let report = wait_for(Duration::from_secs(5), || {
        diagnostics
            .take()
            .ok()
            .flatten()
            .filter(|(d, _)| d.status.iter().any(|s| s.message.contains("rejected")))
            .map(|(d, _)| d)
    });
    assert!(report.is_some(), "the rejection is reported in /diagnostics");
    let before = last;
    let after = wait_for(Duration::from_secs(5), || {
        clock.take().ok().flatten().map(|(c, _)| c.clock.seconds()).filter(|t| *t > before + 0.1)
    });
    assert!(after.is_some(), "the node keeps running after a bad command");
    // so is a command for an actuator that does not exist
    commands
        .publish(msg::ActuatorCommand {
            name: vec!["no_such_winch".into()],
            rest_length: vec![1.0],
            ..Default::default()
        })
        .unwrap();
    let second =
        wait_for(Duration::from_secs(5), || {
            diagnostics.take().ok().flatten().filter(|(d, _)| {
                d.status.iter().any(|s| s.message.contains("unknown actuator 'no_such_winch'"))
            })
        });
    assert!(second.is_some(), "the unknown name is reported in /diagnostics");

    // a late subscriber still gets the structure (transient local)
    let structure = ctl.create_subscription::<msg::Structure>(&t_structure, Some(qos(1, true))).unwrap();
    let s = wait_for(Duration::from_secs(10), || structure.take().ok().flatten())
        .expect("late joiner receives the structure")
        .0;
    assert_eq!(s.cable_names, vec!["side0", "side1", "side2", "ring"]);

    let stats = node.stop();
    assert_eq!(stats.commands_rejected, 2);
    assert!(stats.commands_received >= 3);
}

/// Sends one request and waits up to 10 s for its response.
fn call<Req, Resp>(client: &ros2_client::Client<Req, Resp>, req: Req) -> Resp
where
    Req: ros2_client::Message + Clone + 'static,
    Resp: ros2_client::Message + 'static,
{
    peer::call(client, req, Duration::from_secs(10)).expect("service answered")
}

#[test]
fn lockstep_services_step_exactly_n_steps_and_reset_restores_the_start() {
    if !isolated_or_rerun("lockstep_services_step_exactly_n_steps_and_reset_restores_the_start") {
        return;
    }
    use ros2_client::{ServiceMapping, ServiceTypeName};
    let domain = 62;
    let params =
        NodeParams { domain_id: domain, start_paused: true, state_publish_rate: 0.0, ..Default::default() };
    let model = bundled("tbar.toml");
    let initial_rest = model.initial_rest_lengths.clone();
    let node = RunningNode::start(model, params);
    let ctx = context(domain, false).unwrap();
    let mut ctl = ctx.new_node(NodeName::new("/", "controller").unwrap(), NodeOptions::new()).unwrap();
    let ns = "/tensegrity_sim";
    macro_rules! client {
        ($name:expr, $pkg:expr, $ty:expr) => {
            ctl.create_client(
                ServiceMapping::Enhanced,
                &Name::new(ns, $name).unwrap(),
                &ServiceTypeName::new($pkg, $ty),
                qos(10, false),
                qos(10, false),
            )
            .unwrap()
        };
    }
    let step: ros2_client::Client<msg::StepSimulationRequest, msg::ResultResponse> =
        client!("step_simulation", "simulation_interfaces", "StepSimulation");
    let get_state: ros2_client::Client<msg::Empty, msg::GetSimulationStateResponse> =
        client!("get_simulation_state", "simulation_interfaces", "GetSimulationState");
    let set_state: ros2_client::Client<msg::SetSimulationStateRequest, msg::ResultResponse> =
        client!("set_simulation_state", "simulation_interfaces", "SetSimulationState");
    let reset: ros2_client::Client<msg::ResetSimulationRequest, msg::ResultResponse> =
        client!("reset_simulation", "simulation_interfaces", "ResetSimulation");
    let features: ros2_client::Client<msg::Empty, msg::GetSimulatorFeaturesResponse> =
        client!("get_simulator_features", "simulation_interfaces", "GetSimulatorFeatures");
    let unpause: ros2_client::Client<msg::Empty, msg::Empty> = client!("unpause", "std_srvs", "Empty");
    let t_clock = ctl
        .create_topic(
            &Name::new("/", "clock").unwrap(),
            MessageTypeName::new("rosgraph_msgs", "Clock"),
            &qos(1, false),
        )
        .unwrap();
    let clock = ctl.create_subscription::<msg::Clock>(&t_clock, Some(qos(1000, false))).unwrap();
    let t_cables = ctl
        .create_topic(
            &Name::new(ns, "cable_states").unwrap(),
            MessageTypeName::new("tensegrity_msgs", "CableStates"),
            &qos(10, false),
        )
        .unwrap();
    let cables = ctl.create_subscription::<msg::CableStates>(&t_cables, Some(qos(1000, false))).unwrap();
    std::thread::sleep(Duration::from_millis(1500)); // discovery of every service pair

    assert_eq!(call(&get_state, msg::Empty::default()).state.state, 2, "starts paused");
    let f = call(&features, msg::Empty::default()).features;
    assert!(f.features.contains(&31) && f.features.contains(&32) && f.features.contains(&20));

    // StepSimulation of 25 steps while paused advances exactly 25 steps of 1 ms
    assert_eq!(call(&step, msg::StepSimulationRequest { steps: 25 }).result.result, 1);
    let mut ticks = Vec::new();
    while let Some(t) =
        wait_for(Duration::from_millis(300), || clock.take().ok().flatten().map(|(c, _)| c.clock.seconds()))
    {
        ticks.push(t);
    }
    assert_eq!(ticks.len(), 25, "one clock tick per step: {ticks:?}");
    assert!((ticks[24] - 0.025).abs() < 1e-9, "{ticks:?}");
    assert!(ticks.windows(2).all(|w| (w[1] - w[0] - 0.001).abs() < 1e-9));

    // not while playing
    call(&unpause, msg::Empty::default());
    assert_eq!(call(&get_state, msg::Empty::default()).state.state, 1);
    assert_eq!(
        call(&step, msg::StepSimulationRequest { steps: 1 }).result.result,
        3,
        "INCORRECT_STATE while playing"
    );
    let r = call(&set_state, msg::SetSimulationStateRequest { state: msg::SimulationState { state: 2 } });
    assert_eq!(r.result.result, 1);
    let r = call(&set_state, msg::SetSimulationStateRequest { state: msg::SimulationState { state: 2 } });
    assert_eq!(r.result.result, 101, "ALREADY_IN_TARGET_STATE");

    // reset restores the initial time and rest lengths
    assert_eq!(call(&reset, msg::ResetSimulationRequest { scope: 0 }).result.result, 1);
    let restored = wait_for(Duration::from_secs(5), || {
        cables.take().ok().flatten().filter(|(m, _)| m.header.stamp.seconds() == 0.0).map(|(m, _)| m)
    })
    .expect("the reset state is published at t = 0");
    assert_eq!(restored.rest_length, initial_rest);

    node.stop();
}

#[test]
fn cyclone_dds_controller_reads_state_and_drives_the_node() {
    if !isolated_or_rerun("cyclone_dds_controller_reads_state_and_drives_the_node") {
        return;
    }
    let domain = 63;
    let params = NodeParams {
        domain_id: domain,
        real_time_factor: 1.0,
        state_publish_rate: 100.0,
        ..Default::default()
    };
    let model = bundled("prism3.toml");
    let ring = model.cable_id("ring").unwrap().0;
    let target = 0.97 * model.initial_rest_lengths[ring];
    let node = RunningNode::start(model, params);
    let script =
        std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/interop/cyclone_controller.py");
    // .ci/test puts the Cyclone DDS binding in a virtual environment and names its interpreter
    let python = std::env::var("TENSEGRITY_PYTHON").unwrap_or_else(|_| "python3".into());
    let out = std::process::Command::new(&python)
        .arg(&script)
        .args([domain.to_string(), "ring_winch".into(), ring.to_string(), format!("{target:.17}")])
        .env(
            "CYCLONEDDS_URI",
            "<CycloneDDS><Domain id=\"any\"><Discovery><ParticipantIndex>auto</ParticipantIndex><Peers><Peer address=\"127.0.0.1\"/></Peers></Discovery></Domain></CycloneDDS>",
        )
        .output()
        .expect("python runs (bash .ci/test installs the cyclonedds package in target/pyenv)");
    let stats = node.stop();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "Cyclone controller failed: {stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(stdout.starts_with("OK"), "{stdout}");
    assert!(stdout.contains("bodies 3") && stdout.contains("'ring'"), "{stdout}");
    let number = |key: &str| -> f64 {
        let rest = &stdout[stdout.find(key).unwrap() + key.len()..];
        rest.split_whitespace().next().unwrap().parse().unwrap()
    };
    assert!(number("tension_after ") > number("tension_before "), "{stdout}");
    assert!(stats.commands_received >= 1 && stats.commands_rejected == 0);
}

#[test]
fn command_timeout_stops_the_winch_and_markers_show_the_structure() {
    if !isolated_or_rerun("command_timeout_stops_the_winch_and_markers_show_the_structure") {
        return;
    }
    use ros2_client::{ServiceMapping, ServiceTypeName};
    let domain = 64;
    let params = NodeParams {
        domain_id: domain,
        start_paused: true,
        state_publish_rate: 0.0,
        command_timeout: 0.05,
        command_timeout_action: "hold".into(),
        ..Default::default()
    };
    let model = bundled("prism3.toml");
    let ring = model.cable_id("ring").unwrap().0;
    let l0 = model.initial_rest_lengths[ring];
    let segments: usize = model.cables.iter().map(|c| c.segment_count()).sum();
    let node = RunningNode::start(model, params);
    let ctx = context(domain, false).unwrap();
    let mut ctl = ctx.new_node(NodeName::new("/", "controller").unwrap(), NodeOptions::new()).unwrap();
    let ns = "/tensegrity_sim";
    let step: ros2_client::Client<msg::StepSimulationRequest, msg::ResultResponse> = ctl
        .create_client(
            ServiceMapping::Enhanced,
            &Name::new(ns, "step_simulation").unwrap(),
            &ServiceTypeName::new("simulation_interfaces", "StepSimulation"),
            qos(10, false),
            qos(10, false),
        )
        .unwrap();
    let topic = |name: &str, pkg: &str, ty: &str, depth| {
        ctl.create_topic(&Name::new(ns, name).unwrap(), MessageTypeName::new(pkg, ty), &qos(depth, false))
            .unwrap()
    };
    let t_cables = topic("cable_states", "tensegrity_msgs", "CableStates", 10);
    let t_markers = topic("markers", "visualization_msgs", "MarkerArray", 1);
    let t_cmd = topic("actuator_commands", "tensegrity_msgs", "ActuatorCommand", 1);
    let cables = ctl.create_subscription::<msg::CableStates>(&t_cables, Some(qos(1000, false))).unwrap();
    let markers = ctl.create_subscription::<msg::MarkerArray>(&t_markers, Some(qos(100, false))).unwrap();
    let commands = ctl.create_publisher::<msg::ActuatorCommand>(&t_cmd, None).unwrap();
    std::thread::sleep(Duration::from_millis(1500)); // discovery

    // reel in at 0.1 m/s, then say nothing more: after 0.05 s of sim time the winch must stop
    commands
        .publish(msg::ActuatorCommand {
            name: vec!["ring_winch".into()],
            rate: vec![-0.1],
            ..Default::default()
        })
        .unwrap();
    std::thread::sleep(Duration::from_millis(500)); // taken while paused, at t = 0
    assert_eq!(call(&step, msg::StepSimulationRequest { steps: 200 }).result.result, 1);
    let mut rest = Vec::new();
    while let Some(m) = wait_for(Duration::from_millis(300), || cables.take().ok().flatten()) {
        rest.push((m.0.header.stamp.seconds(), m.0.rest_length[ring]));
    }
    let (t_end, l_end) = *rest.last().expect("cable states during the steps");
    assert!((t_end - 0.2).abs() < 1e-9, "{t_end}");
    assert!((l_end - (l0 - 0.1 * 0.05)).abs() < 1e-9, "winch stopped at {l_end}, expected {}", l0 - 0.005);
    for (t, l) in &rest {
        if *t > 0.0505 {
            assert!((l - l_end).abs() < 1e-12, "moved after the timeout: {l} at {t}");
        }
    }

    // the markers: struts, and cable segments coloured one colour per point
    let m = wait_for(Duration::from_secs(5), || markers.take().ok().flatten()).expect("markers arrive").0;
    let by_ns = |ns: &str| m.markers.iter().find(|k| k.ns == ns).unwrap_or_else(|| panic!("no {ns} marker"));
    assert_eq!(by_ns("struts").points.len(), 2 * 3 * 2, "bar a-b as two half-lines from the centre");
    let c = by_ns("cables");
    assert_eq!(c.points.len(), 2 * segments);
    assert_eq!(c.colors.len(), c.points.len());
    assert_eq!(c.kind, 5);

    let stats = node.stop();
    assert_eq!(stats.command_timeouts, 1);
}

#[test]
fn a_robot_on_the_ground_publishes_its_contacts() {
    if !isolated_or_rerun("a_robot_on_the_ground_publishes_its_contacts") {
        return;
    }
    let domain = 73;
    let params = NodeParams {
        domain_id: domain,
        real_time_factor: 1.0,
        state_publish_rate: 100.0,
        start_from_equilibrium: true,
        ..Default::default()
    };
    let model = bundled("sixbar.toml");
    let weight: f64 = model.bodies.iter().map(|b| b.mass).sum::<f64>() * 9.81;
    let _node = RunningNode::start(model, params);
    let ctx = context(domain, false).unwrap();
    let mut ctl = ctx.new_node(NodeName::new("/", "controller").unwrap(), NodeOptions::new()).unwrap();
    let t_contacts = ctl
        .create_topic(
            &Name::new("/tensegrity_sim", "contacts").unwrap(),
            MessageTypeName::new("tensegrity_msgs", "ContactStates"),
            &qos(10, false),
        )
        .unwrap();
    let contacts = ctl.create_subscription::<msg::ContactStates>(&t_contacts, None).unwrap();
    let m = wait_for(Duration::from_secs(10), || contacts.take().ok().flatten())
        .expect("contact states arrive")
        .0;
    assert!(m.is_finite());
    assert_eq!(m.point.len(), 12, "two ends of six bars against one floor");
    assert!(m.ground.iter().all(|g| g == "floor"));
    // standing on its bottom face (the winch starts hauling at 0.2 s: the first messages stand)
    if m.header.stamp.seconds() < 0.2 {
        let carried: f64 = m.normal_force.iter().sum();
        assert!((carried - weight).abs() < 1e-3 * weight, "{carried} N of {weight} N");
        assert_eq!(m.in_contact.iter().filter(|c| **c).count(), 3);
    }
    assert!(m.normal.iter().all(|n| (n.z - 1.0).abs() < 1e-12));
}
