//! What a solve will cost in time, predicted before any work: what `volrad info` prints and
//! the progress bar shows from the start.
//!
//! [`solve_time`] sums named parts — the light pass, the emitter pass, each method's operator
//! build and its iterations — each a count of work (cells, direction bins, links, pairs of
//! cells, rays) times seconds per unit measured on the project's 2-core machine, scaled to the
//! solve's worker threads. The one quantity not counted from the scene is the number of
//! iterations: it follows from the spectral radius of the scattering operator, which
//! [`spectral_radius_estimate`] takes from diffusion theory — the fundamental mode of a region
//! as thick as the medium's optical size along each axis — and from how each iteration
//! contracts at that radius. `benches/memory.py` compares the prediction with measured solve
//! times (docs/performance.md, "Time").

use std::fmt;
use std::time::Duration;

use scene::{Scene, SolveMethod, SolveSettings};

use super::budget::{transport_scale, transport_split, Occupancy};

/// One term of a prediction.
#[derive(Clone, Debug, serde::Serialize)]
pub struct TimePart {
    pub what: &'static str,
    pub seconds: f64,
}

/// A predicted solve time, in named parts.
#[derive(Clone, Debug, serde::Serialize)]
pub struct TimeEstimate {
    parts: Vec<TimePart>,
    /// Iterations per channel the linear solve is expected to take (`None`: no linear solve).
    iterations: Option<usize>,
    /// The estimated spectral radius of the scattering operator (the largest of the channels).
    spectral_radius: Option<f64>,
    threads: usize,
}

impl TimeEstimate {
    pub fn total(&self) -> Duration {
        Duration::from_secs_f64(self.parts.iter().map(|p| p.seconds).sum::<f64>().max(0.0))
    }

    pub fn iterations(&self) -> Option<usize> {
        self.iterations
    }

    pub fn spectral_radius(&self) -> Option<f64> {
        self.spectral_radius
    }
}

impl fmt::Display for TimeEstimate {
    /// `about 12 s on 2 threads (the hierarchical operator 9.1 s, 6 iterations 0.4 s, …)`.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "about {} on {} thread{}",
            duration_text(self.total()),
            self.threads,
            if self.threads == 1 { "" } else { "s" }
        )?;
        let shown: Vec<String> = self
            .parts
            .iter()
            .filter(|p| p.seconds >= 0.05)
            .map(|p| {
                format!(
                    "{} {}",
                    p.what,
                    duration_text(Duration::from_secs_f64(p.seconds))
                )
            })
            .collect();
        if !shown.is_empty() {
            write!(f, " ({})", shown.join(", "))?;
        }
        Ok(())
    }
}

/// `0.4 s`, `12 s`, `3 min 20 s`, `2 h 5 min`.
pub fn duration_text(t: Duration) -> String {
    let s = t.as_secs_f64();
    if s < 9.95 {
        format!("{s:.1} s")
    } else if s < 59.5 {
        format!("{s:.0} s")
    } else if s < 3600.0 {
        let s = s.round() as u64;
        format!("{} min {} s", s / 60, s % 60)
    } else {
        let m = (s / 60.0).round() as u64;
        format!("{} h {} min", m / 60, m % 60)
    }
}

