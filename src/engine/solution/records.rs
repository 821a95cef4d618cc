//! NOTE: a change to any record's fields changes the file layout: bump FORMAT_VERSION in
//! container.rs and refresh the golden file (`VOLRAD_BLESS=1 cargo test --test it solution_file`,
//! which rewrites `tests/data/solution-golden/`).
//!
//! The metadata records of a solution file: plain structs and enums owned by the solution
//! module that spell out exactly what the file stores. They, and not the libraries' types,
//! derive `Serialize`/`Deserialize` for the file, so adding a field to a library type (a
//! `SolveReport`, a `Light`) cannot change the bytes behind `FORMAT_VERSION`'s back: it stops
//! compiling here instead, where the mapping must be extended on purpose.
//!
//! The encoding is bincode 2 (standard configuration) of these types: fields in declaration
//! order, enums by variant index. So the order of fields *and of enum variants* is part of
//! the layout, as are the array names that `super` writes beside the metadata. Integers the
//! libraries hold as `usize` are stored as `u64`.
//!
//! Each record is made from its library value with `From<&Library>` (or a `record` function)
//! and turned back with a checked `into_library`, which goes through the library's own
//! checks (`Grid::new`, `PhaseFunction::validate`, `Light::validated`, the bin layout of
//! `formfactor::ordinates`) and refuses what they refuse, with a message for
//! [`super::SolutionError::Inconsistent`].

use glam::DVec3;
use medium::environment::{EnvironmentSpec, SkySpec};
use medium::ground::{Ground, GroundPatches, GroundRadiance};
use medium::light_pass::LightEnergy;
use medium::{Environment, Grid, Interpolation, Light, PhaseFunction};
use montecarlo::two_pass::{PhotonEnergy, TwoPassSolution};
use scene::{CameraSpec, OpticalModel, Projection, RenderSettings, SolveMethod};
use serde::{Deserialize, Serialize};
use solver::{SolveReport, StopReason};

use super::StoredBins;

/// A stored count back to `usize`, refusing what this machine cannot index.
fn to_usize(v: u64, what: &str) -> Result<usize, String> {
    usize::try_from(v).map_err(|_| format!("{what} = {v} does not fit this machine's usize"))
}

fn vec3(v: DVec3) -> [f64; 3] {
    v.to_array()
}

/// The whole metadata block of a solution file.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct MetaRecord {
    /// The `volrad` version that wrote the file (informational; never checked).
    pub volrad_version: String,
    pub scene_hash: String,
    pub scene_origin: String,
    pub method: SolveMethodRecord,
    pub grid: GridRecord,
    pub phase: PhaseRecord,
    pub interpolation: InterpolationRecord,
    /// Whether the array `data` (the raw data values) is present.
    pub has_data: bool,
    pub lights: Vec<LightRecord>,
    /// The scene's environment light, when it has one.
    pub environment: Option<EnvironmentRecord>,
    pub background: f64,
    /// The ground, when the scene has one; its reflected radiance per patch is the array
    /// `ground/{c}` of each channel.
    pub ground: Option<GroundRecord>,
    pub render: RenderRecord,
    pub cameras: Vec<CameraRecord>,
    pub bins: Option<BinsRecord>,
    /// Data cells per side of a transport cell: the scattered fields and the emitters'
    /// fluence are stored on the transport grid (1: the data grid).
    pub transport_scale: u64,
    /// Transport cells per side of a data cell (`transport_refinement`; 1: not split). At
    /// most one of this and `transport_scale` is above 1.
    pub transport_split: u64,
    pub channels: Vec<ChannelRecord>,
}

/// [`Environment`]: a uniform radiance per channel, or the parameters of a sky (which the
/// library rebuilds, so the file stores what the scene said).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub enum EnvironmentRecord {
    Uniform {
        radiance: [f64; 3],
    },
    Sky {
        turbidity: f64,
        sun_elevation_degrees: f64,
        sun_azimuth_degrees: f64,
        up: [f64; 3],
        sun_irradiance: f64,
        sky_fraction: f64,
        ground_albedo: f64,
    },
    /// An environment map; its texels (linear RGB, row 0 the zenith) are the array
    /// `environment/map`, `width × height × 3` values.
    Map {
        width: u64,
        height: u64,
        up: [f64; 3],
        rotation_degrees: f64,
        scale: f64,
    },
}

impl From<&Environment> for EnvironmentRecord {
    fn from(e: &Environment) -> Self {
        match e.spec() {
            EnvironmentSpec::Uniform { radiance } => EnvironmentRecord::Uniform { radiance },
            EnvironmentSpec::Sky(s) => EnvironmentRecord::Sky {
                turbidity: s.turbidity,
                sun_elevation_degrees: s.sun_elevation_degrees,
                sun_azimuth_degrees: s.sun_azimuth_degrees,
                up: vec3(s.up),
                sun_irradiance: s.sun_irradiance,
                sky_fraction: s.sky_fraction,
                ground_albedo: s.ground_albedo,
            },
            EnvironmentSpec::Map(m) => EnvironmentRecord::Map {
                width: m.width() as u64,
                height: m.height() as u64,
                up: vec3(m.up()),
                rotation_degrees: m.rotation_degrees(),
                scale: m.scale(),
            },
        }
    }
}

