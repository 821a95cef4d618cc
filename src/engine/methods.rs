//! The solve methods wired end to end (light pass → operator → solver → stored field), the
//! scattered-light sources a render adds, and the per-cell fields `volrad export` writes.

use std::f64::consts::PI;
use std::fmt;

use crate::engine::pipeline::channel_phase;
use anyhow::{bail, Context, Result};
use formfactor::ordinates::{
    default_forward_truncation_degrees, DirectionBins, OrdinatesOperator, OrdinatesOptions,
};
use formfactor::{ExactOptions, FormFactorMatrix, HierarchicalOperator, HierarchicalOptions};
use glam::DVec3;
use medium::emitter_pass::{EmitterPass, EmitterPassOptions};
use medium::light_pass::LightPass;
use medium::{Environment, Medium, PhaseFunction};
use rayon::prelude::*;
use scene::{Scene, SolveMethod, SolveSettings};
use serde::Serialize;
use solver::{Method, SolveOptions, SolveReport, TransportOperator};

use crate::engine::ground::{relative_change, ChannelGround, GROUND_TOLERANCE, MAX_GROUND_ROUNDS};
use crate::engine::solution::{
    CellRows, ChannelSolution, EmitterBeam, ScatteredField, Solution, StoredBins,
    EMITTER_BEAM_VALUES, EMITTER_BIN_VALUES,
};
use crate::engine::SolveHooks;

/// Direction bins of a sky's uncollided fluence in the zonal methods (one transmittance pass
/// each, 6 · 8² = 384; a uniform environment needs none, see `solve_zonal`).
pub const ENVIRONMENT_BINS: usize = 384;

/// Direction bins of the ground's light into the zonal methods (the upward half: one
/// transmittance pass each per ground–medium round).
pub const GROUND_INFLOW_BINS: usize = 96;

/// Rays per cell of the transmittance passes that bring the ground's light into the zonal
/// methods (as many as `Environment::uncollided_fluence` takes for an environment's).
const ZONAL_INFLOW_RAYS_PER_CELL: usize = 4;

/// Link tolerance of the hierarchical zonal operator. 1e-4 keeps the solved source terms of
/// the cloud24 reference within 1 % (relative L2) of the exact operator's (0.77 % measured;
/// the library default 3e-4 gives 2 %), at about twice the links.
pub const HIERARCHY_TOLERANCE: f64 = 1e-4;

/// Refuses, before any operator is built, an iteration the solve method's operator cannot
/// run: the conjugate-gradient family needs reciprocity (zonal operators only), and
/// `dsa-cg` a diffusion approximation, which only the hierarchical operator provides.
/// Methods that do not iterate (none, single scatter, two-pass) ignore the setting.
pub fn check_iteration(settings: &SolveSettings) -> Result<()> {
    if !settings.method.solves_linear_system() {
        return Ok(());
    }
    let it = settings.iteration;
    let needs_symmetry = matches!(
        it,
        Method::ConjugateGradient | Method::CoarseCg | Method::TwoLevelCg { .. } | Method::DsaCg
    );
    let zonal = matches!(
        settings.method,
        SolveMethod::Zonal | SolveMethod::ZonalHierarchical
    );
    if it == Method::DsaCg && settings.method != SolveMethod::ZonalHierarchical {
        bail!(
            "[solve] iteration `dsa-cg` needs a diffusion approximation, which only method \
             `zonal-hierarchical` provides (not `{}`); use cg",
            settings.method.name()
        );
    }
    if needs_symmetry && !zonal {
        bail!(
            "[solve] iteration `{}` needs a symmetrisable (zonal) operator, which method `{}` \
             does not build; use gauss-seidel, sor:OMEGA, gmres or bicgstab",
            it,
            settings.method.name()
        );
    }
    Ok(())
}

/// Refuses, before any work, a solve method that cannot carry the scene's environment light:
/// its first bounce lives in the solved field, which `single-scatter` and `none` do not build.
pub fn check_environment(scene: &Scene, settings: &SolveSettings) -> Result<()> {
    if scene.environment.as_ref().is_none_or(|e| e.is_dark()) {
        return Ok(());
    }
    match settings.method {
        SolveMethod::Zonal
        | SolveMethod::ZonalHierarchical
        | SolveMethod::DiscreteOrdinates
        | SolveMethod::TwoPass => Ok(()),
        other => bail!(
            "[solve] method `{}` cannot carry an environment light (its light enters the \
             solved field); use zonal, zonal-hierarchical, discrete-ordinates or two-pass, or \
             render with --path-trace",
            other.name()
        ),
    }
}

fn solve_options(settings: &SolveSettings) -> SolveOptions {
    SolveOptions {
        method: settings.iteration,
        tolerance: settings.tolerance,
        max_iterations: settings.max_iterations,
        record_history: true,
    }
}

fn run_solver(
    op: &dyn TransportOperator,
    source: &[f64],
    initial: Option<&[f64]>,
    settings: &SolveSettings,
    hooks: &SolveHooks,
) -> Result<(Vec<f64>, SolveReport)> {
    let options = solve_options(settings);
    hooks
        .control
        .phase(&format!("iterating ({})", options.method));
    let (g, report) = solver::solve(op, source, initial, &options, &hooks.control)
        .with_context(|| format!("solving with {}", options.method))?;
    tracing::info!(
        method = %report.method,
        iterations = report.iterations,
        residual = report.final_residual,
        converged = report.converged,
        seconds = report.seconds,
        "solved"
    );
    Ok((g, report))
}

/// The emitter pass's largest expected cost, in rays per cell, for a solve to run it. A compact
/// source (Kobayashi's 6³ source cells in 60³: about 310, its edge's sources sampled at points)
/// is where the bins' ray effects are and the pass pays; a cloud that emits throughout
/// (data/fire-scattering.toml: thousands, 17× the solve and more) is a smooth source the
/// operator carries well.
pub const MAX_EMITTER_RAYS_PER_CELL: f64 = 512.0;

/// The most cells whose emitted light a discrete-ordinates solve keeps in direction bins
/// (the widest-lit; [`EmitterPassOptions::binned_cells`]): 3 kB each, 48 MB at most.
pub const EMITTER_BINNED_CELLS: usize = 16_384;

/// Cells at which the emitter pass's cost is sampled before it runs.
pub const EMITTER_COST_SAMPLES: usize = 64;

/// Rays an emitter pass may trace in all whatever its cost per cell (a small grid's pass is
/// cheap even where every cell emits): about 2–5 s on 2 cores.
pub const MAX_EMITTER_RAYS: f64 = 2e7;

/// Rays an export may trace to give the zonal methods' fluence where cells do not scatter
/// (about 15 s on 2 cores; the fire sample's 24³ cells take 4.4 × 10⁷ per channel).
pub const MAX_EXPORT_RAYS: f64 = 1e8;

/// Whether an emitter pass of `rays_per_cell` (estimated) over `cells` cells is worth running.
pub fn emitter_pass_pays(rays_per_cell: f64, cells: usize) -> bool {
    rays_per_cell <= MAX_EMITTER_RAYS_PER_CELL || rays_per_cell * cells as f64 <= MAX_EMITTER_RAYS
}

/// The emitter pass's estimated rays per cell for channel `c` of `medium` (the grid the solve
/// runs on), and whether a solve runs the pass at that cost: what [`emitter_pass`] decides and
/// `volrad info` reports.
pub fn emitter_pass_decision(medium: &Medium, c: usize) -> Result<(f64, bool)> {
    let cost = EmitterPass::estimated_rays_per_cell(
        medium,
        c,
        &EmitterPassOptions::default(),
        EMITTER_COST_SAMPLES,
    )
    .context("the emitter pass")?;
    Ok((cost, emitter_pass_pays(cost, medium.grid().cell_count())))
}