// Seconds per unit of work on the 2-core machine the coefficients were measured on
// (docs/performance.md, "Time"; `benches/memory.py`).
/// The process and the scene's set-up.
const BASE_SECONDS: f64 = 0.03;
/// Per data cell and channel, whatever the method: the first bounce's fields at the data's
/// resolution, coarsening them for a transport grid, the solution file.
const DATA_GRID_SECONDS_PER_CELL: f64 = 2.0e-7;
/// The light pass, per cell, channel and light (an environment counts as
/// [`ENVIRONMENT_LIGHTS`]).
const LIGHT_PASS_SECONDS_PER_CELL_LIGHT: f64 = 5.0e-8;
const ENVIRONMENT_LIGHTS: f64 = 2.0;
/// The emitter pass, per ray (measured on Kobayashi's benchmark: 39 M rays in 7.7 s).
const EMITTER_SECONDS_PER_RAY: f64 = 2.0e-7;
/// Exact zonal: building the form factors, and one application, per pair of non-empty cells.
const ZONAL_BUILD_SECONDS_PER_PAIR: f64 = 2.1e-7;
const ZONAL_APPLY_SECONDS_PER_PAIR: f64 = 8.0e-10;
/// Hierarchical zonal: building, and one application, per link.
const HIERARCHICAL_BUILD_SECONDS_PER_LINK: f64 = 1.3e-7;
const HIERARCHICAL_APPLY_SECONDS_PER_LINK: f64 = 1.6e-9;
/// Discrete ordinates: the set-up (first-scattering source, the stored field, the file) per
/// cell and bin; per sweep, the transport per cell and bin, the scattering product per cell
/// it multiplies ([`Occupancy::ordinates_product_cells`]) and `bins^1.5` (an `M²` product
/// that runs faster per multiply-add the larger `M` is), and the cost of a state larger than
/// the caches, per cell and bin, growing to its full value at
/// [`ORDINATES_CACHED_CELL_BINS`]. The product and cache terms were fitted on nine solves from
/// 0.6 M to 21 M cell-bins (clouds, uniform blocks, Kobayashi's shield; 24–384 bins), the sweep
/// and uncached terms refitted to the face-coupled sweep on the seven cases of
/// `benches/ordinates_sweep.py`, which prints the model against the measured sweeps
/// (docs/performance.md, "Time"), and all three again (least squares in relative error, on
/// the same cases: −13 … +5 %) when the sweep stopped copying the iterate and the source
/// into bin-major order.
const ORDINATES_SETUP_SECONDS_PER_CELL_BIN: f64 = 7.0e-8;
const ORDINATES_SWEEP_SECONDS_PER_CELL_BIN: f64 = 5.6e-9;
const ORDINATES_PRODUCT_SECONDS_PER_CELL_BIN_ROOT_BIN: f64 = 1.0e-9;
const ORDINATES_UNCACHED_SECONDS_PER_CELL_BIN: f64 = 9.6e-9;
const ORDINATES_CACHED_CELL_BINS: f64 = 2.0e7;
/// Two-pass: per cell and tally bin (the tallies and their sum), and per photon and cell
/// along the grid's longest side (a photon's path crosses cells in proportion to it).
const TWO_PASS_SECONDS_PER_CELL_BIN: f64 = 6.0e-8;
const TWO_PASS_SECONDS_PER_PHOTON_SIDE: f64 = 9.0e-9;
/// The ground's rounds of coupling with the medium: each solves the medium again from the
/// last solution, the early ones loosely, so their iterations add up to about one solve's
/// (measured: 20 + 14 + 26 against 60); each round gathers the medium's light on the
/// ground's patches.
const GROUND_ROUNDS: f64 = 3.0;
const GROUND_SECONDS_PER_PATCH_ROUND: f64 = 2.0e-6;
/// The threads the coefficients were measured with.
const MEASURED_THREADS: f64 = 2.0;

