//! Render speed: the generated 64×64×48 cloud (Max's cloud, seed 7) at 512×384, 1 sample per
//! pixel, exact per-cell segments: emission + absorption (the particle model, emission = σt),
//! and the scattering renders of `data/cloud.toml` (first bounce from the light pass, alone
//! and with a stored per-cell multiple-scattering source as a zonal solution supplies it), and
//! the table the emitters' first scattering is drawn with and its binned cells' cost per view.
//! Run with `cargo bench --bench render`.

use criterion::{criterion_group, criterion_main, Criterion};
use gather::{render, Camera, RenderOptions};
use glam::DVec3;
use medium::generators::cloud;
use medium::{CellValues, ChannelMedium, Grid, Interpolation, Medium, PhaseFunction};
use scene::OpticalModel;

/// σt = 0.4 × density (peak 0.4 per cell): column optical depths up to roughly 10, like the
/// reference clouds.
const SIGMA_T_SCALE: f32 = 0.4;

fn cloud_medium(interpolation: Interpolation) -> Medium {
    let dims = [64, 64, 48];
    let sigma_t: Vec<f32> = cloud(dims, 7).iter().map(|d| d * SIGMA_T_SCALE).collect();
    let emission = CellValues::PerCell(sigma_t.clone());
    Medium::new(
        Grid::new(dims, 1.0).unwrap(),
        vec![ChannelMedium {
            sigma_t,
            albedo: CellValues::Uniform(0.0),
            emission,
        }],
        PhaseFunction::Isotropic,
        interpolation,
        None,
    )
    .unwrap()
}

fn camera() -> Camera {
    // The direction of the reference scenes' view (tests/data/cloud24-*), close enough
    // that the cloud fills most of the frame.
    let centre = DVec3::new(32.0, 32.0, 24.0);
    let eye = centre + DVec3::new(-15.42, -46.26, 16.448) * 1.5;
    Camera::perspective(eye, centre, DVec3::Z, 40.0, 512, 384).unwrap()
}

fn bench_render(c: &mut Criterion) {
    let cam = camera();
    let opts = RenderOptions {
        model: OpticalModel::EmissionAbsorption,
        spp: 1,
        ..RenderOptions::default()
    };
    let mut group = c.benchmark_group("render");
    group.sample_size(30);
    let nearest = cloud_medium(Interpolation::Nearest);
    group.bench_function("cloud64x64x48_512x384_nearest", |b| {
        b.iter(|| render(&nearest, 0, &cam, &opts, &()).unwrap())
    });
    let trilinear = cloud_medium(Interpolation::Trilinear);
    group.bench_function("cloud64x64x48_512x384_trilinear", |b| {
        b.iter(|| render(&trilinear, 0, &cam, &opts, &()).unwrap())
    });
    group.finish();
}

/// The scattering renders of `data/cloud.toml`'s front camera. The higher-order source is
/// the zonal first-pass source `E` standing in for a solved `g − E`: a render's cost does not
/// depend on the values it reads.
fn bench_scattering_render(c: &mut Criterion) {
    use gather::single_scatter::{SingleScatter, SingleScatterOptions};
    use medium::light_pass::LightPass;
    use scene::Scene;

    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    let scene = Scene::from_file(&root.join("data/cloud.toml")).unwrap();
    // Exact per-cell segments, as measured since #3 (the scene itself is drawn `trilinear`).
    let medium = &scene
        .medium
        .clone()
        .with_interpolation(Interpolation::Nearest);
    let pass = LightPass::compute(medium, 0, &scene.lights).unwrap();
    let spec = scene.camera("front").unwrap();
    let cam = Camera::from_spec(spec).unwrap();
    let opts = RenderOptions {
        model: OpticalModel::Scattering,
        spp: 1,
        background: scene.background,
        ..RenderOptions::default()
    };
    let first = SingleScatter::new(medium, 0, &pass, SingleScatterOptions::default()).unwrap();
    let higher: Vec<f32> = pass
        .zonal_source(medium, 0)
        .unwrap()
        .iter()
        .map(|&v| v as f32)
        .collect();
    // Drawn as a solution of this `nearest` medium draws it: smooth light, each cell's mean
    // kept.
    let scattering = volrad::engine::solution::InverseScattering::of_channel(medium, 0);
    let solution = (
        SingleScatter::new(medium, 0, &pass, SingleScatterOptions::default()).unwrap(),
        volrad::engine::sources::CellSource::new(
            &higher,
            volrad::engine::sources::CellLattice::of_own_grid(medium, 0, &scattering),
        ),
    );
    let mut group = c.benchmark_group("render");
    group.sample_size(20);
    // A solution keeps its render index (ChannelSolution::render_cache), as it keeps the
    // first bounce's light-depth model built inside `SingleScatter::new` above.
    let index = gather::RenderIndex::new(medium, 0, opts.model).unwrap();
    group.bench_function("cloud_toml_512x384_single_scatter", |b| {
        b.iter(|| gather::render_indexed(medium, &cam, &opts, &first, &index).unwrap())
    });
    group.bench_function("cloud_toml_512x384_zonal_solution", |b| {
        b.iter(|| gather::render_indexed(medium, &cam, &opts, &solution, &index).unwrap())
    });
    group.finish();
}

