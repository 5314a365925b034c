//! Structure-exploiting QP for a scenario tree with non-anticipativity (the coupled multi-stage
//! NMPC of paper eq. 12): per-scenario Riccati recursions and a small dense block on the shared
//! inputs (a block-arrowhead factorisation), inside the Goldfarb–Idnani dual active-set method.
//!
//! `S` scenarios share the first `Nr` inputs and own the rest:
//!
//! ```text
//! min  Σ_{j<Nr} ½ s_jᵀ R̄_j s_j + ḡ_jᵀ s_j
//!      + Σ_i [ Σ_{Nr≤j<Nc} ½ u_{i,j}ᵀ R_{i,j} u_{i,j} + g_{i,j}ᵀ u_{i,j}
//!              + Σ_{j=1}^{Np} ½ x_{i,j}ᵀ Q_{i,j} x_{i,j} + g_{x,i,j}ᵀ x_{i,j} ]
//! s.t. x_{i,0} = 0,  x_{i,j+1} = A_{i,j} x_{i,j} + B_{i,j} v_{i,j},
//!      v_{i,j} = s_j (j < Nr),  u_{i,j} (Nr ≤ j < Nc),  no input (j ≥ Nc),
//!      lo ≤ (s, u, x) ≤ hi  component-wise (entries may be ±∞).
//! ```
//!
//! Factorisation (`O(S·Np·(nx+nu)³ + S·Nr·nx²·Nr·nu + (Nr·nu)³)`): each scenario's Riccati
//! recursion runs backward from `Np` to `Nr`, eliminating its private inputs; through the shared
//! stages `j < Nr` it continues with the shared inputs as parameters (cost-to-go
//! `½xᵀP_j x + xᵀC_j s + ½sᵀE_j s`, `C_j = [A_jᵀP_{j+1}B_j, A_jᵀC_{j+1}]`,
//! `E_j = [[B_jᵀP_{j+1}B_j, B_jᵀC_{j+1}], [·, E_{j+1}]]`). At `x_0 = 0` each scenario leaves a
//! quadratic `½sᵀE_{i,0}s` in the shared inputs; the sum `Σ_i E_{i,0} + R̄` is the small dense
//! (arrowhead) block, factorised by Cholesky. A solve with a right-hand side is one backward
//! vector sweep per scenario, one `Nr·nu` triangular solve and one forward sweep per scenario
//! (`O(S·Np·(nx+nu)²)`). The Goldfarb–Idnani method adds violated bounds through the same
//! solves (a normal `e_k` of scenario `i` needs the backward sweep of scenario `i` only), so the
//! iterates are those of the dense method on the condensed QP and the solution agrees with
//! [`super::DenseQp`] to rounding.

use super::active_set::{box_dual_from_fields, solve_box, BoxWork};
use super::cholesky::{chol_solve, cholesky};
use super::qp::{QpInfo, QpSettings};
use super::stage::{self, quad, with_stage_size, RiccatiFactor};
use super::stage_data::{check_dims, dim, StageDims, StageQpData};
use super::SolverError;
use alloc::{vec, vec::Vec};

/// The scenario-tree QP described in the module documentation, with all workspace allocated at
/// construction: its [`StageQpData`] (`S` scenarios, the first `Nr` inputs shared; trajectory
/// vectors `[s_0..s_{Nr−1}, u_{1,Nr}..u_{1,Nc−1}, …, u_{S,Nr}..u_{S,Nc−1}, x_{1,1}..x_{1,Np}, …,
/// x_{S,1}..x_{S,Np}]`, the inputs first, in the order of the coupled NLP's decision vector)
/// with the shared inputs' `R̄_j` beside it, and the factor.
#[derive(Debug, Clone)]
pub struct TreeQp {
    /// Dynamics, the scenarios' own input and state costs, linear term and bounds (`qp.a` reads
    /// `qp.data.a`).
    pub data: StageQpData,
    /// `R̄_j` of the shared inputs, `j < Nr`, at `j·nu²` (symmetric positive definite).
    pub r_shared: Vec<f64>,
    settings: QpSettings,
    /// The scenarios' Riccati factor of their own stages and the sweeps' workspace.
    f: RiccatiFactor,
    // The shared block: `Bᵀ P B`, `C_{j+1}`, `C_j`, `Σ_i E_{i,0} + R̄` (factorised), and the
    // sweeps' `e`.
    bpb: Vec<f64>,
    cm: Vec<f64>,
    cn: Vec<f64>,
    hs: Vec<f64>,
    ev: Vec<f64>,
    /// Solution, multipliers and active set.
    w: BoxWork,
}

