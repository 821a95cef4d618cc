//! `volrad info`: what a scene is and what solving it will cost.

use std::fmt;

use crate::engine::{budget, methods, timing};
use scene::Scene;
use scene::{SceneOrigin, SolveMethod};
use serde::Serialize;

/// A description of a scene for people (`Display`) and programs (`Serialize`).
#[derive(Debug, Serialize)]
pub struct SceneInfo {
    pub origin: String,
    pub dims: [usize; 3],
    pub cells: usize,
    pub cell_size: f64,
    pub channels: usize,
    pub sigma_t_min: f64,
    pub sigma_t_max: f64,
    /// Fraction of cells with σt > 0.
    pub occupied_fraction: f64,
    /// Largest optical depth along an axis-parallel row of cells.
    pub max_axis_optical_depth: f64,
    /// Largest single-scattering albedo, as stored (f32).
    pub albedo_max: f32,
    pub phase: String,
    pub lights: usize,
    /// The environment light, described (none: `None`).
    pub environment: Option<String>,
    /// The ground, described (none: `None`).
    pub ground: Option<String>,
    pub cameras: Vec<String>,
    /// The emitting cells and how the solve method carries their light (`None`: nothing
    /// emits).
    pub emission: Option<String>,
    pub method: String,
    /// The linear iteration, as `[solve] iteration` spells it.
    pub iteration: String,
    pub medium_bytes: usize,
    /// Predicted peak resident memory of `volrad solve` with the scene's settings
    /// ([`budget::solve_peak`]), and its parts.
    pub peak_memory_bytes: u64,
    pub memory_parts: Vec<budget::MemoryPart>,
    /// Predicted time of `volrad solve` with the scene's settings on this machine's worker
    /// threads ([`timing::solve_time`]), its parts, the iterations per channel it expects
    /// and the spectral radius it expects them from.
    pub predicted_seconds: f64,
    pub time: timing::TimeEstimate,
    /// Largest optical depth of one cell (σt · cell size).
    pub max_cell_optical_depth: f64,
    /// The transport grid multiple scattering is solved on, when it is coarser than the
    /// data grid.
    pub transport: Option<TransportInfo>,
    /// What the discrete-ordinates solve will use (discrete ordinates only).
    pub ordinates: Option<OrdinatesInfo>,
    /// The error class measured for the zonal methods at this phase function and cell
    /// optical depth (zonal and zonal-hierarchical only; discrete ordinates' is in
    /// `ordinates`).
    pub zonal_expected_error: Option<String>,
    /// For an OpenVDB volume: the grid read, its active box and transform.
    pub openvdb: Option<OpenVdbInfo>,
}

/// Where an OpenVDB grid came from, and where volrad's grid corner is in the file's world.
#[derive(Debug, Serialize)]
pub struct OpenVdbInfo {
    #[serde(flatten)]
    pub placement: medium::vdb::VdbPlacement,
    pub world_corner: [f64; 3],
}

/// A transport grid other than the data grid: coarser (`[solve] transport_scale`) or split
/// (`[solve] transport_refinement`).
#[derive(Debug, Serialize)]
pub struct TransportInfo {
    /// Data cells per side of a transport cell.
    pub scale: usize,
    /// Transport cells per side of a data cell (`transport_refinement`).
    pub split: usize,
    /// On a split grid, the data cells' optical depth that set it: the 99th percentile over
    /// non-empty cells ([`budget::thick_cell_optical_depth`]).
    pub thick_cell_optical_depth: Option<f64>,
    pub dims: [usize; 3],
    pub cells: usize,
    /// Whether volrad chose the scale or the split (`"auto"`).
    pub chosen_by_volrad: bool,
}

/// The discrete-ordinates settings a solve uses, with what volrad chose and the error class
/// measured for them.
#[derive(Debug, Serialize)]
pub struct OrdinatesInfo {
    pub bins: usize,
    /// Why volrad chose these bins (`bins = "auto"`, the default: by the phase function's
    /// mean cosine, within the state it allows itself on this transport grid); `None`: the
    /// scene set them.
    pub bins_choice: Option<String>,
    /// Half-angle of the δ-M forward-peak cone, degrees (0: none).
    pub forward_peak_cone_degrees: f64,
    /// Whether the cone is volrad's choice (the scene did not set one).
    pub cone_chosen_by_volrad: bool,
    /// Fraction of scattering treated as unscattered by the truncation.
    pub forward_peak_fraction: f64,
    /// The error class measured for this g and bin count (docs/validation.md).
    pub expected_error: String,
}

