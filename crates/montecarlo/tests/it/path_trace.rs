//! The path tracer against closed forms: absorption only, the single-scattering slab, the
//! infinite emitting medium; plus determinism and refused inputs.

use gather::Camera;
use glam::DVec3;
use medium::{CellValues, ChannelMedium, Grid, Interpolation, Light, Medium, PhaseFunction};
use montecarlo::{path_trace, path_trace_with_error, MonteCarloError, PathTraceOptions};

/// A heterogeneous 8×8×4 medium with σt from a fixed hash, so every column has its own depth.
fn columns(albedo: f32) -> Medium {
    let grid = Grid::new([8, 8, 4], 1.0).unwrap();
    let sigma_t: Vec<f32> = (0..grid.cell_count())
        .map(|i| ((i as u64 * 2654435761) % 1000) as f32 / 1000.0 * 0.6)
        .collect();
    Medium::grey(grid, sigma_t, albedo, PhaseFunction::Isotropic).unwrap()
}

/// The image's mean radiance and its standard error (the pixels' errors in quadrature).
fn image_mean(t: &montecarlo::PathTraced) -> (f64, f64) {
    let n = t.mean.pixels.len() as f64;
    let mean = t.mean.pixels.iter().map(|&v| v as f64).sum::<f64>() / n;
    let variance: f64 = t.std_error.pixels.iter().map(|&s| (s as f64).powi(2)).sum();
    (mean, variance.sqrt() / n)
}

/// Orthographic camera looking down −z whose 8×8 pixels are exactly the grid's columns.
fn top_camera() -> Camera {
    Camera::orthographic(
        DVec3::new(4.0, 4.0, 10.0),
        DVec3::new(4.0, 4.0, 0.0),
        DVec3::Y,
        8.0,
        8,
        8,
    )
    .unwrap()
}

#[test]
fn absorption_only_is_the_transmittance_image() {
    let medium = columns(0.0);
    let options = PathTraceOptions {
        spp: 400,
        seed: 3,
        ..Default::default()
    };
    let out = path_trace_with_error(&medium, 0, &[], 1.0, &top_camera(), &options).unwrap();
    let ch = &medium.channels()[0];
    let mut checked_se = 0;
    for py in 0..8u32 {
        for px in 0..8u32 {
            let (i, j) = (px as usize, 7 - py as usize);
            let tau: f64 = (0..4)
                .map(|k| ch.sigma_t[medium.grid().index(i, j, k)] as f64)
                .sum();
            let t = (-tau).exp();
            // Each path is a Bernoulli trial with mean T: its exact standard error.
            let sigma = (t * (1.0 - t) / 400.0).sqrt();
            let got = out.mean.get(px, py) as f64;
            assert!(
                (got - t).abs() <= 4.5 * sigma + 1e-9,
                "pixel ({px},{py}): {got} vs {t}"
            );
            if (0.2..0.8).contains(&t) {
                let se = out.std_error.get(px, py) as f64;
                assert!(
                    (se / sigma - 1.0).abs() < 0.2,
                    "stderr {se} vs exact {sigma}"
                );
                checked_se += 1;
            }
        }
    }
    assert!(checked_se > 10);
}

/// Single scattering off a homogeneous slab seen from the lit side, against
/// `I = a E0 p(Θ) μ0/(μ0+μ) (1 − e^{−τ(1/μ0+1/μ)})`. Returns (estimate, its standard error,
/// the closed form).
fn slab_reflection(albedo: f32, g: f64, max_depth: Option<u32>, spp: u32) -> (f64, f64, f64) {
    let (sigma_t, thickness) = (0.3f32, 2usize);
    let grid = Grid::new([40, 40, thickness], 1.0).unwrap();
    let phase = PhaseFunction::HenyeyGreenstein { g };
    let medium = Medium::homogeneous(grid, sigma_t, albedo, 0.0, phase).unwrap();
    let theta0 = 40f64.to_radians();
    let light_dir = DVec3::new(theta0.sin(), 0.0, -theta0.cos());
    let lights = [Light::Directional {
        direction: light_dir,
        irradiance: 2.0,
    }];
    let view = DVec3::new(0.3, 0.25, -0.9).normalize();
    let target = DVec3::new(20.0, 20.0, 2.0);
    let camera = Camera::orthographic(target - view * 30.0, target, DVec3::Z, 2.0, 4, 4).unwrap();
    let options = PathTraceOptions {
        spp,
        seed: 11,
        max_depth,
        ..Default::default()
    };
    let out = path_trace_with_error(&medium, 0, &lights, 0.0, &camera, &options).unwrap();
    let (mean, se) = image_mean(&out);
    let (mu0, mu) = (theta0.cos(), -view.z);
    let tau = sigma_t as f64 * thickness as f64;
    let p = phase.eval(light_dir.dot(-view));
    let exact =
        albedo as f64 * 2.0 * p * mu0 / (mu0 + mu) * (1.0 - (-tau * (1.0 / mu0 + 1.0 / mu)).exp());
    (mean, se, exact)
}

