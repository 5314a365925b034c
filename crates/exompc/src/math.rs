//! f64 math without `std` (the library's `std` feature off, docs/EMBEDDED.md).
//!
//! `core` has no `f64::sqrt`, `sin`, `exp`, ...: a file of the numerical core that calls them
//! imports [`Float`] under `#[cfg(not(feature = "std"))]`, so its call sites read the same as
//! on the host, where the standard library's methods are used unchanged. The functions are
//! `libm`'s (musl's algorithms; they differ from glibc's by at most an ulp on a few arguments),
//! `powi` is the compiler runtime's `__powidf2` loop (as `f64::powi` on the host), and with the
//! `arm-fp64` feature (an Arm core with a double-precision FPU, e.g. the Cortex-M7's FPv5-D16)
//! the square root is the FPU's `vsqrt.f64` (correctly rounded, as on the host) instead of
//! libm's software one.
//!
//! [`Real`], the model's scalar type, is `f64` only here: the dual-number derivatives
//! (`num-dual`) are host-side oracles; the control step uses the hand-derived ones.

// With `std` this module is compiled for its tests only (against `std` and `num-dual`).
#![cfg_attr(feature = "std", allow(dead_code))]

use core::iter::Sum;
use core::ops::{Add, AddAssign, Div, DivAssign, Mul, MulAssign, Neg, Sub, SubAssign};

/// The `f64` methods of `std` that the numerical core uses (module docs).
pub(crate) trait Float: Sized {
    fn sqrt(self) -> Self;
    fn sin(self) -> Self;
    fn cos(self) -> Self;
    fn sin_cos(self) -> (Self, Self);
    fn tan(self) -> Self;
    fn exp(self) -> Self;
    fn ln(self) -> Self;
    fn powi(self, n: i32) -> Self;
    fn ceil(self) -> Self;
    fn floor(self) -> Self;
    fn round(self) -> Self;
}

impl Float for f64 {
    #[inline]
    fn sqrt(self) -> f64 {
        #[cfg(all(target_arch = "arm", feature = "arm-fp64"))]
        {
            let r: f64;
            // SAFETY: one FPU instruction on registers; `arm-fp64` promises the FPU has it.
            unsafe {
                core::arch::asm!(
                    "vsqrt.f64 {r}, {x}",
                    r = lateout(dreg_low16) r,
                    x = in(dreg_low16) self,
                    options(pure, nomem, nostack, preserves_flags)
                );
            }
            r
        }
        #[cfg(not(all(target_arch = "arm", feature = "arm-fp64")))]
        {
            libm::sqrt(self)
        }
    }
    #[inline]
    fn sin(self) -> f64 {
        libm::sin(self)
    }
    #[inline]
    fn cos(self) -> f64 {
        libm::cos(self)
    }
    #[inline]
    fn sin_cos(self) -> (f64, f64) {
        libm::sincos(self)
    }
    #[inline]
    fn tan(self) -> f64 {
        libm::tan(self)
    }
    #[inline]
    fn exp(self) -> f64 {
        libm::exp(self)
    }
    #[inline]
    fn ln(self) -> f64 {
        libm::log(self)
    }
    #[inline]
    fn powi(self, n: i32) -> f64 {
        // compiler-rt's `__powidf2`, which `f64::powi` calls on the host.
        let (mut a, mut b, mut r) = (self, n, 1.0);
        loop {
            if b & 1 != 0 {
                r *= a;
            }
            b /= 2;
            if b == 0 {
                break;
            }
            a *= a;
        }
        if n < 0 {
            1.0 / r
        } else {
            r
        }
    }
    #[inline]
    fn ceil(self) -> f64 {
        libm::ceil(self)
    }
    #[inline]
    fn floor(self) -> f64 {
        libm::floor(self)
    }
    #[inline]
    fn round(self) -> f64 {
        libm::round(self)
    }
}

