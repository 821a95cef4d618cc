//! Solution files: the solved source terms plus everything a render needs (grid and σt, the
//! light pass, the phase function, lights and background, the method and its report, a hash
//! of the scene), so one solve serves many views. The byte layout lives in [`container`]
//! alone and the metadata's shape in [`records`] (types owned by this module, so a change to
//! a library type cannot change the file unnoticed); this module maps the domain types onto
//! named arrays and those records.

pub mod container;
pub mod records;
pub mod rows;

use std::borrow::Cow;
use std::path::Path;
use std::sync::Arc;

use gather::light_depth::{LightDepth, LightDepthModel};
use gather::RenderIndex;
use medium::coarsening::Coarsening;
use medium::ground::GroundRadiance;
use medium::light_pass::{LightField, LightPass};
use medium::{CellValues, ChannelMedium, Environment, Light, Medium};
use rayon::prelude::*;
use records::{ChannelRecord, FieldKind, MetaRecord};
use scene::{CameraSpec, OpticalModel, RenderSettings, SolveMethod};

pub use container::{Container, ContainerError};
pub use rows::CellRows;

/// The solved scattered light of one colour channel.
#[derive(Clone, Debug, PartialEq)]
pub enum ScatteredField {
    /// Single scattering only (or no scattering): the render evaluates the first bounce from
    /// the light pass and needs nothing else.
    None,
    /// Zonal: `source` is the solved `g` per cell (radiance per length, isotropic);
    /// `higher_order = g − E` is what the render adds to the exact first bounce.
    Isotropic {
        source: Vec<f32>,
        higher_order: Vec<f32>,
    },
    /// Discrete ordinates: `fluence[cell]`, the bins' radiance integrated over directions
    /// (`Σ_l I_l Ω_l`: all light but the lights' unscattered beams — the scattered light, and
    /// the environment's, collided or not), and `higher_order`, per cell and bin `l` the
    /// source of second and higher orders scattered into bin `l` (radiance per length), kept
    /// for the cells that scatter only.
    Binned {
        fluence: Vec<f32>,
        higher_order: CellRows,
    },
    /// Blasi & Wuethrich's two-pass method: second and higher orders stored per optical
    /// voxel and direction bin by the energetization pass.
    TwoPass(Box<montecarlo::two_pass::TwoPassSolution>),
}

/// Values per transport cell of [`ChannelSolution::emitted_beam`]: `σs φ` of the emitters'
/// first scattering, the incident light's shape (its cone's weight and cosine) and its axis.
pub const EMITTER_BEAM_VALUES: usize = 6;

/// Discrete ordinates' emitters' first scattering, as the render draws it in the view's own
/// direction ([`crate::engine::sources::EmitterBeamSource`]; the bins then hold no first
/// scattering of the emission). Made by [`crate::engine::methods::emitter_beam`].
#[derive(Clone, Debug, PartialEq)]
pub struct EmitterBeam {
    /// Per transport cell [`EMITTER_BEAM_VALUES`] values: `σs φ`, the incident light's shape
    /// (a cone and a rest) and its axis.
    pub shapes: Vec<f32>,
    /// The widest-lit cells' incident light in direction bins
    /// ([`medium::emitter_pass::EmitterPass::binned_row`]'s rows, [`EMITTER_BIN_VALUES`]
    /// wide): what a cone and a rest cannot hold beside an emitting region.
    pub binned: CellRows,
}

/// Values per row of [`EmitterBeam::binned`].
pub const EMITTER_BIN_VALUES: usize =
    medium::phase::BINNED_VALUES * medium::phase::DirectionBins::INCIDENT;

