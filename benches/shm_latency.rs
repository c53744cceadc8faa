//! Shared memory (iceoryx2) against DDS, measured in one run (run: `cargo bench --features
//! ros2,shm --bench shm_latency`; `-- --quick` for fewer samples).
//!
//! 1. Command-to-effect latency at 1 kHz real time: one node serves both transports (shared
//!    memory first in its publish order) and publishes the state every step; a controller
//!    alternates a shm command waited for the default way (polling 200 us, then blocking on the
//!    node's event), a shm command waited for by polling (`set_spin` 2 ms: a controller that owns
//!    a core) and a DDS command (a 10 um rest-length change, reached within one step) and times
//!    until the first state carrying it, on the same transport. For shm it also
//!    splits the latency with the node's wall-clock stamps: the wait for the next step boundary
//!    (`commands_applied_ns - sent`), and the rest (step and publish, then delivery). Then the
//!    same for shm against a node serving shm alone.
//! 2. Lockstep throughput (node paused, one step per request, following the scene's deployment
//!    schedule so that every step moves the structure) on `prism3` and the 3-stage `tower`:
//!    round trips from Rust over shm (node serving shm only, then shm,dds), from Python
//!    over shm (`tests/interop/shm_client.py --bench`, when a Python with iceoryx2 is found:
//!    `TENSEGRITY_PYTHON` or target/pyenv), and over DDS `StepSimulation`; the overhead is the
//!    round trip minus the median offline `Simulator::step` time of the same scene, timed in the
//!    same run.
//!
//! Like the DDS tests it first moves itself into a private loopback-only network namespace.

#[path = "../tests/common/cleanup.rs"]
mod cleanup;
#[path = "../tests/common/netns.rs"]
mod netns;
#[path = "../tests/common/peer.rs"]
mod peer;
#[path = "../tests/common/python.rs"]
mod python;
#[path = "../tests/common/running_node.rs"]
mod running_node;

use running_node::RunningNode;

use std::process::Command;
use std::time::{Duration, Instant};

use ros2_client::ServiceMapping;
use tensegrity::io::msg;
use tensegrity::io::node::params::{NodeParams, TransportKind};
use tensegrity::io::node::NodeCore;
use tensegrity::io::shm::{realtime_ns, CommandEntry, ShmClient};
use tensegrity::sim::Simulator;

const WAIT: Duration = Duration::from_secs(10);

/// Quantile `p` (0 to 1) of sorted `v`.
fn q(v: &[f64], p: f64) -> f64 {
    v[((v.len() as f64 - 1.0) * p).round() as usize]
}

fn sorted(mut v: Vec<f64>) -> Vec<f64> {
    v.sort_by(f64::total_cmp);
    v
}

fn scene(name: &str) -> tensegrity::Model {
    let path = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("config/scenes").join(name);
    tensegrity::scene::load(&path).unwrap()
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).filter(|a| a != "--bench").collect();
    let refs: Vec<&str> = args.iter().map(String::as_str).collect();
    if !netns::isolated_or_rerun(&refs) {
        return;
    }
    iceoryx2::prelude::set_log_level_from_env_or(iceoryx2::prelude::LogLevel::Error);
    let quick = args.iter().any(|a| a == "--quick");
    let (latency_samples, lockstep_n, dds_n) = if quick { (100, 500, 100) } else { (500, 5000, 500) };
    command_to_effect(latency_samples, true);
    println!();
    command_to_effect(latency_samples, false);
    println!();
    println!("Lockstep, node paused, 1 step per request, deploying (scene schedule), generalized-alpha dt = 1 ms ({lockstep_n} round trips; DDS {dds_n}):\n");
    println!("| scene | client | node transports | round trip p50 us | p99 us | round trips/s | offline step p50 us | overhead p50 us |");
    println!("| --- | --- | --- | ---: | ---: | ---: | ---: | ---: |");
    for (k, name) in ["prism3.toml", "tower.toml", "sixbar.toml"].iter().enumerate() {
        lockstep_table(name, lockstep_n, dds_n, 76 + k as u16);
    }
}

