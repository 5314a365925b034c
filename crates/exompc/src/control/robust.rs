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
//! interaction oscillation, and then stays engaged.

use super::lag::{ForceLag, HfShareDetector};
use super::Measurement;
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
    /// is taken as the robot's low-passed at this frequency, > 0. Default 3.
    pub human_bandwidth_hz: f64,
    /// With `"on_oscillation"`: return to the paper's estimate after this long (s) without a
    /// detected oscillation; 0 = stay engaged for the rest of the run. >= 0. Default 0.
    pub release_s: f64,
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
        }
    }

    /// Record measurement `m`; `gap` restarts the angle history (first sample or skipped
    /// periods). Returns whether the filter-aware mode is engaged for this step.
    pub(crate) fn observe(&mut self, m: &Measurement<N>, gap: bool) -> bool {
        if gap {
            self.lag.reset();
            self.detector.reset();
        }
        self.lag.push(&m.q);
        let osc = self.detector.push(&m.force);
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
