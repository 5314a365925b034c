//! The real-time runtime without sockets: the frame codec (property tests on round trips and
//! arbitrary bytes), sequence bookkeeping, the controller loop against the virtual robot on a
//! test clock (reproduces the offline closed loop of `simulate`), the robot's watchdog, the
//! stop ramp, and the network fault injector.

use exompc::config::Scenario;
use exompc::control::{Controller, StepStatus};
use exompc::runtime::frame::{
    command_flags, command_len, robot_flags, sample_len, status_code, status_from_code,
};
use exompc::runtime::{
    decode, encode_command, encode_sample, Clock, ControlLoop, Frame, FrameError, LinkStats,
    LoopSettings, NetFaultSettings, NetFaults, RejectCounts, RobotCommand, RobotInterface,
    RobotSample, RobotStep, SeqTracker, VirtualRobot,
};
use exompc::scenario::{
    build_supervised, limits, plant_params, run_experiment, uncertainty, Dof, TwoDof,
};
use exompc::sim::{Plant, Sensors, TraceLog};
use nalgebra::{SVector, Vector2};
use proptest::prelude::*;
use std::cell::Cell;
use std::rc::Rc;
use std::time::Duration;

fn any_f64() -> impl Strategy<Value = f64> + Clone {
    prop_oneof![
        -1e3..1e3f64,
        Just(f64::NAN),
        Just(f64::INFINITY),
        any::<f64>()
    ]
}

fn vec2(s: impl Strategy<Value = f64> + Clone) -> impl Strategy<Value = Vector2<f64>> {
    (s.clone(), s).prop_map(|(a, b)| Vector2::new(a, b))
}

fn sample2() -> impl Strategy<Value = RobotSample<2>> {
    (
        any::<u32>(),
        any::<u64>(),
        any::<u32>(),
        vec2(any_f64()),
        vec2(any_f64()),
        vec2(any_f64()),
        vec2(any_f64()),
    )
        .prop_map(|(seq, stamp_ns, flags, q, qd, force, effort)| RobotSample {
            seq,
            stamp_ns,
            flags,
            q,
            qd,
            force,
            effort,
        })
}

fn command2() -> impl Strategy<Value = RobotCommand<2>> {
    (
        any::<u32>(),
        any::<u64>(),
        any::<u32>(),
        any::<u16>(),
        any::<u8>(),
        any::<u32>(),
        any::<u32>(),
        vec2(-1e6..1e6f64),
    )
        .prop_map(
            |(seq, stamp_ns, answers, flags, status, iterations, compute_ns, torque)| {
                RobotCommand {
                    seq,
                    stamp_ns,
                    answers,
                    flags,
                    status,
                    iterations,
                    compute_ns,
                    torque,
                }
            },
        )
}

/// Bit-exact equality (NaN payloads included).
fn same_bits(a: &SVector<f64, 2>, b: &SVector<f64, 2>) -> bool {
    a.iter()
        .zip(b.iter())
        .all(|(x, y)| x.to_bits() == y.to_bits())
}

fn enc_sample(s: &RobotSample<2>) -> Vec<u8> {
    let mut v = Vec::new();
    encode_sample(s, &mut v);
    v
}

