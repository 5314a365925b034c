//! Deterministic pseudo-random numbers for the unit tests (a 64-bit LCG).

/// Uniform numbers in `[−0.5, 0.5)` from the seed, reproducible across platforms.
pub(crate) fn lcg(seed: u64) -> impl FnMut() -> f64 {
    let mut state = seed;
    move || {
        state = state
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (state >> 11) as f64 / (1u64 << 53) as f64 - 0.5
    }
}
