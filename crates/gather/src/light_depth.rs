//! The first bounce's model of a directional light's optical depth `d = −ln T_L` inside a cell,
//! chosen once per light pass.
//!
//! The fast model is trilinear interpolation of depths on a lattice of corners: the light
//! pass's own cell corners (refinement 1), or the corners of `r × r × r` sub-cells, whose depths
//! come from an exact light pass over the same medium split into sub-cells (refinement `r`).
//! Along a view segment inside one (sub-)cell the depth is then taken as linear between its
//! trilinear end values, so `∫ e^{−σt s} T_L ds` is one closed form per piece, and the
//! transmittance at the end of a segment is where the next one starts: a single `exp` per
//! piece.
//!
//! Trilinear depth is exact where `d` is linear (a homogeneous slab) and good where the cell is
//! optically thin toward the light; in thick cells `d` has kinks (the face the light enters
//! through changes), which sub-cells resolve. [`LightDepth::Auto`] takes the coarsest lattice
//! whose cell means of `T_L` reproduce the light pass's exact cell averages to
//! [`TRILINEAR_CELL_MEAN_TOLERANCE`], else the finest it can afford. Against exact shadow rays
//! sub-cells beat the older exit-face model (bilinear on the exit face plus exact in-cell
//! attenuation, by quadrature) from refinement 2 on; it remains for point and spot lights and
//! for grids too large to refine.

use std::fmt;
use std::sync::Arc;

use glam::DVec3;
use medium::fma::mul_add;
use medium::grid::clamped_floor;
use medium::light_pass::{directional_corner_depths, LightPass};
use medium::{Grid, Light};
use rayon::prelude::*;

use crate::exponential::exp;
use crate::scattering::ViewSegment;
use crate::GatherError;

/// [`LightDepth::Auto`] takes a trilinear lattice when its cell means of `T_L` match the
/// light pass's exact ones to this (extinction-weighted relative L1) error. The error and the
/// model chosen are logged at debug level (`RUST_LOG=gather=debug volrad render ...`).
pub const TRILINEAR_CELL_MEAN_TOLERANCE: f64 = 0.012;

/// Finest sub-cell lattice [`LightDepth::Auto`] tries (and [`LightDepth::Refined`] accepts).
pub const MAX_REFINEMENT: usize = 4;

/// [`LightDepth::Auto`] does not refine past this many sub-cells (about 100 MB of transient
/// light pass); larger grids that need it keep the exit-face model.
const AUTO_SUBCELL_BUDGET: usize = 8 << 20;

/// Cells of a grid beyond which the [`LightDepth::Auto`] check takes a sample of them
/// ([`DepthLattice::cell_mean_error`]).
const AUTO_CHECK_CELLS: usize = 4 << 20;

/// The stride of the [`LightDepth::Auto`] check's sample on `grid`: 1 up to
/// [`AUTO_CHECK_CELLS`] cells, else about `cells / AUTO_CHECK_CELLS`, raised until it shares
/// no factor with a layer's cells (nor so with a row's), so that the sample walks across every
/// column and row rather than down a few of them.
fn check_stride(grid: &Grid) -> usize {
    fn coprime(mut a: usize, mut b: usize) -> bool {
        while b != 0 {
            (a, b) = (b, a % b);
        }
        a == 1
    }
    let mut stride = grid.cell_count().div_ceil(AUTO_CHECK_CELLS);
    if stride <= 1 {
        return 1;
    }
    let layer = grid.dims[0] * grid.dims[1];
    while !coprime(stride, layer) {
        stride += 1;
    }
    stride
}

/// The in-cell model of a directional light's optical depth, for `nearest` renders.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LightDepth {
    /// The coarsest trilinear lattice (refinement 1, 2, … [`MAX_REFINEMENT`]) whose cell
    /// means of `T_L` reproduce the light pass's exact cell averages within
    /// [`TRILINEAR_CELL_MEAN_TOLERANCE`], else the finest affordable one (up to 8M sub-cells;
    /// [`LightDepth::ExitFace`] past that). Smooth, finely resolved media take refinement 1;
    /// coarse grids of thick cells need sub-cells. The test
    /// `auto_light_depth_is_within_one_and_a_half_percent_of_exact_shadow_rays` bounds the
    /// image error.
    Auto,
    /// Trilinear in the light pass's corner depths (refinement 1).
    CornerTrilinear,
    /// Trilinear on `r³` sub-cells per cell (`2 ≤ r ≤` [`MAX_REFINEMENT`]), their corner
    /// depths from an exact light pass over the split grid.
    Refined(usize),
    /// Bilinear on the face where the ray toward the light leaves the cell plus the exact
    /// in-cell attenuation, split where that face changes and integrated by Gauss–Legendre:
    /// several times the work of a lattice.
    ExitFace,
}

