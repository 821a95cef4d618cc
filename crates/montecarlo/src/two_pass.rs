//! Blasi & Wuethrich's two-pass Monte Carlo method (1994, §3.2).
//!
//! **Energetization pass** ([`energetize`]): photons leave each light stochastically
//! (directional: uniformly over a square perpendicular to the light that covers the grid's
//! shadow; point: uniformly over the sphere; spot: uniformly over its cone), each carrying an
//! equal share of the light's power. They fly through the medium with exact per-cell
//! interception ([`crate::flight`]: free paths sampled from σt cell by cell, the limit of their
//! equal-probability steps). At an interaction in cell `c` the photon's power `w` is
//! extinguished there: `w (1 − a_c)` is absorbed and `w a_c` scattered; the scattered power is
//! stored with the photon's direction of flight in the **optical voxel** holding `c` (a
//! storage grid coarser than the density grid by an integer `storage_factor`, §3.2.4), in
//! the bin of a sphere sampled by meridians and parallels ([`DirectionBins`]). The photon
//! goes on with weight `w a_c` along a direction drawn from the phase function (exact
//! importance sampling of HG and of their two-lobe mix), with Russian roulette once its
//! weight falls.
//!
//! Over a ground ([`energetize_over_ground`]) the ground's unscattered light enters as photons
//! from below (drawn as the environment's, with the ground's radiance where each line meets the
//! plane); a photon that leaves the medium going down after scattering meets the ground, its
//! power is tallied on the ground's patch there and it goes on reflected (Lambertian, power
//! times the albedo). A photon that reaches the ground unscattered stops: its reflection is
//! the ground's own light.
//!
//! **Conversion** (end of the pass, §3.2.2): the stored incident power per bin becomes
//! scattered radiance per bin with the phase function averaged over bin pairs,
//! `Q_o,l = Σ_b Φ_o,b P_lb / V`, `P` renormalised so that `Σ_l P_lb Ω_l = 1` (no energy is
//! created or lost by the binning). Inside an optical voxel each density cell takes its share
//! in proportion to its interception (`σs_c`, the B&W rule): the source of cell `c` is
//! `Q_s(c, ω) = σs_c / (Σ_{c'∈o} σs_c' V_c') · Φ-weighted P`, radiance per unit length.
//!
//! **Rendering pass**: [`TwoPassSolution`] implements [`gather::InScattering`] (piecewise
//! constant in each cell, nearest outgoing bin); render with `OpticalModel::Scattering`.
//! The renderer's σt is the medium it is given, so a different render-time absorption
//! (their §4.3) is a medium with rescaled σt ([`with_extinction_scale`]); the stored
//! sources do not change.
//!
//! Bias, stated: the source is constant over each cell (over each optical voxel up to the
//! σs weights) and over each direction bin; the first bounce, if stored
//! (`include_first_bounce`), carries those approximations too. Leaving it out and adding
//! an exact first-bounce source at render time (physics.md, "final gather") removes most of
//! the bias for forward-peaked phase functions.
//!
//! Light emitted by the medium itself (`e`) is not photon-traced: the renderer adds it
//! directly, its scattering is not included.

use std::f64::consts::PI;
use std::sync::atomic::{AtomicU64, Ordering};

use gather::{InScattering, RayCarry, ViewSegment};
use glam::DVec3;
use medium::ground::{cosine_direction, GroundPatches, GroundRadiance};
use medium::phase::rotate_about;
use medium::traversal::Ray;
use medium::{ChannelMedium, Environment, Grid, Light, Medium, PhaseFunction};
use rand::Rng;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::directions::DirectionBins;
use crate::flight::{fly, Flight};
use crate::{rng, MonteCarloError};

/// Photons per light of the two-pass method when photons per light (a scene's `[solve] photons`) is absent.
pub const DEFAULT_PHOTONS: u64 = 1 << 21;

/// Bounds of photons per light (a scene's `[solve] photons`): fewer is noise, more is hours.
pub const PHOTON_RANGE: std::ops::RangeInclusive<u64> = 1_000..=(1 << 30);

