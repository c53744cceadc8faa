//! Invariant: the test kit (`tensegrity::testing`) lets a user test a controller in a few lines,
//! deterministically and in isolation. The README's proportional ring-tension controller reaches
//! its target in lockstep (tight tolerance) and in real time (looser); the same controller over
//! DDS, stepped with `step_awaiting_commands`, gives bit for bit the in-process trajectory while a
//! second simulator on another leased domain runs beside it; over shared memory, lockstep results
//! are bit-identical across runs and under a CPU hog on every core. These four tests run in
//! parallel (`cargo test`'s default threads) with the default node and topic names. A test
//! interrupted by Ctrl-C leaves no child behind, not even one it stopped.
// without the transports only the in-process tests remain
#![cfg_attr(not(all(feature = "ros2", feature = "shm")), allow(unused_imports, dead_code))]

use std::time::Duration;

use tensegrity::io::node::params::TransportKind;
use tensegrity::testing::{self, Command, DomainLease, KitError, SimBuilder, Snapshot};

/// Ring tension the README's controller drives to, N (the scene starts at 100 N).
const TARGET: f64 = 300.0;
/// Winch rate per newton of tension error, m/s/N (a 0.2 s time constant on this prism).
const GAIN: f64 = 2e-3;
/// Steps between two controller updates (10 ms at the scene's 1 ms step).
const PERIOD: u64 = 10;

/// The README's controller: winch rate proportional to the tension error.
fn ring_command(s: &Snapshot) -> Command {
    let tension = s.tension("ring").expect("prism3 has a ring cable");
    Command::new("ring_winch").rate(GAIN * (tension - TARGET))
}

// README example (Rust, lockstep): start here.
#[test]
fn lockstep_controller_reaches_its_target_tension() {
    let sim = SimBuilder::bundled("prism3").start().unwrap();
    let mut state = sim.step(0).unwrap(); // the initial state
    for _ in 0..150 {
        state = sim.step_with(&[ring_command(&state)], PERIOD).unwrap();
    }
    let tension = state.tension("ring").unwrap();
    assert!((tension - TARGET).abs() < 0.5, "ring tension {tension} N after 1.5 s");
    assert_eq!(state.step, 1500);
    assert!((state.time - 1.5).abs() < 1e-12);
    // a careless command is refused with the node's reason; the simulation goes on
    let e = sim.command(Command::new("ring_winch").rest_length(f64::NAN)).unwrap_err();
    assert!(matches!(&e, KitError::Refused(why) if why.contains("finite")), "{e}");
    let e = sim.command(Command::new("no_such_winch").rate(0.1)).unwrap_err();
    assert!(e.to_string().contains("no_such_winch"), "{e}");
    assert_eq!(sim.step(1).unwrap().step, 1501);
    let end = sim.stop();
    assert_eq!((end.stats.commands_received, end.stats.commands_rejected), (152, 2));
    assert_eq!(end.fault, None);
}
// README example end.

/// The README's lockstep controller for 150 periods (1.5 s), every state kept.
fn lockstep_run(sim: &testing::SimUnderTest) -> Vec<Snapshot> {
    let mut s = sim.step(0).unwrap();
    let mut all = vec![s.clone()];
    for _ in 0..150 {
        s = sim.step_with(&[ring_command(&s)], PERIOD).unwrap();
        all.push(s.clone());
    }
    all
}

// README example (Rust, real time): start here.
#[test]
fn real_time_controller_reaches_its_target_tension() {
    let sim = SimBuilder::bundled("prism3").real_time().param("state_publish_rate", "100").start().unwrap();
    let mut seen = 0;
    let mut state = sim.latest();
    while state.time < 2.0 {
        // the next published state (every 10 ms of sim time), however late the test thread runs
        state = sim.wait_for_state(|s| s.step > seen).unwrap();
        seen = state.step;
        sim.command(ring_command(&state)).unwrap();
    }
    let tension = state.tension("ring").unwrap();
    assert!((tension - TARGET).abs() < 0.02 * TARGET, "ring tension {tension} N after {} s", state.time);
    // the lockstep calls are refused while playing
    assert!(matches!(sim.step(1), Err(KitError::Refused(_))));
}
// README example end.

