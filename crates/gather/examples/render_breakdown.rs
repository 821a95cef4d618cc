//! Where a scattering render's time goes, for the two renders the floors are about: the load
//! test's 24×24×18 cloud (sub-cell first bounce) and `data/cloud.toml` (cell corners). For each:
//! how many pixels, rays reaching the grid and occupied cell segments there are, and the best
//! of N one-thread render times with the first bounce and with a constant source of the same
//! bound (which costs the traversal and compositing alone), and the time to build the render
//! index that each of those renders builds first.
//!
//!   cargo run --release -p gather --example render_breakdown [renders]

use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Instant;

use gather::light_depth::{LightDepth, LightDepthModel};
use gather::single_scatter::{SingleScatter, SingleScatterOptions};
use gather::OpticalModel;
use gather::{render, Camera, InScattering, RayCarry, RenderIndex, RenderOptions, ViewSegment};
use glam::DVec3;
use medium::generators::cloud;
use medium::light_pass::LightPass;
use medium::{Grid, Interpolation, Light, Medium, PhaseFunction};
use scene::Scene;

/// A source that counts the segments it is asked about.
struct Counted<'a> {
    inner: &'a dyn InScattering,
    segments: AtomicUsize,
}

impl InScattering for Counted<'_> {
    fn segment(&self, seg: &ViewSegment, carry: &mut RayCarry) -> f64 {
        self.segments.fetch_add(1, Ordering::Relaxed);
        self.inner.segment(seg, carry)
    }
    fn at(&self, x: DVec3, cell: usize, w: DVec3) -> f64 {
        self.inner.at(x, cell, w)
    }
    fn max_source(&self) -> f64 {
        self.inner.max_source()
    }
}

/// The same value everywhere: the render's cost without the first bounce. No bound is given,
/// so rays stop only where the transmittance vanishes, as they do with the first bounce in
/// these thin clouds (the segment counts printed agree).
struct Constant(f64);

impl InScattering for Constant {
    fn segment(&self, seg: &ViewSegment, _: &mut RayCarry) -> f64 {
        self.0 * seg.weight
    }
    fn at(&self, _: DVec3, _: usize, _: DVec3) -> f64 {
        self.0
    }
}

fn breakdown(name: &str, medium: &Medium, lights: &[Light], camera: &Camera, renders: usize) {
    let pass = LightPass::compute(medium, 0, lights).unwrap();
    let depth = LightDepthModel::build(&pass, LightDepth::Auto).unwrap();
    let first =
        SingleScatter::with_depth_model(medium, 0, &pass, SingleScatterOptions::default(), &depth)
            .unwrap();
    let options = RenderOptions {
        model: OpticalModel::Scattering,
        ..RenderOptions::default()
    };
    let one_thread = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap();
    let best = |source: &dyn InScattering| {
        (0..renders)
            .map(|_| {
                let start = Instant::now();
                one_thread.install(|| render(medium, 0, camera, &options, source).unwrap());
                start.elapsed().as_secs_f64() * 1e3
            })
            .fold(f64::INFINITY, f64::min)
    };
    let count = |inner: &dyn InScattering| {
        let counted = Counted {
            inner,
            segments: AtomicUsize::new(0),
        };
        render(medium, 0, camera, &options, &counted).unwrap();
        counted.segments.load(Ordering::Relaxed)
    };
    let constant_source = Constant(first.max_source());
    let (segments, constant_segments) = (count(&first), count(&constant_source));
    let reaching = (0..camera.height)
        .flat_map(|y| (0..camera.width).map(move |x| (x, y)))
        .filter(|&(x, y)| {
            let ray = camera.ray(x as f64 + 0.5, y as f64 + 0.5);
            medium.grid().clip(&ray, 0.0, f64::INFINITY).is_some()
        })
        .count();
    // What a solution keeps and a one-off render builds first (serial in part).
    let index_ms = (0..renders)
        .map(|_| {
            let start = Instant::now();
            std::hint::black_box(RenderIndex::new(medium, 0, options.model).unwrap());
            start.elapsed().as_secs_f64() * 1e3
        })
        .fold(f64::INFINITY, f64::min);
    let with_first = best(&first);
    let constant = best(&constant_source);
    println!("{name}: light depth {depth:?}");
    println!(
        "  {} pixels, {reaching} rays reach the grid, {segments} occupied cell segments \
         ({constant_segments} with the constant source)",
        camera.width * camera.height
    );
    println!(
        "  one thread, best of {renders}: {with_first:.1} ms with the first bounce, \
         {constant:.1} ms with a constant source: the first bounce costs {:.0} ns per segment",
        (with_first - constant) * 1e6 / segments as f64
    );
    println!("  building the render index (each render above includes it): {index_ms:.2} ms");
}

fn main() {
    let renders = std::env::args()
        .nth(1)
        .and_then(|n| n.parse().ok())
        .unwrap_or(30);

    // The load test's cloud and one of its views (benches/render.rs: service).
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
    let centre = medium.grid().extent() * 0.5;
    let (radius, angle) = (2.5 * 24.0, 0.5f64);
    let eye = centre + DVec3::new(radius * angle.sin(), -radius * angle.cos(), 0.3 * radius);
    let camera = Camera::perspective(eye, centre, DVec3::Z, 40.0, 512, 384).unwrap();
    breakdown(
        "load test cloud 24×24×18",
        &medium,
        &lights,
        &camera,
        renders,
    );

    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../data/cloud.toml");
    let scene = Scene::from_file(&root).unwrap();
    let camera = Camera::from_spec(scene.camera("front").unwrap()).unwrap();
    // The per-cell segments counted here are the `nearest` render's (the scene is drawn
    // `trilinear`, which samples in fixed steps instead).
    let medium = scene
        .medium
        .clone()
        .with_interpolation(Interpolation::Nearest);
    breakdown(
        "data/cloud.toml 64×64×48",
        &medium,
        &scene.lights,
        &camera,
        renders.div_ceil(3),
    );
}
