//! Orchestration shared by the command line and the service: scene → light pass → operator →
//! solve → [`Solution`]; solution + camera → image.

use std::borrow::Cow;
use std::sync::Arc;

use anyhow::{Context, Result};
use gather::{Camera, Image, InScattering, RenderOptions};
use medium::light_pass::LightPass;
use medium::Medium;
use scene::{CameraSpec, Scene, SceneOrigin, SolveMethod, SolveSettings};

use crate::engine::ground::GroundSetup;
use crate::engine::methods::OutsideLight;
use crate::engine::solution::{ChannelSolution, ScatteredField, Solution};
use crate::engine::SolveHooks;

/// A stable hash of everything that determines a solution (medium, lights, solve settings).
pub fn scene_hash(scene: &Scene) -> String {
    use sha2::{Digest, Sha256};
    let mut h = Sha256::new();
    let cfg = bincode::config::standard();
    let mut feed = |bytes: Vec<u8>| {
        h.update((bytes.len() as u64).to_le_bytes());
        h.update(bytes);
    };
    feed(bincode::serde::encode_to_vec(&scene.medium, cfg).unwrap_or_default());
    feed(bincode::serde::encode_to_vec(&scene.lights, cfg).unwrap_or_default());
    if let Some(env) = &scene.environment {
        feed(format!("environment {env:?}").into_bytes());
    }
    // The solve settings by their scene-file spelling, so the hash depends on what they
    // mean rather than on a derive's byte layout.
    let solve = &scene.solve;
    feed(
        format!(
            "method={} bins={} iteration={} tolerance={:e} max_iterations={} \
             transport_refinement={} photons={} transport_scale={}",
            solve.method,
            solve.bins,
            solve.iteration,
            solve.tolerance,
            solve.max_iterations,
            solve.transport_refinement,
            solve.photons,
            solve.transport_scale
        )
        .into_bytes(),
    );
    feed(scene.background.to_le_bytes().to_vec());
    if let Some(g) = &scene.ground {
        feed(format!("ground {} {:?}", g.height(), g.albedo_rgb()).into_bytes());
    }
    let digest = h.finalize();
    digest.iter().take(16).map(|b| format!("{b:02x}")).collect()
}

fn origin_label(scene: &Scene) -> String {
    match &scene.origin {
        SceneOrigin::File(p) => p.display().to_string(),
        SceneOrigin::BuiltIn(n) => format!("<built-in {n}>"),
    }
}