/// Photons traced per task (one RNG stream each).
const BATCH: u64 = 4096;
/// Fixed number of accumulators the batches are spread over: parallelism without making
/// the floating-point sums depend on the thread count.
const GROUPS: usize = 4;

/// How to run the energetization pass.
#[derive(Clone, Debug, PartialEq)]
pub struct EnergetizeOptions {
    /// Photons sent from each light (and as many from the environment, and from the medium's
    /// emission, each counted as one more light).
    pub photons_per_light: u64,
    pub seed: u64,
    /// Optical voxels are `storage_factor³` density cells (1: one per cell).
    pub storage_factor: usize,
    /// Directions stored per optical voxel.
    pub bins: DirectionBins,
    /// Store the first interaction too (the stored source is then the whole `Q_s`); when
    /// false, the stored source is the second and higher orders only.
    pub include_first_bounce: bool,
    /// Russian roulette starts after this many interactions.
    pub rr_start_depth: u32,
    /// Sub-samples per axis of each bin for the bin-averaged phase matrix.
    pub phase_quadrature: usize,
    /// Light from every direction at infinity, sent as `photons_per_light` more photons.
    /// Its first bounce is always stored (it is smooth in direction, so renders take it
    /// from the stored field rather than from their exact single scattering).
    pub environment: Option<Environment>,
}

impl Default for EnergetizeOptions {
    fn default() -> Self {
        EnergetizeOptions {
            photons_per_light: 1 << 20,
            seed: 0,
            storage_factor: 1,
            bins: DirectionBins::ISOTROPIC,
            include_first_bounce: true,
            rr_start_depth: 3,
            phase_quadrature: 4,
            environment: None,
        }
    }
}

/// Power bookkeeping of the energetization pass (all over every light).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct PhotonEnergy {
    /// Power launched (the lights' power toward the sampled region).
    pub emitted: f64,
    /// Power of the photons whose path crosses the grid.
    pub entering: f64,
    /// Power absorbed in the medium, `Σ w (1 − a)` over interactions.
    pub absorbed: f64,
    /// Power leaving the grid after entering it.
    pub escaped: f64,
    /// Power scattered, `Σ w a` over interactions (stored or not).
    pub scattered: f64,
    /// Power stored in the optical voxels.
    pub stored: f64,
    /// Photons traced.
    pub photons: u64,
    /// Interactions simulated.
    pub interactions: u64,
}

impl PhotonEnergy {
    /// `|entering − absorbed − escaped| / entering` (Russian roulette makes it zero only on
    /// average).
    pub fn relative_imbalance(&self) -> f64 {
        if self.entering == 0.0 {
            0.0
        } else {
            (self.entering - self.absorbed - self.escaped).abs() / self.entering
        }
    }

    fn add(&mut self, o: &PhotonEnergy) {
        self.emitted += o.emitted;
        self.entering += o.entering;
        self.absorbed += o.absorbed;
        self.escaped += o.escaped;
        self.scattered += o.scattered;
        self.stored += o.stored;
        self.photons += o.photons;
        self.interactions += o.interactions;
    }
}

/// The stored result of the energetization pass for one channel: scattered radiance per
/// optical voxel and outgoing direction bin, and each density cell's share.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TwoPassSolution {
    /// The density grid the solution was computed on.
    pub grid: Grid,
    pub storage_factor: usize,
    /// Optical voxels per axis: `ceil(dims / storage_factor)`.
    pub optical_dims: [usize; 3],
    pub bins: DirectionBins,
    /// `Σ_b Φ_o,b P_lb` per optical voxel `o` and outgoing flow bin `l` (`o · bins + l`):
    /// scattered power per steradian.
    pub voxel_source: Vec<f32>,
    /// Per density cell: `σs_c / Σ_{c'∈o} σs_c' V_c'` (1/volume), the cell's share.
    pub cell_share: Vec<f32>,
    pub energy: PhotonEnergy,
    /// Whether the first interaction is in the stored source.
    pub include_first_bounce: bool,
    /// Upper bound on `Q_s` over cells and directions.
    pub max_source: f64,
}

