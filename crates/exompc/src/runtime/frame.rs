//! The versioned little-endian binary frame of the robot link, authenticated by a MAC (see
//! `docs/REALTIME.md` for the byte-offset table and the handshake).
//!
//! Every frame is a 24-byte header, a payload whose length is fixed by the frame kind and the
//! joint count, and a 32-byte MAC (keyed BLAKE3) of everything before it:
//!
//! | offset | size | field |
//! |---|---|---|
//! | 0 | 4 | magic `EXMP` |
//! | 4 | 1 | version (2) |
//! | 5 | 1 | kind: 1 sample (robot → controller), 2 command (controller → robot), 3 hello (controller → robot), 4 challenge (robot → controller) |
//! | 6 | 1 | joint count N |
//! | 7 | 1 | reserved, 0 |
//! | 8 | 4 | sequence number (u32, the sender's own counter in this session) |
//! | 12 | 8 | timestamp (u64, ns of the sender's run clock) |
//! | 20 | 2 | payload length (u16) |
//! | 22 | 2 | reserved, 0 |
//! | 24 | L | payload |
//! | 24 + L | 32 | MAC of bytes 0 .. 24 + L: hello and challenge under the handshake key, sample and command under the session key ([`super::session`]) |
//!
//! Decoding never panics: every way a byte string can fail is a [`FrameError`] variant, so the
//! receiver can count it ([`RejectCounts`]). The MAC is checked before any payload field is
//! read, so a frame without the key is rejected whatever it holds.

use super::key::{Key, NONCE_LEN};
use alloc::vec::Vec;
use nalgebra::SVector;
use serde::Serialize;

/// The four magic bytes that start every frame.
pub const MAGIC: [u8; 4] = *b"EXMP";
/// The protocol version this build speaks (2: authenticated; 1 had a CRC-32 and no MAC).
pub const VERSION: u8 = 2;
/// Header length (bytes).
pub const HEADER_LEN: usize = 24;
/// MAC trailer length (bytes): a full 256-bit keyed BLAKE3 output.
pub const MAC_LEN: usize = 32;
/// Largest joint count a frame may carry.
pub const MAX_JOINTS: usize = 16;
/// Planned torques a command carries for the periods after its own (played out by the robot
/// while no newer command arrives: [`RobotCommand::plan`]).
pub const PLAN_LEN: usize = 8;

const KIND_SAMPLE: u8 = 1;
const KIND_COMMAND: u8 = 2;
const KIND_HELLO: u8 = 3;
const KIND_CHALLENGE: u8 = 4;

/// Robot status flags carried by a [`RobotSample`].
pub mod robot_flags {
    /// No valid command arrived for this period: the robot plays out the last command's plan
    /// (rate-limited) while riding through the gap.
    pub const WATCHDOG: u32 = 1;
    /// The robot ended the run (duration reached, stop received or robot shut down).
    pub const END_OF_RUN: u32 = 2;
    /// A sensor of the robot reports a fault (values may be non-finite).
    pub const SENSOR_FAULT: u32 = 4;
    /// The robot made a protective stop (torque ramped to zero and held there); it accepts no
    /// command of this session and waits for a restart at the robot.
    pub const PROTECTIVE_STOP: u32 = 8;
}

/// Controller flags carried by a [`RobotCommand`].
pub mod command_flags {
    /// The controller confirms the handshake (first frame of a session); the torque field is
    /// not applied.
    pub const HELLO: u16 = 1;
    /// The controller stopped: ramp to zero torque and end the session.
    pub const STOP: u16 = 2;
    /// The controller is ramping the torque to zero before a stop.
    pub const RAMP_DOWN: u16 = 4;
}

/// One state sample, robot → controller (the `read()` side of the interface).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RobotSample<const N: usize> {
    /// Robot sequence number (one per period).
    pub seq: u32,
    /// Robot time of the sample (ns since the robot's run start).
    pub stamp_ns: u64,
    /// Robot status flags ([`robot_flags`]).
    pub flags: u32,
    /// Joint angles (rad).
    pub q: SVector<f64, N>,
    /// Joint velocities (rad/s), unfiltered.
    pub qd: SVector<f64, N>,
    /// Strap forces (N), unfiltered, thigh then shank (1-DOF: shank only).
    pub force: SVector<f64, N>,
    /// Joint torque applied over the period that ended at this sample (N·m).
    pub effort: SVector<f64, N>,
}