#[test]
fn single_scattering_slab_matches_the_closed_form() {
    // Backward scattering with a forward-peaked HG lobe: checks the direction convention too.
    for g in [0.0, 0.6, -0.5] {
        let (got, se, exact) = slab_reflection(0.9, g, Some(1), 256);
        assert!(
            (got - exact).abs() < 4.0 * se,
            "g = {g}: {got} ± {se} vs closed form {exact}"
        );
        assert!(
            se < 0.02 * exact,
            "g = {g}: noise {se} too large to test {exact}"
        );
    }
}

#[test]
fn low_albedo_slab_approaches_single_scattering() {
    // At albedo 0.02 the higher orders add well under 2 % (they scale with a²).
    let (got, se, exact) = slab_reflection(0.02, 0.3, None, 256);
    assert!(
        got >= exact - 4.0 * se,
        "{got} ± {se} below single scattering {exact}"
    );
    assert!(
        ((got - exact) / exact).abs() < 0.02 + 4.0 * se / exact,
        "{got} vs {exact}"
    );
}

#[test]
fn infinite_emitting_medium_reaches_e_over_absorption() {
    // σt = 2, a = 0.5: the centre is 24 mean free paths from the edges, so the radiance is
    // e / (σt (1 − a)) = 1 up to a leak of order exp(−24·√(3·0.5)).
    let grid = Grid::new([24, 24, 24], 1.0).unwrap();
    let medium = Medium::homogeneous(grid, 2.0, 0.5, 1.0, PhaseFunction::Isotropic).unwrap();
    let centre = grid.center();
    let camera = Camera::perspective(
        centre,
        centre + DVec3::new(1.0, 0.3, 0.2),
        DVec3::Z,
        90.0,
        4,
        4,
    )
    .unwrap();
    let options = PathTraceOptions {
        spp: 1024,
        seed: 5,
        ..Default::default()
    };
    let out = path_trace_with_error(&medium, 0, &[], 0.0, &camera, &options).unwrap();
    let (mean, se) = image_mean(&out);
    assert!(
        (mean - 1.0).abs() < 4.0 * se && se < 0.01,
        "{mean} ± {se} vs 1"
    );
}

#[test]
fn point_and_spot_lights_follow_inverse_square_and_cone() {
    // Single scattering of a point light 4 below a 4-deep column, seen from above through a
    // pencil-thin orthographic image: light and view paths together always cross the whole
    // column once, so I = σs/(4π) · J · e^{−4σt} · ∫_4^8 dr/r² = σs J e^{−4σt} / (32π).
    let grid = Grid::new([4, 4, 4], 1.0).unwrap();
    let sigma_t: f64 = 0.05;
    let medium =
        Medium::homogeneous(grid, sigma_t as f32, 1.0, 0.0, PhaseFunction::Isotropic).unwrap();
    let camera = Camera::orthographic(
        DVec3::new(2.0, 2.0, 20.0),
        DVec3::new(2.0, 2.0, 0.0),
        DVec3::Y,
        0.01,
        2,
        2,
    )
    .unwrap();
    let position = DVec3::new(2.0, 2.0, -4.0);
    let intensity = 3.0;
    let options = PathTraceOptions {
        spp: 4000,
        seed: 9,
        max_depth: Some(1),
        ..Default::default()
    };
    let render = |light: Light| {
        let out = path_trace_with_error(&medium, 0, &[light], 0.0, &camera, &options).unwrap();
        image_mean(&out)
    };
    let exact = sigma_t * intensity * (-4.0 * sigma_t).exp() / (32.0 * std::f64::consts::PI);
    let (point, se) = render(Light::Point {
        position,
        intensity,
    });
    assert!(
        (point - exact).abs() < 4.0 * se && se < 0.03 * exact,
        "{point} ± {se} vs {exact}"
    );
    let spot = |axis: DVec3| Light::Spot {
        position,
        axis,
        half_angle: 0.3,
        intensity,
    };
    let (lit, se) = render(spot(DVec3::Z));
    assert!(
        (lit - exact).abs() < 4.0 * se,
        "spot toward the grid: {lit} ± {se} vs {exact}"
    );
    let (dark, _) = render(spot(-DVec3::Z));
    assert_eq!(dark, 0.0, "spot facing away lights nothing");
}

