//! Invariant: under a sustained hostile load the node stays up, bounded and truthful. For 60 s (or
//! `TENSEGRITY_SOAK_SECS`) the node process is flooded by a controller publishing mixed valid and
//! malformed commands as fast as its writer allows, a reliable subscriber is frozen with SIGSTOP
//! for most of the run, and a checking subscriber is killed and restarted every 5 s
//! (`TENSEGRITY_SOAK_CHURN_SECS`). At the end
//! the node is alive; its counts add up (`received = accepted + rejected`, no more received than
//! sent, no more accepted than valid ones sent, no more rejected than malformed ones sent); its
//! resident memory floor grew by less than 16 MB over the last third of the flood (the least RSS
//! of its last 10 s against the least of the 10 s that end two thirds into it: the node's bounded
//! buffers and the killed subscribers' discovery data fill up in the first part of the run, at a
//! pace the machine's load sets; transient buffers come and go; a leak raises the floor) and its
//! peak stayed under 256 MB; no subscriber saw a non-finite number;
//! and a valid command sent after the flood takes effect within 2 steps. The real-time factor
//! during the flood is printed, not asserted (machines are noisy).
//!
//! `cargo test --all-features --test node_soak -- --ignored` runs the 10-minute variant.

#![cfg(feature = "ros2")]

mod common;
use common::{netns, peer, roles};

use std::time::{Duration, Instant};

use ros2_client::ServiceMapping;
use tensegrity::io::msg;

use peer::{call, closing_counts, rss_kb, scratch_file, signal, spawn_role, wait_for, NodeProcess, Peer, NS};

const SEC: Duration = Duration::from_secs(1);

