//! `driver = "raw"`: a strap-force node that sends its forces in a plain CAN frame (a custom
//! amplifier): the frame's ID, and per strap the bytes that hold the value and its scaling.

use super::{check_int, check_range, err, ConfigError, Strap};
use serde::Deserialize;

/// One force channel of a raw frame: `force = scale · raw + offset_n`, `raw` the integer in
/// `bytes` bytes from byte `byte` (little-endian unless `big_endian`).
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ForceChannel {
    /// Which strap.
    pub strap: Strap,
    /// First byte, 0..=7.
    pub byte: u32,
    /// Width: 1, 2 or 4 bytes; default 2.
    #[serde(default = "two")]
    pub bytes: u32,
    /// Whether the integer is signed (two's complement); default true.
    #[serde(default = "yes")]
    pub signed: bool,
    /// Byte order; default little-endian.
    #[serde(default)]
    pub big_endian: bool,
    /// Newtons per count, non-zero, |scale| in 1e-6..=1e3.
    pub scale: f64,
    /// Newtons added after scaling, −1e4..=1e4; default 0.
    #[serde(default)]
    pub offset_n: f64,
}

fn two() -> u32 {
    2
}

fn yes() -> bool {
    true
}

fn default_rate() -> f64 {
    1000.0
}

/// `driver = "raw"`: a node sending one frame with the strap force(s) at its own rate.
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RawForceSensor {
    /// The frame's identifier (standard 0..=0x7FF unless `extended`).
    pub can_id: u32,
    /// Whether `can_id` is a 29-bit identifier; default false.
    #[serde(default)]
    pub extended: bool,
    /// The node's sending rate (Hz), 1..=10 000; default 1000 (the virtual node sends at this
    /// rate; for real hardware it documents what to expect).
    #[serde(default = "default_rate")]
    pub rate_hz: f64,
    /// The channels (one per strap this node measures).
    pub channels: Vec<ForceChannel>,
}

impl ForceChannel {
    /// The force (N) in `data`, `None` if the frame is too short.
    pub fn decode(&self, data: &[u8]) -> Option<f64> {
        let (b, n) = (self.byte as usize, self.bytes as usize);
        let s = data.get(b..b + n)?;
        let mut v: u64 = 0;
        for i in 0..n {
            let byte = if self.big_endian { s[i] } else { s[n - 1 - i] };
            v = (v << 8) | u64::from(byte);
        }
        let raw = if self.signed {
            let shift = 64 - 8 * n as u32;
            (((v << shift) as i64) >> shift) as f64
        } else {
            v as f64
        };
        Some(self.scale * raw + self.offset_n)
    }

    /// The bytes of `force` (N) written into `data` (rounded, saturated to the width).
    pub fn encode(&self, force: f64, data: &mut [u8; 8]) {
        let (b, n) = (self.byte as usize, self.bytes as usize);
        let raw = ((force - self.offset_n) / self.scale).round();
        let bits = 8 * n as u32;
        let (lo, hi) = if self.signed {
            (
                -(2f64.powi(bits as i32 - 1)),
                2f64.powi(bits as i32 - 1) - 1.0,
            )
        } else {
            (0.0, 2f64.powi(bits as i32) - 1.0)
        };
        let raw = if raw.is_finite() {
            raw.clamp(lo, hi)
        } else {
            0.0
        };
        let v = raw as i64 as u64;
        for i in 0..n {
            let byte = (v >> (8 * i)) as u8;
            let at = if self.big_endian {
                b + n - 1 - i
            } else {
                b + i
            };
            if let Some(d) = data.get_mut(at) {
                *d = byte;
            }
        }
    }
}

impl RawForceSensor {
    /// Frame length the channels need.
    pub fn frame_len(&self) -> usize {
        self.channels
            .iter()
            .map(|c| c.byte as usize + c.bytes as usize)
            .max()
            .unwrap_or(0)
    }

    /// Checks every value; `key` is the table's dotted path.
    pub fn validate(&self, key: &str) -> Result<(), ConfigError> {
        let max = if self.extended { 0x1FFF_FFFF } else { 0x7FF };
        check_int(&format!("{key}.can_id"), i64::from(self.can_id), 0, max)?;
        check_range(&format!("{key}.rate_hz"), self.rate_hz, 1.0, 10_000.0)?;
        if self.channels.is_empty() || self.channels.len() > 2 {
            return Err(err(
                format!("{key}.channels"),
                format!("{} channels (allowed 1..=2)", self.channels.len()),
            ));
        }
        for (i, c) in self.channels.iter().enumerate() {
            let k = format!("{key}.channels[{i}]");
            check_int(&format!("{k}.byte"), i64::from(c.byte), 0, 7)?;
            if ![1, 2, 4].contains(&c.bytes) {
                return Err(err(
                    format!("{k}.bytes"),
                    format!("{} is not allowed (allowed: 1, 2 or 4)", c.bytes),
                ));
            }
            if c.byte + c.bytes > 8 {
                return Err(err(
                    format!("{k}.byte"),
                    format!(
                        "bytes {}..{} pass the end of an 8-byte frame",
                        c.byte,
                        c.byte + c.bytes
                    ),
                ));
            }
            if !(c.scale.is_finite() && (1e-6..=1e3).contains(&c.scale.abs())) {
                return Err(err(
                    format!("{k}.scale"),
                    format!(
                        "{} is out of range (allowed |scale| in 1e-6..=1e3)",
                        c.scale
                    ),
                ));
            }
            check_range(&format!("{k}.offset_n"), c.offset_n, -1e4, 1e4)?;
        }
        Ok(())
    }
}
