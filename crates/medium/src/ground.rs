//! The ground: a Lambertian plane `z = height` under the volume, with albedo per colour
//! channel, that the medium shadows and that lights the medium from below.
//!
//! - [`Ground`]: the plane and its albedo, checked by [`Ground::new`].
//! - [`GroundPatches`]: the square patches the solvers resolve its light on, over the part
//!   of the plane the medium can change (its footprint, a margin of the volume's height above
//!   the plane, and the shadows of the directional lights). Beyond them the ground is lit by
//!   the lights and the environment unshadowed.
//! - [`GroundRadiance`]: what the ground reflects, per patch and channel — the radiance
//!   `L = A E / π` of a Lambertian surface under irradiance `E` — as a solve leaves it and a
//!   render looks it up (bilinear between patch centres).
//!
//! The irradiance of a patch is the sum of three parts: the lights' (each through the medium
//! to its centre, exactly per cell), the environment's from above the horizon (through the
//! medium, over [`GROUND_DIRECTIONS`] cosine-weighted directions) and the medium's own
//! scattered light (integrated along the same directions from a source the solver gives).
//! The first two do not change while a solve couples the ground and the medium; the third is
//! what the coupling iterates.

use std::f64::consts::PI;

use glam::DVec3;
use rayon::prelude::*;

use crate::environment::pick;
use crate::traversal::{segment_weight, Ray};
use crate::{Environment, Grid, Light, MediumError};

/// Directions over the upper hemisphere a patch gathers the environment's and the medium's
/// light along (cosine-weighted, equal weights `π / n`).
pub const GROUND_DIRECTIONS: usize = 256;

/// Most patches along a side of the ground's patch grid (so at most 65,536 patches): larger
/// regions take larger patches.
pub const MAX_PATCHES_PER_SIDE: usize = 256;

/// A Lambertian plane `z = height` with an albedo per colour channel (linear sRGB; a grey
/// ground has three equal values).
///
/// # Invariants
/// `height` is finite and every albedo is in `[0, 1]`; checked by [`Ground::new`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Ground {
    height: f64,
    albedo: [f64; 3],
}

impl Ground {
    pub fn new(height: f64, albedo: [f64; 3]) -> Result<Ground, MediumError> {
        if !height.is_finite() {
            return Err(MediumError::invalid(
                "ground height",
                format!("{height} must be finite"),
            ));
        }
        if let Some(a) = albedo.iter().find(|a| !(0.0..=1.0).contains(*a)) {
            return Err(MediumError::invalid(
                "ground albedo",
                format!("{a} must be in [0, 1]"),
            ));
        }
        Ok(Ground { height, albedo })
    }

    pub fn height(&self) -> f64 {
        self.height
    }

    /// The albedo per colour channel (linear sRGB).
    pub fn albedo_rgb(&self) -> [f64; 3] {
        self.albedo
    }

    /// The albedo in channel `c` of a `channels`-channel medium (one channel: the luminance).
    pub fn albedo(&self, c: usize, channels: usize) -> f64 {
        pick(&self.albedo, c, channels)
    }

    /// Whether the channels differ (a grey medium is then solved in three channels).
    pub fn is_coloured(&self) -> bool {
        let [r, g, b] = self.albedo;
        r != g || g != b
    }

    /// Distance along unit `direction` from `origin` to the plane, for a ray that comes down
    /// onto it from above (the plane is seen from above only).
    #[inline]
    pub fn hit(&self, origin: DVec3, direction: DVec3) -> Option<f64> {
        if direction.z < 0.0 && origin.z >= self.height {
            Some((self.height - origin.z) / direction.z)
        } else {
            None
        }
    }
}

/// A grid of square patches on the ground, `dims[0] × dims[1]`, x-fastest, patch `(i, j)`
/// covering `origin + [i, i + 1] × [j, j + 1] · size`.
///
/// # Invariants
/// `size` is finite and positive, the origin finite and each side in `1 ..=
/// MAX_PATCHES_PER_SIDE`; checked by [`GroundPatches::new`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GroundPatches {
    origin: [f64; 2],
    size: f64,
    dims: [usize; 2],
}

