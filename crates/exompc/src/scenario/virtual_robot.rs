//! The virtual robot: the simulated human + exoskeleton of `exompc simulate` behind the robot
//! side of the protocol, with the lifecycle of [`Lifecycle`], its own torque and torque-rate
//! limits, the ride-through of brief command gaps and the protective stop. Time advances one
//! period per [`VirtualRobot::advance`]; the caller paces it in real time. It lives here, where
//! the simulator and the runtime meet, so that the runtime's robot boundary does not import the
//! simulator.

use crate::control::{StepStatus, TorqueLimits};
use crate::model::JointState;
use crate::runtime::frame::{
    command_flags, robot_flags, FrameError, RobotCommand, RobotSample, PLAN_LEN,
};
use crate::runtime::Lifecycle;
use crate::sim::{Plant, Sensors, StepRecord, Trajectory};
use nalgebra::SVector;
use serde::Serialize;

/// Counters of a [`VirtualRobot`].
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
pub struct RobotStats {
    /// Periods simulated.
    pub periods: u64,
    /// Periods whose torque target was the command answering that period's sample.
    pub commanded: u64,
    /// Periods of an active session without a fresh command, riding through the gap on the
    /// last command's plan (at most the ride-through's periods in a row).
    pub held: u64,
    /// Periods with a zero torque target (inactive, protective stop, or before the first
    /// session); the applied torque ramps to zero at the rate limit.
    pub idle_periods: u64,
    /// Gaps in the commands of an active session (intervals ridden through, or ending in a
    /// protective stop).
    pub watchdog_trips: u64,
    /// Applied torques that violated a torque limit relative to the previous applied torque
    /// (the robot clamps every target to both limits: must stay 0).
    pub limit_violations: u64,
    /// Periods whose target (a command or a plan entry) the robot changed to meet its torque
    /// or torque-rate limit.
    pub clamped: u64,
    /// Protective stops made.
    pub protective_stops: u64,
    /// Sessions activated.
    pub sessions: u64,
    /// Restarts after a protective stop.
    pub restarts: u64,
    /// Gap or stop events not logged because the log was full (still counted above).
    pub events_dropped: u64,
}

/// Capacity of the gap and stop event logs.
const MAX_EVENTS: usize = 4096;

/// A gap in the commands of an active session (robot time, s).
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct WatchdogEvent {
    /// Time of the first period without a command.
    pub tripped_at: f64,
    /// Time of the last valid command before the gap (`None`: none yet in this session).
    pub last_command_at: Option<f64>,
    /// Time commands resumed (`None`: not yet, or the gap ended in a protective stop).
    pub resumed_at: Option<f64>,
}

/// Why the robot made a protective stop.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum StopCause {
    /// No valid command for longer than the ride-through.
    LostController,
    /// The controller asked for a stop (flag `STOP`).
    StopRequested,
    /// A fault the robot detected (a non-finite state or sensor value, a failed actuator).
    Fault,
    /// The operator at the robot (e.g. a signal or the stop of the robot process).
    Operator,
}

/// A protective stop (robot time, s).
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct StopEvent {
    /// Why.
    pub cause: StopCause,
    /// Time the stop began (the torque target became zero).
    pub at: f64,
    /// Time of the last valid command before it (`None`: none in the session).
    pub last_command_at: Option<f64>,
    /// Time the applied torque reached zero (`None`: not yet).
    pub zero_at: Option<f64>,
}

/// One simulated period, for the robot's trace and metrics.
#[derive(Clone, Copy, Debug)]
pub struct RobotStep<const N: usize> {
    /// Period index.
    pub k: u64,
    /// Time `t_k` (s).
    pub t: f64,
    /// Robot state at `t_k`.
    pub robot: JointState<f64, N>,
    /// Human state at `t_k`.
    pub human: JointState<f64, N>,
    /// Desired angles at `t_k`.
    pub desired: SVector<f64, N>,
    /// Torque applied over the period.
    pub torque: SVector<f64, N>,
    /// Torque applied over the previous period.
    pub torque_prev: SVector<f64, N>,
    /// Human torque at `t_k`.
    pub torque_human: SVector<f64, N>,
    /// True strap forces at `t_k`.
    pub force_true: SVector<f64, N>,
    /// Raw (noisy, fault-injected) strap forces sent.
    pub force_raw: SVector<f64, N>,
    /// The command applied (`None`: ride-through, inactive or stopped).
    pub command: Option<RobotCommand<N>>,
    /// No fresh command this period in an active session (riding through the gap).
    pub watchdog: bool,
    /// The lifecycle state over the period.
    pub state: Lifecycle,
    /// The applied torque met both limits relative to the previous one (always, since the
    /// robot clamps its targets).
    pub within_limits: bool,
}

