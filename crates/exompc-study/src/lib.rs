//! What the `exompc` command-line tool, the Python package and the fuzz targets share, in a
//! crate of its own so that none of them depends on the binary's crate and the library
//! (`exompc`) keeps no file-format dependency:
//!
//! * [`io`]: scenario files — read and check a TOML file (unknown keys and bad values named
//!   with their allowed range), `set key = value` by dotted path, write; JSON output helpers.
//! * [`gait`]: recorded gaits — the CSV of time and joint angles that `[trajectory] kind =
//!   "recorded"` replays.
//! * [`envelope`]: the operating-envelope scan (scenario changes × payloads × controllers) and
//!   its verdicts.
//! * [`config_help`]: the messages that name a key, the file or flag that set it, and the range.
//! * [`error`]: the error type with its exit codes; [`interrupt`]: a clean stop on SIGINT/SIGTERM.
#![warn(missing_docs)]

pub mod config_help;
pub mod envelope;
pub mod error;
pub mod gait;
pub mod interrupt;
pub mod io;
