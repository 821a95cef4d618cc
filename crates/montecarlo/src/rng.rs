//! Deterministic random streams: one independent PCG stream per (seed, task index), so
//! results do not depend on the thread count or on scheduling.

use rand::SeedableRng;
use rand_pcg::Pcg64;

#[inline]
fn splitmix64(mut x: u64) -> u64 {
    x = x.wrapping_add(0x9E37_79B9_7F4A_7C15);
    x = (x ^ (x >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    x = (x ^ (x >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    x ^ (x >> 31)
}

/// The generator for task `index` (a pixel, a photon batch) of a run with `seed`. The two
/// numbers are hashed together before seeding so that neighbouring indices get unrelated
/// PCG states and streams (nearby PCG streams with equal state are correlated).
pub fn stream(seed: u64, domain: u64, index: u64) -> Pcg64 {
    let key = splitmix64(splitmix64(seed ^ splitmix64(domain)) ^ index);
    Pcg64::seed_from_u64(key)
}
