//! `driver = "canopen"`: a CANopen strap-force node (CiA 404-style analog inputs): the thigh
//! and shank process values 0x7130 sub 1 and 2 (INTEGER16) in a TPDO sent on every SYNC.

use super::{check_int, check_range, err, ConfigError};
use crate::canopen::{cob, NodeId};
use crate::force_node::ForceSource;
use serde::Deserialize;
use std::time::Duration;

fn yes() -> bool {
    true
}

fn hb() -> f64 {
    50.0
}

fn hb_timeout() -> f64 {
    150.0
}

/// `driver = "canopen"`: thigh = sub 1, shank = sub 2; `N = value × scale + offset`.
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CanopenForceSensor {
    /// The node id, 1..=127.
    pub node_id: u8,
    /// The TPDO's COB-ID, 0x181..=0x57F; default 0x180 + node_id (TPDO1).
    pub cob_id: Option<u16>,
    /// N per count, |scale| in 1e-6..=1e3.
    pub scale: f64,
    /// N added to the thigh force, −1e4..=1e4; default 0.
    #[serde(default)]
    pub offset_thigh_n: f64,
    /// N added to the shank force, −1e4..=1e4; default 0.
    #[serde(default)]
    pub offset_shank_n: f64,
    /// Map the TPDO (both values, every SYNC) and the heartbeat by SDO at activation, then
    /// start the node; `false` for a node configured once by its maker (then it must already
    /// send the TPDO on SYNC). Default true.
    #[serde(default = "yes")]
    pub configure: bool,
    /// The node's heartbeat period (ms), 10..=1000; default 50.
    #[serde(default = "hb")]
    pub heartbeat_ms: f64,
    /// No heartbeat for this long (ms) → protective stop; 20..=5000, more than heartbeat_ms;
    /// default 150.
    #[serde(default = "hb_timeout")]
    pub heartbeat_timeout_ms: f64,
}

impl CanopenForceSensor {
    /// Checks every value.
    pub fn validate(&self, key: &str) -> Result<(), ConfigError> {
        check_int(&format!("{key}.node_id"), i64::from(self.node_id), 1, 127)?;
        if let Some(c) = self.cob_id {
            check_int(&format!("{key}.cob_id"), i64::from(c), 0x181, 0x57F)?;
        }
        if !(self.scale.is_finite() && (1e-6..=1e3).contains(&self.scale.abs())) {
            return Err(err(
                format!("{key}.scale"),
                format!(
                    "{} is out of range (allowed |scale| in 1e-6..=1e3)",
                    self.scale
                ),
            ));
        }
        check_range(
            &format!("{key}.offset_thigh_n"),
            self.offset_thigh_n,
            -1e4,
            1e4,
        )?;
        check_range(
            &format!("{key}.offset_shank_n"),
            self.offset_shank_n,
            -1e4,
            1e4,
        )?;
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
        Ok(())
    }

    /// The TPDO's COB-ID.
    pub fn tpdo_cob_id(&self) -> u16 {
        self.cob_id
            .unwrap_or(cob::TPDO[0] + u16::from(self.node_id))
    }

    /// The master's source description (after [`CanopenForceSensor::validate`]).
    pub fn source(&self) -> Option<ForceSource> {
        Some(ForceSource::Canopen {
            node: NodeId::new(u32::from(self.node_id)).ok()?,
            cob_id: self.tpdo_cob_id(),
            scale: self.scale,
            offset: [self.offset_thigh_n, self.offset_shank_n],
            configure: self.configure,
            heartbeat: Some((
                Duration::from_secs_f64(self.heartbeat_ms / 1000.0),
                Duration::from_secs_f64(self.heartbeat_timeout_ms / 1000.0),
            )),
        })
    }
}
