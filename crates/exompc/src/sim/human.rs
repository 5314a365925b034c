//! The simulated human: leg model from Winter's tables and the "brain" (MODEL.md §2, paper §4.1).

use crate::model::{Chain, HumanSegment, Link};
use nalgebra::SVector;

/// The human leg of `N` segments: Winter fractions, height, and a body mass that may ramp.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HumanLeg<const N: usize> {
    /// Segment fractions from the hip outwards (1-DOF: the shank only).
    pub segments: [HumanSegment; N],
    /// Body height (m).
    pub height: f64,
}

impl<const N: usize> HumanLeg<N> {
    /// The leg's chain for body mass `body_mass` (kg).
    pub fn chain(&self, body_mass: f64) -> Chain<N> {
        let links: [Link; N] =
            core::array::from_fn(|i| self.segments[i].link(body_mass, self.height));
        Chain::new(links)
    }
}

/// The human "brain": feedback linearisation on the nominal model with PD gains and
/// compensation of the felt interaction torque (MODEL.md §2):
/// `T_H = M̂(q_H)(qdd_d + Kd(qd_d − qd_H) + Kp(q_d − q_H)) + Ĉ qd_H + Ĝ + T_int`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HumanBrain<const N: usize> {
    /// The nominal model the brain believes in (60 kg).
    pub nominal: Chain<N>,
    /// Proportional gain (1/s²), default 400.
    pub kp: f64,
    /// Derivative gain (1/s), default 40.
    pub kd: f64,
}

impl<const N: usize> HumanBrain<N> {
    /// Human joint torque for desired `(q_d, qd_d, qdd_d)`, actual `(q, qd)` and the interaction
    /// torque `t_int` acting on the robot (the human feels `−t_int` and compensates it).
    #[inline]
    pub fn torque(
        &self,
        desired: &(SVector<f64, N>, SVector<f64, N>, SVector<f64, N>),
        q: &SVector<f64, N>,
        qd: &SVector<f64, N>,
        t_int: &SVector<f64, N>,
    ) -> SVector<f64, N> {
        let (qdes, qddes, qdddes) = desired;
        let (m, cqd, g) = self.nominal.terms(q, qd);
        let v = qdddes + (qddes - qd) * self.kd + (qdes - q) * self.kp;
        m * v + cqd + g + t_int
    }
}
