//! What the simulator is told and what it tells: `SimSettings` (step, integrator, Newton,
//! tolerance), `StepStats` (what one step cost) and `StepError` (why a step could not be taken).

use std::time::Duration;

use crate::error::readable_number;
use crate::solve::dynamics::{Integrator, NewtonSettings, NEWTON_TOLERANCE_RANGE};
use crate::solve::linear::LinearBackend;

/// How the simulator steps.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SimSettings {
    /// Physics step, s.
    pub dt: f64,
    /// Integrator.
    pub integrator: Integrator,
    /// Newton settings of the implicit integrator.
    pub newton: NewtonSettings,
    /// Smallest sub-step a rejected step may be cut to, s.
    pub min_dt: f64,
    /// Factorization of the Newton systems.
    pub linear: LinearBackend,
    /// Local error tolerance, m (`None`: fixed steps). With a tolerance, `dt` is the output
    /// interval: each `step` reaches `t + dt` exactly in sub-steps whose size the integrator's
    /// local error estimate chooses (generalized-alpha and Dormand-Prince only).
    pub tolerance: Option<f64>,
}

/// The physics step when neither the caller nor the scene (`physics_dt`) gives one, s.
pub const DEFAULT_PHYSICS_DT: f64 = 1e-3;

impl Default for SimSettings {
    fn default() -> Self {
        Self {
            dt: DEFAULT_PHYSICS_DT,
            integrator: Integrator::GeneralizedAlpha { rho_inf: 0.8 },
            newton: NewtonSettings::default(),
            min_dt: 1e-9,
            linear: LinearBackend::Auto,
            tolerance: None,
        }
    }
}

/// A dynamic run's options as a user gives them (the command line's `--integrator`, `--dt`,
/// `--rho-inf`, `--tol`, `--newton-tol`; the Python library's keywords of the same names):
/// checked into `SimSettings` by `DynamicOptions::settings`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DynamicOptions {
    /// Integrator (its spectral radius, if generalized-alpha, comes from `rho_inf`).
    pub integrator: Integrator,
    /// Physics step, s (`None`: the scene's `physics_dt`, else `DEFAULT_PHYSICS_DT`).
    pub dt: Option<f64>,
    /// Spectral radius at infinity of generalized-alpha, in [0, 1] (default 0.8).
    pub rho_inf: f64,
    /// Local error tolerance per step, m (`None`: fixed steps).
    pub tolerance: Option<f64>,
    /// Newton tolerance relative to the forces, in `NEWTON_TOLERANCE_RANGE` (`None`: 1e-9).
    pub newton_tolerance: Option<f64>,
}

impl Default for DynamicOptions {
    fn default() -> Self {
        Self {
            integrator: Integrator::GeneralizedAlpha { rho_inf: 0.8 },
            dt: None,
            rho_inf: 0.8,
            tolerance: None,
            newton_tolerance: None,
        }
    }
}

impl DynamicOptions {
    /// The settings these options give for a scene whose `physics_dt` is `scene_dt`, or the
    /// reason one is out of range, naming the option as `name` spells it (`name("rho_inf")` is
    /// `--rho-inf` on the command line, `rho_inf` in Python).
    pub fn settings(
        &self,
        scene_dt: Option<f64>,
        name: impl Fn(&str) -> String,
    ) -> Result<SimSettings, String> {
        let dt = self.dt.or(scene_dt).unwrap_or(DEFAULT_PHYSICS_DT);
        if !(self.rho_inf.is_finite() && (0.0..=1.0).contains(&self.rho_inf)) {
            return Err(format!(
                "{} must be in [0, 1], got {}",
                name("rho_inf"),
                readable_number(self.rho_inf)
            ));
        }
        let dt = checked_dt(&name("dt"), dt)?;
        if let Some(tol) = self.tolerance {
            if !(tol.is_finite() && tol > 0.0) {
                return Err(format!("{} must be positive, got {tol}", name("tol")));
            }
        }
        let integrator = match self.integrator {
            Integrator::GeneralizedAlpha { .. } => Integrator::GeneralizedAlpha { rho_inf: self.rho_inf },
            other => other,
        };
        let newton = checked_newton(&name("newton_tol"), self.newton_tolerance)?;
        Ok(SimSettings { dt, integrator, tolerance: self.tolerance, newton, ..Default::default() })
    }
}

/// `dt` when it lies in the physics step range every part accepts (scene `physics_dt`, the node's
/// parameter, the command line, Python: `scene::limits::PHYSICS_DT`), else the reason naming
/// `option`.
pub fn checked_dt(option: &str, dt: f64) -> Result<f64, String> {
    let (lo, hi) = crate::scene::limits::PHYSICS_DT;
    if dt.is_finite() && (lo..=hi).contains(&dt) {
        Ok(dt)
    } else {
        Err(format!(
            "{option} must be in [{}, {}] s (the physics step range of scenes and the node), got {}",
            readable_number(lo),
            readable_number(hi),
            readable_number(dt)
        ))
    }
}

/// The Newton settings for a relative Newton tolerance `tolerance` (default 1e-9) when it lies
/// in `NEWTON_TOLERANCE_RANGE`, else the reason naming `option`.
pub fn checked_newton(option: &str, tolerance: Option<f64>) -> Result<NewtonSettings, String> {
    let mut newton = NewtonSettings::default();
    if let Some(t) = tolerance {
        let (lo, hi) = NEWTON_TOLERANCE_RANGE;
        if !(t.is_finite() && (lo..=hi).contains(&t)) {
            return Err(format!(
                "{option} must be in [{}, {}] (relative to the forces), got {}",
                readable_number(lo),
                readable_number(hi),
                readable_number(t)
            ));
        }
        newton.tolerance = t;
    }
    Ok(newton)
}

