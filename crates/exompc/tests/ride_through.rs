//! Riding through sensor faults (issue 28; control/ride_through.rs, docs/RELIABILITY.md §2):
//! the detectors fire on no clean sample, each fault kind is flagged within its stated delay,
//! a fault of one channel group for 200 ms leaves the person's true strap force near the clean
//! run's, the controller is back within 100 ms of the channel being good, handovers during a
//! sensor fault do not latch, a loss of every sensor is ridden through on the replayed torque,
//! and a persistent fault ends in the protective stop.

use exompc::config::{ControllerKind, Experiment};
use exompc::control::{
    ChannelGuard, EstimatedChannels, Measurement, MonitorAction, MonitorKind, Repaired, StepStatus,
    TorqueExtrapolation, EXTRAPOLATION_FADE_STEPS, EXTRAPOLATION_MAX_HZ, FORCE_BIAS_RATE,
    FORCE_FIT_S, FORCE_RANGE_MARGIN, FORCE_REPLAY_WEIGHT, FORCE_RESYNC_S, GAIT_MAX_HZ,
    SLOPE_ACCEPT_GATES, UNVERIFIED_S, VELOCITY_GATE,
};
use exompc::estimate::MovingAverage;
use exompc::model::Straps;
use exompc::scenario::{cell_scenario, peak_goal_n, run_experiment_report, ChannelGroup, TwoDof};
use exompc::sim::{Channel, FaultEvent, FaultKind, TraceLog};
use exompc::Controller;
use nalgebra::SVector;

fn scenario(kind: ControllerKind, payload: f64, seconds: f64) -> Experiment {
    let mut s = Experiment::default();
    s.controller.kind = kind;
    s.uncertainty.payload_kg = payload;
    s.timing.duration_2dof_s = seconds;
    s
}

fn fault(kind: FaultKind, channels: &[Channel], start: f64, dur: f64, mag: f64) -> Vec<FaultEvent> {
    channels
        .iter()
        .map(|&channel| FaultEvent {
            kind,
            channel,
            start_s: start,
            duration_s: dur,
            magnitude: mag,
        })
        .collect()
}

/// (peak |true strap force| (N), RMS per strap (N), safety report, trace).
fn run(s: &Experiment) -> (f64, [f64; 2], exompc::control::SafetyReport, TraceLog<2>) {
    let mut log = TraceLog::default();
    let (sum, rep) = run_experiment_report::<TwoDof, 2>(s, &mut [&mut log]).unwrap();
    assert_eq!(sum.limit_violations, 0);
    let peak = log
        .rows
        .iter()
        .flat_map(|r| r.force_true.iter().map(|f| f.abs()).collect::<Vec<_>>())
        .fold(0.0, f64::max);
    let rms = [
        sum.rms_force_n.thigh.unwrap(),
        sum.rms_force_n.shank.unwrap(),
    ];
    (peak, rms, rep, log)
}

const ANGLES: [Channel; 2] = [Channel::Q1, Channel::Q2];
const VELOCITIES: [Channel; 2] = [Channel::Qd1, Channel::Qd2];

/// The detectors never fire on the clean default runs (pd, nmpc, msnmpc; 0 and 3 kg): no
/// channel rejected, so the runs are those of the unsupervised controller bit for bit (the
/// golden tests pin that).
#[test]
fn clean_runs_reject_no_channel() {
    for kind in [
        ControllerKind::PD,
        ControllerKind::NMPC,
        ControllerKind::MSNMPC,
    ] {
        for payload in [0.0, 3.0] {
            let (_, _, rep, _) = run(&scenario(kind, payload, 6.0));
            assert_eq!(
                (
                    rep.sensor_faults,
                    rep.estimated_steps,
                    rep.bad_measurement_steps
                ),
                (0, 0, 0),
                "{kind:?} {payload} kg"
            );
            assert_eq!(
                rep.monitor_trips, 0,
                "{kind:?} {payload} kg: {:?}",
                rep.events
            );
        }
    }
}

/// Issue 28 goal for one channel group: a 200-ms fault of the angles (a 0.5-rad encoder
/// spike; main: 136 N peak, RMS 11.5× at 2 kg) or of the velocities (NaN; main: 66 N, 2.7×)
/// at 2 kg keeps the peak true strap force within 6 N of the clean run's (msnmpc: ≤ 12 N, twice
/// the clean peak; nmpc, whose clean peak at 2 kg is 27.5 N, within the same margin) and the
/// RMS ≤ 1.5× the clean run's, without a monitor trip or a latch, for msnmpc (its EKF bank
/// updates on the measured rows) and nmpc (the supervisor's own estimates).
#[test]
fn a_200_ms_fault_of_one_channel_group_is_ridden_through() {
    let cases = [
        (ControllerKind::MSNMPC, FaultKind::Spike, &ANGLES, 0.5),
        (ControllerKind::MSNMPC, FaultKind::Nan, &VELOCITIES, 0.0),
        (ControllerKind::NMPC, FaultKind::Stuck, &ANGLES, 0.0),
        (ControllerKind::NMPC, FaultKind::Nan, &VELOCITIES, 0.0),
    ];
    for (kind, fk, chans, mag) in cases {
        let clean = scenario(kind, 2.0, 6.0);
        let mut faulty = clean.clone();
        faulty.faults.events = fault(fk, chans, 3.0, 0.2, mag);
        let (peak0, rms0, _, _) = run(&clean);
        let (peak, rms, rep, log) = run(&faulty);
        let what = format!("{kind:?} {fk:?} {chans:?}");
        assert!(
            peak <= peak0 + 6.0,
            "{what}: peak {peak:.1} N, clean {peak0:.1} N"
        );
        if kind == ControllerKind::MSNMPC {
            assert!(peak <= 12.0, "{what}: peak {peak:.1} N");
        }
        for i in 0..2 {
            assert!(rms[i] <= 1.5 * rms0[i], "{what}: RMS {rms:?} vs {rms0:?}");
        }
        assert!(rep.sensor_faults > 0, "{what}: nothing detected");
        assert_eq!(rep.monitor_trips, 0, "{what}: {:?}", rep.events);
        assert_eq!(rep.latched_at, None);
        // The full controller is back within 100 ms of the channel being good (a NaN on a
        // velocity stays in its 5-sample filter for 40 ms after the fault).
        let back = 3.2 + 0.04 + 0.1;
        for r in log.rows.iter().filter(|r| r.t > back + 1e-9) {
            assert!(
                !matches!(
                    r.status,
                    StepStatus::BadMeasurement | StepStatus::MonitorTripped
                ),
                "{what}: {:?} at {} s",
                r.status,
                r.t
            );
        }
    }
}

/// A stuck or dropped-out velocity ends: its filtered value moves again while its window
/// still averages frozen samples for `filter_window − 1` more, and it is not accepted back
/// until they are gone. 60-ms stuck velocities (both joints) at 1.5 s, 0 kg, and dropouts at
/// 5.5 s, 1 kg (cells of the fine phase scan, docs/RELIABILITY.md §2a): peak ≤ 12 N, RMS ≤
/// 1.5× clean, no monitor trip. Accepted on the ramp back, the velocity between the frozen and
/// the true one made the controller swing (here 77.6 N at 1.5 s; in the scan's 10-s runs 70.1
/// and 60.2 N).
#[test]
fn a_velocity_that_moves_again_is_accepted_once_its_window_is_clean() {
    for (fk, payload, start) in [(FaultKind::Stuck, 0.0, 1.5), (FaultKind::Dropout, 1.0, 5.5)] {
        let clean = scenario(ControllerKind::MSNMPC, payload, start + 1.0);
        let mut faulty = clean.clone();
        faulty.faults.events = fault(fk, &VELOCITIES, start, 0.06, 0.0);
        let (_, rms0, _, _) = run(&clean);
        let (peak, rms, rep, _) = run(&faulty);
        let what = format!("{fk:?} at {start} s, {payload} kg");
        assert!(rep.sensor_faults > 0, "{what}: nothing detected");
        assert!(peak <= 12.0, "{what}: peak {peak:.1} N");
        for i in 0..2 {
            assert!(rms[i] <= 1.5 * rms0[i], "{what}: RMS {rms:?} vs {rms0:?}");
        }
        assert_eq!(rep.monitor_trips, 0, "{what}: {:?}", rep.events);
    }
}

/// A channel rejected for longer than `sensor_timeout_s` (0.5 s) ends in the protective
/// stop: the torque ramps to zero within the rate limit and stays there while the fault
/// lasts; when the channel is good again the controller takes over within 0.2 s (no latch;
/// the handover after the stop may trip a monitor). At 0 kg; at 2 kg the person carries robot
/// and payload during the stop (strap forces near 40 N; docs/RELIABILITY.md §2; the next test
/// bounds the return).
#[test]
fn a_persistent_fault_ends_in_the_protective_stop_and_recovers() {
    let mut s = scenario(ControllerKind::MSNMPC, 0.0, 6.0);
    s.faults.events = fault(FaultKind::Nan, &ANGLES, 2.0, 1.5, 0.0);
    let rate = s.rate_limit_per_step();
    let (_, _, rep, log) = run(&s);
    let trip = rep
        .events
        .iter()
        .find(|e| e.monitor == MonitorKind::SensorTimeout && e.action == MonitorAction::Trip)
        .expect("no protective stop");
    assert!((trip.t - 2.5).abs() < 0.02, "stop at {} s", trip.t);
    let mut prev: Option<SVector<f64, 2>> = None;
    for r in &log.rows {
        if let Some(p) = prev {
            assert!(
                (r.torque_robot - p).amax() <= rate + 1e-9,
                "step at {} s",
                r.t
            );
        }
        prev = Some(r.torque_robot);
        // Zero once the ramp (at most 30 N·m at the rate limit) is done, until the fault ends.
        if r.t > trip.t + 0.35 && r.t < 3.5 {
            assert_eq!(r.torque_robot, SVector::<f64, 2>::zeros(), "at {} s", r.t);
        }
    }
    assert_eq!(rep.latched_at, None);
    // The stop clears 0.1 s after the angles are good again (3.5 s): the controller steps.
    let back = log
        .rows
        .iter()
        .find(|r| r.t > 3.5 && r.status == StepStatus::Ok)
        .map(|r| r.t);
    assert!(back.is_some_and(|t| t < 3.7), "back at {back:?}");
}

/// Back from the protective stop at 3 kg (a 1.5-s NaN on both angles from 2 s, 6-s msnmpc
/// run; the stop from 2.5 s): the torque goes back to the controller's over
/// `STOP_HANDBACK_STEPS` (0.2 s), and the controller's return trips no oscillation monitor
/// (over 0.1 s the torque-oscillation monitor tripped at 3.93 s and the monitors held the
/// torque on 317 of 600 steps; measured on 2026-12-06).
#[test]
fn the_return_from_a_protective_stop_at_3_kg_does_not_oscillate() {
    let mut s = scenario(ControllerKind::MSNMPC, 3.0, 6.0);
    s.faults.events = fault(FaultKind::Nan, &ANGLES, 2.0, 1.5, 0.0);
    let (peak, _, rep, _) = run(&s);
    let trips = |kind: MonitorKind| {
        (rep.events.iter())
            .filter(|e| e.monitor == kind && e.action == MonitorAction::Trip)
            .count()
    };
    assert_eq!(trips(MonitorKind::SensorTimeout), 1, "{:?}", rep.events);
    assert_eq!(trips(MonitorKind::TorqueOscillation), 0, "{:?}", rep.events);
    assert_eq!(trips(MonitorKind::ForceOscillation), 0, "{:?}", rep.events);
    assert!(peak <= 70.0, "peak {peak:.1} N");
    assert_eq!(rep.latched_at, None);
}

/// Issue 28, a fault of 1 s at 3 kg: every sensor's spike (0.5 rad, 0.5 rad/s, 30 N) from 1 s
/// (a cell of the 1-s scan; 6-s run) stays within 70 N without a latch. With the torque handed
/// back from the protective stop over 0.1 s the fallback that took it after the first stop
/// was judged failed, a second stop followed, and the controller's return from it swung the
/// hip's torque from −30 to +26 N·m: the torque-oscillation monitor's handover was the
/// second, and the supervisor latched (at 4.90 s in this run, 4.87 s in the scan's 10-s run;
/// measured on 2026-12-06).
#[test]
fn every_sensor_spiked_for_a_second_at_3_kg_does_not_latch() {
    every_sensor_spiked_for_a_second_from_1_s(3.0, 6.0);
}

/// Every sensor's 1-s spike from 1 s at `payload_kg` (a `seconds`-long run, msnmpc): the
/// monitors hand over, the true strap forces stay within 70 N, no latch.
fn every_sensor_spiked_for_a_second_from_1_s(payload_kg: f64, seconds: f64) {
    let fault = (FaultKind::Spike, ChannelGroup::All, 1.0, 1.0);
    let s = cell_scenario(&Experiment::default(), seconds, payload_kg, Some(fault));
    let (peak, _, rep, _) = run(&s);
    assert!(rep.monitor_trips > 0, "the monitors never handed over");
    assert!(peak <= 70.0, "peak {peak:.1} N");
    assert_eq!(rep.latched_at, None, "{:?}", rep.events);
}

/// Issue 28, a fault beyond 1 s at 3 kg: every sensor's spike (0.5 rad, 0.5 rad/s, 30 N) for
/// 1.5 s from 2 s (10-s msnmpc run; the spike ends at 3.5 s). When the tracking-error monitor
/// trips at 4.16 s, the encoder channel believed on smoothness alone within `UNVERIFIED_S`
/// before it (after the spike; the rule cannot tell an offset from a true reading) is rejected
/// again (`ChannelGuard::revoke_unverified`; a `revoke` event), its fault continues past the
/// persistent-fault limit, and the protective stop follows at once: peak true strap force
/// 72.0 N, no latch. With the rejection again skipped (a build with the call removed, same
/// day): 110.5 N. Measured on 2026-12-06.
#[test]
fn the_controller_failing_on_an_offset_angle_rejects_it_again() {
    let fault = (FaultKind::Spike, ChannelGroup::All, 2.0, 1.5);
    let s = cell_scenario(&Experiment::default(), 10.0, 3.0, Some(fault));
    let (peak, _, rep, _) = run(&s);
    let revoke = (rep.events.iter())
        .find(|e| e.action == MonitorAction::Revoke)
        .unwrap_or_else(|| panic!("no channel rejected again: {:?}", rep.events));
    assert!(revoke.value >= 1.0, "{revoke:?}");
    assert!((3.5..4.5).contains(&revoke.t), "{revoke:?}");
    let stop = (rep.events.iter())
        .find(|e| e.monitor == MonitorKind::SensorTimeout && e.action == MonitorAction::Trip)
        .map(|e| e.t);
    assert!(
        stop.is_some_and(|t| t >= revoke.t && t <= revoke.t + 0.05),
        "the stop at {stop:?}, the revocation at {:.2} s",
        revoke.t
    );
    assert!(peak <= 80.0, "peak {peak:.1} N");
    assert_eq!(rep.latched_at, None, "{:?}", rep.events);
}

/// `ChannelGuard::revoke_unverified`: a 0.5-rad offset on one angle from step 300 is believed
/// on smoothness alone after `resync_after` (20 steps) and stays revocable for `UNVERIFIED_S`
/// (a second guard, never revoked, checks both ends of that window). Rejected again 5 steps
/// after its acceptance, its fault continues (past `resync_after`, where the persistent-fault
/// limit counts), it stays rejected for another `resync_after` steps, and its next acceptance
/// (its estimate was built on the offset samples) is unverified again. With nothing believed
/// on smoothness alone nothing is rejected again.
#[test]
fn an_angle_believed_on_smoothness_alone_is_rejected_again_on_request() {
    let resync = 20;
    let dt = 0.01;
    let window = (UNVERIFIED_S / dt).ceil() as usize;
    let mut g = Gait::new();
    let mut guard = gait_guard();
    let mut never_revoked = gait_guard();
    let (mut accepted, mut revoked_at, mut back) = (None, None, None);
    let mut window_checked = [false; 2];
    let mut reaccepted_checked = false;
    for k in 0..420 {
        let mut raw = g.raw(k);
        if k >= 300 {
            raw.0[0] += 0.5;
        }
        let m = g.measure(k, raw);
        let rep = guard.repair(&m, None, resync, None);
        never_revoked.repair(&m, None, resync, None);
        if k == 250 {
            assert_eq!(
                guard.revoke_unverified(resync),
                0,
                "nothing believed on smoothness"
            );
        }
        let rejected = guard.is_rejected(0, 0);
        if accepted.is_none() && k > 300 && !rejected {
            accepted = Some(k);
        }
        let Some(a) = accepted else { continue };
        // The unverified window, on the guard never rejected again.
        if k == a + window - 1 {
            assert_eq!(
                never_revoked.clone().revoke_unverified(resync),
                1,
                "step {k}"
            );
            window_checked[0] = true;
        }
        if k == a + window {
            assert_eq!(
                never_revoked.clone().revoke_unverified(resync),
                0,
                "step {k}"
            );
            window_checked[1] = true;
        }
        match (revoked_at, back) {
            (None, _) if k == a + 5 => {
                assert_eq!(guard.revoke_unverified(resync), 1, "step {k}");
                assert!(guard.is_rejected(0, 0), "step {k}");
                revoked_at = Some(k);
            }
            (Some(r), None) if k > r => {
                if k == r + 1 {
                    assert!(
                        rep.longest_fault_s > resync as f64 * dt,
                        "the fault restarted: {} s",
                        rep.longest_fault_s
                    );
                }
                if k < r + resync as usize {
                    assert!(rejected, "accepted again at step {k}, {} after", k - r);
                } else if !rejected {
                    back = Some(k);
                    assert_eq!(guard.clone().revoke_unverified(resync), 1, "step {k}");
                    reaccepted_checked = true;
                }
            }
            _ => {}
        }
    }
    let a = accepted.expect("the offset angle was never believed");
    assert!(a >= 300 + resync as usize, "believed at step {a}");
    let (r, b) = (revoked_at.unwrap(), back.expect("never believed again"));
    assert!(b <= r + resync as usize + 5, "believed again at step {b}");
    assert_eq!(window_checked, [true; 2]);
    assert!(reaccepted_checked);
}