impl GroundPatches {
    pub fn new(origin: [f64; 2], size: f64, dims: [usize; 2]) -> Result<Self, MediumError> {
        if !(origin.iter().all(|v| v.is_finite()) && size.is_finite() && size > 0.0) {
            return Err(MediumError::invalid(
                "ground patches",
                format!("origin {origin:?} and size {size} must be finite, the size positive"),
            ));
        }
        if dims.iter().any(|&d| d == 0 || d > MAX_PATCHES_PER_SIDE) {
            return Err(MediumError::invalid(
                "ground patches",
                format!("{dims:?} patches: each side must be 1 ..= {MAX_PATCHES_PER_SIDE}"),
            ));
        }
        Ok(GroundPatches { origin, size, dims })
    }

    /// The patches over the part of `ground` that a medium on `grid` lit by `lights` can
    /// change: the grid's footprint grown by its top's height above the plane on every side
    /// (where its scattered light falls) and by the shadows the directional lights cast (of
    /// at most four footprints' length), in patches of at least one cell.
    pub fn covering(ground: &Ground, grid: &Grid, lights: &[Light]) -> GroundPatches {
        let extent = grid.extent();
        let rise = (extent.z - ground.height).max(0.0);
        let mut lo = [-rise, -rise];
        let mut hi = [extent.x + rise, extent.y + rise];
        let reach = 4.0 * extent.x.max(extent.y);
        for light in lights {
            if let Light::Directional { direction, .. } = light {
                if direction.z < 0.0 {
                    // Where the grid's top corners' shadows fall.
                    let shift = direction.truncate() * (rise / -direction.z);
                    let shift = shift.clamp_length_max(reach);
                    for a in 0..2 {
                        lo[a] = lo[a].min(shift[a]);
                        hi[a] = hi[a].max(extent[a] + shift[a]);
                    }
                }
            }
        }
        let side = (hi[0] - lo[0]).max(hi[1] - lo[1]);
        let size = grid
            .cell_size
            .max(side / MAX_PATCHES_PER_SIDE as f64 * (1.0 + 1e-9));
        let dims = [0, 1]
            .map(|a| (((hi[a] - lo[a]) / size).ceil() as usize).clamp(1, MAX_PATCHES_PER_SIDE));
        GroundPatches {
            origin: lo,
            size,
            dims,
        }
    }

    pub fn origin(&self) -> [f64; 2] {
        self.origin
    }

    pub fn size(&self) -> f64 {
        self.size
    }

    pub fn dims(&self) -> [usize; 2] {
        self.dims
    }

    pub fn count(&self) -> usize {
        self.dims[0] * self.dims[1]
    }

    /// The centre of patch `index` (x-fastest) on the plane `z = height`.
    #[inline]
    pub fn centre(&self, index: usize, height: f64) -> DVec3 {
        let (i, j) = (index % self.dims[0], index / self.dims[0]);
        DVec3::new(
            self.origin[0] + (i as f64 + 0.5) * self.size,
            self.origin[1] + (j as f64 + 0.5) * self.size,
            height,
        )
    }

    /// Whether `(x, y)` lies on the patches.
    #[inline]
    fn covers(&self, x: f64, y: f64) -> bool {
        let (u, v) = (x - self.origin[0], y - self.origin[1]);
        u >= 0.0
            && v >= 0.0
            && u <= self.dims[0] as f64 * self.size
            && v <= self.dims[1] as f64 * self.size
    }

    /// Bilinear interpolation of per-patch `values` between patch centres (clamped at the
    /// outer half patch).
    #[inline]
    fn bilinear<T: Copy + Into<f64>>(&self, values: &[T], x: f64, y: f64) -> f64 {
        let axis = |p: f64, a: usize| {
            let u = ((p - self.origin[a]) / self.size - 0.5).clamp(0.0, (self.dims[a] - 1) as f64);
            let i = (u as usize).min(self.dims[a].saturating_sub(2));
            (i, u - i as f64)
        };
        let (i, fx) = axis(x, 0);
        let (j, fy) = axis(y, 1);
        let nx = self.dims[0];
        let i1 = (i + 1).min(nx - 1);
        let j1 = (j + 1).min(self.dims[1] - 1);
        let v = |i: usize, j: usize| values[i + nx * j].into();
        (1.0 - fy) * ((1.0 - fx) * v(i, j) + fx * v(i1, j))
            + fy * ((1.0 - fx) * v(i, j1) + fx * v(i1, j1))
    }
}

