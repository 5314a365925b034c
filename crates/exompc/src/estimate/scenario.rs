//! One payload scenario: EKF on `[q, qd, d]` with an RK4 robot model and exact Jacobians.

use super::{
    Ekf, EkfError, EkfSettings, EstimateError, EstimatorOptions, Innovation, InnovationStats,
};
use crate::model::{
    rk4_step, ChainConstants, HeldTorque, JointState, Real, RobotModel, TailoredRk4,
};
#[cfg(feature = "std")]
use nalgebra::{Const, U1};
use nalgebra::{SMatrix, SVector};
#[cfg(feature = "std")]
use num_dual::DualSVec64;

/// Result of one [`ScenarioEkf::step`]: the innovation entering paper eq. 10 (standard or paper
/// form, see [`Innovation`]) or the reason the step failed, in which case the filter is unchanged.
pub type ScenarioUpdate<const NY: usize> = Result<InnovationStats<NY>, EkfError>;

/// The EKF of one payload scenario (paper §3.2, MODEL.md §8).
///
/// Augmented state `x = [q, qd, d] ∈ ℝ^{3N}` (`NA = 3N`), measurement `y = [q, qd] ∈ ℝ^{2N}`
/// (`NY = 2N`, linear: `H = [I 0]`).
///
/// **Process model.** Over one period `dt` the robot model
/// `qdd = M(q)⁻¹ (T_R(k−1) + T_int(k−1) + d − C(q, qd) qd − G(q) − friction(qd))`
/// is integrated by `substeps` RK4 steps with the applied torque `T_R(k−1)`, the filtered strap
/// torque `T_int(k−1) = Jᵀ F(k−1)` and the disturbance `d` held, and `d` is a random walk
/// (`d(k) = d(k−1) + w`). The model should use the smooth `tanh` Coulomb law (MODEL.md §3) so that
/// its Jacobian is meaningful.
///
/// **Jacobian.** `F = ∂x(k|k−1)/∂x(k−1|k−1)` is exact: the hand-derived RK4 sensitivity of the
/// robot model that the NMPC prediction uses ([`crate::model::StepJacobian`]; per stage the
/// analytic derivatives of `qdd`, chained through the stages), with `∂/∂d = ∂/∂T_R` since `d`
/// enters like the torque, and `[0 0 I]` rows for the random walk. It equals forward-mode
/// dual numbers through the generic RK4 (`predict_with_jacobian_dual`, the tests' oracle) to
/// rounding at about a tenth of the cost. (The `tanh` friction's derivative uses the
/// overflow-safe [`crate::model::tanh`], so the Jacobian stays finite at any joint speed.)
///
/// **Step** ([`ScenarioEkf::step`]): `x̂(k|k−1) = f(x̂(k−1|k−1))`, `P = F P Fᵀ + Q`, then the
/// standard EKF update with `v = y(k) − H x̂(k|k−1)` (see [`Ekf`]).
#[derive(Clone, Copy, Debug)]
pub struct ScenarioEkf<const N: usize, const NA: usize, const NY: usize> {
    model: RobotModel<N>,
    consts: ChainConstants<N>,
    dt: f64,
    substeps: usize,
    mode: Innovation,
    ekf: Ekf<NA, NY>,
    h: SMatrix<f64, NY, NA>,
    x0: SVector<f64, NA>,
    p0: SMatrix<f64, NA, NA>,
    residual: SVector<f64, NY>,
    last: Option<InnovationStats<NY>>,
}

/// `substeps` RK4 steps of the robot model over `dt` with the net external torque
/// `tau = u + t_int + d` held.
#[inline]
fn propagate<T: Real, const N: usize>(
    model: &RobotModel<N>,
    dt: f64,
    substeps: usize,
    x: JointState<T, N>,
    tau: &SVector<T, N>,
) -> JointState<T, N> {
    let h = dt / substeps as f64;
    let mut s = x;
    for i in 0..substeps {
        s = rk4_step(
            |_, s: &JointState<T, N>| JointState {
                q: s.qd,
                qd: model.acceleration(&s.q, &s.qd, tau),
            },
            i as f64 * h,
            &s,
            h,
        );
    }
    s
}

