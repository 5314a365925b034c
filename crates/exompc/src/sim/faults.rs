//! Sensor fault injection (`[faults]`, see [`FaultInjector`]) and the soak run's counters.

use super::closed_loop::{Recorder, StepRecord};
use crate::check::{self, InvalidField, Range};
use crate::control::{Measurement, StepStatus};
#[cfg(not(feature = "std"))]
use crate::math::Float;
use alloc::{format, vec, vec::Vec};
use serde::{Deserialize, Serialize};

/// Kind of an injected sensor fault.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum FaultKind {
    /// The channel reads NaN.
    Nan,
    /// The channel reads +infinity.
    Inf,
    /// No new sample arrives (the controller sees a stale/missing measurement).
    Dropout,
    /// `magnitude` is added to the reading.
    Spike,
    /// The reading freezes at its value at the fault's start.
    Stuck,
    /// The reading is clipped to `±faults.saturation_n` (force channels).
    Saturation,
}

impl FaultKind {
    /// Every kind, in the order of [`FaultKind::NAMES`].
    pub const ALL: [FaultKind; 6] = [
        FaultKind::Nan,
        FaultKind::Inf,
        FaultKind::Dropout,
        FaultKind::Spike,
        FaultKind::Stuck,
        FaultKind::Saturation,
    ];
    /// The kinds' names as written in `[[faults.events]] kind` and on the command line.
    pub const NAMES: [&'static str; 6] = [
        FaultKind::Nan.name(),
        FaultKind::Inf.name(),
        FaultKind::Dropout.name(),
        FaultKind::Spike.name(),
        FaultKind::Stuck.name(),
        FaultKind::Saturation.name(),
    ];

    /// The lowercase name (`"nan"`, `"dropout"`, ...; the serialised form).
    pub const fn name(self) -> &'static str {
        match self {
            FaultKind::Nan => "nan",
            FaultKind::Inf => "inf",
            FaultKind::Dropout => "dropout",
            FaultKind::Spike => "spike",
            FaultKind::Stuck => "stuck",
            FaultKind::Saturation => "saturation",
        }
    }

    /// Parses a name of [`FaultKind::name`].
    pub fn parse(s: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|k| k.name() == s)
    }
}

/// Measured channel affected by a fault.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Channel {
    /// Hip angle (rad).
    Q1,
    /// Knee angle (rad).
    Q2,
    /// Hip velocity (rad/s).
    Qd1,
    /// Knee velocity (rad/s).
    Qd2,
    /// Thigh strap force (N).
    F1,
    /// Shank strap force (N).
    F2,
}

impl Channel {
    /// Every channel, in the order of [`Channel::NAMES`].
    pub const ALL: [Channel; 6] = [
        Channel::Q1,
        Channel::Q2,
        Channel::Qd1,
        Channel::Qd2,
        Channel::F1,
        Channel::F2,
    ];
    /// The channels' names as written in `[[faults.events]] channel`.
    pub const NAMES: [&'static str; 6] = [
        Channel::Q1.name(),
        Channel::Q2.name(),
        Channel::Qd1.name(),
        Channel::Qd2.name(),
        Channel::F1.name(),
        Channel::F2.name(),
    ];

    /// The lowercase name (`"q1"`, ..., `"f2"`; the serialised form).
    pub const fn name(self) -> &'static str {
        match self {
            Channel::Q1 => "q1",
            Channel::Q2 => "q2",
            Channel::Qd1 => "qd1",
            Channel::Qd2 => "qd2",
            Channel::F1 => "f1",
            Channel::F2 => "f2",
        }
    }

    /// Zero-based joint / strap index (0 = hip / thigh, 1 = knee / shank).
    pub fn joint(self) -> usize {
        match self {
            Channel::Q1 | Channel::Qd1 | Channel::F1 => 0,
            Channel::Q2 | Channel::Qd2 | Channel::F2 => 1,
        }
    }
}

