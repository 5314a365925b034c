//! Riding through sensor faults: per-channel fault detection and the estimate that stands in
//! for a rejected channel ([`ChannelGuard`], used by the [`Supervisor`](super::Supervisor)).

use super::Measurement;
#[cfg(not(feature = "std"))]
use crate::math::Float;
use alloc::{boxed::Box, vec, vec::Vec};
use nalgebra::{SMatrix, SVector};

/// Index of the angle, velocity and force signal of a measurement.
const Q: usize = 0;
const QD: usize = 1;
const F: usize = 2;

/// Largest acceleration (rad/s²) an encoder angle may show against its own linear
/// extrapolation before the sample counts as a jump no leg can make: the gate on
/// `|q_k − (2 q̂_{k−1} − q̂_{k−2})|` is `max(JUMP_ACCEL · dt², 0.01 rad)` (0.05 rad at 10 ms).
pub const JUMP_ACCEL: f64 = 500.0;
/// Gate (rad/s) on the filtered velocity against the encoder's mean slope over the filter
/// window (both are the window's mean velocity on a clean sensor).
pub const VELOCITY_GATE: f64 = 0.08;
/// Gate (N) on a filtered strap force against its own linear extrapolation.
pub const FORCE_GATE: f64 = 2.0;
/// A rejected strap force is accepted again on smoothness alone (three smooth fresh samples)
/// after this long (s), whatever its estimate says: a real force must not stay hidden behind
/// its estimate (a jump in the force can be the robot's own doing). A smooth 30-N spike
/// longer than this is believed. 0.1 s believed 200-ms spikes (74.4 / 43.7 N at 0 / 2 kg);
/// 0.3 s rides them through (5.4 / 6.0 N) and, with the slope's window rule and the ungated
/// samples after a re-acceptance, no longer hides the real forces after a 200-ms link outage
/// (test `link_outages_are_ridden_through`: 19.8 N either way; docs/RELIABILITY.md §2a).
pub const FORCE_RESYNC_S: f64 = 0.3;
/// How long (s) an encoder channel (angle or velocity) believed again on smoothness alone
/// stays unverified: a monitor that sees the controller fail tripping within it rejects the
/// channel again ([`ChannelGuard::revoke_unverified`]). A smooth value that disagrees with its
/// estimate may be an offset (a 0.5-rad encoder spike believed after `sensor_timeout_s`), and
/// a controller stepping on it fails within a few steps. Chosen by measurement (the scans of
/// docs/RELIABILITY.md §2a): 0.1, 0.3 and 0.6 s give the same cells; without the rule every
/// sensor's 1-s spike at 1 s, 3 kg, has an RMS of 5.03× clean (3.50× with it), and 1 s raised
/// the same spike at 1.5 s, 3 kg, from 41.1 to 52.2 N.
pub const UNVERIFIED_S: f64 = 0.3;
/// Rate (N/s) at which a strap force believed on smoothness alone ([`FORCE_RESYNC_S`]) moves
/// from the estimate that stood in for it to the measurement: the jump is taken in over
/// `|jump| / FORCE_BIAS_RATE`, so a sensor offset believed after a long fault does not step
/// the controller's force (docs/RELIABILITY.md §2). The same holds for a force accepted again
/// within [`FORCE_RESYNC_S`] of its rejection after it was found frozen: its filter window
/// still averages frozen samples, and their ramp back is accepted where it passes the
/// estimate.
pub const FORCE_BIAS_RATE: f64 = 100.0;
/// Each gate widens to this many times the RMS of the channel's recent residuals (accepted
/// samples, time constant [`RESIDUAL_TAU_S`]) when that is larger: a fast or forceful gait's
/// own innovations are not faults (the fixed gates are for the default gait).
pub const ADAPTIVE_GATE_SIGMAS: f64 = 6.0;
/// Time constant (s) of the residuals' running mean square.
pub const RESIDUAL_TAU_S: f64 = 1.0;
/// A faulted channel is accepted again when it is within this many gates of its estimate.
pub const ACCEPT_GATES: f64 = 4.0;
/// A faulted velocity whose angle has been good over the filter window is accepted again
/// within this many gates of the angle's mean slope over the window (its estimate, a
/// measurement of the same quantity that does not drift: with [`ACCEPT_GATES`] the ramp back
/// of a frozen filtered velocity was accepted 0.17 rad/s off and the controller pushed on it).
/// The same for a velocity whose angle is rejected too ([`JOINT_LOST_LIMIT_FACTOR`]), judged
/// against its estimate there (the gait replay; before the period is known, the controller's
/// model prediction): a filtered velocity ramps into a 0.5-rad/s spike over its window, and
/// within [`ACCEPT_GATES`] of the replay it was accepted again on the sample after its
/// rejection, 0.14 rad/s off, then believed with the whole spike (every sensor's 1-s spike at
/// 4 s, 3 kg: 81.9 N, 14.2 N with this). Chosen by measurement (docs/RELIABILITY.md §2).
pub const SLOPE_ACCEPT_GATES: f64 = 1.5;
/// A velocity whose angle is measured, or a strap force, may stay rejected this many times
/// longer than an angle before the protective stop: its estimate stays anchored to measured
/// channels (measured on the 1-s fault grid, docs/RELIABILITY.md §2).
pub const ANCHORED_LIMIT_FACTOR: u64 = 4;
/// An encoder channel of a joint whose angle and velocity are both rejected is believed on
/// smoothness alone, and trips the persistent-fault limit (the protective stop), only after
/// this many times `sensor_timeout_s` (a channel rejected again,
/// [`ChannelGuard::revoke_unverified`], at once). Its estimate is the gait replayed one period
/// back (before the gait period is known, the controller's model prediction), and while every
/// encoder is rejected the torque is replayed one period back (before the period is known,
/// extrapolated): the replay follows the leg for about a period, while a smooth value that
/// disagrees with its estimate after `sensor_timeout_s` was mostly an offset (every sensor's
/// 1-s spike at 3 s, 3 kg: 74.0 N, 16.3 N with 2; at 1.5 s, before the period is known: 75.9 N,
/// 41.1 N), and the stop leaves the person carrying robot and payload. Measured on the 1-s scan
/// (docs/RELIABILITY.md §2; 3 gave the same cells with the period known).
pub const JOINT_LOST_LIMIT_FACTOR: u64 = 2;
/// An encoder angle repeated bit for bit while the joint moves faster than this (rad/s) is
/// stuck: the floor of the speed threshold, raised for a coarse encoder
/// ([`ChannelGuard::with_encoder_step`]).
pub const STUCK_SPEED: f64 = 0.05;
/// Shortest span (periods) of angles accepted after an angle fault whose slope, moved back by the
/// filter's lag, stands for the velocity while the filter window still holds estimates
/// ([`ChannelGuard`]).
pub const PARTIAL_SLOPE_SPAN: usize = 2;
/// Longest time (s) a rejected strap force follows the forces' continuation at the gait
/// frequency ([`TorqueExtrapolation`] fitted to the forces of the last [`EXTRAPOLATION_FIT_S`]
/// at the fault's start), while every encoder is measured; after it, or with an encoder lost,
/// the estimate replays the gait one period back (continuous with the continuation), or holds
/// before the gait period is known. Chosen by measurement (docs/RELIABILITY.md §2).
pub const FORCE_FIT_S: f64 = 0.3;
/// Weight of the gait replay in a rejected strap force's estimate while it follows its
/// continuation ([`FORCE_FIT_S`]) with the gait period known: the estimate is
/// `(1 − w) · continuation + w · replay`, the replay the force one period back with the offset
/// it had at the fault's start (the lag matched then). The continuation misses a gait whose
/// shape changes within the fault, the replay one that changed since the period before (the
/// human grows heavier, docs/MODEL.md §2): a 200-ms NaN of both forces at 2.25 s, 3 kg, 14.1 N
/// continued, 9.9 N blended; at 2.5 s, 8.9 → 10.7 N. Chosen by measurement
/// (docs/RELIABILITY.md §2).
pub const FORCE_REPLAY_WEIGHT: f64 = 0.4;
/// With the gait period known, a strap force's continuation may leave the range of the forces
/// it was fitted to by this fraction of that range on either side (the torque's
/// [`TorqueExtrapolation`] stays within it): forces that grow from one step of the gait to the
/// next (the human grows heavier) were held at the last second's extreme. Chosen by measurement
/// (docs/RELIABILITY.md §2).
pub const FORCE_RANGE_MARGIN: f64 = 0.25;
/// Samples of the angles over which the replay's lag is matched: the lag within
/// [`PERIOD_MATCH_SPAN`] of the supervisor's gait period at which the last this many angles
/// best equal (least squares) the angles that lag back. The supervisor's period is the time
/// between the last two upward crossings, one cycle old: while the gait's frequency changes
/// it was 107 steps where the angles repeat after 101, and the replayed strap forces fell
/// 1 N behind within 0.1 s (docs/RELIABILITY.md §2).
pub const PERIOD_MATCH_STEPS: usize = 20;
/// Fraction of the supervisor's gait period within which the replay's lag is matched
/// ([`PERIOD_MATCH_STEPS`]).
pub const PERIOD_MATCH_SPAN: f64 = 0.15;
/// Steps between matches of the replay's lag while every channel is good (while one is
/// rejected, and when the supervisor's period changes, it is matched at every step).
pub const PERIOD_MATCH_EVERY: u32 = 10;

