//! The robust extensions of the multi-stage NMPC (`[controller] method = "robust"`, the
//! default) beyond the paper's method (`method = "paper"`), set in `[controller.robust]`. See
//! `docs/ROBUSTNESS-controller.md` for what they do across the operating envelope.
//!
//! The extension is a *filter-aware* mode: the NMPC starts from the EKF bank's lag-free velocity
//! (probability-weighted, instead of the moving-averaged one), the human-intent estimate of
//! eqs. 5-6 uses that velocity and the Smith-predicted strap force of [`ForceLag`] instead of
//! the filtered one, and so does the EKF's strap-torque input. It removes the limit cycles of
//! the paper's method (heavy legs, long filters, stiff straps) but tracks less tightly where the
//! paper's method is stable, so by default it engages when the [`HfShareDetector`] sees an
//! interaction oscillation in the strap forces or in the controller's own torque, and then
//! stays engaged.
//!
//! More extensions act from the first step: the intent gains follow the strap stiffness
//! ([`RobustIntentGains::StrapModel`], the default; identical to the configured gains at the
//! paper's straps); the predictions take their disturbance estimates from a second EKF bank
//! with a slower random walk and a led strap-force input ([`RobustTuning::disturbance_q`],
//! [`RobustTuning::disturbance_lead`]; the probabilities stay the paper's bank's); and
//! optionally the EKF's strap-torque input is led by a share of the moving average's delay
//! ([`RobustTuning::ekf_force_lead`], default off).

use super::intent::{GainSetting, IntentGain};
use super::lag::{ForceLag, HfShareDetector};
use super::Measurement;
#[cfg(not(feature = "std"))]
use crate::math::Float;
use alloc::{format, string::String};
use nalgebra::SVector;
use serde::de::IgnoredAny;
use serde::{Deserialize, Serialize};

/// Which controller method `msnmpc` runs.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Method {
    /// The paper's multi-stage NMPC (paper §3.2) exactly; reproduces `docs/REPRODUCING.md`.
    Paper,
    /// The paper's method plus the `[controller.robust]` extensions (the default).
    #[default]
    Robust,
}

/// When the filter-aware mode is used.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum FilterAware {
    /// Never (the paper's estimate throughout).
    Off,
    /// From the first detected interaction oscillation on (the default).
    #[default]
    OnOscillation,
    /// From the first step.
    Always,
}

