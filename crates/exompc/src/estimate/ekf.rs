//! A generic extended Kalman filter on fixed-size nalgebra types.

#[cfg(not(feature = "std"))]
use crate::math::Float;
use nalgebra::{Cholesky, SMatrix, SVector};

/// Why an [`Ekf`] step was rejected. The filter is left exactly as it was.
#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
pub enum EkfError {
    /// A measurement, predicted measurement, propagated state or Jacobian is NaN or infinite.
    #[error("non-finite input to the Kalman filter")]
    NonFiniteInput,
    /// The innovation covariance `S = H P Hᵀ + R` is not (numerically) positive definite.
    #[error("innovation covariance is not positive definite")]
    SingularInnovation,
    /// The step would have produced a non-finite state or covariance.
    #[error("Kalman filter step produced non-finite values")]
    NonFiniteResult,
}

/// Innovation of one measurement update: `v = y − ŷ`, `S = H P⁻ Hᵀ + R`, and the derived
/// quantities the scenario probabilities need (paper eq. 10).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct InnovationStats<const NY: usize> {
    /// Innovation `v = y − ŷ`.
    pub v: SVector<f64, NY>,
    /// Innovation covariance `S = H P⁻ Hᵀ + R` (symmetric positive definite).
    pub s: SMatrix<f64, NY, NY>,
    /// `S⁻¹` (from the Cholesky factor of `S`).
    pub s_inv: SMatrix<f64, NY, NY>,
    /// `ln |S|`.
    pub log_det_s: f64,
    /// Squared Mahalanobis distance `vᵀ S⁻¹ v` (may be `+∞` for an astronomically large `v`).
    pub mahalanobis: f64,
}

impl<const NY: usize> InnovationStats<NY> {
    /// The same covariance with another innovation vector `v` (Mahalanobis distance recomputed).
    pub fn with_innovation(&self, v: SVector<f64, NY>) -> Self {
        let mahalanobis = v.dot(&(self.s_inv * v));
        Self {
            v,
            mahalanobis,
            ..*self
        }
    }

    /// Log of the scaled Gaussian likelihood of paper eq. 10,
    /// `ln[ exp(−½ c1 vᵀ S⁻¹ v) / sqrt((2π)^ny |c1 S|) ]
    ///  = −½ c1 vᵀ S⁻¹ v − ½ (ny ln 2π + ny ln c1 + ln |S|)`.
    ///
    /// Finite whenever the stats came from a successful update and `c1 > 0`, except that it is
    /// `−∞` for an astronomically large innovation (which [`update_probabilities`] handles).
    ///
    /// [`update_probabilities`]: super::update_probabilities
    pub fn log_likelihood(&self, c1: f64) -> f64 {
        let ny = NY as f64;
        -0.5 * c1 * self.mahalanobis.abs()
            - 0.5 * (ny * (2.0 * core::f64::consts::PI).ln() + ny * c1.ln() + self.log_det_s)
    }
}

/// Extended Kalman filter with state `x ∈ ℝ^NX`, covariance `P`, process noise `Q` and
/// measurement noise `R ∈ ℝ^{NY×NY}`; fixed-size, allocation-free, panic-free.
///
/// The model is supplied by the caller at each step:
///
/// * prediction ([`Ekf::predict`]): `x⁻ = f(x⁺)`, `P⁻ = F P⁺ Fᵀ + Q` with `F = ∂f/∂x`;
/// * update ([`Ekf::update`]) with the predicted measurement `ŷ` and `H = ∂h/∂x`:
///   `v = y − ŷ`, `S = H P⁻ Hᵀ + R`, `K = P⁻ Hᵀ S⁻¹`, `x⁺ = x⁻ + K v`, and the Joseph form
///   `P⁺ = (I − K H) P⁻ (I − K H)ᵀ + K R Kᵀ`, which stays symmetric positive semi-definite under
///   round-off (the result is explicitly symmetrised as well).
///
/// A step with non-finite inputs, a non-positive-definite `S` or non-finite results returns an
/// [`EkfError`] and leaves the filter unchanged.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Ekf<const NX: usize, const NY: usize> {
    x: SVector<f64, NX>,
    p: SMatrix<f64, NX, NX>,
    q: SMatrix<f64, NX, NX>,
    r: SMatrix<f64, NY, NY>,
}

fn finite<const R: usize, const C: usize>(m: &SMatrix<f64, R, C>) -> bool {
    m.iter().all(|v| v.is_finite())
}

fn symmetrise<const D: usize>(m: &SMatrix<f64, D, D>) -> SMatrix<f64, D, D> {
    (m + m.transpose()) * 0.5
}

impl<const NX: usize, const NY: usize> Ekf<NX, NY> {
    /// A filter at `x0` with covariance `p0`, process noise `q` and measurement noise `r`
    /// (all symmetrised).
    pub fn new(
        x0: SVector<f64, NX>,
        p0: SMatrix<f64, NX, NX>,
        q: SMatrix<f64, NX, NX>,
        r: SMatrix<f64, NY, NY>,
    ) -> Self {
        Self {
            x: x0,
            p: symmetrise(&p0),
            q: symmetrise(&q),
            r: symmetrise(&r),
        }
    }

    /// State estimate `x̂`.
    pub fn state(&self) -> &SVector<f64, NX> {
        &self.x
    }

    /// Covariance `P`.
    pub fn covariance(&self) -> &SMatrix<f64, NX, NX> {
        &self.p
    }

    /// Process noise `Q`.
    pub fn process_noise(&self) -> &SMatrix<f64, NX, NX> {
        &self.q
    }

    /// Measurement noise `R`.
    pub fn measurement_noise(&self) -> &SMatrix<f64, NY, NY> {
        &self.r
    }

