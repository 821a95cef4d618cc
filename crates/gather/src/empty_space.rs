//! Empty-space skipping: the Chebyshev distance (in cells) from every cell to the nearest
//! occupied one, so rays can jump over empty regions instead of visiting each empty cell.
//!
//! A cell at distance `d` has only empty cells within `d − 1` cells of it (max-norm), so a ray
//! inside it may jump to where it leaves that cube of cells without missing anything.

use medium::grid::Grid;
use medium::traversal::Ray;

/// Distances are capped here (they are stored as `u8`).
const MAX_DISTANCE: u8 = 255;

#[derive(Clone)]
pub(crate) struct EmptySpace {
    grid: Grid,
    /// Per cell of the grid padded by one cell on every side (the array the transform runs
    /// on, kept as it is rather than copied out: on a large grid a copy is tens of MB of
    /// fresh memory per render index).
    padded: Vec<u8>,
    /// The padded grid's strides in y and z.
    stride_y: usize,
    stride_z: usize,
}

impl EmptySpace {
    /// Exact Chebyshev distance transform of `occupied` (one flag per cell) by the two-pass
    /// chamfer scan with the full 3×3×3 mask (all weights 1, which is exact for the
    /// max-norm), on a copy padded by one empty cell so the inner loop needs no bounds checks.
    pub(crate) fn new(grid: &Grid, occupied: &[bool]) -> Self {
        let [nx, ny, nz] = grid.dims;
        let (px, py, pz) = (nx + 2, ny + 2, nz + 2);
        let mut padded = vec![MAX_DISTANCE; px * py * pz];
        for k in 0..nz {
            for j in 0..ny {
                let src = nx * (j + ny * k);
                let dst = 1 + px * (j + 1 + py * (k + 1));
                for i in 0..nx {
                    if occupied[src + i] {
                        padded[dst + i] = 0;
                    }
                }
            }
        }
        // A forward pass, then its mirror image (the mask is symmetric). Each row's 12
        // neighbours in earlier rows are taken as whole shifted rows (which vectorises); only
        // the in-row neighbour is a serial scan.
        chamfer_pass(&mut padded, px, py, pz, true);
        chamfer_pass(&mut padded, px, py, pz, false);
        EmptySpace {
            grid: *grid,
            padded,
            stride_y: px,
            stride_z: px * py,
        }
    }

    /// The Chebyshev distance of the cell at `coords` to the nearest occupied cell (capped at
    /// 255).
    #[inline]
    pub(crate) fn distance(&self, coords: [usize; 3]) -> u8 {
        let [i, j, k] = coords;
        self.padded[1 + i + self.stride_y * (1 + j) + self.stride_z * (1 + k)]
    }

    /// How many cells around the cell at `coords` (max-norm radius, beyond the cell itself)
    /// are known to be empty, when up to `reach` cells of margin are needed (1 for trilinear
    /// reconstruction).
    #[inline]
    pub(crate) fn empty_radius(&self, coords: [usize; 3], reach: u8) -> i64 {
        self.distance(coords) as i64 - 1 - reach as i64
    }

    /// Where `ray`, now inside the cell at `coords`, leaves the cube of cells within `radius`
    /// of it.
    #[inline]
    pub(crate) fn exit(&self, ray: &Ray, coords: [usize; 3], radius: i64) -> f64 {
        let h = self.grid.cell_size;
        let mut t = f64::INFINITY;
        for (a, index) in coords.into_iter().enumerate() {
            let d = ray.direction[a];
            let bound = if d > 0.0 {
                (index as i64 + radius + 1) as f64 * h
            } else if d < 0.0 {
                (index as i64 - radius) as f64 * h
            } else {
                continue;
            };
            t = t.min((bound - ray.origin[a]) / d);
        }
        t
    }
}