/// Channel `c`'s [`CellRows`] of `width` values as a file stores them: the kept mask
/// `{name}_kept/{c}` over `cells` cells ([`CellRows::kept_mask`]) and the kept rows
/// `{name}/{c}` ([`CellRows::values`]), taken out of the file's arrays by `take`. The outer
/// error is `take`'s; the inner one names what does not fit.
fn take_rows(
    take: &mut impl FnMut(String, usize) -> Result<Vec<f32>, SolutionError>,
    name: &str,
    c: usize,
    cells: usize,
    width: usize,
) -> Result<Result<CellRows, String>, SolutionError> {
    let kept = take(format!("{name}_kept/{c}"), cells)?;
    let kept_cells = kept.iter().filter(|&&k| k == 1.0).count();
    let rows = take(format!("{name}/{c}"), kept_cells * width)?;
    Ok(CellRows::from_parts(width, &kept, rows))
}

/// Direction bins as stored: what a render needs to look radiance up by direction (in the
/// file as [`records::BinsRecord`]).
#[derive(Clone, Debug, PartialEq)]
pub struct StoredBins {
    /// `n` of the `6 n²` cube-face construction.
    pub face_resolution: usize,
    pub directions: Vec<[f64; 3]>,
    pub solid_angles: Vec<f64>,
}

#[derive(Clone, Debug, PartialEq)]
pub struct ChannelSolution {
    pub light_pass: LightPass,
    pub scattered: ScatteredField,
    pub report: Option<solver::SolveReport>,
    /// The emitters' uncollided fluence as each cell's mean (the emitter pass), when the
    /// method solved with it as its first-collision source (zonal methods and discrete
    /// ordinates in a channel that emits); `None` otherwise.
    pub emitted_fluence: Option<Vec<f32>>,
    /// Discrete ordinates with an emitter pass: the emitters' first scattering, drawn by the
    /// render in the view's own direction. `None` otherwise.
    pub emitted_beam: Option<EmitterBeam>,
    /// Built from the light pass on first render, shared by every later one; not stored.
    pub render_cache: RenderCache,
}

/// What renders derive from a channel's light pass and medium and can share: the first
/// bounce's light-depth model ([`LightDepthModel`], whose automatic choice and refined light
/// passes cost more than a render) and the channel's [`RenderIndex`] under the solution's
/// render model (empty-space distances: a serial walk over every cell). Not part of the file;
/// equal to any other cache.
#[derive(Clone, Default)]
pub struct RenderCache {
    /// The model, or why it could not be built (kept as text: renders report it each time).
    light_depth: std::sync::OnceLock<Result<LightDepthModel, String>>,
    /// The index, or why it could not be built.
    render_index: std::sync::OnceLock<Result<RenderIndex, String>>,
    /// `ln` of a binned higher-order source (−∞ where it is 0), for interpolating between bin
    /// centres geometrically.
    log_source: std::sync::OnceLock<Vec<f32>>,
    /// The transport grid's medium and what renders need of it, when it is coarser than the
    /// data grid.
    transport: std::sync::OnceLock<Result<TransportCache, String>>,
    /// `1/σs` per data cell, for `nearest` renders of a source solved on the data grid.
    own_grid: std::sync::OnceLock<InverseScattering>,
    /// A per-cell source's centre values that keep each cell's mean (`nearest` renders).
    centre_values: std::sync::OnceLock<Vec<f32>>,
    /// A two-pass field's mean over its direction bins per cell, and the largest ratio of a
    /// cell's value in one bin to that mean ([`crate::engine::sources::TwoPassSource`]).
    two_pass_means: std::sync::OnceLock<(Vec<f32>, f64)>,
    /// What the emitters' first scattering (`emitted_beam`) is drawn with: the phase
    /// function's table for incident shapes (2.4 ms to build at g = 0.85, 8.0 ms at 0.95:
    /// `cargo bench --bench render -- emitter_shape`), the source's bound and which cells
    /// emit ([`crate::engine::sources::EmitterBeamSource`]).
    emitter_beam: std::sync::OnceLock<(medium::phase::ShapeScattering, f64, Vec<bool>)>,
    /// `fluence` on the grid the channel's fields live on (the transport grid's, at most a
    /// few MB): tracing the cells' sources there can take seconds, and the service's slices
    /// ask for it again for every plane.
    fluence: std::sync::OnceLock<Result<Vec<f64>, String>>,
}

