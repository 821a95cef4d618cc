//! `volrad info`: what a scene is and what solving it will cost.

use std::fmt;

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
    pub cameras: Vec<String>,
    pub method: String,
    /// The linear iteration, as `[solve] iteration` spells it.
    pub iteration: String,
    pub medium_bytes: usize,
    /// Rough memory a solve needs with the scene's method (unknowns, work vectors, operator).
    pub solve_memory_estimate_bytes: usize,
}

impl SceneInfo {
    pub fn of(scene: &Scene) -> SceneInfo {
        let m = &scene.medium;
        let cells = m.grid().cell_count();
        let (mut lo, mut hi, mut occupied) = (f64::INFINITY, 0.0f64, 0usize);
        for ch in m.channels() {
            for &s in &ch.sigma_t {
                lo = lo.min(s as f64);
                hi = hi.max(s as f64);
            }
        }
        for i in 0..cells {
            if m.channels().iter().any(|c| c.sigma_t[i] > 0.0) {
                occupied += 1;
            }
        }
        let unknowns_per_cell = match scene.solve.method {
            SolveMethod::DiscreteOrdinates => scene.solve.bins,
            SolveMethod::Zonal | SolveMethod::ZonalHierarchical => 1,
            _ => 0,
        };
        // Unknowns and ~4 f64 work vectors, the light pass, plus the operator: the exact zonal
        // matrix is dense over occupied cells (12 bytes per stored entry); the hierarchical
        // operator is estimated at ~200 links per cell.
        let vectors = occupied * unknowns_per_cell * 8 * 5 + cells * 8;
        let operator = match scene.solve.method {
            SolveMethod::Zonal => occupied * occupied * 12,
            SolveMethod::ZonalHierarchical => occupied * 200 * 16,
            SolveMethod::DiscreteOrdinates => scene.solve.bins * scene.solve.bins * 8,
            _ => 0,
        };
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
            cameras: scene.cameras.iter().map(|c| c.name.clone()).collect(),
            method: scene.solve.method.name().to_string(),
            iteration: scene.solve.iteration.to_string(),
            medium_bytes: m.memory_bytes(),
            solve_memory_estimate_bytes: vectors + operator,
        }
    }
}

fn mib(bytes: usize) -> f64 {
    bytes as f64 / (1024.0 * 1024.0)
}

impl fmt::Display for SceneInfo {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(f, "scene            {}", self.origin)?;
        writeln!(
            f,
            "grid             {} × {} × {} = {} cells, cell size {}",
            self.dims[0], self.dims[1], self.dims[2], self.cells, self.cell_size
        )?;
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
        writeln!(f, "cameras          {}", self.cameras.join(", "))?;
        writeln!(f, "solve method     {}", self.method)?;
        writeln!(f, "iteration        {}", self.iteration)?;
        writeln!(
            f,
            "memory           medium {:.1} MiB, solve ≈ {:.1} MiB",
            mib(self.medium_bytes),
            mib(self.solve_memory_estimate_bytes)
        )
    }
}
