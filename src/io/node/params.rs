//! Node parameters: takes the command line (with ROS 2's `--ros-args` section), a parameters file
//! in the ROS YAML layout and the ROS environment variables, gives `NodeParams`. ros2-client reads
//! none of these itself, so the node does it here (no middleware needed, so it is tested without
//! DDS).
//!
//! Understood: `--ros-args` followed by `-p name:=value`, `--param name:=value`,
//! `--params-file FILE`, `-r __ns:=/ns`, `-r __node:=name` (also `--remap`), ended by `--`;
//! `ROS_DOMAIN_ID`; `ROS_LOCALHOST_ONLY=1` or `ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST` bind DDS to
//! 127.0.0.1. Later settings override earlier ones; `-p` overrides the file.

use std::path::{Path, PathBuf};

use crate::error::readable_number;

/// What a ROS node name or namespace part may be, for messages.
const ROS_NAME_RULE: &str = "letters, digits and underscores, not starting with a digit, not empty";

/// True for a valid ROS node name or namespace part: `[A-Za-z_][A-Za-z0-9_]*`.
fn ros_name_ok(name: &str) -> bool {
    let mut chars = name.chars();
    chars.next().is_some_and(|c| c.is_ascii_alphabetic() || c == '_')
        && chars.all(|c| c.is_ascii_alphanumeric() || c == '_')
}

/// Everything the node is configured by. Defaults in `Default`.
#[derive(Debug, Clone, PartialEq)]
pub struct NodeParams {
    /// Node name (`__node`), default `tensegrity_sim`.
    pub node_name: String,
    /// Namespace (`__ns`), default `/`.
    pub namespace: String,
    /// Scene file; the bundled default scene when absent.
    pub scene: Option<PathBuf>,
    /// Physics step, s (parameter `physics_dt`; default: the scene's `physics_dt`, else 0.001).
    pub physics_dt: Option<f64>,
    /// Real-time factor: 1 = real time, 0 = as fast as possible (`real_time_factor`).
    pub real_time_factor: f64,
    /// Start paused; advance with StepSimulation or unpause (`start_paused`).
    pub start_paused: bool,
    /// Start (and reset to) the static equilibrium at t = 0 rather than the scene's pose
    /// (`start_from_equilibrium`; `Simulator::at_equilibrium`).
    pub start_from_equilibrium: bool,
    /// State publishing rate in sim-time Hz, 0 = every step (`state_publish_rate`, default 100).
    pub state_publish_rate: f64,
    /// Fixed frame of poses and transforms (`frame_id`, default `world`).
    pub frame_id: String,
    /// Integrator name (`integrator`: generalized-alpha, symplectic-euler, rk4 or
    /// dormand-prince).
    pub integrator: String,
    /// Generalized-alpha spectral radius (`rho_inf`, default 0.8).
    pub rho_inf: f64,
    /// Local error tolerance, m (`tolerance`, default 0 = fixed steps): error-controlled
    /// sub-steps inside every `physics_dt`, so publish times stay regular (generalized-alpha
    /// and dormand-prince).
    pub tolerance: f64,
    /// Newton tolerance of generalized-alpha, relative to the forces (`newton_tolerance`,
    /// default 1e-9, in `NEWTON_TOLERANCE_RANGE`): a looser one takes fewer iterations per step.
    pub newton_tolerance: f64,
    /// Follow the scene's deployment schedule (`follow_schedule`, default false: actuators hold
    /// their initial rest lengths until commanded).
    pub follow_schedule: bool,
    /// RViz markers per second of sim time (`markers_rate`, default 30, 0 = off).
    pub markers_rate: f64,
    /// Seed of the scene's sensor noise (`sensor_seed`; `None`: the scene's `[sensors] seed`).
    pub sensor_seed: Option<u64>,
    /// Sim-time seconds without an accepted command after which `command_timeout_action` is
    /// taken (`command_timeout`, default 0 = never).
    pub command_timeout: f64,
    /// `hold`: every winch stops where it is; `initial`: winches return to their initial rest
    /// lengths (`command_timeout_action`, default hold).
    pub command_timeout_action: String,
    /// Service request/reply mapping (`service_mapping`: enhanced, the default, suits Fast DDS
    /// and RustDDS clients; cyclone suits Cyclone DDS clients; basic).
    pub service_mapping: String,
    /// DDS domain id (`ROS_DOMAIN_ID`, default 0).
    pub domain_id: u16,
    /// Bind DDS to 127.0.0.1 only.
    pub localhost_only: bool,
    /// Transports to serve (`transports`, a comma-separated list of `dds` and `shm`; default:
    /// every transport this build has, see `TransportKind::BUILT`).
    pub transports: Vec<TransportKind>,
    /// How long the shared-memory transport keeps polling for the next request after answering
    /// one before it blocks on its event, us (`shm_spin_us`, default 200, 0 = block at once):
    /// a lockstep controller's next request arrives within a few microseconds, far sooner than an
    /// event wake-up (tens of microseconds); the poll yields the core between polls (a controller
    /// on the same core runs at once) and never runs while the node is idle.
    pub shm_spin_us: u64,
    /// The shared-memory service prefix instead of `<ns>/<node>` (`shm_prefix`, default: none),
    /// so that several nodes (parallel tests) keep their ROS names and still have distinct
    /// iceoryx2 services: shared memory is one per machine, not per network namespace.
    pub shm_prefix_override: Option<String>,
    /// Record a rosbag2 bag into this directory (`record`, default: none): every published
    /// topic and the applied commands (`io::record`).
    pub record: Option<PathBuf>,
}

