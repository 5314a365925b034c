//! The NMPC prediction model (MODEL.md §8): the scenario's robot model, the disturbance estimate,
//! and the strap torque predicted from the human-intent estimate inside every RK4 stage.

use crate::model::{
    c, rk4_step, sin_cos, sin_cos_near, tanh, Friction, JointState, Real, RkState, RobotModel,
    Straps,
};
use nalgebra::{SMatrix, SVector};
use num_dual::{DualSVec64, DualStruct};
use serde::{Deserialize, Serialize};

/// How the strap torque is modelled over the horizon (MODEL.md §8).
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
    /// and `u` in three passes. The reference for [`Self::step_with_jacobian`] (same values to
    /// rounding), about ten times slower. A test and benchmark oracle, hidden from the docs.
    #[doc(hidden)]
    pub fn step_with_jacobian_dual(
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

    /// [`Self::step`] with its exact Jacobian, hand-derived: per RK4 stage the analytic partial
    /// derivatives of `qdd = M⁻¹(u + T_int + d − C qd − G − friction)` with respect to `q`, `qd`
    /// and `u` (first and second derivatives of `M` from the chain's closed form), chained
    /// through the stages. Equals the dual-number Jacobian (`step_with_jacobian_dual`, the tests' oracle) to rounding.
    pub fn step_with_jacobian(
        &self,
        x: &JointState<f64, N>,
        u: &SVector<f64, N>,
        tau0: f64,
        inp: &HorizonInputs<N>,
    ) -> (JointState<f64, N>, StepJacobian<N>) {
        self.step_with_jacobian_using(&self.jacobian_constants(), x, u, tau0, inp)
    }

    /// The model constants [`Self::step_with_jacobian_using`] needs, computed once for a
    /// rollout of many steps.
    #[inline]
    pub(crate) fn jacobian_constants(&self) -> StageConstants<N> {
        StageConstants::new(self)
    }

    /// [`Self::step_with_jacobian`] with the constants of [`Self::jacobian_constants`] (of this
    /// model) computed by the caller: the same numbers.
    #[inline]
    pub(crate) fn step_with_jacobian_using(
        &self,
        consts: &StageConstants<N>,
        x: &JointState<f64, N>,
        u: &SVector<f64, N>,
        tau0: f64,
        inp: &HorizonInputs<N>,
    ) -> (JointState<f64, N>, StepJacobian<N>) {
        let n = self.substeps.max(1);
        let h = self.dt / n as f64;
        let eye = SMatrix::<f64, N, N>::identity();
        let zero = SMatrix::<f64, N, N>::zeros();
        let mut s = *x;
        let mut sens = StepJacobian {
            qq: eye,
            qv: zero,
            vq: zero,
            vv: eye,
            qu: zero,
            vu: zero,
        };
        for i in 0..n {
            let t = tau0 + i as f64 * h;
            // The substep's first stage evaluates `sin`/`cos` of the link angles; the later
            // stages rotate them by the small angle increments (`LinkTrig`).
            let mut trig = None;
            // The first substep starts from the identity sensitivity: its first stage has no
            // products and its second stage two fewer (`stage_sens_first`, `stage_sens_second`).
            let (k1, d1) = if i == 0 {
                self.stage_sens_first(consts, t, &s, u, inp, &mut trig)
            } else {
                self.stage_sens(consts, t, &s, u, inp, &sens, &mut trig)
            };
            let x2 = s.add_scaled(0.5 * h, &k1);
            // From the identity sensitivity, `sens + c·d` adds nothing to the zero entries of
            // `sens` and of `d1` and one to the diagonal: the sums are formed only where they
            // are not exact (`0 + y = y`, `1·c = c`; same values).
            let (k2, d2) = if i == 0 {
                let s2 = StepJacobian::identity_plus_first(0.5 * h, &d1);
                self.stage_sens_second(consts, t + 0.5 * h, &x2, u, inp, 0.5 * h, &s2, &mut trig)
            } else {
                let s2 = sens.add_scaled(0.5 * h, &d1);
                self.stage_sens(consts, t + 0.5 * h, &x2, u, inp, &s2, &mut trig)
            };
            let x3 = s.add_scaled(0.5 * h, &k2);
            let s3 = if i == 0 {
                StepJacobian::identity_plus(0.5 * h, &d2)
            } else {
                sens.add_scaled(0.5 * h, &d2)
            };
            let (k3, d3) = self.stage_sens(consts, t + 0.5 * h, &x3, u, inp, &s3, &mut trig);
            let x4 = s.add_scaled(h, &k3);
            let s4 = if i == 0 {
                StepJacobian::identity_plus(h, &d3)
            } else {
                sens.add_scaled(h, &d3)
            };
            let (k4, d4) = self.stage_sens(consts, t + h, &x4, u, inp, &s4, &mut trig);
            s = s
                .add_scaled(h / 6.0, &k1)
                .add_scaled(h / 3.0, &k2)
                .add_scaled(h / 3.0, &k3)
                .add_scaled(h / 6.0, &k4);
            let first = if i == 0 {
                StepJacobian::identity_plus_first(h / 6.0, &d1)
            } else {
                sens.add_scaled(h / 6.0, &d1)
            };
            sens = first
                .add_scaled(h / 3.0, &d2)
                .add_scaled(h / 3.0, &d3)
                .add_scaled(h / 6.0, &d4);
        }
        (s, sens)
    }

    /// The state of [`Self::step_with_jacobian_using`] without the sensitivities, for the
    /// rollouts that need no Jacobian (the line search's backtracking trials, the dense
    /// back-end's residuals). With two links the stages use the written-out two-link
    /// acceleration and the trigonometry of the Jacobian code (its derivative terms,
    /// unused, are left out by the compiler), so the state equals that of
    /// `step_with_jacobian_using` to the bit and [`Self::step`] to rounding; other link counts
    /// take [`Self::step`].
    #[inline]
    pub(crate) fn step_value_using(
        &self,
        consts: &StageConstants<N>,
        x: &JointState<f64, N>,
        u: &SVector<f64, N>,
        tau0: f64,
        inp: &HorizonInputs<N>,
    ) -> JointState<f64, N> {
        if N != 2 {
            return self.step(x, u, tau0, inp);
        }
        let n = self.substeps.max(1);
        let h = self.dt / n as f64;
        let f = |t: f64, y: &JointState<f64, N>, trig: &mut Option<LinkTrig>| JointState {
            q: y.qd,
            qd: self
                .derivative_jacobian_two_links(consts, t, y, u, inp, trig)
                .qdd,
        };
        let mut s = *x;
        for i in 0..n {
            let t = tau0 + i as f64 * h;
            let mut trig = None;
            let k1 = f(t, &s, &mut trig);
            let k2 = f(t + 0.5 * h, &s.add_scaled(0.5 * h, &k1), &mut trig);
            let k3 = f(t + 0.5 * h, &s.add_scaled(0.5 * h, &k2), &mut trig);
            let k4 = f(t + h, &s.add_scaled(h, &k3), &mut trig);
            s = s
                .add_scaled(h / 6.0, &k1)
                .add_scaled(h / 3.0, &k2)
                .add_scaled(h / 3.0, &k3)
                .add_scaled(h / 6.0, &k4);
        }
        s
    }

    /// One RK4 stage `k = f(τ, X, u)` and its sensitivity `∂k/∂(x₀, u)` given the stage state's
    /// sensitivity `sx = ∂X/∂(x₀, u)`.
    #[inline(always)]
    #[allow(clippy::too_many_arguments)] // the stage's arguments and the substep's trigonometry
    fn stage_sens(
        &self,
        consts: &StageConstants<N>,
        tau: f64,
        x: &JointState<f64, N>,
        u: &SVector<f64, N>,
        inp: &HorizonInputs<N>,
        sx: &StepJacobian<N>,
        trig: &mut Option<LinkTrig>,
    ) -> (JointState<f64, N>, StepJacobian<N>) {
        let d = self.derivative_jacobian(consts, tau, x, u, inp, trig);
        let k = JointState { q: x.qd, qd: d.qdd };
        let dk = StepJacobian {
            qq: sx.vq,
            qv: sx.vv,
            qu: sx.vu,
            vq: d.a_q * sx.qq + d.a_v * sx.vq,
            vv: d.a_q * sx.qv + d.a_v * sx.vv,
            vu: d.a_q * sx.qu + d.a_v * sx.vu + d.minv,
        };
        (k, dk)
    }

    /// [`Self::stage_sens`] from the identity sensitivity (`sx = [[I, 0, 0], [0, I, 0]]`):
    /// `∂k/∂(x₀, u) = [[0, I, 0], [a_q, a_v, M⁻¹]]`, the values `stage_sens` forms from products
    /// with the identity and zero blocks (`x·1 + y·0 = x`).
    #[inline(always)]
    fn stage_sens_first(
        &self,
        consts: &StageConstants<N>,
        tau: f64,
        x: &JointState<f64, N>,
        u: &SVector<f64, N>,
        inp: &HorizonInputs<N>,
        trig: &mut Option<LinkTrig>,
    ) -> (JointState<f64, N>, StepJacobian<N>) {
        let d = self.derivative_jacobian(consts, tau, x, u, inp, trig);
        let k = JointState { q: x.qd, qd: d.qdd };
        let dk = StepJacobian {
            qq: SMatrix::zeros(),
            qv: SMatrix::identity(),
            qu: SMatrix::zeros(),
            vq: d.a_q,
            vv: d.a_v,
            vu: d.minv,
        };
        (k, dk)
    }

    /// [`Self::stage_sens`] for the second RK4 stage of the first substep, where `sx.qq = I`,
    /// `sx.qu = 0` and `sx.qv = h2·I` exactly (identity plus `h2 = h/2` times the first stage's
    /// blocks `0`, `I`, `0`): the products with them are left out or scalar (same values).
    #[inline(always)]
    #[allow(clippy::too_many_arguments)] // `stage_sens`'s arguments and the known `sx.qv`
    fn stage_sens_second(
        &self,
        consts: &StageConstants<N>,
        tau: f64,
        x: &JointState<f64, N>,
        u: &SVector<f64, N>,
        inp: &HorizonInputs<N>,
        h2: f64,
        sx: &StepJacobian<N>,
        trig: &mut Option<LinkTrig>,
    ) -> (JointState<f64, N>, StepJacobian<N>) {
        let d = self.derivative_jacobian(consts, tau, x, u, inp, trig);
        let k = JointState { q: x.qd, qd: d.qdd };
        let dk = StepJacobian {
            qq: sx.vq,
            qv: sx.vv,
            qu: sx.vu,
            vq: d.a_q + d.a_v * sx.vq,
            vv: d.a_q * h2 + d.a_v * sx.vv,
            vu: d.a_v * sx.vu + d.minv,
        };
        (k, dk)
    }

    /// `qdd` of [`Self::derivative`] with its partial derivatives `∂qdd/∂q`, `∂qdd/∂qd` and
    /// `∂qdd/∂u = M⁻¹`, in `f64`.
    #[inline(always)]
    fn derivative_jacobian(
        &self,
        k: &StageConstants<N>,
        tau: f64,
        x: &JointState<f64, N>,
        u: &SVector<f64, N>,
        inp: &HorizonInputs<N>,
        trig: &mut Option<LinkTrig>,
    ) -> AccelJacobian<N> {
        if N == 2 {
            self.derivative_jacobian_two_links(k, tau, x, u, inp, trig)
        } else {
            self.derivative_jacobian_chain(k, tau, x, u, inp)
        }
    }

    /// [`Self::derivative_jacobian`] for any `N`: the chain's tensors `∂M/∂q`, `∂²M/∂q²`.
    #[allow(clippy::needless_range_loop)] // index algebra of the closed-form derivatives
    fn derivative_jacobian_chain(
        &self,
        k: &StageConstants<N>,
        tau: f64,
        x: &JointState<f64, N>,
        u: &SVector<f64, N>,
        inp: &HorizonInputs<N>,
    ) -> AccelJacobian<N> {
        let (q, v) = (&x.q, &x.qd);
        // Absolute angles and their trigonometry.
        let mut th = [0.0; N];
        let mut acc = 0.0;
        for a in 0..N {
            acc += q[a];
            th[a] = acc;
        }
        // sin/cos of the absolute angles; of the differences by the subtraction formulas.
        let mut sin_th = [0.0; N];
        let mut cos_th = [0.0; N];
        for a in 0..N {
            (sin_th[a], cos_th[a]) = sin_cos(th[a]);
        }
        let mut cs = [[1.0; N]; N];
        let mut sn = [[0.0; N]; N];
        for a in 0..N {
            for b in (a + 1)..N {
                let s = sin_th[a] * cos_th[b] - cos_th[a] * sin_th[b];
                let co = cos_th[a] * cos_th[b] + sin_th[a] * sin_th[b];
                cs[a][b] = co;
                cs[b][a] = co;
                sn[a][b] = s;
                sn[b][a] = -s;
            }
        }
        // M, D1[k][i][j] = ∂M_ij/∂q_k and D2[r][k][i][j] = ∂²M_ij/∂q_k∂q_r from
        // M_ij = Σ_{k ≥ max(i,j)} I_k + Σ_{a ≥ i, b ≥ j} P_ab cos(θ_a − θ_b).
        let mut m = SMatrix::<f64, N, N>::zeros();
        let mut d1 = [[[0.0; N]; N]; N];
        let mut d2 = [[[[0.0; N]; N]; N]; N];
        for i in 0..N {
            for j in 0..N {
                let mut s = k.inertia_tail[i.max(j)];
                for a in i..N {
                    for b in j..N {
                        s += k.p[a][b] * cs[a][b];
                    }
                }
                m[(i, j)] = s;
            }
        }
        for a in 0..N {
            for b in 0..N {
                if a == b {
                    continue;
                }
                let ps = -k.p[a][b] * sn[a][b];
                let pc = -k.p[a][b] * cs[a][b];
                // w_r = [r ≤ a] − [r ≤ b]: nonzero for min(a,b) < r ≤ max(a,b).
                let (lo, hi) = (a.min(b) + 1, a.max(b));
                let sign = if a > b { 1.0 } else { -1.0 };
                for r in lo..=hi {
                    for i in 0..=a {
                        for j in 0..=b {
                            d1[r][i][j] += ps * sign;
                        }
                    }
                    for s in lo..=hi {
                        for i in 0..=a {
                            for j in 0..=b {
                                d2[s][r][i][j] += pc;
                            }
                        }
                    }
                }
            }
        }
        // h = C qd with h_i = Σ_jk (∂M_ij/∂q_k − ½ ∂M_jk/∂q_i) v_j v_k, and its derivatives.
        let mut hv = SVector::<f64, N>::zeros();
        let mut dh_q = SMatrix::<f64, N, N>::zeros();
        let mut dh_v = SMatrix::<f64, N, N>::zeros();
        for i in 0..N {
            let mut s = 0.0;
            for j in 0..N {
                for kk in 0..N {
                    let g = d1[kk][i][j] - 0.5 * d1[i][j][kk];
                    s += g * v[j] * v[kk];
                    // ∂/∂v_j and ∂/∂v_k of the bilinear term.
                    dh_v[(i, j)] += g * v[kk];
                    dh_v[(i, kk)] += g * v[j];
                }
            }
            hv[i] = s;
            for r in 0..N {
                let mut s = 0.0;
                for j in 0..N {
                    for kk in 0..N {
                        s += (d2[r][kk][i][j] - 0.5 * d2[r][i][j][kk]) * v[j] * v[kk];
                    }
                }
                dh_q[(i, r)] = s;
            }
        }
        // Gravity G_r = Σ_{a ≥ r} W_a sin θ_a, ∂G_r/∂q_s = Σ_{a ≥ max(r,s)} W_a cos θ_a.
        let mut g = SVector::<f64, N>::zeros();
        let mut wcos = [0.0; N];
        let mut accs = 0.0;
        for a in (0..N).rev() {
            accs += k.w[a] * sin_th[a];
            g[a] = accs;
            wcos[a] = k.w[a] * cos_th[a];
        }
        let mut dg = SMatrix::<f64, N, N>::zeros();
        for r in 0..N {
            for s in 0..N {
                dg[(r, s)] = wcos[r.max(s)..].iter().sum();
            }
        }
        // Friction and its (diagonal) derivative.
        let rb = &self.robot;
        let mut fr = SVector::<f64, N>::zeros();
        let mut dfr = [0.0; N];
        for i in 0..N {
            let (coul, dcoul) = friction_terms(rb, v[i]);
            fr[i] = v[i] * rb.viscous + coul;
            dfr[i] = rb.viscous + dcoul;
        }
        // Interaction torque and its derivatives (−ks JᵀJ, −cs JᵀJ when predicted).
        let (t_int, ti_q, ti_v) = self.interaction_terms(k, tau, q, v, inp);
        let mut rhs = SVector::<f64, N>::zeros();
        for i in 0..N {
            rhs[i] = u[i] + t_int[i] + inp.disturbance[i] - hv[i] - g[i] - fr[i];
        }
        let minv = spd_inverse(&m);
        let qdd = minv * rhs;
        // ∂(M qdd)/∂q_r = ∂rhs/∂q_r ⇒ ∂qdd/∂q_r = M⁻¹(∂rhs/∂q_r − ∂M/∂q_r qdd).
        let mut bq = SMatrix::<f64, N, N>::zeros();
        for r in 0..N {
            for i in 0..N {
                let mut dmq = 0.0;
                for j in 0..N {
                    dmq += d1[r][i][j] * qdd[j];
                }
                bq[(i, r)] = -ti_q[(i, r)] - dh_q[(i, r)] - dg[(i, r)] - dmq;
            }
        }
        let mut bv = -dh_v;
        for i in 0..N {
            for j in 0..N {
                bv[(i, j)] -= ti_v[(i, j)];
            }
            bv[(i, i)] -= dfr[i];
        }
        AccelJacobian {
            qdd,
            a_q: minv * bq,
            a_v: minv * bv,
            minv,
        }
    }
}

