//! A test kit for users' controllers: takes a scene (bundled name, file, text or a `Model`), node
//! parameters and the transports to serve (DDS, shared memory, or none), gives a running simulator
//! (`SimUnderTest`) that a launch-free integration test steps deterministically, reads and stops.
//!
//! ```no_run
//! use tensegrity::testing::{Command, SimBuilder};
//! let sim = SimBuilder::bundled("prism3").start().unwrap(); // paused: the test owns time
//! let before = sim.step(10).unwrap(); // 10 steps of the scene's dt, then the state
//! sim.command(Command::new("ring_winch").rest_length(0.99 * before.actuator_rest_length[0])).unwrap();
//! let after = sim.step(100).unwrap();
//! assert!(after.tension("ring").unwrap() > before.tension("ring").unwrap());
//! ```
//!
//! How it is isolated and deterministic:
//! - The node runs its usual loop (`runner::SimNode`) on a thread of the test process, with one
//!   more transport, the kit's own in-process channel, beside the ones asked for. Commands sent
//!   through the kit are checked by the same `NodeCore` code as DDS and shared-memory commands.
//! - By default it starts paused (`start_paused`): `step(n)` applies the commands sent before it at
//!   the next step boundary and takes exactly `n` steps, so results never depend on machine load
//!   (bit for bit: the physics has no thread-count, hash-order or wall-clock dependence).
//!   `real_time()` starts it playing at `real_time_factor` instead.
//! - DDS: a domain id is leased from 101..=232 (`DomainLease`, lock files shared by every process
//!   on the machine, the Python kit's too), so parallel tests do not hear each other; the node binds
//!   to 127.0.0.1 unless told otherwise. Shared memory is one per machine (not per network
//!   namespace): the kit gives every simulator its own service prefix (`shm_prefix`), and keeps the
//!   ROS names (`/tensegrity_sim/...`) so a controller under test needs no remapping.
//! - `start` returns once the node is discoverable: a DDS participant of the kit's own has
//!   received the transient-local `~/structure`, a shared-memory client has read the structure.
//! - Dropping the handle stops the node and waits for its thread (a bag being recorded is closed).
//!
//! A controller that talks DDS in lockstep: `step_awaiting_commands(n, k)` steps, then waits
//! until the node has received `k` more command messages (the controller's answer to the state it
//! was sent), so the next step sees them whatever the load.
//!
//! Network rule: `isolated_or_rerun(test)` runs the calling test again inside a private network
//! namespace whose only interface is loopback (`unshare`, `ip`), so a DDS test sends no packet off
//! the machine.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::mpsc::{self, Receiver, Sender};
use std::sync::{Arc, Condvar, Mutex, MutexGuard};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use crate::io::msg::{self, SimResult};
use crate::io::node::{result_code, CoreError, NodeCore, NodeSink, NodeStats, NodeView, PublishError, Topic};
use crate::io::params::{NodeParams, TransportKind};
use crate::io::runner::{Transport, With};
use crate::model::Model;

/// DDS domain ids the kit leases (`DomainLease`): above the ids our own tests use (61-78), up
/// to the largest whose ports fit (232).
pub const LEASED_DOMAINS: std::ops::RangeInclusive<u16> = 101..=232;

/// Why the kit could not start or serve a simulator.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum KitError {
    /// The scene could not be read or is invalid.
    #[error("scene: {0}")]
    Scene(String),
    /// A parameter is unknown, out of range or does not fit the scene.
    #[error("parameter: {0}")]
    Params(String),
    /// A transport could not start, or the node was not discoverable in time.
    #[error("transport: {0}")]
    Transport(String),
    /// The simulation could not start, or a step failed (the node then holds the last good state
    /// until `reset`).
    #[error("physics: {0}")]
    Physics(String),
    /// The node refused the request (a rejected command, stepping while playing), with its reason.
    #[error("refused: {0}")]
    Refused(String),
    /// No answer within the time allowed.
    #[error("timed out after {0:?} waiting for {1}")]
    Timeout(Duration, String),
    /// The node's loop is no longer running.
    #[error("the simulator has stopped")]
    Stopped,
}

// ----- network isolation ---------------------------------------------------------------------

/// Interfaces of this process's network namespace (from /proc, which is per namespace).
pub fn network_interfaces() -> Vec<String> {
    std::fs::read_to_string("/proc/self/net/dev")
        .unwrap_or_default()
        .lines()
        .skip(2)
        .filter_map(|l| l.split(':').next().map(|s| s.trim().to_string()))
        .collect()
}

/// True when this process's only network interface is loopback.
pub fn network_is_loopback_only() -> bool {
    let all = network_interfaces();
    !all.is_empty() && all.iter().all(|i| i == "lo")
}

