//! Second derivatives of the prediction step for the exact-Hessian SQP
//! (`[controller.sqp] hessian = "exact"`, [`crate::solver::HessianModel::Exact`]).
//!
//! The cost of eq. 7 is `½‖r‖²` with residuals linear in the predicted states, so the Hessian of
//! the Lagrangian of one multiple-shooting stage `j` is the residual part `JᵀJ` plus
//!
//! ```text
//! W_j = ∇²_{(q_j, qd_j, T_j)} [ λ_{j+1}ᵀ Φ(q_j, qd_j, T_j) ]
//! ```
//!
//! with `Φ` the RK4 prediction step (docs/MODEL.md §8) and `λ_{j+1}` the adjoint (costate) of the
//! cost gradient, `λ_{Np} = ∇_{x_Np} ½‖r‖²`, `λ_j = ∇_{x_j} ½‖r‖² + F_jᵀ λ_{j+1}` (`F_j` the
//! `(q, qd)` block of the step Jacobian). Summed over the stages and condensed with the state
//! sensitivities, `Σ_j Γ_jᵀ W_j Γ_j` is the exact second-order term `Σ rᵢ ∇²rᵢ` of the
//! single-shooting cost (the constraints of eqs. 8–9 are linear, so this is the exact Lagrangian
//! Hessian of the SQP as in acados/HPIPM's exact-Hessian mode).
//!
//! `W_j` is computed exactly by forward-mode hyper-dual numbers (`num-dual`'s `HyperDual64`,
//! one pass through the generic [`PredictionModel::step`] per pair of the `3N` stage variables);
//! the tests check it against finite differences of the exact first-order Jacobian.

use super::prediction::{HorizonInputs, PredictionModel, StepJacobian};
use crate::model::JointState;
use alloc::{vec, vec::Vec};
use nalgebra::{DMatrix, SMatrix, SVector};
#[cfg(feature = "std")]
use num_dual::HyperDual64;

/// The symmetric `3N × 3N` Hessian of `λ_qᵀ q⁺ + λ_vᵀ qd⁺` of one prediction step with respect
/// to `(q, qd, u)` (`u` the torque held over the step), in `N × N` blocks.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StepHessian<const N: usize> {
    /// `∂²/∂q∂q`.
    pub qq: SMatrix<f64, N, N>,
    /// `∂²/∂q∂qd` (rows `q`, columns `qd`).
    pub qv: SMatrix<f64, N, N>,
    /// `∂²/∂q∂u`.
    pub qu: SMatrix<f64, N, N>,
    /// `∂²/∂qd∂qd`.
    pub vv: SMatrix<f64, N, N>,
    /// `∂²/∂qd∂u`.
    pub vu: SMatrix<f64, N, N>,
    /// `∂²/∂u∂u`.
    pub uu: SMatrix<f64, N, N>,
}

impl<const N: usize> StepHessian<N> {
    /// All blocks zero.
    pub fn zeros() -> Self {
        let z = SMatrix::zeros();
        StepHessian {
            qq: z,
            qv: z,
            qu: z,
            vv: z,
            vu: z,
            uu: z,
        }
    }

    /// Entry `(a, b)` of the full matrix, variables ordered `(q, qd, u)` (`a, b < 3N`).
    #[inline]
    pub fn get(&self, a: usize, b: usize) -> f64 {
        let (ba, ia) = (a / N, a % N);
        let (bb, ib) = (b / N, b % N);
        match (ba, bb) {
            (0, 0) => self.qq[(ia, ib)],
            (0, 1) => self.qv[(ia, ib)],
            (1, 0) => self.qv[(ib, ia)],
            (0, 2) => self.qu[(ia, ib)],
            (2, 0) => self.qu[(ib, ia)],
            (1, 1) => self.vv[(ia, ib)],
            (1, 2) => self.vu[(ia, ib)],
            (2, 1) => self.vu[(ib, ia)],
            _ => self.uu[(ia, ib)],
        }
    }

    /// Sets entry `(a, b)` for `a ≤ b` (and so its mirror).
    #[inline]
    fn set_upper(&mut self, a: usize, b: usize, v: f64) {
        let (ba, ia) = (a / N, a % N);
        let (bb, ib) = (b / N, b % N);
        match (ba, bb) {
            (0, 0) => {
                self.qq[(ia, ib)] = v;
                self.qq[(ib, ia)] = v;
            }
            (0, 1) => self.qv[(ia, ib)] = v,
            (0, 2) => self.qu[(ia, ib)] = v,
            (1, 1) => {
                self.vv[(ia, ib)] = v;
                self.vv[(ib, ia)] = v;
            }
            (1, 2) => self.vu[(ia, ib)] = v,
            _ => {
                self.uu[(ia, ib)] = v;
                self.uu[(ib, ia)] = v;
            }
        }
    }

