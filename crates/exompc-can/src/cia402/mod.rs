//! CiA 402 (IEC 61800-7-201) drives over CANopen: the device state machine driven through the
//! controlword 0x6040 and read from the statusword 0x6041, the modes of operation 0x6060/0x6061
//! (cyclic synchronous torque 10, profile torque 4), the target torque 0x6071 in per mille of
//! the motor rated torque 0x6076, and the actual values 0x6064 (position), 0x606C (velocity)
//! and 0x6077 (torque) in TPDOs. [`master::Cia402Master`] is the driver `exompc run` uses;
//! [`emulator::Cia402Emulator`] a virtual drive honouring the same protocol.

pub mod emulator;
pub mod leg;
pub mod master;
pub mod robot;

use std::f64::consts::TAU;

/// Object indices used (CiA 301 communication area and CiA 402 profile area).
pub mod obj {
    /// Device type (UNSIGNED32; 0x00020192 = CiA 402 servo drive).
    pub const DEVICE_TYPE: u16 = 0x1000;
    /// Error register (UNSIGNED8).
    pub const ERROR_REGISTER: u16 = 0x1001;
    /// Consumer heartbeat time (sub 1: `node << 16 | ms`).
    pub const HEARTBEAT_CONSUMER: u16 = 0x1016;
    /// Producer heartbeat time (UNSIGNED16, ms).
    pub const HEARTBEAT_PRODUCER: u16 = 0x1017;
    /// Error code of the last fault (UNSIGNED16).
    pub const ERROR_CODE: u16 = 0x603F;
    /// Controlword (UNSIGNED16).
    pub const CONTROLWORD: u16 = 0x6040;
    /// Statusword (UNSIGNED16).
    pub const STATUSWORD: u16 = 0x6041;
    /// Quick stop option code (INTEGER16).
    pub const QUICK_STOP_OPTION: u16 = 0x605A;
    /// Modes of operation (INTEGER8).
    pub const MODES_OF_OPERATION: u16 = 0x6060;
    /// Modes of operation display (INTEGER8).
    pub const MODES_DISPLAY: u16 = 0x6061;
    /// Position actual value (INTEGER32, increments).
    pub const POSITION_ACTUAL: u16 = 0x6064;
    /// Velocity actual value (INTEGER32, velocity units).
    pub const VELOCITY_ACTUAL: u16 = 0x606C;
    /// Target torque (INTEGER16, per mille of rated torque).
    pub const TARGET_TORQUE: u16 = 0x6071;
    /// Max torque (UNSIGNED16, per mille of rated torque).
    pub const MAX_TORQUE: u16 = 0x6072;
    /// Motor rated torque (UNSIGNED32, mNm).
    pub const RATED_TORQUE: u16 = 0x6076;
    /// Torque actual value (INTEGER16, per mille of rated torque).
    pub const TORQUE_ACTUAL: u16 = 0x6077;
    /// Supported drive modes (UNSIGNED32 bit field; bit 3 profile torque, bit 9 CST).
    pub const SUPPORTED_MODES: u16 = 0x6502;
}

/// Device type of a CiA 402 servo drive (0x1000).
pub const DEVICE_TYPE_SERVO: u32 = 0x0002_0192;
/// Emergency / 0x603F error code: heartbeat of the master lost (life guard / heartbeat error).
pub const ERROR_HEARTBEAT: u16 = 0x8130;
/// 0x603F error code of a generic drive fault (injected by tests).
pub const ERROR_GENERIC: u16 = 0x1000;

/// A mode of operation (0x6060).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Mode {
    /// Profile torque (4): the target torque applies when received.
    ProfileTorque,
    /// Cyclic synchronous torque (10): the target torque applies at each SYNC.
    CyclicSynchronousTorque,
}

impl Mode {
    /// The 0x6060 value.
    pub fn code(self) -> i8 {
        match self {
            Mode::ProfileTorque => 4,
            Mode::CyclicSynchronousTorque => 10,
        }
    }