/// The texels of an environment map as the array `environment/map` stores them.
pub fn environment_map_array(e: &Environment) -> Option<Vec<f32>> {
    match e.spec() {
        EnvironmentSpec::Map(m) => Some(m.texels().iter().flatten().copied().collect()),
        _ => None,
    }
}

/// [`GroundRadiance`] without its per-patch values (the arrays `ground/{c}`) and lights (the
/// solution's).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct GroundRecord {
    pub height: f64,
    pub albedo: [f64; 3],
    pub origin: [f64; 2],
    pub patch_size: f64,
    pub dims: [u64; 2],
    /// The environment's irradiance beyond the patches, per channel.
    pub sky_irradiance: Vec<f64>,
}

impl From<&GroundRadiance> for GroundRecord {
    fn from(g: &GroundRadiance) -> Self {
        let p = g.patches();
        GroundRecord {
            height: g.ground().height(),
            albedo: g.ground().albedo_rgb(),
            origin: p.origin(),
            patch_size: p.size(),
            dims: p.dims().map(|d| d as u64),
            sky_irradiance: g.sky_irradiance().to_vec(),
        }
    }
}

impl GroundRecord {
    /// Through [`GroundRadiance::new`]; `patch_array(c, len)` gives channel `c`'s values
    /// (checked to hold `len`).
    pub fn into_library(
        self,
        lights: &[Light],
        mut patch_array: impl FnMut(usize, usize) -> Result<Vec<f32>, String>,
    ) -> Result<GroundRadiance, String> {
        let ground = Ground::new(self.height, self.albedo).map_err(|e| e.to_string())?;
        let dims = [
            to_usize(self.dims[0], "ground patches")?,
            to_usize(self.dims[1], "ground patches")?,
        ];
        let patches =
            GroundPatches::new(self.origin, self.patch_size, dims).map_err(|e| e.to_string())?;
        if !matches!(self.sky_irradiance.len(), 1 | 3) {
            return Err(format!(
                "the ground has {} channels (1 or 3)",
                self.sky_irradiance.len()
            ));
        }
        let radiance = (0..self.sky_irradiance.len())
            .map(|c| patch_array(c, patches.count()))
            .collect::<Result<Vec<_>, _>>()?;
        GroundRadiance::new(
            ground,
            patches,
            radiance,
            lights.to_vec(),
            self.sky_irradiance,
        )
        .map_err(|e| e.to_string())
    }
}

impl EnvironmentRecord {
    /// Through [`Environment::new`]; `map_array(len)` gives a map's texels (the array
    /// `environment/map`, checked to hold `len` values).
    pub fn into_library(
        self,
        map_array: impl FnOnce(usize) -> Result<Vec<f32>, String>,
    ) -> Result<Environment, String> {
        Environment::new(match self {
            EnvironmentRecord::Map {
                width,
                height,
                up,
                rotation_degrees,
                scale,
            } => {
                let (w, h) = (
                    to_usize(width, "map width")?,
                    to_usize(height, "map height")?,
                );
                let len = w
                    .checked_mul(h)
                    .filter(|&n| n <= medium::environment_map::MAX_TEXELS)
                    .ok_or_else(|| format!("an environment map of {w} × {h} texels"))?;
                let values = map_array(3 * len)?;
                let map = medium::environment_map::EnvironmentMap::from_interleaved(
                    w,
                    h,
                    3,
                    &values,
                    DVec3::from_array(up),
                    rotation_degrees,
                    scale,
                )
                .map_err(|e| e.to_string())?;
                EnvironmentSpec::Map(std::sync::Arc::new(map))
            }
            EnvironmentRecord::Uniform { radiance } => EnvironmentSpec::Uniform { radiance },
            EnvironmentRecord::Sky {
                turbidity,
                sun_elevation_degrees,
                sun_azimuth_degrees,
                up,
                sun_irradiance,
                sky_fraction,
                ground_albedo,
            } => EnvironmentSpec::Sky(SkySpec {
                turbidity,
                sun_elevation_degrees,
                sun_azimuth_degrees,
                up: DVec3::from_array(up),
                sun_irradiance,
                sky_fraction,
                ground_albedo,
            }),
        })
        .map_err(|e| e.to_string())
    }
}