/// One torque command, controller → robot (the `write()` side of the interface).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RobotCommand<const N: usize> {
    /// Controller sequence number (one per command sent).
    pub seq: u32,
    /// Controller time of sending (ns since the controller's run start).
    pub stamp_ns: u64,
    /// The sample sequence number this command answers.
    pub answers: u32,
    /// Controller flags ([`command_flags`]).
    pub flags: u16,
    /// Controller step status code ([`status_code`]).
    pub status: u8,
    /// Entries of [`RobotCommand::plan`] in use (0 ..= [`PLAN_LEN`]).
    pub plan_len: u8,
    /// SQP iterations of the step.
    pub iterations: u32,
    /// Controller compute time of the step (ns).
    pub compute_ns: u32,
    /// Joint torques (N·m), always finite.
    pub torque: SVector<f64, N>,
    /// The controller's planned torques for the next periods (`plan[j]` for the `j+1`-th
    /// period after this command's), from its last solve; finite.
    pub plan: [SVector<f64, N>; PLAN_LEN],
}

impl<const N: usize> RobotCommand<N> {
    /// A command with torque `torque` and no plan.
    pub fn new(seq: u32, stamp_ns: u64, answers: u32, flags: u16, torque: SVector<f64, N>) -> Self {
        RobotCommand {
            seq,
            stamp_ns,
            answers,
            flags,
            status: 0,
            plan_len: 0,
            iterations: 0,
            compute_ns: 0,
            torque,
            plan: [SVector::zeros(); PLAN_LEN],
        }
    }

    /// The plan entries in use.
    pub fn plan(&self) -> &[SVector<f64, N>] {
        &self.plan[..usize::from(self.plan_len).min(PLAN_LEN)]
    }
}

/// The controller's handshake opening (controller → robot): its fresh nonce.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Hello {
    /// Controller sequence number (informational; hellos are not ordered).
    pub seq: u32,
    /// Controller time of sending (ns).
    pub stamp_ns: u64,
    /// The controller's fresh random nonce of this handshake.
    pub nonce_c: [u8; NONCE_LEN],
}

/// The robot's handshake answer (robot → controller): the controller's nonce echoed and the
/// robot's fresh nonce; both sides derive the session key from the two.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Challenge {
    /// Robot time of sending (ns).
    pub stamp_ns: u64,
    /// The controller's nonce this answers.
    pub nonce_c: [u8; NONCE_LEN],
    /// The robot's fresh random nonce.
    pub nonce_r: [u8; NONCE_LEN],
}

/// A decoded frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Frame<const N: usize> {
    /// Robot → controller.
    Sample(RobotSample<N>),
    /// Controller → robot.
    Command(RobotCommand<N>),
    /// Controller → robot, handshake.
    Hello(Hello),
    /// Robot → controller, handshake.
    Challenge(Challenge),
}

/// Why a byte string is not a valid frame (or not a frame to use).
#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
pub enum FrameError {
    /// Shorter than the header and MAC, or shorter than its header announces.
    #[error("truncated frame ({len} bytes)")]
    Truncated {
        /// Bytes received.
        len: usize,
    },
    /// Does not start with `EXMP`.
    #[error("bad magic")]
    BadMagic,
    /// A protocol version this build does not speak.
    #[error("protocol version {0}, expected {VERSION}")]
    WrongVersion(u8),
    /// Unknown frame kind.
    #[error("unknown frame kind {0}")]
    UnknownKind(u8),
    /// A joint count other than the receiver's.
    #[error("frame for {got} joints, expected {expected}")]
    WrongJoints {
        /// Joint count in the frame.
        got: u8,
        /// Joint count of the receiver.
        expected: usize,
    },
    /// Payload length field or total length inconsistent with the kind and joint count, or a
    /// reserved byte not zero.
    #[error("malformed frame (length or reserved fields)")]
    Malformed,
    /// MAC mismatch: altered, forged, of another session, or under another key.
    #[error("MAC mismatch (altered, forged, other session or wrong key)")]
    BadMac,
    /// A session frame while no session key is established.
    #[error("no session")]
    NoSession,
    /// A command whose torque or plan is not finite (never applied).
    #[error("non-finite torque in command")]
    NonFinite,
    /// A frame of the wrong direction (a sample sent to the robot, a command to the controller).
    #[error("frame of the wrong direction")]
    WrongDirection,
    /// Same sequence number as the last accepted frame.
    #[error("duplicate frame")]
    Duplicate,
    /// Older sequence number than the last accepted frame (a replay or a reordered frame).
    #[error("out-of-order frame")]
    OutOfOrder,
    /// Sequence number further ahead of the last accepted one than the replay window allows
    /// (about 1 s of periods).
    #[error("sequence number too far ahead")]
    TooFarAhead,
    /// Valid but too old to use (a command answering an earlier sample than the current one).
    #[error("stale frame")]
    Stale,
    /// A valid frame the receiver's state does not allow (a hello during an active session or
    /// after a protective stop, a command of a stopped session, a challenge not answering
    /// this controller's hello).
    #[error("frame not allowed in this state")]
    NotAllowed,
    /// A datagram from an address other than the session's peer.
    #[error("datagram from a foreign address")]
    Foreign,
}

