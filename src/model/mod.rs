//! The constant description of a structure (`Model`): bodies, their attachment points, cables and
//! their routes, joints, actuators and the deployment schedule. Built once from a scene
//! (`crate::scene`), never changed by a step; everything that changes lives in `crate::state::State`.
//!
//! # Coordinates (why minimal, on a Lie group)
//! Each body's configuration is a pose `(x, R)`: `x` the world position of its centre of mass (m),
//! `R` the rotation from body to world frame. The configuration space is the direct product
//! `R^3 x SO(3)` per body, and generalized coordinates are *local increments* at the current pose:
//! `x <- x + dx` (world frame) and `R <- R exp([dtheta]x)` (body frame). A body exposes only the
//! increments its kind needs through a constant 6 x k basis `B` (columns map local coordinates to
//! `(dx, dtheta)`):
//!
//! | kind | k | basis |
//! | --- | --- | --- |
//! | `node` | 3 (2 planar) | translations |
//! | `bar` | 5 (3 planar) | translations + rotations about the two body axes normal to the bar (body z = bar axis) |
//! | `rigid` | 6 (3 planar) | translations + body rotations |
//! | `fixed` | 0 | none |
//!
//! We chose this over natural coordinates because it needs no constraints for the bodies themselves
//! (a bar costs 5 unknowns, not 6 plus a length constraint), the statics tangent is the Hessian of the
//! energy on the free space (so positive definiteness *is* stability), and the body-frame mass matrix
//! `B^T diag(m I, J) B` is constant. The price is a nonlinear point map, whose second derivative is
//! supplied analytically by `crate::kinematics` and checked by finite differences in the tests.
//! Rotations never pass through a singular chart: increments are always taken at the current pose.

use std::sync::Arc;

use nalgebra::{Matrix3, Matrix6, UnitQuaternion, Vector3};

/// Index of a body in `Model::bodies`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct BodyId(pub usize);

/// Disjoint sets of bodies (union-find with path halving): the groups that the caller's joins
/// (joints, cables) make of `Model::bodies`, each named by the index of its root body.
#[derive(Debug, Clone)]
pub(crate) struct BodyGroups {
    parent: Vec<usize>,
}

impl BodyGroups {
    /// `n` bodies, each its own group.
    pub(crate) fn new(n: usize) -> Self {
        Self { parent: (0..n).collect() }
    }

    /// Puts the group of body `a` into the group of body `b`.
    pub(crate) fn join(&mut self, a: usize, b: usize) {
        let (ra, rb) = (self.root(a), self.root(b));
        self.parent[ra] = rb;
    }

    /// The root body of body `b`'s group.
    pub(crate) fn root(&mut self, mut b: usize) -> usize {
        while self.parent[b] != b {
            self.parent[b] = self.parent[self.parent[b]];
            b = self.parent[b];
        }
        b
    }
}
/// Index of an attachment point in `Model::points`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct PointId(pub usize);
/// Index of a cable in `Model::cables`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct CableId(pub usize);
/// Index of an actuator in `Model::actuators`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct ActuatorId(pub usize);

/// How a body is modelled (docs/architecture.md, "Bodies"): the cheapest model that captures what the scene needs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum BodyKind {
    /// Point mass, translations only.
    Node,
    /// Slender rigid strut: mass on its axis (body z), no inertia about the axis, 5 DOF.
    Bar,
    /// Full rigid body with a full inertia tensor, 6 DOF.
    Rigid,
    /// A frame on the ground: no coordinates.
    Fixed,
}

impl BodyKind {
    /// Lower-case name as used in scene files.
    pub fn as_str(self) -> &'static str {
        match self {
            BodyKind::Node => "node",
            BodyKind::Bar => "bar",
            BodyKind::Rigid => "rigid",
            BodyKind::Fixed => "fixed",
        }
    }
}

/// A body's pose: world position of its origin (the centre of mass, m) and body-to-world rotation.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pose {
    /// World position of the body origin (centre of mass), m.
    pub position: Vector3<f64>,
    /// Rotation from body frame to world frame.
    pub rotation: UnitQuaternion<f64>,
}

impl Pose {
    /// World position of a point given in body coordinates: `x + R p`.
    pub fn transform_point(&self, p_body: &Vector3<f64>) -> Vector3<f64> {
        self.position + self.rotation * p_body
    }
}

/// One body: its kind, inertia and which local increments are coordinates.
#[derive(Debug, Clone)]
pub struct BodyModel {
    /// Unique name from the scene.
    pub name: String,
    /// Model kind.
    pub kind: BodyKind,
    /// Mass, kg (0 for fixed bodies).
    pub mass: f64,
    /// Inertia tensor about the centre of mass in body axes, kg m^2.
    pub inertia: Matrix3<f64>,
    /// Columns `0..dof_count` map this body's local coordinates to `(dx_world, dtheta_body)`.
    pub basis: Matrix6<f64>,
    /// Number of generalized coordinates of this body (0..=6).
    pub dof_count: usize,
    /// Index of this body's first coordinate in the global coordinate vector.
    pub dof_offset: usize,
    /// Pose at the start of the simulation.
    pub initial_pose: Pose,
}

impl BodyModel {
    /// `(dx, dtheta) = B dq_b` for this body's slice of a global coordinate vector `dq`, times
    /// `scale` (fixed size, no allocation).
    pub fn local_increment(&self, dq: &[f64], scale: f64) -> nalgebra::Vector6<f64> {
        let mut out = nalgebra::Vector6::zeros();
        for (c, x) in dq[self.dof_offset..self.dof_offset + self.dof_count].iter().enumerate() {
            out += self.basis.column(c) * (x * scale);
        }
        out
    }

    /// The body's constant mass matrix in its local coordinates, `B^T diag(m I, J) B` (k x k,
    /// top-left block of the returned 6 x 6).
    pub fn mass_matrix(&self) -> Matrix6<f64> {
        let mut m6 = Matrix6::zeros();
        for i in 0..3 {
            m6[(i, i)] = self.mass;
        }
        m6.fixed_view_mut::<3, 3>(3, 3).copy_from(&self.inertia);
        self.basis.transpose() * m6 * self.basis
    }
}

