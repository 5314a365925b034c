//! The stage operations of the Riccati recursion, written once for the stage QP
//! ([`super::RiccatiQp`], its any-size path) and the scenario tree ([`super::TreeQp`], which
//! runs the same recursion per scenario and adds the coupling of the shared inputs).
//!
//! Blocks are column-major slices (`A` is `nx × nx`, `B` `nx × nu`, `P` `nx × nx` symmetric,
//! `S̄` and `K` `nu × nx`). Every sum runs in one fixed order, so a caller gets the same bits
//! whichever solver it is in. Callers pass `nx`, `nu` as constants where they can (the NMPC's
//! 1-DOF and 2-DOF stage sizes): the functions are inlined and the loops unrolled.

use super::cholesky::{chol_solve, cholesky};
use super::stage_data::{StageDims, StageQpData};
use alloc::{vec, vec::Vec};

/// The factor and sweep workspace of the Riccati recursion that [`super::RiccatiQp`] and
/// [`super::TreeQp`] share (per scenario `i` and stage `j` at index `i·Nc + j`; one scenario:
/// `j`): the cost-to-go `P_j`, the reduced input Hessians' factors, `S̄_j`, the gains, and the
/// vector sweeps' costates, feed-forward terms and state.
#[derive(Debug, Clone)]
pub(super) struct RiccatiFactor {
    /// `P_j`, `j = 0..=Np`, of the scenario being factorised.
    pub pm: Vec<f64>,
    /// `P_{j+1} A_j` of the current stage.
    pub pa: Vec<f64>,
    /// `P_{j+1} B_j` of the current stage.
    pub pb: Vec<f64>,
    /// `S̄ = Bᵀ P A (+ S)` per stage.
    pub sbar: Vec<f64>,
    /// Gains `K = −(R + Bᵀ P B)⁻¹ S̄` per stage.
    pub kgain: Vec<f64>,
    /// Cholesky factors of `R + Bᵀ P B` per stage.
    pub lchol: Vec<f64>,
    /// Costates of the backward vector sweep.
    pub pv: Vec<f64>,
    /// Feed-forward terms per stage.
    pub kff: Vec<f64>,
    /// State of the forward sweep.
    pub xs: Vec<f64>,
}

impl RiccatiFactor {
    /// Workspace for the dimensions `d`.
    pub(super) fn new(d: StageDims) -> Self {
        let (nx, nu, np, stages) = (d.nx, d.nu, d.np, d.ns * d.nc);
        Self {
            pm: vec![0.0; (np + 1) * nx * nx],
            pa: vec![0.0; nx * nx],
            pb: vec![0.0; nx * nu],
            sbar: vec![0.0; stages * nu * nx],
            kgain: vec![0.0; stages * nu * nx],
            lchol: vec![0.0; stages * nu * nu],
            pv: vec![0.0; (np + 1) * nx],
            kff: vec![0.0; stages * nu],
            xs: vec![0.0; nx],
        }
    }

    /// The diagonal of the Gram part `Bᵀ V B` of the condensed Hessian (in the inputs) of
    /// scenario `i`: `each(j, k, d)` for every input stage `j < Nc` and component `k`, with
    /// `d = (B_jᵀ V_j B_j)_kk`, `V_{Np−1} = Q_{Np}`, `V_j = Q_{j+1} + A_{j+1}ᵀ V_{j+1} A_{j+1}`
    /// (`O(Np·nx³)`). Uses `pm`, `pa`, `pb`.
    #[inline(always)]
    pub(super) fn condensed_diagonal(
        &mut self,
        (nx, nu): (usize, usize),
        data: &StageQpData,
        i: usize,
        mut each: impl FnMut(usize, usize, f64),
    ) {
        let StageDims { np, nc, .. } = data.dims;
        let n2 = nx * nx;
        let ab = i * np * n2;
        let v = &mut self.pm[..n2];
        v.copy_from_slice(&data.q[ab + (np - 1) * n2..ab + np * n2]);
        for j in (0..np).rev() {
            if j + 1 < np {
                let a = &data.a[ab + (j + 1) * n2..ab + (j + 2) * n2];
                p_times(nx, nx, v, a, &mut self.pa);
                let qj = &data.q[ab + j * n2..ab + (j + 1) * n2];
                cost_to_go(nx, nu, qj, a, &self.pa, None, v);
            }
            if j < nc {
                let b = &data.b[(i * nc + j) * nx * nu..(i * nc + j + 1) * nx * nu];
                // diag(Bᵀ V B) from V B.
                p_times(nx, nu, v, b, &mut self.pb);
                for k in 0..nu {
                    let col = &b[k * nx..(k + 1) * nx];
                    let mut d = 0.0;
                    for (c, bc) in col.iter().enumerate() {
                        d += bc * self.pb[k * nx + c];
                    }
                    each(j, k, d);
                }
            }
        }
    }

