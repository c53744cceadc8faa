//! Time integration: takes a `Model`, a `State` with its accelerations, and a step size; gives the
//! state one step later, or `None` when the step failed (Newton did not converge, or a non-finite
//! number appeared) so that the caller can retry with a smaller step. The state is only written on
//! success.
//!
//! Equations of motion in local coordinates (see `crate::model`):
//! `M vdot + w x (J w) + Phi_q^T lambda = Q(q, v, t)`, `Phi(q) = 0`, with `M` the constant
//! block-diagonal body mass matrix and `w x (J w)` the gyroscopic torque of rigid bodies.
//!
//! **Generalized-alpha** (Chung & Hulbert 1993; Lie-group form of Bruls, Cardona & Arnold 2012,
//! constraints at position level as in Arnold & Bruls 2007). With spectral radius at infinity
//! `rho` in [0, 1]: `alpha_m = (2 rho - 1)/(rho + 1)`, `alpha_f = rho/(rho + 1)`,
//! `gamma = 1/2 + alpha_f - alpha_m`, `beta = (gamma + 1/2)^2 / 4`; the pseudo-acceleration `a`
//! obeys `(1 - alpha_m) a_(n+1) + alpha_m a_n = (1 - alpha_f) vdot_(n+1) + alpha_f vdot_n`,
//! `q_(n+1) = q_n exp(h v_n + h^2 (1/2 - beta) a_n + h^2 beta a_(n+1))`,
//! `v_(n+1) = v_n + h (1 - gamma) a_n + h gamma a_(n+1)`, and the equations hold at `t_(n+1)`.
//! Newton on the increment `delta` uses the analytic tangent
//! `S = M beta' + (C + C_gyro) gamma' + K + H_lambda`, `beta' = (1 - alpha_m)/(h^2 beta (1 - alpha_f))`,
//! `gamma' = gamma/(h beta)` (the exponential map's tangent operator is taken as identity, which
//! costs Newton a little speed, never accuracy), with the constraint rows scaled by `beta'`.
//! Second order, A-stable, `rho = 1` has no numerical dissipation, `rho = 0` annihilates the
//! highest frequencies in one step.
//!
//! Modified Newton: the factors of the Newton matrix are kept across iterations and steps while
//! they contract the residual by at least `1 / REFACTOR_CONTRACTION` per iteration; on the sparse
//! backend they are the `LDL^T` of the matrix's symmetric part, replaced by the exact LU for the
//! rest of a step when fresh symmetric factors contract poorly (`crate::solve::linear`); a step
//! that needed `SLOW_STEP_ITERATIONS` iterations on old factors makes the next one start with
//! fresh factors. The convergence test is the residual test above either way. The workspace of
//! the last (converged) evaluation is handed to the caller (`take_final_evaluation`), so a step
//! evaluates the forces once per Newton iteration plus once to confirm convergence, no more.
//!
//! **Semi-implicit (symplectic) Euler**: `v_(n+1) = v_n + h M^-1 (Q(q_n, v_n, t_n) - gyro - Phi_q^T lambda)`
//! with the constraints imposed on the new velocity (`Phi_q v_(n+1) = -Phi(q_n) / h`, which also
//! removes position drift), then `q_(n+1) = q_n exp(h v_(n+1))`. First order, cheap, explicit in
//! the forces; stable only for `h < 2 / omega_max` (`omega_max` the highest natural frequency of
//! the linearized system, see `stability_limit`); stiff or damped cables shrink that limit. Its
//! linear system is solved through the joints' Schur complement on the dense backend
//! (`JointSchur`) and by the exact sparse `LDL^T` on the sparse one.

use nalgebra::{DMatrix, DVector, Matrix3, Matrix6, SymmetricEigen, Vector3, Vector6};

use crate::constraints::{add_multiplier_hessian_to, add_reaction_force, evaluate_rates, joint_points};
use crate::forces::cable::{add_block, add_vector, length_gradient_dot, route_geometry};
use crate::forces::{
    add_tangents, evaluate, evaluate_forces, kinetic_energy, TangentSink, Tangents, Workspace,
};
use crate::model::{BodyId, BodyKind, CableId, Model};
use crate::solve::linear::{FactorKind, KktSystem, LinearBackend};
use crate::state::{retract, State};

pub mod explicit;

/// Which integrator advances the dynamics.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Integrator {
    /// Implicit generalized-alpha with spectral radius at infinity `rho_inf` in [0, 1].
    GeneralizedAlpha {
        /// High-frequency spectral radius: 1 = no numerical dissipation, 0 = maximal.
        rho_inf: f64,
    },
    /// Semi-implicit (symplectic) Euler; conditionally stable.
    SymplecticEuler,
    /// The classical explicit 4th-order Runge-Kutta method (`explicit`); conditionally stable.
    Rk4,
    /// The Dormand-Prince 5(4) explicit embedded pair (`explicit`): 5th order, with a local error
    /// estimate for step-size control; conditionally stable.
    DormandPrince,
}

impl Integrator {
    /// Parses `generalized-alpha` / `ga`, `symplectic-euler` / `euler`, `rk4`,
    /// `dormand-prince` / `dopri5`.
    pub fn parse(name: &str, rho_inf: f64) -> Option<Self> {
        match name {
            "generalized-alpha" | "ga" => Some(Integrator::GeneralizedAlpha { rho_inf }),
            "symplectic-euler" | "euler" => Some(Integrator::SymplecticEuler),
            "rk4" => Some(Integrator::Rk4),
            "dormand-prince" | "dopri5" => Some(Integrator::DormandPrince),
            _ => None,
        }
    }
    /// Short name for tables.
    pub fn name(&self) -> String {
        match self {
            Integrator::GeneralizedAlpha { rho_inf } => format!("generalized-alpha(rho={rho_inf})"),
            Integrator::SymplecticEuler => "symplectic-euler".into(),
            Integrator::Rk4 => "rk4".into(),
            Integrator::DormandPrince => "dormand-prince".into(),
        }
    }
    /// Order of the local error of a step: `h^(order + 1)`.
    pub fn order(&self) -> u32 {
        match self {
            Integrator::GeneralizedAlpha { .. } => 2,
            Integrator::SymplecticEuler => 1,
            Integrator::Rk4 => 4,
            Integrator::DormandPrince => 5,
        }
    }
    /// True for the explicit (conditionally stable) integrators.
    pub fn is_explicit(&self) -> bool {
        !matches!(self, Integrator::GeneralizedAlpha { .. })
    }
    /// True when the integrator estimates its local error, so that it can choose its steps
    /// (`SimSettings::tolerance`).
    pub fn estimates_error(&self) -> bool {
        matches!(self, Integrator::GeneralizedAlpha { .. } | Integrator::DormandPrince)
    }
    /// How the error ratio of `AttemptStats::error_ratio` scales with the step, `ratio ~ h^(1/e)`:
    /// the step that would meet the tolerance is `h ratio^(-e)`. Generalized-alpha's local error
    /// goes like `h^3` (`e = 1/3`), Dormand-Prince's 4th-order estimate like `h^5` (`e = 1/5`).
    pub fn error_exponent(&self) -> f64 {
        match self {
            Integrator::DormandPrince => 0.2,
            _ => 1.0 / 3.0,
        }
    }
}

