//! The CiA 402 master for one drive: configures it by SDO (mode of operation, max torque,
//! heartbeats, PDO mapping), checks its rated torque, walks its state machine to operation
//! enabled, then runs it cyclically: one RPDO per control period (controlword and target
//! torque) before the SYNC, two TPDOs back after it (statusword and position; velocity and
//! torque). Heartbeat loss, a fault in the statusword or an EMCY end in [`DriveFault`].

use super::{obj, Command, Mode, Scaling, State};
use crate::canopen::heartbeat::{HeartbeatConsumer, HeartbeatProducer, Monitored};
use crate::canopen::nmt::{NmtCommand, NmtState};
use crate::canopen::pdo::{Direction, Layout, Mapped, PdoConfig, COB_ID_INVALID};
use crate::canopen::sdo::{self, AbortCode, Now, SdoClient, SdoError};
use crate::canopen::{cob, frame, std_id, NodeId};
use crate::{CanBus, CanFrame};
use std::time::Duration;
use thiserror::Error;

/// The configuration of one CiA 402 drive.
#[derive(Clone, Debug, PartialEq)]
pub struct Cia402Config {
    /// The drive's node id.
    pub node: NodeId,
    /// Cyclic synchronous torque (default) or profile torque.
    pub mode: Mode,
    /// Gear, direction, encoder, zero and the motor rated torque the drive must report.
    pub scaling: Scaling,
    /// Joint torque limit (N·m); also written to the drive as 0x6072.
    pub max_torque: f64,
    /// The drive's heartbeat period (0x1017).
    pub heartbeat_period: Duration,
    /// The master declares the drive lost after this long without its heartbeat.
    pub heartbeat_timeout: Duration,
    /// The master's own heartbeat (node id, period) that the drive watches (0x1016 sub 1 with
    /// a consumer time of three periods); `None`: the drive does not watch the master.
    pub master_heartbeat: Option<(NodeId, Duration)>,
    /// SDO timeout.
    pub sdo_timeout: Duration,
    /// How long the walk to operation enabled may take.
    pub enable_timeout: Duration,
}

impl Cia402Config {
    /// Defaults for a drive at `node` with the given mechanics and torque limit: CST, 50-ms
    /// heartbeat with a 150-ms timeout, master heartbeat from node 127 every 50 ms.
    pub fn new(node: NodeId, scaling: Scaling, max_torque: f64) -> Self {
        Self {
            node,
            mode: Mode::CyclicSynchronousTorque,
            scaling,
            max_torque,
            heartbeat_period: Duration::from_millis(50),
            heartbeat_timeout: Duration::from_millis(150),
            master_heartbeat: NodeId::new(127)
                .ok()
                .map(|n| (n, Duration::from_millis(50))),
            sdo_timeout: Duration::from_millis(200),
            enable_timeout: Duration::from_secs(2),
        }
    }

    /// RPDO1: controlword and target torque.
    pub fn rpdo(&self) -> PdoConfig {
        PdoConfig {
            cob_id: self.node.cob(cob::RPDO[0]),
            transmission_type: 1,
            mapping: vec![
                Mapped::new(obj::CONTROLWORD, 0, 16),
                Mapped::new(obj::TARGET_TORQUE, 0, 16),
            ],
        }
    }

    /// TPDO1 (statusword, position) and TPDO2 (velocity, torque), both on every SYNC.
    pub fn tpdos(&self) -> [PdoConfig; 2] {
        [
            PdoConfig {
                cob_id: self.node.cob(cob::TPDO[0]),
                transmission_type: 1,
                mapping: vec![
                    Mapped::new(obj::STATUSWORD, 0, 16),
                    Mapped::new(obj::POSITION_ACTUAL, 0, 32),
                ],
            },
            PdoConfig {
                cob_id: self.node.cob(cob::TPDO[1]),
                transmission_type: 1,
                mapping: vec![
                    Mapped::new(obj::VELOCITY_ACTUAL, 0, 32),
                    Mapped::new(obj::TORQUE_ACTUAL, 0, 16),
                ],
            },
        ]
    }

