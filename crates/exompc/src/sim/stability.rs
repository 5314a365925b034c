//! Classifying a closed-loop run as stable, limit cycle, growing or saturating from its
//! strap-force and torque traces (the operating-envelope scans of `exompc envelope`).
//!
//! Three measures per strap force, all on the *true* strap forces of a [`TraceLog`]:
//!
//! * the fraction of the signal's power above a cutoff frequency (3 Hz: the gait lives below
//!   it, the delay-driven limit cycles near 4 Hz above it), from the discrete Fourier
//!   transform of the whole run (Parseval: the power at or below the cutoff is summed over the
//!   DFT bins `0..=k_c`, the rest of `Σ x²` lies above);
//! * the RMS of the last and of the first window (2 s), whose ratio shows growth;
//! * the RMS over the run.
//!
//! Plus the fraction of steps on the torque limit (`|T| = T_max` on some joint) and on the
//! rate limit (`|T − T_prev| = ΔT_max`), paper eqs. 8-9.

use super::closed_loop::TraceLog;
use crate::control::TorqueLimits;
#[cfg(not(feature = "std"))]
use crate::math::Float;
use alloc::vec::Vec;
use serde::{Deserialize, Serialize};

/// Thresholds of [`classify_run`] and of the envelope acceptance (issue "Done when").
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct StabilityCriteria {
    /// Frequency separating gait from oscillation (Hz). Default 3.
    pub cutoff_hz: f64,
    /// A strap whose power fraction above `cutoff_hz` reaches this is oscillating. Default 0.25.
    pub max_high_frequency_fraction: f64,
    /// Length of the first / last window compared for growth (s). Default 2.
    pub window_s: f64,
    /// Last-window RMS above this multiple of the first-window RMS is growth. Default 1.5.
    pub max_growth: f64,
    /// A run on the torque or rate limit in more than this fraction of its steps is
    /// saturating. Default 0.05.
    pub max_limit_fraction: f64,
    /// Largest acceptable RMS strap force (N), waived for saturating runs. Default 20.
    pub max_rms_n: f64,
}

impl Default for StabilityCriteria {
    fn default() -> Self {
        StabilityCriteria {
            cutoff_hz: 3.0,
            max_high_frequency_fraction: 0.25,
            window_s: 2.0,
            max_growth: 1.5,
            max_limit_fraction: 0.05,
            max_rms_n: 20.0,
        }
    }
}

/// What a run does, in order of precedence (the first that applies).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum RunClass {
    /// Some strap's last-window RMS exceeds `max_growth ×` its first-window RMS.
    Growing,
    /// Some strap has at least `max_high_frequency_fraction` of its power above `cutoff_hz`.
    LimitCycle,
    /// Not growing nor oscillating, but on the torque or rate limit in more than
    /// `max_limit_fraction` of the steps.
    Saturating,
    /// None of the above.
    Stable,
}

impl RunClass {
    /// Lower-case name (`stable`, `limit_cycle`, `growing`, `saturating`).
    pub fn name(self) -> &'static str {
        match self {
            RunClass::Growing => "growing",
            RunClass::LimitCycle => "limit_cycle",
            RunClass::Saturating => "saturating",
            RunClass::Stable => "stable",
        }
    }
}

/// The measures of one strap force.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct StrapStability {
    /// RMS over the run (N).
    pub rms_n: f64,
    /// Fraction of the power (mean square, DC included) above the cutoff, in [0, 1].
    pub high_frequency_fraction: f64,
    /// RMS of the first window (N).
    pub first_window_rms_n: f64,
    /// RMS of the last window (N).
    pub last_window_rms_n: f64,
}

