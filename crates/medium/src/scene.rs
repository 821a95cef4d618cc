//! Scene files (TOML, `docs/scene-format.md`) validated into a [`Scene`].
//!
//! Parsing happens in two stages, as in ripgrep's flags: serde reads the raw file into
//! structs that mirror the TOML exactly (unknown keys refused), then validation turns them
//! into the high-level [`Scene`] with a loaded [`Medium`], naming the file and key of the
//! first problem it finds ([`MediumError::Scene`]; keys are dotted paths such as
//! `medium.phase.g` or `light[1].direction`).
//!
//! Extensions to the contract, in its style:
//! - `[volume] file` may be raw f32 (needs `dims`), Mitsuba `.vol` or NRRD `.nrrd`/`.nhdr`
//!   (header gives the dims; `dims`, if given, must agree).
//! - `[volume] generator = { kind = "cloud", seed = 7 }` or `{ kind = "dipole" }` (needs `dims`).
//! - `[volume] sigma_t = { kind = "piecewise-linear", points = [[x, y], ...] }` or
//!   `{ kind = "preset", name = "threshold" }`: σt = `sigma_t_scale` × table(value).
//! - `albedo` and `emission`: a number, `[r, g, b]`, `{ kind = "constant", value = ... }`,
//!   `{ kind = "piecewise-linear", points = [[x, y], ...] or [[x, r, g, b], ...], scale = 1 }`,
//!   `{ kind = "preset", name = "...", scale = 1 }`; emission also
//!   `{ kind = "particle", c = 0.5 or [r, g, b] }` (Max eq. 8: emission = C·σt). Transfers
//!   read the raw data value. `sigma_t_scale` may be `[r, g, b]`. Any RGB item makes the
//!   medium three-channel; grey items are shared by all channels.
//! - `phase = "isotropic"` / `"lambertian-sphere"` or a table with `kind` = `isotropic`,
//!   `henyey-greenstein` (`g`), `lambertian-sphere`, `two-lobe` (`r`, `g1`, `g2`).
//! - `[[light]]` kinds: `directional` (direction, irradiance), `point` (position,
//!   intensity), `spot` (position, axis, half_angle_degrees, intensity). No light is allowed
//!   only when the medium emits.
//! - `[render] model = "absorption-only" | "emission-only" | "emission-absorption" |
//!   "single-scatter-unshadowed" | "scattering"` (default: emission-absorption when
//!   `[solve] method = "none"`, else scattering), `exposure = 1.0`, `spp = 1`.
//! - `[[camera]] projection = "orthographic"` with `ortho_height` instead of `fov_y`.

use std::path::{Path, PathBuf};

use glam::DVec3;
use serde::{Deserialize, Serialize};

use crate::generators::Generator;
use crate::transfer::{PiecewiseLinear, SigmaTransfer, Transfer};
use crate::volume_io::{load_volume, VolumeData, VolumeFormat};
use crate::{ChannelMedium, Grid, Interpolation, Light, Medium, MediumError, PhaseFunction};

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
    /// Where the medium's data came from (a volume file or a generator).
    pub source: VolumeSource,
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
    /// Blasi & Wuethrich's Monte Carlo two-pass method (photons from the lights deposited in
    /// the grid with their directions; the render adds the exact first bounce).
    TwoPass,
    None,
}

/// The linear iteration of `[solve] iteration`. The contract's two are `jacobi` and
/// `gauss-seidel`; the accelerated ones extend it (`sor:1.5`, `gmres:30`, `bicgstab`, `cg`,
/// `coarse-gs`, `coarse-jacobi`, `two-level-cg[:SMOOTHING]`, `dsa-cg`). The `solver` crate
/// maps these to its methods.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum IterationMethod {
    Jacobi,
    GaussSeidel,
    Sor {
        omega: f64,
    },
    Gmres {
        restart: usize,
    },
    BiCgStab,
    ConjugateGradient,
    CoarseJacobi,
    CoarseGaussSeidel,
    /// CG with the balancing two-level preconditioner on the operator's aggregates, smoothed
    /// by `Σ_{j≤smoothing} K^j` (`smoothing` ≤ [`MAX_TWO_LEVEL_SMOOTHING`]).
    TwoLevelCg {
        smoothing: usize,
    },
    /// CG preconditioned by diffusion-synthetic acceleration (operators with a diffusion
    /// approximation: the zonal-hierarchical one).
    DsaCg,
}

/// Spellings of `[solve] iteration`, for messages.
pub const ITERATION_NAMES: &str = "jacobi, gauss-seidel, sor:OMEGA, gmres[:RESTART], bicgstab, \
     cg, coarse-jacobi, coarse-gs, two-level-cg[:SMOOTHING 0..8], dsa-cg";

/// Largest `two-level-cg:SMOOTHING` (each step costs an application of the operator); the
/// same bound as the solver's.
pub const MAX_TWO_LEVEL_SMOOTHING: usize = 8;

