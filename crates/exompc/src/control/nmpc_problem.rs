//! The NMPC problem of paper eq. 7 (constraints 8-9): its settings and the condensed
//! least-squares form the dense SQP solves; the stage form (`ocp.rs`) and the solver state
//! (`nmpc.rs`) build on it.

use super::hessian::CurvatureWork;
use super::prediction::{HorizonInputs, PredictionModel, StepJacobian};
use super::TorqueLimits;
#[cfg(not(feature = "std"))]
use crate::math::Float;
use crate::model::JointState;
use crate::solver::{Constraints, HessianModel, LeastSquares, SqpSettings};
use alloc::{vec, vec::Vec};
use nalgebra::{DMatrix, SMatrix, SVector};
use serde::{Deserialize, Serialize};

/// Which QP solver the NMPC's SQP uses (`[controller.sqp] qp`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum QpBackend {
    /// Condensed dense Goldfarb–Idnani QP ([`crate::solver::DenseQp`]) with the configured
    /// Hessian model: `O((N·Nc)³)` per iteration. The oracle.
    Dense,
    /// Multiple-shooting stages with the Riccati QP ([`crate::solver::RiccatiQp`]) and the
    /// Gauss–Newton or exact Hessian: `O(Np·N³)` per iteration.
    Structured,
    /// `Structured` when `N·Nc ≥` [`AUTO_STRUCTURED_MIN_VARS`], else `Dense` (the default).
    #[default]
    Auto,
}

/// Smallest number of decision variables `N·Nc` for which [`QpBackend::Auto`] picks the
/// structured solver (measured with `exompc bench --qp`, docs/PERFORMANCE.md).
pub const AUTO_STRUCTURED_MIN_VARS: usize = 16;

impl QpBackend {
    /// Whether this backend resolves to the structured solver for `n_vars = N·Nc` variables
    /// by size alone (a library caller's [`NmpcSettings`]; a scenario file's `qp` and `hessian`
    /// are resolved together by [`QpBackend::resolve`]).
    pub fn is_structured(self, n_vars: usize) -> bool {
        match self {
            QpBackend::Dense => false,
            QpBackend::Structured => true,
            QpBackend::Auto => n_vars >= AUTO_STRUCTURED_MIN_VARS,
        }
    }

    /// What `[controller.sqp] qp = self` and `hessian` resolve to for a problem of `n_vars`
    /// decision variables: the scenario tree of the coupled formulation when `tree` (whose
    /// `auto` threshold is `tree_min_vars`, `AUTO_TREE_MIN_VARS`), else one scenario's NMPC
    /// (threshold [`AUTO_STRUCTURED_MIN_VARS`]).
    ///
    /// `qp = "auto"` chooses only the QP back-end: the structured one when the problem has at
    /// least the threshold's variables and the structured back-end runs the Hessian the dense
    /// one would (so `hessian = "structured_secant"`, which only the dense back-end runs, keeps
    /// the dense back-end). `hessian = "auto"` (the default) is the back-end's own model:
    /// `structured_secant` on the dense back-end, `gauss_newton` on the structured one. An
    /// explicit model is run where the back-end has it; the structured back-end runs
    /// `gauss_newton` for `structured_secant`, and the scenario tree (either back-end) runs
    /// `gauss_newton` for `exact` ([`HessianModel::Exact`]); the result names the model run.
    pub fn resolve(
        self,
        hessian: HessianSetting,
        n_vars: usize,
        tree: bool,
        tree_min_vars: usize,
    ) -> SolverChoice {
        let min_vars = if tree {
            tree_min_vars
        } else {
            AUTO_STRUCTURED_MIN_VARS
        };
        let structured = match self {
            QpBackend::Dense => false,
            QpBackend::Structured => true,
            QpBackend::Auto => {
                n_vars >= min_vars
                    && match hessian.model() {
                        None => true,
                        Some(h) => hessian_run(true, tree, h) == hessian_run(false, tree, h),
                    }
            }
        };
        let hessian = match hessian.model() {
            None if structured => HessianModel::GaussNewton,
            None => HessianModel::StructuredSecant,
            Some(h) => hessian_run(structured, tree, h),
        };
        SolverChoice {
            qp: if structured {
                QpBackend::Structured
            } else {
                QpBackend::Dense
            },
            hessian,
        }
    }
}

/// The Hessian model a back-end runs for the requested `h` (see [`QpBackend::resolve`]).
fn hessian_run(structured: bool, tree: bool, h: HessianModel) -> HessianModel {
    match h {
        HessianModel::StructuredSecant if structured => HessianModel::GaussNewton,
        HessianModel::Exact if tree => HessianModel::GaussNewton,
        h => h,
    }
}