/// Per-channel sensor-fault detection and the estimate that replaces a rejected channel.
///
/// Each channel (angle, filtered velocity, filtered strap force of each joint) is rejected when its
/// sample is non-finite or out of range (in the same sample), repeated bit for bit (a frozen
/// sensor: an angle only while the joint moves faster than [`STUCK_SPEED`], or than twice a
/// coarse encoder's step per period, [`ChannelGuard::with_encoder_step`], and on its first
/// repeat only where the angles' extrapolation moves it by more than four steps; a filtered
/// velocity on its second repeat in a row, its first with a window of one sample; a filtered
/// force on its first), or outside its
/// innovation gate: an angle further than `max(`[`JUMP_ACCEL`]`·dt², 0.01)` from its linear
/// extrapolation (a jump no leg can make), a velocity further than [`VELOCITY_GATE`] from the
/// encoder's mean slope over the filter window (what a clean filtered velocity equals; after an
/// angle fault, until the window holds accepted angles only, their slope over at least
/// [`PARTIAL_SLOPE_SPAN`] periods moved back by the filter's lag, else its linear extrapolation), a
/// force further than [`FORCE_GATE`] from its linear extrapolation moved by the robot's own part of
/// the force ([`ChannelGuard::with_straps`]). A rejected channel is estimated: an angle by
/// integrating its good velocity, a velocity from its good angle's slope (the same slope: a slope
/// across the jump from an estimate back to the measurement is not used, and with fewer accepted
/// angles the velocity counts as one whose angle is lost), and a channel whose
/// partner is lost too (or a force) by replaying the gait one period back (the supervisor's gait
/// period, the lag matched on the angles near it: [`PERIOD_MATCH_STEPS`]) with the offset it had when the replay began (added once; a new period estimate
/// restarts the replay where it is), or, without a known period, by holding (an angle:
/// integrating the estimated velocity); a strap force, while every encoder is measured, first
/// follows its continuation at the gait frequency for [`FORCE_FIT_S`] (with the period known,
/// blended with the replay, [`FORCE_REPLAY_WEIGHT`]), and one whose measurement moves smoothly
/// is followed under its offset (`ChannelGuard::follow_offset`). A rejected channel is
/// accepted again once a fresh sample lies within [`ACCEPT_GATES`] gates of its estimate
/// ([`SLOPE_ACCEPT_GATES`] for a velocity estimated from its good angle's slope, or whose angle
/// is lost too; a filtered velocity or force also moving like its estimate, within one gate),
/// or, after `resync_after` steps ([`JOINT_LOST_LIMIT_FACTOR`] times that for both encoders of
/// a joint), once three fresh samples are smooth (the estimate then jumps to it: the
/// supervisor's rate limit bounds the torque step; a strap force that moves along its estimate, an offset, moves
/// from it to the measurement at [`FORCE_BIAS_RATE`]; a velocity estimated from its good angle's
/// slope, a measurement of the same quantity, is never accepted on smoothness alone; a velocity
/// rejected only by the stall rule is accepted once it is fresh and smooth after the filter
/// window, and with its angle still rejected, measured over the window before the stall, the
/// angles of the stall's steps are rewritten as the velocities received then imply them,
/// [`Repaired::q_from_velocity`]). The two
/// samples after a re-acceptance are not gated: the extrapolation still runs through the
/// estimate. An encoder channel believed on smoothness alone stays unverified for
/// [`UNVERIFIED_S`] and is rejected again on request ([`ChannelGuard::revoke_unverified`]).
#[derive(Clone, Debug)]
pub struct ChannelGuard<const N: usize> {
    dt: f64,
    /// The encoders' angle step (rad; 0: exact angles, [`ChannelGuard::with_encoder_step`]).
    encoder_step: f64,
    /// Filter window of the velocity and force channels (samples).
    window: usize,
    bounds: [f64; 3],
    gates: [f64; 3],
    /// Estimate history per signal (ring of `len` samples).
    hist: [Vec<SVector<f64, N>>; 3],
    /// Time of the last measurement (s; NaN before the first).
    last_t: f64,
    pos: usize,
    filled: usize,
    /// Raw previous two samples per signal (bit-exact repeats, smoothness).
    raw: [[SVector<f64, N>; 2]; 3],
    /// Fault state per signal and joint: steps since the channel was rejected (0 = good).
    bad_for: [[u64; N]; 3],
    /// Replay offset per signal and joint (NaN: not replaying).
    offset: [SVector<f64, N>; 3],
    /// Per signal and joint: consecutive steps the estimate has been the replay (from `p`
    /// on, the value a period back is itself a replayed one and carries the offset); reset
    /// where a replay takes its offset, so meaningful while the offset is finite.
    replayed_for: [[u32; N]; 3],
    /// Consecutive fresh, smooth raw samples of a rejected channel.
    smooth: [[u32; N]; 3],
    /// Rejected channels: steps on which some channel was estimated, fault episodes.
    estimated_steps: u64,
    episodes: u64,
    /// Largest residual over its gate of an accepted sample, per signal (the detectors'
    /// margin on this run: below 1 nothing fired on a residual).
    peak_ratio: [f64; 3],
    /// Running mean square of the accepted residuals per signal and joint.
    res_ms: [SVector<f64, N>; 3],
    res_alpha: f64,
    /// Per strap: the force's current rejection began with a full-scale reading.
    railed: [bool; N],
    /// Samples after a re-acceptance whose innovation is not gated (the extrapolation still
    /// runs through the estimate that stood in for the channel).
    after_accept: [[u8; N]; 3],
    /// Per encoder signal (q, qd) and joint: steps since the channel was believed again on
    /// smoothness alone while it disagreed with its estimate (0: not so, or longer ago than
    /// [`UNVERIFIED_S`]), and the steps it had been rejected then.
    unverified: [[u32; N]; 2],
    unverified_bad_for: [[u64; N]; 2],
    /// Per encoder signal and joint: a channel rejected again by
    /// [`ChannelGuard::revoke_unverified`] is accepted no sooner than this many steps into
    /// its fault (0: no such floor).
    accept_floor: [[u64; N]; 2],
    /// Per encoder signal and joint: rejected again since it was last accepted. Its estimate
    /// was built on the samples it was believed on, so its next acceptance, by agreement too,
    /// is unverified again.
    revoked: [[bool; N]; 2],
    /// Per joint: consecutive accepted angle samples (the angle's slope over the filter
    /// window stands for the velocity once the window holds no estimate; the slope over the
    /// accepted ones, moved back by the filter's lag, from [`PARTIAL_SLOPE_SPAN`] periods of
    /// them). Counted from the last gap in the data and the first sample kept in the history
    /// after it ([`ChannelGuard::restart_counts`]).
    q_good_for: [u32; N],
    /// Per joint: consecutive accepted velocity samples before this step (counted as
    /// `q_good_for`).
    qd_good_for: [u32; N],
    /// Per joint: samples left during which the velocity is not accepted again, because its
    /// filter window may still hold faulty samples: a filter window after a stalled
    /// acquisition (every angle frozen or invalid at once, one frozen), `window − 1` after it
    /// was found frozen (once it moves, the window still averages frozen samples).
    qd_held_off: [u32; N],
    /// Per joint, while the angle is rejected: its fault began after a filter window of
    /// accepted angles and its estimate has been the angle its measured velocity implies on
    /// every step since (so it is anchored to measured angles).
    q_anchored: [bool; N],
    /// Per joint: the angle was rejected as frozen and has repeated that value since.
    q_frozen: [bool; N],
    /// The strap model `(ks J, τ = cs/ks)` (docs/MODEL.md §4), when known: the force gate
    /// then judges the filtered force less the robot's own part of it
    /// ([`ChannelGuard::with_straps`]).
    straps: Option<(SMatrix<f64, N, N>, f64)>,
    /// The robot's part `ks J (q̄ + τ q̇̄)` of the filtered strap forces at the last two
    /// steps (NaN when unknown).
    robot_part: [SVector<f64, N>; 2],
    /// The gait period (steps) of the last step's replays.
    replay_period: Option<usize>,
    /// Per strap: the bias added to a force believed on smoothness alone, or accepted again
    /// soon after a frozen fault, fading to zero at [`FORCE_BIAS_RATE`].
    force_bias: SVector<f64, N>,
    /// Per strap: its current fault found the filtered force frozen (a finite bit-for-bit
    /// repeat: a stuck or dropped-out sensor).
    force_frozen: [bool; N],
    /// The supervisor's gait period (steps) and the replay lag matched to it
    /// ([`PERIOD_MATCH_STEPS`]), and the steps since that match.
    matched: Option<(usize, usize)>,
    match_age: u32,
    /// The strap forces' continuation fitted at the start of the current force fault
    /// ([`FORCE_FIT_S`]; boxed in `new`: the guard is built on the firmware's stack), and the
    /// steps since (`u32::MAX` once an encoder was lost in the fault: it is not followed
    /// again).
    force_fit: Box<Option<TorqueExtrapolation<N>>>,
    force_fit_age: u32,
    /// The replay lag the continuation is blended with ([`FORCE_REPLAY_WEIGHT`]; 0: the
    /// period was unknown at the fault's start).
    blend_lag: usize,
    /// Per strap: its estimate is the continuation on this step.
    fit_used: [bool; N],
    /// Per strap: whether its current fault's force is followed under its offset
    /// ([`ChannelGuard::follow_offset`]).
    follow: [OffsetFollow; N],
    /// The filtered velocities received since a stalled acquisition was found (the stall rule
    /// holds them off), and how many are held (`None`: no stall since, or more than the buffer
    /// holds): when they prove fresh, the angles of those steps are the ones they imply
    /// ([`ChannelGuard::angles_through_stall`]).
    stall_qd: Vec<SVector<f64, N>>,
    stall_len: Option<usize>,
    /// Per joint: the velocity's current rejection is the stall rule's hold-off alone (it was
    /// neither frozen nor out of range since).
    qd_stall_only: [bool; N],
    /// Per joint: the angles of the filter window before the last stall were measured (the
    /// anchors of [`ChannelGuard::angles_through_stall`]).
    stall_anchored: [bool; N],
    /// Consecutive steps (from the first kept sample) on which no channel was rejected and no
    /// strap force carried a bias: the history a continuation is fitted to holds measurements
    /// alone when it spans no more.
    clean_steps: u32,
    /// The current force fault's continuation was fitted to such a history.
    fit_clean: bool,
}

/// A rejected strap force followed under its offset ([`ChannelGuard::follow_offset`]); the
/// values in `f32` (N), as the `d̂` history: the guard is built on the Cortex-M7's stack, and
/// the image is within its RAM goal by less than 200 B (docs/EMBEDDED.md).
#[derive(Clone, Copy, Debug, PartialEq)]
enum OffsetFollow {
    /// Not followed in the current fault yet; it may be.
    Ready,
    /// Not followed in the current fault: the history before it was not clean, an encoder
    /// was lost within it, or a gap in the data came within it.
    Barred,
    /// Followed: the estimate is the measurement plus `offset`; `regular` is the estimate it
    /// replaced on this step, the forces' continuation when `continued`.
    Offset {
        offset: f32,
        regular: f32,
        continued: bool,
    },
    /// The measurement stopped moving smoothly: the estimate goes on from its last value by
    /// the steps of the estimate it replaces (`regular` and `continued` as above).
    Continued { regular: f32, continued: bool },
}

/// Which channels of a measurement stand in for rejected ones and must not update a
/// model-based estimator: an angle, and a velocity whose angle is rejected too (a velocity
/// estimated from its good angle's slope is a measurement of it and not listed).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EstimatedChannels<const N: usize> {
    /// Per joint: the angle is an estimate.
    pub q: [bool; N],
    /// Per joint: the velocity is an estimate not derived from a measured angle.
    pub qd: [bool; N],
    /// Per strap: the force is an estimate.
    pub force: [bool; N],
    /// The gait period in control steps, when the guard knows it (the lag of its replay).
    pub period: Option<usize>,
    /// While the strap forces follow their continuation at the gait frequency
    /// ([`FORCE_FIT_S`]): that frequency (rad/s), at which a model-based estimator may continue
    /// what the forces carry. With the gait period known, only for a continuation fitted to
    /// measurements alone (no channel rejected and no force biased over the fit's history: one
    /// fitted across an earlier fault continues that fault); else the MS-NMPC replays `d̂`.
    /// Also while such a force is followed under its offset instead (the continuation is its
    /// estimate's reference then; measured so, docs/RELIABILITY.md §2).
    pub gait_omega: Option<f64>,
    /// An angle that stood in for a rejected one as a measurement (implied by its measured
    /// velocity, [`Repaired::q_from_velocity`]) is measured again, further than its gate from
    /// the implied angle's extrapolation (up to [`ACCEPT_GATES`] gates, or any distance when
    /// resynchronised): a jump no leg makes, so a model-based estimator restarts its states
    /// at this measurement, as after listed estimates, instead of updating on the jump. Also
    /// on the step the angles of a stall take over from the velocities received through it
    /// (from the estimates that stood in for them).
    pub resume: bool,
}

