//! Procedural volumes from the seed papers, deterministic pure functions of `(dims, seed)`:
//! Max's (1995) cloud, a sum of ellipsoidal densities roughened by fractal Perlin noise, and
//! Blasi & Wuethrich's field magnitude of a magnetic dipole.
//!
//! Both return x-fastest values (`i + nx (j + ny k)`) with peak 1.0, to be scaled into σt by
//! the scene's `sigma_t_scale` or transfer function.

use glam::DVec3;
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// A generator as named in a scene's `[volume] generator = { kind = ... }`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Generator {
    Cloud { seed: u64 },
    Dipole,
}

impl Generator {
    pub fn generate(&self, dims: [usize; 3]) -> Vec<f32> {
        match *self {
            Generator::Cloud { seed } => cloud(dims, seed),
            Generator::Dipole => dipole(dims),
        }
    }
}

/// Seeded 3D gradient noise in the manner of Perlin (1985, with the 2002 quintic fade): a
/// shuffled permutation table picks one of twelve edge gradients per lattice point.
#[derive(Clone, Debug)]
pub struct GradientNoise {
    perm: [u8; 512],
}

const GRADIENTS: [[f64; 3]; 12] = [
    [1.0, 1.0, 0.0],
    [-1.0, 1.0, 0.0],
    [1.0, -1.0, 0.0],
    [-1.0, -1.0, 0.0],
    [1.0, 0.0, 1.0],
    [-1.0, 0.0, 1.0],
    [1.0, 0.0, -1.0],
    [-1.0, 0.0, -1.0],
    [0.0, 1.0, 1.0],
    [0.0, -1.0, 1.0],
    [0.0, 1.0, -1.0],
    [0.0, -1.0, -1.0],
];

impl GradientNoise {
    pub fn new(seed: u64) -> Self {
        let mut rng = Pcg64::seed_from_u64(seed ^ 0x9e37_79b9_7f4a_7c15);
        let mut p: [u8; 256] = std::array::from_fn(|i| i as u8);
        // Fisher–Yates with our own seeded generator, so the table is stable across rand versions.
        for i in (1..256).rev() {
            let j = rng.random_range(0..=i);
            p.swap(i, j);
        }
        let mut perm = [0u8; 512];
        for i in 0..512 {
            perm[i] = p[i & 255];
        }
        GradientNoise { perm }
    }

    #[inline]
    fn grad(&self, hash: u8, x: f64, y: f64, z: f64) -> f64 {
        let g = GRADIENTS[(hash % 12) as usize];
        g[0] * x + g[1] * y + g[2] * z
    }

    /// Noise in roughly `[-1, 1]`, zero at integer lattice points.
    pub fn noise(&self, p: DVec3) -> f64 {
        let f = p.floor();
        let (xi, yi, zi) = (
            (f.x as i64 & 255) as usize,
            (f.y as i64 & 255) as usize,
            (f.z as i64 & 255) as usize,
        );
        let (x, y, z) = (p.x - f.x, p.y - f.y, p.z - f.z);
        let fade = |t: f64| t * t * t * (t * (t * 6.0 - 15.0) + 10.0);
        let (u, v, w) = (fade(x), fade(y), fade(z));
        let pm = &self.perm;
        let a = pm[xi] as usize + yi;
        let (aa, ab) = (pm[a] as usize + zi, pm[a + 1] as usize + zi);
        let b = pm[xi + 1] as usize + yi;
        let (ba, bb) = (pm[b] as usize + zi, pm[b + 1] as usize + zi);
        let lerp = |t: f64, a: f64, b: f64| a + t * (b - a);
        lerp(
            w,
            lerp(
                v,
                lerp(
                    u,
                    self.grad(pm[aa], x, y, z),
                    self.grad(pm[ba], x - 1.0, y, z),
                ),
                lerp(
                    u,
                    self.grad(pm[ab], x, y - 1.0, z),
                    self.grad(pm[bb], x - 1.0, y - 1.0, z),
                ),
            ),
            lerp(
                v,
                lerp(
                    u,
                    self.grad(pm[aa + 1], x, y, z - 1.0),
                    self.grad(pm[ba + 1], x - 1.0, y, z - 1.0),
                ),
                lerp(
                    u,
                    self.grad(pm[ab + 1], x, y - 1.0, z - 1.0),
                    self.grad(pm[bb + 1], x - 1.0, y - 1.0, z - 1.0),
                ),
            ),
        )
    }

    /// Fractal sum of `octaves` octaves, each at twice the frequency and half the amplitude;
    /// normalised so the result stays in roughly `[-1, 1]`.
    pub fn fractal(&self, p: DVec3, octaves: u32) -> f64 {
        let (mut sum, mut amp, mut norm, mut freq) = (0.0, 1.0, 0.0, 1.0);
        for o in 0..octaves {
            // Offset each octave so lattice zeros do not line up.
            sum += amp * self.noise(p * freq + DVec3::splat(17.31 * o as f64));
            norm += amp;
            amp *= 0.5;
            freq *= 2.0;
        }
        sum / norm
    }
}

fn smoothstep(e0: f64, e1: f64, x: f64) -> f64 {
    let t = ((x - e0) / (e1 - e0)).clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}

fn normalise_peak(values: &mut [f32]) {
    let peak = values.iter().copied().fold(0.0f32, f32::max);
    if peak > 0.0 {
        let inv = 1.0 / peak;
        values.iter_mut().for_each(|v| *v *= inv);
    }
}

struct Ellipsoid {
    center: DVec3,
    radii: DVec3,
    weight: f64,
}