/// A directional light's optical depth at the corners of a lattice `refine` times finer than
/// the grid.
#[derive(Clone, Debug, PartialEq)]
pub struct DepthLattice {
    refine: usize,
    /// Sub-cell side and its inverse.
    sub_size: f64,
    inv_sub_size: f64,
    /// Corner strides in y and z (x is 1).
    stride_y: usize,
    stride_z: usize,
    /// The corner depths: the light pass's own (shared) at refinement 1.
    depth: Arc<Vec<f32>>,
}

impl DepthLattice {
    /// The lattice of light `l` of `pass` at refinement `refine`: the pass's own corners for
    /// 1, else an exact light pass over the grid split into `refine³` sub-cells per cell.
    pub fn build(pass: &LightPass, l: usize, refine: usize) -> Result<Self, GatherError> {
        if !(1..=MAX_REFINEMENT).contains(&refine) {
            return Err(GatherError::Render(format!(
                "light-depth refinement {refine} (1 to {MAX_REFINEMENT} supported)"
            )));
        }
        let grid = pass.grid;
        let depth = if refine == 1 {
            Arc::clone(&pass.fields[l].corner_optical_depth)
        } else {
            let fine = Grid::new(
                grid.dims.map(|n| n * refine),
                grid.cell_size / refine as f64,
            )
            .map_err(|e| GatherError::Render(format!("refined light grid: {e}")))?;
            let [fx, fy, fz] = fine.dims;
            let mut sigma_t = vec![0.0f32; fx * fy * fz];
            sigma_t
                .par_chunks_mut(fx * fy)
                .enumerate()
                .for_each(|(k, layer)| {
                    for j in 0..fy {
                        for i in 0..fx {
                            let coarse = grid.index(i / refine, j / refine, k / refine);
                            layer[i + fx * j] = pass.sigma_t[coarse];
                        }
                    }
                });
            let Light::Directional { direction, .. } = pass.fields[l].light else {
                return Err(GatherError::Render(format!(
                    "light {l} is not directional: only directional lights take a lattice"
                )));
            };
            Arc::new(
                directional_corner_depths(&fine, &sigma_t, direction)
                    .map_err(|e| GatherError::Render(format!("refined corner depths: {e}")))?,
            )
        };
        let stride_y = grid.dims[0] * refine + 1;
        Ok(DepthLattice {
            refine,
            sub_size: grid.cell_size / refine as f64,
            inv_sub_size: refine as f64 / grid.cell_size,
            stride_y,
            stride_z: stride_y * (grid.dims[1] * refine + 1),
            depth,
        })
    }

    /// Bytes of its corner depths (at refinement 1 the light pass's own, shared).
    pub fn bytes(&self) -> usize {
        self.depth.len() * std::mem::size_of::<f32>()
    }

    /// The eight corner depths of sub-cell `sub` (lattice coordinates).
    #[inline(always)]
    fn corners(&self, sub: [usize; 3]) -> SubCellDepths {
        let c = sub[0] + self.stride_y * sub[1] + self.stride_z * sub[2];
        let (sy, sz) = (self.stride_y, self.stride_z);
        // One bounds check for the eight loads.
        let block = &self.depth[c..=c + sz + sy + 1];
        let v = |o: usize| block[o] as f64;
        SubCellDepths {
            lo: DVec3::new(sub[0] as f64, sub[1] as f64, sub[2] as f64) * self.sub_size,
            inv_size: self.inv_sub_size,
            d: [
                v(0),
                v(1),
                v(sy),
                v(sy + 1),
                v(sz),
                v(sz + 1),
                v(sz + sy),
                v(sz + sy + 1),
            ],
        }
    }

    /// The trilinear depth at world point `x` inside the grid cell `coords` (what
    /// [`DepthLattice::segment`] interpolates between sub-cell face crossings).
    pub fn depth_at(&self, x: DVec3, coords: [usize; 3]) -> f64 {
        self.depth_at_with::<false>(x, coords)
    }