impl StrapStability {
    /// The measures of force samples `x` taken every `dt` seconds.
    pub fn of(x: &[f64], dt: f64, c: &StabilityCriteria) -> Self {
        let w = ((c.window_s / dt).round() as usize).clamp(1, x.len().max(1));
        let (first, last) = if x.is_empty() {
            (&x[..0], &x[..0])
        } else {
            (&x[..w], &x[x.len() - w..])
        };
        StrapStability {
            rms_n: rms(x),
            high_frequency_fraction: high_frequency_fraction(x, dt, c.cutoff_hz),
            first_window_rms_n: rms(first),
            last_window_rms_n: rms(last),
        }
    }

    /// Growth above `max_growth` (or not a number).
    pub fn is_growing(&self, c: &StabilityCriteria) -> bool {
        let g = self.growth();
        g.is_nan() || g > c.max_growth
    }

    /// Power fraction above the cutoff at least `max_high_frequency_fraction` (or not a
    /// number).
    pub fn is_oscillating(&self, c: &StabilityCriteria) -> bool {
        let f = self.high_frequency_fraction;
        f.is_nan() || f >= c.max_high_frequency_fraction
    }

    /// Last-window RMS over first-window RMS (∞ when only the first is zero, 1 when both are).
    pub fn growth(&self) -> f64 {
        if self.first_window_rms_n > 0.0 {
            self.last_window_rms_n / self.first_window_rms_n
        } else if self.last_window_rms_n > 0.0 {
            f64::INFINITY
        } else {
            1.0
        }
    }
}

/// Root mean square of `x` (0 for an empty slice; NaN if any sample is NaN).
pub fn rms(x: &[f64]) -> f64 {
    if x.is_empty() {
        return 0.0;
    }
    (x.iter().map(|v| v * v).sum::<f64>() / x.len() as f64).sqrt()
}

/// Fraction of the power of `x` (sampled every `dt` s; mean square, DC included) at
/// frequencies strictly above `cutoff_hz`, from its discrete Fourier transform: with
/// `X_k = Σ x_n e^{−2πi kn/N}`, Parseval gives `N Σ x² = Σ_k |X_k|²`, and bin `k` (with its
/// mirror `N − k`) is at `k / (N dt)` Hz. Only the bins at or below the cutoff are computed
/// (`O(N k_c)`), the rest of the power lies above. 0 for an all-zero or empty signal, NaN if a
/// sample is not finite.
pub fn high_frequency_fraction(x: &[f64], dt: f64, cutoff_hz: f64) -> f64 {
    let n = x.len();
    let total: f64 = x.iter().map(|v| v * v).sum();
    if !total.is_finite() {
        return f64::NAN;
    }
    if n == 0 || total == 0.0 {
        return 0.0;
    }
    // Highest bin at or below the cutoff, and at most the Nyquist bin.
    let kc = ((cutoff_hz * n as f64 * dt + 1e-9).floor().max(0.0) as usize).min(n / 2);
    let mut low = 0.0;
    for k in 0..=kc {
        // X_k by a rotating phasor (recomputed exactly every 64 samples against drift).
        let w = -2.0 * core::f64::consts::PI * k as f64 / n as f64;
        let (mut re, mut im) = (0.0, 0.0);
        let (step_s, step_c) = w.sin_cos();
        let (mut s, mut c) = (0.0f64, 1.0f64);
        for (j, &v) in x.iter().enumerate() {
            if j % 64 == 0 {
                (s, c) = (w * j as f64).sin_cos();
            }
            re += v * c;
            im += v * s;
            (s, c) = (s * step_c + c * step_s, c * step_c - s * step_s);
        }
        let p = re * re + im * im;
        // Bins 1..N/2 stand for their mirror too (except the Nyquist bin of an even N).
        let mirrored = k != 0 && !(n.is_multiple_of(2) && k == n / 2);
        low += if mirrored { 2.0 * p } else { p };
    }
    (1.0 - low / (n as f64 * total)).clamp(0.0, 1.0)
}

