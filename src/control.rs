//! Actuator control: takes actuator commands (a rest-length target and/or a rate) and the
//! deployment schedule, gives each cable's rest length at the end of every step. Commands are
//! validated against the actuator's limits before they are accepted: a non-finite, out-of-range or
//! empty command is rejected with a `CommandError` and changes nothing. An accepted command takes
//! the actuator off the schedule and is held until replaced.
//!
//! - target `L*` (with optional rate `r`, default the actuator's `max_rate`): the rest length moves
//!   towards `L*` at `r` m/s and stays there;
//! - rate only `r`: the rest length changes at `r` m/s (negative shortens) until a limit, where it
//!   stops;
//! - tension only `T*` (a winch's actuator only): the winch's motor is driven so that its line
//!   force is `T*` (`crate::forces::winch`, tension mode); an ideal actuator has no force to set
//!   and refuses it.
//!
//! An actuator with a `command_delay` of `k` steps gets each accepted command `k` steps late
//! (`Control::tick`, once per `Simulator::step`). A winch's cable keeps its rest length here: its
//! motor moves it (`crate::forces::winch`), and the mode becomes what the winch's controller is
//! asked for (`Control::winch_command`).

use crate::forces::winch::WinchCommand;
use crate::model::{ActuatorId, Model};

/// A command for one actuator: a rest length, a rate, both, or a tension alone.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct ActuatorCommand {
    /// Target rest length, m, within `[min_rest_length, max_rest_length]`.
    pub rest_length: Option<f64>,
    /// Rate, m/s: with a target, the speed towards it (> 0, <= max_rate); alone, the signed rate
    /// (|rate| <= max_rate).
    pub rate: Option<f64>,
    /// Tension, N, within `[0, stall_tension]`: the line force a winch's motor is to hold (tension
    /// mode). Only for an actuator with a winch, and only alone.
    pub tension: Option<f64>,
}

impl ActuatorCommand {
    /// Move to the rest length `rest_length` (m) at the actuator's `max_rate`.
    pub fn target(rest_length: f64) -> Self {
        Self { rest_length: Some(rest_length), ..Self::default() }
    }

    /// Change the rest length at the signed rate `rate` (m/s).
    pub fn rate(rate: f64) -> Self {
        Self { rate: Some(rate), ..Self::default() }
    }

    /// Hold the line force `tension` (N) with the actuator's winch motor.
    pub fn tension(tension: f64) -> Self {
        Self { tension: Some(tension), ..Self::default() }
    }
}

/// Why a command was rejected. The actuator keeps its previous command.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum CommandError {
    /// No actuator has this name.
    #[error("unknown actuator '{0}'")]
    UnknownActuator(String),
    /// A value is NaN or infinite.
    #[error("actuator '{actuator}': {field} = {value} is not finite")]
    NonFinite {
        /// Actuator name.
        actuator: String,
        /// `rest_length`, `rate` or `tension`.
        field: &'static str,
        /// The value received.
        value: f64,
    },
    /// A value is outside the actuator's limits.
    #[error("actuator '{actuator}': {field} = {value} is outside [{min}, {max}]")]
    OutOfRange {
        /// Actuator name.
        actuator: String,
        /// `rest_length`, `rate` or `tension`.
        field: &'static str,
        /// The value received.
        value: f64,
        /// Lower limit.
        min: f64,
        /// Upper limit.
        max: f64,
    },
    /// Neither a target, a rate nor a tension.
    #[error("actuator '{0}': a command needs a rest length, a rate, both, or a tension")]
    Empty(String),
    /// A tension together with a rest length or a rate (which should the winch follow?).
    #[error("actuator '{0}': a tension command cannot also carry a rest length or a rate")]
    TensionWithLength(String),
    /// A tension for an actuator without a winch motor (an ideal actuator sets a rest length,
    /// never a force).
    #[error("actuator '{0}' has no winch motor: tension commands need `[actuators.winch]` in the scene")]
    NoWinch(String),
}

