//! The scene file's serde mirror: takes TOML text, gives a `SceneSpec` (every table and field as
//! written, unknown fields refused) or a `SceneError` naming file, line and field; also the
//! ranges numbers must lie in (`limits`), `to_toml` for the generators, and `locate`, the line of
//! a field that the build stages' errors name.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

use crate::error::SceneError;

/// The ranges a scene's numbers must lie in. They keep every product the solvers form finite in
/// double precision (EA times a strain times a Jacobian, masses over step squared) and refuse
/// numbers no structure has, so a typo (an exponent too many) is caught at load time.
pub mod limits {
    /// Physics step, s (shared with the node's `physics_dt` parameter).
    pub const PHYSICS_DT: (f64, f64) = (1e-6, 0.1);
    /// Largest |coordinate| of a position, bar end, point or pin, m.
    pub const MAX_COORDINATE: f64 = 1e6;
    /// Largest |rotation vector| component, rad.
    pub const MAX_ROTATION: f64 = 1e3;
    /// Masses, kg.
    pub const MASS: (f64, f64) = (1e-9, 1e9);
    /// Moments of inertia, kg m^2.
    pub const INERTIA: (f64, f64) = (1e-15, 1e12);
    /// Axial stiffness EA, N.
    pub const EA: (f64, f64) = (1e-6, 1e12);
    /// Bending stiffness EI, N m².
    pub const BENDING_STIFFNESS: (f64, f64) = (1e-12, 1e12);
    /// Buckling load, N.
    pub const BUCKLING_LOAD: (f64, f64) = (1e-9, 1e12);
    /// Damping coefficient, N s/m.
    pub const DAMPING: (f64, f64) = (0.0, 1e9);
    /// Damping ratio.
    pub const DAMPING_RATIO: (f64, f64) = (0.0, 100.0);
    /// Rayleigh mass-proportional coefficient alpha, 1/s.
    pub const RAYLEIGH_ALPHA: (f64, f64) = (0.0, 1e6);
    /// Rayleigh stiffness-proportional coefficient beta, s.
    pub const RAYLEIGH_BETA: (f64, f64) = (0.0, 1e3);
    /// Rest lengths and actuator limits, m.
    pub const LENGTH: (f64, f64) = (1e-9, 1e6);
    /// Prestress, N.
    pub const PRESTRESS: (f64, f64) = (0.0, 1e12);
    /// Force density, N/m.
    pub const FORCE_DENSITY: (f64, f64) = (0.0, 1e12);
    /// Actuator rates, m/s.
    pub const RATE: (f64, f64) = (1e-12, 1e6);
    /// Winch parameters (radius, tension, speed, motor constants, inertia, gains).
    pub const WINCH: (f64, f64) = (1e-12, 1e12);
    /// Command delay, steps (and a sensor's delay), in the step-counted fields.
    pub const COMMAND_DELAY: usize = 100_000;
    /// Command delay and a sensor's delay, s.
    pub const DELAY_S: (f64, f64) = (0.0, 1.0);
    /// A sensor's noise, bias and resolution, in its unit.
    pub const SENSOR_VALUE: (f64, f64) = (0.0, 1e12);
    /// A sensor's update rate, Hz.
    pub const SENSOR_RATE: (f64, f64) = (1e-6, 1e9);
    /// Largest |gravity| component, m/s^2.
    pub const MAX_GRAVITY: f64 = 1e3;
    /// Contact sphere radius, m.
    pub const CONTACT_RADIUS: (f64, f64) = (0.0, 1e6);
    /// Ground penalty stiffness, N/m.
    pub const CONTACT_STIFFNESS: (f64, f64) = (1e-6, 1e12);
    /// Hunt-Crossley dissipation, s/m.
    pub const CONTACT_DISSIPATION: (f64, f64) = (0.0, 1e6);
    /// Friction coefficient.
    pub const FRICTION: (f64, f64) = (0.0, 100.0);
    /// Friction regularization speed, m/s.
    pub const STICTION_SPEED: (f64, f64) = (1e-9, 1e3);
    /// Stick-slip friction's tangential stiffness, N/m.
    pub const STICK_STIFFNESS: (f64, f64) = (1e-6, 1e12);
    /// Stick-slip friction's tangential damping, N s/m.
    pub const STICK_DAMPING: (f64, f64) = (0.0, 1e9);
    /// Ramp start and duration, s.
    pub const TIME: (f64, f64) = (0.0, 1e6);
    /// Quasi-static load steps of a deployment.
    pub const MAX_LOAD_STEPS: usize = 1_000_000;
    /// Points on one cable's route.
    pub const MAX_ROUTE_POINTS: usize = 1000;
    /// Newton iterations per quasi-static load step.
    pub const MAX_SOLVER_ITERATIONS: usize = 10_000;
}

