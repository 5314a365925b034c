//! Recorded gaits as CSV files: reading them into the library's
//! [`GaitRecording`] (with errors naming file, line and column) and
//! writing sampled trajectories (`exompc gait export`).
//!
//! Format: a header naming the columns with their units, then one sample per line; lines
//! starting with `#` are comments. Columns (any order): time `t_s` (or `time_s`), knee angle
//! `knee_rad` or `knee_deg`, and for the 2-DOF layout the hip angle `hip_rad` or `hip_deg`.
//!
//! ```text
//! t_s,hip_rad,knee_rad
//! 0.00,0.100000000,0.000000000
//! 0.01,0.115074...,-0.004380...
//! ```

use crate::error::CliError;
use exompc::config::{Experiment, TrajectoryKind};
use exompc::sim::{GaitRecording, RecordingColumn, RecordingError};
use std::path::Path;
use std::sync::Arc;

/// Unit of an angle column.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Unit {
    Rad,
    Deg,
}

/// One recognised column of the header.
#[derive(Debug, Clone)]
struct Column {
    /// Index in the record (from 0).
    index: usize,
    /// Name as written in the header.
    name: String,
    unit: Unit,
}

const COLUMNS_HELP: &str =
    "expected t_s (or time_s), knee_rad or knee_deg, and for 2 DOF hip_rad or hip_deg";

/// Reads the gait CSV at `path` (see the module documentation).
pub fn read_gait(path: &Path) -> Result<GaitRecording, CliError> {
    let shown = path.display().to_string();
    let text = std::fs::read_to_string(path)
        .map_err(|e| CliError::Config(format!("cannot read gait file {shown}: {e}")))?;
    parse_gait(&text, &shown).map_err(CliError::Config)
}

/// Largest time (s) in a gait file: ten times the longest run (`timing.duration_*_s` <= 1e6).
const MAX_TIME_S: f64 = 1e7;
/// Largest joint angle (rad) in a gait file before the recording's own ±2π check.
const MAX_ANGLE_RAD: f64 = 1e3;