impl IterationMethod {
    /// Parses the scene/command-line spelling; `None` for anything else.
    pub fn parse(text: &str) -> Option<IterationMethod> {
        let (name, arg) = match text.split_once(':') {
            Some((n, a)) => (n.trim(), Some(a.trim())),
            None => (text.trim(), None),
        };
        Some(match (name, arg) {
            ("jacobi", None) => IterationMethod::Jacobi,
            ("gauss-seidel" | "gs", None) => IterationMethod::GaussSeidel,
            ("sor", Some(a)) => {
                let omega: f64 = a.parse().ok()?;
                if !(omega > 0.0 && omega < 2.0) {
                    return None;
                }
                IterationMethod::Sor { omega }
            }
            ("gmres", None) => IterationMethod::Gmres { restart: 30 },
            ("gmres", Some(a)) => IterationMethod::Gmres {
                restart: a.parse().ok().filter(|&r: &usize| r >= 1)?,
            },
            ("bicgstab", None) => IterationMethod::BiCgStab,
            ("cg", None) => IterationMethod::ConjugateGradient,
            ("coarse-jacobi", None) => IterationMethod::CoarseJacobi,
            ("coarse-gs" | "coarse-gauss-seidel", None) => IterationMethod::CoarseGaussSeidel,
            ("two-level-cg", None) => IterationMethod::TwoLevelCg { smoothing: 0 },
            ("two-level-cg", Some(a)) => IterationMethod::TwoLevelCg {
                smoothing: a
                    .parse()
                    .ok()
                    .filter(|&m: &usize| m <= MAX_TWO_LEVEL_SMOOTHING)?,
            },
            ("dsa-cg", None) => IterationMethod::DsaCg,
            _ => return None,
        })
    }
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
    /// Discrete ordinates only: each cell swept as `r × r × r` sub-cells (`r` in
    /// 1..=[`MAX_TRANSPORT_REFINEMENT`]), which shrinks the sweep's numerical diffusion at
    /// `r³` times the sweep cost; the unknowns stay per cell.
    pub transport_refinement: usize,
    /// Two-pass only: photons per light of the energetization pass (its noise falls like
    /// `1/√photons`).
    pub photons: u64,
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
#[serde(rename_all = "kebab-case")]
pub enum Projection {
    Perspective {
        fov_y_degrees: f64,
    },
    /// Orthographic with the given world-space image height.
    Orthographic {
        height: f64,
    },
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

/// Where the medium's data values came from.
#[derive(Clone, Debug, PartialEq)]
pub enum VolumeSource {
    /// A volume file (absolute, or relative to the working directory when the scene was
    /// given as text with a relative base directory).
    File(PathBuf),
    Generator(Generator),
}

/// Names of `[solve] method`, in the scene's spelling.
pub const SOLVE_METHOD_NAMES: [&str; 6] = [
    "discrete-ordinates",
    "zonal",
    "zonal-hierarchical",
    "single-scatter",
    "two-pass",
    "none",
];

/// Names of `[render] model`, in the scene's spelling.
pub const OPTICAL_MODEL_NAMES: [&str; 5] = [
    "absorption-only",
    "emission-only",
    "emission-absorption",
    "single-scatter-unshadowed",
    "scattering",
];

impl SolveMethod {
    pub fn parse(name: &str) -> Option<SolveMethod> {
        Some(match name {
            "discrete-ordinates" => SolveMethod::DiscreteOrdinates,
            "zonal" => SolveMethod::Zonal,
            "zonal-hierarchical" => SolveMethod::ZonalHierarchical,
            "single-scatter" => SolveMethod::SingleScatter,
            "two-pass" => SolveMethod::TwoPass,
            "none" => SolveMethod::None,
            _ => return None,
        })
    }

    pub fn name(self) -> &'static str {
        match self {
            SolveMethod::DiscreteOrdinates => "discrete-ordinates",
            SolveMethod::Zonal => "zonal",
            SolveMethod::ZonalHierarchical => "zonal-hierarchical",
            SolveMethod::SingleScatter => "single-scatter",
            SolveMethod::TwoPass => "two-pass",
            SolveMethod::None => "none",
        }
    }

