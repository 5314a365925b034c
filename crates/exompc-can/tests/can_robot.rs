//! The CAN robot in closed loop on the virtual bus (simulated bus time: the tests do not run in
//! real time): virtual AK80-9 motors at hip and knee and a raw force node with the simulated
//! leg behind them; the protective stop on a device timeout, a drive fault, error-passive and
//! bus-off; no torque before every device is ready.

use exompc::config::Experiment;
use exompc::runtime::{Clock, ControlLoop, Lifecycle, LoopSettings, PeriodRecord, RobotInterface};
use exompc::scenario::{build_supervised, limits, plant_params, uncertainty, Dof, TwoDof};
use exompc::sim::{Plant, Sensors};
use exompc_can::ak::AkDrive;
use exompc_can::config::{AkJoint, AkModel, AkReplyEffort, ForceChannel, RawForceSensor, Strap};
use exompc_can::emulator::{AkEmulator, Mount, VirtualLeg};
use exompc_can::robot::{CanRobot, CanRobotSettings, CanStopCause};
use exompc_can::{
    BusState, TimeBase, VirtualBus, VirtualBusSettings, VirtualClock, VirtualEndpoint,
};
use std::sync::{Arc, Mutex};
use std::time::Duration;

type Traj = <TwoDof as Dof<2>>::Traj;
type Leg = VirtualLeg<2, Traj>;

fn joint(id: u32, fine: bool) -> AkJoint {
    AkJoint {
        can_id: id,
        model: "AK80-9".into(),
        reply_id: 0,
        gear_ratio: 1.0,
        direction: 1,
        zero_offset_rad: 0.0,
        torque_limit_nm: None,
        reply_effort: AkReplyEffort::Torque,
        torque_per_amp: None,
        p_max: fine.then_some(FINE.p_max),
        v_max: fine.then_some(FINE.v_max),
        t_max: None,
        kp_max: None,
        kd_max: None,
    }
}

fn force_node() -> RawForceSensor {
    let ch = |strap, byte| ForceChannel {
        strap,
        byte,
        bytes: 2,
        signed: true,
        big_endian: false,
        scale: 0.01,
        offset_n: 0.0,
    };
    RawForceSensor {
        can_id: 0x300,
        extended: false,
        rate_hz: 1000.0,
        channels: vec![ch(Strap::Thigh, 0), ch(Strap::Shank, 2)],
    }
}

struct Rig {
    s: Experiment,
    bus: VirtualBus,
    leg: Arc<Mutex<Leg>>,
    robot: CanRobot<2, VirtualEndpoint, VirtualClock>,
    ep: usize,
}

/// Narrower MIT ranges than the AK80-9's (±3 rad, ±5 rad/s): 10× finer velocity steps, to
/// separate the quantisation's effect from the bus's.
const FINE: AkModel = AkModel {
    name: "fine",
    p_max: 3.0,
    v_max: 5.0,
    t_max: 18.0,
    kp_max: 500.0,
    kd_max: 5.0,
};

fn rig() -> Rig {
    rig_with(false)
}

fn rig_with(fine: bool) -> Rig {
    rig_opts(fine, Duration::ZERO, None, vec![force_node()])
}

/// The thigh and the shank strap on nodes of their own, at different rates.
fn two_force_nodes() -> Vec<RawForceSensor> {
    let mut thigh = force_node();
    thigh.channels.truncate(1);
    let mut shank = force_node();
    shank.can_id = 0x301;
    shank.rate_hz = 500.0;
    shank.channels.remove(0);
    shank.channels[0].byte = 0;
    vec![thigh, shank]
}

