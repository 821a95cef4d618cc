//! A plane-parallel slab solved by discrete ordinates in one periodic column (and, for
//! isotropic scattering, by the zonal method folded onto one column), its reflected and
//! transmitted radiance as the final gather forms it; DISORT's cases. Shared by the slab tests
//! (tests/it/ordinates_slab.rs, tests/it/disort_slabs.rs) and the examples slab_explorer and
//! disort_slabs.

use formfactor::ordinates::bins::interpolate_bins;
use formfactor::ordinates::{
    gauss_legendre_unit, BeamProfiles, DirectionBins, OrdinatesOperator, OrdinatesOptions,
};
use formfactor::{ExactOptions, FormFactorMatrix};
use glam::DVec3;
use medium::{CellValues, ChannelMedium, Grid, Interpolation, Medium, PhaseFunction};
use solver::operator::TransportOperator;
use solver::{Method, SolveControl, SolveOptions};

pub struct SlabResult {
    pub r: f64,
    pub t_diffuse: f64,
    pub imbalance: f64,
    /// The operator and the final gather's higher-order source at the bin centres
    /// ([`OrdinatesOperator::gather_density`] of the solution).
    pub op: OrdinatesOperator,
    pub gathered: Vec<f64>,
    /// The solved radiance (cell-major, `x[c·M + l]`), every order of scattering.
    pub radiance: Vec<f64>,
}

/// The operator of a slab of optical depth `tau` (albedo, Henyey–Greenstein g, beam at
/// `cos θ0 = mu0` onto the top face) in `nz` layers of one periodic column and `6 n²` bins,
/// the beam's first-scattering density and its profiles in the layers.
pub fn slab_operator(
    (tau, albedo, g, mu0): (f64, f64, f64, f64),
    nz: usize,
    n: usize,
    base: OrdinatesOptions,
) -> (OrdinatesOperator, Vec<f64>, BeamProfiles) {
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
    let external = op.external_density(&[(dir, &irradiance)]).unwrap();
    // The beam's optical depth falls by σh/μ0 from each layer's lower face to its upper.
    let depth_change = vec![[0.0, 0.0, -a]; nz];
    let beams = op
        .beam_profiles(&[(dir, &irradiance, &depth_change)])
        .unwrap();
    (op, external, beams)
}

/// The flux reflectance of the beam's first scattering alone (one transport of it, the
/// power escaping through the top over the power incident).
pub fn first_order_reflectance(
    case: (f64, f64, f64, f64),
    nz: usize,
    n: usize,
    options: OrdinatesOptions,
) -> f64 {
    let (op, external, beams) = slab_operator(case, nz, n, options);
    let mut out = vec![0.0; op.len()];
    let energy = op.transport_first_bounce(&external, &beams, &mut out, None);
    energy.escaped[5] / case.3
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
    let (op, external, beams) = slab_operator((tau, albedo, g, mu0), nz, n, base);
    let len = op.len();
    let mut e = vec![0.0; len];
    op.transport_first_bounce(&external, &beams, &mut e, None);
    // I = E + K I by GMRES: source iteration needs tens of thousands of sweeps for the thick,
    // conservative slabs (spectral radius 1 − O(1/τ²)).
    let options = SolveOptions {
        method: Method::Gmres { restart: 200 },
        tolerance: 1e-10,
        max_iterations: 20_000,
        record_history: false,
    };
    let (x, report) = solver::solve(&op, &e, None, &options, &SolveControl::new()).unwrap();
    assert!(
        report.converged,
        "slab tau {tau} a {albedo} g {g} mu0 {mu0}: {} after {} iterations, residual {:.1e}",
        report.stop_reason, report.iterations, report.final_residual
    );
    let balance = op.energy_balance(&x, &external, Some(&beams));
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
        radiance: x,
    }
}

/// The cases of tests/data/disort.json (τ = 1; 64 streams).
pub fn disort_cases() -> Vec<serde_json::Value> {
    cases_of(include_str!("../data/disort.json"))
}

/// The cases of tests/data/disort_slabs.json (τ = 1 … 64, g = 0 … 0.9; 128 streams), made by
/// tests/data/make_disort_slabs.py.
pub fn disort_slab_cases() -> Vec<serde_json::Value> {
    cases_of(include_str!("../data/disort_slabs.json"))
}

