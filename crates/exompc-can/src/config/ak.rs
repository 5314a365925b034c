//! `driver = "ak"`: a T-Motor/CubeMars AK actuator in MIT mode.

use super::{check_int, check_range, err, ConfigError};
use serde::Deserialize;

/// The MIT-mode ranges of one AK model: each command field is packed linearly over its range
/// (position 16 bit, velocity 12, kp 12, kd 12, torque 12), and the reply's fields the same.
/// The values are the output side's (after the actuator's own gearbox), as the firmware reports
/// them.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AkModel {
    /// The model name as written in the config (`AK80-9`).
    pub name: &'static str,
    /// Position range ±p_max (rad).
    pub p_max: f64,
    /// Velocity range ±v_max (rad/s).
    pub v_max: f64,
    /// Torque range ±t_max (N·m).
    pub t_max: f64,
    /// Stiffness range 0..kp_max (N·m/rad).
    pub kp_max: f64,
    /// Damping range 0..kd_max (N·m·s/rad).
    pub kd_max: f64,
}

/// The MIT-mode ranges of the AK models the config knows by name (CubeMars AK-series manual,
/// MIT-mode tables). Firmware versions differ: a motor whose firmware packs over other ranges
/// is configured with the `p_max`, `v_max`, `t_max`, `kp_max`, `kd_max` keys, which override
/// the table.
pub const AK_MODELS: [AkModel; 6] = [
    AkModel {
        name: "AK80-9",
        p_max: 12.5,
        v_max: 50.0,
        t_max: 18.0,
        kp_max: 500.0,
        kd_max: 5.0,
    },
    AkModel {
        name: "AK60-6",
        p_max: 12.5,
        v_max: 45.0,
        t_max: 15.0,
        kp_max: 500.0,
        kd_max: 5.0,
    },
    AkModel {
        name: "AK70-10",
        p_max: 12.5,
        v_max: 50.0,
        t_max: 25.0,
        kp_max: 500.0,
        kd_max: 5.0,
    },
    AkModel {
        name: "AK10-9",
        p_max: 12.5,
        v_max: 50.0,
        t_max: 65.0,
        kp_max: 500.0,
        kd_max: 5.0,
    },
    AkModel {
        name: "AK80-6",
        p_max: 12.5,
        v_max: 76.0,
        t_max: 12.0,
        kp_max: 500.0,
        kd_max: 5.0,
    },
    AkModel {
        name: "AK80-64",
        p_max: 12.5,
        v_max: 8.0,
        t_max: 144.0,
        kp_max: 500.0,
        kd_max: 5.0,
    },
];

impl AkModel {
    /// The table entry of `name` (case-insensitive).
    pub fn by_name(name: &str) -> Option<AkModel> {
        AK_MODELS
            .iter()
            .find(|m| m.name.eq_ignore_ascii_case(name))
            .copied()
    }
}

/// What the 12-bit effort field of the motor's reply carries.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum AkReplyEffort {
    /// Torque over ±t_max (N·m), as the MIT-mode manual specifies.
    #[default]
    Torque,
    /// Current over ±t_max read as amperes (some firmware); converted with
    /// `torque_per_amp`.
    Current,
}

fn one() -> f64 {
    1.0
}

fn dir() -> i64 {
    1
}

