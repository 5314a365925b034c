//! The human's desired gait (docs/MODEL.md §6): the scenario's `[trajectory]` table ([`Gait`]),
//! either the parametric swing of the paper or a recorded motion ([`GaitRecording`]: joint
//! angles sampled in time, interpolated by a C2 cubic spline).
//!
//! The library reads no files: a front end (the `exompc` CLI reads a CSV) hands the samples to
//! [`GaitRecording::new`], which checks them and builds the splines once; the plant and the
//! controller then evaluate the trajectory at whatever times they ask (the plant's RK4 stages),
//! with velocity and acceleration differentiated exactly from the spline.

use super::spline::{CubicSpline, SplineEnds};
use super::trajectory::{KneeTrajectory, SwingTrajectory, Trajectory};
use crate::check::InvalidField;
use crate::model::Real;
use alloc::{format, string::ToString, vec, vec::Vec};
use core::fmt;
use nalgebra::SVector;
use serde::{Deserialize, Serialize};
#[cfg(feature = "std")]
use std::path::PathBuf;

/// A file name without `std` (nothing reads files on the target): the text as written.
#[cfg(not(feature = "std"))]
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(transparent)]
pub struct PathBuf(pub alloc::string::String);

#[cfg(not(feature = "std"))]
impl PathBuf {
    /// The file name as written.
    pub fn display(&self) -> &str {
        &self.0
    }
}
use alloc::sync::Arc;

/// Which desired motion the human follows (`[trajectory] kind`).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum GaitKind {
    /// The paper's parametric motion: [`SwingTrajectory`] (2-DOF) or [`KneeTrajectory`]
    /// (1-DOF), from the table's other keys. Also spelled `"sine"`.
    #[default]
    #[serde(alias = "sine")]
    Parametric,
    /// Joint angles recorded in time (`[trajectory] file`, see [`GaitRecording`]).
    Recorded,
}

/// `[trajectory]`: the human's desired motion (MODEL.md §6).
///
/// The parametric keys are those of [`SwingTrajectory`] (2-DOF) and [`KneeTrajectory`]
/// (`one_dof_amplitude`, `one_dof_frequency_hz`), written flat in the table. With
/// `kind = "recorded"`, the motion is the recording in `file` instead; a front end loads it into
/// [`Gait::recording`] (the `exompc` CLI reads `file` as a CSV relative to the config file's
/// folder).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Gait {
    /// `"parametric"` (default; alias `"sine"`) or `"recorded"`.
    pub kind: GaitKind,
    /// The recording (CSV of time and joint angles) when `kind = "recorded"`; absent otherwise.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub file: Option<PathBuf>,
    /// The 2-DOF parametric swing (its keys sit directly in the table).
    #[serde(flatten)]
    pub swing: SwingTrajectory,
    /// The 1-DOF parametric knee motion (keys `one_dof_amplitude`, `one_dof_frequency_hz`).
    #[serde(flatten)]
    pub knee: KneeTrajectory,
    /// The loaded recording of `file` (never read from or written to the table itself).
    #[serde(skip)]
    pub recording: Option<Arc<GaitRecording>>,
}

impl Gait {
    /// Checks every key (see [`SwingTrajectory::validate`], [`KneeTrajectory::validate`]) and
    /// that `kind = "recorded"` comes with a loaded recording, `file` only with `kind =
    /// "recorded"`. The error names the key within the table (`file`, `hip_amplitude`).
    pub fn validate(&self) -> Result<(), InvalidField> {
        self.swing.validate()?;
        self.knee.validate()?;
        let shown = |f: &Option<PathBuf>| match f {
            Some(p) => format!("\"{}\"", p.display()),
            None => "absent".to_string(),
        };
        match self.kind {
            GaitKind::Parametric if self.file.is_some() => Err(InvalidField::new(
                "kind",
                "\"parametric\"",
                format!(
                    "\"recorded\" when file is set (file = {}); or remove file",
                    shown(&self.file)
                ),
            )),
            GaitKind::Recorded if self.recording.is_none() => Err(InvalidField::new(
                "file",
                shown(&self.file),
                "with kind = \"recorded\": a CSV of time and joint angles, loaded by the front \
                 end (the exompc CLI reads the file; library users set Gait::recording)",
            )),
            _ => Ok(()),
        }
    }

