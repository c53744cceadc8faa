//! Command checks and limits: takes an incoming actuator command (a `msg::ActuatorCommand`, a
//! `sensor_msgs/JointState`, or a shared-memory command's entries, already resolved) and the
//! `Model`, gives validated per-actuator `control::ActuatorCommand`s or the `MessageError` that
//! says why the whole message is refused. Every transport judges a command here, the same way:
//! sizes first, then array lengths, names, duplicates and every value against its actuator's
//! limits (`control::Control::validate`).

use crate::control;
use crate::io::msg::{ActuatorCommand, AppliedCommands};
use crate::model::{ActuatorId, Model};

/// Most command messages the transports hand to the core per step (`tick`); the rest wait in the
/// transport's own queue (keep-last QoS there), so a flood costs each step a bounded amount.
pub const MAX_COMMANDS_PER_STEP: usize = 64;

/// Longest actuator name (and command `frame_id`) a command may carry, bytes.
pub const MAX_NAME_BYTES: usize = 256;
/// Most entries (names, rest lengths or rates) one command message may carry.
pub const MAX_COMMAND_ENTRIES: usize = 1024;
/// Largest command message, bytes of strings plus 8 per number (checked before anything else).
pub const MAX_COMMAND_BYTES: usize = 64 * 1024;
/// Longest excerpt of received text that an error or a diagnostic repeats, characters.
pub const EXCERPT_CHARS: usize = 48;

/// At most `max` characters of `text`, with the full size said when it was cut.
pub fn excerpt(text: &str, max: usize) -> String {
    match text.char_indices().nth(max) {
        None => text.to_string(),
        Some((cut, _)) => format!("{}... ({} bytes)", &text[..cut], text.len()),
    }
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
    /// A size limit is exceeded (checked before any other work).
    #[error("{what} is {size}, over the limit of {limit}")]
    TooLarge {
        /// What was measured.
        what: &'static str,
        /// Its size.
        size: usize,
        /// The limit.
        limit: usize,
    },
    /// The message names no actuator.
    #[error("the command names no actuator")]
    NoNames,
    /// The same actuator appears twice in one message (which entry should win is ambiguous).
    #[error("actuator '{0}' is named more than once")]
    Duplicate(String),
    /// An actuator given by index that the model does not have.
    #[error("actuator index {index} is out of range (the scene has {count} actuators)")]
    UnknownIndex {
        /// The index received.
        index: u64,
        /// Actuators in the model.
        count: usize,
    },
    /// A field that cannot be read (a name that is not UTF-8 or has no terminating NUL in its
    /// fixed-size field, unknown flag bits).
    #[error("{0}")]
    Malformed(String),
    /// One of the commands is invalid.
    #[error(transparent)]
    Command(#[from] control::CommandError),
}

/// The value arrays of one command message, each empty (not commanded) or parallel to its names.
#[derive(Debug, Clone, Copy, Default)]
pub struct CommandArrays<'a> {
    /// Target rest lengths, m.
    pub rest_length: &'a [f64],
    /// Rates, m/s.
    pub rate: &'a [f64],
    /// Tensions, N (winch actuators; alone).
    pub tension: &'a [f64],
}

