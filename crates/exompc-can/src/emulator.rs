//! Virtual devices on the virtual bus: AK motors in MIT mode and raw-frame strap-force nodes,
//! with the simulated human + exoskeleton of `exompc simulate` (the same
//! [`Plant`] and [`Sensors`]) behind them.
//!
//! [`VirtualLeg`] is one [`VirtualNode`]: the plant steps every `dt` of bus time (from bus time
//! 0) with the torques the motors apply; the sensors are read once per step (noise, faults);
//! each motor answers a command after its latency with the step's position and velocity and
//! the torque it applies, all quantised by the MIT packing; the force node sends the step's
//! strap forces at its own rate.

use crate::ak::{
    pack_reply, unpack_command, MitReply, ENTER_MOTOR_MODE, EXIT_MOTOR_MODE, SET_ZERO,
};
use crate::config::{AkModel, RawForceSensor, Strap};
use crate::frame::{CanFrame, CanId};
use crate::virtual_bus::{NodeTx, VirtualNode};
use exompc::sim::{Plant, Sensors, Trajectory};
use nalgebra::SVector;
use std::time::Duration;

/// One emulated AK motor: motor mode, zero, the last (quantised) command, its torque limit,
/// and injectable faults.
#[derive(Clone, Debug)]
pub struct AkEmulator {
    /// The motor's CAN ID.
    pub can_id: u8,
    /// The ID its replies carry.
    pub reply_id: u16,
    /// The MIT ranges of its firmware.
    pub ranges: AkModel,
    /// `true` in motor mode (it applies commands).
    pub motor_mode: bool,
    /// Output-side position the motor reports as 0 (set by the set-zero frame).
    pub zero: f64,
    /// The last command as the motor read it: `(p, v, kp, kd, t)`.
    pub command: crate::ak::MitCommand,
    /// Fault injection: the motor stops answering (a cable off, a dead drive).
    pub silent: bool,
    /// Fault injection: the error code its replies carry (0: none); a non-zero code also
    /// makes it apply no torque, as a drive in fault does.
    pub fault: u8,
    /// Commands received.
    pub commands: u64,
    /// Replies sent.
    pub replies: u64,
}

impl AkEmulator {
    /// A motor with `can_id`, replying on `reply_id`, with the ranges `ranges`, out of motor
    /// mode.
    pub fn new(can_id: u8, reply_id: u16, ranges: AkModel) -> Self {
        AkEmulator {
            can_id,
            reply_id,
            ranges,
            motor_mode: false,
            zero: 0.0,
            command: Default::default(),
            silent: false,
            fault: 0,
            commands: 0,
            replies: 0,
        }
    }

    /// The output torque the motor applies at output-side position `p` and velocity `v`:
    /// `kp·(p_des − p) + kd·(v_des − v) + t_ff`, limited to ±t_max; 0 out of motor mode or in
    /// fault.
    pub fn torque(&self, p: f64, v: f64) -> f64 {
        if !self.motor_mode || self.fault != 0 {
            return 0.0;
        }
        let c = &self.command;
        let t = c.kp * (c.p - (p - self.zero)) + c.kd * (c.v - v) + c.t;
        t.clamp(-self.ranges.t_max, self.ranges.t_max)
    }

    /// Handle a frame addressed to this motor; `Some(reply)` if it answers.
    fn on_frame(&mut self, data: &[u8], p: f64, v: f64) -> Option<[u8; 8]> {
        let d: &[u8; 8] = data.try_into().ok()?;
        if self.silent {
            return None;
        }
        match *d {
            ENTER_MOTOR_MODE => {
                self.motor_mode = true;
                self.command = Default::default();
            }
            EXIT_MOTOR_MODE => {
                self.motor_mode = false;
                self.command = Default::default();
            }
            SET_ZERO => self.zero = p,
            _ => {
                if !self.motor_mode {
                    return None;
                }
                self.command = unpack_command(&self.ranges, d);
                self.commands += 1;
            }
        }
        self.replies += 1;
        let reply = MitReply {
            motor_id: self.can_id,
            p: p - self.zero,
            v,
            effort: self.torque(p, v),
            temperature: Some(30),
            error: Some(self.fault),
        };
        Some(pack_reply(&self.ranges, &reply))
    }
}

/// How a virtual motor drives a model joint: `τ_joint = direction · gear_ratio · τ_motor`,
/// `p_motor = direction · gear_ratio · (q − zero_offset)`.
#[derive(Clone, Copy, Debug)]
pub struct Mount {
    /// +1 or −1.
    pub direction: f64,
    /// Joint torque per motor torque.
    pub gear_ratio: f64,
    /// Joint angle at motor position 0 (rad).
    pub zero_offset: f64,
}

/// One plant step of a [`VirtualLeg`], for traces and metrics.
#[derive(Clone, Copy, Debug)]
pub struct LegStep<const N: usize> {
    /// Time of the step's start (s).
    pub t: f64,
    /// Robot joint angles (rad).
    pub q: SVector<f64, N>,
    /// True strap forces at `t` (N).
    pub force_true: SVector<f64, N>,
    /// Joint torques applied over the step (N·m).
    pub torque: SVector<f64, N>,
}

/// A raw-frame force node of a [`VirtualLeg`] and when it sends next.
struct ForceNode {
    cfg: RawForceSensor,
    next: Duration,
    period: Duration,
}

