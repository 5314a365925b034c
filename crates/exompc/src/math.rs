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