fn enc_command(c: &RobotCommand<2>) -> Vec<u8> {
    let mut v = Vec::new();
    encode_command(c, &mut v);
    v
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(512))]

    #[test]
    fn sample_round_trips_bit_exactly(s in sample2()) {
        let bytes = enc_sample(&s);
        prop_assert_eq!(bytes.len(), sample_len(2));
        match decode::<2>(&bytes) {
            Ok(Frame::Sample(d)) => {
                prop_assert_eq!((d.seq, d.stamp_ns, d.flags), (s.seq, s.stamp_ns, s.flags));
                prop_assert!(same_bits(&d.q, &s.q) && same_bits(&d.qd, &s.qd));
                prop_assert!(same_bits(&d.force, &s.force) && same_bits(&d.effort, &s.effort));
            }
            other => prop_assert!(false, "decoded {:?}", other),
        }
    }

    #[test]
    fn command_round_trips(c in command2()) {
        let bytes = enc_command(&c);
        prop_assert_eq!(bytes.len(), command_len(2));
        prop_assert_eq!(decode::<2>(&bytes), Ok(Frame::Command(c)));
    }

    /// Arbitrary bytes: never a panic; whatever is accepted re-encodes to the same bytes.
    #[test]
    fn arbitrary_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..200)) {
        match decode::<2>(&bytes) {
            Ok(Frame::Sample(s)) => prop_assert_eq!(enc_sample(&s), bytes.clone()),
            Ok(Frame::Command(c)) => prop_assert_eq!(enc_command(&c), bytes.clone()),
            Err(_) => {}
        }
        let _ = decode::<1>(&bytes);
    }

    /// A valid frame with its header made plausible but the rest random: the CRC catches it.
    #[test]
    fn corrupted_byte_is_rejected(c in command2(), at in 0usize..command_len(2), x in 1u8..=255) {
        let mut bytes = enc_command(&c);
        bytes[at] ^= x;
        prop_assert!(decode::<2>(&bytes).is_err(), "corruption at {} accepted", at);
    }

    #[test]
    fn every_truncation_is_rejected_as_truncated(s in sample2(), cut in 0usize..sample_len(2)) {
        let bytes = enc_sample(&s);
        let r = decode::<2>(&bytes[..cut]);
        prop_assert!(matches!(r, Err(FrameError::Truncated { .. })), "{:?}", r);
    }

    /// Sequence numbers: newer (by less than 2³¹, across the wrap) accepted and gaps counted;
    /// equal is a duplicate; older is out of order.
    #[test]
    fn seq_tracker_orders_across_wrap(start in any::<u32>(), step in 1u32..1000) {
        let mut t = SeqTracker::default();
        prop_assert_eq!(t.accept(start), Ok(()));
        prop_assert_eq!(t.accept(start), Err(FrameError::Duplicate));
        prop_assert_eq!(t.accept(start.wrapping_add(step)), Ok(()));
        prop_assert_eq!(t.gaps, u64::from(step - 1));
        prop_assert_eq!(t.accept(start), Err(FrameError::OutOfOrder));
        prop_assert_eq!(t.last(), Some(start.wrapping_add(step)));
    }
}

#[test]
fn each_defect_has_its_reason() {
    let c = RobotCommand::<2> {
        seq: 7,
        stamp_ns: 1,
        answers: 3,
        flags: 0,
        status: 0,
        iterations: 2,
        compute_ns: 40_000,
        torque: Vector2::new(1.0, -2.0),
    };
    let good = enc_command(&c);
    let with = |f: &dyn Fn(&mut Vec<u8>)| {
        let mut b = good.clone();
        f(&mut b);
        decode::<2>(&b)
    };
    assert_eq!(with(&|b| b[0] = b'X'), Err(FrameError::BadMagic));
    assert_eq!(with(&|b| b[4] = 2), Err(FrameError::WrongVersion(2)));
    assert_eq!(with(&|b| b[5] = 9), Err(FrameError::UnknownKind(9)));
    assert_eq!(
        with(&|b| b[6] = 1),
        Err(FrameError::WrongJoints {
            got: 1,
            expected: 2
        })
    );
    assert_eq!(with(&|b| b[7] = 1), Err(FrameError::Malformed));
    assert_eq!(with(&|b| b[20] = 99), Err(FrameError::Malformed));
    assert_eq!(with(&|b| b.push(0)), Err(FrameError::Malformed));
    assert_eq!(with(&|b| b[30] ^= 1), Err(FrameError::BadCrc));
    assert_eq!(
        decode::<1>(&good),
        Err(FrameError::WrongJoints {
            got: 2,
            expected: 1
        })
    );
    let nan = RobotCommand {
        torque: Vector2::new(f64::NAN, 0.0),
        ..c
    };
    assert_eq!(decode::<2>(&enc_command(&nan)), Err(FrameError::NonFinite));
    // Counting: every reason lands in its own counter.
    let mut counts = RejectCounts::default();
    for e in [
        FrameError::BadMagic,
        FrameError::BadCrc,
        FrameError::BadCrc,
        FrameError::Stale,
    ] {
        counts.count(e);
    }
    assert_eq!((counts.bad_magic, counts.bad_crc, counts.stale), (1, 2, 1));
    assert_eq!(counts.total(), 4);
}

