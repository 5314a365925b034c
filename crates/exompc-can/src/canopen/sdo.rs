//! SDO (service data objects, CiA 301 §7.2.4): confirmed reads (upload) and writes (download)
//! of object-dictionary entries, expedited (≤ 4 bytes in one frame) or segmented (7 bytes per
//! frame with an alternating toggle bit), and the abort protocol. [`SdoClient`] is the master's
//! side, [`SdoServer`] the node's; both are sans-I/O (frames in, frames out) with time passed
//! in, and [`transfer`] runs a client transfer over a [`CanBus`].

use super::od::ObjectDictionary;
use super::{cob, frame, std_id, NodeId};
use crate::{BusError, CanBus, CanFrame};
use std::time::{Duration, Instant};
use thiserror::Error;

/// An SDO abort code (CiA 301 Table 22).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct AbortCode(pub u32);

impl AbortCode {
    /// Toggle bit not alternated.
    pub const TOGGLE: AbortCode = AbortCode(0x0503_0000);
    /// SDO protocol timed out.
    pub const TIMEOUT: AbortCode = AbortCode(0x0504_0000);
    /// Client/server command specifier not valid or unknown.
    pub const COMMAND: AbortCode = AbortCode(0x0504_0001);
    /// Unsupported access to an object.
    pub const UNSUPPORTED: AbortCode = AbortCode(0x0601_0000);
    /// Attempt to read a write-only object.
    pub const WRITE_ONLY: AbortCode = AbortCode(0x0601_0001);
    /// Attempt to write a read-only object.
    pub const READ_ONLY: AbortCode = AbortCode(0x0601_0002);
    /// Object does not exist in the object dictionary.
    pub const NO_OBJECT: AbortCode = AbortCode(0x0602_0000);
    /// Object cannot be mapped to the PDO.
    pub const NOT_MAPPABLE: AbortCode = AbortCode(0x0604_0041);
    /// The number and length of the objects to be mapped would exceed the PDO length.
    pub const PDO_LENGTH: AbortCode = AbortCode(0x0604_0042);
    /// Data type does not match, length of service parameter does not match.
    pub const LENGTH: AbortCode = AbortCode(0x0607_0010);
    /// Data type does not match, length of service parameter too high.
    pub const LENGTH_TOO_HIGH: AbortCode = AbortCode(0x0607_0012);
    /// Data type does not match, length of service parameter too low.
    pub const LENGTH_TOO_LOW: AbortCode = AbortCode(0x0607_0013);
    /// Sub-index does not exist.
    pub const NO_SUB_INDEX: AbortCode = AbortCode(0x0609_0011);
    /// Invalid value for parameter (download only).
    pub const VALUE_RANGE: AbortCode = AbortCode(0x0609_0030);
    /// Value of parameter written too high.
    pub const VALUE_TOO_HIGH: AbortCode = AbortCode(0x0609_0031);
    /// Value of parameter written too low.
    pub const VALUE_TOO_LOW: AbortCode = AbortCode(0x0609_0032);
    /// General error.
    pub const GENERAL: AbortCode = AbortCode(0x0800_0000);
    /// Data cannot be transferred or stored because of the present device state.
    pub const WRONG_STATE: AbortCode = AbortCode(0x0800_0022);

    /// What the code means.
    pub fn describe(self) -> &'static str {
        match self {
            AbortCode::TOGGLE => "toggle bit not alternated",
            AbortCode::TIMEOUT => "SDO protocol timed out",
            AbortCode::COMMAND => "command specifier not valid or unknown",
            AbortCode::UNSUPPORTED => "unsupported access to an object",
            AbortCode::WRITE_ONLY => "attempt to read a write-only object",
            AbortCode::READ_ONLY => "attempt to write a read-only object",
            AbortCode::NO_OBJECT => "object does not exist",
            AbortCode::NOT_MAPPABLE => "object cannot be mapped to the PDO",
            AbortCode::PDO_LENGTH => "mapped objects exceed the PDO length",
            AbortCode::LENGTH => "length of service parameter does not match",
            AbortCode::LENGTH_TOO_HIGH => "length of service parameter too high",
            AbortCode::LENGTH_TOO_LOW => "length of service parameter too low",
            AbortCode::NO_SUB_INDEX => "sub-index does not exist",
            AbortCode::VALUE_RANGE => "invalid value for parameter",
            AbortCode::VALUE_TOO_HIGH => "value of parameter written too high",
            AbortCode::VALUE_TOO_LOW => "value of parameter written too low",
            AbortCode::GENERAL => "general error",
            AbortCode::WRONG_STATE => "not possible in the present device state",
            _ => "unknown abort code",
        }
    }
}

