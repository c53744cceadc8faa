//! The explicit Runge-Kutta methods' data: takes nothing, gives their tableaus (`RK4`, `DOPRI5`),
//! stability radii, the share of the tolerance Dormand-Prince aims each step at, and the stage
//! buffers a step fills (`EmbeddedState`, `ExplicitBuffers`), preallocated once per model.

use nalgebra::{DVector, Quaternion, UnitQuaternion, Vector3, Vector4};

use crate::model::{Model, Pose};
use crate::state::State;

/// Dormand-Prince aims each step's local error at this share of the tolerance: the local errors
/// of a run add up to a few times each one's (measured on the bundled scenes: at the full
/// tolerance the runs' largest point error reached 4.4 times it).
pub const LOCAL_TOLERANCE_SHARE: f64 = 1.0 / 3.0;

/// Below this tolerance (m) Dormand-Prince's local tolerance also shrinks like
/// `(tol / TIGHT_TOLERANCE)^TIGHT_EXPONENT` (`local_tolerance`).
pub const TIGHT_TOLERANCE: f64 = 1e-6;

/// See `TIGHT_TOLERANCE`.
pub const TIGHT_EXPONENT: f64 = 0.2;

/// The local error Dormand-Prince aims each step at for a requested tolerance `tol` (m):
/// `LOCAL_TOLERANCE_SHARE tol min(1, (tol / TIGHT_TOLERANCE)^TIGHT_EXPONENT)`. The local errors
/// of a run add up to a few times each one's; below about 1e-6 m the runs' largest point error
/// also grew faster than the tolerance fell (2.3, 3.3 and 6.6 times it at 1e-7, 1e-8 and 1e-9 m
/// on prism3), so tight tolerances are transformed the way implicit codes transform theirs
/// (RADAU5 aims at `0.1 tol^(2/3)`). Measured on prism3 (`bench work-precision`) at 1e-7, 1e-8
/// and 1e-9 m: exponent 0.1 left the largest error at 2.0, 2.8 and 3.7 times the tolerance,
/// 0.15 at 1.8, 2.5 and 2.9, 0.2 at 1.2, 2.1 and 2.1 (with 7 %, 12 % and 21 % more steps than
/// no transformation); 0.2 keeps a margin under 3x.
pub fn local_tolerance(tol: f64) -> f64 {
    LOCAL_TOLERANCE_SHARE * tol * (tol / TIGHT_TOLERANCE).powf(TIGHT_EXPONENT).min(1.0)
}

/// Radius of the left half-disk in the classical Runge-Kutta method's stability region.
pub const RK4_STABILITY_RADIUS: f64 = 2.615;

/// Radius of the left half-disk in the Dormand-Prince 5(4) method's stability region.
pub const DOPRI5_STABILITY_RADIUS: f64 = 0.997;

/// An explicit Runge-Kutta tableau: `c`, `a` (lower triangle, row by row), the propagated
/// weights `b` and, for an embedded pair, the error weights `e = b - b_hat`.
pub struct Tableau {
    /// Stage times as fractions of the step.
    pub c: &'static [f64],
    /// `a[i]` holds the `i` coefficients of stage `i`.
    pub a: &'static [&'static [f64]],
    /// Weights of the propagated solution.
    pub b: &'static [f64],
    /// `b - b_hat` (the embedded solution's weights), when the method estimates its error.
    pub error: Option<&'static [f64]>,
    /// Order of the propagated solution.
    pub order: u32,
    /// The last stage is evaluated at the propagated solution (first same as last).
    pub fsal: bool,
}

/// The classical 4th-order Runge-Kutta method.
pub const RK4: Tableau = Tableau {
    c: &[0.0, 0.5, 0.5, 1.0],
    a: &[&[], &[0.5], &[0.0, 0.5], &[0.0, 0.0, 1.0]],
    b: &[1.0 / 6.0, 1.0 / 3.0, 1.0 / 3.0, 1.0 / 6.0],
    error: None,
    order: 4,
    fsal: false,
};