/// One `[[faults.events]]` entry: a sensor fault active on `[start_s, start_s + duration_s)`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FaultEvent {
    /// Fault kind (`"nan"`, `"inf"`, `"dropout"`, `"spike"`, `"stuck"`, `"saturation"`).
    pub kind: FaultKind,
    /// Affected channel (`"q1"`, `"q2"`, `"qd1"`, `"qd2"`, `"f1"`, `"f2"`).
    pub channel: Channel,
    /// Start time (s), >= 0.
    pub start_s: f64,
    /// Duration (s), >= 0.
    pub duration_s: f64,
    /// Additive magnitude of a spike (channel units), finite; optional, default 0.
    #[serde(default)]
    pub magnitude: f64,
}

impl FaultEvent {
    /// Whether the fault is active at time `t` (s).
    pub fn active_at(&self, t: f64) -> bool {
        t >= self.start_s && t < self.start_s + self.duration_s
    }
}

/// `[faults]`: scripted sensor faults for robustness tests.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Faults {
    /// Fault events (`[[faults.events]]`). Default none.
    pub events: Vec<FaultEvent>,
    /// Force sensor range ±saturation_n (N), > 0. Default 70.
    pub saturation_n: f64,
}

impl Default for Faults {
    fn default() -> Self {
        Self {
            events: Vec::new(),
            saturation_n: 70.0,
        }
    }
}

impl Faults {
    /// Checks the force range (finite, > 0), every event's start and duration (finite and
    /// not negative) and magnitude (finite); the error names the key (`saturation_n`,
    /// `events[2].start_s`).
    pub fn validate(&self) -> Result<(), InvalidField> {
        check::real("saturation_n", self.saturation_n, Range::Pos)?;
        for (i, ev) in self.events.iter().enumerate() {
            check::reals(&[
                ("start_s", ev.start_s, Range::NonNeg),
                ("duration_s", ev.duration_s, Range::NonNeg),
                ("magnitude", ev.magnitude, Range::Any),
            ])
            .map_err(|e| e.within(&format!("events[{i}]")))?;
        }
        Ok(())
    }
}

/// Which signal of a measurement a fault acts on.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Signal {
    Angle,
    Velocity,
    Force,
}

#[derive(Clone, Copy, Debug)]
struct Armed {
    kind: FaultKind,
    signal: Signal,
    joint: usize,
    start: f64,
    end: f64,
    magnitude: f64,
    /// The channel's value when the fault became active (for `stuck`).
    held: Option<f64>,
}

/// Applies a fault schedule to raw sensor samples; allocation-free after construction.
///
/// The faults of `[faults]` are scripted NaN, inf, dropout, spike, stuck and saturation
/// faults, applied to the raw sensor sample *before* the moving-average filter, so the
/// controller sees exactly what a real faulty sensor would produce after filtering (a NaN
/// poisons the filter window for `filter_window` samples after the fault ends, a spike is
/// smeared over the window, a dropout or a stuck sensor yields a frozen filtered value once
/// the window is full of repeated samples).
///
/// Channel mapping: in 2-DOF runs `q1/qd1/f1` are the hip/thigh (index 0) and `q2/qd2/f2`
/// the knee/shank (index 1). In 1-DOF runs (hip locked) the single joint is the knee, so
/// `q2/qd2/f2` map to it and `q1/qd1/f1` events are ignored.
#[derive(Clone, Debug)]
pub struct FaultInjector<const N: usize> {
    events: Vec<Armed>,
    saturation_n: f64,
    /// The previous raw sample as delivered (after faults), for `dropout`.
    last: Option<Measurement<N>>,
}

/// Joint index of `channel` in an `N`-joint run, or `None` when the channel does not exist
/// (`q1/qd1/f1` in 1-DOF runs).
pub fn channel_index<const N: usize>(channel: Channel) -> Option<usize> {
    let j = channel.joint();
    let offset = 2usize.saturating_sub(N);
    j.checked_sub(offset).filter(|&i| i < N)
}

