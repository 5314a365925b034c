//! Authenticated sessions of the robot link: keys, the handshake, and the protocol state of
//! both ends (no sockets: [`super::UdpRobot`] and the virtual robot's transport move the bytes).
//!
//! Both sides hold a pre-shared key ([`Psk`], `exompc keygen`). The controller opens with a
//! [`Hello`] carrying a fresh random nonce; the robot, while it accepts a
//! session (lifecycle inactive), answers with a [`Challenge`] echoing
//! it with its own fresh nonce; both frames carry a MAC under the handshake key derived from
//! the PSK. Both sides then derive the session key from the PSK and the two nonces
//! ([`Psk::session_key`]); the controller's first command (flag `HELLO`) under the session key
//! activates the robot. Every later frame carries a MAC under the session key over the whole
//! frame, so frames of one session are worthless in any other, and a sequence number checked
//! against the replay window ([`SeqTracker`]). Keyed BLAKE3 (the `blake3` crate) is the MAC.

use super::frame::{
    decode, encode_challenge, encode_command, encode_hello, encode_sample, max_frame_len,
    Challenge, Frame, FrameError, Hello, RobotCommand, RobotSample, SeqTracker,
};
#[cfg(feature = "std")]
pub use super::key::random_nonce;
pub use super::key::{Key, KeyError, Psk, MAX_KEY_LEN, MIN_KEY_LEN, NONCE_LEN};
use super::LinkStats;
use alloc::vec::Vec;
use core::net::SocketAddr;

/// The controller's end of a session (protocol state only).
#[derive(Debug)]
pub struct ControllerLink<const N: usize> {
    psk: Psk,
    max_ahead: u32,
    nonce_c: Option<[u8; NONCE_LEN]>,
    session: Option<Key>,
    rx: SeqTracker,
    tx_seq: u32,
    hellos: u32,
    out: Vec<u8>,
    stats: LinkStats,
}

impl<const N: usize> ControllerLink<N> {
    /// A link under `psk`; samples more than `max_ahead` sequence numbers ahead of the last one
    /// are rejected (about 1 s of periods).
    pub fn new(psk: Psk, max_ahead: u32) -> Self {
        ControllerLink {
            psk,
            max_ahead,
            nonce_c: None,
            session: None,
            rx: SeqTracker::session(max_ahead),
            tx_seq: 0,
            hellos: 0,
            out: Vec::with_capacity(max_frame_len(N)),
            stats: LinkStats::default(),
        }
    }

    /// Start a fresh handshake with the controller nonce `nonce_c` (the old session, if any,
    /// is forgotten).
    pub fn start(&mut self, nonce_c: [u8; NONCE_LEN]) {
        self.nonce_c = Some(nonce_c);
        self.session = None;
        self.rx = SeqTracker::session(self.max_ahead);
        self.tx_seq = 0;
    }

    /// Forget the session and the handshake.
    pub fn reset(&mut self) {
        self.nonce_c = None;
        self.session = None;
    }

    /// Whether the handshake is started.
    pub fn started(&self) -> bool {
        self.nonce_c.is_some()
    }

    /// Whether the session key is established (a valid challenge answered this handshake).
    pub fn established(&self) -> bool {
        self.session.is_some()
    }

    /// The encoded hello of the current handshake (empty before [`ControllerLink::start`]).
    pub fn hello(&mut self, stamp_ns: u64) -> &[u8] {
        self.out.clear();
        if let Some(nonce_c) = self.nonce_c {
            self.hellos = self.hellos.wrapping_add(1);
            let h = Hello {
                seq: self.hellos,
                stamp_ns,
                nonce_c,
            };
            encode_hello::<N>(&h, self.psk.handshake_key(), &mut self.out);
        }
        &self.out
    }

    /// Encode `c` under the session key with the session's next sequence number (which
    /// replaces `c.seq`); empty without a session.
    pub fn command(&mut self, c: &RobotCommand<N>) -> &[u8] {
        self.out.clear();
        if let Some(key) = &self.session {
            self.tx_seq = self.tx_seq.wrapping_add(1);
            let c = RobotCommand {
                seq: self.tx_seq,
                ..*c
            };
            encode_command(&c, key, &mut self.out);
        }
        &self.out
    }

    /// Count a datagram from an address other than the robot's.
    pub fn count_foreign(&mut self) {
        self.stats.received += 1;
        self.stats.rejected.count(FrameError::Foreign);
    }

