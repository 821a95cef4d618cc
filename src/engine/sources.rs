//! The scattered light a render adds from a solution, as [`gather::InScattering`] sources:
//! the exact first bounce from `gather::single_scatter` plus the solved higher orders — per
//! cell ([`CellSource`], zonal), per cell and direction bin ([`BinnedSource`], discrete
//! ordinates) or the two-pass method's stored field.

use anyhow::Result;
use formfactor::ordinates::bins::{face_bilinear, interpolate_with};
use gather::single_scatter::{SingleScatter, SingleScatterOptions};
use gather::{each_step, InScattering, OpticalModel, RayCarry, StepSample, Trilinear, ViewSegment};
use glam::DVec3;
use medium::phase::{IncidentShape, ShapeScattering};
use medium::{CellValues, ChannelMedium, Grid, Interpolation, Medium, PhaseFunction};

use crate::engine::solution::{
    CellRows, ChannelSolution, EmitterBeam, InverseScattering, RenderCache, ScatteredField,
    Solution, EMITTER_BEAM_VALUES,
};

/// Where a per-cell source is drawn between cell centres: `trilinear` renders (which call
/// `at`) reconstruct the source function `Q/σt` trilinearly over the cells with σt > 0 and
/// multiply by the reconstructed σt ([`Trilinear::source`]), so a solved field looks as
/// smooth as the medium.
///
/// A `nearest` medium's cells keep their own σs, but the light in them is continuous (the
/// solve gives each cell's mean; drawn constant per cell it was up to 4 % off per pixel next
/// to a bright emitter or a lit face): its source is drawn as the cell's σs times the
/// in-scattered radiance `Q/σs` interpolated trilinearly between the centres of the cells
/// that scatter, from centre values corrected so that each cell keeps its solved mean
/// (`segment` takes it at the segment's middle).
///
/// A source solved on a coarser transport grid is drawn the same way from the transport
/// cells: the data grid's σs times their in-scattered radiance, interpolated between their
/// centres — smooth light over the data's own detail.
#[derive(Clone, Copy)]
pub struct CellLattice<'a> {
    grid: Grid,
    sigma_t: &'a [f32],
    /// The medium is `trilinear` (else `at` is the cell's own value, as `segment`'s).
    trilinear: bool,
    /// The transport grid, when the source lives on one coarser than `grid`.
    transport: Option<TransportLattice<'a>>,
}

/// How many times brighter one side of a [`TransportLattice::regions`] boundary must be than
/// the other for the two cells to be drawn apart. Across an emitting region's boundary the
/// first scattering is continuous (its derivative jumps): interpolated, a cube emitting in a
/// cloud is drawn within 1.1 % RMS (isotropic and g = 0.6), with this constant 0 (always
/// apart) 1.8 % and 2.2 %, and 4, 1.2 % and 1.5 %. But scattered forward (g = 0.85) toward a
/// view along the boundary it changes many-fold within a cell (light along a face comes from
/// the emitter on one side of it and not on the other), more than a mean-keeping line
/// between centres can hold without going negative: drawn across, the dim bands' first
/// scattering around the cube was 8–34 % low (`cargo test --release --test it emitters --
/// --nocapture`).
const REGION_CONTRAST: f64 = 8.0;

#[derive(Clone, Copy)]
struct TransportLattice<'a> {
    coarse: Grid,
    /// `1 / coarse.cell_size`.
    inverse_coarse_size: f64,
    /// The data grid's channel (its σs).
    channel: &'a ChannelMedium,
    /// `1/σs` per transport cell, 0 where it does not scatter.
    inverse_sigma_s: &'a [f32],
    max_sigma_s: f64,
    /// Centre values corrected so that each cell keeps its own mean ([`nodal_ratio`]): a
    /// `nearest` medium on its own grid, whose solved values are the cells' means. (On a
    /// transport grid the data cells' own σs already vary inside a transport cell.)
    ///
    /// [`nodal_ratio`]: TransportLattice::nodal_ratio
    keep_cell_means: bool,
    /// Cells on either side of a boundary the drawn field may change steeply across (the
    /// emitting cells for the emitters' first scattering, [`CellLattice::split_at`]): where
    /// the two sides differ more than [`REGION_CONTRAST`]-fold, a point takes no value from
    /// the other side's centres, and a centre's mean-keeping correction counts a neighbour
    /// there as itself. `None`: one region.
    regions: Option<&'a [bool]>,
    /// The transport grid is at least twice as coarse as the data grid: [`pair`] reads the
    /// field once, midway between its two steps.
    ///
    /// [`pair`]: TransportLattice::pair
    pairs_share_a_read: bool,
}