/// `1/σs` of one channel per cell of the grid a source lives on (0 where a cell does not
/// scatter): a stored source divided by it is the in-scattered radiance `Q/σs`, which a render
/// interpolates between cell centres; and a bound on the data grid's σs.
#[derive(Clone)]
pub struct InverseScattering {
    pub inverse_sigma_s: Vec<f32>,
    /// An upper bound on the channel's σs on the data grid.
    pub max_sigma_s: f64,
}

impl InverseScattering {
    /// Of channel `c` of `medium`, on its own grid.
    pub fn of_channel(medium: &Medium, c: usize) -> InverseScattering {
        let ch = &medium.channels()[c];
        InverseScattering::of(ch, ch)
    }

    /// Of channel `coarse` (cells of the grid the source lives on), bounded by the data
    /// grid's channel `fine`.
    fn of(coarse: &medium::ChannelMedium, fine: &medium::ChannelMedium) -> InverseScattering {
        let inverse_sigma_s = (0..coarse.sigma_t.len())
            .map(|o| {
                let s = coarse.sigma_s(o);
                if s > 0.0 {
                    1.0 / s
                } else {
                    0.0
                }
            })
            .collect();
        InverseScattering {
            inverse_sigma_s,
            max_sigma_s: fine.max_sigma_t() as f64 * fine.albedo.max() as f64,
        }
    }
}

/// The medium on a solution's transport grid and what a render of channel `c` reads from it.
#[derive(Clone)]
pub struct TransportCache {
    /// [`Coarsening::medium`] of the solution's medium.
    pub medium: Medium,
    /// Channel `c`'s `1/σs` per transport cell: what the render spreads over the data cells.
    pub scattering: InverseScattering,
}

impl RenderCache {
    /// The automatic light-depth model of `pass` (the same `pass` on every call). Renders
    /// that ask while another builds it wait for that build instead of repeating it.
    pub fn light_depth(&self, pass: &LightPass) -> anyhow::Result<&LightDepthModel> {
        self.light_depth
            .get_or_init(|| {
                LightDepthModel::build(pass, LightDepth::Auto).map_err(|e| e.to_string())
            })
            .as_ref()
            .map_err(|e| anyhow::anyhow!("first-bounce light-depth model: {e}"))
    }

    /// The transport grid's medium of `medium` under `transport` and channel `c`'s render
    /// data ([`TransportCache`]; the same arguments on every call).
    pub fn transport(
        &self,
        medium: &Medium,
        transport: &Coarsening,
        c: usize,
    ) -> anyhow::Result<&TransportCache> {
        self.transport
            .get_or_init(|| {
                let coarse = transport.medium(medium).map_err(|e| e.to_string())?;
                let ch = coarse
                    .channels()
                    .get(c)
                    .ok_or_else(|| format!("channel {c} does not exist"))?;
                let scattering = InverseScattering::of(ch, &medium.channels()[c]);
                Ok(TransportCache {
                    medium: coarse,
                    scattering,
                })
            })
            .as_ref()
            .map_err(|e| anyhow::anyhow!("transport grid: {e}"))
    }

    /// Channel `c`'s `1/σs` per cell of `medium` (the solution's own, on every call), for
    /// a source solved on the data grid.
    pub fn own_grid(&self, medium: &Medium, c: usize) -> &InverseScattering {
        self.own_grid
            .get_or_init(|| InverseScattering::of_channel(medium, c))
    }

    /// The channel's per-cell source's centre values, made by `make` on the first call (the
    /// same source on every call).
    pub fn centre_values(&self, make: impl FnOnce() -> Vec<f32>) -> &[f32] {
        self.centre_values.get_or_init(make)
    }

    /// The channel's two-pass field's means over directions and their largest bin ratio,
    /// made by `make` on the first call (the same field on every call).
    pub fn two_pass_means(&self, make: impl FnOnce() -> (Vec<f32>, f64)) -> (&[f32], f64) {
        let (means, ratio) = self.two_pass_means.get_or_init(make);
        (means, *ratio)
    }