impl std::fmt::Display for AbortCode {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{:#010x} ({})", self.0, self.describe())
    }
}

/// The abort frame for (index, sub) on COB-ID `id`.
pub fn abort_frame(id: u16, index: u16, sub: u8, code: AbortCode) -> CanFrame {
    let mut d = [0x80, 0, 0, sub, 0, 0, 0, 0];
    d[1..3].copy_from_slice(&index.to_le_bytes());
    d[4..8].copy_from_slice(&code.0.to_le_bytes());
    frame(id, &d)
}

fn mux(d: &[u8]) -> (u16, u8) {
    (u16::from_le_bytes([d[1], d[2]]), d[3])
}

fn with_mux(cs: u8, index: u16, sub: u8, payload: &[u8]) -> [u8; 8] {
    let mut d = [cs, 0, 0, sub, 0, 0, 0, 0];
    d[1..3].copy_from_slice(&index.to_le_bytes());
    d[4..4 + payload.len()].copy_from_slice(payload);
    d
}

/// Why an SDO transfer failed.
#[derive(Debug, Error)]
pub enum SdoError {
    /// The server (or we, after a protocol error) aborted the transfer.
    #[error("SDO {dir} of {index:#06x}:{sub:#04x} on node {node} aborted: {code}")]
    Aborted {
        /// The node.
        node: NodeId,
        /// "read" or "write".
        dir: &'static str,
        /// The object's index.
        index: u16,
        /// Its sub-index.
        sub: u8,
        /// The abort code.
        code: AbortCode,
    },
    /// No answer within the SDO timeout.
    #[error("SDO {dir} of {index:#06x}:{sub:#04x} on node {node}: no answer within {timeout:?}")]
    Timeout {
        /// The node.
        node: NodeId,
        /// "read" or "write".
        dir: &'static str,
        /// The object's index.
        index: u16,
        /// Its sub-index.
        sub: u8,
        /// The timeout.
        timeout: Duration,
    },
    /// A transfer is already running on this client.
    #[error("an SDO transfer is already running")]
    Busy,
    /// The bus failed.
    #[error(transparent)]
    Bus(#[from] BusError),
}

/// A finished client transfer.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum SdoDone {
    /// The write was confirmed.
    Downloaded,
    /// The value read.
    Uploaded(Vec<u8>),
}

/// What the client does with a received frame.
#[derive(Debug)]
pub enum ClientStep {
    /// Send this frame next.
    Send(CanFrame),
    /// The transfer finished.
    Done(SdoDone),
    /// The transfer failed; send the abort frame, if any.
    Failed(SdoError, Option<CanFrame>),
}

#[derive(Clone, Debug)]
enum ClientOp {
    Download {
        index: u16,
        sub: u8,
        data: Vec<u8>,
        pos: usize,
        toggle: bool,
        segmented: bool,
    },
    Upload {
        index: u16,
        sub: u8,
        buf: Vec<u8>,
        size: Option<usize>,
        toggle: bool,
    },
}

/// The master's side of SDO for one server node (default COB-IDs 0x600/0x580 + node id).
#[derive(Clone, Debug)]
pub struct SdoClient {
    node: NodeId,
    timeout: Duration,
    op: Option<ClientOp>,
    deadline: Duration,
}

impl SdoClient {
    /// A client for `node`, failing a transfer after `timeout` without an answer.
    pub fn new(node: NodeId, timeout: Duration) -> Self {
        Self {
            node,
            timeout,
            op: None,
            deadline: Duration::ZERO,
        }
    }

    /// The node served.
    pub fn node(&self) -> NodeId {
        self.node
    }