/// Back from the protective stop at 2 kg (the same 1.5-s NaN on both angles): during the stop
/// the robot hung on the person (strap forces near 40 N), and the torque goes back to the
/// controller's over `STOP_HANDBACK_STEPS`. The strap forces then follow the robot's own fast
/// motion; the force gate judges them less the robot's part (`ChannelGuard::with_straps`), so
/// they stay measured and the true strap forces over the 0.3 s after the controller is back
/// stay under 70 N (the issue's bound for faults of up to 1 s; 40.0 N on 2026-12-05, 56.6 N
/// with the torque handed back at once). Before the robot's part, the gate rejected them as
/// spikes, and the controller, stepping on their estimates, drove the knee 0.6 rad past the
/// leg: 127 N.
#[test]
fn the_controller_resumes_after_a_protective_stop_on_measured_forces() {
    let mut s = scenario(ControllerKind::MSNMPC, 2.0, 4.5);
    s.faults.events = fault(FaultKind::Nan, &ANGLES, 2.0, 1.5, 0.0);
    let (_, _, _, log) = run(&s);
    let back = log
        .rows
        .iter()
        .find(|r| r.t > 3.5 && r.status == StepStatus::Ok)
        .map(|r| r.t)
        .expect("the controller is not back after the stop");
    let peak = log
        .rows
        .iter()
        .filter(|r| r.t >= back && r.t <= back + 0.3)
        .map(|r| r.force_true.amax())
        .fold(0.0, f64::max);
    assert!(
        peak < 70.0,
        "peak {peak:.1} N in the 0.3 s after the controller was back at {back:.2} s"
    );
}

/// A sine gait through the sensors' 5-sample filter: `(q, filtered qd, filtered F)` at step k.
struct Gait {
    dt: f64,
    qd_f: MovingAverage<2>,
    f_f: MovingAverage<2>,
}

/// The guard of the unit tests: 10-ms periods, a 5-sample filter window, the default ranges
/// (π rad, 30 rad/s, 70 N).
fn gait_guard() -> ChannelGuard<2> {
    ChannelGuard::new(0.01, 5, [std::f64::consts::PI, 30.0, 70.0])
}

impl Gait {
    fn new() -> Self {
        Gait {
            dt: 0.01,
            qd_f: MovingAverage::new(5),
            f_f: MovingAverage::new(5),
        }
    }
    /// The clean raw sample at step k.
    fn raw(&self, k: usize) -> (SVector<f64, 2>, SVector<f64, 2>, SVector<f64, 2>) {
        self.raw_at(k as f64 * self.dt)
    }
    /// The clean raw sample at time t (s).
    fn raw_at(&self, t: f64) -> (SVector<f64, 2>, SVector<f64, 2>, SVector<f64, 2>) {
        let w = 2.0 * std::f64::consts::PI;
        let q = SVector::from([0.4 * (w * t).sin(), -0.6 + 0.5 * (w * t + 1.0).sin()]);
        let qd = SVector::from([0.4 * w * (w * t).cos(), 0.5 * w * (w * t + 1.0).cos()]);
        let f = SVector::from([3.0 * (w * t + 0.3).sin(), 5.0 * (w * t + 0.7).sin()]);
        (q, qd, f)
    }
    fn measure(
        &mut self,
        k: usize,
        (q, qd, f): (SVector<f64, 2>, SVector<f64, 2>, SVector<f64, 2>),
    ) -> Measurement<2> {
        Measurement {
            t: k as f64 * self.dt,
            q,
            qd: self.qd_f.push(qd),
            force: self.f_f.push(f),
        }
    }
}

/// Steps from the fault's onset until `signal` of joint 1 is rejected, for a fault applied to
/// the raw sample from step 300 on by `corrupt`; `None` if it is never flagged in 20 steps.
fn delay(
    signal: usize,
    corrupt: impl Fn(&mut (SVector<f64, 2>, SVector<f64, 2>, SVector<f64, 2>), usize),
) -> Option<usize> {
    let mut g = Gait::new();
    let mut guard = gait_guard();
    for k in 0..320 {
        let mut raw = g.raw(k);
        if k >= 300 {
            corrupt(&mut raw, k);
        }
        let m = g.measure(k, raw);
        guard.repair(&m, Some(1.0), 50, None);
        if k < 300 {
            assert!(!guard.is_rejected(signal, 1), "false alarm at step {k}");
        } else if guard.is_rejected(signal, 1) {
            return Some(k - 300);
        }
    }
    None
}

/// A gap in the data (the runtime steps nothing in a period without a sample) while a channel
/// is rejected (no gait period known yet): the first sample after it, in range, is accepted on
/// every channel, and the estimate is ready. There is no warm history to compare it with;
/// before, a rejected channel waited for the resynchronisation (`resync_after` steps, `sensor_timeout_s`) while the
/// guard, its history restarted, stayed not ready, so the supervisor held the torque for
/// 0.5 s (the runtime's 20-ms delay spikes: 74.6 N, docs/REALTIME.md).
#[test]
fn a_gap_in_the_data_ends_a_rejection_without_waiting() {
    for (sig, spike) in [(0, 0.5), (1, 5.0), (2, 30.0)] {
        let mut g = Gait::new();
        let mut guard = gait_guard();
        for k in 0..303 {
            let mut raw = g.raw(k);
            if k >= 300 {
                match sig {
                    0 => raw.0[1] += spike,
                    1 => raw.1[1] += spike,
                    _ => raw.2[1] += spike,
                }
            }
            let m = g.measure(k, raw);
            guard.repair(&m, None, 50, None);
        }
        assert!(
            guard.is_rejected(sig, 1),
            "signal {sig}: the spike is rejected"
        );
        // Samples 303-312 never arrive; the loop restarts its filter windows after the gap.
        g.qd_f.reset();
        g.f_f.reset();
        for k in 313..320 {
            let m = g.measure(k, g.raw(k));
            let rep = guard.repair(&m, None, 50, None);
            assert!(rep.ready, "signal {sig}, step {k}: not ready");
            assert!(
                !rep.any_rejected,
                "signal {sig}, step {k}: {:?}",
                rep.estimated
            );
            assert_eq!(rep.m, m, "signal {sig}, step {k}");
        }
    }
}

/// Detection delays (docs/RELIABILITY.md §2), on a 1-Hz sine gait through the 5-sample filter
/// at 10 ms: non-finite and out-of-range angles, velocities and forces in the same sample, an
/// encoder spike in the same sample, a stuck encoder within one sample, a velocity spike or
/// stuck velocity within 30 ms, a strap-force spike in the same sample; a stuck (frozen)
/// strap force once its
/// filter window repeats (≤ 50 ms), without a false alarm on the clean gait before.
#[test]
fn each_fault_kind_is_flagged_within_its_stated_delay() {
    let held = |sig: usize| {
        let g = Gait::new();
        let v = match sig {
            0 => g.raw(300).0[1],
            1 => g.raw(300).1[1],
            _ => g.raw(300).2[1],
        };
        move |r: &mut (SVector<f64, 2>, SVector<f64, 2>, SVector<f64, 2>), _k: usize| match sig {
            0 => r.0[1] = v,
            1 => r.1[1] = v,
            _ => r.2[1] = v,
        }
    };
    let cases: [(&str, usize, Option<usize>, usize); 12] = [
        ("q NaN", 0, delay(0, |r, _| r.0[1] = f64::NAN), 0),
        ("q out of range", 0, delay(0, |r, _| r.0[1] = 4.0), 0),
        ("q spike 0.5 rad", 0, delay(0, |r, _| r.0[1] += 0.5), 0),
        ("q stuck", 0, delay(0, held(0)), 1),
        ("qd NaN", 1, delay(1, |r, _| r.1[1] = f64::NAN), 0),
        ("qd spike 0.5 rad/s", 1, delay(1, |r, _| r.1[1] += 0.5), 3),
        ("qd stuck", 1, delay(1, held(1)), 3),
        ("qd out of range", 1, delay(1, |r, _| r.1[1] = 1000.0), 0),
        ("F NaN", 2, delay(2, |r, _| r.2[1] = f64::NAN), 0),
        ("F out of range", 2, delay(2, |r, _| r.2[1] = 1000.0), 0),
        ("F spike 30 N", 2, delay(2, |r, _| r.2[1] += 30.0), 0),
        ("F stuck", 2, delay(2, held(2)), 5),
    ];
    for (what, _sig, got, within) in cases {
        let d = got.unwrap_or_else(|| panic!("{what}: not flagged"));
        assert!(
            d <= within,
            "{what}: flagged after {d} steps, stated {within}"
        );
    }
}

/// A strap force that follows the robot's own fast motion is no sensor fault: with the strap
/// model (`ChannelGuard::with_straps`, as the supervisor builds it) the force gate judges the
/// force less the robot's part of it. The robot (default straps, 2 DOF) leaves the person's
/// gait with a jerk (its torque stepping at the rate limit: 150 rad/s² within 20 ms, for
/// 40 ms, then braking), and the strap forces, made by the plant's strap model through the
/// 5-sample filter, swing by some 100 N: none is rejected, while the guard without the model
/// rejects them (the controller resuming after a protective stop at 2 kg then stepped on
/// held forces and drove the robot on into the person: 164.9 N). A 30-N spike on the same
/// motion is still flagged in the same sample.
#[test]
fn a_strap_force_that_follows_the_robots_own_motion_is_not_rejected() {
    let dt = 0.01;
    let straps = Straps::two_dof(0.28, 0.16, 937.5, 93.7);
    let ks_j = straps.j * straps.stiffness;
    let tau = straps.damping / straps.stiffness;
    // The robot's departure from the gait (rad, rad/s) at time `t` from its start: the
    // acceleration ramps to −150 rad/s² in 20 ms, holds, and reverses after 40 ms.
    let departure = |t: f64| {
        let (mut e, mut ed, h) = (0.0, 0.0, 1e-5);
        let n = (t / h).round() as usize;
        for i in 0..n {
            let s = i as f64 * h;
            let a = if s < 0.04 {
                -150.0 * (s / 0.02).min(1.0)
            } else if s < 0.08 {
                150.0 * ((s - 0.04) / 0.02).min(1.0)
            } else {
                0.0
            };
            e += ed * h + 0.5 * a * h * h;
            ed += a * h;
        }
        (e, ed)
    };
    let run = |with_straps: bool, spike_at: Option<usize>| {
        let mut g = Gait::new();
        let mut guard = ChannelGuard::<2>::new(dt, 5, [std::f64::consts::PI, 30.0, 70.0]);
        if with_straps {
            guard = guard.with_straps(ks_j, tau);
        }
        let mut rejected = Vec::new();
        for k in 0..330 {
            // The person's own force is the gait's; the robot's departure adds its part.
            let (q_h, qd_h, f_h) = g.raw(k);
            let (e, ed) = if k >= 300 {
                departure((k - 300) as f64 * dt)
            } else {
                (0.0, 0.0)
            };
            // The robot departs on the knee; the person's leg is the gait.
            let q_r = q_h + SVector::from([0.0, e]);
            let qd_r = qd_h + SVector::from([0.0, ed]);
            let mut f = f_h + straps.force(&(q_h - q_r), &(qd_h - qd_r));
            if spike_at == Some(k) {
                f[1] += 30.0;
            }
            let m = g.measure(k, (q_r, qd_r, f));
            guard.repair(&m, Some(1.0), 50, None);
            if guard.is_rejected(2, 0) || guard.is_rejected(2, 1) {
                rejected.push(k);
            }
        }
        (rejected, g.f_f.mean())
    };
    let (with, _) = run(true, None);
    assert!(with.is_empty(), "forces rejected at steps {with:?}");
    let (without, _) = run(false, None);
    assert!(
        !without.is_empty(),
        "the departure must be fast enough to trip the plain force gate"
    );
    let (spiked, _) = run(true, Some(304));
    assert_eq!(spiked.first(), Some(&304), "spike flagged at {spiked:?}");
}

/// A strap force that rails at full scale and comes back is a real force: the range check
/// handles the full-scale samples, and the in-range samples right after them are not gated
/// against an extrapolation through the estimate that stood in for the rail (the 1.3 Hz, 3 kg
/// envelope cell, whose 67 N·m gait saturates the ±70 N sensor every half period).
#[test]
fn a_force_back_from_full_scale_is_not_rejected() {
    let dt = 0.01;
    let mut guard = ChannelGuard::<1>::new(dt, 5, [3.0, 20.0, 70.0]);
    let w = 2.0 * std::f64::consts::PI * 1.3;
    for k in 0..400 {
        let t = k as f64 * dt;
        let f = (100.0 * (w * t).sin()).clamp(-70.0, 70.0);
        let m = Measurement {
            t,
            q: SVector::from([0.3 * (w * t).sin()]),
            qd: SVector::from([0.3 * w * (w * t).cos()]),
            force: SVector::from([f]),
        };
        guard.repair(&m, None, 10, None);
        if f.abs() < 70.0 {
            assert!(
                !guard.is_rejected(2, 0),
                "in-range force {f} N rejected at {t} s"
            );
        }
    }
}

/// Spikes on the filtered channels (issue 28): a 60-ms, 30-N spike on both strap forces and
/// a 0.5-rad/s spike on both velocities (60 ms, 200 ms and 1 s) at 2 kg (msnmpc) stay within
/// the goals of one channel group (peak true strap force ≤ 12 N, RMS ≤ 1.5× clean) without a
/// monitor trip. The moving average spreads a spike over `filter_window` more samples, whose
/// ramp back crosses the estimate: a channel is accepted back only when it also moves like
/// its estimate (before: 78 N for the force spike, 15-20 N for velocity spikes). A 200-ms
/// force spike is ridden through since `FORCE_RESYNC_S` is 0.3 s (with 0.1 s: 43.7 N;
/// docs/RELIABILITY.md §2a). A velocity whose angle is measured is judged against the angle's
/// slope only and never believed on smoothness alone (the 1-s spike believed after
/// `sensor_timeout_s`: 29.4 N; 29.3 N in the 1-s grid's 10-s run).
#[test]
fn spikes_on_filtered_channels_are_ridden_through() {
    const FORCES: [Channel; 2] = [Channel::F1, Channel::F2];
    let clean = scenario(ControllerKind::MSNMPC, 2.0, 6.0);
    let (_, rms0, _, _) = run(&clean);
    for (chans, mag, durs) in [
        (&FORCES, 30.0, &[0.06, 0.2][..]),
        (&VELOCITIES, 0.5, &[0.06, 0.2, 1.0]),
    ] {
        for &dur in durs {
            let mut faulty = clean.clone();
            faulty.faults.events = fault(FaultKind::Spike, chans, 3.0, dur, mag);
            let (peak, rms, rep, _) = run(&faulty);
            let what = format!("{chans:?} {dur} s");
            assert!(peak <= 12.0, "{what}: peak {peak:.1} N");
            for i in 0..2 {
                assert!(rms[i] <= 1.5 * rms0[i], "{what}: RMS {rms:?} vs {rms0:?}");
            }
            assert!(rep.sensor_faults > 0, "{what}: nothing detected");
            assert_eq!(rep.monitor_trips, 0, "{what}: {:?}", rep.events);
            assert_eq!(rep.latched_at, None);
        }
    }
}

