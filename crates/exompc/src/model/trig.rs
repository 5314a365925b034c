//! `sin` and `cos` of one `f64` angle in one inlined call, for the hot path of the prediction
//! model's exact Jacobian (`control::prediction`), where the libm call was ~14 % of a long-horizon
//! control step.
//!
//! The method is the classic fdlibm one (as in musl): Cody–Waite reduction by `π/2` in up to three
//! rounds of a three-part `π/2` (exact enough for every `|x| < 2²⁰·π/2`) and the minimax kernel
//! polynomials on `[−π/4, π/4]`, each below one unit in the last place. Larger or non-finite
//! arguments go to the standard library. Tested against `f64::sin_cos` (crates/exompc/tests/model.rs).

// The fdlibm constants as published (more digits than an f64 holds; they round to the intended values).
#![allow(clippy::excessive_precision)]

#[cfg(not(feature = "std"))]
use crate::math::Float;
use core::f64::consts::{FRAC_2_PI, FRAC_PI_4};

const PIO2_1: f64 = 1.570_796_326_734_125_614_17e0;
const PIO2_1T: f64 = 6.077_100_506_506_192_249_32e-11;
const PIO2_2: f64 = 6.077_100_506_303_965_976_60e-11;
const PIO2_2T: f64 = 2.022_266_248_795_950_631_54e-21;
const PIO2_3: f64 = 2.022_266_248_711_166_455_80e-21;
const PIO2_3T: f64 = 8.478_427_660_368_899_569_97e-32;
/// `2²⁰·π/2`: below it the reduction above is exact enough.
const MEDIUM: f64 = 1_647_099.0;

const S1: f64 = -1.666_666_666_666_663_243_48e-1;
const S2: f64 = 8.333_333_333_322_489_461_24e-3;
const S3: f64 = -1.984_126_982_985_794_931_34e-4;
const S4: f64 = 2.755_731_370_707_006_767_89e-6;
const S5: f64 = -2.505_076_025_340_686_341_95e-8;
const S6: f64 = 1.589_690_995_211_550_102_21e-10;

const C1: f64 = 4.166_666_666_666_660_190_37e-2;
const C2: f64 = -1.388_888_888_887_410_957_49e-3;
const C3: f64 = 2.480_158_728_947_672_941_78e-5;
const C4: f64 = -2.755_731_435_139_066_330_35e-7;
const C5: f64 = 2.087_572_321_298_174_827_90e-9;
const C6: f64 = -1.135_964_755_778_819_482_65e-11;

/// `sin(x + y)` for `|x| ≤ π/4`, `y` the tail of the reduced argument.
#[inline(always)]
fn kernel_sin(x: f64, y: f64) -> f64 {
    let z = x * x;
    let w = z * z;
    let r = S2 + z * (S3 + z * S4) + z * w * (S5 + z * S6);
    let v = z * x;
    x - ((z * (0.5 * y - v * r) - y) - v * S1)
}

/// `cos(x + y)` for `|x| ≤ π/4`.
#[inline(always)]
fn kernel_cos(x: f64, y: f64) -> f64 {
    let z = x * x;
    let w = z * z;
    let r = z * (C1 + z * (C2 + z * C3)) + w * w * (C4 + z * (C5 + z * C6));
    let hz = 0.5 * z;
    let w = 1.0 - hz;
    w + (((1.0 - w) - hz) + (z * r - x * y))
}

/// Biased exponent of `v`.
#[inline(always)]
fn exponent(v: f64) -> i64 {
    ((v.to_bits() >> 52) & 0x7ff) as i64
}

/// `(sin x, cos x)`, each within one unit in the last place (non-finite `x` gives NaNs, like
/// [`f64::sin_cos`]).
#[inline(always)]
pub fn sin_cos(x: f64) -> (f64, f64) {
    if x.abs() <= FRAC_PI_4 {
        let z = x * x;
        let r = S2 + z * (S3 + z * S4) + z * (z * z) * (S5 + z * S6);
        return (x + z * x * (S1 + z * r), kernel_cos(x, 0.0));
    }
    if x.is_nan() || x.abs() >= MEDIUM {
        return x.sin_cos();
    }
    // x = n·π/2 + (y0 + y1), rounds 2 and 3 only under heavy cancellation.
    let f = (x * FRAC_2_PI).round();
    let n = f as i64;
    let mut r = x - f * PIO2_1;
    let mut w = f * PIO2_1T;
    let mut y0 = r - w;
    let ex = exponent(x);
    // Each further round subtracts the next part of π/2 while the result has lost more than
    // `bits` of the argument's exponent to cancellation.
    for (p, pt, bits) in [(PIO2_2, PIO2_2T, 16), (PIO2_3, PIO2_3T, 49)] {
        if ex - exponent(y0) <= bits {
            break;
        }
        let t = r;
        w = f * p;
        r = t - w;
        w = f * pt - ((t - r) - w);
        y0 = r - w;
    }
    let y1 = (r - y0) - w;
    let (s, c) = (kernel_sin(y0, y1), kernel_cos(y0, y1));
    match n & 3 {
        0 => (s, c),
        1 => (c, -s),
        2 => (-s, -c),
        _ => (-c, s),
    }
}

/// Largest increment `|x − x0|` that [`sin_cos_near`] rotates by; beyond it, [`sin_cos`].
pub const NEAR: f64 = 0.0625;

/// `(sin x, cos x)` from `(s0, c0) = (sin x0, cos x0)` of a nearby angle: for `d = x − x0` with
/// `|d| ≤ 1/16` by the angle-sum formulas `sin x = s0 + (s0·(cos d − 1) + c0·sin d)`,
/// `cos x = c0 + (c0·(cos d − 1) − s0·sin d)`, with `sin d` and `cos d − 1` from their Taylor
/// series to `d¹¹` and `d¹⁰` (truncation below `|d|¹²/12! < 8e-24`); otherwise (and for
/// non-finite arguments, whose `d` is not a number) [`sin_cos`] of `x`. With `s0`, `c0` from
/// [`sin_cos`] the absolute error stays within `2·2⁻⁵³` (one in 400,000 random cases of
/// crates/exompc/tests/model.rs against `f64::sin_cos`).
#[inline(always)]
pub fn sin_cos_near(x: f64, x0: f64, s0: f64, c0: f64) -> (f64, f64) {
    let d = x - x0;
    if d.abs() > NEAR || d.is_nan() {
        return sin_cos(x);
    }
    let z = d * d;
    // sin d = d + d·z·(−1/3! + z(1/5! + z(−1/7! + z(1/9! − z/11!)))).
    let sd = d + d
        * z
        * (-1.666_666_666_666_666_6e-1
            + z * (8.333_333_333_333_333e-3
                + z * (-1.984_126_984_126_984e-4
                    + z * (2.755_731_922_398_589e-6 - z * 2.505_210_838_544_172e-8))));
    // cos d − 1 = z·(−1/2 + z(1/4! + z(−1/6! + z(1/8! − z/10!)))).
    let cm1 = z
        * (-0.5
            + z * (4.166_666_666_666_666_4e-2
                + z * (-1.388_888_888_888_889e-3
                    + z * (2.480_158_730_158_730_2e-5 - z * 2.755_731_922_398_589e-7))));
    (s0 + (s0 * cm1 + c0 * sd), c0 + (c0 * cm1 - s0 * sd))
}
