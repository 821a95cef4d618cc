//! The unbiased volumetric path tracer: the ground truth volrad's deterministic methods are
//! checked against.
//!
//! - Free paths are sampled exactly cell by cell ([`crate::flight`]), not by Woodcock
//!   tracking: with `nearest` data σt is piecewise constant, so the analytic per-cell
//!   inversion is exact and needs no majorant or null collisions. (`trilinear` media are
//!   traced as their piecewise-constant `nearest` version, the medium the solvers use.)
//! - At every scattering vertex, next-event estimation toward each light: a shadow ray with
//!   the exact per-cell optical depth ([`medium::Grid::optical_depth`]) to the grid's edge
//!   (directional) or to the light (point, spot: `1/r²` and the cone from
//!   [`Light::arriving_at`]). Lights are deltas, so NEE is their only path: no double counting.
//! - Emission `e` is collected along every flight by the track-length estimator `∫ e ds` up
//!   to the collision (unbiased for `∫ T e ds`, and valid where σt = 0).
//! - Absorption by weight: the throughput is multiplied by the albedo at each collision and
//!   the new direction is drawn from the phase function (exact importance sampling, weight 1).
//! - Unlimited depth with Russian roulette from `rr_start_depth` (survival probability equal
//!   to the throughput, at most 1; pbrt's rule), or a hard `max_depth` (number of scattering
//!   events counted: `Some(1)` is single scattering).
//! - Paths that leave the grid add what they meet there ([`Surroundings`]) times their
//!   throughput: the environment light along the path's direction (none by default), or,
//!   without one, the background `I0` for camera rays that never scattered. The
//!   environment is not importance-sampled: it is smooth, and escaping paths find it.
//! - A ground ([`Surroundings::ground`]) is met by paths that leave the grid going down: a
//!   Lambertian bounce (the throughput times the albedo), next-event estimation toward each
//!   light from the hit point (`E cos θ T / π`), and a cosine-distributed new direction up.
//!   Below a ground no environment is seen.
//!
//! Each pixel is the mean of `spp` paths through uniformly jittered positions in its area, on
//! its own PCG stream seeded from `(seed, pixel index)`: deterministic for a seed, whatever the
//! thread count. Rows are rendered in parallel.

use gather::{Camera, Image, ImageChannel};
use glam::DVec3;
use medium::ground::{cosine_direction, light_irradiance, Ground};
use medium::traversal::Ray;
use medium::{CellValues, Environment, Grid, Light, Medium, PhaseFunction};
use rand::Rng;
use rayon::prelude::*;

use crate::flight::{fly, transmittance, Flight};
use crate::{rng, MonteCarloError};

/// How to path trace.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PathTraceOptions {
    /// Paths per pixel (at least 1; at least 2 for a standard error).
    pub spp: u32,
    /// Seed of every random stream.
    pub seed: u64,
    /// Largest number of scattering events per path; `None`: unlimited (Russian roulette).
    pub max_depth: Option<u32>,
    /// Russian roulette starts after this many scattering events.
    pub rr_start_depth: u32,
    /// Next-event estimation toward the emitting cells: after each collision two or more
    /// cells from every emitter, one point of an emitting cell (chosen by its power) is
    /// connected to it, and the next flight's emission is not counted. Without it a path
    /// meets a small emitter's light only when one of its flights crosses the emitter, and
    /// pixels lit by that light after scattering have standard errors of 30–100 % at
    /// hundreds of paths. Collisions next to an emitter keep the flight's emission (there
    /// the connection's `1/r²` would have unbounded variance).
    pub emitter_sampling: bool,
}

impl Default for PathTraceOptions {
    fn default() -> Self {
        PathTraceOptions {
            spp: 64,
            seed: 0,
            max_depth: None,
            rr_start_depth: 3,
            emitter_sampling: false,
        }
    }
}