/// Which scenarios' right-hand sides a sweep reads: `lo..hi`, backward from stage `top`.
#[derive(Clone, Copy)]
struct Active {
    lo: usize,
    hi: usize,
    top: usize,
}

impl TreeQp {
    /// A solver for `ns ≥ 1` scenarios of `np ≥ 1` stages with state dimension `nx ≥ 1`, the
    /// first `1 ≤ nc ≤ np` stages with an input of dimension `nu ≥ 1`, of which the first
    /// `1 ≤ nr ≤ nc` are shared by all scenarios.
    pub fn new(
        nx: usize,
        nu: usize,
        np: usize,
        nc: usize,
        nr: usize,
        ns: usize,
        settings: QpSettings,
    ) -> Result<Self, SolverError> {
        settings.validate()?;
        check_dims(nx, nu, np, nc)?;
        dim("nr", nr, nr >= 1 && nr <= nc, "1 ≤ nr ≤ nc")?;
        let dims = StageDims {
            nx,
            nu,
            np,
            nc,
            nr,
            ns,
        };
        let data = StageQpData::new(dims)?;
        let nsh = nr * nu;
        let len = data.len();
        // At most as many linearly independent active constraints as inputs; one spare for the
        // entering one.
        let cap = data.num_inputs() + 1;
        Ok(Self {
            data,
            r_shared: vec![0.0; nr * nu * nu],
            settings,
            f: RiccatiFactor::new(dims),
            bpb: vec![0.0; nu * nu],
            cm: vec![0.0; nx * nsh],
            cn: vec![0.0; nx * nsh],
            hs: vec![0.0; nsh * nsh],
            ev: vec![0.0; nsh],
            w: BoxWork::new(len, cap),
        })
    }

    /// Largest diagonal entry of the condensed Hessian (in the inputs) of the current data:
    /// for scenario `i`'s input `(j, k)`, `(R_{i,j} + B_{i,j}ᵀ V_{i,j} B_{i,j})_kk` with
    /// `V_{i,Np−1} = Q_{i,Np}`, `V_{i,j} = Q_{i,j+1} + A_{i,j+1}ᵀ V_{i,j+1} A_{i,j+1}`; for a
    /// shared input the sum over the scenarios plus `R̄_j`. Uses the factor workspace (call
    /// before [`Self::solve`]); `O(S·Np·nx³)`.
    pub fn max_condensed_diagonal(&mut self) -> f64 {
        with_stage_size!((self.data.dims.nx, self.data.dims.nu), |nx, nu| self
            .max_condensed_diagonal_dims(nx, nu))
    }

    #[inline(always)]
    fn max_condensed_diagonal_dims(&mut self, nx: usize, nu: usize) -> f64 {
        let StageDims { nc, nr, .. } = self.data.dims;
        let mut maxd: f64 = 0.0;
        // Shared diagonal accumulated in `ev`.
        for j in 0..nr {
            for k in 0..nu {
                self.ev[j * nu + k] = self.r_shared[j * nu * nu + k * nu + k];
            }
        }
        for i in 0..self.data.dims.ns {
            let (ev, r) = (&mut self.ev, &self.data.r);
            self.f
                .condensed_diagonal((nx, nu), &self.data, i, |j, k, d| {
                    if j < nr {
                        ev[j * nu + k] += d;
                    } else {
                        let rij = (i * (nc - nr) + j - nr) * nu * nu;
                        maxd = maxd.max(d + r[rij + k * nu + k]);
                    }
                });
        }
        for &d in &self.ev {
            maxd = maxd.max(d);
        }
        maxd
    }

