//! CANopen strap-force sensor nodes (CiA 404-style analog inputs): the thigh and shank process
//! values 0x7130 sub 1 and 2 (INTEGER16), mapped into a TPDO sent on every SYNC;
//! N = value × scale + offset. [`ForceNodeEmulator`] is a virtual node. (A custom amplifier's
//! raw frame is [`crate::config::RawForceSensor`].)

use crate::canopen::heartbeat::{HeartbeatConsumer, HeartbeatProducer};
use crate::canopen::nmt::{NmtCommand, NmtState};
use crate::canopen::od::{Access, DataType, ObjectDictionary};
use crate::canopen::pdo::{self, ActivePdo, Direction, Mapped, PdoConfig};
use crate::canopen::sdo::{self, Now, SdoClient, SdoError, SdoServer};
use crate::canopen::{cob, heartbeat, std_id, sync, NodeId};
use crate::virtual_bus::{NodeTx, VirtualNode};
use crate::{CanBus, CanFrame};
use std::time::Duration;
use thiserror::Error;

/// CiA 404 analog input process value (INTEGER16), sub 1 thigh, sub 2 shank.
pub const AI_PROCESS_VALUE: u16 = 0x7130;
/// CiA 404 analog input field value (INTEGER16, the raw ADC reading).
pub const AI_FIELD_VALUE: u16 = 0x7100;

/// Where the strap forces come from.
#[derive(Clone, Debug, PartialEq)]
pub enum ForceSource {
    /// A CANopen node's TPDO with the two analog-input process values.
    Canopen {
        /// The node.
        node: NodeId,
        /// The TPDO's COB-ID (default 0x180 + node id).
        cob_id: u16,
        /// N per process-value count.
        scale: f64,
        /// N added after scaling (thigh, shank).
        offset: [f64; 2],
        /// Configure the node's TPDO1 and heartbeat by SDO and start it; otherwise only listen.
        configure: bool,
        /// Heartbeat period asked of the node (when configuring) and the timeout watched.
        heartbeat: Option<(Duration, Duration)>,
    },
}

/// The newest strap forces.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ForceSample {
    /// Thigh strap force (N).
    pub thigh: f64,
    /// Shank strap force (N).
    pub shank: f64,
    /// Bus time of the frame.
    pub at: Duration,
}

/// Why the sensor cannot be used.
#[derive(Debug, Error)]
pub enum ForceNodeError {
    /// Configuration by SDO failed.
    #[error("force sensor node {node}: configuration failed: {source}")]
    Sdo {
        /// The node.
        node: NodeId,
        /// The SDO error.
        source: SdoError,
    },
    /// The bus failed.
    #[error("force sensor: {0}")]
    Bus(#[from] crate::BusError),
    /// No heartbeat within the timeout.
    #[error("force sensor node {node}: no heartbeat for {silent:?}")]
    HeartbeatLost {
        /// The node.
        node: NodeId,
        /// Time since the last one.
        silent: Duration,
    },
}

/// The master's side of a strap-force sensor.
#[derive(Clone, Debug)]
pub struct ForceSensor {
    source: ForceSource,
    heartbeat: HeartbeatConsumer,
    sample: Option<ForceSample>,
    fresh: bool,
    lost: Option<Duration>,
}

impl ForceSensor {
    /// A sensor reading `source`.
    pub fn new(source: ForceSource) -> Self {
        let mut heartbeat = HeartbeatConsumer::new();
        if let ForceSource::Canopen {
            node,
            heartbeat: Some((_, timeout)),
            ..
        } = &source
        {
            heartbeat.watch(*node, *timeout);
        }
        Self {
            source,
            heartbeat,
            sample: None,
            fresh: false,
            lost: None,
        }
    }

    /// The TPDO the master maps on a CANopen node: both process values, every SYNC.
    pub fn tpdo(cob_id: u16) -> PdoConfig {
        PdoConfig {
            cob_id,
            transmission_type: 1,
            mapping: vec![
                Mapped::new(AI_PROCESS_VALUE, 1, 16),
                Mapped::new(AI_PROCESS_VALUE, 2, 16),
            ],
        }
    }

