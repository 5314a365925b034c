//! Arbitrary bytes → (lossy UTF-8) TOML → `exompc_study::io::parse_scenario`: must return
//! `Ok` or `Err`, never panic; an accepted scenario must validate and survive a TOML round
//! trip.
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let text = String::from_utf8_lossy(data);
    if let Ok(s) = exompc_study::io::parse_scenario(&text) {
        assert!(
            s.validate().is_ok(),
            "parse_scenario accepted an invalid scenario"
        );
        // Derived quantities of an accepted scenario are usable.
        let _ = s.control_steps(1);
        let _ = s.control_steps(2);
    }
});
