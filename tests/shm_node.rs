//! Invariant: the shared-memory (iceoryx2) path drives the simulator exactly as the physics
//! would offline and survives what local controllers do to it. N lockstep requests of k steps
//! take exactly N*k steps and end in the state an offline `Simulator` reaches with the same
//! commands, bit for bit; bad commands (NaN, unknown index or name, out of range, empty, unknown
//! field bits) are rejected whole and counted while the node keeps stepping; a scene over the
//! payload capacities or with a name too long is refused at start naming the limit; two
//! namespaces never see each other and a second node on a taken one is refused; a controller
//! killed with SIGKILL, again and again (more times than the services have controller slots),
//! leaves the node serving the next one; a node killed with SIGKILL leaves resources that the
//! next start on the same namespace cleans up; a paused shm-only node opens no UDP socket and
//! uses no measurable CPU; and the Python client (PyPI iceoryx2, ctypes mirrors) reads the
//! structure and state, sends commands and runs lockstep.
//!
//! Shared memory opens no network socket, so these tests need no network namespace; each uses a
//! namespace of its own (with the test process id) so parallel tests never share services.

#![cfg(feature = "shm")]

mod common;
use common::cpu::cpu_ticks;
use common::{bundled, python, running_node};
#[cfg(feature = "ros2")]
use common::{netns, peer};

use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use tensegrity::control::ActuatorCommand;
use tensegrity::io::node::params::{NodeParams, TransportKind};
use tensegrity::io::node::NodeCore;
use tensegrity::io::shm::{
    check_capacity, CommandEntry, ShmClient, ShmError, StateSample, MAX_ACTUATORS, MAX_BODIES,
    MAX_CONTROLLERS,
};
use tensegrity::model::ActuatorId;
use tensegrity::sim::Simulator;

use running_node::RunningNode;

const WAIT: Duration = Duration::from_secs(10);

/// Parameters of a shm-only node under a namespace of this test's own.
fn shm_params(test: &str) -> NodeParams {
    NodeParams {
        namespace: format!("/shm_{test}_{}", std::process::id()),
        transports: vec![TransportKind::Shm],
        ..NodeParams::default()
    }
}

/// The node's state as `fill_state` writes it, from an offline simulator.
fn expected_bits(sim: &Simulator) -> Vec<u64> {
    let mut out = vec![sim.state().time.to_bits()];
    for p in &sim.state().poses {
        let q = p.rotation.quaternion();
        out.extend([p.position.x, p.position.y, p.position.z, q.i, q.j, q.k, q.w].map(f64::to_bits));
    }
    for c in &sim.workspace().cables {
        out.extend([c.tension, c.length, c.rest_length].map(f64::to_bits));
    }
    out
}

/// The same numbers from a state sample.
fn sample_bits(s: &StateSample) -> Vec<u64> {
    let mut out = vec![s.time.to_bits()];
    for i in 0..s.body_count as usize {
        out.extend(s.body_position[i].map(f64::to_bits));
        out.extend(s.body_orientation[i].map(f64::to_bits));
    }
    for i in 0..s.cable_count as usize {
        out.extend([s.cable_tension[i], s.cable_length[i], s.cable_rest_length[i]].map(f64::to_bits));
    }
    out
}