/// A real scalar of the model: without `std` only `f64` (module docs); the methods the generic
/// model code calls, with the names of `num-dual`'s `DualNum`.
pub trait Real:
    Copy
    + nalgebra::Scalar
    + num_traits::Zero
    + num_traits::One
    + From<f64>
    + Sum
    + Add<Output = Self>
    + Sub<Output = Self>
    + Mul<Output = Self>
    + Div<Output = Self>
    + Neg<Output = Self>
    + AddAssign
    + SubAssign
    + MulAssign
    + DivAssign
    + AddAssign<f64>
    + SubAssign<f64>
    + MulAssign<f64>
    + DivAssign<f64>
    + Add<f64, Output = Self>
    + Sub<f64, Output = Self>
    + Mul<f64, Output = Self>
    + Div<f64, Output = Self>
{
    /// The real part (the value itself for `f64`).
    fn re(&self) -> f64;
    /// Sine.
    fn sin(self) -> Self;
    /// Cosine.
    fn cos(self) -> Self;
    /// Sine and cosine.
    fn sin_cos(self) -> (Self, Self);
    /// `e^x`.
    fn exp(self) -> Self;
    /// `1/x`.
    fn recip(self) -> Self;
    /// `x^n`.
    fn powi(self, n: i32) -> Self;
}

impl Real for f64 {
    #[inline]
    fn re(&self) -> f64 {
        *self
    }
    #[inline]
    fn sin(self) -> f64 {
        Float::sin(self)
    }
    #[inline]
    fn cos(self) -> f64 {
        Float::cos(self)
    }
    #[inline]
    fn sin_cos(self) -> (f64, f64) {
        Float::sin_cos(self)
    }
    #[inline]
    fn exp(self) -> f64 {
        Float::exp(self)
    }
    #[inline]
    fn recip(self) -> f64 {
        1.0 / self
    }
    #[inline]
    fn powi(self, n: i32) -> f64 {
        Float::powi(self, n)
    }
}

/// A second-order dual number `x + v1·ε + v2·ε²/2`: value, first and second derivative along
/// one direction; without `std` it replaces `num_dual::Dual2` for the exact time derivatives of
/// the desired trajectories (`sim::Trajectory::eval`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Dual2<F> {
    /// Value.
    pub re: F,
    /// First derivative.
    pub v1: F,
    /// Second derivative.
    pub v2: F,
}

impl Dual2<f64> {
    /// The value `x` with first derivative 1 (the variable of differentiation).
    fn variable(x: f64) -> Self {
        Dual2 {
            re: x,
            v1: 1.0,
            v2: 0.0,
        }
    }
    /// `f(self)` from `f`, `f'` and `f''` at the value (the chain rule to second order).
    #[inline]
    fn chain(self, f0: f64, f1: f64, f2: f64) -> Self {
        Dual2 {
            re: f0,
            v1: f1 * self.v1,
            v2: f1 * self.v2 + f2 * self.v1 * self.v1,
        }
    }
}

/// `(f(t), f'(t), f''(t))` of a scalar function written over [`Real`], as
/// `num_dual::second_derivative`.
pub fn second_derivative(f: impl FnOnce(Dual2<f64>) -> Dual2<f64>, t: f64) -> (f64, f64, f64) {
    let y = f(Dual2::variable(t));
    (y.re, y.v1, y.v2)
}

impl From<f64> for Dual2<f64> {
    fn from(x: f64) -> Self {
        Dual2 {
            re: x,
            v1: 0.0,
            v2: 0.0,
        }
    }
}

impl Add for Dual2<f64> {
    type Output = Self;
    #[inline]
    fn add(self, b: Self) -> Self {
        Dual2 {
            re: self.re + b.re,
            v1: self.v1 + b.v1,
            v2: self.v2 + b.v2,
        }
    }
}

impl Sub for Dual2<f64> {
    type Output = Self;
    #[inline]
    fn sub(self, b: Self) -> Self {
        Dual2 {
            re: self.re - b.re,
            v1: self.v1 - b.v1,
            v2: self.v2 - b.v2,
        }
    }
}