/// Deserializers that insist on the exact number of entries (serde's fixed-size arrays would
/// silently drop extra ones).
mod exact {
    use serde::de::{Deserializer, Error};
    use serde::Deserialize;

    fn three<E: Error>(v: Vec<f64>) -> Result<[f64; 3], E> {
        <[f64; 3]>::try_from(v.as_slice())
            .map_err(|_| E::custom(format!("expected exactly 3 numbers [x, y, z], got {}", v.len())))
    }
    pub fn vec3<'de, D: Deserializer<'de>>(d: D) -> Result<[f64; 3], D::Error> {
        three(Vec::<f64>::deserialize(d)?)
    }
    pub fn some_vec3<'de, D: Deserializer<'de>>(d: D) -> Result<Option<[f64; 3]>, D::Error> {
        vec3(d).map(Some)
    }
    pub fn some_ends<'de, D: Deserializer<'de>>(d: D) -> Result<Option<[[f64; 3]; 2]>, D::Error> {
        let v = Vec::<Vec<f64>>::deserialize(d)?;
        if v.len() != 2 {
            return Err(D::Error::custom(format!(
                "expected exactly 2 end points [[x, y, z], [x, y, z]], got {}",
                v.len()
            )));
        }
        let mut ends = v.into_iter().map(three::<D::Error>);
        Ok(Some([ends.next().expect("2")?, ends.next().expect("2")?]))
    }
}

/// A whole scene file.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SceneSpec {
    /// Scene name.
    #[serde(default, skip_serializing_if = "String::is_empty")]
    pub name: String,
    /// Free text.
    #[serde(default, skip_serializing_if = "String::is_empty")]
    pub description: String,
    /// Gravity acceleration, m/s^2, world frame (default none).
    #[serde(default, skip_serializing_if = "is_zero3", deserialize_with = "exact::vec3")]
    pub gravity: [f64; 3],
    /// 2-D scene: everything moves in the world xy plane.
    #[serde(default, skip_serializing_if = "is_false")]
    pub planar: bool,
    /// Physics step for dynamic runs and the node, s (1e-6 to 0.1); tools fall back to 0.001.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub physics_dt: Option<f64>,
    /// Quasi-static solver settings.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub solver: Option<SolverSpec>,
    /// Structural (Rayleigh) damping.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub damping: Option<DampingSpec>,
    /// Coulomb friction coefficient of every pulley whose cable does not say (default 0).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pulley_friction: Option<f64>,
    /// Bodies.
    #[serde(default)]
    pub bodies: Vec<BodySpec>,
    /// Ball joints and pins.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub joints: Vec<JointSpec>,
    /// Cables, classical (2 points) and sliding (more).
    #[serde(default)]
    pub cables: Vec<CableSpec>,
    /// Elastic members between two points: they push as well as pull (struts of a nodal,
    /// finite-element model between point masses).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub members: Vec<MemberSpec>,
    /// Actuators.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub actuators: Vec<ActuatorSpec>,
    /// Deployment schedule.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub deployment: Option<DeploymentSpec>,
    /// Half-space grounds that bodies with contact geometry (`contact_radius`) rest on.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub grounds: Vec<GroundSpec>,
    /// Strut-strut collision between bars' capsules (off unless declared).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub collisions: Option<CollisionSpec>,
    /// Sensor models (`[sensors]`; none: what the node publishes is the exact state).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sensors: Option<SensorsSpec>,
    /// Seeded randomization of parameters (`[randomize]`; none: the scene as written).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub randomize: Option<RandomizeSpec>,
}

