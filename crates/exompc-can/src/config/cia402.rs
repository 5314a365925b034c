//! `driver = "cia402"`: a CANopen drive with the CiA 402 profile (Maxon EPOS4, Elmo, Copley,
//! …) in cyclic synchronous torque (or profile torque) mode.

use super::{check_int, check_range, err, ConfigError};
use crate::canopen::NodeId;
use crate::cia402::master::Cia402Config;
use crate::cia402::{Mode, Scaling};
use serde::Deserialize;
use std::time::Duration;

/// The mode of operation written to 0x6060.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Cia402Mode {
    /// Cyclic synchronous torque (10): the target applies at each SYNC.
    #[default]
    Cst,
    /// Profile torque (4): the target applies when received.
    Pt,
}

/// The unit of the drive's velocity actual value 0x606C.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum VelocityUnit {
    /// Motor revolutions per minute (EPOS4's default).
    #[default]
    Rpm,
    /// Encoder increments per second.
    CountsPerS,
}

fn one() -> f64 {
    1.0
}

fn dir() -> i8 {
    1
}

fn counts() -> f64 {
    4096.0
}

fn hb() -> f64 {
    50.0
}

fn hb_timeout() -> f64 {
    150.0
}

fn master_id() -> u8 {
    127
}

/// `driver = "cia402"`: one CiA 402 drive.
///
/// Joint angle `q = direction · 2π · position / (counts_per_rev · gear_ratio) +
/// zero_offset_rad`; joint torque `τ = direction · gear_ratio · rated_torque_nm · t / 1000`
/// for a torque value `t` in per mille of the motor's rated torque (0x6071, 0x6077).
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Cia402Joint {
    /// The drive's CANopen node id, 1..=127.
    pub node_id: u8,
    /// The motor's rated torque (N·m), 0.001..=1000: the drive's 0x6076 must report this × 1000
    /// mNm (checked at activation, as every torque is scaled by it).
    pub rated_torque_nm: f64,
    /// Motor turns per joint turn (gearbox), 0.1..=1000; default 1.
    #[serde(default = "one")]
    pub gear_ratio: f64,
    /// +1 or −1: whether the motor's positive direction is the joint's; default +1.
    #[serde(default = "dir")]
    pub direction: i8,
    /// The joint angle when the drive reads position 0 (rad), −2π..=2π; default 0.
    #[serde(default)]
    pub zero_offset_rad: f64,
    /// Position increments per motor revolution (0x6064 units), 1..=1e9; default 4096.
    #[serde(default = "counts")]
    pub counts_per_rev: f64,
    /// The unit of 0x606C: `rpm` (default) or `counts_per_s`.
    #[serde(default)]
    pub velocity_unit: VelocityUnit,
    /// Joint torque limit (N·m), 0.01..=1000, written to the drive's max torque 0x6072 as
    /// well; the controller's own limit applies too.
    pub torque_limit_nm: f64,
    /// `cst` (cyclic synchronous torque, default) or `pt` (profile torque).
    #[serde(default)]
    pub mode: Cia402Mode,
    /// The drive's heartbeat period (ms), 10..=1000; default 50.
    #[serde(default = "hb")]
    pub heartbeat_ms: f64,
    /// No heartbeat from the drive for this long (ms) → protective stop; 20..=5000, more
    /// than `heartbeat_ms`; default 150.
    #[serde(default = "hb_timeout")]
    pub heartbeat_timeout_ms: f64,
    /// The node id exompc's own heartbeat carries (the drive watches it, 0x1016, and faults
    /// when exompc goes silent for three of its periods), 1..=127; default 127.
    #[serde(default = "master_id")]
    pub master_node_id: u8,
}