    /// The contract's "method that suits the medium": the hierarchical zonal method for an
    /// isotropic phase function, discrete ordinates otherwise.
    pub fn default_for(phase: &PhaseFunction) -> SolveMethod {
        if phase.is_isotropic() {
            SolveMethod::ZonalHierarchical
        } else {
            SolveMethod::DiscreteOrdinates
        }
    }
}

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

impl IterationMethod {
    /// The fastest robust iteration for a method (`volrad bench albedo`, docs/albedo.md):
    /// diffusion-synthetic CG for the hierarchical zonal system (6 iterations where Jacobi
    /// needs 69 and CG 14 on the sample cloud at albedo 0.999, and the fastest from albedo
    /// 0.5 to 1), conjugate gradients for the exact zonal system (symmetrisable by
    /// reciprocity, but without the diffusion approximation DSA needs), Gauss–Seidel for
    /// discrete ordinates (not symmetric, and Krylov vectors of cells × bins would cost
    /// gigabytes).
    pub fn default_for(method: SolveMethod) -> IterationMethod {
        match method {
            SolveMethod::ZonalHierarchical => IterationMethod::DsaCg,
            SolveMethod::Zonal => IterationMethod::ConjugateGradient,
            _ => IterationMethod::GaussSeidel,
        }
    }
}

impl SolveSettings {
    /// `[solve]` absent: the method for `phase`, its default iteration
    /// ([`IterationMethod::default_for`]), tolerance 1e-5, 2000 iterations, 96 bins.
    pub fn default_for(phase: &PhaseFunction) -> SolveSettings {
        let method = SolveMethod::default_for(phase);
        SolveSettings {
            method,
            bins: 96,
            iteration: IterationMethod::default_for(method),
            tolerance: 1e-5,
            max_iterations: 2000,
            transport_refinement: 1,
            photons: DEFAULT_TWO_PASS_PHOTONS,
        }
    }
}

/// Photons per light of the two-pass method when `[solve] photons` is absent.
pub const DEFAULT_TWO_PASS_PHOTONS: u64 = 1 << 21;

/// Bounds of `[solve] photons`: fewer is noise, more is hours.
pub const TWO_PASS_PHOTON_RANGE: std::ops::RangeInclusive<u64> = 1_000..=(1 << 30);

/// Largest `[solve] transport_refinement` (sub-cells per cell side of the ordinates sweep).
pub const MAX_TRANSPORT_REFINEMENT: usize = 4;

/// Discrete-ordinates bin counts volrad supports: the `6 n²` faces of an `n³` block of cubes.
pub const VALID_BINS: [usize; 8] = [6, 24, 54, 96, 150, 216, 294, 384];

/// The largest optical depth `Σ σt h` along any row of cells parallel to an axis, over all
/// channels: how opaque the medium is "across the grid".
pub fn max_axis_optical_depth(medium: &Medium) -> f64 {
    let [nx, ny, nz] = medium.grid.dims;
    let h = medium.grid.cell_size;
    let mut best = 0.0f64;
    for ch in &medium.channels {
        let s = &ch.sigma_t;
        let mut along_x = vec![0.0f64; ny * nz];
        let mut along_y = vec![0.0f64; nx * nz];
        let mut along_z = vec![0.0f64; nx * ny];
        for k in 0..nz {
            for j in 0..ny {
                for i in 0..nx {
                    let v = s[i + nx * (j + ny * k)] as f64;
                    along_x[j + ny * k] += v;
                    along_y[i + nx * k] += v;
                    along_z[i + nx * j] += v;
                }
            }
        }
        for v in along_x.iter().chain(&along_y).chain(&along_z) {
            best = best.max(v * h);
        }
    }
    best
}

// ---------------------------------------------------------------------------------------
// Raw structs: mirror the TOML; serde refuses unknown keys and reports missing ones. Values
// stay `toml::Value` so that validation can name the exact key of a bad value.

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawScene {
    // Required sections are optional here so that problems are reported in file order
    // (an unknown key in [volume] before a missing [[camera]]).
    volume: Option<toml::Value>,
    medium: Option<toml::Value>,
    light: Option<toml::Value>,
    background: Option<toml::Value>,
    solve: Option<toml::Value>,
    render: Option<toml::Value>,
    camera: Option<toml::Value>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawVolume {
    file: Option<toml::Value>,
    generator: Option<toml::Value>,
    dims: Option<toml::Value>,
    sigma_t_scale: Option<toml::Value>,
    sigma_t: Option<toml::Value>,
    cell_size: Option<toml::Value>,
    interpolation: Option<toml::Value>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawMedium {
    albedo: toml::Value,
    phase: Option<toml::Value>,
    emission: Option<toml::Value>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawBackground {
    radiance: toml::Value,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawSolve {
    method: Option<toml::Value>,
    bins: Option<toml::Value>,
    iteration: Option<toml::Value>,
    tolerance: Option<toml::Value>,
    max_iterations: Option<toml::Value>,
    transport_refinement: Option<toml::Value>,
    photons: Option<toml::Value>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawRender {
    model: Option<toml::Value>,
    exposure: Option<toml::Value>,
    spp: Option<toml::Value>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawCamera {
    name: toml::Value,
    eye: toml::Value,
    target: toml::Value,
    up: toml::Value,
    projection: Option<toml::Value>,
    fov_y: Option<toml::Value>,
    ortho_height: Option<toml::Value>,
    width: toml::Value,
    height: toml::Value,
}

// ---------------------------------------------------------------------------------------
// Validation.

/// The scene file being validated, for error messages.
struct Ctx<'a> {
    file: &'a Path,
    base_dir: &'a Path,
}

fn join(prefix: &str, key: &str) -> String {
    if prefix.is_empty() {
        key.to_string()
    } else {
        format!("{prefix}.{key}")
    }
}

fn type_name(v: &toml::Value) -> &'static str {
    match v {
        toml::Value::String(_) => "a string",
        toml::Value::Integer(_) => "an integer",
        toml::Value::Float(_) => "a number",
        toml::Value::Boolean(_) => "a boolean",
        toml::Value::Datetime(_) => "a date",
        toml::Value::Array(_) => "an array",
        toml::Value::Table(_) => "a table",
    }
}

/// Colour-channel values: one for grey, three for RGB.
type Channels<T> = Vec<T>;

impl Ctx<'_> {
    fn err(&self, key: impl Into<String>, message: impl Into<String>) -> MediumError {
        MediumError::Scene {
            file: self.file.to_path_buf(),
            key: key.into(),
            message: message.into(),
        }
    }

    /// Deserialises a raw struct, naming the unknown or missing key serde reports.
    fn raw<T: serde::de::DeserializeOwned>(
        &self,
        value: toml::Value,
        prefix: &str,
    ) -> Result<T, MediumError> {
        if !value.is_table() {
            return Err(self.err(
                prefix,
                format!("expected a table, found {}", type_name(&value)),
            ));
        }
        value.try_into::<T>().map_err(|e| {
            let msg = e.message().to_string();
            let field = msg.split('`').nth(1).unwrap_or("");
            if msg.starts_with("unknown field") {
                let expected = msg.split_once(", expected").map_or("", |(_, rest)| rest);
                self.err(
                    join(prefix, field),
                    format!("unknown key (expected{expected})"),
                )
            } else if msg.starts_with("missing field") {
                self.err(join(prefix, field), "required key is missing")
            } else {
                self.err(prefix, msg)
            }
        })
    }

    fn number(&self, v: &toml::Value, key: &str) -> Result<f64, MediumError> {
        let x = match v {
            toml::Value::Float(x) => *x,
            toml::Value::Integer(i) => *i as f64,
            other => {
                return Err(self.err(
                    key,
                    format!("expected a number, found {}", type_name(other)),
                ))
            }
        };
        if !x.is_finite() {
            return Err(self.err(key, format!("{x} is not finite; expected a finite number")));
        }
        Ok(x)
    }

    fn non_negative(&self, v: &toml::Value, key: &str) -> Result<f64, MediumError> {
        let x = self.number(v, key)?;
        if x < 0.0 {
            return Err(self.err(key, format!("{x} is negative; expected a number ≥ 0")));
        }
        Ok(x)
    }

    fn positive(&self, v: &toml::Value, key: &str) -> Result<f64, MediumError> {
        let x = self.number(v, key)?;
        if x <= 0.0 {
            return Err(self.err(key, format!("{x}: expected a number > 0")));
        }
        Ok(x)
    }

    fn integer(&self, v: &toml::Value, key: &str, min: i64) -> Result<i64, MediumError> {
        match v {
            toml::Value::Integer(i) if *i >= min => Ok(*i),
            toml::Value::Integer(i) => {
                Err(self.err(key, format!("{i}: expected a whole number ≥ {min}")))
            }
            other => Err(self.err(
                key,
                format!("expected a whole number, found {}", type_name(other)),
            )),
        }
    }

    fn string<'v>(&self, v: &'v toml::Value, key: &str) -> Result<&'v str, MediumError> {
        v.as_str()
            .ok_or_else(|| self.err(key, format!("expected a string, found {}", type_name(v))))
    }

    fn array<'v>(
        &self,
        v: &'v toml::Value,
        key: &str,
        len: Option<usize>,
    ) -> Result<&'v [toml::Value], MediumError> {
        let a = v
            .as_array()
            .ok_or_else(|| self.err(key, format!("expected an array, found {}", type_name(v))))?;
        if let Some(n) = len {
            if a.len() != n {
                return Err(self.err(key, format!("expected {n} elements, found {}", a.len())));
            }
        }
        Ok(a)
    }

    fn vec3(&self, v: &toml::Value, key: &str) -> Result<DVec3, MediumError> {
        let a = self.array(v, key, Some(3))?;
        Ok(DVec3::new(
            self.number(&a[0], key)?,
            self.number(&a[1], key)?,
            self.number(&a[2], key)?,
        ))
    }

