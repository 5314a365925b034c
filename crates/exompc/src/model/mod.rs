//! Planar serial chains: human and robot legs, payload, friction, interaction straps, RK4.
//!
//! Paper §2, eqs. 1-4; docs/MODEL.md §1-4. Everything here is generic over the scalar type
//! ([`Real`]) so that the very same code yields exact derivatives with forward-mode dual numbers
//! (`num-dual`).

mod chain;
mod human;
mod rk4;
mod rk4_jacobian;
mod robot;
mod straps;
mod trig;

pub use chain::{Chain, Link};
pub use human::HumanSegment;
pub use rk4::{rk4_step, JointState, RkState};
#[cfg(test)]
pub(crate) use rk4_jacobian::chained;
pub use rk4_jacobian::StepJacobian;
pub(crate) use rk4_jacobian::{ChainConstants, HeldTorque, StageTorque, TailoredRk4, TorqueTerms};
pub use robot::{tanh, Friction, RobotModel};
pub use straps::Straps;
pub use trig::{sin_cos, sin_cos_near};

#[cfg(feature = "std")]
use num_dual::DualNum;

/// Standard gravity (m/s²), MODEL.md §1.
pub const GRAVITY: f64 = 9.81;

/// A real scalar: `f64` or a forward-mode dual number over `f64`.
#[cfg(feature = "std")]
pub trait Real: DualNum<Primitive = f64> + Copy {}
#[cfg(feature = "std")]
impl<T: DualNum<Primitive = f64> + Copy> Real for T {}

#[cfg(not(feature = "std"))]
pub use crate::math::Real;

/// Lift an `f64` constant into the scalar type.
#[inline(always)]
pub fn c<T: Real>(x: f64) -> T {
    T::from(x)
}