#[test]
fn status_codes_round_trip() {
    for s in [
        StepStatus::Ok,
        StepStatus::MaxIterations,
        StepStatus::MaxTime,
        StepStatus::SolverFailed,
        StepStatus::BadMeasurement,
        StepStatus::MonitorTripped,
    ] {
        assert_eq!(status_from_code(status_code(s)), Some(s));
    }
    assert_eq!(status_from_code(200), None);
}

// ---------------------------------------------------------------------------------------------
// The loop against the virtual robot, in-process.

type Robot = VirtualRobot<2, <TwoDof as Dof<2>>::Traj>;

fn robot(s: &Scenario, watchdog: u64) -> Robot {
    let plant = Plant::new(plant_params::<TwoDof, 2>(s), TwoDof::trajectory(s));
    let sensors = Sensors::new(uncertainty(s), s.uncertainty.filter_window).with_faults(&s.faults);
    VirtualRobot::new(plant, sensors, limits(s), s.timing.dt, watchdog)
}

/// A test clock shared by the loop and the robot (time moves only when someone waits).
#[derive(Clone, Default)]
struct SharedClock(Rc<Cell<Duration>>);

impl Clock for SharedClock {
    fn now(&self) -> Duration {
        self.0.get()
    }
    fn sleep_until(&mut self, t: Duration) {
        self.0.set(self.0.get().max(t));
    }
}

/// The virtual robot wired directly to the loop: `read` advances the robot over the previous
/// period (with whatever command arrived) and returns its next sample, at its timestamp on the
/// shared clock (zero transit time); samples of the periods in `drop_samples` and commands
/// answering `drop_commands` are lost.
struct Direct {
    clock: SharedClock,
    vr: Robot,
    started: bool,
    steps: Vec<RobotStep<2>>,
    drop_samples: Vec<u64>,
    drop_commands: Vec<u32>,
    /// Samples arriving 3 ms after their timestamp.
    late_samples: Vec<u64>,
    stats: LinkStats,
}

impl Direct {
    fn new(vr: Robot) -> Self {
        Direct {
            clock: SharedClock::default(),
            vr,
            started: false,
            steps: Vec::new(),
            drop_samples: Vec::new(),
            drop_commands: Vec::new(),
            late_samples: Vec::new(),
            stats: LinkStats::default(),
        }
    }
}

impl RobotInterface<2> for Direct {
    fn read(&mut self, _timeout: Duration) -> std::io::Result<Option<RobotSample<2>>> {
        if self.started {
            self.steps.push(self.vr.advance());
        }
        self.started = true;
        let s = self.vr.sample();
        let mut at = Duration::from_nanos(s.stamp_ns);
        if self.late_samples.contains(&u64::from(s.seq)) {
            at += Duration::from_millis(3);
        }
        self.clock.sleep_until(at);
        if self.drop_samples.contains(&u64::from(s.seq)) {
            return Ok(None);
        }
        self.stats.accepted += 1;
        Ok(Some(s))
    }

    fn write(&mut self, cmd: &RobotCommand<2>) -> std::io::Result<()> {
        self.stats.sent += 1;
        if self.started && !self.drop_commands.contains(&cmd.answers) {
            if let Err(e) = self.vr.command(cmd) {
                self.stats.rejected.count(e);
            }
        }
        Ok(())
    }

    fn link_stats(&self) -> LinkStats {
        self.stats
    }
}

fn scenario(duration: f64) -> Scenario {
    let mut s = Scenario::default();
    s.uncertainty.payload_kg = 2.0;
    s.timing.duration_2dof_s = duration;
    s.validate().unwrap();
    s
}

type Loop = ControlLoop<2, exompc::control::Supervisor<2, Box<dyn Controller<2>>>>;

fn control_loop(s: &Scenario) -> Loop {
    let sup = build_supervised::<TwoDof, 2>(s, s.controller.kind).unwrap();
    let settings = LoopSettings::new(
        Duration::from_secs_f64(s.timing.dt),
        s.uncertainty.filter_window,
        limits(s),
    );
    ControlLoop::new(sup, settings, 1024)
}

