//! Human-robot interaction straps as spring-dampers (paper eqs. 3-4, MODEL.md §4).

use super::Real;
use nalgebra::{SMatrix, SVector};

/// Strap model: `F = ks J (q_H − q_R) + cs J (qd_H − qd_R)`, `T_int = Jᵀ F` (paper eqs. 3-4).
/// The robot receives `+T_int`, the human `−T_int`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Straps<const N: usize> {
    /// Strap lever matrix `J` (m): row `s` maps joint angle differences to strap `s` stretch.
    pub j: SMatrix<f64, N, N>,
    /// Stiffness `ks` (N/m).
    pub stiffness: f64,
    /// Damping `cs` (N·s/m).
    pub damping: f64,
}

impl Straps<2> {
    /// The 2-DOF straps of MODEL.md §4: `J = [[Ls1, 0], [Ls1, Ls2]]`.
    pub fn two_dof(ls1: f64, ls2: f64, stiffness: f64, damping: f64) -> Self {
        Straps {
            j: SMatrix::<f64, 2, 2>::new(ls1, 0.0, ls1, ls2),
            stiffness,
            damping,
        }
    }
}

impl Straps<1> {
    /// The 1-DOF (hip locked) shank strap: `J = [Ls2]` (MODEL.md §6, paper eq. 4 with `dq_hip = 0`).
    pub fn one_dof(ls2: f64, stiffness: f64, damping: f64) -> Self {
        Straps {
            j: SMatrix::<f64, 1, 1>::new(ls2),
            stiffness,
            damping,
        }
    }
}

impl<const N: usize> Straps<N> {
    /// Strap forces (N) for angle differences `dq = q_H − q_R` and rate differences `dqd`.
    #[inline]
    pub fn force<T: Real>(&self, dq: &SVector<T, N>, dqd: &SVector<T, N>) -> SVector<T, N> {
        let mut f = *dq;
        for s in 0..N {
            let mut acc = T::zero();
            for i in 0..N {
                let jsi = self.j[(s, i)];
                if jsi != 0.0 {
                    acc += dq[i] * (self.stiffness * jsi) + dqd[i] * (self.damping * jsi);
                }
            }
            f[s] = acc;
        }
        f
    }

    /// Interaction torque `T_int = Jᵀ F` (N·m) for strap forces `f`.
    #[inline]
    pub fn torque<T: Real>(&self, f: &SVector<T, N>) -> SVector<T, N> {
        let mut t = *f;
        for i in 0..N {
            let mut acc = T::zero();
            for s in 0..N {
                let jsi = self.j[(s, i)];
                if jsi != 0.0 {
                    acc += f[s] * jsi;
                }
            }
            t[i] = acc;
        }
        t
    }

    /// Spring potential energy `½ ks |J dq|²` (J) of the straps.
    pub fn spring_energy(&self, dq: &SVector<f64, N>) -> f64 {
        0.5 * self.stiffness * (self.j * dq).norm_squared()
    }
}