/// An emitting channel's emitter pass as a solve of a scene would decide it.
pub struct EmitterPassPlan {
    pub channel: usize,
    /// Estimated rays per cell, and the cells of the grid the solve runs on.
    pub rays_per_cell: f64,
    pub cells: usize,
    /// Whether the solve runs the pass at that cost ([`emitter_pass_pays`]).
    pub runs: bool,
}

/// The emitter passes a solve of `scene` with `settings` considers, one per emitting channel,
/// decided as the solve decides them: on the grid it solves on (the transport grid when it is
/// coarser). Empty for methods without the pass, or when nothing emits.
pub fn emitter_pass_plans(scene: &Scene, settings: &SolveSettings) -> Vec<EmitterPassPlan> {
    let medium = &scene.medium;
    let emitting: Vec<usize> = (0..medium.channels().len())
        .filter(|&c| !medium.channels()[c].emission.is_zero())
        .collect();
    if !settings.method.solves_linear_system() || emitting.is_empty() {
        return Vec::new();
    }
    let coarse = crate::engine::budget::transport_grid(scene, settings)
        .ok()
        .filter(|k| !k.is_data_grid())
        .and_then(|k| k.medium(medium).ok());
    let solved = coarse.as_ref().unwrap_or(medium);
    emitting
        .into_iter()
        .filter_map(|c| {
            let (rays_per_cell, runs) = emitter_pass_decision(solved, c).ok()?;
            Some(EmitterPassPlan {
                channel: c,
                rays_per_cell,
                cells: solved.grid().cell_count(),
                runs,
            })
        })
        .collect()
}

/// The emitter pass of channel `c` (the emitters' uncollided light, traced to every cell
/// centre) when the solve method takes it as its first-collision source — the zonal methods
/// and discrete ordinates —, the channel emits, and the pass's estimated cost is at most
/// [`MAX_EMITTER_RAYS_PER_CELL`]; `None` otherwise (the emission then goes through the
/// operator, as its source term).
pub fn emitter_pass(
    medium: &Medium,
    c: usize,
    settings: &SolveSettings,
    hooks: &SolveHooks,
) -> Result<Option<EmitterPass>> {
    if !settings.method.solves_linear_system() || medium.channels()[c].emission.is_zero() {
        return Ok(None);
    }
    let (cost, pays) = emitter_pass_decision(medium, c)?;
    if !pays {
        // An extended emitting region (a fire in its smoke): a smooth source, which the
        // operator carries without ray effects, and whose pass would cost far more than the
        // solve.
        tracing::info!(
            rays_per_cell = cost,
            "emitter pass skipped: the emission is carried by the operator"
        );
        return Ok(None);
    }
    hooks.control.phase(&channel_phase(
        "tracing the emitters' uncollided light",
        c,
        medium.channels().len(),
    ));
    // Discrete ordinates draw the emitters' first scattering from the pass; beside an
    // emitting region its light is binned by direction (the rest keep a cone and a rest).
    let options = EmitterPassOptions {
        binned_cells: if settings.method == SolveMethod::DiscreteOrdinates {
            EMITTER_BINNED_CELLS
        } else {
            0
        },
        ..EmitterPassOptions::default()
    };
    let pass = EmitterPass::compute(medium, c, &options).context("the emitter pass")?;
    let report = pass.report();
    tracing::info!(
        emitting_cells = report.emitting_cells,
        clusters = report.clusters,
        near_cells = report.near_cells,
        binned_cells = report.binned_cells,
        far_rays = report.far_rays,
        seconds = report.seconds,
        "emitter pass"
    );
    Ok(Some(pass))
}

/// `64×64×48 cells`, for progress messages.
pub fn grid_text(grid: &medium::Grid) -> String {
    let [x, y, z] = grid.dims;
    format!("{x}×{y}×{z} cells")
}

/// Zonal multiple scattering (exact or hierarchical form factors) for channel `c`. With an
/// emitter pass, the emission's uncollided light is the pass's (traced exactly) and the
/// operator carries only scattered light: `g = e + g_s` with
/// `g_s = S₁ + σs φ_e / 4π + K g_s` instead of `g = S₁ + e + K g`.
pub fn solve_zonal(
    medium: &Medium,
    outside: OutsideLight,
    c: usize,
    light_pass: &LightPass,
    emitters: Option<&EmitterPass>,
    settings: &SolveSettings,
    hooks: &SolveHooks,
) -> Result<ChannelSolve> {
    let OutsideLight {
        environment,
        ground,
    } = outside;
    let channel = &medium.channels()[c];
    // The lights' first bounce is the render's exact single scattering; the environment's is
    // smooth in direction and stays in the solved source (`higher_order` keeps it).
    let light_source = light_pass
        .zonal_source(medium, c)
        .with_context(|| format!("zonal source of channel {c}"))?;
    if channel.albedo.max() == 0.0 {
        // Nothing scatters: the source is the answer (g = E), whatever the iteration — the
        // symmetrised methods' weights (σt/σs) do not even exist here.
        tracing::info!("no scattering in channel {c}: the first pass is the solution");
        // The ground: lit by what reaches it unscattered and by the emission.
        let ground_radiance = match ground {
            Some(gr) => {
                let e_scat = gr.scattered_irradiance(medium, c, &|cell, _| {
                    channel.emission.get(cell) as f64
                })?;
                Some(gr.radiance(Some(&e_scat)))
            }
            None => None,
        };
        return Ok((
            ScatteredField::Isotropic {
                source: light_source.iter().map(|&v| v as f32).collect(),
                higher_order: vec![0.0; light_source.len()],
            },
            Some(SolveReport::without_iterations(
                settings.iteration.to_string(),
            )),
            ground_radiance,
        ));
    }
    let mut source = light_source.clone();
    if let Some(pass) = emitters {
        // The emission leaves the iterated source; its first collision comes in exactly.
        for (i, (s, phi)) in source.iter_mut().zip(pass.fluence()).enumerate() {
            *s += channel.sigma_s(i) as f64 * phi / (4.0 * PI) - channel.emission.get(i) as f64;
        }
    }
    let channels = medium.channels().len();
    let op: Box<dyn TransportOperator> = match settings.method {
        SolveMethod::Zonal => {
            hooks.control.phase(&channel_phase(
                &format!(
                    "building the exact form factors ({})",
                    grid_text(medium.grid())
                ),
                c,
                channels,
            ));
            let op = FormFactorMatrix::build(medium, c, &ExactOptions::default(), None)
                .context("building the exact form factors")?;
            tracing::info!(
                entries = op.report().entries,
                seconds = op.report().seconds,
                "form factors built"
            );
            Box::new(op)
        }
        _ => {
            hooks.control.phase(&channel_phase(
                &format!(
                    "building the hierarchical form factors ({})",
                    grid_text(medium.grid())
                ),
                c,
                channels,
            ));
            let op = HierarchicalOperator::build_with_importance(
                medium,
                c,
                &HierarchicalOptions {
                    tolerance: HIERARCHY_TOLERANCE,
                    ..HierarchicalOptions::default()
                },
                // Error control relative to every cell's own light, estimated by its
                // first-collision source.
                Some(&source),
            )
            .context("building the hierarchical form factors")?;
            tracing::info!(
                links = op.report().entries,
                near_entries = op.near_entries(),
                shared_near_rows = op.shared_near_rows(),
                links_per_level = ?op.links_per_level(),
                seconds = op.report().seconds,
                "hierarchy built"
            );
            Box::new(op)
        }
    };
    let environment = environment.filter(|e| !e.is_dark());
    let (g, report, ground_radiance) = match ground {
        None => {
            if let Some(env) = environment {
                add_zonal_environment(&mut source, env, medium, c, op.as_ref(), false)?;
            }
            let (mut g, report) = run_solver(op.as_ref(), &source, None, settings, hooks)?;
            if emitters.is_some() {
                for (i, g) in g.iter_mut().enumerate() {
                    *g += channel.emission.get(i) as f64;
                }
            }
            (g, report, None)
        }
        Some(gr) => {
            // Below the horizon the ground, not the environment, sends light up; the ground
            // adds what it sends beyond what the environment's source already counts there.
            let below = match environment {
                Some(env) => add_zonal_environment(&mut source, env, medium, c, op.as_ref(), true)?,
                None => 0.0,
            };
            let mut round =
                |ground_source: &[f32], initial: Option<&[f64]>, settings: &SolveSettings| {
                    let looked_up = gr.lookup(ground_source.to_vec())?;
                    let mut s = source.clone();
                    add_zonal_ground(&mut s, medium, c, &looked_up, below)?;
                    let (mut g, report) = run_solver(op.as_ref(), &s, initial, settings, hooks)?;
                    let without_emission = emitters.is_some().then(|| g.clone());
                    if emitters.is_some() {
                        for (i, g) in g.iter_mut().enumerate() {
                            *g += channel.emission.get(i) as f64;
                        }
                    }
                    // The ground sees every order, the emission and the first bounce included.
                    let e_scat = gr.scattered_irradiance(medium, c, &|cell, _| g[cell])?;
                    let next = gr.radiance(Some(&e_scat));
                    Ok::<_, anyhow::Error>((
                        without_emission.unwrap_or_else(|| g.clone()),
                        g,
                        report,
                        next,
                    ))
                };
            couple_ground(gr, settings, hooks, c, medium.channels().len(), &mut round)?
        }
    };
    let higher_order = g
        .iter()
        .zip(&light_source)
        .map(|(g, e)| (g - e).max(0.0) as f32)
        .collect();
    Ok((
        ScatteredField::Isotropic {
            source: g.iter().map(|&v| v as f32).collect(),
            higher_order,
        },
        Some(report),
        ground_radiance,
    ))
}