/// One request of the service load test (`examples/load_test.rs`): its 24×24×18 cloud (σt
/// peak 0.6, albedo 0.95, isotropic), a zonal-style solution, a 512×384 view from its orbit
/// (single-threaded, as each of the service's render slots runs). Cells this coarse need the
/// first bounce's sub-cell lattice (`LightDepth::Auto` picks refinement 2).
fn bench_service_render(c: &mut Criterion) {
    use gather::light_depth::{LightDepth, LightDepthModel};
    use gather::single_scatter::{SingleScatter, SingleScatterOptions};
    use medium::light_pass::LightPass;
    use medium::Light;

    let dims = [24, 24, 18];
    let sigma_t: Vec<f32> = cloud(dims, 7).iter().map(|d| d * 0.6).collect();
    let medium = Medium::grey(
        Grid::new(dims, 1.0).unwrap(),
        sigma_t,
        0.95,
        PhaseFunction::Isotropic,
    )
    .unwrap();
    let lights = [Light::Directional {
        direction: DVec3::new(0.5, -1.0, 0.35).normalize(),
        irradiance: 1.0,
    }];
    let pass = LightPass::compute(&medium, 0, &lights).unwrap();
    let depth = LightDepthModel::build(&pass, LightDepth::Auto).unwrap();
    let higher: Vec<f32> = pass
        .zonal_source(&medium, 0)
        .unwrap()
        .iter()
        .map(|&v| v as f32)
        .collect();
    let first =
        SingleScatter::with_depth_model(&medium, 0, &pass, SingleScatterOptions::default(), &depth)
            .unwrap();
    let scattering = volrad::engine::solution::InverseScattering::of_channel(&medium, 0);
    let solution = (
        first,
        volrad::engine::sources::CellSource::new(
            &higher,
            volrad::engine::sources::CellLattice::of_own_grid(&medium, 0, &scattering),
        ),
    );
    let centre = medium.grid().extent() * 0.5;
    let radius = 2.5 * 24.0;
    let angle = 0.5f64;
    let eye = centre + DVec3::new(radius * angle.sin(), -radius * angle.cos(), 0.3 * radius);
    let cam = Camera::perspective(eye, centre, DVec3::Z, 40.0, 512, 384).unwrap();
    let opts = RenderOptions {
        model: OpticalModel::Scattering,
        ..RenderOptions::default()
    };
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap();
    let mut group = c.benchmark_group("render");
    group.sample_size(20);
    let index = gather::RenderIndex::new(&medium, 0, opts.model).unwrap();
    group.bench_function("service_cloud24_512x384_one_thread", |b| {
        b.iter(|| {
            pool.install(|| {
                gather::render_indexed(&medium, &cam, &opts, &solution, &index).unwrap()
            })
        })
    });
    group.finish();
}

/// The table a render of discrete ordinates' emitters' first scattering draws with
/// (`ShapeScattering`): built on a solution's first render and kept in its render cache.
fn bench_shape_table(c: &mut Criterion) {
    let mut group = c.benchmark_group("render");
    for g in [0.85, 0.95] {
        let phase = PhaseFunction::HenyeyGreenstein { g };
        group.bench_function(format!("emitter_shape_table_g{g}"), |b| {
            b.iter(|| phase.shape_scattering())
        });
    }
    // A view's value of each cell whose emitted light is kept in direction bins: 1000 cells
    // lit from a hemisphere (half the bins), on one thread.
    let table = PhaseFunction::HenyeyGreenstein { g: 0.85 }.shape_scattering();
    let bins = medium::phase::DirectionBins::incident();
    let mut row = vec![0.0f32; medium::phase::BINNED_VALUES * bins.len()];
    for k in 0..bins.len() {
        let d = bins.direction(k);
        if d.z > 0.0 {
            let share = 2.0 / bins.len() as f32;
            row[4 * k] = share;
            row[4 * k + 1] = share * d.x as f32 * 0.99;
            row[4 * k + 2] = share * d.y as f32 * 0.99;
            row[4 * k + 3] = share * d.z as f32 * 0.99;
        }
    }
    group.bench_function("emitter_binned_1000_cells_g0.85", |b| {
        b.iter(|| {
            (0..1000)
                .map(|i| {
                    let a = i as f64 * 0.01;
                    table.eval_binned(&row, DVec3::new(a.cos(), a.sin(), 0.0))
                })
                .sum::<f64>()
        })
    });
    group.finish();
}

criterion_group!(
    benches,
    bench_render,
    bench_scattering_render,
    bench_service_render,
    bench_shape_table
);
criterion_main!(benches);
