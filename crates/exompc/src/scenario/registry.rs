//! The controller registry: every controller exompc can build, with its names, description,
//! figure colour and builders. Adding a controller = its implementation of
//! [`Controller`] + a [`ControllerKind`] variant (the config's spelling) + one entry here; the
//! CLI's `--controller` values, folder names, figure colours and legends all read this table.

use super::build::{build_multistage, build_nmpc, build_pd, OneDof, TwoDof};
use super::RunError;
use crate::config::{ControllerKind, Scenario};
use crate::control::Controller;
use nalgebra::SVector;

/// Builds a controller of scenario `s` with `N` joints and initial previous torque `t0`.
pub type Builder<const N: usize> =
    fn(&Scenario, SVector<f64, N>) -> Result<Box<dyn Controller<N>>, RunError>;

/// One registered controller.
#[derive(Clone, Copy, Debug)]
pub struct ControllerInfo {
    /// The configuration value (`controller.kind`).
    pub kind: ControllerKind,
    /// Name in config files, on the command line, in folder names and in summaries.
    pub name: &'static str,
    /// Legend label in figures.
    pub label: &'static str,
    /// One-line description (command-line help).
    pub description: &'static str,
    /// Index of the controller's colour in the figures' palette.
    pub colour: usize,
    /// Builder for the 2-DOF hip-knee layout ([`TwoDof`]).
    pub build_2dof: Builder<2>,
    /// Builder for the 1-DOF knee layout ([`OneDof`]).
    pub build_1dof: Builder<1>,
}

/// Every controller exompc can build, in the order help texts and legends list them.
pub const CONTROLLERS: &[ControllerInfo] = &[
    ControllerInfo {
        kind: ControllerKind::Pd,
        name: "pd",
        label: "PD",
        description: "joint PD toward the estimated human intent, with gravity compensation",
        colour: 2,
        build_2dof: build_pd::<TwoDof, 2>,
        build_1dof: build_pd::<OneDof, 1>,
    },
    ControllerInfo {
        kind: ControllerKind::Nmpc,
        name: "nmpc",
        label: "NMPC",
        description: "NMPC on the nominal (0 kg) model (paper eq. 7)",
        colour: 1,
        build_2dof: build_nmpc::<TwoDof, 2>,
        build_1dof: build_nmpc::<OneDof, 1>,
    },
    ControllerInfo {
        kind: ControllerKind::Msnmpc,
        name: "msnmpc",
        label: "MS-NMPC",
        description: "multi-stage robust NMPC over the payload scenarios (paper eqs. 10-13)",
        colour: 0,
        build_2dof: build_multistage::<TwoDof, 2, 6, 4>,
        build_1dof: build_multistage::<OneDof, 1, 3, 2>,
    },
];

/// The registry entry of `kind` (every [`ControllerKind`] has one; checked by a test).
pub fn controller_info(kind: ControllerKind) -> &'static ControllerInfo {
    CONTROLLERS
        .iter()
        .find(|c| c.kind == kind)
        .expect("every ControllerKind has a CONTROLLERS entry")
}

/// The registry entry named `name` (`"pd"`, `"nmpc"`, `"msnmpc"`), if any.
pub fn controller_by_name(name: &str) -> Option<&'static ControllerInfo> {
    CONTROLLERS.iter().find(|c| c.name == name)
}
