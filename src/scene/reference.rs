//! The scene-file field reference: takes nothing, gives every field of every table with its
//! format, unit, default and allowed range (ranges from `limits`, so they cannot drift from what
//! validation enforces), and the Markdown table that docs/scene-format.md carries and `tensegrity fields`
//! prints. `tests/readme.rs` checks that docs/scene-format.md holds exactly this table and that its field
//! names are exactly the ones the scene parser accepts.

use super::limits;
use crate::error::readable_number;

/// One field of a scene table.
#[derive(Debug, Clone, PartialEq)]
pub struct FieldDoc {
    /// Table as written in the file: `(top level)`, `[[bodies]]`, `[solver]`, ...
    pub table: &'static str,
    /// Key.
    pub field: &'static str,
    /// Format: `string`, `number`, `[x, y, z]`, ...
    pub format: &'static str,
    /// SI unit, or `-`.
    pub unit: &'static str,
    /// Default, or `required`.
    pub default: String,
    /// Allowed values and meaning.
    pub range: String,
}

/// The tables in file order, with the key the parser reports them under (for tests).
pub const TABLES: [(&str, &str); 17] = [
    ("(top level)", ""),
    ("[[bodies]]", "bodies"),
    ("[[joints]]", "joints"),
    ("[[cables]]", "cables"),
    ("[[members]]", "members"),
    ("[[actuators]]", "actuators"),
    ("[actuators.winch]", "actuators.winch"),
    ("[solver]", "solver"),
    ("[damping]", "damping"),
    ("[deployment]", "deployment"),
    ("[[deployment.ramps]]", "deployment.ramps"),
    ("[[grounds]]", "grounds"),
    ("[collisions]", "collisions"),
    ("[sensors]", "sensors"),
    ("[sensors.CHANNEL]", "sensors.tension"),
    ("[randomize]", "randomize"),
    ("[[randomize.parameters]]", "randomize.parameters"),
];

fn range((lo, hi): (f64, f64)) -> String {
    format!("{} to {}", readable_number(lo), readable_number(hi))
}

