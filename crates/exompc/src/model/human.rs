//! The human leg from Winter's anthropometric tables (MODEL.md §2, paper eq. 2).

use super::Link;
use serde::{Deserialize, Serialize};

/// Winter's segment fractions (MODEL.md §2): of body mass, of height, COM from the proximal joint
/// (fraction of segment length), radius of gyration about the COM (fraction of segment length).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct WinterFractions {
    /// Segment mass / body mass.
    pub mass: f64,
    /// Segment length / body height.
    pub length: f64,
    /// COM distance from proximal joint / segment length.
    pub com: f64,
    /// Radius of gyration about the COM / segment length.
    pub gyration: f64,
}

/// The two human leg segments of MODEL.md §2.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum HumanSegment {
    /// Thigh: 0.100 m_b, 0.245 h, COM 0.433 l, gyration 0.323 l.
    Thigh,
    /// Shank and foot: 0.061 m_b, 0.246 h, COM 0.606 l, gyration 0.416 l.
    Shank,
}

impl HumanSegment {
    /// Winter's fractions of this segment (MODEL.md §2 table).
    pub fn fractions(self) -> WinterFractions {
        match self {
            HumanSegment::Thigh => WinterFractions {
                mass: 0.100,
                length: 0.245,
                com: 0.433,
                gyration: 0.323,
            },
            HumanSegment::Shank => WinterFractions {
                mass: 0.061,
                length: 0.246,
                com: 0.606,
                gyration: 0.416,
            },
        }
    }
}

impl WinterFractions {
    /// The segment's link for body mass `body_mass` (kg) and height `height` (m):
    /// `m = f_m m_b`, `l = f_l h`, `c = f_c l`, `I = m (f_ρ l)²` (MODEL.md §2).
    pub fn link(&self, body_mass: f64, height: f64) -> Link {
        let mass = self.mass * body_mass;
        let length = self.length * height;
        Link {
            length,
            mass,
            com: self.com * length,
            inertia: mass * (self.gyration * length).powi(2),
        }
    }
}
