//! A planar serial chain of `N` revolute links hanging from a fixed base (MODEL.md §1).
#![allow(clippy::needless_range_loop)] // index-heavy formulas read closest to the math

use super::{c, Real, GRAVITY};
use crate::check::{self, InvalidField, Range};
use nalgebra::{SMatrix, SVector};
use serde::{Deserialize, Serialize};

/// Rigid link parameters (MODEL.md §1): length, mass, COM distance from the proximal joint along
/// the link, and inertia about the COM. The scenario's `[robot.thigh]` / `[robot.shank]` tables
/// (keys `length_m`, `mass_kg`, `com_m`, `inertia_kgm2`).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Link {
    /// Length `l` (m): distance from the proximal to the distal joint, > 0.
    #[serde(rename = "length_m")]
    pub length: f64,
    /// Mass `m` (kg), > 0.
    #[serde(rename = "mass_kg")]
    pub mass: f64,
    /// COM distance `c` (m) from the proximal joint, in [0, length].
    #[serde(rename = "com_m")]
    pub com: f64,
    /// Inertia `I` about the COM (kg·m²), > 0.
    #[serde(rename = "inertia_kgm2")]
    pub inertia: f64,
}

impl Link {
    /// Default robot thigh: l 0.43 m, m 2.0 kg, c 0.20 m, I 0.035 kg·m² (MODEL.md §3).
    pub const ROBOT_THIGH: Self = Self {
        length: 0.43,
        mass: 2.0,
        com: 0.20,
        inertia: 0.035,
    };
    /// Default robot shank: l 0.43 m, m 1.2 kg, c 0.18 m, I 0.018 kg·m² (MODEL.md §3).
    pub const ROBOT_SHANK: Self = Self {
        length: 0.43,
        mass: 1.2,
        com: 0.18,
        inertia: 0.018,
    };

    /// Checks length and mass (finite, > 0), the COM on the link (in [0, length]) and the
    /// inertia (finite, > 0), in this order; the error names the key (`length_m`, `mass_kg`,
    /// `com_m`, `inertia_kgm2`).
    pub fn validate(&self) -> Result<(), InvalidField> {
        check::reals(&[
            ("length_m", self.length, Range::Pos),
            ("mass_kg", self.mass, Range::Pos),
            ("com_m", self.com, Range::Closed(0.0, self.length)),
            ("inertia_kgm2", self.inertia, Range::Pos),
        ])
    }

    /// The link with a point mass `mp` (kg) rigidly attached at distance `d` (m) from its proximal
    /// joint, merged by the parallel-axis theorem (MODEL.md §3, payload).
    pub fn with_point_mass(&self, mp: f64, d: f64) -> Link {
        let m = self.mass + mp;
        if m <= 0.0 {
            return *self;
        }
        let com = (self.mass * self.com + mp * d) / m;
        let inertia = self.inertia + self.mass * (self.com - com).powi(2) + mp * (d - com).powi(2);
        Link {
            length: self.length,
            mass: m,
            com,
            inertia,
        }
    }

    /// The link with `dm` (kg) added to its mass, COM location and COM inertia unchanged
    /// (MODEL.md §5, `m_dis`).
    pub fn with_mass_added(&self, dm: f64) -> Link {
        Link {
            mass: self.mass + dm,
            ..*self
        }
    }
}

/// Planar serial chain of `N` links in the sagittal plane, hip joint at the origin, joint
/// angles relative (MODEL.md §1): `q1` from the downward vertical, `q_i` relative to link `i-1`.
///
/// Implements the rigid-body terms of paper eqs. 1-2: `M(q) qdd + C(q, qd) qd + G(q)`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Chain<const N: usize> {
    /// Links from the base outwards.
    pub links: [Link; N],
    /// Gravity (m/s²).
    pub gravity: f64,
}

/// Lever `d_{k,a}` of link `a`'s direction in the position of COM `k` (a ≤ k).
#[inline(always)]
fn lever(links: &[Link], k: usize, a: usize) -> f64 {
    if a == k {
        links[k].com
    } else {
        links[a].length
    }
}

impl<const N: usize> Chain<N> {
    /// A chain under standard gravity.
    pub fn new(links: [Link; N]) -> Self {
        Chain {
            links,
            gravity: GRAVITY,
        }
    }

    /// Absolute link angles `θ_a = q_1 + ... + q_a`.
    #[inline(always)]
    pub fn absolute_angles<T: Real>(q: &SVector<T, N>) -> [T; N] {
        let mut th = [T::zero(); N];
        let mut acc = T::zero();
        for a in 0..N {
            acc += q[a];
            th[a] = acc;
        }
        th
    }