/// Shell run by `unshare` inside the new namespace: loopback up, multicast on and routed to it
/// (DDS discovery), then the command.
const LOOPBACK_SETUP: &str = "ip link set lo up && ip link set lo multicast on && \
     { ip route add 224.0.0.0/4 dev lo 2>/dev/null || true; } && exec \"$@\"";

/// For a `#[test]` that opens DDS sockets: returns true when this process is already inside a
/// loopback-only network namespace (run the test body); otherwise runs this test executable again
/// with `--exact test --nocapture --test-threads=1` inside a new one (`unshare --net`, mapping
/// the user to root when not root; needs `unshare` and `ip`), panics if that run failed, and
/// returns false (return at once: the body ran in the child).
///
/// ```no_run
/// #[test]
/// fn my_controller_holds_the_ring() {
///     if !tensegrity::testing::isolated_or_rerun("my_controller_holds_the_ring") {
///         return;
///     }
///     // ... DDS traffic stays on this machine
/// }
/// ```
pub fn isolated_or_rerun(test: &str) -> bool {
    rerun_isolated(&["--exact", test, "--nocapture", "--test-threads=1"])
}

/// Like `isolated_or_rerun`, with the test executable's arguments given whole.
pub fn rerun_isolated(args: &[&str]) -> bool {
    if network_is_loopback_only() {
        return true;
    }
    assert!(
        std::env::var_os("TENSEGRITY_NETNS").is_none(),
        "still not isolated inside the namespace: {:?}",
        network_interfaces()
    );
    let exe = std::env::current_exe().expect("the test executable's path");
    let mut cmd = std::process::Command::new("unshare");
    cmd.arg("--net");
    if !is_root() {
        cmd.arg("--map-root-user");
    }
    let status = cmd
        .args(["--", "sh", "-c", LOOPBACK_SETUP, "loopback-net"])
        .arg(exe)
        .args(args)
        .env("TENSEGRITY_NETNS", "1")
        .status()
        .expect("unshare (util-linux) and ip (iproute2) are needed to isolate DDS tests");
    assert!(status.success(), "{args:?} failed inside its network namespace ({status})");
    false
}

fn is_root() -> bool {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines().find(|l| l.starts_with("Uid:")).map(|l| l.split_whitespace().nth(1) == Some("0"))
        })
        .unwrap_or(false)
}

// ----- DDS domain leases ---------------------------------------------------------------------

/// A DDS domain id held for one simulator: a lock file `<tmp>/tensegrity-dds-domains/<id>` holding
/// the owner's process id, created exclusively, removed on drop. A file whose process no longer
/// runs is taken over. Every process on the machine (the Rust kit, the Python kit) leases from the
/// same directory, so parallel tests never share a domain.
#[derive(Debug)]
pub struct DomainLease {
    id: u16,
    file: PathBuf,
}

static LEASE_SEQUENCE: AtomicU64 = AtomicU64::new(0);

impl DomainLease {
    /// The directory of the lock files.
    pub fn directory() -> PathBuf {
        std::env::temp_dir().join("tensegrity-dds-domains")
    }

    /// Leases a free id from `LEASED_DOMAINS`, starting at a place that depends on the process
    /// and the call, so parallel callers rarely contend.
    pub fn acquire() -> Result<Self, KitError> {
        let dir = Self::directory();
        std::fs::create_dir_all(&dir)
            .map_err(|e| KitError::Transport(format!("domain leases in {}: {e}", dir.display())))?;
        let (lo, hi) = (*LEASED_DOMAINS.start() as u64, *LEASED_DOMAINS.end() as u64);
        let span = hi - lo + 1;
        let first = (std::process::id() as u64 * 7 + LEASE_SEQUENCE.fetch_add(1, Ordering::Relaxed)) % span;
        for k in 0..span {
            let id = (lo + (first + k) % span) as u16;
            if let Some(lease) = Self::try_take(&dir, id) {
                return Ok(lease);
            }
        }
        Err(KitError::Transport(format!("every DDS domain id {lo}-{hi} is leased ({})", dir.display())))
    }

    /// Takes `id` if its file is absent or left by a process that has ended.
    fn try_take(dir: &Path, id: u16) -> Option<Self> {
        let file = dir.join(id.to_string());
        for _ in 0..2 {
            match std::fs::OpenOptions::new().write(true).create_new(true).open(&file) {
                Ok(mut f) => {
                    use std::io::Write;
                    f.write_all(std::process::id().to_string().as_bytes()).ok()?;
                    return Some(Self { id, file });
                }
                Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => {
                    let owner = std::fs::read_to_string(&file).ok()?;
                    let owner: u32 = owner.trim().parse().ok()?;
                    if Path::new(&format!("/proc/{owner}")).exists() {
                        return None;
                    }
                    // stale: its owner is gone (two takers race on create_new, one wins)
                    let _ = std::fs::remove_file(&file);
                }
                Err(_) => return None,
            }
        }
        None
    }

