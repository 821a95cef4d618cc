//! Blasi & Wuethrich's two-pass method: energy balance, conservation of the stored source,
//! agreement with the path tracer, determinism, refused inputs.

use std::sync::atomic::{AtomicU64, Ordering};

use gather::OpticalModel;
use gather::{render, Camera, RenderOptions};
use glam::DVec3;
use medium::{Grid, Light, Medium, PhaseFunction};
use montecarlo::{
    energetize, path_trace_with_error, DirectionBins, EnergetizeOptions, MonteCarloError,
    PathTraceOptions,
};

/// A heterogeneous block with σt from a fixed hash in [0, 0.8) and some empty cells.
fn blotchy(phase: PhaseFunction, albedo: f32) -> Medium {
    let grid = Grid::new([12, 10, 8], 1.0).unwrap();
    let sigma_t: Vec<f32> = (0..grid.cell_count())
        .map(|i| {
            let h = (i as u64).wrapping_mul(2654435761) % 1000;
            if h < 150 {
                0.0
            } else {
                h as f32 / 1000.0 * 0.8
            }
        })
        .collect();
    Medium::grey(grid, sigma_t, albedo, phase).unwrap()
}

fn sun() -> Light {
    Light::Directional {
        direction: DVec3::new(0.4, -0.3, -0.85).normalize(),
        irradiance: 1.5,
    }
}

#[test]
fn energy_balance_to_one_percent() {
    let medium = blotchy(PhaseFunction::HenyeyGreenstein { g: 0.5 }, 0.9);
    let light = sun();
    let options = EnergetizeOptions {
        photons_per_light: 200_000,
        seed: 7,
        storage_factor: 2,
        bins: DirectionBins {
            n_theta: 4,
            n_phi: 8,
        },
        ..Default::default()
    };
    let sol = energetize(&medium, 0, &[light], &options, None).unwrap();
    let e = sol.energy;
    // Power crossing into the box: E0 times the box's projected area Σ |d_a| A_a.
    let Light::Directional {
        direction: d,
        irradiance,
    } = light
    else {
        unreachable!()
    };
    let ext = medium.grid().extent();
    let projected =
        d.x.abs() * ext.y * ext.z + d.y.abs() * ext.x * ext.z + d.z.abs() * ext.x * ext.y;
    let exact = irradiance * projected;
    assert!(
        (e.entering / exact - 1.0).abs() < 0.01,
        "entering {} vs {exact}",
        e.entering
    );
    let out = e.absorbed + e.escaped;
    assert!(
        (out / exact - 1.0).abs() < 0.01,
        "absorbed + escaped {out} vs entering {exact}"
    );
    assert!(e.absorbed > 0.1 * exact && e.escaped > 0.1 * exact, "{e:?}");
    // Scattered = albedo/(1 − albedo) × absorbed for a uniform albedo.
    let a = 0.9f32 as f64;
    assert!((e.scattered / (a / (1.0 - a) * e.absorbed) - 1.0).abs() < 1e-9);
    // The conversion to radiance (phase matrix, per-cell shares) creates and loses nothing.
    assert!(
        (sol.source_power() / e.stored - 1.0).abs() < 1e-4,
        "{} vs {}",
        sol.source_power(),
        e.stored
    );
}

#[test]
fn point_light_energy_balance() {
    let medium = blotchy(PhaseFunction::Isotropic, 0.7);
    let light = Light::Point {
        position: DVec3::new(6.0, 5.0, 4.0),
        intensity: 2.0,
    };
    let options = EnergetizeOptions {
        photons_per_light: 100_000,
        seed: 1,
        ..Default::default()
    };
    let sol = energetize(&medium, 0, &[light], &options, None).unwrap();
    let e = sol.energy;
    // A light inside the grid puts all of its 4π I into it.
    let exact = 4.0 * std::f64::consts::PI * 2.0;
    assert!((e.entering / exact - 1.0).abs() < 1e-9);
    assert!(
        ((e.absorbed + e.escaped) / exact - 1.0).abs() < 0.01,
        "{e:?}"
    );
}

