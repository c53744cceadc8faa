//! The node's side of shared memory: takes the node core's views and the controllers' samples and
//! requests, gives `ShmTransport`, a `Transport` of the node's loop that publishes the state,
//! takes commands and answers lockstep requests.

use std::time::{Duration, Instant};

use iceoryx2::port::listener::Listener;
use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::server::Server;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::port::update_connections::UpdateConnections;
use iceoryx2::prelude::*;

use crate::control::ActuatorCommand;
use crate::io::msg::result_code;
use crate::io::msg::SimResult;
use crate::io::node::params::NodeParams;
use crate::io::node::runner::{Transport, With};
use crate::io::node::NodeCore;
use crate::io::sink::{NodeSink, NodeView, PublishError};
use crate::io::topics::Topic;
use crate::model::{ActuatorId, Model};

use super::payload::*;
use super::service::*;
use crate::task::{quaternion_xyzw, xyzw_of_wxyz};

/// Fills `out` (all zero on entry) from `view`; `commands_applied_ns` as in `StateSample`.
pub fn fill_state(out: &mut StateSample, v: &NodeView<'_>, commands_applied_ns: u64) {
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
        out.body_position[i] = [p.position.x, p.position.y, p.position.z];
        out.body_orientation[i] = quaternion_xyzw(p);
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
    // pulleys: with friction from the return map, else one tension along the route
    let mut k = 0;
    for (cable, c) in model.cables.iter().zip(&ws.cables) {
        let pulleys = cable.pulley_count();
        match cable.friction {
            Some(f) => {
                let f = &model.pulley_friction[f];
                for i in 0..pulleys {
                    let p = ws.friction.pulley(f, i);
                    out.pulley_slip_speed[k + i] = p.slip_speed;
                    out.pulley_tension_ratio[k + i] = p.tension_ratio;
                    out.pulley_sticks[k + i] = u8::from(p.state == crate::forces::pulley::PulleyState::Stick);
                }
            }
            None => {
                for i in 0..pulleys {
                    out.pulley_tension_ratio[k + i] =
                        crate::forces::pulley::tension_ratio(c.tension, c.tension);
                }
            }
        }
        k += pulleys;
    }
    out.pulley_count = k as u32;
    out.published_ns = realtime_ns();
}

/// Fills `out` (all zero on entry) with what the sensors of `v` report (`NodeView::measured`).
pub fn fill_measured(out: &mut MeasuredSample, v: &NodeView<'_>) {
    use crate::sensors::{reading, SensorKind};
    let model = v.model;
    out.time = v.state.time;
    out.step = v.step;
    out.body_count = model.bodies.len() as u32;
    out.cable_count = model.cables.len() as u32;
    out.actuator_count = model.actuators.len() as u32;
    let measured = |kind| reading(model, v.measured, kind);
    if let Some(t) = measured(SensorKind::Tension) {
        out.channels |= MEASURED_TENSION;
        out.cable_tension[..t.len()].copy_from_slice(t);
    }
    if let Some(l) = measured(SensorKind::Length) {
        out.channels |= MEASURED_LENGTH;
        out.cable_length[..l.len()].copy_from_slice(l);
    }
    if let Some(l0) = measured(SensorKind::RestLength) {
        out.channels |= MEASURED_REST_LENGTH;
        out.actuator_rest_length[..l0.len()].copy_from_slice(l0);
    }
    if let Some(x) = measured(SensorKind::Position) {
        out.channels |= MEASURED_POSITION;
        for (to, x) in out.body_position.iter_mut().zip(x.chunks_exact(3)) {
            to.copy_from_slice(x);
        }
    }
    if let Some(q) = measured(SensorKind::Orientation) {
        out.channels |= MEASURED_ORIENTATION;
        // the sensors' w, x, y, z into ROS order
        for (to, q) in out.body_orientation.iter_mut().zip(q.chunks_exact(4)) {
            *to = xyzw_of_wxyz(q);
        }
    }
    for (kind, bit, to) in [
        (SensorKind::Gyro, MEASURED_GYRO, &mut out.body_angular_velocity),
        (SensorKind::Accelerometer, MEASURED_ACCELEROMETER, &mut out.body_specific_force),
    ] {
        if let Some(x) = measured(kind) {
            out.channels |= bit;
            for (to, x) in to.iter_mut().zip(x.chunks_exact(3)) {
                to.copy_from_slice(x);
            }
        }
    }
    for (body, imu) in v.imu_truth.chunks_exact(6).enumerate() {
        out.true_angular_velocity[body].copy_from_slice(&imu[..3]);
        out.true_specific_force[body].copy_from_slice(&imu[3..]);
    }
    // the lost flags, channel by channel as the values (`Sensors::lost`, parallel to measured)
    if v.lost.len() != v.measured.len() {
        return;
    }
    for (kind, start, n) in crate::sensors::layout(model) {
        let lost = v.lost[start..start + n].iter().map(|l| u8::from(*l));
        let flat: &mut [u8] = match kind {
            SensorKind::Tension => &mut out.cable_tension_lost[..n],
            SensorKind::Length => &mut out.cable_length_lost[..n],
            SensorKind::RestLength => &mut out.actuator_rest_length_lost[..n],
            SensorKind::Position => out.body_position_lost.as_flattened_mut(),
            SensorKind::Gyro => out.body_angular_velocity_lost.as_flattened_mut(),
            SensorKind::Accelerometer => out.body_specific_force_lost.as_flattened_mut(),
            SensorKind::Orientation => {
                for (to, q) in
                    out.body_orientation_lost.iter_mut().zip(v.lost[start..start + n].chunks_exact(4))
                {
                    *to = u8::from(q[0]);
                }
                continue;
            }
        };
        for (to, l) in flat.iter_mut().zip(lost) {
            *to = l;
        }
    }
}