fn cases_of(text: &str) -> Vec<serde_json::Value> {
    let v: serde_json::Value = serde_json::from_str(text).unwrap();
    v["cases"].as_array().unwrap().clone()
}

/// A case's `(τ, albedo, g, μ0)`.
pub fn case_parameters(case: &serde_json::Value) -> (f64, f64, f64, f64) {
    let get = |key: &str| case[key].as_f64().unwrap();
    (get("tau"), get("albedo"), get("g"), get("mu0"))
}

/// A case's radiances of one table (`"reflected_radiance"` or
/// `"transmitted_diffuse_radiance"`): `(μ, φ in degrees, view, value)`, the view the unit
/// direction of travel (up for reflection, down for transmission; φ = 0 travels the beam's
/// horizontal way, +x).
pub fn case_radiances(case: &serde_json::Value, table: &str) -> Vec<(f64, f64, DVec3, f64)> {
    let up = table.starts_with("reflected");
    let mut out = Vec::new();
    for (mu_key, angles) in case[table].as_object().unwrap() {
        let mu: f64 = mu_key.trim_start_matches("mu=").parse().unwrap();
        for (phi_key, value) in angles.as_object().unwrap() {
            let phi: f64 = phi_key.trim_start_matches("phi=").parse().unwrap();
            let s = (1.0 - mu * mu).sqrt();
            let (sp, cp) = phi.to_radians().sin_cos();
            let z = if up { mu } else { -mu };
            out.push((
                mu,
                phi,
                DVec3::new(s * cp, s * sp, z),
                value.as_f64().unwrap(),
            ));
        }
    }
    out
}

/// Layer `k`'s final-gather source towards `view`, interpolated between bin centres as the
/// renderer does ([`interpolate_bins`]).
fn gathered_towards(res: &SlabResult, k: usize, view: DVec3) -> f64 {
    let m = res.op.bins().len();
    let layer = &res.gathered[k * m..(k + 1) * m];
    interpolate_bins(
        res.op.bins().face_divisions(),
        view,
        |l| layer[l],
        |l| layer[l].ln(),
    )
}

/// Reflected radiance leaving the top of the slab along the upward unit `view` (flow
/// direction), as the final gather forms it: the exact first bounce (true phase function,
/// analytic in depth) plus the higher orders from the solution, the library's final-gather
/// source at the bin centres ([`OrdinatesOperator::gather_density`]: true phase function)
/// interpolated to `view` as the renderer does ([`interpolate_bins`]), constant per layer and
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
    let first = reflected_first_bounce(tau, albedo, g, mu0, view);
    let higher = column_integral(tau, nz, view.z, true, |k| gathered_towards(res, k, view));
    (first, higher)
}

/// Diffuse radiance leaving the bottom of the slab along the downward unit `view` (flow
/// direction), formed as [`reflected_radiance`] forms the reflected one: the exact first
/// bounce plus the final gather's higher-order source interpolated to `view`, integrated down
/// through the layers. Returns (first bounce, higher orders).
pub fn transmitted_radiance(
    res: &SlabResult,
    tau: f64,
    albedo: f64,
    g: f64,
    mu0: f64,
    view: DVec3,
) -> (f64, f64) {
    let op = &res.op;
    let nz = op.grid().dims[2];
    let first = transmitted_first_bounce(tau, albedo, g, mu0, view);
    let higher = column_integral(tau, nz, -view.z, false, |k| gathered_towards(res, k, view));
    (first, higher)
}

/// Single-scattered radiance leaving the bottom along the downward `view`:
/// `a p μ0/(μ − μ0) (e^{−τ/μ} − e^{−τ/μ0})`, `a p τ/μ0 e^{−τ/μ0}` at `μ = μ0`.
pub fn transmitted_first_bounce(tau: f64, albedo: f64, g: f64, mu0: f64, view: DVec3) -> f64 {
    let phase = PhaseFunction::HenyeyGreenstein { g };
    let beam = DVec3::new((1.0 - mu0 * mu0).sqrt(), 0.0, -mu0);
    let mu = -view.z;
    let p = albedo * phase.eval(view.dot(beam));
    if (mu - mu0).abs() < 1e-9 {
        p * tau / mu0 * (-tau / mu0).exp()
    } else {
        p * mu0 / (mu - mu0) * ((-tau / mu).exp() - (-tau / mu0).exp())
    }
}

