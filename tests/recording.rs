//! Invariant: a run recorded as a rosbag2 bag reads back in an independent reader (the Python
//! `rosbags` package, with our message types registered from `msg/` and the standard ones from
//! its own ROS 2 store) with every topic, type, count and value the simulator produced; replaying
//! a bag with its recorded commands at their recorded steps gives the same bits, and a changed
//! scene is caught at its first differing field; a bag cut short or whose writer was killed is
//! read up to its last complete chunk and can be rewritten complete (`bag reindex`).
//!
//! The node's own recordings (DDS commands from a controller on a second context, Ctrl-C) run in
//! a private loopback-only network namespace, each on its own domain id, like every DDS test.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Duration;

use tensegrity::io::msg;
use tensegrity::io::node::params::NodeParams;
use tensegrity::io::node::NodeCore;
use tensegrity::io::record;
use tensegrity::io::record::bag::{self, BagOptions, BagReader};
use tensegrity::sim::{SimSettings, Simulator};

mod common;
use common::bags;

use bags::{applied_commands, floats, our_counts, rosbags_counts, rosbags_read};

fn scene_path(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("config/scenes").join(name)
}

fn cli(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_tensegrity")).args(args).output().expect("tensegrity runs")
}

/// A fresh (not yet existing) bag directory for one test.
fn bag_dir(name: &str) -> PathBuf {
    let d = common::scratch("bags").join(name);
    let _ = std::fs::remove_dir_all(&d);
    d
}

/// Records `tensegrity deploy prism3.toml ARGS --record DIR` into a fresh bag directory `name`.
fn deploy_recorded(name: &str, args: &[&str]) -> PathBuf {
    let dir = bag_dir(name);
    let prism = scene_path("prism3.toml");
    let mut all = vec!["deploy", prism.to_str().unwrap()];
    all.extend_from_slice(args);
    all.extend_from_slice(&["--record", dir.to_str().unwrap()]);
    let out = cli(&all);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    dir
}

/// Records `tensegrity deploy SCENE --dynamic --from-equilibrium --duration DURATION --record
/// DIR` into a fresh bag directory `name`.
fn record_from_equilibrium(scene: &Path, name: &str, duration: &str) -> PathBuf {
    let dir = bag_dir(name);
    let (scene, bag) = (scene.to_str().unwrap(), dir.to_str().unwrap());
    let out =
        cli(&["deploy", scene, "--dynamic", "--from-equilibrium", "--duration", duration, "--record", bag]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    dir
}

/// `tensegrity replay DIR` succeeds and says "identical".
fn assert_replays_identically(dir: &Path) {
    let out = cli(&["replay", dir.to_str().unwrap()]);
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success() && text.contains("identical"),
        "{text}{}",
        String::from_utf8_lossy(&out.stderr)
    );
}

#[test]
fn a_robot_on_the_ground_records_its_contacts_and_replays_them_bit_for_bit() {
    let scene = scene_path("sixbar.toml");
    let dir = record_from_equilibrium(&scene, "contacts", "0.3");
    let ours = our_counts(&dir);
    let contacts = "/tensegrity_sim/contacts";
    assert_eq!(ours.get(contacts), Some(&("tensegrity_msgs/msg/ContactStates".to_string(), 301)), "{ours:?}");
    // at rest on its bottom face: three ends carry the weight, in the simulator's numbers
    let model = tensegrity::scene::load(&scene).unwrap();
    let weight: f64 = model.bodies.iter().map(|b| b.mass).sum::<f64>() * 9.81;
    let reader = BagReader::open(&dir).unwrap();
    let first: msg::ContactStates =
        reader.messages().map(Result::unwrap).find(|m| m.topic == contacts).unwrap().decode().unwrap();
    assert_eq!(first.point.len(), 12);
    let standing: Vec<&str> =
        first.point.iter().zip(&first.in_contact).filter(|(_, c)| **c).map(|(p, _)| p.as_str()).collect();
    assert_eq!(standing, ["x0.b", "y0.b", "z0.b"]);
    let carried: f64 = first.normal_force.iter().sum();
    assert!((carried - weight).abs() < 1e-6 * weight, "{carried} N of {weight} N");
    if let Some(v) = rosbags_read(&dir) {
        assert_eq!(rosbags_counts(&v), ours, "rosbags and our reader disagree");
        let read = &v["messages"][contacts][0];
        assert_eq!(floats(&read["normal_force"]), first.normal_force, "rosbags reads other numbers");
    }
    assert_replays_identically(&dir);
}

#[test]
fn colliding_struts_are_recorded_as_contacts_and_replay_bit_for_bit() {
    let dir = bag_dir("collision");
    let root = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let scene = root.join("config/examples/collision.toml");
    let args = [
        "deploy",
        scene.to_str().unwrap(),
        "--dynamic",
        "--duration",
        "0.5",
        "--record",
        dir.to_str().unwrap(),
    ];
    let out = cli(&args);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    assert!(String::from_utf8_lossy(&out.stdout).contains("struts that collided: rod-trapeze"));
    let contacts = "/tensegrity_sim/contacts";
    let reader = BagReader::open(&dir).unwrap();
    let states: Vec<msg::ContactStates> = reader
        .messages()
        .map(Result::unwrap)
        .filter(|m| m.topic == contacts)
        .map(|m| m.decode().unwrap())
        .collect();
    assert_eq!(states.len(), 501);
    assert_eq!(
        (states[0].point.as_slice(), states[0].ground.as_slice()),
        (&["rod".to_string()][..], &["trapeze".to_string()][..])
    );
    // the rod lands on the bar: pressed in, pushed up (the normal from the bar to the rod)
    let landed = states.iter().find(|m| m.in_contact[0]).expect("the rod never touched the bar");
    assert!(landed.normal_force[0] > 0.0 && landed.normal[0].z > 0.99, "{landed:?}");
    assert_replays_identically(&dir);
}