    fn tx(&self) -> u16 {
        self.node.cob(cob::SDO_RX)
    }

    /// Start writing `data` to (index, sub); returns the first frame to send. Up to 4 bytes go
    /// expedited, more segmented.
    pub fn download(
        &mut self,
        index: u16,
        sub: u8,
        data: &[u8],
        now: Duration,
    ) -> Result<CanFrame, SdoError> {
        if self.op.is_some() {
            return Err(SdoError::Busy);
        }
        let segmented = data.len() > 4 || data.is_empty();
        let f = if segmented {
            let size = (data.len() as u32).to_le_bytes();
            frame(self.tx(), &with_mux(0x21, index, sub, &size))
        } else {
            let n = (4 - data.len()) as u8;
            frame(self.tx(), &with_mux(0x23 | n << 2, index, sub, data))
        };
        self.op = Some(ClientOp::Download {
            index,
            sub,
            data: data.to_vec(),
            pos: 0,
            toggle: false,
            segmented,
        });
        self.deadline = now + self.timeout;
        Ok(f)
    }

    /// Start reading (index, sub); returns the frame to send.
    pub fn upload(&mut self, index: u16, sub: u8, now: Duration) -> Result<CanFrame, SdoError> {
        if self.op.is_some() {
            return Err(SdoError::Busy);
        }
        self.op = Some(ClientOp::Upload {
            index,
            sub,
            buf: Vec::new(),
            size: None,
            toggle: false,
        });
        self.deadline = now + self.timeout;
        Ok(frame(self.tx(), &with_mux(0x40, index, sub, &[])))
    }

    /// `true` while a transfer runs.
    pub fn busy(&self) -> bool {
        self.op.is_some()
    }

    fn fail(&mut self, code: AbortCode, send_abort: bool) -> ClientStep {
        let (dir, index, sub) = match self.op.take() {
            Some(ClientOp::Download { index, sub, .. }) => ("write", index, sub),
            Some(ClientOp::Upload { index, sub, .. }) => ("read", index, sub),
            None => ("?", 0, 0),
        };
        let abort = send_abort.then(|| abort_frame(self.tx(), index, sub, code));
        ClientStep::Failed(
            SdoError::Aborted {
                node: self.node,
                dir,
                index,
                sub,
                code,
            },
            abort,
        )
    }

