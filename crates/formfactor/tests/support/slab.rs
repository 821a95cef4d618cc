//! A plane-parallel slab solved by discrete ordinates in one periodic column, and its
//! reflected radiance as the final gather forms it; DISORT's cases. Shared by the slab tests
//! (tests/ordinates_slab.rs) and the slab explorer (examples/slab_explorer.rs).

use formfactor::ordinates::bins::face_bilinear;
use formfactor::ordinates::{DirectionBins, OrdinatesOperator, OrdinatesOptions};
use glam::DVec3;
use medium::{CellValues, ChannelMedium, Grid, Interpolation, Medium, PhaseFunction};
use solver::operator::TransportOperator;

pub struct SlabResult {
    pub r: f64,
    pub t_diffuse: f64,
    pub imbalance: f64,
    /// The operator and the final gather's higher-order source at the bin centres
    /// ([`OrdinatesOperator::gather_density`] of the solution).
    pub op: OrdinatesOperator,
    pub gathered: Vec<f64>,
}

/// Solves a slab of optical depth `tau` with `nz` layers in one periodic column, beam of flux
/// 1 (on a plane perpendicular to it) at `cos θ0 = mu0` onto the top (+z) face.
pub fn solve_slab(tau: f64, albedo: f64, g: f64, mu0: f64, nz: usize, n: usize) -> SlabResult {
    solve_slab_with(tau, albedo, g, mu0, nz, n, OrdinatesOptions::default())
}

pub fn solve_slab_with(
    tau: f64,
    albedo: f64,
    g: f64,
    mu0: f64,
    nz: usize,
    n: usize,
    base: OrdinatesOptions,
) -> SlabResult {
    let grid = Grid::new([1, 1, nz], 1.0).unwrap();
    let sigma = tau / nz as f64;
    let channel = ChannelMedium {
        sigma_t: vec![sigma as f32; nz],
        albedo: CellValues::Uniform(albedo as f32),
        emission: CellValues::Uniform(0.0),
    };
    let options = OrdinatesOptions {
        periodic_xy: true,
        // Fewer phase-matrix nodes for the 384-bin set keep the test fast.
        phase_quadrature: base.phase_quadrature.or((n > 6).then_some(3)),
        ..base
    };
    let medium = Medium::new(
        grid,
        vec![channel],
        PhaseFunction::HenyeyGreenstein { g },
        Interpolation::Nearest,
        None,
    )
    .unwrap();
    let op = OrdinatesOperator::new(&medium, 0, DirectionBins::cube(n).unwrap(), options).unwrap();
    // Exact cell means of E0 T_L for the beam: layer at depth t (from the top) sees
    // e^{−σ t h/μ0} (1 − e^{−σh/μ0}) / (σh/μ0).
    let a = sigma / mu0;
    let irradiance: Vec<f64> = (0..nz)
        .map(|k| {
            let depth = (nz - 1 - k) as f64;
            (-a * depth).exp() * (-(-a).exp_m1()) / a
        })
        .collect();
    let dir = DVec3::new((1.0 - mu0 * mu0).sqrt(), 0.0, -mu0);
    let external = op.external_density(None, &[(dir, &irradiance)]).unwrap();
    let len = op.len();
    let mut e = vec![0.0; len];
    op.transport(&external, &mut e);
    // Source iteration I ← E + K I.
    let mut x = e.clone();
    let mut y = vec![0.0; len];
    let norm_e: f64 = e.iter().map(|v| v * v).sum::<f64>().sqrt();
    for _ in 0..2000 {
        op.apply(&x, &mut y);
        let mut change = 0.0;
        for i in 0..len {
            let new = e[i] + y[i];
            change += (new - x[i]) * (new - x[i]);
            x[i] = new;
        }
        if change.sqrt() < 1e-10 * norm_e {
            break;
        }
    }
    let balance = op.energy_balance(&x, &external);
    SlabResult {
        r: balance.escaped[5] / mu0,
        t_diffuse: balance.escaped[4] / mu0,
        imbalance: balance.relative_imbalance(),
        gathered: {
            let mut gathered = vec![0.0; len];
            op.gather_density(&x, &mut gathered);
            gathered
        },
        op,
    }
}

pub fn disort_cases() -> Vec<serde_json::Value> {
    let text = include_str!("../data/disort.json");
    let v: serde_json::Value = serde_json::from_str(text).unwrap();
    v["cases"].as_array().unwrap().clone()
}

/// Reflected radiance leaving the top of the slab along the upward unit `view` (flow
/// direction), as the final gather forms it: the exact first bounce (true phase function,
/// analytic in depth) plus the higher orders from the solution, the library's final-gather
/// source at the bin centres ([`OrdinatesOperator::gather_density`]: true phase function)
/// interpolated to `view` as the renderer does ([`face_bilinear`]), constant per layer and
/// integrated along the view ray through the layers. Returns (first bounce, higher orders).
pub fn reflected_radiance(
    res: &SlabResult,
    tau: f64,
    albedo: f64,
    g: f64,
    mu0: f64,
    view: DVec3,
) -> (f64, f64) {
    let op = &res.op;
    let nz = op.grid().dims[2];
    let m = op.bins().len();
    let phase = PhaseFunction::HenyeyGreenstein { g };
    let mu = view.z;
    let beam = DVec3::new((1.0 - mu0 * mu0).sqrt(), 0.0, -mu0);
    let first = albedo * phase.eval(view.dot(beam)) * mu0 / (mu0 + mu)
        * -(-tau * (1.0 / mu0 + 1.0 / mu)).exp_m1();
    let weights = face_bilinear(op.bins().face_divisions(), view);
    let sigma = tau / nz as f64;
    let slant = sigma / mu;
    let mut higher = 0.0;
    for k in 0..nz {
        let q: f64 = weights
            .iter()
            .map(|&(l, w)| w * res.gathered[k * m + l])
            .sum();
        let above = (nz - 1 - k) as f64;
        higher += q * (-slant * above).exp() * -(-slant).exp_m1() / sigma;
    }
    (first, higher)
}