impl<const N: usize> EstimatedChannels<N> {
    /// Some angle or velocity is an estimate.
    pub fn any_encoder(&self) -> bool {
        self.q.iter().chain(&self.qd).any(|&e| e)
    }

    /// Some strap force is an estimate.
    pub fn any_force(&self) -> bool {
        self.force.iter().any(|&e| e)
    }

    /// Some channel is an estimate.
    pub fn any(&self) -> bool {
        self.any_encoder() || self.any_force()
    }
}

/// What [`ChannelGuard::repair`] made of a measurement.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Repaired<const N: usize> {
    /// The measurement with every rejected channel replaced by its estimate.
    pub m: Measurement<N>,
    /// Some channel was rejected this step.
    pub any_rejected: bool,
    /// Some channel is non-finite, out of range or frozen this step: a sensor fault that no
    /// controller can cause (an innovation-gate rejection can be a real, fast motion).
    pub definite_fault: bool,
    /// The channels that stand in for rejected ones.
    pub estimated: EstimatedChannels<N>,
    /// Longest time (s) a channel has been rejected, 0 when all are good; a velocity whose
    /// angle is measured and a strap force count [`ANCHORED_LIMIT_FACTOR`] times slower; an
    /// encoder channel of a joint whose angle and velocity are both rejected counts
    /// [`JOINT_LOST_LIMIT_FACTOR`] times slower (not after a rejection again).
    pub longest_fault_s: f64,
    /// Every encoder channel (angle, velocity) is good.
    pub encoders_good: bool,
    /// The estimate is usable (at least one measurement has been accepted).
    pub ready: bool,
    /// Every angle turned frozen or invalid in this sample, at least one frozen (a stalled
    /// acquisition): the velocities were rejected with them (for a filter window; fresh after
    /// it, they imply the angles, [`Repaired::q_from_velocity`]).
    pub stalled: bool,
    /// Per joint: the angle is rejected and its estimate has been, on every step since it was
    /// last accepted, the angle its measured velocity implies through the filter window
    /// (listed in `estimated.q`, but anchored to the measured angles by measured velocities, as
    /// a velocity estimated from its good angle's slope is a measurement of it: a model-based
    /// estimator may update with it). After a stall of the angles alone, from the step the
    /// velocities are accepted again: the angles of the held-off steps are rewritten as the
    /// velocities received then imply them.
    pub q_from_velocity: [bool; N],
}

impl<const N: usize> ChannelGuard<N> {
    /// History kept for the gait replay (s): periods longer than this are not replayed.
    pub const HISTORY_S: f64 = 3.0;

    /// For samples every `dt` s through a `window`-sample moving average (velocities, forces);
    /// `bounds` are the plausible `|q|`, `|qd|` and (strictly below) `|F|`.
    pub fn new(dt: f64, window: usize, bounds: [f64; 3]) -> Self {
        let dt = if dt.is_finite() && dt > 0.0 { dt } else { 0.01 };
        let len = ((Self::HISTORY_S / dt).ceil() as usize).clamp(8, 1 << 16);
        let gates = [(JUMP_ACCEL * dt * dt).max(0.01), VELOCITY_GATE, FORCE_GATE];
        ChannelGuard {
            dt,
            encoder_step: 0.0,
            window: window.clamp(1, 1000),
            bounds,
            gates,
            hist: core::array::from_fn(|_| vec![SVector::zeros(); len]),
            pos: 0,
            filled: 0,
            raw: [[SVector::repeat(f64::NAN); 2]; 3],
            bad_for: [[0; N]; 3],
            offset: [SVector::repeat(f64::NAN); 3],
            replayed_for: [[0; N]; 3],
            smooth: [[0; N]; 3],
            estimated_steps: 0,
            episodes: 0,
            peak_ratio: [0.0; 3],
            res_ms: [SVector::zeros(); 3],
            res_alpha: 1.0 - (-dt / RESIDUAL_TAU_S).exp(),
            railed: [false; N],
            after_accept: [[0; N]; 3],
            unverified: [[0; N]; 2],
            unverified_bad_for: [[0; N]; 2],
            accept_floor: [[0; N]; 2],
            revoked: [[false; N]; 2],
            q_good_for: [0; N],
            qd_good_for: [0; N],
            qd_held_off: [0; N],
            q_anchored: [false; N],
            q_frozen: [false; N],
            last_t: f64::NAN,
            straps: None,
            robot_part: [SVector::repeat(f64::NAN); 2],
            replay_period: None,
            force_bias: SVector::zeros(),
            force_frozen: [false; N],
            force_fit: Box::new(None),
            force_fit_age: 0,
            blend_lag: 0,
            fit_used: [false; N],
            follow: [OffsetFollow::Ready; N],
            stall_qd: vec![SVector::zeros(); window.clamp(1, 1000) + 3],
            stall_len: None,
            qd_stall_only: [false; N],
            stall_anchored: [false; N],
            clean_steps: 0,
            fit_clean: false,
            matched: None,
            match_age: 0,
        }
    }

    /// The encoders' angle step `step` (rad, ≥ 0): an angle repeated bit for bit is frozen only
    /// while its joint moves faster than `max(STUCK_SPEED, 2 step / dt)` (a quantised angle
    /// repeats while the joint moves less than a step per period), and, on its first repeat,
    /// only where the angles' own extrapolation moves it by more than 4 steps (a turn between
    /// two samples). 0: exact angles.
    pub fn with_encoder_step(mut self, step: f64) -> Self {
        if step.is_finite() && step > 0.0 {
            self.encoder_step = step;
        }
        self
    }

    /// The same guard with the strap model `F = ks J (Δq + τ Δq̇)`, `Δq = q_H − q_R` (paper
    /// eqs. 3-4): `ks_j` is `ks J`, `tau` is `cs/ks`. The force gate, the acceptance of a
    /// rejected force and its smoothness test then judge the filtered force less the robot's
    /// own part of it, `ks J (q̄_R + τ q̇̄_R)` averaged over the filter window (from the
    /// measured angles), which leaves the person's part `ks J (q̄_H + τ q̇̄_H)`. Without it a
    /// strap force that followed the robot's own fast motion (the controller resuming after a
    /// protective stop at 2 kg, its torque stepping at the rate limit) was rejected as a
    /// spike, and the controller, stepping on the estimate, drove the robot on into the
    /// person (164.9 N; docs/RELIABILITY.md §2).
    pub fn with_straps(mut self, ks_j: SMatrix<f64, N, N>, tau: f64) -> Self {
        let ok = ks_j.iter().all(|v| v.is_finite()) && tau.is_finite() && tau >= 0.0;
        self.straps = ok.then_some((ks_j, tau));
        self
    }

    /// The strap model's `ks J` given by [`Self::with_straps`], if any.
    pub(crate) fn strap_stiffness_map(&self) -> Option<SMatrix<f64, N, N>> {
        self.straps.map(|(ks_j, _)| ks_j)
    }

    /// The robot's motion of joint `i` as the straps feel it through the filter window,
    /// `q̄_i + τ q̇̄_i`, with this step's angle `q` and the window's earlier angles from the
    /// history; NaN without the strap model, or unless the angles of the window and of the
    /// sample before it are measured (an estimate's step back to the measurement is no motion
    /// of the robot).
    fn joint_motion(&self, q: f64, i: usize) -> f64 {
        let Some((_, tau)) = self.straps else {
            return f64::NAN;
        };
        let w = self.window;
        if self.filled < w + 1 || (self.q_good_for[i] as usize) < w + 1 {
            return f64::NAN;
        }
        let q = |m: usize| if m == 0 { q } else { self.back(Q, m)[i] };
        let mean = (0..w).map(q).sum::<f64>() / w as f64;
        // The window's mean velocity: central differences at its inner samples, the
        // three-point backward difference at the newest (exact for a quadratic, five times
        // closer than the window's secant for a cubic).
        let rate = if w >= 3 {
            (4.0 * q(0) - 3.0 * q(1) + q(2) - q(w - 1) - q(w)) / (2.0 * w as f64 * self.dt)
        } else {
            (q(0) - q(1)) / self.dt
        };
        mean + tau * rate
    }

    /// Steps on which some channel was estimated.
    pub fn estimated_steps(&self) -> u64 {
        self.estimated_steps
    }

    /// Channel fault episodes (a channel rejected after being good).
    pub fn episodes(&self) -> u64 {
        self.episodes
    }

    /// Largest residual of an accepted sample over its gate, per signal (q, qd, F).
    pub fn peak_ratio(&self) -> [f64; 3] {
        self.peak_ratio
    }

    /// Reject again every encoder channel believed on smoothness alone within the last
    /// [`UNVERIFIED_S`] (the supervisor calls it when a monitor that sees the controller fail
    /// trips: the believed value is taken to be an offset). Each continues its fault where it
    /// was accepted, so the persistent-fault limit applies (an angle's is past it: the
    /// protective stop; a velocity whose angle is measured counts [`ANCHORED_LIMIT_FACTOR`]
    /// times slower), and is not accepted again for another `resync_after` steps (as `repair`
    /// takes them); its next acceptance is unverified again. Returns how many were rejected
    /// again.
    pub fn revoke_unverified(&mut self, resync_after: u64) -> u32 {
        let mut revoked = 0;
        for sig in [Q, QD] {
            for j in 0..N {
                if self.unverified[sig][j] == 0 || self.bad_for[sig][j] > 0 {
                    continue;
                }
                let resumed = self.unverified_bad_for[sig][j].max(1);
                self.bad_for[sig][j] = resumed;
                self.accept_floor[sig][j] = resumed.saturating_add(resync_after);
                self.revoked[sig][j] = true;
                self.unverified[sig][j] = 0;
                self.after_accept[sig][j] = 0;
                self.smooth[sig][j] = 0;
                self.offset[sig][j] = f64::NAN;
                if sig == Q {
                    self.q_anchored[j] = false;
                    self.q_good_for[j] = 0;
                } else {
                    self.qd_good_for[j] = 0;
                }
                revoked += 1;
            }
        }
        revoked
    }

    /// True while the channel `signal` (0 q, 1 qd, 2 F) of `joint` is rejected.
    pub fn is_rejected(&self, signal: usize, joint: usize) -> bool {
        self.bad_for[signal][joint] > 0
    }

