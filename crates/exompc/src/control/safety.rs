//! Runtime safety supervision around any controller: see [`Supervisor`].

use super::highpass::HighPass;
use super::ride_through::{ChannelGuard, Repaired, TorqueExtrapolation, EXTRAPOLATION_ANGLE_S};
use super::{
    ControlOutput, Controller, EstimatedChannels, FallbackSettings, Measurement, StepStatus,
    TorqueLimits, Transparent,
};
use crate::check::{self, InvalidField, Range};
#[cfg(not(feature = "std"))]
use crate::math::Float;
use alloc::{boxed::Box, format, vec, vec::Vec};
use nalgebra::{SMatrix, SVector};
use serde::{Deserialize, Serialize};

/// Thresholds and responses of a [`Supervisor`].
#[derive(Clone, Debug, PartialEq)]
pub struct SafetySettings {
    /// Torque limits enforced on every output.
    pub limits: TorqueLimits,
    /// Control period (s), the supervisor's clock.
    pub dt: f64,
    /// Intent gain `K1` (rad/N) of the scenario (for reference: the tracking-error monitor
    /// inverts the strap model instead, see `strap_levers_m`).
    pub k1: f64,
    /// Strap levers `Ls` (m), hip outwards (`[Ls1, Ls2]`); a supervisor of `N` joints uses
    /// the last `N` (the 1-DOF knee: `Ls2`) in `J(s, i) = Ls_i` for `i ≤ s` (docs/MODEL.md §4).
    pub strap_levers_m: Vec<f64>,
    /// Strap stiffness `ks` (N/m).
    pub strap_stiffness: f64,
    /// Strap damping `cs` (N·s/m).
    pub strap_damping: f64,
    /// Force sensor range (N): `|F| ≥ saturation_n` is implausible.
    pub saturation_n: f64,
    /// Plausible joint angles `|q| ≤ angle_max` (rad).
    pub angle_max: f64,
    /// Plausible joint velocities `|qd| ≤ velocity_max` (rad/s).
    pub velocity_max: f64,
    /// The `[monitors]` thresholds and response.
    pub monitors: Monitors,
    /// A tripped monitor clears after its condition has been absent this long (s).
    pub clear_after_s: f64,
    /// Capacity of the event log (events beyond it are counted only).
    pub max_events: usize,
    /// Moving-average window of the velocity and force channels (samples): the velocity
    /// check compares a filtered velocity with the encoder's slope over this window.
    pub filter_window: usize,
}

impl SafetySettings {
    /// Plausibility limit on joint angles (rad).
    pub const ANGLE_MAX: f64 = core::f64::consts::PI;
    /// Plausibility limit on joint velocities (rad/s).
    pub const VELOCITY_MAX: f64 = 30.0;
    /// Default hold-off before a monitor clears (s).
    pub const CLEAR_AFTER_S: f64 = 0.1;
    /// A handover within this long (s) of a definite sensor fault (a non-finite, out-of-range
    /// or frozen channel; not a sample outside an innovation gate, which a failing controller
    /// can cause) does not count toward the latch: the latch is for a failing controller.
    pub const SENSOR_FAULT_GRACE_S: f64 = 0.5;
}

/// What the safety monitor does when it trips.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum MonitorResponse {
    /// Hold the last safe torque; after [`RESPONSE_ESCALATE_S`] with the trip's cause present,
    /// the transparent fallback (when the supervisor has one).
    Hold,
    /// Ramp the torque to zero at [`STOP_RAMP_NM_PER_S`] (within the rate limit); after
    /// [`RESPONSE_ESCALATE_S`] with the trip's cause present, the transparent fallback (when
    /// the supervisor has one).
    RampToZero,
    /// Switch to the transparent fallback controller ([`Transparent`]: the robot's own
    /// gravity, friction, most of its inertia and the estimated payload compensated, no intent
    /// feed-forward), within the rate limit; `ramp_to_zero` while an encoder channel (q, qd)
    /// is invalid or silent (a silent or saturated force channel only freezes its payload
    /// estimate).
    Fallback,
}

/// `[monitors]`: runtime safety monitors.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Monitors {
    /// Trip when the human-robot angle error `|q_H − q_R|` of some joint, estimated from the
    /// measured strap forces by inverting the strap model (`F = ks J (Δq + (cs/ks) Δqd)`,
    /// docs/MODEL.md §4), exceeds this (rad), > 0. Default 0.35 (20°; the default scenario
    /// stays below 0.15).
    pub tracking_error_max_rad: f64,
    /// Trip when any measured strap force exceeds this (N), > 0; when this is at most the
    /// force sensor's range (`[faults] saturation_n`, 70 N), a reading at full scale trips
    /// too. Default 70.
    pub force_max_n: f64,
    /// Persistent-fault limit (s), > 0: a sensor channel rejected (non-finite, out of range,
    /// frozen or outside its innovation gate, see [`ChannelGuard`]) for longer than this trips
    /// the `sensor_timeout` monitor, whose response is always the protective stop (torque
    /// ramped to zero at [`STOP_RAMP_NM_PER_S`] and held until every channel has been good for
    /// 0.1 s, then handed back to the controller over [`STOP_HANDBACK_STEPS`]). Shorter faults
    /// are ridden through on the channel's estimate. Default 0.5.
    pub sensor_timeout_s: f64,
    /// Response when tripped (`"hold"`, `"ramp_to_zero"` or `"fallback"`, the transparent
    /// fallback controller; `hold` and `ramp_to_zero` hand over to the fallback when they have
    /// had the torque for [`RESPONSE_ESCALATE_S`] and the trip's cause is present). Default
    /// `"fallback"`.
    pub response: MonitorResponse,
    /// Oscillation monitor: trip when the RMS of a measured strap force's content above
    /// `oscillation_cutoff_hz` over the last `oscillation_window_s` exceeds this (N), > 0.
    /// Default 8.
    pub oscillation_force_rms_n: f64,
    /// Oscillation monitor: the same on the commanded joint torques (N·m), > 0. Default 10.
    pub oscillation_torque_rms_nm: f64,
    /// Oscillation monitor high-pass cutoff (Hz), > 0; a cutoff at or above the Nyquist
    /// frequency `0.5 / timing.dt` is taken just below it. Default 3.
    pub oscillation_cutoff_hz: f64,
    /// Oscillation monitor sliding window (s), in (0, 10]; at least one sample. Default 0.5.
    pub oscillation_window_s: f64,
    /// Gait-following cut-off: the oscillation monitors high-pass at
    /// `max(oscillation_cutoff_hz, oscillation_cutoff_gait_ratio · f̂)`, `f̂` the gait frequency
    /// estimated from the human's joint angles ([`GaitFrequency`]: encoder angle plus the
    /// strap-model angle error, at most [`GAIT_MAX_HZ`]), so that a fast gait's own torque and
    /// force (its fundamental, which a second-order high-pass passes with gain
    /// `1/√(1 + (f_c/f)⁴)`) is not taken for an oscillation (docs/ROBUSTNESS.md §4, eighth
    /// pass). Until a gait frequency is estimated (one gait period after the first upward
    /// crossing) the cut-off is `oscillation_cutoff_hz`. 0 keeps the cut-off fixed; in
    /// [0, 20]. Default 3: the default
    /// cut-off's ratio to the default gait's fastest frequency (3 Hz / 1.0 Hz), so the default
    /// scenario keeps its 3 Hz.
    pub oscillation_cutoff_gait_ratio: f64,
    /// A tripped oscillation monitor (which applies `response`) clears after its condition
    /// has been absent this long (s), in [0, 1e6]: longer than the other monitors' 0.1 s so
    /// that a limit cycle does not restart at once. Default 2.
    pub oscillation_clear_s: f64,
    /// Latch after repeated trips: when the supervisor has taken the torque from the
    /// controller (a *handover*: a tracking-error, strap-force or oscillation monitor tripped
    /// while none of them was; sensor timeouts do not count) this many times within
    /// `latch_window_s`, it latches: the response keeps the torque when the monitors clear,
    /// until [`Supervisor::reset_latch`] (an operator's reset), instead of handing back to a
    /// controller that has just failed again. 0 disables the latch; in 0..=1000. Default 2 (the
    /// controller gets one second chance a minute).
    pub latch_trips: usize,
    /// The window of `latch_trips` (s), in (0, 1e6]. Default 60.
    pub latch_window_s: f64,
    /// The encoders' angle step (rad), in [0, 0.01]: a quantised angle repeats legitimately
    /// while its joint moves less than a step per period, so an angle repeated bit for bit is
    /// taken for frozen only while the joint moves faster than
    /// `max(STUCK_SPEED, 2 · encoder_step_rad / dt)` ([`ChannelGuard::with_encoder_step`];
    /// twice the step per period: the test reads the filtered velocity, which lags the
    /// joint's by two samples where the leg turns), and on its first repeat only where the
    /// angles' quadratic extrapolation moves it by more than 4 steps (a turn between two
    /// samples). 0 (default): `STUCK_SPEED` (0.05 rad/s)
    /// alone, as for exact angles; on the 1-Hz test gait the T-Motor AK's 16-bit position
    /// (0.38 mrad) raised no rejection with it, a 12-bit encoder per turn (1.53 mrad) one at
    /// every turn of the leg. `exompc run` with CiA 402 drives takes at least one position
    /// increment at the joint, `2π / (counts_per_rev · gear_ratio)`.
    pub encoder_step_rad: f64,
    /// `[monitors.fallback]`: the transparent fallback controller of `response = "fallback"`
    /// (and what `hold` and `ramp_to_zero` hand over to, [`RESPONSE_ESCALATE_S`]).
    pub fallback: FallbackSettings,
}

impl Default for Monitors {
    fn default() -> Self {
        Self {
            tracking_error_max_rad: 0.35,
            force_max_n: 70.0,
            sensor_timeout_s: 0.5,
            response: MonitorResponse::Fallback,
            oscillation_force_rms_n: 8.0,
            oscillation_torque_rms_nm: 10.0,
            oscillation_cutoff_hz: 3.0,
            oscillation_window_s: 0.5,
            oscillation_cutoff_gait_ratio: 3.0,
            oscillation_clear_s: 2.0,
            latch_trips: 2,
            latch_window_s: 60.0,
            encoder_step_rad: 0.0,
            fallback: FallbackSettings::default(),
        }
    }
}

impl Monitors {
    /// Largest `latch_trips`.
    pub const MAX_LATCH_TRIPS: usize = 1000;
    /// Largest `encoder_step_rad` (rad): 20 rad/s at 10 ms would switch the frozen-angle test off.
    pub const MAX_ENCODER_STEP_RAD: f64 = 0.01;

    /// Checks every threshold, cutoff and time (finite, > 0; the window in (0, 10], the gait
    /// ratio in [0, 20], the clear time in [0, 1e6], the encoder step in [0, 0.01], the latch
    /// window in (0, 1e6],
    /// `latch_trips` in 0..=1000); the error names the key (`force_max_n`, ...).
    pub fn validate(&self) -> Result<(), InvalidField> {
        check::reals(&[
            (
                "tracking_error_max_rad",
                self.tracking_error_max_rad,
                Range::Pos,
            ),
            ("force_max_n", self.force_max_n, Range::Pos),
            ("sensor_timeout_s", self.sensor_timeout_s, Range::Pos),
            (
                "oscillation_force_rms_n",
                self.oscillation_force_rms_n,
                Range::Pos,
            ),
            (
                "oscillation_torque_rms_nm",
                self.oscillation_torque_rms_nm,
                Range::Pos,
            ),
            (
                "oscillation_cutoff_hz",
                self.oscillation_cutoff_hz,
                Range::Pos,
            ),
            (
                "oscillation_window_s",
                self.oscillation_window_s,
                Range::OpenClosed(0.0, 10.0),
            ),
            (
                "oscillation_cutoff_gait_ratio",
                self.oscillation_cutoff_gait_ratio,
                Range::Closed(0.0, 20.0),
            ),
            (
                "oscillation_clear_s",
                self.oscillation_clear_s,
                Range::Closed(0.0, 1e6),
            ),
            (
                "encoder_step_rad",
                self.encoder_step_rad,
                Range::Closed(0.0, Self::MAX_ENCODER_STEP_RAD),
            ),
            (
                "latch_window_s",
                self.latch_window_s,
                Range::OpenClosed(0.0, 1e6),
            ),
        ])?;
        check::int("latch_trips", self.latch_trips, 0, Self::MAX_LATCH_TRIPS)?;
        self.fallback
            .validate()
            .map_err(|e| InvalidField::new(&format!("fallback.{}", e.field), e.value, e.allowed))
    }
}

