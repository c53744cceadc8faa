//! The shared-memory payloads: fixed-size `#[repr(C)]` types (state, structure, commands,
//! lockstep request and answer) that the Python client (`python/tensegrity/testing/shm.py`)
//! mirrors with `ctypes`, how names are written into them, and how a command sample is checked
//! (exactly like a DDS command, `io::commands`).

use std::mem::MaybeUninit;

use iceoryx2::prelude::*;

use crate::control::ActuatorCommand;
use crate::io::commands;
use crate::io::commands::MessageError;
use crate::model::{ActuatorId, Model};

/// Most bodies a scene may have on this transport.
pub const MAX_BODIES: usize = 256;
/// Most cables a scene may have on this transport.
pub const MAX_CABLES: usize = 1024;
/// Most actuators a scene may have on this transport (and entries in one command).
pub const MAX_ACTUATORS: usize = 256;
/// Most pulleys (interior route points, over all cables) a scene may have on this transport.
pub const MAX_PULLEYS: usize = 1024;
/// Most contacts (ground pairs and strut pairs, `Model::contact_pairs`) a scene may have on this
/// transport.
pub const MAX_CONTACTS: usize = 512;
/// Bytes of a name field (UTF-8, NUL-terminated, so names have at most `NAME_BYTES - 1` bytes).
pub const NAME_BYTES: usize = 64;
/// Bytes of the message of a lockstep answer (UTF-8, NUL-terminated).
pub const MESSAGE_BYTES: usize = 256;
/// Most controllers (ports of other processes) on one service at a time.
pub const MAX_CONTROLLERS: usize = 16;
/// State samples a controller's subscriber keeps (the oldest is overwritten: a slow reader never
/// holds the node up).
pub const STATE_BUFFER: usize = 4;
/// Command samples the node's subscriber keeps (the oldest is overwritten in a flood).
pub const COMMAND_BUFFER: usize = 64;
/// `CommandEntry::actuator` value meaning "by name".
pub const BY_NAME: u32 = u32::MAX;
/// `CommandEntry::fields` bit: `rest_length` is given.
pub const FIELD_REST_LENGTH: u32 = 1;
/// `CommandEntry::fields` bit: `rate` is given.
pub const FIELD_RATE: u32 = 2;
/// `CommandEntry::fields` bit: `tension` is given (alone; a winch actuator's tension mode).
pub const FIELD_TENSION: u32 = 4;

/// The whole state after a step, in scene order (see `StructureSample` for the names). Only the
/// first `body_count`, `cable_count` and `actuator_count` entries of the arrays are meaningful;
/// the rest are zero.
#[derive(Debug, Clone, ZeroCopySend)]
#[repr(C)]
#[type_name("TensegrityState")]
pub struct StateSample {
    /// Simulation time, s.
    pub time: f64,
    /// Steps taken since the start or the last reset.
    pub step: u64,
    /// Wall-clock time this sample was written, ns since the Unix epoch (CLOCK_REALTIME; Python:
    /// `time.time_ns()`).
    pub published_ns: u64,
    /// Wall-clock time at which the newest commands (from any transport) took effect, the step
    /// boundary before the step they first act in, ns since the Unix epoch; 0 before the first.
    pub commands_applied_ns: u64,
    /// Command messages received from every transport (`= accepted + rejected`).
    pub commands_received: u64,
    /// Command messages accepted.
    pub commands_accepted: u64,
    /// Command messages rejected (each one whole).
    pub commands_rejected: u64,
    /// Steps that ended later than real-time pacing allowed.
    pub overruns: u64,
    /// Bodies in use.
    pub body_count: u32,
    /// Cables in use.
    pub cable_count: u32,
    /// Actuators in use.
    pub actuator_count: u32,
    /// `simulation_interfaces` state: 1 playing, 2 paused.
    pub simulation_state: u8,
    /// 1 while a physics failure holds the simulation paused (until reset).
    pub faulted: u8,
    /// Zero.
    pub reserved: [u8; 2],
    /// Body centres of mass, m, world frame.
    pub body_position: [[f64; 3]; MAX_BODIES],
    /// Body orientations, unit quaternions `[x, y, z, w]` (body to world, ROS order).
    pub body_orientation: [[f64; 4]; MAX_BODIES],
    /// Cable tensions, N.
    pub cable_tension: [f64; MAX_CABLES],
    /// Cable lengths (whole route), m.
    pub cable_length: [f64; MAX_CABLES],
    /// Cable rest lengths, m.
    pub cable_rest_length: [f64; MAX_CABLES],
    /// Actuator (winch) rest lengths, m: the rest length of the cable each drives.
    pub actuator_rest_length: [f64; MAX_ACTUATORS],
    /// Actuator rest-length rates over the last step, m/s.
    pub actuator_rate: [f64; MAX_ACTUATORS],
    /// Cable slack flags: 1 when the cable is not taut.
    pub cable_slack: [u8; MAX_CABLES],
    /// Pulleys of all cables, in cable then route order (`segment_count - 1` per cable).
    pub pulley_count: u32,
    /// Zero (keeps the arrays after it 8-byte aligned).
    pub pulley_reserved: u32,
    /// Per pulley with friction: its slip speed over the last step, m/s, positive toward the
    /// cable's last anchor (0 for a frictionless pulley).
    pub pulley_slip_speed: [f64; MAX_PULLEYS],
    /// Per pulley: tension after it over tension before it (0 when either side is slack; 1 on a
    /// taut frictionless cable).
    pub pulley_tension_ratio: [f64; MAX_PULLEYS],
    /// Per pulley: 1 while a pulley with friction holds the cable.
    pub pulley_sticks: [u8; MAX_PULLEYS],
}

