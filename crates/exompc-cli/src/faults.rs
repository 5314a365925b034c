//! `exompc faults`: the fault-response scan (issue 28): sensor fault kinds × channel groups ×
//! durations × start times × payloads, each judged against the same run without the fault;
//! writes `faults.md`, `faults.json` and the heat map `faults.{png,svg}` into `--out` (default
//! `out/faults`).

use crate::args::{parse_payloads, ConfigOpt};
use crate::plot::{heat_cell, heat_err as err, write_drawing, Drawing};
use clap::Args;
use exompc::config::ControllerKind;
use exompc::scenario::{
    fault_scan_markdown, run_fault_scan, ChannelGroup, FaultCell, FaultGrid, RunError,
};
use exompc::sim::FaultKind;
use exompc_cli::error::CliError;
use exompc_cli::io;
use plotters::coord::Shift;
use plotters::prelude::*;
use std::path::{Path, PathBuf};

/// What `faults` writes into its folder.
const FAULT_FILES: &[&str] = &["faults.md", "faults.json", "faults.png", "faults.svg"];

/// The heat map's colour scale saturates at this peak strap force (N).
const HEAT_MAX_N: f64 = 120.0;

#[derive(Debug, Args)]
pub(crate) struct FaultsArgs {
    #[command(flatten)]
    config: ConfigOpt,
    /// Fault kinds, comma-separated (spike, dropout, nan, inf, stuck, saturation).
    #[arg(long, value_name = "LIST", default_value = "spike,dropout,nan,stuck")]
    kinds: String,
    /// Channel groups, comma-separated (all, angles, velocities, forces; joint1, joint2: one
    /// joint's encoder, its angle and velocity).
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
    /// Replace the results of an earlier scan in the output folder (faults.md, faults.json,
    /// faults.png, faults.svg; nothing else). Without it such a folder is refused.
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
        FaultKind::parse,
        &FaultKind::NAMES.join(", "),
    )?;
    let groups = list(
        "--groups",
        &a.groups,
        ChannelGroup::parse,
        &ChannelGroup::NAMES.join(", "),
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
    heat_map(&grid, &cells, &a.out)?;
    print!("{md}");
    println!(
        "  wrote {}, faults.json, faults.png and faults.svg",
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

/// The heat map: rows kind × group, columns duration × payload × start (in the grid's
/// order); each cell coloured by its peak true strap force and labelled with it, a black frame
/// and `✗` where the cell fails its goals; a colour bar up to [`HEAT_MAX_N`].
fn draw<DB: DrawingBackend>(
    root: DrawingArea<DB, plotters::coord::Shift>,
    grid: &FaultGrid,
    cells: &[FaultCell],
) -> Result<(), CliError>
where
    DB::ErrorType: 'static,
{
    let font = "sans-serif";
    root.fill(&WHITE).map_err(err)?;
    let (w, h) = root.dim_in_pixel();
    root.draw(&Text::new(
        "Peak true strap force (N) under sensor faults",
        (20, 12),
        (font, 20).into_font(),
    ))
    .map_err(err)?;
    let legend = [
        "✗ fails its goals: peak ≤ 12 N for one channel group, ≤ 35 N for all, ≤ 70 N beyond",
        "200 ms; RMS ≤ 1.5× the clean run's; no latch.   Grey: the run failed.",
    ];
    for (l, text) in legend.into_iter().enumerate() {
        root.draw(&Text::new(
            text,
            (20, 38 + 17 * l as i32),
            (font, 13).into_font(),
        ))
        .map_err(err)?;
    }
    let rows: Vec<(FaultKind, ChannelGroup)> = grid
        .kinds
        .iter()
        .flat_map(|&k| grid.groups.iter().map(move |&g| (k, g)))
        .collect();
    let cols: Vec<(f64, f64, f64)> = grid
        .durations_s
        .iter()
        .flat_map(|&d| {
            grid.payloads_kg
                .iter()
                .flat_map(move |&p| grid.starts_s.iter().map(move |&t| (d, p, t)))
        })
        .collect();
    let (left, top, bottom, bar_w) = (170i32, 100i32, 64i32, 110i32);
    let nr = rows.len().max(1) as i32;
    let nc = cols.len().max(1) as i32;
    let cw = ((w as i32 - left - bar_w - 10) / nc).max(10);
    let ch = ((h as i32 - top - bottom) / nr).max(10);
    crate::plot::colour_bar(
        &root,
        (w as i32 - bar_w + 20, top),
        nr * ch,
        font,
        HEAT_MAX_N,
    )?;
    for (j, &(d, p, t)) in cols.iter().enumerate() {
        let x = left + j as i32 * cw + 4;
        let lines = [
            format!("{:.0} ms", d * 1e3),
            format!("{p} kg"),
            format!("at {t} s"),
        ];
        for (l, text) in lines.into_iter().enumerate() {
            root.draw(&Text::new(
                text,
                (x, top + nr * ch + 6 + 16 * l as i32),
                (font, 12).into_font(),
            ))
            .map_err(err)?;
        }
    }
    for (i, &(k, g)) in rows.iter().enumerate() {
        let y = top + i as i32 * ch;
        root.draw(&Text::new(
            format!("{} · {}", k.name(), g.name()),
            (10, y + ch / 2 - 7),
            (font, 13).into_font(),
        ))
        .map_err(err)?;
        for (j, &(d, p, t)) in cols.iter().enumerate() {
            let x = left + j as i32 * cw;
            let cell = cells.iter().find(|c| {
                c.kind == k
                    && c.group == g
                    && c.duration_s == d
                    && c.payload_kg == p
                    && c.start_s == t
            });
            let v = cell.map_or(f64::NAN, |c| c.peak_force_n);
            let fail = cell.is_some_and(|c| !c.pass);
            let mut label = if v.is_finite() {
                format!("{v:.0}")
            } else {
                "failed".into()
            };
            if fail {
                label += " ✗";
            }
            heat_cell(
                &root,
                (x, y, cw, ch),
                v,
                HEAT_MAX_N,
                if fail { 2 } else { 0 },
                label,
                cw / 2 - 16,
                13,
            )?;
        }
    }
    root.present().map_err(err)?;
    Ok(())
}

/// The heat map of a fault scan (drawn by [`draw`]).
struct FaultMap<'a> {
    grid: &'a FaultGrid,
    cells: &'a [FaultCell],
}

impl Drawing for FaultMap<'_> {
    fn draw<DB: DrawingBackend>(&self, root: DrawingArea<DB, Shift>) -> Result<(), CliError>
    where
        DB::ErrorType: 'static,
    {
        draw(root, self.grid, self.cells)
    }
}

/// Writes `dir/faults.svg` and `dir/faults.png`.
fn heat_map(grid: &FaultGrid, cells: &[FaultCell], dir: &Path) -> Result<(), CliError> {
    let rows = grid.kinds.len() * grid.groups.len();
    let cols = grid.durations_s.len() * grid.payloads_kg.len() * grid.starts_s.len();
    let size = (
        (290 + 64 * cols).clamp(700, 4000) as u32,
        (170 + 30 * rows).clamp(300, 4000) as u32,
    );
    write_drawing(&FaultMap { grid, cells }, dir, "faults", size).map(drop)
}