    /// Overwrite the state estimate and covariance (e.g. for a reset).
    pub fn set(&mut self, x: SVector<f64, NX>, p: SMatrix<f64, NX, NX>) {
        self.x = x;
        self.p = symmetrise(&p);
    }

    /// Time update with the caller's propagated state `x_next = f(x̂)` and Jacobian
    /// `f_jac = F = ∂f/∂x` at `x̂`: `x̂ ← x_next`, `P ← F P Fᵀ + Q` (symmetrised).
    pub fn predict(
        &mut self,
        x_next: &SVector<f64, NX>,
        f_jac: &SMatrix<f64, NX, NX>,
    ) -> Result<(), EkfError> {
        self.predict_holding(x_next, f_jac, &[false; NX])
    }

    /// [`predict`](Self::predict) with the process noise of the states whose `held` entry is
    /// true left out (their rows and columns of `Q` taken as zero): a state the caller sets
    /// from outside the filter, whose uncertainty should not grow meanwhile.
    pub fn predict_holding(
        &mut self,
        x_next: &SVector<f64, NX>,
        f_jac: &SMatrix<f64, NX, NX>,
        held: &[bool; NX],
    ) -> Result<(), EkfError> {
        if !finite(x_next) || !finite(f_jac) {
            return Err(EkfError::NonFiniteInput);
        }
        let fpf = f_jac * self.p * f_jac.transpose();
        let p = if held.iter().any(|&h| h) {
            let q = SMatrix::<f64, NX, NX>::from_fn(|i, j| {
                if held[i] || held[j] {
                    0.0
                } else {
                    self.q[(i, j)]
                }
            });
            symmetrise(&(fpf + q))
        } else {
            symmetrise(&(fpf + self.q))
        };
        if !finite(&p) {
            return Err(EkfError::NonFiniteResult);
        }
        self.x = *x_next;
        self.p = p;
        Ok(())
    }

    /// The innovation `v = y − ŷ`, `S = H P Hᵀ + R` at the current (predicted) estimate, without
    /// changing the filter. Also returns the Kalman gain `K = P Hᵀ S⁻¹`.
    pub fn innovation(
        &self,
        y: &SVector<f64, NY>,
        y_pred: &SVector<f64, NY>,
        h_jac: &SMatrix<f64, NY, NX>,
    ) -> Result<(InnovationStats<NY>, SMatrix<f64, NX, NY>), EkfError> {
        if !finite(y) || !finite(y_pred) || !finite(h_jac) {
            return Err(EkfError::NonFiniteInput);
        }
        let v = y - y_pred;
        let pht = self.p * h_jac.transpose();
        let s = symmetrise(&(h_jac * pht + self.r));
        if !finite(&s) || !finite(&v) {
            return Err(EkfError::NonFiniteResult);
        }
        let chol = Cholesky::new(s).ok_or(EkfError::SingularInnovation)?;
        let l = chol.l_dirty();
        let mut log_det_s = 0.0;
        for i in 0..NY {
            let d = l[(i, i)];
            if !(d.is_finite() && d > 0.0) {
                return Err(EkfError::SingularInnovation);
            }
            log_det_s += 2.0 * d.ln();
        }
        let s_inv = symmetrise(&chol.inverse());
        let mahalanobis = v.dot(&chol.solve(&v));
        // K = P Hᵀ S⁻¹  ⇔  S Kᵀ = H P (S symmetric).
        let k = chol.solve(&pht.transpose()).transpose();
        if !finite(&s_inv) || !finite(&k) || mahalanobis.is_nan() {
            return Err(EkfError::SingularInnovation);
        }
        Ok((
            InnovationStats {
                v,
                s,
                s_inv,
                log_det_s,
                mahalanobis,
            },
            k,
        ))
    }

    /// Measurement update with the measurement `y`, the predicted measurement `y_pred = ŷ` and
    /// `h_jac = H = ∂h/∂x`: `v = y − ŷ`, `S = H P Hᵀ + R`, `K = P Hᵀ S⁻¹`, `x̂ ← x̂ + K v`,
    /// `P ← (I − K H) P (I − K H)ᵀ + K R Kᵀ` (Joseph form, symmetrised).
    ///
    /// Returns the innovation statistics, or an error leaving the filter unchanged.
    pub fn update(
        &mut self,
        y: &SVector<f64, NY>,
        y_pred: &SVector<f64, NY>,
        h_jac: &SMatrix<f64, NY, NX>,
    ) -> Result<InnovationStats<NY>, EkfError> {
        self.update_holding(y, y_pred, h_jac, &[false; NX])
    }

    /// [`update`](Self::update) with the states whose `held` entry is true left out of the
    /// correction (the Schmidt–Kalman "consider" update): their rows of `K` are zeroed, so `x̂`
    /// keeps them and the other states take the gain of the full update; `P` follows by the
    /// same Joseph form, which holds for any gain (a held state's own variance is unchanged).
    pub fn update_holding(
        &mut self,
        y: &SVector<f64, NY>,
        y_pred: &SVector<f64, NY>,
        h_jac: &SMatrix<f64, NY, NX>,
        held: &[bool; NX],
    ) -> Result<InnovationStats<NY>, EkfError> {
        let (stats, mut k) = self.innovation(y, y_pred, h_jac)?;
        for (r, &h) in held.iter().enumerate() {
            if h {
                k.row_mut(r).fill(0.0);
            }
        }
        let x = self.x + k * stats.v;
        let ikh = SMatrix::<f64, NX, NX>::identity() - k * h_jac;
        let p = symmetrise(&(ikh * self.p * ikh.transpose() + k * self.r * k.transpose()));
        if !finite(&x) || !finite(&p) {
            return Err(EkfError::NonFiniteResult);
        }
        self.x = x;
        self.p = p;
        Ok(stats)
    }
}