impl<const N: usize> PredictionModel<N> {
    /// Interaction torque and its derivatives (`−ks JᵀJ`, `−cs JᵀJ` when predicted).
    #[inline(always)]
    fn interaction_terms(
        &self,
        k: &StageConstants<N>,
        tau: f64,
        q: &SVector<f64, N>,
        v: &SVector<f64, N>,
        inp: &HorizonInputs<N>,
    ) -> (SVector<f64, N>, SMatrix<f64, N, N>, SMatrix<f64, N, N>) {
        match self.interaction {
            Interaction::Hold => (inp.t_int_measured, zero_mat(), zero_mat()),
            Interaction::Predict => {
                let mut dq = SVector::<f64, N>::zeros();
                let mut dqd = SVector::<f64, N>::zeros();
                for i in 0..N {
                    dq[i] = -q[i] + (inp.q_h[i] + tau * inp.qd_h[i]);
                    dqd[i] = -v[i] + inp.qd_h[i];
                }
                (strap_torque(&self.straps, &dq, &dqd), k.ks_jtj, k.cs_jtj)
            }
        }
    }

    /// [`Self::derivative_jacobian_chain`] for `N = 2` with the chain's tensors written out: of
    /// `∂M/∂q` (8 entries) and `∂²M/∂q²` (16) only three each are nonzero, so the Coriolis
    /// terms and their derivatives reduce to a few products. Every nonzero term is formed and
    /// summed in the order of the chain code, and the terms it skips are exact zeros, so the
    /// results are the same numbers (unit test `two_link_jacobian_equals_the_chain_code`).
    #[inline(always)]
    fn derivative_jacobian_two_links(
        &self,
        k: &StageConstants<N>,
        tau: f64,
        x: &JointState<f64, N>,
        u: &SVector<f64, N>,
        inp: &HorizonInputs<N>,
        trig: &mut Option<LinkTrig>,
    ) -> AccelJacobian<N> {
        debug_assert_eq!(N, 2);
        let (q, v) = (&x.q, &x.qd);
        let (v0, v1) = (v[0], v[1]);
        let th0 = 0.0 + q[0];
        let th1 = th0 + q[1];
        let t = LinkTrig::at(th0, th1, trig);
        let (s0, c0, s1, c1) = (t.s[0], t.c[0], t.s[1], t.c[1]);
        // sin and cos of θ0 − θ1.
        let sn = s0 * c1 - c0 * s1;
        let co = c0 * c1 + s0 * s1;
        let p = &k.p;
        let it = &k.inertia_tail;
        let mut m = SMatrix::<f64, N, N>::zeros();
        m[(0, 0)] = it[0] + p[0][0] + p[0][1] * co + p[1][0] * co + p[1][1];
        m[(0, 1)] = it[1] + p[0][1] * co + p[1][1];
        m[(1, 0)] = it[1] + p[1][0] * co + p[1][1];
        m[(1, 1)] = it[1] + p[1][1];
        // The nonzero entries d1[1][0][0] = a, d1[1][0][1] = b, d1[1][1][0] = c of ∂M/∂q and
        // d2[1][1][0][0] = e, d2[1][1][0][1] = f, d2[1][1][1][0] = gd of ∂²M/∂q².
        let ps01 = -p[0][1] * sn;
        let pc01 = -p[0][1] * co;
        let ps10 = -p[1][0] * -sn;
        let pc10 = -p[1][0] * co;
        let a = -ps01 + ps10;
        let b = -ps01;
        let c = ps10;
        let e = pc01 + pc10;
        let f = pc01;
        let gd = pc10;
        // h = C qd and ∂h/∂qd.
        let (g00, g01, g10) = (-(0.5 * a), c - 0.5 * b, -(0.5 * c));
        let hv0 = a * v0 * v1 + b * v1 * v1;
        let hv1 = g00 * v0 * v0 + g01 * v0 * v1 + g10 * v1 * v0;
        let mut dh_v = SMatrix::<f64, N, N>::zeros();
        dh_v[(0, 0)] = a * v1;
        dh_v[(0, 1)] = a * v0 + b * v1 + b * v1;
        dh_v[(1, 0)] = g00 * v0 + g00 * v0 + g01 * v1 + g10 * v1;
        dh_v[(1, 1)] = g01 * v0 + g10 * v0;
        // ∂h/∂q: the first column is zero.
        let (e00, e01, e10) = (-(0.5 * e), gd - 0.5 * f, -(0.5 * gd));
        let dh_q01 = e * v0 * v1 + f * v1 * v1;
        let dh_q11 = e00 * v0 * v0 + e01 * v0 * v1 + e10 * v1 * v0;
        // Gravity and its derivative.
        let g1 = 0.0 + k.w[1] * s1;
        let g0 = g1 + k.w[0] * s0;
        let (wc0, wc1) = (k.w[0] * c0, k.w[1] * c1);
        let dg00 = 0.0 + wc0 + wc1;
        // Friction and its (diagonal) derivative.
        let rb = &self.robot;
        let mut fr = SVector::<f64, N>::zeros();
        let mut dfr = [0.0; N];
        for i in 0..N {
            let (coul, dcoul) = friction_terms(rb, v[i]);
            fr[i] = v[i] * rb.viscous + coul;
            dfr[i] = rb.viscous + dcoul;
        }
        let (t_int, ti_q, ti_v) = self.interaction_terms(k, tau, q, v, inp);
        let hv = [hv0, hv1];
        let g = [g0, g1];
        let mut rhs = SVector::<f64, N>::zeros();
        for i in 0..N {
            rhs[i] = u[i] + t_int[i] + inp.disturbance[i] - hv[i] - g[i] - fr[i];
        }
        let minv = spd_inverse(&m);
        let qdd = minv * rhs;
        let mut bq = SMatrix::<f64, N, N>::zeros();
        bq[(0, 0)] = -ti_q[(0, 0)] - dg00;
        bq[(1, 0)] = -ti_q[(1, 0)] - wc1;
        bq[(0, 1)] = -ti_q[(0, 1)] - dh_q01 - wc1 - (a * qdd[0] + b * qdd[1]);
        bq[(1, 1)] = -ti_q[(1, 1)] - dh_q11 - wc1 - c * qdd[0];
        let mut bv = -dh_v;
        for i in 0..N {
            for j in 0..N {
                bv[(i, j)] -= ti_v[(i, j)];
            }
            bv[(i, i)] -= dfr[i];
        }
        AccelJacobian {
            qdd,
            a_q: minv * bq,
            a_v: minv * bv,
            minv,
        }
    }
}

