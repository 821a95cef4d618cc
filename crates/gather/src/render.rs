//! The renderer: front-to-back integration of `dI/ds = Q − σt I` along camera rays.
//!
//! `nearest` media are piecewise constant per cell, so each cell a ray crosses (found by the
//! exact DDA of [`Grid::traverse`]) contributes the analytic segment integral of physics.md:
//! `ΔI = T · Q · (1 − e^{−σt Δs}) / σt`, then `T ← T · e^{−σt Δs}`. `trilinear` media are
//! marched in fixed steps (half a cell by default; a step that may be optically thick is
//! split into pieces of optical depth ≤ `MAX_PIECE_DEPTH`) of the trilinearly interpolated σt
//! and emission, each integrated with the same formula at its midpoint values. In thin
//! medium (σt bounded near them) two steps are one piece, and two consecutive such pieces are
//! handed to the sources together ([`InScattering::at_step_pair`]), which may share what is
//! the same at both. The background adds `T · I0` at the end.
//!
//! Early termination: a ray stops once the rest of it cannot change the pixel by more than
//! `termination` (default 1e-4) relative to what it has gathered, i.e. when
//! `T · R ≤ termination · I`. `R` bounds what the rest of the ray can still add per unit of
//! transmittance: `I0 + min(e_max · L, max(e/σt)) + Q_s,max · L`, with `L` the chord still
//! inside the occupied part of the grid. (`∫ T e ds ≤ max(e/σt) ∫ T σt ds ≤ max(e/σt)`, so for
//! the particle model, e = Cσt, the rule is just `T · (I0 + C) ≤ 10⁻⁴ I`.) When the scattered
//! source has no known bound, the rule falls back to `T < termination`.

use glam::DVec3;
use medium::grid::{clamped_floor, Grid};
use medium::ground::GroundRadiance;
use medium::traversal::Ray;
use medium::{CellValues, Environment, Interpolation, Medium};
use std::borrow::Cow;
use std::sync::Arc;

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::empty_space::EmptySpace;
use crate::extinction_bound::ExtinctionBound;
use crate::image_io::Image;
use crate::scattering::{
    weight_and_attenuation_with, InScattering, RayCarry, StepSample, ViewSegment,
};
use crate::{Camera, GatherError};

/// Width of the blocks a task's band of rows is walked in, so that neighbouring rays (which
/// cross the same cells) run together.
pub const TILE: usize = 16;

/// Rows per parallel task: small enough that the tasks of a frame whose cost is concentrated
/// in a few rows (a cloud in mid-frame) still spread evenly over the threads.
const BAND_ROWS: usize = 4;

/// Which of Max's optical models a render uses.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum OpticalModel {
    /// `Q = 0`: the image is `I0 · T` (X-ray).
    AbsorptionOnly,
    /// `σt = 0` in the integral: emission adds up without attenuation (Max eq. 5).
    EmissionOnly,
    /// Max eq. 7 (the particle model of eq. 8 is emission = C·σt with this model).
    EmissionAbsorption,
    /// Single scattering with `T_L ≡ 1` ("Utah", no shadows), plus emission.
    SingleScatterUnshadowed,
    /// Emission plus scattered light: shadowed single scattering, and multiple scattering
    /// when a solution is given.
    Scattering,
}

/// Names of `[render] model`, in the scene's spelling.
pub const OPTICAL_MODEL_NAMES: [&str; 5] = [
    "absorption-only",
    "emission-only",
    "emission-absorption",
    "single-scatter-unshadowed",
    "scattering",
];

impl OpticalModel {
    pub fn parse(name: &str) -> Option<OpticalModel> {
        Some(match name {
            "absorption-only" => OpticalModel::AbsorptionOnly,
            "emission-only" => OpticalModel::EmissionOnly,
            "emission-absorption" => OpticalModel::EmissionAbsorption,
            "single-scatter-unshadowed" => OpticalModel::SingleScatterUnshadowed,
            "scattering" => OpticalModel::Scattering,
            _ => return None,
        })
    }

    pub fn name(self) -> &'static str {
        match self {
            OpticalModel::AbsorptionOnly => "absorption-only",
            OpticalModel::EmissionOnly => "emission-only",
            OpticalModel::EmissionAbsorption => "emission-absorption",
            OpticalModel::SingleScatterUnshadowed => "single-scatter-unshadowed",
            OpticalModel::Scattering => "scattering",
        }
    }
}

/// A scene's `[render]` section: the optical model, the PNG exposure and samples per pixel.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RenderSettings {
    pub model: OpticalModel,
    /// PNG exposure: pixel value = 1 − exp(−exposure · radiance), then sRGB. `None`:
    /// automatic, per picture ([`auto_exposure`](crate::exposure::auto_exposure)).
    pub exposure: Option<f64>,
    /// Stratified samples per pixel.
    pub spp: u32,
}

/// Most samples per pixel a render takes: each is a full ray; beyond this the image costs
/// hours without a visible change (a typo like `spp = 1000000` is refused, not run).
pub const MAX_SPP: u32 = 4096;

/// What to render and how.
#[derive(Clone, Debug, PartialEq)]
pub struct RenderOptions {
    /// Which of Max's optical models.
    pub model: OpticalModel,
    /// Samples per pixel, stratified over the pixel's area (1: the pixel centre).
    pub spp: u32,
    /// Background radiance `I0` seen through the volume.
    pub background: f64,
    /// An environment seen through the volume instead of `background`, by direction (a sky).
    pub environment: Option<Environment>,
    /// The ground and the light it reflects, seen by rays going down (instead of the
    /// environment or the background below it).
    pub ground: Option<Arc<GroundRadiance>>,
    /// Step of the `trilinear` march as a fraction of the cell size (steps that may be
    /// optically thick are split further; two steps whose neighbourhood is thin, optical
    /// depth ≤ 0.1 together by the largest σt near them, are taken as one). Half a cell by
    /// default: images of the sample scenes differ from an eighth of a cell's by ≤ 0.14 %
    /// RMS (docs/performance.md).
    pub trilinear_step: f64,
    /// Relative early-termination tolerance (see the module docs); 0 disables it.
    pub termination: f64,
}