/// Every field of every table, in file order.
pub fn scene_fields() -> Vec<FieldDoc> {
    let f = |table, field, format, unit, default: &str, range: String| FieldDoc {
        table,
        field,
        format,
        unit,
        default: default.to_string(),
        range,
    };
    let coord = format!("each within +-{}", readable_number(limits::MAX_COORDINATE));
    let top = TABLES[0].0;
    let (bodies, joints, cables, members) = (TABLES[1].0, TABLES[2].0, TABLES[3].0, TABLES[4].0);
    let (actuators, winch) = (TABLES[5].0, TABLES[6].0);
    let (solver, damping, deployment) = (TABLES[7].0, TABLES[8].0, TABLES[9].0);
    let (ramps, grounds, collisions) = (TABLES[10].0, TABLES[11].0, TABLES[12].0);
    let (sensors, channel) = (TABLES[13].0, TABLES[14].0);
    let (randomize, random) = (TABLES[15].0, TABLES[16].0);
    vec![
        f(top, "name", "string", "-", "empty", "scene name (reports, node topics)".into()),
        f(top, "description", "string", "-", "empty", "free text".into()),
        f(
            top,
            "gravity",
            "[x, y, z]",
            "m/s^2",
            "[0, 0, 0]",
            format!("world frame (z up; planar: y up), each within +-{}", readable_number(limits::MAX_GRAVITY)),
        ),
        f(top, "planar", "boolean", "-", "false", "true: everything moves in the world xy plane".into()),
        f(
            top,
            "physics_dt",
            "number",
            "s",
            "0.001 (tools)",
            format!("{}; step of dynamic runs and of the node", range(limits::PHYSICS_DT)),
        ),
        f(
            top,
            "pulley_friction",
            "number",
            "-",
            "0",
            format!("Coulomb mu of every pulley whose cable does not say, {}", range(limits::FRICTION)),
        ),
        f(bodies, "name", "string", "-", "required", "unique; no dots or spaces".into()),
        f(bodies, "kind", "string", "-", "required", "`node` (3 DOF), `bar` (5), `rigid` (6), `fixed` (0)".into()),
        f(bodies, "mass", "number", "kg", "required (not fixed)", format!("{}; fixed bodies take none", range(limits::MASS))),
        f(
            bodies,
            "position",
            "[x, y, z]",
            "m",
            "required (node, rigid); fixed: [0, 0, 0]",
            format!("centre of mass (node, rigid) or frame origin (fixed); not for bars; {coord}"),
        ),
        f(
            bodies,
            "rotation",
            "[x, y, z]",
            "rad",
            "[0, 0, 0]",
            format!("rotation vector body -> world (rigid, fixed), each within +-{}", readable_number(limits::MAX_ROTATION)),
        ),
        f(bodies, "ends", "[[x, y, z], [x, y, z]]", "m", "required (bar)", format!("bar ends `a`, `b`; {coord}")),
        f(
            bodies,
            "inertia",
            "[numbers]",
            "kg m^2",
            "required (rigid); bar: m l^2 / 12",
            format!(
                "rigid: [Ixx, Iyy, Izz] or [Ixx, Iyy, Izz, Ixy, Ixz, Iyz] about the COM in body axes; bar: [I]; {}",
                range(limits::INERTIA)
            ),
        ),
        f(
            bodies,
            "points",
            "table name = [x, y, z] or fraction",
            "m",
            "none",
            "named points (not for nodes): body coordinates, or for a bar the fraction along a -> b".into(),
        ),
        f(
            bodies,
            "contact_radius",
            "number",
            "m",
            "none (touches nothing)",
            format!(
                "{}; contact spheres against the grounds: a node's at the node, a bar's at both ends (its capsule; also its radius in `[collisions]`), a rigid body's at its `contact_points`",
                range(limits::CONTACT_RADIUS)
            ),
        ),
        f(
            bodies,
            "contact_points",
            "[strings]",
            "-",
            "bar: [\"a\", \"b\"]",
            "names of the body's points that carry contact spheres (required for rigid bodies; not for nodes)".into(),
        ),
        f(
            joints,
            "kind",
            "string",
            "-",
            "required",
            "`ball` (a on b), `pin` (a on a world position), `roller` (a on a world line), `slider` (a on a world plane), `hinge` (a on b, or on a world position, turning about `axis` only), `planar` (a on a world plane, or on the plane through b that turns with b's body, turning about its normal only)".into(),
        ),
        f(joints, "a", "string", "-", "required", "point `body.point`, or `body` for its origin".into()),
        f(joints, "b", "string", "-", "required (ball)", "second point of a ball joint, a hinge or a planar joint between two bodies".into()),
        f(
            joints,
            "at",
            "[x, y, z]",
            "m",
            "where `a` starts",
            format!("pin position (or a hinge's without `b`), or a point of a roller's line or a slider's or planar joint's plane; {coord}"),
        ),
        f(joints, "direction", "[x, y, z]", "-", "required (roller)", "the roller's line, any length (planar: z 0)".into()),
        f(joints, "normal", "[x, y, z]", "-", "required (slider, planar)", "the plane's normal, any length (planar scenes: z 0; no planar joints)".into()),
        f(joints, "axis", "[x, y, z]", "-", "required (hinge)", "the hinge's axis, world frame at the start, any length (planar scenes: [0, 0, 1])".into()),
        f(
            joints,
            "damping",
            "number",
            "N m s/rad",
            "0",
            format!("{}; torque against the bodies' relative spin (bars, rigid bodies, the ground)", range(limits::DAMPING)),
        ),
        f(cables, "name", "string", "-", "required", "unique".into()),
        f(
            cables,
            "route",
            "[strings]",
            "-",
            "required",
            format!(
                "points from anchor to anchor, pulleys between; 2 to {} points; a closed ring repeats its first point",
                limits::MAX_ROUTE_POINTS
            ),
        ),
        f(cables, "ea", "number", "N", "required", format!("axial stiffness EA, {}", range(limits::EA))),
        f(cables, "damping", "number", "N s/m", "0", format!("{}; excludes `damping_ratio`", range(limits::DAMPING))),
        f(
            cables,
            "damping_ratio",
            "number",
            "-",
            "none",
            format!("{}; c = 2 zeta sqrt((EA/L0) m_eff)", range(limits::DAMPING_RATIO)),
        ),
        f(
            cables,
            "rest_length",
            "number",
            "m",
            "form finding",
            format!("{}; excludes `prestress`, `force_density`", range(limits::LENGTH)),
        ),
        f(
            cables,
            "prestress",
            "number",
            "N",
            "none",
            format!("target tension at the initial geometry (form finding), {}", range(limits::PRESTRESS)),
        ),
        f(
            cables,
            "force_density",
            "number",
            "N/m",
            "none",
            format!("target T/L at the initial geometry (form finding), {}", range(limits::FORCE_DENSITY)),
        ),
        f(
            cables,
            "tension_only",
            "boolean",
            "-",
            "true",
            "false: a two-point cable keeps its law in compression and pushes (no pulleys)".into(),
        ),
        f(
            cables,
            "pulley_friction",
            "number or [mu, ...]",
            "-",
            "scene's, else 0",
            format!("Coulomb mu of every pulley, or one per pulley in route order, {}", range(limits::FRICTION)),
        ),
        f(
            cables,
            "winch_end",
            "string",
            "-",
            "first",
            "`first` or `last`: the anchor an actuator winds at (with pulley friction only)".into(),
        ),
        f(members, "name", "string", "-", "required", "unique among cables and members".into()),
        f(members, "ends", "[a, b]", "-", "required", "the two points it joins".into()),
        f(members, "ea", "number", "N", "required", format!("axial stiffness EA, {}", range(limits::EA))),
        f(members, "damping", "number", "N s/m", "0", format!("{}; excludes `damping_ratio`", range(limits::DAMPING))),
        f(members, "damping_ratio", "number", "-", "none", format!("{}; as a cable's", range(limits::DAMPING_RATIO))),
        f(
            members,
            "rest_length",
            "number",
            "m",
            "initial length",
            format!("{}; default: unstressed at the initial geometry", range(limits::LENGTH)),
        ),
        f(
            members,
            "force",
            "number",
            "N",
            "none",
            format!(
                "axial force at the initial geometry (negative: compression, above -EA), |force| up to {}",
                readable_number(limits::PRESTRESS.1)
            ),
        ),
        f(members, "form_find", "boolean", "-", "false", "true: the force that makes the initial geometry an equilibrium".into()),
        f(
            members,
            "mass",
            "number",
            "kg",
            "0",
            format!("{}; on its ends, which must be nodes or fixed bodies", range(limits::MASS)),
        ),
        f(
            members,
            "mass_matrix",
            "string",
            "-",
            "`lumped`",
            "`lumped` (half the mass on each end) or `consistent` (the uniform bar's (m/6) [[2, 1], [1, 2]], whose turning inertia is m L^2 / 12); needs `mass`".into(),
        ),
        f(
            members,
            "bending_stiffness",
            "number",
            "N m^2",
            "none",
            format!("EI, {}: buckles at pi^2 EI / L0^2 (L0 its initial rest length), then follows the elastica's post-buckling law", range(limits::BENDING_STIFFNESS)),
        ),
        f(
            members,
            "buckling_load",
            "number",
            "N",
            "none",
            format!("{}: the buckling load given directly (not with bending_stiffness)", range(limits::BUCKLING_LOAD)),
        ),
        f(actuators, "name", "string", "-", "required", "unique".into()),
        f(actuators, "cable", "string", "-", "required", "the cable whose rest length it sets".into()),
        f(actuators, "min_rest_length", "number", "m", "required", range(limits::LENGTH)),
        f(actuators, "max_rest_length", "number", "m", "required", format!("{}, >= min", range(limits::LENGTH))),
        f(actuators, "max_rate", "number", "m/s", "required", range(limits::RATE)),
        f(
            actuators,
            "command_delay_s",
            "number",
            "s",
            "0",
            format!("{}: each accepted command acts that late, in whole physics steps (rounded, with a warning)", range(limits::DELAY_S)),
        ),
        f(
            actuators,
            "command_delay",
            "integer",
            "steps",
            "0",
            format!("0 to {}: the same in physics steps; kept for one release, with a warning", limits::COMMAND_DELAY),
        ),
        f(actuators, "winch", "table", "-", "none", "a winch motor instead of the ideal actuator, below".into()),
        f(winch, "drum_radius", "number", "m", "required", range(limits::WINCH)),
        f(
            winch,
            "stall_tension",
            "number",
            "N",
            "required (or the DC form)",
            format!("{}: line force at full drive and zero speed", range(limits::WINCH)),
        ),
        f(
            winch,
            "no_load_speed",
            "number",
            "m/s",
            "required (or the DC form)",
            format!("{}: reel-in speed at full drive and zero tension", range(limits::WINCH)),
        ),
        f(
            winch,
            "torque_constant",
            "number",
            "N m/A",
            "none",
            format!("{}; DC form, with resistance and voltage: T_s = N k_t V / (R r), v0 = r V / (N k_t)", range(limits::WINCH)),
        ),
        f(winch, "resistance", "number", "ohm", "none", format!("{}; DC form", range(limits::WINCH))),
        f(winch, "voltage", "number", "V", "none", format!("{}; DC form, the supply at full drive", range(limits::WINCH))),
        f(winch, "gear_ratio", "number", "-", "1", format!("{}; DC form, motor turns per drum turn", range(limits::WINCH))),
        f(winch, "rotor_inertia", "number", "kg m^2", "0", format!("0 to {}, reflected to the drum", readable_number(limits::WINCH.1))),
        f(winch, "viscous_friction", "number", "N m s/rad", "0", format!("0 to {}, at the drum", readable_number(limits::WINCH.1))),
        f(winch, "back_drivable", "boolean", "-", "true", "false: a self-locking gear the load never turns back".into()),
        f(
            winch,
            "max_acceleration",
            "number",
            "m/s^2",
            "none",
            format!("{}: the speed set-point's largest change", range(limits::WINCH)),
        ),
        f(
            winch,
            "position_gains",
            "[kp, ki, kd]",
            "1/s, 1/s^2, -",
            "[20, 100, 0]",
            format!("each 0 to {}: speed set-point from the rest-length error", readable_number(limits::WINCH.1)),
        ),
        f(solver, "tolerance", "number", "-", "1e-11", "relative residual of the quasi-static Newton, in (0, 1)".into()),
        f(
            solver,
            "max_iterations",
            "integer",
            "-",
            "60",
            format!("Newton iterations per load step, 1 to {}", limits::MAX_SOLVER_ITERATIONS),
        ),
        f(
            damping,
            "alpha",
            "number",
            "1/s",
            "0",
            format!("{}; Rayleigh alpha M on every body (damps rigid motion too, like a drag)", range(limits::RAYLEIGH_ALPHA)),
        ),
        f(
            damping,
            "beta",
            "number",
            "s",
            "0",
            format!("{}; Rayleigh beta K0: adds beta EA/L0 to each cable's and member's damping", range(limits::RAYLEIGH_BETA)),
        ),
        f(
            deployment,
            "steps",
            "integer",
            "-",
            "50",
            format!("quasi-static load steps over the schedule, 1 to {}", limits::MAX_LOAD_STEPS),
        ),
        f(deployment, "ramps", "array of tables", "-", "none", "linear rest-length ramps, below".into()),
        f(ramps, "actuator", "string", "-", "required", "actuator name".into()),
        f(ramps, "start", "number", "s", "0", range(limits::TIME)),
        f(ramps, "duration", "number", "s", "required", format!("> 0, up to {}; within the actuator's max_rate", readable_number(limits::TIME.1))),
        f(ramps, "rest_length", "number", "m", "required", "reached at start + duration, within the actuator's limits".into()),
        f(grounds, "name", "string", "-", "ground, ground1, ...", "unique; names the contacts in outputs".into()),
        f(
            grounds,
            "normal",
            "[x, y, z]",
            "-",
            "against gravity (else +z; planar +y)",
            "outward normal of the half-space (any length, not zero); a tilted normal is an incline; planar: in the xy plane".into(),
        ),
        f(grounds, "point", "[x, y, z]", "m", "[0, 0, 0]", format!("a point on the plane; {coord}")),
        f(grounds, "mu", "number", "-", "1", format!("Coulomb friction coefficient, {}", range(limits::FRICTION))),
        f(
            grounds,
            "stiffness",
            "number",
            "N/m",
            "1000 W / L, at least 1e3",
            format!(
                "penalty stiffness k: a sphere pressed d into the ground feels k d; the default lets the whole weight W on one sphere press it in by a thousandth of the scene's size L; {}",
                range(limits::CONTACT_STIFFNESS)
            ),
        ),
        f(
            grounds,
            "dissipation",
            "number",
            "s/m",
            "1",
            format!(
                "Hunt-Crossley alpha: normal force k d (1 + alpha d_dot), restitution about 1 - (2/3) alpha v_impact; {}",
                range(limits::CONTACT_DISSIPATION)
            ),
        ),
        f(
            grounds,
            "stiction_speed",
            "number",
            "m/s",
            "1e-5",
            format!(
                "friction regularization v_s: a load at a fraction r of mu F_n creeps at v_s r / sqrt(1 - r^2); {}",
                range(limits::STICTION_SPEED)
            ),
        ),
        f(
            grounds,
            "stick_stiffness",
            "number",
            "N/m",
            "none (regularized friction)",
            format!(
                "stick-slip friction: each contact sticks where it touched through a tangential spring k_t until it pulls with mu F_n, then slips; no creep, stiction_speed unused; {}",
                range(limits::STICK_STIFFNESS)
            ),
        ),
        f(
            grounds,
            "stick_damping",
            "number",
            "N s/m",
            "2 sqrt(k_t m), m the sphere's body's mass",
            format!("the stick-slip spring's damper c_t (needs stick_stiffness); {}", range(limits::STICK_DAMPING)),
        ),
        f(
            collisions,
            "pairs",
            "\"all\" or [[bar, bar], ...]",
            "-",
            "\"all\"",
            "bars whose capsules (radius: each bar's contact_radius) collide; all: every two bars with a contact_radius that no joint joins".into(),
        ),
        f(collisions, "mu", "number", "-", "0.3", format!("Coulomb friction between struts, {}", range(limits::FRICTION))),
        f(
            collisions,
            "stiffness",
            "number",
            "N/m",
            "1000 W / L, at least 1e3",
            format!("penalty stiffness k, as a ground's; {}", range(limits::CONTACT_STIFFNESS)),
        ),
        f(
            collisions,
            "dissipation",
            "number",
            "s/m",
            "1",
            format!("Hunt-Crossley alpha, as a ground's; {}", range(limits::CONTACT_DISSIPATION)),
        ),
        f(
            collisions,
            "stiction_speed",
            "number",
            "m/s",
            "1e-5",
            format!("friction regularization v_s, as a ground's; {}", range(limits::STICTION_SPEED)),
        ),
        f(sensors, "seed", "integer", "-", "0", "seed of the noise generators, 0 to 2^64 - 1 (the node's sensor_seed overrides it)".into()),
        f(sensors, "tension", "table", "-", "none", "every cable's tension, N".into()),
        f(sensors, "length", "table", "-", "none", "every cable's length, m".into()),
        f(sensors, "rest_length", "table", "-", "none", "every actuator's rest length (the winch's encoder), m".into()),
        f(sensors, "position", "table", "-", "none", "every body's position, m".into()),
        f(sensors, "orientation", "table", "-", "none", "every body's orientation (noise in rad; no bias or resolution)".into()),
        f(sensors, "gyro", "table", "-", "none", "every body's angular velocity in its own axes (an IMU's gyro), rad/s".into()),
        f(sensors, "accelerometer", "table", "-", "none", "every body's specific force R^T (a - g) in its own axes (an IMU's accelerometer), m/s^2".into()),
        f(channel, "sigma", "number", "the channel's", "0", format!("Gaussian noise's standard deviation, 0 to {}", readable_number(limits::SENSOR_VALUE.1))),
        f(channel, "bias", "number", "the channel's", "0", format!("constant offset, within +-{}", readable_number(limits::SENSOR_VALUE.1))),
        f(channel, "resolution", "number", "the channel's", "0", format!("quantization step (0: none), 0 to {}", readable_number(limits::SENSOR_VALUE.1))),
        f(channel, "delay_s", "number", "s", "0", format!("{}: reports what was measured that long before, in whole physics steps (rounded, with a warning)", range(limits::DELAY_S))),
        f(channel, "delay", "integer", "steps", "0", format!("0 to {}: the same in physics steps; kept for one release, with a warning", limits::COMMAND_DELAY)),
        f(channel, "rate", "number", "Hz", "every step", format!("{}: updates per second, held in between", range(limits::SENSOR_RATE))),
        f(channel, "dropout", "number", "-", "0", "probability in [0, 1) that an update is lost (the last value is held)".into()),
        f(randomize, "seed", "integer", "-", "0", "seed of the draws, 0 to 2^64 - 1: the same seed, the same model".into()),
        f(
            randomize,
            "per",
            "string",
            "-",
            "run",
            "run: one draw for every run; reset: the node draws anew at every reset (episode k: seed + k)".into(),
        ),
        f(randomize, "parameters", "array of tables", "-", "none", "the parameters drawn, in order, below".into()),
        f(
            random,
            "parameter",
            "string",
            "-",
            "required",
            "ea, damping, mass or pulley_friction (a factor on the value as written), or rest_length (an offset, m)".into(),
        ),
        f(random, "elements", "array of strings", "-", "every one", "cables (bodies for mass) whose parameter is drawn, each on its own".into()),
        f(random, "distribution", "string", "-", "required", "uniform (low, high), normal or lognormal (mean, sigma; of the logarithm for lognormal)".into()),
        f(random, "low", "number", "-", "required for uniform", "lower bound; a factor's above 0".into()),
        f(random, "high", "number", "-", "required for uniform", "upper bound, above low".into()),
        f(random, "mean", "number", "-", "required for normal, lognormal", "mean; a factor's normal above 6 sigma".into()),
        f(random, "sigma", "number", "-", "required for normal, lognormal", "standard deviation, positive".into()),
    ]
}

/// The reference as a Markdown table (docs/scene-format.md's, verbatim).
pub fn markdown() -> String {
    let mut out = String::from("| table | field | format | unit | default | range and meaning |\n");
    out.push_str("| --- | --- | --- | --- | --- | --- |\n");
    for d in scene_fields() {
        out.push_str(&format!(
            "| `{}` | `{}` | {} | {} | {} | {} |\n",
            d.table, d.field, d.format, d.unit, d.default, d.range
        ));
    }
    out
}
