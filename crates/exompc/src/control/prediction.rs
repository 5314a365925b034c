//! The NMPC prediction model (spec §8): the scenario's robot model, the disturbance estimate,
//! and the strap torque predicted from the human-intent estimate inside every RK4 stage.

use crate::model::{c, rk4_step, JointState, Real, RobotModel, Straps};
use nalgebra::{SMatrix, SVector};
use num_dual::{DualSVec64, DualStruct};
use serde::{Deserialize, Serialize};

/// How the strap torque is modelled over the horizon (spec §8).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Interaction {
    /// Predict `T_int(τ) = Jᵀ(ks J (q̂_H + τ q̂d_H − q(τ)) + cs J (q̂d_H − qd(τ)))` inside every
    /// RK4 stage from the human-intent estimate (the default).
    #[default]
    Predict,
    /// Hold the measured strap torque `Jᵀ F` over the horizon (the paper's literal reading).
    Hold,
}

/// Exact Jacobian of one prediction step `x⁺ = Φ(x, u)`, in `N×N` blocks.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StepJacobian<const N: usize> {
    /// `∂q⁺/∂q`.
    pub qq: SMatrix<f64, N, N>,
    /// `∂q⁺/∂qd`.
    pub qv: SMatrix<f64, N, N>,
    /// `∂qd⁺/∂q`.
    pub vq: SMatrix<f64, N, N>,
    /// `∂qd⁺/∂qd`.
    pub vv: SMatrix<f64, N, N>,
    /// `∂q⁺/∂u`.
    pub qu: SMatrix<f64, N, N>,
    /// `∂qd⁺/∂u`.
    pub vu: SMatrix<f64, N, N>,
}

/// One scenario's discrete prediction model over a control period.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PredictionModel<const N: usize> {
    /// Robot model of the scenario (smooth friction).
    pub robot: RobotModel<N>,
    /// Strap model.
    pub straps: Straps<N>,
    /// Interaction mode.
    pub interaction: Interaction,
    /// Control period (s).
    pub dt: f64,
    /// RK4 steps per control period.
    pub substeps: usize,
}

/// The inputs that are constant over one horizon.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HorizonInputs<const N: usize> {
    /// Human-intent angle estimate `q̂_H(k)` (rad).
    pub q_h: SVector<f64, N>,
    /// Human-intent velocity estimate `q̂d_H(k)` (rad/s).
    pub qd_h: SVector<f64, N>,
    /// Measured strap torque `Jᵀ F` (N·m), used by [`Interaction::Hold`].
    pub t_int_measured: SVector<f64, N>,
    /// Disturbance estimate `d̂` (N·m), added to the right-hand side of eq. 1.
    pub disturbance: SVector<f64, N>,
}

impl<const N: usize> PredictionModel<N> {
    /// State derivative at time `tau` after `t_k`: `(qd, M⁻¹(u + T_int(τ) + d − C qd − G − friction))`.
    #[inline]
    pub fn derivative<T: Real>(
        &self,
        tau: f64,
        x: &JointState<T, N>,
        u: &SVector<T, N>,
        inp: &HorizonInputs<N>,
    ) -> JointState<T, N> {
        let t_int: SVector<T, N> = match self.interaction {
            Interaction::Hold => inp.t_int_measured.map(c::<T>),
            Interaction::Predict => {
                let mut dq = x.q;
                let mut dqd = x.qd;
                for i in 0..N {
                    dq[i] = -x.q[i] + (inp.q_h[i] + tau * inp.qd_h[i]);
                    dqd[i] = -x.qd[i] + inp.qd_h[i];
                }
                self.straps.torque(&self.straps.force(&dq, &dqd))
            }
        };
        let mut tau_net = *u;
        for i in 0..N {
            tau_net[i] = u[i] + t_int[i] + inp.disturbance[i];
        }
        JointState {
            q: x.qd,
            qd: self.robot.acceleration(&x.q, &x.qd, &tau_net),
        }
    }

    /// One control period from `x` with torque `u` held, starting `tau0` after `t_k`.
    #[inline]
    pub fn step<T: Real>(
        &self,
        x: &JointState<T, N>,
        u: &SVector<T, N>,
        tau0: f64,
        inp: &HorizonInputs<N>,
    ) -> JointState<T, N> {
        let n = self.substeps.max(1);
        let h = self.dt / n as f64;
        let mut s = *x;
        for i in 0..n {
            s = rk4_step(
                |t, y: &JointState<T, N>| self.derivative(t, y, u, inp),
                tau0 + i as f64 * h,
                &s,
                h,
            );
        }
        s
    }

    /// [`Self::step`] with its exact Jacobian, by forward-mode dual numbers seeded on `q`, `qd`
    /// and `u` in three passes.
    pub fn step_with_jacobian(
        &self,
        x: &JointState<f64, N>,
        u: &SVector<f64, N>,
        tau0: f64,
        inp: &HorizonInputs<N>,
    ) -> (JointState<f64, N>, StepJacobian<N>) {
        type D<const N: usize> = DualSVec64<N>;
        let lift = |v: &SVector<f64, N>| v.map(D::<N>::from);
        let seed = |v: &SVector<f64, N>| {
            let mut out = lift(v);
            for i in 0..N {
                out[i] = D::<N>::from(v[i]).derivative(i);
            }
            out
        };
        let unpack = |s: &JointState<D<N>, N>| {
            let mut a = SMatrix::<f64, N, N>::zeros();
            let mut b = SMatrix::<f64, N, N>::zeros();
            for r in 0..N {
                if let Some(e) = &s.q[r].eps.0 {
                    for col in 0..N {
                        a[(r, col)] = e[col];
                    }
                }
                if let Some(e) = &s.qd[r].eps.0 {
                    for col in 0..N {
                        b[(r, col)] = e[col];
                    }
                }
            }
            (a, b)
        };
        let sq = self.step(
            &JointState {
                q: seed(&x.q),
                qd: lift(&x.qd),
            },
            &lift(u),
            tau0,
            inp,
        );
        let sv = self.step(
            &JointState {
                q: lift(&x.q),
                qd: seed(&x.qd),
            },
            &lift(u),
            tau0,
            inp,
        );
        let su = self.step(
            &JointState {
                q: lift(&x.q),
                qd: lift(&x.qd),
            },
            &seed(u),
            tau0,
            inp,
        );
        let (qq, vq) = unpack(&sq);
        let (qv, vv) = unpack(&sv);
        let (qu, vu) = unpack(&su);
        let next = JointState {
            q: sq.q.map(|v| v.re()),
            qd: sq.qd.map(|v| v.re()),
        };
        (
            next,
            StepJacobian {
                qq,
                qv,
                vq,
                vv,
                qu,
                vu,
            },
        )
    }
}
