//! UDP transport of the robot link (one datagram per frame).

use super::frame::{
    decode, encode_command, encode_sample, max_frame_len, Frame, FrameError, RobotCommand,
    RobotSample, SeqTracker,
};
use super::{LinkStats, RobotInterface};
use std::io::ErrorKind;
use std::net::{SocketAddr, UdpSocket};
use std::time::{Duration, Instant};

fn would_block(e: &std::io::Error) -> bool {
    matches!(e.kind(), ErrorKind::WouldBlock | ErrorKind::TimedOut)
}

/// Wait until `sock` is readable or `timeout` passed (`ppoll`: a high-resolution timeout,
/// unlike `SO_RCVTIMEO`, which the kernel rounds to its tick of several milliseconds).
#[cfg(unix)]
fn wait_readable(sock: &UdpSocket, timeout: Duration) -> std::io::Result<()> {
    use std::os::fd::AsRawFd;
    let mut fds = libc::pollfd {
        fd: sock.as_raw_fd(),
        events: libc::POLLIN,
        revents: 0,
    };
    let ts = libc::timespec {
        tv_sec: timeout.as_secs().min(i32::MAX as u64) as libc::time_t,
        tv_nsec: libc::c_long::from(timeout.subsec_nanos() as i32),
    };
    // SAFETY: one valid pollfd, a valid timespec, no signal mask.
    let r = unsafe { libc::ppoll(&mut fds, 1, &ts, std::ptr::null()) };
    if r < 0 {
        let e = std::io::Error::last_os_error();
        if e.kind() != ErrorKind::Interrupted {
            return Err(e);
        }
    }
    Ok(())
}

#[cfg(not(unix))]
fn wait_readable(sock: &UdpSocket, timeout: Duration) -> std::io::Result<()> {
    sock.set_nonblocking(false)?;
    sock.set_read_timeout(Some(timeout.max(Duration::from_micros(1))))?;
    let mut b = [0u8; 1];
    let r = sock.peek(&mut b);
    sock.set_nonblocking(true)?;
    match r {
        Ok(_) => Ok(()),
        Err(e) if would_block(&e) || e.kind() == ErrorKind::ConnectionRefused => Ok(()),
        Err(e) => Err(e),
    }
}

/// Receive one datagram, waiting at most `timeout` (zero: do not wait). `Ok(None)` when
/// nothing arrived; an ICMP "connection refused" from an earlier send is skipped. The socket
/// must be non-blocking.
fn recv_within(
    sock: &UdpSocket,
    buf: &mut [u8],
    timeout: Duration,
) -> std::io::Result<Option<(usize, SocketAddr)>> {
    let end = Instant::now() + timeout;
    loop {
        match sock.recv_from(buf) {
            Ok(r) => return Ok(Some(r)),
            Err(e) if would_block(&e) || e.kind() == ErrorKind::ConnectionRefused => {}
            Err(e) => return Err(e),
        }
        let now = Instant::now();
        if now >= end {
            return Ok(None);
        }
        wait_readable(sock, end - now)?;
    }
}

/// The controller's side of a UDP robot link: a [`RobotInterface`] that receives
/// [`RobotSample`] frames and sends [`RobotCommand`] frames.
pub struct UdpRobot<const N: usize> {
    sock: UdpSocket,
    robot: SocketAddr,
    buf: Vec<u8>,
    out: Vec<u8>,
    seq: SeqTracker,
    stats: LinkStats,
}

impl<const N: usize> UdpRobot<N> {
    /// Bind `local` (e.g. `127.0.0.1:0`) and talk to the robot at `robot`; datagrams from any
    /// other address are ignored.
    pub fn connect(local: SocketAddr, robot: SocketAddr) -> std::io::Result<Self> {
        let sock = UdpSocket::bind(local)?;
        sock.set_nonblocking(true)?;
        Ok(UdpRobot {
            sock,
            robot,
            buf: vec![0; 2048],
            out: Vec::with_capacity(max_frame_len(N)),
            seq: SeqTracker::default(),
            stats: LinkStats::default(),
        })
    }

    /// The local address.
    pub fn local_addr(&self) -> std::io::Result<SocketAddr> {
        self.sock.local_addr()
    }

    fn take(&mut self, n: usize, newest: &mut Option<RobotSample<N>>) {
        self.stats.received += 1;
        let r = match decode::<N>(&self.buf[..n]) {
            Ok(Frame::Sample(s)) => self.seq.accept(s.seq).map(|()| s),
            Ok(Frame::Command(_)) => Err(FrameError::WrongDirection),
            Err(e) => Err(e),
        };
        match r {
            Ok(s) => {
                self.stats.accepted += 1;
                if newest.replace(s).is_some() {
                    self.stats.superseded += 1;
                }
            }
            Err(e) => self.stats.rejected.count(e),
        }
        self.stats.gaps = self.seq.gaps;
    }
}

