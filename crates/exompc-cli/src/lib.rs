//! Library part of the `exompc` command-line tool: the streamed trace format, the single-run
//! driver and the verdicts shared by the subcommands (and usable from the CLI's integration
//! tests). Scenario files, gaits, the envelope scan, the error type and the interrupt flag are
//! in `exompc-study` (shared with the Python package and the fuzz targets), re-exported here.
#![warn(missing_docs)]

pub use exompc_study::{config_help, envelope, error, gait, interrupt, io};

pub mod can;
pub mod can_cia402;
pub mod earlier;
pub mod explain;
pub mod layout;
pub mod run;
pub mod trace;
pub mod verdict;