/// A runtime safety monitor.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum MonitorKind {
    /// Estimated `|q_H − q_R| > tracking_error_max_rad` on some joint.
    TrackingError,
    /// `|F| > force_max_n` on some strap, or, when `force_max_n ≤ saturation_n`, a reading at
    /// the force sensor's full scale (`|F| ≥ saturation_n`: the true force is at least the
    /// range, which a clipped reading can never exceed).
    StrapForce,
    /// A channel without a fresh valid sample for longer than `sensor_timeout_s`.
    SensorTimeout,
    /// Strap-force RMS above the cutoff over the window `> oscillation_force_rms_n`.
    ForceOscillation,
    /// Torque RMS above the cutoff over the window `> oscillation_torque_rms_nm`.
    TorqueOscillation,
    /// The transparent fallback's demanded torque moved by more than
    /// [`FALLBACK_DEMAND_JUMP`] × the rate limit in one period, to beyond
    /// [`FALLBACK_DEMAND_BEYOND`] × the torque limit (in [`MonitorAction::Stop`] events only:
    /// a check of the fallback, not a monitor of the controller).
    FallbackDemand,
}

const MONITORS: [MonitorKind; 5] = [
    MonitorKind::TrackingError,
    MonitorKind::StrapForce,
    MonitorKind::SensorTimeout,
    MonitorKind::ForceOscillation,
    MonitorKind::TorqueOscillation,
];

/// A strap force reading full scale this long (s) trips the sensor-timeout monitor, with the
/// configured response (the limit of such readings before issue 28).
pub const RAILED_TIMEOUT_S: f64 = 0.05;

/// A transparent fallback whose demanded torque moves by more than this many times the rate
/// limit `ΔT_max` in one period, to beyond [`FALLBACK_DEMAND_BEYOND`] × the torque limit, is
/// diverging (issue 28): the actuator cannot follow such a demand, and it comes from the
/// fallback's estimate of the human motion (differentiated twice) feeding on the robot's own
/// acceleration. Measured on 2026-12-05: the fallback's demand moves by at most 3.4 × on the
/// hard cells at 3 kg (`tests/response_paths.rs`); in the envelope's 1.3-Hz gait at 3 kg
/// (beyond the actuator) by up to 6.7 ×, to at most 1.3 × the limit; where it diverged after a
/// 1-s spike of both forces at 0 kg, by 4.6 ×, to 1.75 × (docs/RELIABILITY.md §2).
pub const FALLBACK_DEMAND_JUMP: f64 = 4.0;

/// The torque-limit multiple a diverging fallback's demand lands beyond
/// ([`FALLBACK_DEMAND_JUMP`]).
pub const FALLBACK_DEMAND_BEYOND: f64 = 1.5;

/// Indices of the oscillation monitors in [`MONITORS`].
const OSCILLATION: [usize; 2] = [3, 4];

/// Indices of the monitors that see the *controller* fail (all but the sensor timeout: a
/// silent channel is a sensor fault, and the fallback needs the same sensors): their
/// handovers count toward the latch.
const LATCHING: [usize; 4] = [0, 1, 3, 4];

/// Half-cycles beyond the hysteresis band (the RMS threshold) an oscillation monitor needs in
/// its window, besides the RMS: one and a half periods, so that a single jolt (whose high-pass
/// response swings at most twice beyond the band) does not trip it.
pub const OSCILLATION_MIN_HALF_CYCLES: u32 = 3;

/// Sliding-window RMS of a signal's content above a cutoff frequency, per channel: a
/// second-order Butterworth high-pass (`control::HighPass`, shared with the robust method's
/// `HfShareDetector`; bilinear transform with pre-warping, so that
/// `|H(f)|² = 1 / (1 + (tan(π f_c dt) / tan(π f dt))⁴)` exactly) followed by the mean square
/// of its output over the last `window` samples, kept in a ring buffer allocated once.
#[derive(Clone, Debug)]
pub struct OscillationDetector<const N: usize> {
    hp: HighPass<N>,
    ring: Vec<SVector<f64, N>>,
    pos: usize,
    filled: usize,
    sum: SVector<f64, N>,
    /// Hysteresis band of the half-cycle count (0: counting off).
    band: f64,
    /// Per channel: sign (+1 / −1 / 0 = none yet) of the last excursion beyond `±band`.
    side: SVector<f64, N>,
    /// Per sample: 1 where the channel completed a half-cycle (ring aligned with `ring`).
    turns: Vec<SVector<f64, N>>,
    turn_sum: SVector<f64, N>,
}

impl<const N: usize> OscillationDetector<N> {
    /// High-pass at `cutoff_hz` for samples every `dt` s, RMS over `window_s` (at least one
    /// sample). Out-of-range values are brought into range: the cutoff into (0, Nyquist).
    pub fn new(cutoff_hz: f64, dt: f64, window_s: f64) -> Self {
        let dt = if dt.is_finite() && dt > 0.0 { dt } else { 0.01 };
        let w = if window_s.is_finite() {
            ((window_s / dt).round() as usize).clamp(1, 1 << 20)
        } else {
            1
        };
        OscillationDetector {
            hp: HighPass::new(cutoff_hz, dt),
            ring: vec![SVector::zeros(); w],
            pos: 0,
            filled: 0,
            sum: SVector::zeros(),
            band: 0.0,
            side: SVector::zeros(),
            turns: vec![SVector::zeros(); w],
            turn_sum: SVector::zeros(),
        }
    }

    /// Also count half-cycles: a half-cycle is completed each time the high-passed signal
    /// swings from beyond `−band` to beyond `+band` or back (hysteresis, so noise around zero
    /// does not count). [`OscillationDetector::half_cycles`] gives the count over the window.
    /// A limit cycle completes two per period; a single jolt (a step or a pulse, whose
    /// high-pass response rings out within about one period of the cutoff) at most two or three.
    pub fn with_hysteresis(mut self, band: f64) -> Self {
        self.band = if band.is_finite() { band.max(0.0) } else { 0.0 };
        self
    }

    /// Per-channel number of half-cycles beyond the hysteresis band over the window (0 when
    /// the band is 0).
    pub fn half_cycles(&self) -> SVector<f64, N> {
        self.turn_sum.map(|s| s.max(0.0).round())
    }

    /// Moves the high-pass cut-off to `cutoff_hz` for samples every `dt` s, keeping the
    /// filter's state and the window ([`HighPass::set_cutoff`]).
    pub fn set_cutoff(&mut self, cutoff_hz: f64, dt: f64) {
        self.hp.set_cutoff(cutoff_hz, dt);
    }

    /// Window length (samples).
    pub fn window(&self) -> usize {
        self.ring.len()
    }

    /// Feed one sample; returns the largest channel RMS over the (partly filled) window. A
    /// sample with a non-finite entry is skipped (the detector keeps its state).
    pub fn push(&mut self, v: &SVector<f64, N>) -> f64 {
        if !v.iter().all(|x| x.is_finite()) {
            return self.rms_max();
        }
        let y = self.hp.push(v);
        let sq = y.component_mul(&y);
        let w = self.ring.len();
        let mut turn = SVector::<f64, N>::zeros();
        if self.band > 0.0 {
            for j in 0..N {
                let side = if y[j] > self.band {
                    1.0
                } else if y[j] < -self.band {
                    -1.0
                } else {
                    0.0
                };
                if side != 0.0 && side != self.side[j] {
                    if self.side[j] != 0.0 {
                        turn[j] = 1.0;
                    }
                    self.side[j] = side;
                }
            }
        }
        self.turn_sum += turn - self.turns[self.pos];
        self.turns[self.pos] = turn;
        self.sum += sq - self.ring[self.pos];
        self.ring[self.pos] = sq;
        self.pos = (self.pos + 1) % w;
        self.filled = (self.filled + 1).min(w);
        if self.pos == 0 {
            // Re-sum once per window against rounding drift (amortised O(1)).
            self.sum = self.ring.iter().fold(SVector::zeros(), |a, b| a + b);
            self.turn_sum = self.turns.iter().fold(SVector::zeros(), |a, b| a + b);
        }
        self.rms_max()
    }

    /// Per-channel RMS of the high-passed signal over the window (0 before any sample; over
    /// the samples so far while the window fills).
    pub fn rms(&self) -> SVector<f64, N> {
        let n = self.filled.max(1) as f64;
        self.sum.map(|s| (s.max(0.0) / n).sqrt())
    }

    /// Largest channel RMS.
    pub fn rms_max(&self) -> f64 {
        self.rms().iter().copied().fold(0.0, f64::max)
    }

    /// True when some channel is *sustained* above `threshold`: its RMS over the window
    /// exceeds it and it completed at least `min_half_cycles` half-cycles beyond the hysteresis
    /// band (with counting off, the RMS alone decides).
    pub fn is_oscillating(&self, threshold: f64, min_half_cycles: u32) -> bool {
        let (rms, cycles) = (self.rms(), self.half_cycles());
        (0..N).any(|j| {
            rms[j] > threshold && (self.band <= 0.0 || cycles[j] >= f64::from(min_half_cycles))
        })
    }
}

/// The cut-off of the fallback's oscillation check as a multiple of the gait frequency
/// (`Supervisor::watch_fallback`; at least `oscillation_cutoff_hz`): above the third harmonic
/// of a torque that follows a fast gait at its limits (a 1.3-Hz gait at 3 kg, whose fallback
/// torque the gait-following cut-off of 3 × the gait took for an oscillation, measured on
/// 2026-12-05, docs/RELIABILITY.md §2).
pub const FALLBACK_OSCILLATION_GAIT_RATIO: f64 = 5.0;

/// Fastest gait frequency (Hz) the gait-following cut-off follows (`[monitors]
/// oscillation_cutoff_gait_ratio`): estimates above it count as this, so the cut-off never
/// exceeds `ratio · GAIT_MAX_HZ` (6 Hz with the default ratio 3).
pub const GAIT_MAX_HZ: f64 = 2.0;

/// Hysteresis band (rad) of [`GaitFrequency`]'s mean crossings: a joint must swing beyond
/// `±GAIT_BAND_RAD` around its running mean to complete a half-cycle.
pub const GAIT_BAND_RAD: f64 = 0.05;

/// Time constant (s) of [`GaitFrequency`]'s running mean of each joint angle.
pub const GAIT_MEAN_TAU_S: f64 = 2.0;