    /// The max torque 0x6072 in per mille of rated torque.
    pub fn max_torque_per_mille(&self) -> u16 {
        self.scaling.per_mille(self.max_torque).unsigned_abs()
    }
}

/// Why the drive cannot run.
#[derive(Debug, Error)]
pub enum DriveFault {
    /// An SDO transfer failed during configuration.
    #[error("drive {node}: configuration failed: {source}")]
    Sdo {
        /// The drive.
        node: NodeId,
        /// The SDO error.
        source: SdoError,
    },
    /// The drive's rated torque is not the configured one.
    #[error("drive {node}: reports rated torque 0x6076 = {reported} mNm, the config says {configured} mNm (rated_torque); the per-mille torque would be scaled wrongly")]
    RatedTorque {
        /// The drive.
        node: NodeId,
        /// 0x6076 as read.
        reported: u32,
        /// From the config.
        configured: u32,
    },
    /// The drive does not run the mode asked for.
    #[error("drive {node}: mode of operation display 0x6061 = {display}, asked for {asked}")]
    Mode {
        /// The drive.
        node: NodeId,
        /// 0x6061 as read.
        display: i8,
        /// 0x6060 written.
        asked: i8,
    },
    /// The state machine did not reach operation enabled in time.
    #[error("drive {node}: stuck in {state:?} (statusword {statusword:#06x}) after {waited:?} of enabling")]
    EnableTimeout {
        /// The drive.
        node: NodeId,
        /// Its last state.
        state: Option<State>,
        /// Its last statusword.
        statusword: u16,
        /// How long we tried.
        waited: Duration,
    },
    /// The drive reports a fault (statusword or EMCY).
    #[error("drive {node}: fault (error code 0x603F = {code:#06x}, statusword {statusword:#06x})")]
    Fault {
        /// The drive.
        node: NodeId,
        /// The EMCY / 0x603F error code (0 when unknown).
        code: u16,
        /// The last statusword.
        statusword: u16,
    },
    /// The drive left operation enabled without a fault (quick stop, disabled by its inputs).
    #[error("drive {node}: left operation enabled, now {state:?} (statusword {statusword:#06x})")]
    NotEnabled {
        /// The drive.
        node: NodeId,
        /// Its state.
        state: Option<State>,
        /// The statusword.
        statusword: u16,
    },
    /// No heartbeat within the timeout.
    #[error("drive {node}: no heartbeat for {silent:?} (timeout {timeout:?})")]
    HeartbeatLost {
        /// The drive.
        node: NodeId,
        /// Time since the last one.
        silent: Duration,
        /// The configured timeout.
        timeout: Duration,
    },
    /// The drive's heartbeat reports it is no longer operational (reset, stopped).
    #[error("drive {node}: NMT state {state:?}, not operational")]
    NotOperational {
        /// The drive.
        node: NodeId,
        /// Its reported state.
        state: NmtState,
    },
    /// The bus failed.
    #[error("drive {node}: {source}")]
    Bus {
        /// The drive.
        node: NodeId,
        /// The bus error.
        source: crate::BusError,
    },
}

/// The newest values a drive reported, in joint units.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct DriveSample {
    /// Joint angle (rad).
    pub position: f64,
    /// Joint velocity (rad/s).
    pub velocity: f64,
    /// Joint torque the drive reports applying (N·m).
    pub torque: f64,
    /// The statusword.
    pub statusword: u16,
    /// Bus time of the TPDO1 carrying the statusword and position.
    pub at: Duration,
}

/// The master of one drive.
#[derive(Clone, Debug)]
pub struct Cia402Master {
    cfg: Cia402Config,
    sdo: SdoClient,
    rpdo: Layout,
    tpdo: [Layout; 2],
    heartbeat: HeartbeatConsumer,
    producer: Option<HeartbeatProducer>,
    sample: DriveSample,
    fresh: [bool; 2],
    emcy: Option<u16>,
    enabled: bool,
    enabled_at: Duration,
    fault: Option<DriveFaultKind>,
}

