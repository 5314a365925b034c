//! Baseline controller: gravity compensation plus PD toward the human-intent estimate.

use super::{ControlOutput, Controller, IntentEstimator, Measurement, StepStatus, TorqueLimits};
use crate::model::{RobotModel, Straps};
use nalgebra::SVector;

/// `T = G_R(q) + Kp (q̂_H − q) + Kd (q̂d_H − qd)` on the nominal robot model, with the intent
/// estimate of paper eqs. 5-6, clamped to the limits of eqs. 8-9. A simple baseline so the
/// simulator works without an optimiser.
#[derive(Clone, Debug)]
pub struct PdController<const N: usize> {
    model: RobotModel<N>,
    intent: IntentEstimator,
    /// The straps the intent gains are derived from (`k1 = "auto"`).
    straps: Straps<N>,
    limits: TorqueLimits,
    kp: f64,
    kd: f64,
    prev: SVector<f64, N>,
}

impl<const N: usize> PdController<N> {
    /// A PD controller with gains `kp` (N·m/rad), `kd` (N·m·s/rad) and initial torque `t0`;
    /// `straps` give the intent gains derived from the strap model.
    pub fn new(
        model: RobotModel<N>,
        intent: IntentEstimator,
        straps: Straps<N>,
        limits: TorqueLimits,
        kp: f64,
        kd: f64,
        t0: SVector<f64, N>,
    ) -> Self {
        PdController {
            model,
            intent,
            straps,
            limits,
            kp,
            kd,
            prev: limits.admissible(&t0),
        }
    }
}

impl<const N: usize> Controller<N> for PdController<N> {
    fn step(&mut self, m: &Measurement<N>) -> ControlOutput<N> {
        if !m.is_finite() {
            return ControlOutput {
                torque: self.prev,
                status: StepStatus::BadMeasurement,
                iterations: 0,
            };
        }
        let (qh, qdh) = self.intent.estimate(m, &self.straps);
        let desired =
            self.model.chain.gravity_torque(&m.q) + (qh - m.q) * self.kp + (qdh - m.qd) * self.kd;
        let t = self.limits.clamp(&self.prev, &desired);
        self.prev = t;
        ControlOutput {
            torque: t,
            status: StepStatus::Ok,
            iterations: 0,
        }
    }

    fn name(&self) -> &'static str {
        "pd"
    }

    fn previous_torque(&self) -> SVector<f64, N> {
        self.prev
    }

    fn set_previous_torque(&mut self, t: SVector<f64, N>) {
        self.prev = self.limits.admissible(&t);
    }
}
