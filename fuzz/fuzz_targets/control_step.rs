//! Arbitrary bytes → a sequence of measurements (f64s decoded from the bytes: raw bit
//! patterns, i.e. NaN/±∞/huge/subnormal, or everyday scaled values) fed to the default
//! msnmpc (and its coupled formulation) and nmpc controllers (2-DOF), bare and under the
//! safety supervisor: every torque
//! must satisfy the limits relative to the previous one, and nothing may panic.
#![no_main]

use exompc::config::{ControllerKind, Formulation, Experiment};
use exompc::control::{Controller, Measurement};
use exompc::scenario::{build_controller, build_supervised, limits, TwoDof};
use libfuzzer_sys::fuzz_target;
use nalgebra::SVector;

/// Decodes one f64 per call: a tag byte selects raw bits (8 bytes) or a scaled i16 (2 bytes).
struct Bytes<'a>(&'a [u8]);

impl Bytes<'_> {
    fn take(&mut self, n: usize) -> Option<&[u8]> {
        if self.0.len() < n {
            return None;
        }
        let (a, b) = self.0.split_at(n);
        self.0 = b;
        Some(a)
    }
    fn f64(&mut self, scale: f64) -> Option<f64> {
        let tag = self.take(1)?[0];
        if tag % 5 == 0 {
            let b: [u8; 8] = self.take(8)?.try_into().ok()?;
            Some(f64::from_le_bytes(b))
        } else {
            let b: [u8; 2] = self.take(2)?.try_into().ok()?;
            Some(f64::from(i16::from_le_bytes(b)) / 32768.0 * scale)
        }
    }
    fn measurement(&mut self, k: usize) -> Option<Measurement<2>> {
        let mut v = [0.0; 6];
        let scales = [3.5, 3.5, 35.0, 35.0, 100.0, 100.0];
        for (x, s) in v.iter_mut().zip(scales) {
            *x = self.f64(s)?;
        }
        Some(Measurement {
            t: 0.01 * k as f64,
            q: SVector::from([v[0], v[1]]),
            qd: SVector::from([v[2], v[3]]),
            force: SVector::from([v[4], v[5]]),
        })
    }
}

const MAX_STEPS: usize = 64;

fuzz_target!(|data: &[u8]| {
    let s = Experiment::default();
    let mut coupled = Experiment::default();
    coupled.multistage.formulation = Formulation::Coupled;
    let lim = limits(&s);
    let mut ms: Vec<Box<dyn Controller<2>>> = Vec::new();
    for (s, kind) in [
        (&s, ControllerKind::MSNMPC),
        (&s, ControllerKind::NMPC),
        (&coupled, ControllerKind::MSNMPC),
    ] {
        ms.push(build_controller::<TwoDof, 2>(s, kind).unwrap());
        ms.push(Box::new(build_supervised::<TwoDof, 2>(s, kind).unwrap()));
    }
    let mut bytes = Bytes(data);
    for k in 0..MAX_STEPS {
        let Some(m) = bytes.measurement(k) else { break };
        for c in ms.iter_mut() {
            let prev = c.previous_torque();
            let out = c.step(&m);
            assert!(
                lim.admits(&prev, &out.torque),
                "{}: step {k}: {prev:?} -> {:?} ({:?}) from {m:?}",
                c.name(),
                out.torque,
                out.status
            );
            assert_eq!(c.previous_torque(), out.torque);
        }
    }
});