    /// Feed a received frame; `None` when it is not for this transfer.
    pub fn on_frame(&mut self, f: &CanFrame, now: Duration) -> Option<ClientStep> {
        if std_id(f) != Some(self.node.cob(cob::SDO_TX)) || f.is_remote() || f.len() != 8 {
            return None;
        }
        let d = f.data();
        let tx = self.tx();
        let op = self.op.as_mut()?;
        let (cur_index, cur_sub) = match op {
            ClientOp::Download { index, sub, .. } | ClientOp::Upload { index, sub, .. } => {
                (*index, *sub)
            }
        };
        let scs = d[0] >> 5;
        if scs == 4 {
            if mux(d) != (cur_index, cur_sub) {
                return None;
            }
            let code = AbortCode(u32::from_le_bytes([d[4], d[5], d[6], d[7]]));
            return Some(self.fail(code, false));
        }
        self.deadline = now + self.timeout;
        match op {
            ClientOp::Download {
                data,
                pos,
                toggle,
                segmented,
                ..
            } => {
                match scs {
                    3 if mux(d) == (cur_index, cur_sub) && *pos == 0 && !*toggle => {
                        if !*segmented {
                            self.op = None;
                            return Some(ClientStep::Done(SdoDone::Downloaded));
                        }
                    }
                    1 if *segmented => {
                        if (d[0] >> 4 & 1 == 1) != *toggle {
                            return Some(self.fail(AbortCode::TOGGLE, true));
                        }
                        *toggle = !*toggle;
                        if *pos >= data.len() {
                            self.op = None;
                            return Some(ClientStep::Done(SdoDone::Downloaded));
                        }
                    }
                    _ => return Some(self.fail(AbortCode::COMMAND, true)),
                }
                let chunk = &data[*pos..(*pos + 7).min(data.len())];
                *pos += chunk.len();
                let last = *pos >= data.len();
                let n = (7 - chunk.len()) as u8;
                let mut seg = [0u8; 8];
                seg[0] = u8::from(*toggle) << 4 | n << 1 | u8::from(last);
                seg[1..1 + chunk.len()].copy_from_slice(chunk);
                Some(ClientStep::Send(frame(tx, &seg)))
            }
            ClientOp::Upload {
                buf, size, toggle, ..
            } => match scs {
                2 if mux(d) == (cur_index, cur_sub) && size.is_none() && buf.is_empty() => {
                    let (e, s) = (d[0] & 2 != 0, d[0] & 1 != 0);
                    if e {
                        let len = if s { 4 - usize::from(d[0] >> 2 & 3) } else { 4 };
                        let v = d[4..4 + len].to_vec();
                        self.op = None;
                        return Some(ClientStep::Done(SdoDone::Uploaded(v)));
                    }
                    *size = Some(if s {
                        u32::from_le_bytes([d[4], d[5], d[6], d[7]]) as usize
                    } else {
                        usize::MAX
                    });
                    Some(ClientStep::Send(frame(tx, &[0x60, 0, 0, 0, 0, 0, 0, 0])))
                }
                0 if size.is_some() => {
                    if (d[0] >> 4 & 1 == 1) != *toggle {
                        return Some(self.fail(AbortCode::TOGGLE, true));
                    }
                    let n = usize::from(d[0] >> 1 & 7);
                    buf.extend_from_slice(&d[1..8 - n]);
                    let last = d[0] & 1 != 0;
                    let want = size.unwrap_or(usize::MAX);
                    if last {
                        if want != usize::MAX && buf.len() != want {
                            return Some(self.fail(AbortCode::LENGTH, true));
                        }
                        let v = std::mem::take(buf);
                        self.op = None;
                        return Some(ClientStep::Done(SdoDone::Uploaded(v)));
                    }
                    if buf.len() > want {
                        return Some(self.fail(AbortCode::LENGTH, true));
                    }
                    *toggle = !*toggle;
                    let req = 0x60 | u8::from(*toggle) << 4;
                    Some(ClientStep::Send(frame(tx, &[req, 0, 0, 0, 0, 0, 0, 0])))
                }
                _ => Some(self.fail(AbortCode::COMMAND, true)),
            },
        }
    }

    /// Check the timeout at `now`: the error and the abort frame to send when it expired.
    pub fn poll(&mut self, now: Duration) -> Option<(SdoError, CanFrame)> {
        if self.op.is_none() || now < self.deadline {
            return None;
        }
        match self.fail(AbortCode::TIMEOUT, true) {
            ClientStep::Failed(
                SdoError::Aborted {
                    node,
                    dir,
                    index,
                    sub,
                    ..
                },
                Some(abort),
            ) => Some((
                SdoError::Timeout {
                    node,
                    dir,
                    index,
                    sub,
                    timeout: self.timeout,
                },
                abort,
            )),
            _ => None,
        }
    }
}

/// The time of a bus: the OS clock for real adapters, the bus's own clock for the virtual bus
/// (whose simulated time moves only while someone waits on it).
pub type Now<'a> = &'a dyn Fn() -> Duration;

/// A [`Now`] on the OS monotonic clock, epoch at the call.
pub fn os_clock() -> impl Fn() -> Duration {
    let t0 = Instant::now();
    move || t0.elapsed()
}