/// Per-group accumulators.
struct Tally {
    power: Vec<f64>,
    /// Scattered power arriving on each of the ground's tally patches.
    ground: Vec<f64>,
    energy: PhotonEnergy,
}

/// A light's photon emitter: start ray and power per photon.
#[derive(Clone, Copy)]
enum Emitter<'a> {
    Square {
        corner: DVec3,
        e1: DVec3,
        e2: DVec3,
        side: f64,
        direction: DVec3,
    },
    Cone {
        position: DVec3,
        axis: DVec3,
        cos_max: f64,
    },
    /// The channel's emitting cells: a cell chosen by its power `e V` (the cumulative sums
    /// `cdf` over `cells`), a uniform point in it, a uniform direction.
    Volume {
        grid: Grid,
        cells: &'a [u32],
        cdf: &'a [f64],
    },
    /// Uniform directions, each from a uniform point of the bounding sphere's disc across it.
    Environment {
        environment: Option<&'a Environment>,
        /// The ground's light from below, as it leaves the ground unscattered.
        ground: Option<&'a GroundRadiance>,
        centre: DVec3,
        radius: f64,
        /// This channel and the medium's channel count (the environment's colour).
        channel: (usize, usize),
    },
}

impl Emitter<'_> {
    /// The emitter and its total power toward the sampled region.
    fn new(light: &Light, grid: &Grid) -> (Emitter<'static>, f64) {
        match *light {
            Light::Directional {
                direction,
                irradiance,
            } => {
                let radius = 0.5 * grid.extent().length();
                let (e1, e2) = direction.any_orthonormal_pair();
                let side = 2.0 * radius * (1.0 + 1e-9);
                let corner = grid.center()
                    - direction * (radius + grid.cell_size)
                    - (e1 + e2) * (0.5 * side);
                (
                    Emitter::Square {
                        corner,
                        e1,
                        e2,
                        side,
                        direction,
                    },
                    irradiance * side * side,
                )
            }
            Light::Point {
                position,
                intensity,
            } => (
                Emitter::Cone {
                    position,
                    axis: DVec3::Z,
                    cos_max: -1.0,
                },
                4.0 * PI * intensity,
            ),
            Light::Spot {
                position,
                axis,
                half_angle,
                intensity,
            } => {
                let cos_max = half_angle.cos();
                (
                    Emitter::Cone {
                        position,
                        axis,
                        cos_max,
                    },
                    2.0 * PI * (1.0 - cos_max) * intensity,
                )
            }
        }
    }

    /// A photon's start ray and its share of the power (1 for lights; the environment's
    /// radiance along the ray for the environment, whose power is per unit radiance).
    #[inline]
    fn ray<R: Rng + ?Sized>(&self, rng: &mut R) -> (Ray, f64) {
        match *self {
            Emitter::Volume { grid, cells, cdf } => {
                let total = cdf.last().copied().unwrap_or(0.0);
                let u = rng.random::<f64>() * total;
                let k = cdf.partition_point(|&c| c <= u).min(cells.len() - 1);
                let corner = grid.cell_min(cells[k] as usize);
                let offset = DVec3::new(rng.random(), rng.random(), rng.random());
                let cos_theta = 1.0 - 2.0 * rng.random::<f64>();
                let phi = 2.0 * PI * rng.random::<f64>();
                (
                    Ray {
                        origin: corner + offset * grid.cell_size,
                        direction: rotate_about(DVec3::Z, cos_theta, phi),
                    },
                    1.0,
                )
            }
            Emitter::Environment {
                environment,
                ground,
                centre,
                radius,
                channel: (c, channels),
            } => {
                let cos_theta = 1.0 - 2.0 * rng.random::<f64>();
                let phi = 2.0 * PI * rng.random::<f64>();
                let direction = rotate_about(DVec3::Z, cos_theta, phi);
                let (e1, e2) = direction.any_orthonormal_pair();
                let r = radius * rng.random::<f64>().sqrt();
                let a = 2.0 * PI * rng.random::<f64>();
                let origin =
                    centre - direction * (radius * 1.001) + e1 * (r * a.cos()) + e2 * (r * a.sin());
                // Going up under a ground, the light is the ground's where the line meets it.
                let from_ground = ground
                    .filter(|_| direction.z > 0.0)
                    .map(|g| g.sent_along(origin, direction, 0));
                let radiance = match (from_ground, environment) {
                    (Some(l), _) => l,
                    (None, Some(env)) => env.radiance_along(direction, c, channels),
                    (None, None) => 0.0,
                };
                (Ray { origin, direction }, radiance)
            }
            Emitter::Square {
                corner,
                e1,
                e2,
                side,
                direction,
            } => (
                Ray {
                    origin: corner
                        + e1 * (side * rng.random::<f64>())
                        + e2 * (side * rng.random::<f64>()),
                    direction,
                },
                1.0,
            ),
            Emitter::Cone {
                position,
                axis,
                cos_max,
            } => {
                let cos_theta = 1.0 - (1.0 - cos_max) * rng.random::<f64>();
                let phi = 2.0 * PI * rng.random::<f64>();
                (
                    Ray {
                        origin: position,
                        direction: rotate_about(axis, cos_theta, phi),
                    },
                    1.0,
                )
            }
        }
    }
}

