//! The controller side of the real-time loop, one period per call, on absolute deadlines.

use super::frame::{command_flags, robot_flags, status_code, RobotCommand, RobotSample, PLAN_LEN};
use super::timing::{Clock, TimingStats};
use super::{Lifecycle, RobotInterface};
use crate::control::{ControlOutput, Controller, Measurement, StepStatus, TorqueLimits};
use crate::estimate::MovingAverage;
use nalgebra::SVector;
use serde::Serialize;
use std::time::Duration;

/// Timing and filtering of a [`ControlLoop`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LoopSettings {
    /// Control period (the scenario's `timing.dt`).
    pub dt: Duration,
    /// The loop wakes this long before a sample is expected (phase of the deadlines against
    /// the robot's sending instants).
    pub lead: Duration,
    /// Wait for a sample at most this long after the wake-up; `None` after it is a missing
    /// sample (the supervisor holds the torque and its sensor-timeout monitor counts).
    pub sample_timeout: Duration,
    /// Moving-average window of velocities and forces (the scenario's
    /// `uncertainty.filter_window`, MODEL.md §5).
    pub filter_window: usize,
    /// Torque limits, checked on every command independently of the controller.
    pub limits: TorqueLimits,
    /// Clock sync: the deadlines follow the robot's sample timestamps plus the smallest
    /// `arrival − timestamp` over this many recent samples (the robot's clock offset plus the
    /// fastest transit), so a late sample, a stall or a drifting robot clock never shifts the
    /// loop's phase against the robot's (≥ 1).
    pub sync_window: usize,
    /// A period without a sample does not step the controller (the robot rides through on
    /// the last command's plan, and the controller resumes from the applied torque with the
    /// next sample); `false`: step it on the empty (NaN) measurement, so that the
    /// supervisor's sensor-timeout monitor sees the gap.
    pub skip_missing: bool,
    /// Send the controller's planned torques ([`Controller::planned_torques`]) with each
    /// command, for the robot to play out during a gap; `false` (the default): no plan, the
    /// robot holds the last commanded torque. Measured on 2026-12-03 (test
    /// `link_outages_are_ridden_through`, outages at 1 s into a 2-kg run, MS-NMPC with
    /// `Np = 3`): the plan gave peaks of 15.8 / 23.3 / 72.3 N for 60 / 120 / 200 ms, holding
    /// 6.2 / 6.7 / 19.8 N: the short horizon's later moves are not a forecast worth playing.
    pub send_plan: bool,
}

impl LoopSettings {
    /// Defaults for period `dt`: lead `dt/5`, sample timeout `dt/2`, sync window 100 samples,
    /// missing samples skipped, no plan sent.
    pub fn new(dt: Duration, filter_window: usize, limits: TorqueLimits) -> Self {
        LoopSettings {
            dt,
            lead: dt / 5,
            sample_timeout: dt / 2,
            filter_window,
            limits,
            sync_window: 100,
            skip_missing: true,
            send_plan: false,
        }
    }
}

/// Counters of a [`ControlLoop`].
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
pub struct LoopStats {
    /// Periods run.
    pub periods: u64,
    /// Periods with a fresh sample.
    pub samples: u64,
    /// Periods without a sample within the timeout (torque held by the supervisor).
    pub missing_samples: u64,
    /// Samples that arrived after their expected instant by more than a quarter period.
    pub late_samples: u64,
    /// Samples read from an earlier slot than the current period's (queued after a stall);
    /// the loop then waited for the current one.
    pub old_samples: u64,
    /// Samples whose applied torque differed from the last command (a command lost or a
    /// robot watchdog): the controller resumed from the applied torque.
    pub effort_resyncs: u64,
    /// Samples flagged by the robot as riding through a gap in the commands.
    pub robot_watchdog_samples: u64,
    /// Samples flagged by the robot's protective stop.
    pub robot_stop_samples: u64,
    /// Commands that carried a plan (the controller's torques for the next periods).
    pub planned_commands: u64,
    /// Samples flagged with a sensor fault.
    pub sensor_fault_samples: u64,
    /// Commands written.
    pub commands: u64,
    /// Commands that violated a torque limit (must stay 0).
    pub limit_violations: u64,
    /// Steps whose solve did not converge.
    pub solver_failures: u64,
    /// Steps with a rejected (non-finite or implausible) measurement, missing samples
    /// included.
    pub bad_measurements: u64,
    /// Steps on which a safety monitor set the torque.
    pub monitor_steps: u64,
}