/// Most patches a side on which the ground's smooth parts (the environment's light and the
/// medium's scattered light, both from wide solid angles) are computed, on
/// [`GroundPatches::coarsened`] patches; the patches between interpolate bilinearly.
pub const SMOOTH_SIDE: usize = 64;

impl GroundPatches {
    /// The same region in patches at most `max_side` a side (each an integer number of this
    /// grid's patches across), for tallies that need more samples per patch.
    pub fn coarsened(&self, max_side: usize) -> GroundPatches {
        let k = self.dims[0]
            .max(self.dims[1])
            .div_ceil(max_side.max(1))
            .max(1);
        GroundPatches {
            origin: self.origin,
            size: self.size * k as f64,
            dims: self.dims.map(|d| d.div_ceil(k)),
        }
    }

    /// The patch under `(x, y)`, if the patches cover it.
    #[inline]
    pub fn index_of(&self, x: f64, y: f64) -> Option<usize> {
        let (u, v) = (
            (x - self.origin[0]) / self.size,
            (y - self.origin[1]) / self.size,
        );
        if !(u >= 0.0 && v >= 0.0) {
            return None;
        }
        let (i, j) = (u as usize, v as usize);
        (i < self.dims[0] && j < self.dims[1]).then_some(i + self.dims[0] * j)
    }

    /// `values` on the patches of `coarse` (per patch), interpolated bilinearly to the
    /// centres of these patches.
    pub fn resample(&self, coarse: &GroundPatches, values: &[f64]) -> Vec<f64> {
        (0..self.count())
            .map(|index| {
                let c = self.centre(index, 0.0);
                coarse.bilinear(values, c.x, c.y)
            })
            .collect()
    }
}

/// The direction a Lambertian surface facing +z reflects into, from two uniform numbers in
/// [0, 1): cosine-distributed about +z.
#[inline]
pub fn cosine_direction(u1: f64, u2: f64) -> DVec3 {
    let (r, phi) = (u1.sqrt(), 2.0 * PI * u2);
    DVec3::new(r * phi.cos(), r * phi.sin(), (1.0 - u1).max(0.0).sqrt())
}

/// `n` unit directions over the upper hemisphere (`z > 0`), cosine-weighted: a Fibonacci
/// lattice on the unit disk lifted to the hemisphere, so `E = π/n Σ L(ω_k)` integrates
/// radiance into irradiance on a horizontal surface.
pub fn cosine_directions(n: usize) -> Vec<DVec3> {
    let golden = PI * (3.0 - 5f64.sqrt());
    (0..n)
        .map(|k| {
            let r2 = (k as f64 + 0.5) / n as f64;
            let (r, phi) = (r2.sqrt(), golden * k as f64);
            DVec3::new(r * phi.cos(), r * phi.sin(), (1.0 - r2).sqrt())
        })
        .collect()
}

/// The environment's radiance arriving from each of `directions` (up from the ground), times
/// the quadrature weight `π / n`: their sum is its irradiance on an unshadowed horizontal
/// plane.
fn sky_weights(env: &Environment, directions: &[DVec3], c: usize, channels: usize) -> Vec<f64> {
    let weight = PI / directions.len() as f64;
    directions
        .iter()
        .map(|&d| weight * env.radiance_along(-d, c, channels))
        .collect()
}

/// The environment's irradiance on an unshadowed horizontal plane facing +z, channel `c` of
/// `channels` (over [`GROUND_DIRECTIONS`] directions, as the patches gather it).
pub fn environment_irradiance(env: &Environment, c: usize, channels: usize) -> f64 {
    sky_weights(env, &cosine_directions(GROUND_DIRECTIONS), c, channels)
        .iter()
        .sum()
}

/// Transmittance through the grid along `ray` to `t_max`.
#[inline]
fn transmittance(grid: &Grid, sigma_t: &[f32], ray: &Ray, t_max: f64) -> f64 {
    (-grid.optical_depth(sigma_t, ray, 0.0, t_max)).exp()
}

fn check_sigma(grid: &Grid, sigma_t: &[f32]) -> Result<(), MediumError> {
    if sigma_t.len() != grid.cell_count() {
        return Err(MediumError::invalid(
            "ground irradiance",
            format!(
                "{} σt values for {} cells",
                sigma_t.len(),
                grid.cell_count()
            ),
        ));
    }
    Ok(())
}