/// Generalized-alpha coefficients for a spectral radius.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AlphaCoefficients {
    /// `alpha_m`.
    pub alpha_m: f64,
    /// `alpha_f`.
    pub alpha_f: f64,
    /// `gamma`.
    pub gamma: f64,
    /// `beta`.
    pub beta: f64,
}

impl AlphaCoefficients {
    /// Chung-Hulbert coefficients for `rho_inf` in [0, 1].
    pub fn new(rho_inf: f64) -> Self {
        let rho = rho_inf.clamp(0.0, 1.0);
        let alpha_m = (2.0 * rho - 1.0) / (rho + 1.0);
        let alpha_f = rho / (rho + 1.0);
        let gamma = 0.5 + alpha_f - alpha_m;
        let beta = 0.25 * (gamma + 0.5).powi(2);
        Self { alpha_m, alpha_f, gamma, beta }
    }
}

/// Newton settings of the implicit integrator.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NewtonSettings {
    /// Converged when `|residual|_inf <= tolerance * force_scale` (or at the round-off floor).
    pub tolerance: f64,
    /// Iterations before the step is rejected.
    pub max_iterations: usize,
    /// Modified Newton: keep the last factored Newton matrix (across iterations and steps of the
    /// same size) and refactor only when an iteration contracts the residual by less than
    /// `REFACTOR_CONTRACTION`, after `MAX_STALE_ITERATIONS` iterations on old factors, or when
    /// the step size changes. The convergence test is the same residual test either way.
    pub reuse_factorization: bool,
}

/// A reused factorization is replaced when an iteration leaves more than this fraction of the
/// residual (`|r_k| > REFACTOR_CONTRACTION |r_(k-1)|`).
pub const REFACTOR_CONTRACTION: f64 = 0.25;
/// Iterations in a row on one reused factorization before it is replaced anyway.
pub const MAX_STALE_ITERATIONS: usize = 4;
/// Generalized-alpha's local errors add up over the steps: each step may make `tolerance
/// h_avg / TOLERANCE_TIME` of it, `h_avg` the running mean step, so that a second's worth of
/// steps adds up to about the tolerance, while each step gets the same share (equidistributed
/// local errors take the fewest steps for a total), s. Errors that go into damped modes get more
/// (`damped_mode_relief`).
pub const TOLERANCE_TIME: f64 = 1.0;

/// A step that needed this many Newton iterations on factors from earlier steps makes the next
/// step start with fresh factors. On a structure whose stiffness keeps changing (a 64-stage
/// helical tower deploying through every stage) factors a step old already need 3 iterations
/// and a factorization costs about 2.6 iterations: refreshing after 3-iteration steps cost
/// 9.0e9 instructions per 1000 steps, after 4-iteration steps 7.1e9, never 7.7e9 (callgrind,
/// `bench steps tower:helical:64 --steps 1000`).
pub const SLOW_STEP_ITERATIONS: usize = 4;

impl Default for NewtonSettings {
    fn default() -> Self {
        Self { tolerance: 1e-9, max_iterations: 15, reuse_factorization: true }
    }
}

/// What one successful step attempt cost.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct AttemptStats {
    /// Newton iterations (0 for the explicit integrators).
    pub iterations: usize,
    /// Final residual max-norm, N.
    pub residual: f64,
    /// Newton-matrix factorizations (0 when every iteration reused older factors).
    pub factorizations: usize,
    /// Force evaluations (stages of an explicit method, iterations plus one of an implicit one).
    pub evaluations: usize,
    /// The local error estimate of the step, m (`None` for integrators without one).
    pub error: Option<f64>,
    /// The error estimate over what the tolerance allows this step (`<= 1` when accepted;
    /// `None` without a tolerance or an estimate).
    pub error_ratio: Option<f64>,
}

/// Why a step attempt was refused. The state is unchanged either way.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum AttemptFailure {
    /// Newton did not converge, a solve failed, or a number was not finite.
    Diverged,
    /// The local error estimate exceeded the tolerance by this factor (> 1).
    ErrorTooLarge(f64),
}

/// Integrator memory and preallocated buffers for one model.
#[derive(Debug, Clone)]
pub struct Dynamics {
    /// Each body's constant mass matrix in its local coordinates (`BodyModel::mass_matrix`).
    mass: Vec<Matrix6<f64>>,
    /// True acceleration `vdot` at the current state.
    pub acceleration: DVector<f64>,
    /// Generalized-alpha pseudo-acceleration `a`.
    pub pseudo_acceleration: DVector<f64>,
    ws: Workspace,
    /// The explicit integrator's joint projection on the dense backend (`JointSchur`).
    schur: JointSchur,
    /// Stage buffers of the Runge-Kutta integrators.
    explicit: explicit::ExplicitBuffers,
    /// Per body: the largest distance of its points from its origin (at least 1 mm), m; a
    /// rotation error times this is a point error.
    reach: Vec<f64>,
    trial: State,
    rhs: DVector<f64>,
    residual: DVector<f64>,
    kkt: KktSystem,
    /// `(beta', gamma')` of the generalized-alpha matrix whose factors `kkt` holds.
    factored_for: Option<(f64, f64)>,
    /// The last step needed `SLOW_STEP_ITERATIONS` or more iterations on reused factors: the
    /// next step starts with fresh ones.
    refresh: bool,
    /// `ws` holds the evaluation of the state the last step committed.
    final_evaluation: bool,
    /// The acceleration before the last generalized-alpha step, and that step's size (`None`
    /// after a restart): the central difference of the error estimate.
    previous_acceleration: DVector<f64>,
    previous_step: Option<f64>,
    /// The largest jerk envelope times lever of the recent attempts, decaying by
    /// `ENVELOPE_HOLD` per accepted step (m/s^3; 0 after a restart).
    held_envelope: f64,
    /// The largest `jerk_decay_rate` of the error-controlled steps so far, 1/s
    /// (`damped_mode_relief`).
    largest_decay_rate: f64,
    /// The jerk of the last generalized-alpha attempt (scratch of `jerk_decay_rate`).
    jerk: DVector<f64>,
    // generalized-alpha iterates, preallocated so that a step never allocates
    vdot: DVector<f64>,
    a_next: DVector<f64>,
    v: DVector<f64>,
    delta: DVector<f64>,
    lambda: DVector<f64>,
}

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

