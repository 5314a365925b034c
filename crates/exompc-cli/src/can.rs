//! The CAN robot of `exompc run --config` and `exompc virtual-robot --config`: reads the
//! hardware keys of `[robot]` (see `exompc_can::config`) and builds the bus, the drives, the
//! virtual devices with the simulated leg, and the [`CanRobot`].

use crate::error::CliError;
use exompc::config::Experiment;
use exompc::runtime::{Clock, MonotonicClock};
use exompc::scenario::{limits, plant_params, uncertainty, Dof};
use exompc::sim::{Plant, Sensors};
use exompc_can::ak::AkDrive;
use exompc_can::config::{BusConfig, ForceSensor, HardwareConfig, Joint, RawForceSensor};
use exompc_can::emulator::{AkEmulator, Mount, VirtualLeg};
use exompc_can::robot::{CanRobot, CanRobotSettings};
use exompc_can::{
    BusCounters, BusError, BusState, CanBus, CanFrame, TimeBase, VirtualBus, VirtualBusSettings,
    VirtualClock, VirtualEndpoint,
};
use std::path::Path;
use std::sync::{Arc, Mutex};
use std::time::Duration;

/// The hardware keys of the scenario file at `path` (`None`: no file, or no hardware keys).
pub fn hardware_of(path: Option<&Path>) -> Result<Option<HardwareConfig>, CliError> {
    let Some(path) = path else {
        return Ok(None);
    };
    let text = std::fs::read_to_string(path).map_err(|e| {
        CliError::Config(format!("cannot read config file {}: {e}", path.display()))
    })?;
    let bad = |e: exompc_can::config::ConfigError| {
        CliError::Config(format!("config file {}: {e}", path.display()))
    };
    let (_, hw) = exompc_can::config::split_hardware(&text).map_err(bad)?;
    hw.map(HardwareConfig::from_table).transpose().map_err(bad)
}

