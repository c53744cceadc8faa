//! The backtracking line search both Newton forms of the static solver share: takes the Newton
//! step's largest allowed fraction, the merits at the start and a trial function, gives the
//! fraction of the step to take.

/// Where a line search starts from.
#[derive(Debug, Clone, Copy)]
pub(crate) struct LineSearch {
    /// The largest fraction of the step (`StaticSolver::step_limit`), tried first.
    pub limit: f64,
    /// The residual merit at the start (`Residual::merit`).
    pub merit0: f64,
    /// The energy merit at the start: potential energy plus a joint-violation penalty, J.
    pub energy0: f64,
    /// Whether the step is a descent step of the energy (a convexity-shifted tangent): accepted
    /// only when the energy falls. A Newton step is accepted when it lowers the residual norm
    /// (Armijo, `merit <= (1 - 1e-4 alpha) merit0`) or the energy.
    pub energy_mode: bool,
}

/// What a line search found.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Searched {
    /// The fraction of the step to take.
    pub alpha: f64,
    /// Whether a trial decreased (`LineSearch::energy_mode`); else `alpha` is the best of the 12.
    pub decreased: bool,
}

/// Trials at `alpha = limit, limit/2, ...` (12 at most): `trial(alpha)` sets the trial state and
/// gives its residual merit and energy merit. Stops at the first trial that decreases (see
/// `LineSearch::energy_mode`) and gives the fraction of the best finite trial so far (by the
/// merit the mode compares); `None` when no trial was finite.
pub(crate) fn line_search(search: &LineSearch, mut trial: impl FnMut(f64) -> (f64, f64)) -> Option<Searched> {
    let mut alpha = search.limit;
    let mut best = (f64::INFINITY, alpha);
    let mut decreased = false;
    for _ in 0..12 {
        let (residual_merit, energy) = trial(alpha);
        let value = if search.energy_mode { energy } else { residual_merit };
        if value.is_finite() && value < best.0 {
            best = (value, alpha);
        }
        // a Newton step on a positive-definite tangent is a descent step of the energy too: far
        // from the solution the energy tells progress better than the residual (a cable swung
        // about its anchor stretches on the tangent line), near it the residual does (the
        // energy's decrease drowns in round-off)
        decreased = value.is_finite()
            && if search.energy_mode {
                value < search.energy0
            } else {
                value <= (1.0 - 1e-4 * alpha) * search.merit0 || energy < search.energy0
            };
        if decreased {
            break;
        }
        alpha *= 0.5;
    }
    best.0.is_finite().then_some(Searched { alpha: best.1, decreased })
}