/// A 1-s NaN of both angles at 2.5 s, 3 kg (the 1-s scan's cell, 10-s msnmpc run) ends in the
/// protective stop, and when the angles are back the torque goes back to the controller's
/// over `STOP_HANDBACK_STEPS`: the true strap forces stay within the 1-s goal of 70 N, without
/// a latch (before: handed the torque at once, the controller asked for the torque limit with
/// the robot lagging the person, 84.7 N; docs/RELIABILITY.md §2).
#[test]
fn the_torque_is_handed_back_gradually_after_a_protective_stop() {
    let mut s = scenario(ControllerKind::MSNMPC, 3.0, 10.0);
    s.faults.events = fault(FaultKind::Nan, &ANGLES, 2.5, 1.0, 0.0);
    let (peak, _, rep, _) = run(&s);
    let stop = rep
        .events
        .iter()
        .find(|e| e.monitor == MonitorKind::SensorTimeout && e.action == MonitorAction::Trip);
    assert!(stop.is_some(), "no protective stop: {:?}", rep.events);
    assert!(peak <= 70.0, "peak {peak:.1} N");
    assert_eq!(rep.latched_at, None);
}

/// Issue 28, every sensor lost: a 200-ms dropout of every channel at 0 kg, a 200-ms stuck
/// fault of every channel at 2 kg and a 60-ms NaN on every channel at 0 kg (the default
/// scan's 10-s runs, msnmpc) keep the peak true strap force ≤ 35 N and the RMS ≤ 1.5× the
/// clean run's, without a latch. While every encoder channel is an estimate, and until
/// every channel is back, the torque replays the torque of one gait period back, then blends
/// back to the controller's (before: 32.8 N / RMS 1.95×, 72.8 N and 37.2 N:
/// docs/RELIABILITY.md §2a).
#[test]
fn losing_every_sensor_is_ridden_through_on_the_replayed_torque() {
    every_sensor_is_ridden_through(
        3.0,
        &[
            (FaultKind::Dropout, 0.0, 0.2),
            (FaultKind::Stuck, 2.0, 0.2),
            (FaultKind::Nan, 0.0, 0.06),
        ],
    );
}

/// Issue 28, every sensor lost for 1 s with the gait period known (cells of the 1-s grid,
/// from 3 s): while the angle and velocity of a joint are both lost, the replay of one period
/// back stands in for them for `JOINT_LOST_LIMIT_FACTOR` × `sensor_timeout_s` (1 s), so neither
/// the protective stop nor a value believed on smoothness alone ends the ride-through. With the
/// limit at `sensor_timeout_s` the stop at 3.5 s left the person carrying robot and payload:
/// 39.0 N, RMS 3.18× at 2 kg, 15.3 N, 1.91× at 0 kg (measured on 2026-12-06).
#[test]
fn losing_every_sensor_for_a_second_is_ridden_through_on_the_replay() {
    every_sensor_is_ridden_through(
        3.0,
        &[(FaultKind::Dropout, 2.0, 1.0), (FaultKind::Nan, 0.0, 1.0)],
    );
}

/// Issue 28, every sensor's 1-s spike before the gait period is known (from 1.5 s, 3 kg, a
/// cell of the 1-s scan, 10-s msnmpc run): both encoders of each joint wait
/// `JOINT_LOST_LIMIT_FACTOR` × `sensor_timeout_s` (1 s, the end of the spike) before a smooth
/// value is believed, so the 0.5-rad offset is never believed: ≤ 70 N, no latch. At
/// `sensor_timeout_s` the offset was believed at 2.0 s and the controller drove the knee to
/// 8.9 rad/s before the monitors stopped it: 75.9 N (now 41.1 N; measured on 2026-12-06).
/// The forces are not followed under their offset once an encoder is lost
/// (`ChannelGuard::follow_offset`): followed through the encoders' loss, 74.4 N (measured on
/// 2026-12-07).
#[test]
fn every_sensor_spiked_for_a_second_in_the_first_gait_period_stays_within_70_n() {
    every_sensor_spiked_for_a_second_within(1.5, 3.0, 70.0);
}

/// Every sensor's 1-s spike from `start` (s) at `payload_kg` (the scan's cell, 10-s msnmpc
/// run): the peak true strap force stays within `goal` (N), no latch.
fn every_sensor_spiked_for_a_second_within(start: f64, payload_kg: f64, goal: f64) {
    let cell = (FaultKind::Spike, ChannelGroup::All, start, 1.0);
    let s = cell_scenario(&Experiment::default(), 10.0, payload_kg, Some(cell));
    let (peak, _, rep, _) = run(&s);
    assert!(peak <= goal, "peak {peak:.1} N, goal {goal} N");
    assert_eq!(rep.latched_at, None, "{:?}", rep.events);
}

/// Issue 28, every sensor's 0.5-rad / 0.5-rad/s / 30-N spike for 1 s with the gait period
/// known (cells of the 1-s scan, 10-s msnmpc runs): at 4 s, 3 kg, and 5 s, 2 kg, the peak true
/// strap force stays ≤ 35 N and the RMS ≤ 1.5× the clean run's, without a latch. A velocity
/// whose angle is lost too is accepted again only within `SLOPE_ACCEPT_GATES` of the gait
/// replay: within `ACCEPT_GATES` the knee's filtered velocity was accepted on the fault's
/// second sample, 0.14 rad/s off, took the rest of the spike in, and took the knee off the
/// replay: 81.9 N, RMS 4.64× at 4 s, 3 kg; 55.0 N, 3.50× at 5 s, 2 kg (measured on 2026-12-06).
#[test]
fn every_sensor_spiked_for_a_second_is_ridden_through_on_the_replay() {
    every_sensor_is_ridden_through(4.0, &[(FaultKind::Spike, 3.0, 1.0)]);
    every_sensor_is_ridden_through(5.0, &[(FaultKind::Spike, 2.0, 1.0)]);
}

/// The channels of `group` faulted from `start` (s), for each `(kind, payload kg, duration
/// s)`, in the scan's 10-s msnmpc runs (`cell_scenario`, the scan's spike magnitudes): peak
/// true strap force within issue 28's goal for the group (`peak_goal_n`: 35 N for every
/// sensor, 12 N for one group), RMS ≤ 1.5× the clean run's, the fault detected, no latch.
fn group_is_ridden_through(group: ChannelGroup, start: f64, cells: &[(FaultKind, f64, f64)]) {
    for &(fk, payload, dur) in cells {
        let base = Experiment::default();
        let (_, rms0, _, _) = run(&cell_scenario(&base, 10.0, payload, None));
        let cell = (fk, group, start, dur);
        let what = format!("{fk:?} {group:?} {payload} kg {dur} s from {start} s");
        let faulted = cell_scenario(&base, 10.0, payload, Some(cell));
        assert_ridden_through(&what, &faulted, rms0, peak_goal_n(group, dur));
    }
}

/// Runs the faulted scenario `s` and checks issue 28's goals against the clean run's RMS
/// `rms0`: peak true strap force ≤ `goal`, RMS ≤ 1.5×, the fault detected, no latch.
fn assert_ridden_through(what: &str, s: &Experiment, rms0: [f64; 2], goal: f64) {
    let (peak, rms, rep, _) = run(s);
    assert!(peak <= goal, "{what}: peak {peak:.1} N, goal {goal} N");
    for i in 0..2 {
        assert!(rms[i] <= 1.5 * rms0[i], "{what}: RMS {rms:?} vs {rms0:?}");
    }
    assert!(rep.sensor_faults > 0, "{what}: nothing detected");
    assert_eq!(rep.latched_at, None, "{what}");
}

/// [`group_is_ridden_through`] for every sensor (the 35-N goal).
fn every_sensor_is_ridden_through(start: f64, cells: &[(FaultKind, f64, f64)]) {
    group_is_ridden_through(ChannelGroup::All, start, cells);
}

/// Issue 28, one joint's encoder lost (its angle and velocity; `exompc faults --groups
/// joint1,joint2`): the torque replays one gait period back, or follows its extrapolation in
/// the first gait period, as when every encoder is lost, and the peak true strap force stays
/// within the 12-N goal of one group. Stepped on the model's prediction of the lost joint, the
/// controller drove the torque to its limit: the knee's 60-ms NaN at 1.5 s, 3 kg, 115.9 N; the
/// hip's 200-ms dropout at 3 s, 2 kg, 44.7 N; the hip's 60-ms spike at 1.5 s, 2 kg, 60.8 N
/// (docs/RELIABILITY.md §2a).
#[test]
fn losing_one_joints_encoder_is_ridden_through_on_the_replayed_torque() {
    group_is_ridden_through(ChannelGroup::Joint2, 1.5, &[(FaultKind::Nan, 3.0, 0.06)]);
    group_is_ridden_through(ChannelGroup::Joint1, 3.0, &[(FaultKind::Dropout, 2.0, 0.2)]);
    group_is_ridden_through(ChannelGroup::Joint1, 1.5, &[(FaultKind::Spike, 2.0, 0.06)]);
}

/// Issue 28, one joint's encoder lost at 3 kg where the torque one gait period back (or its
/// extrapolation) is a few N·m off the clean run's (early in the run the simulated human
/// grows heavier, docs/MODEL.md §2): the coast's torque is corrected by the strap forces'
/// change since it began (`COAST_FORCE_GAIN`), and the peak true strap force stays within the
/// 12-N goal. Without the correction (measured on 2026-12-07): the knee's 200-ms NaN at
/// 1.75 s (first gait period, the extrapolation) 26.6 N, the hip's 200-ms dropout at 2.25 s
/// 16.2 N, the hip's 200-ms stuck encoder at 3.75 s 15.9 N.
#[test]
fn one_joints_encoder_lost_at_3_kg_is_corrected_by_the_strap_forces() {
    group_is_ridden_through(ChannelGroup::Joint2, 1.75, &[(FaultKind::Nan, 3.0, 0.2)]);
    group_is_ridden_through(
        ChannelGroup::Joint1,
        2.25,
        &[(FaultKind::Dropout, 3.0, 0.2)],
    );
    group_is_ridden_through(ChannelGroup::Joint1, 3.75, &[(FaultKind::Stuck, 3.0, 0.2)]);
}

/// Issue 28, one angle lost while its velocity stays measured (a 200-ms stuck hip angle and a
/// dropped-out knee angle at 2.25 s, 3 kg, in the scan's 10-s msnmpc runs): the joint coasts
/// for the whole fault, and the peak true strap force stays within the 12-N goal of one
/// group, the RMS within 1.5× the clean run's, without a latch. Handed to the controller on
/// the angle its velocity integrates to after the filter window (measured on 2026-12-07):
/// 33.7 / 22.9 N.
#[test]
fn one_angle_lost_is_ridden_through_on_its_joints_coast() {
    let base = cell_scenario(&Experiment::default(), 10.0, 3.0, None);
    let (_, rms0, _, _) = run(&base);
    for (ch, kind) in [
        (Channel::Q1, FaultKind::Stuck),
        (Channel::Q2, FaultKind::Dropout),
    ] {
        let mut s = base.clone();
        s.faults.events = fault(kind, &[ch], 2.25, 0.2, 0.0);
        assert_ridden_through(&format!("{kind:?} {ch:?}"), &s, rms0, 12.0);
    }
}

/// Issue 28, every sensor lost in the first gait period (before the gait period is known, the
/// torque of one period back cannot be replayed): a 200-ms dropout at 3 kg, a 200-ms stuck
/// fault at 2 kg and a 200-ms NaN at 1 kg of every channel from 1 s (the wider scan's 10-s
/// runs, msnmpc) keep the peak true strap force ≤ 35 N and the RMS ≤ 1.5× the clean run's,
/// without a latch. The torque follows its extrapolation at the angles' gait frequency
/// (`TorqueExtrapolation`); holding it gave 97.1 N / 3.59×, 81.9 N / 11.0× and 28.6 N / 1.84×
/// (docs/RELIABILITY.md §2a).
#[test]
fn losing_every_sensor_in_the_first_gait_period_is_ridden_through() {
    every_sensor_is_ridden_through(
        1.0,
        &[
            (FaultKind::Dropout, 3.0, 0.2),
            (FaultKind::Stuck, 2.0, 0.2),
            (FaultKind::Nan, 1.0, 0.2),
        ],
    );
}

/// The torque extrapolation against the analytic continuation of a two-harmonic torque over
/// a sine gait (1 Hz, 10 ms): fitted on 0.9 s of history (all of it), it follows the torque
/// for the next 0.2 s within 1 % of its amplitude (kept within the range of the fitted
/// torques); it holds
/// (no fit) on a leg that does not swing or with less than 0.3 s of history.
#[test]
fn torque_extrapolation_continues_a_periodic_torque() {
    let dt = 0.01;
    let w = 2.0 * std::f64::consts::PI;
    let torque = |t: f64| {
        SVector::from([
            3.0 + 10.0 * (w * t + 0.4).sin() + 2.0 * (2.0 * w * t).cos(),
            -1.0 + 4.0 * (w * t - 1.0).sin(),
        ])
    };
    let angle =
        |t: f64| SVector::from([0.1 + 0.3 * (w * t).sin(), -0.5 + 0.5 * (w * t - 1.0).cos()]);
    let len = 300;
    let n = 90;
    let ring = |f: &dyn Fn(f64) -> SVector<f64, 2>| {
        let mut r = vec![SVector::<f64, 2>::zeros(); len];
        for (k, v) in r.iter_mut().enumerate().take(n) {
            *v = f(k as f64 * dt);
        }
        r
    };
    let (tq, an) = (ring(&torque), ring(&angle));
    let x = TorqueExtrapolation::<2>::fit(&tq, n, &an, n, n, dt).expect("a swinging leg is fitted");
    let mut lo = SVector::<f64, 2>::repeat(f64::INFINITY);
    let mut hi = SVector::<f64, 2>::repeat(f64::NEG_INFINITY);
    for t in &tq[..n] {
        lo = lo.inf(t);
        hi = hi.sup(t);
    }
    for i in 0..20u32 {
        let want = torque((n as f64 + f64::from(i)) * dt).sup(&lo).inf(&hi);
        let got = x.at(i, dt);
        for j in 0..2 {
            let amp = [12.0, 4.0][j];
            assert!(
                (got[j] - want[j]).abs() <= 0.01 * amp,
                "joint {j}, {i} steps on: {} vs {}",
                got[j],
                want[j]
            );
        }
    }
    // The extrapolation's frequency bound is the supervisor's.
    assert_eq!(EXTRAPOLATION_MAX_HZ, GAIT_MAX_HZ);
    let still = vec![SVector::<f64, 2>::from([0.1, -0.5]); len];
    assert!(TorqueExtrapolation::<2>::fit(&tq, n, &still, n, n, dt).is_none());
    assert!(TorqueExtrapolation::<2>::fit(&tq, 25, &an, 25, 25, dt).is_none());
    // A series fitted at its frequency to samples that leave its recent ones out (here
    // corrupted), started at a given last value: its continuation, with the last value's
    // offset (1 N·m) fading out over `EXTRAPOLATION_FADE_STEPS`, within the samples' range.
    let now = 150;
    let back =
        |i: usize| torque((now - i) as f64 * dt) + SVector::repeat(if i < 5 { 50.0 } else { 0.0 });
    let samples = || (5..=120).map(|i| (i, back(i)));
    let last = torque((now - 1) as f64 * dt) + SVector::repeat(1.0);
    let x = TorqueExtrapolation::<2>::fit_series(samples(), w, dt, last).expect("a fit");
    assert_eq!(x.omega(), w);
    let (lo, hi) = samples().fold(
        (
            SVector::repeat(f64::INFINITY),
            SVector::repeat(f64::NEG_INFINITY),
        ),
        |(lo, hi): (SVector<f64, 2>, SVector<f64, 2>), (_, v)| (lo.inf(&v), hi.sup(&v)),
    );
    for i in 0..20u32 {
        let fade = (1.0 - f64::from(i + 1) / f64::from(EXTRAPOLATION_FADE_STEPS)).max(0.0);
        let want = (torque((now as f64 + f64::from(i)) * dt) + SVector::repeat(fade))
            .sup(&lo)
            .inf(&hi);
        let err = (x.at(i, dt) - want).amax();
        assert!(err <= 1e-6, "{i} steps on: {err:.2e} off");
    }
    let few = (5..=8).map(|i| (i, back(i)));
    assert!(TorqueExtrapolation::<2>::fit_series(few, w, dt, last).is_none());
}

/// A stalled acquisition (every raw sample frozen at once, a dropout or stuck fault of every
/// sensor): the filtered velocities still move for `window − 1` samples, but they are rejected
/// in the same sample as the angles (before: after up to 3 samples, while the controller
/// stepped on them). A frozen angle alone (the velocities measured) leaves the velocities
/// accepted after the filter window.
#[test]
fn a_stalled_acquisition_flags_the_velocities_in_the_same_sample() {
    for every in [true, false] {
        let mut g = Gait::new();
        let mut guard = gait_guard();
        let held = g.raw(299);
        for k in 0..320 {
            let mut raw = g.raw(k);
            if k >= 300 {
                raw.0 = held.0;
                if every {
                    raw.1 = held.1;
                    raw.2 = held.2;
                }
            }
            let m = g.measure(k, raw);
            let rep = guard.repair(&m, Some(1.0), 50, None);
            if k < 300 {
                assert!(!rep.any_rejected, "false alarm at step {k}");
            } else if k == 300 {
                assert!(rep.stalled, "every={every}");
                for j in 0..2 {
                    assert!(
                        guard.is_rejected(0, j) && guard.is_rejected(1, j),
                        "joint {j}"
                    );
                }
            } else if !every && k >= 306 {
                for j in 0..2 {
                    assert!(!guard.is_rejected(1, j), "every={every} joint {j} step {k}");
                }
            } else if every {
                for j in 0..2 {
                    assert!(guard.is_rejected(1, j), "joint {j} step {k}");
                }
            }
        }
    }
}