impl<const N: usize> RobotStep<N> {
    /// The period as the one per-step record of simulation and runtime (trace, metrics): the
    /// true states and forces, `force_measured` = the raw forces sent, the command's
    /// iterations and compute time; `status` is the last command's outcome (the caller keeps
    /// it across periods without a command), `disturbances` the controller's estimates if
    /// known (none travel on the link).
    pub fn record<'a>(
        &self,
        status: StepStatus,
        disturbances: Option<&'a [SVector<f64, N>]>,
    ) -> StepRecord<'a, N> {
        StepRecord {
            k: self.k as usize,
            t: self.t,
            robot: self.robot,
            human: self.human,
            desired: self.desired,
            torque_robot: self.torque,
            torque_prev: self.torque_prev,
            torque_human: self.torque_human,
            force_true: self.force_true,
            force_measured: self.force_raw,
            probabilities: None,
            disturbances,
            status,
            iterations: self.command.map_or(0, |c| c.iterations),
            step_time_us: self.command.map_or(0.0, |c| f64::from(c.compute_ns) * 1e-3),
            within_limits: self.within_limits,
        }
    }
}

/// The virtual robot: the simulated human + exoskeleton of `exompc simulate` (the same
/// [`Plant`] and [`Sensors`]) behind the robot side of the protocol.
///
/// It protects itself whatever arrives: every applied torque meets the torque limit and the
/// torque-rate limit relative to the previous applied torque (it ramps towards any target).
/// It starts [`Lifecycle::Inactive`] (zero torque) and becomes active only through
/// [`VirtualRobot::activate`] (an authenticated session). In an active session, a period
/// without a fresh command plays out the last command's plan (then holds its last entry);
/// without a plan, the torque it applied one gait period earlier (the period of its own
/// encoder angles, found when the gap began: [`VirtualRobot::MATCH_WINDOW_S`]), and before a
/// gait period is known the applied torque extrapolated along its slope when the gap began,
/// fading with [`VirtualRobot::TREND_TAU_S`]. This goes on
/// for at most `ride_through` periods; one more is a lost controller: protective stop
/// ([`Lifecycle::Error`]: torque ramped to zero at the rate limit and held there) until
/// [`VirtualRobot::restart`]. Issue 28: holding the last torque instead pushed the strap to
/// 15-35 N within a 200-ms outage (docs/REALTIME.md, the outage grid).
pub struct VirtualRobot<const N: usize, Tr: Trajectory<N>> {
    plant: Plant<N, Tr>,
    sensors: Sensors<N>,
    limits: TorqueLimits,
    ride_through: u64,
    dt: f64,
    k: u64,
    k0: u64,
    state: Lifecycle,
    current: Option<RobotCommand<N>>,
    plan: [SVector<f64, N>; PLAN_LEN],
    plan_len: usize,
    last_target: SVector<f64, N>,
    last_valid_k: Option<u64>,
    applied: SVector<f64, N>,
    gap: bool,
    event_open: bool,
    stop_requested: bool,
    ended: bool,
    end_samples: u32,
    /// This period's true and measured strap forces and measured angles, once sampled.
    sampled: Option<(SVector<f64, N>, SVector<f64, N>, SVector<f64, N>)>,
    /// Encoder angles and applied torques of the last [`VirtualRobot::HISTORY_S`] per period
    /// (rings, allocated once), for the replay during a gap.
    q_hist: Vec<SVector<f64, N>>,
    hist: Vec<SVector<f64, N>>,
    hist_pos: usize,
    hist_filled: usize,
    /// The gait period (periods) found when the current gap began (`None`: none found).
    gap_period: Option<usize>,
    /// The applied torque and its slope per period when the current gap began (`None`:
    /// not enough history).
    gap_trend: Option<(SVector<f64, N>, SVector<f64, N>)>,
    stats: RobotStats,
    events: Vec<WatchdogEvent>,
    stops: Vec<StopEvent>,
}

