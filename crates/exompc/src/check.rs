//! Range checks shared by the settings types' `validate()` methods (model links and segments,
//! estimator, monitors, faults, uncertainties, gait): one error type, [`InvalidField`], naming
//! the key inside its own table, so the scenario layer ([`crate::config`]) only prefixes the
//! table path (`mass_kg` → `robot.thigh.mass_kg`).

use alloc::{format, string::String, string::ToString};
use core::fmt;

/// A setting outside its allowed range; `field` is the key inside its own table
/// (`hip_amplitude`, `events[0].start_s`), so a scenario layer can prefix its table path
/// (`trajectory.hip_amplitude`, `faults.events[0].start_s`).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("invalid value for {field}: {value} (allowed: {allowed})")]
pub struct InvalidField {
    /// Key of the field within its table, e.g. `hip_amplitude`.
    pub field: String,
    /// The offending value as text.
    pub value: String,
    /// What is allowed, e.g. `finite, >= 0`.
    pub allowed: String,
}

impl InvalidField {
    /// The error for `field` holding `value`, which should have satisfied `allowed`.
    pub fn new(field: &str, value: impl fmt::Display, allowed: impl Into<String>) -> Self {
        InvalidField {
            field: field.into(),
            value: value.to_string(),
            allowed: allowed.into(),
        }
    }

    /// The same error with its key inside the table `prefix` (`start_s` in `events[0]` →
    /// `events[0].start_s`).
    pub fn within(mut self, prefix: &str) -> Self {
        self.field = format!("{prefix}.{}", self.field);
        self
    }
}

/// Allowed range of a real setting (every variant also requires the value to be finite).
#[derive(Debug, Clone, Copy)]
#[cfg_attr(not(feature = "std"), allow(dead_code))] // some ranges are the std-only layers'
pub(crate) enum Range {
    /// Any finite value.
    Any,
    /// `> 0`.
    Pos,
    /// `>= 0`.
    NonNeg,
    /// `[a, b]`.
    Closed(f64, f64),
    /// `(a, b]`.
    OpenClosed(f64, f64),
    /// `(a, b)`.
    Open(f64, f64),
    /// `[a, b)`.
    ClosedOpen(f64, f64),
}

impl Range {
    /// Whether `v` is finite and inside the range.
    pub(crate) fn contains(self, v: f64) -> bool {
        v.is_finite()
            && match self {
                Range::Any => true,
                Range::Pos => v > 0.0,
                Range::NonNeg => v >= 0.0,
                Range::Closed(a, b) => a <= v && v <= b,
                Range::OpenClosed(a, b) => a < v && v <= b,
                Range::Open(a, b) => a < v && v < b,
                Range::ClosedOpen(a, b) => a <= v && v < b,
            }
    }

    /// The range as the error messages state it, e.g. `finite, in (0, 1]`.
    pub(crate) fn describe(self) -> String {
        match self {
            Range::Any => "finite".into(),
            Range::Pos => "finite, > 0".into(),
            Range::NonNeg => "finite, >= 0".into(),
            Range::Closed(a, b) => format!("finite, in [{a}, {b}]"),
            Range::OpenClosed(a, b) => format!("finite, in ({a}, {b}]"),
            Range::Open(a, b) => format!("finite, in ({a}, {b})"),
            Range::ClosedOpen(a, b) => format!("finite, in [{a}, {b})"),
        }
    }
}

/// Checks a real value against a range, naming `field` on failure.
pub(crate) fn real(field: &str, v: f64, r: Range) -> Result<(), InvalidField> {
    if r.contains(v) {
        Ok(())
    } else {
        Err(InvalidField::new(field, v, r.describe()))
    }
}

/// Checks an integer value against the inclusive range `lo..=hi`.
pub(crate) fn int(field: &str, v: usize, lo: usize, hi: usize) -> Result<(), InvalidField> {
    if (lo..=hi).contains(&v) {
        Ok(())
    } else {
        Err(InvalidField::new(
            field,
            v,
            format!("integer in {lo}..={hi}"),
        ))
    }
}

/// Checks a list of `(field, value, range)` triples in order; the first failure is returned.
pub(crate) fn reals(items: &[(&str, f64, Range)]) -> Result<(), InvalidField> {
    items.iter().try_for_each(|&(f, v, r)| real(f, v, r))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ranges_accept_their_ends_as_stated_and_reject_non_finite_values() {
        let cases = [
            (Range::Closed(0.0, 1.0), [true, true], "finite, in [0, 1]"),
            (
                Range::OpenClosed(0.0, 1.0),
                [false, true],
                "finite, in (0, 1]",
            ),
            (Range::Open(0.0, 1.0), [false, false], "finite, in (0, 1)"),
            (
                Range::ClosedOpen(0.0, 1.0),
                [true, false],
                "finite, in [0, 1)",
            ),
        ];
        for (r, [lo, hi], text) in cases {
            assert_eq!(r.contains(0.0), lo, "{text}");
            assert_eq!(r.contains(1.0), hi, "{text}");
            assert!(
                r.contains(0.5) && !r.contains(-0.5) && !r.contains(1.5),
                "{text}"
            );
            assert!(!r.contains(f64::NAN), "{text}");
            assert_eq!(r.describe(), text);
        }
        assert!(Range::Any.contains(-1e300) && !Range::Any.contains(f64::INFINITY));
        assert!(Range::NonNeg.contains(0.0) && !Range::Pos.contains(0.0));
        let e = real("mass_kg", -1.0, Range::Pos)
            .unwrap_err()
            .within("robot.thigh");
        assert_eq!(
            e.to_string(),
            "invalid value for robot.thigh.mass_kg: -1 (allowed: finite, > 0)"
        );
        assert_eq!(int("n", 0, 1, 5).unwrap_err().allowed, "integer in 1..=5");
        assert!(int("n", 5, 1, 5).is_ok());
    }
}