/// A path-traced channel with the standard error of each pixel's mean.
#[derive(Clone, Debug, PartialEq)]
pub struct PathTraced {
    /// Mean radiance per pixel.
    pub mean: ImageChannel,
    /// Standard error of each pixel's mean, from the per-pixel sample variance
    /// (`sqrt(s² / spp)`); infinite when `spp` is 1.
    pub std_error: ImageChannel,
    /// Paths traced (`width · height · spp`).
    pub paths: u64,
}

/// Traces paths through one channel of a medium. Built once per render; `radiance` does not
/// allocate.
#[derive(Clone, Debug)]
pub struct PathTracer<'a> {
    grid: Grid,
    sigma_t: &'a [f32],
    albedo: &'a CellValues,
    emission: Option<&'a CellValues>,
    phase: PhaseFunction,
    lights: &'a [Light],
    surroundings: Surroundings,
    /// This channel and the medium's channel count (the environment's colour).
    channel: (usize, usize),
    max_depth: u32,
    rr_start_depth: u32,
    emitters: Option<EmitterSampler>,
}

/// The emitting cells of a channel, for next-event estimation
/// ([`PathTraceOptions::emitter_sampling`]).
#[derive(Clone, Debug)]
struct EmitterSampler {
    cells: Vec<u32>,
    /// Cumulative share of the emitted power, per entry of `cells`.
    cumulative: Vec<f64>,
    /// `Σ e V` over the grid.
    power: f64,
    /// Cells within one cell (Chebyshev) of an emitting cell: no connection from there.
    near: Vec<bool>,
}

impl EmitterSampler {
    fn new(grid: &Grid, emission: &CellValues) -> Option<EmitterSampler> {
        let n = grid.cell_count();
        let cells: Vec<u32> = (0..n as u32)
            .filter(|&c| emission.get(c as usize) > 0.0)
            .collect();
        if cells.is_empty() {
            return None;
        }
        let volume = grid.cell_volume();
        let mut cumulative = Vec::with_capacity(cells.len());
        let mut power = 0.0;
        for &c in &cells {
            power += emission.get(c as usize) as f64 * volume;
            cumulative.push(power);
        }
        cumulative.iter_mut().for_each(|v| *v /= power);
        Some(EmitterSampler {
            near: medium::emitter_pass::near_emitting_cells(grid, &cells),
            cells,
            cumulative,
            power,
        })
    }
}

/// What a path meets where it leaves the grid.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Surroundings {
    /// Radiance `I0` a camera ray sees where it leaves the grid without scattering, when
    /// there is no environment.
    pub background: f64,
    /// Light from every direction at infinity, picked up by every path that leaves (camera
    /// rays see it as the background).
    pub environment: Option<Environment>,
    /// A Lambertian plane under the grid that paths going down bounce off.
    pub ground: Option<Ground>,
}

impl Surroundings {
    /// A background seen by camera rays and nothing lighting the medium from outside.
    pub fn background(background: f64) -> Self {
        Surroundings {
            background,
            environment: None,
            ground: None,
        }
    }
}

impl From<f64> for Surroundings {
    fn from(background: f64) -> Self {
        Surroundings::background(background)
    }
}

fn check_lights(lights: &[Light]) -> Result<(), MonteCarloError> {
    for (index, light) in lights.iter().enumerate() {
        light.validated().map_err(|e| MonteCarloError::Light {
            index,
            message: e.to_string(),
        })?;
    }
    Ok(())
}