/// Irradiance from `lights` at `p` on a plane facing +z, through the medium (σt per cell of
/// the grid, the exact per-cell optical depth) or unshadowed when `medium` is `None`.
pub fn light_irradiance(p: DVec3, lights: &[Light], medium: Option<(&Grid, &[f32])>) -> f64 {
    let mut e = 0.0;
    for light in lights {
        let (flow, irradiance) = light.arriving_at(p);
        let cos = -flow.z;
        if irradiance <= 0.0 || cos <= 0.0 {
            continue;
        }
        let t = match medium {
            Some((grid, sigma_t)) => {
                let t_max = match *light {
                    Light::Directional { .. } => f64::INFINITY,
                    Light::Point { position, .. } | Light::Spot { position, .. } => {
                        (position - p).length()
                    }
                };
                transmittance(
                    grid,
                    sigma_t,
                    &Ray {
                        origin: p,
                        direction: -flow,
                    },
                    t_max,
                )
            }
            None => 1.0,
        };
        e += irradiance * cos * t;
    }
    e
}

impl GroundPatches {
    /// Per channel and patch, the irradiance of the light that reaches the ground unscattered:
    /// the `lights` through the medium (`sigma_t[c]` per cell of `grid`, one slice per channel)
    /// at every patch, and the environment's light from above the horizon through the medium,
    /// which shadows softly, on patches at most [`SMOOTH_SIDE`] a side and interpolated
    /// between. Channels with the same σt share their rays.
    pub fn uncollided_irradiance(
        &self,
        ground: &Ground,
        grid: &Grid,
        sigma_t: &[&[f32]],
        lights: &[Light],
        environment: Option<&Environment>,
    ) -> Result<Vec<Vec<f64>>, MediumError> {
        for s in sigma_t {
            check_sigma(grid, s)?;
        }
        let channels = sigma_t.len();
        let mut out: Vec<Vec<f64>> = Vec::with_capacity(channels);
        for c in 0..channels {
            if let Some(same) = (0..c).find(|&o| sigma_t[o] == sigma_t[c]) {
                // The lights are white: the same σt gives the same light (the sky, coloured,
                // is added below).
                let direct = out[same].clone();
                out.push(direct);
                continue;
            }
            let sigma = sigma_t[c];
            let direct: Vec<f64> = (0..self.count())
                .into_par_iter()
                .map(|index| {
                    light_irradiance(
                        self.centre(index, ground.height),
                        lights,
                        Some((grid, sigma)),
                    )
                })
                .collect();
            out.push(direct);
        }
        if let Some(env) = environment {
            let directions = cosine_directions(GROUND_DIRECTIONS);
            let coarse = self.coarsened(SMOOTH_SIDE);
            // Transmittance along each direction from each coarse patch, shared by channels
            // with the same σt.
            let mut tables: Vec<(usize, Vec<f32>)> = Vec::new();
            for c in 0..channels {
                let t = match tables.iter().find(|(o, _)| sigma_t[*o] == sigma_t[c]) {
                    Some((_, t)) => t,
                    None => {
                        let sigma = sigma_t[c];
                        let t: Vec<f32> = (0..coarse.count())
                            .into_par_iter()
                            .flat_map_iter(|index| {
                                let p = coarse.centre(index, ground.height);
                                directions.iter().map(move |&d| {
                                    let ray = Ray {
                                        origin: p,
                                        direction: d,
                                    };
                                    transmittance(grid, sigma, &ray, f64::INFINITY) as f32
                                })
                            })
                            .collect();
                        tables.push((c, t));
                        &tables.last().expect("just pushed").1
                    }
                };
                let sky = sky_weights(env, &directions, c, channels);
                let on_coarse: Vec<f64> = t
                    .chunks(directions.len())
                    .map(|row| row.iter().zip(&sky).map(|(&t, l)| t as f64 * l).sum())
                    .collect();
                for (e, v) in out[c].iter_mut().zip(self.resample(&coarse, &on_coarse)) {
                    *e += v;
                }
            }
        }
        Ok(out)
    }