    /// Whether every entry is finite.
    pub fn is_finite(&self) -> bool {
        [self.qq, self.qv, self.qu, self.vv, self.vu, self.uu]
            .iter()
            .all(|m| m.iter().all(|v| v.is_finite()))
    }
}

impl<const N: usize> PredictionModel<N> {
    /// Exact Hessian of `λ_qᵀ q⁺ + λ_vᵀ qd⁺` of the prediction step `(q⁺, qd⁺) = Φ(x, u)`
    /// ([`Self::step`], torque `u` held, starting `tau0` after `t_k`) with respect to
    /// `(q, qd, u)`: the stage block `W_j` of the exact-Hessian SQP (module docs). Forward-mode
    /// hyper-dual numbers, one pass per pair of variables (`3N(3N+1)/2` passes); allocates
    /// nothing.
    #[cfg(feature = "std")]
    pub fn step_lagrangian_hessian(
        &self,
        x: &JointState<f64, N>,
        u: &SVector<f64, N>,
        tau0: f64,
        inp: &HorizonInputs<N>,
        lam_q: &SVector<f64, N>,
        lam_v: &SVector<f64, N>,
    ) -> StepHessian<N> {
        let mut h = StepHessian::zeros();
        let nv = 3 * N;
        for a in 0..nv {
            for b in a..nv {
                let lift = |v: f64, i: usize| {
                    let mut d = HyperDual64::from(v);
                    if i == a {
                        d.eps1 = 1.0;
                    }
                    if i == b {
                        d.eps2 = 1.0;
                    }
                    d
                };
                let xs = JointState {
                    q: SVector::from_fn(|i, _| lift(x.q[i], i)),
                    qd: SVector::from_fn(|i, _| lift(x.qd[i], N + i)),
                };
                let us = SVector::from_fn(|i, _| lift(u[i], 2 * N + i));
                let s = self.step(&xs, &us, tau0, inp);
                let mut v = 0.0;
                for i in 0..N {
                    v += lam_q[i] * s.q[i].eps1eps2 + lam_v[i] * s.qd[i].eps1eps2;
                }
                h.set_upper(a, b, v);
            }
        }
        h
    }

    /// Without `std` there are no hyper-dual numbers (`num-dual` needs `std`):
    /// [`crate::solver::SqpSettings::validate`] rejects `HessianModel::Exact`, and this block
    /// is all NaN, so that a solve reaching it anyway fails with a safe fallback.
    #[cfg(not(feature = "std"))]
    pub fn step_lagrangian_hessian(
        &self,
        _x: &JointState<f64, N>,
        _u: &SVector<f64, N>,
        _tau0: f64,
        _inp: &HorizonInputs<N>,
        _lam_q: &SVector<f64, N>,
        _lam_v: &SVector<f64, N>,
    ) -> StepHessian<N> {
        let mut h = StepHessian::zeros();
        for a in 0..3 * N {
            for b in a..3 * N {
                h.set_upper(a, b, f64::NAN);
            }
        }
        h
    }
}

/// Costates `λ_{j+1} = g_{j+1} + F_{j+1}ᵀ λ_{j+2}` (`λ_{Np+1} = 0`) of the `(q, qd)` parts of
/// the states, from the cost gradient `g` at the states and the step Jacobians: `grad(j)` is
/// `(∂/∂q_{j+1}, ∂/∂qd_{j+1}) ½‖r‖²`, `jac(j)` the Jacobian of step `j` (from `x_j` to `x_{j+1}`).
/// `lam[j]` receives `λ_{j+1}` for `j = 0..np`.
pub(crate) fn costates<const N: usize>(
    np: usize,
    grad: impl Fn(usize) -> (SVector<f64, N>, SVector<f64, N>),
    jac: impl Fn(usize) -> StepJacobian<N>,
    lam: &mut [(SVector<f64, N>, SVector<f64, N>)],
) {
    let mut next = (SVector::<f64, N>::zeros(), SVector::<f64, N>::zeros());
    for j in (0..np).rev() {
        let (mut lq, mut lv) = grad(j);
        if j + 1 < np {
            let f = jac(j + 1);
            lq += f.qq.tr_mul(&next.0) + f.vq.tr_mul(&next.1);
            lv += f.qv.tr_mul(&next.0) + f.vv.tr_mul(&next.1);
        }
        lam[j] = (lq, lv);
        next = (lq, lv);
    }
}

