//! Issue 28's goals for a sensor fault (peak true strap force, RMS against the same run without
//! the fault, torque limits, no latch), shared by the fault scan (`exompc faults`) and the
//! soak's per-fault verdicts ([`soak_fault_classes`]).

#[cfg(not(feature = "std"))]
use crate::math::Float;
use crate::sim::{Channel, FaultEvent, RecordResult, Recorder, StepRecord};
use alloc::{format, string::String, vec::Vec};
use serde::Serialize;

/// A group of sensor channels that fails together (more may come: match with a wildcard
/// arm, or use [`ChannelGroup::EVERY`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
#[non_exhaustive]
pub enum ChannelGroup {
    /// Every sensor: both angles, velocities and strap forces.
    All,
    /// Both encoder angles.
    Angles,
    /// Both filtered velocities.
    Velocities,
    /// Both strap forces.
    Forces,
    /// Joint 1's encoder (the hip): its angle and velocity.
    Joint1,
    /// Joint 2's encoder (the knee): its angle and velocity.
    Joint2,
}

impl ChannelGroup {
    /// The groups of the scan's default grid (issue 28's), in the scan's order: the first four
    /// of [`ChannelGroup::EVERY`].
    pub const ALL: [ChannelGroup; 4] = {
        let e = Self::EVERY;
        [e[0], e[1], e[2], e[3]]
    };

    /// Every group, in the declaration's order: [`ChannelGroup::ALL`] and one joint's encoder
    /// each.
    pub const EVERY: [ChannelGroup; 6] = [
        ChannelGroup::All,
        ChannelGroup::Angles,
        ChannelGroup::Velocities,
        ChannelGroup::Forces,
        ChannelGroup::Joint1,
        ChannelGroup::Joint2,
    ];

    /// The group's channels.
    pub fn channels(self) -> &'static [Channel] {
        match self {
            ChannelGroup::All => &Channel::ALL,
            ChannelGroup::Angles => &[Channel::Q1, Channel::Q2],
            ChannelGroup::Velocities => &[Channel::Qd1, Channel::Qd2],
            ChannelGroup::Forces => &[Channel::F1, Channel::F2],
            ChannelGroup::Joint1 => &[Channel::Q1, Channel::Qd1],
            ChannelGroup::Joint2 => &[Channel::Q2, Channel::Qd2],
        }
    }

    /// The smallest group holding every channel of `channels`: angles, velocities or forces
    /// when they are all of one kind, one joint's encoder when they are its angle and velocity,
    /// otherwise (or for none) every sensor.
    pub fn of(channels: impl IntoIterator<Item = Channel>) -> Self {
        let (mut any, mut held) = (false, [true; Self::EVERY.len()]);
        for c in channels {
            any = true;
            for (h, g) in held.iter_mut().zip(Self::EVERY) {
                *h &= g.channels().contains(&c);
            }
        }
        // `EVERY[1..]` holds two channels each: the first that holds them all is the smallest.
        Self::EVERY[1..]
            .iter()
            .zip(&held[1..])
            .find(|(_, &h)| any && h)
            .map_or(ChannelGroup::All, |(&g, _)| g)
    }

    /// The lowercase name (`all`, `angles`, ..., `joint1`).
    pub fn name(self) -> &'static str {
        Self::NAMES[self as usize]
    }

    /// Every group's name, in the order of [`ChannelGroup::EVERY`] (the declaration's).
    pub const NAMES: [&'static str; 6] =
        ["all", "angles", "velocities", "forces", "joint1", "joint2"];

    /// Parses a name of [`ChannelGroup::name`].
    pub fn parse(s: &str) -> Option<Self> {
        Self::EVERY.into_iter().find(|g| g.name() == s)
    }
}

/// Spike magnitude of a channel in the scan (issue 28): 0.5 rad on an angle, 0.5 rad/s on a
/// velocity, 30 N on a strap force.
pub fn spike_magnitude(c: Channel) -> f64 {
    match c {
        Channel::Q1 | Channel::Q2 | Channel::Qd1 | Channel::Qd2 => 0.5,
        Channel::F1 | Channel::F2 => 30.0,
    }
}

