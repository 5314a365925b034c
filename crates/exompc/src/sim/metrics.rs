//! Metrics of paper Table 2 (MODEL.md §9), accumulated online from the closed loop.

use super::closed_loop::{Recorder, StepRecord};
#[cfg(not(feature = "std"))]
use crate::math::Float;
use alloc::{string::String, string::ToString, vec, vec::Vec};
use serde::{Deserialize, Serialize};

/// Controller compute time per step (µs).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct StepTimeStats {
    /// Mean (µs).
    pub mean: f64,
    /// Median (µs).
    pub p50: f64,
    /// 99th percentile (µs).
    pub p99: f64,
    /// Maximum (µs).
    pub max: f64,
}

impl StepTimeStats {
    /// Statistics of `samples` (sorted in place).
    pub fn from_samples(samples: &mut [f64]) -> Self {
        if samples.is_empty() {
            return Self::default();
        }
        samples.sort_by(f64::total_cmp);
        let n = samples.len();
        let pct = |p: f64| samples[((p * (n - 1) as f64).round() as usize).min(n - 1)];
        StepTimeStats {
            mean: samples.iter().sum::<f64>() / n as f64,
            p50: pct(0.5),
            p99: pct(0.99),
            max: samples[n - 1],
        }
    }
}

/// A thigh/shank (or hip/knee) pair; `None` for the thigh/hip in 1-DOF runs.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct StrapPair {
    /// Thigh strap (N) — `null` in 1-DOF runs.
    pub thigh: Option<f64>,
    /// Shank strap (N).
    pub shank: Option<f64>,
}

/// Hip/knee pair; `hip` is `None` in 1-DOF runs.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct JointPair {
    /// Hip (deg) — `null` in 1-DOF runs.
    pub hip: Option<f64>,
    /// Knee (deg).
    pub knee: Option<f64>,
}

/// One run's summary (paper Table 2 columns plus compute time and safety counters).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Summary {
    /// Controller name.
    pub controller: String,
    /// Degrees of freedom (1 or 2).
    pub dof: usize,
    /// True payload (kg).
    pub payload_kg: f64,
    /// Simulated duration (s).
    pub duration_s: f64,
    /// Control steps.
    pub steps: usize,
    /// RMS of the true strap forces (N).
    pub rms_force_n: StrapPair,
    /// Maximum absolute human-robot angle difference per joint (deg).
    pub delta_max_deg: JointPair,
    /// Time-average of each scenario probability (fraction, 0-1), `null` without scenarios.
    pub mean_probability: Option<Vec<f64>>,
    /// Names of the multi-stage scenarios, in the order of `mean_probability` (`"0 kg"`, ...
    /// for the payload shorthand, else the `[[multistage.scenarios]]` names); `null` without
    /// scenarios.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub scenarios: Option<Vec<String>>,
    /// The QP back-end and Hessian model the NMPC solves ran (`[controller.sqp] qp` and
    /// `hessian` resolved, `control::QpBackend::resolve`); `null` for a controller without
    /// an SQP (`pd`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub solver: Option<crate::control::SolverChoice>,
    /// Controller compute time per step (µs).
    pub step_time_us: StepTimeStats,
    /// Steps whose torque violated a limit (must be 0).
    pub limit_violations: u64,
    /// Steps whose solve did not converge (fallback or best iterate used).
    pub solver_failures: u64,
    /// Safety supervisor: monitor trips (per kind, first time), monitor-held and rejected steps.
    #[serde(default)]
    pub safety: super::SafetySummary,
}

/// Online accumulator of the summary metrics (MODEL.md §9, §8a: true forces and angle differences
/// at the control instants).
#[derive(Clone, Debug, Default)]
pub struct Metrics {
    steps: usize,
    sum_f2: Vec<f64>,
    delta_max: Vec<f64>,
    prob_sum: Vec<f64>,
    times: Vec<f64>,
    limit_violations: u64,
    solver_failures: u64,
}

impl Metrics {
    /// An empty accumulator with room for `steps` step times.
    pub fn with_capacity(steps: usize) -> Self {
        Metrics {
            times: Vec::with_capacity(steps),
            ..Default::default()
        }
    }

    /// Finish into a summary.
    pub fn summary(&self, controller: &str, dof: usize, payload_kg: f64, dt: f64) -> Summary {
        let n = self.steps.max(1) as f64;
        let rms: Vec<f64> = self.sum_f2.iter().map(|s| (s / n).sqrt()).collect();
        let deg: Vec<f64> = self.delta_max.iter().map(|d| d.to_degrees()).collect();
        let pair = |v: &[f64]| match v.len() {
            2 => (Some(v[0]), Some(v[1])),
            1 => (None, Some(v[0])),
            _ => (None, None),
        };
        let (thigh, shank) = pair(&rms);
        let (hip, knee) = pair(&deg);
        let mut times = self.times.clone();
        Summary {
            controller: controller.to_string(),
            dof,
            payload_kg,
            duration_s: self.steps as f64 * dt,
            steps: self.steps,
            rms_force_n: StrapPair { thigh, shank },
            delta_max_deg: JointPair { hip, knee },
            mean_probability: if self.prob_sum.is_empty() {
                None
            } else {
                Some(self.prob_sum.iter().map(|s| s / n).collect())
            },
            scenarios: None,
            solver: None,
            step_time_us: StepTimeStats::from_samples(&mut times),
            limit_violations: self.limit_violations,
            solver_failures: self.solver_failures,
            safety: Default::default(),
        }
    }
}

impl<const N: usize> Recorder<N> for Metrics {
    fn record(&mut self, r: &StepRecord<'_, N>) -> super::closed_loop::RecordResult {
        if self.sum_f2.is_empty() {
            self.sum_f2 = vec![0.0; N];
            self.delta_max = vec![0.0; N];
        }
        for i in 0..N {
            self.sum_f2[i] += r.force_true[i] * r.force_true[i];
            // A NaN difference must propagate (f64::max would silently drop it).
            let d = (r.human.q[i] - r.robot.q[i]).abs();
            if d.is_nan() || d > self.delta_max[i] {
                self.delta_max[i] = d;
            }
        }
        if let Some(p) = r.probabilities {
            if self.prob_sum.len() != p.len() {
                self.prob_sum = vec![0.0; p.len()];
            }
            for (s, v) in self.prob_sum.iter_mut().zip(p) {
                *s += v;
            }
        }
        self.times.push(r.step_time_us);
        self.limit_violations += u64::from(!r.within_limits);
        self.solver_failures += u64::from(r.status.is_solver_failure());
        self.steps += 1;
        Ok(())
    }
}
