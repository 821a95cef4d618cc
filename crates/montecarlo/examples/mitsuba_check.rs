//! Full-resolution comparison of the path tracer with the Mitsuba 3 references in
//! `tests/data/cloud24-*`: prints the relative RMS error over pixels above 1 % of the
//! maximum with both noises taken out, `err² = Σ[(x−r)² − s_r² − s_x²] / Σ r²`.
//!
//! `cargo run --release -p montecarlo --example mitsuba_check [spp] [block] [photons]`
//! (defaults: 256 spp, block 1 = per pixel; block 4 also compares 4×4 block means; with
//! `photons` > 0 the two-pass method is compared too: that many photons, one optical voxel
//! per cell, 1 direction bin for isotropic scattering and 12 × 24 otherwise, rendered with
//! 4 stratified samples per pixel; its own Monte Carlo noise is not taken out).

use std::path::PathBuf;
use std::time::Instant;

use gather::OpticalModel;
use gather::{read_pfm, render, Camera, ImageChannel, RenderOptions};
use montecarlo::{
    compare, energetize, path_trace_with_error, DirectionBins, EnergetizeOptions, NoisyImage,
    PathTraceOptions,
};
use scene::Scene;

fn grey(path: PathBuf) -> ImageChannel {
    let img = read_pfm(&path).expect("reference image");
    ImageChannel {
        width: img.width,
        height: img.height,
        pixels: img.pixels,
    }
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let spp: u32 = args.get(1).and_then(|s| s.parse().ok()).unwrap_or(256);
    let block: u32 = args.get(2).and_then(|s| s.parse().ok()).unwrap_or(1);
    let photons: u64 = args.get(3).and_then(|s| s.parse().ok()).unwrap_or(0);
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../tests/data");
    for name in ["cloud24-isotropic", "cloud24-anisotropic"] {
        let dir = root.join(name);
        let scene = Scene::from_file(&dir.join("scene.toml")).expect("scene");
        let reference = NoisyImage {
            mean: grey(dir.join("front.pfm")),
            std_error: grey(dir.join("front_stderr.pfm")),
        };
        let camera = Camera::from_spec(&scene.cameras[0]).expect("camera");
        let options = PathTraceOptions {
            spp,
            seed: 2024,
            ..Default::default()
        };
        let start = Instant::now();
        let out = path_trace_with_error(
            &scene.medium,
            0,
            &scene.lights,
            scene.background,
            &camera,
            &options,
        )
        .expect("render");
        let seconds = start.elapsed().as_secs_f64();
        let x = NoisyImage {
            mean: out.mean,
            std_error: out.std_error,
        };
        println!(
            "{name}: {}×{} at {spp} spp, {:.1} s ({:.3e} paths/s)",
            camera.width,
            camera.height,
            seconds,
            out.paths as f64 / seconds
        );
        let mut factors = vec![1];
        if block > 1 {
            factors.push(block);
        }
        let mut candidates = vec![("path trace", x)];
        if photons > 0 {
            let bins = if scene.medium.phase().is_isotropic() {
                DirectionBins::ISOTROPIC
            } else {
                DirectionBins {
                    n_theta: 12,
                    n_phi: 24,
                }
            };
            let options = EnergetizeOptions {
                photons_per_light: photons,
                seed: 2024,
                bins,
                ..Default::default()
            };
            let start = Instant::now();
            let sol = energetize(&scene.medium, 0, &scene.lights, &options, None).expect("solve");
            let solve = start.elapsed().as_secs_f64();
            let start = Instant::now();
            let render_options = RenderOptions {
                model: OpticalModel::Scattering,
                spp: 4,
                background: scene.background,
                ..Default::default()
            };
            let img = render(&scene.medium, 0, &camera, &render_options, &sol).expect("render");
            println!(
                "  two-pass: {photons} photons in {solve:.1} s, render {:.2} s, energy imbalance {:.2e}",
                start.elapsed().as_secs_f64(),
                sol.energy.relative_imbalance()
            );
            let zero = ImageChannel {
                pixels: vec![0.0; img.pixels.len()],
                ..img.clone()
            };
            candidates.push((
                "two-pass",
                NoisyImage {
                    mean: img,
                    std_error: zero,
                },
            ));
        }
        for (label, x) in &candidates {
            for &f in &factors {
                let (xb, rb) = (
                    x.block_average(f).unwrap(),
                    reference.block_average(f).unwrap(),
                );
                let c = compare(&xb, &rb, 0.01).expect("bright pixels");
                println!(
                "  {label}, {f}×{f} blocks: {} px above 1 % of max; relative RMS error (noise removed) {:.2} %; \
                 raw {:.2} %, noise {:.2} %; mean difference {:+.2} % ± {:.2} %; χ²/px {:.2}",
                c.pixels,
                100.0 * c.relative_rms_error,
                100.0 * c.relative_rms_raw,
                100.0 * c.relative_rms_noise,
                100.0 * c.relative_mean_difference,
                100.0 * c.relative_mean_std_error,
                c.chi2_per_pixel
            );
            }
        }
    }
}
