//! Winch motors (docs/scene-format.md, "Winches"): takes a winch's model (drum, torque-speed
//! line, rotor inertia, friction, gear), its state at the start of a sub-step and the geometry of
//! its cable, gives the cable's tension and rest length at the end of the sub-step, the tangent
//! factors the implicit integrator needs, the controller's drive and the energy booked per step.
//!
//! Everything is in rope units at the drum (radius `r`): the reel-in speed `v = r omega` (m/s,
//! positive when it winds cable in and shortens the rest length), the motor's line force
//! `F_m = T_s (u - v/v0)`
//! (N; `T_s` the stall tension, `v0` the no-load speed, `u` in `[-1, 1]` the drive, a DC motor's
//! voltage over its supply), the rotor's equivalent mass `M = J / r^2` (kg) and the drum's viscous
//! friction `c_v = b / r^2` (N s/m). The drum obeys
//!
//! `M dv/dt = T_s u - (T_s/v0 + c_v) v - T`,   `dL0/dt = -v`,
//!
//! advanced over each sub-step `h` by implicit Euler, whatever the structure's integrator, with
//! `u` held over the sub-step (a digital drive): with `D = M/h + T_s/v0 + c_v` and
//! `A = M v_n / h + T_s u`, the speed at the end is `v(T) = (A - T) / D` and the rest length
//! `L0(T) = L0_n - h v(T)`, an affine function of the end tension. Condensed into the cable law
//! `T = EA (L - L0)/L0 + c Ldot`, the tension solves one monotone scalar equation
//! `g(T) = T - law(L, Ldot, L0(T)) = 0` (`g' = 1 + EA L / L0^2 dL0/dT > 0`), and the winch acts as
//! a compliance `h^2 / (M + h (T_s/v0 + c_v))` in series with the cable: the tangents are the
//! cable's with `EA` and `c` scaled by `s = 1 / g'(T)` (`tangent_scale`).
//!
//! The drive comes from the command (`prepare`): position mode runs a PID on the rest length,
//! speed mode asks for `u = -rate / v0`, both through a speed set-point held within `max_rate`
//! and `max_acceleration`; tension mode is a torque (current) loop, `u = T* / T_s + v_n / v0`,
//! so the motor's force at the drum's speed at the start of the sub-step is `T*`. In steady
//! motion the cable then carries `T* - (b / r^2) v` (the drum's friction is not compensated); the
//! speed is bounded by the torque-speed line (`|u| <= 1`), not by `max_rate`.
//!
//! A gear that is not back-drivable (a worm drive) never lets the load turn the drum back: the
//! speed is floored at `min(0, v(0))`, what the motor alone does (hold, or pay out at its own
//! speed when driven that way). The rest-length limits are hard stops. Both make `L0(T)`
//! piecewise affine, still non-decreasing, so `g` stays monotone.

use crate::forces::cable::{self, CableResponse, CableScratch};
use crate::kinematics::PointKinematics;
pub use crate::model::{PositionGains, WinchModel};
pub use crate::state::WinchState;

use crate::model::{CableModel, Model, PointId};

/// What the controller asks of a winch over one sub-step.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum WinchCommand {
    /// Track the rest-length reference `reference` (m), which moves at `rate` (m/s, signed
    /// `dL_ref/dt`).
    Position {
        /// Reference rest length at the end of the sub-step, m.
        reference: f64,
        /// Its rate, m/s.
        rate: f64,
    },
    /// Run at the no-load speed `-rate` (m/s; `rate` is `dL0/dt`, negative reels in): the drive
    /// `u = -rate / v0`, so the speed droops under load along the torque-speed line.
    Speed(f64),
    /// Hold the line force at this tension (N): a torque (current) loop that sets the drive so
    /// that the motor's force at the drum's present speed is the tension,
    /// `u = T* / T_s + v_n / v0` within `[-1, 1]`.
    Tension(f64),
}

