//! Exact free-flight sampling through a piecewise-constant medium.
//!
//! With `nearest` data σt is constant per cell, so the optical depth along a ray is a
//! piecewise-linear function of distance that [`Grid::traverse`] gives exactly. A free path
//! is sampled by drawing a target optical depth `τ* = −ln u` and walking cells until the
//! accumulated depth passes it, solving inside the last cell analytically. That is exact
//! (no majorant, no null collisions) and cheaper than Woodcock tracking for voxel data.

use medium::traversal::Ray;
use medium::{CellValues, Grid};

/// Where a free flight ended.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Flight {
    /// An interaction at distance `t` along the ray, inside `cell`.
    Collision { t: f64, cell: usize },
    /// The ray left the grid (or reached `t_max`) without an interaction.
    Escaped,
}

/// Samples where a ray starting at `t = 0` first interacts, for the target optical depth
/// `target_depth` (`−ln u`). Also returns `∫ e ds` along the part actually flown (the
/// track-length estimator of `∫ T e ds`: its expectation over the flight is exactly that
/// integral), computed only when `emission` is given.
#[inline]
pub fn fly(
    grid: &Grid,
    sigma_t: &[f32],
    emission: Option<&CellValues>,
    ray: &Ray,
    t_max: f64,
    target_depth: f64,
) -> (Flight, f64) {
    let mut depth = 0.0;
    let mut emitted = 0.0;
    for seg in grid.traverse(ray, 0.0, t_max) {
        let st = sigma_t[seg.cell] as f64;
        let len = seg.length();
        let seg_depth = st * len;
        if depth + seg_depth >= target_depth && st > 0.0 {
            let t = seg.t_enter + (target_depth - depth) / st;
            let t = t.clamp(seg.t_enter, seg.t_exit);
            if let Some(e) = emission {
                emitted += e.get(seg.cell) as f64 * (t - seg.t_enter);
            }
            return (Flight::Collision { t, cell: seg.cell }, emitted);
        }
        depth += seg_depth;
        if let Some(e) = emission {
            emitted += e.get(seg.cell) as f64 * len;
        }
    }
    (Flight::Escaped, emitted)
}

/// Transmittance `exp(−∫ σt)` from `ray.origin` to distance `t_max` (the grid's edge when
/// infinite), by the exact per-cell optical depth.
#[inline]
pub fn transmittance(grid: &Grid, sigma_t: &[f32], ray: &Ray, t_max: f64) -> f64 {
    (-grid.optical_depth(sigma_t, ray, 0.0, t_max)).exp()
}