/// The per-view error measured for discrete ordinates at asymmetry `g` with `bins` bins, a
/// largest cell optical depth `tau_cell` and data cells split in `split`³ (docs/validation.md:
/// the cloud24 orbit and the DISORT slab tables).
fn expected_ordinates_error(g: f64, bins: usize, tau_cell: f64, split: usize) -> String {
    let angular = if g <= 0.3 {
        "about 2 % (DISORT slabs, τ ≤ 4; the isotropic cloud24, 8 views: 1.0 %, +0.1 … +0.4 % \
         in the mean)"
            .to_string()
    } else if g <= 0.7 {
        if bins >= 216 {
            "about 3 % per view, image mean within about 1 % (cloud24, g = 0.6, 8 views, 216 bins: \
             1.1 %, −0.2 … +0.8 %)"
                .to_string()
        } else {
            format!(
                "about 3 % per view, image mean up to +2.4 % (cloud24, g = 0.6, 8 views, 96 bins: \
                 2.6 %, +0.1 … +2.4 %; {bins} bins here): set [solve] bins = 216 for a mean \
                 within about 1 % (about 2.5× the solve)"
            )
        }
    } else if bins >= 864 && g > 0.9 {
        "about 5 % per view, image mean within 2 % (cloud24, g = 0.95, 864 bins, 8 views of \
         64 × 48 against 65536-path references still 10–16 % noisy per pixel: 5.3 %, \
         −1.8 … +1.4 % in the means; 384 bins: 5.7 %, −1.4 … +3.0 %)"
            .to_string()
    } else if bins >= 864 {
        "about 2.5 % per view, image mean within 1 % (cloud24, g = 0.85, 864 bins, 8 views: \
         2.5 %, −0.4 … +0.7 % in the means; the bins' angular error falls about as 1 / bins: \
         600 bins 2.6 %, 0.0 … +1.1 %, 384 bins 2.9 %, +0.2 … +1.8 %)"
            .to_string()
    } else if bins >= 600 {
        "about 3 % per view, image mean within about 1 % (cloud24, g = 0.85, 600 bins, 8 views: \
         2.6 %, 0.0 … +1.1 %): [solve] bins = 864 for −0.4 … +0.7 % (about 1.5× the solve)"
            .to_string()
    } else if bins >= 384 && split > 1 {
        "about 3 % per view, image mean within 2 % (cloud24, g = 0.85, 384 bins, cells split \
         in 2³, 8 views: 2.9 %, too bright by +0.4 … +1.8 %, the same whole; the bins' angular \
         error, falling as the bins narrow: [solve] bins = 864 for −0.4 … +0.7 %)"
            .to_string()
    } else if bins >= 384 {
        "about 3 % per view, image mean within 2 % (cloud24, g = 0.85, 384 bins, 8 views: \
         2.9 %, too bright by +0.2 … +1.8 %; the 192-class cloud: 3.5 %, −1.7 %): the bins' \
         angular error, falling about as 1 / bins: [solve] bins = 864 for a mean within 1 % \
         (−0.4 … +0.7 %, about 3× the solve)"
            .to_string()
    } else {
        format!(
            "about 8 % per view, back-lit views up to +8 % bright at g = 0.85 with 96 bins \
             (216 bins: 6 %, +3 %; {bins} bins here): set [solve] bins = 864 for about \
             2.5 %, within 1 % in the mean (about 20× the solve)"
        )
    };
    if tau_cell > 1.0 {
        format!(
            "{angular}; transport cells up to optical depth {tau_cell:.2}: thick cells carry \
             their light a little too deep (cloud24 at σt × 4, cells up to 4: 3.1 % per view, \
             −1.7 … +1.1 % in the mean; split in 2³ by [solve] transport_refinement: 2.0 %, \
             −0.6 … +1.5 %)"
        )
    } else if tau_cell > 0.25 {
        format!(
            "{angular}; transport cells up to optical depth {tau_cell:.2}: wide uniform slabs \
             of such cells transmit a little too little, mostly the bins' angular error \
             (DISORT τ = 16 slab at 0.25 per cell: T −2.3 % at 96 bins, −0.6 % at 384)"
        )
    } else {
        angular
    }
}

