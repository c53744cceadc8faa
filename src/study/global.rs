//! Global error control: takes a way to run a scene at a local error tolerance and sample its
//! points, gives the run whose estimated global error meets the tolerance asked for.
//!
//! A local estimate controls the error each step makes, not what the motion does with it: a run
//! through an unstable equilibrium (a robot tipping over an edge) amplifies whatever error it
//! carries there, about tenfold on the bundled six-bar, at every tolerance alike. Under error
//! control the global error is proportional to the local tolerance (tolerance proportionality),
//! so two runs whose tolerances differ tenfold measure it: the looser run's error is about the
//! largest distance between the two, and the tighter run's a tenth of that.

use nalgebra::Vector3;

use super::{rigidly_aligned, RunTotals};

/// Each refinement runs again at this fraction of the last local tolerance.
pub const REFINEMENT: f64 = 0.1;

/// Runs at most (the first included) before global error control gives up.
pub const MAX_GLOBAL_RUNS: usize = 4;

/// Positions of every point at each sample time, m.
pub type PointSamples = Vec<Vec<Vector3<f64>>>;

/// The run taken by `globally_controlled` and what it cost.
#[derive(Debug, Clone, PartialEq)]
pub struct GlobalRun {
    /// The global tolerance asked for, m.
    pub requested: f64,
    /// The local tolerance of the run taken, m.
    pub tolerance: f64,
    /// Its estimated global error, m: `REFINEMENT` times the previous run's error, measured
    /// against the run taken (largest point distance over the samples).
    pub estimate: f64,
    /// Runs made (at least 2).
    pub runs: usize,
    /// The samples of the run taken.
    pub samples: PointSamples,
    /// Steps and iterations of every run made, summed.
    pub totals: RunTotals,
}

/// The largest distance of any point between two sample series of the same run length, m; for
/// a structure held by nothing (`free`), after aligning `a` rigidly onto `b` at each sample.
pub fn largest_distance(a: &PointSamples, b: &PointSamples, free: bool) -> f64 {
    a.iter()
        .zip(b)
        .flat_map(|(x, y)| {
            let x = if free { rigidly_aligned(x, y) } else { x.clone() };
            x.iter().zip(y).map(|(p, q)| (p - q).norm()).collect::<Vec<_>>()
        })
        .fold(0.0, f64::max)
}

/// Finds the run whose estimated global error is at most `requested` (m): runs `run_at(tol)`
/// at `tol_0 = requested`, then each time at `REFINEMENT` times the last, and takes the run at
/// `tol_{k+1}` once `REFINEMENT * d_k <= requested`, `d_k` the largest point distance between the
/// runs at `tol_k` and `tol_{k+1}` (the error of the run at `tol_k`). A scene whose local control
/// already meets the tolerance costs two runs; the bundled six-bar's roll, three. Errors when
/// `MAX_GLOBAL_RUNS` runs do not meet it (tolerances below the integrator's floor stop helping),
/// or when a run fails.
pub fn globally_controlled(
    requested: f64,
    free: bool,
    mut run_at: impl FnMut(f64) -> Result<(PointSamples, RunTotals), String>,
) -> Result<GlobalRun, String> {
    if !(requested.is_finite() && requested > 0.0) {
        return Err(format!("a global tolerance must be positive, got {requested}"));
    }
    let mut tolerance = requested;
    let (mut samples, mut totals) = run_at(tolerance)?;
    let mut runs = 1;
    loop {
        let finer = tolerance * REFINEMENT;
        let (next, more) = run_at(finer)?;
        runs += 1;
        totals.add_totals(&more);
        let estimate = REFINEMENT * largest_distance(&samples, &next, free);
        (tolerance, samples) = (finer, next);
        if estimate <= requested {
            return Ok(GlobalRun { requested, tolerance, estimate, runs, samples, totals });
        }
        if runs == MAX_GLOBAL_RUNS {
            return Err(format!(
                "global error control: the run at local tolerance {tolerance:e} m is still estimated {estimate:.3e} m off, above the {requested:e} m asked for, after {runs} runs"
            ));
        }
    }
}
