//! Sensor models: takes the scene's `[sensors]` (`SensorModel`, constant) and, after every step,
//! the true state and its evaluation; gives what a robot's sensors would report
//! (`Sensors::readings`): cable tensions, cable lengths, actuated cables' rest lengths (the
//! winches' encoders), body positions and orientations, and an IMU on every body (a gyro: the
//! angular velocity in body axes; an accelerometer: the specific force `R^T (a - g)` in body axes,
//! `a` the mean acceleration over the last step), each with Gaussian noise, a bias,
//! quantization, a delay (in seconds, whole physics steps), an update rate (held between
//! updates) and dropouts (a lost update holds the last value, marked in `Sensors::lost`),
//! drawn from a seeded generator so that the same seed gives the same streams to the bit. The physics never reads them: the truth stays the state.
//!
//! Per channel and update, in this order for each value `x_i`: a standard normal `n_i`, then,
//! with a dropout probability, a uniform `d_i`; the value `q(x_i + bias + sigma n_i)` with
//! `q(y) = resolution round(y / resolution)` replaces the held one unless `d_i < dropout`. The
//! generator is PCG64 (`rand_pcg::Pcg64`), one per channel, seeded from the scene's seed and the
//! channel, so that declaring one channel does not change another's stream.

use nalgebra::{UnitQuaternion, Vector3};
use rand::{RngExt, SeedableRng};
use rand_distr::StandardNormal;
use rand_pcg::Pcg64;

use crate::evaluate::Workspace;
pub use crate::model::{ChannelModel, SensorKind, SensorModel};

use crate::model::Model;
use crate::state::State;

/// One channel's state: its generator, the held values, the delay line.
#[derive(Debug, Clone)]
struct Channel {
    kind: SensorKind,
    model: ChannelModel,
    rng: Pcg64,
    /// The last update's values (held until the next).
    held: Vec<f64>,
    /// Per value: true while `held` holds a value whose last update was lost (a dropout),
    /// until an update measures it again.
    held_lost: Vec<bool>,
    /// The delay in whole steps (`Delay::steps` at the physics step).
    delay_steps: usize,
    /// The last `delay_steps + 1` held vectors, as one ring of `delay_steps + 1` rows.
    ring: Vec<f64>,
    /// `held_lost` of the same rows.
    lost_ring: Vec<bool>,
    /// Row of `ring` the next report writes.
    head: usize,
    /// Time of the next update, s.
    next_update: f64,
    /// Updates taken (dropped values included).
    updates: u64,
    /// Values lost to dropout.
    dropped: u64,
    /// Whether the last `update` took a new measurement.
    fresh: bool,
    /// Scratch of the true values.
    truth: Vec<f64>,
}

/// Every declared channel's state (`Sensors::new`), updated after every step.
#[derive(Debug, Clone)]
pub struct Sensors {
    channels: Vec<Channel>,
    /// What every channel reports now, concatenated in `SensorKind::ALL` order (`layout`).
    measured: Vec<f64>,
    /// Per value of `measured`: whether it is held after a lost update (`Sensors::lost`).
    lost: Vec<bool>,
    /// The true IMU values now, `[gyro x y z, specific force x y z]` per body, where the scene
    /// declares a gyro or an accelerometer (empty otherwise).
    imu: Vec<f64>,
    /// Each body's world velocity at the last update, m/s (3 per body; with `imu`), and that
    /// update's time (`None` before the first).
    previous_velocity: Vec<f64>,
    previous_time: Option<f64>,
}

/// Whether `model`'s sensors include an IMU channel (gyro or accelerometer).
pub fn has_imu(model: &Model) -> bool {
    model.sensors.channels.iter().any(|(k, _)| matches!(k, SensorKind::Gyro | SensorKind::Accelerometer))
}