/// The gait's frequency from the human's joint angles `q̂_H = q_R + Δq̂` (encoder angle plus
/// the strap-model angle error of [`StrapAngleEstimate`], which follows the person and not a
/// robot oscillating against the straps), per joint: a running mean (first-order, time
/// constant [`GAIT_MEAN_TAU_S`]), upward crossings of it with hysteresis `±`[`GAIT_BAND_RAD`],
/// and the time `p` between the last two upward crossings (one period). A joint's estimate is
/// `1 / max(p, t − t_up)` (`t_up` the last upward crossing), so it falls at once when the gait
/// slows or stops; the estimate is the smallest over the joints that have one (the lower
/// cut-off), at most [`GAIT_MAX_HZ`]. On a sine gait it is the gait frequency within the period's
/// quantisation (one sample; test `gait_frequency_follows_a_sine_gait_and_ignores_a_small_4_hz_ripple`).
#[derive(Clone, Copy, Debug)]
pub struct GaitFrequency<const N: usize> {
    alpha: f64,
    mean: SVector<f64, N>,
    started: bool,
    side: SVector<f64, N>,
    /// Last upward crossing time per joint (NaN: none yet).
    up: SVector<f64, N>,
    /// The last period per joint (NaN: not yet).
    period: SVector<f64, N>,
}

impl<const N: usize> GaitFrequency<N> {
    /// For samples every `dt` s (non-positive or non-finite: 0.01 s).
    pub fn new(dt: f64) -> Self {
        let dt = if dt.is_finite() && dt > 0.0 { dt } else { 0.01 };
        GaitFrequency {
            alpha: 1.0 - (-dt / GAIT_MEAN_TAU_S).exp(),
            mean: SVector::zeros(),
            started: false,
            side: SVector::zeros(),
            up: SVector::repeat(f64::NAN),
            period: SVector::repeat(f64::NAN),
        }
    }

    /// Feed the human's joint angles `q_h` (rad) at time `t` (s); a sample with a non-finite
    /// entry (or time) is skipped.
    pub fn update(&mut self, q_h: &SVector<f64, N>, t: f64) {
        if !t.is_finite() || !q_h.iter().all(|v| v.is_finite()) {
            return;
        }
        if !self.started {
            self.mean = *q_h;
            self.started = true;
        }
        self.mean += (q_h - self.mean) * self.alpha;
        for j in 0..N {
            let e = q_h[j] - self.mean[j];
            let side = if e > GAIT_BAND_RAD {
                1.0
            } else if e < -GAIT_BAND_RAD {
                -1.0
            } else {
                0.0
            };
            if side != 0.0 && side != self.side[j] {
                if side > 0.0 && self.side[j] < 0.0 {
                    if self.up[j].is_finite() {
                        self.period[j] = t - self.up[j];
                    }
                    self.up[j] = t;
                }
                self.side[j] = side;
            }
        }
    }

    /// The gait frequency (Hz) at time `t`, at most [`GAIT_MAX_HZ`]; `None` until some joint
    /// has completed a period (two upward crossings).
    pub fn frequency(&self, t: f64) -> Option<f64> {
        let mut best: Option<f64> = None;
        for j in 0..N {
            let p = self.period[j];
            if !(p.is_finite() && p > 0.0) {
                continue;
            }
            let slowest = p.max(t - self.up[j]);
            let f = (1.0 / slowest).min(GAIT_MAX_HZ);
            best = Some(best.map_or(f, |b: f64| b.min(f)));
        }
        best
    }
}

/// The strap model `F = ks J (Δq + τ Δq̇)` of a supervisor of `N` joints (paper eqs. 3-4,
/// docs/MODEL.md §4): `(ks J, τ = cs/ks)`, `J(s, i) = Ls_i` for `i ≤ s` from the last `N` of
/// `levers` (hip outwards; a missing or non-positive lever counts as 1 m, a non-positive
/// stiffness as 1 N/m, a non-positive damping as none), and whether every one of those
/// levers and the stiffness were given (no stand-in).
fn strap_model<const N: usize>(
    levers: &[f64],
    stiffness: f64,
    damping: f64,
) -> (SMatrix<f64, N, N>, f64, bool) {
    let given: [Option<f64>; N] = core::array::from_fn(|i| {
        let j = (levers.len() + i).checked_sub(N);
        j.and_then(|j| levers.get(j))
            .copied()
            .filter(|l| l.is_finite() && *l > 0.0)
    });
    let stiffness_given = stiffness.is_finite() && stiffness > 0.0;
    let ks = if stiffness_given { stiffness } else { 1.0 };
    let j = SMatrix::<f64, N, N>::from_fn(|s, i| {
        if i <= s {
            ks * given[i].unwrap_or(1.0)
        } else {
            0.0
        }
    });
    let tau = if damping.is_finite() && damping > 0.0 {
        damping / ks
    } else {
        0.0
    };
    (j, tau, stiffness_given && given.iter().all(Option::is_some))
}

/// Human-robot angle error `Δq = q_H − q_R` estimated from measured strap forces by inverting
/// the strap model `F = ks J (Δq + τ Δqd)`, `τ = cs/ks` (paper eqs. 3-4, docs/MODEL.md §4):
/// `u = (ks J)⁻¹ F` is the error the springs alone would need, and `Δq` follows
/// `τ Δqd + Δq = u`, integrated exactly for `u` held over each period.
#[derive(Clone, Copy, Debug)]
pub struct StrapAngleEstimate<const N: usize> {
    inv: SMatrix<f64, N, N>,
    alpha: f64,
    dq: SVector<f64, N>,
    started: bool,
}

impl<const N: usize> StrapAngleEstimate<N> {
    /// From the strap levers (the last `N` of `levers`, hip outwards; a missing or
    /// non-positive lever counts as 1 m), stiffness, damping and control period `dt`.
    pub fn new(levers: &[f64], stiffness: f64, damping: f64, dt: f64) -> Self {
        let (j, tau, _) = strap_model::<N>(levers, stiffness, damping);
        let inv = j.try_inverse().unwrap_or_else(SMatrix::zeros);
        let alpha = if tau > 0.0 && dt.is_finite() && dt > 0.0 {
            1.0 - (-dt / tau).exp()
        } else {
            1.0
        };
        StrapAngleEstimate {
            inv,
            alpha,
            dq: SVector::zeros(),
            started: false,
        }
    }

    /// Update with measured forces `f` (N); returns the estimated `Δq` (rad). A non-finite
    /// force keeps the previous estimate.
    pub fn update(&mut self, f: &SVector<f64, N>) -> SVector<f64, N> {
        if f.iter().all(|v| v.is_finite()) {
            let u = self.inv * f;
            self.dq = if self.started {
                self.dq + (u - self.dq) * self.alpha
            } else {
                u
            };
            self.started = true;
        }
        self.dq
    }
}

/// A monitor tripping or clearing.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum MonitorAction {
    /// The monitor tripped; its response now sets the torque.
    Trip,
    /// The monitor cleared; the controller resumed.
    Clear,
    /// The supervisor latched (`[monitors] latch_trips` handovers within `latch_window_s`;
    /// `monitor` is the one whose trip made the last handover, `value` the number of
    /// handovers in the window): the response keeps the torque until a reset.
    Latch,
    /// The latch was reset ([`Supervisor::reset_latch`]); the controller resumes once no
    /// monitor is tripped (`monitor` is the one that latched, `value` 0).
    Reset,
    /// The transparent fallback failed: the protective stop (the ramp to zero at
    /// [`STOP_RAMP_NM_PER_S`]) replaces it until every monitor has cleared. It oscillated
    /// (its torque above `oscillation_torque_rms_nm` above [`FALLBACK_OSCILLATION_GAIT_RATIO`]
    /// × the gait frequency, after it had had the torque for `oscillation_window_s`; `monitor`
    /// is [`MonitorKind::TorqueOscillation`], `value` the torque's RMS over the window, N·m),
    /// or its demand diverged (`monitor` is [`MonitorKind::FallbackDemand`], `value` the
    /// demand's move over one period, N·m).
    Stop,
    /// The configured `hold` or `ramp_to_zero` had had the torque for [`RESPONSE_ESCALATE_S`]
    /// and the trip's cause was present (or the latch): the transparent fallback takes it
    /// until every monitor has cleared (`monitor` is a tripped monitor whose condition
    /// persists, or the one that latched; `value` the response's time so far, s).
    Escalate,
    /// A monitor that sees the controller fail tripped, the controller having had the torque,
    /// within [`UNVERIFIED_S`](super::UNVERIFIED_S) of an encoder channel being believed again
    /// on smoothness alone: those channels are rejected again
    /// ([`ChannelGuard::revoke_unverified`]), their fault continuing, so the persistent-fault
    /// limit brings the protective stop for an angle (`monitor` is the one that tripped,
    /// `value` the number of channels rejected again).
    Revoke,
}

/// One logged monitor event.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct MonitorEvent {
    /// Supervisor time (s): first measurement time plus steps × dt.
    pub t: f64,
    /// Which monitor.
    pub monitor: MonitorKind,
    /// Trip or clear.
    pub action: MonitorAction,
    /// The offending value at a trip (rad, N or s), 0 at a clear.
    pub value: f64,
}

/// Counters and the event log of a [`Supervisor`].
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct SafetyReport {
    /// Steps supervised.
    pub steps: u64,
    /// Steps whose measurement was rejected (non-finite or implausible).
    pub bad_measurement_steps: u64,
    /// Monitor trips (all monitors).
    pub monitor_trips: u64,
    /// Steps on which a monitor's response set the torque.
    pub monitor_steps: u64,
    /// Logged events, in time order (at most `max_events`).
    pub events: Vec<MonitorEvent>,
    /// Events not stored because the log was full.
    pub events_dropped: u64,
    /// Handovers: times the supervisor took the torque from the controller because it failed
    /// (a tracking-error, strap-force or oscillation monitor tripped while none of them was;
    /// several tripping together make one handover; sensor timeouts do not count).
    pub handovers: u64,
    /// Times the transparent fallback failed (oscillated or diverged) and the protective stop
    /// replaced it ([`MonitorAction::Stop`]).
    pub fallback_stops: u64,
    /// Times the configured `hold` or `ramp_to_zero` handed the torque to the transparent
    /// fallback after [`RESPONSE_ESCALATE_S`] ([`MonitorAction::Escalate`]).
    pub escalations: u64,
    /// Times encoder channels believed on smoothness alone were rejected again because the
    /// controller failed right after ([`MonitorAction::Revoke`]).
    pub revocations: u64,
    /// Supervisor time (s) at which it latched (`[monitors] latch_trips`), `None` when it has
    /// not, or when the latch was reset since.
    pub latched_at: Option<f64>,
    /// The monitor whose trip made the latching handover, `None` when not latched.
    pub latched_by: Option<MonitorKind>,
    /// How long (s) the latch alone (no monitor tripped) kept the torque from the controller.
    pub latched_for_s: f64,
    /// Steps on which some channel was rejected and the controller stepped on its estimate.
    pub estimated_steps: u64,
    /// Channel fault episodes: a channel (angle, velocity or force of one joint) rejected
    /// after being good.
    pub sensor_faults: u64,
}

/// Rate (N·m/s) at which `ramp_to_zero` and the protective stop take the torque to zero (the
/// torque-rate limit bounds it too): 30 N·m in 0.3 s. At the default rate limit (1000 N·m/s,
/// 10 N·m a period) the load dropped onto the person within 1-3 periods: on the hard cells of
/// the envelope at 3 kg the protective stop stepped a true strap force by up to 27 N in one
/// period, 15 N at this rate (issue 28; docs/RELIABILITY.md §2b, the measured table).
pub const STOP_RAMP_NM_PER_S: f64 = 100.0;

/// Steps over which the torque goes back from the replay of one gait period back (every
/// encoder channel, or one joint's encoder, lost) to the controller's, linearly (0.1 s at
/// 10 ms).
pub const REPLAY_HANDBACK_STEPS: u32 = 10;

