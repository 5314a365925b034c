//! The whole simulation / control scenario as plain serde structs.
//!
//! [`Scenario::default()`] is the embedded default scenario: every value is the one stated in
//! the repository's `docs/MODEL.md` (section numbers "§n" below refer to it) or by the paper
//! (Aliyari & Vossoughi, equation numbers "eq. N" refer to it). A configuration file
//! (TOML in the CLI, but any serde format works) overrides only what it names: every struct is
//! `#[serde(default)]`, and the thigh/shank sub-tables are merged field by field onto their own
//! defaults. Unknown keys are rejected (`#[serde(deny_unknown_fields)]`).
//!
//! Deserialisation checks only types; [`Scenario::validate`] checks every numeric value (finite
//! and inside a documented range) and reports the first offending field by its dotted path.
//!
//! Units are SI throughout (m, kg, s, rad, N, N·m).

use serde::{Deserialize, Deserializer, Serialize};
use std::fmt;

mod keys;
pub mod scenarios;
pub use keys::{explain, Allowed, End, KeyDoc, Limit, KEYS};

// ---------------------------------------------------------------------------------------------
// Error
// ---------------------------------------------------------------------------------------------

/// A configuration value outside its allowed range.
///
/// Displays as `invalid value for robot.thigh.mass_kg: -1 (allowed: finite, > 0)`; when the
/// range comes from another key (a cross-field rule), the message names that key too:
/// `invalid value for straps.ls1_m: 0.28 (allowed: finite, in (0, 0.2]): must be <=
/// robot.thigh.length_m = 0.2 (the thigh strap sits on the robot's thigh link)`.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("invalid value for {field}: {value} (allowed: {allowed}){}", self.depends_on.as_ref().map_or(String::new(), |d| format!(": {d}")))]
pub struct ConfigError {
    /// Dotted path of the field, e.g. `robot.thigh.mass_kg` or `faults.events[0].start_s`.
    pub field: String,
    /// The offending value as text (e.g. `-1`, `NaN`, `[]`).
    pub value: String,
    /// Human-readable description of the allowed values, e.g. `finite, > 0`.
    pub allowed: String,
    /// For a cross-field rule: the other key the allowed range depends on (`None` for a
    /// range of its own).
    pub depends_on: Option<Box<Dependency>>,
}

/// The other side of a cross-field rule (see [`ConfigError::depends_on`]).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("must be {relation} {key} = {value} ({reason})")]
pub struct Dependency {
    /// Dotted path of the other key, e.g. `robot.thigh.length_m`.
    pub key: String,
    /// Its value as text.
    pub value: String,
    /// How the field must relate to it: `<=`, `<`, `>=`, ...
    pub relation: String,
    /// Why, in a few words, e.g. `the thigh strap sits on the robot's thigh link`.
    pub reason: String,
    /// What to change, naming both keys, e.g. `set straps.ls1_m <= 0.2 or lengthen
    /// robot.thigh.length_m`.
    pub fix: String,
}

impl ConfigError {
    /// Builds an error for `field` holding `value`, which should have satisfied `allowed`.
    pub fn new(
        field: impl Into<String>,
        value: impl fmt::Display,
        allowed: impl Into<String>,
    ) -> Self {
        Self {
            field: field.into(),
            value: value.to_string(),
            allowed: allowed.into(),
            depends_on: None,
        }
    }

    /// This error, marked as the breach of a cross-field rule: the field must be `relation`
    /// the other `key` (holding `value`) because of `reason`; `fix` says what to change.
    pub fn depending_on(
        mut self,
        key: impl Into<String>,
        value: impl fmt::Display,
        relation: &str,
        reason: &str,
        fix: impl Into<String>,
    ) -> Self {
        self.depends_on = Some(Box::new(Dependency {
            key: key.into(),
            value: value.to_string(),
            relation: relation.into(),
            reason: reason.into(),
            fix: fix.into(),
        }));
        self
    }
}

/// The other side of a cross-field check: key, value, relation, reason and fix (see
/// [`Dependency`]).
struct Other<'a> {
    key: &'a str,
    value: String,
    relation: &'a str,
    reason: &'a str,
    fix: String,
}

/// Marks the error of a range check whose bound is another key's value as a cross-field
/// breach when `breached` (the bound, not the field's own range, was crossed).
fn cross(r: Result<(), ConfigError>, breached: bool, o: Other<'_>) -> Result<(), ConfigError> {
    r.map_err(|e| {
        let field = e.field.clone();
        on_field(e, &field, breached, o)
    })
}

/// [`cross`] for an error from a group of checks: marks it only if it is about `field`.
fn on_field(e: ConfigError, field: &str, breached: bool, o: Other<'_>) -> ConfigError {
    if breached && e.field == field {
        e.depending_on(o.key, o.value, o.relation, o.reason, o.fix)
    } else {
        e
    }
}

/// Allowed range of a real-valued field (all variants also require the value to be finite).
#[derive(Debug, Clone, Copy)]
enum R {
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
}

impl R {
    fn contains(self, v: f64) -> bool {
        v.is_finite()
            && match self {
                R::Any => true,
                R::Pos => v > 0.0,
                R::NonNeg => v >= 0.0,
                R::Closed(a, b) => a <= v && v <= b,
                R::OpenClosed(a, b) => a < v && v <= b,
                R::Open(a, b) => a < v && v < b,
            }
    }