    fn dims(&self, v: &toml::Value, key: &str) -> Result<[usize; 3], MediumError> {
        let a = self.array(v, key, Some(3))?;
        let mut d = [0usize; 3];
        for (slot, x) in d.iter_mut().zip(a) {
            *slot = self.integer(x, key, 1)? as usize;
        }
        Ok(d)
    }

    /// A table with a `kind` and only the listed keys (used for nested `{ kind = ... }`).
    fn kind_table<'v>(
        &self,
        v: &'v toml::Value,
        key: &str,
        kinds: &[(&str, &[&str], &[&str])],
    ) -> Result<(&'v str, &'v toml::Table), MediumError> {
        let t = v
            .as_table()
            .ok_or_else(|| self.err(key, format!("expected a table, found {}", type_name(v))))?;
        let kind_value = t
            .get("kind")
            .ok_or_else(|| self.err(join(key, "kind"), "required key is missing"))?;
        let kind = self.string(kind_value, &join(key, "kind"))?;
        let names: Vec<&str> = kinds.iter().map(|k| k.0).collect();
        let Some((_, required, optional)) = kinds.iter().find(|k| k.0 == kind) else {
            return Err(self.err(
                join(key, "kind"),
                format!(
                    "unknown kind `{kind}` (expected one of: {})",
                    names.join(", ")
                ),
            ));
        };
        for k in t.keys() {
            if k != "kind" && !required.contains(&k.as_str()) && !optional.contains(&k.as_str()) {
                let mut allowed: Vec<&str> =
                    required.iter().chain(optional.iter()).copied().collect();
                allowed.insert(0, "kind");
                return Err(self.err(
                    join(key, k),
                    format!(
                        "unknown key for kind `{kind}` (expected one of: {})",
                        allowed.join(", ")
                    ),
                ));
            }
        }
        for r in *required {
            if !t.contains_key(*r) {
                return Err(self.err(
                    join(key, r),
                    format!("required key for kind `{kind}` is missing"),
                ));
            }
        }
        Ok((kind, t))
    }

    /// A number or an `[r, g, b]` triple, each checked with `check`.
    fn grey_or_rgb(
        &self,
        v: &toml::Value,
        key: &str,
        check: &dyn Fn(f64) -> Result<(), String>,
    ) -> Result<Channels<f64>, MediumError> {
        let values = match v {
            toml::Value::Array(_) => {
                let a = self
                    .array(v, key, Some(3))
                    .map_err(|_| self.err(key, "expected a number or an [r, g, b] triple"))?;
                a.iter()
                    .map(|x| self.number(x, key))
                    .collect::<Result<Vec<_>, _>>()?
            }
            _ => vec![self.number(v, key)?],
        };
        for &x in &values {
            check(x).map_err(|m| self.err(key, format!("{x}: {m}")))?;
        }
        Ok(values)
    }

    /// `points = [[x, y], ...]` (grey) or `[[x, r, g, b], ...]` (RGB).
    fn table_points(
        &self,
        v: &toml::Value,
        key: &str,
    ) -> Result<Channels<Vec<[f64; 2]>>, MediumError> {
        let rows = self.array(v, key, None)?;
        if rows.is_empty() {
            return Err(self.err(key, "expected at least one point [x, y]"));
        }
        let width = self.array(&rows[0], key, None)?.len();
        if width != 2 && width != 4 {
            return Err(self.err(
                key,
                "each point must be [x, y] (grey) or [x, r, g, b] (colour)",
            ));
        }
        let mut channels = vec![Vec::with_capacity(rows.len()); width - 1];
        for row in rows {
            let r = self.array(row, key, Some(width))?;
            let x = self.number(&r[0], key)?;
            for (c, y) in r[1..].iter().enumerate() {
                channels[c].push([x, self.number(y, key)?]);
            }
        }
        Ok(channels)
    }

    /// A table transfer (`piecewise-linear` or `preset`), per channel.
    fn table_transfer(
        &self,
        kind: &str,
        t: &toml::Table,
        key: &str,
    ) -> Result<Channels<PiecewiseLinear>, MediumError> {
        let scale = match t.get("scale") {
            Some(s) => self.non_negative(s, &join(key, "scale"))?,
            None => 1.0,
        };
        let tables = if kind == "preset" {
            let name_key = join(key, "name");
            let name = self.string(&t["name"], &name_key)?;
            vec![PiecewiseLinear::preset(name).map_err(|e| self.err(name_key, e.to_string()))?]
        } else {
            let points_key = join(key, "points");
            self.table_points(&t["points"], &points_key)?
                .into_iter()
                .map(|p| PiecewiseLinear::new(p).map_err(|e| self.err(&points_key, e.to_string())))
                .collect::<Result<Vec<_>, _>>()?
        };
        Ok(tables.into_iter().map(|t| t.scaled(scale)).collect())
    }

    /// `albedo` or `emission`: a number, `[r, g, b]`, or a transfer-function table.
    fn transfer(
        &self,
        v: &toml::Value,
        key: &str,
        range: (f64, f64),
        allow_particle: bool,
    ) -> Result<Channels<Transfer>, MediumError> {
        let (lo, hi) = range;
        let expected = if hi.is_finite() {
            format!("expected a value in [{lo}, {hi}]")
        } else {
            format!("expected a value ≥ {lo}")
        };
        let check = |x: f64| {
            if x >= lo && x <= hi {
                Ok(())
            } else {
                Err(expected.clone())
            }
        };
        if !v.is_table() {
            return Ok(self
                .grey_or_rgb(v, key, &check)?
                .into_iter()
                .map(|value| Transfer::Constant { value })
                .collect());
        }
        let mut kinds: Vec<(&str, &[&str], &[&str])> = vec![
            ("constant", &["value"], &[]),
            ("piecewise-linear", &["points"], &["scale"]),
            ("preset", &["name"], &["scale"]),
        ];
        if allow_particle {
            kinds.push(("particle", &["c"], &[]));
        }
        let (kind, t) = self.kind_table(v, key, &kinds)?;
        match kind {
            "constant" => Ok(self
                .grey_or_rgb(&t["value"], &join(key, "value"), &check)?
                .into_iter()
                .map(|value| Transfer::Constant { value })
                .collect()),
            "particle" => Ok(self
                .grey_or_rgb(&t["c"], &join(key, "c"), &|x| {
                    if x >= 0.0 {
                        Ok(())
                    } else {
                        Err("expected a particle colour C ≥ 0".into())
                    }
                })?
                .into_iter()
                .map(|c| Transfer::Particle { c })
                .collect()),
            _ => {
                let tables = self.table_transfer(kind, t, key)?;
                for table in &tables {
                    let (tlo, thi) = table.range();
                    if tlo < lo || thi > hi {
                        return Err(self.err(
                            key,
                            format!("the table's values span [{tlo}, {thi}]; {expected}"),
                        ));
                    }
                }
                Ok(tables
                    .into_iter()
                    .map(|table| Transfer::Table { table })
                    .collect())
            }
        }
    }

    fn phase(&self, v: &toml::Value, key: &str) -> Result<PhaseFunction, MediumError> {
        if let Some(name) = v.as_str() {
            return match name {
                "isotropic" => Ok(PhaseFunction::Isotropic),
                "lambertian-sphere" => Ok(PhaseFunction::LambertianSphere),
                other => Err(self.err(
                    key,
                    format!(
                        "`{other}`: expected \"isotropic\", \"lambertian-sphere\", or a table such as {{ kind = \"henyey-greenstein\", g = 0.6 }}"
                    ),
                )),
            };
        }
        let (kind, t) = self.kind_table(
            v,
            key,
            &[
                ("isotropic", &[], &[]),
                ("henyey-greenstein", &["g"], &[]),
                ("lambertian-sphere", &[], &[]),
                ("two-lobe", &["r", "g1", "g2"], &[]),
            ],
        )?;
        let g = |name: &str| -> Result<f64, MediumError> {
            let k = join(key, name);
            let g = self.number(&t[name], &k)?;
            if g.abs() >= 1.0 {
                return Err(self.err(k, format!("{g}: expected |g| < 1")));
            }
            Ok(g)
        };
        Ok(match kind {
            "isotropic" => PhaseFunction::Isotropic,
            "lambertian-sphere" => PhaseFunction::LambertianSphere,
            "henyey-greenstein" => PhaseFunction::HenyeyGreenstein { g: g("g")? },
            _ => {
                let rk = join(key, "r");
                let r = self.number(&t["r"], &rk)?;
                if !(0.0..=1.0).contains(&r) {
                    return Err(self.err(rk, format!("{r}: expected a lobe weight in [0, 1]")));
                }
                PhaseFunction::TwoLobe {
                    r,
                    g1: g("g1")?,
                    g2: g("g2")?,
                }
            }
        })
    }

    fn light(&self, v: &toml::Value, key: &str) -> Result<Light, MediumError> {
        let (kind, t) = self.kind_table(
            v,
            key,
            &[
                ("directional", &["direction", "irradiance"], &[]),
                ("point", &["position", "intensity"], &[]),
                (
                    "spot",
                    &["position", "axis", "half_angle_degrees", "intensity"],
                    &[],
                ),
            ],
        )?;
        let nonzero = |name: &str| -> Result<DVec3, MediumError> {
            let k = join(key, name);
            let d = self.vec3(&t[name], &k)?;
            if d.length() < 1e-12 {
                return Err(self.err(k, format!("{d:?} is a zero vector; expected a direction")));
            }
            Ok(d.normalize())
        };
        let light = match kind {
            "directional" => Light::Directional {
                direction: nonzero("direction")?,
                irradiance: self.non_negative(&t["irradiance"], &join(key, "irradiance"))?,
            },
            "point" => Light::Point {
                position: self.vec3(&t["position"], &join(key, "position"))?,
                intensity: self.non_negative(&t["intensity"], &join(key, "intensity"))?,
            },
            _ => {
                let ak = join(key, "half_angle_degrees");
                let half = self.number(&t["half_angle_degrees"], &ak)?;
                if !(half > 0.0 && half <= 180.0) {
                    return Err(
                        self.err(ak, format!("{half}: expected an angle in (0, 180] degrees"))
                    );
                }
                Light::Spot {
                    position: self.vec3(&t["position"], &join(key, "position"))?,
                    axis: nonzero("axis")?,
                    half_angle: half.to_radians(),
                    intensity: self.non_negative(&t["intensity"], &join(key, "intensity"))?,
                }
            }
        };
        light.validated().map_err(|e| self.err(key, e.to_string()))
    }

    fn camera(&self, v: toml::Value, key: &str) -> Result<CameraSpec, MediumError> {
        let raw: RawCamera = self.raw(v, key)?;
        let name = self.string(&raw.name, &join(key, "name"))?.to_string();
        if name.is_empty() {
            return Err(self.err(join(key, "name"), "expected a non-empty name"));
        }
        let eye = self.vec3(&raw.eye, &join(key, "eye"))?;
        let target = self.vec3(&raw.target, &join(key, "target"))?;
        let up = self.vec3(&raw.up, &join(key, "up"))?;
        let view = target - eye;
        if view.length() < 1e-12 {
            return Err(self.err(
                join(key, "target"),
                "equals `eye`; expected a distinct point to look at",
            ));
        }
        if up.length() < 1e-12 || view.normalize().cross(up.normalize()).length() < 1e-9 {
            return Err(self.err(
                join(key, "up"),
                format!("{up:?} is zero or parallel to the view direction; expected an up vector"),
            ));
        }
        let projection_name = match &raw.projection {
            Some(p) => self.string(p, &join(key, "projection"))?,
            None => "perspective",
        };
        let projection = match projection_name {
            "perspective" => {
                if raw.ortho_height.is_some() {
                    return Err(self.err(
                        join(key, "ortho_height"),
                        "only for projection = \"orthographic\"",
                    ));
                }
                let fk = join(key, "fov_y");
                let fov = raw.fov_y.as_ref().ok_or_else(|| {
                    self.err(
                        &fk,
                        "required key is missing (vertical field of view, degrees)",
                    )
                })?;
                let fov = self.number(fov, &fk)?;
                if !(fov > 0.0 && fov < 180.0) {
                    return Err(self.err(fk, format!("{fov}: expected degrees in (0, 180)")));
                }
                Projection::Perspective { fov_y_degrees: fov }
            }
            "orthographic" => {
                if raw.fov_y.is_some() {
                    return Err(
                        self.err(join(key, "fov_y"), "only for projection = \"perspective\"")
                    );
                }
                let hk = join(key, "ortho_height");
                let h = raw.ortho_height.as_ref().ok_or_else(|| {
                    self.err(&hk, "required key is missing (world-space image height)")
                })?;
                Projection::Orthographic {
                    height: self.positive(h, &hk)?,
                }
            }
            other => {
                return Err(self.err(
                    join(key, "projection"),
                    format!("unknown projection `{other}` (expected perspective or orthographic)"),
                ))
            }
        };
        let size = |v: &toml::Value, k: &str| -> Result<u32, MediumError> {
            let k = join(key, k);
            let n = self.integer(v, &k, 1)?;
            u32::try_from(n)
                .ok()
                .filter(|&n| n <= 65536)
                .ok_or_else(|| self.err(k, format!("{n}: expected at most 65536 pixels")))
        };
        Ok(CameraSpec {
            name,
            eye,
            target,
            up: up.normalize(),
            projection,
            width: size(&raw.width, "width")?,
            height: size(&raw.height, "height")?,
        })
    }
}