    /// The replay's lag for the supervisor's gait period `p0` (steps): the lag within
    /// [`PERIOD_MATCH_SPAN`] of `p0` at which the last [`PERIOD_MATCH_STEPS`] angles best
    /// match those one lag back, `argmin_p Σ_j |q(k−j) − q(k−j−p)|²` (the first of equals;
    /// `p0`, not kept, while the history is shorter than the whole range needs). Matched every
    /// [`PERIOD_MATCH_EVERY`] calls, and at every call while a channel is rejected or when `p0`
    /// changes.
    fn replay_lag(&mut self, p0: usize) -> usize {
        let busy = self.bad_for.iter().flatten().any(|&b| b > 0);
        if let Some((c, p)) = self.matched {
            if c == p0 && !busy && self.match_age + 1 < PERIOD_MATCH_EVERY {
                self.match_age += 1;
                return p;
            }
        }
        let w = PERIOD_MATCH_STEPS;
        let avail = self.filled.min(self.hist[Q].len());
        let lo = ((p0 as f64) * (1.0 - PERIOD_MATCH_SPAN)).floor().max(2.0) as usize;
        let hi = ((p0 as f64) * (1.0 + PERIOD_MATCH_SPAN)).ceil() as usize;
        if hi + w + 3 > avail {
            // A range cut short would drop `p0` and the lags above it.
            return p0;
        }
        let mut best = (f64::INFINITY, p0);
        for p in lo..=hi {
            let cost: f64 = (1..=w)
                .map(|j| (self.back(Q, j) - self.back(Q, j + p)).norm_squared())
                .sum();
            if cost < best.0 {
                best = (cost, p);
            }
        }
        self.matched = Some((p0, best.1));
        self.match_age = 0;
        best.1
    }

    /// The history slot of the sample `steps` steps back (1: the last one kept).
    fn slot(&self, steps: usize) -> usize {
        let len = self.hist[0].len();
        (self.pos + len - steps % len) % len
    }

    fn back(&self, sig: usize, steps: usize) -> SVector<f64, N> {
        self.hist[sig][self.slot(steps)]
    }

