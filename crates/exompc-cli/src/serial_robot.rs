//! `exompc virtual-robot --serial PATH`: the virtual robot on a byte stream (a Unix socket that
//! QEMU's `-serial unix:PATH` connects to: the firmware's UART) instead of UDP, in lockstep
//! with the controller: each period waits for the command answering its sample, however long
//! the controller takes in wall time (an emulated MCU is not real-time), so the run is the
//! simulated-time closed loop of `simulate` with the controller at the far end of the link.
//! The frames, keys, handshake and the robot's protocol state are `exompc::runtime`'s (the
//! firmware runs the same code); the stream is split into frames by [`Deframer`]
//! (docs/EMBEDDED.md, "The serial link").

use super::{max_ahead, open_out, write_json, LiveTrace};
use exompc::config::Experiment;
use exompc::control::StepStatus;
use exompc::runtime::frame::{max_frame_len, status_from_code};
use exompc::runtime::session::random_nonce;
use exompc::runtime::{Deframer, Lifecycle, LinkStats, Psk, RobotLink, RobotRx};
use exompc::scenario::{
    limits, plant_params, uncertainty, Dof, RobotStats, StopCause, VirtualRobot,
};
use exompc::sim::{Metrics, Plant, Recorder, Sensors};
use exompc_cli::error::CliError;
use exompc_cli::run::scenario_keys;
use serde::Serialize;
use std::io::{Read, Write};
use std::net::SocketAddr;
use std::os::unix::net::{UnixListener, UnixStream};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// The serial line's one peer (the link's address checks need one).
const LINE: SocketAddr = SocketAddr::new(std::net::IpAddr::V4(std::net::Ipv4Addr::UNSPECIFIED), 0);

/// What `virtual-robot --serial` needs from its arguments.
pub(crate) struct SerialOpts<'a> {
    /// The Unix socket to create and listen on.
    pub path: &'a Path,
    /// Wait this long (wall time) for the controller to connect, and for any frame after.
    pub timeout: Duration,
    /// Ride-through periods before a protective stop.
    pub watchdog_periods: u64,
    /// At this robot time (s), send a forged copy of the sample and a replay of the previous
    /// one before the real sample (tests the controller's rejection).
    pub inject_forged_at: Option<f64>,
    /// Output folder and whether earlier results may be moved aside.
    pub out: &'a PathBuf,
    /// Move earlier results aside.
    pub force: bool,
    /// No progress lines.
    pub quiet: bool,
}

#[derive(Serialize)]
struct SerialSummary {
    summary: exompc::sim::Summary,
    stop_reason: String,
    lifecycle: Lifecycle,
    robot: RobotStats,
    link: LinkStats,
    stream_skipped_bytes: u64,
    injected: Injected,
    trace_error: Option<String>,
}

#[derive(Default, Serialize)]
struct Injected {
    forged: u64,
    replayed: u64,
}

/// The byte stream with the deframer: the next frame, waiting at most `timeout`.
struct Line {
    sock: UnixStream,
    deframer: Deframer,
    chunk: [u8; 512],
    held: usize,
    at: usize,
    timeout: Duration,
}

impl Line {
    fn send(&mut self, bytes: &[u8]) -> Result<(), CliError> {
        self.sock
            .write_all(bytes)
            .map_err(|e| CliError::io("serial link: writing", e))
    }