/// Gyroscopic generalized force `B^T [0; w x J w]` of rigid bodies (N m), added into `out`.
pub fn add_gyroscopic(model: &Model, v: &DVector<f64>, out: &mut DVector<f64>) {
    for (b, body) in model.bodies.iter().enumerate() {
        if body.kind != BodyKind::Rigid {
            continue;
        }
        let local = body.local_increment(v.as_slice(), 1.0);
        let w = Vector3::new(local[3], local[4], local[5]);
        let t = w.cross(&(body.inertia * w));
        add_vector(
            model,
            BodyId(b),
            &(body.basis.transpose() * Vector6::new(0.0, 0.0, 0.0, t.x, t.y, t.z)),
            1.0,
            out,
        );
    }
}

/// The velocity derivative of the gyroscopic force, `B^T [[0,0],[0, [w]x J - [J w]x]] B`
/// (N m s), added into the damping blocks of `sink`.
pub fn add_gyroscopic_damping<S: TangentSink + ?Sized>(model: &Model, v: &DVector<f64>, sink: &mut S) {
    for (b, body) in model.bodies.iter().enumerate() {
        if body.kind != BodyKind::Rigid {
            continue;
        }
        let local = body.local_increment(v.as_slice(), 1.0);
        let w = Vector3::new(local[3], local[4], local[5]);
        let jw = body.inertia * w;
        let d: Matrix3<f64> = w.cross_matrix() * body.inertia - jw.cross_matrix();
        let mut d6 = Matrix6::zeros();
        d6.fixed_view_mut::<3, 3>(3, 3).copy_from(&d);
        sink.damping(BodyId(b), BodyId(b), &(body.basis.transpose() * d6 * body.basis), 1.0);
    }
}

/// Constant mass matrix of `model` (dense, block diagonal, kg and kg m^2).
pub fn mass_matrix(model: &Model) -> DMatrix<f64> {
    let mut m = DMatrix::zeros(model.dof_count, model.dof_count);
    for (b, body) in model.bodies.iter().enumerate() {
        add_block(model, BodyId(b), BodyId(b), &body.mass_matrix(), 1.0, &mut m);
    }
    m
}

/// `d(Phi_q)/dt v` by a central difference of `Phi_q v` along `v` (m/s^2), the velocity-squared
/// term of the constraint acceleration; zero without joints.
fn constraint_curvature(model: &Model, state: &State, ws: &mut Workspace) -> DVector<f64> {
    let nc = model.constraint_count;
    if nc == 0 || state.velocities.amax() == 0.0 {
        return DVector::zeros(nc);
    }
    let eps = 1e-6 / state.velocities.amax().max(1e-12);
    let mut s = state.clone();
    let mut out = DVector::zeros(nc);
    let mut rates = DVector::zeros(nc);
    for (sign, scale) in [(1.0, eps), (-1.0, -eps)] {
        s.poses.copy_from_slice(&state.poses);
        retract(model, &mut s.poses, &state.velocities, scale);
        evaluate_forces(model, &s, ws);
        evaluate_rates(model, &ws.points, &mut rates);
        out.axpy(sign / (2.0 * eps), &rates, 1.0);
    }
    out
}

fn force_scale(model: &Model, ws: &Workspace, inertial: f64) -> f64 {
    let weight = model.bodies.iter().map(|b| b.mass * model.gravity.norm()).fold(0.0, f64::max);
    let tension = ws.cables.iter().map(|c| c.tension).fold(0.0, f64::max);
    weight.max(tension).max(inertial).max(1e-9)
}

fn force_floor(model: &Model, ws: &Workspace) -> f64 {
    model
        .cables
        .iter()
        .zip(&ws.cables)
        .map(|(m, c)| 64.0 * f64::EPSILON * m.axial_stiffness * c.length / c.rest_length)
        .fold(0.0, f64::max)
}

fn all_finite(v: &DVector<f64>) -> bool {
    v.iter().all(|x| x.is_finite())
}

impl Dynamics {
    /// Buffers for `model`, solving its Newton systems with `backend`.
    pub fn new(model: &Model, backend: LinearBackend) -> Self {
        let n = model.dof_count;
        let kkt = KktSystem::new(model, backend);
        Self {
            mass: model.bodies.iter().map(|b| b.mass_matrix()).collect(),
            acceleration: DVector::zeros(n),
            pseudo_acceleration: DVector::zeros(n),
            ws: Workspace::for_forces(model),
            schur: JointSchur::new(model),
            explicit: explicit::ExplicitBuffers::new(model, n + model.constraint_count),
            reach: body_reach(model),
            trial: State::initial(model),
            rhs: DVector::zeros(kkt.size()),
            residual: DVector::zeros(n),
            kkt,
            factored_for: None,
            refresh: false,
            final_evaluation: false,
            previous_acceleration: DVector::zeros(n),
            previous_step: None,
            held_envelope: 0.0,
            largest_decay_rate: 0.0,
            jerk: DVector::zeros(n),
            vdot: DVector::zeros(n),
            a_next: DVector::zeros(n),
            v: DVector::zeros(n),
            delta: DVector::zeros(n),
            lambda: DVector::zeros(model.constraint_count),
        }
    }

    /// Swaps `ws` with the workspace the last successful generalized-alpha step evaluated at the
    /// state it committed (its convergence check), and returns true; false (nothing swapped)
    /// after a symplectic Euler step, whose evaluation is of the state before the step. Saves the
    /// caller a force evaluation per step.
    pub fn take_final_evaluation(&mut self, ws: &mut Workspace) -> bool {
        if !self.final_evaluation {
            return false;
        }
        std::mem::swap(ws, &mut self.ws);
        self.final_evaluation = false;
        true
    }

    /// The linear-solver backend in use (dense or sparse).
    pub fn linear_backend(&self) -> LinearBackend {
        self.kkt.backend()
    }

    /// The Newton system (size, nonzeros, bordered cables).
    pub fn kkt(&self) -> &KktSystem {
        &self.kkt
    }