/// Everything about one period, for logging.
#[derive(Clone, Copy, Debug)]
pub struct PeriodRecord<const N: usize> {
    /// Period index.
    pub k: u64,
    /// Wake-up time minus the deadline (µs).
    pub wake_error_us: f64,
    /// The sample used (`None`: none arrived in time).
    pub sample: Option<RobotSample<N>>,
    /// The filtered measurement given to the controller (NaN without a sample).
    pub measurement: Measurement<N>,
    /// The controller output (torque sent when a sample was answered).
    pub output: ControlOutput<N>,
    /// The previous torque `T_R(k−1)`.
    pub torque_prev: SVector<f64, N>,
    /// Controller step time (µs).
    pub compute_us: f64,
    /// Whether a command was written.
    pub sent: bool,
    /// Whether the output met both limits relative to the previous torque.
    pub within_limits: bool,
    /// The robot flagged the end of its run.
    pub robot_ended: bool,
    /// The robot flagged a protective stop (it applies no more commands of this session).
    pub robot_stopped: bool,
}

/// The controller process's loop: see the [module documentation](super).
pub struct ControlLoop<const N: usize, C> {
    ctrl: C,
    s: LoopSettings,
    vel: MovingAverage<N>,
    force: MovingAverage<N>,
    /// Deadline of the next period (clock time), once connected.
    next: Option<Duration>,
    pending: Option<RobotSample<N>>,
    k: u64,
    cmd_seq: u32,
    last_t: f64,
    started: bool,
    /// The timestamp of the last sample (ns): a later one more than 1.5 periods after it
    /// follows a gap in the data.
    last_stamp_ns: Option<u64>,
    stopping: bool,
    stats: LoopStats,
    timing: TimingStats,
    /// Recent `arrival − timestamp` (ns), a ring of `sync_window` entries.
    offsets: Vec<i64>,
    offsets_next: usize,
}

impl<const N: usize, C: Controller<N>> ControlLoop<N, C> {
    /// A loop around `ctrl` (normally a [`Supervisor`](crate::control::Supervisor));
    /// `capacity` periods of timing samples are preallocated.
    pub fn new(ctrl: C, settings: LoopSettings, capacity: usize) -> Self {
        ControlLoop {
            ctrl,
            vel: MovingAverage::new(settings.filter_window),
            force: MovingAverage::new(settings.filter_window),
            s: settings,
            next: None,
            pending: None,
            k: 0,
            cmd_seq: 0,
            last_t: 0.0,
            started: false,
            last_stamp_ns: None,
            stopping: false,
            stats: LoopStats::default(),
            timing: TimingStats::with_capacity(capacity),
            offsets: Vec::with_capacity(settings.sync_window.max(1)),
            offsets_next: 0,
        }
    }

    /// The controller.
    pub fn controller(&self) -> &C {
        &self.ctrl
    }

    /// Counters so far.
    pub fn stats(&self) -> &LoopStats {
        &self.stats
    }

    /// Timing so far.
    pub fn timing(&self) -> &TimingStats {
        &self.timing
    }

    /// The next period's deadline (clock time), once connected.
    pub fn next_deadline(&self) -> Option<Duration> {
        self.next
    }

    /// True once [`ControlLoop::request_stop`] was called.
    pub fn is_stopping(&self) -> bool {
        self.stopping
    }

    /// True when stopping and the torque has reached zero.
    pub fn ramp_done(&self) -> bool {
        self.stopping && self.ctrl.previous_torque().iter().all(|v| *v == 0.0)
    }

    /// From now on the torque ramps to zero at the rate limit (the controller is no longer
    /// stepped); see [`ControlLoop::ramp_done`] and [`ControlLoop::send_stop`].
    pub fn request_stop(&mut self) {
        self.stopping = true;
    }

    fn command(
        &mut self,
        clock: &dyn Clock,
        answers: u32,
        flags: u16,
        out: &ControlOutput<N>,
        compute_us: f64,
    ) -> RobotCommand<N> {
        self.cmd_seq = self.cmd_seq.wrapping_add(1);
        let mut plan = [SVector::zeros(); PLAN_LEN];
        let plan_len = if flags & command_flags::HELLO != 0 || flags & command_flags::STOP != 0 {
            0
        } else if self.stopping {
            // The rest of the ramp to zero.
            let mut t = out.torque;
            for p in plan.iter_mut() {
                t = self.s.limits.clamp(&t, &SVector::zeros());
                *p = t;
            }
            PLAN_LEN
        } else {
            if self.s.send_plan {
                self.ctrl.planned_torques(&mut plan).min(PLAN_LEN)
            } else {
                0
            }
        };
        self.stats.planned_commands += u64::from(plan_len > 0);
        RobotCommand {
            seq: self.cmd_seq,
            stamp_ns: clock.now().as_nanos() as u64,
            answers,
            flags,
            status: status_code(out.status),
            plan_len: plan_len as u8,
            iterations: out.iterations,
            compute_ns: (compute_us * 1e3).clamp(0.0, u32::MAX as f64) as u32,
            torque: out.torque,
            plan,
        }
    }