/// A stall of the angles alone (both angles frozen at once for 200 ms, the velocities and
/// forces measured, no gait period known): the velocities are rejected with the angles for the
/// stall rule's filter window, are accepted again once it is over (they did not freeze), and
/// from that step the angles are the ones the received velocities imply, also over the
/// held-off steps (the history rewritten): `Repaired::q_from_velocity`, within 2 mrad of the
/// true angles, and `resume` on the step they take over. Before, the angles stayed estimates
/// (integrated from the held-off velocities' estimates) until the fault ended.
#[test]
fn a_stall_of_the_angles_alone_is_measured_through_by_the_velocities() {
    let mut g = Gait::new();
    let mut guard = gait_guard();
    let held = g.raw(299).0;
    let mut implied_from = None;
    for k in 0..330 {
        let clean = g.raw(k);
        let mut raw = clean;
        let faulty = (300..320).contains(&k);
        if faulty {
            raw.0 = held;
        }
        let m = g.measure(k, raw);
        let rep = guard.repair(&m, None, 50, None);
        if k == 300 {
            assert!(rep.stalled);
        }
        if !faulty {
            assert!(rep.q_from_velocity.iter().all(|&v| !v), "step {k}");
            continue;
        }
        if implied_from.is_none() && !guard.is_rejected(1, 0) && !guard.is_rejected(1, 1) {
            implied_from = Some(k);
            assert!(rep.estimated.resume, "step {k}");
        }
        if implied_from.is_some() {
            for j in 0..2 {
                assert!(
                    rep.estimated.q[j] && rep.q_from_velocity[j],
                    "step {k} joint {j}"
                );
                let err = (rep.m.q[j] - clean.0[j]).abs();
                assert!(err <= 2e-3, "step {k} joint {j}: {err:.4} rad off");
            }
        }
    }
    assert_eq!(implied_from, Some(306));
}

/// The angles through a stall are implied only from trusted data: not for a joint whose angle
/// was not measured over the filter window before the stall (a NaN until two samples before
/// it: the rewrite would anchor on estimates), and not for a joint whose velocity was out of
/// range within the stall (a glitch integrated into the angle); the other joint still is.
#[test]
fn the_angles_through_a_stall_are_implied_only_from_trusted_data() {
    for case in ["late angle", "velocity glitch"] {
        let mut g = Gait::new();
        let mut guard = gait_guard();
        let held = g.raw(299).0;
        let (mut implied, mut stalled) = ([false; 2], false);
        for k in 0..330 {
            let mut raw = g.raw(k);
            if case == "late angle" && (294..298).contains(&k) {
                raw.0[0] = f64::NAN;
            }
            if case == "velocity glitch" && k == 301 {
                raw.1[1] = 1e3;
            }
            if (300..320).contains(&k) {
                raw.0 = held;
            }
            let m = g.measure(k, raw);
            let rep = guard.repair(&m, None, 50, None);
            stalled |= rep.stalled;
            for (j, imp) in implied.iter_mut().enumerate() {
                *imp |= (300..320).contains(&k) && rep.q_from_velocity[j];
            }
        }
        assert!(stalled, "{case}");
        let want = if case == "late angle" {
            [false, true]
        } else {
            [true, false]
        };
        assert_eq!(implied, want, "{case}");
    }
}

/// Issue 28, one group at 3 kg: 200-ms stuck or dropped pairs of angles at 1.25 s and 2.75 s
/// (stalls of the encoders, cells of the fine phase scan) meet one group's goal. On the torque
/// replayed one gait period back until every channel was back, the hip torque stayed 3-4 N·m
/// off the clean run's (the gait one period back is another gait early in the run: the human
/// grows heavier, docs/MODEL.md §2): 15.5 / 15.8 N at 1.25 s, 14.1 / 14.3 N at 2.75 s
/// (measured on 2026-12-06); now the controller takes over once the velocities, accepted again
/// after the stall rule's window, imply the angles
/// (`a_stall_of_the_angles_alone_is_measured_through_by_the_velocities`): 8.9 N, 10.2 / 9.8 N.
#[test]
fn a_stall_of_the_angles_alone_at_3_kg_hands_back_to_the_controller() {
    for start in [1.25, 2.75] {
        for kind in [FaultKind::Stuck, FaultKind::Dropout] {
            one_group_cell_meets_the_goal(3.0, kind, &ANGLES, start, 0.2);
        }
    }
}

/// Issue 28, one group at 3 kg: a 200-ms stuck or dropped fault of both angles at 5.3 s (a
/// stalled acquisition of the encoders, the velocities flagged with them and the torque
/// replayed until every channel is back) keeps the peak true strap force ≤ 12 N and the RMS
/// ≤ 1.5× clean, without a latch (before: 36.2 / 37.0 N, RMS 1.55 / 1.53×).
#[test]
fn a_stuck_encoder_pair_at_3_kg_is_ridden_through() {
    let clean = scenario(ControllerKind::MSNMPC, 3.0, 10.0);
    let (_, rms0, _, _) = run(&clean);
    for fk in [FaultKind::Stuck, FaultKind::Dropout] {
        let mut faulty = clean.clone();
        faulty.faults.events = fault(fk, &ANGLES, 5.3, 0.2, 0.0);
        let (peak, rms, rep, _) = run(&faulty);
        assert!(peak <= 12.0, "{fk:?}: peak {peak:.1} N");
        for i in 0..2 {
            assert!(rms[i] <= 1.5 * rms0[i], "{fk:?}: RMS {rms:?} vs {rms0:?}");
        }
        assert_eq!(rep.latched_at, None, "{fk:?}");
    }
}

/// Issue 28, the forces at 3 kg (beyond the scenarios' payloads): while both forces are
/// estimated (after `REPLAY_AFTER_STEPS`) the EKF banks' `d̂` replays the gait one period back
/// instead of holding where the fault found it. A 200-ms dropout of both forces at 4.25 s and
/// at 5.3 s (cells of the fine and the wider phase scans, docs/RELIABILITY.md §2a), without a
/// monitor trip or latch. Measured on 2026-12-05 with `d̂` held over the whole fault: 35.7 N,
/// RMS 1.43× clean at 4.25 s, 23.5 N, 1.24× at 5.3 s; replayed after five held steps: 23.4 N,
/// 1.11× and 14.4 N, 1.06×; the filters updated over those five steps (the replay continuing
/// from their `d̂`): 16.2 N, 1.07× and 10.6 N, 1.03×.
#[test]
fn a_force_dropout_beyond_the_scenario_payloads_is_ridden_through() {
    force_faults(
        3.0,
        &[
            (FaultKind::Dropout, 4.25, 0.2, 20.0, 1.1),
            (FaultKind::Dropout, 5.3, 0.2, 12.0, 1.05),
        ],
    );
}

/// 10-s MS-NMPC runs at `payload` kg with a fault of both strap forces (30-N spikes), one per cell
/// `(kind, start s, duration s, peak bound N, RMS bound × the clean run's per strap)`: each
/// within its bounds, without a monitor trip or latch.
fn force_faults(payload: f64, cells: &[(FaultKind, f64, f64, f64, f64)]) {
    let clean = scenario(ControllerKind::MSNMPC, payload, 10.0);
    let (_, rms0, _, _) = run(&clean);
    for &(kind, start, dur, max_peak, max_ratio) in cells {
        let mut faulty = clean.clone();
        faulty.faults.events = fault(kind, &[Channel::F1, Channel::F2], start, dur, 30.0);
        let (peak, rms, rep, _) = run(&faulty);
        assert!(peak <= max_peak, "{kind:?} at {start} s: peak {peak:.1} N");
        for i in 0..2 {
            assert!(
                rms[i] <= max_ratio * rms0[i],
                "{kind:?} at {start} s: RMS {rms:?} vs {rms0:?}"
            );
        }
        assert_eq!(rep.monitor_trips, 0, "{kind:?} at {start} s");
        assert_eq!(rep.latched_at, None, "{kind:?} at {start} s");
    }
}

/// Issue 28: while the strap forces are estimated the MS-NMPC's EKF banks update with the
/// measured angles and velocities over the first `REPLAY_AFTER_STEPS` (5) steps, so each
/// scenario's `d̂` moves on each of them, and from the sixth on predict without an update, so
/// `d̂` stays where it is (no gait period given: no replay). Before, `d̂` stayed where the
/// fault found it from the first step.
#[test]
fn the_filters_update_over_the_first_steps_of_estimated_forces() {
    let s = scenario(ControllerKind::MSNMPC, 3.0, 10.0);
    let mut c = exompc::build_controller::<TwoDof, 2>(&s, ControllerKind::MSNMPC).unwrap();
    let w = std::f64::consts::TAU;
    let m = |k: usize| {
        let t = k as f64 * 0.01;
        Measurement {
            t,
            q: SVector::from([0.4 * (w * t).sin(), 0.3 * (1.0 - (w * t).cos())]),
            qd: SVector::from([0.4 * w * (w * t).cos(), 0.3 * w * (w * t).sin()]),
            force: SVector::from([5.0 * (w * t + 0.5).sin(), 4.0 * (w * t + 1.0).sin()]),
        }
    };
    for k in 0..150 {
        c.step(&m(k));
    }
    let estimated = EstimatedChannels {
        q: [false; 2],
        qd: [false; 2],
        force: [true; 2],
        period: None,
        gait_omega: None,
        resume: false,
    };
    let mut prev = c.disturbance(0).unwrap();
    for step in 1..=10 {
        c.step_estimated(&m(149 + step), &estimated);
        let d = c.disturbance(0).unwrap();
        let moved = (d - prev).amax();
        if step <= 5 {
            assert!(moved > 1e-9, "step {step} of the fault: d̂ did not move");
        } else {
            assert_eq!(moved, 0.0, "step {step} of the fault: d̂ moved by {moved}");
        }
        prev = d;
    }
}

/// Issue 28: while the strap forces follow their continuation (`EstimatedChannels::gait_omega`
/// given) the MS-NMPC continues each scenario's `d̂` from the fault's first step, so the
/// estimated forces do not move it: two controllers fed the same angles and velocities, one
/// with the forces' estimates 10 N off, keep the same `d̂` over the fault's first steps. Over
/// them the filters used to update on the estimated forces (a 200-ms NaN of both forces at
/// 1 s, 3 kg: 12.5 N; continued from the first step 11.8 N, docs/RELIABILITY.md §2).
#[test]
fn estimated_forces_do_not_move_the_continued_disturbance() {
    let s = scenario(ControllerKind::MSNMPC, 3.0, 10.0);
    let build = || exompc::build_controller::<TwoDof, 2>(&s, ControllerKind::MSNMPC).unwrap();
    let w = std::f64::consts::TAU * 0.9;
    let m = |k: usize, off: f64| {
        let t = k as f64 * 0.01;
        Measurement {
            t,
            q: SVector::from([0.4 * (w * t).sin(), 0.3 * (1.0 - (w * t).cos())]),
            qd: SVector::from([0.4 * w * (w * t).cos(), 0.3 * w * (w * t).sin()]),
            force: SVector::from([5.0 * (w * t + 0.5).sin(), 4.0 * (w * t + 1.0).sin()])
                .add_scalar(off),
        }
    };
    let (mut a, mut b) = (build(), build());
    let start = 200;
    for k in 0..start {
        a.step(&m(k, 0.0));
        b.step(&m(k, 0.0));
    }
    let estimated = EstimatedChannels {
        q: [false; 2],
        qd: [false; 2],
        force: [true; 2],
        period: None,
        gait_omega: Some(w),
        resume: false,
    };
    let before = a.disturbance(0).unwrap();
    for (step, k) in (start..start + 5).enumerate() {
        a.step_estimated(&m(k, 0.0), &estimated);
        b.step_estimated(&m(k, 10.0), &estimated);
        for i in 0..3 {
            let off = (a.disturbance(i).unwrap() - b.disturbance(i).unwrap()).amax();
            assert_eq!(
                off,
                0.0,
                "step {} of the fault, scenario {i}: {off} N·m",
                step + 1
            );
        }
    }
    // Continued, not held.
    let moved = (a.disturbance(0).unwrap() - before).amax();
    assert!(moved > 1e-6, "d̂ held over the fault's first steps");
}

/// Issue 28, strap forces estimated before the gait period is known: while the guard
/// continues them at the gait frequency (`EstimatedChannels::gait_omega`) the MS-NMPC
/// continues each scenario's `d̂` at that frequency too (from the fault's first step), instead
/// of holding it from the sixth step. On a periodic gait at 3 kg (the model's error moving `d̂`
/// along the gait), the continued `d̂` stays closer to that of the same controller with the
/// forces measured than the held one does, over 0.25 s (0.83 against 3.02 N·m; measured on
/// 2026-12-07). Held after it, and then replayed once the period is known, `d̂` goes on from
/// where it is (0.32 N·m per step at most; 4.04 N·m when the replay started from the filters'
/// last update before the continuation). With the gait period known as well, `d̂` is
/// continued the same way, not replayed one period back (within 0.3 N·m of the continuation
/// without the period; the same to the last bit since both begin on the fault's first step).
#[test]
fn the_disturbance_is_continued_with_the_forces() {
    let s = scenario(ControllerKind::MSNMPC, 3.0, 10.0);
    let build = || exompc::build_controller::<TwoDof, 2>(&s, ControllerKind::MSNMPC).unwrap();
    let w = std::f64::consts::TAU * 0.9;
    let m = |k: usize| {
        let t = k as f64 * 0.01;
        Measurement {
            t,
            q: SVector::from([0.4 * (w * t).sin(), 0.3 * (1.0 - (w * t).cos())]),
            qd: SVector::from([0.4 * w * (w * t).cos(), 0.3 * w * (w * t).sin()]),
            force: SVector::from([5.0 * (w * t + 0.5).sin(), 4.0 * (w * t + 1.0).sin()]),
        }
    };
    let (mut clean, mut held, mut continued) = (build(), build(), build());
    let mut known = build();
    let start = 200;
    for k in 0..start {
        for c in [&mut clean, &mut held, &mut continued, &mut known] {
            c.step(&m(k));
        }
    }
    let estimated = |omega: Option<f64>| EstimatedChannels {
        q: [false; 2],
        qd: [false; 2],
        force: [true; 2],
        period: None,
        gait_omega: omega,
        resume: false,
    };
    let period = (std::f64::consts::TAU / w / 0.01).round() as usize;
    let (mut err_held, mut err_continued, mut err_known) = (0.0f64, 0.0f64, 0.0f64);
    for k in start..start + 25 {
        clean.step(&m(k));
        held.step_estimated(&m(k), &estimated(None));
        continued.step_estimated(&m(k), &estimated(Some(w)));
        let with_period = EstimatedChannels {
            period: Some(period),
            ..estimated(Some(w))
        };
        known.step_estimated(&m(k), &with_period);
        for i in 0..3 {
            let d = clean.disturbance(i).unwrap();
            err_held = err_held.max((held.disturbance(i).unwrap() - d).amax());
            err_continued = err_continued.max((continued.disturbance(i).unwrap() - d).amax());
            let off = (known.disturbance(i).unwrap() - continued.disturbance(i).unwrap()).amax();
            err_known = err_known.max(off);
        }
    }
    assert!(
        err_continued < 0.5 * err_held,
        "continued {err_continued:.3} N·m off, held {err_held:.3} N·m off"
    );
    // With the period known the history records the gait one period back during the fault;
    // the continuation, fitted to the history before the fault's first step, does not read it
    // (0.11 N·m apart when it began on the sixth step; replayed instead, 0.76 N·m from the
    // continued `d̂`).
    assert!(
        err_known <= 0.3,
        "the period known: {err_known:.3} N·m from the continued d̂"
    );
    // The continuation over (no frequency given: `d̂` held), then the period known: the
    // replay starts from the current `d̂`, not from the filters' last update before the
    // continuation (which would step it by the gait's change since).
    let held_at = continued.disturbance(0).unwrap();
    for k in start + 25..start + 30 {
        continued.step_estimated(&m(k), &estimated(None));
        let moved = (continued.disturbance(0).unwrap() - held_at).amax();
        assert_eq!(moved, 0.0, "step {k}: the held d̂ moved by {moved}");
    }
    let p = (1.0 / 0.9 / 0.01f64).round() as usize;
    let mut replayed = estimated(None);
    replayed.period = Some(p);
    let mut prev = held_at;
    let mut largest = 0.0f64;
    for k in start + 30..start + 40 {
        continued.step_estimated(&m(k), &replayed);
        let d = continued.disturbance(0).unwrap();
        largest = largest.max((d - prev).amax());
        prev = d;
    }
    assert!(largest <= 1.0, "the replay stepped d̂ by {largest:.3} N·m");
}

