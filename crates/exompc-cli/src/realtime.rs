//! `exompc run` (the controller process) and `exompc virtual-robot` (the simulated robot
//! process): the real-time loop over the UDP link of `exompc::runtime` (see
//! `docs/REALTIME.md`).

use crate::args::ConfigOpt;
use clap::Args;
use exompc::config::ControllerKind;
use exompc::config::Experiment;
use exompc::control::{Controller, StepStatus};
use exompc::runtime::frame::status_from_code;
use exompc::runtime::{
    Clock, ControlLoop, Lifecycle, LoopSettings, MonotonicClock, NetFaultSettings, NetFaults, Psk,
    RobotInterface, RobotRx, Schedule, TimingStats, UdpPeer, UdpRobot,
};
use exompc::scenario::{
    build_supervised, limits, plant_params, uncertainty, Dof, OneDof, StopCause, TwoDof,
    VirtualRobot,
};
use exompc::sim::{Metrics, Plant, Recorder, Sensors, StepRecord};
use exompc_cli::error::CliError;
use exompc_cli::io;
use exompc_cli::run::scenario_keys;
use exompc_cli::trace::CsvTrace;
use nalgebra::SVector;
use serde::Serialize;
use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Duration;

/// Real-time settings of the process (both commands).
#[derive(Debug, Args)]
pub(crate) struct RtOpts {
    /// SCHED_FIFO priority (1-99) of the process; 0 keeps the normal scheduler.
    #[arg(long, value_name = "P", default_value_t = 80, value_parser = clap::value_parser!(u8).range(0..=99))]
    rt_priority: u8,
    /// Pin the process to this CPU (0-1023).
    #[arg(long, value_name = "CPU", value_parser = clap::value_parser!(u16).range(0..=1023))]
    cpu: Option<u16>,
    /// Do not lock memory (mlockall).
    #[arg(long)]
    no_mlock: bool,
    /// Busy-wait the last part of each sleep (µs, 0-10000); 0 only sleeps.
    #[arg(long, value_name = "US", default_value_t = 0, value_parser = clap::value_parser!(u64).range(0..=10_000))]
    spin_us: u64,
    /// No live statistics on stderr.
    #[arg(long)]
    quiet: bool,
}

/// What the real-time setup obtained.
#[derive(Debug, Default, Serialize)]
struct RtStatus {
    sched_fifo: Option<u8>,
    mlockall: bool,
    cpu: Option<usize>,
    warnings: Vec<String>,
}

fn rt_setup(o: &RtOpts) -> RtStatus {
    let mut st = RtStatus::default();
    #[cfg(target_os = "linux")]
    {
        // SAFETY: plain libc calls on the calling process with valid, initialised arguments.
        unsafe {
            if !o.no_mlock {
                if libc::mlockall(libc::MCL_CURRENT | libc::MCL_FUTURE) == 0 {
                    st.mlockall = true;
                } else {
                    st.warnings.push(format!(
                        "mlockall failed ({}): memory may be paged out",
                        std::io::Error::last_os_error()
                    ));
                }
            }
            if o.rt_priority > 0 {
                let p = libc::sched_param {
                    sched_priority: i32::from(o.rt_priority),
                };
                if libc::sched_setscheduler(0, libc::SCHED_FIFO, &p) == 0 {
                    st.sched_fifo = Some(o.rt_priority);
                } else {
                    st.warnings.push(format!(
                        "SCHED_FIFO priority {} not granted ({}): running on the normal \
                         scheduler (grant it with `ulimit -r` / CAP_SYS_NICE or run as root)",
                        o.rt_priority,
                        std::io::Error::last_os_error()
                    ));
                }
            }
            if let Some(cpu) = o.cpu.map(usize::from) {
                let mut set: libc::cpu_set_t = std::mem::zeroed();
                if cpu < libc::CPU_SETSIZE as usize {
                    libc::CPU_SET(cpu, &mut set);
                }
                if cpu < libc::CPU_SETSIZE as usize
                    && libc::sched_setaffinity(0, std::mem::size_of::<libc::cpu_set_t>(), &set) == 0
                {
                    st.cpu = Some(cpu);
                } else {
                    st.warnings.push(format!(
                        "pinning to CPU {cpu} failed ({}): not pinned",
                        std::io::Error::last_os_error()
                    ));
                }
            }
        }
    }
    #[cfg(not(target_os = "linux"))]
    {
        if o.rt_priority > 0 || o.cpu.is_some() || !o.no_mlock {
            st.warnings
                .push("real-time scheduling, mlockall and pinning are Linux-only here".into());
        }
    }
    for w in &st.warnings {
        eprintln!("warning: {w}");
    }
    st
}

/// SIGINT, SIGTERM (both: stop) and SIGUSR1 (the virtual robot's restart) as flags.
struct Signals {
    int: Arc<AtomicBool>,
    term: Arc<AtomicBool>,
    usr1: Arc<AtomicBool>,
}

impl Signals {
    fn install() -> Result<Self, CliError> {
        let s = Signals {
            int: Arc::new(AtomicBool::new(false)),
            term: Arc::new(AtomicBool::new(false)),
            usr1: Arc::new(AtomicBool::new(false)),
        };
        for (sig, f) in [
            (signal_hook::consts::SIGINT, &s.int),
            (signal_hook::consts::SIGTERM, &s.term),
            (signal_hook::consts::SIGUSR1, &s.usr1),
        ] {
            signal_hook::flag::register(sig, Arc::clone(f))
                .map_err(|e| CliError::io("installing the signal handler", e))?;
        }
        Ok(s)
    }

    fn any(&self) -> bool {
        self.int.load(Ordering::Relaxed) || self.term.load(Ordering::Relaxed)
    }

    fn name(&self) -> &'static str {
        if self.term.load(Ordering::Relaxed) {
            "SIGTERM"
        } else {
            "SIGINT"
        }
    }

    /// The error of a run stopped by the signal: exit 143 for SIGTERM, 130 for SIGINT.
    fn error(&self, msg: String) -> CliError {
        if self.term.load(Ordering::Relaxed) {
            CliError::Terminated(msg)
        } else {
            CliError::Interrupted(msg)
        }
    }
}

fn secs(name: &str, v: f64, lo: f64, hi: f64) -> Result<Duration, CliError> {
    if v.is_finite() && v >= lo && v <= hi {
        Ok(Duration::from_secs_f64(v))
    } else {
        Err(CliError::Usage(format!(
            "--{name}: must be in [{lo}, {hi}], got {v}"
        )))
    }
}

pub(crate) fn write_json(path: &Path, v: &impl Serialize) -> Result<(), CliError> {
    let json = serde_json::to_string_pretty(v)
        .map_err(|e| CliError::Runtime(format!("serialising summary: {e}")))?;
    io::write_atomic(path, json.as_bytes())
}

fn live(t: f64, timing: &TimingStats, extra: &str) {
    let p = timing.recent(100);
    let b = timing.recent_busy(100);
    eprintln!(
        "t {t:7.1} s | period error p50 {:6.0} us p99 {:6.0} us max {:6.0} us | busy p99 {:5.0} us | deadline misses {} | {extra}",
        p.p50, p.p99, p.max, b.p99, timing.deadline_misses
    );
}

/// A warning for an address other than loopback (the threat model of docs/REALTIME.md).
fn warn_exposed(flag: &str, addr: SocketAddr) {
    if !addr.ip().is_loopback() {
        eprintln!(
            "warning: {flag} {addr} is not a loopback address: any host that reaches it can send \
             datagrams (rejected without the key, but a flood is not stopped; the robot's \
             watchdog makes it safe); see the threat model in docs/REALTIME.md"
        );
    }
}