impl Default for RenderOptions {
    fn default() -> Self {
        RenderOptions {
            model: OpticalModel::EmissionAbsorption,
            spp: 1,
            background: 0.0,
            environment: None,
            ground: None,
            trilinear_step: 0.5,
            termination: 1e-4,
        }
    }
}

impl RenderOptions {
    /// The model and spp of a scene's `[render]` section over the given background;
    /// defaults for the rest.
    pub fn from_settings(render: &RenderSettings, background: f64) -> Self {
        RenderOptions {
            model: render.model,
            spp: render.spp,
            background,
            ..RenderOptions::default()
        }
    }

    fn validate(&self) -> Result<(), GatherError> {
        let bad = |m: String| Err(GatherError::Render(m));
        if !(1..=MAX_SPP).contains(&self.spp) {
            return bad(format!("spp {} must be from 1 to {MAX_SPP}", self.spp));
        }
        if !(self.background.is_finite() && self.background >= 0.0) {
            return bad(format!(
                "background radiance {} must be finite and ≥ 0",
                self.background
            ));
        }
        if !(self.trilinear_step.is_finite() && self.trilinear_step > 0.0) {
            return bad(format!(
                "trilinear step {} must be a positive fraction of the cell size",
                self.trilinear_step
            ));
        }
        if !(self.termination >= 0.0 && self.termination < 1.0) {
            return bad(format!(
                "termination tolerance {} must lie in [0, 1)",
                self.termination
            ));
        }
        Ok(())
    }

    /// The stratification `sx × sy = spp` of a pixel: the most square factorisation, wider
    /// than tall (a prime spp gives `spp × 1` strips).
    // `is_multiple_of` needs Rust 1.87; the workspace supports 1.80.
    #[allow(clippy::manual_is_multiple_of)]
    pub fn strata(&self) -> (u32, u32) {
        let n = self.spp.max(1);
        let mut sy = (n as f64).sqrt() as u32;
        while sy > 1 && n % sy != 0 {
            sy -= 1;
        }
        (n / sy, sy)
    }
}

/// One rendered colour channel: radiance per pixel, row-major, top row first.
#[derive(Clone, Debug, PartialEq)]
pub struct ImageChannel {
    pub width: u32,
    pub height: u32,
    pub pixels: Vec<f32>,
}

impl ImageChannel {
    #[inline]
    pub fn get(&self, x: u32, y: u32) -> f32 {
        self.pixels[(y * self.width + x) as usize]
    }
}

/// Integrates radiance along single rays through one channel of a medium. Built once per
/// render (it precomputes the source bound); `radiance` is allocation-free.
pub struct RayIntegrator<'a> {
    grid: Grid,
    sigma_t: &'a [f32],
    emission: &'a CellValues,
    scattering: &'a dyn InScattering,
    interpolation: Interpolation,
    use_sigma: bool,
    use_emission: bool,
    use_scattering: bool,
    /// `I0`, or with an environment the most it sends in this channel (the termination bound).
    background: f64,
    /// The environment seen where rays leave, with this channel and the medium's count.
    environment: Option<(Environment, usize, usize)>,
    /// The ground, seen by rays going down, and this channel.
    ground: Option<(Arc<GroundRadiance>, usize)>,
    /// The most the ground sends in this channel (with `background`, the termination bound).
    ground_max: f64,
    /// Upper bound on the scattered source (0 when unused; infinite if unknown).
    scattering_max: f64,
    /// Copied from the index for the per-segment termination test.
    emission_max: f64,
    emission_ratio_max: f64,
    /// What the render derives from the medium alone (built here, or shared by the caller).
    index: Cow<'a, RenderIndex>,
    termination: f64,
    step: f64,
    /// The CPU has FMA: rays run [`RayIntegrator::radiance_nearest_fma`] and
    /// [`RayIntegrator::radiance_trilinear_fma`].
    fma: bool,
}

impl<'a> RayIntegrator<'a> {
    /// `scattering` is used only by the scattering models; the others ignore it.
    pub fn new(
        medium: &'a Medium,
        channel: usize,
        options: &RenderOptions,
        scattering: &'a dyn InScattering,
    ) -> Result<Self, GatherError> {
        options.validate()?;
        let index = RenderIndex::new(medium, channel, options.model)?;
        Self::build(medium, options, scattering, Cow::Owned(index))
    }

    /// As [`RayIntegrator::new`] with the index built once for this medium, channel and
    /// `options.model` (refused if it was built for another grid, channel, model or
    /// interpolation).
    pub fn with_index(
        medium: &'a Medium,
        options: &RenderOptions,
        scattering: &'a dyn InScattering,
        index: &'a RenderIndex,
    ) -> Result<Self, GatherError> {
        options.validate()?;
        index.check(medium, options.model)?;
        Self::build(medium, options, scattering, Cow::Borrowed(index))
    }

