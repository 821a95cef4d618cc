//! The path tracer against the Mitsuba 3 references in `tests/data/cloud24-*` (repository
//! root), rendered cheaply at a quarter of the resolution: a 64×48 pixel is exactly the mean
//! of a 4×4 block of the 256×192 reference (a pixel is the mean over its area). The full
//! comparison is `cargo run --release -p montecarlo --example mitsuba_check`.

use std::path::PathBuf;

use gather::{read_pfm, Camera, ImageChannel};
use montecarlo::{compare, path_trace_with_error, NoisyImage, PathTraceOptions};
use scene::Scene;

fn data(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../tests/data")
        .join(name)
}

fn grey(path: PathBuf) -> ImageChannel {
    let img = read_pfm(&path).unwrap();
    assert_eq!(img.channels, 1);
    ImageChannel {
        width: img.width,
        height: img.height,
        pixels: img.pixels,
    }
}

fn check(name: &str, spp: u32) {
    let dir = data(name);
    let scene = Scene::from_file(&dir.join("scene.toml")).unwrap();
    let reference = NoisyImage {
        mean: grey(dir.join("front.pfm")),
        std_error: grey(dir.join("front_stderr.pfm")),
    };
    let reference = reference.block_average(4).unwrap();
    let mut spec = scene.cameras[0].clone();
    spec.width /= 4;
    spec.height /= 4;
    let camera = Camera::from_spec(&spec).unwrap();
    let options = PathTraceOptions {
        spp,
        seed: 1,
        ..Default::default()
    };
    let out = path_trace_with_error(
        &scene.medium,
        0,
        &scene.lights,
        scene.background,
        &camera,
        &options,
    )
    .unwrap();
    let x = NoisyImage {
        mean: out.mean,
        std_error: out.std_error,
    };
    let c = compare(&x, &reference, 0.01).unwrap();
    eprintln!("{name}: {c:?}");
    assert!(c.pixels > 300, "{name}: only {} bright pixels", c.pixels);
    // The image mean over the bright region within 4 combined standard errors.
    assert!(
        c.relative_mean_difference.abs() < 4.0 * c.relative_mean_std_error,
        "{name}: mean differs by {:.4} ± {:.4}",
        c.relative_mean_difference,
        c.relative_mean_std_error
    );
    // Pixel by pixel, the differences are noise: χ²/pixel near 1 (a bias of a few per cent
    // anywhere in the image would push it well above 2 at this noise level). Needs enough
    // paths per pixel for the sample variance to be trusted: at 64 spp a silhouette pixel
    // whose paths all missed the cloud reports zero error and dominates χ².
    assert!(
        c.chi2_per_pixel < 1.6,
        "{name}: χ²/pixel {}",
        c.chi2_per_pixel
    );
}

#[test]
fn agrees_with_mitsuba_isotropic() {
    check("cloud24-isotropic", 512);
}

#[test]
fn agrees_with_mitsuba_anisotropic() {
    check("cloud24-anisotropic", 1024);
}