/// The rest length at the end of the sub-step for an end tension `t` (N), and its derivative
/// `dL0/dT` (m/N): `L0_n - h max(v(T), floor)` held within `[min, max]` (module docs).
pub fn rest_length_at(model: &Model, w: &WinchModel, s: &WinchState, l0_start: f64, t: f64) -> (f64, f64) {
    let act = &model.actuators[w.actuator.0];
    let h = s.step;
    let d = w.equivalent_mass() / h + w.speed_resistance();
    let a = w.equivalent_mass() * s.speed / h + w.stall_tension * s.drive;
    let v = (a - t) / d;
    let (v, slope) = if v < s.floor { (s.floor, 0.0) } else { (v, h / d) };
    let l0 = l0_start - h * v;
    if l0 < act.min_rest_length {
        (act.min_rest_length, 0.0)
    } else if l0 > act.max_rest_length {
        (act.max_rest_length, 0.0)
    } else {
        (l0, slope)
    }
}

/// Solves `g(T) = T - law(L, Ldot, L0(T)) = 0` (module docs) for the end tension of winch `w`'s
/// cable at length `l` (m) and length rate `l_rate` (m/s), starting from rest length `l0_start`
/// (m). Returns `(T, L0(T), dL0/dT)`. Safeguarded Newton inside `[0, law(L0(0))]`; `g` is
/// increasing, so the root is unique.
pub fn solve_tension(
    model: &Model,
    w: &WinchModel,
    s: &WinchState,
    cable: &CableModel,
    l0_start: f64,
    l: f64,
    l_rate: f64,
) -> (f64, f64, f64) {
    let (l0_slack, slope0) = rest_length_at(model, w, s, l0_start, 0.0);
    let high = cable::tension(cable, l0_slack, l, l_rate);
    if high <= 0.0 {
        return (0.0, l0_slack, slope0);
    }
    let (mut lo, mut hi) = (0.0, high);
    let mut t = high;
    for _ in 0..100 {
        let (l0, slope) = rest_length_at(model, w, s, l0_start, t);
        let g = t - cable::tension(cable, l0, l, l_rate);
        if g > 0.0 {
            hi = t;
        } else {
            lo = t;
        }
        let dg = 1.0 + cable.axial_stiffness * l / (l0 * l0) * slope;
        let mut next = t - g / dg;
        if !(next > lo && next < hi) {
            next = 0.5 * (lo + hi);
        }
        if (next - t).abs() <= 1e-14 * high || hi - lo <= 1e-14 * high {
            t = next;
            break;
        }
        t = next;
    }
    let (l0, slope) = rest_length_at(model, w, s, l0_start, t);
    (t, l0, slope)
}

/// `s = 1 / g'(T) = 1 / (1 + EA L / L0^2 dL0/dT)`: the factor on `EA` and `c` in the tangents of
/// a winch's cable (module docs); 1 where the rest length does not move with the tension.
pub fn tangent_scale(cable: &CableModel, l: f64, l0: f64, slope: f64) -> f64 {
    1.0 / (1.0 + cable.axial_stiffness * l / (l0 * l0) * slope)
}

/// Like `crate::forces::cable::add_cable_force` for a cable driven by winch `w` during a
/// sub-step (`WinchState::step > 0`): the tension and rest length of `solve_tension`, the force
/// `-T g` into `force`. The response's `rest_length` is the rest length at the end of the
/// sub-step.
#[allow(clippy::too_many_arguments)]
pub fn add_winch_cable_force(
    model: &Model,
    route: &[PointId],
    cable: &CableModel,
    w: &WinchModel,
    s: &WinchState,
    l0_start: f64,
    kin: &[PointKinematics],
    scratch: &mut CableScratch,
    force: &mut nalgebra::DVector<f64>,
) -> CableResponse {
    let (length, length_rate) = cable::route_geometry(route, kin, scratch);
    let (t, l0, _) = solve_tension(model, w, s, cable, l0_start, length, length_rate);
    if t != 0.0 {
        cable::add_length_gradient(model, route, kin, scratch, -t, force);
    }
    CableResponse {
        length,
        length_rate,
        rest_length: l0,
        tension: t,
        slack: length <= l0,
        energy: cable::elastic_energy(cable, l0, length),
    }
}