/// A rig with the protective stop's `stop_ramp`, if given the torque-rate limit (N·m/s), and
/// the force nodes `forces`.
fn rig_opts(
    fine: bool,
    stop_ramp: Duration,
    torque_rate_max: Option<f64>,
    forces: Vec<RawForceSensor>,
) -> Rig {
    let mut s = Experiment::default();
    s.controller.torque_max = 18.0;
    if let Some(r) = torque_rate_max {
        s.controller.torque_rate_max = r;
    }
    let dt = Duration::from_secs_f64(s.timing.dt);
    let bus = VirtualBus::new(VirtualBusSettings::default(), TimeBase::Simulated);
    let plant = Plant::new(plant_params::<TwoDof, 2>(&s), TwoDof::trajectory(&s));
    let sensors = Sensors::new(uncertainty(&s), s.uncertainty.filter_window);
    let ak = if fine {
        FINE
    } else {
        AkModel::by_name("AK80-9").unwrap()
    };
    let mount = Mount {
        direction: 1.0,
        gear_ratio: 1.0,
        zero_offset: 0.0,
    };
    let leg = VirtualLeg::new(
        plant,
        sensors,
        [AkEmulator::new(1, 0, ak), AkEmulator::new(2, 0, ak)],
        [mount; 2],
        forces.clone(),
        dt,
        Duration::from_micros(100),
    )
    .with_history(1100);
    let leg = Arc::new(Mutex::new(leg));
    bus.attach(leg.clone());
    let ep = bus.endpoint();
    let idx = ep.index();
    let robot = CanRobot::new(
        ep,
        bus.clock(),
        [
            AkDrive::new(&joint(1, fine)).unwrap(),
            AkDrive::new(&joint(2, fine)).unwrap(),
        ],
        ["hip", "knee"],
        forces,
        CanRobotSettings {
            dt,
            ready_timeout: Duration::from_millis(200),
            reply_timeout: Duration::from_millis(30),
            stop_ramp,
            limits: limits(&s),
            phase: Some(0.5),
        },
    );
    Rig {
        s,
        bus,
        leg,
        robot,
        ep: idx,
    }
}

/// Run the loop for `periods` (or until the robot stops), calling `at(k, rig)` before each.
fn run(rig: &mut Rig, periods: usize, mut at: impl FnMut(usize, &Rig)) -> Vec<PeriodRecord<2>> {
    let s = &rig.s;
    let dt = Duration::from_secs_f64(s.timing.dt);
    let sup = build_supervised::<TwoDof, 2>(s, s.controller.kind).unwrap();
    let mut lp = ControlLoop::new(
        sup,
        LoopSettings::new(dt, s.uncertainty.filter_window, limits(s)),
        periods + 8,
    );
    let mut clock = rig.bus.clock();
    assert!(lp
        .connect(
            &mut rig.robot,
            &mut clock,
            Duration::from_secs(1),
            Duration::from_millis(50)
        )
        .unwrap());
    let mut out = Vec::new();
    for k in 0..periods {
        at(k, rig);
        let rec = lp.period(&mut rig.robot, &mut clock).unwrap();
        let stopped = rec.robot_stopped;
        out.push(rec);
        if stopped {
            break;
        }
    }
    out
}

fn rms(v: &[f64]) -> f64 {
    (v.iter().map(|x| x * x).sum::<f64>() / v.len().max(1) as f64).sqrt()
}

/// RMS true strap forces (thigh, shank) of a 10-s closed loop on the virtual bus, and of the
/// same scenario simulated without the bus.
fn closed_loop(fine: bool) -> ([f64; 2], [f64; 2]) {
    let mut r = rig_with(fine);
    r.s.timing.duration_2dof_s = 10.0;
    let recs = run(&mut r, 1005, |_, _| {});
    assert_eq!(recs.len(), 1005);
    assert!(recs.iter().all(|x| x.within_limits && x.sample.is_some()));
    assert_eq!(r.robot.stats().missing_samples, 0);
    assert_eq!(r.robot.stats().protective_stops, 0);
    assert!(r.bus.now() >= Duration::from_secs(10));
    let leg = r.leg.lock().unwrap();
    let h: Vec<_> = leg.history().iter().filter(|x| x.t < 10.0 - 1e-9).collect();
    assert_eq!(h.len(), 1000);
    // Every applied torque within the motor's range.
    assert!(h.iter().all(|x| x.torque.amax() <= 18.0 + 1e-9));
    let sim = exompc::scenario::run_experiment::<TwoDof, 2>(&r.s, &mut []).unwrap();
    let can = [0, 1].map(|j| rms(&h.iter().map(|x| x.force_true[j]).collect::<Vec<_>>()));
    let want = [
        sim.rms_force_n.thigh.unwrap(),
        sim.rms_force_n.shank.unwrap(),
    ];
    eprintln!("fine {fine}: CAN {can:.3?} N, simulate {want:.3?} N");
    (can, want)
}

/// With fine MIT steps the loop over the bus (frame timing, polls, the robot's own grid)
/// reproduces `simulate` within 6 % RMS per strap. The bus's strap forces are 10-mN counts
/// through the loop's moving average: at slow phases a reading repeats bit for bit and the
/// supervisor rejects it as frozen for one sample (9 times in these 10 s), which is most of
/// the difference. Measured on 2026-12-05: 1.742 / 2.833 N against 1.703 / 2.681 N (+2.3 /
/// +5.7 %); 1.722 / 2.777 N (+1.1 / +3.6 %) before the EKF banks' updates over a force
/// fault's first steps (docs/RELIABILITY.md §2); 1.706 / 2.670 N with a force counted frozen
/// only on its second repeat (not kept: it cost two 1-s stuck-force cells of the fault scan).
#[test]
fn closed_loop_on_the_virtual_bus_matches_the_simulation() {
    let (can, want) = closed_loop(true);
    for j in 0..2 {
        assert!(
            (can[j] - want[j]).abs() <= 0.06 * want[j],
            "strap {j}: {can:?} vs {want:?}"
        );
    }
}