/// Seeded randomization of scene parameters (`crate::randomize`), drawn when the model is built.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RandomizeSpec {
    /// Seed of the draws (default 0).
    #[serde(default)]
    pub seed: u64,
    /// `run` (default): one draw for every run of the scene; `reset`: the node draws anew at
    /// every reset (episode `k` with seed `seed + k`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub per: Option<String>,
    /// The parameters drawn, in order.
    #[serde(default)]
    pub parameters: Vec<RandomParameterSpec>,
}

/// One randomized parameter: which, of which elements, from which distribution.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RandomParameterSpec {
    /// `ea`, `damping`, `mass` or `pulley_friction` (factors on the nominal value), or
    /// `rest_length` (an offset, m).
    pub parameter: String,
    /// Cable names (bodies for `mass`); default every one that has the parameter.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub elements: Option<Vec<String>>,
    /// `uniform` (`low`, `high`), `normal` (`mean`, `sigma`) or `lognormal` (`mean`, `sigma` of
    /// the logarithm).
    pub distribution: String,
    /// Uniform: lower bound.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub low: Option<f64>,
    /// Uniform: upper bound.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub high: Option<f64>,
    /// Normal and lognormal: mean (of the logarithm for lognormal).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mean: Option<f64>,
    /// Normal and lognormal: standard deviation (of the logarithm for lognormal).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sigma: Option<f64>,
}

/// The scene's sensors (`crate::sensors`): a seed and one table per channel.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SensorsSpec {
    /// Seed of the noise generators (default 0).
    #[serde(default)]
    pub seed: u64,
    /// Every cable's tension, N.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub tension: Option<ChannelSpec>,
    /// Every cable's length, m.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub length: Option<ChannelSpec>,
    /// Every actuator's rest length (the winch's encoder), m.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rest_length: Option<ChannelSpec>,
    /// Every body's position, m.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub position: Option<ChannelSpec>,
    /// Every body's orientation (noise in rad; no bias or resolution).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub orientation: Option<ChannelSpec>,
    /// Every body's angular velocity in its own axes (an IMU's gyro), rad/s.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub gyro: Option<ChannelSpec>,
    /// Every body's specific force in its own axes (an IMU's accelerometer), m/s^2.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub accelerometer: Option<ChannelSpec>,
}

/// One sensor channel's imperfections; every field defaults to a perfect sensor.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ChannelSpec {
    /// Gaussian noise's standard deviation, in the channel's unit.
    #[serde(default)]
    pub sigma: f64,
    /// Constant offset, in the channel's unit.
    #[serde(default)]
    pub bias: f64,
    /// Quantization step (0: none).
    #[serde(default)]
    pub resolution: f64,
    /// Time between a measurement and its report, s.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub delay_s: Option<f64>,
    /// The same in physics steps (kept for one release; `delay_s` is the field).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub delay: Option<usize>,
    /// Updates per second (none: every step), held in between.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rate: Option<f64>,
    /// Probability that an update is lost (the last value is held), in [0, 1).
    #[serde(default)]
    pub dropout: f64,
}

/// Which bars collide with which, and the contact law between them
/// (`crate::forces::collision`): the same law as against a ground.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CollisionSpec {
    /// `"all"` (default): every two bars with a `contact_radius` that no joint joins; or a list
    /// of bar-name pairs, `[["s1", "s2"], ["s1", "s3"]]`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pairs: Option<CollisionPairsSpec>,
    /// Coulomb friction coefficient between struts (default 0.3; 0 is frictionless).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mu: Option<f64>,
    /// Penalty stiffness, N/m (default as a ground's: `1000 W / L`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub stiffness: Option<f64>,
    /// Hunt-Crossley dissipation, s/m (default 1).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub dissipation: Option<f64>,
    /// Friction regularization speed, m/s (default 1e-5).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub stiction_speed: Option<f64>,
}

/// The bar pairs of `[collisions]`: the word `all`, or a list of name pairs.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum CollisionPairsSpec {
    /// `"all"`.
    Word(String),
    /// `[["s1", "s2"], ...]`.
    List(Vec<[String; 2]>),
}

