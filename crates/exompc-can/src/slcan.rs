//! slcan: the Lawicel ASCII protocol that CANable, USBtin and CAN232-style adapters speak over
//! a serial port. Commands and frames are ASCII lines ended by `\r`; the adapter answers a
//! command with `\r` (or a short reply such as `z\r`) and an error with BEL (0x07).
//!
//! | Line | Meaning |
//! |------|---------|
//! | `S0`…`S8` | bit rate 10k, 20k, 50k, 100k, 125k, 250k, 500k, 800k, 1M (channel closed) |
//! | `O` / `C` | open / close the channel |
//! | `tiiildd…` | standard data frame: 3 hex id, 1 digit length, 2 hex per byte |
//! | `Tiiiiiiiildd…` | extended data frame: 8 hex id |
//! | `riiil` / `Riiiiiiiil` | remote request, standard / extended |
//! | `F` | status flags, answered `Fxx` (bit 5 error-passive, bit 7 bus error) |
//! | `V` / `N` | version / serial number |
//!
//! [`encode`] and [`decode`] convert frames; [`SlcanBus`] is the host side over a serial port
//! or any file descriptor; [`SlcanAdapter`](crate::slcan_adapter::SlcanAdapter) is the adapter
//! side, putting a [`CanBus`] (e.g. the virtual bus) behind a pseudo-terminal.

use crate::bus::{BusCounters, BusError, BusState, CanBus};
use crate::frame::{CanFrame, CanId};
use std::collections::VecDeque;
use std::time::{Duration, Instant};
use thiserror::Error;

/// BEL: the adapter's answer to a command it refused.
pub const BEL: u8 = 0x07;

/// The bit rates of `S0`…`S8` (bit/s).
pub const BITRATES: [u32; 9] = [
    10_000, 20_000, 50_000, 100_000, 125_000, 250_000, 500_000, 800_000, 1_000_000,
];

/// The `Sn` code of a bit rate; `None` if slcan has none for it.
pub fn bitrate_code(bitrate: u32) -> Option<u8> {
    BITRATES.iter().position(|&b| b == bitrate).map(|i| i as u8)
}

/// Status flag of `F`: the controller is error-passive.
pub const STATUS_ERROR_PASSIVE: u8 = 1 << 5;
/// Status flag of `F`: bus error (exompc reads it as bus-off).
pub const STATUS_BUS_ERROR: u8 = 1 << 7;

/// Why an slcan line could not be read as a frame.
#[derive(Clone, Debug, PartialEq, Eq, Error)]
pub enum SlcanError {
    /// Not a frame line (it does not start with `t`, `T`, `r` or `R`).
    #[error("not an slcan frame line: {0:?}")]
    NotAFrame(String),
    /// A frame line with the wrong length or a non-hex digit.
    #[error("malformed slcan frame line: {0:?}")]
    Malformed(String),
}

/// The slcan line of a frame, `\r` included.
pub fn encode(frame: &CanFrame) -> String {
    use std::fmt::Write;
    let mut s = String::with_capacity(27);
    let (kind, width) = match (frame.id().is_extended(), frame.is_remote()) {
        (false, false) => ('t', 3),
        (true, false) => ('T', 8),
        (false, true) => ('r', 3),
        (true, true) => ('R', 8),
    };
    s.push(kind);
    let _ = write!(
        s,
        "{:0width$X}{}",
        frame.id().raw(),
        frame.len(),
        width = width
    );
    for b in frame.data() {
        let _ = write!(s, "{b:02X}");
    }
    s.push('\r');
    s
}

fn hex(s: &[u8]) -> Option<u32> {
    let mut v = 0u32;
    for &c in s {
        v = (v << 4) | (c as char).to_digit(16)?;
    }
    Some(v)
}