/// With the AK80-9's own ranges (velocity steps of 0.024 rad/s, readings dithered within the
/// step) the run stays within 5 % of `simulate` too (docs/HARDWARE.md has the figures).
#[test]
fn ak80_9_quantisation_stays_within_five_percent() {
    let (can, want) = closed_loop(false);
    for j in 0..2 {
        assert!(
            (can[j] - want[j]).abs() <= 0.05 * want[j],
            "strap {j}: {can:?} vs {want:?}"
        );
    }
}

fn expect_stop(
    r: &mut Rig,
    at: usize,
    inject: impl Fn(&Rig),
    cause: impl Fn(&CanStopCause) -> bool,
) {
    let recs = run(r, 200, |k, rig| {
        if k == at {
            inject(rig);
        }
    });
    let last = recs.last().unwrap();
    assert!(last.robot_stopped, "no protective stop");
    assert!(
        recs.len() > at && recs.len() < at + 10,
        "stopped after {} periods",
        recs.len()
    );
    assert_eq!(r.robot.state(), Lifecycle::Error);
    assert_eq!(r.robot.stats().protective_stops, 1);
    let ev = &r.robot.stop_events()[0];
    assert!(cause(&ev.cause), "{:?}", ev.cause);
}

#[test]
fn a_silent_motor_ends_in_a_protective_stop_with_the_torque_ramped_to_zero() {
    let mut r = rig();
    expect_stop(
        &mut r,
        100,
        |rig| rig.leg.lock().unwrap().motors_mut()[1].silent = true,
        |c| matches!(c, CanStopCause::DeviceTimeout(d) if d.contains("knee")),
    );
    let ev = r.robot.stop_events()[0].clone();
    assert!(ev.zero_at.is_some() && ev.ramp_send_failures == 0);
    // The hip motor, still listening, ramped to zero and left motor mode.
    let mut leg = r.leg.lock().unwrap();
    let hip = &leg.motors_mut()[0];
    assert!(!hip.motor_mode);
    assert!(hip.command.t.abs() < 0.01, "{:?}", hip.command);
}

/// The joint torques the leg applied from the period the stop began: each period's change stays
/// within the rate limit (plus one MIT torque step), and the ramp reaches zero.
fn stop_ramp_torques(stop_ramp: Duration, rate_per_s: f64) -> (f64, Vec<[f64; 2]>) {
    let mut r = rig_opts(false, stop_ramp, Some(rate_per_s), vec![force_node()]);
    let at = 100;
    expect_stop(
        &mut r,
        at,
        |rig| rig.leg.lock().unwrap().set_force_silent(true),
        |c| matches!(c, CanStopCause::DeviceTimeout(_)),
    );
    let rate = limits(&r.s).rate;
    let leg = r.leg.lock().unwrap();
    let torques: Vec<[f64; 2]> = leg.history()[at..]
        .iter()
        .map(|h| [h.torque[0], h.torque[1]])
        .collect();
    (rate, torques)
}

#[test]
fn the_protective_stop_ramps_within_the_rate_limit() {
    // 0.5 N·m per period: the torque at the stop needs several periods to reach zero.
    let (rate, tq) = stop_ramp_torques(Duration::ZERO, 50.0);
    let quantum = 2.0 * 18.0 / 4095.0;
    let biggest = tq[0][0].abs().max(tq[0][1].abs());
    assert!(
        biggest > 2.0 * rate,
        "torque at the stop {biggest} N·m: too small to test"
    );
    for w in tq.windows(2) {
        for (j, (a, b)) in w[0].iter().zip(&w[1]).enumerate() {
            let d = (b - a).abs();
            assert!(d <= rate + quantum, "joint {j}: step {d} N·m > {rate} N·m");
        }
    }
    let last = tq.last().unwrap();
    assert!(
        last[0].abs() < quantum && last[1].abs() < quantum,
        "{last:?}"
    );
}