#[derive(Clone, Copy, Debug)]
enum DriveFaultKind {
    Fault(u16),
    NotEnabled,
    Heartbeat(Duration),
    Nmt(NmtState),
}

impl Cia402Master {
    /// A master for the drive `cfg` describes (nothing is sent yet).
    pub fn new(cfg: Cia402Config) -> Self {
        let rpdo = Layout::new(&cfg.rpdo().mapping).unwrap_or_else(|| unreachable!("4 bytes"));
        let [t1, t2] = cfg.tpdos();
        let tpdo = [
            Layout::new(&t1.mapping).unwrap_or_else(|| unreachable!("6 bytes")),
            Layout::new(&t2.mapping).unwrap_or_else(|| unreachable!("6 bytes")),
        ];
        let mut heartbeat = HeartbeatConsumer::new();
        heartbeat.watch(cfg.node, cfg.heartbeat_timeout);
        let producer = cfg
            .master_heartbeat
            .map(|(id, period)| HeartbeatProducer::new(id, period));
        Self {
            sdo: SdoClient::new(cfg.node, cfg.sdo_timeout),
            cfg,
            rpdo,
            tpdo,
            heartbeat,
            producer,
            sample: DriveSample::default(),
            fresh: [false; 2],
            emcy: None,
            enabled: false,
            enabled_at: Duration::ZERO,
            fault: None,
        }
    }

    /// The configuration.
    pub fn config(&self) -> &Cia402Config {
        &self.cfg
    }

    /// The drive's node id.
    pub fn node(&self) -> NodeId {
        self.cfg.node
    }

    fn sdo_err(&self, source: SdoError) -> DriveFault {
        match source {
            SdoError::Bus(source) => DriveFault::Bus {
                node: self.cfg.node,
                source,
            },
            source => DriveFault::Sdo {
                node: self.cfg.node,
                source,
            },
        }
    }

    fn write<B: CanBus + ?Sized>(
        &mut self,
        bus: &mut B,
        now: Now<'_>,
        index: u16,
        sub: u8,
        data: &[u8],
    ) -> Result<(), DriveFault> {
        let mut other = Vec::new();
        let r = sdo::write(bus, now, &mut self.sdo, index, sub, data, &mut |f| {
            other.push(*f)
        });
        for f in &other {
            self.on_frame(f, now());
        }
        r.map_err(|e| self.sdo_err(e))
    }

    fn read<B: CanBus + ?Sized>(
        &mut self,
        bus: &mut B,
        now: Now<'_>,
        index: u16,
        sub: u8,
    ) -> Result<Vec<u8>, DriveFault> {
        let mut other = Vec::new();
        let r = sdo::read(bus, now, &mut self.sdo, index, sub, &mut |f| other.push(*f));
        for f in &other {
            self.on_frame(f, now());
        }
        r.map_err(|e| self.sdo_err(e))
    }

    fn send<B: CanBus + ?Sized>(&self, bus: &mut B, f: &CanFrame) -> Result<(), DriveFault> {
        bus.send(f).map_err(|source| DriveFault::Bus {
            node: self.cfg.node,
            source,
        })
    }

    fn read_u32<B: CanBus + ?Sized>(
        &mut self,
        bus: &mut B,
        now: Now<'_>,
        index: u16,
    ) -> Result<u32, DriveFault> {
        let v = self.read(bus, now, index, 0)?;
        let mut b = [0u8; 4];
        let n = v.len().min(4);
        b[..n].copy_from_slice(&v[..n]);
        Ok(u32::from_le_bytes(b))
    }