/// Part 1: command-to-effect at 1 kHz, shm and DDS interleaved against one node.
fn command_to_effect(samples: usize, with_dds: bool) {
    let domain = 75;
    let model = scene("prism3.toml");
    let ring = model.cable_id("ring").unwrap().0;
    let l0 = model.initial_rest_lengths[ring];
    let params = NodeParams {
        domain_id: domain,
        real_time_factor: 1.0,
        state_publish_rate: 0.0,
        transports: if with_dds {
            vec![TransportKind::Shm, TransportKind::Dds]
        } else {
            vec![TransportKind::Shm]
        },
        namespace: "/bench_latency".into(),
        ..NodeParams::default()
    };
    let prefix = params.shm_prefix();
    let node = RunningNode::start_serving(model, params);
    let dds = with_dds.then(|| {
        let mut peer = peer::Peer::new(domain, "latency_probe");
        let ns = format!("/{prefix}");
        let cables =
            peer.subscribe::<msg::CableStates>(&ns, "cable_states", "tensegrity_msgs", "CableStates", 100);
        let commands = peer.publisher::<msg::ActuatorCommand>(
            &ns,
            "actuator_commands",
            "tensegrity_msgs",
            "ActuatorCommand",
            tensegrity::io::ros2::qos(1, false),
        );
        peer::wait_for(WAIT, || cables.take().ok().flatten()).expect("DDS cable states arrive");
        (peer, cables, commands)
    });
    let mut shm = ShmClient::connect(&prefix, WAIT).unwrap();
    std::thread::sleep(Duration::from_millis(500));
    let modes = if with_dds { 3 } else { 2 };

    // shm with the client's default wait (polls 200 us, then blocks on the node's event), shm
    // with a client that polls through the whole wait (a controller owning a core), and DDS
    const MODES: [&str; 3] = [
        "shm (iceoryx2), client blocks (default)",
        "shm (iceoryx2), client polls (set_spin 2 ms)",
        "DDS (RustDDS, loopback)",
    ];
    const SPIN: [Duration; 2] = [Duration::from_micros(200), Duration::from_millis(2)];
    let mut total: [Vec<f64>; 3] = Default::default();
    // per shm mode: the wait for the step boundary, node side, delivery, latency minus the wait
    let mut splits: [[Vec<f64>; 4]; 2] = Default::default();
    let mut lost = [0usize; 3];
    for k in 0..modes * (samples + 30) {
        let mode = k % modes;
        // consecutive samples alternate between two targets, so each command changes the rest length
        let target = l0 - 1e-5 * ((k % 2) as f64 + 1.0);
        if let Some((_, cables, _)) = &dds {
            while cables.take().ok().flatten().is_some() {}
        }
        drop(shm.drain_states().unwrap());
        let sent_ns = realtime_ns();
        let sent = Instant::now();
        let mut seen = None;
        if mode < 2 {
            shm.set_spin(SPIN[mode]);
            let client = &shm;
            client.send_command(&[CommandEntry::index(0).rest_length(target)]).unwrap();
            while sent.elapsed() < Duration::from_millis(500) {
                if let Some(s) = client.next_state(Duration::from_millis(50)).unwrap() {
                    let received_ns = realtime_ns();
                    let s = s.payload();
                    if (s.actuator_rest_length[0] - target).abs() < 1e-12 {
                        let us = |a: u64, b: u64| a.saturating_sub(b) as f64 * 1e-3;
                        let split = [
                            us(s.commands_applied_ns, sent_ns),
                            us(s.published_ns, s.commands_applied_ns),
                            us(received_ns, s.published_ns),
                        ];
                        seen = Some((sent.elapsed().as_secs_f64() * 1e6, split));
                        break;
                    }
                }
            }
        } else if let Some((_, cables, commands)) = &dds {
            let m = msg::ActuatorCommand {
                name: vec!["ring_winch".into()],
                rest_length: vec![target],
                ..Default::default()
            };
            commands.publish(m).unwrap();
            while sent.elapsed() < Duration::from_millis(500) {
                if let Ok(Some((m, _))) = cables.take() {
                    if (m.rest_length[ring] - target).abs() < 1e-12 {
                        seen = Some((sent.elapsed().as_secs_f64() * 1e6, [0.0; 3]));
                        break;
                    }
                } else {
                    std::thread::yield_now();
                }
            }
        }
        match seen {
            Some((us, split)) if k >= 30 * modes => {
                total[mode].push(us);
                if let Some([wait, node_side, delivery, rest]) = splits.get_mut(mode) {
                    wait.push(split[0]);
                    node_side.push(split[1]);
                    delivery.push(us - split[0] - split[1]);
                    rest.push(us - split[0]);
                }
            }
            None => lost[mode] += 1,
            _ => {}
        }
        std::thread::sleep(Duration::from_micros(2300 + 700 * (k as u64 / modes as u64 % 3)));
    }
    let stats = node.stop();
    println!(
        "Command-to-effect latency, node at 1 kHz real time (prism3, transports {}), state every step, \
         the modes alternated, {} samples each (node overruns {}):\n",
        if with_dds { "shm,dds" } else { "shm" },
        total[0].len(),
        stats.overruns
    );
    println!("| transport | p50 us | p99 us | max us | lost | wait for step boundary p50 / p99 us | latency minus that wait p50 / p99 us | of which node (step + publish) p50 us | of which delivery p50 / p99 us |");
    println!("| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |");
    for mode in 0..modes {
        let t = sorted(std::mem::take(&mut total[mode]));
        let mut line = format!(
            "| {} | {:.1} | {:.1} | {:.1} | {} |",
            MODES[mode],
            q(&t, 0.5),
            q(&t, 0.99),
            q(&t, 1.0),
            lost[mode]
        );
        if let Some(split) = splits.get_mut(mode) {
            let [w, n, d, rest] = std::mem::take(split).map(sorted);
            line += &format!(
                " {:.1} / {:.1} | {:.1} / {:.1} | {:.1} | {:.1} / {:.1} |",
                q(&w, 0.5),
                q(&w, 0.99),
                q(&rest, 0.5),
                q(&rest, 0.99),
                q(&n, 0.5),
                q(&d, 0.5),
                q(&d, 0.99)
            );
        } else {
            line += " | | | |";
        }
        println!("{line}");
    }
}

