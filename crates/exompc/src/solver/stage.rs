//! The stage operations of the Riccati recursion, written once for the stage QP
//! ([`super::RiccatiQp`], its any-size path) and the scenario tree ([`super::TreeQp`], which
//! runs the same recursion per scenario and adds the coupling of the shared inputs).
//!
//! Blocks are column-major slices (`A` is `nx × nx`, `B` `nx × nu`, `P` `nx × nx` symmetric,
//! `S̄` and `K` `nu × nx`). Every sum runs in one fixed order, so a caller gets the same bits
//! whichever solver it is in. Callers pass `nx`, `nu` as constants where they can (the NMPC's
//! 1-DOF and 2-DOF stage sizes): the functions are inlined and the loops unrolled.

use super::cholesky::{chol_solve, cholesky};
use super::SolverError;

/// Checks a solver's stage dimensions: `nx, nu, np ≥ 1`, `1 ≤ nc ≤ np`.
pub(super) fn check_dims(nx: usize, nu: usize, np: usize, nc: usize) -> Result<(), SolverError> {
    for (what, value, ok, allowed) in [
        ("nx", nx, nx >= 1, "at least 1"),
        ("nu", nu, nu >= 1, "at least 1"),
        ("np", np, np >= 1, "at least 1"),
        ("nc", nc, nc >= 1 && nc <= np, "1 ≤ nc ≤ np"),
    ] {
        dim(what, value, ok, allowed)?;
    }
    Ok(())
}

/// `Ok` when `ok`, else the dimension error naming `what = value` and the allowed range.
pub(super) fn dim(
    what: &'static str,
    value: usize,
    ok: bool,
    allowed: &'static str,
) -> Result<(), SolverError> {
    if ok {
        Ok(())
    } else {
        Err(SolverError::InvalidDimension {
            what,
            value,
            allowed,
        })
    }
}

/// `out = P X` for the symmetric `nx × nx` `P` and an `nx × m` `X` (`P A`, `P B`).
#[inline(always)]
pub(super) fn p_times(nx: usize, m: usize, p: &[f64], x: &[f64], out: &mut [f64]) {
    for c in 0..m {
        for rr in 0..nx {
            let mut s = 0.0;
            for k in 0..nx {
                s += p[k * nx + rr] * x[c * nx + k];
            }
            out[c * nx + rr] = s;
        }
    }
}

/// `out = init + Bᵀ X` (`nu × m`) for `B` `nx × nu` and `X` `nx × m`, `init` zero when `None`:
/// `R + Bᵀ (P B)` and `S̄ = Bᵀ (P A)`.
#[inline(always)]
pub(super) fn bt_times(
    nx: usize,
    nu: usize,
    m: usize,
    init: Option<&[f64]>,
    b: &[f64],
    x: &[f64],
    out: &mut [f64],
) {
    for c in 0..m {
        for rr in 0..nu {
            let mut s = match init {
                Some(r) => r[c * nu + rr],
                None => 0.0,
            };
            for k in 0..nx {
                s += b[rr * nx + k] * x[c * nx + k];
            }
            out[c * nu + rr] = s;
        }
    }
}

/// `out = Aᵀ X` (`nx × m`) for `A` `nx × nx` and `X` `nx × m` (the tree's `C_j = Aᵀ[P B, C]`).
#[inline(always)]
pub(super) fn at_times(nx: usize, m: usize, a: &[f64], x: &[f64], out: &mut [f64]) {
    for c in 0..m {
        for rr in 0..nx {
            let mut s = 0.0;
            for k in 0..nx {
                s += a[rr * nx + k] * x[c * nx + k];
            }
            out[c * nx + rr] = s;
        }
    }
}