// ------------------------------------------------------------------------------------------
// Keys

/// Load the pre-shared key of `--key` (exit 2 without one, for a file readable or writable
/// by group or others, as ssh does, and for a key too short or unreadable).
fn load_key(path: Option<&Path>) -> Result<Psk, CliError> {
    let Some(path) = path else {
        return Err(CliError::Usage(
            "no key: the robot link is authenticated; pass --key FILE with the pre-shared key of \
             the controller and the robot (create one with `exompc keygen FILE` and give both \
             processes the same file)"
                .into(),
        ));
    };
    let shown = path.display();
    let meta = std::fs::metadata(path)
        .map_err(|e| CliError::Usage(format!("--key {shown}: cannot read the key file: {e}")))?;
    if !meta.is_file() {
        return Err(CliError::Usage(format!(
            "--key {shown}: not a regular file"
        )));
    }
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        let mode = meta.permissions().mode() & 0o777;
        if mode & 0o077 != 0 {
            return Err(CliError::Usage(format!(
                "--key {shown}: the key file is accessible by group or others (mode {mode:04o}); \
                 make it private with `chmod 600 {shown}` (and consider the key compromised)"
            )));
        }
    }
    let bytes = std::fs::read(path)
        .map_err(|e| CliError::Usage(format!("--key {shown}: cannot read the key file: {e}")))?;
    Psk::new(&bytes).map_err(|e| CliError::Usage(format!("--key {shown}: {e}")))
}

/// `exompc keygen FILE`: a fresh random pre-shared key for `run` and `virtual-robot`.
#[derive(Debug, Args)]
pub(crate) struct KeygenArgs {
    /// The key file to write (mode 0600).
    #[arg(value_name = "FILE")]
    file: PathBuf,
    /// Replace an existing key file (both ends then need the new key).
    #[arg(long)]
    force: bool,
}

fn create_private(path: &Path) -> std::io::Result<std::fs::File> {
    let mut o = std::fs::OpenOptions::new();
    o.write(true).create_new(true);
    #[cfg(unix)]
    {
        use std::os::unix::fs::OpenOptionsExt;
        o.mode(0o600);
    }
    o.open(path)
}

pub(crate) fn keygen(a: KeygenArgs) -> Result<(), CliError> {
    use std::io::Write as _;
    let shown = a.file.display();
    let exists = std::fs::symlink_metadata(&a.file).is_ok();
    if exists && !a.force {
        return Err(CliError::Usage(format!(
            "{shown} exists: refusing to overwrite a key (pass --force to replace it; both \
             the controller and the robot then need the new key)"
        )));
    }
    let contents = Psk::generate_file()
        .map_err(|e| CliError::Runtime(format!("no random numbers from the OS: {e}")))?;
    // Written under a temporary name (created with mode 0600, never changed after) and
    // renamed, so a key file is whole or absent.
    let dir = a
        .file
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    let name = a
        .file
        .file_name()
        .map_or("key".into(), |n| n.to_string_lossy().into_owned());
    let temp = dir.join(format!(".{name}.tmp.{}", std::process::id()));
    let write = || -> std::io::Result<()> {
        let mut f = create_private(&temp)?;
        f.write_all(contents.as_bytes())?;
        f.sync_all()?;
        if a.force {
            std::fs::rename(&temp, &a.file)
        } else {
            // Fails if the file appeared meanwhile: never overwrite without --force.
            std::fs::hard_link(&temp, &a.file)?;
            std::fs::remove_file(&temp)
        }
    };
    if let Err(e) = write() {
        let _ = std::fs::remove_file(&temp);
        let code = if e.kind() == std::io::ErrorKind::AlreadyExists {
            CliError::Usage(format!(
                "{shown} exists: refusing to overwrite a key (--force)"
            ))
        } else {
            CliError::io(format!("writing {shown}"), e)
        };
        return Err(code);
    }
    println!(
        "wrote a new 256-bit key to {shown} (mode 0600); give `exompc run` and `exompc \
         virtual-robot` the same --key {shown}"
    );
    Ok(())
}

// ------------------------------------------------------------------------------------------
// Output folders: refused before anything runs, created only once the session is open.

fn earlier_results(dir: &Path) -> Vec<String> {
    exompc_cli::earlier::RUN_FILES
        .iter()
        .filter(|f| dir.join(f).exists())
        .map(|f| f.to_string())
        .collect()
}

/// Refuse an output folder holding an earlier run's results (without `--force`) or that is not
/// a folder; creates nothing.
pub(crate) fn check_out(dir: &Path, force: bool) -> Result<(), CliError> {
    if dir.exists() && !dir.is_dir() {
        return Err(CliError::Usage(format!(
            "output path {} exists and is not a folder",
            dir.display()
        )));
    }
    let found = earlier_results(dir);
    if !force && !found.is_empty() {
        return Err(CliError::Usage(format!(
            "{} already holds results of an earlier run ({}): choose another --out, or pass \
             --force to move them aside (renamed NAME.replaced-TIME) and write new ones",
            dir.display(),
            found.join(", ")
        )));
    }
    Ok(())
}

/// Create the output folder and, with `--force`, move an earlier run's results aside
/// (`trace.csv` → `trace.csv.replaced-<unix seconds>`): nothing is deleted.
pub(crate) fn open_out(dir: &Path, force: bool) -> Result<(), CliError> {
    io::ensure_out_dir(dir)?;
    if force {
        let stamp = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.as_secs());
        for f in earlier_results(dir) {
            let from = dir.join(&f);
            let mut to = dir.join(format!("{f}.replaced-{stamp}"));
            let mut i = 1;
            while to.exists() {
                to = dir.join(format!("{f}.replaced-{stamp}-{i}"));
                i += 1;
            }
            std::fs::rename(&from, &to)
                .map_err(|e| CliError::io(format!("moving {} aside", from.display()), e))?;
        }
    }
    Ok(())
}

/// A live trace that stops writing at its first error (keeping what was written) and
/// remembers the error, naming the file.
pub(crate) struct LiveTrace {
    trace: Option<CsvTrace>,
    path: PathBuf,
    error: Option<String>,
}

impl LiveTrace {
    pub(crate) fn create(dir: &Path, n: usize, keys: &[String]) -> Result<Self, CliError> {
        let path = dir.join("trace.csv");
        Ok(LiveTrace {
            trace: Some(CsvTrace::create_live(&path, n, keys)?),
            path,
            error: None,
        })
    }

    fn fail(&mut self, e: std::io::Error) {
        self.trace = None;
        self.error = Some(format!("writing {}: {e}", self.path.display()));
    }

    /// Record a row; `false` on the first failure.
    pub(crate) fn record<const N: usize>(&mut self, r: &StepRecord<'_, N>) -> bool {
        let Some(t) = self.trace.as_mut() else {
            return self.error.is_none();
        };
        if let Err(e) = Recorder::<N>::record(t, r) {
            self.fail(e);
            return false;
        }
        true
    }

    fn flush(&mut self) -> bool {
        let Some(t) = self.trace.as_mut() else {
            return self.error.is_none();
        };
        if let Err(e) = t.flush() {
            self.fail(e);
            return false;
        }
        true
    }

    /// Flush and fsync; the error message, if any write failed.
    pub(crate) fn finish(mut self) -> Option<String> {
        if let Some(t) = self.trace.take() {
            if let Err(e) = t.finish() {
                self.error = Some(format!("{} ({e})", self.path.display()));
            }
        }
        self.error
    }
}

// ------------------------------------------------------------------------------------------
// exompc run