/// The classification of one run and the measures behind it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RunStability {
    /// The class (first of growing, limit cycle, saturating, stable that applies).
    pub class: RunClass,
    /// Per strap force, thigh then shank (1-DOF: shank only).
    pub straps: Vec<StrapStability>,
    /// Fraction of steps with `|T| = T_max` on some joint.
    pub torque_limit_fraction: f64,
    /// Fraction of steps with `|T − T_prev| = ΔT_max` on some joint (from the second step).
    pub rate_limit_fraction: f64,
    /// Steps classified.
    pub steps: usize,
}

impl RunStability {
    /// Largest high-frequency fraction over the straps.
    pub fn max_high_frequency_fraction(&self) -> f64 {
        self.straps
            .iter()
            .map(|s| s.high_frequency_fraction)
            .fold(0.0, f64::max)
    }

    /// Largest growth ratio over the straps.
    pub fn max_growth(&self) -> f64 {
        self.straps
            .iter()
            .map(StrapStability::growth)
            .fold(0.0, f64::max)
    }

    /// Largest RMS strap force (N).
    pub fn max_rms_n(&self) -> f64 {
        self.straps.iter().map(|s| s.rms_n).fold(0.0, f64::max)
    }

    /// On the torque or rate limit in more than `max_limit_fraction` of the steps.
    pub fn on_limits(&self, c: &StabilityCriteria) -> bool {
        self.torque_limit_fraction > c.max_limit_fraction
            || self.rate_limit_fraction > c.max_limit_fraction
    }
}

/// Classify measures: see [`RunClass`] for the precedence.
pub fn classify(
    straps: Vec<StrapStability>,
    torque_limit_fraction: f64,
    rate_limit_fraction: f64,
    steps: usize,
    c: &StabilityCriteria,
) -> RunStability {
    let mut r = RunStability {
        class: RunClass::Stable,
        straps,
        torque_limit_fraction,
        rate_limit_fraction,
        steps,
    };
    // NaN measures count as the bad case.
    let growing = r.straps.iter().any(|s| s.is_growing(c));
    let oscillating = r.straps.iter().any(|s| s.is_oscillating(c));
    r.class = if growing {
        RunClass::Growing
    } else if oscillating {
        RunClass::LimitCycle
    } else if r.on_limits(c) {
        RunClass::Saturating
    } else {
        RunClass::Stable
    };
    r
}

/// Classify a run from its trace: true strap forces, robot torques against `limits`, control
/// period `dt` (s).
pub fn classify_run<const N: usize>(
    trace: &TraceLog<N>,
    limits: &TorqueLimits,
    dt: f64,
    c: &StabilityCriteria,
) -> RunStability {
    let rows = &trace.rows;
    let straps = (0..N)
        .map(|s| {
            let x: Vec<f64> = rows.iter().map(|r| r.force_true[s]).collect();
            StrapStability::of(&x, dt, c)
        })
        .collect();
    // On a limit: within 1e-9 relative of it (the controllers clamp exactly onto it).
    let at = |v: f64, lim: f64| v.abs() >= lim * (1.0 - 1e-9);
    let on_torque = rows
        .iter()
        .filter(|r| r.torque_robot.iter().any(|&t| at(t, limits.max)))
        .count();
    let on_rate = rows
        .windows(2)
        .filter(|w| (0..N).any(|i| at(w[1].torque_robot[i] - w[0].torque_robot[i], limits.rate)))
        .count();
    let n = rows.len().max(1) as f64;
    classify(
        straps,
        on_torque as f64 / n,
        on_rate as f64 / n,
        rows.len(),
        c,
    )
}

