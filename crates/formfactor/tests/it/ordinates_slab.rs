//! Plane-parallel slab against DISORT (tests/data/disort.json and disort_slabs.json): flux
//! reflectance, diffuse transmittance and radiances of the discrete-ordinates solution, one
//! periodic column of cells.

#[path = "../support/slab.rs"]
#[allow(dead_code)] // solve_slab_with and the zonal slab serve the examples
mod slab;

use formfactor::ordinates::OrdinatesOptions;
use glam::DVec3;
use slab::{
    case_parameters, case_radiances, disort_cases, disort_slab_cases, reflected_radiance,
    solve_slab, solve_slab_with, transmitted_radiance,
};

/// Flux reflectance and diffuse transmittance within 2 % of DISORT for every τ = 1 case.
/// g = 0: Max's 96 bins, 16 layers (worst 0.8 %; 8 layers give 2.5 %). g = 0.7: 384 bins
/// (n = 8), 16 layers (worst 1.9 %); 96 bins are within 6.3 % (the forward peak is coarsely
/// binned: reflectance too high).
#[test]
fn slab_matches_disort_for_unit_optical_depth() {
    let mut checked = 0;
    for case in disort_cases() {
        if case["tau"].as_f64() != Some(1.0) {
            continue;
        }
        let (a, g, mu0) = (
            case["albedo"].as_f64().unwrap(),
            case["g"].as_f64().unwrap(),
            case["mu0"].as_f64().unwrap(),
        );
        let (nz, n) = if g == 0.0 { (16, 4) } else { (16, 8) };
        let res = solve_slab(1.0, a, g, mu0, nz, n);
        let (r, t) = (
            case["R"].as_f64().unwrap(),
            case["T_diffuse"].as_f64().unwrap(),
        );
        assert!(
            res.imbalance < 1e-6,
            "a {a} g {g} mu0 {mu0}: imbalance {}",
            res.imbalance
        );
        assert!(
            (res.r / r - 1.0).abs() < 0.02,
            "a {a} g {g} mu0 {mu0}: R {} vs {r}",
            res.r
        );
        assert!(
            (res.t_diffuse / t - 1.0).abs() < 0.02,
            "a {a} g {g} mu0 {mu0}: T {} vs {t}",
            res.t_diffuse
        );
        checked += 1;
    }
    assert_eq!(checked, 12);
}

/// Reflected radiances within 3 % of DISORT at every exit angle (μ = 1, 0.7, 0.4;
/// φ = 0, 90, 180°) of every τ = 1 case, evaluated as the renderer does (exact first bounce
/// plus the true-phase final gather from the bin radiances, interpolated between bin
/// centres). g = 0: 96 bins, 16 layers (worst 0.7 %). g = 0.7: 384 bins, 64 layers (worst
/// 2.7 %, at μ = 1 where the view lies between four bin centres; 32 layers give 3.5 %:
/// the step scheme's layer-constant source, not the bins, is what needs the thin layers).
#[test]
fn slab_reflected_radiance_matches_disort_for_unit_optical_depth() {
    let mut checked = 0;
    for case in disort_cases() {
        if case["tau"].as_f64() != Some(1.0) {
            continue;
        }
        let (a, g, mu0) = (
            case["albedo"].as_f64().unwrap(),
            case["g"].as_f64().unwrap(),
            case["mu0"].as_f64().unwrap(),
        );
        let (nz, n) = if g == 0.0 { (16, 4) } else { (64, 8) };
        let res = solve_slab(1.0, a, g, mu0, nz, n);
        for (mu_key, angles) in case["reflected_radiance"].as_object().unwrap() {
            let mu: f64 = mu_key.trim_start_matches("mu=").parse().unwrap();
            for (phi_key, value) in angles.as_object().unwrap() {
                let phi = phi_key
                    .trim_start_matches("phi=")
                    .parse::<f64>()
                    .unwrap()
                    .to_radians();
                let s = (1.0 - mu * mu).sqrt();
                let view = DVec3::new(s * phi.cos(), s * phi.sin(), mu);
                let (first, higher) = reflected_radiance(&res, 1.0, a, g, mu0, view);
                let want = value.as_f64().unwrap();
                assert!(
                    ((first + higher) / want - 1.0).abs() < 0.03,
                    "a {a} g {g} mu0 {mu0} mu {mu} {phi_key}: {} (first bounce {first}) vs {want}",
                    first + higher
                );
                checked += 1;
            }
        }
    }
    assert_eq!(checked, 12 * 9);
}

