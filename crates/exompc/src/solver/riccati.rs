//! Structure-exploiting QP for optimal-control stages: a Riccati factorisation (as in HPIPM)
//! inside a Goldfarb–Idnani dual active-set method.
//!
//! The QP is the linear-quadratic optimal control problem
//!
//! ```text
//! min  Σ_{j=0}^{Nc−1} ½ u_jᵀ R_j u_j + u_jᵀ S_j x_j + g_{u,j}ᵀ u_j  +  Σ_{j=1}^{Np} ½ x_jᵀ Q_j x_j + g_{x,j}ᵀ x_j
//! s.t. x_0 = 0,  x_{j+1} = A_j x_j + B_j u_j   (no input for j ≥ Nc),
//!      lo ≤ (u, x) ≤ hi   component-wise (entries may be ±∞),
//! ```
//!
//! the step-space QP of one Gauss–Newton SQP iteration of the paper's eq. 7 written in
//! multiple-shooting stages (state `x = [q, qd, T]`, input `dT`, so the cumulative torque bound of
//! eq. 8 is a state box and the rate bound of eq. 9 an input box; see `control::ocp`).
//!
//! The reduced Hessian `H` (in the inputs) is factorised once per QP by the backward Riccati
//! recursion, `O(Np·(nx+nu)³)`: `R̃ = R + BᵀPB`, `S̄ = S + BᵀPA`, `K = −R̃⁻¹S̄`,
//! `P ← Q + AᵀPA + S̄ᵀK` (the cross terms `S_j` come from the exact Hessian; the Gauss–Newton
//! QP has `S = 0`, which takes exactly the recursion without them). The unconstrained minimiser is one vector sweep (backward and
//! forward, `O(Np·(nx+nu)²)`): if it satisfies every bound, that is the answer. Otherwise the
//! dual active-set method of Goldfarb and Idnani adds the most violated bound; each addition costs
//! one more vector sweep (`H⁻¹ n` for the entering normal `n`) plus a `k×k` Cholesky of the
//! active set's Schur complement `N_Wᵀ H⁻¹ N_W`. The iterates are exactly those of the dense
//! Goldfarb–Idnani method on the condensed QP (same `H`, `g`, constraints), so the solution agrees
//! with [`super::DenseQp`] to rounding.

use super::active_set::{box_dual_from_fields, solve_box, BoxWork};
use super::cholesky::chol_solve;
use super::qp::{QpInfo, QpSettings, QpStatus};
use super::stage::{self, neg_adjugate_solve, RiccatiFactor};
use super::stage_data::{StageDims, StageQpData};
use super::SolverError;
use alloc::{vec, vec::Vec};
use nalgebra::{SMatrix, SVector};

/// The stage-structured QP described in the module documentation, with all workspace allocated
/// at construction: its [`StageQpData`] (one scenario, no shared inputs; trajectory vectors
/// `[u_0, …, u_{Nc−1}, x_1, …, x_{Np}]`) with the cross terms `S_j` beside it, and the factor.
#[derive(Debug, Clone)]
pub struct RiccatiQp {
    /// Dynamics, stage costs, linear term and bounds (`qp.a` reads `qp.data.a`).
    pub data: StageQpData,
    /// Cross terms `S_j` of the stage cost `u_jᵀ S_j x_j`, `j = 0..Nc`, each `nu × nx`
    /// column-major (zero by default; `S_0` multiplies `x_0 = 0`). Used by the exact-Hessian SQP
    /// (`control::ocp`); all zero gives exactly the factorisation without cross terms.
    pub s: Vec<f64>,
    settings: QpSettings,
    /// The Riccati factor and the sweeps' workspace.
    f: RiccatiFactor,
    /// `[a, b, c, 1/(ac − b²)]` of each two-input stage's `M = [[a, b], [b, c]]` (Gauss–Newton
    /// factorisations, see [`neg_adjugate_solve`]).
    madj: Vec<f64>,
    /// Solution, multipliers and active set.
    w: BoxWork,
    /// The data of the last factorisation has the held-input form
    /// ([`Self::held_input_structure`]); the sweeps then skip its zero and identity blocks.
    held: bool,
    /// Some cross term `S_j` of the last factorisation is nonzero.
    cross: bool,
    /// The owner writes only data of the held-input form (see
    /// [`Self::assume_held_input_form`]): the factorisation skips detecting it.
    held_known: bool,
    /// The owner writes only finite `A_j`, `B_j`, `Q_j`, `S_j` (see
    /// [`Self::assume_finite_stage_data`]): `solve` scans only `R`, `g` and the bounds.
    finite_known: bool,
}

impl RiccatiQp {
    /// A solver for `np ≥ 1` stages of state dimension `nx ≥ 1`, of which the first
    /// `1 ≤ nc ≤ np` have an input of dimension `nu ≥ 1`.
    pub fn new(
        nx: usize,
        nu: usize,
        np: usize,
        nc: usize,
        settings: QpSettings,
    ) -> Result<Self, SolverError> {
        settings.validate()?;
        let dims = StageDims {
            nx,
            nu,
            np,
            nc,
            nr: 0,
            ns: 1,
        };
        let data = StageQpData::new(dims)?;
        let len = data.len();
        // At most nc·nu linearly independent active constraints; one spare for the entering one.
        let cap = nc * nu + 1;
        Ok(Self {
            data,
            s: vec![0.0; nc * nu * nx],
            settings,
            f: RiccatiFactor::new(dims),
            madj: vec![0.0; nc * 4],
            w: BoxWork::new(len, cap),
            held: false,
            cross: false,
            held_known: false,
            finite_known: false,
        })
    }

    /// Index of input component `i` of stage `j < Nc` in trajectory layout.
    pub fn u_index(&self, j: usize, i: usize) -> usize {
        self.data.u_index(0, j, i)
    }

    /// Index of component `i` of state `x_j`, `1 ≤ j ≤ Np`, in trajectory layout.
    pub fn x_index(&self, j: usize, i: usize) -> usize {
        self.data.x_index(0, j, i)
    }