#[test]
fn same_seed_same_image_for_any_thread_count() {
    let medium = columns(0.8);
    let lights = [Light::Directional {
        direction: DVec3::new(0.2, 0.1, -1.0).normalize(),
        irradiance: 1.0,
    }];
    let options = PathTraceOptions {
        spp: 8,
        seed: 42,
        ..Default::default()
    };
    let run = || path_trace(&medium, 0, &lights, 0.1, &top_camera(), &options).unwrap();
    let a = run();
    let one = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap();
    let b = one.install(run);
    assert_eq!(a, b);
    let other = PathTraceOptions {
        seed: 43,
        ..options
    };
    let c = path_trace(&medium, 0, &lights, 0.1, &top_camera(), &other).unwrap();
    assert_ne!(a, c);
}

#[test]
fn bad_inputs_are_refused() {
    let medium = columns(0.5);
    let cam = top_camera();
    let zero = PathTraceOptions {
        spp: 0,
        ..Default::default()
    };
    assert!(matches!(
        path_trace(&medium, 0, &[], 0.0, &cam, &zero),
        Err(MonteCarloError::Options(_))
    ));
    assert!(matches!(
        path_trace(&medium, 1, &[], 0.0, &cam, &PathTraceOptions::default()),
        Err(MonteCarloError::Channel {
            channel: 1,
            channels: 1
        })
    ));
    assert!(path_trace(&medium, 0, &[], -1.0, &cam, &PathTraceOptions::default()).is_err());
    let bad = [Light::Directional {
        direction: DVec3::ZERO,
        irradiance: 1.0,
    }];
    assert!(matches!(
        path_trace(&medium, 0, &bad, 0.0, &cam, &PathTraceOptions::default()),
        Err(MonteCarloError::Light { index: 0, .. })
    ));
}

#[test]
fn colour_channels_are_traced_separately() {
    // Three channels: opaque, empty and half-transparent; absorption only against a
    // background of 1, so the image is (≈0, 1, e^{−τ}) per pixel.
    let grid = Grid::new([4, 4, 2], 1.0).unwrap();
    let n = grid.cell_count();
    let channel = |s: f32| ChannelMedium {
        sigma_t: vec![s; n],
        albedo: CellValues::Uniform(0.0),
        emission: CellValues::Uniform(0.0),
    };
    let medium = Medium::new(
        grid,
        vec![channel(20.0), channel(0.0), channel(0.35)],
        PhaseFunction::Isotropic,
        Interpolation::Nearest,
        None,
    )
    .unwrap();
    let camera = Camera::orthographic(
        DVec3::new(2.0, 2.0, 9.0),
        DVec3::new(2.0, 2.0, 0.0),
        DVec3::Y,
        4.0,
        4,
        4,
    )
    .unwrap();
    let options = PathTraceOptions {
        spp: 1000,
        seed: 2,
        ..Default::default()
    };
    let img = montecarlo::path_trace_image(&medium, &[], 1.0, &camera, &options).unwrap();
    assert_eq!((img.width, img.height, img.channels), (4, 4, 3));
    let t = (-0.7f64).exp();
    let sigma = (t * (1.0 - t) / 1000.0).sqrt();
    for y in 0..4 {
        for x in 0..4 {
            assert!(img.get(x, y, 0) < 1e-3);
            assert_eq!(img.get(x, y, 1), 1.0);
            assert!((img.get(x, y, 2) as f64 - t).abs() < 4.5 * sigma);
        }
    }
}