#[derive(Debug, Args)]
pub(crate) struct RunArgs {
    #[command(flatten)]
    config: ConfigOpt,
    /// The pre-shared key file of the controller and the robot (`exompc keygen FILE`; mode
    /// 0600). Required.
    #[arg(long, value_name = "FILE")]
    key: Option<PathBuf>,
    /// Experiment: 1 (knee only) or 2 (hip and knee).
    #[arg(long, default_value_t = 2, value_parser = clap::value_parser!(u8).range(1..=2))]
    dof: u8,
    /// Override `controller.kind`.
    #[arg(long, value_parser = crate::args::controller_parser())]
    controller: Option<ControllerKind>,
    /// The robot's address.
    #[arg(long, value_name = "ADDR", default_value = "127.0.0.1:7300")]
    robot: SocketAddr,
    /// Local address to bind (port 0: any free port).
    #[arg(long, value_name = "ADDR", default_value = "127.0.0.1:0")]
    bind: SocketAddr,
    /// Stop (with the torque ramp) after this long (s, up to 1e6); default: until the robot
    /// ends the run or SIGINT/SIGTERM.
    #[arg(long, value_name = "S")]
    duration: Option<f64>,
    /// Wait this long for the robot's session (s, 0-3600).
    #[arg(long, value_name = "S", default_value_t = 10.0)]
    connect_timeout: f64,
    /// Give up when no sample arrived for this long (s, 0.05-3600): the robot vanished.
    #[arg(long, value_name = "S", default_value_t = 3.0)]
    give_up: f64,
    /// Wake this long before a sample is expected (ms, 0 to the period); default period/5.
    #[arg(long, value_name = "MS")]
    lead_ms: Option<f64>,
    /// Wait for a sample at most this long after waking (ms, 0 to the period); default
    /// period/2.
    #[arg(long, value_name = "MS")]
    sample_timeout_ms: Option<f64>,
    /// Output folder for `trace.csv` (written as the run goes) and `summary.json`.
    #[arg(long, value_name = "DIR", default_value = "out/run")]
    out: PathBuf,
    /// Move the results of an earlier run in the output folder aside (without it, refused).
    #[arg(long)]
    force: bool,
    /// Override `uncertainty.payload_kg` (kg) of the simulated leg: only with a `[robot.bus]`
    /// of `transport = "virtual"` (docs/HARDWARE.md).
    #[arg(long, value_name = "KG", allow_negative_numbers = true)]
    payload: Option<f64>,
    #[command(flatten)]
    rt: RtOpts,
}

#[derive(Serialize)]
struct RunSummary {
    controller: String,
    dof: usize,
    /// The QP back-end and Hessian model `[controller.sqp]` resolved to (as `simulate`'s
    /// `summary.json`); absent for a controller without an SQP.
    #[serde(skip_serializing_if = "Option::is_none")]
    solver: Option<exompc::control::SolverChoice>,
    robot: String,
    stop_reason: String,
    /// Whether the run ended as planned (the robot's or `--duration`'s end).
    completed: bool,
    duration_s: f64,
    timing_us: exompc::runtime::TimingSummary,
    controller_step_us: exompc::runtime::Percentiles,
    counters: exompc::runtime::LoopStats,
    link: exompc::runtime::LinkStats,
    safety: Option<exompc::control::SafetyReport>,
    /// The supervisor's counters as `exompc simulate`'s `summary.json` has them (trips per
    /// monitor with the first, handovers, `latched_at_s`).
    safety_summary: Option<exompc::sim::SafetySummary>,
    rms_force_measured_n: Vec<f64>,
    trace_error: Option<String>,
    realtime: RtStatus,
    /// The CAN robot's counters, stops and bus load (`run --config` with `[robot.bus]`).
    #[serde(skip_serializing_if = "Option::is_none")]
    can: Option<serde_json::Value>,
}

/// Why `run` ended.
enum RunEnd {
    /// As planned (exit 0).
    Planned(String),
    /// SIGINT/SIGTERM (exit 130/143).
    Signal,
    /// The robot vanished, refused or stopped the session, or the controller's own fault
    /// (exit 1).
    Failed(String),
}

pub(crate) fn run(a: RunArgs) -> Result<(), CliError> {
    let mut s = a.config.load()?;
    let hw = exompc_cli::can::hardware_of(a.config.config.as_deref())?;
    let virtual_bus = matches!(
        hw.as_ref().map(|h| &h.bus),
        Some(exompc_can::config::BusConfig::Virtual(_))
    );
    if a.payload.is_some() && !virtual_bus {
        return Err(CliError::Usage(
            "--payload is for the virtual devices only: a config with [robot.bus] transport = \
             \"virtual\""
                .into(),
        ));
    }
    crate::args::apply_overrides(&mut s, a.dof, a.controller, None, a.payload, None)?;
    if let Some(d) = a.duration {
        secs("duration", d, 0.0, 1e6)?;
    }
    secs("connect-timeout", a.connect_timeout, 0.0, 3600.0)?;
    secs("give-up", a.give_up, 0.05, 3600.0)?;
    if let Some(ms) = a.lead_ms {
        secs("lead-ms", ms * 1e-3, 0.0, s.timing.dt)?;
    }
    if let Some(ms) = a.sample_timeout_ms {
        secs("sample-timeout-ms", ms * 1e-3, 0.0, s.timing.dt)?;
    }
    if let Some(hw) = hw {
        check_out(&a.out, a.force)?;
        if exompc_cli::can_cia402::uses_cia402(&hw) {
            // A repeated angle below one position increment per period is no frozen encoder.
            if let Some(step) = exompc_cli::can_cia402::encoder_step(&hw) {
                let m = &mut s.monitors;
                let max = exompc::control::Monitors::MAX_ENCODER_STEP_RAD;
                m.encoder_step_rad = m.encoder_step_rad.max(step.min(max));
            }
            return match a.dof {
                1 => run_cia402::<OneDof, 1>(&s, &a, &hw),
                _ => run_cia402::<TwoDof, 2>(&s, &a, &hw),
            };
        }
        return match a.dof {
            1 => run_can::<OneDof, 1>(&s, &a, &hw),
            _ => run_can::<TwoDof, 2>(&s, &a, &hw),
        };
    }
    let psk = load_key(a.key.as_deref())?;
    check_out(&a.out, a.force)?;
    warn_exposed("--bind", a.bind);
    match a.dof {
        1 => run_dof::<OneDof, 1>(&s, &a, psk),
        _ => run_dof::<TwoDof, 2>(&s, &a, psk),
    }
}

/// `run --config` with `[robot.bus]`: the CAN robot the config describes.
fn run_can<D: Dof<N>, const N: usize>(
    s: &Experiment,
    a: &RunArgs,
    hw: &exompc_can::config::HardwareConfig,
) -> Result<(), CliError>
where
    D::Traj: Send + 'static,
{
    let periods = can_periods::<D, N>(s, a);
    let mut rig =
        exompc_cli::can::rig::<D, N>(s, hw, Duration::from_micros(a.rt.spin_us), periods + 64)?;
    if !a.rt.quiet {
        eprintln!("exompc run: CAN robot on the {}", rig.label);
    }
    let label = rig.label.clone();
    let bus = rig.bus.clone();
    let leg = rig.leg.clone();
    let dt = s.timing.dt;
    drive::<D, N, _, _>(s, a, &mut rig.robot, rig.clock, &label, move |robot| {
        use exompc_can::CanBus as _;
        let rms_true =
            leg.map(|l| rms_force_true(l.lock().unwrap_or_else(|e| e.into_inner()).history()));
        let load = bus.map(|b| bus_load_json(&b.load()));
        Some(can_summary(
            None,
            robot.stats(),
            robot.stop_events(),
            &robot.bus().counters(),
            load,
            rms_true,
            dt,
        ))
    })
}