    /// Largest diagonal entry of the Gram part `Bᵀ V B` of the condensed Hessian (in the
    /// inputs) of the current data, the condensed Hessian without `R`: for input `(j, k)`,
    /// `(B_jᵀ V_j B_j)_kk` with `V_{Np−1} = Q_{Np}`, `V_j = Q_{j+1} + A_{j+1}ᵀ V_{j+1} A_{j+1}`
    /// (as [`super::TreeQp::max_condensed_diagonal`], which adds `R`). Uses the factor
    /// workspace (call before [`Self::solve`]); `O(Np·nx³)`.
    pub fn max_condensed_gram_diagonal(&mut self) -> f64 {
        let (nx, nu) = (self.data.dims.nx, self.data.dims.nu);
        let mut maxd: f64 = 0.0;
        self.f
            .condensed_diagonal((nx, nu), &self.data, 0, |_, _, d| maxd = maxd.max(d));
        maxd
    }

    /// Declares that every `A_j`, `B_j` this solver will be given has the held-input form of
    /// [`Self::held_input_structure`] (the NMPC's stages, `control::ocp`, which write it by
    /// construction): factorisations then use the held-input kernels without comparing the data
    /// (24 comparisons a stage). Only for the stage sizes with those kernels (`nx × nu` = 3 × 1,
    /// 6 × 2); ignored for others. Debug builds still check the form.
    pub(crate) fn assume_held_input_form(&mut self) {
        self.held_known = matches!((self.data.dims.nx, self.data.dims.nu), (3, 1) | (6, 2));
    }

    /// Declares that the `A_j`, `B_j`, `Q_j` and `S_j` this solver will be given are always
    /// finite (the NMPC's stages, `control::ocp`: linearisations are used only when every entry
    /// is finite, and curvature blocks only when finite): `solve` then skips scanning them
    /// (1,920 entries a QP at Np = Nc = 20 with two joints); `R`, `g` and the bounds are still
    /// checked. Debug builds still check.
    pub(crate) fn assume_finite_stage_data(&mut self) {
        self.finite_known = true;
    }

    /// Factorises the reduced Hessian by the backward Riccati recursion. Returns `false` when a
    /// reduced input Hessian `R + BᵀPB` is not numerically positive definite.
    fn factor(&mut self) -> bool {
        self.cross = any_nonzero(&self.s);
        // The NMPC's stage sizes (1-DOF, 2-DOF) as constants: unrolled, bounds checks removed.
        let detect = |qp: &Self| match (qp.data.dims.nx, qp.data.dims.nu) {
            (3, 1) => qp.held_input_structure::<3, 1>(),
            (6, 2) => qp.held_input_structure::<6, 2>(),
            _ => false,
        };
        self.held = if self.held_known {
            debug_assert!(detect(self), "data not of the held-input form");
            true
        } else {
            detect(self)
        };
        match (self.data.dims.nx, self.data.dims.nu) {
            (3, 1) if self.held => self.factor_fixed::<3, 1, true>(),
            (6, 2) if self.held => self.factor_fixed::<6, 2, true>(),
            (3, 1) => self.factor_fixed::<3, 1, false>(),
            (6, 2) => self.factor_fixed::<6, 2, false>(),
            (nx, nu) => self.factor_dims(nx, nu),
        }
    }

    /// Whether every stage has the NMPC's held-input form (`control::ocp`): the last `NU` state
    /// components are the input accumulated so far, `A_j = [[F_j, G_j], [0, I]]`, and
    /// `B_j = [G_j; I]` is the last `NU` columns of `A_j` (compared exactly: the OCP writes
    /// the same numbers into both).
    fn held_input_structure<const NX: usize, const NU: usize>(&self) -> bool {
        let ns = NX - NU;
        let n2 = NX * NX;
        // Branch-free within a stage (every comparison is made; the answer is the same).
        for j in 0..self.data.dims.np {
            let a = &self.data.a[j * n2..(j + 1) * n2];
            let mut differ = false;
            for c in 0..NX {
                for r in ns..NX {
                    let want = if c == r { 1.0 } else { 0.0 };
                    differ |= a[c * NX + r] != want;
                }
            }
            if j < self.data.dims.nc {
                let b = &self.data.b[j * NX * NU..(j + 1) * NX * NU];
                for (bv, av) in b.iter().zip(&a[ns * NX..]) {
                    differ |= bv != av;
                }
            }
            if differ {
                return false;
            }
        }
        true
    }

    /// The Riccati recursion with fixed-size blocks on the stack for the NMPC's `nx × nu`
    /// stages: `P_j = Q_{j−1} + A_jᵀ P_{j+1} A_j + S̄_jᵀ K_j`, `S̄_j = B_jᵀ P_{j+1} A_j`,
    /// `K_j = −(R_j + B_jᵀ P_{j+1} B_j)⁻¹ S̄_j`. In general form every sum runs in the order of
    /// [`RiccatiFactor::own_stages`], so the factor is identical to the last bit (nalgebra's
    /// `P A`, `P B`, `Bᵀ(PA)` accumulate column by column from zero like the slice loops). With
    /// `HELD` (the held-input form of [`Self::held_input_structure`]) the stage's products come
    /// from the congruence `W = Aᵀ P A` that skips the zero and identity blocks of `A_j`, with
    /// `Bᵀ P A`, `Bᵀ P B` read off `W` (about half the multiply-adds of the general stage;
    /// equal to it to rounding, unit test against the general recursion).
    fn factor_fixed<const NX: usize, const NU: usize, const HELD: bool>(&mut self) -> bool {
        let StageDims { np, nc, .. } = self.data.dims;
        let n2 = NX * NX;
        let mut p = SMatrix::<f64, NX, NX>::from_column_slice(&self.data.q[(np - 1) * n2..np * n2]);
        for j in (0..np).rev() {
            let a = SMatrix::<f64, NX, NX>::from_column_slice(&self.data.a[j * n2..(j + 1) * n2]);
            // Held: `W = Aᵀ P A`; general: `P A` (`Aᵀ (P A)` is summed in the update below).
            let m = if HELD {
                held_congruence::<NX, NU>(&p, &a)
            } else {
                p * a
            };
            let mut sb = SMatrix::<f64, NU, NX>::zeros();
            let mut kg = SMatrix::<f64, NU, NX>::zeros();
            if j < nc {
                sb = self.input_blocks::<NX, NU, HELD>(j, &p, &m);
                if self.cross {
                    self.add_cross::<NX, NU>(j, &mut sb);
                }
                match self.stage_gain(j, &sb) {
                    Some(k) => kg = k,
                    None => return false,
                }
            }
            if j == 0 {
                break;
            }
            let qj = &self.data.q[(j - 1) * n2..j * n2];
            riccati_update(&mut p, j < nc, &sb, &kg, |r, c| {
                let mut s = qj[c * NX + r];
                if HELD {
                    s += m[(r, c)];
                } else {
                    for k in 0..NX {
                        s += a[(k, r)] * m[(k, c)];
                    }
                }
                s
            });
        }
        all_finite(&self.f.lchol) && all_finite(&self.f.kgain)
    }