/// What an actuator is following.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum ActuatorMode {
    /// The model's deployment schedule.
    Schedule,
    /// Move towards `rest_length` (m) at `rate` (m/s, > 0) and hold it.
    Target {
        /// Target rest length, m.
        rest_length: f64,
        /// Speed towards it, m/s.
        rate: f64,
    },
    /// Change at a constant signed rate (m/s) until a limit.
    Rate(f64),
    /// Hold the winch motor's line force at this tension (N); winch actuators only.
    Tension(f64),
}

/// The mode of every actuator, and the commands still on their way to actuators with a
/// `command_delay`.
#[derive(Debug, Clone, PartialEq)]
pub struct Control {
    modes: Vec<ActuatorMode>,
    /// Each actuator's command delay in whole steps (`Delay::steps` at the physics step).
    delay_steps: Vec<usize>,
    /// Accepted commands waiting for their step: `(steps left, actuator, mode)`, oldest first.
    delayed: std::collections::VecDeque<(usize, ActuatorId, ActuatorMode)>,
}

impl Control {
    /// Every actuator on the schedule; command delays resolved to whole steps of `dt` (s).
    pub fn new(model: &Model, dt: f64) -> Self {
        Self {
            modes: vec![ActuatorMode::Schedule; model.actuators.len()],
            delay_steps: model.actuators.iter().map(|a| a.command_delay.steps(dt)).collect(),
            delayed: std::collections::VecDeque::new(),
        }
    }

    /// Current mode of actuator `id`.
    pub fn mode(&self, id: ActuatorId) -> ActuatorMode {
        self.modes[id.0]
    }

