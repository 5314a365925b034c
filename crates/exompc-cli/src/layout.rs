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
    /// The sweep was interrupted (SIGINT/SIGTERM): `rows` holds only the runs completed.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub partial: bool,
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

/// The controllers of `rows` in the order tables and figures show them: the registry's order
/// ([`exompc::scenario::controllers`]), then names the registry does not know (results of
/// another process's registered controllers) in the order they first appear.
pub fn controller_order(rows: &[Summary]) -> Vec<String> {
    let mut out: Vec<String> = exompc::scenario::controllers()
        .iter()
        .map(|c| c.name().to_string())
        .filter(|n| rows.iter().any(|r| &r.controller == n))
        .collect();
    for r in rows {
        if !out.contains(&r.controller) {
            out.push(r.controller.clone());
        }
    }
    out
}

/// The legend label of controller `name` (its registry label; the name itself if the
/// registry does not know it).
pub fn controller_label(name: &str) -> String {
    exompc::scenario::controller_by_name(name).map_or_else(|| name.to_string(), |c| c.label.into())
}