    /// The input blocks of stage `j` from `P = P_{j+1}` and the stage product `m` of
    /// [`Self::factor_fixed`]: writes `R_j + Bᵀ P B` into `lchol[j]` and returns
    /// `S̄ = Bᵀ P A`. Held form: `B = [G; I]` is the last `NU` columns of `A`, so both are rows
    /// `ns..` of `W = m`; general: `Bᵀ (P B)` and `Bᵀ (P A)`.
    #[inline(always)]
    fn input_blocks<const NX: usize, const NU: usize, const HELD: bool>(
        &mut self,
        j: usize,
        p: &SMatrix<f64, NX, NX>,
        m: &SMatrix<f64, NX, NX>,
    ) -> SMatrix<f64, NU, NX> {
        let rj = &self.data.r[j * NU * NU..(j + 1) * NU * NU];
        let ls = &mut self.f.lchol[j * NU * NU..(j + 1) * NU * NU];
        if HELD {
            let ns = NX - NU;
            for c in 0..NU {
                for r in 0..NU {
                    ls[c * NU + r] = rj[c * NU + r] + m[(ns + r, ns + c)];
                }
            }
            let mut sb = SMatrix::<f64, NU, NX>::zeros();
            for c in 0..NX {
                for i in 0..NU {
                    sb[(i, c)] = m[(ns + i, c)];
                }
            }
            sb
        } else {
            let b = SMatrix::<f64, NX, NU>::from_column_slice(
                &self.data.b[j * NX * NU..(j + 1) * NX * NU],
            );
            let pb = p * b;
            for c in 0..NU {
                for rr in 0..NU {
                    let mut s = rj[c * NU + rr];
                    for k in 0..NX {
                        s += b[(k, rr)] * pb[(k, c)];
                    }
                    ls[c * NU + rr] = s;
                }
            }
            b.tr_mul(m)
        }
    }

    /// `S̄ ← S̄ + S_j` (the stage cross term).
    #[inline(always)]
    fn add_cross<const NX: usize, const NU: usize>(&self, j: usize, sb: &mut SMatrix<f64, NU, NX>) {
        for (v, sj) in sb
            .as_mut_slice()
            .iter_mut()
            .zip(&self.s[j * NU * NX..(j + 1) * NU * NX])
        {
            *v += sj;
        }
    }

    /// Factorises `R_j + Bᵀ P B` (written into `lchol[j]` by the caller), and stores
    /// `S̄_j = Bᵀ P A` and the gain `K_j = −(R_j + Bᵀ P B)⁻¹ S̄_j`, which it returns; `None`
    /// when the reduced input Hessian is not numerically positive definite.
    #[inline(always)]
    fn stage_gain<const NX: usize, const NU: usize>(
        &mut self,
        j: usize,
        sb: &SMatrix<f64, NU, NX>,
    ) -> Option<SMatrix<f64, NU, NX>> {
        let mut kg = SMatrix::<f64, NU, NX>::zeros();
        let adj = (NU == 2 && !self.cross).then_some(&mut self.madj[j * 4..(j + 1) * 4]);
        let ls = &mut self.f.lchol[j * NU * NU..(j + 1) * NU * NU];
        if !stage::stage_gain(NX, NU, ls, sb.as_slice(), kg.as_mut_slice(), adj) {
            return None;
        }
        self.f.sbar[j * NU * NX..(j + 1) * NU * NX].copy_from_slice(sb.as_slice());
        self.f.kgain[j * NU * NX..(j + 1) * NU * NX].copy_from_slice(kg.as_slice());
        Some(kg)
    }

    /// The Riccati recursion for any stage size ([`RiccatiFactor::own_stages`], shared with
    /// the tree).
    fn factor_dims(&mut self, nx: usize, nu: usize) -> bool {
        let cross = self.cross.then_some(&self.s[..]);
        let adj = (nu == 2 && !self.cross).then_some(&mut self.madj[..]);
        self.f.own_stages((nx, nu), &self.data, 0, cross, adj)
            && all_finite(&self.f.lchol)
            && all_finite(&self.f.kgain)
    }

    /// Minimiser of `½wᵀHw + linᵀw` over the dynamics (trajectory layout) into `out`, where
    /// `lin` is zero on every stage after `top` (inputs `u_j`, `j > top`, and states
    /// `x_j`, `j > top + 1`).
    fn sweep(&mut self, use_unit: bool, top: usize, out_is_yp: bool) {
        match (self.data.dims.nx, self.data.dims.nu, self.held) {
            (3, 1, true) => self.sweep_fixed::<3, 1, true>(use_unit, top, out_is_yp),
            (6, 2, true) => self.sweep_fixed::<6, 2, true>(use_unit, top, out_is_yp),
            (3, 1, false) => self.sweep_fixed::<3, 1, false>(use_unit, top, out_is_yp),
            (6, 2, false) => self.sweep_fixed::<6, 2, false>(use_unit, top, out_is_yp),
            (nx, nu, _) => self.sweep_dims(nx, nu, use_unit, top, out_is_yp),
        }
    }

