//! Named multi-stage scenarios on any prediction-model parameter (`[[multistage.scenarios]]`,
//! docs/MODEL.md §8 "Scenarios").
//!
//! The multi-stage controller of paper §3.2 runs one NMPC and one EKF per scenario. By default
//! the scenarios differ only in the payload (`multistage.payloads_kg`, the paper's set-up). As
//! do-mpc lets users declare uncertain values, a scenario file may instead list named
//! scenarios, each a partial override of the base `[robot]` and `[straps]` tables plus the
//! payload the scenario's model carries:
//!
//! ```toml
//! [[multistage.scenarios]]
//! name = "soft straps"
//! straps.stiffness = 600.0
//!
//! [[multistage.scenarios]]
//! name = "heavy shank"
//! payload_kg = 1.0
//! robot.shank.mass_kg = 2.0
//! ```
//!
//! Each scenario's prediction model and EKF model are the base model with its override applied
//! ([`resolve`], [`prediction_models`](crate::scenario::multistage::prediction_models)); the controller and the estimator receive plain model
//! parameter sets ([`PredictionModel`](crate::control::PredictionModel)), never these configuration types. The payload list is
//! a shorthand: `payloads_kg = [0, 1, 2]` gives scenarios named `"0 kg"`, `"1 kg"`, `"2 kg"`
//! with the base robot and straps (exactly the models of the paper's set-up).
//!
//! [`validate`] checks every override with the ranges of the base tables and reports the field
//! as `multistage.scenarios[2].straps.stiffness`. [`warnings`](crate::scenario::multistage::warnings) lists pairs of scenarios the EKF
//! bank cannot tell apart (see [`ScenarioWarning`](crate::scenario::multistage::ScenarioWarning) for the criterion).

use super::{
    ConfigError, Experiment, Link, RobotSettings, StrapsSettings, MAX_PAYLOAD_KG, MAX_SCENARIOS,
};
use crate::check::{self, Range};
use alloc::{format, string::String, vec::Vec};
use serde::{Deserialize, Serialize};

// ---------------------------------------------------------------------------------------------
// Configuration types
// ---------------------------------------------------------------------------------------------

/// One `[[multistage.scenarios]]` entry: a named, partial override of the base model.
///
/// Keys absent from the entry keep the base table's value (`[robot]`, `[straps]`); the payload
/// of the scenario's model is `payload_kg` (absent: 0 kg, the nominal robot).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ScenarioSpec {
    /// Name shown in the trace columns, figure legends and summaries: non-empty, unique, at
    /// most 40 characters, no commas, quotes or control characters.
    pub name: String,
    /// Payload point mass the scenario's robot model carries at `robot.payload_position_m`
    /// (kg), in [0, 20]. Default 0.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub payload_kg: Option<f64>,
    /// Override of `[robot]` (links, friction, payload position).
    #[serde(default, skip_serializing_if = "RobotOverride::is_empty")]
    pub robot: RobotOverride,
    /// Override of `[straps]` (strap positions, stiffness, damping).
    #[serde(default, skip_serializing_if = "StrapsOverride::is_empty")]
    pub straps: StrapsOverride,
}

/// Partial `[robot]` table of a scenario; every key as in [`RobotSettings`].
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RobotOverride {
    /// `robot.viscous_friction` (N·m·s).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub viscous_friction: Option<f64>,
    /// `robot.coulomb_friction` (N·m).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub coulomb_friction: Option<f64>,
    /// `robot.coulomb_smoothing` (rad/s).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub coulomb_smoothing: Option<f64>,
    /// `robot.payload_position_m` (m).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub payload_position_m: Option<f64>,
    /// `robot.thigh.*`.
    #[serde(skip_serializing_if = "LinkOverride::is_empty")]
    pub thigh: LinkOverride,
    /// `robot.shank.*`.
    #[serde(skip_serializing_if = "LinkOverride::is_empty")]
    pub shank: LinkOverride,
}

/// Partial `[robot.thigh]` / `[robot.shank]` table; every key as in [`Link`].
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct LinkOverride {
    /// Link length (m).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub length_m: Option<f64>,
    /// Link mass (kg).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub mass_kg: Option<f64>,
    /// COM distance from the proximal joint (m).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub com_m: Option<f64>,
    /// Inertia about the COM (kg·m²).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub inertia_kgm2: Option<f64>,
}

/// Partial `[straps]` table of a scenario; every key as in [`StrapsSettings`].
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct StrapsOverride {
    /// Thigh strap distance from the hip (m).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub ls1_m: Option<f64>,
    /// Shank strap distance from the knee (m).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub ls2_m: Option<f64>,
    /// Strap stiffness (N/m).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub stiffness: Option<f64>,
    /// Strap damping (N·s/m).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub damping: Option<f64>,
}