fn signal(channel: Channel) -> Signal {
    match channel {
        Channel::Q1 | Channel::Q2 => Signal::Angle,
        Channel::Qd1 | Channel::Qd2 => Signal::Velocity,
        Channel::F1 | Channel::F2 => Signal::Force,
    }
}

fn slot<const N: usize>(m: &mut Measurement<N>, s: Signal, j: usize) -> &mut f64 {
    match s {
        Signal::Angle => &mut m.q[j],
        Signal::Velocity => &mut m.qd[j],
        Signal::Force => &mut m.force[j],
    }
}

impl<const N: usize> FaultInjector<N> {
    /// An injector with no faults and the default force range.
    pub fn none() -> Self {
        Self::new(&Faults::default())
    }

    /// An injector for the `[faults]` section (events on channels absent in an `N`-joint run
    /// are dropped; events with a non-finite or negative time are ignored).
    pub fn new(faults: &Faults) -> Self {
        let events = faults
            .events
            .iter()
            .filter_map(|e: &FaultEvent| {
                let joint = channel_index::<N>(e.channel)?;
                let ok = e.start_s.is_finite() && e.duration_s.is_finite() && e.duration_s >= 0.0;
                ok.then_some(Armed {
                    kind: e.kind,
                    signal: signal(e.channel),
                    joint,
                    start: e.start_s,
                    end: e.start_s + e.duration_s,
                    magnitude: if e.magnitude.is_finite() {
                        e.magnitude
                    } else {
                        0.0
                    },
                    held: None,
                })
            })
            .collect();
        let saturation_n = if faults.saturation_n.is_finite() && faults.saturation_n > 0.0 {
            faults.saturation_n
        } else {
            Faults::default().saturation_n
        };
        FaultInjector {
            events,
            saturation_n,
            last: None,
        }
    }

    /// Number of events that apply to this run.
    pub fn event_count(&self) -> usize {
        self.events.len()
    }

    /// Force sensor range ±`saturation_n` (N).
    pub fn saturation_n(&self) -> f64 {
        self.saturation_n
    }

    /// Apply the physical force range and every fault active at `raw.t` to the raw sample.
    ///
    /// * `nan` / `inf`: the channel reads NaN / +∞;
    /// * `dropout`: the channel repeats its previous delivered raw value;
    /// * `stuck`: the channel holds the value it had when the fault started;
    /// * `spike`: `magnitude` is added;
    /// * `saturation`: the sensor rails: the reading jumps to full scale `±saturation_n` with
    ///   the sign of the reading (channel units; on angle/velocity channels this is an
    ///   implausible value the supervisor rejects).
    ///
    /// The force channels are always clipped to `±saturation_n` first (the sensor's range).
    pub fn apply(&mut self, raw: &mut Measurement<N>) {
        let sat = self.saturation_n;
        for f in raw.force.iter_mut() {
            // NaN stays NaN (clamp propagates it); only faults produce non-finite values.
            *f = f.clamp(-sat, sat);
        }
        let t = raw.t;
        let clean = *raw;
        for e in self.events.iter_mut() {
            let active = t >= e.start && t < e.end;
            if !active {
                e.held = None;
                continue;
            }
            let v = slot(raw, e.signal, e.joint);
            match e.kind {
                FaultKind::Nan => *v = f64::NAN,
                FaultKind::Inf => *v = f64::INFINITY,
                FaultKind::Dropout => {
                    if let Some(mut last) = self.last {
                        *v = *slot(&mut last, e.signal, e.joint);
                    }
                }
                FaultKind::Stuck => {
                    let mut c = clean;
                    let h = *e.held.get_or_insert(*slot(&mut c, e.signal, e.joint));
                    *v = h;
                }
                FaultKind::Spike => *v += e.magnitude,
                FaultKind::Saturation => {
                    *v = if v.is_nan() { *v } else { sat.copysign(*v) };
                }
            }
        }
        self.last = Some(*raw);
    }
}