impl Cia402Joint {
    /// Checks every value; errors name `key.field` and the allowed range.
    pub fn validate(&self, key: &str) -> Result<(), ConfigError> {
        check_int(&format!("{key}.node_id"), i64::from(self.node_id), 1, 127)?;
        check_range(
            &format!("{key}.rated_torque_nm"),
            self.rated_torque_nm,
            0.001,
            1000.0,
        )?;
        check_range(&format!("{key}.gear_ratio"), self.gear_ratio, 0.1, 1000.0)?;
        if self.direction != 1 && self.direction != -1 {
            return Err(err(
                format!("{key}.direction"),
                format!("{} is not allowed (allowed: 1 or -1)", self.direction),
            ));
        }
        let tau = std::f64::consts::TAU;
        check_range(
            &format!("{key}.zero_offset_rad"),
            self.zero_offset_rad,
            -tau,
            tau,
        )?;
        check_range(
            &format!("{key}.counts_per_rev"),
            self.counts_per_rev,
            1.0,
            1e9,
        )?;
        check_range(
            &format!("{key}.torque_limit_nm"),
            self.torque_limit_nm,
            0.01,
            1000.0,
        )?;
        // 0x6072 is UNSIGNED16 per mille, and 0x6071 INTEGER16.
        let rated_joint = self.rated_torque_nm * self.gear_ratio;
        if self.torque_limit_nm / rated_joint * 1000.0 > 32767.0 {
            return Err(err(
                format!("{key}.torque_limit_nm"),
                format!(
                    "{} N·m is more than 32.767 × the rated joint torque {rated_joint} N·m \
                     (rated_torque_nm × gear_ratio): the per-mille target cannot carry it",
                    self.torque_limit_nm
                ),
            ));
        }
        check_range(
            &format!("{key}.heartbeat_ms"),
            self.heartbeat_ms,
            10.0,
            1000.0,
        )?;
        check_range(
            &format!("{key}.heartbeat_timeout_ms"),
            self.heartbeat_timeout_ms,
            20.0,
            5000.0,
        )?;
        if self.heartbeat_timeout_ms <= self.heartbeat_ms {
            return Err(err(
                format!("{key}.heartbeat_timeout_ms"),
                format!(
                    "{} ms is not more than heartbeat_ms = {} ms",
                    self.heartbeat_timeout_ms, self.heartbeat_ms
                ),
            ));
        }
        check_int(
            &format!("{key}.master_node_id"),
            i64::from(self.master_node_id),
            1,
            127,
        )?;
        if self.master_node_id == self.node_id {
            return Err(err(
                format!("{key}.master_node_id"),
                format!("{} is the drive's own node_id", self.master_node_id),
            ));
        }
        Ok(())
    }

    /// The mechanics as the master and the emulator use them.
    pub fn scaling(&self) -> Scaling {
        let velocity_unit = match self.velocity_unit {
            VelocityUnit::Rpm => std::f64::consts::TAU / 60.0,
            VelocityUnit::CountsPerS => std::f64::consts::TAU / self.counts_per_rev,
        };
        Scaling {
            rated_torque: self.rated_torque_nm,
            gear_ratio: self.gear_ratio,
            direction: f64::from(self.direction),
            zero_offset: self.zero_offset_rad,
            counts_per_rev: self.counts_per_rev,
            velocity_unit,
        }
    }

    /// The master's configuration (after [`Cia402Joint::validate`]).
    pub fn master_config(&self, period: Duration) -> Option<Cia402Config> {
        let node = NodeId::new(u32::from(self.node_id)).ok()?;
        let mut c = Cia402Config::new(node, self.scaling(), self.torque_limit_nm);
        c.mode = match self.mode {
            Cia402Mode::Cst => Mode::CyclicSynchronousTorque,
            Cia402Mode::Pt => Mode::ProfileTorque,
        };
        c.heartbeat_period = Duration::from_secs_f64(self.heartbeat_ms / 1000.0);
        c.heartbeat_timeout = Duration::from_secs_f64(self.heartbeat_timeout_ms / 1000.0);
        let master = NodeId::new(u32::from(self.master_node_id)).ok()?;
        // The master's heartbeat at the control period's multiple nearest 50 ms.
        let n = (0.05 / period.as_secs_f64().max(1e-4)).round().max(1.0);
        c.master_heartbeat = Some((master, period.mul_f64(n)));
        Some(c)
    }
}
