//! The exact one-period RK4 sensitivity of the robot model (MODEL.md §8; paper §3.1, eqs. 1
//! and 7), hand-derived instead of by dual numbers: per RK4 stage the analytic partial
//! derivatives of `qdd = M(q)⁻¹(u + T_ext + d − C(q, qd) qd − G(q) − friction(qd))` (eq. 1)
//! with respect to `q`, `qd` and `u` (first and second derivatives of `M` from the chain's
//! closed form, MODEL.md §1), chained through the stages.
//!
//! Shared by the NMPC prediction model (`control::prediction`, whose `T_ext` is the predicted or
//! held strap torque) and the scenario EKFs (`estimate::scenario`, `T_ext` the held filtered
//! strap torque): the external torque and its derivatives come from a [`StageTorque`].

use super::{sin_cos, sin_cos_near, tanh, Friction, JointState, RkState, RobotModel};
use nalgebra::{SMatrix, SVector};

/// Exact Jacobian of one prediction step `x⁺ = Φ(x, u)`, in `N×N` blocks (with a held
/// disturbance `d` added to `u`, `∂x⁺/∂d = ∂x⁺/∂u`).
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

impl<const N: usize> StepJacobian<N> {
    /// The state `Φ(x, u)` of a step function and its Jacobian by forward-mode dual numbers
    /// seeded on `q`, `qd` and `u` in three passes: the oracle of the hand-derived Jacobians
    /// (`control::PredictionModel::step_with_jacobian`; same values to rounding, about ten
    /// times slower) in tests and benchmarks, hidden from the docs. `step` is the step at dual
    /// scalars, e.g. `|x, u| model.step(x, u, tau0, &inp)`.
    #[doc(hidden)]
    #[cfg(feature = "std")]
    pub fn by_dual_numbers(
        x: &JointState<f64, N>,
        u: &SVector<f64, N>,
        step: impl Fn(&JointState<Dual<N>, N>, &SVector<Dual<N>, N>) -> JointState<Dual<N>, N>,
    ) -> (JointState<f64, N>, Self) {
        use num_dual::DualStruct;
        let lift = |v: &SVector<f64, N>| v.map(Dual::<N>::from);
        let seed = |v: &SVector<f64, N>| {
            let mut out = lift(v);
            for i in 0..N {
                out[i] = Dual::<N>::from(v[i]).derivative(i);
            }
            out
        };
        let unpack = |s: &JointState<Dual<N>, N>| {
            let mut a = SMatrix::<f64, N, N>::zeros();
            let mut b = SMatrix::<f64, N, N>::zeros();
            for r in 0..N {
                for (m, v) in [(&mut a, &s.q[r]), (&mut b, &s.qd[r])] {
                    if let Some(e) = &v.eps.0 {
                        for col in 0..N {
                            m[(r, col)] = e[col];
                        }
                    }
                }
            }
            (a, b)
        };
        // One pass seeded on `q`, `qd` or `u`.
        let pass = |on: usize| {
            let pick = |k: usize, v: &SVector<f64, N>| if on == k { seed(v) } else { lift(v) };
            let x0 = JointState {
                q: pick(0, &x.q),
                qd: pick(1, &x.qd),
            };
            step(&x0, &pick(2, u))
        };
        let (sq, sv, su) = (pass(0), pass(1), pass(2));
        let (qq, vq) = unpack(&sq);
        let (qv, vv) = unpack(&sv);
        let (qu, vu) = unpack(&su);
        let next = JointState {
            q: sq.q.map(|v| v.re()),
            qd: sq.qd.map(|v| v.re()),
        };
        let jac = Self {
            qq,
            qv,
            vq,
            vv,
            qu,
            vu,
        };
        (next, jac)
    }
}

/// The dual number of [`StepJacobian::by_dual_numbers`]: `N` derivative directions.
#[cfg(feature = "std")]
type Dual<const N: usize> = num_dual::DualSVec64<N>;