/// Counters of rejected frames, one per [`FrameError`] reason.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
pub struct RejectCounts {
    /// [`FrameError::Truncated`].
    pub truncated: u64,
    /// [`FrameError::BadMagic`].
    pub bad_magic: u64,
    /// [`FrameError::WrongVersion`].
    pub wrong_version: u64,
    /// [`FrameError::UnknownKind`].
    pub unknown_kind: u64,
    /// [`FrameError::WrongJoints`].
    pub wrong_joints: u64,
    /// [`FrameError::Malformed`].
    pub malformed: u64,
    /// [`FrameError::BadMac`].
    pub bad_mac: u64,
    /// [`FrameError::NoSession`].
    pub no_session: u64,
    /// [`FrameError::NonFinite`].
    pub non_finite: u64,
    /// [`FrameError::WrongDirection`].
    pub wrong_direction: u64,
    /// [`FrameError::Duplicate`].
    pub duplicate: u64,
    /// [`FrameError::OutOfOrder`].
    pub out_of_order: u64,
    /// [`FrameError::TooFarAhead`].
    pub too_far_ahead: u64,
    /// [`FrameError::Stale`].
    pub stale: u64,
    /// [`FrameError::NotAllowed`].
    pub not_allowed: u64,
    /// [`FrameError::Foreign`].
    pub foreign: u64,
}

impl RejectCounts {
    /// Count one rejection.
    pub fn count(&mut self, e: FrameError) {
        let c = match e {
            FrameError::Truncated { .. } => &mut self.truncated,
            FrameError::BadMagic => &mut self.bad_magic,
            FrameError::WrongVersion(_) => &mut self.wrong_version,
            FrameError::UnknownKind(_) => &mut self.unknown_kind,
            FrameError::WrongJoints { .. } => &mut self.wrong_joints,
            FrameError::Malformed => &mut self.malformed,
            FrameError::BadMac => &mut self.bad_mac,
            FrameError::NoSession => &mut self.no_session,
            FrameError::NonFinite => &mut self.non_finite,
            FrameError::WrongDirection => &mut self.wrong_direction,
            FrameError::Duplicate => &mut self.duplicate,
            FrameError::OutOfOrder => &mut self.out_of_order,
            FrameError::TooFarAhead => &mut self.too_far_ahead,
            FrameError::Stale => &mut self.stale,
            FrameError::NotAllowed => &mut self.not_allowed,
            FrameError::Foreign => &mut self.foreign,
        };
        *c += 1;
    }

    /// Datagrams that are not frames of this protocol at all (truncated, bad magic, wrong
    /// version, unknown kind, malformed).
    pub fn not_frames(&self) -> u64 {
        self.truncated + self.bad_magic + self.wrong_version + self.unknown_kind + self.malformed
    }

    /// All rejections.
    pub fn total(&self) -> u64 {
        self.not_frames()
            + self.wrong_joints
            + self.bad_mac
            + self.no_session
            + self.non_finite
            + self.wrong_direction
            + self.duplicate
            + self.out_of_order
            + self.too_far_ahead
            + self.stale
            + self.not_allowed
            + self.foreign
    }
}

