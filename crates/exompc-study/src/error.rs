//! The CLI's error type and its mapping to process exit codes.

use std::fmt;
use std::sync::atomic::{AtomicI32, Ordering};

/// The signal that interrupted the command (0: none), stored by the SIGINT/SIGTERM handler
/// (module `interrupt`).
pub(crate) static SIGNAL: AtomicI32 = AtomicI32::new(0);

/// The exit code after the signal received: 128 + its number (130 for SIGINT, 143 for
/// SIGTERM), as a shell reports a process killed by it; 130 when none was recorded.
pub fn interrupted_exit_code() -> u8 {
    match SIGNAL.load(Ordering::SeqCst) {
        s @ 1..=127 => 128 + s as u8,
        _ => EXIT_INTERRUPTED,
    }
}

/// Exit code for bad input: an invalid config value, an unknown key or a bad flag (clap's own
/// usage errors also exit 2).
pub const EXIT_USAGE: u8 = 2;
/// Exit code after SIGINT (128 + 2, as the shell reports a Ctrl-C); SIGTERM gives 143
/// (see [`interrupted_exit_code`]).
pub const EXIT_INTERRUPTED: u8 = 130;
/// Exit code after SIGTERM where a command tells it from SIGINT (`run`, `virtual-robot`:
/// 128 + 15).
pub const EXIT_TERMINATED: u8 = 143;
/// Exit code for a runtime failure (I/O error while writing results, solver failure, ...).
pub const EXIT_FAILURE: u8 = 1;
/// Exit code of `--strict` runs whose verdict is `degraded` (the results are written).
pub const EXIT_DEGRADED: u8 = 3;

/// An error reported by the CLI as one `error: ...` line on stderr.
#[derive(Debug)]
pub enum CliError {
    /// Invalid configuration file or value (exit 2).
    Config(String),
    /// Invalid command-line flag or combination (exit 2).
    Usage(String),
    /// File-system problem (exit 1).
    Io(String),
    /// Any other runtime failure (exit 1).
    Runtime(String),
    /// Stopped by SIGINT/SIGTERM; the message says what was completed (exit 130 or 143).
    Interrupted(String),
    /// A `--strict` run whose verdict is `degraded` (exit 3).
    Degraded(String),
    /// Stopped by SIGTERM, where the command tells it from SIGINT (exit 143).
    Terminated(String),
}

impl CliError {
    /// Process exit code for this error.
    pub fn exit_code(&self) -> u8 {
        match self {
            CliError::Config(_) | CliError::Usage(_) => EXIT_USAGE,
            CliError::Io(_) | CliError::Runtime(_) => EXIT_FAILURE,
            CliError::Interrupted(_) => interrupted_exit_code(),
            CliError::Degraded(_) => EXIT_DEGRADED,
            CliError::Terminated(_) => EXIT_TERMINATED,
        }
    }

    /// Builds an [`CliError::Io`] from an I/O error and what was being done (`"writing out.csv"`).
    pub fn io(what: impl fmt::Display, err: std::io::Error) -> Self {
        CliError::Io(format!("{what}: {err}"))
    }
}

impl fmt::Display for CliError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            CliError::Config(m)
            | CliError::Usage(m)
            | CliError::Io(m)
            | CliError::Runtime(m)
            | CliError::Interrupted(m)
            | CliError::Degraded(m)
            | CliError::Terminated(m) => f.write_str(m),
        }
    }
}

impl std::error::Error for CliError {}
