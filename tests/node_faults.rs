//! Invariant: no peer can stop the node or make it lie. A subscriber frozen with SIGSTOP for 30 s
//! neither stops nor stalls the steps, and the topics it does not read keep flowing; a
//! StepSimulation request of 10^12 steps leaves get-state, reset and SIGTERM working, and SIGTERM
//! still answers the caller and exits 0; a request in another service mapping's layout is refused,
//! not obeyed; a paused node answers a burst of requests larger than one turn's share and then
//! takes no CPU; a second node of the same name on the same domain is warned of; subscribers resume after the node restarts; a controller killed while flooding
//! commands leaves the node running with counts that add up; 300 subscribers joining and leaving
//! leave it serving the others.
//!
//! Network rule: each test re-executes itself inside a private loopback-only network namespace
//! (tests/common/netns.rs) and uses its own domain id (65-71, 74). The tests of this file take a lock
//! so that they do not compete for the two cores.

#![cfg(feature = "ros2")]

mod common;
use common::cpu::cpu_ticks;
use common::{bundled, netns, peer, roles, running_node};

use std::sync::Mutex;
use std::time::{Duration, Instant};

use ros2_client::ServiceMapping;
use tensegrity::io::msg;
use tensegrity::io::node::params::NodeParams;

use peer::{call, closing_counts, scratch_file, signal, spawn_role, wait_for, NodeProcess, Peer, NS};
use running_node::RunningNode;

static ONE_AT_A_TIME: Mutex<()> = Mutex::new(());

/// Whether the DDS test `test` on `domain` goes on here: true inside the private namespace; false
/// where this process plays a helper role of the test (`roles`), or ran the test again inside the
/// namespace (one test of this file at a time), where the test returns.
fn runs_here(test: &str, domain: u16) -> bool {
    if roles::play_role_if_asked(domain) {
        return false;
    }
    if netns::interfaces().iter().all(|i| i == "lo") {
        return true;
    }
    let _lock = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    netns::isolated_or_rerun(&["--exact", test, "--nocapture", "--test-threads=1"])
}

const SEC: Duration = Duration::from_secs(1);

#[test]
fn a_frozen_subscriber_neither_stops_nor_stalls_the_node() {
    const TEST: &str = "a_frozen_subscriber_neither_stops_nor_stalls_the_node";
    let domain = 65;
    if !runs_here(TEST, domain) {
        return;
    }
    let params = NodeParams { domain_id: domain, state_publish_rate: 0.0, ..Default::default() };
    let node = RunningNode::start(bundled("prism3.toml"), params);
    let mut me = Peer::new(domain, "healthy");
    let actuators = me.subscribe::<msg::JointState>(NS, "actuator_states", "sensor_msgs", "JointState", 1000);
    let clock = me.subscribe::<msg::Clock>("/", "clock", "rosgraph_msgs", "Clock", 1000);
    let stop_file = scratch_file("frozen-stop");
    let _ = std::fs::remove_file(&stop_file);
    let mut frozen =
        spawn_role(TEST, "frozen-subscriber", &[("TENSEGRITY_STOP_FILE", stop_file.display().to_string())]);
    std::thread::sleep(3 * SEC); // discovery and matching
    signal(frozen.id(), "STOP");

    // 30 s frozen: the node keeps stepping at its pace, and a topic the frozen one does not read
    // keeps reaching the healthy subscriber to the end
    let start = Instant::now();
    let (mut first, mut last, mut late) = (None, 0.0, 0usize);
    while start.elapsed() < 30 * SEC {
        while let Ok(Some((m, _))) = actuators.take() {
            let t = m.header.stamp.seconds();
            first.get_or_insert(t);
            last = t;
            if start.elapsed() > 25 * SEC {
                late += 1;
            }
        }
        while let Ok(Some(_)) = clock.take() {}
        std::thread::sleep(Duration::from_millis(5));
    }
    let sim_advance = last - first.expect("actuator states while the subscriber is frozen");
    println!("frozen 30 s: sim time advanced {sim_advance:.3} s, {late} actuator states in the last 5 s");
    assert!(sim_advance > 15.0, "the node stalled: {sim_advance} s of sim time in 30 s");
    assert!(late > 100, "a topic the frozen subscriber does not read stopped flowing");

    // it resumes: /clock (which it reads) flows again to everyone. Measured here: about 19 s after
    // SIGCONT (a RustDDS reader recovers from a long freeze slowly; at the latest its participant's
    // 50 s lease ends the stall)
    signal(frozen.id(), "CONT");
    let resumed = wait_for(40 * SEC, || {
        clock.take().ok().flatten().map(|(c, _)| c.clock.seconds()).filter(|t| *t > last - 1.0)
    });
    println!("after SIGCONT: /clock at {resumed:?} (last actuator state {last:.3} s)");
    assert!(resumed.is_some(), "/clock flows again after the subscriber resumes");
    std::fs::write(&stop_file, "stop").unwrap();
    let _ = frozen.wait();
    let stats = node.stop();
    println!("publish failures per topic while frozen: {:?}", stats.publish_failures);
    assert!(stats.steps as f64 > 0.5 * 33_000.0, "{} steps", stats.steps);
    assert_eq!(stats.physics_failures, 0);
}