/// `[controller.robust]`: the extensions of `method = "robust"` (ignored for `"paper"`): the
/// knobs a user has a reason to turn. The detectors' thresholds, the disturbance bank and the
/// inertia gate are tuned constants ([`RobustTuning`], not keys of the file). A key that was
/// removed from this table (issue 31) is rejected with an error naming it and its fixed value
/// ([`REMOVED_ROBUST_KEYS`]).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(try_from = "RobustFile")]
pub struct RobustSettings {
    /// When the filter-aware mode is used: `"off"` (never: the paper's filtered estimate
    /// throughout), `"on_oscillation"` (from the first interaction oscillation the detectors
    /// or the inertia gate see) or `"always"` (from the first step; tracks less tightly where
    /// the paper's method is stable). Default `"on_oscillation"`.
    pub filter_aware: FilterAware,
    /// Bandwidth (Hz) of the human's motion in the Smith predictor: the human's acceleration
    /// is taken as the robot's low-passed at this frequency, > 0; the strap observer
    /// ([`Self::intent_estimate`]) low-passes its human acceleration at it too. Raise it for
    /// faster movements than walking (the predictor then follows more of the robot's own
    /// acceleration, and more of its noise). Default 3.
    pub human_bandwidth_hz: f64,
    /// With `"on_oscillation"`: return to the paper's estimate after this long (s) without a
    /// detected oscillation; 0 = stay engaged for the rest of the run. In [0, 1e6]. Default 0.
    pub release_s: f64,
    /// Intent gains of the robust method: `"strap_model"` (the configured `controller.k1`,
    /// `k2` are the gains at the paper's 937.5 N/m straps and scale with `937.5 / ks`, i.e.
    /// `K = (κ / ks)·I` with `κ = 937.5·k`; exactly the configured gains at the default straps)
    /// or `"configured"` (`controller.k1`, `k2` as they are, the paper's). Default
    /// `"strap_model"`.
    pub intent_gains: RobustIntentGains,
    /// Time constant (s) of a first-order low-pass on the scenario probabilities before they
    /// weight the scenarios' costs (paper eq. 12); the probabilities themselves (reported,
    /// and the filter-aware velocity blend) stay the bank's. Where no scenario fits, the
    /// posteriors chatter between 0 and 1 and each switch steps the torque
    /// (`control/weights.rs`); longer = smoother torque, slower to follow a real payload
    /// change. The low-pass starts once one scenario first holds more than half of the
    /// probability; until then the weights are the probabilities (the bank's uniform prior is
    /// not smoothed in). In [0, 10]; 0 = the probabilities as they are (the paper's).
    /// Default 0.15.
    pub weight_smoothing_s: f64,
    /// The human-intent estimate of the robust method: `"paper"` (eqs. 5-6,
    /// `q̂_H = q_R + K1 F̄`, `q̂d_H = qd̄_R + K2 F̄`, with the filtered velocity as the NMPC's start
    /// state until the filter-aware mode engages) or `"strap_observer"` (the strap model
    /// inverted as a first-order observer of the stretch and its rate, moved forward over the
    /// sensor filter's lag, in both modes, with the EKF bank's lag-free velocity as the start
    /// state; `control/strap_intent.rs`). Default `"strap_observer"`.
    pub intent_estimate: IntentEstimate,
    /// With `intent_estimate = "strap_observer"`: gain `kv` (1/s) of the human-robot angle
    /// error in the reference velocity, `qd_ref = q̂d_H + kv (q̂_H − q_R)` (the encoder angle
    /// `q_R` is exact, so this feedback has no filter delay); higher = the robot closes an
    /// angle gap to the person faster, at the cost of stiffer interaction. In [0, 1000].
    /// Default 25.
    pub observer_velocity_gain: f64,
    /// Where the NMPC's velocity residual is measured: `"strap"` (`√r_d L (qd − qd_ref)`,
    /// `L = diag(J)⁻¹ J`: each strap's stretch rate in its link's angle units, so a hip held on
    /// its torque limit does not load the shank strap as well; [`super::VelocityTracking`]) or
    /// `"joint"` (the paper's eq. 7). Applies to every MS-NMPC scenario (the plain NMPC is the
    /// paper's); no effect with one joint. Default `"strap"`.
    pub velocity_tracking: super::VelocityTracking,
    /// The tuned constants of the extensions (not keys of the file; library callers and the
    /// tests switch single extensions off with them to measure what each does).
    #[serde(skip)]
    pub tuning: RobustTuning,
}

/// The fixed tuning of the robust extensions: values measured across the operating envelope
/// (docs/ROBUSTNESS-controller.md) that a user has no reason to turn, so they are not keys of
/// `[controller.robust]` ([`REMOVED_ROBUST_KEYS`]); [`Default`] holds them.
#[derive(Clone, Debug, PartialEq)]
pub struct RobustTuning {
    /// Cut-off (Hz) above which filtered strap-force power counts as oscillation: 2.5, above
    /// the gait's harmonics and below the 3-8 Hz interaction limit cycles.
    pub oscillation_cutoff_hz: f64,
    /// Averaging time (s) of the strap-force detector: 0.25, a few limit-cycle periods.
    pub oscillation_window_s: f64,
    /// Share of the strap-force power above the cut-off that counts as oscillation: 0.4.
    pub oscillation_fraction: f64,
    /// Smallest RMS (N) of the high-passed strap forces that counts as oscillation: 1.5, above
    /// the force sensor's filtered noise.
    pub oscillation_min_force_n: f64,
    /// Lead of the EKF's strap-torque input while the filter-aware mode is not engaged, as a
    /// share of the moving average's delay `(w−1)/2·dt` (`F̄(k) + λ (w−1)/2 (F̄(k) − F̄(k−1))`):
    /// 0, the filtered force (the paper's); the disturbance bank below leads instead.
    pub ekf_force_lead: f64,
    /// Lead `λ_d` of the strap-force input of the *disturbance bank* (a second EKF bank, same
    /// scenarios and `[ekf]` settings except [`Self::disturbance_q`], that supplies only the
    /// predictions' `d̂ᵢ`; the probabilities `μᵢ` stay the paper's bank's), as a share of the
    /// moving average's delay: 0.5. In the paper's bank `d̂` absorbs the filter's lag torque
    /// `Jᵀ(F − F̄)`, which the prediction then holds over the horizon.
    pub disturbance_lead: f64,
    /// Random-walk variance ((N·m)² per step) of the disturbance bank's `d̂`: 1e-3, ten times
    /// slower than `[ekf] q_disturbance`, so that `d̂` follows a payload mismatch but not the
    /// gait-frequency lag torque. With `disturbance_lead = 0` and `disturbance_q = 0` there is
    /// no disturbance bank (the paper's `d̂`).
    pub disturbance_q: f64,
    /// With `"on_oscillation"`: the mode also engages on an oscillation of the controller's
    /// own torque (the safety layer's torque-oscillation signal, seen earlier and with lower
    /// thresholds, so that the start-up swing of a heavy or distal load engages the mode
    /// before the monitor trips): the torque's high-passed RMS above 3 N·m (0 = off).
    pub torque_oscillation_nm: f64,
    /// Averaging time (s) of the torque detector: 0.1.
    pub torque_oscillation_window_s: f64,
    /// Cut-off (Hz) of the torque detector's high-pass: 4.
    pub torque_oscillation_cutoff_hz: f64,
    /// Share of the torque power above the cut-off that counts as oscillation: 0.6.
    pub torque_oscillation_fraction: f64,
    /// With `"on_oscillation"`: the mode is also used on every step where the scenarios whose
    /// *inertia ratio* reaches 3 hold at least half of the EKF bank's probability
    /// (control/heavy.rs; a scenario's ratio is the largest over the joints of its diagonal
    /// mass-matrix entry at the stretched leg over the lightest scenario's): a payload far
    /// down the shank makes the moving average's delay unstable from the first step, before a
    /// detector sees it. 0 = off.
    pub inertia_engage_ratio: f64,
    /// How long (s) the heavy scenarios must hold half of the probability without a break
    /// before the inertia gate opens (it then stays open): 0.1.
    pub inertia_engage_s: f64,
}