/// Why `volrad` chose `bins` for mean cosine `g` on the scene's transport grid: the step
/// the forward peak asks for, and when the state cap held it lower, what the wanted step
/// would cost.
fn bins_choice(g: f64, bins: usize, scene: &Scene, occupancy: &budget::Occupancy) -> String {
    // No cells: no cap, the step the forward peak alone asks for.
    let wanted = formfactor::ordinates::auto_bin_count(g, 0);
    let why = format!("chosen by volrad for mean cosine {g:.2}");
    if wanted == bins {
        return why;
    }
    let cells = budget::transport_cell_count(scene, &scene.solve);
    let costs: Vec<String> = formfactor::ordinates::AUTO_BIN_STEPS
        .into_iter()
        .filter(|&b| b > bins && b <= wanted)
        .map(|b| {
            let settings = scene::SolveSettings {
                bins: scene::BinCount::Fixed(b),
                ..scene.solve.clone()
            };
            let peak = budget::solve_peak(scene, &settings, occupancy).total();
            format!(
                "[solve] bins = {b} needs about {}",
                budget::human_bytes(peak)
            )
        })
        .collect();
    format!(
        "{why}, which asks for {wanted}; held to {bins} so that the sweeps' work (transport \
         cells × bins, a cell-bin above 384 bins counted (bins / 384)^¼) stays within {:.1} M \
         ({cells} transport cells): {}",
        formfactor::ordinates::AUTO_BINS_MAX_CELL_BINS as f64 / 1e6,
        costs.join(", ")
    )
}

/// The per-view error measured for the zonal methods (docs/validation.md: the cloud24 orbit
/// across albedo and σt, the transport grid's test) at a largest transport-cell optical depth
/// `tau_cell`, solved on transport cells of `scale`³ data cells.
fn expected_zonal_error(isotropic: bool, tau_cell: f64, scale: usize, split: usize) -> String {
    if !isotropic {
        return "the zonal methods scatter isotropically after the first bounce: about 50 % off \
                per view on the g = 0.6 cloud (cloud24, 8 views); use discrete-ordinates or \
                two-pass"
            .to_string();
    }
    if split > 1 {
        return format!(
            "data cells split in {split}³, transport cells up to optical depth {tau_cell:.1}: \
             about 2.5 % per view, up to +1.2 % in the image mean seen against the light \
             (cloud24 at σt × 4 split in 2³, zonal-hierarchical, 8 views: 2.4 %, −1.1 … \
             +1.2 %)"
        );
    }
    let class = if tau_cell <= 1.0 {
        "within 2 % per view, image mean within about 1 % (cloud24, albedo 0.5–1, cells up to \
         optical depth 1, 8 views)"
            .to_string()
    } else if tau_cell <= 4.0 {
        format!(
            "cells up to optical depth {tau_cell:.1}: about 6 % per view, −3 … +3 % in the \
             image mean from the lit side to against the light (cloud24 at σt × 4, cells up \
             to 4, zonal-hierarchical: 6.0 %, −2.9 … +2.6 %; a source uniform over thick \
             cells carries light too deep; [solve] transport_refinement splits them)"
        )
    } else {
        format!(
            "cells up to optical depth {tau_cell:.1}, thicker than any case measured (cells up \
             to 4: about 6 % per view); a finer grid is more accurate"
        )
    };
    if scale > 1 {
        format!(
            "{class}; on transport cells of {scale}³ data cells (a 36×36×28 cloud at scale 2, \
             0.6 per transport cell: 2.6 % per view, −1.5 % in the image mean)"
        )
    } else {
        class
    }
}