/// Steps over which the torque goes back from the protective stop's (where its ramp to zero
/// was) to the controller's when the stop ends, linearly (0.2 s at 10 ms). Handed the torque
/// at once, the controller asked for up to the torque limit on its first steps, with the
/// robot lagging the person it had not held (a 1-s NaN of both angles at 2.5 s, 3 kg:
/// 84.7 N). Over 10 steps a 1-s spike of every sensor at 1 s, 3 kg, latched; 20, 30 and 50
/// steps did not, and changed no other verdict of the scans (docs/RELIABILITY.md §2).
pub const STOP_HANDBACK_STEPS: u32 = 20;

/// Steps over which the torque blends from the applied one into the replay of the torque one
/// gait period back when every encoder channel is lost (0.05 s at 10 ms; one joint's coast
/// starts from the applied torque by the offset `T(k₀ − 1) − T(k₀ − 1 − p)` instead, fading
/// out over one period, docs/RELIABILITY.md §2): the gait is not
/// exactly periodic, and the replay's first value differs from the applied torque by up to
/// several N·m, which the rate limit (10 N·m a period) let through in one step. Measured on
/// 2026-12-05 (docs/RELIABILITY.md §2, the scans of §2a): 3 / 5 / 8 steps took the fine phase
/// scan from 2310 to 2318 / 2319 / 2317 of 2432 (stuck or dropped angles, 1 and 3 kg) and the
/// wider scan from 372 to 373 of 384; 8 steps lost a cell of the 1-s scan; a blend over 5
/// steps also into the torque's extrapolation of the first gait period lost three angle
/// cells at 1.75 s (8.4-10.4 → 27.1-37.2 N), so that one starts at the applied torque as it
/// was ([`TorqueExtrapolation`]).
pub const REPLAY_BLEND_IN_STEPS: u32 = 5;

/// Gain of the strap-force feedback on one joint's coast: while a joint's encoder is lost and
/// the strap forces are measured, the coast's torque (the replay of one gait period back, or
/// the torque's extrapolation before the period is known) is corrected by
/// `COAST_FORCE_GAIN · Jᵀ (F − F₀)`, `F₀` the strap forces when the coast began and `Jᵀ` the
/// straps' lever map (paper eqs. 3-4: `Jᵀ F` is the strap torque on the robot). The replay is
/// open loop: the gait is not exactly periodic (early in a run the torque one period back lay
/// 3-4 N·m off), and the strap stretch it left built up over the coast; the measured forces
/// see it. The correction ends with the joint's coast (the handback blends the controller in
/// from the replay without it; the rate limit bounds that step); in a coast longer than one
/// gait period the replayed torque carries the correction of one period back, to which the
/// new one adds. Chosen by measurement (docs/RELIABILITY.md §2, "One joint's encoder"): 1 / 2
/// / 3 took the fine joint scan to 1214 / 1216 / 1216 of 1216 cells (worst 13.1 / 10.1 /
/// 11.8 N) and its 1-s scan to 286 / 288 / 288 of 288 (worst 117.8 / 56.1 / 54.7 N).
pub const COAST_FORCE_GAIN: f64 = 2.0;

/// How long (s) the configured `hold` or `ramp_to_zero` keeps the torque before the
/// transparent fallback takes it, if the trip's cause is then present (a tripped monitor's
/// condition, still or again before the monitors have cleared, or the latch;
/// [`MonitorAction::Escalate`]). On a moving leg a held torque stops
/// fitting within a few periods and a zero torque hands robot and payload to the person;
/// either left the strap force at full scale, which kept the strap-force monitor tripped: on the
/// hard cells at 3 kg (docs/RELIABILITY.md §2b) `hold` peaked at 214 N and `ramp_to_zero` at
/// 164 N for the rest of the run. Measured there (escalation after 0.02 / 0.03 / 0.04 / 0.1 /
/// 0.2 s): 0.02 s keeps every `hold` and `ramp_to_zero` run at or below 67 N and 1.5× the
/// clean RMS; from 0.04 s on some run was left to the protective stop after the fallback,
/// started on a leg already pushed away, diverged (up to 166 N).
pub const RESPONSE_ESCALATE_S: f64 = 0.02;

/// The blend of a handback from `from` to `to` with `left` of `steps` steps left: linear in
/// the step, `to` once none is left.
fn handback_blend<const N: usize>(
    from: SVector<f64, N>,
    to: SVector<f64, N>,
    left: u32,
    steps: u32,
) -> SVector<f64, N> {
    let a = 1.0 - f64::from(left) / f64::from(steps + 1);
    from + (to - from) * a
}

/// Runtime safety supervision (exoskeleton-firmware style): measurement plausibility checks
/// with a safe fallback, and the `[monitors]` of the scenario, wrapped around any controller.
///
/// [`Supervisor`] implements [`Controller`] around an inner controller:
///
/// * **Plausibility.** A measurement with a non-finite value, `|q| > angle_max` (π),
///   `|qd| > velocity_max` (30 rad/s) or `|F| ≥ saturation_n` (the force sensor's range) is
///   rejected: the inner controller is *not* stepped (it is never fed garbage) and the previous
///   torque is held (status [`StepStatus::BadMeasurement`]). When the data is good again the
///   inner controller resumes from the torque actually applied (kept in sync through
///   [`Controller::set_previous_torque`]).
/// * **Monitors.** The human-robot angle error `|q_H − q_R|` (q_H is not measured: it is
///   estimated from the measured strap forces by inverting the strap model
///   `F = ks J (Δq + τ Δqd)`, `τ = cs/ks`, docs/MODEL.md §4, see [`StrapAngleEstimate`])
///   above `tracking_error_max_rad`, strap force above `force_max_n` or (when
///   `force_max_n ≤ saturation_n`) at the sensor's full scale, and any sensor channel
///   without a fresh valid sample (non-finite, implausible, or bit-for-bit repeated) for longer
///   than `sensor_timeout_s`. A tripped monitor applies the configured response (`hold` the
///   last safe torque: the torque of the last fully measured step with no monitor tripped,
///   reached within the rate limit; or `ramp_to_zero` at [`STOP_RAMP_NM_PER_S`]; status
///   [`StepStatus::MonitorTripped`]; `hold` and `ramp_to_zero` hand the torque to the
///   transparent fallback when they have had it for [`RESPONSE_ESCALATE_S`] and the trip's
///   cause is present, [`MonitorAction::Escalate`]); it clears after its condition has been
///   absent for
///   `clear_after_s`, and the inner controller resumes from the applied torque. Trips and
///   clears are logged with their time in a bounded event list ([`SafetyReport`]).
/// * **Oscillation.** The measured strap forces and the commanded torques each pass a
///   second-order Butterworth high-pass at `oscillation_cutoff_hz` (3 Hz: the gait lives
///   below, the delay-driven limit cycles near 4 Hz above); the RMS of its output over the
///   last `oscillation_window_s` ([`OscillationDetector`], a ring buffer) above
///   `oscillation_force_rms_n` / `oscillation_torque_rms_nm` trips the oscillation monitor;
///   for the forces only when *sustained* (the high-passed force swung across `±threshold`
///   at least [`OSCILLATION_MIN_HALF_CYCLES`] times in the window), so that a single jolt
///   from the person does not trip it.
///   It applies the configured `response` like the other monitors and clears after
///   `oscillation_clear_s` (2 s) without oscillation, so that a limit cycle does not restart
///   at once.
/// * **The fallback's stop.** Once the gait frequency is known and the transparent fallback
///   has had the torque for `oscillation_window_s`, an applied torque oscillating above
///   `oscillation_torque_rms_nm` with content above [`FALLBACK_OSCILLATION_GAIT_RATIO`] × the
///   gait frequency (sustained: [`OSCILLATION_MIN_HALF_CYCLES`] half-cycles) hands the torque
///   to the protective stop until every monitor has cleared ([`MonitorAction::Stop`],
///   [`SafetyReport::fallback_stops`]).
/// * **Latch.** Each time a monitor that sees the controller fail (tracking error, strap force,
///   force or torque oscillation; not the sensor timeout, a sensor fault) trips while none of
///   them was, the supervisor takes the torque from the controller (a *handover*, counted in
///   [`SafetyReport::handovers`]). After
///   `latch_trips` (2) handovers within `latch_window_s` (60 s) it latches: the response
///   keeps the torque when the monitors clear (a controller that failed twice in a minute
///   is not handed the person again), until [`Supervisor::reset_latch`]. The latch is
///   logged ([`MonitorAction::Latch`]) with its time in [`SafetyReport::latched_at`].
/// * **Limits.** Every output passes through [`TorqueLimits::clamp`] relative to the previous
///   output, so `|T| ≤ T_max` and `|T − T_prev| ≤ ΔT_max` hold whatever the inner controller
///   returns (NaN included).
///
/// The hot path does not allocate (the event list is preallocated; events beyond its capacity
/// are counted, not stored).
#[derive(Clone, Debug)]
pub struct Supervisor<const N: usize, C> {
    inner: C,
    s: SafetySettings,
    prev: SVector<f64, N>,
    k: u64,
    t0: f64,
    /// Per-channel fault detection and the estimates of rejected channels.
    guard: ChannelGuard<N>,
    /// Last time a channel was rejected (latch grace).
    fault_t: f64,
    /// Time of the previous measurement (s; NaN before the first): a later one more than
    /// 1.5 periods on follows a gap in the data.
    last_t: f64,
    /// How long (s) some strap force has read full scale, and whether the sensor-timeout
    /// monitor tripped on that (configured response) rather than on a sensor fault (stop).
    railed_for: f64,
    railed_trip: bool,
    tripped: [bool; 5],
    ok_since: [Option<f64>; 5],
    angle: StrapAngleEstimate<N>,
    force_osc: OscillationDetector<N>,
    torque_osc: OscillationDetector<N>,
    /// The gait frequency of the gait-following cut-off, and the detectors' cut-off now (Hz).
    gait: GaitFrequency<N>,
    cutoff_hz: f64,
    fallback: Option<Transparent<N>>,
    /// A controller-failure monitor (or the latch) had the torque on the previous step.
    engaged: bool,
    latched: bool,
    /// Times of the last `latch_trips` handovers (ring, allocated once).
    handover_t: Vec<f64>,
    handover_pos: usize,
    latch_monitor: MonitorKind,
    report: SafetyReport,
    /// Applied torques of the last [`ChannelGuard::HISTORY_S`] (ring, allocated once), for
    /// the torque replay while every encoder channel, or one joint's encoder, is lost.
    torque_hist: Vec<SVector<f64, N>>,
    /// The angles the controller stepped on over the last [`EXTRAPOLATION_ANGLE_S`] (ring,
    /// advanced with `torque_hist`): the gait frequency of the torque extrapolation before a
    /// gait period is known.
    angle_hist: Vec<SVector<f64, N>>,
    angle_pos: usize,
    torque_pos: usize,
    torque_filled: usize,
    /// The torque extrapolation while an encoder is lost (every one, or one joint's) before
    /// the gait period is known (`None`: hold the torque), and the steps since it began.
    extrapolation: Box<Option<TorqueExtrapolation<N>>>,
    extrapolated_steps: u32,
    /// The transparent fallback's demanded torque of the previous step while it had the
    /// torque (the divergence check of `watch_fallback`).
    fallback_demand: Option<SVector<f64, N>>,
    /// The previous step fed the fallback a measurement (it restarts when fed again after
    /// steps without one).
    fallback_fed: bool,
    /// The current coast began with a stalled acquisition, or one came within it
    /// ([`Repaired::stalled`]).
    stall_coast: bool,
    /// Per joint, consecutive steps its angle (`[0]`) and its velocity (`[1]`) have been
    /// estimates: a joint's two channels lost within the filter window of each other are
    /// one encoder's fault ([`Supervisor::joint_lost`]).
    estimated_for: [[u32; N]; 2],
    /// The current coast began with a joint's encoder lost, not every encoder: it lasts while
    /// a joint's angle is estimated, or a channel of a joint whose angle and velocity were both
    /// estimates within it (`coast_joints`), not until every channel is back.
    joint_coast: bool,
    /// The joints whose angle and velocity were both estimates within the current coast.
    coast_joints: [bool; N],
    /// The torque replay had the torque on the previous step.
    coasting: bool,
    /// Steps left of the blend into the torque replay of one gait period back, and the
    /// applied torque it starts from ([`REPLAY_BLEND_IN_STEPS`]).
    blend_in: u32,
    blend_in_from: SVector<f64, N>,
    /// One joint's coast: the offset that continues the applied torque into the replay of one
    /// gait period back, `T(k₀ − 1) − T(k₀ − 1 − p)` (`k₀` the coast's first step), fading
    /// out over one period, and the steps since the coast began.
    coast_offset: SVector<f64, N>,
    coast_steps: u32,
    /// One joint's coast: the strap forces when it began (`None`: they were estimates), from
    /// which the strap-force feedback counts their change ([`COAST_FORCE_GAIN`]).
    coast_force0: Option<SVector<f64, N>>,
    /// Steps left of the blend from the replay back to the controller, and the replay's lag
    /// (steps) on the last step.
    handback: u32,
    replay_lag_now: Option<usize>,
    /// The current (or last) coast began with the channel guard's replay lag known: the torque
    /// replays at it.
    replay_at_guard_lag: bool,
    /// The protective stop had the torque on the previous step.
    stopped: bool,
    /// Steps left of the blend from the end of the protective stop back to the controller,
    /// and the torque it starts from.
    stop_handback: u32,
    stop_handback_from: SVector<f64, N>,
    /// The torque of the last fully measured step (every channel measured, no monitor
    /// tripped, no replay): what `hold` holds.
    last_safe: SVector<f64, N>,
    /// When the transparent fallback took the torque (`None`: it does not have it).
    fallback_since: Option<f64>,
    /// The applied torque's oscillation well above the gait (cut-off
    /// [`FALLBACK_OSCILLATION_GAIT_RATIO`] × the gait frequency, sustained half-cycles), and
    /// its cut-off now (Hz): the fallback's own oscillation (`watch_fallback`).
    fallback_osc: OscillationDetector<N>,
    fallback_cutoff_hz: f64,
    /// The fallback failed: the protective stop has the torque until the monitors clear.
    fallback_failed: bool,
    /// When the configured `hold` or `ramp_to_zero` took the torque (`None`: it does not
    /// have it), and whether it has handed it to the fallback ([`RESPONSE_ESCALATE_S`]).
    response_since: Option<f64>,
    escalated: bool,
}

