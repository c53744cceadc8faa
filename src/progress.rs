//! Progress of long work: takes what solvers and studies report as they go (`report`: a count,
//! its total when known, a residual), gives it to the one observer a front end installs
//! (`observe`), such as the command line's progress bar. Without an observer a report costs one
//! relaxed atomic load; nothing the physics computes depends on it.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::RwLock;

/// One report of long work.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Report {
    /// What is counted, plural: `"Newton iterations"` (a static solve), `"load steps"` (a
    /// quasi-static path), `"runs"` (a study's or a benchmark's), `"steps"` (a timed run).
    pub unit: &'static str,
    /// Done so far.
    pub done: u64,
    /// Of how many, when known.
    pub total: Option<u64>,
    /// The latest force residual, N, where the work is a solve.
    pub residual_n: Option<f64>,
}

type Observer = Box<dyn Fn(&Report) + Send + Sync>;

static OBSERVED: AtomicBool = AtomicBool::new(false);
static OBSERVER: RwLock<Option<Observer>> = RwLock::new(None);

/// Makes `f` the observer of every later `report`, from any thread (one at a time: it replaces
/// the one before). `f` must be quick: it runs on the reporting thread.
pub fn observe(f: impl Fn(&Report) + Send + Sync + 'static) {
    if let Ok(mut slot) = OBSERVER.write() {
        *slot = Some(Box::new(f));
        OBSERVED.store(true, Ordering::Release);
    }
}

/// Removes the observer: later reports go nowhere.
pub fn stop_observing() {
    OBSERVED.store(false, Ordering::Release);
    if let Ok(mut slot) = OBSERVER.write() {
        *slot = None;
    }
}

/// Gives `r` to the observer, if one is installed.
pub fn report(r: Report) {
    if !OBSERVED.load(Ordering::Relaxed) {
        return;
    }
    if let Ok(slot) = OBSERVER.read() {
        if let Some(f) = slot.as_ref() {
            f(&r);
        }
    }
}