/// Names and array order of the structure, published once (history 1) so late joiners get it.
#[derive(Debug, Clone, ZeroCopySend)]
#[repr(C)]
#[type_name("TensegrityStructure")]
pub struct StructureSample {
    /// The node's step (`physics_dt`), s.
    pub physics_dt: f64,
    /// Bodies in use.
    pub body_count: u32,
    /// Cables in use.
    pub cable_count: u32,
    /// Actuators in use.
    pub actuator_count: u32,
    /// Contacts in use (ground pairs, then strut pairs); 0 for a scene without contact, which
    /// has no `contacts` service.
    pub contact_count: u32,
    /// Scene name.
    pub scene_name: [u8; NAME_BYTES],
    /// Fixed frame of the poses.
    pub frame_id: [u8; NAME_BYTES],
    /// Body names, in `StateSample` order.
    pub body_names: [[u8; NAME_BYTES]; MAX_BODIES],
    /// Cable names, in `StateSample` order.
    pub cable_names: [[u8; NAME_BYTES]; MAX_CABLES],
    /// Actuator names, in `StateSample` order (and the indices `CommandEntry::actuator` takes).
    pub actuator_names: [[u8; NAME_BYTES]; MAX_ACTUATORS],
    /// The cable each actuator drives (index into the cable arrays).
    pub actuator_cable: [u32; MAX_ACTUATORS],
    /// Smallest rest length each actuator accepts, m.
    pub actuator_min_rest_length: [f64; MAX_ACTUATORS],
    /// Largest rest length each actuator accepts, m.
    pub actuator_max_rest_length: [f64; MAX_ACTUATORS],
    /// Largest rate each actuator accepts, m/s.
    pub actuator_max_rate: [f64; MAX_ACTUATORS],
    /// Each contact's first name, in `ContactsSample` order: a contact sphere's centre point
    /// (`body.point`, or `body` for a node), or a strut pair's first bar.
    pub contact_point: [[u8; NAME_BYTES]; MAX_CONTACTS],
    /// Each contact's second name: the ground, or a strut pair's second bar.
    pub contact_with: [[u8; NAME_BYTES]; MAX_CONTACTS],
}

/// Every contact after a step (`report::ContactReport`'s numbers), on `<prefix>/contacts`, a
/// service only scenes with contacts have. The node publishes it with every state sample and
/// before every lockstep answer, so the newest one a controller holds after an answer is that
/// answer's step. Only the first `contact_count` entries are meaningful.
#[derive(Debug, Clone, ZeroCopySend)]
#[repr(C)]
#[type_name("TensegrityContacts")]
pub struct ContactsSample {
    /// Simulation time, s.
    pub time: f64,
    /// Steps taken since the start or the last reset (as `StateSample::step`).
    pub step: u64,
    /// Contacts in use.
    pub contact_count: u32,
    /// Zero.
    pub reserved: u32,
    /// Signed distance of the surfaces, m (negative: pressed in).
    pub gap: [f64; MAX_CONTACTS],
    /// Normal force, N (>= 0).
    pub normal_force: [f64; MAX_CONTACTS],
    /// Slip speed of the contact point, m/s.
    pub slip_speed: [f64; MAX_CONTACTS],
    /// Contact point, m, world frame.
    pub position: [[f64; 3]; MAX_CONTACTS],
    /// Unit normal: the ground's outward one (a strut pair's, from the second bar to the first).
    pub normal: [[f64; 3]; MAX_CONTACTS],
    /// Friction force on the body (a strut pair's first bar), N, world frame.
    pub friction: [[f64; 3]; MAX_CONTACTS],
    /// 1 while pressed in.
    pub in_contact: [u8; MAX_CONTACTS],
}

