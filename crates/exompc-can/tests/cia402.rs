//! The CiA 402 master against the virtual drive on the simulated virtual bus: configuration by
//! SDO, the walk to operation enabled, cyclic synchronous torque with the drive's torque limit,
//! and every fault the master must turn into a stop (drive fault with EMCY, lost drive
//! heartbeat, lost master heartbeat at the drive, wrong rated torque).

use exompc_can::canopen::nmt::NmtState;
use exompc_can::canopen::sync::SyncProducer;
use exompc_can::canopen::NodeId;
use exompc_can::cia402::emulator::{Cia402Emulator, InertiaLoad};
use exompc_can::cia402::master::{Cia402Config, Cia402Master, DriveFault};
use exompc_can::cia402::{Mode, Scaling, State, ERROR_GENERIC, ERROR_HEARTBEAT};
use exompc_can::{CanBus, TimeBase, VirtualBus, VirtualBusSettings, VirtualEndpoint};
use std::sync::{Arc, Mutex};
use std::time::Duration;

const PERIOD: Duration = Duration::from_millis(10);

fn scaling() -> Scaling {
    Scaling {
        rated_torque: 0.5,
        gear_ratio: 40.0,
        direction: -1.0,
        zero_offset: 0.2,
        counts_per_rev: 4096.0,
        velocity_unit: std::f64::consts::TAU / 60.0,
    }
}

struct Rig {
    bus: VirtualBus,
    ep: VirtualEndpoint,
    drive: Arc<Mutex<Cia402Emulator>>,
    load: Arc<Mutex<InertiaLoad>>,
    master: Cia402Master,
    sync: SyncProducer,
}

fn rig(cfg: Cia402Config, drive_scaling: Scaling) -> Rig {
    let bus = VirtualBus::new(VirtualBusSettings::default(), TimeBase::Simulated);
    let ep = bus.endpoint();
    let load = Arc::new(Mutex::new(InertiaLoad::new(0.5, 2.0)));
    let drive = Arc::new(Mutex::new(Cia402Emulator::new(
        cfg.node,
        drive_scaling,
        Box::new(load.clone()),
    )));
    bus.attach(drive.clone());
    Rig {
        bus,
        ep,
        drive,
        load,
        master: Cia402Master::new(cfg),
        sync: SyncProducer::new(PERIOD, 0),
    }
}

impl Rig {
    fn now(&self) -> Duration {
        self.bus.now()
    }

    fn enable(&mut self) -> Result<(), DriveFault> {
        let bus = self.bus.clone();
        self.master
            .configure_and_enable(&mut self.ep, &|| bus.now())
    }

    /// One control period: heartbeat, RPDO, SYNC, then the TPDOs until the period ends.
    fn cycle(&mut self, tau: f64) -> Result<(), DriveFault> {
        let t0 = self.now();
        if let Some(hb) = self.master.heartbeat_frame(t0) {
            self.ep.send(&hb).unwrap();
        }
        self.ep.send(&self.master.command(tau)).unwrap();
        self.ep.send(&self.sync.emit()).unwrap();
        let end = t0 + PERIOD;
        loop {
            let now = self.now();
            if now >= end {
                break;
            }
            if let Some(f) = self.ep.recv(end - now).unwrap() {
                self.master.on_frame(&f, self.now());
            }
        }
        self.master.check(self.now())
    }
}

fn node(id: u32) -> NodeId {
    NodeId::new(id).unwrap()
}