/// A named attachment point fixed on a body.
#[derive(Debug, Clone)]
pub struct PointModel {
    /// Qualified name `body.point` (or `body` for the body origin).
    pub name: String,
    /// Body the point is fixed on.
    pub body: BodyId,
    /// Position in body coordinates (origin at the centre of mass), m.
    pub local: Vector3<f64>,
}

/// A cable, or an elastic member (`tension_only = false`), along a route of points: the
/// Kelvin-Voigt law `T = (EA/L0)(L - L0) + c Ldot` (`crate::forces::cable::tension`), clamped at
/// zero for a cable and not for a member, which pushes as well as pulls.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CableModel {
    /// Index of the first point of the route in `Model::route_points`.
    pub route_start: usize,
    /// Number of points on the route (anchors included), >= 2.
    pub route_len: usize,
    /// Axial stiffness EA, N (> 0).
    pub axial_stiffness: f64,
    /// Viscous damping coefficient c, N s/m (>= 0).
    pub damping: f64,
    /// True for a cable (goes slack below its rest length, never pushes); false for an elastic
    /// member between two points (`[[members]]`, or a cable with `tension_only = false`), whose
    /// law holds in compression too. A member's route has exactly two points.
    pub tension_only: bool,
    /// A member's buckling load `P`, N (> 0; `f64::INFINITY`: it never buckles, and always for
    /// a cable): compressed beyond `P`, it follows the post-buckling law of
    /// `crate::forces::cable::elastic_force` instead of `EA/L0`.
    pub buckling_load: f64,
    /// Index into `Model::pulley_friction` when some pulley of this cable has friction (`None`:
    /// frictionless pulleys, one tension along the route, and friction costs nothing).
    pub friction: Option<usize>,
    /// Index into `Model::winches` when a winch motor drives this cable (`None`: an ideal
    /// actuator or none, and winches cost nothing).
    pub winch: Option<usize>,
}

impl CableModel {
    /// Number of segments `m = route_len - 1`; `m = 1` is the classical two-point cable.
    pub fn segment_count(&self) -> usize {
        self.route_len - 1
    }
    /// Number of pulleys (interior route points), `m - 1`.
    pub fn pulley_count(&self) -> usize {
        self.route_len - 2
    }
}

/// Coulomb friction at a clustered cable's pulleys (`crate::forces::pulley`): the cable's
/// material on each segment is state (`State::segment_rest_lengths`), and across pulley `i`
/// the tensions of its two segments keep `T_high <= T_low exp(mu_i theta_i)`, `theta_i` the
/// wrap angle from the geometry; the cable slips through the pulley only at that bound.
#[derive(Debug, Clone, PartialEq)]
pub struct PulleyFriction {
    /// The cable.
    pub cable: CableId,
    /// Friction coefficient of each pulley in route order (`pulley_count` entries, >= 0).
    pub mu: Vec<f64>,
    /// Index of the cable's first segment in `State::segment_rest_lengths` (and of its
    /// segments' entries in the workspace).
    pub segment_offset: usize,
    /// Index of the cable's first pulley among all friction pulleys (workspace outputs).
    pub pulley_offset: usize,
    /// The segment an actuator winds material into or out of: 0 (the winch at the route's
    /// first anchor) or `segment_count - 1` (at its last).
    pub fed_segment: usize,
}

/// The contact law of a ground (`crate::forces::contact`): a compliant normal force with
/// Hunt-Crossley damping and Coulomb friction, regularized or elastic stick-slip.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ContactMaterial {
    /// Penalty stiffness `k`, N/m: a sphere pressed `delta` into the ground feels `k delta`.
    pub stiffness: f64,
    /// Hunt-Crossley dissipation `alpha`, s/m: the normal force is `k delta (1 + alpha
    /// delta_dot)`, so the loss per impact grows with the impact speed and the force is
    /// continuous at touchdown (restitution `e ~ 1 - (2/3) alpha v_in` for small `alpha v_in`).
    pub dissipation: f64,
    /// Coulomb friction coefficient `mu` (>= 0; 0: frictionless).
    pub friction: f64,
    /// Regularization speed `v_s` of the friction law, m/s (> 0): the friction force is
    /// `-mu F_n u / sqrt(|u|^2 + v_s^2)` for the slip velocity `u`, so a load at a fraction `r`
    /// of the friction limit creeps at `v_s r / sqrt(1 - r^2)`.
    pub stiction_speed: f64,
    /// Elastic stick-slip friction in place of the regularized law (`None`: regularized). Grounds
    /// only; `crate::forces::contact` module docs.
    pub stick: Option<StickFriction>,
}

/// Elastic stick-slip (spring-slider) friction of a ground: each contact is anchored where it
/// stuck, a tangential spring and damper pull it back, `F_trial = -(k_t d + c_t u)`, and while
/// `|F_trial| <= mu F_n` that is the friction (the contact sticks, without creeping); beyond,
/// the contact slips with `mu F_n` along `F_trial` and its anchor follows
/// (`crate::forces::contact::commit_anchors`, after each accepted step).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StickFriction {
    /// Tangential stiffness `k_t`, N/m (> 0).
    pub stiffness: f64,
    /// Tangential damping `c_t`, N s/m; `None`: critical for the mass of the sphere's body,
    /// `2 sqrt(k_t m)`.
    pub damping: Option<f64>,
}

/// A half-space the bodies' contact spheres cannot enter: the free side is `n . x >= offset`.
#[derive(Debug, Clone, PartialEq)]
pub struct GroundModel {
    /// Name from the scene (default `ground`, `ground1`, ...).
    pub name: String,
    /// Unit outward normal `n` (world frame): the free side is where it points.
    pub normal: Vector3<f64>,
    /// `n . x` of the plane's points, m.
    pub offset: f64,
    /// The contact law against this ground.
    pub material: ContactMaterial,
}

/// A contact sphere on a body: its centre is an attachment point (a node, a bar's end, a rigid
/// body's listed point). Two spheres at a bar's ends are the bar's capsule against a half-space
/// exactly (the signed distance of the capsule's axis to a plane is linear along it).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ContactSphere {
    /// The sphere's centre.
    pub point: PointId,
    /// Radius, m (>= 0).
    pub radius: f64,
}