/// A half-space ground: a plane through `point` with outward `normal`, and its contact law
/// (`crate::forces::contact`).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GroundSpec {
    /// Unique name (default `ground`, then `ground1`, ...).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub name: Option<String>,
    /// Outward normal, world frame (any length; default: against gravity, or +z (+y in a planar
    /// scene) without gravity). An inclined plane is a tilted normal.
    #[serde(default, skip_serializing_if = "Option::is_none", deserialize_with = "exact::some_vec3")]
    pub normal: Option<[f64; 3]>,
    /// A point on the plane, m (default the origin).
    #[serde(default, skip_serializing_if = "Option::is_none", deserialize_with = "exact::some_vec3")]
    pub point: Option<[f64; 3]>,
    /// Coulomb friction coefficient (default 1; 0 is frictionless).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mu: Option<f64>,
    /// Penalty stiffness, N/m (default `1000 W / L`: the structure's whole weight `W` on one
    /// sphere presses it in by a thousandth of the structure's size `L`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub stiffness: Option<f64>,
    /// Hunt-Crossley dissipation, s/m (default 1): the normal force is `k d (1 + dissipation
    /// d_dot)`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub dissipation: Option<f64>,
    /// Friction regularization speed, m/s (default 1e-5): below it friction acts as a stiff
    /// viscous stick, and a load at a fraction `r` of the friction limit creeps at
    /// `stiction_speed r / sqrt(1 - r^2)`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub stiction_speed: Option<f64>,
    /// Stick-slip friction's tangential stiffness, N/m (default none: regularized friction).
    /// Given, each contact sticks to where it touched through a spring of this stiffness until
    /// the spring pulls with `mu F_n`, and then slips (no creep; `stiction_speed` is unused).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub stick_stiffness: Option<f64>,
    /// Stick-slip friction's tangential damping, N s/m (default: critical for the mass of the
    /// sphere's body, `2 sqrt(stick_stiffness m)`); needs `stick_stiffness`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub stick_damping: Option<f64>,
}

fn is_zero3(v: &[f64; 3]) -> bool {
    v.iter().all(|x| *x == 0.0)
}

fn is_false(b: &bool) -> bool {
    !*b
}

fn is_true(b: &bool) -> bool {
    *b
}

fn yes() -> bool {
    true
}

/// Body kinds as written in scene files.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum BodyKindSpec {
    /// Point mass.
    Node,
    /// Slender strut.
    Bar,
    /// Full rigid body.
    Rigid,
    /// Ground frame.
    Fixed,
}

/// A point on a body: body coordinates (m), or for bars a fraction along the bar from `a` to `b`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum PointSpec {
    /// Fraction `s` along a bar: at `a + s (b - a)`.
    Along(f64),
    /// Body coordinates, m, origin at the centre of mass.
    Local(#[serde(deserialize_with = "exact::vec3")] [f64; 3]),
}

/// One body.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BodySpec {
    /// Unique name (no dots).
    pub name: String,
    /// Model kind.
    pub kind: BodyKindSpec,
    /// Mass, kg (node, bar, rigid).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mass: Option<f64>,
    /// Centre of mass (node, rigid) or frame origin (fixed), m.
    #[serde(default, skip_serializing_if = "Option::is_none", deserialize_with = "exact::some_vec3")]
    pub position: Option<[f64; 3]>,
    /// Rotation vector body -> world, rad (rigid, fixed).
    #[serde(default, skip_serializing_if = "Option::is_none", deserialize_with = "exact::some_vec3")]
    pub rotation: Option<[f64; 3]>,
    /// End positions `a` and `b` of a bar, m.
    #[serde(default, skip_serializing_if = "Option::is_none", deserialize_with = "exact::some_ends")]
    pub ends: Option<[[f64; 3]; 2]>,
    /// Inertia about the centre of mass in body axes, kg m^2: rigid `[Ixx, Iyy, Izz]` or
    /// `[Ixx, Iyy, Izz, Ixy, Ixz, Iyz]`; bar `[I_transverse]` (default `m l^2 / 12`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub inertia: Option<Vec<f64>>,
    /// Named attachment points.
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub points: BTreeMap<String, PointSpec>,
    /// Contact geometry, m: the radius of the spheres this body meets the grounds with (a node:
    /// one at the node; a bar: one at each end, its capsule; a rigid body: one at each of
    /// `contact_points`). None: the body touches nothing.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub contact_radius: Option<f64>,
    /// Names of this body's points that carry contact spheres (a rigid body needs them; a bar
    /// defaults to `["a", "b"]`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub contact_points: Option<Vec<String>>,
}

