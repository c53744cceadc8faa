//! The shared-memory transport (feature `shm`, iceoryx2 0.10): takes `NodeParams` and the model,
//! gives `ShmTransport` (the node's zero-copy face in the node's loop, `io::runner`) and
//! `ShmClient` (a controller's side, in Rust); the payloads are fixed-size `#[repr(C)]` types
//! that the Python client (`python/tensegrity_testing/shm.py`) mirrors with `ctypes`.
//!
//! Services, named under the node's namespace and name like its ROS topics (`<ns>/<node>/...`
//! without the leading slash; `tensegrity_sim/...` by default):
//! - `state` (publish-subscribe, `StateSample`): one sample per published step (the node's
//!   `state_publish_rate`, every step when 0; in lockstep, as the steps are taken);
//! - `structure` (publish-subscribe, `StructureSample`, history 1): names and array order, for
//!   late joiners;
//! - `actuator_commands` (publish-subscribe, `CommandSample`): commands in, checked exactly like
//!   DDS commands (`msg::check_entry`: rejected whole, counted in `StateSample` and
//!   `/diagnostics`), applied at the next step boundary;
//! - `lockstep` (request-response, `LockstepRequest` -> `LockstepResponse`): commands plus a
//!   number of steps in, the state after those steps out; only while the node is paused (like
//!   StepSimulation), requests served one at a time in arrival order;
//! - events `to_node` (controllers notify after sending, and on asking for the structure) and `from_node` (the node notifies
//!   after each state sample, `EVENT_STATE`, and lockstep answer, `EVENT_RESPONSE`), so neither
//!   side busy-spins: after an answer each side polls for at most `NodeParams::shm_spin_us`
//!   (`ShmClient::set_spin`), yielding its core between polls, then blocks on its listener.
//!
//! Capacities (`MAX_BODIES`, `MAX_CABLES`, `MAX_ACTUATORS`, `NAME_BYTES`) are compile-time
//! constants checked against the scene at start-up. Dead iceoryx2 nodes (a controller or node
//! killed with SIGKILL) are cleaned up at start and every `CLEANUP_PERIOD`, so their ports do not
//! hold the service's slots. Only one node can serve a namespace: a second fails to start.

use std::mem::MaybeUninit;
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use iceoryx2::active_request::ActiveRequest;
use iceoryx2::port::client::Client;
use iceoryx2::port::listener::Listener;
use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::server::Server;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::port::update_connections::UpdateConnections;
use iceoryx2::prelude::*;
use iceoryx2::response::Response;
use iceoryx2::sample::Sample;

use crate::control::ActuatorCommand;
use crate::io::msg::{self, MessageError, SimResult};
use crate::io::node::{result_code, NodeCore, NodeSink, NodeView, PublishError, Topic};
use crate::io::params::NodeParams;
use crate::io::runner::{Transport, With};
use crate::model::{ActuatorId, Model};

/// Most bodies a scene may have on this transport.
pub const MAX_BODIES: usize = 256;
/// Most cables a scene may have on this transport.
pub const MAX_CABLES: usize = 1024;
/// Most actuators a scene may have on this transport (and entries in one command).
pub const MAX_ACTUATORS: usize = 256;
/// Bytes of a name field (UTF-8, NUL-terminated, so names have at most `NAME_BYTES - 1` bytes).
pub const NAME_BYTES: usize = 64;
/// Bytes of the message of a lockstep answer (UTF-8, NUL-terminated).
pub const MESSAGE_BYTES: usize = 256;
/// Most controllers (ports of other processes) on one service at a time.
pub const MAX_CONTROLLERS: usize = 16;
/// State samples a controller's subscriber keeps (the oldest is overwritten: a slow reader never
/// holds the node up).
pub const STATE_BUFFER: usize = 4;
/// Command samples the node's subscriber keeps (the oldest is overwritten in a flood).
pub const COMMAND_BUFFER: usize = 64;
/// Interval between dead-node cleanups while running.
pub const CLEANUP_PERIOD: Duration = Duration::from_secs(2);

/// `from_node` event: a state sample was published.
pub const EVENT_STATE: usize = 1;
/// `from_node` event: a lockstep request was answered.
pub const EVENT_RESPONSE: usize = 2;
/// `to_node` event: a command was sent.
pub const EVENT_COMMAND: usize = 1;
/// `to_node` event: a lockstep request was sent.
pub const EVENT_LOCKSTEP: usize = 2;
/// `to_node` event: a controller connected (the node hands it the structure).
pub const EVENT_HELLO: usize = 3;

/// `CommandEntry::actuator` value meaning "by name".
pub const BY_NAME: u32 = u32::MAX;
/// `CommandEntry::fields` bit: `rest_length` is given.
pub const FIELD_REST_LENGTH: u32 = 1;
/// `CommandEntry::fields` bit: `rate` is given.
pub const FIELD_RATE: u32 = 2;

