//! Wire types: takes the simulator's `Model`, `State` and evaluated `Workspace`, gives flat serde
//! structs whose fields follow the `.msg` files in `msg/msg/` (and the standard ROS 2 types they
//! use) in order, so that CDR serialization matches, and the `simulation_interfaces` codes.
//! Wire structs only: what checks an incoming command is `io::commands`, which message each
//! topic carries is `io::sink::TopicMessage`. `tests/msg_sync.rs` keeps these structs and the
//! `.msg` files identical field by field. Imports no other `io` module.

use serde::{Deserialize, Serialize};

use crate::control;
use crate::evaluate::Workspace;
use crate::model::{ActuatorId, Model};
use crate::report;
use crate::state::State;

/// `simulation_interfaces/msg/SimulationState` codes.
pub mod sim_state {
    /// Stopped (reset and paused).
    pub const STOPPED: u8 = 0;
    /// Playing.
    pub const PLAYING: u8 = 1;
    /// Paused.
    pub const PAUSED: u8 = 2;
    /// Quitting.
    pub const QUITTING: u8 = 3;
}

/// `simulation_interfaces/msg/Result` codes.
pub mod result_code {
    /// Success.
    pub const OK: u8 = 1;
    /// The request is not valid in the current state.
    pub const INCORRECT_STATE: u8 = 3;
    /// The operation failed.
    pub const OPERATION_FAILED: u8 = 4;
    /// Already in the requested state.
    pub const ALREADY_IN_TARGET_STATE: u8 = 101;
}

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
    /// Tensions, N (an elastic member's is negative in compression).
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
    /// Per pulley: true while a pulley with friction holds the cable.
    pub pulley_sticks: Vec<bool>,
    /// Per pulley: slip speed over the last step, m/s, positive toward the last anchor (0 for a
    /// frictionless pulley).
    pub pulley_slip_speed: Vec<f64>,
    /// Per pulley: tension after it over tension before it (0 when either side is slack).
    pub pulley_tension_ratio: Vec<f64>,
}

impl CableStates {
    /// Replaces the tensions, lengths and rest lengths by what the scene's sensors report in
    /// `measured` (`crate::sensors::Sensors::measured`), where it declares them; the strains
    /// follow the reported lengths and rest lengths.
    pub fn measure(&mut self, model: &Model, measured: &[f64]) {
        use crate::sensors::{reading, SensorKind};
        if measured.is_empty() {
            return;
        }
        if let Some(t) = reading(model, measured, SensorKind::Tension) {
            self.tension.copy_from_slice(t);
        }
        let lengths = reading(model, measured, SensorKind::Length);
        if let Some(l) = lengths {
            self.length.copy_from_slice(l);
        }
        let rest_lengths = reading(model, measured, SensorKind::RestLength);
        if let Some(l0) = rest_lengths {
            for (a, l0) in model.actuators.iter().zip(l0) {
                self.rest_length[a.cable.0] = *l0;
            }
        }
        if lengths.is_some() || rest_lengths.is_some() {
            for ((e, l), l0) in self.strain.iter_mut().zip(&self.length).zip(&self.rest_length) {
                *e = (l - l0) / l0;
            }
        }
    }

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
            if c.pulleys.is_empty() {
                // frictionless: one tension along the route
                let pulleys = c.pulley_slip.len();
                let ratio = crate::forces::pulley::tension_ratio(c.tension, c.tension);
                m.pulley_sticks.extend(std::iter::repeat_n(false, pulleys));
                m.pulley_slip_speed.extend(std::iter::repeat_n(0.0, pulleys));
                m.pulley_tension_ratio.extend(std::iter::repeat_n(ratio, pulleys));
            }
            for p in &c.pulleys {
                m.pulley_sticks.push(p.state == "stick");
                m.pulley_slip_speed.push(p.slip_speed_m_s);
                m.pulley_tension_ratio.push(p.tension_ratio());
            }
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
            &self.pulley_slip_speed,
            &self.pulley_tension_ratio,
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

/// `tensegrity_msgs/msg/ImuStates`: every body's IMU (gyro and accelerometer) in its own axes.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct ImuStates {
    /// Stamp (the step's simulation time) and frame.
    pub header: Header,
    /// Body names.
    pub name: Vec<String>,
    /// Angular velocities, rad/s, body axes; empty where the gyro is not declared.
    pub angular_velocity: Vec<Vector3>,
    /// Specific forces `R^T (a - g)`, m/s^2, body axes; empty where the accelerometer is not
    /// declared.
    pub specific_force: Vec<Vector3>,
}