    /// Detect faulty channels of `m` and replace them by their estimates; `period_s` is the
    /// gait period, if known, for the replay; `model` the controller's own model prediction
    /// of `(q, qd)` ([`Controller::predicted_state`](super::Controller::predicted_state)),
    /// which replaces rejected encoder channels when given; `resync_after` the steps after
    /// which a rejected channel is accepted on smoothness alone.
    pub fn repair(
        &mut self,
        m: &Measurement<N>,
        period_s: Option<f64>,
        resync_after: u64,
        model: Option<(SVector<f64, N>, SVector<f64, N>)>,
    ) -> Repaired<N> {
        // A gap in the data (the runtime does not step the controller in a period without a
        // sample): the extrapolations and the stuck test assume one period per call, so they
        // restart from this sample, as the EKF bank resumes (`EkfBank::resume_at`).
        if m.t - self.last_t > 1.5 * self.dt {
            self.filled = 0;
            self.matched = None;
            self.force_bias = SVector::zeros();
            self.force_frozen = [false; N];
            *self.force_fit = None;
            self.robot_part = [SVector::repeat(f64::NAN); 2];
            // A channel rejected again is accepted as any other after a gap (unverified).
            self.accept_floor = [[0; N]; 2];
            self.stall_len = None;
            // A force fault that goes on across the gap is not followed.
            self.follow = [OffsetFollow::Barred; N];
            self.restart_counts();
        }
        self.last_t = m.t;
        let unverified_steps = (UNVERIFIED_S / self.dt).ceil() as u32;
        let warm = self.filled > self.window + 2;
        let vals = [m.q, m.qd, m.force];
        let mut out = vals;
        let mut any = false;
        let mut definite = false;
        let mut longest: u64 = 0;
        let mut q_from_velocity = [false; N];
        // Per joint, the robot's motion as the straps feel it, and per strap, the robot's part
        // of the filtered force (`joint_motion`; NaN when unknown).
        let mut motion = SVector::<f64, N>::repeat(f64::NAN);
        let mut robot_part = SVector::<f64, N>::repeat(f64::NAN);
        let mut estimated = EstimatedChannels {
            q: [false; N],
            qd: [false; N],
            force: [false; N],
            period: None,
            gait_omega: None,
            resume: false,
        };
        let period = period_s
            .filter(|p| p.is_finite() && *p > 0.0)
            .map(|p| (p / self.dt).round() as usize)
            .filter(|&p| p >= 2 && p + 2 < self.filled.min(self.hist[0].len()))
            .map(|p| self.replay_lag(p));
        // A new gait-period estimate within a replay restarts it, continuous with the
        // estimate it replaces: the old offset against the new lag made the replay step (a
        // 200-ms force spike at 3 kg: the period went from 107 to 101 steps within the fault
        // and the estimated forces stepped by 3 N).
        if period != self.replay_period {
            self.offset = [SVector::repeat(f64::NAN); 3];
        }
        self.replay_period = period;
        // Linear extrapolations of the estimates, and the mean slope of the angle over the
        // filter window (what a clean filtered velocity equals).
        let pred: [SVector<f64, N>; 3] =
            core::array::from_fn(|s| self.back(s, 1) * 2.0 - self.back(s, 2));
        let span = self.window_span();
        let force_resync = (FORCE_RESYNC_S / self.dt).ceil().max(1.0) as u64;
        // Every angle frozen or out of range in the same sample, at least one frozen: the
        // acquisition stalled (it delivers no new samples), and the filtered velocities of the
        // same encoders still move on the samples before the stall for `window − 1` samples:
        // they are rejected with the angles. Angles that are all non-finite or out of range
        // are invalid readings, not a stall: the velocities, fresh, are judged on their own
        // and imply the angles (rejecting them too made a 60-ms NaN of both angles at 3 kg
        // the loss of every encoder: 22.1 N). Velocities still fresh after the window (a stalled
        // one has frozen by then) show that only the angles failed: they are accepted on their
        // own and imply the angles of the whole fault (`angles_through_stall`).
        let angle_in_range =
            |j: usize| vals[Q][j].is_finite() && vals[Q][j].abs() <= self.bounds[Q];
        // (On the joint's velocity alone: a stall at one joint's turn is still a stall.)
        let angle_frozen = |j: usize| {
            angle_in_range(j)
                && vals[Q][j].to_bits() == self.raw[Q][0][j].to_bits()
                && self.moving(vals[QD][j], j)
        };
        let stall = warm
            && (0..N).all(|j| self.bad_for[Q][j] == 0 && (!angle_in_range(j) || angle_frozen(j)))
            && (0..N).any(angle_frozen);
        if stall {
            self.stall_len = Some(0);
            self.stall_anchored = core::array::from_fn(|j| self.q_good_for[j] as usize >= span);
        }
        if let Some(n) = self.stall_len {
            self.stall_len = self.stall_qd.get_mut(n).map(|slot| {
                *slot = vals[QD];
                n + 1
            });
        }
        for j in 0..N {
            // The velocity the accepted angles give (`angle_velocity`), once the angle's verdict
            // is in: the velocity's estimate in its verdict and, if it is rejected, its value.
            let mut qd_from_angles = None;
            // Angle first: the velocity check needs the angle's verdict.
            for sig in [Q, QD, F] {
                // The angle's slope over the window is a velocity measurement only once the
                // window holds measured angles alone.
                let slope_ok = self.slope_ok(j);
                let v = vals[sig][j];
                let in_range = v.is_finite()
                    && if sig == F {
                        v.abs() < self.bounds[sig]
                    } else {
                        v.abs() <= self.bounds[sig]
                    };
                let repeated = v.to_bits() == self.raw[sig][0][j].to_bits();
                // A filtered velocity repeats once where the raw sample entering its window
                // equals the one leaving it (a quantised velocity, at its extremes); a frozen one
                // repeats from then on. A filtered force is frozen on its first repeat: one
                // sample later lost 4 fine-scan cells (docs/RELIABILITY.md §2).
                let stuck = warm
                    && repeated
                    && match sig {
                        Q => self.angle_moved(vals[QD][j], j),
                        QD => self.window <= 1 || self.repeated_before(QD, j),
                        _ => true,
                    };
                // A strap force's extrapolation moves with the robot's own part of it (the
                // second difference of `ks J (q̄ + τ q̇̄)` while the angles of its joints are
                // measured, [`ChannelGuard::with_straps`]).
                let robot_d2 = if sig == F {
                    motion[j] = self.joint_motion(out[Q][j], j);
                    robot_part[j] = self.straps.map_or(f64::NAN, |(ks_j, _)| {
                        (0..=j).map(|i| ks_j[(j, i)] * motion[i]).sum()
                    });
                    let d2 = robot_part[j] - 2.0 * self.robot_part[0][j] + self.robot_part[1][j];
                    if d2.is_finite() {
                        d2
                    } else {
                        0.0
                    }
                } else {
                    0.0
                };
                let p = pred[sig][j] - robot_d2;
                // A velocity's estimate while its angle is measured: the accepted angles' slope
                // (`angle_velocity`; `out[Q]` is this step's accepted angle); else the linear
                // extrapolation.
                if sig == QD {
                    qd_from_angles = self.angle_velocity(&out, j);
                }
                let estimate = match sig {
                    QD => qd_from_angles.unwrap_or(p),
                    _ => p,
                };
                // A strap force believed on smoothness alone carries the bias that kept it at
                // its estimate (`force_bias`, fading at [`FORCE_BIAS_RATE`]).
                let vb = if sig == F { v + self.force_bias[j] } else { v };
                let residual = if warm { (vb - estimate).abs() } else { 0.0 };
                let gate = self.gate(sig, j);
                let was_bad = self.bad_for[sig][j] > 0;
                let smooth_now = in_range
                    && !repeated
                    && (v - 2.0 * self.raw[sig][0][j] + self.raw[sig][1][j] + robot_d2).abs()
                        < gate;
                // A force at full scale may be a real force of at least the range: it is
                // accepted again as soon as it is back in range.
                let railed = sig == F && v.is_finite() && !in_range;
                // Right after a full-scale reading the extrapolation runs through the estimate
                // that stood in for it, not through the force: no innovation to gate yet (the
                // range check has handled the full-scale samples).
                let after_rail = sig == F
                    && warm
                    && self.raw[F][..]
                        .iter()
                        .any(|r| r[j].is_finite() && r[j].abs() >= self.bounds[F]);
                definite |= !in_range || stuck;
                let after_accept = !was_bad && self.after_accept[sig][j] > 0;
                let mut resynced = false;
                // Believed on smoothness alone while it disagrees with its estimate.
                let mut unverified = false;
                // A velocity rejected with a stalled acquisition stays rejected for a filter
                // window: by then a stalled velocity has frozen (and is rejected as such), a
                // good one is accepted again. A frozen filtered velocity (a stuck or
                // dropped-out raw velocity) that moves again still averages frozen samples
                // for `window − 1` samples: its ramp back crosses the estimate, and accepting
                // it there fed the controller a velocity between the frozen and the true one
                // (a 60-ms stuck velocity at 1.5 s, 0 kg: 70 N).
                let stalled = stall && !was_bad;
                let held_off = sig == QD && (stalled || self.qd_held_off[j] > 0);
                if sig == QD {
                    if !in_range || stuck || (!was_bad && !stalled) {
                        self.qd_stall_only[j] = false;
                    } else if stalled {
                        self.qd_stall_only[j] = true;
                    }
                    let left = self.qd_held_off[j].saturating_sub(1);
                    self.qd_held_off[j] = if stalled {
                        self.window as u32
                    } else if stuck && in_range {
                        left.max(self.window.saturating_sub(1) as u32)
                    } else {
                        left
                    };
                }
                // An angle found frozen stays rejected while it repeats the frozen value, also
                // where its joint pauses (the stuck test needs motion) and its estimate passes
                // the value: a frozen encoder accepted at a turn of the hip ended the
                // protective stop within its fault (tests/latch.rs).
                let still_frozen = sig == Q && was_bad && self.q_frozen[j] && repeated;
                // Rejected again after being believed on smoothness alone (`revoke_unverified`):
                // not accepted before its floor.
                let floored =
                    sig != F && was_bad && self.bad_for[sig][j] < self.accept_floor[sig][j];
                // An encoder channel of a joint whose angle and velocity are both rejected
                // ([`JOINT_LOST_LIMIT_FACTOR`]).
                let joint_lost = sig != F && self.bad_for[Q][j] > 0 && self.bad_for[QD][j] > 0;
                let good = if !in_range || stuck || held_off || still_frozen || floored {
                    false
                } else if (was_bad && (self.railed[j] || !warm))
                    || (!was_bad && (after_rail || after_accept))
                {
                    // Without a warm history (the start, or a gap in the data) there is no
                    // estimate to compare with: a value in range is accepted, as a channel that
                    // was good is then. Waiting for the resynchronisation instead held the
                    // torque for `sensor_timeout_s` after a gap (`ready` stays false while a
                    // channel is rejected and the history is empty).
                    true
                } else if sig == QD
                    && was_bad
                    && self.qd_stall_only[j]
                    && smooth_now
                    && self.smooth[QD][j] >= 2
                {
                    // Held off by the stall rule alone and still fresh after it (a stalled
                    // velocity would have frozen): the acquisition did not stall, only the
                    // angles failed. The velocity, judged on its own (three smooth samples),
                    // is a measurement; against the estimate that stood in for it (the gait
                    // replay), a knee accelerating at 3 kg was not accepted within the fault.
                    // Unverified where it disagrees with that estimate, as a channel believed
                    // on smoothness alone.
                    unverified = (vb - estimate).abs() >= ACCEPT_GATES * gate;
                    true
                } else if was_bad {
                    let resync = if sig == F {
                        resync_after.min(force_resync)
                    } else if joint_lost {
                        resync_after.saturating_mul(JOINT_LOST_LIMIT_FACTOR)
                    } else {
                        resync_after
                    };
                    // A filtered channel (velocity, force) must also move like its estimate:
                    // the moving average spreads a spike over `window` more samples, whose
                    // ramp back passes the estimate's value before the spike has left it.
                    let last = self.raw[sig][0][j];
                    let moves_along = sig == Q
                        || !last.is_finite()
                        || (v - last - (estimate - self.back(sig, 1)[j])).abs() < gate;
                    // A velocity estimated from its good angle's slope is a measurement of
                    // the same quantity, not an estimate drifting through the fault (over the
                    // whole window only: on the slope of a partial window, for the few steps it
                    // lasts, `ACCEPT_GATES` and smoothness as for an estimate, as measured).
                    let accept_gates = if sig == QD && (slope_ok || joint_lost) {
                        SLOPE_ACCEPT_GATES
                    } else {
                        ACCEPT_GATES
                    };
                    let agrees = (vb - estimate).abs() < accept_gates * gate && moves_along;
                    // A velocity estimated from its good angle's slope is not believed on
                    // smoothness alone: the slope measures the same quantity, so a smooth
                    // velocity that disagrees with it is an offset (a 1-s 0.5-rad/s spike,
                    // believed after `resync_after`, gave 29-46 N at 0-3 kg).
                    let resync_now = !agrees
                        && self.bad_for[sig][j] >= resync
                        && self.smooth[sig][j] >= 2
                        && !(sig == QD && slope_ok);
                    resynced = resync_now && moves_along;
                    unverified = resync_now;
                    agrees || resync_now
                } else {
                    residual <= gate
                };
                // A velocity held off by the stall rule and accepted again while the angle is
                // still rejected: the acquisition did not stall (a stalled velocity would have
                // frozen), only the angles failed. The angles of the fault's steps are the
                // ones the received velocities imply, and the angle is implied from now on.
                if sig == QD && good && was_bad && self.qd_stall_only[j] && self.stall_anchored[j] {
                    if let Some(n) = self.stall_len {
                        if self.bad_for[Q][j] as usize == n
                            && self.bad_for[QD][j] as usize + 1 == n
                            && self.angles_through_stall(j, n, gate)
                        {
                            self.q_anchored[j] = true;
                            estimated.resume = true;
                        }
                    }
                }
                self.smooth[sig][j] = if smooth_now {
                    self.smooth[sig][j].saturating_add(1)
                } else {
                    0
                };
                // An angle that was implied by its measured velocity, and handed over as a
                // measurement, comes back off its extrapolation (see `resume`).
                estimated.resume |=
                    sig == Q && was_bad && good && self.q_anchored[j] && residual > gate;
                if sig == F && !was_bad && !good {
                    self.railed[j] = railed;
                }
                if sig == F {
                    // Accepted again within `FORCE_RESYNC_S` of its rejection, after it was found
                    // frozen: the filtered force still averages frozen samples, and its ramp
                    // back was accepted where it passed the estimate (a 200-ms dropout of both
                    // forces at 3.5 s, 3 kg: the hip torque swung from −13.6 to +11.0 N·m in 3
                    // steps, 14.8 N; 10.3 N taken in from the estimate). After longer faults the
                    // estimate has drifted and is not kept (a 1-s dropout at 1.5 s, 2 kg:
                    // 11.8 N, 22.5 N taken in from it). A force back from full scale is believed
                    // at once (`railed`).
                    let after_frozen = warm
                        && was_bad
                        && self.force_frozen[j]
                        && !self.railed[j]
                        && self.bad_for[F][j] < force_resync;
                    if good && (resynced || after_frozen) && (estimate - v).is_finite() {
                        // The force starts at its estimate and the difference is taken in at
                        // `FORCE_BIAS_RATE`. Believed on smoothness alone, only while it moves
                        // along its estimate (an offset); one that moves otherwise is believed at
                        // once.
                        self.force_bias[j] = estimate - v;
                    }
                    if good {
                        out[F][j] = v + self.force_bias[j];
                        self.force_frozen[j] = false;
                    } else if stuck && in_range {
                        self.force_frozen[j] = true;
                    }
                    let fade = FORCE_BIAS_RATE * self.dt;
                    self.force_bias[j] -= self.force_bias[j].clamp(-fade, fade);
                }
                if sig != F {
                    // Accepted on smoothness alone, or accepted at all after being rejected
                    // again (`revoked`): unverified.
                    let fresh = good && was_bad && (unverified || self.revoked[sig][j]);
                    let u = &mut self.unverified[sig][j];
                    *u = if fresh {
                        self.unverified_bad_for[sig][j] = self.bad_for[sig][j];
                        1
                    } else if good && *u > 0 && *u < unverified_steps {
                        *u + 1
                    } else {
                        0
                    };
                    if good {
                        self.accept_floor[sig][j] = 0;
                        self.revoked[sig][j] = false;
                    }
                }
                if good {
                    if was_bad {
                        self.after_accept[sig][j] = 2;
                    } else if after_accept {
                        self.after_accept[sig][j] -= 1;
                    } else if !after_rail {
                        if residual / gate > self.peak_ratio[sig] {
                            self.peak_ratio[sig] = residual / gate;
                        }
                        let ms = &mut self.res_ms[sig][j];
                        *ms += (residual * residual - *ms) * self.res_alpha;
                    }
                    self.bad_for[sig][j] = 0;
                    self.offset[sig][j] = f64::NAN;
                    if sig == F {
                        self.follow[j] = OffsetFollow::Ready;
                    }
                } else {
                    if !was_bad {
                        self.episodes += 1;
                    }
                    self.bad_for[sig][j] = self.bad_for[sig][j].saturating_add(1);
                    any = true;
                    let anchored = sig == F || (sig == QD && self.bad_for[Q][j] == 0);
                    // A channel rejected again (`revoke_unverified`) is past its limit at once.
                    let age = if joint_lost && !self.revoked[sig][j] {
                        self.bad_for[sig][j] / JOINT_LOST_LIMIT_FACTOR
                    } else if anchored {
                        self.bad_for[sig][j] / ANCHORED_LIMIT_FACTOR
                    } else {
                        self.bad_for[sig][j]
                    };
                    longest = longest.max(age);
                }
                if sig == Q {
                    self.q_frozen[j] = !good && in_range && (stuck || still_frozen);
                    // A new fault of the angle: its velocity can imply it only from a filter
                    // window of measured angles (not from one accepted between two faults),
                    // and not for a frozen angle, which may have been frozen for samples
                    // before it was found so (the frozen test needs the joint to move; a
                    // latched fallback on a 1-s dropout of one angle railed a strap).
                    if !good && !was_bad {
                        self.q_anchored[j] = self.q_good_for[j] as usize >= span && !repeated;
                    }
                    self.q_good_for[j] = if good {
                        self.q_good_for[j].saturating_add(1)
                    } else {
                        0
                    };
                }
                self.raw[sig][1][j] = self.raw[sig][0][j];
                self.raw[sig][0][j] = v;
            }
            // Estimates once every verdict of the joint is in: an angle from its good velocity,
            // a velocity from its good angle, else the replay.
            for sig in [Q, QD, F] {
                if self.bad_for[sig][j] > 0 {
                    let q_bad = self.bad_for[Q][j] > 0 || (sig == QD && qd_from_angles.is_none());
                    let qd_bad = self.bad_for[QD][j] > 0;
                    // An angle whose velocity has been measured on every step since the
                    // angle was last accepted: the angle the velocity implies through the
                    // filter window (what the velocity check holds a clean velocity to; the
                    // model's prediction drifted 0.07 rad in 200 ms at 3 kg, outside its
                    // payload scenarios). Else the model; with both encoders lost, the gait
                    // replay when a period is known (an open-loop model drifts away within
                    // 100 ms).
                    let replay = q_bad && qd_bad && period.is_some();
                    let implied = if sig == Q && !qd_bad && self.q_anchored[j] {
                        self.angle_from_velocity(j, out[QD][j])
                    } else {
                        None
                    };
                    if sig == Q {
                        self.q_anchored[j] = implied.is_some();
                        q_from_velocity[j] = implied.is_some();
                    }
                    let (value, replayed) = match (sig, model, implied, qd_from_angles) {
                        (Q, _, Some(q), _) => (q, false),
                        (Q, Some((q, _)), None, _) if !replay => (q[j], false),
                        (QD, _, _, Some(v)) if self.filled >= 2 => (v, false),
                        (QD, Some((_, qd)), _, None) if !replay => (qd[j], false),
                        _ => self.estimate(sig, j, &out, period),
                    };
                    let value = if sig == F {
                        self.follow_offset(j, vals[F][j], value, replayed)
                    } else {
                        value
                    };
                    out[sig][j] = value;
                    // Not the replay on this step: the next replay starts with a new offset.
                    if !replayed {
                        self.offset[sig][j] = f64::NAN;
                    }
                    match sig {
                        Q => estimated.q[j] = true,
                        QD => estimated.qd[j] = q_bad,
                        _ => estimated.force[j] = true,
                    }
                }
            }
            self.qd_good_for[j] = if self.bad_for[QD][j] == 0 {
                self.qd_good_for[j].saturating_add(1)
            } else {
                0
            };
        }
        estimated.period = period;
        // The continuation only while every encoder is measured: judged once every joint's
        // verdict is in (a strap's estimate came before the later joints' verdicts); once one
        // is lost, the continued forces replay the gait one period back, or hold before the
        // period is known, and are not continued again in this fault.
        let encoders = self.encoders_measured();
        if !encoders {
            // A force followed under its offset is held on this step (an encoder of a later
            // joint was judged after it), as in `follow_offset`.
            for (j, o) in out[F].iter_mut().enumerate() {
                if self.bad_for[F][j] == 0 {
                    continue;
                }
                if let Some(held) = self.bar_follow(j) {
                    *o = held;
                    self.fit_used[j] = false;
                }
            }
        }
        if !encoders && self.fit_used.iter().any(|&u| u) {
            let used = self.fit_used;
            for j in (0..N).filter(|&j| used[j]) {
                out[F][j] = match period {
                    Some(p) => self.replay(F, j, p),
                    None => self.back(F, 1)[j],
                };
            }
            self.fit_used = [false; N];
        }
        if !encoders {
            self.force_fit_age = u32::MAX;
        }
        // With the period known only from a clean history: a continuation fitted across an
        // earlier fault continues that fault.
        let clean_fit = self.fit_clean || period.is_none();
        estimated.gait_omega = (*self.force_fit)
            .as_ref()
            .filter(|_| clean_fit && self.fit_used.iter().any(|&u| u))
            .map(|f| f.omega());
        self.fit_used = [false; N];
        if (0..N).all(|j| self.bad_for[F][j] == 0) {
            *self.force_fit = None;
        } else if self.force_fit.is_some() {
            self.force_fit_age = self.force_fit_age.saturating_add(1);
        }
        let ready = self.filled > 0 || !any;
        if !ready {
            self.restart_counts();
        }
        if any {
            self.estimated_steps += 1;
        }
        // (The first sample kept after a gap in the data starts the count.)
        self.clean_steps = if any || self.force_bias.iter().any(|b| *b != 0.0) {
            0
        } else if self.filled == 0 {
            1
        } else {
            self.clean_steps.saturating_add(1)
        };
        if ready {
            let len = self.hist[0].len();
            for (sig, o) in out.iter().enumerate() {
                self.hist[sig][self.pos] = *o;
            }
            self.pos = (self.pos + 1) % len;
            self.filled = (self.filled + 1).min(len);
            self.robot_part = [robot_part, self.robot_part[0]];
        }
        Repaired {
            m: Measurement {
                t: m.t,
                q: out[Q],
                qd: out[QD],
                force: out[F],
            },
            any_rejected: any,
            definite_fault: definite,
            estimated,
            longest_fault_s: longest as f64 * self.dt,
            encoders_good: encoders,
            ready,
            stalled: stall,
            q_from_velocity,
        }
    }