    /// `out = M x` with the block-diagonal mass matrix (no `n x n` product).
    fn mass_times(&self, model: &Model, x: &DVector<f64>, out: &mut DVector<f64>) {
        for (b, body) in model.bodies.iter().enumerate() {
            let (o, k) = (body.dof_offset, body.dof_count);
            for r in 0..k {
                let mut sum = 0.0;
                for c in 0..k {
                    sum += self.mass[b][(r, c)] * x[o + c];
                }
                out[o + r] = sum;
            }
        }
    }

    /// Starts the matrix `[M, Phi_q^T; Phi_q, 0]` (bordered rows `dT = 0`) at the point
    /// kinematics in the workspace.
    fn assemble_mass_and_joints(&mut self, model: &Model) {
        assemble_mass_and_joints(model, &self.ws, &self.mass, &mut self.kkt);
    }

    /// Sets consistent accelerations and reactions at `state` (solves
    /// `[M Phi_q^T; Phi_q 0][vdot; lambda] = [Q - gyro; -dPhi_q/dt v]`), and `a = vdot`.
    pub fn initialize(&mut self, model: &Model, state: &mut State) -> bool {
        let n = model.dof_count;
        let nc = model.constraint_count;
        let curvature = constraint_curvature(model, state, &mut self.ws);
        evaluate_forces(model, state, &mut self.ws);
        let mut gyro = DVector::zeros(n);
        add_gyroscopic(model, &state.velocities, &mut gyro);
        self.assemble_mass_and_joints(model);
        self.rhs.fill(0.0);
        self.rhs.rows_mut(0, n).copy_from(&(&self.ws.force - gyro));
        self.rhs.rows_mut(n, nc).copy_from(&(-curvature));
        self.factored_for = None;
        if !self.kkt.solve(&mut self.rhs) {
            return false;
        }
        self.acceleration.copy_from(&self.rhs.rows(0, n));
        self.pseudo_acceleration.copy_from(&self.acceleration);
        self.previous_step = None;
        self.held_envelope = 0.0;
        state.multipliers.copy_from(&self.rhs.rows(n, nc));
        true
    }

    /// One step of size `h` with rest lengths `rest_next` at the new time. On success writes the
    /// new state into `state` (and the accelerations here) and returns the attempt's statistics;
    /// on failure leaves everything unchanged and returns `None`.
    #[allow(clippy::too_many_arguments)]
    pub fn step(
        &mut self,
        model: &Model,
        integrator: Integrator,
        newton: &NewtonSettings,
        state: &mut State,
        rest_now: &[f64],
        rest_next: &[f64],
        h: f64,
        tolerance: Option<f64>,
    ) -> Result<AttemptStats, AttemptFailure> {
        match integrator {
            Integrator::GeneralizedAlpha { rho_inf } => self.generalized_alpha(
                model,
                AlphaCoefficients::new(rho_inf),
                newton,
                state,
                rest_next,
                h,
                tolerance,
            ),
            Integrator::SymplecticEuler => {
                self.explicit.invalidate();
                self.previous_step = None;
                self.symplectic_euler(model, state, rest_now, rest_next, h).ok_or(AttemptFailure::Diverged)
            }
            Integrator::Rk4 | Integrator::DormandPrince => {
                self.previous_step = None;
                let tableau = if integrator == Integrator::Rk4 { &explicit::RK4 } else { &explicit::DOPRI5 };
                // the local errors of a run add up to a few times each one's: aim lower
                let tolerance = tolerance.map(explicit::local_tolerance);
                match self.explicit_step(model, tableau, state, rest_now, rest_next, h, tolerance) {
                    Ok(s) => Ok(AttemptStats {
                        iterations: 0,
                        residual: 0.0,
                        factorizations: 0,
                        evaluations: s.evaluations,
                        error: s.error,
                        error_ratio: s.error.zip(tolerance).map(|(e, t)| e / t),
                    }),
                    Err(ratio) if ratio.is_finite() => Err(AttemptFailure::ErrorTooLarge(ratio)),
                    Err(_) => Err(AttemptFailure::Diverged),
                }
            }
        }
    }

