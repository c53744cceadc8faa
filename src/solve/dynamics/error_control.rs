//! What generalized-alpha's error estimate reads: the jerk envelope of three accelerations, the
//! hold on it, and the relief for errors that go into the cables' damped modes (their decay rate
//! under the cables' damping).

use nalgebra::DVector;

use crate::evaluate::{kinetic_energy, Workspace};
use crate::forces::cable::{length_gradient_dot, route_geometry};
use crate::model::{CableId, Model};

use crate::solve::dynamics::system::TOLERANCE_TIME;

/// The envelope of a jerk from three accelerations, m/s^3 (or rad/s^3), at the middle sample:
/// `sqrt(j^2 + max(0, -a s - |a| s_noise))`, with
/// - `a = a_now`;
/// - `j = (a_next - a_prev) / (h_prev + h)`, the central difference;
/// - `s = 2 ((a_next - a_now) / h - (a_now - a_prev) / h_prev) / (h_prev + h)`, the second
///   difference (the snap);
/// - `s_noise = 4 noise / (h_prev h)`, what an acceleration noise of `noise` makes of `s`.
///
/// The Teager-Kaiser energy operator `j^2 - a s` is `A^2 w^6` for an oscillation `A sin(w t)`
/// whatever its phase, where the jerk alone, `A w^3 cos(w t)`, passes through zero twice a cycle.
/// An error estimate from the jerk alone takes long steps where the jerk is small and short ones
/// where it peaks, while the oscillation's phase error grows the same through the cycle: on the
/// elastic Atwood machine at a tolerance of 1e-6 m that took 1.39 times the sub-steps of the
/// fixed step of equal error, the envelope 0.95 times (tests/integrators.rs). For a motion that
/// is not an oscillation `-a s` may be negative: the envelope is never below `|j|`. The noise
/// term keeps the product of a large acceleration and a noisy snap (Newton's tolerance, the
/// joints' tolerance, over `h^2`) from shrinking the steps at tight tolerances.
///
/// Preconditions: `h_prev > 0`, `h > 0`, `noise >= 0`.
pub fn jerk_envelope(a_prev: f64, a_now: f64, a_next: f64, h_prev: f64, h: f64, noise: f64) -> f64 {
    let jerk = (a_next - a_prev) / (h_prev + h);
    let snap = 2.0 * ((a_next - a_now) / h - (a_now - a_prev) / h_prev) / (h_prev + h);
    let snap_noise = 4.0 * noise / (h_prev * h);
    (jerk * jerk + (-a_now * snap - a_now.abs() * snap_noise).max(0.0)).sqrt()
}

/// The fraction of the largest jerk envelope of the recent steps that generalized-alpha's
/// error estimate keeps after each accepted step: the estimate uses
/// `max(envelope now, held)`, `held` decaying by this factor per step, so the step may grow by at
/// most `ENVELOPE_HOLD^(-1/3)` (7.7 %) a step while the held value dominates. A slower decay
/// (0.95) refused fewer attempts on prism3 (157) but slowed the growth of loose-tolerance runs
/// after a transient: the free prism at 1e-3 m took 182 sub-steps instead of 101.
///
/// `jerk_envelope` is exact for one oscillation. For a ringing mode on top of a larger, slower
/// acceleration (a structure that rings while it deploys) the product `-a s` carries the cross
/// term of the two, which changes sign once per cycle of the ring: there the envelope falls to
/// the bare jerk, which passes through zero. Without the hold the estimate dropped to a few
/// percent of the tolerance for about ten steps, the step grew fivefold and was refused with 4
/// to 100 times the tolerance, again and again: on prism3 at 1e-6 m, 965 of 7573 attempts were
/// refused; with the hold 251 of 6717, and the same error (tests/integrators.rs).
pub const ENVELOPE_HOLD: f64 = 0.8;

/// How much more error generalized-alpha's estimate lets a step make when the error goes into
/// the cables' damped modes: errors there die out within a few `1/sigma` instead of adding up
/// over `TOLERANCE_TIME`. A structure rings after an actuator starts or stops, with jerks 40-50
/// times those of its slow deployment, decaying at about 28/s on prism3; giving those steps the
/// slow phase's share took 1.18 (1e-4 m) and 1.12 (1e-6 m) times the sub-steps of the fixed step
/// of equal error, where the fixed step's larger errors in the ring died out with it
/// (tests/integrators.rs).
pub const DECAY_RELIEF: f64 = 1.0;