/// Payload length of a sample with `n` joints (bytes): flags, reserved, then q, qd, F, effort.
pub const fn sample_payload_len(n: usize) -> usize {
    8 + 32 * n
}

/// Payload length of a command with `n` joints (bytes): answers, flags, status, plan length,
/// iterations, compute time, the torques, then [`PLAN_LEN`] planned torques.
pub const fn command_payload_len(n: usize) -> usize {
    16 + 8 * n + 8 * n * PLAN_LEN
}

/// Payload length of a hello (bytes): the controller's nonce.
pub const HELLO_PAYLOAD_LEN: usize = NONCE_LEN;
/// Payload length of a challenge (bytes): both nonces.
pub const CHALLENGE_PAYLOAD_LEN: usize = 2 * NONCE_LEN;

/// Total encoded length of a sample with `n` joints (bytes).
pub const fn sample_len(n: usize) -> usize {
    HEADER_LEN + sample_payload_len(n) + MAC_LEN
}

/// Total encoded length of a command with `n` joints (bytes).
pub const fn command_len(n: usize) -> usize {
    HEADER_LEN + command_payload_len(n) + MAC_LEN
}

/// Longest frame for `n` joints (bytes): a buffer this long holds any frame.
pub const fn max_frame_len(n: usize) -> usize {
    let (s, c) = (sample_len(n), command_len(n));
    let m = if s > c { s } else { c };
    let h = HEADER_LEN + CHALLENGE_PAYLOAD_LEN + MAC_LEN;
    if m > h {
        m
    } else {
        h
    }
}

fn header(out: &mut Vec<u8>, kind: u8, n: usize, seq: u32, stamp_ns: u64, payload: usize) {
    out.extend_from_slice(&MAGIC);
    out.push(VERSION);
    out.push(kind);
    out.push(n as u8);
    out.push(0);
    out.extend_from_slice(&seq.to_le_bytes());
    out.extend_from_slice(&stamp_ns.to_le_bytes());
    out.extend_from_slice(&(payload as u16).to_le_bytes());
    out.extend_from_slice(&[0, 0]);
}

fn finish(out: &mut Vec<u8>, start: usize, key: &Key) {
    let tag = key.mac(&out[start..]);
    out.extend_from_slice(&tag);
}

fn put<const N: usize>(out: &mut Vec<u8>, v: &SVector<f64, N>) {
    for x in v.iter() {
        out.extend_from_slice(&x.to_le_bytes());
    }
}

/// Append the encoding of `s` under the session key `key` to `out` (no allocation once `out`
/// has room for [`sample_len`]`(N)` more bytes).
pub fn encode_sample<const N: usize>(s: &RobotSample<N>, key: &Key, out: &mut Vec<u8>) {
    let start = out.len();
    header(
        out,
        KIND_SAMPLE,
        N,
        s.seq,
        s.stamp_ns,
        sample_payload_len(N),
    );
    out.extend_from_slice(&s.flags.to_le_bytes());
    out.extend_from_slice(&0u32.to_le_bytes());
    put(out, &s.q);
    put(out, &s.qd);
    put(out, &s.force);
    put(out, &s.effort);
    finish(out, start, key);
}

/// Append the encoding of `c` under the session key `key` to `out` (no allocation once `out`
/// has room for [`command_len`]`(N)` more bytes). Plan entries past `plan_len` are sent as
/// zeros.
pub fn encode_command<const N: usize>(c: &RobotCommand<N>, key: &Key, out: &mut Vec<u8>) {
    let start = out.len();
    header(
        out,
        KIND_COMMAND,
        N,
        c.seq,
        c.stamp_ns,
        command_payload_len(N),
    );
    let used = usize::from(c.plan_len).min(PLAN_LEN);
    out.extend_from_slice(&c.answers.to_le_bytes());
    out.extend_from_slice(&c.flags.to_le_bytes());
    out.push(c.status);
    out.push(used as u8);
    out.extend_from_slice(&c.iterations.to_le_bytes());
    out.extend_from_slice(&c.compute_ns.to_le_bytes());
    put(out, &c.torque);
    for (j, p) in c.plan.iter().enumerate() {
        put(out, &if j < used { *p } else { SVector::zeros() });
    }
    finish(out, start, key);
}