    /// The mode of a 0x6060 value.
    pub fn from_code(code: i8) -> Option<Self> {
        match code {
            4 => Some(Mode::ProfileTorque),
            10 => Some(Mode::CyclicSynchronousTorque),
            _ => None,
        }
    }
}

/// A state of the CiA 402 device state machine.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum State {
    /// Not ready to switch on (initialising).
    NotReadyToSwitchOn,
    /// Switch on disabled (no high voltage to the motor).
    SwitchOnDisabled,
    /// Ready to switch on.
    ReadyToSwitchOn,
    /// Switched on (power stage on, no torque).
    SwitchedOn,
    /// Operation enabled: the drive follows its targets.
    OperationEnabled,
    /// Quick stop active.
    QuickStopActive,
    /// Fault reaction active.
    FaultReactionActive,
    /// Fault.
    Fault,
}

impl State {
    /// Decode a statusword (CiA 402 Table 30: bits 0-3, 5, 6).
    pub fn from_statusword(sw: u16) -> Option<State> {
        Some(if sw & 0x4F == 0x00 {
            State::NotReadyToSwitchOn
        } else if sw & 0x4F == 0x40 {
            State::SwitchOnDisabled
        } else if sw & 0x6F == 0x21 {
            State::ReadyToSwitchOn
        } else if sw & 0x6F == 0x23 {
            State::SwitchedOn
        } else if sw & 0x6F == 0x27 {
            State::OperationEnabled
        } else if sw & 0x6F == 0x07 {
            State::QuickStopActive
        } else if sw & 0x4F == 0x0F {
            State::FaultReactionActive
        } else if sw & 0x4F == 0x08 {
            State::Fault
        } else {
            return None;
        })
    }

    /// The state bits of the statusword (bit 4 voltage enabled set where the power stage is
    /// on; bit 5 quick stop is active low).
    pub fn statusword_bits(self) -> u16 {
        match self {
            State::NotReadyToSwitchOn => 0x0000,
            State::SwitchOnDisabled => 0x0040,
            State::ReadyToSwitchOn => 0x0031,
            State::SwitchedOn => 0x0033,
            State::OperationEnabled => 0x0037,
            State::QuickStopActive => 0x0017,
            State::FaultReactionActive => 0x001F,
            State::Fault => 0x0008,
        }
    }

    /// The controlword that moves a drive in this state one step towards operation enabled
    /// (`None`: wait, the drive moves by itself or is there).
    pub fn command_towards_enabled(self) -> Option<Command> {
        match self {
            State::NotReadyToSwitchOn | State::FaultReactionActive | State::OperationEnabled => {
                None
            }
            State::Fault => Some(Command::FaultReset),
            State::SwitchOnDisabled => Some(Command::Shutdown),
            State::ReadyToSwitchOn => Some(Command::SwitchOn),
            State::SwitchedOn => Some(Command::EnableOperation),
            State::QuickStopActive => Some(Command::DisableVoltage),
        }
    }
}

/// A device control command (CiA 402 Table 27).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Command {
    /// Shutdown (→ ready to switch on): 0x0006.
    Shutdown,
    /// Switch on (→ switched on; also "disable operation"): 0x0007.
    SwitchOn,
    /// Switch on + enable operation (→ operation enabled): 0x000F.
    EnableOperation,
    /// Disable voltage (→ switch on disabled): 0x0000.
    DisableVoltage,
    /// Quick stop: 0x0002.
    QuickStop,
    /// Fault reset (rising edge of bit 7): 0x0080.
    FaultReset,
}

impl Command {
    /// The controlword.
    pub fn controlword(self) -> u16 {
        match self {
            Command::Shutdown => 0x0006,
            Command::SwitchOn => 0x0007,
            Command::EnableOperation => 0x000F,
            Command::DisableVoltage => 0x0000,
            Command::QuickStop => 0x0002,
            Command::FaultReset => 0x0080,
        }
    }