    /// Configure the drive (pre-operational, SDO), start it (NMT operational) and walk its
    /// state machine to operation enabled with a zero torque target. Blocking; frames of
    /// other nodes received meanwhile are dropped.
    pub fn configure_and_enable<B: CanBus + ?Sized>(
        &mut self,
        bus: &mut B,
        now: Now<'_>,
    ) -> Result<(), DriveFault> {
        self.fault = None;
        self.emcy = None;
        self.enabled = false;
        let node = self.cfg.node;
        self.send(bus, &NmtCommand::EnterPreOperational.frame(Some(node)))?;
        // The rated torque scales every torque: refuse a drive that disagrees with the config.
        let reported = self.read_u32(bus, now, obj::RATED_TORQUE)?;
        let configured = (self.cfg.scaling.rated_torque * 1000.0).round() as u32;
        if reported.abs_diff(configured) > configured / 200 {
            return Err(DriveFault::RatedTorque {
                node,
                reported,
                configured,
            });
        }
        // Torque off before anything else.
        self.write(
            bus,
            now,
            obj::CONTROLWORD,
            0,
            &Command::DisableVoltage.controlword().to_le_bytes(),
        )?;
        self.write(bus, now, obj::TARGET_TORQUE, 0, &0i16.to_le_bytes())?;
        self.write(
            bus,
            now,
            obj::MODES_OF_OPERATION,
            0,
            &[self.cfg.mode.code() as u8],
        )?;
        let max = self.cfg.max_torque_per_mille();
        self.write(bus, now, obj::MAX_TORQUE, 0, &max.to_le_bytes())?;
        // PDOs: ours, and every other one disabled (a drive may come with defaults enabled;
        // one the drive does not have is fine).
        let mut writes = self.cfg.rpdo().sdo_writes(Direction::Rx, 0);
        for (i, t) in self.cfg.tpdos().iter().enumerate() {
            writes.extend(t.sdo_writes(Direction::Tx, i as u8));
        }
        for (index, sub, data) in writes {
            self.write(bus, now, index, sub, &data)?;
        }
        for (dir, nums) in [(Direction::Rx, 1..4u8), (Direction::Tx, 2..4u8)] {
            for num in nums {
                let base = if dir == Direction::Rx {
                    cob::RPDO
                } else {
                    cob::TPDO
                };
                let cob_id = u32::from(node.cob(base[usize::from(num)])) | COB_ID_INVALID;
                match self.write(bus, now, dir.comm_index(num), 1, &cob_id.to_le_bytes()) {
                    Err(DriveFault::Sdo {
                        source: SdoError::Aborted { code, .. },
                        ..
                    }) if code == AbortCode::NO_OBJECT || code == AbortCode::NO_SUB_INDEX => {}
                    r => r?,
                }
            }
        }
        let hb_ms = self.cfg.heartbeat_period.as_millis().min(0xFFFF) as u16;
        self.write(bus, now, obj::HEARTBEAT_PRODUCER, 0, &hb_ms.to_le_bytes())?;
        if let Some((id, period)) = self.cfg.master_heartbeat {
            let ms = (3 * period.as_millis()).min(0xFFFF) as u32;
            let v = u32::from(id.get()) << 16 | ms;
            self.write(bus, now, obj::HEARTBEAT_CONSUMER, 1, &v.to_le_bytes())?;
            // The drive watches from our first heartbeat on: send one now.
            if let Some(p) = self.producer.as_mut() {
                if let Some(f) = p.poll(now(), NmtState::Operational) {
                    self.send(bus, &f)?;
                }
            }
        }
        self.send(bus, &NmtCommand::Start.frame(Some(node)))?;
        // Walk the state machine by SDO (works before any PDO flows).
        let t0 = now();
        let mut last_cmd = None;
        loop {
            let sw = self.read_u32(bus, now, obj::STATUSWORD)? as u16;
            self.sample.statusword = sw;
            let state = State::from_statusword(sw);
            if state == Some(State::OperationEnabled) {
                break;
            }
            let waited = now().saturating_sub(t0);
            if waited > self.cfg.enable_timeout {
                return Err(DriveFault::EnableTimeout {
                    node,
                    state,
                    statusword: sw,
                    waited,
                });
            }
            let cmd = state.and_then(State::command_towards_enabled);
            if let Some(cmd) = cmd {
                if cmd == Command::FaultReset && last_cmd == Some(Command::FaultReset) {
                    // A fault reset needs a rising edge of bit 7.
                    self.write(bus, now, obj::CONTROLWORD, 0, &0u16.to_le_bytes())?;
                }
                self.write(
                    bus,
                    now,
                    obj::CONTROLWORD,
                    0,
                    &cmd.controlword().to_le_bytes(),
                )?;
                last_cmd = Some(cmd);
            } else {
                self.heartbeat_tick(bus, now)?;
                let _ = bus.recv(Duration::from_millis(5)).map(|f| {
                    if let Some(f) = f {
                        self.on_frame(&f, now());
                    }
                });
            }
        }
        let display = self.read(bus, now, obj::MODES_DISPLAY, 0)?;
        let display = display.first().copied().unwrap_or(0) as i8;
        if display != self.cfg.mode.code() {
            return Err(DriveFault::Mode {
                node,
                display,
                asked: self.cfg.mode.code(),
            });
        }
        self.enabled = true;
        self.enabled_at = now();
        self.emcy = None;
        Ok(())
    }