impl<const N: usize, Tr: Trajectory<N>> VirtualRobot<N, Tr> {
    /// Encoder angles and applied torques kept for the replay during a gap (s): one gait
    /// period of a gait down to 0.4 Hz, plus the matched window.
    pub const HISTORY_S: f64 = 2.5;
    /// Shortest gait period the replay looks for (s).
    pub const MIN_GAIT_PERIOD_S: f64 = 0.4;
    /// Window of the most recent encoder angles matched against one period earlier (s).
    pub const MATCH_WINDOW_S: f64 = 0.3;
    /// Largest mean squared mismatch of that window, as a share of the angles' variance over
    /// the history, for a period to count as found.
    pub const MATCH_TOLERANCE: f64 = 0.05;

    /// Periods over which the slope of the applied torque is taken for the extrapolation
    /// before a gait period is known.
    pub const TREND_PERIODS: usize = 5;
    /// Time constant (s) of the fading of that slope during a gap.
    pub const TREND_TAU_S: f64 = 0.1;

    fn history_len(dt: f64) -> usize {
        ((Self::HISTORY_S / dt.max(1e-6)).ceil() as usize).clamp(8, 1 << 16)
    }

    /// A robot over `plant` and `sensors` (noise and sensor faults), period `dt` (s), torque
    /// `limits` enforced on what it applies, riding through at most `ride_through` periods
    /// (≥ 1) without a valid command before a protective stop. It starts inactive.
    pub fn new(
        plant: Plant<N, Tr>,
        sensors: Sensors<N>,
        limits: TorqueLimits,
        dt: f64,
        ride_through: u64,
    ) -> Self {
        VirtualRobot {
            plant,
            sensors,
            limits,
            ride_through: ride_through.max(1),
            dt,
            k: 0,
            k0: 0,
            state: Lifecycle::Inactive,
            current: None,
            plan: [SVector::zeros(); PLAN_LEN],
            plan_len: 0,
            last_target: SVector::zeros(),
            last_valid_k: None,
            applied: SVector::zeros(),
            gap: false,
            event_open: false,
            stop_requested: false,
            ended: false,
            end_samples: 0,
            sampled: None,
            q_hist: vec![SVector::zeros(); Self::history_len(dt)],
            hist: vec![SVector::zeros(); Self::history_len(dt)],
            gap_period: None,
            gap_trend: None,
            hist_pos: 0,
            hist_filled: 0,
            stats: RobotStats::default(),
            events: Vec::with_capacity(MAX_EVENTS),
            stops: Vec::with_capacity(64),
        }
    }

    /// The plant.
    pub fn plant(&self) -> &Plant<N, Tr> {
        &self.plant
    }

    /// Current period index.
    pub fn k(&self) -> u64 {
        self.k
    }

    /// Counters.
    pub fn stats(&self) -> &RobotStats {
        &self.stats
    }

    /// Gaps in the commands.
    pub fn watchdog_events(&self) -> &[WatchdogEvent] {
        &self.events
    }

    /// Protective stops.
    pub fn stop_events(&self) -> &[StopEvent] {
        &self.stops
    }

    /// The lifecycle state.
    pub fn state(&self) -> Lifecycle {
        self.state
    }

    /// The torque applied over the last period.
    pub fn applied(&self) -> SVector<f64, N> {
        self.applied
    }

    /// True while a gap in the commands is being ridden through.
    pub fn watchdog_active(&self) -> bool {
        self.gap
    }

    /// True once the controller asked for a stop (flag `STOP`) in any session.
    pub fn stop_requested(&self) -> bool {
        self.stop_requested
    }

    /// True once a command answering the current sample was accepted.
    pub fn has_current(&self) -> bool {
        self.current.is_some()
    }

    /// Whether a new session may be activated (inactive).
    pub fn accepts_session(&self) -> bool {
        self.state == Lifecycle::Inactive
    }