impl<const N: usize, C: Controller<N>> Supervisor<N, C> {
    /// Wrap `inner`; the supervisor starts from the inner controller's previous torque.
    pub fn new(inner: C, settings: SafetySettings) -> Self {
        let cap = settings.max_events;
        let settings_latch_trips = settings.monitors.latch_trips.min(Monitors::MAX_LATCH_TRIPS);
        let prev = settings.limits.admissible(&inner.previous_torque());
        let mo = &settings.monitors;
        let detector = |band: f64| {
            OscillationDetector::new(
                mo.oscillation_cutoff_hz,
                settings.dt,
                mo.oscillation_window_s,
            )
            .with_hysteresis(band)
        };
        // Strap forces see jolts from the person (a stumble, a bump): count half-cycles. The
        // commanded torque is the controller's own, rate-limited output: its RMS alone trips.
        let force_osc = detector(mo.oscillation_force_rms_n);
        let torque_osc = detector(0.0);
        let fallback_osc = detector(mo.oscillation_torque_rms_nm);
        let (ks_j, tau, known_straps) = strap_model::<N>(
            &settings.strap_levers_m,
            settings.strap_stiffness,
            settings.strap_damping,
        );
        let angle = StrapAngleEstimate::new(
            &settings.strap_levers_m,
            settings.strap_stiffness,
            settings.strap_damping,
            settings.dt,
        );
        let gait = GaitFrequency::new(settings.dt);
        let cutoff_hz = settings.monitors.oscillation_cutoff_hz;
        let hist_len = ((ChannelGuard::<N>::HISTORY_S / settings.dt.max(1e-6)).ceil() as usize)
            .clamp(8, 1 << 16);
        let angle_len = ((EXTRAPOLATION_ANGLE_S / settings.dt.max(1e-6)).ceil() as usize + 2)
            .clamp(8, hist_len);
        let guard = ChannelGuard::new(
            settings.dt,
            settings.filter_window,
            [
                settings.angle_max,
                settings.velocity_max,
                settings.saturation_n,
            ],
        );
        let guard = guard.with_encoder_step(settings.monitors.encoder_step_rad);
        // The force gate's robot part needs the scenario's own straps, not the stand-ins.
        let guard = if known_straps {
            guard.with_straps(ks_j, tau)
        } else {
            guard
        };
        let mut sup = Supervisor {
            inner,
            s: settings,
            prev,
            k: 0,
            t0: 0.0,
            guard,
            fault_t: f64::NEG_INFINITY,
            last_t: f64::NAN,
            railed_for: 0.0,
            railed_trip: false,
            tripped: [false; 5],
            ok_since: [None; 5],
            angle,
            force_osc,
            torque_osc,
            gait,
            cutoff_hz,
            fallback: None,
            engaged: false,
            latched: false,
            handover_t: vec![f64::NEG_INFINITY; settings_latch_trips.max(1)],
            handover_pos: 0,
            latch_monitor: MonitorKind::TorqueOscillation,
            report: SafetyReport {
                events: Vec::with_capacity(cap),
                ..Default::default()
            },
            torque_hist: vec![SVector::zeros(); hist_len],
            angle_hist: vec![SVector::zeros(); angle_len],
            angle_pos: 0,
            fallback_demand: None,
            fallback_fed: false,
            torque_pos: 0,
            torque_filled: 0,
            extrapolation: Box::new(None),
            extrapolated_steps: 0,
            stall_coast: false,
            estimated_for: [[0; N]; 2],
            joint_coast: false,
            coast_joints: [false; N],
            coasting: false,
            blend_in: 0,
            blend_in_from: SVector::zeros(),
            coast_offset: SVector::zeros(),
            coast_steps: 0,
            coast_force0: None,
            handback: 0,
            replay_lag_now: None,
            replay_at_guard_lag: false,
            stopped: false,
            stop_handback: 0,
            stop_handback_from: SVector::zeros(),
            last_safe: prev,
            fallback_since: None,
            fallback_osc,
            fallback_cutoff_hz: cutoff_hz,
            fallback_failed: false,
            response_since: None,
            escalated: false,
        };
        sup.inner.set_previous_torque(prev);
        sup
    }

    /// Whether a joint's encoder is lost this step, and whether a channel of a joint whose angle
    /// and velocity were both estimates within the current coast (`coast_joints`) still is,
    /// counting how long each channel has been estimated (`estimated_for`; a step that is not
    /// valid holds the counts). A joint's encoder is lost when its angle and velocity are both
    /// estimated, their faults begun within `filter_window` steps of each other (a filtered
    /// velocity shows a dropped-out or stuck raw velocity only over its window), and while its
    /// angle is estimated whatever its velocity (a velocity still accepted may be failing with
    /// it unseen; not for an angle that its velocity implies, nor in a stalled acquisition).
    /// Coasting for the whole angle fault: a 200-ms stuck hip angle at 2.25 s, 3 kg, 9.8 N,
    /// against 33.7 N handed to the controller on the angle its velocity integrates to after
    /// the filter window. A velocity rejected later in an angle fault does not make the two
    /// one encoder's fault (a coast begun at that rejection took a 1-s spike of both angles at
    /// 3 s, 2 kg, to 59.8 N); the angle's coast covers it from the angle's first step
    /// (27.1 N). `all_lost`: every encoder channel is estimated (such a coast is not a
    /// joint's).
    fn joint_lost(&mut self, valid: bool, rep: &Repaired<N>, all_lost: bool) -> (bool, bool) {
        let window = u32::try_from(self.s.filter_window).unwrap_or(u32::MAX);
        let stalled = rep.stalled || (self.coasting && self.stall_coast);
        let new_coast = all_lost || !self.coasting;
        if new_coast {
            self.coast_joints = [false; N];
        }
        let (mut lost, mut faulted) = (false, false);
        for j in 0..N {
            let estimated = [rep.estimated.q[j], rep.estimated.qd[j]];
            if valid {
                for (n, &e) in self.estimated_for.iter_mut().zip(&estimated) {
                    n[j] = if e { n[j].saturating_add(1) } else { 0 };
                }
            }
            let [q_for, qd_for] = [self.estimated_for[0][j], self.estimated_for[1][j]];
            let both = valid && q_for > 0 && qd_for > 0;
            self.coast_joints[j] |= both;
            let together = both && q_for.abs_diff(qd_for) <= window;
            let onset = valid && q_for > 0 && !rep.q_from_velocity[j] && !stalled;
            lost |= together || onset;
            faulted |= self.coast_joints[j] && (estimated[0] || estimated[1]);
        }
        if new_coast {
            self.joint_coast = lost && !all_lost;
        }
        (lost, faulted)
    }

    /// The gait period `period_s` in steps, when the torque history holds more than it: the lag
    /// of the replay of one gait period back when the channel guard's is not used (and of the
    /// fill of a gap in the data, after which the guard has none). A period longer than the
    /// history, shorter than two steps or not finite is not replayed (checked in floating point:
    /// no overflow).
    fn replay_lag(&self, period_s: Option<f64>) -> Option<usize> {
        period_s
            .map(|p| (p / self.dt()).round())
            .filter(|&p| p >= 2.0 && p + 2.0 < self.torque_filled as f64)
            .map(|p| p as usize)
    }

    /// The configured `hold` or `ramp_to_zero` hands the torque to the transparent fallback
    /// once it has had it for [`RESPONSE_ESCALATE_S`] and the trip's cause is present: a
    /// tripped monitor's condition (still, or again before the monitors have cleared; not
    /// only its `clear_after_s` hold-off), or the latch. `tripped`: a monitor or the latch
    /// has the torque; `stop`: the protective stop has it (the escalation, once made, is kept
    /// through it); `fallback_ready`: the fallback has a demand this step (it was fed; the
    /// escalation is made on the first such step `RESPONSE_ESCALATE_S` or more into the
    /// response). Logged as
    /// [`MonitorAction::Escalate`]; the fallback keeps the torque until every monitor has
    /// cleared (or, if it fails, the protective stop does: no new escalation then).
    fn escalate(&mut self, tripped: bool, stop: bool, fallback_ready: bool, now: f64) {
        if !tripped {
            self.response_since = None;
            self.escalated = false;
            return;
        }
        if self.s.monitors.response == MonitorResponse::Fallback
            || self.escalated
            || stop
            || self.fallback_failed
        {
            return;
        }
        let since = *self.response_since.get_or_insert(now);
        if !fallback_ready || now - since < RESPONSE_ESCALATE_S - 1e-9 {
            return;
        }
        let persisting =
            (0..MONITORS.len()).find(|&i| self.tripped[i] && self.ok_since[i].is_none());
        let cause = match (persisting, self.latched) {
            (Some(i), _) => MONITORS[i],
            (None, true) => self.report.latched_by.unwrap_or(MONITORS[0]),
            (None, false) => return,
        };
        self.escalated = true;
        self.report.escalations += 1;
        self.log(MonitorEvent {
            t: now,
            monitor: cause,
            action: MonitorAction::Escalate,
            value: now - since,
        });
    }

