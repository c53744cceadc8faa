//! Invariant: the node honours the ROS conventions that ros2-client leaves to it — `--ros-args`
//! with `-p name:=value`, `--params-file` in the ROS YAML layout (node-specific and `/**` entries,
//! `-p` overriding the file), `-r __ns:=` and `-r __node:=`, `ROS_DOMAIN_ID`, `ROS_LOCALHOST_ONLY`
//! and `ROS_AUTOMATIC_DISCOVERY_RANGE` — and refuses what it cannot honour with a reason.

use tensegrity::io::node::params::{NodeParams, TransportKind};

fn args(s: &str) -> Vec<String> {
    s.split_whitespace().map(String::from).collect()
}

fn no_env(_: &str) -> Option<String> {
    None
}

#[test]
fn defaults_and_plain_arguments() {
    let (p, rest) = NodeParams::from_args(&args("config/scenes/tbar.toml"), no_env).unwrap();
    assert_eq!(p, NodeParams::default());
    assert_eq!(rest, vec!["config/scenes/tbar.toml"]);
    assert_eq!(
        (p.node_name.as_str(), p.namespace.as_str(), p.physics_dt, p.domain_id),
        ("tensegrity_sim", "/", None, 0)
    );
}

#[test]
fn ros_args_set_parameters_and_remap_name_and_namespace() {
    let (p, rest) = NodeParams::from_args(
        &args("scene.toml --ros-args -p physics_dt:=0.002 -p start_paused:=true -p real_time_factor:=0 -r __ns:=/lab -r __node:=sim2 -- --verbose"),
        no_env,
    )
    .unwrap();
    assert_eq!(rest, vec!["scene.toml", "--verbose"]);
    assert_eq!(p.physics_dt, Some(0.002));
    assert!(p.start_paused);
    assert_eq!(p.real_time_factor, 0.0);
    assert_eq!((p.namespace.as_str(), p.node_name.as_str()), ("/lab", "sim2"));
}

