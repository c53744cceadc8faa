//! `tensegrity_node`: the simulator as a ROS 2 node (argument parsing and wiring only).
//!
//! Usage: `tensegrity_node [SCENE.toml] [--ros-args -p name:=value ...]` (`--help` lists every
//! parameter); without a scene it runs the bundled `prism3`. Stops cleanly on SIGINT and SIGTERM.

use std::process::ExitCode;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

use tensegrity::io::params::{NodeParams, PARAMETERS};
use tensegrity::io::ros2::SimNode;

const DEFAULT_SCENE: &str = include_str!("../../config/scenes/prism3.toml");

fn main() -> ExitCode {
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
        "tensegrity_node: the clustered-tensegrity simulator as a ROS 2 node (DDS, no ROS install needed)\n\n\
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
          services in ~/ (see the README). SIGINT or SIGTERM stops it (exit 0); bad arguments, scene\n\
          or parameters exit 1 with the reason.\n";
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
    let stop = Arc::new(AtomicBool::new(false));
    let flag = stop.clone();
    ctrlc::set_handler(move || flag.store(true, Ordering::Relaxed)).map_err(|e| e.to_string())?;
    eprintln!(
        "tensegrity_node: '{}' as {}/{} on domain {}{}, dt {} s, real-time factor {}",
        model.name,
        params.namespace.trim_end_matches('/'),
        params.node_name,
        params.domain_id,
        if params.localhost_only { " (localhost only)" } else { "" },
        params.physics_dt.or(model.physics_dt).unwrap_or(1e-3),
        params.real_time_factor
    );
    let mut node = SimNode::new(model, params).map_err(|e| e.to_string())?;
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
    Ok(())
}
