//! Validation of each section of a scene file into the libraries' settings types; one
//! function per section, called in file order by [`Ctx::scene`].

use formfactor::ordinates::{forward_truncation_fraction, MAX_FACE_DIVISIONS, VALID_BINS};
use gather::{CameraSpec, OpticalModel, RenderSettings, OPTICAL_MODEL_NAMES};
use medium::blackbody::RgbTable;
use medium::coarsening::{MAX_TRANSPORT_SCALE, MAX_TRANSPORT_SPLIT};
use medium::generators::Generator;
use medium::ground::Ground;
use medium::light_pass::MAX_LIGHTS;
use medium::transfer::{PiecewiseLinear, SigmaTransfer, Transfer};
use medium::vdb::VdbPlacement;
use medium::volume_io::{load_volume_with, VolumeData, VolumeFormat, VolumeRequest};
use medium::{
    CellValues, ChannelMedium, Environment, Grid, Interpolation, Light, Medium, MediumError,
    PhaseFunction,
};

use montecarlo::two_pass::PHOTON_RANGE;
use solver::ParseMethodError;

use crate::check::{broadcast, join, Channels, Ctx, SceneLight};
use crate::raw::{RawBackground, RawGround, RawMedium, RawRender, RawScene, RawSolve, RawVolume};
use crate::settings::{BinCount, TransportRefinement, TransportScale, UnknownSolveMethod};
use crate::{Scene, SceneError, SceneOrigin, SolveMethod, SolveSettings, VolumeSource};
use glam::DVec3;

/// The hottest temperature a blackbody emission accepts (kelvin): well above any flame or
/// star surface a volume renderer meets, and it bounds the colour table's size.
const MAX_TEMPERATURE: f64 = 1.0e5;

/// Whether an emission value is `{ kind = "blackbody", ... }`.
fn is_blackbody(v: &toml::Value) -> bool {
    v.get("kind").and_then(|k| k.as_str()) == Some("blackbody")
}

/// Per-cell temperature in kelvin (≤ 0: no emission).
enum Temperature {
    Uniform(f64),
    PerCell(Vec<f32>),
}

/// `[medium] emission = { kind = "blackbody", ... }`, parsed.
struct Blackbody {
    temperature: Temperature,
    scale: f64,
}

impl Blackbody {
    fn max_temperature(&self) -> f64 {
        match &self.temperature {
            Temperature::Uniform(t) => *t,
            Temperature::PerCell(v) => v.iter().copied().fold(0.0, f32::max) as f64,
        }
    }

    /// Channel `c`'s emission: `scale · (1 − a) · σt · rgb_c(T)`. Kirchhoff's law: in local
    /// thermal equilibrium a medium emits its absorption coefficient `σa = (1 − a) σt` times
    /// the Planck radiance.
    fn emission(
        &self,
        c: usize,
        table: &RgbTable,
        sigma_t: &[f32],
        albedo: &CellValues,
    ) -> CellValues {
        let at = |t: f64, cell: usize| {
            let sigma_a = (1.0 - albedo.get(cell) as f64) * sigma_t[cell] as f64;
            (self.scale * sigma_a * table.get(t)[c]) as f32
        };
        let values: Vec<f32> = match &self.temperature {
            Temperature::Uniform(t) => (0..sigma_t.len()).map(|i| at(*t, i)).collect(),
            Temperature::PerCell(v) => v
                .iter()
                .enumerate()
                .map(|(i, &t)| at(t as f64, i))
                .collect(),
        };
        CellValues::PerCell(values)
    }
}

/// `[ground] albedo` when not given: a typical grass or soil.
pub const DEFAULT_GROUND_ALBEDO: f64 = 0.2;

/// The up direction of a sky or an environment map (a uniform environment has none).
fn environment_up(environment: &Environment) -> Option<DVec3> {
    match environment.spec() {
        medium::environment::EnvironmentSpec::Sky(s) => Some(s.up),
        medium::environment::EnvironmentSpec::Map(m) => Some(m.up()),
        medium::environment::EnvironmentSpec::Uniform { .. } => None,
    }
}

/// What `[volume]` gives: the data values on their grid and the σt transfer per channel.
struct Volume {
    source: VolumeSource,
    data: VolumeData,
    grid: Grid,
    interpolation: Interpolation,
    sigma_scales: Channels<f64>,
    sigma_tables: Channels<Option<PiecewiseLinear>>,
    /// A `.vdb` grid's place in the file's world.
    placement: Option<VdbPlacement>,
    /// `coordinates = "file"`: the world position of the grid's corner, subtracted from
    /// camera and light positions.
    file_origin: Option<DVec3>,
}

