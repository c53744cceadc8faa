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

use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::mpsc::{self, Sender};
use std::sync::{Arc, Condvar, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use crate::io::node::params::{NodeParams, TransportKind};
use crate::io::node::{CoreError, NodeCore};
use crate::io::sink::NodeStats;
use crate::model::Model;
use mio::Waker;

mod error;
mod isolation;
mod snapshot;
mod transport;

pub use error::KitError;
pub use isolation::*;
pub use snapshot::*;
use transport::{KitTransport, Latest, Request, Shared};

/// Where the scene comes from.
enum SceneSource {
    Bundled(String),
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
    /// `config/scenes/`, with or without `.toml`; `scene::bundled`).
    pub fn bundled(name: &str) -> Self {
        Self::with(SceneSource::Bundled(name.to_string()))
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
            SceneSource::Bundled(name) => {
                crate::scene::bundled(&name).map_err(|e| KitError::Scene(e.to_string()))?
            }
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
        let kit =
            KitTransport { requests: inbox, shared: shared.clone(), stepping: None, names: names.clone() };
        let stop = Arc::new(AtomicBool::new(false));
        let (started, start_result) = mpsc::channel();
        let thread = {
            let (stop, shared, params) = (stop.clone(), shared.clone(), params.clone());
            std::thread::Builder::new()
                .name("tensegrity-sim".into())
                .spawn(move || run_node(model, params, kit, &stop, &shared, started))
                .map_err(|e| KitError::Transport(format!("node thread: {e}")))?
        };
        let mut sim = SimUnderTest {
            requests,
            shared,
            stop,
            thread: Some(thread),
            params,
            names,
            timeout: self.timeout,
            waker: None,
            _lease: lease,
        };
        match start_result.recv_timeout(self.timeout) {
            Ok(Ok(waker)) => sim.waker = waker,
            Ok(Err(e)) => return Err(e),
            Err(_) => return Err(KitError::Timeout(self.timeout, "the node to start".into())),
        }
        sim.wait_discoverable()?;
        Ok(sim)
    }
}

/// The node thread: builds the node (shared-memory ports stay on the thread that made them), says
/// whether it started, runs until stopped, and leaves its counters and fault in `shared`.
fn run_node(
    model: Model,
    params: NodeParams,
    kit: KitTransport,
    stop: &AtomicBool,
    shared: &Shared,
    started: Sender<Result<Option<Arc<Waker>>, KitError>>,
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
    let _ = started.send(Ok(node.waker()));
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
    /// Wakes the node's loop after each request (`SimNode::waker`; empty if it has none, and
    /// then it looks every `POLL_SLICE`).
    waker: Option<Arc<Waker>>,
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
        self.wake();
        match rx.recv_timeout(self.timeout) {
            Ok(answer) => answer,
            Err(mpsc::RecvTimeoutError::Timeout) => Err(KitError::Timeout(self.timeout, what.to_string())),
            Err(mpsc::RecvTimeoutError::Disconnected) => Err(KitError::Stopped),
        }
    }

    /// Sends one command; it applies at the next step boundary. A command the node refuses is an
    /// error with its reason (and counted as rejected, as on any transport).
    pub fn command(&self, command: Command) -> Result<(), KitError> {
        self.ask(|tx| Request::Command(command, tx), "a command's answer")
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
        self.ask(|tx| Request::Reset(None, tx), "reset")
    }

    /// `reset`, the new episode drawn from `seed`: a randomized scene's draws and the sensors'
    /// streams (`NodeCore::reset_seeded`). The same seed gives the same episode to the bit.
    pub fn reset_seeded(&self, seed: u64) -> Result<(), KitError> {
        self.ask(|tx| Request::Reset(Some(seed), tx), "reset")
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

    /// Wakes the node's loop (after a request, or to stop).
    fn wake(&self) {
        if let Some(w) = &self.waker {
            // a failed wake leaves the loop to look at its next due turn
            let _ = w.wake();
        }
    }

    fn halt(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        self.wake();
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
/// `~/structure` (`io::ros2::structure_received`): a controller started now finds the node.
#[cfg(feature = "ros2")]
fn dds_sees_structure(domain: u16, params: &NodeParams, timeout: Duration) -> Result<(), KitError> {
    match crate::io::ros2::structure_received(domain, params, timeout) {
        Ok(true) => Ok(()),
        Ok(false) => Err(KitError::Timeout(timeout, format!("~/structure on DDS domain {domain}"))),
        Err(why) => Err(KitError::Transport(why)),
    }
}