#[test]
fn lockstep_takes_exactly_n_times_k_steps_and_matches_an_offline_run_bit_for_bit() {
    let model = bundled("tower.toml");
    let params = NodeParams { start_paused: true, state_publish_rate: 0.0, ..shm_params("lockstep") };
    let prefix = params.shm_prefix();
    // the offline reference: the node's own settings, actuators held at the start like the node
    let settings = *NodeCore::new(model.clone(), params.clone()).unwrap().simulator().settings();
    let mut offline = Simulator::new(model.clone(), settings).unwrap();
    for (i, a) in model.actuators.iter().enumerate() {
        let hold = ActuatorCommand {
            rest_length: Some(model.initial_rest_lengths[a.cable.0]),
            rate: None,
            tension: None,
        };
        offline.command_actuator(ActuatorId(i), hold).unwrap();
    }
    let names = model.actuator_names.clone();
    assert!(names.len() >= 2, "the tower scene drives several cables");
    let node = RunningNode::start_serving(model.clone(), params);
    let client = ShmClient::connect(&prefix, WAIT).unwrap();
    let structure = client.structure(WAIT).unwrap();
    assert_eq!(structure.actuator_names, names);
    assert_eq!(structure.body_names.len(), model.bodies.len());

    let (n, k) = (12u64, 7u64);
    for r in 0..n {
        // every third request shortens one winch (by index, then by name) or sets a rate alone
        let entries: Vec<CommandEntry> = match r % 3 {
            0 => {
                let a = (r as usize / 3) % names.len();
                let l0 = model.initial_rest_lengths[model.actuators[a].cable.0];
                vec![CommandEntry::index(a).rest_length(l0 * (1.0 - 0.002 * (r + 1) as f64))]
            }
            1 => vec![CommandEntry::named(&names[1]).rate(-0.01)],
            _ => vec![],
        };
        for e in &entries {
            let id = if e.actuator == tensegrity::io::shm::BY_NAME {
                ActuatorId(1)
            } else {
                ActuatorId(e.actuator as usize)
            };
            let cmd = ActuatorCommand {
                rest_length: (e.fields & 1 != 0).then_some(e.rest_length),
                rate: (e.fields & 2 != 0).then_some(e.rate),
                tension: (e.fields & 4 != 0).then_some(e.tension),
            };
            offline.command_actuator(id, cmd).unwrap();
        }
        for _ in 0..k {
            offline.step().unwrap();
        }
        let answer = client.lockstep(k, &entries, WAIT).unwrap();
        let a = answer.payload();
        assert_eq!(a.steps_taken, k);
        assert_eq!(a.state.step, (r + 1) * k, "request {r}");
        assert_eq!(a.state.simulation_state, 2, "still paused");
        assert_eq!(sample_bits(&a.state), expected_bits(&offline), "request {r}: not bit for bit");
    }
    // one sample per step went out on the state service too (the newest STATE_BUFFER are kept)
    let states = client.drain_states().unwrap();
    assert!(!states.is_empty());
    assert_eq!(states.last().unwrap().payload().step, n * k);
    assert!(states.windows(2).all(|w| w[1].payload().step == w[0].payload().step + 1));
    drop(states);
    let stats = node.stop();
    assert_eq!(stats.steps, n * k);
    assert_eq!(stats.commands_rejected, 0);
}

#[test]
fn bad_commands_are_rejected_whole_and_counted_and_the_node_keeps_stepping() {
    let model = bundled("prism3.toml");
    let ring = model.actuators[0];
    let l0 = model.initial_rest_lengths[ring.cable.0];
    let params = NodeParams { state_publish_rate: 0.0, ..shm_params("bad_commands") };
    let prefix = params.shm_prefix();
    let node = RunningNode::start_serving(model, params);
    let client = ShmClient::connect(&prefix, WAIT).unwrap();
    let bad: Vec<Vec<CommandEntry>> = vec![
        vec![CommandEntry::index(0).rest_length(f64::NAN)],
        vec![CommandEntry::index(0).rate(f64::INFINITY)],
        vec![CommandEntry::index(7).rest_length(l0)],
        vec![CommandEntry::named("no_such_winch").rest_length(l0)],
        vec![CommandEntry::index(0).rest_length(ring.max_rest_length * 2.0)],
        vec![CommandEntry::index(0).rest_length(-1.0)],
        vec![CommandEntry::index(0).rate(10.0 * ring.max_rate + 1.0)],
        vec![],
        vec![CommandEntry { fields: 8, ..CommandEntry::index(0) }],
        // a good entry with a bad one: the whole message is rejected
        vec![CommandEntry::index(0).rest_length(0.99 * l0), CommandEntry::named("ring_winch").rate(f64::NAN)],
        vec![CommandEntry::index(0).rest_length(0.99 * l0), CommandEntry::index(0).rest_length(0.98 * l0)],
    ];
    let first = client.next_state(WAIT).unwrap().expect("the node publishes").payload().step;
    for entries in &bad {
        client.send_command(entries).unwrap();
        std::thread::sleep(Duration::from_millis(3));
    }
    let target = 0.99 * l0;
    client.send_command(&[CommandEntry::named("ring_winch").rest_length(target)]).unwrap();
    // too many entries never leave the client
    let many = vec![CommandEntry::index(0).rest_length(l0); MAX_ACTUATORS + 1];
    assert_eq!(client.send_command(&many), Err(ShmError::TooManyEntries(MAX_ACTUATORS + 1)));
    // lockstep is refused while playing, with the reason
    match client.lockstep(1, &[], WAIT) {
        Err(ShmError::Refused { code: 3, message }) => assert!(message.contains("paused"), "{message}"),
        other => panic!("lockstep while playing: {:?}", other.map(|a| a.payload().steps_taken)),
    }
    let mut last = None;
    let counted = |s: &StateSample| s.commands_received == bad.len() as u64 + 1;
    let deadline = Instant::now() + WAIT;
    while Instant::now() < deadline {
        if let Some(s) = client.next_state(WAIT).unwrap() {
            let done = counted(s.payload()) && s.payload().actuator_rest_length[0] < l0;
            last = Some(s.payload().clone());
            if done {
                break;
            }
        }
    }
    let s = last.expect("states keep coming");
    assert_eq!(s.commands_received, bad.len() as u64 + 1, "every message counted");
    assert_eq!(s.commands_rejected, bad.len() as u64);
    assert_eq!(s.commands_accepted, 1);
    assert!(s.step > first + 10, "the node kept stepping ({first} -> {})", s.step);
    assert!(s.actuator_rest_length[0] < l0 && s.actuator_rest_length[0] >= target, "the good command acts");
    assert_eq!(s.faulted, 0);
    let all_finite = (0..s.cable_count as usize).all(|i| s.cable_tension[i].is_finite());
    assert!(all_finite);
    let stats = node.stop();
    assert_eq!(stats.commands_rejected, bad.len() as u64);
}