/// What one colour channel stores beside its named arrays.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ChannelRecord {
    /// A uniform albedo, or `None` when the array `albedo/{c}` holds one per cell.
    pub albedo: Option<f32>,
    /// A uniform emission, or `None` when the array `emission/{c}` holds one per cell.
    pub emission: Option<f32>,
    /// Whether the array `emitted_fluence/{c}` (the emitter pass's fluence) is present.
    pub has_emitted_fluence: bool,
    /// Whether the arrays `emitted_beam/{c}` (discrete ordinates' emitters' first scattering,
    /// six values per transport cell), `emitted_bins_kept/{c}` and `emitted_bins/{c}` (the
    /// widest-lit cells' light in direction bins) are present.
    pub has_emitted_beam: bool,
    /// The light pass's power bookkeeping, one per light in the scene's order.
    pub light_energy: Vec<LightEnergyRecord>,
    pub field: FieldKind,
    pub report: Option<SolveReportRecord>,
    /// The two-pass method's stored result (its arrays are small: one value per optical
    /// voxel and direction bin), present exactly when `field` is [`FieldKind::TwoPass`].
    pub two_pass: Option<TwoPassRecord>,
}

/// Which scattered field a channel stores (and so which arrays it has).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum FieldKind {
    /// No arrays: single scattering only.
    None,
    /// `source/{c}` and `higher_order/{c}`, one value per cell.
    Isotropic,
    /// `fluence/{c}`, one value per cell; `higher_order_kept/{c}`, per cell 1 if it has a
    /// row of higher orders (0 if they are all zero), and `higher_order/{c}`, those rows (one
    /// value per direction bin) in cell order.
    Binned,
    /// No arrays: the result is in [`ChannelRecord::two_pass`].
    TwoPass,
}

/// [`Grid`]: dims and cell size.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct GridRecord {
    pub dims: [u64; 3],
    pub cell_size: f64,
}

impl From<&Grid> for GridRecord {
    fn from(g: &Grid) -> Self {
        GridRecord {
            dims: g.dims.map(|d| d as u64),
            cell_size: g.cell_size,
        }
    }
}

impl GridRecord {
    /// Through [`Grid::new`].
    pub fn into_library(self) -> Result<Grid, String> {
        let [x, y, z] = self.dims;
        let dims = [
            to_usize(x, "grid dims[0]")?,
            to_usize(y, "grid dims[1]")?,
            to_usize(z, "grid dims[2]")?,
        ];
        Grid::new(dims, self.cell_size).map_err(|e| e.to_string())
    }
}

/// [`PhaseFunction`] with its parameters.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub enum PhaseRecord {
    Isotropic,
    HenyeyGreenstein { g: f64 },
    LambertianSphere,
    TwoLobe { r: f64, g1: f64, g2: f64 },
}

impl From<&PhaseFunction> for PhaseRecord {
    fn from(p: &PhaseFunction) -> Self {
        match *p {
            PhaseFunction::Isotropic => PhaseRecord::Isotropic,
            PhaseFunction::HenyeyGreenstein { g } => PhaseRecord::HenyeyGreenstein { g },
            PhaseFunction::LambertianSphere => PhaseRecord::LambertianSphere,
            PhaseFunction::TwoLobe { r, g1, g2 } => PhaseRecord::TwoLobe { r, g1, g2 },
        }
    }
}

impl PhaseRecord {
    /// Through [`PhaseFunction::validate`].
    pub fn into_library(self) -> Result<PhaseFunction, String> {
        let p = match self {
            PhaseRecord::Isotropic => PhaseFunction::Isotropic,
            PhaseRecord::HenyeyGreenstein { g } => PhaseFunction::HenyeyGreenstein { g },
            PhaseRecord::LambertianSphere => PhaseFunction::LambertianSphere,
            PhaseRecord::TwoLobe { r, g1, g2 } => PhaseFunction::TwoLobe { r, g1, g2 },
        };
        p.validate().map_err(|e| e.to_string())?;
        Ok(p)
    }
}

/// [`Interpolation`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum InterpolationRecord {
    Nearest,
    Trilinear,
}

impl From<&Interpolation> for InterpolationRecord {
    fn from(i: &Interpolation) -> Self {
        match i {
            Interpolation::Nearest => InterpolationRecord::Nearest,
            Interpolation::Trilinear => InterpolationRecord::Trilinear,
        }
    }
}

impl InterpolationRecord {
    pub fn into_library(self) -> Interpolation {
        match self {
            InterpolationRecord::Nearest => Interpolation::Nearest,
            InterpolationRecord::Trilinear => Interpolation::Trilinear,
        }
    }
}

/// [`Light`] with its fields (vectors as `[x, y, z]`).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub enum LightRecord {
    Directional {
        direction: [f64; 3],
        irradiance: f64,
    },
    Point {
        position: [f64; 3],
        intensity: f64,
    },
    Spot {
        position: [f64; 3],
        axis: [f64; 3],
        /// Radians.
        half_angle: f64,
        intensity: f64,
    },
}

impl From<&Light> for LightRecord {
    fn from(l: &Light) -> Self {
        match *l {
            Light::Directional {
                direction,
                irradiance,
            } => LightRecord::Directional {
                direction: vec3(direction),
                irradiance,
            },
            Light::Point {
                position,
                intensity,
            } => LightRecord::Point {
                position: vec3(position),
                intensity,
            },
            Light::Spot {
                position,
                axis,
                half_angle,
                intensity,
            } => LightRecord::Spot {
                position: vec3(position),
                axis: vec3(axis),
                half_angle,
                intensity,
            },
        }
    }
}