/// Run `periods` periods; returns the link (holding the robot's steps) and the loop.
fn run(
    s: &Scenario,
    periods: usize,
    link: Direct,
) -> (Direct, Loop, Vec<exompc::runtime::PeriodRecord<2>>) {
    let mut lp = control_loop(s);
    let mut link = link;
    let mut clock = link.clock.clone();
    assert!(lp
        .connect(
            &mut link,
            &mut clock,
            Duration::from_secs(1),
            Duration::from_millis(100)
        )
        .unwrap());
    let mut recs = Vec::new();
    for _ in 0..periods {
        recs.push(lp.period(&mut link, &mut clock).unwrap());
    }
    // Apply the last command.
    link.steps.push(link.vr.advance());
    (link, lp, recs)
}

/// Oracle: with no losses, the loop over the robot interface is the offline closed loop of
/// `simulate` (same plant, sensors, filter, supervised controller): identical true forces
/// and torques at every step.
#[test]
fn loop_with_virtual_robot_reproduces_simulate() {
    let s = scenario(1.5);
    let steps = s.control_steps(2);
    let mut log = TraceLog::<2>::default();
    let summary = run_experiment::<TwoDof, 2>(&s, &mut [&mut log]).unwrap();
    let (link, lp, recs) = run(&s, steps, Direct::new(robot(&s, 2)));
    assert_eq!(link.steps.len(), steps);
    for (k, (a, b)) in log.rows.iter().zip(&link.steps).enumerate() {
        assert!(
            (a.force_true - b.force_true).amax() < 1e-9,
            "step {k}: force {:?} vs {:?}",
            a.force_true,
            b.force_true
        );
        assert!(
            (a.torque_robot - b.torque).amax() < 1e-9,
            "step {k}: torque"
        );
    }
    assert!(recs.iter().all(|r| r.sent && r.within_limits));
    let st = lp.stats();
    assert_eq!(st.missing_samples, 0);
    assert_eq!(st.effort_resyncs, 0);
    assert_eq!(st.limit_violations, 0);
    assert_eq!(link.vr.stats().commanded as usize, steps);
    assert_eq!(link.vr.stats().watchdog_trips, 0);
    assert!(summary.rms_force_n.shank.unwrap() > 0.0);
    // The test clock never sleeps past a deadline: zero period error.
    assert_eq!(lp.timing().summary().period_error_us.max, 0.0);
    assert_eq!(lp.timing().deadline_misses, 0);
}

/// A lost sample: the loop sends nothing, the supervisor holds the torque (bad measurement),
/// the robot holds the last command for that period; the next sample resumes normally.
#[test]
fn missing_sample_holds_torque_and_is_counted() {
    let s = scenario(1.0);
    let mut link = Direct::new(robot(&s, 2));
    link.drop_samples = vec![20];
    let (link, lp, recs) = run(&s, 40, link);
    let r = recs.iter().find(|r| r.sample.is_none()).unwrap();
    assert!(!r.sent);
    assert_eq!(r.output.status, StepStatus::BadMeasurement);
    assert_eq!(r.output.torque, r.torque_prev);
    assert_eq!(lp.stats().missing_samples, 1);
    assert_eq!(link.vr.stats().held, 1);
    assert_eq!(link.vr.stats().watchdog_trips, 0);
    // The robot held the command of period 19 in period 20: same torque as the loop held.
    assert_eq!(link.steps[20].torque, link.steps[19].torque);
    assert!(recs.iter().all(|r| r.within_limits));
}