/// Broadcasts a grey list to `n` channels.
fn broadcast<T: Clone>(v: Vec<T>, n: usize) -> Vec<T> {
    if v.len() == n {
        v
    } else {
        vec![v[0].clone(); n]
    }
}

impl Scene {
    /// The camera called `name`.
    pub fn camera(&self, name: &str) -> Option<&CameraSpec> {
        self.cameras.iter().find(|c| c.name == name)
    }

    /// The raw data values with their dims (what `volrad export` writes), when the medium
    /// was loaded from data.
    pub fn volume_data(&self) -> Option<VolumeData> {
        self.medium.data.as_ref().map(|values| VolumeData {
            dims: self.medium.grid.dims,
            values: values.clone(),
        })
    }

    /// Reads and validates a scene file; paths inside are relative to the file's directory.
    pub fn from_file(path: &Path) -> Result<Scene, MediumError> {
        let text = std::fs::read_to_string(path).map_err(|source| MediumError::Io {
            file: path.to_path_buf(),
            source,
        })?;
        let base = match path.parent() {
            Some(p) if !p.as_os_str().is_empty() => p,
            _ => Path::new("."),
        };
        Scene::from_toml_str(&text, base, path)
    }

    /// Validates scene text. `base_dir` resolves relative volume paths; `file_label` names
    /// the scene in errors and in [`Scene::origin`].
    pub fn from_toml_str(
        text: &str,
        base_dir: &Path,
        file_label: &Path,
    ) -> Result<Scene, MediumError> {
        let ctx = Ctx {
            file: file_label,
            base_dir,
        };
        let table: toml::Table = text.parse().map_err(|e: toml::de::Error| {
            let line = e
                .span()
                .map(|s| text[..s.start.min(text.len())].matches('\n').count() + 1);
            let key = match line {
                Some(l) => format!("(line {l})"),
                None => "(syntax)".to_string(),
            };
            ctx.err(key, format!("not valid TOML: {}", e.message()))
        })?;
        let raw: RawScene = ctx.raw(toml::Value::Table(table), "")?;
        let mut scene = ctx.scene(raw)?;
        scene.origin = SceneOrigin::File(file_label.to_path_buf());
        Ok(scene)
    }