#[test]
fn the_master_enables_the_drive_and_runs_cyclic_synchronous_torque() {
    let cfg = Cia402Config::new(node(3), scaling(), 12.0);
    let mut r = rig(cfg, scaling());
    r.enable().unwrap();
    assert_eq!(r.drive.lock().unwrap().state(), State::OperationEnabled);
    assert_eq!(r.drive.lock().unwrap().nmt_state(), NmtState::Operational);
    // 5 N·m at the joint: -5 / (40 · 0.5) · 1000 = -250 ‰ with direction -1.
    let step = scaling().gear_ratio * scaling().rated_torque / 1000.0;
    for _ in 0..50 {
        r.cycle(5.0).unwrap();
        let s = r.master.take_sample().expect("both TPDOs every period");
        assert_eq!(
            State::from_statusword(s.statusword),
            Some(State::OperationEnabled)
        );
    }
    let s = r.master.last_sample();
    assert!((s.torque - 5.0).abs() <= step / 2.0, "{}", s.torque);
    assert!((r.load.lock().unwrap().torque() - 5.0).abs() <= step / 2.0);
    // The joint moved positively under positive torque, and the master's angle and velocity
    // agree with the load's to the encoder and velocity resolution (one period old at most).
    let (q, qd) = {
        let l = *r.load.lock().unwrap();
        let mut l = l;
        exompc_can::cia402::emulator::DriveJoint::state(&mut l, s.at)
    };
    assert!(s.velocity > 1.0 && q > 0.2, "q {q} qd {qd}");
    // The load is at "now"; the sample was taken at the last SYNC, up to one period earlier.
    let lag = (r.now() - s.at).as_secs_f64() + 1e-3;
    assert!(
        (s.position - q).abs() < qd * lag + 1e-3,
        "{} vs {q}",
        s.position
    );
    let accel = (5.0 - 2.0 * qd) / 0.5;
    assert!(
        (s.velocity - qd).abs() < accel * lag + 0.01,
        "{} vs {qd}",
        s.velocity
    );
    // A command above the limit is clamped by the master; the drive's 0x6072 is the same.
    r.cycle(100.0).unwrap();
    r.cycle(100.0).unwrap();
    assert!((r.master.last_sample().torque - 12.0).abs() <= step / 2.0);
    assert_eq!(
        r.drive
            .lock()
            .unwrap()
            .stats()
            .lock()
            .unwrap()
            .torque_limited,
        0
    );
    assert_eq!(r.master.commanded_torque(f64::NAN), 0.0);
    // The protective stop: quick stop, zero torque.
    r.ep.send(&r.master.stop()).unwrap();
    r.ep.send(&r.sync.emit()).unwrap();
    r.ep.recv(Duration::from_millis(5)).unwrap();
    r.bus.advance_to(r.now() + Duration::from_millis(5));
    assert_eq!(r.load.lock().unwrap().torque(), 0.0);
    assert_ne!(r.drive.lock().unwrap().state(), State::OperationEnabled);
}

#[test]
fn the_drive_enforces_its_own_torque_limit() {
    // A master configured with a higher limit than the drive's 0x6072 written afterwards:
    // write 0x6072 directly to 100 ‰ and check the drive cuts the target.
    let cfg = Cia402Config::new(node(4), scaling(), 15.0);
    let mut r = rig(cfg, scaling());
    r.enable().unwrap();
    let bus = r.bus.clone();
    let mut c = exompc_can::canopen::sdo::SdoClient::new(node(4), Duration::from_millis(100));
    exompc_can::canopen::sdo::write(
        &mut r.ep,
        &|| bus.now(),
        &mut c,
        0x6072,
        0,
        &100u16.to_le_bytes(),
        &mut |_| {},
    )
    .unwrap();
    for _ in 0..3 {
        r.cycle(15.0).unwrap();
    }
    let step = scaling().gear_ratio * scaling().rated_torque / 1000.0;
    assert!((r.load.lock().unwrap().torque() - 100.0 * step).abs() < 1e-9);
    assert!((r.master.last_sample().torque - 2.0).abs() < 1e-9);
    assert_ne!(
        r.master.last_sample().statusword & 0x0800,
        0,
        "internal limit active"
    );
    assert!(
        r.drive
            .lock()
            .unwrap()
            .stats()
            .lock()
            .unwrap()
            .torque_limited
            > 0
    );
}

#[test]
fn a_drive_fault_is_reported_with_its_error_code_and_reset_on_the_next_enable() {
    let cfg = Cia402Config::new(node(5), scaling(), 10.0);
    let mut r = rig(cfg, scaling());
    r.enable().unwrap();
    r.cycle(3.0).unwrap();
    let inject = Cia402Emulator::fault_injector(&r.drive);
    inject(ERROR_GENERIC);
    let err = (0..5).find_map(|_| r.cycle(3.0).err()).expect("fault seen");
    match err {
        DriveFault::Fault { code, .. } => assert_eq!(code, ERROR_GENERIC),
        e => panic!("{e}"),
    }
    let _ = r.cycle(3.0);
    let sw = r.master.last_sample().statusword;
    assert_eq!(State::from_statusword(sw), Some(State::Fault));
    assert!(err_text(&r).contains("0x1000"));
    assert_eq!(r.load.lock().unwrap().torque(), 0.0, "no torque in fault");
    // Restart on command: the master resets the fault and enables again.
    r.enable().unwrap();
    r.cycle(3.0).unwrap();
    assert!(r.load.lock().unwrap().torque() > 2.9);
}

