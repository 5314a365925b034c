//! The trace CSV written by `simulate`, `sweep` and `soak`, streamed row by row (nothing held in
//! memory) through an [`AtomicWriter`], and read back by `plot`.
//!
//! Columns: the library's table ([`exompc::sim::trace::TRACE_COLUMNS`], listed in
//! docs/REPRODUCING.md): `t`; per joint J (`hip`, `knee`; 1-DOF: `knee`) `q_robot_J, …,
//! torque_human_J`; per strap S `force_true_S, force_measured_S`; per scenario `mu_K` and per
//! scenario and joint `dist_K_J`; then `status, iterations, step_us`.
//! The scenario key `K` is its number `1, 2, ...` for the `multistage.payloads_kg` shorthand
//! (whose names `"0 kg"`, ... are in `summary.json`) and its name for
//! `[[multistage.scenarios]]` (e.g. `mu_soft straps`).

use crate::error::CliError;
use crate::io::AtomicWriter;
use exompc::sim::{Recorder, StepRecord};
use std::io::Write;
use std::path::Path;

pub use exompc::sim::trace::{joint_names, strap_names};

/// Column names of a trace with `n` joints and `scenarios` scenarios keyed `1, 2, ...`.
pub fn header(n: usize, scenarios: usize) -> Vec<String> {
    header_with(n, &numbered(scenarios))
}

/// The scenario keys `1, 2, ..., scenarios`.
pub fn numbered(scenarios: usize) -> Vec<String> {
    (1..=scenarios).map(|i| i.to_string()).collect()
}

/// Column names of a trace with `n` joints and one scenario per key of `scenarios` (columns
/// `mu_K`, `dist_K_J`): the library's table ([`exompc::sim::trace::csv_header`]).
pub fn header_with(n: usize, scenarios: &[String]) -> Vec<String> {
    exompc::sim::trace::csv_header(n, scenarios)
}

/// Where a [`CsvTrace`] writes: a temporary file renamed when finished, or (`run`,
/// `virtual-robot`) the final file itself, written as the run goes.
enum Sink {
    Atomic(AtomicWriter),
    Live(std::fs::File),
}

impl Write for Sink {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        match self {
            Sink::Atomic(w) => w.write(buf),
            Sink::Live(f) => f.write(buf),
        }
    }
    fn flush(&mut self) -> std::io::Result<()> {
        match self {
            Sink::Atomic(w) => w.flush(),
            Sink::Live(f) => f.flush(),
        }
    }
}

/// A streaming CSV trace recorder.
pub struct CsvTrace {
    out: std::io::BufWriter<Sink>,
    scenarios: usize,
    n: usize,
    line: String,
}

impl CsvTrace {
    /// Create `path` (through a temporary file renamed by [`CsvTrace::finish`]) and write the
    /// header for `n` joints and `scenarios` scenarios.
    pub fn create(path: &Path, n: usize, scenarios: usize) -> Result<Self, CliError> {
        Self::create_with(path, n, &numbered(scenarios))
    }

    /// [`CsvTrace::create`] with the scenario keys `scenarios` (see [`header_with`]).
    pub fn create_with(path: &Path, n: usize, scenarios: &[String]) -> Result<Self, CliError> {
        Self::start(
            Sink::Atomic(AtomicWriter::create(path)?),
            path,
            n,
            scenarios,
        )
    }

    /// A trace written directly to its final file `path` (created new: an existing file is an
    /// error), so that the rows written so far survive a crash or kill -9; call
    /// [`CsvTrace::flush`] regularly and [`CsvTrace::finish`] (fsync) at the end.
    pub fn create_live(path: &Path, n: usize, scenarios: &[String]) -> Result<Self, CliError> {
        let f = std::fs::OpenOptions::new()
            .write(true)
            .create_new(true)
            .open(path)
            .map_err(|e| CliError::io(format!("cannot create {}", path.display()), e))?;
        Self::start(Sink::Live(f), path, n, scenarios)
    }