/// How many cells emit, and how the scene's solve method carries their light.
fn emission_info(scene: &Scene) -> Option<String> {
    let m = &scene.medium;
    let emitting = (0..m.grid().cell_count())
        .filter(|&i| m.channels().iter().any(|c| c.emission.get(i) > 0.0))
        .count();
    if emitting == 0 {
        return None;
    }
    let how = match scene.solve.method {
        method if method.solves_linear_system() => {
            let runs = methods::emitter_pass_plans(scene, &scene.solve)
                .iter()
                .any(|p| p.runs);
            if runs {
                "uncollided light traced to every cell, its mean (emitter pass), its first \
                 collision the solve's source"
            } else {
                "an extended source, carried by the operator (an emitter pass would trace \
                 too many rays per cell)"
            }
        }
        SolveMethod::TwoPass => "photons sent from the emitting cells as from a light",
        _ => "integrated along view rays only (not scattered)",
    };
    Some(format!("{emitting} emitting cells; {how}"))
}

impl SceneInfo {
    pub fn of(scene: &Scene) -> SceneInfo {
        let m = &scene.medium;
        let cells = m.grid().cell_count();
        let (mut lo, mut hi) = (f64::INFINITY, 0.0f64);
        for ch in m.channels() {
            for &s in &ch.sigma_t {
                lo = lo.min(s as f64);
                hi = hi.max(s as f64);
            }
        }
        let occupancy = budget::Occupancy::of(m);
        let occupied = occupancy.at(1);
        let peak = budget::solve_peak(scene, &scene.solve, &occupancy);
        let time = timing::solve_time(
            scene,
            &scene.solve,
            &occupancy,
            rayon::current_num_threads(),
        );
        let h = m.grid().cell_size;
        let max_cell_optical_depth = hi * h;
        let scale = budget::transport_scale(scene, &scene.solve);
        let split = budget::transport_split(scene, &scene.solve);
        // A transport cell's side in data cells.
        let cell_factor = scale as f64 / split as f64;
        let transport = budget::transport_grid(scene, &scene.solve)
            .ok()
            .filter(|k| !k.is_data_grid())
            .map(|k| TransportInfo {
                scale,
                split,
                dims: k.transport().dims,
                cells: k.transport().cell_count(),
                chosen_by_volrad: if split > 1 {
                    scene.solve.transport_refinement == scene::TransportRefinement::Auto
                } else {
                    scene.solve.transport_scale == scene::TransportScale::Auto
                },
                thick_cell_optical_depth: (split > 1).then(|| budget::thick_cell_optical_depth(m)),
            });
        let ordinates = (scene.solve.method == SolveMethod::DiscreteOrdinates).then(|| {
            let phase = m.phase();
            let bins = budget::direction_bins(scene, &scene.solve);
            let (cone, fraction) = methods::forward_truncation(&scene.solve, bins, &phase);
            // The sweep runs through σt − f σs: its thickest cell.
            let tau_cell = m
                .channels()
                .iter()
                .flat_map(|c| {
                    (0..c.sigma_t.len()).map(|i| c.sigma_t[i] - fraction as f32 * c.sigma_s(i))
                })
                .fold(0.0f32, f32::max) as f64
                * h
                * cell_factor;
            OrdinatesInfo {
                bins,
                bins_choice: (scene.solve.bins == scene::BinCount::Auto)
                    .then(|| bins_choice(phase.mean_cosine(), bins, scene, &occupancy)),
                forward_peak_cone_degrees: cone,
                cone_chosen_by_volrad: scene.solve.forward_peak_cone.is_none(),
                forward_peak_fraction: fraction,
                expected_error: expected_ordinates_error(
                    phase.mean_cosine(),
                    bins,
                    tau_cell,
                    split,
                ),
            }
        });
        let zonal_expected_error = matches!(
            scene.solve.method,
            SolveMethod::Zonal | SolveMethod::ZonalHierarchical
        )
        .then(|| {
            expected_zonal_error(
                m.phase().is_isotropic(),
                max_cell_optical_depth * cell_factor,
                scale,
                split,
            )
        });
        SceneInfo {
            origin: match &scene.origin {
                SceneOrigin::File(p) => p.display().to_string(),
                SceneOrigin::BuiltIn(name) => format!("<built-in {name}>"),
            },
            dims: m.grid().dims,
            cells,
            cell_size: m.grid().cell_size,
            channels: m.channels().len(),
            sigma_t_min: if lo.is_finite() { lo } else { 0.0 },
            sigma_t_max: hi,
            occupied_fraction: occupied as f64 / cells as f64,
            max_axis_optical_depth: m.max_axis_optical_depth(),
            albedo_max: m
                .channels()
                .iter()
                .map(|c| c.albedo.max())
                .fold(0.0, f32::max),
            phase: scene::phase_spelling(&m.phase()),
            lights: scene.lights.len(),
            environment: scene.environment.as_ref().map(|e| match e.spec() {
                medium::environment::EnvironmentSpec::Uniform { radiance } => {
                    format!("uniform, radiance {}", grey_or_rgb(radiance))
                }
                medium::environment::EnvironmentSpec::Sky(s) => format!(
                    "Preetham sky, turbidity {}, sun at {}° elevation, {}° azimuth (the sun is \
                     one of the lights), ground albedo {}",
                    s.turbidity, s.sun_elevation_degrees, s.sun_azimuth_degrees, s.ground_albedo
                ),
                medium::environment::EnvironmentSpec::Map(m) => format!(
                    "map of {} × {} texels, scale {}, turned {}° about up {:?} (peak radiance {:.4})",
                    m.width(),
                    m.height(),
                    m.scale(),
                    m.rotation_degrees(),
                    m.up().to_array(),
                    m.max_rgb().into_iter().fold(0.0, f64::max)
                ),
            }),
            ground: scene.ground.map(|g| {
                let patches = medium::ground::GroundPatches::covering(&g, m.grid(), &scene.lights);
                format!(
                    "Lambertian plane at z = {}, albedo {}; its light solved on {} × {} \
                     patches of {:.3} (coupled with the medium)",
                    g.height(),
                    grey_or_rgb(g.albedo_rgb()),
                    patches.dims()[0],
                    patches.dims()[1],
                    patches.size()
                )
            }),
            cameras: scene.cameras.iter().map(|c| c.name.clone()).collect(),
            emission: emission_info(scene),
            method: scene.solve.method.name().to_string(),
            iteration: scene.solve.iteration.to_string(),
            medium_bytes: m.memory_bytes(),
            peak_memory_bytes: peak.total(),
            memory_parts: peak.parts().to_vec(),
            predicted_seconds: time.total().as_secs_f64(),
            time,
            max_cell_optical_depth,
            transport,
            ordinates,
            zonal_expected_error,
            openvdb: scene.volume_placement().map(|p| OpenVdbInfo {
                placement: p.clone(),
                world_corner: p.world_corner(),
            }),
        }
    }
}