impl Default for RobustTuning {
    fn default() -> Self {
        RobustTuning {
            oscillation_cutoff_hz: 2.5,
            oscillation_window_s: 0.25,
            oscillation_fraction: 0.4,
            oscillation_min_force_n: 1.5,
            ekf_force_lead: 0.0,
            disturbance_lead: 0.5,
            disturbance_q: 1e-3,
            torque_oscillation_nm: 3.0,
            torque_oscillation_window_s: 0.1,
            torque_oscillation_cutoff_hz: 4.0,
            torque_oscillation_fraction: 0.6,
            inertia_engage_ratio: 3.0,
            inertia_engage_s: 0.1,
        }
    }
}

/// The keys `[controller.robust]` no longer has (issue 31): each is a constant of
/// [`RobustTuning`] now. A file that sets one is rejected with an error naming it.
pub const REMOVED_ROBUST_KEYS: [&str; 13] = [
    "oscillation_cutoff_hz",
    "oscillation_window_s",
    "oscillation_fraction",
    "oscillation_min_force_n",
    "ekf_force_lead",
    "disturbance_lead",
    "disturbance_q",
    "torque_oscillation_nm",
    "torque_oscillation_window_s",
    "torque_oscillation_cutoff_hz",
    "torque_oscillation_fraction",
    "inertia_engage_ratio",
    "inertia_engage_s",
];

/// The error for a removed `[controller.robust]` key `key` ([`REMOVED_ROBUST_KEYS`]).
pub fn removed_robust_key(key: &str) -> String {
    format!(
        "controller.robust.{key} is no longer a setting: since issue 31 it is a fixed constant \
         of the robust method (control::RobustTuning, docs/ROBUSTNESS-controller.md); delete \
         the key"
    )
}

/// `[controller.robust]` as a file has it: the knobs, and the removed keys only to name them
/// in the error ([`RobustSettings`] is built from it).
#[derive(Deserialize)]
#[serde(default, deny_unknown_fields)]
struct RobustFile {
    filter_aware: FilterAware,
    human_bandwidth_hz: f64,
    release_s: f64,
    intent_gains: RobustIntentGains,
    weight_smoothing_s: f64,
    intent_estimate: IntentEstimate,
    observer_velocity_gain: f64,
    velocity_tracking: super::VelocityTracking,
    oscillation_cutoff_hz: Option<IgnoredAny>,
    oscillation_window_s: Option<IgnoredAny>,
    oscillation_fraction: Option<IgnoredAny>,
    oscillation_min_force_n: Option<IgnoredAny>,
    ekf_force_lead: Option<IgnoredAny>,
    disturbance_lead: Option<IgnoredAny>,
    disturbance_q: Option<IgnoredAny>,
    torque_oscillation_nm: Option<IgnoredAny>,
    torque_oscillation_window_s: Option<IgnoredAny>,
    torque_oscillation_cutoff_hz: Option<IgnoredAny>,
    torque_oscillation_fraction: Option<IgnoredAny>,
    inertia_engage_ratio: Option<IgnoredAny>,
    inertia_engage_s: Option<IgnoredAny>,
}