    /// The fallback's own failure (issue 28), with `responding` whether it has the torque (the
    /// configured `fallback` response, or `hold` / `ramp_to_zero` escalated to it) and
    /// `demand` its demanded torque this step:
    /// - it diverges: its demand moves by more than [`FALLBACK_DEMAND_JUMP`] × the rate limit
    ///   in one period, to beyond [`FALLBACK_DEMAND_BEYOND`] × the torque limit (from its
    ///   second step with the torque on);
    /// - it oscillates: once it has had the torque for `oscillation_window_s` (the window then
    ///   holds its torques only), its torque oscillates above `oscillation_torque_rms_nm` well
    ///   above the gait (its content above [`FALLBACK_OSCILLATION_GAIT_RATIO`] × the gait
    ///   frequency, swinging across ± that threshold at least [`OSCILLATION_MIN_HALF_CYCLES`]
    ///   times in the window: a fast gait's torque at its limits is no oscillation; not before
    ///   the gait frequency is known).
    ///
    /// Either hands the torque to the protective stop until no monitor is tripped.
    fn watch_fallback(&mut self, responding: bool, demand: Option<SVector<f64, N>>, now: f64) {
        let mo = &self.s.monitors;
        if !responding || self.fallback.is_none() {
            self.fallback_demand = None;
            if !self.is_tripped() && !self.latched {
                self.fallback_since = None;
                self.fallback_failed = false;
            }
            return;
        }
        let since = *self.fallback_since.get_or_insert(now);
        let jump = match (self.fallback_demand, demand) {
            (Some(p), Some(d)) => (d - p).amax(),
            _ => 0.0,
        };
        self.fallback_demand = demand;
        if self.fallback_failed {
            return;
        }
        let beyond = demand.is_some_and(|d| d.amax() > FALLBACK_DEMAND_BEYOND * self.s.limits.max);
        let failure = if beyond && jump > FALLBACK_DEMAND_JUMP * self.s.limits.rate {
            Some((MonitorKind::FallbackDemand, jump))
        } else if self.gait.frequency(now).is_some()
            && now - since >= mo.oscillation_window_s - 1e-9
            && self
                .fallback_osc
                .is_oscillating(mo.oscillation_torque_rms_nm, OSCILLATION_MIN_HALF_CYCLES)
        {
            Some((MonitorKind::TorqueOscillation, self.fallback_osc.rms_max()))
        } else {
            None
        };
        if let Some((monitor, value)) = failure {
            self.fallback_failed = true;
            self.report.fallback_stops += 1;
            self.log(MonitorEvent {
                t: now,
                monitor,
                action: MonitorAction::Stop,
                value,
            });
        }
    }

    /// The torque applied `lag` periods before the period `ahead` periods after the next one
    /// (`ahead < lag`: one already in the history): the replay of one gait period back.
    fn torque_back(&self, lag: usize, ahead: usize) -> SVector<f64, N> {
        let len = self.torque_hist.len();
        self.torque_hist[(self.torque_pos + ahead + len - lag % len) % len]
    }

    /// One joint's coast: the offset that continues the applied torque into the replay at lag
    /// `p`, `steps` steps into the coast (fading out linearly over `p` steps).
    fn coast_offset_at(&self, steps: u32, p: usize) -> SVector<f64, N> {
        let fade = 1.0 - f64::from(steps) / p.max(1) as f64;
        self.coast_offset * fade.max(0.0)
    }

    /// The strap-force feedback's torque `COAST_FORCE_GAIN · Jᵀ ΔF` for the strap forces'
    /// change `df` ([`COAST_FORCE_GAIN`]; `Jᵀ ΔF` the change of the strap torque on the robot,
    /// paper eqs. 3-4, from the channel guard's `ks J`); zero without the straps' levers and
    /// stiffness or if not finite.
    fn strap_feedback(&self, df: &SVector<f64, N>) -> SVector<f64, N> {
        let Some(ks_j) = self.guard.strap_stiffness_map() else {
            return SVector::zeros();
        };
        let c = ks_j.transpose() * df * (COAST_FORCE_GAIN / self.s.strap_stiffness);
        if c.iter().all(|v| v.is_finite()) {
            c
        } else {
            SVector::zeros()
        }
    }

    /// A gap of `gap_s` in the measurements (periods the runtime did not step the controller,
    /// e.g. a link outage): the torque history moves on by the missing periods, filled with
    /// the replay of one gait period back (what the robot plays out during the gap) or,
    /// before the period `period_s` is known, the last torque; the history stays aligned with
    /// time for the replay and the handback after the gap. A gap of more than the history
    /// (or not finite) clears it.
    fn bridge_gap(&mut self, gap_s: f64, period_s: Option<f64>) {
        let len = self.torque_hist.len();
        let missing = (gap_s / self.dt()).round() - 1.0;
        if !(missing >= 0.0 && missing < len as f64) {
            self.torque_filled = 0;
            return;
        }
        let p = self.replay_lag(period_s);
        for _ in 0..missing as usize {
            let t = p.map_or(self.prev, |p| self.torque_back(p, 0));
            // No angles were measured in the gap: the last one stands in.
            let alen = self.angle_hist.len();
            let q = self.angle_hist[(self.angle_pos + alen - 1) % alen];
            self.push_history(t, q);
        }
    }

    /// One step of the torque and angle histories: the applied `torque` and the angles `q`.
    fn push_history(&mut self, torque: SVector<f64, N>, q: SVector<f64, N>) {
        let len = self.torque_hist.len();
        self.torque_hist[self.torque_pos] = torque;
        self.torque_pos = (self.torque_pos + 1) % len;
        self.torque_filled = (self.torque_filled + 1).min(len);
        self.angle_hist[self.angle_pos] = q;
        self.angle_pos = (self.angle_pos + 1) % self.angle_hist.len();
    }

    /// Use `fallback` for the `fallback` monitor response, and as what `hold` and
    /// `ramp_to_zero` hand over to ([`RESPONSE_ESCALATE_S`]); without one, the `fallback`
    /// response ramps the torque to zero and the others never hand over. It observes every
    /// valid measurement, so its payload estimate is ready when a monitor trips.
    pub fn with_fallback(mut self, fallback: Transparent<N>) -> Self {
        self.fallback = Some(fallback);
        self
    }

    /// The fallback controller, if any.
    pub fn fallback(&self) -> Option<&Transparent<N>> {
        self.fallback.as_ref()
    }

    /// The wrapped controller.
    pub fn inner(&self) -> &C {
        &self.inner
    }

    /// The settings.
    pub fn settings(&self) -> &SafetySettings {
        &self.s
    }

    /// Counters and logged events so far.
    pub fn report(&self) -> &SafetyReport {
        &self.report
    }

    /// True while any monitor is tripped.
    pub fn is_tripped(&self) -> bool {
        self.tripped.iter().any(|&t| t)
    }

    /// True while the supervisor is latched (`[monitors] latch_trips`): the response keeps
    /// the torque whatever the monitors say, until [`Supervisor::reset_latch`].
    pub fn is_latched(&self) -> bool {
        self.latched
    }

    /// An operator's reset of the latch: the handover history is forgotten and the controller
    /// takes the torque back once no monitor is tripped (at once if none is). Logged as a
    /// [`MonitorAction::Reset`] event; does nothing when not latched.
    pub fn reset_latch(&mut self) {
        if !self.latched {
            return;
        }
        self.latched = false;
        self.report.latched_at = None;
        self.report.latched_by = None;
        self.handover_t.fill(f64::NEG_INFINITY);
        let now = self.t0 + self.k.saturating_sub(1) as f64 * self.dt();
        self.log(MonitorEvent {
            t: now,
            monitor: self.latch_monitor,
            action: MonitorAction::Reset,
            value: 0.0,
        });
    }

    fn dt(&self) -> f64 {
        if self.s.dt.is_finite() && self.s.dt > 0.0 {
            self.s.dt
        } else {
            0.01
        }
    }

    /// Rejects again the encoder channels believed on smoothness alone within
    /// [`UNVERIFIED_S`](super::UNVERIFIED_S) ([`ChannelGuard::revoke_unverified`]) and logs a
    /// [`MonitorAction::Revoke`] under the first tripped controller-failure monitor.
    fn revoke_unverified(&mut self, resync_after: u64, now: f64) {
        let revoked = self.guard.revoke_unverified(resync_after);
        if revoked == 0 {
            return;
        }
        self.report.revocations += 1;
        let i = LATCHING
            .into_iter()
            .find(|&i| self.tripped[i])
            .unwrap_or(LATCHING[0]);
        self.log(MonitorEvent {
            t: now,
            monitor: MONITORS[i],
            action: MonitorAction::Revoke,
            value: f64::from(revoked),
        });
    }

    /// Counts a handover at `now` and latches after `latch_trips` of them within
    /// `latch_window_s`.
    fn handover(&mut self, now: f64) {
        self.report.handovers += 1;
        let k = self.s.monitors.latch_trips.min(self.handover_t.len());
        // A handover during or just after a sensor fault is the fault's, not the controller's.
        let sensor = now - self.fault_t < SafetySettings::SENSOR_FAULT_GRACE_S;
        if k == 0 || self.latched || sensor {
            return;
        }
        self.handover_t[self.handover_pos] = now;
        self.handover_pos = (self.handover_pos + 1) % k;
        let window = self.s.monitors.latch_window_s;
        let recent = self.handover_t[..k]
            .iter()
            .filter(|&&t| now - t < window - 1e-9)
            .count();
        if recent >= k {
            self.latched = true;
            self.report.latched_at = Some(now);
            self.latch_monitor = (0..MONITORS.len())
                .find(|&i| LATCHING.contains(&i) && self.tripped[i])
                .map_or(MonitorKind::TorqueOscillation, |i| MONITORS[i]);
            self.report.latched_by = Some(self.latch_monitor);
            self.log(MonitorEvent {
                t: now,
                monitor: self.latch_monitor,
                action: MonitorAction::Latch,
                value: recent as f64,
            });
        }
    }

    /// The oscillation monitors' high-pass cut-off now (Hz): `oscillation_cutoff_hz`, or the
    /// gait-following one once a gait frequency is estimated
    /// (`[monitors] oscillation_cutoff_gait_ratio`).
    pub fn oscillation_cutoff_hz(&self) -> f64 {
        self.cutoff_hz
    }

    /// The estimated gait frequency (Hz) at the last step, if any ([`GaitFrequency`]).
    pub fn gait_frequency_hz(&self) -> Option<f64> {
        let now = self.t0 + self.k.saturating_sub(1) as f64 * self.dt();
        self.gait.frequency(now)
    }

    /// True while an oscillation monitor is tripped.
    pub fn is_oscillation_tripped(&self) -> bool {
        OSCILLATION.iter().any(|&i| self.tripped[i])
    }

    fn log(&mut self, e: MonitorEvent) {
        if self.report.events.len() < self.s.max_events {
            self.report.events.push(e);
        } else {
            self.report.events_dropped += 1;
        }
    }

