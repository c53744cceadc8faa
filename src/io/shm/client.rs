//! A controller's side of shared memory, in Rust: `ShmClient` reads the structure and states,
//! sends commands and lockstep requests (notifying the node's event, which wakes its loop), and
//! waits for the node's answers.

use std::time::{Duration, Instant};

use iceoryx2::port::client::Client;
use iceoryx2::port::listener::Listener;
use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::*;
use iceoryx2::response::Response;
use iceoryx2::sample::Sample;

use crate::io::msg::result_code;

use super::payload::*;
use super::service::*;

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
    /// Each contact's two names, in `ContactsSample` order (empty without contacts).
    pub contact_names: Vec<(String, String)>,
}

/// The owned `Structure` of a structure sample.
pub(super) fn structure_of(s: &StructureSample) -> Structure {
    let names = |fields: &[[u8; NAME_BYTES]], n: u32| -> Vec<String> {
        fields[..n as usize].iter().map(|f| read_name(f).unwrap_or("").to_string()).collect()
    };
    Structure {
        scene_name: read_name(&s.scene_name).unwrap_or("").to_string(),
        physics_dt: s.physics_dt,
        body_names: names(&s.body_names, s.body_count),
        cable_names: names(&s.cable_names, s.cable_count),
        actuator_names: names(&s.actuator_names, s.actuator_count),
        actuator_cable: s.actuator_cable[..s.actuator_count as usize].iter().map(|c| *c as usize).collect(),
        contact_names: (0..s.contact_count as usize)
            .map(|i| {
                let name = |f: &[u8; NAME_BYTES]| read_name(f).unwrap_or("").to_string();
                (name(&s.contact_point[i]), name(&s.contact_with[i]))
            })
            .collect(),
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
    /// The contacts (None: the scene has none).
    contacts: Option<Subscriber<Svc, ContactsSample, ()>>,
    /// What the sensors report (None: the scene declares none).
    measured: Option<Subscriber<Svc, MeasuredSample, ()>>,
    commands: Publisher<Svc, CommandSample, ()>,
    lockstep: Client<Svc, LockstepRequest, (), LockstepResponse, ()>,
    updates: Listener<Svc>,
    wake_node: Notifier<Svc>,
    spin: Duration,
}

/// A state sample as received (zero-copy; dereferences to `StateSample` through `payload()`).
pub type StateRef = Sample<Svc, StateSample, ()>;
/// A contacts sample as received (zero-copy; `payload()` is the `ContactsSample`).
pub type ContactsRef = Sample<Svc, ContactsSample, ()>;
/// A sensors sample as received (zero-copy; `payload()` is the `MeasuredSample`).
pub type MeasuredRef = Sample<Svc, MeasuredSample, ()>;
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
        // the node creates every service, then its ports: a request sent before its lockstep
        // server exists, or a command before its subscriber, would be lost (under load a test's
        // first lockstep waited out its 10 s). Until they are there, the node is still starting
        let ports_ready = lockstep.dynamic_config().number_of_servers() > 0
            && commands.dynamic_config().number_of_subscribers() > 0
            && to_node.dynamic_config().number_of_listeners() > 0
            && state.dynamic_config().number_of_publishers() > 0;
        if !ports_ready {
            return Err(ShmError::Ipc("the node's ports are not created yet".into()));
        }
        // the node creates it before the others, so it exists now if the scene has contacts
        let contacts = match node
            .service_builder(&service_name(&names.contacts)?)
            .publish_subscribe::<ContactsSample>()
            .open()
        {
            Ok(service) => Some(service.subscriber_builder().create().map_err(ipc("contacts subscriber"))?),
            Err(_) => None,
        };
        // likewise the sensors' service, for a scene with sensors
        let measured = match node
            .service_builder(&service_name(&names.measured)?)
            .publish_subscribe::<MeasuredSample>()
            .open()
        {
            Ok(service) => Some(service.subscriber_builder().create().map_err(ipc("measured subscriber"))?),
            Err(_) => None,
        };
        Ok(Self {
            contacts,
            measured,
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
        Ok(structure_of(sample.payload()))
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

    /// The newest contacts sample received so far (older ones are released), or None when none
    /// arrived since the last call or the scene has no contacts. After a lockstep answer it is
    /// that answer's step (the node publishes the contacts first).
    pub fn latest_contacts(&self) -> Result<Option<ContactsRef>, ShmError> {
        let Some(contacts) = &self.contacts else { return Ok(None) };
        newest_sample(contacts, "contacts")
    }

    /// The newest sensors sample received so far (older ones are released), or None when none
    /// arrived since the last call or the scene declares no sensors. After a lockstep answer it
    /// is that answer's step (the node publishes it before the answer).
    pub fn latest_measured(&self) -> Result<Option<MeasuredRef>, ShmError> {
        let Some(measured) = &self.measured else { return Ok(None) };
        newest_sample(measured, "measured")
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
        self.lockstep_with(steps, entries, None, timeout)
    }

    /// `lockstep` after a reset (`LOCKSTEP_RESET`), its episode drawn from `seed` where given
    /// (`LOCKSTEP_SEEDED`): a learning environment's `reset(seed)`. With `reset` `None`, plain
    /// `lockstep`.
    pub fn lockstep_with(
        &self,
        steps: u64,
        entries: &[CommandEntry],
        reset: Option<Option<u64>>,
        timeout: Duration,
    ) -> Result<LockstepAnswer, ShmError> {
        check_entry_count(entries)?;
        let mut request = self.lockstep.loan_uninit().map_err(ipc("lockstep loan"))?;
        let r = zeroed(request.payload_mut());
        r.steps = steps;
        if let Some(seed) = reset {
            r.flags = LOCKSTEP_RESET;
            if let Some(seed) = seed {
                r.flags |= LOCKSTEP_SEEDED;
                r.seed = seed;
            }
        }
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