    /// [`DepthLattice::depth_at`], fused multiply-adds where `FMA`.
    #[inline(always)]
    pub(crate) fn depth_at_with<const FMA: bool>(&self, x: DVec3, coords: [usize; 3]) -> f64 {
        let r = self.refine;
        let h = self.sub_size * r as f64;
        let lo = DVec3::new(coords[0] as f64, coords[1] as f64, coords[2] as f64) * h;
        let f = (x - lo) * self.inv_sub_size;
        let at = |q: usize| coords[q] * r + clamped_floor(f[q], r - 1);
        self.corners([at(0), at(1), at(2)]).at::<FMA>(x)
    }

    /// Extinction-weighted relative L1 error of this lattice's cell means of `T_L` against the
    /// light pass's exact cell averages (`cell_irradiance / E`), over the cells that
    /// extinguish. Each sub-cell's mean is 2×2×2-point Gauss–Legendre. On grids of more than
    /// [`AUTO_CHECK_CELLS`] cells, over every [`check_stride`]-th cell: the first view of a
    /// 384-class cloud spent 0.2 s of CPU on 5 million cell means for a mean error that a
    /// tenth of them gives as well.
    pub fn cell_mean_error(&self, pass: &LightPass, l: usize) -> f64 {
        self.cell_mean_error_every(pass, l, check_stride(&pass.grid))
    }

    /// [`cell_mean_error`](Self::cell_mean_error) over the cells `0, stride, 2·stride, …`.
    fn cell_mean_error_every(&self, pass: &LightPass, l: usize, stride: usize) -> f64 {
        let field = &pass.fields[l];
        let Light::Directional { irradiance, .. } = field.light else {
            return 0.0;
        };
        if irradiance <= 0.0 {
            return 0.0;
        }
        let fma = medium::fma::available();
        let stride = stride.max(1);
        let (err, total) = (0..pass.sigma_t.len().div_ceil(stride))
            .into_par_iter()
            .map(|i| (i * stride, pass.sigma_t[i * stride]))
            .filter(|&(_, sigma)| sigma > 0.0)
            .map(|(cell, sigma)| {
                let mean = self.cell_mean_with(fma, pass.grid.coords(cell));
                let exact = field.cell_irradiance[cell] as f64 / irradiance;
                (sigma as f64 * (mean - exact).abs(), sigma as f64 * exact)
            })
            .reduce(|| (0.0, 0.0), |a, b| (a.0 + b.0, a.1 + b.1));
        if total > 0.0 {
            err / total
        } else {
            0.0
        }
    }

    /// [`DepthLattice::cell_mean`], through [`DepthLattice::cell_mean_fma`] where `fma`.
    #[inline]
    fn cell_mean_with(&self, fma: bool, coords: [usize; 3]) -> f64 {
        #[cfg(target_arch = "x86_64")]
        if fma {
            // SAFETY: `fma` is set only where the CPU has FMA.
            return unsafe { self.cell_mean_fma(coords) };
        }
        #[cfg(not(target_arch = "x86_64"))]
        let _ = fma;
        self.cell_mean::<false>(coords)
    }

