//! The adapter side of slcan: a [`CanBus`] (the virtual bus, or any other) behind a byte stream,
//! answering the host's commands as a CANable/CAN232 adapter does, so that a host (exompc's
//! [`SlcanBus`](crate::slcan::SlcanBus), python-can's `slcan` interface) can reach virtual
//! devices through a pseudo-terminal.

use crate::bus::{BusState, CanBus};
use crate::slcan::{
    decode, encode, LineReader, Port, Token, BEL, BITRATES, STATUS_BUS_ERROR, STATUS_ERROR_PASSIVE,
};
use std::time::Duration;

/// Counters of an [`SlcanAdapter`].
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct AdapterCounters {
    /// Command and frame lines read from the host.
    pub lines: u64,
    /// Lines refused with BEL (unknown command, wrong state, malformed frame).
    pub refused: u64,
    /// Frames the host sent onto the bus.
    pub to_bus: u64,
    /// Frames from the bus written to the host.
    pub to_host: u64,
    /// Frames from the bus dropped (channel closed, or the host not reading).
    pub dropped: u64,
}

/// An slcan adapter over a bus `B`, talking to the host through port `P`.
///
/// The channel starts closed at the bus's bit rate; `S<n>` changes the rate only while closed,
/// and `O` at a rate other than the bus's is refused (a real node at the wrong rate would see
/// only error frames). Frames are accepted only while open, answered `z` (standard) or `Z`
/// (extended); `F` answers the error state of the bus endpoint.
pub struct SlcanAdapter<B: CanBus, P: Port> {
    bus: B,
    port: P,
    reader: LineReader,
    bus_bitrate: u32,
    bitrate: u32,
    open: bool,
    counters: AdapterCounters,
    out: Vec<u8>,
}

/// How long a write to the host may wait before the data is dropped.
const HOST_WRITE_TIMEOUT: Duration = Duration::from_millis(20);

impl<B: CanBus, P: Port> SlcanAdapter<B, P> {
    /// An adapter for `bus` (running at `bus_bitrate` bit/s) behind `port`.
    pub fn new(bus: B, port: P, bus_bitrate: u32) -> Self {
        SlcanAdapter {
            bus,
            port,
            reader: LineReader::default(),
            bus_bitrate,
            bitrate: bus_bitrate,
            open: false,
            counters: AdapterCounters::default(),
            out: Vec::with_capacity(256),
        }
    }

    /// The counters so far.
    pub fn counters(&self) -> AdapterCounters {
        self.counters
    }

    /// `true` while the host has the channel open.
    pub fn is_open(&self) -> bool {
        self.open
    }

    /// The bus.
    pub fn bus_mut(&mut self) -> &mut B {
        &mut self.bus
    }

    /// Serve once: handle what the host sent (waiting at most `timeout` for it), then forward
    /// the frames received from the bus meanwhile.
    pub fn serve(&mut self, timeout: Duration) -> std::io::Result<()> {
        let mut buf = [0u8; 1024];
        let n = self.port.read_timeout(&mut buf, timeout)?;
        let mut tokens = Vec::new();
        self.reader.feed(&buf[..n], &mut |t| tokens.push(t));
        for t in tokens {
            match t {
                Token::Line(l) => self.line(&l),
                Token::Overlong => self.refuse(),
                Token::Bel => {}
            }
        }
        while let Ok(Some(f)) = self.bus.recv(Duration::ZERO) {
            if self.open {
                self.out.extend_from_slice(encode(&f).as_bytes());
                self.counters.to_host += 1;
            } else {
                self.counters.dropped += 1;
            }
        }
        self.flush()
    }

    fn flush(&mut self) -> std::io::Result<()> {
        if self.out.is_empty() {
            return Ok(());
        }
        let r = self.port.write_all_timeout(&self.out, HOST_WRITE_TIMEOUT);
        self.out.clear();
        match r {
            Err(e) if e.kind() == std::io::ErrorKind::TimedOut => {
                self.counters.dropped += 1;
                Ok(())
            }
            r => r,
        }
    }

    fn refuse(&mut self) {
        self.counters.refused += 1;
        self.out.push(BEL);
    }

    fn ack(&mut self, reply: &[u8]) {
        self.out.extend_from_slice(reply);
        self.out.push(b'\r');
    }

    fn line(&mut self, l: &[u8]) {
        self.counters.lines += 1;
        match l.first().copied() {
            None => self.ack(b""),
            Some(b'S') if l.len() == 2 => {
                let code = l[1].wrapping_sub(b'0') as usize;
                match BITRATES.get(code) {
                    Some(&b) if !self.open => {
                        self.bitrate = b;
                        self.ack(b"");
                    }
                    _ => self.refuse(),
                }
            }
            Some(b'O') if l.len() == 1 => {
                if self.open || self.bitrate != self.bus_bitrate {
                    self.refuse();
                } else {
                    self.open = true;
                    // Frames that arrived while closed are not delivered.
                    while let Ok(Some(_)) = self.bus.recv(Duration::ZERO) {
                        self.counters.dropped += 1;
                    }
                    self.ack(b"");
                }
            }
            Some(b'C') if l.len() == 1 => {
                if self.open {
                    self.open = false;
                    self.ack(b"");
                } else {
                    self.refuse();
                }
            }
            Some(b'F') if l.len() == 1 => {
                let flags = match self.bus.state() {
                    BusState::ErrorActive => 0,
                    BusState::ErrorPassive => STATUS_ERROR_PASSIVE,
                    BusState::BusOff => STATUS_BUS_ERROR,
                };
                self.ack(format!("F{flags:02X}").as_bytes());
            }
            Some(b'V') if l.len() == 1 => self.ack(b"V1013"),
            Some(b'N') if l.len() == 1 => self.ack(b"NEXO1"),
            Some(b'Z') if l.len() == 2 && matches!(l[1], b'0' | b'1') => self.ack(b""),
            Some(b't' | b'T' | b'r' | b'R') => match decode(l) {
                Ok(f) if self.open => match self.bus.send(&f) {
                    Ok(()) => {
                        self.counters.to_bus += 1;
                        self.ack(if f.id().is_extended() { b"Z" } else { b"z" });
                    }
                    Err(_) => self.refuse(),
                },
                _ => self.refuse(),
            },
            _ => self.refuse(),
        }
    }
}