fn soak(test: &str, domain: u16, default_secs: u64) {
    if roles::play_role_if_asked(domain)
        || !netns::isolated_or_rerun(&[
            "--exact",
            test,
            "--nocapture",
            "--test-threads=1",
            "--include-ignored",
        ])
    {
        return;
    }
    let secs: u64 =
        std::env::var("TENSEGRITY_SOAK_SECS").ok().and_then(|s| s.parse().ok()).unwrap_or(default_secs);
    let flood_secs = secs.saturating_sub(8).max(10);
    // a SIGKILLed subscriber's participant and readers stay in the node's discovery data until
    // their lease ends (50 s for RustDDS peers): the kill period sets how many such ghosts pile up
    let churn_every = Duration::from_secs_f64(
        std::env::var("TENSEGRITY_SOAK_CHURN_SECS").ok().and_then(|s| s.parse().ok()).unwrap_or(5.0),
    );
    let mut node = NodeProcess::start(domain, &["state_publish_rate:=0", "real_time_factor:=1"]);
    let mut me = Peer::new(domain, "monitor");
    let actuators = me.subscribe::<msg::JointState>(NS, "actuator_states", "sensor_msgs", "JointState", 100);
    let diagnostics =
        me.subscribe::<msg::DiagnosticArray>("/", "diagnostics", "diagnostic_msgs", "DiagnosticArray", 100);

    let counts = scratch_file("flood-counts");
    let stop_frozen = scratch_file("frozen-stop");
    let bad = scratch_file("nonfinite");
    for f in [&counts, &stop_frozen, &bad] {
        let _ = std::fs::remove_file(f);
    }
    let mut flooder = spawn_role(
        test,
        "flooder",
        &[
            ("TENSEGRITY_FLOOD_SECS", flood_secs.to_string()),
            ("TENSEGRITY_COUNTS", counts.display().to_string()),
        ],
    );
    let mut frozen =
        spawn_role(test, "frozen-subscriber", &[("TENSEGRITY_STOP_FILE", stop_frozen.display().to_string())]);
    let checker_env = [("TENSEGRITY_BAD_FILE", bad.display().to_string())];
    let mut checker = spawn_role(test, "checking-subscriber", &checker_env);

    let start = Instant::now();
    let (mut frozen_now, mut last_restart) = (false, Instant::now());
    let mut rtf = Vec::new();
    let mut nonfinite = 0usize;
    let mut rss: Vec<u64> = Vec::new(); // kB, once a second
    while start.elapsed() < Duration::from_secs(flood_secs + 1) {
        let t = start.elapsed();
        if !frozen_now && t > 4 * SEC && t < Duration::from_secs(flood_secs) - 10 * SEC {
            signal(frozen.id(), "STOP");
            frozen_now = true;
        }
        if frozen_now && t > Duration::from_secs(flood_secs) - 10 * SEC {
            signal(frozen.id(), "CONT");
            std::fs::write(&stop_frozen, "stop").unwrap();
            frozen_now = false;
        }
        if last_restart.elapsed() > churn_every {
            signal(checker.id(), "KILL");
            let _ = checker.wait();
            checker = spawn_role(test, "checking-subscriber", &checker_env);
            last_restart = Instant::now();
        }
        if t.as_secs() > rss.len() as u64 {
            rss.push(rss_kb(node.pid()));
        }
        assert!(node.alive(), "the node died {:.1} s into the soak", t.as_secs_f64());
        while let Ok(Some((m, _))) = actuators.take() {
            nonfinite += [&m.position, &m.velocity, &m.effort]
                .iter()
                .flat_map(|v| v.iter())
                .filter(|x| !x.is_finite())
                .count();
        }
        while let Ok(Some((m, _))) = diagnostics.take() {
            for s in m.status.iter().filter(|s| s.name.ends_with("simulation")) {
                if let Some(v) = s.values.iter().find(|kv| kv.key == "real_time_factor") {
                    rtf.push(v.value.parse::<f64>().unwrap_or(f64::NAN));
                }
            }
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    let flood_status = flooder.wait().unwrap();
    assert!(flood_status.success());
    signal(checker.id(), "KILL");
    let _ = checker.wait();
    let _ = frozen.wait();
    let sent: Vec<u64> =
        std::fs::read_to_string(&counts).unwrap().split_whitespace().map(|x| x.parse().unwrap()).collect();
    let (sent_valid, sent_malformed) = (sent[0], sent[1]);

    // a valid command after the flood takes effect within 2 steps (lockstep, so load cannot blur it)
    let pause: ros2_client::Client<msg::Empty, msg::Empty> =
        me.client(ServiceMapping::Enhanced, "pause", "std_srvs", "Empty");
    let step: ros2_client::Client<msg::StepSimulationRequest, msg::ResultResponse> =
        me.client(ServiceMapping::Enhanced, "step_simulation", "simulation_interfaces", "StepSimulation");
    let command = me.publisher::<msg::ActuatorCommand>(
        NS,
        "actuator_commands",
        "tensegrity_msgs",
        "ActuatorCommand",
        tensegrity::io::ros2::qos(1, false),
    );
    std::thread::sleep(2 * SEC);
    call(&pause, msg::Empty::default(), 10 * SEC).expect("pause answers after the soak");
    let winch =
        msg::ActuatorCommand { name: vec!["ring_winch".into()], rate: vec![-0.02], ..Default::default() };
    command.publish(winch).unwrap();
    std::thread::sleep(SEC);
    while let Ok(Some(_)) = actuators.take() {}
    let r = call(&step, msg::StepSimulationRequest { steps: 2 }, 10 * SEC).expect("step answers");
    assert_eq!(r.result.result, 1);
    let states: Vec<msg::JointState> =
        std::iter::from_fn(|| wait_for(SEC, || actuators.take().ok().flatten().map(|(m, _)| m))).collect();
    let k = states
        .last()
        .expect("the 2 steps are published")
        .name
        .iter()
        .position(|n| n == "ring_winch")
        .unwrap();
    let rates: Vec<f64> = states.iter().map(|m| m.velocity[k]).collect();
    assert!(
        rates.iter().any(|r| (r + 0.02).abs() < 1e-9),
        "the command shows within 2 steps: rates {rates:?}"
    );

    let (status, stderr) = node.stop("INT");
    assert!(status.success(), "{stderr}");
    let (received, accepted, rejected) = closing_counts(&stderr);
    rtf.retain(|x| x.is_finite());
    rtf.sort_by(f64::total_cmp);
    let median_rtf = rtf.get(rtf.len() / 2).copied().unwrap_or(f64::NAN);
    // growth of the resident-memory floor: the least RSS of 10 s windows. Transient buffers
    // (a burst of 100 kB names, the frozen reader's queue) come and go within seconds and raise a
    // window's median when they last half of it (one fresh-clone CI run read 98 MB for the last
    // 10 s against a floor of 68 MB that it returned to between bursts), while a leak raises every
    // later sample, the least included. The first window ends two thirds into the flood, not at
    // 20 s: the node's bounded buffers (the killed subscribers' discovery data) fill up over the
    // first part of the run at a pace set by the machine's load.
    let floor = |w: &[u64]| w.iter().min().copied().unwrap_or(0);
    let settled = (rss.len() * 2 / 3).max(20);
    let (early, late) = (floor(&rss[settled - 10..settled]), floor(&rss[rss.len() - 10..]));
    let growth = late as i64 - early as i64;
    let peak = rss.iter().max().copied().unwrap_or(0);
    println!(
        "soak {secs} s: sent {sent_valid} valid + {sent_malformed} malformed; node received {received}, accepted {accepted}, rejected {rejected}; RSS floor {early} kB over {}-{settled} s, {late} kB over the last 10 s ({growth:+} kB), peak {peak} kB; real-time factor median {median_rtf:.3} over {} reports",
        settled - 10,
        rtf.len()
    );
    println!("{}", stderr.lines().last().unwrap_or(""));
    println!("node RSS once a second, MB: {:?}", rss.iter().map(|k| k / 1024).collect::<Vec<_>>());
    assert_eq!(received, accepted + rejected, "counts add up");
    assert!(
        received <= sent_valid + sent_malformed + 1,
        "never more received than sent (+1: the last command)"
    );
    assert!(accepted <= sent_valid + 1 && rejected <= sent_malformed);
    assert!(rejected > 0 && accepted > 0, "the flood reached the node");
    // the killed checking subscribers' participants most likely stay in the node's discovery data
    // until their lease ends (50 s for RustDDS peers), up to ten at a time at one kill every 5 s,
    // so within the first minute the floor may rise by that much (measured: +1 to +3 MB in most
    // runs, +10.8 MB in one fresh-clone CI run); a leak keeps rising, which the ten-minute soak
    // (`-- --ignored`) checks against the same bound
    assert!(growth < 16 * 1024, "the RSS floor grew by {growth} kB over the last third of the flood");
    // bounded, whatever the pace: peaks of 96-107 MB were measured in fresh-clone CI runs
    assert!(peak < 256 * 1024, "the node's resident memory peaked at {peak} kB");
    assert_eq!(nonfinite, 0, "non-finite values in actuator states");
    assert!(!bad.exists(), "a checking subscriber saw a non-finite value");
}

#[test]
fn soak_flood_frozen_and_churning_subscribers() {
    soak("soak_flood_frozen_and_churning_subscribers", 70, 60);
}

#[test]
#[ignore = "10 minutes: cargo test --all-features --test node_soak -- --ignored"]
fn soak_ten_minutes() {
    soak("soak_ten_minutes", 72, 600);
}
