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
//! ([`resolve`], [`prediction_models`]); the controller and the estimator receive plain model
//! parameter sets ([`PredictionModel`]), never these configuration types. The payload list is
//! a shorthand: `payloads_kg = [0, 1, 2]` gives scenarios named `"0 kg"`, `"1 kg"`, `"2 kg"`
//! with the base robot and straps (exactly the models of the paper's set-up).
//!
//! [`validate`] checks every override with the ranges of the base tables and reports the field
//! as `multistage.scenarios[2].straps.stiffness`. [`warnings`] lists pairs of scenarios the EKF
//! bank cannot tell apart (see [`ScenarioWarning`] for the criterion).

use crate::config::{
    ConfigError, Robot, RobotLink, Scenario, Straps, MAX_PAYLOAD_KG, MAX_SCENARIOS,
};
use crate::control::PredictionModel;
use crate::estimate::{EkfBank, EstimatorOptions};
use crate::model::JointState;
use crate::sim::{prediction_model, Dof, OneDof, Trajectory, TwoDof};
use nalgebra::SVector;
use serde::{Deserialize, Serialize};
use std::fmt;

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

/// Partial `[robot]` table of a scenario; every key as in [`Robot`].
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

/// Partial `[robot.thigh]` / `[robot.shank]` table; every key as in [`RobotLink`].
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

/// Partial `[straps]` table of a scenario; every key as in [`Straps`].
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
        let (r, st) = (Robot::default(), Straps::default());
        let link = |l: RobotLink| LinkOverride {
            length_m: Some(l.length_m),
            mass_kg: Some(l.mass_kg),
            com_m: Some(l.com_m),
            inertia_kgm2: Some(l.inertia_kgm2),
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
    pub fn apply(&self, mut base: RobotLink) -> RobotLink {
        set(&mut base.length_m, self.length_m);
        set(&mut base.mass_kg, self.mass_kg);
        set(&mut base.com_m, self.com_m);
        set(&mut base.inertia_kgm2, self.inertia_kgm2);
        base
    }
}

impl RobotOverride {
    /// True when no key is given.
    pub fn is_empty(&self) -> bool {
        *self == Self::default()
    }

