//! The simulated leg of `exompc simulate` behind virtual CiA 402 drives and a virtual CANopen
//! strap-force node: one [`VirtualNode`] that steps the plant every `dt` of bus time with the
//! torques the drives apply, reads the sensors once per step, and lets each drive and the
//! force node answer the bus with the step's values.

use super::emulator::{Cia402Emulator, DriveJoint, EmulatorStats};
use super::Scaling;
use crate::canopen::NodeId;
use crate::emulator::LegStep;
use crate::force_node::ForceNodeEmulator;
use crate::virtual_bus::{NodeTx, VirtualNode};
use crate::CanFrame;
use exompc::sim::{Plant, Sensors, Trajectory};
use nalgebra::SVector;
use std::sync::{Arc, Mutex};
use std::time::Duration;

/// What a drive and the leg share: the joint's sensed angle and velocity, the torque applied.
#[derive(Clone, Copy, Debug, Default)]
struct Port {
    q: f64,
    qd: f64,
    tau: f64,
}

#[derive(Clone)]
struct SharedJoint(Arc<Mutex<Port>>);

impl SharedJoint {
    fn get(&self) -> Port {
        *self.0.lock().unwrap_or_else(|e| e.into_inner())
    }

    fn set_sensed(&self, q: f64, qd: f64) {
        let mut p = self.0.lock().unwrap_or_else(|e| e.into_inner());
        p.q = q;
        p.qd = qd;
    }
}

impl DriveJoint for SharedJoint {
    fn state(&mut self, _now: Duration) -> (f64, f64) {
        let p = self.get();
        (p.q, p.qd)
    }

    fn set_torque(&mut self, _now: Duration, tau: f64) {
        self.0.lock().unwrap_or_else(|e| e.into_inner()).tau = tau;
    }
}

/// One virtual drive of a [`Cia402Leg`].
#[derive(Clone, Copy, Debug)]
pub struct LegDrive {
    /// Node id.
    pub node: NodeId,
    /// The drive's mechanics (its 0x6076 reports `rated_torque`).
    pub scaling: Scaling,
}

/// The virtual force node of a [`Cia402Leg`].
#[derive(Clone, Copy, Debug)]
pub struct LegForceNode {
    /// Node id.
    pub node: NodeId,
    /// N per count of its process values.
    pub scale: f64,
}

/// The leg with `N` virtual CiA 402 drives (hip, knee or knee) and a CANopen force node.
pub struct Cia402Leg<const N: usize, Tr: Trajectory<N>> {
    plant: Plant<N, Tr>,
    sensors: Sensors<N>,
    drives: Vec<Cia402Emulator>,
    ports: Vec<SharedJoint>,
    force: ForceNodeEmulator,
    forces: Arc<Mutex<[f64; 2]>>,
    dt: Duration,
    k: u64,
    history: Vec<LegStep<N>>,
    record: bool,
}

impl<const N: usize, Tr: Trajectory<N> + Send> Cia402Leg<N, Tr> {
    /// A leg over `plant` and `sensors` stepped every `dt`, driven by `drives` (joint order),
    /// its strap forces sent by `force` (thigh → sub 1, shank → sub 2).
    pub fn new(
        plant: Plant<N, Tr>,
        sensors: Sensors<N>,
        drives: [LegDrive; N],
        force: LegForceNode,
        dt: Duration,
    ) -> Self {
        let ports: Vec<SharedJoint> = (0..N)
            .map(|_| SharedJoint(Arc::new(Mutex::new(Port::default()))))
            .collect();
        let emulators = drives
            .iter()
            .zip(&ports)
            .map(|(d, p)| Cia402Emulator::new(d.node, d.scaling, Box::new(p.clone())))
            .collect();
        let forces = Arc::new(Mutex::new([0.0; 2]));
        let f2 = forces.clone();
        let force = ForceNodeEmulator::new(
            force.node,
            force.scale,
            false,
            Box::new(move |_now: Duration| {
                let f = *f2.lock().unwrap_or_else(|e| e.into_inner());
                (f[0], f[1])
            }),
        );
        let mut leg = Cia402Leg {
            plant,
            sensors,
            drives: emulators,
            ports,
            force,
            forces,
            dt,
            k: 0,
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

    /// The drives (for inspection and fault injection).
    pub fn drives_mut(&mut self) -> &mut [Cia402Emulator] {
        &mut self.drives
    }

    /// The drives' counters.
    pub fn drive_stats(&self) -> Vec<EmulatorStats> {
        self.drives
            .iter()
            .map(|d| *d.stats().lock().unwrap_or_else(|e| e.into_inner()))
            .collect()
    }

    /// Fault injection: the force node stops sending.
    pub fn set_force_silent(&mut self, silent: bool) {
        self.force.set_silent(silent);
    }

    fn sample(&mut self) {
        let t = self.plant.time();
        let s = *self.plant.state();
        let f = self.plant.strap_force();
        let (raw, _) = self.sensors.read(t, &s.robot.q, &s.robot.qd, &f);
        for i in 0..N {
            self.ports[i].set_sensed(raw.q[i], raw.qd[i]);
        }
        let mut fs = self.forces.lock().unwrap_or_else(|e| e.into_inner());
        *fs = [if N >= 2 { raw.force[0] } else { 0.0 }, raw.force[N - 1]];
    }
}

impl<const N: usize, Tr: Trajectory<N> + Send> VirtualNode for Cia402Leg<N, Tr> {
    fn on_frame(&mut self, now: Duration, frame: &CanFrame, tx: &mut NodeTx) {
        for d in &mut self.drives {
            d.on_frame(now, frame, tx);
        }
        self.force.on_frame(now, frame, tx);
    }

    fn next_wakeup(&self) -> Option<Duration> {
        let mut t = self.dt * (self.k as u32 + 1);
        for d in &self.drives {
            if let Some(w) = d.next_wakeup() {
                t = t.min(w);
            }
        }
        if let Some(w) = self.force.next_wakeup() {
            t = t.min(w);
        }
        Some(t)
    }

    fn on_wakeup(&mut self, now: Duration, tx: &mut NodeTx) {
        let step = self.dt * (self.k as u32 + 1);
        if now >= step {
            let mut tau = SVector::<f64, N>::zeros();
            for i in 0..N {
                tau[i] = self.ports[i].get().tau;
            }
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
        for d in &mut self.drives {
            if d.next_wakeup().is_some_and(|w| w <= now) {
                d.on_wakeup(now, tx);
            }
        }
        if self.force.next_wakeup().is_some_and(|w| w <= now) {
            self.force.on_wakeup(now, tx);
        }
    }
}
