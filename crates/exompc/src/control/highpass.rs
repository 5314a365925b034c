//! The high-pass filter shared by the oscillation detectors (`safety::OscillationDetector` of
//! the supervisor and `lag::HfShareDetector` of the robust method).

#[cfg(not(feature = "std"))]
use crate::math::Float;
use nalgebra::SVector;

/// Second-order Butterworth high-pass per channel, by the bilinear transform with
/// pre-warping, so that `|H(f)|² = 1 / (1 + (tan(π f_c dt) / tan(π f dt))⁴)` exactly. It starts
/// as if its first input had always been there (no step response to the initial value).
#[derive(Clone, Copy, Debug)]
pub struct HighPass<const N: usize> {
    b: [f64; 3],
    a: [f64; 2],
    x: [SVector<f64, N>; 2],
    y: [SVector<f64, N>; 2],
    started: bool,
}

impl<const N: usize> HighPass<N> {
    /// Cut-off `cutoff_hz` for samples every `dt` s; out-of-range values are brought into
    /// range (`dt` ≤ 0 or non-finite → 0.01 s, the cut-off into (0, Nyquist)).
    pub fn new(cutoff_hz: f64, dt: f64) -> Self {
        let (b, a) = Self::coefficients(cutoff_hz, dt);
        HighPass {
            b,
            a,
            x: [SVector::zeros(); 2],
            y: [SVector::zeros(); 2],
            started: false,
        }
    }

    /// Moves the cut-off to `cutoff_hz` (brought into range as by [`HighPass::new`]) and keeps
    /// the filter's state (its last two inputs and outputs), so that a cut-off that follows a
    /// slowly varying frequency (the supervisor's gait-following cut-off,
    /// `safety::OscillationDetector::set_cutoff`) filters on without a restart.
    pub fn set_cutoff(&mut self, cutoff_hz: f64, dt: f64) {
        (self.b, self.a) = Self::coefficients(cutoff_hz, dt);
    }

    /// Numerator `b` and denominator `a` (without the leading 1) of the pre-warped bilinear
    /// Butterworth high-pass: `k = tan(π f_c dt)`, `b = [1, −2, 1] / n`,
    /// `a = [2 (k² − 1), 1 − √2 k + k²] / n`, `n = 1 + √2 k + k²`.
    fn coefficients(cutoff_hz: f64, dt: f64) -> ([f64; 3], [f64; 2]) {
        let dt = if dt.is_finite() && dt > 0.0 { dt } else { 0.01 };
        let nyquist = 0.5 / dt;
        let fc = if cutoff_hz.is_finite() {
            cutoff_hz.clamp(1e-6 * nyquist, 0.999 * nyquist)
        } else {
            0.3 * nyquist
        };
        let k = (core::f64::consts::PI * fc * dt).tan();
        let r2 = core::f64::consts::SQRT_2;
        let norm = 1.0 / (1.0 + r2 * k + k * k);
        (
            [norm, -2.0 * norm, norm],
            [2.0 * (k * k - 1.0) * norm, (1.0 - r2 * k + k * k) * norm],
        )
    }

    /// Restart: the next sample is taken as the initial value.
    pub fn reset(&mut self) {
        self.x = [SVector::zeros(); 2];
        self.y = [SVector::zeros(); 2];
        self.started = false;
    }

    /// Filter one sample (finite values expected; the caller skips others).
    pub fn push(&mut self, v: &SVector<f64, N>) -> SVector<f64, N> {
        if !self.started {
            self.x = [*v, *v];
            self.started = true;
        }
        let [b0, b1, b2] = self.b;
        let [a1, a2] = self.a;
        let y = v * b0 + self.x[0] * b1 + self.x[1] * b2 - self.y[0] * a1 - self.y[1] * a2;
        self.x = [*v, self.x[0]];
        self.y = [y, self.y[0]];
        y
    }
}
