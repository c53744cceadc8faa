//! The node's loop with any set of transports: takes a `NodeCore` and the transports (DDS, shared
//! memory, ...) as `Transport` adapters, gives `SimNode`, which moves inputs from every transport
//! into the core, turns the core when it is due and publishes its outputs on every transport.
//!
//! No transport crate is named here: an adapter implements `Transport` in its own module. While
//! the core is idle (paused, no step requested), the loop waits on the last transport that can
//! block until input arrives (`Transport::event_driven`: shared memory's event listener, the test
//! kit's channel), so an idle node takes no CPU and a request on it wakes the node at once; the
//! other transports (DDS, which can only be polled, and any other event-driven one) are polled
//! every `POLL_SLICE`. Between paced real-time steps it sleeps to the
//! step's due time instead (`std::thread::sleep`, precise to tens of microseconds): what
//! arrives meanwhile applies at that step boundary anyway, and event waits with a timeout
//! (iceoryx2's socket `SO_RCVTIMEO`) round up to the kernel tick, up to 4 ms late. After taking inputs, a core that slept because it was idle is turned at once
//! when the inputs gave it work (`NodeCore::idle_turn_due`), so a lockstep or StepSimulation
//! request starts without waiting for the idle period.

use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use crate::control::ActuatorCommand;
use crate::io::msg::SimResult;
use crate::io::node::NodeCore;
use crate::io::sink::{NodeSink, NodeStats, NodeView, PublishError};
use crate::io::topics::Topic;
use crate::model::ActuatorId;
use crate::sim::Simulator;

/// Longest sleep between polls of transports that cannot wake the loop themselves.
pub const POLL_SLICE: Duration = Duration::from_millis(5);

/// One transport's adapter around the core: its outgoing side is a `NodeSink`; its incoming
/// side hands samples and requests to the core.
pub trait Transport: NodeSink {
    /// A short name for logs (`dds`, `shm`).
    fn name(&self) -> &'static str;
    /// Takes what arrived (commands, within `NodeCore::wants_commands`; service requests) into
    /// `core`. What the core publishes while serving them (the state after a reset, say) goes to
    /// this transport and to `others`, the other transports' sinks.
    fn take_inputs(&mut self, core: &mut NodeCore, others: &mut dyn NodeSink);
    /// False for a transport that never has inputs (the bag recorder): the loop need not poll it.
    fn takes_inputs(&self) -> bool {
        true
    }
    /// True when `wait` blocks until input may have arrived (an event), false when it cannot
    /// tell and the loop must poll.
    fn event_driven(&self) -> bool {
        false
    }
    /// Blocks for at most `timeout`, returning early when input may have arrived. The default
    /// sleeps the whole time.
    fn wait(&mut self, timeout: Duration) {
        std::thread::sleep(timeout);
    }
    /// True while the transport owes a peer an answer that the core has not given yet (a
    /// StepSimulation or lockstep request under way); at shutdown the loop gives such answers a
    /// moment to be delivered.
    fn answering(&self) -> bool {
        false
    }
}

/// Several transports as one sink: every output goes to each (a publish fails when any of them
/// failed; a step answer goes to all, and each answers only its own tickets).
pub struct TransportSinks<'a> {
    first: &'a mut [Box<dyn Transport>],
    second: &'a mut [Box<dyn Transport>],
}

impl<'a> TransportSinks<'a> {
    /// Every transport in `all`.
    pub fn all(all: &'a mut [Box<dyn Transport>]) -> Self {
        Self { first: all, second: &mut [] }
    }
    fn each(&mut self) -> impl Iterator<Item = &mut Box<dyn Transport>> {
        self.first.iter_mut().chain(self.second.iter_mut())
    }
}

impl NodeSink for TransportSinks<'_> {
    fn publish(&mut self, topic: Topic, view: &NodeView<'_>) -> Result<(), PublishError> {
        let mut result = Ok(());
        for t in self.each() {
            if let Err(e) = t.publish(topic, view) {
                result = Err(e);
            }
        }
        result
    }
    fn step_request_done(&mut self, ticket: u64, result: SimResult, view: &NodeView<'_>) {
        for t in self.each() {
            t.step_request_done(ticket, result.clone(), view);
        }
    }
    fn commands_applied(&mut self, time: f64, step: u64, commands: &[(ActuatorId, ActuatorCommand)]) {
        for t in self.each() {
            t.commands_applied(time, step, commands);
        }
    }
    fn simulation_reset(&mut self, time: f64, step: u64) {
        for t in self.each() {
            t.simulation_reset(time, step);
        }
    }
}