/// Append the encoding of a hello for `N` joints under the handshake key `key` to `out`.
pub fn encode_hello<const N: usize>(h: &Hello, key: &Key, out: &mut Vec<u8>) {
    let start = out.len();
    header(out, KIND_HELLO, N, h.seq, h.stamp_ns, HELLO_PAYLOAD_LEN);
    out.extend_from_slice(&h.nonce_c);
    finish(out, start, key);
}

/// Append the encoding of a challenge for `N` joints under the handshake key `key` to `out`.
pub fn encode_challenge<const N: usize>(c: &Challenge, key: &Key, out: &mut Vec<u8>) {
    let start = out.len();
    header(out, KIND_CHALLENGE, N, 0, c.stamp_ns, CHALLENGE_PAYLOAD_LEN);
    out.extend_from_slice(&c.nonce_c);
    out.extend_from_slice(&c.nonce_r);
    finish(out, start, key);
}

/// A bounds-checked little-endian reader (never panics: every read is checked before).
struct Rd<'a> {
    b: &'a [u8],
    at: usize,
}

impl Rd<'_> {
    fn bytes<const K: usize>(&mut self) -> [u8; K] {
        let mut a = [0u8; K];
        if let Some(s) = self.b.get(self.at..self.at + K) {
            a.copy_from_slice(s);
        }
        self.at += K;
        a
    }
    fn u8(&mut self) -> u8 {
        self.bytes::<1>()[0]
    }
    fn u16(&mut self) -> u16 {
        u16::from_le_bytes(self.bytes())
    }
    fn u32(&mut self) -> u32 {
        u32::from_le_bytes(self.bytes())
    }
    fn u64(&mut self) -> u64 {
        u64::from_le_bytes(self.bytes())
    }
    fn vec<const N: usize>(&mut self) -> SVector<f64, N> {
        SVector::from_fn(|_, _| f64::from_le_bytes(self.bytes()))
    }
}

/// Decode one frame for a receiver with `N` joints: hello and challenge frames are checked
/// under the handshake key `handshake`, samples and commands under the session key `session`
/// ([`FrameError::NoSession`] without one). Checks, in order: length of header and MAC, magic,
/// version, kind, joint count, payload length and total length, reserved bytes, MAC, and
/// (commands) finite torques. Never panics on any input.
pub fn decode<const N: usize>(
    bytes: &[u8],
    handshake: &Key,
    session: Option<&Key>,
) -> Result<Frame<N>, FrameError> {
    let len = bytes.len();
    if len < HEADER_LEN + MAC_LEN {
        return Err(FrameError::Truncated { len });
    }
    let mut r = Rd { b: bytes, at: 0 };
    if r.bytes::<4>() != MAGIC {
        return Err(FrameError::BadMagic);
    }
    let version = r.u8();
    if version != VERSION {
        return Err(FrameError::WrongVersion(version));
    }
    let kind = r.u8();
    let expected_payload = match kind {
        KIND_SAMPLE => sample_payload_len(N),
        KIND_COMMAND => command_payload_len(N),
        KIND_HELLO => HELLO_PAYLOAD_LEN,
        KIND_CHALLENGE => CHALLENGE_PAYLOAD_LEN,
        k => return Err(FrameError::UnknownKind(k)),
    };
    let joints = r.u8();
    if usize::from(joints) != N {
        return Err(FrameError::WrongJoints {
            got: joints,
            expected: N,
        });
    }
    let reserved1 = r.u8();
    let seq = r.u32();
    let stamp_ns = r.u64();
    let payload = usize::from(r.u16());
    let reserved2 = r.u16();
    if payload != expected_payload {
        return Err(FrameError::Malformed);
    }
    let total = HEADER_LEN + payload + MAC_LEN;
    if len < total {
        return Err(FrameError::Truncated { len });
    }
    if len > total || reserved1 != 0 || reserved2 != 0 {
        return Err(FrameError::Malformed);
    }
    let body = HEADER_LEN + payload;
    let key = match kind {
        KIND_HELLO | KIND_CHALLENGE => handshake,
        _ => session.ok_or(FrameError::NoSession)?,
    };
    if !key.verify(&bytes[..body], &bytes[body..total]) {
        return Err(FrameError::BadMac);
    }
    match kind {
        KIND_SAMPLE => {
            let flags = r.u32();
            let _reserved = r.u32();
            let q = r.vec();
            let qd = r.vec();
            let force = r.vec();
            let effort = r.vec();
            Ok(Frame::Sample(RobotSample {
                seq,
                stamp_ns,
                flags,
                q,
                qd,
                force,
                effort,
            }))
        }
        KIND_COMMAND => {
            let answers = r.u32();
            let flags = r.u16();
            let status = r.u8();
            let plan_len = r.u8();
            let iterations = r.u32();
            let compute_ns = r.u32();
            let torque: SVector<f64, N> = r.vec();
            let mut plan = [SVector::<f64, N>::zeros(); PLAN_LEN];
            for p in plan.iter_mut() {
                *p = r.vec();
            }
            if usize::from(plan_len) > PLAN_LEN {
                return Err(FrameError::Malformed);
            }
            if !torque
                .iter()
                .chain(plan.iter().flatten())
                .all(|v| v.is_finite())
            {
                return Err(FrameError::NonFinite);
            }
            Ok(Frame::Command(RobotCommand {
                seq,
                stamp_ns,
                answers,
                flags,
                status,
                plan_len,
                iterations,
                compute_ns,
                torque,
                plan,
            }))
        }
        KIND_HELLO => Ok(Frame::Hello(Hello {
            seq,
            stamp_ns,
            nonce_c: r.bytes(),
        })),
        _ => {
            let nonce_c = r.bytes();
            let nonce_r = r.bytes();
            Ok(Frame::Challenge(Challenge {
                stamp_ns,
                nonce_c,
                nonce_r,
            }))
        }
    }
}