fn optical_index(grid: &Grid, factor: usize, odims: [usize; 3], cell: usize) -> usize {
    let [i, j, k] = grid.coords(cell);
    (i / factor) + odims[0] * ((j / factor) + odims[1] * (k / factor))
}

/// The bin-averaged phase matrix `P_lb` (row-major `l · M + b`), renormalised so that
/// `Σ_l P_lb Ω = 1` for every `b`.
fn phase_matrix(phase: &medium::PhaseFunction, bins: DirectionBins, q: usize) -> Vec<f64> {
    let m = bins.count();
    if m == 1 {
        return vec![1.0 / (4.0 * PI)];
    }
    let points = |b: usize| -> Vec<DVec3> {
        let mut v = Vec::with_capacity(q * q);
        for iu in 0..q {
            for iv in 0..q {
                v.push(bins.direction_in(
                    b,
                    (iu as f64 + 0.5) / q as f64,
                    (iv as f64 + 0.5) / q as f64,
                ));
            }
        }
        v
    };
    let all: Vec<Vec<DVec3>> = (0..m).map(points).collect();
    let mut p = vec![0.0; m * m];
    p.par_chunks_mut(m).enumerate().for_each(|(l, row)| {
        for (b, entry) in row.iter_mut().enumerate() {
            let mut s = 0.0;
            for wl in &all[l] {
                for wb in &all[b] {
                    s += phase.eval(wl.dot(*wb));
                }
            }
            *entry = s / (q * q * q * q) as f64;
        }
    });
    let omega = bins.solid_angle();
    for b in 0..m {
        let col: f64 = (0..m).map(|l| p[l * m + b]).sum::<f64>() * omega;
        if col > 0.0 {
            for l in 0..m {
                p[l * m + b] /= col;
            }
        }
    }
    p
}

/// The energetization pass for channel `channel` of `medium` lit by `lights`, then the
/// conversion to scattered radiance. `progress(done, total)` is called after each batch of
/// photons (from worker threads). Deterministic for a seed, whatever the thread count.
///
/// Four stages: the options checked, the photons traced into per-voxel, per-bin power
/// ([`trace_photons`]), each density cell's share of its voxel ([`cell_shares`]) and the
/// power turned into scattered radiance by the bin-to-bin phase matrix ([`voxel_sources`]).
pub fn energetize(
    medium: &Medium,
    channel: usize,
    lights: &[Light],
    options: &EnergetizeOptions,
    progress: Option<&(dyn Fn(u64, u64) + Sync)>,
) -> Result<TwoPassSolution, MonteCarloError> {
    Ok(energetize_inner(medium, channel, lights, options, None, progress)?.0)
}

/// A ground under the medium for [`energetize_over_ground`]: the light it sends up
/// unscattered (`A E / π` of the light that reaches it unscattered, one channel: look it up in
/// channel 0), which photons carry into the medium like an environment's from below.
pub struct GroundPhotons {
    pub unscattered: GroundRadiance,
    /// The patches the scattered light arriving on the ground is tallied on.
    pub tally: GroundPatches,
}