    /// Send the master heartbeat when due.
    pub fn heartbeat_tick<B: CanBus + ?Sized>(
        &mut self,
        bus: &mut B,
        now: Now<'_>,
    ) -> Result<(), DriveFault> {
        if let Some(f) = self
            .producer
            .as_mut()
            .and_then(|p| p.poll(now(), NmtState::Operational))
        {
            self.send(bus, &f)?;
        }
        Ok(())
    }

    /// The master heartbeat due at `now`, if any (for a caller running its own send loop).
    pub fn heartbeat_frame(&mut self, now: Duration) -> Option<CanFrame> {
        self.producer
            .as_mut()
            .and_then(|p| p.poll(now, NmtState::Operational))
    }

    /// The cyclic RPDO: enable operation with the joint torque `tau` (N·m), clamped to the
    /// configured limit and quantised to per mille of rated torque. No allocation.
    pub fn command(&self, tau: f64) -> CanFrame {
        let lim = self.cfg.max_torque.abs();
        let tau = if tau.is_finite() {
            tau.clamp(-lim, lim)
        } else {
            0.0
        };
        let pm = self.cfg.scaling.per_mille(tau);
        let max = i16::try_from(self.cfg.max_torque_per_mille()).unwrap_or(i16::MAX);
        self.rpdo_frame(Command::EnableOperation, pm.clamp(-max, max))
    }

    /// The joint torque a command of `tau` actually asks for (after clamping and per-mille
    /// quantisation).
    pub fn commanded_torque(&self, tau: f64) -> f64 {
        let lim = self.cfg.max_torque.abs();
        let tau = if tau.is_finite() {
            tau.clamp(-lim, lim)
        } else {
            0.0
        };
        self.cfg
            .scaling
            .joint_torque(self.cfg.scaling.per_mille(tau))
    }

    /// The protective-stop RPDO: zero torque, quick stop.
    pub fn stop(&self) -> CanFrame {
        self.rpdo_frame(Command::QuickStop, 0)
    }

    /// Zero torque while staying enabled (the first frame of a ramp-free stop).
    pub fn zero(&self) -> CanFrame {
        self.rpdo_frame(Command::EnableOperation, 0)
    }

    fn rpdo_frame(&self, cmd: Command, per_mille: i16) -> CanFrame {
        let mut buf = [0u8; 8];
        self.rpdo
            .put(&mut buf, obj::CONTROLWORD, 0, u32::from(cmd.controlword()));
        self.rpdo
            .put(&mut buf, obj::TARGET_TORQUE, 0, u32::from(per_mille as u16));
        frame(self.cfg.node.cob(cob::RPDO[0]), &buf[..self.rpdo.len()])
    }

