//! What a solve will cost in time, predicted before any work: what `volrad info` prints and
//! the progress bar shows from the start.
//!
//! [`solve_time`] sums named parts — the light pass, the emitter pass, each method's operator
//! build and its iterations — each a count of work (cells, direction bins, links, pairs of
//! cells, rays) times seconds per unit measured on the project's 2-core machine, scaled to the
//! solve's worker threads and to this machine's speed, which [`machine_factor`] measures
//! with a fixed kernel (about 40 ms). The one quantity not counted from the scene is the number of
//! iterations: [`probe`] measures it on a copy of the medium coarsened to a few thousand
//! cells (the spectral radius of the scattering operator by power iteration, and the solve's
//! iteration run there from the lights' first scattering), which costs about 0.2 s and is a
//! part of the prediction itself. Where no copy can be built, diffusion theory
//! ([`spectral_radius_estimate`]) stands in. `benches/memory.py` compares the prediction with
//! measured solve times (docs/performance.md, "Time").

use std::fmt;
use std::time::Duration;

use scene::{Scene, SolveMethod, SolveSettings};

use super::budget::{transport_scale, transport_split, HierarchyLinks, Occupancy};

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
    /// Whether the iterations and radius were measured by [`probe`] (not diffusion theory).
    probed: bool,
    threads: usize,
    /// This machine's time per unit of work over the coefficients' machine's
    /// ([`machine_factor`]), which every part has been multiplied by (`None`: not measured,
    /// for the methods that take a fraction of a second).
    machine: Option<f64>,
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

    /// Whether the iterations were measured on a coarse copy of the medium ([`probe`]).
    pub fn probed(&self) -> bool {
        self.probed
    }

    /// This machine's time per unit of work over the coefficients' machine's, where measured.
    pub fn machine_factor(&self) -> Option<f64> {
        self.machine
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
        if let Some(machine) = self.machine {
            write!(
                f,
                "; this machine measured at {machine:.2}× the model's time"
            )?;
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
/// Exact zonal: building the form factors, and one application, per pair of non-empty cells;
/// and the near field's ray stencil per non-empty cell whose near row is not shared
/// ([`Occupancy::hierarchy_shared_rows`]: a uniform block shares nearly all). Fitted on the
/// `form factors built` seconds of `RUST_LOG=info volrad solve`: uniform 16³ and 20³ blocks
/// (1.6 and 1.8 × 10⁻⁷ s per pair, rows shared) and Max's cloud generator at 32 × 32 × 24 and
/// 40 × 40 × 30 (2.6 and 2.4 × 10⁻⁷ per pair with 3,041 and 5,970 rows of their own).
const ZONAL_BUILD_SECONDS_PER_PAIR: f64 = 1.7e-7;
const ZONAL_NEAR_SECONDS_PER_STORED_ROW: f64 = 3.0e-4;
const ZONAL_APPLY_SECONDS_PER_PAIR: f64 = 8.0e-10;
/// Hierarchical zonal: building a far link (its transmittance between the clusters, or the
/// exact far estimate of a leaf pair) and a stored near-field entry (a column of the ray
/// stencil), and one application per link of either. The two build costs fitted to the
/// `hierarchy built` seconds of `RUST_LOG=info volrad solve` on the far-link model's cases
/// ([`super::budget::far_links_per_occupied_cell`]; `benches/far_links.py`) with their own
/// counts, within 14 % on all but the smallest (0.32 s against 0.37–0.51 s); one cost for
/// both, with the same counts, was −41 … +28 % (a far link costs 2.4 near entries).
const HIERARCHICAL_BUILD_SECONDS_PER_FAR_LINK: f64 = 1.9e-7;
const HIERARCHICAL_BUILD_SECONDS_PER_NEAR_ENTRY: f64 = 8.0e-8;
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
/// into bin-major order. The source linear in each cell (its slopes from 6 neighbours per
/// cell and piece) added 13–32 % per sweep on those cases (3.4–7.7 ns per cell and bin,
/// measured against the flat source on a machine 16 % slower than the fit's): 3.0e-9 s per
/// cell and bin on the sweep term, 2.5e-9 on the uncached one.
const ORDINATES_SETUP_SECONDS_PER_CELL_BIN: f64 = 7.0e-8;
const ORDINATES_SWEEP_SECONDS_PER_CELL_BIN: f64 = 8.6e-9;
const ORDINATES_PRODUCT_SECONDS_PER_CELL_BIN_ROOT_BIN: f64 = 1.0e-9;
const ORDINATES_UNCACHED_SECONDS_PER_CELL_BIN: f64 = 12.1e-9;
const ORDINATES_CACHED_CELL_BINS: f64 = 2.0e7;
/// Two-pass: per cell and tally bin (the tallies and their sum), and per photon and cell
/// along the grid's longest side (a photon's path crosses cells in proportion to it). Fitted
/// to the medians of three solves each of seed-2 clouds from 16 × 16 × 12 to 64 × 64 × 48
/// (2²¹ photons; 10⁵ and 10⁶ on the 32 × 32 × 24 one: ten times the photons cost it 5 %) and
/// a uniform 32³ block, 2026-12-06: within 17 % (the constants before, 6.0e-8 and 9.0e-9,
/// −26 … +34 %). The first solve after a pause can take 1.5× (its threads' CPU the same).
const TWO_PASS_SECONDS_PER_CELL_BIN: f64 = 7.2e-8;
const TWO_PASS_SECONDS_PER_PHOTON_SIDE: f64 = 5.5e-9;
/// The ground's rounds of coupling with the medium: each solves the medium again from the
/// last solution, the early ones loosely, so their iterations add up to about one solve's
/// (measured: 20 + 14 + 26 against 60); each round gathers the medium's light on the
/// ground's patches.
const GROUND_ROUNDS: f64 = 3.0;
const GROUND_SECONDS_PER_PATCH_ROUND: f64 = 2.0e-6;
/// Discrete ordinates' part of a round beyond its iterations, per cell and bin: the ground's
/// light looked up along every upward bin, swept in, scattered once, and the medium's light
/// gathered toward the ground (measured on `data/cloud-sky.toml`: about 0.5 s a round on
/// 5.3 × 10⁶ cell-bins).
const GROUND_ORDINATES_SECONDS_PER_CELL_BIN_ROUND: f64 = 9.0e-8;
/// The probe ([`probe`]): its sweeps on the coarse copy (about 0.2 s whatever the medium,
/// its cells being capped), and coarsening the data grid into it, per data cell (measured as
/// `volrad info`'s time with the probe less without it: 0.18–0.24 s on media of 2.4 × 10⁴ to
/// 2 × 10⁵ cells, 0.44 s on the 192 × 192 × 144 cloud).
const PROBE_SECONDS: f64 = 0.2;
const PROBE_SECONDS_PER_DATA_CELL: f64 = 4.0e-8;
/// The Krylov methods' vector work per iteration (their basis, dot products and updates),
/// per unknown and pass over a vector: fitted on GMRES(8) and BiCGSTAB over a 32 × 32 × 24
/// cloud at 216 bins (2.1 s and 0.9 s beyond their sweeps).
const KRYLOV_SECONDS_PER_ENTRY_PASS: f64 = 1.35e-9;
/// The threads the coefficients were measured with.
const MEASURED_THREADS: f64 = 2.0;

/// The machine's own speed against the one the coefficients were measured on: the time of
/// one application of a fixed discrete-ordinates operator ([`CALIBRATION_SIDE`]³ uniform
/// cells, [`PROBE_BINS`] bins, g = 0.6) on one thread, over
/// [`CALIBRATION_REFERENCE_SECONDS`], measured on the coefficients' machine the hour their
/// table was (docs/performance.md, "Time"). Machines, and one machine from hour to hour,
/// differ by tens of percent per core; the model's own thread scaling does the rest. One
/// thread, because what the other cores happen to be doing for the few milliseconds of the
/// kernel says little of the minutes of a solve: on 2 threads it took 1.4 ms, and 2.6 ms —
/// one thread's time — whenever another process held the second core; on one thread it
/// took 2.3–2.5 ms on a quiet machine and 2.0–2.5 ms beside other work. About 90 ms, once
/// per process; `VOLRAD_MACHINE_FACTOR` sets it instead (1: the coefficients as they are);
/// 1 where it cannot run.
pub fn machine_factor() -> f64 {
    static FACTOR: std::sync::OnceLock<f64> = std::sync::OnceLock::new();
    *FACTOR.get_or_init(|| {
        let given = std::env::var("VOLRAD_MACHINE_FACTOR").ok();
        let factor = machine_factor_from(given.as_deref(), kernel_seconds);
        tracing::debug!(factor, ?given, "machine speed against the time model's");
        factor
    })
}

/// [`machine_factor`]'s choice: a positive finite `given` factor as it is; otherwise the
/// kernel's seconds (`measure`) over [`CALIBRATION_REFERENCE_SECONDS`] within
/// [`CALIBRATION_BOUNDS`] (outside them the timing is taken as disturbed, not as the
/// machine); otherwise 1.
pub fn machine_factor_from(given: Option<&str>, measure: impl FnOnce() -> Option<f64>) -> f64 {
    if let Some(f) = given
        .and_then(|v| v.trim().parse::<f64>().ok())
        .filter(|f| f.is_finite() && *f > 0.0)
    {
        return f;
    }
    measure()
        .map(|seconds| seconds / CALIBRATION_REFERENCE_SECONDS)
        .filter(|f| f.is_finite() && (CALIBRATION_BOUNDS.0..=CALIBRATION_BOUNDS.1).contains(f))
        .unwrap_or(1.0)
}

/// Whether a prediction for `method` runs [`machine_factor`]'s kernel: not for the methods
/// without a linear solve, which take a fraction of a second.
pub fn measures_the_machine(method: SolveMethod) -> bool {
    method.solves_linear_system() || method == SolveMethod::TwoPass
}

/// Cells per side of [`machine_factor`]'s medium (16³ × 24 bins: about 2.5 ms an
/// application).
const CALIBRATION_SIDE: usize = 16;
/// Applications of [`machine_factor`]'s operator before the timed ones, and timed, in each
/// of [`CALIBRATION_BURSTS`] bursts [`CALIBRATION_PAUSE`] apart: a disturbance that covers
/// one burst (the host taking the core for 40 ms happens) seldom covers all three.
const CALIBRATION_WARM_UP: usize = 2;
const CALIBRATION_APPLICATIONS: usize = 5;
const CALIBRATION_BURSTS: usize = 3;
const CALIBRATION_PAUSE: std::time::Duration = std::time::Duration::from_millis(15);
/// [`machine_factor`]'s seconds per application (the fastest of its times) on a machine as
/// fast as the coefficients say: fitted so that the solves of docs/performance.md's table,
/// measured the same hour, are centred (the kernel took 2.3–2.5 ms there, the solves about
/// 1.4× the coefficients' seconds; 1.76e-3 for the lower third of the times, which runs about
/// 1 % above the fastest).
const CALIBRATION_REFERENCE_SECONDS: f64 = 1.74e-3;
/// The factor's bounds ([`machine_factor_from`]).
const CALIBRATION_BOUNDS: (f64, f64) = (0.25, 4.0);

/// The kernel of [`machine_factor`]: the fastest of the times of its applications, in
/// seconds (`None` if its operator cannot be built).
pub fn kernel_seconds() -> Option<f64> {
    use formfactor::ordinates::{DirectionBins, OrdinatesOperator, OrdinatesOptions};
    use solver::TransportOperator;
    let grid = medium::Grid::new([CALIBRATION_SIDE; 3], 1.0).ok()?;
    let medium = medium::Medium::homogeneous(
        grid,
        0.5,
        0.9,
        0.0,
        medium::PhaseFunction::HenyeyGreenstein { g: 0.6 },
    )
    .ok()?;
    let bins = DirectionBins::with_count(PROBE_BINS).ok()?;
    let op = OrdinatesOperator::new(&medium, 0, bins, OrdinatesOptions::default()).ok()?;
    let x = vec![1.0; op.len()];
    let mut y = vec![0.0; op.len()];
    let mut seconds = Vec::with_capacity(CALIBRATION_BURSTS * CALIBRATION_APPLICATIONS);
    rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .ok()?
        .install(|| {
            // Untimed: the scratch is allocated and the caches filled.
            for _ in 0..CALIBRATION_WARM_UP {
                op.apply(&x, &mut y);
            }
            for burst in 0..CALIBRATION_BURSTS {
                if burst > 0 {
                    std::thread::sleep(CALIBRATION_PAUSE);
                    op.apply(&x, &mut y);
                }
                for _ in 0..CALIBRATION_APPLICATIONS {
                    let start = std::time::Instant::now();
                    op.apply(&x, &mut y);
                    seconds.push(start.elapsed().as_secs_f64());
                }
            }
        });
    seconds.sort_by(f64::total_cmp);
    tracing::debug!(
        fastest = seconds[0],
        median = seconds[seconds.len() / 2],
        slowest = seconds[seconds.len() - 1],
        "the time model's kernel, seconds per application"
    );
    // The fastest: a disturbance (another process waking, the host taking the core) only
    // ever slows an application, and one may cover most of a burst: twelve runs in a row of
    // one burst of 15 gave fastest 2.45–2.58 ms, but one a median of 4.13 ms, whose lower
    // third made the factor 2.64 where the others were 1.43–1.50.
    Some(seconds[0])
}

/// The predicted time of solving `scene` with `settings` on `threads` worker threads;
/// `occupancy` is [`Occupancy::of`] its medium.
pub fn solve_time(
    scene: &Scene,
    settings: &SolveSettings,
    occupancy: &Occupancy,
    threads: usize,
) -> TimeEstimate {
    solve_time_cancellable(
        scene,
        settings,
        occupancy,
        threads,
        &solver::SolveControl::default(),
    )
}

/// [`solve_time`] for a solve that `control` can cancel: the probe's iterations (seconds on a
/// grid of many distinct σt) stop when it is, and the probe then counts as not measured.
pub fn solve_time_cancellable(
    scene: &Scene,
    settings: &SolveSettings,
    occupancy: &Occupancy,
    threads: usize,
    control: &solver::SolveControl,
) -> TimeEstimate {
    let machine = measures_the_machine(settings.method).then(machine_factor);
    estimate(scene, settings, occupancy, threads, machine, control)
}

/// [`solve_time`] on a machine `machine` times slower than the coefficients' (`None`: as
/// fast, and not measured).
pub fn solve_time_at_speed(
    scene: &Scene,
    settings: &SolveSettings,
    occupancy: &Occupancy,
    threads: usize,
    machine: Option<f64>,
) -> TimeEstimate {
    let control = solver::SolveControl::default();
    estimate(scene, settings, occupancy, threads, machine, &control)
}

fn estimate(
    scene: &Scene,
    settings: &SolveSettings,
    occupancy: &Occupancy,
    threads: usize,
    machine: Option<f64>,
    control: &solver::SolveControl,
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
    tracing::debug!(
        cells,
        transport_cells,
        transport_occupied,
        scale,
        "the time model's counts"
    );
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

    let probed = if settings.method.solves_linear_system() {
        parts.push(TimePart {
            what: "the probe of a coarse copy",
            seconds: PROBE_SECONDS + cells * PROBE_SECONDS_PER_DATA_CELL,
        });
        probe(scene, settings, control)
    } else {
        None
    };
    let rho = probed.map_or_else(
        || spectral_radius_estimate(scene, settings),
        |p| p.spectral_radius,
    );
    // Without a probe's own count, a Gauss–Seidel sweep is taken to gain a power of ρ.
    let sweep = rho.powf(gauss_seidel_power(
        settings.method,
        scene.medium.phase().mean_cosine(),
    ));
    tracing::debug!(
        probed = ?probed,
        diffusion = spectral_radius_estimate(scene, settings),
        "spectral radius"
    );
    let iterations = settings
        .method
        .solves_linear_system()
        .then(|| {
            probed.and_then(|p| p.iterations).unwrap_or_else(|| {
                expected_iterations(&settings.iteration, rho, settings.tolerance, sweep)
            })
        })
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
    // The zonal methods' near-field rows not shared by a uniform block (each its own
    // stencil); a scan of the medium, so only for them.
    let stored_rows = || {
        (transport_occupied - occupancy.hierarchy_shared_rows(scale) as f64 * parts_per_cell)
            .max(0.0)
    };
    // `extra_build`: seconds of the build not proportional to `units`, per channel.
    let mut operator =
        |what: &'static str, units: f64, build: f64, extra_build: f64, apply: f64| {
            parts.push(TimePart {
                what,
                seconds: channels * (units * build + extra_build),
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
            stored_rows() * ZONAL_NEAR_SECONDS_PER_STORED_ROW,
            ZONAL_APPLY_SECONDS_PER_PAIR,
        ),
        SolveMethod::ZonalHierarchical => {
            let HierarchyLinks {
                far, near_entries, ..
            } = occupancy.hierarchy_links(scale, transport_split(scene, settings));
            operator(
                "the hierarchical operator",
                far + near_entries,
                0.0,
                far * HIERARCHICAL_BUILD_SECONDS_PER_FAR_LINK
                    + near_entries * HIERARCHICAL_BUILD_SECONDS_PER_NEAR_ENTRY,
                HIERARCHICAL_APPLY_SECONDS_PER_LINK,
            )
        }
        SolveMethod::DiscreteOrdinates => {
            let bins = super::budget::direction_bins(scene, settings) as f64;
            let cell_bins = transport_cells * bins;
            parts.push(TimePart {
                what: "the sweeps' set-up and stored field",
                seconds: channels * cell_bins * ORDINATES_SETUP_SECONDS_PER_CELL_BIN,
            });
            if scene.ground.is_some() {
                parts.push(TimePart {
                    what: "the ground's rounds in the bins",
                    seconds: channels
                        * GROUND_ROUNDS
                        * cell_bins
                        * GROUND_ORDINATES_SECONDS_PER_CELL_BIN_ROUND,
                });
            }
            let product_cells = occupancy.ordinates_product_cells(scale) as f64 * parts_per_cell;
            // The state (the iterate and the source) is the cells with medium; the sweeps
            // cross every cell.
            let state_cell_bins = transport_occupied * bins;
            let uncached = (state_cell_bins / ORDINATES_CACHED_CELL_BINS).min(1.0);
            let per_sweep = cell_bins * ORDINATES_SWEEP_SECONDS_PER_CELL_BIN
                + state_cell_bins * uncached * ORDINATES_UNCACHED_SECONDS_PER_CELL_BIN
                + product_cells
                    * bins
                    * bins.sqrt()
                    * ORDINATES_PRODUCT_SECONDS_PER_CELL_BIN_ROOT_BIN;
            let vector_work = iterations.map_or(0.0, |n| {
                n as f64 * krylov_vector_passes(&settings.iteration) * state_cell_bins
            }) * KRYLOV_SECONDS_PER_ENTRY_PASS;
            parts.push(TimePart {
                what: iterations_label,
                seconds: channels * (applications * per_sweep + vector_work),
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
    let speed = machine.unwrap_or(1.0) * MEASURED_THREADS / threads.max(1) as f64;
    for p in &mut parts {
        p.seconds *= speed;
    }
    TimeEstimate {
        parts,
        iterations,
        spectral_radius: settings.method.solves_linear_system().then_some(rho),
        probed: probed.is_some(),
        threads: threads.max(1),
        machine,
    }
}

/// Passes over a vector of unknowns per iteration of a Krylov method beyond its
/// applications of the operator: GMRES(m) orthogonalises against half its basis on average
/// (a dot product and an update each) and forms its update; BiCGSTAB's five dot products and
/// five updates. The stationary methods' few are in their sweeps' constants.
fn krylov_vector_passes(iteration: &solver::Method) -> f64 {
    match iteration {
        solver::Method::Gmres { restart } => *restart as f64 + 4.0,
        solver::Method::BiCgStab => 10.0,
        _ => 0.0,
    }
}

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

/// Cells of the coarse copy of the medium [`probe`] works on (at most).
const PROBE_CELLS: usize = 12_288;
/// Direction bins of the probe's sweeps (`6 n²`, n = 2).
const PROBE_BINS: usize = 24;
/// Applications of the operator the probe's power iteration runs at most.
const PROBE_POWER_STEPS: usize = 60;
/// Successive growth factors within this (relative) end the probe's power iteration.
const PROBE_TOLERANCE: f64 = 3e-4;
/// Iterations of the probe's solve; past them the rest is extrapolated at the last rate.
const PROBE_SOLVE_ITERATIONS: usize = 40;

/// What a zonal Gauss–Seidel sweep (rows in cell order) gains over a Jacobi step, in
/// iterations: 63 / 44, 68 / 50 and 476 / 410 on `data/cloud.toml`, `data/dipole.toml` and
/// `data/cloud-backlit.toml` by the hierarchy — not the ρ² of a symmetric ordering.
const ZONAL_GAUSS_SEIDEL_GAIN: f64 = 1.3;

/// What a solve's iterations were measured to do on a coarse copy of its medium.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Probe {
    /// `ρ(K)`: what one application of the scattering operator keeps of its slowest mode.
    pub spectral_radius: f64,
    /// Iterations the solve's iteration is expected to take, from those an iteration took
    /// on the copy (extrapolated past [`PROBE_SOLVE_ITERATIONS`]): discrete ordinates' own
    /// iteration; for the zonal methods Jacobi's, and Gauss–Seidel's from it by
    /// [`ZONAL_GAUSS_SEIDEL_GAIN`]. `None` for the iterations the copy cannot run (those
    /// that need a symmetric operator or the zonal hierarchy's coarse levels).
    pub iterations: Option<usize>,
}

/// The solve measured on a copy of the medium coarsened to at most [`PROBE_CELLS`] cells,
/// swept in [`PROBE_BINS`] bins with the phase function the solve scatters by (discrete
/// ordinates: the scene's, δ-M truncated as the solve truncates it; the zonal methods:
/// isotropic): the spectral radius of `K` by power iteration, and the iterations of the
/// solve's iteration ([`Probe::iterations`]) from the lights' first scattering to its
/// tolerance. Both are properties of the medium and its lighting — albedo, optical size and
/// shape, holes, where the light enters — more than of the grid it is solved on, and a copy of
/// a few thousand cells gives them in about 0.2 s, where diffusion theory on
/// the medium's bounding block ([`spectral_radius_estimate`]) misjudges clumped, back-lit
/// and forward-scattering media. `None` if the copy cannot be built, or when `control` is
/// cancelled (its iterations stop then: seconds on a grid of many distinct σt).
pub fn probe(
    scene: &Scene,
    settings: &SolveSettings,
    control: &solver::SolveControl,
) -> Option<Probe> {
    use formfactor::ordinates::{DirectionBins, OrdinatesOperator};
    use medium::coarsening::Coarsening;

    // The solve's cancellation, not its progress: the probe's iterations are not the solve's.
    let control = &solver::SolveControl::with_flag(control.flag());
    if control.is_cancelled() {
        return None;
    }
    let medium = &scene.medium;
    let grid = medium.grid();
    let scale = super::budget::smallest_scale_within(grid, PROBE_CELLS);
    let coarse = Coarsening::new(grid, scale).ok()?.medium(medium).ok()?;
    let ordinates = settings.method == SolveMethod::DiscreteOrdinates;
    let coarse = if ordinates {
        coarse
    } else {
        let (grid, channels, _, interpolation, data) = coarse.into_parts();
        medium::Medium::new(
            grid,
            channels,
            medium::PhaseFunction::Isotropic,
            interpolation,
            data,
        )
        .ok()?
    };
    let phase = coarse.phase();
    let solve_bins =
        DirectionBins::with_count(super::budget::direction_bins(scene, settings)).ok()?;
    // The solve's δ-M cone (chosen for its own bins), so the probe scatters what it does.
    let mut options = super::methods::ordinates_options(settings, &solve_bins, &phase);
    // As many Gauss–Seidel groups as the solve sweeps (up to one per bin): what a sweep gains
    // over a Jacobi step grows with the groups that see the ones updated before them.
    options.gauss_seidel_group =
        (PROBE_BINS * options.gauss_seidel_group / solve_bins.len()).clamp(1, PROBE_BINS);
    let mut found: Option<Probe> = None;
    for (c, channel) in coarse.channels().iter().enumerate() {
        // A grey medium in colour (under a sky) repeats its one channel.
        if coarse.channels()[..c].contains(channel) {
            continue;
        }
        let bins = DirectionBins::with_count(PROBE_BINS).ok()?;
        let op = OrdinatesOperator::new(&coarse, c, bins, options).ok()?;
        let rho =
            solver::spectral_radius_cancellable(&op, PROBE_POWER_STEPS, PROBE_TOLERANCE, control)?
                .rho;
        if !rho.is_finite() {
            return None;
        }
        use solver::Method as M;
        let run = |method| probe_iterations(scene, settings, (&coarse, c, &op), method, control);
        let iterations = match (ordinates, settings.iteration) {
            (true, M::Jacobi | M::GaussSeidel | M::Sor { .. } | M::Gmres { .. } | M::BiCgStab) => {
                run(settings.iteration)
            }
            // The zonal rows' own sweeps are not the probe's: their Jacobi count is (the
            // same K), and their Gauss–Seidel gains a measured factor on it.
            (false, M::Jacobi) => run(M::Jacobi),
            (false, M::GaussSeidel | M::Sor { .. }) => run(M::Jacobi)
                .map(|k| ((k as f64 / ZONAL_GAUSS_SEIDEL_GAIN).ceil() as usize).max(1)),
            _ => None,
        };
        // Cancelled during the iterations: they stopped early, so nothing was measured.
        if control.is_cancelled() {
            return None;
        }
        let measured = Probe {
            spectral_radius: rho,
            iterations,
        };
        // The channel that takes longest sets the prediction.
        let slower = match found {
            None => true,
            Some(f) => match (measured.iterations, f.iterations) {
                (Some(a), Some(b)) => a > b,
                _ => rho > f.spectral_radius,
            },
        };
        if slower {
            found = Some(measured);
        }
    }
    found
}

/// The iterations `method` takes on the probe's operator `op` (channel `c` of the
/// coarse copy `coarse`), from the lights' first scattering transported once (a scene without
/// lights: the scattering of a uniform radiance, as from a sky or a glow), to the solve's
/// tolerance; past [`PROBE_SOLVE_ITERATIONS`], extrapolated at the rate of the last five.
fn probe_iterations(
    scene: &Scene,
    settings: &SolveSettings,
    (coarse, c, op): (
        &medium::Medium,
        usize,
        &formfactor::ordinates::OrdinatesOperator,
    ),
    method: solver::Method,
    control: &solver::SolveControl,
) -> Option<usize> {
    use solver::TransportOperator;
    let n = op.len();
    let mut external = vec![0.0; n];
    if scene.lights.is_empty() {
        op.apply(&vec![1.0; n], &mut external);
    } else {
        let pass = medium::light_pass::LightPass::compute(coarse, c, &scene.lights).ok()?;
        let density = op.first_bounce_density_from_pass(&pass).ok()?;
        op.transport_external(&density, None, &mut external, None);
    }
    let options = solver::SolveOptions {
        method,
        tolerance: settings.tolerance,
        max_iterations: PROBE_SOLVE_ITERATIONS.min(settings.max_iterations),
        record_history: true,
    };
    let (_, report) = solver::solve(op, &external, None, &options, control).ok()?;
    if report.converged || report.iterations >= settings.max_iterations {
        return Some(report.iterations.max(1));
    }
    let history = &report.residual_history;
    let last = *history.last()?;
    let back = history.len().checked_sub(6)?;
    let rate = (last / history[back]).powf(1.0 / 5.0);
    if !(rate > 0.0 && rate < 1.0 && last > 0.0) {
        return Some(settings.max_iterations);
    }
    let more = ((settings.tolerance / last).ln() / rate.ln())
        .ceil()
        .max(0.0);
    Some((report.iterations + more as usize).min(settings.max_iterations))
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

/// The power of ρ a Gauss–Seidel sweep contracts by, where no probe measured it: for the
/// zonal rows [`ZONAL_GAUSS_SEIDEL_GAIN`]; for discrete ordinates `min(2, 3 √(1 − g))`, which
/// corrected the diffusion estimate where it falls faster with the forward peak than the
/// sweeps do (`data/cloud.toml`'s cloud at 96 bins, g = 0, 0.3, 0.6, 0.85, 0.95: 34, 31, 27,
/// 20, 11 sweeps taken, against 52, 38, 24, 10, 4 with ρ² and 52, 38, 25, 17, 12 with this).
pub fn gauss_seidel_power(method: SolveMethod, mean_cosine: f64) -> f64 {
    match method {
        SolveMethod::DiscreteOrdinates => (3.0 * (1.0 - mean_cosine.max(0.0)).sqrt()).min(2.0),
        _ => ZONAL_GAUSS_SEIDEL_GAIN,
    }
}

/// Iterations of `iteration` to bring the residual down by `tolerance` on an operator of
/// spectral radius `rho`: Jacobi contracts by ρ per iteration, Gauss–Seidel (and SOR) by
/// `sweep` per sweep, the Krylov methods as conjugate gradients on a condition number
/// `(1 + ρ) / (1 − ρ)` (the bound, times 0.7 — measured), the preconditioned ones by about
/// 0.1 per iteration whatever ρ (measured on clouds and slabs: 5–6 iterations to 10⁻⁵–10⁻⁶).
pub fn expected_iterations(
    iteration: &solver::Method,
    rho: f64,
    tolerance: f64,
    sweep: f64,
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
        M::GaussSeidel | M::Sor { .. } => by_contraction(sweep),
        M::CoarseCorrected { .. } => by_contraction(0.5 * rho * rho),
        M::Gmres { .. } | M::BiCgStab | M::ConjugateGradient => krylov(),
        M::CoarseCg | M::TwoLevelCg { .. } | M::DsaCg => by_contraction(0.1),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::engine::budget::far_links_per_occupied_cell;

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

    /// The far links the hierarchy builds, against the model's count, on clouds of another
    /// seed than the fit's (thin and four times thicker: the thick one has about half as many
    /// per cell) and a uniform block: −3 %, +1 % and +3 % when written. The single log-line
    /// before (`50 log₂ n − 370`, whatever the medium) was −6 %, +93 % and +26 %.
    #[test]
    fn the_far_links_the_hierarchy_builds_are_predicted() {
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(
            dir.path().join("block.f32"),
            0.05f32.to_le_bytes().repeat(20 * 20 * 20),
        )
        .unwrap();
        let mut per_cell = Vec::new();
        for volume in [
            "generator = { kind = \"cloud\", seed = 3 }\ndims = [32, 32, 24]",
            "generator = { kind = \"cloud\", seed = 3 }\ndims = [32, 32, 24]\nsigma_t_scale = 4.0",
            "file = \"block.f32\"\ndims = [20, 20, 20]",
        ] {
            let text = format!(
                "[volume]\n{volume}\n[medium]\nalbedo = 0.9\n[[light]]\nkind = \"directional\"\ndirection = [0.0, 0.0, -1.0]\nirradiance = 1.0\n"
            );
            let scene =
                Scene::from_toml_str(&text, dir.path(), std::path::Path::new("far.toml")).unwrap();
            let medium = &scene.medium;
            let built: usize = formfactor::HierarchicalOperator::build(
                medium,
                0,
                &formfactor::HierarchicalOptions {
                    tolerance: super::super::methods::HIERARCHY_TOLERANCE,
                    ..formfactor::HierarchicalOptions::default()
                },
            )
            .unwrap()
            .links_per_level()
            .iter()
            .sum();
            let occupancy = Occupancy::of(medium);
            let occupied = occupancy.at(1) as f64;
            let fill = occupied / medium.grid().cell_count() as f64;
            let side = occupancy.hierarchy_near_rows(1).mean_optical_side;
            let predicted = occupied * far_links_per_occupied_cell(occupied, fill, side);
            let error = predicted / built as f64 - 1.0;
            assert!(
                error.abs() < 0.15,
                "{volume}: {built} far links built, {predicted:.0} predicted ({:+.1} %)",
                100.0 * error
            );
            per_cell.push(built as f64 / occupied);
        }
        assert!(per_cell[1] < 0.7 * per_cell[0], "{per_cell:?}");
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
        assert_eq!(expected_iterations(&M::Jacobi, 0.5, 1e-5, 0.25), 17);
        // A Gauss–Seidel sweep contracting by ρ² = 0.25: 0.25^9 < 1e-5 < 0.25^8.
        assert_eq!(expected_iterations(&M::GaussSeidel, 0.5, 1e-5, 0.25), 9);
        assert_eq!(expected_iterations(&M::DsaCg, 0.99, 1e-5, 0.98), 5);
        assert!(expected_iterations(&M::ConjugateGradient, 0.99, 1e-5, 0.98) < 200);
        assert!(
            expected_iterations(&M::ConjugateGradient, 0.99, 1e-5, 0.98)
                > expected_iterations(&M::ConjugateGradient, 0.5, 1e-5, 0.25)
        );
        assert_eq!(expected_iterations(&M::Jacobi, 0.0, 1e-5, 0.0), 1);
        // Without a measurement, discrete ordinates' sweeps are taken to gain less over ρ the
        // more forward the phase function.
        let p = gauss_seidel_power(SolveMethod::DiscreteOrdinates, 0.85);
        assert!((1.1..1.2).contains(&p), "{p}");
        assert_eq!(gauss_seidel_power(SolveMethod::DiscreteOrdinates, 0.0), 2.0);
        assert_eq!(
            gauss_seidel_power(SolveMethod::ZonalHierarchical, 0.85),
            ZONAL_GAUSS_SEIDEL_GAIN
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