#[test]
fn a_dynamic_deployment_bag_reads_back_in_rosbags_equal_to_the_simulator() {
    let dir = deploy_recorded("dynamic", &["--dynamic", "--duration", "0.25"]);
    let ours = our_counts(&dir);
    let expected = [
        ("/clock", "rosgraph_msgs/msg/Clock", 250),
        ("/tf", "tf2_msgs/msg/TFMessage", 251),
        ("/tf_static", "tf2_msgs/msg/TFMessage", 1),
        ("/tensegrity_sim/body_poses", "geometry_msgs/msg/PoseArray", 251),
        ("/tensegrity_sim/cable_states", "tensegrity_msgs/msg/CableStates", 251),
        ("/tensegrity_sim/actuator_states", "sensor_msgs/msg/JointState", 251),
        ("/tensegrity_sim/structure", "tensegrity_msgs/msg/Structure", 1),
        ("/tensegrity_sim/applied_commands", "tensegrity_msgs/msg/AppliedCommands", 0),
    ];
    for (topic, ty, n) in expected {
        assert_eq!(ours.get(topic), Some(&(ty.to_string(), n)), "{topic}: {ours:?}");
    }
    assert!(ours.contains_key("/diagnostics") && ours.contains_key("/tensegrity_sim/markers"), "{ours:?}");
    assert!(!ours.contains_key("/tensegrity_sim/contacts"), "a scene without grounds has no contacts topic");
    let Some(v) = rosbags_read(&dir) else { return };
    assert_eq!(rosbags_counts(&v), ours, "rosbags and our reader disagree");

    // contents: an independent run of the same simulator, step by step
    let model = tensegrity::scene::load(&scene_path("prism3.toml")).unwrap();
    let mut sim = Simulator::new(model.clone(), SimSettings::default()).unwrap();
    let cables = v["messages"]["/tensegrity_sim/cable_states"].as_array().unwrap();
    let poses = v["messages"]["/tensegrity_sim/body_poses"].as_array().unwrap();
    let clock = v["messages"]["/clock"].as_array().unwrap();
    for k in 0..=250 {
        if k > 0 {
            sim.step().unwrap();
            let t = msg::Time::from_seconds(sim.state().time);
            assert_eq!(
                (clock[k - 1]["sec"].as_i64(), clock[k - 1]["nanosec"].as_u64()),
                (Some(t.sec as i64), Some(t.nanosec as u64))
            );
        }
        let tension: Vec<f64> = sim.workspace().cables.iter().map(|c| c.tension).collect();
        assert_eq!(floats(&cables[k]["tension"]), tension, "tensions at step {k}");
        assert_eq!(floats(&cables[k]["rest_length"]), sim.state().rest_lengths, "rest lengths at step {k}");
        let expected = msg::PoseArray::from_state(sim.state(), "world");
        for (b, p) in expected.poses.iter().enumerate() {
            assert_eq!(
                floats(&poses[k]["position"][b]),
                vec![p.position.x, p.position.y, p.position.z],
                "step {k}"
            );
            let q = &p.orientation;
            assert_eq!(floats(&poses[k]["orientation"][b]), vec![q.x, q.y, q.z, q.w], "step {k}");
        }
    }
    assert_eq!(
        v["messages"]["/tensegrity_sim/structure"][0]["cable_names"],
        serde_json::json!(model.cable_names)
    );

    // the same bag replays bit for bit, and `bag info` lists it like `ros2 bag info`
    assert_replays_identically(&dir);
    let out = cli(&["bag", "info", dir.to_str().unwrap()]);
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(text.contains("Topic: /tensegrity_sim/cable_states") && text.contains("Count: 251"), "{text}");
    assert!(text.contains("deploy-dynamic of 'prism3'"), "{text}");
}

#[test]
fn a_run_from_the_static_equilibrium_is_recorded_as_such_and_replays_bit_for_bit() {
    let dir = deploy_recorded("from-equilibrium", &["--dynamic", "--from-equilibrium", "--duration", "0.05"]);
    assert_replays_identically(&dir);
}

#[test]
fn a_changed_scene_is_caught_at_its_first_differing_field() {
    let dir = deploy_recorded("changed", &["--dynamic", "--duration", "0.05"]);
    // one cable's EA changed (the ring's: the last `ea` of the file)
    let text = std::fs::read_to_string(scene_path("prism3.toml")).unwrap();
    let at = text.rfind("ea = 50000.0").unwrap();
    let changed = format!("{}ea = 50001.0{}", &text[..at], &text[at + "ea = 50000.0".len()..]);
    let scene = common::scratch("bags").join("prism3-ea.toml");
    std::fs::write(&scene, changed).unwrap();
    let out = cli(&["replay", dir.to_str().unwrap(), "--scene", scene.to_str().unwrap()]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "a changed scene must not replay as identical");
    // the prestress fixes the tensions; form finding gives the ring another rest length
    assert!(
        err.contains("first difference at step 0 on /tensegrity_sim/cable_states: rest_length[3]"),
        "the ring's rest length at the start differs first: {err}"
    );
    assert!(err.contains("differs by"), "{err}");
    // the library says the same, with the size of the difference
    let report =
        record::replay(&dir, Some((&std::fs::read_to_string(&scene).unwrap(), "changed")), None).unwrap();
    let d = report.difference.expect("a difference");
    assert_eq!((d.step, d.field.as_str()), (0, "rest_length[3]"));
    assert!(d.by.unwrap() > 0.0);
}