impl fmt::Display for SceneInfo {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(f, "scene            {}", self.origin)?;
        writeln!(
            f,
            "grid             {} × {} × {} = {} cells, cell size {}",
            self.dims[0], self.dims[1], self.dims[2], self.cells, self.cell_size
        )?;
        if let Some(v) = &self.openvdb {
            let p = &v.placement;
            writeln!(
                f,
                "openvdb grid     `{}`, active voxels {:?} ..= {:?}, grid corner at {:?} in the file's world",
                p.grid, p.bbox_min, p.bbox_max, v.world_corner
            )?;
        }
        writeln!(f, "channels         {}", self.channels)?;
        writeln!(
            f,
            "σt               {:.4} .. {:.4} (1/length), {:.1} % of cells non-empty",
            self.sigma_t_min,
            self.sigma_t_max,
            100.0 * self.occupied_fraction
        )?;
        writeln!(
            f,
            "optical depth    {:.3} at most across the grid (axis-parallel)",
            self.max_axis_optical_depth
        )?;
        writeln!(f, "albedo           ≤ {}", self.albedo_max)?;
        writeln!(f, "phase            {}", self.phase)?;
        writeln!(f, "lights           {}", self.lights)?;
        if let Some(e) = &self.environment {
            writeln!(f, "environment      {e}")?;
        }
        if let Some(g) = &self.ground {
            writeln!(f, "ground           {g}")?;
        }
        if self.cameras.is_empty() {
            writeln!(f, "cameras          none (a render frames the whole grid)")?;
        } else {
            writeln!(f, "cameras          {}", self.cameras.join(", "))?;
        }
        if let Some(e) = &self.emission {
            writeln!(f, "emission         {e}")?;
        }
        writeln!(f, "solve method     {}", self.method)?;
        writeln!(f, "iteration        {}", self.iteration)?;
        if let Some(t) = &self.transport {
            let [x, y, z] = t.dims;
            let chosen = if t.chosen_by_volrad {
                ", chosen by volrad"
            } else {
                ""
            };
            let what = if let Some(tau) = t.thick_cell_optical_depth {
                format!(
                    ", each data cell split into {}³{chosen} (99 % of the cells up to optical \
                     depth {tau:.2})",
                    t.split
                )
            } else {
                format!(
                    " of {}³ data cells{chosen} (the first bounce stays at full resolution)",
                    t.scale
                )
            };
            writeln!(f, "transport grid   {x}×{y}×{z} = {} cells{what}", t.cells)?;
        }
        if let Some(o) = &self.ordinates {
            if o.forward_peak_cone_degrees > 0.0 {
                writeln!(
                    f,
                    "direction bins   {}, forward peak within {:.1}° truncated (δ-M, {:.0} % of \
                     scattering){}",
                    o.bins,
                    o.forward_peak_cone_degrees,
                    100.0 * o.forward_peak_fraction,
                    if o.cone_chosen_by_volrad {
                        ", chosen by volrad: one bin's cone"
                    } else {
                        ""
                    }
                )?;
            } else {
                writeln!(f, "direction bins   {}, no forward-peak truncation", o.bins)?;
            }
            if let Some(why) = &o.bins_choice {
                writeln!(f, "                 {why}")?;
            }
            writeln!(f, "expected error   {}", o.expected_error)?;
        }
        if let Some(e) = &self.zonal_expected_error {
            writeln!(f, "expected error   {e}")?;
        }
        writeln!(
            f,
            "memory           solve peak ≈ {} ({})",
            budget::human_bytes(self.peak_memory_bytes),
            self.memory_parts
                .iter()
                .filter(|p| p.bytes >= 1 << 20)
                .map(|p| format!("{} {}", p.what, budget::human_bytes(p.bytes)))
                .collect::<Vec<_>>()
                .join(", ")
        )?;
        write!(f, "time             solve {}", self.time)?;
        if let (Some(n), Some(rho)) = (self.time.iterations(), self.time.spectral_radius()) {
            write!(
                f,
                "; {n} iteration{} per channel expected (spectral radius ≈ {rho:.3}, {})",
                if n == 1 { "" } else { "s" },
                if self.time.probed() {
                    "measured on a coarse copy of the medium"
                } else {
                    "estimated by diffusion theory"
                }
            )?;
        }
        writeln!(f)
    }
}

