//! The whole simulation / control scenario as plain serde structs.
//!
//! [`Experiment::default()`] is the embedded default scenario: every value is the one stated in
//! the repository's `docs/MODEL.md` (section numbers "§n" below refer to it) or by the paper
//! (Aliyari & Vossoughi, equation numbers "eq. N" refer to it). A configuration file
//! (TOML in the CLI, but any serde format works) overrides only what it names: every struct is
//! `#[serde(default)]`, and the thigh/shank sub-tables are merged field by field onto their own
//! defaults. Unknown keys are rejected (`#[serde(deny_unknown_fields)]`).
//!
//! Deserialisation checks only types; [`Experiment::validate`] checks every numeric value (finite
//! and inside a documented range) and reports the first offending field by its dotted path.
//!
//! Units are SI throughout (m, kg, s, rad, N, N·m).

use crate::check::{self, InvalidField, Range as R};
#[cfg(not(feature = "std"))]
use crate::math::Float;
use alloc::{boxed::Box, format, string::String, string::ToString, vec, vec::Vec};
use core::fmt;
use serde::{Deserialize, Deserializer, Serialize};

mod controller_kind;
mod keys;
pub mod scenarios;
pub use keys::{explain, removed_key, Allowed, End, KeyDoc, Limit, KEYS};

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

impl From<InvalidField> for ConfigError {
    fn from(e: InvalidField) -> Self {
        ConfigError::new(e.field, e.value, e.allowed)
    }
}

/// A settings type's error (its key inside its own table) as a scenario error: the key gets
/// the table path `prefix` (`mass_kg` → `robot.thigh.mass_kg`).
fn at(prefix: &str) -> impl Fn(InvalidField) -> ConfigError + '_ {
    move |e| e.within(prefix).into()
}

/// Checks a real value against a range.
fn real(path: &str, v: f64, r: R) -> Result<(), ConfigError> {
    Ok(check::real(path, v, r)?)
}

/// Checks an integer value against an inclusive range.
fn int(path: &str, v: usize, lo: usize, hi: usize) -> Result<(), ConfigError> {
    Ok(check::int(path, v, lo, hi)?)
}

