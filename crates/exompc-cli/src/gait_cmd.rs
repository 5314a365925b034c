//! `exompc gait export`: samples the scenario's desired motion (the parametric gait of
//! docs/MODEL.md §6 by default) into a gait CSV that `[trajectory] kind = "recorded"` or
//! `--gait FILE` replays.

use crate::args::ConfigOpt;
use clap::{Args, Subcommand};
use exompc::config::Experiment;
use exompc::scenario::{Dof, OneDof, TwoDof};
use exompc::sim::Trajectory;
use exompc_cli::error::CliError;
use exompc_cli::gait::gait_csv;
use exompc_cli::io;
use std::path::PathBuf;

#[derive(Debug, Args)]
pub(crate) struct GaitArgs {
    #[command(subcommand)]
    command: GaitCommand,
}

#[derive(Debug, Subcommand)]
enum GaitCommand {
    /// Write the scenario's desired joint angles, sampled at --rate, as a gait CSV
    /// (t_s,hip_rad,knee_rad; t_s,knee_rad for --dof 1).
    Export(ExportArgs),
}

#[derive(Debug, Args)]
struct ExportArgs {
    #[command(flatten)]
    config: ConfigOpt,
    /// Layout: 2 (hip and knee columns) or 1 (knee column only).
    #[arg(long, default_value_t = 2, value_parser = clap::value_parser!(u8).range(1..=2))]
    dof: u8,
    /// Sample rate (Hz), in [1, 100000].
    #[arg(
        long,
        value_name = "HZ",
        default_value_t = 100.0,
        allow_hyphen_values = true
    )]
    rate: f64,
    /// Length (s); default: the scenario's run length of the layout (timing.duration_Ndof_s).
    #[arg(long, value_name = "S", allow_hyphen_values = true)]
    duration: Option<f64>,
    /// Output CSV file; default `out/gait/gait_<dof>dof.csv`.
    #[arg(long, value_name = "FILE")]
    out: Option<PathBuf>,
    /// Replace an existing output file (without it, an existing file is refused).
    #[arg(long)]
    force: bool,
}

pub(crate) fn run(a: GaitArgs) -> Result<(), CliError> {
    match a.command {
        GaitCommand::Export(e) => export(&e),
    }
}

fn export(a: &ExportArgs) -> Result<(), CliError> {
    let s = a.config.load()?;
    if !(a.rate.is_finite() && (1.0..=1e5).contains(&a.rate)) {
        return Err(CliError::Usage(format!(
            "--rate {}: out of range (allowed: finite, in [1, 100000] Hz)",
            crate::args::show_number(a.rate)
        )));
    }
    let duration = a.duration.unwrap_or(s.duration_s(a.dof as usize));
    if !(duration.is_finite() && duration > 0.0 && duration * a.rate <= 1e8) {
        return Err(CliError::Usage(format!(
            "--duration {}: out of range (allowed: finite, > 0 s, at most 1e8 samples at --rate)",
            crate::args::show_number(duration)
        )));
    }
    let out = a
        .out
        .clone()
        .unwrap_or_else(|| PathBuf::from(format!("out/gait/gait_{}dof.csv", a.dof)));
    if out.is_dir() {
        return Err(CliError::Usage(format!(
            "--out {}: is a folder; give a file name such as {}/walk.csv",
            out.display(),
            out.display()
        )));
    }
    if out.exists() && !a.force {
        return Err(CliError::Usage(format!(
            "{} already exists: choose another --out, or pass --force to replace it",
            out.display()
        )));
    }
    let parent = out.parent().filter(|p| !p.as_os_str().is_empty());
    let _out_dir = parent.map(io::prepare_out_dir).transpose()?;
    let n = (duration * a.rate).round() as usize + 1;
    let times: Vec<f64> = (0..n).map(|k| k as f64 / a.rate).collect();
    let what = match (&s.trajectory.file, a.dof) {
        (Some(f), _) if s.trajectory.recording.is_some() => {
            format!("the recording {} resampled", f.display())
        }
        (_, 1) => "the parametric 1-DOF knee motion of docs/MODEL.md §6".to_string(),
        _ => "the parametric 2-DOF swing of docs/MODEL.md §6".to_string(),
    };
    let comment = vec![
        format!("exompc gait export: {what}"),
        format!(
            "{} Hz, {duration} s, {n} samples; replay with [trajectory] kind = \"recorded\", file = \"...\"",
            a.rate
        ),
    ];
    let text = match a.dof {
        1 => {
            let knee = sample::<OneDof, 1>(&s, &times, 0);
            gait_csv(&comment, &times, None, &knee)
        }
        _ => {
            let hip = sample::<TwoDof, 2>(&s, &times, 0);
            let knee = sample::<TwoDof, 2>(&s, &times, 1);
            gait_csv(&comment, &times, Some(&hip), &knee)
        }
    };
    io::write_atomic(&out, text.as_bytes())?;
    println!(
        "wrote {} ({n} samples, {duration} s at {} Hz)",
        out.display(),
        a.rate
    );
    Ok(())
}

/// Joint `j`'s desired angle of layout `D` at `times`.
fn sample<D: Dof<N>, const N: usize>(s: &Experiment, times: &[f64], j: usize) -> Vec<f64> {
    let traj = D::trajectory(s);
    times.iter().map(|&t| traj.position(t)[j]).collect()
}
