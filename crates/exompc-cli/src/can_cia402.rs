//! The CiA 402 robot of `exompc run --config`: CANopen drives (`driver = "cia402"`) at every
//! joint and a CANopen strap-force node (`driver = "canopen"`), on the virtual bus with the
//! simulated leg behind virtual drives, or on hardware behind an slcan adapter or a SocketCAN
//! interface (`crate::can::hardware_bus`).

use crate::can::{hardware_bus, virtual_bus, AnyBus, AnyClock};
use crate::error::CliError;
use exompc::config::Experiment;
use exompc::runtime::MonotonicClock;
use exompc::scenario::{limits, plant_params, uncertainty, Dof};
use exompc::sim::{Plant, Sensors};
use exompc_can::canopen::NodeId;
use exompc_can::cia402::leg::{Cia402Leg, LegDrive, LegForceNode};
use exompc_can::cia402::master::Cia402Master;
use exompc_can::cia402::robot::{Cia402Robot, Cia402RobotSettings};
use exompc_can::config::{
    BusConfig, CanopenForceSensor, Cia402Joint, ForceSensor, HardwareConfig, Joint,
};
use exompc_can::force_node::ForceSensor as ForceReader;
use exompc_can::TimeBase;
use std::sync::{Arc, Mutex};
use std::time::Duration;

/// `true` when any joint of the config is a CiA 402 drive.
pub fn uses_cia402(hw: &HardwareConfig) -> bool {
    hw.joints
        .iter()
        .iter()
        .any(|(_, j)| matches!(j, Joint::Cia402(_)))
}

/// The coarsest joint-angle step (rad) of the config's CiA 402 drives: one position increment
/// at the joint, `2π / (counts_per_rev · gear_ratio)`. An angle repeated bit for bit while
/// the joint moves less than that per period is no frozen encoder (`[monitors]
/// encoder_step_rad`, docs/RELIABILITY.md §2). `None` without a CiA 402 joint.
pub fn encoder_step(hw: &HardwareConfig) -> Option<f64> {
    hw.joints
        .iter()
        .iter()
        .filter_map(|(_, j)| match j {
            Joint::Cia402(c) => {
                Some(std::f64::consts::TAU / (c.counts_per_rev * c.gear_ratio).abs())
            }
            _ => None,
        })
        .reduce(f64::max)
}