impl Default for RobustFile {
    fn default() -> Self {
        let d = RobustSettings::default();
        RobustFile {
            filter_aware: d.filter_aware,
            human_bandwidth_hz: d.human_bandwidth_hz,
            release_s: d.release_s,
            intent_gains: d.intent_gains,
            weight_smoothing_s: d.weight_smoothing_s,
            intent_estimate: d.intent_estimate,
            observer_velocity_gain: d.observer_velocity_gain,
            velocity_tracking: d.velocity_tracking,
            oscillation_cutoff_hz: None,
            oscillation_window_s: None,
            oscillation_fraction: None,
            oscillation_min_force_n: None,
            ekf_force_lead: None,
            disturbance_lead: None,
            disturbance_q: None,
            torque_oscillation_nm: None,
            torque_oscillation_window_s: None,
            torque_oscillation_cutoff_hz: None,
            torque_oscillation_fraction: None,
            inertia_engage_ratio: None,
            inertia_engage_s: None,
        }
    }
}

impl TryFrom<RobustFile> for RobustSettings {
    type Error = String;

    fn try_from(f: RobustFile) -> Result<Self, String> {
        let removed = [
            f.oscillation_cutoff_hz.is_some(),
            f.oscillation_window_s.is_some(),
            f.oscillation_fraction.is_some(),
            f.oscillation_min_force_n.is_some(),
            f.ekf_force_lead.is_some(),
            f.disturbance_lead.is_some(),
            f.disturbance_q.is_some(),
            f.torque_oscillation_nm.is_some(),
            f.torque_oscillation_window_s.is_some(),
            f.torque_oscillation_cutoff_hz.is_some(),
            f.torque_oscillation_fraction.is_some(),
            f.inertia_engage_ratio.is_some(),
            f.inertia_engage_s.is_some(),
        ];
        if let Some(i) = removed.iter().position(|&set| set) {
            return Err(removed_robust_key(REMOVED_ROBUST_KEYS[i]));
        }
        Ok(RobustSettings {
            filter_aware: f.filter_aware,
            human_bandwidth_hz: f.human_bandwidth_hz,
            release_s: f.release_s,
            intent_gains: f.intent_gains,
            weight_smoothing_s: f.weight_smoothing_s,
            intent_estimate: f.intent_estimate,
            observer_velocity_gain: f.observer_velocity_gain,
            velocity_tracking: f.velocity_tracking,
            tuning: RobustTuning::default(),
        })
    }
}

/// The human-intent estimate of the robust method ([`RobustSettings::intent_estimate`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum IntentEstimate {
    /// The paper's eqs. 5-6 with the robust method's gains.
    Paper,
    /// The strap-model observer of `control/strap_intent.rs` (the default).
    #[default]
    StrapObserver,
}

/// The strap stiffness (N/m) at which the paper's intent gains hold (paper Table 1,
/// docs/MODEL.md §4); `intent_gains = "strap_model"` scales the configured gains from it.
pub const PAPER_STRAP_STIFFNESS: f64 = 937.5;

impl RobustIntentGains {
    /// The gain the robust method uses for the configured `k` (`kappa_auto`: the `κ` of
    /// `"auto"`): `"configured"` keeps it; `"strap_model"` turns a fixed `k` into
    /// `κ = PAPER_STRAP_STIFFNESS · k` per stiffness (`"auto"` stays `"auto"`).
    pub fn gain(&self, k: GainSetting, kappa_auto: f64) -> IntentGain {
        match (self, k) {
            (RobustIntentGains::StrapModel, GainSetting::Value(v)) => {
                IntentGain::PerStiffness(PAPER_STRAP_STIFFNESS * v)
            }
            _ => k.gain(kappa_auto),
        }
    }
}

/// Which intent gains `method = "robust"` uses (docs/ROBUSTNESS-controller.md).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum RobustIntentGains {
    /// `controller.k1`, `controller.k2` as configured (the paper's fixed `K = k·I`).
    Configured,
    /// The configured gains scaled to each scenario's strap stiffness,
    /// `K = (937.5 N/m · k / ks)·I` (the default).
    #[default]
    StrapModel,
}