/// Progress counts every row of every channel once, the image is the same as without it,
/// and a callback that says stop cancels the render instead of finishing it.
#[test]
fn progress_counts_rows_and_can_cancel() {
    use std::sync::atomic::{AtomicU64, Ordering};
    let medium = columns(0.7);
    let light = Light::Directional {
        direction: DVec3::new(0.2, 0.1, -1.0).normalize(),
        irradiance: 1.0,
    };
    let options = PathTraceOptions {
        spp: 8,
        seed: 5,
        ..Default::default()
    };
    let camera = top_camera();
    let calls = AtomicU64::new(0);
    let largest = AtomicU64::new(0);
    let image = montecarlo::path_trace::path_trace_image_with_progress(
        &medium,
        &[light],
        0.0,
        &camera,
        &options,
        &|rows| {
            calls.fetch_add(1, Ordering::Relaxed);
            largest.fetch_max(rows, Ordering::Relaxed);
            true
        },
    )
    .unwrap();
    assert_eq!(calls.load(Ordering::Relaxed), 8);
    assert_eq!(largest.load(Ordering::Relaxed), 8);
    let plain = montecarlo::path_trace_image(&medium, &[light], 0.0, &camera, &options).unwrap();
    assert_eq!(image.pixels, plain.pixels);
    let stopped = montecarlo::path_trace::path_trace_image_with_progress(
        &medium,
        &[light],
        0.0,
        &camera,
        &options,
        &|rows| rows < 3,
    );
    assert!(matches!(stopped, Err(MonteCarloError::Cancelled)));
}

/// Next-event estimation toward the emitters gives the same image as counting each flight's
/// emission (the image mean within four combined standard errors), with far smaller errors
/// in the pixels a small emitter lights only through scattering.
#[test]
fn emitter_sampling_keeps_the_image_and_shrinks_its_noise() {
    let grid = Grid::new([16, 16, 16], 1.0).unwrap();
    let emission: Vec<f32> = (0..grid.cell_count())
        .map(|c| {
            let [i, j, k] = grid.coords(c);
            if (7..9).contains(&i) && (7..9).contains(&j) && (7..9).contains(&k) {
                5.0
            } else {
                0.0
            }
        })
        .collect();
    let medium = Medium::new(
        grid,
        vec![ChannelMedium {
            sigma_t: vec![0.3; grid.cell_count()],
            albedo: CellValues::Uniform(0.9),
            emission: CellValues::PerCell(emission),
        }],
        PhaseFunction::HenyeyGreenstein { g: 0.5 },
        Interpolation::Nearest,
        None,
    )
    .unwrap();
    let camera = Camera::perspective(
        DVec3::new(8.0, -30.0, 8.0),
        DVec3::new(8.0, 8.0, 8.0),
        DVec3::Z,
        // Every pixel sees the grid.
        22.0,
        24,
        24,
    )
    .unwrap();
    let traced = |emitter_sampling| {
        let options = PathTraceOptions {
            spp: 256,
            seed: 9,
            emitter_sampling,
            ..Default::default()
        };
        path_trace_with_error(&medium, 0, &[], 0.0, &camera, &options).unwrap()
    };
    let (plain, sampled) = (traced(false), traced(true));
    let ((m0, s0), (m1, s1)) = (image_mean(&plain), image_mean(&sampled));
    assert!(
        (m0 - m1).abs() < 4.0 * (s0 * s0 + s1 * s1).sqrt(),
        "image mean {m1} ± {s1} with emitter sampling, {m0} ± {s0} without"
    );
    // Relative errors of the pixels that do not see the emitter (below 5 % of the peak, by
    // the low-noise image): lit by scattered light only.
    let peak = sampled.mean.pixels.iter().fold(0.0f32, |a, &b| a.max(b));
    let dim: Vec<usize> = (0..sampled.mean.pixels.len())
        .filter(|&i| sampled.mean.pixels[i] < 0.05 * peak)
        .collect();
    assert!(dim.len() > 200);
    let relative = |t: &montecarlo::PathTraced| {
        let mut r: Vec<f64> = dim
            .iter()
            .map(|&i| {
                // A pixel no path lit is 100 % off (its standard error says 0).
                let (m, e) = (t.mean.pixels[i] as f64, t.std_error.pixels[i] as f64);
                if m > 0.0 {
                    e / m
                } else {
                    1.0
                }
            })
            .collect();
        r.sort_by(f64::total_cmp);
        r[r.len() / 2]
    };
    let unlit =
        |t: &montecarlo::PathTraced| dim.iter().filter(|&&i| t.mean.pixels[i] <= 0.0).count();
    let (r0, r1, u0, u1) = (
        relative(&plain),
        relative(&sampled),
        unlit(&plain),
        unlit(&sampled),
    );
    eprintln!(
        "{} pixels lit by scattering only: median relative error {r1:.3} with emitter \
         sampling, {r0:.3} without; no path found the emitter in {u1} of them with it, {u0} \
         without",
        dim.len()
    );
    assert!(u1 == 0 && r1 < 0.5 * r0);
}