    /// Checks that this gait can drive a run of layout `dof` (1 or 2 joints) lasting
    /// `duration_s`: a recording must have a hip column for 2 joints, and must last at least
    /// the run or loop (its last sample equal to its first). Always `Ok` for the parametric
    /// motion. `duration_key` names the setting of the run length in the message.
    pub fn check_run(
        &self,
        dof: usize,
        duration_s: f64,
        duration_key: &str,
    ) -> Result<(), InvalidField> {
        let Some(rec) = self
            .recording
            .as_ref()
            .filter(|_| self.kind == GaitKind::Recorded)
        else {
            return Ok(());
        };
        let file = self.file.as_ref().map_or("the recording".to_string(), |p| {
            format!("\"{}\"", p.display())
        });
        if dof == 2 && !rec.has_hip() {
            return Err(InvalidField::new(
                "file",
                format!("{file} (knee angles only)"),
                "for the 2-DOF layout, a hip column as well (hip_rad or hip_deg); a knee-only \
                 recording drives the 1-DOF layout",
            ));
        }
        // Rounding slack: a recording written at the run's own sample times ends exactly there.
        if !rec.is_periodic() && rec.duration() < duration_s - 1e-9 * duration_s.max(1.0) {
            return Err(InvalidField::new(
                "file",
                format!(
                    "{file} (recording is {} s, run asks {} s)",
                    rec.duration(),
                    duration_s
                ),
                format!(
                    "a recording lasting the whole run ({duration_key} = {duration_s} s), or a \
                     loop (last sample equal to the first, replayed periodically); or shorten \
                     {duration_key}"
                ),
            ));
        }
        Ok(())
    }

    /// The 2-DOF desired trajectory: the parametric swing, or the recording's hip and knee.
    ///
    /// A table that [`Gait::validate`] and [`Gait::check_run`] reject (a recorded kind without
    /// recording, a knee-only recording) still evaluates without panicking: the parametric swing,
    /// or the hip held at 0 rad.
    pub fn two_dof(&self) -> GaitTrajectory<SwingTrajectory, 2> {
        self.build(self.swing)
    }

    /// The 1-DOF desired trajectory: the parametric knee motion, or the recording's knee.
    pub fn one_dof(&self) -> GaitTrajectory<KneeTrajectory, 1> {
        self.build(self.knee)
    }

    fn build<P, const N: usize>(&self, parametric: P) -> GaitTrajectory<P, N> {
        match (&self.recording, self.kind) {
            (Some(rec), GaitKind::Recorded) => GaitTrajectory::Recorded(RecordedTrajectory {
                recording: Arc::clone(rec),
            }),
            _ => GaitTrajectory::Parametric(parametric),
        }
    }
}

/// A column of a recording, as named in [`RecordingError`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum RecordingColumn {
    /// Time (s).
    Time,
    /// Hip angle (rad).
    Hip,
    /// Knee angle (rad).
    Knee,
}

impl fmt::Display for RecordingColumn {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            RecordingColumn::Time => "time",
            RecordingColumn::Hip => "hip angle",
            RecordingColumn::Knee => "knee angle",
        })
    }
}