/// Sequence numbers a frame may be ahead of the last one: about 1 s of periods.
pub(crate) fn max_ahead(dt: f64) -> u32 {
    (1.0 / dt).ceil().clamp(2.0, 1e6) as u32
}

fn run_dof<D: Dof<N>, const N: usize>(
    s: &Experiment,
    a: &RunArgs,
    psk: Psk,
) -> Result<(), CliError> {
    let mut robot = UdpRobot::<N>::connect(a.bind, a.robot, psk, max_ahead(s.timing.dt))
        .map_err(|e| CliError::io(format!("binding {}", a.bind), e))?;
    let clock = MonotonicClock::new(Duration::from_micros(a.rt.spin_us));
    if !a.rt.quiet {
        eprintln!(
            "exompc run: robot {} (from {})",
            a.robot,
            robot.local_addr().map_or("?".into(), |x| x.to_string())
        );
    }
    drive::<D, N, _, _>(s, a, &mut robot, clock, &a.robot.to_string(), |_| None)
}

/// The control loop of `run` against any robot: connect, run the periods, write the trace
/// and the summary (`extra`: what the robot adds to it).
fn drive<D: Dof<N>, const N: usize, R: RobotInterface<N>, K: Clock>(
    s: &Experiment,
    a: &RunArgs,
    robot: &mut R,
    mut clock: K,
    robot_label: &str,
    extra: impl FnOnce(&mut R) -> Option<serde_json::Value>,
) -> Result<(), CliError> {
    let dt = Duration::from_secs_f64(s.timing.dt);
    let mut settings = LoopSettings::new(dt, s.uncertainty.filter_window, limits(s));
    if let Some(ms) = a.lead_ms {
        settings.lead = Duration::from_secs_f64(ms * 1e-3);
    }
    if let Some(ms) = a.sample_timeout_ms {
        settings.sample_timeout = Duration::from_secs_f64(ms * 1e-3);
    }
    let sup = build_supervised::<D, N>(s, s.controller.kind)
        .map_err(|e| CliError::Runtime(e.to_string()))?;
    let name = sup.name().to_string();
    let capacity = a
        .duration
        .map_or(s.control_steps(D::DOF), |d| (d / s.timing.dt) as usize + 16)
        .min(1 << 22);
    let mut lp = ControlLoop::new(sup, settings, capacity);
    let sig = Signals::install()?;
    let rt = rt_setup(&a.rt);
    if !a.rt.quiet {
        eprintln!(
            "exompc run: {name}, {}-DOF, period {} ms",
            D::DOF,
            s.timing.dt * 1e3,
        );
    }
    let io_err = |e| CliError::io("robot link", e);
    // The handshake, in slices so that a signal stops it within a fraction of a second.
    let connect_end = clock.now() + Duration::from_secs_f64(a.connect_timeout);
    loop {
        if sig.any() {
            return Err(sig.error(format!(
                "interrupted by {} while connecting to the robot at {}; nothing written",
                sig.name(),
                robot_label
            )));
        }
        let left = connect_end.saturating_sub(clock.now());
        if left.is_zero() {
            return Err(CliError::Runtime(format!(
                "no session with the robot at {} within {} s: is it running with the same \
                 --key, and not in a protective stop (restart it)? (link: {} datagrams \
                 received, {} rejected)",
                robot_label,
                a.connect_timeout,
                robot.link_stats().received,
                robot.link_stats().rejected.total()
            )));
        }
        if lp
            .connect(
                robot,
                &mut clock,
                left.min(Duration::from_millis(200)),
                Duration::from_millis(100),
            )
            .map_err(io_err)?
        {
            break;
        }
    }
    open_out(&a.out, a.force)?;
    let mut trace = LiveTrace::create(&a.out, N, &scenario_keys(s))?;
    let mut dist =
        vec![SVector::<f64, N>::zeros(); lp.controller().probabilities().map_or(0, |p| p.len())];
    let mut sum_f2 = [0.0f64; N];
    let mut n_f = 0u64;
    let mut step_us = Vec::with_capacity(capacity);
    let mut last_sample = clock.now();
    let mut next_live = clock.now() + Duration::from_secs(1);
    let mut end: Option<RunEnd> = None;
    let nan = SVector::<f64, N>::from_element(f64::NAN);
    loop {
        let k = lp.stats().periods;
        if !lp.is_stopping() {
            if sig.any() {
                lp.request_stop();
                end = Some(RunEnd::Signal);
            } else if a.duration.is_some_and(|d| k as f64 * s.timing.dt >= d) {
                lp.request_stop();
                end = Some(RunEnd::Planned("duration".into()));
            } else if let Some(t) = lp.controller().safety_report().and_then(|r| r.latched_at) {
                lp.request_stop();
                end = Some(RunEnd::Failed(format!(
                    "the controller latched its fallback at {t:.2} s: torque ramped to zero and \
                     the session ended"
                )));
            } else if let Some(e) = &trace.error {
                lp.request_stop();
                end = Some(RunEnd::Failed(format!(
                    "{e}: torque ramped to zero and the session ended; the rows written before \
                     are kept"
                )));
            }
        }
        let rec = match lp.period(robot, &mut clock) {
            Ok(r) => r,
            Err(e) => {
                // The link failed: the robot stops itself when no command reaches it.
                robot.error();
                let _ = trace.finish();
                return Err(io_err(e));
            }
        };
        let now = clock.now();
        for (i, d) in dist.iter_mut().enumerate() {
            *d = lp
                .controller()
                .disturbance(i)
                .unwrap_or_else(SVector::zeros);
        }
        let m = &rec.measurement;
        if rec.sample.is_some() {
            last_sample = now;
            if m.force.iter().all(|f| f.is_finite()) {
                for (acc, f) in sum_f2.iter_mut().zip(m.force.iter()) {
                    *acc += f * f;
                }
                n_f += 1;
            }
        }
        step_us.push(rec.compute_us);
        let sr = StepRecord {
            k: rec.k as usize,
            t: m.t,
            robot: exompc::model::JointState {
                q: rec.sample.map_or(nan, |x| x.q),
                qd: rec.sample.map_or(nan, |x| x.qd),
            },
            human: exompc::model::JointState { q: nan, qd: nan },
            desired: nan,
            torque_robot: rec.output.torque,
            torque_prev: rec.torque_prev,
            torque_human: nan,
            force_true: nan,
            force_measured: m.force,
            probabilities: lp.controller().probabilities(),
            disturbances: if dist.is_empty() { None } else { Some(&dist) },
            status: rec.output.status,
            iterations: rec.output.iterations,
            step_time_us: rec.compute_us,
            within_limits: rec.within_limits,
        };
        trace.record(&sr);
        if rec.robot_stopped {
            end = Some(RunEnd::Failed(format!(
                "the robot made a protective stop (at {:.2} s): it applies no more commands of \
                 this session; restart it at the robot for a new session",
                m.t
            )));
            break;
        }
        if rec.robot_ended {
            if end.is_none() {
                end = Some(RunEnd::Planned("robot ended the run".into()));
            }
            break;
        }
        if lp.ramp_done() {
            break;
        }
        if now.saturating_sub(last_sample).as_secs_f64() > a.give_up {
            end = Some(RunEnd::Failed(format!(
                "no sample from the robot for {} s: the robot vanished",
                a.give_up
            )));
            break;
        }
        if now >= next_live {
            next_live += Duration::from_secs(1);
            trace.flush();
            if !a.rt.quiet {
                let st = lp.stats();
                live(
                    m.t,
                    lp.timing(),
                    &format!(
                        "missing samples {} late {} | robot ride-through {} | rejected {}",
                        st.missing_samples,
                        st.late_samples,
                        st.robot_watchdog_samples,
                        robot.link_stats().rejected.total()
                    ),
                );
            }
        }
    }
    let _ = lp.send_stop(robot, &clock, 3);
    let _ = robot.deactivate();
    let trace_error = trace.finish();
    let end = match (end, &trace_error) {
        (Some(RunEnd::Signal), _) => RunEnd::Signal,
        (Some(RunEnd::Failed(m)), _) => RunEnd::Failed(m),
        (_, Some(e)) => RunEnd::Failed(format!("{e}; the rows written before are kept")),
        (Some(p), None) => p,
        (None, None) => RunEnd::Planned("ramp done".into()),
    };
    let stop_reason = match &end {
        RunEnd::Planned(r) | RunEnd::Failed(r) => r.clone(),
        RunEnd::Signal => "signal".into(),
    };
    let summary = RunSummary {
        controller: name,
        dof: D::DOF,
        solver: exompc::scenario::summary_solver(s, D::DOF).unwrap_or_default(),
        robot: robot_label.to_string(),
        stop_reason,
        completed: matches!(end, RunEnd::Planned(_)),
        duration_s: lp.stats().periods as f64 * s.timing.dt,
        timing_us: lp.timing().summary(),
        controller_step_us: exompc::runtime::Percentiles::of(&mut step_us),
        counters: *lp.stats(),
        link: robot.link_stats(),
        safety: lp.controller().safety_report().cloned(),
        safety_summary: lp
            .controller()
            .safety_report()
            .map(exompc::sim::SafetySummary::from_report),
        rms_force_measured_n: sum_f2
            .iter()
            .map(|v| (v / n_f.max(1) as f64).sqrt())
            .collect(),
        trace_error: trace_error.clone(),
        realtime: rt,
        can: None,
    };
    let summary = RunSummary {
        can: extra(robot),
        ..summary
    };
    let wrote = write_json(&a.out.join("summary.json"), &summary);
    let t = &summary.timing_us;
    println!(
        "exompc run: stopped ({}) after {:.1} s, {} periods\n  period error  p50 {:.0} us  p99 {:.0} us  max {:.0} us   deadline misses {}\n  controller step p50 {:.0} us  p99 {:.0} us   missing samples {}   limit violations {}\n  wrote {}/trace.csv{}",
        summary.stop_reason,
        summary.duration_s,
        t.periods,
        t.period_error_us.p50,
        t.period_error_us.p99,
        t.period_error_us.max,
        t.deadline_misses,
        summary.controller_step_us.p50,
        summary.controller_step_us.p99,
        summary.counters.missing_samples,
        summary.counters.limit_violations,
        a.out.display(),
        if wrote.is_ok() { " and summary.json" } else { "" }
    );
    if let Some(c) = &summary.solver {
        println!("  solver  {}", exompc_cli::run::solver_label(c));
    }
    if let Some(sa) = &summary.safety_summary {
        println!("{}", exompc_cli::run::describe_safety(sa));
    }
    match end {
        RunEnd::Planned(_) => wrote,
        RunEnd::Signal => Err(sig.error(format!(
            "interrupted by {} after {:.1} s: torque ramped to zero and the session ended; \
             wrote {}",
            sig.name(),
            summary.duration_s,
            a.out.display()
        ))),
        RunEnd::Failed(m) => Err(CliError::Runtime(m)),
    }
}