    /// Activate a session (inactive → active): the samples are numbered from 1 again and the
    /// ride-through counts from now. Returns `false` (and changes nothing) unless inactive.
    pub fn activate(&mut self) -> bool {
        if self.state != Lifecycle::Inactive {
            return false;
        }
        self.state = Lifecycle::Active;
        self.k0 = self.k;
        self.last_valid_k = Some(self.k);
        self.plan_len = 0;
        self.last_target = self.applied;
        self.current = None;
        self.stats.sessions += 1;
        true
    }

    /// Protective stop (any state → error): the torque ramps to zero at the rate limit and
    /// stays there until [`VirtualRobot::restart`]. A second stop keeps the first's cause.
    pub fn protective_stop(&mut self, cause: StopCause) {
        if self.state == Lifecycle::Error {
            return;
        }
        let was_active = self.state == Lifecycle::Active;
        self.state = Lifecycle::Error;
        self.current = None;
        self.close_gap(None);
        if !was_active && self.applied.iter().all(|v| *v == 0.0) {
            // Nothing to ramp: still a stop (no session accepted until a restart).
            self.stats.protective_stops += 1;
            self.log_stop(cause, Some(self.time()));
            return;
        }
        self.stats.protective_stops += 1;
        self.log_stop(cause, None);
    }

    fn log_stop(&mut self, cause: StopCause, zero_at: Option<f64>) {
        if self.stops.len() < self.stops.capacity() {
            self.stops.push(StopEvent {
                cause,
                at: self.time(),
                last_command_at: self.last_valid_k.map(|j| j as f64 * self.dt),
                zero_at,
            });
        } else {
            self.stats.events_dropped += 1;
        }
    }

    /// Restart after a protective stop (error → inactive): a new session may be activated
    /// through a fresh handshake. Returns `false` unless in error.
    pub fn restart(&mut self) -> bool {
        if self.state != Lifecycle::Error {
            return false;
        }
        self.state = Lifecycle::Inactive;
        self.last_valid_k = None;
        self.plan_len = 0;
        self.stats.restarts += 1;
        true
    }

    /// Mark the run as ended: later samples carry [`robot_flags::END_OF_RUN`].
    pub fn end(&mut self) {
        self.ended = true;
    }

    fn time(&self) -> f64 {
        self.k as f64 * self.dt
    }

    /// Sequence number of this period's sample in the current session (from 1).
    fn seq(&self) -> u32 {
        (self.k.wrapping_sub(self.k0) as u32)
            .wrapping_add(1)
            .wrapping_add(self.end_samples)
    }

    /// The state sample of `t_k` (sensors read once per period: call once before
    /// [`VirtualRobot::advance`]).
    pub fn sample(&mut self) -> RobotSample<N> {
        let t = self.plant.time();
        let s = *self.plant.state();
        let force_true = self.plant.strap_force();
        let (raw, _) = self.sensors.read(t, &s.robot.q, &s.robot.qd, &force_true);
        self.sampled = Some((force_true, raw.force, raw.q));
        let seq = self.seq();
        let mut flags = 0;
        if self.gap {
            flags |= robot_flags::WATCHDOG;
        }
        if self.state == Lifecycle::Error {
            flags |= robot_flags::PROTECTIVE_STOP;
        }
        if self.ended {
            flags |= robot_flags::END_OF_RUN;
            // Repeated end-of-run samples (against loss) get their own sequence numbers.
            self.end_samples = self.end_samples.wrapping_add(1);
        }
        if !raw.is_finite() {
            flags |= robot_flags::SENSOR_FAULT;
        }
        RobotSample {
            seq,
            stamp_ns: (t * 1e9).round() as u64,
            flags,
            q: raw.q,
            qd: raw.qd,
            force: raw.force,
            effort: self.applied,
        }
    }

    /// Offer an authenticated command of the session (sequence numbers are checked by the
    /// link). Refused unless active ([`FrameError::NotAllowed`]); a STOP makes a protective
    /// stop; a command answering an earlier sample is stale, one answering a later sample
    /// malformed. Returns whether it answers the current sample.
    pub fn command(&mut self, c: &RobotCommand<N>) -> Result<bool, FrameError> {
        if self.state != Lifecycle::Active {
            return Err(FrameError::NotAllowed);
        }
        if c.flags & command_flags::STOP != 0 {
            self.stop_requested = true;
            self.protective_stop(StopCause::StopRequested);
            return Ok(false);
        }
        if c.flags & command_flags::HELLO != 0 {
            return Ok(false);
        }
        let ahead = c.answers.wrapping_sub(self.seq()) as i32;
        if ahead < 0 {
            return Err(FrameError::Stale);
        }
        if ahead > 0 {
            return Err(FrameError::Malformed);
        }
        self.current = Some(*c);
        Ok(true)
    }

