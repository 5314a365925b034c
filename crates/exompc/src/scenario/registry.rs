//! The controller registry: every controller exompc can build, with its name, legend label,
//! description, figure colour and builders.
//!
//! Adding a controller = its implementation of [`Controller`] + one [`ControllerInfo`] entry:
//! in [`BUILTIN`] for a controller of exompc, or at run time with [`register_controller`] for
//! a controller of your own. Everything else reads this registry: `controller.kind` in config
//! files (a [`ControllerKind`], checked by [`validate`]), the builders
//! ([`build_controller`](super::build_controller), [`run_experiment`](super::run_experiment)),
//! the CLI's `--controller` values and help, folder names, figure colours and legends.

use super::build::{build_multistage, build_nmpc, build_pd, fallback, initial_torque};
use super::error::RunError;
use super::info::ControllerInfo;
use super::layout::{Dof, OneDof, TwoDof};
use crate::config::{ConfigError, ControllerKind, Experiment};
use crate::control::{Controller, SafetySettings, Supervisor};
use alloc::{boxed::Box, format, string::String, vec::Vec};
#[cfg(feature = "std")]
use std::sync::{PoisonError, RwLock};

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
#[cfg(feature = "std")]
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
/// use exompc::config::{ControllerKind, Experiment};
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
/// let mut s = Experiment::default();
/// s.controller.kind = ControllerKind::new("my-pd").unwrap();
/// exompc::scenario::validate(&s).unwrap();
/// assert!(register_controller(&MINE).is_err());
/// ```
#[cfg(feature = "std")]
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
    #[cfg(feature = "std")]
    let extra = REGISTERED.read().unwrap_or_else(PoisonError::into_inner);
    #[cfg(not(feature = "std"))]
    let extra: [&'static ControllerInfo; 0] = []; // no registry without std: the built-ins
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

/// [`Experiment::validate`], and `controller.kind` names a registered controller: the whole
/// check of a scenario before it is run.
pub fn validate(s: &Experiment) -> Result<(), ConfigError> {
    s.validate()?;
    controller_info(s.controller.kind).map(|_| ())
}

/// The controller `kind` for scenario `s`, built by its registry entry
/// ([`controllers`](super::controllers)); [`RunError::Config`] naming `controller.kind` if no
/// controller of that name is registered.
pub fn build_controller<D: Dof<N>, const N: usize>(
    s: &Experiment,
    kind: ControllerKind,
) -> Result<Box<dyn Controller<N>>, RunError> {
    let info = controller_info(kind)?;
    let t0 = initial_torque::<D, N>(s);
    D::builder(info)(s, t0)
}

/// The controller `kind` of scenario `s` wrapped in the safety [`Supervisor`]
/// (plausibility checks and the `[monitors]` of `s`).
pub fn build_supervised<D: Dof<N>, const N: usize>(
    s: &Experiment,
    kind: ControllerKind,
) -> Result<Supervisor<N, Box<dyn Controller<N>>>, RunError> {
    Ok(supervise::<D, N>(s, build_controller::<D, N>(s, kind)?))
}

/// `ctrl` under the supervisor of scenario `s` (its safety settings and the transparent
/// fallback: the `fallback` response, and what `hold` and `ramp_to_zero` hand over to when
/// the trip's cause is present after `control::RESPONSE_ESCALATE_S`), as [`build_supervised`]
/// builds it; for a
/// build that names its controller's builder directly instead of going through the registry
/// (the firmware's controller-only image links one controller only).
pub fn supervise<D: Dof<N>, const N: usize>(
    s: &Experiment,
    ctrl: Box<dyn Controller<N>>,
) -> Supervisor<N, Box<dyn Controller<N>>> {
    Supervisor::new(ctrl, SafetySettings::from_scenario(s)).with_fallback(fallback::<D, N>(s))
}
