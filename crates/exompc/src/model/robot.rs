//! The exoskeleton robot: a chain with joint friction (paper eq. 1, MODEL.md §3).

use super::{c, Chain, Real};
use nalgebra::SVector;

/// Coulomb friction law.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Friction {
    /// `kf2 sign(qd)` — the plant (MODEL.md §3).
    Sign,
    /// `kf2 tanh(qd / width)` — the smooth law of prediction models (MODEL.md §3), `width` in rad/s.
    Tanh {
        /// Velocity scale of the smoothing (rad/s).
        width: f64,
    },
}

/// Robot dynamics of paper eq. 1 without the interaction and disturbance inputs:
/// `M qdd + C qd + G + kf1 qd + kf2 sign(qd) = tau`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RobotModel<const N: usize> {
    /// Rigid-body chain (payload and mass perturbation already merged into the links).
    pub chain: Chain<N>,
    /// Viscous friction `kf1` (N·m·s) per joint.
    pub viscous: f64,
    /// Coulomb friction `kf2` (N·m) per joint.
    pub coulomb: f64,
    /// Coulomb law.
    pub friction: Friction,
}

impl<const N: usize> RobotModel<N> {
    /// Friction torque `kf1 qd + kf2 sign(qd)` (or its smooth `tanh` version).
    #[inline]
    pub fn friction_torque<T: Real>(&self, qd: &SVector<T, N>) -> SVector<T, N> {
        let mut f = *qd;
        for i in 0..N {
            let coul = match self.friction {
                Friction::Sign => {
                    let r = qd[i].re();
                    c::<T>(if r > 0.0 {
                        self.coulomb
                    } else if r < 0.0 {
                        -self.coulomb
                    } else {
                        0.0
                    })
                }
                Friction::Tanh { width } => tanh(qd[i] * (1.0 / width)) * self.coulomb,
            };
            f[i] = qd[i] * self.viscous + coul;
        }
        f
    }

    /// Joint accelerations for the net external joint torque `tau` (applied torque plus
    /// interaction torque plus disturbance), friction included: paper eq. 1 solved for `qdd`.
    #[inline]
    pub fn acceleration<T: Real>(
        &self,
        q: &SVector<T, N>,
        qd: &SVector<T, N>,
        tau: &SVector<T, N>,
    ) -> SVector<T, N> {
        let fr = self.friction_torque(qd);
        let mut net = *tau;
        for i in 0..N {
            net[i] = tau[i] - fr[i];
        }
        self.chain.forward_dynamics(q, qd, &net)
    }
}

/// Argument beyond which [`tanh`] is exactly `±1` in `f64`.
const TANH_SATURATED: f64 = 19.0;

/// Overflow-safe `tanh` for any scalar: `sign(x) (1 − e)/(1 + e)` with `e = exp(−2|x|)`.
///
/// `num-dual`'s own `tanh` is `sinh/cosh`, which becomes `inf/inf = NaN` for `|x| > ~355`
/// (e.g. a joint speed above 3.5 rad/s with the 0.01 rad/s friction smoothing).
///
/// For `|x| ≥ 19` the value is exactly `±1` in `f64` (`e < 2⁻⁵⁴`, so `1 ± e` rounds to 1) and
/// is returned without the `exp` (the derivative there is below `4e−16`): with the default
/// 0.01 rad/s smoothing most joint speeds of a gait are in this range.
#[inline]
pub fn tanh<T: Real>(x: T) -> T {
    if x.re() >= TANH_SATURATED {
        return T::one();
    }
    if x.re() <= -TANH_SATURATED {
        return -T::one();
    }
    if x.re() >= 0.0 {
        let e = (x * -2.0).exp();
        (T::one() - e) / (T::one() + e)
    } else {
        let e = (x * 2.0).exp();
        (e - T::one()) / (T::one() + e)
    }
}
