//! A virtual CiA 402 drive on a [`VirtualBus`](crate::VirtualBus): NMT, an SDO server over its
//! object dictionary, PDOs configured by SDO, heartbeat producer and consumer (a lost master
//! heartbeat is a fault), the device state machine, cyclic synchronous or profile torque with
//! the max-torque limit 0x6072, and faults reported by EMCY. A [`DriveJoint`] (the simulated leg,
//! or a test load) turns the torque into motion.

use super::{obj, DriveStateMachine, Mode, Scaling, State, DEVICE_TYPE_SERVO, ERROR_HEARTBEAT};
use crate::canopen::heartbeat::{self, HeartbeatConsumer, HeartbeatProducer};
use crate::canopen::nmt::{NmtCommand, NmtState};
use crate::canopen::od::{Access, Allowed, DataType, ObjectDictionary};
use crate::canopen::pdo::{self, ActivePdo, Direction};
use crate::canopen::sdo::SdoServer;
use crate::canopen::{cob, frame, std_id, sync, NodeId};
use crate::virtual_bus::{NodeTx, VirtualNode};
use crate::CanFrame;
use std::sync::{Arc, Mutex};
use std::time::Duration;

/// What the drive moves: its joint's angle and velocity, and the torque it applies.
pub trait DriveJoint: Send {
    /// Joint angle (rad) and velocity (rad/s) at bus time `now`.
    fn state(&mut self, now: Duration) -> (f64, f64);
    /// Apply joint torque `tau` (N·m) from bus time `now` on.
    fn set_torque(&mut self, now: Duration, tau: f64);
}

/// A rigid inertia with viscous damping, integrated exactly between calls: the load of the
/// drive tests.
#[derive(Clone, Copy, Debug)]
pub struct InertiaLoad {
    /// Inertia (kg·m²).
    pub inertia: f64,
    /// Viscous damping (N·m·s/rad).
    pub damping: f64,
    q: f64,
    qd: f64,
    tau: f64,
    t: Duration,
}

impl InertiaLoad {
    /// A load at rest at angle 0.
    pub fn new(inertia: f64, damping: f64) -> Self {
        Self {
            inertia,
            damping,
            q: 0.0,
            qd: 0.0,
            tau: 0.0,
            t: Duration::ZERO,
        }
    }

    /// The torque applied now.
    pub fn torque(&self) -> f64 {
        self.tau
    }

    fn advance(&mut self, now: Duration) {
        let dt = now.saturating_sub(self.t).as_secs_f64();
        self.t = self.t.max(now);
        if dt == 0.0 {
            return;
        }
        // J qdd = tau - b qd: exact for constant tau.
        let a = self.damping / self.inertia;
        let v_inf = self.tau / self.damping;
        let e = (-a * dt).exp();
        let qd1 = v_inf + (self.qd - v_inf) * e;
        self.q += v_inf * dt + (self.qd - v_inf) * (1.0 - e) / a;
        self.qd = qd1;
    }
}

impl DriveJoint for InertiaLoad {
    fn state(&mut self, now: Duration) -> (f64, f64) {
        self.advance(now);
        (self.q, self.qd)
    }

    fn set_torque(&mut self, now: Duration, tau: f64) {
        self.advance(now);
        self.tau = tau;
    }
}

impl<J: DriveJoint> DriveJoint for Arc<Mutex<J>> {
    fn state(&mut self, now: Duration) -> (f64, f64) {
        self.lock().unwrap_or_else(|e| e.into_inner()).state(now)
    }

    fn set_torque(&mut self, now: Duration, tau: f64) {
        self.lock()
            .unwrap_or_else(|e| e.into_inner())
            .set_torque(now, tau)
    }
}

/// Counters of the emulated drive.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct EmulatorStats {
    /// SYNCs received while operational.
    pub syncs: u64,
    /// SDO requests served.
    pub sdo_requests: u64,
    /// RPDOs applied.
    pub rpdos: u64,
    /// TPDOs sent.
    pub tpdos: u64,
    /// Times the torque target was cut by the max torque 0x6072.
    pub torque_limited: u64,
    /// Faults entered.
    pub faults: u64,
}