/// Two bars whose capsules collide (`crate::forces::collision`): each bar's axis runs between
/// its ends `a` and `b`, and the capsules have the bars' `contact_radius`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StrutPair {
    /// The two bars.
    pub bars: [BodyId; 2],
    /// The axes' end points: the first bar's `a`, `b`, then the second's.
    pub ends: [PointId; 4],
    /// Sum of the two capsule radii, m: the axes touch at this distance.
    pub radius: f64,
}

/// The other side of a ball joint.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum JointTarget {
    /// Coincide with a point on another body (class-k ball joint).
    Point(PointId),
    /// Coincide with a fixed world position, m (pin to the ground).
    World(Vector3<f64>),
}

/// What a joint holds (`JointModel`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum JointKind {
    /// Two points coincide (a ball joint between bodies).
    Ball,
    /// A point held at a world position.
    Pin,
    /// A point held on a world line (a roller support): free along the line.
    Roller,
    /// A point held on a world plane (a slider support): free in the plane.
    Slider,
    /// A revolute axis: a ball joint (or a pin) whose two bodies (or body and ground) also keep
    /// their axes aligned, so they turn about the axis only. Two `JointModel`s: the point's rows
    /// and, after them, the axis's (`JointModel::alignment`).
    Hinge,
    /// A body held on a ground plane, free to slide in it and to turn about its normal only: a
    /// slider row and two alignment rows (`JointModel::alignment`).
    Planar,
}

impl JointKind {
    /// Lower-case name as used in scene files.
    pub fn as_str(self) -> &'static str {
        match self {
            JointKind::Ball => "ball",
            JointKind::Pin => "pin",
            JointKind::Roller => "roller",
            JointKind::Slider => "slider",
            JointKind::Hinge => "hinge",
            JointKind::Planar => "planar",
        }
    }
}

/// A joint: `Phi = D (r_a(q) - r_b(q)) = 0`, one equation per row of `D` (world directions).
/// A ball joint or a pin holds every direction: `D = I`, 3 rows (2 in planar scenes: x and y);
/// a roller holds the 2 directions across its line (1 in a planar scene), a slider the normal of
/// its plane (1). An alignment (`alignment` set: the axis rows of a hinge or planar joint) holds
/// orientations instead, `Phi_k = e_k . w` (`Alignment`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct JointModel {
    /// Point on the first body.
    pub point: PointId,
    /// What the point is held to.
    pub target: JointTarget,
    /// Index of this joint's first row in the constraint vector.
    pub row_offset: usize,
    /// Number of rows (equations), 1 to 3.
    pub rows: usize,
    /// The held world directions as the rows of `D` (unit, orthogonal; the first `rows` count);
    /// `None`: the coordinate axes (ball joints and pins), so `Phi` is `r_a - r_b` itself.
    pub directions: Option<Matrix3<f64>>,
    /// What the joint is.
    pub kind: JointKind,
    /// Rotational damping `c`, N m s/rad (0: none): torques `-c (omega_a - omega_b)` on the
    /// first body and the opposite on the second (`crate::forces::joint_damping`).
    pub damping: f64,
    /// `Some`: these rows hold an axis, not a point (`Alignment`); `directions` is unused.
    pub alignment: Option<Alignment>,
    /// `Some(u)`: the point row of a planar joint between two moving bodies, whose plane turns
    /// with body `b` (`u` its unit normal in `b`'s frame): `Phi = (R_b u) . (r_a - r_b)`, one row
    /// (`crate::constraints::plane_vectors`); `directions` is unused. `None` for every other
    /// joint (a planar joint to the ground or to a fixed body holds a world direction).
    pub plane_normal: Option<Vector3<f64>>,
    /// Index of the scene's `[[joints]]` entry this joint comes from (a hinge or a planar joint
    /// gives two `JointModel`s with the same index).
    pub scene_index: usize,
}

/// The axis rows of a hinge or planar joint: body `a` (the joint point's body) keeps two
/// body-fixed unit vectors `e_k = R_a n_k` normal to an axis `w`, which is body `b`'s
/// `w = R_b u` (a joint between two bodies) or the world's `w = u` (to the ground):
/// `Phi_k = e_k . w - offset = 0`, `k = 1, 2` (`offset = 0`), so the bodies turn relative to
/// each other about `w` only. With `a_k = e_k x w`, `Phi_q v = a_k . (omega_a - omega_b)`
/// (world angular velocities): the rows are `a_k^T G` with `G = [0 | R] B` the body's spin
/// Jacobian, and the multipliers carry the moment `sum_k lambda_k a_k` (N m) on body `a` (its
/// opposite on `b`).
///
/// A bar turns freely about its own axis (no inertia about it, no coordinate for it), so a joint
/// with a bar on one side holds only its direction `d`: with the axis along the bar the two rows
/// above (their moments are normal to the bar); otherwise one row (`JointModel::rows` = 1),
/// `Phi_1 = e_1 . w - cos(theta_0)`, the bar's angle `theta_0` to the axis, with `e_1` the bar's
/// axis (bar `a`: `n_1` = body z) or `w` the bar's axis (bar `b`: `u` = body z, `n_1` the joint's
/// axis in `a`'s frame). Its moment `lambda_1 (d x w)` is normal to the bar.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Alignment {
    /// `n_1`, `n_2`: unit, in body `a`'s frame (two rows: orthogonal to each other and to the
    /// axis; one row: `n_2` unused).
    pub normals: [Vector3<f64>; 2],
    /// `u`: the unit axis in body `b`'s frame (`JointTarget::Point`) or the world (`World`).
    pub axis: Vector3<f64>,
    /// `e_1 . w` at the initial pose (one row: `cos(theta_0)`; two rows: 0).
    pub offset: f64,
}

impl JointModel {
    /// `D v` for a world vector `v` (its first `rows` entries are the joint's rows).
    pub fn project(&self, v: &Vector3<f64>) -> Vector3<f64> {
        match &self.directions {
            None => *v,
            Some(d) => d * v,
        }
    }

