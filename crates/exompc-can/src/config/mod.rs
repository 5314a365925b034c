//! The hardware keys of a scenario's `[robot]` table: the bus (`[robot.bus]`), the drive of
//! each joint (`[robot.joints.hip]`, `[robot.joints.knee]`), the strap-force sensor node(s)
//! (`[[robot.force_sensors]]`) and the bus safety (`[robot.safety]`).
//!
//! The model keys of `[robot]` (links, friction; MODEL.md §3) stay the scenario's; the loader
//! splits the hardware tables off with [`split_hardware`] so that `exompc simulate` reads the
//! same file and ignores them. Every value is checked by [`HardwareConfig::validate`]; an error
//! names the key by its dotted path and the allowed range.
//!
//! Drivers are enums tagged by `driver = "..."`: a joint is `ak` ([`AkJoint`], in `ak.rs`) or
//! `cia402` ([`Cia402Joint`], in `cia402.rs`); a force sensor is `raw` ([`RawForceSensor`], in
//! `force_raw.rs`) or `canopen` ([`CanopenForceSensor`], in `force_canopen.rs`). Other drivers
//! add a variant and a file of their own.

mod ak;
mod cia402;
mod force_canopen;
mod force_raw;

pub use ak::{AkJoint, AkModel, AkReplyEffort, AK_MODELS};
pub use cia402::{Cia402Joint, Cia402Mode, VelocityUnit};
pub use force_canopen::CanopenForceSensor;
pub use force_raw::{ForceChannel, RawForceSensor};

use serde::Deserialize;
use std::fmt;

/// The `[robot]` keys that describe hardware (everything else in `[robot]` is the model's).
pub const HARDWARE_KEYS: [&str; 4] = ["bus", "joints", "force_sensors", "safety"];

/// A configuration value out of its allowed range (or missing, or inconsistent).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ConfigError {
    /// The key, dotted from the top of the file (`robot.joints.hip.can_id`).
    pub key: String,
    /// What is wrong and what is allowed.
    pub message: String,
}

impl fmt::Display for ConfigError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}: {}", self.key, self.message)
    }
}

impl std::error::Error for ConfigError {}

fn err(key: impl Into<String>, message: impl Into<String>) -> ConfigError {
    ConfigError {
        key: key.into(),
        message: message.into(),
    }
}

/// Checks that `v` is finite and within `lo..=hi`.
pub(crate) fn check_range(key: &str, v: f64, lo: f64, hi: f64) -> Result<(), ConfigError> {
    if v.is_finite() && v >= lo && v <= hi {
        Ok(())
    } else {
        Err(err(
            key,
            format!("{v} is out of range (allowed {lo}..={hi})"),
        ))
    }
}

/// Checks that the integer `v` is within `lo..=hi`.
pub(crate) fn check_int(key: &str, v: i64, lo: i64, hi: i64) -> Result<(), ConfigError> {
    if (lo..=hi).contains(&v) {
        Ok(())
    } else {
        Err(err(
            key,
            format!("{v} is out of range (allowed {lo}..={hi})"),
        ))
    }
}

/// The hardware keys of `[robot]`.
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HardwareConfig {
    /// `[robot.bus]`: the transport.
    pub bus: BusConfig,
    /// `[robot.joints]`: the drive of each joint.
    pub joints: Joints,
    /// `[[robot.force_sensors]]`: the strap-force sensor node(s); together they must provide
    /// the thigh and the shank strap force exactly once each.
    #[serde(default)]
    pub force_sensors: Vec<ForceSensor>,
    /// `[robot.safety]`: timeouts and the protective stop.
    #[serde(default)]
    pub safety: SafetyConfig,
}

/// `[robot.bus]`: which transport carries the bus, tagged by `transport = "..."`.
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(tag = "transport", rename_all = "lowercase", deny_unknown_fields)]
pub enum BusConfig {
    /// The in-process virtual bus with virtual devices and the simulated leg behind them.
    Virtual(VirtualTransport),
    /// An slcan adapter (CANable, USBtin) on a serial port.
    Slcan(SlcanTransport),
    /// A Linux SocketCAN interface (`can0`, `vcan0`).
    Socketcan(SocketcanTransport),
}

