//! `exompc`: command-line front end of the exompc toolkit.
//!
//! Exit codes: 0 success, 1 runtime failure, 2 bad input (invalid config value, unknown key,
//! bad flag, or a subcommand that is not implemented yet). Every error is one `error: ...`
//! line on stderr.

mod bench;

use clap::{Args, Parser, Subcommand};
use exompc::config::{ControllerKind, Scenario};
use exompc_cli::error::CliError;
use exompc_cli::io;
use std::io::Write as _;
use std::path::PathBuf;
use std::process::ExitCode;

/// Multi-stage robust nonlinear MPC of a lower-limb exoskeleton: simulation and tools.
#[derive(Debug, Parser)]
#[command(name = "exompc", version, about, propagate_version = true)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Run one closed-loop simulation and write its traces and metrics.
    Simulate(SimulateArgs),
    /// Run a grid of simulations (controllers × payloads) and write a metrics table.
    Sweep(SweepArgs),
    /// Evaluate the robot/human models at a state (dynamics terms, for checking).
    Model(ModelArgs),
    /// Solve one NMPC problem at a given state and print the solution.
    Solve(SolveArgs),
    /// Print the default scenario as TOML (`exompc config > my.toml`), or check a file.
    Config(ConfigArgs),
    /// Time the controllers on the default scenario.
    Bench(BenchArgs),
    /// Plot traces written by `simulate`.
    Plot(PlotArgs),
    /// Long randomised runs with fault injection, checking the safety monitors.
    Soak(SoakArgs),
}

/// `--config FILE`, shared by the subcommands that run a scenario.
#[derive(Debug, Args)]
struct ConfigOpt {
    /// Scenario TOML file applied on top of the default scenario (see `exompc config`).
    #[arg(long, value_name = "FILE")]
    config: Option<PathBuf>,
}

impl ConfigOpt {
    /// Loads and validates the scenario named by `--config` (the default when absent).
    fn load(&self) -> Result<Scenario, CliError> {
        io::load_scenario(self.config.as_deref())
    }
}

#[derive(Debug, Args)]
struct SimulateArgs {
    #[command(flatten)]
    config: ConfigOpt,
    /// Experiment: 1 (knee only, hip locked) or 2 (hip and knee).
    #[arg(long, default_value_t = 2, value_parser = clap::value_parser!(u8).range(1..=2))]
    dof: u8,
    /// Override `controller.kind`.
    #[arg(long, value_enum)]
    controller: Option<ControllerArg>,
    /// Override `uncertainty.payload_kg` (kg).
    #[arg(long, value_name = "KG")]
    payload: Option<f64>,
    /// Output folder for traces and metrics.
    #[arg(long, value_name = "DIR")]
    out: Option<PathBuf>,
}

#[derive(Debug, Args)]
struct SweepArgs {
    #[command(flatten)]
    config: ConfigOpt,
    /// Output folder for the metrics table.
    #[arg(long, value_name = "DIR")]
    out: Option<PathBuf>,
}

#[derive(Debug, Args)]
struct ModelArgs {}

#[derive(Debug, Args)]
struct SolveArgs {}

#[derive(Debug, Args)]
struct ConfigArgs {
    /// Instead of printing the default, load and validate FILE and report the first problem.
    #[arg(long, value_name = "FILE")]
    check: Option<PathBuf>,
}

#[derive(Debug, Args)]
struct BenchArgs {
    #[command(flatten)]
    config: ConfigOpt,
    /// Print one JSON object instead of tables.
    #[arg(long)]
    json: bool,
    /// Closed-loop steps per controller (default: the scenario's 2-DOF run).
    #[arg(long, value_name = "N")]
    steps: Option<usize>,
}

#[derive(Debug, Args)]
struct PlotArgs {
    /// Folder written by `simulate`.
    #[arg(value_name = "DIR")]
    input: Option<PathBuf>,
}

#[derive(Debug, Args)]
struct SoakArgs {
    #[command(flatten)]
    config: ConfigOpt,
    /// Output folder for the soak report.
    #[arg(long, value_name = "DIR")]
    out: Option<PathBuf>,
}

/// Controller choice on the command line (mirrors [`ControllerKind`]).
#[derive(Debug, Clone, Copy, clap::ValueEnum)]
enum ControllerArg {
    Pd,
    Nmpc,
    Msnmpc,
}

impl From<ControllerArg> for ControllerKind {
    fn from(c: ControllerArg) -> Self {
        match c {
            ControllerArg::Pd => ControllerKind::Pd,
            ControllerArg::Nmpc => ControllerKind::Nmpc,
            ControllerArg::Msnmpc => ControllerKind::Msnmpc,
        }
    }
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    match run(cli) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::from(e.exit_code())
        }
    }
}

fn run(cli: Cli) -> Result<(), CliError> {
    match cli.command {
        Command::Config(a) => cmd_config(&a),
        Command::Simulate(a) => {
            let mut scenario = a.config.load()?;
            if let Some(k) = a.controller {
                scenario.controller.kind = k.into();
            }
            if let Some(p) = a.payload {
                scenario.uncertainty.payload_kg = p;
                scenario
                    .validate()
                    .map_err(|e| CliError::Usage(format!("--payload: {e}")))?;
            }
            if let Some(out) = &a.out {
                io::ensure_out_dir(out)?;
            }
            let _ = (scenario, a.dof);
            not_implemented("simulate")
        }
        Command::Sweep(a) => {
            let _scenario = a.config.load()?;
            if let Some(out) = &a.out {
                io::ensure_out_dir(out)?;
            }
            not_implemented("sweep")
        }
        Command::Soak(a) => {
            let _scenario = a.config.load()?;
            if let Some(out) = &a.out {
                io::ensure_out_dir(out)?;
            }
            not_implemented("soak")
        }
        Command::Bench(a) => bench::run(&a.config.load()?, a.json, a.steps),
        Command::Model(ModelArgs {}) => not_implemented("model"),
        Command::Solve(SolveArgs {}) => not_implemented("solve"),
        Command::Plot(a) => {
            let _ = a.input;
            not_implemented("plot")
        }
    }
}

/// Stub for subcommands the integrator has not wired yet: reported as an error, exit 2.
fn not_implemented(cmd: &'static str) -> Result<(), CliError> {
    Err(CliError::NotImplemented(cmd))
}

/// `exompc config`: print the default scenario, or check a file with `--check FILE`.
fn cmd_config(a: &ConfigArgs) -> Result<(), CliError> {
    if let Some(path) = &a.check {
        io::load_scenario(Some(path))?;
        println!("{}: ok", path.display());
        return Ok(());
    }
    let text = io::default_config_toml()?;
    let mut out = std::io::stdout().lock();
    out.write_all(text.as_bytes())
        .and_then(|()| out.flush())
        .map_err(|e| CliError::io("writing to stdout", e))
}