#[test]
fn a_trillion_step_request_leaves_reset_and_sigterm_working() {
    const TEST: &str = "a_trillion_step_request_leaves_reset_and_sigterm_working";
    let domain = 66;
    if !runs_here(TEST, domain) {
        return;
    }
    let node = NodeProcess::start(domain, &["start_paused:=true", "state_publish_rate:=10"]);
    let mut me = Peer::new(domain, "controller");
    let step: ros2_client::Client<msg::StepSimulationRequest, msg::ResultResponse> =
        me.client(ServiceMapping::Enhanced, "step_simulation", "simulation_interfaces", "StepSimulation");
    let get_state: ros2_client::Client<msg::Empty, msg::GetSimulationStateResponse> = me.client(
        ServiceMapping::Enhanced,
        "get_simulation_state",
        "simulation_interfaces",
        "GetSimulationState",
    );
    let reset: ros2_client::Client<msg::ResetSimulationRequest, msg::ResultResponse> =
        me.client(ServiceMapping::Enhanced, "reset_simulation", "simulation_interfaces", "ResetSimulation");
    let clock = me.subscribe::<msg::Clock>("/", "clock", "rosgraph_msgs", "Clock", 10);
    std::thread::sleep(2 * SEC); // discovery of every service pair
    assert_eq!(call(&get_state, msg::Empty::default(), 10 * SEC).expect("answer").state.state, 2);

    let trillion = msg::StepSimulationRequest { steps: 1_000_000_000_000 };
    let id = step.send_request(trillion).unwrap();
    std::thread::sleep(SEC);
    // stepping, yet answering: the state service and the clock
    let t = wait_for(5 * SEC, || clock.take().ok().flatten().map(|(c, _)| c.clock.seconds()));
    assert!(t.is_some_and(|t| t > 0.1), "steps are being taken: {t:?}");
    let state =
        call(&get_state, msg::Empty::default(), 5 * SEC).expect("get_state answers during the request");
    assert_eq!(state.state.state, 2, "still paused");
    // reset answers, and interrupts the request with an answer that says so
    let r = call(&reset, msg::ResetSimulationRequest { scope: 0 }, 5 * SEC).expect("reset answers");
    assert_eq!(r.result.result, 1);
    let interrupted = wait_for(5 * SEC, || match step.receive_response() {
        Ok(Some((rid, r))) if rid == id => Some(r),
        _ => None,
    })
    .expect("the interrupted request is answered");
    assert_eq!(interrupted.result.result, 4);
    assert!(interrupted.result.error_message.contains("reset"), "{}", interrupted.result.error_message);

    // SIGTERM during another such request: the caller gets an answer, the node exits 0
    let id = step.send_request(trillion).unwrap();
    std::thread::sleep(SEC);
    signal(node.pid(), "TERM");
    let answer = wait_for(5 * SEC, || match step.receive_response() {
        Ok(Some((rid, r))) if rid == id => Some(r),
        _ => None,
    });
    let (status, stderr) = node.wait();
    assert!(status.success(), "exit status {status:?}: {stderr}");
    let answer = answer
        .unwrap_or_else(|| panic!("the request under way is answered on shutdown; node said: {stderr}"));
    assert!(answer.result.error_message.contains("shutting down"), "{}", answer.result.error_message);
}

