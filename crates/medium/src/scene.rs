//! Scene files (TOML, `docs/scene-format.md`) validated into a [`Scene`].
//!
//! Parsing happens in two stages, as in ripgrep's flags: serde reads the raw file into
//! structs that mirror the TOML exactly (unknown keys refused), then validation turns them
//! into the high-level [`Scene`] with a loaded [`Medium`], naming the file and key of the
//! first problem it finds.

use std::path::PathBuf;

use glam::DVec3;
use serde::{Deserialize, Serialize};

use crate::{Light, Medium};

/// A validated scene: the medium, its lighting, how to solve it and how to look at it.
#[derive(Clone, Debug)]
pub struct Scene {
    pub medium: Medium,
    pub lights: Vec<Light>,
    /// Background radiance `I0` seen through the volume.
    pub background: f64,
    pub solve: SolveSettings,
    pub render: RenderSettings,
    pub cameras: Vec<CameraSpec>,
    /// Where the scene came from (a file, or the built-in default).
    pub origin: SceneOrigin,
}

#[derive(Clone, Debug, PartialEq, Eq)]
pub enum SceneOrigin {
    File(PathBuf),
    BuiltIn(&'static str),
}

/// The multiple-scattering method of `[solve] method`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum SolveMethod {
    DiscreteOrdinates,
    Zonal,
    ZonalHierarchical,
    SingleScatter,
    None,
}

/// The linear iteration of `[solve] iteration`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum IterationMethod {
    Jacobi,
    GaussSeidel,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SolveSettings {
    pub method: SolveMethod,
    /// Direction bins (discrete ordinates only): `6 n²` for `n = 1..=8`; 96 is Max's set.
    pub bins: usize,
    pub iteration: IterationMethod,
    /// Relative residual `‖g − E − aFg‖ / ‖E‖` at which to stop.
    pub tolerance: f64,
    pub max_iterations: usize,
}

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

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RenderSettings {
    pub model: OpticalModel,
    /// PNG exposure: pixel value = 1 − exp(−exposure · radiance), then sRGB.
    pub exposure: f64,
    /// Stratified samples per pixel.
    pub spp: u32,
}

#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "kebab-case")]
pub enum Projection {
    Perspective { fov_y_degrees: f64 },
    /// Orthographic with the given world-space image height.
    Orthographic { height: f64 },
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CameraSpec {
    pub name: String,
    pub eye: DVec3,
    pub target: DVec3,
    pub up: DVec3,
    pub projection: Projection,
    pub width: u32,
    pub height: u32,
}
