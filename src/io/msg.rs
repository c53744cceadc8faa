//! Wire types: takes the simulator's `Model`, `State` and evaluated `Workspace`, gives flat serde
//! structs whose fields follow the `.msg` files in `msg/msg/` (and the standard ROS 2 types they
//! use) in order, so that CDR serialization matches; and turns an incoming `ActuatorCommand`
//! message into validated per-actuator commands. `tests/msg_sync.rs` keeps these structs and the
//! `.msg` files identical field by field.

use serde::{Deserialize, Serialize};

use crate::control;
use crate::forces::Workspace;
use crate::model::Model;
use crate::report;
use crate::state::State;

/// `builtin_interfaces/msg/Time`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct Time {
    /// Whole seconds.
    pub sec: i32,
    /// Nanoseconds, < 1e9.
    pub nanosec: u32,
}

impl Time {
    /// The time `t` seconds (>= 0), rounded to the nanosecond.
    pub fn from_seconds(t: f64) -> Self {
        let ns = (t.max(0.0) * 1e9).round() as u64;
        Self { sec: (ns / 1_000_000_000) as i32, nanosec: (ns % 1_000_000_000) as u32 }
    }
    /// Seconds.
    pub fn seconds(&self) -> f64 {
        self.sec as f64 + self.nanosec as f64 * 1e-9
    }
}

/// `std_msgs/msg/Header`.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct Header {
    /// Simulation time of the data.
    pub stamp: Time,
    /// Frame the data is expressed in.
    pub frame_id: String,
}

/// `tensegrity_msgs/msg/CableStates`.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct CableStates {
    /// Stamp and frame.
    pub header: Header,
    /// Cable names, in structure order.
    pub name: Vec<String>,
    /// Tensions, N.
    pub tension: Vec<f64>,
    /// Lengths, m.
    pub length: Vec<f64>,
    /// Rest lengths, m.
    pub rest_length: Vec<f64>,
    /// Strains.
    pub strain: Vec<f64>,
    /// Slack flags.
    pub slack: Vec<bool>,
    /// Segments per cable.
    pub segment_count: Vec<u32>,
    /// Segment lengths, concatenated, m.
    pub segment_length: Vec<f64>,
    /// Pulley slip, concatenated, m.
    pub pulley_slip: Vec<f64>,
}

impl CableStates {
    /// The cables of an evaluated state; `reference` holds each cable's pulley coordinates at the
    /// start (`report::all_pulley_coordinates`).
    pub fn from_state(
        model: &Model,
        state: &State,
        ws: &Workspace,
        reference: &[Vec<f64>],
        frame: &str,
    ) -> Self {
        let mut m = Self {
            header: Header { stamp: Time::from_seconds(state.time), frame_id: frame.into() },
            ..Default::default()
        };
        for c in report::cable_reports(model, state, ws, reference) {
            m.name.push(c.name);
            m.tension.push(c.tension);
            m.length.push(c.length);
            m.rest_length.push(c.rest_length);
            m.strain.push(c.strain);
            m.slack.push(c.slack);
            m.segment_count.push(c.segment_lengths.len() as u32);
            m.segment_length.extend(c.segment_lengths);
            m.pulley_slip.extend(c.pulley_slip);
        }
        m
    }

    /// True if every number is finite (nothing else may be published).
    pub fn is_finite(&self) -> bool {
        [
            &self.tension,
            &self.length,
            &self.rest_length,
            &self.strain,
            &self.segment_length,
            &self.pulley_slip,
        ]
        .iter()
        .all(|v| v.iter().all(|x| x.is_finite()))
    }
}

/// `tensegrity_msgs/msg/ActuatorCommand`.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct ActuatorCommand {
    /// Stamp and frame (not used for timing: commands apply at the next step).
    pub header: Header,
    /// Actuator names.
    pub name: Vec<String>,
    /// Target rest lengths, m: empty or parallel to `name`.
    pub rest_length: Vec<f64>,
    /// Rates, m/s: empty or parallel to `name`.
    pub rate: Vec<f64>,
}

