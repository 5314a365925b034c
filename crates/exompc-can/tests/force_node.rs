//! The strap-force sensor: a virtual CiA 404-style node configured by SDO and read by SYNC,
//! its heartbeat loss, and the raw-frame option.

use exompc_can::canopen::sync::SyncProducer;
use exompc_can::canopen::NodeId;
use exompc_can::force_node::{
    ForceNodeEmulator, ForceNodeError, ForceSensor, ForceSource, RawField,
};
use exompc_can::{CanBus, CanFrame, CanId, TimeBase, VirtualBus, VirtualBusSettings};
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

#[test]
fn a_raw_amplifier_frame_is_decoded_by_its_fields() {
    let bus = VirtualBus::new(VirtualBusSettings::default(), TimeBase::Simulated);
    let mut amp = bus.endpoint();
    let mut ep = bus.endpoint();
    let field = |offset, big_endian| RawField {
        offset,
        size: 2,
        signed: true,
        big_endian,
        scale: 0.1,
        offset_n: 0.0,
    };
    let mut sensor = ForceSensor::new(ForceSource::Raw {
        id: CanId::Extended(0x18FF_1234),
        fields: [field(0, false), field(2, true)],
    });
    let mut d = [0u8; 4];
    d[..2].copy_from_slice(&(-123i16).to_le_bytes());
    d[2..].copy_from_slice(&456i16.to_be_bytes());
    amp.send(&CanFrame::new(CanId::Extended(0x18FF_1234), &d).unwrap())
        .unwrap();
    // Same number on a standard id: not the amplifier.
    amp.send(&CanFrame::standard(0x234, &d).unwrap()).unwrap();
    while let Some(f) = ep.recv(Duration::from_millis(1)).unwrap() {
        sensor.on_frame(&f, bus.now());
    }
    let s = sensor.take_sample().unwrap();
    assert!((s.thigh + 12.3).abs() < 1e-9 && (s.shank - 45.6).abs() < 1e-9);
    assert!(
        sensor.take_sample().is_none(),
        "the standard-id frame was not taken"
    );
    sensor.check(bus.now()).unwrap();
}
