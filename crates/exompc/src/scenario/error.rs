//! Why an experiment could not run.

use crate::config::ConfigError;
use crate::control::{MultiStageError, NmpcError};

/// Why an experiment could not run.
#[derive(Debug, thiserror::Error)]
pub enum RunError {
    /// The scenario is invalid.
    #[error(transparent)]
    Config(#[from] ConfigError),
    /// The NMPC controller could not be built (invalid limits or solver settings).
    #[error("controller: {0}")]
    Nmpc(#[from] NmpcError),
    /// The multi-stage controller could not be built (invalid limits, estimator or solver
    /// settings, or no scenario).
    #[error("multi-stage controller: {0}")]
    MultiStage(#[from] MultiStageError),
    /// The simulated plant diverged (its state stopped being finite) at time `t`.
    #[error(
        "the simulated plant diverged at t = {t} s (its state is no longer finite); \
         a shorter plant step (timing.dt / timing.plant_substeps) keeps RK4 stable"
    )]
    Diverged {
        /// Time (s) of the first non-finite state.
        t: f64,
    },
    /// A recorder failed (e.g. a trace file could not be written).
    #[error("recording failed: {0}")]
    Io(#[from] crate::sim::RecordError),
}