impl<const N: usize, const NA: usize, const NY: usize> ScenarioEkf<N, NA, NY> {
    /// A filter for the scenario `model` (payload already merged into its links), starting at
    /// `[q0, qd0, d = 0]` with `P0`, `Q`, `R` from `settings`; `options` gives `dt`, the RK4
    /// `substeps` and the innovation mode (`c1` and `floor` are not used here).
    ///
    /// `NA = 3N` and `NY = 2N` are checked at compile time.
    pub fn new(
        model: RobotModel<N>,
        settings: &EkfSettings,
        options: &EstimatorOptions,
        q0: &SVector<f64, N>,
        qd0: &SVector<f64, N>,
    ) -> Result<Self, EstimateError> {
        const { assert!(NA == 3 * N && NY == 2 * N) }
        settings.validate()?;
        options.validate(1)?;
        let x0 = Self::augmented(q0, qd0);
        let p0 = settings.initial_covariance::<NA>();
        let ekf = Ekf::new(
            x0,
            p0,
            settings.process_noise::<NA>(),
            settings.measurement_noise::<NY>(),
        );
        let h = SMatrix::<f64, NY, NA>::from_fn(|r, c| if r == c { 1.0 } else { 0.0 });
        Ok(Self {
            consts: ChainConstants::new(&model),
            model,
            dt: options.dt,
            substeps: options.substeps,
            mode: options.innovation,
            ekf,
            h,
            x0,
            p0,
            residual: SVector::zeros(),
            last: None,
        })
    }

    fn augmented(q: &SVector<f64, N>, qd: &SVector<f64, N>) -> SVector<f64, NA> {
        let mut x = SVector::<f64, NA>::zeros();
        for i in 0..N {
            x[i] = q[i];
            x[N + i] = qd[i];
        }
        x
    }

    /// Back to the initial state `[q0, qd0, 0]` and `P0`; forgets the last innovation.
    pub fn reset(&mut self) {
        self.ekf.set(self.x0, self.p0);
        self.residual = SVector::zeros();
        self.last = None;
    }

    /// Restart from `[q, qd, 0]` with `P0` (and make that the state [`reset`](Self::reset)
    /// returns to).
    pub fn reset_to(&mut self, q: &SVector<f64, N>, qd: &SVector<f64, N>) {
        self.x0 = Self::augmented(q, qd);
        self.reset();
    }

    /// Resume after a gap in the data (periods without a usable measurement): restart the
    /// joint states from the measured `[q, qd]` with their `P0` block, keeping the disturbance
    /// estimate and its covariance, with no update (predicting one period across a longer gap
    /// would produce a spurious innovation).
    pub fn resume_at(&mut self, q: &SVector<f64, N>, qd: &SVector<f64, N>) {
        let (x_now, p_now) = (*self.ekf.state(), *self.ekf.covariance());
        let mut x = Self::augmented(q, qd);
        let mut p = self.p0;
        for i in 2 * N..NA {
            x[i] = x_now[i];
            for j in 2 * N..NA {
                p[(i, j)] = p_now[(i, j)];
            }
        }
        self.ekf.set(x, p);
        self.residual = SVector::zeros();
        self.last = None;
    }

    /// Overwrite the disturbance estimate `d̂` (N·m), keeping the joint states and the
    /// covariance: `d̂` carried by the gait while its measurement input (the strap force) is
    /// an estimate (`control/multistage.rs`). A non-finite `d` is ignored.
    pub fn set_disturbance(&mut self, d: &SVector<f64, N>) {
        if !d.iter().all(|v| v.is_finite()) {
            return;
        }
        let mut x = *self.ekf.state();
        for i in 0..N {
            x[2 * N + i] = d[i];
        }
        let p = *self.ekf.covariance();
        self.ekf.set(x, p);
    }

    /// The scenario's robot model.
    pub fn model(&self) -> &RobotModel<N> {
        &self.model
    }

    /// The underlying filter.
    pub fn ekf(&self) -> &Ekf<NA, NY> {
        &self.ekf
    }

    /// Augmented state estimate `x̂ = [q̂, q̂d, d̂]`.
    pub fn state(&self) -> &SVector<f64, NA> {
        self.ekf.state()
    }

    /// Covariance of the augmented state.
    pub fn covariance(&self) -> &SMatrix<f64, NA, NA> {
        self.ekf.covariance()
    }

    /// Joint angle estimate `q̂`.
    pub fn angles(&self) -> SVector<f64, N> {
        SVector::from_fn(|i, _| self.ekf.state()[i])
    }

    /// Joint velocity estimate `q̂d`.
    pub fn velocities(&self) -> SVector<f64, N> {
        SVector::from_fn(|i, _| self.ekf.state()[N + i])
    }

    /// Lumped joint torque disturbance estimate `d̂` (N·m), added to the model's right-hand side.
    pub fn disturbance(&self) -> SVector<f64, N> {
        SVector::from_fn(|i, _| self.ekf.state()[2 * N + i])
    }

    /// Innovation (as used for eq. 10) of the last successful step, if any since the (re)start.
    pub fn last_innovation(&self) -> Option<&InnovationStats<NY>> {
        self.last.as_ref()
    }