    /// The built-in isotropic cloud (what `volrad` with no arguments solved until its default
    /// became the backlit `data/cloud-backlit.toml`): Max's procedural cloud (seed 7) on
    /// 48×48×36 cells, σt scaled so the thickest axis-parallel row has optical depth 10,
    /// albedo 0.99, isotropic phase, one directional light from above and to the side, and
    /// one 512×384 camera "front".
    pub fn builtin_default() -> Scene {
        let mut scene =
            Scene::from_toml_str(BUILTIN_CLOUD, Path::new("."), Path::new("<built-in cloud>"))
                .expect("the built-in scene is valid");
        let depth = max_axis_optical_depth(&scene.medium);
        if depth > 0.0 {
            let factor = (BUILTIN_OPTICAL_DEPTH / depth) as f32;
            for ch in &mut scene.medium.channels {
                ch.sigma_t.iter_mut().for_each(|s| *s *= factor);
            }
        }
        scene.origin = SceneOrigin::BuiltIn("cloud");
        scene
    }
}

/// Largest axis-parallel optical depth of the built-in cloud.
pub const BUILTIN_OPTICAL_DEPTH: f64 = 10.0;

const BUILTIN_CLOUD: &str = r#"
[volume]
generator = { kind = "cloud", seed = 7 }
dims = [48, 48, 36]

[medium]
albedo = 0.99
phase = { kind = "isotropic" }

[[light]]
kind = "directional"
direction = [0.5, -1.0, 0.35]
irradiance = 1.0

[render]
exposure = 6.0

[[camera]]
name = "front"
eye = [24.0, 32.0, -56.0]
target = [24.0, 22.0, 18.0]
up = [0.0, 1.0, 0.0]
fov_y = 40.0
width = 512
height = 384
"#;