/// The light that enters a channel's solve from outside the grid: the environment's and,
/// with a ground, the ground's (which the solve couples with the medium).
#[derive(Clone, Copy, Default)]
pub struct OutsideLight<'a> {
    pub environment: Option<&'a Environment>,
    pub ground: Option<&'a ChannelGround<'a>>,
}

/// A channel's solve: the scattered field, the iteration's report and, with a ground, the
/// ground's reflected radiance per patch.
pub type ChannelSolve = (ScatteredField, Option<SolveReport>, Option<Vec<f32>>);

/// One ground–medium round: from the ground's radiance per patch, the solution to start
/// from and the solve's settings for the round, the solution to start the next round from,
/// the solved vector, the report and the ground's next radiance.
type GroundRound<'a> = dyn FnMut(
        &[f32],
        Option<&[f64]>,
        &SolveSettings,
    ) -> Result<(Vec<f64>, Vec<f64>, SolveReport, Vec<f32>)>
    + 'a;

/// Iterates ground and medium by blocks until the ground's radiance settles (see
/// [`crate::engine::ground`]); the report counts the iterations of every round.
fn couple_ground(
    gr: &ChannelGround,
    settings: &SolveSettings,
    hooks: &SolveHooks,
    c: usize,
    channels: usize,
    round: &mut GroundRound<'_>,
) -> Result<(Vec<f64>, SolveReport, Option<Vec<f32>>)> {
    let mut ground = gr.radiance(None);
    let mut warm: Option<Vec<f64>> = None;
    let mut iterations = 0;
    // Early rounds need the medium only as well as the ground is known: each is solved to a
    // hundredth of the ground's last change, and once the ground has settled one last round
    // is solved to the scene's tolerance.
    let mut change = 1.0f64;
    let mut last = false;
    for k in 1.. {
        hooks.control.phase(&channel_phase(
            &format!("coupling the ground, round {k}"),
            c,
            channels,
        ));
        // (Within ten times the scene's tolerance, the scene's: no round for so little.)
        let loose = 0.01 * change;
        let round_settings = SolveSettings {
            tolerance: if last || loose < 10.0 * settings.tolerance {
                settings.tolerance
            } else {
                loose
            },
            ..settings.clone()
        };
        let (next_warm, solved, mut report, next) =
            round(&ground, warm.as_deref(), &round_settings)?;
        if hooks.control.is_cancelled() {
            bail!("solve cancelled");
        }
        iterations += report.iterations;
        change = relative_change(&ground, &next);
        ground = next;
        tracing::info!(
            round = k,
            change,
            iterations = report.iterations,
            tolerance = round_settings.tolerance,
            "ground and medium"
        );
        let settled = change <= GROUND_TOLERANCE;
        if (settled && round_settings.tolerance <= settings.tolerance) || k >= MAX_GROUND_ROUNDS {
            if !settled {
                tracing::warn!(
                    change,
                    "the ground's light had not settled after {MAX_GROUND_ROUNDS} rounds"
                );
            }
            report.iterations = iterations;
            return Ok((solved, report, Some(ground)));
        }
        last = settled;
        warm = Some(next_warm);
    }
    unreachable!("the loop returns by its last round")
}

/// Adds to the zonal `source` of channel `c` the first-collision source of a ground's light
/// (`ground`, looked up along each bin's lines going up) beyond a uniform radiance `below`
/// the environment's source already counts there: its uncollided fluence over the upward half
/// of [`GROUND_INFLOW_BINS`], one transmittance pass per bin.
fn add_zonal_ground(
    source: &mut [f64],
    medium: &Medium,
    c: usize,
    ground: &medium::ground::GroundRadiance,
    below: f64,
) -> Result<()> {
    let channel = &medium.channels()[c];
    let grid = medium.grid();
    let bins = DirectionBins::with_count(GROUND_INFLOW_BINS)?;
    let mut fluence = vec![0.0; grid.cell_count()];
    for (&d, &omega) in bins.centres().iter().zip(bins.solid_angles()) {
        if d.z <= 0.0 {
            continue;
        }
        let t = medium::light_pass::directional_cell_transmittance(
            grid,
            &channel.sigma_t,
            d,
            ZONAL_INFLOW_RAYS_PER_CELL,
        )
        .context("the ground's uncollided light")?;
        fluence
            .par_iter_mut()
            .zip(&t)
            .enumerate()
            .for_each(|(i, (f, ti))| {
                *f += omega * (ground.sent_along(grid.cell_center(i), d, 0) - below) * ti
            });
    }
    add_scattered_fluence(source, medium, c, &fluence);
    Ok(())
}

/// Adds `σs φ / 4π`, the isotropic first-collision source of the uncollided fluence `φ`, to
/// the zonal `source` of channel `c`.
fn add_scattered_fluence(source: &mut [f64], medium: &Medium, c: usize, fluence: &[f64]) {
    let channel = &medium.channels()[c];
    for (i, (s, phi)) in source.iter_mut().zip(fluence).enumerate() {
        *s += channel.albedo.get(i) as f64 * channel.sigma_t[i] as f64 * phi / (4.0 * PI);
    }
}

/// The radiance `env` sends along each bin of `bins` in channel `c` of `channels`: at the
/// bin's centre, or, for a map, its mean over the bin (every texel's power put in the bin its
/// light travels through, so a small bright source keeps its power whatever the bins; a
/// smooth sky is well sampled at the centres).
pub fn environment_bin_radiance(
    env: &Environment,
    bins: &DirectionBins,
    c: usize,
    channels: usize,
) -> Vec<f64> {
    let Some(map) = env.as_map() else {
        return bins
            .centres()
            .iter()
            .map(|&d| env.radiance_along(d, c, channels))
            .collect();
    };
    let mut power = vec![0.0; bins.len()];
    map.for_each_sample(|from, omega, rgb| {
        // Light from `from` travels along −from.
        power[bins.bin_of(-from)] += omega * medium::environment::pick(&rgb, c, channels);
    });
    power
        .iter()
        .zip(bins.solid_angles())
        .map(|(p, omega)| p / omega)
        .collect()
}

