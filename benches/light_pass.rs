//! Light-pass speed: one directional light (oblique, the built-in scene's direction) through
//! the generated 64×64×48 cloud (Max's cloud, seed 7, σt = 0.4 × density), default options
//! (4×4 rays per cell face, exact corner transmittance), the same with 2×2 rays per cell,
//! and an axis-aligned light (one ray per cell, exact). Run with `cargo bench --bench light_pass`.

use criterion::{criterion_group, criterion_main, Criterion};
use glam::DVec3;
use medium::generators::cloud;
use medium::light_pass::{LightPass, LightPassOptions};
use medium::{CellValues, ChannelMedium, Grid, Interpolation, Light, Medium, PhaseFunction};
// Benchmarks run with the product's allocator, which the volrad crate sets.
use volrad as _;

const SIGMA_T_SCALE: f32 = 0.4;

fn bench_light_pass(c: &mut Criterion) {
    let dims = [64, 64, 48];
    let grid = Grid::new(dims, 1.0).unwrap();
    let channel = ChannelMedium {
        sigma_t: cloud(dims, 7).iter().map(|d| d * SIGMA_T_SCALE).collect(),
        albedo: CellValues::Uniform(0.99),
        emission: CellValues::Uniform(0.0),
    };
    let medium = Medium::new(
        grid,
        vec![channel],
        PhaseFunction::Isotropic,
        Interpolation::Nearest,
        None,
    )
    .unwrap();
    let oblique = [Light::Directional {
        direction: DVec3::new(0.5, -1.0, 0.35),
        irradiance: 1.0,
    }];
    let axis = [Light::Directional {
        direction: DVec3::new(0.0, -1.0, 0.0),
        irradiance: 1.0,
    }];
    let mut group = c.benchmark_group("light_pass");
    group.sample_size(20);
    group.bench_function("cloud64x64x48_directional_oblique", |b| {
        b.iter(|| LightPass::compute(&medium, 0, &oblique).unwrap())
    });
    let coarse = LightPassOptions {
        rays_per_cell: 2,
        ..Default::default()
    };
    group.bench_function("cloud64x64x48_directional_oblique_2x2rays", |b| {
        b.iter(|| LightPass::compute_with(&medium, 0, &oblique, &coarse).unwrap())
    });
    group.bench_function("cloud64x64x48_directional_axis", |b| {
        b.iter(|| LightPass::compute(&medium, 0, &axis).unwrap())
    });
    group.finish();
}

criterion_group!(benches, bench_light_pass);
criterion_main!(benches);