impl<'a> PathTracer<'a> {
    pub fn new(
        medium: &'a Medium,
        channel: usize,
        lights: &'a [Light],
        surroundings: impl Into<Surroundings>,
        options: &PathTraceOptions,
    ) -> Result<Self, MonteCarloError> {
        let surroundings = surroundings.into();
        let background = surroundings.background;
        let ch = medium
            .channels()
            .get(channel)
            .ok_or(MonteCarloError::Channel {
                channel,
                channels: medium.channels().len(),
            })?;
        if options.spp == 0 {
            return Err(MonteCarloError::Options("spp must be at least 1".into()));
        }
        if !(background.is_finite() && background >= 0.0) {
            return Err(MonteCarloError::Options(format!(
                "background radiance {background} must be finite and ≥ 0"
            )));
        }
        check_lights(lights)?;
        Ok(PathTracer {
            grid: *medium.grid(),
            sigma_t: &ch.sigma_t,
            albedo: &ch.albedo,
            emission: (!ch.emission.is_zero()).then_some(&ch.emission),
            phase: medium.phase(),
            lights,
            surroundings,
            channel: (channel, medium.channels().len()),
            max_depth: options.max_depth.unwrap_or(u32::MAX),
            rr_start_depth: options.rr_start_depth,
            emitters: options
                .emitter_sampling
                .then(|| EmitterSampler::new(medium.grid(), &ch.emission))
                .flatten(),
        })
    }

    /// Radiance in-scattered toward `-travel` at `x` from the lights (NEE), per unit of
    /// (collision-weighted) throughput: `Σ_L E_L T_L p(ω_L · (−travel))`.
    #[inline]
    fn direct(&self, x: DVec3, travel: DVec3) -> f64 {
        let mut sum = 0.0;
        for light in self.lights {
            let (flow, irradiance) = light.arriving_at(x);
            if irradiance <= 0.0 {
                continue;
            }
            let t_max = match *light {
                Light::Directional { .. } => f64::INFINITY,
                Light::Point { position, .. } | Light::Spot { position, .. } => {
                    (position - x).length()
                }
            };
            let phase = self.phase.eval(-flow.dot(travel));
            if phase <= 0.0 {
                continue;
            }
            let shadow = Ray {
                origin: x,
                direction: -flow,
            };
            sum += irradiance * phase * transmittance(&self.grid, self.sigma_t, &shadow, t_max);
        }
        sum
    }

    /// Radiance in-scattered toward `-travel` at `x` from the emitting cells, one point of
    /// one cell chosen by its power (NEE): `P p(ω · (−travel)) T / r²`, `P = Σ e V`, `ω` the
    /// direction from the point to `x` and `r` its distance.
    fn emitted_toward<R: Rng + ?Sized>(
        &self,
        sampler: &EmitterSampler,
        x: DVec3,
        travel: DVec3,
        rng: &mut R,
    ) -> f64 {
        let u: f64 = rng.random();
        let k = sampler
            .cumulative
            .partition_point(|&c| c < u)
            .min(sampler.cells.len() - 1);
        let corner = self.grid.cell_min(sampler.cells[k] as usize);
        let y = corner + DVec3::new(rng.random(), rng.random(), rng.random()) * self.grid.cell_size;
        let to_x = x - y;
        let r = to_x.length();
        if r <= 0.0 {
            return 0.0;
        }
        let flow = to_x / r;
        let phase = self.phase.eval(-flow.dot(travel));
        if phase <= 0.0 {
            return 0.0;
        }
        let shadow = Ray {
            origin: x,
            direction: -flow,
        };
        sampler.power * phase * transmittance(&self.grid, self.sigma_t, &shadow, r) / (r * r)
    }

    /// Radiance a Lambertian ground of albedo 1 at `x` reflects from the lights (NEE):
    /// `Σ_L E_L cos θ_L T_L / π`.
    #[inline]
    fn direct_on_ground(&self, x: DVec3) -> f64 {
        light_irradiance(x, self.lights, Some((&self.grid, self.sigma_t))) / std::f64::consts::PI
    }

    /// Russian roulette after `depth` events (pbrt's rule: survival probability the
    /// throughput, at least 5 %): the surviving path's throughput, or `None` when it ends.
    #[inline]
    fn roulette<R: Rng + ?Sized>(&self, depth: u32, throughput: f64, rng: &mut R) -> Option<f64> {
        if depth < self.rr_start_depth || throughput >= 1.0 {
            return Some(throughput);
        }
        let q = (1.0 - throughput).max(0.05);
        (rng.random::<f64>() >= q).then(|| throughput / (1.0 - q))
    }