impl TransportLattice<'_> {
    /// Whether cells `a` and `b`, of `Q/σs` `ra` and `rb`, are drawn apart: on either side
    /// of the regions' boundary, one more than [`REGION_CONTRAST`] times the other.
    #[inline]
    fn apart(&self, a: usize, ra: f64, b: usize, rb: f64) -> bool {
        self.regions.is_some_and(|r| {
            r[a] != r[b] && (ra > REGION_CONTRAST * rb || rb > REGION_CONTRAST * ra)
        })
    }

    /// The transport cell holding `x` (the nearest where `x` is on the grid's surface).
    #[inline]
    fn cell_of(&self, x: DVec3) -> usize {
        let q = x * self.inverse_coarse_size;
        let [nx, ny, nz] = self.coarse.dims;
        self.coarse.index(
            medium::grid::clamped_floor(q.x, nx - 1),
            medium::grid::clamped_floor(q.y, ny - 1),
            medium::grid::clamped_floor(q.z, nz - 1),
        )
    }

    /// `σs · Q/σs` at `x`: `sigma_s` is the data grid's σs there, `value` the transport
    /// cells' source ([`at_block`](Self::at_block) with a block of its own, read afresh).
    #[inline]
    fn at(&self, x: DVec3, sigma_s: f64, value: impl FnMut(usize) -> f64) -> f64 {
        let mut block = Block::EMPTY;
        self.at_block(x, sigma_s, &mut block, (0, 0), value)
    }

    /// [`at`](Self::at) through `block`, which keeps the 8 transport cells' `Q/σs` around
    /// the last point: a ray's steps stay between the same 8 centres for several steps
    /// (`2s` at half a data cell per step), so their values are read once, not once per step.
    #[inline]
    fn at_block(
        &self,
        x: DVec3,
        sigma_s: f64,
        block: &mut Block,
        tag: (u64, u64),
        mut value: impl FnMut(usize) -> f64,
    ) -> f64 {
        if sigma_s <= 0.0 {
            return 0.0;
        }
        let corners = Trilinear::with_inverse_size(&self.coarse, self.inverse_coarse_size, x);
        let cells = corners.cells();
        // With regions, which corner holds `x`: the others are read against it.
        let own = self.regions.and_then(|_| {
            let cell = self.cell_of(x);
            cells.iter().position(|&c| c == cell)
        });
        let key = (tag.0, tag.1, 9 * cells[0] + own.map_or(8, |k| k), cells[7]);
        if block.key != Some(key) {
            block.key = Some(key);
            let own = own.map(|k| {
                let o = cells[k];
                (o, value(o) * self.inverse_sigma_s[o] as f64)
            });
            for (k, &o) in cells.iter().enumerate() {
                let inv = self.inverse_sigma_s[o] as f64;
                let r = if inv > 0.0 { value(o) * inv } else { 0.0 };
                let drawn = inv > 0.0 && !own.is_some_and(|(a, ra)| self.apart(a, ra, o, r));
                (block.ratio[k], block.scatters[k]) = if drawn && self.keep_cell_means {
                    (self.nodal_ratio(o, r, &mut value), 1.0)
                } else if drawn {
                    (r, 1.0)
                } else {
                    (0.0, 0.0)
                };
            }
        }
        let weights = corners.weights();
        let (mut sum, mut weight) = (0.0, 0.0);
        for ((w, r), m) in weights.iter().zip(&block.ratio).zip(&block.scatters) {
            sum += w * r;
            weight += w * m;
        }
        if weight > 0.0 {
            sigma_s * sum / weight
        } else {
            0.0
        }
    }

    /// The value at cell `o`'s centre whose trilinear interpolant keeps the cell's own mean
    /// `Q/σs`: the interpolant of centre values `v` averages `(v₋ + 6 v + v₊) / 8` over a
    /// cell along each axis, so `v = r − (r₋ − 2 r + r₊) / 8` per axis (`r` = `Q/σs`). Where
    /// a neighbour does not scatter (or lies outside the grid) the interpolant holds the
    /// cell's own value on that side, so that neighbour counts as `r` (`v = r − (r₊ − r) / 8`);
    /// left uncorrected, a cloud's edge cells took a share of their brighter interior's light
    /// and its silhouette came out bright. Without the correction the interpolated light
    /// loses (where the light peaks inside the medium) or gains (where it falls off) a share
    /// of each cell's solved energy — about −1 % of the image mean on a cloud of albedo 0.99.
    /// Never below 0. `r` is the cell's own `Q/σs` (`value(o)` times its `1/σs`).
    #[inline]
    fn nodal_ratio(&self, o: usize, r: f64, value: &mut impl FnMut(usize) -> f64) -> f64 {
        let [nx, ny, nz] = self.coarse.dims;
        let (i, j, k) = (o % nx, (o / nx) % ny, o / (nx * ny));
        let mut curvature = 0.0;
        let mut neighbour = |at: Option<usize>| {
            at.map(|c| (c, self.inverse_sigma_s[c] as f64))
                .filter(|&(_, inv)| inv > 0.0)
                .map(|(c, inv)| (c, value(c) * inv))
                .filter(|&(c, rc)| !self.apart(o, r, c, rc))
                .map_or(r, |(_, rc)| rc)
        };
        for (coord, n, stride) in [(i, nx, 1), (j, ny, nx), (k, nz, nx * ny)] {
            let lo = (coord > 0).then(|| o - stride);
            let hi = (coord + 1 < n).then(|| o + stride);
            curvature += neighbour(lo) - 2.0 * r + neighbour(hi);
        }
        (r - 0.125 * curvature).max(0.0)
    }

    /// Two consecutive steps of a march in thin medium ([`InScattering::at_step_pair`]):
    /// each step's σs times `ratio`, `Q/σs` at a point ([`at`](Self::at) or
    /// [`at_block`](Self::at_block) with σs = 1). On a transport grid at least twice as
    /// coarse as the data (found once, where the lattice is built) the field is read once,
    /// midway between the steps: the steps are at most a quarter of a transport cell from
    /// there, and the field is trilinear between transport cells' centres (the 192-class
    /// cloud's views moved by 0.004 % RMS; docs/performance.md). On finer transport grids,
    /// at each step.
    #[inline]
    fn pair(
        &self,
        steps: &[StepSample; 2],
        trilinear: bool,
        mut ratio: impl FnMut(DVec3) -> f64,
    ) -> [f64; 2] {
        let [a, b] = steps;
        let (ratio_a, ratio_b) = if self.pairs_share_a_read {
            let r = ratio(0.5 * (a.x + b.x));
            (r, r)
        } else {
            (ratio(a.x), ratio(b.x))
        };
        [
            self.sigma_s_at(a, trilinear) * ratio_a,
            self.sigma_s_at(b, trilinear) * ratio_b,
        ]
    }

    /// The data grid's σs at a step: σt there (the renderer's, when it reads this medium's)
    /// times a uniform albedo, else interpolated from the cells' own σs.
    #[inline]
    fn sigma_s_at(&self, step: &StepSample, trilinear: bool) -> f64 {
        match (&self.channel.albedo, trilinear) {
            (CellValues::Uniform(a), true) => *a as f64 * step.sigma_t_from(&self.channel.sigma_t),
            (_, true) => step.corners.sample(|i| self.channel.sigma_s(i) as f64),
            (_, false) => self.channel.sigma_s(step.corners.cell()) as f64,
        }
    }
}

/// The transport cells' `Q/σs` (0 where a cell does not scatter) and whether each scatters
/// (1 or 0), at the 8 corners of one block of [`Trilinear::cells`], for one source and
/// direction.
#[derive(Clone, Copy)]
struct Block {
    /// `(generation, source, first corner, last corner)` the values are of.
    key: Option<(u64, u64, usize, usize)>,
    ratio: [f64; 8],
    scatters: [f64; 8],
}

impl Block {
    /// A block that holds nothing yet.
    const EMPTY: Block = Block {
        key: None,
        ratio: [0.0; 8],
        scatters: [0.0; 8],
    };
}

impl<'a> CellLattice<'a> {
    /// Channel `c` of `medium`, for a source on its own grid.
    pub fn of_medium(medium: &'a Medium, c: usize) -> Self {
        CellLattice {
            grid: *medium.grid(),
            sigma_t: &medium.channels()[c].sigma_t,
            trilinear: medium.interpolation() == Interpolation::Trilinear,
            transport: None,
        }
    }