/// The project's DISORT tables (tests/data/disort_slabs.json, 128 streams) on a sample of thin,
/// thick and forward-scattering slabs at Max's 96 bins and 64 layers (the default of
/// `examples/disort_slabs.rs`), each with bounds a little above the errors today's code
/// reaches (measured, in %, reflected / transmitted radiance / R / T: 1.7 / 2.0 / 1.3 / 0.8;
/// 0.5 / 0.5 / 0.2 / 0.8; 2.7 / 6.8 / 0.3 / 2.1; 12.9 / 13.8 / 2.3 / 6.2; 1.9 / 2.7 / 0.1 /
/// 2.2 with linear faces; uniform faces gave 1.2 / 1.6 / 1.0 / 0.8; 0.3 / 0.7 / 0.1 / 0.0;
/// 2.0 / 6.1 / 0.3 / 1.0; 12.8 / 13.2 / 2.0 / 5.5; 3.1 / 8.4 / 0.5 / 8.6, and fail the last
/// case's bounds). A regression guard, not issue 18's floors (3 % radiance, 1 % flux): the
/// forward-scattering cases at 96 bins are the known gap of docs/validation.md.
#[test]
fn slab_matches_disort_tables_on_a_sample() {
    // (τ, g, albedo, μ0), then bounds on the relative error of the reflected and transmitted
    // radiances (worst of the 9 angles each), R and T.
    type Case = (f64, f64, f64, f64);
    let samples: [(Case, [f64; 4]); 5] = [
        ((1.0, 0.3, 0.9, 0.4), [0.02, 0.025, 0.015, 0.012]),
        ((4.0, 0.0, 0.99, 0.7), [0.01, 0.01, 0.005, 0.011]),
        ((16.0, 0.7, 0.99, 1.0), [0.03, 0.075, 0.005, 0.025]),
        ((16.0, 0.85, 1.0, 0.4), [0.14, 0.145, 0.025, 0.065]),
        ((64.0, 0.6, 1.0, 0.7), [0.025, 0.035, 0.005, 0.03]),
    ];
    let cases = disort_slab_cases();
    for ((tau, g, albedo, mu0), [refl_bound, trans_bound, r_bound, t_bound]) in samples {
        let case = cases
            .iter()
            .find(|c| case_parameters(c) == (tau, albedo, g, mu0))
            .unwrap();
        let res = solve_slab(tau, albedo, g, mu0, 64, 4);
        let label = format!("tau {tau} g {g} a {albedo} mu0 {mu0}");
        assert!(res.imbalance < 1e-6, "{label}: imbalance {}", res.imbalance);
        for (key, got, bound) in [("R", res.r, r_bound), ("T_diffuse", res.t_diffuse, t_bound)] {
            let want = case[key].as_f64().unwrap();
            let err = got / want - 1.0;
            eprintln!(
                "{label}: {key} {got:.5} vs {want:.5} ({:+.2} %)",
                100.0 * err
            );
            assert!(err.abs() < bound, "{label}: {key} {got} vs {want}");
        }
        for (table, bound) in [
            ("reflected_radiance", refl_bound),
            ("transmitted_diffuse_radiance", trans_bound),
        ] {
            let mut worst: f64 = 0.0;
            for (mu, phi, view, want) in case_radiances(case, table) {
                let (first, higher) = if view.z > 0.0 {
                    reflected_radiance(&res, tau, albedo, g, mu0, view)
                } else {
                    transmitted_radiance(&res, tau, albedo, g, mu0, view)
                };
                let err = (first + higher) / want - 1.0;
                assert!(
                    err.abs() < bound,
                    "{label}: {table} mu {mu} phi {phi}: {} vs {want}",
                    first + higher
                );
                worst = worst.max(err.abs());
            }
            eprintln!("{label}: {table} worst {:.2} %", 100.0 * worst);
        }
    }
}

