//! What changes during a run (`State`): time, body poses, local velocities, cable rest lengths and
//! joint reaction multipliers; plus `retract`, the group update that moves poses along local
//! coordinate increments (see `crate::model` for the coordinates).

use nalgebra::{DVector, UnitQuaternion, Vector3};

use crate::forces::contact::ContactAnchor;
use crate::model::{Model, Pose};

/// Everything that changes during a run. Built from a `Model` with `State::initial`
/// (`Default` is the empty state of a model with nothing in it: a placeholder that allocates
/// nothing).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct State {
    /// Simulation time, s.
    pub time: f64,
    /// Body poses, parallel to `Model::bodies`.
    pub poses: Vec<Pose>,
    /// Generalized velocities in local coordinates (m/s and rad/s, body-frame rotations).
    pub velocities: DVector<f64>,
    /// Current rest length of every cable, m (> 0).
    pub rest_lengths: Vec<f64>,
    /// Joint reaction multipliers (N), one per constraint row: the force that holds the joint.
    pub multipliers: DVector<f64>,
    /// Rest length of every segment of the cables with pulley friction, m
    /// (`PulleyFriction::segment_offset`; empty without friction): the material on each side of
    /// a pulley at the last accepted step, from which the next step's sticking and slipping
    /// start.
    pub segment_rest_lengths: Vec<f64>,
    /// Every winch motor's state, parallel to `Model::winches` (empty without).
    pub winches: Vec<WinchState>,
    /// Where every ground pair's contact is anchored, parallel to `Model::contact_pair_list`,
    /// when some ground has stick-slip friction (`Model::has_stick_friction`; empty without):
    /// from it the next step's sticking and slipping start.
    pub contact_anchors: Vec<ContactAnchor>,
}

impl State {
    /// The state at t = 0: initial poses, at rest, initial rest lengths, zero reactions.
    pub fn initial(model: &Model) -> Self {
        let poses: Vec<Pose> = model.bodies.iter().map(|b| b.initial_pose).collect();
        let contact_anchors = crate::forces::contact::initial_anchors(model, &poses);
        Self {
            time: 0.0,
            poses,
            velocities: DVector::zeros(model.dof_count),
            rest_lengths: model.initial_rest_lengths.clone(),
            multipliers: DVector::zeros(model.constraint_count),
            segment_rest_lengths: model.initial_segment_rest_lengths.clone(),
            winches: model
                .winches
                .iter()
                .map(|w| WinchState {
                    reference: model.initial_rest_lengths[w.cable.0],
                    ..Default::default()
                })
                .collect(),
            contact_anchors,
        }
    }

    /// Copies `other` into `self` in place (same model: equal sizes), without allocating.
    pub fn copy_from(&mut self, other: &State) {
        self.time = other.time;
        self.poses.copy_from_slice(&other.poses);
        self.velocities.copy_from(&other.velocities);
        self.rest_lengths.copy_from_slice(&other.rest_lengths);
        self.multipliers.copy_from(&other.multipliers);
        self.segment_rest_lengths.copy_from_slice(&other.segment_rest_lengths);
        self.winches.copy_from_slice(&other.winches);
        self.contact_anchors.copy_from_slice(&other.contact_anchors);
    }

    /// True if every number in the state is finite.
    pub fn is_finite(&self) -> bool {
        self.time.is_finite()
            && self.velocities.iter().all(|v| v.is_finite())
            && self.multipliers.iter().all(|v| v.is_finite())
            && self.rest_lengths.iter().all(|v| v.is_finite())
            && self.segment_rest_lengths.iter().all(|v| v.is_finite())
            && self.winches.iter().all(|w| w.speed.is_finite() && w.integral.is_finite())
            && self
                .contact_anchors
                .iter()
                .all(|a| a.lever.iter().chain(a.anchor.iter()).all(|v| v.is_finite()))
            && self.poses.iter().all(|p| {
                p.position.iter().all(|v| v.is_finite()) && p.rotation.coords.iter().all(|v| v.is_finite())
            })
    }
}

/// Moves every pose by `scale * dq` in local coordinates:
/// `x <- x + B_t dq_b`, `R <- R exp([B_r dq_b]x)` for each body `b`.
///
/// `dq` has `model.dof_count` entries. The exponential map is exact, so rotations stay unit.
pub fn retract(model: &Model, poses: &mut [Pose], dq: &DVector<f64>, scale: f64) {
    for (body, pose) in model.bodies.iter().zip(poses.iter_mut()) {
        if body.dof_count == 0 {
            continue;
        }
        let incr = body.local_increment(dq.as_slice(), scale);
        pose.position += Vector3::new(incr[0], incr[1], incr[2]);
        let theta = Vector3::new(incr[3], incr[4], incr[5]);
        if theta.norm_squared() > 0.0 {
            pose.rotation *= UnitQuaternion::from_scaled_axis(theta);
            pose.rotation.renormalize();
        }
    }
}

/// A winch's state: what it carries from sub-step to sub-step (`speed`, `integral`, `setpoint`,
/// `reference`) and what the sub-step under way holds fixed (`drive`, `step`, `floor`, set by
/// `crate::forces::winch::prepare`).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct WinchState {
    /// Reel-in speed `v = r omega` at the last accepted sub-step, m/s.
    pub speed: f64,
    /// Integral of the position error, m s.
    pub integral: f64,
    /// Speed set-point of the last accepted sub-step, m/s (what `max_acceleration` limits).
    pub setpoint: f64,
    /// Rest-length reference at the last accepted sub-step, m (position mode).
    pub reference: f64,
    /// Drive `u` in `[-1, 1]` over the sub-step under way.
    pub drive: f64,
    /// Length of the sub-step under way, s; 0 between sub-steps, when the cable keeps its rest
    /// length (statics, outputs).
    pub step: f64,
    /// Lowest speed the gear allows over the sub-step under way, m/s (`-inf` when back-drivable).
    pub floor: f64,
    /// What `crate::forces::winch::prepare` computed for the sub-step under way, kept for `commit`: the set-point, the
    /// reference and the position error.
    pub pending: [f64; 3],
}
