//! Exact traversal of a ray through the grid (3D DDA, Amanatides & Woo 1987).
//!
//! Every per-cell analytic integral in volrad (renders with `nearest`, optical depths for form
//! factors, the light pass, Monte Carlo tracking) walks cells with [`Grid::traverse`]. It
//! yields each cell the ray crosses exactly once, in order, with the parametric interval
//! `[t_enter, t_exit]`; consecutive intervals share their end points, so the segment lengths
//! sum to the chord exactly (up to rounding).

use glam::DVec3;

use crate::Grid;

/// A ray `origin + t · direction`, `direction` of unit length (so `t` is distance).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Ray {
    pub origin: DVec3,
    pub direction: DVec3,
}

impl Ray {
    /// `direction` is normalised here.
    pub fn new(origin: DVec3, direction: DVec3) -> Self {
        Ray {
            origin,
            direction: direction.normalize(),
        }
    }

    #[inline]
    pub fn at(&self, t: f64) -> DVec3 {
        self.origin + self.direction * t
    }
}

/// One cell's share of a ray.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Segment {
    pub cell: usize,
    /// The cell's `[i, j, k]` (what `Grid::coords(cell)` would divide out again).
    pub coords: [usize; 3],
    pub t_enter: f64,
    pub t_exit: f64,
}

impl Segment {
    #[inline]
    pub fn length(&self) -> f64 {
        self.t_exit - self.t_enter
    }
}

/// `∫_0^{Δs} e^{−σt s} ds = (1 − e^{−σt Δs}) / σt` (`= Δs` when `σt Δs` is tiny), the weight
/// of a source constant over one segment: what every per-cell march that integrates a source
/// (renders, the emitter pass, the ground's gather) adds per segment.
#[inline]
pub fn segment_weight(sigma_t: f64, length: f64) -> f64 {
    let tau = sigma_t * length;
    if tau < 1e-8 {
        // Series: Δs (1 − τ/2); the relative error of dropping τ²/6 is below 1e-16.
        length * (1.0 - 0.5 * tau)
    } else {
        -(-tau).exp_m1() / sigma_t
    }
}

impl Grid {
    /// The parametric interval where the ray is inside the grid's box, intersected with
    /// `[t_min, t_max]`; `None` when empty.
    #[inline]
    pub fn clip(&self, ray: &Ray, t_min: f64, t_max: f64) -> Option<(f64, f64)> {
        let ext = self.extent();
        let (mut t0, mut t1) = (t_min, t_max);
        for a in 0..3 {
            let (o, d, hi) = (ray.origin[a], ray.direction[a], ext[a]);
            if d == 0.0 {
                if o < 0.0 || o > hi {
                    return None;
                }
            } else {
                let inv = 1.0 / d;
                let (mut ta, mut tb) = ((0.0 - o) * inv, (hi - o) * inv);
                if ta > tb {
                    std::mem::swap(&mut ta, &mut tb);
                }
                t0 = t0.max(ta);
                t1 = t1.min(tb);
            }
        }
        (t0 < t1).then_some((t0, t1))
    }

    /// Walks the cells the ray crosses between `t_min` and `t_max`.
    #[inline]
    pub fn traverse(&self, ray: &Ray, t_min: f64, t_max: f64) -> GridTraversal {
        GridTraversal::new(self, ray, t_min, t_max)
    }

    /// Optical depth `∫ σt ds` along the ray from `t_min` to `t_max` (piecewise-constant σt).
    pub fn optical_depth(&self, sigma_t: &[f32], ray: &Ray, t_min: f64, t_max: f64) -> f64 {
        self.traverse(ray, t_min, t_max)
            .map(|s| sigma_t[s.cell] as f64 * s.length())
            .sum()
    }
}

/// Iterator state of the DDA. Allocation-free; cheap to create per ray.
#[derive(Clone, Debug)]
pub struct GridTraversal {
    dims: [i64; 3],
    cell: [i64; 3],
    step: [i64; 3],
    /// The linear index of `cell` and its change per step on each axis.
    index: i64,
    index_step: [i64; 3],
    t_next: [f64; 3],
    t_delta: [f64; 3],
    t: f64,
    t_end: f64,
    done: bool,
}

impl GridTraversal {
    #[inline]
    fn new(grid: &Grid, ray: &Ray, t_min: f64, t_max: f64) -> Self {
        let dims = grid.dims.map(|d| d as i64);
        let h = grid.cell_size;
        let Some((t0, t1)) = grid.clip(ray, t_min, t_max) else {
            return GridTraversal {
                dims,
                cell: [0; 3],
                step: [0; 3],
                index: 0,
                index_step: [0; 3],
                t_next: [0.0; 3],
                t_delta: [0.0; 3],
                t: 0.0,
                t_end: 0.0,
                done: true,
            };
        };
        // Locate the first cell from the midpoint of a tiny step inside, which is robust when
        // the entry point lies on a cell boundary or edge.
        let probe = ray.at(t0 + (t1 - t0).min(h) * 1e-9);
        let mut cell = [0i64; 3];
        let mut step = [0i64; 3];
        let mut t_next = [f64::INFINITY; 3];
        let mut t_delta = [f64::INFINITY; 3];
        for a in 0..3 {
            let c = ((probe[a] / h).floor() as i64).clamp(0, dims[a] - 1);
            cell[a] = c;
            let d = ray.direction[a];
            if d > 0.0 {
                step[a] = 1;
                t_next[a] = ((c + 1) as f64 * h - ray.origin[a]) / d;
                t_delta[a] = h / d;
            } else if d < 0.0 {
                step[a] = -1;
                t_next[a] = (c as f64 * h - ray.origin[a]) / d;
                t_delta[a] = -h / d;
            }
        }
        let stride = [1, dims[0], dims[0] * dims[1]];
        GridTraversal {
            dims,
            cell,
            step,
            index: cell[0] + stride[1] * cell[1] + stride[2] * cell[2],
            index_step: [0, 1, 2].map(|a| step[a] * stride[a]),
            t_next,
            t_delta,
            t: t0,
            t_end: t1,
            done: false,
        }
    }
}

