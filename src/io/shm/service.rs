//! What both sides of shared memory share: the service names, the events, the errors, the
//! scene's capacity check, and how a waiting side polls before it blocks.

use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use iceoryx2::active_request::ActiveRequest;
use iceoryx2::prelude::*;

use crate::io::commands;
use crate::model::Model;

use super::payload::*;

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

/// Wall-clock time, ns since the Unix epoch.
pub fn realtime_ns() -> u64 {
    SystemTime::now().duration_since(UNIX_EPOCH).map_or(0, |d| d.as_nanos() as u64)
}

/// Why the transport or a client could not start or act.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ShmError {
    /// The scene does not fit the payloads.
    #[error("the scene has {count} {what}, more than this build's shared-memory capacity {limit} ({constant} in src/io/shm/payload.rs, mirrored in python/tensegrity/testing/shm.py); run it over DDS (-p transports:=dds) or raise the constant")]
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

pub(super) fn ipc<E: std::fmt::Debug>(what: &str) -> impl FnOnce(E) -> ShmError + '_ {
    move |e| ShmError::Ipc(format!("{what}: {e:?}"))
}

/// Checks that `model` fits the payloads (counts and name lengths) and returns nothing or the
/// first limit it exceeds.
pub fn check_capacity(model: &Model, frame_id: &str) -> Result<(), ShmError> {
    let counts = [
        ("bodies", model.bodies.len(), MAX_BODIES, "MAX_BODIES"),
        ("cables", model.cables.len(), MAX_CABLES, "MAX_CABLES"),
        ("actuators", model.actuators.len(), MAX_ACTUATORS, "MAX_ACTUATORS"),
        ("contacts", model.contact_pairs(), MAX_CONTACTS, "MAX_CONTACTS"),
        ("pulleys", model.cables.iter().map(|c| c.pulley_count()).sum(), MAX_PULLEYS, "MAX_PULLEYS"),
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
        .chain(model.actuator_names.iter().map(|n| ("actuator name", n.as_str())))
        .chain(model.contact_labels().flat_map(|(a, b)| [("contact name", a), ("contact name", b)]));
    for (what, name) in names {
        if name.len() >= NAME_BYTES {
            let shown = commands::excerpt(name, commands::EXCERPT_CHARS);
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
    /// `<prefix>/contacts` (scenes with contacts only).
    pub contacts: String,
    /// `<prefix>/measured` (scenes with sensors only).
    pub measured: String,
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
            contacts: n("contacts"),
            measured: n("measured"),
            to_node: n("to_node"),
            from_node: n("from_node"),
        }
    }
}

pub(super) fn service_name(name: &str) -> Result<ServiceName, ShmError> {
    ServiceName::new(name).map_err(ipc("service name"))
}

pub(super) fn new_node() -> Result<iceoryx2::node::Node<ipc::Service>, ShmError> {
    NodeBuilder::new()
        .signal_handling_mode(SignalHandlingMode::Disabled)
        .create::<ipc::Service>()
        .map_err(ipc("node"))
}

pub(super) type Svc = ipc::Service;

/// The newest sample `subscriber` has received since the last call (the older ones are
/// released on the way), or None; `what` names the service in an error.
pub(super) fn newest_sample<T: std::fmt::Debug + ZeroCopySend>(
    subscriber: &iceoryx2::port::subscriber::Subscriber<Svc, T, ()>,
    what: &str,
) -> Result<Option<iceoryx2::sample::Sample<Svc, T, ()>>, ShmError> {
    let mut newest = None;
    while let Some(s) = subscriber.receive().map_err(ipc(what))? {
        newest = Some(s);
    }
    Ok(newest)
}
pub(super) type Lockstep = ActiveRequest<Svc, LockstepRequest, (), LockstepResponse, ()>;

/// Polls `ready` until it returns true (then true) or `until` passes (then false), yielding the
/// core between polls, so a thread waiting for this core (the node or the controller, on a busy
/// or pinned machine) runs at once. Spinning instead held the other side off until the spin
/// ended (440 us lockstep round trips on one core); yielding costs a one-step round trip on
/// prism3 about 4 us, and spinning 20 us before yielding was slower still (docs/shared-memory.md).
pub(super) fn poll(until: Instant, mut ready: impl FnMut() -> bool) -> bool {
    while Instant::now() < until {
        if ready() {
            return true;
        }
        std::thread::yield_now();
    }
    false
}
