//! The scenario layer: turns a [`Scenario`](crate::config::Scenario) description into a plant,
//! a trajectory, prediction models and controllers ([`build_controller`], [`build_supervised`]),
//! and runs experiments ([`run_experiment`], [`run_soak`]).
//!
//! This layer only composes the domain types of [`crate::model`], [`crate::control`],
//! [`crate::estimate`] and [`crate::sim`]; nothing below it imports it.

mod build;
mod fault_scan;
pub mod multistage;
mod registry;
mod run;

pub use build::{
    build_controller, build_multistage, build_nmpc, build_pd, build_supervised, fallback,
    gait_demand, initial_torque, intent, limits, multistage_nmpc_settings, nmpc_settings,
    plant_params, prediction_model, scenario_robot, uncertainty, Dof, OneDof, TwoDof,
};
pub use fault_scan::{
    cell_scenario, fault_scan_markdown, peak_goal_n, run_fault_scan, spike_magnitude, ChannelGroup,
    FaultCell, FaultGrid, RMS_RATIO_GOAL,
};
pub use registry::{
    controller_by_name, controller_info, controllers, register_controller, validate, Builder,
    ControllerInfo, DuplicateController, BUILTIN,
};
pub use run::{
    run_experiment, run_experiment_report, run_soak, soak_scenario, RunError, SoakReport,
};