/// Fills `out` (all zero on entry) with every contact of `v`.
pub fn fill_contacts(out: &mut ContactsSample, v: &NodeView<'_>) {
    out.time = v.state.time;
    out.step = v.step;
    out.contact_count = v.workspace.contacts.len() as u32;
    for (i, c) in v.workspace.contacts.iter().enumerate() {
        out.gap[i] = c.gap;
        out.normal_force[i] = c.normal_force;
        out.slip_speed[i] = c.slip.norm();
        out.position[i] = c.position.into();
        out.normal[i] = c.normal.into();
        out.friction[i] = c.friction.into();
        out.in_contact[i] = u8::from(c.in_contact());
    }
}

/// Opens (or creates) the per-step publish-subscribe service `name` of payload `T` (the state,
/// the contacts): one publisher, `MAX_CONTROLLERS` subscribers that keep the newest
/// `STATE_BUFFER` samples (the oldest is overwritten: a slow reader never holds the node up), no
/// history.
fn per_step_service<T: std::fmt::Debug + ZeroCopySend>(
    node: &iceoryx2::node::Node<Svc>,
    name: &str,
    what: &str,
) -> Result<iceoryx2::service::port_factory::publish_subscribe::PortFactory<Svc, T, ()>, ShmError> {
    node.service_builder(&service_name(name)?)
        .publish_subscribe::<T>()
        .max_publishers(1)
        .max_subscribers(MAX_CONTROLLERS)
        .subscriber_max_buffer_size(STATE_BUFFER)
        .subscriber_max_borrowed_samples(STATE_BUFFER)
        .history_size(0)
        .enable_safe_overflow(true)
        .open_or_create()
        .map_err(ipc(what))
}