/// A frame from one slcan line (without its `\r`). A 4-digit timestamp after the data (mode
/// `Z1`) is accepted and ignored.
pub fn decode(line: &[u8]) -> Result<CanFrame, SlcanError> {
    let text = || String::from_utf8_lossy(line).into_owned();
    let bad = || SlcanError::Malformed(text());
    let (ext, remote) = match line.first() {
        Some(b't') => (false, false),
        Some(b'T') => (true, false),
        Some(b'r') => (false, true),
        Some(b'R') => (true, true),
        _ => return Err(SlcanError::NotAFrame(text())),
    };
    let width = if ext { 8 } else { 3 };
    if line.len() < 2 + width {
        return Err(bad());
    }
    let id = hex(&line[1..1 + width]).ok_or_else(bad)?;
    let len = hex(&line[1 + width..2 + width]).ok_or_else(bad)? as usize;
    if len > 8 {
        return Err(bad());
    }
    let body = &line[2 + width..];
    let data_chars = if remote { 0 } else { 2 * len };
    if body.len() != data_chars && body.len() != data_chars + 4 {
        return Err(bad());
    }
    if body.len() == data_chars + 4 {
        hex(&body[data_chars..]).ok_or_else(bad)?;
    }
    let cid = if ext {
        CanId::Extended(id)
    } else {
        CanId::Standard(id as u16)
    };
    if remote {
        return CanFrame::remote(cid, len).map_err(|_| bad());
    }
    let mut data = [0u8; 8];
    for (i, d) in data.iter_mut().take(len).enumerate() {
        *d = hex(&body[2 * i..2 * i + 2]).ok_or_else(bad)? as u8;
    }
    CanFrame::new(cid, &data[..len]).map_err(|_| bad())
}

/// Splits a byte stream into slcan lines (ended by `\r`) and BELs; a `\n` after `\r` is
/// ignored. Lines longer than any slcan line are discarded.
#[derive(Debug, Default)]
pub struct LineReader {
    buf: Vec<u8>,
    overlong: bool,
}

/// One item of an slcan byte stream.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Token {
    /// A line without its `\r` (may be empty: a plain acknowledgement).
    Line(Vec<u8>),
    /// BEL: an error answer.
    Bel,
    /// A line longer than any slcan line (discarded).
    Overlong,
}

/// Longest slcan line: `T` + 8 + 1 + 16 + 4 (timestamp).
const MAX_LINE: usize = 30;

impl LineReader {
    /// Feed bytes; the complete tokens go to `out`.
    pub fn feed(&mut self, bytes: &[u8], out: &mut impl FnMut(Token)) {
        for &b in bytes {
            match b {
                b'\r' => {
                    if self.overlong {
                        out(Token::Overlong);
                    } else {
                        out(Token::Line(std::mem::take(&mut self.buf)));
                    }
                    self.buf.clear();
                    self.overlong = false;
                }
                b'\n' => {}
                BEL => out(Token::Bel),
                _ => {
                    if self.buf.len() < MAX_LINE {
                        self.buf.push(b);
                    } else {
                        self.overlong = true;
                    }
                }
            }
        }
    }
}

/// The host side of slcan over a serial port or file descriptor (a [`CanBus`]).
///
/// Opening sends `C` (in case the channel was left open), `S<n>` for the bit rate and `O`; a
/// refused command (BEL) fails the open. Received frame lines are queued; `z`/`Z`/empty
/// acknowledgements are skipped; BEL after a send counts as a send error; anything else that
/// is not a frame counts as a receive error. [`SlcanBus::poll_status`] asks `F` for the error
/// state.
pub struct SlcanBus<P: Port> {
    port: P,
    reader: LineReader,
    frames: VecDeque<CanFrame>,
    counters: BusCounters,
    state: BusState,
    bels: u64,
    status: Option<u8>,
}

/// A byte stream with timeouts: what [`SlcanBus`] runs over (a serial port, a pty).
pub trait Port {
    /// Read what is available, waiting at most `timeout` for the first byte; 0 bytes on timeout.
    fn read_timeout(&mut self, buf: &mut [u8], timeout: Duration) -> std::io::Result<usize>;
    /// Write all of `bytes`, waiting at most `timeout`.
    fn write_all_timeout(&mut self, bytes: &[u8], timeout: Duration) -> std::io::Result<()>;
}

/// How long a command's answer may take.
const ANSWER_TIMEOUT: Duration = Duration::from_millis(500);
/// How long a send may wait for room in the port's buffer.
const WRITE_TIMEOUT: Duration = Duration::from_millis(100);