/// The joints of an `N`-DOF run: hip and knee, or the knee alone.
fn joints<const N: usize>(hw: &HardwareConfig) -> [(&'static str, &Joint); N] {
    let all = hw.joints.iter();
    std::array::from_fn(|i| all[i + 2 - N])
}

/// The drives of the joints.
pub fn drives<const N: usize>(
    hw: &HardwareConfig,
) -> Result<([AkDrive; N], [&'static str; N]), CliError> {
    let js = joints::<N>(hw);
    let mut out = Vec::with_capacity(N);
    for (name, j) in js {
        let Joint::Ak(a) = j else {
            return Err(CliError::Config(format!(
                "robot.joints.{name}.driver: every joint must be \"ak\" when one is"
            )));
        };
        out.push(AkDrive::new(a).ok_or_else(|| {
            CliError::Config(format!(
                "robot.joints.{name}.model: unknown model {:?}",
                a.model
            ))
        })?);
    }
    let drives: [AkDrive; N] = out
        .try_into()
        .map_err(|_| CliError::Runtime("joint count".into()))?;
    Ok((drives, js.map(|(n, _)| n)))
}

/// The raw force sensors.
pub fn force_sensors(hw: &HardwareConfig) -> Vec<RawForceSensor> {
    hw.force_sensors
        .iter()
        .filter_map(|f| match f {
            ForceSensor::Raw(r) => Some(r.clone()),
            ForceSensor::Canopen(_) => None,
        })
        .collect()
}

/// The robot's timing and safety from the scenario and `[robot.safety]`.
pub fn settings(s: &Experiment, hw: &HardwareConfig, phase: Option<f64>) -> CanRobotSettings {
    let ms = |v: f64| Duration::from_secs_f64(v * 1e-3);
    CanRobotSettings {
        dt: Duration::from_secs_f64(s.timing.dt),
        ready_timeout: ms(hw.safety.ready_timeout_ms),
        reply_timeout: ms(hw.safety.reply_timeout_ms),
        stop_ramp: ms(hw.safety.stop_ramp_ms),
        limits: limits(s),
        phase,
    }
}

/// The simulated leg behind virtual AK motors and the first raw force node, as the config
/// describes them; it keeps a record of `history` plant steps (0: none).
pub fn virtual_leg<D: Dof<N>, const N: usize>(
    s: &Experiment,
    hw: &HardwareConfig,
    history: usize,
) -> Result<VirtualLeg<N, D::Traj>, CliError>
where
    D::Traj: Send,
{
    s.check_trajectory(D::DOF)
        .map_err(|e| CliError::Config(e.to_string()))?;
    let plant = Plant::new(plant_params::<D, N>(s), D::trajectory(s));
    let sensors = Sensors::new(uncertainty(s), s.uncertainty.filter_window).with_faults(&s.faults);
    let js = joints::<N>(hw);
    let mut motors = Vec::with_capacity(N);
    let mut mounts = Vec::with_capacity(N);
    for (name, j) in js {
        let Joint::Ak(a) = j else {
            return Err(CliError::Config(format!(
                "robot.joints.{name}.driver: every joint must be \"ak\" when one is"
            )));
        };
        let ranges = a.ranges().ok_or_else(|| {
            CliError::Config(format!(
                "robot.joints.{name}.model: unknown model {:?}",
                a.model
            ))
        })?;
        motors.push(AkEmulator::new(
            a.can_id.min(0x7F) as u8,
            a.reply_id.min(0x7FF) as u16,
            ranges,
        ));
        mounts.push(Mount {
            direction: if a.direction < 0 { -1.0 } else { 1.0 },
            gear_ratio: a.gear_ratio,
            zero_offset: a.zero_offset_rad,
        });
    }
    let nodes = force_sensors(hw);
    if nodes.is_empty() {
        return Err(CliError::Config(
            "robot.force_sensors: a virtual robot needs a raw force node".into(),
        ));
    }
    let latency = match &hw.bus {
        BusConfig::Virtual(v) => Duration::from_micros(u64::from(v.device_latency_us)),
        _ => Duration::from_micros(100),
    };
    let motors: [AkEmulator; N] = motors
        .try_into()
        .map_err(|_| CliError::Runtime("joint count".into()))?;
    let mounts: [Mount; N] = mounts
        .try_into()
        .map_err(|_| CliError::Runtime("joint count".into()))?;
    let leg = VirtualLeg::new(
        plant,
        sensors,
        motors,
        mounts,
        nodes,
        Duration::from_secs_f64(s.timing.dt),
        latency,
    );
    Ok(if history > 0 {
        leg.with_history(history)
    } else {
        leg
    })
}

/// A virtual bus for the config (`transport = "virtual"` settings, or the defaults).
pub fn virtual_bus(hw: &HardwareConfig, time: TimeBase) -> VirtualBus {
    let mut settings = VirtualBusSettings::default();
    if let BusConfig::Virtual(v) = &hw.bus {
        settings.bitrate = v.bitrate;
        settings.loss = v.loss;
        settings.error_frames = v.error_frames;
        settings.seed = v.seed;
    } else {
        settings.bitrate = hw.bus.bitrate();
    }
    VirtualBus::new(settings, time)
}

/// The bus of a CAN run: the in-process virtual bus, an slcan adapter, or a SocketCAN interface.
pub enum AnyBus {
    /// An endpoint of the in-process virtual bus.
    Virtual(VirtualEndpoint),
    /// An slcan adapter on a serial port (or a pty of `exompc virtual-robot --config`).
    #[cfg(unix)]
    Slcan(exompc_can::SlcanBus<exompc_can::FdPort>),
    /// A Linux SocketCAN interface (feature `socketcan`).
    #[cfg(all(target_os = "linux", feature = "socketcan"))]
    SocketCan(exompc_can::socketcan_bus::SocketCanBus),
}

impl CanBus for AnyBus {
    fn send(&mut self, frame: &CanFrame) -> Result<(), BusError> {
        match self {
            AnyBus::Virtual(b) => b.send(frame),
            #[cfg(unix)]
            AnyBus::Slcan(b) => b.send(frame),
            #[cfg(all(target_os = "linux", feature = "socketcan"))]
            AnyBus::SocketCan(b) => b.send(frame),
        }
    }

    fn recv(&mut self, timeout: Duration) -> Result<Option<CanFrame>, BusError> {
        match self {
            AnyBus::Virtual(b) => b.recv(timeout),
            #[cfg(unix)]
            AnyBus::Slcan(b) => b.recv(timeout),
            #[cfg(all(target_os = "linux", feature = "socketcan"))]
            AnyBus::SocketCan(b) => b.recv(timeout),
        }
    }

    fn counters(&self) -> BusCounters {
        match self {
            AnyBus::Virtual(b) => b.counters(),
            #[cfg(unix)]
            AnyBus::Slcan(b) => b.counters(),
            #[cfg(all(target_os = "linux", feature = "socketcan"))]
            AnyBus::SocketCan(b) => b.counters(),
        }
    }

    fn state(&self) -> BusState {
        match self {
            AnyBus::Virtual(b) => b.state(),
            #[cfg(unix)]
            AnyBus::Slcan(b) => b.state(),
            #[cfg(all(target_os = "linux", feature = "socketcan"))]
            AnyBus::SocketCan(b) => b.state(),
        }
    }
}

/// The clock of a CAN run: the virtual bus's, or the OS clock.
#[derive(Clone)]
pub enum AnyClock {
    /// The virtual bus's clock.
    Virtual(VirtualClock),
    /// The OS monotonic clock.
    Monotonic(MonotonicClock),
}

impl Clock for AnyClock {
    fn now(&self) -> Duration {
        match self {
            AnyClock::Virtual(c) => c.now(),
            AnyClock::Monotonic(c) => c.now(),
        }
    }

    fn sleep_until(&mut self, t: Duration) {
        match self {
            AnyClock::Virtual(c) => c.sleep_until(t),
            AnyClock::Monotonic(c) => c.sleep_until(t),
        }
    }
}

/// Opens the hardware bus of `robot.bus` (slcan, or SocketCAN in a Linux build with the
/// feature `socketcan`) for the AK and the CiA 402 robots alike, with a label for messages
/// (`slcan /dev/ttyACM0 at 1000000 bit/s`, `SocketCAN can0`). The virtual transport is built
/// with its simulated leg by each robot's `rig`; here it, and a transport this build lacks,
/// is a configuration error.
pub fn hardware_bus(bus: &BusConfig) -> Result<(AnyBus, String), CliError> {
    match bus {
        #[cfg(unix)]
        BusConfig::Slcan(sl) => {
            let port = exompc_can::FdPort::open(Path::new(&sl.port)).map_err(|e| {
                CliError::io(
                    format!("opening the slcan port {} (robot.bus.port)", sl.port),
                    e,
                )
            })?;
            let bus = exompc_can::SlcanBus::open(port, sl.bitrate)
                .map_err(|e| CliError::Runtime(format!("slcan adapter at {}: {e}", sl.port)))?;
            Ok((
                AnyBus::Slcan(bus),
                format!("slcan {} at {} bit/s", sl.port, sl.bitrate),
            ))
        }
        #[cfg(all(target_os = "linux", feature = "socketcan"))]
        BusConfig::Socketcan(sc) => {
            let bus =
                exompc_can::socketcan_bus::SocketCanBus::open(&sc.interface).map_err(|e| {
                    CliError::io(
                        format!(
                            "opening SocketCAN interface {} (robot.bus.interface)",
                            sc.interface
                        ),
                        e,
                    )
                })?;
            Ok((
                AnyBus::SocketCan(bus),
                format!("SocketCAN {}", sc.interface),
            ))
        }
        BusConfig::Virtual(_) => Err(CliError::Config(
            "robot.bus.transport: \"virtual\" has no hardware bus to open".into(),
        )),
        #[allow(unreachable_patterns)]
        _ => Err(CliError::Config(
            "robot.bus.transport: \"socketcan\" needs a Linux build with the feature \
             `socketcan` (cargo build --release --features exompc-cli/socketcan); available \
             here: \"virtual\", \"slcan\""
                .into(),
        )),
    }
}

/// A CAN robot with its clock, and for the virtual transport the bus and the simulated leg.
pub struct CanRig<const N: usize, Tr: exompc::sim::Trajectory<N>> {
    /// The robot.
    pub robot: CanRobot<N, AnyBus, AnyClock>,
    /// The loop's clock (the robot's clock).
    pub clock: AnyClock,
    /// The virtual bus (virtual transport).
    pub bus: Option<VirtualBus>,
    /// The simulated leg (virtual transport).
    pub leg: Option<Arc<Mutex<VirtualLeg<N, Tr>>>>,
    /// What the robot is, for messages (`virtual CAN bus`, `slcan /dev/ttyACM0`).
    pub label: String,
}

/// Build the robot of the config. `payload` (kg) is for the virtual devices only.
pub fn rig<D: Dof<N>, const N: usize>(
    s: &Experiment,
    hw: &HardwareConfig,
    spin: Duration,
    history: usize,
) -> Result<CanRig<N, D::Traj>, CliError>
where
    D::Traj: Send + 'static,
{
    let (drives, names) = drives::<N>(hw)?;
    let sensors = force_sensors(hw);
    match &hw.bus {
        BusConfig::Virtual(_) => {
            let bus = virtual_bus(hw, TimeBase::Real);
            let leg = Arc::new(Mutex::new(virtual_leg::<D, N>(s, hw, history)?));
            bus.attach(leg.clone());
            let clock = AnyClock::Virtual(bus.clock());
            let robot = CanRobot::new(
                AnyBus::Virtual(bus.endpoint()),
                clock.clone(),
                drives,
                names,
                sensors,
                settings(s, hw, Some(0.5)),
            );
            Ok(CanRig {
                robot,
                clock,
                bus: Some(bus),
                leg: Some(leg),
                label: format!("virtual CAN bus at {} bit/s", hw.bus.bitrate()),
            })
        }
        hardware => {
            let (bus, label) = hardware_bus(hardware)?;
            let clock = AnyClock::Monotonic(MonotonicClock::new(spin));
            let robot = CanRobot::new(
                bus,
                clock.clone(),
                drives,
                names,
                sensors,
                settings(s, hw, None),
            );
            Ok(CanRig {
                robot,
                clock,
                bus: None,
                leg: None,
                label,
            })
        }
    }
}
