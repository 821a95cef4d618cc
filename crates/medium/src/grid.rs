//! The cell lattice: dimensions, cell size, x-fastest indexing and world-space geometry.

use glam::DVec3;
use serde::{Deserialize, Serialize};

use crate::MediumError;

/// An `nx × ny × nz` lattice of cubes of side `cell_size`. Cell `(i, j, k)` covers
/// `[i h, (i+1) h] × [j h, (j+1) h] × [k h, (k+1) h]`; its flat index is `i + nx (j + ny k)`.
///
/// # Invariants
/// Every dimension is at least 1, `cell_size` is finite and positive, and the cell count fits
/// in `u32` (so cell indices may be stored as `u32`). Checked by [`Grid::new`].
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Grid {
    pub dims: [usize; 3],
    pub cell_size: f64,
}

impl Grid {
    pub fn new(dims: [usize; 3], cell_size: f64) -> Result<Self, MediumError> {
        if dims.contains(&0) {
            return Err(MediumError::invalid(
                "grid",
                format!("dims {dims:?} must all be at least 1"),
            ));
        }
        if !(cell_size.is_finite() && cell_size > 0.0) {
            return Err(MediumError::invalid(
                "grid",
                format!("cell size {cell_size} must be finite and positive"),
            ));
        }
        let cells = dims
            .iter()
            .try_fold(1usize, |acc, &d| acc.checked_mul(d))
            .filter(|&n| n <= u32::MAX as usize);
        if cells.is_none() {
            return Err(MediumError::invalid(
                "grid",
                format!("dims {dims:?} have more cells than volrad can index (2^32)"),
            ));
        }
        Ok(Grid { dims, cell_size })
    }

    #[inline]
    pub fn cell_count(&self) -> usize {
        self.dims[0] * self.dims[1] * self.dims[2]
    }

    #[inline]
    pub fn index(&self, i: usize, j: usize, k: usize) -> usize {
        debug_assert!(i < self.dims[0] && j < self.dims[1] && k < self.dims[2]);
        i + self.dims[0] * (j + self.dims[1] * k)
    }

    #[inline]
    pub fn coords(&self, index: usize) -> [usize; 3] {
        let [nx, ny, _] = self.dims;
        [index % nx, (index / nx) % ny, index / (nx * ny)]
    }

    /// World-space size of the whole grid.
    #[inline]
    pub fn extent(&self) -> DVec3 {
        DVec3::new(
            self.dims[0] as f64,
            self.dims[1] as f64,
            self.dims[2] as f64,
        ) * self.cell_size
    }

    #[inline]
    pub fn center(&self) -> DVec3 {
        self.extent() * 0.5
    }

    #[inline]
    pub fn cell_volume(&self) -> f64 {
        self.cell_size.powi(3)
    }

    #[inline]
    pub fn cell_center(&self, index: usize) -> DVec3 {
        let [i, j, k] = self.coords(index);
        (DVec3::new(i as f64, j as f64, k as f64) + 0.5) * self.cell_size
    }

    /// Lower corner of a cell.
    #[inline]
    pub fn cell_min(&self, index: usize) -> DVec3 {
        let [i, j, k] = self.coords(index);
        DVec3::new(i as f64, j as f64, k as f64) * self.cell_size
    }

    /// The cell containing a world point, or `None` outside the grid.
    pub fn cell_at(&self, p: DVec3) -> Option<usize> {
        let q = p / self.cell_size;
        if q.x < 0.0 || q.y < 0.0 || q.z < 0.0 {
            return None;
        }
        let (i, j, k) = (q.x as usize, q.y as usize, q.z as usize);
        (i < self.dims[0] && j < self.dims[1] && k < self.dims[2]).then(|| self.index(i, j, k))
    }

    /// Number of cell corners, `(nx+1)(ny+1)(nz+1)`, for per-corner fields.
    #[inline]
    pub fn corner_count(&self) -> usize {
        (self.dims[0] + 1) * (self.dims[1] + 1) * (self.dims[2] + 1)
    }

    /// Flat index of corner `(i, j, k)`, x fastest, `0 ≤ i ≤ nx`.
    #[inline]
    pub fn corner_index(&self, i: usize, j: usize, k: usize) -> usize {
        i + (self.dims[0] + 1) * (j + (self.dims[1] + 1) * k)
    }
}

/// `⌊v⌋` clamped to `0 ..= last` (NaN gives 0): the cell or lattice index of a coordinate in
/// cells. Marches take several per step; the standard `as usize` cast saturates out-of-range
/// values with a handful of extra instructions each, which this clamp makes unnecessary.
#[inline(always)]
pub fn clamped_floor(v: f64, last: usize) -> usize {
    // Comparisons, not `f64::max`/`min`: one instruction each (`NaN > 0` is false, so NaN → 0).
    let v = if v > 0.0 { v } else { 0.0 };
    let high = last as f64;
    let v = if v < high { v } else { high };
    // SAFETY: `v` is finite and within `0 ..= last`, so its truncation fits an `i64`.
    unsafe { v.to_int_unchecked::<i64>() as usize }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn index_and_coords_round_trip() {
        let g = Grid::new([3, 4, 5], 0.5).unwrap();
        for idx in 0..g.cell_count() {
            let [i, j, k] = g.coords(idx);
            assert_eq!(g.index(i, j, k), idx);
            assert_eq!(g.cell_at(g.cell_center(idx)), Some(idx));
        }
    }

    #[test]
    fn refuses_bad_dims() {
        assert!(Grid::new([0, 1, 1], 1.0).is_err());
        assert!(Grid::new([1, 1, 1], -1.0).is_err());
        assert!(Grid::new([1, 1, 1], f64::NAN).is_err());
        assert!(Grid::new([1 << 20, 1 << 20, 1 << 20], 1.0).is_err());
    }

    #[test]
    fn clamped_floor_floors_within_the_range_and_clamps_outside_it() {
        assert_eq!(clamped_floor(2.999, 5), 2);
        assert_eq!(clamped_floor(3.0, 5), 3);
        assert_eq!(clamped_floor(-0.5, 5), 0);
        assert_eq!(clamped_floor(7.5, 5), 5);
        assert_eq!(clamped_floor(f64::INFINITY, 5), 5);
        assert_eq!(clamped_floor(f64::NEG_INFINITY, 5), 0);
        assert_eq!(clamped_floor(f64::NAN, 5), 0);
        assert_eq!(clamped_floor(0.7, 0), 0);
    }
}