    fn describe(self) -> String {
        match self {
            R::Any => "finite".into(),
            R::Pos => "finite, > 0".into(),
            R::NonNeg => "finite, >= 0".into(),
            R::Closed(a, b) => format!("finite, in [{a}, {b}]"),
            R::OpenClosed(a, b) => format!("finite, in ({a}, {b}]"),
            R::Open(a, b) => format!("finite, in ({a}, {b})"),
        }
    }
}

/// Checks a real value against a range.
fn real(path: &str, v: f64, r: R) -> Result<(), ConfigError> {
    if r.contains(v) {
        Ok(())
    } else {
        Err(ConfigError::new(path, v, r.describe()))
    }
}

/// Checks an integer value against an inclusive range.
fn int(path: &str, v: usize, lo: usize, hi: usize) -> Result<(), ConfigError> {
    if (lo..=hi).contains(&v) {
        Ok(())
    } else {
        Err(ConfigError::new(path, v, format!("integer in {lo}..={hi}")))
    }
}

/// Checks a list of `(name, value, range)` triples under the table path `prefix`.
fn reals(prefix: &str, items: &[(&str, f64, R)]) -> Result<(), ConfigError> {
    items
        .iter()
        .try_for_each(|&(name, v, r)| real(&format!("{prefix}.{name}"), v, r))
}

/// Generates a private "patch" struct (all fields optional) and a deserialiser function that
/// merges a partial table onto a given default; used for thigh/shank sub-tables whose defaults
/// differ although they share a type.
macro_rules! patch_deserializer {
    ($patch:ident, $target:ident, { $($field:ident),* $(,)? }, $( $fname:ident => $default:expr ),* $(,)?) => {
        #[derive(Deserialize)]
        #[serde(deny_unknown_fields)]
        struct $patch {
            $( $field: Option<f64>, )*
        }
        impl $patch {
            fn apply(self, mut base: $target) -> $target {
                $( if let Some(v) = self.$field { base.$field = v; } )*
                base
            }
        }
        $(
            fn $fname<'de, D: Deserializer<'de>>(d: D) -> Result<$target, D::Error> {
                $patch::deserialize(d).map(|p| p.apply($default))
            }
        )*
    };
}

// ---------------------------------------------------------------------------------------------
// [human]
// ---------------------------------------------------------------------------------------------

/// `[human]`: the human leg model and its "brain" (MODEL.md §2, paper eq. 2).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Human {
    /// Body height (m); segment lengths are fractions of it (MODEL.md §2). Default 1.75.
    pub height_m: f64,
    /// Body mass m_b (kg) of the nominal brain model and initial plant mass (MODEL.md §2). Default 60.
    pub body_mass_kg: f64,
    /// Plant body mass (kg) at the end of the 2-DOF run, reached by a linear ramp from
    /// `body_mass_kg` (MODEL.md §2, paper §4.1); the 1-DOF run keeps `body_mass_kg`. Default 85.
    pub final_body_mass_kg: f64,
    /// Brain PD stiffness Kp (1/s², applied as `Kp·I` on the joint-angle error) (MODEL.md §2). Default 400.
    pub kp: f64,
    /// Brain PD damping Kd (1/s, applied as `Kd·I` on the joint-velocity error) (MODEL.md §2). Default 40.
    pub kd: f64,
    /// `[human.thigh]`: Winter fractions of the thigh (MODEL.md §2 table).
    #[serde(deserialize_with = "de_human_thigh")]
    pub thigh: HumanSegment,
    /// `[human.shank]`: Winter fractions of the shank + foot (MODEL.md §2 table).
    #[serde(deserialize_with = "de_human_shank")]
    pub shank: HumanSegment,
}

/// `[human.thigh]` / `[human.shank]`: anthropometric fractions from Winter's tables (MODEL.md §2).
///
/// A partial table overrides only the fields it names; the rest keep the thigh's or shank's
/// default (see [`HumanSegment::WINTER_THIGH`], [`HumanSegment::WINTER_SHANK`]).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
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

    /// Segment mass (kg) for body mass `body_mass_kg`.
    pub fn mass_kg(&self, body_mass_kg: f64) -> f64 {
        self.mass_fraction * body_mass_kg
    }
    /// Segment length l (m) for body height `height_m`.
    pub fn length_m(&self, height_m: f64) -> f64 {
        self.length_fraction * height_m
    }
    /// COM distance from the proximal joint c (m) for body height `height_m`.
    pub fn com_m(&self, height_m: f64) -> f64 {
        self.com_fraction * self.length_m(height_m)
    }
    /// Inertia about the COM, `I = m (rho l)^2` (kg·m², MODEL.md §2).
    pub fn inertia_kgm2(&self, body_mass_kg: f64, height_m: f64) -> f64 {
        let r = self.gyration_fraction * self.length_m(height_m);
        self.mass_kg(body_mass_kg) * r * r
    }

    fn validate(&self, p: &str) -> Result<(), ConfigError> {
        let f = R::OpenClosed(0.0, 1.0);
        reals(
            p,
            &[
                ("mass_fraction", self.mass_fraction, f),
                ("length_fraction", self.length_fraction, f),
                ("com_fraction", self.com_fraction, f),
                ("gyration_fraction", self.gyration_fraction, f),
            ],
        )
    }
}

patch_deserializer!(HumanSegmentPatch, HumanSegment,
    { mass_fraction, length_fraction, com_fraction, gyration_fraction },
    de_human_thigh => HumanSegment::WINTER_THIGH,
    de_human_shank => HumanSegment::WINTER_SHANK,
);