impl ImuStates {
    /// The message at sim time `time` from the true IMU values `truth` (`[gyro, specific force]`
    /// per body, `crate::sensors::Sensors::imu_truth`), with what the sensors report in
    /// `measured` (`crate::sensors::Sensors::measured`) in their place when `measured` is not
    /// empty: then only the declared channels' arrays are filled.
    pub fn from_imu(model: &Model, time: f64, truth: &[f64], measured: &[f64], frame: &str) -> Self {
        use crate::sensors::{reading, SensorKind};
        let vectors = |v: &[f64]| v.chunks_exact(3).map(|c| Vector3 { x: c[0], y: c[1], z: c[2] }).collect();
        let (angular_velocity, specific_force) = if measured.is_empty() {
            let mut split = (Vec::new(), Vec::new());
            for body in truth.chunks_exact(6) {
                split.0.push(Vector3 { x: body[0], y: body[1], z: body[2] });
                split.1.push(Vector3 { x: body[3], y: body[4], z: body[5] });
            }
            split
        } else {
            let of = |kind| reading(model, measured, kind).map(vectors).unwrap_or_default();
            (of(SensorKind::Gyro), of(SensorKind::Accelerometer))
        };
        Self {
            header: Header { stamp: Time::from_seconds(time), frame_id: frame.to_string() },
            name: model.bodies.iter().map(|b| b.name.clone()).collect(),
            angular_velocity,
            specific_force,
        }
    }

    /// True when every number is finite.
    pub fn is_finite(&self) -> bool {
        self.angular_velocity
            .iter()
            .chain(&self.specific_force)
            .all(|v| v.x.is_finite() && v.y.is_finite() && v.z.is_finite())
    }
}

/// `tensegrity_msgs/msg/SensorReadings`: what every declared sensor channel reports, with a
/// lost flag per value.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct SensorReadings {
    /// Stamp (the step's simulation time) and frame.
    pub header: Header,
    /// Declared channels (`crate::sensors::SensorKind::name`), in `SensorKind::ALL` order.
    pub channel: Vec<String>,
    /// Values per channel (`crate::sensors::SensorKind::len`).
    pub count: Vec<u32>,
    /// What the channels report, concatenated (`crate::sensors::Sensors::measured`).
    pub value: Vec<f64>,
    /// Parallel to `value`: held after a lost update (`crate::sensors::Sensors::lost`).
    pub lost: Vec<bool>,
}

impl SensorReadings {
    /// The message at sim time `time` from what the sensors of `model` report (`measured`) and
    /// their lost flags (`lost`, parallel to it).
    pub fn from_sensors(model: &Model, time: f64, measured: &[f64], lost: &[bool], frame: &str) -> Self {
        let layout: Vec<_> = crate::sensors::layout(model).collect();
        Self {
            header: Header { stamp: Time::from_seconds(time), frame_id: frame.to_string() },
            channel: layout.iter().map(|(kind, _, _)| kind.name().to_string()).collect(),
            count: layout.iter().map(|(_, _, n)| *n as u32).collect(),
            value: measured.to_vec(),
            lost: lost.to_vec(),
        }
    }

    /// True when every number is finite.
    pub fn is_finite(&self) -> bool {
        self.value.iter().all(|x| x.is_finite())
    }
}