impl BodySpec {
    /// A body of `kind` called `name` with every optional field empty.
    pub fn new(name: &str, kind: BodyKindSpec) -> Self {
        Self {
            name: name.into(),
            kind,
            mass: None,
            position: None,
            rotation: None,
            ends: None,
            inertia: None,
            points: BTreeMap::new(),
            contact_radius: None,
            contact_points: None,
        }
    }
}

/// Joint kinds.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum JointKindSpec {
    /// Point `a` held on point `b` of another body.
    Ball,
    /// Point `a` held at a fixed world position (`at`, default its initial position).
    Pin,
    /// Point `a` held on a world line through `at` (default its initial position) along
    /// `direction`: a roller support, free to roll along the line.
    Roller,
    /// Point `a` held on a world plane through `at` (default its initial position) with
    /// `normal`: a slider support, free to slide in the plane.
    Slider,
    /// A revolute joint: point `a` held on point `b` of another body (or, without `b`, at `at`,
    /// default its initial position), and the two bodies (or the body and the ground) turn
    /// relative to each other about `axis` only. Both bodies turn (bar, rigid) or are fixed.
    Hinge,
    /// A planar support: point `a` held on a world plane through `at` with `normal`, and its
    /// body turns about the normal only (it slides in the plane and spins about the normal).
    Planar,
}

/// A ball joint or a pin to the ground.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct JointSpec {
    /// Joint kind.
    pub kind: JointKindSpec,
    /// Point on the first body.
    pub a: String,
    /// Point on the second body (ball joints).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub b: Option<String>,
    /// World position of a pin, or a point of a roller's line or a slider's plane, m (default:
    /// where `a` starts).
    #[serde(default, skip_serializing_if = "Option::is_none", deserialize_with = "exact::some_vec3")]
    pub at: Option<[f64; 3]>,
    /// A roller's line direction, world frame (any length).
    #[serde(default, skip_serializing_if = "Option::is_none", deserialize_with = "exact::some_vec3")]
    pub direction: Option<[f64; 3]>,
    /// A slider's or planar joint's plane normal, world frame (any length).
    #[serde(default, skip_serializing_if = "Option::is_none", deserialize_with = "exact::some_vec3")]
    pub normal: Option<[f64; 3]>,
    /// A hinge's axis, world frame at the initial pose (any length).
    #[serde(default, skip_serializing_if = "Option::is_none", deserialize_with = "exact::some_vec3")]
    pub axis: Option<[f64; 3]>,
    /// Rotational damping, N m s/rad: torques against the two bodies' relative spin (both must
    /// turn: bars or rigid bodies, or one of them and the ground).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub damping: Option<f64>,
}

/// A cable through an ordered route of points: anchors at both ends, pulleys between.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CableSpec {
    /// Unique name.
    pub name: String,
    /// Points from the first anchor to the last (at least 2).
    pub route: Vec<String>,
    /// Axial stiffness EA, N (> 0).
    pub ea: f64,
    /// Damping coefficient c, N s/m (>= 0).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub damping: Option<f64>,
    /// Damping ratio: `c = 2 zeta sqrt((EA/L0) m_eff)`, `1/m_eff = sum 1/m_b` over the free
    /// bodies the cable touches.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub damping_ratio: Option<f64>,
    /// Rest length, m (> 0).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rest_length: Option<f64>,
    /// Target tension at the initial geometry, N (>= 0); form finding sets the rest length.
    /// With neither `rest_length` nor `prestress`, form finding determines the tension.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub prestress: Option<f64>,
    /// Target force density `q = T / L` at the initial geometry, N/m (>= 0); form finding sets
    /// the rest length. Excludes `rest_length` and `prestress`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub force_density: Option<f64>,
    /// True (default): the cable goes slack and never pushes. False: a two-point cable keeps its
    /// law in compression (a modelling choice, like a finite-element code whose strings may push;
    /// see `[[members]]`). Refused on a route with pulleys.
    #[serde(default = "yes", skip_serializing_if = "is_true")]
    pub tension_only: bool,
    /// Coulomb friction coefficient of the route's pulleys (>= 0): one number for every
    /// pulley, or one per pulley in route order. Default: the scene's `pulley_friction`, else 0
    /// (frictionless: one tension along the route).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pulley_friction: Option<PulleyFrictionSpec>,
    /// The anchor where an actuator winds this cable in or pays it out: `first` (default) or
    /// `last`. It matters only with pulley friction, where the material enters at that end.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub winch_end: Option<WinchEndSpec>,
}

