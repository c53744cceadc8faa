//! Sensor models: takes the scene's `[sensors]` (`SensorModel`, constant) and, after every step,
//! the true state and its evaluation; gives what a robot's sensors would report
//! (`Sensors::readings`): cable tensions, cable lengths, actuated cables' rest lengths (the
//! winches' encoders), body positions and orientations, each with Gaussian noise, a bias,
//! quantization, a delay in steps, an update rate (held between updates) and dropouts (a lost
//! update holds the last value), drawn from a seeded generator so that the same seed gives the
//! same streams to the bit. The physics never reads them: the truth stays the state.
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
    /// The last `delay + 1` held vectors, oldest first, as one ring of `delay + 1` rows.
    ring: Vec<f64>,
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
    /// The sensors of `model` with `seed` (the scene's when `None`), before any update.
    pub fn new(model: &Model, seed: Option<u64>) -> Self {
        let seed = seed.unwrap_or(model.sensors.seed);
        let channels = model
            .sensors
            .channels
            .iter()
            .map(|&(kind, m)| {
                let n = kind.len(model);
                let index = SensorKind::ALL.iter().position(|k| *k == kind).unwrap_or(0) as u64;
                Channel {
                    kind,
                    model: m,
                    rng: Pcg64::seed_from_u64(seed ^ (index + 1).wrapping_mul(0x9E37_79B9_7F4A_7C15)),
                    held: vec![0.0; n],
                    ring: vec![0.0; n * (m.delay + 1)],
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
        Self { channels, measured: vec![0.0; total] }
    }

    /// What every declared channel reports now, concatenated (`layout`); empty without sensors.
    pub fn measured(&self) -> &[f64] {
        &self.measured
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
        for ch in &mut self.channels {
            let first = ch.updates == 0;
            truth(model, state, ws, ch.kind, &mut ch.truth);
            let due = ch.updates == 0 || state.time + 1e-9 * ch.model.period.max(1e-12) >= ch.next_update;
            ch.fresh = due;
            if due {
                ch.updates += 1;
                ch.next_update = if ch.updates == 1 { state.time } else { ch.next_update } + ch.model.period;
                ch.measure();
            }
            let n = ch.held.len();
            let rows = ch.model.delay + 1;
            if first {
                // the delay line starts full of the first measurement
                for r in 0..rows {
                    ch.ring[r * n..(r + 1) * n].copy_from_slice(&ch.held);
                }
                ch.head = 0;
            } else {
                ch.ring[ch.head * n..(ch.head + 1) * n].copy_from_slice(&ch.held);
                ch.head = (ch.head + 1) % rows;
            }
        }
        let mut start = 0;
        for ch in &self.channels {
            let n = ch.held.len();
            self.measured[start..start + n].copy_from_slice(&ch.ring[ch.head * n..(ch.head + 1) * n]);
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
            for (q, t) in self.held.chunks_exact_mut(4).zip(self.truth.chunks_exact(4)) {
                let noise: [f64; 3] = std::array::from_fn(|_| self.rng.sample::<f64, _>(StandardNormal));
                let lost = m.dropout > 0.0 && self.rng.random::<f64>() < m.dropout;
                if lost && self.updates > 1 {
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
        for (h, x) in self.held.iter_mut().zip(&self.truth) {
            let n: f64 = self.rng.sample(StandardNormal);
            let lost = m.dropout > 0.0 && self.rng.random::<f64>() < m.dropout;
            // the first update has nothing to hold: it is never lost
            if lost && self.updates > 1 {
                self.dropped += 1;
                continue;
            }
            let y = x + m.bias + m.sigma * n;
            *h = if m.resolution > 0.0 { m.resolution * (y / m.resolution).round() } else { y };
        }
    }
}

/// The true values of channel `kind` at `state` (evaluated into `ws`) into `out`.
fn truth(model: &Model, state: &State, ws: &Workspace, kind: SensorKind, out: &mut [f64]) {
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
    }
}

/// CSV column names of every declared channel's values, in `Sensors::measured` order:
/// `{cable}_tension_measured_N`, `{cable}_length_measured_m`, `{actuator}_rest_length_measured_m`,
/// `{body}_{x|y|z}_measured_m`, `{body}_{qw|qx|qy|qz}_measured`.
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
        }
    }
    cols
}