    /// The innovation mode.
    pub fn innovation_mode(&self) -> Innovation {
        self.mode
    }

    /// The process model `f`: the augmented state one period after `x` under the applied torque
    /// `u` and strap torque `t_int` (both held), `d` unchanged.
    pub fn predict(
        &self,
        x: &SVector<f64, NA>,
        u: &SVector<f64, N>,
        t_int: &SVector<f64, N>,
    ) -> SVector<f64, NA> {
        let s = JointState {
            q: SVector::<f64, N>::from_fn(|i, _| x[i]),
            qd: SVector::<f64, N>::from_fn(|i, _| x[N + i]),
        };
        let tau = SVector::<f64, N>::from_fn(|i, _| u[i] + t_int[i] + x[2 * N + i]);
        let out = propagate(&self.model, self.dt, self.substeps, s, &tau);
        let mut xn = *x;
        for i in 0..N {
            xn[i] = out.q[i];
            xn[N + i] = out.qd[i];
        }
        xn
    }

    /// [`predict`](Self::predict) (to rounding) together with its exact Jacobian `F = ∂f/∂x`,
    /// hand-derived: the RK4 sensitivity of the robot model ([`crate::model::StepJacobian`],
    /// the tailored Jacobian of the NMPC prediction model with the strap torque held), with
    /// `∂/∂d = ∂/∂u` (the disturbance enters like the torque) and the random walk's `[0 0 I]`
    /// rows: `F = [[∂q⁺/∂q, ∂q⁺/∂qd, ∂q⁺/∂u], [∂qd⁺/∂q, ∂qd⁺/∂qd, ∂qd⁺/∂u], [0, 0, I]]`.
    /// Equals [`predict_with_jacobian_dual`](Self::predict_with_jacobian_dual) to rounding
    /// (crates/exompc/tests/estimate.rs).
    pub fn predict_with_jacobian(
        &self,
        x: &SVector<f64, NA>,
        u: &SVector<f64, N>,
        t_int: &SVector<f64, N>,
    ) -> (SVector<f64, NA>, SMatrix<f64, NA, NA>) {
        let s = JointState {
            q: SVector::<f64, N>::from_fn(|i, _| x[i]),
            qd: SVector::<f64, N>::from_fn(|i, _| x[N + i]),
        };
        let d = SVector::<f64, N>::from_fn(|i, _| x[2 * N + i]);
        let (out, j) = TailoredRk4 {
            robot: &self.model,
            consts: &self.consts,
            input: u,
            disturbance: &d,
            torque: HeldTorque(*t_int),
            dt: self.dt,
            substeps: self.substeps,
        }
        .step_with_jacobian(&s, 0.0);
        let mut xn = *x;
        let mut f = SMatrix::<f64, NA, NA>::zeros();
        for i in 0..N {
            xn[i] = out.q[i];
            xn[N + i] = out.qd[i];
            for c in 0..N {
                f[(i, c)] = j.qq[(i, c)];
                f[(i, N + c)] = j.qv[(i, c)];
                f[(i, 2 * N + c)] = j.qu[(i, c)];
                f[(N + i, c)] = j.vq[(i, c)];
                f[(N + i, N + c)] = j.vv[(i, c)];
                f[(N + i, 2 * N + c)] = j.vu[(i, c)];
            }
            f[(2 * N + i, 2 * N + i)] = 1.0;
        }
        (xn, f)
    }

    /// [`predict`](Self::predict) together with its exact Jacobian `F = ∂f/∂x` by one
    /// forward-mode dual-number pass seeded on all `NA` state components: the reference for
    /// [`predict_with_jacobian`](Self::predict_with_jacobian) (same values to rounding), about
    /// ten times slower. A test oracle, hidden from the docs.
    #[doc(hidden)]
    #[cfg(feature = "std")]
    pub fn predict_with_jacobian_dual(
        &self,
        x: &SVector<f64, NA>,
        u: &SVector<f64, N>,
        t_int: &SVector<f64, N>,
    ) -> (SVector<f64, NA>, SMatrix<f64, NA, NA>) {
        type D<const K: usize> = DualSVec64<K>;
        let seed = |k: usize| D::<NA>::from_re(x[k]).derivative(k);
        let s = JointState {
            q: SVector::<D<NA>, N>::from_fn(|i, _| seed(i)),
            qd: SVector::<D<NA>, N>::from_fn(|i, _| seed(N + i)),
        };
        let tau = SVector::<D<NA>, N>::from_fn(|i, _| seed(2 * N + i) + (u[i] + t_int[i]));
        let out = propagate(&self.model, self.dt, self.substeps, s, &tau);
        let mut xn = *x;
        let mut f = SMatrix::<f64, NA, NA>::zeros();
        for i in 0..N {
            xn[i] = out.q[i].re;
            xn[N + i] = out.qd[i].re;
            let gq = out.q[i].eps.unwrap_generic(Const::<NA>, U1);
            let gqd = out.qd[i].eps.unwrap_generic(Const::<NA>, U1);
            for c in 0..NA {
                f[(i, c)] = gq[c];
                f[(N + i, c)] = gqd[c];
            }
            f[(2 * N + i, 2 * N + i)] = 1.0;
        }
        (xn, f)
    }