/// The predicted time of solving `scene` with `settings` on `threads` worker threads;
/// `occupancy` is [`Occupancy::of`] its medium.
pub fn solve_time(
    scene: &Scene,
    settings: &SolveSettings,
    occupancy: &Occupancy,
    threads: usize,
) -> TimeEstimate {
    let medium = &scene.medium;
    let grid = medium.grid();
    let channels = medium.channels().len().max(1) as f64;
    let cells = grid.cell_count() as f64;
    let scale = transport_scale(scene, settings);
    // A split transport grid has split³ cells per data cell.
    let parts_per_cell = transport_split(scene, settings).pow(3) as f64;
    let transport_cells = super::budget::transport_cell_count(scene, settings) as f64;
    let transport_occupied = occupancy.at(scale) as f64 * parts_per_cell;
    let mut parts = vec![TimePart {
        what: "set-up",
        seconds: BASE_SECONDS,
    }];
    let lights = scene.lights.len() as f64
        + if scene.environment.is_some() {
            ENVIRONMENT_LIGHTS
        } else {
            0.0
        };
    parts.push(TimePart {
        what: "the light pass and the data grid's fields",
        seconds: cells
            * channels
            * (DATA_GRID_SECONDS_PER_CELL + lights * LIGHT_PASS_SECONDS_PER_CELL_LIGHT),
    });
    if parts_per_cell > 1.0 {
        parts.push(TimePart {
            what: "the light pass on the split transport grid",
            seconds: transport_cells * channels * lights * LIGHT_PASS_SECONDS_PER_CELL_LIGHT,
        });
    }
    let rays: f64 = super::methods::emitter_pass_plans(scene, settings)
        .iter()
        .filter(|p| p.runs)
        .map(|p| p.rays_per_cell * p.cells as f64)
        .sum();
    if rays > 0.0 {
        parts.push(TimePart {
            what: "the emitter pass",
            seconds: rays * EMITTER_SECONDS_PER_RAY,
        });
    }

    let rho = spectral_radius_estimate(scene, settings);
    let sweep_power = gauss_seidel_power(settings.method, scene.medium.phase().mean_cosine());
    let iterations = settings
        .method
        .solves_linear_system()
        .then(|| expected_iterations(&settings.iteration, rho, settings.tolerance, sweep_power))
        .map(|n| n.min(settings.max_iterations));
    let applications = iterations.map_or(0.0, |n| {
        n as f64 * applications_per_iteration(&settings.iteration)
    });
    if let Some(ground) = &scene.ground {
        if settings.method.solves_linear_system() || settings.method == SolveMethod::TwoPass {
            let patches =
                medium::ground::GroundPatches::covering(ground, grid, &scene.lights).count();
            parts.push(TimePart {
                what: "the ground's coupling",
                seconds: channels * GROUND_ROUNDS * patches as f64 * GROUND_SECONDS_PER_PATCH_ROUND,
            });
        }
    }
    let iterations_label = "the iterations";
    // An operator built once per channel from `units` (pairs, links), then applied in
    // every iteration.
    let mut operator = |what: &'static str, units: f64, build: f64, apply: f64| {
        parts.push(TimePart {
            what,
            seconds: channels * units * build,
        });
        parts.push(TimePart {
            what: iterations_label,
            seconds: channels * applications * units * apply,
        });
    };
    match settings.method {
        SolveMethod::None | SolveMethod::SingleScatter => {}
        SolveMethod::Zonal => operator(
            "the form factors",
            transport_occupied * transport_occupied,
            ZONAL_BUILD_SECONDS_PER_PAIR,
            ZONAL_APPLY_SECONDS_PER_PAIR,
        ),
        SolveMethod::ZonalHierarchical => operator(
            "the hierarchical operator",
            transport_occupied * far_links_per_occupied_cell(transport_occupied)
                + (transport_occupied
                    - occupancy.hierarchy_shared_rows(scale) as f64 * parts_per_cell)
                    .max(0.0)
                    * NEAR_ENTRIES_PER_STORED_ROW,
            HIERARCHICAL_BUILD_SECONDS_PER_LINK,
            HIERARCHICAL_APPLY_SECONDS_PER_LINK,
        ),
        SolveMethod::DiscreteOrdinates => {
            let bins = super::budget::direction_bins(scene, settings) as f64;
            let cell_bins = transport_cells * bins;
            parts.push(TimePart {
                what: "the sweeps' set-up and stored field",
                seconds: channels * cell_bins * ORDINATES_SETUP_SECONDS_PER_CELL_BIN,
            });
            let product_cells = occupancy.ordinates_product_cells(scale) as f64 * parts_per_cell;
            let uncached = (cell_bins / ORDINATES_CACHED_CELL_BINS).min(1.0);
            let per_sweep = cell_bins
                * (ORDINATES_SWEEP_SECONDS_PER_CELL_BIN
                    + uncached * ORDINATES_UNCACHED_SECONDS_PER_CELL_BIN)
                + product_cells
                    * bins
                    * bins.sqrt()
                    * ORDINATES_PRODUCT_SECONDS_PER_CELL_BIN_ROOT_BIN;
            parts.push(TimePart {
                what: iterations_label,
                seconds: channels * applications * per_sweep,
            });
        }
        SolveMethod::TwoPass => {
            let bins = super::methods::two_pass_bins(&medium.phase());
            let bins = (bins.n_theta * bins.n_phi) as f64;
            let side = grid.dims.into_iter().max().unwrap_or(1) as f64;
            parts.push(TimePart {
                what: "the photons and tallies",
                seconds: channels
                    * (cells * bins * TWO_PASS_SECONDS_PER_CELL_BIN
                        + settings.photons as f64 * side * TWO_PASS_SECONDS_PER_PHOTON_SIDE),
            });
        }
    }
    let speed = MEASURED_THREADS / threads.max(1) as f64;
    for p in &mut parts {
        p.seconds *= speed;
    }
    TimeEstimate {
        parts,
        iterations,
        spectral_radius: settings.method.solves_linear_system().then_some(rho),
        threads: threads.max(1),
    }
}