/// Solves the scene's light transport with `settings` (usually `scene.solve`).
pub fn solve_scene(
    scene: &Scene,
    settings: &SolveSettings,
    hooks: &SolveHooks,
) -> Result<Solution> {
    // Before any light pass or operator: an iteration the method cannot run is refused now.
    crate::engine::methods::check_iteration(settings)?;
    crate::engine::methods::check_environment(scene, settings)?;
    let medium = &scene.medium;
    // Both the memory check and the prediction count the non-empty cells: once.
    let occupancy = (hooks.memory_limit.is_some() || hooks.on_prediction.is_some())
        .then(|| crate::engine::budget::Occupancy::of(medium));
    if let (Some(limit), Some(occupancy)) = (hooks.memory_limit, &occupancy) {
        crate::engine::budget::check_solve_occupied(scene, settings, limit, occupancy)?;
    }
    if let (Some(tell), Some(occupancy)) = (&hooks.on_prediction, &occupancy) {
        let predicted = crate::engine::timing::solve_time_cancellable(
            scene,
            settings,
            occupancy,
            rayon::current_num_threads(),
            &hooks.control,
        );
        tracing::debug!(
            seconds = predicted.total().as_secs_f64(),
            iterations = predicted.iterations(),
            spectral_radius = predicted.spectral_radius(),
            "predicted solve time"
        );
        tell(&predicted);
    }
    // The prediction's probe stops when the solve is cancelled; so does the solve, before it
    // starts.
    if hooks.control.is_cancelled() {
        anyhow::bail!("solve cancelled");
    }
    // Multiple scattering is solved on the transport grid (the data grid itself at scale 1);
    // the light pass stays on the data grid for the render's exact first bounce.
    let transport = crate::engine::budget::transport_grid(scene, settings)?;
    let coarse_medium = if !transport.is_data_grid() {
        tracing::info!(
            scale = transport.scale(),
            split = transport.split_factor(),
            dims = ?transport.transport().dims,
            "solving multiple scattering on a transport grid other than the data's"
        );
        Some(transport.medium(medium)?)
    } else {
        None
    };
    let transport_medium = coarse_medium.as_ref().unwrap_or(medium);
    let environment = scene.environment.as_ref();
    let ground_setup = if scene.ground.is_some() {
        hooks.control.phase("the ground's unscattered light");
        GroundSetup::new(scene)?
    } else {
        None
    };
    let mut ground_radiance = Vec::new();
    let mut channels = Vec::with_capacity(medium.channels().len());
    for c in 0..medium.channels().len() {
        let span = tracing::info_span!("channel", c);
        let _enter = span.enter();
        hooks.control.phase(&channel_phase(
            &format!(
                "light pass ({})",
                crate::engine::methods::grid_text(medium.grid())
            ),
            c,
            medium.channels().len(),
        ));
        let light_pass = LightPass::compute(medium, c, &scene.lights)
            .with_context(|| format!("light pass of channel {c}"))?;
        let coarse_pass = match &coarse_medium {
            Some(coarse) => Some(transport.light_pass(medium, c, &light_pass, coarse)?),
            None => None,
        };
        let transport_pass = coarse_pass.as_ref().unwrap_or(&light_pass);
        let emitters = crate::engine::methods::emitter_pass(transport_medium, c, settings, hooks)?;
        let ground = ground_setup.as_ref().map(|g| g.channel(c));
        let (scattered, report, ground_solved) = match settings.method {
            SolveMethod::None | SolveMethod::SingleScatter => (
                ScatteredField::None,
                None,
                ground.as_ref().map(|g| g.radiance(None)),
            ),
            SolveMethod::Zonal | SolveMethod::ZonalHierarchical => {
                crate::engine::methods::solve_zonal(
                    transport_medium,
                    OutsideLight {
                        environment,
                        ground: ground.as_ref(),
                    },
                    c,
                    transport_pass,
                    emitters.as_ref(),
                    settings,
                    hooks,
                )?
            }
            SolveMethod::DiscreteOrdinates => crate::engine::methods::solve_ordinates(
                transport_medium,
                OutsideLight {
                    environment,
                    ground: ground.as_ref(),
                },
                c,
                transport_pass,
                emitters.as_ref(),
                settings,
                hooks,
            )?,
            SolveMethod::TwoPass => {
                crate::engine::methods::solve_two_pass(scene, ground.as_ref(), c, settings, hooks)?
            }
        };
        ground_radiance.extend(ground_solved);
        channels.push(ChannelSolution {
            light_pass,
            scattered,
            report,
            emitted_fluence: emitters
                .as_ref()
                .map(|e| e.fluence().iter().map(|&v| v as f32).collect()),
            emitted_beam: emitters
                .as_ref()
                .filter(|_| settings.method == SolveMethod::DiscreteOrdinates)
                .map(|e| crate::engine::methods::emitter_beam(transport_medium, c, e))
                .transpose()?,
            render_cache: Default::default(),
        });
    }
    Ok(Solution {
        scene_hash: scene_hash(scene),
        scene_origin: origin_label(scene),
        method: settings.method,
        medium: scene.medium.clone(),
        lights: scene.lights.clone(),
        environment: scene.environment.clone(),
        background: scene.background,
        ground: match &ground_setup {
            Some(setup) => Some(Arc::new(setup.finish(ground_radiance)?)),
            None => None,
        },
        render: scene.render.clone(),
        cameras: scene.cameras.clone(),
        bins: crate::engine::methods::stored_bins(settings, transport_medium),
        transport,
        channels,
    })
}