impl BusConfig {
    /// The bit rate (bit/s).
    pub fn bitrate(&self) -> u32 {
        match self {
            BusConfig::Virtual(v) => v.bitrate,
            BusConfig::Slcan(s) => s.bitrate,
            BusConfig::Socketcan(s) => s.bitrate,
        }
    }
}

fn default_bitrate() -> u32 {
    1_000_000
}

fn default_latency_us() -> u32 {
    100
}

/// `transport = "virtual"`.
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct VirtualTransport {
    /// Bit rate (bit/s), 10 000..=1 000 000; default 1 000 000.
    #[serde(default = "default_bitrate")]
    pub bitrate: u32,
    /// Probability that a frame is lost, 0..=0.5; default 0.
    #[serde(default)]
    pub loss: f64,
    /// Probability that a transmission ends in an error frame (then retransmitted), 0..=0.5;
    /// default 0.
    #[serde(default)]
    pub error_frames: f64,
    /// Seed of the fault injection; default 1.
    #[serde(default = "default_seed")]
    pub seed: u64,
    /// Time a virtual device takes to answer (µs), 0..=5000; default 100.
    #[serde(default = "default_latency_us")]
    pub device_latency_us: u32,
}

fn default_seed() -> u64 {
    1
}

/// `transport = "slcan"`.
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SlcanTransport {
    /// The serial device (`/dev/ttyACM0`, a pty path from `exompc virtual-robot --config`).
    pub port: String,
    /// Bit rate (bit/s): one of slcan's S0..S8 rates; default 1 000 000.
    #[serde(default = "default_bitrate")]
    pub bitrate: u32,
}

/// `transport = "socketcan"`.
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SocketcanTransport {
    /// The interface (`can0`, `vcan0`); its bit rate is set with `ip link`, not here.
    pub interface: String,
    /// The interface's bit rate (bit/s), for the bus-load figures only; default 1 000 000.
    #[serde(default = "default_bitrate")]
    pub bitrate: u32,
}

/// `[robot.joints]`: hip and knee (the 2-DOF leg; for the 1-DOF knee only `knee` is used).
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Joints {
    /// `[robot.joints.hip]`.
    pub hip: Joint,
    /// `[robot.joints.knee]`.
    pub knee: Joint,
}

impl Joints {
    /// `(name, joint)` in the model's joint order (hip, knee).
    pub fn iter(&self) -> [(&'static str, &Joint); 2] {
        [("hip", &self.hip), ("knee", &self.knee)]
    }
}

/// The drive of one joint, tagged by `driver = "..."`.
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(tag = "driver", rename_all = "lowercase")]
pub enum Joint {
    /// A T-Motor/CubeMars AK actuator in MIT mode.
    Ak(AkJoint),
    /// A CANopen CiA 402 drive (cyclic synchronous or profile torque).
    Cia402(Cia402Joint),
}

/// Which strap force a sensor channel measures.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Strap {
    /// The thigh strap (model joint 0's strap).
    Thigh,
    /// The shank strap (model joint 1's strap).
    Shank,
}

/// One strap-force sensor node, tagged by `driver = "..."`.
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(tag = "driver", rename_all = "lowercase")]
pub enum ForceSensor {
    /// A node sending the forces in a plain CAN frame (a custom amplifier).
    Raw(RawForceSensor),
    /// A CANopen node (CiA 404-style analog inputs in a TPDO): thigh and shank.
    Canopen(CanopenForceSensor),
}

impl ForceSensor {
    /// The straps this sensor measures.
    pub fn straps(&self) -> Vec<Strap> {
        match self {
            ForceSensor::Raw(r) => r.channels.iter().map(|c| c.strap).collect(),
            ForceSensor::Canopen(_) => vec![Strap::Thigh, Strap::Shank],
        }
    }
}