/// The cost-to-go update `P_j = Q + Aᵀ (P A) [+ S̄ᵀ K]` on the upper triangle, mirrored, from
/// `pa = P_{j+1} A`; `gain` is `(S̄, K)` of a stage with a private input.
#[inline(always)]
pub(super) fn cost_to_go(
    nx: usize,
    nu: usize,
    q: &[f64],
    a: &[f64],
    pa: &[f64],
    gain: Option<(&[f64], &[f64])>,
    pj: &mut [f64],
) {
    for c in 0..nx {
        for rr in 0..=c {
            let mut s = q[c * nx + rr];
            for k in 0..nx {
                s += a[rr * nx + k] * pa[c * nx + k];
            }
            if let Some((sb, kg)) = gain {
                for i in 0..nu {
                    s += sb[rr * nu + i] * kg[c * nu + i];
                }
            }
            pj[c * nx + rr] = s;
            pj[rr * nx + c] = s;
        }
    }
}

/// Factorises the reduced input Hessian `L Lᵀ = R + Bᵀ P B` (given in `l`, overwritten) and
/// writes the gain `K = −(R + Bᵀ P B)⁻¹ S̄`; `false` when not numerically positive definite.
/// With `adj` (two inputs, Gauss–Newton stages of [`super::RiccatiQp`]) the gain comes from the
/// adjugate, whose `[a, b, c, 1/(ac − b²)]` is stored there for the sweeps; otherwise from the
/// factor's substitutions.
#[inline(always)]
pub(super) fn stage_gain(
    nx: usize,
    nu: usize,
    l: &mut [f64],
    sb: &[f64],
    kg: &mut [f64],
    adj: Option<&mut [f64]>,
) -> bool {
    let m = [l[0], l[nu * nu / 2], l[nu * nu - 1]];
    if !cholesky(l, nu) {
        return false;
    }
    match adj {
        Some(store) if nu == 2 => {
            let a = adjugate_2x2(m);
            store.copy_from_slice(&a);
            gain_2x2(&a, sb, kg);
        }
        _ => {
            for c in 0..nx {
                let col = &mut kg[c * nu..(c + 1) * nu];
                for rr in 0..nu {
                    col[rr] = -sb[c * nu + rr];
                }
                chol_solve(l, nu, col);
            }
        }
    }
    true
}

/// The feed-forward term of a stage, `k = −(R + Bᵀ P B)⁻¹ (lin_u + Bᵀ p)` from the next
/// costate `p`; `factor` is the Cholesky factor of `R + Bᵀ P B` and, for the adjugate solve
/// (see [`stage_gain`]), its adjugate.
#[inline(always)]
pub(super) fn feed_forward(
    nx: usize,
    nu: usize,
    b: &[f64],
    lin_u: &[f64],
    p: &[f64],
    factor: (&[f64], Option<&[f64]>),
    k: &mut [f64],
) {
    let (l, adj) = factor;
    for i in 0..nu {
        let mut s = lin_u[i];
        for t in 0..nx {
            s += b[i * nx + t] * p[t];
        }
        k[i] = -s;
    }
    match adj {
        Some(adj) if nu == 2 => {
            let (k0, k1) = neg_adjugate_solve(adj, -k[0], -k[1]);
            k[0] = k0;
            k[1] = k1;
        }
        _ => chol_solve(l, nu, k),
    }
}

/// The costate of the backward vector sweep, `p_j = lin_x + Aᵀ p_{j+1} [+ S̄ᵀ k]`; `gain` is
/// `(S̄, k)` of a stage with a private input.
#[inline(always)]
pub(super) fn costate(
    nx: usize,
    nu: usize,
    a: &[f64],
    lin_x: &[f64],
    p: &[f64],
    gain: Option<(&[f64], &[f64])>,
    pj: &mut [f64],
) {
    for c in 0..nx {
        let mut s = lin_x[c];
        for t in 0..nx {
            s += a[c * nx + t] * p[t];
        }
        if let Some((sb, kf)) = gain {
            for i in 0..nu {
                s += sb[c * nu + i] * kf[i];
            }
        }
        pj[c] = s;
    }
}

/// `out = A x` (the forward sweep's free response).
#[inline(always)]
pub(super) fn a_times(nx: usize, a: &[f64], x: &[f64], out: &mut [f64]) {
    for rr in 0..nx {
        let mut s = 0.0;
        for c in 0..nx {
            s += a[c * nx + rr] * x[c];
        }
        out[rr] = s;
    }
}