/// `[controller.sqp] hessian`: the Hessian model of the QP subproblems, or `"auto"` (the
/// default: the model of the QP back-end `qp` resolves to, [`QpBackend::resolve`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum HessianSetting {
    /// `structured_secant` on the dense back-end, `gauss_newton` on the structured one.
    #[default]
    Auto,
    /// [`HessianModel::StructuredSecant`] (only the dense back-end runs it).
    StructuredSecant,
    /// [`HessianModel::GaussNewton`].
    GaussNewton,
    /// [`HessianModel::Exact`] (the scenario tree runs Gauss–Newton instead).
    Exact,
}

impl HessianSetting {
    /// The explicit model, `None` for `Auto`.
    pub fn model(self) -> Option<HessianModel> {
        match self {
            HessianSetting::Auto => None,
            HessianSetting::StructuredSecant => Some(HessianModel::StructuredSecant),
            HessianSetting::GaussNewton => Some(HessianModel::GaussNewton),
            HessianSetting::Exact => Some(HessianModel::Exact),
        }
    }
}

impl From<HessianModel> for HessianSetting {
    fn from(h: HessianModel) -> Self {
        match h {
            HessianModel::StructuredSecant => HessianSetting::StructuredSecant,
            HessianModel::GaussNewton => HessianSetting::GaussNewton,
            HessianModel::Exact => HessianSetting::Exact,
        }
    }
}

/// The QP back-end and the Hessian model an NMPC's solves run, as resolved from
/// `[controller.sqp] qp` and `hessian` ([`QpBackend::resolve`]); the run summary's `solver`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct SolverChoice {
    /// `dense` or `structured` (for the coupled formulation: the block-arrowhead tree).
    pub qp: QpBackend,
    /// The Hessian model run.
    pub hessian: HessianModel,
}

/// Horizon and weights of eq. 7 (MODEL.md §8).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct NmpcSettings {
    /// Prediction horizon `Np` (steps), default 3.
    pub np: usize,
    /// Control horizon `Nc ≤ Np` (steps), default 3; the torque is held after `Nc`.
    pub nc: usize,
    /// Velocity-tracking weight `r_d`, default 0.1.
    pub r_d: f64,
    /// Torque-increment weight `r_t`, default 1e-5.
    pub r_t: f64,
    /// SQP settings.
    pub sqp: SqpSettings,
    /// QP solver of the SQP (dense condensed or structured Riccati).
    pub qp: QpBackend,
    /// Where the velocity residual is measured: joint space (the paper's eq. 7) or at the
    /// straps ([`VelocityTracking::Strap`]).
    pub velocity_tracking: VelocityTracking,
}

/// Where the velocity-tracking residual `√r_d (qd − qd_ref)` of eq. 7 is measured
/// (`[controller.robust] velocity_tracking`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum VelocityTracking {
    /// Joint space, `√r_d (qd − qd_ref)`: the paper's eq. 7.
    #[default]
    Joint,
    /// At the straps: `√r_d L (qd − qd_ref)` with `L = diag(J)⁻¹ J`, `J` the strap lever
    /// matrix of paper eqs. 3-4 (docs/MODEL.md §4). Row `i` is strap `i`'s stretch rate
    /// `J_i (qd − qd_ref)` in its own link's angle units (`/ J_ii`): the thigh row is the hip's
    /// residual, the shank row `(Ls1/Ls2)·e_hip + e_knee`. Where `qd_ref` can be followed both
    /// measures have the same minimiser; where the hip cannot (its torque on the limit) the
    /// knee then turns so that the shank strap does not carry the hip's lag
    /// (docs/ROBUSTNESS.md, ninth pass). With one joint `L = 1`.
    Strap,
}

/// The velocity-residual metric `L` of `tracking` for strap levers `j` (`N × N`, lower
/// triangular): the identity, or `diag(J)⁻¹ J` ([`VelocityTracking::Strap`]; the identity
/// where a diagonal lever is not positive and finite).
pub fn velocity_metric<const N: usize>(
    tracking: VelocityTracking,
    j: &SMatrix<f64, N, N>,
) -> SMatrix<f64, N, N> {
    match tracking {
        VelocityTracking::Joint => SMatrix::identity(),
        VelocityTracking::Strap => {
            if (0..N).all(|i| j[(i, i)] > 0.0 && j[(i, i)].is_finite()) {
                SMatrix::from_fn(|r, c| j[(r, c)] / j[(r, r)])
            } else {
                SMatrix::identity()
            }
        }
    }
}