/// Commands lost for 3 periods: the robot holds one period, zeroes the torque from the second
/// (watchdog flag in its samples), and resumes when commands return; the loop resumes from the
/// applied (zero) torque within the rate limit.
#[test]
fn watchdog_zeroes_after_two_periods_and_resumes() {
    let s = scenario(1.0);
    let mut link = Direct::new(robot(&s, 2));
    link.drop_commands = vec![30, 31, 32];
    let (link, lp, recs) = run(&s, 50, link);
    let st = &link.steps;
    assert!(st[30].command.is_none() && !st[30].watchdog);
    assert_eq!(st[30].torque, st[29].torque, "first missing period holds");
    assert!(st[31].watchdog && st[32].watchdog);
    assert_eq!(st[31].torque, Vector2::zeros());
    assert_eq!(st[32].torque, Vector2::zeros());
    assert!(st[33].command.is_some() && !st[33].watchdog, "resumes");
    assert!(st[33].within_limits);
    let lim = limits(&s);
    assert!(lim.admits(&st[32].torque, &st[33].torque));
    let vs = link.vr.stats();
    assert_eq!((vs.watchdog_trips, vs.watchdog_periods, vs.held), (1, 2, 1));
    let ev = link.vr.watchdog_events()[0];
    assert!((ev.tripped_at - 0.31).abs() < 1e-9);
    assert!((ev.last_command_at.unwrap() - 0.29).abs() < 1e-9);
    assert!((ev.resumed_at.unwrap() - 0.33).abs() < 1e-9);
    // The samples of periods 32 and 33 carried the watchdog flag; the loop saw and resynced.
    let flagged = recs
        .iter()
        .filter(|r| {
            r.sample
                .is_some_and(|x| x.flags & robot_flags::WATCHDOG != 0)
        })
        .count();
    assert_eq!(flagged, 2);
    assert_eq!(lp.stats().robot_watchdog_samples, 2);
    assert!(lp.stats().effort_resyncs >= 2);
    assert_eq!(lp.stats().limit_violations, 0);
    assert_eq!(link.vr.stats().limit_violations, 0);
}

/// Clock sync: a sample arriving late (a robot or network stall) is used, counted as late,
/// and does not shift the loop's phase: the following deadlines stay `lead` before the
/// robot's sending instants, so every later sample is answered in its own period.
#[test]
fn late_sample_does_not_shift_the_phase() {
    let s = scenario(1.0);
    let mut link = Direct::new(robot(&s, 2));
    link.late_samples = vec![20, 21, 22];
    let (link, lp, recs) = run(&s, 40, link);
    assert_eq!(lp.stats().late_samples, 3);
    assert!(recs.iter().all(|r| r.sent && r.wake_error_us == 0.0));
    assert_eq!(link.vr.stats().commanded, 40);
    // Next deadline: the next sample's timestamp (period 40) minus the lead (2 ms).
    assert_eq!(lp.next_deadline(), Some(Duration::from_millis(398)));
}

/// Stop: the torque ramps to zero at the rate limit, then STOP tells the robot.
#[test]
fn stop_ramps_to_zero_and_tells_the_robot() {
    let s = scenario(1.0);
    let (mut link, mut lp, _) = run(&s, 30, Direct::new(robot(&s, 2)));
    let mut clock = link.clock.clone();
    lp.request_stop();
    let rate = limits(&s).rate;
    let mut n = 0;
    while !lp.ramp_done() {
        let r = lp.period(&mut link, &mut clock).unwrap();
        assert!(r.within_limits);
        assert!(r.output.torque.amax() <= r.torque_prev.amax());
        n += 1;
        assert!(n < 100, "ramp did not end");
    }
    let t0 = link.steps.last().unwrap().torque.amax();
    assert!(n as f64 <= (t0 / rate).ceil() + 1.0);
    assert!(!link.vr.stop_requested());
    lp.send_stop(&mut link, &clock, 1).unwrap();
    assert!(link.vr.stop_requested());
}

/// The robot rejects stale, duplicate and out-of-order commands, and a HELLO drives nothing.
#[test]
fn robot_rejects_stale_and_repeated_commands() {
    let s = scenario(1.0);
    let mut vr = robot(&s, 2);
    let cmd = |seq: u32, answers: u32, flags: u16| RobotCommand::<2> {
        seq,
        stamp_ns: 0,
        answers,
        flags,
        status: 0,
        iterations: 0,
        compute_ns: 0,
        torque: Vector2::new(1.0, 1.0),
    };
    assert_eq!(vr.command(&cmd(1, 0, command_flags::HELLO)), Ok(false));
    let _ = vr.sample();
    assert_eq!(vr.command(&cmd(2, 0, 0)), Ok(true));
    assert_eq!(vr.command(&cmd(2, 0, 0)), Err(FrameError::Duplicate));
    assert_eq!(vr.command(&cmd(1, 0, 0)), Err(FrameError::OutOfOrder));
    vr.advance();
    let _ = vr.sample();
    assert_eq!(vr.command(&cmd(3, 0, 0)), Err(FrameError::Stale));
    assert_eq!(vr.command(&cmd(4, 5, 0)), Err(FrameError::Malformed));
    assert!(!vr.has_current());
}