/// Longest fault (s) held to the 12/35-N peak and the RMS goal; longer ones have the 70-N peak
/// goal only.
const SHORT_FAULT_S: f64 = 0.2 + 1e-9;

/// Goal on the peak true strap force (N) of a fault of `duration_s` on `group` (issue 28):
/// 12 N for one group (twice the clean run's peak) and 35 N for every sensor, for faults up to
/// 200 ms; 70 N for longer ones.
pub fn peak_goal_n(group: ChannelGroup, duration_s: f64) -> f64 {
    if duration_s > SHORT_FAULT_S {
        70.0
    } else if group == ChannelGroup::All {
        35.0
    } else {
        12.0
    }
}

/// Largest RMS ratio (faulted / clean, per strap) of a passing fault up to 200 ms.
pub const RMS_RATIO_GOAL: f64 = 1.5;

/// The RMS ratio judged against [`RMS_RATIO_GOAL`]: the larger over the two straps of the
/// faulted run's RMS true strap force over the fault-free run's (`[thigh, shank]`, N).
pub fn rms_ratio(faulted: [f64; 2], fault_free: [f64; 2]) -> f64 {
    (0..2)
        .map(|j| faulted[j] / fault_free[j].max(1e-12))
        .fold(0.0, f64::max)
}

/// Whether a fault of `duration_s` on `group` met issue 28's goals: no torque-limit violation,
/// no latch, peak true strap force ≤ [`peak_goal_n`] and, for faults up to 200 ms, the RMS
/// ratio against the same run without the fault ≤ [`RMS_RATIO_GOAL`].
pub fn meets_goals(
    group: ChannelGroup,
    duration_s: f64,
    peak_force_n: f64,
    rms_ratio: f64,
    latched: bool,
    limit_violations: u64,
) -> bool {
    limit_violations == 0
        && !latched
        && peak_force_n <= peak_goal_n(group, duration_s)
        && (duration_s > SHORT_FAULT_S || rms_ratio <= RMS_RATIO_GOAL)
}

/// How long (s) after a fault ends its episode is still judged (the recovery), unless the next
/// fault starts earlier.
pub const EPISODE_AFTER_S: f64 = 5.0;

/// One fault episode of a schedule: events that overlap (or touch) merged into one.
#[derive(Clone, Debug, PartialEq)]
pub struct Episode {
    /// What failed: `"<kind> <channel>"` per distinct event, comma-separated (`"dropout q1"`).
    pub fault: String,
    /// The group of the failing channels ([`ChannelGroup::of`]).
    pub group: ChannelGroup,
    /// First fault start (s).
    pub start_s: f64,
    /// Last fault end (s).
    pub end_s: f64,
    /// End of the judged window (s): `end_s + EPISODE_AFTER_S`, or the next episode's start.
    pub window_end_s: f64,
}

impl Episode {
    /// The fault's duration (s).
    pub fn duration_s(&self) -> f64 {
        self.end_s - self.start_s
    }
}

/// The episodes of a fault schedule, in time order: events whose active intervals overlap or
/// touch form one episode, judged from its first start to [`Episode::window_end_s`].
/// Events of zero duration are ignored.
pub fn episodes(events: &[FaultEvent]) -> Vec<Episode> {
    let mut evs: Vec<&FaultEvent> = events.iter().filter(|e| e.duration_s > 0.0).collect();
    evs.sort_by(|a, b| a.start_s.total_cmp(&b.start_s));
    let mut out: Vec<Episode> = Vec::new();
    let mut channels: Vec<Channel> = Vec::new();
    for e in evs {
        let end = e.start_s + e.duration_s;
        let label = format!("{} {}", e.kind.name(), e.channel.name());
        match out.last_mut() {
            Some(last) if e.start_s <= last.end_s => {
                last.end_s = last.end_s.max(end);
                if !last.fault.split(", ").any(|l| l == label) {
                    last.fault = format!("{}, {label}", last.fault);
                }
                channels.push(e.channel);
                last.group = ChannelGroup::of(channels.iter().copied());
            }
            _ => {
                channels.clear();
                channels.push(e.channel);
                out.push(Episode {
                    fault: label,
                    group: ChannelGroup::of([e.channel]),
                    start_s: e.start_s,
                    end_s: end,
                    window_end_s: f64::INFINITY,
                });
            }
        }
    }
    for i in 0..out.len() {
        let next = out.get(i + 1).map_or(f64::INFINITY, |n| n.start_s);
        out[i].window_end_s = (out[i].end_s + EPISODE_AFTER_S).min(next);
    }
    out
}