    #[allow(clippy::too_many_arguments)]
    fn generalized_alpha(
        &mut self,
        model: &Model,
        c: AlphaCoefficients,
        newton: &NewtonSettings,
        state: &mut State,
        rest_next: &[f64],
        h: f64,
        tolerance: Option<f64>,
    ) -> Result<AttemptStats, AttemptFailure> {
        self.explicit.invalidate();
        let n = model.dof_count;
        let nc = model.constraint_count;
        let beta_p = (1.0 - c.alpha_m) / (h * h * c.beta * (1.0 - c.alpha_f));
        let gamma_p = c.gamma / (h * c.beta);

        // predictor: constant acceleration
        self.vdot.copy_from(&self.acceleration);
        self.update_pseudo_acceleration(&c);
        self.v.copy_from(&state.velocities);
        self.v.axpy(h * (1.0 - c.gamma), &self.pseudo_acceleration, 1.0);
        self.v.axpy(h * c.gamma, &self.a_next, 1.0);
        self.delta.copy_from(&state.velocities);
        self.delta.axpy(h * h * (0.5 - c.beta), &self.pseudo_acceleration, h);
        self.delta.axpy(h * h * c.beta, &self.a_next, 1.0);
        self.lambda.copy_from(&state.multipliers);

        self.trial.time = state.time + h;
        self.trial.rest_lengths.copy_from_slice(rest_next);
        let mut stats = AttemptStats::default();
        let coefficients = (beta_p, gamma_p);
        let mut reuse =
            newton.reuse_factorization && self.factored_for == Some(coefficients) && !self.refresh;
        let mut previous = f64::INFINITY;
        let mut stale = 0;
        let mut factorizations = 0;
        // full Newton factors the exact matrix; modified Newton starts from the symmetric part's
        // LDL^T and turns to the exact LU for the rest of the step when fresh symmetric factors
        // do not contract the residual well enough
        let mut exact = !newton.reuse_factorization;
        let mut fresh = false;
        for iter in 0..=newton.max_iterations {
            self.trial.poses.copy_from_slice(&state.poses);
            retract(model, &mut self.trial.poses, &self.delta, 1.0);
            self.trial.velocities.copy_from(&self.v);
            self.trial.multipliers.copy_from(&self.lambda);
            evaluate_forces(model, &self.trial, &mut self.ws);

            // residual r = M vdot + gyro - Q + Phi_q^T lambda
            let mut residual = std::mem::take(&mut self.residual);
            self.mass_times(model, &self.vdot, &mut residual);
            let inertial = residual.amax();
            add_gyroscopic(model, &self.v, &mut residual);
            residual -= &self.ws.force;
            add_reaction_force(model, &self.ws.points, &self.lambda, 1.0, &mut residual);
            self.residual = residual;
            if !all_finite(&self.residual) {
                return Err(AttemptFailure::Diverged);
            }
            let r_norm = self.residual.amax();
            let phi_norm = if nc > 0 { self.ws.constraint.amax() } else { 0.0 };
            let scale = force_scale(model, &self.ws, inertial);
            let length_scale = self.ws.cables.iter().map(|c| c.length).fold(1e-3, f64::max);
            stats = AttemptStats {
                iterations: iter,
                residual: r_norm,
                factorizations,
                evaluations: iter + 1,
                error: None,
                error_ratio: None,
            };
            if r_norm <= (newton.tolerance * scale).max(force_floor(model, &self.ws))
                && phi_norm <= 1e-12 * length_scale
            {
                break;
            }
            if iter == newton.max_iterations {
                self.factored_for = None;
                return Err(AttemptFailure::Diverged);
            }
            let contraction = r_norm.max(phi_norm * scale / length_scale);
            if reuse && (contraction > REFACTOR_CONTRACTION * previous || stale >= MAX_STALE_ITERATIONS) {
                reuse = false;
                exact |= fresh && self.kkt.factor_kind() == FactorKind::SymmetricLdlt;
            }
            previous = contraction;
            // [M + (gamma' C + K + H_lambda)/beta', Phi_q^T; Phi_q, 0] [d delta; d lambda / beta'] = [-r / beta'; -Phi]
            self.rhs.fill(0.0);
            self.rhs.rows_mut(0, n).axpy(-1.0 / beta_p, &self.residual, 0.0);
            self.rhs.rows_mut(n, nc).axpy(-1.0, &self.ws.constraint, 0.0);
            if reuse && self.kkt.solve_factored(&mut self.rhs) {
                stale += 1;
                fresh = false;
            } else {
                self.assemble_newton_matrix(model, beta_p, gamma_p);
                factorizations += 1;
                self.factored_for = None;
                let factored = if exact { self.kkt.factor() } else { self.kkt.factor_symmetric() };
                if !factored {
                    return Err(AttemptFailure::Diverged);
                }
                fresh = true;
                self.factored_for = Some(coefficients);
                if reuse {
                    // the failed solve on the old factors overwrote the right-hand side
                    self.rhs.fill(0.0);
                    self.rhs.rows_mut(0, n).axpy(-1.0 / beta_p, &self.residual, 0.0);
                    self.rhs.rows_mut(n, nc).axpy(-1.0, &self.ws.constraint, 0.0);
                }
                if !self.kkt.solve_factored(&mut self.rhs) {
                    self.factored_for = None;
                    return Err(AttemptFailure::Diverged);
                }
                reuse = newton.reuse_factorization;
                stale = 0;
            }
            let dd = self.rhs.rows(0, n);
            self.delta += dd;
            self.v.axpy(gamma_p, &dd, 1.0);
            self.vdot.axpy(beta_p, &dd, 1.0);
            if nc > 0 {
                self.lambda.axpy(beta_p, &self.rhs.rows(n, nc), 1.0);
            }
        }
        // local error estimate (after Zienkiewicz & Xie 1991): the displacement's truncation
        // error (beta - 1/6) h^3 (jerk), with the jerk's envelope (`jerk_envelope`) in place of
        // the jerk, so that an oscillation gets the same step through its cycle. The jerk is the
        // central difference of the accelerations over this and the previous step,
        // `(vdot_(n+1) - vdot_(n-1)) / (h + h_prev)`: a jump of the acceleration (an actuator
        // starting) rings in generalized-alpha's spurious mode, which alternates in sign from
        // step to step and cancels in this difference, where the plain `vdot_(n+1) - vdot_n` would
        // keep the steps small long after. First step after a restart: the one-step difference,
        // no envelope. A rotation's error counts times the body's reach. The largest envelope is
        // held over the next steps (`ENVELOPE_HOLD`).
        let weight = h * h * h * (c.beta - 1.0 / 6.0).abs();
        let length_scale = self.ws.cables.iter().map(|c| c.length).fold(1e-3, f64::max);
        // the joints hold to 1e-12 of the length scale at position level, Newton's residual to
        // `newton.tolerance` of the forces: the accelerations' noise (see below)
        let joint_noise = if nc > 0 { 1e-12 * length_scale / (c.beta * h * h) } else { 0.0 };
        let mut largest: f64 = 0.0;
        for (b, body) in model.bodies.iter().enumerate() {
            for k in 0..body.dof_count {
                let j = body.dof_offset + k;
                let lever =
                    if body.basis.column(k).fixed_rows::<3>(3).norm() > 0.0 { self.reach[b] } else { 1.0 };
                let (now, next) = (self.acceleration[j], self.vdot[j]);
                let envelope = match self.previous_step {
                    Some(h_prev) => {
                        let noise = joint_noise + newton.tolerance * now.abs().max(next.abs());
                        jerk_envelope(self.previous_acceleration[j], now, next, h_prev, h, noise)
                    }
                    None => (next - now).abs() / h,
                };
                largest = largest.max(envelope * lever);
            }
        }
        let held = if largest.is_finite() { self.held_envelope.max(largest) } else { largest };
        // the joints' noise in the accelerations, `joint_noise` at each of two samples, is a
        // floor of 2 |beta - 1/6| / beta 1e-12 L in the jerk term whatever the step: below it the
        // estimate says nothing
        let noise = 2.0 * weight * joint_noise / h;
        let error = (weight * held - noise).max(0.0);
        stats.error = Some(error);
        if let Some(tol) = tolerance {
            // the caller's per-step share of the tolerance (`Simulator::step`), more where the
            // error goes into damped modes and dies out (`damped_mode_relief`)
            let mut relief = 1.0;
            if let Some(h_prev) = self.previous_step {
                self.jerk.copy_from(&self.vdot);
                self.jerk -= &self.previous_acceleration;
                self.jerk /= h + h_prev;
                let rate = jerk_decay_rate(model, &mut self.ws, &self.jerk);
                if rate.is_finite() {
                    self.largest_decay_rate = self.largest_decay_rate.max(rate);
                    relief = damped_mode_relief(rate, self.largest_decay_rate);
                }
            }
            let allowed = tol * relief;
            stats.error_ratio = Some(error / allowed);
            if error > allowed || error.is_nan() {
                // a refused attempt measured the envelope too, over a longer step
                if held.is_finite() {
                    self.held_envelope = held;
                }
                return Err(if error.is_finite() {
                    AttemptFailure::ErrorTooLarge(error / allowed)
                } else {
                    AttemptFailure::Diverged
                });
            }
        }
        // commit (the workspace holds the evaluation of exactly the committed state)
        self.final_evaluation = true;
        self.refresh = stats.iterations >= SLOW_STEP_ITERATIONS && factorizations == 0;
        self.update_pseudo_acceleration(&c);
        state.poses.copy_from_slice(&self.trial.poses);
        state.velocities.copy_from(&self.v);
        state.multipliers.copy_from(&self.lambda);
        state.rest_lengths.copy_from_slice(rest_next);
        state.time = self.trial.time;
        self.previous_acceleration.copy_from(&self.acceleration);
        self.previous_step = Some(h);
        self.held_envelope = if held.is_finite() { ENVELOPE_HOLD * held } else { 0.0 };
        self.acceleration.copy_from(&self.vdot);
        self.pseudo_acceleration.copy_from(&self.a_next);
        Ok(stats)
    }