/// Renders the two-pass solution and the path tracer from the same camera; returns the
/// relative difference of the image means over the lit pixels and the path tracer's relative
/// standard error of that mean.
fn two_pass_vs_path_trace(
    phase: PhaseFunction,
    bins: DirectionBins,
    photons: u64,
    higher_orders_only: bool,
) -> (f64, f64) {
    let grid = Grid::new([8, 8, 8], 1.0).unwrap();
    let medium = Medium::homogeneous(grid, 0.5, 0.9, 0.0, phase).unwrap();
    let lights = [sun()];
    let options = EnergetizeOptions {
        photons_per_light: photons,
        seed: 3,
        bins,
        include_first_bounce: !higher_orders_only,
        ..Default::default()
    };
    let sol = energetize(&medium, 0, &lights, &options, None).unwrap();
    let camera = Camera::perspective(
        DVec3::new(-10.0, -14.0, 12.0),
        grid.center(),
        DVec3::Z,
        35.0,
        32,
        32,
    )
    .unwrap();
    let render_options = RenderOptions {
        model: OpticalModel::Scattering,
        spp: 4,
        ..Default::default()
    };
    let two_pass = render(&medium, 0, &camera, &render_options, &sol).unwrap();
    let pt_options = PathTraceOptions {
        spp: 256,
        seed: 4,
        ..Default::default()
    };
    let pt = path_trace_with_error(&medium, 0, &lights, 0.0, &camera, &pt_options).unwrap();
    let mut two_pass = two_pass;
    if higher_orders_only {
        // Add the first bounce from the path tracer (max_depth 1) image by image: the sum
        // must be the whole transport, with no order counted twice or missed.
        let first_options = PathTraceOptions {
            max_depth: Some(1),
            seed: 8,
            ..pt_options
        };
        let first =
            path_trace_with_error(&medium, 0, &lights, 0.0, &camera, &first_options).unwrap();
        for (p, f) in two_pass.pixels.iter_mut().zip(&first.mean.pixels) {
            *p += f;
        }
    }
    let max = pt.mean.pixels.iter().copied().fold(0.0f32, f32::max);
    let (mut a, mut b, mut var) = (0.0f64, 0.0f64, 0.0f64);
    for i in 0..pt.mean.pixels.len() {
        if pt.mean.pixels[i] > 0.01 * max {
            a += two_pass.pixels[i] as f64;
            b += pt.mean.pixels[i] as f64;
            var += (pt.std_error.pixels[i] as f64).powi(2);
        }
    }
    ((a - b) / b, var.sqrt() / b)
}

#[test]
fn agrees_with_the_path_tracer_isotropic() {
    // Stated bias: the source is constant over each cell (σt h = 0.5), which the view rays
    // weight differently from the true profile near the lit faces: below 3 % here.
    let (diff, se) = two_pass_vs_path_trace(
        PhaseFunction::Isotropic,
        DirectionBins::ISOTROPIC,
        200_000,
        false,
    );
    eprintln!(
        "isotropic: two-pass − path trace = {:+.4} (path-trace noise {:.4})",
        diff, se
    );
    assert!(diff.abs() < 0.03 + 4.0 * se, "{diff} ± {se}");
}

#[test]
fn agrees_with_the_path_tracer_anisotropic() {
    // HG g = 0.5 on 6 × 12 direction bins: the binning (bin-averaged phase, nearest outgoing
    // bin) is a further bias, +3.3 % on this image mean (+0.5 % with 12 × 24 bins).
    let (diff, se) = two_pass_vs_path_trace(
        PhaseFunction::HenyeyGreenstein { g: 0.5 },
        DirectionBins {
            n_theta: 6,
            n_phi: 12,
        },
        200_000,
        false,
    );
    eprintln!(
        "anisotropic: two-pass − path trace = {:+.4} (path-trace noise {:.4})",
        diff, se
    );
    assert!(diff.abs() < 0.05 + 4.0 * se, "{diff} ± {se}");
}