/// `Straps::torque(Straps::force(dq, dqd))` in `f64` without the tests for zero entries of `J`:
/// a zero entry adds `±0` to a sum, which leaves it unchanged, so for finite arguments the value
/// is the same (test `branch_free_strap_torque_equals_the_straps_code`).
#[inline(always)]
fn strap_torque<const N: usize>(
    straps: &Straps<N>,
    dq: &SVector<f64, N>,
    dqd: &SVector<f64, N>,
) -> SVector<f64, N> {
    let j = &straps.j;
    let mut f = [0.0; N];
    for (s, fs) in f.iter_mut().enumerate() {
        let mut acc = 0.0;
        for i in 0..N {
            let jsi = j[(s, i)];
            acc += dq[i] * (straps.stiffness * jsi) + dqd[i] * (straps.damping * jsi);
        }
        *fs = acc;
    }
    let mut t = SVector::<f64, N>::zeros();
    for i in 0..N {
        let mut acc = 0.0;
        for (s, fs) in f.iter().enumerate() {
            acc += fs * j[(s, i)];
        }
        t[i] = acc;
    }
    t
}

/// Coulomb friction of one joint speed and its derivative (smooth or sign).
#[inline(always)]
fn friction_terms<const N: usize>(rb: &RobotModel<N>, v: f64) -> (f64, f64) {
    match rb.friction {
        Friction::Sign => (
            if v > 0.0 {
                rb.coulomb
            } else if v < 0.0 {
                -rb.coulomb
            } else {
                0.0
            },
            0.0,
        ),
        Friction::Tanh { width } => {
            let t: f64 = tanh(v * (1.0 / width));
            (t * rb.coulomb, rb.coulomb * (1.0 - t * t) * (1.0 / width))
        }
    }
}