/// The whole state after a step, in scene order (see `StructureSample` for the names). Only the
/// first `body_count`, `cable_count` and `actuator_count` entries of the arrays are meaningful;
/// the rest are zero.
#[derive(Debug, Clone, ZeroCopySend)]
#[repr(C)]
#[type_name("TensegrityState")]
pub struct StateSample {
    /// Simulation time, s.
    pub time: f64,
    /// Steps taken since the start or the last reset.
    pub step: u64,
    /// Wall-clock time this sample was written, ns since the Unix epoch (CLOCK_REALTIME; Python:
    /// `time.time_ns()`).
    pub published_ns: u64,
    /// Wall-clock time at which the newest commands (from any transport) took effect, the step
    /// boundary before the step they first act in, ns since the Unix epoch; 0 before the first.
    pub commands_applied_ns: u64,
    /// Command messages received from every transport (`= accepted + rejected`).
    pub commands_received: u64,
    /// Command messages accepted.
    pub commands_accepted: u64,
    /// Command messages rejected (each one whole).
    pub commands_rejected: u64,
    /// Steps that ended later than real-time pacing allowed.
    pub overruns: u64,
    /// Bodies in use.
    pub body_count: u32,
    /// Cables in use.
    pub cable_count: u32,
    /// Actuators in use.
    pub actuator_count: u32,
    /// `simulation_interfaces` state: 1 playing, 2 paused.
    pub simulation_state: u8,
    /// 1 while a physics failure holds the simulation paused (until reset).
    pub faulted: u8,
    /// Zero.
    pub reserved: [u8; 2],
    /// Body centres of mass, m, world frame.
    pub body_position: [[f64; 3]; MAX_BODIES],
    /// Body orientations, unit quaternions `[x, y, z, w]` (body to world, ROS order).
    pub body_orientation: [[f64; 4]; MAX_BODIES],
    /// Cable tensions, N.
    pub cable_tension: [f64; MAX_CABLES],
    /// Cable lengths (whole route), m.
    pub cable_length: [f64; MAX_CABLES],
    /// Cable rest lengths, m.
    pub cable_rest_length: [f64; MAX_CABLES],
    /// Actuator (winch) rest lengths, m: the rest length of the cable each drives.
    pub actuator_rest_length: [f64; MAX_ACTUATORS],
    /// Actuator rest-length rates over the last step, m/s.
    pub actuator_rate: [f64; MAX_ACTUATORS],
    /// Cable slack flags: 1 when the cable is not taut.
    pub cable_slack: [u8; MAX_CABLES],
}

/// Names and array order of the structure, published once (history 1) so late joiners get it.
#[derive(Debug, Clone, ZeroCopySend)]
#[repr(C)]
#[type_name("TensegrityStructure")]
pub struct StructureSample {
    /// The node's step (`physics_dt`), s.
    pub physics_dt: f64,
    /// Bodies in use.
    pub body_count: u32,
    /// Cables in use.
    pub cable_count: u32,
    /// Actuators in use.
    pub actuator_count: u32,
    /// Zero.
    pub reserved: u32,
    /// Scene name.
    pub scene_name: [u8; NAME_BYTES],
    /// Fixed frame of the poses.
    pub frame_id: [u8; NAME_BYTES],
    /// Body names, in `StateSample` order.
    pub body_names: [[u8; NAME_BYTES]; MAX_BODIES],
    /// Cable names, in `StateSample` order.
    pub cable_names: [[u8; NAME_BYTES]; MAX_CABLES],
    /// Actuator names, in `StateSample` order (and the indices `CommandEntry::actuator` takes).
    pub actuator_names: [[u8; NAME_BYTES]; MAX_ACTUATORS],
    /// The cable each actuator drives (index into the cable arrays).
    pub actuator_cable: [u32; MAX_ACTUATORS],
    /// Smallest rest length each actuator accepts, m.
    pub actuator_min_rest_length: [f64; MAX_ACTUATORS],
    /// Largest rest length each actuator accepts, m.
    pub actuator_max_rest_length: [f64; MAX_ACTUATORS],
    /// Largest rate each actuator accepts, m/s.
    pub actuator_max_rate: [f64; MAX_ACTUATORS],
}

/// One actuator command: a target rest length (reached at the given or the actuator's largest
/// rate), or a rate alone (the winch runs at it until told otherwise).
#[derive(Debug, Clone, Copy, ZeroCopySend)]
#[repr(C)]
#[type_name("TensegrityCommandEntry")]
pub struct CommandEntry {
    /// Actuator index (structure order), or `BY_NAME` to use `name`.
    pub actuator: u32,
    /// Which values are given: `FIELD_REST_LENGTH` | `FIELD_RATE`.
    pub fields: u32,
    /// Target rest length, m (when `FIELD_REST_LENGTH`).
    pub rest_length: f64,
    /// Rate, m/s (when `FIELD_RATE`): with a target, the speed towards it (positive); alone, the
    /// signed rate of change.
    pub rate: f64,
    /// Actuator name, UTF-8, NUL-terminated (when `actuator == BY_NAME`).
    pub name: [u8; NAME_BYTES],
}

impl CommandEntry {
    /// An entry for actuator `index` with nothing given yet.
    pub fn index(index: usize) -> Self {
        Self { actuator: index as u32, fields: 0, rest_length: 0.0, rate: 0.0, name: [0; NAME_BYTES] }
    }
    /// An entry for the actuator called `name` (cut to `NAME_BYTES - 1` bytes) with nothing given
    /// yet.
    pub fn named(name: &str) -> Self {
        let mut e = Self::index(0);
        e.actuator = BY_NAME;
        write_name(&mut e.name, name);
        e
    }
    /// With a target rest length, m.
    pub fn rest_length(mut self, rest_length: f64) -> Self {
        self.fields |= FIELD_REST_LENGTH;
        self.rest_length = rest_length;
        self
    }
    /// With a rate, m/s.
    pub fn rate(mut self, rate: f64) -> Self {
        self.fields |= FIELD_RATE;
        self.rate = rate;
        self
    }
}

/// A command message: the first `count` entries, applied together at the next step boundary or
/// rejected together.
#[derive(Debug, Clone, ZeroCopySend)]
#[repr(C)]
#[type_name("TensegrityCommand")]
pub struct CommandSample {
    /// Entries in use.
    pub count: u32,
    /// Zero.
    pub reserved: u32,
    /// The entries.
    pub entries: [CommandEntry; MAX_ACTUATORS],
}

/// Lockstep: apply `command` (if `command.count > 0`), take `steps` steps, answer the state.
#[derive(Debug, Clone, ZeroCopySend)]
#[repr(C)]
#[type_name("TensegrityLockstepRequest")]
pub struct LockstepRequest {
    /// Steps to take (0: only check and queue the command, answer the current state).
    pub steps: u64,
    /// Commands applied at the boundary before the first step.
    pub command: CommandSample,
}

