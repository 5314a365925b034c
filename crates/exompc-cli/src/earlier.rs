//! Output folders holding results of an earlier run: refused unless `--force`, which removes
//! only the files exompc itself writes there, so old and new results never mix silently.

use crate::error::CliError;
use std::path::{Path, PathBuf};

/// What `simulate`, `run` and `virtual-robot` write into their folder (the figures by
/// `--plot` or `exompc plot`).
pub const RUN_FILES: &[&str] = &[
    "trace.csv",
    "summary.json",
    "states.png",
    "states.svg",
    "interaction.png",
    "interaction.svg",
];

/// What `envelope` writes into its folder.
pub const ENVELOPE_FILES: &[&str] = &[
    "envelope.json",
    "envelope.md",
    "envelope.png",
    "envelope.svg",
];

/// What `soak` writes into its folder.
pub const SOAK_FILES: &[&str] = &["soak.json", "soak_trace.csv"];

/// True for a temporary file exompc leaves only when killed outright (`.trace.csv.tmp.PID.N`)
/// for one of `files`.
fn is_leftover_temp(name: &str, files: &[&str]) -> bool {
    files.iter().any(|f| {
        name.starts_with(&format!(".{f}.tmp."))
            || name.starts_with(&format!(".{}.tmp.", f.split('.').next().unwrap_or(f)))
    })
}

/// Refuses `dir` when it holds any of `files` (results of an earlier run) unless `force`;
/// with `force`, removes those files and exompc's leftover temporary files there, and
/// nothing else. `what` names the command for the message (`simulate`).
pub fn refuse_or_clear(
    dir: &Path,
    files: &[&str],
    force: bool,
    what: &str,
) -> Result<(), CliError> {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return Ok(());
    };
    let mut earlier: Vec<PathBuf> = Vec::new();
    let mut temps: Vec<PathBuf> = Vec::new();
    for e in entries.filter_map(Result::ok) {
        let name = e.file_name().to_string_lossy().into_owned();
        let path = e.path();
        if !path.is_file() {
            continue;
        }
        if files.contains(&name.as_str()) {
            earlier.push(path);
        } else if is_leftover_temp(&name, files) {
            temps.push(path);
        }
    }
    if earlier.is_empty() && temps.is_empty() {
        return Ok(());
    }
    earlier.sort();
    if !force && !earlier.is_empty() {
        let names: Vec<String> = earlier
            .iter()
            .map(|p| {
                p.file_name()
                    .unwrap_or_default()
                    .to_string_lossy()
                    .into_owned()
            })
            .collect();
        return Err(CliError::Usage(format!(
            "{} already holds results of an earlier {what} ({}): choose another --out, or pass \
             --force to replace them",
            dir.display(),
            names.join(", ")
        )));
    }
    for p in earlier.into_iter().chain(temps) {
        std::fs::remove_file(&p)
            .map_err(|e| CliError::io(format!("removing earlier result {}", p.display()), e))?;
    }
    Ok(())
}