#[test]
fn a_longer_stop_ramp_ramps_more_gently() {
    // 100 ms at 100 Hz: at least ten periods from the torque at the stop to zero.
    let (_, tq) = stop_ramp_torques(Duration::from_millis(100), 1000.0);
    let quantum = 2.0 * 18.0 / 4095.0;
    let zero = tq
        .iter()
        .position(|t| t[0].abs() < quantum && t[1].abs() < quantum)
        .expect("the ramp reaches zero");
    assert!(zero >= 10, "zero after {zero} periods");
}

#[test]
fn a_silent_force_node_ends_in_a_protective_stop() {
    let mut r = rig();
    expect_stop(
        &mut r,
        80,
        |rig| rig.leg.lock().unwrap().set_force_silent(true),
        |c| matches!(c, CanStopCause::DeviceTimeout(d) if d.contains("strap-force")),
    );
}

#[test]
fn a_drive_fault_ends_in_a_protective_stop() {
    let mut r = rig();
    expect_stop(
        &mut r,
        50,
        |rig| rig.leg.lock().unwrap().motors_mut()[0].fault = 3,
        |c| *c == CanStopCause::DriveFault("hip".into(), 3),
    );
}

#[test]
fn error_passive_ends_in_a_protective_stop_with_the_ramp_sent() {
    let mut r = rig();
    expect_stop(
        &mut r,
        60,
        |rig| rig.bus.set_state(rig.ep, BusState::ErrorPassive),
        |c| *c == CanStopCause::ErrorPassive,
    );
    assert!(r.robot.stop_events()[0].zero_at.is_some());
    let mut leg = r.leg.lock().unwrap();
    assert!(leg
        .motors_mut()
        .iter()
        .all(|m| !m.motor_mode && m.command.t.abs() < 0.01));
}

#[test]
fn bus_off_ends_in_a_protective_stop() {
    let mut r = rig();
    expect_stop(
        &mut r,
        60,
        |rig| rig.bus.set_state(rig.ep, BusState::BusOff),
        |c| *c == CanStopCause::BusOff,
    );
    // Off the bus, the ramp cannot reach the motors: counted, no zero time claimed.
    let ev = &r.robot.stop_events()[0];
    assert!(ev.zero_at.is_none() && ev.ramp_send_failures > 0);
}

#[test]
fn no_torque_before_every_device_is_ready() {
    let mut r = rig();
    r.leg.lock().unwrap().motors_mut()[1].silent = true;
    let mut clock = r.bus.clock();
    r.robot.configure().unwrap();
    let mut err = None;
    for _ in 0..10 {
        match r.robot.activate(Duration::from_millis(50)) {
            Ok(true) => panic!("activated without the knee motor"),
            Ok(false) => {}
            Err(e) => {
                err = Some(e);
                break;
            }
        }
    }
    let e = err.expect("ready timeout");
    assert!(e.to_string().contains("knee motor (CAN ID 2)"), "{e}");
    assert!(clock.now() >= Duration::from_millis(200));
    clock.sleep_until(clock.now() + Duration::from_millis(50));
    let mut leg = r.leg.lock().unwrap();
    // The hip motor got enter-motor-mode but not a single torque command.
    assert_eq!(leg.motors_mut()[0].commands, 0);
    assert_eq!(r.robot.state(), Lifecycle::Inactive);
}

/// RMS true strap forces (thigh, shank) of the first 3 s of a rig's closed loop; every sample
/// carries both straps' forces as the leg's sensors read them.
fn three_seconds(forces: Vec<RawForceSensor>) -> [f64; 2] {
    let mut r = rig_opts(true, Duration::ZERO, None, forces);
    let recs = run(&mut r, 300, |_, _| {});
    assert_eq!(recs.len(), 300);
    assert_eq!(r.robot.stats().protective_stops, 0);
    assert_eq!(r.robot.stats().missing_samples, 0);
    let last = recs.last().unwrap().sample.unwrap().force;
    let leg = r.leg.lock().unwrap();
    let truth = leg.history().last().unwrap().force_true;
    for j in 0..2 {
        assert!(
            (last[j] - truth[j]).abs() < 1.0,
            "strap {j}: read {last} vs true {truth}"
        );
    }
    let h = leg.history();
    [0, 1].map(|j| rms(&h.iter().map(|x| x.force_true[j]).collect::<Vec<_>>()))
}

/// Thigh and shank on force nodes of their own (other IDs, the shank at 500 Hz): the virtual
/// leg serves both and the loop runs as with one node.
#[test]
fn two_force_nodes_feed_the_loop() {
    let one = three_seconds(vec![force_node()]);
    let two = three_seconds(two_force_nodes());
    for j in 0..2 {
        assert!(
            (one[j] - two[j]).abs() <= 0.05 * one[j],
            "strap {j}: one node {one:?} vs two {two:?}"
        );
    }
}