    /// The command of a controlword (bit 7 alone is read as fault reset; the edge is the
    /// drive's business).
    pub fn from_controlword(cw: u16) -> Command {
        if cw & 0x80 != 0 {
            Command::FaultReset
        } else if cw & 0x02 == 0 {
            Command::DisableVoltage
        } else if cw & 0x04 == 0 {
            Command::QuickStop
        } else if cw & 0x01 == 0 {
            Command::Shutdown
        } else if cw & 0x08 == 0 {
            Command::SwitchOn
        } else {
            Command::EnableOperation
        }
    }
}

/// The drive's side of the state machine (CiA 402 Figure 22), as the emulator runs it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct DriveStateMachine {
    state: State,
    last_cw: u16,
}

impl Default for DriveStateMachine {
    fn default() -> Self {
        Self {
            state: State::NotReadyToSwitchOn,
            last_cw: 0,
        }
    }
}

impl DriveStateMachine {
    /// The current state.
    pub fn state(&self) -> State {
        self.state
    }

    /// A new controlword was received (CiA 402 Figure 22 transitions 2-12, 15, 16).
    pub fn on_controlword(&mut self, cw: u16) {
        let rising_reset = cw & 0x80 != 0 && self.last_cw & 0x80 == 0;
        self.last_cw = cw;
        use State::*;
        self.state = match (self.state, Command::from_controlword(cw)) {
            (Fault, _) if rising_reset => SwitchOnDisabled, // 15
            (Fault | FaultReactionActive | NotReadyToSwitchOn, _) => self.state,
            (_, Command::FaultReset) => self.state,
            (SwitchOnDisabled, Command::Shutdown) => ReadyToSwitchOn, // 2
            (SwitchOnDisabled, _) => SwitchOnDisabled,
            (ReadyToSwitchOn, Command::SwitchOn) => SwitchedOn, // 3
            (ReadyToSwitchOn, Command::EnableOperation) => OperationEnabled, // 3 + 4
            (ReadyToSwitchOn, Command::DisableVoltage | Command::QuickStop) => SwitchOnDisabled, // 7
            (ReadyToSwitchOn, Command::Shutdown) => ReadyToSwitchOn,
            (SwitchedOn, Command::EnableOperation) => OperationEnabled, // 4
            (SwitchedOn, Command::Shutdown) => ReadyToSwitchOn,         // 6
            (SwitchedOn, Command::DisableVoltage | Command::QuickStop) => SwitchOnDisabled, // 10
            (SwitchedOn, Command::SwitchOn) => SwitchedOn,
            (OperationEnabled, Command::SwitchOn) => SwitchedOn, // 5
            (OperationEnabled, Command::Shutdown) => ReadyToSwitchOn, // 8
            (OperationEnabled, Command::DisableVoltage) => SwitchOnDisabled, // 9
            (OperationEnabled, Command::QuickStop) => QuickStopActive, // 11
            (OperationEnabled, Command::EnableOperation) => OperationEnabled,
            (QuickStopActive, Command::EnableOperation) => OperationEnabled, // 16
            (QuickStopActive, Command::DisableVoltage) => SwitchOnDisabled,  // 12
            (QuickStopActive, _) => QuickStopActive,
        };
    }

    /// The automatic transitions: initialisation done (1), fault reaction done (14), quick
    /// stop done (12, when `quick_stop_to_disabled`: quick stop option code 0x605A 0..=4).
    pub fn step(&mut self, quick_stop_to_disabled: bool) {
        self.state = match self.state {
            State::NotReadyToSwitchOn => State::SwitchOnDisabled,
            State::FaultReactionActive => State::Fault,
            State::QuickStopActive if quick_stop_to_disabled => State::SwitchOnDisabled,
            s => s,
        };
    }

