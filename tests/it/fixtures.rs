//! What several test modules share: the `volrad` binary, the repository root, path text.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// Runs the `volrad` binary built for these tests.
pub fn volrad(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_volrad"))
        .args(args)
        .output()
        .expect("the volrad binary runs")
}

pub fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// A path as an argument.
pub fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// The repository's root (the root crate's manifest directory).
pub fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// Per pixel `i` of channel `c` of `image`: `(i, value, reference, its standard error)`.
pub fn pixels_against<'a>(
    image: &'a gather::Image,
    c: usize,
    traced: &'a montecarlo::path_trace::PathTraced,
) -> impl Iterator<Item = (usize, f64, f64, f64)> + 'a {
    let n = image.channels as usize;
    traced
        .mean
        .pixels
        .iter()
        .zip(&traced.std_error.pixels)
        .enumerate()
        .map(move |(i, (&r, &e))| (i, image.pixels[n * i + c] as f64, r as f64, e as f64))
}

/// Relative RMS (the reference's noise taken out), relative mean difference and pixel count
/// of channel `c` of `image` against `traced` over the pixels `counts(i, reference)` selects.
pub fn masked_error(
    image: &gather::Image,
    c: usize,
    traced: &montecarlo::path_trace::PathTraced,
    counts: impl Fn(usize, f64) -> bool,
) -> (f64, f64, usize) {
    let (mut err2, mut ref2, mut diff, mut sum, mut count) = (0.0, 0.0, 0.0, 0.0, 0);
    for (i, x, r, e) in pixels_against(image, c, traced) {
        if counts(i, r) {
            err2 += (x - r).powi(2) - e * e;
            ref2 += r * r;
            diff += x - r;
            sum += r;
            count += 1;
        }
    }
    ((err2.max(0.0) / ref2).sqrt(), diff / sum, count)
}

/// The path tracer's view of channel `c` of `scene` through its first camera (`spp` paths per
/// pixel), with its per-pixel standard error.
pub fn path_traced(scene: &scene::Scene, c: usize, spp: u32) -> montecarlo::path_trace::PathTraced {
    path_traced_view(scene, &scene.cameras[0], c, spp)
}

/// [`path_traced`] through `camera`.
pub fn path_traced_view(
    scene: &scene::Scene,
    camera: &scene::CameraSpec,
    c: usize,
    spp: u32,
) -> montecarlo::path_trace::PathTraced {
    path_traced_with(
        scene,
        camera,
        c,
        &montecarlo::PathTraceOptions {
            spp,
            ..Default::default()
        },
    )
}

/// [`path_traced_view`] with `options` (next-event estimation toward emitters, seeds).
pub fn path_traced_with(
    scene: &scene::Scene,
    camera: &scene::CameraSpec,
    c: usize,
    options: &montecarlo::PathTraceOptions,
) -> montecarlo::path_trace::PathTraced {
    use montecarlo::path_trace::{path_trace_with_error, Surroundings};
    let camera = gather::Camera::from_spec(camera).unwrap();
    path_trace_with_error(
        &scene.medium,
        c,
        &scene.lights,
        Surroundings {
            background: scene.background,
            environment: scene.environment.clone(),
            ground: scene.ground,
        },
        &camera,
        options,
    )
    .unwrap()
}