impl Default for Human {
    fn default() -> Self {
        Self {
            height_m: 1.75,
            body_mass_kg: 60.0,
            final_body_mass_kg: 85.0,
            kp: 400.0,
            kd: 40.0,
            thigh: HumanSegment::WINTER_THIGH,
            shank: HumanSegment::WINTER_SHANK,
        }
    }
}

impl Human {
    fn validate(&self) -> Result<(), ConfigError> {
        reals(
            "human",
            &[
                ("height_m", self.height_m, R::Pos),
                ("body_mass_kg", self.body_mass_kg, R::Pos),
                ("final_body_mass_kg", self.final_body_mass_kg, R::Pos),
                ("kp", self.kp, R::Pos),
                ("kd", self.kd, R::Pos),
            ],
        )?;
        self.thigh.validate("human.thigh")?;
        self.shank.validate("human.shank")
    }
}

// ---------------------------------------------------------------------------------------------
// [robot]
// ---------------------------------------------------------------------------------------------

/// `[robot]`: the exoskeleton (MODEL.md §3, paper eq. 1 and Table 1).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Robot {
    /// Viscous friction kf1 per joint (N·m·s) (paper Table 1). Default 0.000899.
    pub viscous_friction: f64,
    /// Coulomb friction kf2 per joint (N·m) (paper Table 1). Default 0.05048.
    pub coulomb_friction: f64,
    /// Width (rad/s) of the smooth Coulomb term `kf2·tanh(qd/w)` used by prediction models
    /// (the plant uses `sign`) (MODEL.md §3). Default 0.01.
    pub coulomb_smoothing: f64,
    /// Payload point-mass position on the shank, measured from the knee (m) (MODEL.md §3). Default 0.215.
    pub payload_position_m: f64,
    /// `[robot.thigh]` link parameters (MODEL.md §3 table).
    #[serde(deserialize_with = "de_robot_thigh")]
    pub thigh: RobotLink,
    /// `[robot.shank]` link parameters (MODEL.md §3 table).
    #[serde(deserialize_with = "de_robot_shank")]
    pub shank: RobotLink,
}

/// `[robot.thigh]` / `[robot.shank]`: one rigid link of the exoskeleton (MODEL.md §1, §3).
///
/// A partial table overrides only the fields it names; the rest keep the thigh's or shank's
/// default ([`RobotLink::THIGH`], [`RobotLink::SHANK`]).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RobotLink {
    /// Link length l (m), > 0.
    pub length_m: f64,
    /// Link mass m (kg), > 0.
    pub mass_kg: f64,
    /// COM distance c from the proximal joint along the link (m), in [0, length_m].
    pub com_m: f64,
    /// Inertia about the COM I (kg·m²), > 0.
    pub inertia_kgm2: f64,
}

impl RobotLink {
    /// Default robot thigh: l 0.43 m, m 2.0 kg, c 0.20 m, I 0.035 kg·m² (MODEL.md §3).
    pub const THIGH: Self = Self {
        length_m: 0.43,
        mass_kg: 2.0,
        com_m: 0.20,
        inertia_kgm2: 0.035,
    };
    /// Default robot shank: l 0.43 m, m 1.2 kg, c 0.18 m, I 0.018 kg·m² (MODEL.md §3).
    pub const SHANK: Self = Self {
        length_m: 0.43,
        mass_kg: 1.2,
        com_m: 0.18,
        inertia_kgm2: 0.018,
    };

    fn validate(&self, p: &str) -> Result<(), ConfigError> {
        reals(
            p,
            &[
                ("length_m", self.length_m, R::Pos),
                ("mass_kg", self.mass_kg, R::Pos),
            ],
        )?;
        let com = R::Closed(0.0, self.length_m);
        cross(
            real(&format!("{p}.com_m"), self.com_m, com),
            self.com_m > self.length_m,
            Other {
                key: &format!("{p}.length_m"),
                value: self.length_m.to_string(),
                relation: "<=",
                reason: "the centre of mass lies on the link",
                fix: format!(
                    "set {p}.com_m <= {} or lengthen {p}.length_m",
                    self.length_m
                ),
            },
        )?;
        real(&format!("{p}.inertia_kgm2"), self.inertia_kgm2, R::Pos)
    }
}

patch_deserializer!(RobotLinkPatch, RobotLink,
    { length_m, mass_kg, com_m, inertia_kgm2 },
    de_robot_thigh => RobotLink::THIGH,
    de_robot_shank => RobotLink::SHANK,
);

impl Default for Robot {
    fn default() -> Self {
        Self {
            viscous_friction: 0.000899,
            coulomb_friction: 0.05048,
            coulomb_smoothing: 0.01,
            payload_position_m: 0.215,
            thigh: RobotLink::THIGH,
            shank: RobotLink::SHANK,
        }
    }
}

impl Robot {
    fn validate(&self) -> Result<(), ConfigError> {
        self.thigh.validate("robot.thigh")?;
        self.shank.validate("robot.shank")?;
        reals(
            "robot",
            &[
                ("viscous_friction", self.viscous_friction, R::NonNeg),
                ("coulomb_friction", self.coulomb_friction, R::NonNeg),
                ("coulomb_smoothing", self.coulomb_smoothing, R::Pos),
            ],
        )?;
        let (pos, l) = (self.payload_position_m, self.shank.length_m);
        cross(
            real("robot.payload_position_m", pos, R::Closed(0.0, l)),
            pos > l,
            Other {
                key: "robot.shank.length_m",
                value: l.to_string(),
                relation: "<=",
                reason: "the payload sits on the robot's shank link",
                fix: format!(
                    "set robot.payload_position_m <= {l} or lengthen robot.shank.length_m"
                ),
            },
        )
    }
}