#[inline(always)]
fn zero_mat<const N: usize>() -> SMatrix<f64, N, N> {
    SMatrix::zeros()
}

/// Inverse of a small symmetric positive-definite matrix (closed form for `N ≤ 2`).
#[inline(always)]
fn spd_inverse<const N: usize>(m: &SMatrix<f64, N, N>) -> SMatrix<f64, N, N> {
    match N {
        1 => SMatrix::from_element(1.0 / m[(0, 0)]),
        2 => {
            let det = m[(0, 0)] * m[(1, 1)] - m[(0, 1)] * m[(1, 0)];
            let id = 1.0 / det;
            let mut out = *m;
            out[(0, 0)] = m[(1, 1)] * id;
            out[(1, 1)] = m[(0, 0)] * id;
            out[(0, 1)] = -m[(0, 1)] * id;
            out[(1, 0)] = -m[(1, 0)] * id;
            out
        }
        _ => m
            .cholesky()
            .map(|ch| ch.inverse())
            .unwrap_or_else(|| SMatrix::from_element(f64::NAN)),
    }
}

/// `sin` and `cos` of the two absolute link angles `θ0 = q0`, `θ1 = q0 + q1` at the first RK4
/// stage of a substep, the base from which the substep's later stages rotate theirs.
#[derive(Clone, Copy, Debug)]
pub(crate) struct LinkTrig {
    th: [f64; 2],
    s: [f64; 2],
    c: [f64; 2],
}

