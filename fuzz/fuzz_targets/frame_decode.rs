//! Arbitrary bytes → `exompc::runtime::decode` (1 and 2 joints) and the robot's end of an
//! authenticated session (`RobotLink`), before and after a handshake: must return `Ok` or a
//! counted `Err`, never panic; nothing without the key authenticates (a random frame with a
//! valid MAC would be a forgery); an accepted frame re-encodes to exactly the input bytes.
#![no_main]

use exompc::runtime::frame::encode_hello;
use exompc::runtime::{
    decode, encode_command, encode_sample, ControllerLink, Frame, Key, Psk, RejectCounts,
    RobotLink, RobotRx,
};
use libfuzzer_sys::fuzz_target;

fn check<const N: usize>(data: &[u8]) {
    let (hk, sk) = (Key::from_bytes([1; 32]), Key::from_bytes([2; 32]));
    let mut counts = RejectCounts::default();
    match decode::<N>(data, &hk, Some(&sk)) {
        Ok(Frame::Sample(s)) => {
            let mut v = Vec::new();
            encode_sample(&s, &sk, &mut v);
            assert_eq!(v, data, "sample does not re-encode to its bytes");
        }
        Ok(Frame::Command(c)) => {
            assert!(c.torque.iter().all(|t| t.is_finite()), "non-finite torque accepted");
            let mut v = Vec::new();
            encode_command(&c, &sk, &mut v);
            assert_eq!(v, data, "command does not re-encode to its bytes");
        }
        Ok(Frame::Hello(h)) => {
            let mut v = Vec::new();
            encode_hello::<N>(&h, &hk, &mut v);
            assert_eq!(v, data, "hello does not re-encode to its bytes");
        }
        Ok(Frame::Challenge(_)) => {}
        Err(e) => {
            counts.count(e);
            assert_eq!(counts.total(), 1);
        }
    }
}

/// The robot's link in a session with a legitimate controller: fuzzed datagrams (whole, or
/// spliced into a legitimate command) never authenticate.
fn session(data: &[u8]) {
    let psk = Psk::new(b"fuzz target key, thirty-two bytes or more").unwrap();
    let mut rob = RobotLink::<2>::new(psk.clone(), 100);
    let mut ctl = ControllerLink::<2>::new(psk, 100);
    let from = "127.0.0.1:1".parse().unwrap();
    assert_eq!(rob.receive(from, data, 0, &mut || Some([3; 32])), RobotRx::Nothing);
    ctl.start([4; 32]);
    let hello = ctl.hello(0).to_vec();
    rob.receive(from, &hello, 0, &mut || Some([5; 32]));
    let ch = rob.reply().to_vec();
    ctl.receive(&ch);
    let c = exompc::runtime::RobotCommand::new(0, 0, 0, 1, nalgebra::Vector2::zeros());
    let confirm = ctl.command(&c).to_vec();
    assert_eq!(rob.receive(from, &confirm, 0, &mut || None), RobotRx::Activated);
    let legit = ctl.command(&c).to_vec();
    let mut spliced = legit.clone();
    let n = spliced.len().min(data.len());
    spliced[..n].copy_from_slice(&data[..n]);
    if spliced != legit {
        let r = rob.receive(from, &spliced, 0, &mut || None);
        assert!(!matches!(r, RobotRx::Command(_)), "a spliced frame authenticated");
    }
    assert!(!matches!(
        rob.receive(from, data, 0, &mut || None),
        RobotRx::Command(_) | RobotRx::Activated
    ));
}

fuzz_target!(|data: &[u8]| {
    check::<1>(data);
    check::<2>(data);
    session(data);
});