    /// Per patch, the irradiance of the medium's scattered light: `π/n Σ_k ∫ Q T ds` along
    /// each of [`GROUND_DIRECTIONS`] cosine-weighted directions up from the patch's centre,
    /// with `source(cell, travel)` the radiance per unit length cell `cell` sends along
    /// `travel` (piecewise constant in each cell, as σt). Smooth over the ground: computed on
    /// patches at most [`SMOOTH_SIDE`] a side and interpolated between.
    pub fn scattered_irradiance(
        &self,
        ground: &Ground,
        grid: &Grid,
        sigma_t: &[f32],
        source: &(dyn Fn(usize, DVec3) -> f64 + Sync),
    ) -> Result<Vec<f64>, MediumError> {
        check_sigma(grid, sigma_t)?;
        let directions = cosine_directions(GROUND_DIRECTIONS);
        let weight = PI / directions.len() as f64;
        let coarse = self.coarsened(SMOOTH_SIDE);
        let on_coarse: Vec<f64> = (0..coarse.count())
            .into_par_iter()
            .map(|index| {
                let p = coarse.centre(index, ground.height);
                let mut e = 0.0;
                for &d in &directions {
                    let ray = Ray {
                        origin: p,
                        direction: d,
                    };
                    let (mut t, mut l) = (1.0f64, 0.0f64);
                    for seg in grid.traverse(&ray, 0.0, f64::INFINITY) {
                        let sigma = sigma_t[seg.cell] as f64;
                        let len = seg.length();
                        l += t * source(seg.cell, -d) * segment_weight(sigma, len);
                        t *= (-sigma * len).exp();
                        if t < 1e-7 {
                            break;
                        }
                    }
                    e += weight * l;
                }
                e
            })
            .collect();
        Ok(self.resample(&coarse, &on_coarse))
    }
}

/// The light the ground reflects, per patch and channel, as a solve leaves it: radiance
/// `A E / π`, the same in every direction. Beyond the patches, the lights and the environment
/// light the ground unshadowed.
///
/// # Invariants
/// One list of `patches.count()` finite values ≥ 0 per channel (1 or 3 channels), and the
/// environment's irradiance beyond the patches, finite and ≥ 0, per channel; checked by
/// [`GroundRadiance::new`].
#[derive(Clone, Debug, PartialEq)]
pub struct GroundRadiance {
    ground: Ground,
    patches: GroundPatches,
    radiance: Vec<Vec<f32>>,
    lights: Vec<Light>,
    sky_irradiance: Vec<f64>,
}

impl GroundRadiance {
    /// `radiance[c]` the reflected radiance per patch of channel `c`; `lights` those lighting
    /// the ground beyond the patches; `sky_irradiance[c]` the environment's irradiance there.
    pub fn new(
        ground: Ground,
        patches: GroundPatches,
        radiance: Vec<Vec<f32>>,
        lights: Vec<Light>,
        sky_irradiance: Vec<f64>,
    ) -> Result<Self, MediumError> {
        let bad = |m: String| Err(MediumError::invalid("ground radiance", m));
        if !matches!(radiance.len(), 1 | 3) || sky_irradiance.len() != radiance.len() {
            return bad(format!(
                "{} channels of patches and {} of sky irradiance (1 or 3, the same)",
                radiance.len(),
                sky_irradiance.len()
            ));
        }
        for (c, values) in radiance.iter().enumerate() {
            if values.len() != patches.count() {
                return bad(format!(
                    "channel {c} has {} values for {} patches",
                    values.len(),
                    patches.count()
                ));
            }
            if values.iter().any(|v| !(v.is_finite() && *v >= 0.0)) {
                return bad(format!(
                    "channel {c} has a value that is negative or not finite"
                ));
            }
        }
        if sky_irradiance.iter().any(|v| !(v.is_finite() && *v >= 0.0)) {
            return bad("a sky irradiance is negative or not finite".into());
        }
        let lights = lights
            .into_iter()
            .map(Light::validated)
            .collect::<Result<Vec<_>, _>>()?;
        Ok(GroundRadiance {
            ground,
            patches,
            radiance,
            lights,
            sky_irradiance,
        })
    }

    pub fn ground(&self) -> &Ground {
        &self.ground
    }

    pub fn patches(&self) -> &GroundPatches {
        &self.patches
    }

    /// Reflected radiance per patch, per channel.
    pub fn radiance(&self) -> &[Vec<f32>] {
        &self.radiance
    }

    pub fn lights(&self) -> &[Light] {
        &self.lights
    }

    pub fn sky_irradiance(&self) -> &[f64] {
        &self.sky_irradiance
    }

    pub fn channels(&self) -> usize {
        self.radiance.len()
    }

