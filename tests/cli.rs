//! Invariant: the `tensegrity` command line does what the README says on the bundled scenes, the
//! bundled scenes are exactly what the generators produce, and `statics` on `prism3` prints the
//! closed-form self-stress (ring/side tension ratio `r / l_side`) to 1e-6.

use std::path::PathBuf;
use std::process::Command;

mod common;

use tensegrity::scene::generate;

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn tensegrity(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_tensegrity")).args(args).current_dir(root()).output().expect("runs")
}

#[test]
fn bundled_scenes_match_their_generators() {
    let cases = [
        (
            "prism3.toml",
            generate::prism(&generate::PrismParams { cluster_top_ring: true, ..Default::default() }),
        ),
        (
            "prism3_nodal.toml",
            generate::prism(&generate::PrismParams {
                cluster_top_ring: true,
                nodal_strut_ea: Some(1e7),
                ..Default::default()
            }),
        ),
        ("tbar.toml", generate::tbar(&Default::default())),
        (
            "tbar_nodal.toml",
            generate::tbar(&generate::TbarParams {
                nodal_strut_ea: Some(1e7),
                nodal_mass_matrix: tensegrity::scene::MassMatrixSpec::Consistent,
                ..Default::default()
            }),
        ),
        ("tower.toml", generate::tower(&Default::default())),
        ("atwood.toml", generate::atwood(&Default::default())),
        ("sixbar.toml", generate::sixbar(&Default::default())),
        (
            "sixbar_rover.toml",
            generate::sixbar(&generate::SixbarParams { all_winches: true, ..Default::default() }),
        ),
    ];
    for (file, spec) in cases {
        let text = std::fs::read_to_string(root().join("config/scenes").join(file)).unwrap();
        let bundled = tensegrity::scene::parse(&text, file).unwrap();
        assert_eq!(
            bundled, spec,
            "{file} differs from its generator: regenerate it with `tensegrity generate`"
        );
    }
}