/// One envelope cell's verdict against the acceptance ("Done when"): the robust
/// controller's run `ms` against the plain NMPC's run `nmpc` of the same cell.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CellVerdict {
    /// Growth ≤ `max_growth` and power above the cutoff < `max_high_frequency_fraction` on
    /// every strap.
    pub stable: bool,
    /// Every strap's RMS < `max_rms_n`, or waived because the run sits on the torque limit in
    /// more than `max_limit_fraction` of its steps (see `rms_waived`).
    pub rms_ok: bool,
    /// The RMS bound was waived (torque limit in more than `max_limit_fraction` of the steps).
    pub rms_waived: bool,
    /// No step outside the torque or rate limit.
    pub within_limits: bool,
    /// Every strap's RMS ≤ `ratio ×` the NMPC's (ratio 1 at payloads ≥ 1 kg, 1.1 below), or
    /// the NMPC's run tripped a safety monitor while the robust one did not (the reference's
    /// forces are then the safety layer's, and the NMPC failed the cell by itself).
    pub no_worse_than_nmpc: bool,
    /// No safety monitor tripped (a run that needs the safety layer does not hold), or the
    /// trips were waived (see `trips_waived`).
    pub no_monitor_trip: bool,
    /// The trips were waived: the cell's gait needs more torque than the actuator has on more
    /// than `max_limit_fraction` of the instants ([`crate::sim::actuator_demand`]), so the
    /// straps must carry the shortfall and the strap-force monitor must trip whatever the
    /// controller does, and the NMPC's run tripped as well. The run must still be stable,
    /// within the limits and no worse than the NMPC's (the rule for torque-limited
    /// cells).
    #[serde(default)]
    pub trips_waived: bool,
    /// All of the above.
    pub pass: bool,
}