/// Why samples do not make a recording. Samples are counted from 0 in the order given.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum RecordingError {
    /// Fewer than [`GaitRecording::MIN_SAMPLES`] samples.
    #[error("{got} samples; a recording needs at least {min} (a cubic spline through them)", min = GaitRecording::MIN_SAMPLES)]
    TooFew {
        /// Number of samples given.
        got: usize,
    },
    /// An angle column's length differs from the time column's.
    #[error("the {column} column has {got} values for {expected} times")]
    Length {
        /// The angle column.
        column: RecordingColumn,
        /// Its length.
        got: usize,
        /// Number of times.
        expected: usize,
    },
    /// A value is NaN or infinite.
    #[error("sample {sample}: the {column} is {value}, not a finite number")]
    NotFinite {
        /// Sample index (from 0).
        sample: usize,
        /// Column.
        column: RecordingColumn,
        /// The value.
        value: f64,
    },
    /// Time does not increase strictly.
    #[error("sample {sample}: time {t} s is not after the previous sample's {previous} s (time must increase strictly)")]
    NotIncreasing {
        /// Sample index (from 0).
        sample: usize,
        /// Its time (s).
        t: f64,
        /// The previous sample's time (s).
        previous: f64,
    },
    /// A joint angle beyond ±2π rad (most likely degrees given as radians).
    #[error("sample {sample}: the {column} is {value} rad, beyond ±2π rad (a joint turns less than a full circle)")]
    Implausible {
        /// Sample index (from 0).
        sample: usize,
        /// Column.
        column: RecordingColumn,
        /// The value (rad).
        value: f64,
    },
}

impl RecordingError {
    /// The sample (from 0) the error is about, if one.
    pub fn sample(&self) -> Option<usize> {
        match *self {
            RecordingError::NotFinite { sample, .. }
            | RecordingError::NotIncreasing { sample, .. }
            | RecordingError::Implausible { sample, .. } => Some(sample),
            _ => None,
        }
    }

    /// The column the error is about, if one.
    pub fn column(&self) -> Option<RecordingColumn> {
        match *self {
            RecordingError::NotFinite { column, .. }
            | RecordingError::Implausible { column, .. }
            | RecordingError::Length { column, .. } => Some(column),
            RecordingError::NotIncreasing { .. } => Some(RecordingColumn::Time),
            RecordingError::TooFew { .. } => None,
        }
    }
}

/// Recorded joint angles as C2 cubic splines of time (docs/MODEL.md §6).
///
/// Time is shifted so that the first sample is at run time 0. If the last sample's angles equal
/// the first's (within [`GaitRecording::LOOP_TOLERANCE_RAD`]), the recording is a loop: the
/// splines are periodic (value, velocity and acceleration continuous across the seam) and the
/// motion repeats with period `t_last − t_first`. Otherwise the splines are not-a-knot (a cubic
/// motion is reproduced exactly; nothing is imposed at the ends) and a run must not outlast the
/// recording ([`Gait::check_run`]).
#[derive(Debug, Clone, PartialEq)]
pub struct GaitRecording {
    hip: Option<CubicSpline>,
    knee: CubicSpline,
    samples: usize,
}

impl GaitRecording {
    /// Fewest samples accepted.
    pub const MIN_SAMPLES: usize = 4;

    /// Largest difference (rad) between first and last angles that still makes a loop.
    pub const LOOP_TOLERANCE_RAD: f64 = 1e-6;

    /// Checks the samples (at least 4; finite; time strictly increasing; every angle within
    /// ±2π rad) and builds the splines. `times` in s, angles in rad; `hip` is `None` for a
    /// knee-only (1-DOF) recording.
    pub fn new(times: &[f64], hip: Option<&[f64]>, knee: &[f64]) -> Result<Self, RecordingError> {
        let n = times.len();
        let mut columns = vec![(RecordingColumn::Time, times)];
        if let Some(h) = hip {
            columns.push((RecordingColumn::Hip, h));
        }
        columns.push((RecordingColumn::Knee, knee));
        for &(column, values) in &columns[1..] {
            if values.len() != n {
                return Err(RecordingError::Length {
                    column,
                    got: values.len(),
                    expected: n,
                });
            }
        }
        // Sample by sample, so that the first bad line of a file is the one reported.
        for sample in 0..n {
            for &(column, values) in &columns {
                let value = values[sample];
                if !value.is_finite() {
                    return Err(RecordingError::NotFinite {
                        sample,
                        column,
                        value,
                    });
                }
                if column != RecordingColumn::Time && value.abs() > 2.0 * core::f64::consts::PI {
                    return Err(RecordingError::Implausible {
                        sample,
                        column,
                        value,
                    });
                }
            }
            if sample > 0 && times[sample] <= times[sample - 1] {
                return Err(RecordingError::NotIncreasing {
                    sample,
                    t: times[sample],
                    previous: times[sample - 1],
                });
            }
        }
        if n < Self::MIN_SAMPLES {
            return Err(RecordingError::TooFew { got: n });
        }
        let closes = |v: &[f64]| (v[n - 1] - v[0]).abs() <= Self::LOOP_TOLERANCE_RAD;
        let periodic = closes(knee) && hip.is_none_or(closes);
        let ends = if periodic {
            SplineEnds::Periodic
        } else {
            SplineEnds::NotAKnot
        };
        let knots: Vec<f64> = times.iter().map(|t| t - times[0]).collect();
        // The checks above are what the spline needs; only a degenerate knot spacing (such as
        // 1e-300 s) could still fail, reported at the first interval.
        let spline = |values: &[f64]| {
            CubicSpline::new(&knots, values, ends).ok_or(RecordingError::NotIncreasing {
                sample: 1,
                t: times[1],
                previous: times[0],
            })
        };
        Ok(GaitRecording {
            hip: hip.map(spline).transpose()?,
            knee: spline(knee)?,
            samples: n,
        })
    }