/// The physics of two states (time, step, poses, cables, actuators), without the counters.
fn physics(s: &Snapshot) -> impl PartialEq + std::fmt::Debug + '_ {
    (
        s.time,
        s.step,
        &s.body_position,
        &s.body_orientation,
        &s.cable_tension,
        &s.cable_length,
        &s.cable_rest_length,
        &s.actuator_rest_length,
        &s.actuator_rate,
    )
}

/// A DDS controller on `domain`: answers each `~/cable_states` message with the README's control
/// law towards `target` (one command per state) until it has answered `answers` of them. Sets
/// `ready` once it has the node's transient-local structure (its endpoints are matched).
#[cfg(feature = "ros2")]
fn dds_controller(
    domain: u16,
    ns: String,
    target: f64,
    answers: usize,
    ready: std::sync::Arc<std::sync::atomic::AtomicBool>,
) -> std::thread::JoinHandle<usize> {
    use ros2_client::{MessageTypeName, Name, NodeName, NodeOptions};
    use tensegrity::io::msg;
    use tensegrity::io::ros2::{context, qos};
    std::thread::spawn(move || {
        let ctx = context(domain, true).unwrap();
        let mut node = ctx.new_node(NodeName::new("/", "controller").unwrap(), NodeOptions::new()).unwrap();
        let topic = |name: &str, ty: &str, transient: bool| {
            node.create_topic(
                &Name::new(&ns, name).unwrap(),
                MessageTypeName::new("tensegrity_msgs", ty),
                &qos(16, transient),
            )
            .unwrap()
        };
        let t_states = topic("cable_states", "CableStates", false);
        let t_cmd = topic("actuator_commands", "ActuatorCommand", false);
        let t_structure = topic("structure", "Structure", true);
        let states = node.create_subscription::<msg::CableStates>(&t_states, None).unwrap();
        let structure = node.create_subscription::<msg::Structure>(&t_structure, None).unwrap();
        let commands = node.create_publisher::<msg::ActuatorCommand>(&t_cmd, None).unwrap();
        let deadline = std::time::Instant::now() + Duration::from_secs(90);
        while !matches!(structure.take(), Ok(Some(_))) && std::time::Instant::now() < deadline {
            std::thread::sleep(Duration::from_millis(5));
        }
        std::thread::sleep(Duration::from_millis(500)); // the state and command endpoints too
        ready.store(true, std::sync::atomic::Ordering::SeqCst);
        let mut answered = 0;
        while answered < answers && std::time::Instant::now() < deadline {
            match states.take() {
                Ok(Some((m, _))) => {
                    let ring = m.name.iter().position(|n| n == "ring").unwrap();
                    let rate = GAIN * (m.tension[ring] - target);
                    let command = msg::ActuatorCommand {
                        name: vec!["ring_winch".into()],
                        rate: vec![rate],
                        ..Default::default()
                    };
                    commands.publish(command).unwrap();
                    answered += 1;
                }
                _ => std::thread::sleep(Duration::from_micros(200)),
            }
        }
        // leave the participant up until the last command is delivered
        std::thread::sleep(Duration::from_secs(1));
        answered
    })
}

