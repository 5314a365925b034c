//! Library part of the `exompc` command-line tool: error type and file I/O helpers shared by
//! the subcommands (and usable from the CLI's integration tests).
#![warn(missing_docs)]

pub mod error;
pub mod io;