    /// For a CANopen node with `configure`: map its TPDO1, set its heartbeat, start it.
    /// Nothing to do otherwise. Blocking.
    pub fn configure<B: CanBus + ?Sized>(
        &mut self,
        bus: &mut B,
        now: Now<'_>,
    ) -> Result<(), ForceNodeError> {
        let ForceSource::Canopen {
            node,
            cob_id,
            configure: true,
            heartbeat,
            ..
        } = self.source.clone()
        else {
            return Ok(());
        };
        bus.send(&NmtCommand::EnterPreOperational.frame(Some(node)))?;
        let mut c = SdoClient::new(node, Duration::from_millis(200));
        let mut writes = Self::tpdo(cob_id).sdo_writes(Direction::Tx, 0);
        if let Some((period, _)) = heartbeat {
            let ms = period.as_millis().min(0xFFFF) as u16;
            writes.push((0x1017, 0, ms.to_le_bytes().to_vec()));
        }
        let mut other = Vec::new();
        for (index, sub, data) in writes {
            sdo::write(bus, now, &mut c, index, sub, &data, &mut |f| other.push(*f))
                .map_err(|source| ForceNodeError::Sdo { node, source })?;
        }
        for f in &other {
            self.on_frame(f, now());
        }
        bus.send(&NmtCommand::Start.frame(Some(node)))?;
        Ok(())
    }

    /// Feed a received frame; `true` when it was the sensor's.
    pub fn on_frame(&mut self, f: &CanFrame, now: Duration) -> bool {
        if self.heartbeat.on_frame(f, now).is_some() {
            return true;
        }
        let forces = match &self.source {
            ForceSource::Canopen {
                cob_id,
                scale,
                offset,
                ..
            } => {
                if std_id(f) != Some(*cob_id) || f.len() < 4 {
                    return false;
                }
                let d = f.data();
                let pv = |i: usize| f64::from(i16::from_le_bytes([d[2 * i], d[2 * i + 1]]));
                [pv(0) * scale + offset[0], pv(1) * scale + offset[1]]
            }
        };
        self.sample = Some(ForceSample {
            thigh: forces[0],
            shank: forces[1],
            at: now,
        });
        self.fresh = true;
        true
    }

    /// The newest sample if one arrived since the last call.
    pub fn take_sample(&mut self) -> Option<ForceSample> {
        if self.fresh {
            self.fresh = false;
            self.sample
        } else {
            None
        }
    }

    /// The newest sample, fresh or not.
    pub fn last_sample(&self) -> Option<ForceSample> {
        self.sample
    }

    /// Heartbeat check (CANopen nodes with a heartbeat): latched once lost.
    pub fn check(&mut self, now: Duration) -> Result<(), ForceNodeError> {
        if let Some(t) = self.heartbeat.check(now) {
            self.lost = Some(t.silent_for);
        }
        match (&self.source, self.lost) {
            (ForceSource::Canopen { node, .. }, Some(silent)) => {
                Err(ForceNodeError::HeartbeatLost {
                    node: *node,
                    silent,
                })
            }
            (_, None) => Ok(()),
        }
    }
}

/// What the virtual sensor measures.
pub trait StrapForces: Send {
    /// Thigh and shank strap forces (N) at bus time `now`.
    fn forces(&mut self, now: Duration) -> (f64, f64);
}

impl<F: FnMut(Duration) -> (f64, f64) + Send> StrapForces for F {
    fn forces(&mut self, now: Duration) -> (f64, f64) {
        self(now)
    }
}

/// A virtual CANopen strap-force node: analog inputs 0x7100/0x7130 sub 1-2, TPDOs configured
/// by SDO (none mapped at power-on unless `default_tpdo`), heartbeat, NMT.
pub struct ForceNodeEmulator {
    node: NodeId,
    scale: f64,
    od: ObjectDictionary,
    sdo: SdoServer,
    nmt: NmtState,
    producer: HeartbeatProducer,
    tpdos: Vec<ActivePdo>,
    source: Box<dyn StrapForces>,
    next_tick: Duration,
    booted: bool,
    silent: bool,
    sync_count: u32,
}

impl ForceNodeEmulator {
    /// A node at `node` measuring `source`, reporting N / `scale` counts (saturated to
    /// INTEGER16). With `default_tpdo`, TPDO1 (0x180 + id, both values, every SYNC) is mapped
    /// at power-on, as a sensor configured once by its maker would be.
    pub fn new(node: NodeId, scale: f64, default_tpdo: bool, source: Box<dyn StrapForces>) -> Self {
        let mut od = ObjectDictionary::new();
        od.add(0x1000, 0, DataType::U32, Access::Ro, false, 0x0002_0194)
            .add(0x1001, 0, DataType::U8, Access::Ro, true, 0)
            .add(0x1017, 0, DataType::U16, Access::Rw, false, 0);
        for index in [AI_FIELD_VALUE, AI_PROCESS_VALUE] {
            od.add(index, 0, DataType::U8, Access::Const, false, 2);
            od.add(index, 1, DataType::I16, Access::Ro, true, 0);
            od.add(index, 2, DataType::I16, Access::Ro, true, 0);
        }
        pdo::add_parameters(&mut od, Direction::Tx, node);
        if default_tpdo {
            for (index, sub, data) in
                ForceSensor::tpdo(node.cob(cob::TPDO[0])).sdo_writes(Direction::Tx, 0)
            {
                let _ = od.write(index, sub, &data);
            }
        }
        let tpdos = pdo::active(&od, Direction::Tx);
        Self {
            node,
            scale,
            od,
            sdo: SdoServer::new(node, Duration::from_millis(500)),
            nmt: NmtState::BootUp,
            producer: HeartbeatProducer::new(node, Duration::ZERO),
            tpdos,
            source,
            next_tick: Duration::ZERO,
            booted: false,
            silent: false,
            sync_count: 0,
        }
    }