    /// Hand each frame arriving within the timeout to `take` until it returns `true`.
    fn until(&mut self, mut take: impl FnMut(&[u8]) -> bool) -> Result<(), CliError> {
        let end = Instant::now() + self.timeout;
        loop {
            while self.at < self.held {
                let b = self.chunk[self.at];
                self.at += 1;
                if let Some(f) = self.deframer.push(b) {
                    if take(f) {
                        return Ok(());
                    }
                }
            }
            let left = end.saturating_duration_since(Instant::now());
            if left.is_zero() {
                return Err(CliError::Runtime(format!(
                    "serial link: the controller sent nothing usable for {} s",
                    self.timeout.as_secs_f64()
                )));
            }
            self.sock
                .set_read_timeout(Some(left))
                .map_err(|e| CliError::io("serial link", e))?;
            match self.sock.read(&mut self.chunk) {
                Ok(0) => {
                    return Err(CliError::Runtime(
                        "serial link: the controller closed the line".into(),
                    ))
                }
                Ok(n) => {
                    self.held = n;
                    self.at = 0;
                }
                Err(e)
                    if matches!(
                        e.kind(),
                        std::io::ErrorKind::WouldBlock
                            | std::io::ErrorKind::TimedOut
                            | std::io::ErrorKind::Interrupted
                    ) => {}
                Err(e) => return Err(CliError::io("serial link: reading", e)),
            }
        }
    }
}

fn accept(path: &Path, timeout: Duration) -> Result<UnixStream, CliError> {
    if path.exists() {
        return Err(CliError::Usage(format!(
            "--serial {}: the path exists; name a new socket path (nothing is deleted)",
            path.display()
        )));
    }
    let l = UnixListener::bind(path)
        .map_err(|e| CliError::io(format!("--serial {}: binding", path.display()), e))?;
    println!("listening on {}", path.display());
    let _ = std::io::stdout().flush();
    l.set_nonblocking(true)
        .map_err(|e| CliError::io("serial link", e))?;
    let end = Instant::now() + timeout;
    let got = loop {
        match l.accept() {
            Ok((s, _)) => break Ok(s),
            Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => {
                if Instant::now() >= end {
                    break Err(CliError::Runtime(format!(
                        "no controller connected to {} within {} s",
                        path.display(),
                        timeout.as_secs_f64()
                    )));
                }
                std::thread::sleep(Duration::from_millis(20));
            }
            Err(e) => break Err(CliError::io("serial link: accepting", e)),
        }
    };
    // The socket file is ours (created above): remove it once connected or given up.
    let _ = std::fs::remove_file(path);
    let s = got?;
    s.set_nonblocking(false)
        .map_err(|e| CliError::io("serial link", e))?;
    Ok(s)
}

