//! slcan end to end over a pseudo-terminal: exompc's host side ([`SlcanBus`]) talks to its
//! adapter side ([`SlcanAdapter`]) in front of the virtual bus, as to a CANable.
#![cfg(unix)]

use exompc_can::{
    BusState, CanBus, CanFrame, CanId, FdPort, NodeTx, Port, Pty, SlcanAdapter, SlcanBus, TimeBase,
    VirtualBus, VirtualBusSettings, VirtualNode,
};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

/// Answers a frame (extended, or standard below 0x700) with id + 1 and the bytes reversed, 50 µs later.
struct Echo;

impl VirtualNode for Echo {
    fn on_frame(&mut self, now: Duration, f: &CanFrame, tx: &mut NodeTx) {
        if f.id().is_extended() || f.id().raw() < 0x700 {
            let mut d = f.data().to_vec();
            d.reverse();
            let id = match f.id() {
                CanId::Standard(i) => CanId::Standard(i + 1),
                CanId::Extended(i) => CanId::Extended(i + 1),
            };
            tx.send_at(
                now + Duration::from_micros(50),
                CanFrame::new(id, &d).unwrap(),
            );
        }
    }
}

struct Served {
    pty: Pty,
    bus: VirtualBus,
    stop: Arc<AtomicBool>,
    thread: Option<std::thread::JoinHandle<exompc_can::AdapterCounters>>,
    adapter_ep: usize,
}

impl Served {
    fn start() -> Served {
        let pty = Pty::open().unwrap();
        let bus = VirtualBus::new(VirtualBusSettings::default(), TimeBase::Real);
        bus.attach(Arc::new(Mutex::new(Echo)));
        let ep = bus.endpoint();
        let adapter_ep = ep.index();
        let master = pty.master().unwrap();
        let stop = Arc::new(AtomicBool::new(false));
        let s2 = stop.clone();
        let thread = std::thread::spawn(move || {
            let mut a = SlcanAdapter::new(ep, master, 1_000_000);
            while !s2.load(Ordering::Relaxed) {
                a.serve(Duration::from_micros(200)).unwrap();
            }
            a.counters()
        });
        Served {
            pty,
            bus,
            stop,
            thread: Some(thread),
            adapter_ep,
        }
    }

    fn finish(mut self) -> exompc_can::AdapterCounters {
        self.stop.store(true, Ordering::Relaxed);
        self.thread.take().unwrap().join().unwrap()
    }
}

#[test]
fn frames_go_both_ways_through_the_pty() {
    let served = Served::start();
    let mut other = served.bus.endpoint();
    let mut host = SlcanBus::open(FdPort::open(served.pty.path()).unwrap(), 1_000_000).unwrap();
    let frames = [
        CanFrame::standard(0x141, &[1, 2, 3, 4, 5, 6, 7, 8]).unwrap(),
        CanFrame::new(CanId::Extended(0x1234567), &[0xAA]).unwrap(),
        CanFrame::standard(0x010, &[]).unwrap(),
    ];
    for f in &frames {
        host.send(f).unwrap();
        // Another node on the bus sees the host's frame ...
        assert_eq!(other.recv(Duration::from_secs(2)).unwrap(), Some(*f));
        // ... and the device's answer comes back through the adapter.
        let back = host.recv(Duration::from_secs(2)).unwrap().unwrap();
        assert_eq!(back.id().raw(), f.id().raw() + 1);
        assert_eq!(back.id().is_extended(), f.id().is_extended());
        let mut d = f.data().to_vec();
        d.reverse();
        assert_eq!(back.data(), &d[..]);
        // The echo of the answer reaches `other` too.
        assert!(other.recv(Duration::from_secs(2)).unwrap().is_some());
    }
    // A frame from another node reaches the host.
    let from_other = CanFrame::standard(0x701, &[7]).unwrap();
    other.send(&from_other).unwrap();
    assert_eq!(host.recv(Duration::from_secs(2)).unwrap(), Some(from_other));
    assert_eq!(host.poll_status().unwrap(), Some(0));
    served
        .bus
        .set_state(served.adapter_ep, BusState::ErrorPassive);
    assert_eq!(
        host.poll_status().unwrap(),
        Some(exompc_can::slcan::STATUS_ERROR_PASSIVE)
    );
    assert_eq!(host.state(), BusState::ErrorPassive);
    served.bus.set_state(served.adapter_ep, BusState::BusOff);
    host.poll_status().unwrap();
    assert_eq!(host.state(), BusState::BusOff);
    assert!(host.send(&frames[0]).is_err());
    let c = host.counters();
    assert_eq!((c.sent, c.received, c.receive_errors), (3, 4, 0));
    let port = host.close().unwrap();
    drop(port);
    let a = served.finish();
    assert_eq!(a.to_bus, 3);
    // The one refusal: the `C` the host sends first, to a channel that was closed.
    assert_eq!(a.refused, 1);
}

#[test]
fn the_adapter_refuses_what_a_real_one_refuses() {
    let served = Served::start();
    // 500 kbit/s on a 1 Mbit/s bus: `O` is refused, the open fails.
    let err = SlcanBus::open(FdPort::open(served.pty.path()).unwrap(), 500_000);
    assert!(err.is_err());
    // Raw lines: a frame while closed, a malformed frame, an unknown command, S9.
    let mut port = FdPort::open(served.pty.path()).unwrap();
    let mut answers = Vec::new();
    // Bytes read and not yet taken, and the frames that came from the bus meanwhile: the
    // node's answer to the frame sent arrives whenever it does, also within a later answer.
    let mut pending: Vec<u8> = Vec::new();
    let mut from_bus = Vec::new();
    let mut buf = [0u8; 64];
    for line in [
        "C\r",
        "t1230\r",
        "S8\r",
        "O\r",
        "t12\r",
        "Q\r",
        "S9\r",
        "S6\r",
        "t1231AA\r",
        "V\r",
    ] {
        port.write_all_timeout(line.as_bytes(), Duration::from_secs(1))
            .unwrap();
        // The answer: the first token (ending in \r or BEL) that is not a received frame.
        let answer = loop {
            if let Some(end) = pending.iter().position(|&b| b == b'\r' || b == 7) {
                let token: Vec<u8> = pending.drain(..=end).collect();
                let token = String::from_utf8_lossy(&token).into_owned();
                if token.len() > 1 && token.starts_with(['t', 'T', 'r', 'R']) {
                    from_bus.push(token);
                    continue;
                }
                break token;
            }
            let n = port.read_timeout(&mut buf, Duration::from_secs(2)).unwrap();
            assert!(n > 0, "no answer to {line:?}");
            pending.extend_from_slice(&buf[..n]);
        };
        answers.push(answer);
    }
    // The node's answer to the one frame that reached the bus (id + 1, bytes reversed).
    while from_bus.is_empty() && !pending.ends_with(b"\r") {
        let n = port.read_timeout(&mut buf, Duration::from_secs(2)).unwrap();
        assert!(n > 0, "no frame from the bus");
        pending.extend_from_slice(&buf[..n]);
    }
    from_bus.extend(
        String::from_utf8_lossy(&pending)
            .split_inclusive('\r')
            .map(str::to_owned),
    );
    assert_eq!(from_bus, ["t1241AA\r"]);
    let bel = "\u{7}";
    // The first `C` may close a channel the failed open left closed: BEL.
    assert_eq!(
        answers[1..],
        [bel, "\r", "\r", bel, bel, bel, bel, "z\r", "V1013\r"]
    );
    let a = served.finish();
    assert_eq!(a.to_bus, 1);
}