    /// Assembles the generalized-alpha Newton matrix at the trial state.
    fn assemble_newton_matrix(&mut self, model: &Model, beta_p: f64, gamma_p: f64) {
        assemble_newton_matrix(model, &self.trial, &mut self.ws, &self.mass, &mut self.kkt, beta_p, gamma_p);
    }

    /// `a_next = (alpha_f vdot_n - alpha_m a_n + (1 - alpha_f) vdot) / (1 - alpha_m)`, in place.
    fn update_pseudo_acceleration(&mut self, c: &AlphaCoefficients) {
        self.a_next.copy_from(&self.acceleration);
        self.a_next.axpy(-c.alpha_m, &self.pseudo_acceleration, c.alpha_f);
        self.a_next.axpy(1.0 - c.alpha_f, &self.vdot, 1.0);
        self.a_next /= 1.0 - c.alpha_m;
    }

    fn symplectic_euler(
        &mut self,
        model: &Model,
        state: &mut State,
        rest_now: &[f64],
        rest_next: &[f64],
        h: f64,
    ) -> Option<AttemptStats> {
        let n = model.dof_count;
        let nc = model.constraint_count;
        self.trial.time = state.time;
        self.trial.poses.copy_from_slice(&state.poses);
        self.trial.velocities.copy_from(&state.velocities);
        self.trial.multipliers.copy_from(&state.multipliers);
        self.trial.rest_lengths.copy_from_slice(rest_now);
        evaluate_forces(model, &self.trial, &mut self.ws);
        // f = Q - gyro (in `residual`), M v_n (in `vdot`)
        self.v.fill(0.0);
        add_gyroscopic(model, &state.velocities, &mut self.v);
        self.residual.copy_from(&self.ws.force);
        self.residual -= &self.v;
        let mut mv = std::mem::take(&mut self.vdot);
        self.mass_times(model, &state.velocities, &mut mv);
        self.vdot = mv;
        // [M Phi_q^T; Phi_q 0] [v+; h lambda] = [M v + h f; -Phi / h]
        self.rhs.fill(0.0);
        self.rhs.rows_mut(0, n).copy_from(&self.vdot);
        self.rhs.rows_mut(0, n).axpy(h, &self.residual, 1.0);
        self.rhs.rows_mut(n, nc).axpy(-1.0 / h, &self.ws.constraint, 0.0);
        if self.kkt.backend() == LinearBackend::Dense {
            // small scenes: the joints' Schur complement (nc x nc) instead of the whole matrix
            if !self.schur.solve(model, &self.ws, &mut self.rhs) {
                return None;
            }
        } else {
            self.assemble_mass_and_joints(model);
            self.factored_for = None;
            // the matrix is symmetric: its LDL^T (where the backend has one) is exact
            if !(self.kkt.factor_symmetric() && self.kkt.solve_factored(&mut self.rhs)) {
                return None;
            }
        }
        self.v.copy_from(&self.rhs.rows(0, n));
        retract(model, &mut self.trial.poses, &self.v, h);
        if self.trial.poses.iter().any(|p| !p.position.iter().all(|x| x.is_finite())) {
            return None;
        }
        // commit
        self.vdot.copy_from(&self.v);
        self.vdot.axpy(-1.0 / h, &state.velocities, 1.0 / h);
        state.poses.copy_from_slice(&self.trial.poses);
        state.velocities.copy_from(&self.v);
        for r in 0..nc {
            state.multipliers[r] = self.rhs[n + r] / h;
        }
        state.rest_lengths.copy_from_slice(rest_next);
        state.time += h;
        self.acceleration.copy_from(&self.vdot);
        self.pseudo_acceleration.copy_from(&self.vdot);
        Some(AttemptStats {
            iterations: 0,
            residual: 0.0,
            factorizations: 1,
            evaluations: 1,
            error: None,
            error_ratio: None,
        })
    }
}

/// The explicit integrator's velocity step by the joints' Schur complement (dense backend): with
/// the block-diagonal mass matrix inverted once per model,
/// `[M, Phi_q^T; Phi_q, 0] [v; mu] = [p; c]` becomes `S mu = Phi_q M^-1 p - c` with
/// `S = Phi_q M^-1 Phi_q^T` (nc x nc, symmetric positive definite for independent joints, which
/// scenes guarantee), then `v = M^-1 (p - Phi_q^T mu)`: an `nc x nc` Cholesky per step instead of
/// an `(n + nc)` LU, assembled from 3 x 3 blocks of the joint sides that share a body.
struct JointSchur {
    /// Per body: the inverse of its local mass matrix (top-left `k x k`).
    mass_inverse: Vec<Matrix6<f64>>,
    /// Per body: the joint sides on it, `(joint, point, sign)`.
    sides: Vec<Vec<(usize, crate::model::PointId, f64)>>,
    /// `S`, column-major, and its Cholesky factor in place.
    s: Vec<f64>,
    /// Per joint side in `sides` order: `M_b^-1 J^T` (k x 3 in a 6 x 3).
    weighted: Vec<nalgebra::Matrix6x3<f64>>,
    u: DVector<f64>,
    b: DVector<f64>,
    mem: faer::dyn_stack::MemBuffer,
}

