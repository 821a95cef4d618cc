//! The ground under the volume in a solve: the light that reaches it unscattered (once per
//! scene, on the data grid), and the coupling of its patches with the medium in each
//! channel's solve.
//!
//! The ground and the medium form one linear system: the medium's scattered light lights the
//! ground, whose reflected radiance `A E / π` lights the medium from below. A solve iterates
//! it by blocks (ground–medium Gauss–Seidel): solve the medium with the ground's current
//! light entering from below, gather the scattered irradiance on every patch, update the
//! ground, and solve again from the last solution, until the ground's radiance changes by
//! less than [`GROUND_TOLERANCE`]. Each block's error shrinks by the fraction of the ground's
//! light the medium returns times its albedo (`A · R`, below 0.3 for a cloud over grass), and
//! each later solve starts where the last stopped, so it takes few iterations.

use std::f64::consts::PI;

use anyhow::{Context, Result};
use glam::DVec3;
use medium::ground::{environment_irradiance, Ground, GroundPatches, GroundRadiance};
use medium::{Light, Medium};
use scene::Scene;

/// The largest relative change (to the brightest patch) of the ground's radiance at which
/// the ground–medium iteration stops.
pub const GROUND_TOLERANCE: f64 = 1e-3;

/// Most ground–medium rounds (each a solve from the last one's solution).
pub const MAX_GROUND_ROUNDS: usize = 30;

/// A scene's ground as a solve starts it: its patches and, per channel, the irradiance of the
/// light that reaches them unscattered (through the data grid, so shadows are as sharp as the
/// data) and the environment's irradiance beyond them.
#[derive(Clone, Debug)]
pub struct GroundSetup {
    ground: Ground,
    patches: GroundPatches,
    lights: Vec<Light>,
    uncollided: Vec<Vec<f64>>,
    sky_irradiance: Vec<f64>,
}

impl GroundSetup {
    /// The ground of `scene`, if it has one, lit by its lights and environment through its
    /// medium.
    pub fn new(scene: &Scene) -> Result<Option<GroundSetup>> {
        let Some(ground) = scene.ground else {
            return Ok(None);
        };
        let medium = &scene.medium;
        let channels = medium.channels().len();
        let patches = GroundPatches::covering(&ground, medium.grid(), &scene.lights);
        let environment = scene.environment.as_ref();
        let sigma_t: Vec<&[f32]> = medium.channels().iter().map(|c| &c.sigma_t[..]).collect();
        let uncollided = patches
            .uncollided_irradiance(&ground, medium.grid(), &sigma_t, &scene.lights, environment)
            .context("the ground's unscattered light")?;
        Ok(Some(GroundSetup {
            ground,
            patches,
            lights: scene.lights.clone(),
            uncollided,
            sky_irradiance: (0..channels)
                .map(|c| environment.map_or(0.0, |e| environment_irradiance(e, c, channels)))
                .collect(),
        }))
    }

    /// The part of channel `c` (of the medium's channels) a channel's solve couples.
    pub fn channel(&self, c: usize) -> ChannelGround<'_> {
        let channels = self.uncollided.len();
        ChannelGround {
            setup: self,
            albedo: self.ground.albedo(c, channels),
            c,
        }
    }

    /// The solved ground, from each channel's reflected radiance per patch.
    pub fn finish(&self, radiance: Vec<Vec<f32>>) -> Result<GroundRadiance> {
        Ok(GroundRadiance::new(
            self.ground,
            self.patches,
            radiance,
            self.lights.clone(),
            self.sky_irradiance.clone(),
        )?)
    }
}

/// One channel of a ground in a solve.
pub struct ChannelGround<'a> {
    setup: &'a GroundSetup,
    albedo: f64,
    c: usize,
}

impl ChannelGround<'_> {
    pub fn patches(&self) -> &GroundPatches {
        &self.setup.patches
    }

    /// The reflected radiance per patch, `A (E_unscattered + E_scattered) / π`.
    pub fn radiance(&self, scattered: Option<&[f64]>) -> Vec<f32> {
        let unc = &self.setup.uncollided[self.c];
        (0..unc.len())
            .map(|i| {
                let e = unc[i] + scattered.map_or(0.0, |s| s[i]);
                (self.albedo / PI * e.max(0.0)) as f32
            })
            .collect()
    }

    /// The ground of this channel alone with reflected radiance `values` per patch, to look
    /// up (`radiance_at(p, 0)`).
    pub fn lookup(&self, values: Vec<f32>) -> Result<GroundRadiance> {
        let ground = Ground::new(self.setup.ground.height(), [self.albedo; 3])?;
        Ok(GroundRadiance::new(
            ground,
            self.setup.patches,
            vec![values],
            self.setup.lights.clone(),
            vec![self.setup.sky_irradiance[self.c]],
        )?)
    }

    /// The ground's irradiance on its patches from the medium's scattered light, with
    /// `source(cell, travel)` the radiance per unit length a cell of `medium` (the transport
    /// grid's) sends along `travel`.
    pub fn scattered_irradiance(
        &self,
        medium: &Medium,
        c: usize,
        source: &(dyn Fn(usize, DVec3) -> f64 + Sync),
    ) -> Result<Vec<f64>> {
        Ok(self.setup.patches.scattered_irradiance(
            &self.setup.ground,
            medium.grid(),
            &medium.channels()[c].sigma_t,
            source,
        )?)
    }
}

/// The largest change between two ground radiances relative to the brightest patch.
pub fn relative_change(old: &[f32], new: &[f32]) -> f64 {
    let top = new.iter().fold(0.0f64, |m, &v| m.max(v as f64));
    if top == 0.0 {
        return 0.0;
    }
    old.iter()
        .zip(new)
        .fold(0.0f64, |m, (&a, &b)| m.max((a as f64 - b as f64).abs()))
        / top
}