impl LightRecord {
    /// Checked by [`Light::validated`]; the stored values are returned as they are (the
    /// light was validated when its scene was read, and normalising its direction a second
    /// time could move the last bit, which renders from the file must not see).
    pub fn into_library(self) -> Result<Light, String> {
        let light = match self {
            LightRecord::Directional {
                direction,
                irradiance,
            } => Light::Directional {
                direction: DVec3::from_array(direction),
                irradiance,
            },
            LightRecord::Point {
                position,
                intensity,
            } => Light::Point {
                position: DVec3::from_array(position),
                intensity,
            },
            LightRecord::Spot {
                position,
                axis,
                half_angle,
                intensity,
            } => Light::Spot {
                position: DVec3::from_array(position),
                axis: DVec3::from_array(axis),
                half_angle,
                intensity,
            },
        };
        light.validated().map_err(|e| e.to_string())?;
        Ok(light)
    }
}

/// [`LightEnergy`]: one light's power bookkeeping in one channel.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct LightEnergyRecord {
    pub entering: f64,
    pub extinguished: f64,
    pub leaving: f64,
}

impl From<&LightEnergy> for LightEnergyRecord {
    fn from(e: &LightEnergy) -> Self {
        LightEnergyRecord {
            entering: e.entering,
            extinguished: e.extinguished,
            leaving: e.leaving,
        }
    }
}

impl LightEnergyRecord {
    pub fn into_library(self) -> LightEnergy {
        LightEnergy {
            entering: self.entering,
            extinguished: self.extinguished,
            leaving: self.leaving,
        }
    }
}

/// [`OpticalModel`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum OpticalModelRecord {
    AbsorptionOnly,
    EmissionOnly,
    EmissionAbsorption,
    SingleScatterUnshadowed,
    Scattering,
}

impl From<&OpticalModel> for OpticalModelRecord {
    fn from(m: &OpticalModel) -> Self {
        match m {
            OpticalModel::AbsorptionOnly => OpticalModelRecord::AbsorptionOnly,
            OpticalModel::EmissionOnly => OpticalModelRecord::EmissionOnly,
            OpticalModel::EmissionAbsorption => OpticalModelRecord::EmissionAbsorption,
            OpticalModel::SingleScatterUnshadowed => OpticalModelRecord::SingleScatterUnshadowed,
            OpticalModel::Scattering => OpticalModelRecord::Scattering,
        }
    }
}

impl OpticalModelRecord {
    pub fn into_library(self) -> OpticalModel {
        match self {
            OpticalModelRecord::AbsorptionOnly => OpticalModel::AbsorptionOnly,
            OpticalModelRecord::EmissionOnly => OpticalModel::EmissionOnly,
            OpticalModelRecord::EmissionAbsorption => OpticalModel::EmissionAbsorption,
            OpticalModelRecord::SingleScatterUnshadowed => OpticalModel::SingleScatterUnshadowed,
            OpticalModelRecord::Scattering => OpticalModel::Scattering,
        }
    }
}

/// [`RenderSettings`]: the scene's `[render]` section.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct RenderRecord {
    pub model: OpticalModelRecord,
    /// `None`: automatic exposure.
    pub exposure: Option<f64>,
    pub spp: u32,
}

impl From<&RenderSettings> for RenderRecord {
    fn from(r: &RenderSettings) -> Self {
        RenderRecord {
            model: (&r.model).into(),
            exposure: r.exposure,
            spp: r.spp,
        }
    }
}

impl RenderRecord {
    /// Refuses what no scene can state: `spp = 0` or a non-finite or negative exposure.
    pub fn into_library(self) -> Result<RenderSettings, String> {
        if self.spp == 0 {
            return Err("render spp is 0 (must be at least 1)".into());
        }
        if let Some(e) = self.exposure.filter(|e| !(e.is_finite() && *e >= 0.0)) {
            return Err(format!("render exposure {e} must be finite and ≥ 0"));
        }
        Ok(RenderSettings {
            model: self.model.into_library(),
            exposure: self.exposure,
            spp: self.spp,
        })
    }
}

/// [`Projection`] of a camera.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub enum ProjectionRecord {
    Perspective { fov_y_degrees: f64 },
    Orthographic { height: f64 },
}

impl From<&Projection> for ProjectionRecord {
    fn from(p: &Projection) -> Self {
        match *p {
            Projection::Perspective { fov_y_degrees } => {
                ProjectionRecord::Perspective { fov_y_degrees }
            }
            Projection::Orthographic { height } => ProjectionRecord::Orthographic { height },
        }
    }
}

impl ProjectionRecord {
    pub fn into_library(self) -> Projection {
        match self {
            ProjectionRecord::Perspective { fov_y_degrees } => {
                Projection::Perspective { fov_y_degrees }
            }
            ProjectionRecord::Orthographic { height } => Projection::Orthographic { height },
        }
    }
}

