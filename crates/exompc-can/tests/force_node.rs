//! The strap-force sensor: a virtual CiA 404-style node configured by SDO and read by SYNC,
//! and its heartbeat loss.

use exompc_can::canopen::sync::SyncProducer;
use exompc_can::canopen::NodeId;
use exompc_can::force_node::{ForceNodeEmulator, ForceNodeError, ForceSensor, ForceSource};
use exompc_can::{CanBus, TimeBase, VirtualBus, VirtualBusSettings};
use std::sync::{Arc, Mutex};
use std::time::Duration;

fn truth(t: Duration) -> (f64, f64) {
    let s = t.as_secs_f64();
    (40.0 * (6.0 * s).sin(), -25.0 + 10.0 * (4.0 * s).cos())
}

#[test]
fn a_canopen_force_node_is_configured_and_read_every_sync() {
    let bus = VirtualBus::new(VirtualBusSettings::default(), TimeBase::Simulated);
    let mut ep = bus.endpoint();
    let node = NodeId::new(20).unwrap();
    let scale = 0.01;
    let emu = Arc::new(Mutex::new(ForceNodeEmulator::new(
        node,
        scale,
        false,
        Box::new(truth),
    )));
    bus.attach(emu.clone());
    let mut sensor = ForceSensor::new(ForceSource::Canopen {
        node,
        cob_id: 0x1A0,
        scale,
        offset: [0.0, 0.0],
        configure: true,
        heartbeat: Some((Duration::from_millis(50), Duration::from_millis(150))),
    });
    let b = bus.clone();
    sensor.configure(&mut ep, &|| b.now()).unwrap();
    let mut sync = SyncProducer::new(Duration::from_millis(10), 0);
    let mut n = 0;
    for _ in 0..100 {
        let t_sync = bus.now();
        ep.send(&sync.emit()).unwrap();
        let end = t_sync + Duration::from_millis(10);
        while bus.now() < end {
            if let Some(f) = ep.recv(end - bus.now()).unwrap() {
                sensor.on_frame(&f, bus.now());
            }
        }
        sensor.check(bus.now()).unwrap();
        let s = sensor.take_sample().expect("one TPDO per SYNC");
        // Sampled when the SYNC arrived, within 200 µs of t_sync (its own frame, or a
        // heartbeat ahead of it): half a count plus 200 µs of the fastest change (240 N/s).
        let (a, b) = truth(t_sync);
        let tol = scale / 2.0 + 240.0 * 200e-6;
        assert!((s.thigh - a).abs() < tol, "{} vs {a}", s.thigh);
        assert!((s.shank - b).abs() < tol, "{} vs {b}", s.shank);
        n += 1;
    }
    assert_eq!(n, 100);
    emu.lock().unwrap().set_silent(true);
    let cut = bus.now();
    let err = loop {
        ep.recv(Duration::from_millis(10)).unwrap();
        if let Err(e) = sensor.check(bus.now()) {
            break e;
        }
        assert!(bus.now() - cut < Duration::from_millis(400));
    };
    assert!(matches!(err, ForceNodeError::HeartbeatLost { .. }), "{err}");
}