/// [`energetize`] over a ground: photons that leave the medium going down after scattering
/// meet the ground, are tallied there and reflected (Lambertian); the ground's own
/// unscattered light enters as photons from below. Also returns the irradiance of the
/// scattered light on each of `ground.tally`'s patches (power per area).
pub fn energetize_over_ground(
    medium: &Medium,
    channel: usize,
    lights: &[Light],
    options: &EnergetizeOptions,
    ground: &GroundPhotons,
    progress: Option<&(dyn Fn(u64, u64) + Sync)>,
) -> Result<(TwoPassSolution, Vec<f64>), MonteCarloError> {
    energetize_inner(medium, channel, lights, options, Some(ground), progress)
}

fn energetize_inner(
    medium: &Medium,
    channel: usize,
    lights: &[Light],
    options: &EnergetizeOptions,
    ground: Option<&GroundPhotons>,
    progress: Option<&(dyn Fn(u64, u64) + Sync)>,
) -> Result<(TwoPassSolution, Vec<f64>), MonteCarloError> {
    let ch = medium
        .channels()
        .get(channel)
        .ok_or(MonteCarloError::Channel {
            channel,
            channels: medium.channels().len(),
        })?;
    check_options(options, lights)?;
    let grid = medium.grid();
    let layout = VoxelLayout::new(grid, options.storage_factor);
    let (power, on_ground, energy) =
        trace_photons(medium, channel, lights, options, &layout, ground, progress);
    let area = ground.map_or(1.0, |g| g.tally.size() * g.tally.size());
    let ground_irradiance = on_ground.iter().map(|p| p / area).collect();
    let cell_share = cell_shares(grid, ch, &layout);
    let voxel_source = voxel_sources(&medium.phase(), options, &power);
    let m = options.bins.count();
    let mut voxel_max = vec![0.0f32; layout.optical_count];
    for (o, q) in voxel_source.chunks(m).enumerate() {
        voxel_max[o] = q.iter().copied().fold(0.0, f32::max);
    }
    let max_source = (0..grid.cell_count())
        .map(|c| cell_share[c] as f64 * voxel_max[layout.voxel_of[c] as usize] as f64)
        .fold(0.0, f64::max);
    let solution = TwoPassSolution {
        grid: *grid,
        storage_factor: options.storage_factor,
        optical_dims: layout.optical_dims,
        bins: options.bins,
        voxel_source,
        cell_share,
        energy,
        include_first_bounce: options.include_first_bounce,
        max_source,
    };
    Ok((solution, ground_irradiance))
}

/// Refuses options that cannot produce a result and lights with bad parameters.
fn check_options(options: &EnergetizeOptions, lights: &[Light]) -> Result<(), MonteCarloError> {
    if options.photons_per_light == 0 {
        return Err(MonteCarloError::Options(
            "photons_per_light must be at least 1".into(),
        ));
    }
    if options.storage_factor == 0 {
        return Err(MonteCarloError::Options(
            "storage_factor must be at least 1".into(),
        ));
    }
    if options.bins.count() == 0 {
        return Err(MonteCarloError::Options(
            "direction bins must be at least 1 × 1".into(),
        ));
    }
    if options.phase_quadrature == 0 {
        return Err(MonteCarloError::Options(
            "phase_quadrature must be at least 1".into(),
        ));
    }
    for (index, light) in lights.iter().enumerate() {
        light.validated().map_err(|e| MonteCarloError::Light {
            index,
            message: e.to_string(),
        })?;
    }
    Ok(())
}

/// The optical voxels of a storage factor: their dims, count and each density cell's voxel.
struct VoxelLayout {
    optical_dims: [usize; 3],
    optical_count: usize,
    voxel_of: Vec<u32>,
}