    fn build(
        medium: &'a Medium,
        options: &RenderOptions,
        scattering: &'a dyn InScattering,
        index: Cow<'a, RenderIndex>,
    ) -> Result<Self, GatherError> {
        if let Some(g) = &options.ground {
            if g.channels() != medium.channels().len() {
                return Err(GatherError::Render(format!(
                    "the ground's light has {} channels, the medium {}",
                    g.channels(),
                    medium.channels().len()
                )));
            }
        }
        let ch = &medium.channels()[index.channel];
        use OpticalModel::*;
        let use_scattering =
            matches!(options.model, SingleScatterUnshadowed | Scattering) && !scattering.is_zero();
        let scattering_max = if use_scattering {
            scattering.max_source()
        } else {
            0.0
        };
        Ok(RayIntegrator {
            grid: *medium.grid(),
            sigma_t: &ch.sigma_t,
            emission: &ch.emission,
            scattering,
            interpolation: medium.interpolation(),
            use_sigma: index.use_sigma,
            use_emission: index.use_emission,
            use_scattering,
            background: match &options.environment {
                Some(e) => e.max_radiance(index.channel, medium.channels().len()),
                None => options.background,
            },
            ground_max: options
                .ground
                .as_ref()
                .map_or(0.0, |g| g.max_radiance(index.channel)),
            ground: options.ground.clone().map(|g| (g, index.channel)),
            environment: options
                .environment
                .clone()
                .map(|e| (e, index.channel, medium.channels().len())),
            scattering_max,
            emission_max: index.emission_max,
            emission_ratio_max: index.emission_ratio_max,
            index,
            termination: options.termination,
            step: options.trilinear_step * medium.grid().cell_size,
            fma: medium::fma::available(),
        })
    }

    /// Radiance arriving at `ray.origin` from direction `−ray.direction`, integrating from
    /// `t = 0` (so the medium behind the origin is not seen) and adding the background.
    #[inline]
    pub fn radiance(&self, ray: &Ray) -> f64 {
        let Some((lo, hi)) = self.index.occupied else {
            return self.backdrop(ray);
        };
        let Some((t_in, t_out)) = clip_box(lo, hi, ray) else {
            return self.backdrop(ray);
        };
        match self.interpolation {
            Interpolation::Nearest => {
                #[cfg(target_arch = "x86_64")]
                if self.fma {
                    // SAFETY: `fma` is set only where the CPU has FMA.
                    return unsafe { self.radiance_nearest_fma(ray, t_in, t_out) };
                }
                self.radiance_nearest::<false>(ray, t_in, t_out)
            }
            Interpolation::Trilinear => {
                #[cfg(target_arch = "x86_64")]
                if self.fma {
                    // SAFETY: `fma` is set only where the CPU has FMA.
                    return unsafe { self.radiance_trilinear_fma(ray, t_in, t_out) };
                }
                self.radiance_trilinear::<false>(ray, t_in, t_out)
            }
        }
    }

    /// What a ray sees where it leaves: the environment in its direction (light travelling
    /// back along it), or the background.
    #[inline]
    fn backdrop(&self, ray: &Ray) -> f64 {
        if let Some((ground, c)) = &self.ground {
            if let Some(l) = ground.seen_along(ray.origin, ray.direction, *c) {
                return l;
            }
        }
        match &self.environment {
            Some((e, channel, channels)) => e.radiance_along(-ray.direction, *channel, *channels),
            None => self.background,
        }
    }

    /// True when the rest of the ray (from `t` to `t_out`) cannot change the result by more
    /// than the relative tolerance.
    #[inline]
    fn can_stop(&self, transmittance: f64, radiance: f64, t: f64, t_out: f64) -> bool {
        let rest_length = (t_out - t).max(0.0);
        let rest = self.background.max(self.ground_max)
            + (self.emission_max * rest_length).min(self.emission_ratio_max)
            + self.scattering_max * rest_length;
        if rest.is_finite() {
            transmittance * rest <= self.termination * radiance
        } else {
            transmittance < self.termination
        }
    }