impl Mul for Dual2<f64> {
    type Output = Self;
    #[inline]
    fn mul(self, b: Self) -> Self {
        Dual2 {
            re: self.re * b.re,
            v1: self.v1 * b.re + self.re * b.v1,
            v2: self.v2 * b.re + 2.0 * self.v1 * b.v1 + self.re * b.v2,
        }
    }
}

impl Div for Dual2<f64> {
    type Output = Self;
    #[inline]
    fn div(self, b: Self) -> Self {
        // (a/b)' = (a' − q b')/b, (a/b)'' = (a'' − 2 q' b' − q b'')/b with q = a/b.
        let re = self.re / b.re;
        let v1 = (self.v1 - re * b.v1) / b.re;
        Dual2 {
            re,
            v1,
            v2: (self.v2 - 2.0 * v1 * b.v1 - re * b.v2) / b.re,
        }
    }
}

impl Neg for Dual2<f64> {
    type Output = Self;
    #[inline]
    fn neg(self) -> Self {
        Dual2 {
            re: -self.re,
            v1: -self.v1,
            v2: -self.v2,
        }
    }
}

impl Add<f64> for Dual2<f64> {
    type Output = Self;
    #[inline]
    fn add(self, b: f64) -> Self {
        Dual2 {
            re: self.re + b,
            ..self
        }
    }
}

impl Sub<f64> for Dual2<f64> {
    type Output = Self;
    #[inline]
    fn sub(self, b: f64) -> Self {
        Dual2 {
            re: self.re - b,
            ..self
        }
    }
}

impl Mul<f64> for Dual2<f64> {
    type Output = Self;
    #[inline]
    fn mul(self, b: f64) -> Self {
        Dual2 {
            re: self.re * b,
            v1: self.v1 * b,
            v2: self.v2 * b,
        }
    }
}

impl Div<f64> for Dual2<f64> {
    type Output = Self;
    #[inline]
    fn div(self, b: f64) -> Self {
        Dual2 {
            re: self.re / b,
            v1: self.v1 / b,
            v2: self.v2 / b,
        }
    }
}

impl AddAssign for Dual2<f64> {
    fn add_assign(&mut self, b: Self) {
        *self = *self + b;
    }
}

impl SubAssign for Dual2<f64> {
    fn sub_assign(&mut self, b: Self) {
        *self = *self - b;
    }
}

impl MulAssign for Dual2<f64> {
    fn mul_assign(&mut self, b: Self) {
        *self = *self * b;
    }
}

impl DivAssign for Dual2<f64> {
    fn div_assign(&mut self, b: Self) {
        *self = *self / b;
    }
}

impl AddAssign<f64> for Dual2<f64> {
    fn add_assign(&mut self, b: f64) {
        *self = *self + b;
    }
}

impl SubAssign<f64> for Dual2<f64> {
    fn sub_assign(&mut self, b: f64) {
        *self = *self - b;
    }
}

impl MulAssign<f64> for Dual2<f64> {
    fn mul_assign(&mut self, b: f64) {
        *self = *self * b;
    }
}

impl DivAssign<f64> for Dual2<f64> {
    fn div_assign(&mut self, b: f64) {
        *self = *self / b;
    }
}

impl num_traits::Zero for Dual2<f64> {
    fn zero() -> Self {
        Self::from(0.0)
    }
    fn is_zero(&self) -> bool {
        self.re == 0.0 && self.v1 == 0.0 && self.v2 == 0.0
    }
}

impl num_traits::One for Dual2<f64> {
    fn one() -> Self {
        Self::from(1.0)
    }
}

impl Sum for Dual2<f64> {
    fn sum<I: Iterator<Item = Self>>(iter: I) -> Self {
        iter.fold(Self::from(0.0), |a, b| a + b)
    }
}