// ---------------------------------------------------------------------------------------------
// [straps]
// ---------------------------------------------------------------------------------------------

/// `[straps]`: spring-damper human-robot interaction (MODEL.md §4, paper eqs. 3-4).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Straps {
    /// Thigh strap distance from the hip Ls1 (m), in (0, robot.thigh.length_m]. Default 0.28.
    pub ls1_m: f64,
    /// Shank strap distance from the knee Ls2 (m), in (0, robot.shank.length_m]. Default 0.16.
    pub ls2_m: f64,
    /// Strap stiffness ks (N/m), > 0. Default 937.5.
    pub stiffness: f64,
    /// Strap damping cs (N·s/m), >= 0. Default 93.7.
    pub damping: f64,
}

impl Default for Straps {
    fn default() -> Self {
        Self {
            ls1_m: 0.28,
            ls2_m: 0.16,
            stiffness: 937.5,
            damping: 93.7,
        }
    }
}

// ---------------------------------------------------------------------------------------------
// [uncertainty]
// ---------------------------------------------------------------------------------------------

/// `[uncertainty]`: plant uncertainties and sensor imperfections (MODEL.md §5, paper §4.1).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Uncertainty {
    /// True payload m_p at the middle of the robot shank (kg), in [0, 20]; unknown to the
    /// controller (MODEL.md §3, §5). Default 0.
    pub payload_kg: f64,
    /// Enable `m_dis(t) = 0.05 sin(t) + 0.01 sin(100 t + pi/4)` kg on each robot link (MODEL.md §5).
    pub mass_perturbation: bool,
    /// Enable the lumped joint disturbance `D(t) = 0.1 sin(t) + 0.05 sin(100 t + pi/2)` N·m (MODEL.md §5).
    pub disturbance: bool,
    /// Enable the linear human body-mass ramp of the 2-DOF run (MODEL.md §2).
    pub human_mass_ramp: bool,
    /// Velocity measurement noise amplitude (rad/s), >= 0: `a sin(w t)` (MODEL.md §5). Default 1e-4.
    pub velocity_noise: f64,
    /// Strap force measurement noise amplitude (N), >= 0 (MODEL.md §5). Default 1e-3.
    pub force_noise: f64,
    /// Angular frequency w of the measurement noise (rad/s), >= 0 (MODEL.md §5). Default 100.
    pub noise_frequency: f64,
    /// Moving-average window on measured velocities and forces (samples), 1..=100 (MODEL.md §5). Default 5.
    pub filter_window: usize,
}

impl Default for Uncertainty {
    fn default() -> Self {
        Self {
            payload_kg: 0.0,
            mass_perturbation: true,
            disturbance: true,
            human_mass_ramp: true,
            velocity_noise: 1e-4,
            force_noise: 1e-3,
            noise_frequency: 100.0,
            filter_window: 5,
        }
    }
}

// ---------------------------------------------------------------------------------------------
// [trajectory]
// ---------------------------------------------------------------------------------------------

/// `[trajectory]`: the human's desired motion (MODEL.md §6), parametric or recorded; defined
/// with its keys, ranges and `validate` in [`crate::sim::Gait`].
pub use crate::sim::Gait as Trajectory;
pub use crate::sim::GaitKind as TrajectoryKind;

/// A `[trajectory]` error as a scenario error: the key gets its table path (`trajectory.`).
fn in_trajectory(e: crate::sim::InvalidField) -> ConfigError {
    ConfigError::new(format!("trajectory.{}", e.field), e.value, e.allowed)
}

// ---------------------------------------------------------------------------------------------
// [timing]
// ---------------------------------------------------------------------------------------------

/// `[timing]`: control period, integration steps and run lengths (MODEL.md §7).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Timing {
    /// Control period dt (s), in (0, 1]. Default 0.01.
    pub dt: f64,
    /// Plant RK4 steps per control period, 1..=1000. Default 10 (1 ms steps).
    pub plant_substeps: usize,
    /// Prediction-model RK4 steps per control period, 1..=1000. Default 1.
    pub prediction_substeps: usize,
    /// Length of the 2-DOF run (s), in [dt, 1e6]. Default 20.
    pub duration_2dof_s: f64,
    /// Length of the 1-DOF run (s), in [dt, 1e6]. Default 30.
    pub duration_1dof_s: f64,
}

impl Default for Timing {
    fn default() -> Self {
        Self {
            dt: 0.01,
            plant_substeps: 10,
            prediction_substeps: 1,
            duration_2dof_s: 20.0,
            duration_1dof_s: 30.0,
        }
    }
}

// ---------------------------------------------------------------------------------------------
// [controller]
// ---------------------------------------------------------------------------------------------

/// Which controller drives the robot.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ControllerKind {
    /// Baseline joint PD on the estimated human intent (`[controller.pd]` gains).
    Pd,
    /// Non-robust NMPC on the nominal (0 kg) model, no disturbance estimate (paper §3.1, eq. 7).
    Nmpc,
    /// Multi-stage robust NMPC (paper §3.2, eqs. 10-13).
    Msnmpc,
}

pub use crate::control::Interaction;
pub use crate::control::{FilterAware, GainSetting, Method, RobustSettings};

