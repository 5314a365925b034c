//! The clock without `std` (docs/EMBEDDED.md): a counter the firmware supplies with
//! [`set_clock`]. Until it does, time stands still (zero elapsed time: a solve is bounded by
//! its iteration limits only, recorded step times are zero). With a clock, `SqpSettings::max_time`
//! applies and the closed loop records each control step's time; the solver's and the EKF
//! bank's share of each step add up in [`take_parts`]. With `std` the library uses
//! `std::time::Instant` and none of this exists.

use core::sync::atomic::{AtomicU32, AtomicUsize, Ordering};
use core::time::Duration;

/// The firmware's `fn() -> u64` (nanoseconds), as an address; 0 when none is set.
static NOW: AtomicUsize = AtomicUsize::new(0);
static SOLVER_NS: AtomicU32 = AtomicU32::new(0);
static EKF_BANK_NS: AtomicU32 = AtomicU32::new(0);

/// Sets the clock: `now_ns` returns a monotonic time in nanoseconds.
pub fn set_clock(now_ns: fn() -> u64) {
    NOW.store(now_ns as usize, Ordering::Relaxed);
}

fn now_ns() -> u64 {
    match NOW.load(Ordering::Relaxed) {
        0 => 0,
        f => {
            // SAFETY: a non-zero value was stored from a `fn() -> u64` by `set_clock`.
            let f: fn() -> u64 = unsafe { core::mem::transmute::<usize, fn() -> u64>(f) };
            f()
        }
    }
}

/// The time spent since the last call in SQP solves and in EKF bank updates, in nanoseconds
/// of the clock (saturating at `u32::MAX`); resets both.
pub fn take_parts() -> (u32, u32) {
    (
        SOLVER_NS.swap(0, Ordering::Relaxed),
        EKF_BANK_NS.swap(0, Ordering::Relaxed),
    )
}

/// A part of the control step whose time [`take_parts`] reports.
#[derive(Clone, Copy, Debug)]
pub(crate) enum Part {
    /// One SQP solve.
    Solver,
    /// The EKF bank's update.
    EkfBank,
}

/// Adds `d` to the time of `part`.
pub(crate) fn account(part: Part, d: Duration) {
    let ns = u32::try_from(d.as_nanos()).unwrap_or(u32::MAX);
    let acc = match part {
        Part::Solver => &SOLVER_NS,
        Part::EkfBank => &EKF_BANK_NS,
    };
    let _ = acc.fetch_update(Ordering::Relaxed, Ordering::Relaxed, |v| {
        Some(v.saturating_add(ns))
    });
}

/// A point in time of the firmware's clock (module docs).
#[derive(Clone, Copy, Debug)]
pub(crate) struct Instant(u64);

impl Instant {
    /// Now.
    pub(crate) fn now() -> Self {
        Instant(now_ns())
    }
    /// Time since `self` (zero without a clock).
    pub(crate) fn elapsed(&self) -> Duration {
        Duration::from_nanos(now_ns().saturating_sub(self.0))
    }
}