/// A default fault schedule of one period: one event of each kind on varied channels of an
/// `N`-joint run, starting at `offset_s` (used by the soak test; repeat with
/// [`repeat_schedule`]). Each event lasts 0.2–0.5 s and they are 8 s apart.
pub fn default_schedule(offset_s: f64, dof: usize) -> Vec<FaultEvent> {
    let two = dof >= 2;
    let pick = |a: Channel, b: Channel| if two { a } else { b };
    let ev = |kind, channel, start: f64, duration_s, magnitude| FaultEvent {
        kind,
        channel,
        start_s: offset_s + start,
        duration_s,
        magnitude,
    };
    vec![
        ev(
            FaultKind::Nan,
            pick(Channel::F1, Channel::F2),
            5.0,
            0.2,
            0.0,
        ),
        ev(FaultKind::Inf, Channel::Qd2, 13.0, 0.1, 0.0),
        ev(
            FaultKind::Dropout,
            pick(Channel::Q1, Channel::Q2),
            21.0,
            0.3,
            0.0,
        ),
        ev(FaultKind::Spike, Channel::F2, 29.0, 0.05, 40.0),
        ev(
            FaultKind::Stuck,
            pick(Channel::Qd1, Channel::Qd2),
            37.0,
            0.5,
            0.0,
        ),
        ev(FaultKind::Saturation, Channel::F2, 45.0, 0.2, 0.0),
    ]
}

/// `base` (times within one period) repeated every `period_s` up to `duration_s`.
pub fn repeat_schedule(base: &[FaultEvent], period_s: f64, duration_s: f64) -> Vec<FaultEvent> {
    let mut out = Vec::new();
    if !(period_s > 0.0 && duration_s.is_finite()) {
        return out;
    }
    let mut k = 0.0;
    while k * period_s < duration_s {
        for e in base {
            let mut e = e.clone();
            e.start_s += k * period_s;
            if e.start_s < duration_s {
                out.push(e);
            }
        }
        k += 1.0;
    }
    out
}

/// Counters of a long fault-injected run, accumulated online (constant memory).
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct SoakStats {
    /// Control steps.
    pub steps: u64,
    /// Steps with a non-finite torque, robot/human state or true strap force.
    pub nan_count: u64,
    /// Steps whose torque violated a limit (checked by the closed loop).
    pub limit_violations: u64,
    /// Largest true strap force magnitude (N).
    pub max_abs_force_n: f64,
    /// RMS of the true strap forces over all straps and steps (N).
    pub rms_force_n: f64,
    /// Steps whose solve did not converge.
    pub solver_failures: u64,
    /// Steps with status `bad_measurement`.
    pub bad_measurement_steps: u64,
    /// Steps with status `monitor_tripped`.
    pub monitor_steps: u64,
    #[serde(skip)]
    sum_f2: f64,
    #[serde(skip)]
    n_f: u64,
}