impl Default for RobustSettings {
    fn default() -> Self {
        RobustSettings {
            filter_aware: FilterAware::OnOscillation,
            human_bandwidth_hz: 3.0,
            release_s: 0.0,
            intent_gains: RobustIntentGains::StrapModel,
            weight_smoothing_s: 0.15,
            intent_estimate: IntentEstimate::StrapObserver,
            observer_velocity_gain: 25.0,
            velocity_tracking: super::VelocityTracking::Strap,
            tuning: RobustTuning::default(),
        }
    }
}

/// Run-time state of the robust extensions inside a controller.
#[derive(Clone, Debug)]
pub(crate) struct RobustState<const N: usize> {
    lag: ForceLag<N>,
    detector: HfShareDetector<N>,
    mode: FilterAware,
    engaged: bool,
    /// Steps without a detected oscillation before release (0 = never), and the count.
    release_steps: usize,
    quiet: usize,
    /// Lead (samples) of the EKF's strap force while not engaged, and the last filtered force.
    lead: f64,
    /// Lead (samples) of the disturbance bank's strap force (0 = no disturbance bank).
    dlead: f64,
    dq: f64,
    /// Detector on the controller's own torque ([`RobustTuning::torque_oscillation_nm`]).
    torque_det: HfShareDetector<N>,
    torque_on: bool,
    last_force: Option<SVector<f64, N>>,
}

impl<const N: usize> RobustState<N> {
    pub(crate) fn new(s: &RobustSettings, window: usize, dt: f64) -> Self {
        let t = &s.tuning;
        RobustState {
            lag: ForceLag::new(window, dt, s.human_bandwidth_hz),
            detector: HfShareDetector::new(
                dt,
                t.oscillation_cutoff_hz,
                t.oscillation_window_s,
                t.oscillation_fraction,
                t.oscillation_min_force_n,
            ),
            mode: s.filter_aware,
            engaged: s.filter_aware == FilterAware::Always,
            release_steps: (s.release_s / dt).round() as usize,
            quiet: 0,
            lead: t.ekf_force_lead * (window.max(1) - 1) as f64 / 2.0,
            dlead: t.disturbance_lead * (window.max(1) - 1) as f64 / 2.0,
            dq: t.disturbance_q,
            torque_det: HfShareDetector::new(
                dt,
                t.torque_oscillation_cutoff_hz,
                t.torque_oscillation_window_s,
                t.torque_oscillation_fraction,
                t.torque_oscillation_nm,
            ),
            torque_on: t.torque_oscillation_nm > 0.0,
            last_force: None,
        }
    }

    /// Record measurement `m` and the controller's previous torque `torque`; `gap` restarts
    /// the angle history (first sample or skipped periods). Returns whether the filter-aware
    /// mode is engaged for this step.
    pub(crate) fn observe(
        &mut self,
        m: &Measurement<N>,
        torque: &SVector<f64, N>,
        gap: bool,
    ) -> bool {
        if gap {
            self.lag.reset();
            self.detector.reset();
            self.last_force = None;
            self.torque_det.reset();
        }
        self.lag.push(&m.q);
        let mut osc = self.detector.push(&m.force);
        if self.torque_on {
            osc |= self.torque_det.push(torque);
        }
        if self.mode == FilterAware::OnOscillation {
            if osc {
                self.engaged = true;
                self.quiet = 0;
            } else if self.engaged && self.release_steps > 0 {
                self.quiet += 1;
                if self.quiet >= self.release_steps {
                    self.engaged = false;
                    self.quiet = 0;
                }
            }
        }
        self.engaged
    }

    /// The strap force the EKF takes as its input while the filter-aware mode is not engaged:
    /// the filtered force `f` led by [`RobustTuning::ekf_force_lead`] (the filtered force
    /// itself on the first sample after a gap or with no lead), and the one the disturbance
    /// bank takes, led by [`RobustTuning::disturbance_lead`]. Call once per step.
    pub(crate) fn ekf_forces(&mut self, f: &SVector<f64, N>) -> (SVector<f64, N>, SVector<f64, N>) {
        let led = |lead: f64| match self.last_force {
            Some(prev) if lead > 0.0 => f + (f - prev) * lead,
            _ => *f,
        };
        let out = (led(self.lead), led(self.dlead));
        self.last_force = Some(*f);
        out
    }

    /// Restart the Smith predictor's velocity history (the filter-aware mode was off on the
    /// previous step, so its last velocity is stale).
    pub(crate) fn restart_velocity(&mut self) {
        self.lag.restart_velocity();
    }