#[test]
fn a_playing_shm_node_keeps_real_time() {
    // event waits with a timeout round up to the kernel tick; the runner must not use them to
    // pace real-time steps (a generous bound: at most 40 % behind wall time over 1.5 s)
    let params = shm_params("real_time");
    let prefix = params.shm_prefix();
    let node = RunningNode::start_serving(bundled("prism3.toml"), params);
    let client = ShmClient::connect(&prefix, WAIT).unwrap();
    let first = client.next_state(WAIT).unwrap().unwrap().payload().time;
    let start = Instant::now();
    std::thread::sleep(Duration::from_millis(1500));
    drop(client.drain_states().unwrap());
    let last = client.next_state(WAIT).unwrap().unwrap().payload().time;
    let wall = start.elapsed().as_secs_f64();
    let stats = node.stop();
    assert!(
        last - first >= 0.6 * wall,
        "sim time {:.3} s in {wall:.3} s of wall time ({} overruns)",
        last - first,
        stats.overruns
    );
}

#[test]
fn a_scene_over_the_capacities_or_with_a_long_name_is_refused_naming_the_limit() {
    let spec = tensegrity::scene::generate::tower(&tensegrity::scene::generate::TowerParams {
        stages: MAX_BODIES / 3 + 1,
        ..Default::default()
    });
    let big = tensegrity::scene::build_model(&spec, "<generated tower>", None).unwrap();
    assert!(big.bodies.len() > MAX_BODIES);
    let e = check_capacity(&big, "world").unwrap_err().to_string();
    assert!(e.contains("MAX_BODIES") && e.contains(&MAX_BODIES.to_string()), "{e}");
    let e = match tensegrity::io::launch(big, shm_params("capacity")) {
        Err(e) => e.to_string(),
        Ok(_) => panic!("a scene over MAX_BODIES was served"),
    };
    assert!(e.starts_with("shm:") && e.contains("MAX_BODIES") && e.contains("transports:=dds"), "{e}");

    let long = "c".repeat(70);
    let text = std::fs::read_to_string(
        std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("config/scenes/prism3.toml"),
    )
    .unwrap()
    .replace("name = \"ring\"", &format!("name = \"{long}\""))
    .replace("cable = \"ring\"", &format!("cable = \"{long}\""));
    let model = tensegrity::scene::from_toml(&text, "<long name>").unwrap();
    let e = match tensegrity::io::launch(model, shm_params("long_name")) {
        Err(e) => e.to_string(),
        Ok(_) => panic!("a 70-byte name was served"),
    };
    assert!(e.contains("cable name") && e.contains("70 bytes") && e.contains("63"), "{e}");
}

#[test]
fn namespaces_are_isolated_and_a_taken_one_is_refused() {
    let a = shm_params("iso_a");
    let b = NodeParams { start_paused: true, ..shm_params("iso_b") };
    let (pa, pb) = (a.shm_prefix(), b.shm_prefix());
    let node_a = RunningNode::start_serving(bundled("prism3.toml"), a.clone());
    let node_b = RunningNode::start_serving(bundled("tbar.toml"), b);
    let ca = ShmClient::connect(&pa, WAIT).unwrap();
    let cb = ShmClient::connect(&pb, WAIT).unwrap();
    assert_eq!(ca.structure(WAIT).unwrap().scene_name, "prism3");
    assert_eq!(cb.structure(WAIT).unwrap().scene_name, "tbar");
    // b is paused: lockstep works there, and a's (playing) samples never reach b's client
    let answer = cb.lockstep(3, &[], WAIT).unwrap();
    assert_eq!(answer.payload().state.step, 3);
    drop(answer);
    assert!(ca.next_state(WAIT).unwrap().is_some());
    let from_b: Vec<u64> = cb.drain_states().unwrap().iter().map(|s| s.payload().step).collect();
    assert!(from_b.iter().all(|s| *s <= 3), "b's client saw another node's samples: {from_b:?}");
    // a second node on a's namespace is refused, and a keeps serving
    let e = match tensegrity::io::launch(bundled("prism3.toml"), a) {
        Err(e) => e.to_string(),
        Ok(_) => panic!("two nodes served one namespace"),
    };
    assert!(e.contains("another node already serves") && e.contains(&pa), "{e}");
    assert!(ca.next_state(WAIT).unwrap().is_some());
    node_a.stop();
    node_b.stop();
}