/// `tensegrity_msgs/msg/TensionCommand`: tension commands for winch actuators (on
/// `~/tension_commands`; a type of its own, so that `ActuatorCommand` stays what existing
/// controllers write).
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct TensionCommand {
    /// Stamp and frame (not used for timing: commands apply at the next step).
    pub header: Header,
    /// Actuator names.
    pub name: Vec<String>,
    /// Tensions, N: parallel to `name`.
    pub tension: Vec<f64>,
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
    /// The scene's `[randomize]` seed (0 without).
    pub randomize_seed: u64,
    /// Resets that drew anew (0 at the start, and without per-reset randomization).
    pub randomize_episode: u32,
    /// Each draw's parameter.
    pub randomized_parameter: Vec<String>,
    /// Each draw's element (cable, or body for mass).
    pub randomized_element: Vec<String>,
    /// Each draw's factor, or offset for a rest length.
    pub randomized_drawn: Vec<f64>,
    /// Each draw's value used.
    pub randomized_value: Vec<f64>,
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
            randomize_seed: model.randomization.map_or(0, |r| r.seed),
            randomize_episode: model.randomization.map_or(0, |r| r.episode as u32),
            randomized_parameter: model.randomized.iter().map(|d| d.parameter.name().to_string()).collect(),
            randomized_element: model.randomized.iter().map(|d| d.element.clone()).collect(),
            randomized_drawn: model.randomized.iter().map(|d| d.drawn).collect(),
            randomized_value: model.randomized.iter().map(|d| d.value).collect(),
        }
    }
}

/// `rosgraph_msgs/msg/Clock`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct Clock {
    /// Simulation time.
    pub clock: Time,
}

/// `geometry_msgs/msg/Point`.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct Point {
    /// m.
    pub x: f64,
    /// m.
    pub y: f64,
    /// m.
    pub z: f64,
}

/// `geometry_msgs/msg/Quaternion`.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct Quaternion {
    /// x.
    pub x: f64,
    /// y.
    pub y: f64,
    /// z.
    pub z: f64,
    /// w.
    pub w: f64,
}

/// `geometry_msgs/msg/Pose`.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct Pose {
    /// Position, m.
    pub position: Point,
    /// Orientation.
    pub orientation: Quaternion,
}

/// `geometry_msgs/msg/PoseArray`.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct PoseArray {
    /// Stamp and frame.
    pub header: Header,
    /// Poses in structure order.
    pub poses: Vec<Pose>,
}

impl PoseArray {
    /// Every body's pose (centre of mass, body-to-world rotation).
    pub fn from_state(state: &State, frame: &str) -> Self {
        Self {
            header: Header { stamp: Time::from_seconds(state.time), frame_id: frame.into() },
            poses: state.poses.iter().map(pose_of).collect(),
        }
    }

    /// Replaces the positions and orientations by what the scene's sensors report in `measured`
    /// (`crate::sensors::Sensors::measured`), where it declares them.
    pub fn measure(&mut self, model: &Model, measured: &[f64]) {
        use crate::sensors::{reading, SensorKind};
        if let Some(x) = reading(model, measured, SensorKind::Position) {
            for (p, x) in self.poses.iter_mut().zip(x.chunks_exact(3)) {
                p.position = Point { x: x[0], y: x[1], z: x[2] };
            }
        }
        if let Some(q) = reading(model, measured, SensorKind::Orientation) {
            for (p, q) in self.poses.iter_mut().zip(q.chunks_exact(4)) {
                p.orientation = Quaternion { w: q[0], x: q[1], y: q[2], z: q[3] };
            }
        }
    }
}

fn pose_of(p: &crate::model::Pose) -> Pose {
    let q = p.rotation.quaternion();
    Pose {
        position: Point { x: p.position.x, y: p.position.y, z: p.position.z },
        orientation: Quaternion { x: q.i, y: q.j, z: q.k, w: q.w },
    }
}