/// `v` for a grey triple, `[r, g, b]` otherwise: how a scene file spells a colour.
fn grey_or_rgb([r, g, b]: [f64; 3]) -> String {
    if r == g && g == b {
        format!("{r}")
    } else {
        format!("[{r}, {g}, {b}]")
    }
}

#[cfg(test)]
mod tests {
    use super::expected_zonal_error;

    /// The class follows what docs/validation.md measured: anisotropic scenes are pointed to
    /// the other methods, thin cells get the cloud24 figure, thick cells and transport grids
    /// say why they are less accurate.
    #[test]
    fn the_zonal_error_class_follows_the_medium() {
        assert!(expected_zonal_error(false, 0.5, 1, 1).contains("discrete-ordinates"));
        let thin = expected_zonal_error(true, 1.0, 1, 1);
        assert!(thin.starts_with("within 2 %"), "{thin}");
        let thick = expected_zonal_error(true, 3.0, 1, 1);
        assert!(
            thick.contains("about 6 %") && thick.contains("3.0"),
            "{thick}"
        );
        assert!(expected_zonal_error(true, 9.0, 1, 1).contains("thicker than any case measured"));
        assert!(expected_zonal_error(true, 0.6, 2, 1).contains("transport cells of 2³"));
        let split = expected_zonal_error(true, 2.0, 1, 2);
        assert!(
            split.contains("split in 2³") && split.contains("2.0"),
            "{split}"
        );
    }
}