#[test]
fn a_quasi_static_bag_reads_back_and_replays_identically() {
    let dir = deploy_recorded("quasi", &["--quasi-static", "--steps", "12"]);
    let ours = our_counts(&dir);
    // the initial equilibrium and 12 load steps
    assert_eq!(ours["/tensegrity_sim/cable_states"].1, 13, "{ours:?}");
    assert_eq!(ours["/clock"].1, 13);
    assert_replays_identically(&dir);
    let Some(v) = rosbags_read(&dir) else { return };
    assert_eq!(rosbags_counts(&v), ours);
    // the ring shortens along the path (the schedule's ramp)
    let cables = v["messages"]["/tensegrity_sim/cable_states"].as_array().unwrap();
    let ring = |k: usize| floats(&cables[k]["rest_length"])[3];
    assert!(ring(12) < ring(0), "{} -> {}", ring(0), ring(12));
}

/// The bundled prism's node core (state every step, no pacing), started into a recorder of
/// `dir` with `options` (logged by step), and a command for its ring winch.
fn prism_core_recording(
    dir: &Path,
    options: &BagOptions,
) -> (NodeCore, record::BagRecorder, msg::ActuatorCommand) {
    let model = tensegrity::scene::load(&scene_path("prism3.toml")).unwrap();
    let params = NodeParams { real_time_factor: 0.0, state_publish_rate: 0.0, ..NodeParams::default() };
    let sim = Simulator::new(model.clone(), SimSettings::default()).unwrap();
    let run = record::run_info(record::KIND_NODE, &model, "prism3", sim.settings(), &params);
    let mut recorder =
        record::BagRecorder::create(dir, &model, &params, &run, record::LogTime::Step, options).unwrap();
    let mut core = NodeCore::with_simulator(sim, params);
    core.start(&mut recorder);
    let ring = msg::ActuatorCommand {
        name: vec!["ring_winch".into()],
        rest_length: vec![4.0],
        rate: vec![0.5],
        ..Default::default()
    };
    (core, recorder, ring)
}

/// Records `steps` steps of the bundled prism through the node core (ring commands at steps 20
/// and 60, a reset at 90) into `dir` with small chunks, the way the CLI and the node record.
fn record_through_the_core(dir: &Path, steps: u64, chunk_size: u64) -> u64 {
    let (mut core, mut recorder, ring) =
        prism_core_recording(dir, &BagOptions { chunk_size, ..BagOptions::default() });
    for k in 0..steps {
        let now = Duration::from_millis(k);
        match k {
            20 => core.offer_command(&ring),
            60 => core.offer_command(&msg::ActuatorCommand { rest_length: vec![4.3], ..ring.clone() }),
            90 => core.reset(&mut recorder),
            _ => {}
        }
        core.tick(now, &mut recorder);
        assert!(core.fault().is_none());
    }
    recorder.finish().unwrap().counts.iter().sum()
}