/// `geometry_msgs/msg/Vector3`.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct Vector3 {
    /// x.
    pub x: f64,
    /// y.
    pub y: f64,
    /// z.
    pub z: f64,
}

/// `tensegrity_msgs/msg/ContactStates`.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct ContactStates {
    /// Stamp and frame.
    pub header: Header,
    /// Each pair's sphere centre point (`body.point`, or `body` for a node; a strut pair: its first bar).
    pub point: Vec<String>,
    /// Each pair's ground (a strut pair: its second bar).
    pub ground: Vec<String>,
    /// Pressing into the ground.
    pub in_contact: Vec<bool>,
    /// Signed distance of the sphere's surface from the ground, m (negative: pressed in).
    pub gap: Vec<f64>,
    /// Contact point on the ground, m.
    pub position: Vec<Point>,
    /// The ground's outward unit normal.
    pub normal: Vec<Vector3>,
    /// Normal force, N.
    pub normal_force: Vec<f64>,
    /// Friction force on the body, N.
    pub friction: Vec<Vector3>,
    /// Slip speed of the contact point, m/s.
    pub slip_speed: Vec<f64>,
}

impl ContactStates {
    /// Every contact pair of an evaluated state (`report::contact_reports`).
    pub fn from_state(model: &Model, state: &State, ws: &Workspace, frame: &str) -> Self {
        let mut m = Self {
            header: Header { stamp: Time::from_seconds(state.time), frame_id: frame.into() },
            ..Default::default()
        };
        let v = |a: [f64; 3]| Vector3 { x: a[0], y: a[1], z: a[2] };
        for c in report::contact_reports(model, ws) {
            m.point.push(c.point);
            m.ground.push(c.ground);
            m.in_contact.push(c.in_contact);
            m.gap.push(c.gap_m);
            let p = c.position_m;
            m.position.push(Point { x: p[0], y: p[1], z: p[2] });
            m.normal.push(v(c.normal));
            m.normal_force.push(c.normal_force_n);
            m.friction.push(v(c.friction_n));
            m.slip_speed.push(c.slip_speed_m_s);
        }
        m
    }

    /// True if every number is finite (nothing else may be published).
    pub fn is_finite(&self) -> bool {
        let finite3 = |v: &Vector3| v.x.is_finite() && v.y.is_finite() && v.z.is_finite();
        self.gap.iter().chain(&self.normal_force).chain(&self.slip_speed).all(|x| x.is_finite())
            && self.position.iter().all(|p| p.x.is_finite() && p.y.is_finite() && p.z.is_finite())
            && self.normal.iter().all(finite3)
            && self.friction.iter().all(finite3)
    }
}

/// `geometry_msgs/msg/Transform`.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct Transform {
    /// Translation, m.
    pub translation: Vector3,
    /// Rotation.
    pub rotation: Quaternion,
}

/// `geometry_msgs/msg/TransformStamped`.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct TransformStamped {
    /// Stamp and parent frame.
    pub header: Header,
    /// Child frame.
    pub child_frame_id: String,
    /// Parent-to-child transform.
    pub transform: Transform,
}

/// `tf2_msgs/msg/TFMessage`.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct TfMessage {
    /// Transforms.
    pub transforms: Vec<TransformStamped>,
}

impl TfMessage {
    /// One transform per body (`fixed` bodies when `fixed` is true, the others otherwise), from
    /// `frame` to a child frame named after the body.
    pub fn from_state(model: &Model, state: &State, frame: &str, fixed: bool) -> Self {
        let transforms = model
            .bodies
            .iter()
            .zip(&state.poses)
            .filter(|(b, _)| (b.kind == crate::model::BodyKind::Fixed) == fixed)
            .map(|(b, p)| {
                let pose = pose_of(p);
                TransformStamped {
                    header: Header { stamp: Time::from_seconds(state.time), frame_id: frame.into() },
                    child_frame_id: b.name.clone(),
                    transform: Transform {
                        translation: Vector3 { x: pose.position.x, y: pose.position.y, z: pose.position.z },
                        rotation: pose.orientation,
                    },
                }
            })
            .collect();
        Self { transforms }
    }
}