/// A jerk whose decay rate is at least this fraction of the largest seen counts as wholly in the
/// damped modes (`damped_mode_relief`): a structure's damped modes decay at somewhat different
/// rates, and at 1.0 the estimate's relief, `1 / sqrt(1 - f)` at most, stays near 3-4 in a pure
/// ring (prism3 took 1.08 times the fixed step's sub-steps at 1e-6 m).
pub const DAMPED_SHARE_SPREAD: f64 = 0.9;

/// Decay rate of the motion along the jerk `j` under the cables' damping, 1/s: that of one damped
/// oscillator with the jerk's Rayleigh quotients
/// - `sigma_c = j^T C j / (2 j^T M j)`, with `j^T C j = sum_k c_k (dL_k/dq j)^2`,
/// - `w^2 = j^T K j / j^T M j`, with the cables' material stiffness
///   `j^T K j = sum_k (EA_k / L0_k) (dL_k/dq j)^2`,
///
/// over the taut cables (`c_k` in N s/m, `j^T M j` twice `kinetic_energy(j)`): `sigma_c` when the
/// oscillator is underdamped (`sigma_c <= w`; `zeta w` for one damped mode), the slower root
/// `sigma_c - sqrt(sigma_c^2 - w^2)` when it is overdamped (about `w / (2 zeta)`: a heavily
/// damped structure creeps back, and its errors with it: prism3 at damping ratio 2 and 1e-6 m
/// lands at 2.37 times the tolerance with 6 % fewer attempts than without any relief (1.57);
/// with `sigma_c` alone at 2.67 with 3 % fewer). Motion that stretches no cable (a mechanism, a
/// rigid body's drift, a pendulum) gives 0, as does `j = 0`.
///
/// Preconditions: `ws` holds the evaluation of the state `j` belongs to (its points' positions and
/// Jacobians, its cables' rest lengths and slack flags; its route scratch is overwritten);
/// `j.len() == model.dof_count`.
pub fn jerk_decay_rate(model: &Model, ws: &mut Workspace, j: &DVector<f64>) -> f64 {
    let inertia = 2.0 * kinetic_energy(model, j);
    if inertia <= 0.0 {
        return 0.0;
    }
    let (mut damping, mut stiffness) = (0.0, 0.0);
    for (c, cable) in model.cables.iter().enumerate() {
        let response = &ws.cables[c];
        if cable.damping == 0.0 || response.slack {
            continue;
        }
        let k = cable.axial_stiffness / response.rest_length;
        let route = model.route(CableId(c));
        route_geometry(route, &ws.points, &mut ws.scratch);
        let stretch = length_gradient_dot(model, route, &ws.points, &ws.scratch, j);
        damping += cable.damping * stretch * stretch;
        stiffness += k * stretch * stretch;
    }
    let sigma = damping / (2.0 * inertia);
    let w2 = stiffness / inertia;
    if sigma * sigma <= w2 {
        sigma
    } else {
        // the slower root, written without the cancellation of sigma - sqrt(sigma^2 - w^2)
        w2 / (sigma + (sigma * sigma - w2).sqrt())
    }
}

/// The factor on a generalized-alpha step's share of the tolerance for a jerk of decay rate
/// `rate` (`jerk_decay_rate`) when the largest seen is `largest` (both 1/s):
/// `1 / sqrt((1 - f) + f / R^2)`, with
/// - `f = min(1, rate / (DAMPED_SHARE_SPREAD largest))`, the share of the jerk (and so of the
///   step's error) in the damped modes: 0 for a mechanism's motion, 1 in a pure ring;
/// - `R = max(1, DECAY_RELIEF largest TOLERANCE_TIME)`: errors that die out within
///   `1 / largest` may be `R` times those that add up over `TOLERANCE_TIME`.
///
/// Errors of the two shares add in squares. The factor is 1 for an undamped structure and for a
/// jerk that stretches no cable, `R` at most. The Rayleigh quotient is a mean over the modes the
/// jerk holds: a slow motion with a ring on top gets a share in between, and the slow motion's
/// error, which does not die out, keeps most of its weight (`1 - f`).
///
/// Preconditions: `0 <= rate <= largest`.
pub fn damped_mode_relief(rate: f64, largest: f64) -> f64 {
    if largest <= 0.0 {
        return 1.0;
    }
    let share = (rate / (DAMPED_SHARE_SPREAD * largest)).clamp(0.0, 1.0);
    let ratio = (DECAY_RELIEF * largest * TOLERANCE_TIME).max(1.0);
    1.0 / ((1.0 - share) + share / (ratio * ratio)).sqrt()
}