impl LinkTrig {
    /// `sin`/`cos` of `θ0`, `θ1`: by [`sin_cos`] when `base` is empty (the substep's first stage;
    /// the result becomes the base), else rotated from the base by the increments
    /// ([`sin_cos_near`]: the later stages lie within `h·q̇` of the first stage's angles; within
    /// a few units in the last place of `sin_cos`, which a larger increment takes).
    #[inline(always)]
    fn at(th0: f64, th1: f64, base: &mut Option<LinkTrig>) -> LinkTrig {
        match base {
            None => {
                let (s0, c0) = sin_cos(th0);
                let (s1, c1) = sin_cos(th1);
                let t = LinkTrig {
                    th: [th0, th1],
                    s: [s0, s1],
                    c: [c0, c1],
                };
                *base = Some(t);
                t
            }
            Some(b) => {
                let (s0, c0) = sin_cos_near(th0, b.th[0], b.s[0], b.c[0]);
                let (s1, c1) = sin_cos_near(th1, b.th[1], b.s[1], b.c[1]);
                LinkTrig {
                    th: [th0, th1],
                    s: [s0, s1],
                    c: [c0, c1],
                }
            }
        }
    }
}

/// `qdd` and its partial derivatives at one stage.
struct AccelJacobian<const N: usize> {
    qdd: SVector<f64, N>,
    a_q: SMatrix<f64, N, N>,
    a_v: SMatrix<f64, N, N>,
    minv: SMatrix<f64, N, N>,
}

