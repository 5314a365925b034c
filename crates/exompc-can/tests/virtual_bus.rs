//! The in-process virtual bus: timing, arbitration, faults, error states, simulated devices.

use exompc::runtime::Clock;
use exompc_can::{
    frame_time, BusError, BusState, CanBus, CanFrame, NodeTx, Stuffing, TimeBase, VirtualBus,
    VirtualBusSettings, VirtualNode,
};
use std::sync::{Arc, Mutex};
use std::time::Duration;

fn sim_bus(s: VirtualBusSettings) -> VirtualBus {
    VirtualBus::new(s, TimeBase::Simulated)
}

#[test]
fn a_frame_arrives_after_its_time_on_the_bus() {
    let bus = sim_bus(VirtualBusSettings::default());
    let mut a = bus.endpoint();
    let mut b = bus.endpoint();
    let f = CanFrame::standard(0x123, &[1, 2, 3, 4, 5, 6, 7, 8]).unwrap();
    a.send(&f).unwrap();
    let got = b.recv(Duration::from_millis(1)).unwrap();
    assert_eq!(got, Some(f));
    // 8 data bytes at 1 Mbit/s, worst-case stuffing: 135 µs.
    assert_eq!(bus.now(), Duration::from_micros(135));
    assert_eq!(
        frame_time(&f, 1_000_000, Stuffing::WorstCase),
        Duration::from_micros(135)
    );
    // The sender does not hear itself; nothing more arrives, and waiting moves time.
    assert_eq!(a.recv(Duration::from_millis(2)).unwrap(), None);
    assert_eq!(
        bus.now(),
        Duration::from_micros(135) + Duration::from_millis(2)
    );
    assert_eq!(a.counters().sent, 1);
    assert_eq!(b.counters().received, 1);
}

#[test]
fn the_lowest_identifier_wins_arbitration_and_frames_queue_back_to_back() {
    let bus = sim_bus(VirtualBusSettings {
        stuffing: Stuffing::Nominal,
        ..Default::default()
    });
    let mut a = bus.endpoint();
    let mut b = bus.endpoint();
    let mut c = bus.endpoint();
    // 0x300 is alone when it starts; 0x200 and 0x100 then wait for the bus.
    a.send(&CanFrame::standard(0x300, &[0; 8]).unwrap())
        .unwrap();
    a.send(&CanFrame::standard(0x200, &[0; 8]).unwrap())
        .unwrap();
    b.send(&CanFrame::standard(0x100, &[0; 8]).unwrap())
        .unwrap();
    let mut order = Vec::new();
    while let Some(f) = c.recv(Duration::from_millis(1)).unwrap() {
        order.push((f.id().raw(), bus.now()));
    }
    let us = Duration::from_micros;
    assert_eq!(
        order,
        vec![(0x300, us(111)), (0x100, us(222)), (0x200, us(333))]
    );
    let load = bus.load();
    assert_eq!(load.frames, 3);
    assert_eq!(load.busy, us(333));
}

#[test]
fn lost_frames_and_error_frames_are_counted() {
    let bus = sim_bus(VirtualBusSettings {
        loss: 1.0,
        ..Default::default()
    });
    let mut a = bus.endpoint();
    let mut b = bus.endpoint();
    for _ in 0..5 {
        a.send(&CanFrame::standard(1, &[1]).unwrap()).unwrap();
    }
    assert_eq!(b.recv(Duration::from_millis(5)).unwrap(), None);
    assert_eq!(b.counters().dropped, 5);
    assert_eq!(a.counters().dropped, 0);

    let bus = sim_bus(VirtualBusSettings {
        error_frames: 0.5,
        seed: 7,
        ..Default::default()
    });
    let mut a = bus.endpoint();
    let mut b = bus.endpoint();
    for i in 0..20u8 {
        a.send(&CanFrame::standard(1, &[i]).unwrap()).unwrap();
    }
    // Every frame arrives, in order, despite the error frames (retransmission).
    for i in 0..20u8 {
        let f = b.recv(Duration::from_millis(50)).unwrap().unwrap();
        assert_eq!(f.data(), &[i]);
    }
    let errors = b.counters().error_frames;
    assert!(errors > 0 && errors == a.counters().error_frames);
    assert_eq!(bus.load().error_frames, errors);
}