impl Ctx<'_> {
    fn scene(&self, raw: RawScene) -> Result<Scene, MediumError> {
        // [volume]
        let missing = |key: &str| self.err(key, "required key is missing");
        let volume = raw.volume.ok_or_else(|| missing("volume"))?;
        let vol: RawVolume = self.raw(volume, "volume")?;
        let dims = vol
            .dims
            .as_ref()
            .map(|d| self.dims(d, "volume.dims"))
            .transpose()?;
        let (source, data) = match (&vol.file, &vol.generator) {
            (Some(_), Some(_)) => {
                return Err(self.err(
                    "volume.generator",
                    "give either `file` or `generator`, not both",
                ))
            }
            (None, None) => return Err(self.err(
                "volume.file",
                "required key is missing (or give `generator = { kind = \"cloud\", seed = 7 }`)",
            )),
            (Some(f), None) => {
                let name = self.string(f, "volume.file")?;
                let path = self.base_dir.join(name);
                let format = VolumeFormat::from_path(&path);
                if format == VolumeFormat::RawF32 && dims.is_none() {
                    return Err(self.err(
                        "volume.dims",
                        "required key is missing (a raw f32 file has no header)",
                    ));
                }
                let data = load_volume(&path, dims).map_err(|e| {
                    let key = match (&e, format) {
                        (MediumError::Volume { .. }, VolumeFormat::RawF32) => "volume.dims",
                        _ => "volume.file",
                    };
                    self.err(key, e.to_string())
                })?;
                (VolumeSource::File(path), data)
            }
            (None, Some(g)) => {
                let (kind, t) = self.kind_table(
                    g,
                    "volume.generator",
                    &[("cloud", &[], &["seed"]), ("dipole", &[], &[])],
                )?;
                let generator = match kind {
                    "cloud" => Generator::Cloud {
                        seed: match t.get("seed") {
                            Some(s) => self.integer(s, "volume.generator.seed", 0)? as u64,
                            None => 7,
                        },
                    },
                    _ => Generator::Dipole,
                };
                let dims = dims.ok_or_else(|| {
                    self.err(
                        "volume.dims",
                        "required key is missing (the generator needs the grid size)",
                    )
                })?;
                Grid::new(dims, 1.0).map_err(|e| self.err("volume.dims", e.to_string()))?;
                let values = generator.generate(dims);
                (
                    VolumeSource::Generator(generator),
                    VolumeData { dims, values },
                )
            }
        };
        let data_key = match source {
            VolumeSource::File(_) => "volume.file",
            VolumeSource::Generator(_) => "volume.generator",
        };
        if let Some(i) = data.values.iter().position(|v| !v.is_finite()) {
            let [x, y, z] = Grid {
                dims: data.dims,
                cell_size: 1.0,
            }
            .coords(i);
            return Err(self.err(
                data_key,
                format!(
                    "cell ({x}, {y}, {z}) has value {}; expected finite values",
                    data.values[i]
                ),
            ));
        }
        let cell_size = match &vol.cell_size {
            Some(v) => self.positive(v, "volume.cell_size")?,
            None => 1.0,
        };
        let grid =
            Grid::new(data.dims, cell_size).map_err(|e| self.err("volume.dims", e.to_string()))?;
        let interpolation = match &vol.interpolation {
            None => Interpolation::Nearest,
            Some(v) => match self.string(v, "volume.interpolation")? {
                "nearest" => Interpolation::Nearest,
                "trilinear" => Interpolation::Trilinear,
                other => {
                    return Err(self.err(
                        "volume.interpolation",
                        format!("unknown interpolation `{other}` (expected nearest or trilinear)"),
                    ))
                }
            },
        };
        let scales = match &vol.sigma_t_scale {
            Some(v) => self.grey_or_rgb(v, "volume.sigma_t_scale", &|x| {
                if x >= 0.0 {
                    Ok(())
                } else {
                    Err("expected a scale ≥ 0".into())
                }
            })?,
            None => vec![1.0],
        };
        let sigma_tables: Channels<Option<PiecewiseLinear>> = match &vol.sigma_t {
            None => vec![None],
            Some(v) => {
                let (kind, t) = self.kind_table(
                    v,
                    "volume.sigma_t",
                    &[
                        ("piecewise-linear", &["points"], &["scale"]),
                        ("preset", &["name"], &["scale"]),
                    ],
                )?;
                let tables = self.table_transfer(kind, t, "volume.sigma_t")?;
                for table in &tables {
                    let (lo, _) = table.range();
                    if lo < 0.0 {
                        return Err(self.err(
                            "volume.sigma_t",
                            format!("the table reaches {lo}; σt must be ≥ 0"),
                        ));
                    }
                }
                tables.into_iter().map(Some).collect()
            }
        };
        if sigma_tables[0].is_none() {
            if let Some(i) = data.values.iter().position(|&v| v < 0.0) {
                let [x, y, z] = grid.coords(i);
                return Err(self.err(
                    data_key,
                    format!(
                        "cell ({x}, {y}, {z}) has value {}: σt = value × sigma_t_scale must be ≥ 0",
                        data.values[i]
                    ),
                ));
            }
        }

        // [medium]
        let med: RawMedium = self.raw(raw.medium.ok_or_else(|| missing("medium"))?, "medium")?;
        let albedo = self.transfer(&med.albedo, "medium.albedo", (0.0, 1.0), false)?;
        let emission = match &med.emission {
            Some(v) => self.transfer(v, "medium.emission", (0.0, f64::INFINITY), true)?,
            None => vec![Transfer::Constant { value: 0.0 }],
        };
        let phase = match &med.phase {
            Some(v) => self.phase(v, "medium.phase")?,
            None => PhaseFunction::Isotropic,
        };

        let n_channels = [
            scales.len(),
            sigma_tables.len(),
            albedo.len(),
            emission.len(),
        ]
        .into_iter()
        .max()
        .unwrap_or(1);
        let scales = broadcast(scales, n_channels);
        let sigma_tables = broadcast(sigma_tables, n_channels);
        let albedo = broadcast(albedo, n_channels);
        let emission = broadcast(emission, n_channels);
        let mut channels = Vec::with_capacity(n_channels);
        for c in 0..n_channels {
            let sigma = SigmaTransfer {
                scale: scales[c],
                table: sigma_tables[c].clone(),
            };
            let sigma_t = sigma.apply(&data.values);
            if let Some(i) = sigma_t.iter().position(|s| !s.is_finite()) {
                return Err(self.err(
                    "volume.sigma_t_scale",
                    format!("σt of cell {i} overflows f32"),
                ));
            }
            let albedo_c = albedo[c].apply(&data.values, &sigma_t);
            let emission_c = emission[c].apply(&data.values, &sigma_t);
            channels.push(ChannelMedium {
                sigma_t,
                albedo: albedo_c,
                emission: emission_c,
            });
        }
        let has_emission = channels.iter().any(|c| !c.emission.is_zero());
        let medium = Medium::new(grid, channels, phase, interpolation, Some(data.values))
            .map_err(|e| self.err("medium", e.to_string()))?;

        // [[light]]
        let lights = match raw.light {
            None => Vec::new(),
            Some(v) => {
                let list = v
                    .as_array()
                    .ok_or_else(|| self.err("light", "expected an array of tables ([[light]])"))?;
                list.iter()
                    .enumerate()
                    .map(|(i, l)| self.light(l, &format!("light[{i}]")))
                    .collect::<Result<Vec<_>, _>>()?
            }
        };
        if lights.is_empty() && !has_emission {
            return Err(self.err(
                "light",
                "no light and no emission: add a [[light]] or a non-zero medium.emission",
            ));
        }

        // [background]
        let background = match raw.background {
            None => 0.0,
            Some(v) => {
                let b: RawBackground = self.raw(v, "background")?;
                self.non_negative(&b.radiance, "background.radiance")?
            }
        };

        // [solve]
        let solve = match raw.solve {
            None => SolveSettings::default_for(&phase),
            Some(v) => {
                let s: RawSolve = self.raw(v, "solve")?;
                let mut out = SolveSettings::default_for(&phase);
                if let Some(m) = &s.method {
                    let name = self.string(m, "solve.method")?;
                    out.method = SolveMethod::parse(name).ok_or_else(|| {
                        self.err(
                            "solve.method",
                            format!(
                                "unknown method `{name}` (expected one of: {})",
                                SOLVE_METHOD_NAMES.join(", ")
                            ),
                        )
                    })?;
                    out.iteration = IterationMethod::default_for(out.method);
                }
                if let Some(b) = &s.bins {
                    let bins = self.integer(b, "solve.bins", 1)? as usize;
                    if !VALID_BINS.contains(&bins) {
                        return Err(self.err(
                            "solve.bins",
                            format!("{bins}: expected 6n² for n = 1..=8 ({VALID_BINS:?})"),
                        ));
                    }
                    out.bins = bins;
                }
                if let Some(it) = &s.iteration {
                    let text = self.string(it, "solve.iteration")?;
                    out.iteration = IterationMethod::parse(text).ok_or_else(|| {
                        self.err(
                            "solve.iteration",
                            format!(
                                "unknown iteration `{text}` (expected one of {ITERATION_NAMES})"
                            ),
                        )
                    })?;
                }
                if let Some(t) = &s.tolerance {
                    out.tolerance = self.positive(t, "solve.tolerance")?;
                }
                if let Some(m) = &s.max_iterations {
                    out.max_iterations = self.integer(m, "solve.max_iterations", 1)? as usize;
                }
                if let Some(r) = &s.transport_refinement {
                    let key = "solve.transport_refinement";
                    let r = self.integer(r, key, 1)?;
                    if r > MAX_TRANSPORT_REFINEMENT as i64 {
                        return Err(self.err(
                            key,
                            format!(
                                "{r}: expected a whole number from 1 to {MAX_TRANSPORT_REFINEMENT} \
                                 (sub-cells per cell side; the sweep costs r³ times more)"
                            ),
                        ));
                    }
                    out.transport_refinement = r as usize;
                }
                if let Some(n) = &s.photons {
                    let key = "solve.photons";
                    let n = self.integer(n, key, 1)? as u64;
                    if !TWO_PASS_PHOTON_RANGE.contains(&n) {
                        return Err(self.err(
                            key,
                            format!(
                                "{n}: expected a whole number of photons per light from {} to {}",
                                TWO_PASS_PHOTON_RANGE.start(),
                                TWO_PASS_PHOTON_RANGE.end()
                            ),
                        ));
                    }
                    out.photons = n;
                }
                out
            }
        };

        // [render]
        let default_model = if solve.method == SolveMethod::None {
            OpticalModel::EmissionAbsorption
        } else {
            OpticalModel::Scattering
        };
        let render = match raw.render {
            None => RenderSettings {
                model: default_model,
                exposure: 1.0,
                spp: 1,
            },
            Some(v) => {
                let r: RawRender = self.raw(v, "render")?;
                let model = match &r.model {
                    None => default_model,
                    Some(m) => {
                        let name = self.string(m, "render.model")?;
                        OpticalModel::parse(name).ok_or_else(|| {
                            self.err(
                                "render.model",
                                format!(
                                    "unknown model `{name}` (expected one of: {})",
                                    OPTICAL_MODEL_NAMES.join(", ")
                                ),
                            )
                        })?
                    }
                };
                let exposure = match &r.exposure {
                    Some(e) => self.positive(e, "render.exposure")?,
                    None => 1.0,
                };
                let spp = match &r.spp {
                    Some(s) => {
                        let n = self.integer(s, "render.spp", 1)?;
                        u32::try_from(n)
                            .map_err(|_| self.err("render.spp", format!("{n} is too large")))?
                    }
                    None => 1,
                };
                RenderSettings {
                    model,
                    exposure,
                    spp,
                }
            }
        };

        // [[camera]]
        let list = raw
            .camera
            .ok_or_else(|| missing("camera"))?
            .as_array()
            .ok_or_else(|| self.err("camera", "expected an array of tables ([[camera]])"))?
            .clone();
        if list.is_empty() {
            return Err(self.err("camera", "expected at least one [[camera]]"));
        }
        let mut cameras: Vec<CameraSpec> = Vec::with_capacity(list.len());
        for (i, c) in list.into_iter().enumerate() {
            let key = format!("camera[{i}]");
            let cam = self.camera(c, &key)?;
            if cameras.iter().any(|o| o.name == cam.name) {
                return Err(self.err(
                    join(&key, "name"),
                    format!("duplicate camera name `{}`", cam.name),
                ));
            }
            cameras.push(cam);
        }

        Ok(Scene {
            medium,
            lights,
            background,
            solve,
            render,
            cameras,
            origin: SceneOrigin::File(self.file.to_path_buf()),
            source,
        })
    }
}

#[cfg(test)]
mod iteration_tests {
    use super::*;

    #[test]
    fn accelerated_cg_iterations_parse_and_bad_parameters_are_refused() {
        assert_eq!(
            IterationMethod::parse("dsa-cg"),
            Some(IterationMethod::DsaCg)
        );
        assert_eq!(
            IterationMethod::parse("two-level-cg"),
            Some(IterationMethod::TwoLevelCg { smoothing: 0 })
        );
        assert_eq!(
            IterationMethod::parse("two-level-cg:2"),
            Some(IterationMethod::TwoLevelCg { smoothing: 2 })
        );
        for bad in ["dsa-cg:1", "two-level-cg:9", "two-level-cg:x", "dsa"] {
            assert_eq!(IterationMethod::parse(bad), None, "{bad}");
        }
    }
}