// ------------------------------------------------------------------------------------------
// exompc virtual-robot

#[derive(Debug, Args)]
pub(crate) struct VirtualRobotArgs {
    #[command(flatten)]
    config: ConfigOpt,
    /// The pre-shared key file of the controller and the robot (`exompc keygen FILE`; mode
    /// 0600). Required.
    #[arg(long, value_name = "FILE")]
    key: Option<PathBuf>,
    /// Experiment: 1 (knee only) or 2 (hip and knee).
    #[arg(long, default_value_t = 2, value_parser = clap::value_parser!(u8).range(1..=2))]
    dof: u8,
    /// Override `uncertainty.payload_kg` (kg).
    #[arg(long, value_name = "KG", allow_hyphen_values = true)]
    payload: Option<f64>,
    /// Override the run length (s) of the chosen experiment.
    #[arg(long, value_name = "S", allow_hyphen_values = true)]
    duration: Option<f64>,
    /// Address to listen on (port 0: any free port, printed on stdout).
    #[arg(long, value_name = "ADDR", default_value = "127.0.0.1:7300")]
    listen: SocketAddr,
    /// Wait this long for a controller's session (s, 0-3600).
    #[arg(long, value_name = "S", default_value_t = 60.0)]
    connect_timeout: f64,
    /// Wait for the command answering a sample at most this long (ms, 0 to the period);
    /// default 0.8 period.
    #[arg(long, value_name = "MS")]
    command_wait_ms: Option<f64>,
    /// Ride through at most this many periods (1-50) without a valid command, playing out the
    /// last command's plan; one more is a lost controller: protective stop.
    #[arg(long, value_name = "N", default_value_t = 20, value_parser = clap::value_parser!(u64).range(1..=50))]
    watchdog_periods: u64,
    /// After a protective stop, restart by itself after this long (s, 0-3600) once the torque
    /// is zero (for tests; otherwise a line `restart` on stdin or SIGUSR1 restarts it).
    #[arg(long, value_name = "S")]
    auto_restart_after: Option<f64>,
    /// Network fault: probability of losing each frame, both directions (0-1).
    #[arg(long, value_name = "P", default_value_t = 0.0)]
    loss: f64,
    /// Network fault: probability of duplicating each frame (0-1).
    #[arg(long, value_name = "P", default_value_t = 0.0)]
    duplicate: f64,
    /// Network fault: probability of swapping a frame with the next one (0-1).
    #[arg(long, value_name = "P", default_value_t = 0.0)]
    reorder: f64,
    /// Network fault: delay of a delay spike (ms, 0-10000).
    #[arg(long, value_name = "MS", default_value_t = 20.0)]
    delay_ms: f64,
    /// Network fault: a delay spike every this many seconds (0-3600; 0: none).
    #[arg(long, value_name = "S", default_value_t = 0.0)]
    delay_every: f64,
    /// Network fault: length of each delay spike (s, 0-3600).
    #[arg(long, value_name = "S", default_value_t = 0.05)]
    delay_width: f64,
    /// Network fault: disconnect (drop everything) at this time (s, 0-1e6).
    #[arg(long, value_name = "S")]
    disconnect_at: Option<f64>,
    /// Network fault: length of the disconnection (s, 0-3600).
    #[arg(long, value_name = "S", default_value_t = 1.0)]
    disconnect_for: f64,
    /// Seed of the network fault draws.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Serve the controller on a byte stream instead of UDP: create the Unix socket PATH
    /// (QEMU's `-serial unix:PATH` connects to it: the firmware's UART) and run in lockstep,
    /// each period waiting for its command (up to --connect-timeout of wall time).
    #[arg(long, value_name = "PATH")]
    serial: Option<PathBuf>,
    /// With --serial: at this robot time (s), send a forged copy of the sample (one bit
    /// flipped) and a replay of the previous sample before the real one; the controller must
    /// reject both (counted in its link counters).
    #[arg(long, value_name = "S", requires = "serial")]
    inject_forged_at: Option<f64>,
    /// Output folder for the robot's `trace.csv` (true states, written as the run goes) and
    /// `summary.json`.
    #[arg(long, value_name = "DIR", default_value = "out/robot")]
    out: PathBuf,
    /// Move the results of an earlier run in the output folder aside (without it, refused).
    #[arg(long)]
    force: bool,
    #[command(flatten)]
    rt: RtOpts,
}

