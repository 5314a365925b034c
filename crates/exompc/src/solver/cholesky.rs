//! Small dense Cholesky factorisation and solve (column-major, in place), shared by the stage
//! recursions (`riccati.rs`, `arrowhead.rs`) and the active-set loop on their bounds
//! (`active_set.rs`).

#[cfg(not(feature = "std"))]
use crate::math::Float;

/// In-place lower Cholesky factor of the `n × n` column-major `m` (upper part ignored).
/// Returns `false` unless the matrix is numerically positive definite.
/// The stage sizes of the NMPC (`n = 1, 2`) get their own unrolled copy of the same arithmetic.
#[inline]
pub(super) fn cholesky(m: &mut [f64], n: usize) -> bool {
    match n {
        1 => cholesky_n(m, 1),
        2 => cholesky_n(m, 2),
        _ => cholesky_n(m, n),
    }
}

#[inline(always)]
fn cholesky_n(m: &mut [f64], n: usize) -> bool {
    let m = &mut m[..n * n];
    let mut maxd: f64 = 0.0;
    for i in 0..n {
        maxd = maxd.max(m[i * n + i].abs());
    }
    for j in 0..n {
        let mut d = m[j * n + j];
        for k in 0..j {
            d -= m[k * n + j] * m[k * n + j];
        }
        if d.is_nan() || d <= 1e-14 * maxd || !d.is_finite() {
            return false;
        }
        let d = d.sqrt();
        m[j * n + j] = d;
        for i in j + 1..n {
            let mut s = m[j * n + i];
            for k in 0..j {
                s -= m[k * n + i] * m[k * n + j];
            }
            m[j * n + i] = s / d;
        }
    }
    true
}

/// Solves `L Lᵀ x = b` in place with the factor of [`cholesky`], multiplying by the
/// reciprocals `1/L_ii` (one division per diagonal entry, shared by the two triangular solves and
/// hoisted out of a caller's loop over right-hand sides; the substitutions' chains then hold no
/// division). Unrolled for `n = 1, 2` like [`cholesky`] (same arithmetic).
#[inline]
pub(super) fn chol_solve(l: &[f64], n: usize, b: &mut [f64]) {
    match n {
        1 => chol_solve_n(l, 1, b),
        2 => chol_solve_n(l, 2, b),
        _ => chol_solve_n(l, n, b),
    }
}

#[inline(always)]
fn chol_solve_n(l: &[f64], n: usize, b: &mut [f64]) {
    let (l, b) = (&l[..n * n], &mut b[..n]);
    for i in 0..n {
        let mut s = b[i];
        for k in 0..i {
            s -= l[k * n + i] * b[k];
        }
        b[i] = s * (1.0 / l[i * n + i]);
    }
    for i in (0..n).rev() {
        let mut s = b[i];
        for k in i + 1..n {
            s -= l[i * n + k] * b[k];
        }
        b[i] = s * (1.0 / l[i * n + i]);
    }
}
