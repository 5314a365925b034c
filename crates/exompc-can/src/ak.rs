//! T-Motor/CubeMars AK actuators in MIT mode: the special frames (enter/exit motor mode, set
//! zero), the 8-byte command and the reply, packed as the vendor's manual specifies, and the
//! joint-side view of one actuator ([`AkDrive`]: gear ratio, direction, zero offset).
//!
//! Packing (manual, "MIT mode"): each value is clamped to its range `[min, max]` and mapped to
//! an unsigned integer of `bits` bits, `u = ⌊(x − min) · (2^bits − 1) / (max − min)⌋`, and
//! back `x = u · (max − min) / (2^bits − 1) + min`. Command: position 16 bit, velocity 12,
//! kp 12 (0..kp_max), kd 12 (0..kd_max), torque 12, big-endian bit fields in 8 bytes. Reply:
//! byte 0 the motor ID, position 16, velocity 12, torque (or current) 12, then temperature
//! (°C) and an error code where the firmware sends 8 bytes.

use crate::config::{AkJoint, AkModel, AkReplyEffort};
use crate::frame::{CanFrame, CanId};

/// Enter motor mode (the motor applies commands from then on).
pub const ENTER_MOTOR_MODE: [u8; 8] = [0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFC];
/// Exit motor mode (the motor goes limp).
pub const EXIT_MOTOR_MODE: [u8; 8] = [0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFD];
/// Set the current position as zero.
pub const SET_ZERO: [u8; 8] = [0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFE];

/// `x` in `[min, max]` (clamped; NaN counts as `min`) as a `bits`-bit unsigned integer.
pub fn float_to_uint(x: f64, min: f64, max: f64, bits: u32) -> u32 {
    let full = ((1u64 << bits) - 1) as f64;
    let x = if x.is_nan() { min } else { x.clamp(min, max) };
    (((x - min) * full / (max - min)) as u64).min(full as u64) as u32
}

/// The `bits`-bit unsigned integer `u` as a value in `[min, max]`.
pub fn uint_to_float(u: u32, min: f64, max: f64, bits: u32) -> f64 {
    let full = ((1u64 << bits) - 1) as f64;
    f64::from(u) * (max - min) / full + min
}

/// One MIT-mode command (output side of the actuator).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct MitCommand {
    /// Position target (rad).
    pub p: f64,
    /// Velocity target (rad/s).
    pub v: f64,
    /// Stiffness (N·m/rad).
    pub kp: f64,
    /// Damping (N·m·s/rad).
    pub kd: f64,
    /// Feed-forward torque (N·m).
    pub t: f64,
}

/// One MIT-mode reply (output side of the actuator).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct MitReply {
    /// The motor's ID (byte 0).
    pub motor_id: u8,
    /// Position (rad).
    pub p: f64,
    /// Velocity (rad/s).
    pub v: f64,
    /// Torque (N·m), or current (A) when the firmware sends current.
    pub effort: f64,
    /// Temperature (°C), if the reply has 7 or more bytes.
    pub temperature: Option<i8>,
    /// Error code (0: none), if the reply has 8 bytes.
    pub error: Option<u8>,
}

/// The 8 data bytes of `c` over the ranges `r` (values outside a range are clamped).
pub fn pack_command(r: &AkModel, c: &MitCommand) -> [u8; 8] {
    let p = float_to_uint(c.p, -r.p_max, r.p_max, 16);
    let v = float_to_uint(c.v, -r.v_max, r.v_max, 12);
    let kp = float_to_uint(c.kp, 0.0, r.kp_max, 12);
    let kd = float_to_uint(c.kd, 0.0, r.kd_max, 12);
    let t = float_to_uint(c.t, -r.t_max, r.t_max, 12);
    [
        (p >> 8) as u8,
        p as u8,
        (v >> 4) as u8,
        (((v & 0xF) << 4) | (kp >> 8)) as u8,
        kp as u8,
        (kd >> 4) as u8,
        (((kd & 0xF) << 4) | (t >> 8)) as u8,
        t as u8,
    ]
}

