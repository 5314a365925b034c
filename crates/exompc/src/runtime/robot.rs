//! The virtual robot: the simulated human + exoskeleton of `exompc simulate` behind the robot
//! side of the protocol, with a command watchdog. Time advances one period per
//! [`VirtualRobot::advance`]; the caller paces it in real time.

use super::frame::{command_flags, robot_flags, FrameError, RobotCommand, RobotSample, SeqTracker};
use crate::control::TorqueLimits;
use crate::model::JointState;
use crate::sim::{Plant, Sensors, Trajectory};
use nalgebra::SVector;
use serde::Serialize;

/// Counters of a [`VirtualRobot`].
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
pub struct RobotStats {
    /// Periods simulated.
    pub periods: u64,
    /// Periods whose torque was the command answering that period's sample.
    pub commanded: u64,
    /// Periods without a fresh command that held the last one (fewer than the watchdog's
    /// periods since it).
    pub held: u64,
    /// Periods with zero torque by the watchdog.
    pub watchdog_periods: u64,
    /// Times the watchdog fired.
    pub watchdog_trips: u64,
    /// Applied commands that violated a torque limit relative to the previous applied torque
    /// (the watchdog's zero and the first command excluded).
    pub limit_violations: u64,
    /// Commands whose torque exceeded `±T_max` and were saturated.
    pub saturated: u64,
    /// Watchdog intervals not logged because the event log was full (counted in
    /// `watchdog_trips`).
    pub events_dropped: u64,
}

/// Capacity of the watchdog event log.
const MAX_EVENTS: usize = 4096;

/// A watchdog interval (robot time, s).
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct WatchdogEvent {
    /// Time the torque was zeroed.
    pub tripped_at: f64,
    /// Time of the last valid command before the trip (`None`: none yet).
    pub last_command_at: Option<f64>,
    /// Time commands resumed (`None`: not yet).
    pub resumed_at: Option<f64>,
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
    /// The command applied (`None`: held or watchdog).
    pub command: Option<RobotCommand<N>>,
    /// The watchdog zeroed the torque this period.
    pub watchdog: bool,
    /// The applied torque met both limits (watchdog zero and first command count as met).
    pub within_limits: bool,
}

/// The virtual robot: the simulated human + exoskeleton of `exompc simulate` (the same
/// [`Plant`] and [`Sensors`]) behind the robot side of the protocol, with a command watchdog
/// (no valid command for two periods → zero torque and a flag, resumes when commands return).
/// Time advances one period per [`VirtualRobot::advance`]; the caller paces it in real time.
pub struct VirtualRobot<const N: usize, Tr: Trajectory<N>> {
    plant: Plant<N, Tr>,
    sensors: Sensors<N>,
    limits: TorqueLimits,
    watchdog_periods: u64,
    dt: f64,
    k: u64,
    cmd_seq: SeqTracker,
    current: Option<RobotCommand<N>>,
    held: Option<RobotCommand<N>>,
    last_valid_k: Option<u64>,
    applied: SVector<f64, N>,
    any_applied: bool,
    watchdog: bool,
    event_open: bool,
    stop: bool,
    ended: bool,
    end_samples: u32,
    sampled: Option<(SVector<f64, N>, SVector<f64, N>)>,
    stats: RobotStats,
    events: Vec<WatchdogEvent>,
}