/// What the scene's sensors report after a step (`crate::sensors`; scenes with `[sensors]`
/// only), published with every state sample and before every lockstep answer, like the
/// contacts: the state sample keeps the exact values. Only the channels whose bit is set in
/// `channels` are filled, and only the first `body_count`, `cable_count` and `actuator_count`
/// entries of their arrays.
#[derive(Debug, Clone, ZeroCopySend)]
#[repr(C)]
#[type_name("TensegrityMeasured")]
pub struct MeasuredSample {
    /// Simulation time, s.
    pub time: f64,
    /// Steps taken since the start or the last reset (as `StateSample::step`).
    pub step: u64,
    /// The declared channels: `MEASURED_TENSION` | `MEASURED_LENGTH` | `MEASURED_REST_LENGTH` |
    /// `MEASURED_POSITION` | `MEASURED_ORIENTATION` | `MEASURED_GYRO` | `MEASURED_ACCELEROMETER`.
    pub channels: u32,
    /// Bodies in use.
    pub body_count: u32,
    /// Cables in use.
    pub cable_count: u32,
    /// Actuators in use.
    pub actuator_count: u32,
    /// Measured body positions, m, world frame.
    pub body_position: [[f64; 3]; MAX_BODIES],
    /// Measured body orientations, unit quaternions `[x, y, z, w]` (ROS order).
    pub body_orientation: [[f64; 4]; MAX_BODIES],
    /// Measured cable tensions, N.
    pub cable_tension: [f64; MAX_CABLES],
    /// Measured cable lengths, m.
    pub cable_length: [f64; MAX_CABLES],
    /// Measured actuator rest lengths (the winches' encoders), m.
    pub actuator_rest_length: [f64; MAX_ACTUATORS],
    /// Measured angular velocities (gyro), rad/s, body axes.
    pub body_angular_velocity: [[f64; 3]; MAX_BODIES],
    /// Measured specific forces (accelerometer), `R^T (a - g)`, m/s^2, body axes.
    pub body_specific_force: [[f64; 3]; MAX_BODIES],
    /// The true angular velocities, rad/s, body axes (with a gyro or an accelerometer; the
    /// state sample has no accelerations, so the truth of both IMU channels travels here).
    pub true_angular_velocity: [[f64; 3]; MAX_BODIES],
    /// The true specific forces, m/s^2, body axes (with a gyro or an accelerometer).
    pub true_specific_force: [[f64; 3]; MAX_BODIES],
    /// Per value of `body_position`: 1 when it is held because its last update was lost (a
    /// dropout; `crate::sensors::Sensors::lost`), else 0. The same for the arrays below.
    pub body_position_lost: [[u8; 3]; MAX_BODIES],
    /// Per body: 1 when its orientation is held after a lost update (its four values go
    /// together).
    pub body_orientation_lost: [u8; MAX_BODIES],
    /// Per cable: its tension is held after a lost update.
    pub cable_tension_lost: [u8; MAX_CABLES],
    /// Per cable: its length is held after a lost update.
    pub cable_length_lost: [u8; MAX_CABLES],
    /// Per actuator: its rest length is held after a lost update.
    pub actuator_rest_length_lost: [u8; MAX_ACTUATORS],
    /// Per value of `body_angular_velocity`: held after a lost update.
    pub body_angular_velocity_lost: [[u8; 3]; MAX_BODIES],
    /// Per value of `body_specific_force`: held after a lost update.
    pub body_specific_force_lost: [[u8; 3]; MAX_BODIES],
}

/// `MeasuredSample::channels` bit: tensions.
pub const MEASURED_TENSION: u32 = 1;
/// `MeasuredSample::channels` bit: lengths.
pub const MEASURED_LENGTH: u32 = 2;
/// `MeasuredSample::channels` bit: actuator rest lengths.
pub const MEASURED_REST_LENGTH: u32 = 4;
/// `MeasuredSample::channels` bit: body positions.
pub const MEASURED_POSITION: u32 = 8;
/// `MeasuredSample::channels` bit: body orientations.
pub const MEASURED_ORIENTATION: u32 = 16;
/// `MeasuredSample::channels` bit: angular velocities (gyro).
pub const MEASURED_GYRO: u32 = 32;
/// `MeasuredSample::channels` bit: specific forces (accelerometer).
pub const MEASURED_ACCELEROMETER: u32 = 64;