/// Where each declared channel's values sit in a concatenation of all of them
/// (`Sensors::measured`), in `SensorKind::ALL` order: `(kind, start, len)`.
pub fn layout(model: &Model) -> impl Iterator<Item = (SensorKind, usize, usize)> + '_ {
    let mut start = 0;
    model.sensors.channels.iter().map(move |(kind, _)| {
        let n = kind.len(model);
        start += n;
        (*kind, start - n, n)
    })
}

/// Channel `kind`'s values in `measured` (a `Sensors::measured` of `model`), `None` when the
/// scene does not declare it or `measured` is empty.
pub fn reading<'a>(model: &Model, measured: &'a [f64], kind: SensorKind) -> Option<&'a [f64]> {
    if measured.is_empty() {
        return None;
    }
    layout(model).find(|(k, _, _)| *k == kind).map(|(_, start, n)| &measured[start..start + n])
}

impl Sensors {
    /// The sensors of `model` with `seed` (the scene's when `None`), before any update, updated
    /// once per physics step of `dt` (s, > 0: the delays in whole steps).
    pub fn new(model: &Model, seed: Option<u64>, dt: f64) -> Self {
        let seed = seed.unwrap_or(model.sensors.seed);
        let channels = model
            .sensors
            .channels
            .iter()
            .map(|&(kind, m)| {
                let n = kind.len(model);
                let delay_steps = m.delay.steps(dt);
                let index = SensorKind::ALL.iter().position(|k| *k == kind).unwrap_or(0) as u64;
                Channel {
                    kind,
                    model: m,
                    rng: Pcg64::seed_from_u64(seed ^ (index + 1).wrapping_mul(0x9E37_79B9_7F4A_7C15)),
                    held: vec![0.0; n],
                    held_lost: vec![false; n],
                    delay_steps,
                    ring: vec![0.0; n * (delay_steps + 1)],
                    lost_ring: vec![false; n * (delay_steps + 1)],
                    head: 0,
                    next_update: 0.0,
                    updates: 0,
                    dropped: 0,
                    fresh: false,
                    truth: vec![0.0; n],
                }
            })
            .collect();
        let total = layout(model).map(|(_, _, n)| n).sum();
        let bodies = if has_imu(model) { model.bodies.len() } else { 0 };
        Self {
            channels,
            measured: vec![0.0; total],
            lost: vec![false; total],
            imu: vec![0.0; 6 * bodies],
            previous_velocity: vec![0.0; 3 * bodies],
            previous_time: None,
        }
    }

    /// The true IMU values at the last update, `[gyro x y z (rad/s), specific force x y z
    /// (m/s^2)]` per body in body axes; empty unless the scene declares a gyro or an
    /// accelerometer.
    pub fn imu_truth(&self) -> &[f64] {
        &self.imu
    }

    /// The true IMU values of `state` into `imu`: each body's angular velocity in its axes and
    /// `R^T (a - g)`, `a` the change of its centre's velocity since the last update over the time
    /// between (0 at the first update, or when time did not advance).
    fn update_imu(&mut self, model: &Model, state: &State) {
        let elapsed = self.previous_time.map(|t0| state.time - t0).filter(|dt| *dt > 0.0);
        for (b, body) in model.bodies.iter().enumerate() {
            let twist = body.local_increment(state.velocities.as_slice(), 1.0);
            let v = Vector3::new(twist[0], twist[1], twist[2]);
            let previous = Vector3::from_column_slice(&self.previous_velocity[3 * b..3 * b + 3]);
            let a = elapsed.map_or(Vector3::zeros(), |dt| (v - previous) / dt);
            let f = state.poses[b].rotation.inverse_transform_vector(&(a - model.gravity));
            self.imu[6 * b..6 * b + 3].copy_from_slice(&[twist[3], twist[4], twist[5]]);
            self.imu[6 * b + 3..6 * b + 6].copy_from_slice(f.as_slice());
            self.previous_velocity[3 * b..3 * b + 3].copy_from_slice(v.as_slice());
        }
        self.previous_time = Some(state.time);
    }

