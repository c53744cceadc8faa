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
//! **Semi-implicit (symplectic) Euler**: `v_(n+1) = v_n + h M^-1 (Q(q_n, v_n, t_n) - gyro - Phi_q^T lambda)`
//! with the constraints imposed on the new velocity (`Phi_q v_(n+1) = -Phi(q_n) / h`, which also
//! removes position drift), then `q_(n+1) = q_n exp(h v_(n+1))`. First order, cheap, explicit in
//! the forces; stable only for `h < 2 / omega_max` (`omega_max` the highest natural frequency of
//! the linearized system, see `stability_limit`); stiff or damped cables shrink that limit.

use nalgebra::{DMatrix, DVector, Matrix3, Matrix6, SymmetricEigen, Vector3, Vector6};

use crate::constraints::add_multiplier_hessian;
use crate::forces::cable::{add_block, add_vector};
use crate::forces::{evaluate, Tangents, Workspace};
use crate::model::{BodyId, BodyKind, Model};
use crate::solve::linear::{LinearBackend, LinearSolver};
use crate::state::{retract, State};

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
}

impl Integrator {
    /// Parses `generalized-alpha` / `ga` or `symplectic-euler` / `euler`.
    pub fn parse(name: &str, rho_inf: f64) -> Option<Self> {
        match name {
            "generalized-alpha" | "ga" => Some(Integrator::GeneralizedAlpha { rho_inf }),
            "symplectic-euler" | "euler" => Some(Integrator::SymplecticEuler),
            _ => None,
        }
    }
    /// Short name for tables.
    pub fn name(&self) -> String {
        match self {
            Integrator::GeneralizedAlpha { rho_inf } => format!("generalized-alpha(rho={rho_inf})"),
            Integrator::SymplecticEuler => "symplectic-euler".into(),
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
}

impl Default for NewtonSettings {
    fn default() -> Self {
        Self { tolerance: 1e-9, max_iterations: 15 }
    }
}

/// What one successful step attempt cost.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct AttemptStats {
    /// Newton iterations (0 for the explicit integrator).
    pub iterations: usize,
    /// Final residual max-norm, N.
    pub residual: f64,
}

/// Integrator memory and preallocated buffers for one model.
#[derive(Debug, Clone)]
pub struct Dynamics {
    /// Constant mass matrix (dense, block diagonal).
    pub mass: DMatrix<f64>,
    /// True acceleration `vdot` at the current state.
    pub acceleration: DVector<f64>,
    /// Generalized-alpha pseudo-acceleration `a`.
    pub pseudo_acceleration: DVector<f64>,
    ws: Workspace,
    trial: State,
    matrix: DMatrix<f64>,
    rhs: DVector<f64>,
    residual: DVector<f64>,
    hessian: DMatrix<f64>,
    linear: LinearSolver,
    // generalized-alpha iterates, preallocated so that a step never allocates
    vdot: DVector<f64>,
    a_next: DVector<f64>,
    v: DVector<f64>,
    delta: DVector<f64>,
    lambda: DVector<f64>,
}

/// Gyroscopic generalized force `B^T [0; w x J w]` of rigid bodies, added into `out`, and its
/// velocity derivative `B^T [[0,0],[0, [w]x J - [J w]x]] B` added into `c_out` when given.
pub fn add_gyroscopic(
    model: &Model,
    v: &DVector<f64>,
    out: &mut DVector<f64>,
    mut c_out: Option<&mut DMatrix<f64>>,
) {
    for (b, body) in model.bodies.iter().enumerate() {
        if body.kind != BodyKind::Rigid {
            continue;
        }
        let local = body.local_increment(v.as_slice(), 1.0);
        let w = Vector3::new(local[3], local[4], local[5]);
        let jw = body.inertia * w;
        let t = w.cross(&jw);
        add_vector(
            model,
            BodyId(b),
            &(body.basis.transpose() * Vector6::new(0.0, 0.0, 0.0, t.x, t.y, t.z)),
            1.0,
            out,
        );
        if let Some(c) = c_out.as_deref_mut() {
            let d: Matrix3<f64> = w.cross_matrix() * body.inertia - jw.cross_matrix();
            let mut d6 = Matrix6::zeros();
            d6.fixed_view_mut::<3, 3>(3, 3).copy_from(&d);
            add_block(model, BodyId(b), BodyId(b), &(body.basis.transpose() * d6 * body.basis), 1.0, c);
        }
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
    for (sign, scale) in [(1.0, eps), (-1.0, -eps)] {
        s.poses.copy_from_slice(&state.poses);
        retract(model, &mut s.poses, &state.velocities, scale);
        evaluate(model, &s, ws, Tangents::None);
        out += &ws.constraint_jacobian * &state.velocities * (sign / (2.0 * eps));
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
        let size = n + model.constraint_count;
        Self {
            mass: mass_matrix(model),
            acceleration: DVector::zeros(n),
            pseudo_acceleration: DVector::zeros(n),
            ws: Workspace::new(model),
            trial: State::initial(model),
            matrix: DMatrix::zeros(size, size),
            rhs: DVector::zeros(size),
            residual: DVector::zeros(n),
            hessian: DMatrix::zeros(n, n),
            linear: LinearSolver::new(model, backend),
            vdot: DVector::zeros(n),
            a_next: DVector::zeros(n),
            v: DVector::zeros(n),
            delta: DVector::zeros(n),
            lambda: DVector::zeros(model.constraint_count),
        }
    }

    /// The linear-solver backend in use (dense or sparse).
    pub fn linear_backend(&self) -> LinearBackend {
        self.linear.backend()
    }

    /// Sets consistent accelerations and reactions at `state` (solves
    /// `[M Phi_q^T; Phi_q 0][vdot; lambda] = [Q - gyro; -dPhi_q/dt v]`), and `a = vdot`.
    pub fn initialize(&mut self, model: &Model, state: &mut State) -> bool {
        let n = model.dof_count;
        let nc = model.constraint_count;
        let curvature = constraint_curvature(model, state, &mut self.ws);
        evaluate(model, state, &mut self.ws, Tangents::None);
        let mut gyro = DVector::zeros(n);
        add_gyroscopic(model, &state.velocities, &mut gyro, None);
        let f = &self.ws.force - gyro;
        self.matrix.fill(0.0);
        self.matrix.view_mut((0, 0), (n, n)).copy_from(&self.mass);
        if nc > 0 {
            self.matrix.view_mut((0, n), (n, nc)).copy_from(&self.ws.constraint_jacobian.transpose());
            self.matrix.view_mut((n, 0), (nc, n)).copy_from(&self.ws.constraint_jacobian);
        }
        self.rhs.rows_mut(0, n).copy_from(&f);
        if nc > 0 {
            self.rhs.rows_mut(n, nc).copy_from(&(-curvature));
        }
        let mut x = self.rhs.clone();
        if !self.linear.solve(&self.matrix, &mut x) {
            return false;
        }
        self.acceleration.copy_from(&x.rows(0, n));
        self.pseudo_acceleration.copy_from(&self.acceleration);
        state.multipliers.copy_from(&x.rows(n, nc));
        true
    }

    /// One step of size `h` with rest lengths `rest_next` at the new time. On success writes the
    /// new state into `state` (and the accelerations here) and returns the attempt's statistics;
    /// on failure leaves everything unchanged and returns `None`.
    pub fn step(
        &mut self,
        model: &Model,
        integrator: Integrator,
        newton: &NewtonSettings,
        state: &mut State,
        rest_now: &[f64],
        rest_next: &[f64],
        h: f64,
    ) -> Option<AttemptStats> {
        match integrator {
            Integrator::GeneralizedAlpha { rho_inf } => {
                self.generalized_alpha(model, AlphaCoefficients::new(rho_inf), newton, state, rest_next, h)
            }
            Integrator::SymplecticEuler => self.symplectic_euler(model, state, rest_now, rest_next, h),
        }
    }

    fn generalized_alpha(
        &mut self,
        model: &Model,
        c: AlphaCoefficients,
        newton: &NewtonSettings,
        state: &mut State,
        rest_next: &[f64],
        h: f64,
    ) -> Option<AttemptStats> {
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
        for iter in 0..=newton.max_iterations {
            self.trial.poses.copy_from_slice(&state.poses);
            retract(model, &mut self.trial.poses, &self.delta, 1.0);
            self.trial.velocities.copy_from(&self.v);
            self.trial.multipliers.copy_from(&self.lambda);
            evaluate(model, &self.trial, &mut self.ws, Tangents::StiffnessAndDamping);

            // residual r = M vdot + gyro - Q + Phi_q^T lambda
            self.mass.mul_to(&self.vdot, &mut self.residual);
            let inertial = self.residual.amax();
            add_gyroscopic(model, &self.v, &mut self.residual, Some(&mut self.ws.damping));
            self.residual -= &self.ws.force;
            if nc > 0 {
                self.residual.gemv_tr(1.0, &self.ws.constraint_jacobian, &self.lambda, 1.0);
            }
            if !all_finite(&self.residual) {
                return None;
            }
            let r_norm = self.residual.amax();
            let phi_norm = if nc > 0 { self.ws.constraint.amax() } else { 0.0 };
            let scale = force_scale(model, &self.ws, inertial);
            let length_scale = self.ws.cables.iter().map(|c| c.length).fold(1e-3, f64::max);
            stats = AttemptStats { iterations: iter, residual: r_norm };
            if r_norm <= (newton.tolerance * scale).max(force_floor(model, &self.ws))
                && phi_norm <= 1e-12 * length_scale
            {
                break;
            }
            if iter == newton.max_iterations {
                return None;
            }
            // [S / beta', Phi_q^T; Phi_q, 0] [d delta; d lambda / beta'] = [-r / beta'; -Phi]
            if nc > 0 {
                self.hessian.fill(0.0);
                add_multiplier_hessian(model, &self.trial.poses, &self.lambda, &mut self.hessian);
            }
            for j in 0..n {
                for i in 0..n {
                    let mut a = self.mass[(i, j)]
                        + (gamma_p * self.ws.damping[(i, j)] + self.ws.stiffness[(i, j)]) / beta_p;
                    if nc > 0 {
                        a += self.hessian[(i, j)] / beta_p;
                    }
                    self.matrix[(i, j)] = a;
                }
                self.rhs[j] = -self.residual[j] / beta_p;
            }
            self.fill_constraint_border(n, nc, 1.0);
            if !self.linear.solve(&self.matrix, &mut self.rhs) {
                return None;
            }
            let dd = self.rhs.rows(0, n);
            self.delta += dd;
            self.v.axpy(gamma_p, &dd, 1.0);
            self.vdot.axpy(beta_p, &dd, 1.0);
            if nc > 0 {
                self.lambda.axpy(beta_p, &self.rhs.rows(n, nc), 1.0);
            }
        }
        // commit
        self.update_pseudo_acceleration(&c);
        state.poses.copy_from_slice(&self.trial.poses);
        state.velocities.copy_from(&self.v);
        state.multipliers.copy_from(&self.lambda);
        state.rest_lengths.copy_from_slice(rest_next);
        state.time = self.trial.time;
        self.acceleration.copy_from(&self.vdot);
        self.pseudo_acceleration.copy_from(&self.a_next);
        Some(stats)
    }

    /// Writes the KKT border `[., Phi_q^T; Phi_q, 0]` into the matrix and `-Phi * phi_scale` into
    /// the constraint rows of the right-hand side.
    fn fill_constraint_border(&mut self, n: usize, nc: usize, phi_scale: f64) {
        for r in 0..nc {
            for j in 0..n {
                let g = self.ws.constraint_jacobian[(r, j)];
                self.matrix[(n + r, j)] = g;
                self.matrix[(j, n + r)] = g;
            }
            for q in 0..nc {
                self.matrix[(n + r, n + q)] = 0.0;
            }
            self.rhs[n + r] = -self.ws.constraint[r] * phi_scale;
        }
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
        evaluate(model, &self.trial, &mut self.ws, Tangents::None);
        // f = Q - gyro (in `residual`), M v_n (in `vdot`)
        self.v.fill(0.0);
        add_gyroscopic(model, &state.velocities, &mut self.v, None);
        self.residual.copy_from(&self.ws.force);
        self.residual -= &self.v;
        self.mass.mul_to(&state.velocities, &mut self.vdot);
        // [M Phi_q^T; Phi_q 0] [v+; h lambda] = [M v + h f; -Phi / h]
        for j in 0..n {
            for i in 0..n {
                self.matrix[(i, j)] = self.mass[(i, j)];
            }
            self.rhs[j] = self.vdot[j] + h * self.residual[j];
        }
        self.fill_constraint_border(n, nc, 1.0 / h);
        if !self.linear.solve(&self.matrix, &mut self.rhs) {
            return None;
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
        Some(AttemptStats { iterations: 0, residual: 0.0 })
    }
}

/// Largest stable step of the symplectic Euler integrator at `state`: `2 / omega_max`, with
/// `omega_max^2` the largest eigenvalue of `M^-1 K` on the directions the joints allow
/// (`Z^T K Z x = w^2 Z^T M Z x`, `Z` a null-space basis of `Phi_q`), reduced for cable damping:
/// for a damped mode the explicit limit is `h < 2 / (omega (sqrt(1 + z^2) + z))`, `z = c/(2 omega)`
/// with `c` the largest eigenvalue of the mass-normalized damping matrix. Infinite without
/// stiffness and damping.
pub fn stability_limit(model: &Model, state: &State) -> f64 {
    let n = model.dof_count;
    if n == 0 {
        return f64::INFINITY;
    }
    let mut ws = Workspace::new(model);
    evaluate(model, state, &mut ws, Tangents::StiffnessAndDamping);
    let Some(z) = crate::constraints::null_space(&ws.constraint_jacobian, n) else { return f64::INFINITY };
    let m = z.transpose() * mass_matrix(model) * &z;
    let k = z.transpose() * ((&ws.stiffness + ws.stiffness.transpose()) * 0.5) * &z;
    let c = z.transpose() * ((&ws.damping + ws.damping.transpose()) * 0.5) * &z;
    // symmetric form L^-1 K L^-T with M = L L^T
    let Some(chol) = m.cholesky() else { return 0.0 };
    let l_inv = chol.l().try_inverse().unwrap_or_else(|| DMatrix::identity(z.ncols(), z.ncols()));
    let w2 = SymmetricEigen::new(&l_inv * k * l_inv.transpose()).eigenvalues.max().max(0.0);
    let c_max = SymmetricEigen::new(&l_inv * c * l_inv.transpose()).eigenvalues.max().max(0.0);
    let w = w2.sqrt();
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