/// The command in 8 data bytes (as the motor reads it: quantised).
pub fn unpack_command(r: &AkModel, d: &[u8; 8]) -> MitCommand {
    let p = (u32::from(d[0]) << 8) | u32::from(d[1]);
    let v = (u32::from(d[2]) << 4) | (u32::from(d[3]) >> 4);
    let kp = ((u32::from(d[3]) & 0xF) << 8) | u32::from(d[4]);
    let kd = (u32::from(d[5]) << 4) | (u32::from(d[6]) >> 4);
    let t = ((u32::from(d[6]) & 0xF) << 8) | u32::from(d[7]);
    MitCommand {
        p: uint_to_float(p, -r.p_max, r.p_max, 16),
        v: uint_to_float(v, -r.v_max, r.v_max, 12),
        kp: uint_to_float(kp, 0.0, r.kp_max, 12),
        kd: uint_to_float(kd, 0.0, r.kd_max, 12),
        t: uint_to_float(t, -r.t_max, r.t_max, 12),
    }
}

/// The 8 data bytes of a reply (effort over ±t_max; temperature and error in bytes 6, 7).
pub fn pack_reply(r: &AkModel, m: &MitReply) -> [u8; 8] {
    let p = float_to_uint(m.p, -r.p_max, r.p_max, 16);
    let v = float_to_uint(m.v, -r.v_max, r.v_max, 12);
    let e = float_to_uint(m.effort, -r.t_max, r.t_max, 12);
    [
        m.motor_id,
        (p >> 8) as u8,
        p as u8,
        (v >> 4) as u8,
        (((v & 0xF) << 4) | (e >> 8)) as u8,
        e as u8,
        m.temperature.unwrap_or(0) as u8,
        m.error.unwrap_or(0),
    ]
}

/// A reply from its data bytes (6 to 8); `None` if shorter.
pub fn unpack_reply(r: &AkModel, d: &[u8]) -> Option<MitReply> {
    if d.len() < 6 {
        return None;
    }
    let p = (u32::from(d[1]) << 8) | u32::from(d[2]);
    let v = (u32::from(d[3]) << 4) | (u32::from(d[4]) >> 4);
    let e = ((u32::from(d[4]) & 0xF) << 8) | u32::from(d[5]);
    Some(MitReply {
        motor_id: d[0],
        p: uint_to_float(p, -r.p_max, r.p_max, 16),
        v: uint_to_float(v, -r.v_max, r.v_max, 12),
        effort: uint_to_float(e, -r.t_max, r.t_max, 12),
        temperature: d.get(6).map(|&b| b as i8),
        error: d.get(7).copied(),
    })
}

/// A joint's reading from its motor's reply (joint side).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct JointReading {
    /// Joint angle (rad).
    pub q: f64,
    /// Joint velocity (rad/s).
    pub qd: f64,
    /// Joint torque the motor reports (N·m).
    pub torque: f64,
    /// Temperature (°C), if sent.
    pub temperature: Option<i8>,
    /// Error code (0: none), if sent.
    pub error: Option<u8>,
}

/// One AK actuator driving one joint, torque-only (kp = kd = 0): its frames, and the
/// conversion between the motor's output side and the joint (gear ratio, direction, zero
/// offset) from its config.
#[derive(Clone, Debug)]
pub struct AkDrive {
    id: u16,
    reply_id: u16,
    ranges: AkModel,
    ratio: f64,
    dir: f64,
    zero: f64,
    limit: f64,
    effort: AkReplyEffort,
    per_amp: f64,
    rng: fastrand::Rng,
}