    /// The radiance the ground sends up from `p` (on the plane) in channel `c`.
    #[inline]
    pub fn radiance_at(&self, p: DVec3, c: usize) -> f64 {
        if self.patches.covers(p.x, p.y) {
            return self.patches.bilinear(&self.radiance[c], p.x, p.y);
        }
        let albedo = self.ground.albedo(c, self.channels());
        albedo / PI * (self.sky_irradiance[c] + light_irradiance(p, &self.lights, None))
    }

    /// The radiance the ground sends along unit `travel` (going up; 0 otherwise) on the line
    /// through `x`, where that line meets the plane (before or after `x`: in the void between
    /// the radiance is the same all along it).
    #[inline]
    pub fn sent_along(&self, x: DVec3, travel: DVec3, c: usize) -> f64 {
        if travel.z <= 0.0 {
            return 0.0;
        }
        let to_plane = (self.ground.height - x.z) / travel.z;
        self.radiance_at(x + travel * to_plane, c)
    }

    /// What a ray along unit `direction` from `origin` sees of the ground, if it meets it.
    #[inline]
    pub fn seen_along(&self, origin: DVec3, direction: DVec3, c: usize) -> Option<f64> {
        let t = self.ground.hit(origin, direction)?;
        Some(self.radiance_at(origin + direction * t, c))
    }

