//! Actuators and the deployment schedule: takes `[[actuators]]` (with their winches) and
//! `[deployment]`, gives `ActuatorModel`s, `WinchModel`s and the `Schedule`.

use super::context::{delay, in_range, Ctx};
use crate::error::SceneError;
use crate::forces::winch::{PositionGains, WinchModel};
use crate::model::{ActuatorModel, Model, Ramp, Schedule};
use crate::scene::spec::{limits, SceneSpec, WinchSpec};

/// Checks and builds `actuators` (one per cable, length and rate limits): the actuators and
/// their names.
pub(super) fn build_actuators(
    spec: &SceneSpec,
    cx: &Ctx,
    cable_names: &[String],
) -> Result<Actuators, SceneError> {
    let mut winches = Vec::new();
    let mut actuators = Vec::new();
    let mut actuator_names: Vec<String> = Vec::new();
    for (i, a) in spec.actuators.iter().enumerate() {
        let e = |field: &str, reason: String| cx.err("actuators", i, field, reason);
        if a.name.is_empty() || actuator_names.contains(&a.name) {
            return Err(e("name", format!("empty or duplicate actuator name '{}'", a.name)));
        }
        let cable = cable_names
            .iter()
            .position(|n| *n == a.cable)
            .ok_or_else(|| e("cable", format!("unknown cable '{}'", a.cable)))?;
        if actuators.iter().any(|o: &ActuatorModel| o.cable.0 == cable) {
            return Err(e("cable", format!("cable '{}' already has an actuator", a.cable)));
        }
        in_range(a.min_rest_length, limits::LENGTH, "m").map_err(|r| e("min_rest_length", r))?;
        in_range(a.max_rest_length, limits::LENGTH, "m").map_err(|r| e("max_rest_length", r))?;
        if a.max_rest_length < a.min_rest_length {
            return Err(e(
                "max_rest_length",
                format!("must be >= min_rest_length, got {}", a.max_rest_length),
            ));
        }
        in_range(a.max_rate, limits::RATE, "m/s").map_err(|r| e("max_rate", r))?;
        let command_delay = delay(a.command_delay_s, a.command_delay, "command_delay", e)?;
        let winch = match &a.winch {
            Some(w) => {
                let id = crate::model::ActuatorId(actuators.len());
                winches.push(build_winch(w, id, crate::model::CableId(cable), &e)?);
                Some(winches.len() - 1)
            }
            None => None,
        };
        actuators.push(ActuatorModel {
            cable: crate::model::CableId(cable),
            min_rest_length: a.min_rest_length,
            max_rest_length: a.max_rest_length,
            max_rate: a.max_rate,
            command_delay,
            winch,
        });
        actuator_names.push(a.name.clone());
    }

    Ok(Actuators { actuators, actuator_names, winches })
}

/// What `build_actuators` gives: the actuators, their names, and the winch motors of those that
/// have one.
pub(super) struct Actuators {
    pub(super) actuators: Vec<ActuatorModel>,
    pub(super) actuator_names: Vec<String>,
    pub(super) winches: Vec<WinchModel>,
}

/// Checks one `[actuators.winch]` table and gives its model: the torque-speed line in rope units
/// from `stall_tension` and `no_load_speed`, or from a DC motor (`T_s = N k_t V / (R r)`,
/// `v0 = r V / (N k_t)`), never both; `e(field, reason)` names the actuator.
pub(super) fn build_winch(
    w: &WinchSpec,
    actuator: crate::model::ActuatorId,
    cable: crate::model::CableId,
    e: &dyn Fn(&str, String) -> SceneError,
) -> Result<WinchModel, SceneError> {
    let positive = |x: f64, field: &str, unit: &str| {
        in_range(x, limits::WINCH, unit).map_err(|r| e(&format!("winch.{field}"), r))
    };
    let r = positive(w.drum_radius, "drum_radius", "m")?;
    let dc = [w.torque_constant, w.resistance, w.voltage];
    let (stall_tension, no_load_speed) = match (w.stall_tension, w.no_load_speed, dc) {
        (Some(t), Some(v), [None, None, None]) if w.gear_ratio.is_none() => {
            (positive(t, "stall_tension", "N")?, positive(v, "no_load_speed", "m/s")?)
        }
        (None, None, [Some(kt), Some(res), Some(volt)]) => {
            let kt = positive(kt, "torque_constant", "N m/A")?;
            let res = positive(res, "resistance", "ohm")?;
            let volt = positive(volt, "voltage", "V")?;
            let n = positive(w.gear_ratio.unwrap_or(1.0), "gear_ratio", "")?;
            (n * kt * volt / (res * r), r * volt / (n * kt))
        }
        _ => {
            return Err(e(
                "winch",
                "give either stall_tension and no_load_speed, or torque_constant, resistance and \
                 voltage (with an optional gear_ratio)"
                    .into(),
            ))
        }
    };
    let nonnegative = |x: f64, field: &str, unit: &str| {
        in_range(x, (0.0, limits::WINCH.1), unit).map_err(|r| e(&format!("winch.{field}"), r))
    };
    let rotor_inertia = nonnegative(w.rotor_inertia, "rotor_inertia", "kg m^2")?;
    let viscous_friction = nonnegative(w.viscous_friction, "viscous_friction", "N m s/rad")?;
    let max_acceleration = match w.max_acceleration {
        Some(a) => positive(a, "max_acceleration", "m/s^2")?,
        None => f64::INFINITY,
    };
    let [kp, ki, kd] = w.position_gains.unwrap_or([20.0, 100.0, 0.0]);
    for (g, name) in [(kp, "kp"), (ki, "ki"), (kd, "kd")] {
        nonnegative(g, &format!("position_gains.{name}"), "")?;
    }
    Ok(WinchModel {
        actuator,
        cable,
        drum_radius: r,
        stall_tension,
        no_load_speed,
        rotor_inertia,
        viscous_friction,
        back_drivable: w.back_drivable,
        max_acceleration,
        gains: PositionGains { kp, ki, kd },
    })
}