/// Env of a child process that plays a controller on `prefix` until killed.
const ROLE: &str = "TENSEGRITY_SHM_ROLE";

/// In a child process: connects and runs lockstep requests with commands forever.
#[test]
fn role_controller_until_killed() {
    let Ok(prefix) = std::env::var(ROLE) else { return };
    let client = ShmClient::connect(&prefix, WAIT).unwrap();
    let mut k = 0u64;
    loop {
        k += 1;
        let rate = if k % 2 == 0 { 1e-3 } else { -1e-3 };
        // keep the node busy (a lockstep under way when the kill comes) and send commands too
        let _ = client.send_command(&[CommandEntry::index(0).rate(0.0)]);
        let _ = client.lockstep(2, &[CommandEntry::index(0).rate(rate)], WAIT);
    }
}

fn spawn_controller(prefix: &str) -> Child {
    let mut cmd = Command::new(std::env::current_exe().unwrap());
    tensegrity::testing::die_with_parent(&mut cmd);
    cmd.args(["--exact", "role_controller_until_killed", "--nocapture", "--test-threads=1"])
        .env(ROLE, prefix)
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap()
}

#[test]
fn controllers_killed_mid_run_leave_the_node_serving_the_next() {
    let model = bundled("prism3.toml");
    let l0 = model.initial_rest_lengths[model.actuators[0].cable.0];
    let params = NodeParams { start_paused: true, state_publish_rate: 0.0, ..shm_params("killed") };
    let prefix = params.shm_prefix();
    let node = RunningNode::start_serving(model, params);
    let watcher = ShmClient::connect(&prefix, WAIT).unwrap();
    let rounds = MAX_CONTROLLERS + 4;
    let mut last_step = 0;
    for round in 0..rounds {
        let mut child = spawn_controller(&prefix);
        // wait until the child has driven the node 20 steps further, then kill it mid-run
        let deadline = Instant::now() + WAIT;
        loop {
            assert!(Instant::now() < deadline, "round {round}: the child controller never stepped the node");
            if let Some(s) = watcher.next_state(Duration::from_millis(100)).unwrap() {
                if s.payload().step >= last_step + 20 {
                    break;
                }
            }
        }
        child.kill().unwrap();
        child.wait().unwrap();
        // the node still serves: this process's lockstep works (retry while the killed child's
        // request may still be finishing)
        let deadline = Instant::now() + WAIT;
        let answer = loop {
            match watcher.lockstep(1, &[CommandEntry::index(0).rest_length(l0)], Duration::from_secs(2)) {
                Ok(a) => break a,
                Err(e) => assert!(Instant::now() < deadline, "round {round}: {e}"),
            }
        };
        last_step = answer.payload().state.step;
        drop(answer);
        drop(watcher.drain_states().unwrap());
    }
    let stats = node.stop();
    assert!(stats.steps >= 20 * rounds as u64, "{} steps", stats.steps);
    assert_eq!(stats.physics_failures, 0);
}

/// A `tensegrity_node` process serving shared memory only.
fn node_process(namespace: &str, extra: &[&str]) -> Child {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_tensegrity_node"));
    tensegrity::testing::die_with_parent(&mut cmd);
    cmd.args(["--ros-args", "-p", "transports:=shm", "-r", &format!("__ns:=/{namespace}")]);
    for p in extra {
        cmd.args(["-p", p]);
    }
    cmd.stdin(Stdio::null()).stdout(Stdio::null()).stderr(Stdio::piped()).spawn().unwrap()
}

/// Inodes of the UDP sockets (IPv4 and IPv6) of this network namespace.
fn udp_socket_inodes(pid: u32) -> Vec<String> {
    ["udp", "udp6"]
        .iter()
        .flat_map(|f| {
            std::fs::read_to_string(format!("/proc/{pid}/net/{f}"))
                .unwrap_or_default()
                .lines()
                .skip(1)
                .map(|l| l.split_whitespace().nth(9).unwrap_or("").to_string())
                .collect::<Vec<_>>()
        })
        .collect()
}

