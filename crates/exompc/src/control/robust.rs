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
//! with a slower random walk and a led strap-force input ([`RobustSettings::disturbance_q`],
//! [`RobustSettings::disturbance_lead`]; the probabilities stay the paper's bank's); and
//! optionally the EKF's strap-torque input is led by a share of the moving average's delay
//! ([`RobustSettings::ekf_force_lead`], default off).

use super::intent::{GainSetting, IntentGain};
use super::lag::{ForceLag, HfShareDetector};
use super::Measurement;
#[cfg(not(feature = "std"))]
use crate::math::Float;
use nalgebra::SVector;
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

/// `[controller.robust]`: the extensions of `method = "robust"` (ignored for `"paper"`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RobustSettings {
    /// `"off"`, `"on_oscillation"` or `"always"`. Default `"on_oscillation"`.
    pub filter_aware: FilterAware,
    /// Cut-off (Hz) above which filtered strap-force power counts as oscillation, > 0 (one
    /// at or above the Nyquist frequency `1/(2·timing.dt)` sees almost nothing). Default 2.5.
    pub oscillation_cutoff_hz: f64,
    /// Averaging time (s) of the oscillation detector, in (0, 10]. Default 0.25.
    pub oscillation_window_s: f64,
    /// Share of the strap-force power above the cut-off that counts as oscillation, in
    /// (0, 1). Default 0.4.
    pub oscillation_fraction: f64,
    /// Smallest RMS (N) of the high-passed strap forces that counts as oscillation, >= 0.
    /// Default 1.5.
    pub oscillation_min_force_n: f64,
    /// Bandwidth (Hz) of the human's motion in the Smith predictor: the human's acceleration
    /// is taken as the robot's low-passed at this frequency, > 0; the strap observer
    /// ([`Self::intent_estimate`]) low-passes its human acceleration at it too. Default 3.
    pub human_bandwidth_hz: f64,
    /// With `"on_oscillation"`: return to the paper's estimate after this long (s) without a
    /// detected oscillation; 0 = stay engaged for the rest of the run. >= 0. Default 0.
    pub release_s: f64,
    /// Lead of the EKF's strap-torque input while the filter-aware mode is not engaged, as a
    /// fraction of the moving average's delay `(w−1)/2·dt`: the filtered force is extrapolated
    /// linearly from its last two samples, `F̄(k) + λ (w−1)/2 (F̄(k) − F̄(k−1))`. In [0, 3];
    /// 0 = the filtered force (the paper's). Default 0.
    pub ekf_force_lead: f64,
    /// Intent gains of the robust method: `"strap_model"` (the configured `controller.k1`,
    /// `k2` are the gains at the paper's 937.5 N/m straps and scale with `937.5 / ks`, i.e.
    /// `K = (κ / ks)·I` with `κ = 937.5·k`; exactly the configured gains at the default straps)
    /// or `"configured"` (`controller.k1`, `k2` as they are, the paper's). Default
    /// `"strap_model"`.
    pub intent_gains: RobustIntentGains,
    /// Lead of the strap-force input of the *disturbance bank*, as a share `λ_d` of the moving
    /// average's delay `(w−1)/2` samples, like [`Self::ekf_force_lead`]. The disturbance bank is
    /// a second EKF bank (same scenarios and `[ekf]` settings except
    /// [`Self::disturbance_q`]) that supplies only the disturbance estimates `d̂ᵢ` fed to the
    /// predictions; the scenario probabilities `μᵢ` stay the paper's bank's. In the paper's
    /// bank `d̂` absorbs the filter's lag torque `Jᵀ(F − F̄)`, which the prediction then holds
    /// over the horizon (docs/ROBUSTNESS.md, fifth pass). In [0, 3]. Default 0.5.
    pub disturbance_lead: f64,
    /// Random-walk variance ((N·m)² per step) of the disturbance bank's `d̂` (the `[ekf]
    /// q_disturbance` of the paper's bank is 1e-2: a slower `d̂` follows a payload mismatch
    /// but not the gait-frequency lag torque). >= 0; 0 = `[ekf] q_disturbance`. With
    /// `disturbance_lead = 0` and `disturbance_q = 0` there is no disturbance bank (the
    /// paper's `d̂`). Default 1e-3.
    pub disturbance_q: f64,
    /// With `"on_oscillation"`: the filter-aware mode also engages on an oscillation of the
    /// controller's own torque — the signal of the safety layer's torque-oscillation monitor,
    /// seen earlier and with lower thresholds, so that the start-up swing of a heavy or distal
    /// load engages the mode before the monitor trips: the torque high-passed at
    /// [`Self::torque_oscillation_cutoff_hz`], averaged over
    /// [`Self::torque_oscillation_window_s`], above this RMS (N·m) and above
    /// [`Self::torque_oscillation_fraction`] of the torque's power. >= 0; 0 = off (the strap
    /// force detector alone). Default 3.
    pub torque_oscillation_nm: f64,
    /// Averaging time (s) of the torque detector, in (0, 10]. Default 0.1.
    pub torque_oscillation_window_s: f64,
    /// Cut-off (Hz) of the torque detector's high-pass, > 0. Default 4.
    pub torque_oscillation_cutoff_hz: f64,
    /// Share of the torque power above the cut-off that counts as oscillation, in
    /// [0, 0.999]. Default 0.6.
    pub torque_oscillation_fraction: f64,
    /// With `"on_oscillation"`: the filter-aware mode is also used on every step where the
    /// scenarios whose *inertia ratio* reaches this value hold at least half of the EKF bank's
    /// probability (control/heavy.rs): a scenario's ratio is the largest over the joints of its
    /// diagonal mass-matrix entry at the stretched leg over the lightest scenario's. A payload
    /// far down the shank makes the moving average's delay unstable from the first step,
    /// before a detector sees it (docs/ROBUSTNESS.md, sixth pass). >= 0; 0 = off. Default 3.
    pub inertia_engage_ratio: f64,
    /// How long (s) the heavy scenarios must hold half of the probability without a break
    /// before the inertia gate opens; it then stays open. In [0, 10] (0 = one step).
    /// Default 0.1.
    pub inertia_engage_s: f64,
    /// Time constant (s) of a first-order low-pass on the scenario probabilities before they
    /// weight the scenarios' costs (paper eq. 12); the probabilities themselves (reported,
    /// and the filter-aware velocity blend) stay the bank's. Where no scenario fits, the
    /// posteriors chatter between 0 and 1 and each switch steps the torque
    /// (`control/weights.rs`). The low-pass starts once one scenario first holds more than
    /// half of the probability; until then the weights are the probabilities (the bank's
    /// uniform prior is not smoothed in). In [0, 10]; 0 = the probabilities as they are (the
    /// paper's). Default 0.15.
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
    /// `q_R` is exact, so this feedback has no filter delay). In [0, 1000]. Default 25.
    pub observer_velocity_gain: f64,
    /// Where the NMPC's velocity residual is measured: `"strap"` (`√r_d L (qd − qd_ref)`,
    /// `L = diag(J)⁻¹ J`: each strap's stretch rate in its link's angle units, so a hip held on
    /// its torque limit does not load the shank strap as well; [`super::VelocityTracking`]) or
    /// `"joint"` (the paper's eq. 7). Applies to every MS-NMPC scenario (the plain NMPC is the
    /// paper's); no effect with one joint. Default `"strap"`.
    pub velocity_tracking: super::VelocityTracking,
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
            oscillation_cutoff_hz: 2.5,
            oscillation_window_s: 0.25,
            oscillation_fraction: 0.4,
            oscillation_min_force_n: 1.5,
            human_bandwidth_hz: 3.0,
            release_s: 0.0,
            ekf_force_lead: 0.0,
            intent_gains: RobustIntentGains::StrapModel,
            disturbance_lead: 0.5,
            disturbance_q: 1e-3,
            torque_oscillation_nm: 3.0,
            torque_oscillation_window_s: 0.1,
            torque_oscillation_cutoff_hz: 4.0,
            torque_oscillation_fraction: 0.6,
            inertia_engage_ratio: 3.0,
            inertia_engage_s: 0.1,
            weight_smoothing_s: 0.15,
            intent_estimate: IntentEstimate::StrapObserver,
            observer_velocity_gain: 25.0,
            velocity_tracking: super::VelocityTracking::Strap,
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
    /// Detector on the controller's own torque ([`RobustSettings::torque_oscillation_nm`]).
    torque_det: HfShareDetector<N>,
    torque_on: bool,
    last_force: Option<SVector<f64, N>>,
}