/// `sensor_msgs/msg/JointState`: for actuators, position = rest length (m), velocity = its rate
/// (m/s), effort = the cable's tension (N).
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct JointState {
    /// Stamp and frame.
    pub header: Header,
    /// Actuator names.
    pub name: Vec<String>,
    /// Rest lengths, m.
    pub position: Vec<f64>,
    /// Rates, m/s.
    pub velocity: Vec<f64>,
    /// Tensions, N.
    pub effort: Vec<f64>,
}

impl JointState {
    /// The actuators of an evaluated state; `rates` holds each cable's rest-length rate (m/s).
    pub fn actuators(model: &Model, state: &State, ws: &Workspace, rates: &[f64]) -> Self {
        let mut m = Self {
            header: Header { stamp: Time::from_seconds(state.time), frame_id: String::new() },
            ..Default::default()
        };
        for (i, a) in model.actuators.iter().enumerate() {
            m.name.push(model.actuator_names[i].clone());
            m.position.push(state.rest_lengths[a.cable.0]);
            m.velocity.push(rates[a.cable.0]);
            m.effort.push(ws.cables[a.cable.0].tension);
        }
        m
    }

    /// As actuator commands (topic-based ros2_control convention): position = target rest
    /// length, velocity = rate; each array empty or parallel to `name`. (With both empty, the
    /// node reads `effort` as tensions: `io::node::NodeCore::offer_joint_command`.)
    pub fn as_command(&self) -> ActuatorCommand {
        ActuatorCommand {
            header: self.header.clone(),
            name: self.name.clone(),
            rest_length: self.position.clone(),
            rate: self.velocity.clone(),
        }
    }
}

/// `tensegrity_msgs/msg/AppliedCommands`: the commands the simulator applied at one step
/// boundary, or a reset there (what a bag needs to replay a run; see `io::bag`).
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct AppliedCommands {
    /// Stamp: the simulation time of the boundary, s.
    pub header: Header,
    /// Steps taken since the start (resets do not restart it) at the boundary: the commands act
    /// from step `step + 1` on.
    pub step: u64,
    /// True: the simulation was reset to its initial state here (the arrays are empty).
    pub reset: bool,
    /// Actuator names, in the order the commands were applied.
    pub name: Vec<String>,
    /// Target rest lengths, m; NaN where the command gave none.
    pub rest_length: Vec<f64>,
    /// Rates, m/s; NaN where the command gave none.
    pub rate: Vec<f64>,
    /// Tensions, N; NaN where the command gave none. Empty in bags written before tension
    /// commands existed (the recorder's `applied_commands` reads both layouts).
    pub tension: Vec<f64>,
    /// True: the reset drew its episode from `reset_seed` (`NodeCore::reset_seeded`).
    pub reset_seeded: bool,
    /// The reset episode's seed (with `reset_seeded`).
    pub reset_seed: u64,
}

impl AppliedCommands {
    /// The message for `commands` applied at sim time `time` after `step` steps; `names` are the
    /// model's actuator names.
    pub fn new(
        names: &[String],
        time: f64,
        step: u64,
        commands: &[(ActuatorId, control::ActuatorCommand)],
    ) -> Self {
        Self {
            header: Header { stamp: Time::from_seconds(time), frame_id: String::new() },
            step,
            reset: false,
            name: commands.iter().map(|(id, _)| names[id.0].clone()).collect(),
            rest_length: commands.iter().map(|(_, c)| c.rest_length.unwrap_or(f64::NAN)).collect(),
            rate: commands.iter().map(|(_, c)| c.rate.unwrap_or(f64::NAN)).collect(),
            tension: commands.iter().map(|(_, c)| c.tension.unwrap_or(f64::NAN)).collect(),
            reset_seeded: false,
            reset_seed: 0,
        }
    }
}