    /// The channel's table, bound and emitting cells for drawing its emitters' first
    /// scattering, made by `make` on the first call (the same solution on every call).
    pub fn emitter_beam(
        &self,
        make: impl FnOnce() -> (medium::phase::ShapeScattering, f64, Vec<bool>),
    ) -> (&medium::phase::ShapeScattering, f64, &[bool]) {
        let (table, bound, emitting) = self.emitter_beam.get_or_init(make);
        (table, *bound, emitting)
    }

    /// The channel's `fluence` on the grid its fields live on, made by `make` on the first
    /// call (the same on every call; an error is kept and reported again).
    pub fn fluence(
        &self,
        make: impl FnOnce() -> anyhow::Result<Vec<f64>>,
    ) -> anyhow::Result<&[f64]> {
        self.fluence
            .get_or_init(|| make().map_err(|e| format!("{e:#}")))
            .as_deref()
            .map_err(|e| anyhow::anyhow!("{e}"))
    }

    /// `ln` of `values` (the channel's binned higher-order source, the same on every call).
    pub fn log_source(&self, values: &[f32]) -> &[f32] {
        self.log_source
            .get_or_init(|| values.par_iter().map(|&v| v.ln()).collect())
    }

    /// Channel `channel`'s render index of `medium` (the solution's own, on every call) under
    /// `model`. The first call's model is the one kept (a solution renders under its own
    /// model); another model is refused rather than served a wrong index.
    pub fn render_index(
        &self,
        medium: &Medium,
        channel: usize,
        model: OpticalModel,
    ) -> anyhow::Result<&RenderIndex> {
        let index = self
            .render_index
            .get_or_init(|| RenderIndex::new(medium, channel, model).map_err(|e| e.to_string()))
            .as_ref()
            .map_err(|e| anyhow::anyhow!("render index: {e}"))?;
        if index.model() != model {
            anyhow::bail!(
                "render index kept for model {:?}, asked for {model:?}",
                index.model()
            );
        }
        Ok(index)
    }
}

impl Solution {
    /// Builds what renders derive from the solution and share (each channel's
    /// [`RenderCache`]), so that the first view is as fast as the rest. Errors are left for the
    /// renders to report.
    ///
    /// They are built side by side (the render index's distance transform is serial, and on
    /// a large grid each is a fraction of a second of mostly fresh memory); a channel whose
    /// caches are all built costs a few lookups, so every render may call this.
    pub fn prepare_renders(&self) {
        for (c, ch) in self.channels.iter().enumerate() {
            let cache = &ch.render_cache;
            let warn = |result: anyhow::Result<()>| {
                if let Err(e) = result {
                    tracing::warn!("preparing renders: {e:#}");
                }
            };
            let light_depth = || warn(cache.light_depth(&ch.light_pass).map(drop));
            let render_index = || {
                warn(
                    cache
                        .render_index(&self.medium, c, self.render.model)
                        .map(drop),
                )
            };
            let solved_field = || {
                if let ScatteredField::Binned { higher_order, .. } = &ch.scattered {
                    cache.log_source(higher_order.values());
                }
                if !self.transport.is_data_grid() {
                    warn(cache.transport(&self.medium, &self.transport, c).map(drop));
                }
            };
            // Each cache beside whether it is built already, so that a view after the first
            // starts no thread.
            let caches: [(bool, &(dyn Fn() + Sync)); 3] = [
                (cache.render_index.get().is_some(), &render_index),
                (
                    (!matches!(ch.scattered, ScatteredField::Binned { .. })
                        || cache.log_source.get().is_some())
                        && (self.transport.is_data_grid() || cache.transport.get().is_some()),
                    &solved_field,
                ),
                (cache.light_depth.get().is_some(), &light_depth),
            ];
            let mut to_build = caches.iter().filter(|(built, _)| !built).map(|(_, f)| f);
            let Some(last) = to_build.next_back() else {
                continue;
            };
            // On threads of their own, not rayon tasks: a rayon worker that waits inside one
            // cache's initialisation (its parallel loops) may run another task meanwhile, and
            // a task initialising the same cache there would wait on itself.
            std::thread::scope(|scope| {
                for build in to_build {
                    scope.spawn(build);
                }
                last();
            });
        }
    }
}

