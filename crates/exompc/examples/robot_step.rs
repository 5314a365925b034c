//! The controller as it runs on a robot: built once, then one `step` per control period.
//!
//! `build_supervised` builds the multi-stage NMPC of the default scenario (docs/MODEL.md §8)
//! inside the safety [`Supervisor`](exompc::Supervisor): all memory is allocated here, once.
//! Every period the robot's drivers supply a measurement — encoder angles, the filtered joint
//! velocities and the filtered strap forces (§5) — and `step` returns the torque to send to the
//! motors. The step allocates nothing, never panics and always returns a torque within the
//! torque and torque-rate limits; its status says how the torque was obtained, and a bad sensor
//! sample is answered by holding the previous torque instead of feeding it to the optimiser.
//!
//! Here `read_sensors` and `write_torques` stand in for the robot's drivers (a slow swing of the
//! leg with the straps pulling, and one corrupted sample); the loop keeps a 10 ms period with
//! `std::thread::sleep`, where a robot would wait on its real-time clock or bus.
//!
//! Run with `cargo run --release -p exompc --example robot_step`.

use exompc::scenario::limits;
use exompc::{
    build_supervised, Controller, ControllerKind, Experiment, Measurement, StepStatus, TwoDof,
};
use nalgebra::Vector2;
use std::time::{Duration, Instant};

/// Stand-in for the robot's sensor drivers at control step `k` (time `t`).
fn read_sensors(k: usize, t: f64) -> Measurement<2> {
    let w = 2.0 * std::f64::consts::PI * 0.5;
    let mut m = Measurement {
        t,
        q: Vector2::new(0.1 + 0.2 * (w * t).sin(), -0.25 - 0.2 * (w * t).sin()),
        qd: Vector2::new(0.2 * w * (w * t).cos(), -0.2 * w * (w * t).cos()),
        force: Vector2::new(2.0 * (w * t).cos(), -3.0 * (w * t).cos()),
    };
    if k == 50 {
        m.force[1] = f64::NAN; // a corrupted strap-force sample
    }
    m
}

/// Stand-in for the motor drivers.
fn write_torques(_torque: &Vector2<f64>) {}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let scenario = Experiment::default();
    let lim = limits(&scenario);
    let mut controller = build_supervised::<TwoDof, 2>(&scenario, ControllerKind::MSNMPC)?;

    let period = Duration::from_secs_f64(scenario.timing.dt);
    let mut next = Instant::now();
    let mut worst = Duration::ZERO;
    let mut held = 0;
    for k in 0..100 {
        let t = k as f64 * scenario.timing.dt;
        let m = read_sensors(k, t);
        let prev = controller.previous_torque();

        let started = Instant::now();
        let out = controller.step(&m);
        worst = worst.max(started.elapsed());
        write_torques(&out.torque);

        match out.status {
            StepStatus::Ok | StepStatus::MaxIterations | StepStatus::MaxTime => {}
            StepStatus::BadMeasurement => {
                held += 1;
                println!(
                    "t = {t:.2} s: bad sensor sample, torque held at {:?}",
                    out.torque
                );
            }
            other => println!("t = {t:.2} s: {other:?}"),
        }
        if !(out.torque.amax() <= lim.max && (out.torque - prev).amax() <= lim.rate + 1e-9) {
            return Err(format!("torque {:?} outside the limits at t = {t}", out.torque).into());
        }

        next += period;
        if let Some(wait) = next.checked_duration_since(Instant::now()) {
            std::thread::sleep(wait);
        }
    }
    let report = controller.report();
    println!(
        "100 steps; slowest step {:.0} µs of the {:.0} ms period; {} steps held on bad data",
        worst.as_secs_f64() * 1e6,
        period.as_secs_f64() * 1e3,
        report.bad_measurement_steps
    );
    if held != 1 || report.bad_measurement_steps != 1 {
        return Err("the corrupted sample was not rejected exactly once".into());
    }
    Ok(())
}
