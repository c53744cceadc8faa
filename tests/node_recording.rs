//! Invariant: the node records what it published and what it applied. A controller on a second
//! DDS context drives the node (commands and a reset) while it records; the bag holds every
//! topic, reads back in the Python `rosbags` package with the applied commands as sent, and
//! replays bit for bit; a scene with one EA changed is caught; Ctrl-C closes the bag properly.
//!
//! Network rule: each test re-executes itself inside a private loopback-only network namespace
//! and uses its own domain id (77, 78).

#![cfg(feature = "ros2")]

mod common;
use common::{bags, netns, peer, running_node};

use std::time::Duration;

use tensegrity::io::msg;
use tensegrity::io::node::params::NodeParams;
use tensegrity::io::record;
use tensegrity::io::record::bag::BagReader;
use tensegrity::io::ros2::qos;

use bags::{applied_commands, floats, our_counts, rosbags_counts, rosbags_read};
use peer::{call, wait_for, NodeProcess, Peer, NS};
use running_node::RunningNode;

fn isolated_or_rerun(test: &str) -> bool {
    netns::isolated_or_rerun(&["--exact", test, "--nocapture", "--test-threads=1"])
}

fn bag_dir(name: &str) -> std::path::PathBuf {
    let d = std::env::temp_dir().join(format!("tensegrity-node-bags-{}", std::process::id())).join(name);
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(d.parent().unwrap()).unwrap();
    d
}

#[test]
fn the_node_records_what_it_published_and_applied_and_the_bag_replays_bit_for_bit() {
    let test = "the_node_records_what_it_published_and_applied_and_the_bag_replays_bit_for_bit";
    if !isolated_or_rerun(test) {
        return;
    }
    let domain = 77;
    let dir = bag_dir("driven");
    let scene = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("config/scenes/prism3.toml");
    let model = tensegrity::scene::load(&scene).unwrap();
    let params = NodeParams { domain_id: domain, record: Some(dir.clone()), ..Default::default() };
    let node = RunningNode::start(model, params);

    let mut ctl = Peer::new(domain, "controller");
    let cables = ctl.subscribe::<msg::CableStates>(NS, "cable_states", "tensegrity_msgs", "CableStates", 10);
    let commands = ctl.publisher::<msg::ActuatorCommand>(
        NS,
        "actuator_commands",
        "tensegrity_msgs",
        "ActuatorCommand",
        qos(1, false),
    );
    let reset: ros2_client::Client<msg::ResetSimulationRequest, msg::ResultResponse> = ctl.client(
        ros2_client::ServiceMapping::Enhanced,
        "reset_simulation",
        "simulation_interfaces",
        "ResetSimulation",
    );
    wait_for(Duration::from_secs(10), || cables.take().ok().flatten()).expect("the node's state arrives");
    // discovery both ways: the node must also have matched our writer before commands count
    std::thread::sleep(Duration::from_millis(500));
    let sent = [(4.2, 0.5), (4.0, 1.0), (4.4, 0.8)];
    let command = |(l, r): (f64, f64)| msg::ActuatorCommand {
        name: vec!["ring_winch".into()],
        rest_length: vec![l],
        rate: vec![r],
        ..Default::default()
    };
    commands.publish(command(sent[0])).unwrap();
    std::thread::sleep(Duration::from_millis(200));
    commands.publish(command(sent[1])).unwrap();
    std::thread::sleep(Duration::from_millis(200));
    let answer = call(&reset, msg::ResetSimulationRequest { scope: 0 }, Duration::from_secs(5))
        .expect("reset answered");
    assert_eq!(answer.result.result, 1);
    std::thread::sleep(Duration::from_millis(100));
    commands.publish(command(sent[2])).unwrap();
    std::thread::sleep(Duration::from_millis(300));
    let stats = node.stop();
    assert_eq!(stats.commands_accepted, 3, "{stats:?}");

    // the applied commands, in order, stamped with the steps at which they took effect
    let reader = BagReader::open(&dir).unwrap();
    assert!(reader.complete(), "the node closes its bag when it stops");
    let applied = applied_commands(&reader);
    assert_eq!(applied.len(), 4, "three commands and a reset: {applied:?}");
    assert!(applied[2].reset);
    for (a, (l, r)) in [&applied[0], &applied[1], &applied[3]].into_iter().zip(sent) {
        assert_eq!(
            (a.name.clone(), a.rest_length.clone(), a.rate.clone()),
            (vec!["ring_winch".to_string()], vec![l], vec![r])
        );
    }
    assert!(applied[0].step > 0 && applied[0].step < applied[1].step && applied[1].step <= applied[2].step);
    let ours = our_counts(&dir);
    for topic in [
        "/clock",
        "/tf",
        "/tf_static",
        "/diagnostics",
        "/tensegrity_sim/body_poses",
        "/tensegrity_sim/cable_states",
        "/tensegrity_sim/actuator_states",
        "/tensegrity_sim/structure",
        "/tensegrity_sim/markers",
    ] {
        assert!(ours.get(topic).is_some_and(|(_, n)| *n > 0), "{topic} missing: {ours:?}");
    }
    // state at 100 Hz of sim time, the clock every step (1 kHz)
    let (clock, states) = (ours["/clock"].1, ours["/tensegrity_sim/cable_states"].1);
    assert!(clock > 5 * states && states > 50, "clock {clock}, states {states}");

    // bit for bit again, with the commands and the reset at their recorded steps
    let report = record::replay(&dir, None, None).unwrap();
    assert_eq!(report.difference, None, "{report:?}");
    assert_eq!((report.command_batches, report.resets), (3, 1));
    assert!(report.compared > clock, "{report:?}");
    // one EA changed: caught at the start
    let text = std::fs::read_to_string(&scene).unwrap().replacen("ea = 50000.0", "ea = 49000.0", 1);
    let changed = record::replay(&dir, Some((&text, "changed")), None).unwrap();
    let d = changed.difference.expect("a changed scene differs");
    assert_eq!(d.step, 0, "{d}");

    if let Some(v) = rosbags_read(&dir) {
        assert_eq!(rosbags_counts(&v), ours);
        let seen = v["messages"]["/tensegrity_sim/applied_commands"].as_array().unwrap();
        assert_eq!(floats(&seen[3]["rest_length"]), vec![sent[2].0]);
        assert_eq!(seen[2]["reset"], true);
    }
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn ctrl_c_closes_the_node_bag() {
    if !isolated_or_rerun("ctrl_c_closes_the_node_bag") {
        return;
    }
    let dir = bag_dir("interrupted");
    let record = format!("record:={}", dir.display());
    let node = NodeProcess::start(78, &[&record]);
    std::thread::sleep(Duration::from_millis(2000));
    let (status, stderr) = node.stop("INT");
    assert!(status.success(), "{stderr}");
    let reader = BagReader::open(&dir).unwrap();
    assert!(reader.complete(), "Ctrl-C writes the summary and the end magic");
    let ours = our_counts(&dir);
    assert!(ours["/clock"].1 > 100, "{ours:?}");
    assert!(stderr.contains(&format!("bag {}", dir.display())), "the node says where its bag is: {stderr}");
    if let Some(v) = rosbags_read(&dir) {
        assert_eq!(rosbags_counts(&v), ours);
    }
    let _ = std::fs::remove_dir_all(&dir);
}