#[cfg(feature = "ros2")]
#[test]
fn a_dds_controller_in_lockstep_matches_the_in_process_run_bit_for_bit_beside_another_simulator() {
    use std::sync::atomic::{AtomicBool, Ordering};
    use std::sync::Arc;
    const TEST: &str =
        "a_dds_controller_in_lockstep_matches_the_in_process_run_bit_for_bit_beside_another_simulator";
    if !testing::isolated_or_rerun(TEST) {
        return;
    }
    // the in-process reference
    let reference = lockstep_run(&SimBuilder::bundled("prism3").start().unwrap());

    // two simulators with DDS and the default names, each on its own leased domain, publishing
    // their state once per controller period (100 Hz of sim time); a controller on each
    let start = || {
        SimBuilder::bundled("prism3")
            .transports(&[TransportKind::Dds])
            .param("state_publish_rate", "100")
            .start()
            .unwrap()
    };
    let (sim, other) = (start(), start());
    assert_ne!(sim.domain_id(), other.domain_id());
    assert_eq!(sim.private_namespace(), other.private_namespace());
    let ready = [Arc::new(AtomicBool::new(false)), Arc::new(AtomicBool::new(false))];
    let ns = sim.private_namespace();
    let a = dds_controller(sim.domain_id().unwrap(), ns.clone(), TARGET, 150, ready[0].clone());
    let b = dds_controller(other.domain_id().unwrap(), ns, 150.0, 150, ready[1].clone());
    let start = std::time::Instant::now();
    while !ready.iter().all(|r| r.load(Ordering::SeqCst)) {
        assert!(start.elapsed() < Duration::from_secs(60), "the controllers did not find the nodes");
        std::thread::sleep(Duration::from_millis(10));
    }
    // the first command comes from the test (the initial state was published before the
    // controller subscribed); then the controller answers each state, and the kit waits for it
    let first = sim.step(0).unwrap();
    assert_eq!(physics(&first), physics(&reference[0]));
    sim.command(ring_command(&first)).unwrap();
    other.command(Command::new("ring_winch").rate(GAIN * (100.0 - 150.0))).unwrap();
    let mut over_dds = vec![first];
    for _ in 0..150 {
        over_dds.push(sim.step_awaiting_commands(PERIOD, 1).unwrap());
        other.step_awaiting_commands(PERIOD, 1).unwrap();
    }
    for (k, (d, r)) in over_dds.iter().zip(&reference).enumerate() {
        assert_eq!(
            physics(d),
            physics(r),
            "period {k}: the DDS-driven state differs from the in-process one"
        );
    }
    let other_tension = other.latest().tension("ring").unwrap();
    assert!((other_tension - 150.0).abs() < 1.0, "the other simulator went its own way: {other_tension} N");
    let (ends, other_ends) = (sim.stop(), other.stop());
    assert_eq!((ends.stats.commands_received, other_ends.stats.commands_received), (151, 151));
    assert_eq!((a.join().unwrap(), b.join().unwrap()), (150, 150));
}

#[cfg(feature = "shm")]
#[test]
fn shared_memory_lockstep_is_bit_identical_across_runs_and_under_a_cpu_hog() {
    use tensegrity::io::shm::{CommandEntry, ShmClient};
    let run = || {
        let sim = SimBuilder::bundled("prism3").transports(&[TransportKind::Shm]).start().unwrap();
        let client = ShmClient::connect(&sim.shm_prefix().unwrap(), Duration::from_secs(10)).unwrap();
        let mut tension = 100.0;
        let mut trajectory = Vec::new();
        for _ in 0..150 {
            let command = [CommandEntry::named("ring_winch").rate(GAIN * (tension - TARGET))];
            let answer = client.lockstep(PERIOD, &command, Duration::from_secs(10)).unwrap();
            let p = answer.payload();
            tension = p.state.cable_tension[3];
            trajectory.push((
                p.state.time,
                p.state.body_position[..3].to_vec(),
                p.state.cable_tension[..4].to_vec(),
            ));
        }
        // what the kit's handle reads is the same state
        let latest = sim.latest();
        assert_eq!(latest.cable_tension, trajectory.last().unwrap().2);
        trajectory
    };
    let quiet = run();
    let hogs: Vec<_> = (0..std::thread::available_parallelism().map_or(2, |n| n.get()))
        .map(|_| {
            let mut hog = std::process::Command::new("sh");
            // an interrupted test must not leave the hogs spinning
            tensegrity::testing::die_with_parent(hog.args(["-c", "while :; do :; done"]));
            hog.spawn().unwrap()
        })
        .collect();
    let loaded = run();
    for mut h in hogs {
        let _ = h.kill();
        let _ = h.wait();
    }
    assert_eq!(quiet, loaded, "lockstep results changed under load");
    let tension = quiet.last().unwrap().2[3];
    assert!((tension - TARGET).abs() < 0.5, "{tension}");
}