    /// [`DepthLattice::cell_mean`] compiled with FMA (its `exp` inlined: the check behind
    /// [`LightDepth::Auto`] takes 8 per sub-cell of every cell that extinguishes, 40 million on
    /// a 384-class cloud).
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "fma")]
    fn cell_mean_fma(&self, coords: [usize; 3]) -> f64 {
        self.cell_mean::<true>(coords)
    }

    /// The lattice's mean of `T_L` over the grid cell at `coords`: each sub-cell's by
    /// 2×2×2-point Gauss–Legendre.
    #[inline(always)]
    fn cell_mean<const FMA: bool>(&self, coords: [usize; 3]) -> f64 {
        let r = self.refine;
        let nodes = [0.5 - 0.5 / 3f64.sqrt(), 0.5 + 0.5 / 3f64.sqrt()];
        let [i, j, k] = coords;
        let mut sum = 0.0;
        for sk in 0..r {
            for sj in 0..r {
                for si in 0..r {
                    let depths = self.corners([i * r + si, j * r + sj, k * r + sk]);
                    for fz in nodes {
                        for fy in nodes {
                            for fx in nodes {
                                let depth = depths.lerp::<FMA>(DVec3::new(fx, fy, fz));
                                sum += exp::<FMA>(-depth);
                            }
                        }
                    }
                }
            }
        }
        sum / (8 * r * r * r) as f64
    }

    /// `∫_{t0}^{t1} e^{−σt (t−t0)} T_L(ray(t)) dt` over a view segment (inside one cell of
    /// the grid), and the light at `t1`. `start` is the light at `t0` when the caller knows
    /// it (the previous segment ended there: the lattice is continuous across faces). The
    /// segment is split where it crosses sub-cell faces; on each piece `σt s + d` is linear, so
    /// the piece integrates in closed form from its end values `F = e^{−σt (t−t0)} T_L`.
    #[inline]
    pub fn segment(&self, seg: &ViewSegment, start: Option<LightAt>) -> (f64, LightAt) {
        // Renders do not come here (the first bounce inlines `segment_body` into its own
        // FMA-compiled path), so the standard library's cached check is cheap enough.
        #[cfg(target_arch = "x86_64")]
        if medium::fma::available() {
            // SAFETY: the CPU has FMA, checked on the line above.
            return unsafe { self.segment_fma(seg, start) };
        }
        self.segment_body::<false>(seg, start)
    }

    /// [`DepthLattice::segment`] compiled with FMA: fused interpolation and the inlined
    /// [`crate::exponential::exp_fused`] instead of libm calls (the last bits differ from the
    /// portable build's).
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "fma")]
    fn segment_fma(&self, seg: &ViewSegment, start: Option<LightAt>) -> (f64, LightAt) {
        self.segment_body::<true>(seg, start)
    }

    /// [`DepthLattice::segment`] for callers that are themselves compiled with FMA (`FMA`
    /// true) or not: inlined into them.
    #[inline(always)]
    pub(crate) fn segment_body<const FMA: bool>(
        &self,
        seg: &ViewSegment,
        start: Option<LightAt>,
    ) -> (f64, LightAt) {
        match self.refine {
            1 => self.whole_cell_segment::<FMA>(seg, start),
            2 => self.halves_segment::<FMA>(seg, start),
            _ => self.sub_cell_segment::<FMA>(seg, start),
        }
    }

    /// Refinement 2 (what [`LightDepth::Auto`] takes for coarse grids): each axis has one
    /// mid-plane, so the pieces end where the segment crosses them, at most three times, sorted
    /// by a three-element network; each piece's sub-cell is the side of every mid-plane its
    /// midpoint lies on. The same pieces as [`DepthLattice::sub_cell_segment`]'s walk, without
    /// its per-axis state in memory and its unpredictable choice of axis at every step.
    #[inline(always)]
    fn halves_segment<const FMA: bool>(
        &self,
        seg: &ViewSegment,
        start: Option<LightAt>,
    ) -> (f64, LightAt) {
        let (ray, coords) = (seg.ray, seg.coords);
        let (t0, t1) = (seg.t0, seg.t1);
        let s = self.sub_size;
        let mid = DVec3::new(coords[0] as f64, coords[1] as f64, coords[2] as f64) * (2.0 * s) + s;
        // Crossings strictly inside the segment; the others become t1 (sorted to the end).
        let cross = |a: usize| {
            let d = ray.direction[a];
            let t = (mid[a] - ray.origin[a]) / d;
            if d != 0.0 && t > t0 && t < t1 {
                t
            } else {
                t1
            }
        };
        let (x, y, z) = (cross(0), cross(1), cross(2));
        let (x, y) = (x.min(y), x.max(y));
        let (y, z) = (y.min(z), y.max(z));
        let (x, y) = (x.min(y), x.max(y));
        let ends = [x, y, z, t1];
        let inner = usize::from(x < t1) + usize::from(y < t1) + usize::from(z < t1);
        let first = coords.map(|c| 2 * c);
        let sub_at = |p: DVec3| {
            [
                first[0] + usize::from(p.x >= mid.x),
                first[1] + usize::from(p.y >= mid.y),
                first[2] + usize::from(p.z >= mid.z),
            ]
        };
        let mut depths = self.corners(sub_at(ray.at(0.5 * (t0 + ends[0]))));
        let mut walk = PieceWalk::start::<FMA>(&depths, seg, start);
        for (k, &b) in ends[..inner].iter().enumerate() {
            walk.piece_to::<FMA>(&depths, seg, b);
            depths = self.corners(sub_at(ray.at(0.5 * (b + ends[k + 1]))));
        }
        walk.finish::<FMA>(&depths, seg)
    }

    /// Refinement 1: the cell is one piece.
    #[inline(always)]
    fn whole_cell_segment<const FMA: bool>(
        &self,
        seg: &ViewSegment,
        start: Option<LightAt>,
    ) -> (f64, LightAt) {
        let depths = self.corners(seg.coords);
        PieceWalk::start::<FMA>(&depths, seg, start).finish::<FMA>(&depths, seg)
    }

    /// Refinement 3 and 4 (any `r > 1`: the test of [`DepthLattice::halves_segment`] runs it
    /// at 2): the sub-cells the segment crosses are walked in order (a small DDA inside the
    /// cell), one closed-form piece each.
    #[inline(always)]
    fn sub_cell_segment<const FMA: bool>(
        &self,
        seg: &ViewSegment,
        start: Option<LightAt>,
    ) -> (f64, LightAt) {
        let (ray, coords) = (seg.ray, seg.coords);
        let r = self.refine;
        let s = self.sub_size;
        let lo = DVec3::new(coords[0] as f64, coords[1] as f64, coords[2] as f64) * (s * r as f64);
        // The sub-cell holding the start, and where the ray next crosses a sub-cell face on
        // each axis. A start on a face may land in the neighbour across it: the first piece is
        // then of zero length and the walk steps into the right sub-cell.
        let f0 = (ray.at(seg.t0) - lo) * self.inv_sub_size;
        let mut sub = [0usize; 3];
        let mut t_next = [f64::INFINITY; 3];
        let mut t_delta = [0.0f64; 3];
        let mut step_up = [false; 3];
        for a in 0..3 {
            let q = clamped_floor(f0[a], r - 1);
            sub[a] = coords[a] * r + q;
            let d = ray.direction[a];
            if d > 0.0 {
                step_up[a] = true;
                t_delta[a] = s / d;
                if q + 1 < r {
                    t_next[a] = (lo[a] + (q + 1) as f64 * s - ray.origin[a]) / d;
                }
            } else if d < 0.0 {
                t_delta[a] = -s / d;
                if q > 0 {
                    t_next[a] = (lo[a] + q as f64 * s - ray.origin[a]) / d;
                }
            }
        }
        let first = coords.map(|c| c * r);
        let mut depths = self.corners(sub);
        let mut walk = PieceWalk::start::<FMA>(&depths, seg, start);
        loop {
            let axis = if t_next[0] < t_next[1] {
                if t_next[0] < t_next[2] {
                    0
                } else {
                    2
                }
            } else if t_next[1] < t_next[2] {
                1
            } else {
                2
            };
            if t_next[axis] >= seg.t1 {
                return walk.finish::<FMA>(&depths, seg);
            }
            walk.piece_to::<FMA>(&depths, seg, t_next[axis].max(walk.a));
            // Into the neighbouring sub-cell (always inside this cell: a face on the cell's
            // boundary has no crossing scheduled).
            if step_up[axis] {
                sub[axis] += 1;
                if sub[axis] + 1 - first[axis] >= r {
                    t_next[axis] = f64::INFINITY;
                } else {
                    t_next[axis] += t_delta[axis];
                }
            } else {
                sub[axis] -= 1;
                if sub[axis] == first[axis] {
                    t_next[axis] = f64::INFINITY;
                } else {
                    t_next[axis] += t_delta[axis];
                }
            }
            depths = self.corners(sub);
        }
    }
}