/// `diagnostic_msgs/msg/KeyValue`.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct KeyValue {
    /// Key.
    pub key: String,
    /// Value.
    pub value: String,
}

/// `diagnostic_msgs/msg/DiagnosticStatus` (level: 0 OK, 1 WARN, 2 ERROR, 3 STALE).
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct DiagnosticStatus {
    /// Level.
    pub level: u8,
    /// Component name.
    pub name: String,
    /// Summary.
    pub message: String,
    /// Hardware id.
    pub hardware_id: String,
    /// Values.
    pub values: Vec<KeyValue>,
}

/// `diagnostic_msgs/msg/DiagnosticArray`.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct DiagnosticArray {
    /// Stamp.
    pub header: Header,
    /// Statuses.
    pub status: Vec<DiagnosticStatus>,
}

/// An empty ROS message (`std_srvs/srv/Empty` request and response, and empty service requests):
/// rosidl gives empty structures one placeholder byte.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct Empty {
    /// Placeholder (always 0).
    pub structure_needs_at_least_one_member: u8,
}

/// `simulation_interfaces/msg/Result` (2.1.0).
#[derive(Debug, Clone, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct SimResult {
    /// `FEATURE_UNSUPPORTED = 0`, `OK = 1`, `NOT_FOUND = 2`, `INCORRECT_STATE = 3`,
    /// `OPERATION_FAILED = 4`, service-specific codes above 100.
    pub result: u8,
    /// Details when useful.
    pub error_message: String,
}

impl SimResult {
    /// `OK`.
    pub fn ok() -> Self {
        Self { result: 1, error_message: String::new() }
    }
    /// A failure code with its message.
    pub fn err(result: u8, message: impl Into<String>) -> Self {
        Self { result, error_message: message.into() }
    }
}

/// `simulation_interfaces/msg/SimulationState`: `STOPPED = 0`, `PLAYING = 1`, `PAUSED = 2`,
/// `QUITTING = 3`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct SimulationState {
    /// State code.
    pub state: u8,
}

/// `simulation_interfaces/srv/StepSimulation` request.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct StepSimulationRequest {
    /// Steps to take (default 1).
    pub steps: u64,
}

/// A StepSimulation request as the server reads it off the wire: `steps`, and how many bytes
/// followed it. A request in the layout the server was configured for carries at most 3 bytes of
/// CDR padding after `steps`; a request in another service mapping's layout (e.g. the 16-byte
/// rmw_cyclonedds header in front, read by an `enhanced` server) has more, or too few, and must be
/// refused rather than obeyed: its `steps` would be a header field.
///
/// Deserializes as a CDR tuple of unbounded length (`u64`, then bytes until the input ends), so
/// it is only meaningful with a CDR deserializer; it serializes as a plain `StepSimulationRequest`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct StepSimulationWire {
    /// Steps asked for.
    pub steps: u64,
    /// Bytes after `steps` in the payload.
    pub trailing_bytes: usize,
}

impl StepSimulationWire {
    /// Most trailing bytes that are padding, not another layout.
    pub const MAX_PADDING: usize = 3;
    /// True when the payload had exactly the request's layout.
    pub fn layout_matches(&self) -> bool {
        self.trailing_bytes <= Self::MAX_PADDING
    }
}

impl Serialize for StepSimulationWire {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        StepSimulationRequest { steps: self.steps }.serialize(s)
    }
}

impl<'de> Deserialize<'de> for StepSimulationWire {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct Visitor;
        impl<'de> serde::de::Visitor<'de> for Visitor {
            type Value = StepSimulationWire;
            fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
                f.write_str("a StepSimulation request (uint64 steps)")
            }
            fn visit_seq<A: serde::de::SeqAccess<'de>>(self, mut seq: A) -> Result<Self::Value, A::Error> {
                let steps: u64 =
                    seq.next_element()?.ok_or_else(|| serde::de::Error::invalid_length(0, &self))?;
                let mut trailing_bytes = 0;
                // the end of the input shows up as an error or as the end of the sequence
                while let Ok(Some(_)) = seq.next_element::<u8>() {
                    trailing_bytes += 1;
                }
                Ok(StepSimulationWire { steps, trailing_bytes })
            }
        }
        d.deserialize_tuple(usize::MAX, Visitor)
    }
}