#[test]
fn domain_leases_are_distinct_and_a_dead_owners_lease_is_taken_over() {
    let leases: Vec<_> = (0..20).map(|_| DomainLease::acquire().unwrap()).collect();
    let mut ids: Vec<_> = leases.iter().map(|l| l.id()).collect();
    ids.sort_unstable();
    ids.dedup();
    assert_eq!(ids.len(), 20);
    assert!(ids.iter().all(|id| testing::LEASED_DOMAINS.contains(id)));
    drop(leases);
    // a lock file left by a process that has ended is stale
    let dead = std::process::Command::new("true").spawn().unwrap();
    let dead_pid = dead.id();
    let _ = { dead }.wait();
    let dir = DomainLease::directory();
    let all: Vec<u16> = testing::LEASED_DOMAINS.collect();
    let mut held = Vec::new();
    for id in &all {
        let f = dir.join(id.to_string());
        if std::fs::OpenOptions::new().write(true).create_new(true).open(&f).is_ok() {
            std::fs::write(&f, dead_pid.to_string()).unwrap();
            held.push(f);
        }
    }
    let lease = DomainLease::acquire().expect("a stale lease is taken over");
    assert_eq!(
        std::fs::read_to_string(dir.join(lease.id().to_string())).unwrap(),
        std::process::id().to_string()
    );
    drop(lease);
    for f in held {
        // only those still stale (a parallel test may have taken one over meanwhile)
        if std::fs::read_to_string(&f).is_ok_and(|o| o == dead_pid.to_string()) {
            let _ = std::fs::remove_file(f);
        }
    }
}

#[test]
fn careless_starts_are_refused_with_the_reason() {
    let e = SimBuilder::scene_file("no/such/scene.toml").start().unwrap_err();
    assert!(matches!(&e, KitError::Scene(why) if why.contains("no/such/scene.toml")), "{e}");
    let e = SimBuilder::bundled("prism3").param("physics_dt", "-1").start().unwrap_err();
    assert!(matches!(&e, KitError::Params(why) if why.contains("physics_dt")), "{e}");
    let e = SimBuilder::bundled("prism3").param("integrator", "leapfrog").start().unwrap_err();
    assert!(matches!(&e, KitError::Params(_)), "{e}");
    let e = SimBuilder::scene_text("name = 3", "<inline>").start().unwrap_err();
    assert!(e.to_string().contains("<inline>"), "{e}");
    // transports given as a parameter are served, not silently dropped
    let e = SimBuilder::bundled("prism3").param("transports", "udp").start().unwrap_err();
    assert!(matches!(&e, KitError::Params(why) if why.contains("udp")), "{e}");
    #[cfg(feature = "shm")]
    {
        let sim = SimBuilder::bundled("prism3").param("transports", "shm").start().unwrap();
        assert!(sim.shm_prefix().is_some_and(|p| p.contains("_kit")), "{sim:?}");
    }
}

/// Process state letter of `pid` from /proc (`None` once it is gone).
fn process_state(pid: u32) -> Option<char> {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).ok()?;
    stat[stat.rfind(')')? + 2..].chars().next()
}