/// Run one client transfer to its end over `bus`: send `first`, answer the server until done,
/// handing every other received frame to `other` (PDOs, heartbeats keep flowing).
pub fn transfer<B: CanBus + ?Sized>(
    bus: &mut B,
    now: Now<'_>,
    client: &mut SdoClient,
    first: CanFrame,
    other: &mut dyn FnMut(&CanFrame),
) -> Result<SdoDone, SdoError> {
    let t0 = now();
    client.deadline = t0 + client.timeout;
    bus.send(&first)?;
    loop {
        let now_ = now();
        if let Some((err, abort)) = client.poll(now_) {
            // Best effort: the transfer has failed anyway.
            let _ = bus.send(&abort);
            return Err(err);
        }
        let wait = client
            .deadline
            .saturating_sub(now_)
            .clamp(Duration::from_micros(100), Duration::from_millis(20));
        let Some(f) = bus.recv(wait)? else { continue };
        match client.on_frame(&f, now()) {
            None => other(&f),
            Some(ClientStep::Send(next)) => bus.send(&next)?,
            Some(ClientStep::Done(done)) => return Ok(done),
            Some(ClientStep::Failed(err, abort)) => {
                if let Some(a) = abort {
                    let _ = bus.send(&a);
                }
                return Err(err);
            }
        }
    }
}

/// Write `data` to (index, sub) of the client's node over `bus`.
pub fn write<B: CanBus + ?Sized>(
    bus: &mut B,
    now: Now<'_>,
    client: &mut SdoClient,
    index: u16,
    sub: u8,
    data: &[u8],
    other: &mut dyn FnMut(&CanFrame),
) -> Result<(), SdoError> {
    let first = client.download(index, sub, data, Duration::ZERO)?;
    transfer(bus, now, client, first, other).map(|_| ())
}

/// Read (index, sub) of the client's node over `bus`.
pub fn read<B: CanBus + ?Sized>(
    bus: &mut B,
    now: Now<'_>,
    client: &mut SdoClient,
    index: u16,
    sub: u8,
    other: &mut dyn FnMut(&CanFrame),
) -> Result<Vec<u8>, SdoError> {
    let first = client.upload(index, sub, Duration::ZERO)?;
    match transfer(bus, now, client, first, other)? {
        SdoDone::Uploaded(v) => Ok(v),
        SdoDone::Downloaded => Ok(Vec::new()),
    }
}

#[derive(Clone, Debug)]
enum ServerOp {
    Download {
        buf: Vec<u8>,
        size: Option<usize>,
        toggle: bool,
    },
    Upload {
        data: Vec<u8>,
        pos: usize,
        toggle: bool,
    },
}

/// A response of the server, and the entry a completed write changed.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Served {
    /// The frame to send.
    pub response: CanFrame,
    /// (index, sub) written by a completed download.
    pub written: Option<(u16, u8)>,
}

/// The node's side of SDO (default COB-IDs 0x600/0x580 + node id) over an
/// [`ObjectDictionary`].
#[derive(Clone, Debug)]
pub struct SdoServer {
    node: NodeId,
    timeout: Duration,
    op: Option<ServerOp>,
    mux: (u16, u8),
    deadline: Duration,
}

impl SdoServer {
    /// A server for `node`, dropping a segmented transfer after `timeout` of silence.
    pub fn new(node: NodeId, timeout: Duration) -> Self {
        Self {
            node,
            timeout,
            op: None,
            mux: (0, 0),
            deadline: Duration::ZERO,
        }
    }

    fn tx(&self) -> u16 {
        self.node.cob(cob::SDO_TX)
    }

    fn abort(&mut self, index: u16, sub: u8, code: AbortCode) -> Option<Served> {
        self.op = None;
        Some(Served {
            response: abort_frame(self.tx(), index, sub, code),
            written: None,
        })
    }

    fn reply(&self, d: &[u8; 8], written: Option<(u16, u8)>) -> Option<Served> {
        Some(Served {
            response: frame(self.tx(), d),
            written,
        })
    }