/// Links of the hierarchical operator beyond the near field per non-empty cell: they grow
/// with the log of the cells (each level of the cluster tree adds its interactions; measured
/// 208 per cell at 3 × 10³ non-empty cells and 396 at 2.4 × 10⁴ on clouds; fewer in uniform
/// and dense media: 191 and 244 on uniform 24³ and 40³ blocks, 349 on Kobayashi's 60³; the
/// `links_per_level` of `RUST_LOG=info volrad solve`'s `hierarchy built` line).
fn far_links_per_occupied_cell(occupied: f64) -> f64 {
    (50.0 * occupied.max(2.0).log2() - 370.0).max(100.0)
}

/// Near-field entries of a non-empty cell whose row is stored (not shared): its non-empty
/// neighbours within the near radius (measured 434–568 on clouds, 728 of 728 in a dense
/// shield's mixed border).
const NEAR_ENTRIES_PER_STORED_ROW: f64 = 600.0;

/// Applications of the operator per iteration.
fn applications_per_iteration(iteration: &solver::Method) -> f64 {
    match iteration {
        solver::Method::BiCgStab => 2.0,
        solver::Method::TwoLevelCg { smoothing } => 1.0 + *smoothing as f64,
        _ => 1.0,
    }
}

/// The spectral radius of the scattering operator `K` (the fraction of scattered light that
/// scatters again, in its slowest mode), estimated from diffusion theory: the fundamental mode
/// of a block as thick as the medium's largest optical depth along each axis (extrapolated
/// by 0.71 mean free paths on each side) has buckling `B² = Σ (π / τ_axis)²`, and
/// `ρ = ω / (1 + B² / (3 (1 − ω g)))` with the largest albedo `ω`. Discrete ordinates solve
/// for the delta-M-truncated medium (`ω' = ω (1 − f) / (1 − ω f)`, `τ' = τ (1 − ω f)`).
pub fn spectral_radius_estimate(scene: &Scene, settings: &SolveSettings) -> f64 {
    let medium = &scene.medium;
    let phase = medium.phase();
    let g = phase.mean_cosine();
    let depths = medium.axis_optical_depths();
    let truncated = if settings.method == SolveMethod::DiscreteOrdinates {
        super::methods::forward_truncation(
            settings,
            super::budget::direction_bins(scene, settings),
            &phase,
        )
        .1
    } else {
        0.0
    };
    medium
        .channels()
        .iter()
        .map(|ch| diffusion_spectral_radius(ch.albedo.max() as f64, g, depths, truncated))
        .fold(0.0, f64::max)
}

