//! Clocks, absolute-time schedules and timing statistics of a periodic loop.

use serde::Serialize;
use std::time::{Duration, Instant};

/// A monotonic clock the periodic loops run on; a test clock makes them testable without
/// sockets or real sleeping.
pub trait Clock {
    /// Time since the clock's epoch.
    fn now(&self) -> Duration;
    /// Sleep until `t` (return at once if `t` has passed).
    fn sleep_until(&mut self, t: Duration);
}

/// The OS monotonic clock (`Instant`), epoch at construction. `sleep_until` sleeps to within
/// `spin` of the target and busy-waits the rest (0 to only sleep).
#[derive(Clone, Copy, Debug)]
pub struct MonotonicClock {
    epoch: Instant,
    spin: Duration,
}

impl MonotonicClock {
    /// A clock starting now, busy-waiting the last `spin` of every sleep.
    pub fn new(spin: Duration) -> Self {
        MonotonicClock {
            epoch: Instant::now(),
            spin,
        }
    }

    /// The `Instant` of clock time `t`.
    pub fn instant(&self, t: Duration) -> Instant {
        self.epoch + t
    }
}

impl Clock for MonotonicClock {
    fn now(&self) -> Duration {
        self.epoch.elapsed()
    }

    fn sleep_until(&mut self, t: Duration) {
        let target = self.epoch + t;
        loop {
            let now = Instant::now();
            if now >= target {
                return;
            }
            let left = target - now;
            if left > self.spin {
                std::thread::sleep(left - self.spin);
            } else {
                std::hint::spin_loop();
            }
        }
    }
}

/// Absolute-time deadlines `T_k = T_0 + k·dt` (no drift: a late wake-up does not shift the
/// following deadlines). `T_0` may be nudged by [`Schedule::shift`] to follow a peer's clock.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Schedule {
    /// `T_0` (clock time).
    pub start: Duration,
    /// Period.
    pub dt: Duration,
}

impl Schedule {
    /// Deadline of period `k`.
    pub fn deadline(&self, k: u64) -> Duration {
        self.start + self.dt.mul_f64(k as f64)
    }

    /// Move `T_0` by `by_ns` nanoseconds (negative: earlier; saturating at 0).
    pub fn shift(&mut self, by_ns: i64) {
        let s = self.start.as_nanos() as i64 + by_ns;
        self.start = Duration::from_nanos(s.max(0) as u64);
    }
}

/// Percentiles of a set of samples.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct Percentiles {
    /// Median.
    pub p50: f64,
    /// 99th percentile.
    pub p99: f64,
    /// Maximum.
    pub max: f64,
    /// Mean.
    pub mean: f64,
}

impl Percentiles {
    /// Percentiles of `v` (sorted in place; zeros when empty).
    pub fn of(v: &mut [f64]) -> Self {
        if v.is_empty() {
            return Self::default();
        }
        v.sort_by(f64::total_cmp);
        let n = v.len();
        let pct = |p: f64| v[((p * (n - 1) as f64).round() as usize).min(n - 1)];
        Percentiles {
            p50: pct(0.5),
            p99: pct(0.99),
            max: v[n - 1],
            mean: v.iter().sum::<f64>() / n as f64,
        }
    }
}

/// Timing record of a periodic loop: wake-up error against the absolute deadline, compute
/// time, and the period's total busy time; deadline misses (busy past the next deadline).
#[derive(Clone, Debug, Default)]
pub struct TimingStats {
    wake_error_us: Vec<f64>,
    compute_us: Vec<f64>,
    /// Periods whose work ended after the next period's deadline.
    pub deadline_misses: u64,
    /// Periods recorded.
    pub periods: u64,
}

/// Summary of [`TimingStats`] (µs).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct TimingSummary {
    /// Periods recorded.
    pub periods: u64,
    /// Wake-up time minus the absolute deadline (µs): the period error.
    pub period_error_us: Percentiles,
    /// Work time per period, receive excluded (µs).
    pub compute_us: Percentiles,
    /// Periods whose work ended after the next deadline.
    pub deadline_misses: u64,
}

impl TimingStats {
    /// Room for `periods` periods without reallocating.
    pub fn with_capacity(periods: usize) -> Self {
        TimingStats {
            wake_error_us: Vec::with_capacity(periods),
            compute_us: Vec::with_capacity(periods),
            ..Default::default()
        }
    }

    /// Record one period: wake-up error and compute time (µs), and whether the work ended past
    /// the next deadline.
    pub fn record(&mut self, wake_error_us: f64, compute_us: f64, missed: bool) {
        self.wake_error_us.push(wake_error_us);
        self.compute_us.push(compute_us);
        self.deadline_misses += u64::from(missed);
        self.periods += 1;
    }

    /// The latest `window` wake errors' percentiles (for live display).
    pub fn recent(&self, window: usize) -> Percentiles {
        let from = self.wake_error_us.len().saturating_sub(window);
        let mut v = self.wake_error_us[from..].to_vec();
        Percentiles::of(&mut v)
    }

    /// The latest `window` busy times' percentiles (for live display).
    pub fn recent_busy(&self, window: usize) -> Percentiles {
        let from = self.compute_us.len().saturating_sub(window);
        let mut v = self.compute_us[from..].to_vec();
        Percentiles::of(&mut v)
    }

    /// Summary over all periods.
    pub fn summary(&self) -> TimingSummary {
        TimingSummary {
            periods: self.periods,
            period_error_us: Percentiles::of(&mut self.wake_error_us.clone()),
            compute_us: Percentiles::of(&mut self.compute_us.clone()),
            deadline_misses: self.deadline_misses,
        }
    }
}

/// A clock for tests: time moves only when `sleep_until` or [`TestClock::advance`] is called.
#[derive(Clone, Copy, Debug, Default)]
pub struct TestClock {
    /// Current time.
    pub now: Duration,
}

impl TestClock {
    /// Move time forward by `d`.
    pub fn advance(&mut self, d: Duration) {
        self.now += d;
    }
}

impl Clock for TestClock {
    fn now(&self) -> Duration {
        self.now
    }
    fn sleep_until(&mut self, t: Duration) {
        self.now = self.now.max(t);
    }
}