    /// [`Self::sweep_dims`] with fixed-size blocks on the stack, in the same summation order
    /// (identical results). With `HELD` (data of the held-input form, see
    /// [`Self::held_input_structure`]) the zero and identity blocks of `A_j` are skipped (equal
    /// to rounding).
    fn sweep_fixed<const NX: usize, const NU: usize, const HELD: bool>(
        &mut self,
        use_unit: bool,
        top: usize,
        out_is_yp: bool,
    ) {
        let StageDims { np, nc, .. } = self.data.dims;
        let n2 = NX * NX;
        let off = nc * NU;
        let lin: &[f64] = if use_unit { &self.w.unit } else { &self.data.g };
        // Backward pass for the feed-forward terms.
        let xi = off + top * NX;
        let mut pn = SVector::<f64, NX>::from_column_slice(&lin[xi..xi + NX]);
        for j in top + 1..nc {
            self.f.kff[j * NU..(j + 1) * NU].fill(0.0);
        }
        for j in (0..=top).rev() {
            let mut kf = SVector::<f64, NU>::zeros();
            if j < nc {
                let b = &self.data.b[j * NX * NU..(j + 1) * NX * NU];
                for i in 0..NU {
                    let mut s = lin[j * NU + i];
                    // Held form: B = [G; I].
                    let rows = if HELD { NX - NU } else { NX };
                    for t in 0..rows {
                        s += b[i * NX + t] * pn[t];
                    }
                    if HELD {
                        s += pn[NX - NU + i];
                    }
                    kf[i] = -s;
                }
                if NU == 2 && !self.cross {
                    // The gain's adjugate (`kf` holds `−s`).
                    let (k0, k1) =
                        neg_adjugate_solve(&self.madj[j * 4..(j + 1) * 4], -kf[0], -kf[1]);
                    kf[0] = k0;
                    kf[1] = k1;
                } else {
                    chol_solve(
                        &self.f.lchol[j * NU * NU..(j + 1) * NU * NU],
                        NU,
                        kf.as_mut_slice(),
                    );
                }
                self.f.kff[j * NU..(j + 1) * NU].copy_from_slice(kf.as_slice());
            }
            if j == 0 {
                break;
            }
            let a = &self.data.a[j * n2..(j + 1) * n2];
            let xo = off + (j - 1) * NX;
            let mut next = SVector::<f64, NX>::zeros();
            for c in 0..NX {
                let mut s = lin[xo + c];
                // Held form: column c of A is [F or G column; unit vector or 0].
                let rows = if HELD { NX - NU } else { NX };
                for t in 0..rows {
                    s += a[c * NX + t] * pn[t];
                }
                if HELD && c >= NX - NU {
                    s += pn[c];
                }
                if j < nc {
                    let sb = &self.f.sbar[j * NU * NX..(j + 1) * NU * NX];
                    for i in 0..NU {
                        s += sb[c * NU + i] * kf[i];
                    }
                }
                next[c] = s;
            }
            pn = next;
        }
        // Forward pass from x_0 = 0.
        let out: &mut [f64] = if out_is_yp {
            &mut self.w.yp
        } else {
            &mut self.w.sol
        };
        let mut xs = SVector::<f64, NX>::zeros();
        for j in 0..np {
            let a = SMatrix::<f64, NX, NX>::from_column_slice(&self.data.a[j * n2..(j + 1) * n2]);
            let mut xn = if HELD {
                // [F G] xs on the top rows, the held inputs copied.
                let mut xn = SVector::<f64, NX>::zeros();
                for c in 0..NX {
                    for r in 0..NX - NU {
                        xn[r] += a[(r, c)] * xs[c];
                    }
                }
                for r in NX - NU..NX {
                    xn[r] = xs[r];
                }
                xn
            } else {
                a * xs
            };
            if j < nc {
                let kg = &self.f.kgain[j * NU * NX..(j + 1) * NU * NX];
                let b = &self.data.b[j * NX * NU..(j + 1) * NX * NU];
                for i in 0..NU {
                    let mut s = self.f.kff[j * NU + i];
                    for c in 0..NX {
                        s += kg[c * NU + i] * xs[c];
                    }
                    out[j * NU + i] = s;
                    if HELD {
                        for rr in 0..NX - NU {
                            xn[rr] += b[i * NX + rr] * s;
                        }
                        xn[NX - NU + i] += s;
                    } else {
                        for rr in 0..NX {
                            xn[rr] += b[i * NX + rr] * s;
                        }
                    }
                }
            }
            let xo = off + j * NX;
            out[xo..xo + NX].copy_from_slice(xn.as_slice());
            xs = xn;
        }
    }

    #[inline(always)]
    fn sweep_dims(&mut self, nx: usize, nu: usize, use_unit: bool, top: usize, out_is_yp: bool) {
        let StageDims { np, nc, .. } = self.data.dims;
        let n2 = nx * nx;
        let off = nc * nu;
        let lin: &[f64] = if use_unit { &self.w.unit } else { &self.data.g };
        // Backward pass for the feed-forward terms.
        let xi = off + top * nx;
        self.f.pv[(top + 1) * nx..(top + 2) * nx].copy_from_slice(&lin[xi..xi + nx]);
        for j in top + 1..nc {
            self.f.kff[j * nu..(j + 1) * nu].fill(0.0);
        }
        let adj2 = nu == 2 && !self.cross;
        for j in (0..=top).rev() {
            let (head, tail) = self.f.pv.split_at_mut((j + 1) * nx);
            let pn = &tail[..nx];
            let (su, sx) = (j * nu..(j + 1) * nu, j * nu * nx..(j + 1) * nu * nx);
            if j < nc {
                let b = &self.data.b[j * nx * nu..(j + 1) * nx * nu];
                let l = &self.f.lchol[j * nu * nu..(j + 1) * nu * nu];
                let adj = adj2.then_some(&self.madj[j * 4..(j + 1) * 4]);
                let k = &mut self.f.kff[su.clone()];
                stage::feed_forward(nx, nu, b, &lin[su.clone()], pn, (l, adj), k);
            }
            if j == 0 {
                break;
            }
            let a = &self.data.a[j * n2..(j + 1) * n2];
            let xo = off + (j - 1) * nx;
            let gain = (j < nc).then(|| (&self.f.sbar[sx], &self.f.kff[su]));
            stage::costate(nx, nu, a, &lin[xo..xo + nx], pn, gain, &mut head[j * nx..]);
        }
        // Forward pass from x_0 = 0.
        let out: &mut [f64] = if out_is_yp {
            &mut self.w.yp
        } else {
            &mut self.w.sol
        };
        self.f.xs.fill(0.0);
        for j in 0..np {
            let a = &self.data.a[j * n2..(j + 1) * n2];
            let xo = off + j * nx;
            stage::a_times(nx, a, &self.f.xs, &mut out[xo..xo + nx]);
            if j < nc {
                let kg = &self.f.kgain[j * nu * nx..(j + 1) * nu * nx];
                let b = &self.data.b[j * nx * nu..(j + 1) * nx * nu];
                for i in 0..nu {
                    let s = stage::feedback(nx, nu, i, self.f.kff[j * nu + i], kg, &self.f.xs);
                    out[j * nu + i] = s;
                    stage::add_input(nx, b, i, s, &mut out[xo..xo + nx]);
                }
            }
            self.f.xs.copy_from_slice(&out[xo..xo + nx]);
        }
    }