/// Single-scattered radiance leaving the top along the upward `view`:
/// `a p μ0/(μ0 + μ) (1 − e^{−τ(1/μ0 + 1/μ)})`.
pub fn reflected_first_bounce(tau: f64, albedo: f64, g: f64, mu0: f64, view: DVec3) -> f64 {
    let phase = PhaseFunction::HenyeyGreenstein { g };
    let beam = DVec3::new((1.0 - mu0 * mu0).sqrt(), 0.0, -mu0);
    let mu = view.z;
    albedo * phase.eval(view.dot(beam)) * mu0 / (mu0 + mu)
        * -(-tau * (1.0 / mu0 + 1.0 / mu)).exp_m1()
}

/// `∫ Q e^{−t} ds` along a ray leaving the slab (`nz` layers of optical depth `τ/nz`, cell
/// size 1) at direction cosine `mu` to the face it leaves through (`up`: the top), `Q` constant
/// per layer (`source(k)`, k = 0 the bottom layer).
pub fn column_integral(
    tau: f64,
    nz: usize,
    mu: f64,
    up: bool,
    source: impl Fn(usize) -> f64,
) -> f64 {
    let sigma = tau / nz as f64;
    let slant = sigma / mu;
    (0..nz)
        .map(|k| {
            let between = if up { nz - 1 - k } else { k } as f64;
            source(k) * (-slant * between).exp() * -(-slant).exp_m1() / sigma
        })
        .sum()
}

/// A slab solved by the zonal method (isotropic scattering): per layer (k = 0 the bottom) the
/// first-bounce source `E_k` and the solution `g_k` of `g = E + a K g`, radiance per length.
pub struct ZonalSlab {
    pub first: Vec<f64>,
    pub solution: Vec<f64>,
}

/// The zonal form factors of a slab of `nz` layers (optical depth `tau`), folded onto one
/// column: `K[k][k'] = Σ_j F(c_k, j)` over the cells `j` of layer `k'`, `c_k` the centre
/// cell of layer `k`, from an exact [`FormFactorMatrix`] on a `width × width × nz` grid of unit
/// cubes. By translation invariance that is an infinite slab's layer-to-layer coupling, less
/// what reaches cells more than `width/2` cells away sideways. Independent of albedo and beam.
pub fn zonal_slab_coupling(tau: f64, nz: usize, width: usize) -> Vec<Vec<f64>> {
    let grid = Grid::new([width, width, nz], 1.0).unwrap();
    let channel = ChannelMedium {
        sigma_t: vec![(tau / nz as f64) as f32; grid.cell_count()],
        albedo: CellValues::Uniform(1.0),
        emission: CellValues::Uniform(0.0),
    };
    let medium = Medium::new(
        grid,
        vec![channel],
        PhaseFunction::Isotropic,
        Interpolation::Nearest,
        None,
    )
    .unwrap();
    let zonal = FormFactorMatrix::build(&medium, 0, &ExactOptions::default(), None).unwrap();
    let c = width / 2;
    let mut coupling = vec![vec![0.0; nz]; nz];
    let matrix = zonal.matrix();
    for (k, row) in coupling.iter_mut().enumerate() {
        let i = grid.index(c, c, k);
        for (j, &f) in matrix.outer_view(i).unwrap().iter() {
            row[grid.coords(j)[2]] += f;
        }
    }
    coupling
}