/// `[controller]`: intent estimation and NMPC (MODEL.md §8, paper eqs. 5-9, Table 1).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Controller {
    /// Controller used by `simulate` (`"pd"`, `"nmpc"`, `"msnmpc"`). Default `"msnmpc"`.
    pub kind: ControllerKind,
    /// Intent gain K1 (1/N, applied as `K1·I`): `q̂_H = q_R + K1 F` (paper eq. 5), >= 0, or
    /// `"auto"`: `K1 = 4.6875 rad/m / straps.stiffness` (`control::GainSetting`; 0.005 at the
    /// default straps). Default 0.005.
    pub k1: GainSetting,
    /// Intent gain K2 (1/(N·s)): `q̂d_H = qd_R + K2 F` (paper eq. 6), >= 0, or `"auto"`:
    /// `K2 = 46.875 rad/(m·s) / straps.stiffness` (0.05 at the default straps). Default 0.05.
    pub k2: GainSetting,
    /// Prediction horizon Np (steps), 1..=200. Default 3.
    pub np: usize,
    /// Control horizon Nc (steps), 1..=np. Default 3.
    pub nc: usize,
    /// Velocity tracking weight r_d (paper eq. 7), >= 0. Default 0.1.
    pub r_d: f64,
    /// Torque-increment weight r_t (1/(N·m)², paper eq. 7; see MODEL.md §9 note), > 0. Default 1e-5.
    pub r_t: f64,
    /// Torque bound |T| (N·m) per joint (paper eq. 8), > 0. Default 30.
    pub torque_max: f64,
    /// Torque rate bound (N·m/s); the per-step bound on |dT| is `torque_rate_max·dt`
    /// (paper eq. 9), > 0. Default 1000.
    pub torque_rate_max: f64,
    /// Strap-torque model over the horizon (`"predict"` or `"hold"`). Default `"predict"`.
    pub interaction: Interaction,
    /// `[controller.sqp]` solver settings.
    pub sqp: Sqp,
    /// `[controller.pd]` baseline PD gains.
    pub pd: PdGains,
    /// Multi-stage method: `"robust"` (the paper's method with the `[controller.robust]`
    /// extensions) or `"paper"` (exactly the paper's, reproduces `docs/REPRODUCING.md`).
    /// Default `"robust"`.
    pub method: Method,
    /// `[controller.robust]` switches of `method = "robust"`.
    pub robust: RobustSettings,
}

impl Default for Controller {
    fn default() -> Self {
        Self {
            kind: ControllerKind::Msnmpc,
            k1: GainSetting::Value(0.005),
            k2: GainSetting::Value(0.05),
            np: 3,
            nc: 3,
            r_d: 0.1,
            r_t: 1e-5,
            torque_max: 30.0,
            torque_rate_max: 1000.0,
            interaction: Interaction::Predict,
            sqp: Sqp::default(),
            pd: PdGains::default(),
            method: Method::Robust,
            robust: RobustSettings::default(),
        }
    }
}

/// `[controller.sqp]`: SQP solver limits (paper §3.1).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Sqp {
    /// Maximum SQP iterations per solve, 1..=1000. Default 20.
    pub max_iterations: usize,
    /// KKT residual tolerance, in (0, 1]. Default 1e-8.
    pub kkt_tolerance: f64,
    /// Optional wall-clock budget per solve (µs), 1..=10_000_000; absent = no time budget.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub max_time_us: Option<u64>,
    /// Hessian model of the QP subproblems: `"structured_secant"` (Gauss-Newton plus a
    /// secant estimate of the residual curvature) or `"gauss_newton"`. Default
    /// `"structured_secant"`.
    pub hessian: crate::solver::HessianModel,
    /// QP solver of the SQP: `"dense"` (condensed, the oracle), `"structured"` (Riccati over
    /// the horizon stages, Gauss-Newton Hessian) or `"auto"` (structured when joints·nc ≥ 16).
    /// Default `"auto"`.
    pub qp: crate::control::QpBackend,
    /// Real-time iteration: one SQP iteration (one linearisation, one QP, full step) per
    /// control period from the shifted previous solution, instead of iterating to the KKT
    /// tolerance. Default `false`.
    pub rti: bool,
}

impl Default for Sqp {
    fn default() -> Self {
        Self {
            max_iterations: 20,
            kkt_tolerance: 1e-8,
            max_time_us: None,
            hessian: crate::solver::HessianModel::StructuredSecant,
            qp: crate::control::QpBackend::Auto,
            rti: false,
        }
    }
}

/// `[controller.pd]`: gains of the baseline PD controller.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PdGains {
    /// Proportional gain (N·m/rad), > 0. Default 30 (60 with kd 6 already limit-cycles on
    /// the default scenario; 30/3 keeps RMS strap forces near 7 N thigh, 3 N shank at 0 kg).
    pub kp: f64,
    /// Derivative gain (N·m·s/rad), > 0. Default 3.
    pub kd: f64,
}

impl Default for PdGains {
    fn default() -> Self {
        Self { kp: 30.0, kd: 3.0 }
    }
}

// ---------------------------------------------------------------------------------------------
// [multistage]
// ---------------------------------------------------------------------------------------------

pub use crate::control::Formulation;
pub use crate::estimate::Innovation;