/// Model constants of the tailored Jacobian ([`PredictionModel::jacobian_constants`]).
#[derive(Clone, Copy, Debug)]
pub(crate) struct StageConstants<const N: usize> {
    /// `P_ab = Σ_{k ≥ max(a,b)} m_k d_ka d_kb`.
    p: [[f64; N]; N],
    /// `Σ_{k ≥ i} I_k`.
    inertia_tail: [f64; N],
    /// Gravity weights `W_a = g (m_a c_a + Σ_{k>a} m_k l_a)`.
    w: [f64; N],
    /// `ks JᵀJ`.
    ks_jtj: SMatrix<f64, N, N>,
    /// `cs JᵀJ`.
    cs_jtj: SMatrix<f64, N, N>,
}

impl<const N: usize> StageConstants<N> {
    #[inline(always)]
    fn new(model: &PredictionModel<N>) -> Self {
        let l = &model.robot.chain.links;
        let lever = |k: usize, a: usize| if a == k { l[k].com } else { l[a].length };
        let mut p = [[0.0; N]; N];
        for (a, pa) in p.iter_mut().enumerate() {
            for (b, pab) in pa.iter_mut().enumerate() {
                let mut s = 0.0;
                for (k, lk) in l.iter().enumerate().skip(a.max(b)) {
                    s += lk.mass * lever(k, a) * lever(k, b);
                }
                *pab = s;
            }
        }
        let mut inertia_tail = [0.0; N];
        let mut acc = 0.0;
        for i in (0..N).rev() {
            acc += l[i].inertia;
            inertia_tail[i] = acc;
        }
        let g = model.robot.chain.gravity;
        let mut w = [0.0; N];
        for a in 0..N {
            let mut s = l[a].mass * l[a].com;
            for lk in l.iter().skip(a + 1) {
                s += lk.mass * l[a].length;
            }
            w[a] = g * s;
        }
        let jtj = model.straps.j.transpose() * model.straps.j;
        StageConstants {
            p,
            inertia_tail,
            w,
            ks_jtj: jtj * model.straps.stiffness,
            cs_jtj: jtj * model.straps.damping,
        }
    }
}

/// `I + h·m`, adding one on the diagonal only (`0 + y = y` off it; same values).
#[inline(always)]
fn eye_plus<const N: usize>(h: f64, m: &SMatrix<f64, N, N>) -> SMatrix<f64, N, N> {
    let mut out = m * h;
    for i in 0..N {
        out[(i, i)] += 1.0;
    }
    out
}

impl<const N: usize> StepJacobian<N> {
    /// `[[I, 0, 0], [0, I, 0]] + h · d` (the identity sensitivity plus a stage's), formed
    /// without the exact additions of zero: the values of `identity.add_scaled(h, d)`.
    #[inline(always)]
    fn identity_plus(h: f64, d: &Self) -> Self {
        StepJacobian {
            qq: eye_plus(h, &d.qq),
            qv: d.qv * h,
            vq: d.vq * h,
            vv: eye_plus(h, &d.vv),
            qu: d.qu * h,
            vu: d.vu * h,
        }
    }

    /// [`Self::identity_plus`] for the first stage of a substep from the identity, whose
    /// `d.qq = 0`, `d.qv = I`, `d.qu = 0` (`stage_sens_first`): `qq = I`, `qv = h·I`, `qu = 0`.
    #[inline(always)]
    fn identity_plus_first(h: f64, d: &Self) -> Self {
        StepJacobian {
            qq: SMatrix::identity(),
            qv: SMatrix::identity() * h,
            vq: d.vq * h,
            vv: eye_plus(h, &d.vv),
            qu: SMatrix::zeros(),
            vu: d.vu * h,
        }
    }