/// Per-episode true strap forces of a 2-DOF run: peak, the sums for the RMS per strap and the
/// torque-limit violations within each episode's window, accumulated online.
#[derive(Clone, Debug)]
pub struct EpisodeStats {
    windows: Vec<(f64, f64)>,
    next: usize,
    /// Per episode: largest |true strap force| (N) and its time (s).
    pub peak: Vec<(f64, f64)>,
    /// Per episode: sum of squared true strap forces per strap.
    pub sum_sq: Vec<[f64; 2]>,
    /// Per episode: steps recorded.
    pub steps: Vec<u64>,
    /// Per episode: steps whose torque violated a limit.
    pub violations: Vec<u64>,
}

impl EpisodeStats {
    /// Empty counters for `episodes`.
    pub fn new(episodes: &[Episode]) -> Self {
        let n = episodes.len();
        EpisodeStats {
            windows: episodes
                .iter()
                .map(|e| (e.start_s, e.window_end_s))
                .collect(),
            next: 0,
            peak: alloc::vec![(0.0, 0.0); n],
            sum_sq: alloc::vec![[0.0; 2]; n],
            steps: alloc::vec![0; n],
            violations: alloc::vec![0; n],
        }
    }

    /// RMS true strap force (N) per strap of episode `i` (0 when it has no steps).
    pub fn rms(&self, i: usize) -> [f64; 2] {
        let n = self.steps[i].max(1) as f64;
        [
            (self.sum_sq[i][0] / n).sqrt(),
            (self.sum_sq[i][1] / n).sqrt(),
        ]
    }
}

impl Recorder<2> for EpisodeStats {
    fn record(&mut self, r: &StepRecord<'_, 2>) -> RecordResult {
        while self.next < self.windows.len() && r.t >= self.windows[self.next].1 {
            self.next += 1;
        }
        let i = self.next;
        if i < self.windows.len() && r.t >= self.windows[i].0 {
            for (j, f) in r.force_true.iter().enumerate() {
                if f.abs() > self.peak[i].0 || !f.is_finite() {
                    self.peak[i] = (f.abs(), r.t);
                }
                self.sum_sq[i][j] += f * f;
            }
            self.steps[i] += 1;
            self.violations[i] += u64::from(!r.within_limits);
        }
        Ok(())
    }
}

/// The soak's verdict for one class of injected fault (same kind, channels and duration):
/// how many of its episodes met issue 28's goals ([`meets_goals`]) and its worst episode.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct SoakFaultClass {
    /// What failed (`"dropout q1"`; see [`Episode::fault`]).
    pub fault: String,
    /// The failing channels' group.
    pub group: ChannelGroup,
    /// Fault duration (s).
    pub duration_s: f64,
    /// The goal on the peak true strap force (N, [`peak_goal_n`]).
    pub peak_goal_n: f64,
    /// Episodes judged (those the run and its fault-free reference both reached).
    pub episodes: u64,
    /// Episodes that met the goals.
    pub passing: u64,
    /// Largest peak true strap force (N) of any episode, and when it happened (s).
    pub worst_peak_force_n: f64,
    /// Time (s) of that peak.
    pub worst_peak_at_s: f64,
    /// Largest RMS ratio (per strap, over the episode's window, faulted / fault-free).
    pub worst_rms_ratio: f64,
    /// Start (s) of the episode with that ratio.
    pub worst_rms_at_s: f64,
}