/// `[multistage]`: scenario tree and probabilities (MODEL.md §8, paper §3.2, eqs. 10-13).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Multistage {
    /// Payload of each scenario (kg): 1..=32 entries, each in [0, 20]; a shorthand for
    /// scenarios named `"0 kg"`, `"1 kg"`, ... with the base robot and straps. Default [0, 1, 2].
    pub payloads_kg: Vec<f64>,
    /// Convergence constant c1 of the probability update (paper eq. 10), > 0. Default 100.
    pub c1: f64,
    /// Probability floor before renormalisation, in (0, 1/number of scenarios). Default 1e-4.
    pub probability_floor: f64,
    /// `"decoupled"` (paper eq. 13) or `"coupled"` (eq. 12). Default `"decoupled"`.
    pub formulation: Formulation,
    /// Number of leading control moves shared by all scenarios (coupled form), 1..=nc. Default 1.
    pub robust_horizon: usize,
    /// Solve the scenarios in parallel threads. Default false.
    pub parallel: bool,
    /// `"standard"` or `"paper"` EKF innovation (paper §3.2). Default `"standard"`.
    pub innovation: Innovation,
    /// `[[multistage.scenarios]]`: named scenarios, each a partial override of `[robot]` and
    /// `[straps]` with its payload (see [`scenarios`]); when given they
    /// replace `payloads_kg` (which must then be left out). Default none.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub scenarios: Vec<scenarios::ScenarioSpec>,
}

impl Default for Multistage {
    fn default() -> Self {
        Self {
            payloads_kg: vec![0.0, 1.0, 2.0],
            c1: 100.0,
            probability_floor: 1e-4,
            formulation: Formulation::Decoupled,
            robust_horizon: 1,
            parallel: false,
            innovation: Innovation::Standard,
            scenarios: Vec::new(),
        }
    }
}

// ---------------------------------------------------------------------------------------------
// [ekf]
// ---------------------------------------------------------------------------------------------

/// `[ekf]`: per-component covariances of each scenario's EKF on `[q, qd, d]` (MODEL.md §8); the
/// estimator's own settings type, so the scenario file maps onto it one to one.
pub use crate::estimate::EkfSettings as Ekf;

// ---------------------------------------------------------------------------------------------
// [faults]
// ---------------------------------------------------------------------------------------------

pub use crate::sim::{Channel, FaultEvent, FaultKind, Faults};

// ---------------------------------------------------------------------------------------------
// [monitors]
// ---------------------------------------------------------------------------------------------

pub use crate::control::{MonitorResponse, Monitors};

// ---------------------------------------------------------------------------------------------
// Scenario
// ---------------------------------------------------------------------------------------------

/// The complete scenario: plant, human, controller, estimator, faults and monitors.
///
/// `Scenario::default()` is the embedded default scenario of spec `MODEL.md`.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Scenario {
    /// `[human]` (MODEL.md §2).
    pub human: Human,
    /// `[robot]` (MODEL.md §3).
    pub robot: Robot,
    /// `[straps]` (MODEL.md §4).
    pub straps: Straps,
    /// `[uncertainty]` (MODEL.md §5).
    pub uncertainty: Uncertainty,
    /// `[trajectory]` (MODEL.md §6).
    pub trajectory: Trajectory,
    /// `[timing]` (MODEL.md §7).
    pub timing: Timing,
    /// `[controller]` (MODEL.md §8).
    pub controller: Controller,
    /// `[multistage]` (MODEL.md §8).
    pub multistage: Multistage,
    /// `[ekf]` (MODEL.md §8).
    pub ekf: Ekf,
    /// `[faults]`.
    pub faults: Faults,
    /// `[monitors]`.
    pub monitors: Monitors,
}

/// Upper bound on any payload (kg) accepted by validation.
pub const MAX_PAYLOAD_KG: f64 = 20.0;

/// Most control steps one run may take (`duration / dt`), so that a tiny `dt` cannot start a
/// practically endless run.
pub const MAX_CONTROL_STEPS: usize = 100_000_000;

/// Maximum number of multi-stage scenarios.
pub const MAX_SCENARIOS: usize = 32;