/// A segment's walk over its pieces: where the next piece starts, the depth and
/// `F = e^{−σt (t−t0)} T_L` there, and the integral so far. Each piece's depth is linear
/// between its ends' trilinear values, so it integrates in closed form from `F` at both ends.
struct PieceWalk {
    a: f64,
    d_a: f64,
    f_a: f64,
    total: f64,
}

impl PieceWalk {
    /// At the segment's start, with the light carried from the previous segment if known.
    #[inline(always)]
    fn start<const FMA: bool>(
        depths: &SubCellDepths,
        seg: &ViewSegment,
        start: Option<LightAt>,
    ) -> Self {
        let (d_a, f_a) = match start {
            Some(light) => (light.depth, light.transmittance),
            None => {
                let d = depths.at::<FMA>(seg.ray.at(seg.t0));
                (d, exp::<FMA>(-d))
            }
        };
        PieceWalk {
            a: seg.t0,
            d_a,
            f_a,
            total: 0.0,
        }
    }

    /// The piece from where the walk stands to `b`, inside the segment, in `depths`' sub-cell.
    #[inline(always)]
    fn piece_to<const FMA: bool>(&mut self, depths: &SubCellDepths, seg: &ViewSegment, b: f64) {
        let sigma = seg.sigma_t;
        let d_b = depths.at::<FMA>(seg.ray.at(b));
        let f_b = exp::<FMA>(-(sigma * (b - seg.t0) + d_b));
        let len = b - self.a;
        if len > 0.0 {
            self.total += piece_integral(self.f_a, f_b, sigma * len + d_b - self.d_a, len);
        }
        (self.a, self.d_a, self.f_a) = (b, d_b, f_b);
    }