impl Real for Dual2<f64> {
    #[inline]
    fn re(&self) -> f64 {
        self.re
    }
    #[inline]
    fn sin(self) -> Self {
        let (s, c) = Float::sin_cos(self.re);
        self.chain(s, c, -s)
    }
    #[inline]
    fn cos(self) -> Self {
        let (s, c) = Float::sin_cos(self.re);
        self.chain(c, -s, -c)
    }
    #[inline]
    fn sin_cos(self) -> (Self, Self) {
        let (s, c) = Float::sin_cos(self.re);
        (self.chain(s, c, -s), self.chain(c, -s, -c))
    }
    #[inline]
    fn exp(self) -> Self {
        let e = Float::exp(self.re);
        self.chain(e, e, e)
    }
    #[inline]
    fn recip(self) -> Self {
        let r = 1.0 / self.re;
        self.chain(r, -r * r, 2.0 * r * r * r)
    }
    #[inline]
    fn powi(self, n: i32) -> Self {
        match n {
            0 => Self::from(1.0),
            1 => self,
            _ => {
                let p2 = Float::powi(self.re, n - 2);
                let p1 = p2 * self.re;
                let nf = f64::from(n);
                self.chain(p1 * self.re, nf * p1, nf * (nf - 1.0) * p2)
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::{second_derivative as d2, Dual2, Float, Real};
    use num_dual::DualNum as _;

    /// A function of the trajectories' kind: products, quotients, sin/cos, exp, powi.
    fn f<T: Real>(t: T) -> T {
        let a = (t * 2.1).sin() * (t * 0.7 + 0.3).cos() + (t * -0.4).exp() * t.powi(3);
        let (s, c) = (t * 1.3).sin_cos();
        a / (t * t + 1.5) + s * c - (T::from(2.0) - t).recip() * 0.25
    }

    #[test]
    fn second_derivatives_equal_num_dual() {
        for i in 0..200 {
            let t = -3.0 + 0.031 * f64::from(i);
            let ours = d2(|x: Dual2<f64>| f(x), t);
            let theirs = num_dual::second_derivative(
                |x: num_dual::Dual2<f64>| {
                    let a = (x * 2.1).sin() * (x * 0.7 + 0.3).cos() + (x * -0.4).exp() * x.powi(3);
                    let (s, c) = (x * 1.3).sin_cos();
                    a / (x * x + 1.5) + s * c - (num_dual::Dual2::from(2.0) - x).recip() * 0.25
                },
                t,
            );
            for (o, e) in [(ours.0, theirs.0), (ours.1, theirs.1), (ours.2, theirs.2)] {
                assert!(
                    (o - e).abs() <= 1e-12 * (1.0 + e.abs()),
                    "t {t}: {o} vs {e}"
                );
            }
        }
    }

    #[test]
    fn libm_and_powi_agree_with_std() {
        for i in 0..2000 {
            let x = -20.0 + 0.0173 * f64::from(i);
            assert_eq!(Float::powi(x, 2), x.powi(2));
            assert_eq!(Float::powi(x, 3), x.powi(3));
            assert_eq!(Float::powi(x, -2), x.powi(-2));
            assert_eq!(Float::sqrt(x.abs()), x.abs().sqrt());
            assert_eq!(Float::round(x), x.round());
            assert_eq!(Float::floor(x), x.floor());
            assert_eq!(Float::ceil(x), x.ceil());
            // musl's and glibc's sin/cos/exp/ln are both within an ulp of the exact value.
            let ulps = |a: f64, b: f64| (a.to_bits() as i64 - b.to_bits() as i64).unsigned_abs();
            assert!(ulps(Float::sin(x), x.sin()) <= 1, "sin {x}");
            assert!(ulps(Float::cos(x), x.cos()) <= 1, "cos {x}");
            assert!(ulps(Float::exp(x), x.exp()) <= 1, "exp {x}");
            assert!(
                ulps(Float::ln(x.abs() + 1e-3), (x.abs() + 1e-3).ln()) <= 1,
                "ln {x}"
            );
        }
    }
}
