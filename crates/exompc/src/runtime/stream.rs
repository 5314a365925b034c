//! Frames over a byte stream (a UART, a serial port, a pipe): the frame's own header delimits
//! it, so no extra framing layer is needed. A frame starts with the magic `EXMP` and its header
//! carries the payload length (bytes 20-21), so the receiver knows where it ends; bytes before
//! a magic are skipped (resynchronisation after noise or a lost byte). Whether a delimited
//! frame is valid is [`super::frame::decode`]'s decision (its MAC covers every byte); a frame
//! damaged on the line is rejected there, and the stream realigns on the next magic.
//!
//! Used by both ends of the serial link: the firmware on the MCU's UART and
//! `exompc virtual-robot --serial` on the host (docs/EMBEDDED.md, "The serial link").

use super::frame::{HEADER_LEN, MAC_LEN, MAGIC};
use alloc::vec::Vec;

/// Offset of the payload length (u16, little-endian) in the header.
const LEN_AT: usize = 20;

/// Splits a byte stream into frames (allocation-free after [`Deframer::new`]).
#[derive(Clone, Debug)]
pub struct Deframer {
    buf: Vec<u8>,
    max_len: usize,
    done: bool,
    skipped: u64,
}

impl Deframer {
    /// A deframer for frames of at most `max_len` bytes ([`super::frame::max_frame_len`] of
    /// the joint count); a header announcing a longer frame is skipped.
    pub fn new(max_len: usize) -> Self {
        let max_len = max_len.max(HEADER_LEN + MAC_LEN);
        Deframer {
            buf: Vec::with_capacity(max_len),
            max_len,
            done: false,
            skipped: 0,
        }
    }

    /// Bytes skipped so far (not part of a delimited frame).
    pub fn skipped(&self) -> u64 {
        self.skipped
    }

    /// Take one byte; the whole frame when this byte completes one (valid until the next
    /// call).
    pub fn push(&mut self, b: u8) -> Option<&[u8]> {
        if core::mem::take(&mut self.done) {
            self.buf.clear();
        }
        let at = self.buf.len();
        if at < MAGIC.len() {
            if MAGIC.get(at) == Some(&b) {
                self.buf.push(b);
            } else {
                // Not a frame start: drop what was held; this byte may start the next magic.
                let restart = b == MAGIC[0];
                self.skipped += at as u64 + u64::from(!restart);
                self.buf.clear();
                if restart {
                    self.buf.push(b);
                }
            }
            return None;
        }
        self.buf.push(b);
        let (Some(&lo), Some(&hi)) = (self.buf.get(LEN_AT), self.buf.get(LEN_AT + 1)) else {
            return None;
        };
        if self.buf.len() < HEADER_LEN {
            return None;
        }
        let total = HEADER_LEN + usize::from(u16::from_le_bytes([lo, hi])) + MAC_LEN;
        if total > self.max_len {
            self.skipped += self.buf.len() as u64;
            self.buf.clear();
            return None;
        }
        if self.buf.len() < total {
            return None;
        }
        self.done = true;
        Some(&self.buf)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::runtime::frame::{decode, encode_sample, max_frame_len, Frame, RobotSample};
    use crate::runtime::Key;
    use nalgebra::SVector;

    fn sample(seq: u32) -> RobotSample<2> {
        RobotSample {
            seq,
            stamp_ns: u64::from(seq) * 10_000_000,
            flags: 0,
            q: SVector::from([0.1 * f64::from(seq), -0.2]),
            qd: SVector::from([0.5, 0.25]),
            force: SVector::from([1.0, -2.0]),
            effort: SVector::from([3.0, 4.0]),
        }
    }

    /// Frames separated by noise (including a false magic start and a header announcing an
    /// oversize frame) come out whole, in order, and decode under the key; the noise is
    /// counted as skipped.
    #[test]
    fn delimits_frames_in_a_noisy_stream() {
        let key = Key::from_bytes([7; 32]);
        let mut stream = Vec::new();
        let mut want = Vec::new();
        for seq in 1..=3u32 {
            stream.extend_from_slice(b"noiseEXM");
            let mut f = Vec::new();
            encode_sample(&sample(seq), &key, &mut f);
            stream.extend_from_slice(&f);
            want.push(f);
        }
        // A header announcing a 60000-byte payload: skipped, then a good frame.
        let mut bogus = Vec::new();
        encode_sample(&sample(9), &key, &mut bogus);
        bogus[LEN_AT..LEN_AT + 2].copy_from_slice(&60000u16.to_le_bytes());
        stream.extend_from_slice(&bogus[..HEADER_LEN]);
        let mut last = Vec::new();
        encode_sample(&sample(4), &key, &mut last);
        stream.extend_from_slice(&last);
        want.push(last);

        let mut d = Deframer::new(max_frame_len(2));
        let mut got = Vec::new();
        for b in stream {
            if let Some(f) = d.push(b) {
                got.push(f.to_vec());
            }
        }
        assert_eq!(got, want);
        for (f, seq) in got.iter().zip([1, 2, 3, 4]) {
            assert_eq!(
                decode::<2>(f, &key, Some(&key)),
                Ok(Frame::Sample(sample(seq)))
            );
        }
        assert_eq!(d.skipped(), 3 * 8 + HEADER_LEN as u64);
    }
}
