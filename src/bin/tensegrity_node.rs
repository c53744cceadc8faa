//! `tensegrity_node`: the simulator as a ROS 2 node and a shared-memory server (argument parsing
//! and wiring only).
//!
//! Usage: `tensegrity_node [SCENE.toml] [--ros-args -p name:=value ...]` (`--help` lists every
//! parameter); without a scene it runs the bundled `prism3`. Serves the transports of
//! `-p transports:=` (default: every one built in, features `ros2` and `shm`). Stops cleanly on
//! SIGINT and SIGTERM.

use std::process::ExitCode;
use std::sync::atomic::AtomicBool;
use std::sync::Arc;

use tensegrity::io::params::{NodeParams, TransportKind, PARAMETERS};

const DEFAULT_SCENE: &str = include_str!("../../config/scenes/prism3.toml");

fn main() -> ExitCode {
    // iceoryx2 warns when no config file exists; errors still show (IOX2_LOG_LEVEL overrides)
    #[cfg(feature = "shm")]
    iceoryx2::prelude::set_log_level_from_env_or(iceoryx2::prelude::LogLevel::Error);
    match run() {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::FAILURE
        }
    }
}

/// The help text: usage, parameters (from `PARAMETERS`), environment, signals, exit status.
fn help() -> String {
    let mut h = String::from(
        "tensegrity_node: the clustered-tensegrity simulator as a ROS 2 node (DDS, no ROS install needed)\n\
         and an iceoryx2 shared-memory server for local controllers\n\n\
         Usage: tensegrity_node [SCENE.toml] [--ros-args -p NAME:=VALUE ... --params-file FILE\n\
         \x20                                   -r __ns:=/NAMESPACE -r __node:=NAME]\n\
         \x20      tensegrity_node --help | --version\n\nParameters (-p NAME:=VALUE, or a ROS 2 params file):\n",
    );
    for (name, default, meaning) in PARAMETERS {
        h += &format!("  {name:<24} {default:<22} {meaning}\n");
    }
    h += "\nEnvironment:\n  ROS_DOMAIN_ID                    DDS domain, 0-232 (default 0)\n  \
          ROS_LOCALHOST_ONLY=1             bind DDS to 127.0.0.1 (not a firewall: see .ci/loopback-net)\n  \
          ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST   the same\n\n\
          Topics /clock, /tf, /tf_static, /diagnostics and ~/body_poses, ~/cable_states, ~/actuator_states,\n\
          ~/structure, ~/markers out; ~/actuator_commands, ~/joint_commands in; simulation_interfaces\n\
          services in ~/ (see the README). -p record:=DIR also writes them and the applied commands\n\
          (~/applied_commands) to a rosbag2 bag (MCAP); `tensegrity replay DIR` runs it again. SIGINT or SIGTERM stops it (exit 0); bad arguments, scene\n\
          or parameters exit 1 with the reason.\n\n\
          Shared memory (iceoryx2, services <ns>/<node>/...: state, structure, actuator_commands,\n\
          lockstep; events to_node, from_node): see the README and tests/interop/shm_client.py.\n";
    h += &format!(
        "\nTransports built into this binary: {}\n",
        TransportKind::BUILT.iter().map(|t| t.name()).collect::<Vec<_>>().join(", ")
    );
    h
}

fn run() -> Result<(), String> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let before_ros_args = args.iter().take_while(|a| *a != "--ros-args");
    for a in before_ros_args {
        match a.as_str() {
            "-h" | "--help" => {
                print!("{}", help());
                return Ok(());
            }
            "-V" | "--version" => {
                println!("tensegrity_node {}", env!("CARGO_PKG_VERSION"));
                return Ok(());
            }
            other if other.starts_with('-') => {
                return Err(format!("unknown option '{other}'; see tensegrity_node --help"));
            }
            _ => {}
        }
    }
    let (mut params, rest) =
        NodeParams::from_args(&args, |k| std::env::var(k).ok()).map_err(|e| e.to_string())?;
    match rest.as_slice() {
        [] => {}
        [scene] => params.scene = Some(scene.into()),
        more => {
            return Err(format!(
                "unexpected arguments {more:?}; usage: tensegrity_node [SCENE.toml] [--ros-args ...]"
            ))
        }
    }
    let model = match &params.scene {
        Some(path) => tensegrity::scene::load(path).map_err(|e| e.to_string())?,
        None => tensegrity::scene::from_toml(DEFAULT_SCENE, "<bundled prism3>").map_err(|e| e.to_string())?,
    };
    let mut serving = Vec::new();
    for t in &params.transports {
        serving.push(match t {
            TransportKind::Dds => format!(
                "DDS domain {}{}",
                params.domain_id,
                if params.localhost_only { " (localhost only)" } else { "" }
            ),
            TransportKind::Shm => format!("shared memory {}/*", params.shm_prefix()),
        });
    }
    eprintln!(
        "tensegrity_node: '{}' as {}/{} on {}, dt {} s, real-time factor {}",
        model.name,
        params.namespace.trim_end_matches('/'),
        params.node_name,
        serving.join(" and "),
        params.physics_dt.or(model.physics_dt).unwrap_or(1e-3),
        params.real_time_factor
    );
    let bag = params.record.clone();
    let mut node = tensegrity::io::launch(model, params).map_err(|e| e.to_string())?;
    if let Some(dir) = &bag {
        eprintln!("tensegrity_node: recording to the bag {}", dir.display());
    }
    let stop = Arc::new(AtomicBool::new(false));
    #[cfg(any(feature = "ros2", feature = "shm"))]
    {
        let flag = stop.clone();
        ctrlc::set_handler(move || flag.store(true, std::sync::atomic::Ordering::Relaxed))
            .map_err(|e| e.to_string())?;
    }
    node.run(&stop);
    let s = node.stats();
    let failures: u64 = s.publish_failures.iter().sum();
    eprintln!(
        "tensegrity_node: stopped after {} steps; commands received {}, accepted {}, rejected {}; \
         publish failures {failures}; malformed incoming {}; overruns {}; physics failures {}",
        s.steps,
        s.commands_received,
        s.commands_accepted,
        s.commands_rejected,
        s.malformed_incoming,
        s.overruns,
        s.physics_failures
    );
    // the recorder closes its bag (summary, end magic, metadata.yaml) when the node goes
    drop(node);
    if let Some(dir) = bag {
        eprintln!("tensegrity_node: bag {} closed", dir.display());
    }
    Ok(())
}