#[test]
fn an_interrupted_test_leaves_no_child_behind_not_even_a_stopped_one() {
    const TEST: &str = "an_interrupted_test_leaves_no_child_behind_not_even_a_stopped_one";
    if let Ok(pid_file) = std::env::var("TENSEGRITY_ORPHAN_ROLE") {
        // the role: a test that stopped a child of its own (the frozen-subscriber test does),
        // then is interrupted
        let mut sleeper = std::process::Command::new("sleep");
        testing::die_with_parent(sleeper.arg("1000"));
        let mut child = sleeper.spawn().unwrap();
        let stopped = std::process::Command::new("kill").args(["-STOP", &child.id().to_string()]).status();
        assert!(stopped.unwrap().success());
        std::fs::write(&pid_file, child.id().to_string()).unwrap();
        std::thread::sleep(Duration::from_secs(60));
        // not reached when the test interrupts this role, as it does
        let _ = child.kill();
        let _ = child.wait();
        return;
    }
    let pid_file = std::env::temp_dir().join(format!("tensegrity-orphan-{}", std::process::id()));
    let _ = std::fs::remove_file(&pid_file);
    let mut role = std::process::Command::new(std::env::current_exe().unwrap());
    testing::die_with_parent(&mut role);
    let mut role = role
        .args(["--exact", TEST, "--nocapture", "--test-threads=1"])
        .env("TENSEGRITY_ORPHAN_ROLE", &pid_file)
        .stdout(std::process::Stdio::null())
        .spawn()
        .unwrap();
    let start = std::time::Instant::now();
    let child: u32 = loop {
        if let Some(pid) = std::fs::read_to_string(&pid_file).ok().and_then(|t| t.trim().parse().ok()) {
            break pid;
        }
        assert!(start.elapsed() < Duration::from_secs(20), "the role did not start its child");
        std::thread::sleep(Duration::from_millis(10));
    };
    let _ = std::fs::remove_file(&pid_file);
    // SIGSTOP is delivered asynchronously: `kill` returns before the child shows as stopped
    let start = std::time::Instant::now();
    while process_state(child) != Some('T') && start.elapsed() < Duration::from_secs(10) {
        std::thread::sleep(Duration::from_millis(10));
    }
    assert_eq!(process_state(child), Some('T'), "the role's child is stopped");
    // Ctrl-C reaches the test process; its stopped child cannot act on any signal but SIGKILL
    let interrupted = std::process::Command::new("kill").args(["-INT", &role.id().to_string()]).status();
    assert!(interrupted.unwrap().success());
    role.wait().unwrap();
    let start = std::time::Instant::now();
    // gone, or a zombie waiting for a reaper: either way it no longer runs or holds anything
    while !matches!(process_state(child), None | Some('Z')) {
        assert!(start.elapsed() < Duration::from_secs(10), "the stopped child outlived the test");
        std::thread::sleep(Duration::from_millis(10));
    }
}

// README example (Rust, a robot): start here.
/// Where the six-bar robot rolls when a winch hauls in the cable between two of the strut ends
/// it stands on (`a`, `b`): along that edge, toward the side the two struts lean to (the
/// horizontal run from each foot to its strut's centre, summed along the edge). A rule read off
/// the simulator for this robot, checked at every roll below. A unit vector in the floor's plane.
fn roll_direction(s: &Snapshot, a: &str, b: &str) -> [f64; 2] {
    let strut = |foot: &str| s.position(foot.split('.').next().unwrap()).unwrap();
    let (pa, pb) = (s.contact(a).unwrap().position, s.contact(b).unwrap().position);
    let (ca, cb) = (strut(a), strut(b));
    let edge = [pb[0] - pa[0], pb[1] - pa[1]];
    let length = edge[0].hypot(edge[1]);
    let lean = (ca[0] - pa[0] + cb[0] - pb[0]) * edge[0] + (ca[1] - pa[1] + cb[1] - pb[1]) * edge[1];
    let sign = if lean >= 0.0 { 1.0 } else { -1.0 };
    [sign * edge[0] / length, sign * edge[1] / length]
}

/// The robot's centre (the struts' mean position) in the floor's plane, m.
fn centre(s: &Snapshot) -> [f64; 2] {
    let n = s.body_position.len() as f64;
    let sum = s.body_position.iter().fold([0.0, 0.0], |c, p| [c[0] + p[0], c[1] + p[1]]);
    [sum[0] / n, sum[1] / n]
}