/// The acceptance of one cell: `ms` is the robust run classified, `nmpc_rms` the NMPC run's
/// per-strap RMS forces and `nmpc_trips` its safety-monitor trips, `violations` and
/// `monitor_trips` the robust run's limit violations and safety-monitor trips, `payload_kg`
/// the true payload, `gait_beyond_limit` the share of the instants at which the cell's gait
/// needs more than the torque limit ([`crate::sim::ActuatorDemand::beyond_limit_fraction`]).
#[allow(clippy::too_many_arguments)]
pub fn cell_verdict(
    ms: &RunStability,
    nmpc_rms: &[f64],
    nmpc_trips: u64,
    violations: u64,
    monitor_trips: u64,
    payload_kg: f64,
    gait_beyond_limit: f64,
    c: &StabilityCriteria,
) -> CellVerdict {
    let stable = ms
        .straps
        .iter()
        .all(|s| !s.is_growing(c) && !s.is_oscillating(c));
    let rms_waived = ms.torque_limit_fraction > c.max_limit_fraction;
    let rms_ok = rms_waived || ms.straps.iter().all(|s| s.rms_n < c.max_rms_n);
    let ratio = if payload_kg >= 1.0 { 1.0 } else { 1.1 };
    let reference_needed_the_safety_layer = nmpc_trips > 0 && monitor_trips == 0;
    let no_worse_than_nmpc = reference_needed_the_safety_layer
        || (ms.straps.len() == nmpc_rms.len()
            && ms
                .straps
                .iter()
                .zip(nmpc_rms)
                .all(|(s, &n)| s.rms_n <= ratio * n));
    let within_limits = violations == 0;
    let trips_waived =
        monitor_trips > 0 && gait_beyond_limit > c.max_limit_fraction && nmpc_trips > 0;
    let no_monitor_trip = monitor_trips == 0 || trips_waived;
    CellVerdict {
        stable,
        rms_ok,
        rms_waived,
        within_limits,
        no_worse_than_nmpc,
        no_monitor_trip,
        trips_waived,
        pass: stable && rms_ok && within_limits && no_worse_than_nmpc && no_monitor_trip,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::PI;

    const DT: f64 = 0.01;

    fn signal(n: usize, f: impl Fn(f64) -> f64) -> Vec<f64> {
        (0..n).map(|k| f(k as f64 * DT)).collect()
    }

    #[test]
    fn power_fraction_of_sines_matches_parseval() {
        let c = StabilityCriteria::default();
        // Whole periods in 20 s: exact bins, closed-form fractions.
        let n = 2000;
        let hf = |x: &[f64]| high_frequency_fraction(x, DT, c.cutoff_hz);
        assert!(hf(&signal(n, |t| (2.0 * PI * 4.0 * t).sin())) > 1.0 - 1e-9);
        assert!(hf(&signal(n, |t| (2.0 * PI * 1.0 * t).sin())) < 1e-9);
        assert!(hf(&signal(n, |_| 3.0)) < 1e-12);
        // a² / 2 at 5 Hz vs b² / 2 at 0.8 Hz and a DC d²: a² / (a² + b² + 2 d²).
        let (a, b, d) = (2.0, 3.0, 1.0);
        let x = signal(n, |t| {
            a * (2.0 * PI * 5.0 * t).sin() + b * (2.0 * PI * 0.8 * t).cos() + d
        });
        let want = a * a / (a * a + b * b + 2.0 * d * d);
        assert!((hf(&x) - want).abs() < 1e-9, "{} vs {want}", hf(&x));
        // Exactly 3 Hz is not above the cutoff.
        assert!(hf(&signal(n, |t| (2.0 * PI * 3.0 * t).sin())) < 1e-9);
        // Odd length and a non-integer number of periods: leakage stays small.
        let x = signal(1999, |t| (2.0 * PI * 0.83 * t).sin());
        assert!(hf(&x) < 1e-3, "{}", hf(&x));
        assert_eq!(hf(&[]), 0.0);
        assert!(hf(&[1.0, f64::NAN]).is_nan());
    }

    #[test]
    fn white_noise_spreads_power_evenly_over_the_band() {
        // A deterministic pseudo-random sequence (xorshift): about (50 − 3) / 50 of the
        // power lies above 3 Hz of the 50 Hz band.
        let mut s = 0x2545_f491_4f6c_dd1du64;
        let x: Vec<f64> = (0..20_000)
            .map(|_| {
                s ^= s << 13;
                s ^= s >> 7;
                s ^= s << 17;
                (s >> 11) as f64 / (1u64 << 53) as f64 - 0.5
            })
            .collect();
        let f = high_frequency_fraction(&x, DT, 3.0);
        assert!((f - 0.94).abs() < 0.02, "{f}");
    }

    fn strap(x: &[f64]) -> StrapStability {
        StrapStability::of(x, DT, &StabilityCriteria::default())
    }

    #[test]
    fn classes_of_synthetic_runs() {
        let c = StabilityCriteria::default();
        let n = 2000;
        let gait = signal(n, |t| 5.0 * (2.0 * PI * 0.8 * t).sin());
        let osc = signal(n, |t| 5.0 * (2.0 * PI * 4.0 * t).sin());
        // 1 Hz sine growing e-fold every 5 s: last / first window RMS ≈ e^(18/5).
        let grow = signal(n, |t| (t / 5.0).exp() * (2.0 * PI * 1.0 * t).sin());
        let cls = |x: &[f64], tl: f64| classify(vec![strap(&gait), strap(x)], tl, 0.0, n, &c).class;
        assert_eq!(cls(&gait, 0.0), RunClass::Stable);
        assert_eq!(cls(&osc, 0.0), RunClass::LimitCycle);
        assert_eq!(cls(&grow, 0.0), RunClass::Growing);
        assert_eq!(cls(&gait, 0.06), RunClass::Saturating);
        assert_eq!(cls(&gait, 0.05), RunClass::Stable);
        let g = strap(&grow).growth();
        assert!((g / (18.0f64 / 5.0).exp() - 1.0).abs() < 0.05, "{g}");
        // A growing oscillation is growing first.
        let grow_osc = signal(n, |t| (t / 5.0).exp() * (2.0 * PI * 4.0 * t).sin());
        assert_eq!(cls(&grow_osc, 0.0), RunClass::Growing);
        // Gait plus a 4 Hz ripple of a fifth of its amplitude: 1/26 of the power, stable.
        let ripple: Vec<f64> = gait.iter().zip(&osc).map(|(a, b)| a + 0.2 * b).collect();
        assert_eq!(cls(&ripple, 0.0), RunClass::Stable);
        let nan = vec![f64::NAN; n];
        assert_ne!(cls(&nan, 0.0), RunClass::Stable);
    }

    #[test]
    fn acceptance_of_a_cell() {
        let c = StabilityCriteria::default();
        let n = 2000;
        let ms = |amp: f64, tl: f64| {
            let x = signal(n, |t| amp * (2.0 * PI * 0.8 * t).sin());
            classify(vec![strap(&x), strap(&x)], tl, 0.0, n, &c)
        };
        let a = 5.0 / 2f64.sqrt(); // RMS of the 5 N sine
        assert!(cell_verdict(&ms(5.0, 0.0), &[a, a], 0, 0, 0, 1.0, 0.0, &c).pass);
        // At ≥ 1 kg no worse than NMPC; at 0 kg within 1.1×.
        let v = cell_verdict(&ms(5.0, 0.0), &[0.95 * a, a], 0, 0, 0, 1.0, 0.0, &c);
        assert!(!v.pass && !v.no_worse_than_nmpc && v.stable);
        assert!(cell_verdict(&ms(5.0, 0.0), &[0.95 * a, a], 0, 0, 0, 0.0, 0.0, &c).pass);
        assert!(!cell_verdict(&ms(5.0, 0.0), &[a, a], 0, 1, 0, 0.0, 0.0, &c).pass);
        // 30 N amplitude: RMS 21 N fails unless the torque limit waives it.
        let big = 30.0 / 2f64.sqrt() + 0.01;
        let v = cell_verdict(&ms(30.0, 0.0), &[big, big], 0, 0, 0, 2.0, 0.0, &c);
        assert!(!v.rms_ok && !v.pass);
        let v = cell_verdict(&ms(30.0, 0.2), &[big, big], 0, 0, 0, 2.0, 0.0, &c);
        assert!(v.rms_ok && v.rms_waived && v.pass);
        let v = cell_verdict(&ms(5.0, 0.0), &[a, a], 0, 0, 1, 1.0, 0.0, &c);
        assert!(!v.pass && !v.no_monitor_trip);
        // A reference that needed the safety layer (its forces are the fallback's) does not
        // make a robust run without trips worse; with trips on both sides forces decide.
        let v = cell_verdict(&ms(5.0, 0.0), &[0.5 * a, 0.5 * a], 3, 0, 0, 1.0, 0.0, &c);
        assert!(v.no_worse_than_nmpc && v.pass);
        let v = cell_verdict(&ms(5.0, 0.0), &[0.5 * a, 0.5 * a], 3, 0, 1, 1.0, 0.0, &c);
        assert!(!v.no_worse_than_nmpc && !v.pass);
        // Trips are waived only where the gait needs more than the actuator on more than
        // `max_limit_fraction` of the instants and the NMPC tripped too; stability and "no
        // worse than NMPC" still decide.
        let beyond = c.max_limit_fraction + 0.01;
        let v = cell_verdict(&ms(5.0, 0.0), &[a, a], 2, 0, 1, 1.0, beyond, &c);
        assert!(v.trips_waived && v.no_monitor_trip && v.pass, "{v:?}");
        let v = cell_verdict(
            &ms(5.0, 0.0),
            &[a, a],
            2,
            0,
            1,
            1.0,
            c.max_limit_fraction,
            &c,
        );
        assert!(!v.trips_waived && !v.pass);
        let v = cell_verdict(&ms(5.0, 0.0), &[a, a], 0, 0, 1, 1.0, beyond, &c);
        assert!(!v.trips_waived && !v.pass, "the NMPC did not trip");
        let v = cell_verdict(&ms(5.0, 0.0), &[0.9 * a, a], 2, 0, 1, 1.0, beyond, &c);
        assert!(v.trips_waived && !v.no_worse_than_nmpc && !v.pass);
        let v = cell_verdict(&ms(5.0, 0.0), &[a, a], 0, 0, 0, 1.0, beyond, &c);
        assert!(!v.trips_waived && v.pass, "nothing to waive");
    }
}