#[test]
fn a_paused_node_answers_a_burst_of_requests_and_stays_quiet() {
    const TEST: &str = "a_paused_node_answers_a_burst_of_requests_and_stays_quiet";
    let domain = 70;
    if !runs_here(TEST, domain) {
        return;
    }
    let node = NodeProcess::start(domain, &["start_paused:=true"]);
    let mut me = Peer::new(domain, "controller");
    let get_state: ros2_client::Client<msg::Empty, msg::GetSimulationStateResponse> = me.client(
        ServiceMapping::Enhanced,
        "get_simulation_state",
        "simulation_interfaces",
        "GetSimulationState",
    );
    wait_for(10 * SEC, || call(&get_state, msg::Empty::default(), SEC / 5)).expect("the node answers");

    // more requests at once than the node takes from one server in a turn (16): the rest are not
    // announced again, and must not wait for the next idle turn
    let ids: Vec<_> = (0..40).map(|_| get_state.send_request(msg::Empty::default()).unwrap()).collect();
    let mut answered = Vec::new();
    wait_for(10 * SEC, || {
        while let Ok(Some((id, r))) = get_state.receive_response() {
            assert_eq!(r.state.state, 2, "paused");
            answered.push(id);
        }
        (answered.len() >= ids.len()).then_some(())
    })
    .unwrap_or_else(|| panic!("{} of {} requests answered", answered.len(), ids.len()));
    assert!(ids.iter().all(|id| answered.contains(id)));

    // paused and unasked, it blocks in its readiness poll: no busy loop
    std::thread::sleep(SEC / 2);
    let before = cpu_ticks(node.pid());
    std::thread::sleep(3 * SEC);
    let used = cpu_ticks(node.pid()) - before;
    // clock ticks are 10 ms: the diagnostics turn (1 Hz) and DDS's own timers may take one or two
    assert!(used <= 5, "a paused DDS node used {used} ticks of CPU in 3 s");

    // SIGINT wakes the blocked loop: a clean exit
    let (status, stderr) = node.stop("INT");
    assert!(status.success(), "exit status {status:?}: {stderr}");
}

#[test]
fn a_second_node_of_the_same_name_on_the_same_domain_is_warned_of() {
    const TEST: &str = "a_second_node_of_the_same_name_on_the_same_domain_is_warned_of";
    let domain = 71;
    if !runs_here(TEST, domain) {
        return;
    }
    const WARNING: &str = "another node named /tensegrity_sim is on DDS domain 71";
    // alone: no warning (it hears its own ~/structure)
    let alone = NodeProcess::start(domain, &["start_paused:=true"]);
    std::thread::sleep(3 * SEC);
    let (status, stderr) = alone.stop("INT");
    assert!(status.success() && !stderr.contains(WARNING), "{stderr}");
    // two of one name: both keep running, and each says so
    let first = NodeProcess::start(domain, &["start_paused:=true"]);
    let second = NodeProcess::start(domain, &["start_paused:=true"]);
    std::thread::sleep(4 * SEC);
    let (s1, e1) = first.stop("INT");
    let (s2, e2) = second.stop("INT");
    assert!(s1.success() && s2.success());
    assert!(e1.contains(WARNING) && e2.contains(WARNING), "no warning:\n{e1}\n{e2}");
    assert!(e2.contains("-r __node:=NAME"), "the warning says how to rename: {e2}");
}

#[test]
fn a_request_in_another_mappings_layout_is_refused_not_obeyed() {
    const TEST: &str = "a_request_in_another_mappings_layout_is_refused_not_obeyed";
    let domain = 67;
    if !runs_here(TEST, domain) {
        return;
    }
    let params = NodeParams { domain_id: domain, start_paused: true, ..Default::default() };
    let node = RunningNode::start(bundled("prism3.toml"), params);
    let mut me = Peer::new(domain, "controller");
    // an rmw_cyclonedds-style client puts a 16-byte header before `steps`
    let cyclone: ros2_client::Client<msg::StepSimulationRequest, msg::ResultResponse> =
        me.client(ServiceMapping::Cyclone, "step_simulation", "simulation_interfaces", "StepSimulation");
    let enhanced: ros2_client::Client<msg::StepSimulationRequest, msg::ResultResponse> =
        me.client(ServiceMapping::Enhanced, "step_simulation", "simulation_interfaces", "StepSimulation");
    let clock = me.subscribe::<msg::Clock>("/", "clock", "rosgraph_msgs", "Clock", 100);
    std::thread::sleep(2 * SEC);
    let misread = call(&cyclone, msg::StepSimulationRequest { steps: 5 }, 2 * SEC);
    assert!(misread.is_none(), "a request the server cannot read is not answered as if it were");
    let r = call(&enhanced, msg::StepSimulationRequest { steps: 3 }, 10 * SEC).expect("answer");
    assert_eq!(r.result.result, 1);
    let mut ticks = 0;
    while wait_for(SEC / 2, || clock.take().ok().flatten()).is_some() {
        ticks += 1;
    }
    let stats = node.stop();
    assert_eq!(stats.steps, 3, "only the well-formed request stepped");
    assert_eq!(ticks, 3);
    assert!(stats.malformed_incoming >= 1, "the misread request was counted");
}