impl Ctx<'_> {
    fn missing(&self, key: &str) -> SceneError {
        self.err(key, "required key is missing")
    }

    pub(crate) fn scene(&self, raw: RawScene) -> Result<Scene, SceneError> {
        let volume = self.volume(raw.volume.ok_or_else(|| self.missing("volume"))?)?;
        let source = volume.source.clone();
        let (placement, file_origin) = (volume.placement.clone(), volume.file_origin);
        let medium = self.medium(raw.medium.ok_or_else(|| self.missing("medium"))?, volume)?;
        let (mut lights, environment) = self.lights(raw.light, &medium)?;
        let background = self.background(raw.background, environment.as_ref())?;
        let ground = raw
            .ground
            .map(|g| self.ground(g, medium.grid(), environment.as_ref(), file_origin))
            .transpose()?;
        // Coloured light needs coloured transport: a grey medium is solved in three channels.
        let coloured = environment.as_ref().is_some_and(|e| e.is_coloured())
            || ground.is_some_and(|g| g.is_coloured());
        let medium = if coloured { medium.in_colour() } else { medium };
        let solve = self.solve(raw.solve, &medium.phase())?;
        let render = self.render(raw.render, solve.method)?;
        let mut cameras = self.cameras(raw.camera)?;
        if let Some(o) = file_origin {
            // Positions were given in the file's world; volrad's grid has its corner at 0.
            for light in &mut lights {
                match light {
                    Light::Point { position, .. } | Light::Spot { position, .. } => *position -= o,
                    Light::Directional { .. } => {}
                }
            }
            for c in &mut cameras {
                c.eye -= o;
                c.target -= o;
            }
        }
        if let Some(g) = &ground {
            self.lights_above(&lights, g)?;
        }
        Ok(Scene {
            medium,
            lights,
            environment,
            background,
            ground,
            solve,
            render,
            cameras,
            origin: SceneOrigin::File(self.file.to_path_buf()),
            source,
            placement,
        })
    }

    fn volume(&self, volume: toml::Value) -> Result<Volume, SceneError> {
        let vol: RawVolume = self.raw(volume, "volume")?;
        let dims = vol
            .dims
            .as_ref()
            .map(|d| self.dims(d, "volume.dims"))
            .transpose()?;
        let grid_name = vol
            .grid
            .as_ref()
            .map(|g| self.string(g, "volume.grid"))
            .transpose()?;
        let mut placement = None;
        let mut voxel_size = None;
        let supplied = self.supplied.take();
        if supplied.is_some() {
            for (key, given) in [
                ("volume.file", vol.file.is_some()),
                ("volume.generator", vol.generator.is_some()),
                ("volume.grid", vol.grid.is_some()),
            ] {
                if given {
                    return Err(self.err(
                        key,
                        "the volume's values were given as an array; leave out `file`, `generator` and `grid`",
                    ));
                }
            }
        }
        let (source, data) = match (&vol.file, &vol.generator) {
            _ if supplied.is_some() => {
                let data = supplied.expect("checked above");
                if let Some(d) = dims.filter(|d| *d != data.dims) {
                    return Err(self.err(
                        "volume.dims",
                        format!("{d:?} disagrees with the given array's {:?}", data.dims),
                    ));
                }
                Grid::new(data.dims, 1.0).map_err(|e| self.err("volume.dims", e.to_string()))?;
                // The fields are public: a caller may have paired values and dims wrongly.
                let data = VolumeData::new(data.dims, data.values)
                    .map_err(|e| self.err("volume", e.to_string()))?;
                (VolumeSource::Supplied, data)
            }
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
                if grid_name.is_some() && format != VolumeFormat::OpenVdb {
                    return Err(self.err(
                        "volume.grid",
                        format!("`grid` chooses a grid of an OpenVDB (.vdb) file; `{name}` holds one volume"),
                    ));
                }
                let request = VolumeRequest {
                    dims,
                    grid: grid_name,
                };
                let loaded = load_volume_with(&path, &request).map_err(|e| {
                    let key = match (&e, format) {
                        (MediumError::Volume { .. }, VolumeFormat::RawF32) => "volume.dims",
                        _ => "volume.file",
                    };
                    self.err(key, e.to_string())
                })?;
                placement = loaded.placement;
                voxel_size = loaded.voxel_size;
                (VolumeSource::File(path), loaded.data)
            }
            (None, Some(g)) => {
                if grid_name.is_some() {
                    return Err(self.err(
                        "volume.grid",
                        "`grid` chooses a grid of an OpenVDB (.vdb) file, not of a generator",
                    ));
                }
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
                let grid =
                    Grid::new(dims, 1.0).map_err(|e| self.err("volume.dims", e.to_string()))?;
                // The data values, σt and a working copy, 4 bytes each per cell (`volrad info`
                // of a generated 512×512×256 cloud peaks at 12.2 bytes per cell), with a margin,
                // before they are allocated: a grid too large is refused here, not aborted.
                let bytes = grid.cell_count() as u64 * 14;
                medium::resources::check_memory(&format!("a generated {dims:?} volume"), bytes)
                    .map_err(|e| self.err("volume.dims", e.to_string()))?;
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
            VolumeSource::Supplied => "volume",
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
        let cell_size = match (&vol.cell_size, &placement) {
            (Some(v), _) => self.positive(v, "volume.cell_size")?,
            // A NIfTI file gives its voxel spacing (pixdim); the same rule as a .vdb's.
            (None, None) => match voxel_size {
                None => 1.0,
                Some([x, y, z]) if x == y && y == z && x.is_finite() && x > 0.0 => x,
                Some(p) => {
                    return Err(self.err(
                        "volume.cell_size",
                        format!(
                            "required key is missing: the file's voxel spacing (pixdim) {p:?} is not uniform and positive, and volrad's cells are cubes; give cell_size (positions are then voxel index × cell_size)"
                        ),
                    ))
                }
            },
            // A .vdb gives its voxel size; volrad's cells are cubes, so it must be uniform.
            (None, Some(p)) => p.uniform_voxel_size().ok_or_else(|| {
                self.err(
                    "volume.cell_size",
                    format!(
                        "required key is missing: the grid's voxel size {:?} is not uniform and volrad's cells are cubes; give cell_size",
                        p.voxel_size
                    ),
                )
            })?,
        };
        let file_origin = match &vol.coordinates {
            None => None,
            Some(v) => match self.string(v, "volume.coordinates")? {
                "grid" => None,
                "file" => {
                    let p = placement.as_ref().ok_or_else(|| {
                        self.err(
                            "volume.coordinates",
                            "`file` needs an OpenVDB (.vdb) volume, whose transform places it in a world",
                        )
                    })?;
                    if p.uniform_voxel_size() != Some(cell_size) {
                        return Err(self.err(
                            "volume.coordinates",
                            format!(
                                "`file` needs the grid's voxel size to be uniform and equal to cell_size {cell_size}; it is {:?}",
                                p.voxel_size
                            ),
                        ));
                    }
                    Some(DVec3::from_array(p.world_corner()))
                }
                other => {
                    return Err(self.err(
                        "volume.coordinates",
                        format!("unknown coordinates `{other}` (expected grid or file)"),
                    ))
                }
            },
        };
        let grid =
            Grid::new(data.dims, cell_size).map_err(|e| self.err("volume.dims", e.to_string()))?;
        let interpolation = match &vol.interpolation {
            // Smooth pictures unless the scene asks for cells (docs/scene-format.md).
            None => Interpolation::default(),
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
        Ok(Volume {
            source,
            data,
            grid,
            interpolation,
            sigma_scales: scales,
            sigma_tables,
            placement,
            file_origin,
        })
    }

    fn medium(&self, medium: toml::Value, volume: Volume) -> Result<Medium, SceneError> {
        let Volume {
            source,
            data,
            grid,
            interpolation,
            sigma_scales: scales,
            sigma_tables,
            placement,
            ..
        } = volume;
        let med: RawMedium = self.raw(medium, "medium")?;
        let albedo = self.transfer(&med.albedo, "medium.albedo", (0.0, 1.0), false)?;
        let blackbody = match &med.emission {
            Some(v) if is_blackbody(v) => {
                Some(self.blackbody(v, &data, &source, placement.as_ref())?)
            }
            _ => None,
        };
        let emission = match &med.emission {
            Some(v) if blackbody.is_none() => {
                self.transfer(v, "medium.emission", (0.0, f64::INFINITY), true)?
            }
            _ => vec![Transfer::Constant { value: 0.0 }],
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
            // Blackbody emission is coloured: the medium becomes RGB.
            if blackbody.is_some() { 3 } else { 1 },
        ]
        .into_iter()
        .max()
        .unwrap_or(1);
        let rgb_table = blackbody
            .as_ref()
            .map(|b| RgbTable::new(b.max_temperature()));
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
            let emission_c = match (&blackbody, &rgb_table) {
                (Some(b), Some(table)) => b.emission(c, table, &sigma_t, &albedo_c),
                _ => emission[c].apply(&data.values, &sigma_t),
            };
            channels.push(ChannelMedium {
                sigma_t,
                albedo: albedo_c,
                emission: emission_c,
            });
        }
        let medium = Medium::new(grid, channels, phase, interpolation, Some(data.values))
            .map_err(|e| self.err("medium", e.to_string()))?;
        Ok(medium)
    }

    /// `emission = { kind = "blackbody", temperature = T | grid = "name", scale = s }`: the
    /// temperature of every cell (kelvin), from a constant, a piecewise-linear transfer of the
    /// data value, or a second grid of the volume's `.vdb` file.
    fn blackbody(
        &self,
        v: &toml::Value,
        data: &VolumeData,
        source: &VolumeSource,
        placement: Option<&VdbPlacement>,
    ) -> Result<Blackbody, SceneError> {
        let key = "medium.emission";
        let (_, t) = self.kind_table(
            v,
            key,
            &[("blackbody", &[], &["temperature", "grid", "scale"])],
        )?;
        let scale = match t.get("scale") {
            Some(s) => self.non_negative(s, "medium.emission.scale")?,
            None => 1.0,
        };
        let t_key = "medium.emission.temperature";
        let g_key = "medium.emission.grid";
        let check = |x: f64, what: String| -> Result<(), SceneError> {
            if x.is_finite() && x <= MAX_TEMPERATURE {
                Ok(())
            } else {
                Err(self.err(
                    t_key,
                    format!("{what}{x} K: expected a finite temperature ≤ {MAX_TEMPERATURE} K"),
                ))
            }
        };
        let temperature = match (t.get("temperature"), t.get("grid")) {
            (Some(_), Some(_)) => {
                return Err(self.err(g_key, "give either `temperature` or `grid`, not both"))
            }
            (None, None) => {
                return Err(self.err(
                    t_key,
                    "required key for kind `blackbody` is missing (or give `grid = \"temperature\"` for a .vdb)",
                ))
            }
            (Some(tv), None) if tv.is_table() => {
                let (_, tt) = self.kind_table(tv, t_key, &[("piecewise-linear", &["points"], &[])])?;
                let points_key = join(t_key, "points");
                let mut channels = self.table_points(&tt["points"], &points_key)?;
                if channels.len() != 1 {
                    return Err(self.err(
                        points_key,
                        "each point must be [data value, kelvin]",
                    ));
                }
                let points = channels.remove(0);
                for p in &points {
                    check(p[1], format!("point [{}, {}] gives ", p[0], p[1]))?;
                }
                let table = PiecewiseLinear::new(points)
                    .map_err(|e| self.err(&points_key, e.to_string()))?;
                Temperature::PerCell(data.values.iter().map(|&x| table.eval(x as f64) as f32).collect())
            }
            (Some(tv), None) => {
                let x = match tv {
                    toml::Value::Float(x) => *x,
                    _ => self.number(tv, t_key)?,
                };
                check(x, String::new())?;
                Temperature::Uniform(x)
            }
            (None, Some(gv)) => {
                let name = self.string(gv, g_key)?;
                let (VolumeSource::File(path), Some(on)) = (source, placement) else {
                    return Err(self.err(
                        g_key,
                        "`grid` names a second grid of the volume's OpenVDB (.vdb) file; this volume is not one",
                    ));
                };
                let other = medium::vdb::read_vdb(path, Some(name))
                    .map_err(|e| self.err(g_key, e.to_string()))?;
                let op = &other.placement;
                if op.voxel_size != on.voxel_size || op.translation != on.translation || op.map != on.map {
                    return Err(self.err(
                        g_key,
                        format!(
                            "grid `{name}` has another transform ({} voxel {:?} at {:?}) than `{}` ({} voxel {:?} at {:?}); its voxels cannot be matched by index",
                            op.map, op.voxel_size, op.translation, on.grid, on.map, on.voxel_size, on.translation
                        ),
                    ));
                }
                let values = other.sample_on(on, data.dims);
                if let Some(i) = values.iter().position(|&x| !(x.is_finite() && x as f64 <= MAX_TEMPERATURE)) {
                    let [x, y, z] = Grid { dims: data.dims, cell_size: 1.0 }.coords(i);
                    return Err(self.err(
                        g_key,
                        format!(
                            "grid `{name}` holds {} K at cell ({x}, {y}, {z}); expected a finite temperature ≤ {MAX_TEMPERATURE} K",
                            values[i]
                        ),
                    ));
                }
                Temperature::PerCell(values)
            }
        };
        Ok(Blackbody { temperature, scale })
    }

    /// The `[[light]]` list: the lights, and the environment when one entry is
    /// `kind = "environment"` (at most one).
    fn lights(
        &self,
        light: Option<toml::Value>,
        medium: &Medium,
    ) -> Result<(Vec<Light>, Option<Environment>), SceneError> {
        let has_emission = medium.channels().iter().any(|c| !c.emission.is_zero());
        let lights = match light {
            None => Vec::new(),
            Some(v) => {
                let list = v
                    .as_array()
                    .ok_or_else(|| self.err("light", "expected an array of tables ([[light]])"))?;
                if list.len() > MAX_LIGHTS {
                    return Err(self.err(
                        "light",
                        format!(
                            "{} lights: at most {MAX_LIGHTS} (each costs a pass through the grid)",
                            list.len()
                        ),
                    ));
                }
                list.iter()
                    .enumerate()
                    .map(|(i, l)| self.light(l, &format!("light[{i}]")))
                    .collect::<Result<Vec<_>, _>>()?
            }
        };
        let mut environment = None;
        let mut kept = Vec::with_capacity(lights.len());
        for (i, light) in lights.into_iter().enumerate() {
            match light {
                SceneLight::Light(l) => kept.push(l),
                SceneLight::Environment(..) if environment.is_some() => {
                    return Err(self.err(
                        format!("light[{i}].kind"),
                        "a second environment light: a scene has at most one",
                    ))
                }
                SceneLight::Environment(e, placed) => {
                    // A sky brings its sun: the directional light the model is lit by; a map
                    // the small bright sources split off it.
                    if let Some((to_sun, irradiance)) = e.sun() {
                        kept.push(Light::Directional {
                            direction: -to_sun,
                            irradiance,
                        });
                    }
                    kept.extend(placed);
                    environment = Some(e)
                }
            }
        }
        if kept.is_empty() && environment.is_none() && !has_emission {
            return Err(self.err(
                "light",
                "no light and no emission: add a [[light]] or a non-zero medium.emission",
            ));
        }
        Ok((kept, environment))
    }

    /// `[background] radiance`; with an environment light the background is the environment
    /// (what camera rays see where they leave the grid), so giving both is refused (and
    /// `background` is then 0: renders look the environment up by direction).
    fn background(
        &self,
        background: Option<toml::Value>,
        environment: Option<&Environment>,
    ) -> Result<f64, SceneError> {
        Ok(match (background, environment) {
            (None, None) => 0.0,
            (None, Some(_)) => 0.0,
            (Some(_), Some(_)) => {
                return Err(self.err(
                    "background",
                    "the environment light is the background: remove [background] (camera \
                     rays that leave the grid see the environment)",
                ))
            }
            (Some(v), None) => {
                let b: RawBackground = self.raw(v, "background")?;
                self.non_negative(&b.radiance, "background.radiance")?
            }
        })
    }

    /// Under a ground light comes from above it: a directional light must travel down, a point
    /// or spot light must be over the plane (the ground would block what the solvers would
    /// otherwise carry into the medium from below).
    fn lights_above(&self, lights: &[Light], ground: &Ground) -> Result<(), SceneError> {
        for (i, light) in lights.iter().enumerate() {
            match *light {
                Light::Directional { direction, .. } if direction.z >= 0.0 => {
                    return Err(self.err(
                        format!("light[{i}].direction"),
                        format!(
                            "[{:.3}, {:.3}, {:.3}] does not travel down: under a [ground] light \
                             comes from above (direction z < 0)",
                            direction.x, direction.y, direction.z
                        ),
                    ));
                }
                Light::Point { position, .. } | Light::Spot { position, .. }
                    if position.z <= ground.height() =>
                {
                    return Err(self.err(
                        format!("light[{i}].position"),
                        format!(
                            "[{}, {}, {}] is not above the ground (z = {})",
                            position.x,
                            position.y,
                            position.z,
                            ground.height()
                        ),
                    ));
                }
                _ => {}
            }
        }
        Ok(())
    }

    /// `[ground] height, albedo`: a Lambertian plane under the grid (its height at most the
    /// grid's bottom, 0 by default; in the file's world with `coordinates = "file"`), seen
    /// from above; the world's up is +z, so an environment must have that up too.
    fn ground(
        &self,
        ground: toml::Value,
        grid: &Grid,
        environment: Option<&Environment>,
        file_origin: Option<DVec3>,
    ) -> Result<Ground, SceneError> {
        let g: RawGround = self.raw(ground, "ground")?;
        let mut height = match &g.height {
            Some(v) => self.number(v, "ground.height")?,
            None => file_origin.map_or(0.0, |o| o.z),
        };
        if let Some(o) = file_origin {
            height -= o.z;
        }
        if height > 1e-9 * grid.cell_size {
            return Err(self.err(
                "ground.height",
                format!(
                    "{height}: the ground lies under the volume, at most at the grid's bottom \
                     (z = 0{})",
                    file_origin.map_or(String::new(), |o| format!(", {} in the file's world", o.z))
                ),
            ));
        }
        let albedo = match &g.albedo {
            Some(v) => {
                let values = self.grey_or_rgb(v, "ground.albedo", &|x| {
                    if (0.0..=1.0).contains(&x) {
                        Ok(())
                    } else {
                        Err("expected an albedo in [0, 1]".into())
                    }
                })?;
                [0, 1, 2].map(|c| values[c.min(values.len() - 1)])
            }
            None => [DEFAULT_GROUND_ALBEDO; 3],
        };
        if let Some(up) = environment.and_then(environment_up) {
            if (up - DVec3::Z).length() > 1e-9 {
                return Err(self.err(
                    "ground",
                    format!(
                        "the environment's up is {up:?}: a ground is the plane z = height, so give \
                         the environment up = [0, 0, 1]"
                    ),
                ));
            }
        }
        Ground::new(height.min(0.0), albedo).map_err(|e| self.err("ground", e.to_string()))
    }

    fn solve(
        &self,
        solve: Option<toml::Value>,
        phase: &PhaseFunction,
    ) -> Result<SolveSettings, SceneError> {
        Ok(match solve {
            None => SolveSettings::default_for(phase),
            Some(v) => {
                let s: RawSolve = self.raw(v, "solve")?;
                let mut out = SolveSettings::default_for(phase);
                if let Some(m) = &s.method {
                    let name = self.string(m, "solve.method")?;
                    out.method = name
                        .parse()
                        .map_err(|e: UnknownSolveMethod| self.err("solve.method", e.to_string()))?;
                    out.iteration = out.method.default_iteration();
                }
                if let Some(b) = &s.bins {
                    out.bins = self.bins(b)?;
                }
                if let Some(it) = &s.iteration {
                    let text = self.string(it, "solve.iteration")?;
                    out.iteration = text.parse().map_err(|e: ParseMethodError| {
                        self.err("solve.iteration", e.to_string())
                    })?;
                }
                if let Some(t) = &s.tolerance {
                    out.tolerance = self.positive(t, "solve.tolerance")?;
                }
                if let Some(m) = &s.max_iterations {
                    out.max_iterations = self.integer(m, "solve.max_iterations", 1)? as usize;
                }
                if let Some(r) = &s.transport_refinement {
                    out.transport_refinement = self.transport_refinement(r)?;
                }
                if let Some(c) = &s.forward_peak_cone {
                    let key = "solve.forward_peak_cone";
                    let degrees = self.non_negative(c, key)?;
                    forward_truncation_fraction(degrees, phase)
                        .map_err(|e| self.err(key, e.to_string()))?;
                    out.forward_peak_cone = Some(degrees);
                }
                if let Some(n) = &s.photons {
                    let key = "solve.photons";
                    let n = self.integer(n, key, 1)? as u64;
                    if !PHOTON_RANGE.contains(&n) {
                        return Err(self.err(
                            key,
                            format!(
                                "{n}: expected a whole number of photons per light from {} to {}",
                                PHOTON_RANGE.start(),
                                PHOTON_RANGE.end()
                            ),
                        ));
                    }
                    out.photons = n;
                }
                if let Some(v) = &s.transport_scale {
                    out.transport_scale = self.transport_scale(v)?;
                }
                if let Some(conflict) = out.transport_conflict() {
                    return Err(self.err("solve.transport_refinement", conflict));
                }
                out
            }
        })
    }

    /// A key that is `"auto"` (`None`) or a whole number `valid` accepts; anything else is
    /// refused naming `key` and what it `expects`.
    fn auto_or_count(
        &self,
        v: &toml::Value,
        key: &str,
        expects: &str,
        valid: impl Fn(i64) -> bool,
    ) -> Result<Option<usize>, SceneError> {
        if let toml::Value::String(text) = v {
            return if text == "auto" {
                Ok(None)
            } else {
                Err(self.err(key, format!("\"{text}\": expected \"auto\" or {expects}")))
            };
        }
        let n = self.integer(v, key, 1)?;
        if !valid(n) {
            return Err(self.err(key, format!("{n}: expected \"auto\" or {expects}")));
        }
        Ok(Some(n as usize))
    }

    /// `[solve] transport_refinement`: `"auto"` or a whole number of transport cells per side
    /// of a data cell.
    fn transport_refinement(&self, v: &toml::Value) -> Result<TransportRefinement, SceneError> {
        let expects = format!(
            "a whole number from 1 to {MAX_TRANSPORT_SPLIT} (transport cells per data cell \
             side; the solve's cells and its cost grow r³ times)"
        );
        let r = self.auto_or_count(v, "solve.transport_refinement", &expects, |r| {
            r <= MAX_TRANSPORT_SPLIT as i64
        })?;
        Ok(r.map_or(TransportRefinement::Auto, TransportRefinement::Fixed))
    }

    /// `[solve] bins`: `"auto"` or one of [`VALID_BINS`].
    fn bins(&self, v: &toml::Value) -> Result<BinCount, SceneError> {
        let expects = format!("6n² for n = 1..={MAX_FACE_DIVISIONS} ({VALID_BINS:?})");
        let bins = self.auto_or_count(v, "solve.bins", &expects, |b| {
            VALID_BINS.contains(&(b as usize))
        })?;
        Ok(bins.map_or(BinCount::Auto, BinCount::Fixed))
    }

    /// `[solve] transport_scale`: `"auto"` or a whole number of data cells per side.
    fn transport_scale(&self, v: &toml::Value) -> Result<TransportScale, SceneError> {
        let expects = format!(
            "a whole number from 1 to {MAX_TRANSPORT_SCALE} (data cells per side of a \
             transport cell)"
        );
        let s = self.auto_or_count(v, "solve.transport_scale", &expects, |s| {
            s <= MAX_TRANSPORT_SCALE as i64
        })?;
        Ok(s.map_or(TransportScale::Auto, TransportScale::Fixed))
    }

    fn render(
        &self,
        render: Option<toml::Value>,
        method: SolveMethod,
    ) -> Result<RenderSettings, SceneError> {
        let default_model = if method == SolveMethod::None {
            OpticalModel::EmissionAbsorption
        } else {
            OpticalModel::Scattering
        };
        Ok(match render {
            None => RenderSettings {
                model: default_model,
                exposure: None,
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
                    Some(e) => Some(self.positive(e, "render.exposure")?),
                    None => None,
                };
                let spp = match &r.spp {
                    Some(s) => {
                        let n = self.integer(s, "render.spp", 1)?;
                        u32::try_from(n)
                            .ok()
                            .filter(|&n| n <= gather::MAX_SPP)
                            .ok_or_else(|| {
                                self.err(
                                    "render.spp",
                                    format!(
                                        "{n}: expected a whole number from 1 to {}",
                                        gather::MAX_SPP
                                    ),
                                )
                            })?
                    }
                    None => 1,
                };
                RenderSettings {
                    model,
                    exposure,
                    spp,
                }
            }
        })
    }

    /// The `[[camera]]` list; none at all is fine (cameras are render-time: a render without
    /// one frames the whole grid), but an empty `camera = []` says nothing and is refused.
    fn cameras(&self, camera: Option<toml::Value>) -> Result<Vec<CameraSpec>, SceneError> {
        let Some(camera) = camera else {
            return Ok(Vec::new());
        };
        let list = camera
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
        Ok(cameras)
    }
}
