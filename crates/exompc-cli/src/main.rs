//! `exompc`: command-line front end of the exompc toolkit.
//!
//! Exit codes: 0 success, 1 runtime failure, 2 bad input (invalid config value, unknown key,
//! bad flag). Every error is one `error: ...`
//! line on stderr.

mod bench;
mod envelope_cmd;
mod gait_cmd;
mod model_cmd;
mod plot;
mod realtime;
mod simulate;
mod soak;
mod solve;
mod sweep;

use bench::BenchArgs;
use clap::{Args, Parser, Subcommand};
use envelope_cmd::EnvelopeArgs;
use exompc::config::{ControllerKind, Scenario};
use exompc_cli::error::CliError;
use exompc_cli::io;
use model_cmd::ModelArgs;
use plot::PlotArgs;
use simulate::SimulateArgs;
use soak::SoakArgs;
use solve::SolveArgs;
use std::io::Write as _;
use std::path::PathBuf;
use std::process::ExitCode;
use sweep::SweepArgs;

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
    ///
    /// Reads one JSON object on stdin, e.g.
    /// {"link":"robot","payload_kg":1.0,"q":[0.2,-0.5],"qd":[0.5,-1.0],"tau":[3.0,1.0],"dt":0.01}
    /// (`link`: robot or human; `body_mass_kg` for the human; 1-element arrays for the 1-DOF
    /// shank) and prints {"M":..,"Cqd":..,"G":..,"qdd":..,"next":{"q":..,"qd":..}}: `tau` is the
    /// applied joint torque (robot friction included as the plant has it), `next` one RK4 step
    /// of `dt` with `tau` held.
    Model(ModelArgs),
    /// Solve one NMPC problem at a given state and print the solution.
    ///
    /// Reads one JSON object on stdin, e.g.
    /// {"payload_kg":0.0,"q":[0.1,-0.3],"qd":[0.5,-1.0],"t_prev":[1.0,0.5],"force":[2.0,-1.0],"disturbance":[0,0]}
    /// (force: measured strap forces in N; optional "config" object with np, nc, r_d, r_t,
    /// interaction, torque_max, torque_rate_max) and prints {"status":..,"iterations":..,
    /// "kkt_residual":..,"cost":..,"dT":..,"T":..,"q_pred":..,"qd_pred":..}.
    Solve(SolveArgs),
    /// Print the default scenario as TOML (`exompc config > my.toml`), or check a file.
    Config(ConfigArgs),
    /// Time the controllers on the default scenario.
    Bench(BenchArgs),
    /// Draw the figures (PNG and SVG) of a folder written by `simulate` or `sweep`.
    Plot(PlotArgs),
    /// A long run (1 h by default) with sensor faults, checking limits, NaN and the monitors.
    Soak(SoakArgs),
    /// Drive a robot in real time over UDP (the controller process; see docs/REALTIME.md).
    Run(realtime::RunArgs),
    /// Simulate the robot of `simulate` in real time behind the UDP protocol, to test `run`.
    VirtualRobot(realtime::VirtualRobotArgs),
    /// Scan the operating envelope (scenario changes × payloads × controllers): classify every
    /// run (stable / limit cycle / growing / saturating), judge MS-NMPC against NMPC per cell,
    /// write envelope.json, envelope.md and a heat map (see docs/ROBUSTNESS.md).
    Envelope(EnvelopeArgs),
    /// Recorded gaits: `exompc gait export --out F.csv` samples the desired motion to a CSV
    /// that `[trajectory] kind = "recorded"` or `--gait F.csv` replays (see README).
    Gait(gait_cmd::GaitArgs),
}

/// `--config FILE`, shared by the subcommands that run a scenario.
#[derive(Debug, Args)]
pub(crate) struct ConfigOpt {
    /// Scenario TOML file applied on top of the default scenario (see `exompc config`).
    #[arg(long, value_name = "FILE")]
    pub(crate) config: Option<PathBuf>,
    /// Replay a recorded gait: CSV of time and joint angles (t_s,hip_rad,knee_rad or _deg
    /// columns) as the human's desired motion; sets [trajectory] kind = "recorded", file = FILE.
    #[arg(long, value_name = "FILE.csv")]
    pub(crate) gait: Option<PathBuf>,
}

impl ConfigOpt {
    /// Loads and validates the scenario named by `--config` (the default when absent).
    pub(crate) fn load(&self) -> Result<Scenario, CliError> {
        let mut s = io::load_scenario(self.config.as_deref())?;
        if let Some(g) = &self.gait {
            exompc_cli::gait::use_gait(&mut s, g)?;
        }
        Ok(s)
    }
}

fn main() -> ExitCode {
    // Behave like other Unix tools when the reader of stdout goes away (`exompc ... | head`):
    // end quietly on SIGPIPE instead of panicking on the failed write.
    #[cfg(unix)]
    // SAFETY: restoring the default disposition of SIGPIPE before any thread is started.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
    let cli = Cli::parse();
    // Ctrl-C / SIGTERM: finish cleanly (temporary files removed, say what completed, exit 130).
    exompc_cli::interrupt::install();
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
        Command::Simulate(a) => simulate::run(a),
        Command::Sweep(a) => sweep::run(a),
        Command::Soak(a) => soak::run(a),
        Command::Bench(a) => bench::run(a),
        Command::Model(a) => model_cmd::run(a),
        Command::Solve(a) => solve::run(a),
        Command::Plot(a) => plot::run(a),
        Command::Run(a) => realtime::run(a),
        Command::VirtualRobot(a) => realtime::virtual_robot(a),
        Command::Envelope(a) => envelope_cmd::run(a),
        Command::Gait(a) => gait_cmd::run(a),
    }
}

/// Controller choice on the command line (mirrors [`ControllerKind`]).
#[derive(Debug, Clone, Copy, clap::ValueEnum)]
pub(crate) enum ControllerArg {
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

#[derive(Debug, Args)]
struct ConfigArgs {
    /// Instead of printing the default, load and validate FILE and report the first problem.
    #[arg(long, value_name = "FILE")]
    check: Option<PathBuf>,
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