#[derive(Serialize)]
struct RobotSummary {
    summary: exompc::sim::Summary,
    stop_reason: String,
    lifecycle: Lifecycle,
    robot: exompc::scenario::RobotStats,
    watchdog_events: Vec<exompc::scenario::WatchdogEvent>,
    protective_stops: Vec<exompc::scenario::StopEvent>,
    link: exompc::runtime::LinkStats,
    net_faults: NetFaultReport,
    timing_us: exompc::runtime::TimingSummary,
    trace_error: Option<String>,
    realtime: RtStatus,
}

#[derive(Serialize)]
struct NetFaultReport {
    settings: NetFaultSettings,
    to_controller: exompc::runtime::NetFaultCounts,
    from_controller: exompc::runtime::NetFaultCounts,
}

pub(crate) fn virtual_robot(a: VirtualRobotArgs) -> Result<(), CliError> {
    let mut s = a.config.load()?;
    crate::args::apply_overrides(&mut s, a.dof, None, None, a.payload, a.duration)?;
    if let Some(hw) = exompc_cli::can::hardware_of(a.config.config.as_deref())? {
        return match a.dof {
            1 => serve_can::<OneDof, 1>(&s, &a, &hw),
            _ => serve_can::<TwoDof, 2>(&s, &a, &hw),
        };
    }
    secs("connect-timeout", a.connect_timeout, 0.0, 3600.0)?;
    if let Some(v) = a.auto_restart_after {
        secs("auto-restart-after", v, 0.0, 3600.0)?;
    }
    if let Some(ms) = a.command_wait_ms {
        secs("command-wait-ms", ms * 1e-3, 0.0, s.timing.dt)?;
    }
    secs("delay-ms", a.delay_ms * 1e-3, 0.0, 10.0)?;
    secs("delay-every", a.delay_every, 0.0, 3600.0)?;
    secs("delay-width", a.delay_width, 0.0, 3600.0)?;
    secs("disconnect-for", a.disconnect_for, 0.0, 3600.0)?;
    if let Some(v) = a.disconnect_at {
        secs("disconnect-at", v, 0.0, 1e6)?;
    }
    let faults = NetFaultSettings {
        loss: a.loss,
        duplicate: a.duplicate,
        reorder: a.reorder,
        delay_s: a.delay_ms * 1e-3,
        delay_every_s: a.delay_every,
        delay_width_s: a.delay_width,
        disconnect_at_s: a.disconnect_at,
        disconnect_s: a.disconnect_for,
        seed: a.seed,
    };
    faults
        .validate()
        .map_err(|e| CliError::Usage(format!("network fault: {e}")))?;
    let psk = load_key(a.key.as_deref())?;
    check_out(&a.out, a.force)?;
    #[cfg(not(unix))]
    if a.serial.is_some() {
        return Err(CliError::Usage("--serial: Unix sockets only".into()));
    }
    #[cfg(unix)]
    if let Some(path) = &a.serial {
        if let Some(v) = a.inject_forged_at {
            secs("inject-forged-at", v, 0.0, 1e6)?;
        }
        let o = serial_robot::SerialOpts {
            path,
            timeout: Duration::from_secs_f64(a.connect_timeout),
            watchdog_periods: a.watchdog_periods,
            inject_forged_at: a.inject_forged_at,
            out: &a.out,
            force: a.force,
            quiet: a.rt.quiet,
        };
        return match a.dof {
            1 => serial_robot::serve::<OneDof, 1>(&s, &o, psk),
            _ => serial_robot::serve::<TwoDof, 2>(&s, &o, psk),
        };
    }
    match a.dof {
        1 => robot_dof::<OneDof, 1>(&s, &a, faults, psk),
        _ => robot_dof::<TwoDof, 2>(&s, &a, faults, psk),
    }
}

/// `virtual-robot --config` with `[robot]` hardware tables: the virtual AK motors and force
/// node of the config, with the simulated leg behind them, served as an slcan adapter on a new
/// pseudo-terminal (its path printed on stdout) until `--duration` or SIGINT/SIGTERM.
#[cfg(unix)]
fn serve_can<D: Dof<N>, const N: usize>(
    s: &Experiment,
    a: &VirtualRobotArgs,
    hw: &exompc_can::config::HardwareConfig,
) -> Result<(), CliError>
where
    D::Traj: Send + 'static,
{
    use std::io::Write as _;
    let pty = exompc_can::Pty::open().map_err(|e| CliError::io("opening a pseudo-terminal", e))?;
    let bus = exompc_cli::can::virtual_bus(hw, exompc_can::TimeBase::Real);
    if exompc_cli::can_cia402::uses_cia402(hw) {
        let leg = exompc_cli::can_cia402::virtual_leg::<D, N>(s, hw, 0)?;
        bus.attach(Arc::new(std::sync::Mutex::new(leg)));
    } else {
        let leg = Arc::new(std::sync::Mutex::new(exompc_cli::can::virtual_leg::<D, N>(
            s, hw, 0,
        )?));
        bus.attach(leg.clone());
    }
    let master = pty
        .master()
        .map_err(|e| CliError::io("opening the pseudo-terminal", e))?;
    let mut adapter = exompc_can::SlcanAdapter::new(bus.endpoint(), master, hw.bus.bitrate());
    let sig = Signals::install()?;
    println!("{}", pty.path().display());
    let _ = std::io::stdout().flush();
    eprintln!(
        "virtual robot: {N} virtual AK motor(s) and a force node behind slcan on {} ({} bit/s); \
         payload {} kg; stop with Ctrl-C",
        pty.path().display(),
        hw.bus.bitrate(),
        s.uncertainty.payload_kg
    );
    let start = std::time::Instant::now();
    while !sig.any() && a.duration.is_none_or(|d| start.elapsed().as_secs_f64() < d) {
        adapter
            .serve(Duration::from_micros(200))
            .map_err(|e| CliError::io("serving slcan", e))?;
    }
    let c = adapter.counters();
    let load = bus.load();
    println!(
        "virtual robot: {} frames to the bus, {} to the host, {} refused, {} dropped; bus load \
         {:.1} %",
        c.to_bus,
        c.to_host,
        c.refused,
        c.dropped,
        100.0 * load.fraction()
    );
    Ok(())
}

#[cfg(not(unix))]
fn serve_can<D: Dof<N>, const N: usize>(
    _s: &Experiment,
    _a: &VirtualRobotArgs,
    _hw: &exompc_can::config::HardwareConfig,
) -> Result<(), CliError> {
    Err(CliError::Usage(
        "virtual-robot --config with [robot] hardware needs a pseudo-terminal (Unix)".into(),
    ))
}

/// Restart requests typed at the robot: a line `restart` on stdin (read by a thread).
fn stdin_restart(flag: Arc<AtomicBool>) {
    let _ = std::thread::Builder::new()
        .name("restart-stdin".into())
        .spawn(move || {
            use std::io::BufRead as _;
            for line in std::io::stdin().lock().lines() {
                match line {
                    Ok(l) if l.trim() == "restart" => flag.store(true, Ordering::Relaxed),
                    Ok(_) => {}
                    Err(_) => return,
                }
            }
        });
}