    /// Factorises the tree: per-scenario Riccati recursions and the shared block. Returns
    /// `false` when a reduced Hessian is not numerically positive definite.
    fn factor(&mut self) -> bool {
        // The NMPC's stage sizes (1-DOF, 2-DOF) as constants: unrolled, bounds checks removed.
        with_stage_size!((self.data.dims.nx, self.data.dims.nu), |nx, nu| self
            .factor_dims(nx, nu))
    }

    #[inline(always)]
    fn factor_dims(&mut self, nx: usize, nu: usize) -> bool {
        let StageDims { np, nc, nr, ns, .. } = self.data.dims;
        let n2 = nx * nx;
        let nsh = nr * nu;
        self.hs.fill(0.0);
        for i in 0..ns {
            // Own stages j = Np−1 .. Nr: the Riccati recursion of `RiccatiQp`.
            if !self.f.own_stages((nx, nu), &self.data, i, None, None) {
                return false;
            }
            let ab = i * np * n2;
            // Shared stages j = Nr−1 .. 0, shared inputs as parameters: C_{j+1} in `cm`
            // (columns (j+1)·nu .. Nr·nu), contributions to the lower part of `hs`.
            for j in (0..nr).rev() {
                let p = &self.f.pm[(j + 1) * n2..(j + 2) * n2];
                let st = i * nc + j;
                let b = &self.data.b[st * nx * nu..(st + 1) * nx * nu];
                stage::p_times(nx, nu, p, b, &mut self.f.pb);
                stage::bt_times(nx, nu, nu, None, b, &self.f.pb, &mut self.bpb);
                let jo = j * nu;
                for c in 0..nu {
                    for rr in c..nu {
                        self.hs[(jo + c) * nsh + jo + rr] += self.bpb[c * nu + rr];
                    }
                }
                // Block (k, j), k > j: (B_jᵀ C_{j+1})ᵀ.
                for col in (j + 1) * nu..nsh {
                    let cc = &self.cm[col * nx..(col + 1) * nx];
                    for rr in 0..nu {
                        let mut s = 0.0;
                        for k in 0..nx {
                            s += b[rr * nx + k] * cc[k];
                        }
                        self.hs[(jo + rr) * nsh + col] += s;
                    }
                }
                if j == 0 {
                    break;
                }
                let a = &self.data.a[ab + j * n2..ab + (j + 1) * n2];
                // C_j = [Aᵀ P B, Aᵀ C_{j+1}].
                let (cj, cn) = (jo * nx, (j + 1) * nu * nx);
                stage::at_times(nx, nu, a, &self.f.pb, &mut self.cn[cj..cn]);
                stage::at_times(
                    nx,
                    nsh - (j + 1) * nu,
                    a,
                    &self.cm[cn..],
                    &mut self.cn[cn..],
                );
                core::mem::swap(&mut self.cm, &mut self.cn);
                // P_j = Q_j + AᵀPA.
                stage::p_times(nx, nx, p, a, &mut self.f.pa);
                let qj = &self.data.q[ab + (j - 1) * n2..ab + j * n2];
                let (head, _) = self.f.pm.split_at_mut((j + 1) * n2);
                stage::cost_to_go(nx, nu, qj, a, &self.f.pa, None, &mut head[j * n2..]);
            }
        }
        for j in 0..nr {
            let rj = &self.r_shared[j * nu * nu..(j + 1) * nu * nu];
            let jo = j * nu;
            for c in 0..nu {
                for rr in c..nu {
                    self.hs[(jo + c) * nsh + jo + rr] += rj[c * nu + rr];
                }
            }
        }
        if !cholesky(&mut self.hs, nsh) {
            return false;
        }
        self.hs.iter().all(|v| v.is_finite())
            && self.f.lchol.iter().all(|v| v.is_finite())
            && self.f.kgain.iter().all(|v| v.is_finite())
    }

    /// Minimiser of `½wᵀHw + linᵀw` over the dynamics (trajectory layout) into `sol` or `yp`,
    /// where `lin` (`g` or `unit`) is zero outside the shared inputs and the scenarios of `act`,
    /// and in those zero on every stage after `act.top`.
    fn sweep(&mut self, use_unit: bool, act: Active, out_is_yp: bool) {
        with_stage_size!((self.data.dims.nx, self.data.dims.nu), |nx, nu| self
            .sweep_dims(nx, nu, use_unit, act, out_is_yp))
    }