    /// Trajectory `H⁻¹ n` for the constraint normal `n = σ e_id` (in trajectory coordinates)
    /// into `yp`.
    fn normal_solve(&mut self, id: usize, sigma: f64) {
        let StageDims { nx, nu, nc, .. } = self.data.dims;
        self.w.unit[id] = 1.0;
        let top = if id < nc * nu {
            id / nu
        } else {
            (id - nc * nu) / nx
        };
        self.sweep(true, top, true);
        self.w.unit[id] = 0.0;
        // The sweep gives −H⁻¹ e; the normal is σ e.
        for v in self.w.yp.iter_mut() {
            *v *= -sigma;
        }
    }

    /// Objective `½wᵀHw + gᵀw` of the trajectory `w = self.w.sol`.
    fn objective(&self) -> f64 {
        match (self.data.dims.nx, self.data.dims.nu) {
            (3, 1) => self.objective_fixed::<3, 1>(),
            (6, 2) => self.objective_fixed::<6, 2>(),
            _ => self.objective_dims(),
        }
    }

    /// [`Self::objective_dims`] with fixed-size nalgebra blocks.
    fn objective_fixed<const NX: usize, const NU: usize>(&self) -> f64 {
        let off = self.data.dims.nc * NU;
        let mut f = 0.0;
        for (w, g) in self.w.sol.iter().zip(&self.data.g) {
            f += w * g;
        }
        for j in 0..self.data.dims.nc {
            let u = SVector::<f64, NU>::from_column_slice(&self.w.sol[j * NU..(j + 1) * NU]);
            let rj = SMatrix::<f64, NU, NU>::from_column_slice(
                &self.data.r[j * NU * NU..(j + 1) * NU * NU],
            );
            f += 0.5 * u.dot(&(rj * u));
            if self.cross && j > 0 {
                let sj = SMatrix::<f64, NU, NX>::from_column_slice(
                    &self.s[j * NU * NX..(j + 1) * NU * NX],
                );
                let x = SVector::<f64, NX>::from_column_slice(
                    &self.w.sol[off + (j - 1) * NX..off + j * NX],
                );
                f += u.dot(&(sj * x));
            }
        }
        for j in 0..self.data.dims.np {
            let x = SVector::<f64, NX>::from_column_slice(
                &self.w.sol[off + j * NX..off + (j + 1) * NX],
            );
            let qj = SMatrix::<f64, NX, NX>::from_column_slice(
                &self.data.q[j * NX * NX..(j + 1) * NX * NX],
            );
            f += 0.5 * x.dot(&(qj * x));
        }
        f
    }

    /// Objective `½wᵀHw + gᵀw` of the trajectory `w = self.w.sol`, any stage size.
    fn objective_dims(&self) -> f64 {
        let StageDims { nx, nu, np, nc, .. } = self.data.dims;
        let off = nc * nu;
        let mut f = 0.0;
        for (w, g) in self.w.sol.iter().zip(&self.data.g) {
            f += w * g;
        }
        for j in 0..nc {
            let u = &self.w.sol[j * nu..(j + 1) * nu];
            let rj = &self.data.r[j * nu * nu..(j + 1) * nu * nu];
            for c in 0..nu {
                for rr in 0..nu {
                    f += 0.5 * u[rr] * rj[c * nu + rr] * u[c];
                }
            }
            if self.cross && j > 0 {
                let x = &self.w.sol[off + (j - 1) * nx..off + j * nx];
                let sj = &self.s[j * nu * nx..(j + 1) * nu * nx];
                for c in 0..nx {
                    for rr in 0..nu {
                        f += u[rr] * sj[c * nu + rr] * x[c];
                    }
                }
            }
        }
        for j in 0..np {
            let x = &self.w.sol[off + j * nx..off + (j + 1) * nx];
            let qj = &self.data.q[j * nx * nx..(j + 1) * nx * nx];
            for c in 0..nx {
                for rr in 0..nx {
                    f += 0.5 * x[rr] * qj[c * nx + rr] * x[c];
                }
            }
        }
        f
    }

    /// Solves the QP with the current data. Never panics and allocates nothing; the solution is
    /// [`Self::solution`] and the multipliers [`Self::multipliers`].
    pub fn solve(&mut self) -> QpInfo {
        let finite = all_finite;
        let stages_finite = |qp: &Self| {
            finite(&qp.data.a) && finite(&qp.data.b) && finite(&qp.data.q) && finite(&qp.s)
        };
        let stages_finite = if self.finite_known {
            debug_assert!(stages_finite(self), "non-finite stage data");
            true
        } else {
            stages_finite(self)
        };
        let data_finite = stages_finite && finite(&self.data.r) && finite(&self.data.g);
        let settings = self.settings;
        let start = |qp: &mut Self| {
            let top = qp.data.dims.np - 1;
            qp.factor() && {
                qp.sweep(false, top, false);
                true
            }
        };
        match solve_box(self, &settings, data_finite, start) {
            Ok(mut info) => {
                info.objective = if info.status == QpStatus::Solved {
                    self.objective_at_solution()
                } else {
                    self.objective()
                };
                info
            }
            Err(info) => info,
        }
    }

