//! `scene`: volrad's scene files (TOML, `docs/scene-format.md`), read and validated into the
//! libraries' own settings types. It sits above the libraries and below the root crate, as
//! ripgrep's low-level → high-level arguments do: each library owns its settings and their
//! bounds (gather the optical model and camera spec, solver the iteration grammar,
//! formfactor the bin counts and refinement limit, montecarlo the photon count), and this
//! crate only maps the file's keys onto them.
//!
//! The core types:
//! - [`Scene`]: a validated scene — the [`Medium`], lights, background, [`SolveSettings`],
//!   [`RenderSettings`] and cameras ([`CameraSpec`]).
//! - [`SolveMethod`]: the multiple-scattering method of `[solve] method`.
//! - [`SceneError`]: the first problem found, naming the file and the dotted key.
//!
//! Parsing happens in two stages, as in ripgrep's flags: serde reads the raw file into
//! structs that mirror the TOML exactly (unknown keys refused), then validation turns them
//! into the high-level [`Scene`] with a loaded [`Medium`], naming the file and key of the
//! first problem it finds ([`SceneError::Invalid`]; keys are dotted paths such as
//! `medium.phase.g` or `light[1].direction`).
//!
//! Extensions to the contract, in its style:
//! - `[volume] file` may be raw f32 (needs `dims`), Mitsuba `.vol`, NRRD `.nrrd`/`.nhdr`
//!   (header gives the dims; `dims`, if given, must agree) or OpenVDB `.vdb` (`grid = "name"`,
//!   the active voxels' box; `cell_size` defaults to a uniform voxel size;
//!   `coordinates = "file"` reads camera and light positions in the file's world).
//! - `[volume] generator = { kind = "cloud", seed = 7 }` or `{ kind = "dipole" }` (needs `dims`).
//! - `[volume] sigma_t = { kind = "piecewise-linear", points = [[x, y], ...] }` or
//!   `{ kind = "preset", name = "threshold" }`: σt = `sigma_t_scale` × table(value).
//! - `albedo` and `emission`: a number, `[r, g, b]`, `{ kind = "constant", value = ... }`,
//!   `{ kind = "piecewise-linear", points = [[x, y], ...] or [[x, r, g, b], ...], scale = 1 }`,
//!   `{ kind = "preset", name = "...", scale = 1 }`; emission also
//!   `{ kind = "particle", c = 0.5 or [r, g, b] }` (Max eq. 8: emission = C·σt) and
//!   `{ kind = "blackbody", temperature = K or { kind = "piecewise-linear", points } | grid =
//!   "temperature", scale = 1 }` (Planck colour × (1 − a) σt, always RGB). Transfers
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

mod check;
mod raw;
mod sections;
mod settings;

use std::path::{Path, PathBuf};

pub use gather::{CameraSpec, OpticalModel, Projection, RenderSettings};
use medium::generators::Generator;
use medium::ground::Ground;
pub use medium::vdb::VdbPlacement;
use medium::volume_io::VolumeData;
use medium::{Environment, Light, Medium};

use crate::check::Ctx;
use crate::raw::RawScene;
pub use crate::settings::{
    phase_spelling, BinCount, SolveMethod, SolveSettings, TransportRefinement, TransportScale,
    UnknownSolveMethod,
};

/// A validated scene: the medium, its lighting, how to solve it and how to look at it.
#[derive(Clone, Debug)]
pub struct Scene {
    pub medium: Medium,
    pub lights: Vec<Light>,
    /// Light from every direction at infinity (`[[light]] kind = "environment"` or `"sky"`),
    /// which lights the medium in every solving method and is what camera rays see where they
    /// leave the grid. A sky's sun is in `lights`.
    pub environment: Option<Environment>,
    /// Background radiance `I0` seen through the volume (0 with an environment).
    pub background: f64,
    /// A Lambertian plane under the volume (`[ground]`), lit by the lights, the environment
    /// and the medium, and lighting the medium from below; camera rays going down see it.
    pub ground: Option<Ground>,
    pub solve: SolveSettings,
    pub render: RenderSettings,
    pub cameras: Vec<CameraSpec>,
    /// Where the scene came from (a file, or the built-in default).
    pub origin: SceneOrigin,
    /// Where the medium's data came from (a volume file or a generator).
    pub source: VolumeSource,
    /// For an OpenVDB volume: the grid's name, active box and transform in the file.
    pub placement: Option<VdbPlacement>,
}