/// [`CameraSpec`]: a camera as the scene states it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CameraRecord {
    pub name: String,
    pub eye: [f64; 3],
    pub target: [f64; 3],
    pub up: [f64; 3],
    pub projection: ProjectionRecord,
    pub width: u32,
    pub height: u32,
}

impl From<&CameraSpec> for CameraRecord {
    fn from(c: &CameraSpec) -> Self {
        CameraRecord {
            name: c.name.clone(),
            eye: vec3(c.eye),
            target: vec3(c.target),
            up: vec3(c.up),
            projection: (&c.projection).into(),
            width: c.width,
            height: c.height,
        }
    }
}

impl CameraRecord {
    /// A `CameraSpec` is unchecked by design (gather's `Camera::from_spec` checks it when a
    /// view is rendered, naming the camera), so it is returned as stored.
    pub fn into_library(self) -> CameraSpec {
        CameraSpec {
            name: self.name,
            eye: DVec3::from_array(self.eye),
            target: DVec3::from_array(self.target),
            up: DVec3::from_array(self.up),
            projection: self.projection.into_library(),
            width: self.width,
            height: self.height,
        }
    }
}

/// [`SolveMethod`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum SolveMethodRecord {
    DiscreteOrdinates,
    Zonal,
    ZonalHierarchical,
    SingleScatter,
    TwoPass,
    None,
}

impl From<&SolveMethod> for SolveMethodRecord {
    fn from(m: &SolveMethod) -> Self {
        match m {
            SolveMethod::DiscreteOrdinates => SolveMethodRecord::DiscreteOrdinates,
            SolveMethod::Zonal => SolveMethodRecord::Zonal,
            SolveMethod::ZonalHierarchical => SolveMethodRecord::ZonalHierarchical,
            SolveMethod::SingleScatter => SolveMethodRecord::SingleScatter,
            SolveMethod::TwoPass => SolveMethodRecord::TwoPass,
            SolveMethod::None => SolveMethodRecord::None,
        }
    }
}

impl SolveMethodRecord {
    pub fn into_library(self) -> SolveMethod {
        match self {
            SolveMethodRecord::DiscreteOrdinates => SolveMethod::DiscreteOrdinates,
            SolveMethodRecord::Zonal => SolveMethod::Zonal,
            SolveMethodRecord::ZonalHierarchical => SolveMethod::ZonalHierarchical,
            SolveMethodRecord::SingleScatter => SolveMethod::SingleScatter,
            SolveMethodRecord::TwoPass => SolveMethod::TwoPass,
            SolveMethodRecord::None => SolveMethod::None,
        }
    }
}

/// [`StoredBins`]: the discrete-ordinates direction bins a render looks radiance up in.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct BinsRecord {
    /// `n` of the `6 n²` cube-face construction.
    pub face_resolution: u64,
    pub directions: Vec<[f64; 3]>,
    pub solid_angles: Vec<f64>,
}

impl From<&StoredBins> for BinsRecord {
    fn from(b: &StoredBins) -> Self {
        BinsRecord {
            face_resolution: b.face_resolution as u64,
            directions: b.directions.clone(),
            solid_angles: b.solid_angles.clone(),
        }
    }
}

impl BinsRecord {
    /// Refuses a face resolution `formfactor::ordinates` cannot build and lists whose length
    /// is not `6 n²`.
    pub fn into_library(self) -> Result<StoredBins, String> {
        let n = to_usize(self.face_resolution, "bins face resolution")?;
        if !(1..=formfactor::ordinates::bins::MAX_FACE_DIVISIONS).contains(&n) {
            return Err(format!(
                "bins face resolution {n} is outside 1..={}",
                formfactor::ordinates::bins::MAX_FACE_DIVISIONS
            ));
        }
        let count = 6 * n * n;
        if self.directions.len() != count || self.solid_angles.len() != count {
            return Err(format!(
                "{} bin directions and {} solid angles for face resolution {n} (expected {count})",
                self.directions.len(),
                self.solid_angles.len()
            ));
        }
        Ok(StoredBins {
            face_resolution: n,
            directions: self.directions,
            solid_angles: self.solid_angles,
        })
    }
}

/// [`StopReason`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum StopReasonRecord {
    Converged,
    MaxIterations,
    Cancelled,
    Diverged,
    Stagnated,
}

impl From<&StopReason> for StopReasonRecord {
    fn from(s: &StopReason) -> Self {
        match s {
            StopReason::Converged => StopReasonRecord::Converged,
            StopReason::MaxIterations => StopReasonRecord::MaxIterations,
            StopReason::Cancelled => StopReasonRecord::Cancelled,
            StopReason::Diverged => StopReasonRecord::Diverged,
            StopReason::Stagnated => StopReasonRecord::Stagnated,
        }
    }
}