/// The answer to a `LockstepRequest`.
#[derive(Debug, Clone, ZeroCopySend)]
#[repr(C)]
#[type_name("TensegrityLockstepResponse")]
pub struct LockstepResponse {
    /// `simulation_interfaces` result code: 1 OK, 3 incorrect state (not paused, or busy), 4
    /// failed (command rejected, physics failure, reset, shutdown).
    pub result: u8,
    /// Zero.
    pub reserved: [u8; 7],
    /// Steps taken for this request.
    pub steps_taken: u64,
    /// Why it failed (UTF-8, NUL-terminated); empty on success.
    pub message: [u8; MESSAGE_BYTES],
    /// The state after the steps taken.
    pub state: StateSample,
}

/// Writes `text` into a NUL-terminated fixed field, cut at a character boundary to fit.
pub fn write_name(field: &mut [u8], text: &str) {
    field.fill(0);
    let mut end = text.len().min(field.len().saturating_sub(1));
    while !text.is_char_boundary(end) {
        end -= 1;
    }
    field[..end].copy_from_slice(&text.as_bytes()[..end]);
}

/// The text of a NUL-terminated fixed field, or why it is not text.
pub fn read_name(field: &[u8]) -> Result<&str, MessageError> {
    let end = field.iter().position(|b| *b == 0).ok_or_else(|| {
        MessageError::Malformed(format!("a name field has no terminating NUL within {} bytes", field.len()))
    })?;
    std::str::from_utf8(&field[..end])
        .map_err(|_| MessageError::Malformed("a name field is not UTF-8".into()))
}

/// Wall-clock time, ns since the Unix epoch.
pub fn realtime_ns() -> u64 {
    SystemTime::now().duration_since(UNIX_EPOCH).map_or(0, |d| d.as_nanos() as u64)
}

/// Checks one command message (`count` entries) against `model` exactly like a DDS command:
/// sizes, then each entry's actuator (index in range, or a known name), duplicates and values
/// (`msg::check_entry`). Fills `out` on success.
pub fn check_command(
    model: &Model,
    cmd: &CommandSample,
    out: &mut Vec<(ActuatorId, ActuatorCommand)>,
) -> Result<(), MessageError> {
    let count = cmd.count as usize;
    if count > MAX_ACTUATORS {
        return Err(MessageError::TooLarge { what: "entry count", size: count, limit: MAX_ACTUATORS });
    }
    if count == 0 {
        return Err(MessageError::NoNames);
    }
    for e in &cmd.entries[..count] {
        let id = if e.actuator == BY_NAME {
            msg::actuator_by_name(model, read_name(&e.name)?)?
        } else if (e.actuator as usize) < model.actuators.len() {
            ActuatorId(e.actuator as usize)
        } else {
            return Err(MessageError::UnknownIndex {
                index: e.actuator.into(),
                count: model.actuators.len(),
            });
        };
        if e.fields & !(FIELD_REST_LENGTH | FIELD_RATE) != 0 {
            return Err(MessageError::Malformed(format!("unknown bits in fields: {:#x}", e.fields)));
        }
        let given = |bit: u32, v: f64| (e.fields & bit != 0).then_some(v);
        let c = ActuatorCommand {
            rest_length: given(FIELD_REST_LENGTH, e.rest_length),
            rate: given(FIELD_RATE, e.rate),
        };
        msg::check_entry(model, id, c, out)?;
    }
    Ok(())
}

/// Why the transport or a client could not start or act.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ShmError {
    /// The scene does not fit the payloads.
    #[error("the scene has {count} {what}, more than this build's shared-memory capacity {limit} ({constant} in src/io/shm.rs, mirrored in python/tensegrity_testing/shm.py); run it over DDS (-p transports:=dds) or raise the constant")]
    Capacity {
        /// What is counted.
        what: &'static str,
        /// How many the scene has.
        count: usize,
        /// The capacity.
        limit: usize,
        /// The constant to raise.
        constant: &'static str,
    },
    /// A name is longer than a name field holds.
    #[error("{what} '{name}' has {len} bytes, more than the {max} a shared-memory name field holds (NAME_BYTES - 1); shorten it or run over DDS (-p transports:=dds)")]
    NameTooLong {
        /// Which name.
        what: &'static str,
        /// The name.
        name: String,
        /// Its length in bytes.
        len: usize,
        /// The most a field holds.
        max: usize,
    },
    /// A command with more entries than a command message holds.
    #[error("a command has {0} entries, more than the {MAX_ACTUATORS} a message holds (MAX_ACTUATORS)")]
    TooManyEntries(usize),
    /// An iceoryx2 call failed (which, and its words).
    #[error("iceoryx2: {0}")]
    Ipc(String),
    /// Another live node serves the same namespace.
    #[error("another node already serves '{0}' (iceoryx2 {1}); give this one another namespace or name (-r __ns:=/NAME)")]
    Taken(String, String),
    /// The node did not answer in time.
    #[error("no answer from the node at '{0}' within {1:?}")]
    Timeout(String, Duration),
    /// The node refused a lockstep request.
    #[error("lockstep refused (code {code}): {message}")]
    Refused {
        /// `simulation_interfaces` result code.
        code: u8,
        /// The node's reason.
        message: String,
    },
}

fn ipc<E: std::fmt::Debug>(what: &str) -> impl FnOnce(E) -> ShmError + '_ {
    move |e| ShmError::Ipc(format!("{what}: {e:?}"))
}

/// Checks that `model` fits the payloads (counts and name lengths) and returns nothing or the
/// first limit it exceeds.
pub fn check_capacity(model: &Model, frame_id: &str) -> Result<(), ShmError> {
    let counts = [
        ("bodies", model.bodies.len(), MAX_BODIES, "MAX_BODIES"),
        ("cables", model.cables.len(), MAX_CABLES, "MAX_CABLES"),
        ("actuators", model.actuators.len(), MAX_ACTUATORS, "MAX_ACTUATORS"),
    ];
    for (what, count, limit, constant) in counts {
        if count > limit {
            return Err(ShmError::Capacity { what, count, limit, constant });
        }
    }
    let names = std::iter::once(("scene name", model.name.as_str()))
        .chain(std::iter::once(("frame_id", frame_id)))
        .chain(model.bodies.iter().map(|b| ("body name", b.name.as_str())))
        .chain(model.cable_names.iter().map(|n| ("cable name", n.as_str())))
        .chain(model.actuator_names.iter().map(|n| ("actuator name", n.as_str())));
    for (what, name) in names {
        if name.len() >= NAME_BYTES {
            let shown = msg::excerpt(name, msg::EXCERPT_CHARS);
            return Err(ShmError::NameTooLong { what, name: shown, len: name.len(), max: NAME_BYTES - 1 });
        }
    }
    Ok(())
}