    /// The last piece, to the segment's end: the integral and the light at `t1`.
    #[inline(always)]
    fn finish<const FMA: bool>(
        mut self,
        depths: &SubCellDepths,
        seg: &ViewSegment,
    ) -> (f64, LightAt) {
        let d_b = depths.at::<FMA>(seg.ray.at(seg.t1));
        let end = LightAt {
            depth: d_b,
            transmittance: exp::<FMA>(-d_b),
        };
        let len = seg.t1 - self.a;
        if len > 0.0 {
            let f_b = seg.attenuation * end.transmittance;
            self.total += piece_integral(self.f_a, f_b, seg.sigma_t * len + d_b - self.d_a, len);
        }
        (self.total, end)
    }
}

/// A light's optical depth toward a point of a view ray and its transmittance `e^{−depth}`,
/// carried from one segment to the next.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LightAt {
    pub depth: f64,
    pub transmittance: f64,
}

/// `∫_0^L e^{−D(s)} ds` for `D` linear from `D_a` to `D_b = D_a + x`, given `f_a = e^{−D_a}`
/// and `f_b = e^{−D_b}`: `(f_a − f_b) L / x`, or its series where `|x|` is small (relative
/// error below 1e-13).
#[inline]
fn piece_integral(f_a: f64, f_b: f64, x: f64, len: f64) -> f64 {
    if x.abs() > 1e-3 {
        // len / x does not wait for f_b (an exp): the division overlaps with it.
        (f_a - f_b) * (len / x)
    } else {
        f_a * len * (1.0 - x * (0.5 - x * (1.0 / 6.0 - x * (1.0 / 24.0))))
    }
}

/// A (sub-)cell's eight corner depths, for trilinear interpolation. Trilinear is continuous
/// across faces (no seams between cells in an image) and exact wherever the depth is linear.
struct SubCellDepths {
    /// The sub-cell's lower corner in world space.
    lo: DVec3,
    inv_size: f64,
    /// `d[i + 2j + 4k]` at corner offset `(i, j, k)`.
    d: [f64; 8],
}

impl SubCellDepths {
    /// The depth at world point `x` (clamped to the sub-cell).
    #[inline(always)]
    fn at<const FMA: bool>(&self, x: DVec3) -> f64 {
        self.lerp::<FMA>((x - self.lo) * self.inv_size)
    }

    #[inline(always)]
    fn lerp<const FMA: bool>(&self, f: DVec3) -> f64 {
        let f = f.clamp(DVec3::ZERO, DVec3::ONE);
        let d = &self.d;
        let x00 = mul_add::<FMA>(f.x, d[1] - d[0], d[0]);
        let x10 = mul_add::<FMA>(f.x, d[3] - d[2], d[2]);
        let x01 = mul_add::<FMA>(f.x, d[5] - d[4], d[4]);
        let x11 = mul_add::<FMA>(f.x, d[7] - d[6], d[6]);
        let y0 = mul_add::<FMA>(f.y, x10 - x00, x00);
        let y1 = mul_add::<FMA>(f.y, x11 - x01, x01);
        mul_add::<FMA>(f.z, y1 - y0, y0)
    }
}

/// The depth model of every light of a light pass: a lattice per directional light that takes
/// one, `None` for the exit-face model (always so for point and spot lights). Building it runs
/// the [`LightDepth::Auto`] checks and any refined light passes, which cost more than a render:
/// build it once per light pass and share it ([`crate::single_scatter::SingleScatter::with_depth_model`]).
#[derive(Clone, PartialEq)]
pub struct LightDepthModel {
    lattices: Vec<Option<DepthLattice>>,
}

impl fmt::Debug for LightDepthModel {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_list()
            .entries(self.lattices.iter().map(|l| match l {
                Some(l) => format!("trilinear, refinement {}", l.refine),
                None => "exit face".to_string(),
            }))
            .finish()
    }
}