/// Issue 28, strap-force faults at 3 kg in the first gait period, cells of the fine and
/// wider scans (docs/RELIABILITY.md §2a): a 200-ms NaN and a 200-ms stuck force at 1.5 s, a
/// 200-ms dropout and a 200-ms NaN at 1 s stay ≤ 12 N and ≤ 1.05× clean with no trip.
/// Measured on 2026-12-06 with `d̂` held after the first five steps (the forces continued):
/// 31.9, 25.4 and 20.3 N (RMS 1.38-1.39×, 1.20×) for the first three; measured on
/// 2026-12-07 with `d̂` continued after them: 8.9, 8.9, 8.9 and 12.5 N; continued from the
/// fault's first step: 8.9, 8.9, 9.7 and 11.8 N.
#[test]
fn force_faults_at_3_kg_in_the_first_gait_period_continue_the_disturbance() {
    force_faults(
        3.0,
        &[
            (FaultKind::Nan, 1.5, 0.2, 12.0, 1.05),
            (FaultKind::Stuck, 1.5, 0.2, 12.0, 1.05),
            (FaultKind::Dropout, 1.0, 0.2, 12.0, 1.05),
            (FaultKind::Nan, 1.0, 0.2, 12.0, 1.05),
        ],
    );
}

/// Issue 28, the forces at 3 kg: over a strap-force fault's first steps `d̂` keeps following
/// the model's error along the gait (held over them, the torque stalled at once while the leg
/// moved on): continued with the forces from the fault's first step (these cells, every
/// encoder measured), or updated by the filters over the first `REPLAY_AFTER_STEPS` steps
/// without a continuation. Cells of the fine phase scan (docs/RELIABILITY.md §2a) within the
/// one-group goal (12 N): measured on 2026-12-05 with `d̂` held over those steps: a 60-ms NaN
/// at 4.75 s 16.5 N, a 200-ms 30-N spike at 3.5 s 27.5 N and at 4.5 s 30.7 N, a 200-ms stuck
/// force at 5.5 s 16.1 N (RMS 1.03-1.17× clean); updated: 10.2, 8.9, 8.9, 10.4 N (RMS ≤
/// 1.01×); measured on 2026-12-07, continued from the first step: 8.9 N each, the clean run's
/// own peak (RMS ≤ 1.02×).
#[test]
fn short_force_faults_beyond_the_scenario_payloads_stay_within_the_goal() {
    force_faults(
        3.0,
        &[
            (FaultKind::Nan, 4.75, 0.06, 12.0, 1.05),
            (FaultKind::Spike, 3.5, 0.2, 12.0, 1.05),
            (FaultKind::Spike, 4.5, 0.2, 12.0, 1.05),
            (FaultKind::Stuck, 5.5, 0.2, 12.0, 1.05),
        ],
    );
}

/// Issue 28, the forces at 3 kg where the hip reverses (the fine scan's x.25 s starts): while
/// `d̂` is replayed the EKF banks hold it and update their joint states with the measured
/// angles and velocities, and the replay's lag is matched on the angles. The NMPC starts from
/// the filters' velocity; predicted without an update it fell 0.1-0.2 rad/s behind within
/// 0.1 s (the torque then changes by about 30 N·m per rad/s), and the supervisor's period,
/// one cycle old while the gait speeds up (107 steps where the angles repeat after 101), put
/// the replayed forces 1 N behind. Measured on 2026-12-06 (docs/RELIABILITY.md §2a), before →
/// now: a 200-ms NaN at 3.25 s 22.2 → 8.5 N, a 200-ms 30-N spike at 4.25 s 22.3 → 8.9 N, a
/// 60-ms NaN at 2.25 s 19.4 → 8.9 N (RMS 1.24 / 1.13 / 1.02× → ≤ 1.01×).
#[test]
fn force_faults_at_the_hip_reversal_beyond_the_scenario_payloads_are_ridden_through() {
    force_faults(
        3.0,
        &[
            (FaultKind::Nan, 3.25, 0.2, 12.0, 1.05),
            (FaultKind::Spike, 4.25, 0.2, 12.0, 1.05),
            (FaultKind::Nan, 2.25, 0.06, 12.0, 1.05),
        ],
    );
}

/// Issue 28, a lost strap-force sensor for a whole second at 2 kg: with `d̂` replayed and the
/// joint states following the measured angles, the gait goes on as in the clean run. Measured
/// on 2026-12-06 (the 1-s scan, docs/RELIABILITY.md §2a), before → now: a dropout at 4 s
/// 57.0 → 5.9 N (RMS 4.19 → 0.97×), a NaN at 5 s 46.0 → 5.9 N (2.05 → 1.03×).
#[test]
fn a_force_sensor_lost_for_a_second_is_ridden_through() {
    force_faults(
        2.0,
        &[
            (FaultKind::Dropout, 4.0, 1.0, 12.0, 1.1),
            (FaultKind::Nan, 5.0, 1.0, 12.0, 1.1),
        ],
    );
}

/// Issue 28, a strap force lost before the gait period is known (nothing to replay): while
/// every encoder is measured its estimate continues the forces of the last second at the gait
/// frequency of the angles, for [`FORCE_FIT_S`], then holds. It holds from the start with an
/// encoder lost at the fault's start, from the step an encoder is lost within the fault (and
/// is not continued again when the encoder is back), and for a strap whose fault began after
/// the continuation's first step. Before, it held from the start: here 5.6 N off after 0.29 s.
#[test]
fn a_force_lost_in_the_first_gait_period_follows_its_continuation() {
    let w = std::f64::consts::TAU * 0.9;
    let q = |t: f64| SVector::<f64, 2>::from([0.4 * (w * t).sin(), 0.3 * (1.0 - (w * t).cos())]);
    let f = |t: f64| {
        SVector::<f64, 2>::from([
            5.0 * (w * t + 0.5).sin() + 1.5 * (2.0 * w * t).cos(),
            4.0 * (w * t + 1.0).sin() - 1.0,
        ])
    };
    // The forces are lost from 1.3 s (step 130) for 0.4 s; the cases: the angles lost too from
    // the start, lost for 5 steps from the 10th step of the fault, the shank's force lost 3
    // steps after the thigh's.
    let fault_at = 130;
    let fit_steps = (FORCE_FIT_S / 0.01).round() as usize;
    #[derive(Clone, Copy, PartialEq)]
    enum Case {
        Encoders,
        AnglesLost,
        AnglesLostWithin,
        StrapsApart,
    }
    for case in [
        Case::Encoders,
        Case::AnglesLost,
        Case::AnglesLostWithin,
        Case::StrapsApart,
    ] {
        let mut guard = gait_guard();
        let mut prev = SVector::<f64, 2>::zeros();
        for k in 0..fault_at + 40 {
            let t = k as f64 * 0.01;
            let lost = [
                k >= fault_at,
                k >= fault_at + usize::from(case == Case::StrapsApart) * 3,
            ];
            let angles_lost = match case {
                Case::AnglesLost => k >= fault_at,
                Case::AnglesLostWithin => (fault_at + 10..fault_at + 15).contains(&k),
                _ => false,
            };
            let mut force = f(t);
            for j in 0..2 {
                if lost[j] {
                    force[j] = f64::NAN;
                }
            }
            let m = Measurement {
                t,
                q: if angles_lost {
                    SVector::repeat(f64::NAN)
                } else {
                    q(t)
                },
                qd: (q(t) - q(t - 0.04)) / 0.04,
                force,
            };
            let rep = guard.repair(&m, None, 50, None);
            let est = rep.m.force;
            if k < fault_at {
                assert!(!rep.any_rejected, "step {k}: a clean channel was rejected");
            }
            for j in 0..2 {
                if !lost[j] {
                    continue;
                }
                assert!(rep.estimated.force[j], "step {k}, strap {j}");
                let step = (est[j] - prev[j]).abs();
                let err = (est[j] - f(t)[j]).abs();
                let continued = match case {
                    Case::Encoders => k < fault_at + fit_steps,
                    Case::AnglesLost => false,
                    Case::AnglesLostWithin => k < fault_at + 10,
                    Case::StrapsApart => j == 0 && k < fault_at + fit_steps,
                };
                let first = k == fault_at + usize::from(case == Case::StrapsApart && j == 1) * 3;
                if continued {
                    assert!(
                        err <= 0.3,
                        "case {}, step {k}, strap {j}: {err:.3} N off",
                        case as u8
                    );
                } else if !first {
                    assert!(
                        step <= 1e-12,
                        "case {}, step {k}, strap {j}: moved {step:.3} N",
                        case as u8
                    );
                }
            }
            prev = est;
        }
    }
    // Holding, as before: the force's change over the continuation.
    let held_err = (f(1.29 + FORCE_FIT_S - 0.01) - f(1.29)).amax();
    assert!(held_err > 5.0, "{held_err:.2} N");
}

/// Issue 28, strap-force faults in the first gait period (no period known: `d̂` held, the
/// filters predicting only), cells of the fine scan (docs/RELIABILITY.md §2a) that failed
/// while the force estimate held: a 60-ms NaN of both forces at 1.5 s, 3 kg, and a 200-ms
/// dropout at 2 s, 2 kg, stay ≤ 12 N and ≤ 1.1× clean with no trip. Measured on 2026-12-06:
/// held, 35.4 N (RMS 1.51×) and 20.3 N (1.21×); the forces continued, 8.7 N (0.99×) and 5.9 N
/// (1.03×); `d̂` continued with them, 8.9 N (1.00×) and 7.2 N (1.01×).
#[test]
fn force_faults_in_the_first_gait_period_follow_the_forces_continuation() {
    force_faults(3.0, &[(FaultKind::Nan, 1.5, 0.06, 12.0, 1.1)]);
    force_faults(2.0, &[(FaultKind::Dropout, 2.0, 0.2, 12.0, 1.1)]);
}

/// The replay's lag is matched on the angles (`PERIOD_MATCH_STEPS`): on a gait whose frequency
/// rises (here 0.9 → 1.1 Hz over 4 s, the angles at 3 s repeating after 98 steps), with every
/// channel good (the lag matched every `PERIOD_MATCH_EVERY` steps, cached between), a
/// supervisor's period one cycle old (1.07 s) gives the lag at which the angles repeat, within
/// one step of the exact one, and a period of the right length is kept. While the history is
/// too short for the whole search range (after the first steps, and again after a gap in the
/// data, which restarts it) the lag is the supervisor's period.
#[test]
fn the_replay_lag_is_matched_on_the_angles() {
    // phase of a linear chirp f(t) = 0.9 + 0.05 t Hz
    let phase = |t: f64| std::f64::consts::TAU * (0.9 * t + 0.025 * t * t);
    let q = |t: f64| SVector::<f64, 2>::from([0.3 * phase(t).sin(), 0.5 * (1.0 - phase(t).cos())]);
    // Clean channels: the filtered velocity is the angle's slope over the 5-sample window.
    let m = |k: usize| {
        let t = k as f64 * 0.01;
        Measurement {
            t,
            q: q(t),
            qd: (q(t) - q(t - 0.04)) / 0.04,
            force: SVector::from([2.0 * phase(t).sin(), 3.0 * phase(t).cos()]),
        }
    };
    let lag_at = |guard: &mut ChannelGuard<2>, k: usize, period_s: f64| {
        let rep = guard.repair(&m(k), Some(period_s), 50, None);
        assert!(!rep.any_rejected, "step {k}: a clean channel was rejected");
        rep.estimated.period
    };
    // The exact lag at 3 s: phase(t) − phase(t − p) = 2π.
    let t = 3.0;
    let exact = (1..200)
        .min_by(|&a, &b| {
            let e =
                |p: usize| (phase(t) - phase(t - p as f64 * 0.01) - std::f64::consts::TAU).abs();
            e(a).total_cmp(&e(b))
        })
        .unwrap();
    for period_s in [1.07, exact as f64 * 0.01] {
        let p0 = (period_s / 0.01).round() as usize;
        let mut guard = gait_guard();
        let mut lag = None;
        for k in 0..=300 {
            lag = lag_at(&mut guard, k, period_s);
            if k == p0 + 10 {
                assert_eq!(
                    lag,
                    Some(p0),
                    "history of {k} steps: the supervisor's period"
                );
            }
        }
        let matched = lag.expect("a lag");
        assert!(
            matched.abs_diff(exact) <= 1,
            "period {period_s} s: lag {matched} steps, the angles repeat after {exact}"
        );
        // A gap of 50 ms restarts the history.
        for k in 306..=306 + p0 + 10 {
            lag = lag_at(&mut guard, k, period_s);
        }
        assert_eq!(lag, Some(p0), "after the gap: the supervisor's period");
    }
}

/// An angle spike while the velocity stays measured: the rejected angle is the one the
/// measured velocity implies through the filter window (within 0.01 rad of the true angle for
/// 200 ms), not the controller's model prediction (here 0.1 rad off, as a model outside its
/// payload scenarios drifts); it is handed to the controller as a measurement
/// (`q_from_velocity`) and, back within its gate, needs no restart of the estimators. A spike
/// believed after the resynchronisation (`resync_after` steps) comes back 0.5 rad off:
/// `resume` restarts them at the measurement. Before, the model's angle stood in (a 0.5-rad
/// spike on both angles at 5.3 s, 3 kg: 0.07 rad off after 200 ms, 37.0 N).
#[test]
fn an_angle_with_a_measured_velocity_follows_the_velocity() {
    for (steps, resync) in [(20usize, 50u64), (20, 10)] {
        let mut g = Gait::new();
        let mut guard = gait_guard();
        let mut resumed = false;
        for k in 0..330 {
            let clean = g.raw(k);
            let mut raw = clean;
            let spiked = (300..300 + steps).contains(&k);
            if spiked {
                raw.0.add_scalar_mut(0.5);
            }
            let m = g.measure(k, raw);
            let model = Some((clean.0.add_scalar(0.1), m.qd));
            let rep = guard.repair(&m, Some(1.0), resync, model);
            resumed |= rep.estimated.resume;
            if !spiked || rep.m.q == m.q {
                continue;
            }
            for j in 0..2 {
                assert!(rep.estimated.q[j] && rep.q_from_velocity[j], "step {k}");
                assert!(!rep.estimated.qd[j], "step {k}");
                let err = (rep.m.q[j] - clean.0[j]).abs();
                assert!(err < 0.01, "step {k} joint {j}: {err:.4} rad off");
            }
        }
        assert_eq!(
            resumed,
            resync < steps as u64,
            "spike of {steps} steps, resync {resync}"
        );
    }
}

/// Issue 28, one group at 3 kg: a 0.5-rad spike of both angles for 60 or 200 ms at 5.3 s keeps
/// the peak true strap force ≤ 12 N and the RMS ≤ 1.5× clean, without a monitor trip or a
/// latch (before: the model's angles stood in, 0.07 rad off after 200 ms, and the controller
/// swung on the return: 12.9 / 37.0 N, RMS 1.03 / 1.53×, a force-oscillation trip).
#[test]
fn an_angle_spike_at_3_kg_is_ridden_through() {
    let clean = scenario(ControllerKind::MSNMPC, 3.0, 10.0);
    let (_, rms0, _, _) = run(&clean);
    for dur in [0.06, 0.2] {
        let mut faulty = clean.clone();
        faulty.faults.events = fault(FaultKind::Spike, &ANGLES, 5.3, dur, 0.5);
        let (peak, rms, rep, _) = run(&faulty);
        assert!(peak <= 12.0, "{dur} s: peak {peak:.1} N");
        for i in 0..2 {
            assert!(rms[i] <= 1.5 * rms0[i], "{dur} s: RMS {rms:?} vs {rms0:?}");
        }
        assert_eq!(rep.monitor_trips, 0, "{dur} s: {:?}", rep.events);
        assert_eq!(rep.latched_at, None, "{dur} s");
    }
}

/// Both angles invalid (NaN) in the same sample while the velocities are measured: no stalled
/// acquisition (that needs a frozen angle), the velocities stay accepted and imply the angles
/// (within 0.01 rad for 200 ms). Before, NaN angles counted as a stall: the velocities were
/// rejected with them and every encoder was lost (a 60-ms NaN of both angles at 3.25 s, 3 kg:
/// 22.1 N, `a_nan_of_both_angles_at_3_kg_is_ridden_through`).
#[test]
fn invalid_angles_with_measured_velocities_are_no_stall() {
    let mut g = Gait::new();
    let mut guard = gait_guard();
    for k in 0..330 {
        let clean = g.raw(k);
        let mut raw = clean;
        let faulty = (300..320).contains(&k);
        if faulty {
            raw.0 = SVector::repeat(f64::NAN);
        }
        let m = g.measure(k, raw);
        let rep = guard.repair(&m, Some(1.0), 50, None);
        assert!(!rep.stalled, "step {k}");
        for j in 0..2 {
            assert!(
                !guard.is_rejected(1, j),
                "velocity {j} rejected at step {k}"
            );
            if faulty {
                assert!(rep.q_from_velocity[j], "angle {j} at step {k}");
                let err = (rep.m.q[j] - clean.0[j]).abs();
                assert!(err <= 0.01, "angle {j} at step {k}: {err:.4} rad off");
            }
        }
    }
}