#[test]
fn a_killed_node_leaves_nothing_that_stops_the_next_and_a_paused_one_is_quiet() {
    let namespace = format!("shm_stale_{}", std::process::id());
    let prefix = format!("{namespace}/tensegrity_sim");
    let mut first = node_process(&namespace, &["start_paused:=true"]);
    let client = ShmClient::connect(&prefix, WAIT).unwrap();
    assert_eq!(client.lockstep(5, &[], WAIT).unwrap().payload().state.step, 5);
    first.kill().unwrap();
    first.wait().unwrap();
    drop(client);

    let mut second = node_process(&namespace, &["start_paused:=true"]);
    let client = ShmClient::connect(&prefix, WAIT).unwrap();
    let deadline = Instant::now() + WAIT;
    let answer = loop {
        // the first answer may come from the services the dead node left until they are replaced
        match client.lockstep(5, &[], Duration::from_millis(500)) {
            Ok(a) => break a,
            Err(e) => {
                assert!(second.try_wait().unwrap().is_none(), "the second node exited: {e}");
                assert!(Instant::now() < deadline, "the restarted node never answered: {e}");
            }
        }
    };
    assert_eq!(answer.payload().state.step, 5, "a fresh node answers from the start");
    drop(answer);

    // paused and shared memory only: no UDP socket, no measurable CPU
    let pid = second.id();
    let own: Vec<String> = std::fs::read_dir(format!("/proc/{pid}/fd"))
        .unwrap()
        .filter_map(|e| std::fs::read_link(e.ok()?.path()).ok())
        .filter_map(|l| l.to_string_lossy().strip_prefix("socket:[")?.strip_suffix(']').map(String::from))
        .collect();
    let udp = udp_socket_inodes(pid);
    assert!(own.iter().all(|i| !udp.contains(i)), "a shm-only node opened a UDP socket");
    let before = cpu_ticks(pid);
    std::thread::sleep(Duration::from_secs(3));
    let used = cpu_ticks(pid) - before;
    // clock ticks are 10 ms: a paused node may wake once a second for its diagnostics turn
    assert!(used <= 3, "a paused shm-only node used {used} ticks of CPU in 3 s");
    second.kill().unwrap();
    second.wait().unwrap();
}

#[test]
fn python_client_reads_state_sends_commands_and_runs_lockstep() {
    // `bash .ci/test` names a Python with iceoryx2==0.10.0 (target/pyenv); a plain `cargo test`
    // runs the test when the system Python has the module and says it skipped otherwise
    let Some(python) = python::python_with("iceoryx2") else { return };
    let script = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/interop/shm_client.py");
    // the ctypes mirrors have the Rust payloads' names, sizes and alignments
    let out = Command::new(&python).arg(&script).arg("--sizes").output().unwrap();
    let sizes = String::from_utf8_lossy(&out.stdout);
    use std::mem::{align_of, size_of};
    use tensegrity::io::shm::{
        CommandSample, ContactsSample, LockstepRequest, LockstepResponse, MeasuredSample, StructureSample,
    };
    for (name, size, align) in [
        ("TensegrityState", size_of::<StateSample>(), align_of::<StateSample>()),
        ("TensegrityStructure", size_of::<StructureSample>(), align_of::<StructureSample>()),
        ("TensegrityCommandEntry", size_of::<CommandEntry>(), align_of::<CommandEntry>()),
        ("TensegrityCommand", size_of::<CommandSample>(), align_of::<CommandSample>()),
        ("TensegrityLockstepRequest", size_of::<LockstepRequest>(), align_of::<LockstepRequest>()),
        ("TensegrityLockstepResponse", size_of::<LockstepResponse>(), align_of::<LockstepResponse>()),
        ("TensegrityContacts", size_of::<ContactsSample>(), align_of::<ContactsSample>()),
        ("TensegrityMeasured", size_of::<MeasuredSample>(), align_of::<MeasuredSample>()),
    ] {
        let line = format!("{name} {size} {align}");
        assert!(sizes.lines().any(|l| l == line), "Python mirror differs: want '{line}' in\n{sizes}");
    }
    let model = bundled("prism3.toml");
    let l0 = model.initial_rest_lengths[model.actuators[0].cable.0];
    let params = NodeParams { start_paused: true, state_publish_rate: 0.0, ..shm_params("python") };
    let prefix = params.shm_prefix();
    let node = RunningNode::start_serving(model, params);
    let out = Command::new(&python)
        .arg(&script)
        .args(["--prefix", &prefix, "--check", &format!("{:.17}", 0.97 * l0)])
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{stdout}\n{}", String::from_utf8_lossy(&out.stderr));
    assert!(stdout.contains("OK"), "{stdout}");
    let stats = node.stop();
    // the script sends a NaN command and a lockstep command for an unknown winch (both
    // rejected), one good lockstep command, and takes 10 + 1 + 1 + 200 steps
    assert_eq!(stats.commands_rejected, 2, "{stdout}");
    assert_eq!(stats.commands_accepted, 1, "{stdout}");
    assert_eq!(stats.steps, 212, "{stdout}");
    eprintln!("{stdout}");
}

