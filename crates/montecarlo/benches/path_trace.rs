//! Path-tracer throughput on the generated 64×64×48 cloud (seed 7, σt = 0.4 × density:
//! column optical depths up to about 10, as in benches/render.rs), albedo 0.99, isotropic,
//! the reference scenes' light and view direction, 128×96 pixels × 4 paths. Criterion
//! reports paths per second (elements/s), every camera path counted.
//! Run with `cargo bench -p montecarlo --bench path_trace`.

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use gather::Camera;
use glam::DVec3;
use medium::generators::cloud;
use medium::{Grid, Light, Medium, PhaseFunction};
use montecarlo::{energetize, path_trace, EnergetizeOptions, PathTraceOptions};

fn cloud_medium() -> Medium {
    let dims = [64, 64, 48];
    let sigma_t: Vec<f32> = cloud(dims, 7).iter().map(|d| d * 0.4).collect();
    Medium::grey(
        Grid::new(dims, 1.0).unwrap(),
        sigma_t,
        0.99,
        PhaseFunction::Isotropic,
    )
    .unwrap()
}

fn bench(c: &mut Criterion) {
    let medium = cloud_medium();
    let lights = [Light::Directional {
        direction: DVec3::new(0.34954588533198816, 0.5492863912359816, -0.7590139224351744),
        irradiance: 1.0,
    }];
    let centre = DVec3::new(32.0, 32.0, 24.0);
    let eye = centre + DVec3::new(-15.42, -46.26, 16.448) * 1.5;
    let camera = Camera::perspective(eye, centre, DVec3::Z, 40.0, 128, 96).unwrap();
    let options = PathTraceOptions {
        spp: 4,
        seed: 1,
        ..Default::default()
    };
    let mut group = c.benchmark_group("path_trace");
    group.sample_size(10);
    group.throughput(Throughput::Elements(128 * 96 * 4));
    group.bench_function("cloud64x64x48_a0.99_128x96x4spp", |b| {
        b.iter(|| path_trace(&medium, 0, &lights, 0.0, &camera, &options).unwrap())
    });
    let photons = 1 << 17;
    group.throughput(Throughput::Elements(photons));
    group.bench_function("cloud64x64x48_a0.99_two_pass_energetize", |b| {
        let options = EnergetizeOptions {
            photons_per_light: photons,
            ..Default::default()
        };
        b.iter(|| energetize(&medium, 0, &lights, &options, None).unwrap())
    });
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
