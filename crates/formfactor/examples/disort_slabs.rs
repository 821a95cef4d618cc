//! Discrete ordinates (and, for g = 0, the zonal method) against the DISORT slab tables
//! (tests/data/disort_slabs.json: τ = 1 … 64, g = 0 … 0.9, albedo 0.9 / 0.99 / 1, μ0 = 1, 0.7,
//! 0.4). Per case: the worst relative error of the reflected radiance (μ = 1, 0.7, 0.4 ×
//! φ = 0, 90, 180°), of the transmitted diffuse radiance, and of the flux reflectance R and
//! diffuse transmittance T; then the worst per (τ, g) as a Markdown table.
//!
//! Settings from the environment (comma lists):
//! - `DISORT_BINS` (default 96): direction bins, `6 n²` (96, 216, 384), or `auto`: the bins
//!   volrad chooses for each case's g (`auto_bin_count`);
//! - `DISORT_LAYERS` (default 64): layers of the slab (one periodic column of unit cubes);
//! - `DISORT_TAU`, `DISORT_G`, `DISORT_ALBEDO`, `DISORT_MU0`: only these cases;
//! - `DISORT_NOMATCH=1`: the phase matrix without [`match_asymmetry`]; `DISORT_PQ=k`: its
//!   sub-squares per bin side (default 3 above 216 bins, else the library's);
//! - `DISORT_ZONAL=1`: also the zonal method on the g = 0 cases: exact form factors on a grid
//!   `DISORT_ZONAL_LAYERS` deep (default 4 √τ: σt·h = 0.25 … 2) and wide enough for
//!   `DISORT_ZONAL_REACH` optical depths (default 6) on each side of the centre column,
//!   folded onto that column (the build is O(cells²): 3–90 s per τ);
//! - `DISORT_CONE`: the δ-M forward-peak cone in degrees (`auto`: one bin's, as volrad's
//!   default; unset or 0: none), for the g > 0 cases;
//! - `DISORT_MAX_SHARES=1`: the sweep without face coupling (Max's fixed face shares,
//!   `OrdinatesOptions::face_coupling` off);
//! - `DISORT_FLAT=1`: the scattered source uniform in each cell (without
//!   `OrdinatesOptions::linear_source`);
//! - `DISORT_NODIFFUSION=1`: the phase matrix matched to `g*` only, without making up the
//!   bins' diffusion loss (`OrdinatesOptions::match_diffusion` off);
//! - `DISORT_NEIGHBOUR_SLOPES=1`: the beam's first scattering swept with the neighbours'
//!   differences for slopes, not its own profile (`OrdinatesOptions::beam_profiles` off);
//! - `DISORT_DETAIL=1`: every radiance.
//!
//! The transmitted radiances and T of cases whose DISORT `T_diffuse` is below 1e-6 (τ = 64 at
//! albedo 0.9: 1e-15 … 1e-6) are printed per case but left out of the summary.
//!
//! `cargo run --release -p formfactor --example disort_slabs`
//!
//! [`match_asymmetry`]: formfactor::ordinates::PhaseMatrix::match_asymmetry

#[path = "../tests/support/slab.rs"]
#[allow(dead_code)]
mod slab;

use std::collections::BTreeMap;
use std::time::Instant;

use formfactor::ordinates::{auto_bin_count, OrdinatesOptions};
use slab::{
    case_parameters, case_radiances, disort_slab_cases, reflected_radiance, slab_extinction,
    solve_slab_with, solve_zonal_slab, transmitted_radiance, zonal_fluxes, zonal_radiance,
    zonal_slab_coupling,
};

/// Smallest DISORT diffuse transmittance whose radiances enter the summary.
const SUMMARY_MIN_T: f64 = 1e-6;

fn list<T: std::str::FromStr>(key: &str) -> Option<Vec<T>>
where
    T::Err: std::fmt::Debug,
{
    std::env::var(key)
        .ok()
        .map(|v| v.split(',').map(|x| x.trim().parse().unwrap()).collect())
}

/// Signed error of largest magnitude.
#[derive(Clone, Copy, Default)]
struct Worst {
    err: f64,
}

impl Worst {
    fn add(&mut self, err: f64) {
        if err.abs() > self.err.abs() {
            self.err = err;
        }
    }
    fn merge(&mut self, other: Worst) {
        self.add(other.err);
    }
}

impl std::fmt::Display for Worst {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{:+.1} %", 100.0 * self.err)
    }
}

#[derive(Clone, Copy, Default)]
struct Errors {
    reflected: Worst,
    transmitted: Worst,
    r: Worst,
    t: Worst,
}

impl Errors {
    fn merge(&mut self, other: &Errors) {
        self.reflected.merge(other.reflected);
        self.transmitted.merge(other.transmitted);
        self.r.merge(other.r);
        self.t.merge(other.t);
    }
}