    /// Channel `c` of `medium` for a source on its own grid, drawn as a solution draws it: a
    /// `trilinear` medium's as [`of_medium`](Self::of_medium); a `nearest` medium's as its
    /// cells' σs times the in-scattered radiance interpolated between centres, keeping each
    /// cell's mean (the type's doc). `scattering` is
    /// [`InverseScattering::of_channel`](crate::engine::solution::InverseScattering::of_channel)
    /// of the same channel.
    pub fn of_own_grid(medium: &'a Medium, c: usize, scattering: &'a InverseScattering) -> Self {
        let lattice = Self::of_medium(medium, c);
        if lattice.trilinear {
            return lattice;
        }
        let grid = *medium.grid();
        CellLattice {
            transport: Some(TransportLattice {
                coarse: grid,
                inverse_coarse_size: 1.0 / grid.cell_size,
                channel: &medium.channels()[c],
                inverse_sigma_s: &scattering.inverse_sigma_s,
                max_sigma_s: scattering.max_sigma_s,
                keep_cell_means: true,
                regions: None,
                // The data grid itself: no coarser than the data.
                pairs_share_a_read: false,
            }),
            ..lattice
        }
    }

    /// Channel `c` of `solution` (the solved one); `ch` is its solution.
    pub fn of(solution: &'a Solution, c: usize, ch: &'a ChannelSolution) -> Result<Self> {
        let medium = &solution.medium;
        if solution.transport.is_data_grid() {
            if medium.interpolation() == Interpolation::Trilinear {
                return Ok(Self::of_medium(medium, c));
            }
            return Ok(Self::of_own_grid(
                medium,
                c,
                ch.render_cache.own_grid(medium, c),
            ));
        }
        let scattering = &ch
            .render_cache
            .transport(medium, &solution.transport, c)?
            .scattering;
        let coarse = *solution.transport.transport();
        // A split grid of a `nearest` medium has σs constant in each transport cell, as a
        // data grid does: its centre values can keep each cell's mean. A coarser grid's
        // cells hold data cells of differing σs.
        let keep_cell_means = solution.transport.split_factor() > 1
            && medium.interpolation() == Interpolation::Nearest;
        let transport = Some(TransportLattice {
            coarse,
            inverse_coarse_size: 1.0 / coarse.cell_size,
            channel: &medium.channels()[c],
            inverse_sigma_s: &scattering.inverse_sigma_s,
            max_sigma_s: scattering.max_sigma_s,
            keep_cell_means,
            regions: None,
            pairs_share_a_read: coarse.cell_size >= 2.0 * medium.grid().cell_size,
        });
        Ok(CellLattice {
            transport,
            ..Self::of_medium(medium, c)
        })
    }

    /// `Q` at `x` in `cell` from the per-cell `value` (see the type's doc).
    #[inline]
    fn at(&self, x: DVec3, cell: usize, mut value: impl FnMut(usize) -> f64) -> f64 {
        if let Some(t) = &self.transport {
            let sigma_s = if self.trilinear {
                Trilinear::new(&self.grid, x).sample(|i| t.channel.sigma_s(i) as f64)
            } else {
                t.channel.sigma_s(cell) as f64
            };
            return t.at(x, sigma_s, value);
        }
        if self.trilinear {
            Trilinear::new(&self.grid, x).source(self.sigma_t, value)
        } else {
            value(cell)
        }
    }

    /// [`at`](Self::at) with what the renderer found at its step.
    #[inline]
    fn at_step(&self, step: &StepSample, mut value: impl FnMut(usize) -> f64) -> f64 {
        if let Some(t) = &self.transport {
            return t.at(step.x, t.sigma_s_at(step, self.trilinear), value);
        }
        if self.trilinear {
            step.corners.source(self.sigma_t, value)
        } else {
            value(step.corners.cell())
        }
    }

    /// `Q` of a `nearest` render's segment: the cell's σs times the in-scattered radiance at
    /// the segment's middle (the cell's own value only for a lattice of the bare medium,
    /// [`of_medium`](Self::of_medium)).
    #[inline]
    fn segment(&self, seg: &ViewSegment, value: impl Fn(usize) -> f64) -> f64 {
        match &self.transport {
            None => value(seg.cell),
            Some(t) => t.at(
                seg.ray.at(0.5 * (seg.t0 + seg.t1)),
                t.channel.sigma_s(seg.cell) as f64,
                value,
            ),
        }
    }

    /// An upper bound on `Q` anywhere from `values` (`per_cell` values per cell of the grid
    /// they live on).
    fn bound(&self, values: &[f32], per_cell: usize) -> f64 {
        self.bound_of_cells(
            values
                .chunks(per_cell.max(1))
                .map(|v| v.iter().copied().fold(0.0f32, f32::max))
                .enumerate(),
        )
    }

    /// [`bound`](Self::bound) of one value per cell given for some cells only (the rest 0).
    fn bound_of_cells(&self, values: impl Iterator<Item = (usize, f32)>) -> f64 {
        match &self.transport {
            None => values.map(|(_, v)| v).fold(0.0f32, f32::max) as f64,
            Some(t) => {
                let ratio = values
                    .map(|(cell, v)| v as f64 * t.inverse_sigma_s[cell] as f64)
                    .fold(0.0, f64::max);
                // A corrected centre value is at most r + 3 · 2r / 8 (three axes, neighbours
                // at 0).
                let correction = if t.keep_cell_means { 1.75 } else { 1.0 };
                t.max_sigma_s * ratio * correction
            }
        }
    }

    /// The grid the solved per-cell values live on: the transport grid, or the data grid.
    fn solved_grid(&self) -> &Grid {
        self.transport.as_ref().map_or(&self.grid, |t| &t.coarse)
    }

    /// Whether centre values are corrected to keep each cell's mean (a `nearest` medium on
    /// its own grid).
    fn keeps_cell_means(&self) -> bool {
        self.transport.is_some_and(|t| t.keep_cell_means)
    }

    /// For one value per cell: the values whose plain interpolation ([`plain`](Self::plain))
    /// is that of `values` with each cell's mean kept — the cell's σs times its corrected
    /// centre ratio. `values` itself for a lattice that keeps no means.
    fn centre_values(&self, values: &[f32]) -> Vec<f32> {
        use rayon::prelude::*;
        let Some(t) = self.transport.filter(|t| t.keep_cell_means) else {
            return values.to_vec();
        };
        (0..values.len())
            .into_par_iter()
            .map(|o| {
                let inv = t.inverse_sigma_s[o] as f64;
                if inv > 0.0 {
                    let r = values[o] as f64 * inv;
                    (t.nodal_ratio(o, r, &mut |i| values[i] as f64) / inv) as f32
                } else {
                    values[o]
                }
            })
            .collect()
    }

