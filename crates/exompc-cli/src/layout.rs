//! The results-folder layout written by `exompc simulate` and `exompc sweep` and read by
//! `exompc plot`: one folder per run named by [`run_dir_name`], and `sweep.json`
//! ([`SweepFile`]) beside them.

use exompc::sim::Summary;
use serde::{Deserialize, Serialize};

/// The content of `sweep.json`.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct SweepFile {
    /// One summary per run, payload-major in the order of `--payloads`, then `--controllers`.
    pub rows: Vec<Summary>,
}

/// Rounds to 1e-9 kg so that `a + i·step` prints as the user wrote it.
pub fn tidy(v: f64) -> f64 {
    let r = (v * 1e9).round() / 1e9;
    if r == 0.0 {
        0.0
    } else {
        r
    }
}

/// Folder name of one run: `<controller>_<payload>kg`.
pub fn run_dir_name(controller: &str, payload: f64) -> String {
    format!("{controller}_{}kg", tidy(payload))
}