/// A transport the node can serve.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TransportKind {
    /// ROS 2 over DDS (feature `ros2`).
    Dds,
    /// iceoryx2 shared memory (feature `shm`).
    Shm,
}

impl TransportKind {
    /// The transports this build has (cargo features `ros2`, `shm`), in serving order.
    pub const BUILT: &'static [TransportKind] = match (cfg!(feature = "ros2"), cfg!(feature = "shm")) {
        (true, true) => &[TransportKind::Dds, TransportKind::Shm],
        (true, false) => &[TransportKind::Dds],
        (false, true) => &[TransportKind::Shm],
        (false, false) => &[],
    };
    /// The name in `transports` (`dds`, `shm`).
    pub fn name(self) -> &'static str {
        match self {
            TransportKind::Dds => "dds",
            TransportKind::Shm => "shm",
        }
    }
    /// The cargo feature that builds it.
    pub fn feature(self) -> &'static str {
        match self {
            TransportKind::Dds => "ros2",
            TransportKind::Shm => "shm",
        }
    }
    /// Parses a `transports` value: names separated by commas (spaces ignored), each once, each
    /// built into this binary.
    pub fn parse_list(text: &str) -> Result<Vec<TransportKind>, ParamError> {
        let mut out = Vec::new();
        for part in text.split(',').map(str::trim).filter(|p| !p.is_empty()) {
            let kind = match part.to_ascii_lowercase().as_str() {
                "dds" | "ros2" => TransportKind::Dds,
                "shm" | "iceoryx2" => TransportKind::Shm,
                other => {
                    return Err(err(format!(
                        "parameter transports: unknown transport '{other}' (dds or shm)"
                    )))
                }
            };
            if !Self::BUILT.contains(&kind) {
                return Err(err(format!(
                    "parameter transports: '{}' is not built into this binary (rebuild with the default \
                     features, cargo build --release, or --features {})",
                    kind.name(),
                    kind.feature()
                )));
            }
            if out.contains(&kind) {
                return Err(err(format!("parameter transports: '{}' is named twice", kind.name())));
            }
            out.push(kind);
        }
        if out.is_empty() {
            return Err(err("parameter transports: names no transport (dds, shm or dds,shm)"));
        }
        Ok(out)
    }
}

