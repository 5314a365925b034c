//! Helpers shared by the integration tests.
#![allow(dead_code)]

/// A tiny deterministic random generator (xorshift64*), so tests need no `rand`.
pub struct Rng(u64);

impl Rng {
    pub fn new(seed: u64) -> Self {
        Rng(seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1)
    }
    pub fn next_u64(&mut self) -> u64 {
        let mut x = self.0;
        x ^= x >> 12;
        x ^= x << 25;
        x ^= x >> 27;
        self.0 = x;
        x.wrapping_mul(0x2545_F491_4F6C_DD1D)
    }
    /// Uniform in [lo, hi).
    pub fn uniform(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * ((self.next_u64() >> 11) as f64 / (1u64 << 53) as f64)
    }
}

/// A value for property tests: mostly moderate, sometimes huge or non-finite.
pub fn value() -> impl proptest::strategy::Strategy<Value = f64> {
    use proptest::prelude::*;
    prop_oneof![
        8 => -5.0..5.0f64,
        2 => -1e4..1e4f64,
        1 => Just(f64::NAN),
        1 => Just(f64::INFINITY),
        1 => Just(f64::NEG_INFINITY),
        1 => any::<f64>(),
    ]
}

/// An arbitrary 2-DOF measurement built from [`value`]s.
pub fn measurement() -> impl proptest::strategy::Strategy<Value = exompc::control::Measurement<2>> {
    use proptest::prelude::*;
    prop::array::uniform6(value()).prop_map(|v| exompc::control::Measurement {
        t: 0.0,
        q: nalgebra::Vector2::new(v[0], v[1]),
        qd: nalgebra::Vector2::new(v[2], v[3]),
        force: nalgebra::Vector2::new(v[4], v[5]),
    })
}
