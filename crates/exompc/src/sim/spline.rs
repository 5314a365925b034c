//! Interpolating cubic splines (C2) for recorded joint angles (docs/MODEL.md §6).
//!
//! A spline through samples `(t_i, y_i)` is a cubic polynomial on each interval
//! `[t_i, t_{i+1}]`, with value, slope and curvature continuous at every interior knot. Two end
//! conditions are offered:
//!
//! - **not-a-knot**: the third derivative is also continuous at `t_1` and `t_{n-2}` (the first
//!   two and the last two pieces are one cubic each). Any cubic polynomial is reproduced
//!   exactly, and nothing is assumed about the motion at the ends (a natural spline would force
//!   zero acceleration there).
//! - **periodic**: `y_{n-1} = y_0`, and slope and curvature also match across the wrap from the
//!   last sample to the first, so a looped recording stays C2 at the seam.
//!
//! Evaluation is generic over [`Real`]: with dual numbers the velocity and acceleration come out
//! exact (the derivatives of the piecewise cubic), not finite differences. Outside the samples
//! the end pieces are extended (not-a-knot) or time wraps around (periodic).

#[cfg(not(feature = "std"))]
use crate::math::Float;
use crate::model::Real;
use alloc::{vec, vec::Vec};

/// How the spline ends (see the module documentation).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SplineEnds {
    /// Third derivative continuous at the second and the second-to-last knot.
    NotAKnot,
    /// Value, slope and curvature continuous across the wrap (`y_{n-1}` must equal `y_0`).
    Periodic,
}

/// A C2 interpolating cubic spline (see the module documentation).
#[derive(Clone, Debug, PartialEq)]
pub struct CubicSpline {
    /// Knots `t_0 < t_1 < … < t_{n-1}`.
    knots: Vec<f64>,
    /// Per interval `i`: `[a, b, c, d]` of `y = a + b·s + c·s² + d·s³`, `s = t − t_i`.
    coefficients: Vec<[f64; 4]>,
    ends: SplineEnds,
}

impl CubicSpline {
    /// The spline through `(knots[i], values[i])`.
    ///
    /// Needs at least 4 samples, strictly increasing finite knots and finite values (for
    /// [`SplineEnds::Periodic`], `values[n-1]` is taken as `values[0]`); returns `None` otherwise.
    /// The caller (e.g. [`GaitRecording::new`](super::GaitRecording::new)) reports which sample
    /// is wrong.
    pub fn new(knots: &[f64], values: &[f64], ends: SplineEnds) -> Option<Self> {
        let n = knots.len();
        if n < 4
            || values.len() != n
            || knots.iter().chain(values).any(|v| !v.is_finite())
            || knots.windows(2).any(|w| w[1] <= w[0])
        {
            return None;
        }
        let mut y = values.to_vec();
        if ends == SplineEnds::Periodic {
            y[n - 1] = y[0];
        }
        let h: Vec<f64> = knots.windows(2).map(|w| w[1] - w[0]).collect();
        let slope: Vec<f64> = (0..n - 1).map(|i| (y[i + 1] - y[i]) / h[i]).collect();
        let m = match ends {
            SplineEnds::NotAKnot => moments_not_a_knot(&h, &slope),
            SplineEnds::Periodic => moments_periodic(&h, &slope),
        };
        if m.iter().any(|v| !v.is_finite()) {
            return None;
        }
        let coefficients = (0..n - 1)
            .map(|i| {
                [
                    y[i],
                    slope[i] - h[i] * (2.0 * m[i] + m[i + 1]) / 6.0,
                    m[i] / 2.0,
                    (m[i + 1] - m[i]) / (6.0 * h[i]),
                ]
            })
            .collect();
        Some(CubicSpline {
            knots: knots.to_vec(),
            coefficients,
            ends,
        })
    }

    /// First knot (s).
    pub fn start(&self) -> f64 {
        self.knots[0]
    }

    /// Last knot (s).
    pub fn end(&self) -> f64 {
        self.knots[self.knots.len() - 1]
    }

    /// The end condition.
    pub fn ends(&self) -> SplineEnds {
        self.ends
    }

