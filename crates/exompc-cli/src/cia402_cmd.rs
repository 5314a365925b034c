//! `exompc cia402`: a virtual CiA 402 drive served on an slcan pseudo-terminal (`serve`), and
//! exompc's CiA 402 master driving a drive behind an slcan port (`master`), for rehearsals and
//! for the tests against independent CANopen implementations (python-canopen).

use clap::{Args, Subcommand, ValueEnum};
use exompc_can::canopen::sdo::os_clock;
use exompc_can::canopen::sync::SyncProducer;
use exompc_can::canopen::NodeId;
use exompc_can::cia402::emulator::{Cia402Emulator, InertiaLoad};
use exompc_can::cia402::master::{Cia402Config, Cia402Master};
use exompc_can::cia402::{Mode, Scaling};
use exompc_can::{CanBus, VirtualBus, VirtualBusSettings};
use exompc_cli::error::CliError;
use exompc_cli::interrupt;
use std::io::Write as _;
use std::path::PathBuf;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

/// `exompc cia402 …`.
#[derive(Debug, Args)]
pub struct Cia402Args {
    #[command(subcommand)]
    cmd: Cia402Cmd,
}

#[derive(Debug, Subcommand)]
enum Cia402Cmd {
    /// Serve a virtual CiA 402 drive (an inertia load behind it) on an slcan pseudo-terminal:
    /// prints `pty PATH` on the first line of stdout, then serves until Ctrl-C or --duration.
    Serve(ServeArgs),
    /// Drive a CiA 402 drive behind an slcan port: configure it by SDO, enable it, run
    /// --cycles control periods of SYNC + RPDO with a constant torque, print one JSON line per
    /// period with the drive's TPDO values, then quick-stop it.
    Master(MasterArgs),
}

/// The drive's mechanics.
#[derive(Debug, Args, Clone)]
struct DriveArgs {
    /// Node id (1..=127).
    #[arg(long, default_value_t = 1)]
    node: u32,
    /// Motor rated torque in N·m (0x6076 is this × 1000 mNm).
    #[arg(long, default_value_t = 0.5)]
    rated_torque: f64,
    /// Gear ratio (motor turns per joint turn).
    #[arg(long, default_value_t = 40.0)]
    gear_ratio: f64,
    /// +1 or -1: joint direction relative to the motor.
    #[arg(long, default_value_t = 1.0, allow_negative_numbers = true)]
    direction: f64,
    /// Position increments per motor revolution.
    #[arg(long, default_value_t = 4096.0)]
    counts_per_rev: f64,
}

impl DriveArgs {
    fn parse(&self) -> Result<(NodeId, Scaling), CliError> {
        let node = NodeId::new(self.node).map_err(|e| CliError::Usage(format!("--node: {e}")))?;
        let positive = |name: &str, v: f64| {
            if v.is_finite() && v > 0.0 {
                Ok(v)
            } else {
                Err(CliError::Usage(format!(
                    "{name} {v} is out of range (allowed: a finite number > 0)"
                )))
            }
        };
        if self.direction != 1.0 && self.direction != -1.0 {
            return Err(CliError::Usage(format!(
                "--direction {} is out of range (allowed: 1 or -1)",
                self.direction
            )));
        }
        Ok((
            node,
            Scaling {
                rated_torque: positive("--rated-torque", self.rated_torque)?,
                gear_ratio: positive("--gear-ratio", self.gear_ratio)?,
                direction: self.direction,
                zero_offset: 0.0,
                counts_per_rev: positive("--counts-per-rev", self.counts_per_rev)?,
                ..Scaling::default()
            },
        ))
    }
}

#[derive(Debug, Args)]
struct ServeArgs {
    #[command(flatten)]
    drive: DriveArgs,
    /// Inertia of the load at the joint (kg·m²).
    #[arg(long, default_value_t = 0.5)]
    inertia: f64,
    /// Viscous damping of the load (N·m·s/rad).
    #[arg(long, default_value_t = 2.0)]
    damping: f64,
    /// Stop after this many seconds (default: until Ctrl-C / SIGTERM).
    #[arg(long)]
    duration: Option<f64>,
}