impl PartialEq for RenderCache {
    fn eq(&self, _: &Self) -> bool {
        true
    }
}

impl std::fmt::Debug for RenderCache {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RenderCache")
            .field("light_depth", &self.light_depth.get())
            .field("render_index", &self.render_index.get().map(|r| r.is_ok()))
            .finish()
    }
}

/// A solved scene, as written by `volrad solve` and read by `volrad render --solution`.
#[derive(Clone, Debug, PartialEq)]
pub struct Solution {
    pub scene_hash: String,
    pub scene_origin: String,
    pub method: SolveMethod,
    pub medium: Medium,
    pub lights: Vec<Light>,
    /// The scene's environment light, which the solved field already contains.
    pub environment: Option<Environment>,
    pub background: f64,
    /// The ground and the light it reflects, per patch and channel, as the solve left it.
    pub ground: Option<Arc<GroundRadiance>>,
    pub render: RenderSettings,
    pub cameras: Vec<CameraSpec>,
    pub bins: Option<StoredBins>,
    /// The transport grid the scattered fields and the emitters' fluence live on (blocks of
    /// `scale³` cells of the medium's grid; scale 1 is the grid itself); the light pass is on
    /// the medium's grid.
    pub transport: Coarsening,
    pub channels: Vec<ChannelSolution>,
}