/// One actuator command: a target rest length (reached at the given or the actuator's largest
/// rate), a rate alone (the winch runs at it until told otherwise), or a tension alone (a winch
/// motor holds its line force at it).
#[derive(Debug, Clone, Copy, ZeroCopySend)]
#[repr(C)]
#[type_name("TensegrityCommandEntry")]
pub struct CommandEntry {
    /// Actuator index (structure order), or `BY_NAME` to use `name`.
    pub actuator: u32,
    /// Which values are given: `FIELD_REST_LENGTH` | `FIELD_RATE`, or `FIELD_TENSION` alone.
    pub fields: u32,
    /// Target rest length, m (when `FIELD_REST_LENGTH`).
    pub rest_length: f64,
    /// Rate, m/s (when `FIELD_RATE`): with a target, the speed towards it (positive); alone, the
    /// signed rate of change.
    pub rate: f64,
    /// Tension, N (when `FIELD_TENSION`): within `[0, stall tension]` of the actuator's winch.
    pub tension: f64,
    /// Actuator name, UTF-8, NUL-terminated (when `actuator == BY_NAME`).
    pub name: [u8; NAME_BYTES],
}

impl CommandEntry {
    /// An entry for actuator `index` with nothing given yet.
    pub fn index(index: usize) -> Self {
        Self {
            actuator: index as u32,
            fields: 0,
            rest_length: 0.0,
            rate: 0.0,
            tension: 0.0,
            name: [0; NAME_BYTES],
        }
    }
    /// An entry for the actuator called `name` (cut to `NAME_BYTES - 1` bytes) with nothing given
    /// yet.
    pub fn named(name: &str) -> Self {
        let mut e = Self::index(0);
        e.actuator = BY_NAME;
        write_name(&mut e.name, name);
        e
    }
    /// With a target rest length, m.
    pub fn rest_length(mut self, rest_length: f64) -> Self {
        self.fields |= FIELD_REST_LENGTH;
        self.rest_length = rest_length;
        self
    }
    /// With a rate, m/s.
    pub fn rate(mut self, rate: f64) -> Self {
        self.fields |= FIELD_RATE;
        self.rate = rate;
        self
    }
    /// With a tension, N (alone: the actuator's winch motor holds it).
    pub fn tension(mut self, tension: f64) -> Self {
        self.fields |= FIELD_TENSION;
        self.tension = tension;
        self
    }
}

/// A command message: the first `count` entries, applied together at the next step boundary or
/// rejected together.
#[derive(Debug, Clone, ZeroCopySend)]
#[repr(C)]
#[type_name("TensegrityCommand")]
pub struct CommandSample {
    /// Entries in use.
    pub count: u32,
    /// Zero.
    pub reserved: u32,
    /// The entries.
    pub entries: [CommandEntry; MAX_ACTUATORS],
}

/// Lockstep: apply `command` (if `command.count > 0`), take `steps` steps, answer the state.
#[derive(Debug, Clone, ZeroCopySend)]
#[repr(C)]
#[type_name("TensegrityLockstepRequest")]
pub struct LockstepRequest {
    /// Steps to take (0: only check and queue the command, answer the current state).
    pub steps: u64,
    /// `LOCKSTEP_RESET` | `LOCKSTEP_SEEDED`: reset first (as the reset service does), its episode
    /// drawn from `seed` (`NodeCore::reset_seeded`).
    pub flags: u32,
    /// Zero.
    pub reserved: u32,
    /// The reset episode's seed (with `LOCKSTEP_SEEDED`): the scene's randomization and the
    /// sensors' streams.
    pub seed: u64,
    /// Commands applied at the boundary before the first step (after the reset).
    pub command: CommandSample,
}

/// `LockstepRequest::flags` bit: reset before the command and the steps.
pub const LOCKSTEP_RESET: u32 = 1;
/// `LockstepRequest::flags` bit (with `LOCKSTEP_RESET`): draw the episode from `seed`.
pub const LOCKSTEP_SEEDED: u32 = 2;