/// The simulator node: a `NodeCore` and its transports. Build the transports (e.g. with
/// `io::launch`), then drive it with `run` (the paced loop) or `take_inputs` and `turn` (one turn
/// at a time, for tests).
pub struct SimNode {
    core: NodeCore,
    transports: Vec<Box<dyn Transport>>,
    /// The core's last turn found it idle (so the loop may sleep long).
    idle: bool,
}

impl SimNode {
    /// A node around `core` serving `transports`; publishes what a late joiner needs (structure,
    /// static transforms), the initial state and the start-up diagnostics on all of them.
    pub fn new(mut core: NodeCore, mut transports: Vec<Box<dyn Transport>>) -> Self {
        core.start(&mut TransportSinks::all(&mut transports));
        Self { idle: core.idle(), core, transports }
    }

    /// The node's core (read-only).
    pub fn core(&self) -> &NodeCore {
        &self.core
    }
    /// The simulator (read-only).
    pub fn simulator(&self) -> &Simulator {
        self.core.simulator()
    }
    /// Counters.
    pub fn stats(&self) -> NodeStats {
        self.core.stats()
    }
    /// The transports' names, in the order they are served.
    pub fn transport_names(&self) -> Vec<&'static str> {
        self.transports.iter().map(|t| t.name()).collect()
    }

    /// Takes every transport's inputs into the core (commands within the core's per-step budget,
    /// service requests).
    pub fn take_inputs(&mut self) {
        for i in 0..self.transports.len() {
            let (before, rest) = self.transports.split_at_mut(i);
            let (this, after) = rest.split_first_mut().expect("i < len");
            let mut others = TransportSinks { first: before, second: after };
            this.take_inputs(&mut self.core, &mut others);
        }
    }

    /// One turn of the loop at wall time `now` since the loop's epoch: the core's `tick`, with
    /// every transport as its sink. Returns when the core wants the next turn (`None`: at once).
    pub fn turn(&mut self, now: Duration) -> Option<Duration> {
        let wake = self.core.tick(now, &mut TransportSinks::all(&mut self.transports));
        self.idle = self.core.idle();
        wake
    }

    /// Runs until `stop` is set or SetSimulationState asks to quit: takes inputs, turns the core
    /// when it is due (or at once when inputs gave an idle core work) and waits in between (see
    /// the module docs). On the way out, a request under way is answered with a failure.
    pub fn run(&mut self, stop: &AtomicBool) {
        let epoch = Instant::now();
        let mut wake_at = Duration::ZERO;
        // the last event-driven transport is waited on; every other one with inputs is polled
        let waiter = self.transports.iter().rposition(|t| t.event_driven());
        let polled = self.transports.iter().enumerate().any(|(k, t)| t.takes_inputs() && Some(k) != waiter);
        while !stop.load(Ordering::Relaxed) && !self.core.quit_requested() {
            self.take_inputs();
            let now = epoch.elapsed();
            if self.idle && self.core.idle_turn_due() {
                wake_at = now;
            }
            if now >= wake_at {
                wake_at = self.turn(now).unwrap_or(now);
                continue;
            }
            let mut wait = wake_at - now;
            if polled || waiter.is_none() {
                wait = wait.min(POLL_SLICE);
            }
            match waiter {
                Some(k) if self.idle => self.transports[k].wait(wait),
                _ => std::thread::sleep(wait),
            }
        }
        let answering = self.transports.iter().any(|t| t.answering());
        self.core.shutdown(&mut TransportSinks::all(&mut self.transports));
        if answering {
            // give reliable writers a moment to deliver the answers before the entities go
            std::thread::sleep(Duration::from_millis(300));
        }
    }
}

/// A transport's own sink together with the others, for serving its requests.
pub struct With<'a> {
    /// The transport's own sink.
    pub own: &'a mut dyn NodeSink,
    /// The other transports.
    pub others: &'a mut dyn NodeSink,
}

impl NodeSink for With<'_> {
    fn publish(&mut self, topic: Topic, view: &NodeView<'_>) -> Result<(), PublishError> {
        let a = self.own.publish(topic, view);
        let b = self.others.publish(topic, view);
        a.and(b)
    }
    fn step_request_done(&mut self, ticket: u64, result: SimResult, view: &NodeView<'_>) {
        self.own.step_request_done(ticket, result.clone(), view);
        self.others.step_request_done(ticket, result, view);
    }
    fn commands_applied(&mut self, time: f64, step: u64, commands: &[(ActuatorId, ActuatorCommand)]) {
        self.own.commands_applied(time, step, commands);
        self.others.commands_applied(time, step, commands);
    }
    fn simulation_reset(&mut self, time: f64, step: u64) {
        self.own.simulation_reset(time, step);
        self.others.simulation_reset(time, step);
    }
}
