//! `exompc simulate`: one closed-loop run of the scenario; writes `trace.csv` and
//! `summary.json` into `--out` (default `out/simulate`) and prints a short summary.

use crate::args::{apply_overrides_with, ConfigOpt, FormulationArg};
use clap::Args;
use exompc::config::ControllerKind;
use exompc_cli::error::CliError;
use exompc_cli::io;
use exompc_cli::run::{describe, run_to_dir};
use exompc_cli::verdict::Verdict;
use std::path::PathBuf;

#[derive(Debug, Args)]
pub(crate) struct SimulateArgs {
    #[command(flatten)]
    pub(crate) config: ConfigOpt,
    /// Experiment: 1 (knee only, hip locked) or 2 (hip and knee).
    #[arg(long, default_value_t = 2, value_parser = clap::value_parser!(u8).range(1..=2))]
    pub(crate) dof: u8,
    /// Override `controller.kind`.
    #[arg(long, value_parser = crate::args::controller_parser())]
    pub(crate) controller: Option<ControllerKind>,
    /// Override `multistage.formulation` (msnmpc only).
    #[arg(long, value_enum)]
    pub(crate) formulation: Option<FormulationArg>,
    /// Override `uncertainty.payload_kg` (kg).
    #[arg(long, value_name = "KG", allow_hyphen_values = true)]
    pub(crate) payload: Option<f64>,
    /// Override the run length (s) of the chosen experiment.
    #[arg(long, value_name = "S", allow_hyphen_values = true)]
    pub(crate) duration: Option<f64>,
    /// Output folder for `trace.csv` and `summary.json`.
    #[arg(long, value_name = "DIR", default_value = "out/simulate")]
    pub(crate) out: PathBuf,
    /// Print the summary as JSON on stdout instead of the readable text.
    #[arg(long)]
    pub(crate) json: bool,
    /// Also draw the figures into the output folder.
    #[arg(long)]
    pub(crate) plot: bool,
    /// Replace the results of an earlier run in the output folder (trace.csv, summary.json,
    /// figures; nothing else). Without it such a folder is refused.
    #[arg(long)]
    pub(crate) force: bool,
    /// Exit 3 when the verdict is `degraded` (monitor trips, held torques, solver fallbacks),
    /// not only 1 when it is `failed`.
    #[arg(long)]
    pub(crate) strict: bool,
}

pub(crate) fn run(a: SimulateArgs) -> Result<(), CliError> {
    let (mut s, origins) = a.config.load_with_origins()?;
    apply_overrides_with(
        &mut s,
        &origins,
        a.dof,
        a.controller,
        a.formulation,
        a.payload,
        a.duration,
    )?;
    exompc_cli::earlier::refuse_or_clear(&a.out, exompc_cli::earlier::RUN_FILES, a.force, "run")?;
    for w in exompc_cli::run::scenario_warnings_interruptible(&s, a.dof)? {
        eprintln!("{w}");
    }
    let _out_dir = io::prepare_out_dir(&a.out)?;
    let summary = run_to_dir(&s, a.dof, Some(&a.out))?;
    if a.plot {
        crate::plot::draw_dir(&a.out)?;
    }
    let verdict = Verdict::of_run(&summary);
    if a.json {
        let json = serde_json::to_string(&summary)
            .map_err(|e| CliError::Runtime(format!("serialising summary: {e}")))?;
        println!("{json}");
    } else {
        println!("{}", describe(&summary));
        println!("  wrote {}/trace.csv and summary.json", a.out.display());
        println!("{verdict}");
    }
    verdict.outcome("run", a.strict)
}