    /// Validates `cmd` for actuator `id` against its limits and returns the mode it asks for;
    /// changes nothing.
    pub fn validate(
        model: &Model,
        id: ActuatorId,
        cmd: ActuatorCommand,
    ) -> Result<ActuatorMode, CommandError> {
        let act = &model.actuators[id.0];
        let name = || model.actuator_names[id.0].clone();
        let check = |field: &'static str, value: f64, min: f64, max: f64| {
            if !value.is_finite() {
                Err(CommandError::NonFinite { actuator: name(), field, value })
            } else if value < min || value > max {
                Err(CommandError::OutOfRange { actuator: name(), field, value, min, max })
            } else {
                Ok(value)
            }
        };
        if let Some(t) = cmd.tension {
            if cmd.rest_length.is_some() || cmd.rate.is_some() {
                return Err(CommandError::TensionWithLength(name()));
            }
            let Some(w) = act.winch else { return Err(CommandError::NoWinch(name())) };
            let stall = model.winches[w].stall_tension;
            return Ok(ActuatorMode::Tension(check("tension", t, 0.0, stall)?));
        }
        match (cmd.rest_length, cmd.rate) {
            (Some(l), r) => {
                let rest_length = check("rest_length", l, act.min_rest_length, act.max_rest_length)?;
                let rate = match r {
                    Some(r) => check("rate", r, f64::MIN_POSITIVE, act.max_rate)?,
                    None => act.max_rate,
                };
                Ok(ActuatorMode::Target { rest_length, rate })
            }
            (None, Some(r)) => Ok(ActuatorMode::Rate(check("rate", r, -act.max_rate, act.max_rate)?)),
            (None, None) => Err(CommandError::Empty(name())),
        }
    }

    /// Validates `cmd` for actuator `id` and, if valid, makes it the actuator's mode from the
    /// next step, or, with a `command_delay` of `k` steps, from the step after `k` more
    /// `tick`s. A rejected command is refused at once, whatever the delay.
    pub fn command(
        &mut self,
        model: &Model,
        id: ActuatorId,
        cmd: ActuatorCommand,
    ) -> Result<(), CommandError> {
        let mode = Self::validate(model, id, cmd)?;
        match self.delay_steps[id.0] {
            0 => self.modes[id.0] = mode,
            k => self.delayed.push_back((k, id, mode)),
        }
        Ok(())
    }

    /// Called once at the start of every `Simulator::step`: commands whose delay has run out
    /// become their actuators' modes, in the order they arrived.
    pub fn tick(&mut self) {
        while let Some(&(0, id, mode)) = self.delayed.front() {
            self.modes[id.0] = mode;
            self.delayed.pop_front();
        }
        for (left, _, _) in self.delayed.iter_mut() {
            *left -= 1;
        }
    }

    /// Commands accepted and still delayed.
    pub fn pending_commands(&self) -> usize {
        self.delayed.len()
    }

    /// Like `command`, by actuator name.
    pub fn command_by_name(
        &mut self,
        model: &Model,
        name: &str,
        cmd: ActuatorCommand,
    ) -> Result<(), CommandError> {
        let id = model.actuator_id(name).ok_or_else(|| CommandError::UnknownActuator(name.to_string()))?;
        self.command(model, id, cmd)
    }

    /// Rest lengths (m) at time `t + h` given those at `t` (`now`): scheduled actuators follow the
    /// schedule, commanded ones move as their mode says, clamped to their limits; cables without
    /// an actuator keep their rest length.
    ///
    /// A winch's cable keeps its rest length here: its motor moves it during the sub-step
    /// (`winch_command`, `crate::forces::winch`).
    pub fn advance(&self, model: &Model, t: f64, h: f64, now: &[f64], out: &mut [f64]) {
        out.copy_from_slice(now);
        for (i, act) in model.actuators.iter().enumerate() {
            if act.winch.is_none() {
                out[act.cable.0] = self.ideal_rest_length(model, ActuatorId(i), t, h, now[act.cable.0]);
            }
        }
    }

    /// Where the ideal actuator `id` takes the rest length `now` (m) over the step from `t` to
    /// `t + h` (s): the schedule's value, a move towards the target at its rate, or the signed
    /// rate, held within the limits.
    fn ideal_rest_length(&self, model: &Model, id: ActuatorId, t: f64, h: f64, now: f64) -> f64 {
        let act = &model.actuators[id.0];
        match self.modes[id.0] {
            ActuatorMode::Schedule => {
                model.schedule.rest_length(id, model.initial_rest_lengths[act.cable.0], t + h)
            }
            ActuatorMode::Target { rest_length, rate } => {
                let step = rate * h;
                now + (rest_length - now).clamp(-step, step)
            }
            ActuatorMode::Rate(r) => (now + r * h).clamp(act.min_rest_length, act.max_rest_length),
            // refused by `validate` for an ideal actuator; a winch's reference holds
            ActuatorMode::Tension(_) => now,
        }
    }

    /// What winch `id`'s controller is asked for over the sub-step from `t` to `t + h` (s): a
    /// signed rate is a speed command, a tension a tension command; the schedule and a target
    /// are a rest-length reference, moved from `reference` (m, the last one) as the ideal
    /// actuator would move its rest length, with its rate as the feed-forward.
    pub fn winch_command(
        &self,
        model: &Model,
        id: ActuatorId,
        t: f64,
        h: f64,
        reference: f64,
    ) -> WinchCommand {
        match self.modes[id.0] {
            ActuatorMode::Rate(r) => WinchCommand::Speed(r),
            ActuatorMode::Tension(t) => WinchCommand::Tension(t),
            ActuatorMode::Schedule | ActuatorMode::Target { .. } => {
                let next = self.ideal_rest_length(model, id, t, h, reference);
                WinchCommand::Position { reference: next, rate: (next - reference) / h }
            }
        }
    }

    /// Rate of each actuator's rest length (m/s) over a step from `now` to `next` of length `h`.
    pub fn rates(model: &Model, now: &[f64], next: &[f64], h: f64, out: &mut [f64]) {
        out.fill(0.0);
        for a in &model.actuators {
            let c = a.cable.0;
            out[c] = (next[c] - now[c]) / h;
        }
    }
}