impl Default for NmpcSettings {
    fn default() -> Self {
        NmpcSettings {
            np: 3,
            nc: 3,
            r_d: 0.1,
            r_t: 1e-5,
            sqp: SqpSettings::default(),
            qp: QpBackend::default(),
            velocity_tracking: VelocityTracking::default(),
        }
    }
}

/// The least-squares form of eq. 7 for one scenario: decision variables the torque increments
/// `dT(k..k+Nc−1)`, residuals `q(k+j) − q_ref(k+j)`, `√r_d L (qd(k+j) − qd_ref)` for `j = 1..Np`
/// and `√r_t dT(k+j)` for `j = 0..Nc−1`, with `q_ref(k+j) = q̂_H + j dt q̂d_H`, `qd_ref = q̂d_H`
/// (MODEL.md §8). The Jacobian is condensed by forward sensitivity propagation through the exact
/// RK4 step Jacobians, at cost O(Np·Nc).
#[derive(Clone, Debug)]
pub struct NmpcProblem<const N: usize> {
    /// Prediction model.
    pub model: PredictionModel<N>,
    np: usize,
    nc: usize,
    sqrt_rd: f64,
    sqrt_rt: f64,
    /// Initial state `[q, filtered qd]`.
    pub x0: JointState<f64, N>,
    /// Previous torque `T(k−1)`.
    pub t_prev: SVector<f64, N>,
    /// Inputs constant over the horizon.
    pub inputs: HorizonInputs<N>,
    // Sensitivities of the current state w.r.t. each increment block.
    sq: Vec<SMatrix<f64, N, N>>,
    sv: Vec<SMatrix<f64, N, N>>,
    /// Velocity-residual metric `L` ([`velocity_metric`]) and whether it is the identity.
    lv: SMatrix<f64, N, N>,
    lv_identity: bool,
    // Workspace of the exact Hessian's second-order term.
    curvature: CurvatureWork<N>,
}

impl<const N: usize> NmpcProblem<N> {
    /// A problem for `model` with the horizon and weights of `s`.
    pub fn new(model: PredictionModel<N>, s: &NmpcSettings) -> Self {
        let lv = velocity_metric(s.velocity_tracking, &model.straps.j);
        NmpcProblem {
            model,
            np: s.np,
            nc: s.nc,
            sqrt_rd: s.r_d.sqrt(),
            sqrt_rt: s.r_t.sqrt(),
            x0: JointState {
                q: SVector::zeros(),
                qd: SVector::zeros(),
            },
            t_prev: SVector::zeros(),
            inputs: HorizonInputs {
                q_h: SVector::zeros(),
                qd_h: SVector::zeros(),
                t_int_measured: SVector::zeros(),
                disturbance: SVector::zeros(),
            },
            sq: vec![SMatrix::zeros(); s.nc],
            sv: vec![SMatrix::zeros(); s.nc],
            lv,
            lv_identity: lv == SMatrix::<f64, N, N>::identity(),
            curvature: CurvatureWork::new(s.np, s.nc),
        }
    }

    /// Prediction horizon.
    pub fn np(&self) -> usize {
        self.np
    }

    /// Control horizon.
    pub fn nc(&self) -> usize {
        self.nc
    }

    /// The velocity-residual metric `L`: the residual is `√r_d L (qd − qd_ref)`
    /// ([`VelocityTracking`]).
    pub fn velocity_metric(&self) -> &SMatrix<f64, N, N> {
        &self.lv
    }

    /// The velocity residual `r_v = √r_d L (qd − qd_ref)` at the predicted velocity `qd` for
    /// the weight `sqrt_rd`, and `Lᵀ r_v` (the cost gradient's velocity part is `√r_d Lᵀ r_v`);
    /// with `L = I` exactly the paper's `√r_d (qd_a − qd_ref,a)` and `r_v` itself.
    #[inline]
    pub(crate) fn velocity_residual(
        &self,
        qd: &SVector<f64, N>,
        sqrt_rd: f64,
    ) -> (SVector<f64, N>, SVector<f64, N>) {
        let e = qd - self.inputs.qd_h;
        if self.lv_identity {
            let rv = e * sqrt_rd;
            (rv, rv)
        } else {
            let rv = self.lv * e * sqrt_rd;
            (rv, self.lv.tr_mul(&rv))
        }
    }