/// The emulated drive.
pub struct Cia402Emulator {
    node: NodeId,
    scaling: Scaling,
    od: ObjectDictionary,
    initial: ObjectDictionary,
    sdo: SdoServer,
    nmt: NmtState,
    fsm: DriveStateMachine,
    producer: HeartbeatProducer,
    consumer: HeartbeatConsumer,
    rpdos: Vec<ActivePdo>,
    tpdos: Vec<ActivePdo>,
    sync_count: u32,
    joint: Box<dyn DriveJoint>,
    tick: Duration,
    next_tick: Duration,
    booted: bool,
    pending_fault: Option<u16>,
    silent: bool,
    stats: Arc<Mutex<EmulatorStats>>,
}

/// The emulator's tick (heartbeat, consumer and SDO timers).
const TICK: Duration = Duration::from_millis(1);

impl Cia402Emulator {
    /// A drive with node id `node`, the mechanics `scaling` (its 0x6076 is the scaling's
    /// rated torque) and the joint it moves. It boots at bus time 0.
    pub fn new(node: NodeId, scaling: Scaling, joint: Box<dyn DriveJoint>) -> Self {
        let od = Self::dictionary(node, &scaling);
        Self {
            node,
            scaling,
            initial: od.clone(),
            od,
            sdo: SdoServer::new(node, Duration::from_millis(500)),
            nmt: NmtState::BootUp,
            fsm: DriveStateMachine::default(),
            producer: HeartbeatProducer::new(node, Duration::ZERO),
            consumer: HeartbeatConsumer::new(),
            rpdos: Vec::new(),
            tpdos: Vec::new(),
            sync_count: 0,
            joint,
            tick: TICK,
            next_tick: Duration::ZERO,
            booted: false,
            pending_fault: None,
            silent: false,
            stats: Arc::default(),
        }
    }

    /// The drive's object dictionary at power-on: CiA 301 communication objects with all PDOs
    /// disabled, and the CiA 402 objects of a torque drive.
    pub fn dictionary(node: NodeId, scaling: &Scaling) -> ObjectDictionary {
        let mut od = ObjectDictionary::new();
        let rated_mnm = (scaling.rated_torque * 1000.0).round() as i64;
        od.add(
            obj::DEVICE_TYPE,
            0,
            DataType::U32,
            Access::Ro,
            false,
            i64::from(DEVICE_TYPE_SERVO),
        )
        .add(obj::ERROR_REGISTER, 0, DataType::U8, Access::Ro, true, 0)
        .add(
            obj::HEARTBEAT_CONSUMER,
            0,
            DataType::U8,
            Access::Const,
            false,
            1,
        )
        .add(
            obj::HEARTBEAT_CONSUMER,
            1,
            DataType::U32,
            Access::Rw,
            false,
            0,
        )
        .add(
            obj::HEARTBEAT_PRODUCER,
            0,
            DataType::U16,
            Access::Rw,
            false,
            0,
        )
        .add(0x1018, 0, DataType::U8, Access::Const, false, 1)
        .add(0x1018, 1, DataType::U32, Access::Ro, false, 0x0000_0E50)
        .add(obj::ERROR_CODE, 0, DataType::U16, Access::Ro, true, 0)
        .add(obj::CONTROLWORD, 0, DataType::U16, Access::Rw, true, 0)
        .add(obj::STATUSWORD, 0, DataType::U16, Access::Ro, true, 0)
        .add(
            obj::QUICK_STOP_OPTION,
            0,
            DataType::I16,
            Access::Rw,
            false,
            2,
        )
        .add(
            obj::MODES_OF_OPERATION,
            0,
            DataType::I8,
            Access::Rw,
            true,
            0,
        )
        .add(obj::MODES_DISPLAY, 0, DataType::I8, Access::Ro, true, 0)
        .add(obj::POSITION_ACTUAL, 0, DataType::I32, Access::Ro, true, 0)
        .add(obj::VELOCITY_ACTUAL, 0, DataType::I32, Access::Ro, true, 0)
        .add(obj::TARGET_TORQUE, 0, DataType::I16, Access::Rw, true, 0)
        .add(obj::MAX_TORQUE, 0, DataType::U16, Access::Rw, true, 1000)
        .add(
            obj::RATED_TORQUE,
            0,
            DataType::U32,
            Access::Ro,
            false,
            rated_mnm,
        )
        .add(obj::TORQUE_ACTUAL, 0, DataType::I16, Access::Ro, true, 0)
        .add(
            obj::SUPPORTED_MODES,
            0,
            DataType::U32,
            Access::Ro,
            false,
            1 << 3 | 1 << 9,
        );
        od.add_bytes(
            0x1008,
            0,
            DataType::VisibleString,
            Access::Const,
            b"exompc CiA 402 drive",
        );
        od.restrict(obj::MODES_OF_OPERATION, 0, Allowed::OneOf(vec![0, 4, 10]));
        od.restrict(obj::QUICK_STOP_OPTION, 0, Allowed::Range(0, 8));
        od.restrict(obj::MAX_TORQUE, 0, Allowed::Range(0, 32767));
        pdo::add_parameters(&mut od, Direction::Rx, node);
        pdo::add_parameters(&mut od, Direction::Tx, node);
        od
    }