    /// `base` with the given keys replaced.
    pub fn apply(&self, base: &Robot) -> Robot {
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
    pub fn apply(&self, base: &Straps) -> Straps {
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
    pub robot: Robot,
    /// `[straps]` of its model.
    pub straps: Straps,
}

impl ResolvedScenario {
    /// `s` with this scenario's robot and straps (the base of its models).
    pub fn apply_to(&self, s: &Scenario) -> Scenario {
        let mut out = s.clone();
        out.robot = self.robot.clone();
        out.straps = self.straps.clone();
        out
    }
}

/// Whether the scenarios come from `[[multistage.scenarios]]` (true) or from the
/// `payloads_kg` shorthand (false).
pub fn is_named(s: &Scenario) -> bool {
    !s.multistage.scenarios.is_empty()
}

/// Name of the payload-shorthand scenario with payload `kg`: `"0 kg"`, `"1.5 kg"`.
pub fn payload_name(kg: f64) -> String {
    format!("{kg} kg")
}

/// Number of multi-stage scenarios of `s`.
pub fn count(s: &Scenario) -> usize {
    if is_named(s) {
        s.multistage.scenarios.len()
    } else {
        s.multistage.payloads_kg.len()
    }
}

/// The scenario names of `s`, in order.
pub fn names(s: &Scenario) -> Vec<String> {
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
pub fn resolve(s: &Scenario) -> Vec<ResolvedScenario> {
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

/// The prediction model of every scenario for layout `D` (docs/MODEL.md §8): the base model
/// with the scenario's override and payload. The EKF bank uses each model's robot.
pub fn prediction_models<D: Dof<N>, const N: usize>(s: &Scenario) -> Vec<PredictionModel<N>> {
    resolve(s)
        .iter()
        .map(|r| prediction_model::<D, N>(&r.apply_to(s), r.payload_kg))
        .collect()
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
pub fn validate(s: &Scenario) -> Result<usize, ConfigError> {
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
    if m.payloads_kg != crate::config::Multistage::default().payloads_kg {
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
        probe.multistage = crate::config::Multistage::default();
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
    if v.is_finite() && (0.0..=MAX_PAYLOAD_KG).contains(&v) {
        Ok(())
    } else {
        Err(ConfigError::new(
            path,
            v,
            format!("finite, in [0, {MAX_PAYLOAD_KG}]"),
        ))
    }
}

// ---------------------------------------------------------------------------------------------
// Warnings: scenarios the estimator cannot tell apart
// ---------------------------------------------------------------------------------------------

/// Length of the identifiability test run (s), whatever the length of the run itself.
pub const IDENTIFY_WINDOW_S: f64 = 5.0;

/// Smallest accumulated log-likelihood ratio counted as distinguishable: `ln 10`, a 10:1
/// probability ratio from uniform.
pub const MIN_EVIDENCE: f64 = std::f64::consts::LN_10;

/// Why two scenarios cannot be told apart by the EKF bank.
#[derive(Debug, Clone, PartialEq)]
pub enum Indistinguishable {
    /// Their prediction models (NMPC and EKF) are the same in this layout.
    Identical,
    /// Their EKF models are the same; the models differ only in the listed keys, which enter
    /// the NMPC prediction but not the EKF (strap stiffness and damping: the EKF takes the
    /// measured strap force).
    NotInEstimator,
    /// Their EKF models differ too little: fed `IDENTIFY_WINDOW_S` of noise-free data that one
    /// of them explains exactly, the bank's accumulated log-likelihood ratio stays below
    /// [`MIN_EVIDENCE`] (the value given here).
    TooClose {
        /// The smaller of the two accumulated log-likelihood ratios (either truth).
        evidence: f64,
    },
}

/// A pair of scenarios the EKF bank cannot tell apart: their probabilities stay equal (or
/// nearly), so the multi-stage controller cannot favour the right one.
///
/// Criterion, for the layout of the run (1-DOF ignores the thigh and `ls1_m`):
/// 1. the two scenarios' prediction models are equal: [`Indistinguishable::Identical`];
/// 2. their EKF models (robot model with payload and friction) are equal:
///    [`Indistinguishable::NotInEstimator`];
/// 3. otherwise an identifiability run: for each of the two as the truth, the scenario's robot
///    follows the run's desired trajectory for [`IDENTIFY_WINDOW_S`] under computed-torque
///    control with its own model (no strap force, no noise); the EKF bank of the run's
///    settings (`[ekf]`, `c1`, innovation) filters that motion, and the log-likelihoods of
///    eq. 10 are summed. If the truth's sum exceeds the other's by less than [`MIN_EVIDENCE`]
///    for either truth, even perfect data would not move the probabilities 10:1 apart in that
///    time: [`Indistinguishable::TooClose`]. Measurement noise and filter lag only make it
///    harder, so the warning errs on the side of silence.
#[derive(Debug, Clone, PartialEq)]
pub struct ScenarioWarning {
    /// Indices of the two scenarios.
    pub pair: (usize, usize),
    /// Their names.
    pub names: (String, String),
    /// Configuration keys whose values differ between the two (e.g. `straps.stiffness`).
    pub differing: Vec<String>,
    /// Why they are indistinguishable.
    pub reason: Indistinguishable,
}

impl fmt::Display for ScenarioWarning {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let (a, b) = &self.names;
        let which = format!(
            "multi-stage scenarios \"{a}\" and \"{b}\" (#{} and #{})",
            self.pair.0 + 1,
            self.pair.1 + 1
        );
        let keys = if self.differing.is_empty() {
            "nothing".to_string()
        } else {
            self.differing.join(", ")
        };
        match &self.reason {
            Indistinguishable::Identical => write!(
                f,
                "{which} have the same model in this layout (they differ in: {keys}); the \
                 estimator cannot tell them apart"
            ),
            Indistinguishable::NotInEstimator => write!(
                f,
                "{which} differ only in {keys}, which the EKF bank does not model (it takes \
                 the measured strap force): the estimator cannot tell them apart and their \
                 probabilities stay equal"
            ),
            Indistinguishable::TooClose { evidence } => write!(
                f,
                "{which} differ too little for the estimator to tell apart (in: {keys}): over \
                 {IDENTIFY_WINDOW_S} s of noise-free data the log-likelihood ratio reaches \
                 only {evidence:.3} (< ln 10)"
            ),
        }
    }
}

/// The configuration keys whose values differ between two resolved scenarios.
pub fn differing_keys(a: &ResolvedScenario, b: &ResolvedScenario) -> Vec<String> {
    let mut out = Vec::new();
    let mut cmp = |k: &str, x: f64, y: f64| {
        if x != y {
            out.push(k.to_string());
        }
    };
    cmp("payload_kg", a.payload_kg, b.payload_kg);
    let (ra, rb) = (&a.robot, &b.robot);
    cmp(
        "robot.viscous_friction",
        ra.viscous_friction,
        rb.viscous_friction,
    );
    cmp(
        "robot.coulomb_friction",
        ra.coulomb_friction,
        rb.coulomb_friction,
    );
    cmp(
        "robot.coulomb_smoothing",
        ra.coulomb_smoothing,
        rb.coulomb_smoothing,
    );
    cmp(
        "robot.payload_position_m",
        ra.payload_position_m,
        rb.payload_position_m,
    );
    for (l, la, lb) in [
        ("thigh", &ra.thigh, &rb.thigh),
        ("shank", &ra.shank, &rb.shank),
    ] {
        cmp(&format!("robot.{l}.length_m"), la.length_m, lb.length_m);
        cmp(&format!("robot.{l}.mass_kg"), la.mass_kg, lb.mass_kg);
        cmp(&format!("robot.{l}.com_m"), la.com_m, lb.com_m);
        cmp(
            &format!("robot.{l}.inertia_kgm2"),
            la.inertia_kgm2,
            lb.inertia_kgm2,
        );
    }
    let (sa, sb) = (&a.straps, &b.straps);
    cmp("straps.ls1_m", sa.ls1_m, sb.ls1_m);
    cmp("straps.ls2_m", sa.ls2_m, sb.ls2_m);
    cmp("straps.stiffness", sa.stiffness, sb.stiffness);
    cmp("straps.damping", sa.damping, sb.damping);
    out
}

/// The pairs of scenarios of `s` that the EKF bank cannot tell apart in the `dof`-DOF layout
/// (1 or 2), see [`ScenarioWarning`]. Empty for a single scenario, and for the default
/// scenario set. `s` should be valid ([`Scenario::validate`]); an invalid one gives no
/// warnings.
pub fn warnings(s: &Scenario, dof: usize) -> Vec<ScenarioWarning> {
    if s.validate().is_err() {
        return Vec::new();
    }
    if dof == 1 {
        warnings_for::<OneDof, 1, 3, 2>(s)
    } else {
        warnings_for::<TwoDof, 2, 6, 4>(s)
    }
}

/// [`warnings`] for layout `D` (`NA = 3N`, `NY = 2N` as in the EKF bank).
pub fn warnings_for<D: Dof<N>, const N: usize, const NA: usize, const NY: usize>(
    s: &Scenario,
) -> Vec<ScenarioWarning> {
    let resolved = resolve(s);
    let models = prediction_models::<D, N>(s);
    let n = models.len();
    let mut out = Vec::new();
    let mut numeric = Vec::new();
    for i in 0..n {
        for j in i + 1..n {
            let reason = if models[i] == models[j] {
                Some(Indistinguishable::Identical)
            } else if models[i].robot == models[j].robot {
                Some(Indistinguishable::NotInEstimator)
            } else {
                numeric.push((i, j));
                None
            };
            if let Some(reason) = reason {
                out.push(warning(&resolved, i, j, reason));
            }
        }
    }
    if !numeric.is_empty() {
        let ev = evidence::<D, N, NA, NY>(s, &models);
        for (i, j) in numeric {
            let e = (ev[i][i] - ev[i][j]).min(ev[j][j] - ev[j][i]);
            if e.is_nan() || e < MIN_EVIDENCE {
                out.push(warning(
                    &resolved,
                    i,
                    j,
                    Indistinguishable::TooClose { evidence: e },
                ));
            }
        }
    }
    out.sort_by_key(|w| w.pair);
    out
}

fn warning(
    r: &[ResolvedScenario],
    i: usize,
    j: usize,
    reason: Indistinguishable,
) -> ScenarioWarning {
    ScenarioWarning {
        pair: (i, j),
        names: (r[i].name.clone(), r[j].name.clone()),
        differing: differing_keys(&r[i], &r[j]),
        reason,
    }
}

/// `ev[t][j]`: with scenario `t` as the truth, the log-likelihood of eq. 10 of scenario `j`'s
/// filter summed over the identifiability run (see [`ScenarioWarning`]).
fn evidence<D: Dof<N>, const N: usize, const NA: usize, const NY: usize>(
    s: &Scenario,
    models: &[PredictionModel<N>],
) -> Vec<Vec<f64>> {
    let robots: Vec<_> = models.iter().map(|m| m.robot).collect();
    let opts = EstimatorOptions {
        dt: s.timing.dt,
        substeps: s.timing.prediction_substeps,
        innovation: s.multistage.innovation,
        c1: s.multistage.c1,
        floor: 0.0,
    };
    let traj = D::trajectory(s);
    let dt = s.timing.dt;
    // A property of the models, not of the run: the same window whatever the run length.
    let steps = ((IDENTIFY_WINDOW_S / dt).round() as usize).max(1);
    // Computed-torque gains of the data generator: a 2 %-overshoot 5 Hz loop.
    let (kp, kd) = {
        let w = 2.0 * std::f64::consts::PI * 5.0;
        (w * w, 1.6 * w)
    };
    let zero = SVector::<f64, N>::zeros();
    let mut out = vec![vec![0.0; robots.len()]; robots.len()];
    for (t, truth) in robots.iter().enumerate() {
        let (q0, qd0, _) = traj.eval(0.0);
        let Ok(mut bank) = EkfBank::<N, NA, NY>::new(&robots, &s.ekf, &opts, &q0, &qd0) else {
            return out;
        };
        let truth_ekf = bank.filters()[t];
        let mut x = JointState { q: q0, qd: qd0 };
        for k in 0..steps {
            let (q_des, qd_des, qdd_des) = traj.eval(k as f64 * dt);
            let a = qdd_des + (q_des - x.q) * kp + (qd_des - x.qd) * kd;
            let bias = truth.acceleration(&x.q, &x.qd, &zero);
            let u = truth.chain.mass_matrix(&x.q) * (a - bias);
            let mut xa = SVector::<f64, NA>::zeros();
            for i in 0..N {
                xa[i] = x.q[i];
                xa[N + i] = x.qd[i];
            }
            let xn = truth_ekf.predict(&xa, &u, &zero);
            let mut y = SVector::<f64, NY>::zeros();
            for i in 0..2 * N {
                y[i] = xn[i];
            }
            x = JointState {
                q: SVector::from_fn(|i, _| xn[i]),
                qd: SVector::from_fn(|i, _| xn[N + i]),
            };
            if bank.step(&y, &u, &zero).is_err() {
                break;
            }
            for (o, l) in out[t].iter_mut().zip(bank.log_likelihoods()) {
                *o += l;
            }
        }
    }
    out
}
