//! Shared bench fixtures: the default 2-DOF scenario and measurements recorded from its closed
//! loop.

use exompc::config::{ControllerKind, Experiment};
use exompc::control::Measurement;
use exompc::scenario::{build_controller, plant_params, uncertainty, Dof, TwoDof};
use exompc::sim::{Plant, Sensors};

/// `steps` filtered measurements of a closed loop of `s` under the plain NMPC.
pub fn record(s: &Experiment, steps: usize) -> Vec<Measurement<2>> {
    let mut c = build_controller::<TwoDof, 2>(s, ControllerKind::NMPC).expect("controller");
    let mut plant = Plant::new(plant_params::<TwoDof, 2>(s), TwoDof::trajectory(s));
    let mut sensors = Sensors::new(uncertainty(s), s.uncertainty.filter_window);
    let mut out = Vec::with_capacity(steps);
    for _ in 0..steps {
        let t = plant.time();
        let st = *plant.state();
        let force = plant.strap_force();
        let (_raw, meas) = sensors.read(t, &st.robot.q, &st.robot.qd, &force);
        out.push(meas);
        let u = c.step(&meas).torque;
        plant.step(&u);
    }
    out
}