impl ScenarioSpec {
    /// An entry with every key set (to the base defaults): the schema of
    /// `[[multistage.scenarios]]` for tools that check a file key by key.
    pub fn every_key() -> Self {
        let (r, st) = (RobotSettings::default(), StrapsSettings::default());
        let link = |l: Link| LinkOverride {
            length_m: Some(l.length),
            mass_kg: Some(l.mass),
            com_m: Some(l.com),
            inertia_kgm2: Some(l.inertia),
        };
        ScenarioSpec {
            name: "name".into(),
            payload_kg: Some(0.0),
            robot: RobotOverride {
                viscous_friction: Some(r.viscous_friction),
                coulomb_friction: Some(r.coulomb_friction),
                coulomb_smoothing: Some(r.coulomb_smoothing),
                payload_position_m: Some(r.payload_position_m),
                thigh: link(r.thigh),
                shank: link(r.shank),
            },
            straps: StrapsOverride {
                ls1_m: Some(st.ls1_m),
                ls2_m: Some(st.ls2_m),
                stiffness: Some(st.stiffness),
                damping: Some(st.damping),
            },
        }
    }
}

fn set(dst: &mut f64, v: Option<f64>) {
    if let Some(v) = v {
        *dst = v;
    }
}

impl LinkOverride {
    /// True when no key is given.
    pub fn is_empty(&self) -> bool {
        *self == Self::default()
    }

    /// `base` with the given keys replaced.
    pub fn apply(&self, mut base: Link) -> Link {
        set(&mut base.length, self.length_m);
        set(&mut base.mass, self.mass_kg);
        set(&mut base.com, self.com_m);
        set(&mut base.inertia, self.inertia_kgm2);
        base
    }
}

impl RobotOverride {
    /// True when no key is given.
    pub fn is_empty(&self) -> bool {
        *self == Self::default()
    }

    /// `base` with the given keys replaced.
    pub fn apply(&self, base: &RobotSettings) -> RobotSettings {
        let mut r = base.clone();
        set(&mut r.viscous_friction, self.viscous_friction);
        set(&mut r.coulomb_friction, self.coulomb_friction);
        set(&mut r.coulomb_smoothing, self.coulomb_smoothing);
        set(&mut r.payload_position_m, self.payload_position_m);
        r.thigh = self.thigh.apply(r.thigh);
        r.shank = self.shank.apply(r.shank);
        r
    }
}

impl StrapsOverride {
    /// True when no key is given.
    pub fn is_empty(&self) -> bool {
        *self == Self::default()
    }

    /// `base` with the given keys replaced.
    pub fn apply(&self, base: &StrapsSettings) -> StrapsSettings {
        let mut s = base.clone();
        set(&mut s.ls1_m, self.ls1_m);
        set(&mut s.ls2_m, self.ls2_m);
        set(&mut s.stiffness, self.stiffness);
        set(&mut s.damping, self.damping);
        s
    }
}

// ---------------------------------------------------------------------------------------------
// Resolution
// ---------------------------------------------------------------------------------------------

/// One scenario with its override applied: the full robot and strap tables of its model.
#[derive(Debug, Clone, PartialEq)]
pub struct ResolvedScenario {
    /// The scenario's name.
    pub name: String,
    /// Payload its robot model carries (kg).
    pub payload_kg: f64,
    /// `[robot]` of its model.
    pub robot: RobotSettings,
    /// `[straps]` of its model.
    pub straps: StrapsSettings,
}

impl ResolvedScenario {
    /// `s` with this scenario's robot and straps (the base of its models).
    pub fn apply_to(&self, s: &Experiment) -> Experiment {
        let mut out = s.clone();
        out.robot = self.robot.clone();
        out.straps = self.straps.clone();
        out
    }
}

/// Whether the scenarios come from `[[multistage.scenarios]]` (true) or from the
/// `payloads_kg` shorthand (false).
pub fn is_named(s: &Experiment) -> bool {
    !s.multistage.scenarios.is_empty()
}

/// Name of the payload-shorthand scenario with payload `kg`: `"0 kg"`, `"1.5 kg"`.
pub fn payload_name(kg: f64) -> String {
    format!("{kg} kg")
}

/// Number of multi-stage scenarios of `s`.
pub fn count(s: &Experiment) -> usize {
    if is_named(s) {
        s.multistage.scenarios.len()
    } else {
        s.multistage.payloads_kg.len()
    }
}

/// The scenario names of `s`, in order.
pub fn names(s: &Experiment) -> Vec<String> {
    if is_named(s) {
        s.multistage
            .scenarios
            .iter()
            .map(|c| c.name.clone())
            .collect()
    } else {
        s.multistage
            .payloads_kg
            .iter()
            .map(|&p| payload_name(p))
            .collect()
    }
}