/// The node's service names under a prefix (`NodeParams::shm_prefix`).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ServiceNames {
    /// `<prefix>/state`.
    pub state: String,
    /// `<prefix>/structure`.
    pub structure: String,
    /// `<prefix>/actuator_commands`.
    pub commands: String,
    /// `<prefix>/lockstep`.
    pub lockstep: String,
    /// `<prefix>/to_node` (event).
    pub to_node: String,
    /// `<prefix>/from_node` (event).
    pub from_node: String,
}

impl ServiceNames {
    /// The names under `prefix`.
    pub fn new(prefix: &str) -> Self {
        let n = |s: &str| format!("{prefix}/{s}");
        Self {
            state: n("state"),
            structure: n("structure"),
            commands: n("actuator_commands"),
            lockstep: n("lockstep"),
            to_node: n("to_node"),
            from_node: n("from_node"),
        }
    }
}

fn service_name(name: &str) -> Result<ServiceName, ShmError> {
    ServiceName::new(name).map_err(ipc("service name"))
}

fn new_node() -> Result<iceoryx2::node::Node<ipc::Service>, ShmError> {
    NodeBuilder::new()
        .signal_handling_mode(SignalHandlingMode::Disabled)
        .create::<ipc::Service>()
        .map_err(ipc("node"))
}

/// Fills `out` (all zero on entry) from `view`; `commands_applied_ns` as in `StateSample`.
fn fill_state(out: &mut StateSample, v: &NodeView<'_>, commands_applied_ns: u64) {
    let (model, state, ws) = (v.model, v.state, v.workspace);
    out.time = state.time;
    out.step = v.step;
    out.commands_applied_ns = commands_applied_ns;
    out.commands_received = v.stats.commands_received;
    out.commands_accepted = v.stats.commands_accepted;
    out.commands_rejected = v.stats.commands_rejected;
    out.overruns = v.stats.overruns;
    out.body_count = state.poses.len() as u32;
    out.cable_count = model.cables.len() as u32;
    out.actuator_count = model.actuators.len() as u32;
    out.simulation_state = v.simulation_state;
    out.faulted = u8::from(v.faulted);
    for (i, p) in state.poses.iter().enumerate() {
        let q = p.rotation.quaternion();
        out.body_position[i] = [p.position.x, p.position.y, p.position.z];
        out.body_orientation[i] = [q.i, q.j, q.k, q.w];
    }
    for (i, c) in ws.cables.iter().enumerate() {
        out.cable_tension[i] = c.tension;
        out.cable_length[i] = c.length;
        out.cable_rest_length[i] = c.rest_length;
        out.cable_slack[i] = u8::from(c.slack);
    }
    for (i, a) in model.actuators.iter().enumerate() {
        out.actuator_rest_length[i] = state.rest_lengths[a.cable.0];
        out.actuator_rate[i] = v.rates[a.cable.0];
    }
    out.published_ns = realtime_ns();
}

/// Payloads for which all-zero bytes are a valid value (integers, floats and arrays of them, no
/// references, enums or `bool`s), so `zeroed` may initialize them in place.
///
/// # Safety
/// Implement only for such types.
#[allow(unsafe_code)]
pub unsafe trait ZeroValid {}
// SAFETY (all five): `#[repr(C)]` structs of u8, u32, u64, f64 and arrays of them (CommandEntry too)
#[allow(unsafe_code)]
unsafe impl ZeroValid for StateSample {}
#[allow(unsafe_code)]
unsafe impl ZeroValid for StructureSample {}
#[allow(unsafe_code)]
unsafe impl ZeroValid for CommandSample {}
#[allow(unsafe_code)]
unsafe impl ZeroValid for LockstepRequest {}
#[allow(unsafe_code)]
unsafe impl ZeroValid for LockstepResponse {}

/// Zeroes a loaned payload in place (no copy through the stack) and returns it initialized.
#[allow(unsafe_code)]
fn zeroed<T: ZeroValid>(slot: &mut MaybeUninit<T>) -> &mut T {
    // SAFETY: all-zero bytes are a valid `T` (`ZeroValid`), and the pointer is the slot's own
    unsafe {
        std::ptr::write_bytes(slot.as_mut_ptr(), 0, 1);
        slot.assume_init_mut()
    }
}

type Svc = ipc::Service;
type Lockstep = ActiveRequest<Svc, LockstepRequest, (), LockstepResponse, ()>;

/// The node's shared-memory face: see the module docs.
pub struct ShmTransport {
    node: iceoryx2::node::Node<Svc>,
    prefix: String,
    state: Publisher<Svc, StateSample, ()>,
    structure: Publisher<Svc, StructureSample, ()>,
    commands: Subscriber<Svc, CommandSample, ()>,
    lockstep: Server<Svc, LockstepRequest, (), LockstepResponse, ()>,
    wake: Listener<Svc>,
    notify: Notifier<Svc>,
    /// Lockstep requests under way: the core's ticket, the request, the step index it started at.
    tickets: Vec<(u64, Lockstep, u64)>,
    /// The request being handed to the core (answered if the core answers at once), with the
    /// step index it starts at.
    incoming: Option<(Lockstep, u64)>,
    spin: Duration,
    spin_until: Option<Instant>,
    last_cleanup: Instant,
    commands_applied_ns: u64,
}