#[derive(Clone, Copy, Debug, ValueEnum)]
enum ModeArg {
    /// Cyclic synchronous torque (0x6060 = 10).
    Cst,
    /// Profile torque (0x6060 = 4).
    Pt,
}

#[derive(Debug, Args)]
struct MasterArgs {
    #[command(flatten)]
    drive: DriveArgs,
    /// The slcan serial port (a CANable's /dev/ttyACM0, or a pseudo-terminal).
    #[arg(long)]
    port: PathBuf,
    /// CAN bit rate.
    #[arg(long, default_value_t = 1_000_000)]
    bitrate: u32,
    /// Joint torque to command (N·m).
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true)]
    torque: f64,
    /// Joint torque limit (N·m), also written to the drive's 0x6072.
    #[arg(long, default_value_t = 10.0)]
    max_torque: f64,
    /// Control periods to run (0..=1000000).
    #[arg(long, default_value_t = 100)]
    cycles: u64,
    /// Control rate (Hz, 1..=1000): SYNC and RPDO per period.
    #[arg(long, default_value_t = 100.0)]
    rate: f64,
    /// Mode of operation.
    #[arg(long, value_enum, default_value_t = ModeArg::Cst)]
    mode: ModeArg,
    /// Do not ask the drive to watch the master's heartbeat (0x1016).
    #[arg(long)]
    no_master_heartbeat: bool,
}

/// Run `exompc cia402 …`.
pub fn run(a: Cia402Args) -> Result<(), CliError> {
    match a.cmd {
        Cia402Cmd::Serve(s) => serve(s),
        Cia402Cmd::Master(m) => master(m),
    }
}

#[cfg(unix)]
fn serve(a: ServeArgs) -> Result<(), CliError> {
    use exompc_can::{Pty, SlcanAdapter, TimeBase};
    let (node, scaling) = a.drive.parse()?;
    for (name, v) in [("--inertia", a.inertia), ("--damping", a.damping)] {
        if !(v.is_finite() && v > 0.0) {
            return Err(CliError::Usage(format!(
                "{name} {v} is out of range (allowed: a finite number > 0)"
            )));
        }
    }
    let duration = match a.duration {
        Some(d) if !(d.is_finite() && d > 0.0) => {
            return Err(CliError::Usage(format!(
                "--duration {d} is out of range (allowed: seconds > 0)"
            )))
        }
        d => d.map(Duration::from_secs_f64),
    };
    let pty = Pty::open().map_err(|e| CliError::io("opening a pseudo-terminal", e))?;
    let bus = VirtualBus::new(VirtualBusSettings::default(), TimeBase::Real);
    let load = InertiaLoad::new(a.inertia, a.damping);
    let drive = Arc::new(Mutex::new(Cia402Emulator::new(
        node,
        scaling,
        Box::new(load),
    )));
    bus.attach(drive.clone());
    let master = pty
        .master()
        .map_err(|e| CliError::io("opening the pseudo-terminal", e))?;
    let mut adapter = SlcanAdapter::new(bus.endpoint(), master, 1_000_000);
    println!("pty {}", pty.path().display());
    std::io::stdout()
        .flush()
        .map_err(|e| CliError::io("writing stdout", e))?;
    let t0 = Instant::now();
    while !interrupt::requested() && duration.is_none_or(|d| t0.elapsed() < d) {
        adapter
            .serve(Duration::from_millis(1))
            .map_err(|e| CliError::io("serving the pseudo-terminal", e))?;
    }
    let stats = *drive
        .lock()
        .unwrap_or_else(|e| e.into_inner())
        .stats()
        .lock()
        .unwrap_or_else(|e| e.into_inner());
    eprintln!(
        "virtual drive {node}: {} SDO requests, {} SYNCs, {} RPDOs, {} TPDOs, {} faults",
        stats.sdo_requests, stats.syncs, stats.rpdos, stats.tpdos, stats.faults
    );
    if interrupt::requested() {
        return Err(CliError::Interrupted(format!(
            "stopped by {}",
            interrupt::signal_name()
        )));
    }
    Ok(())
}

#[cfg(not(unix))]
fn serve(_a: ServeArgs) -> Result<(), CliError> {
    Err(CliError::Usage(
        "cia402 serve needs pseudo-terminals (Unix)".into(),
    ))
}