    /// The leased domain id.
    pub fn id(&self) -> u16 {
        self.id
    }
}

impl Drop for DomainLease {
    fn drop(&mut self) {
        let ours =
            std::fs::read_to_string(&self.file).is_ok_and(|s| s.trim() == std::process::id().to_string());
        if ours {
            let _ = std::fs::remove_file(&self.file);
        }
    }
}

// ----- snapshots and commands ------------------------------------------------------------------

/// Names of the scene's bodies, cables and actuators, in the order of a `Snapshot`'s arrays.
#[derive(Debug, Clone, PartialEq)]
pub struct Names {
    /// Scene name.
    pub scene: String,
    /// Body names.
    pub bodies: Vec<String>,
    /// Cable names.
    pub cables: Vec<String>,
    /// Actuator names.
    pub actuators: Vec<String>,
}

impl Names {
    fn of(model: &Model) -> Self {
        Self {
            scene: model.name.clone(),
            bodies: model.bodies.iter().map(|b| b.name.clone()).collect(),
            cables: model.cable_names.clone(),
            actuators: model.actuator_names.clone(),
        }
    }
}

/// The simulator's state after a step, as the node publishes it: SI units (m, N, m/s, s).
#[derive(Debug, Clone, PartialEq)]
pub struct Snapshot {
    /// The names behind the arrays.
    pub names: Arc<Names>,
    /// Simulation time, s.
    pub time: f64,
    /// Steps since the start or the last reset.
    pub step: u64,
    /// True while a physics failure holds the simulation (until `reset`).
    pub faulted: bool,
    /// Each body's position in the fixed frame, m.
    pub body_position: Vec<[f64; 3]>,
    /// Each body's orientation, unit quaternion `[x, y, z, w]`.
    pub body_orientation: Vec<[f64; 4]>,
    /// Each cable's tension, N (0 when slack).
    pub cable_tension: Vec<f64>,
    /// Each cable's length along its route, m.
    pub cable_length: Vec<f64>,
    /// Each cable's rest length, m.
    pub cable_rest_length: Vec<f64>,
    /// Each cable's slack flag.
    pub cable_slack: Vec<bool>,
    /// Each actuator's rest length (its cable's), m.
    pub actuator_rest_length: Vec<f64>,
    /// Each actuator's rest-length rate over the last step, m/s.
    pub actuator_rate: Vec<f64>,
    /// The node's counters at this state.
    pub stats: NodeStats,
}

impl Snapshot {
    fn empty(names: Arc<Names>) -> Self {
        Self {
            names,
            time: 0.0,
            step: 0,
            faulted: false,
            body_position: Vec::new(),
            body_orientation: Vec::new(),
            cable_tension: Vec::new(),
            cable_length: Vec::new(),
            cable_rest_length: Vec::new(),
            cable_slack: Vec::new(),
            actuator_rest_length: Vec::new(),
            actuator_rate: Vec::new(),
            stats: NodeStats::default(),
        }
    }

    /// The state `v` shows, named by `names`.
    fn of(names: Arc<Names>, v: &NodeView<'_>) -> Self {
        let mut s = Self::empty(names);
        s.fill(v);
        s
    }

    /// Copies `v` in, reusing this snapshot's buffers (no allocation once they have the size).
    fn fill(&mut self, v: &NodeView<'_>) {
        let (model, state, ws) = (v.model, v.state, v.workspace);
        self.time = state.time;
        self.step = v.step;
        self.faulted = v.faulted;
        self.stats = v.stats;
        self.body_position.clear();
        self.body_orientation.clear();
        for p in &state.poses {
            let q = p.rotation.quaternion();
            self.body_position.push([p.position.x, p.position.y, p.position.z]);
            self.body_orientation.push([q.i, q.j, q.k, q.w]);
        }
        self.cable_tension.clear();
        self.cable_length.clear();
        self.cable_rest_length.clear();
        self.cable_slack.clear();
        for c in &ws.cables {
            self.cable_tension.push(c.tension);
            self.cable_length.push(c.length);
            self.cable_rest_length.push(c.rest_length);
            self.cable_slack.push(c.slack);
        }
        self.actuator_rest_length.clear();
        self.actuator_rate.clear();
        for a in &model.actuators {
            self.actuator_rest_length.push(state.rest_lengths[a.cable.0]);
            self.actuator_rate.push(v.rates[a.cable.0]);
        }
    }