/// Adds the environment's first-collision source to the zonal `source` of channel `c`; with
/// `under_ground`, a sky's light from below the horizon is left out (the ground sends it).
/// Returns the radiance the source counts from below the horizon: a uniform environment's,
/// which is taken whole even over a ground (its reciprocity source is exact in the
/// operator's own terms: the white furnace), and 0 for a sky.
fn add_zonal_environment(
    source: &mut [f64],
    env: &Environment,
    medium: &Medium,
    c: usize,
    op: &dyn TransportOperator,
    under_ground: bool,
) -> Result<f64> {
    let channel = &medium.channels()[c];
    let channels = medium.channels().len();
    if env.uniform_radiance().is_some() {
        // A uniform environment by reciprocity: the light it sends into cell i is what cell i
        // would send out uncollided, `E_i = L (a_i σt_i − (K σt)_i)` (a non-absorbing medium
        // then holds L everywhere: the white furnace), with this operator's own form factors
        // so the two stay consistent. (Uniform: any direction gives L.)
        let l = env.radiance_along(DVec3::Z, c, channels);
        let sigma_t: Vec<f64> = channel.sigma_t.iter().map(|&s| s as f64).collect();
        let mut collided = vec![0.0; sigma_t.len()];
        op.apply(&sigma_t, &mut collided);
        for (i, (s, k)) in source.iter_mut().zip(&collided).enumerate() {
            *s += l * (channel.albedo.get(i) as f64 * sigma_t[i] - k).max(0.0);
        }
        return Ok(l);
    }
    // A sky: its uncollided fluence over ENVIRONMENT_BINS directions, scattered isotropically
    // (bins of light going up, from below the horizon, carry none over a ground).
    let bins = DirectionBins::with_count(ENVIRONMENT_BINS)?;
    let mut radiances = environment_bin_radiance(env, &bins, c, channels);
    if under_ground {
        for (r, d) in radiances.iter_mut().zip(bins.centres()) {
            if d.z > 0.0 {
                *r = 0.0;
            }
        }
    }
    let fluence = Environment::uncollided_fluence(
        medium.grid(),
        &channel.sigma_t,
        bins.centres(),
        bins.solid_angles(),
        &radiances,
    )
    .context("the environment's uncollided light")?;
    add_scattered_fluence(source, medium, c, &fluence);
    Ok(0.0)
}

/// The sweep options a scene's `[solve]` settings ask for, for `phase` in `bins`.
pub fn ordinates_options(
    settings: &SolveSettings,
    bins: &DirectionBins,
    phase: &PhaseFunction,
) -> OrdinatesOptions {
    OrdinatesOptions {
        // The scene's refinement splits the transport grid (the unknowns with it), which
        // [`solve_ordinates`] is given; the sweep's own sub-cells stay at one per cell.
        transport_refinement: 1,
        forward_truncation_degrees: settings
            .forward_peak_cone
            .unwrap_or_else(|| default_forward_truncation_degrees(bins, phase)),
        ..OrdinatesOptions::default()
    }
}

/// The forward peak a discrete-ordinates solve with `settings` in `bins` direction bins
/// truncates (δ-M): its cone in degrees and the fraction of scattering inside it.
pub fn forward_truncation(
    settings: &SolveSettings,
    bins: usize,
    phase: &PhaseFunction,
) -> (f64, f64) {
    let cone = DirectionBins::with_count(bins)
        .map(|bins| ordinates_options(settings, &bins, phase))
        .unwrap_or_default()
        .forward_truncation_degrees;
    let fraction = formfactor::ordinates::forward_truncation_fraction(cone, phase).unwrap_or(0.0);
    (cone, fraction)
}

/// Discrete-ordinates multiple scattering for channel `c`. With an emitter pass the bins
/// carry no uncollided emission (whose few directions would show as ray effects): the
/// emission's first collision, from the pass, is the external density instead of `e`, and is
/// what the render adds as its first scattering.
pub fn solve_ordinates(
    medium: &Medium,
    outside: OutsideLight,
    c: usize,
    light_pass: &LightPass,
    emitters: Option<&EmitterPass>,
    settings: &SolveSettings,
    hooks: &SolveHooks,
) -> Result<ChannelSolve> {
    let OutsideLight {
        environment,
        ground,
    } = outside;
    // `medium` is the transport grid's: the bins volrad chooses are chosen on it.
    let bins = DirectionBins::with_count(
        settings
            .bins
            .count(&medium.phase(), medium.grid().cell_count()),
    )?;
    let options = ordinates_options(settings, &bins, &medium.phase());
    let channels = medium.channels().len();
    hooks.control.phase(&channel_phase(
        &format!(
            "preparing the transport sweeps ({} × {} bins)",
            grid_text(medium.grid()),
            bins.len()
        ),
        c,
        channels,
    ));
    let op = OrdinatesOperator::new(medium, c, bins, options)?;
    // I = T(S1 + e) + K I: the once-transported external density is the system's source
    // (with an emitter pass, the emission's first collision S_e in place of e, and the
    // channel's emission is left out of the transport).
    let mut external = op.first_bounce_density_from_pass(light_pass)?;
    // The beams' first scattering is swept with its own profile in each cell, not the
    // neighbours' differences (thick cells along an oblique beam).
    let beams = op.beam_profiles_from_pass(light_pass)?;
    let mut source = vec![0.0; op.len()];
    // The fluence of the source and of any uncollided inflow at every cell, the empty ones
    // too (which carry no state): with `K I`'s, the export's fluence there.
    let mut fixed_fluence = vec![0.0; medium.grid().cell_count()];
    match emitters {
        Some(pass) => {
            op.add_collision_density(pass, &mut external)?;
            op.transport_first_bounce(&external, &beams, &mut source, Some(&mut fixed_fluence));
        }
        None => {
            op.transport_external(
                &external,
                Some(&beams),
                &mut source,
                Some(&mut fixed_fluence),
            );
        }
    }
    drop(beams);
    let mut inflow_fluence: Option<Vec<f64>> = None;
    let environment = environment.filter(|e| !e.is_dark());
    // A ground's last round gathers the final bounce toward every bin already (what the
    // ground sees): the render's higher orders are that, not a second gather.
    let mut gathered: Option<Vec<f64>> = None;
    let (radiance, report, ground_radiance) = match ground {
        None => {
            // Only a ground's rounds read the external density again: each cells × bins
            // vector let go is a solve's peak lowered by a quarter.
            drop(external);
            // The environment's uncollided radiance ψ on the bins, in the sweep's own
            // discretisation (so a non-absorbing medium holds L everywhere: the white
            // furnace). Its scattering K ψ joins the source, and ψ what the render's final
            // bounce scatters: its first bounce is smooth in direction, so the bins carry it
            // rather than the render's single scattering.
            let uncollided = match environment {
                Some(env) => {
                    let along = environment_bin_radiance(env, op.bins(), c, channels);
                    let psi = op.inflow_radiance(&along)?;
                    let mut scattered = vec![0.0; op.len()];
                    op.apply(&psi.radiance, &mut scattered);
                    for (s, k) in source.iter_mut().zip(&scattered) {
                        *s += k;
                    }
                    inflow_fluence = Some(psi.fluence);
                    Some(psi.radiance)
                }
                None => None,
            };
            let (mut radiance, report) = run_solver(&op, &source, None, settings, hooks)?;
            drop(source);
            // The bins hold everything but the lights' unscattered beams.
            if let Some(psi) = &uncollided {
                for (r, p) in radiance.iter_mut().zip(psi) {
                    *r += p;
                }
            }
            (radiance, report, None)
        }
        Some(gr) => {
            // Light enters from the environment above the horizon and from the ground below,
            // each constant along a bin's lines: ψ from one sweep, as for the environment.
            let m = op.bins().len();
            let along = match environment {
                Some(env) => environment_bin_radiance(env, op.bins(), c, channels),
                None => vec![0.0; m],
            };
            let centres = op.bins().centres().to_vec();
            let grid = *medium.grid();
            let channel = &medium.channels()[c];
            let mut round =
                |ground_source: &[f32], initial: Option<&[f64]>, settings: &SolveSettings| {
                    let looked_up = gr.lookup(ground_source.to_vec())?;
                    let psi = op.inflow_field(|cell, l| {
                        let d = centres[l];
                        if d.z > 0.0 {
                            looked_up.sent_along(grid.cell_center(cell), d, 0)
                        } else {
                            along[l]
                        }
                    });
                    inflow_fluence = Some(psi.fluence);
                    let psi = psi.radiance;
                    let mut s = vec![0.0; op.len()];
                    op.apply(&psi, &mut s);
                    for (s, b) in s.iter_mut().zip(&source) {
                        *s += b;
                    }
                    let (solved, report) = run_solver(&op, &s, initial, settings, hooks)?;
                    drop(s);
                    let mut total = solved.clone();
                    for (r, p) in total.iter_mut().zip(&psi) {
                        *r += p;
                    }
                    drop(psi);
                    // What the ground sees: every scattering toward it (the first bounce, from the
                    // external density, and the higher orders) and the emission.
                    let mut toward = vec![0.0; op.len()];
                    op.gather_density(&total, &mut toward);
                    let bins = op.bins();
                    // `external` holds no emission (it is transported apart, or replaced by
                    // the emitters' first collision).
                    let e_scat = gr.scattered_irradiance(medium, c, &|cell, travel| {
                        let scattered = op.state_row(cell).map_or(0.0, |k| {
                            let i = k * m + bins.bin_of(travel);
                            (toward[i] + external[i]).max(0.0)
                        });
                        scattered + channel.emission.get(cell) as f64
                    })?;
                    let next = gr.radiance(Some(&e_scat));
                    gathered = Some(toward);
                    Ok::<_, anyhow::Error>((solved, total, report, next))
                };
            couple_ground(gr, settings, hooks, c, channels, &mut round)?
        }
    };
    // What the render adds to the exact first bounce: scattering of the bins' radiance (the
    // lights' once-scattered light and beyond), i.e. second and higher orders, by the true
    // phase function towards each bin centre (the final directional bounce; the render
    // interpolates).
    let higher = gathered.unwrap_or_else(|| {
        let mut higher = vec![0.0; op.len()];
        op.gather_density(&radiance, &mut higher);
        higher
    });
    // The emission's own first scattering is not among them: the render draws it in the
    // view's own direction ([`emitter_beam`]), as it draws the lights'.
    // Of the bins' radiance only its fluence is kept (the export's; at the empty cells the
    // source's, the inflow's and one more scattering's, `I = F + K I`); the higher orders as
    // f32, for the cells that scatter (the rest are zeros), after the f64 radiance is let go.
    if let Some(inflow) = &inflow_fluence {
        for (f, i) in fixed_fluence.iter_mut().zip(inflow) {
            *f += i;
        }
    }
    let fluence: Vec<f32> = op
        .fluence_everywhere(&radiance, &fixed_fluence)
        .iter()
        .map(|&v| v as f32)
        .collect();
    drop(radiance);
    let higher_order = CellRows::from_rows(
        op.grid().cell_count(),
        op.bins().len(),
        op.state_cells(),
        |i| higher[i].max(0.0) as f32,
    )
    .context("the higher orders' rows")?;
    drop(higher);
    Ok((
        ScatteredField::Binned {
            fluence,
            higher_order,
        },
        Some(report),
        ground_radiance,
    ))
}