impl Default for NodeParams {
    fn default() -> Self {
        Self {
            node_name: "tensegrity_sim".into(),
            namespace: "/".into(),
            scene: None,
            physics_dt: None,
            real_time_factor: 1.0,
            start_paused: false,
            start_from_equilibrium: false,
            state_publish_rate: 100.0,
            frame_id: "world".into(),
            integrator: "generalized-alpha".into(),
            rho_inf: 0.8,
            tolerance: 0.0,
            newton_tolerance: crate::solve::dynamics::DEFAULT_NEWTON_TOLERANCE,
            follow_schedule: false,
            markers_rate: 30.0,
            sensor_seed: None,
            command_timeout: 0.0,
            command_timeout_action: "hold".into(),
            service_mapping: "enhanced".into(),
            domain_id: 0,
            localhost_only: false,
            transports: TransportKind::BUILT.to_vec(),
            shm_spin_us: 200,
            shm_prefix_override: None,
            record: None,
        }
    }
}

/// Accepted `physics_dt`, s: below 1 us a real-time step cannot be kept, above 0.1 s no tensegrity
/// dynamics is resolved.
pub const PHYSICS_DT_RANGE: (f64, f64) = crate::scene::limits::PHYSICS_DT;
/// Accepted `real_time_factor` (0 = as fast as possible).
pub const REAL_TIME_FACTOR_RANGE: (f64, f64) = (0.0, 1e3);
/// Accepted `state_publish_rate`, Hz of sim time (0 = every step).
pub const PUBLISH_RATE_RANGE: (f64, f64) = (0.0, 1e6);
/// Accepted `markers_rate`, Hz of sim time (0 = off).
pub const MARKERS_RATE_RANGE: (f64, f64) = (0.0, 1e3);
/// Accepted `tolerance`, m (0 = fixed steps).
pub const TOLERANCE_RANGE: (f64, f64) = (0.0, 1.0);
/// Accepted `shm_spin_us`, microseconds.
pub const SHM_SPIN_RANGE: (f64, f64) = (0.0, 1e4);
/// Accepted `command_timeout`, s of sim time (0 = never).
pub const COMMAND_TIMEOUT_RANGE: (f64, f64) = (0.0, 1e6);

/// Every node parameter: name, default (as `-p name:=value` takes it), meaning. `tensegrity_node
/// --help` prints this table; a test sets each default through `NodeParams::set`.
pub const PARAMETERS: &[(&str, &str, &str)] = &[
    ("scene", "(bundled prism3)", "scene file, or bundled:NAME; also the first plain argument"),
    ("physics_dt", "(scene's, else 0.001)", "physics step, s, 1e-6 to 0.1"),
    ("real_time_factor", "1.0", "1 = real time, 0 = as fast as possible, at most 1000"),
    ("start_paused", "false", "start paused; advance with StepSimulation or unpause"),
    (
        "start_from_equilibrium",
        "false",
        "start and reset at rest in the static equilibrium, not the scene's pose",
    ),
    ("state_publish_rate", "100.0", "state messages per second of sim time, 0 = every step"),
    ("follow_schedule", "false", "follow the scene's deployment schedule instead of holding"),
    ("frame_id", "world", "fixed frame of poses and transforms"),
    ("integrator", "generalized-alpha", "generalized-alpha, symplectic-euler, rk4 or dormand-prince"),
    ("rho_inf", "0.8", "generalized-alpha spectral radius, 0 to 1"),
    ("tolerance", "0.0", "local error tolerance, m, 0 = fixed steps (generalized-alpha, dormand-prince)"),
    (
        "newton_tolerance",
        "1e-9",
        "generalized-alpha's Newton tolerance, relative to the forces, 1e-12 to 1e-3; looser is faster",
    ),
    ("markers_rate", "30.0", "RViz markers per second of sim time, 0 = off"),
    ("sensor_seed", "(scene's)", "seed of the scene's sensor noise, 0 to 2^64 - 1"),
    ("command_timeout", "0.0", "sim-time s without a command before the action, 0 = never"),
    ("command_timeout_action", "hold", "hold (winches stop) or initial (back to start)"),
    ("service_mapping", "enhanced", "enhanced (Fast DDS, RustDDS), cyclone or basic"),
    ("transports", "(every one built)", "dds, shm or dds,shm (shm alone opens no DDS socket)"),
    ("shm_spin_us", "200", "us the shm transport polls for the next request before blocking, 0 to 10000"),
    ("shm_prefix", "(<ns>/<node>)", "shared-memory service prefix, e.g. a unique one per parallel test"),
    (
        "record",
        "(off)",
        "record a rosbag2 bag (MCAP) of every topic and applied command into this new directory",
    ),
    ("use_sim_time", "false", "accepted and ignored (the node is the clock)"),
];