    /// Objective at a solution: stationarity `H w + g + Eᵀν + mult = 0` (`E w = 0` the
    /// dynamics) gives `wᵀ H w = −gᵀw − multᵀw`, so `½wᵀHw + gᵀw = ½(gᵀw − multᵀw)`: one pass
    /// over the trajectory instead of the stage quadratic forms of [`Self::objective`] (equal to
    /// rounding; unit test).
    fn objective_at_solution(&self) -> f64 {
        let mut f = 0.0;
        for ((w, g), m) in self.w.sol.iter().zip(&self.data.g).zip(&self.w.mult) {
            f += w * (g - m);
        }
        0.5 * f
    }
}

/// `P ← base(r, c) + [with_input] S̄ᵀ K` on the upper triangle, mirrored: the last step of one
/// Riccati stage (`base` = `Q + Aᵀ P A` in the caller's summation order).
#[inline(always)]
fn riccati_update<const NX: usize, const NU: usize>(
    p: &mut SMatrix<f64, NX, NX>,
    with_input: bool,
    sb: &SMatrix<f64, NU, NX>,
    kg: &SMatrix<f64, NU, NX>,
    base: impl Fn(usize, usize) -> f64,
) {
    for c in 0..NX {
        for r in 0..=c {
            let mut s = base(r, c);
            if with_input {
                for i in 0..NU {
                    s += sb[(i, r)] * kg[(i, c)];
                }
            }
            p[(r, c)] = s;
            p[(c, r)] = s;
        }
    }
}

/// `Aᵀ P A` for a symmetric `P` and `A = [[F, G], [0, I]]` of the held-input form (the last `NU`
/// states are the input accumulated so far; `control::ocp`), skipping the zero and identity
/// blocks: `X = P A` (first columns `P[:, :ns] F`, last `P[:, :ns] G + P[:, ns:]`), then
/// `Aᵀ X` (rows `≥ ns` add `X[r, :]`), symmetric. About half the multiply-adds of the general
/// product; equal to it to rounding.
#[inline(always)]
pub(crate) fn held_congruence<const NX: usize, const NU: usize>(
    p: &SMatrix<f64, NX, NX>,
    a: &SMatrix<f64, NX, NX>,
) -> SMatrix<f64, NX, NX> {
    let ns = NX - NU;
    // Column by column as `X[:, c] += P[:, k] a_kc` (each entry summed in the order `k = 0, 1,
    // …` from its start value, as a dot per entry would). `X[ns.., ..ns]` feeds only the
    // lower triangle of `Aᵀ X`, which the mirror below overwrites: left at zero.
    let mut x = SMatrix::<f64, NX, NX>::zeros();
    for c in 0..ns {
        for k in 0..ns {
            let akc = a[(k, c)];
            for r in 0..ns {
                x[(r, c)] += p[(r, k)] * akc;
            }
        }
    }
    for c in ns..NX {
        for r in 0..NX {
            x[(r, c)] = p[(r, c)];
        }
        for k in 0..ns {
            let akc = a[(k, c)];
            for r in 0..NX {
                x[(r, c)] += p[(r, k)] * akc;
            }
        }
    }
    // The upper triangle, then mirrored. Computed on the full square (constant loop bounds,
    // unrolled); the lower half is overwritten by the mirror, so the result is the same.
    let mut w = SMatrix::<f64, NX, NX>::zeros();
    let at = a.transpose();
    for c in 0..NX {
        for r in 0..NX {
            let mut s = if r >= ns { x[(r, c)] } else { 0.0 };
            for k in 0..ns {
                s += at[(r, k)] * x[(k, c)];
            }
            w[(r, c)] = s;
        }
    }
    for c in 0..NX {
        for r in c + 1..NX {
            w[(r, c)] = w[(c, r)];
        }
    }
    w
}

/// Whether every entry is finite, without a branch per entry: `x − x` is 0 for a finite `x`
/// and NaN otherwise, summed in four independent lanes (vectorisable).
#[inline]
#[allow(clippy::eq_op)] // `x − x` is the test
fn all_finite(v: &[f64]) -> bool {
    let mut acc = [0.0f64; 4];
    let chunks = v.chunks_exact(4);
    let rest = chunks.remainder();
    for c in chunks {
        for l in 0..4 {
            acc[l] += c[l] - c[l];
        }
    }
    for x in rest {
        acc[0] += x - x;
    }
    (acc[0] + acc[1] + acc[2] + acc[3]) == 0.0
}

/// Whether some entry is nonzero (NaN counts as nonzero), without a branch per entry.
#[inline]
fn any_nonzero(v: &[f64]) -> bool {
    let mut acc = [false; 4];
    let chunks = v.chunks_exact(4);
    let rest = chunks.remainder();
    for c in chunks {
        for l in 0..4 {
            acc[l] |= c[l] != 0.0;
        }
    }
    for x in rest {
        acc[0] |= *x != 0.0;
    }
    acc[0] | acc[1] | acc[2] | acc[3]
}

box_dual_from_fields!(RiccatiQp);

#[cfg(test)]
mod tests {
    use super::*;
    use crate::solver::active_set::bounds_ordered;

    /// A QP with pseudo-random stage data (deterministic LCG), `Q`, `R` positive definite.
    fn random_qp(nx: usize, nu: usize, np: usize, nc: usize, seed: u64) -> RiccatiQp {
        let mut next = crate::test_rng::lcg(seed);
        let mut qp = RiccatiQp::new(nx, nu, np, nc, QpSettings::default()).unwrap();
        for v in qp
            .data
            .a
            .iter_mut()
            .chain(qp.data.b.iter_mut())
            .chain(qp.data.g.iter_mut())
        {
            *v = next();
        }
        for (blocks, n, shift) in [(&mut qp.data.q, nx, 0.0), (&mut qp.data.r, nu, 0.1)] {
            for blk in blocks.chunks_mut(n * n) {
                let l: Vec<f64> = (0..n * n).map(|_| next()).collect();
                for c in 0..n {
                    for r in 0..n {
                        let mut s = if r == c { shift } else { 0.0 };
                        for k in 0..n {
                            s += l[k * n + r] * l[k * n + c];
                        }
                        blk[c * n + r] = s;
                    }
                }
            }
        }
        qp
    }