impl StopReasonRecord {
    pub fn into_library(self) -> StopReason {
        match self {
            StopReasonRecord::Converged => StopReason::Converged,
            StopReasonRecord::MaxIterations => StopReason::MaxIterations,
            StopReasonRecord::Cancelled => StopReason::Cancelled,
            StopReasonRecord::Diverged => StopReason::Diverged,
            StopReasonRecord::Stagnated => StopReason::Stagnated,
        }
    }
}

/// [`SolveReport`]: every field of the record of a linear solve.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SolveReportRecord {
    /// Canonical iteration string, e.g. `"sor:1.5"`.
    pub method: String,
    pub iterations: u64,
    pub converged: bool,
    pub final_residual: f64,
    pub residual_history: Vec<f64>,
    pub seconds: f64,
    pub seconds_per_iteration: f64,
    pub operator_applications: u64,
    pub operator_sweeps: u64,
    pub cancelled: bool,
    pub stop_reason: StopReasonRecord,
}

impl From<&SolveReport> for SolveReportRecord {
    fn from(r: &SolveReport) -> Self {
        SolveReportRecord {
            method: r.method.clone(),
            iterations: r.iterations as u64,
            converged: r.converged,
            final_residual: r.final_residual,
            residual_history: r.residual_history.clone(),
            seconds: r.seconds,
            seconds_per_iteration: r.seconds_per_iteration,
            operator_applications: r.operator_applications as u64,
            operator_sweeps: r.operator_sweeps as u64,
            cancelled: r.cancelled,
            stop_reason: (&r.stop_reason).into(),
        }
    }
}

impl SolveReportRecord {
    /// The report is a record of what happened, not an input: only the counts are checked
    /// (they must fit a `usize`).
    pub fn into_library(self) -> Result<SolveReport, String> {
        Ok(SolveReport {
            method: self.method,
            iterations: to_usize(self.iterations, "report iterations")?,
            converged: self.converged,
            final_residual: self.final_residual,
            residual_history: self.residual_history,
            seconds: self.seconds,
            seconds_per_iteration: self.seconds_per_iteration,
            operator_applications: to_usize(
                self.operator_applications,
                "report operator applications",
            )?,
            operator_sweeps: to_usize(self.operator_sweeps, "report operator sweeps")?,
            cancelled: self.cancelled,
            stop_reason: self.stop_reason.into_library(),
        })
    }
}

/// [`PhotonEnergy`]: the two-pass energetization's power bookkeeping.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct PhotonEnergyRecord {
    pub emitted: f64,
    pub entering: f64,
    pub absorbed: f64,
    pub escaped: f64,
    pub scattered: f64,
    pub stored: f64,
    pub photons: u64,
    pub interactions: u64,
}

impl From<&PhotonEnergy> for PhotonEnergyRecord {
    fn from(e: &PhotonEnergy) -> Self {
        PhotonEnergyRecord {
            emitted: e.emitted,
            entering: e.entering,
            absorbed: e.absorbed,
            escaped: e.escaped,
            scattered: e.scattered,
            stored: e.stored,
            photons: e.photons,
            interactions: e.interactions,
        }
    }
}

impl PhotonEnergyRecord {
    pub fn into_library(self) -> PhotonEnergy {
        PhotonEnergy {
            emitted: self.emitted,
            entering: self.entering,
            absorbed: self.absorbed,
            escaped: self.escaped,
            scattered: self.scattered,
            stored: self.stored,
            photons: self.photons,
            interactions: self.interactions,
        }
    }
}

/// [`TwoPassSolution`]: the two-pass method's stored result for one channel.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TwoPassRecord {
    pub grid: GridRecord,
    pub storage_factor: u64,
    pub optical_dims: [u64; 3],
    /// The direction bins: `n_theta` bands times `n_phi` sectors.
    pub n_theta: u64,
    pub n_phi: u64,
    /// Per optical voxel and outgoing bin (`o · bins + l`). Stored as the array
    /// `two_pass/{channel}/voxel_source`, not in the metadata (it is megabytes to gigabytes).
    #[serde(skip)]
    pub voxel_source: Vec<f32>,
    /// Per density cell; stored as the array `two_pass/{channel}/cell_share`.
    #[serde(skip)]
    pub cell_share: Vec<f32>,
    pub energy: PhotonEnergyRecord,
    pub include_first_bounce: bool,
    pub max_source: f64,
}

impl From<&TwoPassSolution> for TwoPassRecord {
    fn from(t: &TwoPassSolution) -> Self {
        TwoPassRecord {
            grid: (&t.grid).into(),
            storage_factor: t.storage_factor as u64,
            optical_dims: t.optical_dims.map(|d| d as u64),
            n_theta: t.bins.n_theta as u64,
            n_phi: t.bins.n_phi as u64,
            voxel_source: t.voxel_source.clone(),
            cell_share: t.cell_share.clone(),
            energy: (&t.energy).into(),
            include_first_bounce: t.include_first_bounce,
            max_source: t.max_source,
        }
    }
}