/// One sample of a channel guard's run on the test gait: the true filtered strap force, the
/// measurement handed to the guard and its repair.
struct ForceSample {
    true_f: SVector<f64, 2>,
    m: Measurement<2>,
    rep: Repaired<2>,
}

/// A channel guard over `steps` samples of the test gait, each raw strap force `k` changed by
/// `world(k, &mut force)` (the true force) and then by `fault(k, &mut force)` (the sensor's
/// fault), the gait period `period(k)` (s) and resynchronisation after `resync_after` steps.
fn force_fault_run(
    steps: usize,
    world: impl Fn(usize, &mut SVector<f64, 2>),
    fault: impl Fn(usize, &mut SVector<f64, 2>),
    period: impl Fn(usize) -> f64,
    resync_after: u64,
) -> Vec<ForceSample> {
    let mut g = Gait::new();
    let mut guard = gait_guard();
    let mut truth = MovingAverage::<2>::new(5);
    (0..steps)
        .map(|k| {
            let mut raw = g.raw(k);
            world(k, &mut raw.2);
            let true_f = truth.push(raw.2);
            fault(k, &mut raw.2);
            let m = g.measure(k, raw);
            let rep = guard.repair(&m, Some(period(k)), resync_after, None);
            ForceSample { true_f, m, rep }
        })
        .collect()
}

/// The largest step `|x(k) − x(k − 1)|` of each prefix of `xs` (0 for the first).
fn largest_steps(xs: impl Iterator<Item = SVector<f64, 2>>) -> Vec<f64> {
    let mut prev = None::<SVector<f64, 2>>;
    let mut largest: f64 = 0.0;
    xs.map(|x| {
        if let Some(p) = prev {
            largest = largest.max((x - p).amax());
        }
        prev = Some(x);
        largest
    })
    .collect()
}

/// A force replayed over more than one gait period repeats the gait before the fault with one
/// offset, the one it had when the replay began: the replay does not extrapolate the change of
/// the period before the fault. The force rises by 5 N half a period before the fault. For its
/// first `FORCE_FIT_S` the estimate follows the forces' continuation (fitted across the rise);
/// the replay then starts there: through its first period it is the period before the fault
/// plus one offset (here 0.3 N or more), and from the second period on it repeats itself
/// (`F̂(k) − F̂(k − p)` = 0). Adding the offset again every period extrapolated it; without
/// it the replay stepped where it began.
#[test]
fn a_replay_over_several_periods_adds_its_offset_once() {
    let p = 100;
    let run = force_fault_run(
        560,
        |k, f| {
            if k >= 250 {
                f.add_scalar_mut(5.0);
            }
        },
        |k, f| {
            if (300..550).contains(&k) {
                *f = SVector::repeat(f64::NAN);
            }
        },
        |_| 1.0,
        50,
    );
    let est = |k: usize| run[k].rep.m.force;
    for (k, s) in run.iter().enumerate().take(550).skip(300) {
        assert!(s.rep.estimated.force.iter().all(|&e| e), "step {k}");
    }
    let replay_from = 300 + (FORCE_FIT_S / 0.01).round() as usize;
    // The replay begins continuous with the continuation, one offset above the period before.
    let offset = est(replay_from) - est(replay_from - p);
    let start_step = (est(replay_from) - est(replay_from - 1)).amax();
    assert!(offset.amax() >= 0.3, "offset {offset:?}: nothing to test");
    assert!(
        start_step <= 0.35,
        "the replay stepped by {start_step:.3} N where it began"
    );
    // Through its first period (while the period back is measured): that offset.
    for k in replay_from..300 + p {
        let moved = (est(k) - est(k - p) - offset).amax();
        assert!(moved <= 1e-9, "step {k}: the offset moved by {moved:.3} N");
    }
    // From the second period on: the first, repeated.
    for k in replay_from + p..550 {
        let again = (est(k) - est(k - p)).amax();
        assert!(again <= 1e-9, "step {k}: {again:.3} N added a period later");
    }
}

/// A new gait-period estimate within a replay (the supervisor's gait frequency is updated at
/// each upward crossing) restarts the replay where it is: the force estimate does not step.
/// Before, the offset taken for the old period stayed against the new lag: a 200-ms force
/// spike at 3.25 s, 3 kg (the fine phase scan), saw the period go from 107 to 101 steps
/// within the fault and the estimated forces step by 3 N.
#[test]
fn a_new_gait_period_within_a_replay_does_not_step_it() {
    let run = force_fault_run(
        400,
        |_, _| {},
        |k, f| {
            if (300..360).contains(&k) {
                *f = SVector::repeat(f64::NAN);
            }
        },
        // The gait-frequency estimate moves from 1 s to 0.94 s 40 steps into the fault, 10
        // into the replay (the forces' continuation runs for the first `FORCE_FIT_S`).
        |k| if k < 340 { 1.0 } else { 0.94 },
        50,
    );
    for (k, s) in run.iter().enumerate().take(360).skip(300) {
        assert!(s.rep.estimated.force.iter().all(|&e| e), "step {k}");
    }
    let true_step = *largest_steps(run.iter().map(|s| s.true_f)).last().unwrap();
    let est_step = *largest_steps(run[300..360].iter().map(|s| s.rep.m.force))
        .last()
        .unwrap();
    assert!(
        est_step <= 1.2 * true_step,
        "the estimate stepped by {est_step:.3} N, the force by at most {true_step:.3} N"
    );
}

/// A strap force believed on smoothness alone after [`FORCE_RESYNC_S`] (a 30-N offset on both
/// forces that lasts) starts at the estimate that stood in for it and moves to the
/// measurement at [`FORCE_BIAS_RATE`], then follows the measurement.
#[test]
fn a_force_believed_on_smoothness_alone_is_taken_in_at_the_bias_rate() {
    let run = force_fault_run(
        500,
        |_, _| {},
        |k, f| {
            if k >= 300 {
                f.add_scalar_mut(30.0);
            }
        },
        |_| 1.0,
        1000,
    );
    // The true force's largest step up to each sample.
    let true_step = largest_steps(run.iter().map(|s| s.true_f));
    let mut believed_at = None;
    for (k, s) in run.iter().enumerate().skip(300) {
        let measured = !s.rep.estimated.force.iter().any(|&e| e);
        if measured && believed_at.is_none() {
            believed_at = Some(k);
        }
        if k > 300 {
            let step = (s.rep.m.force - run[k - 1].rep.m.force).amax();
            let bound = FORCE_BIAS_RATE * 0.01 + true_step[k] + 0.05;
            assert!(
                step <= bound,
                "step {k}: the force moved {step:.2} N (≤ {bound:.2})"
            );
        }
        if let Some(b) = believed_at {
            // 30 N at the bias rate, and a few samples of margin.
            if k >= b + (30.0 / (FORCE_BIAS_RATE * 0.01)) as usize + 5 {
                let err = (s.rep.m.force - s.m.force).amax();
                assert!(err <= 1e-9, "step {k}: {err:.3} N off the measurement");
            }
        }
    }
    let b = believed_at.expect("the offset force is believed");
    let after = (b - 300) as f64 * 0.01;
    assert!(
        (FORCE_RESYNC_S - 0.011..=FORCE_RESYNC_S + 0.1).contains(&after),
        "believed after {after:.2} s"
    );
}

/// Issue 28, faults of 1 s: a 30-N spike of both forces for 1 s from 1 s at 1 kg (the first
/// gait period) stays within the 70-N goal with no latch (before the force's jump was taken in
/// at [`FORCE_BIAS_RATE`], the offset believed after 0.3 s stepped the controller: 189.0 N).
#[test]
fn a_one_second_force_spike_in_the_first_gait_period_stays_within_70_n() {
    let mut s = scenario(ControllerKind::MSNMPC, 1.0, 4.0);
    s.faults.events = fault(
        FaultKind::Spike,
        &[Channel::F1, Channel::F2],
        1.0,
        1.0,
        30.0,
    );
    let (peak, _, rep, _) = run(&s);
    assert!(peak <= 70.0, "peak {peak:.1} N");
    assert_eq!(rep.latched_at, None);
}

/// Issue 28, a fault of 1 s: every sensor's spike (0.5 rad, 0.5 rad/s, 30 N) from 1 s at 2 kg,
/// a cell of the 1-s scan, stays within 70 N without a latch. The monitors hand the torque to
/// the transparent fallback, which is not fed while its angles are estimated: it then demands
/// no torque and the response ramps to zero until it is fed again. Its stale last demand,
/// held, kept 25 N·m on the hip for 0.3 s while the leg moved on: 76.1 N in this run (75.7 N
/// in the scan's 10-s run; measured on 2026-12-05).
#[test]
fn an_unfed_fallback_demands_no_torque() {
    every_sensor_spiked_for_a_second_from_1_s(2.0, 4.0);
}

/// Issue 28, every sensor at 2 kg: a stuck or dropped-out sensor set for 200 ms at 5.25 s (a
/// cell of the fine phase scan) is ridden through within one group's goal (before, the gait
/// replay stepped where the period estimate changed within the fault: peak 17.9 N, RMS
/// 1.54× clean).
#[test]
fn every_sensor_stuck_at_5_25_s_at_2_kg_is_ridden_through() {
    one_group_cell_meets_the_goal(2.0, FaultKind::Stuck, &Channel::ALL, 5.25, 0.2);
}

/// Issue 28, one group at 3 kg: a 60-ms NaN of both angles at 3.25 s (a cell of the fine
/// phase scan) is ridden through on the angles the measured velocities imply: peak true strap
/// force ≤ 12 N, RMS ≤ 1.5× clean, no monitor trip or latch (before, as a stalled acquisition
/// with every encoder lost and the torque replayed: 22.1 N).
#[test]
fn a_nan_of_both_angles_at_3_kg_is_ridden_through() {
    one_group_cell_meets_the_goal(3.0, FaultKind::Nan, &ANGLES, 3.25, 0.06);
}

/// Issue 28, every encoder lost: the torque blends from the applied one into the replay of
/// one gait period back over `REPLAY_BLEND_IN_STEPS` instead of stepping there at the rate
/// limit. A cell of the fine phase scan meets one group's goal with it: a 60-ms stuck pair of
/// angles (a stall: every encoder lost) at 3.25 s, 1 kg (12.1 N before; measured on
/// 2026-12-05). The blend took a second cell, at 2.25 s, 3 kg, from 13.1 to 11.3 N; with the
/// torque replayed at the channel guard's lag it is 13.0 N (docs/RELIABILITY.md §2).
#[test]
fn the_torque_blends_into_its_replay() {
    one_group_cell_meets_the_goal(1.0, FaultKind::Stuck, &ANGLES, 3.25, 0.06);
}

/// Issue 28, every encoder lost at 3 kg: the supervisor replays the torque one gait period back
/// at the channel guard's lag, where the angles repeat (`PERIOD_MATCH_STEPS`). A 60-ms
/// dropout and a 200-ms stuck pair of angles at 3.25 s (a stall: cells of the fine phase scan)
/// meet one group's goal (at the supervisor's gait period, one cycle old, the replayed hip
/// torque rose while the leg's fell: 19.1 / 17.0 N, measured on 2026-12-06).
///
/// The cell it costs, a 60-ms stuck pair at 2.25 s, 3 kg (11.3 → 13.0 N), stays within 14 N,
/// without a trip or latch.
#[test]
fn the_torque_replays_at_the_lag_where_the_angles_repeat() {
    one_group_cell_meets_the_goal(3.0, FaultKind::Dropout, &ANGLES, 3.25, 0.06);
    one_group_cell_meets_the_goal(3.0, FaultKind::Stuck, &ANGLES, 3.25, 0.2);
    let mut s = scenario(ControllerKind::MSNMPC, 3.0, 10.0);
    s.faults.events = fault(FaultKind::Stuck, &ANGLES, 2.25, 0.06, 0.0);
    let (peak, _, rep, _) = run(&s);
    assert!(peak <= 14.0, "peak {peak:.1} N");
    assert_eq!(rep.monitor_trips, 0, "{:?}", rep.events);
    assert_eq!(rep.latched_at, None);
}

/// The issue's goal for one channel group on the 10-s MS-NMPC run at `payload` kg with a
/// fault `kind` on `channels` from `start` s for `dur` s: peak true strap force ≤ 12 N, RMS
/// ≤ 1.5× the clean run's, no monitor trip, no latch.
fn one_group_cell_meets_the_goal(
    payload: f64,
    kind: FaultKind,
    channels: &[Channel],
    start: f64,
    dur: f64,
) {
    let clean = scenario(ControllerKind::MSNMPC, payload, 10.0);
    let (_, rms0, _, _) = run(&clean);
    let mut faulty = clean.clone();
    faulty.faults.events = fault(kind, channels, start, dur, 0.0);
    let (peak, rms, rep, _) = run(&faulty);
    assert!(peak <= 12.0, "peak {peak:.1} N");
    for i in 0..2 {
        assert!(rms[i] <= 1.5 * rms0[i], "RMS {rms:?} vs {rms0:?}");
    }
    assert_eq!(rep.monitor_trips, 0, "{:?}", rep.events);
    assert_eq!(rep.latched_at, None);
}

/// Issue 28, the velocities at 1 kg: a 60-ms dropout of both velocities at 3.5 s (a cell of the
/// fine phase scan) keeps the peak true strap force ≤ 12 N and the RMS ≤ 1.5× clean without a
/// trip. The filtered velocity ramps back from the frozen reading after the fault; it is
/// accepted again only within `SLOPE_ACCEPT_GATES` of the angle's slope (before, within
/// `ACCEPT_GATES`: accepted 0.17 rad/s off, and the controller pushed on it: 18.1 N).
#[test]
fn a_velocity_dropout_is_not_accepted_on_its_ramp_back() {
    one_group_cell_meets_the_goal(1.0, FaultKind::Dropout, &VELOCITIES, 3.5, 0.06);
}

/// A frozen raw velocity (a dropout for 60 ms) is accepted again only within
/// `SLOPE_ACCEPT_GATES` gates of the angle's mean slope over the filter window, from above and
/// from below: the filtered velocity's ramp back from the frozen reading is not taken for the
/// velocity (with `ACCEPT_GATES`, 4 gates, it was, 0.17 rad/s off).
#[test]
fn a_frozen_velocity_is_accepted_again_only_near_the_angles_slope() {
    let mut accepted = 0;
    for start in [300, 310, 325, 340, 360, 375] {
        let mut g = Gait::new();
        let mut guard = gait_guard();
        let held = g.raw(start - 1).1;
        let mut qs = Vec::new();
        let mut was = [false; 2];
        for k in 0..start + 40 {
            let mut raw = g.raw(k);
            if (start..start + 6).contains(&k) {
                raw.1 = held;
            }
            qs.push(raw.0);
            let m = g.measure(k, raw);
            guard.repair(&m, Some(1.0), 50, None);
            for j in 0..2 {
                let bad = guard.is_rejected(1, j);
                if was[j] && !bad {
                    accepted += 1;
                    let slope = (qs[k][j] - qs[k - 4][j]) / 0.04;
                    let off = (m.qd[j] - slope).abs();
                    assert!(
                        off <= SLOPE_ACCEPT_GATES * VELOCITY_GATE + 1e-9,
                        "start {start}, joint {j}: accepted at step {k}, {off:.3} rad/s off the slope"
                    );
                }
                was[j] = bad;
            }
        }
    }
    assert!(accepted >= 6, "only {accepted} re-acceptances");
}

/// Issue 28: after a fault of both the angle and the velocity of a joint, the velocity (still
/// lost) is taken from the returning angles as soon as three are accepted: their slope, moved
/// back by the filter's lag (`PARTIAL_SLOPE_SPAN`), a measurement that a model-based estimator
/// may update with. Before, it was the controller's model prediction (here a wrong one, zero)
/// until the filter window held accepted angles only. The angles that stood in during the
/// fault (the model's, 0.03 rad off) stay out of the slope.
#[test]
fn a_velocity_is_taken_from_the_returning_angles() {
    let mut g = Gait::new();
    let mut clean_qd = MovingAverage::<2>::new(5);
    let mut guard = gait_guard();
    let mut worst: f64 = 0.0;
    for k in 0..340 {
        let clean = g.raw(k);
        let qd_clean = clean_qd.push(clean.1);
        let mut raw = clean;
        if (300..320).contains(&k) {
            raw.0 = SVector::repeat(f64::NAN);
        }
        if (300..328).contains(&k) {
            raw.1 = SVector::repeat(f64::NAN);
        }
        let m = g.measure(k, raw);
        // The model's angle is off too: a slope that reached back to an estimate would show it.
        let model = Some((clean.0.add_scalar(0.03), SVector::zeros()));
        let rep = guard.repair(&m, None, 50, model);
        if !(320..332).contains(&k) {
            continue;
        }
        for j in 0..2 {
            assert!(!rep.estimated.q[j], "step {k}");
            assert_eq!(rep.estimated.qd[j], k < 322, "step {k} joint {j}");
            if k >= 322 {
                let err = (rep.m.qd[j] - qd_clean[j]).abs();
                worst = worst.max(err);
            }
        }
    }
    assert!(worst < 0.02, "{worst:.4} rad/s off");
}

