//! `tensegrity_node`: the simulator as a ROS 2 node and a shared-memory server (argument parsing
//! and wiring only).
//!
//! Usage: `tensegrity_node [SCENE.toml] [--ros-args -p name:=value ...]` (`--help` lists every
//! parameter); without a scene it runs the bundled `prism3`, and `bundled:NAME` runs another bundled
//! scene (`config/scenes/NAME.toml`, built into the binary). Serves the transports of
//! `-p transports:=` (default: every one built in, features `ros2` and `shm`). Stops cleanly on
//! SIGINT and SIGTERM.

use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::atomic::AtomicBool;
use std::sync::Arc;

use tensegrity::io::node::params::{NodeParams, TransportKind, PARAMETERS};
use tensegrity::io::LaunchError;

/// Why the node stopped, as its exit status says it (`--help` lists them).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Exit {
    /// Bad arguments or parameters (also a parameter that does not fit the scene).
    BadArguments = 2,
    /// The scene could not be read or is invalid.
    BadScene = 3,
    /// A transport (DDS, shared memory, the bag recorder) or the signal handler could not start.
    Middleware = 4,
    /// The simulation could not start, or it stopped while a physics failure held it (no reset
    /// cleared it).
    Physics = 5,
}

/// A failure and its exit status.
struct Failure(Exit, String);

fn fail(exit: Exit) -> impl Fn(String) -> Failure {
    move |message| Failure(exit, message)
}

fn main() -> ExitCode {
    // iceoryx2 warns when no config file exists; errors still show (IOX2_LOG_LEVEL overrides)
    #[cfg(feature = "shm")]
    iceoryx2::prelude::set_log_level_from_env_or(iceoryx2::prelude::LogLevel::Error);
    match run() {
        Ok(()) => ExitCode::SUCCESS,
        Err(Failure(exit, message)) => {
            eprintln!("error: {message}");
            ExitCode::from(exit as u8)
        }
    }
}
/// The help text: usage, parameters (from `PARAMETERS`), environment, signals, exit status.
fn help() -> String {
    let mut h = String::from(
        "tensegrity_node: the clustered-tensegrity simulator as a ROS 2 node (DDS, no ROS install needed)\n\
         and an iceoryx2 shared-memory server for local controllers\n\n\
         Usage: tensegrity_node [--ready-file PATH] [SCENE.toml] [--ros-args -p NAME:=VALUE ...\n\
         \x20                      --params-file FILE -r __ns:=/NAMESPACE -r __node:=NAME]\n\
         \x20      tensegrity_node --help | --version\n\n\
         Options:\n  --ready-file PATH                once every publisher and service is up, writes PATH\n\
         \x20                                  (pid=, domain_id=, namespace=, node=, private_namespace=,\n\
         \x20                                  shm_prefix=, transports= lines; written whole, removed at\n\
         \x20                                  exit) and\n\
         \x20                                  prints `ready` on stdout\n\nParameters (-p NAME:=VALUE, or a ROS 2 params file):\n",
    );
    let bundled: Vec<&str> = tensegrity::scene::BUNDLED.iter().map(|(n, _)| *n).collect();
    h = h.replacen(
        "Options:",
        &format!(
            "SCENE.toml may also be bundled:NAME, a scene built into the node (the default is\n\
             bundled:prism3); bundled: {}.\n\nOptions:",
            bundled.join(", ")
        ),
        1,
    );
    for (name, default, meaning) in PARAMETERS {
        h += &format!("  {name:<24} {default:<22} {meaning}\n");
    }
    h += "\nEnvironment:\n  ROS_DOMAIN_ID                    DDS domain, 0-232 (default 0)\n  \
          ROS_LOCALHOST_ONLY=1             bind DDS to 127.0.0.1 (not a firewall: see .ci/loopback-net)\n  \
          ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST   the same\n\n\
          Topics /clock, /tf, /tf_static, /diagnostics and ~/body_poses, ~/cable_states, ~/actuator_states,\n\
          ~/structure, ~/markers out (with sensors also ~/ground_truth/... and ~/imu); ~/actuator_commands,\n\
          ~/joint_commands, ~/tension_commands in; simulation_interfaces\n\
          services in ~/ (see docs/node.md). -p record:=DIR also writes them and the applied commands\n\
          (~/applied_commands) to a rosbag2 bag (MCAP); `tensegrity replay DIR` runs it again.\n\n\
          Exit status (the reason is printed on stderr): 0 stopped by SIGINT, SIGTERM or\n\
          SetSimulationState(QUITTING); 2 bad arguments or parameters; 3 the scene cannot be read or is\n\
          invalid; 4 a transport (DDS, shared memory, the bag recorder) cannot start; 5 a physics failure:\n\
          the simulation cannot start, or it was stopped while a physics failure held it (no reset).\n\n\
          Shared memory (iceoryx2, services <ns>/<node>/...: state, structure, actuator_commands,\n\
          lockstep; events to_node, from_node): see docs/shared-memory.md and python/tensegrity/testing/shm.py.\n";
    h += &format!(
        "\nTransports built into this binary: {}\n",
        TransportKind::BUILT.iter().map(|t| t.name()).collect::<Vec<_>>().join(", ")
    );
    h
}