/// The emitters' first scattering in channel `c` of `medium` (the grid the pass ran on), as
/// the render draws it ([`crate::engine::sources::EmitterBeamSource`]): per cell
/// `[σs φ, weight, cos_half_angle, d]` — the emitter pass's flux `φ` and the incident light's
/// shape about the flux vector's direction `d` ([`medium::phase::IncidentShape`], from the
/// pass's mean and mean squared cosine; the shape
/// [`OrdinatesOperator::add_collision_density`] gives the sweeps) — and the widest-lit cells'
/// light in direction bins ([`EmitterPass::binned_row`]), which a cone and a rest cannot
/// hold beside an emitting region. Drawn with the true phase function in the view's
/// direction: stored in the bins at their centres, as a beam and an isotropic rest, it was
/// drawn between bin centres and was 5–8 % RMS off the path tracer on a cube emitting inside
/// a g = 0.6 cloud, whatever the bins (docs/validation.md, *Light from emitting cells*).
pub fn emitter_beam(medium: &Medium, c: usize, pass: &EmitterPass) -> Result<EmitterBeam> {
    let channel = &medium.channels()[c];
    let fluence = pass.fluence();
    let mut shapes = Vec::with_capacity(EMITTER_BEAM_VALUES * fluence.len());
    for (i, &phi) in fluence.iter().enumerate() {
        let sigma_s = channel.sigma_s(i) as f64;
        if sigma_s == 0.0 || phi <= 0.0 {
            shapes.extend_from_slice(&[0.0; EMITTER_BEAM_VALUES]);
            continue;
        }
        let (shape, d) = pass.incident_shape(i);
        shapes.extend_from_slice(&[
            (sigma_s * phi) as f32,
            shape.weight() as f32,
            shape.cos_half_angle() as f32,
            d.x as f32,
            d.y as f32,
            d.z as f32,
        ]);
    }
    let binned = CellRows::from_rows(
        fluence.len(),
        EMITTER_BIN_VALUES,
        pass.binned_cells(),
        |i| pass.binned_row(i / EMITTER_BIN_VALUES)[i % EMITTER_BIN_VALUES],
    )
    .context("the emitters' binned light")?;
    Ok(EmitterBeam { shapes, binned })
}

/// Blasi & Wuethrich's two-pass method for channel `c`: second and higher orders stored by a
/// seeded, deterministic photon pass (the render adds the exact first bounce).
pub fn solve_two_pass(
    scene: &Scene,
    ground: Option<&ChannelGround>,
    c: usize,
    settings: &SolveSettings,
    hooks: &SolveHooks,
) -> Result<ChannelSolve> {
    use montecarlo::two_pass::{
        energetize, energetize_over_ground, EnergetizeOptions, GroundPhotons,
    };
    let bins = two_pass_bins(&scene.medium.phase());
    let options = EnergetizeOptions {
        photons_per_light: settings.photons,
        bins,
        include_first_bounce: false,
        environment: scene.environment.clone(),
        ..EnergetizeOptions::default()
    };
    if hooks.control.is_cancelled() {
        bail!("solve cancelled");
    }
    hooks.control.phase(&channel_phase(
        "tracing photons",
        c,
        scene.medium.channels().len(),
    ));
    let (solution, ground_radiance) = match ground {
        None => (
            energetize(&scene.medium, c, &scene.lights, &options, None)
                .context("two-pass energetization")?,
            None,
        ),
        Some(gr) => {
            // The photons carry the ground's unscattered light up and bring the scattered
            // light down, tallied on coarse patches (enough photons each) and interpolated.
            let photons = GroundPhotons {
                unscattered: gr.lookup(gr.radiance(None))?,
                tally: gr.patches().coarsened(GROUND_TALLY_SIDE),
            };
            let (solution, tallied) =
                energetize_over_ground(&scene.medium, c, &scene.lights, &options, &photons, None)
                    .context("two-pass energetization")?;
            let scattered = gr.patches().resample(&photons.tally, &tallied);
            (solution, Some(gr.radiance(Some(&scattered))))
        }
    };
    tracing::info!(
        photons = solution.energy.photons,
        imbalance = solution.energy.relative_imbalance(),
        "two-pass energetization done"
    );
    Ok((
        ScatteredField::TwoPass(Box::new(solution)),
        None,
        ground_radiance,
    ))
}