    /// The spline at `t` (allocation-free, `O(log n)`); exact derivatives with dual numbers.
    pub fn eval<T: Real>(&self, t: T) -> T {
        let mut t = t;
        if self.ends == SplineEnds::Periodic {
            // Shift by whole periods; a constant shift leaves the derivative parts unchanged.
            let period = self.end() - self.start();
            let k = ((t.re() - self.start()) / period).floor();
            if k != 0.0 {
                t -= k * period;
            }
        }
        let x = t.re();
        // Interval i with knots[i] <= x < knots[i+1]; the end intervals extend outwards.
        let i = self
            .knots
            .partition_point(|&k| k <= x)
            .saturating_sub(1)
            .min(self.coefficients.len() - 1);
        let [a, b, c, d] = self.coefficients[i];
        let s = t - self.knots[i];
        ((s * d + c) * s + b) * s + a
    }
}

/// Curvatures `M_i = y''(t_i)` of the not-a-knot spline: the standard tridiagonal moment
/// equations `h_{i-1} M_{i-1} + 2 (h_{i-1} + h_i) M_i + h_i M_{i+1} = 6 (δ_i − δ_{i-1})` for the
/// interior knots, with `M_0` and `M_{n-1}` eliminated by the not-a-knot conditions
/// `(M_1 − M_0)/h_0 = (M_2 − M_1)/h_1` (and likewise at the end); solved by the Thomas algorithm.
fn moments_not_a_knot(h: &[f64], slope: &[f64]) -> Vec<f64> {
    let n = h.len() + 1;
    let k = n - 2; // unknowns M_1..M_{n-2}
    let (mut sub, mut diag, mut sup, mut rhs) =
        (vec![0.0; k], vec![0.0; k], vec![0.0; k], vec![0.0; k]);
    for j in 0..k {
        let i = j + 1;
        sub[j] = h[i - 1];
        diag[j] = 2.0 * (h[i - 1] + h[i]);
        sup[j] = h[i];
        rhs[j] = 6.0 * (slope[i] - slope[i - 1]);
    }
    // M_0 = ((h0 + h1) M_1 − h0 M_2) / h1, substituted into the first row.
    let (h0, h1) = (h[0], h[1]);
    diag[0] += h0 * (h0 + h1) / h1;
    sup[0] -= h0 * h0 / h1;
    // M_{n-1} = ((hb + ha) M_{n-2} − ha M_{n-3}) / hb with ha = h_{n-2}, hb = h_{n-3}.
    let (ha, hb) = (h[n - 2], h[n - 3]);
    diag[k - 1] += ha * (ha + hb) / hb;
    sub[k - 1] -= ha * ha / hb;
    let inner = thomas(&sub, &diag, &sup, &rhs);
    let mut m = Vec::with_capacity(n);
    m.push(((h0 + h1) * inner[0] - h0 * inner[1]) / h1);
    m.extend_from_slice(&inner);
    m.push(((ha + hb) * inner[k - 1] - ha * inner[k - 2]) / hb);
    m
}

/// Curvatures of the periodic spline: the moment equations of every knot with cyclic indices
/// (a cyclic tridiagonal system, solved by the Sherman–Morrison correction of the Thomas
/// algorithm); `M_{n-1} = M_0`.
fn moments_periodic(h: &[f64], slope: &[f64]) -> Vec<f64> {
    let k = h.len(); // unknowns M_0..M_{n-2}
    let prev = |i: usize| if i == 0 { k - 1 } else { i - 1 };
    let (mut sub, mut diag, mut sup, mut rhs) =
        (vec![0.0; k], vec![0.0; k], vec![0.0; k], vec![0.0; k]);
    for i in 0..k {
        sub[i] = h[prev(i)];
        diag[i] = 2.0 * (h[prev(i)] + h[i]);
        sup[i] = h[i];
        rhs[i] = 6.0 * (slope[i] - slope[prev(i)]);
    }
    // A = T + u vᵀ with the corners moved into u = (γ, 0, …, 0, c), v = (1, 0, …, 0, a/γ).
    let (corner_a, corner_c) = (sub[0], sup[k - 1]); // A[0][k-1], A[k-1][0]
    let gamma = -diag[0];
    let mut d = diag.clone();
    d[0] -= gamma;
    d[k - 1] -= corner_c * corner_a / gamma;
    let x = thomas(&sub, &d, &sup, &rhs);
    let mut u = vec![0.0; k];
    u[0] = gamma;
    u[k - 1] = corner_c;
    let z = thomas(&sub, &d, &sup, &u);
    let vx = x[0] + corner_a / gamma * x[k - 1];
    let vz = z[0] + corner_a / gamma * z[k - 1];
    let factor = vx / (1.0 + vz);
    let mut m: Vec<f64> = x.iter().zip(&z).map(|(xi, zi)| xi - factor * zi).collect();
    m.push(m[0]);
    m
}