/// The drive `u` (in `[-1, 1]`) for the sub-step of `h` s that starts now, from `command`,
/// written into `s` with `step = h` and the gear's `floor`; `l0` is the rest length now (m).
/// What the sub-step will carry to `commit` goes into `s.pending`.
pub fn prepare(model: &Model, w: &WinchModel, s: &mut WinchState, command: WinchCommand, l0: f64, h: f64) {
    let act = &model.actuators[w.actuator.0];
    // a speed set-point within the rate and acceleration limits, and the drive that asks for it
    let dv = w.max_acceleration * h;
    let limited = |v: f64| {
        let v = v.clamp(-act.max_rate, act.max_rate).clamp(s.setpoint - dv, s.setpoint + dv);
        (v, (v / w.no_load_speed).clamp(-1.0, 1.0))
    };
    let (setpoint, drive, reference, error) = match command {
        WinchCommand::Position { reference, rate } => {
            let e = l0 - reference;
            let g = w.gains;
            let (v, u) = limited(-rate + g.kp * e + g.ki * (s.integral + e * h) - g.kd * s.speed);
            (v, u, reference, e)
        }
        // the reference follows the drum, so that a later position command starts from where
        // the cable is
        WinchCommand::Speed(rate) => {
            let (v, u) = limited(-rate);
            (v, u, l0, 0.0)
        }
        // no speed set-point: the present speed, so that a later command ramps from it
        WinchCommand::Tension(tension) => {
            let u = (tension / w.stall_tension + s.speed / w.no_load_speed).clamp(-1.0, 1.0);
            (s.speed, u, l0, 0.0)
        }
    };
    s.drive = drive;
    s.step = h;
    s.floor = if w.back_drivable {
        f64::NEG_INFINITY
    } else {
        let unloaded = (w.equivalent_mass() * s.speed / h + w.stall_tension * drive)
            / (w.equivalent_mass() / h + w.speed_resistance());
        unloaded.min(0.0)
    };
    s.pending = [setpoint, reference, error];
}

/// Energies of one accepted sub-step of a winch, J.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct WinchWork {
    /// Work of the motor's line force, `h F_m(v) v`.
    pub motor: f64,
    /// Loss in the drum's viscous friction, `h (b / r^2) v^2`.
    pub friction: f64,
}

/// After an accepted sub-step: the end speed `v = (L0_n - L0) / h` (the drum turned exactly as
/// much cable as the rest length changed; stops and a held gear included), the controller's
/// state, and `step = 0`. `l0_start` and `l0_end` are the rest lengths at both ends (m). Returns
/// the sub-step's energies. The integral does not wind up while the drive is saturated.
pub fn commit(w: &WinchModel, s: &mut WinchState, l0_start: f64, l0_end: f64) -> WinchWork {
    let h = s.step;
    let v = (l0_start - l0_end) / h;
    let [setpoint, reference, error] = s.pending;
    let work = WinchWork {
        motor: h * w.motor_force(s.drive, v) * v,
        friction: h * w.viscous_friction / (w.drum_radius * w.drum_radius) * v * v,
    };
    if s.drive.abs() < 1.0 {
        s.integral += error * h;
    }
    s.speed = v;
    s.setpoint = setpoint;
    s.reference = reference;
    s.step = 0.0;
    work
}

/// Kinetic energy of the rotor at reel-in speed `v`, `J omega^2 / 2 = M v^2 / 2`, J.
pub fn rotor_energy(w: &WinchModel, v: f64) -> f64 {
    0.5 * w.equivalent_mass() * v * v
}