#[test]
fn statics_on_prism3_prints_the_closed_form_self_stress() {
    let out = tensegrity(&["statics", "config/scenes/prism3.toml", "--json"]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert!(v["stable"].as_bool().unwrap());
    let cable =
        |name: &str| v["cables"].as_array().unwrap().iter().find(|c| c["name"] == name).unwrap().clone();
    let (side, ring) = (cable("side0"), cable("ring"));
    let p = generate::PrismParams::default();
    let expected = p.radius / side["length"].as_f64().unwrap();
    let ratio = ring["tension"].as_f64().unwrap() / side["tension"].as_f64().unwrap();
    assert!((ratio - expected).abs() <= 1e-6 * expected, "ratio {ratio} vs {expected}");
    assert!((side["tension"].as_f64().unwrap() - p.side_prestress).abs() <= 1e-6 * p.side_prestress);
    assert_eq!(ring["segment_lengths"].as_array().unwrap().len(), 3);
    assert_eq!(ring["pulley_slip"].as_array().unwrap().len(), 2);
}

#[test]
fn check_prints_counts() {
    let out = tensegrity(&["check", "config/scenes/tower.toml"]);
    assert!(out.status.success());
    let text = String::from_utf8(out.stdout).unwrap();
    for line in [
        "bodies: 9 (0 node, 9 bar, 0 rigid, 0 fixed)",
        "coordinates: 45",
        "constraints: 27",
        "cables: 12 (3 sliding)",
        "pulleys: 6",
    ] {
        assert!(text.contains(line), "missing '{line}' in:\n{text}");
    }
}

#[test]
fn deploy_writes_one_row_per_step() {
    let dir = std::env::temp_dir().join(format!("tensegrity-cli-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let csv = dir.join("tbar.csv");
    let out = tensegrity(&[
        "deploy",
        "config/scenes/tbar.toml",
        "--quasi-static",
        "--steps",
        "8",
        "--out",
        csv.to_str().unwrap(),
    ]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let text = std::fs::read_to_string(&csv).unwrap();
    let lines: Vec<&str> = text.lines().collect();
    assert_eq!(lines.len(), 1 + 9);
    let header: Vec<&str> = lines[0].split(',').collect();
    assert!(
        header.contains(&"upper_tension_N")
            && header.contains(&"lower_left_rest_length_m")
            && header.contains(&"mast.b_y_m")
            && header.contains(&"newton_iterations"),
        "one naming scheme, <name>_<quantity>_<unit>, as in the dynamic CSV: {header:?}"
    );
    assert!(lines[1..].iter().all(|l| l.split(',').count() == header.len()));
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn malformed_scene_fails_with_file_line_and_field() {
    let dir = std::env::temp_dir().join(format!("tensegrity-cli-bad-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let bad = dir.join("bad.toml");
    let text = std::fs::read_to_string(root().join("config/scenes/atwood.toml")).unwrap().replacen(
        "mass = 2.0",
        "mass = -2.0",
        1,
    );
    std::fs::write(&bad, text).unwrap();
    let out = tensegrity(&["check", bad.to_str().unwrap()]);
    assert!(!out.status.success());
    let err = String::from_utf8(out.stderr).unwrap();
    assert!(err.contains("bad.toml:") && err.contains("bodies[1].mass: must be positive, got -2"), "{err}");
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn out_of_range_steps_and_durations_are_refused_in_the_numbers_a_person_writes() {
    let deploy = |flag: &str, value: &str| {
        let out =
            tensegrity(&["deploy", "config/scenes/prism3.toml", "--dynamic", flag, value, "--out", "-"]);
        assert!(!out.status.success(), "{flag} {value} accepted");
        assert!(out.stdout.is_empty());
        String::from_utf8(out.stderr).unwrap()
    };
    // negative numbers reach the check (no clap tip about `-- -0.001`), and the step range is
    // the one of scenes and the node
    for (flag, value, says) in [
        (
            "--dt",
            "-0.001",
            "--dt must be in [1e-6, 0.1] s (the physics step range of scenes and the node), got -0.001",
        ),
        ("--dt", "1", "--dt must be in [1e-6, 0.1] s"),
        ("--dt", "0", "got 0"),
        ("--duration", "-1", "--duration must be positive, got -1"),
        ("--rho-inf", "-0.5", "--rho-inf must be in [0, 1], got -0.5"),
        ("--tol", "-1e-6", "--tol must be positive"),
        ("--newton-tol", "0", "--newton-tol must be in [1e-12, 0.001] (relative to the forces), got 0"),
        ("--newton-tol", "0.5", "--newton-tol must be in [1e-12, 0.001]"),
        ("--newton-tol", "-1e-6", "--newton-tol must be in [1e-12, 0.001]"),
        ("--newton-tol", "nan", "--newton-tol must be in [1e-12, 0.001]"),
        ("--newton-tol", "inf", "--newton-tol must be in [1e-12, 0.001]"),
    ] {
        let err = deploy(flag, value);
        assert!(err.contains(says) && !err.contains("tip:"), "{flag} {value}: {err}");
    }
    // the equilibrium start is a dynamic run's option (a quasi-static path starts there anyway)
    let out = tensegrity(&[
        "deploy",
        "config/scenes/prism3.toml",
        "--quasi-static",
        "--from-equilibrium",
        "--out",
        "-",
    ]);
    assert!(!out.status.success() && out.stdout.is_empty());
    assert!(String::from_utf8_lossy(&out.stderr).contains("cannot be used with '--from-equilibrium'"));
}

#[test]
fn generators_refuse_arguments_that_make_invalid_scenes() {
    for (args, says) in [
        (vec!["generate", "prism", "--prestress=-5"], "cables[0].prestress: a cable can only pull"),
        (vec!["generate", "prism", "--prestress", "-5"], "cables[0].prestress: a cable can only pull"),
        (vec!["generate", "atwood", "--m1=0"], "bodies[1].mass: must be positive, got 0"),
        (vec!["generate", "atwood", "--m1", "-1"], "bodies[1].mass: must be positive, got -1"),
        // a clustered ring through 1000 pulleys is longer than a route may be (it used to panic)
        (vec!["generate", "prism", "--n", "1000", "--cluster"], "a route has at most 1000 points, got 1001"),
    ] {
        let out = tensegrity(&args);
        assert_eq!(out.status.code(), Some(1), "{args:?}");
        assert!(out.stdout.is_empty(), "{args:?} wrote a scene");
        let err = String::from_utf8(out.stderr).unwrap();
        assert!(err.contains("cannot generate") && err.contains(says), "{args:?}: {err}");
    }
    let ok = tensegrity(&["generate", "atwood", "--m1", "3"]);
    assert!(ok.status.success());
}

#[test]
fn modes_lists_frequencies_and_the_sliding_of_the_clustered_ring() {
    let out = tensegrity(&["modes", "config/scenes/prism3.toml", "--count", "3"]);
    assert!(out.status.success());
    let text = String::from_utf8(out.stdout).unwrap();
    assert!(text.starts_with("prism3: 6 modes at the equilibrium (stable); 0 zero-frequency"), "{text}");
    assert!(text.contains("1.1603") && text.contains("ring 0.000 (slides: segments"), "{text}");
    let json = tensegrity(&["modes", "config/scenes/prism3.toml", "--json"]);
    let modes: serde_json::Value = serde_json::from_slice(&json.stdout).unwrap();
    assert_eq!(modes.as_array().unwrap().len(), 6);
    assert!(modes[0]["frequency_hz"].as_f64().unwrap() > 1.0);
}

#[test]
fn deploy_writes_a_row_for_t_zero_and_can_write_to_standard_output() {
    let out =
        tensegrity(&["deploy", "config/scenes/prism3.toml", "--dynamic", "--duration", "0.01", "--out", "-"]);
    assert!(out.status.success());
    let csv = String::from_utf8(out.stdout).unwrap();
    let rows: Vec<&str> = csv.lines().collect();
    assert!(rows[0].starts_with("time_s,"));
    assert!(rows[1].starts_with("0.000000000,"), "the first row is t = 0: {}", rows[1]);
    assert_eq!(rows.len(), 1 + 1 + 10, "header, t = 0 and one row per step");
    assert!(
        String::from_utf8_lossy(&out.stderr).contains("10 steps of 0.001 s"),
        "the summary goes to stderr"
    );
}

#[test]
fn check_of_a_999_strut_clustered_prism_finds_its_form() {
    // form finding on 4995 coordinates and 2994 unknowns takes the sparse path (a dense SVD of
    // that size took minutes); its cost is tested in tests/formfind.rs
    let dir = common::scratch("check999");
    let scene = dir.join("prism999.toml");
    let out = tensegrity(&["generate", "prism", "--n", "999", "--cluster", "--out", scene.to_str().unwrap()]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let out = tensegrity(&["check", scene.to_str().unwrap()]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let text = String::from_utf8(out.stdout).unwrap();
    assert!(text.contains("valid scene 'prism999'") && text.contains("pulleys: 998"), "{text}");
}

#[test]
fn output_into_a_closed_pipe_ends_quietly() {
    // `tensegrity ... | head -1`: the reader leaves early; no panic, no backtrace
    use std::io::Read;
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_tensegrity"));
    tensegrity::testing::die_with_parent(&mut cmd);
    let mut child = cmd
        .args(["deploy", "config/scenes/prism3.toml", "--dynamic", "--out", "-"])
        .current_dir(root())
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .expect("runs");
    let mut first = [0u8; 16];
    child.stdout.take().expect("piped").read_exact(&mut first).expect("some output");
    // the read end is dropped here, closing the pipe
    let out = child.wait_with_output().expect("exits");
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!err.contains("panicked"), "{err}");
    assert!(out.status.code().is_some_and(|c| c == 0), "status {:?}: {err}", out.status);
}

#[test]
fn text_statics_lists_segments_and_slips_and_never_a_negative_zero() {
    let out = tensegrity(&["statics", "config/scenes/tbar.toml"]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let text = String::from_utf8(out.stdout).unwrap();
    // the upper cable runs over the mast top: two segments of 1.166190 m, one pulley, no slip yet
    assert!(text.contains("sliding cable   segment      length m       slip m"), "{text}");
    assert!(text.contains("upper                 1     1.166190     0.000000"), "{text}");
    assert!(text.contains("                      2     1.166190            -"), "{text}");
    // mast.a sits at z = -1e-17 or so: printed as 0.000000
    assert!(!text.contains("-0.000000"), "{text}");
    let csv =
        tensegrity(&["deploy", "config/scenes/prism3.toml", "--dynamic", "--duration", "0.01", "--out", "-"]);
    assert!(csv.status.success());
    let csv = String::from_utf8(csv.stdout).unwrap();
    assert!(
        !csv.contains(",-0.000000000000,") && !csv.contains(",-0.000000000,"),
        "negative zeros in the CSV"
    );
}

#[test]
fn the_readme_names_the_command_that_writes_each_bundled_scene() {
    // rows "| `prism3.toml` | `tensegrity generate prism --cluster` | ..." of the table in docs/cli.md
    let readme = common::user_docs();
    let mut checked = 0;
    for line in readme.lines().filter(|l| l.starts_with("| `") && l.contains("` | `tensegrity generate ")) {
        let cells: Vec<&str> = line.split('|').map(|c| c.trim().trim_matches('`')).collect();
        let (file, command) = (cells[1], cells[2]);
        let args: Vec<&str> = command.split_whitespace().skip(1).collect();
        let out = tensegrity(&args);
        assert!(out.status.success(), "{command}");
        let bundled = std::fs::read_to_string(root().join("config/scenes").join(file)).unwrap();
        assert_eq!(String::from_utf8(out.stdout).unwrap(), bundled, "`{command}` does not write {file}");
        checked += 1;
    }
    assert_eq!(
        checked,
        tensegrity::scene::BUNDLED.len(),
        "the bundled-scene table lists every scene with its command"
    );
}

#[test]
fn a_quasi_static_roll_of_the_robot_says_to_follow_it_dynamically() {
    // the six-bar has no equilibrium once it tips over: a careless quasi-static deploy is told why
    // and what to run instead
    let out = common::scratch("quasi-static-roll").join("roll.csv");
    let run = tensegrity(&[
        "deploy",
        "config/scenes/sixbar.toml",
        "--quasi-static",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(!run.status.success());
    let err = String::from_utf8_lossy(&run.stderr);
    assert!(err.contains("equilibrium not found") && err.contains("--dynamic"), "{err}");
    // the rows up to the tip-over are written
    let rows = std::fs::read_to_string(&out).unwrap().lines().count();
    assert!(rows > 50, "{rows} rows");
}

#[test]
fn the_sensed_csv_marks_every_lost_reading_and_the_step_counted_delay_is_warned_about() {
    // config/examples/sensors.toml drops 1 % of its position updates; its rest-length delay
    // given in steps instead of seconds is warned about, and gives the same numbers
    let scene = root().join("config/examples/sensors.toml");
    let dir = common::scratch("sensed_csv");
    let csv = dir.join("sensed.csv");
    let out = tensegrity(&[
        "deploy",
        "--dynamic",
        scene.to_str().unwrap(),
        "--from-equilibrium",
        "--duration",
        "1",
        "--out",
        csv.to_str().unwrap(),
    ]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    assert!(!String::from_utf8_lossy(&out.stderr).contains("warning"), "delays in seconds are quiet");
    let text = std::fs::read_to_string(&csv).unwrap();
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    let rows: Vec<Vec<f64>> = lines.map(|l| l.split(',').map(|x| x.parse().unwrap()).collect()).collect();
    assert_eq!(rows.len(), 1001);
    let col =
        |name: &str| header.iter().position(|h| *h == name).unwrap_or_else(|| panic!("{name}: {header:?}"));
    for lost in ["rope_tension_lost", "winch_rest_length_lost", "ceiling_x_lost", "load_z_lost"] {
        col(lost);
    }
    let mut flagged = 0;
    for axis in ["x", "y", "z"] {
        let (value, lost) = (col(&format!("load_{axis}_measured_m")), col(&format!("load_{axis}_lost")));
        for w in rows.windows(2) {
            assert!(w[1][lost] == 0.0 || w[1][lost] == 1.0);
            assert_eq!(w[1][lost] == 1.0, w[1][value] == w[0][value], "flagged exactly when held");
            flagged += (w[1][lost] == 1.0) as usize;
        }
    }
    assert!(flagged > 10 && flagged < 60, "about 1 % of 3000 values: {flagged}");
    assert!(rows.iter().all(|r| r[col("rope_tension_lost")] == 0.0));
    // the step-counted delay: a warning naming its replacement, the same CSV
    let stepped = dir.join("stepped.toml");
    let old = std::fs::read_to_string(&scene).unwrap().replace("delay_s = 0.003", "delay = 3");
    std::fs::write(&stepped, old).unwrap();
    let again = dir.join("again.csv");
    let out = tensegrity(&[
        "deploy",
        "--dynamic",
        stepped.to_str().unwrap(),
        "--from-equilibrium",
        "--duration",
        "1",
        "--out",
        again.to_str().unwrap(),
    ]);
    assert!(out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("warning: sensors.rest_length.delay = 3 counts physics steps")
            && err.contains("delay_s = 0.003"),
        "{err}"
    );
    // the same numbers but the wall time
    let wall = col("wall_us");
    let without_wall = |text: &str| -> Vec<String> {
        text.lines()
            .map(|l| l.split(',').enumerate().filter(|(i, _)| *i != wall).map(|(_, x)| x).collect())
            .collect()
    };
    assert!(without_wall(&std::fs::read_to_string(&again).unwrap()) == without_wall(&text), "the same run");
}

#[test]
fn long_work_shows_progress_lines_when_standard_error_is_not_a_terminal() {
    // TENSEGRITY_PROGRESS_AFTER_S = 0 shows at once what a run longer than a second shows: one
    // plain line (then one every 5 s), and a closing line; standard output is unchanged
    let run = |args: &[&str], after: Option<&str>| {
        let mut c = Command::new(env!("CARGO_BIN_EXE_tensegrity"));
        c.args(args).current_dir(root());
        if let Some(a) = after {
            c.env("TENSEGRITY_PROGRESS_AFTER_S", a);
        }
        let out = c.output().unwrap();
        assert!(out.status.success(), "{args:?}: {}", String::from_utf8_lossy(&out.stderr));
        (String::from_utf8(out.stdout).unwrap(), String::from_utf8(out.stderr).unwrap())
    };
    let statics = ["statics", "config/scenes/prism3.toml"];
    let (quiet_out, quiet_err) = run(&statics, None);
    let (out, err) = run(&statics, Some("0"));
    assert!(quiet_err.is_empty(), "a short solve says nothing: {quiet_err}");
    assert_eq!(out, quiet_out);
    assert!(err.starts_with("statics config/scenes/prism3.toml: 0 Newton iterations, residual "), "{err}");
    assert!(err.lines().last().unwrap().contains(": done in "), "{err}");
    // a quasi-static path counts its load steps out of the total, a study its runs, a benchmark
    // its steps
    let path = common::scratch("progress_deploy").join("path.csv");
    let (_, err) = run(
        &["deploy", "--quasi-static", "config/scenes/prism3.toml", "--out", path.to_str().unwrap()],
        Some("0"),
    );
    assert!(err.contains("deploy config/scenes/prism3.toml: ") && err.contains(" load steps"), "{err}");
    let study = common::scratch("progress_study");
    let (_, err) = run(
        &[
            "study",
            "config/scenes/prism3.toml",
            "--ramp-times",
            "0.5",
            "--settle",
            "0.1",
            "--out",
            study.to_str().unwrap(),
        ],
        Some("0"),
    );
    assert!(err.contains("study config/scenes/prism3.toml: ") && err.contains(" runs"), "{err}");
    let (_, err) = run(&["bench", "steps", "config/scenes/prism3.toml", "--steps", "600"], Some("0"));
    assert!(err.starts_with("bench: 256/600 steps"), "{err}");
}

#[test]
fn statics_on_the_ground_reports_each_contacts_friction_and_says_when_a_contact_slips() {
    // the six-bar on its face: three ends pressed in and stuck, the rest open (text and JSON)
    let out = tensegrity(&["statics", "config/scenes/sixbar.toml", "--json"]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let contacts = v["contacts"].as_array().unwrap();
    let states: Vec<&str> = contacts.iter().map(|c| c["friction_state"].as_str().unwrap()).collect();
    assert_eq!(states.iter().filter(|s| **s == "stick").count(), 3, "{states:?}");
    assert_eq!(states.iter().filter(|s| **s == "open").count(), 9, "{states:?}");
    for c in contacts {
        let limit = c["friction_limit_n"].as_f64().unwrap();
        assert!((limit - 0.8 * c["normal_force_n"].as_f64().unwrap()).abs() <= 1e-12 * limit.max(1.0), "{c}");
        assert!(!c["at_limit"].as_bool().unwrap());
    }
    let text = String::from_utf8(tensegrity(&["statics", "config/scenes/sixbar.toml"]).stdout).unwrap();
    assert!(text.contains("mu Fn N  friction"), "{text}");
    assert!(text.lines().any(|l| l.starts_with("x0.b") && l.trim_end().ends_with("stick")), "{text}");

    // a block on 30 degrees at mu 0.3: no equilibrium, and the message names the contact
    let dir = std::env::temp_dir().join(format!("tensegrity-cli-slope-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let scene = dir.join("slope.toml");
    let (s, c) = (30f64.to_radians().sin(), 30f64.to_radians().cos());
    std::fs::write(
        &scene,
        format!(
            "name = \"slope\"\ngravity = [0.0, 0.0, -9.81]\n[[bodies]]\nname = \"block\"\nkind = \"node\"\nmass = 1.0\n\
             position = [0.0, 0.0, 0.0]\ncontact_radius = 0.0\n[[grounds]]\nname = \"slope\"\nnormal = [0.0, {}, {c}]\n\
             mu = 0.3\nstiffness = 1e5\nstick_stiffness = 5e3\n",
            -s
        ),
    )
    .unwrap();
    let out = tensegrity(&["statics", scene.to_str().unwrap()]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(
        err.contains("no equilibrium found") && err.contains("(contact slips: block@slope beyond mu F_n;"),
        "{err}"
    );
    let out = tensegrity(&["deploy", "--quasi-static", scene.to_str().unwrap(), "--out", "-"]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && err.contains("contact slips: block@slope"), "{err}");
    std::fs::remove_dir_all(&dir).ok();
}