// ---------------------------------------------------------------------------------------------
// Network faults.

fn drain(f: &mut NetFaults, now: f64) -> Vec<Vec<u8>> {
    std::iter::from_fn(|| f.pop_due(now)).collect()
}

#[test]
fn no_faults_pass_everything_in_order() {
    let mut f = NetFaults::new(NetFaultSettings::default());
    for i in 0..100u8 {
        f.submit(f64::from(i) * 0.01, &[i]);
    }
    let out = drain(&mut f, 10.0);
    assert_eq!(out, (0..100u8).map(|i| vec![i]).collect::<Vec<_>>());
}

#[test]
fn loss_rate_and_disconnection() {
    let mut f = NetFaults::new(NetFaultSettings {
        loss: 0.05,
        disconnect_at_s: Some(10.0),
        disconnect_s: 1.0,
        seed: 3,
        ..Default::default()
    });
    for i in 0..6000u32 {
        f.submit(f64::from(i) * 0.01, &i.to_le_bytes());
    }
    let out = drain(&mut f, 1e9);
    let c = *f.counts();
    assert_eq!(c.disconnected, 100);
    assert_eq!(out.len() as u64, 6000 - 100 - c.lost);
    // 5 % of 5900 = 295, binomial sd ≈ 17.
    assert!((220..370).contains(&c.lost), "lost {}", c.lost);
    for b in &out {
        let i = u32::from_le_bytes([b[0], b[1], b[2], b[3]]);
        assert!(
            !(1000..1100).contains(&i),
            "frame {i} passed the disconnection"
        );
    }
}

#[test]
fn duplication_reordering_and_delay_spikes() {
    let mut f = NetFaults::new(NetFaultSettings {
        duplicate: 1.0,
        ..Default::default()
    });
    f.submit(0.0, &[1]);
    assert_eq!(drain(&mut f, 0.0), vec![vec![1], vec![1]]);

    let mut f = NetFaults::new(NetFaultSettings {
        reorder: 1.0,
        ..Default::default()
    });
    f.submit(0.0, &[1]);
    assert!(drain(&mut f, 0.0).is_empty(), "held back");
    f.submit(0.01, &[2]);
    assert_eq!(drain(&mut f, 0.01), vec![vec![2], vec![1]]);

    let mut f = NetFaults::new(NetFaultSettings {
        delay_s: 0.02,
        delay_every_s: 1.0,
        delay_width_s: 0.05,
        ..Default::default()
    });
    f.submit(0.5, &[1]);
    f.submit(1.01, &[2]);
    assert_eq!(drain(&mut f, 1.02), vec![vec![1]]);
    assert_eq!(f.next_due(), Some(1.03));
    assert_eq!(drain(&mut f, 1.03), vec![vec![2]]);
    assert_eq!(f.counts().delayed, 1);
}

#[test]
fn fault_draws_are_deterministic_per_seed() {
    let run = |seed| {
        let mut f = NetFaults::new(NetFaultSettings {
            loss: 0.2,
            duplicate: 0.1,
            reorder: 0.1,
            seed,
            ..Default::default()
        });
        for i in 0..500u32 {
            f.submit(f64::from(i) * 0.01, &i.to_le_bytes());
        }
        drain(&mut f, 1e9)
    };
    assert_eq!(run(7), run(7));
    assert_ne!(run(7), run(8));
}

#[test]
fn fault_settings_are_validated() {
    let bad = NetFaultSettings {
        loss: 1.5,
        ..Default::default()
    };
    assert!(bad.validate().unwrap_err().contains("loss"));
    let bad = NetFaultSettings {
        delay_s: -1.0,
        ..Default::default()
    };
    assert!(bad.validate().unwrap_err().contains("delay"));
    assert!(NetFaultSettings::default().validate().is_ok());
    assert!(NetFaultSettings::default().is_none());
}