    /// `D^T lambda` for the joint's multipliers `lambda` (its first `rows` entries): the world
    /// force the rows carry.
    pub fn force(&self, lambda: &Vector3<f64>) -> Vector3<f64> {
        match &self.directions {
            None => *lambda,
            Some(d) => d.transpose() * lambda,
        }
    }
}

/// A delay as the scene gives it: in seconds (`delay_s`, `command_delay_s`), or in physics
/// steps (the step-counted `delay` and `command_delay`, kept for one release), which change
/// their length in seconds with the physics step.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Delay {
    /// `k` physics steps (`Simulator::step` calls): `k dt` seconds.
    Steps(usize),
    /// Seconds, `>= 0`: `round(s / dt)` physics steps.
    Seconds(f64),
}

impl Default for Delay {
    fn default() -> Self {
        Delay::Steps(0)
    }
}

impl std::fmt::Display for Delay {
    /// `3 steps` or `0.003 s`.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Delay::Steps(k) => write!(f, "{k} steps"),
            Delay::Seconds(s) => write!(f, "{} s", crate::error::readable_number(*s)),
        }
    }
}

impl Delay {
    /// Relative distance from a whole number of steps under which a delay in seconds counts as
    /// whole (`0.003 / 0.001` is `2.9999999999999996`).
    const WHOLE: f64 = 1e-9;

    /// Whole physics steps at the physics step `dt` (s, > 0): `k`, or `round(s / dt)`.
    pub fn steps(self, dt: f64) -> usize {
        match self {
            Delay::Steps(k) => k,
            Delay::Seconds(s) => (s / dt).round() as usize,
        }
    }

    /// True when the delay is zero (no queue, the next step).
    pub fn is_zero(self) -> bool {
        matches!(self, Delay::Steps(0)) || self == Delay::Seconds(0.0)
    }

    /// What a user should hear about this delay at the physics step `dt` (`field` its place in
    /// the scene, e.g. `actuators[0].command_delay`): a step-counted field's length in seconds
    /// and its replacement, or a delay in seconds that is not a whole number of steps and the
    /// steps it was rounded to; `None` for a delay in seconds that is whole.
    pub fn warning(self, dt: f64, field: &str) -> Option<String> {
        match self {
            Delay::Steps(0) => None,
            Delay::Steps(k) => Some(format!(
                "{field} = {k} counts physics steps ({} s at physics_dt {} s) and changes with \
                 physics_dt: write {field}_s = {} instead (the step-counted field goes in the next release)",
                crate::error::readable_number(k as f64 * dt),
                crate::error::readable_number(dt),
                crate::error::readable_number(k as f64 * dt),
            )),
            Delay::Seconds(s) => {
                let ratio = s / dt;
                let k = ratio.round();
                ((ratio - k).abs() > Self::WHOLE * k.max(1.0)).then(|| {
                    format!(
                        "{field}_s = {} s is not a whole number of physics steps of {} s: rounded to {k} step{} ({} s)",
                        crate::error::readable_number(s),
                        crate::error::readable_number(dt),
                        if k == 1.0 { "" } else { "s" },
                        crate::error::readable_number(k * dt),
                    )
                })
            }
        }
    }
}

/// An actuator owns one cable and sets its rest length within limits (docs/architecture.md, "Actuation").
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ActuatorModel {
    /// The cable whose rest length this actuator sets.
    pub cable: CableId,
    /// Smallest allowed rest length, m (> 0).
    pub min_rest_length: f64,
    /// Largest allowed rest length, m.
    pub max_rest_length: f64,
    /// Largest allowed rate of change of the rest length, m/s (> 0).
    pub max_rate: f64,
    /// Time between a command's arrival and its effect (zero: the next step), resolved to
    /// whole physics steps by `Delay::steps`.
    pub command_delay: Delay,
    /// Index into `Model::winches` when a winch motor drives the cable (`None`: the ideal
    /// actuator, which follows its command exactly).
    pub winch: Option<usize>,
}

/// Position-mode gains of a winch's controller: the speed set-point (m/s, reel-in positive) is
/// `v* = v_ff + kp e + ki int e dt - kd de/dt` with `e = L0 - L_ref` (m) the rest length's excess
/// over its reference, `v_ff` the reference's own reel-in speed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PositionGains {
    /// Proportional gain, 1/s.
    pub kp: f64,
    /// Integral gain, 1/s^2.
    pub ki: f64,
    /// Derivative gain (on the measured reel-in speed), dimensionless.
    pub kd: f64,
}

/// A winch motor driving one actuator's cable (`crate::forces::winch`, rope units at the drum).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WinchModel {
    /// The actuator it drives.
    pub actuator: ActuatorId,
    /// The actuator's cable.
    pub cable: CableId,
    /// Drum radius `r`, m (> 0).
    pub drum_radius: f64,
    /// Stall tension `T_s`, N (> 0): the line force at full drive and zero speed.
    pub stall_tension: f64,
    /// No-load reel-in speed `v0`, m/s (> 0): the speed at full drive and zero tension.
    pub no_load_speed: f64,
    /// Rotor inertia at the drum `J`, kg m^2 (>= 0).
    pub rotor_inertia: f64,
    /// Viscous friction at the drum `b`, N m s/rad (>= 0).
    pub viscous_friction: f64,
    /// False for a self-locking gear: the load never turns the drum back.
    pub back_drivable: bool,
    /// Largest change of the speed set-point, m/s^2 (`f64::INFINITY`: none).
    pub max_acceleration: f64,
    /// Position-mode gains.
    pub gains: PositionGains,
}

impl WinchModel {
    /// Equivalent mass of the rotor on the rope, `M = J / r^2`, kg.
    pub fn equivalent_mass(&self) -> f64 {
        self.rotor_inertia / (self.drum_radius * self.drum_radius)
    }

    /// Speed-proportional resistance on the rope, `T_s / v0 + b / r^2`, N s/m: the torque-speed
    /// line's slope plus the drum's viscous friction.
    pub fn speed_resistance(&self) -> f64 {
        self.stall_tension / self.no_load_speed
            + self.viscous_friction / (self.drum_radius * self.drum_radius)
    }