/// Solves the folded zonal slab ([`zonal_slab_coupling`]) for albedo `albedo` and a beam of
/// flux 1 at `cos θ0 = mu0`: `E_k = a σt ⟨T_L⟩_k / 4π` (physics.md), `(I − a K) g = E` by
/// Gaussian elimination.
pub fn solve_zonal_slab(coupling: &[Vec<f64>], tau: f64, albedo: f64, mu0: f64) -> ZonalSlab {
    let nz = coupling.len();
    let sigma = tau / nz as f64;
    let a = sigma / mu0;
    let first: Vec<f64> = (0..nz)
        .map(|k| {
            let depth = (nz - 1 - k) as f64;
            let mean_t = (-a * depth).exp() * (-(-a).exp_m1()) / a;
            albedo * sigma * mean_t / (4.0 * std::f64::consts::PI)
        })
        .collect();
    // Dense (I − aK) g = E with partial pivoting.
    let mut m: Vec<Vec<f64>> = (0..nz)
        .map(|k| {
            let mut row: Vec<f64> = coupling[k].iter().map(|f| -albedo * f).collect();
            row[k] += 1.0;
            row.push(first[k]);
            row
        })
        .collect();
    for col in 0..nz {
        let pivot = (col..nz)
            .max_by(|&p, &q| m[p][col].abs().total_cmp(&m[q][col].abs()))
            .unwrap();
        m.swap(col, pivot);
        let (upper, lower) = m.split_at_mut(col + 1);
        let pivot_row = &upper[col];
        for row in lower {
            let f = row[col] / pivot_row[col];
            for (x, p) in row[col..].iter_mut().zip(&pivot_row[col..]) {
                *x -= f * p;
            }
        }
    }
    let mut solution = vec![0.0; nz];
    for r in (0..nz).rev() {
        let s: f64 = (r + 1..nz).map(|c| m[r][c] * solution[c]).sum();
        solution[r] = (m[r][nz] - s) / m[r][r];
    }
    ZonalSlab { first, solution }
}

/// Radiance of the zonal slab leaving along the unit `view` (up: reflected at the top, down:
/// transmitted at the bottom): the exact first bounce plus the isotropic higher-order source
/// `g − E` integrated along the view. Returns (first bounce, higher orders).
pub fn zonal_radiance(
    slab: &ZonalSlab,
    tau: f64,
    albedo: f64,
    mu0: f64,
    view: DVec3,
) -> (f64, f64) {
    let up = view.z > 0.0;
    let first = if up {
        reflected_first_bounce(tau, albedo, 0.0, mu0, view)
    } else {
        transmitted_first_bounce(tau, albedo, 0.0, mu0, view)
    };
    let nz = slab.solution.len();
    let higher = column_integral(tau, nz, view.z.abs(), up, |k| {
        slab.solution[k] - slab.first[k]
    });
    (first, higher)
}

/// The exact fraction of a uniform isotropic emission in layer `k` of the slab (`nz` layers,
/// optical depth `tau`) that is extinguished inside the slab: `1 − [E3(t) − E3(t + Δ)]/(2Δ)`
/// summed over both faces, `t` the optical depth from the layer to the face, `Δ = τ/nz`. The
/// folded zonal coupling's row sums estimate it.
pub fn slab_extinction(tau: f64, nz: usize) -> Vec<f64> {
    let (nodes, weights): (Vec<f64>, Vec<f64>) = gauss_legendre_unit(200).into_iter().unzip();
    let e3 = |t: f64| -> f64 {
        nodes
            .iter()
            .zip(&weights)
            .map(|(&mu, &w)| w * mu * (-t / mu).exp())
            .sum()
    };
    let d = tau / nz as f64;
    (0..nz)
        .map(|k| {
            let (top, bottom) = ((nz - 1 - k) as f64 * d, k as f64 * d);
            1.0 - (e3(top) - e3(top + d) + e3(bottom) - e3(bottom + d)) / (2.0 * d)
        })
        .collect()
}

/// Zonal flux reflectance and diffuse transmittance (per μ0) of the slab: the higher-order
/// source's escape through the top and bottom (each layer's isotropic source `Q` leaving a
/// face of an infinite slab: `2π Q ∫₀¹ (1 − e^{−σh/μ}) e^{−t/μ} μ dμ / σ`, `t` the optical
/// depth between the layer and the face) plus the first bounce's, all per μ0.
pub fn zonal_fluxes(slab: &ZonalSlab, tau: f64, mu0: f64) -> (f64, f64) {
    let nz = slab.solution.len();
    // Escape through one face by Gauss–Legendre in μ (64 nodes on (0, 1)).
    let (nodes, weights): (Vec<f64>, Vec<f64>) = gauss_legendre_unit(64).into_iter().unzip();
    let flux = |up: bool| -> f64 {
        nodes
            .iter()
            .zip(&weights)
            .map(|(&mu, &w)| {
                w * mu
                    * 2.0
                    * std::f64::consts::PI
                    * column_integral(tau, nz, mu, up, |k| slab.solution[k])
            })
            .sum::<f64>()
    };
    (flux(true) / mu0, flux(false) / mu0)
}