/// With both transports: what shared memory carries equals, field by field, what DDS publishes
/// for the same step, lockstep runs show on DDS (`/clock` and the state topics), and a command
/// rejected on shared memory is reported in `/diagnostics`.
#[cfg(feature = "ros2")]
mod with_dds {
    use super::*;
    use tensegrity::io::msg;

    use super::{netns, peer};

    #[test]
    fn shm_state_samples_equal_the_dds_messages_of_the_same_step() {
        let test = "with_dds::shm_state_samples_equal_the_dds_messages_of_the_same_step";
        if !netns::isolated_or_rerun(&["--exact", test, "--nocapture", "--test-threads=1"]) {
            return;
        }
        let domain = 75;
        let params = NodeParams {
            domain_id: domain,
            transports: vec![TransportKind::Dds, TransportKind::Shm],
            start_paused: true,
            state_publish_rate: 0.0,
            ..shm_params("dds")
        };
        let prefix = params.shm_prefix();
        let ns = format!("/{prefix}");
        let node = RunningNode::start_serving(bundled("prism3.toml"), params);
        let mut peer = peer::Peer::new(domain, "checker");
        let cables =
            peer.subscribe::<msg::CableStates>(&ns, "cable_states", "tensegrity_msgs", "CableStates", 100);
        let poses = peer.subscribe::<msg::PoseArray>(&ns, "body_poses", "geometry_msgs", "PoseArray", 100);
        let actuators =
            peer.subscribe::<msg::JointState>(&ns, "actuator_states", "sensor_msgs", "JointState", 100);
        let clock = peer.subscribe::<msg::Clock>("/", "clock", "rosgraph_msgs", "Clock", 100);
        let diagnostics = peer.subscribe::<msg::DiagnosticArray>(
            "/",
            "diagnostics",
            "diagnostic_msgs",
            "DiagnosticArray",
            100,
        );
        std::thread::sleep(Duration::from_millis(1500)); // discovery

        let client = ShmClient::connect(&prefix, WAIT).unwrap();
        let mut samples: Vec<StateSample> = Vec::new();
        for r in 0..3 {
            let entries = [CommandEntry::index(0).rate(-0.5 * (r + 1) as f64)];
            let answer = client.lockstep(4, &entries, WAIT).unwrap();
            samples.push(answer.payload().state.clone());
            drop(answer);
            samples.extend(client.drain_states().unwrap().iter().map(|s| s.payload().clone()));
        }
        samples.sort_by_key(|s| s.step);
        samples.dedup_by_key(|s| s.step);
        assert_eq!(samples.last().unwrap().step, 12);
        let stamps: Vec<msg::Time> = samples.iter().map(|s| msg::Time::from_seconds(s.time)).collect();

        // every shm sample's step arrives on DDS (one message per step)
        let (mut c, mut p, mut a, mut clocks) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
        let all_there = peer::wait_for(Duration::from_secs(10), || {
            while let Ok(Some((m, _))) = cables.take() {
                c.push(m);
            }
            while let Ok(Some((m, _))) = poses.take() {
                p.push(m);
            }
            while let Ok(Some((m, _))) = actuators.take() {
                a.push(m);
            }
            while let Ok(Some((m, _))) = clock.take() {
                clocks.push(m.clock);
            }
            let has = |t: &msg::Time| {
                c.iter().any(|m: &msg::CableStates| m.header.stamp == *t)
                    && p.iter().any(|m: &msg::PoseArray| m.header.stamp == *t)
                    && a.iter().any(|m: &msg::JointState| m.header.stamp == *t)
            };
            stamps.iter().all(has).then_some(())
        });
        assert!(all_there.is_some(), "DDS did not carry every lockstep step ({} cable states)", c.len());
        assert!(clocks.iter().any(|t| *t == *stamps.last().unwrap()), "/clock shows the lockstep run");
        for (s, t) in samples.iter().zip(&stamps) {
            let cm = c.iter().find(|m| m.header.stamp == *t).unwrap();
            let pm = p.iter().find(|m| m.header.stamp == *t).unwrap();
            let am = a.iter().find(|m| m.header.stamp == *t).unwrap();
            let n = s.cable_count as usize;
            assert_eq!(cm.tension, s.cable_tension[..n], "step {}", s.step);
            assert_eq!(cm.length, s.cable_length[..n], "step {}", s.step);
            assert_eq!(cm.rest_length, s.cable_rest_length[..n], "step {}", s.step);
            let slack: Vec<bool> = s.cable_slack[..n].iter().map(|f| *f == 1).collect();
            assert_eq!(cm.slack, slack, "step {}", s.step);
            // per pulley, the same numbers on both transports
            let k = s.pulley_count as usize;
            assert_eq!(k, cm.pulley_tension_ratio.len());
            assert_eq!(cm.pulley_tension_ratio, s.pulley_tension_ratio[..k], "step {}", s.step);
            assert_eq!(cm.pulley_slip_speed, s.pulley_slip_speed[..k], "step {}", s.step);
            let sticks: Vec<bool> = s.pulley_sticks[..k].iter().map(|f| *f == 1).collect();
            assert_eq!(cm.pulley_sticks, sticks, "step {}", s.step);
            assert_eq!(pm.poses.len(), s.body_count as usize);
            for (i, pose) in pm.poses.iter().enumerate() {
                let o = &pose.orientation;
                assert_eq!([pose.position.x, pose.position.y, pose.position.z], s.body_position[i]);
                assert_eq!([o.x, o.y, o.z, o.w], s.body_orientation[i], "step {} body {i}", s.step);
            }
            let k = s.actuator_count as usize;
            assert_eq!(am.position, s.actuator_rest_length[..k], "step {}", s.step);
            assert_eq!(am.velocity, s.actuator_rate[..k], "step {}", s.step);
        }

        // a command rejected on shared memory is reported where ROS tools look
        client.send_command(&[CommandEntry::named("no_such_winch").rest_length(1.0)]).unwrap();
        let reported = peer::wait_for(Duration::from_secs(5), || {
            diagnostics.take().ok().flatten().filter(|(d, _)| {
                d.status.iter().any(|s| s.message.contains("unknown actuator 'no_such_winch'"))
            })
        });
        assert!(reported.is_some(), "the shm rejection is in /diagnostics");
        let stats = node.stop();
        assert_eq!((stats.steps, stats.commands_accepted, stats.commands_rejected), (12, 3, 1));
    }
}