    /// The motor's line force at drive `u` and reel-in speed `v` (m/s), `T_s (u - v / v0)`, N.
    pub fn motor_force(&self, drive: f64, v: f64) -> f64 {
        self.stall_tension * (drive - v / self.no_load_speed)
    }
}

/// What one channel measures.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SensorKind {
    /// Every cable's tension, N (one value per cable).
    Tension,
    /// Every cable's length, m (one per cable).
    Length,
    /// Every actuator's cable rest length, m (one per actuator): the winch's encoder.
    RestLength,
    /// Every body's position, m (x, y, z per body).
    Position,
    /// Every body's orientation (a unit quaternion w, x, y, z per body); its noise is a rotation
    /// vector of `sigma` rad per axis, no bias or quantization.
    Orientation,
    /// Every body's angular velocity in its own axes, rad/s (an IMU's gyro; x, y, z per body; 0
    /// for nodes and fixed bodies).
    Gyro,
    /// Every body's specific force at its centre of mass in its own axes, m/s^2 (an IMU's
    /// accelerometer; x, y, z per body): `R^T (a - g)` with `a` the mean acceleration over the
    /// last step, `(v(t) - v(t - h)) / h` (0 at the first sample, before any step).
    Accelerometer,
}

impl SensorKind {
    /// Every kind, in the order channels are kept and seeded.
    pub const ALL: [SensorKind; 7] = [
        SensorKind::Tension,
        SensorKind::Length,
        SensorKind::RestLength,
        SensorKind::Position,
        SensorKind::Orientation,
        SensorKind::Gyro,
        SensorKind::Accelerometer,
    ];

    /// The scene's name of the channel (`[sensors.NAME]`).
    pub fn name(self) -> &'static str {
        match self {
            SensorKind::Tension => "tension",
            SensorKind::Length => "length",
            SensorKind::RestLength => "rest_length",
            SensorKind::Position => "position",
            SensorKind::Orientation => "orientation",
            SensorKind::Gyro => "gyro",
            SensorKind::Accelerometer => "accelerometer",
        }
    }

    /// Values the channel carries for `model`.
    pub fn len(self, model: &Model) -> usize {
        match self {
            SensorKind::Tension | SensorKind::Length => model.cables.len(),
            SensorKind::RestLength => model.actuators.len(),
            SensorKind::Position | SensorKind::Gyro | SensorKind::Accelerometer => 3 * model.bodies.len(),
            SensorKind::Orientation => 4 * model.bodies.len(),
        }
    }
}

/// One channel's imperfections (all default to a perfect sensor).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ChannelModel {
    /// Standard deviation of the Gaussian noise, in the channel's unit (rad for orientation).
    pub sigma: f64,
    /// Constant offset, in the channel's unit.
    pub bias: f64,
    /// Quantization step, in the channel's unit (0: none).
    pub resolution: f64,
    /// Time between a measurement and its report, resolved to whole physics steps by
    /// `Delay::steps`.
    pub delay: Delay,
    /// Time between updates, s (0: every step); held in between.
    pub period: f64,
    /// Probability that an update is lost, in `[0, 1)`: the value is held.
    pub dropout: f64,
}

/// The scene's sensors: a seed and the channels it declares (none: no sensors, nothing drawn).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct SensorModel {
    /// Seed of every channel's generator.
    pub seed: u64,
    /// The declared channels, in `SensorKind::ALL` order.
    pub channels: Vec<(SensorKind, ChannelModel)>,
}

/// Which parameter a declaration draws.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Parameter {
    /// A cable's or member's axial stiffness EA (factor).
    AxialStiffness,
    /// A cable's or member's damping coefficient (factor).
    Damping,
    /// A body's mass, and its inertia with it (factor).
    Mass,
    /// A cable's initial rest length (offset, m).
    RestLength,
    /// Every friction coefficient of a cable's pulleys (one factor).
    PulleyFriction,
}

impl Parameter {
    /// The scene's name of the parameter.
    pub fn name(self) -> &'static str {
        match self {
            Parameter::AxialStiffness => "ea",
            Parameter::Damping => "damping",
            Parameter::Mass => "mass",
            Parameter::RestLength => "rest_length",
            Parameter::PulleyFriction => "pulley_friction",
        }
    }

    /// The parameter of a scene name.
    pub fn parse(name: &str) -> Option<Self> {
        [Self::AxialStiffness, Self::Damping, Self::Mass, Self::RestLength, Self::PulleyFriction]
            .into_iter()
            .find(|p| p.name() == name)
    }

    /// True when a draw is a factor on the value as written (else an offset).
    pub fn is_factor(self) -> bool {
        self != Parameter::RestLength
    }
}

/// How a scene's randomization runs: its seed, whether the node draws anew at every reset, and
/// the episode this model was drawn for (drawn with seed `seed + episode`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RandomizationRun {
    /// The scene's seed.
    pub seed: u64,
    /// True: each reset draws anew (`crate::scene::redraw`); false: one draw per run.
    pub per_reset: bool,
    /// Resets that drew anew before this model (0 at the start).
    pub episode: u64,
}

/// One draw as applied.
#[derive(Debug, Clone, PartialEq)]
pub struct Draw {
    /// Which parameter.
    pub parameter: Parameter,
    /// The element's name (cable, or body for `mass`).
    pub element: String,
    /// The factor or offset drawn.
    pub drawn: f64,
    /// The value as written and the value used (EA in N, damping in N s/m, mass in kg, rest
    /// length in m, the first pulley's coefficient).
    pub written: f64,
    /// The value used.
    pub value: f64,
}

/// One linear rest-length ramp of a deployment schedule.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Ramp {
    /// Actuator being driven.
    pub actuator: ActuatorId,
    /// Start time of the ramp, s.
    pub start: f64,
    /// Duration, s (> 0).
    pub duration: f64,
    /// Rest length reached at `start + duration`, m.
    pub target: f64,
}

