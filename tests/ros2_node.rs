//! Invariant: the ROS 2 node, started in-process with no launch file, talks DDS the way ROS 2
//! controllers expect. A controller on a second `Context` receives body poses and cable states
//! stamped with simulation time, a `/clock` that only moves forward, and (as a late joiner) the
//! transient-local structure; shortening a cable by command raises its tension as statics
//! predicts; a NaN command is rejected, reported in `/diagnostics`, and the node keeps publishing.
//!
//! Network rule: every DDS socket must stay on this machine, so each test first re-executes
//! itself inside a private network namespace that has only a loopback interface (with multicast
//! on, for discovery), the same set-up as `loopback-net`; each test uses its own domain id.

#![cfg(feature = "ros2")]

use std::process::Command;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use ros2_client::{MessageTypeName, Name, NodeName, NodeOptions};
use tensegrity::io::msg;
use tensegrity::io::params::NodeParams;
use tensegrity::io::ros2::{context, qos, SimNode};

/// Interfaces of this process's network namespace (from /proc, which is per namespace).
fn interfaces() -> Vec<String> {
    std::fs::read_to_string("/proc/self/net/dev")
        .unwrap_or_default()
        .lines()
        .skip(2)
        .filter_map(|l| l.split(':').next().map(|s| s.trim().to_string()))
        .collect()
}

/// Returns true when already isolated; otherwise runs `test` again inside a loopback-only network
/// namespace, asserts it passed, and returns false.
fn isolated_or_rerun(test: &str) -> bool {
    if interfaces().iter().all(|i| i == "lo") {
        return true;
    }
    assert!(
        std::env::var_os("TENSEGRITY_NETNS").is_none(),
        "still not isolated inside the namespace: {:?}",
        interfaces()
    );
    let exe = std::env::current_exe().unwrap();
    let mut cmd = Command::new("unshare");
    cmd.arg("--net");
    if !std::process::Command::new("id")
        .arg("-u")
        .output()
        .map(|o| o.stdout.starts_with(b"0"))
        .unwrap_or(false)
    {
        cmd.arg("--map-root-user");
    }
    let status = cmd
        .args([
            "--",
            "sh",
            "-c",
            "ip link set lo up && ip link set lo multicast on && (ip route add 224.0.0.0/4 dev lo 2>/dev/null || true) && exec \"$0\" \"$@\"",
        ])
        .arg(exe)
        .args(["--exact", test, "--nocapture", "--test-threads=1"])
        .env("TENSEGRITY_NETNS", "1")
        .status()
        .expect("unshare (util-linux) and ip (iproute2) are needed to isolate DDS tests");
    assert!(status.success(), "{test} failed inside its network namespace");
    false
}

fn bundled(name: &str) -> tensegrity::Model {
    let path = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("config/scenes").join(name);
    tensegrity::scene::load(&path).unwrap()
}

/// Polls `f` every millisecond until it returns `Some` or `timeout` passes.
fn wait_for<T>(timeout: Duration, mut f: impl FnMut() -> Option<T>) -> Option<T> {
    let start = Instant::now();
    while start.elapsed() < timeout {
        if let Some(v) = f() {
            return Some(v);
        }
        std::thread::sleep(Duration::from_millis(1));
    }
    None
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
    let stop = Arc::new(AtomicBool::new(false));
    let node_stop = stop.clone();
    let node = std::thread::spawn(move || {
        let mut node = SimNode::new(model, params).unwrap();
        node.run(&node_stop).unwrap();
        node.stats()
    });

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

    // a late subscriber still gets the structure (transient local)
    let structure = ctl.create_subscription::<msg::Structure>(&t_structure, Some(qos(1, true))).unwrap();
    let s = wait_for(Duration::from_secs(10), || structure.take().ok().flatten())
        .expect("late joiner receives the structure")
        .0;
    assert_eq!(s.cable_names, vec!["side0", "side1", "side2", "ring"]);

    stop.store(true, Ordering::Relaxed);
    let stats = node.join().unwrap();
    assert_eq!(stats.commands_rejected, 1);
    assert!(stats.commands_received >= 2);
}