impl TwoPassRecord {
    /// The length of `voxel_source` the record's dims and bins imply (`None` on overflow);
    /// the reader takes the array of that length, and `into_library` checks it again.
    pub fn voxel_source_len(&self) -> Option<usize> {
        let voxels = self
            .optical_dims
            .iter()
            .try_fold(1u64, |acc, &d| acc.checked_mul(d))?;
        let values = voxels.checked_mul(self.n_theta)?.checked_mul(self.n_phi)?;
        usize::try_from(values).ok()
    }

    /// Checks what `energetize` guarantees and the render's lookups index by: the grid
    /// ([`Grid::new`]), a storage factor of at least 1 with the optical dims it implies, at
    /// least one direction bin, one source value per optical voxel and bin, one share per
    /// cell, and a finite, non-negative source bound.
    pub fn into_library(self) -> Result<TwoPassSolution, String> {
        let grid = self.grid.into_library()?;
        let storage_factor = to_usize(self.storage_factor, "two-pass storage factor")?;
        if storage_factor == 0 {
            return Err("two-pass storage factor is 0".into());
        }
        let optical_dims = grid.dims.map(|d| d.div_ceil(storage_factor));
        if self.optical_dims != optical_dims.map(|d| d as u64) {
            return Err(format!(
                "two-pass optical dims {:?} do not match grid dims {:?} at storage factor \
                 {storage_factor} (expected {optical_dims:?})",
                self.optical_dims, grid.dims
            ));
        }
        let bins = montecarlo::DirectionBins {
            n_theta: to_usize(self.n_theta, "two-pass n_theta")?,
            n_phi: to_usize(self.n_phi, "two-pass n_phi")?,
        };
        let bin_count = bins
            .n_theta
            .checked_mul(bins.n_phi)
            .filter(|&m| m > 0)
            .ok_or_else(|| {
                format!(
                    "two-pass direction bins {} × {} are not a usable count",
                    bins.n_theta, bins.n_phi
                )
            })?;
        let voxels = optical_dims[0] * optical_dims[1] * optical_dims[2];
        let expected = voxels.checked_mul(bin_count);
        if expected != Some(self.voxel_source.len()) {
            return Err(format!(
                "two-pass source has {} values for {voxels} optical voxels × {bin_count} bins",
                self.voxel_source.len()
            ));
        }
        if self.cell_share.len() != grid.cell_count() {
            return Err(format!(
                "two-pass cell shares have {} values for {} cells",
                self.cell_share.len(),
                grid.cell_count()
            ));
        }
        if !(self.max_source.is_finite() && self.max_source >= 0.0) {
            return Err(format!(
                "two-pass source bound {} must be finite and ≥ 0",
                self.max_source
            ));
        }
        Ok(TwoPassSolution {
            grid,
            storage_factor,
            optical_dims,
            bins,
            voxel_source: self.voxel_source,
            cell_share: self.cell_share,
            energy: self.energy.into_library(),
            include_first_bounce: self.include_first_bounce,
            max_source: self.max_source,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_library_value_survives_its_record_exactly() {
        let grid = Grid::new([3, 2, 5], 0.125).unwrap();
        assert_eq!(GridRecord::from(&grid).into_library().unwrap(), grid);

        for p in [
            PhaseFunction::Isotropic,
            PhaseFunction::HenyeyGreenstein { g: 0.6 },
            PhaseFunction::LambertianSphere,
            PhaseFunction::TwoLobe {
                r: 0.7,
                g1: 0.8,
                g2: -0.3,
            },
        ] {
            assert_eq!(PhaseRecord::from(&p).into_library().unwrap(), p);
        }
        for i in [Interpolation::Nearest, Interpolation::Trilinear] {
            assert_eq!(InterpolationRecord::from(&i).into_library(), i);
        }
        // A direction whose renormalisation is not the identity keeps its stored bits.
        let d = DVec3::new(0.3, -1.0, 0.2).normalize();
        for l in [
            Light::Directional {
                direction: d,
                irradiance: 1.5,
            },
            Light::Point {
                position: DVec3::new(1.0, 2.0, -3.0),
                intensity: 4.0,
            },
            Light::Spot {
                position: DVec3::new(0.5, 0.5, -2.0),
                axis: DVec3::Z,
                half_angle: 0.4,
                intensity: 2.0,
            },
        ] {
            assert_eq!(LightRecord::from(&l).into_library().unwrap(), l);
        }
        let e = LightEnergy {
            entering: 1.0,
            extinguished: 0.25,
            leaving: 0.75,
        };
        assert_eq!(LightEnergyRecord::from(&e).into_library(), e);
        for model in [
            OpticalModel::AbsorptionOnly,
            OpticalModel::EmissionOnly,
            OpticalModel::EmissionAbsorption,
            OpticalModel::SingleScatterUnshadowed,
            OpticalModel::Scattering,
        ] {
            let r = RenderSettings {
                model,
                exposure: Some(2.5),
                spp: 4,
            };
            assert_eq!(RenderRecord::from(&r).into_library().unwrap(), r);
        }
        for projection in [
            Projection::Perspective {
                fov_y_degrees: 40.0,
            },
            Projection::Orthographic { height: 3.0 },
        ] {
            let c = CameraSpec {
                name: "front".into(),
                eye: DVec3::new(1.0, 2.0, -10.0),
                target: DVec3::new(1.0, 1.0, 0.5),
                up: DVec3::Y,
                projection,
                width: 40,
                height: 30,
            };
            assert_eq!(CameraRecord::from(&c).into_library(), c);
        }
        for m in SolveMethod::ALL {
            assert_eq!(SolveMethodRecord::from(&m).into_library(), m);
        }
        let bins = StoredBins {
            face_resolution: 1,
            directions: vec![[1.0, 0.0, 0.0]; 6],
            solid_angles: vec![4.0 * std::f64::consts::PI / 6.0; 6],
        };
        assert_eq!(BinsRecord::from(&bins).into_library().unwrap(), bins);
        for stop_reason in [
            StopReason::Converged,
            StopReason::MaxIterations,
            StopReason::Cancelled,
            StopReason::Diverged,
            StopReason::Stagnated,
        ] {
            let r = SolveReport {
                method: "sor:1.5".into(),
                iterations: 7,
                converged: stop_reason == StopReason::Converged,
                final_residual: 3e-7,
                residual_history: vec![1.0, 0.1, 3e-7],
                seconds: 0.5,
                seconds_per_iteration: 0.5 / 7.0,
                operator_applications: 9,
                operator_sweeps: 8,
                cancelled: stop_reason == StopReason::Cancelled,
                stop_reason,
            };
            assert_eq!(SolveReportRecord::from(&r).into_library().unwrap(), r);
        }
        let t = two_pass_sample();
        assert_eq!(TwoPassRecord::from(&t).into_library().unwrap(), t);
    }

    fn two_pass_sample() -> TwoPassSolution {
        let grid = Grid::new([3, 2, 2], 0.5).unwrap();
        TwoPassSolution {
            grid,
            storage_factor: 2,
            optical_dims: [2, 1, 1],
            bins: montecarlo::DirectionBins {
                n_theta: 2,
                n_phi: 3,
            },
            voxel_source: (0..12).map(|i| i as f32 * 0.5).collect(),
            cell_share: vec![0.25; 12],
            energy: PhotonEnergy {
                emitted: 2.0,
                entering: 1.5,
                absorbed: 0.5,
                escaped: 1.0,
                scattered: 0.75,
                stored: 0.5,
                photons: 1000,
                interactions: 1234,
            },
            include_first_bounce: false,
            max_source: 2.75,
        }
    }

    #[test]
    fn records_the_libraries_would_refuse_are_refused() {
        let grid = GridRecord {
            dims: [2, 0, 2],
            cell_size: 1.0,
        };
        assert!(grid.into_library().is_err());
        let grid = GridRecord {
            dims: [2, 2, 2],
            cell_size: f64::NAN,
        };
        assert!(grid.into_library().is_err());
        assert!(PhaseRecord::HenyeyGreenstein { g: 1.0 }
            .into_library()
            .is_err());
        assert!(PhaseRecord::TwoLobe {
            r: 1.5,
            g1: 0.1,
            g2: 0.1
        }
        .into_library()
        .is_err());
        assert!(LightRecord::Directional {
            direction: [0.0; 3],
            irradiance: 1.0
        }
        .into_library()
        .is_err());
        assert!(LightRecord::Spot {
            position: [0.0; 3],
            axis: [0.0, 0.0, 1.0],
            half_angle: 4.0,
            intensity: 1.0
        }
        .into_library()
        .is_err());
        let render = RenderRecord {
            model: OpticalModelRecord::Scattering,
            exposure: None,
            spp: 0,
        };
        assert!(render.into_library().is_err());
        let bins = BinsRecord {
            face_resolution: 2,
            directions: vec![[1.0, 0.0, 0.0]; 6],
            solid_angles: vec![1.0; 6],
        };
        assert!(bins.into_library().is_err());
        let bins = BinsRecord {
            face_resolution: 13,
            directions: vec![[1.0, 0.0, 0.0]; 1014],
            solid_angles: vec![1.0; 1014],
        };
        assert!(bins.into_library().is_err());

        let good = TwoPassRecord::from(&two_pass_sample());
        let mut t = good.clone();
        t.voxel_source.pop();
        assert!(t.into_library().unwrap_err().contains("source"));
        let mut t = good.clone();
        t.cell_share.push(0.0);
        assert!(t.into_library().unwrap_err().contains("shares"));
        let mut t = good.clone();
        t.optical_dims = [3, 2, 2];
        assert!(t.into_library().unwrap_err().contains("optical dims"));
        let mut t = good.clone();
        t.storage_factor = 0;
        assert!(t.into_library().is_err());
        let mut t = good.clone();
        t.n_phi = 0;
        assert!(t.into_library().is_err());
        let mut t = good;
        t.max_source = f64::INFINITY;
        assert!(t.into_library().is_err());
    }
}