    /// [`RayIntegrator::radiance_nearest`] compiled with FMA (its per-cell `exp` inlined).
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "fma")]
    fn radiance_nearest_fma(&self, ray: &Ray, t_in: f64, t_out: f64) -> f64 {
        self.radiance_nearest::<true>(ray, t_in, t_out)
    }

    #[inline(always)]
    fn radiance_nearest<const FMA: bool>(&self, ray: &Ray, t_in: f64, t_out: f64) -> f64 {
        let empty = &self.index.empty;
        let mut transmittance = 1.0f64;
        let mut radiance = 0.0f64;
        let mut t_start = t_in;
        let mut carry = RayCarry::default();
        'restart: loop {
            for seg in self.grid.traverse(ray, t_start, t_out) {
                // Deep in empty space: jump to where the ray leaves the known-empty cube and
                // restart the traversal there (worth it only for cubes of several cells).
                let radius = empty.empty_radius(seg.coords, 0);
                if radius >= JUMP_RADIUS {
                    let t_next = empty.exit(ray, seg.coords, radius);
                    if t_next >= t_out {
                        break 'restart;
                    }
                    if t_next > seg.t_exit {
                        t_start = t_next;
                        continue 'restart;
                    }
                }
                let len = seg.length();
                let sigma = if self.use_sigma {
                    self.sigma_t[seg.cell] as f64
                } else {
                    0.0
                };
                let emission = if self.use_emission {
                    self.emission.get(seg.cell) as f64
                } else {
                    0.0
                };
                // Nothing absorbs, emits or scatters here (scattering needs σs = a σt > 0).
                if (sigma == 0.0 && emission == 0.0) || len <= 0.0 {
                    continue;
                }
                let view = ViewSegment::new_with::<FMA>(ray, &seg, sigma);
                let mut q = emission * view.weight;
                if self.use_scattering {
                    q += self.scattering.segment(&view, &mut carry);
                }
                radiance += transmittance * q;
                transmittance *= view.attenuation;
                if self.can_stop(transmittance, radiance, seg.t_exit, t_out) {
                    return radiance;
                }
            }
            break;
        }
        radiance + transmittance * self.backdrop(ray)
    }

    /// [`RayIntegrator::radiance_trilinear`] compiled with FMA (its per-step `exp` inlined).
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "fma")]
    fn radiance_trilinear_fma(&self, ray: &Ray, t_in: f64, t_out: f64) -> f64 {
        self.radiance_trilinear::<true>(ray, t_in, t_out)
    }

    #[inline(always)]
    fn radiance_trilinear<const FMA: bool>(&self, ray: &Ray, t_in: f64, t_out: f64) -> f64 {
        let empty = &self.index.empty;
        let length = t_out - t_in;
        let steps = (length / self.step).ceil().max(1.0);
        let dt = length / steps;
        let steps = steps as usize;
        let flow = -ray.direction;
        let inverse_cell_size = 1.0 / self.grid.cell_size;
        let mut transmittance = 1.0f64;
        let mut radiance = 0.0f64;
        let mut k = 0;
        while k < steps {
            let t = t_in + (k as f64 + 0.5) * dt;
            let x = ray.at(t);
            // The interpolated field is zero in cells whose neighbours are all empty; jump over
            // the whole known-empty cube, keeping to the lattice of step midpoints. (The cell
            // alone: most steps go on as a thin pair about another point.)
            let coords = own_coords(&self.grid, inverse_cell_size, x);
            let radius = empty.empty_radius(coords, 1);
            if radius >= 0 {
                let t_next = empty.exit(ray, coords, radius);
                let k_next = ((t_next - t_in) / dt - 0.5).ceil();
                k = if k_next > k as f64 {
                    k_next as usize
                } else {
                    k + 1
                };
                continue;
            }
            // Where steps `j − 1` and `j` lie in thin medium (σt bounded near them), one step
            // of twice the length about their common end, `(t, x)` (the bound keeps it one
            // piece).
            let thin_pair_ending = |j: usize| {
                self.index.extinction.as_ref().and_then(|bound| {
                    let t = t_in + j as f64 * dt;
                    let x = ray.at(t);
                    (bound.at(x) * 2.0 * dt <= MAX_PIECE_DEPTH).then_some((t, x))
                })
            };
            let pair_end = if k + 1 < steps {
                thin_pair_ending(k + 1)
            } else {
                None
            };
            // A second thin pair right after the first: the two pieces are taken together, so
            // that the sources may share what is the same at both (a directional light's
            // `exp`, the solved field's lookups: `InScattering::at_step_pair`).
            let quad = self.use_sigma && self.use_scattering && k + 3 < steps;
            if let (Some((_, x1)), true) = (pair_end, quad) {
                if let Some((t2, x2)) = thin_pair_ending(k + 3) {
                    k += 4;
                    let length = 2.0 * dt;
                    let samples = [
                        self.step_sample(x1, inverse_cell_size),
                        self.step_sample(x2, inverse_cell_size),
                    ];
                    let scattered = self.scattering.at_step_pair(&samples, flow);
                    for (s, q) in samples.iter().zip(scattered) {
                        let (sigma, emitted) = self.extinction_and_emission(
                            &s.corners,
                            Some(s.sigma_t_from(self.sigma_t)),
                        );
                        let (weight, attenuation) =
                            weight_and_attenuation_with::<FMA>(sigma, length);
                        radiance += transmittance * (emitted + q) * weight;
                        transmittance *= attenuation;
                    }
                    if self.can_stop(transmittance, radiance, t2 + dt, t_out) {
                        return radiance;
                    }
                    continue;
                }
            }
            let thin_pair = pair_end.is_some();
            let (t, x, length) = match pair_end {
                Some((t, x)) => (t, x, 2.0 * dt),
                None => (t, x, dt),
            };
            k += if thin_pair { 2 } else { 1 };
            let corners = Trilinear::with_inverse_size(&self.grid, inverse_cell_size, x);
            // Where the step may be optically thick, the source and σt change too much within
            // it for one midpoint: split it into pieces of at most `MAX_PIECE_DEPTH` (bounded
            // by the largest σt of the midpoint's 8 neighbours, read once for the bound and the
            // midpoint's value). A thin pair is one piece: its bound bounds those neighbours.
            let (pieces, sigma) = if self.use_sigma {
                let values = corners.gather(self.sigma_t);
                let pieces = if thin_pair {
                    1.0
                } else {
                    // σt is finite and ≥ 0 (the medium checks it): a plain comparison fold.
                    let sigma_max = values
                        .into_iter()
                        .fold(0.0, |m, v| if v > m { v } else { m });
                    let depth = sigma_max * length;
                    if depth <= MAX_PIECE_DEPTH {
                        1.0
                    } else {
                        (depth / MAX_PIECE_DEPTH).ceil().clamp(1.0, MAX_PIECES)
                    }
                };
                (pieces, Some(corners.dot(&values)))
            } else {
                (1.0, None)
            };
            if pieces == 1.0 {
                let (q, attenuation) = self.piece::<FMA>(x, corners, sigma, length, flow);
                radiance += transmittance * q;
                transmittance *= attenuation;
            } else {
                let piece = length / pieces;
                for j in 0..pieces as usize {
                    let x = ray.at(t + (j as f64 + 0.5 - 0.5 * pieces) * piece);
                    let corners = Trilinear::with_inverse_size(&self.grid, inverse_cell_size, x);
                    let (q, attenuation) = self.piece::<FMA>(x, corners, None, piece, flow);
                    radiance += transmittance * q;
                    transmittance *= attenuation;
                }
            }
            if self.can_stop(transmittance, radiance, t + 0.5 * length, t_out) {
                return radiance;
            }
        }
        radiance + transmittance * self.backdrop(ray)
    }

    /// The step of a `trilinear` march at `x`, σt read there.
    #[inline(always)]
    fn step_sample(&self, x: DVec3, inverse_cell_size: f64) -> StepSample<'_> {
        let corners = Trilinear::with_inverse_size(&self.grid, inverse_cell_size, x);
        let sigma = corners.dot(&corners.gather(self.sigma_t));
        StepSample::interpolated(x, corners, self.sigma_t, sigma)
    }

    /// σt and emission at the midpoint of a piece of a `trilinear` march (neighbours
    /// `corners`; σt there when the caller has it), each 0 where the model leaves it out.
    #[inline(always)]
    fn extinction_and_emission(&self, corners: &Trilinear, sigma: Option<f64>) -> (f64, f64) {
        match (self.use_sigma, self.use_emission, sigma) {
            (true, false, Some(sigma)) => (sigma, 0.0),
            (true, true, Some(sigma)) => (sigma, corners.sample(|c| self.emission.get(c) as f64)),
            (true, true, None) => corners.sample2(self.sigma_t, self.emission),
            (true, false, None) => (corners.sample(|c| self.sigma_t[c] as f64), 0.0),
            (false, true, _) => (0.0, corners.sample(|c| self.emission.get(c) as f64)),
            (false, false, _) => (0.0, 0.0),
        }
    }

    /// One piece of `length` of a `trilinear` march with its midpoint `x` (neighbours
    /// `corners`; σt there when the caller has it): what it adds for unit transmittance
    /// before it, and its attenuation.
    #[inline(always)]
    fn piece<const FMA: bool>(
        &self,
        x: DVec3,
        corners: Trilinear,
        sigma: Option<f64>,
        length: f64,
        flow: DVec3,
    ) -> (f64, f64) {
        let (sigma, mut q) = self.extinction_and_emission(&corners, sigma);
        let (weight, attenuation) = weight_and_attenuation_with::<FMA>(sigma, length);
        if self.use_scattering {
            // With no σt read (emission-only), the sources interpolate their own.
            let cells = if self.use_sigma { self.sigma_t } else { &[] };
            let step = StepSample::interpolated(x, corners, cells, sigma);
            q += self.scattering.at_step(&step, flow);
        }
        (q * weight, attenuation)
    }
}