    /// The index of cable `name`.
    pub fn cable_index(&self, name: &str) -> Option<usize> {
        self.names.cables.iter().position(|c| c == name)
    }
    /// The index of actuator `name`.
    pub fn actuator_index(&self, name: &str) -> Option<usize> {
        self.names.actuators.iter().position(|a| a == name)
    }
    /// The index of body `name`.
    pub fn body_index(&self, name: &str) -> Option<usize> {
        self.names.bodies.iter().position(|b| b == name)
    }
    /// Tension of cable `name`, N.
    pub fn tension(&self, name: &str) -> Option<f64> {
        self.cable_index(name).map(|i| self.cable_tension[i])
    }
    /// Rest length of actuator `name`, m.
    pub fn rest_length(&self, actuator: &str) -> Option<f64> {
        self.actuator_index(actuator).map(|i| self.actuator_rest_length[i])
    }
    /// Position of body `name`, m.
    pub fn position(&self, body: &str) -> Option<[f64; 3]> {
        self.body_index(body).map(|i| self.body_position[i])
    }
}

/// One actuator command: a target rest length (m) and/or a rate (m/s), checked by the node exactly
/// like a DDS `~/actuator_commands` message (finite, within the actuator's limits, known name).
#[derive(Debug, Clone, PartialEq)]
pub struct Command {
    /// Actuator name.
    pub actuator: String,
    /// Target rest length, m.
    pub rest_length: Option<f64>,
    /// Rate, m/s (towards the target, or a steady rate without one).
    pub rate: Option<f64>,
}

impl Command {
    /// A command for actuator `name` that changes nothing yet.
    pub fn new(actuator: &str) -> Self {
        Self { actuator: actuator.to_string(), rest_length: None, rate: None }
    }
    /// With a target rest length, m.
    pub fn rest_length(mut self, metres: f64) -> Self {
        self.rest_length = Some(metres);
        self
    }
    /// With a rate, m/s.
    pub fn rate(mut self, metres_per_second: f64) -> Self {
        self.rate = Some(metres_per_second);
        self
    }
    /// The command as the DDS message carries it.
    pub fn message(&self) -> msg::ActuatorCommand {
        msg::ActuatorCommand {
            name: vec![self.actuator.clone()],
            rest_length: self.rest_length.into_iter().collect(),
            rate: self.rate.into_iter().collect(),
            ..Default::default()
        }
    }
}

// ----- the kit's own transport -----------------------------------------------------------------

/// What a test asks of the node, with where to answer.
enum Request {
    Command(msg::ActuatorCommand, Sender<Result<(), KitError>>),
    Step(u64, Sender<Result<Snapshot, KitError>>),
    Pause(bool, Sender<Result<(), KitError>>),
    Reset(Sender<Result<(), KitError>>),
}

/// What the node thread shares with the handle: the latest state and the counters.
struct Shared {
    latest: Mutex<Latest>,
    changed: Condvar,
}

struct Latest {
    snapshot: Snapshot,
    stats: NodeStats,
    /// The fault the node ended in (set when its loop has stopped).
    fault: Option<String>,
    running: bool,
}

impl Shared {
    fn lock(&self) -> MutexGuard<'_, Latest> {
        self.latest.lock().unwrap_or_else(|p| p.into_inner())
    }
}

/// The kit's in-process transport: requests in through a channel, state out into `Shared`.
struct KitTransport {
    requests: Receiver<Request>,
    /// A request `wait` received before `take_inputs` ran.
    early: Option<Request>,
    shared: Arc<Shared>,
    /// The StepSimulation ticket under way and where to answer it.
    stepping: Option<(u64, Sender<Result<Snapshot, KitError>>)>,
    names: Arc<Names>,
    /// True when shared memory is served too: the loop blocks on its event (so that
    /// controllers' requests wake it at once) and the kit, which wakes it through that event
    /// (`NodeWaker`), is polled.
    woken_through_shm: bool,
}

impl NodeSink for KitTransport {
    fn publish(&mut self, topic: Topic, view: &NodeView<'_>) -> Result<(), PublishError> {
        if topic == Topic::State {
            let mut l = self.shared.lock();
            l.snapshot.fill(view);
            l.stats = view.stats;
            drop(l);
            self.shared.changed.notify_all();
        }
        Ok(())
    }

    fn step_request_done(&mut self, ticket: u64, result: SimResult, view: &NodeView<'_>) {
        let Some((ours, _)) = &self.stepping else { return };
        if *ours != ticket {
            return;
        }
        let (_, reply) = self.stepping.take().expect("checked above");
        let answer = if result.result == result_code::OK {
            Ok(Snapshot::of(self.names.clone(), view))
        } else if view.faulted {
            Err(KitError::Physics(result.error_message))
        } else {
            Err(KitError::Refused(result.error_message))
        };
        let _ = reply.send(answer);
    }
}