    /// Feed a received frame; the response when it was an SDO request to this node.
    pub fn on_frame(
        &mut self,
        f: &CanFrame,
        od: &mut ObjectDictionary,
        now: Duration,
    ) -> Option<Served> {
        if std_id(f) != Some(self.node.cob(cob::SDO_RX)) || f.is_remote() {
            return None;
        }
        let d = f.data();
        if d.len() != 8 {
            let (i, s) = self.mux;
            return self.abort(i, s, AbortCode::COMMAND);
        }
        self.deadline = now + self.timeout;
        let ccs = d[0] >> 5;
        match ccs {
            4 => {
                self.op = None;
                None
            }
            1 => {
                let (index, sub) = mux(d);
                self.mux = (index, sub);
                let (e, s) = (d[0] & 2 != 0, d[0] & 1 != 0);
                if e {
                    let mut len = if s { 4 - usize::from(d[0] >> 2 & 3) } else { 4 };
                    if !s {
                        // Size not indicated: the object's own size.
                        if let Some(size) = od.entry(index, sub).and_then(|e| e.dtype.size()) {
                            len = len.min(size);
                        }
                    }
                    self.op = None;
                    if let Err(code) = od.write(index, sub, &d[4..4 + len]) {
                        return self.abort(index, sub, code);
                    }
                    self.reply(&with_mux(0x60, index, sub, &[]), Some((index, sub)))
                } else {
                    // Segmented: check the object exists and is writable before accepting.
                    if let Err(code) = od.read(index, sub).map(|_| ()).or_else(|c| {
                        if c == AbortCode::WRITE_ONLY {
                            Ok(())
                        } else {
                            Err(c)
                        }
                    }) {
                        return self.abort(index, sub, code);
                    }
                    let size = s.then(|| u32::from_le_bytes([d[4], d[5], d[6], d[7]]) as usize);
                    self.op = Some(ServerOp::Download {
                        buf: Vec::new(),
                        size,
                        toggle: false,
                    });
                    self.reply(&with_mux(0x60, index, sub, &[]), None)
                }
            }
            0 => {
                let (index, sub) = self.mux;
                let Some(ServerOp::Download {
                    buf, size, toggle, ..
                }) = self.op.as_mut()
                else {
                    return self.abort(index, sub, AbortCode::COMMAND);
                };
                if (d[0] >> 4 & 1 == 1) != *toggle {
                    return self.abort(index, sub, AbortCode::TOGGLE);
                }
                let n = usize::from(d[0] >> 1 & 7);
                buf.extend_from_slice(&d[1..8 - n]);
                let t = u8::from(*toggle);
                *toggle = !*toggle;
                if buf.len() > size.unwrap_or(usize::MAX) {
                    return self.abort(index, sub, AbortCode::LENGTH_TOO_HIGH);
                }
                if d[0] & 1 == 0 {
                    return self.reply(&[0x20 | t << 4, 0, 0, 0, 0, 0, 0, 0], None);
                }
                let data = std::mem::take(buf);
                if size.is_some_and(|s| s != data.len()) {
                    return self.abort(index, sub, AbortCode::LENGTH);
                }
                self.op = None;
                if let Err(code) = od.write(index, sub, &data) {
                    return self.abort(index, sub, code);
                }
                self.reply(&[0x20 | t << 4, 0, 0, 0, 0, 0, 0, 0], Some((index, sub)))
            }
            2 => {
                let (index, sub) = mux(d);
                self.mux = (index, sub);
                let value = match od.read(index, sub) {
                    Ok(v) => v.to_vec(),
                    Err(code) => return self.abort(index, sub, code),
                };
                if (1..=4).contains(&value.len()) {
                    self.op = None;
                    let n = (4 - value.len()) as u8;
                    self.reply(&with_mux(0x43 | n << 2, index, sub, &value), None)
                } else {
                    let size = (value.len() as u32).to_le_bytes();
                    self.op = Some(ServerOp::Upload {
                        data: value,
                        pos: 0,
                        toggle: false,
                    });
                    self.reply(&with_mux(0x41, index, sub, &size), None)
                }
            }
            3 => {
                let (index, sub) = self.mux;
                let Some(ServerOp::Upload { data, pos, toggle }) = self.op.as_mut() else {
                    return self.abort(index, sub, AbortCode::COMMAND);
                };
                if (d[0] >> 4 & 1 == 1) != *toggle {
                    return self.abort(index, sub, AbortCode::TOGGLE);
                }
                let chunk_end = (*pos + 7).min(data.len());
                let mut seg = [0u8; 8];
                let len = chunk_end - *pos;
                seg[1..1 + len].copy_from_slice(&data[*pos..chunk_end]);
                *pos = chunk_end;
                let last = *pos >= data.len();
                seg[0] = u8::from(*toggle) << 4 | ((7 - len) as u8) << 1 | u8::from(last);
                *toggle = !*toggle;
                if last {
                    self.op = None;
                }
                self.reply(&seg, None)
            }
            _ => {
                let (index, sub) = mux(d);
                self.abort(index, sub, AbortCode::COMMAND)
            }
        }
    }