/// Largest optical depth of one midpoint sample of a `trilinear` march (bounded by the
/// largest σt around the step's midpoint): the first bounce changes by `e^{−τ}` across it.
const MAX_PIECE_DEPTH: f64 = 0.1;

/// Most pieces one step of a `trilinear` march is split into.
const MAX_PIECES: f64 = 64.0;

/// `max e/σt` over the cells that emit; infinite if one emits with σt = 0.
fn emission_ratio_max(sigma_t: &[f32], emission: &CellValues) -> f64 {
    let mut ratio = 0.0f64;
    for (c, &s) in sigma_t.iter().enumerate() {
        let e = emission.get(c) as f64;
        if e > 0.0 {
            if s > 0.0 {
                ratio = ratio.max(e / s as f64);
            } else {
                return f64::INFINITY;
            }
        }
    }
    ratio
}

/// The coordinates of the cell containing `x` (clamped to the grid): [`Trilinear::coords`]
/// without the neighbours and weights.
#[inline(always)]
fn own_coords(grid: &Grid, inverse_cell_size: f64, x: DVec3) -> [usize; 3] {
    let [nx, ny, nz] = grid.dims;
    [
        clamped_floor(x.x * inverse_cell_size, nx - 1),
        clamped_floor(x.y * inverse_cell_size, ny - 1),
        clamped_floor(x.z * inverse_cell_size, nz - 1),
    ]
}

/// The 8 cell-centred neighbours of a point and their trilinear weights (values clamped to
/// the edge cells outside the outermost centres): the `trilinear` reconstruction.
pub struct Trilinear {
    /// The cell containing the point, and its coordinates.
    cell: usize,
    coords: [usize; 3],
    index: [[usize; 2]; 3],
    frac: [f64; 3],
    strides: [usize; 3],
}

impl Trilinear {
    #[inline]
    pub fn new(grid: &Grid, x: DVec3) -> Self {
        Self::with_inverse_size(grid, 1.0 / grid.cell_size, x)
    }

    /// [`Trilinear::new`] with `1 / grid.cell_size` given (a march finds it once, not per
    /// step).
    #[inline(always)]
    pub fn with_inverse_size(grid: &Grid, inverse_cell_size: f64, x: DVec3) -> Self {
        let mut index = [[0usize; 2]; 3];
        let mut frac = [0.0; 3];
        let mut own = [0usize; 3];
        for a in 0..3 {
            let n = grid.dims[a];
            let q = x[a] * inverse_cell_size;
            own[a] = clamped_floor(q, n - 1);
            // `q − ½` clamped to `[0, n − 1]` (comparisons: NaN-free, one instruction each).
            let last = (n - 1) as f64;
            let u = q - 0.5;
            let u = if u > 0.0 { u } else { 0.0 };
            let u = if u < last { u } else { last };
            let i0 = clamped_floor(u, n.saturating_sub(2));
            let i1 = (i0 + 1).min(n - 1);
            index[a] = [i0, i1];
            frac[a] = u - i0 as f64;
        }
        let strides = [1, grid.dims[0], grid.dims[0] * grid.dims[1]];
        Trilinear {
            cell: own[0] + strides[1] * own[1] + strides[2] * own[2],
            coords: own,
            index,
            frac,
            strides,
        }
    }

    /// σt and emission at once (same weights), the common case of emission + absorption.
    #[inline]
    fn sample2(&self, sigma_t: &[f32], emission: &CellValues) -> (f64, f64) {
        match emission {
            CellValues::Uniform(e) => {
                let sigma = self.sample(|c| sigma_t[c] as f64);
                (sigma, *e as f64)
            }
            CellValues::PerCell(e) => (
                self.sample(|c| sigma_t[c] as f64),
                self.sample(|c| e[c] as f64),
            ),
        }
    }

    /// The cell that contains the point.
    #[inline]
    pub fn cell(&self) -> usize {
        self.cell
    }

    /// The coordinates of [`Trilinear::cell`].
    #[inline]
    pub fn coords(&self) -> [usize; 3] {
        self.coords
    }

