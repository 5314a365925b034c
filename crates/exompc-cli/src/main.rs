//! `exompc`: command-line front end of the exompc toolkit.
//!
//! Exit codes: see [`EXIT_CODES`]. Every error is one `error: ...` line on stderr.

mod args;
mod bench;
mod cia402_cmd;
mod envelope_cmd;
mod faults;
mod gait_cmd;
mod model_cmd;
mod plot;
mod plot_cmd;
mod realtime;
mod simulate;
mod soak;
mod solve;
mod sweep;

use bench::BenchArgs;
use clap::{Args, Parser, Subcommand};
use envelope_cmd::EnvelopeArgs;
use exompc_cli::error::CliError;
use exompc_cli::io;
use model_cmd::ModelArgs;
use plot_cmd::PlotArgs;
use simulate::SimulateArgs;
use soak::SoakArgs;
use solve::SolveArgs;
use std::io::Write as _;
use std::path::PathBuf;
use std::process::ExitCode;
use sweep::SweepArgs;

/// The exit codes, shown by `exompc --help` (and in the README).
const EXIT_CODES: &str = "\
Exit codes:
  0    success; a run's verdict is ok or degraded
  1    a run failed its own checks (verdict failed: limit violation, non-finite value), or a
       runtime error (I/O, no robot)
  2    bad input: invalid config value, unknown key, bad or conflicting flags, an output
       folder holding earlier results (without --force)
  3    with --strict (simulate, sweep, soak): the verdict is degraded (monitor trips, held
       torques, solver fallbacks); the results are written
  130  interrupted by SIGINT (143: by SIGTERM): simulate, sweep, soak, envelope and bench
       stop within a control step and keep what they completed, marked partial
       (\"partial\": true in summary.json, sweep.json, soak.json, envelope.json); run and
       virtual-robot ramp the torque to zero first and keep the trace written so far";

/// Multi-stage robust nonlinear MPC of a lower-limb exoskeleton: simulation and tools.
#[derive(Debug, Parser)]
#[command(
    name = "exompc",
    version,
    about,
    propagate_version = true,
    after_help = EXIT_CODES
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Run one closed-loop simulation and write its traces and metrics.
    #[command(after_help = EXIT_CODES)]
    Simulate(SimulateArgs),
    /// Run a grid of simulations (controllers × payloads) and write a metrics table.
    #[command(after_help = EXIT_CODES)]
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
    /// Print the default scenario as TOML with every key explained in a comment
    /// (`exompc config > my.toml`), check a file (`--check`), or explain one key (`--explain`).
    Config(ConfigArgs),
    /// Time the controllers on the default scenario.
    Bench(BenchArgs),
    /// Draw the figures (PNG and SVG) of a folder written by `simulate` or `sweep`.
    Plot(PlotArgs),
    /// A long run (1 h by default) with sensor faults, checking limits, NaN and the monitors.
    #[command(after_help = EXIT_CODES)]
    Soak(SoakArgs),
    /// Drive a robot in real time over UDP (the controller process; see docs/REALTIME.md).
    #[command(after_help = EXIT_CODES)]
    Run(realtime::RunArgs),
    /// Simulate the robot of `simulate` in real time behind the UDP protocol, to test `run`.
    #[command(after_help = EXIT_CODES)]
    VirtualRobot(realtime::VirtualRobotArgs),
    /// Write a fresh random pre-shared key (mode 0600) for `run` and `virtual-robot` --key.
    Keygen(realtime::KeygenArgs),
    /// Scan the operating envelope (scenario changes × payloads × controllers): classify every
    /// run (stable / limit cycle / growing / saturating), judge MS-NMPC against NMPC per cell,
    /// write envelope.json, envelope.md and a heat map (see docs/ROBUSTNESS.md).
    Envelope(EnvelopeArgs),
    /// Recorded gaits: `exompc gait export --out F.csv` samples the desired motion to a CSV
    /// that `[trajectory] kind = "recorded"` or `--gait F.csv` replays (see README).
    Gait(gait_cmd::GaitArgs),
    /// Scan the response to sensor faults: kinds × channel groups × durations × start times ×
    /// payloads, each against the same run without the fault (peak true strap force, RMS
    /// ratio, trips, held steps, latch); writes faults.md and faults.json (docs/RELIABILITY.md).
    Faults(faults::FaultsArgs),
    /// CiA 402 over slcan: `serve` a virtual drive on a pseudo-terminal, or run exompc's
    /// `master` against a drive behind an slcan port (see docs/HARDWARE.md).
    Cia402(cia402_cmd::Cia402Args),
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
        Command::Plot(a) => plot_cmd::run(a),
        Command::Run(a) => realtime::run(a),
        Command::VirtualRobot(a) => realtime::virtual_robot(a),
        Command::Keygen(a) => realtime::keygen(a),
        Command::Envelope(a) => envelope_cmd::run(a),
        Command::Gait(a) => gait_cmd::run(a),
        Command::Faults(a) => faults::run(a),
        Command::Cia402(a) => cia402_cmd::run(a),
    }
}

#[derive(Debug, Args)]
struct ConfigArgs {
    /// Instead of printing the default, load and validate FILE and report the first problem.
    #[arg(long, value_name = "FILE", conflicts_with = "explain")]
    check: Option<PathBuf>,
    /// Explain one key (`trajectory.hip_amplitude`) or table (`robot.thigh`): unit, meaning,
    /// default, allowed values and the docs/MODEL.md section it comes from.
    #[arg(long, value_name = "KEY")]
    explain: Option<String>,
}

/// `exompc config`: print the default scenario, or check a file with `--check FILE`, or
/// explain a key with `--explain KEY`.
fn cmd_config(a: &ConfigArgs) -> Result<(), CliError> {
    if let Some(key) = &a.explain {
        let text = exompc_cli::explain::explain_text(key).map_err(CliError::Usage)?;
        print!("{text}");
        return Ok(());
    }
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
