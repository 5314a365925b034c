//! A closed loop around a plant of your own, driven by exompc's multi-stage controller.
//!
//! The plant is written here from scratch and kept simple: the default exoskeleton leg (built
//! from exompc's chain model, docs/MODEL.md §3) carries a 1.5 kg payload that the controller
//! does not know, and is strapped (§4) to a human leg that moves exactly along its own path —
//! a "stiff" human whose angles are prescribed and who never yields to the robot. Sensors are
//! ideal. The controller is the library's multi-stage NMPC of the default scenario, used
//! as-is: measurement in, torque out, once per 10 ms period.
//!
//! Run with `cargo run --release -p exompc --example closed_loop_own_plant`. The program checks
//! the torque limits on every step and that the strap forces stay bounded, and exits with an
//! error if they do not.

use exompc::model::{rk4_step, Chain, Friction, JointState, Link, RobotModel, Straps};
use exompc::scenario::limits;
use exompc::{build_controller, Controller, ControllerKind, Experiment, Measurement, TwoDof};
use nalgebra::Vector2;
use std::f64::consts::PI;

/// The human's hip and knee angles (rad) and velocities (rad/s): a 0.8 Hz swing.
fn human(t: f64) -> (Vector2<f64>, Vector2<f64>) {
    let w = 2.0 * PI * 0.8;
    let (s, c) = (w * t).sin_cos();
    let q = Vector2::new(0.1 + 0.3 * s, -0.4 * (1.0 - c));
    let qd = Vector2::new(0.3 * w * c, -0.4 * w * s);
    (q, qd)
}

/// The user's plant: robot leg, straps to the prescribed human leg, RK4 with 1 ms steps.
struct MyPlant {
    robot: RobotModel<2>,
    straps: Straps<2>,
    x: JointState<f64, 2>,
    t: f64,
}

impl MyPlant {
    /// Strap forces (N), thigh then shank, at the current state.
    fn strap_forces(&self) -> Vector2<f64> {
        let (qh, qdh) = human(self.t);
        self.straps.force(&(qh - self.x.q), &(qdh - self.x.qd))
    }

    /// Advance one control period `dt` with the robot torque held (zero-order hold).
    fn advance(&mut self, torque: &Vector2<f64>, dt: f64) {
        const SUBSTEPS: usize = 10;
        let h = dt / SUBSTEPS as f64;
        let (robot, straps) = (&self.robot, &self.straps);
        let rhs = |t: f64, x: &JointState<f64, 2>| {
            let (qh, qdh) = human(t);
            let t_int = straps.torque(&straps.force(&(qh - x.q), &(qdh - x.qd)));
            JointState {
                q: x.qd,
                qd: robot.acceleration(&x.q, &x.qd, &(torque + t_int)),
            }
        };
        for _ in 0..SUBSTEPS {
            self.x = rk4_step(rhs, self.t, &self.x, h);
            self.t += h;
        }
    }
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let scenario = Experiment::default();
    let dt = scenario.timing.dt;
    let lim = limits(&scenario);
    let mut controller = build_controller::<TwoDof, 2>(&scenario, ControllerKind::MSNMPC)?;

    // The plant: thigh and shank of the default robot, 1.5 kg at the middle of the shank.
    let thigh = Link {
        length: 0.43,
        mass: 2.0,
        com: 0.20,
        inertia: 0.035,
    };
    let shank = Link {
        length: 0.43,
        mass: 1.2,
        com: 0.18,
        inertia: 0.018,
    }
    .with_point_mass(1.5, 0.215);
    let robot = RobotModel {
        chain: Chain::new([thigh, shank]),
        viscous: 0.000899,
        coulomb: 0.05048,
        friction: Friction::Sign,
    };
    let (q0, qd0) = human(0.0);
    let mut plant = MyPlant {
        robot,
        straps: Straps::two_dof(0.28, 0.16, 937.5, 93.7),
        x: JointState { q: q0, qd: qd0 },
        t: 0.0,
    };
    // Start from the torque that holds this robot against gravity, T_R(-1).
    controller.set_previous_torque(plant.robot.chain.gravity_torque(&q0));

    let steps = (5.0 / dt).round() as usize;
    let mut sum_sq = Vector2::zeros();
    let mut max_force: f64 = 0.0;
    for _ in 0..steps {
        let force = plant.strap_forces();
        let m = Measurement {
            t: plant.t,
            q: plant.x.q,
            qd: plant.x.qd,
            force,
        };
        let prev = controller.previous_torque();
        let out = controller.step(&m);
        if !(out.torque.amax() <= lim.max && (out.torque - prev).amax() <= lim.rate + 1e-9) {
            return Err(
                format!("torque {:?} outside the limits at t = {}", out.torque, m.t).into(),
            );
        }
        sum_sq += force.component_mul(&force);
        max_force = max_force.max(force.amax());
        plant.advance(&out.torque, dt);
    }
    let rms = (sum_sq / steps as f64).map(f64::sqrt);
    let mu = controller.probabilities().unwrap_or(&[]);
    println!("{steps} steps of {dt} s against a stiff human, unknown payload 1.5 kg");
    println!(
        "RMS strap force: thigh {:.2} N, shank {:.2} N (max {max_force:.2} N)",
        rms[0], rms[1]
    );
    println!("scenario probabilities (0, 1, 2 kg): {mu:.3?}");
    if !rms.iter().all(|f| f.is_finite()) || max_force >= 100.0 {
        return Err(format!("strap force {max_force} N: the loop is not stable").into());
    }
    Ok(())
}