    /// The value a source function `j = Q/σt` reconstructs to at the point, times σt there:
    /// `σt(x) · Σ w_c j_c / Σ w_c` over the neighbours with `σt > 0` (`j` is undefined in
    /// empty cells, so they do not pull it to zero; `σt(x)` fades the edges). `value(c)` is the
    /// cell's `Q`. This is how a solved per-cell source is drawn smoothly: a `trilinear`
    /// medium's σt times a trilinear source function.
    #[inline]
    pub fn source(&self, sigma_t: &[f32], mut value: impl FnMut(usize) -> f64) -> f64 {
        let (mut sigma, mut weighted, mut weight) = (0.0, 0.0, 0.0);
        self.for_each(|c, w| {
            let s = sigma_t[c] as f64;
            sigma += w * s;
            if s > 0.0 {
                weighted += w * value(c) / s;
                weight += w;
            }
        });
        if weight > 0.0 {
            sigma * weighted / weight
        } else {
            0.0
        }
    }

    /// The 8 neighbours, x fastest then y then z (the order of [`Trilinear::weights`]; a
    /// neighbour appears twice where the point is past the outermost centres).
    #[inline(always)]
    pub fn cells(&self) -> [usize; 8] {
        // Written out: the array combinators are not always inlined in the march.
        let [x0, x1] = self.index[0];
        let [y0, y1] = self.index[1].map(|j| j * self.strides[1]);
        let [z0, z1] = self.index[2].map(|k| k * self.strides[2]);
        [
            x0 + y0 + z0,
            x1 + y0 + z0,
            x0 + y1 + z0,
            x1 + y1 + z0,
            x0 + y0 + z1,
            x1 + y0 + z1,
            x0 + y1 + z1,
            x1 + y1 + z1,
        ]
    }

    /// The trilinear weights of [`Trilinear::cells`].
    #[inline]
    pub fn weights(&self) -> [f64; 8] {
        let w = self.frac.map(|f| [1.0 - f, f]);
        std::array::from_fn(|k| w[0][k & 1] * w[1][(k >> 1) & 1] * w[2][k >> 2])
    }

    /// Calls `f(cell, weight)` for each neighbour of non-zero weight.
    #[inline]
    pub fn for_each(&self, mut f: impl FnMut(usize, f64)) {
        for dz in 0..2 {
            let wz = if dz == 0 {
                1.0 - self.frac[2]
            } else {
                self.frac[2]
            };
            let oz = self.index[2][dz] * self.strides[2];
            for dy in 0..2 {
                let wy = if dy == 0 {
                    1.0 - self.frac[1]
                } else {
                    self.frac[1]
                };
                let oy = oz + self.index[1][dy] * self.strides[1];
                let wyz = wy * wz;
                if wyz == 0.0 {
                    continue;
                }
                let w0 = (1.0 - self.frac[0]) * wyz;
                let w1 = self.frac[0] * wyz;
                if w0 != 0.0 {
                    f(oy + self.index[0][0], w0);
                }
                if w1 != 0.0 {
                    f(oy + self.index[0][1], w1);
                }
            }
        }
    }

    /// The trilinear interpolation of the per-cell `value`.
    #[inline]
    pub fn sample(&self, value: impl FnMut(usize) -> f64) -> f64 {
        self.dot(&self.gather_with(value))
    }

    /// The 8 neighbours' `values` (in the order of [`Trilinear::cells`]), read once for both
    /// an interpolation ([`Trilinear::dot`]) and a bound.
    #[inline(always)]
    pub fn gather(&self, values: &[f32]) -> [f64; 8] {
        self.gather_with(|c| values[c] as f64)
    }

    /// `value` of the 8 neighbours, in the order of [`Trilinear::cells`].
    #[inline(always)]
    fn gather_with(&self, mut value: impl FnMut(usize) -> f64) -> [f64; 8] {
        // Written out: the array combinators are not always inlined in the march.
        let c = self.cells();
        [
            value(c[0]),
            value(c[1]),
            value(c[2]),
            value(c[3]),
            value(c[4]),
            value(c[5]),
            value(c[6]),
            value(c[7]),
        ]
    }

    /// The interpolation of the neighbours' `values` (in the order of [`Trilinear::cells`]).
    #[inline(always)]
    pub fn dot(&self, values: &[f64; 8]) -> f64 {
        // Branch-free: weight-0 neighbours are in range (clamped) and add 0.
        let w = self.frac.map(|f| [1.0 - f, f]);
        let mut sum = 0.0;
        for dz in 0..2 {
            for dy in 0..2 {
                let k = 4 * dz + 2 * dy;
                let row = w[0][0] * values[k] + w[0][1] * values[k + 1];
                sum += w[1][dy] * w[2][dz] * row;
            }
        }
        sum
    }
}

/// What renders of one channel of a medium under one optical model derive from the medium
/// alone: the box rays are clipped to, the empty-space distances they jump by, and the
/// emission bounds of early termination. Building it walks every cell (serially, in part), so
/// renders of many views of one medium share one ([`render_indexed`],
/// [`RayIntegrator::with_index`]); [`render`] builds its own each time.
#[derive(Clone)]
pub struct RenderIndex {
    grid: Grid,
    channel: usize,
    model: OpticalModel,
    interpolation: Interpolation,
    use_sigma: bool,
    use_emission: bool,
    /// Largest emission anywhere, and largest `e/σt` (infinite if some cell emits without
    /// extinction, or for the emission-only model): bounds for early termination.
    emission_max: f64,
    emission_ratio_max: f64,
    /// World-space box holding every cell that can absorb or emit (for `trilinear`, grown by
    /// a cell for the interpolation's reach); rays are clipped to it, so the empty margins
    /// of a volume cost nothing. `None`: the medium is empty for this model.
    occupied: Option<(DVec3, DVec3)>,
    /// Distances to the nearest occupied cell, for jumping over empty space.
    empty: EmptySpace,
    /// σt bounds per block of cells (`trilinear` with σt): where a whole cell's length of
    /// ray is optically thin, the march takes it in one step instead of two.
    extinction: Option<ExtinctionBound>,
}