/// What one call to `Simulator::step` cost.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct StepStats {
    /// Newton iterations over all accepted sub-steps.
    pub newton_iterations: usize,
    /// Newton-matrix factorizations over all accepted sub-steps (fewer than the iterations when
    /// `NewtonSettings::reuse_factorization` reuses older factors).
    pub factorizations: usize,
    /// Largest final Newton residual of the accepted sub-steps, N.
    pub residual: f64,
    /// Rejected attempts (each followed by a halved retry).
    pub rejected: usize,
    /// Accepted sub-steps (1 when nothing was rejected and the step is fixed).
    pub substeps: usize,
    /// Force evaluations over all attempts.
    pub evaluations: usize,
    /// Largest local error estimate of the accepted sub-steps, m (0 without an estimate).
    pub error: f64,
    /// Sub-steps accepted at the smallest error-controlled step (`MIN_CONTROLLED_STEP` of the
    /// interval) without meeting the tolerance: where the motion jumps (a cable goes slack).
    pub forced: usize,
    /// Sub-steps undone and retried in halves because one bar passed through another
    /// (`[collisions]`: the side one axis passes the other on flipped within the sub-step).
    pub pass_throughs: usize,
    /// Wall-clock time spent in the step.
    pub wall_time: Duration,
}

/// Why a step could not be taken. The state is left at the last accepted step.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum StepError {
    /// Even the smallest allowed sub-step failed.
    #[error(
        "step failed at t = {time} s: sub-step cut to {dt:.3e} s (minimum {min_dt:.3e} s) without convergence; last residual {residual:.3e} N"
    )]
    StepTooSmall {
        /// Time of the last accepted state, s.
        time: f64,
        /// The sub-step that failed, s.
        dt: f64,
        /// The minimum sub-step, s.
        min_dt: f64,
        /// Residual of the last attempt (NaN if it diverged).
        residual: f64,
    },
    /// A bar passed through another within even the smallest allowed sub-step.
    #[error(
        "bar '{first}' passed through bar '{second}' at t = {time} s within a sub-step of {dt:.3e} s (the smallest allowed): stiffen [collisions] or give the bars larger contact_radius"
    )]
    PassThrough {
        /// The first bar of the pair.
        first: String,
        /// The second bar.
        second: String,
        /// Time of the last accepted state, s.
        time: f64,
        /// The sub-step that let it through, s.
        dt: f64,
    },
    /// Consistent initial accelerations could not be computed (singular mass/constraint system).
    #[error("cannot start the dynamics: the mass and constraint matrix is singular or not finite")]
    Initialization,
    /// The step size is not positive and finite.
    #[error("invalid step size {0} s")]
    InvalidStep(f64),
    /// The explicit integrator would be unstable at this step size.
    #[error(
        "{integrator} is unstable at dt = {dt:.3e} s: its stability limit here is {limit:.3e} s{cause}; use a smaller step, an error tolerance (dormand-prince) or generalized-alpha"
    )]
    UnstableExplicitStep {
        /// The integrator's name.
        integrator: String,
        /// Requested step, s.
        dt: f64,
        /// Stability limit at the initial state, s.
        limit: f64,
        /// What sets the limit when it is not the cables: `" (set by the ground contact's
        /// stiffness and stuck friction: X s without contact)"`, else empty.
        cause: String,
    },
    /// An explicit integrator's run diverged although its step was below the stability limit at
    /// the start (the structure stiffened since): the energy it made up is far above any the
    /// run was given. The state is left as it was before the step.
    #[error(
        "{integrator} diverged at t = {time} s: the step made up {gain:.3e} J of energy, against {scale:.3e} J the run holds; use a smaller step, an error tolerance (dormand-prince) or generalized-alpha"
    )]
    Diverged {
        /// The integrator's name.
        integrator: String,
        /// Time of the last good state, s.
        time: f64,
        /// Energy the run has made up (`-EnergyAccount::numerical_loss`), J.
        gain: f64,
        /// The run's energy scale (`Guards::arm`), J.
        scale: f64,
    },
    /// A run asked to start from the static equilibrium (`Simulator::at_equilibrium`), and
    /// statics found none from the scene's pose.
    #[error(
        "no static equilibrium to start from: the residual is {residual:.3e} N after {iterations} Newton iterations from the scene's pose (start from the scene's pose instead, or see `tensegrity statics`)"
    )]
    NoEquilibrium {
        /// Newton iterations taken.
        iterations: usize,
        /// Residual at the end, N.
        residual: f64,
    },
    /// An error tolerance was given to an explicit integrator in a scene with contacts: its error
    /// estimate measures positions, and through an impact (milliseconds in which the velocity
    /// turns over while the position hardly moves) it lets the rebound velocity go wrong
    /// (Dormand-Prince at 1 mm came off a bouncing ball's reference by 43 mm, `tests/contact.rs`).
    #[error("{integrator} cannot take a tolerance in a scene with ground contact (its error estimate does not see the velocity jumps of impacts); use generalized-alpha, whose error control resolves impacts, or a fixed step")]
    ToleranceWithContact {
        /// The integrator's name.
        integrator: String,
    },
    /// An error tolerance was given to an integrator that cannot estimate its error.
    #[error("{integrator} has no error estimate, so it cannot take a tolerance; use generalized-alpha or dormand-prince, or a fixed step")]
    ToleranceNotSupported {
        /// The integrator's name.
        integrator: String,
    },
    /// The tolerance is not positive and finite.
    #[error("invalid error tolerance {0} m")]
    InvalidTolerance(f64),
    /// The model has no free coordinate (every body is fixed): there is nothing to simulate.
    #[error("nothing to move: every body is fixed (the scene has no free coordinate)")]
    NothingToMove,
}