impl AkDrive {
    /// The drive of a (validated) joint config; `None` for an unknown model.
    pub fn new(cfg: &AkJoint) -> Option<Self> {
        Some(AkDrive {
            id: cfg.can_id.min(0x7F) as u16,
            reply_id: cfg.reply_id.min(0x7FF) as u16,
            ranges: cfg.ranges()?,
            ratio: cfg.gear_ratio,
            dir: if cfg.direction < 0 { -1.0 } else { 1.0 },
            zero: cfg.zero_offset_rad,
            limit: cfg.joint_torque_limit(),
            effort: cfg.reply_effort,
            per_amp: cfg.torque_per_amp.unwrap_or(1.0),
            rng: fastrand::Rng::with_seed(0xA4 ^ u64::from(cfg.can_id)),
        })
    }

    /// The MIT ranges in use.
    pub fn ranges(&self) -> &AkModel {
        &self.ranges
    }

    /// The motor's CAN ID.
    pub fn can_id(&self) -> u16 {
        self.id
    }

    /// The joint torque limit (N·m).
    pub fn torque_limit(&self) -> f64 {
        self.limit
    }

    fn frame(&self, data: &[u8; 8]) -> CanFrame {
        CanFrame::with_id8(self.id as u8, data)
    }

    /// Enter motor mode.
    pub fn enter(&self) -> CanFrame {
        self.frame(&ENTER_MOTOR_MODE)
    }

    /// Exit motor mode.
    pub fn exit(&self) -> CanFrame {
        self.frame(&EXIT_MOTOR_MODE)
    }

    /// Set zero at the current position.
    pub fn set_zero(&self) -> CanFrame {
        self.frame(&SET_ZERO)
    }

    /// The motor-side torque of a joint torque (limited to the joint limit first).
    pub fn motor_torque(&self, tau_joint: f64) -> f64 {
        let tau = if tau_joint.is_finite() {
            tau_joint.clamp(-self.limit, self.limit)
        } else {
            0.0
        };
        self.dir * tau / self.ratio
    }

    /// The torque-only command (kp = kd = 0) for a joint torque (N·m).
    pub fn torque_frame(&self, tau_joint: f64) -> CanFrame {
        let c = MitCommand {
            t: self.motor_torque(tau_joint),
            ..Default::default()
        };
        self.frame(&pack_command(&self.ranges, &c))
    }

    /// `true` if `f` is this motor's reply (its reply ID, byte 0 its motor ID).
    pub fn is_reply(&self, f: &CanFrame) -> bool {
        f.id() == CanId::Standard(self.reply_id)
            && f.data().len() >= 6
            && u16::from(f.data()[0]) == self.id
    }

    /// The joint's reading from a reply (`None` if `f` is not this motor's reply).
    pub fn decode(&mut self, f: &CanFrame) -> Option<JointReading> {
        if !self.is_reply(f) {
            return None;
        }
        let mut m = unpack_reply(&self.ranges, f.data())?;
        // The firmware truncates (⌊·⌋) when it packs: the value lies in [u, u + 1) steps. The
        // reading is drawn uniformly in that interval (dither): no truncation bias (−0.012
        // rad/s on an AK80-9's velocity otherwise), and a joint moving slowly does not repeat
        // a reading bit for bit, which the estimator's frozen-sensor test would reject.
        let r = &self.ranges;
        m.p += self.rng.f64() * 2.0 * r.p_max / f64::from(u16::MAX);
        m.v += self.rng.f64() * 2.0 * r.v_max / 4095.0;
        m.effort += self.rng.f64() * 2.0 * r.t_max / 4095.0;
        let motor_torque = match self.effort {
            AkReplyEffort::Torque => m.effort,
            AkReplyEffort::Current => m.effort * self.per_amp,
        };
        Some(JointReading {
            q: self.dir * m.p / self.ratio + self.zero,
            qd: self.dir * m.v / self.ratio,
            torque: self.dir * motor_torque * self.ratio,
            temperature: m.temperature,
            error: m.error,
        })
    }
}