fn robot_dof<D: Dof<N>, const N: usize>(
    s: &Experiment,
    a: &VirtualRobotArgs,
    faults: NetFaultSettings,
    psk: Psk,
) -> Result<(), CliError> {
    let dt = s.timing.dt;
    let wait = a
        .command_wait_ms
        .map_or(Duration::from_secs_f64(0.8 * dt), |ms| {
            Duration::from_secs_f64(ms * 1e-3)
        });
    s.check_trajectory(D::DOF)
        .map_err(|e| CliError::Config(e.to_string()))?;
    let plant = Plant::new(plant_params::<D, N>(s), D::trajectory(s));
    let sensors = Sensors::new(uncertainty(s), s.uncertainty.filter_window).with_faults(&s.faults);
    let mut robot = VirtualRobot::new(plant, sensors, limits(s), dt, a.watchdog_periods);
    let steps = s.control_steps(D::DOF);
    let sig = Signals::install()?;
    stdin_restart(Arc::clone(&sig.usr1));
    let rt = rt_setup(&a.rt);
    warn_exposed("--listen", a.listen);
    let mut peer = UdpPeer::<N>::bind(a.listen, psk, max_ahead(dt))
        .map_err(|e| CliError::io(format!("binding {}", a.listen), e))?;
    let local = peer
        .local_addr()
        .map_err(|e| CliError::io("reading the bound address", e))?;
    {
        use std::io::Write as _;
        println!("listening on {local}");
        let _ = std::io::stdout().flush();
    }
    let io_err = |e| CliError::io("controller link", e);
    let mut clock = MonotonicClock::new(Duration::from_micros(a.rt.spin_us));
    let mut raw = Vec::with_capacity(2048);
    let connect_end = clock.now() + Duration::from_secs_f64(a.connect_timeout);
    while robot.state() != Lifecycle::Active {
        if sig.any() {
            return Err(sig.error(format!(
                "interrupted by {} before a controller connected; nothing written",
                sig.name()
            )));
        }
        if clock.now() >= connect_end {
            return Err(CliError::Runtime(format!(
                "no controller opened a session on {local} within {} s ({} datagrams \
                 received, {} rejected: a controller with another key is rejected)",
                a.connect_timeout,
                peer.stats().received,
                peer.stats().rejected.total()
            )));
        }
        if let Some(from) = peer
            .recv_raw(Duration::from_millis(100), &mut raw)
            .map_err(io_err)?
        {
            if peer.take(from, &raw, 0).map_err(io_err)? == RobotRx::Activated {
                robot.activate();
            }
        }
    }
    if !a.rt.quiet {
        eprintln!(
            "virtual robot: controller {} connected; {}-DOF, payload {} kg, {} s",
            peer.peer().map_or("?".into(), |p| p.to_string()),
            D::DOF,
            s.uncertainty.payload_kg,
            s.duration_s(D::DOF)
        );
    }
    open_out(&a.out, a.force)?;
    let mut trace = LiveTrace::create(&a.out, N, &scenario_keys(s))?;
    let mut metrics = Metrics::with_capacity(steps.min(1 << 22));
    let sched = Schedule {
        start: clock.now(),
        dt: Duration::from_secs_f64(dt),
    };
    let mut out_f = NetFaults::<SocketAddr>::tagged(faults);
    let mut in_f = NetFaults::<SocketAddr>::tagged(NetFaultSettings {
        seed: faults.seed.wrapping_add(0x9E37),
        ..faults
    });
    let mut timing = TimingStats::with_capacity(steps.min(1 << 22));
    let mut last_status = StepStatus::Ok;
    let mut reason = "duration reached".to_string();
    let mut signalled = false;
    let mut next_live = Duration::from_secs(1);
    let link_t = |clock: &MonotonicClock| clock.now().saturating_sub(sched.start).as_secs_f64();
    let dist: Vec<SVector<f64, N>> = Vec::new();
    for k in 0..steps as u64 {
        let deadline = sched.deadline(k);
        service(
            &mut peer, &mut robot, &mut out_f, &mut in_f, &mut clock, &mut raw, deadline, false,
            &link_t,
        )
        .map_err(io_err)?;
        let woke = clock.now();
        let wake_err = (woke.as_secs_f64() - deadline.as_secs_f64()) * 1e6;
        let sample = robot.sample();
        if let Some((bytes, to)) = peer.encode(&sample) {
            out_f.submit_tagged(link_t(&clock), to, &bytes);
        }
        service(
            &mut peer,
            &mut robot,
            &mut out_f,
            &mut in_f,
            &mut clock,
            &mut raw,
            deadline + wait,
            true,
            &link_t,
        )
        .map_err(io_err)?;
        let busy_from = clock.now();
        let st = robot.advance();
        if let Some(c) = st.command {
            last_status = status_from_code(c.status).unwrap_or(StepStatus::Ok);
        }
        let rec = st.record(
            last_status,
            if dist.is_empty() { None } else { Some(&dist) },
        );
        metrics.record(&rec).map_err(io_err)?;
        if !trace.record(&rec) {
            // A full disk or another write error: stop safely, keep what was written.
            robot.protective_stop(StopCause::Fault);
        }
        let p = robot.plant().state();
        if !(p
            .robot
            .q
            .iter()
            .chain(p.robot.qd.iter())
            .all(|v| v.is_finite()))
        {
            reason = format!("the simulated plant diverged at t = {} s", st.t);
            break;
        }
        let done = clock.now();
        timing.record(
            wake_err,
            (done.as_secs_f64() - busy_from.as_secs_f64()) * 1e6,
            done > sched.deadline(k + 1),
        );
        let at_zero = robot.applied().iter().all(|v| *v == 0.0);
        if sig.any() && !signalled {
            signalled = true;
            robot.protective_stop(StopCause::Operator);
        }
        if robot.state() == Lifecycle::Error && at_zero {
            if signalled {
                reason = "signal".into();
                break;
            }
            if robot.stop_requested() {
                reason = "the controller stopped".into();
                break;
            }
            if trace.error.is_some() {
                reason = "trace write error".into();
                break;
            }
            let since = robot
                .stop_events()
                .last()
                .and_then(|e| e.zero_at)
                .map_or(0.0, |z| st.t - z);
            let auto = a.auto_restart_after.is_some_and(|v| since >= v);
            if sig.usr1.swap(false, Ordering::Relaxed) || auto {
                robot.restart();
                peer.link().reset();
                if !a.rt.quiet {
                    eprintln!(
                        "virtual robot: restarted at t {:.2} s; waiting for a new session",
                        st.t
                    );
                }
            }
        }
        if done.saturating_sub(sched.start) >= next_live {
            next_live += Duration::from_secs(1);
            trace.flush();
            if !a.rt.quiet {
                let rs = robot.stats();
                live(
                    st.t,
                    &timing,
                    &format!(
                        "{:?} | held {} | idle {} | stops {} | rejected {}",
                        robot.state(),
                        rs.held,
                        rs.idle_periods,
                        rs.protective_stops,
                        peer.stats().rejected.total()
                    ),
                );
            }
        }
    }
    // Tell the controller the run ended (zero torque from here on).
    robot.end();
    for _ in 0..3 {
        let sample = robot.sample();
        if let Some((bytes, to)) = peer.encode(&sample) {
            let _ = peer.send_raw(&bytes, to);
        }
    }
    let trace_error = trace.finish();
    let summary = RobotSummary {
        summary: metrics.summary(
            &s.controller.kind.to_string(),
            D::DOF,
            s.uncertainty.payload_kg,
            dt,
        ),
        stop_reason: reason,
        lifecycle: robot.state(),
        robot: *robot.stats(),
        watchdog_events: robot.watchdog_events().to_vec(),
        protective_stops: robot.stop_events().to_vec(),
        link: peer.stats(),
        net_faults: NetFaultReport {
            settings: faults,
            to_controller: *out_f.counts(),
            from_controller: *in_f.counts(),
        },
        timing_us: timing.summary(),
        trace_error: trace_error.clone(),
        realtime: rt,
    };
    let wrote = write_json(&a.out.join("summary.json"), &summary);
    let m = &summary.summary;
    let f = |v: Option<f64>| v.map_or("-".to_string(), |x| format!("{x:.2}"));
    println!(
        "virtual robot: {} after {:.1} s\n  RMS strap force   thigh {} N   shank {} N\n  commanded {}  held {}  idle {}  protective stops {}  clamped {}  limit violations {}\n  rejected frames {}\n  wrote {}/trace.csv{}",
        summary.stop_reason,
        m.duration_s,
        f(m.rms_force_n.thigh),
        f(m.rms_force_n.shank),
        summary.robot.commanded,
        summary.robot.held,
        summary.robot.idle_periods,
        summary.robot.protective_stops,
        summary.robot.clamped,
        summary.robot.limit_violations,
        summary.link.rejected.total(),
        a.out.display(),
        if wrote.is_ok() { " and summary.json" } else { "" }
    );
    if let Some(e) = trace_error {
        return Err(CliError::Io(format!(
            "{e}: the robot made a protective stop and ended the run; the rows written before \
             are kept"
        )));
    }
    if signalled {
        return Err(sig.error(format!(
            "interrupted by {}: protective stop (torque ramped to zero); wrote {}",
            sig.name(),
            a.out.display()
        )));
    }
    wrote
}