/// `what` of channel `c`, naming the channel only when there are several.
pub fn channel_phase(what: &str, c: usize, channels: usize) -> String {
    if channels > 1 {
        format!("{what} (channel {} of {channels})", c + 1)
    } else {
        what.to_string()
    }
}

/// Renders one view of a solution.
pub fn render_view(solution: &Solution, camera: &CameraSpec, spp: Option<u32>) -> Result<Image> {
    render_view_scaled(solution, camera, spp, None)
}

/// Renders one view of a solution, with σt along the view rays multiplied by
/// `extinction_scale` when given (Blasi & Wuethrich §4.3's separate render-time absorption;
/// the solved sources and the first bounce keep the solved medium). For several views with one
/// scale, build the medium once with [`view_medium`] and render each with
/// [`render_view_through`].
pub fn render_view_scaled(
    solution: &Solution,
    camera: &CameraSpec,
    spp: Option<u32>,
    extinction_scale: Option<f32>,
) -> Result<Image> {
    let medium = view_medium(solution, extinction_scale)?;
    render_view_through(solution, &medium, camera, spp)
}

/// The medium view rays pass through: the solved one, or a copy with σt multiplied by
/// `extinction_scale` (a whole-grid copy, so callers rendering many views build it once).
pub fn view_medium(solution: &Solution, extinction_scale: Option<f32>) -> Result<Cow<'_, Medium>> {
    match extinction_scale {
        None => Ok(Cow::Borrowed(&solution.medium)),
        Some(scale) => montecarlo::with_extinction_scale(&solution.medium, scale)
            .map(Cow::Owned)
            .map_err(|e| anyhow::anyhow!("--extinction-scale: {e}")),
    }
}

/// Renders one view of a solution with the view rays passing through `view_medium` (from
/// [`view_medium`]: the solved medium or a rescaled copy; the solved sources and the first
/// bounce keep the solved medium). It must share the solution's grid and channels.
pub fn render_view_through(
    solution: &Solution,
    view_medium: &Medium,
    camera: &CameraSpec,
    spp: Option<u32>,
) -> Result<Image> {
    // The sources index cells of the solution's grid: another grid would read the wrong cells.
    if view_medium.grid() != solution.medium.grid()
        || view_medium.channels().len() != solution.medium.channels().len()
    {
        anyhow::bail!(
            "the view medium ({:?} cells, {} channels) does not match the solution's ({:?} cells, {} channels)",
            view_medium.grid().dims,
            view_medium.channels().len(),
            solution.medium.grid().dims,
            solution.medium.channels().len()
        );
    }
    let camera = Camera::from_spec(camera)?;
    let view = crate::engine::sources::Viewpoint::of_camera(&camera);
    // The solution's caches, built together on a first view (at once after that); a
    // rescaled view medium gets its own render index below.
    if std::ptr::eq(view_medium, &solution.medium) {
        solution.prepare_renders();
    }
    let mut options = RenderOptions::from_settings(&solution.render, solution.background);
    options.environment = solution.environment.clone();
    options.ground = solution.ground.clone();
    if let Some(spp) = spp {
        options.spp = spp;
    }
    let sources = solution
        .channels
        .iter()
        .enumerate()
        .map(|(c, ch)| {
            crate::engine::sources::channel_scattering(solution, c, ch, options.model, view)
        })
        .collect::<Result<Vec<Box<dyn InScattering + '_>>>>()?;
    let refs: Vec<&dyn InScattering> = sources.iter().map(|b| b.as_ref()).collect();
    // The solved medium's render indices are kept with the solution; a rescaled view medium
    // gets its own for this render.
    if !std::ptr::eq(view_medium, &solution.medium) {
        return Ok(gather::render_image(view_medium, &camera, &options, &refs)?);
    }
    let indices = solution
        .channels
        .iter()
        .enumerate()
        .map(|(c, ch)| {
            ch.render_cache
                .render_index(&solution.medium, c, options.model)
        })
        .collect::<Result<Vec<_>>>()?;
    Ok(gather::render_image_indexed(
        view_medium,
        &camera,
        &options,
        &refs,
        &indices,
    )?)
}