impl KitTransport {
    fn serve(&mut self, request: Request, core: &mut NodeCore, others: &mut dyn NodeSink) {
        match request {
            Request::Command(m, reply) => {
                let r = core.offer_parsed(|model, out| {
                    msg::check_command(model, &m.header.frame_id, &m.name, &m.rest_length, &m.rate, out)
                });
                let _ = reply.send(r.map_err(|e| KitError::Refused(e.to_string())));
            }
            Request::Step(steps, reply) => {
                self.stepping = None;
                let mut sink = With { own: self, others };
                match core.request_steps(steps, &mut sink) {
                    Ok(ticket) => {
                        if steps == 0 {
                            let _ = reply.send(Ok(Snapshot::of(self.names.clone(), &core.view())));
                        } else {
                            self.stepping = Some((ticket, reply));
                        }
                    }
                    Err(r) => {
                        let e = if core.fault().is_some() {
                            KitError::Physics(r.error_message)
                        } else {
                            KitError::Refused(r.error_message)
                        };
                        let _ = reply.send(Err(e));
                    }
                }
            }
            Request::Pause(paused, reply) => {
                core.set_paused(paused, &mut With { own: self, others });
                let _ = reply.send(Ok(()));
            }
            Request::Reset(reply) => {
                core.reset(&mut With { own: self, others });
                let _ = reply.send(Ok(()));
            }
        }
    }
}

impl Transport for KitTransport {
    fn name(&self) -> &'static str {
        "kit"
    }

    fn take_inputs(&mut self, core: &mut NodeCore, others: &mut dyn NodeSink) {
        if let Some(r) = self.early.take() {
            self.serve(r, core, others);
        }
        while let Ok(r) = self.requests.try_recv() {
            self.serve(r, core, others);
        }
        // counters for `step_awaiting_commands` and `stats`, every turn
        let mut l = self.shared.lock();
        if l.stats != core.stats() {
            l.stats = core.stats();
            drop(l);
            self.shared.changed.notify_all();
        }
    }

    fn event_driven(&self) -> bool {
        !self.woken_through_shm
    }

    fn wait(&mut self, timeout: Duration) {
        if self.early.is_none() {
            self.early = self.requests.recv_timeout(timeout).ok();
        }
    }

    fn answering(&self) -> bool {
        self.stepping.is_some()
    }
}

// ----- the builder and the handle --------------------------------------------------------------

/// Where the scene comes from.
enum SceneSource {
    Path(PathBuf),
    Text(String, String),
    Model(Box<Model>),
}

/// How to start a simulator for a test (see the module docs). Defaults: paused (lockstep), no
/// transport but the kit's own, DDS bound to 127.0.0.1 on a leased domain when DDS is asked for.
pub struct SimBuilder {
    scene: SceneSource,
    settings: Vec<(String, String)>,
    transports: Vec<TransportKind>,
    real_time: bool,
    domain: Option<u16>,
    timeout: Duration,
    base: Option<NodeParams>,
}

static SHM_SEQUENCE: AtomicU64 = AtomicU64::new(0);

impl SimBuilder {
    fn with(scene: SceneSource) -> Self {
        Self {
            scene,
            settings: Vec::new(),
            transports: Vec::new(),
            real_time: false,
            domain: None,
            timeout: Duration::from_secs(20),
            base: None,
        }
    }

    /// A scene bundled with the crate, by name (`prism3`, `tbar`, `atwood`, ...: the files of
    /// `config/scenes/`, with or without `.toml`).
    pub fn bundled(name: &str) -> Self {
        let file = if name.ends_with(".toml") { name.to_string() } else { format!("{name}.toml") };
        Self::scene_file(Path::new(env!("CARGO_MANIFEST_DIR")).join("config/scenes").join(file))
    }
    /// A scene file.
    pub fn scene_file(path: impl Into<PathBuf>) -> Self {
        Self::with(SceneSource::Path(path.into()))
    }
    /// A scene's TOML text; `label` names it in errors.
    pub fn scene_text(text: &str, label: &str) -> Self {
        Self::with(SceneSource::Text(text.to_string(), label.to_string()))
    }
    /// A model built in code (e.g. by `scene::generate`).
    pub fn model(model: Model) -> Self {
        Self::with(SceneSource::Model(Box::new(model)))
    }

    /// Sets node parameter `name` to `value`, as `-p name:=value` does (errors come from `start`).
    pub fn param(mut self, name: &str, value: &str) -> Self {
        self.settings.push((name.to_string(), value.to_string()));
        self
    }
    /// Serves these transports besides the kit's own (default none: the test talks to the node
    /// through this handle only).
    pub fn transports(mut self, transports: &[TransportKind]) -> Self {
        self.transports = transports.to_vec();
        self
    }
    /// Starts playing in real time (`real_time_factor`, default 1) instead of paused.
    pub fn real_time(mut self) -> Self {
        self.real_time = true;
        self
    }
    /// Uses DDS domain `id` instead of leasing one.
    pub fn domain(mut self, id: u16) -> Self {
        self.domain = Some(id);
        self
    }
    /// Starts from `params` as given instead of the kit's defaults: their transports, pause,
    /// DDS domain and shared-memory names are used as they are (no lease, no unique prefix); for
    /// tests that set the node up field by field. Later `param` calls still apply.
    pub fn node_params(mut self, params: NodeParams) -> Self {
        self.base = Some(params);
        self
    }
    /// How long `start` and each request wait for the node (default 20 s).
    pub fn timeout(mut self, timeout: Duration) -> Self {
        self.timeout = timeout;
        self
    }