    /// Open the session ([`RobotInterface::configure`] if needed, then
    /// [`RobotInterface::activate`] in slices of `retry`) until the robot's first sample
    /// arrives or `timeout` passes; on success the deadlines start `lead` before that
    /// sample's arrival and the sample is used by the first [`ControlLoop::period`]. Returns
    /// whether a sample arrived; call again to go on waiting (the handshake continues).
    pub fn connect<R: RobotInterface<N>, K: Clock>(
        &mut self,
        robot: &mut R,
        clock: &mut K,
        timeout: Duration,
        retry: Duration,
    ) -> std::io::Result<bool> {
        if matches!(robot.state(), Lifecycle::Unconfigured | Lifecycle::Error) {
            robot.configure()?;
        }
        let end = clock.now() + timeout;
        loop {
            let left = end.saturating_sub(clock.now());
            if robot.activate(left.min(retry))? {
                if let Some(s) = robot.read(retry.min(end.saturating_sub(clock.now())))? {
                    let arrival = clock.now();
                    self.next = Some(arrival.saturating_sub(self.s.lead));
                    self.pending = Some(s);
                    return Ok(true);
                }
            }
            if clock.now() >= end {
                return Ok(false);
            }
        }
    }

    /// Run one period: sleep to the deadline `T_k`, read the newest sample (waiting up to the
    /// sample timeout), filter, step the controller (or ramp down when stopping), write the
    /// command answering the sample, record timing. Call [`ControlLoop::connect`] first.
    pub fn period<R: RobotInterface<N>, K: Clock>(
        &mut self,
        robot: &mut R,
        clock: &mut K,
    ) -> std::io::Result<PeriodRecord<N>> {
        let k = self.k;
        let deadline = self.next.unwrap_or_else(|| clock.now());
        // Without a sample this period, the next deadline is one period on.
        let mut next = deadline + self.s.dt;
        clock.sleep_until(deadline);
        let woke = clock.now();
        let wake_error_us = (woke.as_secs_f64() - deadline.as_secs_f64()) * 1e6;
        let sample = match self.pending.take() {
            Some(s) => Some(s),
            None => {
                let until = deadline + self.s.sample_timeout;
                let mut got = robot.read(until.saturating_sub(woke))?;
                // A sample from an earlier slot (left queued after a stall) would make this
                // period answer a sample the robot has already moved past, and keep the loop a
                // period behind: wait, within the timeout, for this slot's sample.
                if let (Some(s), Some(min_off)) = (got, self.offsets.iter().copied().min()) {
                    let slot_stamp = (deadline + self.s.lead).as_nanos() as i64 - min_off;
                    if (s.stamp_ns as i64) < slot_stamp - self.s.dt.as_nanos() as i64 / 2 {
                        self.stats.old_samples += 1;
                        if let Some(newer) = robot.read(until.saturating_sub(clock.now()))? {
                            got = Some(newer);
                        }
                    }
                }
                got
            }
        };
        let arrival = clock.now();
        let dt_s = self.s.dt.as_secs_f64();
        let mut robot_ended = false;
        let mut robot_stopped = false;
        let meas = match &sample {
            Some(s) => {
                self.stats.samples += 1;
                let expected = deadline + self.s.lead;
                let err_ns = arrival.as_nanos() as i64 - expected.as_nanos() as i64;
                if k > 0 && err_ns > self.s.dt.as_nanos() as i64 / 4 {
                    self.stats.late_samples += 1;
                }
                // Clock sync: the next sample is expected at its timestamp plus the smallest
                // recent offset; wake `lead` before it.
                let off = arrival.as_nanos() as i64 - s.stamp_ns as i64;
                if self.offsets.len() < self.s.sync_window.max(1) {
                    self.offsets.push(off);
                } else if let Some(slot) = self.offsets.get_mut(self.offsets_next) {
                    *slot = off;
                }
                self.offsets_next = (self.offsets_next + 1) % self.s.sync_window.max(1).max(1);
                let min_off = self.offsets.iter().copied().min().unwrap_or(off);
                let dt_ns = self.s.dt.as_nanos() as i64;
                let mut at = s.stamp_ns as i64 + dt_ns + min_off - self.s.lead.as_nanos() as i64;
                // A sample that arrived late (a delay spike) may put that slot in the past:
                // skip to the first slot still ahead instead of running catch-up periods.
                let now_ns = arrival.as_nanos() as i64;
                if at <= now_ns && dt_ns > 0 {
                    at += ((now_ns - at) / dt_ns + 1) * dt_ns;
                }
                next = Duration::from_nanos(at.max(0) as u64);
                if s.flags & robot_flags::WATCHDOG != 0 {
                    self.stats.robot_watchdog_samples += 1;
                }
                if s.flags & robot_flags::SENSOR_FAULT != 0 {
                    self.stats.sensor_fault_samples += 1;
                }
                robot_ended = s.flags & robot_flags::END_OF_RUN != 0;
                robot_stopped = s.flags & robot_flags::PROTECTIVE_STOP != 0;
                self.stats.robot_stop_samples += u64::from(robot_stopped);
                // Resume from the torque the robot applied (a lost command, a watchdog).
                let applied = self.s.limits.admissible(&s.effort);
                if self.started && applied != self.ctrl.previous_torque() {
                    self.ctrl.set_previous_torque(applied);
                    self.stats.effort_resyncs += 1;
                }
                self.started = true;
                let t = s.stamp_ns as f64 * 1e-9;
                self.last_t = t;
                // After a gap in the data the filter windows restart: the samples from before
                // the gap would pull the filtered velocity and force back to the leg's motion
                // of up to `filter_window` samples before it (a 120-ms outage at 3 s into a
                // 2-kg run: the controller resumed on a velocity of the wrong sign). A sample
                // that only arrived late (a period without a sample, then this one, next in
                // time) is no gap: restarting the windows then made the filtered channels
                // jump, and the supervisor rejected them (20-ms delay spikes: 74.6 N).
                let period_ns = self.s.dt.as_nanos() as u64;
                let gap = self
                    .last_stamp_ns
                    .is_some_and(|p| s.stamp_ns > p + period_ns + period_ns / 2);
                self.last_stamp_ns = Some(s.stamp_ns);
                if gap {
                    self.vel.reset();
                    self.force.reset();
                }
                Measurement {
                    t,
                    q: s.q,
                    qd: self.vel.push(s.qd),
                    force: self.force.push(s.force),
                }
            }
            None => {
                self.stats.missing_samples += 1;
                self.last_t += dt_s;
                Measurement {
                    t: self.last_t,
                    q: SVector::from_element(f64::NAN),
                    qd: SVector::from_element(f64::NAN),
                    force: SVector::from_element(f64::NAN),
                }
            }
        };
        self.next = Some(next);
        let prev = self.ctrl.previous_torque();
        let t0 = clock.now();
        let output = if self.stopping {
            let torque = self.s.limits.clamp(&prev, &SVector::zeros());
            self.ctrl.set_previous_torque(torque);
            ControlOutput {
                torque,
                status: StepStatus::Ok,
                iterations: 0,
            }
        } else if sample.is_none() && self.s.skip_missing {
            // No sample: nothing is sent, the robot rides through on the last plan; the
            // controller is not stepped on an empty measurement (it resumes from the applied
            // torque on the next sample).
            ControlOutput {
                torque: prev,
                status: StepStatus::BadMeasurement,
                iterations: 0,
            }
        } else {
            self.ctrl.step(&meas)
        };
        let compute_us = (clock.now().as_secs_f64() - t0.as_secs_f64()) * 1e6;
        let within_limits = self.s.limits.admits(&prev, &output.torque);
        self.stats.limit_violations += u64::from(!within_limits);
        self.stats.solver_failures += u64::from(output.status.is_solver_failure());
        self.stats.bad_measurements += u64::from(output.status == StepStatus::BadMeasurement);
        self.stats.monitor_steps += u64::from(output.status == StepStatus::MonitorTripped);
        let mut sent = false;
        if let Some(s) = &sample {
            let flags = if self.stopping {
                command_flags::RAMP_DOWN
            } else {
                0
            };
            let cmd = self.command(clock, s.seq, flags, &output, compute_us);
            robot.write(&cmd)?;
            self.stats.commands += 1;
            sent = true;
        }
        let done = clock.now();
        let busy_us = (done.as_secs_f64() - arrival.as_secs_f64()) * 1e6;
        self.timing
            .record(wake_error_us, busy_us, done > deadline + self.s.dt);
        self.stats.periods += 1;
        self.k += 1;
        Ok(PeriodRecord {
            k,
            wake_error_us,
            sample,
            measurement: meas,
            output,
            torque_prev: prev,
            compute_us,
            sent,
            within_limits,
            robot_ended,
            robot_stopped,
        })
    }

    /// Tell the robot the controller stopped (zero torque, STOP flag: the robot makes a
    /// protective stop, ramping from what it applies), `repeat` times against loss.
    pub fn send_stop<R: RobotInterface<N>, K: Clock>(
        &mut self,
        robot: &mut R,
        clock: &K,
        repeat: usize,
    ) -> std::io::Result<()> {
        let zero = ControlOutput {
            torque: SVector::zeros(),
            status: StepStatus::Ok,
            iterations: 0,
        };
        let answers = self.pending.map_or(0, |s| s.seq);
        for _ in 0..repeat {
            let cmd = self.command(clock, answers, command_flags::STOP, &zero, 0.0);
            robot.write(&cmd)?;
            self.stats.commands += 1;
        }
        Ok(())
    }
}