/// A parameter or argument that could not be used.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{0}")]
pub struct ParamError(pub String);

fn err(s: impl Into<String>) -> ParamError {
    ParamError(s.into())
}

impl NodeParams {
    /// The shared-memory service prefix: `shm_prefix` when set, else namespace and node name as
    /// in ROS (`<ns>/<node>`) without the leading slash: `tensegrity_sim` by default, `lab/sim2`
    /// for `-r __ns:=/lab -r __node:=sim2`.
    pub fn shm_prefix(&self) -> String {
        if let Some(prefix) = &self.shm_prefix_override {
            return prefix.clone();
        }
        let ns = self.namespace.trim_matches('/');
        if ns.is_empty() {
            self.node_name.clone()
        } else {
            format!("{ns}/{}", self.node_name)
        }
    }

    /// The namespace of the node's private (`~/`) topics: `<ns>/<node>` (`/tensegrity_sim`).
    pub fn private_namespace(&self) -> String {
        format!("{}/{}", self.namespace.trim_end_matches('/'), self.node_name)
    }

    /// Sets parameter `name` from its text `value` (YAML scalar syntax for booleans and numbers).
    pub fn set(&mut self, name: &str, value: &str) -> Result<(), ParamError> {
        let num = |v: &str| -> Result<f64, ParamError> {
            let x: f64 =
                v.trim().parse().map_err(|_| err(format!("parameter {name}: '{v}' is not a number")))?;
            if x.is_finite() {
                Ok(x)
            } else {
                Err(err(format!("parameter {name}: {v} is not finite")))
            }
        };
        let within = |x: f64, (lo, hi): (f64, f64)| {
            if (lo..=hi).contains(&x) {
                Ok(x)
            } else {
                Err(err(format!(
                    "parameter {name} must be in [{}, {}], got {}",
                    readable_number(lo),
                    readable_number(hi),
                    readable_number(x)
                )))
            }
        };
        let boolean = |v: &str| match v.trim().to_ascii_lowercase().as_str() {
            "true" | "1" | "yes" | "on" => Ok(true),
            "false" | "0" | "no" | "off" => Ok(false),
            _ => Err(err(format!("parameter {name}: '{v}' is not a boolean"))),
        };
        let text = |v: &str| v.trim().trim_matches('"').trim_matches('\'').to_string();
        match name {
            "scene" => self.scene = Some(PathBuf::from(text(value))),
            "physics_dt" => self.physics_dt = Some(within(num(value)?, PHYSICS_DT_RANGE)?),
            "real_time_factor" => self.real_time_factor = within(num(value)?, REAL_TIME_FACTOR_RANGE)?,
            "start_paused" => self.start_paused = boolean(value)?,
            "start_from_equilibrium" => self.start_from_equilibrium = boolean(value)?,
            "follow_schedule" => self.follow_schedule = boolean(value)?,
            "state_publish_rate" => self.state_publish_rate = within(num(value)?, PUBLISH_RATE_RANGE)?,
            "frame_id" => {
                let v = text(value);
                if v.is_empty() || v.len() > 256 {
                    return Err(err(format!("parameter frame_id must have 1 to 256 bytes, got {}", v.len())));
                }
                self.frame_id = v;
            }
            "integrator" => {
                let v = text(value);
                if crate::solve::dynamics::Integrator::parse(&v, self.rho_inf).is_none() {
                    let names = ["generalized-alpha", "symplectic-euler", "rk4", "dormand-prince"];
                    return Err(err(format!(
                        "parameter integrator: unknown '{v}'{}; the integrators: {}",
                        crate::error::did_you_mean(&v, names),
                        names.join(", ")
                    )));
                }
                self.integrator = v;
            }
            "rho_inf" => {
                let r = num(value)?;
                if !(0.0..=1.0).contains(&r) {
                    return Err(err(format!("parameter rho_inf must be in [0, 1], got {r}")));
                }
                self.rho_inf = r;
            }
            "tolerance" => self.tolerance = within(num(value)?, TOLERANCE_RANGE)?,
            "newton_tolerance" => {
                self.newton_tolerance = within(num(value)?, crate::solve::dynamics::NEWTON_TOLERANCE_RANGE)?
            }
            "markers_rate" => self.markers_rate = within(num(value)?, MARKERS_RATE_RANGE)?,
            "sensor_seed" => {
                let v = text(value);
                self.sensor_seed = Some(v.parse::<u64>().map_err(|_| {
                    err(format!("parameter sensor_seed: '{v}' is not an integer from 0 to 2^64 - 1"))
                })?);
            }
            "command_timeout" => self.command_timeout = within(num(value)?, COMMAND_TIMEOUT_RANGE)?,
            "command_timeout_action" => {
                let v = text(value).to_ascii_lowercase();
                if !matches!(v.as_str(), "hold" | "initial") {
                    return Err(err(format!(
                        "parameter command_timeout_action: '{v}' is not hold or initial"
                    )));
                }
                self.command_timeout_action = v;
            }
            "service_mapping" => {
                let v = text(value).to_ascii_lowercase();
                if !matches!(v.as_str(), "enhanced" | "cyclone" | "basic") {
                    return Err(err(format!(
                        "parameter service_mapping: '{v}' is not enhanced, cyclone or basic"
                    )));
                }
                self.service_mapping = v;
            }
            "transports" => self.transports = TransportKind::parse_list(&text(value))?,
            "shm_spin_us" => {
                let v = within(num(value)?, SHM_SPIN_RANGE)?;
                if v.fract() != 0.0 {
                    return Err(err(format!("parameter shm_spin_us must be a whole number, got {v}")));
                }
                self.shm_spin_us = v as u64;
            }
            "shm_prefix" => {
                let v = text(value);
                let ok = |c: char| c.is_ascii_alphanumeric() || matches!(c, '_' | '-' | '/');
                // a ROS name's leading slash is not part of the prefix (`/lab/sim` is `lab/sim`)
                let v = v.strip_prefix('/').map(str::to_string).unwrap_or(v);
                if v.is_empty() {
                    self.shm_prefix_override = None;
                } else if v.len() > 200 || !v.chars().all(ok) || v.starts_with('/') || v.ends_with('/') {
                    return Err(err(format!(
                        "parameter shm_prefix: '{}' must be 1 to 200 letters, digits, '_', '-' and '/' (a leading \
                         '/' is dropped, as in a ROS name; no trailing one)",
                        crate::io::commands::excerpt(&v, 60)
                    )));
                } else {
                    self.shm_prefix_override = Some(v);
                }
            }
            "record" => {
                let v = text(value);
                self.record = (!v.is_empty()).then(|| PathBuf::from(v));
            }
            "use_sim_time" => {}
            _ => {
                return Err(err(format!(
                    "unknown parameter '{name}'{}; tensegrity_node --help lists them",
                    crate::error::did_you_mean(name, PARAMETERS.iter().map(|(n, _, _)| *n))
                )))
            }
        }
        Ok(())
    }

