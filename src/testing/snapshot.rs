//! What a test reads and sends: `Snapshot` (the state after a step, by name, with its contacts),
//! `Names` (the scene's names in array order) and `Command` (one actuator command, built by
//! name).

use std::sync::Arc;

use crate::io::msg::{self};
use crate::io::sink::{NodeStats, NodeView};
use crate::model::Model;

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
    /// Each contact's two names (`Model::contact_labels`): a sphere's point and its ground
    /// (`x0.b`, `floor`), then each colliding strut pair's two bars.
    pub contacts: Vec<(String, String)>,
}

impl Names {
    pub(crate) fn of(model: &Model) -> Self {
        Self {
            scene: model.name.clone(),
            bodies: model.bodies.iter().map(|b| b.name.clone()).collect(),
            cables: model.cable_names.clone(),
            actuators: model.actuator_names.clone(),
            contacts: model.contact_labels().map(|(a, b)| (a.to_string(), b.to_string())).collect(),
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
    /// Each contact (in `Names::contacts` order; empty for a scene without contact).
    pub contacts: Vec<ContactSnapshot>,
    /// The node's counters at this state.
    pub stats: NodeStats,
}

/// What one contact is doing (`report::ContactReport`, without the names).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct ContactSnapshot {
    /// Pressed in.
    pub in_contact: bool,
    /// Signed distance of the surfaces, m (negative: pressed in).
    pub gap: f64,
    /// The contact point, m.
    pub position: [f64; 3],
    /// Unit normal (a ground's outward one; for two struts, from the second toward the first).
    pub normal: [f64; 3],
    /// Normal force, N.
    pub normal_force: f64,
    /// Friction force on the body (the first bar), N.
    pub friction: [f64; 3],
    /// Slip speed, m/s.
    pub slip_speed: f64,
}

impl Snapshot {
    pub(crate) fn empty(names: Arc<Names>) -> Self {
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
            contacts: Vec::new(),
            stats: NodeStats::default(),
        }
    }

    /// The state `v` shows, named by `names`.
    pub(crate) fn of(names: Arc<Names>, v: &NodeView<'_>) -> Self {
        let mut s = Self::empty(names);
        s.fill(v);
        s
    }

    /// Copies `v` in, reusing this snapshot's buffers (no allocation once they have the size).
    pub(crate) fn fill(&mut self, v: &NodeView<'_>) {
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
        self.contacts.clear();
        for c in &ws.contacts {
            self.contacts.push(ContactSnapshot {
                in_contact: c.in_contact(),
                gap: c.gap,
                position: c.position.into(),
                normal: c.normal.into(),
                normal_force: c.normal_force,
                friction: c.friction.into(),
                slip_speed: c.slip.norm(),
            });
        }
    }

    /// The first contact of point `name` (a sphere's centre, `body.point`; for a strut pair, its
    /// first bar).
    pub fn contact(&self, name: &str) -> Option<&ContactSnapshot> {
        self.names.contacts.iter().position(|c| c.0 == name).map(|k| &self.contacts[k])
    }

    /// The points (a sphere's, `body.point`) that press into a ground now, in contact order;
    /// for a strut pair in contact, its first bar.
    pub fn touching(&self) -> impl Iterator<Item = &str> + '_ {
        self.names
            .contacts
            .iter()
            .zip(&self.contacts)
            .filter(|(_, c)| c.in_contact)
            .map(|(n, _)| n.0.as_str())
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

/// One actuator command: a target rest length (m) and/or a rate (m/s), or a tension (N) alone for
/// a winch actuator, checked by the node exactly like a DDS `~/actuator_commands` (or
/// `~/tension_commands`) message (finite, within the actuator's limits, known name).
#[derive(Debug, Clone, PartialEq)]
pub struct Command {
    /// Actuator name.
    pub actuator: String,
    /// Target rest length, m.
    pub rest_length: Option<f64>,
    /// Rate, m/s (towards the target, or a steady rate without one).
    pub rate: Option<f64>,
    /// Tension, N (the winch motor's tension mode).
    pub tension: Option<f64>,
}

impl Command {
    /// A command for actuator `name` that changes nothing yet.
    pub fn new(actuator: &str) -> Self {
        Self { actuator: actuator.to_string(), rest_length: None, rate: None, tension: None }
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
    /// With a tension, N (alone: a tension command for the actuator's winch motor).
    pub fn tension(mut self, newtons: f64) -> Self {
        self.tension = Some(newtons);
        self
    }
    /// The rest length and rate as the DDS `~/actuator_commands` message carries them (a
    /// tension goes on `~/tension_commands`: `tension_message`).
    pub fn message(&self) -> msg::ActuatorCommand {
        msg::ActuatorCommand {
            name: vec![self.actuator.clone()],
            rest_length: self.rest_length.into_iter().collect(),
            rate: self.rate.into_iter().collect(),
            ..Default::default()
        }
    }
    /// The tension as the DDS `~/tension_commands` message carries it.
    pub fn tension_message(&self) -> msg::TensionCommand {
        msg::TensionCommand {
            name: vec![self.actuator.clone()],
            tension: self.tension.into_iter().collect(),
            ..Default::default()
        }
    }
}
