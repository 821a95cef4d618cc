//! Plane-parallel slab against DISORT (tests/data/disort.json and disort_slabs.json): flux
//! reflectance, diffuse transmittance and radiances of the discrete-ordinates solution, one
//! periodic column of cells.

#[path = "../support/slab.rs"]
#[allow(dead_code)] // solve_slab_with and the zonal slab serve the examples
mod slab;

use formfactor::ordinates::OrdinatesOptions;
use glam::DVec3;
use slab::{
    case_parameters, case_radiances, disort_cases, disort_slab_cases, first_order_reflectance,
    reflected_radiance, solve_slab, solve_slab_with, transmitted_radiance,
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
/// reaches (measured, in %, reflected / transmitted radiance / R / T: 2.0 / 2.0 / 1.0 / 0.5;
/// 1.0 / 0.3 / 0.1 / 0.1; 2.9 / 5.1 / 0.2 / 0.1; 12.8 / 12.8 / 1.8 / 4.9; 1.7 / 4.0 / 0.0 /
/// 0.4 with the bins' diffusion matched ([`OrdinatesOptions::match_diffusion`]); without it
/// 1.7 / 2.0 / 1.3 / 0.8; 0.5 / 0.5 / 0.2 / 0.8; 2.7 / 6.8 / 0.3 / 2.1; 12.9 / 13.8 / 2.3 /
/// 6.2; 1.9 / 2.7 / 0.1 / 2.2, which fails three of the T bounds; uniform faces failed the last
/// case's). The last case's transmitted radiance is now a little high at the right flux
/// (+4.0 % at μ = 0.7, −0.4 % in T; 2.7 % and −2.2 % before). A regression guard, not issue 18's floors (3 % radiance,
/// 1 % flux): the forward-scattering cases at 96 bins are the known gap of docs/validation.md.
#[test]
fn slab_matches_disort_tables_on_a_sample() {
    // (τ, g, albedo, μ0), then bounds on the relative error of the reflected and transmitted
    // radiances (worst of the 9 angles each), R and T.
    type Case = (f64, f64, f64, f64);
    let samples: [(Case, [f64; 4]); 5] = [
        ((1.0, 0.3, 0.9, 0.4), [0.02, 0.025, 0.015, 0.012]),
        ((4.0, 0.0, 0.99, 0.7), [0.012, 0.01, 0.005, 0.005]),
        ((16.0, 0.7, 0.99, 1.0), [0.03, 0.075, 0.005, 0.01]),
        ((16.0, 0.85, 1.0, 0.4), [0.14, 0.145, 0.025, 0.065]),
        // T −1.3 %: conservative thick layers (σt h = 1) keep about −2 % at every μ0 with
        // the beams' own profiles, −0.3 % at 128 layers (docs/validation.md, *The lights'
        // first scattering inside thick cells*).
        ((64.0, 0.6, 1.0, 0.7), [0.025, 0.045, 0.005, 0.02]),
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
/// +381 % with the flat source, +148 % with the linear one (+333 % and +118 % before the
/// phase matrix made up the bins' diffusion loss; the rest is the face-averaged flux
/// that crosses the layers' sides, which [`linear_faces_stop_a_thick_slab_leaking`] takes
/// out). The slopes move no power: the sweep stays conservative.
#[test]
fn a_linear_source_lets_a_thick_slab_transmit_less() {
    let error = |linear_source: bool| {
        thick_slab_errors(
            (64.0, 1.0),
            4,
            OrdinatesOptions {
                linear_source,
                linear_faces: false,
                ..Default::default()
            },
        )
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
    assert!(linear_r.abs() < flat_r.abs(), "R: {linear_r} vs {flat_r}");
}

/// Face fluxes linear across each face ([`OrdinatesOptions::linear_faces`]) where uniform
/// ones let a thick, nearly conservative slab through: τ = 64, isotropic, albedo 0.99, μ0 = 1,
/// 64 layers, 96 bins. With uniform faces a piece crossing a layer's side face re-enters the
/// next cell spread over the face's height, whatever depth it left at: T +148 %. With linear
/// faces T is +2.8 % (−10 % without [`OrdinatesOptions::match_diffusion`], the bins' own loss:
/// [`matching_the_bins_diffusion_lets_thick_slabs_through`]) and R within 1 %. Both conserve
/// power.
#[test]
fn linear_faces_stop_a_thick_slab_leaking() {
    let error = |linear_faces: bool| {
        thick_slab_errors(
            (64.0, 1.0),
            4,
            OrdinatesOptions {
                linear_faces,
                ..Default::default()
            },
        )
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

/// Radiance constant over each bin carries `1 − ε` of the current a fluence gradient drives
/// (`ε` = [`DirectionBins::diffusion_loss`], 2.4 % for 96 bins, 1.1 % for 216), so thick,
/// nearly conservative slabs transmitted too little, the more so the thicker: T −2.3 % at
/// τ = 16 and −9.7 % at τ = 64 (96 bins), −5.7 % at τ = 64 (216 bins); albedo 0.99, μ0 = 1,
/// 64 layers. The phase matrix matched to `g* + ε (1 − g*)`
/// ([`OrdinatesOptions::match_diffusion`]) makes the diffusion coefficient up: +0.4 %, +2.8 %
/// and 0.0 %. At τ = 64 with 96 bins the match over-corrects a little (about +2.3 % even at
/// 256 layers; not yet explained). R moves by less than 0.5 %.
///
/// [`DirectionBins::diffusion_loss`]: formfactor::ordinates::DirectionBins::diffusion_loss
#[test]
fn matching_the_bins_diffusion_lets_thick_slabs_through() {
    // (τ, face divisions), the bound on |T| with the diffusion matched.
    for ((tau, n), bound) in [((16.0, 4), 0.01), ((64.0, 4), 0.045), ((64.0, 6), 0.015)] {
        let errors = |match_diffusion: bool| {
            let options = OrdinatesOptions {
                match_diffusion,
                ..Default::default()
            };
            thick_slab_errors((tau, 1.0), n, options)
        };
        let (lost_t, lost_r) = errors(false);
        let (matched_t, matched_r) = errors(true);
        eprintln!(
            "tau {tau}, {} bins: T {:+.1} % → {:+.1} %, R {:+.2} % → {:+.2} %",
            6 * n * n,
            100.0 * lost_t,
            100.0 * matched_t,
            100.0 * lost_r,
            100.0 * matched_r
        );
        assert!(lost_t < -bound, "the loss is gone: T {lost_t}");
        assert!(
            matched_t.abs() < bound,
            "T with diffusion matched: {matched_t}"
        );
        assert!(
            (matched_r - lost_r).abs() < 0.005,
            "R moved: {lost_r} → {matched_r}"
        );
    }
}

/// A beam's first scattering swept with the slopes of its own profile in each cell
/// ([`OrdinatesOptions::beam_profiles`]), not the neighbours' differences: on layers of
/// optical depth 1 an oblique beam (μ0 = 0.4) crosses each with an optical path of 2.5, and
/// the differences made the slope nearly 3× too steep inside and 2.5× too flat in the lit
/// layer, whose upper neighbour is outside; the first scattering's mean depth was 0.48 for
/// 0.40, and a thick slab transmits in proportion to that depth plus the extrapolation
/// length: τ = 64, albedo 0.99, 96 bins, 64 layers, T +8.9 % at μ0 = 0.4 against +3.4 % at
/// μ0 = 1. With the beam's profile both are +2.8 % (what is left is the bins' diffusion
/// match, the same at every μ0) and R is within 0.8 %.
#[test]
fn an_oblique_beam_scatters_first_at_its_own_depth() {
    let errors = |mu0: f64, beam_profiles: bool| {
        let options = OrdinatesOptions {
            beam_profiles,
            ..Default::default()
        };
        thick_slab_errors((64.0, mu0), 4, options)
    };
    let (neighbours_t, _) = errors(0.4, false);
    let (oblique_t, oblique_r) = errors(0.4, true);
    let (normal_t, normal_r) = errors(1.0, true);
    eprintln!(
        "μ0 0.4: T {:+.1} % → {:+.1} % (μ0 1: {:+.1} %); R {:+.2} %, {:+.2} %",
        100.0 * neighbours_t,
        100.0 * oblique_t,
        100.0 * normal_t,
        100.0 * oblique_r,
        100.0 * normal_r
    );
    assert!(neighbours_t > 0.07, "the excess is gone: T {neighbours_t}");
    assert!(oblique_t.abs() < 0.04, "T at μ0 0.4: {oblique_t}");
    assert!(
        (oblique_t - normal_t).abs() < 0.01,
        "T at μ0 0.4 and 1: {oblique_t}, {normal_t}"
    );
    for r in [oblique_r, normal_r] {
        assert!(r.abs() < 0.01, "R {r}");
    }
}

/// The beam's first scattering alone, against single scattering's reflectance of a
/// semi-infinite isotropic medium, `R1 = (ω/2)(1 − μ0 ln(1 + 1/μ0))`: τ = 64 in 64 layers
/// (σt h = 1), 216 bins. With the beam's own profile in each cell the sweep's escape is
/// −0.3 % (μ0 = 1) and −2.6 % (μ0 = 0.4), what the linear fit of an exponential source gives
/// (it keeps the mean depth, not the curvature near the surface); with the neighbours'
/// slopes −4.2 % and −16.0 %. (At 256 layers both are +0.6 … +1.1 %, the bins' own error.)
#[test]
fn the_first_scattering_escapes_as_single_scattering_does() {
    let albedo = 0.5;
    for (mu0, bound) in [(1.0f64, 0.01), (0.4, 0.03)] {
        let exact = 0.5 * albedo * (1.0 - mu0 * (1.0 + 1.0 / mu0).ln());
        let error = |beam_profiles: bool| {
            let options = OrdinatesOptions {
                beam_profiles,
                ..Default::default()
            };
            first_order_reflectance((64.0, albedo, 0.0, mu0), 64, 6, options) / exact - 1.0
        };
        let (own, neighbours) = (error(true), error(false));
        eprintln!(
            "μ0 {mu0}: R1 {:+.2} % (neighbours' slopes {:+.2} %)",
            100.0 * own,
            100.0 * neighbours
        );
        assert!(own.abs() < bound, "μ0 {mu0}: {own}");
        assert!(
            neighbours < -0.035,
            "μ0 {mu0}: the neighbours' error is gone: {neighbours}"
        );
    }
}

/// The relative errors `(T, R)` against DISORT of an isotropic slab of optical depth `tau`
/// lit at `mu0` (albedo 0.99, 64 layers) in `6 n²` bins with `options`, which must conserve
/// power and sweep the faces `options` asks for.
fn thick_slab_errors((tau, mu0): (f64, f64), n: usize, options: OrdinatesOptions) -> (f64, f64) {
    let case = disort_slab_cases()
        .into_iter()
        .find(|c| case_parameters(c) == (tau, 0.99, 0.0, mu0))
        .unwrap();
    let res = solve_slab_with(tau, 0.99, 0.0, mu0, 64, n, options);
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