/// Median time of one offline `Simulator::step` on `model` with the node's settings, us.
fn offline_step_us(model: &tensegrity::Model, steps: usize) -> f64 {
    let settings = *NodeCore::new(model.clone(), NodeParams::default()).unwrap().simulator().settings();
    // following the scene's deployment schedule, like the lockstep node, so every step moves
    let mut sim = Simulator::new(model.clone(), settings).unwrap();
    let mut t = Vec::with_capacity(steps);
    for _ in 0..steps {
        let start = Instant::now();
        sim.step().unwrap();
        t.push(start.elapsed().as_secs_f64() * 1e6);
    }
    q(&sorted(t), 0.5)
}

fn row(scene: &str, client: &str, transports: &str, rt: &[f64], per_s: f64, step: f64) {
    println!(
        "| {scene} | {client} | {transports} | {:.1} | {:.1} | {per_s:.0} | {step:.1} | {:.1} |",
        q(rt, 0.5),
        q(rt, 0.99),
        q(rt, 0.5) - step
    );
}

/// Times `n` one-step lockstep round trips from Rust (after 200 not counted): sorted us, per s.
fn rust_lockstep(prefix: &str, n: usize) -> (Vec<f64>, f64) {
    let client = ShmClient::connect(prefix, WAIT).unwrap();
    for _ in 0..200 {
        drop(client.lockstep(1, &[], WAIT).unwrap());
    }
    let mut t = Vec::with_capacity(n);
    let start = Instant::now();
    for _ in 0..n {
        let s = Instant::now();
        let answer = client.lockstep(1, &[], WAIT).unwrap();
        t.push(s.elapsed().as_secs_f64() * 1e6);
        drop(answer);
    }
    (sorted(t), n as f64 / start.elapsed().as_secs_f64())
}

