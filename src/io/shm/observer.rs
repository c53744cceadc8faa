//! A watcher of a running node over shared memory: takes the node's prefix, gives its structure
//! and its newest state and contacts samples, without a port the node waits on or wakes (no
//! listener, no publisher, no lockstep client), so watching costs the node one more subscriber
//! queue per sample; and whether the node is still there. The live viewer's source.

use std::time::{Duration, Instant};

use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::service::port_factory::publish_subscribe::PortFactory;
use iceoryx2::service::port_factory::PortFactory as _;

use super::client::{structure_of, ContactsRef, StateRef, Structure};
use super::payload::*;
use super::service::*;

/// Read-only subscriptions to a node's state, structure and contacts.
pub struct ShmObserver {
    prefix: String,
    node: iceoryx2::node::Node<Svc>,
    state_service: PortFactory<Svc, StateSample, ()>,
    state: Subscriber<Svc, StateSample, ()>,
    structure: Subscriber<Svc, StructureSample, ()>,
    contacts: Option<Subscriber<Svc, ContactsSample, ()>>,
}

impl ShmObserver {
    /// Subscribes to the node serving `prefix` (`tensegrity_sim` by default), waiting up to
    /// `timeout` for its state service to have a publisher. Removes what dead processes left
    /// first.
    pub fn connect(prefix: &str, timeout: Duration) -> Result<Self, ShmError> {
        let names = ServiceNames::new(prefix);
        let node = new_node()?;
        node.try_cleanup_dead_nodes();
        let start = Instant::now();
        loop {
            match Self::open(&node, &names) {
                Ok((state_service, state, structure, contacts)) => {
                    return Ok(Self {
                        prefix: prefix.to_string(),
                        node,
                        state_service,
                        state,
                        structure,
                        contacts,
                    })
                }
                Err(_) if start.elapsed() < timeout => std::thread::sleep(Duration::from_millis(20)),
                Err(e) => return Err(ShmError::Ipc(format!("no node at '{prefix}' ({e})"))),
            }
        }
    }

    #[allow(clippy::type_complexity)]
    fn open(
        node: &iceoryx2::node::Node<Svc>,
        names: &ServiceNames,
    ) -> Result<
        (
            PortFactory<Svc, StateSample, ()>,
            Subscriber<Svc, StateSample, ()>,
            Subscriber<Svc, StructureSample, ()>,
            Option<Subscriber<Svc, ContactsSample, ()>>,
        ),
        ShmError,
    > {
        let state_service = node
            .service_builder(&service_name(&names.state)?)
            .publish_subscribe::<StateSample>()
            .open()
            .map_err(ipc("state service"))?;
        if state_service.dynamic_config().number_of_publishers() == 0 {
            return Err(ShmError::Ipc("the node's state publisher is not created yet".into()));
        }
        let structure = node
            .service_builder(&service_name(&names.structure)?)
            .publish_subscribe::<StructureSample>()
            .open()
            .map_err(ipc("structure service"))?;
        let contacts = match node
            .service_builder(&service_name(&names.contacts)?)
            .publish_subscribe::<ContactsSample>()
            .open()
        {
            Ok(service) => Some(service.subscriber_builder().create().map_err(ipc("contacts subscriber"))?),
            Err(_) => None,
        };
        let state = state_service.subscriber_builder().create().map_err(ipc("state subscriber"))?;
        let structure = structure.subscriber_builder().create().map_err(ipc("structure subscriber"))?;
        Ok((state_service, state, structure, contacts))
    }

    /// The node's namespace prefix.
    pub fn prefix(&self) -> &str {
        &self.prefix
    }

    /// The structure (the node keeps its last one for late joiners and hands it over at its
    /// next turn: at once while it steps, within about a second while it is paused).
    pub fn structure(&self, timeout: Duration) -> Result<Structure, ShmError> {
        let start = Instant::now();
        loop {
            if let Some(s) = self.structure.receive().map_err(ipc("structure"))? {
                return Ok(structure_of(s.payload()));
            }
            if start.elapsed() >= timeout {
                return Err(ShmError::Timeout(self.prefix.clone(), timeout));
            }
            std::thread::sleep(Duration::from_millis(5));
        }
    }

    /// The newest state sample received since the last call (older ones are released), or None.
    pub fn newest_state(&self) -> Result<Option<StateRef>, ShmError> {
        newest_sample(&self.state, "state")
    }

    /// The newest contacts sample received since the last call, or None (also for a scene
    /// without contacts).
    pub fn newest_contacts(&self) -> Result<Option<ContactsRef>, ShmError> {
        let Some(contacts) = &self.contacts else { return Ok(None) };
        newest_sample(contacts, "contacts")
    }

    /// Whether the node still publishes states: after removing what dead processes left (a
    /// node killed with SIGKILL), its state service still has a publisher.
    pub fn node_alive(&self) -> bool {
        self.node.try_cleanup_dead_nodes();
        self.state_service.dynamic_config().number_of_publishers() > 0
    }
}
