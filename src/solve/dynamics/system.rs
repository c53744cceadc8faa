//! The integrator's memory and the pieces every method shares: takes a model, gives `Dynamics`
//! (preallocated buffers, the Newton system, the previous accelerations of the error estimate)
//! with its dispatch to the methods (`step`, `initialize`), the Newton settings, an attempt's
//! statistics, the gyroscopic and mass terms, and the explicit methods' stability limits.

use nalgebra::{DMatrix, DVector, Matrix3, Matrix6, SymmetricEigen, Vector3, Vector6};

use crate::assembly::TangentSink;
use crate::assembly::{add_block, add_vector};
use crate::constraints::evaluate_rates;
use crate::evaluate::{evaluate, evaluate_forces, Tangents, Workspace};
use crate::model::{BodyId, BodyKind, Model};
use crate::solve::linear::{KktSystem, LinearBackend};
use crate::state::{retract, State};

use crate::solve::dynamics::integrator::{AlphaCoefficients, Integrator};
use crate::solve::dynamics::joint_schur::JointSchur;
use crate::solve::dynamics::tableaus::{self, ExplicitBuffers};

/// Newton settings of the implicit integrator.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NewtonSettings {
    /// Converged when `|residual|_inf <= tolerance * force_scale` (or at the round-off floor);
    /// relative, in `NEWTON_TOLERANCE_RANGE`, default `DEFAULT_NEWTON_TOLERANCE`.
    pub tolerance: f64,
    /// Iterations before the step is rejected.
    pub max_iterations: usize,
    /// Modified Newton: keep the last factored Newton matrix (across iterations and steps of the
    /// same size) and refactor only when an iteration contracts the residual by less than
    /// `REFACTOR_CONTRACTION`, after `MAX_STALE_ITERATIONS` iterations on old factors, or when
    /// the step size changes. The convergence test is the same residual test either way.
    pub reuse_factorization: bool,
}

/// The Newton tolerance by default (`NewtonSettings::tolerance`), relative to the force scale:
/// on a 1 kg body at dt = 1 ms it moves the step's end by about `1e-9 g dt^2`, 1e-14 m.
pub const DEFAULT_NEWTON_TOLERANCE: f64 = 1e-9;

/// The Newton tolerances a user may choose (`--newton-tol`, the node's `newton_tolerance`),
/// relative. A looser one stops Newton sooner: generalized-alpha's step then solves its equations
/// to that fraction of the forces (fewer iterations per step on a robot on the ground, measured
/// in docs/benchmarks.md; its own rows in `bench work-precision`); below 1e-12 the round-off of
/// the residual itself would keep Newton from stopping.
pub const NEWTON_TOLERANCE_RANGE: (f64, f64) = (1e-12, 1e-3);

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
        Self { tolerance: DEFAULT_NEWTON_TOLERANCE, max_iterations: 15, reuse_factorization: true }
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
    pub(super) mass: Vec<Matrix6<f64>>,
    /// True acceleration `vdot` at the current state.
    pub acceleration: DVector<f64>,
    /// Generalized-alpha pseudo-acceleration `a`.
    pub pseudo_acceleration: DVector<f64>,
    pub(super) ws: Workspace,
    /// The explicit integrator's joint projection on the dense backend (`JointSchur`).
    pub(super) schur: JointSchur,
    /// Stage buffers of the Runge-Kutta integrators.
    pub(super) explicit: ExplicitBuffers,
    /// Per body: the largest distance of its points from its origin (at least 1 mm), m; a
    /// rotation error times this is a point error.
    pub(super) reach: Vec<f64>,
    pub(super) trial: State,
    pub(super) rhs: DVector<f64>,
    pub(super) residual: DVector<f64>,
    pub(super) kkt: KktSystem,
    /// `(beta', gamma')` of the generalized-alpha matrix whose factors `kkt` holds.
    pub(super) factored_for: Option<(f64, f64)>,
    /// The last step needed `SLOW_STEP_ITERATIONS` or more iterations on reused factors: the
    /// next step starts with fresh ones.
    pub(super) refresh: bool,
    /// `ws` holds the evaluation of the state the last step committed.
    pub(super) final_evaluation: bool,
    /// The acceleration before the last generalized-alpha step, and that step's size (`None`
    /// after a restart): the central difference of the error estimate.
    pub(super) previous_acceleration: DVector<f64>,
    pub(super) previous_step: Option<f64>,
    /// The largest jerk envelope times lever of the recent attempts, decaying by
    /// `ENVELOPE_HOLD` per accepted step (m/s^3; 0 after a restart).
    pub(super) held_envelope: f64,
    /// The largest `jerk_decay_rate` of the error-controlled steps so far, 1/s
    /// (`damped_mode_relief`).
    pub(super) largest_decay_rate: f64,
    /// The jerk of the last generalized-alpha attempt (scratch of `jerk_decay_rate`).
    pub(super) jerk: DVector<f64>,
    /// The three accelerations of the error estimate projected onto the joints' tangent space
    /// (scratch of generalized-alpha under error control with joints).
    pub(super) tangent_accelerations: [DVector<f64>; 3],
    // generalized-alpha iterates, preallocated so that a step never allocates
    pub(super) vdot: DVector<f64>,
    pub(super) a_next: DVector<f64>,
    pub(super) v: DVector<f64>,
    pub(super) delta: DVector<f64>,
    pub(super) lambda: DVector<f64>,
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

