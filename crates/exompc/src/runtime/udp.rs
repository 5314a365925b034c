//! UDP transport of the robot link (one datagram per frame, authenticated: [`super::session`]).

use super::frame::{RobotCommand, RobotSample};
use super::session::{random_nonce, ControllerLink, Psk, RobotLink, RobotRx};
use super::{Lifecycle, LinkStats, RobotInterface};
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

enum Out<'a, const N: usize> {
    Hello,
    Command(&'a RobotCommand<N>),
}

/// The controller's side of a UDP robot link: a [`RobotInterface`] that opens an
/// authenticated session ([`RobotInterface::activate`]: the handshake), receives
/// [`RobotSample`] frames and sends [`RobotCommand`] frames. Datagrams from any address other
/// than the robot's are counted ([`FrameError::Foreign`](super::FrameError::Foreign)) and
/// dropped.
pub struct UdpRobot<const N: usize> {
    sock: UdpSocket,
    robot: SocketAddr,
    buf: Vec<u8>,
    link: ControllerLink<N>,
    state: Lifecycle,
    first: Option<RobotSample<N>>,
    next_hello: Option<Instant>,
    retry: Duration,
}

impl<const N: usize> UdpRobot<N> {
    /// Bind `local` (e.g. `127.0.0.1:0`) and talk to the robot at `robot` under the pre-shared
    /// key `psk`; samples more than `max_ahead` sequence numbers ahead are rejected. The
    /// interface starts unconfigured.
    pub fn connect(
        local: SocketAddr,
        robot: SocketAddr,
        psk: Psk,
        max_ahead: u32,
    ) -> std::io::Result<Self> {
        let sock = UdpSocket::bind(local)?;
        sock.set_nonblocking(true)?;
        Ok(UdpRobot {
            sock,
            robot,
            buf: vec![0; 2048],
            link: ControllerLink::new(psk, max_ahead),
            state: Lifecycle::Unconfigured,
            first: None,
            next_hello: None,
            retry: Duration::from_millis(100),
        })
    }

    /// The local address.
    pub fn local_addr(&self) -> std::io::Result<SocketAddr> {
        self.sock.local_addr()
    }

    /// Send the link's encoded frame (nothing when it is empty), counting the outcome.
    fn send_frame(&mut self, which: Out<'_, N>) -> std::io::Result<()> {
        let bytes = match which {
            Out::Hello => self.link.hello(0),
            Out::Command(c) => self.link.command(c),
        };
        if bytes.is_empty() {
            return Ok(());
        }
        let ok = send_counted(&self.sock, bytes, self.robot)?;
        self.link.count_sent(ok);
        Ok(())
    }

    /// Receive datagrams for at most `timeout`, returning the newest valid sample.
    /// Returns early (without a sample) when a challenge just established the session key.
    fn receive(&mut self, timeout: Duration) -> std::io::Result<Option<RobotSample<N>>> {
        let end = Instant::now() + timeout;
        let mut newest: Option<RobotSample<N>> = None;
        loop {
            let wait = if newest.is_some() {
                Duration::ZERO
            } else {
                end.saturating_duration_since(Instant::now())
            };
            let got = recv_within(&self.sock, &mut self.buf, wait)?;
            match got {
                Some((n, from)) if from == self.robot => {
                    let was = self.link.established();
                    if let Some(s) = self.link.receive(&self.buf[..n]) {
                        if newest.replace(s).is_some() {
                            self.link.count_superseded();
                        }
                    }
                    if !was && self.link.established() {
                        // Confirm the handshake at once: the robot activates on it.
                        return Ok(None);
                    }
                }
                Some(_) => self.link.count_foreign(),
                None if newest.is_some() || Instant::now() >= end => return Ok(newest),
                None => {}
            }
        }
    }

    fn confirm(&mut self) -> std::io::Result<()> {
        let c = RobotCommand::new(
            0,
            0,
            0,
            super::frame::command_flags::HELLO,
            nalgebra::SVector::zeros(),
        );
        self.send_frame(Out::Command(&c))
    }
}

impl<const N: usize> RobotInterface<N> for UdpRobot<N> {
    fn state(&self) -> Lifecycle {
        self.state
    }

    fn configure(&mut self) -> std::io::Result<()> {
        self.link.start(random_nonce()?);
        self.first = None;
        self.next_hello = None;
        self.state = Lifecycle::Inactive;
        Ok(())
    }