/// Sequence-number bookkeeping of one direction of a session (the replay window): rejects
/// duplicates and frames older than the last accepted one (the receiver only ever uses the
/// newest frame, so the window behind it is empty), and frames more than `max_ahead` ahead of
/// it (wrap-around safe: "newer" means ahead by less than 2³¹); counts gaps.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SeqTracker {
    last: Option<u32>,
    max_ahead: u32,
    /// Sequence numbers skipped between accepted frames (frames lost or still in flight).
    pub gaps: u64,
}

impl Default for SeqTracker {
    fn default() -> Self {
        SeqTracker::new(u32::MAX >> 1)
    }
}

impl SeqTracker {
    /// A tracker rejecting frames more than `max_ahead` (≥ 1) ahead of the last accepted one.
    pub fn new(max_ahead: u32) -> Self {
        SeqTracker {
            last: None,
            max_ahead: max_ahead.clamp(1, u32::MAX >> 1),
            gaps: 0,
        }
    }

    /// The tracker of one direction of a fresh session: both sides number their frames from 1,
    /// so the first frame may be at most `max_ahead` ahead of 0.
    pub fn session(max_ahead: u32) -> Self {
        SeqTracker {
            last: Some(0),
            ..SeqTracker::new(max_ahead)
        }
    }

    /// The last accepted sequence number.
    pub fn last(&self) -> Option<u32> {
        self.last
    }

    /// Accept `seq` if it is newer than the last accepted one and not too far ahead.
    pub fn accept(&mut self, seq: u32) -> Result<(), FrameError> {
        if let Some(last) = self.last {
            let ahead = seq.wrapping_sub(last) as i32;
            if ahead == 0 {
                return Err(FrameError::Duplicate);
            }
            if ahead < 0 {
                return Err(FrameError::OutOfOrder);
            }
            if ahead as u32 > self.max_ahead {
                return Err(FrameError::TooFarAhead);
            }
            self.gaps += u64::from(ahead as u32 - 1);
        }
        self.last = Some(seq);
        Ok(())
    }
}

/// Wire code of a controller [`StepStatus`](crate::control::StepStatus): its
/// [`code`](crate::control::StepStatus::code).
pub fn status_code(s: crate::control::StepStatus) -> u8 {
    s.code()
}

/// The [`StepStatus`](crate::control::StepStatus) of a wire code (`None` for an unknown code).
pub fn status_from_code(c: u8) -> Option<crate::control::StepStatus> {
    crate::control::StepStatus::from_code(c)
}