/// Max's cloud: a flattened body and 6–10 random ellipsoidal puffs with smooth `(1 − d²)²`
/// falloff, summed, with a flat cumulus base, then roughened by additive fractal gradient
/// noise so the edges break up; peak 1.0, and zero within
/// about two cells of the grid boundary so the cloud is isolated in its grid.
pub fn cloud(dims: [usize; 3], seed: u64) -> Vec<f32> {
    let n = dims[0] * dims[1] * dims[2];
    if n == 0 {
        return Vec::new();
    }
    let mut rng = Pcg64::seed_from_u64(seed);
    let extent = DVec3::new(dims[0] as f64, dims[1] as f64, dims[2] as f64);
    let min_extent = extent.min_element();
    // A cumulus: a wide, flattened body and 6–10 round puffs on and around it; sizes are
    // fractions of the grid, in cells.
    let mut ellipsoids = vec![Ellipsoid {
        center: extent * DVec3::new(0.5, 0.42, 0.5),
        radii: extent * DVec3::new(0.4, 0.2, 0.38),
        weight: 1.0,
    }];
    let puffs = rng.random_range(6..=10);
    for _ in 0..puffs {
        let center = extent
            * DVec3::new(
                0.5 + rng.random_range(-0.25..0.25),
                rng.random_range(0.45..0.62),
                0.5 + rng.random_range(-0.22..0.22),
            );
        let radius = min_extent * rng.random_range(0.17..0.28);
        let squash = DVec3::new(
            rng.random_range(0.85..1.25),
            rng.random_range(0.75..1.0),
            rng.random_range(0.85..1.25),
        );
        ellipsoids.push(Ellipsoid {
            center,
            radii: squash * radius,
            weight: rng.random_range(0.6..1.0),
        });
    }
    // The flat base typical of cumulus, a little below the body's centre.
    let base = extent.y * 0.3;
    let noise = GradientNoise::new(seed);
    // About four noise features across the smallest extent at the base octave.
    let base_frequency = 4.0 / min_extent;
    let noise_offset = DVec3::new(
        rng.random_range(0.0..64.0),
        rng.random_range(0.0..64.0),
        rng.random_range(0.0..64.0),
    );
    let margin = 2.0f64.min(min_extent * 0.25);

    let mut values: Vec<f32> = (0..n)
        .into_par_iter()
        .map(|idx| {
            let i = idx % dims[0];
            let j = (idx / dims[0]) % dims[1];
            let k = idx / (dims[0] * dims[1]);
            let p = DVec3::new(i as f64 + 0.5, j as f64 + 0.5, k as f64 + 0.5);
            let body: f64 = ellipsoids
                .iter()
                .map(|e| {
                    let d2 = ((p - e.center) / e.radii).length_squared();
                    if d2 < 1.0 {
                        e.weight * (1.0 - d2) * (1.0 - d2)
                    } else {
                        0.0
                    }
                })
                .sum();
            if body <= 0.0 {
                return 0.0;
            }
            let fbm = noise.fractal(p * base_frequency + noise_offset, 5);
            // Additive noise dominates where the body is thin (the edges, which break up into
            // fractal wisps) and only modulates the core.
            let density =
                (body + 0.55 * fbm - 0.1).max(0.0) * smoothstep(base - 1.0, base + 2.5, p.y);
            // Distance to the nearest grid face, in cells: fade to zero at the boundary.
            let to_face = p.min(extent - p).min_element();
            let window = smoothstep(margin, margin + 2.0, to_face);
            (density * window) as f32
        })
        .collect();
    normalise_peak(&mut values);
    values
}

/// Blasi & Wuethrich's dipole field: `|B| ∝ |3(m·r̂)r̂ − m| / (r² + ε²)^{3/2}` with `m` along
/// +y, centred in the grid (r in cells from the grid centre), softened with ε = 1.5 cells
/// (at least 4 % of the smallest extent); normalised to peak 1.
pub fn dipole(dims: [usize; 3]) -> Vec<f32> {
    let n = dims[0] * dims[1] * dims[2];
    if n == 0 {
        return Vec::new();
    }
    let extent = DVec3::new(dims[0] as f64, dims[1] as f64, dims[2] as f64);
    let center = extent * 0.5;
    let eps = 1.5f64.max(0.04 * extent.min_element());
    let m = DVec3::Y;
    let mut values: Vec<f32> = (0..n)
        .into_par_iter()
        .map(|idx| {
            let i = idx % dims[0];
            let j = (idx / dims[0]) % dims[1];
            let k = idx / (dims[0] * dims[1]);
            let r = DVec3::new(i as f64 + 0.5, j as f64 + 0.5, k as f64 + 0.5) - center;
            let r2 = r.length_squared();
            let angular = if r2 > 1e-24 {
                let rhat = r / r2.sqrt();
                (3.0 * m.dot(rhat) * rhat - m).length()
            } else {
                1.0
            };
            (angular / (r2 + eps * eps).powf(1.5)) as f32
        })
        .collect();
    normalise_peak(&mut values);
    values
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn noise_vanishes_on_lattice_and_is_bounded() {
        let noise = GradientNoise::new(3);
        let mut rng = Pcg64::seed_from_u64(1);
        for _ in 0..2000 {
            let p = DVec3::new(
                rng.random_range(-20.0..20.0),
                rng.random_range(-20.0..20.0),
                rng.random_range(-20.0..20.0),
            );
            let v = noise.noise(p);
            assert!(v.abs() <= 1.5, "noise {v} at {p}");
            assert!(noise.noise(p.floor()).abs() < 1e-12);
        }
    }

    #[test]
    fn noise_is_continuous() {
        let noise = GradientNoise::new(9);
        let p = DVec3::new(3.3, 7.7, 1.2);
        let d = DVec3::splat(1e-6);
        assert!((noise.noise(p) - noise.noise(p + d)).abs() < 1e-4);
    }
}