/// Workspace of the condensed exact curvature `Σ_j Γ_jᵀ W_j Γ_j` of the dense (single-shooting)
/// NMPC problem; allocated once.
#[derive(Clone, Debug)]
pub(crate) struct CurvatureWork<const N: usize> {
    xs: Vec<JointState<f64, N>>,
    us: Vec<SVector<f64, N>>,
    jac: Vec<StepJacobian<N>>,
    lam: Vec<(SVector<f64, N>, SVector<f64, N>)>,
    /// `(∂q_j/∂z_i, ∂qd_j/∂z_i)` per increment block `i`.
    sens: Vec<(SMatrix<f64, N, N>, SMatrix<f64, N, N>)>,
    /// `W_j Γ_j[i]` per block `i`, in row blocks `(q, qd, u)`.
    wg: Vec<[SMatrix<f64, N, N>; 3]>,
}

impl<const N: usize> CurvatureWork<N> {
    /// Workspace for horizons `np`, `nc`.
    pub(crate) fn new(np: usize, nc: usize) -> Self {
        let z = SMatrix::<f64, N, N>::zeros();
        let zx = JointState {
            q: SVector::zeros(),
            qd: SVector::zeros(),
        };
        CurvatureWork {
            xs: vec![zx; np],
            us: vec![SVector::zeros(); np],
            jac: vec![
                StepJacobian {
                    qq: z,
                    qv: z,
                    vq: z,
                    vv: z,
                    qu: z,
                    vu: z,
                };
                np
            ],
            lam: vec![(SVector::zeros(), SVector::zeros()); np],
            sens: vec![(z, z); nc],
            wg: vec![[z; 3]; nc],
        }
    }

