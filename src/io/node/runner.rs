//! The node's loop with any set of transports: takes a `NodeCore` and the transports (DDS, shared
//! memory, ...) as `Transport` adapters, gives `SimNode`, which moves inputs from every transport
//! into the core, turns the core when it is due and publishes its outputs on every transport.
//!
//! No transport crate is named here: an adapter implements `Transport` in its own module. Between
//! turns the loop blocks in one readiness poll (`mio`, epoll on Linux) on which every transport
//! registered what signals its input (`Transport::register_wake`: DDS readers and service
//! servers, shared memory's event listener, the test kit's waker), so a request or command wakes
//! the node at once, paused or playing, and a paused node takes no CPU. A transport that cannot
//! register is polled every `POLL_SLICE` instead. The poll's timeout is whole milliseconds
//! (rounded up), so the last millisecond before a paced step's due time is slept precisely
//! (`std::thread::sleep`, tens of microseconds late at most); what arrives meanwhile applies at
//! that step boundary anyway. After taking inputs, a core that slept because it was idle is turned
//! at once when the inputs gave it work (`NodeCore::idle_turn_due`), so a lockstep or
//! StepSimulation request starts without waiting for the idle period.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use mio::{Events, Poll, Registry, Token, Waker};

use crate::control::ActuatorCommand;
use crate::io::msg::SimResult;
use crate::io::node::NodeCore;
use crate::io::sink::{NodeSink, NodeStats, NodeView, PublishError};
use crate::io::topics::Topic;
use crate::model::ActuatorId;
use crate::sim::Simulator;

/// Longest sleep between polls of transports that cannot wake the loop themselves.
pub const POLL_SLICE: Duration = Duration::from_millis(5);

/// Waits shorter than this are slept, not polled: the readiness poll counts whole milliseconds.
const PRECISE_SLEEP: Duration = Duration::from_millis(2);

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
    /// Registers on `registry`, under `token`, whatever becomes readable when input arrives on this
    /// transport, so that the loop's poll returns at once. Returns false when the transport cannot
    /// (the loop then polls it every `POLL_SLICE`). The default registers nothing.
    fn register_wake(&mut self, registry: &Registry, token: Token) -> std::io::Result<bool> {
        let _ = (registry, token);
        Ok(false)
    }
    /// Called just before the loop blocks until `deadline`: consumes stale wake-ups (what the
    /// poll reported last time, so it can report the next arrival) and returns true when input is
    /// already waiting, in which case the loop does not block. A transport that promised a peer a
    /// fast answer may busy-poll here for a short while. The default does nothing.
    fn before_wait(&mut self, deadline: Instant) -> bool {
        let _ = deadline;
        false
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
    fn simulation_reset(&mut self, time: f64, step: u64, seed: Option<u64>) {
        for t in self.each() {
            t.simulation_reset(time, step, seed);
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
    /// The readiness poll the loop blocks in (`None` if the system gave none: then it sleeps in
    /// slices of `POLL_SLICE`).
    poll: Option<Poll>,
    /// Wakes the poll from any thread (`SimNode::waker`).
    waker: Option<Arc<Waker>>,
    /// Whether every transport with inputs registered on the poll (known once `run` started).
    all_wake: Option<bool>,
}

/// The poll token of `SimNode::waker`; transports use their index.
const WAKER_TOKEN: Token = Token(usize::MAX);

impl SimNode {
    /// A node around `core` serving `transports`; publishes what a late joiner needs (structure,
    /// static transforms), the initial state and the start-up diagnostics on all of them.
    pub fn new(mut core: NodeCore, mut transports: Vec<Box<dyn Transport>>) -> Self {
        core.start(&mut TransportSinks::all(&mut transports));
        let poll = Poll::new()
            .inspect_err(|e| {
                eprintln!("warning: no readiness poll ({e}); the loop polls every {POLL_SLICE:?}")
            })
            .ok();
        let waker = poll.as_ref().and_then(|p| Waker::new(p.registry(), WAKER_TOKEN).ok()).map(Arc::new);
        Self { idle: core.idle(), core, transports, poll, waker, all_wake: None }
    }

    /// Wakes the loop from another thread: call `wake()` after setting `run`'s stop flag (so the
    /// node stops at once, not at its next due turn) or after handing a transport input that no
    /// readiness source announces (the test kit's requests). `None` without a readiness poll
    /// (the loop then looks every `POLL_SLICE` anyway).
    pub fn waker(&self) -> Option<Arc<Waker>> {
        self.waker.clone()
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
        // the poll leaves `self` while the loop borrows it, and comes back at the end
        let mut poll = self.poll.take();
        let mut events = Events::with_capacity(64);
        let all_wake = *self.all_wake.get_or_insert_with(|| {
            // true when every transport with inputs wakes the poll itself
            let mut all = poll.is_some();
            for (k, t) in self.transports.iter_mut().enumerate().filter(|(_, t)| t.takes_inputs()) {
                all &= match &poll {
                    Some(p) => t.register_wake(p.registry(), Token(k)).unwrap_or_else(|e| {
                        eprintln!(
                            "warning: transport {}: cannot wake the loop ({e}); polled instead",
                            t.name()
                        );
                        false
                    }),
                    None => false,
                };
            }
            all
        });
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
            if !all_wake {
                wait = wait.min(POLL_SLICE);
            }
            let deadline = Instant::now() + wait;
            let mut ready = false;
            for t in self.transports.iter_mut().filter(|t| t.takes_inputs()) {
                ready |= t.before_wait(deadline);
            }
            if ready {
                continue;
            }
            let left = deadline.saturating_duration_since(Instant::now());
            match poll.as_mut() {
                // the poll's timeout is whole milliseconds, rounded up: stop it a millisecond
                // early and sleep the rest precisely
                Some(p) if left >= PRECISE_SLEEP => {
                    let coarse = Duration::from_millis(left.as_millis() as u64 - 1);
                    // an interrupted poll (EINTR) just turns the loop once more
                    let _ = p.poll(&mut events, Some(coarse));
                }
                _ => std::thread::sleep(left),
            }
        }
        self.poll = poll;
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
    fn simulation_reset(&mut self, time: f64, step: u64, seed: Option<u64>) {
        self.own.simulation_reset(time, step, seed);
        self.others.simulation_reset(time, step, seed);
    }
}