    /// Reads a ROS 2 parameters file: a map from node name (or `/**`, or the namespaced name) to
    /// `ros__parameters`, whose entries are set in order. Entries for other nodes are ignored.
    pub fn load_params_file(&mut self, path: &Path) -> Result<(), ParamError> {
        let text = std::fs::read_to_string(path).map_err(|e| err(format!("{}: {e}", path.display())))?;
        let docs = yaml_rust2::YamlLoader::load_from_str(&text)
            .map_err(|e| err(format!("{}: not YAML: {e}", path.display())))?;
        let full = format!("{}/{}", self.namespace.trim_end_matches('/'), self.node_name);
        for doc in &docs {
            let Some(map) = doc.as_hash() else { continue };
            for (key, node) in map {
                let k = key.as_str().unwrap_or("");
                if !(k == "/**" || k == self.node_name || k == full || k == format!("/{}", self.node_name)) {
                    continue;
                }
                let Some(params) = node["ros__parameters"].as_hash() else {
                    return Err(err(format!("{}: {k}: missing ros__parameters", path.display())));
                };
                for (pk, pv) in params {
                    let name = pk
                        .as_str()
                        .ok_or_else(|| err(format!("{}: parameter names must be strings", path.display())))?;
                    let value = match pv {
                        yaml_rust2::Yaml::Real(s) | yaml_rust2::Yaml::String(s) => s.clone(),
                        yaml_rust2::Yaml::Integer(i) => i.to_string(),
                        yaml_rust2::Yaml::Boolean(b) => b.to_string(),
                        other => {
                            return Err(err(format!(
                                "{}: parameter {name}: unsupported value {other:?}",
                                path.display()
                            )))
                        }
                    };
                    self.set(name, &value).map_err(|e| err(format!("{}: {e}", path.display())))?;
                }
            }
        }
        Ok(())
    }

