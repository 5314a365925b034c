//! CANopen (CiA 301) on top of [`CanFrame`](crate::CanFrame): node ids and predefined
//! COB-IDs, NMT, SDO client and server (expedited and segmented), heartbeat producer and
//! consumer, the SYNC producer, PDO mapping and packing, and an object dictionary for emulated
//! nodes.
//!
//! Every codec here is sans-I/O: it turns frames into events and requests into frames, with
//! time passed in as a [`Duration`](std::time::Duration) since an arbitrary origin, so the same
//! code runs on the virtual bus, slcan or SocketCAN and is tested without any of them.

pub mod heartbeat;
pub mod nmt;
pub mod od;
pub mod pdo;
pub mod sdo;
pub mod sync;

use thiserror::Error;

/// Function codes of the predefined connection set (CiA 301 §7.3.5): the COB-ID of a
/// node-specific object is its function code plus the node id.
pub mod cob {
    /// NMT node control (master → nodes), COB-ID 0x000.
    pub const NMT: u16 = 0x000;
    /// SYNC, COB-ID 0x080.
    pub const SYNC: u16 = 0x080;
    /// Emergency, 0x080 + node id.
    pub const EMCY: u16 = 0x080;
    /// TPDO1..4 (node → master): 0x180, 0x280, 0x380, 0x480 + node id.
    pub const TPDO: [u16; 4] = [0x180, 0x280, 0x380, 0x480];
    /// RPDO1..4 (master → node): 0x200, 0x300, 0x400, 0x500 + node id.
    pub const RPDO: [u16; 4] = [0x200, 0x300, 0x400, 0x500];
    /// SDO server → client (responses), 0x580 + node id.
    pub const SDO_TX: u16 = 0x580;
    /// SDO client → server (requests), 0x600 + node id.
    pub const SDO_RX: u16 = 0x600;
    /// NMT error control (heartbeat, boot-up), 0x700 + node id.
    pub const HEARTBEAT: u16 = 0x700;
}

/// A CANopen node id, 1..=127.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct NodeId(u8);

/// A node id outside 1..=127.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Error)]
#[error("CANopen node id {0} is out of range (allowed 1..=127)")]
pub struct NodeIdError(pub u32);

impl NodeId {
    /// The node id, checked to lie in 1..=127.
    pub fn new(id: u32) -> Result<Self, NodeIdError> {
        if (1..=127).contains(&id) {
            Ok(Self(id as u8))
        } else {
            Err(NodeIdError(id))
        }
    }

    /// The id as a number.
    pub fn get(self) -> u8 {
        self.0
    }

    /// The COB-ID `function + id` (11 bit).
    pub fn cob(self, function: u16) -> u16 {
        function + u16::from(self.0)
    }
}

impl std::fmt::Display for NodeId {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}", self.0)
    }
}

/// The standard 11-bit identifier of a frame, or `None` for an extended one.
pub(crate) fn std_id(frame: &crate::CanFrame) -> Option<u16> {
    match frame.id() {
        crate::CanId::Standard(id) => Some(id),
        crate::CanId::Extended(_) => None,
    }
}

/// A data frame on a standard identifier known to be valid (≤ 0x7FF, ≤ 8 bytes).
pub(crate) fn frame(id: u16, data: &[u8]) -> crate::CanFrame {
    debug_assert!(id <= crate::MAX_STANDARD_ID && data.len() <= 8);
    crate::CanFrame::standard(id & crate::MAX_STANDARD_ID, &data[..data.len().min(8)])
        .unwrap_or_else(|_| unreachable!("id and length are masked"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn node_ids_are_checked() {
        assert!(NodeId::new(0).is_err());
        assert!(NodeId::new(128).is_err());
        let id = NodeId::new(5).unwrap();
        assert_eq!(id.cob(cob::SDO_RX), 0x605);
        assert_eq!(id.cob(cob::HEARTBEAT), 0x705);
        assert_eq!(
            NodeId::new(200).unwrap_err().to_string(),
            "CANopen node id 200 is out of range (allowed 1..=127)"
        );
    }
}