    fn activate(&mut self, timeout: Duration) -> std::io::Result<bool> {
        if self.state == Lifecycle::Active {
            return Ok(true);
        }
        if self.state != Lifecycle::Inactive {
            self.configure()?;
        }
        let end = Instant::now() + timeout;
        loop {
            let now = Instant::now();
            if self.next_hello.is_none_or(|t| now >= t) {
                self.next_hello = Some(now + self.retry);
                if self.link.established() {
                    self.confirm()?;
                } else {
                    self.send_frame(Out::Hello)?;
                }
            }
            let was = self.link.established();
            let wait = end
                .min(self.next_hello.unwrap_or(end))
                .saturating_duration_since(Instant::now());
            let got = self.receive(wait)?;
            if !was && self.link.established() {
                self.confirm()?;
                self.next_hello = Some(Instant::now() + self.retry);
            }
            if let Some(s) = got {
                self.first = Some(s);
                self.state = Lifecycle::Active;
                return Ok(true);
            }
            if Instant::now() >= end {
                return Ok(false);
            }
        }
    }

    fn deactivate(&mut self) -> std::io::Result<()> {
        self.link.reset();
        self.state = Lifecycle::Inactive;
        Ok(())
    }

    fn error(&mut self) {
        self.link.reset();
        self.state = Lifecycle::Error;
    }

    fn read(&mut self, timeout: Duration) -> std::io::Result<Option<RobotSample<N>>> {
        if let Some(s) = self.first.take() {
            return Ok(Some(s));
        }
        self.receive(timeout)
    }

    fn write(&mut self, cmd: &RobotCommand<N>) -> std::io::Result<()> {
        self.send_frame(Out::Command(cmd))
    }

    fn link_stats(&self) -> LinkStats {
        self.link.stats()
    }
}

/// The robot's side of a UDP link: bound to a local address, it answers handshakes while the
/// robot accepts a session and then talks only to that session's controller ([`RobotLink`]).
pub struct UdpPeer<const N: usize> {
    sock: UdpSocket,
    buf: Vec<u8>,
    link: RobotLink<N>,
}

impl<const N: usize> UdpPeer<N> {
    /// Bind `local` (port 0 picks a free port: see [`UdpPeer::local_addr`]) with the
    /// pre-shared key `psk`; commands more than `max_ahead` sequence numbers ahead are
    /// rejected.
    pub fn bind(local: SocketAddr, psk: Psk, max_ahead: u32) -> std::io::Result<Self> {
        let sock = UdpSocket::bind(local)?;
        sock.set_nonblocking(true)?;
        Ok(UdpPeer {
            sock,
            buf: vec![0; 2048],
            link: RobotLink::new(psk, max_ahead),
        })
    }

    /// The bound address.
    pub fn local_addr(&self) -> std::io::Result<SocketAddr> {
        self.sock.local_addr()
    }

    /// The protocol state.
    pub fn link(&mut self) -> &mut RobotLink<N> {
        &mut self.link
    }

    /// The session's controller address, once known.
    pub fn peer(&self) -> Option<SocketAddr> {
        self.link.peer()
    }

    /// Counters.
    pub fn stats(&self) -> LinkStats {
        self.link.stats()
    }

    /// Receive one datagram, waiting at most `timeout`: `Some((from, bytes))` (copied into
    /// `into`) or `None`.
    pub fn recv_raw(
        &mut self,
        timeout: Duration,
        into: &mut Vec<u8>,
    ) -> std::io::Result<Option<SocketAddr>> {
        match recv_within(&self.sock, &mut self.buf, timeout)? {
            Some((n, from)) => {
                into.clear();
                into.extend_from_slice(&self.buf[..n]);
                Ok(Some(from))
            }
            None => Ok(None),
        }
    }

    /// Hand a datagram to the link; a challenge to send back is sent at once.
    pub fn take(
        &mut self,
        from: SocketAddr,
        bytes: &[u8],
        stamp_ns: u64,
    ) -> std::io::Result<RobotRx<N>> {
        let r = self
            .link
            .receive(from, bytes, stamp_ns, &mut || random_nonce().ok());
        if r == RobotRx::Reply {
            let ok = send_counted(&self.sock, self.link.reply(), from)?;
            self.link.count_sent(ok);
        }
        Ok(r)
    }

    /// Encode a sample of the session (`None` without a session).
    pub fn encode(&mut self, s: &RobotSample<N>) -> Option<(Vec<u8>, SocketAddr)> {
        self.link.sample(s).map(|(b, p)| (b.to_vec(), p))
    }

    /// Send raw bytes to `to`.
    pub fn send_raw(&mut self, bytes: &[u8], to: SocketAddr) -> std::io::Result<()> {
        let ok = send_counted(&self.sock, bytes, to)?;
        self.link.count_sent(ok);
        Ok(())
    }
}

fn send_counted(sock: &UdpSocket, bytes: &[u8], to: SocketAddr) -> std::io::Result<bool> {
    match sock.send_to(bytes, to) {
        Ok(_) => Ok(true),
        Err(e) if e.kind() == ErrorKind::ConnectionRefused => Ok(false),
        Err(e) => Err(e),
    }
}