/// One chamfer sweep over a padded `px × py × pz` array of distances (x fastest): each inner
/// cell becomes the minimum of itself and 1 + its 13 neighbours that come before it in the
/// sweep's order (`forward`: planes, rows and cells in increasing order; else decreasing, the
/// mirror image). The padding (one cell on every side, never written) keeps every neighbour
/// in bounds.
fn chamfer_pass(d: &mut [u8], px: usize, py: usize, pz: usize, forward: bool) {
    let plane = px * py;
    let mut before = vec![MAX_DISTANCE; px];
    let mut sweep_row = |d: &mut [u8], row: usize| {
        // The minimum over the earlier rows' neighbours, for every cell of the row at once:
        // rows (j∓1, j, j±1) of the plane before and row j∓1 of this plane, each at i−1, i,
        // i+1.
        before.fill(MAX_DISTANCE);
        let sources = if forward {
            [row - plane - px, row - plane, row - plane + px, row - px]
        } else {
            [row + plane + px, row + plane, row + plane - px, row + px]
        };
        for src in sources {
            // Cell i (1 ≤ i ≤ px − 2) sees columns i − 1, i, i + 1 of the source row.
            let (left, mid, right) = (
                &d[src..src + px - 2],
                &d[src + 1..src + px - 1],
                &d[src + 2..src + px],
            );
            for (((b, &l), &m), &r) in before[1..px - 1].iter_mut().zip(left).zip(mid).zip(right) {
                *b = (*b).min(l).min(m).min(r);
            }
        }
        let step = |previous: &mut u8, (cell, &seen): (&mut u8, &u8)| {
            let v = (*cell)
                .min(seen.saturating_add(1))
                .min(previous.saturating_add(1));
            *cell = v;
            *previous = v;
        };
        // The row's padding cells, where each direction's scan starts.
        let (mut first, mut last) = (d[row], d[row + px - 1]);
        let cells = d[row + 1..row + px - 1].iter_mut().zip(&before[1..px - 1]);
        if forward {
            cells.for_each(|c| step(&mut first, c));
        } else {
            cells.rev().for_each(|c| step(&mut last, c));
        }
    };
    if forward {
        for k in 1..pz - 1 {
            for j in 1..py - 1 {
                sweep_row(d, px * j + plane * k);
            }
        }
    } else {
        for k in (1..pz - 1).rev() {
            for j in (1..py - 1).rev() {
                sweep_row(d, px * j + plane * k);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::DVec3;

    #[test]
    fn distances_match_brute_force_chebyshev() {
        let grid = Grid::new([9, 7, 6], 1.0).unwrap();
        let marked = [(1, 1, 1), (7, 5, 4), (4, 0, 5)];
        let occupied: Vec<bool> = (0..grid.cell_count())
            .map(|c| {
                let [i, j, k] = grid.coords(c);
                marked.contains(&(i as i64, j as i64, k as i64))
            })
            .collect();
        let space = EmptySpace::new(&grid, &occupied);
        for c in 0..grid.cell_count() {
            let [i, j, k] = grid.coords(c).map(|v| v as i64);
            let want = marked
                .iter()
                .map(|&(a, b, e)| (i - a).abs().max((j - b).abs()).max((k - e).abs()))
                .min()
                .unwrap();
            assert_eq!(
                space.distance(grid.coords(c)) as i64,
                want,
                "cell {:?}",
                grid.coords(c)
            );
        }
    }

    #[test]
    fn distances_match_brute_force_on_random_occupancy() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_pcg::Pcg64::seed_from_u64(11);
        for _ in 0..40 {
            let dims = [0, 1, 2].map(|_| rng.random_range(1..9));
            let grid = Grid::new(dims, 1.0).unwrap();
            let density = rng.random_range(0.0..0.2);
            let occupied: Vec<bool> = (0..grid.cell_count())
                .map(|_| rng.random_bool(density))
                .collect();
            let marked: Vec<[i64; 3]> = (0..grid.cell_count())
                .filter(|&c| occupied[c])
                .map(|c| grid.coords(c).map(|v| v as i64))
                .collect();
            let space = EmptySpace::new(&grid, &occupied);
            for c in 0..grid.cell_count() {
                let p = grid.coords(c).map(|v| v as i64);
                let want = marked
                    .iter()
                    .map(|m| (0..3).map(|a| (p[a] - m[a]).abs()).max().unwrap())
                    .min()
                    .map_or(MAX_DISTANCE, |d| d.min(MAX_DISTANCE as i64) as u8);
                assert_eq!(
                    space.distance(grid.coords(c)),
                    want,
                    "dims {dims:?}, cell {p:?}"
                );
            }
        }
    }

    #[test]
    fn exit_leaves_the_empty_cube() {
        let grid = Grid::new([9, 9, 9], 0.5).unwrap();
        let occupied = vec![false; grid.cell_count()];
        let space = EmptySpace::new(&grid, &occupied);
        let cell = grid.index(4, 4, 4);
        let ray = Ray::new(grid.cell_center(cell), DVec3::new(1.0, 0.3, -0.2));
        // Radius 2 around cell 4: cells 2..=6, i.e. x up to 7 · 0.5 = 3.5; the x face is hit
        // first (from x = 2.25, distance 1.25 along x).
        let t = space.exit(&ray, grid.coords(cell), 2);
        assert!((ray.at(t).x - 3.5).abs() < 1e-12);
    }
}
