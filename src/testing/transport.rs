//! The kit's own in-process transport: a `Transport` of the node's loop that takes the test's
//! requests (steps, commands, reset) over a channel and hands back snapshots and answers.

use std::sync::mpsc::{Receiver, Sender};
use std::sync::{Arc, Condvar, Mutex, MutexGuard};

use super::error::KitError;
use super::snapshot::{Command, Names, Snapshot};
use crate::io::commands;
use crate::io::msg::result_code;
use crate::io::msg::SimResult;
use crate::io::node::runner::{Transport, With};
use crate::io::node::NodeCore;
use crate::io::sink::{NodeSink, NodeStats, NodeView, PublishError};
use crate::io::topics::Topic;

/// What a test asks of the node, with where to answer.
pub(super) enum Request {
    Command(Command, Sender<Result<(), KitError>>),
    Step(u64, Sender<Result<Snapshot, KitError>>),
    Pause(bool, Sender<Result<(), KitError>>),
    Reset(Option<u64>, Sender<Result<(), KitError>>),
}

/// What the node thread shares with the handle: the latest state and the counters.
pub(super) struct Shared {
    pub(super) latest: Mutex<Latest>,
    pub(super) changed: Condvar,
}

pub(super) struct Latest {
    pub(super) snapshot: Snapshot,
    pub(super) stats: NodeStats,
    /// The fault the node ended in (set when its loop has stopped).
    pub(super) fault: Option<String>,
    pub(super) running: bool,
}

impl Shared {
    pub(super) fn lock(&self) -> MutexGuard<'_, Latest> {
        self.latest.lock().unwrap_or_else(|p| p.into_inner())
    }
}

/// The kit's in-process transport: requests in through a channel, state out into `Shared`.
pub(super) struct KitTransport {
    pub(super) requests: Receiver<Request>,
    pub(super) shared: Arc<Shared>,
    /// The StepSimulation ticket under way and where to answer it.
    pub(super) stepping: Option<(u64, Sender<Result<Snapshot, KitError>>)>,
    pub(super) names: Arc<Names>,
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
                let names = [m.actuator];
                let (rest_length, rate, tension) =
                    (m.rest_length.as_slice(), m.rate.as_slice(), m.tension.as_slice());
                let values = commands::CommandArrays { rest_length, rate, tension };
                let r =
                    core.offer_parsed(|model, out| commands::check_command(model, "", &names, values, out));
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
            Request::Reset(seed, reply) => {
                core.reset_seeded(seed, &mut With { own: self, others });
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

    /// Nothing to register: the handle wakes the loop through `SimNode::waker` after each
    /// request it sends.
    fn register_wake(&mut self, _registry: &mio::Registry, _token: mio::Token) -> std::io::Result<bool> {
        Ok(true)
    }

    fn answering(&self) -> bool {
        self.stepping.is_some()
    }
}