impl Scenario {
    /// Checks every numeric field (finite and within its documented range) and the
    /// cross-field rules (nc <= np, robust_horizon <= nc, com within the link, ...).
    ///
    /// Returns the first violation, naming the field by its dotted path.
    pub fn validate(&self) -> Result<(), ConfigError> {
        self.human.validate()?;
        self.robot.validate()?;

        let s = &self.straps;
        for (name, v, link, l) in [
            ("ls1_m", s.ls1_m, "thigh", self.robot.thigh.length_m),
            ("ls2_m", s.ls2_m, "shank", self.robot.shank.length_m),
        ] {
            cross(
                real(&format!("straps.{name}"), v, R::OpenClosed(0.0, l)),
                v > l,
                Other {
                    key: &format!("robot.{link}.length_m"),
                    value: l.to_string(),
                    relation: "<=",
                    reason: &format!("the {link} strap sits on the robot's {link} link"),
                    fix: format!("set straps.{name} <= {l} or lengthen robot.{link}.length_m"),
                },
            )?;
        }
        reals(
            "straps",
            &[
                ("stiffness", s.stiffness, R::Pos),
                ("damping", s.damping, R::NonNeg),
            ],
        )?;

        let u = &self.uncertainty;
        reals(
            "uncertainty",
            &[
                ("payload_kg", u.payload_kg, R::Closed(0.0, MAX_PAYLOAD_KG)),
                ("velocity_noise", u.velocity_noise, R::NonNeg),
                ("force_noise", u.force_noise, R::NonNeg),
                ("noise_frequency", u.noise_frequency, R::NonNeg),
            ],
        )?;
        int("uncertainty.filter_window", u.filter_window, 1, 100)?;

        let sw = &self.trajectory.swing;
        let (swing, base) = (sw.frequency_swing_hz, sw.base_frequency_hz);
        self.trajectory
            .validate()
            .map_err(in_trajectory)
            .map_err(|e| {
                on_field(e, "trajectory.frequency_swing_hz", swing >= base, Other {
                    key: "trajectory.base_frequency_hz",
                    value: base.to_string(),
                    relation: "<",
                    reason: "the gait frequency base ± swing stays above 0",
                    fix: format!("set trajectory.frequency_swing_hz < {base} or raise trajectory.base_frequency_hz"),
                })
            })?;

        let tm = &self.timing;
        real("timing.dt", tm.dt, R::OpenClosed(0.0, 1.0))?;
        int("timing.plant_substeps", tm.plant_substeps, 1, 1000)?;
        int(
            "timing.prediction_substeps",
            tm.prediction_substeps,
            1,
            1000,
        )?;
        reals(
            "timing",
            &[
                ("duration_2dof_s", tm.duration_2dof_s, R::Closed(tm.dt, 1e6)),
                ("duration_1dof_s", tm.duration_1dof_s, R::Closed(tm.dt, 1e6)),
            ],
        )
        .map_err(|e| {
            let short = e.value.parse::<f64>().is_ok_and(|d| d < tm.dt);
            let field = e.field.clone();
            on_field(
                e,
                &field,
                short,
                Other {
                    key: "timing.dt",
                    value: tm.dt.to_string(),
                    relation: ">=",
                    reason: "a run is at least one control period",
                    fix: format!("set {field} >= {} or shorten timing.dt", tm.dt),
                },
            )
        })?;
        for (name, d) in [
            ("timing.duration_2dof_s", tm.duration_2dof_s),
            ("timing.duration_1dof_s", tm.duration_1dof_s),
        ] {
            if d / tm.dt > MAX_CONTROL_STEPS as f64 {
                let most = MAX_CONTROL_STEPS as f64 * tm.dt;
                return Err(ConfigError::new(
                    name,
                    d,
                    format!(
                        "at most {MAX_CONTROL_STEPS} control steps, i.e. <= {most} s at timing.dt = {} s",
                        tm.dt
                    ),
                )
                .depending_on(
                    "timing.dt",
                    tm.dt,
                    &format!("<= {MAX_CONTROL_STEPS} ×"),
                    "a run has at most that many control steps",
                    format!("set {name} <= {most} or lengthen timing.dt"),
                ));
            }
        }

        let c = &self.controller;
        int("controller.np", c.np, 1, 200)?;
        cross(
            int("controller.nc", c.nc, 1, c.np),
            c.nc > c.np,
            Other {
                key: "controller.np",
                value: c.np.to_string(),
                relation: "<=",
                reason: "the control horizon lies within the prediction horizon",
                fix: format!("set controller.nc <= {} or raise controller.np", c.np),
            },
        )?;
        reals(
            "controller",
            &[
                ("k1", c.k1.value().unwrap_or(0.0), R::NonNeg),
                ("k2", c.k2.value().unwrap_or(0.0), R::NonNeg),
                ("r_d", c.r_d, R::NonNeg),
                ("r_t", c.r_t, R::Pos),
                ("torque_max", c.torque_max, R::Pos),
                ("torque_rate_max", c.torque_rate_max, R::Pos),
            ],
        )?;
        int(
            "controller.sqp.max_iterations",
            c.sqp.max_iterations,
            1,
            1000,
        )?;
        real(
            "controller.sqp.kkt_tolerance",
            c.sqp.kkt_tolerance,
            R::OpenClosed(0.0, 1.0),
        )?;
        if let Some(us) = c.sqp.max_time_us {
            if !(1..=10_000_000).contains(&us) {
                return Err(ConfigError::new(
                    "controller.sqp.max_time_us",
                    us,
                    "integer in 1..=10000000, or absent",
                ));
            }
        }
        reals(
            "controller.pd",
            &[("kp", c.pd.kp, R::Pos), ("kd", c.pd.kd, R::Pos)],
        )?;
        let rb = &c.robust;
        reals(
            "controller.robust",
            &[
                ("oscillation_cutoff_hz", rb.oscillation_cutoff_hz, R::Pos),
                (
                    "oscillation_window_s",
                    rb.oscillation_window_s,
                    R::OpenClosed(0.0, 10.0),
                ),
                (
                    "oscillation_fraction",
                    rb.oscillation_fraction,
                    R::Open(0.0, 1.0),
                ),
                (
                    "oscillation_min_force_n",
                    rb.oscillation_min_force_n,
                    R::NonNeg,
                ),
                ("human_bandwidth_hz", rb.human_bandwidth_hz, R::Pos),
                ("release_s", rb.release_s, R::Closed(0.0, 1e6)),
            ],
        )?;

        let m = &self.multistage;
        // `payloads_kg` or `[[multistage.scenarios]]`: count, names, every override's range.
        let n = scenarios::validate(self)?;
        reals(
            "multistage",
            &[
                ("c1", m.c1, R::Pos),
                (
                    "probability_floor",
                    m.probability_floor,
                    R::Open(0.0, 1.0 / n as f64),
                ),
            ],
        )
        .map_err(|e| {
            let high = m.probability_floor >= 1.0 / n as f64;
            on_field(
                e,
                "multistage.probability_floor",
                high,
                Other {
                    key: "multistage.payloads_kg",
                    value: format!("{:?} ({n} scenarios)", m.payloads_kg),
                    relation: "< 1 / the number of entries of",
                    reason: "the floored probabilities must still sum to 1",
                    fix: format!(
                    "set multistage.probability_floor < {} or list fewer multistage.payloads_kg",
                    1.0 / n as f64
                ),
                },
            )
        })?;
        cross(
            int("multistage.robust_horizon", m.robust_horizon, 1, c.nc),
            m.robust_horizon > c.nc,
            Other {
                key: "controller.nc",
                value: c.nc.to_string(),
                relation: "<=",
                reason: "the shared moves lie within the control horizon",
                fix: format!(
                    "set multistage.robust_horizon <= {} or raise controller.nc",
                    c.nc
                ),
            },
        )?;

        let e = &self.ekf;
        reals(
            "ekf",
            &[
                ("q_angle", e.q_angle, R::Pos),
                ("q_velocity", e.q_velocity, R::Pos),
                ("q_disturbance", e.q_disturbance, R::Pos),
                ("r_angle", e.r_angle, R::Pos),
                ("r_velocity", e.r_velocity, R::Pos),
                ("p0_angle", e.p0_angle, R::Pos),
                ("p0_velocity", e.p0_velocity, R::Pos),
                ("p0_disturbance", e.p0_disturbance, R::Pos),
            ],
        )?;

        real("faults.saturation_n", self.faults.saturation_n, R::Pos)?;
        for (i, ev) in self.faults.events.iter().enumerate() {
            reals(
                &format!("faults.events[{i}]"),
                &[
                    ("start_s", ev.start_s, R::NonNeg),
                    ("duration_s", ev.duration_s, R::NonNeg),
                    ("magnitude", ev.magnitude, R::Any),
                ],
            )?;
        }

        let mo = &self.monitors;
        reals(
            "monitors",
            &[
                ("tracking_error_max_rad", mo.tracking_error_max_rad, R::Pos),
                ("force_max_n", mo.force_max_n, R::Pos),
                ("sensor_timeout_s", mo.sensor_timeout_s, R::Pos),
                (
                    "oscillation_force_rms_n",
                    mo.oscillation_force_rms_n,
                    R::Pos,
                ),
                (
                    "oscillation_torque_rms_nm",
                    mo.oscillation_torque_rms_nm,
                    R::Pos,
                ),
                ("oscillation_cutoff_hz", mo.oscillation_cutoff_hz, R::Pos),
                (
                    "oscillation_window_s",
                    mo.oscillation_window_s,
                    R::OpenClosed(0.0, 10.0),
                ),
                (
                    "oscillation_clear_s",
                    mo.oscillation_clear_s,
                    R::Closed(0.0, 1e6),
                ),
            ],
        )
    }