    /// Go silent (cut cable).
    pub fn set_silent(&mut self, silent: bool) {
        self.silent = silent;
    }

    fn sample(&mut self, now: Duration) {
        let (a, b) = self.source.forces(now);
        for (sub, f) in [(1u8, a), (2u8, b)] {
            let pv = if f.is_finite() {
                (f / self.scale).round().clamp(-32768.0, 32767.0)
            } else {
                0.0
            } as i64;
            self.od.set(AI_FIELD_VALUE, sub, pv);
            self.od.set(AI_PROCESS_VALUE, sub, pv);
        }
    }
}

impl VirtualNode for ForceNodeEmulator {
    fn on_frame(&mut self, now: Duration, f: &CanFrame, tx: &mut NodeTx) {
        if self.silent || !self.booted {
            return;
        }
        if let Some((cmd, target)) = NmtCommand::decode(f) {
            if NmtCommand::addresses(target, self.node) {
                self.nmt = self.nmt.after(cmd);
                if matches!(cmd, NmtCommand::ResetNode | NmtCommand::ResetCommunication) {
                    tx.send_at(now, heartbeat::boot_up(self.node));
                }
            }
            return;
        }
        if self.nmt == NmtState::Stopped {
            return;
        }
        if let Some(served) = self.sdo.on_frame(f, &mut self.od, now) {
            tx.send_at(now, served.response);
            match served.written {
                Some((0x1017, 0)) => {
                    let ms = self.od.get(0x1017, 0).unwrap_or(0) as u64;
                    self.producer.set_period(Duration::from_millis(ms));
                }
                Some((index, _)) if (0x1800..0x1C00).contains(&index) => {
                    self.tpdos = pdo::active(&self.od, Direction::Tx)
                }
                _ => {}
            }
            return;
        }
        if self.nmt == NmtState::Operational && sync::is_sync(f) {
            self.sync_count = self.sync_count.wrapping_add(1);
            self.sample(now);
            for p in &self.tpdos {
                let tt = u32::from(p.transmission_type);
                if (1..=240).contains(&tt) && self.sync_count.is_multiple_of(tt) {
                    tx.send_at(now, p.pack(&self.od));
                }
            }
        }
    }

    fn next_wakeup(&self) -> Option<Duration> {
        Some(self.next_tick)
    }

    fn on_wakeup(&mut self, now: Duration, tx: &mut NodeTx) {
        self.next_tick = now + Duration::from_millis(1);
        if self.silent {
            return;
        }
        if !self.booted {
            self.booted = true;
            self.nmt = NmtState::PreOperational;
            tx.send_at(now, heartbeat::boot_up(self.node));
            return;
        }
        if let Some(hb) = self.producer.poll(now, self.nmt) {
            tx.send_at(now, hb);
        }
        if let Some(a) = self.sdo.poll(now) {
            tx.send_at(now, a);
        }
    }
}