    /// Feed a received frame; `true` when it was this drive's.
    pub fn on_frame(&mut self, f: &CanFrame, now: Duration) -> bool {
        let Some(id) = std_id(f) else { return false };
        let node = self.cfg.node;
        if let Some((_, state)) = self.heartbeat.on_frame(f, now) {
            if self.enabled && state != NmtState::Operational && self.fault.is_none() {
                self.fault = Some(DriveFaultKind::Nmt(state));
            }
            return true;
        }
        if id == node.cob(cob::EMCY) && f.len() >= 2 {
            let code = u16::from_le_bytes([f.data()[0], f.data()[1]]);
            if code != 0 {
                self.emcy = Some(code);
                if self.enabled && self.fault.is_none() {
                    self.fault = Some(DriveFaultKind::Fault(code));
                }
            }
            return true;
        }
        let s = self.cfg.scaling;
        if id == node.cob(cob::TPDO[0]) {
            let d = f.data();
            let (Some(sw), Some(pos)) = (
                self.tpdo[0].get(d, obj::STATUSWORD, 0),
                self.tpdo[0].get(d, obj::POSITION_ACTUAL, 0),
            ) else {
                return true;
            };
            self.sample.statusword = sw as u16;
            self.sample.position = s.joint_angle(pos as i32);
            self.sample.at = now;
            self.fresh[0] = true;
            if self.enabled && self.fault.is_none() {
                match State::from_statusword(sw as u16) {
                    Some(State::OperationEnabled) => {}
                    Some(State::Fault | State::FaultReactionActive) => {
                        self.fault = Some(DriveFaultKind::Fault(self.emcy.unwrap_or(0)))
                    }
                    _ => self.fault = Some(DriveFaultKind::NotEnabled),
                }
            }
            return true;
        }
        if id == node.cob(cob::TPDO[1]) {
            let d = f.data();
            if let (Some(v), Some(t)) = (
                self.tpdo[1].get(d, obj::VELOCITY_ACTUAL, 0),
                self.tpdo[1].get(d, obj::TORQUE_ACTUAL, 0),
            ) {
                self.sample.velocity = s.joint_velocity(v as i32);
                self.sample.torque = s.joint_torque(t as u16 as i16);
                self.fresh[1] = true;
            }
            return true;
        }
        id == node.cob(cob::SDO_TX)
    }

    /// The newest sample once both TPDOs arrived since the last call (then cleared).
    pub fn take_sample(&mut self) -> Option<DriveSample> {
        if self.fresh == [true, true] {
            self.fresh = [false, false];
            Some(self.sample)
        } else {
            None
        }
    }

    /// The newest values, fresh or not.
    pub fn last_sample(&self) -> DriveSample {
        self.sample
    }

    /// `true` after a successful [`Cia402Master::configure_and_enable`] and before a fault.
    pub fn enabled(&self) -> bool {
        self.enabled && self.fault.is_none()
    }

    /// Check heartbeat and fault state at `now`: the first problem found, latched until the
    /// next [`Cia402Master::configure_and_enable`].
    pub fn check(&mut self, now: Duration) -> Result<(), DriveFault> {
        if self.fault.is_none() {
            if let Some(t) = self.heartbeat.check(now) {
                self.fault = Some(DriveFaultKind::Heartbeat(t.silent_for));
            } else if self.enabled
                && self.heartbeat.status(self.cfg.node) == Some(Monitored::Waiting)
                && now.saturating_sub(self.enabled_at) > self.cfg.heartbeat_timeout
            {
                // No heartbeat at all since enabling: count from the enable.
                self.fault = Some(DriveFaultKind::Heartbeat(now - self.enabled_at));
            }
        }
        let node = self.cfg.node;
        let statusword = self.sample.statusword;
        match self.fault {
            None => Ok(()),
            Some(DriveFaultKind::Fault(code)) => Err(DriveFault::Fault {
                node,
                code,
                statusword,
            }),
            Some(DriveFaultKind::NotEnabled) => Err(DriveFault::NotEnabled {
                node,
                state: State::from_statusword(statusword),
                statusword,
            }),
            Some(DriveFaultKind::Heartbeat(silent)) => Err(DriveFault::HeartbeatLost {
                node,
                silent,
                timeout: self.cfg.heartbeat_timeout,
            }),
            Some(DriveFaultKind::Nmt(state)) => Err(DriveFault::NotOperational { node, state }),
        }
    }
}