/// Part 2 for one scene: Rust shm (shm only; dds,shm), Python shm, DDS StepSimulation.
fn lockstep_table(name: &str, n: usize, dds_n: usize, domain: u16) {
    let model = scene(name);
    let label = name.trim_end_matches(".toml");
    let step = offline_step_us(&model, n);
    let base = NodeParams {
        start_paused: true,
        follow_schedule: true,
        domain_id: domain,
        namespace: "/bench_lockstep".into(),
        ..NodeParams::default()
    };
    let prefix = base.shm_prefix();

    let node = RunningNode::start_serving(
        model.clone(),
        NodeParams { transports: vec![TransportKind::Shm], ..base.clone() },
    );
    let (rt, per_s) = rust_lockstep(&prefix, n);
    row(label, "Rust", "shm", &rt, per_s, step);
    node.stop();
    // a fresh node, so that the Python client steps the same stretch of the schedule
    let node = RunningNode::start_serving(
        model.clone(),
        NodeParams { transports: vec![TransportKind::Shm], ..base.clone() },
    );
    if let Some(py) = python::bench_python_with("iceoryx2") {
        let script = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/interop/shm_client.py");
        let out = Command::new(py)
            .arg(script)
            .args(["--prefix", &prefix, "--bench", &n.to_string()])
            .output()
            .unwrap();
        let text = String::from_utf8_lossy(&out.stdout);
        let field = |key: &str| -> Option<f64> {
            let line = text.lines().find(|l| l.starts_with("BENCH"))?;
            let words: Vec<&str> = line.split_whitespace().collect();
            words.iter().position(|w| *w == key).and_then(|i| words.get(i + 1)?.parse().ok())
        };
        match (field("p50_us"), field("p99_us"), field("per_s")) {
            (Some(p50), Some(p99), Some(per_s)) => println!(
                "| {label} | Python | shm | {p50:.1} | {p99:.1} | {per_s:.0} | {step:.1} | {:.1} |",
                p50 - step
            ),
            _ => println!(
                "| {label} | Python | shm | failed: {} | | | | |",
                String::from_utf8_lossy(&out.stderr).lines().last().unwrap_or("")
            ),
        }
    } else {
        println!(
            "| {label} | Python | shm | (no Python with iceoryx2: bash .ci/test installs one) | | | | |"
        );
    }
    node.stop();

    let node = RunningNode::start_serving(
        model,
        NodeParams { transports: vec![TransportKind::Shm, TransportKind::Dds], ..base },
    );
    let (rt, per_s) = rust_lockstep(&prefix, n);
    row(label, "Rust", "shm,dds", &rt, per_s, step);
    // DDS StepSimulation: the node's services live under /bench_lockstep/tensegrity_sim
    let mut peer = peer::Peer::new(domain, "lockstep_probe");
    let step_client: ros2_client::Client<msg::StepSimulationRequest, msg::ResultResponse> = peer
        .node
        .create_client(
            ServiceMapping::Enhanced,
            &ros2_client::Name::new(&format!("/{prefix}"), "step_simulation").unwrap(),
            &ros2_client::ServiceTypeName::new("simulation_interfaces", "StepSimulation"),
            tensegrity::io::ros2::qos(10, false),
            tensegrity::io::ros2::qos(10, false),
        )
        .unwrap();
    std::thread::sleep(Duration::from_millis(1500)); // discovery of the service pair
    let call = || peer::call_spinning(&step_client, msg::StepSimulationRequest { steps: 1 }, WAIT);
    for _ in 0..20 {
        call();
    }
    let mut t = Vec::with_capacity(dds_n);
    let start = Instant::now();
    for _ in 0..dds_n {
        let s = Instant::now();
        assert_eq!(call().result.result, 1);
        t.push(s.elapsed().as_secs_f64() * 1e6);
    }
    let per_s = dds_n as f64 / start.elapsed().as_secs_f64();
    row(label, "Rust", "DDS StepSimulation", &sorted(t), per_s, step);
    node.stop();
}