    /// Drop a segmented transfer silent for longer than the timeout; the abort to send.
    pub fn poll(&mut self, now: Duration) -> Option<CanFrame> {
        if self.op.is_some() && now >= self.deadline {
            let (i, s) = self.mux;
            self.op = None;
            return Some(abort_frame(self.tx(), i, s, AbortCode::TIMEOUT));
        }
        None
    }
}

#[cfg(test)]
mod tests {
    use super::super::od::{Access, DataType};
    use super::*;

    fn node() -> NodeId {
        NodeId::new(4).unwrap()
    }

    fn dict() -> ObjectDictionary {
        let mut od = ObjectDictionary::new();
        od.add(0x6040, 0, DataType::U16, Access::Rw, true, 0)
            .add(0x1017, 0, DataType::U16, Access::Rw, false, 100)
            .add(0x6041, 0, DataType::U16, Access::Ro, true, 0x0250);
        od.add_bytes(
            0x1008,
            0,
            DataType::VisibleString,
            Access::Const,
            b"exompc virtual drive",
        );
        od.add_bytes(0x2000, 0, DataType::Domain, Access::Rw, b"");
        od
    }

    /// Run a client transfer against a server directly, returning the result and the number of
    /// frames exchanged.
    fn run(
        client: &mut SdoClient,
        server: &mut SdoServer,
        od: &mut ObjectDictionary,
        first: CanFrame,
    ) -> (Result<SdoDone, String>, usize) {
        let mut req = first;
        let now = Duration::ZERO;
        for n in 1..100 {
            let Some(resp) = server.on_frame(&req, od, now) else {
                return (Err("server silent".into()), n);
            };
            match client.on_frame(&resp.response, now) {
                Some(ClientStep::Send(next)) => req = next,
                Some(ClientStep::Done(d)) => return (Ok(d), n),
                Some(ClientStep::Failed(e, _)) => return (Err(e.to_string()), n),
                None => return (Err("not for the client".into()), n),
            }
        }
        (Err("no end".into()), 100)
    }