/// Marks each winch's cable (`CableModel::winch`) and refuses a winch on an element that cannot
/// take one: a member (it pushes; a drum only pulls) or a cable with pulley friction.
pub(super) fn attach_winches(model: &mut Model, cx: &Ctx) -> Result<(), SceneError> {
    for (w, winch) in model.winches.iter().enumerate() {
        let i = winch.actuator.0;
        let cable = &mut model.cables[winch.cable.0];
        if !cable.tension_only {
            return Err(cx.err("actuators", i, "winch", "a winch drives a cable, not a member that pushes"));
        }
        if cable.friction.is_some() {
            return Err(cx.err(
                "actuators",
                i,
                "winch",
                "a winch on a cable with pulley friction is not modelled yet (use the ideal actuator)",
            ));
        }
        cable.winch = Some(w);
    }
    Ok(())
}

/// The `[deployment]` schedule, checked against the actuators' limits (one load step when the
/// scene has none).
pub(super) fn build_schedule(spec: &SceneSpec, model: &Model, cx: &Ctx) -> Result<Schedule, SceneError> {
    if let Some(d) = &spec.deployment {
        if d.steps == 0 || d.steps > limits::MAX_LOAD_STEPS {
            return Err(cx.top(
                "deployment",
                format!("steps must be in [1, {}], got {}", limits::MAX_LOAD_STEPS, d.steps),
            ));
        }
        let mut ramps = Vec::new();
        for (i, r) in d.ramps.iter().enumerate() {
            let e = |field: &str, reason: String| cx.err("deployment.ramps", i, field, reason);
            let id = model
                .actuator_id(&r.actuator)
                .ok_or_else(|| e("actuator", format!("unknown actuator '{}'", r.actuator)))?;
            in_range(r.start, limits::TIME, "s").map_err(|r| e("start", r))?;
            if in_range(r.duration, limits::TIME, "s").map_err(|r| e("duration", r))? == 0.0 {
                return Err(e("duration", "must be positive, got 0".into()));
            }
            let act = model.actuators[id.0];
            if !(r.rest_length >= act.min_rest_length && r.rest_length <= act.max_rest_length) {
                return Err(e(
                    "rest_length",
                    format!(
                        "{} m is outside the actuator's range [{}, {}]",
                        r.rest_length, act.min_rest_length, act.max_rest_length
                    ),
                ));
            }
            ramps.push((
                i,
                Ramp { actuator: id, start: r.start, duration: r.duration, target: r.rest_length },
            ));
        }
        ramps.sort_by(|a, b| {
            (a.1.actuator, a.1.start).partial_cmp(&(b.1.actuator, b.1.start)).expect("finite")
        });
        let mut prev: Option<Ramp> = None;
        for (i, r) in &ramps {
            let e = |field: &str, reason: String| cx.err("deployment.ramps", *i, field, reason);
            let from = match prev {
                Some(p) if p.actuator == r.actuator => {
                    if r.start < p.start + p.duration - 1e-12 {
                        return Err(e("start", "overlaps the previous ramp of the same actuator".into()));
                    }
                    p.target
                }
                _ => model.initial_rest_lengths[model.actuators[r.actuator.0].cable.0],
            };
            let rate = (r.target - from).abs() / r.duration;
            let max_rate = model.actuators[r.actuator.0].max_rate;
            if rate > max_rate * (1.0 + 1e-12) {
                return Err(e(
                    "duration",
                    format!("needs {rate:.4} m/s, above the actuator's max_rate {max_rate} m/s"),
                ));
            }
            prev = Some(*r);
        }
        Ok(Schedule { ramps: ramps.into_iter().map(|(_, r)| r).collect(), steps: d.steps })
    } else {
        Ok(Schedule { steps: 1, ..Schedule::default() })
    }
}