#[test]
fn subscribers_resume_after_the_node_restarts() {
    const TEST: &str = "subscribers_resume_after_the_node_restarts";
    let domain = 68;
    if !runs_here(TEST, domain) {
        return;
    }
    let mut me = Peer::new(domain, "listener");
    let clock = me.subscribe::<msg::Clock>("/", "clock", "rosgraph_msgs", "Clock", 10);
    let cables = me.subscribe::<msg::CableStates>(NS, "cable_states", "tensegrity_msgs", "CableStates", 10);
    for run in 0..2 {
        let node = NodeProcess::start(domain, &[]);
        let t = wait_for(15 * SEC, || clock.take().ok().flatten().map(|(c, _)| c.clock.seconds()));
        assert!(t.is_some(), "run {run}: the clock reaches the subscriber that stayed up");
        let c = wait_for(5 * SEC, || cables.take().ok().flatten());
        assert!(c.is_some(), "run {run}: cable states too");
        std::thread::sleep(SEC);
        let (status, stderr) = node.stop("INT");
        assert!(status.success(), "{stderr}");
        while let Ok(Some(_)) = clock.take() {}
    }
}

#[test]
fn a_controller_killed_while_flooding_leaves_the_node_running() {
    const TEST: &str = "a_controller_killed_while_flooding_leaves_the_node_running";
    let domain = 69;
    if !runs_here(TEST, domain) {
        return;
    }
    let mut node = NodeProcess::start(domain, &[]);
    let mut me = Peer::new(domain, "listener");
    let clock = me.subscribe::<msg::Clock>("/", "clock", "rosgraph_msgs", "Clock", 10);
    let mut flooder = spawn_role(TEST, "flooder", &[]);
    std::thread::sleep(5 * SEC);
    signal(flooder.id(), "KILL");
    let _ = flooder.wait();
    std::thread::sleep(SEC);
    assert!(node.alive(), "the node survived the flood and the killed controller");
    while let Ok(Some(_)) = clock.take() {}
    let t = wait_for(5 * SEC, || clock.take().ok().flatten().map(|(c, _)| c.clock.seconds()));
    assert!(t.is_some(), "and keeps publishing");
    let (status, stderr) = node.stop("INT");
    assert!(status.success(), "{stderr}");
    let (received, accepted, rejected) = closing_counts(&stderr);
    println!("{}", stderr.lines().last().unwrap_or(""));
    assert!(received > 100, "the flood arrived: {received}");
    assert_eq!(received, accepted + rejected);
    assert!(rejected > 0 && accepted > 0);
}

#[test]
fn subscribers_joining_and_leaving_hundreds_of_times_leave_the_node_unharmed() {
    const TEST: &str = "subscribers_joining_and_leaving_hundreds_of_times_leave_the_node_unharmed";
    let domain = 74;
    if !runs_here(TEST, domain) {
        return;
    }
    let mut node = NodeProcess::start(domain, &[]);
    let mut steady = Peer::new(domain, "steady");
    let clock = steady.subscribe::<msg::Clock>("/", "clock", "rosgraph_msgs", "Clock", 10);
    assert!(wait_for(15 * SEC, || clock.take().ok().flatten()).is_some(), "the steady subscriber is served");
    let rss_before = peer::rss_kb(node.pid());
    for k in 0..300 {
        // a participant with reliable readers on the busiest topics, gone again at once
        let mut visitor = Peer::new(domain, &format!("visitor{k}"));
        let _c =
            visitor.subscribe::<msg::CableStates>(NS, "cable_states", "tensegrity_msgs", "CableStates", 10);
        let _t = visitor.subscribe::<msg::Clock>("/", "clock", "rosgraph_msgs", "Clock", 1);
        std::thread::sleep(Duration::from_millis(10));
    }
    std::thread::sleep(2 * SEC);
    assert!(node.alive());
    while let Ok(Some(_)) = clock.take() {}
    assert!(
        wait_for(10 * SEC, || clock.take().ok().flatten()).is_some(),
        "the steady subscriber is still served"
    );
    let rss_after = peer::rss_kb(node.pid());
    println!("300 visitors: node RSS {rss_before} kB -> {rss_after} kB");
    let (status, stderr) = node.stop("INT");
    assert!(status.success(), "{stderr}");
}