    /// `cos(θ_a − θ_b)` and `sin(θ_a − θ_b)` for all pairs (symmetric / antisymmetric).
    #[inline(always)]
    fn pair_trig<T: Real>(th: &[T; N]) -> ([[T; N]; N], [[T; N]; N]) {
        let mut cs = [[T::one(); N]; N];
        let mut sn = [[T::zero(); N]; N];
        for a in 0..N {
            for b in (a + 1)..N {
                let (s, co) = (th[a] - th[b]).sin_cos();
                cs[a][b] = co;
                cs[b][a] = co;
                sn[a][b] = s;
                sn[b][a] = -s;
            }
        }
        (cs, sn)
    }

    /// Mass matrix `M(q)` (MODEL.md §1), from the planar Lagrangian:
    /// `M_ij = Σ_{k ≥ max(i,j)} [ I_k + m_k Σ_{a=i..k} Σ_{b=j..k} d_ka d_kb cos(θ_a − θ_b) ]`.
    pub fn mass_matrix<T: Real>(&self, q: &SVector<T, N>) -> SMatrix<T, N, N> {
        let th = Self::absolute_angles(q);
        let (cs, _) = Self::pair_trig(&th);
        self.mass_matrix_from_trig(&cs)
    }

    fn mass_matrix_from_trig<T: Real>(&self, cs: &[[T; N]; N]) -> SMatrix<T, N, N> {
        let l = &self.links;
        let mut m = SMatrix::<T, N, N>::from_element(T::zero());
        for i in 0..N {
            for j in i..N {
                let mut s = T::zero();
                for k in j..N {
                    let mut acc = T::zero();
                    for a in i..=k {
                        for b in j..=k {
                            acc += cs[a][b] * (l[k].mass * lever(l, k, a) * lever(l, k, b));
                        }
                    }
                    s += acc + c::<T>(l[k].inertia);
                }
                m[(i, j)] = s;
                m[(j, i)] = s;
            }
        }
        m
    }

    /// Partial derivatives `∂M/∂q_r` for `r = 0..N`.
    pub fn mass_matrix_derivatives<T: Real>(&self, q: &SVector<T, N>) -> [SMatrix<T, N, N>; N] {
        let th = Self::absolute_angles(q);
        let (_, sn) = Self::pair_trig(&th);
        self.mass_matrix_derivatives_from_trig(&sn)
    }

    fn mass_matrix_derivatives_from_trig<T: Real>(
        &self,
        sn: &[[T; N]; N],
    ) -> [SMatrix<T, N, N>; N] {
        let l = &self.links;
        let mut out = [SMatrix::<T, N, N>::from_element(T::zero()); N];
        // ∂cos(θ_a − θ_b)/∂q_r = −sin(θ_a − θ_b) ([r ≤ a] − [r ≤ b]).
        for (r, dm) in out.iter_mut().enumerate() {
            for i in 0..N {
                for j in i..N {
                    let mut s = T::zero();
                    for k in j..N {
                        for a in i..=k {
                            for b in j..=k {
                                let w = (r <= a) as i32 - (r <= b) as i32;
                                if w != 0 {
                                    s -= sn[a][b]
                                        * (l[k].mass * lever(l, k, a) * lever(l, k, b) * w as f64);
                                }
                            }
                        }
                    }
                    dm[(i, j)] = s;
                    dm[(j, i)] = s;
                }
            }
        }
        out
    }

    /// Coriolis/centrifugal matrix `C(q, qd)` from the Christoffel symbols of `M`
    /// (`c_ijk = ½(∂M_ij/∂q_k + ∂M_ik/∂q_j − ∂M_jk/∂q_i)`), so that `Ṁ − 2C` is skew-symmetric.
    pub fn coriolis_matrix<T: Real>(
        &self,
        q: &SVector<T, N>,
        qd: &SVector<T, N>,
    ) -> SMatrix<T, N, N> {
        let dm = self.mass_matrix_derivatives(q);
        let mut cm = SMatrix::<T, N, N>::from_element(T::zero());
        let half = c::<T>(0.5);
        for i in 0..N {
            for j in 0..N {
                let mut s = T::zero();
                for k in 0..N {
                    s += (dm[k][(i, j)] + dm[j][(i, k)] - dm[i][(j, k)]) * qd[k];
                }
                cm[(i, j)] = s * half;
            }
        }
        cm
    }

    /// Gravity torque `G(q) = ∂V/∂q`, `G_r = g Σ_k m_k Σ_{a=r..k} d_ka sin θ_a` (MODEL.md §1).
    pub fn gravity_torque<T: Real>(&self, q: &SVector<T, N>) -> SVector<T, N> {
        let th = Self::absolute_angles(q);
        let mut sin = [T::zero(); N];
        for a in 0..N {
            sin[a] = th[a].sin();
        }
        self.gravity_from_sin(&sin)
    }