impl LightDepthModel {
    /// The model `policy` asks for, for every light of `pass`.
    pub fn build(pass: &LightPass, policy: LightDepth) -> Result<Self, GatherError> {
        let mut lattices = Vec::with_capacity(pass.fields.len());
        for (l, field) in pass.fields.iter().enumerate() {
            if !matches!(field.light, Light::Directional { .. }) {
                lattices.push(None);
                continue;
            }
            let lattice = match policy {
                LightDepth::ExitFace => None,
                LightDepth::CornerTrilinear => Some(DepthLattice::build(pass, l, 1)?),
                LightDepth::Refined(r) => Some(DepthLattice::build(pass, l, r)?),
                LightDepth::Auto => Self::auto(pass, l)?,
            };
            lattices.push(lattice);
        }
        let model = LightDepthModel { lattices };
        tracing::debug!(
            ?model,
            bytes = model.bytes(),
            "first-bounce light depth model built"
        );
        Ok(model)
    }

    fn auto(pass: &LightPass, l: usize) -> Result<Option<DepthLattice>, GatherError> {
        let cells = pass.grid.cell_count();
        let affordable = (2..=MAX_REFINEMENT)
            .take_while(|r| cells * r.pow(3) <= AUTO_SUBCELL_BUDGET)
            .last()
            .unwrap_or(1);
        for refine in 1..=affordable {
            let lattice = DepthLattice::build(pass, l, refine)?;
            if refine > 1 && refine == affordable {
                // The fallback whatever its error: no need to measure it.
                tracing::debug!(light = l, refine, "first-bounce light depth model (finest)");
                return Ok(Some(lattice));
            }
            let error = lattice.cell_mean_error(pass, l);
            tracing::debug!(
                light = l,
                refine,
                trilinear_cell_mean_error = error,
                accepted = error <= TRILINEAR_CELL_MEAN_TOLERANCE,
                "first-bounce light depth model"
            );
            if error <= TRILINEAR_CELL_MEAN_TOLERANCE {
                return Ok(Some(lattice));
            }
        }
        // Sub-cells converge to the exact T_L and beat the exit-face model from refinement 2
        // on (tests/it/single_scatter.rs), so the finest affordable lattice is the fallback; the
        // exit face only when the grid is too big to refine at all.
        Ok(None)
    }

    /// Every light's lattice (`None`: the exit-face model), in light order.
    #[inline]
    pub fn lattices(&self) -> impl Iterator<Item = Option<&DepthLattice>> {
        self.lattices.iter().map(Option::as_ref)
    }

    /// Light `l`'s lattice, or `None` for the exit-face model.
    #[inline]
    pub fn lattice(&self, l: usize) -> Option<&DepthLattice> {
        self.lattices.get(l).and_then(Option::as_ref)
    }