/// The external joint torque `T_ext(τ, q, qd)` on the right-hand side of eq. 1 besides the input
/// `u` and the disturbance `d`, with its partial derivatives: [`StageTorque::terms`] at time `τ`
/// into the period and the stage state `(q, qd)`.
pub(crate) trait StageTorque<const N: usize> {
    /// `(T_ext, ∂T_ext/∂q, ∂T_ext/∂qd)` at the stage state `x`.
    fn terms(&self, tau: f64, x: &JointState<f64, N>) -> TorqueTerms<N>;
}

/// `(T_ext, ∂T_ext/∂q, ∂T_ext/∂qd)`: an external joint torque and its partial derivatives.
pub(crate) type TorqueTerms<const N: usize> =
    (SVector<f64, N>, SMatrix<f64, N, N>, SMatrix<f64, N, N>);

/// A torque held over the period (MODEL.md §8, the EKF's `T_int(k−1)`): zero derivatives.
#[derive(Clone, Copy, Debug)]
pub(crate) struct HeldTorque<const N: usize>(pub SVector<f64, N>);

impl<const N: usize> StageTorque<N> for HeldTorque<N> {
    #[inline(always)]
    fn terms(&self, _tau: f64, _x: &JointState<f64, N>) -> TorqueTerms<N> {
        (self.0, SMatrix::zeros(), SMatrix::zeros())
    }
}

/// One period of the robot model for the tailored Jacobian: `dt` in `substeps` RK4 steps of
/// eq. 1 with the input `u` held, the disturbance `d` held and the external torque of `torque`.
#[derive(Clone, Copy, Debug)]
pub(crate) struct TailoredRk4<'a, const N: usize, T> {
    /// Robot model (smooth friction for a meaningful Jacobian).
    pub robot: &'a RobotModel<N>,
    /// Its constants ([`ChainConstants::new`] of `robot`).
    pub consts: &'a ChainConstants<N>,
    /// Input `u` (N·m), held.
    pub input: &'a SVector<f64, N>,
    /// Disturbance `d` (N·m), held.
    pub disturbance: &'a SVector<f64, N>,
    /// External torque.
    pub torque: T,
    /// Period (s).
    pub dt: f64,
    /// RK4 steps per period (at least one is taken).
    pub substeps: usize,
}