    fn gravity_from_sin<T: Real>(&self, sin: &[T; N]) -> SVector<T, N> {
        let l = &self.links;
        let g = self.gravity;
        // Per absolute angle a: weight w_a = g (m_a c_a + Σ_{k>a} m_k l_a).
        let mut wa = [T::zero(); N];
        for a in 0..N {
            let mut w = l[a].mass * l[a].com;
            for lk in l.iter().skip(a + 1) {
                w += lk.mass * l[a].length;
            }
            wa[a] = sin[a] * (g * w);
        }
        let mut out = SVector::<T, N>::from_element(T::zero());
        let mut acc = T::zero();
        for r in (0..N).rev() {
            acc += wa[r];
            out[r] = acc;
        }
        out
    }

    /// Potential energy `V(q)` (J), zero with the chain horizontal at the base height.
    pub fn potential_energy(&self, q: &SVector<f64, N>) -> f64 {
        let th = Self::absolute_angles(q);
        let l = &self.links;
        let mut v = 0.0;
        for k in 0..N {
            let mut y = 0.0;
            for a in 0..=k {
                y -= lever(l, k, a) * th[a].cos();
            }
            v += l[k].mass * self.gravity * y;
        }
        v
    }

    /// Kinetic energy `½ qdᵀ M(q) qd` (J).
    pub fn kinetic_energy(&self, q: &SVector<f64, N>, qd: &SVector<f64, N>) -> f64 {
        0.5 * qd.dot(&(self.mass_matrix(q) * qd))
    }

    /// All rigid-body terms at once: `M(q)`, `C(q, qd) qd` and `G(q)`, sharing the trigonometry.
    pub fn terms<T: Real>(
        &self,
        q: &SVector<T, N>,
        qd: &SVector<T, N>,
    ) -> (SMatrix<T, N, N>, SVector<T, N>, SVector<T, N>) {
        let th = Self::absolute_angles(q);
        let (cs, sn) = Self::pair_trig(&th);
        let mut sin = [T::zero(); N];
        for a in 0..N {
            sin[a] = th[a].sin();
        }
        let m = self.mass_matrix_from_trig(&cs);
        let dm = self.mass_matrix_derivatives_from_trig(&sn);
        // (C qd)_i = Σ_jk c_ijk qd_j qd_k = Σ_jk (∂M_ij/∂q_k − ½ ∂M_jk/∂q_i) qd_j qd_k.
        let mut cqd = SVector::<T, N>::from_element(T::zero());
        let half = c::<T>(0.5);
        for i in 0..N {
            let mut s = T::zero();
            for j in 0..N {
                for k in 0..N {
                    s += (dm[k][(i, j)] - dm[i][(j, k)] * half) * qd[j] * qd[k];
                }
            }
            cqd[i] = s;
        }
        (m, cqd, self.gravity_from_sin(&sin))
    }

    /// Forward dynamics `qdd = M(q)⁻¹ (tau − C(q, qd) qd − G(q))` for a generalised force `tau`
    /// that already contains friction, interaction and disturbance torques.
    #[inline]
    pub fn forward_dynamics<T: Real>(
        &self,
        q: &SVector<T, N>,
        qd: &SVector<T, N>,
        tau: &SVector<T, N>,
    ) -> SVector<T, N> {
        let (m, cqd, g) = self.terms(q, qd);
        let mut rhs = *tau;
        for i in 0..N {
            rhs[i] = tau[i] - cqd[i] - g[i];
        }
        solve_spd(&m, &rhs)
    }
}

/// Solve `M x = b` for a small symmetric positive-definite `M` by LDLᵀ (no square roots, so it
/// works unchanged on dual numbers).
#[inline]
pub fn solve_spd<T: Real, const N: usize>(
    m: &SMatrix<T, N, N>,
    b: &SVector<T, N>,
) -> SVector<T, N> {
    let mut l = [[T::zero(); N]; N];
    let mut d = [T::zero(); N];
    for j in 0..N {
        let mut dj = m[(j, j)];
        for k in 0..j {
            dj -= l[j][k] * l[j][k] * d[k];
        }
        d[j] = dj;
        let inv = dj.recip();
        for i in (j + 1)..N {
            let mut s = m[(i, j)];
            for k in 0..j {
                s -= l[i][k] * l[j][k] * d[k];
            }
            l[i][j] = s * inv;
        }
    }
    let mut y = *b;
    for i in 0..N {
        for k in 0..i {
            let t = l[i][k] * y[k];
            y[i] -= t;
        }
    }
    for i in 0..N {
        y[i] /= d[i];
    }
    for i in (0..N).rev() {
        for k in (i + 1)..N {
            let t = l[k][i] * y[k];
            y[i] -= t;
        }
    }
    y
}
