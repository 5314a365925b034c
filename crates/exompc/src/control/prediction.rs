//! The NMPC prediction model (MODEL.md §8): the scenario's robot model, the disturbance estimate,
//! and the strap torque predicted from the human-intent estimate inside every RK4 stage.

use crate::model::{
    c, rk4_step, ChainConstants, JointState, Real, RobotModel, StageTorque, Straps, TailoredRk4,
    TorqueTerms,
};
use nalgebra::{SMatrix, SVector};
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

pub use crate::model::StepJacobian;

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

    /// [`Self::step`] with its exact Jacobian, hand-derived: per RK4 stage the analytic partial
    /// derivatives of `qdd = M⁻¹(u + T_int + d − C qd − G − friction)` with respect to `q`, `qd`
    /// and `u` (first and second derivatives of `M` from the chain's closed form), chained
    /// through the stages. Equals the dual-number Jacobian of [`Self::step`]
    /// ([`StepJacobian::by_dual_numbers`], the tests' oracle) to rounding.
    pub fn step_with_jacobian(
        &self,
        x: &JointState<f64, N>,
        u: &SVector<f64, N>,
        tau0: f64,
        inp: &HorizonInputs<N>,
    ) -> (JointState<f64, N>, StepJacobian<N>) {
        self.tailored(&self.jacobian_constants(), inp, u)
            .step_with_jacobian(x, tau0)
    }

    /// The model constants [`Self::tailored`] needs, computed once for a rollout of many
    /// steps.
    #[inline]
    pub(crate) fn jacobian_constants(&self) -> StageConstants<N> {
        StageConstants::new(self)
    }

    /// The state of the tailored step with Jacobian ([`Self::tailored`]) without the sensitivities, for the
    /// rollouts that need no Jacobian (the line search's backtracking trials, the dense
    /// back-end's residuals). With two links the stages use the written-out two-link
    /// acceleration and the trigonometry of the Jacobian code (its derivative terms,
    /// unused, are left out by the compiler), so the state equals that of
    /// `step_with_jacobian` to the bit and [`Self::step`] to rounding; other link counts
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
        self.tailored(consts, inp, u).step_value_two_links(x, tau0)
    }

    /// The model-level tailored RK4 of this model with the constants `consts`, the horizon
    /// inputs `inp` and the input `u`: the strap torque of [`Self::interaction_terms`] as the
    /// external torque. Its `step_with_jacobian` is [`Self::step_with_jacobian`] with the
    /// constants computed by the caller (of this model: the same numbers).
    #[inline(always)]
    pub(crate) fn tailored<'a>(
        &'a self,
        consts: &'a StageConstants<N>,
        inp: &'a HorizonInputs<N>,
        u: &'a SVector<f64, N>,
    ) -> TailoredRk4<'a, N, StrapTorque<'a, N>> {
        TailoredRk4 {
            robot: &self.robot,
            consts: &consts.chain,
            input: u,
            disturbance: &inp.disturbance,
            torque: StrapTorque {
                model: self,
                consts,
                inp,
            },
            dt: self.dt,
            substeps: self.substeps,
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

#[inline(always)]
fn zero_mat<const N: usize>() -> SMatrix<f64, N, N> {
    SMatrix::zeros()
}

/// Model constants of the tailored Jacobian ([`PredictionModel::jacobian_constants`]): the
/// chain's and the straps' derivative matrices.
#[derive(Clone, Copy, Debug)]
pub(crate) struct StageConstants<const N: usize> {
    /// The chain's constants.
    chain: ChainConstants<N>,
    /// `ks JᵀJ`.
    ks_jtj: SMatrix<f64, N, N>,
    /// `cs JᵀJ`.
    cs_jtj: SMatrix<f64, N, N>,
}

impl<const N: usize> StageConstants<N> {
    #[inline(always)]
    fn new(model: &PredictionModel<N>) -> Self {
        let jtj = model.straps.j.transpose() * model.straps.j;
        StageConstants {
            chain: ChainConstants::new(&model.robot),
            ks_jtj: jtj * model.straps.stiffness,
            cs_jtj: jtj * model.straps.damping,
        }
    }
}

/// The strap torque of a prediction model as the tailored RK4's external torque
/// ([`PredictionModel::interaction_terms`]).
pub(crate) struct StrapTorque<'a, const N: usize> {
    model: &'a PredictionModel<N>,
    consts: &'a StageConstants<N>,
    inp: &'a HorizonInputs<N>,
}

impl<const N: usize> StageTorque<N> for StrapTorque<'_, N> {
    #[inline(always)]
    fn terms(&self, tau: f64, x: &JointState<f64, N>) -> TorqueTerms<N> {
        let (model, inp) = (self.model, self.inp);
        model.interaction_terms(self.consts, tau, &x.q, &x.qd, inp)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::{chained, rk4_step, Chain, Friction, Link};

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

    /// One case of a scan: a model, a point and a start time into the horizon.
    struct Case<const N: usize> {
        m: PredictionModel<N>,
        x: JointState<f64, N>,
        u: SVector<f64, N>,
        inp: HorizonInputs<N>,
        tau0: f64,
    }

    /// Case `case` of a scan: a pseudo-random model (every third case holds the interaction
    /// torque, every fifth has sign friction, the others `Tanh { width }`) with `substeps`, a
    /// point within `±q`, `±qd` ([`Lcg::point`]) and `tau0 = 0.01·(case mod 4)`.
    fn scan_case<const N: usize>(
        rng: &mut Lcg,
        case: usize,
        width: f64,
        substeps: usize,
        (q, qd): (f64, f64),
    ) -> Case<N> {
        let friction = if case % 5 == 4 {
            Friction::Sign
        } else {
            Friction::Tanh { width }
        };
        let m = model::<N>(rng, interaction_of(case), friction, substeps);
        let (x, u, inp) = rng.point(q, qd);
        let tau0 = 0.01 * (case % 4) as f64;
        Case { m, x, u, inp, tau0 }
    }

    /// `runs` (one per link count 1, 2, 3) with the seeds `seed`, `seed + 1`, `seed + 2`.
    fn each_link_count(runs: [fn(u64); 3], seed: u64) {
        for (k, run) in runs.into_iter().enumerate() {
            run(seed + k as u64);
        }
    }

    fn check<const N: usize>(seed: u64) {
        let mut rng = Lcg(seed);
        for case in 0..200 {
            let width = [0.01, 0.1, 1.0][case % 3];
            let Case { m, x, u, inp, tau0 } =
                scan_case::<N>(&mut rng, case, width, 1 + case % 3, (1.5, 3.0));
            let (xa, ja) = m.step_with_jacobian(&x, &u, tau0, &inp);
            let (xb, jb) = StepJacobian::by_dual_numbers(&x, &u, |x, u| m.step(x, u, tau0, &inp));
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
            let Case {
                m,
                x,
                u,
                inp,
                tau0: tau,
            } = scan_case::<2>(&mut rng, case, 0.1, 1, (4.0, 6.0));
            let k = StageConstants::new(&m);
            let tailored = m.tailored(&k, &inp, &u);
            let a = tailored.derivative_jacobian_two_links(tau, &x, &mut None);
            let b = tailored.derivative_jacobian_chain(tau, &x);
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
        each_link_count([run::<1>, run::<2>, run::<3>], 31);
    }

    /// `step_with_jacobian` (with the shortened first substep) gives the numbers of the plain
    /// RK4 chaining of the stages' sensitivities (`chained`) by the model's `rk4_step`.
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
            let tailored = m.tailored(&consts, inp, u);
            let n = m.substeps.max(1);
            let h = m.dt / n as f64;
            let mut s = (*x, StepJacobian::identity());
            for i in 0..n {
                // The model's generic RK4 step of the state and its sensitivity together.
                let mut trig = None;
                let f = |t: f64, (y, sy): &(JointState<f64, N>, StepJacobian<N>)| {
                    tailored.stage(t, y, sy, &mut trig, chained)
                };
                s = rk4_step(f, tau0 + i as f64 * h, &s, h);
            }
            s
        }
        fn run<const N: usize>(seed: u64) {
            let mut rng = Lcg(seed);
            for case in 0..300 {
                let Case { m, x, u, inp, tau0 } =
                    scan_case::<N>(&mut rng, case, 0.1, 1 + case % 3, (1.5, 3.0));
                let a = m.step_with_jacobian(&x, &u, tau0, &inp);
                assert_eq!(a, plain(&m, &x, &u, tau0, &inp), "N = {N} case {case}");
            }
        }
        each_link_count([run::<1>, run::<2>, run::<3>], 21);
    }

    /// The value-only step equals the state of `step_with_jacobian` to the bit (two links; the
    /// other link counts take `step`) and the generic `step` to rounding.
    #[test]
    fn value_step_equals_the_jacobian_step_state() {
        fn run<const N: usize>(seed: u64) {
            let mut rng = Lcg(seed);
            for case in 0..300 {
                let Case { m, x, u, inp, tau0 } =
                    scan_case::<N>(&mut rng, case, 0.1, 1 + case % 3, (1.5, 3.0));
                let consts = m.jacobian_constants();
                let v = m.step_value_using(&consts, &x, &u, tau0, &inp);
                let p = m.step(&x, &u, tau0, &inp);
                if N == 2 {
                    let (s, _) = m.tailored(&consts, &inp, &u).step_with_jacobian(&x, tau0);
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
        each_link_count([run::<1>, run::<2>, run::<3>], 41);
    }

    /// The tailored Jacobian equals forward-mode dual numbers through the generic step (an
    /// independent derivation) to rounding, for one, two and three links.
    #[test]
    fn tailored_jacobian_matches_dual() {
        each_link_count([check::<1>, check::<2>, check::<3>], 1);
    }
}