    /// This lattice drawing a field that may change steeply between cells marked `true` in
    /// `regions` and the rest (one mark per cell of the solved grid): where the two sides
    /// differ more than [`REGION_CONTRAST`]-fold, each is interpolated and keeps its cells'
    /// means on its own. Only a lattice that keeps cell means on the data grid (a `nearest`
    /// medium) takes it; the others are returned as they are.
    pub fn split_at(self, regions: &'a [bool]) -> CellLattice<'a> {
        let Some(t) = self.transport else {
            return self;
        };
        if !t.keep_cell_means
            || t.coarse.dims != self.grid.dims
            || regions.len() != self.grid.cell_count()
        {
            return self;
        }
        CellLattice {
            transport: Some(TransportLattice {
                regions: Some(regions),
                ..t
            }),
            ..self
        }
    }

    /// This lattice without the correction of its centre values.
    fn plain(&self) -> CellLattice<'a> {
        CellLattice {
            transport: self.transport.map(|t| TransportLattice {
                keep_cell_means: false,
                ..t
            }),
            ..*self
        }
    }
}

/// Higher-order isotropic source per cell (zonal `g − E`): one value per cell, the same in
/// every direction.
pub struct CellSource<'a> {
    values: std::borrow::Cow<'a, [f32]>,
    lattice: CellLattice<'a>,
    max: f64,
}

impl<'a> CellSource<'a> {
    pub fn new(values: &'a [f32], lattice: CellLattice<'a>) -> Self {
        Self::drawn(values, lattice, None)
    }

    /// As [`new`](Self::new), the corrected centre values (if the lattice keeps cell means)
    /// kept in `cache` for every render of the same solution channel.
    pub fn cached(values: &'a [f32], lattice: CellLattice<'a>, cache: &'a RenderCache) -> Self {
        Self::drawn(values, lattice, Some(cache))
    }

    fn drawn(values: &'a [f32], lattice: CellLattice<'a>, cache: Option<&'a RenderCache>) -> Self {
        // One value per cell and direction-free: the centre values that keep each cell's
        // mean are found once per source (or per solution, with a cache), not from 7 cells
        // at every step of the render.
        let (values, lattice) = if lattice.keeps_cell_means() {
            let make = || lattice.centre_values(values);
            let centre = match cache {
                Some(cache) => std::borrow::Cow::Borrowed(cache.centre_values(make)),
                None => std::borrow::Cow::Owned(make()),
            };
            (centre, lattice.plain())
        } else {
            (std::borrow::Cow::Borrowed(values), lattice)
        };
        let max = lattice.bound(&values, 1);
        CellSource {
            values,
            lattice,
            max,
        }
    }
}

impl InScattering for CellSource<'_> {
    #[inline]
    fn segment(&self, seg: &ViewSegment, _: &mut RayCarry) -> f64 {
        self.lattice.segment(seg, |c| self.values[c] as f64) * seg.weight
    }
    #[inline]
    fn at(&self, x: DVec3, cell: usize, _w: DVec3) -> f64 {
        self.lattice.at(x, cell, |c| self.values[c] as f64)
    }
    #[inline]
    fn at_step(&self, step: &StepSample, _w: DVec3) -> f64 {
        self.lattice.at_step(step, |c| self.values[c] as f64)
    }
    #[inline]
    fn at_step_pair(&self, steps: &[StepSample; 2], w: DVec3) -> [f64; 2] {
        match &self.lattice.transport {
            Some(t) => {
                let mut block = Block::EMPTY;
                let mut value = |c| self.values[c] as f64;
                t.pair(steps, self.lattice.trilinear, |x| {
                    t.at_block(x, 1.0, &mut block, (0, 0), &mut value)
                })
            }
            None => each_step(self, steps, w),
        }
    }
    fn max_source(&self) -> f64 {
        self.max
    }
    fn is_zero(&self) -> bool {
        self.max == 0.0
    }
}

/// A per-cell, per-bin source looked up by direction between bin centres
/// (`formfactor::ordinates::bins::interpolate_bins`: geometric between positive centres; the
/// layout of `formfactor::ordinates::bins`: bin `f n² + i n + j`).
pub struct BinnedSource<'a> {
    /// Per cell and bin; cells without a row read as zeros.
    rows: &'a CellRows,
    /// `ln` of the rows' values (−∞ for 0), as they are laid out.
    logs: &'a [f32],
    n: usize,
    lattice: CellLattice<'a>,
    max: f64,
    /// Unique per source made in this process: what [`LookupCache`] entries are tagged with.
    id: u64,
}

/// The next [`BinnedSource`]'s id.
static NEXT_SOURCE_ID: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(1);

impl<'a> BinnedSource<'a> {
    /// `logs` is `ln` of the rows' values, element by element ([`RenderCache::log_source`]).
    ///
    /// [`RenderCache::log_source`]: crate::engine::solution::RenderCache::log_source
    pub fn new(rows: &'a CellRows, logs: &'a [f32], n: usize, lattice: CellLattice<'a>) -> Self {
        debug_assert_eq!(rows.values().len(), logs.len());
        debug_assert_eq!(rows.width(), 6 * n * n);
        let max = lattice.bound(&rows.row_maxima(), 1);
        BinnedSource {
            rows,
            logs,
            n,
            lattice,
            max,
            id: NEXT_SOURCE_ID.fetch_add(1, std::sync::atomic::Ordering::Relaxed),
        }
    }

    /// This thread's lookups of this source toward `w` (`cache`: the thread's
    /// [`LookupCache`]): each cell's value, cached for the ray; this source's block of
    /// transport cells; and the tag its entries carry.
    #[inline(always)]
    fn lookups<'c>(
        &'c self,
        cache: &'c mut LookupCache,
        w: DVec3,
    ) -> (impl FnMut(usize) -> f64 + 'c, &'c mut Block, (u64, u64)) {
        let weights = cache.direction(self.n, w);
        let LookupCache {
            generation,
            cells,
            blocks,
            ..
        } = cache;
        let generation = *generation;
        let value = move |c| cells.get(generation, self.id, c, || self.lookup_with(c, &weights));
        let block = &mut blocks[(self.id as usize) % BLOCKS];
        (value, block, (generation, self.id))
    }

    /// The source of `cell` in the direction whose bin weights are `weights`.
    #[inline]
    fn lookup_with(&self, cell: usize, weights: &[(usize, f64); 4]) -> f64 {
        let Some(base) = self.rows.start_of(cell) else {
            return 0.0;
        };
        let values = self.rows.values();
        interpolate_with(
            weights,
            |l| values[base + l] as f64,
            |l| self.logs[base + l] as f64,
        )
    }
}

/// Slots of [`LookupCache`] (a power of two).
const LOOKUP_SLOTS: usize = 256;