fn main() {
    // `auto`: the bins volrad chooses for each case's g (`auto_bin_count`).
    let bins: Vec<Option<usize>> = list::<String>("DISORT_BINS").map_or(vec![Some(96)], |l| {
        l.iter()
            .map(|b| (b != "auto").then(|| b.parse().expect("DISORT_BINS: 6 n² or auto")))
            .collect()
    });
    let layers: Vec<usize> = list("DISORT_LAYERS").unwrap_or(vec![64]);
    let keep = |key: &str, value: f64| list::<f64>(key).is_none_or(|l| l.contains(&value));
    let detail = std::env::var("DISORT_DETAIL").is_ok();
    let cases: Vec<_> = disort_slab_cases()
        .into_iter()
        .filter(|c| {
            let (tau, a, g, mu0) = case_parameters(c);
            keep("DISORT_TAU", tau)
                && keep("DISORT_G", g)
                && keep("DISORT_ALBEDO", a)
                && keep("DISORT_MU0", mu0)
        })
        .collect();
    let match_asymmetry = std::env::var("DISORT_NOMATCH").is_err();
    let pq: Option<usize> = std::env::var("DISORT_PQ").ok().map(|v| v.parse().unwrap());
    let cone = std::env::var("DISORT_CONE").ok();

    let faces = |nb: usize| {
        let n = ((nb / 6) as f64).sqrt().round() as usize;
        assert_eq!(6 * n * n, nb, "bins must be 6 n²");
        n
    };
    for &bins_spec in &bins {
        let label = bins_spec.map_or("auto".to_string(), |nb| nb.to_string());
        for &nz in &layers {
            let base = OrdinatesOptions {
                phase_quadrature: pq,
                match_asymmetry,
                face_coupling: std::env::var("DISORT_MAX_SHARES").is_err(),
                linear_source: std::env::var("DISORT_FLAT").is_err(),
                match_diffusion: std::env::var("DISORT_NODIFFUSION").is_err(),
                beam_profiles: std::env::var("DISORT_NEIGHBOUR_SLOPES").is_err(),
                ..Default::default()
            };
            println!(
                "\n## discrete ordinates, {label} bins, {nz} layers{}{}{}{}{}{}{}",
                if base.face_coupling {
                    ""
                } else {
                    ", Max's face shares"
                },
                if base.linear_source && base.face_coupling {
                    ""
                } else {
                    ", flat source"
                },
                if match_asymmetry {
                    ""
                } else {
                    ", match_asymmetry off"
                },
                if base.match_diffusion {
                    ""
                } else {
                    ", match_diffusion off"
                },
                if base.beam_profiles {
                    ""
                } else {
                    ", beam_profiles off"
                },
                pq.map_or(String::new(), |k| format!(", phase quadrature {k}")),
                cone.as_ref()
                    .map_or(String::new(), |c| format!(", forward-peak cone {c}"))
            );
            let start = Instant::now();
            let mut summary: BTreeMap<(u64, u64), Errors> = BTreeMap::new();
            for case in &cases {
                let (tau, a, g, mu0) = case_parameters(case);
                let n = faces(bins_spec.unwrap_or_else(|| auto_bin_count(g, nz)));
                let t0 = Instant::now();
                let degrees = match cone.as_deref() {
                    _ if g <= 0.0 => 0.0,
                    None => 0.0,
                    Some("auto") => formfactor::ordinates::default_forward_truncation_degrees(
                        &formfactor::ordinates::DirectionBins::cube(n).unwrap(),
                        &medium::PhaseFunction::HenyeyGreenstein { g },
                    ),
                    Some(d) => d.parse().expect("DISORT_CONE: degrees or auto"),
                };
                let options = OrdinatesOptions {
                    forward_truncation_degrees: degrees,
                    ..base
                };
                let res = solve_slab_with(tau, a, g, mu0, nz, n, options);
                let errors = measure(
                    case,
                    detail,
                    |view| {
                        let (first, higher) = if view.z > 0.0 {
                            reflected_radiance(&res, tau, a, g, mu0, view)
                        } else {
                            transmitted_radiance(&res, tau, a, g, mu0, view)
                        };
                        first + higher
                    },
                    (res.r, res.t_diffuse),
                );
                report_case(case, &errors, t0.elapsed().as_secs_f64());
                fold(&mut summary, case, errors);
            }
            print_summary(&summary, start.elapsed().as_secs_f64());
        }
    }

    if std::env::var("DISORT_ZONAL").is_ok() {
        let reach: f64 = list("DISORT_ZONAL_REACH").map_or(6.0, |l: Vec<f64>| l[0]);
        let mut taus: Vec<f64> = cases.iter().map(|c| case_parameters(c).0).collect();
        taus.dedup();
        let mut summary: BTreeMap<(u64, u64), Errors> = BTreeMap::new();
        let start = Instant::now();
        for tau in taus {
            // 4 √τ layers by default: σt·h = 0.25, 0.5, 1, 2 for τ = 1, 4, 16, 64.
            let nz = list("DISORT_ZONAL_LAYERS")
                .map_or((4.0 * tau.sqrt()).round() as usize, |l: Vec<usize>| l[0]);
            let sigma_h = tau / nz as f64;
            let width = 2 * (reach / sigma_h).ceil() as usize + 1;
            let t0 = Instant::now();
            let coupling = zonal_slab_coupling(tau, nz, width);
            println!(
                "\n## zonal, {nz} layers (σt·h {sigma_h}), folded from a {width}×{width} grid ({:.1} s)",
                t0.elapsed().as_secs_f64()
            );
            let exact = slab_extinction(tau, nz);
            let (k, excess) = coupling
                .iter()
                .zip(&exact)
                .map(|(row, x)| row.iter().sum::<f64>() / x - 1.0)
                .enumerate()
                .max_by(|a, b| a.1.abs().total_cmp(&b.1.abs()))
                .unwrap();
            println!(
                "folded row sums (extinguished fraction of a layer's emission) vs the exact slab's: worst {:+.2} % (layer {k} of {nz})",
                100.0 * excess
            );
            for case in cases
                .iter()
                .filter(|c| case_parameters(c).0 == tau && case_parameters(c).2 == 0.0)
            {
                let (_, a, _, mu0) = case_parameters(case);
                let slab = solve_zonal_slab(&coupling, tau, a, mu0);
                let errors = measure(
                    case,
                    detail,
                    |view| {
                        let (first, higher) = zonal_radiance(&slab, tau, a, mu0, view);
                        first + higher
                    },
                    zonal_fluxes(&slab, tau, mu0),
                );
                report_case(case, &errors, 0.0);
                fold(&mut summary, case, errors);
            }
        }
        print_summary(&summary, start.elapsed().as_secs_f64());
    }
}