#[derive(Debug, thiserror::Error)]
pub enum SolutionError {
    #[error(transparent)]
    Container(#[from] ContainerError),
    #[error("{path}: inconsistent solution: {message}")]
    Inconsistent { path: String, message: String },
}

fn uniform_or_array<'a>(
    values: &'a CellValues,
    name: String,
    arrays: &mut Vec<(String, Cow<'a, [f32]>)>,
) -> Option<f32> {
    match values {
        CellValues::Uniform(v) => Some(*v),
        CellValues::PerCell(v) => {
            arrays.push((name, Cow::Borrowed(v)));
            None
        }
    }
}

impl Solution {
    /// The file's contents, the arrays borrowed from the solution.
    fn to_container(&self) -> Container<'_, MetaRecord> {
        let mut arrays = Vec::new();
        let mut channels = Vec::new();
        for (c, (ch, sol)) in self
            .medium
            .channels()
            .iter()
            .zip(&self.channels)
            .enumerate()
        {
            arrays.push((format!("sigma_t/{c}"), Cow::Borrowed(&ch.sigma_t[..])));
            let albedo = uniform_or_array(&ch.albedo, format!("albedo/{c}"), &mut arrays);
            let emission = uniform_or_array(&ch.emission, format!("emission/{c}"), &mut arrays);
            for (l, f) in sol.light_pass.fields.iter().enumerate() {
                arrays.push((
                    format!("light/{c}/{l}/cell_irradiance"),
                    Cow::Borrowed(&f.cell_irradiance[..]),
                ));
                arrays.push((
                    format!("light/{c}/{l}/corner_optical_depth"),
                    Cow::Borrowed(&f.corner_optical_depth[..]),
                ));
            }
            let mut two_pass = None;
            let field = match &sol.scattered {
                ScatteredField::None => FieldKind::None,
                ScatteredField::TwoPass(t) => {
                    let mut record: records::TwoPassRecord = t.as_ref().into();
                    // The fields go with the arrays: metadata stays kilobytes.
                    arrays.push((
                        format!("two_pass/{c}/voxel_source"),
                        Cow::Owned(std::mem::take(&mut record.voxel_source)),
                    ));
                    arrays.push((
                        format!("two_pass/{c}/cell_share"),
                        Cow::Owned(std::mem::take(&mut record.cell_share)),
                    ));
                    two_pass = Some(record);
                    FieldKind::TwoPass
                }
                ScatteredField::Isotropic {
                    source,
                    higher_order,
                } => {
                    arrays.push((format!("source/{c}"), Cow::Borrowed(&source[..])));
                    arrays.push((
                        format!("higher_order/{c}"),
                        Cow::Borrowed(&higher_order[..]),
                    ));
                    FieldKind::Isotropic
                }
                ScatteredField::Binned {
                    fluence,
                    higher_order,
                } => {
                    arrays.push((format!("fluence/{c}"), Cow::Borrowed(&fluence[..])));
                    arrays.push((
                        format!("higher_order_kept/{c}"),
                        Cow::Owned(higher_order.kept_mask()),
                    ));
                    arrays.push((
                        format!("higher_order/{c}"),
                        Cow::Borrowed(higher_order.values()),
                    ));
                    FieldKind::Binned
                }
            };
            if let Some(f) = &sol.emitted_fluence {
                arrays.push((format!("emitted_fluence/{c}"), Cow::Borrowed(&f[..])));
            }
            if let Some(b) = &sol.emitted_beam {
                arrays.push((format!("emitted_beam/{c}"), Cow::Borrowed(&b.shapes[..])));
                arrays.push((
                    format!("emitted_bins_kept/{c}"),
                    Cow::Owned(b.binned.kept_mask()),
                ));
                arrays.push((
                    format!("emitted_bins/{c}"),
                    Cow::Borrowed(b.binned.values()),
                ));
            }
            channels.push(ChannelRecord {
                albedo,
                emission,
                has_emitted_fluence: sol.emitted_fluence.is_some(),
                has_emitted_beam: sol.emitted_beam.is_some(),
                light_energy: sol
                    .light_pass
                    .fields
                    .iter()
                    .map(|f| (&f.energy).into())
                    .collect(),
                field,
                report: sol.report.as_ref().map(Into::into),
                two_pass,
            });
        }
        if let Some(d) = self.medium.data() {
            arrays.push(("data".into(), Cow::Borrowed(d)));
        }
        if let Some(map) = self
            .environment
            .as_ref()
            .and_then(records::environment_map_array)
        {
            arrays.push(("environment/map".into(), Cow::Owned(map)));
        }
        if let Some(g) = &self.ground {
            for (c, values) in g.radiance().iter().enumerate() {
                arrays.push((format!("ground/{c}"), Cow::Borrowed(&values[..])));
            }
        }
        Container {
            meta: MetaRecord {
                volrad_version: env!("CARGO_PKG_VERSION").into(),
                scene_hash: self.scene_hash.clone(),
                scene_origin: self.scene_origin.clone(),
                method: (&self.method).into(),
                grid: (self.medium.grid()).into(),
                phase: (&self.medium.phase()).into(),
                interpolation: (&self.medium.interpolation()).into(),
                has_data: self.medium.data().is_some(),
                lights: self.lights.iter().map(Into::into).collect(),
                environment: self.environment.as_ref().map(Into::into),
                background: self.background,
                ground: self.ground.as_deref().map(Into::into),
                render: (&self.render).into(),
                cameras: self.cameras.iter().map(Into::into).collect(),
                bins: self.bins.as_ref().map(Into::into),
                transport_scale: self.transport.scale() as u64,
                transport_split: self.transport.split_factor() as u64,
                channels,
            },
            arrays,
        }
    }