#[test]
fn params_file_in_ros_layout_is_read_and_overridden_by_p() {
    let dir = std::env::temp_dir().join(format!("tensegrity-params-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let file = dir.join("params.yaml");
    std::fs::write(
        &file,
        "/**:\n  ros__parameters:\n    frame_id: map\n    rho_inf: 0.5\nother_node:\n  ros__parameters:\n    physics_dt: 9.0\ntensegrity_sim:\n  ros__parameters:\n    physics_dt: 0.0005\n    state_publish_rate: 50\n    start_paused: true\n",
    )
    .unwrap();
    let line = format!("--ros-args --params-file {} -p state_publish_rate:=25.0", file.display());
    let (p, _) = NodeParams::from_args(&args(&line), no_env).unwrap();
    assert_eq!(p.frame_id, "map");
    assert_eq!(p.rho_inf, 0.5);
    assert_eq!(p.physics_dt, Some(0.0005), "other nodes' entries are ignored");
    assert!(p.start_paused);
    assert_eq!(p.state_publish_rate, 25.0, "-p overrides the file");
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn environment_sets_domain_and_localhost_only() {
    let env = |k: &str| match k {
        "ROS_DOMAIN_ID" => Some("42".to_string()),
        "ROS_AUTOMATIC_DISCOVERY_RANGE" => Some("LOCALHOST".to_string()),
        _ => None,
    };
    let (p, _) = NodeParams::from_args(&[], env).unwrap();
    assert_eq!(p.domain_id, 42);
    assert!(p.localhost_only);
    let (p, _) =
        NodeParams::from_args(&[], |k: &str| (k == "ROS_LOCALHOST_ONLY").then(|| "1".to_string())).unwrap();
    assert!(p.localhost_only);
}

#[test]
fn bad_parameters_are_refused_with_a_reason() {
    for (line, needle) in [
        ("--ros-args -p physics_dt:=-1", "physics_dt"),
        ("--ros-args -p physics_dt:=10", "physics_dt must be in [1e-6, 0.1], got 10"),
        ("--ros-args -p physics_dt:=0", "physics_dt must be in [1e-6, 0.1], got 0"),
        ("--ros-args -r __node:=bad-name", "not a ROS node name (letters, digits and underscores"),
        ("--ros-args -r __node:=", "not a ROS node name"),
        ("--ros-args -r __ns:=/lab/2x", "namespace part '2x' is not a ROS name"),
        ("--ros-args -p physics_dt:=1e-12", "physics_dt must be in"),
        ("--ros-args -p real_time_factor:=1e9", "real_time_factor must be in"),
        ("--ros-args -p markers_rate:=1e9", "markers_rate must be in"),
        ("--ros-args -p command_timeout:=-3", "command_timeout must be in"),
        ("--ros-args -p frame_id:=''", "frame_id must have"),
        ("--ros-args -p physics_dt:=nan", "not finite"),
        ("--ros-args -p rho_inf:=2", "rho_inf"),
        ("--ros-args -p newton_tolerance:=0", "newton_tolerance must be in [1e-12, 0.001], got 0"),
        ("--ros-args -p newton_tolerance:=0.1", "newton_tolerance must be in"),
        ("--ros-args -p newton_tolerance:=nan", "not finite"),
        ("--ros-args -p newton_tolerance:=fast", "newton_tolerance"),
        ("--ros-args -p warp_speed:=9", "unknown parameter"),
        ("--ros-args -p start_paused:=maybe", "boolean"),
        ("--ros-args -p physics_dt", "name:=value"),
        ("--ros-args -r chatter:=talk", "unsupported remapping"),
        ("--ros-args --params-file /nonexistent/p.yaml", "/nonexistent/p.yaml"),
        ("--ros-args -p", "needs a value"),
    ] {
        let e = NodeParams::from_args(&args(line), no_env).unwrap_err();
        assert!(e.to_string().contains(needle), "'{line}' gave '{e}'");
    }
    let e =
        NodeParams::from_args(&[], |k: &str| (k == "ROS_DOMAIN_ID").then(|| "999".to_string())).unwrap_err();
    assert!(e.to_string().contains("ROS_DOMAIN_ID"));
}

#[test]
fn every_parameter_in_the_help_table_is_understood_with_its_default() {
    let built = TransportKind::BUILT.iter().map(|t| t.name()).collect::<Vec<_>>().join(",");
    for (name, default, meaning) in tensegrity::io::node::params::PARAMETERS {
        assert!(!meaning.is_empty());
        let value = match *default {
            "(bundled prism3)" => "scene.toml",
            "(scene's, else 0.001)" => "0.001",
            "(scene's)" => "7",
            "(every one built)" if built.is_empty() => continue,
            "(every one built)" => built.as_str(),
            "(off)" | "(<ns>/<node>)" => "",
            d => d,
        };
        let mut p = NodeParams::default();
        p.set(name, value).unwrap_or_else(|e| panic!("{name} := {value}: {e}"));
    }
    assert!(NodeParams::default().set("no_such_parameter", "1").is_err());
}

#[test]
fn transports_are_parsed_checked_and_default_to_every_one_built() {
    assert_eq!(NodeParams::default().transports, TransportKind::BUILT.to_vec());
    let mut p = NodeParams::default();
    let mut bad = vec![(String::new(), "names no transport"), ("udp".into(), "unknown transport 'udp'")];
    for kind in TransportKind::BUILT {
        bad.push((format!("{0}, {0}", kind.name()), "named twice"));
    }
    for (text, needle) in bad {
        let e = p.set("transports", &text).unwrap_err().to_string();
        assert!(e.contains(needle), "'{text}' gave '{e}'");
    }
    for kind in [TransportKind::Dds, TransportKind::Shm] {
        let built = TransportKind::BUILT.contains(&kind);
        match p.set("transports", kind.name()) {
            Ok(()) => {
                assert!(built);
                assert_eq!(p.transports, vec![kind]);
            }
            Err(e) => {
                assert!(!built);
                assert!(e.to_string().contains(kind.feature()), "{e}");
            }
        }
    }
    if TransportKind::BUILT.len() == 2 {
        p.set("transports", " shm , dds ").unwrap();
        assert_eq!(p.transports, vec![TransportKind::Shm, TransportKind::Dds], "order kept, spaces ignored");
    }
    let e = p.set("shm_spin_us", "20000").unwrap_err().to_string();
    assert!(e.contains("shm_spin_us"), "{e}");
    assert!(p.set("shm_spin_us", "1.5").is_err());
    p.set("shm_spin_us", "0").unwrap();
    assert_eq!(p.shm_spin_us, 0);
}

#[test]
fn shared_memory_names_follow_namespace_and_node_remapping() {
    let (p, _) =
        NodeParams::from_args(&args("--ros-args -r __ns:=/lab/rig2 -r __node:=sim"), no_env).unwrap();
    assert_eq!(p.shm_prefix(), "lab/rig2/sim");
    assert_eq!(NodeParams::default().shm_prefix(), "tensegrity_sim");
    // an explicit prefix wins over the ROS names (parallel tests keep their topic names)
    let mut q = p.clone();
    q.set("shm_prefix", "kit/test_7").unwrap();
    assert_eq!(q.shm_prefix(), "kit/test_7");
    assert_eq!(q.private_namespace(), p.private_namespace());
    q.set("shm_prefix", "").unwrap();
    assert_eq!(q.shm_prefix(), "lab/rig2/sim");
    for bad in ["//abs", "trailing/", "sp ace", "dot.ted", &"x".repeat(201)] {
        let e = q.set("shm_prefix", bad).unwrap_err().to_string();
        assert!(e.contains("parameter shm_prefix"), "{bad}: {e}");
    }
}

#[test]
fn a_mistyped_parameter_or_integrator_is_answered_with_what_was_meant() {
    let e = NodeParams::from_args(&args("--ros-args -p real_time_factr:=2"), no_env).unwrap_err().to_string();
    assert!(e.contains("unknown parameter 'real_time_factr' (did you mean 'real_time_factor'?)"), "{e}");
    let e = NodeParams::from_args(&args("--ros-args -p integrator:=rk5"), no_env).unwrap_err().to_string();
    assert!(e.contains("unknown 'rk5' (did you mean 'rk4'?)"), "{e}");
    assert!(e.contains("generalized-alpha, symplectic-euler, rk4, dormand-prince"), "{e}");
    // far from every name: no guess, the list
    let e = NodeParams::from_args(&args("--ros-args -p integrator:=verlet"), no_env).unwrap_err().to_string();
    assert!(!e.contains("did you mean") && e.contains("dormand-prince"), "{e}");
    // a shared-memory prefix written like a ROS name: its leading slash is dropped
    let (p, _) = NodeParams::from_args(&args("--ros-args -p shm_prefix:=/lab/sim2"), no_env).unwrap();
    assert_eq!(p.shm_prefix(), "lab/sim2");
    assert!(NodeParams::from_args(&args("--ros-args -p shm_prefix:=/lab/"), no_env).is_err());
}

#[test]
fn an_unknown_bundled_scene_is_named_as_the_user_wrote_it() {
    let e = tensegrity::scene::bundled("sixbars").unwrap_err().to_string();
    assert!(e.starts_with("bundled:sixbars: no bundled scene 'sixbars' (bundled: "), "{e}");
    assert!(e.ends_with("(did you mean 'sixbar'?)"), "{e}");
    assert!(!e.contains("config/scenes"), "{e}");
}

#[test]
fn the_node_refuses_a_scene_with_nothing_to_move_as_a_bad_scene() {
    let dir = std::env::temp_dir().join(format!("tensegrity-node-fixed-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let scene = dir.join("fixed.toml");
    std::fs::write(
        &scene,
        "[[bodies]]\nname = \"a\"\nkind = \"fixed\"\n[[bodies]]\nname = \"b\"\nkind = \"fixed\"\nposition = [1.0, 0.0, 0.0]\n\
         [[cables]]\nname = \"c\"\nroute = [\"a\", \"b\"]\nea = 1000.0\nrest_length = 0.9\n",
    )
    .unwrap();
    // it stops before any transport opens: no network namespace needed
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_tensegrity_node")).arg(&scene).output().unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(3), "{stderr}");
    assert!(stderr.contains("nothing to move"), "{stderr}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn the_newton_tolerance_reaches_the_simulator_and_the_run_record() {
    let (p, _) = NodeParams::from_args(&args("--ros-args -p newton_tolerance:=1e-6"), no_env).unwrap();
    assert_eq!(p.newton_tolerance, 1e-6);
    let model = tensegrity::scene::bundled("prism3").unwrap();
    let core = tensegrity::io::node::NodeCore::new(model.clone(), p.clone()).unwrap();
    let settings = core.simulator().settings();
    assert_eq!(settings.newton.tolerance, 1e-6);
    // a bag's run record replays with it
    let run =
        tensegrity::io::record::run_info(tensegrity::io::record::KIND_NODE, &model, "prism3", settings, &p);
    assert_eq!(run.get("newton_tolerance").map(String::as_str), Some("1e-6"), "{run:?}");
    let (again, params) = tensegrity::io::record::settings_of(&run).unwrap();
    assert_eq!((again.newton.tolerance, params.newton_tolerance), (1e-6, 1e-6));
    // the default is the library's
    let (default, _) = NodeParams::from_args(&[], no_env).unwrap();
    assert_eq!(default.newton_tolerance, tensegrity::solve::dynamics::DEFAULT_NEWTON_TOLERANCE);
}