    /// A fault occurred (13): fault reaction active, then fault.
    pub fn fault(&mut self) {
        if self.state != State::Fault {
            self.state = State::FaultReactionActive;
        }
    }

    /// Back to not ready to switch on (an NMT reset of the drive).
    pub fn reset(&mut self) {
        *self = Self::default();
    }

    /// `true` when the power stage follows the torque target.
    pub fn torque_enabled(&self) -> bool {
        self.state == State::OperationEnabled
    }
}

/// The mechanics between the drive's units and the joint: gear, direction, encoder, zero.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Scaling {
    /// Motor rated torque (N·m at the motor), 0x6076 = this × 1000 mNm.
    pub rated_torque: f64,
    /// Gear ratio (motor turns per joint turn, > 0).
    pub gear_ratio: f64,
    /// +1 or -1: the joint's positive direction relative to the motor's.
    pub direction: f64,
    /// Joint angle (rad) when the motor position is 0.
    pub zero_offset: f64,
    /// Position increments per motor revolution.
    pub counts_per_rev: f64,
    /// Motor rad/s per velocity unit of 0x606C (2π/60 for rpm).
    pub velocity_unit: f64,
}

impl Default for Scaling {
    fn default() -> Self {
        Self {
            rated_torque: 1.0,
            gear_ratio: 1.0,
            direction: 1.0,
            zero_offset: 0.0,
            counts_per_rev: 4096.0,
            velocity_unit: TAU / 60.0,
        }
    }
}

impl Scaling {
    /// Joint angle (rad) of a position actual value.
    pub fn joint_angle(&self, counts: i32) -> f64 {
        self.direction * f64::from(counts) * TAU / self.counts_per_rev / self.gear_ratio
            + self.zero_offset
    }

    /// Position actual value of a joint angle (rounded, saturated).
    pub fn counts(&self, angle: f64) -> i32 {
        let c = (angle - self.zero_offset) * self.direction * self.gear_ratio * self.counts_per_rev
            / TAU;
        c.round().clamp(f64::from(i32::MIN), f64::from(i32::MAX)) as i32
    }

    /// Joint velocity (rad/s) of a velocity actual value.
    pub fn joint_velocity(&self, units: i32) -> f64 {
        self.direction * f64::from(units) * self.velocity_unit / self.gear_ratio
    }

    /// Velocity actual value of a joint velocity (rounded, saturated).
    pub fn velocity_units(&self, qd: f64) -> i32 {
        let v = qd * self.direction * self.gear_ratio / self.velocity_unit;
        v.round().clamp(f64::from(i32::MIN), f64::from(i32::MAX)) as i32
    }

    /// Joint torque (N·m) of a torque value in per mille of rated torque.
    pub fn joint_torque(&self, per_mille: i16) -> f64 {
        self.direction * self.gear_ratio * self.rated_torque * f64::from(per_mille) / 1000.0
    }

    /// Per mille of rated torque of a joint torque (rounded, saturated to INTEGER16).
    pub fn per_mille(&self, tau: f64) -> i16 {
        let pm = tau * self.direction / (self.gear_ratio * self.rated_torque) * 1000.0;
        if pm.is_nan() {
            return 0;
        }
        pm.round().clamp(-32767.0, 32767.0) as i16
    }