    /// An upper bound of the radiance it sends in channel `c` (for renders' early termination).
    pub fn max_radiance(&self, c: usize) -> f64 {
        let patches = self.radiance[c]
            .iter()
            .fold(0.0f64, |m, &v| m.max(v as f64));
        let mut e = self.sky_irradiance[c];
        for light in &self.lights {
            e += match *light {
                Light::Directional {
                    direction,
                    irradiance,
                } => irradiance * (-direction.z).max(0.0),
                Light::Point {
                    position,
                    intensity,
                }
                | Light::Spot {
                    position,
                    intensity,
                    ..
                } => {
                    let above = (position.z - self.ground.height).abs().max(1e-6);
                    intensity / (above * above)
                }
            };
        }
        patches.max(self.ground.albedo(c, self.channels()) / PI * e)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cosine_directions_integrate_cosine_weighted_radiance() {
        let dirs = cosine_directions(GROUND_DIRECTIONS);
        assert!(dirs
            .iter()
            .all(|d| d.z > 0.0 && (d.length() - 1.0).abs() < 1e-12));
        // E of a uniform L is π L; of L ∝ cos θ it is 2π/3.
        let w = PI / dirs.len() as f64;
        let uniform: f64 = dirs.iter().map(|_| w).sum();
        let cosine: f64 = dirs.iter().map(|d| w * d.z).sum();
        assert!((uniform - PI).abs() < 1e-12);
        assert!((cosine - 2.0 * PI / 3.0).abs() < 2e-3 * cosine, "{cosine}");
    }

    #[test]
    fn ground_checks_its_values_and_is_seen_from_above_only() {
        assert!(Ground::new(f64::NAN, [0.5; 3]).is_err());
        assert!(Ground::new(0.0, [0.5, 1.2, 0.5]).is_err());
        let g = Ground::new(-1.0, [0.2, 0.4, 0.6]).unwrap();
        assert!(g.is_coloured());
        let down = DVec3::new(0.6, 0.0, -0.8);
        assert!((g.hit(DVec3::new(0.0, 0.0, 3.0), down).unwrap() - 5.0).abs() < 1e-12);
        assert_eq!(g.hit(DVec3::new(0.0, 0.0, 3.0), -down), None);
        assert_eq!(g.hit(DVec3::new(0.0, 0.0, -2.0), down), None);
    }

    #[test]
    fn patches_cover_the_footprint_and_the_shadow() {
        let grid = Grid::new([8, 8, 4], 1.0).unwrap();
        let ground = Ground::new(0.0, [0.5; 3]).unwrap();
        // Sun 45° up from +x: the shadow falls toward −x... light travels toward +x and down.
        let sun = Light::Directional {
            direction: DVec3::new(1.0, 0.0, -1.0).normalize(),
            irradiance: 1.0,
        };
        let p = GroundPatches::covering(&ground, &grid, &[sun]);
        let [x0, y0] = p.origin();
        let x1 = x0 + p.dims()[0] as f64 * p.size();
        assert!(x0 <= -4.0 && y0 <= -4.0, "{p:?}");
        // The top's shadow reaches 4 beyond the far side, plus the margin.
        assert!(x1 >= 8.0 + 4.0, "{p:?}");
        assert!(p.size() >= 1.0);
    }

    #[test]
    fn an_empty_medium_leaves_the_ground_unshadowed() {
        let grid = Grid::new([4, 4, 4], 1.0).unwrap();
        let ground = Ground::new(-1.0, [0.5; 3]).unwrap();
        let sun = Light::Directional {
            direction: DVec3::new(0.0, 0.6, -0.8),
            irradiance: 2.0,
        };
        let env = Environment::uniform(0.3).unwrap();
        let patches = GroundPatches::covering(&ground, &grid, &[sun]);
        let sigma = vec![0.0f32; 64];
        let e = patches
            .uncollided_irradiance(&ground, &grid, &[&sigma], &[sun], Some(&env))
            .unwrap();
        let e = &e[0];
        let want = 2.0 * 0.8 + PI * 0.3;
        assert!(e.iter().all(|v| (v - want).abs() < 1e-9 * want));
        // And a dense medium shadows the patch under it.
        let dense = vec![50.0f32; 64];
        let e = patches
            .uncollided_irradiance(&ground, &grid, &[&dense], &[sun], None)
            .unwrap();
        let e = &e[0];
        let under = (0..patches.count())
            .find(|&i| {
                let c = patches.centre(i, -1.0);
                (c.x - 1.5).abs() < 0.1 && (c.y - 2.5).abs() < 0.1
            })
            .unwrap();
        assert!(e[under] < 1e-6, "{}", e[under]);
        // A cloud that glows with Q everywhere in a thick layer: E → π Q / σ from below.
        let glow = patches
            .scattered_irradiance(&ground, &grid, &dense, &|_, _| 50.0 * 0.1)
            .unwrap();
        let v = glow[under];
        assert!(v > 0.0 && v <= PI * 0.1 * 1.0001, "{v}");
    }

    #[test]
    fn coarse_patches_cover_the_same_region_and_resample_linear_fields() {
        let fine = GroundPatches::new([-3.0, 2.0], 0.5, [100, 70]).unwrap();
        let coarse = fine.coarsened(16);
        assert!(coarse.dims()[0] <= 16 && coarse.dims()[1] <= 16);
        assert_eq!(coarse.index_of(-3.0, 2.0), Some(0));
        assert_eq!(coarse.index_of(-3.1, 2.0), None);
        assert_eq!(coarse.index_of(-3.0 + 60.0, 2.0), None);
        let f = |x: f64, y: f64| 1.0 + 0.5 * x - 0.25 * y;
        let values: Vec<f64> = (0..coarse.count())
            .map(|i| {
                let c = coarse.centre(i, 0.0);
                f(c.x, c.y)
            })
            .collect();
        let back = fine.resample(&coarse, &values);
        // Exact between the coarse centres (clamped beyond the outer ones).
        let c = fine.centre(40 + 100 * 30, 0.0);
        assert!((back[40 + 100 * 30] - f(c.x, c.y)).abs() < 1e-9);
    }

    #[test]
    fn radiance_is_bilinear_on_the_patches_and_unshadowed_beyond() {
        let ground = Ground::new(0.0, [0.5; 3]).unwrap();
        let patches = GroundPatches::new([0.0, 0.0], 1.0, [2, 1]).unwrap();
        let sun = Light::Directional {
            direction: DVec3::new(0.0, 0.0, -1.0),
            irradiance: PI,
        };
        let g = GroundRadiance::new(ground, patches, vec![vec![1.0, 3.0]], vec![sun], vec![0.0])
            .unwrap();
        assert!((g.radiance_at(DVec3::new(1.0, 0.5, 0.0), 0) - 2.0).abs() < 1e-12);
        assert!((g.radiance_at(DVec3::new(0.2, 0.5, 0.0), 0) - 1.0).abs() < 1e-12);
        assert!((g.radiance_at(DVec3::new(5.0, 5.0, 0.0), 0) - 0.5).abs() < 1e-12);
        assert!(g.max_radiance(0) >= 3.0);
        assert!(GroundRadiance::new(ground, patches, vec![vec![1.0]], vec![], vec![0.0]).is_err());
        assert!(
            GroundRadiance::new(ground, patches, vec![vec![1.0, -1.0]], vec![], vec![0.0]).is_err()
        );
    }
}