/// The Dormand-Prince 5(4) pair (Dormand & Prince 1980; Hairer, Norsett & Wanner, table II.5.2).
pub const DOPRI5: Tableau = Tableau {
    c: &[0.0, 1.0 / 5.0, 3.0 / 10.0, 4.0 / 5.0, 8.0 / 9.0, 1.0, 1.0],
    a: &[
        &[],
        &[1.0 / 5.0],
        &[3.0 / 40.0, 9.0 / 40.0],
        &[44.0 / 45.0, -56.0 / 15.0, 32.0 / 9.0],
        &[19372.0 / 6561.0, -25360.0 / 2187.0, 64448.0 / 6561.0, -212.0 / 729.0],
        &[9017.0 / 3168.0, -355.0 / 33.0, 46732.0 / 5247.0, 49.0 / 176.0, -5103.0 / 18656.0],
        &[35.0 / 384.0, 0.0, 500.0 / 1113.0, 125.0 / 192.0, -2187.0 / 6784.0, 11.0 / 84.0],
    ],
    b: &[35.0 / 384.0, 0.0, 500.0 / 1113.0, 125.0 / 192.0, -2187.0 / 6784.0, 11.0 / 84.0, 0.0],
    error: Some(&[
        71.0 / 57600.0,
        0.0,
        -71.0 / 16695.0,
        71.0 / 1920.0,
        -17253.0 / 339200.0,
        22.0 / 525.0,
        -1.0 / 40.0,
    ]),
    order: 5,
    fsal: true,
};

/// A point of the embedded state space: positions, quaternion coordinates, velocities (or their
/// rates, for a stage derivative).
#[derive(Debug, Clone)]
pub(super) struct EmbeddedState {
    pub(super) positions: Vec<Vector3<f64>>,
    pub(super) rotations: Vec<Vector4<f64>>,
    pub(super) velocities: DVector<f64>,
}

impl EmbeddedState {
    pub(super) fn new(model: &Model) -> Self {
        Self {
            positions: vec![Vector3::zeros(); model.bodies.len()],
            rotations: vec![Vector4::zeros(); model.bodies.len()],
            velocities: DVector::zeros(model.dof_count),
        }
    }

    pub(super) fn load(&mut self, state: &State) {
        for (b, pose) in state.poses.iter().enumerate() {
            self.positions[b] = pose.position;
            self.rotations[b] = pose.rotation.quaternion().coords;
        }
        self.velocities.copy_from(&state.velocities);
    }

    /// `self = base + h sum_j weights_j k_j`.
    pub(super) fn combine(&mut self, base: &EmbeddedState, h: f64, weights: &[f64], k: &[EmbeddedState]) {
        self.positions.copy_from_slice(&base.positions);
        self.rotations.copy_from_slice(&base.rotations);
        self.velocities.copy_from(&base.velocities);
        for (&w, k) in weights.iter().zip(k) {
            if w == 0.0 {
                continue;
            }
            let w = h * w;
            for (p, d) in self.positions.iter_mut().zip(&k.positions) {
                *p += d * w;
            }
            for (q, d) in self.rotations.iter_mut().zip(&k.rotations) {
                *q += d * w;
            }
            self.velocities.axpy(w, &k.velocities, 1.0);
        }
    }

    /// Poses (quaternions normalized) and velocities into `state`.
    pub(super) fn store(&self, state: &mut State) {
        for (b, pose) in state.poses.iter_mut().enumerate() {
            *pose = Pose {
                position: self.positions[b],
                rotation: UnitQuaternion::new_normalize(Quaternion::from(self.rotations[b])),
            };
        }
        state.velocities.copy_from(&self.velocities);
    }
}

/// Stage buffers of the explicit integrators, sized once per model.
#[derive(Debug, Clone)]
pub(super) struct ExplicitBuffers {
    pub(super) start: EmbeddedState,
    pub(super) stage: EmbeddedState,
    /// Stage derivatives `k_1 .. k_7`.
    pub(super) k: Vec<EmbeddedState>,
    /// `k_last` of the previous step at the state it committed, valid for first-same-as-last.
    pub(super) fsal_valid: bool,
    /// Right-hand side and solution of `Dynamics::solve_mass_and_joints`.
    pub(super) work: DVector<f64>,
}

impl ExplicitBuffers {
    pub(super) fn new(model: &Model, size: usize) -> Self {
        Self {
            start: EmbeddedState::new(model),
            stage: EmbeddedState::new(model),
            k: (0..7).map(|_| EmbeddedState::new(model)).collect(),
            fsal_valid: false,
            work: DVector::zeros(size),
        }
    }

    /// Forget the first-same-as-last stage (the state was changed from outside).
    pub(super) fn invalidate(&mut self) {
        self.fsal_valid = false;
    }
}

/// The local error of one explicit step, m: the largest of the embedded pair's position
/// differences (rotations times the body's reach) and its velocity differences times the step.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) struct ExplicitStep {
    pub(super) error: Option<f64>,
    pub(super) evaluations: usize,
}