    /// Rewrites the history of joint `j` over the `n − 1` steps before this one, since a
    /// stalled acquisition was found: the velocities received then (`stall_qd`) and the angles
    /// they imply (`q_i = q_{i−span} + span·dt·qd_i`, the filtered velocity being the angle's
    /// mean slope over the filter window), anchored on the measured angles before the stall.
    /// `false` (nothing written) when a received velocity is non-finite, out of range, repeats
    /// the one before bit for bit (a stall after all) or is not smooth (a second difference
    /// beyond `gate`), or the history does not reach back far enough.
    fn angles_through_stall(&mut self, j: usize, n: usize, gate: f64) -> bool {
        let span = self.window_span();
        if n < 2 || self.filled <= n + span || n > self.stall_qd.len() {
            return false;
        }
        let v = &self.stall_qd[..n];
        let bound = self.bounds[QD];
        let fresh = v.iter().all(|x| x[j].is_finite() && x[j].abs() <= bound)
            && v.windows(2).all(|w| w[0][j].to_bits() != w[1][j].to_bits())
            && v.windows(3)
                .all(|w| (w[2][j] - 2.0 * w[1][j] + w[0][j]).abs() < gate);
        let anchors = (n..n + span).all(|b| self.back(Q, b)[j].is_finite());
        if !fresh || !anchors {
            return false;
        }
        for i in 0..n - 1 {
            let back = n - 1 - i;
            let q = self.back(Q, back + span)[j] + span as f64 * self.dt * self.stall_qd[i][j];
            let at = self.slot(back);
            self.hist[Q][at][j] = q;
            self.hist[QD][at][j] = self.stall_qd[i][j];
        }
        true
    }

    /// The periods a filter window spans (`window − 1`, at least 1): the angle's slope over
    /// them is what a clean filtered velocity equals.
    fn window_span(&self) -> usize {
        (self.window - 1).max(1)
    }

    /// The estimate of rejected strap force `j`, `regular` the one [`Self::estimate`] gives
    /// (the continuation, the replay, `replayed`, or the hold) and `v` this step's
    /// measurement: a force rejected after a clean history (no channel rejected and no force
    /// bias over the span a continuation is fitted to: up to [`EXTRAPOLATION_FIT_S`], less
    /// early in a run or after a gap in the data), while every encoder is measured, whose
    /// measurement moves smoothly (three smooth fresh samples in a row, as for the acceptance
    /// on smoothness alone) and on such a step steps like `regular` (within one gate), is
    /// followed under the offset it has from `regular` there: the estimate is `v` plus that
    /// offset. A spike is an offset, and under it the sensor still measures the person's
    /// force, which the continuation only forecasts (a 200-ms 30-N spike of both forces at
    /// 1 s, 3 kg: 12.7 N on the continuation, 8.9 N followed; docs/RELIABILITY.md §2). When
    /// the measurement stops moving smoothly (the offset ends) the estimate goes on from its
    /// last value: by the steps of the continuation or of a replay that began before, and as
    /// the replay or the hold that start from it (both take the last estimate as their
    /// start), until the force is accepted again. Once an encoder is lost in the fault the
    /// force is held on that step and then goes the way of a force off its continuation (the
    /// replay from the held value, or the hold): followed through the encoders' loss, every
    /// sensor's 1-s spike at 1.5 s, 3 kg, 74.4 N; nor is it followed after a history that
    /// was not clean: there the fault may be the return of a force believed on smoothness
    /// alone, a real step (every sensor's 1-s spike at 3 s, 2 kg: 17.7 → 28.9 N followed, the
    /// shank's force hidden under a 19-N offset). A real step of the person's force rejected
    /// as a jump is hidden until its acceptance on smoothness ([`FORCE_RESYNC_S`]), as on the
    /// continuation, its shape followed meanwhile.
    fn follow_offset(&mut self, j: usize, v: f64, regular: f64, replayed: bool) -> f64 {
        use OffsetFollow::{Barred, Continued, Offset, Ready};
        let last = self.back(F, 1)[j];
        if self.bad_for[F][j] == 1 {
            self.follow[j] = if self.history_clean() { Ready } else { Barred };
        }
        // (A later joint's encoders are judged after this strap: `repair` bars it then.)
        if !self.encoders_measured() {
            if let Some(held) = self.bar_follow(j) {
                return held;
            }
        }
        let smooth = self.smooth[F][j] >= 2 && v.is_finite();
        let gate = self.gate(F, j);
        let continued = self.fit_used[j];
        // The replay or the hold taking the last estimate as its start on this step (a replay
        // begun on it, `replay`'s count at 1).
        let anchored = !continued && (!replayed || self.replayed_for[F][j] == 1);
        let now = regular as f32;
        let (follow, value) = match self.follow[j] {
            Ready if smooth && ((v - self.raw[F][1][j]) - (regular - last)).abs() < gate => {
                let offset = (regular - v) as f32;
                let follow = Offset {
                    offset,
                    regular: now,
                    continued,
                };
                (follow, v + f64::from(offset))
            }
            Offset { offset, .. } if smooth => (
                Offset {
                    offset,
                    regular: now,
                    continued,
                },
                v + f64::from(offset),
            ),
            Offset {
                regular: before,
                continued: was,
                ..
            }
            | Continued {
                regular: before,
                continued: was,
            } => {
                let value = if anchored {
                    regular
                } else if was == continued {
                    last + (f64::from(now) - f64::from(before))
                } else {
                    last
                };
                (
                    Continued {
                        regular: now,
                        continued,
                    },
                    value,
                )
            }
            other => (other, regular),
        };
        self.follow[j] = follow;
        if value.is_finite() {
            value
        } else {
            regular
        }
    }

    /// Strap `j` is not followed for the rest of its fault (an encoder lost): a force that was
    /// followed is held at its last estimate on this step (returned), and a replay on the next
    /// starts from it.
    fn bar_follow(&mut self, j: usize) -> Option<f64> {
        let followed = matches!(
            self.follow[j],
            OffsetFollow::Offset { .. } | OffsetFollow::Continued { .. }
        );
        self.follow[j] = OffsetFollow::Barred;
        followed.then(|| {
            self.offset[F][j] = f64::NAN;
            self.back(F, 1)[j]
        })
    }

    /// The gate of channel `sig` of joint `j`: its fixed gate, widened to
    /// [`ADAPTIVE_GATE_SIGMAS`] times the RMS of its recent residuals when that is larger.
    fn gate(&self, sig: usize, j: usize) -> f64 {
        self.gates[sig].max(ADAPTIVE_GATE_SIGMAS * self.res_ms[sig][j].sqrt())
    }

    /// Every encoder channel (every joint's angle and velocity) accepted: on this step once
    /// every joint's verdict is in.
    fn encoders_measured(&self) -> bool {
        (0..N).all(|i| self.bad_for[Q][i] == 0 && self.bad_for[QD][i] == 0)
    }

    /// The history holds measurements alone over the span a continuation is fitted to (no
    /// channel rejected and no force bias: `clean_steps`).
    fn history_clean(&self) -> bool {
        self.clean_steps as usize >= TorqueExtrapolation::<N>::fit_steps(self.filled, self.dt)
    }

    /// The angle's slope and the velocity's change start anew: after a gap in the data, and
    /// on a sample not kept in the history (they would reach back across it as if it were one
    /// period).
    fn restart_counts(&mut self) {
        self.q_good_for = [0; N];
        self.qd_good_for = [0; N];
    }

    /// Joint `j` moves fast enough for a repeated angle to be frozen: its velocity (this
    /// sample's `qd` if the velocity was accepted on the last step and `qd` is finite, else the
    /// last estimate) faster than `max(STUCK_SPEED, 2 · encoder_step / dt)`.
    fn moving(&self, qd: f64, j: usize) -> bool {
        let qd = if self.bad_for[QD][j] == 0 && qd.is_finite() {
            qd
        } else {
            self.back(QD, 1)[j]
        };
        qd.abs() > STUCK_SPEED.max(2.0 * self.encoder_step / self.dt)
    }