/// Solves the tridiagonal system `sub[i] x[i-1] + diag[i] x[i] + sup[i] x[i+1] = rhs[i]`
/// (`sub[0]` and `sup[k-1]` ignored).
fn thomas(sub: &[f64], diag: &[f64], sup: &[f64], rhs: &[f64]) -> Vec<f64> {
    let k = diag.len();
    let mut c = vec![0.0; k];
    let mut d = vec![0.0; k];
    c[0] = sup[0] / diag[0];
    d[0] = rhs[0] / diag[0];
    for i in 1..k {
        let w = diag[i] - sub[i] * c[i - 1];
        c[i] = sup[i] / w;
        d[i] = (rhs[i] - sub[i] * d[i - 1]) / w;
    }
    for i in (0..k - 1).rev() {
        d[i] -= c[i] * d[i + 1];
    }
    d
}

#[cfg(test)]
mod tests {
    use super::*;
    use num_dual::{second_derivative, Dual2};
    use std::f64::consts::PI;

    fn derivs(s: &CubicSpline, t: f64) -> (f64, f64, f64) {
        second_derivative(|x: Dual2<f64>| s.eval(x), t)
    }

    /// Uneven knots, so that no symmetry hides a wrong coefficient.
    fn uneven(n: usize, span: f64) -> Vec<f64> {
        let raw: Vec<f64> = (0..n)
            .map(|i| i as f64 + 0.35 * ((i * 7 % 5) as f64 / 5.0))
            .collect();
        let scale = span / raw[n - 1];
        raw.iter().map(|r| (r - raw[0]) * scale).collect()
    }

    #[test]
    fn not_a_knot_reproduces_a_cubic_exactly() {
        let p = |t: f64| {
            (
                1.5 - 0.7 * t + 0.3 * t * t - 0.05 * t * t * t,
                -0.7 + 0.6 * t - 0.15 * t * t,
                0.6 - 0.3 * t,
            )
        };
        for n in [4, 5, 6, 9, 40] {
            let knots = uneven(n, 6.0);
            let values: Vec<f64> = knots.iter().map(|&t| p(t).0).collect();
            let s = CubicSpline::new(&knots, &values, SplineEnds::NotAKnot).unwrap();
            // Inside, at the knots and outside (the end pieces are the same cubic).
            for k in 0..=130 {
                let t = -0.3 + 6.6 * k as f64 / 130.0;
                let (y, yd, ydd) = derivs(&s, t);
                let (ey, eyd, eydd) = p(t);
                assert!((y - ey).abs() < 1e-11, "n {n} t {t}: {y} vs {ey}");
                assert!((yd - eyd).abs() < 1e-10, "n {n} t {t}: {yd} vs {eyd}");
                assert!((ydd - eydd).abs() < 1e-9, "n {n} t {t}: {ydd} vs {eydd}");
            }
        }
    }

    #[test]
    fn interpolates_and_is_c2_at_the_knots() {
        let knots = uneven(25, 5.0);
        let values: Vec<f64> = knots.iter().map(|&t| (1.3 * t).sin() + 0.2 * t).collect();
        let s = CubicSpline::new(&knots, &values, SplineEnds::NotAKnot).unwrap();
        for (i, (&t, &y)) in knots.iter().zip(&values).enumerate() {
            assert!((s.eval(t) - y).abs() < 1e-12, "knot {i}");
            if i == 0 || i == knots.len() - 1 {
                continue;
            }
            // The pieces left and right of the knot agree in value, slope and curvature.
            let [a, b, c, d] = s.coefficients[i - 1];
            let hl = t - knots[i - 1];
            let left = (
                a + hl * (b + hl * (c + hl * d)),
                b + hl * (2.0 * c + 3.0 * hl * d),
                2.0 * c + 6.0 * hl * d,
            );
            let [a, b, c, _] = s.coefficients[i];
            assert!((left.0 - a).abs() < 1e-12, "value at knot {i}");
            assert!((left.1 - b).abs() < 1e-10, "slope at knot {i}");
            assert!((left.2 - 2.0 * c).abs() < 1e-8, "curvature at knot {i}");
        }
    }