    /// [`random_qp`] with the NMPC's held-input form: `A_j = [[F, G], [0, I]]`, `B_j = [G; I]`.
    fn random_held_qp(nx: usize, nu: usize, np: usize, nc: usize, seed: u64) -> RiccatiQp {
        let mut qp = random_qp(nx, nu, np, nc, seed);
        let ns = nx - nu;
        for j in 0..np {
            let a = &mut qp.data.a[j * nx * nx..(j + 1) * nx * nx];
            for c in 0..nx {
                for r in ns..nx {
                    a[c * nx + r] = if c == r { 1.0 } else { 0.0 };
                }
            }
            if j < nc {
                let tail = a[ns * nx..].to_vec();
                qp.data.b[j * nx * nu..(j + 1) * nx * nu].copy_from_slice(&tail);
            }
        }
        qp
    }

    /// The full and the truncated sweeps of the active-set method (`top` at the end, the middle
    /// and the start; with and without the unit right-hand side): `a` by `sweep_a`, `b` by the
    /// general slice sweep, both handed to `check` after each.
    fn each_sweep(
        a: &mut RiccatiQp,
        b: &mut RiccatiQp,
        sweep_a: impl Fn(&mut RiccatiQp, bool, usize),
        check: impl Fn(&RiccatiQp, &RiccatiQp),
    ) {
        let StageDims { nx, nu, np, .. } = a.data.dims;
        for top in [np - 1, np / 2, 0] {
            for use_unit in [false, true] {
                let id = a.len() / 2;
                for qp in [&mut *a, &mut *b] {
                    qp.w.unit.fill(0.0);
                    qp.w.unit[id] = 1.0;
                }
                sweep_a(a, use_unit, top);
                b.sweep_dims(nx, nu, use_unit, top, use_unit);
                check(a, b);
            }
        }
    }

    #[test]
    fn all_finite_finds_every_non_finite_entry() {
        for len in [0, 1, 3, 4, 5, 8, 37] {
            let v = vec![1.5; len];
            assert!(all_finite(&v));
            for i in 0..len {
                for bad in [f64::NAN, f64::INFINITY, f64::NEG_INFINITY] {
                    let mut w = v.clone();
                    w[i] = bad;
                    assert!(!all_finite(&w), "len {len}, index {i}, {bad}");
                }
            }
        }
        assert!(all_finite(&[
            f64::MAX,
            -f64::MAX,
            f64::MIN_POSITIVE,
            0.0,
            -0.0
        ]));
    }

    /// `held_congruence` equals nalgebra's general product `Aᵀ (P A)` to rounding and is exactly
    /// symmetric (random symmetric `P`, held `A`, zeros of both signs).
    #[test]
    fn held_congruence_equals_the_general_product() {
        fn run<const NX: usize, const NU: usize>(seed: u64) {
            let mut st = seed;
            let mut next = || {
                st = st
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                let v = ((st >> 11) as f64 / (1u64 << 53) as f64) * 2.0 - 1.0;
                if v.abs() < 0.05 {
                    if v < 0.0 {
                        -0.0
                    } else {
                        0.0
                    }
                } else {
                    v
                }
            };
            let ns = NX - NU;
            for _ in 0..500 {
                let mut p = SMatrix::<f64, NX, NX>::zeros();
                for c in 0..NX {
                    for r in 0..=c {
                        let v = next();
                        p[(r, c)] = v;
                        p[(c, r)] = v;
                    }
                }
                let mut a = SMatrix::<f64, NX, NX>::zeros();
                for c in 0..NX {
                    for r in 0..ns {
                        a[(r, c)] = next();
                    }
                }
                for i in ns..NX {
                    a[(i, i)] = 1.0;
                }
                let w = held_congruence::<NX, NU>(&p, &a);
                let v = a.transpose() * (p * a);
                let scale = 1.0 + p.amax() * (1.0 + a.amax()) * (1.0 + a.amax());
                assert!((w - v).amax() <= 1e-14 * NX as f64 * scale, "{w} {v}");
                assert_eq!(w, w.transpose());
            }
        }
        run::<3, 1>(11);
        run::<6, 2>(12);
        run::<4, 1>(13);
    }

    /// The branch-free scans answer as the loops they replace: `any(v != 0)` and the bound-pair
    /// test of `solve` (NaN, crossed and infinite bounds at every position).
    #[test]
    fn branch_free_scans_equal_the_loops() {
        let specials = [
            0.0,
            -0.0,
            1.0,
            -2.5,
            f64::NAN,
            f64::INFINITY,
            f64::NEG_INFINITY,
        ];
        for len in [0, 1, 3, 4, 5, 9] {
            for pos in 0..len.max(1) {
                for &x in &specials {
                    let mut v = vec![0.0; len];
                    if len > 0 {
                        v[pos] = x;
                    }
                    assert_eq!(any_nonzero(&v), v.iter().any(|e| *e != 0.0));
                    for &y in &specials {
                        let mut lo = vec![-1.0; len];
                        let mut hi = vec![1.0; len];
                        if len > 0 {
                            lo[pos] = x;
                            hi[pos] = y;
                        }
                        // The loop's two tests: NaN first, then crossed or infinite.
                        let usable = |l: &f64, h: &f64| {
                            if l.is_nan() || h.is_nan() {
                                return false;
                            }
                            !(l > h || *l == f64::INFINITY || *h == f64::NEG_INFINITY)
                        };
                        let want = lo.iter().zip(&hi).all(|(l, h)| usable(l, h));
                        assert_eq!(bounds_ordered(&lo, &hi), want, "{x} {y}");
                    }
                }
            }
        }
    }