/// The binned sources' values of the cells a ray's last steps read, in the ray's direction.
/// A `trilinear` render reads the same 8 neighbours for several steps (4 per data cell, more
/// on a transport grid), and each read interpolates 4 bins geometrically, so the values are
/// kept per thread until the direction changes (a new ray). Direct-mapped by a hash of the
/// cell; an entry also names its source, so the channels of one ray share it, and the
/// direction it was made for (a generation count, so a new ray empties nothing).
struct LookupCache {
    /// The direction and bin count of the current generation (NaN before the first).
    key: (DVec3, usize),
    generation: u64,
    weights: [(usize, f64); 4],
    cells: CellSlots,
    /// The last block of transport cells read per source (by its id modulo [`BLOCKS`]).
    blocks: [Block; BLOCKS],
}

/// Blocks of [`LookupCache`]: one per source of a ray's channels, up to this many.
const BLOCKS: usize = 4;

/// Direct-mapped per-cell values of [`LookupCache`].
struct CellSlots {
    /// `(generation, source, cell)` per slot (`source`: the [`BinnedSource`]'s id).
    tags: [(u64, u64, usize); LOOKUP_SLOTS],
    values: [f64; LOOKUP_SLOTS],
}

impl CellSlots {
    #[inline]
    fn get(
        &mut self,
        generation: u64,
        source: u64,
        cell: usize,
        value: impl FnOnce() -> f64,
    ) -> f64 {
        let tag = (generation, source, cell);
        // Fibonacci hashing: neighbours a row or a layer apart land in different slots.
        let hash = (cell as u64 ^ source.rotate_left(29)).wrapping_mul(0x9E37_79B9_7F4A_7C15);
        let slot = (hash >> (64 - LOOKUP_SLOTS.trailing_zeros())) as usize;
        if self.tags[slot] == tag {
            return self.values[slot];
        }
        let v = value();
        self.tags[slot] = tag;
        self.values[slot] = v;
        v
    }
}

impl LookupCache {
    /// The bin weights of direction `w` for `n²` bins per face; a direction other than the
    /// last call's starts a new generation.
    #[inline]
    fn direction(&mut self, n: usize, w: DVec3) -> [(usize, f64); 4] {
        // Compared as floats, not bits (a store and reload of each): the same direction is
        // the same ray's, and no ray has a NaN direction.
        if self.key != (w, n) {
            self.key = (w, n);
            self.generation += 1;
            self.weights = face_bilinear(n, w);
        }
        self.weights
    }

    fn new() -> Box<LookupCache> {
        Box::new(LookupCache {
            key: (DVec3::NAN, 0),
            generation: 0,
            weights: [(0, 0.0); 4],
            cells: CellSlots {
                tags: [(0, 0, 0); LOOKUP_SLOTS],
                values: [0.0; LOOKUP_SLOTS],
            },
            blocks: [Block::EMPTY; BLOCKS],
        })
    }

    /// Runs `f` with this thread's cache. The cache lives on the heap: thread-local storage
    /// itself stays a pointer, as a library loaded at run time (the Python module) has only a
    /// little static TLS to give.
    #[inline]
    fn with<R>(f: impl FnOnce(&mut LookupCache) -> R) -> R {
        LOOKUPS.with_borrow_mut(|cache| f(cache.get_or_insert_with(LookupCache::new)))
    }
}

thread_local! {
    static LOOKUPS: std::cell::RefCell<Option<Box<LookupCache>>> =
        const { std::cell::RefCell::new(None) };
}

impl InScattering for BinnedSource<'_> {
    #[inline]
    fn segment(&self, seg: &ViewSegment, _: &mut RayCarry) -> f64 {
        let weights = face_bilinear(self.n, -seg.ray.direction);
        self.lattice.segment(seg, |c| self.lookup_with(c, &weights)) * seg.weight
    }
    #[inline]
    fn at(&self, x: DVec3, cell: usize, w: DVec3) -> f64 {
        LookupCache::with(|cache| {
            let weights = cache.direction(self.n, w);
            self.lattice.at(x, cell, |c| {
                cache.cells.get(cache.generation, self.id, c, || {
                    self.lookup_with(c, &weights)
                })
            })
        })
    }
    #[inline]
    fn at_step(&self, step: &StepSample, w: DVec3) -> f64 {
        LookupCache::with(|cache| {
            let (mut value, block, tag) = self.lookups(cache, w);
            match &self.lattice.transport {
                Some(t) => {
                    let sigma_s = t.sigma_s_at(step, self.lattice.trilinear);
                    t.at_block(step.x, sigma_s, block, tag, value)
                }
                None => self.lattice.at_step(step, &mut value),
            }
        })
    }
    #[inline]
    fn at_step_pair(&self, steps: &[StepSample; 2], w: DVec3) -> [f64; 2] {
        let Some(t) = &self.lattice.transport else {
            return each_step(self, steps, w);
        };
        LookupCache::with(|cache| {
            let (mut value, block, tag) = self.lookups(cache, w);
            t.pair(steps, self.lattice.trilinear, |x| {
                t.at_block(x, 1.0, block, tag, &mut value)
            })
        })
    }
    fn max_source(&self) -> f64 {
        self.max
    }
    fn is_zero(&self) -> bool {
        self.max == 0.0
    }
}

/// Where a render's camera sees the medium from: what the emitters' binned first scattering
/// ([`EmitterBeamSource`]) is evaluated toward, once per cell and view.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Viewpoint {
    /// A perspective camera's eye: light reaches it from `x` along `eye − x`.
    Eye(DVec3),
    /// An orthographic camera: light reaches it along this unit direction everywhere.
    Along(DVec3),
}

impl Viewpoint {
    pub fn of_camera(camera: &gather::Camera) -> Viewpoint {
        match camera.projection {
            gather::CameraProjection::Perspective { .. } => Viewpoint::Eye(camera.eye),
            gather::CameraProjection::Orthographic { .. } => Viewpoint::Along(-camera.forward),
        }
    }

    /// The direction light flows from `x` to the camera (unit; along the view axis where
    /// `x` is the eye).
    fn from(&self, x: DVec3) -> DVec3 {
        match *self {
            Viewpoint::Eye(eye) => (eye - x).try_normalize().unwrap_or(DVec3::Z),
            Viewpoint::Along(d) => d,
        }
    }
}

/// The emitters' first scattering (discrete ordinates with an emitter pass), in the view's own
/// direction: per cell of the solved grid `[σs φ, weight, cos_half_angle, d]`
/// ([`emitter_beam`](crate::engine::methods::emitter_beam)), the source toward `ω` being
/// `σs φ · S(shape, ω·d)` ([`medium::phase::ShapeScattering`]) with the true phase function,
/// drawn between cells as the solved sources are. The widest-lit cells, whose light is
/// kept in direction bins, take `σs φ · S(bins, ω_c)` instead, `ω_c` the direction from the
/// cell's centre to the camera ([`Viewpoint`]), evaluated once per view: 192 bins per cell
/// are too many to sum at every step, and the directions of the rays through one cell differ
/// by about its size over its distance.
pub struct EmitterBeamSource<'a> {
    values: &'a [f32],
    binned: &'a CellRows,
    /// Per binned cell (by rank), `σs φ · S(bins, ω_c)`.
    toward_camera: Vec<f32>,
    scattering: &'a ShapeScattering,
    lattice: CellLattice<'a>,
    max: f64,
}