    /// Joint `j` moved over the last period by more than a repeated angle allows: it moves
    /// ([`Self::moving`]), and on the angle's first repeat the angles' quadratic extrapolation
    /// moves it by more than 4 encoder steps (its own quantisation error is up to 3 steps, and
    /// a repeat allows 1). The filtered velocity lags the leg by half its window: at a turn
    /// between two samples it still moves while the angle stays within a step (the CiA 402
    /// loop over the bus, `crates/exompc-can/tests/cia402_robot.rs`: a turn extrapolated 2.0
    /// steps away).
    fn angle_moved(&self, qd: f64, j: usize) -> bool {
        if !self.moving(qd, j) {
            return false;
        }
        if self.repeated_before(Q, j) {
            return true;
        }
        let [a, b, c] = [1, 2, 3].map(|s| self.back(Q, s)[j]);
        let d = (2.0 * (a - b) - (b - c)).abs();
        // A NaN estimate counts as moved.
        d.is_nan() || d > 4.0 * self.encoder_step
    }

    /// The last sample of channel `sig` of joint `j` repeated the one before it bit for bit.
    fn repeated_before(&self, sig: usize, j: usize) -> bool {
        self.raw[sig][0][j].to_bits() == self.raw[sig][1][j].to_bits()
    }

    /// The angle of joint `j` has been accepted over the whole filter window (on at least two
    /// samples, so that a one-sample window's slope does not reach back to an estimate; counted
    /// from the last gap in the data).
    fn slope_ok(&self, j: usize) -> bool {
        self.q_good_for[j] as usize > self.window_span()
    }

    /// The angle of joint `j` that the filtered velocity `qd` implies: the angle `window − 1`
    /// periods back plus `qd` over that span (a clean filtered velocity is the angle's mean
    /// slope over the filter window, the velocity check's rule, so the estimate carries the
    /// filter's lag no further than the window). `None` without that much history or a finite
    /// velocity.
    fn angle_from_velocity(&self, j: usize, qd: f64) -> Option<f64> {
        let span = self.window_span();
        if !qd.is_finite() || self.filled < span.max(2) {
            return None;
        }
        let q = self.back(Q, span)[j] + span as f64 * self.dt * qd;
        q.is_finite().then_some(q)
    }

    /// The velocity of joint `j` that its accepted angles give (`out[Q]` is this step's angle):
    /// their mean slope over the filter window (what a clean filtered velocity equals) once the
    /// window holds accepted angles only; after an angle fault, while at least
    /// [`PARTIAL_SLOPE_SPAN`] periods of them are accepted, their slope moved back by the
    /// filter's lag over the rest of the window (half the missing span times the velocity's
    /// change over the last period). `None` while the angle is rejected or too few are accepted.
    fn angle_velocity(&self, out: &[SVector<f64, N>; 3], j: usize) -> Option<f64> {
        let full = self.window_span();
        if self.slope_ok(j) {
            return Some(self.slope(out, j, full));
        }
        let span = (self.q_good_for[j] as usize).checked_sub(1)?;
        if self.bad_for[Q][j] > 0 || span < PARTIAL_SLOPE_SPAN {
            return None;
        }
        // The velocity's change over the last period: the filtered velocity's own when its last
        // two samples were accepted, else the angles' last second difference.
        let measured = self.back(QD, 1)[j] - self.back(QD, 2)[j];
        let dv = if self.qd_good_for[j] >= 2 && measured.is_finite() {
            measured
        } else {
            (out[Q][j] - 2.0 * self.back(Q, 1)[j] + self.back(Q, 2)[j]) / self.dt
        };
        let lag = dv * full.saturating_sub(span) as f64 / 2.0;
        Some(self.slope(out, j, span) - lag)
    }

    /// The angle's mean slope over the last `span` periods, `out[Q]` being this step's angle.
    fn slope(&self, out: &[SVector<f64, N>; 3], j: usize, span: usize) -> f64 {
        (out[Q][j] - self.back(Q, span)[j]) / (span as f64 * self.dt)
    }

    /// The estimate of a rejected channel `sig` of joint `j` (`out` holds this step's values
    /// of the signals already decided), and whether it is the gait replay; a velocity that its
    /// accepted angles give ([`ChannelGuard::angle_velocity`]) takes that in `repair` instead.
    fn estimate(
        &mut self,
        sig: usize,
        j: usize,
        out: &[SVector<f64, N>; 3],
        period: Option<usize>,
    ) -> (f64, bool) {
        if self.filled < 2 {
            return (0.0, false);
        }
        let prev = self.back(sig, 1)[j];
        if sig == Q && self.bad_for[QD][j] == 0 && out[QD][j].is_finite() {
            return (prev + self.dt * out[QD][j], false);
        }
        // A strap force follows its continuation at the gait frequency first (with the period
        // known, blended with the replay, `FORCE_REPLAY_WEIGHT`): the gait one period back is
        // another gait while it changes (the human grows heavier, docs/MODEL.md §2; a 200-ms
        // dropout of both forces at 2.5 s, 3 kg: 21.6 N replayed, 10.4 N blended).
        if sig == F {
            if let Some(v) = self.force_continuation(j, period) {
                return (v, false);
            }
        }
        if let Some(p) = period {
            return (self.replay(sig, j, p), true);
        }
        match sig {
            Q => (prev + self.dt * self.back(QD, 1)[j], false),
            _ => (prev, false),
        }
    }

    /// Signal `sig` of joint `j` replayed one gait period `p` back, with the offset it had when
    /// this replay began; from the second period on, the value a period back is a replayed
    /// one and already carries it.
    fn replay(&mut self, sig: usize, j: usize, p: usize) -> f64 {
        let then = self.back(sig, p)[j];
        if !self.offset[sig][j].is_finite() {
            self.offset[sig][j] = self.back(sig, 1)[j] - self.back(sig, p + 1)[j];
            self.replayed_for[sig][j] = 0;
        }
        let replayed = &mut self.replayed_for[sig][j];
        let carried = *replayed as usize >= p;
        *replayed = replayed.saturating_add(1);
        if carried {
            then
        } else {
            then + self.offset[sig][j]
        }
    }

    /// Strap force `j` continued at the gait frequency ([`FORCE_FIT_S`]): fitted on the
    /// fault's first step, for the straps whose fault began on that step, followed for at
    /// most [`FORCE_FIT_S`] while every encoder is measured (checked in `repair` once every
    /// joint's verdict is in). With the gait period (lag `period`) known on the first step,
    /// longer than the continuation and held in the history with it, the continuation may
    /// leave the fitted range by [`FORCE_RANGE_MARGIN`] and is blended with the replay at
    /// that lag ([`FORCE_REPLAY_WEIGHT`]).
    fn force_continuation(&mut self, j: usize, period: Option<usize>) -> Option<f64> {
        if self.force_fit.is_none() && self.bad_for[F][j] == 1 {
            *self.force_fit = TorqueExtrapolation::fit(
                &self.hist[F],
                self.pos,
                &self.hist[Q],
                self.pos,
                self.filled,
                self.dt,
            );
            // The blend and the margin are decided once, here: on for a lag that reaches back
            // before the fault over the whole continuation within the history held (a check
            // on each step would switch a long period's blend off partway, stepping the
            // estimate).
            let continued_steps = (FORCE_FIT_S / self.dt).ceil() as usize;
            let held = self.filled.min(self.hist[F].len());
            self.blend_lag = period
                .filter(|&p| p > continued_steps && p + continued_steps < held)
                .unwrap_or(0);
            if self.blend_lag > 0 {
                if let Some(f) = self.force_fit.as_mut() {
                    f.widen(FORCE_RANGE_MARGIN);
                }
            }
            self.force_fit_age = 0;
            self.fit_clean = self.history_clean();
        }
        let fit = (*self.force_fit).as_ref()?;
        let age = self.force_fit_age;
        let from_start = self.bad_for[F][j] == u64::from(age) + 1;
        let on = from_start && f64::from(age) * self.dt < FORCE_FIT_S - 1e-9;
        self.fit_used[j] = on;
        if !on {
            return None;
        }
        let continued = fit.at(age, self.dt)[j];
        // The replay from the fault's start (`a + 1` steps back, the last measured sample):
        // `F(k − p) + F(k₀ − 1) − F(k₀ − 1 − p)`; a lag set at the fit outlasts the
        // continuation and is held in the history over it.
        let (p, a) = (self.blend_lag, age as usize);
        if p > 0 {
            let replayed = self.back(F, p)[j] + self.back(F, a + 1)[j] - self.back(F, a + 1 + p)[j];
            if replayed.is_finite() {
                return Some(continued + FORCE_REPLAY_WEIGHT * (replayed - continued));
            }
        }
        Some(continued)
    }
}

/// Length (s) of the applied-torque history a [`TorqueExtrapolation`] is fitted to (at most;
/// at least [`EXTRAPOLATION_MIN_S`]).
pub const EXTRAPOLATION_FIT_S: f64 = 1.0;
/// Shortest history (s) a [`TorqueExtrapolation`] is fitted to; with less the torque is held.
pub const EXTRAPOLATION_MIN_S: f64 = 0.3;
/// Window (s) of the angles whose oscillation gives the gait frequency of a
/// [`TorqueExtrapolation`].
pub const EXTRAPOLATION_ANGLE_S: f64 = 0.5;
/// Steps over which a [`TorqueExtrapolation`]'s offset to the last applied torque fades out.
pub const EXTRAPOLATION_FADE_STEPS: u32 = 10;
/// Fastest gait frequency (Hz) a [`TorqueExtrapolation`] accepts from the angles (the
/// supervisor's gait-frequency bound, [`GAIT_MAX_HZ`](super::GAIT_MAX_HZ)).
pub const EXTRAPOLATION_MAX_HZ: f64 = 2.0;
/// Slowest gait frequency (Hz) a [`TorqueExtrapolation`] accepts from the angles.
pub const EXTRAPOLATION_MIN_HZ: f64 = 0.2;

/// The applied torque continued at the gait frequency, for the first gait period of a run
/// (before [`GaitFrequency`](super::GaitFrequency) knows the period, the torque of one period back cannot be
/// replayed): while every encoder channel, or one joint's encoder, is lost the torque follows
/// `T(τ) = a + Σ_{h=1,2} (b_h sin hωτ + c_h cos hωτ)`, fitted by least squares to the
/// applied torque of the last [`EXTRAPOLATION_FIT_S`], started at the last applied torque (the
/// fit's residual there fades out over [`EXTRAPOLATION_FADE_STEPS`]) and kept within the range
/// of those torques. `ω` is the gait frequency of the angles before the fault: each joint's swing is
/// fitted as a harmonic oscillator `q̈ = α − ω² q` over the last [`EXTRAPOLATION_ANGLE_S`]
/// (second differences at a 50-ms stride, exact for a sine), and the joint with the widest
/// swing gives `ω`
/// (issue 28: coasting on the predicted human motion; docs/RELIABILITY.md §2).
#[derive(Clone, Copy, Debug)]
pub struct TorqueExtrapolation<const N: usize> {
    omega: f64,
    coef: [[f64; 5]; N],
    lo: SVector<f64, N>,
    /// The last applied torque less the fit there: added at the start, fading out linearly
    /// over [`EXTRAPOLATION_FADE_STEPS`], so that the extrapolation starts where the torque is.
    offset: SVector<f64, N>,
    hi: SVector<f64, N>,
}