    /// The gait period (in periods) of the robot's own encoder angles: the shortest lag, from
    /// [`VirtualRobot::MIN_GAIT_PERIOD_S`] to what the history holds, at which the mean
    /// squared difference (over the joints) between the last [`VirtualRobot::MATCH_WINDOW_S`]
    /// of angles and the angles one lag earlier has a local minimum within
    /// [`VirtualRobot::MATCH_TOLERANCE`] of the variance of the angles over the history.
    /// `None` before a period of history, for a leg at rest or a non-finite angle in the
    /// compared samples.
    fn gait_period(&self) -> Option<usize> {
        let len = self.q_hist.len();
        let w = ((Self::MATCH_WINDOW_S / self.dt).round() as usize).clamp(2, len / 2);
        let p_min = ((Self::MIN_GAIT_PERIOD_S / self.dt).round() as usize).max(2);
        // `back` periods before the coming one (1: the last recorded).
        let at = |back: usize| &self.q_hist[(self.hist_pos + len - back % len) % len];
        let n = self.hist_filled;
        let p_max = n.checked_sub(w)?;
        let mean = (1..=n).map(at).sum::<SVector<f64, N>>() / n as f64;
        let var = (1..=n).map(|i| (at(i) - mean).norm_squared()).sum::<f64>() / n as f64;
        if var.is_nan() || var <= 1e-6 {
            return None;
        }
        // At most 64 samples of the window per lag (keeps the search cheap at a fine `dt`).
        let stride = w.div_ceil(64);
        let err = |p: usize| {
            let (sum, count) = (1..=w).step_by(stride).fold((0.0, 0usize), |(s, c), i| {
                (s + (at(i) - at(i + p)).norm_squared(), c + 1)
            });
            sum / count as f64
        };
        let tol = Self::MATCH_TOLERANCE * var;
        let (mut before, mut here) = (f64::INFINITY, err(p_min));
        for p in p_min..=p_max {
            let after = if p < p_max { err(p + 1) } else { f64::INFINITY };
            if here <= tol && here <= before && here <= after {
                return Some(p);
            }
            (before, here) = (here, after);
        }
        None
    }

    /// The applied torque and its mean slope per period over the last
    /// [`VirtualRobot::TREND_PERIODS`] periods, for the extrapolation during a gap; `None`
    /// with less history.
    fn torque_trend(&self) -> Option<(SVector<f64, N>, SVector<f64, N>)> {
        let len = self.hist.len();
        let n = Self::TREND_PERIODS;
        if self.hist_filled <= n {
            return None;
        }
        let at = |back: usize| self.hist[(self.hist_pos + len - back) % len];
        Some((at(1), (at(1) - at(1 + n)) / n as f64))
    }

    /// Periods of slope the extrapolation adds after `j` periods of a gap:
    /// `τ (1 − e^(−j/τ))`, `τ` = [`VirtualRobot::TREND_TAU_S`] in periods (the slope fades, so
    /// a gap of any length adds at most `τ` periods of it).
    fn extrapolation_gain(j: u64, dt: f64) -> f64 {
        let tau = Self::TREND_TAU_S / dt.max(1e-6);
        tau * (1.0 - (-(j as f64) / tau).exp())
    }

    /// The torque applied one gait period before the coming period (the period found when
    /// the gap began, [`VirtualRobot::gait_period`]); `None` without one.
    fn replay(&self) -> Option<SVector<f64, N>> {
        let p = self.gap_period?;
        let len = self.hist.len();
        (p < self.hist_filled).then(|| self.hist[(self.hist_pos + len - p) % len])
    }

    fn close_gap(&mut self, resumed: Option<f64>) {
        if self.gap && self.event_open {
            if let Some(e) = self.events.last_mut() {
                e.resumed_at = resumed;
            }
        }
        self.gap = false;
        self.event_open = false;
    }