    /// The held-input recursion equals the general one to rounding, and is only chosen for
    /// data of that form.
    #[test]
    fn held_input_factor_equals_the_general_one() {
        for (nx, nu) in [(3, 1), (6, 2)] {
            for (np, nc, seed) in [(1, 1, 4), (7, 4, 5), (12, 12, 6), (30, 30, 7)] {
                let mut a = random_held_qp(nx, nu, np, nc, seed);
                let mut b = a.clone();
                let held = match (nx, nu) {
                    (3, 1) => a.held_input_structure::<3, 1>(),
                    _ => a.held_input_structure::<6, 2>(),
                };
                assert!(held);
                // Declared held form: the same factor without the detection.
                let mut c = a.clone();
                c.assume_held_input_form();
                assert!(c.factor() && c.held);
                assert!(a.factor() && b.factor_dims(nx, nu));
                assert_eq!(
                    (&c.f.lchol, &c.f.kgain, &c.f.sbar),
                    (&a.f.lchol, &a.f.kgain, &a.f.sbar)
                );
                let close = |x: &[f64], y: &[f64]| {
                    let scale = y.iter().fold(1.0f64, |m, v| m.max(v.abs()));
                    x.iter().zip(y).all(|(u, v)| (u - v).abs() <= 1e-12 * scale)
                };
                assert!(close(&a.f.lchol, &b.f.lchol));
                assert!(close(&a.f.kgain, &b.f.kgain));
                assert!(close(&a.f.sbar, &b.f.sbar));
                assert!(a.held);
                each_sweep(
                    &mut a,
                    &mut b,
                    |a, unit, top| a.sweep(unit, top, unit),
                    |a, b| {
                        assert!(close(&a.w.sol, &b.w.sol) && close(&a.w.yp, &b.w.yp));
                        assert!(close(&a.f.kff, &b.f.kff));
                    },
                );
                // The general data of `random_qp` is not of the held form.
                let g = random_qp(nx, nu, np, nc, seed);
                let general = match (nx, nu) {
                    (3, 1) => g.held_input_structure::<3, 1>(),
                    _ => g.held_input_structure::<6, 2>(),
                };
                assert!(!general);
            }
        }
    }

    /// Declared finite stage data: the same solution, and non-finite `R` or `g` still reported.
    #[test]
    fn declared_finite_stage_data_solves_the_same_and_still_checks_r_and_g() {
        for (nx, nu, np, nc, seed) in [(3, 1, 9, 5, 21), (6, 2, 20, 20, 22)] {
            let mut a = random_held_qp(nx, nu, np, nc, seed);
            let mut next = crate::test_rng::lcg(seed);
            for k in 0..nc * nu {
                a.lo[k] = -0.05 * (1.0 + next().abs());
                a.hi[k] = 0.05 * (1.0 + next().abs());
            }
            let mut b = a.clone();
            b.assume_finite_stage_data();
            let (ia, ib) = (a.solve(), b.solve());
            assert_eq!(ia.status, QpStatus::Solved);
            assert!(a.num_active() > 0);
            assert_eq!((ia.status, ia.iterations), (ib.status, ib.iterations));
            assert_eq!((&a.w.sol, &a.w.mult), (&b.w.sol, &b.w.mult));
            for bad in [f64::NAN, f64::INFINITY] {
                let mut c = b.clone();
                c.r[0] = bad;
                assert_eq!(c.solve().status, QpStatus::NonFiniteInput);
                let mut c = b.clone();
                c.g[1] = bad;
                assert_eq!(c.solve().status, QpStatus::NonFiniteInput);
            }
        }
    }

    /// The objective from the stationarity identity equals the stage quadratic forms, with and
    /// without active bounds.
    #[test]
    fn objective_at_solution_equals_the_quadratic_form() {
        let mut with_active = 0;
        for (nx, nu) in [(3, 1), (6, 2), (4, 3)] {
            for (np, nc, seed) in [(1, 1, 1), (7, 4, 2), (12, 12, 3), (20, 9, 4)] {
                for bound in [f64::INFINITY, 0.5, 0.05] {
                    let mut qp = random_qp(nx, nu, np, nc, seed);
                    for i in 0..qp.len() {
                        qp.data.lo[i] = -bound;
                        qp.data.hi[i] = bound;
                    }
                    let info = qp.solve();
                    assert_eq!(info.status, QpStatus::Solved);
                    with_active += usize::from(qp.num_active() > 0);
                    let full = qp.objective();
                    assert!(
                        (info.objective - full).abs() <= 1e-10 * (1.0 + full.abs()),
                        "{nx}x{nu} np {np} bound {bound}: {} vs {full}",
                        info.objective
                    );
                }
            }
        }
        assert!(with_active >= 10, "{with_active}");
    }

    /// The fixed-size kernels (the NMPC's 1-DOF and 2-DOF stages) equal the general slice
    /// kernels to the last bit: factor, full sweep and the truncated sweeps of the active-set
    /// method.
    #[test]
    fn fixed_size_kernels_equal_general_ones_bitwise() {
        for (nx, nu) in [(3, 1), (6, 2)] {
            for (np, nc, seed) in [(1, 1, 1), (7, 4, 2), (12, 12, 3)] {
                let mut a = random_qp(nx, nu, np, nc, seed);
                let mut b = a.clone();
                let ok = match (nx, nu) {
                    (3, 1) => a.factor_fixed::<3, 1, false>(),
                    _ => a.factor_fixed::<6, 2, false>(),
                };
                assert!(ok && b.factor_dims(nx, nu));
                assert_eq!(a.f.lchol, b.f.lchol);
                assert_eq!(a.f.kgain, b.f.kgain);
                assert_eq!(a.f.sbar, b.f.sbar);
                each_sweep(
                    &mut a,
                    &mut b,
                    |a, unit, top| match (nx, nu) {
                        (3, 1) => a.sweep_fixed::<3, 1, false>(unit, top, unit),
                        _ => a.sweep_fixed::<6, 2, false>(unit, top, unit),
                    },
                    |a, b| {
                        assert_eq!(a.w.sol, b.w.sol);
                        assert_eq!(a.w.yp, b.w.yp);
                        assert_eq!(a.f.kff, b.f.kff);
                    },
                );
                let (oa, ob) = (a.objective(), b.objective_dims());
                assert!((oa - ob).abs() <= 1e-12 * (1.0 + ob.abs()));
            }
        }
    }
}