/// The simulated leg behind virtual AK motors and raw-frame force nodes.
pub struct VirtualLeg<const N: usize, Tr: Trajectory<N>> {
    plant: Plant<N, Tr>,
    sensors: Sensors<N>,
    motors: [AkEmulator; N],
    mounts: [Mount; N],
    forces: Vec<ForceNode>,
    dt: Duration,
    latency: Duration,
    k: u64,
    q_raw: SVector<f64, N>,
    qd_raw: SVector<f64, N>,
    force_raw: SVector<f64, N>,
    force_silent: bool,
    history: Vec<LegStep<N>>,
    record: bool,
}

impl<const N: usize, Tr: Trajectory<N> + Send> VirtualLeg<N, Tr> {
    /// A leg over `plant` and `sensors` stepped every `dt`, driven by `motors` mounted as
    /// `mounts`, its strap forces sent by the nodes `forces` (each its own channels at its own
    /// rate); devices answer after `latency`.
    pub fn new(
        plant: Plant<N, Tr>,
        sensors: Sensors<N>,
        motors: [AkEmulator; N],
        mounts: [Mount; N],
        forces: Vec<RawForceSensor>,
        dt: Duration,
        latency: Duration,
    ) -> Self {
        let forces = forces
            .into_iter()
            .map(|cfg| ForceNode {
                period: Duration::from_secs_f64(1.0 / cfg.rate_hz.max(1.0)),
                next: Duration::ZERO,
                cfg,
            })
            .collect();
        let mut leg = VirtualLeg {
            plant,
            sensors,
            motors,
            mounts,
            forces,
            dt,
            latency,
            k: 0,
            q_raw: SVector::zeros(),
            qd_raw: SVector::zeros(),
            force_raw: SVector::zeros(),
            force_silent: false,
            history: Vec::new(),
            record: false,
        };
        leg.sample();
        leg
    }

    /// Keep a [`LegStep`] per plant step (room for `capacity` reserved).
    pub fn with_history(mut self, capacity: usize) -> Self {
        self.record = true;
        self.history = Vec::with_capacity(capacity);
        self
    }

    /// The plant steps so far (if recording).
    pub fn history(&self) -> &[LegStep<N>] {
        &self.history
    }

    /// The plant.
    pub fn plant(&self) -> &Plant<N, Tr> {
        &self.plant
    }

    /// The motors (for inspection and fault injection).
    pub fn motors_mut(&mut self) -> &mut [AkEmulator; N] {
        &mut self.motors
    }

    /// Fault injection: the force nodes stop sending.
    pub fn set_force_silent(&mut self, silent: bool) {
        self.force_silent = silent;
    }

    fn sample(&mut self) {
        let t = self.plant.time();
        let s = *self.plant.state();
        let f = self.plant.strap_force();
        let (raw, _) = self.sensors.read(t, &s.robot.q, &s.robot.qd, &f);
        self.q_raw = raw.q;
        self.qd_raw = raw.qd;
        self.force_raw = raw.force;
    }

    /// Output-side position and velocity of motor `i` now.
    fn motor_pv(&self, i: usize) -> (f64, f64) {
        let m = &self.mounts[i];
        let s = m.direction * m.gear_ratio;
        (s * (self.q_raw[i] - m.zero_offset), s * self.qd_raw[i])
    }

    fn joint_torques(&self) -> SVector<f64, N> {
        let mut tau = SVector::zeros();
        for i in 0..N {
            let (p, v) = self.motor_pv(i);
            let m = &self.mounts[i];
            tau[i] = m.direction * m.gear_ratio * self.motors[i].torque(p, v);
        }
        tau
    }

    fn force_frame(&self, node: &RawForceSensor) -> Option<CanFrame> {
        let mut data = [0u8; 8];
        for c in &node.channels {
            let i = match c.strap {
                Strap::Thigh => 0,
                Strap::Shank => N - 1,
            };
            if N == 1 && c.strap == Strap::Thigh {
                continue;
            }
            c.encode(self.force_raw[i], &mut data);
        }
        let id = if node.extended {
            CanId::Extended(node.can_id)
        } else {
            CanId::Standard(node.can_id as u16)
        };
        CanFrame::new(id, &data[..node.frame_len()]).ok()
    }
}

impl<const N: usize, Tr: Trajectory<N> + Send> VirtualNode for VirtualLeg<N, Tr> {
    fn on_frame(&mut self, now: Duration, frame: &CanFrame, tx: &mut NodeTx) {
        let CanId::Standard(id) = frame.id() else {
            return;
        };
        for i in 0..N {
            if u16::from(self.motors[i].can_id) == id {
                let (p, v) = self.motor_pv(i);
                if let Some(reply) = self.motors[i].on_frame(frame.data(), p, v) {
                    let rid = self.motors[i].reply_id;
                    if let Ok(f) = CanFrame::standard(rid, &reply) {
                        tx.send_at(now + self.latency, f);
                    }
                }
            }
        }
    }

    fn next_wakeup(&self) -> Option<Duration> {
        let step = self.dt * (self.k as u32 + 1);
        Some(self.forces.iter().fold(step, |t, f| t.min(f.next)))
    }

    fn on_wakeup(&mut self, now: Duration, tx: &mut NodeTx) {
        let step = self.dt * (self.k as u32 + 1);
        if now >= step {
            let tau = self.joint_torques();
            if self.record {
                self.history.push(LegStep {
                    t: self.plant.time(),
                    q: self.plant.state().robot.q,
                    force_true: self.plant.strap_force(),
                    torque: tau,
                });
            }
            self.plant.step(&tau);
            self.k += 1;
            self.sample();
        }
        for i in 0..self.forces.len() {
            if now >= self.forces[i].next {
                let period = self.forces[i].period;
                self.forces[i].next += period;
                if !self.force_silent {
                    if let Some(f) = self.force_frame(&self.forces[i].cfg) {
                        tx.send_at(now, f);
                    }
                }
            }
        }
    }
}