    /// `self + h · d`, block-wise.
    #[inline(always)]
    fn add_scaled(&self, h: f64, d: &Self) -> Self {
        StepJacobian {
            qq: self.qq + d.qq * h,
            qv: self.qv + d.qv * h,
            vq: self.vq + d.vq * h,
            vv: self.vv + d.vv * h,
            qu: self.qu + d.qu * h,
            vu: self.vu + d.vu * h,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::{Chain, Link};

    /// Deterministic pseudo-random numbers in `[-1, 1)`.
    struct Lcg(u64);
    impl Lcg {
        fn next(&mut self) -> f64 {
            self.0 = self
                .0
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((self.0 >> 11) as f64 / (1u64 << 53) as f64) * 2.0 - 1.0
        }
        fn vec<const N: usize>(&mut self, scale: f64) -> SVector<f64, N> {
            SVector::from_fn(|_, _| scale * self.next())
        }
        /// A state (angles within `±q`, velocities within `±qd`), a torque and horizon inputs
        /// near that state.
        fn point<const N: usize>(
            &mut self,
            q: f64,
            qd: f64,
        ) -> (JointState<f64, N>, SVector<f64, N>, HorizonInputs<N>) {
            let x = JointState {
                q: self.vec(q),
                qd: self.vec(qd),
            };
            let u = self.vec(20.0);
            let inp = HorizonInputs {
                q_h: x.q + self.vec(0.05),
                qd_h: x.qd + self.vec(0.5),
                t_int_measured: self.vec(5.0),
                disturbance: self.vec(2.0),
            };
            (x, u, inp)
        }
    }

    /// Every third case holds the interaction torque, the others predict it.
    fn interaction_of(case: usize) -> Interaction {
        if case % 3 == 2 {
            Interaction::Hold
        } else {
            Interaction::Predict
        }
    }

    fn model<const N: usize>(
        rng: &mut Lcg,
        interaction: Interaction,
        friction: Friction,
        substeps: usize,
    ) -> PredictionModel<N> {
        let links = core::array::from_fn(|_| {
            let length = 0.3 + 0.2 * rng.next().abs();
            Link {
                length,
                mass: 2.0 + 3.0 * rng.next().abs(),
                com: length * (0.3 + 0.4 * rng.next().abs()),
                inertia: 0.02 + 0.05 * rng.next().abs(),
            }
        });
        let mut j = SMatrix::<f64, N, N>::zeros();
        for r in 0..N {
            for col in 0..=r {
                j[(r, col)] = 0.1 + 0.2 * rng.next().abs();
            }
        }
        PredictionModel {
            robot: RobotModel {
                chain: Chain::new(links),
                viscous: 0.5 + rng.next().abs(),
                coulomb: 0.3 + rng.next().abs(),
                friction,
            },
            straps: Straps {
                j,
                stiffness: 500.0 + 1000.0 * rng.next().abs(),
                damping: 10.0 + 20.0 * rng.next().abs(),
            },
            interaction,
            dt: 0.01,
            substeps,
        }
    }

    fn check<const N: usize>(seed: u64) {
        let mut rng = Lcg(seed);
        for case in 0..200 {
            let interaction = interaction_of(case);
            let friction = if case % 5 == 4 {
                Friction::Sign
            } else {
                Friction::Tanh {
                    width: [0.01, 0.1, 1.0][case % 3],
                }
            };
            let substeps = 1 + case % 3;
            let m = model::<N>(&mut rng, interaction, friction, substeps);
            let (x, u, inp) = rng.point(1.5, 3.0);
            let tau0 = 0.01 * (case % 4) as f64;
            let (xa, ja) = m.step_with_jacobian(&x, &u, tau0, &inp);
            let (xb, jb) = m.step_with_jacobian_dual(&x, &u, tau0, &inp);
            let close = |a: &SMatrix<f64, N, N>, b: &SMatrix<f64, N, N>, what: &str| {
                let err = (a - b).amax();
                let scale = 1.0 + b.amax();
                assert!(
                    err <= 1e-10 * scale,
                    "N={N} case {case} {what}: tailored {a} dual {b} err {err:e}"
                );
            };
            close(&ja.qq, &jb.qq, "qq");
            close(&ja.qv, &jb.qv, "qv");
            close(&ja.vq, &jb.vq, "vq");
            close(&ja.vv, &jb.vv, "vv");
            close(&ja.qu, &jb.qu, "qu");
            close(&ja.vu, &jb.vu, "vu");
            assert!((xa.q - xb.q).amax() <= 1e-12 * (1.0 + xb.q.amax()));
            assert!((xa.qd - xb.qd).amax() <= 1e-12 * (1.0 + xb.qd.amax()));
        }
    }

    /// The written-out two-link Jacobian gives the chain code's numbers (same nonzero terms in
    /// the same order; the skipped terms are exact zeros).
    #[test]
    fn two_link_jacobian_equals_the_chain_code() {
        let mut rng = Lcg(11);
        for case in 0..2000 {
            let interaction = interaction_of(case);
            let friction = if case % 5 == 4 {
                Friction::Sign
            } else {
                Friction::Tanh { width: 0.1 }
            };
            let m = model::<2>(&mut rng, interaction, friction, 1);
            let k = StageConstants::new(&m);
            let (x, u, inp) = rng.point(4.0, 6.0);
            let tau = 0.01 * (case % 4) as f64;
            let a = m.derivative_jacobian_two_links(&k, tau, &x, &u, &inp, &mut None);
            let b = m.derivative_jacobian_chain(&k, tau, &x, &u, &inp);
            assert_eq!(a.qdd, b.qdd, "case {case}");
            assert_eq!(a.a_q, b.a_q, "case {case}");
            assert_eq!(a.a_v, b.a_v, "case {case}");
            assert_eq!(a.minv, b.minv, "case {case}");
        }
    }

    /// The branch-free strap torque of the Jacobian code equals `Straps::torque(Straps::force)`
    /// for finite arguments, with and without zero entries in `J`.
    #[test]
    fn branch_free_strap_torque_equals_the_straps_code() {
        fn run<const N: usize>(seed: u64) {
            let mut rng = Lcg(seed);
            for case in 0..500 {
                let mut m = model::<N>(&mut rng, Interaction::Predict, Friction::Sign, 1);
                if case % 2 == 0 {
                    m.straps.j[(N - 1, 0)] = 0.0;
                }
                let (dq, dqd) = (rng.vec::<N>(0.1), rng.vec::<N>(2.0));
                let want = m.straps.torque(&m.straps.force(&dq, &dqd));
                assert_eq!(
                    strap_torque(&m.straps, &dq, &dqd),
                    want,
                    "N = {N} case {case}"
                );
            }
        }
        run::<1>(31);
        run::<2>(32);
        run::<3>(33);
    }

    /// `step_with_jacobian` (with the shortened first substep) gives the numbers of the plain
    /// RK4 chaining through `stage_sens`.
    #[test]
    fn first_substep_shortcut_equals_plain_chaining() {
        fn plain<const N: usize>(
            m: &PredictionModel<N>,
            x: &JointState<f64, N>,
            u: &SVector<f64, N>,
            tau0: f64,
            inp: &HorizonInputs<N>,
        ) -> (JointState<f64, N>, StepJacobian<N>) {
            let consts = StageConstants::new(m);
            let n = m.substeps.max(1);
            let h = m.dt / n as f64;
            let (eye, zero) = (SMatrix::identity(), SMatrix::zeros());
            let mut s = *x;
            let mut sens = StepJacobian {
                qq: eye,
                qv: zero,
                vq: zero,
                vv: eye,
                qu: zero,
                vu: zero,
            };
            for i in 0..n {
                let t = tau0 + i as f64 * h;
                let mut tr = None;
                let (k1, d1) = m.stage_sens(&consts, t, &s, u, inp, &sens, &mut tr);
                let (x2, s2) = (s.add_scaled(0.5 * h, &k1), sens.add_scaled(0.5 * h, &d1));
                let (k2, d2) = m.stage_sens(&consts, t + 0.5 * h, &x2, u, inp, &s2, &mut tr);
                let (x3, s3) = (s.add_scaled(0.5 * h, &k2), sens.add_scaled(0.5 * h, &d2));
                let (k3, d3) = m.stage_sens(&consts, t + 0.5 * h, &x3, u, inp, &s3, &mut tr);
                let (x4, s4) = (s.add_scaled(h, &k3), sens.add_scaled(h, &d3));
                let (k4, d4) = m.stage_sens(&consts, t + h, &x4, u, inp, &s4, &mut tr);
                s = s
                    .add_scaled(h / 6.0, &k1)
                    .add_scaled(h / 3.0, &k2)
                    .add_scaled(h / 3.0, &k3)
                    .add_scaled(h / 6.0, &k4);
                sens = sens
                    .add_scaled(h / 6.0, &d1)
                    .add_scaled(h / 3.0, &d2)
                    .add_scaled(h / 3.0, &d3)
                    .add_scaled(h / 6.0, &d4);
            }
            (s, sens)
        }
        fn run<const N: usize>(seed: u64) {
            let mut rng = Lcg(seed);
            for case in 0..300 {
                let interaction = interaction_of(case);
                let m = model::<N>(
                    &mut rng,
                    interaction,
                    Friction::Tanh { width: 0.1 },
                    1 + case % 3,
                );
                let (x, u, inp) = rng.point(1.5, 3.0);
                let a = m.step_with_jacobian(&x, &u, 0.01, &inp);
                assert_eq!(a, plain(&m, &x, &u, 0.01, &inp), "N = {N} case {case}");
            }
        }
        run::<1>(21);
        run::<2>(22);
        run::<3>(23);
    }

    /// The value-only step equals the state of `step_with_jacobian` to the bit (two links; the
    /// other link counts take `step`) and the generic `step` to rounding.
    #[test]
    fn value_step_equals_the_jacobian_step_state() {
        fn run<const N: usize>(seed: u64) {
            let mut rng = Lcg(seed);
            for case in 0..300 {
                let interaction = interaction_of(case);
                let friction = if case % 5 == 4 {
                    Friction::Sign
                } else {
                    Friction::Tanh { width: 0.1 }
                };
                let m = model::<N>(&mut rng, interaction, friction, 1 + case % 3);
                let consts = m.jacobian_constants();
                let (x, u, inp) = rng.point(1.5, 3.0);
                let tau0 = 0.01 * (case % 4) as f64;
                let v = m.step_value_using(&consts, &x, &u, tau0, &inp);
                let p = m.step(&x, &u, tau0, &inp);
                if N == 2 {
                    let (s, _) = m.step_with_jacobian_using(&consts, &x, &u, tau0, &inp);
                    assert_eq!(v, s, "N = {N} case {case}");
                } else {
                    assert_eq!(v, p, "N = {N} case {case}");
                }
                assert!(
                    (v.q - p.q).amax() <= 1e-12 * (1.0 + p.q.amax()),
                    "case {case}"
                );
                assert!(
                    (v.qd - p.qd).amax() <= 1e-12 * (1.0 + p.qd.amax()),
                    "case {case}"
                );
            }
        }
        run::<1>(41);
        run::<2>(42);
        run::<3>(43);
    }

    #[test]
    fn tailored_jacobian_matches_dual_n1() {
        check::<1>(1);
    }

    #[test]
    fn tailored_jacobian_matches_dual_n2() {
        check::<2>(2);
    }

    #[test]
    fn tailored_jacobian_matches_dual_n3() {
        check::<3>(3);
    }
}