impl<P: Port> SlcanBus<P> {
    /// Open the channel at `bitrate` (one of [`BITRATES`]) over `port`.
    pub fn open(port: P, bitrate: u32) -> Result<Self, BusError> {
        let code = bitrate_code(bitrate).ok_or_else(|| {
            BusError::Io(std::io::Error::new(
                std::io::ErrorKind::InvalidInput,
                format!("slcan has no bit rate {bitrate} (allowed: {BITRATES:?})"),
            ))
        })?;
        let mut bus = SlcanBus {
            port,
            reader: LineReader::default(),
            frames: VecDeque::new(),
            counters: BusCounters::default(),
            state: BusState::ErrorActive,
            bels: 0,
            status: None,
        };
        // A channel left open refuses `C` with BEL only if it was closed: ignore that answer.
        bus.command(b"C\r")?;
        for cmd in [format!("S{code}\r"), "O\r".to_string()] {
            if !bus.command(cmd.as_bytes())? {
                return Err(BusError::Io(std::io::Error::other(format!(
                    "the slcan adapter refused {:?}",
                    cmd.trim_end()
                ))));
            }
        }
        Ok(bus)
    }

    /// Send a command and wait for its answer: `true` for an acknowledgement, `false` for BEL.
    fn command(&mut self, cmd: &[u8]) -> Result<bool, BusError> {
        self.port.write_all_timeout(cmd, WRITE_TIMEOUT)?;
        let bels = self.bels;
        let end = Instant::now() + ANSWER_TIMEOUT;
        let mut ack = false;
        loop {
            let left = end.saturating_duration_since(Instant::now());
            if left.is_zero() {
                return Err(BusError::Io(std::io::Error::new(
                    std::io::ErrorKind::TimedOut,
                    format!(
                        "no answer from the slcan adapter to {:?}",
                        String::from_utf8_lossy(cmd).trim_end()
                    ),
                )));
            }
            self.pump(left, &mut ack, true)?;
            if self.bels > bels {
                return Ok(false);
            }
            if ack {
                return Ok(true);
            }
        }
    }

    /// Read once (waiting at most `timeout`) and handle what arrived; sets `ack` on an
    /// acknowledgement line. A BEL outside a command is a refused send.
    fn pump(
        &mut self,
        timeout: Duration,
        ack: &mut bool,
        in_command: bool,
    ) -> Result<(), BusError> {
        let mut buf = [0u8; 512];
        let n = self.port.read_timeout(&mut buf, timeout)?;
        let mut tokens = Vec::new();
        self.reader.feed(&buf[..n], &mut |t| tokens.push(t));
        for t in tokens {
            match t {
                Token::Bel => {
                    self.bels += 1;
                    if !in_command {
                        self.counters.send_errors += 1;
                    }
                }
                Token::Overlong => self.counters.receive_errors += 1,
                Token::Line(l) => match l.first() {
                    None | Some(b'z') | Some(b'Z') if l.len() <= 1 => *ack = true,
                    Some(b'F') if l.len() == 3 => match hex(&l[1..]) {
                        Some(v) => {
                            let v = v as u8;
                            self.status = Some(v);
                            self.state = if v & STATUS_BUS_ERROR != 0 {
                                BusState::BusOff
                            } else if v & STATUS_ERROR_PASSIVE != 0 {
                                BusState::ErrorPassive
                            } else {
                                BusState::ErrorActive
                            };
                            *ack = true;
                        }
                        None => self.counters.receive_errors += 1,
                    },
                    Some(b'V') | Some(b'N') => *ack = true,
                    _ => match decode(&l) {
                        Ok(f) => {
                            self.frames.push_back(f);
                            self.counters.received += 1;
                        }
                        Err(_) => self.counters.receive_errors += 1,
                    },
                },
            }
        }
        Ok(())
    }

    /// Ask the adapter for its status flags (`F`) and update [`CanBus::state`]; `None` if the
    /// adapter does not support `F` (it answers BEL).
    pub fn poll_status(&mut self) -> Result<Option<u8>, BusError> {
        self.status = None;
        if self.command(b"F\r")? {
            Ok(self.status)
        } else {
            Ok(None)
        }
    }