    /// One filter period when some measured channels are missing (a sensor fault): the time
    /// update of [`step`](Self::step), then the measurement update with the rows of `y` whose
    /// `measured` entry is true only (the other rows of `H` zeroed, their innovation 0, so they
    /// move neither `x̂` nor `P`); with no row measured, the time update alone. With
    /// `hold_disturbance` the disturbance `d` is held: the caller sets `d̂`
    /// ([`set_disturbance`](Self::set_disturbance)), the update leaves it out
    /// ([`Ekf::update_holding`]) and its random walk is paused ([`Ekf::predict_holding`]), so
    /// the joint states follow the measured rows and `d`'s variance stays where it was. The
    /// innovation statistics of the last full update are kept (they weigh the scenarios'
    /// probabilities, which the caller keeps through a fault). On failure the filter is left as
    /// it was.
    pub fn step_masked(
        &mut self,
        y: &SVector<f64, NY>,
        measured: &[bool; NY],
        hold_disturbance: bool,
        u_prev: &SVector<f64, N>,
        t_int_prev: &SVector<f64, N>,
    ) -> Result<(), EkfError> {
        let (xp, f) = self.predict_with_jacobian(self.ekf.state(), u_prev, t_int_prev);
        let mut held = [false; NA];
        if hold_disturbance {
            held[2 * N..].fill(true);
        }
        let mut ekf = self.ekf;
        ekf.predict_holding(&xp, &f, &held)?;
        if measured.iter().any(|&m| m) {
            let mut h = self.h;
            let mut ym = SVector::<f64, NY>::zeros();
            for r in 0..NY {
                if measured[r] {
                    ym[r] = y[r];
                } else {
                    h.row_mut(r).fill(0.0);
                }
            }
            let y_pred = h * ekf.state();
            ekf.update_holding(&ym, &y_pred, &h, &held)?;
        }
        self.ekf = ekf;
        if measured.iter().all(|&m| m) {
            // The a-posteriori residual of a full update (the paper innovation's `e(k−1)`).
            self.residual = y - self.h * self.ekf.state();
        }
        Ok(())
    }

    /// One filter period: `y = [q, qd]` measured at step `k`, `u_prev = T_R(k−1)`,
    /// `t_int_prev = Jᵀ F` (filtered) of step `k−1`.
    ///
    /// Predicts `x̂(k|k−1)` and `P` through [`predict_with_jacobian`](Self::predict_with_jacobian),
    /// then updates with `H = [I 0]`. Returns the innovation for paper eq. 10 —
    /// [`Innovation::Standard`]: `v = y(k) − H x̂(k|k−1)`; [`Innovation::Paper`]:
    /// `v = y(k) − (H x̂(k|k−1) + e(k−1))`, `e(k−1) = y(k−1) − H x̂(k−1|k−1)` — with the
    /// standard `S`. On any failure (non-finite input, non-positive-definite `S`, non-finite
    /// result) the filter is left exactly as before the call and the error is returned.
    pub fn step(
        &mut self,
        y: &SVector<f64, NY>,
        u_prev: &SVector<f64, N>,
        t_int_prev: &SVector<f64, N>,
    ) -> ScenarioUpdate<NY> {
        if !y.iter().all(|v| v.is_finite()) {
            return Err(EkfError::NonFiniteInput);
        }
        let (xp, f) = self.predict_with_jacobian(self.ekf.state(), u_prev, t_int_prev);
        let mut ekf = self.ekf;
        ekf.predict(&xp, &f)?;
        let y_pred = self.h * ekf.state();
        let stats = ekf.update(y, &y_pred, &self.h)?;
        let residual = y - self.h * ekf.state();
        let out = match self.mode {
            Innovation::Standard => stats,
            Innovation::Paper => stats.with_innovation(stats.v - self.residual),
        };
        if out.mahalanobis.is_nan() {
            return Err(EkfError::NonFiniteResult);
        }
        self.ekf = ekf;
        self.residual = residual;
        self.last = Some(out);
        Ok(out)
    }
}