/// Most patches a side the two-pass method tallies the ground's scattered light on.
const GROUND_TALLY_SIDE: usize = 32;

/// One line per channel whose iteration stopped before its tolerance (what `volrad solve`
/// warns and the Python package raises as a `RuntimeWarning`).
pub fn convergence_warnings(solution: &Solution) -> Vec<String> {
    solution
        .channels
        .iter()
        .enumerate()
        .filter_map(|(c, ch)| {
            let r = ch.report.as_ref().filter(|r| !r.converged)?;
            Some(format!(
                "channel {c} did not converge: relative residual {:.3e} after {} iterations ({})",
                r.final_residual, r.iterations, r.stop_reason
            ))
        })
        .collect()
}

/// The direction bins the two-pass method tallies photons in: one for isotropic scattering,
/// 12 × 24 otherwise.
pub fn two_pass_bins(phase: &medium::PhaseFunction) -> montecarlo::DirectionBins {
    if phase.is_isotropic() {
        montecarlo::DirectionBins::ISOTROPIC
    } else {
        montecarlo::DirectionBins {
            n_theta: 12,
            n_phi: 24,
        }
    }
}

/// The direction bins a solution of `transport` (the transport grid's medium) stores
/// (discrete ordinates only).
pub fn stored_bins(settings: &SolveSettings, transport: &Medium) -> Option<StoredBins> {
    if settings.method != SolveMethod::DiscreteOrdinates {
        return None;
    }
    let count = settings
        .bins
        .count(&transport.phase(), transport.grid().cell_count());
    let bins = DirectionBins::with_count(count).ok()?;
    Some(StoredBins {
        face_resolution: bins.face_divisions(),
        directions: bins.centres().iter().map(|d| d.to_array()).collect(),
        solid_angles: bins.solid_angles().to_vec(),
    })
}

/// What `volrad solve` prints: per channel, the method, iterations and residual.
#[derive(Debug, Serialize)]
pub struct SolveSummary {
    pub method: String,
    pub scene_hash: String,
    pub seconds: f64,
    pub channels: Vec<ChannelSummary>,
}

#[derive(Debug, Serialize)]
pub struct ChannelSummary {
    pub iteration: Option<String>,
    pub iterations: usize,
    pub converged: bool,
    pub final_residual: Option<f64>,
    pub stop_reason: Option<String>,
    pub solve_seconds: Option<f64>,
    pub light_energy_imbalance: f64,
}

impl SolveSummary {
    pub fn of(solution: &Solution, seconds: f64) -> SolveSummary {
        SolveSummary {
            method: solution.method.name().to_string(),
            scene_hash: solution.scene_hash.clone(),
            seconds,
            channels: solution
                .channels
                .iter()
                .map(|ch| ChannelSummary {
                    iteration: ch.report.as_ref().map(|r| r.method.clone()),
                    iterations: ch.report.as_ref().map_or(0, |r| r.iterations),
                    converged: ch.report.as_ref().is_none_or(|r| r.converged),
                    final_residual: ch.report.as_ref().map(|r| r.final_residual),
                    stop_reason: ch.report.as_ref().map(|r| r.stop_reason.name().to_string()),
                    solve_seconds: ch.report.as_ref().map(|r| r.seconds),
                    light_energy_imbalance: ch
                        .light_pass
                        .fields
                        .iter()
                        .map(|f| f.energy.relative_imbalance())
                        .fold(0.0, f64::max),
                })
                .collect(),
        }
    }
}

impl fmt::Display for SolveSummary {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(f, "method      {}", self.method)?;
        for (c, ch) in self.channels.iter().enumerate() {
            match (&ch.iteration, ch.final_residual) {
                (Some(it), Some(res)) => {
                    writeln!(
                    f,
                    "channel {c}   {it}: {} iterations, relative residual {res:.3e}, {} ({:.2} s)",
                    ch.iterations,
                    if ch.converged { "converged" } else { "NOT converged" },
                    ch.solve_seconds.unwrap_or(0.0)
                )?
                }
                _ => writeln!(f, "channel {c}   light pass only (no linear solve)")?,
            }
        }
        writeln!(
            f,
            "total       {:.2} s, scene hash {}",
            self.seconds, self.scene_hash
        )
    }
}

/// A per-cell field of a solution that `volrad export` writes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ExportField {
    /// ∫ I dω per cell, including unscattered light.
    Fluence,
    /// The solved source g per cell (radiance per unit length).
    Source,
    /// Extinction coefficient per cell.
    SigmaT,
}

impl ExportField {
    /// The spellings `--field` accepts, in the order of [`ExportField::name`].
    pub const NAMES: [&'static str; 3] = ["fluence", "source", "sigma-t"];

    pub fn name(self) -> &'static str {
        match self {
            ExportField::Fluence => Self::NAMES[0],
            ExportField::Source => Self::NAMES[1],
            ExportField::SigmaT => Self::NAMES[2],
        }
    }
}

impl std::str::FromStr for ExportField {
    type Err = String;

    fn from_str(name: &str) -> Result<Self, String> {
        [
            ExportField::Fluence,
            ExportField::Source,
            ExportField::SigmaT,
        ]
        .into_iter()
        .find(|f| f.name() == name)
        .ok_or_else(|| {
            format!(
                "unknown field `{name}` (expected one of: {})",
                Self::NAMES.join(", ")
            )
        })
    }
}

/// A per-cell field of a solution for export, with its units.
pub fn export_field(
    solution: &Solution,
    channel: usize,
    field: ExportField,
) -> Result<(Vec<f32>, &'static str)> {
    let Some(ch) = solution.channels.get(channel) else {
        bail!(
            "--channel {channel}: the solution has {} channel(s)",
            solution.channels.len()
        );
    };
    let medium = &solution.medium.channels()[channel];
    let cells = solution.medium.grid().cell_count();
    Ok(match field {
        ExportField::SigmaT => (medium.sigma_t.clone(), "1/length"),
        ExportField::Source => match &ch.scattered {
            ScatteredField::Isotropic { source, .. } if solution.transport.is_data_grid() => {
                (source.clone(), "radiance/length")
            }
            _ => {
                // Angular mean of the source: emission + σs (fluence / 4π).
                let fluence = fluence(solution, channel)?;
                let values = (0..cells)
                    .map(|i| {
                        (medium.emission.get(i) as f64
                            + medium.sigma_s(i) as f64 * fluence[i] / (4.0 * PI))
                            as f32
                    })
                    .collect();
                (values, "radiance/length (angular mean)")
            }
        },
        ExportField::Fluence => (
            fluence(solution, channel)?
                .into_iter()
                .map(|v| v as f32)
                .collect(),
            "radiance × steradian (∫ I dω)",
        ),
    })
}

