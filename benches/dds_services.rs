//! ROS 2 service round trips and command-to-effect over DDS, and a paused node's CPU, measured in
//! one run (run: `cargo bench --bench dds_services`; `-- --quick` for fewer
//! samples). The node is the `tensegrity_node` binary on `prism3`, a separate process serving DDS
//! only (set `TENSEGRITY_NODE_BIN` to time another build of it).
//!
//! 1. Paused node, `~/step_simulation` with 1 step and `~/get_simulation_state`, alternated:
//!    from ros2-client (RustDDS, the enhanced service mapping) and from Eclipse Cyclone DDS
//!    (`benches/dds_services_cyclone.py`, rmw_cyclonedds' request layout, node with
//!    `service_mapping:=cyclone`; needs a Python with `cyclonedds`: `TENSEGRITY_PYTHON` or
//!    target/pyenv, which `bash .ci/test` makes).
//! 2. The same node's CPU while paused and unasked, from `/proc/PID/stat` over 10 s.
//! 3. Playing node (1 kHz, real time, state published every step): a 10 um rest-length command on `~/actuator_commands` until
//!    the first `~/cable_states` that carries it, from both clients.
//!
//! Like the DDS tests it first moves itself into a private loopback-only network namespace.

#[path = "../tests/common/cleanup.rs"]
mod cleanup;
#[path = "../tests/common/cpu.rs"]
mod cpu;
#[path = "../tests/common/netns.rs"]
mod netns;
#[path = "../tests/common/peer.rs"]
mod peer;
#[path = "../tests/common/python.rs"]
mod python;

use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use ros2_client::{Client, ServiceMapping};
use tensegrity::io::msg;

const WAIT: Duration = Duration::from_secs(10);
const DOMAIN: u16 = 81;

/// Quantile `p` (0 to 1) of `v`, sorted here.
fn q(v: &[f64], p: f64) -> f64 {
    let mut v = v.to_vec();
    v.sort_by(f64::total_cmp);
    v[((v.len() as f64 - 1.0) * p).round() as usize]
}

fn node_binary() -> String {
    std::env::var("TENSEGRITY_NODE_BIN").unwrap_or_else(|_| env!("CARGO_BIN_EXE_tensegrity_node").to_string())
}

/// The node on prism3 with `params` (`-p` values), DDS only, as a child process.
fn start_node(params: &[&str]) -> Child {
    let scene = format!("{}/config/scenes/prism3.toml", env!("CARGO_MANIFEST_DIR"));
    let mut cmd = Command::new(node_binary());
    cmd.arg(scene).args(["--ros-args", "-p", "transports:=dds"]);
    for p in params {
        cmd.args(["-p", p]);
    }
    cmd.env("ROS_DOMAIN_ID", DOMAIN.to_string())
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .expect("tensegrity_node starts")
}

fn stop_node(mut child: Child) {
    peer::signal(child.id(), "INT");
    if peer::wait_for(WAIT, || child.try_wait().unwrap()).is_none() {
        let _ = child.kill();
    }
}

/// Runs the Cyclone DDS client (`what`: services or commands) and returns its `name p50 p99 n`
/// lines, or why not.
fn cyclone(what: &str, n: usize) -> Result<Vec<(String, f64, f64, usize)>, String> {
    let py = python::bench_python_with("cyclonedds")
        .ok_or("no Python with cyclonedds (bash .ci/test makes target/pyenv)")?;
    let script = format!("{}/benches/dds_services_cyclone.py", env!("CARGO_MANIFEST_DIR"));
    let out = Command::new(py)
        .args([script.as_str(), what, &DOMAIN.to_string(), peer::NS, &n.to_string()])
        .output()
        .map_err(|e| e.to_string())?;
    let text = String::from_utf8_lossy(&out.stdout);
    if !out.status.success() {
        return Err(format!("{text} {}", String::from_utf8_lossy(&out.stderr)));
    }
    Ok(text
        .lines()
        .filter_map(|l| {
            let f: Vec<&str> = l.split_whitespace().collect();
            Some((
                f.first()?.to_string(),
                f.get(1)?.parse().ok()?,
                f.get(2)?.parse().ok()?,
                f.get(3)?.parse().ok()?,
            ))
        })
        .collect())
}