    /// What every declared channel reports now, concatenated (`layout`); empty without sensors.
    pub fn measured(&self) -> &[f64] {
        &self.measured
    }

    /// Per value of `measured`, in its order: `true` when the value reported is held because
    /// its last update was lost (a dropout): a real driver would have published nothing. It
    /// stays `true` until an update measures that value again, and travels through the delay
    /// with the value. An orientation's four values are lost together. Empty without sensors.
    pub fn lost(&self) -> &[bool] {
        &self.lost
    }

    /// True when the scene declares no channel.
    pub fn is_empty(&self) -> bool {
        self.channels.is_empty()
    }

    /// Measures `state` (evaluated into `ws`): each channel whose update is due draws a new
    /// measurement (`ChannelModel`), the others hold; then each reports the value of `delay`
    /// updates ago (until then, the first). Call once at the start and once after every step;
    /// allocates nothing.
    pub fn update(&mut self, model: &Model, state: &State, ws: &Workspace) {
        if !self.imu.is_empty() {
            self.update_imu(model, state);
        }
        for ch in &mut self.channels {
            let first = ch.updates == 0;
            truth(model, state, ws, &self.imu, ch.kind, &mut ch.truth);
            let due = ch.updates == 0 || state.time + 1e-9 * ch.model.period.max(1e-12) >= ch.next_update;
            ch.fresh = due;
            if due {
                ch.updates += 1;
                ch.next_update = if ch.updates == 1 { state.time } else { ch.next_update } + ch.model.period;
                ch.measure();
            }
            let n = ch.held.len();
            let rows = ch.delay_steps + 1;
            if first {
                // the delay line starts full of the first measurement
                for r in 0..rows {
                    ch.ring[r * n..(r + 1) * n].copy_from_slice(&ch.held);
                    ch.lost_ring[r * n..(r + 1) * n].copy_from_slice(&ch.held_lost);
                }
                ch.head = 0;
            } else {
                ch.ring[ch.head * n..(ch.head + 1) * n].copy_from_slice(&ch.held);
                ch.lost_ring[ch.head * n..(ch.head + 1) * n].copy_from_slice(&ch.held_lost);
                ch.head = (ch.head + 1) % rows;
            }
        }
        let mut start = 0;
        for ch in &self.channels {
            let n = ch.held.len();
            let row = ch.head * n..(ch.head + 1) * n;
            self.measured[start..start + n].copy_from_slice(&ch.ring[row.clone()]);
            self.lost[start..start + n].copy_from_slice(&ch.lost_ring[row]);
            start += n;
        }
    }

    /// What channel `kind` reports now (`None` when the scene does not declare it): the held
    /// measurement of `delay` updates ago.
    pub fn readings(&self, kind: SensorKind) -> Option<&[f64]> {
        // `head` is the next row to write: after the first update it points one past the
        // newest row, and the oldest row (delay updates back) sits right at it; `update` copies
        // that row into `measured`
        let ch = self.channels.iter().position(|c| c.kind == kind)?;
        let start: usize = self.channels[..ch].iter().map(|c| c.held.len()).sum();
        Some(&self.measured[start..start + self.channels[ch].held.len()])
    }

    /// Whether channel `kind` took a new measurement at the last update (`false` if undeclared).
    pub fn is_fresh(&self, kind: SensorKind) -> bool {
        self.channels.iter().any(|c| c.kind == kind && c.fresh)
    }

    /// Values lost to dropout on channel `kind` so far.
    pub fn dropped(&self, kind: SensorKind) -> u64 {
        self.channels.iter().filter(|c| c.kind == kind).map(|c| c.dropped).sum()
    }

    /// Updates channel `kind` has taken so far.
    pub fn updates(&self, kind: SensorKind) -> u64 {
        self.channels.iter().filter(|c| c.kind == kind).map(|c| c.updates).sum()
    }
}