/// A cable's `pulley_friction`: one coefficient for all its pulleys, or one each.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum PulleyFrictionSpec {
    /// The same `mu` at every pulley.
    All(f64),
    /// `mu` per pulley, in route order.
    Each(Vec<f64>),
}

/// Which anchor of a cable its winch is at.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum WinchEndSpec {
    /// The route's first point.
    First,
    /// The route's last point.
    Last,
}

/// An elastic member between two points: the cable law `T = (EA/L0)(L - L0) + c Ldot` without
/// the clamp at zero, so it pushes when compressed (`T < 0`); its mass, if any, lumped half on
/// each end. It appears among the cables (name, length, force) with a negative tension in
/// compression.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MemberSpec {
    /// Unique name among cables and members.
    pub name: String,
    /// The two points it joins.
    pub ends: [String; 2],
    /// Axial stiffness EA, N (> 0).
    pub ea: f64,
    /// Damping coefficient c, N s/m (>= 0), Kelvin-Voigt.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub damping: Option<f64>,
    /// Damping ratio, as a cable's (`c = 2 zeta sqrt((EA/L0) m_eff)`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub damping_ratio: Option<f64>,
    /// Rest length, m (> 0). Default: the ends' initial distance (unstressed), unless `force`
    /// or `form_find` is given.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rest_length: Option<f64>,
    /// Axial force at the initial geometry, N (negative: compression, above `-EA`); form
    /// finding sets the rest length.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub force: Option<f64>,
    /// True: the force is whatever makes the initial geometry an equilibrium (form finding, as
    /// for a cable given neither rest length nor prestress).
    #[serde(default, skip_serializing_if = "is_false")]
    pub form_find: bool,
    /// Mass, kg, on its ends; the ends must then be nodes or fixed points.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mass: Option<f64>,
    /// How `mass` sits on the ends: `"lumped"` (the default, half on each) or `"consistent"`
    /// (the uniform bar's consistent mass matrix, `crate::model::MassCoupling`; needs an
    /// implicit integrator or the Runge-Kutta methods' linear solve, see the scene format).
    #[serde(default, skip_serializing_if = "MassMatrixSpec::is_lumped")]
    pub mass_matrix: MassMatrixSpec,
    /// Bending stiffness EI, N m² (> 0): the member buckles at the Euler load of a pinned-pinned
    /// column of its initial rest length, `P = pi^2 EI / L0^2`. Excludes `buckling_load`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub bending_stiffness: Option<f64>,
    /// Buckling load P, N (> 0), given directly. Excludes `bending_stiffness`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub buckling_load: Option<f64>,
}

/// How a member's mass sits on its end nodes (`MemberSpec::mass_matrix`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum MassMatrixSpec {
    /// Half the mass on each end node, no coupling (block-diagonal mass matrix).
    #[default]
    Lumped,
    /// The uniform bar's consistent mass matrix `(m/6) [[2 I, I], [I, 2 I]]`.
    Consistent,
}

impl MassMatrixSpec {
    fn is_lumped(&self) -> bool {
        *self == MassMatrixSpec::Lumped
    }
}