#[cfg(unix)]
fn master(a: MasterArgs) -> Result<(), CliError> {
    use exompc_can::{FdPort, SlcanBus};
    let (node, scaling) = a.drive.parse()?;
    if !(a.rate.is_finite() && (1.0..=1000.0).contains(&a.rate)) {
        return Err(CliError::Usage(format!(
            "--rate {} is out of range (allowed: 1..=1000 Hz)",
            a.rate
        )));
    }
    if a.cycles > 1_000_000 {
        return Err(CliError::Usage(format!(
            "--cycles {} is out of range (allowed: 0..=1000000)",
            a.cycles
        )));
    }
    if !(a.max_torque.is_finite() && a.max_torque > 0.0) {
        return Err(CliError::Usage(format!(
            "--max-torque {} is out of range (allowed: a finite number > 0)",
            a.max_torque
        )));
    }
    if !a.torque.is_finite() {
        return Err(CliError::Usage(format!(
            "--torque {} is out of range (allowed: a finite number)",
            a.torque
        )));
    }
    let mut cfg = Cia402Config::new(node, scaling, a.max_torque);
    cfg.mode = match a.mode {
        ModeArg::Cst => Mode::CyclicSynchronousTorque,
        ModeArg::Pt => Mode::ProfileTorque,
    };
    if a.no_master_heartbeat {
        cfg.master_heartbeat = None;
    }
    let port = FdPort::open(&a.port)
        .map_err(|e| CliError::io(format!("opening {}", a.port.display()), e))?;
    let mut bus = SlcanBus::open(port, a.bitrate)
        .map_err(|e| CliError::Runtime(format!("{}: {e}", a.port.display())))?;
    let clock = os_clock();
    let mut m = Cia402Master::new(cfg);
    m.configure_and_enable(&mut bus, &clock)
        .map_err(|e| CliError::Runtime(e.to_string()))?;
    let out = std::io::stdout();
    let mut out = out.lock();
    let line = |out: &mut std::io::StdoutLock, s: String| {
        writeln!(out, "{s}")
            .and_then(|_| out.flush())
            .map_err(|e| CliError::io("writing stdout", e))
    };
    line(
        &mut out,
        format!("{{\"event\":\"enabled\",\"node\":{node}}}"),
    )?;
    let period = Duration::from_secs_f64(1.0 / a.rate);
    let mut sync = SyncProducer::new(period, 0);
    let bus_err = |e: exompc_can::BusError| CliError::Runtime(format!("CAN bus: {e}"));
    let mut samples = 0u64;
    let mut result = Ok(());
    for cycle in 0..a.cycles {
        if interrupt::requested() {
            result = Err(CliError::Interrupted(format!(
                "stopped by {} after {cycle} periods",
                interrupt::signal_name()
            )));
            break;
        }
        let t0 = clock();
        if let Some(hb) = m.heartbeat_frame(t0) {
            bus.send(&hb).map_err(bus_err)?;
        }
        bus.send(&m.command(a.torque)).map_err(bus_err)?;
        bus.send(&sync.emit()).map_err(bus_err)?;
        let end = t0 + period;
        loop {
            let now = clock();
            if now >= end {
                break;
            }
            if let Some(f) = bus.recv(end - now).map_err(bus_err)? {
                m.on_frame(&f, clock());
            }
        }
        if let Some(s) = m.take_sample() {
            samples += 1;
            line(
                &mut out,
                format!(
                    "{{\"cycle\":{cycle},\"position\":{},\"velocity\":{},\"torque\":{},\"statusword\":{}}}",
                    s.position, s.velocity, s.torque, s.statusword
                ),
            )?;
        }
        if let Err(e) = m.check(clock()) {
            result = Err(CliError::Runtime(e.to_string()));
            break;
        }
    }
    // Stop: zero torque and quick stop, whatever happened.
    let _ = bus.send(&m.stop());
    let _ = bus.send(&sync.emit());
    std::thread::sleep(Duration::from_millis(20));
    line(
        &mut out,
        format!("{{\"event\":\"stopped\",\"samples\":{samples}}}"),
    )?;
    result
}

#[cfg(not(unix))]
fn master(_a: MasterArgs) -> Result<(), CliError> {
    Err(CliError::Usage(
        "cia402 master needs serial ports (Unix)".into(),
    ))
}