/// The node's shared-memory face: see the module docs.
pub struct ShmTransport {
    node: iceoryx2::node::Node<Svc>,
    prefix: String,
    state: Publisher<Svc, StateSample, ()>,
    structure: Publisher<Svc, StructureSample, ()>,
    /// The contacts' publisher (scenes with contacts only).
    contacts: Option<Publisher<Svc, ContactsSample, ()>>,
    /// The sensors' publisher (scenes with sensors only).
    measured: Option<Publisher<Svc, MeasuredSample, ()>>,
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
    /// The core took commands at the end of the last `take_inputs` (else they wait for its turn).
    takes_commands: bool,
    /// No lockstep request was under way at the end of the last `take_inputs`.
    takes_lockstep: bool,
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
        // first, so that a controller that finds the other services finds this one too
        let contacts = if model.contact_pairs() > 0 {
            let service = per_step_service::<ContactsSample>(&node, &names.contacts, "contacts service")?;
            Some(service.publisher_builder().create().map_err(|e| taken(format!("{e:?}")))?)
        } else {
            None
        };
        let measured = if model.sensors.channels.is_empty() {
            None
        } else {
            let service = per_step_service::<MeasuredSample>(&node, &names.measured, "measured service")?;
            Some(service.publisher_builder().create().map_err(|e| taken(format!("{e:?}")))?)
        };
        let state = per_step_service::<StateSample>(&node, &names.state, "state service")?;
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
            contacts,
            measured,
            commands,
            lockstep,
            wake,
            notify,
            tickets: Vec::new(),
            incoming: None,
            spin: Duration::from_micros(params.shm_spin_us),
            spin_until: None,
            takes_commands: true,
            takes_lockstep: true,
            last_cleanup: Instant::now(),
            commands_applied_ns: 0,
        })
    }

    /// The service prefix (`tensegrity_sim` by default).
    pub fn prefix(&self) -> &str {
        &self.prefix
    }

    /// Publishes the contacts of `v` (nothing for a scene without contacts).
    fn publish_contacts(&mut self, v: &NodeView<'_>) -> Result<(), PublishError> {
        let Some(publisher) = &self.contacts else { return Ok(()) };
        let fail = |e: String| PublishError::Failed(format!("contacts: {e}"));
        let mut sample = publisher.loan_uninit().map_err(|e| fail(format!("{e:?}")))?;
        fill_contacts(zeroed(sample.payload_mut()), v);
        // SAFETY: `zeroed` initialized the whole payload
        #[allow(unsafe_code)]
        let sample = unsafe { sample.assume_init() };
        sample.send().map_err(|e| fail(format!("{e:?}")))?;
        Ok(())
    }

    /// Publishes what the sensors of `v` report (nothing for a scene without sensors).
    fn publish_measured(&mut self, v: &NodeView<'_>) -> Result<(), PublishError> {
        let Some(publisher) = &self.measured else { return Ok(()) };
        let fail = |e: String| PublishError::Failed(format!("measured: {e}"));
        let mut sample = publisher.loan_uninit().map_err(|e| fail(format!("{e:?}")))?;
        fill_measured(zeroed(sample.payload_mut()), v);
        // SAFETY: `zeroed` initialized the whole payload
        #[allow(unsafe_code)]
        let sample = unsafe { sample.assume_init() };
        sample.send().map_err(|e| fail(format!("{e:?}")))?;
        Ok(())
    }

    fn publish_state(&mut self, v: &NodeView<'_>) -> Result<(), PublishError> {
        self.publish_contacts(v)?;
        self.publish_measured(v)?;
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
        s.contact_count = m.contact_pairs() as u32;
        for (i, (point, with)) in m.contact_labels().enumerate() {
            write_name(&mut s.contact_point[i], point);
            write_name(&mut s.contact_with[i], with);
        }
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
        // the contacts of the answer's step first (a failure to publish them is the state's too)
        let _ = self.publish_contacts(view);
        let _ = self.publish_measured(view);
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

    /// True when a command or a lockstep request waits that the core would take now (as of the
    /// last `take_inputs`): the spin's and the poll's test before blocking.
    fn input_waiting(&self) -> bool {
        (self.takes_commands && self.commands.has_samples().unwrap_or(false))
            || (self.takes_lockstep && self.lockstep.has_requests().unwrap_or(false))
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
        let flags = request.payload().flags;
        if flags & !(LOCKSTEP_RESET | LOCKSTEP_SEEDED) != 0 || flags == LOCKSTEP_SEEDED {
            core.incoming_malformed();
            let why = format!("lockstep flags {flags:#x}: only RESET (1), alone or with SEEDED (2)");
            let view = core.view();
            return self.answer(request, &SimResult::err(result_code::OPERATION_FAILED, why), 0, &view);
        }
        if flags & LOCKSTEP_RESET != 0 {
            let seed = (flags & LOCKSTEP_SEEDED != 0).then_some(request.payload().seed);
            core.reset_seeded(seed, &mut With { own: &mut *self, others });
        }
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
        self.takes_commands = core.wants_commands();
        self.takes_lockstep = self.tickets.is_empty() && core.steps_remaining() == 0;
        // hand the structure (history 1) to controllers that connected since the last turn
        let _ = self.structure.update_connections();
        if self.last_cleanup.elapsed() >= CLEANUP_PERIOD {
            self.node.try_cleanup_dead_nodes();
            self.last_cleanup = Instant::now();
        }
    }

    /// Registers the node's event listener (a datagram socket) for the loop's readiness poll.
    fn register_wake(&mut self, registry: &mio::Registry, token: mio::Token) -> std::io::Result<bool> {
        // SAFETY: the descriptor stays open as long as `self.wake`; the poll it joins belongs to
        // the same `SimNode` and is only waited on while this transport lives, and a closed
        // descriptor leaves epoll by itself
        #[allow(unsafe_code)]
        let fd = unsafe { self.wake.file_descriptor().native_handle() };
        registry.register(&mut mio::unix::SourceFd(&fd), token, mio::Interest::READABLE)?;
        Ok(true)
    }

    /// Busy-polls until the spin window after a lockstep answer ends (a controller in lockstep
    /// asks again within microseconds), then empties the listener so the poll reports the next
    /// notification, and says whether input arrived meanwhile.
    fn before_wait(&mut self, deadline: Instant) -> bool {
        if let Some(until) = self.spin_until.take() {
            if poll(until.min(deadline), || self.input_waiting()) {
                return true;
            }
        }
        // the events only wake; what arrived is read from the services
        let _ = self.wake.try_wait(|_| {});
        self.input_waiting()
    }

    fn answering(&self) -> bool {
        !self.tickets.is_empty()
    }
}
