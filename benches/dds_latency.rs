//! Command-to-effect latency over DDS at 1 kHz (run: `cargo bench --features ros2 --bench dds_latency`).
//!
//! The node runs in-process at real time with a 1 ms step and publishes cable states every step;
//! a controller on a second DDS `Context` commands a new rest-length target (a 10 um change, which
//! the winch reaches within one step) and times until the first cable-state message that carries
//! it. Reported: p50, p90, p99 and max over the samples, in a Markdown table. Like the DDS tests, it
//! first moves itself into a private loopback-only network namespace.

#[path = "../tests/common/netns.rs"]
mod netns;
#[path = "../tests/common/running_node.rs"]
mod running_node;

use running_node::RunningNode;

use std::time::{Duration, Instant};

use ros2_client::{MessageTypeName, Name, NodeName, NodeOptions};
use tensegrity::io::msg;
use tensegrity::io::params::NodeParams;
use tensegrity::io::ros2::{context, qos};

const SAMPLES: usize = 500;

fn main() {
    let args: Vec<String> = std::env::args().skip(1).filter(|a| a != "--bench").collect();
    let refs: Vec<&str> = args.iter().map(String::as_str).collect();
    if !netns::isolated_or_rerun(&refs) {
        return;
    }
    let domain = 71;
    let path = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("config/scenes/prism3.toml");
    let model = tensegrity::scene::load(&path).unwrap();
    let ring = model.cable_id("ring").unwrap().0;
    let l0 = model.initial_rest_lengths[ring];
    let params = NodeParams {
        domain_id: domain,
        real_time_factor: 1.0,
        state_publish_rate: 0.0,
        ..Default::default()
    };
    let node = RunningNode::start(model, params);

    let ctx = context(domain, false).unwrap();
    let mut ctl = ctx.new_node(NodeName::new("/", "latency_probe").unwrap(), NodeOptions::new()).unwrap();
    let ns = "/tensegrity_sim";
    let t_cables = ctl
        .create_topic(
            &Name::new(ns, "cable_states").unwrap(),
            MessageTypeName::new("tensegrity_msgs", "CableStates"),
            &qos(10, false),
        )
        .unwrap();
    let t_cmd = ctl
        .create_topic(
            &Name::new(ns, "actuator_commands").unwrap(),
            MessageTypeName::new("tensegrity_msgs", "ActuatorCommand"),
            &qos(1, false),
        )
        .unwrap();
    let cables = ctl.create_subscription::<msg::CableStates>(&t_cables, Some(qos(100, false))).unwrap();
    let commands = ctl.create_publisher::<msg::ActuatorCommand>(&t_cmd, None).unwrap();
    // discovery, then a warm-up of 50 commands that are not counted
    let start = Instant::now();
    while start.elapsed() < Duration::from_secs(10) && cables.take().ok().flatten().is_none() {
        std::thread::sleep(Duration::from_millis(1));
    }
    std::thread::sleep(Duration::from_millis(500));

    let mut latencies = Vec::with_capacity(SAMPLES);
    let mut lost = 0;
    for k in 0..SAMPLES + 50 {
        let target = l0 - 1e-5 * ((k % 2) as f64 + 1.0);
        while cables.take().ok().flatten().is_some() {} // drain
        let sent = Instant::now();
        commands
            .publish(msg::ActuatorCommand {
                name: vec!["ring_winch".into()],
                rest_length: vec![target],
                ..Default::default()
            })
            .unwrap();
        let mut seen = None;
        while sent.elapsed() < Duration::from_millis(500) {
            if let Ok(Some((m, _))) = cables.take() {
                if (m.rest_length[ring] - target).abs() < 1e-12 {
                    seen = Some(sent.elapsed());
                    break;
                }
            } else {
                std::thread::yield_now();
            }
        }
        match seen {
            Some(d) if k >= 50 => latencies.push(d.as_secs_f64() * 1e3),
            None => lost += 1,
            _ => {}
        }
        std::thread::sleep(Duration::from_millis(3));
    }
    let stats = node.stop();
    latencies.sort_by(f64::total_cmp);
    let q = |p: f64| latencies[((latencies.len() as f64 - 1.0) * p).round() as usize];
    println!("Command-to-effect latency over DDS (RustDDS, loopback namespace), node at 1 kHz real time, cable states every step, {} samples:\n", latencies.len());
    println!("| p50 ms | p90 ms | p99 ms | max ms | lost | node overruns |");
    println!("| ---: | ---: | ---: | ---: | ---: | ---: |");
    println!(
        "| {:.3} | {:.3} | {:.3} | {:.3} | {lost} | {} |",
        q(0.5),
        q(0.9),
        q(0.99),
        q(1.0),
        stats.overruns
    );
}