    /// One path's estimate of the radiance arriving at `ray.origin` from `−ray.direction`
    /// (the medium behind the origin is not seen).
    pub fn radiance<R: Rng + ?Sized>(&self, ray: &Ray, rng: &mut R) -> f64 {
        let mut ray = *ray;
        let mut throughput = 1.0f64;
        let mut radiance = 0.0f64;
        let mut depth = 0u32;
        // False after a collision connected to the emitters: its next flight's emission was
        // counted by the connection.
        let mut count_emission = true;
        loop {
            // 1 − u ∈ (0, 1]: the target depth is finite.
            let target = -(1.0 - rng.random::<f64>()).ln();
            let (flight, emitted) = fly(
                &self.grid,
                self.sigma_t,
                self.emission,
                &ray,
                f64::INFINITY,
                target,
            );
            if count_emission {
                radiance += throughput * emitted;
            }
            count_emission = true;
            let (t, cell) = match flight {
                Flight::Escaped => {
                    let hit = self.surroundings.ground.as_ref().and_then(|g| {
                        let t = g.hit(ray.origin, ray.direction)?;
                        Some((g.albedo(self.channel.0, self.channel.1), ray.at(t)))
                    });
                    if let Some((albedo, x)) = hit {
                        depth += 1;
                        if depth > self.max_depth || albedo <= 0.0 {
                            break;
                        }
                        throughput *= albedo;
                        radiance += throughput * self.direct_on_ground(x);
                        let Some(t) = self.roulette(depth, throughput, rng) else {
                            break;
                        };
                        throughput = t;
                        // The Lambertian BRDF's sampling.
                        ray = Ray {
                            origin: x,
                            direction: cosine_direction(rng.random(), rng.random()),
                        };
                        continue;
                    }
                    radiance += throughput
                        * match (depth, &self.surroundings.environment) {
                            (0, None) => self.surroundings.background,
                            (_, Some(env)) => {
                                // The light it meets travels back along the path.
                                env.radiance_along(-ray.direction, self.channel.0, self.channel.1)
                            }
                            (_, None) => 0.0,
                        };
                    break;
                }
                Flight::Collision { t, cell } => (t, cell),
            };
            depth += 1;
            if depth > self.max_depth {
                break;
            }
            let albedo = self.albedo.get(cell) as f64;
            if albedo <= 0.0 {
                break;
            }
            throughput *= albedo;
            let x = ray.at(t);
            if !self.lights.is_empty() {
                radiance += throughput * self.direct(x, ray.direction);
            }
            if let Some(sampler) = self.emitters.as_ref().filter(|e| !e.near[cell]) {
                radiance += throughput * self.emitted_toward(sampler, x, ray.direction, rng);
                count_emission = false;
            }
            let Some(t) = self.roulette(depth, throughput, rng) else {
                break;
            };
            throughput = t;
            ray = Ray {
                origin: x,
                direction: self.phase.sample(ray.direction, rng),
            };
        }
        radiance
    }
}

/// Renders one channel: mean radiance per pixel (see [`path_trace_with_error`]).
pub fn path_trace(
    medium: &Medium,
    channel: usize,
    lights: &[Light],
    surroundings: impl Into<Surroundings>,
    camera: &Camera,
    options: &PathTraceOptions,
) -> Result<ImageChannel, MonteCarloError> {
    Ok(path_trace_with_error(medium, channel, lights, surroundings, camera, options)?.mean)
}

/// Renders one channel with the standard error of every pixel. Pixel `(x, y)` uses the
/// stream `(seed, y · width + x)`, so the image is the same for any thread count.
pub fn path_trace_with_error(
    medium: &Medium,
    channel: usize,
    lights: &[Light],
    surroundings: impl Into<Surroundings>,
    camera: &Camera,
    options: &PathTraceOptions,
) -> Result<PathTraced, MonteCarloError> {
    path_trace_rows(
        medium,
        channel,
        lights,
        surroundings.into(),
        camera,
        options,
        &|_| true,
    )
}