/// A deployment schedule: ramps per actuator, each starting from the value the previous one left.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Schedule {
    /// Ramps, sorted by actuator then start time; ramps of one actuator never overlap.
    pub ramps: Vec<Ramp>,
    /// Number of quasi-static load steps over the schedule's duration.
    pub steps: usize,
}

impl Schedule {
    /// Time at which the last ramp ends, s (0 for an empty schedule).
    pub fn end_time(&self) -> f64 {
        self.ramps.iter().map(|r| r.start + r.duration).fold(0.0, f64::max)
    }

    /// Rest length of `actuator` at time `t` (s), starting from `initial` (m): piecewise linear,
    /// holding the last target between and after ramps.
    pub fn rest_length(&self, actuator: ActuatorId, initial: f64, t: f64) -> f64 {
        let mut value = initial;
        for ramp in self.ramps.iter().filter(|r| r.actuator == actuator) {
            if t <= ramp.start {
                break;
            }
            let s = ((t - ramp.start) / ramp.duration).min(1.0);
            value += s * (ramp.target - value);
            if s < 1.0 {
                break;
            }
        }
        value
    }

    /// Rate of change of `actuator`'s rest length at time `t` (m/s), the right derivative of
    /// `rest_length`: the slope of the ramp running at `t` (a ramp that ends at `t` no longer
    /// counts), 0 between and after ramps.
    pub fn rest_rate(&self, actuator: ActuatorId, initial: f64, t: f64) -> f64 {
        let mut value = initial;
        for ramp in self.ramps.iter().filter(|r| r.actuator == actuator) {
            if t < ramp.start {
                return 0.0;
            }
            if t < ramp.start + ramp.duration {
                return (ramp.target - value) / ramp.duration;
            }
            value = ramp.target;
        }
        0.0
    }
}

/// Rayleigh (structural) damping `C = alpha M + beta K0`, declared per scene (`[damping]`):
/// `alpha M` acts on every body's velocity (its local mass matrix, rotations included), and
/// `beta K0` is each cable's and member's material stiffness `EA/L0`, with `L0` its initial rest
/// length, added to its Kelvin-Voigt damping (`c += beta EA / L0`, done when the scene is built).
/// A mode whose stiffness is material has the damping ratio `(alpha / omega + beta omega) / 2`;
/// a mode held by prestress alone (the prism's twist) is damped by `alpha` only: the geometric
/// stiffness is left out of `K0` because, element by element, it would damp rigid rotations
/// too. `alpha` also damps rigid-body motion, like a drag against the world frame.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct RayleighDamping {
    /// Mass-proportional coefficient `alpha`, 1/s (>= 0).
    pub alpha: f64,
    /// Stiffness-proportional coefficient `beta`, s (>= 0).
    pub beta: f64,
}

/// Numerical settings of the quasi-static solver.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SolverSettings {
    /// Newton converges when the residual's max norm is below `tolerance * force_scale`.
    pub tolerance: f64,
    /// Newton iterations per load step before the step is cut.
    pub max_iterations: usize,
    /// Largest number of times a failing load step is halved.
    pub max_step_cuts: usize,
}

impl Default for SolverSettings {
    fn default() -> Self {
        Self { tolerance: 1e-11, max_iterations: 60, max_step_cuts: 12 }
    }
}

/// A member's consistent-mass correction (`[[members]] mass_matrix = "consistent"`).
///
/// A uniform bar element of mass `m` has the consistent mass matrix `(m/6) [[2 I, I], [I, 2 I]]`
/// on its end translations; the end nodes already carry the lumped `(m/2) I` each, so the model
/// adds the difference `(m/6) [[-I, I], [I, -I]]`. Its rows sum to zero: weight, total mass,
/// centre of mass and momentum are the lumped ones; what changes is how the mass resists
/// relative motion of the ends (a straight member turning about its middle has the rigid bar's
/// `m L^2 / 12` instead of the lumped `m L^2 / 4`). An end on a fixed body keeps only its own
/// diagonal term. The sum stays positive definite (eigenvalues `m/2` and `m/6` per pair).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MassCoupling {
    /// The member's end bodies (nodes or fixed bodies).
    pub ends: [BodyId; 2],
    /// `m / 6`, kg: the off-diagonal coefficient of the consistent element matrix.
    pub coefficient: f64,
}