#[test]
fn the_node_binary_answers_help_and_version_and_refuses_unknown_options() {
    // no DDS socket is opened: no namespace needed
    let run = |args: &[&str]| {
        std::process::Command::new(env!("CARGO_BIN_EXE_tensegrity_node")).args(args).output().unwrap()
    };
    let help = run(&["--help"]);
    assert!(help.status.success());
    let text = String::from_utf8(help.stdout).unwrap();
    for (name, _, _) in tensegrity::io::node::params::PARAMETERS {
        assert!(text.contains(name), "--help lists {name}");
    }
    assert!(text.contains("ROS_DOMAIN_ID") && text.contains("SIGTERM"));
    // the ready file's lines, all of them (write_ready_file)
    for key in
        ["pid=", "domain_id=", "namespace=", "node=", "private_namespace=", "shm_prefix=", "transports="]
    {
        assert!(text.contains(key), "--help names the ready file's {key} line");
    }
    let version = run(&["--version"]);
    assert!(
        version.status.success()
            && String::from_utf8_lossy(&version.stdout).contains(env!("CARGO_PKG_VERSION"))
    );
    let unknown = run(&["--frobnicate"]);
    assert_eq!(unknown.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&unknown.stderr).contains("unknown option '--frobnicate'"));
    // ROS arguments before --ros-args, and a node name ROS refuses: argument errors that say why
    let early = run(&["-p", "physics_dt:=0.002"]);
    assert_eq!(early.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&early.stderr).contains("put it after --ros-args"));
    let bad_name = run(&["--ros-args", "-r", "__node:=bad-name"]);
    assert_eq!(bad_name.status.code(), Some(2), "an argument error, not a transport error");
    assert!(String::from_utf8_lossy(&bad_name.stderr).contains("letters, digits and underscores"));
}

#[test]
fn exit_statuses_say_why_the_node_stopped_and_the_ready_file_says_when_it_is_up() {
    // shared memory only, or refused before any transport: no DDS socket is opened
    let node = env!("CARGO_BIN_EXE_tensegrity_node");
    let prefix = format!("-p shm_prefix:=exit_test_{}", std::process::id());
    let run = |args: &str| {
        let mut a: Vec<String> = args.split_whitespace().map(String::from).collect();
        if let Some(i) = a.iter().position(|x| x == "--ros-args") {
            a.splice(i + 1..i + 1, ["-p".to_string(), "transports:=shm".to_string()]);
            a.extend(prefix.split_whitespace().map(String::from));
        }
        std::process::Command::new(node).args(&a).output().unwrap()
    };
    let scratch = std::env::temp_dir().join(format!("tensegrity-exit-{}", std::process::id()));
    std::fs::create_dir_all(&scratch).unwrap();
    let bad_scene = scratch.join("bad.toml");
    std::fs::write(&bad_scene, "name = 3\n").unwrap();
    let cases = [
        ("--frobnicate", 2, "unknown option"),
        ("--ready-file", 2, "--ready-file needs a PATH"),
        ("--ros-args -p physics_dt:=-1", 2, "physics_dt"),
        ("--ros-args -p no_such:=1", 2, "no_such"),
        (&format!("{} --ros-args", bad_scene.display()), 3, "bad.toml"),
        ("/no/such/scene.toml --ros-args", 3, "/no/such/scene.toml"),
        ("bundled:prism4 --ros-args", 3, "no bundled scene 'prism4' (bundled: atwood, prism3"),
        ("--ros-args -p record:=/proc/no/such/dir", 4, "record"),
        ("--ros-args -p integrator:=symplectic-euler -p physics_dt:=0.05", 5, "stability limit"),
    ];
    for (args, code, needle) in cases {
        let out = run(args);
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(code), "{args}: {err}");
        assert!(err.contains(needle), "{args}: {err}");
    }

    // the ready file appears whole once the node serves, and goes when it stops
    let ready = scratch.join("ready");
    let mut cmd = std::process::Command::new(node);
    tensegrity::testing::die_with_parent(&mut cmd);
    let mut child = cmd
        .args(["--ready-file", ready.to_str().unwrap(), "--ros-args", "-p", "transports:=shm"])
        .args(prefix.split_whitespace())
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    let text = wait_for(10 * SEC, || std::fs::read_to_string(&ready).ok()).expect("the ready file appears");
    assert!(text.contains(&format!("pid={}\n", child.id())), "{text}");
    assert!(
        text.contains("transports=shm\n")
            && text.contains(&format!("shm_prefix=exit_test_{}", std::process::id()))
    );
    signal(child.id(), "INT");
    let status = wait_for(10 * SEC, || child.try_wait().unwrap()).expect("it stops on SIGINT");
    assert_eq!(status.code(), Some(0));
    let mut stdout = String::new();
    std::io::Read::read_to_string(child.stdout.as_mut().unwrap(), &mut stdout).unwrap();
    assert_eq!(stdout, "ready\n");
    assert!(!ready.exists(), "the ready file is removed at exit");
    let _ = std::fs::remove_dir_all(&scratch);
}