    /// Apply the torque over the period and advance the plant to `t_{k+1}`. The target: the
    /// command answering this period's sample; else, in an active session within the
    /// ride-through, the last command's plan entry for this period (its last entry once used
    /// up); without a plan the torque applied one gait period earlier, or without a known
    /// period the extrapolated torque (see [`VirtualRobot`]); else zero (a gap longer than the
    /// ride-through makes a protective stop first). The applied torque is the target clamped
    /// to the torque limit and to the rate limit from the previous applied torque.
    pub fn advance(&mut self) -> RobotStep<N> {
        let t = self.plant.time();
        let s = *self.plant.state();
        let (force_true, force_raw, q_meas) = self.sampled.take().unwrap_or_else(|| {
            let f = self.plant.strap_force();
            (f, f, s.robot.q)
        });
        if self.state == Lifecycle::Active
            && !(s.robot.q.iter().chain(s.robot.qd.iter())).all(|v| v.is_finite())
        {
            self.protective_stop(StopCause::Fault);
        }
        let prev = self.applied;
        let command = if self.state == Lifecycle::Active {
            self.current.take()
        } else {
            None
        };
        let mut gap_now = false;
        let target = if let Some(c) = command {
            self.close_gap(Some(t));
            self.last_valid_k = Some(self.k);
            self.plan_len = usize::from(c.plan_len).min(PLAN_LEN);
            self.plan = c.plan;
            self.last_target = c.torque;
            self.stats.commanded += 1;
            c.torque
        } else if self.state == Lifecycle::Active {
            let j = self.k - self.last_valid_k.unwrap_or(self.k0);
            if j > self.ride_through {
                self.protective_stop(StopCause::LostController);
                SVector::zeros()
            } else {
                gap_now = true;
                if !self.gap {
                    self.gap = true;
                    self.gap_period = self.gait_period();
                    self.gap_trend = self.torque_trend();
                    self.stats.watchdog_trips += 1;
                    self.event_open = self.events.len() < MAX_EVENTS;
                    if self.event_open {
                        self.events.push(WatchdogEvent {
                            tripped_at: t,
                            last_command_at: self.last_valid_k.map(|j| j as f64 * self.dt),
                            resumed_at: None,
                        });
                    } else {
                        self.stats.events_dropped += 1;
                    }
                }
                self.stats.held += 1;
                let i = (j as usize).saturating_sub(1);
                if self.plan_len > 0 {
                    // A plan (the controller's, or the rest of a ramp to zero before a stop).
                    self.plan[i.min(self.plan_len - 1)]
                } else if let Some(r) = self.replay() {
                    r
                } else if let Some((base, slope)) = self.gap_trend {
                    base + slope * Self::extrapolation_gain(j, self.dt)
                } else {
                    self.last_target
                }
            }
        } else {
            SVector::zeros()
        };
        if self.state != Lifecycle::Active {
            self.stats.idle_periods += 1;
        }
        // The robot's own limits, whatever arrived (non-finite targets count as zero).
        let torque = self.limits.clamp(&prev, &self.limits.admissible(&target));
        if torque != target && (command.is_some() || gap_now) {
            self.stats.clamped += 1;
        }
        let within = self.limits.admits(&prev, &torque);
        if !within {
            self.stats.limit_violations += 1;
        }
        if self.state == Lifecycle::Error && torque.iter().all(|v| *v == 0.0) {
            if let Some(e) = self.stops.last_mut() {
                if e.zero_at.is_none() {
                    e.zero_at = Some(t + self.dt);
                }
            }
        }
        let step = RobotStep {
            k: self.k,
            t,
            robot: s.robot,
            human: s.human,
            desired: self.plant.trajectory().eval(t).0,
            torque,
            torque_prev: prev,
            torque_human: self.plant.human_torque(),
            force_true,
            force_raw,
            command,
            watchdog: gap_now,
            state: self.state,
            within_limits: within,
        };
        self.applied = torque;
        let len = self.hist.len();
        self.hist[self.hist_pos] = torque;
        self.q_hist[self.hist_pos] = q_meas;
        self.hist_pos = (self.hist_pos + 1) % len;
        self.hist_filled = (self.hist_filled + 1).min(len);
        self.plant.step(&torque);
        self.stats.periods += 1;
        self.k += 1;
        step
    }
}