/// An actuator: sets one cable's rest length within limits.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ActuatorSpec {
    /// Unique name.
    pub name: String,
    /// Cable driven.
    pub cable: String,
    /// Smallest rest length, m (> 0).
    pub min_rest_length: f64,
    /// Largest rest length, m.
    pub max_rest_length: f64,
    /// Largest rate, m/s (> 0).
    pub max_rate: f64,
    /// Time between a command's arrival and its effect, s (default 0: the next step).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub command_delay_s: Option<f64>,
    /// The same in physics steps (kept for one release; `command_delay_s` is the field).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub command_delay: Option<usize>,
    /// A winch motor instead of the ideal actuator (`[actuators.winch]`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub winch: Option<WinchSpec>,
}

/// A winch motor (`crate::forces::winch`): a drum, a linear torque-speed line given in rope
/// units (`stall_tension`, `no_load_speed`) or as a DC motor (`torque_constant`, `resistance`,
/// `voltage`, `gear_ratio`), rotor inertia, friction, gear and controller gains.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WinchSpec {
    /// Drum radius, m (> 0).
    pub drum_radius: f64,
    /// Line force at full drive and zero speed, N.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub stall_tension: Option<f64>,
    /// Reel-in speed at full drive and zero tension, m/s.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub no_load_speed: Option<f64>,
    /// DC motor torque constant k_t (= back-EMF constant), N m/A.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub torque_constant: Option<f64>,
    /// DC motor winding resistance, ohm.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub resistance: Option<f64>,
    /// DC motor supply voltage, V.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub voltage: Option<f64>,
    /// Gear ratio, motor turns per drum turn (default 1; DC form only).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub gear_ratio: Option<f64>,
    /// Rotor inertia reflected to the drum, kg m^2 (default 0).
    #[serde(default)]
    pub rotor_inertia: f64,
    /// Viscous friction at the drum, N m s/rad (default 0).
    #[serde(default)]
    pub viscous_friction: f64,
    /// False for a self-locking gear that the load cannot turn back (default true).
    #[serde(default = "default_true")]
    pub back_drivable: bool,
    /// Largest change of the speed set-point, m/s^2 (default: none).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub max_acceleration: Option<f64>,
    /// Position-mode gains `[kp (1/s), ki (1/s^2), kd]` (default `[20, 100, 0]`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub position_gains: Option<[f64; 3]>,
}

fn default_true() -> bool {
    true
}

/// Deployment schedule.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DeploymentSpec {
    /// Quasi-static load steps over the whole schedule (default 50).
    #[serde(default = "default_steps")]
    pub steps: usize,
    /// Linear rest-length ramps.
    #[serde(default)]
    pub ramps: Vec<RampSpec>,
}

fn default_steps() -> usize {
    50
}

/// A linear ramp of one actuator's rest length.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RampSpec {
    /// Actuator name.
    pub actuator: String,
    /// Start time, s (>= 0).
    #[serde(default)]
    pub start: f64,
    /// Duration, s (> 0).
    pub duration: f64,
    /// Rest length at the end of the ramp, m.
    pub rest_length: f64,
}

/// Quasi-static solver settings.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SolverSpec {
    /// Relative residual tolerance (default 1e-11).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub tolerance: Option<f64>,
    /// Newton iterations per load step (default 60).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub max_iterations: Option<usize>,
}

/// Structural damping of a scene (`crate::model::RayleighDamping`): `C = alpha M + beta K0`.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DampingSpec {
    /// Mass-proportional coefficient, 1/s (default 0).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub alpha: Option<f64>,
    /// Stiffness-proportional coefficient, s (default 0): adds `beta EA / L0` to every cable's
    /// and member's damping.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub beta: Option<f64>,
}

/// Parses scene text into a `SceneSpec` without validating the structure.
pub fn parse(text: &str, file: &str) -> Result<SceneSpec, SceneError> {
    toml::from_str::<SceneSpec>(text).map_err(|e| {
        let line = e.span().map(|s| line_of_offset(text, s.start));
        let message = e.message().trim();
        let field = line.map(|l| field_at_line(text, l, message)).unwrap_or_default();
        let mut reason = plain_words(message);
        if field.starts_with("bodies") && field.contains(".points") {
            reason += " (every key after a [bodies.points] header belongs to that table: write \
                       top-level keys before the first table, points inline as points = { ... })";
        }
        SceneError { file: file.to_string(), line, field, reason }
    })
}

