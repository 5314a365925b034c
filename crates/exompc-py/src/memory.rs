//! The memory a run will keep, checked against the memory available before the run starts, so
//! that an absurd duration is a `ValueError` naming the limit instead of a failed allocation
//! that aborts the interpreter.

use crate::ConfigError;
use exompc::config::{scenarios, Experiment};
use exompc::scenario::controller_info;
use pyo3::prelude::*;

/// Share of the available memory one call may plan to use.
pub const SHARE: f64 = 0.8;

/// Most memory one call plans to keep, whatever is available (16 GiB: a 2-DOF MS-NMPC trace
/// of about 5 days at 100 Hz); longer records are better streamed to disk (`exompc simulate
/// --out` writes its trace as it goes).
pub const MAX_PLAN: u64 = 16 << 30;

/// Bytes per step the summary keeps (one step time, doubled for the buffer's growth).
pub const METRICS_PER_STEP: u64 = 16;

/// Bytes per step of the Python-side status column (`numpy.str_` array of the names, `<U15`).
const PY_STATUS_PER_STEP: u64 = 64;

/// Memory available to new allocations (bytes), `MemAvailable` of `/proc/meminfo` (Linux).
fn available_bytes() -> Option<u64> {
    let text = std::fs::read_to_string("/proc/meminfo").ok()?;
    let line = text.lines().find(|l| l.starts_with("MemAvailable:"))?;
    let kb: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb.saturating_mul(1024))
}

/// Number of scenarios of the scenario's controller (0 without scenarios).
pub fn scenario_count(s: &Experiment) -> usize {
    match controller_info(s.controller.kind) {
        Ok(info) if info.multistage => scenarios::count(s),
        _ => 0,
    }
}

/// Bytes per step of `simulate`'s trace columns for `n` joints and `scenarios` scenarios.
pub fn trace_per_step(n: usize, scenarios: usize) -> u64 {
    // t, the per-joint/strap columns, μ, disturbances
    let f64s = 1 + crate::convert::trace_vector_columns().count() * n + scenarios + scenarios * n;
    (f64s * 8 + 1 + 4 + 8 + 1) as u64 + PY_STATUS_PER_STEP // status, iterations, time, limits
}

/// Checks that `runs` concurrent runs of `s` in the `dof` layout, keeping `per_step` bytes per
/// control step each, fit in [`SHARE`] of the available memory. `arg` names what the user set
/// (`"duration"` or the duration key); `hint` says how to need less.
pub fn check(
    arg: &str,
    s: &Experiment,
    dof: u8,
    per_step: u64,
    runs: u64,
    hint: &str,
) -> PyResult<()> {
    let steps = s.control_steps(usize::from(dof)) as u64;
    let need = steps.saturating_mul(per_step).saturating_mul(runs.max(1));
    let share = available_bytes().map(|a| ((a as f64 * SHARE) as u64, a));
    let (limit, source) = match share {
        Some((l, a)) if l < MAX_PLAN => (
            l,
            format!(
                "{:.0} % of the {} of memory available now",
                SHARE * 100.0,
                gb(a)
            ),
        ),
        _ => (MAX_PLAN, "the most one call plans to keep".to_string()),
    };
    if need <= limit {
        return Ok(());
    }
    let at_once = if runs > 1 {
        format!(", {runs} runs at once")
    } else {
        String::new()
    };
    Err(ConfigError::new_err(format!(
        "{arg}: {} s at timing.dt = {} s is {steps} control steps{at_once}; keeping them needs \
         about {} ({per_step} B per step), more than the limit of {} ({source}); {hint}",
        s.duration_s(usize::from(dof)),
        s.timing.dt,
        gb(need),
        gb(limit),
    )))
}

/// Bytes as decimal gigabytes (`26.4 GB`).
fn gb(b: u64) -> String {
    format!("{:.1} GB", b as f64 / 1e9)
}