    fn start(sink: Sink, path: &Path, n: usize, scenarios: &[String]) -> Result<Self, CliError> {
        let mut out = std::io::BufWriter::with_capacity(1 << 16, sink);
        writeln!(out, "{}", header_with(n, scenarios).join(","))
            .map_err(|e| CliError::io(format!("writing {}", path.display()), e))?;
        Ok(CsvTrace {
            out,
            scenarios: scenarios.len(),
            n,
            line: String::with_capacity(512),
        })
    }

    /// Write the buffered rows to the file.
    pub fn flush(&mut self) -> std::io::Result<()> {
        self.out.flush()
    }

    /// Flush and move the finished file into place (a live trace: flush and fsync).
    pub fn finish(self) -> Result<(), CliError> {
        let w = self
            .out
            .into_inner()
            .map_err(|e| CliError::io("flushing trace", e.into_error()))?;
        match w {
            Sink::Atomic(w) => w.finish(),
            Sink::Live(f) => f.sync_all().map_err(|e| CliError::io("syncing trace", e)),
        }
    }
}

impl<const N: usize> Recorder<N> for CsvTrace {
    fn record(&mut self, r: &StepRecord<'_, N>) -> std::io::Result<()> {
        debug_assert_eq!(N, self.n);
        self.line.clear();
        exompc::sim::trace::csv_row(r, self.scenarios, &mut self.line);
        self.out.write_all(self.line.as_bytes())
    }
}

/// A trace read back from CSV: numeric columns (the `status` column as NaN) and the statuses.
#[derive(Clone, Debug, Default)]
pub struct TraceTable {
    /// Column names.
    pub columns: Vec<String>,
    /// Rows of values, one per column.
    pub rows: Vec<Vec<f64>>,
    /// The `status` column.
    pub status: Vec<String>,
}

impl TraceTable {
    /// Index of column `name`.
    pub fn index(&self, name: &str) -> Option<usize> {
        self.columns.iter().position(|c| c == name)
    }

    /// The values of column `name`.
    pub fn column(&self, name: &str) -> Option<Vec<f64>> {
        let i = self.index(name)?;
        Some(self.rows.iter().map(|r| r[i]).collect())
    }

    /// Number of joints (1 or 2) of the trace.
    pub fn joints(&self) -> usize {
        if self.index("q_robot_hip").is_some() {
            2
        } else {
            1
        }
    }

    /// Number of scenarios (probability columns).
    pub fn scenarios(&self) -> usize {
        self.columns.iter().filter(|c| c.starts_with("mu_")).count()
    }

    /// The scenario keys `K` of the probability columns `mu_K`, in order (`1, 2, ...` or the
    /// scenario names).
    pub fn scenario_keys(&self) -> Vec<String> {
        self.columns
            .iter()
            .filter_map(|c| c.strip_prefix("mu_").map(str::to_string))
            .collect()
    }
}

/// Read a trace CSV written by [`CsvTrace`].
pub fn read_trace(path: &Path) -> Result<TraceTable, CliError> {
    let mut rdr = csv::Reader::from_path(path)
        .map_err(|e| CliError::Io(format!("cannot read trace {}: {e}", path.display())))?;
    let columns: Vec<String> = rdr
        .headers()
        .map_err(|e| CliError::Io(format!("bad trace header in {}: {e}", path.display())))?
        .iter()
        .map(str::to_string)
        .collect();
    let st = columns.iter().position(|c| c == "status");
    let mut t = TraceTable {
        columns,
        ..Default::default()
    };
    for rec in rdr.records() {
        let rec =
            rec.map_err(|e| CliError::Io(format!("bad trace row in {}: {e}", path.display())))?;
        let row: Vec<f64> = rec
            .iter()
            .map(|v| v.parse::<f64>().unwrap_or(f64::NAN))
            .collect();
        if let Some(i) = st {
            t.status.push(rec.get(i).unwrap_or("").to_string());
        }
        t.rows.push(row);
    }
    Ok(t)
}