impl RenderIndex {
    pub fn new(medium: &Medium, channel: usize, model: OpticalModel) -> Result<Self, GatherError> {
        let ch = medium.channels().get(channel).ok_or_else(|| {
            GatherError::Render(format!(
                "channel {channel} requested of a medium with {}",
                medium.channels().len()
            ))
        })?;
        use OpticalModel::*;
        let use_sigma = model != EmissionOnly;
        let use_emission = model != AbsorptionOnly && !ch.emission.is_zero();
        let (emission_max, emission_ratio_max) = if use_emission {
            let ratio = if use_sigma {
                emission_ratio_max(&ch.sigma_t, &ch.emission)
            } else {
                f64::INFINITY
            };
            (ch.emission.max() as f64, ratio)
        } else {
            (0.0, 0.0)
        };
        let occupancy = occupancy(&ch.sigma_t, &ch.emission, use_sigma, use_emission);
        // The distance transform is serial: the rest is built beside it.
        let (empty, (occupied, extinction)) = rayon::join(
            || EmptySpace::new(medium.grid(), &occupancy),
            || {
                rayon::join(
                    || occupied_box(medium.grid(), &occupancy, medium.interpolation()),
                    || {
                        (use_sigma && medium.interpolation() == Interpolation::Trilinear)
                            .then(|| ExtinctionBound::new(medium.grid(), &ch.sigma_t))
                    },
                )
            },
        );
        Ok(RenderIndex {
            grid: *medium.grid(),
            channel,
            model,
            interpolation: medium.interpolation(),
            use_sigma,
            use_emission,
            emission_max,
            emission_ratio_max,
            occupied,
            empty,
            extinction,
        })
    }

    /// The optical model it was built for.
    pub fn model(&self) -> OpticalModel {
        self.model
    }

    /// Refuses an index built for another grid, channel count, optical model or
    /// interpolation than `medium` and `model` (the values themselves cannot be checked
    /// cheaply: an index is for the medium it was built from).
    fn check(&self, medium: &Medium, model: OpticalModel) -> Result<(), GatherError> {
        if self.grid != *medium.grid()
            || self.channel >= medium.channels().len()
            || self.model != model
            || self.interpolation != medium.interpolation()
        {
            return Err(GatherError::Render(format!(
                "render index built for channel {} of a {:?} grid, model {:?}, {:?} \
                 interpolation; asked for a {:?} grid with {} channels, model {model:?}, {:?}",
                self.channel,
                self.grid.dims,
                self.model,
                self.interpolation,
                medium.grid().dims,
                medium.channels().len(),
                medium.interpolation()
            )));
        }
        Ok(())
    }
}

/// Smallest empty radius (cells around the current one) worth a restart of the traversal.
const JUMP_RADIUS: i64 = 2;

/// Which cells can absorb (`use_sigma`, σt > 0) or emit (`use_emission`, e > 0).
fn occupancy(
    sigma_t: &[f32],
    emission: &CellValues,
    use_sigma: bool,
    use_emission: bool,
) -> Vec<bool> {
    match (use_emission, emission) {
        (true, CellValues::PerCell(e)) => sigma_t
            .par_iter()
            .zip(e.par_iter())
            .map(|(&s, &e)| (use_sigma && s > 0.0) || e > 0.0)
            .collect(),
        (true, CellValues::Uniform(e)) if *e > 0.0 => vec![true; sigma_t.len()],
        _ => sigma_t.par_iter().map(|&s| use_sigma && s > 0.0).collect(),
    }
}

/// The world-space box of the occupied cells (those that can absorb or emit; scattered light
/// needs σs = a σt > 0, so it lies inside too).
fn occupied_box(
    grid: &Grid,
    occupancy: &[bool],
    interpolation: Interpolation,
) -> Option<(DVec3, DVec3)> {
    let [nx, ny, nz] = grid.dims;
    let mut lo = [usize::MAX; 3];
    let mut hi = [0usize; 3];
    let mut any = false;
    for k in 0..nz {
        for j in 0..ny {
            let row = nx * (j + ny * k);
            for i in 0..nx {
                if occupancy[row + i] {
                    any = true;
                    for (a, v) in [i, j, k].into_iter().enumerate() {
                        lo[a] = lo[a].min(v);
                        hi[a] = hi[a].max(v + 1);
                    }
                }
            }
        }
    }
    if !any {
        return None;
    }
    // Trilinear values reach up to one cell beyond the last non-zero centre.
    let grow = match interpolation {
        Interpolation::Nearest => 0,
        Interpolation::Trilinear => 1,
    };
    let lo = DVec3::from_array(lo.map(|v| v.saturating_sub(grow) as f64)) * grid.cell_size;
    let hi = DVec3::from_array([0, 1, 2].map(|a| (hi[a] + grow).min(grid.dims[a]) as f64))
        * grid.cell_size;
    Some((lo, hi))
}

/// The parametric interval `t ≥ 0` of a ray inside the box `[lo, hi]`, or `None`.
#[inline]
fn clip_box(lo: DVec3, hi: DVec3, ray: &Ray) -> Option<(f64, f64)> {
    let (mut t0, mut t1) = (0.0f64, f64::INFINITY);
    for a in 0..3 {
        let (o, d) = (ray.origin[a], ray.direction[a]);
        if d == 0.0 {
            if o < lo[a] || o > hi[a] {
                return None;
            }
        } else {
            let inv = 1.0 / d;
            let (ta, tb) = ((lo[a] - o) * inv, (hi[a] - o) * inv);
            t0 = t0.max(ta.min(tb));
            t1 = t1.min(ta.max(tb));
        }
    }
    (t0 < t1).then_some((t0, t1))
}

