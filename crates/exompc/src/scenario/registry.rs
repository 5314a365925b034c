//! The controller registry: every controller exompc can build, with its name, legend label,
//! description, figure colour and builders.
//!
//! Adding a controller = its implementation of [`Controller`] + one [`ControllerInfo`] entry:
//! in [`BUILTIN`] for a controller of exompc, or at run time with [`register_controller`] for
//! a controller of your own. Everything else reads this registry: `controller.kind` in config
//! files (a [`ControllerKind`], checked by [`validate`]), the builders
//! ([`build_controller`](super::build_controller), [`run_experiment`](super::run_experiment)),
//! the CLI's `--controller` values and help, folder names, figure colours and legends.

use super::build::{build_multistage, build_nmpc, build_pd, OneDof, TwoDof};
use super::RunError;
use crate::config::{ConfigError, ControllerKind, Scenario};
use crate::control::Controller;
use nalgebra::SVector;
use std::sync::{PoisonError, RwLock};

/// Builds a controller of scenario `s` with `N` joints and initial previous torque `t0`.
pub type Builder<const N: usize> =
    fn(&Scenario, SVector<f64, N>) -> Result<Box<dyn Controller<N>>, RunError>;

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
    /// Builder for the 2-DOF hip-knee layout ([`TwoDof`]).
    pub build_2dof: Builder<2>,
    /// Builder for the 1-DOF knee layout ([`OneDof`]).
    pub build_1dof: Builder<1>,
}

impl ControllerInfo {
    /// The name ([`ControllerInfo::kind`] as text).
    pub fn name(&'static self) -> &'static str {
        self.kind.as_str()
    }
}

/// The controllers of exompc, in the order help texts, tables and legends list them.
pub const BUILTIN: &[ControllerInfo] = &[
    ControllerInfo {
        kind: ControllerKind::MSNMPC,
        label: "MS-NMPC",
        description: "multi-stage robust NMPC over the payload scenarios (paper eqs. 10-13)",
        colour: 0,
        multistage: true,
        build_2dof: build_multistage::<TwoDof, 2, 6, 4>,
        build_1dof: build_multistage::<OneDof, 1, 3, 2>,
    },
    ControllerInfo {
        kind: ControllerKind::NMPC,
        label: "NMPC",
        description: "NMPC on the nominal (0 kg) model (paper eq. 7)",
        colour: 1,
        multistage: false,
        build_2dof: build_nmpc::<TwoDof, 2>,
        build_1dof: build_nmpc::<OneDof, 1>,
    },
    ControllerInfo {
        kind: ControllerKind::PD,
        label: "PD",
        description: "joint PD toward the estimated human intent, with gravity compensation",
        colour: 2,
        multistage: false,
        build_2dof: build_pd::<TwoDof, 2>,
        build_1dof: build_pd::<OneDof, 1>,
    },
];

/// Controllers added by [`register_controller`], after [`BUILTIN`].
static REGISTERED: RwLock<Vec<&'static ControllerInfo>> = RwLock::new(Vec::new());

/// Error of [`register_controller`].
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("a controller named {0:?} is already registered")]
pub struct DuplicateController(pub ControllerKind);

/// Add a controller of your own to the registry (for the whole process): from then on
/// `controller.kind = "<its name>"` validates, and [`build_controller`](super::build_controller),
/// [`build_supervised`](super::build_supervised) and
/// [`run_experiment`](super::run_experiment) build it. Fails if the name is taken.
///
/// ```
/// use exompc::config::{ControllerKind, Scenario};
/// use exompc::scenario::{build_pd, register_controller, ControllerInfo, OneDof, TwoDof};
///
/// static MINE: ControllerInfo = ControllerInfo {
///     kind: ControllerKind::from_static("my-pd"),
///     label: "my PD",
///     description: "the PD baseline under another name",
///     colour: 3,
///     multistage: false,
///     build_2dof: build_pd::<TwoDof, 2>,
///     build_1dof: build_pd::<OneDof, 1>,
/// };
/// register_controller(&MINE).unwrap();
/// let mut s = Scenario::default();
/// s.controller.kind = ControllerKind::new("my-pd").unwrap();
/// exompc::scenario::validate(&s).unwrap();
/// assert!(register_controller(&MINE).is_err());
/// ```
pub fn register_controller(info: &'static ControllerInfo) -> Result<(), DuplicateController> {
    let mut all = REGISTERED.write().unwrap_or_else(PoisonError::into_inner);
    if BUILTIN
        .iter()
        .chain(all.iter().copied())
        .any(|c| c.kind == info.kind)
    {
        return Err(DuplicateController(info.kind));
    }
    all.push(info);
    Ok(())
}

/// Every registered controller: [`BUILTIN`], then those of [`register_controller`] in the
/// order they were registered.
pub fn controllers() -> Vec<&'static ControllerInfo> {
    let extra = REGISTERED.read().unwrap_or_else(PoisonError::into_inner);
    BUILTIN.iter().chain(extra.iter().copied()).collect()
}

/// The registry entry named `name`, if any.
pub fn controller_by_name(name: &str) -> Option<&'static ControllerInfo> {
    controllers().into_iter().find(|c| c.kind.as_str() == name)
}

/// The registry entry of `kind`; the error (field `controller.kind`) lists the registered
/// names.
pub fn controller_info(kind: ControllerKind) -> Result<&'static ControllerInfo, ConfigError> {
    controller_by_name(kind.as_str()).ok_or_else(|| {
        let names: Vec<String> = controllers()
            .iter()
            .map(|c| format!("\"{}\"", c.kind))
            .collect();
        ConfigError::new(
            "controller.kind",
            format!("\"{kind}\""),
            format!("a registered controller: {}", names.join(", ")),
        )
    })
}

/// [`Scenario::validate`], and `controller.kind` names a registered controller: the whole
/// check of a scenario before it is run.
pub fn validate(s: &Scenario) -> Result<(), ConfigError> {
    s.validate()?;
    controller_info(s.controller.kind).map(|_| ())
}