impl ShmTransport {
    /// Checks the scene against the capacities, removes what dead iceoryx2 nodes left behind,
    /// and opens the node's services under `prefix(params)`.
    pub fn new(model: &Model, params: &NodeParams) -> Result<Self, ShmError> {
        check_capacity(model, &params.frame_id)?;
        let prefix = params.shm_prefix();
        let names = ServiceNames::new(&prefix);
        let node = new_node()?;
        node.try_cleanup_dead_nodes();
        let taken = |e: String| ShmError::Taken(prefix.clone(), e);
        let state = node
            .service_builder(&service_name(&names.state)?)
            .publish_subscribe::<StateSample>()
            .max_publishers(1)
            .max_subscribers(MAX_CONTROLLERS)
            .subscriber_max_buffer_size(STATE_BUFFER)
            .subscriber_max_borrowed_samples(STATE_BUFFER)
            .history_size(0)
            .enable_safe_overflow(true)
            .open_or_create()
            .map_err(ipc("state service"))?;
        let structure = node
            .service_builder(&service_name(&names.structure)?)
            .publish_subscribe::<StructureSample>()
            .max_publishers(1)
            .max_subscribers(MAX_CONTROLLERS)
            .subscriber_max_buffer_size(1)
            .subscriber_max_borrowed_samples(1)
            .history_size(1)
            .enable_safe_overflow(true)
            .open_or_create()
            .map_err(ipc("structure service"))?;
        let commands = node
            .service_builder(&service_name(&names.commands)?)
            .publish_subscribe::<CommandSample>()
            .max_publishers(MAX_CONTROLLERS)
            .max_subscribers(1)
            .subscriber_max_buffer_size(COMMAND_BUFFER)
            .history_size(0)
            .enable_safe_overflow(true)
            .open_or_create()
            .map_err(ipc("actuator_commands service"))?;
        let lockstep = node
            .service_builder(&service_name(&names.lockstep)?)
            .request_response::<LockstepRequest, LockstepResponse>()
            .max_servers(1)
            .max_clients(MAX_CONTROLLERS)
            .max_active_requests_per_client(2)
            .max_response_buffer_size(2)
            .open_or_create()
            .map_err(ipc("lockstep service"))?;
        let to_node = node
            .service_builder(&service_name(&names.to_node)?)
            .event()
            .max_listeners(1)
            .max_notifiers(2 * MAX_CONTROLLERS)
            .open_or_create()
            .map_err(ipc("to_node event"))?;
        let from_node = node
            .service_builder(&service_name(&names.from_node)?)
            .event()
            .max_notifiers(1)
            .max_listeners(2 * MAX_CONTROLLERS)
            .open_or_create()
            .map_err(ipc("from_node event"))?;
        // the single-owner ports: a second live node on the same prefix fails here
        let state_publisher = state.publisher_builder().create().map_err(|e| taken(format!("{e:?}")))?;
        let structure = structure.publisher_builder().create().map_err(|e| taken(format!("{e:?}")))?;
        let commands = commands.subscriber_builder().create().map_err(|e| taken(format!("{e:?}")))?;
        let lockstep = lockstep.server_builder().create().map_err(|e| taken(format!("{e:?}")))?;
        let wake = to_node.listener_builder().create().map_err(|e| taken(format!("{e:?}")))?;
        let notify = from_node.notifier_builder().create().map_err(|e| taken(format!("{e:?}")))?;
        Ok(Self {
            node,
            prefix,
            state: state_publisher,
            structure,
            commands,
            lockstep,
            wake,
            notify,
            tickets: Vec::new(),
            incoming: None,
            spin: Duration::from_micros(params.shm_spin_us),
            spin_until: None,
            last_cleanup: Instant::now(),
            commands_applied_ns: 0,
        })
    }

    /// The service prefix (`tensegrity_sim` by default).
    pub fn prefix(&self) -> &str {
        &self.prefix
    }

    fn publish_state(&mut self, v: &NodeView<'_>) -> Result<(), PublishError> {
        let mut sample =
            self.state.loan_uninit().map_err(|e| PublishError::Failed(format!("state: {e:?}")))?;
        fill_state(zeroed(sample.payload_mut()), v, self.commands_applied_ns);
        // SAFETY: `zeroed` initialized the whole payload
        #[allow(unsafe_code)]
        let sample = unsafe { sample.assume_init() };
        sample.send().map_err(|e| PublishError::Failed(format!("state: {e:?}")))?;
        let _ = self.notify.notify_with_custom_event_id(EventId::new(EVENT_STATE));
        Ok(())
    }

    fn publish_structure(&mut self, v: &NodeView<'_>) -> Result<(), PublishError> {
        let fail = |e: String| PublishError::Failed(format!("structure: {e}"));
        let mut sample = self.structure.loan_uninit().map_err(|e| fail(format!("{e:?}")))?;
        let s = zeroed(sample.payload_mut());
        let m = v.model;
        s.physics_dt = v.dt;
        s.body_count = m.bodies.len() as u32;
        s.cable_count = m.cables.len() as u32;
        s.actuator_count = m.actuators.len() as u32;
        write_name(&mut s.scene_name, &m.name);
        write_name(&mut s.frame_id, v.frame_id);
        for (i, b) in m.bodies.iter().enumerate() {
            write_name(&mut s.body_names[i], &b.name);
        }
        for (i, n) in m.cable_names.iter().enumerate() {
            write_name(&mut s.cable_names[i], n);
        }
        for (i, a) in m.actuators.iter().enumerate() {
            write_name(&mut s.actuator_names[i], &m.actuator_names[i]);
            s.actuator_cable[i] = a.cable.0 as u32;
            s.actuator_min_rest_length[i] = a.min_rest_length;
            s.actuator_max_rest_length[i] = a.max_rest_length;
            s.actuator_max_rate[i] = a.max_rate;
        }
        // SAFETY: `zeroed` initialized the whole payload
        #[allow(unsafe_code)]
        let sample = unsafe { sample.assume_init() };
        sample.send().map_err(|e| fail(format!("{e:?}")))?;
        Ok(())
    }

