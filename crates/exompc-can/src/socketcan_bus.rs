//! Linux SocketCAN (feature `socketcan`): a real adapter (PEAK, Kvaser, CANable with gs_usb)
//! or `vcan`, through the `socketcan` crate. Error frames are enabled and read for the
//! controller's error state (error-passive, bus-off).

use crate::bus::{BusCounters, BusError, BusState, CanBus};
use crate::frame::{CanFrame, CanId};
use socketcan::{
    CanSocket, EmbeddedFrame, ExtendedId, Frame, Id, Socket, SocketOptions, StandardId,
};
use std::time::Duration;

/// Error-frame class: controller problem (data byte 1 has the details).
const ERR_CRTL: u32 = 0x0000_0004;
/// Error-frame class: bus-off.
const ERR_BUSOFF: u32 = 0x0000_0040;
/// Controller problem: receive or transmit error-passive.
const CRTL_PASSIVE: u8 = 0x10 | 0x20;
/// Controller problem: back to error-active.
const CRTL_ACTIVE: u8 = 0x40;
/// Error-frame class: the controller restarted after bus-off.
const ERR_RESTARTED: u32 = 0x0000_0100;

/// A SocketCAN interface as a [`CanBus`].
pub struct SocketCanBus {
    socket: CanSocket,
    counters: BusCounters,
    state: BusState,
}

impl SocketCanBus {
    /// Open `interface` (`can0`, `vcan0`); fails where the kernel has no AF_CAN or the
    /// interface does not exist.
    pub fn open(interface: &str) -> std::io::Result<Self> {
        let socket = CanSocket::open(interface)?;
        socket.set_error_filter_accept_all()?;
        Ok(SocketCanBus {
            socket,
            counters: BusCounters::default(),
            state: BusState::ErrorActive,
        })
    }

    fn error_frame(&mut self, class: u32, data: &[u8]) {
        self.counters.error_frames += 1;
        if class & ERR_BUSOFF != 0 {
            self.state = BusState::BusOff;
        } else if class & ERR_RESTARTED != 0 {
            self.state = BusState::ErrorActive;
        } else if class & ERR_CRTL != 0 {
            let d1 = data.get(1).copied().unwrap_or(0);
            if d1 & CRTL_PASSIVE != 0 {
                self.state = BusState::ErrorPassive;
            } else if d1 & CRTL_ACTIVE != 0 {
                self.state = BusState::ErrorActive;
            }
        }
    }
}

fn to_id(id: CanId) -> Option<Id> {
    Some(match id {
        CanId::Standard(v) => Id::Standard(StandardId::new(v)?),
        CanId::Extended(v) => Id::Extended(ExtendedId::new(v)?),
    })
}

impl CanBus for SocketCanBus {
    fn send(&mut self, frame: &CanFrame) -> Result<(), BusError> {
        if self.state == BusState::BusOff {
            self.counters.send_errors += 1;
            return Err(BusError::BusOff);
        }
        let id = to_id(frame.id()).ok_or(BusError::Closed)?;
        let f = if frame.is_remote() {
            socketcan::CanFrame::new_remote(id, frame.len())
        } else {
            socketcan::CanFrame::new(id, frame.data())
        };
        let Some(f) = f else {
            self.counters.send_errors += 1;
            return Err(BusError::Closed);
        };
        match self.socket.write_frame(&f) {
            Ok(()) => {
                self.counters.sent += 1;
                Ok(())
            }
            Err(e) => {
                self.counters.send_errors += 1;
                Err(BusError::Io(e))
            }
        }
    }

    fn recv(&mut self, timeout: Duration) -> Result<Option<CanFrame>, BusError> {
        let deadline = std::time::Instant::now() + timeout;
        loop {
            let left = deadline.saturating_duration_since(std::time::Instant::now());
            let f = match self
                .socket
                .read_frame_timeout(left.max(Duration::from_micros(1)))
            {
                Ok(f) => f,
                Err(e)
                    if matches!(
                        e.kind(),
                        std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
                    ) =>
                {
                    return Ok(None)
                }
                Err(e) => return Err(BusError::Io(e)),
            };
            if f.is_error_frame() {
                let class = f.id_word() & 0x1FFF_FFFF;
                let data = f.data().to_vec();
                self.error_frame(class, &data);
                continue;
            }
            let id = match f.id() {
                Id::Standard(s) => CanId::Standard(s.as_raw()),
                Id::Extended(x) => CanId::Extended(x.as_raw()),
            };
            let ours = if f.is_remote_frame() {
                CanFrame::remote(id, f.dlc())
            } else {
                CanFrame::new(id, f.data())
            };
            match ours {
                Ok(fr) => {
                    self.counters.received += 1;
                    return Ok(Some(fr));
                }
                Err(_) => self.counters.receive_errors += 1,
            }
        }
    }

    fn counters(&self) -> BusCounters {
        self.counters
    }

    fn state(&self) -> BusState {
        self.state
    }
}