    /// Length `t_last − t_first` (s); the period if the recording loops.
    pub fn duration(&self) -> f64 {
        self.knee.end() - self.knee.start()
    }

    /// Whether the recording loops (its last angles equal its first).
    pub fn is_periodic(&self) -> bool {
        self.knee.ends() == SplineEnds::Periodic
    }

    /// Whether there is a hip column (needed by the 2-DOF layout).
    pub fn has_hip(&self) -> bool {
        self.hip.is_some()
    }

    /// Number of samples.
    pub fn samples(&self) -> usize {
        self.samples
    }

    /// Hip angle (rad) at run time `t` (0 without a hip column); exact derivatives with duals.
    pub fn hip<T: Real>(&self, t: T) -> T {
        self.hip.as_ref().map_or(T::zero(), |s| s.eval(t))
    }

    /// Knee angle (rad) at run time `t`; exact derivatives with dual numbers.
    pub fn knee<T: Real>(&self, t: T) -> T {
        self.knee.eval(t)
    }
}

/// A recording as an `N`-joint desired trajectory: `[hip, knee]` for `N = 2`, `[knee]` for
/// `N = 1` (the 1-DOF layout's joint is the knee).
#[derive(Debug, Clone, PartialEq)]
pub struct RecordedTrajectory<const N: usize> {
    recording: Arc<GaitRecording>,
}

impl<const N: usize> RecordedTrajectory<N> {
    /// The trajectory of `recording`; `None` unless `N` is 1, or 2 with a hip column.
    pub fn new(recording: Arc<GaitRecording>) -> Option<Self> {
        (N == 1 || (N == 2 && recording.has_hip())).then_some(RecordedTrajectory { recording })
    }

    /// The recording.
    pub fn recording(&self) -> &GaitRecording {
        &self.recording
    }
}

impl<const N: usize> Trajectory<N> for RecordedTrajectory<N> {
    fn position<T: Real>(&self, t: T) -> SVector<T, N> {
        SVector::from_fn(|i, _| {
            if i + 1 == N {
                self.recording.knee(t)
            } else if i + 2 == N {
                self.recording.hip(t)
            } else {
                T::zero()
            }
        })
    }
}

/// The desired trajectory of a run: the parametric motion `P` or a recording.
#[derive(Debug, Clone, PartialEq)]
pub enum GaitTrajectory<P, const N: usize> {
    /// The paper's parametric motion.
    Parametric(P),
    /// A recorded motion.
    Recorded(RecordedTrajectory<N>),
}