    /// Builds the scene and the parameters, starts the node on a thread of its own and returns
    /// once every transport is up and discoverable.
    pub fn start(self) -> Result<SimUnderTest, KitError> {
        let model = match self.scene {
            SceneSource::Path(p) => crate::scene::load(&p).map_err(|e| KitError::Scene(e.to_string()))?,
            SceneSource::Text(t, label) => {
                crate::scene::from_toml(&t, &label).map_err(|e| KitError::Scene(e.to_string()))?
            }
            SceneSource::Model(m) => *m,
        };
        let given = self.base.is_some();
        let mut params = self.base.unwrap_or_else(|| NodeParams {
            start_paused: !self.real_time,
            transports: self.transports.clone(),
            localhost_only: true,
            ..NodeParams::default()
        });
        for (name, value) in &self.settings {
            params.set(name, value).map_err(|e| KitError::Params(e.to_string()))?;
        }
        // a `param("transports", ..)` given after `transports(..)` wins, like any other parameter
        let lease = if given {
            None
        } else {
            let dds = params.transports.contains(&TransportKind::Dds);
            let lease = match (dds, self.domain) {
                (true, None) => Some(DomainLease::acquire()?),
                _ => None,
            };
            if let Some(id) = self.domain.or(lease.as_ref().map(DomainLease::id)) {
                params.domain_id = id;
            }
            if params.transports.contains(&TransportKind::Shm) && params.shm_prefix_override.is_none() {
                let n = SHM_SEQUENCE.fetch_add(1, Ordering::Relaxed);
                params.shm_prefix_override =
                    Some(format!("{}_kit{}_{n}", params.shm_prefix(), std::process::id()));
            }
            lease
        };
        let names = Arc::new(Names::of(&model));
        let shared = Arc::new(Shared {
            latest: Mutex::new(Latest {
                snapshot: Snapshot::empty(names.clone()),
                stats: NodeStats::default(),
                fault: None,
                running: true,
            }),
            changed: Condvar::new(),
        });
        let (requests, inbox) = mpsc::channel();
        let kit = KitTransport {
            requests: inbox,
            early: None,
            shared: shared.clone(),
            stepping: None,
            names: names.clone(),
            woken_through_shm: cfg!(feature = "shm") && params.transports.contains(&TransportKind::Shm),
        };
        let stop = Arc::new(AtomicBool::new(false));
        let (started, start_result) = mpsc::channel();
        let thread = {
            let (stop, shared, params) = (stop.clone(), shared.clone(), params.clone());
            std::thread::Builder::new()
                .name("tensegrity-sim".into())
                .spawn(move || run_node(model, params, kit, &stop, &shared, started))
                .map_err(|e| KitError::Transport(format!("node thread: {e}")))?
        };
        #[cfg_attr(not(feature = "shm"), allow(unused_mut))]
        let mut sim = SimUnderTest {
            requests,
            shared,
            stop,
            thread: Some(thread),
            params,
            names,
            timeout: self.timeout,
            #[cfg(feature = "shm")]
            waker: None,
            _lease: lease,
        };
        match start_result.recv_timeout(self.timeout) {
            Ok(Ok(())) => {}
            Ok(Err(e)) => return Err(e),
            Err(_) => return Err(KitError::Timeout(self.timeout, "the node to start".into())),
        }
        sim.wait_discoverable()?;
        #[cfg(feature = "shm")]
        if let Some(prefix) = sim.shm_prefix() {
            let waker = crate::io::shm::NodeWaker::open(&prefix)
                .map_err(|e| KitError::Transport(format!("shared memory: {e}")))?;
            sim.waker = Some(waker);
        }
        Ok(sim)
    }
}