impl Channel {
    /// One update: a new measurement of `truth` into `held`, value by value (module docs).
    fn measure(&mut self) {
        let m = self.model;
        if self.kind == SensorKind::Orientation {
            let quaternions = self.held.chunks_exact_mut(4).zip(self.held_lost.chunks_exact_mut(4));
            for ((q, q_lost), t) in quaternions.zip(self.truth.chunks_exact(4)) {
                let noise: [f64; 3] = std::array::from_fn(|_| self.rng.sample::<f64, _>(StandardNormal));
                let lost = m.dropout > 0.0 && self.rng.random::<f64>() < m.dropout;
                let lost = lost && self.updates > 1;
                q_lost.fill(lost);
                if lost {
                    self.dropped += 1;
                    continue;
                }
                let truth =
                    UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(t[0], t[1], t[2], t[3]));
                let measured = truth * UnitQuaternion::from_scaled_axis(Vector3::from(noise) * m.sigma);
                q.copy_from_slice(&[measured.w, measured.i, measured.j, measured.k]);
            }
            return;
        }
        for ((h, h_lost), x) in self.held.iter_mut().zip(&mut self.held_lost).zip(&self.truth) {
            let n: f64 = self.rng.sample(StandardNormal);
            let lost = m.dropout > 0.0 && self.rng.random::<f64>() < m.dropout;
            // the first update has nothing to hold: it is never lost
            *h_lost = lost && self.updates > 1;
            if *h_lost {
                self.dropped += 1;
                continue;
            }
            let y = x + m.bias + m.sigma * n;
            *h = if m.resolution > 0.0 { m.resolution * (y / m.resolution).round() } else { y };
        }
    }
}

/// The true values of channel `kind` at `state` (evaluated into `ws`; `imu` the true IMU values,
/// `Sensors::imu_truth`) into `out`.
fn truth(model: &Model, state: &State, ws: &Workspace, imu: &[f64], kind: SensorKind, out: &mut [f64]) {
    match kind {
        SensorKind::Tension => {
            for (o, c) in out.iter_mut().zip(&ws.cables) {
                *o = c.tension;
            }
        }
        SensorKind::Length => {
            for (o, c) in out.iter_mut().zip(&ws.cables) {
                *o = c.length;
            }
        }
        SensorKind::RestLength => {
            for (o, a) in out.iter_mut().zip(&model.actuators) {
                *o = state.rest_lengths[a.cable.0];
            }
        }
        SensorKind::Position => {
            for (o, p) in out.chunks_exact_mut(3).zip(&state.poses) {
                o.copy_from_slice(p.position.as_slice());
            }
        }
        SensorKind::Orientation => {
            for (o, p) in out.chunks_exact_mut(4).zip(&state.poses) {
                let q = p.rotation;
                o.copy_from_slice(&[q.w, q.i, q.j, q.k]);
            }
        }
        SensorKind::Gyro | SensorKind::Accelerometer => {
            let skip = if kind == SensorKind::Gyro { 0 } else { 3 };
            for (o, body) in out.chunks_exact_mut(3).zip(imu.chunks_exact(6)) {
                o.copy_from_slice(&body[skip..skip + 3]);
            }
        }
    }
}

/// CSV column names of the true IMU values (`Sensors::imu_truth`), where the scene declares a
/// gyro or an accelerometer: `{body}_{wx|wy|wz}_rad_s` and `{body}_{fx|fy|fz}_m_s2` per body.
pub fn imu_truth_csv_columns(model: &Model) -> Vec<String> {
    if !has_imu(model) {
        return Vec::new();
    }
    let mut cols = Vec::new();
    for b in &model.bodies {
        cols.extend(["wx", "wy", "wz"].map(|w| format!("{}_{w}_rad_s", b.name)));
        cols.extend(["fx", "fy", "fz"].map(|f| format!("{}_{f}_m_s2", b.name)));
    }
    cols
}