/// `ρ = ω' / (1 + B² / (3 (1 − ω' g')))` for a block of optical depths `depths` (see
/// [`spectral_radius_estimate`]); `f` the truncated forward fraction.
fn diffusion_spectral_radius(albedo: f64, g: f64, depths: [f64; 3], f: f64) -> f64 {
    // NaN or ≤ 0: nothing scatters.
    if albedo.is_nan() || albedo <= 0.0 {
        return 0.0;
    }
    let albedo = albedo.min(1.0);
    let f = f.clamp(0.0, 0.999);
    let shrink = 1.0 - albedo * f;
    let albedo_t = albedo * (1.0 - f) / shrink;
    let g_t = if f > 0.0 { (g - f) / (1.0 - f) } else { g };
    let buckling: f64 = depths
        .iter()
        .map(|&tau| {
            let extrapolated = tau * shrink + 2.0 * 0.71;
            (std::f64::consts::PI / extrapolated).powi(2)
        })
        .sum();
    let leakage = buckling / (3.0 * (1.0 - albedo_t * g_t).max(1e-3));
    (albedo_t / (1.0 + leakage)).clamp(0.0, 0.999_999)
}

/// The power of the estimated ρ a Gauss–Seidel sweep contracts by: 2 for the zonal rows;
/// for discrete ordinates `min(2, 3 √(1 − g))`, which corrects the diffusion estimate where
/// it falls faster with the forward peak than the sweeps do (measured on `data/cloud.toml`'s
/// cloud at 96 bins, g = 0, 0.3, 0.6, 0.85, 0.95: 34, 31, 27, 20, 11 sweeps taken, against
/// 52, 38, 24, 10, 4 with ρ² and 52, 38, 25, 17, 12 with this; the 192-class cloud, g = 0.85,
/// 384 bins: 20 taken, 11 with ρ², 19 with this; docs/performance.md, *Time*).
pub fn gauss_seidel_power(method: SolveMethod, mean_cosine: f64) -> f64 {
    match method {
        SolveMethod::DiscreteOrdinates => (3.0 * (1.0 - mean_cosine.max(0.0)).sqrt()).min(2.0),
        _ => 2.0,
    }
}

