//! `exompc simulate`: one closed-loop run of the scenario; writes `trace.csv` and
//! `summary.json` into `--out` (default `out/`) and prints a short summary.

use crate::{ConfigOpt, ControllerArg};
use clap::Args;
use exompc::config::Formulation;
use exompc_cli::config_help::{describe_error, KeyOrigins};
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
    #[arg(long, value_enum)]
    pub(crate) controller: Option<ControllerArg>,
    /// Override `multistage.formulation` (msnmpc only).
    #[arg(long, value_enum)]
    pub(crate) formulation: Option<FormulationArg>,
    /// Override `uncertainty.payload_kg` (kg).
    #[arg(long, value_name = "KG", allow_negative_numbers = true)]
    pub(crate) payload: Option<f64>,
    /// Override the run length (s) of the chosen experiment.
    #[arg(long, value_name = "S", allow_negative_numbers = true)]
    pub(crate) duration: Option<f64>,
    /// Output folder for `trace.csv` and `summary.json`.
    #[arg(long, value_name = "DIR", default_value = "out")]
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

/// Formulation choice on the command line.
#[derive(Debug, Clone, Copy, clap::ValueEnum)]
pub(crate) enum FormulationArg {
    Decoupled,
    Coupled,
}

impl From<FormulationArg> for Formulation {
    fn from(f: FormulationArg) -> Self {
        match f {
            FormulationArg::Decoupled => Formulation::Decoupled,
            FormulationArg::Coupled => Formulation::Coupled,
        }
    }
}

/// Command-line spelling of a formulation.
pub(crate) fn formulation_name(f: FormulationArg) -> &'static str {
    match f {
        FormulationArg::Decoupled => "decoupled",
        FormulationArg::Coupled => "coupled",
    }
}

/// Apply the command-line overrides to the scenario and validate the result; a bad flag value
/// is reported naming the flag.
pub(crate) fn apply_overrides(
    s: &mut exompc::config::Scenario,
    dof: u8,
    controller: Option<ControllerArg>,
    formulation: Option<FormulationArg>,
    payload: Option<f64>,
    duration: Option<f64>,
) -> Result<(), CliError> {
    let origins = KeyOrigins {
        unset: "default or --config",
        ..KeyOrigins::default()
    };
    apply_overrides_with(s, &origins, dof, controller, formulation, payload, duration)
}

/// [`apply_overrides`] knowing which keys the config file set (`origins`), so that a flag
/// value conflicting with another key names both and says which one the user set where.
pub(crate) fn apply_overrides_with(
    s: &mut exompc::config::Scenario,
    origins: &KeyOrigins,
    dof: u8,
    controller: Option<ControllerArg>,
    formulation: Option<FormulationArg>,
    payload: Option<f64>,
    duration: Option<f64>,
) -> Result<(), CliError> {
    let mut origins = origins.clone();
    if let Some(k) = controller {
        s.controller.kind = k.into();
    }
    if let (Some(f), Some(k)) = (formulation, controller) {
        if !matches!(k, ControllerArg::Msnmpc) {
            return Err(CliError::Usage(format!(
                "--formulation {} applies to --controller msnmpc only, not --controller {}",
                formulation_name(f),
                crate::sweep::controller_name(k)
            )));
        }
    }
    if let Some(f) = formulation {
        s.multistage.formulation = f.into();
    }
    if let Some(p) = payload {
        s.uncertainty.payload_kg = p;
        origins.set_by_flag("uncertainty.payload_kg", "--payload");
        s.validate()
            .map_err(|e| CliError::Usage(format!("--payload: {}", describe_error(&e, &origins))))?;
    }
    if let Some(d) = duration {
        if dof == 1 {
            s.timing.duration_1dof_s = d;
            origins.set_by_flag("timing.duration_1dof_s", "--duration");
        } else {
            s.timing.duration_2dof_s = d;
            origins.set_by_flag("timing.duration_2dof_s", "--duration");
        }
        s.validate().map_err(|e| {
            CliError::Usage(format!("--duration: {}", describe_error(&e, &origins)))
        })?;
    }
    Ok(())
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
    io::ensure_out_dir(&a.out)?;
    exompc_cli::earlier::refuse_or_clear(&a.out, exompc_cli::earlier::RUN_FILES, a.force, "run")?;
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
