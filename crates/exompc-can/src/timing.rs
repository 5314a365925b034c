//! Bit timing of classic CAN frames: how long a frame occupies the bus at a bit rate.

use crate::frame::CanFrame;
use std::time::Duration;

/// How stuff bits are counted in a frame's length.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Stuffing {
    /// No stuff bits: the shortest the frame can be.
    Nominal,
    /// The most stuff bits the frame can need (one per four bits of the stuffed region after
    /// the first: SOF through the CRC): the longest the frame can be. The virtual bus uses this
    /// by default, so its timing and the bus loads derived from it are conservative.
    #[default]
    WorstCase,
}

/// Bits a frame occupies on the bus, including the 3-bit intermission that follows it.
///
/// Nominal lengths (ISO 11898-1): a standard-ID data frame has 44 + 8·n bits (SOF 1,
/// identifier 11, RTR 1, IDE 1, r0 1, DLC 4, data 8·n, CRC 15, CRC delimiter 1, ACK 2, EOF 7),
/// an extended-ID data frame 64 + 8·n; a remote frame carries no data bits. Of these, the
/// region from SOF to the end of the CRC (34 + 8·n, resp. 54 + 8·n bits) is stuffed: at worst
/// one stuff bit after the first five equal bits and then after every four more,
/// ⌊(region − 1) / 4⌋.
pub fn frame_bits(frame: &CanFrame, stuffing: Stuffing) -> u32 {
    let data_bits = 8 * frame.data().len() as u32;
    let (nominal, stuffed_region) = if frame.id().is_extended() {
        (64 + data_bits, 54 + data_bits)
    } else {
        (44 + data_bits, 34 + data_bits)
    };
    let stuff = match stuffing {
        Stuffing::Nominal => 0,
        Stuffing::WorstCase => (stuffed_region - 1) / 4,
    };
    nominal + stuff + 3
}

/// Time a frame occupies the bus at `bitrate` bit/s (intermission included).
pub fn frame_time(frame: &CanFrame, bitrate: u32, stuffing: Stuffing) -> Duration {
    let bits = u64::from(frame_bits(frame, stuffing));
    Duration::from_nanos(bits * 1_000_000_000 / u64::from(bitrate.max(1)))
}

/// Bits of an error frame and what follows it (error flag 6–12 bits, delimiter 8,
/// intermission 3): the most, 23.
pub const ERROR_FRAME_BITS: u32 = 23;

#[cfg(test)]
mod tests {
    use super::*;
    use crate::frame::CanId;

    #[test]
    fn frame_lengths() {
        let f8 = CanFrame::standard(0x1, &[0; 8]).unwrap();
        // 44 + 64 = 108 nominal, + 3 intermission.
        assert_eq!(frame_bits(&f8, Stuffing::Nominal), 111);
        // stuffed region 98 bits → 24 stuff bits at worst.
        assert_eq!(frame_bits(&f8, Stuffing::WorstCase), 135);
        let f0 = CanFrame::standard(0x1, &[]).unwrap();
        assert_eq!(frame_bits(&f0, Stuffing::Nominal), 47);
        assert_eq!(frame_bits(&f0, Stuffing::WorstCase), 47 + 8);
        let e8 = CanFrame::new(CanId::Extended(1), &[0; 8]).unwrap();
        assert_eq!(frame_bits(&e8, Stuffing::Nominal), 131);
        assert_eq!(frame_bits(&e8, Stuffing::WorstCase), 131 + 29);
        assert_eq!(
            frame_time(&f8, 1_000_000, Stuffing::WorstCase),
            Duration::from_micros(135)
        );
    }
}
