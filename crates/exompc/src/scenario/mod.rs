//! The scenario layer: turns an [`Experiment`](crate::config::Experiment) description into a plant,
//! a trajectory, prediction models and controllers ([`build_controller`], [`build_supervised`]),
//! and runs experiments ([`run_experiment`], [`run_soak`]).
//!
//! This layer only composes the domain types of [`crate::model`], [`crate::control`],
//! [`crate::estimate`] and [`crate::sim`]; nothing below it imports it.

mod build;
mod error;
mod fault_goals;
#[cfg(feature = "std")]
mod fault_scan;
mod info;
mod layout;
pub mod multistage;
mod registry;
mod run;
#[cfg(feature = "std")]
mod virtual_robot;

pub use build::{
    build_multistage, build_nmpc, build_pd, fallback, initial_torque, intent, limits,
    multistage_nmpc_settings, nmpc_settings, solver_choice,
};
pub use error::RunError;
pub use fault_goals::{
    episodes, meets_goals, peak_goal_n, rms_ratio, soak_fault_classes, spike_magnitude,
    ChannelGroup, Episode, EpisodeStats, SoakFaultClass, EPISODE_AFTER_S, RMS_RATIO_GOAL,
};
#[cfg(feature = "std")]
pub use fault_scan::{cell_scenario, fault_scan_markdown, run_fault_scan, FaultCell, FaultGrid};
pub use info::{Builder, ControllerInfo};
pub use layout::{
    gait_demand, plant_params, prediction_model, scenario_robot, uncertainty, Dof, OneDof, TwoDof,
};
#[cfg(feature = "std")]
pub use registry::register_controller;
pub use registry::{
    build_controller, build_supervised, controller_by_name, controller_info, controllers,
    supervise, validate, DuplicateController, BUILTIN,
};
pub use run::{
    run_experiment, run_experiment_report, run_soak, soak_scenario, summary_solver, SoakReport,
};
#[cfg(feature = "std")]
pub use virtual_robot::{RobotStats, RobotStep, StopCause, StopEvent, VirtualRobot, WatchdogEvent};