impl std::fmt::Debug for JointSchur {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("JointSchur").field("rows", &self.b.len()).finish()
    }
}

impl Clone for JointSchur {
    fn clone(&self) -> Self {
        Self {
            mass_inverse: self.mass_inverse.clone(),
            sides: self.sides.clone(),
            s: self.s.clone(),
            weighted: self.weighted.clone(),
            u: self.u.clone(),
            b: self.b.clone(),
            mem: Self::scratch(self.b.len()),
        }
    }
}

impl JointSchur {
    fn scratch(nc: usize) -> faer::dyn_stack::MemBuffer {
        use faer::linalg::cholesky::llt;
        faer::dyn_stack::MemBuffer::new(faer::dyn_stack::StackReq::or(
            llt::factor::cholesky_in_place_scratch::<f64>(nc, faer::Par::Seq, Default::default()),
            llt::solve::solve_in_place_scratch::<f64>(nc, 1, faer::Par::Seq),
        ))
    }

    fn new(model: &Model) -> Self {
        let nc = model.constraint_count;
        let mass_inverse = model
            .bodies
            .iter()
            .map(|b| {
                let k = b.dof_count;
                let m = b.mass_matrix();
                let block = m.view((0, 0), (k, k)).into_owned().try_inverse();
                let mut inv = Matrix6::zeros();
                if let Some(block) = block {
                    inv.view_mut((0, 0), (k, k)).copy_from(&block);
                }
                inv
            })
            .collect();
        let mut sides = vec![Vec::new(); model.bodies.len()];
        for (j, joint) in model.joints.iter().enumerate() {
            for (p, sign) in joint_points(joint) {
                let body = model.points[p.0].body;
                if model.bodies[body.0].dof_count > 0 {
                    sides[body.0].push((j, p, sign));
                }
            }
        }
        let count = sides.iter().map(|s: &Vec<_>| s.len()).sum();
        Self {
            mass_inverse,
            sides,
            s: vec![0.0; nc * nc],
            weighted: vec![nalgebra::Matrix6x3::zeros(); count],
            u: DVector::zeros(model.dof_count),
            b: DVector::zeros(nc),
            mem: Self::scratch(nc),
        }
    }

    /// Solves `[M, Phi_q^T; Phi_q, 0] x = rhs` in place at the point kinematics in `ws`. False
    /// when `S` is not positive definite or the result is not finite.
    fn solve(&mut self, model: &Model, ws: &Workspace, rhs: &mut DVector<f64>) -> bool {
        use faer::linalg::cholesky::llt;
        let n = model.dof_count;
        let nc = model.constraint_count;
        let rows = model.joint_rows();
        // u = M^-1 p
        for (b, body) in model.bodies.iter().enumerate() {
            let (o, k) = (body.dof_offset, body.dof_count);
            for r in 0..k {
                self.u[o + r] = (0..k).map(|c| self.mass_inverse[b][(r, c)] * rhs[o + c]).sum();
            }
        }
        if nc > 0 {
            // b = Phi_q u - c; S from the 3 x 3 blocks of the joint sides that share a body
            self.b.copy_from(&rhs.rows(n, nc));
            self.b.neg_mut();
            self.s.fill(0.0);
            let mut w = 0;
            for (b, body) in model.bodies.iter().enumerate() {
                let (o, k) = (body.dof_offset, body.dof_count);
                let first = w;
                for &(j, p, sign) in &self.sides[b] {
                    let jac = &ws.points[p.0].jacobian;
                    let mut m = nalgebra::Matrix6x3::zeros();
                    for r in 0..k {
                        for c in 0..rows {
                            m[(r, c)] = sign
                                * (0..k).map(|i| self.mass_inverse[b][(r, i)] * jac[(c, i)]).sum::<f64>();
                        }
                    }
                    self.weighted[w] = m;
                    let row0 = model.joints[j].row_offset;
                    for r in 0..rows {
                        self.b[row0 + r] += sign * (0..k).map(|c| jac[(r, c)] * self.u[o + c]).sum::<f64>();
                    }
                    w += 1;
                }
                for &(ja, pa, sa) in &self.sides[b] {
                    let jac = &ws.points[pa.0].jacobian;
                    let ra = model.joints[ja].row_offset;
                    for (y, &(jb, _, _)) in self.sides[b].iter().enumerate() {
                        let rb = model.joints[jb].row_offset;
                        let wb = &self.weighted[first + y];
                        for r in 0..rows {
                            for c in 0..rows {
                                let v: f64 = (0..k).map(|i| jac[(r, i)] * wb[(i, c)]).sum();
                                self.s[(rb + c) * nc + ra + r] += sa * v;
                            }
                        }
                    }
                }
            }
            let mut s = faer::MatMut::from_column_major_slice_mut(&mut self.s, nc, nc);
            let factored = llt::factor::cholesky_in_place(
                s.as_mut(),
                Default::default(),
                faer::Par::Seq,
                faer::dyn_stack::MemStack::new(&mut self.mem),
                Default::default(),
            );
            if factored.is_err() {
                return false;
            }
            let mu = faer::MatMut::from_column_major_slice_mut(self.b.as_mut_slice(), nc, 1);
            llt::solve::solve_in_place_with_conj(
                s.as_ref(),
                faer::Conj::No,
                mu,
                faer::Par::Seq,
                faer::dyn_stack::MemStack::new(&mut self.mem),
            );
            // v = u - M^-1 Phi_q^T mu (the weighted sides carry their signs)
            let mut w = 0;
            for (b, body) in model.bodies.iter().enumerate() {
                let o = body.dof_offset;
                for &(j, _, _) in &self.sides[b] {
                    let row0 = model.joints[j].row_offset;
                    for r in 0..body.dof_count {
                        self.u[o + r] -=
                            (0..rows).map(|c| self.weighted[w][(r, c)] * self.b[row0 + c]).sum::<f64>();
                    }
                    w += 1;
                }
            }
            rhs.rows_mut(n, nc).copy_from(&self.b);
        }
        rhs.rows_mut(0, n).copy_from(&self.u);
        rhs.iter().all(|x| x.is_finite())
    }
}

/// Per body: the largest distance of its points from its origin, at least 1 mm (m).
fn body_reach(model: &Model) -> Vec<f64> {
    let mut reach = vec![1e-3f64; model.bodies.len()];
    for p in &model.points {
        reach[p.body.0] = reach[p.body.0].max(p.local.norm());
    }
    reach
}