impl<const N: usize> RobustState<N> {
    pub(crate) fn new(s: &RobustSettings, window: usize, dt: f64) -> Self {
        RobustState {
            lag: ForceLag::new(window, dt, s.human_bandwidth_hz),
            detector: HfShareDetector::new(
                dt,
                s.oscillation_cutoff_hz,
                s.oscillation_window_s,
                s.oscillation_fraction,
                s.oscillation_min_force_n,
            ),
            mode: s.filter_aware,
            engaged: s.filter_aware == FilterAware::Always,
            release_steps: (s.release_s / dt).round() as usize,
            quiet: 0,
            lead: s.ekf_force_lead * (window.max(1) - 1) as f64 / 2.0,
            dlead: s.disturbance_lead * (window.max(1) - 1) as f64 / 2.0,
            dq: s.disturbance_q,
            torque_det: HfShareDetector::new(
                dt,
                s.torque_oscillation_cutoff_hz,
                s.torque_oscillation_window_s,
                s.torque_oscillation_fraction,
                s.torque_oscillation_nm,
            ),
            torque_on: s.torque_oscillation_nm > 0.0,
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
    /// the filtered force `f` led by [`RobustSettings::ekf_force_lead`] (the filtered force
    /// itself on the first sample after a gap or with no lead), and the one the disturbance
    /// bank takes, led by [`RobustSettings::disturbance_lead`]. Call once per step.
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
    /// ([`RobustSettings::disturbance_lead`] > 0).
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
                let s = RobustSettings {
                    ekf_force_lead: lead,
                    ..RobustSettings::default()
                };
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
