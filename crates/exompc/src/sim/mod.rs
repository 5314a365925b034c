//! Simulation: the human "brain", desired trajectories, plant uncertainties, sensors and
//! filters, the coupled human-robot plant, the closed loop and its metrics (paper §4.1).
//!
//! The closed loop is deliberately short (see [`run_closed_loop`]): sample the sensors, call the
//! controller, hand every part's values to the recorders, advance the plant.

mod closed_loop;
mod demand;
mod faults;
mod gait;
mod human;
mod metrics;
mod plant;
mod safety_summary;
mod spline;
mod stability;
pub mod trace;
mod trajectory;
mod uncertainty;

pub use crate::check::InvalidField;
#[cfg(feature = "std")]
pub use closed_loop::{is_stop_requested, stop_requested, StopRequested, StopWhen};
pub use closed_loop::{
    record_error, run_closed_loop, RecordError, RecordResult, Recorder, StepRecord, TraceLog,
    TraceRow,
};
pub use demand::{actuator_demand, required_torque, ActuatorDemand};
pub use faults::{
    channel_index, default_schedule, repeat_schedule, Channel, FaultEvent, FaultInjector,
    FaultKind, Faults, SoakStats,
};
pub use gait::{
    Gait, GaitKind, GaitRecording, GaitTrajectory, RecordedTrajectory, RecordingColumn,
    RecordingError,
};
pub use human::{HumanBrain, HumanLeg};
pub use metrics::{Metrics, StepTimeStats, Summary};
pub use plant::{robot_model, Plant, PlantParams, PlantState};
pub use safety_summary::{MonitorTally, SafetySummary};
pub use spline::{CubicSpline, SplineEnds};
pub use stability::{
    cell_verdict, classify, classify_run, high_frequency_fraction, rms, CellVerdict, RunClass,
    RunStability, StabilityCriteria, StrapStability,
};
pub use trajectory::{KneeTrajectory, SwingTrajectory, Trajectory};
pub use uncertainty::{Uncertainty, MAX_PAYLOAD_KG};

use crate::control::Measurement;
use crate::estimate::MovingAverage;
use nalgebra::SVector;

/// The sensor chain of MODEL.md §5: exact encoders, noisy velocity and force sensors sampled at the
/// control instants, and the moving-average filter the controller reads.
#[derive(Clone, Debug)]
pub struct Sensors<const N: usize> {
    uncertainty: Uncertainty,
    velocity: MovingAverage<N>,
    force: MovingAverage<N>,
    faults: FaultInjector<N>,
}

impl<const N: usize> Sensors<N> {
    /// Sensors with the noise of `uncertainty` and a `window`-sample moving average.
    pub fn new(uncertainty: Uncertainty, window: usize) -> Self {
        Sensors {
            uncertainty,
            velocity: MovingAverage::new(window),
            force: MovingAverage::new(window),
            faults: FaultInjector::none(),
        }
    }

    /// The same sensors with the fault schedule and force range of `[faults]` (see
    /// [`FaultInjector`]; the default range ±70 N applies without it).
    pub fn with_faults(mut self, faults: &Faults) -> Self {
        self.faults = FaultInjector::new(faults);
        self
    }

    /// Sample at time `t` the true robot angles, velocities and strap forces; returns the raw
    /// (noisy, range-clipped, fault-injected) sample and the filtered measurement the
    /// controller receives. Faults act on the raw sample, before the filter: a NaN stays in
    /// the filter window (the filtered value is NaN) for `window` samples.
    pub fn read(
        &mut self,
        t: f64,
        q: &SVector<f64, N>,
        qd: &SVector<f64, N>,
        force: &SVector<f64, N>,
    ) -> (Measurement<N>, Measurement<N>) {
        let mut raw = Measurement {
            t,
            q: *q,
            qd: qd.add_scalar(self.uncertainty.velocity_noise(t)),
            force: force.add_scalar(self.uncertainty.force_noise(t)),
        };
        self.faults.apply(&mut raw);
        let filtered = Measurement {
            t,
            q: raw.q,
            qd: self.velocity.push(raw.qd),
            force: self.force.push(raw.force),
        };
        (raw, filtered)
    }
}