impl<const N: usize, T: StageTorque<N>> TailoredRk4<'_, N, T> {
    /// The state one period after `x` under the input (starting `tau0` into the horizon) and its exact
    /// Jacobian: the RK4 sensitivity chained stage by stage (equal to forward-mode dual numbers
    /// to rounding; test `tailored_jacobian_matches_dual`).
    #[inline(always)]
    pub(crate) fn step_with_jacobian(
        &self,
        x: &JointState<f64, N>,
        tau0: f64,
    ) -> (JointState<f64, N>, StepJacobian<N>) {
        let n = self.substeps.max(1);
        let h = self.dt / n as f64;
        let mut s = *x;
        let mut sens = StepJacobian::identity();
        for i in 0..n {
            let t = tau0 + i as f64 * h;
            // The substep's first stage evaluates `sin`/`cos` of the link angles; the later
            // stages rotate them by the small angle increments (`LinkTrig`).
            let mut trig = None;
            // The first substep starts from the identity sensitivity `[[I, 0, 0], [0, I, 0]]`:
            // its first stage has no products (`∂k/∂(x₀, u) = [[0, I, 0], [a_q, a_v, M⁻¹]]`, the
            // values `chained` forms from products with the identity and zero blocks, `x·1 +
            // y·0 = x`) and its second stage two fewer (below).
            let (k1, d1) = if i == 0 {
                let eye = StepJacobian::identity();
                self.stage(t, &s, &eye, &mut trig, |d, _| [d.a_q, d.a_v, d.minv])
            } else {
                self.stage(t, &s, &sens, &mut trig, chained)
            };
            let x2 = s.add_scaled(0.5 * h, &k1);
            // From the identity sensitivity, `sens + c·d` adds nothing to the zero entries of
            // `sens` and of `d1` and one to the diagonal: the sums are formed only where they
            // are not exact (`0 + y = y`, `1·c = c`; same values).
            let (k2, d2) = if i == 0 {
                // `sx.qq = I`, `sx.qu = 0` and `sx.qv = h2·I` exactly (identity plus `h2 = h/2`
                // times the first stage's blocks `0`, `I`, `0`): the products with them are left
                // out or scalar (same values).
                let h2 = 0.5 * h;
                let s2 = StepJacobian::identity_plus_first(h2, &d1);
                self.stage(t + h2, &x2, &s2, &mut trig, |d, sx| {
                    [
                        d.a_q + d.a_v * sx.vq,
                        d.a_q * h2 + d.a_v * sx.vv,
                        d.a_v * sx.vu + d.minv,
                    ]
                })
            } else {
                let s2 = sens.add_scaled(0.5 * h, &d1);
                self.stage(t + 0.5 * h, &x2, &s2, &mut trig, chained)
            };
            let x3 = s.add_scaled(0.5 * h, &k2);
            let s3 = if i == 0 {
                StepJacobian::identity_plus(0.5 * h, &d2)
            } else {
                sens.add_scaled(0.5 * h, &d2)
            };
            let (k3, d3) = self.stage(t + 0.5 * h, &x3, &s3, &mut trig, chained);
            let x4 = s.add_scaled(h, &k3);
            let s4 = if i == 0 {
                StepJacobian::identity_plus(h, &d3)
            } else {
                sens.add_scaled(h, &d3)
            };
            let (k4, d4) = self.stage(t + h, &x4, &s4, &mut trig, chained);
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

    /// The state of [`Self::step_with_jacobian`] without the sensitivities, for `N = 2`: the
    /// stages use the written-out two-link acceleration and the trigonometry of the Jacobian code
    /// (its derivative terms, unused, are left out by the compiler), so the state equals that of
    /// `step_with_jacobian` to the bit.
    #[inline(always)]
    pub(crate) fn step_value_two_links(
        &self,
        x: &JointState<f64, N>,
        tau0: f64,
    ) -> JointState<f64, N> {
        debug_assert_eq!(N, 2);
        let n = self.substeps.max(1);
        let h = self.dt / n as f64;
        let f = |t: f64, y: &JointState<f64, N>, trig: &mut Option<LinkTrig>| JointState {
            q: y.qd,
            qd: self.derivative_jacobian_two_links(t, y, trig).qdd,
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
    /// sensitivity `sx = ∂X/∂(x₀, u)`: the position rows are the velocity rows of `sx`, the
    /// velocity rows `[∂/∂q₀, ∂/∂qd₀, ∂/∂u]` are `rows(d, sx)` of the partial derivatives `d` of
    /// `qdd` ([`chained`] in general, fewer products where `sx` has known identity and zero
    /// blocks).
    #[inline(always)]
    pub(crate) fn stage(
        &self,
        tau: f64,
        x: &JointState<f64, N>,
        sx: &StepJacobian<N>,
        trig: &mut Option<LinkTrig>,
        rows: impl FnOnce(&AccelJacobian<N>, &StepJacobian<N>) -> [SMatrix<f64, N, N>; 3],
    ) -> (JointState<f64, N>, StepJacobian<N>) {
        let d = self.derivative_jacobian(tau, x, trig);
        let k = JointState { q: x.qd, qd: d.qdd };
        let [vq, vv, vu] = rows(&d, sx);
        let dk = StepJacobian {
            qq: sx.vq,
            qv: sx.vv,
            qu: sx.vu,
            vq,
            vv,
            vu,
        };
        (k, dk)
    }

    /// `qdd` of eq. 1 with its partial derivatives `∂qdd/∂q`, `∂qdd/∂qd` and
    /// `∂qdd/∂u = M⁻¹`, in `f64`.
    #[inline(always)]
    fn derivative_jacobian(
        &self,
        tau: f64,
        x: &JointState<f64, N>,
        trig: &mut Option<LinkTrig>,
    ) -> AccelJacobian<N> {
        if N == 2 {
            self.derivative_jacobian_two_links(tau, x, trig)
        } else {
            self.derivative_jacobian_chain(tau, x)
        }
    }

    /// [`Self::derivative_jacobian`] for any `N`: the chain's tensors `∂M/∂q`, `∂²M/∂q²`.
    #[allow(clippy::needless_range_loop)] // index algebra of the closed-form derivatives
    pub(crate) fn derivative_jacobian_chain(
        &self,
        tau: f64,
        x: &JointState<f64, N>,
    ) -> AccelJacobian<N> {
        let k = self.consts;
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
        let terms = ChainTerms { m, hv, g, dh_v };
        // ∂(M qdd)/∂q_r = ∂rhs/∂q_r ⇒ ∂qdd/∂q_r = M⁻¹(∂rhs/∂q_r − ∂M/∂q_r qdd).
        self.accel(tau, x, &terms, &ChainBq { d1, dh_q, dg })
    }

    /// `qdd = M⁻¹ rhs` of eq. 1 with its partial derivatives from the chain's `terms`: friction,
    /// the external torque, `M⁻¹`; `∂qdd/∂q = M⁻¹ bq(∂T_ext/∂q, qdd)` (the caller's `−∂T_ext/∂q −
    /// ∂h/∂q − ∂G/∂q − ∂M/∂q qdd`), `∂qdd/∂qd = M⁻¹(−∂h/∂qd − ∂T_ext/∂qd − diag ∂fr/∂qd)`.
    #[inline(always)]
    fn accel(
        &self,
        tau: f64,
        x: &JointState<f64, N>,
        terms: &ChainTerms<N>,
        bq: &impl PositionBlock<N>,
    ) -> AccelJacobian<N> {
        let v = &x.qd;
        let (hv, g) = (&terms.hv, &terms.g);
        // Friction and its (diagonal) derivative.
        let rb = &self.robot;
        let mut fr = SVector::<f64, N>::zeros();
        let mut dfr = [0.0; N];
        let mut joint = |i: usize, (coul, dcoul): (f64, f64)| {
            fr[i] = v[i] * rb.viscous + coul;
            dfr[i] = rb.viscous + dcoul;
        };
        // The friction law is matched once per stage, not per joint.
        match rb.friction {
            Friction::Sign => (0..N).for_each(|i| joint(i, sign_friction(rb, v[i]))),
            Friction::Tanh { width } => {
                (0..N).for_each(|i| joint(i, tanh_friction(rb, width, v[i])))
            }
        }
        // Interaction torque and its derivatives (−ks JᵀJ, −cs JᵀJ when predicted).
        let (t_int, ti_q, ti_v) = self.torque.terms(tau, x);
        let mut rhs = SVector::<f64, N>::zeros();
        for i in 0..N {
            rhs[i] = self.input[i] + t_int[i] + self.disturbance[i] - hv[i] - g[i] - fr[i];
        }
        let minv = spd_inverse(&terms.m);
        let qdd = minv * rhs;
        let mut bv = -terms.dh_v;
        for i in 0..N {
            for j in 0..N {
                bv[(i, j)] -= ti_v[(i, j)];
            }
            bv[(i, i)] -= dfr[i];
        }
        let bq = bq.bq(&ti_q, &qdd);
        AccelJacobian {
            qdd,
            a_q: minv * bq,
            a_v: minv * bv,
            minv,
        }
    }

    /// [`Self::derivative_jacobian_chain`] for `N = 2` with the chain's tensors written out: of
    /// `∂M/∂q` (8 entries) and `∂²M/∂q²` (16) only three each are nonzero, so the Coriolis
    /// terms and their derivatives reduce to a few products. Every nonzero term is formed and
    /// summed in the order of the chain code, and the terms it skips are exact zeros, so the
    /// results are the same numbers (unit test `two_link_jacobian_equals_the_chain_code`).
    #[inline(always)]
    pub(crate) fn derivative_jacobian_two_links(
        &self,
        tau: f64,
        x: &JointState<f64, N>,
        trig: &mut Option<LinkTrig>,
    ) -> AccelJacobian<N> {
        debug_assert_eq!(N, 2);
        let k = self.consts;
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
        // Gravity and its derivative.
        let g1 = 0.0 + k.w[1] * s1;
        let g0 = g1 + k.w[0] * s0;
        let (wc0, wc1) = (k.w[0] * c0, k.w[1] * c1);
        let dg00 = 0.0 + wc0 + wc1;
        // ∂h/∂q: the first column is zero.
        let (e00, e01, e10) = (-(0.5 * e), gd - 0.5 * f, -(0.5 * gd));
        let dh_q01 = e * v0 * v1 + f * v1 * v1;
        let dh_q11 = e00 * v0 * v0 + e01 * v0 * v1 + e10 * v1 * v0;
        let mut hv = SVector::<f64, N>::zeros();
        let mut g = SVector::<f64, N>::zeros();
        (hv[0], hv[1], g[0], g[1]) = (hv0, hv1, g0, g1);
        let terms = ChainTerms { m, hv, g, dh_v };
        let bq = TwoLinkBq {
            a,
            b,
            c,
            dh_q01,
            dh_q11,
            wc1,
            dg00,
        };
        self.accel(tau, x, &terms, &bq)
    }
}

/// `N × N` matrix of `f64`.
type Mat<const N: usize> = SMatrix<f64, N, N>;

/// The mass matrix `M`, the Coriolis term `h = C qd` with `∂h/∂qd`, and gravity `G` of the chain
/// at one stage (MODEL.md §1).
#[derive(Clone, Copy, Debug)]
pub(crate) struct ChainTerms<const N: usize> {
    m: Mat<N>,
    hv: SVector<f64, N>,
    g: SVector<f64, N>,
    dh_v: Mat<N>,
}

/// `bq = −∂T_ext/∂q − ∂h/∂q − ∂G/∂q − ∂M/∂q qdd`, the right-hand side of `M ∂qdd/∂q = bq`
/// (`∂(M qdd)/∂q_r = ∂rhs/∂q_r`), from the chain's derivative terms at one stage.
pub(crate) trait PositionBlock<const N: usize> {
    /// `bq` given `∂T_ext/∂q` and `qdd`.
    fn bq(&self, ti_q: &Mat<N>, qdd: &SVector<f64, N>) -> Mat<N>;
}

/// The chain code's terms of `bq`: `∂M/∂q` (`d1[r][i][j] = ∂M_ij/∂q_r`), `∂h/∂q` and `∂G/∂q`.
struct ChainBq<const N: usize> {
    d1: [[[f64; N]; N]; N],
    dh_q: Mat<N>,
    dg: Mat<N>,
}

impl<const N: usize> PositionBlock<N> for ChainBq<N> {
    #[inline(always)]
    fn bq(&self, ti_q: &Mat<N>, qdd: &SVector<f64, N>) -> Mat<N> {
        let (d1, dh_q, dg) = (&self.d1, &self.dh_q, &self.dg);
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
        bq
    }
}

/// The two-link code's nonzero terms of `bq`: `∂M/∂q`'s `a`, `b`, `c`, `∂h/∂q`'s second column
/// and `∂G/∂q` (`dg00`, the others `wc1`).
struct TwoLinkBq {
    a: f64,
    b: f64,
    c: f64,
    dh_q01: f64,
    dh_q11: f64,
    wc1: f64,
    dg00: f64,
}

impl<const N: usize> PositionBlock<N> for TwoLinkBq {
    #[inline(always)]
    fn bq(&self, ti_q: &Mat<N>, qdd: &SVector<f64, N>) -> Mat<N> {
        let TwoLinkBq {
            a,
            b,
            c,
            dh_q01,
            dh_q11,
            wc1,
            dg00,
        } = *self;
        let mut bq = SMatrix::<f64, N, N>::zeros();
        bq[(0, 0)] = -ti_q[(0, 0)] - dg00;
        bq[(1, 0)] = -ti_q[(1, 0)] - wc1;
        bq[(0, 1)] = -ti_q[(0, 1)] - dh_q01 - wc1 - (a * qdd[0] + b * qdd[1]);
        bq[(1, 1)] = -ti_q[(1, 1)] - dh_q11 - wc1 - c * qdd[0];
        bq
    }
}

/// The velocity rows of a stage's sensitivity by the chain rule through the stage state's
/// sensitivity `sx`: `∂qdd/∂q₀ = a_q·sx.qq + a_v·sx.vq`, likewise for `qd₀`, and `∂qdd/∂u` with
/// the direct term `M⁻¹`.
#[inline(always)]
pub(crate) fn chained<const N: usize>(
    d: &AccelJacobian<N>,
    sx: &StepJacobian<N>,
) -> [SMatrix<f64, N, N>; 3] {
    [
        d.a_q * sx.qq + d.a_v * sx.vq,
        d.a_q * sx.qv + d.a_v * sx.vv,
        d.a_q * sx.qu + d.a_v * sx.vu + d.minv,
    ]
}

/// Coulomb friction of one joint speed and its derivative, sign law.
#[inline(always)]
fn sign_friction<const N: usize>(rb: &RobotModel<N>, v: f64) -> (f64, f64) {
    let c = if v > 0.0 {
        rb.coulomb
    } else if v < 0.0 {
        -rb.coulomb
    } else {
        0.0
    };
    (c, 0.0)
}

/// Coulomb friction of one joint speed and its derivative, smooth law `tanh(v / width)`.
#[inline(always)]
fn tanh_friction<const N: usize>(rb: &RobotModel<N>, width: f64, v: f64) -> (f64, f64) {
    let t: f64 = tanh(v * (1.0 / width));
    (t * rb.coulomb, rb.coulomb * (1.0 - t * t) * (1.0 / width))
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
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct AccelJacobian<const N: usize> {
    /// `qdd`.
    pub qdd: SVector<f64, N>,
    /// `∂qdd/∂q`.
    pub a_q: SMatrix<f64, N, N>,
    /// `∂qdd/∂qd`.
    pub a_v: SMatrix<f64, N, N>,
    /// `∂qdd/∂u = M⁻¹`.
    pub minv: SMatrix<f64, N, N>,
}

/// Model constants of the tailored Jacobian, computed once per model.
#[derive(Clone, Copy, Debug)]
pub(crate) struct ChainConstants<const N: usize> {
    /// `P_ab = Σ_{k ≥ max(a,b)} m_k d_ka d_kb`.
    p: [[f64; N]; N],
    /// `Σ_{k ≥ i} I_k`.
    inertia_tail: [f64; N],
    /// Gravity weights `W_a = g (m_a c_a + Σ_{k>a} m_k l_a)`.
    w: [f64; N],
}

impl<const N: usize> ChainConstants<N> {
    /// The constants of `robot`'s chain (MODEL.md §1: the closed-form mass matrix and gravity).
    #[inline(always)]
    pub(crate) fn new(robot: &RobotModel<N>) -> Self {
        let l = &robot.chain.links;
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
        let g = robot.chain.gravity;
        let mut w = [0.0; N];
        for a in 0..N {
            let mut s = l[a].mass * l[a].com;
            for lk in l.iter().skip(a + 1) {
                s += lk.mass * l[a].length;
            }
            w[a] = g * s;
        }
        ChainConstants { p, inertia_tail, w }
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
    /// `[[I, 0, 0], [0, I, 0]]`: the sensitivity of the state to itself, where a step starts.
    #[inline(always)]
    pub(crate) fn identity() -> Self {
        let (eye, zero) = (SMatrix::identity(), SMatrix::zeros());
        StepJacobian {
            qq: eye,
            qv: zero,
            vq: zero,
            vv: eye,
            qu: zero,
            vu: zero,
        }
    }

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
}

impl<const N: usize> RkState for StepJacobian<N> {
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