/// Why an `ActuatorCommand` message was refused as a whole.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum MessageError {
    /// An array has the wrong length.
    #[error("{field} has {got} entries for {names} names (must be empty or parallel to name)")]
    WrongLength {
        /// Field name.
        field: &'static str,
        /// Entries received.
        got: usize,
        /// Number of names.
        names: usize,
    },
    /// One of the commands is invalid.
    #[error(transparent)]
    Command(#[from] control::CommandError),
}

impl ActuatorCommand {
    /// The per-actuator commands of this message, validated against `model` as a whole (a
    /// message with one bad entry is refused entirely, so that no partial update happens).
    pub fn commands(&self, model: &Model) -> Result<Vec<(String, control::ActuatorCommand)>, MessageError> {
        for (field, v) in [("rest_length", &self.rest_length), ("rate", &self.rate)] {
            if !v.is_empty() && v.len() != self.name.len() {
                return Err(MessageError::WrongLength { field, got: v.len(), names: self.name.len() });
            }
        }
        let mut check = control::Control::new(model);
        let mut out = Vec::with_capacity(self.name.len());
        for (i, name) in self.name.iter().enumerate() {
            let cmd = control::ActuatorCommand {
                rest_length: self.rest_length.get(i).copied(),
                rate: self.rate.get(i).copied(),
            };
            check.command_by_name(model, name, cmd)?;
            out.push((name.clone(), cmd));
        }
        Ok(out)
    }
}

/// `tensegrity_msgs/msg/Structure`.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct Structure {
    /// Stamp and frame.
    pub header: Header,
    /// Scene name.
    pub scene_name: String,
    /// Body names (order of body poses).
    pub body_names: Vec<String>,
    /// Body kinds.
    pub body_kinds: Vec<String>,
    /// Qualified point names.
    pub point_names: Vec<String>,
    /// Body index of each point.
    pub point_body: Vec<u32>,
    /// Cable names (order of cable states).
    pub cable_names: Vec<String>,
    /// First route point of each cable.
    pub cable_route_start: Vec<u32>,
    /// Route length of each cable.
    pub cable_route_length: Vec<u32>,
    /// Route points, concatenated.
    pub route_points: Vec<String>,
    /// Actuator names (order of actuator states).
    pub actuator_names: Vec<String>,
    /// Cable of each actuator.
    pub actuator_cables: Vec<String>,
    /// Minimum rest lengths, m.
    pub actuator_min_rest_length: Vec<f64>,
    /// Maximum rest lengths, m.
    pub actuator_max_rest_length: Vec<f64>,
    /// Maximum rates, m/s.
    pub actuator_max_rate: Vec<f64>,
}

impl Structure {
    /// The structure of `model`.
    pub fn from_model(model: &Model, frame: &str) -> Self {
        Self {
            header: Header { stamp: Time::default(), frame_id: frame.into() },
            scene_name: model.name.clone(),
            body_names: model.bodies.iter().map(|b| b.name.clone()).collect(),
            body_kinds: model.bodies.iter().map(|b| b.kind.as_str().to_string()).collect(),
            point_names: model.points.iter().map(|p| p.name.clone()).collect(),
            point_body: model.points.iter().map(|p| p.body.0 as u32).collect(),
            cable_names: model.cable_names.clone(),
            cable_route_start: model.cables.iter().map(|c| c.route_start as u32).collect(),
            cable_route_length: model.cables.iter().map(|c| c.route_len as u32).collect(),
            route_points: model.route_points.iter().map(|p| model.points[p.0].name.clone()).collect(),
            actuator_names: model.actuator_names.clone(),
            actuator_cables: model.actuators.iter().map(|a| model.cable_names[a.cable.0].clone()).collect(),
            actuator_min_rest_length: model.actuators.iter().map(|a| a.min_rest_length).collect(),
            actuator_max_rest_length: model.actuators.iter().map(|a| a.max_rest_length).collect(),
            actuator_max_rate: model.actuators.iter().map(|a| a.max_rate).collect(),
        }
    }
}