    /// Count a frame sent, or a send that failed.
    pub fn count_sent(&mut self, ok: bool) {
        if ok {
            self.stats.sent += 1;
        } else {
            self.stats.send_errors += 1;
        }
    }

    /// Take one datagram from the robot: a valid challenge answering this handshake
    /// establishes the session key; a valid sample of the session is returned; everything
    /// else is counted by reason.
    pub fn receive(&mut self, bytes: &[u8]) -> Option<RobotSample<N>> {
        self.stats.received += 1;
        let r = match decode::<N>(bytes, self.psk.handshake_key(), self.session.as_ref()) {
            Ok(Frame::Challenge(ch)) => self.challenge(&ch),
            Ok(Frame::Sample(s)) => self.rx.accept(s.seq).map(|()| Some(s)),
            Ok(Frame::Command(_) | Frame::Hello(_)) => Err(FrameError::WrongDirection),
            Err(e) => Err(e),
        };
        self.stats.gaps = self.rx.gaps;
        match r {
            Ok(s) => {
                self.stats.accepted += 1;
                s
            }
            Err(e) => {
                self.stats.rejected.count(e);
                None
            }
        }
    }

    fn challenge(&mut self, ch: &Challenge) -> Result<Option<RobotSample<N>>, FrameError> {
        if self.nonce_c != Some(ch.nonce_c) {
            return Err(FrameError::NotAllowed);
        }
        if self.session.is_some() {
            // The robot answered a repeated hello again.
            return Err(FrameError::Duplicate);
        }
        self.session = Some(self.psk.session_key(&ch.nonce_c, &ch.nonce_r));
        self.rx = SeqTracker::session(self.max_ahead);
        self.tx_seq = 0;
        Ok(None)
    }

    /// Counters.
    pub fn stats(&self) -> LinkStats {
        self.stats
    }

    /// Count a newer sample read in the same call as an older one.
    pub fn count_superseded(&mut self) {
        self.stats.superseded += 1;
    }
}

#[derive(Clone, Debug)]
struct Pending {
    nonce_c: [u8; NONCE_LEN],
    nonce_r: [u8; NONCE_LEN],
    key: Key,
    from: SocketAddr,
    stamp_ns: u64,
}

/// What a datagram meant to the robot's end of the link.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum RobotRx<const N: usize> {
    /// Nothing to act on (rejected and counted, or a repeated confirmation).
    Nothing,
    /// Send [`RobotLink::reply`] back to the sender (a challenge).
    Reply,
    /// The controller confirmed the handshake: the session is active with that controller.
    Activated,
    /// A valid command of the session.
    Command(RobotCommand<N>),
}

/// The robot's end of a session (protocol state only).
#[derive(Debug)]
pub struct RobotLink<const N: usize> {
    psk: Psk,
    max_ahead: u32,
    accepting: bool,
    pending: Option<Pending>,
    session: Option<(Key, SocketAddr)>,
    rx: SeqTracker,
    out: Vec<u8>,
    stats: LinkStats,
    sessions: u64,
}

impl<const N: usize> RobotLink<N> {
    /// A link under `psk`; commands more than `max_ahead` sequence numbers ahead of the last
    /// one are rejected. It accepts a handshake until a session is active.
    pub fn new(psk: Psk, max_ahead: u32) -> Self {
        RobotLink {
            psk,
            max_ahead,
            accepting: true,
            pending: None,
            session: None,
            rx: SeqTracker::session(max_ahead),
            out: Vec::with_capacity(max_frame_len(N)),
            stats: LinkStats::default(),
            sessions: 0,
        }
    }

    /// Forget the session and any handshake, and accept a new handshake (the robot's restart).
    pub fn reset(&mut self) {
        self.pending = None;
        self.session = None;
        self.accepting = true;
    }

    /// Whether a new handshake is accepted (only while the robot is inactive).
    pub fn accepting(&self) -> bool {
        self.accepting
    }

    /// The session's controller address, once a session is active.
    pub fn peer(&self) -> Option<SocketAddr> {
        self.session.as_ref().map(|s| s.1)
    }

    /// Sessions activated so far.
    pub fn sessions(&self) -> u64 {
        self.sessions
    }

    /// The bytes to send back after [`RobotRx::Reply`].
    pub fn reply(&self) -> &[u8] {
        &self.out
    }

    /// Counters.
    pub fn stats(&self) -> LinkStats {
        self.stats
    }