/// Renders one colour channel of `medium` as seen by `camera`. Each pixel is the mean of
/// `options.spp` stratified samples over its area (the stratum centres: deterministic).
/// Parallel over bands of four rows (fine enough to balance a frame whose cost sits in a few
/// rows), each walked in 16-pixel-wide blocks.
pub fn render(
    medium: &Medium,
    channel: usize,
    camera: &Camera,
    options: &RenderOptions,
    scattering: &dyn InScattering,
) -> Result<ImageChannel, GatherError> {
    let integrator = RayIntegrator::new(medium, channel, options, scattering)?;
    render_rays(&integrator, camera, options)
}

/// [`render`] with the [`RenderIndex`] of this medium, channel and `options.model` built once
/// for many views.
pub fn render_indexed(
    medium: &Medium,
    camera: &Camera,
    options: &RenderOptions,
    scattering: &dyn InScattering,
    index: &RenderIndex,
) -> Result<ImageChannel, GatherError> {
    let integrator = RayIntegrator::with_index(medium, options, scattering, index)?;
    render_rays(&integrator, camera, options)
}

fn render_rays(
    integrator: &RayIntegrator,
    camera: &Camera,
    options: &RenderOptions,
) -> Result<ImageChannel, GatherError> {
    let (width, height) = (camera.width as usize, camera.height as usize);
    let (sx, sy) = options.strata();
    let inv_spp = 1.0 / (sx * sy) as f64;
    let mut pixels = vec![0.0f32; width * height];
    // Pixels whose rays cannot meet the occupied box see only the background: no rays there
    // (with an environment or a ground every pixel sees its own part of it).
    let every_pixel = integrator.environment.is_some() || integrator.ground.is_some();
    let [bx0, by0, bx1, by1] = match (integrator.index.occupied, every_pixel) {
        (_, true) => [0, 0, width, height],
        (Some((lo, hi)), false) => camera.pixel_bounds(lo, hi).map(|v| v as usize),
        (None, false) => [0; 4],
    };
    let background = {
        let sum: f64 = (0..sx * sy).map(|_| integrator.background).sum();
        (sum * inv_spp) as f32
    };
    // A band of BAND_ROWS rows per task (each its own task: `with_max_len(1)`), walked in
    // TILE-wide blocks.
    pixels
        .par_chunks_mut(width * BAND_ROWS)
        .with_max_len(1)
        .enumerate()
        .for_each(|(band, rows)| {
            rows.fill(background);
            let y0 = band * BAND_ROWS;
            let band_height = rows.len() / width;
            for x0 in (bx0..bx1).step_by(TILE) {
                let x1 = (x0 + TILE).min(bx1);
                for dy in 0..band_height {
                    let y = y0 + dy;
                    if y < by0 || y >= by1 {
                        continue;
                    }
                    for x in x0..x1 {
                        let mut sum = 0.0;
                        for b in 0..sy {
                            let py = y as f64 + (b as f64 + 0.5) / sy as f64;
                            for a in 0..sx {
                                let px = x as f64 + (a as f64 + 0.5) / sx as f64;
                                sum += integrator.radiance(&camera.ray(px, py));
                            }
                        }
                        rows[dy * width + x] = (sum * inv_spp) as f32;
                    }
                }
            }
        });
    Ok(ImageChannel {
        width: camera.width,
        height: camera.height,
        pixels,
    })
}

/// Renders every colour channel of `medium` into an [`Image`] (1 or 3 channels, interleaved).
/// `scattering` holds one source per channel, or is empty for none.
pub fn render_image(
    medium: &Medium,
    camera: &Camera,
    options: &RenderOptions,
    scattering: &[&dyn InScattering],
) -> Result<Image, GatherError> {
    render_image_with(medium, camera, options, scattering, &[])
}

/// [`render_image`] with one [`RenderIndex`] per channel built once for many views (channel
/// `c`'s index for channel `c`, under `options.model`).
pub fn render_image_indexed(
    medium: &Medium,
    camera: &Camera,
    options: &RenderOptions,
    scattering: &[&dyn InScattering],
    indices: &[&RenderIndex],
) -> Result<Image, GatherError> {
    if indices.len() != medium.channels().len() {
        return Err(GatherError::Render(format!(
            "{} render indices for a medium with {} channels",
            indices.len(),
            medium.channels().len()
        )));
    }
    render_image_with(medium, camera, options, scattering, indices)
}

fn render_image_with(
    medium: &Medium,
    camera: &Camera,
    options: &RenderOptions,
    scattering: &[&dyn InScattering],
    indices: &[&RenderIndex],
) -> Result<Image, GatherError> {
    let n = medium.channels().len();
    if !scattering.is_empty() && scattering.len() != n {
        return Err(GatherError::Render(format!(
            "{} scattering sources for a medium with {n} channels",
            scattering.len()
        )));
    }
    let mut channels = Vec::with_capacity(n);
    for c in 0..n {
        let source: &dyn InScattering = scattering.get(c).copied().unwrap_or(&());
        channels.push(match indices.get(c) {
            Some(index) if index.channel == c => {
                render_indexed(medium, camera, options, source, index)?
            }
            Some(index) => {
                return Err(GatherError::Render(format!(
                    "render index of channel {} given for channel {c}",
                    index.channel
                )))
            }
            None => render(medium, c, camera, options, source)?,
        });
    }
    let mut pixels = vec![0.0f32; camera.width as usize * camera.height as usize * n];
    for (c, ch) in channels.iter().enumerate() {
        for (i, &v) in ch.pixels.iter().enumerate() {
            pixels[i * n + c] = v;
        }
    }
    Ok(Image {
        width: camera.width,
        height: camera.height,
        channels: n as u32,
        pixels,
    })
}
