//! Safety properties: whatever the measurements (finite, huge, NaN, ±∞), previous torques,
//! payloads and sensor-fault schedules, every controller (pd, nmpc, msnmpc decoupled and
//! coupled), supervised or not, returns a torque within `|T| ≤ T_max` and
//! `|T − T_prev| ≤ ΔT_max`, never NaN, never panics. Plus the fault-injection/monitor
//! behaviour and a soak run with faults (60 s in CI, 1 h `#[ignore]`d).

use exompc::config::{
    Channel, ControllerKind, Experiment, FaultEvent, FaultKind, Formulation, MonitorResponse,
};
use exompc::control::{
    Controller, Measurement, MonitorAction, MonitorKind, SafetySettings, StepStatus, Supervisor,
};
use exompc::scenario::{
    build_controller, build_supervised, limits, run_experiment_report, run_soak, OneDof, TwoDof,
};
use nalgebra::SVector;
use proptest::prelude::*;

/// `PROPTEST_CASES` if set (for long local hunts), else `default`.
fn cases(default: u32) -> u32 {
    std::env::var("PROPTEST_CASES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

/// Finite everyday values, huge values, and the non-finite ones.
fn value() -> impl Strategy<Value = f64> {
    prop_oneof![
        8 => -3.0..3.0f64,
        2 => -100.0..100.0f64,
        1 => -1e300..1e300f64,
        1 => Just(f64::NAN),
        1 => Just(f64::INFINITY),
        1 => Just(f64::NEG_INFINITY),
        1 => Just(0.0),
    ]
}

fn torque() -> impl Strategy<Value = f64> {
    prop_oneof![
        6 => -40.0..40.0f64,
        1 => Just(f64::NAN),
        1 => Just(f64::INFINITY),
        1 => -1e6..1e6f64,
    ]
}

fn measurement<const N: usize>(t: f64, v: &[f64]) -> Measurement<N> {
    Measurement {
        t,
        q: SVector::from_fn(|i, _| v[i]),
        qd: SVector::from_fn(|i, _| v[N + i]),
        force: SVector::from_fn(|i, _| v[2 * N + i]),
    }
}

#[derive(Clone, Copy, Debug)]
enum Kind {
    Pd,
    Nmpc,
    MsDecoupled,
    MsCoupled,
}

fn scenario(kind: Kind, payloads: &[f64]) -> Experiment {
    let mut s = Experiment::default();
    s.multistage.payloads_kg = payloads.to_vec();
    s.controller.kind = match kind {
        Kind::Pd => ControllerKind::PD,
        Kind::Nmpc => ControllerKind::NMPC,
        Kind::MsDecoupled | Kind::MsCoupled => ControllerKind::MSNMPC,
    };
    s.multistage.formulation = match kind {
        Kind::MsCoupled => Formulation::Coupled,
        _ => Formulation::Decoupled,
    };
    // Keep each solve short; the properties do not depend on convergence.
    s.controller.sqp.max_iterations = 5;
    s
}

/// Drives `c` through `samples` after forcing its previous torque to `t0`; checks the limits
/// on every step against the controller's own `previous_torque()`.
fn drive<const N: usize>(
    c: &mut dyn Controller<N>,
    lim: &exompc::control::TorqueLimits,
    t0: &[f64],
    samples: &[Vec<f64>],
) -> Result<(), TestCaseError> {
    c.set_previous_torque(SVector::from_fn(|i, _| t0[i]));
    let p0 = c.previous_torque();
    prop_assert!(p0.iter().all(|v| v.is_finite() && v.abs() <= lim.max));
    for (k, v) in samples.iter().enumerate() {
        let t = if v[3 * N].is_finite() {
            0.01 * k as f64
        } else {
            v[3 * N]
        };
        let m = measurement::<N>(t, v);
        let prev = c.previous_torque();
        let out = c.step(&m);
        prop_assert!(
            lim.admits(&prev, &out.torque),
            "step {k}: {:?} -> {:?} ({:?})",
            prev,
            out.torque,
            out.status
        );
        prop_assert_eq!(c.previous_torque(), out.torque);
        if !m.is_finite() {
            prop_assert!(matches!(
                out.status,
                StepStatus::BadMeasurement | StepStatus::MonitorTripped
            ));
        }
    }
    Ok(())
}

fn kinds() -> impl Strategy<Value = Kind> {
    prop_oneof![
        Just(Kind::Pd),
        Just(Kind::Nmpc),
        Just(Kind::MsDecoupled),
        Just(Kind::MsCoupled)
    ]
}

proptest! {
    #![proptest_config(ProptestConfig { cases: cases(96), ..ProptestConfig::default() })]

    #[test]
    fn two_dof_outputs_within_limits(
        kind in kinds(),
        supervised in any::<bool>(),
        payloads in prop::collection::vec(0.0..20.0f64, 1..4),
        t0 in prop::collection::vec(torque(), 2),
        samples in prop::collection::vec(prop::collection::vec(value(), 7), 1..12),
    ) {
        let s = scenario(kind, &payloads);
        prop_assume!(s.validate().is_ok());
        let lim = limits(&s);
        if supervised {
            let mut c = build_supervised::<TwoDof, 2>(&s, s.controller.kind).unwrap();
            drive::<2>(&mut c, &lim, &t0, &samples)?;
        } else {
            let mut c = build_controller::<TwoDof, 2>(&s, s.controller.kind).unwrap();
            drive::<2>(c.as_mut(), &lim, &t0, &samples)?;
        }
    }

    #[test]
    fn one_dof_outputs_within_limits(
        kind in kinds(),
        supervised in any::<bool>(),
        payloads in prop::collection::vec(0.0..20.0f64, 1..4),
        t0 in prop::collection::vec(torque(), 1),
        samples in prop::collection::vec(prop::collection::vec(value(), 4), 1..12),
    ) {
        let s = scenario(kind, &payloads);
        prop_assume!(s.validate().is_ok());
        let lim = limits(&s);
        if supervised {
            let mut c = build_supervised::<OneDof, 1>(&s, s.controller.kind).unwrap();
            drive::<1>(&mut c, &lim, &t0, &samples)?;
        } else {
            let mut c = build_controller::<OneDof, 1>(&s, s.controller.kind).unwrap();
            drive::<1>(c.as_mut(), &lim, &t0, &samples)?;
        }
    }
}

fn fault_kind() -> impl Strategy<Value = FaultKind> {
    prop_oneof![
        Just(FaultKind::Nan),
        Just(FaultKind::Inf),
        Just(FaultKind::Dropout),
        Just(FaultKind::Spike),
        Just(FaultKind::Stuck),
        Just(FaultKind::Saturation),
    ]
}

fn channel() -> impl Strategy<Value = Channel> {
    prop_oneof![
        Just(Channel::Q1),
        Just(Channel::Q2),
        Just(Channel::Qd1),
        Just(Channel::Qd2),
        Just(Channel::F1),
        Just(Channel::F2),
    ]
}

fn fault_event() -> impl Strategy<Value = FaultEvent> {
    (
        fault_kind(),
        channel(),
        0.0..0.8f64,
        0.0..0.5f64,
        -1e4..1e4f64,
    )
        .prop_map(
            |(kind, channel, start_s, duration_s, magnitude)| FaultEvent {
                kind,
                channel,
                start_s,
                duration_s,
                magnitude,
            },
        )
}

proptest! {
    #![proptest_config(ProptestConfig { cases: cases(32), ..ProptestConfig::default() })]

    /// Closed loops with arbitrary fault schedules: no limit violation, nothing non-finite.
    #[test]
    fn closed_loop_with_faults_stays_within_limits(
        kind in kinds(),
        one_dof in any::<bool>(),
        hold in any::<bool>(),
        payload in 0.0..5.0f64,
        events in prop::collection::vec(fault_event(), 0..6),
    ) {
        let mut s = scenario(kind, &[0.0, 1.0, 2.0]);
        s.uncertainty.payload_kg = payload;
        s.timing.duration_1dof_s = 1.0;
        s.timing.duration_2dof_s = 1.0;
        s.faults.events = events;
        if hold {
            s.monitors.response = MonitorResponse::Hold;
        }
        let mut rows = exompc::sim::TraceLog::default();
        if one_dof {
            let (sum, _) = run_experiment_report::<OneDof, 1>(&s, &mut []).unwrap();
            prop_assert_eq!(sum.limit_violations, 0);
        } else {
            let (sum, _) = run_experiment_report::<TwoDof, 2>(&s, &mut [&mut rows]).unwrap();
            prop_assert_eq!(sum.limit_violations, 0);
            for r in &rows.rows {
                prop_assert!(r.torque_robot.iter().all(|v| v.is_finite()));
                prop_assert!(r.robot.q.iter().all(|v| v.is_finite()));
                prop_assert!(r.force_true.iter().all(|v| v.is_finite()));
            }
        }
    }
}

#[test]
fn nan_fault_poisons_the_filter_and_the_supervisor_holds_then_resumes() {
    let mut s = scenario(Kind::Nmpc, &[0.0]);
    s.timing.duration_2dof_s = 2.0;
    s.monitors.sensor_timeout_s = 1.0; // isolate the plausibility fallback
    s.faults.events = vec![FaultEvent {
        kind: FaultKind::Nan,
        channel: Channel::F2,
        start_s: 0.5,
        duration_s: 0.1,
        magnitude: 0.0,
    }];
    let mut log = exompc::sim::TraceLog::default();
    let (sum, rep) = run_experiment_report::<TwoDof, 2>(&s, &mut [&mut log]).unwrap();
    assert_eq!(sum.limit_violations, 0);
    let bad: Vec<usize> = log
        .rows
        .iter()
        .enumerate()
        .filter(|(_, r)| r.status == StepStatus::BadMeasurement)
        .map(|(k, _)| k)
        .collect();
    // 10 NaN samples, 4 more while the NaN is still in the 5-sample window, and at most one
    // more until the force is back within its gate (docs/RELIABILITY.md §2).
    assert!((14..=15).contains(&bad.len()), "{bad:?}");
    assert_eq!(bad[0], 50);
    assert_eq!(rep.bad_measurement_steps, bad.len() as u64);
    // The controller keeps stepping on the force's estimate (issue 28): the torque follows
    // the leg instead of being held.
    assert!(bad
        .iter()
        .any(|k| log.rows[*k].torque_robot != log.rows[bad[0] - 1].torque_robot));
    assert_ne!(log.rows[66].status, StepStatus::BadMeasurement);
    assert!(rep.monitor_trips == 0);
}

#[test]
fn stale_sensor_trips_the_timeout_monitor_and_ramps_to_zero() {
    let mut s = scenario(Kind::Pd, &[0.0]);
    s.timing.duration_2dof_s = 3.0;
    // A frozen velocity whose angle is measured may stay rejected 4 × sensor_timeout_s.
    s.monitors.sensor_timeout_s = 0.1;
    s.faults.events = vec![FaultEvent {
        kind: FaultKind::Dropout,
        channel: Channel::Qd1,
        start_s: 1.0,
        duration_s: 1.0,
        magnitude: 0.0,
    }];
    let mut log = exompc::sim::TraceLog::default();
    let (sum, rep) = run_experiment_report::<TwoDof, 2>(&s, &mut [&mut log]).unwrap();
    assert_eq!(sum.limit_violations, 0);
    let trips: Vec<_> = rep
        .events
        .iter()
        .filter(|e| e.action == MonitorAction::Trip)
        .collect();
    assert_eq!(trips.len(), 1, "{:?}", rep.events);
    assert_eq!(trips[0].monitor, MonitorKind::SensorTimeout);
    // Window (5 samples) then 4 × 0.1 s after the dropout's start.
    assert!(trips[0].t > 1.35 && trips[0].t < 1.55, "{:?}", trips[0]);
    // Torque at zero well inside the trip, and the controller resumed after the fault.
    let mid = log.rows.iter().find(|r| (r.t - 1.8).abs() < 1e-6).unwrap();
    assert_eq!(mid.status, StepStatus::MonitorTripped);
    assert_eq!(mid.torque_robot, SVector::<f64, 2>::zeros());
    assert!(rep.events.iter().any(|e| e.action == MonitorAction::Clear));
    assert_eq!(log.rows.last().unwrap().status, StepStatus::Ok);
}

/// A supervised 2-DOF MS-NMPC (0 and 2 kg scenarios) with monitor response `response`, and
/// its torque-rate limit per period (N·m).
fn supervised_msnmpc(response: MonitorResponse) -> (Supervisor<2, Box<dyn Controller<2>>>, f64) {
    let s = scenario(Kind::MsDecoupled, &[0.0, 2.0]);
    let inner = build_controller::<TwoDof, 2>(&s, ControllerKind::MSNMPC).unwrap();
    let mut settings = SafetySettings::from_scenario(&s);
    settings.monitors.response = response;
    let rate = settings.limits.rate;
    (Supervisor::new(inner, settings), rate)
}

#[test]
fn supervisor_keeps_the_inner_previous_torque_in_sync() {
    let (mut sup, _) = supervised_msnmpc(MonitorResponse::RampToZero);
    let good = |k: usize| Measurement::<2> {
        t: 0.01 * k as f64,
        q: SVector::from([0.1 + 1e-3 * k as f64, 0.2 - 1e-3 * k as f64]),
        qd: SVector::from([0.05 + 1e-3 * k as f64, -0.1 - 1e-3 * k as f64]),
        force: SVector::from([1.0 + 1e-2 * k as f64, -2.0 + 1e-2 * k as f64]),
    };
    for k in 0..5 {
        sup.step(&good(k));
        assert_eq!(sup.inner().previous_torque(), sup.previous_torque());
    }
    let mut bad = good(5);
    bad.force[0] = 500.0; // implausible (beyond the sensor range) and a strap-force trip
    for k in 5..40 {
        bad.t = 0.01 * k as f64;
        let out = sup.step(&bad);
        assert_eq!(out.status, StepStatus::MonitorTripped);
        assert_eq!(sup.inner().previous_torque(), out.torque);
    }
    assert_eq!(sup.previous_torque(), SVector::<f64, 2>::zeros());
    assert!(sup.report().monitor_trips >= 1);
    for k in 40..80 {
        sup.step(&good(k));
        assert_eq!(sup.inner().previous_torque(), sup.previous_torque());
    }
    assert!(!sup.is_tripped());
}

/// `hold` holds the last *safe* torque (issue 28): the torque of the last fully measured step
/// with no monitor tripped, not the torque of the steps on estimated channels just before the
/// trip; the supervisor returns to it within the rate limit.
#[test]
fn hold_returns_to_the_torque_of_the_last_fully_measured_step() {
    let (mut sup, rate) = supervised_msnmpc(MonitorResponse::Hold);
    let good = |k: usize| Measurement::<2> {
        t: 0.01 * k as f64,
        q: SVector::from([0.1 + 2e-3 * k as f64, 0.2 - 2e-3 * k as f64]),
        qd: SVector::from([0.2 + 1e-4 * (k % 5) as f64, -0.2 - 1e-4 * (k % 3) as f64]),
        force: SVector::from([1.0 + 1e-2 * k as f64, -2.0 + 1e-2 * k as f64]),
    };
    let mut safe = SVector::zeros();
    for k in 0..20 {
        let out = sup.step(&good(k));
        assert!(
            !matches!(
                out.status,
                StepStatus::BadMeasurement | StepStatus::MonitorTripped
            ),
            "{k}: {:?}",
            out.status
        );
        safe = out.torque;
    }
    // A NaN thigh velocity for 5 steps: the controller steps on its estimate ...
    let mut before_trip = safe;
    for k in 20..25 {
        let mut m = good(k);
        m.qd[0] = f64::NAN;
        let out = sup.step(&m);
        assert_eq!(out.status, StepStatus::BadMeasurement, "{k}");
        before_trip = out.torque;
    }
    assert!((before_trip - safe).amax() > 1e-3, "{before_trip} {safe}");
    // ... then a strap-force trip (3 steps beyond the range), held for `clear_after_s`.
    let mut last = before_trip;
    let mut reached = None;
    for k in 25..36 {
        let mut m = good(k);
        if k < 28 {
            m.force[1] = 500.0;
        }
        let out = sup.step(&m);
        assert_eq!(out.status, StepStatus::MonitorTripped, "{k}");
        assert!((out.torque - last).amax() <= rate + 1e-12);
        // Every step goes toward the safe torque, and stays once there.
        assert!(
            (out.torque - safe).amax() <= (last - safe).amax() + 1e-12,
            "{k}"
        );
        if out.torque == safe && reached.is_none() {
            reached = Some(k);
        }
        last = out.torque;
    }
    assert!(reached.is_some(), "{last} {safe}");
    assert_eq!(last, safe);
}

/// `hold` hands the torque to the transparent fallback when the trip's cause is present after
/// `RESPONSE_ESCALATE_S` (issue 28 item 3; docs/RELIABILITY.md §2b): a strap force beyond
/// the range for 10 steps escalates exactly `RESPONSE_ESCALATE_S` after the trip, once
/// (logged and counted), the torque is then the fallback's demand within the rate limit, and
/// the controller has the torque again once the monitor clears;
/// one for 2 steps (gone before `RESPONSE_ESCALATE_S`, the monitor only in its
/// `clear_after_s` hold-off) stays with `hold`.
#[test]
fn hold_escalates_to_the_fallback_only_while_its_cause_persists() {
    use exompc::control::RESPONSE_ESCALATE_S;
    let mut s = scenario(Kind::MsDecoupled, &[0.0, 2.0]);
    s.monitors.response = MonitorResponse::Hold;
    let good = |k: usize| Measurement::<2> {
        t: 0.01 * k as f64,
        q: SVector::from([0.1 + 2e-3 * k as f64, 0.2 - 2e-3 * k as f64]),
        qd: SVector::from([0.2 + 1e-4 * (k % 5) as f64, -0.2 - 1e-4 * (k % 3) as f64]),
        force: SVector::from([1.0 + 1e-2 * k as f64, -2.0 + 1e-2 * k as f64]),
    };
    for (bad_steps, escalates) in [(2, false), (10, true)] {
        let mut sup = build_supervised::<TwoDof, 2>(&s, ControllerKind::MSNMPC).unwrap();
        assert!(sup.fallback().is_some());
        let limits = SafetySettings::from_scenario(&s).limits;
        let mut last = StepStatus::Ok;
        let mut followed = 0;
        for k in 0..80 {
            let mut m = good(k);
            if (25..25 + bad_steps).contains(&k) {
                m.force[1] = 500.0;
            }
            let prev = sup.previous_torque();
            let out = sup.step(&m);
            last = out.status;
            // From the escalation on, while tripped: the fallback's demand of this step.
            if sup.report().escalations > 0 && out.status == StepStatus::MonitorTripped {
                let demand = sup.fallback().unwrap().torque();
                assert_eq!(out.torque, limits.clamp(&prev, &demand), "{k}");
                followed += 1;
            }
        }
        assert_eq!(followed > 0, escalates);
        let rep = sup.report();
        let trip = rep
            .events
            .iter()
            .find(|e| e.action == MonitorAction::Trip)
            .unwrap_or_else(|| panic!("no trip: {:?}", rep.events));
        let esc: Vec<_> = rep
            .events
            .iter()
            .filter(|e| e.action == MonitorAction::Escalate)
            .collect();
        assert_eq!(rep.escalations, esc.len() as u64);
        if escalates {
            assert_eq!(esc.len(), 1, "{:?}", rep.events);
            assert_eq!(esc[0].monitor, MonitorKind::StrapForce);
            assert!(
                (esc[0].t - trip.t - RESPONSE_ESCALATE_S).abs() < 1e-9,
                "{:?}",
                rep.events
            );
        } else {
            assert!(esc.is_empty(), "{:?}", rep.events);
        }
        assert!(!sup.is_tripped(), "{:?}", rep.events);
        assert_ne!(last, StepStatus::MonitorTripped);
    }
}

fn check_soak(seconds: f64) {
    let r = run_soak(&Experiment::default(), seconds, 2.0, &mut [], &mut []).unwrap();
    let st = &r.stats;
    assert_eq!(st.steps as f64, (seconds / 0.01).round());
    assert_eq!(st.nan_count, 0);
    assert_eq!(st.limit_violations, 0);
    assert!(st.max_abs_force_n.is_finite());
    // Every minute: at least the NaN, inf, dropout and stuck faults are detected (and ridden
    // through on the channels' estimates, issue 28).
    assert!(
        r.sensor_faults >= 4 * (seconds / 60.0).floor() as u64,
        "{r:?}"
    );
    // Every injected fault episode is judged against the fault-free run and meets issue
    // 28's goals (six per minute in the default schedule).
    assert_eq!(
        r.fault_episodes,
        6 * (seconds / 60.0).round() as u64,
        "{r:?}"
    );
    assert_eq!(
        r.fault_episodes_passing, r.fault_episodes,
        "{:#?}",
        r.fault_classes
    );
    assert_eq!(r.fault_classes.len(), 6);
    println!("{}", serde_json_like(&r));
}

fn serde_json_like(r: &exompc::scenario::SoakReport) -> String {
    format!(
        "steps {} nan {} violations {} max|F| {:.2} N rms F {:.2} N solver failures {} \
         monitor trips {} wall {:.1} s",
        r.stats.steps,
        r.stats.nan_count,
        r.stats.limit_violations,
        r.stats.max_abs_force_n,
        r.stats.rms_force_n,
        r.stats.solver_failures,
        r.monitor_trips,
        r.wall_time_s
    )
}

#[test]
fn soak_60_s_with_faults() {
    check_soak(60.0);
}

#[test]
#[ignore = "1 h simulated (15-90 s in release); run with --ignored"]
fn soak_1_h_with_faults() {
    check_soak(3600.0);
}

/// A controller that asks for a torque that is a function of time (0.7 Hz, off the gait's
/// 1 Hz) and plans it for the later periods (within the limits from its previous torque).
struct Scheduled {
    last_t: f64,
    dt: f64,
    prev: SVector<f64, 2>,
    limits: exompc::control::TorqueLimits,
}

impl Scheduled {
    fn at(t: f64) -> SVector<f64, 2> {
        let w = 2.0 * std::f64::consts::PI * 0.7;
        SVector::<f64, 2>::new(6.0 * (w * t).sin(), -4.0 * (w * t).cos())
    }
}

impl Controller<2> for Scheduled {
    fn step(&mut self, m: &Measurement<2>) -> exompc::control::ControlOutput<2> {
        self.last_t = m.t;
        self.prev = self.limits.clamp(&self.prev, &Self::at(m.t));
        exompc::control::ControlOutput {
            torque: self.prev,
            status: StepStatus::Ok,
            iterations: 0,
        }
    }
    fn name(&self) -> &'static str {
        "scheduled"
    }
    fn previous_torque(&self) -> SVector<f64, 2> {
        self.prev
    }
    fn set_previous_torque(&mut self, t: SVector<f64, 2>) {
        self.prev = self.limits.admissible(&t);
    }
    fn planned_torques(&self, out: &mut [SVector<f64, 2>]) -> usize {
        let mut p = self.prev;
        for (i, o) in out.iter_mut().enumerate() {
            p = self
                .limits
                .clamp(&p, &Self::at(self.last_t + (i + 1) as f64 * self.dt));
            *o = p;
        }
        out.len()
    }
}

/// Step `k` of a 1-Hz gait seen by the sensors (period `dt`), small varying strap forces;
/// the angles and velocities NaN when asked.
fn gait_sample(k: usize, dt: f64, nan_q: bool, nan_qd: bool) -> Measurement<2> {
    let t = k as f64 * dt;
    let w = 2.0 * std::f64::consts::PI;
    let q = SVector::<f64, 2>::new(0.3 * (w * t).sin(), -0.6 + 0.4 * (w * t).cos());
    let qd = SVector::<f64, 2>::new(0.3 * w * (w * t).cos(), -0.4 * w * (w * t).sin());
    Measurement::<2> {
        t,
        q: if nan_q { q.map(|_| f64::NAN) } else { q },
        qd: if nan_qd { qd.map(|_| f64::NAN) } else { qd },
        force: SVector::<f64, 2>::new(1.0 + 0.2 * (w * t).sin(), 0.5 * (w * t).cos()),
    }
}

/// A supervisor around [`Scheduled`] for the default scenario with `response`, with the
/// scenario's fallback if `with_fallback`, and its period.
fn scheduled_supervisor(
    response: MonitorResponse,
    with_fallback: bool,
) -> (Supervisor<2, Scheduled>, f64) {
    let mut s = Experiment::default();
    s.monitors.response = response;
    let settings = SafetySettings::from_scenario(&s);
    let dt = settings.dt;
    let inner = Scheduled {
        last_t: 0.0,
        dt,
        prev: SVector::zeros(),
        limits: limits(&s),
    };
    let sup = Supervisor::new(inner, settings);
    let sup = if with_fallback {
        sup.with_fallback(exompc::scenario::fallback::<TwoDof, 2>(&s))
    } else {
        sup
    };
    (sup, dt)
}

/// An escalation is made once per trip: `hold` on a strap force beyond the range (2-4.2 s)
/// hands the torque to the fallback after `RESPONSE_ESCALATE_S`; a 0.8-s NaN of both angles
/// within it (2.5-3.3 s) makes the fallback fail (the protective stop), and from then until
/// the monitors clear neither `hold` nor a second escalation takes the torque: it stays at the
/// stop's zero (found in review: the stop cleared the escalation, `hold` took the torque back
/// at 3.3 s and a second escalation was counted while the stop kept the torque).
#[test]
fn an_escalation_is_made_once_per_trip() {
    use exompc::control::RESPONSE_ESCALATE_S;
    let (mut sup, dt) = scheduled_supervisor(MonitorResponse::Hold, true);
    for k in 0..500usize {
        let mut m = gait_sample(k, dt, (250..330).contains(&k), false);
        if (200..420).contains(&k) {
            m.force[1] = 500.0;
        }
        let out = sup.step(&m);
        if (330..420).contains(&k) {
            assert_eq!(out.status, StepStatus::MonitorTripped, "{k}");
            assert_eq!(out.torque, SVector::<f64, 2>::zeros(), "{k}");
        }
    }
    let rep = sup.report();
    let esc: Vec<_> = (rep.events.iter())
        .filter(|e| e.action == MonitorAction::Escalate)
        .collect();
    assert_eq!(esc.len(), 1, "{:?}", rep.events);
    assert!(
        (esc[0].t - 2.0 - RESPONSE_ESCALATE_S).abs() < 1e-9,
        "{esc:?}"
    );
    assert_eq!((rep.escalations, rep.fallback_stops), (1, 1));
}

/// The transparent fallback demands a torque only on a step it was fed: on steps whose angles
/// and velocities are lost (NaN, 2.04-2.08 s) while it has the torque (a strap force beyond
/// the range from 2 s), the torque ramps to zero at `STOP_RAMP_NM_PER_S`, with the configured
/// `fallback` and with `hold` escalated to it; and `hold` whose fallback is not fed when its
/// response begins and when its escalation is due (losses 1.98-2.06 s) escalates on the
/// fallback's first fed step, the escalation's `value` the response's time so far. Found in
/// review: the escalated `hold` went back to its held torque on the unfed steps, and the
/// escalation's clock started only when the fallback was fed (before that, the stale demand
/// was applied).
#[test]
fn an_unfed_fallback_hands_the_torque_to_the_ramp_to_zero() {
    use exompc::control::{RESPONSE_ESCALATE_S, STOP_RAMP_NM_PER_S};
    for (response, early) in [
        (MonitorResponse::Fallback, false),
        (MonitorResponse::Hold, false),
        (MonitorResponse::Hold, true),
    ] {
        let (mut sup, dt) = scheduled_supervisor(response, true);
        let step = STOP_RAMP_NM_PER_S * dt;
        let mut prev = SVector::<f64, 2>::zeros();
        let mut ramped = 0;
        for k in 0..300usize {
            let window = if early { 198..206 } else { 204..208 };
            let lost = window.contains(&k);
            let mut m = gait_sample(k, dt, lost, lost);
            if (200..280).contains(&k) {
                m.force[1] = 500.0;
            }
            let out = sup.step(&m);
            if lost && !early {
                assert_eq!(out.status, StepStatus::MonitorTripped, "{response:?} {k}");
                let want = prev - prev.map(|v| v.clamp(-step, step));
                assert!(
                    (out.torque - want).amax() < 1e-12,
                    "{response:?} {k}: {:?} against {want:?}",
                    out.torque
                );
                ramped += usize::from(prev.amax() > step);
            }
            prev = out.torque;
        }
        if !early {
            assert!(
                ramped >= 3,
                "{response:?}: the torque was near zero already"
            );
        }
        let rep = sup.report();
        let esc: Vec<_> = (rep.events.iter())
            .filter(|e| e.action == MonitorAction::Escalate)
            .collect();
        match (response, early) {
            (MonitorResponse::Fallback, _) => assert!(esc.is_empty(), "{esc:?}"),
            (_, false) => {
                assert_eq!(esc.len(), 1, "{esc:?}");
                assert!(
                    (esc[0].t - 2.0 - RESPONSE_ESCALATE_S).abs() < 1e-9,
                    "{esc:?}"
                );
            }
            (_, true) => {
                // Fed again at 2.06 s: escalated there, 0.06 s into the response.
                assert_eq!(esc.len(), 1, "{esc:?}");
                assert!((esc[0].t - 2.06).abs() < 1e-9, "{esc:?}");
                assert!((esc[0].value - 0.06).abs() < 1e-9, "{esc:?}");
            }
        }
    }
}

/// The supervisor's planned torques (what a robot plays while no command arrives) are the
/// torques it would output on the next periods: also through a handback, after the
/// protective stop (a 1-s NaN of both angles) and after the replay of one gait period back
/// (a 0.2-s NaN of every encoder channel once the gait period is known, and 1- and 2-step
/// ones, shorter than the blend into the replay), where the output blends into the
/// controller's; and no plan within that replay (through a gap the robot
/// replays the torque it applied one gait period earlier). Before, the plan was
/// the controller's own: a link lost in a handback skipped it, and one lost within the
/// replay played the controller's plan.
#[test]
fn the_plan_follows_the_handbacks() {
    let (mut sup, dt) = scheduled_supervisor(Experiment::default().monitors.response, false);
    let m = |k: usize, nan_q: bool, nan_qd: bool| gait_sample(k, dt, nan_q, nan_qd);
    let mut plan = [SVector::<f64, 2>::zeros(); 12];
    // (fault from step, to step, velocities lost too, what ends it)
    let mut k = 0;
    for (from, to, qd_too, what) in [
        (300, 400, false, "protective stop"),
        (700, 720, true, "replay"),
        // Shorter than the blend into the replay (`REPLAY_BLEND_IN_STEPS`): the handback
        // begins within it.
        (1000, 1002, true, "2-step replay"),
        (1300, 1301, true, "1-step replay"),
    ] {
        let mut tripped = false;
        let mut checked = 0;
        while k < to + 200 {
            let fault = k >= from && k < to;
            let out = sup.step(&m(k, fault, fault && qd_too));
            k += 1;
            tripped |= out.status == StepStatus::MonitorTripped;
            let done = if qd_too {
                k > to
            } else {
                tripped && out.status != StepStatus::MonitorTripped
            };
            if done && checked == 0 {
                let n = sup.planned_torques(&mut plan);
                assert_eq!(n, plan.len(), "{what}");
                for (i, p) in plan.iter().enumerate() {
                    let o = sup.step(&m(k, false, false));
                    k += 1;
                    assert!(
                        (o.torque - p).amax() < 1e-12,
                        "{what}: period {i} after the plan, output {:?} against plan {:?}",
                        o.torque,
                        p
                    );
                }
                checked = 1;
            }
        }
        assert_eq!(checked, 1, "{what}: the handback was not reached");
        assert_eq!(tripped, !qd_too, "{what}: {:?}", sup.safety_report());
    }
    // Within a loss of every encoder channel: no plan (through a gap the robot replays the
    // torque it applied one gait period earlier).
    for _ in 0..10 {
        let o = sup.step(&m(k, true, true));
        k += 1;
        assert_eq!(o.status, StepStatus::BadMeasurement);
    }
    assert_eq!(sup.planned_torques(&mut plan), 0, "coast");
}