/// Splits `--ready-file PATH` (or `--ready-file=PATH`) off the arguments before `--ros-args`.
fn take_ready_file(args: &mut Vec<String>) -> Result<Option<PathBuf>, Failure> {
    let end = args.iter().position(|a| a == "--ros-args").unwrap_or(args.len());
    let Some(i) = args[..end].iter().position(|a| a == "--ready-file" || a.starts_with("--ready-file="))
    else {
        return Ok(None);
    };
    let path = match args[i].strip_prefix("--ready-file=") {
        Some(p) => {
            let p = p.to_string();
            args.remove(i);
            p
        }
        None if i + 1 < end => {
            let p = args.remove(i + 1);
            args.remove(i);
            p
        }
        None => return Err(Failure(Exit::BadArguments, "--ready-file needs a PATH".into())),
    };
    if path.is_empty() || path.starts_with('-') {
        return Err(Failure(Exit::BadArguments, format!("--ready-file needs a PATH, got '{path}'")));
    }
    Ok(Some(PathBuf::from(path)))
}

/// Writes the ready file whole (a temporary file renamed into place), so a reader that sees it
/// sees all of it.
fn write_ready_file(path: &Path, params: &NodeParams) -> Result<(), Failure> {
    let transports: Vec<_> = params.transports.iter().map(|t| t.name()).collect();
    let text = format!(
        "pid={}\ndomain_id={}\nnamespace={}\nnode={}\nprivate_namespace={}\nshm_prefix={}\ntransports={}\n",
        std::process::id(),
        params.domain_id,
        params.namespace,
        params.node_name,
        params.private_namespace(),
        params.shm_prefix(),
        transports.join(",")
    );
    let tmp = path.with_extension(format!("tmp{}", std::process::id()));
    std::fs::write(&tmp, text)
        .and_then(|()| std::fs::rename(&tmp, path))
        .map_err(|e| Failure(Exit::BadArguments, format!("--ready-file {}: {e}", path.display())))
}

fn run() -> Result<(), Failure> {
    let mut args: Vec<String> = std::env::args().skip(1).collect();
    let ready_file = take_ready_file(&mut args)?;
    let bad_args = fail(Exit::BadArguments);
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
            "-p" | "--param" | "-r" | "--remap" | "--params-file" => {
                return Err(bad_args(format!(
                    "'{a}' is a ROS argument: put it after --ros-args (tensegrity_node [SCENE.toml] \
                     --ros-args {a} ...)"
                )));
            }
            other if other.starts_with('-') => {
                return Err(bad_args(format!("unknown option '{other}'; see tensegrity_node --help")));
            }
            _ => {}
        }
    }
    let (mut params, rest) =
        NodeParams::from_args(&args, |k| std::env::var(k).ok()).map_err(|e| bad_args(e.to_string()))?;
    match rest.as_slice() {
        [] => {}
        [scene] => params.scene = Some(scene.into()),
        more => {
            return Err(bad_args(format!(
                "unexpected arguments {more:?}; usage: tensegrity_node [SCENE.toml] [--ros-args ...]"
            )))
        }
    }
    let bad_scene = fail(Exit::BadScene);
    let model = match &params.scene {
        // `bundled:NAME` is a scene bundled with the node (config/scenes/NAME.toml)
        Some(path) => match path.to_str().and_then(|p| p.strip_prefix("bundled:")) {
            Some(name) => tensegrity::scene::bundled(name),
            None => tensegrity::scene::load(path),
        }
        .map_err(|e| bad_scene(e.to_string()))?,
        None => tensegrity::scene::from_toml(
            tensegrity::scene::bundled_text("prism3").unwrap_or_default(),
            "<bundled prism3>",
        )
        .map_err(|e| bad_scene(e.to_string()))?,
    };
    if model.dof_count == 0 {
        let label = params.scene.as_ref().map_or("<bundled prism3>".into(), |p| p.display().to_string());
        return Err(bad_scene(format!("{label}: {}", tensegrity::sim::StepError::NothingToMove)));
    }
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
        params.physics_dt.or(model.physics_dt).unwrap_or(tensegrity::sim::DEFAULT_PHYSICS_DT),
        params.real_time_factor
    );
    for w in model
        .delay_warnings(params.physics_dt.or(model.physics_dt).unwrap_or(tensegrity::sim::DEFAULT_PHYSICS_DT))
    {
        eprintln!("tensegrity_node: warning: {w}");
    }
    let bag = params.record.clone();
    let launch_params = params.clone();
    let mut node = tensegrity::io::launch(model, launch_params).map_err(|e| match e {
        LaunchError::Core(tensegrity::io::node::CoreError::Params(why)) => Failure(Exit::BadArguments, why),
        LaunchError::Core(e) => Failure(Exit::Physics, format!("the simulation cannot start: {e}")),
        e @ LaunchError::Transport { .. } => Failure(Exit::Middleware, e.to_string()),
    })?;
    if let Some(dir) = &bag {
        eprintln!("tensegrity_node: recording to the bag {}", dir.display());
    }
    let stop = Arc::new(AtomicBool::new(false));
    #[cfg(any(feature = "ros2", feature = "shm"))]
    {
        let flag = stop.clone();
        // the waker makes a paused node stop at once, not at its next due turn
        let waker = node.waker();
        ctrlc::set_handler(move || {
            flag.store(true, std::sync::atomic::Ordering::Relaxed);
            if let Some(w) = &waker {
                let _ = w.wake();
            }
        })
        .map_err(|e| Failure(Exit::Middleware, format!("signal handler: {e}")))?;
    }
    if let Some(path) = &ready_file {
        write_ready_file(path, &params)?;
    }
    {
        use std::io::Write;
        // a closed stdout must not stop the node
        let mut out = std::io::stdout().lock();
        let _ = writeln!(out, "ready").and_then(|()| out.flush());
    }
    node.run(&stop);
    if let Some(path) = &ready_file {
        let _ = std::fs::remove_file(path);
    }
    let fault = node.core().fault().map(str::to_string);
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
    match fault {
        Some(fault) => Err(Failure(Exit::Physics, format!("stopped while faulted: {fault}"))),
        None => Ok(()),
    }
}