    /// Torque applied over step `j` of the horizon: `T(k−1) + Σ_{i ≤ min(j, Nc−1)} dT(k+i)`.
    #[inline]
    fn torque(&self, z: &[f64], j: usize, acc: &mut SVector<f64, N>) {
        if j < self.nc {
            for a in 0..N {
                acc[a] += z[j * N + a];
            }
        }
    }

    #[inline]
    fn write_step_residuals(&self, j: usize, x: &JointState<f64, N>, r: &mut [f64]) {
        let inp = &self.inputs;
        let base = (j - 1) * 2 * N;
        let tj = j as f64 * self.model.dt;
        let (rv, _) = self.velocity_residual(&x.qd, self.sqrt_rd);
        for a in 0..N {
            r[base + a] = x.q[a] - (inp.q_h[a] + tj * inp.qd_h[a]);
            r[base + N + a] = rv[a];
        }
    }

    fn write_increment_residuals(&self, z: &[f64], r: &mut [f64]) {
        let base = self.np * 2 * N;
        for (ri, zi) in r[base..base + self.nc * N].iter_mut().zip(z) {
            *ri = self.sqrt_rt * zi;
        }
    }

    /// The predicted trajectory `(q, qd)` for `j = 1..Np` and the torques for `j = 0..Np−1`.
    pub fn predict(&self, z: &[f64]) -> (Vec<JointState<f64, N>>, Vec<SVector<f64, N>>) {
        let mut x = self.x0;
        let mut u = self.t_prev;
        let mut xs = Vec::with_capacity(self.np);
        let mut us = Vec::with_capacity(self.np);
        for j in 0..self.np {
            self.torque(z, j, &mut u);
            x = self
                .model
                .step(&x, &u, j as f64 * self.model.dt, &self.inputs);
            xs.push(x);
            us.push(u);
        }
        (xs, us)
    }

    /// Constraints of eqs. 8-9 for previous torque `t_prev`: `|dT| ≤ ΔT_max` (box) and
    /// `−T_max − T(k−1) ≤ Σ_{i≤j} dT(k+i) ≤ T_max − T(k−1)` (cumulative rows), written into `c`.
    pub fn write_constraints(&self, limits: &TorqueLimits, c: &mut Constraints) {
        let nc = self.nc;
        c.zl.fill(-limits.rate);
        c.zu.fill(limits.rate);
        c.a.fill(0.0);
        for j in 0..nc {
            for a in 0..N {
                let row = j * N + a;
                for i in 0..=j {
                    c.a[(row, i * N + a)] = 1.0;
                }
                c.bl[row] = -limits.max - self.t_prev[a];
                c.bu[row] = limits.max - self.t_prev[a];
            }
        }
    }

    /// Number of decision variables `N·Nc`.
    pub fn num_decisions(&self) -> usize {
        N * self.nc
    }
}

impl<const N: usize> LeastSquares for NmpcProblem<N> {
    fn num_vars(&self) -> usize {
        N * self.nc
    }

    fn num_residuals(&self) -> usize {
        2 * N * self.np + N * self.nc
    }

    fn residuals(&mut self, z: &[f64], r: &mut [f64]) -> bool {
        let mut x = self.x0;
        let mut u = self.t_prev;
        let consts = self.model.jacobian_constants();
        for j in 0..self.np {
            self.torque(z, j, &mut u);
            x = self.model.step_value_using(
                &consts,
                &x,
                &u,
                j as f64 * self.model.dt,
                &self.inputs,
            );
            self.write_step_residuals(j + 1, &x, r);
        }
        self.write_increment_residuals(z, r);
        r.iter().all(|v| v.is_finite())
    }