/// Iterations of `iteration` to bring the residual down by `tolerance` on an operator of
/// spectral radius `rho`: Jacobi contracts by ρ per iteration, Gauss–Seidel (and SOR) by
/// about ρ^`sweep_power` ([`gauss_seidel_power`]), the Krylov methods as conjugate gradients on a condition number
/// `(1 + ρ) / (1 − ρ)` (the bound, times 0.7 — measured), the preconditioned ones by about
/// 0.1 per iteration whatever ρ (measured on clouds and slabs: 5–6 iterations to 10⁻⁵–10⁻⁶).
pub fn expected_iterations(
    iteration: &solver::Method,
    rho: f64,
    tolerance: f64,
    sweep_power: f64,
) -> usize {
    use solver::Method as M;
    if !(tolerance > 0.0 && tolerance < 1.0) {
        return if tolerance >= 1.0 { 0 } else { usize::MAX };
    }
    let by_contraction = |c: f64| -> usize {
        if c <= 1e-12 {
            return 1;
        }
        let c = c.min(1.0 - 1e-9);
        // The small allowance keeps exact powers (0.1⁵ = 10⁻⁵) from rounding up.
        (tolerance.ln() / c.ln() - 1e-9).ceil().max(1.0) as usize
    };
    let krylov = || -> usize {
        let kappa = (1.0 + rho) / (1.0 - rho).max(1e-9);
        let root = kappa.sqrt();
        let per = ((root + 1.0) / (root - 1.0).max(1e-12)).ln().max(1e-12);
        ((2.0 / tolerance).ln() / per * 0.7).ceil().max(1.0) as usize
    };
    match iteration {
        M::Jacobi => by_contraction(rho),
        M::GaussSeidel | M::Sor { .. } => by_contraction(rho.powf(sweep_power)),
        M::CoarseCorrected { .. } => by_contraction(0.5 * rho * rho),
        M::Gmres { .. } | M::BiCgStab | M::ConjugateGradient => krylov(),
        M::CoarseCg | M::TwoLevelCg { .. } | M::DsaCg => by_contraction(0.1),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_spectral_radius_grows_with_albedo_and_thickness() {
        let thin = diffusion_spectral_radius(0.9, 0.0, [2.0; 3], 0.0);
        let thick = diffusion_spectral_radius(0.9, 0.0, [50.0; 3], 0.0);
        assert!(thin < thick && thick < 0.9, "{thin} {thick}");
        let whiter = diffusion_spectral_radius(0.99, 0.0, [50.0; 3], 0.0);
        assert!(whiter > thick);
        // A wide slab leaks through its thin side: about as a slab, not as a cube.
        let slab = diffusion_spectral_radius(0.99, 0.0, [1e4, 1e4, 4.0], 0.0);
        let cube = diffusion_spectral_radius(0.99, 0.0, [4.0; 3], 0.0);
        assert!(slab > cube, "{slab} {cube}");
        assert_eq!(diffusion_spectral_radius(0.0, 0.0, [10.0; 3], 0.0), 0.0);
        // Forward scattering carries light further between changes of direction, so more of
        // it leaks out (the transport correction: D = 1 / (3 σt (1 − ω g))).
        let forward = diffusion_spectral_radius(0.9, 0.8, [10.0; 3], 0.0);
        assert!(forward < diffusion_spectral_radius(0.9, 0.0, [10.0; 3], 0.0));
    }

    #[test]
    fn the_measured_cloud_radius_is_predicted() {
        // 64 × 64 × 48 generated cloud, albedo 0.9, g = 0.6, optical size about 25 on each
        // axis: Jacobi on the zonal operator measured 0.852–0.88.
        let rho = diffusion_spectral_radius(0.9, 0.6, [25.1, 25.1, 25.1], 0.0);
        assert!((0.84..0.9).contains(&rho), "{rho}");
    }

    #[test]
    fn iterations_follow_the_contraction() {
        use solver::Method as M;
        // ρ = 0.5, Jacobi: 2^-17 < 1e-5.
        assert_eq!(expected_iterations(&M::Jacobi, 0.5, 1e-5, 2.0), 17);
        assert_eq!(expected_iterations(&M::GaussSeidel, 0.5, 1e-5, 2.0), 9);
        assert_eq!(expected_iterations(&M::DsaCg, 0.99, 1e-5, 2.0), 5);
        assert!(expected_iterations(&M::ConjugateGradient, 0.99, 1e-5, 2.0) < 200);
        assert!(
            expected_iterations(&M::ConjugateGradient, 0.99, 1e-5, 2.0)
                > expected_iterations(&M::ConjugateGradient, 0.5, 1e-5, 2.0)
        );
        assert_eq!(expected_iterations(&M::Jacobi, 0.0, 1e-5, 2.0), 1);
        // Discrete ordinates' sweeps gain less over ρ the more forward the phase function:
        // at g = 0.85, ρ = 0.583 (the 192-class cloud) 19 sweeps, not ρ²'s 11 (20 taken).
        let p = gauss_seidel_power(SolveMethod::DiscreteOrdinates, 0.85);
        assert!((1.1..1.2).contains(&p), "{p}");
        assert_eq!(expected_iterations(&M::GaussSeidel, 0.583, 1e-5, p), 19);
        assert_eq!(gauss_seidel_power(SolveMethod::DiscreteOrdinates, 0.0), 2.0);
        assert_eq!(
            gauss_seidel_power(SolveMethod::ZonalHierarchical, 0.85),
            2.0
        );
    }

    #[test]
    fn durations_read_as_people_write_them() {
        assert_eq!(duration_text(Duration::from_secs_f64(0.42)), "0.4 s");
        assert_eq!(duration_text(Duration::from_secs_f64(12.3)), "12 s");
        assert_eq!(duration_text(Duration::from_secs(200)), "3 min 20 s");
        assert_eq!(duration_text(Duration::from_secs(7500)), "2 h 5 min");
    }
}