    /// Answers a lockstep request with `result` and the state in `view`.
    fn answer(&mut self, request: Lockstep, result: &SimResult, steps_taken: u64, view: &NodeView<'_>) {
        if let Ok(mut response) = request.loan_uninit() {
            let r = zeroed(response.payload_mut());
            r.result = result.result;
            r.steps_taken = steps_taken;
            write_name(&mut r.message, &result.error_message);
            fill_state(&mut r.state, view, self.commands_applied_ns);
            // SAFETY: `zeroed` initialized the whole payload
            #[allow(unsafe_code)]
            let response = unsafe { response.assume_init() };
            // a controller that went away cannot be answered; nothing to do about it
            let _ = response.send();
        }
        let _ = self.notify.notify_with_custom_event_id(EventId::new(EVENT_RESPONSE));
        self.spin_until = Some(Instant::now() + self.spin);
    }

    /// True when a command or a lockstep request waits (for the spin before blocking).
    fn input_waiting(&self) -> bool {
        self.commands.has_samples().unwrap_or(false) || self.lockstep.has_requests().unwrap_or(false)
    }

    /// Takes the next lockstep request if none is under way: its command is checked like any
    /// other (a rejected one fails the request, no step is taken), then the steps are queued.
    fn take_lockstep(&mut self, core: &mut NodeCore, others: &mut dyn NodeSink) {
        if !self.tickets.is_empty() || core.steps_remaining() > 0 {
            return; // one at a time; the rest wait in the service's queue
        }
        let request = match self.lockstep.receive() {
            Ok(Some(r)) => r,
            Ok(None) => return,
            Err(_) => return core.incoming_malformed(),
        };
        let steps = request.payload().steps;
        if request.payload().command.count > 0 {
            let command = &request.payload().command;
            let parsed = core.offer_parsed(|model, out| check_command(model, command, out));
            if let Err(e) = parsed {
                let result = SimResult::err(result_code::OPERATION_FAILED, format!("command rejected: {e}"));
                let view = core.view();
                return self.answer(request, &result, 0, &view);
            }
        }
        self.incoming = Some((request, core.view().step));
        let outcome = core.request_steps(steps, &mut With { own: &mut *self, others });
        match (outcome, self.incoming.take()) {
            (Ok(ticket), Some((request, start))) => self.tickets.push((ticket, request, start)),
            (Err(result), Some((request, _))) => {
                let view = core.view();
                self.answer(request, &result, 0, &view);
            }
            // answered at once (0 steps)
            (_, None) => {}
        }
    }
}

impl NodeSink for ShmTransport {
    fn publish(&mut self, topic: Topic, v: &NodeView<'_>) -> Result<(), PublishError> {
        match topic {
            Topic::State => self.publish_state(v),
            Topic::Structure => self.publish_structure(v),
            // the others are DDS's (clock, transforms, diagnostics, markers) or carried in State
            _ => Ok(()),
        }
    }

    fn step_request_done(&mut self, ticket: u64, result: SimResult, view: &NodeView<'_>) {
        let request = match self.tickets.iter().position(|(t, _, _)| *t == ticket) {
            Some(k) => {
                let (_, request, start) = self.tickets.swap_remove(k);
                Some((request, start))
            }
            // the request being handed over, answered at once
            None => self.incoming.take(),
        };
        if let Some((request, start)) = request {
            self.answer(request, &result, view.step.saturating_sub(start), view);
        }
    }

    fn commands_applied(&mut self, _time: f64, _step: u64, _commands: &[(ActuatorId, ActuatorCommand)]) {
        self.commands_applied_ns = realtime_ns();
    }
}

impl Transport for ShmTransport {
    fn name(&self) -> &'static str {
        "shm"
    }

    fn take_inputs(&mut self, core: &mut NodeCore, others: &mut dyn NodeSink) {
        while core.wants_commands() {
            match self.commands.receive() {
                Ok(Some(sample)) => {
                    // counted and reported by the core (StateSample::commands_rejected, /diagnostics)
                    let _ = core.offer_parsed(|model, out| check_command(model, sample.payload(), out));
                }
                Ok(None) => break,
                Err(_) => {
                    core.incoming_malformed();
                    break;
                }
            }
        }
        self.take_lockstep(core, others);
        // hand the structure (history 1) to controllers that connected since the last turn
        let _ = self.structure.update_connections();
        if self.last_cleanup.elapsed() >= CLEANUP_PERIOD {
            self.node.try_cleanup_dead_nodes();
            self.last_cleanup = Instant::now();
        }
    }

    fn event_driven(&self) -> bool {
        true
    }

    fn wait(&mut self, timeout: Duration) {
        let deadline = Instant::now() + timeout;
        if let Some(until) = self.spin_until.take() {
            if poll(until.min(deadline), || self.input_waiting()) {
                return;
            }
        }
        let left = deadline.saturating_duration_since(Instant::now());
        if !left.is_zero() {
            // the events only wake; what arrived is read from the services
            let _ = self.wake.timed_wait(|_| {}, left);
        }
    }

    fn answering(&self) -> bool {
        !self.tickets.is_empty()
    }
}

/// Polls `ready` until it returns true (then true) or `until` passes (then false), yielding the
/// core between polls, so a thread waiting for this core (the node or the controller, on a busy
/// or pinned machine) runs at once. Spinning instead held the other side off until the spin
/// ended (440 us lockstep round trips on one core); yielding costs a one-step round trip on
/// prism3 about 4 us, and spinning 20 us before yielding was slower still (README).
fn poll(until: Instant, mut ready: impl FnMut() -> bool) -> bool {
    while Instant::now() < until {
        if ready() {
            return true;
        }
        std::thread::yield_now();
    }
    false
}

// ----- the controller's side -------------------------------------------------------------------

/// The structure as a controller reads it (owned).
#[derive(Debug, Clone, PartialEq)]
pub struct Structure {
    /// Scene name.
    pub scene_name: String,
    /// The node's step, s.
    pub physics_dt: f64,
    /// Body names.
    pub body_names: Vec<String>,
    /// Cable names.
    pub cable_names: Vec<String>,
    /// Actuator names (their indices are what `CommandEntry::index` takes).
    pub actuator_names: Vec<String>,
    /// The cable each actuator drives.
    pub actuator_cable: Vec<usize>,
}

