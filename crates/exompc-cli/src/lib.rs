//! Library part of the `exompc` command-line tool: error type, file I/O helpers, the streamed
//! trace format and the single-run driver shared by the subcommands (and usable from the CLI's
//! integration tests).
#![warn(missing_docs)]

pub mod can;
pub mod can_cia402;
pub mod config_help;
pub mod earlier;
pub mod envelope;
pub mod error;
pub mod explain;
pub mod gait;
pub mod interrupt;
pub mod io;
pub mod layout;
pub mod run;
pub mod trace;
pub mod verdict;