    /// Close the channel (`C`) and give the port back.
    pub fn close(mut self) -> Result<P, BusError> {
        self.command(b"C\r")?;
        Ok(self.port)
    }
}

impl<P: Port> CanBus for SlcanBus<P> {
    fn send(&mut self, frame: &CanFrame) -> Result<(), BusError> {
        if self.state == BusState::BusOff {
            self.counters.send_errors += 1;
            return Err(BusError::BusOff);
        }
        match self
            .port
            .write_all_timeout(encode(frame).as_bytes(), WRITE_TIMEOUT)
        {
            Ok(()) => {
                self.counters.sent += 1;
                Ok(())
            }
            Err(e) => {
                self.counters.send_errors += 1;
                Err(if e.kind() == std::io::ErrorKind::TimedOut {
                    BusError::SendTimeout
                } else {
                    BusError::Io(e)
                })
            }
        }
    }

    fn recv(&mut self, timeout: Duration) -> Result<Option<CanFrame>, BusError> {
        let end = Instant::now() + timeout;
        loop {
            if let Some(f) = self.frames.pop_front() {
                return Ok(Some(f));
            }
            let left = end.saturating_duration_since(Instant::now());
            let mut ack = false;
            self.pump(left, &mut ack, false)?;
            if self.frames.is_empty() && Instant::now() >= end {
                return Ok(None);
            }
        }
    }

    fn counters(&self) -> BusCounters {
        self.counters
    }

    fn state(&self) -> BusState {
        self.state
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frames_round_trip_through_lines() {
        let cases = [
            CanFrame::standard(0x7FF, &[0xDE, 0xAD, 0xBE, 0xEF]).unwrap(),
            CanFrame::standard(0, &[]).unwrap(),
            CanFrame::new(CanId::Extended(0x1FFF_FFFF), &[1, 2, 3, 4, 5, 6, 7, 8]).unwrap(),
            CanFrame::remote(CanId::Standard(0x123), 8).unwrap(),
            CanFrame::remote(CanId::Extended(0x12345), 0).unwrap(),
        ];
        let lines = [
            "t7FF4DEADBEEF\r",
            "t0000\r",
            "T1FFFFFFF80102030405060708\r",
            "r1238\r",
            "R000123450\r",
        ];
        for (f, l) in cases.iter().zip(lines) {
            assert_eq!(encode(f), l);
            assert_eq!(decode(l.trim_end().as_bytes()).unwrap(), *f);
        }
        // Timestamp (Z1) accepted; lower-case hex accepted.
        assert_eq!(
            decode(b"t1232abcd1234").unwrap(),
            CanFrame::standard(0x123, &[0xAB, 0xCD]).unwrap()
        );
    }

    #[test]
    fn malformed_lines_are_errors() {
        for l in [
            &b"t12"[..],
            b"t1239",
            b"t1232AB",
            b"t1232ABCDE",
            b"t8001AA",
            b"T200000000",
            b"tXYZ0",
            b"t1231GG",
        ] {
            assert!(matches!(decode(l), Err(SlcanError::Malformed(_))), "{l:?}");
        }
        assert!(matches!(decode(b"O"), Err(SlcanError::NotAFrame(_))));
        assert!(matches!(decode(b""), Err(SlcanError::NotAFrame(_))));
    }

    #[test]
    fn line_reader_splits_lines_and_bels() {
        let mut r = LineReader::default();
        let mut out = Vec::new();
        r.feed(b"t1230\r\x07z\r\n", &mut |t| out.push(t));
        r.feed(&[b'x'; 40], &mut |t| out.push(t));
        r.feed(b"\rt12", &mut |t| out.push(t));
        r.feed(b"30\r", &mut |t| out.push(t));
        assert_eq!(
            out,
            vec![
                Token::Line(b"t1230".to_vec()),
                Token::Bel,
                Token::Line(b"z".to_vec()),
                Token::Overlong,
                Token::Line(b"t1230".to_vec()),
            ]
        );
    }
}