impl<const N: usize> TorqueExtrapolation<N> {
    /// Samples a fit spans with `filled` samples held at period `dt`: those of the last
    /// [`EXTRAPOLATION_FIT_S`], at most `filled`.
    pub(crate) fn fit_steps(filled: usize, dt: f64) -> usize {
        ((EXTRAPOLATION_FIT_S / dt).round() as usize).min(filled)
    }

    /// Fits the extrapolation to the rings `torques` (applied torques) and `angles` (the
    /// angles of the same steps; at least [`EXTRAPOLATION_ANGLE_S`] long), `torque_pos` and
    /// `angle_pos` the next slot to write in each, `filled` the samples held, `dt` the control
    /// period; `None` when the history is too short, the angles do not oscillate at a gait
    /// frequency in [[`EXTRAPOLATION_MIN_HZ`], [`EXTRAPOLATION_MAX_HZ`]], or the fit is not
    /// finite.
    pub fn fit(
        torques: &[SVector<f64, N>],
        torque_pos: usize,
        angles: &[SVector<f64, N>],
        angle_pos: usize,
        filled: usize,
        dt: f64,
    ) -> Option<Self> {
        if torques.is_empty() || angles.is_empty() || !(dt.is_finite() && dt > 0.0) {
            return None;
        }
        let filled = filled.min(torques.len());
        // `i` steps back (1 = the last sample).
        let back = |ring: &[SVector<f64, N>], pos: usize, i: usize| {
            let len = ring.len();
            ring[(pos % len + len - i % len) % len]
        };
        let back_t = |i: usize| back(torques, torque_pos, i);
        let omega = Self::gait_omega(|i| back(angles, angle_pos, i), filled.min(angles.len()), dt)?;
        let n = Self::fit_steps(filled, dt);
        if (n as f64) * dt < EXTRAPOLATION_MIN_S - 1e-9 {
            return None;
        }
        Self::fit_series((1..=n).map(|i| (i, back_t(i))), omega, dt, back_t(1))
    }

    /// The extrapolation of a series at the gait frequency `omega` (rad/s): fitted to the
    /// `samples` `(i, value)`, `i ≥ 1` the steps back of each, and started at `last`, the value
    /// one step back (the offset of [`Self::fit`]); `None` with fewer than five samples or a
    /// fit that is not finite. [`Self::at`]`(s)` is then the value `s + 1` steps after
    /// `last`'s.
    pub fn fit_series(
        samples: impl Iterator<Item = (usize, SVector<f64, N>)>,
        omega: f64,
        dt: f64,
        last: SVector<f64, N>,
    ) -> Option<Self> {
        if !(omega.is_finite() && dt.is_finite() && dt > 0.0) {
            return None;
        }
        let feats = |tau: f64| {
            let (s1, c1) = (omega * tau).sin_cos();
            let (s2, c2) = (2.0 * omega * tau).sin_cos();
            [1.0, s1, c1, s2, c2]
        };
        let mut coef = [[0.0; 5]; N];
        let mut lo = SVector::<f64, N>::repeat(f64::INFINITY);
        let mut hi = SVector::<f64, N>::repeat(f64::NEG_INFINITY);
        let mut a = [[0.0; 5]; 5];
        let mut b = [[0.0; N]; 5];
        let mut n = 0usize;
        for (i, t) in samples {
            n += 1;
            let x = feats(-(i as f64) * dt);
            for r in 0..5 {
                for c in 0..5 {
                    a[r][c] += x[r] * x[c];
                }
                for j in 0..N {
                    b[r][j] += x[r] * t[j];
                }
            }
            lo = lo.inf(&t);
            hi = hi.sup(&t);
        }
        if n < 5 {
            return None;
        }
        for (r, row) in a.iter_mut().enumerate() {
            row[r] += 1e-9 * n as f64;
        }
        for (j, cj) in coef.iter_mut().enumerate() {
            let rhs: [f64; 5] = core::array::from_fn(|r| b[r][j]);
            *cj = solve5(a, rhs)?;
        }
        let x = feats(-dt);
        let offset: SVector<f64, N> = SVector::from_fn(|j, _| {
            last[j] - coef[j].iter().zip(&x).map(|(c, x)| c * x).sum::<f64>()
        });
        (offset.iter().all(|v| v.is_finite())).then_some(TorqueExtrapolation {
            omega,
            coef,
            offset,
            lo,
            hi,
        })
    }

    /// Let the extrapolation leave the range of the fitted samples by `margin` times that
    /// range on either side.
    pub(crate) fn widen(&mut self, margin: f64) {
        let r = self.hi - self.lo;
        self.lo -= r * margin;
        self.hi += r * margin;
    }

    /// The gait frequency (rad/s) the extrapolation continues at.
    pub fn omega(&self) -> f64 {
        self.omega
    }

    /// The gait frequency (rad/s) of the angles `back(i)` (`i` steps back), if they swing.
    fn gait_omega(back: impl Fn(usize) -> SVector<f64, N>, filled: usize, dt: f64) -> Option<f64> {
        let stride = ((0.05 / dt).round() as usize).max(1);
        let n = ((EXTRAPOLATION_ANGLE_S / dt).round() as usize).min(filled);
        if n < 2 * stride + 3 {
            return None;
        }
        let h2 = (stride as f64 * dt).powi(2);
        let mut best: Option<(f64, f64)> = None;
        for j in 0..N {
            // Least squares of y = α + β x, x = q(k − s), y = (q(k) − 2 q(k − s) + q(k − 2s)) / (s dt)².
            let (mut sx, mut sy, mut sxx, mut sxy, mut m) = (0.0, 0.0, 0.0, 0.0, 0.0);
            for i in 1..=(n - 2 * stride) {
                let (q0, q1, q2) = (back(i)[j], back(i + stride)[j], back(i + 2 * stride)[j]);
                let y = (q0 - 2.0 * q1 + q2) / h2;
                sx += q1;
                sy += y;
                sxx += q1 * q1;
                sxy += q1 * y;
                m += 1.0;
            }
            let var = sxx - sx * sx / m;
            if !(var.is_finite() && var > 0.0) {
                continue;
            }
            let beta = (sxy - sx * sy / m) / var;
            // A sine's second difference at stride h is −(2/h)² sin²(ωh/2) times it:
            // ω = (2/h) asin(h √−β / 2) (asin by its series, x ≤ 0.32 up to 2 Hz at 50 ms).
            let h = stride as f64 * dt;
            let x = (h * (-beta).max(0.0).sqrt() / 2.0).min(1.0);
            let x2 = x * x;
            let asin = x * (1.0 + x2 * (1.0 / 6.0 + x2 * (3.0 / 40.0 + x2 * 15.0 / 336.0)));
            let f = 2.0 * asin / h / (2.0 * core::f64::consts::PI);
            if f.is_finite()
                && (EXTRAPOLATION_MIN_HZ..=EXTRAPOLATION_MAX_HZ).contains(&f)
                && best.is_none_or(|(v, _)| var > v)
            {
                best = Some((var, f));
            }
        }
        best.map(|(_, f)| 2.0 * core::f64::consts::PI * f)
    }

    /// The extrapolated torque `steps` control periods after the last applied one's
    /// successor (0: the step the coast begins).
    pub fn at(&self, steps: u32, dt: f64) -> SVector<f64, N> {
        let tau = f64::from(steps) * dt;
        let (s1, c1) = (self.omega * tau).sin_cos();
        let (s2, c2) = (2.0 * self.omega * tau).sin_cos();
        let x = [1.0, s1, c1, s2, c2];
        let fade = 1.0 - f64::from(steps.saturating_add(1)) / f64::from(EXTRAPOLATION_FADE_STEPS);
        SVector::from_fn(|j, _| {
            let v: f64 = self.coef[j].iter().zip(&x).map(|(c, x)| c * x).sum();
            (v + self.offset[j] * fade.max(0.0)).clamp(self.lo[j], self.hi[j])
        })
    }
}

/// Solves the 5×5 system `a x = b` by Gaussian elimination with partial pivoting; `None` when
/// it is singular or not finite.
fn solve5(mut a: [[f64; 5]; 5], mut b: [f64; 5]) -> Option<[f64; 5]> {
    for c in 0..5 {
        let p = (c..5).max_by(|&x, &y| a[x][c].abs().total_cmp(&a[y][c].abs()))?;
        if !(a[p][c].is_finite() && a[p][c].abs() > 1e-300) {
            return None;
        }
        a.swap(c, p);
        b.swap(c, p);
        let pivot = a[c];
        for r in (c + 1)..5 {
            let f = a[r][c] / pivot[c];
            for (x, p) in a[r][c..].iter_mut().zip(&pivot[c..]) {
                *x -= f * p;
            }
            b[r] -= f * b[c];
        }
    }
    let mut x = [0.0; 5];
    for r in (0..5).rev() {
        let s: f64 = ((r + 1)..5).map(|k| a[r][k] * x[k]).sum();
        x[r] = (b[r] - s) / a[r][r];
    }
    x.iter().all(|v| v.is_finite()).then_some(x)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A widened extrapolation leaves the fitted range by its margin at most: a 0.5-Hz sine
    /// fitted over its rise from −1 to 0.69 continues to its crest at 1, held at 0.69 by the
    /// plain range and followed within the range widened by a quarter (up to 1.11).
    #[test]
    fn a_widened_extrapolation_leaves_the_fitted_range_by_its_margin() {
        let (dt, w) = (0.01, core::f64::consts::PI);
        let phi = 0.7_f64.asin();
        let s = |t: f64| SVector::<f64, 1>::repeat((w * t + phi).sin());
        let samples = (1..=100).map(|i| (i, s(-(i as f64) * dt)));
        let plain = TorqueExtrapolation::fit_series(samples, w, dt, s(-dt)).expect("a fit");
        let hi = s(-dt)[0];
        let mut wide = plain;
        wide.widen(FORCE_RANGE_MARGIN);
        let peak = |x: &TorqueExtrapolation<1>| {
            (0..60)
                .map(|k| x.at(k, dt)[0])
                .fold(f64::NEG_INFINITY, f64::max)
        };
        assert!((peak(&plain) - hi).abs() < 1e-12, "plain: {}", peak(&plain));
        assert!((peak(&wide) - 1.0).abs() < 1e-3, "widened: {}", peak(&wide));
        // Below, the widened range still bounds it: −1 − 0.25 · 1.69.
        let low = (0..200)
            .map(|k| wide.at(k, dt)[0])
            .fold(f64::INFINITY, f64::min);
        assert!(
            low >= -1.0 - FORCE_RANGE_MARGIN * (hi + 1.0) - 1e-9,
            "{low}"
        );
    }
}