/// Errors of one case: `radiance(view)` against both radiance tables, `(R, T)` against the
/// fluxes.
fn measure(
    case: &serde_json::Value,
    detail: bool,
    radiance: impl Fn(glam::DVec3) -> f64,
    (r, t): (f64, f64),
) -> Errors {
    let mut errors = Errors::default();
    for table in ["reflected_radiance", "transmitted_diffuse_radiance"] {
        for (mu, phi, view, want) in case_radiances(case, table) {
            let got = radiance(view);
            let err = got / want - 1.0;
            if table.starts_with("reflected") {
                errors.reflected.add(err);
            } else {
                errors.transmitted.add(err);
            }
            if detail {
                println!(
                    "    {} mu {mu} phi {phi}: {got:.6e} vs {want:.6e} ({:+.2} %)",
                    &table[..11],
                    100.0 * err
                );
            }
        }
    }
    errors.r.add(r / case["R"].as_f64().unwrap() - 1.0);
    errors.t.add(t / case["T_diffuse"].as_f64().unwrap() - 1.0);
    errors
}

fn report_case(case: &serde_json::Value, e: &Errors, seconds: f64) {
    let (tau, a, g, mu0) = case_parameters(case);
    println!(
        "tau {tau:>2} g {g:<4} a {a:<4} mu0 {mu0:<3}: reflected {:>8}  transmitted {:>8}  R {:>7}  T {:>7}  ({seconds:.1} s)",
        e.reflected, e.transmitted, e.r, e.t
    );
}

fn fold(summary: &mut BTreeMap<(u64, u64), Errors>, case: &serde_json::Value, mut e: Errors) {
    let (tau, _, g, _) = case_parameters(case);
    if case["T_diffuse"].as_f64().unwrap() < SUMMARY_MIN_T {
        e.transmitted = Worst::default();
        e.t = Worst::default();
    }
    summary
        .entry(((tau * 1000.0) as u64, (g * 1000.0) as u64))
        .or_default()
        .merge(&e);
}

fn print_summary(summary: &BTreeMap<(u64, u64), Errors>, seconds: f64) {
    println!(
        "\nworst over albedo and μ0 (signed; transmitted radiance and T only where T_diffuse ≥ {SUMMARY_MIN_T:e}); {seconds:.0} s\n"
    );
    println!("| τ | g | reflected radiance | transmitted radiance | R | T |");
    println!("|---|---|---|---|---|---|");
    for (&(tau, g), e) in summary {
        println!(
            "| {} | {} | {} | {} | {} | {} |",
            tau as f64 / 1000.0,
            g as f64 / 1000.0,
            e.reflected,
            e.transmitted,
            e.r,
            e.t
        );
    }
}
