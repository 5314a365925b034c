//! `controller.kind`: the name of a controller of the controller registry.

use super::ConfigError;
use alloc::{format, string::String};
use core::fmt;
use serde::{Deserialize, Deserializer, Serialize, Serializer};

/// Longest controller name (bytes).
const MAX_LEN: usize = 31;

/// Which controller drives the robot: the name of an entry of the controller registry
/// ([`exompc::scenario::controllers`](crate::scenario::controllers)), as written in
/// `controller.kind`, on the command line (`--controller msnmpc`), in folder names and in
/// `summary.json`.
///
/// A `ControllerKind` holds a well-formed name ([`ControllerKind::new`]: 1 to 31 characters
/// `a-z`, `0-9`, `_`, `-`, starting with a letter); whether a controller of that name is
/// registered is checked by the scenario layer
/// ([`exompc::scenario::validate`](crate::scenario::validate)), whose error lists the
/// registered names. It is `Copy` and compares by name; serialized, it is the name.
///
/// ```
/// use exompc::config::ControllerKind;
/// let k = ControllerKind::new("msnmpc").unwrap();
/// assert_eq!(k, ControllerKind::MSNMPC);
/// assert_eq!(k.as_str(), "msnmpc");
/// assert!(ControllerKind::new("MS NMPC").is_err());
/// ```
#[derive(Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct ControllerKind {
    len: u8,
    bytes: [u8; MAX_LEN],
}

impl ControllerKind {
    /// Baseline joint PD on the estimated human intent (`[controller.pd]` gains).
    pub const PD: Self = Self::from_static("pd");
    /// Non-robust NMPC on the nominal (0 kg) model, no disturbance estimate (paper §3.1,
    /// eq. 7).
    pub const NMPC: Self = Self::from_static("nmpc");
    /// Multi-stage robust NMPC (paper §3.2, eqs. 10-13).
    pub const MSNMPC: Self = Self::from_static("msnmpc");

    /// The allowed names in words (the `allowed` of a [`ConfigError`]).
    pub const SYNTAX: &'static str =
        "1 to 31 characters a-z, 0-9, '_' or '-', starting with a letter";

    /// The kind named `name`, if it is well-formed (see [`ControllerKind::SYNTAX`]); the
    /// error names the field `controller.kind`.
    pub fn new(name: &str) -> Result<Self, ConfigError> {
        if well_formed(name.as_bytes()) {
            Ok(Self::from_bytes(name.as_bytes()))
        } else {
            Err(ConfigError::new(
                "controller.kind",
                format!("{name:?}"),
                Self::SYNTAX,
            ))
        }
    }

    /// The kind named `name`, for constants (`const MINE: ControllerKind =
    /// ControllerKind::from_static("mine");`). Panics (at compile time in a constant) if
    /// `name` is not well-formed.
    pub const fn from_static(name: &'static str) -> Self {
        assert!(
            well_formed(name.as_bytes()),
            "a controller name has 1 to 31 characters a-z, 0-9, '_' or '-', starting with a letter"
        );
        Self::from_bytes(name.as_bytes())
    }

    const fn from_bytes(b: &[u8]) -> Self {
        let mut bytes = [0u8; MAX_LEN];
        let mut i = 0;
        while i < b.len() {
            bytes[i] = b[i];
            i += 1;
        }
        ControllerKind {
            len: b.len() as u8,
            bytes,
        }
    }

    /// The name.
    pub fn as_str(&self) -> &str {
        // Only ASCII bytes are ever stored (see `well_formed`).
        core::str::from_utf8(&self.bytes[..usize::from(self.len)]).unwrap_or_default()
    }
}

/// 1..=MAX_LEN bytes of `a-z0-9_-`, the first a letter.
const fn well_formed(b: &[u8]) -> bool {
    if b.is_empty() || b.len() > MAX_LEN || !b[0].is_ascii_lowercase() {
        return false;
    }
    let mut i = 0;
    while i < b.len() {
        let c = b[i];
        if !(c.is_ascii_lowercase() || c.is_ascii_digit() || c == b'_' || c == b'-') {
            return false;
        }
        i += 1;
    }
    true
}

impl fmt::Display for ControllerKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

impl fmt::Debug for ControllerKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "ControllerKind({:?})", self.as_str())
    }
}

impl core::str::FromStr for ControllerKind {
    type Err = ConfigError;
    fn from_str(s: &str) -> Result<Self, ConfigError> {
        Self::new(s)
    }
}

impl Serialize for ControllerKind {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_str(self.as_str())
    }
}

impl<'de> Deserialize<'de> for ControllerKind {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        let name = String::deserialize(d)?;
        Self::new(&name).map_err(|e| {
            serde::de::Error::custom(format_args!(
                "controller name {:?}: expected {}",
                name, e.allowed
            ))
        })
    }
}