impl Iterator for GridTraversal {
    type Item = Segment;

    #[inline]
    fn next(&mut self) -> Option<Segment> {
        if self.done {
            return None;
        }
        // The axis whose boundary comes first (ties: y over x, z over both). Selects and
        // nested branches measured the same here (docs/performance.md).
        let t = &self.t_next;
        let a01 = std::hint::select_unpredictable(t[1] <= t[0], 1usize, 0);
        let a = std::hint::select_unpredictable(t[2] <= t[a01], 2usize, a01);
        let t_exit = self.t_next[a].min(self.t_end);
        let seg = Segment {
            cell: self.index as usize,
            coords: self.cell.map(|c| c as usize),
            t_enter: self.t,
            t_exit: t_exit.max(self.t),
        };
        self.t = seg.t_exit;
        if t_exit >= self.t_end {
            self.done = true;
        } else {
            self.cell[a] += self.step[a];
            self.index += self.index_step[a];
            self.t_next[a] += self.t_delta[a];
            // Rounding can leave the box before `t_end`; the unsigned compare catches −1 too.
            if self.cell[a] as u64 >= self.dims[a] as u64 {
                self.done = true;
            }
        }
        Some(seg)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn grid() -> Grid {
        Grid::new([5, 7, 3], 0.75).unwrap()
    }

    #[test]
    fn axis_aligned_ray_visits_a_row() {
        let g = Grid::new([4, 4, 4], 1.0).unwrap();
        let ray = Ray::new(DVec3::new(-1.0, 2.5, 3.5), DVec3::X);
        let segs: Vec<_> = g.traverse(&ray, 0.0, f64::INFINITY).collect();
        assert_eq!(
            segs.iter().map(|s| s.cell).collect::<Vec<_>>(),
            vec![56, 57, 58, 59]
        );
        assert!(segs.iter().all(|s| (s.length() - 1.0).abs() < 1e-12));
    }

    #[test]
    fn ray_missing_the_grid_yields_nothing() {
        let g = grid();
        let ray = Ray::new(DVec3::new(-1.0, -1.0, -1.0), DVec3::new(-1.0, 0.2, 0.1));
        assert_eq!(g.traverse(&ray, 0.0, f64::INFINITY).count(), 0);
    }

    /// Reference: sample the ray finely and record which cells it is in.
    fn sampled_cells(g: &Grid, ray: &Ray, t0: f64, t1: f64) -> Vec<usize> {
        let n = 20_000;
        let mut out: Vec<usize> = Vec::new();
        for s in 0..n {
            let t = t0 + (t1 - t0) * (s as f64 + 0.5) / n as f64;
            if let Some(c) = g.cell_at(ray.at(t)) {
                if out.last() != Some(&c) {
                    out.push(c);
                }
            }
        }
        out
    }

    proptest! {
        #[test]
        fn visits_each_crossed_cell_once_and_lengths_sum_to_chord(
            ox in -3.0f64..7.0, oy in -3.0f64..8.0, oz in -3.0f64..5.0,
            dx in -1.0f64..1.0, dy in -1.0f64..1.0, dz in -1.0f64..1.0,
        ) {
            let d = DVec3::new(dx, dy, dz);
            prop_assume!(d.length() > 1e-3);
            let g = grid();
            let ray = Ray::new(DVec3::new(ox, oy, oz), d);
            let segs: Vec<_> = g.traverse(&ray, 0.0, f64::INFINITY).collect();
            match g.clip(&ray, 0.0, f64::INFINITY) {
                None => prop_assert!(segs.is_empty()),
                Some((t0, t1)) => {
                    let total: f64 = segs.iter().map(|s| s.length()).sum();
                    prop_assert!((total - (t1 - t0)).abs() < 1e-9 * (1.0 + t1));
                    let mut seen = std::collections::HashSet::new();
                    for s in &segs {
                        prop_assert!(seen.insert(s.cell), "cell {} visited twice", s.cell);
                        prop_assert!(s.length() >= 0.0);
                        // The segment's midpoint lies in the reported cell (unless degenerate).
                        if s.length() > 1e-9 {
                            let mid = ray.at(0.5 * (s.t_enter + s.t_exit));
                            let lo = g.cell_min(s.cell) - 1e-9;
                            let hi = lo + g.cell_size + 2e-9;
                            prop_assert!(mid.cmpge(lo).all() && mid.cmple(hi).all());
                        }
                    }
                    // Every cell the ray really passes through (sampled) is visited, in order.
                    let sampled = sampled_cells(&g, &ray, t0, t1);
                    let visited: Vec<usize> = segs.iter().filter(|s| s.length() > 1e-6).map(|s| s.cell).collect();
                    let mut it = visited.iter();
                    for c in sampled {
                        prop_assert!(it.any(|&v| v == c), "sampled cell {} not visited in order", c);
                    }
                }
            }
        }
    }
}