/// Run the virtual robot of `s` over the serial line until the run's duration.
pub(crate) fn serve<D: Dof<N>, const N: usize>(
    s: &Experiment,
    o: &SerialOpts<'_>,
    psk: Psk,
) -> Result<(), CliError> {
    let dt = s.timing.dt;
    s.check_trajectory(D::DOF)
        .map_err(|e| CliError::Config(e.to_string()))?;
    let plant = Plant::new(plant_params::<D, N>(s), D::trajectory(s));
    let sensors = Sensors::new(uncertainty(s), s.uncertainty.filter_window).with_faults(&s.faults);
    let mut robot = VirtualRobot::new(plant, sensors, limits(s), dt, o.watchdog_periods);
    let steps = s.control_steps(D::DOF);
    let mut link = RobotLink::<N>::new(psk, max_ahead(dt));
    let mut line = Line {
        sock: accept(o.path, o.timeout)?,
        deframer: Deframer::new(max_frame_len(N)),
        chunk: [0; 512],
        held: 0,
        at: 0,
        timeout: o.timeout,
    };
    // The handshake: hello → challenge, then the controller's confirmation activates.
    let mut reply: Option<Vec<u8>> = None;
    let mut activated = false;
    while !activated {
        line.until(|f| {
            match link.receive(LINE, f, 0, &mut || random_nonce().ok()) {
                RobotRx::Reply => reply = Some(link.reply().to_vec()),
                RobotRx::Activated => activated = true,
                _ => {}
            }
            reply.is_some() || activated
        })?;
        if let Some(r) = reply.take() {
            line.send(&r)?;
            link.count_sent(true);
        }
    }
    robot.activate();
    if !o.quiet {
        eprintln!(
            "virtual robot: controller connected on the serial line; {}-DOF, payload {} kg, {} s",
            D::DOF,
            s.uncertainty.payload_kg,
            s.duration_s(D::DOF)
        );
    }
    open_out(o.out, o.force)?;
    let mut trace = LiveTrace::create(o.out, N, &scenario_keys(s))?;
    let mut metrics = Metrics::with_capacity(steps.min(1 << 22));
    let mut injected = Injected::default();
    let mut previous: Vec<u8> = Vec::new();
    let mut last_status = StepStatus::Ok;
    let mut reason = "duration reached".to_string();
    let inject_k = o.inject_forged_at.map(|t| (t / dt).round() as u64);
    for k in 0..steps as u64 {
        let sample = robot.sample();
        let Some((bytes, _)) = link.sample(&sample) else {
            reason = "the session ended".into();
            break;
        };
        let bytes = bytes.to_vec();
        if inject_k == Some(k) && !previous.is_empty() {
            let mut forged = bytes.clone();
            if let Some(b) = forged.get_mut(40) {
                *b ^= 1; // a bit of the first joint angle: the MAC no longer matches
            }
            line.send(&forged)?;
            line.send(&previous)?;
            injected.forged += 1;
            injected.replayed += 1;
        }
        line.send(&bytes)?;
        link.count_sent(true);
        previous = bytes;
        line.until(|f| {
            match link.receive(LINE, f, (sample.stamp_ns).max(1), &mut || None) {
                RobotRx::Command(c) => {
                    if let Err(e) = robot.command(&c) {
                        link.count(e);
                    }
                }
                RobotRx::Activated | RobotRx::Reply | RobotRx::Nothing => {}
            }
            robot.has_current()
        })?;
        let st = robot.advance();
        if let Some(c) = st.command {
            last_status = status_from_code(c.status).unwrap_or(StepStatus::Ok);
        }
        let rec = st.record(last_status, None);
        metrics
            .record(&rec)
            .map_err(|e| CliError::io("metrics", e))?;
        if !trace.record(&rec) {
            robot.protective_stop(StopCause::Fault);
            reason = "trace write error".into();
            break;
        }
        if !st
            .robot
            .q
            .iter()
            .chain(st.robot.qd.iter())
            .all(|v| v.is_finite())
        {
            reason = format!("the simulated plant diverged at t = {} s", st.t);
            break;
        }
    }
    // Tell the controller the run ended.
    robot.end();
    let end = robot.sample();
    if let Some((bytes, _)) = link.sample(&end) {
        let b = bytes.to_vec();
        let ok = line.send(&b).is_ok();
        link.count_sent(ok);
        // Keep the line open until the controller closes it (QEMU drops what its guest has
        // not read yet when the other end closes first).
        let mut sink = [0u8; 256];
        let _ = line.sock.set_read_timeout(Some(o.timeout));
        while matches!(line.sock.read(&mut sink), Ok(n) if n > 0) {}
    }
    let trace_error = trace.finish();
    let summary = SerialSummary {
        summary: metrics.summary(
            &s.controller.kind.to_string(),
            D::DOF,
            s.uncertainty.payload_kg,
            dt,
        ),
        stop_reason: reason,
        lifecycle: robot.state(),
        robot: *robot.stats(),
        link: link.stats(),
        stream_skipped_bytes: line.deframer.skipped(),
        injected,
        trace_error: trace_error.clone(),
    };
    let wrote = write_json(&o.out.join("summary.json"), &summary);
    let m = &summary.summary;
    let f = |v: Option<f64>| v.map_or("-".to_string(), |x| format!("{x:.4}"));
    println!(
        "virtual robot (serial): {} after {:.2} s; RMS strap force thigh {} N, shank {} N; \
         commanded {}, held {}, rejected frames {}; wrote {}",
        summary.stop_reason,
        m.duration_s,
        f(m.rms_force_n.thigh),
        f(m.rms_force_n.shank),
        summary.robot.commanded,
        summary.robot.held,
        summary.link.rejected.total(),
        o.out.display()
    );
    if let Some(e) = trace_error {
        return Err(CliError::Io(e));
    }
    wrote
}
