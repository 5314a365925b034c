//! The human leg from Winter's anthropometric tables (MODEL.md §2, paper eq. 2).

use super::Link;
use crate::check::{self, InvalidField, Range};
#[cfg(not(feature = "std"))]
use crate::math::Float;
use serde::{Deserialize, Serialize};

/// One human leg segment as Winter's fractions (MODEL.md §2 table): of body mass, of height,
/// COM from the proximal joint and radius of gyration about the COM (both fractions of the
/// segment length). The scenario's `[human.thigh]` / `[human.shank]` tables.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HumanSegment {
    /// Segment mass as a fraction of body mass (-), in (0, 1].
    pub mass_fraction: f64,
    /// Segment length as a fraction of body height (-), in (0, 1].
    pub length_fraction: f64,
    /// Distance of the COM from the proximal joint as a fraction of the segment length (-), in (0, 1].
    pub com_fraction: f64,
    /// Radius of gyration about the COM as a fraction of the segment length (-), in (0, 1].
    pub gyration_fraction: f64,
}

impl HumanSegment {
    /// Winter's thigh: mass 0.100 m_b, length 0.245 H, COM 0.433 l, gyration 0.323 l (MODEL.md §2).
    pub const WINTER_THIGH: Self = Self {
        mass_fraction: 0.100,
        length_fraction: 0.245,
        com_fraction: 0.433,
        gyration_fraction: 0.323,
    };
    /// Winter's shank + foot: mass 0.061 m_b, length 0.246 H, COM 0.606 l, gyration 0.416 l (MODEL.md §2).
    pub const WINTER_SHANK: Self = Self {
        mass_fraction: 0.061,
        length_fraction: 0.246,
        com_fraction: 0.606,
        gyration_fraction: 0.416,
    };

    /// The segment's link for body mass `body_mass` (kg) and height `height` (m):
    /// `m = f_m m_b`, `l = f_l h`, `c = f_c l`, `I = m (f_ρ l)²` (MODEL.md §2).
    pub fn link(&self, body_mass: f64, height: f64) -> Link {
        let mass = self.mass_fraction * body_mass;
        let length = self.length_fraction * height;
        Link {
            length,
            mass,
            com: self.com_fraction * length,
            inertia: mass * (self.gyration_fraction * length).powi(2),
        }
    }

    /// Checks that every fraction is finite and in (0, 1]; the error names the key
    /// (`mass_fraction`, ...).
    pub fn validate(&self) -> Result<(), InvalidField> {
        let f = Range::OpenClosed(0.0, 1.0);
        check::reals(&[
            ("mass_fraction", self.mass_fraction, f),
            ("length_fraction", self.length_fraction, f),
            ("com_fraction", self.com_fraction, f),
            ("gyration_fraction", self.gyration_fraction, f),
        ])
    }
}
