//! SocketCAN on `vcan0` (feature `socketcan`, Linux). Where the kernel has no AF_CAN or no
//! `vcan0` (`ip link add dev vcan0 type vcan && ip link set up vcan0`), the test prints
//! `SKIPPED: no AF_CAN/vcan` and checks nothing else: run it with `--nocapture` to see which.
#![cfg(all(target_os = "linux", feature = "socketcan"))]

use exompc_can::socketcan_bus::SocketCanBus;
use exompc_can::{BusState, CanBus, CanFrame, CanId};
use std::time::Duration;

#[test]
fn frames_round_trip_on_vcan0() {
    let (mut a, mut b) = match (SocketCanBus::open("vcan0"), SocketCanBus::open("vcan0")) {
        (Ok(a), Ok(b)) => (a, b),
        (Err(e), _) | (_, Err(e)) => {
            println!("SKIPPED: no AF_CAN/vcan ({e})");
            eprintln!("SKIPPED: no AF_CAN/vcan ({e})");
            return;
        }
    };
    let frames = [
        CanFrame::standard(0x141, &[1, 2, 3, 4, 5, 6, 7, 8]).unwrap(),
        CanFrame::new(CanId::Extended(0x1234567), &[0xAA]).unwrap(),
        CanFrame::remote(CanId::Standard(0x7FF), 4).unwrap(),
    ];
    for f in &frames {
        a.send(f).unwrap();
        assert_eq!(b.recv(Duration::from_secs(1)).unwrap(), Some(*f));
    }
    assert_eq!(b.recv(Duration::from_millis(10)).unwrap(), None);
    assert_eq!((a.counters().sent, b.counters().received), (3, 3));
    assert_eq!(a.state(), BusState::ErrorActive);
}

#[test]
fn a_missing_interface_is_an_error() {
    assert!(SocketCanBus::open("nosuchcan9").is_err());
}