    /// Adds `Σ_j Γ_jᵀ W_j Γ_j` to `hess` (`N·Nc` square) for the increments `z`, with the
    /// trajectory simulated from `x0`, `t_prev` and the cost gradient at the states read off the
    /// residuals `r` (layout of `NmpcProblem`: per step `q − q_ref`, `√r_d L (qd − qd_ref)`, so
    /// the velocity gradient is `√r_d Lᵀ r_v`).
    /// Returns `false` (leaving `hess` partly updated) when anything is non-finite, and (leaving it
    /// unchanged) when the dimensions do not match the horizons.
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn add_condensed(
        &mut self,
        model: &PredictionModel<N>,
        x0: &JointState<f64, N>,
        t_prev: &SVector<f64, N>,
        inp: &HorizonInputs<N>,
        sqrt_rd: f64,
        lv: &SMatrix<f64, N, N>,
        z: &[f64],
        r: &[f64],
        hess: &mut DMatrix<f64>,
    ) -> bool {
        let np = self.xs.len();
        let nc = self.sens.len();
        let n = N * nc;
        if nc == 0 || z.len() != n || r.len() < 2 * N * np || hess.shape() != (n, n) {
            return false;
        }
        let dt = model.dt;
        let mut x = *x0;
        let mut u = *t_prev;
        for j in 0..np {
            if j < nc {
                for a in 0..N {
                    u[a] += z[j * N + a];
                }
            }
            self.xs[j] = x;
            self.us[j] = u;
            let (xn, g) = model.step_with_jacobian(&x, &u, j as f64 * dt, inp);
            self.jac[j] = g;
            x = xn;
        }
        let jac = &self.jac;
        costates(
            np,
            |j| {
                let base = j * 2 * N;
                let rv = SVector::<f64, N>::from_fn(|a, _| r[base + N + a]);
                (
                    SVector::from_fn(|a, _| r[base + a]),
                    lv.tr_mul(&rv) * sqrt_rd,
                )
            },
            |j| jac[j],
            &mut self.lam,
        );
        let zero = SMatrix::<f64, N, N>::zeros();
        for s in self.sens.iter_mut() {
            *s = (zero, zero);
        }
        let mut finite = true;
        for j in 0..np {
            let (lq, lv) = self.lam[j];
            let w = model.step_lagrangian_hessian(
                &self.xs[j],
                &self.us[j],
                j as f64 * dt,
                inp,
                &lq,
                &lv,
            );
            finite &= w.is_finite();
            let active = j.min(nc - 1);
            // W Γ[k] with Γ[k] = (Sq, Sv, I): row blocks (q, qd, u).
            for k in 0..=active {
                let (sq, sv) = self.sens[k];
                self.wg[k] = [
                    w.qq * sq + w.qv * sv + w.qu,
                    w.qv.tr_mul(&sq) + w.vv * sv + w.vu,
                    w.qu.tr_mul(&sq) + w.vu.tr_mul(&sv) + w.uu,
                ];
            }
            for i in 0..=active {
                let (sq, sv) = self.sens[i];
                for k in 0..=active {
                    let wg = &self.wg[k];
                    let blk = sq.tr_mul(&wg[0]) + sv.tr_mul(&wg[1]) + wg[2];
                    for b in 0..N {
                        for a in 0..N {
                            hess[(i * N + a, k * N + b)] += blk[(a, b)];
                        }
                    }
                }
            }
            // Γ_{j+1}[i] = F_j Γ_j[i] + G_j (the torque of step j depends on blocks i ≤ active).
            let g = &self.jac[j];
            for i in 0..=active {
                let (sq, sv) = self.sens[i];
                self.sens[i] = (g.qq * sq + g.qv * sv + g.qu, g.vq * sq + g.vv * sv + g.vu);
            }
        }
        finite && hess.iter().all(|v| v.is_finite())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::control::prediction::Interaction;
    use crate::model::{Chain, Friction, Link, RobotModel, Straps};

    fn model<const N: usize>(
        next: &mut impl FnMut() -> f64,
        interaction: Interaction,
    ) -> PredictionModel<N> {
        let links = core::array::from_fn(|_| {
            let length = 0.3 + 0.2 * next().abs();
            Link {
                length,
                mass: 2.0 + 3.0 * next().abs(),
                com: length * (0.3 + 0.4 * next().abs()),
                inertia: 0.02 + 0.05 * next().abs(),
            }
        });
        let mut j = SMatrix::<f64, N, N>::zeros();
        for r in 0..N {
            for c in 0..=r {
                j[(r, c)] = 0.1 + 0.2 * next().abs();
            }
        }
        PredictionModel {
            robot: RobotModel {
                chain: Chain::new(links),
                viscous: 0.5 + next().abs(),
                coulomb: 0.3 + next().abs(),
                friction: Friction::Tanh { width: 0.1 },
            },
            straps: Straps {
                j,
                stiffness: 500.0 + 1000.0 * next().abs(),
                damping: 10.0 + 20.0 * next().abs(),
            },
            interaction,
            dt: 0.01,
            substeps: 2,
        }
    }

    /// `W` against central differences of `λᵀ ∂Φ/∂(q, qd, u)` (the exact first-order Jacobian
    /// by dual numbers), and symmetric by construction.
    fn check<const N: usize>(seed: u64) {
        let mut next = crate::test_rng::lcg(seed);
        for case in 0..20 {
            let interaction = if case % 2 == 0 {
                Interaction::Predict
            } else {
                Interaction::Hold
            };
            let m = model::<N>(&mut next, interaction);
            let x = JointState {
                q: SVector::from_fn(|_, _| 1.2 * next()),
                qd: SVector::from_fn(|_, _| 2.0 * next()),
            };
            let u = SVector::<f64, N>::from_fn(|_, _| 20.0 * next());
            let inp = HorizonInputs {
                q_h: x.q + SVector::from_fn(|_, _| 0.05 * next()),
                qd_h: x.qd + SVector::from_fn(|_, _| 0.5 * next()),
                t_int_measured: SVector::from_fn(|_, _| 5.0 * next()),
                disturbance: SVector::from_fn(|_, _| 2.0 * next()),
            };
            let lq = SVector::<f64, N>::from_fn(|_, _| next());
            let lv = SVector::<f64, N>::from_fn(|_, _| next());
            let tau0 = 0.01 * (case % 3) as f64;
            let w = m.step_lagrangian_hessian(&x, &u, tau0, &inp, &lq, &lv);
            // λᵀ J as a row over (q, qd, u).
            let grad = |x: &JointState<f64, N>, u: &SVector<f64, N>| {
                let (_, j) = StepJacobian::by_dual_numbers(x, u, |x, u| m.step(x, u, tau0, &inp));
                let mut g = vec![0.0; 3 * N];
                for c in 0..N {
                    for r in 0..N {
                        g[c] += lq[r] * j.qq[(r, c)] + lv[r] * j.vq[(r, c)];
                        g[N + c] += lq[r] * j.qv[(r, c)] + lv[r] * j.vv[(r, c)];
                        g[2 * N + c] += lq[r] * j.qu[(r, c)] + lv[r] * j.vu[(r, c)];
                    }
                }
                g
            };
            for b in 0..3 * N {
                let scale = if b < 2 * N { 1e-6 } else { 1e-5 };
                let shift = |sgn: f64| {
                    let mut xp = x;
                    let mut up = u;
                    match b / N {
                        0 => xp.q[b % N] += sgn * scale,
                        1 => xp.qd[b % N] += sgn * scale,
                        _ => up[b % N] += sgn * scale,
                    }
                    grad(&xp, &up)
                };
                let (gp, gm) = (shift(1.0), shift(-1.0));
                for a in 0..3 * N {
                    let fd = (gp[a] - gm[a]) / (2.0 * scale);
                    let ex = w.get(a, b);
                    assert!(
                        (fd - ex).abs() <= 1e-6 * (1.0 + ex.abs()),
                        "N={N} case {case} ({a},{b}): exact {ex:e} fd {fd:e}"
                    );
                    assert_eq!(w.get(a, b), w.get(b, a));
                }
            }
        }
    }

    #[test]
    fn stage_hessian_matches_finite_differences_of_the_exact_jacobian() {
        check::<1>(11);
        check::<2>(12);
        check::<3>(13);
    }
}