/// Groups the `episodes` of a soak into classes and judges each episode against issue 28's
/// goals: the faulted run's per-episode counters `faulted` against `reference`, the same run
/// without faults over the same windows; an episode whose window ends after the supervisor
/// latched (`latched_at_s`) fails. Episodes either run did not reach are not judged.
pub fn soak_fault_classes(
    episodes: &[Episode],
    faulted: &EpisodeStats,
    reference: &EpisodeStats,
    latched_at_s: Option<f64>,
) -> Vec<SoakFaultClass> {
    let mut classes: Vec<SoakFaultClass> = Vec::new();
    for (i, e) in episodes.iter().enumerate() {
        if faulted.steps[i] == 0 || reference.steps[i] == 0 {
            continue;
        }
        let ratio = rms_ratio(faulted.rms(i), reference.rms(i));
        let (peak, peak_at) = faulted.peak[i];
        let latched = latched_at_s.is_some_and(|t| t < e.window_end_s);
        let pass = meets_goals(
            e.group,
            e.duration_s(),
            peak,
            ratio,
            latched,
            faulted.violations[i],
        );
        // Durations of the same schedule entry differ by rounding only.
        let same =
            |c: &SoakFaultClass| c.fault == e.fault && (c.duration_s - e.duration_s()).abs() < 1e-6;
        let c = match classes.iter().position(same) {
            Some(k) => &mut classes[k],
            None => {
                classes.push(SoakFaultClass {
                    fault: e.fault.clone(),
                    group: e.group,
                    duration_s: e.duration_s(),
                    peak_goal_n: peak_goal_n(e.group, e.duration_s()),
                    episodes: 0,
                    passing: 0,
                    worst_peak_force_n: 0.0,
                    worst_peak_at_s: e.start_s,
                    worst_rms_ratio: 0.0,
                    worst_rms_at_s: e.start_s,
                });
                classes.last_mut().expect("just pushed")
            }
        };
        c.episodes += 1;
        c.passing += u64::from(pass);
        if peak > c.worst_peak_force_n || !peak.is_finite() {
            c.worst_peak_force_n = peak;
            c.worst_peak_at_s = peak_at;
        }
        if ratio > c.worst_rms_ratio || !ratio.is_finite() {
            c.worst_rms_ratio = ratio;
            c.worst_rms_at_s = e.start_s;
        }
    }
    classes
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sim::FaultKind;
    use alloc::vec;

    fn ev(kind: FaultKind, channel: Channel, start_s: f64, duration_s: f64) -> FaultEvent {
        FaultEvent {
            kind,
            channel,
            start_s,
            duration_s,
            magnitude: 0.0,
        }
    }

    #[test]
    fn a_group_of_channels_is_the_smallest_group_holding_them() {
        assert_eq!(ChannelGroup::of([Channel::Q1]), ChannelGroup::Angles);
        assert_eq!(
            ChannelGroup::of([Channel::Qd1, Channel::Qd2]),
            ChannelGroup::Velocities
        );
        assert_eq!(ChannelGroup::of([Channel::F2]), ChannelGroup::Forces);
        assert_eq!(
            ChannelGroup::of([Channel::Q1, Channel::F1]),
            ChannelGroup::All
        );
        assert_eq!(
            ChannelGroup::of([Channel::Qd2, Channel::Q2]),
            ChannelGroup::Joint2
        );
        assert_eq!(ChannelGroup::of([Channel::Qd1]), ChannelGroup::Velocities);
        assert_eq!(
            ChannelGroup::of([Channel::Q1, Channel::Qd2]),
            ChannelGroup::All
        );
        assert_eq!(ChannelGroup::of([]), ChannelGroup::All);
        for (g, name) in ChannelGroup::EVERY.into_iter().zip(ChannelGroup::NAMES) {
            assert_eq!(ChannelGroup::of(g.channels().iter().copied()), g);
            assert_eq!(g.name(), name);
            assert_eq!(ChannelGroup::parse(name), Some(g));
        }
    }

    #[test]
    fn overlapping_events_form_one_episode_judged_until_the_next() {
        let evs = vec![
            ev(FaultKind::Stuck, Channel::Q2, 10.0, 0.2),
            ev(FaultKind::Stuck, Channel::Q1, 10.0, 0.2),
            ev(FaultKind::Nan, Channel::F1, 10.1, 0.3),
            ev(FaultKind::Dropout, Channel::Qd1, 12.0, 0.1),
            ev(FaultKind::Spike, Channel::F2, 30.0, 0.0),
            ev(FaultKind::Spike, Channel::F2, 1.0, 0.05),
        ];
        let e = episodes(&evs);
        assert_eq!(e.len(), 3, "{e:?}");
        assert_eq!(e[0].fault, "spike f2");
        assert_eq!(e[0].group, ChannelGroup::Forces);
        assert_eq!(e[0].window_end_s, 1.0 + 0.05 + EPISODE_AFTER_S);
        assert_eq!(e[1].fault, "stuck q2, stuck q1, nan f1");
        assert_eq!(e[1].group, ChannelGroup::All);
        assert_eq!(e[1].start_s, 10.0);
        assert!((e[1].end_s - 10.4).abs() < 1e-12);
        assert_eq!(e[1].window_end_s, 12.0);
        assert_eq!(e[2].group, ChannelGroup::Velocities);
        assert!((e[2].duration_s() - 0.1).abs() < 1e-12);
    }

    #[test]
    fn the_goals_are_the_issues() {
        let g = ChannelGroup::Angles;
        assert!(meets_goals(g, 0.2, 12.0, 1.5, false, 0));
        assert!(!meets_goals(g, 0.2, 12.1, 1.0, false, 0));
        assert!(!meets_goals(g, 0.2, 5.0, 1.51, false, 0));
        assert!(!meets_goals(g, 0.06, 5.0, 1.0, true, 0));
        assert!(!meets_goals(g, 0.06, 5.0, 1.0, false, 1));
        assert!(meets_goals(ChannelGroup::All, 0.2, 35.0, 1.0, false, 0));
        // Longer faults: the 70-N peak only.
        assert!(meets_goals(g, 0.5, 69.0, 3.0, false, 0));
        assert!(!meets_goals(g, 0.5, 71.0, 1.0, false, 0));
        assert!(!meets_goals(g, 0.5, f64::NAN, 1.0, false, 0));
    }

    #[test]
    fn an_episode_over_its_goal_is_counted_in_its_class() {
        let evs = vec![
            ev(FaultKind::Dropout, Channel::Q1, 1.0, 0.1),
            ev(FaultKind::Dropout, Channel::Q1, 10.0, 0.1),
        ];
        let e = episodes(&evs);
        let mut faulted = EpisodeStats::new(&e);
        let mut reference = EpisodeStats::new(&e);
        for (i, peak) in [(0, 5.0), (1, 20.0)] {
            faulted.peak[i] = (peak, e[i].start_s + 0.5);
            faulted.sum_sq[i] = [4.0, 4.0];
            faulted.steps[i] = 1;
            reference.sum_sq[i] = [4.0, 1.0];
            reference.steps[i] = 1;
        }
        let c = soak_fault_classes(&e, &faulted, &reference, None);
        assert_eq!(c.len(), 1);
        assert_eq!((c[0].episodes, c[0].passing), (2, 0), "{c:?}");
        assert_eq!(c[0].worst_peak_force_n, 20.0);
        assert_eq!(c[0].worst_peak_at_s, 10.5);
        assert_eq!(c[0].worst_rms_ratio, 2.0);
        reference.sum_sq[0] = [4.0, 4.0];
        let c = soak_fault_classes(&e, &faulted, &reference, None);
        assert_eq!(c[0].passing, 1);
        // A latch fails every episode whose window ends after it.
        let c = soak_fault_classes(&e, &faulted, &reference, Some(2.0));
        assert_eq!(c[0].passing, 0);
        // Episodes a run did not reach are not judged.
        reference.steps[1] = 0;
        let c = soak_fault_classes(&e, &faulted, &reference, None);
        assert_eq!((c[0].episodes, c[0].passing), (1, 1));
    }
}