/// Move frames until clock time `until` (or, with `until_command`, until the command
/// answering the current sample arrived): send the due outgoing frames, receive datagrams
/// through the incoming fault line and hand them to the link and the robot.
#[allow(clippy::too_many_arguments)]
fn service<const N: usize, Tr: exompc::sim::Trajectory<N>>(
    peer: &mut UdpPeer<N>,
    robot: &mut VirtualRobot<N, Tr>,
    out_f: &mut NetFaults<SocketAddr>,
    in_f: &mut NetFaults<SocketAddr>,
    clock: &mut MonotonicClock,
    raw: &mut Vec<u8>,
    until: Duration,
    until_command: bool,
    link_t: &dyn Fn(&MonotonicClock) -> f64,
) -> std::io::Result<()> {
    loop {
        let now = link_t(clock);
        while let Some((to, b)) = out_f.pop_due_tagged(now) {
            peer.send_raw(&b, to)?;
        }
        while let Some((from, b)) = in_f.pop_due_tagged(now) {
            let stamp = (now * 1e9) as u64;
            match peer.take(from, &b, stamp)? {
                RobotRx::Activated => {
                    robot.activate();
                }
                RobotRx::Command(c) => {
                    if let Err(e) = robot.command(&c) {
                        peer.link().count(e);
                    }
                }
                RobotRx::Reply | RobotRx::Nothing => {}
            }
        }
        if until_command && robot.has_current() {
            return Ok(());
        }
        let t = clock.now();
        if t >= until {
            return Ok(());
        }
        // Wait for a datagram, but not past the next due frame or `until`.
        let mut wait = until - t;
        for due in [out_f.next_due(), in_f.next_due()].into_iter().flatten() {
            let d = Duration::from_secs_f64((due - now).max(0.0));
            wait = wait.min(d);
        }
        if wait.is_zero() {
            continue;
        }
        if let Some(from) = peer.recv_raw(wait, raw)? {
            in_f.submit_tagged(link_t(clock), from, raw);
        }
    }
}

/// `run --config` with CiA 402 drives (`driver = "cia402"`): the robot of
/// `exompc_cli::can_cia402`, through the same loop, trace and summary as the AK robot.
fn run_cia402<D: Dof<N>, const N: usize>(
    s: &Experiment,
    a: &RunArgs,
    hw: &exompc_can::config::HardwareConfig,
) -> Result<(), CliError>
where
    D::Traj: Send + 'static,
{
    let periods = can_periods::<D, N>(s, a);
    let mut rig = exompc_cli::can_cia402::rig::<D, N>(
        s,
        hw,
        Duration::from_micros(a.rt.spin_us),
        periods + 64,
    )?;
    if !a.rt.quiet {
        eprintln!("exompc run: CAN robot on the {}", rig.label);
    }
    let label = rig.label.clone();
    let bus = rig.bus.clone();
    let leg = rig.leg.clone();
    let dt = s.timing.dt;
    drive::<D, N, _, _>(s, a, &mut rig.robot, rig.clock, &label, move |robot| {
        use exompc_can::CanBus as _;
        // The bus load first: reaching the present calls into the leg.
        let load = bus.map(|b| bus_load_json(&b.load()));
        let rms_true =
            leg.map(|l| rms_force_true(l.lock().unwrap_or_else(|e| e.into_inner()).history()));
        Some(can_summary(
            Some("cia402"),
            robot.stats(),
            robot.stop_events(),
            &robot.bus().counters(),
            load,
            rms_true,
            dt,
        ))
    })
}

/// Periods `run --config` plans for a CAN robot: `--duration` (plus a margin) or the
/// scenario's length, at most 2^22.
fn can_periods<D: Dof<N>, const N: usize>(s: &Experiment, a: &RunArgs) -> usize {
    a.duration
        .map_or(s.control_steps(D::DOF), |d| (d / s.timing.dt) as usize + 16)
        .min(1 << 22)
}

/// The summary's `can` section of a CAN robot (`driver` only where it is not the AK default).
fn can_summary<S: serde::Serialize + ?Sized, E: serde::Serialize + ?Sized>(
    driver: Option<&str>,
    stats: &S,
    stops: &E,
    c: &exompc_can::BusCounters,
    load: Option<serde_json::Value>,
    rms_true: Option<Vec<f64>>,
    dt: f64,
) -> serde_json::Value {
    let mut v = serde_json::json!({
        "stats": stats,
        "stops": stops,
        "bus": bus_counters_json(c),
        "bus_load": load,
        "rms_force_true_n": rms_true,
        "period_s": dt,
    });
    if let Some(d) = driver {
        v["driver"] = serde_json::json!(d);
    }
    v
}

/// RMS of the true strap forces (N) over a virtual leg's history, per strap.
fn rms_force_true<const N: usize>(h: &[exompc_can::emulator::LegStep<N>]) -> Vec<f64> {
    let n = h.len().max(1) as f64;
    (0..N)
        .map(|j| {
            (h.iter()
                .map(|x| x.force_true[j] * x.force_true[j])
                .sum::<f64>()
                / n)
                .sqrt()
        })
        .collect()
}

/// A virtual bus's load, for the summary's `can` section.
fn bus_load_json(l: &exompc_can::BusLoad) -> serde_json::Value {
    serde_json::json!({
        "fraction": l.fraction(),
        "frames": l.frames,
        "error_frames": l.error_frames,
        "elapsed_s": l.elapsed.as_secs_f64(),
    })
}

/// A bus endpoint's counters, for the summary's `can` section.
fn bus_counters_json(c: &exompc_can::BusCounters) -> serde_json::Value {
    serde_json::json!({
        "sent": c.sent, "received": c.received, "send_errors": c.send_errors,
        "receive_errors": c.receive_errors, "error_frames": c.error_frames,
        "dropped": c.dropped,
    })
}

/// `virtual-robot --serial` (a child of this command's module: commands stay leaves).
#[cfg(unix)]
#[path = "serial_robot.rs"]
mod serial_robot;