/// Response of the services that only return a `Result` (StepSimulation, ResetSimulation,
/// SetSimulationState).
#[derive(Debug, Clone, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct ResultResponse {
    /// Outcome.
    pub result: SimResult,
}

/// `simulation_interfaces/srv/ResetSimulation` request: `SCOPE_DEFAULT = 0`, `SCOPE_TIME = 1`,
/// `SCOPE_STATE = 2`, `SCOPE_SPAWNED = 4`, `SCOPE_ALL = 255`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct ResetSimulationRequest {
    /// Scope.
    pub scope: u8,
}

/// `simulation_interfaces/srv/GetSimulationState` response.
#[derive(Debug, Clone, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct GetSimulationStateResponse {
    /// Current state.
    pub state: SimulationState,
    /// Outcome.
    pub result: SimResult,
}

/// `simulation_interfaces/srv/SetSimulationState` request.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct SetSimulationStateRequest {
    /// Target state.
    pub state: SimulationState,
}

/// `simulation_interfaces/msg/SimulatorFeatures`.
#[derive(Debug, Clone, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct SimulatorFeatures {
    /// Feature codes (`SIMULATION_RESET = 20`, `SIMULATION_STATE_GETTING = 24`,
    /// `SIMULATION_STATE_SETTING = 25`, `SIMULATION_STATE_PAUSE = 26`,
    /// `STEP_SIMULATION_SINGLE = 31`, `STEP_SIMULATION_MULTIPLE = 32`, ...).
    pub features: Vec<u16>,
    /// Spawn formats (none).
    pub spawn_formats: Vec<String>,
    /// Free text.
    pub custom_info: String,
}

/// `simulation_interfaces/srv/GetSimulatorFeatures` response.
#[derive(Debug, Clone, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct GetSimulatorFeaturesResponse {
    /// Supported features.
    pub features: SimulatorFeatures,
}

/// `builtin_interfaces/msg/Duration`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct Duration {
    /// Seconds.
    pub sec: i32,
    /// Nanoseconds.
    pub nanosec: u32,
}

/// `std_msgs/msg/ColorRGBA`.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct ColorRgba {
    /// Red, 0-1.
    pub r: f32,
    /// Green, 0-1.
    pub g: f32,
    /// Blue, 0-1.
    pub b: f32,
    /// Alpha, 0-1.
    pub a: f32,
}

/// `sensor_msgs/msg/CompressedImage` (unused by our markers, part of their layout).
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct CompressedImage {
    /// Stamp and frame.
    pub header: Header,
    /// Image format.
    pub format: String,
    /// Bytes.
    pub data: Vec<u8>,
}

/// `visualization_msgs/msg/UVCoordinate`.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct UvCoordinate {
    /// u.
    pub u: f32,
    /// v.
    pub v: f32,
}

/// `visualization_msgs/msg/MeshFile`.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct MeshFile {
    /// File name.
    pub filename: String,
    /// Contents.
    pub data: Vec<u8>,
}