/// `[robot.safety]`.
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SafetyConfig {
    /// Time every device has to report ready after the bus opens (ms), 10..=60 000; default
    /// 2000.
    pub ready_timeout_ms: f64,
    /// Longest time without a reply from a motor or a frame from a sensor node while active
    /// (ms), 1..=1000; default 30 (three periods at 100 Hz). Longer → protective stop.
    pub reply_timeout_ms: f64,
    /// Shortest time of the protective stop's ramp of the torque to zero (ms), 0..=5000;
    /// default 0: at the torque-rate limit, as the UDP robot. A longer time ramps more gently;
    /// the rate limit can make the ramp longer, never shorter (`robot::stop_ramp_steps`).
    pub stop_ramp_ms: f64,
}

impl Default for SafetyConfig {
    fn default() -> Self {
        SafetyConfig {
            ready_timeout_ms: 2000.0,
            reply_timeout_ms: 30.0,
            stop_ramp_ms: 0.0,
        }
    }
}

impl HardwareConfig {
    /// Checks every value; the error names the key (`robot....`) and the allowed range.
    pub fn validate(&self) -> Result<(), ConfigError> {
        match &self.bus {
            BusConfig::Virtual(v) => {
                check_int("robot.bus.bitrate", i64::from(v.bitrate), 10_000, 1_000_000)?;
                check_range("robot.bus.loss", v.loss, 0.0, 0.5)?;
                check_range("robot.bus.error_frames", v.error_frames, 0.0, 0.5)?;
                check_int(
                    "robot.bus.device_latency_us",
                    i64::from(v.device_latency_us),
                    0,
                    5000,
                )?;
            }
            BusConfig::Slcan(s) => {
                if crate::slcan::bitrate_code(s.bitrate).is_none() {
                    return Err(err(
                        "robot.bus.bitrate",
                        format!(
                            "{} is not an slcan bit rate (allowed: {:?})",
                            s.bitrate,
                            crate::slcan::BITRATES
                        ),
                    ));
                }
                if s.port.trim().is_empty() {
                    return Err(err("robot.bus.port", "is empty (a serial device path)"));
                }
            }
            BusConfig::Socketcan(s) => {
                if s.interface.is_empty() || s.interface.len() > 15 {
                    return Err(err(
                        "robot.bus.interface",
                        format!("{:?}: an interface name of 1..=15 bytes", s.interface),
                    ));
                }
                check_int("robot.bus.bitrate", i64::from(s.bitrate), 10_000, 1_000_000)?;
            }
        }
        let mut ids: Vec<(u32, String)> = Vec::new();
        for (name, j) in self.joints.iter() {
            let key = format!("robot.joints.{name}");
            match j {
                Joint::Ak(a) => {
                    a.validate(&key)?;
                    ids.push((a.can_id, format!("{key}.can_id")));
                }
                Joint::Cia402(c) => {
                    c.validate(&key)?;
                    // CANopen node ids live in their own number space (COB-IDs 0x180 + id …).
                    ids.push((0x1000 + u32::from(c.node_id), format!("{key}.node_id")));
                }
            }
        }
        for (i, f) in self.force_sensors.iter().enumerate() {
            if let ForceSensor::Canopen(c) = f {
                c.validate(&format!("robot.force_sensors[{i}]"))?;
                let key = format!("robot.force_sensors[{i}].node_id");
                ids.push((0x1000 + u32::from(c.node_id), key));
            }
        }
        for w in 0..ids.len() {
            for v in w + 1..ids.len() {
                if ids[w].0 == ids[v].0 {
                    return Err(err(
                        ids[v].1.clone(),
                        format!("{} is also {}", ids[v].0 & 0xFFF, ids[w].1),
                    ));
                }
            }
        }
        let mut seen = Vec::new();
        for (i, f) in self.force_sensors.iter().enumerate() {
            let key = format!("robot.force_sensors[{i}]");
            match f {
                ForceSensor::Raw(r) => r.validate(&key)?,
                ForceSensor::Canopen(c) => c.validate(&key)?,
            }
            for s in f.straps() {
                if seen.contains(&s) {
                    return Err(err(
                        key,
                        format!("measures the {s:?} strap again (each strap exactly once)"),
                    ));
                }
                seen.push(s);
            }
        }
        if self.force_sensors.is_empty() {
            return Err(err(
                "robot.force_sensors",
                "missing: the controller needs the thigh and shank strap forces",
            ));
        }
        for s in [Strap::Thigh, Strap::Shank] {
            if !seen.contains(&s) {
                return Err(err(
                    "robot.force_sensors",
                    format!("no sensor measures the {s:?} strap (each strap exactly once)"),
                ));
            }
        }
        let s = &self.safety;
        check_range(
            "robot.safety.ready_timeout_ms",
            s.ready_timeout_ms,
            10.0,
            60_000.0,
        )?;
        check_range(
            "robot.safety.reply_timeout_ms",
            s.reply_timeout_ms,
            1.0,
            1000.0,
        )?;
        check_range("robot.safety.stop_ramp_ms", s.stop_ramp_ms, 0.0, 5000.0)?;
        Ok(())
    }

