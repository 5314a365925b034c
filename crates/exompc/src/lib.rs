//! exompc: multi-stage robust nonlinear model predictive control (NMPC) of exoskeleton robots.
//!
//! exompc implements the controller and the simulation study of Aliyari & Vossoughi,
//! *"Multi-stage robust nonlinear model predictive control of a lower-limb exoskeleton robot"*.
//! `docs/MODEL.md` in the repository states every equation and parameter value used;
//! `docs/ARCHITECTURE.md` maps the modules and follows one control step through them.
//!
//! # The problem
//!
//! A human leg (thigh and shank, hip and knee joints) is strapped to a lower-limb exoskeleton
//! with the same two joints. Both are planar serial chains ([`model`]); the straps are
//! spring-dampers, so every angle difference between human and robot shows up as a strap force
//! (paper eqs. 3-4). The exoskeleton should *follow* the human: it measures its own joint
//! angles and velocities and the two strap forces, and must choose its joint torques so that
//! the strap forces — the effort the wearer feels — stay small.
//!
//! The controller does not know the human's motion, only what the straps tell it: the human's
//! intended angles are estimated as `q̂_H = q_R + K1·F`, `q̂d_H = qd_R + K2·F` (eqs. 5-6). Every
//! control period (10 ms) a nonlinear MPC ([`control::Nmpc`], eq. 7) predicts the robot over a
//! short horizon with RK4 and picks the torque increments that track the estimate, subject to
//! hard limits on torque and torque rate (eqs. 8-9), solved by an SQP on a dense active-set QP
//! ([`solver`]).
//!
//! The robot carries an unknown payload. The **multi-stage** NMPC ([`control::MultiStage`],
//! eqs. 10-13) keeps one prediction model per candidate payload (by default 0, 1 and 2 kg).
//! A bank of extended Kalman filters ([`estimate::EkfBank`]), one per scenario, estimates each
//! scenario's lumped disturbance and, from the filters' innovations, the probability that the
//! scenario is the true one; the scenarios' control moves are blended with these
//! probabilities. A [`control::Supervisor`] around any controller rejects implausible sensor
//! data and runs safety monitors, with a safe fallback torque.
//!
//! [`sim`] simulates the coupled human-robot system under the paper's uncertainties (payload,
//! mass perturbation, disturbance, sensor noise and filtering) and computes the paper's
//! metrics; [`config`] holds the scenario, whose [`Default`] is the paper's simulation study;
//! [`scenario`] builds controllers and plants from it and runs experiments.
//!
//! # One control step
//!
//! Build a controller once from a scenario, then call [`Controller::step`] every period with
//! the (filtered) measurement. The step never allocates and never panics; its torque always
//! satisfies the torque and torque-rate limits, and [`StepStatus`] says how it was obtained.
//!
//! ```
//! use exompc::sim::Trajectory;
//! use exompc::scenario::{initial_torque, limits};
//! use exompc::{build_controller, Controller, ControllerKind, Dof, Measurement, Experiment, TwoDof};
//! use nalgebra::Vector2;
//!
//! let scenario = Experiment::default(); // the paper's 2-DOF study (docs/MODEL.md)
//! let mut controller = build_controller::<TwoDof, 2>(&scenario, ControllerKind::MSNMPC)?;
//!
//! // The robot sits on the human's desired start; the straps pull slightly.
//! let (q, qd, _) = TwoDof::trajectory(&scenario).eval(0.0);
//! let measurement = Measurement { t: 0.0, q, qd, force: Vector2::new(1.5, -2.0) };
//! let out = controller.step(&measurement);
//!
//! let lim = limits(&scenario); // |T| <= 30 N·m, |ΔT| <= 10 N·m per step
//! let previous = initial_torque::<TwoDof, 2>(&scenario); // T_R(-1): gravity torque at start
//! assert!(out.torque.iter().all(|t| t.abs() <= lim.max));
//! assert!((out.torque - previous).iter().all(|d| d.abs() <= lim.rate + 1e-12));
//! assert_eq!(controller.probabilities().map(|p| p.len()), Some(3)); // 0, 1 and 2 kg
//! println!("torque {:?} N·m, status {:?}", out.torque, out.status);
//! # Ok::<(), exompc::scenario::RunError>(())
//! ```
//!
//! The crate's `examples/` show a closed loop around a plant of your own
//! (`closed_loop_own_plant`) and the controller as it runs on a robot (`robot_step`):
//! `cargo run --release -p exompc --example robot_step`.
//!
//! # Modules
//!
//! From the bottom up: [`model`] (the dynamics) and [`solver`] (the optimiser), [`estimate`]
//! (the EKF bank), [`control`] (the controllers and the safety supervisor), [`sim`] (the
//! simulated plant and closed loop), [`runtime`] (the real-time loop), [`config`] (the
//! scenario description) and [`scenario`] (builders, the controller registry, experiments).
//! Imports run only from a later module to an earlier one. The most used items are
//! re-exported at the crate root; their module paths work as well.
//!
//! # Without `std`
//!
//! With the default `std` feature off, the library builds `#![no_std]` with `alloc`, e.g. for a
//! Cortex-M7 (`thumbv7em-none-eabihf`; `docs/EMBEDDED.md`): the numerical core, the plant, the
//! scenario and its builders, the closed-loop experiment, and of [`runtime`] the link's frames,
//! keys, handshake and session state and the stream deframer (its loop, clocks, sockets and
//! virtual robot need `std`). Without `std`:
//! f64 math through `libm`, no clock (no solve time budget), multi-stage scenarios in turn, no
//! exact Hessian, no fault scan (rayon), no controller registration at run time.
#![warn(missing_docs)]
#![cfg_attr(not(feature = "std"), no_std)]

extern crate alloc;

mod check;
#[cfg(not(feature = "std"))]
pub mod clock;
pub mod config;
pub mod control;
pub mod estimate;
#[cfg(any(not(feature = "std"), test))]
mod math;
pub mod model;
pub mod runtime;
pub mod scenario;
pub mod sim;
pub mod solver;
#[cfg(test)]
mod test_rng;

pub use check::InvalidField;
pub use config::{ControllerKind, Experiment};
pub use control::{
    ControlOutput, Controller, Measurement, MultiStage, Nmpc, StepStatus, Supervisor, TorqueLimits,
};
pub use estimate::EkfBank;
pub use model::RobotModel;
pub use scenario::{build_controller, build_supervised, run_experiment, Dof, OneDof, TwoDof};

/// The repository's README, whose Rust snippet (the library example) is compiled and run as
/// a doctest, so that it stays correct.
#[cfg(doctest)]
#[doc = include_str!("../../../README.md")]
pub struct ReadmeDoctests;
