//! The integrators by name: takes a name (`generalized-alpha`, `rk4`, ...), gives an
//! `Integrator` and what each one is (explicit or implicit, its order, whether it estimates its
//! error).

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
