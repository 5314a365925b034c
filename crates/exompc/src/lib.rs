//! exompc: multi-stage robust nonlinear model predictive control of exoskeleton robots.
//!
//! Implements Aliyari & Vossoughi, "Multi-stage robust nonlinear model predictive control of a
//! lower-limb exoskeleton robot" (see `docs/ARCHITECTURE.md` for the module map).
#![warn(missing_docs)]

pub mod config;
pub mod control;
pub mod estimate;
pub mod model;
pub mod runtime;
pub mod sim;
pub mod solver;