/// Checks a list of `(name, value, range)` triples under the table path `prefix`.
fn reals(prefix: &str, items: &[(&str, f64, R)]) -> Result<(), ConfigError> {
    Ok(check::reals(items).map_err(|e| e.within(prefix))?)
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
pub struct HumanSettings {
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

/// `[human.thigh]` / `[human.shank]`: Winter's fractions of one segment, the model's own type
/// with its keys, ranges and `validate` (a partial table overrides only the keys it names; the
/// rest keep [`HumanSegment::WINTER_THIGH`] or [`HumanSegment::WINTER_SHANK`]).
pub use crate::model::HumanSegment;

patch_deserializer!(HumanSegmentPatch, HumanSegment,
    { mass_fraction, length_fraction, com_fraction, gyration_fraction },
    de_human_thigh => HumanSegment::WINTER_THIGH,
    de_human_shank => HumanSegment::WINTER_SHANK,
);

impl Default for HumanSettings {
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

impl HumanSettings {
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
        self.thigh.validate().map_err(at("human.thigh"))?;
        self.shank.validate().map_err(at("human.shank"))
    }
}

// ---------------------------------------------------------------------------------------------
// [robot]
// ---------------------------------------------------------------------------------------------

/// `[robot]`: the exoskeleton (MODEL.md §3, paper eq. 1 and Table 1).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RobotSettings {
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
    pub thigh: Link,
    /// `[robot.shank]` link parameters (MODEL.md §3 table).
    #[serde(deserialize_with = "de_robot_shank")]
    pub shank: Link,
}

/// `[robot.thigh]` / `[robot.shank]`: one rigid link of the exoskeleton (MODEL.md §1, §3), the
/// model's own type with its keys (`length_m`, `mass_kg`, `com_m`, `inertia_kgm2`), ranges and
/// `validate`. A partial table overrides only the keys it names (read as a
/// [`scenarios::LinkOverride`]); the rest keep [`Link::ROBOT_THIGH`] or [`Link::ROBOT_SHANK`].
pub use crate::model::Link;

fn de_robot_thigh<'de, D: Deserializer<'de>>(d: D) -> Result<Link, D::Error> {
    scenarios::LinkOverride::deserialize(d).map(|p| p.apply(Link::ROBOT_THIGH))
}

fn de_robot_shank<'de, D: Deserializer<'de>>(d: D) -> Result<Link, D::Error> {
    scenarios::LinkOverride::deserialize(d).map(|p| p.apply(Link::ROBOT_SHANK))
}

impl Default for RobotSettings {
    fn default() -> Self {
        Self {
            viscous_friction: 0.000899,
            coulomb_friction: 0.05048,
            coulomb_smoothing: 0.01,
            payload_position_m: 0.215,
            thigh: Link::ROBOT_THIGH,
            shank: Link::ROBOT_SHANK,
        }
    }
}

impl RobotSettings {
    fn validate(&self) -> Result<(), ConfigError> {
        for (p, l) in [("robot.thigh", &self.thigh), ("robot.shank", &self.shank)] {
            l.validate().map_err(at(p)).map_err(|e| {
                on_field(
                    e,
                    &format!("{p}.com_m"),
                    l.com > l.length,
                    Other {
                        key: &format!("{p}.length_m"),
                        value: l.length.to_string(),
                        relation: "<=",
                        reason: "the centre of mass lies on the link",
                        fix: format!("set {p}.com_m <= {} or lengthen {p}.length_m", l.length),
                    },
                )
            })?;
        }
        reals(
            "robot",
            &[
                ("viscous_friction", self.viscous_friction, R::NonNeg),
                ("coulomb_friction", self.coulomb_friction, R::NonNeg),
                ("coulomb_smoothing", self.coulomb_smoothing, R::Pos),
            ],
        )?;
        let (pos, l) = (self.payload_position_m, self.shank.length);
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
pub struct StrapsSettings {
    /// Thigh strap distance from the hip Ls1 (m), in (0, robot.thigh.length_m]. Default 0.28.
    pub ls1_m: f64,
    /// Shank strap distance from the knee Ls2 (m), in (0, robot.shank.length_m]. Default 0.16.
    pub ls2_m: f64,
    /// Strap stiffness ks (N/m), > 0. Default 937.5.
    pub stiffness: f64,
    /// Strap damping cs (N·s/m), >= 0. Default 93.7.
    pub damping: f64,
}

impl Default for StrapsSettings {
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

/// `[uncertainty]`: plant uncertainties and sensor imperfections (MODEL.md §5, paper §4.1);
/// the simulator's own type with its keys, ranges and `validate`.
pub use crate::sim::{Uncertainty, MAX_PAYLOAD_KG};

// ---------------------------------------------------------------------------------------------
// [trajectory]
// ---------------------------------------------------------------------------------------------

/// `[trajectory]`: the human's desired motion (MODEL.md §6), parametric or recorded; defined
/// with its keys, ranges and `validate` in [`crate::sim::Gait`].
pub use crate::sim::Gait as Trajectory;
pub use crate::sim::GaitKind as TrajectoryKind;

// ---------------------------------------------------------------------------------------------
// [timing]
// ---------------------------------------------------------------------------------------------

/// `[timing]`: control period, integration steps and run lengths (MODEL.md §7).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct TimingSettings {
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

impl Default for TimingSettings {
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

pub use controller_kind::ControllerKind;

pub use crate::control::Interaction;
pub use crate::control::{
    FilterAware, GainSetting, IntentEstimate, Method, RobustIntentGains, RobustSettings,
};
use crate::solver::{SolverError, SqpSettings};
use core::time::Duration;

/// `[controller]`: intent estimation and NMPC (MODEL.md §8, paper eqs. 5-9, Table 1).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ControllerSettings {
    /// Controller used by `simulate`: the name of a registered controller (`"pd"`, `"nmpc"`,
    /// `"msnmpc"` or one added with `exompc::scenario::register_controller`). Default
    /// `"msnmpc"`.
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
    pub sqp: SqpOptions,
    /// `[controller.pd]` baseline PD gains.
    pub pd: PdSettings,
    /// Multi-stage method: `"robust"` (the paper's method with the `[controller.robust]`
    /// extensions) or `"paper"` (exactly the paper's, reproduces `docs/REPRODUCING.md`).
    /// Default `"robust"`.
    pub method: Method,
    /// `[controller.robust]` switches of `method = "robust"`.
    pub robust: RobustSettings,
}

impl Default for ControllerSettings {
    fn default() -> Self {
        Self {
            kind: ControllerKind::MSNMPC,
            k1: GainSetting::Value(0.005),
            k2: GainSetting::Value(0.05),
            np: 3,
            nc: 3,
            r_d: 0.1,
            r_t: 1e-5,
            torque_max: 30.0,
            torque_rate_max: 1000.0,
            interaction: Interaction::Predict,
            sqp: SqpOptions::default(),
            pd: PdSettings::default(),
            method: Method::Robust,
            robust: RobustSettings::default(),
        }
    }
}

/// `[controller.sqp]`: SQP solver limits (paper §3.1); the keys of [`SqpSettings`] a scenario
/// sets (see [`SqpOptions::settings`]), checked by its `validate`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SqpOptions {
    /// Maximum SQP iterations per solve, 1..=1000. Default 20.
    pub max_iterations: usize,
    /// KKT residual tolerance, in [0, 1] (0: never converged, every solve runs to a limit).
    /// Default 1e-8.
    pub kkt_tolerance: f64,
    /// Optional wall-clock budget per solve (µs), 0..=10_000_000 (0: stop after the first
    /// iteration); absent = no time budget.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub max_time_us: Option<u64>,
    /// Hessian model of the QP subproblems: `"auto"` (the QP back-end's own model:
    /// `"structured_secant"` on the dense one, `"gauss_newton"` on the structured one),
    /// `"structured_secant"` (Gauss-Newton plus a secant estimate of the residual curvature;
    /// the dense back-end only, so `qp = "auto"` then stays dense), `"gauss_newton"` or
    /// `"exact"` (the exact Lagrangian Hessian, in both QP back-ends, shifted by `μ I` when it
    /// is not positive definite; the coupled scenario tree uses Gauss-Newton). The run summary's
    /// `solver` names the model run ([`crate::control::QpBackend::resolve`]). Default `"auto"`.
    pub hessian: crate::control::HessianSetting,
    /// QP solver of the SQP: `"dense"` (condensed, the oracle), `"structured"` (Riccati over
    /// the horizon stages, Gauss-Newton or exact Hessian; the coupled formulation: the block-arrowhead
    /// scenario tree) or `"auto"` (structured when joints·nc ≥ 16; coupled: when the tree's
    /// decision variables joints·(Nr + S·(Nc − Nr)) ≥ 16; never a back-end that would run
    /// another Hessian than `hessian` asks for: `auto` chooses the QP back-end only). The run
    /// summary's `solver` names the back-end chosen. Default `"auto"`.
    pub qp: crate::control::QpBackend,
    /// Real-time iteration: one SQP iteration (one linearisation, one QP, full step) per
    /// control period from the shifted previous solution, instead of iterating to the KKT
    /// tolerance. Default `false`.
    pub rti: bool,
}

impl Default for SqpOptions {
    fn default() -> Self {
        let d = SqpSettings::default();
        Self {
            max_iterations: d.max_iterations,
            kkt_tolerance: d.kkt_tolerance,
            max_time_us: None,
            hessian: crate::control::HessianSetting::Auto,
            qp: crate::control::QpBackend::Auto,
            rti: d.real_time_iteration,
        }
    }
}

impl SqpOptions {
    /// The solver settings of this table: its keys set, the solver's defaults elsewhere
    /// (`hessian = "auto"`: the solver's default model, which the structured back-ends run as
    /// Gauss-Newton; [`crate::control::QpBackend::resolve`] names the one run).
    pub fn settings(&self) -> SqpSettings {
        let d = SqpSettings::default();
        SqpSettings {
            max_iterations: self.max_iterations,
            kkt_tolerance: self.kkt_tolerance,
            max_time: self.max_time_us.map(Duration::from_micros),
            hessian: self.hessian.model().unwrap_or(d.hessian),
            real_time_iteration: self.rti,
            ..SqpSettings::default()
        }
    }

    /// Checks the table with the solver's own ranges ([`SqpSettings::validate`]); the error
    /// names the key as `controller.sqp.max_time_us`.
    fn validate(&self) -> Result<(), ConfigError> {
        self.settings().validate().map_err(|e| match e {
            SolverError::InvalidSetting {
                field,
                value,
                allowed,
            } => {
                let key = match field {
                    "max_time" => "max_time_us",
                    "real_time_iteration" => "rti",
                    f => f,
                };
                ConfigError::new(format!("controller.sqp.{key}"), value, allowed)
            }
            other => ConfigError::new("controller.sqp", other, "valid solver settings"),
        })
    }
}

/// `[controller.pd]`: gains of the baseline PD controller.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PdSettings {
    /// Proportional gain (N·m/rad), > 0. Default 30 (60 with kd 6 already limit-cycles on
    /// the default scenario; 30/3 keeps RMS strap forces near 7 N thigh, 3 N shank at 0 kg).
    pub kp: f64,
    /// Derivative gain (N·m·s/rad), > 0. Default 3.
    pub kd: f64,
}

impl Default for PdSettings {
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
pub struct MultistageSettings {
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

impl Default for MultistageSettings {
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

pub use crate::control::{FallbackSettings, MonitorResponse, Monitors};

// ---------------------------------------------------------------------------------------------
// Scenario
// ---------------------------------------------------------------------------------------------

/// The complete scenario: plant, human, controller, estimator, faults and monitors.
///
/// `Experiment::default()` is the embedded default scenario of `docs/MODEL.md`.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Experiment {
    /// `[human]` (MODEL.md §2).
    pub human: HumanSettings,
    /// `[robot]` (MODEL.md §3).
    pub robot: RobotSettings,
    /// `[straps]` (MODEL.md §4).
    pub straps: StrapsSettings,
    /// `[uncertainty]` (MODEL.md §5).
    pub uncertainty: Uncertainty,
    /// `[trajectory]` (MODEL.md §6).
    pub trajectory: Trajectory,
    /// `[timing]` (MODEL.md §7).
    pub timing: TimingSettings,
    /// `[controller]` (MODEL.md §8).
    pub controller: ControllerSettings,
    /// `[multistage]` (MODEL.md §8).
    pub multistage: MultistageSettings,
    /// `[ekf]` (MODEL.md §8).
    pub ekf: Ekf,
    /// `[faults]`.
    pub faults: Faults,
    /// `[monitors]`.
    pub monitors: Monitors,
}

/// One check of [`Experiment::validate`] (a row of [`Experiment::CHECKS`]).
pub type Check = fn(&Experiment) -> Result<(), ConfigError>;

/// Most control steps one run may take (`duration / dt`), so that a tiny `dt` cannot start a
/// practically endless run.
pub const MAX_CONTROL_STEPS: usize = 100_000_000;

/// Maximum number of multi-stage scenarios.
pub const MAX_SCENARIOS: usize = 32;

impl Experiment {
    /// Checks every numeric field (finite and within its documented range) and the
    /// cross-field rules (nc <= np, robust_horizon <= nc, com within the link, ...): the
    /// checks of [`Self::CHECKS`], in order.
    ///
    /// Returns the first violation, naming the field by its dotted path.
    pub fn validate(&self) -> Result<(), ConfigError> {
        Self::CHECKS.iter().try_for_each(|(_, check)| check(self))
    }

    /// The checks of [`Self::validate`], one per table of the file, in the order they run
    /// (the first violation is reported): the table and its check. A table that is a lower
    /// module's settings type runs that type's own `validate` (its message prefixed with the
    /// table's path); the others, and the cross-field rules, are here.
    pub const CHECKS: &'static [(&'static str, Check)] = &[
        ("human", |s| s.human.validate()),
        ("robot", |s| s.robot.validate()),
        ("straps", Self::check_straps),
        ("uncertainty", |s| {
            s.uncertainty.validate().map_err(at("uncertainty"))
        }),
        ("trajectory", Self::check_trajectory_table),
        ("timing", Self::check_timing),
        ("controller", Self::check_controller),
        ("multistage", Self::check_multistage),
        ("ekf", |s| s.ekf.validate().map_err(at("ekf"))),
        ("faults", |s| s.faults.validate().map_err(at("faults"))),
        ("monitors", |s| {
            s.monitors.validate().map_err(at("monitors"))
        }),
    ];

    /// `[straps]`: the strap positions within their links (cross-field), stiffness and damping.
    fn check_straps(&self) -> Result<(), ConfigError> {
        let s = &self.straps;
        for (name, v, link, l) in [
            ("ls1_m", s.ls1_m, "thigh", self.robot.thigh.length),
            ("ls2_m", s.ls2_m, "shank", self.robot.shank.length),
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
        Ok(())
    }

    /// `[trajectory]`: its own checks, and the gait frequency `base ± swing` above 0 (cross-field).
    fn check_trajectory_table(&self) -> Result<(), ConfigError> {
        let sw = &self.trajectory.swing;
        let (swing, base) = (sw.frequency_swing_hz, sw.base_frequency_hz);
        self.trajectory
            .validate()
            .map_err(at("trajectory"))
            .map_err(|e| {
                on_field(e, "trajectory.frequency_swing_hz", swing >= base, Other {
                    key: "trajectory.base_frequency_hz",
                    value: base.to_string(),
                    relation: "<",
                    reason: "the gait frequency base ± swing stays above 0",
                    fix: format!("set trajectory.frequency_swing_hz < {base} or raise trajectory.base_frequency_hz"),
                })
            })?;
        Ok(())
    }

    /// `[timing]`: the control period, substeps and run lengths (at least one period, at most [`MAX_CONTROL_STEPS`]).
    fn check_timing(&self) -> Result<(), ConfigError> {
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
        Ok(())
    }

    /// `[controller]` with `[controller.sqp]`, `[controller.pd]` and `[controller.robust]`: horizons (`nc <= np`), weights, limits.
    fn check_controller(&self) -> Result<(), ConfigError> {
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
        c.sqp.validate()?;
        reals(
            "controller.pd",
            &[("kp", c.pd.kp, R::Pos), ("kd", c.pd.kd, R::Pos)],
        )?;
        let rb = &c.robust;
        reals(
            "controller.robust",
            &[
                ("human_bandwidth_hz", rb.human_bandwidth_hz, R::Pos),
                ("release_s", rb.release_s, R::Closed(0.0, 1e6)),
                (
                    "weight_smoothing_s",
                    rb.weight_smoothing_s,
                    R::Closed(0.0, 10.0),
                ),
                (
                    "observer_velocity_gain",
                    rb.observer_velocity_gain,
                    R::Closed(0.0, 1000.0),
                ),
            ],
        )?;
        Ok(())
    }

    /// `[multistage]`: the scenario set, `c1`, the probability floor (below `1 / S`) and the robust horizon (`<= controller.nc`).
    fn check_multistage(&self) -> Result<(), ConfigError> {
        let c = &self.controller;
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
        Ok(())
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

    /// Checks that `[trajectory]` can drive the `dof`-DOF run of [`Experiment::duration_s`]
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
            .map_err(at("trajectory"))
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
