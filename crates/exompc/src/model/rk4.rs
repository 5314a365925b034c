//! The classical fourth-order Runge-Kutta step shared by the prediction model, the estimator and
//! the plant (paper §3.1: "discretized using the 4th-order Runge-Kutta method").

use super::Real;
use nalgebra::SVector;

/// A state that RK4 can combine: `self + h·d`.
pub trait RkState: Sized {
    /// `self + h · d`.
    fn add_scaled(&self, h: f64, d: &Self) -> Self;
}

/// Two states integrated together (e.g. a state and its sensitivity), combined component-wise.
impl<A: RkState, B: RkState> RkState for (A, B) {
    #[inline(always)]
    fn add_scaled(&self, h: f64, d: &Self) -> Self {
        (self.0.add_scaled(h, &d.0), self.1.add_scaled(h, &d.1))
    }
}

/// Joint positions and velocities of one chain.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct JointState<T: Real, const N: usize> {
    /// Joint angles (rad).
    pub q: SVector<T, N>,
    /// Joint velocities (rad/s).
    pub qd: SVector<T, N>,
}

impl<T: Real, const N: usize> RkState for JointState<T, N> {
    #[inline(always)]
    fn add_scaled(&self, h: f64, d: &Self) -> Self {
        let mut out = *self;
        for i in 0..N {
            out.q[i] += d.q[i] * h;
            out.qd[i] += d.qd[i] * h;
        }
        out
    }
}

/// One RK4 step of `ẋ = f(t, x)` from `(t, x)` over `h`.
#[inline]
pub fn rk4_step<S: RkState>(mut f: impl FnMut(f64, &S) -> S, t: f64, x: &S, h: f64) -> S {
    let k1 = f(t, x);
    let k2 = f(t + 0.5 * h, &x.add_scaled(0.5 * h, &k1));
    let k3 = f(t + 0.5 * h, &x.add_scaled(0.5 * h, &k2));
    let k4 = f(t + h, &x.add_scaled(h, &k3));
    // x + h/6 (k1 + 2 k2 + 2 k3 + k4)
    x.add_scaled(h / 6.0, &k1)
        .add_scaled(h / 3.0, &k2)
        .add_scaled(h / 3.0, &k3)
        .add_scaled(h / 6.0, &k4)
}