    /// Parse the hardware tables of `[robot]` (a TOML table holding some of
    /// [`HARDWARE_KEYS`]) and validate them.
    pub fn from_table(robot_hw: toml::Table) -> Result<Self, ConfigError> {
        let cfg: HardwareConfig = toml::Value::Table(robot_hw)
            .try_into()
            .map_err(|e: toml::de::Error| err("robot", e.message().trim().to_string()))?;
        cfg.validate()?;
        Ok(cfg)
    }
}

/// Split a scenario file into the scenario proper and the hardware tables of `[robot]`.
///
/// Returns the text with the hardware tables blanked out (their lines replaced by empty lines,
/// so that line numbers in later error messages still match the file) and, if the file has
/// any, those tables. Hardware keys must be written as tables (`[robot.bus]`,
/// `[robot.joints.hip]`, `[[robot.force_sensors]]`, `[robot.safety]`); written inline under
/// `[robot]` they are reported as an error.
pub fn split_hardware(text: &str) -> Result<(String, Option<toml::Table>), ConfigError> {
    let mut kept = String::with_capacity(text.len());
    let mut hw = String::new();
    let mut in_hw = false;
    let mut in_robot = false;
    for line in text.split_inclusive('\n') {
        if let Some(path) = header_path(line) {
            let mut parts = path.split('.').map(str::trim);
            let first = parts.next().unwrap_or("");
            let second = parts.next();
            in_robot = first == "robot" && second.is_none();
            in_hw = first == "robot" && second.is_some_and(|s| HARDWARE_KEYS.contains(&s));
        } else if in_robot {
            let key = line.split('=').next().unwrap_or("").trim();
            let key = key.split('.').next().unwrap_or("").trim();
            if line.contains('=') && HARDWARE_KEYS.contains(&key) {
                return Err(err(
                    format!("robot.{key}"),
                    format!("write it as a table of its own, [robot.{key}...], not inline"),
                ));
            }
        }
        if in_hw {
            hw.push_str(line);
            kept.push_str(if line.ends_with('\n') { "\n" } else { "" });
        } else {
            kept.push_str(line);
            hw.push_str(if line.ends_with('\n') { "\n" } else { "" });
        }
    }
    if hw.trim().is_empty() {
        return Ok((kept, None));
    }
    let table: toml::Table = toml::from_str(&hw).map_err(|e| {
        let line = e
            .span()
            .map(|s| hw[..s.start.min(hw.len())].lines().count().max(1))
            .unwrap_or(0);
        err("robot", format!("line {line}: {}", e.message().trim()))
    })?;
    let robot = match table.get("robot") {
        Some(toml::Value::Table(t)) => t.clone(),
        _ => toml::Table::new(),
    };
    Ok((kept, Some(robot)))
}

/// The dotted path of a table header line (`[a.b]` or `[[a.b]]`), quotes removed.
fn header_path(line: &str) -> Option<String> {
    let l = line.trim();
    let l = l.split('#').next().unwrap_or("").trim();
    let inner = l
        .strip_prefix("[[")
        .and_then(|x| x.strip_suffix("]]"))
        .or_else(|| l.strip_prefix('[').and_then(|x| x.strip_suffix(']')))?;
    let ok = inner
        .chars()
        .all(|c| c.is_ascii_alphanumeric() || "_-. \"'".contains(c));
    (ok && !inner.trim().is_empty()).then(|| inner.replace(['"', '\'', ' '], ""))
}

#[cfg(test)]
mod tests;