#[test]
fn a_bag_cut_short_is_read_up_to_its_last_complete_chunk_and_reindexed() {
    let dir = bag_dir("cut");
    let total = record_through_the_core(&dir, 400, 16 * 1024);
    let complete = BagReader::open(&dir).unwrap();
    assert!(complete.complete());
    let all: Vec<_> = complete.messages().collect::<Result<_, _>>().unwrap();
    assert_eq!(all.len() as u64, total);
    let report = record::replay(&dir, None, None).unwrap();
    assert_eq!(report.difference, None, "{report:?}");
    assert_eq!((report.command_batches, report.resets, report.cut_short.clone()), (2, 1, None));
    // every message compared but the diagnostics (wall-clock figures) and the applied commands
    // (which the replay applies)
    let uncompared = |messages: &[bag::RecordedMessage]| {
        messages
            .iter()
            .filter(|m| m.topic == "/diagnostics" || m.topic.ends_with("/applied_commands"))
            .count() as u64
    };
    assert_eq!(report.compared + uncompared(&all), total);

    // cut the file at 60 %: a prefix of the messages is readable, the rest is said to be lost
    let file = complete.path.clone();
    let bytes = std::fs::read(&file).unwrap();
    std::fs::write(&file, &bytes[..bytes.len() * 6 / 10]).unwrap();
    let cut = BagReader::open(&dir).unwrap();
    assert!(!cut.complete());
    let info = cut.info();
    let read: u64 = info.topics.iter().map(|(_, n)| n).sum();
    assert!(read > total / 4 && read < total, "read {read} of {total}");
    assert!(info.cut_short.as_deref().unwrap_or("").contains("cut short"), "{:?}", info.cut_short);
    assert!(info.run.is_some(), "the run record is before the first chunk");
    let prefix: Vec<_> = cut.messages().filter_map(Result::ok).collect();
    assert_eq!(prefix[..], all[..prefix.len()], "what is read is exactly the start of the bag");
    // replay compares up to the cut
    let report = record::replay(&dir, None, None).unwrap();
    assert_eq!(report.difference, None);
    assert!(report.cut_short.is_some() && report.compared + uncompared(&prefix) == read, "{report:?}");

    // reindex: a complete bag of the readable messages, which rosbags opens (it refuses the cut one)
    let out = cli(&["bag", "reindex", dir.to_str().unwrap()]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    assert!(BagReader::open(&dir).unwrap().complete());
    assert_eq!(our_counts(&dir).values().map(|(_, n)| n).sum::<u64>(), read);
    let kept = dir.join(format!("{}.cut", bag::mcap_file_name(&dir)));
    assert_eq!(
        std::fs::metadata(&kept).unwrap().len() as usize,
        bytes.len() * 6 / 10,
        "the original is kept"
    );
    // a complete bag is left as it is (and the kept original is not overwritten)
    let out = cli(&["bag", "reindex", dir.to_str().unwrap()]);
    assert!(String::from_utf8_lossy(&out.stdout).contains("already complete"), "{out:?}");
    assert_eq!(std::fs::metadata(&kept).unwrap().len() as usize, bytes.len() * 6 / 10);
    if let Some(v) = rosbags_read(&dir) {
        assert_eq!(rosbags_counts(&v).values().map(|(_, n)| n).sum::<u64>(), read);
    }
}

#[test]
fn applied_commands_and_resets_are_recorded_and_decode_in_rosbags() {
    let dir = bag_dir("applied");
    record_through_the_core(&dir, 120, 1 << 20);
    let reader = BagReader::open(&dir).unwrap();
    let applied = applied_commands(&reader);
    // the hold of every actuator at start-up is not a command; the two commands and the reset are
    assert_eq!(applied.len(), 3, "{applied:?}");
    assert_eq!(
        (applied[0].step, applied[0].name.clone(), applied[0].rest_length.clone()),
        (20, vec!["ring_winch".to_string()], vec![4.0])
    );
    assert_eq!((applied[1].step, applied[1].rest_length[0], applied[1].rate[0]), (60, 4.3, 0.5));
    assert!(applied[2].reset && applied[2].step == 90 && applied[2].name.is_empty());
    let Some(v) = rosbags_read(&dir) else { return };
    let seen = v["messages"]["/tensegrity_sim/applied_commands"].as_array().unwrap();
    assert_eq!(seen.len(), 3);
    assert_eq!(seen[0]["step"], 20);
    assert_eq!(floats(&seen[1]["rest_length"]), vec![4.3]);
    assert_eq!(seen[2]["reset"], true);
}

#[test]
fn a_killed_recording_keeps_what_it_flushed() {
    let dir = bag_dir("killed");
    let tower = scene_path("tower.toml");
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_tensegrity"));
    tensegrity::testing::die_with_parent(&mut cmd);
    let mut child = cmd
        .args([
            "deploy",
            tower.to_str().unwrap(),
            "--dynamic",
            "--duration",
            "1000",
            "--record",
            dir.to_str().unwrap(),
        ])
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    // chunks close at least every second: wait for a few
    std::thread::sleep(Duration::from_millis(3500));
    child.kill().unwrap(); // SIGKILL
    child.wait().unwrap();
    let reader = BagReader::open(&dir).unwrap();
    assert!(!reader.complete(), "a killed writer cannot have closed the file");
    let info = reader.info();
    let read = info.topics.iter().find(|(t, _)| t.name == "/clock").map_or(0, |(_, n)| *n);
    assert!(read > 0, "at least the first second's chunks are in the file: {info:?}");
    assert!(dir.join("metadata.yaml").exists());
    let out = cli(&["bag", "reindex", dir.to_str().unwrap()]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let report = record::replay(&dir, None, None).unwrap();
    assert_eq!(report.difference, None, "{report:?}");
    if let Some(v) = rosbags_read(&dir) {
        assert_eq!(rosbags_counts(&v)["/clock"].1, read);
    }
    // tens of MB: not left behind
    let _ = std::fs::remove_dir_all(&dir);
}

/// A writer that cannot keep up (a queue of one job, a step every 20 us or so) drops whole
/// states: the failures are counted, every state topic keeps the same steps, and the structure,
/// the static transforms and the applied commands are all there; replay reports the first
/// missing state as a difference.
#[test]
fn a_full_writer_queue_drops_whole_states_never_commands_or_the_structure() {
    let dir = bag_dir("full-queue");
    let (mut core, mut recorder, ring) =
        prism_core_recording(&dir, &BagOptions { queue: 1, ..BagOptions::default() });
    let params = core.params().clone();
    let steps = 300;
    for k in 0..steps {
        if k == 100 || k == 200 {
            core.offer_command(&ring);
        }
        core.tick(Duration::from_millis(k), &mut recorder);
        // slower than the core can step; a batch (`record::BATCH_RECORDS` records, two a step)
        // fills much faster than the writer takes a job (`DRAIN_PERIOD`)
        std::thread::sleep(Duration::from_micros(20));
    }
    let failures: u64 = core.stats().publish_failures.iter().sum();
    recorder.finish().unwrap();
    assert!(failures > 0, "a queue of one batch cannot hold a step every 20 us");

    let counts = our_counts(&dir);
    let count = |short: &str| {
        counts
            .get(&tensegrity::io::topics::topic_name(short, &params.private_namespace()))
            .map_or(0, |(_, n)| *n)
    };
    assert_eq!(count("~/structure"), 1);
    assert_eq!(count("/tf_static"), 1);
    assert_eq!(count("~/applied_commands"), 2, "{counts:?}");
    let states = count("~/body_poses");
    assert!(states > 0 && states < steps, "{states} of {steps} states kept");
    for short in ["/tf", "~/cable_states", "~/actuator_states"] {
        assert_eq!(count(short), states, "{short}: a state is kept or dropped whole ({counts:?})");
    }
    // replay skips the states the bag lacks, counts them, and compares everything else
    let report = record::replay(&dir, None, None).unwrap();
    assert_eq!(report.difference, None, "{report:?}");
    assert_eq!((report.command_batches, report.cut_short.clone()), (2, None));
    let total: u64 = counts.values().map(|(_, n)| n).sum();
    let diagnostics = count("/diagnostics");
    assert_eq!(
        report.compared,
        total - diagnostics - 2,
        "every recorded message but the diagnostics and commands"
    );
    // what it skipped is what the bag lacks of the steps it re-ran (up to the last recorded one)
    let per_step = ["/tf", "~/body_poses", "~/cable_states", "~/actuator_states", "/clock", "~/markers"];
    let lacking: u64 = per_step.iter().map(|short| steps - count(short)).sum();
    assert!(report.missing > 0 && report.missing <= lacking, "{} skipped, {lacking} lacking", report.missing);

    // skipping what the bag lacks hides no difference: a changed scene is still caught at a field
    let text = std::fs::read_to_string(scene_path("prism3.toml")).unwrap();
    let at = text.rfind("ea = 50000.0").unwrap();
    let changed = format!("{}ea = 50001.0{}", &text[..at], &text[at + "ea = 50000.0".len()..]);
    let report = record::replay(&dir, Some((&changed, "changed")), None).unwrap();
    let d = report.difference.expect("a changed EA differs");
    assert!(d.field.starts_with("rest_length[3]") || d.by.is_some(), "{d:?}");
}

/// Nice values of this process's threads named `name` (Linux `/proc`: field 19 of a task's
/// `stat`).
fn nice_values_of_threads(name: &str) -> Vec<i64> {
    let mut out = Vec::new();
    for task in std::fs::read_dir("/proc/self/task").unwrap().flatten() {
        let comm = std::fs::read_to_string(task.path().join("comm")).unwrap_or_default();
        let stat = std::fs::read_to_string(task.path().join("stat")).unwrap_or_default();
        if comm.trim_end() != name {
            continue;
        }
        // the fields after the command name, which may itself hold spaces, start at field 3
        let after = stat.rsplit(')').next().unwrap_or("");
        if let Some(nice) = after.split_whitespace().nth(19 - 3).and_then(|p| p.parse::<i64>().ok()) {
            out.push(nice);
        }
    }
    out
}

/// A node's recorder writes from a background thread (nice 10) so that on a two-core machine the
/// writer never delays the real-time step; offline recorders keep the default priority. The only
/// background writers of this test binary are this test's.
#[test]
fn a_nodes_bag_writer_runs_in_the_background_and_an_offline_one_does_not() {
    let dir = bag_dir("background-writer");
    let (core, _, _) = prism_core_recording(&dir.join("setup"), &BagOptions::default());
    let background =
        || nice_values_of_threads("bag writer").iter().filter(|&&n| n == bag::BACKGROUND_NICE as i64).count();
    let offline = BagOptions::default();
    assert!(!offline.background);
    let node = record::BagRecorder::for_node(&core, &dir.join("node")).unwrap();
    // the thread lowers its own priority first thing: give it the moment it needs
    let deadline = std::time::Instant::now() + Duration::from_secs(5);
    while background() == 0 && std::time::Instant::now() < deadline {
        std::thread::sleep(Duration::from_millis(1));
    }
    assert_eq!(background(), 1, "the node's bag writer is not at nice {}", bag::BACKGROUND_NICE);
    node.finish().unwrap();
    assert_eq!(background(), 0);
    let _ = std::fs::remove_dir_all(&dir);
}

/// Damaged and misnamed bags a careless user hands the bag commands: a file of the MCAP magic and
/// random bytes (a length field of about 1e19 bytes, which once panicked the streaming reader on a
/// capacity overflow), and `bag reindex` given the `.mcap` file instead of its directory (which
/// once renamed the file and left a directory in its place). Each is an error or a report, never
/// a panic, and the file is left as it was.
#[test]
fn bag_commands_refuse_damaged_and_misnamed_bags_without_panicking() {
    let dir = bag_dir("damaged");
    std::fs::create_dir_all(&dir).unwrap();
    let file = dir.join("damaged_0.mcap");
    let mut bytes = b"\x89MCAP0\r\n".to_vec();
    let mut x = 0x2545_F491_4F6C_DD1Du64;
    bytes.extend((0..5000).map(|_| {
        x ^= x << 13;
        x ^= x >> 7;
        x ^= x << 17;
        x as u8
    }));
    std::fs::write(&file, &bytes).unwrap();
    let (d, f) = (dir.to_str().unwrap(), file.to_str().unwrap());
    for args in [vec!["bag", "info", d], vec!["bag", "info", f], vec!["replay", d], vec!["bag", "reindex", f]]
    {
        let out = cli(&args);
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(
            !stderr.contains("panicked") && out.status.code().is_some_and(|c| c <= 1),
            "{args:?}: {stderr}"
        );
    }
    let info = cli(&["bag", "info", d]);
    assert!(String::from_utf8_lossy(&info.stdout).contains("damaged record"), "{info:?}");
    let reindex = cli(&["bag", "reindex", f]);
    assert!(String::from_utf8_lossy(&reindex.stderr).contains("not a bag directory"), "{reindex:?}");
    assert_eq!(std::fs::read(&file).unwrap(), bytes, "the file is left as it was");
    assert_eq!(std::fs::read_dir(&dir).unwrap().count(), 1, "nothing written beside it");
}

#[test]
fn a_run_with_pulley_friction_records_its_pulleys_and_replays_bit_for_bit() {
    // the bundled prism with friction at its ring's pulleys
    let scene = common::scratch("friction").join("prism3_friction.toml");
    let text = std::fs::read_to_string(scene_path("prism3.toml")).unwrap();
    std::fs::write(&scene, format!("pulley_friction = 0.3\n{text}")).unwrap();
    let dir = bag_dir("friction");
    let out = cli(&[
        "deploy",
        scene.to_str().unwrap(),
        "--dynamic",
        "--duration",
        "0.6",
        "--record",
        dir.to_str().unwrap(),
    ]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    assert_replays_identically(&dir);
    let Some(v) = rosbags_read(&dir) else { return };
    let cables = v["messages"]["/tensegrity_sim/cable_states"].as_array().unwrap();
    let last = cables.last().unwrap();
    // the ring's two pulleys: per pulley a stick flag, a slip speed and a tension ratio
    assert_eq!(last["pulley_sticks"].as_array().unwrap().len(), 2, "{last}");
    let ratios = floats(&last["pulley_tension_ratio"]);
    assert!(ratios.iter().any(|r| (r - 1.0).abs() > 1e-3), "friction holds different tensions: {ratios:?}");
    let ever_slipped = cables.iter().any(|m| floats(&m["pulley_slip_speed"]).iter().any(|s| s.abs() > 0.0));
    assert!(ever_slipped, "the winch pulls rope over the pulleys at some step");
}

/// Records `deploy --dynamic` of a 10 kg load hanging on a winch's rope, with noisy sensors
/// seeded `seed`, into a fresh bag `name`; gives the bag and every `(cable_states,
/// ground_truth/cable_states)` tension of the rope.
fn sensed_hoist(name: &str, seed: u64) -> (PathBuf, Vec<(f64, f64)>) {
    let gravity = "gravity = [0.0, 0.0, -9.81]\n";
    let text = common::hanging_load().replacen(gravity, &format!("{gravity}physics_dt = 1e-5\n"), 1);
    let scene = common::scratch("sensors").join(format!("{name}.toml"));
    let sensors = format!(
        "\n[sensors]\nseed = {seed}\n[sensors.tension]\nsigma = 0.5\n\
         [sensors.rest_length]\nresolution = 1e-4\ndelay_s = 0.003\n[sensors.position]\nsigma = 1e-4\nrate = 1000.0\ndropout = 0.05\n"
    );
    std::fs::write(&scene, text + &sensors).unwrap();
    let dir = record_from_equilibrium(&scene, name, "0.02");
    let reader = BagReader::open(&dir).unwrap();
    let tensions = |topic: &str| -> Vec<f64> {
        reader
            .messages()
            .map(Result::unwrap)
            .filter(|m| m.topic == topic)
            .map(|m| m.decode::<msg::CableStates>().unwrap().tension[0])
            .collect()
    };
    let measured = tensions("/tensegrity_sim/cable_states");
    let truth = tensions("/tensegrity_sim/ground_truth/cable_states");
    assert_eq!(measured.len(), truth.len());
    (dir, measured.into_iter().zip(truth).collect())
}

#[test]
fn a_run_with_sensors_records_measured_and_true_states_and_replays_bit_for_bit() {
    let (dir, tensions) = sensed_hoist("sensors_a", 5);
    assert_eq!(tensions.len(), 2001, "a state per step and at the start");
    // the cable states carry the noisy tension, the ground truth the exact one
    let errors: Vec<f64> = tensions.iter().map(|(m, t)| m - t).collect();
    let rms = (errors.iter().map(|e| e * e).sum::<f64>() / errors.len() as f64).sqrt();
    assert!(rms > 0.3 && rms < 0.7, "noise of 0.5 N, rms {rms}");
    assert!(tensions.iter().all(|(_, t)| (t - 98.1).abs() < 1e-3), "at rest the rope carries the load");
    assert_replays_identically(&dir);
    // the same seed gives the same bag's numbers, another seed other ones
    let (_, again) = sensed_hoist("sensors_b", 5);
    assert_eq!(
        tensions.iter().map(|t| t.0.to_bits()).collect::<Vec<_>>(),
        again.iter().map(|t| t.0.to_bits()).collect::<Vec<_>>()
    );
    let (_, other) = sensed_hoist("sensors_c", 6);
    assert!(tensions.iter().zip(&other).filter(|(a, b)| a.0 != b.0).count() > 1990);
    assert_eq!(
        tensions.iter().map(|t| t.1).collect::<Vec<_>>(),
        other.iter().map(|t| t.1).collect::<Vec<_>>()
    );
    // ~/sensor_readings: every channel's values as the state topics carry them, and a lost flag
    // per value on exactly the positions that held their last value after a dropout
    let reader = BagReader::open(&dir).unwrap();
    let readings: Vec<msg::SensorReadings> = (reader.messages().map(Result::unwrap))
        .filter(|m| m.topic == "/tensegrity_sim/sensor_readings")
        .map(|m| m.decode().unwrap())
        .collect();
    assert_eq!(readings.len(), 2001);
    assert_eq!(readings[0].channel, ["tension", "rest_length", "position"]);
    assert_eq!(readings[0].count, [1, 1, 6]);
    for (r, (measured, _)) in readings.iter().zip(&tensions) {
        assert_eq!(r.value[0].to_bits(), measured.to_bits(), "the value ~/cable_states carries");
        assert_eq!(r.lost.len(), r.value.len());
    }
    let mut lost = 0;
    for w in readings.windows(2) {
        for i in 2..8 {
            if w[1].lost[i] {
                lost += 1;
                assert_eq!(w[1].value[i], w[0].value[i], "a lost position holds its last value");
            }
        }
    }
    // 1 kHz at 10 us steps: 20 updates of 6 values (the fixed ceiling's too), 5 % lost
    assert!(lost > 0, "some positions were lost");
    if let Some(v) = rosbags_read(&dir) {
        let read = v["messages"]["/tensegrity_sim/sensor_readings"].as_array().unwrap();
        assert_eq!(read.len(), 2001);
        // the independent reader sees the same values and flags
        for (m, r) in read.iter().zip(&readings) {
            assert_eq!(floats(&m["value"]), r.value);
            assert_eq!(
                m["lost"].as_array().unwrap().iter().map(|b| b.as_bool().unwrap()).collect::<Vec<_>>(),
                r.lost
            );
        }
        let truth = v["messages"]["/tensegrity_sim/ground_truth/cable_states"].as_array().unwrap();
        assert_eq!(truth.len(), 2001);
        let poses = v["messages"]["/tensegrity_sim/ground_truth/body_poses"].as_array().unwrap();
        assert_eq!(poses.len(), 2001);
    }
}

#[test]
fn a_winch_driven_run_replays_bit_for_bit() {
    let scene = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("config/examples/hoist.toml");
    assert_replays_identically(&record_from_equilibrium(&scene, "winch", "0.03"));
}

/// A node core on `model` (state every step, no pacing; from the static equilibrium when
/// `from_equilibrium`), started into a recorder of the fresh bag directory `name`.
fn core_recording(
    model: &tensegrity::model::Model,
    name: &str,
    from_equilibrium: bool,
) -> (NodeCore, record::BagRecorder, PathBuf) {
    let dir = bag_dir(name);
    let params = NodeParams {
        real_time_factor: 0.0,
        state_publish_rate: 0.0,
        start_from_equilibrium: from_equilibrium,
        ..NodeParams::default()
    };
    let sim = Simulator::start(model.clone(), SimSettings::default(), from_equilibrium).unwrap();
    let run = record::run_info(record::KIND_NODE, model, name, sim.settings(), &params);
    let mut recorder = record::BagRecorder::create(
        &dir,
        model,
        &params,
        &run,
        record::LogTime::Step,
        &BagOptions::default(),
    )
    .unwrap();
    let mut core = NodeCore::with_simulator(sim, params);
    core.start(&mut recorder);
    (core, recorder, dir)
}

#[test]
fn a_node_randomized_per_reset_records_each_episode_and_replays_bit_for_bit() {
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let text = std::fs::read_to_string(root.join("config/examples/randomized.toml")).unwrap();
    let text = text.replace("seed = 11\n", "seed = 11\nper = \"reset\"\n");
    let model = tensegrity::scene::from_toml(&text, "randomized.toml").unwrap();
    let (mut core, mut recorder, dir) = core_recording(&model, "randomized", false);
    for k in 0..90 {
        if k % 30 == 29 {
            core.reset(&mut recorder);
        }
        core.tick(Duration::from_millis(k), &mut recorder);
        assert!(core.fault().is_none());
    }
    recorder.finish().unwrap();
    // a structure per episode, each with its own draws
    let reader = BagReader::open(&dir).unwrap();
    let structures: Vec<msg::Structure> = reader
        .messages()
        .map(Result::unwrap)
        .filter(|m| m.topic == "/tensegrity_sim/structure")
        .map(|m| m.decode().unwrap())
        .collect();
    assert_eq!(structures.iter().map(|s| s.randomize_episode).collect::<Vec<_>>(), [0, 1, 2, 3]);
    assert!(structures.windows(2).all(|w| w[0].randomized_value != w[1].randomized_value));
    assert_replays_identically(&dir);
    if let Some(v) = rosbags_read(&dir) {
        let read = v["messages"]["/tensegrity_sim/structure"].as_array().unwrap();
        assert_eq!(read.len(), 4);
        assert_eq!(floats(&read[2]["randomized_value"]), structures[2].randomized_value);
    }
}

#[test]
fn tension_commands_are_recorded_and_replay_bit_for_bit() {
    // the hoist through the node core: a tension command (its own message), one as a JointState
    // effort, and a position command after them
    let scene = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("config/examples/hoist.toml");
    let model = tensegrity::scene::load(&scene).unwrap();
    let (mut core, mut recorder, dir) = core_recording(&model, "tension", true);
    let name = vec!["hoist".to_string()];
    for k in 0..300 {
        match k {
            10 => core.offer_tension_command(&msg::TensionCommand {
                name: name.clone(),
                tension: vec![120.0],
                ..Default::default()
            }),
            100 => core.offer_joint_command(&msg::JointState {
                name: name.clone(),
                effort: vec![90.0],
                ..Default::default()
            }),
            200 => core.offer_command(&msg::ActuatorCommand {
                name: name.clone(),
                rest_length: vec![0.99],
                ..Default::default()
            }),
            _ => {}
        }
        core.tick(Duration::from_millis(k), &mut recorder);
        assert!(core.fault().is_none());
    }
    assert_eq!(core.stats().commands_rejected, 0);
    recorder.finish().unwrap();
    let applied = applied_commands(&BagReader::open(&dir).unwrap());
    let tensions: Vec<(u64, f64)> = applied.iter().map(|a| (a.step, a.tension[0])).collect();
    assert_eq!(&tensions[..2], [(10, 120.0), (100, 90.0)]);
    assert!(tensions[2].1.is_nan() && applied[2].rest_length == [0.99], "{:?}", applied[2]);
    assert!(applied[0].rest_length[0].is_nan() && applied[0].rate[0].is_nan());
    assert_replays_identically(&dir);
    if let Some(v) = rosbags_read(&dir) {
        let seen = v["messages"]["/tensegrity_sim/applied_commands"].as_array().unwrap();
        assert_eq!(floats(&seen[0]["tension"]), vec![120.0]);
    }
}

#[test]
fn applied_commands_from_bags_written_before_tension_commands_still_decode() {
    // the layout those bags have: today's without the `tension` array at the end (an empty
    // sequence is its 4-byte length, after the 8-byte aligned rates)
    let today = msg::AppliedCommands {
        step: 7,
        name: vec!["ring_winch".into()],
        rest_length: vec![4.0],
        rate: vec![f64::NAN],
        ..Default::default()
    };
    let mut data = vec![0, 1, 0, 0];
    data.extend(cdr_encoding::to_vec::<_, byteorder::LittleEndian>(&today).unwrap());
    data.truncate(data.len() - 4);
    let recorded = bag::RecordedMessage {
        topic: "/tensegrity_sim/applied_commands".into(),
        type_name: "tensegrity_msgs/msg/AppliedCommands".into(),
        qos_profiles: String::new(),
        sequence: 7,
        log_time: 0,
        data,
    };
    let a = record::applied_commands(&recorded).unwrap();
    assert_eq!((a.step, a.rest_length.clone(), a.tension.clone()), (7, vec![4.0], vec![]));
    let model = tensegrity::scene::load(&scene_path("prism3.toml")).unwrap();
    let commands = a.commands(&model).unwrap();
    assert_eq!(commands[0].1, tensegrity::control::ActuatorCommand::target(4.0));
}

#[test]
fn an_imu_is_recorded_measured_and_true_and_replays_bit_for_bit() {
    // config/examples/imu.toml: a bar swinging on a pin, its gyro and accelerometer at 200 Hz
    let scene = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("config/examples/imu.toml");
    let dir = bag_dir("imu");
    let (scene, bag) = (scene.to_str().unwrap(), dir.to_str().unwrap());
    let out = cli(&["deploy", scene, "--dynamic", "--duration", "0.5", "--record", bag]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let reader = BagReader::open(&dir).unwrap();
    let imu = |topic: &str| -> Vec<msg::ImuStates> {
        reader
            .messages()
            .map(Result::unwrap)
            .filter(|m| m.topic == topic)
            .map(|m| m.decode().unwrap())
            .collect()
    };
    let (measured, truth) = (imu("/tensegrity_sim/imu"), imu("/tensegrity_sim/ground_truth/imu"));
    assert_eq!((measured.len(), truth.len()), (501, 501), "a message per step and at the start");
    assert_eq!(measured[0].name, ["bar"]);
    // near the bottom at 0.48 s: 5.42 rad/s and 2.5 g towards the pin, measured within the noise
    let (m, t) = (&measured[480], &truth[480]);
    let rate = t.angular_velocity[0].x.hypot(t.angular_velocity[0].y);
    assert!((rate - (3.0f64 * 9.81).sqrt()).abs() < 0.01, "{rate} rad/s");
    assert!((t.specific_force[0].z + 2.5 * 9.81).abs() < 0.1, "{:?}", t.specific_force[0]);
    assert!((m.specific_force[0].z - t.specific_force[0].z).abs() < 1.0, "{:?}", m.specific_force[0]);
    assert!(
        measured.iter().zip(&truth).filter(|(m, t)| m.angular_velocity != t.angular_velocity).count() > 490
    );
    assert_replays_identically(&dir);
    if let Some(v) = rosbags_read(&dir) {
        let read = v["messages"]["/tensegrity_sim/ground_truth/imu"].as_array().unwrap();
        assert_eq!(read.len(), 501);
        assert_eq!(read[480]["specific_force"][0]["z"].as_f64(), Some(t.specific_force[0].z));
    }
}