impl<const N: usize, Tr: Trajectory<N>> VirtualRobot<N, Tr> {
    /// A robot over `plant` and `sensors` (noise and sensor faults), period `dt` (s), torque
    /// `limits` checked on what it applies, zero torque after `watchdog_periods` periods
    /// without a valid command.
    pub fn new(
        plant: Plant<N, Tr>,
        sensors: Sensors<N>,
        limits: TorqueLimits,
        dt: f64,
        watchdog_periods: u64,
    ) -> Self {
        VirtualRobot {
            plant,
            sensors,
            limits,
            watchdog_periods: watchdog_periods.max(1),
            dt,
            k: 0,
            cmd_seq: SeqTracker::default(),
            current: None,
            held: None,
            last_valid_k: None,
            applied: SVector::zeros(),
            any_applied: false,
            watchdog: false,
            event_open: false,
            stop: false,
            ended: false,
            end_samples: 0,
            sampled: None,
            stats: RobotStats::default(),
            events: Vec::with_capacity(MAX_EVENTS),
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

    /// Watchdog intervals.
    pub fn watchdog_events(&self) -> &[WatchdogEvent] {
        &self.events
    }

    /// True while the watchdog holds the torque at zero.
    pub fn watchdog_active(&self) -> bool {
        self.watchdog
    }

    /// True once a STOP command was received.
    pub fn stop_requested(&self) -> bool {
        self.stop
    }

    /// True once a command answering the current sample was accepted.
    pub fn has_current(&self) -> bool {
        self.current.is_some()
    }

    /// Mark the run as ended: later samples carry [`robot_flags::END_OF_RUN`].
    pub fn end(&mut self) {
        self.ended = true;
    }

    /// The state sample of `t_k` (sensors read once per period: call once before
    /// [`VirtualRobot::advance`]).
    pub fn sample(&mut self) -> RobotSample<N> {
        let t = self.plant.time();
        let s = *self.plant.state();
        let force_true = self.plant.strap_force();
        let (raw, _) = self.sensors.read(t, &s.robot.q, &s.robot.qd, &force_true);
        self.sampled = Some((force_true, raw.force));
        let seq = (self.k as u32).wrapping_add(self.end_samples);
        let mut flags = 0;
        if self.watchdog {
            flags |= robot_flags::WATCHDOG;
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

    /// Offer a decoded command. Accepted when newer than the last command and answering the
    /// current sample; a HELLO is accepted and ignored, a STOP sets
    /// [`VirtualRobot::stop_requested`]. Returns whether it answers the current sample.
    pub fn command(&mut self, c: &RobotCommand<N>) -> Result<bool, FrameError> {
        self.cmd_seq.accept(c.seq)?;
        if c.flags & command_flags::STOP != 0 {
            self.stop = true;
            return Ok(false);
        }
        if c.flags & command_flags::HELLO != 0 {
            return Ok(false);
        }
        let ahead = c.answers.wrapping_sub(self.k as u32) as i32;
        if ahead < 0 {
            return Err(FrameError::Stale);
        }
        if ahead > 0 {
            return Err(FrameError::Malformed);
        }
        self.current = Some(*c);
        Ok(true)
    }

    /// Apply the torque over the period and advance the plant to `t_{k+1}`: the command
    /// answering this period's sample; else the last command held while fewer than the
    /// watchdog's periods passed since it; else zero torque (watchdog).
    pub fn advance(&mut self) -> RobotStep<N> {
        let t = self.plant.time();
        let s = *self.plant.state();
        let (force_true, force_raw) = self.sampled.take().unwrap_or_else(|| {
            let f = self.plant.strap_force();
            (f, f)
        });
        let prev = self.applied;
        let mut within = true;
        let mut watchdog_now = false;
        let command = self.current.take();
        let torque = if let Some(c) = command {
            if self.watchdog {
                self.watchdog = false;
                if self.event_open {
                    if let Some(e) = self.events.last_mut() {
                        e.resumed_at = Some(t);
                    }
                }
                self.event_open = false;
            }
            self.last_valid_k = Some(self.k);
            self.held = Some(c);
            self.stats.commanded += 1;
            let sat = self.limits.admissible(&c.torque);
            if sat != c.torque {
                self.stats.saturated += 1;
            }
            if self.any_applied && !self.limits.admits(&prev, &c.torque) {
                within = false;
                self.stats.limit_violations += 1;
            }
            self.any_applied = true;
            sat
        } else if let (Some(j), Some(h)) = (self.last_valid_k, self.held) {
            if self.k - j < self.watchdog_periods && !self.watchdog {
                self.stats.held += 1;
                self.limits.admissible(&h.torque)
            } else {
                watchdog_now = true;
                SVector::zeros()
            }
        } else {
            watchdog_now = true;
            SVector::zeros()
        };
        if watchdog_now {
            self.stats.watchdog_periods += 1;
            if !self.watchdog {
                self.watchdog = true;
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
            watchdog: watchdog_now,
            within_limits: within,
        };
        self.applied = torque;
        self.plant.step(&torque);
        self.stats.periods += 1;
        self.k += 1;
        step
    }
}