/// Wakes a node that blocks on its `to_node` event, for inputs that arrive by another way: an
/// in-process transport served beside shared memory (the test kit's), which the node then polls
/// on the turn the event starts. Its ports are iceoryx2's thread-safe variant, so the waker can
/// be moved between threads; it notifies the same event service as `ShmClient` does.
pub struct NodeWaker {
    // fields drop in order: the port before its node
    notifier: Notifier<ipc_threadsafe::Service>,
    _node: iceoryx2::node::Node<ipc_threadsafe::Service>,
}

impl NodeWaker {
    /// Opens the `to_node` event of the node serving `prefix` (which must be running).
    pub fn open(prefix: &str) -> Result<Self, ShmError> {
        let names = ServiceNames::new(prefix);
        let node = NodeBuilder::new()
            .signal_handling_mode(SignalHandlingMode::Disabled)
            .create::<ipc_threadsafe::Service>()
            .map_err(ipc("node"))?;
        let notifier = node
            .service_builder(&service_name(&names.to_node)?)
            .event()
            .open()
            .map_err(ipc("to_node event"))?
            .notifier_builder()
            .create()
            .map_err(ipc("to_node notifier"))?;
        Ok(Self { notifier, _node: node })
    }

    /// Wakes the node's loop (it reads its inputs from every transport on the next turn).
    pub fn wake(&self) {
        let _ = self.notifier.notify_with_custom_event_id(EventId::new(EVENT_COMMAND));
    }
}

/// A controller's connection to a node over shared memory: state, structure, commands and
/// lockstep, waking on the node's events (after a short poll, `set_spin`).
pub struct ShmClient {
    prefix: String,
    /// The iceoryx2 node the ports belong to (kept alive with them; `None` only while opening).
    _node: Option<iceoryx2::node::Node<Svc>>,
    state: Subscriber<Svc, StateSample, ()>,
    structure: Subscriber<Svc, StructureSample, ()>,
    commands: Publisher<Svc, CommandSample, ()>,
    lockstep: Client<Svc, LockstepRequest, (), LockstepResponse, ()>,
    updates: Listener<Svc>,
    wake_node: Notifier<Svc>,
    spin: Duration,
}

/// A state sample as received (zero-copy; dereferences to `StateSample` through `payload()`).
pub type StateRef = Sample<Svc, StateSample, ()>;
/// A lockstep answer as received (zero-copy; `payload()` is the `LockstepResponse`).
pub type LockstepAnswer = Response<Svc, LockstepResponse, ()>;

impl ShmClient {
    /// Connects to the node serving `prefix` (`tensegrity_sim` by default), waiting up to
    /// `timeout` for its services to exist. Removes what dead controllers left first, so a
    /// controller restarted after a crash finds its slot free.
    pub fn connect(prefix: &str, timeout: Duration) -> Result<Self, ShmError> {
        let names = ServiceNames::new(prefix);
        let node = new_node()?;
        node.try_cleanup_dead_nodes();
        let start = Instant::now();
        // a node still starting has created some services but not all: retry the whole set
        loop {
            match Self::open(&node, &names) {
                Ok(mut client) => {
                    client.prefix = prefix.to_string();
                    client._node = Some(node);
                    return Ok(client);
                }
                Err(_) if start.elapsed() < timeout => std::thread::sleep(Duration::from_millis(5)),
                Err(e) => return Err(ShmError::Ipc(format!("no node at '{prefix}' ({e})"))),
            }
        }
    }

    /// Opens every service under `names` and this client's ports on them.
    fn open(node: &iceoryx2::node::Node<Svc>, names: &ServiceNames) -> Result<Self, ShmError> {
        let state = node
            .service_builder(&service_name(&names.state)?)
            .publish_subscribe::<StateSample>()
            .open()
            .map_err(ipc("state service"))?;
        let structure = node
            .service_builder(&service_name(&names.structure)?)
            .publish_subscribe::<StructureSample>()
            .open()
            .map_err(ipc("structure service"))?;
        let commands = node
            .service_builder(&service_name(&names.commands)?)
            .publish_subscribe::<CommandSample>()
            .open()
            .map_err(ipc("actuator_commands service"))?;
        let lockstep = node
            .service_builder(&service_name(&names.lockstep)?)
            .request_response::<LockstepRequest, LockstepResponse>()
            .open()
            .map_err(ipc("lockstep service"))?;
        let to_node = node
            .service_builder(&service_name(&names.to_node)?)
            .event()
            .open()
            .map_err(ipc("to_node event"))?;
        let from_node = node
            .service_builder(&service_name(&names.from_node)?)
            .event()
            .open()
            .map_err(ipc("from_node event"))?;
        Ok(Self {
            prefix: String::new(),
            state: state.subscriber_builder().create().map_err(ipc("state subscriber"))?,
            structure: structure.subscriber_builder().create().map_err(ipc("structure subscriber"))?,
            commands: commands.publisher_builder().create().map_err(ipc("command publisher"))?,
            lockstep: lockstep.client_builder().create().map_err(ipc("lockstep client"))?,
            updates: from_node.listener_builder().create().map_err(ipc("from_node listener"))?,
            wake_node: to_node.notifier_builder().create().map_err(ipc("to_node notifier"))?,
            _node: None,
            spin: Duration::from_micros(200),
        })
    }

    /// How long to poll for an answer before blocking on the node's event (default 200 us; 0
    /// blocks at once, which costs tens of microseconds per wake-up). Polling yields the core
    /// between polls, so a node that needs it is not held up: a controller that owns a core can
    /// poll through a whole step (e.g. 2 ms at 1 kHz) to take a state microseconds after it is
    /// published.
    pub fn set_spin(&mut self, spin: Duration) {
        self.spin = spin;
    }

    /// Waits for `ready` for up to `timeout`: polls for the spin time, then blocks on events.
    fn wait_for(&self, timeout: Duration, mut ready: impl FnMut() -> bool) -> bool {
        let start = Instant::now();
        if poll(start + self.spin.min(timeout), &mut ready) {
            return true;
        }
        loop {
            if ready() {
                return true;
            }
            let left = timeout.saturating_sub(start.elapsed());
            if left.is_zero() {
                return false;
            }
            let _ = self.updates.timed_wait(|_| {}, left.min(Duration::from_millis(50)));
        }
    }