    /// Shared counters, readable while the bus owns the emulator.
    pub fn stats(&self) -> Arc<Mutex<EmulatorStats>> {
        self.stats.clone()
    }

    /// The drive's node id.
    pub fn node(&self) -> NodeId {
        self.node
    }

    /// A handle that injects a fault (0x603F `code`) at the drive's next tick.
    pub fn fault_injector(this: &Arc<Mutex<Self>>) -> impl Fn(u16) + Send + Sync + 'static {
        let this = this.clone();
        move |code| this.lock().unwrap_or_else(|e| e.into_inner()).pending_fault = Some(code)
    }

    /// Inject a fault (0x603F `code`) at the drive's next tick.
    pub fn inject_fault(&mut self, code: u16) {
        self.pending_fault = Some(code);
    }

    /// Go silent (a cut cable, a dead drive): no frame in or out from now on.
    pub fn set_silent(&mut self, silent: bool) {
        self.silent = silent;
    }

    /// The current state of the state machine.
    pub fn state(&self) -> State {
        self.fsm.state()
    }

    /// The NMT state.
    pub fn nmt_state(&self) -> NmtState {
        self.nmt
    }

    fn stat(&self, f: impl FnOnce(&mut EmulatorStats)) {
        f(&mut self.stats.lock().unwrap_or_else(|e| e.into_inner()));
    }

    fn refresh_pdos(&mut self) {
        self.rpdos = pdo::active(&self.od, Direction::Rx);
        self.tpdos = pdo::active(&self.od, Direction::Tx);
    }

    fn refresh_heartbeats(&mut self) {
        let ms = self.od.get(obj::HEARTBEAT_PRODUCER, 0).unwrap_or(0) as u64;
        self.producer.set_period(Duration::from_millis(ms));
        self.consumer = HeartbeatConsumer::new();
        let c = self.od.get(obj::HEARTBEAT_CONSUMER, 1).unwrap_or(0) as u32;
        let (id, ms) = ((c >> 16) & 0x7F, c & 0xFFFF);
        if let (Ok(id), true) = (NodeId::new(id), ms > 0) {
            self.consumer
                .watch(id, Duration::from_millis(u64::from(ms)));
        }
    }

    fn quick_stop_to_disabled(&self) -> bool {
        (0..=4).contains(&self.od.get(obj::QUICK_STOP_OPTION, 0).unwrap_or(2))
    }

    fn enter_fault(&mut self, code: u16, now: Duration, tx: &mut NodeTx) {
        if matches!(self.fsm.state(), State::Fault | State::FaultReactionActive) {
            return;
        }
        self.fsm.fault();
        self.od.set(obj::ERROR_CODE, 0, i64::from(code));
        self.od.set(obj::ERROR_REGISTER, 0, 0x01);
        self.joint.set_torque(now, 0.0);
        self.stat(|s| s.faults += 1);
        let c = code.to_le_bytes();
        tx.send_at(
            now,
            frame(self.node.cob(cob::EMCY), &[c[0], c[1], 0x01, 0, 0, 0, 0, 0]),
        );
    }

    /// The torque the power stage applies now (joint N·m): the target, clamped by 0x6072, in
    /// operation enabled; 0 otherwise.
    fn apply_torque(&mut self, now: Duration) {
        let tau = if self.fsm.torque_enabled() {
            let target = self.od.get(obj::TARGET_TORQUE, 0).unwrap_or(0);
            let max = self.od.get(obj::MAX_TORQUE, 0).unwrap_or(0);
            let limited = target.clamp(-max, max);
            if limited != target {
                self.stat(|s| s.torque_limited += 1);
            }
            self.od.set(obj::TORQUE_ACTUAL, 0, limited);
            self.scaling.joint_torque(limited as i16)
        } else {
            self.od.set(obj::TORQUE_ACTUAL, 0, 0);
            0.0
        };
        self.joint.set_torque(now, tau);
    }

    fn update_status(&mut self, now: Duration) {
        let (q, qd) = self.joint.state(now);
        self.od
            .set(obj::POSITION_ACTUAL, 0, i64::from(self.scaling.counts(q)));
        self.od.set(
            obj::VELOCITY_ACTUAL,
            0,
            i64::from(self.scaling.velocity_units(qd)),
        );
        let mode = self.od.get(obj::MODES_OF_OPERATION, 0).unwrap_or(0);
        self.od.set(obj::MODES_DISPLAY, 0, mode);
        let limited = self.fsm.torque_enabled()
            && self.od.get(obj::TARGET_TORQUE, 0).unwrap_or(0).abs()
                > self.od.get(obj::MAX_TORQUE, 0).unwrap_or(0);
        // Bit 9 remote, bit 11 internal limit active.
        let sw = self.fsm.state().statusword_bits() | 0x0200 | if limited { 0x0800 } else { 0 };
        self.od.set(obj::STATUSWORD, 0, i64::from(sw));
    }

    /// A new controlword: the state machine moves; torque off takes effect at once, a new
    /// target in profile torque too, in CST only at the next SYNC.
    fn on_controlword(&mut self, now: Duration) {
        let cw = self.od.get(obj::CONTROLWORD, 0).unwrap_or(0) as u16;
        self.fsm.on_controlword(cw);
        if !self.fsm.torque_enabled() || self.mode() == Some(Mode::ProfileTorque) {
            self.apply_torque(now);
        }
        self.update_status(now);
    }

    fn mode(&self) -> Option<Mode> {
        Mode::from_code(self.od.get(obj::MODES_OF_OPERATION, 0).unwrap_or(0) as i8)
    }

    fn reset(&mut self, full: bool, now: Duration, tx: &mut NodeTx) {
        if full {
            self.od = self.initial.clone();
            self.fsm.reset();
        } else {
            for index in (0x1000..0x2000).filter(|i| *i != obj::ERROR_REGISTER) {
                for sub in 0..=8u8 {
                    if let Some(e) = self.initial.entry(index, sub) {
                        let b = e.bytes().to_vec();
                        self.od.set_bytes(index, sub, &b);
                    }
                }
            }
        }
        self.refresh_pdos();
        self.refresh_heartbeats();
        self.nmt = NmtState::PreOperational;
        tx.send_at(now, heartbeat::boot_up(self.node));
        self.joint.set_torque(now, 0.0);
        self.update_status(now);
    }
}