/// Constant mass matrix of `model` (dense, kg and kg m^2): block diagonal, plus the members'
/// consistent-mass corrections (`crate::model::MassCoupling`) if any.
pub fn mass_matrix(model: &Model) -> DMatrix<f64> {
    let mut m = DMatrix::zeros(model.dof_count, model.dof_count);
    for (b, body) in model.bodies.iter().enumerate() {
        add_block(model, BodyId(b), BodyId(b), &body.mass_matrix(), 1.0, &mut m);
    }
    model.for_each_mass_coupling_block(|a, b, blk| add_block(model, a, b, blk, 1.0, &mut m));
    m
}

/// `d(Phi_q)/dt v` by a central difference of `Phi_q v` along `v` (m/s^2), the velocity-squared
/// term of the constraint acceleration; zero without joints.
pub(super) fn constraint_curvature(model: &Model, state: &State, ws: &mut Workspace) -> DVector<f64> {
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
        evaluate_rates(model, &s.poses, &state.velocities, &ws.points, &mut rates);
        out.axpy(sign / (2.0 * eps), &rates, 1.0);
    }
    out
}

pub(super) fn force_scale(model: &Model, ws: &Workspace, inertial: f64) -> f64 {
    let weight = model.bodies.iter().map(|b| b.mass * model.gravity.norm()).fold(0.0, f64::max);
    let tension = ws.cables.iter().map(|c| c.tension.abs()).fold(0.0, f64::max);
    weight.max(tension).max(inertial).max(1e-9)
}

pub(super) fn force_floor(model: &Model, ws: &Workspace) -> f64 {
    model
        .cables
        .iter()
        .zip(&ws.cables)
        .map(|(m, c)| 64.0 * f64::EPSILON * m.axial_stiffness * c.length / c.rest_length)
        .fold(0.0, f64::max)
}

