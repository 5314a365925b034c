//! `exompc faults`: the fault-response scan (issue 28): sensor fault kinds × channel groups ×
//! durations × start times × payloads, each judged against the same run without the fault;
//! writes `faults.md` and `faults.json` into `--out` (default `out/faults`).

use crate::args::{parse_payloads, ConfigOpt};
use clap::Args;
use exompc::config::ControllerKind;
use exompc::scenario::{fault_scan_markdown, run_fault_scan, ChannelGroup, FaultGrid, RunError};
use exompc::sim::FaultKind;
use exompc_cli::error::CliError;
use exompc_cli::io;
use std::path::PathBuf;

/// What `faults` writes into its folder.
const FAULT_FILES: &[&str] = &["faults.md", "faults.json"];

#[derive(Debug, Args)]
pub(crate) struct FaultsArgs {
    #[command(flatten)]
    config: ConfigOpt,
    /// Fault kinds, comma-separated (spike, dropout, nan, inf, stuck, saturation).
    #[arg(long, value_name = "LIST", default_value = "spike,dropout,nan,stuck")]
    kinds: String,
    /// Channel groups, comma-separated (all, angles, velocities, forces).
    #[arg(
        long,
        value_name = "LIST",
        default_value = "all,angles,velocities,forces"
    )]
    groups: String,
    /// Fault durations (s), comma-separated, each in (0, run length).
    #[arg(long, value_name = "LIST", default_value = "0.06,0.2")]
    durations: String,
    /// Fault start times (s), comma-separated, each in [0, run length).
    #[arg(long, value_name = "LIST", default_value = "3")]
    starts: String,
    /// Payloads (kg), `start:step:end` or a comma list.
    #[arg(long, value_name = "LIST", default_value = "0,2")]
    payloads: String,
    /// Length of each run (s), in (0, 600].
    #[arg(long, value_name = "S", default_value_t = 10.0)]
    run_s: f64,
    /// Override `controller.kind`.
    #[arg(long, value_parser = crate::args::controller_parser())]
    controller: Option<ControllerKind>,
    /// Output folder.
    #[arg(long, value_name = "DIR", default_value = "out/faults")]
    out: PathBuf,
    /// Replace the results of an earlier scan in the output folder (faults.md, faults.json;
    /// nothing else). Without it such a folder is refused.
    #[arg(long)]
    force: bool,
    /// Exit with status 1 when a cell fails its goals.
    #[arg(long)]
    check: bool,
}

fn list<T>(
    flag: &str,
    spec: &str,
    parse: impl Fn(&str) -> Option<T>,
    allowed: &str,
) -> Result<Vec<T>, CliError> {
    let out: Vec<T> = spec
        .split(',')
        .map(|v| {
            parse(v.trim()).ok_or_else(|| {
                CliError::Usage(format!("{flag}: `{}` is not one of {allowed}", v.trim()))
            })
        })
        .collect::<Result<_, _>>()?;
    if out.is_empty() {
        return Err(CliError::Usage(format!("{flag}: empty list")));
    }
    Ok(out)
}

fn times(flag: &str, spec: &str, lo: f64, hi: f64, closed_lo: bool) -> Result<Vec<f64>, CliError> {
    list(
        flag,
        spec,
        |v| {
            v.parse::<f64>().ok().filter(|x| {
                x.is_finite() && (if closed_lo { *x >= lo } else { *x > lo }) && *x < hi
            })
        },
        &format!(
            "the numbers in {}{lo}, {hi}) s",
            if closed_lo { "[" } else { "(" }
        ),
    )
}

pub(crate) fn run(a: FaultsArgs) -> Result<(), CliError> {
    let mut base = a.config.load()?;
    if let Some(k) = a.controller {
        base.controller.kind = k;
    }
    if !(a.run_s.is_finite() && a.run_s > 0.0 && a.run_s <= 600.0) {
        return Err(CliError::Usage(format!(
            "--run-s: must be in (0, 600] s, got {}",
            a.run_s
        )));
    }
    let kinds = list(
        "--kinds",
        &a.kinds,
        |v| serde_json::from_value::<FaultKind>(serde_json::Value::String(v.into())).ok(),
        "spike, dropout, nan, inf, stuck, saturation",
    )?;
    let groups = list(
        "--groups",
        &a.groups,
        ChannelGroup::parse,
        "all, angles, velocities, forces",
    )?;
    let grid = FaultGrid {
        kinds,
        groups,
        durations_s: times("--durations", &a.durations, 0.0, a.run_s, false)?,
        starts_s: times("--starts", &a.starts, 0.0, a.run_s, true)?,
        payloads_kg: parse_payloads(&a.payloads)?,
        run_s: a.run_s,
    };
    io::ensure_out_dir(&a.out)?;
    exompc_cli::earlier::refuse_or_clear(&a.out, FAULT_FILES, a.force, "faults")?;
    let cells = run_fault_scan(&base, &grid, &|| {}).map_err(|e| match e {
        RunError::Config(c) => CliError::Usage(c.to_string()),
        other => CliError::Runtime(other.to_string()),
    })?;
    let json = serde_json::to_string_pretty(&serde_json::json!({
        "grid": grid,
        "controller": base.controller.kind.to_string(),
        "cells": cells,
    }))
    .map_err(|e| CliError::Runtime(format!("serialising the scan: {e}")))?;
    io::write_atomic(&a.out.join("faults.json"), json.as_bytes())?;
    let md = fault_scan_markdown(&cells);
    io::write_atomic(&a.out.join("faults.md"), md.as_bytes())?;
    print!("{md}");
    println!(
        "  wrote {} and faults.json",
        a.out.join("faults.md").display()
    );
    if a.check && cells.iter().any(|c| !c.pass) {
        return Err(CliError::Runtime(format!(
            "{} of {} cells fail their goals",
            cells.iter().filter(|c| !c.pass).count(),
            cells.len()
        )));
    }
    Ok(())
}