impl<'a> EmitterBeamSource<'a> {
    /// `beam` is a solution's ([`EmitterBeam`], on the lattice's solved grid); the table and
    /// the shapes' bound are built on the first render and kept in `cache`, the binned
    /// cells' values are this view's.
    pub fn new(
        beam: &'a EmitterBeam,
        phase: PhaseFunction,
        emission: &CellValues,
        lattice: CellLattice<'a>,
        cache: &'a RenderCache,
        view: Viewpoint,
    ) -> Self {
        use rayon::prelude::*;
        let values = &beam.shapes[..];
        let (scattering, shapes_max, emitting) = cache.emitter_beam(|| {
            // Scattered forward toward a view along the emitting region's boundary, the light
            // changes many-fold across it (inside, it comes from all sides; beside, from
            // one): see `REGION_CONTRAST`.
            let emitting: Vec<bool> = (0..values.len() / EMITTER_BEAM_VALUES)
                .map(|i| emission.get(i) > 0.0)
                .collect();
            let lattice = lattice.split_at(&emitting);
            let scattering = phase.shape_scattering();
            // Each cell's largest value: forward or backward, whichever its shape favours (a
            // cone's average of the phase function is largest along its axis or opposite it).
            let largest: Vec<f32> = values
                .chunks(EMITTER_BEAM_VALUES)
                .map(|v| {
                    let shape = IncidentShape::from_parts(v[1] as f64, v[2] as f64);
                    let peak = scattering
                        .eval(shape, 1.0)
                        .max(scattering.eval(shape, -1.0));
                    (v[0] as f64 * peak) as f32
                })
                .collect();
            let max = lattice.bound(&largest, 1);
            (scattering, max, emitting)
        });
        let lattice = lattice.split_at(emitting);
        let grid = lattice.solved_grid();
        let rows: Vec<(usize, &[f32])> = beam.binned.kept_rows().collect();
        let toward_camera: Vec<f32> = rows
            .par_iter()
            .map(|&(cell, row)| {
                let w = view.from(grid.cell_center(cell));
                let sigma_s_phi = values[cell * EMITTER_BEAM_VALUES] as f64;
                (sigma_s_phi * scattering.eval_binned(row, w)) as f32
            })
            .collect();
        let binned_max = lattice.bound_of_cells(
            rows.iter()
                .zip(&toward_camera)
                .map(|(&(cell, _), &v)| (cell, v)),
        );
        EmitterBeamSource {
            values,
            binned: &beam.binned,
            toward_camera,
            scattering,
            lattice,
            max: shapes_max.max(binned_max),
        }
    }

    /// The source of `cell` toward `w` (the direction light flows).
    #[inline]
    fn toward(&self, cell: usize, w: DVec3) -> f64 {
        let v = &self.values[cell * EMITTER_BEAM_VALUES..(cell + 1) * EMITTER_BEAM_VALUES];
        if v[0] == 0.0 {
            return 0.0;
        }
        if let Some(k) = self.binned.rank_of(cell) {
            return self.toward_camera[k] as f64;
        }
        let shape = IncidentShape::from_parts(v[1] as f64, v[2] as f64);
        let d = DVec3::new(v[3] as f64, v[4] as f64, v[5] as f64);
        v[0] as f64 * self.scattering.eval(shape, w.dot(d))
    }
}

impl InScattering for EmitterBeamSource<'_> {
    #[inline]
    fn segment(&self, seg: &ViewSegment, _: &mut RayCarry) -> f64 {
        let w = -seg.ray.direction;
        self.lattice.segment(seg, |c| self.toward(c, w)) * seg.weight
    }
    #[inline]
    fn at(&self, x: DVec3, cell: usize, w: DVec3) -> f64 {
        self.lattice.at(x, cell, |c| self.toward(c, w))
    }
    #[inline]
    fn at_step(&self, step: &StepSample, w: DVec3) -> f64 {
        self.lattice.at_step(step, |c| self.toward(c, w))
    }
    fn max_source(&self) -> f64 {
        self.max
    }
    fn is_zero(&self) -> bool {
        self.max == 0.0
    }
}

/// The two-pass method's stored field drawn between cell centres as the other solved fields
/// are: its mean over directions per cell (the tallies of all bins together, the least noisy
/// part) as a [`CellSource`], times the cell's own angular shape (its value in the bin of the
/// direction over its mean). Each cell keeps its mean in every bin, and a bin's Monte Carlo
/// outlier stays in its cell (interpolating the bins themselves would spread it over the
/// neighbours).
pub struct TwoPassSource<'a> {
    field: &'a montecarlo::two_pass::TwoPassSolution,
    mean: CellSource<'a>,
    /// The per-cell means (the values `mean` draws).
    means: &'a [f32],
    max: f64,
}

impl<'a> TwoPassSource<'a> {
    /// `means` and `largest_ratio` are [`TwoPassSource::means_of`] `field` (kept per solution
    /// in `cache`).
    pub fn new(
        field: &'a montecarlo::two_pass::TwoPassSolution,
        (means, largest_ratio): (&'a [f32], f64),
        lattice: CellLattice<'a>,
        cache: &'a RenderCache,
    ) -> Self {
        let mean = CellSource::cached(means, lattice, cache);
        let max = mean.max_source() * largest_ratio;
        TwoPassSource {
            field,
            mean,
            means,
            max,
        }
    }

    /// The field's mean over its (equal) direction bins per cell, and the largest ratio of a
    /// cell's value in one bin to its mean (what bounds the drawn source).
    pub fn means_of(field: &montecarlo::two_pass::TwoPassSolution) -> (Vec<f32>, f64) {
        let bins = field.bins.count().max(1);
        let mut largest_ratio = 0.0f64;
        let means = (0..field.grid.cell_count())
            .map(|c| {
                let (sum, top) = (0..bins)
                    .map(|l| field.source_in_bin(c, l))
                    .fold((0.0, 0.0f64), |(s, t), v| (s + v, t.max(v)));
                let mean = sum / bins as f64;
                if mean > 0.0 {
                    largest_ratio = largest_ratio.max(top / mean);
                }
                mean as f32
            })
            .collect();
        (means, largest_ratio)
    }

    /// The field in `cell` for light flowing along `w` over the cell's mean.
    #[inline]
    fn shape(&self, cell: usize, w: DVec3) -> f64 {
        let mean = self.means[cell] as f64;
        if mean > 0.0 {
            self.field.source(cell, w) / mean
        } else {
            0.0
        }
    }
}

impl InScattering for TwoPassSource<'_> {
    #[inline]
    fn segment(&self, seg: &ViewSegment, carry: &mut RayCarry) -> f64 {
        self.mean.segment(seg, carry) * self.shape(seg.cell, -seg.ray.direction)
    }
    #[inline]
    fn at(&self, x: DVec3, cell: usize, w: DVec3) -> f64 {
        self.mean.at(x, cell, w) * self.shape(cell, w)
    }
    #[inline]
    fn at_step(&self, step: &StepSample, w: DVec3) -> f64 {
        self.mean.at_step(step, w) * self.shape(step.corners.cell(), w)
    }
    fn max_source(&self) -> f64 {
        self.max
    }
    fn is_zero(&self) -> bool {
        self.max == 0.0
    }
}