/// `∫ I dω` per cell of channel `c`: the lights' unscattered light, the emitters'
/// uncollided light and the scattered light. (Two-pass's from the mean over directions of
/// its stored field; single scatter and none get the emitters' light from an emitter pass,
/// and their scattered light is not counted: they do not solve it. An
/// environment's and a ground's uncollided light are counted where cells scatter, and by
/// discrete ordinates everywhere.)
///
/// A solution on another transport grid (coarser or split) gives the lights' unscattered light per data cell
/// and the rest (scattered, and emitted) interpolated trilinearly from the transport cells.
pub fn fluence(solution: &Solution, c: usize) -> Result<Vec<f64>> {
    let ch = &solution.channels[c];
    let unscattered = ch.light_pass.total_cell_irradiance();
    let transport = &solution.transport;
    if transport.is_data_grid() {
        return Ok(ch
            .render_cache
            .fluence(|| fluence_on(&solution.medium, c, ch, &unscattered, &solution.bins))?
            .to_vec());
    }
    let cache = ch.render_cache.transport(&solution.medium, transport, c)?;
    let coarse_pass = transport
        .light_pass(&solution.medium, c, &ch.light_pass, &cache.medium)
        .context("the light pass on the transport grid")?;
    let coarse_unscattered = coarse_pass.total_cell_irradiance();
    let collided: Vec<f64> = ch
        .render_cache
        .fluence(|| fluence_on(&cache.medium, c, ch, &coarse_unscattered, &solution.bins))?
        .iter()
        .zip(&coarse_unscattered)
        .map(|(f, u)| f - u)
        .collect();
    let grid = solution.medium.grid();
    Ok(unscattered
        .par_iter()
        .enumerate()
        .map(|(i, u)| {
            u + gather::Trilinear::new(transport.transport(), grid.cell_center(i))
                .sample(|o| collided[o])
        })
        .collect())
}

/// [`fluence`] on the grid the channel's fields live on: `medium` is on it, `unscattered` the
/// lights' unscattered fluence per cell of it.
fn fluence_on(
    medium: &Medium,
    c: usize,
    ch: &ChannelSolution,
    unscattered: &[f64],
    bins: &Option<StoredBins>,
) -> Result<Vec<f64>> {
    let m = &medium.channels()[c];
    // The emitters' uncollided fluence, computed only where a branch below needs it (a pass of
    // a whole emitting cloud takes seconds).
    let emitted = || -> Result<Vec<f64>> {
        Ok(match &ch.emitted_fluence {
            Some(f) => f.iter().map(|&v| v as f64).collect(),
            // Discrete ordinates solved without the pass carry the emission in their bins.
            None if matches!(ch.scattered, ScatteredField::Binned { .. }) => {
                vec![0.0; unscattered.len()]
            }
            None if !m.emission.is_zero() => {
                EmitterPass::compute(medium, c, &EmitterPassOptions::default())
                    .context("the emitter pass")?
                    .fluence()
                    .to_vec()
            }
            None => vec![0.0; unscattered.len()],
        })
    };
    let isotropic = medium.phase().is_isotropic();
    Ok(match (&ch.scattered, bins) {
        (ScatteredField::Isotropic { source, .. }, _) => {
            // g = e + σs φ / 4π for isotropic scattering, so φ = 4π (g − e) / σs where cells
            // scatter.
            let g: Vec<f64> = source.iter().map(|&v| (v as f64).max(0.0)).collect();
            let inside = |i: usize| {
                let s = m.sigma_s(i) as f64;
                (s > 0.0).then(|| 4.0 * PI * (g[i] - m.emission.get(i) as f64) / s)
            };
            flux_of_sources(medium, c, &g, unscattered, &emitted, false, inside)?
        }
        (ScatteredField::TwoPass(t), _) => {
            // The stored field holds every interaction but the lights' first (the render's
            // exact single scattering): its mean over directions Q̄ is σs/4π times the flux of
            // all light but the lights' unscattered light, so φ = unscattered + 4π Q̄ / σs.
            let (means, _) = ch
                .render_cache
                .two_pass_means(|| crate::engine::sources::TwoPassSource::means_of(t));
            // Each cell's isotropic source: its emission, the stored field's mean and the
            // lights' first scattering, which the field leaves to the render.
            let g: Vec<f64> = means
                .iter()
                .enumerate()
                .map(|(i, &q)| {
                    q as f64
                        + m.emission.get(i) as f64
                        + m.sigma_s(i) as f64 * unscattered[i] / (4.0 * PI)
                })
                .collect();
            let inside = |i: usize| {
                let s = m.sigma_s(i) as f64;
                (s > 0.0).then(|| unscattered[i] + 4.0 * PI * means[i] as f64 / s)
            };
            // With isotropic scattering traced everywhere: the photons' own noise in each
            // cell's tally averages out along the rays.
            flux_of_sources(medium, c, &g, unscattered, &emitted, isotropic, inside)?
        }
        (ScatteredField::Binned { fluence, .. }, Some(_)) => {
            let binned: Vec<f64> = fluence
                .iter()
                .zip(unscattered.iter().zip(&emitted()?))
                .map(|(f, (u, e))| u + e + *f as f64)
                .collect();
            if !isotropic {
                return Ok(binned);
            }
            // Scattering is isotropic, so every cell's source is g = e + σs φ / 4π: the
            // bins' flux enters only through the sources it feeds, and their ray effects (the
            // scattered light of a compact source carried on a few directions: 20–45 % from
            // cell to cell) average out along the traced rays.
            let g: Vec<f64> = binned
                .iter()
                .enumerate()
                .map(|(i, phi)| {
                    m.emission.get(i) as f64 + m.sigma_s(i) as f64 * phi.max(0.0) / (4.0 * PI)
                })
                .collect();
            flux_of_sources(medium, c, &g, unscattered, &emitted, true, |i| {
                Some(binned[i])
            })?
        }
        _ => unscattered
            .iter()
            .zip(&emitted()?)
            .map(|(u, e)| u + e)
            .collect(),
    })
}

/// The flux per cell from every cell's isotropic source `g` (emitted and scattered) traced to
/// it by an emitter pass of `g`, plus the lights' unscattered light: in every cell when
/// `everywhere`, else where `inside(i)` has no value (cells that do not scatter: empty space
/// around a cloud, absorbing cells, where a per-cell source does not say the flux) and
/// `inside(i)` elsewhere. When tracing would cost more than [`MAX_EXPORT_RAYS`] (a large
/// cloud's source traced to every empty cell: minutes), `inside(i)` where it has a value and
/// the emitters' uncollided light (`emitted`) elsewhere, with a warning.
fn flux_of_sources(
    medium: &Medium,
    c: usize,
    g: &[f64],
    unscattered: &[f64],
    emitted: &dyn Fn() -> Result<Vec<f64>>,
    everywhere: bool,
    inside: impl Fn(usize) -> Option<f64>,
) -> Result<Vec<f64>> {
    let n = unscattered.len();
    let own: Vec<Option<f64>> = (0..n).map(inside).collect();
    if !everywhere && own.iter().all(Option::is_some) {
        return Ok(own.into_iter().flatten().collect());
    }
    let options = EmitterPassOptions::default();
    let cost =
        EmitterPass::estimated_rays_per_cell_of(medium, c, g, &options, EMITTER_COST_SAMPLES)?;
    let (traced, fallback) = if cost * n as f64 <= MAX_EXPORT_RAYS {
        let pass = EmitterPass::from_sources(medium, c, g, &options)
            .context("tracing the cells' sources")?;
        (Some(pass.fluence().to_vec()), Vec::new())
    } else {
        tracing::warn!(
            rays_per_cell = cost,
            "fluence: each cell's own value, and where it has none only the uncollided light \
             (tracing every cell's source would cost too much)"
        );
        let fallback = if own.iter().all(Option::is_some) {
            Vec::new()
        } else {
            emitted()?
        };
        (None, fallback)
    };
    Ok((0..n)
        .map(|i| match (&traced, own[i]) {
            (Some(t), _) if everywhere => unscattered[i] + t[i],
            (_, Some(v)) => v,
            (Some(t), None) => unscattered[i] + t[i],
            (None, None) => unscattered[i] + fallback[i],
        })
        .collect())
}