    /// Evaluates the monitors; returns true while any is tripped.
    /// `raw` is the measurement received, `m` the one with rejected channels estimated.
    fn update_monitors(&mut self, raw: &Measurement<N>, m: &Measurement<N>, silent: f64, now: f64) {
        let mo = &self.s.monitors;
        let mut force: f64 = 0.0;
        for j in 0..N {
            let f = raw.force[j];
            if f.is_finite() {
                force = force.max(f.abs());
            }
        }
        // Only plausible forces feed the estimates (an implausible one keeps their state). The
        // monitors see the measured forces, never the guard's estimates: a real force (a limit
        // cycle the gates took for a fault) must reach them.
        let plausible = raw.force.iter().all(|f| f.abs() < self.s.saturation_n);
        let forces = if plausible {
            raw.force
        } else {
            SVector::repeat(f64::NAN)
        };
        let dq = self.angle.update(&forces);
        let track = dq.amax();
        // The gait-following cut-off (`oscillation_cutoff_gait_ratio`): the human's angles are
        // the encoders' plus the strap-model angle error.
        self.gait.update(&(m.q + dq), now);
        // The monitors' cut-off follows the gait at `oscillation_cutoff_gait_ratio`, the
        // fallback check's at `FALLBACK_OSCILLATION_GAIT_RATIO`.
        let gait_hz = self.gait.frequency(now);
        let follow = |ratio: f64| match gait_hz {
            Some(f) if ratio > 0.0 => mo.oscillation_cutoff_hz.max(ratio * f),
            _ => mo.oscillation_cutoff_hz,
        };
        let cutoff = follow(mo.oscillation_cutoff_gait_ratio);
        if cutoff != self.cutoff_hz {
            self.cutoff_hz = cutoff;
            self.force_osc.set_cutoff(cutoff, self.s.dt);
            self.torque_osc.set_cutoff(cutoff, self.s.dt);
        }
        let fb_cutoff = follow(FALLBACK_OSCILLATION_GAIT_RATIO);
        if fb_cutoff != self.fallback_cutoff_hz {
            self.fallback_cutoff_hz = fb_cutoff;
            self.fallback_osc.set_cutoff(fb_cutoff, self.s.dt);
        }
        self.fallback_osc.push(&self.prev);
        let force_osc = self.force_osc.push(&forces);
        let torque_osc = self.torque_osc.push(&self.prev);
        let values = [track, force, silent, force_osc, torque_osc];
        let cond = [
            track > mo.tracking_error_max_rad,
            // A reading at the sensor's full scale (the sensor clips there) is a force of at
            // least `saturation_n`: over a limit `force_max_n ≤ saturation_n` (70 N both by
            // default), which no reading could exceed.
            force > mo.force_max_n || force >= self.s.saturation_n.max(mo.force_max_n),
            silent > mo.sensor_timeout_s + 1e-9,
            self.force_osc
                .is_oscillating(mo.oscillation_force_rms_n, OSCILLATION_MIN_HALF_CYCLES),
            self.torque_osc
                .is_oscillating(mo.oscillation_torque_rms_nm, OSCILLATION_MIN_HALF_CYCLES),
        ];
        let clear_after = [
            self.s.clear_after_s,
            self.s.clear_after_s,
            self.s.clear_after_s,
            mo.oscillation_clear_s,
            mo.oscillation_clear_s,
        ];
        for i in 0..MONITORS.len() {
            if cond[i] {
                self.ok_since[i] = None;
                if !self.tripped[i] {
                    self.tripped[i] = true;
                    self.report.monitor_trips += 1;
                    self.log(MonitorEvent {
                        t: now,
                        monitor: MONITORS[i],
                        action: MonitorAction::Trip,
                        value: values[i],
                    });
                }
            } else if self.tripped[i] {
                let since = *self.ok_since[i].get_or_insert(now);
                if now - since >= clear_after[i] - 1e-9 {
                    self.tripped[i] = false;
                    self.ok_since[i] = None;
                    self.log(MonitorEvent {
                        t: now,
                        monitor: MONITORS[i],
                        action: MonitorAction::Clear,
                        value: 0.0,
                    });
                }
            }
        }
    }
}

impl<const N: usize, C: Controller<N>> Controller<N> for Supervisor<N, C> {
    fn step(&mut self, m: &Measurement<N>) -> ControlOutput<N> {
        if self.k == 0 && m.t.is_finite() {
            self.t0 = m.t;
        }
        self.k += 1;
        let now = self.t0 + (self.k - 1) as f64 * self.dt();
        self.report.steps += 1;
        // Per-channel fault detection: a rejected channel is replaced by its estimate, so the
        // controller keeps stepping through the gap (`control::ride_through`).
        let period = self.gait.frequency(now).map(|f| 1.0 / f);
        let resync_after = (self.s.monitors.sensor_timeout_s / self.dt())
            .ceil()
            .max(1.0) as u64;
        let model = self.inner.predicted_state();
        let rep = self.guard.repair(m, period, resync_after, model);
        if rep.definite_fault {
            self.fault_t = now;
        }
        let raw = m;
        // A strap force at the sensor's full scale is a real force of at least the range, not
        // a sensor fault: the measurement is rejected as before issue 28 (torque held, the
        // controller not stepped) and after `RAILED_TIMEOUT_S` the sensor-timeout monitor
        // applies the configured response (not the protective stop).
        let railed = raw
            .force
            .iter()
            .any(|f| f.is_finite() && f.abs() >= self.s.saturation_n);
        if railed {
            self.railed_for += self.dt();
        } else {
            self.railed_for = 0.0;
        }
        let m = &rep.m;
        let valid = !railed && rep.ready && m.t.is_finite() && m.is_finite();
        self.report.estimated_steps = self.guard.estimated_steps();
        self.report.sensor_faults = self.guard.episodes();
        let railed_silence = if railed {
            (self.railed_for - self.dt()) * self.s.monitors.sensor_timeout_s / RAILED_TIMEOUT_S
        } else {
            0.0
        };
        if railed_silence > self.s.monitors.sensor_timeout_s + 1e-9 {
            self.railed_trip = true;
        } else if !self.tripped[2] {
            self.railed_trip = false;
        }
        self.update_monitors(raw, m, rep.longest_fault_s.max(railed_silence), now);
        let controller_failed = LATCHING.iter().any(|&i| self.tripped[i]);
        if controller_failed && !self.engaged {
            // The controller failing right after an encoder channel was believed on smoothness
            // alone: the believed value is taken to be an offset and rejected again. A 0.5-rad
            // spike of every sensor for 1 s at 3 kg, believed after `sensor_timeout_s`, put the
            // hip at its limit when the strap-force monitor's hand-over ended: 96.1 N, 75.9 N
            // with the rejection again (docs/RELIABILITY.md §2). Only a failure of the
            // controller's own torque: not during the protective stop (nor a monitor response
            // or the latch: then `engaged`).
            if !self.stopped {
                self.revoke_unverified(resync_after, now);
            }
            self.handover(now);
        }
        self.engaged = controller_failed || self.latched;
        let tripped = self.is_tripped() || self.latched;
        let prev = self.prev;
        // Periods without a measurement (the runtime steps no controller then): the
        // fallback's finite differences and fits would span the gap as if it were one period.
        let gap = m.t - self.last_t > 1.5 * self.dt();
        if gap {
            self.bridge_gap(m.t - self.last_t, period);
        }
        if m.t.is_finite() {
            self.last_t = m.t;
        }
        // The fallback's demand this step: only on a step it was fed (unfed, its last demand
        // is stale; docs/RELIABILITY.md §2).
        let mut demand = None;
        if let Some(fb) = self.fallback.as_mut() {
            // Only measured angles (or the angle a measured velocity implies): the fallback
            // differentiates them twice, and an estimate's step where the measurement returns
            // would be an acceleration no leg made.
            let angles_measured = (rep.estimated.q.iter())
                .zip(&rep.q_from_velocity)
                .all(|(&e, &v)| !e || v);
            // The measurement it observes, and whether its forces are measured (estimated
            // channels or a railed force: the payload estimate stays frozen).
            let input = if valid && !rep.any_rejected {
                Some((m, true))
            } else if valid && angles_measured {
                Some((m, false))
            } else if railed && rep.encoders_good {
                Some((raw, false))
            } else {
                None
            };
            let feed = input.is_some();
            // After a gap, or steps it was not fed (encoders lost), its finite differences and
            // fits would span the missing samples as if they were one period; an angle that
            // stood in for a rejected one and is measured again off it is such a step too.
            let restart = gap || (feed && (!self.fallback_fed || rep.estimated.resume));
            if restart {
                fb.restart();
            }
            // The divergence check compares consecutive fed steps only.
            if restart || !feed {
                self.fallback_demand = None;
            }
            self.fallback_fed = feed;
            match input {
                Some((x, true)) => fb.observe(x, &prev),
                Some((x, false)) => fb.observe_encoders(x, &prev),
                None => {}
            }
            demand = feed.then(|| fb.torque());
        }
        // A channel rejected for longer than `sensor_timeout_s` is the protective stop: the
        // torque ramps to zero at the rate limit and stays there until every channel has been
        // good for `clear_after_s`, whatever `response` says.
        let persistent = rep.longest_fault_s > self.s.monitors.sensor_timeout_s + 1e-9;
        let stop = self.tripped[2] && (persistent || !self.railed_trip);
        // The ramp to zero (`ramp_to_zero`, the protective stop) at `STOP_RAMP_NM_PER_S`.
        let step = STOP_RAMP_NM_PER_S * self.dt();
        let toward_zero = prev - prev.map(|v| v.clamp(-step, step));
        self.escalate(tripped, stop, demand.is_some(), now);
        let configured = self.s.monitors.response;
        let fallback_has_it = configured == MonitorResponse::Fallback || self.escalated;
        self.watch_fallback(tripped && !stop && fallback_has_it, demand, now);
        let response = if stop || self.fallback_failed {
            toward_zero
        } else if fallback_has_it {
            // Without a demand (the fallback not fed) the ramp to zero until it is fed again.
            demand.unwrap_or(toward_zero)
        } else if configured == MonitorResponse::Hold {
            self.last_safe
        } else {
            toward_zero
        };
        let (desired, mut status, iterations) = if valid {
            // The inner controller keeps estimating while a monitor holds the output, and
            // steps on the estimates of rejected channels.
            // An angle implied by its measured velocity is a measurement of it: the
            // controller's estimators update with it (`Repaired::q_from_velocity`), and
            // restart at the measured angle if it comes back off the implied one
            // (`EstimatedChannels::resume`).
            let mut inputs = rep.estimated;
            for (q, v) in inputs.q.iter_mut().zip(&rep.q_from_velocity) {
                *q &= !*v;
            }
            let out = if inputs.any() || inputs.resume {
                self.inner.step_estimated(m, &inputs)
            } else {
                self.inner.step(m)
            };
            if rep.any_rejected {
                self.report.bad_measurement_steps += 1;
                (out.torque, StepStatus::BadMeasurement, out.iterations)
            } else {
                (out.torque, out.status, out.iterations)
            }
        } else {
            self.report.bad_measurement_steps += 1;
            (prev, StepStatus::BadMeasurement, 0)
        };
        // Every encoder channel lost (the estimates are the gait replayed one period back), or
        // one joint's encoder (below): the torque replays the torque applied one gait period
        // back (the rate limit bounds the step into it), so the robot keeps following the leg
        // as it did a period ago, until every channel is measured again (a joint's coast: its
        // channels; before the gait period is known it follows the torque's extrapolation,
        // `TorqueExtrapolation`); then it blends back to the controller's over
        // `REPLAY_HANDBACK_STEPS`. The controller keeps stepping on the estimates; its
        // output, carried over after a period of replayed estimates, drove the robot away
        // from the leg (issue 28, docs/RELIABILITY.md §2).
        let all_lost =
            valid && rep.estimated.q.iter().all(|&e| e) && rep.estimated.qd.iter().all(|&e| e);
        // A coast that began with a stalled acquisition (every angle frozen or invalid, one
        // frozen, at once) ends when the velocities come back while the angles are still lost
        // (only the angles failed): before the gait period is known at once (the controller on
        // the model's angles and the measured velocities follows the leg better than the
        // extrapolation), after it once the velocities imply the angles
        // (`Repaired::q_from_velocity`; on the torque replayed one period back until every
        // channel was back, a 200-ms stall at 1.25 s, 3 kg: 15.5 N, now 8.9 N).
        let angles_only =
            rep.estimated.q.iter().all(|&e| e) && !rep.estimated.qd.iter().any(|&e| e);
        let implied = rep.q_from_velocity.iter().all(|&v| v);
        let angles_fault = self.stall_coast && angles_only && (period.is_none() || implied);
        // One joint's encoder lost (its angle and velocity) coasts too: stepped on the model's
        // prediction of that joint, which follows the applied torque, the controller drove the
        // torque to its limit within 0.05 s (the knee's angle and velocity NaN for 60 ms at
        // 1.5 s, 3 kg: 115.9 N; docs/RELIABILITY.md §2). Such a coast lasts while a joint's
        // angle is estimated, or a channel of a joint whose angle and velocity were both
        // estimates within it; one of every encoder until every channel is back.
        let (joint_lost, joint_faulted) = self.joint_lost(valid, &rep, all_lost);
        let coast = all_lost
            || joint_lost
            || (self.coasting
                && valid
                && if self.joint_coast {
                    joint_faulted
                } else {
                    rep.any_rejected && !angles_fault
                });
        // The torque replays one gait period back at the channel guard's lag, where the angles
        // repeat (`PERIOD_MATCH_STEPS`), as the channels' and `d̂`'s replays do, when the coast
        // began with that lag known; else (a coast that began in the first gait period, whose
        // period becomes known within it and is matched on the coast's own estimates, or the
        // guard's history too short after a gap) at the gait period.
        if coast && !self.coasting {
            self.stall_coast = rep.stalled;
            self.replay_at_guard_lag = rep.estimated.period.is_some();
        }
        // A stall within a joint's coast turns it into the stall's.
        self.stall_coast |= all_lost && rep.stalled;
        let replay_period = (rep.estimated.period)
            .filter(|&p| self.replay_at_guard_lag && p + 2 < self.torque_filled)
            .or_else(|| self.replay_lag(period));
        self.replay_lag_now = replay_period;
        // Before the gait period is known (the first gait period), the replay extrapolates
        // the applied torque at the gait frequency of the recent angles
        // ([`TorqueExtrapolation`], fitted when the coast begins), or holds it when no fit is
        // possible.
        if replay_period.is_none() && coast && !self.coasting && !gap {
            *self.extrapolation = TorqueExtrapolation::fit(
                &self.torque_hist,
                self.torque_pos,
                &self.angle_hist,
                self.angle_pos,
                self.torque_filled,
                self.dt(),
            );
            self.extrapolated_steps = 0;
        }
        // One joint's coast continues the applied torque into the replay (an offset fading out
        // over one period, instead of the blend below) and corrects the replay or the
        // extrapolation by the strap forces' change since it began ([`COAST_FORCE_GAIN`]).
        let forces_measured = !rep.estimated.any_force();
        if coast && !self.coasting {
            self.coast_steps = 0;
            self.coast_offset = match replay_period {
                Some(p) if self.joint_coast => prev - self.torque_back(p + 1, 0),
                _ => SVector::zeros(),
            };
            self.coast_force0 = (self.joint_coast && forces_measured).then_some(rep.m.force);
        }
        // None while the forces are estimates (held, the hip's 1-s spike at 1 s, 3 kg, of the
        // joint scan went from 44.7 to 78.6 N).
        let coast_feedback = match self.coast_force0 {
            Some(f0) if self.joint_coast && forces_measured => {
                self.strap_feedback(&(rep.m.force - f0))
            }
            _ => SVector::zeros(),
        };
        let replay = match replay_period {
            Some(p) => Some(
                self.torque_back(p, 0) + self.coast_offset_at(self.coast_steps, p) + coast_feedback,
            ),
            None => match &*self.extrapolation {
                Some(x) if !gap => {
                    let r = x.at(self.extrapolated_steps, self.dt()) + coast_feedback;
                    self.extrapolated_steps = self.extrapolated_steps.saturating_add(1);
                    Some(r)
                }
                _ => (self.torque_filled > 0).then_some(prev),
            },
        };
        self.coast_steps = self.coast_steps.saturating_add(1);
        // After a gap in the data (a link outage: the robot rode through on its replay of the
        // torque one gait period back) the controller resumes on fresh filters and estimates:
        // its first outputs swung at the rate limit (issue 28, docs/REALTIME.md). The torque
        // blends from the replay to the controller's over `REPLAY_HANDBACK_STEPS`.
        if gap && valid && replay_period.is_some() {
            self.handback = REPLAY_HANDBACK_STEPS;
        }
        // Into the replay of one gait period back the torque blends from the applied one over
        // `REPLAY_BLEND_IN_STEPS` (through a handback that begins within them too).
        if coast && !self.coasting {
            self.blend_in = if replay_period.is_some() && !self.joint_coast {
                REPLAY_BLEND_IN_STEPS
            } else {
                0
            };
            self.blend_in_from = prev;
        }
        let replay = match replay {
            Some(r) if self.blend_in > 0 && !gap && (coast || self.handback > 0) => {
                let b = handback_blend(self.blend_in_from, r, self.blend_in, REPLAY_BLEND_IN_STEPS);
                self.blend_in -= 1;
                Some(b)
            }
            _ if !coast && self.handback == 0 => {
                self.blend_in = 0;
                replay
            }
            other => other,
        };
        let desired = match replay {
            Some(r) if coast && !gap => {
                self.coasting = true;
                self.handback = REPLAY_HANDBACK_STEPS;
                r
            }
            Some(r) if self.handback > 0 && valid => {
                self.coasting = false;
                let blend = handback_blend(r, desired, self.handback, REPLAY_HANDBACK_STEPS);
                self.handback -= 1;
                blend
            }
            _ => {
                self.coasting = false;
                self.handback = 0;
                desired
            }
        };
        if !self.coasting && self.handback == 0 {
            *self.extrapolation = None;
        }
        // When the protective stop ends the torque goes back to the controller's over
        // `STOP_HANDBACK_STEPS`, from where the stop left it.
        if self.stopped && !tripped {
            self.stop_handback = STOP_HANDBACK_STEPS;
            self.stop_handback_from = prev;
        }
        self.stopped = tripped && (stop || self.fallback_failed);
        let desired = if tripped {
            self.stop_handback = 0;
            desired
        } else if self.stop_handback > 0 {
            let blend = handback_blend(
                self.stop_handback_from,
                desired,
                self.stop_handback,
                STOP_HANDBACK_STEPS,
            );
            self.stop_handback -= 1;
            blend
        } else {
            desired
        };
        let desired = if tripped {
            self.report.monitor_steps += 1;
            if self.latched && !self.is_tripped() {
                self.report.latched_for_s += self.dt();
            }
            status = StepStatus::MonitorTripped;
            response
        } else {
            desired
        };
        let torque = self.s.limits.clamp(&prev, &desired);
        self.push_history(torque, m.q);
        self.prev = torque;
        let handing_back = self.handback > 0 || self.stop_handback > 0;
        if valid && !rep.any_rejected && !tripped && !self.coasting && !handing_back {
            self.last_safe = torque;
        }
        if self.inner.previous_torque() != torque {
            self.inner.set_previous_torque(torque);
        }
        ControlOutput {
            torque,
            status,
            iterations,
        }
    }