impl<P: Trajectory<N>, const N: usize> Trajectory<N> for GaitTrajectory<P, N> {
    fn position<T: Real>(&self, t: T) -> SVector<T, N> {
        match self {
            GaitTrajectory::Parametric(p) => p.position(t),
            GaitTrajectory::Recorded(r) => r.position(t),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn samples(
        n: usize,
        rate: f64,
        f: impl Fn(f64) -> (f64, f64),
    ) -> (Vec<f64>, Vec<f64>, Vec<f64>) {
        let t: Vec<f64> = (0..n).map(|k| 3.0 + k as f64 / rate).collect();
        let (h, k) = t.iter().map(|&t| f(t - 3.0)).unzip();
        (t, h, k)
    }

    #[test]
    fn each_bad_recording_is_named() {
        let (t, h, k) = samples(20, 10.0, |t| (0.1 * t, -0.2 * t));
        let err = |t: &[f64], h: &[f64], k: &[f64]| GaitRecording::new(t, Some(h), k).unwrap_err();
        assert_eq!(
            err(&t[..3], &h[..3], &k[..3]),
            RecordingError::TooFew { got: 3 }
        );
        assert!(matches!(
            err(&t, &h[..5], &k),
            RecordingError::Length {
                column: RecordingColumn::Hip,
                got: 5,
                expected: 20
            }
        ));
        let mut bad = t.clone();
        bad[7] = bad[6];
        let e = err(&bad, &h, &k);
        assert_eq!(
            (e.sample(), e.column()),
            (Some(7), Some(RecordingColumn::Time))
        );
        assert!(
            e.to_string()
                .contains("not after the previous sample's 3.6 s"),
            "{e}"
        );
        let mut bad = k.clone();
        bad[4] = f64::NAN;
        let e = err(&t, &h, &bad);
        assert_eq!(
            (e.sample(), e.column()),
            (Some(4), Some(RecordingColumn::Knee))
        );
        let mut bad = h.clone();
        bad[9] = 30.0; // degrees given as radians
        let e = err(&t, &bad, &k);
        assert!(
            matches!(
                e,
                RecordingError::Implausible {
                    sample: 9,
                    column: RecordingColumn::Hip,
                    ..
                }
            ),
            "{e}"
        );
        assert!(e.to_string().contains("beyond ±2π"), "{e}");
        // Time first: the earliest bad sample is reported.
        let mut bad = t.clone();
        bad[2] = f64::INFINITY;
        assert_eq!(err(&bad, &h, &k).sample(), Some(2));
    }

    #[test]
    fn recording_is_shifted_to_zero_and_interpolates() {
        let (t, h, k) = samples(50, 20.0, |t| (0.1 + 0.3 * (2.0 * t).sin(), -0.5 * t * t));
        let rec = GaitRecording::new(&t, Some(&h), &k).unwrap();
        assert!(!rec.is_periodic() && rec.has_hip());
        assert!((rec.duration() - 49.0 / 20.0).abs() < 1e-12);
        assert_eq!(rec.samples(), 50);
        for i in 0..50 {
            let ti = t[i] - 3.0;
            assert!((rec.hip(ti) - h[i]).abs() < 1e-12 && (rec.knee(ti) - k[i]).abs() < 1e-12);
        }
        // The knee is a quadratic: reproduced exactly with its derivatives by the spline.
        let traj = RecordedTrajectory::<2>::new(Arc::new(rec)).unwrap();
        let (q, qd, qdd) = traj.eval(1.234);
        assert!((q[1] + 0.5 * 1.234 * 1.234).abs() < 1e-12);
        assert!(
            (qd[1] + 1.234).abs() < 1e-10 && (qdd[1] + 1.0).abs() < 1e-8,
            "{qd} {qdd}"
        );
    }

    #[test]
    fn replays_the_parametric_swing_with_its_derivatives() {
        let swing = SwingTrajectory::default();
        let rate = 200.0;
        let t: Vec<f64> = (0..=(20.0 * rate) as usize)
            .map(|k| k as f64 / rate)
            .collect();
        let q: Vec<_> = t.iter().map(|&t| swing.position(t)).collect();
        let h: Vec<f64> = q.iter().map(|q| q[0]).collect();
        let k: Vec<f64> = q.iter().map(|q| q[1]).collect();
        let gait = Gait {
            kind: GaitKind::Recorded,
            recording: Some(Arc::new(GaitRecording::new(&t, Some(&h), &k).unwrap())),
            ..Gait::default()
        };
        gait.validate().unwrap();
        gait.check_run(2, 20.0, "timing.duration_2dof_s").unwrap();
        let rec = gait.two_dof();
        assert!(matches!(rec, GaitTrajectory::Recorded(_)));
        for i in 0..995 {
            let t = 0.0201 * i as f64;
            let (a, b) = (rec.eval(t), swing.eval(t));
            assert!((a.0 - b.0).amax() < 1e-7, "q at {t}");
            assert!((a.1 - b.1).amax() < 1e-5, "qd at {t}");
            // O(h²): largest in the end intervals (0.009 rad/s² of 16 at 200 Hz).
            assert!((a.2 - b.2).amax() < 2e-2, "qdd at {t}: {} vs {}", a.2, b.2);
        }
        // The 1-DOF layout reads the knee column.
        let one = gait.one_dof();
        assert!((one.eval(3.3).0[0] - swing.eval(3.3).0[1]).abs() < 1e-7);
    }

    #[test]
    fn loops_when_the_last_sample_equals_the_first() {
        let (t, h, k) = samples(41, 20.0, |t| {
            let p = (std::f64::consts::PI * t).sin(); // period 2 s over 2 s of samples
            (0.2 * p, -0.4 - 0.3 * p)
        });
        let rec = Arc::new(GaitRecording::new(&t, Some(&h), &k).unwrap());
        assert!(rec.is_periodic());
        let traj = RecordedTrajectory::<2>::new(rec).unwrap();
        for x in [0.0, 0.37, 1.99] {
            let (a, b) = (traj.eval(x), traj.eval(x + 6.0));
            assert!((a.0 - b.0).amax() < 1e-12 && (a.1 - b.1).amax() < 1e-9);
        }
        let gait = Gait {
            kind: GaitKind::Recorded,
            recording: Some(Arc::clone(&traj.recording)),
            ..Gait::default()
        };
        gait.check_run(2, 20.0, "timing.duration_2dof_s").unwrap();
    }

    #[test]
    fn gait_table_errors_name_the_key() {
        let mut g = Gait::default();
        g.validate().unwrap();
        g.swing.hip_amplitude = -1.0;
        assert_eq!(g.validate().unwrap_err().field, "hip_amplitude");
        g = Gait::default();
        g.swing.frequency_swing_hz = 0.8;
        let e = g.validate().unwrap_err();
        assert_eq!(
            (e.field.as_str(), e.allowed.as_str()),
            ("frequency_swing_hz", "finite, in [0, 0.8)")
        );
        g = Gait::default();
        g.knee.frequency_hz = 0.0;
        assert_eq!(g.validate().unwrap_err().field, "one_dof_frequency_hz");
        g = Gait {
            kind: GaitKind::Recorded,
            ..Gait::default()
        };
        assert_eq!(g.validate().unwrap_err().field, "file");
        g = Gait {
            file: Some("walk.csv".into()),
            ..Gait::default()
        };
        assert_eq!(g.validate().unwrap_err().field, "kind");
        // Too short, and knee-only for two joints.
        let (t, _, k) = samples(11, 10.0, |t| (0.0, -0.1 * t));
        g = Gait {
            kind: GaitKind::Recorded,
            file: Some("walk.csv".into()),
            recording: Some(Arc::new(GaitRecording::new(&t, None, &k).unwrap())),
            ..Gait::default()
        };
        g.validate().unwrap();
        let e = g.check_run(1, 20.0, "timing.duration_1dof_s").unwrap_err();
        assert!(e.value.contains("recording is 1 s, run asks 20 s"), "{e}");
        assert!(e.allowed.contains("timing.duration_1dof_s"), "{e}");
        g.check_run(1, 1.0, "timing.duration_1dof_s").unwrap();
        assert!(g
            .check_run(2, 1.0, "timing.duration_2dof_s")
            .unwrap_err()
            .allowed
            .contains("hip"));
        assert!(RecordedTrajectory::<2>::new(Arc::clone(g.recording.as_ref().unwrap())).is_none());
    }
}