/// `driver = "ak"`: one AK actuator in MIT mode, used torque-only (kp = kd = 0).
///
/// The joint's angle is `q = direction · p / gear_ratio + zero_offset_rad` where `p` is the
/// motor's reported (output-side) position; the torque sent is
/// `τ_motor = direction · τ_joint / gear_ratio`.
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AkJoint {
    /// The motor's CAN ID (its command frames' standard identifier), 1..=127.
    pub can_id: u32,
    /// The model (`AK80-9`, `AK60-6`, `AK70-10`, `AK10-9`, `AK80-6`, `AK80-64`): the MIT
    /// ranges of [`AK_MODELS`].
    pub model: String,
    /// The CAN ID the motor's replies carry (its "master ID"; the motor ID is in byte 0);
    /// 0..=0x7FF; default 0.
    #[serde(default)]
    pub reply_id: u32,
    /// Ratio of an external transmission between the actuator's output and the joint (joint
    /// torque / actuator torque), 0.1..=100; default 1 (the actuator drives the joint directly).
    #[serde(default = "one")]
    pub gear_ratio: f64,
    /// +1 or −1: whether the motor's positive direction is the joint's; default +1.
    #[serde(default = "dir")]
    pub direction: i64,
    /// The joint angle when the motor reads position 0 (rad), −2π..=2π; default 0.
    #[serde(default)]
    pub zero_offset_rad: f64,
    /// A joint torque limit below the motor's range (N·m); default: the motor's t_max ×
    /// gear_ratio. The controller's own limit (`[timing]`/MODEL.md §7) applies as well.
    pub torque_limit_nm: Option<f64>,
    /// What the reply's effort field carries; default `torque`.
    #[serde(default)]
    pub reply_effort: AkReplyEffort,
    /// Output torque per ampere (N·m/A) when `reply_effort = "current"`, 0.001..=100.
    pub torque_per_amp: Option<f64>,
    /// Override of the model's position range (rad), 0.1..=1000.
    pub p_max: Option<f64>,
    /// Override of the model's velocity range (rad/s), 0.1..=1000.
    pub v_max: Option<f64>,
    /// Override of the model's torque range (N·m), 0.1..=1000.
    pub t_max: Option<f64>,
    /// Override of the model's kp range (N·m/rad), 1..=10 000.
    pub kp_max: Option<f64>,
    /// Override of the model's kd range (N·m·s/rad), 0.1..=1000.
    pub kd_max: Option<f64>,
}

impl AkJoint {
    /// The MIT ranges in use: the model's, with the overrides applied.
    pub fn ranges(&self) -> Option<AkModel> {
        let m = AkModel::by_name(&self.model)?;
        Some(AkModel {
            p_max: self.p_max.unwrap_or(m.p_max),
            v_max: self.v_max.unwrap_or(m.v_max),
            t_max: self.t_max.unwrap_or(m.t_max),
            kp_max: self.kp_max.unwrap_or(m.kp_max),
            kd_max: self.kd_max.unwrap_or(m.kd_max),
            ..m
        })
    }

    /// The joint torque limit (N·m): `torque_limit_nm`, or the motor's range × gear ratio.
    pub fn joint_torque_limit(&self) -> f64 {
        let motor = self.ranges().map_or(0.0, |r| r.t_max) * self.gear_ratio;
        self.torque_limit_nm.unwrap_or(motor).min(motor)
    }

    /// Checks every value; `key` is the table's dotted path.
    pub fn validate(&self, key: &str) -> Result<(), ConfigError> {
        check_int(&format!("{key}.can_id"), i64::from(self.can_id), 1, 127)?;
        check_int(
            &format!("{key}.reply_id"),
            i64::from(self.reply_id),
            0,
            0x7FF,
        )?;
        if AkModel::by_name(&self.model).is_none() {
            let names: Vec<&str> = AK_MODELS.iter().map(|m| m.name).collect();
            return Err(err(
                format!("{key}.model"),
                format!(
                    "{:?} is not a known AK model (allowed: {})",
                    self.model,
                    names.join(", ")
                ),
            ));
        }
        if self.reply_id == self.can_id {
            return Err(err(
                format!("{key}.reply_id"),
                format!(
                    "{} equals can_id: replies need an ID of their own",
                    self.reply_id
                ),
            ));
        }
        check_range(&format!("{key}.gear_ratio"), self.gear_ratio, 0.1, 100.0)?;
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
        for (name, v, lo, hi) in [
            ("p_max", self.p_max, 0.1, 1000.0),
            ("v_max", self.v_max, 0.1, 1000.0),
            ("t_max", self.t_max, 0.1, 1000.0),
            ("kp_max", self.kp_max, 1.0, 10_000.0),
            ("kd_max", self.kd_max, 0.1, 1000.0),
        ] {
            if let Some(v) = v {
                check_range(&format!("{key}.{name}"), v, lo, hi)?;
            }
        }
        let motor = self.ranges().map_or(0.0, |r| r.t_max) * self.gear_ratio;
        if let Some(t) = self.torque_limit_nm {
            check_range(&format!("{key}.torque_limit_nm"), t, 0.0, motor)?;
        }
        match (self.reply_effort, self.torque_per_amp) {
            (AkReplyEffort::Current, None) => {
                return Err(err(
                    format!("{key}.torque_per_amp"),
                    "missing: required when reply_effort = \"current\" (0.001..=100 N·m/A)",
                ))
            }
            (_, Some(k)) => check_range(&format!("{key}.torque_per_amp"), k, 0.001, 100.0)?,
            _ => {}
        }
        Ok(())
    }
}