/// Rows finished so far, for progress; return `false` to stop (the render then fails with
/// [`MonteCarloError::Cancelled`]). Called from the worker threads, once per finished row.
pub type RowProgress<'a> = dyn Fn(u64) -> bool + Sync + 'a;

fn path_trace_rows(
    medium: &Medium,
    channel: usize,
    lights: &[Light],
    surroundings: impl Into<Surroundings>,
    camera: &Camera,
    options: &PathTraceOptions,
    progress: &RowProgress<'_>,
) -> Result<PathTraced, MonteCarloError> {
    use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
    let tracer = PathTracer::new(medium, channel, lights, surroundings, options)?;
    let rows_done = AtomicU64::new(0);
    let stopped = AtomicBool::new(false);
    let (width, height) = (camera.width as usize, camera.height as usize);
    let spp = options.spp as usize;
    let mut mean = vec![0.0f32; width * height];
    let mut std_error = vec![0.0f32; width * height];
    mean.par_chunks_mut(width)
        .zip(std_error.par_chunks_mut(width))
        .enumerate()
        .for_each(|(y, (mean_row, se_row))| {
            if stopped.load(Ordering::Relaxed) {
                return;
            }
            for x in 0..width {
                let pixel = (y * width + x) as u64;
                let mut rng = rng::stream(options.seed, 0, pixel);
                // Welford's running mean and sum of squared deviations.
                let (mut m, mut m2) = (0.0f64, 0.0f64);
                for n in 1..=spp {
                    let px = x as f64 + rng.random::<f64>();
                    let py = y as f64 + rng.random::<f64>();
                    let value = tracer.radiance(&camera.ray(px, py), &mut rng);
                    let delta = value - m;
                    m += delta / n as f64;
                    m2 += delta * (value - m);
                }
                mean_row[x] = m as f32;
                se_row[x] = if spp > 1 {
                    (m2 / ((spp - 1) * spp) as f64).sqrt() as f32
                } else {
                    f32::INFINITY
                };
            }
            if !progress(rows_done.fetch_add(1, Ordering::Relaxed) + 1) {
                stopped.store(true, Ordering::Relaxed);
            }
        });
    if stopped.load(Ordering::Relaxed) {
        return Err(MonteCarloError::Cancelled);
    }
    let channel_image = |pixels| ImageChannel {
        width: camera.width,
        height: camera.height,
        pixels,
    };
    Ok(PathTraced {
        mean: channel_image(mean),
        std_error: channel_image(std_error),
        paths: (width * height * spp) as u64,
    })
}

/// Renders every channel of `medium` into an [`Image`] (1 or 3 interleaved channels). All
/// channels share the pixel streams (common random numbers keep colour noise neutral).
pub fn path_trace_image(
    medium: &Medium,
    lights: &[Light],
    surroundings: impl Into<Surroundings>,
    camera: &Camera,
    options: &PathTraceOptions,
) -> Result<Image, MonteCarloError> {
    path_trace_image_with_progress(medium, lights, surroundings, camera, options, &|_| true)
}

/// [`path_trace_image`] reporting the rows finished over all channels (of
/// `channels × height`) as it goes; the callback's `false` cancels.
pub fn path_trace_image_with_progress(
    medium: &Medium,
    lights: &[Light],
    surroundings: impl Into<Surroundings>,
    camera: &Camera,
    options: &PathTraceOptions,
    progress: &RowProgress<'_>,
) -> Result<Image, MonteCarloError> {
    let surroundings = surroundings.into();
    let n = medium.channels().len();
    let mut pixels = vec![0.0f32; camera.width as usize * camera.height as usize * n];
    for c in 0..n {
        let before = c as u64 * camera.height as u64;
        let ch = path_trace_rows(
            medium,
            c,
            lights,
            surroundings.clone(),
            camera,
            options,
            &|rows| progress(before + rows),
        )?
        .mean;
        for (i, &v) in ch.pixels.iter().enumerate() {
            pixels[i * n + c] = v;
        }
    }
    Ok(Image::new(camera.width, camera.height, n as u32, pixels)?)
}