/// The node thread: builds the node (iceoryx2 ports stay on the thread that made them), says
/// whether it started, runs until stopped, and leaves its counters and fault in `shared`.
fn run_node(
    model: Model,
    params: NodeParams,
    kit: KitTransport,
    stop: &AtomicBool,
    shared: &Shared,
    started: Sender<Result<(), KitError>>,
) {
    let core = match NodeCore::new(model, params) {
        Ok(core) => core,
        Err(CoreError::Params(why)) => {
            let _ = started.send(Err(KitError::Params(why)));
            return;
        }
        Err(e) => {
            let _ = started.send(Err(KitError::Physics(e.to_string())));
            return;
        }
    };
    let mut node = match crate::io::launch_core_with(core, vec![Box::new(kit)]) {
        Ok(node) => node,
        Err(e) => {
            let _ = started.send(Err(KitError::Transport(e.to_string())));
            return;
        }
    };
    let _ = started.send(Ok(()));
    node.run(stop);
    let mut l = shared.lock();
    l.stats = node.stats();
    l.fault = node.core().fault().map(str::to_string);
    l.running = false;
    drop(l);
    shared.changed.notify_all();
}

/// What `SimUnderTest::stop` reports.
#[derive(Debug, Clone, PartialEq)]
pub struct Finished {
    /// The node's counters at the end.
    pub stats: NodeStats,
    /// The physics failure that held the simulation when it stopped, if any.
    pub fault: Option<String>,
}

/// A simulator running for a test (see the module docs); stops on drop.
pub struct SimUnderTest {
    requests: Sender<Request>,
    shared: Arc<Shared>,
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
    params: NodeParams,
    names: Arc<Names>,
    timeout: Duration,
    /// Wakes the node after each request when it blocks on shared memory's event.
    #[cfg(feature = "shm")]
    waker: Option<crate::io::shm::NodeWaker>,
    _lease: Option<DomainLease>,
}

impl SimUnderTest {
    /// The node's parameters as it runs (domain id, shared-memory prefix, ...).
    pub fn params(&self) -> &NodeParams {
        &self.params
    }
    /// The DDS domain id the node serves (when it serves DDS).
    pub fn domain_id(&self) -> Option<u16> {
        self.params.transports.contains(&TransportKind::Dds).then_some(self.params.domain_id)
    }
    /// The namespace of the node's private topics (`/tensegrity_sim`).
    pub fn private_namespace(&self) -> String {
        self.params.private_namespace()
    }
    /// The shared-memory service prefix (when it serves shared memory), for `ShmClient::connect`.
    pub fn shm_prefix(&self) -> Option<String> {
        self.params.transports.contains(&TransportKind::Shm).then(|| self.params.shm_prefix())
    }
    /// Names of bodies, cables and actuators, in array order.
    pub fn names(&self) -> &Names {
        &self.names
    }

    /// Sends `request` and waits for its answer.
    fn ask<T>(
        &self,
        make: impl FnOnce(Sender<Result<T, KitError>>) -> Request,
        what: &str,
    ) -> Result<T, KitError> {
        let (tx, rx) = mpsc::channel();
        self.requests.send(make(tx)).map_err(|_| KitError::Stopped)?;
        #[cfg(feature = "shm")]
        if let Some(waker) = &self.waker {
            waker.wake();
        }
        match rx.recv_timeout(self.timeout) {
            Ok(answer) => answer,
            Err(mpsc::RecvTimeoutError::Timeout) => Err(KitError::Timeout(self.timeout, what.to_string())),
            Err(mpsc::RecvTimeoutError::Disconnected) => Err(KitError::Stopped),
        }
    }

    /// Sends one command; it applies at the next step boundary. A command the node refuses is an
    /// error with its reason (and counted as rejected, as on any transport).
    pub fn command(&self, command: Command) -> Result<(), KitError> {
        let m = command.message();
        self.ask(|tx| Request::Command(m, tx), "a command's answer")
    }

    /// Lockstep (the node paused): takes exactly `steps` steps (after the commands sent before)
    /// and returns the state after them. Refused while playing; a physics failure is
    /// `KitError::Physics`.
    pub fn step(&self, steps: u64) -> Result<Snapshot, KitError> {
        self.ask(|tx| Request::Step(steps, tx), "the requested steps")
    }

    /// `command` for each of `commands`, then `step(steps)`.
    pub fn step_with(&self, commands: &[Command], steps: u64) -> Result<Snapshot, KitError> {
        for c in commands {
            self.command(c.clone())?;
        }
        self.step(steps)
    }

    /// Lockstep with a controller on another transport (DDS, shared memory): `step(steps)`, then
    /// waits until the node has received `commands` more command messages than before the step
    /// (the controller's answer to the state published at the last step). The next `step` then
    /// applies them first, whatever the machine's load.
    pub fn step_awaiting_commands(&self, steps: u64, commands: u64) -> Result<Snapshot, KitError> {
        let before = self.shared.lock().stats.commands_received;
        let snapshot = self.step(steps)?;
        self.wait_until(|l| l.stats.commands_received >= before + commands, "the controller's commands")?;
        Ok(snapshot)
    }

