//! The problem data of a stage-structured QP, separate from the solvers' factor and workspace
//! (the problem/workspace split of OpEn and Clarabel): what a caller fills — dynamics, stage
//! costs, linear term, bounds — for [`super::RiccatiQp`] (one scenario) and
//! [`super::TreeQp`] (a scenario tree whose first inputs are shared), which each keep their own
//! extra data beside it (the cross terms `S_j`; the shared inputs' `R̄_j`).
//!
//! The data describes `S` scenarios of `Np` stages with state dimension `nx`, the first `Nc`
//! stages with an input of dimension `nu`, of which the first `Nr` are shared by all scenarios
//! (the stage QP: `S = 1`, `Nr = 0`):
//!
//! ```text
//! x_{i,0} = 0,  x_{i,j+1} = A_{i,j} x_{i,j} + B_{i,j} v_{i,j},
//!   v_{i,j} = s_j (shared, j < Nr),  u_{i,j} (Nr ≤ j < Nc),  no input (j ≥ Nc);
//! cost Σ_{i, Nr≤j<Nc} ½ u_{i,j}ᵀ R_{i,j} u_{i,j}  +  Σ_{i, 1≤j≤Np} ½ x_{i,j}ᵀ Q_{i,j} x_{i,j}  +  gᵀw;
//! lo ≤ w ≤ hi  component-wise (entries may be ±∞).
//! ```
//!
//! Trajectory vectors `w` (`g`, `lo`, `hi`, a solution, multipliers) use the layout
//! `[s_0..s_{Nr−1}, u_{1,Nr}..u_{1,Nc−1}, …, u_{S,Nr}..u_{S,Nc−1}, x_{1,1}..x_{1,Np}, …,
//! x_{S,1}..x_{S,Np}]`: the inputs first, then every scenario's states (one scenario:
//! `[u_0, …, u_{Nc−1}, x_1, …, x_{Np}]`).

use super::SolverError;
use alloc::{vec, vec::Vec};

/// The dimensions of a stage-structured QP (module documentation).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct StageDims {
    /// State dimension `nx`.
    pub nx: usize,
    /// Input dimension `nu`.
    pub nu: usize,
    /// Stages `Np`.
    pub np: usize,
    /// Stages with an input, `Nc ≤ Np`.
    pub nc: usize,
    /// Leading input stages shared by all scenarios, `Nr ≤ Nc` (0 for the stage QP).
    pub nr: usize,
    /// Scenarios `S` (1 for the stage QP).
    pub ns: usize,
}

/// The data of a stage-structured QP described in the module documentation (blocks
/// column-major), allocated at construction; a [`super::RiccatiQp`] and a [`super::TreeQp`]
/// dereference to theirs (`qp.a` is `qp.data.a`).
#[derive(Debug, Clone)]
pub struct StageQpData {
    pub(super) dims: StageDims,
    /// `A_{i,j}`, `j = 0..Np`, each `nx × nx`, at `(i·Np + j)·nx²`.
    pub a: Vec<f64>,
    /// `B_{i,j}`, `j = 0..Nc`, each `nx × nu`, at `(i·Nc + j)·nx·nu`.
    pub b: Vec<f64>,
    /// `Q_{i,j}` of state `x_{i,j}`, `j = 1..=Np`, each `nx × nx`, at `(i·Np + j − 1)·nx²`
    /// (positive semidefinite).
    pub q: Vec<f64>,
    /// `R_{i,j}` of scenario `i`'s own inputs, `Nr ≤ j < Nc`, each `nu × nu`, at
    /// `(i·(Nc − Nr) + j − Nr)·nu²` (symmetric positive definite; one scenario: `R_j` at
    /// `j·nu²`).
    pub r: Vec<f64>,
    /// Linear term in trajectory layout.
    pub g: Vec<f64>,
    /// Lower bounds in trajectory layout (`−∞` for none).
    pub lo: Vec<f64>,
    /// Upper bounds in trajectory layout (`+∞` for none).
    pub hi: Vec<f64>,
}

impl StageQpData {
    /// Zero data (no bounds) for `ns ≥ 1` scenarios of `np ≥ 1` stages, `1 ≤ nc ≤ np` of them
    /// with inputs, the first `nr ≤ nc` shared; `nx, nu ≥ 1`.
    pub(super) fn new(dims: StageDims) -> Result<Self, SolverError> {
        let (nx, nu, np, nc) = (dims.nx, dims.nu, dims.np, dims.nc);
        let (nr, ns) = (dims.nr, dims.ns);
        check_dims(nx, nu, np, nc)?;
        dim("nr", nr, nr <= nc, "0 ≤ nr ≤ nc")?;
        dim("scenarios", ns, ns >= 1, "at least 1")?;
        let len = nr * nu + ns * ((nc - nr) * nu + np * nx);
        Ok(Self {
            dims,
            a: vec![0.0; ns * np * nx * nx],
            b: vec![0.0; ns * nc * nx * nu],
            q: vec![0.0; ns * np * nx * nx],
            r: vec![0.0; ns * (nc - nr) * nu * nu],
            g: vec![0.0; len],
            lo: vec![f64::NEG_INFINITY; len],
            hi: vec![f64::INFINITY; len],
        })
    }

    /// The dimensions.
    pub fn dims(&self) -> StageDims {
        self.dims
    }

    /// Length of trajectory vectors, `Nr·nu + S·((Nc − Nr)·nu + Np·nx)`.
    pub fn len(&self) -> usize {
        self.num_inputs() + self.dims.ns * self.dims.np * self.dims.nx
    }

    /// Always `false` (dimensions are at least one); present for API symmetry with `len`.
    pub fn is_empty(&self) -> bool {
        false
    }

    /// Number of input variables (shared and own), `Nr·nu + S·(Nc − Nr)·nu`: the leading part
    /// of the trajectory layout.
    pub fn num_inputs(&self) -> usize {
        self.dims.nr * self.dims.nu + self.dims.ns * (self.dims.nc - self.dims.nr) * self.dims.nu
    }

    /// Number of scenarios `S`.
    pub fn scenarios(&self) -> usize {
        self.dims.ns
    }

    /// Index of component `k` of the input of stage `j < Nc` seen by scenario `i` (the shared
    /// input for `j < Nr`) in trajectory layout.
    pub fn u_index(&self, i: usize, j: usize, k: usize) -> usize {
        if j < self.dims.nr {
            j * self.dims.nu + k
        } else {
            self.dims.nr * self.dims.nu
                + (i * (self.dims.nc - self.dims.nr) + j - self.dims.nr) * self.dims.nu
                + k
        }
    }

    /// Index of component `k` of state `x_{i,j}`, `1 ≤ j ≤ Np`, in trajectory layout.
    pub fn x_index(&self, i: usize, j: usize, k: usize) -> usize {
        self.num_inputs() + (i * self.dims.np + j - 1) * self.dims.nx + k
    }
}

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