    #[test]
    fn expedited_frames_match_cia301() {
        let mut c = SdoClient::new(node(), Duration::from_millis(100));
        let f = c
            .download(0x6040, 0, &[0x06, 0x00], Duration::ZERO)
            .unwrap();
        assert_eq!(std_id(&f), Some(0x604));
        assert_eq!(f.data(), &[0x2B, 0x40, 0x60, 0x00, 0x06, 0x00, 0x00, 0x00]);
        let mut s = SdoServer::new(node(), Duration::from_millis(100));
        let mut od = dict();
        let r = s.on_frame(&f, &mut od, Duration::ZERO).unwrap();
        assert_eq!(std_id(&r.response), Some(0x584));
        assert_eq!(r.response.data(), &[0x60, 0x40, 0x60, 0x00, 0, 0, 0, 0]);
        assert_eq!(r.written, Some((0x6040, 0)));
        assert_eq!(od.get(0x6040, 0), Some(6));
        assert!(matches!(
            c.on_frame(&r.response, Duration::ZERO),
            Some(ClientStep::Done(SdoDone::Downloaded))
        ));
        let f = c.upload(0x6041, 0, Duration::ZERO).unwrap();
        assert_eq!(f.data(), &[0x40, 0x41, 0x60, 0x00, 0, 0, 0, 0]);
        let r = s.on_frame(&f, &mut od, Duration::ZERO).unwrap();
        assert_eq!(
            r.response.data(),
            &[0x4B, 0x41, 0x60, 0x00, 0x50, 0x02, 0, 0]
        );
        match c.on_frame(&r.response, Duration::ZERO) {
            Some(ClientStep::Done(SdoDone::Uploaded(v))) => assert_eq!(v, [0x50, 0x02]),
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn segmented_transfers_round_trip() {
        let mut c = SdoClient::new(node(), Duration::from_millis(100));
        let mut s = SdoServer::new(node(), Duration::from_millis(100));
        let mut od = dict();
        let first = c.upload(0x1008, 0, Duration::ZERO).unwrap();
        let (r, n) = run(&mut c, &mut s, &mut od, first);
        assert_eq!(
            r.unwrap(),
            SdoDone::Uploaded(b"exompc virtual drive".to_vec())
        );
        assert_eq!(n, 1 + 3, "initiate + ceil(20 / 7) segments");
        for len in [0usize, 5, 7, 8, 14, 15, 100] {
            let data: Vec<u8> = (0..len as u8).collect();
            let first = c.download(0x2000, 0, &data, Duration::ZERO).unwrap();
            let (r, _) = run(&mut c, &mut s, &mut od, first);
            assert_eq!(r.unwrap(), SdoDone::Downloaded, "len {len}");
            assert_eq!(od.entry(0x2000, 0).unwrap().bytes(), &data[..]);
            let first = c.upload(0x2000, 0, Duration::ZERO).unwrap();
            let (r, _) = run(&mut c, &mut s, &mut od, first);
            assert_eq!(r.unwrap(), SdoDone::Uploaded(data));
        }
    }

    #[test]
    fn aborts_and_timeouts() {
        let mut c = SdoClient::new(node(), Duration::from_millis(100));
        let mut s = SdoServer::new(node(), Duration::from_millis(100));
        let mut od = dict();
        let first = c.download(0x6041, 0, &[0, 0], Duration::ZERO).unwrap();
        let (r, _) = run(&mut c, &mut s, &mut od, first);
        let e = r.unwrap_err();
        assert!(e.contains("0x06010002") && e.contains("read-only"), "{e}");
        let first = c.upload(0x1234, 0, Duration::ZERO).unwrap();
        let (r, _) = run(&mut c, &mut s, &mut od, first);
        assert!(r.unwrap_err().contains("0x06020000"));
        // A second transfer while one runs is refused.
        c.upload(0x6041, 0, Duration::ZERO).unwrap();
        assert!(matches!(
            c.upload(0x6041, 0, Duration::ZERO),
            Err(SdoError::Busy)
        ));
        assert!(c.poll(Duration::from_millis(99)).is_none());
        let (e, abort) = c.poll(Duration::from_millis(100)).unwrap();
        assert!(matches!(e, SdoError::Timeout { index: 0x6041, .. }));
        assert_eq!(abort.data()[0], 0x80);
        assert_eq!(&abort.data()[4..], &0x0504_0000u32.to_le_bytes());
        assert!(!c.busy());
        // A toggle error in a segmented download aborts on the server.
        let first = c.download(0x2000, 0, &[1; 20], Duration::ZERO).unwrap();
        s.on_frame(&first, &mut od, Duration::ZERO).unwrap();
        let bad = frame(0x604, &[0x10, 1, 1, 1, 1, 1, 1, 1]);
        let r = s.on_frame(&bad, &mut od, Duration::ZERO).unwrap();
        assert_eq!(&r.response.data()[4..], &AbortCode::TOGGLE.0.to_le_bytes());
        // The server drops a stalled segmented transfer.
        s.on_frame(&first, &mut od, Duration::from_millis(10))
            .unwrap();
        assert!(s.poll(Duration::from_millis(50)).is_none());
        let a = s.poll(Duration::from_millis(110)).unwrap();
        assert_eq!(&a.data()[4..], &AbortCode::TIMEOUT.0.to_le_bytes());
        // An unknown command specifier is aborted.
        let r = s
            .on_frame(
                &frame(0x604, &[0xE0, 0, 0x20, 0, 0, 0, 0, 0]),
                &mut od,
                Duration::ZERO,
            )
            .unwrap();
        assert_eq!(&r.response.data()[4..], &AbortCode::COMMAND.0.to_le_bytes());
        // Frames of other nodes are not answered.
        assert!(s
            .on_frame(
                &frame(0x605, &[0x40, 0x41, 0x60, 0, 0, 0, 0, 0]),
                &mut od,
                Duration::ZERO
            )
            .is_none());
    }
}