    fn from_container(
        mut c: Container<'static, MetaRecord>,
        path: &Path,
    ) -> Result<Solution, SolutionError> {
        let bad = |message: String| SolutionError::Inconsistent {
            path: path.display().to_string(),
            message,
        };
        let meta = c.meta;
        let grid = meta.grid.into_library().map_err(bad)?;
        let phase = meta.phase.into_library().map_err(bad)?;
        let lights = meta
            .lights
            .into_iter()
            .enumerate()
            .map(|(l, r)| r.into_library().map_err(|e| bad(format!("light {l}: {e}"))))
            .collect::<Result<Vec<Light>, _>>()?;
        let render = meta.render.into_library().map_err(bad)?;
        let cameras: Vec<CameraSpec> = meta.cameras.into_iter().map(|r| r.into_library()).collect();
        let bins = meta
            .bins
            .map(|b| b.into_library())
            .transpose()
            .map_err(bad)?;
        let cells = grid.cell_count();
        let transport = match (
            usize::try_from(meta.transport_scale),
            usize::try_from(meta.transport_split),
        ) {
            (Ok(1), Ok(split)) if split > 1 => {
                Coarsening::split(&grid, split).map_err(|e| e.to_string())
            }
            (Ok(scale), Ok(1)) => Coarsening::new(&grid, scale).map_err(|e| e.to_string()),
            _ => Err(format!(
                "transport scale {} and split {}: at most one may be above 1",
                meta.transport_scale, meta.transport_split
            )),
        }
        .map_err(bad)?;
        let transport_cells = transport.transport().cell_count();
        let mut take = |name: String, len: usize| -> Result<Vec<f32>, SolutionError> {
            let pos = c
                .arrays
                .iter()
                .position(|(n, _)| *n == name)
                .ok_or_else(|| bad(format!("array `{name}` is missing")))?;
            let v = std::mem::take(&mut c.arrays[pos].1).into_owned();
            if v.len() != len {
                return Err(bad(format!(
                    "array `{name}` has {} values, expected {len}",
                    v.len()
                )));
            }
            Ok(v)
        };
        let bin_count = bins.as_ref().map_or(0, |b| b.directions.len());
        let mut medium_channels = Vec::new();
        let mut channels = Vec::new();
        for (ci, cm) in meta.channels.into_iter().enumerate() {
            let sigma_t = take(format!("sigma_t/{ci}"), cells)?;
            let albedo = match cm.albedo {
                Some(v) => CellValues::Uniform(v),
                None => CellValues::PerCell(take(format!("albedo/{ci}"), cells)?),
            };
            let emission = match cm.emission {
                Some(v) => CellValues::Uniform(v),
                None => CellValues::PerCell(take(format!("emission/{ci}"), cells)?),
            };
            if cm.light_energy.len() != lights.len() {
                return Err(bad(format!(
                    "channel {ci} has {} light fields for {} lights",
                    cm.light_energy.len(),
                    lights.len()
                )));
            }
            let mut fields = Vec::new();
            for (l, (light, energy)) in lights.iter().zip(cm.light_energy).enumerate() {
                fields.push(LightField {
                    light: *light,
                    cell_irradiance: take(format!("light/{ci}/{l}/cell_irradiance"), cells)?,
                    corner_optical_depth: std::sync::Arc::new(take(
                        format!("light/{ci}/{l}/corner_optical_depth"),
                        grid.corner_count(),
                    )?),
                    energy: energy.into_library(),
                });
            }
            let scattered = match cm.field {
                FieldKind::None => ScatteredField::None,
                FieldKind::Isotropic => ScatteredField::Isotropic {
                    source: take(format!("source/{ci}"), transport_cells)?,
                    higher_order: take(format!("higher_order/{ci}"), transport_cells)?,
                },
                FieldKind::TwoPass => {
                    let mut record = cm
                        .two_pass
                        .ok_or_else(|| bad("two-pass field without its stored result".into()))?;
                    let values = record.voxel_source_len().ok_or_else(|| {
                        bad(format!("channel {ci}: two-pass dims and bins overflow"))
                    })?;
                    record.voxel_source = take(format!("two_pass/{ci}/voxel_source"), values)?;
                    record.cell_share = take(format!("two_pass/{ci}/cell_share"), cells)?;
                    let t = record
                        .into_library()
                        .map_err(|e| bad(format!("channel {ci}: {e}")))?;
                    t.check_grid(&grid).map_err(|e| bad(e.to_string()))?;
                    ScatteredField::TwoPass(Box::new(t))
                }
                FieldKind::Binned => {
                    if bin_count == 0 {
                        return Err(bad("binned radiance without direction bins".into()));
                    }
                    let higher_order =
                        take_rows(&mut take, "higher_order", ci, transport_cells, bin_count)?
                            .map_err(|e| bad(format!("channel {ci}: higher orders: {e}")))?;
                    ScatteredField::Binned {
                        fluence: take(format!("fluence/{ci}"), transport_cells)?,
                        higher_order,
                    }
                }
            };
            channels.push(ChannelSolution {
                light_pass: LightPass {
                    grid,
                    sigma_t: sigma_t.clone(),
                    fields,
                },
                scattered,
                report: cm
                    .report
                    .map(|r| r.into_library())
                    .transpose()
                    .map_err(|e| bad(format!("channel {ci}: {e}")))?,
                emitted_fluence: if cm.has_emitted_fluence {
                    Some(take(format!("emitted_fluence/{ci}"), transport_cells)?)
                } else {
                    None
                },
                emitted_beam: if cm.has_emitted_beam {
                    let shapes = take(
                        format!("emitted_beam/{ci}"),
                        EMITTER_BEAM_VALUES * transport_cells,
                    )?;
                    let binned = take_rows(
                        &mut take,
                        "emitted_bins",
                        ci,
                        transport_cells,
                        EMITTER_BIN_VALUES,
                    )?
                    .map_err(|e| bad(format!("channel {ci}: emitters' bins: {e}")))?;
                    Some(EmitterBeam { shapes, binned })
                } else {
                    None
                },
                render_cache: RenderCache::default(),
            });
            medium_channels.push(ChannelMedium {
                sigma_t,
                albedo,
                emission,
            });
        }
        let data = if meta.has_data {
            Some(take("data".into(), cells)?)
        } else {
            None
        };
        let medium = Medium::new(
            grid,
            medium_channels,
            phase,
            meta.interpolation.into_library(),
            data,
        )
        .map_err(|e| bad(e.to_string()))?;
        let ground = meta
            .ground
            .map(|g| {
                g.into_library(&lights, |c, len| {
                    take(format!("ground/{c}"), len).map_err(|e| e.to_string())
                })
                .map(Arc::new)
            })
            .transpose()
            .map_err(bad)?;
        Ok(Solution {
            scene_hash: meta.scene_hash,
            scene_origin: meta.scene_origin,
            method: meta.method.into_library(),
            medium,
            lights,
            environment: meta
                .environment
                .map(|e| {
                    e.into_library(|len| {
                        take("environment/map".into(), len).map_err(|e| e.to_string())
                    })
                })
                .transpose()
                .map_err(bad)?,
            background: meta.background,
            ground,
            render,
            cameras,
            bins,
            transport,
            channels,
        })
    }