/// Zeroes `kkt` and adds `[M, Phi_q^T; Phi_q, 0]`: the body mass blocks `mass` (one 6 x 6 per
/// body, `BodyModel::mass_matrix`) and the joint Jacobian rows at the point kinematics in `ws`.
pub fn assemble_mass_and_joints(model: &Model, ws: &Workspace, mass: &[Matrix6<f64>], kkt: &mut KktSystem) {
    kkt.clear();
    for (b, m) in mass.iter().enumerate() {
        kkt.add_body_block(BodyId(b), BodyId(b), m, 1.0);
    }
    for (j, joint) in model.joints.iter().enumerate() {
        for (side, (p, sign)) in joint_points(joint).enumerate() {
            let point = &ws.points[p.0];
            kkt.add_joint_jacobian(j, joint.row_offset, side, point.body, &point.jacobian, sign);
        }
    }
}

/// Assembles the generalized-alpha Newton matrix
/// `[M + (gamma' C + K + H_lambda)/beta', Phi_q^T; Phi_q, 0]` into `kkt` at `state` (its
/// velocities and multipliers are the iterate's), with `ws` evaluated there by
/// `forces::evaluate_forces`. `beta'` (1/s^2) and `gamma'` (1/s) as in the module docs.
pub fn assemble_newton_matrix(
    model: &Model,
    state: &State,
    ws: &mut Workspace,
    mass: &[Matrix6<f64>],
    kkt: &mut KktSystem,
    beta_p: f64,
    gamma_p: f64,
) {
    assemble_mass_and_joints(model, ws, mass, kkt);
    let mut sink = kkt.tangents(1.0 / beta_p, gamma_p / beta_p);
    add_tangents(model, state, &ws.points, &ws.cables, &mut ws.scratch, &mut sink);
    add_gyroscopic_damping(model, &state.velocities, &mut sink);
    if model.constraint_count > 0 {
        add_multiplier_hessian_to(model, &state.poses, &state.multipliers, 1.0, &mut sink);
    }
}

/// Largest stable step of an explicit integrator at `state` (infinite for generalized-alpha):
/// symplectic Euler's `stability_limit`; for the Runge-Kutta methods the radius of the left
/// half-disk inside their stability region (`explicit::RK4_STABILITY_RADIUS`,
/// `explicit::DOPRI5_STABILITY_RADIUS`) over the largest eigenvalue modulus of the linearized
/// system, bounded by `max(omega_max, c_max)` (`spectral_bounds`).
pub fn explicit_stability_limit(model: &Model, state: &State, integrator: Integrator) -> f64 {
    let radius = match integrator {
        Integrator::GeneralizedAlpha { .. } => return f64::INFINITY,
        Integrator::SymplecticEuler => return stability_limit(model, state),
        Integrator::Rk4 => explicit::RK4_STABILITY_RADIUS,
        Integrator::DormandPrince => explicit::DOPRI5_STABILITY_RADIUS,
    };
    let (w, c) = spectral_bounds(model, state);
    let rho = w.max(c);
    if rho > 0.0 {
        radius / rho
    } else {
        f64::INFINITY
    }
}

/// `(omega_max, c_max)` at `state`: the highest natural frequency on the directions the joints
/// allow (`Z^T K Z x = w^2 Z^T M Z x`, `Z` a null-space basis of `Phi_q`, rad/s) and the largest
/// eigenvalue of the mass-normalized damping matrix there (1/s). `(0, 0)` without coordinates or
/// freedom; `(inf, inf)` when the mass matrix there is singular.
pub fn spectral_bounds(model: &Model, state: &State) -> (f64, f64) {
    let n = model.dof_count;
    if n == 0 {
        return (0.0, 0.0);
    }
    let mut ws = Workspace::new(model);
    evaluate(model, state, &mut ws, Tangents::StiffnessAndDamping);
    let Some(z) = crate::constraints::null_space(&ws.constraint_jacobian, n) else { return (0.0, 0.0) };
    let m = z.transpose() * mass_matrix(model) * &z;
    let k = z.transpose() * ((&ws.stiffness + ws.stiffness.transpose()) * 0.5) * &z;
    let c = z.transpose() * ((&ws.damping + ws.damping.transpose()) * 0.5) * &z;
    // symmetric form L^-1 K L^-T with M = L L^T
    let Some(chol) = m.cholesky() else { return (f64::INFINITY, f64::INFINITY) };
    let l_inv = chol.l().try_inverse().unwrap_or_else(|| DMatrix::identity(z.ncols(), z.ncols()));
    let w2 = SymmetricEigen::new(&l_inv * k * l_inv.transpose()).eigenvalues.max().max(0.0);
    let c_max = SymmetricEigen::new(&l_inv * c * l_inv.transpose()).eigenvalues.max().max(0.0);
    (w2.sqrt(), c_max)
}

/// Largest stable step of the symplectic Euler integrator at `state`: `2 / omega_max`, with
/// `omega_max^2` the largest eigenvalue of `M^-1 K` on the directions the joints allow
/// (`Z^T K Z x = w^2 Z^T M Z x`, `Z` a null-space basis of `Phi_q`), reduced for cable damping:
/// for a damped mode the explicit limit is `h < 2 / (omega (sqrt(1 + z^2) + z))`, `z = c/(2 omega)`
/// with `c` the largest eigenvalue of the mass-normalized damping matrix. Infinite without
/// stiffness and damping.
pub fn stability_limit(model: &Model, state: &State) -> f64 {
    let (w, c_max) = spectral_bounds(model, state);
    if w == f64::INFINITY {
        return 0.0;
    }
    if w == 0.0 {
        return if c_max > 0.0 { 2.0 / c_max } else { f64::INFINITY };
    }
    let zeta = c_max / (2.0 * w);
    2.0 / (w * ((1.0 + zeta * zeta).sqrt() + zeta))
}

/// Power flows of the cables at one instant (W): actuator power into the cables and power lost
/// in the dampers (see `EnergyAccount`).
pub fn cable_powers(model: &Model, ws: &Workspace, rest_rate: &[f64]) -> (f64, f64) {
    let mut actuator = 0.0;
    let mut loss = 0.0;
    for (c, r) in ws.cables.iter().enumerate() {
        if r.length <= r.rest_length {
            continue;
        }
        let ea = model.cables[c].axial_stiffness;
        let t_el = ea / r.rest_length * (r.length - r.rest_length);
        actuator -= t_el * (r.length + r.rest_length) / (2.0 * r.rest_length) * rest_rate[c];
        loss += (r.tension - t_el) * r.length_rate;
    }
    (actuator, loss)
}