impl VoxelLayout {
    fn new(grid: &Grid, factor: usize) -> VoxelLayout {
        let optical_dims = grid.dims.map(|d| d.div_ceil(factor));
        let voxel_of = (0..grid.cell_count())
            .map(|c| optical_index(grid, factor, optical_dims, c) as u32)
            .collect();
        VoxelLayout {
            optical_dims,
            optical_count: optical_dims[0] * optical_dims[1] * optical_dims[2],
            voxel_of,
        }
    }
}

/// Traces every light's photons (in seeded batches spread over [`GROUPS`] tallies, summed in
/// a fixed order) and returns the scattered power per optical voxel and incoming bin, with
/// the energy bookkeeping.
fn trace_photons(
    medium: &Medium,
    channel: usize,
    lights: &[Light],
    options: &EnergetizeOptions,
    layout: &VoxelLayout,
    ground: Option<&GroundPhotons>,
    progress: Option<&(dyn Fn(u64, u64) + Sync)>,
) -> (Vec<f64>, Vec<f64>, PhotonEnergy) {
    let grid = medium.grid();
    let ch = &medium.channels()[channel];
    let m = options.bins.count();
    let optical_count = layout.optical_count;
    let voxel_of = &layout.voxel_of;
    let batches_per_light = options.photons_per_light.div_ceil(BATCH);
    let mut emitters: Vec<(Emitter, f64)> = lights.iter().map(|l| Emitter::new(l, grid)).collect();
    let environment = options.environment.as_ref().filter(|e| !e.is_dark());
    let ground_light = ground.map(|g| &g.unscattered);
    if environment.is_some() || ground_light.is_some() {
        // Directions drawn uniformly, each photon starting on the disc of the grid's bounding
        // sphere across its direction: radiance L(ω) through area π R² over 4π sr (a
        // ground's, going up).
        let radius = 0.5 * grid.extent().length() * (1.0 + 1e-9);
        emitters.push((
            Emitter::Environment {
                environment,
                ground: ground_light,
                centre: grid.center(),
                radius,
                channel: (channel, medium.channels().len()),
            },
            4.0 * PI * PI * radius * radius,
        ));
    }
    // The medium's own emission: its first scattering is stored too (renders integrate the
    // emission along view rays, but not its scattering).
    let emitting: Vec<u32> = (0..grid.cell_count() as u32)
        .filter(|&c| ch.emission.get(c as usize) > 0.0)
        .collect();
    let cdf: Vec<f64> = emitting
        .iter()
        .scan(0.0, |sum, &c| {
            *sum += ch.emission.get(c as usize) as f64;
            Some(*sum)
        })
        .collect();
    if let Some(&total) = cdf.last() {
        emitters.push((
            Emitter::Volume {
                grid: *grid,
                cells: &emitting,
                cdf: &cdf,
            },
            4.0 * PI * total * grid.cell_volume(),
        ));
    }
    let total_batches = batches_per_light * emitters.len() as u64;
    let total_photons = options.photons_per_light * emitters.len() as u64;
    let done = AtomicU64::new(0);
    let groups = GROUPS.min(total_batches.max(1) as usize);

    let trace_batch = |tally: &mut Tally, batch: u64| {
        let light_index = (batch / batches_per_light) as usize;
        let local = batch % batches_per_light;
        let first = local * BATCH;
        let count = BATCH.min(options.photons_per_light - first);
        let (emitter, power) = emitters[light_index];
        let store_first = options.include_first_bounce
            || matches!(
                emitter,
                Emitter::Environment { .. } | Emitter::Volume { .. }
            );
        let mut rng = rng::stream(options.seed, 1 + light_index as u64, local);
        for _ in 0..count {
            let (mut ray, radiance) = emitter.ray(&mut rng);
            // Lights send equal shares of their power; the environment's shares follow L(ω).
            let w0 = power * radiance / options.photons_per_light as f64;
            tally.energy.emitted += w0;
            tally.energy.photons += 1;
            if !matches!(emitter, Emitter::Volume { .. })
                && grid.clip(&ray, 0.0, f64::INFINITY).is_none()
            {
                continue;
            }
            tally.energy.entering += w0;
            let mut w = w0;
            let mut depth = 0u32;
            loop {
                let target = -(1.0 - rng.random::<f64>()).ln();
                let (flight, _) = fly(grid, &ch.sigma_t, None, &ray, f64::INFINITY, target);
                let Flight::Collision { t, cell } = flight else {
                    tally.energy.escaped += w;
                    // Scattered light that meets the ground lights it (tallied) and is
                    // reflected on; unscattered light's reflection is the ground emitter's.
                    let Some(g) = ground.filter(|_| depth > 0) else {
                        break;
                    };
                    let Some(d) = g.unscattered.ground().hit(ray.origin, ray.direction) else {
                        break;
                    };
                    let x = ray.at(d);
                    if let Some(i) = g.tally.index_of(x.x, x.y) {
                        tally.ground[i] += w;
                    }
                    w *= g.unscattered.ground().albedo(0, 1);
                    if w <= 0.0 {
                        break;
                    }
                    tally.energy.entering += w;
                    ray = Ray {
                        origin: x,
                        direction: cosine_direction(rng.random(), rng.random()),
                    };
                    continue;
                };
                depth += 1;
                tally.energy.interactions += 1;
                let a = ch.albedo.get(cell) as f64;
                tally.energy.absorbed += w * (1.0 - a);
                let scattered = w * a;
                tally.energy.scattered += scattered;
                if depth > 1 || store_first {
                    let o = voxel_of[cell] as usize;
                    tally.power[o * m + options.bins.bin(ray.direction)] += scattered;
                    tally.energy.stored += scattered;
                }
                if scattered <= 0.0 {
                    break;
                }
                w = scattered;
                if depth >= options.rr_start_depth && w < w0 {
                    let q = (1.0 - w / w0).max(0.05);
                    if rng.random::<f64>() < q {
                        break;
                    }
                    w /= 1.0 - q;
                }
                let x = ray.at(t);
                ray = Ray {
                    origin: x,
                    direction: medium.phase().sample(ray.direction, &mut rng),
                };
            }
        }
        let n = done.fetch_add(count, Ordering::Relaxed) + count;
        if let Some(report) = progress {
            report(n, total_photons);
        }
    };

    let tallies: Vec<Tally> = (0..groups)
        .into_par_iter()
        .map(|g| {
            let mut tally = Tally {
                power: vec![0.0; optical_count * m],
                ground: vec![0.0; ground.map_or(0, |g| g.tally.count())],
                energy: PhotonEnergy::default(),
            };
            let mut batch = g as u64;
            while batch < total_batches {
                trace_batch(&mut tally, batch);
                batch += groups as u64;
            }
            tally
        })
        .collect();
    let mut power = vec![0.0f64; optical_count * m];
    let mut on_ground = vec![0.0f64; ground.map_or(0, |g| g.tally.count())];
    let mut energy = PhotonEnergy::default();
    for t in &tallies {
        for (p, v) in power.iter_mut().zip(&t.power) {
            *p += v;
        }
        for (p, v) in on_ground.iter_mut().zip(&t.ground) {
            *p += v;
        }
        energy.add(&t.energy);
    }
    (power, on_ground, energy)
}

