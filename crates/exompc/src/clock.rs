//! Without `std` there is no clock (docs/EMBEDDED.md): this `Instant` reads zero elapsed time,
//! so a solve is bounded by its iteration limits only (its `max_time` is not checked) and
//! recorded step times are zero; the firmware measures a step's cost itself. With `std` the
//! library uses `std::time::Instant`.

use core::time::Duration;

/// A point in time that never advances (module docs).
#[derive(Clone, Copy, Debug)]
pub(crate) struct Instant;

impl Instant {
    /// Now.
    pub(crate) fn now() -> Self {
        Instant
    }
    /// Time since `self`: always zero.
    pub(crate) fn elapsed(&self) -> Duration {
        Duration::ZERO
    }
}