    /// Whether the filter-aware mode engages on the inertia gate (control/heavy.rs).
    pub(crate) fn gated(&self) -> bool {
        self.mode == FilterAware::OnOscillation
    }

    /// Whether a second EKF bank supplies the disturbance estimates
    /// ([`RobustTuning::disturbance_lead`] > 0).
    pub(crate) fn disturbance_bank(&self) -> bool {
        self.dlead > 0.0 || self.dq > 0.0
    }

    /// The disturbance bank's random-walk variance (0 = the `[ekf]` one).
    pub(crate) fn disturbance_q(&self) -> f64 {
        self.dq
    }

    /// Record the lag-free velocity `qd_now` of this period and return the strap stretch and
    /// its rate whose force the Smith predictor removes ([`ForceLag::relative_motion`]); each
    /// scenario's predicted force is `F̄ − F(Δq, Δqd)` with its own strap model
    /// ([`ForceLag::predicted_force`]).
    pub(crate) fn relative_motion(
        &mut self,
        m: &Measurement<N>,
        qd_now: &SVector<f64, N>,
    ) -> Option<(SVector<f64, N>, SVector<f64, N>)> {
        self.lag.push_velocity(qd_now);
        self.lag.relative_motion(m, qd_now)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A force ramping linearly through a `w`-sample moving average lags by exactly
    /// `(w−1)/2` samples, so the full lead (`ekf_force_lead = 1`) gives back the true force of
    /// the current sample; no lead gives the filtered force.
    #[test]
    fn full_lead_recovers_a_ramp_behind_the_moving_average() {
        let dt = 0.01;
        let truth = |k: usize| SVector::<f64, 2>::new(3.0 + 0.7 * k as f64, -1.0 - 0.2 * k as f64);
        for w in [1usize, 3, 5, 9] {
            for (lead, want_true) in [(1.0, true), (0.0, false)] {
                let mut s = RobustSettings::default();
                s.tuning.ekf_force_lead = lead;
                let mut r = RobustState::<2>::new(&s, w, dt);
                for k in w..40 {
                    let filtered = (k + 1 - w..=k).map(truth).sum::<SVector<f64, 2>>() / w as f64;
                    let out = r.ekf_forces(&filtered).0;
                    if k > w {
                        let want = if want_true { truth(k) } else { filtered };
                        assert!(
                            (out - want).norm() < 1e-9,
                            "w {w} lead {lead} k {k}: {out:?}"
                        );
                    }
                }
            }
        }
    }

    /// Serde alone (a library caller deserialising the table) rejects a removed key by name
    /// and keeps the tuned constants for the rest.
    #[test]
    fn removed_keys_are_rejected_by_name_and_the_knobs_load() {
        for key in REMOVED_ROBUST_KEYS {
            let e = serde_json::from_str::<RobustSettings>(&alloc::format!("{{\"{key}\": 1}}"))
                .unwrap_err()
                .to_string();
            assert!(e.contains(&removed_robust_key(key)), "{key}: {e}");
        }
        let s: RobustSettings =
            serde_json::from_str(r#"{"release_s": 2.0, "filter_aware": "always"}"#).unwrap();
        assert_eq!(s.release_s, 2.0);
        assert_eq!(s.filter_aware, FilterAware::Always);
        assert_eq!(s.tuning, RobustTuning::default());
        let back = serde_json::to_value(&s).unwrap();
        assert!(back.get("tuning").is_none() && back.get("disturbance_lead").is_none());
        assert!(serde_json::from_str::<RobustSettings>(r#"{"nonsense": 1}"#).is_err());
    }

    #[test]
    fn strap_model_gains_equal_the_configured_ones_at_the_papers_straps() {
        let straps = |ks: f64| crate::model::Straps::two_dof(0.28, 0.16, ks, 93.7);
        let g = RobustIntentGains::StrapModel.gain(GainSetting::Value(0.005), 4.6875);
        assert_eq!(g.value(&straps(937.5)), 0.005);
        assert_eq!(g.value(&straps(1875.0)), 0.0025);
        let c = RobustIntentGains::Configured.gain(GainSetting::Value(0.004), 4.6875);
        assert_eq!(c.value(&straps(1875.0)), 0.004);
        let a = RobustIntentGains::StrapModel.gain(GainSetting::Auto, 4.6875);
        assert_eq!(a.value(&straps(468.75)), 0.01);
    }
}