/// Input `i` of the forward sweep, `u_i = k_i + (K x)_i`.
#[inline(always)]
pub(super) fn feedback(nx: usize, nu: usize, i: usize, kff: f64, kg: &[f64], x: &[f64]) -> f64 {
    let mut s = kff;
    for c in 0..nx {
        s += kg[c * nu + i] * x[c];
    }
    s
}

/// `out += B[:, i] v` (input `i` into the next state).
#[inline(always)]
pub(super) fn add_input(nx: usize, b: &[f64], i: usize, v: f64, out: &mut [f64]) {
    for rr in 0..nx {
        out[rr] += b[i * nx + rr] * v;
    }
}

/// The gain `K = −M⁻¹ S̄` of a two-input stage (`M = [[a, b], [b, c]]` given as `[a, b, c]`,
/// positive definite: checked by the caller's [`cholesky`]; `S̄`, `K` column-major `2 × nx`) by
/// the adjugate, `M⁻¹ = [[c, −b], [−b, a]] / (ac − b²)`: one division and two multiply-adds deep
/// from `M`, where the Cholesky factor and its substitutions are a chain of two square roots,
/// three divisions and six multiply-adds (the Riccati recursion runs through it at every stage).
/// Equal to the factor's solve to rounding; the factor is still kept for the sweeps. Used for
/// the Gauss–Newton QPs (no cross terms); the exact Hessian's stages (whose `M` may be close to
/// singular before the inertia correction) keep the factor's substitutions: with the adjugate
/// one exact-Hessian test instance (tests/exact_hessian.rs, 2-DOF n = 3, case 6) took 5
/// iterations against the dense back-end's 4 at KKT tolerance 1e-10.
#[inline(always)]
pub(super) fn gain_2x2(adj: &[f64; 4], sb: &[f64], kg: &mut [f64]) {
    for (k, s) in kg.chunks_exact_mut(2).zip(sb.chunks_exact(2)) {
        let (k0, k1) = neg_adjugate_solve(adj, s[0], s[1]);
        k[0] = k0;
        k[1] = k1;
    }
}

/// `[a, b, c, 1/(ac − b²)]` of `M = [[a, b], [b, c]]` given as `[a, b, c]`.
#[inline(always)]
pub(super) fn adjugate_2x2(m: [f64; 3]) -> [f64; 4] {
    let [a, b, c] = m;
    [a, b, c, 1.0 / (a * c - b * b)]
}

/// `−M⁻¹ s` by the adjugate of [`adjugate_2x2`] (three operations deep from `s`; used by the
/// gain and, with the same `M`, by the sweeps' feed-forward terms).
#[inline(always)]
pub(super) fn neg_adjugate_solve(adj: &[f64], s0: f64, s1: f64) -> (f64, f64) {
    let (a, b, c, idet) = (adj[0], adj[1], adj[2], adj[3]);
    ((b * s1 - c * s0) * idet, (b * s0 - a * s1) * idet)
}

/// `Σ ½ wᵣ M_{rc} w_c` for the `n × n` block `M` (column-major), summed from zero.
#[inline(always)]
pub(super) fn quad(w: &[f64], m: &[f64], n: usize) -> f64 {
    let mut f = 0.0;
    for c in 0..n {
        for rr in 0..n {
            f += 0.5 * w[rr] * m[c * n + rr] * w[c];
        }
    }
    f
}

/// `$body` with `$nx`, `$nu` bound to the stage size, as constants for the NMPC's stage sizes
/// (1-DOF `3 × 1`, 2-DOF `6 × 2`: the inlined stage operations are unrolled and their bounds
/// checks removed), as variables for any other.
macro_rules! with_stage_size {
    (($x:expr, $u:expr), |$nx:ident, $nu:ident| $body:expr) => {
        match ($x, $u) {
            (3, 1) => {
                let ($nx, $nu) = (3usize, 1usize);
                $body
            }
            (6, 2) => {
                let ($nx, $nu) = (6usize, 2usize);
                $body
            }
            ($nx, $nu) => $body,
        }
    };
}
pub(super) use with_stage_size;