/// Refuses a solution whose solve was cancelled in any channel: its fields are partial. (Not
/// converging is a report, not an error: callers warn in their own way.)
pub fn refuse_cancelled(solution: &Solution) -> Result<()> {
    let cancelled = solution
        .channels
        .iter()
        .enumerate()
        .find_map(|(c, ch)| ch.report.as_ref().filter(|r| r.cancelled).map(|r| (c, r)));
    if let Some((c, r)) = cancelled {
        bail!(
            "solve cancelled (channel {c}) after {} iterations",
            r.iterations
        );
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Each solve announces its phases before its iterations, in order, so that a progress
    /// display has something true to say while an operator is built.
    #[test]
    fn solves_announce_their_phases() {
        use std::sync::Arc;
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("tests/data/cloud24-isotropic/scene.toml");
        let scene = Scene::from_file(&path).unwrap();
        for (method, expected) in [
            (
                SolveMethod::ZonalHierarchical,
                vec![
                    "light pass (24×24×18 cells)",
                    "building the hierarchical form factors (24×24×18 cells)",
                    "iterating (dsa-cg)",
                ],
            ),
            (
                SolveMethod::DiscreteOrdinates,
                vec![
                    "light pass (24×24×18 cells)",
                    "preparing the transport sweeps (24×24×18 cells × 96 bins)",
                    "iterating (gauss-seidel)",
                ],
            ),
            (
                SolveMethod::TwoPass,
                vec!["light pass (24×24×18 cells)", "tracing photons"],
            ),
        ] {
            let mut settings = scene.solve.clone();
            settings.method = method;
            settings.iteration = method.default_iteration();
            settings.max_iterations = 2;
            settings.photons = 1000;
            let phases = Arc::new(std::sync::Mutex::new(Vec::<String>::new()));
            let seen = Arc::clone(&phases);
            let hooks = SolveHooks {
                control: Arc::new(
                    solver::SolveControl::new()
                        .with_phase(move |p| seen.lock().unwrap().push(p.to_string())),
                ),
                memory_limit: None,
                on_prediction: None,
            };
            crate::engine::pipeline::solve_scene(&scene, &settings, &hooks).unwrap();
            assert_eq!(*phases.lock().unwrap(), expected, "{method:?}");
        }
    }

    /// A cancel that landed in a later channel refuses the solution just as one in channel 0.
    #[test]
    fn a_cancelled_channel_refuses_the_solution() {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("tests/data/cloud24-isotropic/scene.toml");
        let scene = Scene::from_file(&path).unwrap();
        let mut settings = scene.solve.clone();
        settings.method = SolveMethod::SingleScatter;
        let mut solution =
            crate::engine::pipeline::solve_scene(&scene, &settings, &SolveHooks::default())
                .unwrap();
        let report = |cancelled| SolveReport {
            method: "jacobi".into(),
            iterations: 3,
            converged: false,
            final_residual: 0.5,
            residual_history: Vec::new(),
            seconds: 0.0,
            seconds_per_iteration: 0.0,
            operator_applications: 3,
            operator_sweeps: 0,
            cancelled,
            stop_reason: if cancelled {
                solver::StopReason::Cancelled
            } else {
                solver::StopReason::MaxIterations
            },
        };
        let mut second = solution.channels[0].clone();
        solution.channels[0].report = Some(report(false));
        second.report = Some(report(true));
        assert!(
            refuse_cancelled(&solution).is_ok(),
            "unconverged is no error"
        );
        solution.channels.push(second);
        let err = refuse_cancelled(&solution).unwrap_err().to_string();
        assert!(
            err.contains("channel 1") && err.contains("3 iterations"),
            "{err}"
        );
    }

    #[test]
    fn iteration_checks_apply_only_to_methods_that_iterate() {
        let mut settings = SolveSettings::default_for(&medium::PhaseFunction::Isotropic);
        settings.iteration = Method::ConjugateGradient;
        for method in [
            SolveMethod::SingleScatter,
            SolveMethod::TwoPass,
            SolveMethod::None,
        ] {
            settings.method = method;
            assert!(check_iteration(&settings).is_ok(), "{method:?}");
        }
        settings.method = SolveMethod::DiscreteOrdinates;
        let err = check_iteration(&settings).unwrap_err().to_string();
        assert!(
            err.contains("cg") && err.contains("discrete-ordinates"),
            "{err}"
        );
    }

    #[test]
    fn transport_refinement_splits_the_grid_not_the_sweep() {
        let iso = PhaseFunction::Isotropic;
        let bins = DirectionBins::cube(4).unwrap();
        let mut settings = SolveSettings::default_for(&iso);
        settings.transport_refinement = scene::TransportRefinement::Fixed(3);
        // The solve is given the split transport grid (tests/it/transport_grid.rs); its sweep
        // has one sub-cell per cell.
        assert_eq!(
            ordinates_options(&settings, &bins, &iso).transport_refinement,
            1
        );
    }

    /// The forward peak is truncated by default only where there is one (HG, g > 0), in one
    /// bin's cone; the scene's cone (0: none) wins.
    #[test]
    fn forward_peak_cone_defaults_to_one_bin_and_the_scene_overrides_it() {
        let hg = PhaseFunction::HenyeyGreenstein { g: 0.85 };
        let back = PhaseFunction::HenyeyGreenstein { g: -0.3 };
        let bins = DirectionBins::cube(4).unwrap();
        let mut settings = SolveSettings::default_for(&hg);
        let cone = |s: &SolveSettings, p: &PhaseFunction| {
            ordinates_options(s, &bins, p).forward_truncation_degrees
        };
        assert!(
            (cone(&settings, &hg) - 11.72).abs() < 0.01,
            "{}",
            cone(&settings, &hg)
        );
        assert_eq!(cone(&settings, &PhaseFunction::Isotropic), 0.0);
        assert_eq!(cone(&settings, &back), 0.0);
        settings.forward_peak_cone = Some(0.0);
        assert_eq!(cone(&settings, &hg), 0.0);
        settings.forward_peak_cone = Some(20.0);
        assert_eq!(cone(&settings, &hg), 20.0);
    }

    /// A medium that does not scatter (albedo 0, an emitter in an absorber) is solved by
    /// every zonal method with its default iteration: the first pass is the answer. (The
    /// default `dsa-cg` of the hierarchical method refused it: its weights need σs > 0.)
    #[test]
    fn a_medium_that_does_not_scatter_is_solved_by_the_zonal_methods() {
        let text = r#"
[volume]
generator = { kind = "cloud", seed = 3 }
dims = [8, 8, 6]

[medium]
albedo = 0.0
emission = 0.2

[[light]]
kind = "directional"
direction = [0.3, -1.0, 0.2]
irradiance = 1.0

[[camera]]
name = "c"
eye = [4.0, 4.0, -20.0]
target = [4.0, 4.0, 3.0]
up = [0.0, 1.0, 0.0]
fov_y = 40.0
width = 8
height = 8
"#;
        let scene =
            Scene::from_toml_str(text, std::path::Path::new("."), std::path::Path::new("a0"))
                .unwrap();
        for method in [SolveMethod::ZonalHierarchical, SolveMethod::Zonal] {
            let mut settings = scene.solve.clone();
            settings.method = method;
            settings.iteration = method.default_iteration();
            let solution =
                crate::engine::pipeline::solve_scene(&scene, &settings, &SolveHooks::default())
                    .unwrap_or_else(|e| panic!("{method}: {e:#}"));
            let ch = &solution.channels[0];
            assert!(ch.report.as_ref().unwrap().converged);
            let ScatteredField::Isotropic {
                source,
                higher_order,
            } = &ch.scattered
            else {
                panic!("{method}: not an isotropic field");
            };
            // g = E = the emission (nothing scatters the light in).
            let emission = &scene.medium.channels()[0].emission;
            for (i, &g) in source.iter().enumerate() {
                let want = emission.get(i);
                assert!((g - want).abs() < 1e-6, "{method}: cell {i}: {g} vs {want}");
            }
            assert!(higher_order.iter().all(|&h| h == 0.0));
        }
    }
}