#[test]
fn finer_direction_bins_remove_the_binning_bias() {
    // 12 × 24 bins: the binning bias falls below 1.5 % (+0.5 % measured).
    let fine = DirectionBins {
        n_theta: 12,
        n_phi: 24,
    };
    let g = PhaseFunction::HenyeyGreenstein { g: 0.5 };
    let (diff, se) = two_pass_vs_path_trace(g, fine, 200_000, false);
    eprintln!("anisotropic, 12×24 bins: two-pass − path trace = {diff:+.4} (noise {se:.4})");
    assert!(diff.abs() < 0.015 + 4.0 * se, "{diff} ± {se}");
}

#[test]
fn higher_orders_only_plus_first_bounce_is_the_whole_transport() {
    // The first bounce is about 30 % of this image, so leaving it out twice or counting it
    // twice is far outside the tolerance. Stated bias: the cell-constant source overestimates
    // the higher orders seen through the lit faces by a few per cent (+2.5 % measured on the
    // total), while it underestimates the steeper first bounce, so the full solution is
    // closer (above).
    let fine = DirectionBins {
        n_theta: 12,
        n_phi: 24,
    };
    let g = PhaseFunction::HenyeyGreenstein { g: 0.5 };
    let (diff, se) = two_pass_vs_path_trace(g, fine, 200_000, true);
    eprintln!("anisotropic, higher orders + first bounce: two-pass − path trace = {diff:+.4} (noise {se:.4})");
    assert!(diff.abs() < 0.04 + 4.0 * se, "{diff} ± {se}");
}

#[test]
fn deterministic_for_a_seed_with_progress() {
    let medium = blotchy(PhaseFunction::HenyeyGreenstein { g: 0.3 }, 0.8);
    let options = EnergetizeOptions {
        photons_per_light: 10_000,
        seed: 5,
        bins: DirectionBins {
            n_theta: 2,
            n_phi: 4,
        },
        ..Default::default()
    };
    let lights = [
        sun(),
        Light::Point {
            position: DVec3::new(3.0, 3.0, 9.0),
            intensity: 1.0,
        },
    ];
    let last = AtomicU64::new(0);
    let report = |done: u64, total: u64| {
        assert_eq!(total, 20_000);
        last.fetch_max(done, Ordering::Relaxed);
    };
    let a = energetize(&medium, 0, &lights, &options, Some(&report)).unwrap();
    assert_eq!(last.load(Ordering::Relaxed), 20_000);
    let one = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap();
    let b = one.install(|| energetize(&medium, 0, &lights, &options, None).unwrap());
    assert_eq!(a, b);
    let c = energetize(
        &medium,
        0,
        &lights,
        &EnergetizeOptions { seed: 6, ..options },
        None,
    )
    .unwrap();
    assert_ne!(a.voxel_source, c.voxel_source);
}

#[test]
fn bad_inputs_are_refused() {
    let medium = blotchy(PhaseFunction::Isotropic, 0.5);
    let lights = [sun()];
    let run = |o: EnergetizeOptions| energetize(&medium, 0, &lights, &o, None);
    let base = EnergetizeOptions {
        photons_per_light: 100,
        ..Default::default()
    };
    assert!(matches!(
        run(EnergetizeOptions {
            photons_per_light: 0,
            ..base.clone()
        }),
        Err(MonteCarloError::Options(_))
    ));
    assert!(matches!(
        run(EnergetizeOptions {
            storage_factor: 0,
            ..base.clone()
        }),
        Err(MonteCarloError::Options(_))
    ));
    assert!(run(EnergetizeOptions {
        bins: DirectionBins {
            n_theta: 0,
            n_phi: 4
        },
        ..base.clone()
    })
    .is_err());
    assert!(matches!(
        energetize(&medium, 2, &lights, &base, None),
        Err(MonteCarloError::Channel { channel: 2, .. })
    ));
    let other = Grid::new([4, 4, 4], 1.0).unwrap();
    let sol = run(base).unwrap();
    assert!(sol.check_grid(medium.grid()).is_ok());
    assert!(matches!(
        sol.check_grid(&other),
        Err(MonteCarloError::Mismatch(_))
    ));
}