/// `visualization_msgs/msg/Marker` (layout of Humble, Jazzy and Rolling).
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct Marker {
    /// Stamp and frame.
    pub header: Header,
    /// Namespace.
    pub ns: String,
    /// Id within the namespace.
    pub id: i32,
    /// `LINE_LIST = 5`, `SPHERE_LIST = 7`, ...
    #[serde(rename = "type")]
    pub kind: i32,
    /// `ADD = 0`.
    pub action: i32,
    /// Pose of the marker frame.
    pub pose: Pose,
    /// Line width / sphere size, m.
    pub scale: Vector3,
    /// Colour when `colors` is empty.
    pub color: ColorRgba,
    /// Lifetime (0 = forever).
    pub lifetime: Duration,
    /// Follow the frame.
    pub frame_locked: bool,
    /// Points.
    pub points: Vec<Point>,
    /// Per-point colours.
    pub colors: Vec<ColorRgba>,
    /// Unused.
    pub texture_resource: String,
    /// Unused.
    pub texture: CompressedImage,
    /// Unused.
    pub uv_coordinates: Vec<UvCoordinate>,
    /// Unused.
    pub text: String,
    /// Unused.
    pub mesh_resource: String,
    /// Unused.
    pub mesh_file: MeshFile,
    /// Unused.
    pub mesh_use_embedded_materials: bool,
}

/// `visualization_msgs/msg/MarkerArray`.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct MarkerArray {
    /// Markers.
    pub markers: Vec<Marker>,
}

impl MarkerArray {
    /// RViz view of an evaluated state: struts (bars, and rigid bodies' points joined to their
    /// centre) as grey lines, nodes as spheres, and cable segments coloured from blue (no tension)
    /// to red (the largest tension), slack cables pale grey. In a scene with grounds, also the
    /// contact points that press into a ground (green spheres, `contacts`) and their forces
    /// (`contact_forces`: a line from each contact point along the force on the body, normal and
    /// friction, the largest force drawn a fifth of the structure's size long).
    pub fn from_state(model: &Model, state: &State, ws: &Workspace, frame: &str) -> Self {
        use crate::render::CableLook;
        let header = Header { stamp: Time::from_seconds(state.time), frame_id: frame.into() };
        let point = |p: &nalgebra::Vector3<f64>| Point { x: p.x, y: p.y, z: p.z };
        let identity =
            Pose { orientation: Quaternion { w: 1.0, ..Default::default() }, ..Default::default() };
        let base = |ns: &str, kind: i32, width: f64, color: ColorRgba| Marker {
            header: header.clone(),
            ns: ns.into(),
            kind,
            pose: identity,
            scale: Vector3 { x: width, y: width, z: width },
            color,
            ..Default::default()
        };
        let grey = ColorRgba { r: 0.35, g: 0.35, b: 0.38, a: 1.0 };
        let shown = crate::render::primitives(model, state, ws);
        let mut struts = base("struts", 5, 0.03, grey);
        let mut nodes = base("nodes", 7, 0.06, grey);
        for [a, b] in &shown.struts {
            struts.points.extend([point(a), point(b)]);
        }
        nodes.points.extend(shown.nodes.iter().map(point));
        let mut cables = base("cables", 5, 0.012, grey);
        for ([a, b], look) in &shown.cables {
            let color = match *look {
                CableLook::Member => ColorRgba { r: 0.35, g: 0.35, b: 0.35, a: 1.0 }, // a strut's grey
                CableLook::Taut(s) => ColorRgba { r: s, g: 0.1, b: 1.0 - s, a: 1.0 },
                CableLook::Slack => ColorRgba { r: 0.8, g: 0.8, b: 0.8, a: 0.6 },
            };
            cables.points.extend([point(a), point(b)]);
            cables.colors.extend([color, color]);
        }
        let mut markers = vec![struts, cables];
        if !nodes.points.is_empty() {
            markers.push(nodes);
        }
        if model.contact_pairs() > 0 {
            let green = ColorRgba { r: 0.1, g: 0.7, b: 0.2, a: 1.0 };
            let mut touching = base("contacts", 7, 0.04, green);
            let mut forces = base("contact_forces", 5, 0.01, ColorRgba { r: 0.1, g: 0.5, b: 0.1, a: 1.0 });
            for [at, end] in &shown.contacts {
                touching.points.push(point(at));
                forces.points.extend([point(at), point(end)]);
            }
            markers.push(touching);
            markers.push(forces);
        }
        for (i, m) in markers.iter_mut().enumerate() {
            m.id = i as i32;
        }
        Self { markers }
    }
}