    /// The joint torque of one per mille (the command's quantisation step).
    pub fn torque_step(&self) -> f64 {
        self.gear_ratio * self.rated_torque / 1000.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The statusword masks of CiA 402 Table 30, written out independently.
    const TABLE_30: [(u16, u16, State); 8] = [
        (0x4F, 0x00, State::NotReadyToSwitchOn),
        (0x4F, 0x40, State::SwitchOnDisabled),
        (0x6F, 0x21, State::ReadyToSwitchOn),
        (0x6F, 0x23, State::SwitchedOn),
        (0x6F, 0x27, State::OperationEnabled),
        (0x6F, 0x07, State::QuickStopActive),
        (0x4F, 0x0F, State::FaultReactionActive),
        (0x4F, 0x08, State::Fault),
    ];

    #[test]
    fn statusword_decoding_matches_table_30() {
        for sw in 0..=u16::MAX {
            let expect = TABLE_30
                .iter()
                .find(|(mask, val, _)| sw & mask == *val)
                .map(|t| t.2);
            assert_eq!(State::from_statusword(sw), expect, "{sw:#06x}");
        }
        for (_, _, s) in TABLE_30 {
            assert_eq!(
                State::from_statusword(s.statusword_bits() | 0x0200),
                Some(s)
            );
        }
    }

    #[test]
    fn the_drive_walks_the_state_machine() {
        let mut d = DriveStateMachine::default();
        d.on_controlword(0x06);
        assert_eq!(
            d.state(),
            State::NotReadyToSwitchOn,
            "ignored while initialising"
        );
        d.step(true);
        assert_eq!(d.state(), State::SwitchOnDisabled);
        // The master's walk: command_towards_enabled until operation enabled.
        let mut steps = 0;
        while let Some(c) = d.state().command_towards_enabled() {
            d.on_controlword(c.controlword());
            steps += 1;
        }
        assert_eq!((d.state(), steps), (State::OperationEnabled, 3));
        assert!(d.torque_enabled());
        d.on_controlword(0x07);
        assert_eq!(d.state(), State::SwitchedOn, "disable operation (5)");
        d.on_controlword(0x0F);
        d.on_controlword(0x02);
        assert_eq!(d.state(), State::QuickStopActive, "11");
        d.on_controlword(0x0F);
        assert_eq!(d.state(), State::OperationEnabled, "16");
        d.on_controlword(0x02);
        d.step(true);
        assert_eq!(d.state(), State::SwitchOnDisabled, "12");
        for c in [0x06, 0x0F] {
            d.on_controlword(c);
        }
        assert_eq!(d.state(), State::OperationEnabled, "2, 3 + 4");
        d.fault();
        assert_eq!(d.state(), State::FaultReactionActive);
        assert!(!d.torque_enabled());
        d.on_controlword(0x0F);
        d.step(true);
        assert_eq!(d.state(), State::Fault, "14; commands ignored");
        d.on_controlword(0x8F);
        assert_eq!(
            d.state(),
            State::SwitchOnDisabled,
            "15 on the rising edge of bit 7"
        );
        d.fault();
        d.step(true);
        d.on_controlword(0x80);
        assert_eq!(d.state(), State::Fault, "bit 7 already high: no edge");
        d.on_controlword(0x00);
        d.on_controlword(0x80);
        assert_eq!(d.state(), State::SwitchOnDisabled);
    }

    #[test]
    fn scaling_round_trips() {
        let s = Scaling {
            rated_torque: 0.2,
            gear_ratio: 50.0,
            direction: -1.0,
            zero_offset: 0.1,
            counts_per_rev: 4096.0,
            velocity_unit: TAU / 60.0,
        };
        for q in [-1.0, 0.0, 0.3, 1.2] {
            assert!((s.joint_angle(s.counts(q)) - q).abs() < TAU / 4096.0 / 50.0);
        }
        assert!((s.joint_velocity(s.velocity_units(2.0)) - 2.0).abs() < 0.5 * TAU / 60.0 / 50.0);
        assert_eq!(
            s.per_mille(-10.0),
            1000,
            "10 N·m at the joint = rated torque, reversed"
        );
        assert!((s.joint_torque(s.per_mille(3.33)) - 3.33).abs() <= s.torque_step() / 2.0);
        assert_eq!(s.per_mille(f64::NAN), 0);
        assert_eq!(s.per_mille(1e9), -32767);
        assert_eq!(Mode::from_code(10), Some(Mode::CyclicSynchronousTorque));
        assert_eq!(Mode::from_code(8), None);
    }
}
