//! The roles a child process plays in DDS fault tests (see `peer::spawn_role`): a controller that
//! floods the node with commands, many malformed; a subscriber that subscribes and then stops (the
//! test freezes it with SIGSTOP); and a subscriber that reads state and checks every number.
#![allow(dead_code)]

use std::time::{Duration, Instant};

use ros2_client::qos::WhenFull;
use tensegrity::io::msg;
use tensegrity::io::ros2::qos;

use super::peer::{Peer, NS};

/// Runs the role named by `TENSEGRITY_ROLE`, if any, and returns true (the caller then returns).
pub fn play_role_if_asked(domain: u16) -> bool {
    let Ok(role) = std::env::var("TENSEGRITY_ROLE") else { return false };
    match role.as_str() {
        "flooder" => flooder(domain),
        "frozen-subscriber" => frozen_subscriber(domain),
        "checking-subscriber" => checking_subscriber(domain),
        other => panic!("unknown role {other}"),
    }
    true
}

fn env_path(key: &str) -> Option<std::path::PathBuf> {
    std::env::var_os(key).map(Into::into)
}

/// Commands in a fixed cycle: one valid in three, the rest malformed in every way the node must
/// refuse (NaN, infinite, huge and negative values, unknown and repeated names, mismatched and empty
/// arrays, a 100 kB name). Returns the message and whether it is valid.
pub fn flood_message(k: u64) -> (msg::ActuatorCommand, bool) {
    let cmd = |name: Vec<String>, rest_length: Vec<f64>, rate: Vec<f64>| msg::ActuatorCommand {
        name,
        rest_length,
        rate,
        ..Default::default()
    };
    let w = || vec!["ring_winch".to_string()];
    if k % 3 == 0 {
        let rate = if k % 2 == 0 { 1e-4 } else { -1e-4 };
        return (cmd(w(), vec![], vec![rate]), true);
    }
    let bad = match (k / 3) % 10 {
        0 => cmd(w(), vec![f64::NAN], vec![]),
        1 => cmd(w(), vec![f64::INFINITY], vec![]),
        2 => cmd(w(), vec![1e300], vec![]),
        3 => cmd(w(), vec![-1.0], vec![]),
        4 => cmd(vec!["no_such_winch".into()], vec![1.0], vec![]),
        5 => cmd(vec!["ring_winch".into(), "ring_winch".into()], vec![5.0, 5.0], vec![]),
        6 => cmd(w(), vec![5.0, 5.0], vec![]),
        7 => cmd(vec![], vec![], vec![]),
        8 => cmd(vec!["z".repeat(100_000)], vec![5.0], vec![]),
        _ => cmd(w(), vec![], vec![f64::NEG_INFINITY]),
    };
    (bad, false)
}

/// Publishes `flood_message`s as fast as its writer takes them for `TENSEGRITY_FLOOD_SECS`
/// seconds (default: until killed), then writes "valid malformed" counts of the samples the
/// writer accepted to `TENSEGRITY_COUNTS`.
fn flooder(domain: u16) {
    let secs: f64 = std::env::var("TENSEGRITY_FLOOD_SECS").ok().and_then(|s| s.parse().ok()).unwrap_or(1e9);
    let mut peer = Peer::new(domain, "flooder");
    let q = qos(64, false).reliability_reliable(WhenFull::Fail);
    let publisher = peer.publisher::<msg::ActuatorCommand>(
        NS,
        "actuator_commands",
        "tensegrity_msgs",
        "ActuatorCommand",
        q,
    );
    std::thread::sleep(Duration::from_secs(2)); // discovery
    let start = Instant::now();
    let (mut k, mut valid, mut malformed) = (0u64, 0u64, 0u64);
    while start.elapsed().as_secs_f64() < secs {
        let (m, ok) = flood_message(k);
        k += 1;
        if publisher.publish(m).is_ok() {
            if ok {
                valid += 1;
            } else {
                malformed += 1;
            }
        }
    }
    std::thread::sleep(Duration::from_millis(500)); // let the last samples be delivered
    if let Some(path) = env_path("TENSEGRITY_COUNTS") {
        std::fs::write(path, format!("{valid} {malformed}")).unwrap();
    }
}

/// Subscribes reliably (KeepLast 10) to `/clock`, `/diagnostics`, `~/body_poses` and
/// `~/cable_states`, never reads, and leaves cleanly once `TENSEGRITY_STOP_FILE` exists. The test
/// freezes it with SIGSTOP (what Ctrl-Z does to `ros2 topic echo`).
fn frozen_subscriber(domain: u16) {
    let mut peer = Peer::new(domain, "frozen");
    let _clock = peer.subscribe::<msg::Clock>("/", "clock", "rosgraph_msgs", "Clock", 10);
    let _diag =
        peer.subscribe::<msg::DiagnosticArray>("/", "diagnostics", "diagnostic_msgs", "DiagnosticArray", 10);
    let _poses = peer.subscribe::<msg::PoseArray>(NS, "body_poses", "geometry_msgs", "PoseArray", 10);
    let _cables =
        peer.subscribe::<msg::CableStates>(NS, "cable_states", "tensegrity_msgs", "CableStates", 10);
    let stop = env_path("TENSEGRITY_STOP_FILE");
    while !stop.as_ref().is_some_and(|p| p.exists()) {
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// Reads `~/cable_states`, `~/body_poses` and `/tf` until killed and creates `TENSEGRITY_BAD_FILE`
/// if any number in them is not finite.
fn checking_subscriber(domain: u16) {
    let mut peer = Peer::new(domain, "checker");
    let cables = peer.subscribe::<msg::CableStates>(NS, "cable_states", "tensegrity_msgs", "CableStates", 10);
    let poses = peer.subscribe::<msg::PoseArray>(NS, "body_poses", "geometry_msgs", "PoseArray", 10);
    let tf = peer.subscribe::<msg::TfMessage>("/", "tf", "tf2_msgs", "TFMessage", 10);
    let bad = env_path("TENSEGRITY_BAD_FILE");
    loop {
        let mut finite = true;
        while let Ok(Some((m, _))) = cables.take() {
            finite &= m.is_finite();
        }
        while let Ok(Some((m, _))) = poses.take() {
            finite &= m.poses.iter().all(|p| {
                [p.position.x, p.position.y, p.position.z, p.orientation.w].iter().all(|x| x.is_finite())
            });
        }
        while let Ok(Some((m, _))) = tf.take() {
            finite &= m.transforms.iter().all(|t| t.transform.translation.x.is_finite());
        }
        if !finite {
            if let Some(p) = &bad {
                std::fs::write(p, "non-finite value received").unwrap();
            }
        }
        std::thread::sleep(Duration::from_millis(5));
    }
}