    /// Run length (s) of the `dof`-DOF experiment: `duration_1dof_s` for `dof == 1`,
    /// `duration_2dof_s` otherwise (MODEL.md §7).
    pub fn duration_s(&self, dof: usize) -> f64 {
        if dof == 1 {
            self.timing.duration_1dof_s
        } else {
            self.timing.duration_2dof_s
        }
    }

    /// Checks that `[trajectory]` can drive the `dof`-DOF run of [`Scenario::duration_s`]
    /// (a recording needs a hip column for 2 DOF and must last the run or loop; see
    /// [`crate::sim::Gait::check_run`]).
    pub fn check_trajectory(&self, dof: usize) -> Result<(), ConfigError> {
        let key = if dof == 1 {
            "timing.duration_1dof_s"
        } else {
            "timing.duration_2dof_s"
        };
        self.trajectory
            .check_run(dof, self.duration_s(dof), key)
            .map_err(in_trajectory)
    }

    /// Number of control steps N of the `dof`-DOF run, `round(duration / dt)` (MODEL.md §7, §8a).
    pub fn control_steps(&self, dof: usize) -> usize {
        (self.duration_s(dof) / self.timing.dt).round() as usize
    }

    /// Per-step torque increment bound `torque_rate_max · dt` (N·m; 10 by default, paper eq. 9).
    pub fn rate_limit_per_step(&self) -> f64 {
        self.controller.torque_rate_max * self.timing.dt
    }

    /// Plant RK4 step `dt / plant_substeps` (s; 1 ms by default, MODEL.md §7).
    pub fn plant_step_s(&self) -> f64 {
        self.timing.dt / self.timing.plant_substeps as f64
    }

    /// Prediction-model RK4 step `dt / prediction_substeps` (s, MODEL.md §7).
    pub fn prediction_step_s(&self) -> f64 {
        self.timing.dt / self.timing.prediction_substeps as f64
    }

    /// True human body mass of the plant (kg) at time `t` (s) of the `dof`-DOF run: a linear
    /// ramp from `body_mass_kg` at t = 0 to `final_body_mass_kg` at the end of the 2-DOF run
    /// when `uncertainty.human_mass_ramp` is on; constant `body_mass_kg` otherwise (MODEL.md §2).
    /// `t` is clamped to `[0, duration]`.
    pub fn plant_body_mass_kg(&self, dof: usize, t: f64) -> f64 {
        let h = &self.human;
        if dof == 1 || !self.uncertainty.human_mass_ramp {
            return h.body_mass_kg;
        }
        let d = self.duration_s(dof);
        let s = (t / d).clamp(0.0, 1.0);
        h.body_mass_kg + s * (h.final_body_mass_kg - h.body_mass_kg)
    }
}