/// Each density cell's share of its optical voxel's power, by interception (σs V).
fn cell_shares(grid: &Grid, ch: &ChannelMedium, layout: &VoxelLayout) -> Vec<f32> {
    let voxel_of = &layout.voxel_of;
    let volume = grid.cell_volume();
    let mut voxel_sigma_s = vec![0.0f64; layout.optical_count];
    for c in 0..grid.cell_count() {
        voxel_sigma_s[voxel_of[c] as usize] += ch.sigma_s(c) as f64 * volume;
    }
    (0..grid.cell_count())
        .map(|c| {
            let total = voxel_sigma_s[voxel_of[c] as usize];
            if total > 0.0 {
                (ch.sigma_s(c) as f64 / total) as f32
            } else {
                0.0
            }
        })
        .collect()
}

/// Scattered radiance per optical voxel and outgoing bin: the power per incoming bin through
/// the bin-averaged phase matrix.
fn voxel_sources(phase: &PhaseFunction, options: &EnergetizeOptions, power: &[f64]) -> Vec<f32> {
    let m = options.bins.count();
    let p = phase_matrix(phase, options.bins, options.phase_quadrature);
    let mut voxel_source = vec![0.0f32; power.len()];
    voxel_source
        .par_chunks_mut(m)
        .zip(power.par_chunks(m))
        .for_each(|(out, incident)| {
            for (l, q) in out.iter_mut().enumerate() {
                let row = &p[l * m..(l + 1) * m];
                *q = row.iter().zip(incident).map(|(a, b)| a * b).sum::<f64>() as f32;
            }
        });
    voxel_source
}

