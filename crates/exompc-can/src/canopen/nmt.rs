//! NMT (network management, CiA 301 §7.2.8.3.1): the master's node-control commands on COB-ID
//! 0x000 and the NMT states a node reports in its heartbeat.

use super::{cob, frame, std_id, NodeId};
use crate::CanFrame;

/// An NMT node-control command (byte 0 of the 0x000 frame).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum NmtCommand {
    /// Start remote node → operational.
    Start,
    /// Stop remote node → stopped.
    Stop,
    /// Enter pre-operational.
    EnterPreOperational,
    /// Reset node (application and communication).
    ResetNode,
    /// Reset communication.
    ResetCommunication,
}

impl NmtCommand {
    /// The command specifier.
    pub fn code(self) -> u8 {
        match self {
            NmtCommand::Start => 0x01,
            NmtCommand::Stop => 0x02,
            NmtCommand::EnterPreOperational => 0x80,
            NmtCommand::ResetNode => 0x81,
            NmtCommand::ResetCommunication => 0x82,
        }
    }

    /// The command of a specifier, if it is one.
    pub fn from_code(code: u8) -> Option<Self> {
        Some(match code {
            0x01 => NmtCommand::Start,
            0x02 => NmtCommand::Stop,
            0x80 => NmtCommand::EnterPreOperational,
            0x81 => NmtCommand::ResetNode,
            0x82 => NmtCommand::ResetCommunication,
            _ => return None,
        })
    }

    /// The frame commanding `node` (`None`: all nodes).
    pub fn frame(self, node: Option<NodeId>) -> CanFrame {
        frame(cob::NMT, &[self.code(), node.map_or(0, NodeId::get)])
    }

    /// Decode an NMT frame: the command and its target (`None`: all nodes). `None` for a frame
    /// that is not a valid NMT command.
    pub fn decode(f: &CanFrame) -> Option<(NmtCommand, Option<u8>)> {
        if std_id(f) != Some(cob::NMT) || f.is_remote() || f.len() != 2 {
            return None;
        }
        let cmd = Self::from_code(f.data()[0])?;
        let target = f.data()[1];
        Some((cmd, (target != 0).then_some(target)))
    }

    /// `true` when a command decoded by [`NmtCommand::decode`] addresses `node`.
    pub fn addresses(target: Option<u8>, node: NodeId) -> bool {
        target.is_none_or(|t| t == node.get())
    }
}

/// The NMT state of a node, as its heartbeat reports it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum NmtState {
    /// Boot-up (sent once, after initialisation).
    BootUp,
    /// Stopped: only NMT and heartbeat.
    Stopped,
    /// Operational: PDOs run.
    Operational,
    /// Pre-operational: SDO, no PDOs.
    PreOperational,
}

impl NmtState {
    /// The heartbeat byte.
    pub fn code(self) -> u8 {
        match self {
            NmtState::BootUp => 0x00,
            NmtState::Stopped => 0x04,
            NmtState::Operational => 0x05,
            NmtState::PreOperational => 0x7F,
        }
    }

    /// The state of a heartbeat byte (the toggle bit 7 of node guarding is ignored).
    pub fn from_code(code: u8) -> Option<Self> {
        Some(match code & 0x7F {
            0x00 => NmtState::BootUp,
            0x04 => NmtState::Stopped,
            0x05 => NmtState::Operational,
            0x7F => NmtState::PreOperational,
            _ => return None,
        })
    }

    /// The state a node enters on `cmd` (reset commands pass through boot-up to
    /// pre-operational).
    pub fn after(self, cmd: NmtCommand) -> NmtState {
        match cmd {
            NmtCommand::Start => NmtState::Operational,
            NmtCommand::Stop => NmtState::Stopped,
            NmtCommand::EnterPreOperational => NmtState::PreOperational,
            NmtCommand::ResetNode | NmtCommand::ResetCommunication => NmtState::PreOperational,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nmt_frames_follow_cia301() {
        let n = NodeId::new(3).unwrap();
        let f = NmtCommand::Start.frame(Some(n));
        assert_eq!(std_id(&f), Some(0));
        assert_eq!(f.data(), &[0x01, 0x03]);
        assert_eq!(NmtCommand::decode(&f), Some((NmtCommand::Start, Some(3))));
        let all = NmtCommand::ResetNode.frame(None);
        assert_eq!(all.data(), &[0x81, 0x00]);
        let (cmd, target) = NmtCommand::decode(&all).unwrap();
        assert!(NmtCommand::addresses(target, n));
        assert_eq!(NmtState::Operational.after(cmd), NmtState::PreOperational);
        assert!(!NmtCommand::addresses(Some(4), n));
        // Unknown specifiers, wrong lengths and other ids are not NMT commands.
        assert_eq!(NmtCommand::decode(&frame(0, &[0x03, 0])), None);
        assert_eq!(NmtCommand::decode(&frame(0, &[0x01])), None);
        assert_eq!(NmtCommand::decode(&frame(0x701, &[0x01, 0])), None);
        for s in [
            NmtState::BootUp,
            NmtState::Stopped,
            NmtState::Operational,
            NmtState::PreOperational,
        ] {
            assert_eq!(NmtState::from_code(s.code()), Some(s));
        }
        assert_eq!(NmtState::from_code(0x85), Some(NmtState::Operational));
        assert_eq!(NmtState::from_code(0x06), None);
    }
}