/// A source linear in each cell ([`OrdinatesOptions::linear_source`]) where the flat one lets
/// a thick, highly scattering slab transmit several times DISORT's light: τ = 64, isotropic,
/// albedo 0.99, μ0 = 1, in 64 layers (σt h = 1), with uniform faces: diffuse transmission
/// +333 % with the flat source, +118 % with the linear one (the rest is the face-averaged flux
/// that crosses the layers' sides, which [`linear_faces_stop_a_thick_slab_leaking`] takes
/// out). The slopes move no power: the sweep stays conservative.
#[test]
fn a_linear_source_lets_a_thick_slab_transmit_less() {
    let error = |linear_source: bool| {
        thick_slab_errors(OrdinatesOptions {
            linear_source,
            linear_faces: false,
            ..Default::default()
        })
    };
    let (flat_t, flat_r) = error(false);
    let (linear_t, linear_r) = error(true);
    eprintln!(
        "T {:+.1} % → {:+.1} %, R {:+.1} % → {:+.1} %",
        100.0 * flat_t,
        100.0 * linear_t,
        100.0 * flat_r,
        100.0 * linear_r
    );
    assert!(flat_t > 2.0, "the flat source's excess is gone: {flat_t}");
    assert!(linear_t.abs() < 0.4 * flat_t, "T: {linear_t} vs {flat_t}");
    assert!(
        linear_r.abs() < 0.75 * flat_r.abs(),
        "R: {linear_r} vs {flat_r}"
    );
}

/// Face fluxes linear across each face ([`OrdinatesOptions::linear_faces`]) where uniform
/// ones let a thick, nearly conservative slab through: τ = 64, isotropic, albedo 0.99, μ0 = 1,
/// 64 layers, 96 bins. With uniform faces a piece crossing a layer's side face re-enters the
/// next cell spread over the face's height, whatever depth it left at: T +118 %. With linear
/// faces T is −9 % (what is left is the 96 bins' angular error: −5 % at 216 bins, −4 % at
/// 384) and R within 1 %. Both conserve power.
#[test]
fn linear_faces_stop_a_thick_slab_leaking() {
    let error = |linear_faces: bool| {
        thick_slab_errors(OrdinatesOptions {
            linear_faces,
            ..Default::default()
        })
    };
    let (uniform_t, uniform_r) = error(false);
    let (linear_t, linear_r) = error(true);
    eprintln!(
        "T {:+.1} % → {:+.1} %, R {:+.1} % → {:+.1} %",
        100.0 * uniform_t,
        100.0 * linear_t,
        100.0 * uniform_r,
        100.0 * linear_r
    );
    assert!(
        uniform_t > 0.8,
        "uniform faces' excess is gone: {uniform_t}"
    );
    assert!(linear_t.abs() < 0.12, "T with linear faces: {linear_t}");
    assert!(linear_r.abs() < 0.01, "R with linear faces: {linear_r}");
}

/// The relative errors `(T, R)` against DISORT of the thick slab the two tests above solve
/// (τ = 64, isotropic, albedo 0.99, μ0 = 1, 64 layers, 96 bins) with `options`, which must
/// conserve power and sweep the faces `options` asks for.
fn thick_slab_errors(options: OrdinatesOptions) -> (f64, f64) {
    let case = disort_slab_cases()
        .into_iter()
        .find(|c| case_parameters(c) == (64.0, 0.99, 0.0, 1.0))
        .unwrap();
    let res = solve_slab_with(64.0, 0.99, 0.0, 1.0, 64, 4, options);
    assert_eq!(res.op.linear_faces(), options.linear_faces);
    assert!(
        res.imbalance < 1e-6,
        "{options:?}: imbalance {}",
        res.imbalance
    );
    let want = |key: &str| case[key].as_f64().unwrap();
    (
        res.t_diffuse / want("T_diffuse") - 1.0,
        res.r / want("R") - 1.0,
    )
}