/// The constant description of a structure. See the module docs for the coordinates.
#[derive(Debug, Clone)]
pub struct Model {
    /// Scene name.
    pub name: String,
    /// Bodies in scene order.
    pub bodies: Vec<BodyModel>,
    /// Attachment points; every point of every body, in scene order.
    pub points: Vec<PointModel>,
    /// Cables in scene order.
    pub cables: Vec<CableModel>,
    /// Cable names, parallel to `cables`.
    pub cable_names: Vec<String>,
    /// Concatenated cable routes (see `CableModel::route_start`).
    pub route_points: Vec<PointId>,
    /// Ball joints and pins.
    pub joints: Vec<JointModel>,
    /// Actuators in scene order.
    pub actuators: Vec<ActuatorModel>,
    /// Half-space grounds (none: nothing to touch, and contact costs nothing).
    pub grounds: Vec<GroundModel>,
    /// Contact spheres on bodies; every sphere meets every ground (`Model::contact_pairs`).
    pub contact_spheres: Vec<ContactSphere>,
    /// Bar pairs whose capsules collide (none: struts pass through each other, at no cost).
    pub strut_pairs: Vec<StrutPair>,
    /// The contact law between colliding bars (used only with `strut_pairs`).
    pub strut_material: ContactMaterial,
    /// Actuator names, parallel to `actuators`.
    pub actuator_names: Vec<String>,
    /// Deployment schedule.
    pub schedule: Schedule,
    /// Gravity acceleration in world frame, m/s^2.
    pub gravity: Vector3<f64>,
    /// True for 2-D scenes: motion in the world xy plane only.
    pub planar: bool,
    /// Total number of generalized coordinates.
    pub dof_count: usize,
    /// Total number of constraint equations (joint rows).
    pub constraint_count: usize,
    /// Rest lengths at t = 0, m, parallel to `cables` (from the scene or from form finding).
    pub initial_rest_lengths: Vec<f64>,
    /// Form finding made the sketched pose an equilibrium with friction at stick-slip contacts
    /// (a foot held sideways by a prestressed cable): statics of the structure set down holds
    /// its contacts where the scene sets the bodies first (`StaticSolver::equilibrate`).
    pub friction_holds_sketch: bool,
    /// Cables whose pulleys have friction (none: every pulley is frictionless, and friction
    /// costs nothing).
    pub pulley_friction: Vec<PulleyFriction>,
    /// Rest length of every segment of the friction cables at t = 0, m (`PulleyFriction::
    /// segment_offset`): the initial rest length shared in proportion to the initial segment
    /// lengths, as a frictionless cable would hold it.
    pub initial_segment_rest_lengths: Vec<f64>,
    /// Winch motors (`crate::forces::winch`; none: every actuator is ideal, and winches cost
    /// nothing).
    pub winches: Vec<WinchModel>,
    /// Sensor models (`crate::sensors`; empty: no sensors). The physics never reads them.
    pub sensors: SensorModel,
    /// The scene's `[randomize]` draws, as applied when the model was built (empty: the scene
    /// as written).
    pub randomized: Vec<Draw>,
    /// The scene's randomization settings (`None` without `[randomize]`).
    pub randomization: Option<RandomizationRun>,
    /// Quasi-static solver settings.
    pub solver: SolverSettings,
    /// Rayleigh damping (zero: none, and it costs nothing).
    pub rayleigh: RayleighDamping,
    /// True when some joint has rotational damping (`JointModel::damping`); false: the joints'
    /// damping is not visited at all.
    pub damped_joints: bool,
    /// Consistent-mass corrections of the members that ask for them (`MassCoupling`; empty:
    /// every mass is lumped, the mass matrix is block diagonal, and this costs nothing).
    pub mass_couplings: Vec<MassCoupling>,
    /// Physics step the scene asks for, s (None: the tool's default).
    pub physics_dt: Option<f64>,
    /// The scene text this model was built from (for a generated scene, its TOML), so that a
    /// recording can rebuild it. A model edited in code after building no longer matches it.
    pub source: Arc<str>,
}

impl Model {
    /// What the scene's delays (`Delay::warning`) say at the physics step `dt` (s): step-counted
    /// fields, and delays in seconds rounded to whole steps, one line each, actuators first.
    pub fn delay_warnings(&self, dt: f64) -> Vec<String> {
        let actuators = (self.actuators.iter().enumerate())
            .filter_map(|(i, a)| a.command_delay.warning(dt, &format!("actuators[{i}].command_delay")));
        let sensors = (self.sensors.channels.iter())
            .filter_map(|(kind, c)| c.delay.warning(dt, &format!("sensors.{}.delay", kind.name())));
        actuators.chain(sensors).collect()
    }

    /// Calls `f(a, b, block)` for every block of the consistent-mass corrections
    /// (`MassCoupling`): `block = B_a^T [[c I, 0], [0, 0]] B_b` in the bodies' local coordinates
    /// (their `k_a x k_b` corner), with `c = -m/6` on `(a, a)` and `(b, b)` and `+m/6` on `(a, b)`
    /// and `(b, a)`, kg. Blocks of fixed bodies (no coordinates) are skipped. Nothing is called
    /// when every mass is lumped.
    pub fn for_each_mass_coupling_block(&self, mut f: impl FnMut(BodyId, BodyId, &Matrix6<f64>)) {
        for coupling in &self.mass_couplings {
            let [a, b] = coupling.ends;
            let c = coupling.coefficient;
            for (x, y, sign) in [(a, a, -1.0), (b, b, -1.0), (a, b, 1.0), (b, a, 1.0)] {
                let (bx, by) = (&self.bodies[x.0], &self.bodies[y.0]);
                if bx.dof_count == 0 || by.dof_count == 0 {
                    continue;
                }
                let mut t = Matrix6::zeros();
                for i in 0..3 {
                    t[(i, i)] = sign * c;
                }
                f(x, y, &(bx.basis.transpose() * t * by.basis));
            }
        }
    }

    /// `out += scale * dM v`: the consistent-mass corrections (`MassCoupling`) times a vector
    /// `v` of local coordinates (N s for velocities, N for accelerations, as `v` is). No-op
    /// with lumped mass only.
    pub fn add_mass_coupling_times(&self, v: &[f64], scale: f64, out: &mut [f64]) {
        self.for_each_mass_coupling_block(|a, b, blk| {
            let (ba, bb) = (&self.bodies[a.0], &self.bodies[b.0]);
            for r in 0..ba.dof_count {
                let mut sum = 0.0;
                for c in 0..bb.dof_count {
                    sum += blk[(r, c)] * v[bb.dof_offset + c];
                }
                out[ba.dof_offset + r] += scale * sum;
            }
        });
    }

    /// Route of cable `c`: its points from the first anchor to the last.
    pub fn route(&self, c: CableId) -> &[PointId] {
        let cable = &self.cables[c.0];
        &self.route_points[cable.route_start..cable.route_start + cable.route_len]
    }

    /// Bodies with coordinates that nothing acts on or holds: no cable route point and no joint
    /// on them. Such a body floats free (or falls, under gravity): dynamics can follow it, but it
    /// has no equilibrium. Linear in the scene size.
    pub fn unheld_bodies(&self) -> Vec<BodyId> {
        let mut held = vec![false; self.bodies.len()];
        for p in &self.route_points {
            held[self.points[p.0].body.0] = true;
        }
        for j in &self.joints {
            held[self.points[j.point.0].body.0] = true;
            if let JointTarget::Point(q) = j.target {
                held[self.points[q.0].body.0] = true;
            }
        }
        if !self.grounds.is_empty() {
            for s in &self.contact_spheres {
                held[self.points[s.point.0].body.0] = true;
            }
        }
        (0..self.bodies.len()).filter(|&b| !held[b] && self.bodies[b].dof_count > 0).map(BodyId).collect()
    }