/// Steps until the robot stands still on three feet (its centre moves less than 1 mm in 0.1 s).
fn settle(sim: &testing::SimUnderTest, mut s: Snapshot) -> Snapshot {
    for _ in 0..100 {
        let before = centre(&s);
        s = sim.step(100).unwrap();
        let after = centre(&s);
        if s.touching().count() >= 3 && (after[0] - before[0]).hypot(after[1] - before[1]) < 1e-3 {
            return s;
        }
    }
    panic!("the robot did not come to rest");
}

#[test]
fn a_controller_rolls_the_six_bar_robot_face_to_face_to_a_goal() {
    // sixbar_rover: the six-bar robot with a winch on every cable (w_ and the cable's name)
    let scene = tensegrity::scene::load(std::path::Path::new("config/scenes/sixbar_rover.toml")).unwrap();
    let sim = SimBuilder::bundled("sixbar_rover").param("start_from_equilibrium", "true").start().unwrap();
    let goal = [2.0, -1.0];
    let mut s = sim.step(0).unwrap();
    let mut rolls = 0;
    while (goal[0] - centre(&s)[0]).hypot(goal[1] - centre(&s)[1]) > 0.3 {
        let feet: Vec<&str> = s.touching().collect();
        let here = centre(&s);
        let toward_goal = |d: &[f64; 2]| d[0] * (goal[0] - here[0]) + d[1] * (goal[1] - here[1]);
        // of the cables between two feet, the one whose roll points most toward the goal
        let (cable, predicted) = (0..scene.cables.len())
            .filter_map(|c| {
                let route = scene.route(tensegrity::model::CableId(c));
                let (a, b) = (scene.points[route[0].0].name.as_str(), scene.points[route[1].0].name.as_str());
                (feet.contains(&a) && feet.contains(&b)).then(|| (c, roll_direction(&s, a, b)))
            })
            .max_by(|x, y| toward_goal(&x.1).total_cmp(&toward_goal(&y.1)))
            .expect("the robot stands on a cable between two feet");
        let (winch, rest) = (format!("w_{}", scene.cable_names[cable]), scene.initial_rest_lengths[cable]);
        // haul it in to 57 % for 2.5 s (the robot tips onto the next face), pay it back out, settle
        sim.step_with(&[Command::new(&winch).rest_length(0.57 * rest)], 2500).unwrap();
        s = settle(&sim, sim.step_with(&[Command::new(&winch).rest_length(rest)], 500).unwrap());
        let moved = [centre(&s)[0] - here[0], centre(&s)[1] - here[1]];
        let along = (moved[0] * predicted[0] + moved[1] * predicted[1]) / moved[0].hypot(moved[1]);
        println!(
            "roll {rolls}: {winch} moved the robot {moved:.2?} m, now on {:?}",
            s.touching().collect::<Vec<_>>()
        );
        assert!(along > 0.94, "{winch}: rolled {moved:?}, predicted {predicted:?}");
        rolls += 1;
        assert!(rolls <= 12, "not at the goal after {rolls} rolls: at {:?}", centre(&s));
    }
    assert!(sim.stop().fault.is_none());
}
// README example end.

#[test]
fn a_tension_command_through_the_kit_settles_the_tensioner() {
    let scene = concat!(env!("CARGO_MANIFEST_DIR"), "/config/examples/tensioner.toml");
    let sim = SimBuilder::scene_file(scene).param("start_from_equilibrium", "true").start().unwrap();
    let state = sim.step_with(&[Command::new("tensioner").tension(30.0)], 3000).unwrap();
    let spring = state.tension("spring").unwrap();
    assert!((spring - 30.0).abs() < 1e-6, "the spring carries {spring} N");
    // a tension for a winch that cannot give it, and a tension with a rest length, are refused
    for careless in
        [Command::new("tensioner").tension(1e3), Command::new("tensioner").tension(5.0).rest_length(1.0)]
    {
        let e = sim.command(careless).unwrap_err();
        assert!(matches!(&e, KitError::Refused(why) if why.contains("tension")), "{e}");
    }
    assert_eq!(sim.stop().stats.commands_rejected, 2);
}