/// Checks one command message given as parallel arrays, sizes first (name count, name lengths,
/// total bytes: no other work is done on an oversized message), then array lengths, names,
/// duplicates and every value against its actuator's limits. Fills `out` (cleared first) with the
/// per-actuator commands in message order; on error `out` holds nothing usable. Allocation-free
/// for valid messages once `out` has capacity for the model's actuators.
pub fn check_command(
    model: &Model,
    frame_id: &str,
    names: &[String],
    values: CommandArrays<'_>,
    out: &mut Vec<(ActuatorId, control::ActuatorCommand)>,
) -> Result<(), MessageError> {
    out.clear();
    let CommandArrays { rest_length, rate, tension } = values;
    for (what, size) in [
        ("name count", names.len()),
        ("rest_length count", rest_length.len()),
        ("rate count", rate.len()),
        ("tension count", tension.len()),
    ] {
        if size > MAX_COMMAND_ENTRIES {
            return Err(MessageError::TooLarge { what, size, limit: MAX_COMMAND_ENTRIES });
        }
    }
    let bytes = frame_id.len()
        + names.iter().map(String::len).sum::<usize>()
        + 8 * (rest_length.len() + rate.len() + tension.len());
    if bytes > MAX_COMMAND_BYTES {
        return Err(MessageError::TooLarge {
            what: "message size in bytes",
            size: bytes,
            limit: MAX_COMMAND_BYTES,
        });
    }
    if frame_id.len() > MAX_NAME_BYTES {
        return Err(MessageError::TooLarge {
            what: "frame_id length in bytes",
            size: frame_id.len(),
            limit: MAX_NAME_BYTES,
        });
    }
    if let Some(n) = names.iter().find(|n| n.len() > MAX_NAME_BYTES) {
        return Err(MessageError::TooLarge {
            what: "an actuator name's length in bytes",
            size: n.len(),
            limit: MAX_NAME_BYTES,
        });
    }
    for (field, v) in [("rest_length", rest_length), ("rate", rate), ("tension", tension)] {
        if !v.is_empty() && v.len() != names.len() {
            return Err(MessageError::WrongLength { field, got: v.len(), names: names.len() });
        }
    }
    if names.is_empty() {
        return Err(MessageError::NoNames);
    }
    for (i, name) in names.iter().enumerate() {
        let id = actuator_by_name(model, name)?;
        let cmd = control::ActuatorCommand {
            rest_length: rest_length.get(i).copied(),
            rate: rate.get(i).copied(),
            tension: tension.get(i).copied(),
        };
        check_entry(model, id, cmd, out)?;
    }
    Ok(())
}

/// The actuator called `name`, or the error every transport gives for an unknown name.
pub fn actuator_by_name(model: &Model, name: &str) -> Result<ActuatorId, MessageError> {
    model
        .actuator_id(name)
        .ok_or_else(|| control::CommandError::UnknownActuator(excerpt(name, EXCERPT_CHARS)).into())
}

/// Checks one entry of a command message whose actuator is already resolved, the same way for
/// every transport: a second entry for an actuator already in `out` is refused (which should win
/// is ambiguous), then the values against the actuator's limits (`Control::validate`); a good
/// entry is appended to `out`.
pub fn check_entry(
    model: &Model,
    id: ActuatorId,
    cmd: control::ActuatorCommand,
    out: &mut Vec<(ActuatorId, control::ActuatorCommand)>,
) -> Result<(), MessageError> {
    if out.iter().any(|(seen, _)| *seen == id) {
        return Err(MessageError::Duplicate(model.actuator_names[id.0].clone()));
    }
    control::Control::validate(model, id, cmd)?;
    out.push((id, cmd));
    Ok(())
}

impl ActuatorCommand {
    /// The per-actuator commands of this message, validated against `model` as a whole (a
    /// message with one bad entry is refused entirely, so that no partial update happens); see
    /// `check_command` for the order of the checks.
    pub fn commands(&self, model: &Model) -> Result<Vec<(String, control::ActuatorCommand)>, MessageError> {
        let mut out = Vec::new();
        let values = CommandArrays { rest_length: &self.rest_length, rate: &self.rate, tension: &[] };
        check_command(model, &self.header.frame_id, &self.name, values, &mut out)?;
        Ok(out.into_iter().map(|(id, c)| (model.actuator_names[id.0].clone(), c)).collect())
    }
}

impl AppliedCommands {
    /// The commands again, resolved against `model` (NaN: not given; an empty `tension`, as in
    /// bags written before tension commands, gives none); why not, when a name is unknown or the
    /// arrays are not parallel.
    pub fn commands(
        &self,
        model: &Model,
    ) -> Result<Vec<(ActuatorId, control::ActuatorCommand)>, MessageError> {
        let n = self.name.len();
        // an empty tension array is an old bag's: no tensions
        let tension = if self.tension.is_empty() { n } else { self.tension.len() };
        for (field, got) in
            [("rest_length", self.rest_length.len()), ("rate", self.rate.len()), ("tension", tension)]
        {
            if got != n {
                return Err(MessageError::WrongLength { field, got, names: n });
            }
        }
        let given = |x: f64| (!x.is_nan()).then_some(x);
        (0..n)
            .map(|i| {
                let id = actuator_by_name(model, &self.name[i])?;
                Ok((
                    id,
                    control::ActuatorCommand {
                        rest_length: given(self.rest_length[i]),
                        rate: given(self.rate[i]),
                        tension: self.tension.get(i).copied().and_then(given),
                    },
                ))
            })
            .collect()
    }
}