/// Every scenario of `s` with its override applied to the base `[robot]` and `[straps]`.
pub fn resolve(s: &Experiment) -> Vec<ResolvedScenario> {
    if is_named(s) {
        s.multistage
            .scenarios
            .iter()
            .map(|c| ResolvedScenario {
                name: c.name.clone(),
                payload_kg: c.payload_kg.unwrap_or(0.0),
                robot: c.robot.apply(&s.robot),
                straps: c.straps.apply(&s.straps),
            })
            .collect()
    } else {
        s.multistage
            .payloads_kg
            .iter()
            .map(|&p| ResolvedScenario {
                name: payload_name(p),
                payload_kg: p,
                robot: s.robot.clone(),
                straps: s.straps.clone(),
            })
            .collect()
    }
}

// ---------------------------------------------------------------------------------------------
// Validation
// ---------------------------------------------------------------------------------------------

/// Longest scenario name accepted.
pub const MAX_NAME_LEN: usize = 40;

fn name_ok(n: &str) -> bool {
    !n.trim().is_empty()
        && n.trim() == n
        && n.chars().count() <= MAX_NAME_LEN
        && !n.chars().any(|c| c.is_control() || c == ',' || c == '"')
}

/// Checks the scenario set of `s` and returns the number of scenarios.
///
/// Payload shorthand: 1 to [`MAX_SCENARIOS`] payloads, each in [0, 20] kg. Named scenarios:
/// 1 to [`MAX_SCENARIOS`] entries, names valid and unique, `payload_kg` in [0, 20], and every
/// override key within the range of the base table (the scenario's resolved `[robot]` and
/// `[straps]` pass the base validation, cross-field rules included), reported as
/// `multistage.scenarios[i].robot.shank.mass_kg`. `payloads_kg` must keep its default when
/// named scenarios are given (the two would contradict each other).
pub fn validate(s: &Experiment) -> Result<usize, ConfigError> {
    let m = &s.multistage;
    if !is_named(s) {
        let n = m.payloads_kg.len();
        if n == 0 || n > MAX_SCENARIOS {
            return Err(ConfigError::new(
                "multistage.payloads_kg",
                format!("{:?} ({n} entries)", m.payloads_kg),
                format!("1 to {MAX_SCENARIOS} entries"),
            ));
        }
        for (i, &p) in m.payloads_kg.iter().enumerate() {
            payload(&format!("multistage.payloads_kg[{i}]"), p)?;
        }
        return Ok(n);
    }
    let n = m.scenarios.len();
    if n > MAX_SCENARIOS {
        return Err(ConfigError::new(
            "multistage.scenarios",
            format!("{n} entries"),
            format!("1 to {MAX_SCENARIOS} entries"),
        ));
    }
    if m.payloads_kg != crate::config::MultistageSettings::default().payloads_kg {
        return Err(ConfigError::new(
            "multistage.payloads_kg",
            format!("{:?}", m.payloads_kg),
            "absent when [[multistage.scenarios]] is given (give each scenario its payload_kg)",
        ));
    }
    for (i, c) in m.scenarios.iter().enumerate() {
        let p = format!("multistage.scenarios[{i}]");
        if !name_ok(&c.name) {
            return Err(ConfigError::new(
                format!("{p}.name"),
                format!("{:?}", c.name),
                format!(
                    "non-empty text of at most {MAX_NAME_LEN} characters, without leading or \
                     trailing spaces, commas, quotes or control characters"
                ),
            ));
        }
        if let Some(j) = m.scenarios[..i].iter().position(|o| o.name == c.name) {
            return Err(ConfigError::new(
                format!("{p}.name"),
                format!("{:?}", c.name),
                format!("a name not already used (multistage.scenarios[{j}])"),
            ));
        }
        if let Some(kg) = c.payload_kg {
            payload(&format!("{p}.payload_kg"), kg)?;
        }
    }
    for (i, r) in resolve(s).iter().enumerate() {
        // The base tables are valid (checked before): an error of the scenario's resolved
        // tables comes from its override, or from a cross-field rule the override breaks.
        let mut probe = r.apply_to(s);
        probe.multistage = crate::config::MultistageSettings::default();
        if let Err(e) = probe.validate() {
            if e.field.starts_with("robot.") || e.field.starts_with("straps.") {
                return Err(ConfigError {
                    field: format!("multistage.scenarios[{i}].{}", e.field),
                    ..e
                });
            }
            return Err(e);
        }
    }
    Ok(n)
}

fn payload(path: &str, v: f64) -> Result<(), ConfigError> {
    Ok(check::real(path, v, Range::Closed(0.0, MAX_PAYLOAD_KG))?)
}