#[test]
fn injected_error_states() {
    let bus = sim_bus(VirtualBusSettings::default());
    let mut a = bus.endpoint();
    let mut b = bus.endpoint();
    bus.set_state(a.index(), BusState::ErrorPassive);
    assert_eq!(a.state(), BusState::ErrorPassive);
    a.send(&CanFrame::standard(1, &[]).unwrap()).unwrap();
    assert!(b.recv(Duration::from_millis(1)).unwrap().is_some());
    bus.set_state(a.index(), BusState::BusOff);
    assert!(matches!(
        a.send(&CanFrame::standard(1, &[]).unwrap()),
        Err(BusError::BusOff)
    ));
    assert_eq!(a.counters().send_errors, 1);
    b.send(&CanFrame::standard(2, &[]).unwrap()).unwrap();
    assert!(matches!(
        a.recv(Duration::from_millis(1)),
        Err(BusError::BusOff)
    ));
}

#[test]
fn a_full_receive_queue_drops_frames() {
    let bus = sim_bus(VirtualBusSettings {
        queue_capacity: 3,
        ..Default::default()
    });
    let mut a = bus.endpoint();
    let b = bus.endpoint();
    for _ in 0..5 {
        a.send(&CanFrame::standard(1, &[]).unwrap()).unwrap();
    }
    bus.advance_to(Duration::from_millis(1));
    assert_eq!(b.counters().received, 3);
    assert_eq!(b.counters().dropped, 2);
}

/// Answers every frame with id + 1 after 100 µs, and sends a tick every 1 ms.
struct Echo {
    next_tick: Duration,
}

impl VirtualNode for Echo {
    fn on_frame(&mut self, now: Duration, frame: &CanFrame, tx: &mut NodeTx) {
        let id = frame.id().raw() as u16 + 1;
        tx.send_at(
            now + Duration::from_micros(100),
            CanFrame::standard(id, frame.data()).unwrap(),
        );
    }
    fn next_wakeup(&self) -> Option<Duration> {
        Some(self.next_tick)
    }
    fn on_wakeup(&mut self, now: Duration, tx: &mut NodeTx) {
        tx.send_at(now, CanFrame::standard(0x700, &[]).unwrap());
        self.next_tick += Duration::from_millis(1);
    }
}

#[test]
fn simulated_devices_answer_at_their_bus_time() {
    let bus = sim_bus(VirtualBusSettings {
        stuffing: Stuffing::Nominal,
        ..Default::default()
    });
    let echo = Arc::new(Mutex::new(Echo {
        next_tick: Duration::from_millis(1),
    }));
    bus.attach(echo);
    let mut a = bus.endpoint();
    a.send(&CanFrame::standard(0x10, &[9]).unwrap()).unwrap();
    let f = a.recv(Duration::from_millis(5)).unwrap().unwrap();
    assert_eq!((f.id().raw(), f.data()), (0x11, &[9u8][..]));
    // 55 bits out, 100 µs in the device, 55 bits back.
    assert_eq!(bus.now(), Duration::from_micros(210));
    let mut clock = bus.clock();
    clock.sleep_until(Duration::from_micros(3500));
    assert_eq!(clock.now(), Duration::from_micros(3500));
    let mut ticks = 0;
    while let Some(f) = a.recv(Duration::ZERO).unwrap() {
        assert_eq!(f.id().raw(), 0x700);
        ticks += 1;
    }
    assert_eq!(ticks, 3);
}

#[test]
fn real_time_bus_across_threads() {
    let bus = VirtualBus::new(VirtualBusSettings::default(), TimeBase::Real);
    let mut a = bus.endpoint();
    let mut b = bus.endpoint();
    let t = std::thread::spawn(move || {
        let mut got = Vec::new();
        while got.len() < 10 {
            match b.recv(Duration::from_secs(5)).unwrap() {
                Some(f) => got.push(f.data()[0]),
                None => break,
            }
        }
        got
    });
    for i in 0..10u8 {
        a.send(&CanFrame::standard(0x42, &[i]).unwrap()).unwrap();
        std::thread::sleep(Duration::from_micros(200));
    }
    let got = t.join().unwrap();
    assert_eq!(got, (0..10).collect::<Vec<u8>>());
}