    /// Pauses (`true`) or resumes real-time play (`false`).
    pub fn set_paused(&self, paused: bool) -> Result<(), KitError> {
        self.ask(|tx| Request::Pause(paused, tx), "pause")
    }
    /// Back to the initial state and time (pending commands dropped, a fault cleared).
    pub fn reset(&self) -> Result<(), KitError> {
        self.ask(Request::Reset, "reset")
    }

    /// The latest state the node published (its initial state before any step).
    pub fn latest(&self) -> Snapshot {
        self.shared.lock().snapshot.clone()
    }

    /// Waits up to the timeout for a published state that satisfies `accept` (real-time play) and
    /// returns it.
    pub fn wait_for_state(&self, mut accept: impl FnMut(&Snapshot) -> bool) -> Result<Snapshot, KitError> {
        let mut found = None;
        self.wait_until(
            |l| {
                if accept(&l.snapshot) {
                    found = Some(l.snapshot.clone());
                }
                found.is_some()
            },
            "a state that satisfies the test",
        )?;
        Ok(found.expect("set when waited"))
    }

    /// The node's counters now.
    pub fn stats(&self) -> NodeStats {
        self.shared.lock().stats
    }

    /// Waits until `done` holds for the shared state, or the timeout passes, or the node stops.
    fn wait_until(&self, mut done: impl FnMut(&Latest) -> bool, what: &str) -> Result<(), KitError> {
        let start = Instant::now();
        let mut l = self.shared.lock();
        loop {
            if done(&l) {
                return Ok(());
            }
            if !l.running {
                return Err(KitError::Stopped);
            }
            let left = self.timeout.saturating_sub(start.elapsed());
            if left.is_zero() {
                return Err(KitError::Timeout(self.timeout, what.to_string()));
            }
            l = self.shared.changed.wait_timeout(l, left).unwrap_or_else(|p| p.into_inner()).0;
        }
    }

    /// Waits until the node is reachable on every transport it serves.
    fn wait_discoverable(&self) -> Result<(), KitError> {
        #[cfg(feature = "ros2")]
        if let Some(domain) = self.domain_id() {
            dds_sees_structure(domain, &self.params, self.timeout)?;
        }
        #[cfg(feature = "shm")]
        if let Some(prefix) = self.shm_prefix() {
            let client = crate::io::shm::ShmClient::connect(&prefix, self.timeout)
                .map_err(|e| KitError::Transport(format!("shared memory: {e}")))?;
            client.structure(self.timeout).map_err(|e| KitError::Transport(format!("shared memory: {e}")))?;
        }
        Ok(())
    }

    /// Stops the node, waits for its thread, and reports its counters and any fault it ended in.
    pub fn stop(mut self) -> Finished {
        self.halt();
        let l = self.shared.lock();
        Finished { stats: l.stats, fault: l.fault.clone() }
    }

    fn halt(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

impl std::fmt::Debug for SimUnderTest {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SimUnderTest")
            .field("scene", &self.names.scene)
            .field("transports", &self.params.transports)
            .field("domain_id", &self.domain_id())
            .field("shm_prefix", &self.shm_prefix())
            .finish()
    }
}

impl Drop for SimUnderTest {
    fn drop(&mut self) {
        self.halt();
    }
}

/// Waits until a participant of the kit's own on `domain` has received the node's transient-local
/// `~/structure`: a controller started now finds the node.
#[cfg(feature = "ros2")]
fn dds_sees_structure(domain: u16, params: &NodeParams, timeout: Duration) -> Result<(), KitError> {
    use crate::io::ros2::{context, qos};
    use ros2_client::{MessageTypeName, Name, NodeName, NodeOptions};
    let fail = |what: &str, e: String| KitError::Transport(format!("DDS readiness check ({what}): {e}"));
    let ctx = context(domain, params.localhost_only).map_err(|e| fail("participant", e.to_string()))?;
    let mut probe = ctx
        .new_node(
            NodeName::new("/", "tensegrity_kit_probe").map_err(|e| fail("name", format!("{e:?}")))?,
            NodeOptions::new(),
        )
        .map_err(|e| fail("node", format!("{e:?}")))?;
    let name = Name::new(&params.private_namespace(), "structure")
        .map_err(|e| fail("topic name", format!("{e:?}")))?;
    let topic = probe
        .create_topic(&name, MessageTypeName::new("tensegrity_msgs", "Structure"), &qos(1, true))
        .map_err(|e| fail("topic", format!("{e:?}")))?;
    let reader = probe
        .create_subscription::<msg::Structure>(&topic, None)
        .map_err(|e| fail("subscription", format!("{e:?}")))?;
    let start = Instant::now();
    while start.elapsed() < timeout {
        if let Ok(Some(_)) = reader.take() {
            return Ok(());
        }
        std::thread::sleep(Duration::from_millis(5));
    }
    Err(KitError::Timeout(timeout, format!("~/structure on DDS domain {domain}")))
}