/// The named CiA 402 joints and the CANopen force node of a run.
type Parts<const N: usize> = ([(&'static str, Cia402Joint); N], CanopenForceSensor);

/// The CiA 402 joints of an `N`-DOF run (hip and knee, or the knee alone) and the CANopen
/// force node; a mixed config is refused with the key named.
fn parts<const N: usize>(hw: &HardwareConfig) -> Result<Parts<N>, CliError> {
    let all = hw.joints.iter();
    let mut joints = Vec::with_capacity(N);
    for (name, j) in &all[2 - N..] {
        match j {
            Joint::Cia402(c) => joints.push((*name, c.clone())),
            _ => {
                return Err(CliError::Config(format!(
                    "robot.joints.{name}.driver: every joint must be \"cia402\" when one is \
                     (mixing drivers on one bus is not supported)"
                )))
            }
        }
    }
    let mut force = None;
    for (i, f) in hw.force_sensors.iter().enumerate() {
        match f {
            ForceSensor::Canopen(c) if force.is_none() => force = Some(c.clone()),
            _ => {
                return Err(CliError::Config(format!(
                    "robot.force_sensors[{i}].driver: the CiA 402 robot reads one \"canopen\" \
                     force node (thigh and shank)"
                )))
            }
        }
    }
    let force = force.ok_or_else(|| {
        CliError::Config("robot.force_sensors: a \"canopen\" force node is needed".into())
    })?;
    let joints = joints
        .try_into()
        .map_err(|_| CliError::Runtime("joint count".into()))?;
    Ok((joints, force))
}

/// A CiA 402 robot with its clock, and for the virtual transport the bus and the leg.
pub struct Cia402Rig<const N: usize, Tr: exompc::sim::Trajectory<N>> {
    /// The robot.
    pub robot: Cia402Robot<N, AnyBus, AnyClock>,
    /// The loop's clock.
    pub clock: AnyClock,
    /// The virtual bus (virtual transport).
    pub bus: Option<exompc_can::VirtualBus>,
    /// The simulated leg (virtual transport).
    pub leg: Option<Arc<Mutex<Cia402Leg<N, Tr>>>>,
    /// What the robot is, for messages.
    pub label: String,
}

/// The simulated leg behind the config's virtual CiA 402 drives and CANopen force node
/// (`history`: plant steps to keep).
pub fn virtual_leg<D: Dof<N>, const N: usize>(
    s: &Experiment,
    hw: &HardwareConfig,
    history: usize,
) -> Result<Cia402Leg<N, D::Traj>, CliError>
where
    D::Traj: Send,
{
    let (joints, force) = parts::<N>(hw)?;
    let dt = Duration::from_secs_f64(s.timing.dt);
    s.check_trajectory(D::DOF)
        .map_err(|e| CliError::Config(e.to_string()))?;
    let plant = Plant::new(plant_params::<D, N>(s), D::trajectory(s));
    let sensors = Sensors::new(uncertainty(s), s.uncertainty.filter_window).with_faults(&s.faults);
    let node = |id: u8| NodeId::new(u32::from(id)).map_err(|e| CliError::Config(e.to_string()));
    let mut drives = Vec::with_capacity(N);
    for (_, j) in &joints {
        drives.push(LegDrive {
            node: node(j.node_id)?,
            scaling: j.scaling(),
        });
    }
    let drives: [LegDrive; N] = drives
        .try_into()
        .map_err(|_| CliError::Runtime("joint count".into()))?;
    Ok(Cia402Leg::new(
        plant,
        sensors,
        drives,
        LegForceNode {
            node: node(force.node_id)?,
            scale: force.scale,
        },
        dt,
    )
    .with_history(history))
}

/// Build the CiA 402 robot of the config; `history`: leg steps to keep (virtual transport).
pub fn rig<D: Dof<N>, const N: usize>(
    s: &Experiment,
    hw: &HardwareConfig,
    spin: Duration,
    history: usize,
) -> Result<Cia402Rig<N, D::Traj>, CliError>
where
    D::Traj: Send + 'static,
{
    let (joints, force) = parts::<N>(hw)?;
    let dt = Duration::from_secs_f64(s.timing.dt);
    let mut masters = Vec::with_capacity(N);
    for (name, j) in &joints {
        let cfg = j.master_config(dt).ok_or_else(|| {
            CliError::Config(format!("robot.joints.{name}.node_id: out of range"))
        })?;
        masters.push(Cia402Master::new(cfg));
    }
    let masters: [Cia402Master; N] = masters
        .try_into()
        .map_err(|_| CliError::Runtime("joint count".into()))?;
    let names = joints.clone().map(|(n, _)| n);
    let source = force
        .source()
        .ok_or_else(|| CliError::Config("robot.force_sensors[0].node_id: out of range".into()))?;
    let ms = |v: f64| Duration::from_secs_f64(v * 1e-3);
    let settings = |phase| Cia402RobotSettings {
        dt,
        sample_timeout: ms(hw.safety.reply_timeout_ms),
        stop_ramp: ms(hw.safety.stop_ramp_ms),
        limits: limits(s),
        phase,
    };
    match &hw.bus {
        BusConfig::Virtual(_) => {
            let leg = virtual_leg::<D, N>(s, hw, history)?;
            let bus = virtual_bus(hw, TimeBase::Real);
            let leg = Arc::new(Mutex::new(leg));
            bus.attach(leg.clone());
            let clock = AnyClock::Virtual(bus.clock());
            let robot = Cia402Robot::new(
                AnyBus::Virtual(bus.endpoint()),
                clock.clone(),
                masters,
                names,
                ForceReader::new(source),
                settings(Some(0.5)),
            );
            Ok(Cia402Rig {
                robot,
                clock,
                bus: Some(bus),
                leg: Some(leg),
                label: format!(
                    "virtual CAN bus at {} bit/s (CiA 402 drives)",
                    hw.bus.bitrate()
                ),
            })
        }
        hardware => {
            let (bus, label) = hardware_bus(hardware)?;
            let clock = AnyClock::Monotonic(MonotonicClock::new(spin));
            let robot = Cia402Robot::new(
                bus,
                clock.clone(),
                masters,
                names,
                ForceReader::new(source),
                settings(None),
            );
            Ok(Cia402Rig {
                robot,
                clock,
                bus: None,
                leg: None,
                label: format!("{label} (CiA 402 drives)"),
            })
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn hardware(text: &str) -> HardwareConfig {
        let (_, table) = exompc_can::config::split_hardware(text).unwrap();
        HardwareConfig::from_table(table.unwrap()).unwrap()
    }

    /// One position increment at the joint, the coarsest joint's: 4096 counts per motor turn
    /// behind the example's 50:1 gears, and 80 counts on the hip (1.57 mrad at the joint,
    /// which the frozen-angle test needs to know); none for the AK drives.
    #[test]
    fn the_encoder_step_is_one_increment_at_the_joint() {
        let text = include_str!("../../../examples/can-cia402-virtual.toml");
        let geared = encoder_step(&hardware(text)).unwrap();
        assert!((geared - std::f64::consts::TAU / (4096.0 * 50.0)).abs() < 1e-15);
        let coarse = text.replacen("counts_per_rev = 4096", "counts_per_rev = 80", 1);
        let coarse = encoder_step(&hardware(&coarse)).unwrap();
        assert!((coarse - std::f64::consts::TAU / (80.0 * 50.0)).abs() < 1e-15);
        let ak = include_str!("../../../examples/can-virtual.toml");
        assert_eq!(encoder_step(&hardware(ak)), None);
    }
}