impl TwoPassSolution {
    /// Checks that the solution was made on `grid`.
    pub fn check_grid(&self, grid: &Grid) -> Result<(), MonteCarloError> {
        if self.grid != *grid {
            return Err(MonteCarloError::Mismatch(format!(
                "solved on a {:?} grid (cell {}), used with {:?} (cell {})",
                self.grid.dims, self.grid.cell_size, grid.dims, grid.cell_size
            )));
        }
        Ok(())
    }

    /// `Q_s` in density cell `cell` for light flowing along `flow` (radiance per length).
    #[inline]
    pub fn source(&self, cell: usize, flow: DVec3) -> f64 {
        if self.cell_share[cell] == 0.0 {
            return 0.0;
        }
        let l = if self.bins.count() == 1 {
            0
        } else {
            self.bins.bin(flow)
        };
        self.source_in_bin(cell, l)
    }

    /// `Q_s` in density cell `cell` for light flowing in direction bin `bin`.
    #[inline]
    pub fn source_in_bin(&self, cell: usize, bin: usize) -> f64 {
        let share = self.cell_share[cell];
        if share == 0.0 {
            return 0.0;
        }
        let o = optical_index(&self.grid, self.storage_factor, self.optical_dims, cell);
        share as f64 * self.voxel_source[o * self.bins.count() + bin] as f64
    }

    /// Total scattered power the stored source represents, `Σ_c V ∫ Q_s(c, ω) dω`: equals
    /// `energy.stored` when the conversion conserves energy.
    pub fn source_power(&self) -> f64 {
        let m = self.bins.count();
        let (omega, volume) = (self.bins.solid_angle(), self.grid.cell_volume());
        (0..self.grid.cell_count())
            .map(|c| {
                let o = optical_index(&self.grid, self.storage_factor, self.optical_dims, c);
                let sum: f64 = self.voxel_source[o * m..(o + 1) * m]
                    .iter()
                    .map(|&v| v as f64)
                    .sum();
                self.cell_share[c] as f64 * sum * omega * volume
            })
            .sum()
    }
}

impl InScattering for TwoPassSolution {
    #[inline]
    fn segment(&self, seg: &ViewSegment, _: &mut RayCarry) -> f64 {
        self.source(seg.cell, -seg.ray.direction) * seg.weight
    }

    #[inline]
    fn at(&self, _x: DVec3, cell: usize, view_flow_dir: DVec3) -> f64 {
        self.source(cell, view_flow_dir)
    }

    fn max_source(&self) -> f64 {
        self.max_source
    }

    fn is_zero(&self) -> bool {
        self.max_source == 0.0
    }
}

/// A copy of `medium` with every channel's σt multiplied by `scale`: the separate
/// render-time absorption of Blasi & Wuethrich §4.3 (the stored sources stay as solved).
pub fn with_extinction_scale(medium: &Medium, scale: f32) -> Result<Medium, MonteCarloError> {
    if !(scale.is_finite() && scale >= 0.0) {
        return Err(MonteCarloError::Options(format!(
            "extinction scale {scale} must be finite and ≥ 0"
        )));
    }
    let (grid, mut channels, phase, interpolation, data) = medium.clone().into_parts();
    for ch in &mut channels {
        for s in &mut ch.sigma_t {
            *s *= scale;
        }
    }
    Medium::new(grid, channels, phase, interpolation, data)
        .map_err(|e| MonteCarloError::Options(format!("extinction scale {scale}: {e}")))
}
