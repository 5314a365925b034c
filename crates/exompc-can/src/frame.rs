//! Classic CAN 2.0 frames: an 11-bit (standard) or 29-bit (extended) identifier, up to 8 data
//! bytes, or a remote request.

use thiserror::Error;

/// Largest 11-bit identifier.
pub const MAX_STANDARD_ID: u16 = 0x7FF;
/// Largest 29-bit identifier.
pub const MAX_EXTENDED_ID: u32 = 0x1FFF_FFFF;

/// A CAN identifier: standard (11 bit) or extended (29 bit).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum CanId {
    /// 11-bit identifier, 0..=0x7FF.
    Standard(u16),
    /// 29-bit identifier, 0..=0x1FFF_FFFF.
    Extended(u32),
}

impl CanId {
    /// The identifier as a number.
    pub fn raw(self) -> u32 {
        match self {
            CanId::Standard(id) => u32::from(id),
            CanId::Extended(id) => id,
        }
    }

    /// `true` for a 29-bit identifier.
    pub fn is_extended(self) -> bool {
        matches!(self, CanId::Extended(_))
    }
}

/// Why a frame could not be built.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Error)]
pub enum FrameError {
    /// The identifier does not fit its format.
    #[error(
        "CAN identifier {id:#x} is out of range (standard 0..=0x7FF, extended 0..=0x1FFFFFFF)"
    )]
    IdOutOfRange {
        /// The identifier given.
        id: u32,
    },
    /// More than 8 data bytes.
    #[error("a classic CAN frame carries at most 8 data bytes, not {len}")]
    TooLong {
        /// The length given.
        len: usize,
    },
}

/// A classic CAN frame: identifier, 0-8 data bytes (or a remote request of that length).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct CanFrame {
    id: CanId,
    len: u8,
    data: [u8; 8],
    rtr: bool,
}

impl CanFrame {
    /// A data frame; the identifier and length are checked.
    pub fn new(id: CanId, data: &[u8]) -> Result<Self, FrameError> {
        check_id(id)?;
        if data.len() > 8 {
            return Err(FrameError::TooLong { len: data.len() });
        }
        let mut buf = [0u8; 8];
        buf[..data.len()].copy_from_slice(data);
        Ok(Self {
            id,
            len: data.len() as u8,
            data: buf,
            rtr: false,
        })
    }

    /// A data frame with a standard identifier.
    pub fn standard(id: u16, data: &[u8]) -> Result<Self, FrameError> {
        Self::new(CanId::Standard(id), data)
    }

    /// An 8-byte data frame with a standard identifier below 256 (cannot fail).
    pub fn with_id8(id: u8, data: &[u8; 8]) -> Self {
        Self {
            id: CanId::Standard(u16::from(id)),
            len: 8,
            data: *data,
            rtr: false,
        }
    }

    /// A remote request for `len` bytes (0..=8).
    pub fn remote(id: CanId, len: usize) -> Result<Self, FrameError> {
        check_id(id)?;
        if len > 8 {
            return Err(FrameError::TooLong { len });
        }
        Ok(Self {
            id,
            len: len as u8,
            data: [0; 8],
            rtr: true,
        })
    }

    /// The identifier.
    pub fn id(&self) -> CanId {
        self.id
    }

    /// The data bytes (empty for a remote request).
    pub fn data(&self) -> &[u8] {
        if self.rtr {
            &[]
        } else {
            &self.data[..usize::from(self.len)]
        }
    }

    /// The data length code (0..=8).
    pub fn len(&self) -> usize {
        usize::from(self.len)
    }

    /// `true` when the frame carries no data bytes.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// `true` for a remote request.
    pub fn is_remote(&self) -> bool {
        self.rtr
    }
}

fn check_id(id: CanId) -> Result<(), FrameError> {
    let ok = match id {
        CanId::Standard(v) => v <= MAX_STANDARD_ID,
        CanId::Extended(v) => v <= MAX_EXTENDED_ID,
    };
    if ok {
        Ok(())
    } else {
        Err(FrameError::IdOutOfRange { id: id.raw() })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frames_are_checked() {
        let f = CanFrame::standard(0x123, &[1, 2, 3]).unwrap();
        assert_eq!(f.data(), &[1, 2, 3]);
        assert_eq!(f.len(), 3);
        assert!(!f.is_remote());
        assert_eq!(
            CanFrame::standard(0x800, &[]),
            Err(FrameError::IdOutOfRange { id: 0x800 })
        );
        assert_eq!(
            CanFrame::new(CanId::Extended(0x2000_0000), &[]),
            Err(FrameError::IdOutOfRange { id: 0x2000_0000 })
        );
        assert_eq!(
            CanFrame::standard(1, &[0; 9]),
            Err(FrameError::TooLong { len: 9 })
        );
        let r = CanFrame::remote(CanId::Extended(0x1FFF_FFFF), 8).unwrap();
        assert!(r.is_remote() && r.data().is_empty() && r.len() == 8);
    }
}