#[derive(Clone, Debug, PartialEq, Eq)]
pub enum SceneOrigin {
    File(PathBuf),
    BuiltIn(&'static str),
}

/// Where the medium's data values came from.
#[derive(Clone, Debug, PartialEq)]
pub enum VolumeSource {
    /// A volume file (absolute, or relative to the working directory when the scene was
    /// given as text with a relative base directory).
    File(PathBuf),
    Generator(Generator),
    /// Values given by the caller ([`Scene::with_volume_data`]).
    Supplied,
}

/// Why a scene could not be read.
#[derive(Debug, thiserror::Error)]
pub enum SceneError {
    /// The scene file could not be read.
    #[error("{file}: {error}")]
    Io {
        file: PathBuf,
        error: std::io::Error,
    },
    /// A value is malformed or out of range. `key` is the dotted TOML path
    /// (`medium.phase.g`, `light[1].direction`).
    #[error("{file}: `{key}`: {message}")]
    Invalid {
        file: PathBuf,
        key: String,
        message: String,
    },
}

impl Scene {
    /// The camera called `name`.
    pub fn camera(&self, name: &str) -> Option<&CameraSpec> {
        self.cameras.iter().find(|c| c.name == name)
    }

    /// Where an OpenVDB grid sits in its file's world (`None` for other volumes): volrad's
    /// cell (0, 0, 0) is voxel `bbox_min`, and its corner is at `world_corner()` there.
    pub fn volume_placement(&self) -> Option<&VdbPlacement> {
        self.placement.as_ref()
    }

    /// The raw data values with their dims (what `volrad export` writes), when the medium
    /// was loaded from data.
    pub fn volume_data(&self) -> Option<VolumeData> {
        self.medium.data().map(|values| VolumeData {
            dims: self.medium.grid().dims,
            values: values.to_vec(),
        })
    }

    /// Reads and validates a scene file; paths inside are relative to the file's directory.
    pub fn from_file(path: &Path) -> Result<Scene, SceneError> {
        // A FIFO, device or directory is refused, naming it, before anything is read.
        let text = medium::regular_file::read_to_string(path).map_err(|error| SceneError::Io {
            file: path.to_path_buf(),
            error,
        })?;
        Scene::from_toml_str(&text, Scene::base_dir(path), path)
    }

    /// The directory relative volume paths of the scene file `path` are resolved against:
    /// the file's own (`.` for a bare file name).
    pub fn base_dir(path: &Path) -> &Path {
        match path.parent() {
            Some(p) if !p.as_os_str().is_empty() => p,
            _ => Path::new("."),
        }
    }

    /// Validates scene text. `base_dir` resolves relative volume paths; `file_label` names
    /// the scene in errors and in [`Scene::origin`].
    pub fn from_toml_str(
        text: &str,
        base_dir: &Path,
        file_label: &Path,
    ) -> Result<Scene, SceneError> {
        Scene::parse(text, base_dir, file_label, None)
    }

    /// Validates scene text whose volume data come from the caller (an array in memory, as
    /// the Python package's `Scene(sigma_t=...)` gives them) instead of a `[volume] file` or
    /// `generator`; every other key means what it means in a file. `[volume] dims`, if given,
    /// must agree with `data.dims`.
    pub fn with_volume_data(
        text: &str,
        data: VolumeData,
        base_dir: &Path,
        file_label: &Path,
    ) -> Result<Scene, SceneError> {
        Scene::parse(text, base_dir, file_label, Some(data))
    }

    fn parse(
        text: &str,
        base_dir: &Path,
        file_label: &Path,
        supplied: Option<VolumeData>,
    ) -> Result<Scene, SceneError> {
        let ctx = Ctx {
            file: file_label,
            base_dir,
            supplied: std::cell::Cell::new(supplied),
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

    /// The scene of `volrad` with no arguments: `data/cloud-sky.toml`, compiled in — Max's
    /// cloud (g = 0.6) under Preetham's sky and its sun, in colour, by discrete ordinates,
    /// drawn smoothly.
    pub fn builtin_default() -> Result<Scene, SceneError> {
        let mut scene = Scene::from_toml_str(
            BUILTIN_SCENE,
            Path::new("."),
            Path::new("<built-in sky-lit cloud>"),
        )?;
        scene.origin = SceneOrigin::BuiltIn("sky-lit cloud");
        Ok(scene)
    }
}

/// The built-in scene's text ([`Scene::builtin_default`]).
pub const BUILTIN_SCENE: &str = include_str!("../../../data/cloud-sky.toml");
