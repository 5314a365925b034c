//! What the registry knows of one controller ([`ControllerInfo`]) and how it builds it
//! ([`Builder`]).

use super::error::RunError;
use crate::config::{ControllerKind, Experiment};
use crate::control::Controller;
use alloc::boxed::Box;
use nalgebra::SVector;

/// Builds a controller of scenario `s` with `N` joints and initial previous torque `t0`.
pub type Builder<const N: usize> =
    fn(&Experiment, SVector<f64, N>) -> Result<Box<dyn Controller<N>>, RunError>;

/// One registered controller.
#[derive(Clone, Copy, Debug)]
pub struct ControllerInfo {
    /// The name (`controller.kind`): in config files, on the command line, in folder names, in
    /// summaries; [`Controller::name`] of what the builders build.
    pub kind: ControllerKind,
    /// Legend label in figures.
    pub label: &'static str,
    /// One-line description (command-line help).
    pub description: &'static str,
    /// Index of the controller's colour in the figures' palette.
    pub colour: usize,
    /// Whether the controller blends the `[multistage]` scenarios: it reports their
    /// probabilities (trace columns `mu_<scenario>`, `summary.json` `scenarios`), warns about
    /// scenarios the estimator cannot tell apart, and takes `multistage.formulation`
    /// (`--formulation`).
    pub multistage: bool,
    /// Builder for the 2-DOF hip-knee layout ([`TwoDof`](super::TwoDof)).
    pub build_2dof: Builder<2>,
    /// Builder for the 1-DOF knee layout ([`OneDof`](super::OneDof)).
    pub build_1dof: Builder<1>,
}

impl ControllerInfo {
    /// The name ([`ControllerInfo::kind`] as text).
    pub fn name(&'static self) -> &'static str {
        self.kind.as_str()
    }
}
