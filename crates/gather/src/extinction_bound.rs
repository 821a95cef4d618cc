//! [`ExtinctionBound`]: the largest σt near each block of 2³ cells, so that a `trilinear`
//! march can tell, with one lookup, that a whole cell's length of ray is optically thin.

use medium::grid::clamped_floor;
use medium::Grid;
use rayon::prelude::*;

/// Data cells per side of a block.
const BLOCK: usize = 2;

/// Per block of [`BLOCK`]³ cells, the largest σt of the cells within two cells of it: a
/// bound on the `trilinear` σt at every point within one cell of the block (whose
/// interpolation reads the centres within one cell of the point).
#[derive(Clone, Debug)]
pub struct ExtinctionBound {
    dims: [usize; 3],
    inverse_block_size: f64,
    max: Vec<f32>,
}

impl ExtinctionBound {
    pub fn new(grid: &Grid, sigma_t: &[f32]) -> Self {
        let [nx, ny, nz] = grid.dims;
        let dims = grid.dims.map(|n| n.div_ceil(BLOCK));
        let [bx, by, bz] = dims;
        // Each block's own largest σt, a layer of blocks per task (σt is finite: a plain
        // comparison).
        let mut own = vec![0.0f32; bx * by * bz];
        own.par_chunks_mut(bx * by)
            .enumerate()
            .for_each(|(kb, layer)| {
                for k in kb * BLOCK..((kb + 1) * BLOCK).min(nz) {
                    for j in 0..ny {
                        let row = &sigma_t[nx * (j + ny * k)..][..nx];
                        let blocks = &mut layer[bx * (j / BLOCK)..][..bx];
                        for (b, cells) in blocks.iter_mut().zip(row.chunks(BLOCK)) {
                            for &s in cells {
                                if s > *b {
                                    *b = s;
                                }
                            }
                        }
                    }
                }
            });
        // Grown by one block each way, axis by axis (a block's two cells of margin).
        let strides = [1, bx, bx * by];
        let mut max = own;
        let mut src = vec![0.0f32; max.len()];
        for (axis, &stride) in strides.iter().enumerate() {
            let n = dims[axis];
            src.copy_from_slice(&max);
            for (b, m) in max.iter_mut().enumerate() {
                let c = (b / stride) % n;
                if c > 0 {
                    *m = m.max(src[b - stride]);
                }
                if c + 1 < n {
                    *m = m.max(src[b + stride]);
                }
            }
        }
        ExtinctionBound {
            dims,
            inverse_block_size: 1.0 / (BLOCK as f64 * grid.cell_size),
            max,
        }
    }

    /// The bound at world point `x` (clamped into the grid): σt at every point within one
    /// cell of `x` is at most this.
    #[inline]
    pub fn at(&self, x: glam::DVec3) -> f64 {
        let q = x * self.inverse_block_size;
        let c = |a: usize, v: f64| clamped_floor(v, self.dims[a] - 1);
        let (i, j, k) = (c(0, q.x), c(1, q.y), c(2, q.z));
        self.max[i + self.dims[0] * (j + self.dims[1] * k)] as f64
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::render::Trilinear;
    use glam::DVec3;
    use rand::{Rng, SeedableRng};

    /// On random sparse fields of odd and even sizes, the `trilinear` σt at random points
    /// within one cell (per axis) of a random point — inside the grid and past its edges —
    /// never exceeds the bound there, and the bound is not loose in a uniform medium.
    #[test]
    fn the_bound_holds_within_a_cell_of_the_point() {
        let mut rng = rand_pcg::Pcg64::seed_from_u64(5);
        for _ in 0..40 {
            let dims = [0, 1, 2].map(|_| rng.random_range(1..12));
            let grid = Grid::new(dims, rng.random_range(0.3..2.0)).unwrap();
            let sigma: Vec<f32> = (0..grid.cell_count())
                .map(|_| {
                    if rng.random_bool(0.2) {
                        rng.random_range(0.0..5.0)
                    } else {
                        0.0
                    }
                })
                .collect();
            let bound = ExtinctionBound::new(&grid, &sigma);
            let size = DVec3::from(dims.map(|n| n as f64)) * grid.cell_size;
            for _ in 0..500 {
                let x = DVec3::new(
                    rng.random_range(-0.5..1.5),
                    rng.random_range(-0.5..1.5),
                    rng.random_range(-0.5..1.5),
                ) * size;
                let offset = DVec3::new(
                    rng.random_range(-1.0..1.0),
                    rng.random_range(-1.0..1.0),
                    rng.random_range(-1.0..1.0),
                ) * grid.cell_size;
                let y = x + offset;
                let value = Trilinear::new(&grid, y).sample(|c| sigma[c] as f64);
                assert!(
                    value <= bound.at(x) + 1e-12,
                    "σt {value} at {y} above the bound {} at {x} ({dims:?})",
                    bound.at(x)
                );
            }
        }
        let grid = Grid::new([6, 5, 4], 1.0).unwrap();
        let bound = ExtinctionBound::new(&grid, &[0.7; 120]);
        assert_eq!(bound.at(DVec3::new(2.5, 2.5, 2.5)), 0.7f32 as f64);
    }
}