/// A parser message in the words of the scene format, not of our Rust types.
fn plain_words(message: &str) -> String {
    [
        ("untagged enum PointSpec", "a point: a fraction along a bar, or body coordinates [x, y, z]"),
        ("struct SceneSpec", "a scene"),
        ("struct BodySpec", "a [[bodies]] table"),
        ("struct JointSpec", "a [[joints]] table"),
        ("struct CableSpec", "a [[cables]] table"),
        ("struct ActuatorSpec", "an [[actuators]] table"),
        ("struct WinchSpec", "an [actuators.winch] table"),
        ("struct SensorsSpec", "a [sensors] table"),
        ("struct ChannelSpec", "a [sensors.CHANNEL] table"),
        ("struct RandomizeSpec", "a [randomize] table"),
        ("struct RandomParameterSpec", "a [[randomize.parameters]] table"),
        ("struct DeploymentSpec", "a [deployment] table"),
        ("struct RampSpec", "a [[deployment.ramps]] table"),
        ("struct SolverSpec", "a [solver] table"),
        ("struct GroundSpec", "a [[grounds]] table"),
        ("enum BodyKindSpec", "a body kind (node, bar, rigid or fixed)"),
        ("enum JointKindSpec", "a joint kind (ball, pin, roller, slider, hinge or planar)"),
        ("untagged enum PulleyFrictionSpec", "a friction coefficient, or a list of one per pulley"),
        ("enum WinchEndSpec", "a cable end (first or last)"),
    ]
    .iter()
    .fold(message.to_string(), |m, (from, to)| m.replace(from, to))
}

/// Serializes a spec as TOML (used by the generators and `tensegrity generate`).
pub fn to_toml(spec: &SceneSpec) -> String {
    toml::to_string(spec).expect("scene specs always serialize")
}

fn line_of_offset(text: &str, offset: usize) -> usize {
    text[..offset.min(text.len())].bytes().filter(|b| *b == b'\n').count() + 1
}

/// Field path (`cables[2].ea`) of the key on 1-based `line`, from the array-of-tables headers above.
/// The field path (`cables[0].ea`) of an error on 1-based `line`: the table the line is in (or
/// heads), the key written on it, or the missing field named in `message`.
fn field_at_line(text: &str, line: usize, message: &str) -> String {
    let mut counts: BTreeMap<String, usize> = BTreeMap::new();
    let mut table = String::new();
    for l in text.lines().take(line) {
        let t = l.trim();
        if let Some(name) = t.strip_prefix("[[").and_then(|s| s.strip_suffix("]]")) {
            let idx = counts.entry(name.trim().to_string()).or_insert(0);
            table = format!("{}[{}]", name.trim(), *idx);
            *idx += 1;
        } else if let Some(name) = t.strip_prefix('[').and_then(|s| s.strip_suffix(']')) {
            table = name.trim().to_string();
        }
    }
    let missing = message
        .split_once("missing field `")
        .and_then(|(_, rest)| rest.split_once('`'))
        .map(|(name, _)| name.to_string());
    let key = missing.unwrap_or_else(|| {
        text.lines()
            .nth(line - 1)
            .filter(|l| !l.trim_start().starts_with('['))
            .and_then(|l| l.split_once('='))
            .map(|(k, _)| k.trim().to_string())
            .unwrap_or_default()
    });
    match (table.is_empty(), key.is_empty()) {
        (true, _) => key,
        (false, true) => table,
        (false, false) => format!("{table}.{key}"),
    }
}

/// 1-based line of `field` inside the `index`-th `[[array]]` table of `text`, or of the table
/// header when the field is not written there.
pub fn locate(text: &str, array: &str, index: usize, field: &str) -> Option<usize> {
    let header = format!("[[{array}]]");
    let mut seen = 0;
    let mut start = None;
    for (i, l) in text.lines().enumerate() {
        let t = l.trim();
        if start.is_some() && t.starts_with('[') {
            break;
        }
        if t == header {
            if seen == index {
                start = Some(i);
            }
            seen += 1;
            continue;
        }
        if start.is_some() && !field.is_empty() {
            if let Some((k, _)) = t.split_once('=') {
                if k.trim() == field {
                    return Some(i + 1);
                }
            }
        }
    }
    start.map(|s| s + 1)
}
