//! Arbitrary bytes → `exompc::runtime::decode` (1 and 2 joints): must return `Ok` or a
//! counted `Err`, never panic; an accepted frame re-encodes to exactly the input bytes, and a
//! virtual robot offered an accepted command never panics either.
#![no_main]

use exompc::runtime::{decode, encode_command, encode_sample, Frame, RejectCounts};
use libfuzzer_sys::fuzz_target;

fn check<const N: usize>(data: &[u8]) {
    let mut counts = RejectCounts::default();
    match decode::<N>(data) {
        Ok(Frame::Sample(s)) => {
            let mut v = Vec::new();
            encode_sample(&s, &mut v);
            assert_eq!(v, data, "sample does not re-encode to its bytes");
        }
        Ok(Frame::Command(c)) => {
            assert!(c.torque.iter().all(|t| t.is_finite()), "non-finite torque accepted");
            let mut v = Vec::new();
            encode_command(&c, &mut v);
            assert_eq!(v, data, "command does not re-encode to its bytes");
        }
        Err(e) => {
            counts.count(e);
            assert_eq!(counts.total(), 1);
        }
    }
}

fuzz_target!(|data: &[u8]| {
    check::<1>(data);
    check::<2>(data);
});
