//! Explores the discrete-ordinates slab against DISORT (tests/data/disort.json): flux
//! reflectance and transmittance over layer counts and bin counts, then reflected radiance per
//! exit angle. Settings from the environment: SLAB_NZ, SLAB_N, SLAB_N0, SLAB_G, SLAB_PQ,
//! SLAB_NOMATCH.
//!
//! `cargo run --release -p formfactor --example slab_explorer`

#[path = "../tests/support/slab.rs"]
#[allow(dead_code)]
mod slab;

use formfactor::ordinates::OrdinatesOptions;
use glam::DVec3;
use slab::{disort_cases, reflected_radiance, solve_slab, solve_slab_with};

fn main() {
    explore_slab_resolution();
    explore_slab_radiance();
}

fn explore_slab_resolution() {
    let nzs: Vec<usize> = std::env::var("SLAB_NZ")
        .map(|v| v.split(',').map(|x| x.parse().unwrap()).collect())
        .unwrap_or(vec![16]);
    let ns: Vec<usize> = std::env::var("SLAB_N")
        .map(|v| v.split(',').map(|x| x.parse().unwrap()).collect())
        .unwrap_or(vec![4]);
    for &nz in &nzs {
        for &n in &ns {
            for case in disort_cases() {
                if case["tau"].as_f64() != Some(1.0)
                    || std::env::var("SLAB_G").is_ok_and(|g| case["g"].as_f64() != g.parse().ok())
                {
                    continue;
                }
                let (a, g, mu0) = (
                    case["albedo"].as_f64().unwrap(),
                    case["g"].as_f64().unwrap(),
                    case["mu0"].as_f64().unwrap(),
                );
                let res = solve_slab(1.0, a, g, mu0, nz, n);
                let (r, t) = (
                    case["R"].as_f64().unwrap(),
                    case["T_diffuse"].as_f64().unwrap(),
                );
                println!(
                    "nz {nz} n {n} a {a} g {g} mu0 {mu0}: R {:.4} vs {:.4} ({:+.2}%), T {:.4} vs {:.4} ({:+.2}%), imb {:.1e}",
                    res.r,
                    r,
                    100.0 * (res.r / r - 1.0),
                    res.t_diffuse,
                    t,
                    100.0 * (res.t_diffuse / t - 1.0),
                    res.imbalance
                );
            }
        }
    }
}

fn explore_slab_radiance() {
    let nz: usize = std::env::var("SLAB_NZ")
        .map(|v| v.parse().unwrap())
        .unwrap_or(16);
    let n_iso: usize = std::env::var("SLAB_N0")
        .map(|v| v.parse().unwrap())
        .unwrap_or(4);
    let n_hg: usize = std::env::var("SLAB_N")
        .map(|v| v.parse().unwrap())
        .unwrap_or(8);
    let mut worst: f64 = 0.0;
    for case in disort_cases() {
        let (a, g, mu0) = (
            case["albedo"].as_f64().unwrap(),
            case["g"].as_f64().unwrap(),
            case["mu0"].as_f64().unwrap(),
        );
        if std::env::var("SLAB_G").is_ok_and(|gg| g != gg.parse::<f64>().unwrap()) {
            continue;
        }
        let n = if g == 0.0 { n_iso } else { n_hg };
        let base = OrdinatesOptions {
            phase_quadrature: std::env::var("SLAB_PQ").ok().map(|v| v.parse().unwrap()),
            match_asymmetry: std::env::var("SLAB_NOMATCH").is_err(),
            ..Default::default()
        };
        let res = solve_slab_with(1.0, a, g, mu0, nz, n, base);
        println!("R {:.4} vs {:.4}", res.r, case["R"].as_f64().unwrap());
        for (mu_key, angles) in case["reflected_radiance"].as_object().unwrap() {
            let mu: f64 = mu_key.trim_start_matches("mu=").parse().unwrap();
            for (phi_key, value) in angles.as_object().unwrap() {
                let phi: f64 = phi_key
                    .trim_start_matches("phi=")
                    .parse::<f64>()
                    .unwrap()
                    .to_radians();
                let s = (1.0 - mu * mu).sqrt();
                let view = DVec3::new(s * phi.cos(), s * phi.sin(), mu);
                let (first, higher) = reflected_radiance(&res, 1.0, a, g, mu0, view);
                let want = value.as_f64().unwrap();
                let err = (first + higher) / want - 1.0;
                worst = worst.max(err.abs());
                println!(
                    "a {a} g {g} mu0 {mu0} mu {mu} {phi_key}: {:.5} (1st {:.5}) vs {want:.5} ({:+.2}%)",
                    first + higher, first, 100.0 * err
                );
            }
        }
    }
    println!("worst {:.2}%", 100.0 * worst);
}