impl<const N: usize> Recorder<N> for SoakStats {
    fn record(&mut self, r: &StepRecord<'_, N>) -> super::closed_loop::RecordResult {
        self.steps += 1;
        let finite = r.torque_robot.iter().all(|v| v.is_finite())
            && r.robot
                .q
                .iter()
                .chain(r.robot.qd.iter())
                .all(|v| v.is_finite())
            && r.human
                .q
                .iter()
                .chain(r.human.qd.iter())
                .all(|v| v.is_finite())
            && r.force_true.iter().all(|v| v.is_finite());
        self.nan_count += u64::from(!finite);
        self.limit_violations += u64::from(!r.within_limits);
        for f in r.force_true.iter() {
            if f.is_finite() {
                self.max_abs_force_n = self.max_abs_force_n.max(f.abs());
                self.sum_f2 += f * f;
                self.n_f += 1;
            }
        }
        self.rms_force_n = (self.sum_f2 / self.n_f.max(1) as f64).sqrt();
        self.solver_failures += u64::from(r.status.is_solver_failure());
        self.bad_measurement_steps += u64::from(r.status == StepStatus::BadMeasurement);
        self.monitor_steps += u64::from(r.status == StepStatus::MonitorTripped);
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_names_are_the_serialised_forms() {
        for k in FaultKind::ALL {
            assert_eq!(serde_json::to_value(k).unwrap(), k.name());
            assert_eq!(FaultKind::parse(k.name()), Some(k));
        }
        for c in Channel::ALL {
            assert_eq!(serde_json::to_value(c).unwrap(), c.name());
        }
        assert_eq!(FaultKind::parse("glitch"), None);
    }
    use nalgebra::SVector;

    fn zero_measurement<const N: usize>(t: f64) -> Measurement<N> {
        Measurement {
            t,
            q: SVector::zeros(),
            qd: SVector::zeros(),
            force: SVector::zeros(),
        }
    }

    fn ev(kind: FaultKind, channel: Channel, mag: f64) -> FaultEvent {
        FaultEvent {
            kind,
            channel,
            start_s: 1.0,
            duration_s: 1.0,
            magnitude: mag,
        }
    }

    fn run<const N: usize>(e: FaultEvent, values: &[f64]) -> Vec<f64> {
        let mut inj = FaultInjector::<N>::new(&Faults {
            events: vec![e],
            saturation_n: 70.0,
        });
        values
            .iter()
            .enumerate()
            .map(|(k, &v)| {
                let mut m = zero_measurement::<N>(0.5 * k as f64);
                m.force[N - 1] = v;
                inj.apply(&mut m);
                m.force[N - 1]
            })
            .collect()
    }

    #[test]
    fn kinds() {
        let x = [1.0, 2.0, 3.0, 4.0, 5.0];
        let r = run::<2>(ev(FaultKind::Nan, Channel::F2, 0.0), &x);
        assert!(r[2].is_nan() && r[3].is_nan() && r[4] == 5.0 && r[1] == 2.0);
        let r = run::<2>(ev(FaultKind::Inf, Channel::F2, 0.0), &x);
        assert_eq!(r[2], f64::INFINITY);
        assert_eq!(
            run::<2>(ev(FaultKind::Dropout, Channel::F2, 0.0), &x),
            [1.0, 2.0, 2.0, 2.0, 5.0]
        );
        assert_eq!(
            run::<2>(ev(FaultKind::Stuck, Channel::F2, 0.0), &x),
            [1.0, 2.0, 3.0, 3.0, 5.0]
        );
        assert_eq!(
            run::<2>(ev(FaultKind::Spike, Channel::F2, 10.0), &x),
            [1.0, 2.0, 13.0, 14.0, 5.0]
        );
        assert_eq!(
            run::<2>(
                ev(FaultKind::Saturation, Channel::F2, 0.0),
                &[1.0, -2.0, -3.0, 4.0, 90.0]
            ),
            [1.0, -2.0, -70.0, 70.0, 70.0]
        );
        // 1-DOF: f2 maps to the single strap, f1 is ignored.
        assert_eq!(
            run::<1>(ev(FaultKind::Spike, Channel::F2, 10.0), &x),
            [1.0, 2.0, 13.0, 14.0, 5.0]
        );
        assert_eq!(run::<1>(ev(FaultKind::Spike, Channel::F1, 10.0), &x), x);
        assert_eq!(channel_index::<1>(Channel::Q1), None);
        assert_eq!(channel_index::<1>(Channel::Qd2), Some(0));
        assert_eq!(channel_index::<2>(Channel::Qd1), Some(0));
    }

    #[test]
    fn schedule_repeats() {
        let s = repeat_schedule(&default_schedule(0.0, 2), 60.0, 120.0);
        assert_eq!(s.len(), 12);
        assert!(s.iter().all(|e| e.start_s < 120.0));
    }
}