    fn residuals_jacobian(&mut self, z: &[f64], r: &mut [f64], jac: &mut DMatrix<f64>) -> bool {
        let (np, nc) = (self.np, self.nc);
        let m = jac.nrows();
        // Column-major storage: entry (row, col) at col * m + row. Every entry is written below
        // (the zero blocks above the block diagonal explicitly), so no fill is needed.
        let js = jac.as_mut_slice();
        let mut x = self.x0;
        let mut u = self.t_prev;
        // Finiteness of everything written, checked once at the end.
        let mut finite = SMatrix::<f64, N, N>::zeros();
        let consts = self.model.jacobian_constants();
        for j in 0..np {
            self.torque(z, j, &mut u);
            let (xn, g): (JointState<f64, N>, StepJacobian<N>) = self
                .model
                .tailored(&consts, &self.inputs, &u)
                .step_with_jacobian(&x, j as f64 * self.model.dt);
            // S_{j+1}[i] = Φ S_j[i] + Γ for every block i ≤ min(j, Nc−1); S_j[j] = 0 on entry.
            let active = j.min(nc - 1);
            let row = j * 2 * N;
            for i in 0..=active {
                let (sq, sv) = if i == j {
                    (g.qu, g.vu)
                } else {
                    let (sq, sv) = (self.sq[i], self.sv[i]);
                    (g.qq * sq + g.qv * sv + g.qu, g.vq * sq + g.vv * sv + g.vu)
                };
                self.sq[i] = sq;
                self.sv[i] = sv;
                finite += sq + sv;
                let sv = if self.lv_identity { sv } else { self.lv * sv };
                for b in 0..N {
                    let col = &mut js[(i * N + b) * m + row..(i * N + b) * m + row + 2 * N];
                    for a in 0..N {
                        col[a] = sq[(a, b)];
                        col[N + a] = self.sqrt_rd * sv[(a, b)];
                    }
                }
            }
            for c in (active + 1) * N..nc * N {
                js[c * m + row..c * m + row + 2 * N].fill(0.0);
            }
            x = xn;
            self.write_step_residuals(j + 1, &x, r);
        }
        self.write_increment_residuals(z, r);
        let base = np * 2 * N;
        for k in 0..nc * N {
            let col = &mut js[k * m + base..(k + 1) * m];
            col.fill(0.0);
            col[k] = self.sqrt_rt;
        }
        r.iter().all(|v| v.is_finite()) && finite.iter().all(|v| v.is_finite())
    }

    /// `Σ_j Γ_jᵀ W_j Γ_j` with the exact stage blocks `W_j` of `control::hessian` and the state
    /// sensitivities `Γ_j` (the second-order term of the exact Hessian).
    fn add_residual_curvature(&mut self, z: &[f64], r: &[f64], hess: &mut DMatrix<f64>) -> bool {
        self.curvature.add_condensed(
            &self.model,
            &self.x0,
            &self.t_prev,
            &self.inputs,
            self.sqrt_rd,
            &self.lv,
            z,
            r,
            hess,
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `qp = "auto"` chooses only the back-end: it never makes the solve run another Hessian
    /// than the dense back-end would for the same `hessian`; `hessian = "auto"` follows the
    /// back-end chosen.
    #[test]
    fn auto_qp_chooses_the_back_end_only() {
        use HessianModel as H;
        use HessianSetting as S;
        use QpBackend::{Auto, Dense, Structured};
        let (small, big) = (6, 18);
        // (qp, hessian, n_vars, tree) → (back-end, Hessian run)
        let cases = [
            (Auto, S::Auto, small, false, Dense, H::StructuredSecant),
            (Auto, S::Auto, big, false, Structured, H::GaussNewton),
            (
                Auto,
                S::StructuredSecant,
                big,
                false,
                Dense,
                H::StructuredSecant,
            ),
            (Auto, S::GaussNewton, big, false, Structured, H::GaussNewton),
            (Auto, S::GaussNewton, small, false, Dense, H::GaussNewton),
            (Auto, S::Exact, big, false, Structured, H::Exact),
            (Auto, S::Exact, big, true, Structured, H::GaussNewton),
            (Auto, S::Exact, small, true, Dense, H::GaussNewton),
            (
                Auto,
                S::StructuredSecant,
                big,
                true,
                Dense,
                H::StructuredSecant,
            ),
            (Auto, S::Auto, big, true, Structured, H::GaussNewton),
            (Dense, S::Auto, big, false, Dense, H::StructuredSecant),
            (
                Structured,
                S::Auto,
                small,
                false,
                Structured,
                H::GaussNewton,
            ),
            (
                Structured,
                S::StructuredSecant,
                small,
                false,
                Structured,
                H::GaussNewton,
            ),
            (Dense, S::Exact, small, false, Dense, H::Exact),
        ];
        for (qp, h, n, tree, want_qp, want_h) in cases {
            let c = qp.resolve(h, n, tree, 16);
            assert_eq!(
                (c.qp, c.hessian),
                (want_qp, want_h),
                "{qp:?} {h:?} n {n} tree {tree}"
            );
            // The size rule of `is_structured` where the Hessian does not object.
            if qp != Auto || h == S::Auto || h == S::GaussNewton {
                assert_eq!(c.qp == Structured, qp.is_structured(n), "{qp:?} {h:?} {n}");
            }
        }
    }
}