fn row(what: &str, client: &str, p50: f64, p99: f64, n: usize) {
    println!("| {what} | {client} | {p50:.0} | {p99:.0} | {n} |");
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).filter(|a| a != "--bench").collect();
    let refs: Vec<&str> = args.iter().map(String::as_str).collect();
    if !netns::isolated_or_rerun(&refs) {
        return;
    }
    let n = if args.iter().any(|a| a == "--quick") { 100 } else { 500 };
    println!("node binary: {}\n", node_binary());
    println!("| request | client | p50 us | p99 us | samples |");
    println!("| --- | --- | ---: | ---: | ---: |");

    // 1 and 2: a paused node, ros2-client with the enhanced mapping
    let node = start_node(&["start_paused:=true"]);
    let mut peer = peer::Peer::new(DOMAIN, "bench_dds_services");
    let step: Client<msg::StepSimulationRequest, msg::ResultResponse> =
        peer.client(ServiceMapping::Enhanced, "step_simulation", "simulation_interfaces", "StepSimulation");
    let get: Client<msg::Empty, msg::GetSimulationStateResponse> = peer.client(
        ServiceMapping::Enhanced,
        "get_simulation_state",
        "simulation_interfaces",
        "GetSimulationState",
    );
    peer::wait_for(WAIT, || peer::call(&get, msg::Empty::default(), Duration::from_millis(200)))
        .expect("the node's services answer");
    for _ in 0..20 {
        peer::call_spinning(&step, msg::StepSimulationRequest { steps: 1 }, WAIT);
        peer::call_spinning(&get, msg::Empty::default(), WAIT);
    }
    let (mut t_step, mut t_get) = (Vec::new(), Vec::new());
    for _ in 0..n {
        let s = Instant::now();
        assert_eq!(
            peer::call_spinning(&step, msg::StepSimulationRequest { steps: 1 }, WAIT).result.result,
            1
        );
        t_step.push(s.elapsed().as_secs_f64() * 1e6);
        let s = Instant::now();
        assert_eq!(peer::call_spinning(&get, msg::Empty::default(), WAIT).result.result, 1);
        t_get.push(s.elapsed().as_secs_f64() * 1e6);
    }
    row("StepSimulation(1), paused", "ros2-client (RustDDS)", q(&t_step, 0.5), q(&t_step, 0.99), n);
    row("GetSimulationState, paused", "ros2-client (RustDDS)", q(&t_get, 0.5), q(&t_get, 0.99), n);
    drop((step, get, peer));
    std::thread::sleep(Duration::from_secs(1));
    let (ticks0, wall0) = (cpu::cpu_ticks(node.id()), Instant::now());
    std::thread::sleep(Duration::from_secs(10));
    let ticks = cpu::cpu_ticks(node.id()) - ticks0;
    let idle_cpu = ticks as f64 / cpu::clock_ticks_per_second() / wall0.elapsed().as_secs_f64() * 100.0;
    stop_node(node);

    // 1: the same from Eclipse Cyclone DDS
    let node = start_node(&["start_paused:=true", "service_mapping:=cyclone"]);
    match cyclone("services", n) {
        Ok(lines) => {
            for (name, p50, p99, k) in lines {
                let what = match name.as_str() {
                    "cyclone_step_simulation" => "StepSimulation(1), paused",
                    _ => "GetSimulationState, paused",
                };
                row(what, "Eclipse Cyclone DDS (Python)", p50, p99, k);
            }
        }
        Err(why) => println!("| services | Eclipse Cyclone DDS (Python) | not run: {why} | | |"),
    }
    stop_node(node);

    // 3: command-to-effect on a playing node
    let node = start_node(&["real_time_factor:=1.0", "state_publish_rate:=0.0"]);
    let mut peer = peer::Peer::new(DOMAIN, "bench_dds_commands");
    let cables =
        peer.subscribe::<msg::CableStates>(peer::NS, "cable_states", "tensegrity_msgs", "CableStates", 100);
    let commands = peer.publisher::<msg::ActuatorCommand>(
        peer::NS,
        "actuator_commands",
        "tensegrity_msgs",
        "ActuatorCommand",
        tensegrity::io::ros2::qos(1, false),
    );
    let first = peer::wait_for(WAIT, || cables.take().ok().flatten()).expect("cable states arrive").0;
    let ring = first.name.iter().position(|c| c == "ring").expect("prism3 has a ring cable");
    let l0 = first.rest_length[ring];
    std::thread::sleep(Duration::from_millis(500));
    let mut t = Vec::new();
    for k in 0..n + 20 {
        let target = l0 - 1e-5 * ((k % 2) as f64 + 1.0);
        while cables.take().ok().flatten().is_some() {}
        let sent = Instant::now();
        let command = msg::ActuatorCommand {
            name: vec!["ring_winch".into()],
            rest_length: vec![target],
            ..Default::default()
        };
        commands.publish(command).unwrap();
        let seen = loop {
            match cables.take() {
                Ok(Some((m, _))) if (m.rest_length[ring] - target).abs() < 1e-12 => break sent.elapsed(),
                _ if sent.elapsed() > Duration::from_secs(2) => {
                    panic!("command {k} not reflected within 2 s")
                }
                _ => std::thread::yield_now(),
            }
        };
        if k >= 20 {
            t.push(seen.as_secs_f64() * 1e6);
        }
    }
    row("command to effect, playing 1 kHz", "ros2-client (RustDDS)", q(&t, 0.5), q(&t, 0.99), n);
    drop((cables, commands, peer));
    match cyclone("commands", n) {
        Ok(lines) => {
            for (_, p50, p99, k) in lines {
                row("command to effect, playing 1 kHz", "Eclipse Cyclone DDS (Python)", p50, p99, k);
            }
        }
        Err(why) => println!("| commands | Eclipse Cyclone DDS (Python) | not run: {why} | | |"),
    }
    stop_node(node);
    println!("\nPaused node, unasked, 10 s: CPU {idle_cpu:.2} % of one core");
}