    #[inline(always)]
    fn sweep_dims(&mut self, nx: usize, nu: usize, use_unit: bool, act: Active, out_is_yp: bool) {
        let StageDims { np, nc, nr, .. } = self.data.dims;
        let n2 = nx * nx;
        let nsh = nr * nu;
        let nv = self.num_inputs();
        let lin: &[f64] = if use_unit { &self.w.unit } else { &self.data.g };
        self.ev.fill(0.0);
        for i in act.lo..act.hi {
            let ab = i * np * n2;
            let xb = nv + i * np * nx;
            let ub = nsh + i * (nc - nr) * nu;
            let top = act.top;
            let xi = xb + top * nx;
            self.f.pv[(top + 1) * nx..(top + 2) * nx].copy_from_slice(&lin[xi..xi + nx]);
            for j in nr.max(top + 1)..nc {
                let st = i * nc + j;
                self.f.kff[st * nu..(st + 1) * nu].fill(0.0);
            }
            // Private stages top .. Nr.
            for j in (nr..=top).rev() {
                let (head, tail) = self.f.pv.split_at_mut((j + 1) * nx);
                let pn = &tail[..nx];
                let st = i * nc + j;
                let su = st * nu..(st + 1) * nu;
                if j < nc {
                    let b = &self.data.b[st * nx * nu..(st + 1) * nx * nu];
                    let l = &self.f.lchol[st * nu * nu..(st + 1) * nu * nu];
                    let uo = ub + (j - nr) * nu;
                    let k = &mut self.f.kff[su.clone()];
                    stage::feed_forward(nx, nu, b, &lin[uo..uo + nu], pn, (l, None), k);
                }
                let a = &self.data.a[ab + j * n2..ab + (j + 1) * n2];
                let xo = xb + (j - 1) * nx;
                let gain = (j < nc).then(|| {
                    (
                        &self.f.sbar[st * nu * nx..(st + 1) * nu * nx],
                        &self.f.kff[su],
                    )
                });
                stage::costate(nx, nu, a, &lin[xo..xo + nx], pn, gain, &mut head[j * nx..]);
            }
            // Shared stages: e_j += B_jᵀ p_{j+1}, p_j = lin_x_j + A_jᵀ p_{j+1}.
            for j in (0..nr.min(top + 1)).rev() {
                let (head, tail) = self.f.pv.split_at_mut((j + 1) * nx);
                let pn = &tail[..nx];
                let st = i * nc + j;
                let b = &self.data.b[st * nx * nu..(st + 1) * nx * nu];
                for t in 0..nu {
                    let mut s = 0.0;
                    for c in 0..nx {
                        s += b[t * nx + c] * pn[c];
                    }
                    self.ev[j * nu + t] += s;
                }
                if j == 0 {
                    break;
                }
                let a = &self.data.a[ab + j * n2..ab + (j + 1) * n2];
                let xo = xb + (j - 1) * nx;
                stage::costate(nx, nu, a, &lin[xo..xo + nx], pn, None, &mut head[j * nx..]);
            }
        }
        // Shared inputs: s = −Hs⁻¹ (e + lin_s).
        let out: &mut [f64] = if out_is_yp {
            &mut self.w.yp
        } else {
            &mut self.w.sol
        };
        for k in 0..nsh {
            out[k] = -(self.ev[k] + lin[k]);
        }
        chol_solve(&self.hs, nsh, &mut out[..nsh]);
        // Forward pass of every scenario from x_0 = 0.
        for i in 0..self.data.dims.ns {
            let ab = i * np * n2;
            let xb = nv + i * np * nx;
            let ub = nsh + i * (nc - nr) * nu;
            let own = i >= act.lo && i < act.hi;
            self.f.xs.fill(0.0);
            for j in 0..np {
                let a = &self.data.a[ab + j * n2..ab + (j + 1) * n2];
                let xo = xb + j * nx;
                stage::a_times(nx, a, &self.f.xs, &mut out[xo..xo + nx]);
                if j < nc {
                    let st = i * nc + j;
                    let b = &self.data.b[st * nx * nu..(st + 1) * nx * nu];
                    let kg = &self.f.kgain[st * nu * nx..(st + 1) * nu * nx];
                    for t in 0..nu {
                        let v = if j < nr {
                            out[j * nu + t]
                        } else {
                            let kf = if own { self.f.kff[st * nu + t] } else { 0.0 };
                            let s = stage::feedback(nx, nu, t, kf, kg, &self.f.xs);
                            out[ub + (j - nr) * nu + t] = s;
                            s
                        };
                        stage::add_input(nx, b, t, v, &mut out[xo..xo + nx]);
                    }
                }
                self.f.xs.copy_from_slice(&out[xo..xo + nx]);
            }
        }
    }