impl VirtualNode for Cia402Emulator {
    fn on_frame(&mut self, now: Duration, f: &CanFrame, tx: &mut NodeTx) {
        if self.silent || !self.booted {
            return;
        }
        if let Some((cmd, target)) = NmtCommand::decode(f) {
            if NmtCommand::addresses(target, self.node) {
                match cmd {
                    NmtCommand::ResetNode => self.reset(true, now, tx),
                    NmtCommand::ResetCommunication => self.reset(false, now, tx),
                    _ => self.nmt = self.nmt.after(cmd),
                }
            }
            return;
        }
        if self.consumer.on_frame(f, now).is_some() || self.nmt == NmtState::Stopped {
            return;
        }
        let Some(id) = std_id(f) else { return };
        if id == self.node.cob(cob::SDO_RX) {
            if let Some(served) = self.sdo.on_frame(f, &mut self.od, now) {
                self.stat(|s| s.sdo_requests += 1);
                tx.send_at(now, served.response);
                match served.written {
                    Some((obj::CONTROLWORD, 0)) => self.on_controlword(now),
                    Some((obj::TARGET_TORQUE | obj::MAX_TORQUE, 0))
                        if self.mode() == Some(Mode::ProfileTorque) =>
                    {
                        self.apply_torque(now)
                    }
                    Some((obj::HEARTBEAT_CONSUMER | obj::HEARTBEAT_PRODUCER, _)) => {
                        self.refresh_heartbeats()
                    }
                    Some((index, _)) if (0x1400..0x1C00).contains(&index) => self.refresh_pdos(),
                    _ => {}
                }
            }
            return;
        }
        if self.nmt != NmtState::Operational {
            return;
        }
        if sync::is_sync(f) {
            self.stat(|s| s.syncs += 1);
            self.sync_count = self.sync_count.wrapping_add(1);
            // CST: the targets received since the last SYNC apply now; then the actual values
            // are sampled and the synchronous TPDOs sent.
            self.apply_torque(now);
            self.update_status(now);
            for p in &self.tpdos {
                let tt = u32::from(p.transmission_type);
                if (1..=240).contains(&tt) && self.sync_count.is_multiple_of(tt) {
                    tx.send_at(now, p.pack(&self.od));
                    self.stats.lock().unwrap_or_else(|e| e.into_inner()).tpdos += 1;
                }
            }
            return;
        }
        let mut cw_written = false;
        for p in &self.rpdos {
            if let Some(w) = p.apply(f, &mut self.od) {
                self.stats.lock().unwrap_or_else(|e| e.into_inner()).rpdos += 1;
                cw_written |= w.contains(&(obj::CONTROLWORD, 0));
            }
        }
        if cw_written {
            self.on_controlword(now);
        } else if self.mode() == Some(Mode::ProfileTorque) {
            self.apply_torque(now);
        }
    }