    fn name(&self) -> &'static str {
        self.inner.name()
    }

    fn probabilities(&self) -> Option<&[f64]> {
        self.inner.probabilities()
    }

    fn disturbance(&self, i: usize) -> Option<SVector<f64, N>> {
        self.inner.disturbance(i)
    }

    fn previous_torque(&self) -> SVector<f64, N> {
        self.prev
    }

    fn set_previous_torque(&mut self, t: SVector<f64, N>) {
        self.prev = self.s.limits.admissible(&t);
        self.last_safe = self.prev;
        self.inner.set_previous_torque(self.prev);
    }

    fn safety_report(&self) -> Option<&SafetyReport> {
        Some(&self.report)
    }

    /// The torques the output would take on the next periods, for a robot to play while no
    /// command arrives: none while a monitor response, the latch or the replay of one gait
    /// period back has the torque (through a gap the robot then replays the torque it applied
    /// one gait period earlier); else the inner controller's plan, through the rest
    /// of a handback (from the replay, or from the end of the protective stop) as `step`
    /// blends it; each clamped to the limits from the one before.
    fn planned_torques(&self, out: &mut [SVector<f64, N>]) -> usize {
        if self.engaged || self.latched || self.is_tripped() || self.coasting {
            return 0;
        }
        let n = self.inner.planned_torques(out);
        let mut p = self.prev;
        for (i, o) in out.iter_mut().take(n).enumerate() {
            let ahead = u32::try_from(i).unwrap_or(u32::MAX);
            // Period k+1+i of a handback with `left − i` steps left.
            let left = self.handback.saturating_sub(ahead);
            let replay = match self.replay_lag_now {
                Some(lag) if i < lag => Some(
                    self.torque_back(lag, i)
                        + self.coast_offset_at(self.coast_steps.saturating_add(ahead), lag),
                ),
                Some(_) => None,
                None => (*self.extrapolation)
                    .as_ref()
                    .map(|x| x.at(self.extrapolated_steps.saturating_add(ahead), self.dt())),
            };
            let mut d = *o;
            if let (true, Some(mut r)) = (left > 0, replay) {
                // The blend into the replay, if the handback began within it.
                let blend_in = self.blend_in.saturating_sub(ahead);
                if blend_in > 0 {
                    r = handback_blend(self.blend_in_from, r, blend_in, REPLAY_BLEND_IN_STEPS);
                }
                d = handback_blend(r, d, left, REPLAY_HANDBACK_STEPS);
            }
            let left = self.stop_handback.saturating_sub(ahead);
            if left > 0 {
                d = handback_blend(self.stop_handback_from, d, left, STOP_HANDBACK_STEPS);
            }
            *o = self.s.limits.clamp(&p, &d);
            p = *o;
        }
        n
    }

    fn predicted_state(&self) -> Option<(SVector<f64, N>, SVector<f64, N>)> {
        self.inner.predicted_state()
    }
}

impl<const N: usize, C: Controller<N> + ?Sized> Controller<N> for Box<C> {
    fn step(&mut self, m: &Measurement<N>) -> ControlOutput<N> {
        (**self).step(m)
    }
    fn name(&self) -> &'static str {
        (**self).name()
    }
    fn probabilities(&self) -> Option<&[f64]> {
        (**self).probabilities()
    }
    fn disturbance(&self, i: usize) -> Option<SVector<f64, N>> {
        (**self).disturbance(i)
    }
    fn previous_torque(&self) -> SVector<f64, N> {
        (**self).previous_torque()
    }
    fn set_previous_torque(&mut self, t: SVector<f64, N>) {
        (**self).set_previous_torque(t)
    }
    fn safety_report(&self) -> Option<&SafetyReport> {
        (**self).safety_report()
    }
    fn planned_torques(&self, out: &mut [SVector<f64, N>]) -> usize {
        (**self).planned_torques(out)
    }

    fn predicted_state(&self) -> Option<(SVector<f64, N>, SVector<f64, N>)> {
        (**self).predicted_state()
    }
    fn step_estimated(
        &mut self,
        m: &Measurement<N>,
        estimated: &EstimatedChannels<N>,
    ) -> ControlOutput<N> {
        (**self).step_estimated(m, estimated)
    }
}