/// With a filter window of one sample the angle's slope spans one period: on the first accepted
/// angle after a fault of both encoders it would reach back to the estimate that stood in for
/// the angle (here the model's, 0.03 rad off: a 3-rad/s error). The slope waits for a second
/// accepted angle (then it is the velocity's measurement); until then the lost velocity keeps
/// its estimate (here the model's, 0.1 rad/s off).
#[test]
fn a_one_sample_window_takes_no_slope_from_an_estimated_angle() {
    let mut g = Gait::new();
    g.qd_f = MovingAverage::new(1);
    g.f_f = MovingAverage::new(1);
    let mut guard = ChannelGuard::<2>::new(0.01, 1, [std::f64::consts::PI, 30.0, 70.0]);
    let mut checked = 0;
    for k in 0..330 {
        let clean = g.raw(k);
        let mut raw = clean;
        if (300..320).contains(&k) {
            raw.0 = SVector::repeat(f64::NAN);
        }
        if (300..324).contains(&k) {
            raw.1 = SVector::repeat(f64::NAN);
        }
        let m = g.measure(k, raw);
        let model_qd = clean.1.add_scalar(0.1);
        let model = Some((clean.0.add_scalar(0.03), model_qd));
        let rep = guard.repair(&m, None, 50, model);
        if (320..324).contains(&k) {
            for j in 0..2 {
                assert!(!rep.estimated.q[j], "step {k}");
                assert_eq!(rep.estimated.qd[j], k == 320, "step {k} joint {j}");
                if k == 320 {
                    assert_eq!(rep.m.qd[j], model_qd[j], "joint {j}");
                } else {
                    let err = (rep.m.qd[j] - clean.1[j]).abs();
                    assert!(err < 0.2, "step {k} joint {j}: {err:.3} rad/s off");
                }
                checked += 1;
            }
        }
    }
    assert_eq!(checked, 8);
}

/// After a gap in the data (the runtime steps nothing in a period without a sample) the angle's
/// slope counts the angles kept since: a velocity lost two samples after it is taken from the
/// slope over those (`PARTIAL_SLOPE_SPAN`), not from one over the filter window that spans
/// the gap as if it were one period (here 0.1 s: 6 rad/s off).
#[test]
fn a_slope_does_not_reach_across_a_gap_in_the_data() {
    let mut g = Gait::new();
    let mut clean_qd = MovingAverage::<2>::new(5);
    let mut guard = gait_guard();
    let mut worst: f64 = 0.0;
    for k in 0..330 {
        let clean = g.raw(k);
        let qd_clean = clean_qd.push(clean.1);
        let mut raw = clean;
        if (312..315).contains(&k) {
            raw.1 = SVector::repeat(f64::NAN);
        }
        let m = g.measure(k, raw);
        if (300..310).contains(&k) {
            continue;
        }
        let rep = guard.repair(&m, None, 50, None);
        if (312..320).contains(&k) {
            assert!(rep.ready, "step {k}");
            for j in 0..2 {
                assert!(!rep.estimated.q[j] && !rep.estimated.qd[j], "step {k}");
                let err = (rep.m.qd[j] - qd_clean[j]).abs();
                worst = worst.max(err);
            }
        }
    }
    assert!(worst < 0.05, "{worst:.3} rad/s off");
}

/// Quantised encoders. The T-Motor AK's MIT-mode reply (16-bit position over ±12.5 rad:
/// 0.38 mrad; 12-bit velocity over ±50 rad/s: 24 mrad/s, docs/HARDWARE.md): no channel is
/// rejected on a clean run, nor after a fault of both angles (the velocities measured), when
/// the velocity is judged against the returning angles' slope (`PARTIAL_SLOPE_SPAN`, over two
/// periods). A 12-bit encoder per turn (1.53 mrad): its angle repeats where the leg turns, and
/// is taken for frozen unless the guard knows the step (`[monitors] encoder_step_rad`,
/// [`ChannelGuard::with_encoder_step`]); knowing it, a stuck angle is still rejected in the
/// same sample while the leg swings.
#[test]
fn quantised_encoders_are_not_taken_for_frozen() {
    let ak = 25.0 / 65535.0;
    let turn12 = 2.0 * std::f64::consts::PI / 4096.0;
    let qd_step = 100.0 / 4095.0;
    let quantise = |x: SVector<f64, 2>, step: f64| x.map(|v| (v / step).round() * step);
    // Rejected samples outside the faults, and the delay until a stuck angle is rejected.
    let run = |q_step: f64, known: f64, nan_angles: bool, stuck_at: Option<usize>| {
        let mut g = Gait::new();
        let guard = gait_guard();
        let mut guard = guard.with_encoder_step(known);
        let (mut rejected, mut delay) = (0, None);
        let mut held = SVector::<f64, 2>::zeros();
        for k in 0..600 {
            let clean = g.raw(k);
            let mut raw = (
                quantise(clean.0, q_step),
                quantise(clean.1, qd_step),
                clean.2,
            );
            let nan = nan_angles && (300..320).contains(&k);
            if nan {
                raw.0 = SVector::repeat(f64::NAN);
            }
            let stuck = stuck_at.is_some_and(|s| k >= s);
            if stuck_at == Some(k) {
                held = raw.0;
            }
            if stuck {
                raw.0 = held;
            }
            let m = g.measure(k, raw);
            let rep = guard.repair(&m, None, 50, None);
            if stuck && delay.is_none() && rep.estimated.q[0] {
                delay = Some(k - stuck_at.unwrap());
            }
            if k > 10 && !nan && !stuck && rep.any_rejected {
                rejected += 1;
            }
        }
        (rejected, delay)
    };
    assert_eq!(run(ak, 0.0, false, None).0, 0);
    assert_eq!(run(ak, 0.0, true, None).0, 0);
    assert!(run(turn12, 0.0, false, None).0 > 0);
    assert_eq!(run(turn12, turn12, false, None).0, 0);
    assert_eq!(run(turn12, turn12, true, None).0, 0);
    // Stuck from mid-swing of the hip (k = 400: 2.5 rad/s) until the end of the run.
    assert_eq!(run(turn12, turn12, false, Some(400)).1, Some(1));
    // Both joints slow at once (0.1 rad/s: both angles repeat on the same samples), which
    // the stall test, knowing the step, does not take for a stalled acquisition.
    for known in [0.0, turn12] {
        let guard = gait_guard();
        let mut guard = guard.with_encoder_step(known);
        let (mut stalls, mut rejected) = (0, 0);
        for k in 0..300 {
            let t = k as f64 * 0.01;
            let m = Measurement {
                t,
                q: quantise(SVector::from([0.1 * t, 0.1 * t - 300.0 * turn12]), turn12),
                qd: SVector::repeat(0.1),
                force: SVector::from([1.0 + (3.0 * t).sin(), 2.0 + (3.0 * t).cos()]),
            };
            let rep = guard.repair(&m, None, 50, None);
            stalls += usize::from(rep.stalled);
            rejected += usize::from(k > 10 && rep.any_rejected);
        }
        assert_eq!(
            stalls > 0 && rejected > 0,
            known == 0.0,
            "known step {known}"
        );
    }
}

/// Turns between two samples, on a CiA 402 drive's encoder (4096 increments behind 50:1:
/// 0.03 mrad, known to the guard as `exompc run` sets it) and velocity (1 rpm at the motor:
/// 2.1 mrad/s). With the gait shifted by half a period, each joint turns midway between two
/// samples: the angle repeats there while the filtered velocity, lagging two samples, still
/// moves (0.3 rad/s). That is no frozen angle: no channel is rejected (before: 12 samples in
/// 6 s). A frozen angle is still rejected on its first repeat mid-swing and on its second at
/// a turn. A filtered velocity that repeats once (the raw sample entering its window equal to
/// the one leaving it, as a quantised velocity does at its extremes; once in 10 s on the CiA
/// 402 loop) is not frozen either; a frozen one is rejected on its second repeat at an
/// extreme (where the velocity check cannot see it yet), and within 3 samples where the
/// velocity changes fastest (the stated delay).
#[test]
fn a_turn_between_two_samples_is_not_a_frozen_encoder() {
    let q_step = 2.0 * std::f64::consts::PI / (4096.0 * 50.0);
    let qd_step = 2.0 * std::f64::consts::PI / 60.0 / 50.0;
    let quantise = |x: SVector<f64, 2>, step: f64| x.map(|v| (v / step).round() * step);
    // Rejected samples outside the fault, and the delay until the channel is rejected; with
    // `held_qd = (from, to)`, the hip's filtered velocity repeats the value before `from` on
    // the samples `from..=to` (a fault when `to > from`).
    let run = |stuck: Option<(usize, usize)>, held_qd: Option<(usize, usize)>| {
        let mut g = Gait::new();
        let mut guard = gait_guard().with_encoder_step(q_step);
        let (mut rejected, mut delay) = (0, None);
        let mut held = (SVector::<f64, 2>::zeros(), SVector::<f64, 2>::zeros());
        let mut last_qd = f64::NAN;
        for k in 0..600 {
            // Half a period late: the turns fall midway between samples.
            let clean = g.raw_at(k as f64 * g.dt - 0.005);
            let mut raw = (
                quantise(clean.0, q_step),
                quantise(clean.1, qd_step),
                clean.2,
            );
            let qd_held = held_qd.is_some_and(|(from, to)| (from..=to).contains(&k));
            let faulty = stuck.is_some_and(|(_, at)| k >= at)
                || (qd_held && held_qd.is_some_and(|(from, to)| to > from));
            if let Some((sig, at)) = stuck {
                if k == at {
                    held = (raw.0, raw.1);
                }
                if faulty {
                    match sig {
                        0 => raw.0[0] = held.0[0],
                        _ => raw.1[0] = held.1[0],
                    }
                }
            }
            let mut m = g.measure(k, raw);
            if qd_held {
                m.qd[0] = last_qd;
            }
            last_qd = m.qd[0];
            guard.repair(&m, None, 50, None);
            let (sig, at) = match (stuck, held_qd) {
                (Some(s), _) => s,
                (None, Some((from, _))) => (1, from),
                _ => (0, 0),
            };
            if faulty && delay.is_none() && guard.is_rejected(sig, 0) {
                delay = Some(k - at);
            }
            let any = (0..3).any(|s| (0..2).any(|j| guard.is_rejected(s, j)));
            if k > 10 && !faulty && any {
                rejected += 1;
            }
        }
        (rejected, delay)
    };
    assert_eq!(run(None, None).0, 0, "rejected on a clean run");
    // The hip turns midway between samples 25 and 26 (0.255 s) and swings fastest at 0.505 s;
    // the held value repeats from the sample after `at`.
    assert_eq!(run(Some((0, 50)), None).1, Some(1), "stuck angle mid-swing");
    assert_eq!(
        run(Some((0, 125)), None).1,
        Some(2),
        "stuck angle at a turn"
    );
    // The hip's velocity peaks midway between samples 100 and 101.
    assert_eq!(
        run(None, Some((101, 101))).0,
        0,
        "a filtered velocity repeated once"
    );
    // Frozen from there: its first repeat at 101, its second at 102.
    assert_eq!(
        run(None, Some((101, 599))).1,
        Some(1),
        "a frozen filtered velocity at its extreme"
    );
    // Stuck where the hip's velocity changes fastest (its turn at 0.755 s).
    let qd = run(Some((1, 75)), None).1;
    assert!(qd.is_some_and(|d| d <= 3), "stuck velocity: {qd:?}");
}

/// After a gap the guard keeps no sample in its history while a channel is rejected (nothing
/// to compare with yet): those samples do not count towards the angle's slope either. Here a
/// strap force is NaN on the first sample after a 0.1-s gap (its filtered value for five), and
/// a velocity lost on the second kept sample is the model's estimate there, not a slope
/// reaching back before the gap (8.5 rad/s off), and the kept angles' slope from the third
/// kept sample on.
#[test]
fn samples_the_guard_does_not_keep_do_not_count_towards_the_slope() {
    let mut g = Gait::new();
    let mut clean_qd = MovingAverage::<2>::new(5);
    let mut guard = gait_guard();
    let mut kept_from = None;
    for k in 0..330 {
        let clean = g.raw(k);
        let qd_clean = clean_qd.push(clean.1);
        let mut raw = clean;
        if k == 310 {
            raw.2 = SVector::repeat(f64::NAN);
        }
        if k == 316 {
            raw.1 = SVector::repeat(f64::NAN);
        }
        let m = g.measure(k, raw);
        if (300..310).contains(&k) {
            continue;
        }
        let model = Some((clean.0, qd_clean.add_scalar(0.1)));
        let rep = guard.repair(&m, None, 50, model);
        if k >= 310 && rep.ready && kept_from.is_none() {
            kept_from = Some(k);
        }
        // The velocity's filter holds the NaN from 316 to 320.
        if (316..321).contains(&k) {
            for j in 0..2 {
                if k == 316 {
                    assert!(rep.estimated.qd[j], "joint {j}");
                    assert_eq!(rep.m.qd[j], qd_clean[j] + 0.1, "joint {j}");
                } else {
                    assert!(!rep.estimated.qd[j], "step {k} joint {j}");
                    let err = (rep.m.qd[j] - qd_clean[j]).abs();
                    assert!(err < 0.05, "step {k} joint {j}: {err:.3} rad/s off");
                }
            }
        }
    }
    assert_eq!(kept_from, Some(315));
}

/// Issue 28, one group at 2 kg: a 200-ms stuck or dropped pair of angles at 1.25 s (a stall in
/// the first gait period: cells of the fine phase scan) meets one group's goal. On the
/// angles' return the knee's velocity failed its gate, and the model's velocity (2 rad/s off)
/// stood in for it until the filter window held measured angles only: the torque stepped and
/// the shank strap, rejected for 0.26 s, reached 27.1 / 27.0 N (measured on 2026-12-06). Now
/// the returning angles' slope stands in (`PARTIAL_SLOPE_SPAN`).
#[test]
fn an_angle_stall_in_the_first_gait_period_resumes_on_the_angles_slope() {
    for kind in [FaultKind::Stuck, FaultKind::Dropout] {
        one_group_cell_meets_the_goal(2.0, kind, &ANGLES, 1.25, 0.2);
    }
}

/// What [`frozen_force_return`] sees of a force accepted again.
#[derive(Debug)]
struct ForceReturn {
    /// The output and the measurement on the step the force is accepted again.
    out: f64,
    v: f64,
    /// The output's step there (from the estimate of the step before).
    first_step: f64,
    /// The largest step of the output from then on, less the largest step of the measurement.
    excess_step: f64,
    /// Steps after the acceptance until the output equals the measurement.
    settle: usize,
}

/// The guard alone (a 1-Hz sine gait, the gait period given): strap 2's raw force stuck for
/// `steps` samples from step 300, then live again, until the output equals the measurement.
fn frozen_force_return(steps: usize) -> ForceReturn {
    let mut g = Gait::new();
    let mut guard = gait_guard();
    let mut back: Option<(usize, ForceReturn)> = None;
    let (mut prev_out, mut prev_v, mut max_v_step) = (f64::NAN, f64::NAN, 0.0_f64);
    let stuck = g.raw(299).2[1];
    for k in 0..300 + steps + 100 {
        let mut raw = g.raw(k);
        if (300..300 + steps).contains(&k) {
            raw.2[1] = stuck;
        }
        let m = g.measure(k, raw);
        let was_rejected = guard.is_rejected(2, 1);
        let rep = guard.repair(&m, Some(1.0), 50, None);
        let (out, v) = (rep.m.force[1], m.force[1]);
        match back.as_mut() {
            None if k > 300 && was_rejected && !guard.is_rejected(2, 1) => {
                let r = ForceReturn {
                    out,
                    v,
                    first_step: (out - prev_out).abs(),
                    excess_step: 0.0,
                    settle: 0,
                };
                if out == v {
                    return r;
                }
                back = Some((k, r));
            }
            Some((k0, r)) => {
                max_v_step = max_v_step.max((v - prev_v).abs());
                r.excess_step = r.excess_step.max((out - prev_out).abs() - max_v_step);
                if out == v {
                    r.settle = k - *k0;
                    return back.unwrap().1;
                }
            }
            None => {}
        }
        (prev_out, prev_v) = (out, v);
    }
    panic!("{steps} stuck samples: not accepted again, or never at its measurement: {back:?}");
}