    /// Bytes held by the lattices (logged when built).
    pub fn bytes(&self) -> usize {
        self.lattices
            .iter()
            .flatten()
            .map(DepthLattice::bytes)
            .sum()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use medium::traversal::Ray;
    use medium::{Medium, PhaseFunction};
    use rand::{Rng, SeedableRng};
    use rand_pcg::Pcg64Mcg;

    fn close(a: f64, b: f64) -> bool {
        (a - b).abs() <= 1e-10 * a.abs().max(b.abs()) + 1e-13
    }

    /// The check's sample: every cell on grids up to its size; past it a stride sharing no
    /// factor with the rows and layers (384-class: 11; 192-class: 5, since 2, 3 and 4 divide
    /// 192), and a sampled error close to the whole grid's on a cloud-like medium.
    #[test]
    fn the_auto_check_samples_large_grids_evenly() {
        assert_eq!(check_stride(&Grid::new([64, 64, 48], 1.0).unwrap()), 1);
        assert_eq!(check_stride(&Grid::new([192, 192, 144], 1.0).unwrap()), 5);
        assert_eq!(check_stride(&Grid::new([384, 384, 288], 1.0).unwrap()), 11);
        let mut rng = Pcg64Mcg::seed_from_u64(5);
        let grid = Grid::new([64, 60, 50], 1.0).unwrap();
        let medium = Medium::homogeneous(grid, 1.0, 0.9, 0.0, PhaseFunction::Isotropic).unwrap();
        let mut channel = medium.channels()[0].clone();
        // A smooth blob with noisy cells and empty space around it: errors that vary from
        // cell to cell and region to region.
        for (i, s) in channel.sigma_t.iter_mut().enumerate() {
            let [x, y, z] = grid.coords(i).map(|v| v as f64);
            let r2 = ((x - 32.0) / 26.0).powi(2)
                + ((y - 30.0) / 24.0).powi(2)
                + ((z - 25.0) / 20.0).powi(2);
            *s = if r2 < 1.0 {
                ((1.0 - r2) * (0.5 + rng.random::<f64>())) as f32
            } else {
                0.0
            };
        }
        let medium = medium.with_channel(0, channel).unwrap();
        let light = Light::Directional {
            direction: DVec3::new(0.3, -0.8, 0.5).normalize(),
            irradiance: 1.0,
        };
        let pass = LightPass::compute(&medium, 0, &[light]).unwrap();
        let lattice = DepthLattice::build(&pass, 0, 1).unwrap();
        let whole = lattice.cell_mean_error_every(&pass, 0, 1);
        // The same cells (a grid below the sampled size); the parallel sum's order, and so
        // its last bits, differ from call to call.
        let checked = lattice.cell_mean_error(&pass, 0);
        assert!(
            (checked - whole).abs() <= 1e-12 * whole,
            "{checked} against {whole}"
        );
        assert!(whole > 1e-3, "{whole}");
        for stride in [7, 11, 13] {
            let sampled = lattice.cell_mean_error_every(&pass, 0, stride);
            assert!(
                (sampled / whole - 1.0).abs() < 0.05,
                "stride {stride}: {sampled} against {whole}"
            );
        }
    }

    /// Refinement 2's mid-plane pieces give what the general sub-cell walk gives, on random
    /// segments of a random medium: from scratch and continuing a ray, on oblique rays, rays
    /// parallel to axes and rays lying in a cell's mid-plane (no crossing there, and the
    /// sub-cell on either side of it).
    #[test]
    fn halves_match_the_sub_cell_walk() {
        let mut rng = Pcg64Mcg::seed_from_u64(17);
        let grid = Grid::new([6, 5, 4], 1.0).unwrap();
        let medium = Medium::homogeneous(grid, 1.0, 0.9, 0.0, PhaseFunction::Isotropic).unwrap();
        let mut channel = medium.channels()[0].clone();
        for s in channel.sigma_t.iter_mut() {
            *s = rng.random::<f32>() * 3.0;
        }
        let medium = medium.with_channel(0, channel).unwrap();
        let light = Light::Directional {
            direction: DVec3::new(0.4, -0.7, -0.6).normalize(),
            irradiance: 1.0,
        };
        let pass = LightPass::compute(&medium, 0, &[light]).unwrap();
        let lattice = DepthLattice::build(&pass, 0, 2).unwrap();
        let mut segments = 0;
        for n in 0..600 {
            let mut origin = DVec3::new(rng.random::<f64>() * 6.0, rng.random::<f64>() * 5.0, -0.5);
            let mut direction =
                DVec3::new(rng.random::<f64>() - 0.5, rng.random::<f64>() - 0.5, 1.0);
            match n % 4 {
                // Along y only, in the mid-plane x = 2.5 of a column of cells.
                1 => {
                    origin = DVec3::new(2.5, -0.5, rng.random::<f64>() * 4.0);
                    direction = DVec3::Y;
                }
                // In the mid-plane y = 1.5, oblique in x and z.
                2 => {
                    origin.y = 1.5;
                    direction.y = 0.0;
                }
                _ => {}
            }
            let ray = Ray::new(origin, direction);
            let mut carried: Option<LightAt> = None;
            for seg in grid.traverse(&ray, 0.0, f64::INFINITY) {
                let sigma = medium.channels()[0].sigma_t[seg.cell] as f64;
                let view = ViewSegment::new(&ray, &seg, sigma);
                for start in [None, carried] {
                    let (fast, fast_end) = lattice.halves_segment::<false>(&view, start);
                    let (walk, walk_end) = lattice.sub_cell_segment::<false>(&view, start);
                    assert!(
                        close(fast, walk)
                            && close(fast_end.depth, walk_end.depth)
                            && close(fast_end.transmittance, walk_end.transmittance),
                        "ray {n}, cell {:?}: halves {fast:e} {fast_end:?}, walk {walk:e} {walk_end:?}",
                        seg.coords
                    );
                    segments += 1;
                }
                carried = Some(lattice.sub_cell_segment::<false>(&view, carried).1);
            }
        }
        assert!(segments > 3000, "{segments} segments");
    }
}