/// CSV column names of the lost flags (`Sensors::lost`) of every declared channel, in
/// `Sensors::measured` order, one per value but one per body for an orientation:
/// `{cable}_tension_lost`, `{cable}_length_lost`, `{actuator}_rest_length_lost`,
/// `{body}_{x|y|z}_lost`, `{body}_orientation_lost`, `{body}_{wx|wy|wz}_lost`,
/// `{body}_{fx|fy|fz}_lost`; their cells are `1` for a value held after a lost update, else `0`
/// (`lost_csv_flags`).
pub fn lost_csv_columns(model: &Model) -> Vec<String> {
    let mut cols = Vec::new();
    let per_body = |cols: &mut Vec<String>, axes: [&str; 3]| {
        for b in &model.bodies {
            cols.extend(axes.map(|ax| format!("{}_{ax}_lost", b.name)));
        }
    };
    for (kind, _, _) in layout(model) {
        match kind {
            SensorKind::Tension => cols.extend(model.cable_names.iter().map(|c| format!("{c}_tension_lost"))),
            SensorKind::Length => cols.extend(model.cable_names.iter().map(|c| format!("{c}_length_lost"))),
            SensorKind::RestLength => {
                cols.extend(model.actuator_names.iter().map(|a| format!("{a}_rest_length_lost")))
            }
            SensorKind::Position => per_body(&mut cols, ["x", "y", "z"]),
            SensorKind::Orientation => {
                cols.extend(model.bodies.iter().map(|b| format!("{}_orientation_lost", b.name)))
            }
            SensorKind::Gyro => per_body(&mut cols, ["wx", "wy", "wz"]),
            SensorKind::Accelerometer => per_body(&mut cols, ["fx", "fy", "fz"]),
        }
    }
    cols
}

/// The flags of `lost_csv_columns` from `lost` (`Sensors::lost` of `model`), one per column.
pub fn lost_csv_flags<'a>(model: &'a Model, lost: &'a [bool]) -> impl Iterator<Item = bool> + 'a {
    layout(model).flat_map(move |(kind, start, n)| {
        let step = if kind == SensorKind::Orientation { 4 } else { 1 };
        lost[start..start + n].iter().step_by(step).copied()
    })
}

/// CSV column names of every declared channel's values, in `Sensors::measured` order:
/// `{cable}_tension_measured_N`, `{cable}_length_measured_m`, `{actuator}_rest_length_measured_m`,
/// `{body}_{x|y|z}_measured_m`, `{body}_{qw|qx|qy|qz}_measured`, `{body}_{wx|wy|wz}_measured_rad_s`,
/// `{body}_{fx|fy|fz}_measured_m_s2`.
pub fn csv_columns(model: &Model) -> Vec<String> {
    let mut cols = Vec::new();
    for (kind, _, _) in layout(model) {
        match kind {
            SensorKind::Tension => {
                cols.extend(model.cable_names.iter().map(|c| format!("{c}_tension_measured_N")))
            }
            SensorKind::Length => {
                cols.extend(model.cable_names.iter().map(|c| format!("{c}_length_measured_m")))
            }
            SensorKind::RestLength => {
                cols.extend(model.actuator_names.iter().map(|a| format!("{a}_rest_length_measured_m")))
            }
            SensorKind::Position => {
                for b in &model.bodies {
                    cols.extend(["x", "y", "z"].map(|ax| format!("{}_{ax}_measured_m", b.name)));
                }
            }
            SensorKind::Orientation => {
                for b in &model.bodies {
                    cols.extend(["qw", "qx", "qy", "qz"].map(|q| format!("{}_{q}_measured", b.name)));
                }
            }
            SensorKind::Gyro => {
                for b in &model.bodies {
                    cols.extend(["wx", "wy", "wz"].map(|w| format!("{}_{w}_measured_rad_s", b.name)));
                }
            }
            SensorKind::Accelerometer => {
                for b in &model.bodies {
                    cols.extend(["fx", "fy", "fz"].map(|f| format!("{}_{f}_measured_m_s2", b.name)));
                }
            }
        }
    }
    cols
}