    /// Count a rejection decided by the caller (e.g. a command the robot's state refuses).
    pub fn count(&mut self, e: FrameError) {
        self.stats.accepted = self.stats.accepted.saturating_sub(1);
        self.stats.rejected.count(e);
    }

    /// Count a frame sent, or a send that failed.
    pub fn count_sent(&mut self, ok: bool) {
        if ok {
            self.stats.sent += 1;
        } else {
            self.stats.send_errors += 1;
        }
    }

    /// Take one datagram from `from` at robot time `stamp_ns`; `nonce_r` gives a fresh nonce
    /// for a new handshake (`None`: no randomness available, the hello is dropped).
    pub fn receive(
        &mut self,
        from: SocketAddr,
        bytes: &[u8],
        stamp_ns: u64,
        nonce_r: &mut dyn FnMut() -> Option<[u8; NONCE_LEN]>,
    ) -> RobotRx<N> {
        self.stats.received += 1;
        let r = self.take(from, bytes, stamp_ns, nonce_r);
        self.stats.gaps = self.rx.gaps;
        match r {
            Ok(x) => {
                self.stats.accepted += 1;
                x
            }
            Err(e) => {
                self.stats.rejected.count(e);
                RobotRx::Nothing
            }
        }
    }

    fn take(
        &mut self,
        from: SocketAddr,
        bytes: &[u8],
        stamp_ns: u64,
        nonce_r: &mut dyn FnMut() -> Option<[u8; NONCE_LEN]>,
    ) -> Result<RobotRx<N>, FrameError> {
        if let Some((_, peer)) = &self.session {
            if *peer != from {
                return Err(FrameError::Foreign);
            }
        }
        let key = match (&self.session, &self.pending) {
            (Some((k, _)), _) => Some(k),
            (None, Some(p)) => Some(&p.key),
            (None, None) => None,
        };
        match decode::<N>(bytes, self.psk.handshake_key(), key)? {
            Frame::Hello(h) => {
                if !self.accepting || self.session.is_some() {
                    return Err(FrameError::NotAllowed);
                }
                let same = self
                    .pending
                    .as_ref()
                    .is_some_and(|p| p.nonce_c == h.nonce_c);
                if !same {
                    let nr = nonce_r().ok_or(FrameError::NotAllowed)?;
                    self.pending = Some(Pending {
                        nonce_c: h.nonce_c,
                        nonce_r: nr,
                        key: self.psk.session_key(&h.nonce_c, &nr),
                        from,
                        stamp_ns,
                    });
                }
                if let Some(p) = &mut self.pending {
                    p.from = from;
                    self.out.clear();
                    let ch = Challenge {
                        stamp_ns: p.stamp_ns,
                        nonce_c: p.nonce_c,
                        nonce_r: p.nonce_r,
                    };
                    encode_challenge::<N>(&ch, self.psk.handshake_key(), &mut self.out);
                }
                Ok(RobotRx::Reply)
            }
            Frame::Command(c) => {
                if self.session.is_some() {
                    self.rx.accept(c.seq)?;
                    if c.flags & super::frame::command_flags::HELLO != 0 {
                        return Ok(RobotRx::Nothing);
                    }
                    return Ok(RobotRx::Command(c));
                }
                // Under the pending key: the controller's confirmation.
                let Some(p) = self.pending.take() else {
                    return Err(FrameError::NoSession);
                };
                if !self.accepting || c.flags & super::frame::command_flags::HELLO == 0 {
                    self.pending = Some(p);
                    return Err(FrameError::NotAllowed);
                }
                let mut rx = SeqTracker::session(self.max_ahead);
                if let Err(e) = rx.accept(c.seq) {
                    self.pending = Some(p);
                    return Err(e);
                }
                self.rx = rx;
                self.session = Some((p.key, from));
                self.accepting = false;
                self.sessions += 1;
                Ok(RobotRx::Activated)
            }
            Frame::Sample(_) | Frame::Challenge(_) => Err(FrameError::WrongDirection),
        }
    }

    /// Encode `s` under the session key for the session's controller; `None` without a
    /// session.
    pub fn sample(&mut self, s: &RobotSample<N>) -> Option<(&[u8], SocketAddr)> {
        let (key, peer) = self.session.as_ref()?;
        self.out.clear();
        encode_sample(s, key, &mut self.out);
        Some((&self.out, *peer))
    }
}