fn err_text(r: &Rig) -> String {
    let mut m = r.master.clone();
    m.check(r.now()).unwrap_err().to_string()
}

#[test]
fn a_silent_drive_is_lost_within_the_heartbeat_timeout() {
    let cfg = Cia402Config::new(node(6), scaling(), 10.0);
    let timeout = cfg.heartbeat_timeout;
    let mut r = rig(cfg, scaling());
    r.enable().unwrap();
    for _ in 0..20 {
        r.cycle(1.0).unwrap();
    }
    let cut = r.now();
    r.drive.lock().unwrap().set_silent(true);
    let err = (0..100).find_map(|_| r.cycle(1.0).err()).expect("lost");
    let DriveFault::HeartbeatLost { silent, .. } = err else {
        panic!("{err}")
    };
    let detected = r.now() - cut;
    assert!(silent > timeout);
    // Heartbeat every 50 ms, timeout 150 ms: detected within 150 + 50 + one period.
    assert!(
        detected <= timeout + Duration::from_millis(60),
        "{detected:?}"
    );
}

#[test]
fn the_drive_faults_when_the_master_heartbeat_stops() {
    let cfg = Cia402Config::new(node(7), scaling(), 10.0);
    let mut r = rig(cfg, scaling());
    r.enable().unwrap();
    for _ in 0..10 {
        r.cycle(2.0).unwrap();
    }
    // The master dies: no more frames; the drive must drop the torque by itself.
    r.bus.advance_to(r.now() + Duration::from_millis(200));
    assert_eq!(r.drive.lock().unwrap().state(), State::Fault);
    assert_eq!(r.load.lock().unwrap().torque(), 0.0);
    let mut got_emcy = None;
    while let Some(f) = r.ep.recv(Duration::from_millis(1)).unwrap() {
        if f.id().raw() == 0x87 {
            got_emcy = Some(u16::from_le_bytes([f.data()[0], f.data()[1]]));
        }
        r.master.on_frame(&f, r.now());
    }
    assert_eq!(got_emcy, Some(ERROR_HEARTBEAT));
    assert!(matches!(
        r.master.check(r.now()),
        Err(DriveFault::Fault {
            code: ERROR_HEARTBEAT,
            ..
        })
    ));
}

#[test]
fn a_drive_with_another_rated_torque_is_refused() {
    let cfg = Cia402Config::new(node(8), scaling(), 10.0);
    let mut other = scaling();
    other.rated_torque = 0.6;
    let mut r = rig(cfg, other);
    let e = r.enable().unwrap_err();
    assert!(
        matches!(
            e,
            DriveFault::RatedTorque {
                reported: 600,
                configured: 500,
                ..
            }
        ),
        "{e}"
    );
    assert!(e.to_string().contains("rated_torque"));
    assert_eq!(r.drive.lock().unwrap().state(), State::SwitchOnDisabled);
}

#[test]
fn profile_torque_applies_the_target_without_sync() {
    let mut cfg = Cia402Config::new(node(9), scaling(), 10.0);
    cfg.mode = Mode::ProfileTorque;
    let mut r = rig(cfg, scaling());
    r.enable().unwrap();
    r.ep.send(&r.master.command(4.0)).unwrap();
    r.bus.advance_to(r.now() + Duration::from_millis(1));
    assert!((r.load.lock().unwrap().torque() - 4.0).abs() < 0.02);
}

#[test]
fn an_absent_drive_times_out_in_configuration() {
    let bus = VirtualBus::new(VirtualBusSettings::default(), TimeBase::Simulated);
    let mut ep = bus.endpoint();
    let mut m = Cia402Master::new(Cia402Config::new(node(10), scaling(), 10.0));
    let b = bus.clone();
    let e = m.configure_and_enable(&mut ep, &|| b.now()).unwrap_err();
    assert!(e.to_string().contains("no answer within 200ms"), "{e}");
}