    /// The structure (published once by the node, kept for late joiners).
    pub fn structure(&self, timeout: Duration) -> Result<Structure, ShmError> {
        let start = Instant::now();
        let mut asked = None::<Instant>;
        let sample = loop {
            match self.structure.receive().map_err(ipc("structure"))? {
                Some(s) => break s,
                None if start.elapsed() < timeout => {
                    // a paused node turns once a second: wake it to hand over the structure
                    if asked.is_none_or(|t| t.elapsed() > Duration::from_millis(100)) {
                        let _ = self.wake_node.notify_with_custom_event_id(EventId::new(EVENT_HELLO));
                        asked = Some(Instant::now());
                    }
                    std::thread::sleep(Duration::from_millis(1));
                }
                None => return Err(ShmError::Timeout(self.prefix.clone(), timeout)),
            }
        };
        let s = sample.payload();
        let names = |fields: &[[u8; NAME_BYTES]], n: u32| -> Vec<String> {
            fields[..n as usize].iter().map(|f| read_name(f).unwrap_or("").to_string()).collect()
        };
        Ok(Structure {
            scene_name: read_name(&s.scene_name).unwrap_or("").to_string(),
            physics_dt: s.physics_dt,
            body_names: names(&s.body_names, s.body_count),
            cable_names: names(&s.cable_names, s.cable_count),
            actuator_names: names(&s.actuator_names, s.actuator_count),
            actuator_cable: s.actuator_cable[..s.actuator_count as usize]
                .iter()
                .map(|c| *c as usize)
                .collect(),
        })
    }

    /// The next state sample in arrival order, waiting up to `timeout`; `None` on timeout.
    pub fn next_state(&self, timeout: Duration) -> Result<Option<StateRef>, ShmError> {
        let mut got = None;
        let mut failure = None;
        self.wait_for(timeout, || match self.state.receive() {
            Ok(Some(s)) => {
                got = Some(s);
                true
            }
            Ok(None) => false,
            Err(e) => {
                failure = Some(format!("{e:?}"));
                true
            }
        });
        match failure {
            Some(e) => Err(ShmError::Ipc(format!("state: {e}"))),
            None => Ok(got),
        }
    }

    /// Every state sample received so far, oldest first: the newest `STATE_BUFFER` of them
    /// (older ones are released, so that samples arriving while it drains never exceed what a
    /// subscriber may hold).
    ///
    /// Precondition: the caller holds no other state sample of this client.
    pub fn drain_states(&self) -> Result<Vec<StateRef>, ShmError> {
        let mut out = std::collections::VecDeque::with_capacity(STATE_BUFFER);
        loop {
            if out.len() == STATE_BUFFER {
                out.pop_front();
            }
            match self.state.receive().map_err(ipc("state"))? {
                Some(s) => out.push_back(s),
                None => return Ok(out.into()),
            }
        }
    }

    /// Sends one command message (applied at the node's next step boundary, or rejected whole:
    /// see `StateSample::commands_rejected`).
    pub fn send_command(&self, entries: &[CommandEntry]) -> Result<(), ShmError> {
        check_entry_count(entries)?;
        let mut sample = self.commands.loan_uninit().map_err(ipc("command loan"))?;
        fill_command(zeroed(sample.payload_mut()), entries);
        // SAFETY: `zeroed` initialized the whole payload
        #[allow(unsafe_code)]
        let sample = unsafe { sample.assume_init() };
        sample.send().map_err(ipc("command send"))?;
        let _ = self.wake_node.notify_with_custom_event_id(EventId::new(EVENT_COMMAND));
        Ok(())
    }

    /// Lockstep: applies `entries` (if any) at the next boundary, takes `steps` steps and returns
    /// the node's answer (the state after them) once it arrives, within `timeout`. A refusal
    /// (not paused, command rejected, physics failure) is an error with the node's reason.
    pub fn lockstep(
        &self,
        steps: u64,
        entries: &[CommandEntry],
        timeout: Duration,
    ) -> Result<LockstepAnswer, ShmError> {
        check_entry_count(entries)?;
        let mut request = self.lockstep.loan_uninit().map_err(ipc("lockstep loan"))?;
        let r = zeroed(request.payload_mut());
        r.steps = steps;
        fill_command(&mut r.command, entries);
        // SAFETY: `zeroed` initialized the whole payload
        #[allow(unsafe_code)]
        let request = unsafe { request.assume_init() };
        let pending = request.send().map_err(ipc("lockstep send"))?;
        let _ = self.wake_node.notify_with_custom_event_id(EventId::new(EVENT_LOCKSTEP));
        let mut got = None;
        let mut failure = None;
        self.wait_for(timeout, || match pending.receive() {
            Ok(Some(r)) => {
                got = Some(r);
                true
            }
            Ok(None) => false,
            Err(e) => {
                failure = Some(format!("{e:?}"));
                true
            }
        });
        if let Some(e) = failure {
            return Err(ShmError::Ipc(format!("lockstep answer: {e}")));
        }
        let answer = got.ok_or_else(|| ShmError::Timeout(self.prefix.clone(), timeout))?;
        let p = answer.payload();
        if p.result != result_code::OK {
            let message = read_name(&p.message).unwrap_or("(unreadable)").to_string();
            return Err(ShmError::Refused { code: p.result, message });
        }
        Ok(answer)
    }
}

/// Copies `entries` into a zeroed command.
fn fill_command(out: &mut CommandSample, entries: &[CommandEntry]) {
    out.count = entries.len() as u32;
    out.entries[..entries.len()].copy_from_slice(entries);
}

/// Refuses more entries than a command holds (before anything is loaned).
fn check_entry_count(entries: &[CommandEntry]) -> Result<(), ShmError> {
    if entries.len() > MAX_ACTUATORS {
        return Err(ShmError::TooManyEntries(entries.len()));
    }
    Ok(())
}