    fn next_wakeup(&self) -> Option<Duration> {
        Some(self.next_tick)
    }

    fn on_wakeup(&mut self, now: Duration, tx: &mut NodeTx) {
        self.next_tick = now + self.tick;
        if self.silent {
            // Cut off the bus, the drive still watches the master's heartbeat: it faults and
            // drops the torque by itself once that is lost (it cannot send the EMCY).
            if self.consumer.check(now).is_some() {
                let mut sink = NodeTx::default();
                self.enter_fault(ERROR_HEARTBEAT, now, &mut sink);
            }
            return;
        }
        if !self.booted {
            self.booted = true;
            self.reset(true, now, tx);
            self.fsm.step(true);
            self.update_status(now);
            return;
        }
        if let Some(code) = self.pending_fault.take() {
            self.enter_fault(code, now, tx);
        }
        if self.consumer.check(now).is_some() {
            self.enter_fault(ERROR_HEARTBEAT, now, tx);
        }
        let before = self.fsm.state();
        self.fsm.step(self.quick_stop_to_disabled());
        if before != self.fsm.state() || before == State::QuickStopActive {
            self.apply_torque(now);
        }
        self.update_status(now);
        if let Some(hb) = self.producer.poll(now, self.nmt) {
            tx.send_at(now, hb);
        }
        if let Some(abort) = self.sdo.poll(now) {
            tx.send_at(now, abort);
        }
    }
}