#[test]
fn a_robot_on_the_ground_serves_its_contacts_with_each_lockstep_answer() {
    let model = bundled("sixbar.toml");
    let weight: f64 = model.bodies.iter().map(|b| b.mass).sum::<f64>() * 9.81;
    let params = NodeParams {
        start_paused: true,
        state_publish_rate: 0.0,
        start_from_equilibrium: true,
        ..shm_params("contacts")
    };
    let prefix = params.shm_prefix();
    let _node = RunningNode::start_serving(model.clone(), params);
    let client = ShmClient::connect(&prefix, WAIT).unwrap();
    let structure = client.structure(WAIT).unwrap();
    let labels: Vec<(String, String)> =
        model.contact_labels().map(|(a, b)| (a.to_string(), b.to_string())).collect();
    assert_eq!(structure.contact_names, labels);
    for steps in [1, 20] {
        let answer = client.lockstep(steps, &[], WAIT).unwrap();
        let contacts = client.latest_contacts().unwrap().expect("contacts with the answer");
        let c = contacts.payload();
        assert_eq!(
            (c.step, c.time.to_bits()),
            (answer.payload().state.step, answer.payload().state.time.to_bits())
        );
        assert_eq!(c.contact_count as usize, labels.len());
        let standing: Vec<&str> =
            (0..labels.len()).filter(|&i| c.in_contact[i] == 1).map(|i| labels[i].0.as_str()).collect();
        assert_eq!(standing, ["x0.b", "y0.b", "z0.b"]);
        let carried: f64 = c.normal_force[..labels.len()].iter().sum();
        assert!((carried - weight).abs() < 1e-6 * weight, "{carried} N of {weight} N");
    }
    // a scene without contact has no contacts service and names none
    let params = NodeParams { start_paused: true, state_publish_rate: 0.0, ..shm_params("no_contacts") };
    let prefix = params.shm_prefix();
    let _plain = RunningNode::start_serving(bundled("prism3.toml"), params);
    let client = ShmClient::connect(&prefix, WAIT).unwrap();
    assert!(client.structure(WAIT).unwrap().contact_names.is_empty());
    client.lockstep(1, &[], WAIT).unwrap();
    assert!(client.latest_contacts().unwrap().is_none());
}