impl<const N: usize> RobotInterface<N> for UdpRobot<N> {
    fn read(&mut self, timeout: Duration) -> std::io::Result<Option<RobotSample<N>>> {
        let end = Instant::now() + timeout;
        let mut newest = None;
        loop {
            let wait = if newest.is_some() {
                Duration::ZERO
            } else {
                end.saturating_duration_since(Instant::now())
            };
            let mut buf = std::mem::take(&mut self.buf);
            let got = recv_within(&self.sock, &mut buf, wait);
            self.buf = buf;
            match got? {
                Some((n, from)) if from == self.robot => self.take(n, &mut newest),
                Some(_) => {}
                None if newest.is_some() || Instant::now() >= end => return Ok(newest),
                None => {}
            }
        }
    }

    fn write(&mut self, cmd: &RobotCommand<N>) -> std::io::Result<()> {
        self.out.clear();
        encode_command(cmd, &mut self.out);
        match self.sock.send_to(&self.out, self.robot) {
            Ok(_) => self.stats.sent += 1,
            Err(e) if e.kind() == ErrorKind::ConnectionRefused => self.stats.send_errors += 1,
            Err(e) => return Err(e),
        }
        Ok(())
    }

    fn link_stats(&self) -> LinkStats {
        self.stats
    }
}

/// The robot's side of a UDP link: bound to a local address, it answers the controller that
/// sent the first valid command (HELLO) and ignores datagrams from any other address.
pub struct UdpPeer<const N: usize> {
    sock: UdpSocket,
    peer: Option<SocketAddr>,
    buf: Vec<u8>,
    out: Vec<u8>,
    stats: LinkStats,
}

impl<const N: usize> UdpPeer<N> {
    /// Bind `local` (port 0 picks a free port: see [`UdpPeer::local_addr`]).
    pub fn bind(local: SocketAddr) -> std::io::Result<Self> {
        let sock = UdpSocket::bind(local)?;
        sock.set_nonblocking(true)?;
        Ok(UdpPeer {
            sock,
            peer: None,
            buf: vec![0; 2048],
            out: Vec::with_capacity(max_frame_len(N)),
            stats: LinkStats::default(),
        })
    }

    /// The bound address.
    pub fn local_addr(&self) -> std::io::Result<SocketAddr> {
        self.sock.local_addr()
    }

    /// The controller's address, once known.
    pub fn peer(&self) -> Option<SocketAddr> {
        self.peer
    }

    /// Counters (`rejected` counts decoding failures only; the caller counts the
    /// sequence-number and staleness rejections it makes with [`UdpPeer::count`]).
    pub fn stats(&self) -> LinkStats {
        self.stats
    }

    /// Count a rejection decided by the caller.
    pub fn count(&mut self, e: FrameError) {
        self.stats.rejected.count(e);
    }

    /// Count a frame accepted by the caller.
    pub fn count_accepted(&mut self) {
        self.stats.accepted += 1;
    }

    /// Receive one raw datagram from the controller (or from anyone before the controller is
    /// known), waiting at most `timeout`; the bytes are copied into `into`.
    pub fn recv_raw(&mut self, timeout: Duration, into: &mut Vec<u8>) -> std::io::Result<bool> {
        let got = recv_within(&self.sock, &mut self.buf, timeout)?;
        match got {
            Some((n, from)) if self.peer.is_none_or(|p| p == from) => {
                self.stats.received += 1;
                into.clear();
                into.extend_from_slice(&self.buf[..n]);
                if self.peer.is_none() {
                    if let Ok(Frame::Command(c)) = decode::<N>(into) {
                        if c.flags & super::frame::command_flags::HELLO != 0 {
                            self.peer = Some(from);
                        }
                    }
                }
                Ok(true)
            }
            _ => Ok(false),
        }
    }

    /// Decode a raw command datagram, counting a failure.
    pub fn decode_command(&mut self, bytes: &[u8]) -> Option<RobotCommand<N>> {
        match decode::<N>(bytes) {
            Ok(Frame::Command(c)) => Some(c),
            Ok(Frame::Sample(_)) => {
                self.count(FrameError::WrongDirection);
                None
            }
            Err(e) => {
                self.count(e);
                None
            }
        }
    }

    /// Encode a sample (into an internal buffer, returned for fault injection).
    pub fn encode(&mut self, s: &RobotSample<N>) -> &[u8] {
        self.out.clear();
        encode_sample(s, &mut self.out);
        &self.out
    }

    /// Send raw bytes to the controller (dropped before it is known).
    pub fn send_raw(&mut self, bytes: &[u8]) -> std::io::Result<()> {
        let Some(p) = self.peer else { return Ok(()) };
        match self.sock.send_to(bytes, p) {
            Ok(_) => self.stats.sent += 1,
            Err(e) if e.kind() == ErrorKind::ConnectionRefused => self.stats.send_errors += 1,
            Err(e) => return Err(e),
        }
        Ok(())
    }
}