pub(super) fn all_finite(v: &DVector<f64>) -> bool {
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
            explicit: ExplicitBuffers::new(model, n + model.constraint_count),
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
            tangent_accelerations: [DVector::zeros(n), DVector::zeros(n), DVector::zeros(n)],
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

    /// `out = M x` with the block-diagonal mass matrix and the members' consistent-mass
    /// corrections, if any (no `n x n` product).
    pub(crate) fn mass_times(&self, model: &Model, x: &DVector<f64>, out: &mut DVector<f64>) {
        for (body, m) in model.bodies.iter().zip(&self.mass) {
            let (o, k) = (body.dof_offset, body.dof_count);
            if k == 0 {
                continue;
            }
            // a fixed-size product on the zero-padded slice (the block past k is zero): 3 x 3
            // for nodes and planar bodies, 6 x 6 otherwise
            let (xs, outs) = (&x.as_slice()[o..o + k], &mut out.as_mut_slice()[o..o + k]);
            if k <= 3 {
                let mut xb = Vector3::zeros();
                xb.iter_mut().zip(xs).for_each(|(d, s)| *d = *s);
                let yb = m.fixed_view::<3, 3>(0, 0) * xb;
                outs.iter_mut().zip(yb.iter()).for_each(|(d, s)| *d = *s);
            } else {
                let mut xb = Vector6::zeros();
                xb.iter_mut().zip(xs).for_each(|(d, s)| *d = *s);
                let yb = m * xb;
                outs.iter_mut().zip(yb.iter()).for_each(|(d, s)| *d = *s);
            }
        }
        if !model.mass_couplings.is_empty() {
            add_coupled_mass_times(model, x, out);
        }
    }

    /// True when the explicit integrators solve `[M, Phi_q^T; Phi_q, 0]` through the joints'
    /// Schur complement (`JointSchur`, per-body mass inverses): the dense backend with a
    /// block-diagonal mass matrix. Consistent member masses couple bodies, and take the
    /// `KktSystem`'s factorization instead.
    pub(crate) fn uses_joint_schur(&self, model: &Model) -> bool {
        self.kkt.backend() == LinearBackend::Dense && model.mass_couplings.is_empty()
    }

    /// Starts the matrix `[M, Phi_q^T; Phi_q, 0]` (bordered rows `dT = 0`) at the point
    /// kinematics in the workspace.
    pub(crate) fn assemble_mass_and_joints(&mut self, model: &Model) {
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
                let tableau = if integrator == Integrator::Rk4 { &tableaus::RK4 } else { &tableaus::DOPRI5 };
                // the local errors of a run add up to a few times each one's: aim lower
                let tolerance = tolerance.map(tableaus::local_tolerance);
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
}

/// `out += dM x`, the members' consistent-mass corrections (`Model::add_mass_coupling_times`),
/// kept out of line: `Dynamics::mass_times` of a scene with lumped mass only never runs it.
#[cold]
#[inline(never)]
pub(super) fn add_coupled_mass_times(model: &Model, x: &DVector<f64>, out: &mut DVector<f64>) {
    model.add_mass_coupling_times(x.as_slice(), 1.0, out.as_mut_slice());
}

/// Per body: the largest distance of its points from its origin, at least 1 mm (m).
pub(super) fn body_reach(model: &Model) -> Vec<f64> {
    let mut reach = vec![1e-3f64; model.bodies.len()];
    for p in &model.points {
        reach[p.body.0] = reach[p.body.0].max(p.local.norm());
    }
    reach
}

/// Zeroes `kkt` and adds `[M, Phi_q^T; Phi_q, 0]`: the body mass blocks `mass` (one 6 x 6 per
/// body, `BodyModel::mass_matrix`), the members' consistent-mass corrections if any, and the
/// joint Jacobian rows at the point kinematics in `ws`.
pub fn assemble_mass_and_joints(model: &Model, ws: &Workspace, mass: &[Matrix6<f64>], kkt: &mut KktSystem) {
    kkt.clear();
    for (b, m) in mass.iter().enumerate() {
        kkt.add_body_block(BodyId(b), BodyId(b), m, 1.0);
    }
    model.for_each_mass_coupling_block(|a, b, blk| kkt.add_body_block(a, b, blk, 1.0));
    kkt.add_joints(model, &ws.poses, &ws.points);
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
        Integrator::Rk4 => tableaus::RK4_STABILITY_RADIUS,
        Integrator::DormandPrince => tableaus::DOPRI5_STABILITY_RADIUS,
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
/// eigenvalue of the mass-normalized damping matrix there (1/s), with every cable counted as
/// taut (`taut_stiffness_model`): a cable that starts slack or just taut (a rope at zero tension)
/// has no stiffness yet, but it will have `EA / L0` as soon as it stretches, and a step above
/// the limit that stiffness sets diverges then. Likewise every contact sphere counts as pressed
/// into every ground (`forces::contact::add_contact_bounds`) and every strut pair as touching
/// (`forces::collision::add_collision_bounds`). `(0, 0)` without coordinates or freedom;
/// `(inf, inf)` when the mass matrix there is singular.
pub fn spectral_bounds(model: &Model, state: &State) -> (f64, f64) {
    let Some((m, k, c)) = reduced_linearization(model, state) else { return (0.0, 0.0) };
    // symmetric form L^-1 K L^-T with M = L L^T
    let f = m.ncols();
    let Some(chol) = m.cholesky() else { return (f64::INFINITY, f64::INFINITY) };
    let l_inv = chol.l().try_inverse().unwrap_or_else(|| DMatrix::identity(f, f));
    let w2 = SymmetricEigen::new(&l_inv * k * l_inv.transpose()).eigenvalues.max().max(0.0);
    let c_max = SymmetricEigen::new(&l_inv * c * l_inv.transpose()).eigenvalues.max().max(0.0);
    (w2.sqrt(), c_max)
}

/// The linearized system at `state` on the directions the joints allow, as `spectral_bounds`
/// takes it (every cable taut, every contact pressed in, every strut pair touching): `(Z^T M Z,
/// Z^T K_sym Z, Z^T C_sym Z)` with `Z` a null-space basis of `Phi_q`. `None` without
/// coordinates or freedom.
pub(super) fn reduced_linearization(
    model: &Model,
    state: &State,
) -> Option<(DMatrix<f64>, DMatrix<f64>, DMatrix<f64>)> {
    let n = model.dof_count;
    if n == 0 {
        return None;
    }
    let mut ws = Workspace::new(model);
    evaluate(model, state, &mut ws, Tangents::None);
    let (taut_model, taut_state) = taut_stiffness_model(model, state, &ws);
    let (model, state) = (&taut_model, &taut_state);
    evaluate(model, state, &mut ws, Tangents::StiffnessAndDamping);
    crate::forces::contact::add_contact_bounds(
        model,
        &state.poses,
        &ws.points,
        &mut ws.stiffness,
        &mut ws.damping,
    );
    crate::forces::collision::add_collision_bounds(model, &ws.points, &mut ws.stiffness, &mut ws.damping);
    let z = crate::constraints::null_space(&ws.constraint_jacobian, n)?;
    let m = z.transpose() * mass_matrix(model) * &z;
    let k = z.transpose() * ((&ws.stiffness + ws.stiffness.transpose()) * 0.5) * &z;
    let c = z.transpose() * ((&ws.damping + ws.damping.transpose()) * 0.5) * &z;
    Some((m, k, c))
}

/// `|R(z)|` of an explicit Runge-Kutta method's stability polynomial: RK4's
/// `sum_{k<=4} z^k / k!`, Dormand-Prince's (propagated fifth-order solution)
/// `sum_{k<=5} z^k / k! + z^6 / 600`. 0 for the other integrators (no region).
pub(super) fn stability_polynomial_modulus(integrator: Integrator, z: nalgebra::Complex<f64>) -> f64 {
    let (order, sixth) = match integrator {
        Integrator::Rk4 => (4, 0.0),
        Integrator::DormandPrince => (5, 1.0 / 600.0),
        _ => return 0.0,
    };
    let mut term = nalgebra::Complex::new(1.0, 0.0);
    let mut sum = term;
    for k in 1..=order {
        term = term * z / k as f64;
        sum += term;
    }
    (sum + z.powi(6) * sixth).norm()
}

/// Largest step at which every eigenvalue `mu` of the linearized first-order system at `state`
/// (`[[0, I], [-M^-1 K, -M^-1 C]]` on the directions the joints allow, taken as
/// `spectral_bounds` takes it: every cable taut, every contact pressed in) has `h mu` inside the
/// Runge-Kutta method's stability region, `|R(h mu)| <= 1` (bisection along each eigenvalue's
/// ray), s. Sharper than `explicit_stability_limit`'s half-disk for damped modes, whose
/// eigenvalues lie left of the imaginary axis where the regions reach further (Dormand-Prince's
/// to about 3.3 along the negative real axis; prism3's cable damping gives 2.7 times the
/// half-disk limit); on the imaginary axis, an undamped mode's, RK4's region reaches 2.83 and
/// Dormand-Prince's about 0.99, as its half-disk. Infinite for the other integrators, without
/// freedom or stiffness; the half-disk limit when the mass matrix there is singular.
pub fn stability_region_limit(model: &Model, state: &State, integrator: Integrator) -> f64 {
    if !matches!(integrator, Integrator::Rk4 | Integrator::DormandPrince) {
        return f64::INFINITY;
    }
    let Some((m, k, c)) = reduced_linearization(model, state) else { return f64::INFINITY };
    let f = m.ncols();
    let Some(chol) = m.cholesky() else { return explicit_stability_limit(model, state, integrator) };
    let mut a = DMatrix::zeros(2 * f, 2 * f);
    a.view_mut((0, f), (f, f)).fill_with_identity();
    a.view_mut((f, 0), (f, f)).copy_from(&(-chol.solve(&k)));
    a.view_mut((f, f), (f, f)).copy_from(&(-chol.solve(&c)));
    let mut limit = f64::INFINITY;
    for mu in a.complex_eigenvalues().iter() {
        // a growing mode (an unstable equilibrium) is taken as decaying at the same rate: no
        // step is stable for it, but one that resolves its rate is what accuracy needs
        let mu = nalgebra::Complex::new(-mu.re.abs(), mu.im);
        let modulus = mu.norm();
        if !modulus.is_finite() {
            return explicit_stability_limit(model, state, integrator);
        }
        if modulus < 1e-12 {
            continue;
        }
        // both regions lie within |z| < 6
        let (mut inside, mut outside) = (0.0, 6.0 / modulus);
        for _ in 0..60 {
            let h = 0.5 * (inside + outside);
            if stability_polynomial_modulus(integrator, mu * h) <= 1.0 + 1e-12 {
                inside = h;
            } else {
                outside = h;
            }
        }
        limit = limit.min(inside);
    }
    limit
}

/// `model` and `state` with every slack or just-taut cable (`L <= L0`, lengths from `ws`
/// evaluated at `state`; members, which have their stiffness at every length, are left)
/// made taut by a part in 1e9 with its material stiffness kept: rest length
/// `L0' = L (1 - 1e-9)` and `EA' = EA L0' / L0`, so `EA'/L0' = EA/L0` and its tension is about
/// zero. Taut cables are left as they are. For stability limits (`spectral_bounds`).
pub fn taut_stiffness_model(model: &Model, state: &State, ws: &Workspace) -> (Model, State) {
    let mut taut_model = model.clone();
    let mut taut_state = state.clone();
    for (c, response) in ws.cables.iter().enumerate() {
        let l0 = state.rest_lengths[c];
        if model.cables[c].tension_only && response.length <= l0 && response.length > 0.0 {
            let shorter = response.length * (1.0 - 1e-9);
            taut_model.cables[c].axial_stiffness *= shorter / l0;
            taut_state.rest_lengths[c] = shorter;
        }
    }
    (taut_model, taut_state)
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

/// `cable_powers`' share of the cables with pulley friction (`crate::forces::pulley::powers`),
/// kept out of line: scenes without friction never run it.
#[cold]
#[inline(never)]
pub(super) fn friction_cable_powers(model: &Model, ws: &Workspace, rest_rate: &[f64]) -> (f64, f64) {
    let (mut actuator, mut loss) = (0.0, 0.0);
    for f in &model.pulley_friction {
        let (a, l) = crate::forces::pulley::powers(model, &ws.friction, f, rest_rate[f.cable.0]);
        actuator += a;
        loss += l;
    }
    (actuator, loss)
}

/// Power flows at one instant (W): actuator power into the cables, and power lost in the cable
/// dampers, the contacts (normal damping and friction), the joints' rotational damping and
/// Rayleigh's mass-proportional damping (see `EnergyAccount`).
pub fn cable_powers(model: &Model, ws: &Workspace, rest_rate: &[f64]) -> (f64, f64) {
    let mut actuator = 0.0;
    // Rayleigh's alpha M dissipates alpha v^T M v = 2 alpha (kinetic energy)
    let mut loss =
        ws.contact_loss_power + ws.joint_loss_power + 2.0 * model.rayleigh.alpha * ws.energies.kinetic;
    if !model.pulley_friction.is_empty() {
        let (a, l) = friction_cable_powers(model, ws, rest_rate);
        actuator += a;
        loss += l;
    }
    for (c, r) in ws.cables.iter().enumerate() {
        if model.cables[c].friction.is_some() {
            continue; // booked above
        }
        if r.slack || (model.cables[c].tension_only && r.length <= r.rest_length) {
            continue; // a member works in compression too
        }
        let cable = &model.cables[c];
        let t_el = crate::forces::cable::elastic_force(cable, r.rest_length, r.length);
        // only actuated cables change their rest length
        if rest_rate[c] != 0.0 {
            let rest_force =
                crate::forces::cable::elastic_energy_rest_derivative(cable, r.rest_length, r.length);
            actuator += rest_force * rest_rate[c];
        }
        loss += (r.tension - t_el) * r.length_rate;
    }
    (actuator, loss)
}