/// The answer to a `LockstepRequest`.
#[derive(Debug, Clone, ZeroCopySend)]
#[repr(C)]
#[type_name("TensegrityLockstepResponse")]
pub struct LockstepResponse {
    /// `simulation_interfaces` result code: 1 OK, 3 incorrect state (not paused, or busy), 4
    /// failed (command rejected, physics failure, reset, shutdown).
    pub result: u8,
    /// Zero.
    pub reserved: [u8; 7],
    /// Steps taken for this request.
    pub steps_taken: u64,
    /// Why it failed (UTF-8, NUL-terminated); empty on success.
    pub message: [u8; MESSAGE_BYTES],
    /// The state after the steps taken.
    pub state: StateSample,
}

/// Writes `text` into a NUL-terminated fixed field, cut at a character boundary to fit.
pub fn write_name(field: &mut [u8], text: &str) {
    field.fill(0);
    let mut end = text.len().min(field.len().saturating_sub(1));
    while !text.is_char_boundary(end) {
        end -= 1;
    }
    field[..end].copy_from_slice(&text.as_bytes()[..end]);
}

/// The text of a NUL-terminated fixed field, or why it is not text.
pub fn read_name(field: &[u8]) -> Result<&str, MessageError> {
    let end = field.iter().position(|b| *b == 0).ok_or_else(|| {
        MessageError::Malformed(format!("a name field has no terminating NUL within {} bytes", field.len()))
    })?;
    std::str::from_utf8(&field[..end])
        .map_err(|_| MessageError::Malformed("a name field is not UTF-8".into()))
}

/// Checks one command message (`count` entries) against `model` exactly like a DDS command:
/// sizes, then each entry's actuator (index in range, or a known name), duplicates and values
/// (`commands::check_entry`). Fills `out` on success.
pub fn check_command(
    model: &Model,
    cmd: &CommandSample,
    out: &mut Vec<(ActuatorId, ActuatorCommand)>,
) -> Result<(), MessageError> {
    let count = cmd.count as usize;
    if count > MAX_ACTUATORS {
        return Err(MessageError::TooLarge { what: "entry count", size: count, limit: MAX_ACTUATORS });
    }
    if count == 0 {
        return Err(MessageError::NoNames);
    }
    for e in &cmd.entries[..count] {
        let id = if e.actuator == BY_NAME {
            commands::actuator_by_name(model, read_name(&e.name)?)?
        } else if (e.actuator as usize) < model.actuators.len() {
            ActuatorId(e.actuator as usize)
        } else {
            return Err(MessageError::UnknownIndex {
                index: e.actuator.into(),
                count: model.actuators.len(),
            });
        };
        if e.fields & !(FIELD_REST_LENGTH | FIELD_RATE | FIELD_TENSION) != 0 {
            return Err(MessageError::Malformed(format!("unknown bits in fields: {:#x}", e.fields)));
        }
        let given = |bit: u32, v: f64| (e.fields & bit != 0).then_some(v);
        let c = ActuatorCommand {
            rest_length: given(FIELD_REST_LENGTH, e.rest_length),
            rate: given(FIELD_RATE, e.rate),
            tension: given(FIELD_TENSION, e.tension),
        };
        commands::check_entry(model, id, c, out)?;
    }
    Ok(())
}

/// Payloads for which all-zero bytes are a valid value (integers, floats and arrays of them, no
/// references, enums or `bool`s), so `zeroed` may initialize them in place.
///
/// # Safety
/// Implement only for such types.
#[allow(unsafe_code)]
pub unsafe trait ZeroValid {}
// SAFETY (all six): `#[repr(C)]` structs of u8, u32, u64, f64 and arrays of them (CommandEntry too)
#[allow(unsafe_code)]
unsafe impl ZeroValid for StateSample {}
#[allow(unsafe_code)]
unsafe impl ZeroValid for StructureSample {}
#[allow(unsafe_code)]
unsafe impl ZeroValid for ContactsSample {}
#[allow(unsafe_code)]
unsafe impl ZeroValid for MeasuredSample {}
#[allow(unsafe_code)]
unsafe impl ZeroValid for CommandSample {}
#[allow(unsafe_code)]
unsafe impl ZeroValid for LockstepRequest {}
#[allow(unsafe_code)]
unsafe impl ZeroValid for LockstepResponse {}

/// Zeroes a loaned payload in place (no copy through the stack) and returns it initialized.
#[allow(unsafe_code)]
pub fn zeroed<T: ZeroValid>(slot: &mut MaybeUninit<T>) -> &mut T {
    // SAFETY: all-zero bytes are a valid `T` (`ZeroValid`), and the pointer is the slot's own
    unsafe {
        std::ptr::write_bytes(slot.as_mut_ptr(), 0, 1);
        slot.assume_init_mut()
    }
}