    /// Parameters from the program arguments (without the program name) and the environment
    /// (`env` looks a variable up). Returns the parameters and the arguments that were not part of
    /// a `--ros-args` section.
    pub fn from_args(
        args: &[String],
        env: impl Fn(&str) -> Option<String>,
    ) -> Result<(Self, Vec<String>), ParamError> {
        let mut p = Self::default();
        if let Some(d) = env("ROS_DOMAIN_ID").filter(|d| !d.trim().is_empty()) {
            p.domain_id = d
                .trim()
                .parse::<u16>()
                .ok()
                .filter(|d| *d <= 232)
                .ok_or_else(|| err(format!("ROS_DOMAIN_ID '{d}' is not a domain id (0-232)")))?;
        }
        p.localhost_only = env("ROS_LOCALHOST_ONLY").is_some_and(|v| v.trim() == "1")
            || env("ROS_AUTOMATIC_DISCOVERY_RANGE")
                .is_some_and(|v| v.trim().eq_ignore_ascii_case("LOCALHOST"));
        let mut rest = Vec::new();
        let mut files = Vec::new();
        let mut sets = Vec::new();
        let mut i = 0;
        let mut in_ros = false;
        while i < args.len() {
            let a = args[i].as_str();
            if !in_ros {
                if a == "--ros-args" {
                    in_ros = true;
                } else {
                    rest.push(args[i].clone());
                }
                i += 1;
                continue;
            }
            let value = |i: usize| args.get(i + 1).cloned().ok_or_else(|| err(format!("{a} needs a value")));
            match a {
                "--" => in_ros = false,
                "-p" | "--param" => {
                    let v = value(i)?;
                    let (k, val) = v
                        .split_once(":=")
                        .ok_or_else(|| err(format!("-p expects name:=value, got '{v}'")))?;
                    sets.push((k.to_string(), val.to_string()));
                    i += 1;
                }
                "--params-file" => {
                    files.push(PathBuf::from(value(i)?));
                    i += 1;
                }
                "-r" | "--remap" => {
                    let v = value(i)?;
                    match v.split_once(":=") {
                        Some(("__ns", ns)) => {
                            let bad = ns.trim_start_matches('/').split('/').find(|s| !ros_name_ok(s));
                            if let (Some(segment), false) = (bad, ns == "/") {
                                return Err(err(format!(
                                    "-r __ns:={ns}: namespace part '{segment}' is not a ROS name \
                                     ({ROS_NAME_RULE})"
                                )));
                            }
                            p.namespace = if ns.starts_with('/') { ns.to_string() } else { format!("/{ns}") };
                        }
                        Some(("__node", n)) | Some(("__name", n)) => {
                            if !ros_name_ok(n) {
                                return Err(err(format!(
                                    "-r __node:={n}: not a ROS node name ({ROS_NAME_RULE})"
                                )));
                            }
                            p.node_name = n.to_string();
                        }
                        _ => return Err(err(format!("unsupported remapping '{v}' (only __ns and __node)"))),
                    }
                    i += 1;
                }
                "--log-level" | "--enclave" => i += 1,
                "--ros-args" => {}
                other => return Err(err(format!("unsupported ROS argument '{other}'"))),
            }
            i += 1;
        }
        for f in files {
            p.load_params_file(&f)?;
        }
        for (k, v) in sets {
            p.set(&k, &v)?;
        }
        Ok((p, rest))
    }
}