    #[test]
    fn converges_to_a_smooth_function_with_its_derivatives() {
        // Error of a cubic spline: O(h⁴) in value, O(h²) in acceleration.
        let f = |t: f64| {
            (
                0.3 * (2.0 * PI * 0.8 * t).sin(),
                0.3 * 2.0 * PI * 0.8 * (2.0 * PI * 0.8 * t).cos(),
                -0.3 * (2.0 * PI * 0.8_f64).powi(2) * (2.0 * PI * 0.8 * t).sin(),
            )
        };
        for (rate, tol) in [(100.0, [1e-7, 1e-5, 2e-2]), (500.0, [1e-9, 1e-7, 1e-3])] {
            let n = (4.0 * rate) as usize + 1;
            let knots: Vec<f64> = (0..n).map(|i| i as f64 / rate).collect();
            let values: Vec<f64> = knots.iter().map(|&t| f(t).0).collect();
            let s = CubicSpline::new(&knots, &values, SplineEnds::NotAKnot).unwrap();
            for k in 0..1000 {
                let t = 4.0 * k as f64 / 1000.0 + 0.0013;
                let (y, yd, ydd) = derivs(&s, t);
                let e = f(t);
                assert!((y - e.0).abs() < tol[0], "{rate} Hz t {t}: {y} vs {}", e.0);
                assert!(
                    (yd - e.1).abs() < tol[1],
                    "{rate} Hz t {t}: {yd} vs {}",
                    e.1
                );
                assert!(
                    (ydd - e.2).abs() < tol[2],
                    "{rate} Hz t {t}: {ydd} vs {}",
                    e.2
                );
            }
        }
    }

    #[test]
    fn periodic_spline_is_c2_across_the_wrap_and_repeats() {
        // One period of a smooth periodic function on uneven knots.
        let period = 1.25;
        let f = |t: f64| (2.0 * PI * t / period).sin() + 0.3 * (4.0 * PI * t / period).cos();
        let knots = uneven(30, period);
        let values: Vec<f64> = knots.iter().map(|&t| f(t)).collect();
        let s = CubicSpline::new(&knots, &values, SplineEnds::Periodic).unwrap();
        for k in 0..200 {
            let t = period * k as f64 / 200.0 + 0.001;
            let a = derivs(&s, t);
            for shift in [-2.0, 1.0, 7.0] {
                let b = derivs(&s, t + shift * period);
                assert!(
                    (a.0 - b.0).abs() < 1e-9
                        && (a.1 - b.1).abs() < 1e-8
                        && (a.2 - b.2).abs() < 1e-6
                );
            }
        }
        // Across the seam: just before the end and just after the start.
        let eps = 1e-7;
        let before = derivs(&s, period - eps);
        let after = derivs(&s, eps);
        assert!((before.0 - after.0).abs() < 1e-5);
        assert!((before.1 - after.1).abs() < 1e-4);
        assert!((before.2 - after.2).abs() < 1e-3, "{before:?} vs {after:?}");
        // Accurate as an interpolant too.
        let (y, _, _) = derivs(&s, 0.4);
        assert!((y - f(0.4)).abs() < 1e-3);
    }

    #[test]
    fn bad_samples_give_none() {
        let k = [0.0, 1.0, 2.0, 3.0];
        let v = [0.0, 1.0, 0.0, 1.0];
        assert!(CubicSpline::new(&k[..3], &v[..3], SplineEnds::NotAKnot).is_none());
        assert!(CubicSpline::new(&[0.0, 1.0, 1.0, 3.0], &v, SplineEnds::NotAKnot).is_none());
        assert!(CubicSpline::new(&k, &[0.0, f64::NAN, 0.0, 1.0], SplineEnds::NotAKnot).is_none());
        assert!(CubicSpline::new(&k, &v[..3], SplineEnds::NotAKnot).is_none());
        assert!(CubicSpline::new(&k, &v, SplineEnds::NotAKnot).is_some());
        assert!(CubicSpline::new(&k, &v, SplineEnds::Periodic).is_some());
    }
}