    /// Trajectory `H⁻¹ n` for the constraint normal `n = σ e_id` into `yp`.
    fn normal_solve(&mut self, id: usize, sigma: f64) {
        let StageDims {
            nx, nu, np, nc, nr, ..
        } = self.data.dims;
        let nsh = nr * nu;
        let nv = self.num_inputs();
        let act = if id < nsh {
            Active {
                lo: 0,
                hi: 0,
                top: 0,
            }
        } else if id < nv {
            let npr = (nc - nr) * nu;
            let i = (id - nsh) / npr;
            let top = nr + (id - nsh - i * npr) / nu;
            Active {
                lo: i,
                hi: i + 1,
                top,
            }
        } else {
            let i = (id - nv) / (np * nx);
            let top = (id - nv - i * np * nx) / nx;
            Active {
                lo: i,
                hi: i + 1,
                top,
            }
        };
        self.w.unit[id] = 1.0;
        self.sweep(true, act, true);
        self.w.unit[id] = 0.0;
        // The sweep gives −H⁻¹ e; the normal is σ e.
        for v in self.w.yp.iter_mut() {
            *v *= -sigma;
        }
    }

    /// Objective `½wᵀHw + gᵀw` of the trajectory `w = self.w.sol`.
    fn objective(&self) -> f64 {
        let StageDims { nx, nu, nr, .. } = self.data.dims;
        let nsh = nr * nu;
        let nv = self.num_inputs();
        let mut f: f64 = self
            .w
            .sol
            .iter()
            .zip(&self.data.g)
            .map(|(w, g)| w * g)
            .sum();
        for j in 0..nr {
            f += quad(
                &self.w.sol[j * nu..(j + 1) * nu],
                &self.r_shared[j * nu * nu..(j + 1) * nu * nu],
                nu,
            );
        }
        for (k, rk) in self.data.r.chunks_exact(nu * nu).enumerate() {
            f += quad(&self.w.sol[nsh + k * nu..nsh + (k + 1) * nu], rk, nu);
        }
        for (k, qk) in self.data.q.chunks_exact(nx * nx).enumerate() {
            f += quad(&self.w.sol[nv + k * nx..nv + (k + 1) * nx], qk, nx);
        }
        f
    }

    /// Solves the QP with the current data. Never panics and allocates nothing; the solution is
    /// [`Self::solution`] and the multipliers [`Self::multipliers`].
    pub fn solve(&mut self) -> QpInfo {
        let finite = |v: &[f64]| v.iter().all(|x| x.is_finite());
        let data_finite = finite(&self.data.a)
            && finite(&self.data.b)
            && finite(&self.data.q)
            && finite(&self.data.r)
            && finite(&self.r_shared)
            && finite(&self.data.g);
        let settings = self.settings;
        let start = |qp: &mut Self| {
            let all = Active {
                lo: 0,
                hi: qp.data.dims.ns,
                top: qp.data.dims.np - 1,
            };
            qp.factor() && {
                qp.sweep(false, all, false);
                true
            }
        };
        match solve_box(self, &settings, data_finite, start) {
            Ok(mut info) => {
                info.objective = self.objective();
                info
            }
            Err(info) => info,
        }
    }
}

box_dual_from_fields!(TreeQp);
