//! Step-size control's constants and rules: takes an output interval and a tolerance, gives the
//! smallest controlled sub-step, the first one, the growth rule of an implicit integrator and the
//! caps of an explicit one.

/// An implicit integrator under error control grows its step only when the error estimate
/// allows this factor or more (every new step size costs it a factorization).
pub const GROWTH_THRESHOLD: f64 = 1.2;

/// The smallest sub-step error control takes, as a fraction of the output interval, down to
/// tolerances of `TIGHT_CONTROLLED_TOLERANCE`; a sub-step this small is accepted whatever its
/// error estimate (and counted, `StepStats::forced`). See `smallest_controlled_step`.
pub const MIN_CONTROLLED_STEP: f64 = 1e-5;

/// Below this tolerance (m) the smallest controlled sub-step shrinks with the tolerance
/// (`smallest_controlled_step`).
pub const TIGHT_CONTROLLED_TOLERANCE: f64 = 1e-8;

/// The smallest sub-step error control takes for output interval `dt` (s) and `tolerance` (m):
/// `MIN_CONTROLLED_STEP dt`, times `tol / TIGHT_CONTROLLED_TOLERANCE` below that tolerance. The
/// floor keeps a jump of the acceleration (a cable going slack) from shrinking the step without
/// end; a kink's local error falls with the step, so a tighter tolerance needs a lower floor:
/// a block bouncing on a stiff ground (tests/contact.rs) at 1e-9 m with 10 ms outputs sat at a
/// 1e-7 s floor through each impact for 51857 forced sub-steps and delivered 357 times the
/// tolerance; at 1e-8 s it is never forced.
pub fn smallest_controlled_step(dt: f64, tolerance: Option<f64>) -> f64 {
    let tight = tolerance.map_or(1.0, |t| (t / TIGHT_CONTROLLED_TOLERANCE).min(1.0));
    dt * MIN_CONTROLLED_STEP * tight
}

/// The first sub-step of an error-controlled run, as a fraction of the output interval. Small,
/// because the first step's estimate has one difference of accelerations and no envelope
/// (`dynamics::jerk_envelope`): a structure released from rest has no jerk yet, and a first
/// step of the whole interval was accepted where the next ones were not (on the elastic Atwood
/// machine at 1e-6 m that first step's error set the run's). Growth by up to 5 times a sub-step
/// reaches the size the estimate proposes in a few sub-steps.
pub const INITIAL_STEP_FRACTION: f64 = 1.0 / 256.0;

/// The largest whole fraction `dt / k` of the output interval that is at most `h` (s).
pub(super) fn quantized(dt: f64, h: f64) -> f64 {
    dt / (dt / h * (1.0 - 1e-12)).ceil().max(1.0)
}

/// Dormand-Prince's local errors add up over a run in proportion to its number of steps: a run
/// whose steps are held below this (s) by its stability limit (`EXPLICIT_STEP_CAP`) makes each
/// step's error smaller in proportion, `tol h_mean / EXPLICIT_ERROR_STEP`, so that it delivers
/// what the tolerance asks of runs at this step. The bundled scenes' runs step above it from
/// 1e-3 down to 1e-8 m (prism3 at 1e-8 m: 3.3e-3 s); the nodal prism's members hold its steps
/// at 6.2e-4 s, where without this its error reached 3.3 times the tolerance at 1e-8 m.
pub const EXPLICIT_ERROR_STEP: f64 = 2e-3;

/// An explicit integrator under error control takes sub-steps of at most this fraction of its
/// stability limit at the start (`crate::solve::dynamics::stability_region_limit`): the margin
/// covers the limit's drift as the structure moves.
pub const EXPLICIT_STEP_CAP: f64 = 0.9;