    /// The backward Riccati recursion of scenario `i` over its own stages `j = Np−1 .. Nr`
    /// (one scenario: all, down to `j = 0`) from `P_{Np} = Q_{Np}`: `R̃ = R + BᵀPB`,
    /// `S̄ = BᵀPA [+ S]`, `K = −R̃⁻¹S̄`, `P_j = Q_j + AᵀPA [+ S̄ᵀK]` (`j ≥ 1`). `cross` are the
    /// cross terms `S_j` when nonzero, `adj` the two-input adjugates' store (see
    /// [`stage_gain`]). Leaves `P_{Nr}` in `pm`; `false` when an `R̃` is not numerically
    /// positive definite.
    #[inline(always)]
    pub(super) fn own_stages(
        &mut self,
        (nx, nu): (usize, usize),
        data: &StageQpData,
        i: usize,
        cross: Option<&[f64]>,
        mut adj: Option<&mut [f64]>,
    ) -> bool {
        let StageDims { np, nc, nr, .. } = data.dims;
        let n2 = nx * nx;
        let ab = i * np * n2;
        self.pm[np * n2..(np + 1) * n2].copy_from_slice(&data.q[ab + (np - 1) * n2..ab + np * n2]);
        for j in (nr..np).rev() {
            let (head, tail) = self.pm.split_at_mut((j + 1) * n2);
            let p = &tail[..n2];
            let a = &data.a[ab + j * n2..ab + (j + 1) * n2];
            p_times(nx, nx, p, a, &mut self.pa);
            let st = i * nc + j;
            let sx = st * nu * nx..(st + 1) * nu * nx;
            if j < nc {
                let b = &data.b[st * nx * nu..(st + 1) * nx * nu];
                p_times(nx, nu, p, b, &mut self.pb);
                let l = &mut self.lchol[st * nu * nu..(st + 1) * nu * nu];
                let rij = (i * (nc - nr) + j - nr) * nu * nu;
                bt_times(nx, nu, nu, Some(&data.r[rij..]), b, &self.pb, l);
                let sb = &mut self.sbar[sx.clone()];
                bt_times(nx, nu, nx, None, b, &self.pa, sb);
                if let Some(s) = cross {
                    for (v, sj) in sb.iter_mut().zip(&s[sx.clone()]) {
                        *v += sj;
                    }
                }
                let adj = adj.as_deref_mut().map(|m| &mut m[st * 4..(st + 1) * 4]);
                if !stage_gain(nx, nu, l, sb, &mut self.kgain[sx.clone()], adj) {
                    return false;
                }
            }
            if j == 0 {
                break;
            }
            let gain = (j < nc).then(|| (&self.sbar[sx.clone()], &self.kgain[sx]));
            let qj = &data.q[ab + (j - 1) * n2..ab + j * n2];
            cost_to_go(
                nx,
                nu,
                qj,
                a,
                &self.pa,
                gain,
                &mut head[j * n2..(j + 1) * n2],
            );
        }
        true
    }
}

/// `out = P X` for the symmetric `nx × nx` `P` and an `nx × m` `X` (`P A`, `P B`).
///
/// Column by column as `out[:, c] += P[:, k] X[k, c]` over contiguous columns: each entry is
/// summed from zero in the order `k = 0, 1, …`, the same sums as a dot per entry.
#[inline(always)]
pub(super) fn p_times(nx: usize, m: usize, p: &[f64], x: &[f64], out: &mut [f64]) {
    let p = &p[..nx * nx];
    for (oc, xc) in out[..nx * m]
        .chunks_exact_mut(nx)
        .zip(x[..nx * m].chunks_exact(nx))
    {
        oc.fill(0.0);
        for (pk, &xk) in p.chunks_exact(nx).zip(xc) {
            for (o, &pv) in oc.iter_mut().zip(pk) {
                *o += pv * xk;
            }
        }
    }
}

/// `Σ_k u_k v_k` summed from `init` in the order `k = 0, 1, …` (equally long columns).
#[inline(always)]
fn dot_from(init: f64, u: &[f64], v: &[f64]) -> f64 {
    let mut s = init;
    for (&a, &b) in u.iter().zip(v) {
        s += a * b;
    }
    s
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
    let b = &b[..nx * nu];
    for (c, (oc, xc)) in out[..nu * m]
        .chunks_exact_mut(nu)
        .zip(x[..nx * m].chunks_exact(nx))
        .enumerate()
    {
        for (rr, (o, bc)) in oc.iter_mut().zip(b.chunks_exact(nx)).enumerate() {
            let s = match init {
                Some(r) => r[c * nu + rr],
                None => 0.0,
            };
            *o = dot_from(s, bc, xc);
        }
    }
}

/// `out = Aᵀ X` (`nx × m`) for `A` `nx × nx` and `X` `nx × m` (the tree's `C_j = Aᵀ[P B, C]`).
#[inline(always)]
pub(super) fn at_times(nx: usize, m: usize, a: &[f64], x: &[f64], out: &mut [f64]) {
    let a = &a[..nx * nx];
    for (oc, xc) in out[..nx * m]
        .chunks_exact_mut(nx)
        .zip(x[..nx * m].chunks_exact(nx))
    {
        for (o, ac) in oc.iter_mut().zip(a.chunks_exact(nx)) {
            *o = dot_from(0.0, ac, xc);
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
        let pac = &pa[c * nx..(c + 1) * nx];
        for rr in 0..=c {
            let mut s = dot_from(q[c * nx + rr], &a[rr * nx..(rr + 1) * nx], pac);
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
