//! What this machine gives a real-time loop: takes a period and a duration, gives how late a
//! thread sleeping to each period's deadline wakes (`timer_lateness`, the node's loop without
//! its step, what `cyclictest` measures) and how long a thread that never sleeps is kept off
//! its core (`run_stalls`: time the hypervisor or other work takes). A node's step that ends
//! more than one period late counts as an overrun, so a machine whose figures here reach a
//! period has overruns whatever the physics costs.

use std::time::{Duration, Instant};

/// Order statistics of a set of durations, s.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DurationQuantiles {
    /// Median.
    pub p50: f64,
    /// 99th percentile.
    pub p99: f64,
    /// Largest.
    pub max: f64,
}

impl DurationQuantiles {
    /// Quantiles of `values` (s); all zero when empty.
    pub fn of(mut values: Vec<f64>) -> Self {
        if values.is_empty() {
            return Self { p50: 0.0, p99: 0.0, max: 0.0 };
        }
        values.sort_by(f64::total_cmp);
        let at = |q: f64| values[((values.len() - 1) as f64 * q).round() as usize];
        Self { p50: at(0.5), p99: at(0.99), max: values[values.len() - 1] }
    }
}

/// How late a loop sleeping to fixed deadlines woke.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TimerLateness {
    /// Deadlines slept to.
    pub wakeups: u64,
    /// Wake-up time minus deadline, s.
    pub lateness: DurationQuantiles,
    /// Wake-ups later than one period: each would be an overrun of a node whose step took no
    /// time at all.
    pub later_than_period: u64,
}

/// Sleeps to the deadlines `period` apart for `duration` (each deadline from the start, like
/// the node's real-time pacing; a wake-up later than the next deadline re-anchors, like the
/// node, instead of bursting) and measures each wake-up's lateness.
///
/// Preconditions: `period` > 0.
pub fn timer_lateness(period: Duration, duration: Duration) -> TimerLateness {
    assert!(!period.is_zero(), "period must be positive");
    let start = Instant::now();
    let mut anchor = start;
    let mut k: u32 = 0;
    let mut late = Vec::with_capacity((duration.as_secs_f64() / period.as_secs_f64()) as usize + 1);
    let mut later_than_period = 0;
    while start.elapsed() < duration {
        k += 1;
        let due = anchor + period * k;
        if let Some(wait) = due.checked_duration_since(Instant::now()) {
            std::thread::sleep(wait);
        }
        let woke = Instant::now();
        let lateness = woke.saturating_duration_since(due);
        late.push(lateness.as_secs_f64());
        if lateness > period {
            later_than_period += 1;
            anchor = woke;
            k = 0;
        }
    }
    TimerLateness { wakeups: late.len() as u64, lateness: DurationQuantiles::of(late), later_than_period }
}

/// How long a thread that never sleeps was kept from running.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RunStalls {
    /// Gaps between consecutive clock readings longer than `RunStalls::THRESHOLD`.
    pub over_threshold: u64,
    /// Gaps longer than the period given to `run_stalls`.
    pub over_period: u64,
    /// Longest gap, s.
    pub longest: f64,
}

impl RunStalls {
    /// Shortest gap between two readings of the clock that counts as a stall: far above the
    /// loop's own time per reading (tens of nanoseconds).
    pub const THRESHOLD: Duration = Duration::from_micros(100);
}

/// Reads the clock in a tight loop for `duration` and counts the gaps between readings: the
/// times the thread was not running although it never asked to wait. Under a real-time
/// scheduling policy this includes the kernel's real-time throttling
/// (`/proc/sys/kernel/sched_rt_runtime_us`, by default 50 ms of every second taken from such a
/// thread), which a node asleep between its steps never meets.
///
/// Preconditions: `period` > 0.
pub fn run_stalls(period: Duration, duration: Duration) -> RunStalls {
    let start = Instant::now();
    let mut last = start;
    let mut stalls = RunStalls { over_threshold: 0, over_period: 0, longest: 0.0 };
    while last - start < duration {
        let now = Instant::now();
        let gap = now - last;
        if gap > RunStalls::THRESHOLD {
            stalls.over_threshold += 1;
        }
        if gap > period {
            stalls.over_period += 1;
        }
        stalls.longest = stalls.longest.max(gap.as_secs_f64());
        last = now;
    }
    stalls
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quantiles_of_known_values() {
        let q = DurationQuantiles::of((1..=101).rev().map(f64::from).collect());
        assert_eq!(q, DurationQuantiles { p50: 51.0, p99: 100.0, max: 101.0 });
        assert_eq!(DurationQuantiles::of(Vec::new()), DurationQuantiles { p50: 0.0, p99: 0.0, max: 0.0 });
    }

    #[test]
    fn a_sleeping_loop_wakes_once_per_period_and_never_early() {
        let period = Duration::from_millis(2);
        let t = timer_lateness(period, Duration::from_millis(40));
        // 20 deadlines, fewer when wake-ups came more than a period late and re-anchored
        assert!((1..=21).contains(&t.wakeups), "{t:?}");
        let q = t.lateness;
        assert!(0.0 <= q.p50 && q.p50 <= q.p99 && q.p99 <= q.max, "{t:?}");
        assert!(t.later_than_period <= t.wakeups);
    }

    #[test]
    fn stalls_longer_than_a_period_are_also_longer_than_the_threshold() {
        let s = run_stalls(Duration::from_micros(500), Duration::from_millis(20));
        assert!(s.over_period <= s.over_threshold, "{s:?}");
        assert!(s.longest.is_finite() && s.longest > 0.0, "{s:?}");
    }
}