/// All scattered light of channel `c` for a render with `model` from `view`: the exact first
/// bounce (true phase function, shadowed or "Utah") plus the solved higher orders.
pub fn channel_scattering<'a>(
    solution: &'a Solution,
    c: usize,
    ch: &'a ChannelSolution,
    model: OpticalModel,
    view: Viewpoint,
) -> Result<Box<dyn InScattering + 'a>> {
    let shadows = match model {
        OpticalModel::Scattering => true,
        OpticalModel::SingleScatterUnshadowed => false,
        _ => return Ok(Box::new(())),
    };
    let options = SingleScatterOptions {
        shadows,
        ..SingleScatterOptions::default()
    };
    let depth = ch.render_cache.light_depth(&ch.light_pass)?;
    let first =
        SingleScatter::with_depth_model(&solution.medium, c, &ch.light_pass, options, depth)?;
    if !shadows {
        return Ok(Box::new(first));
    }
    Ok(match (&ch.scattered, &solution.bins) {
        (ScatteredField::Isotropic { higher_order, .. }, _) => Box::new((
            first,
            CellSource::cached(
                higher_order,
                CellLattice::of(solution, c, ch)?,
                &ch.render_cache,
            ),
        )),
        (ScatteredField::Binned { higher_order, .. }, Some(bins)) => {
            let logs = ch.render_cache.log_source(higher_order.values());
            let lattice = CellLattice::of(solution, c, ch)?;
            let higher = BinnedSource::new(higher_order, logs, bins.face_resolution, lattice);
            match &ch.emitted_beam {
                Some(beam) => Box::new((
                    first,
                    (
                        higher,
                        EmitterBeamSource::new(
                            beam,
                            solution.medium.phase(),
                            &solution.medium.channels()[c].emission,
                            lattice,
                            &ch.render_cache,
                            view,
                        ),
                    ),
                )),
                None => Box::new((first, higher)),
            }
        }
        (ScatteredField::TwoPass(t), _) => {
            let means = ch
                .render_cache
                .two_pass_means(|| TwoPassSource::means_of(t));
            let lattice = CellLattice::of(solution, c, ch)?;
            Box::new((
                first,
                TwoPassSource::new(t, means, lattice, &ch.render_cache),
            ))
        }
        _ => Box::new(first),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The light `source` draws in cell `cell` of a row along x, averaged over the cell.
    fn drawn_mean(source: &CellSource, cell: usize) -> f64 {
        let n = 1000;
        (0..n)
            .map(|k| {
                let x = DVec3::new(cell as f64 + (k as f64 + 0.5) / n as f64, 0.5, 0.5);
                source.at(x, cell, DVec3::X)
            })
            .sum::<f64>()
            / n as f64
    }

    /// A row of 7 scattering cells (σs = 1) whose solved values are the cell means of
    /// `(x − ½)²`, `i² + 1/12`: drawn smoothly, each cell keeps its mean exactly (a quadratic
    /// is what the correction is exact for); interpolating the means as centre values would
    /// add `Δ²r / 8 = 1/4` to every inner cell.
    #[test]
    fn a_nearest_medium_keeps_each_cells_mean_when_drawn_smoothly() {
        let grid = Grid::new([7, 1, 1], 1.0).unwrap();
        let medium =
            Medium::grey(grid, vec![1.0; 7], 1.0, medium::PhaseFunction::Isotropic).unwrap();
        assert_eq!(medium.interpolation(), Interpolation::Nearest);
        let scattering = InverseScattering::of_channel(&medium, 0);
        let means: Vec<f32> = (0..7).map(|i| (i * i) as f32 + 1.0 / 12.0).collect();
        let source = CellSource::new(&means, CellLattice::of_own_grid(&medium, 0, &scattering));
        // Cells 2–4: their neighbours' centre values are corrected on both sides (an edge
        // cell's on one: `a_rows_end_cells_keep_their_means`), and none is negative.
        for (cell, &mean) in means.iter().enumerate().take(5).skip(2) {
            let average = drawn_mean(&source, cell);
            let mean = mean as f64;
            assert!(
                (average - mean).abs() < 1e-4 * mean.max(1.0),
                "cell {cell}: drawn {average}, solved {mean}"
            );
            // Smooth: the light at the cell's faces is its neighbours' too.
            let face = DVec3::new(cell as f64 + 1.0, 0.5, 0.5);
            let (left, right) = (
                source.at(face, cell, DVec3::X),
                source.at(face, cell + 1, DVec3::X),
            );
            assert!((left - right).abs() < 1e-9, "{left} {right}");
        }
    }

    /// A row's end cells keep their means too, to first order: next to an empty side the
    /// interpolant holds the cell's own value, so the correction counts the missing
    /// neighbour as the cell itself. On a linear rise 1, 2, 3, 4 the ends were drawn 1/8
    /// toward their neighbours before (1.125 and 3.875: an edge darker than its interior
    /// came out bright); now within 1/64.
    #[test]
    fn a_rows_end_cells_keep_their_means() {
        let grid = Grid::new([4, 1, 1], 1.0).unwrap();
        let medium =
            Medium::grey(grid, vec![1.0; 4], 1.0, medium::PhaseFunction::Isotropic).unwrap();
        let scattering = InverseScattering::of_channel(&medium, 0);
        let means = [1.0f32, 2.0, 3.0, 4.0];
        let source = CellSource::new(&means, CellLattice::of_own_grid(&medium, 0, &scattering));
        for cell in [0, 3] {
            let average = drawn_mean(&source, cell);
            let mean = means[cell] as f64;
            assert!(
                (average - mean).abs() < 0.02,
                "cell {cell}: drawn {average}, solved {mean}"
            );
        }
    }

    /// One cell of σt 1 (a lattice under which `at` is the cell's own value).
    fn one_cell() -> CellLattice<'static> {
        CellLattice {
            grid: Grid::new([1, 1, 1], 1.0).unwrap(),
            sigma_t: &[1.0],
            trilinear: true,
            transport: None,
        }
    }

    /// A `trilinear` medium draws a per-cell source without steps: the cell's value at its
    /// centre, continuous across the face between two cells, and next to an empty cell the
    /// source function of the full one times the fading σt (not pulled toward zero twice).
    #[test]
    fn cell_sources_are_continuous_between_cells_of_a_trilinear_medium() {
        let grid = Grid::new([3, 1, 1], 1.0).unwrap();
        let sigma_t = [1.0f32, 2.0, 0.0];
        let values = [1.0f32, 6.0, 0.0];
        let lattice = CellLattice {
            grid,
            sigma_t: &sigma_t,
            trilinear: true,
            transport: None,
        };
        let source = CellSource::new(&values, lattice);
        let at = |x: f64| source.at(DVec3::new(x, 0.5, 0.5), (x as usize).min(2), DVec3::X);
        assert!((at(0.5) - 1.0).abs() < 1e-12 && (at(1.5) - 6.0).abs() < 1e-12);
        let (left, right) = (at(1.0 - 1e-9), at(1.0 + 1e-9));
        assert!((left - right).abs() < 1e-6, "{left} vs {right}");
        // Half way to the empty cell: σt = 1, source function still the full cell's 3.
        assert!((at(2.0) - 3.0).abs() < 1e-12, "{}", at(2.0));
        assert_eq!(at(2.5), 0.0);
        // The renderer's path, with the neighbours it found, gives the same values.
        for x in [0.5, 0.99, 1.3, 2.0, 2.5] {
            let p = DVec3::new(x, 0.5, 0.5);
            assert_eq!(
                source.at_step(&StepSample::new(&grid, &sigma_t, p), DVec3::X),
                at(x)
            );
        }
        let nearest = CellSource::new(
            &values,
            CellLattice {
                trilinear: false,
                ..lattice
            },
        );
        assert_eq!(nearest.at(DVec3::new(1.9, 0.5, 0.5), 1, DVec3::X), 6.0);
    }

    /// One cell's row of bins.
    fn one_row(values: &[f32]) -> CellRows {
        CellRows::from_dense(1, values.len(), |i| values[i]).unwrap()
    }

    /// A field peaked in one bin, looked up towards the far corner of its face, where the
    /// extrapolation weight of that bin is negative: the source is 0 there, not negative, and
    /// still the bin's value at its centre.
    #[test]
    fn binned_source_never_goes_negative_past_the_outer_centres() {
        let n = 2;
        let mut values = vec![0.0f32; 6 * n * n];
        // Face +x, bin (i = 0 along y, j = 1 along z).
        values[1] = 1.0;
        let logs: Vec<f32> = values.iter().map(|v| v.ln()).collect();
        let rows = one_row(&values);
        let source = BinnedSource::new(&rows, &logs, n, one_cell());
        let corner = DVec3::new(1.0, 0.95, 0.95).normalize();
        let weights = face_bilinear(n, corner);
        let raw: f64 = weights.iter().map(|&(l, w)| w * values[l] as f64).sum();
        assert!(raw < 0.0, "the case must extrapolate below zero ({raw})");
        assert_eq!(source.at(DVec3::splat(0.5), 0, corner), 0.0);
        let centre = DVec3::new(1.0, -0.5, 0.5).normalize();
        assert!((source.at(DVec3::splat(0.5), 0, centre) - 1.0).abs() < 1e-12);
    }

    /// Two sources read alternately in one direction at the same cells (the channels of one
    /// ray) each give their own values through the per-thread lookup cache, and a new
    /// direction gives that direction's values, not the cached ones.
    #[test]
    fn the_lookup_cache_keeps_sources_and_directions_apart() {
        let n = 2;
        let a: Vec<f32> = (0..6 * n * n).map(|l| 1.0 + l as f32).collect();
        let b: Vec<f32> = a.iter().map(|v| 100.0 * v).collect();
        let logs = |v: &[f32]| v.iter().map(|x| x.ln()).collect::<Vec<f32>>();
        let (la, lb) = (logs(&a), logs(&b));
        let (ra, rb) = (one_row(&a), one_row(&b));
        let (sa, sb) = (
            BinnedSource::new(&ra, &la, n, one_cell()),
            BinnedSource::new(&rb, &lb, n, one_cell()),
        );
        let x = DVec3::splat(0.5);
        let d1 = DVec3::new(1.0, 0.2, -0.3).normalize();
        let d2 = DVec3::new(-0.2, 1.0, 0.4).normalize();
        let direct = |s: &BinnedSource, d: DVec3| s.lookup_with(0, &face_bilinear(n, d));
        for d in [d1, d1, d2, d1] {
            for s in [&sa, &sb, &sa] {
                assert_eq!(s.at(x, 0, d), direct(s, d));
            }
        }
        assert!((sb.at(x, 0, d2) / sa.at(x, 0, d2) - 100.0).abs() < 1e-3);
    }

    /// Half way between two positive centres the source is their geometric mean (exact for
    /// a source falling off exponentially with the angle), at the centres their values, and
    /// next to a zero centre the linear mean.
    #[test]
    fn binned_source_interpolates_geometrically_between_positive_centres() {
        let n = 2;
        let mut values = vec![0.0f32; 6 * n * n];
        // Face +x: bins (0, 0) and (1, 0) are 4 and 1, (0, 1) and (1, 1) too.
        values[0] = 4.0;
        values[1] = 4.0;
        values[2] = 1.0;
        values[3] = 1.0;
        let logs: Vec<f32> = values.iter().map(|v| v.ln()).collect();
        let rows = one_row(&values);
        let source = BinnedSource::new(&rows, &logs, n, one_cell());
        let between = DVec3::new(1.0, 0.0, 0.0);
        assert!((source.at(DVec3::splat(0.5), 0, between) - 2.0).abs() < 1e-6);
        let at_centre = DVec3::new(1.0, -0.5, -0.5).normalize();
        assert!((source.at(DVec3::splat(0.5), 0, at_centre) - 4.0).abs() < 1e-5);
        values[3] = 0.0;
        let logs: Vec<f32> = values.iter().map(|v| v.ln()).collect();
        let rows = one_row(&values);
        let source = BinnedSource::new(&rows, &logs, n, one_cell());
        assert!((source.at(DVec3::splat(0.5), 0, between) - 2.25).abs() < 1e-6);
    }
}