    /// True when nothing ties the structure to the ground: no pin, no joint to a fixed body, no
    /// cable point on a fixed body, no contact sphere that a ground could stop. Such a structure (in orbit, in a drop test) has 6 free
    /// rigid-body motions (3 planar); its shape, not its position, is what a deployment changes.
    pub fn is_free_floating(&self) -> bool {
        let fixed = |p: PointId| self.bodies[self.points[p.0].body.0].dof_count == 0;
        (self.grounds.is_empty() || self.contact_spheres.is_empty())
            && !self.route_points.iter().any(|p| fixed(*p))
            && self.joints.iter().all(|j| match j.target {
                JointTarget::World(_) => false,
                JointTarget::Point(q) => !fixed(q) && !fixed(j.point),
            })
    }

    /// Number of constraint rows a ball joint or pin has in this model (3, or 2 when planar); the
    /// most any joint has (`JointModel::rows`).
    pub fn joint_rows(&self) -> usize {
        if self.planar {
            2
        } else {
            3
        }
    }

    /// Number of (sphere, ground) contact pairs: `contact_spheres.len() * grounds.len()`, pair
    /// `s * grounds.len() + g` for sphere `s` and ground `g`.
    pub fn ground_pairs(&self) -> usize {
        self.contact_spheres.len() * self.grounds.len()
    }

    /// True when some ground has elastic stick-slip friction (`StickFriction`): the state then
    /// carries an anchor per ground pair (`State::contact_anchors`).
    pub fn has_stick_friction(&self) -> bool {
        self.grounds.iter().any(|g| g.material.stick.is_some())
    }

    /// True when some contact has regularized friction: a ground with spheres on it, friction
    /// and no `StickFriction`, or strut pairs with friction. Its slope changes by orders of
    /// magnitude between stick and slip, so generalized-alpha's Newton refactors each iteration.
    pub fn has_regularized_friction(&self) -> bool {
        let grounds = !self.contact_spheres.is_empty()
            && self.grounds.iter().any(|g| g.material.stick.is_none() && g.material.friction > 0.0);
        grounds || (!self.strut_pairs.is_empty() && self.strut_material.friction > 0.0)
    }

    /// Number of contacts of every kind: the ground pairs (`ground_pairs`, first) then the strut
    /// pairs (`strut_pairs`, in order). Contact outputs (`Workspace::contacts`, CSV columns, the
    /// `~/contacts` topic, bags) list them in that order.
    pub fn contact_pairs(&self) -> usize {
        self.ground_pairs() + self.strut_pairs.len()
    }

    /// Every contact's names, in `contact_pairs` order: for a ground pair the sphere's point and
    /// the ground (`s1.a`, `ground`), for a strut pair the two bars (`s1`, `s2`).
    pub fn contact_labels(&self) -> impl Iterator<Item = (&str, &str)> + '_ {
        let grounds = self
            .contact_pair_list()
            .map(|(_, sphere, ground)| (self.points[sphere.point.0].name.as_str(), ground.name.as_str()));
        let struts = self
            .strut_pairs
            .iter()
            .map(|p| (self.bodies[p.bars[0].0].name.as_str(), self.bodies[p.bars[1].0].name.as_str()));
        grounds.chain(struts)
    }

    /// The friction coefficient `mu` of every contact pair, in `contact_labels` order: the
    /// ground's for a sphere, the struts' material's for a pair of struts.
    pub fn contact_friction_coefficients(&self) -> impl Iterator<Item = f64> + '_ {
        let grounds = self.contact_pair_list().map(|(_, _, ground)| ground.material.friction);
        grounds.chain(self.strut_pairs.iter().map(|_| self.strut_material.friction))
    }

    /// Every contact pair, in that order: `(k, sphere, ground)` with `k = s * grounds.len() + g`.
    pub fn contact_pair_list(&self) -> impl Iterator<Item = (usize, &ContactSphere, &GroundModel)> + '_ {
        self.contact_spheres
            .iter()
            .flat_map(move |sphere| self.grounds.iter().map(move |ground| (sphere, ground)))
            .enumerate()
            .map(|(k, (sphere, ground))| (k, sphere, ground))
    }

    /// Index of the body called `name`.
    pub fn body_id(&self, name: &str) -> Option<BodyId> {
        self.bodies.iter().position(|b| b.name == name).map(BodyId)
    }

    /// Index of the cable called `name`.
    pub fn cable_id(&self, name: &str) -> Option<CableId> {
        self.cable_names.iter().position(|n| n == name).map(CableId)
    }

    /// Index of the point with qualified name `name` (`body.point`, or `body` for its origin).
    pub fn point_id(&self, name: &str) -> Option<PointId> {
        self.points.iter().position(|p| p.name == name).map(PointId)
    }

    /// Index of the actuator called `name`.
    pub fn actuator_id(&self, name: &str) -> Option<ActuatorId> {
        self.actuator_names.iter().position(|n| n == name).map(ActuatorId)
    }

    /// Number of pulleys over all cables.
    pub fn pulley_count(&self) -> usize {
        self.cables.iter().map(|c| c.pulley_count()).sum()
    }

    /// Rest lengths of all cables at schedule time `t` (s): actuated cables follow the schedule,
    /// the others keep their initial rest length.
    pub fn scheduled_rest_lengths(&self, t: f64, out: &mut [f64]) {
        out.copy_from_slice(&self.initial_rest_lengths);
        for (i, act) in self.actuators.iter().enumerate() {
            let c = act.cable.0;
            out[c] = self.schedule.rest_length(ActuatorId(i), self.initial_rest_lengths[c], t);
        }
    }

    /// Rates of change of all rest lengths at schedule time `t` (m/s, right derivative):
    /// `Schedule::rest_rate` for actuated cables, 0 for the others.
    pub fn scheduled_rest_rates(&self, t: f64, out: &mut [f64]) {
        out.fill(0.0);
        for (i, act) in self.actuators.iter().enumerate() {
            let c = act.cable.0;
            out[c] = self.schedule.rest_rate(ActuatorId(i), self.initial_rest_lengths[c], t);
        }
    }
}

/// Skew-symmetric cross-product matrix `[a]x` with `[a]x b = a x b`.
pub fn skew(a: &Vector3<f64>) -> Matrix3<f64> {
    a.cross_matrix()
}
