//! The scenario-layer part of named multi-stage scenarios (docs/MODEL.md §8 "Scenarios"): each
//! scenario's prediction model, and the warnings about scenarios the EKF bank cannot tell apart.
//! The configuration types, resolution and validation live in [`crate::config::scenarios`] and
//! are re-exported here, so `exompc::scenario::multistage` is the one path users need.

use super::layout::{prediction_model, Dof, OneDof, TwoDof};
pub use crate::config::scenarios::*;
use crate::config::Experiment;
use crate::control::PredictionModel;
use crate::estimate::{EkfBank, EstimatorOptions};
#[cfg(not(feature = "std"))]
use crate::math::Float;
use crate::model::JointState;
use crate::sim::Trajectory;
use alloc::{format, string::String, string::ToString, vec, vec::Vec};
use core::fmt;
use nalgebra::SVector;

/// The prediction model of every scenario for layout `D` (docs/MODEL.md §8): the base model
/// with the scenario's override and payload. The EKF bank uses each model's robot.
pub fn prediction_models<D: Dof<N>, const N: usize>(s: &Experiment) -> Vec<PredictionModel<N>> {
    resolve(s)
        .iter()
        .map(|r| prediction_model::<D, N>(&r.apply_to(s), r.payload_kg))
        .collect()
}

// ---------------------------------------------------------------------------------------------
// Warnings: scenarios the estimator cannot tell apart
// ---------------------------------------------------------------------------------------------

/// Length of the identifiability test run (s), whatever the length of the run itself.
pub const IDENTIFY_WINDOW_S: f64 = 5.0;

/// Smallest accumulated log-likelihood ratio counted as distinguishable: `ln 10`, a 10:1
/// probability ratio from uniform.
pub const MIN_EVIDENCE: f64 = core::f64::consts::LN_10;

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
        cmp(&format!("robot.{l}.length_m"), la.length, lb.length);
        cmp(&format!("robot.{l}.mass_kg"), la.mass, lb.mass);
        cmp(&format!("robot.{l}.com_m"), la.com, lb.com);
        cmp(&format!("robot.{l}.inertia_kgm2"), la.inertia, lb.inertia);
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
/// scenario set. `s` should be valid ([`Experiment::validate`]); an invalid one gives no
/// warnings.
pub fn warnings(s: &Experiment, dof: usize) -> Vec<ScenarioWarning> {
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
    s: &Experiment,
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
    s: &Experiment,
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
        let w = 2.0 * core::f64::consts::PI * 5.0;
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