/// Issue 28: a strap force accepted again within `FORCE_RESYNC_S` of a frozen fault (a stuck
/// or dropped-out sensor) starts at its estimate and takes the difference in at
/// `FORCE_BIAS_RATE`: the filtered force still averages frozen samples, and its ramp back is
/// accepted where it passes the estimate. After a longer fault it is believed at once.
#[test]
fn a_force_back_from_a_short_frozen_fault_is_taken_in_from_its_estimate() {
    let dt = 0.01;
    let r = frozen_force_return(20);
    let jump = (r.v - r.out).abs();
    eprintln!("{r:?}");
    assert!(jump > 0.05, "200 ms: accepted at its measurement: {r:?}");
    // It starts where its estimate stood (the gait moves the force by at most 0.32 N a step)
    // and never steps by more than the measurement does plus the bias rate.
    assert!(r.first_step <= 0.35 && r.first_step < 0.5 * jump, "{r:?}");
    assert!(r.excess_step <= FORCE_BIAS_RATE * dt + 1e-9, "{r:?}");
    let bound = (jump / (FORCE_BIAS_RATE * dt)).ceil() as usize + 1;
    assert!(
        r.settle <= bound,
        "200 ms: {} steps to the measurement, > {bound}",
        r.settle
    );
    let long = (FORCE_RESYNC_S / dt) as usize + 10;
    let r = frozen_force_return(long);
    assert!(
        r.out == r.v && r.settle == 0,
        "{long} samples: not believed at once: {r:?}"
    );
}

/// Issue 28, the closed loop at 3 kg: a 200-ms dropout and a stuck value of both strap forces
/// at 3.5 s (the fine scan's cells). Accepted at once on the filter's ramp back, the hip
/// torque swung from −13.6 to +11.0 N·m in 3 steps: 14.8 / 14.4 N; taken in from the estimate
/// 10.3 / 10.2 N (measured on 2026-12-06).
#[test]
fn a_strap_force_back_from_a_frozen_fault_at_3_kg_does_not_swing_the_torque() {
    force_faults(
        3.0,
        &[
            (FaultKind::Dropout, 3.5, 0.2, 12.0, 1.05),
            (FaultKind::Stuck, 3.5, 0.2, 12.0, 1.05),
        ],
    );
}

/// With the gait period known, a rejected strap force's estimate over its continuation
/// (`FORCE_FIT_S`) is `(1 − w) · continuation + w · replay` (`FORCE_REPLAY_WEIGHT`), the replay
/// the force one period back with its offset at the fault's start; without the period, the
/// continuation alone; after the continuation, the replay, continuous with the blend. The
/// force drifts by 2 N/s on top of the gait: the replay carries the drift, the continuation (no
/// trend term) does not, so the two differ. The blend is checked on every step where the
/// continuation without the period lies inside the range of the fitted forces (there the range
/// margin, `FORCE_RANGE_MARGIN`, makes no difference); on every step the continuation the
/// blend implies lies within that range widened by the margin.
#[test]
fn with_the_period_known_a_force_estimate_blends_the_continuation_with_the_replay() {
    let (start, p, w) = (325, 100, FORCE_REPLAY_WEIGHT);
    let span = (FORCE_FIT_S / 0.01).round() as usize;
    let run = |period: Option<f64>| {
        let mut g = Gait::new();
        let mut guard = gait_guard();
        let (mut measured, mut estimated) = (Vec::new(), Vec::new());
        for k in 0..start + span + 5 {
            let mut raw = g.raw(k);
            raw.2 += SVector::repeat(2.0 * k as f64 * 0.01);
            if k >= start {
                raw.2 = SVector::repeat(f64::NAN);
            }
            let m = g.measure(k, raw);
            let rep = guard.repair(&m, period, 50, None);
            if k < start {
                measured.push(m.force);
            } else {
                assert!(rep.estimated.force.iter().all(|&e| e), "step {k}");
                estimated.push(rep.m.force);
            }
        }
        (measured, estimated)
    };
    let (f, blended) = run(Some(1.0));
    let (_, continued) = run(None);
    let fitted = &f[start - 100..start];
    let (mut checked, mut apart) = (0, 0.0_f64);
    for j in 0..2 {
        let lo = fitted.iter().map(|v| v[j]).fold(f64::INFINITY, f64::min);
        let hi = fitted
            .iter()
            .map(|v| v[j])
            .fold(f64::NEG_INFINITY, f64::max);
        let margin = FORCE_RANGE_MARGIN * (hi - lo);
        for a in 0..span {
            let k = start + a;
            let replayed = f[k - p][j] + f[start - 1][j] - f[start - 1 - p][j];
            let (e, c) = (blended[a][j], continued[a][j]);
            apart = apart.max((replayed - c).abs());
            let implied = (e - w * replayed) / (1.0 - w);
            assert!(
                implied >= lo - margin - 1e-9 && implied <= hi + margin + 1e-9,
                "step {a}, strap {j}: continuation {implied} outside [{lo}, {hi}] ± {margin}"
            );
            if c > lo && c < hi {
                let want = c + w * (replayed - c);
                assert!(
                    (e - want).abs() < 1e-9,
                    "step {a}, strap {j}: {e} vs {want} (continued {c}, replayed {replayed})"
                );
                checked += 1;
            }
        }
        // The replay after the continuation, continuous with the blend.
        for a in span..span + 5 {
            let k = start + a;
            let step = blended[a][j] - blended[a - 1][j];
            let replay_step = f[k - p][j] - f[k - 1 - p][j];
            assert!(
                (step - replay_step).abs() < 1e-9,
                "step {a}, strap {j}: {step} vs the replay's {replay_step}"
            );
        }
    }
    assert!(checked >= span, "the blend checked on {checked} steps only");
    assert!(
        apart > 0.05,
        "the replay and the continuation agree: {apart}"
    );
}

/// Issue 28, the forces at 3 kg early in the run (the fine scan's cells at 2.25 s, the period
/// known): the continuation alone gave a 200-ms NaN / dropout / stuck value / spike of both
/// forces 14.1 / 13.0 / 13.0 / 14.3 N, blended with the replay (`FORCE_REPLAY_WEIGHT`, the
/// range margin `FORCE_RANGE_MARGIN`) 9.9 / 11.8 / 11.5 / 9.9 N (measured on 2026-12-06).
#[test]
fn force_faults_at_3_kg_blend_the_continuation_with_the_replay() {
    force_faults(
        3.0,
        &[
            (FaultKind::Nan, 2.25, 0.2, 12.0, 1.05),
            (FaultKind::Dropout, 2.25, 0.2, 12.0, 1.05),
            (FaultKind::Stuck, 2.25, 0.2, 12.0, 1.05),
            (FaultKind::Spike, 2.25, 0.2, 12.0, 1.05),
        ],
    );
}

/// Issue 28, the forces at 3 kg early in the run: while the strap forces follow their
/// continuation (the period known) the MS-NMPC continues `d̂` with them instead of replaying
/// it one gait period back, another gait there (the human grows heavier, docs/MODEL.md §2).
/// Measured on 2026-12-06, `d̂` replayed → continued: a 200-ms NaN of both forces at 2.25 s,
/// 20.4 → 14.1 N (the hip's reversal), at 2.75 s 11.1 → 9.3 N; with the forces' blend of
/// continuation and replay (`FORCE_REPLAY_WEIGHT`) 9.9 / 8.9 N.
#[test]
fn the_disturbance_follows_the_forces_continuation_with_the_period_known() {
    force_faults(
        3.0,
        &[
            (FaultKind::Nan, 2.25, 0.2, 15.0, 1.06),
            (FaultKind::Nan, 2.75, 0.2, 10.0, 1.04),
        ],
    );
}

/// A strap force's continuation hands its gait frequency to the controller
/// (`EstimatedChannels::gait_omega`, the MS-NMPC then continues `d̂` with it) with the gait
/// period known only when it was fitted to measurements alone: a force fault 0.8 s after an
/// earlier one (its fit's last second holds that fault's estimates) gives none with the period
/// known, and gives one before the period is known; a fault on a clean history gives one.
#[test]
fn a_continuation_fitted_across_an_earlier_fault_is_not_handed_on_with_the_period_known() {
    let omega_at = |first: Option<usize>, period: Option<f64>| {
        let mut g = Gait::new();
        let mut guard = gait_guard();
        let second = 400;
        let mut omega = None;
        for k in 0..=second {
            let mut raw = g.raw(k);
            let faulty = |s: usize| (s..s + 10).contains(&k);
            if first.is_some_and(faulty) || faulty(second) {
                raw.2 = SVector::repeat(f64::NAN);
            }
            let m = g.measure(k, raw);
            let rep = guard.repair(&m, period, 50, None);
            if k == second {
                assert!(rep.estimated.force.iter().all(|&e| e));
                omega = rep.estimated.gait_omega;
            }
        }
        omega
    };
    assert!(omega_at(None, Some(1.0)).is_some());
    assert!(omega_at(Some(320), Some(1.0)).is_none());
    assert!(omega_at(Some(320), None).is_some());
}

/// Issue 28, the forces at 3 kg where the hip reverses at 2.58 s, early in the run: the gait
/// one period back is another gait (the human grows heavier over the run, docs/MODEL.md §2),
/// and the forces replayed from it put the thigh strap at 17.4 N within the fault. A strap
/// force follows its continuation at the gait frequency for `FORCE_FIT_S` first, also with
/// the period known. Measured on 2026-12-06, replayed → continued: a 200-ms dropout at 2.5 s
/// 21.6 → 8.9 N, a 200-ms NaN there 20.4 → 8.9 N (RMS 1.25 / 1.19 → 1.01×); blended with the
/// replay (`FORCE_REPLAY_WEIGHT`) 10.4 / 10.7 N.
#[test]
fn force_faults_while_the_gait_changes_follow_the_forces_continuation() {
    force_faults(
        3.0,
        &[
            (FaultKind::Dropout, 2.5, 0.2, 12.0, 1.05),
            (FaultKind::Nan, 2.5, 0.2, 12.0, 1.05),
        ],
    );
}

/// The person's own change of a strap force the gait before did not have (N): a 5-N bump
/// over steps 300-330 of the test gait.
fn person_bump(k: usize) -> f64 {
    if (300..330).contains(&k) {
        5.0 * (std::f64::consts::PI * (k - 300) as f64 / 30.0).sin()
    } else {
        0.0
    }
}

/// A 30-N spike of both strap forces for 200 ms while the person's force changes under it (a
/// 5-N bump the gait before did not have; the guard alone, `ChannelGuard::follow_offset`):
/// once the filter has ramped into the offset (three smooth samples after the window) the
/// estimate follows the person's force step for step, under the offset it had from the
/// continuation there, where the continuation and the replay forecast the gait before the
/// fault; the force is accepted again within the filter window of the spike's end. Its error
/// at the first followed step (2.5 N, the continuation's there) is kept under the offset, not
/// grown as the bump goes on.
#[test]
fn a_spiked_force_is_followed_under_its_offset() {
    let run = force_fault_run(
        400,
        |k, f| f.add_scalar_mut(person_bump(k)),
        |k, f| {
            if (300..320).contains(&k) {
                f.add_scalar_mut(30.0);
            }
        },
        |_| 1.0,
        1000,
    );
    for (k, s) in run.iter().enumerate().take(325).skip(300) {
        assert!(s.rep.estimated.force.iter().all(|&e| e), "step {k}");
    }
    // The window's ramp (300-304) and three smooth samples: followed from 307 on.
    let step = |k: usize, f: &dyn Fn(&ForceSample) -> SVector<f64, 2>| f(&run[k]) - f(&run[k - 1]);
    for k in 308..320 {
        let off = (step(k, &|s| s.rep.m.force) - step(k, &|s| s.true_f)).amax();
        assert!(
            off <= 1e-9,
            "step {k}: the estimate moved {off:.3} N off the force"
        );
    }
    let err = (run[319].rep.m.force - run[319].true_f).amax();
    assert!(err <= 2.6, "{err:.2} N off at the spike's end");
    // Accepted again once the window holds no spiked sample.
    let back = (320..400).find(|&k| !run[k].rep.estimated.force.iter().any(|&e| e));
    assert_eq!(back, Some(325));
}

/// Issue 28, a 200-ms 30-N spike of both forces at 1 s, 3 kg (first gait period; the fine
/// scan's cell, 10-s msnmpc run): followed under its offset (`ChannelGuard::follow_offset`)
/// the peak true strap force stays within the 12-N goal. On the forces' continuation, fitted
/// to a first second that is not yet periodic, the robot fell behind the leg within the fault
/// and the controller's correction on the forces' return peaked at 12.7 N (measured on
/// 2026-12-07; 8.9 N followed).
#[test]
fn a_force_spike_at_3_kg_in_the_first_gait_period_is_followed_under_its_offset() {
    group_is_ridden_through(ChannelGroup::Forces, 1.0, &[(FaultKind::Spike, 3.0, 0.2)]);
}

/// Issue 28, a force is not followed under its offset after a history that was not clean:
/// every sensor's 1-s spike at 3 s, 2 kg (a cell of the 1-s grid, 10-s msnmpc run). The
/// forces' fault at the spike's end (the forces had been believed on smoothness alone, the
/// encoders were lost until then) is a real step; followed, the shank's force was hidden
/// under a 19-N offset and the peak rose from 17.7 to 28.9 N (measured on 2026-12-07). Once
/// an encoder is lost a force is not followed either
/// (`every_sensor_spiked_for_a_second_in_the_first_gait_period_stays_within_70_n`).
#[test]
fn a_force_after_a_history_that_was_not_clean_is_not_followed_under_an_offset() {
    every_sensor_spiked_for_a_second_within(3.0, 2.0, 20.0);
}

/// A followed force whose offset ends in another fault (a 150-ms 30-N spike of both forces
/// while the person's force has a 5-N bump, then NaN until step 500): the estimate goes on
/// from its last followed value by the continuation's steps, then as the replay or the hold
/// that start from it. Without the gait period it holds after the continuation
/// (`FORCE_FIT_S`); with the period known it replays the gait from there, within its first
/// period never stepping beyond the true force's largest step, and within 4.5 N of the force.
/// Stepped by the hold's own steps (which start from the last estimate) it ran away along a
/// straight line: 400 N off at step 500 (the review of 2026-12-07).
#[test]
fn a_followed_force_goes_on_from_its_last_value_when_its_offset_ends() {
    let run = |period: f64| {
        force_fault_run(
            500,
            |k, f| f.add_scalar_mut(person_bump(k)),
            |k, f| {
                if (300..315).contains(&k) {
                    f.add_scalar_mut(30.0);
                } else if k >= 315 {
                    *f = SVector::repeat(f64::NAN);
                }
            },
            move |_| period,
            1000,
        )
    };
    let est = |r: &[ForceSample], k: usize| r[k].rep.m.force;
    // Followed from the third smooth sample after the window's ramp (as in
    // `a_spiked_force_is_followed_under_its_offset`).
    let unknown = run(f64::NAN);
    let followed = est(&unknown, 314) - est(&unknown, 313);
    let true_step = unknown[314].true_f - unknown[313].true_f;
    assert!((followed - true_step).amax() <= 1e-6, "not followed");
    let held_from = 300 + (FORCE_FIT_S / 0.01).round() as usize;
    for k in held_from..500 {
        let moved = (est(&unknown, k) - est(&unknown, held_from)).amax();
        assert!(moved <= 1e-9, "step {k}: the hold moved by {moved:.3} N");
    }
    let known = run(1.0);
    let true_step = *largest_steps(known.iter().map(|s| s.true_f))
        .last()
        .unwrap();
    for k in 301..400 {
        let step = (est(&known, k) - est(&known, k - 1)).amax();
        assert!(
            step <= true_step + 1e-6,
            "step {k}: {step:.3} N (the force's {true_step:.3})"
        );
        let err = (est(&known, k) - known[k].true_f).amax();
        assert!(err <= 4.5, "step {k}: {err:.2} N off");
    }
}

/// Issue 28, a followed force whose offset ends in a longer fault, in closed loop: a 100-ms
/// 30-N spike of both forces at 1 s, 3 kg, then NaN for 0.6 s (first gait period; 4-s msnmpc
/// run): the estimate holds after its continuation instead of running away, and the peak true
/// strap force stays within the 1-s goal (70 N) with no latch. Measured on 2026-12-07: 16.9 N
/// before forces were followed, 104.8 N with the estimate stepped by the hold's own steps
/// (the monitors tripped), 12.4 N now.
#[test]
fn a_followed_force_that_goes_on_in_another_fault_does_not_run_away() {
    let mut s = scenario(ControllerKind::MSNMPC, 3.0, 4.0);
    let forces = [Channel::F1, Channel::F2];
    s.faults.events = fault(FaultKind::Spike, &forces, 1.0, 0.1, 30.0);
    s.faults
        .events
        .extend(fault(FaultKind::Nan, &forces, 1.1, 0.6, 0.0));
    let (peak, _, rep, _) = run(&s);
    assert!(peak <= 70.0, "peak {peak:.1} N");
    assert_eq!(rep.latched_at, None, "{:?}", rep.events);
}