/// A paused shm node on `config/examples/sensors.toml` (from its equilibrium, state published
/// with each lockstep answer) for test `test`, and a client of it.
fn sensed_node(test: &str) -> (RunningNode, ShmClient) {
    let root = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let model = tensegrity::scene::load(&root.join("config/examples/sensors.toml")).unwrap();
    let params = NodeParams {
        start_paused: true,
        state_publish_rate: 0.0,
        start_from_equilibrium: true,
        ..shm_params(test)
    };
    let prefix = params.shm_prefix();
    let node = RunningNode::start_serving(model, params);
    let client = ShmClient::connect(&prefix, WAIT).unwrap();
    (node, client)
}

#[test]
fn a_scene_with_sensors_serves_what_they_report_with_each_lockstep_answer() {
    use tensegrity::io::shm::{MEASURED_POSITION, MEASURED_TENSION};
    let (_node, client) = sensed_node("measured");
    let mut errors = Vec::new();
    let mut positions = Vec::new();
    for _ in 0..200 {
        let answer = client.lockstep(1, &[], WAIT).unwrap();
        let state = &answer.payload().state;
        let measured = client.latest_measured().unwrap().expect("the sensors with the answer");
        let m = measured.payload();
        assert_eq!((m.step, m.time.to_bits()), (state.step, state.time.to_bits()));
        assert_eq!(m.channels & (MEASURED_TENSION | MEASURED_POSITION), MEASURED_TENSION | MEASURED_POSITION);
        // the state keeps the truth: a load at rest on its rope
        assert!((state.cable_tension[0] - 98.1).abs() < 1e-6);
        errors.push((m.cable_tension[0], m.cable_tension[0] - state.cable_tension[0]));
        assert!((m.body_position[1][2] - state.body_position[1][2]).abs() < 0.01);
        // the scene's positions drop 1 % of their updates: a flagged value is the last one held
        for (x, lost) in m.body_position[1].iter().zip(m.body_position_lost[1]) {
            positions.push((*x, lost));
        }
        assert_eq!(m.cable_tension_lost[0], 0, "no dropout declared on tensions");
    }
    let lost: Vec<usize> = (3..positions.len()).filter(|&i| positions[i].1 == 1).collect();
    assert!(!lost.is_empty(), "some of 600 position values at 1 % were lost");
    assert!(lost.iter().all(|&i| positions[i].0 == positions[i - 3].0), "each holds its last value");
    assert!((3..positions.len()).all(|i| positions[i].1 == 1 || positions[i].0 != positions[i - 3].0));
    // 100 Hz at 1 ms: 20 updates of sigma 0.5 N, held in between
    let distinct = errors.windows(2).filter(|w| w[0].0 != w[1].0).count();
    assert!((18..=20).contains(&distinct), "{distinct} changes in 200 steps");
    assert!(errors.iter().any(|e| e.1.abs() > 0.05) && errors.iter().all(|e| e.1.abs() < 3.0));
    // a scene without sensors has no such service
    let params = NodeParams { start_paused: true, state_publish_rate: 0.0, ..shm_params("no_measured") };
    let prefix = params.shm_prefix();
    let _plain = RunningNode::start_serving(bundled("prism3.toml"), params);
    let client = ShmClient::connect(&prefix, WAIT).unwrap();
    client.lockstep(1, &[], WAIT).unwrap();
    assert!(client.latest_measured().unwrap().is_none());
}

#[test]
fn a_seeded_lockstep_reset_replays_the_same_noisy_episode() {
    let (_node, client) = sensed_node("seeded_reset");
    // an episode: reset with `seed`, then 50 steps of the noisy tension sensor
    let episode = |seed: u64| -> Vec<u64> {
        let first = client.lockstep_with(0, &[], Some(Some(seed)), WAIT).unwrap();
        assert_eq!(first.payload().state.step, 0, "the reset starts at step 0");
        (0..50)
            .map(|_| {
                client.lockstep(1, &[], WAIT).unwrap();
                client.latest_measured().unwrap().unwrap().payload().cable_tension[0].to_bits()
            })
            .collect()
    };
    let a = episode(21);
    client.lockstep(7, &[], WAIT).unwrap();
    assert_eq!(episode(21), a, "the same seed, the same stream");
    assert_ne!(episode(22), a, "another seed, another stream");
}