/// Parses gait CSV `text`; `shown` names the file in messages (`gait file F, line 12, column 3
/// (knee_rad): ...`).
pub fn parse_gait(text: &str, shown: &str) -> Result<GaitRecording, String> {
    let at = |line: u64, col: Option<&Column>| match col {
        Some(c) => format!(
            "gait file {shown}, line {line}, column {} ({})",
            c.index + 1,
            c.name
        ),
        None => format!("gait file {shown}, line {line}"),
    };
    let mut reader = csv::ReaderBuilder::new()
        .comment(Some(b'#'))
        .trim(csv::Trim::All)
        .flexible(false)
        .from_reader(text.as_bytes());
    let header = reader
        .headers()
        .map_err(|e| format!("gait file {shown}: {e}"))?
        .clone();
    let header_line = header.position().map_or(1, |p| p.line());
    let (mut time, mut hip, mut knee) = (None, None, None);
    for (index, raw) in header.iter().enumerate() {
        let name = raw.to_ascii_lowercase();
        let (slot, unit) = match name.as_str() {
            "t_s" | "time_s" => (&mut time, Unit::Rad),
            "hip_rad" => (&mut hip, Unit::Rad),
            "hip_deg" => (&mut hip, Unit::Deg),
            "knee_rad" => (&mut knee, Unit::Rad),
            "knee_deg" => (&mut knee, Unit::Deg),
            _ => {
                return Err(format!(
                    "gait file {shown}, line {header_line}, column {}: unknown column `{raw}` ({COLUMNS_HELP}; the unit is part of the name)",
                    index + 1
                ))
            }
        };
        if let Some(Column { index: first, .. }) = slot {
            return Err(format!(
                "gait file {shown}, line {header_line}, column {}: `{raw}` repeats column {} \
                 (one column per joint)",
                index + 1,
                *first + 1
            ));
        }
        *slot = Some(Column {
            index,
            name: raw.to_string(),
            unit,
        });
    }
    let missing = |what: &str| {
        format!("gait file {shown}, line {header_line}: no {what} column in the header `{}` ({COLUMNS_HELP})", header.iter().collect::<Vec<_>>().join(","))
    };
    let time = time.ok_or_else(|| missing("time"))?;
    let knee = knee.ok_or_else(|| missing("knee angle"))?;

    let (mut t, mut h, mut k, mut lines) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    for record in reader.records() {
        let record = record.map_err(|e| match e.position() {
            Some(p) => format!("{}: {e}", at(p.line(), None)),
            None => format!("gait file {shown}: {e}"),
        })?;
        let line = record.position().map_or(0, |p| p.line());
        let value = |c: &Column| -> Result<f64, String> {
            let raw = record.get(c.index).unwrap_or("");
            let v: f64 = raw
                .parse()
                .map_err(|_| format!("{}: `{raw}` is not a number", at(line, Some(c))))?;
            // Huge values, named as typed (non-finite ones are the recording's to report).
            let limit = match (c.index == time.index, c.unit) {
                (true, _) => MAX_TIME_S,
                (false, Unit::Rad) => MAX_ANGLE_RAD,
                (false, Unit::Deg) => MAX_ANGLE_RAD.to_degrees(),
            };
            if v.is_finite() && v.abs() > limit {
                let unit = if c.index == time.index {
                    "s"
                } else if c.unit == Unit::Deg {
                    "deg"
                } else {
                    "rad"
                };
                return Err(format!(
                    "{}: `{raw}` is out of range (allowed: within ±{} {unit})",
                    at(line, Some(c)),
                    crate::config_help::compact_number(limit)
                ));
            }
            Ok(match c.unit {
                Unit::Rad => v,
                Unit::Deg => v.to_radians(),
            })
        };
        t.push(value(&time)?);
        if let Some(c) = &hip {
            h.push(value(c)?);
        }
        k.push(value(&knee)?);
        lines.push(line);
    }
    GaitRecording::new(&t, hip.as_ref().map(|_| h.as_slice()), &k).map_err(|e| {
        let column = match e.column() {
            Some(RecordingColumn::Time) => Some(&time),
            Some(RecordingColumn::Hip) => hip.as_ref(),
            Some(RecordingColumn::Knee) => Some(&knee),
            None => None,
        };
        let place = match e.sample() {
            Some(i) => at(lines[i], column),
            None => format!("gait file {shown}"),
        };
        let hint = match (&e, column) {
            (RecordingError::Implausible { .. }, Some(c)) if c.unit == Unit::Rad => {
                let joint = c.name.trim_end_matches("_rad").trim_end_matches("_RAD");
                format!("; if this column is in degrees, name it {joint}_deg")
            }
            _ => String::new(),
        };
        format!("{place}: {e}{hint}")
    })
}

/// Loads the recording named by `s.trajectory.file` (relative to `base`, the config file's
/// folder) into `s.trajectory.recording`, when `kind = "recorded"` and a file is named.
pub fn attach_recording(s: &mut Experiment, base: &Path) -> Result<(), CliError> {
    if s.trajectory.kind != TrajectoryKind::Recorded {
        return Ok(());
    }
    if let Some(file) = &s.trajectory.file {
        let path = base.join(file);
        s.trajectory.recording = Some(Arc::new(read_gait(&path)?));
    }
    Ok(())
}

/// Makes `path` (as given on the command line, relative to the working directory) the
/// scenario's desired motion: `kind = "recorded"`, `file = path`, recording loaded, validated.
pub fn use_gait(s: &mut Experiment, path: &Path) -> Result<(), CliError> {
    s.trajectory.kind = TrajectoryKind::Recorded;
    s.trajectory.file = Some(path.to_path_buf());
    s.trajectory.recording = Some(Arc::new(read_gait(path)?));
    s.validate()
        .map_err(|e| CliError::Usage(format!("--gait: {e}")))
}

/// The CSV text of joint angles sampled at `times`: header `t_s,hip_rad,knee_rad` (or
/// `t_s,knee_rad` without `hip`), angles with 9 decimals (1e-9 rad), after `comment` lines.
pub fn gait_csv(comment: &[String], times: &[f64], hip: Option<&[f64]>, knee: &[f64]) -> String {
    let mut out = String::new();
    for c in comment {
        out.push_str(&format!("# {c}\n"));
    }
    out.push_str(if hip.is_some() {
        "t_s,hip_rad,knee_rad\n"
    } else {
        "t_s,knee_rad\n"
    });
    for (i, t) in times.iter().enumerate() {
        match hip {
            Some(h) => out.push_str(&format!("{t:.6},{:.9},{:.9}\n", h[i], knee[i])),
            None => out.push_str(&format!("{t:.6},{:.9}\n", knee[i])),
        }
    }
    out
}