    /// Writes atomically (temporary file, then rename).
    pub fn write(&self, path: &Path) -> Result<(), SolutionError> {
        Ok(self.to_container().write(path)?)
    }

    pub fn read(path: &Path) -> Result<Solution, SolutionError> {
        Self::from_container(Container::read(path)?, path)
    }

    /// The size of the file [`write`](Self::write) writes, without encoding it.
    pub fn file_size(&self) -> u64 {
        self.to_container()
            .encoded_len()
            .expect("solution metadata always encodes") as u64
    }

    pub fn to_bytes(&self) -> Vec<u8> {
        self.to_container()
            .to_bytes()
            .expect("solution metadata always encodes")
    }

    pub fn from_bytes(bytes: &[u8], label: &Path) -> Result<Solution, SolutionError> {
        Self::from_container(Container::from_bytes(bytes, label)?, label)
    }
}

#[cfg(test)]
mod tests {
    use super::RenderCache;

    /// A slice asks for the fluence once per plane: it is made once per solution, and a
    /// failure is reported again rather than made again.
    #[test]
    fn the_fluence_is_made_once() {
        let cache = RenderCache::default();
        let made = std::cell::Cell::new(0);
        for _ in 0..3 {
            let values = cache
                .fluence(|| {
                    made.set(made.get() + 1);
                    Ok(vec![1.0, 2.0])
                })
                .unwrap();
            assert_eq!(values, [1.0, 2.0]);
        }
        assert_eq!(made.get(), 1);
        let failing = RenderCache::default();
        for _ in 0..2 {
            let e = failing
                .fluence(|| {
                    made.set(made.get() + 1);
                    anyhow::bail!("too costly")
                })
                .unwrap_err();
            assert!(e.to_string().contains("too costly"));
        }
        assert_eq!(made.get(), 2);
    }
}
