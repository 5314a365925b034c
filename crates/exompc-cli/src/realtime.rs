//! `exompc run` (the controller process) and `exompc virtual-robot` (the simulated robot
//! process): the real-time loop over the UDP link of `exompc::runtime` (see
//! `docs/REALTIME.md`).

use crate::args::ConfigOpt;
use clap::Args;
use exompc::config::ControllerKind;
use exompc::config::Scenario;
use exompc::control::{Controller, StepStatus};
use exompc::runtime::frame::status_from_code;
use exompc::runtime::{
    Clock, ControlLoop, LoopSettings, MonotonicClock, NetFaultSettings, NetFaults, Schedule,
    TimingStats, UdpPeer, UdpRobot, VirtualRobot,
};
use exompc::scenario::{build_supervised, limits, plant_params, uncertainty, Dof, OneDof, TwoDof};
use exompc::sim::{Metrics, Plant, Recorder, Sensors, StepRecord};
use exompc_cli::error::CliError;
use exompc_cli::io;
use exompc_cli::run::scenario_keys;
use exompc_cli::trace::CsvTrace;
use nalgebra::SVector;
use serde::Serialize;
use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Duration;

/// Real-time settings of the process (both commands).
#[derive(Debug, Args)]
pub(crate) struct RtOpts {
    /// SCHED_FIFO priority (1-99) of the process; 0 keeps the normal scheduler.
    #[arg(long, value_name = "P", default_value_t = 80, value_parser = clap::value_parser!(u8).range(0..=99))]
    rt_priority: u8,
    /// Pin the process to this CPU.
    #[arg(long, value_name = "CPU")]
    cpu: Option<usize>,
    /// Do not lock memory (mlockall).
    #[arg(long)]
    no_mlock: bool,
    /// Busy-wait the last part of each sleep (µs); 0 only sleeps.
    #[arg(long, value_name = "US", default_value_t = 0)]
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
            if let Some(cpu) = o.cpu {
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

fn stop_flag() -> Result<Arc<AtomicBool>, CliError> {
    let f = Arc::new(AtomicBool::new(false));
    for sig in [signal_hook::consts::SIGINT, signal_hook::consts::SIGTERM] {
        signal_hook::flag::register(sig, Arc::clone(&f))
            .map_err(|e| CliError::io("installing the signal handler", e))?;
    }
    Ok(f)
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

fn write_json(path: &std::path::Path, v: &impl Serialize) -> Result<(), CliError> {
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

// ------------------------------------------------------------------------------------------
// exompc run

#[derive(Debug, Args)]
pub(crate) struct RunArgs {
    #[command(flatten)]
    config: ConfigOpt,
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
    /// Stop (with the torque ramp) after this long (s); default: until the robot ends the run
    /// or SIGINT/SIGTERM.
    #[arg(long, value_name = "S")]
    duration: Option<f64>,
    /// Wait this long for the robot's first sample (s).
    #[arg(long, value_name = "S", default_value_t = 10.0)]
    connect_timeout: f64,
    /// Give up when no sample arrived for this long (s).
    #[arg(long, value_name = "S", default_value_t = 3.0)]
    give_up: f64,
    /// Wake this long before a sample is expected (ms); default period/5.
    #[arg(long, value_name = "MS")]
    lead_ms: Option<f64>,
    /// Wait for a sample at most this long after waking (ms); default period/2.
    #[arg(long, value_name = "MS")]
    sample_timeout_ms: Option<f64>,
    /// Output folder for `trace.csv` and `summary.json`.
    #[arg(long, value_name = "DIR", default_value = "out-run")]
    out: PathBuf,
    /// Replace the results of an earlier run in the output folder (without it, refused).
    #[arg(long)]
    force: bool,
    #[command(flatten)]
    rt: RtOpts,
}

#[derive(Serialize)]
struct RunSummary {
    controller: String,
    dof: usize,
    robot: String,
    stop_reason: String,
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
    realtime: RtStatus,
}

pub(crate) fn run(a: RunArgs) -> Result<(), CliError> {
    let mut s = a.config.load()?;
    crate::args::apply_overrides(&mut s, a.dof, a.controller, None, None, None)?;
    if let Some(d) = a.duration {
        secs("duration", d, 0.0, 1e7)?;
    }
    secs("connect-timeout", a.connect_timeout, 0.0, 1e6)?;
    secs("give-up", a.give_up, 0.0, 1e6)?;
    io::ensure_out_dir(&a.out)?;
    exompc_cli::earlier::refuse_or_clear(&a.out, exompc_cli::earlier::RUN_FILES, a.force, "run")?;
    match a.dof {
        1 => run_dof::<OneDof, 1>(&s, &a),
        _ => run_dof::<TwoDof, 2>(&s, &a),
    }
}

fn run_dof<D: Dof<N>, const N: usize>(s: &Scenario, a: &RunArgs) -> Result<(), CliError> {
    let dt = Duration::from_secs_f64(s.timing.dt);
    let mut settings = LoopSettings::new(dt, s.uncertainty.filter_window, limits(s));
    if let Some(ms) = a.lead_ms {
        settings.lead = secs("lead-ms", ms * 1e-3, 0.0, s.timing.dt)?;
    }
    if let Some(ms) = a.sample_timeout_ms {
        settings.sample_timeout = secs("sample-timeout-ms", ms * 1e-3, 0.0, s.timing.dt)?;
    }
    let sup = build_supervised::<D, N>(s, s.controller.kind)
        .map_err(|e| CliError::Runtime(e.to_string()))?;
    let name = sup.name().to_string();
    let capacity = a
        .duration
        .map_or(s.control_steps(D::DOF), |d| (d / s.timing.dt) as usize + 16)
        .min(1 << 22);
    let mut lp = ControlLoop::new(sup, settings, capacity);
    let mut trace = CsvTrace::create_with(&a.out.join("trace.csv"), N, &scenario_keys(s))?;
    let stop = stop_flag()?;
    let rt = rt_setup(&a.rt);
    let mut robot = UdpRobot::<N>::connect(a.bind, a.robot)
        .map_err(|e| CliError::io(format!("binding {}", a.bind), e))?;
    let mut clock = MonotonicClock::new(Duration::from_micros(a.rt.spin_us));
    if !a.rt.quiet {
        eprintln!(
            "exompc run: {name}, {}-DOF, period {} ms, robot {} (from {})",
            D::DOF,
            s.timing.dt * 1e3,
            a.robot,
            robot.local_addr().map_or("?".into(), |x| x.to_string())
        );
    }
    let io_err = |e| CliError::io("robot link", e);
    if !lp
        .connect(
            &mut robot,
            &mut clock,
            Duration::from_secs_f64(a.connect_timeout),
            Duration::from_millis(100),
        )
        .map_err(io_err)?
    {
        return Err(CliError::Runtime(format!(
            "no sample from the robot at {} within {} s",
            a.robot, a.connect_timeout
        )));
    }
    let mut dist =
        vec![SVector::<f64, N>::zeros(); lp.controller().probabilities().map_or(0, |p| p.len())];
    let mut sum_f2 = [0.0f64; N];
    let mut n_f = 0u64;
    let mut step_us = Vec::with_capacity(capacity);
    let mut last_sample = clock.now();
    let mut next_live = clock.now() + Duration::from_secs(1);
    let mut reason = String::new();
    let nan = SVector::<f64, N>::from_element(f64::NAN);
    loop {
        let k = lp.stats().periods;
        if !lp.is_stopping() {
            if stop.load(Ordering::Relaxed) {
                lp.request_stop();
                reason = "signal".into();
            } else if a.duration.is_some_and(|d| k as f64 * s.timing.dt >= d) {
                lp.request_stop();
                reason = "duration".into();
            }
        }
        let rec = lp.period(&mut robot, &mut clock).map_err(io_err)?;
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
        Recorder::<N>::record(&mut trace, &sr).map_err(|e| CliError::io("writing trace", e))?;
        if rec.robot_ended {
            if reason.is_empty() {
                reason = "robot ended the run".into();
            }
            break;
        }
        if lp.ramp_done() {
            break;
        }
        if now.saturating_sub(last_sample).as_secs_f64() > a.give_up {
            reason = format!("no sample from the robot for {} s", a.give_up);
            break;
        }
        if !a.rt.quiet && now >= next_live {
            next_live += Duration::from_secs(1);
            let st = lp.stats();
            live(
                m.t,
                lp.timing(),
                &format!(
                    "missing samples {} late {} | robot watchdog {} | rejected {}",
                    st.missing_samples,
                    st.late_samples,
                    st.robot_watchdog_samples,
                    robot_rejected(&robot)
                ),
            );
        }
    }
    lp.send_stop(&mut robot, &clock, 3).map_err(io_err)?;
    trace.finish()?;
    let summary = RunSummary {
        controller: name,
        dof: D::DOF,
        robot: a.robot.to_string(),
        stop_reason: reason,
        duration_s: lp.stats().periods as f64 * s.timing.dt,
        timing_us: lp.timing().summary(),
        controller_step_us: exompc::runtime::Percentiles::of(&mut step_us),
        counters: *lp.stats(),
        link: exompc::runtime::RobotInterface::<N>::link_stats(&robot),
        safety: lp.controller().safety_report().cloned(),
        safety_summary: lp
            .controller()
            .safety_report()
            .map(exompc::sim::SafetySummary::from_report),
        rms_force_measured_n: sum_f2
            .iter()
            .map(|v| (v / n_f.max(1) as f64).sqrt())
            .collect(),
        realtime: rt,
    };
    write_json(&a.out.join("summary.json"), &summary)?;
    let t = &summary.timing_us;
    println!(
        "exompc run: stopped ({}) after {:.1} s, {} periods\n  period error  p50 {:.0} us  p99 {:.0} us  max {:.0} us   deadline misses {}\n  controller step p50 {:.0} us  p99 {:.0} us   missing samples {}   limit violations {}\n  wrote {}/trace.csv and summary.json",
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
        a.out.display()
    );
    if let Some(sa) = &summary.safety_summary {
        println!("{}", exompc_cli::run::describe_safety(sa));
    }
    Ok(())
}

fn robot_rejected<const N: usize>(r: &UdpRobot<N>) -> u64 {
    exompc::runtime::RobotInterface::<N>::link_stats(r)
        .rejected
        .total()
}

// ------------------------------------------------------------------------------------------
// exompc virtual-robot

#[derive(Debug, Args)]
pub(crate) struct VirtualRobotArgs {
    #[command(flatten)]
    config: ConfigOpt,
    /// Experiment: 1 (knee only) or 2 (hip and knee).
    #[arg(long, default_value_t = 2, value_parser = clap::value_parser!(u8).range(1..=2))]
    dof: u8,
    /// Override `uncertainty.payload_kg` (kg).
    #[arg(long, value_name = "KG", allow_negative_numbers = true)]
    payload: Option<f64>,
    /// Override the run length (s) of the chosen experiment.
    #[arg(long, value_name = "S", allow_negative_numbers = true)]
    duration: Option<f64>,
    /// Address to listen on (port 0: any free port, printed on stdout).
    #[arg(long, value_name = "ADDR", default_value = "127.0.0.1:7300")]
    listen: SocketAddr,
    /// Wait this long for a controller (s).
    #[arg(long, value_name = "S", default_value_t = 60.0)]
    connect_timeout: f64,
    /// Wait for the command answering a sample at most this long (ms); default 0.8 period.
    #[arg(long, value_name = "MS")]
    command_wait_ms: Option<f64>,
    /// Zero the torque after this many periods without a valid command.
    #[arg(long, value_name = "N", default_value_t = 2)]
    watchdog_periods: u64,
    /// Network fault: probability of losing each frame, both directions (0-1).
    #[arg(long, value_name = "P", default_value_t = 0.0)]
    loss: f64,
    /// Network fault: probability of duplicating each frame (0-1).
    #[arg(long, value_name = "P", default_value_t = 0.0)]
    duplicate: f64,
    /// Network fault: probability of swapping a frame with the next one (0-1).
    #[arg(long, value_name = "P", default_value_t = 0.0)]
    reorder: f64,
    /// Network fault: delay of a delay spike (ms).
    #[arg(long, value_name = "MS", default_value_t = 20.0)]
    delay_ms: f64,
    /// Network fault: a delay spike every this many seconds (0: none).
    #[arg(long, value_name = "S", default_value_t = 0.0)]
    delay_every: f64,
    /// Network fault: length of each delay spike (s).
    #[arg(long, value_name = "S", default_value_t = 0.05)]
    delay_width: f64,
    /// Network fault: disconnect (drop everything) at this time (s).
    #[arg(long, value_name = "S")]
    disconnect_at: Option<f64>,
    /// Network fault: length of the disconnection (s).
    #[arg(long, value_name = "S", default_value_t = 1.0)]
    disconnect_for: f64,
    /// Seed of the network fault draws.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Output folder for the robot's `trace.csv` (true states) and `summary.json`.
    #[arg(long, value_name = "DIR", default_value = "out-robot")]
    out: PathBuf,
    /// Replace the results of an earlier run in the output folder (without it, refused).
    #[arg(long)]
    force: bool,
    #[command(flatten)]
    rt: RtOpts,
}

#[derive(Serialize)]
struct RobotSummary {
    summary: exompc::sim::Summary,
    stop_reason: String,
    robot: exompc::runtime::RobotStats,
    watchdog_events: Vec<exompc::runtime::WatchdogEvent>,
    link: exompc::runtime::LinkStats,
    net_faults: NetFaultReport,
    timing_us: exompc::runtime::TimingSummary,
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
    secs("connect-timeout", a.connect_timeout, 0.0, 1e6)?;
    if a.watchdog_periods == 0 {
        return Err(CliError::Usage(
            "--watchdog-periods: must be ≥ 1, got 0".into(),
        ));
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
    io::ensure_out_dir(&a.out)?;
    exompc_cli::earlier::refuse_or_clear(&a.out, exompc_cli::earlier::RUN_FILES, a.force, "run")?;
    match a.dof {
        1 => robot_dof::<OneDof, 1>(&s, &a, faults),
        _ => robot_dof::<TwoDof, 2>(&s, &a, faults),
    }
}

fn robot_dof<D: Dof<N>, const N: usize>(
    s: &Scenario,
    a: &VirtualRobotArgs,
    faults: NetFaultSettings,
) -> Result<(), CliError> {
    let dt = s.timing.dt;
    let wait = match a.command_wait_ms {
        Some(ms) => secs("command-wait-ms", ms * 1e-3, 0.0, dt)?,
        None => Duration::from_secs_f64(0.8 * dt),
    };
    s.check_trajectory(D::DOF)
        .map_err(|e| CliError::Config(e.to_string()))?;
    let plant = Plant::new(plant_params::<D, N>(s), D::trajectory(s));
    let sensors = Sensors::new(uncertainty(s), s.uncertainty.filter_window).with_faults(&s.faults);
    let mut robot = VirtualRobot::new(plant, sensors, limits(s), dt, a.watchdog_periods);
    let steps = s.control_steps(D::DOF);
    let mut trace = CsvTrace::create_with(&a.out.join("trace.csv"), N, &scenario_keys(s))?;
    let mut metrics = Metrics::with_capacity(steps.min(1 << 22));
    let stop = stop_flag()?;
    let rt = rt_setup(&a.rt);
    let mut peer = UdpPeer::<N>::bind(a.listen)
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
    let mut raw = Vec::with_capacity(256);
    let connect_end = clock.now() + Duration::from_secs_f64(a.connect_timeout);
    while peer.peer().is_none() {
        if stop.load(Ordering::Relaxed) || clock.now() >= connect_end {
            return Err(CliError::Runtime(format!(
                "no controller connected to {local} within {} s",
                a.connect_timeout
            )));
        }
        peer.recv_raw(Duration::from_millis(100), &mut raw)
            .map_err(io_err)?;
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
    let sched = Schedule {
        start: clock.now(),
        dt: Duration::from_secs_f64(dt),
    };
    let mut out_f = NetFaults::new(faults);
    let mut in_f = NetFaults::new(NetFaultSettings {
        seed: faults.seed.wrapping_add(0x9E37),
        ..faults
    });
    let mut timing = TimingStats::with_capacity(steps.min(1 << 22));
    let mut last_status = StepStatus::Ok;
    let mut reason = "duration reached".to_string();
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
        let bytes = peer.encode(&sample).to_vec();
        out_f.submit(link_t(&clock), &bytes);
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
        let rec = StepRecord {
            k: st.k as usize,
            t: st.t,
            robot: st.robot,
            human: st.human,
            desired: st.desired,
            torque_robot: st.torque,
            torque_prev: st.torque_prev,
            torque_human: st.torque_human,
            force_true: st.force_true,
            force_measured: st.force_raw,
            probabilities: None,
            disturbances: if dist.is_empty() { None } else { Some(&dist) },
            status: last_status,
            iterations: st.command.map_or(0, |c| c.iterations),
            step_time_us: st.command.map_or(0.0, |c| f64::from(c.compute_ns) * 1e-3),
            within_limits: st.within_limits,
        };
        metrics.record(&rec).map_err(io_err)?;
        Recorder::<N>::record(&mut trace, &rec).map_err(|e| CliError::io("writing trace", e))?;
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
        if robot.stop_requested() {
            reason = "the controller stopped".into();
            break;
        }
        if stop.load(Ordering::Relaxed) {
            reason = "signal".into();
            break;
        }
        if !a.rt.quiet && done.saturating_sub(sched.start) >= next_live {
            next_live += Duration::from_secs(1);
            let rs = robot.stats();
            live(
                st.t,
                &timing,
                &format!(
                    "held {} | watchdog periods {} | rejected {}",
                    rs.held,
                    rs.watchdog_periods,
                    peer.stats().rejected.total()
                ),
            );
        }
    }
    // Tell the controller the run ended (zero torque from here on).
    robot.end();
    for _ in 0..3 {
        let sample = robot.sample();
        let bytes = peer.encode(&sample).to_vec();
        peer.send_raw(&bytes).map_err(io_err)?;
    }
    trace.finish()?;
    let summary = RobotSummary {
        summary: metrics.summary(
            &format!("{:?}", s.controller.kind).to_lowercase(),
            D::DOF,
            s.uncertainty.payload_kg,
            dt,
        ),
        stop_reason: reason,
        robot: *robot.stats(),
        watchdog_events: robot.watchdog_events().to_vec(),
        link: peer.stats(),
        net_faults: NetFaultReport {
            settings: faults,
            to_controller: *out_f.counts(),
            from_controller: *in_f.counts(),
        },
        timing_us: timing.summary(),
        realtime: rt,
    };
    write_json(&a.out.join("summary.json"), &summary)?;
    let m = &summary.summary;
    let f = |v: Option<f64>| v.map_or("-".to_string(), |x| format!("{x:.2}"));
    println!(
        "virtual robot: {} after {:.1} s\n  RMS strap force   thigh {} N   shank {} N\n  commanded {}  held {}  watchdog periods {} (trips {})  limit violations {}\n  rejected frames {}\n  wrote {}/trace.csv and summary.json",
        summary.stop_reason,
        m.duration_s,
        f(m.rms_force_n.thigh),
        f(m.rms_force_n.shank),
        summary.robot.commanded,
        summary.robot.held,
        summary.robot.watchdog_periods,
        summary.robot.watchdog_trips,
        summary.robot.limit_violations,
        summary.link.rejected.total(),
        a.out.display()
    );
    Ok(())
}

/// Move frames until clock time `until` (or, with `until_command`, until the command
/// answering the current sample arrived): send the due outgoing frames, receive commands
/// through the incoming fault line and offer them to the robot.
#[allow(clippy::too_many_arguments)]
fn service<const N: usize, Tr: exompc::sim::Trajectory<N>>(
    peer: &mut UdpPeer<N>,
    robot: &mut VirtualRobot<N, Tr>,
    out_f: &mut NetFaults,
    in_f: &mut NetFaults,
    clock: &mut MonotonicClock,
    raw: &mut Vec<u8>,
    until: Duration,
    until_command: bool,
    link_t: &dyn Fn(&MonotonicClock) -> f64,
) -> std::io::Result<()> {
    loop {
        let now = link_t(clock);
        while let Some(b) = out_f.pop_due(now) {
            peer.send_raw(&b)?;
        }
        while let Some(b) = in_f.pop_due(now) {
            if let Some(c) = peer.decode_command(&b) {
                match robot.command(&c) {
                    Ok(_) => peer.count_accepted(),
                    Err(e) => peer.count(e),
                }
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
        if peer.recv_raw(wait, raw)? {
            in_f.submit(link_t(clock), raw);
        }
    }
}
