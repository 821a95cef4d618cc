//! The hierarchical zonal operator: an octree of cell clusters linked by an error oracle.
//!
//! Clusters form a regular pyramid: level 0 is the cells, level `l` the `2^l`-cell blocks. A
//! cluster carries its interception sum `Σ α_i` (α the chord-averaged interception;
//! extinction in the thin limit), the largest escape factor `β` of its cells, its α-weighted
//! centroid, the spread of its cells about it and its mean σt (the optical-depth pyramid used
//! for transmittance between clusters).
//!
//! Refinement starts from the root pair and splits both clusters of a pair together (so links
//! join clusters of one level). A pair becomes a link when (Barnes–Hut opening test, then the
//! oracle) its boxes are more than R cells apart, `ρ = (r_A + r_B)/d ≤ θ`, and the estimated
//! transferred fraction times the relative transfer error, `m_AB ρ² ≤ tolerance`; given each
//! cell's importance (an estimate of its solved source), also `s_AB ρ² ≤ relative_tolerance`
//! with `s_AB` the largest share of one receiver's own value the link carries, so that dim
//! cells (a shadow, the far side of a shield) get their light through fine links. Leaf pairs
//! within R cells use the exact near-field terms of [`crate::zonal`]; other leaf pairs use the
//! exact far estimate. A link carries `K_AB = G T_AB / d² · (1 + (v_A + v_B)/d²)` (`v` the
//! clusters' per-axis spread of points), so that `F_ij = α_i β_j K_AB` for
//! `i ∈ A, j ∈ B`: reciprocal (`F/σt` symmetric) by construction since each unordered pair is
//! stored once and applied both ways. Column sums are accounted per cell after the build and
//! any above 1 corrected by the symmetric scaling `D F D` (as for the exact matrix).
//!
//! Memory goes to the near rows and the leaf links. A near entry depends only on σt between
//! its two cells, so cells whose whole near neighbourhood has one σt share one row per σt
//! ([`NearField`]); likewise the leaf pairs refinement always reaches just beyond R (the
//! *ring*) for cells uniform out to it. Leaf links are counted first and then written in
//! batches straight into their receiver-sorted arrays, so the build never holds them twice.
//!
//! `apply` is pull (gather `β x` up the pyramid), link transfer per level (parallel over
//! receivers), push (scatter down), plus the near field.

use std::sync::atomic::{AtomicU32, Ordering};
use std::time::Instant;

use glam::DVec3;
use medium::{traversal::Ray, Grid, Medium};
use rayon::prelude::*;
use solver::TransportOperator;

use crate::zonal::kernel::{
    escape, geometry_factor, interception, self_shielding_depth, NearStencil,
};
use crate::zonal::{
    active_cells, albedo_vec, channel_of, far_entry, symmetrizer_weights, uniform_neighbourhoods,
    validate_near, BuildReport, FormFactorError, NearColumns, NearQuadrature,
};

/// Options of [`HierarchicalOperator::build`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HierarchicalOptions {
    pub near: NearQuadrature,
    /// Bound on `m_AB ρ²` for a link (the one accuracy knob; smaller = more links).
    pub tolerance: f64,
    /// Bound on `s_AB ρ²`, `s_AB` the largest share of one receiver's own value the link
    /// carries, when the build is given each cell's importance
    /// ([`HierarchicalOperator::build_with_importance`]): error control relative to every
    /// cell, not only to the largest transfer.
    pub relative_tolerance: f64,
    /// Largest opening ratio `(r_A + r_B)/d` of any cluster link.
    pub max_opening: f64,
    /// Store one near-field row per σt for the cells whose whole near neighbourhood has that
    /// σt ([`crate::zonal::uniform_neighbourhoods`]) instead of a row per cell: the same
    /// numbers (the row depends only on σt along the segments between the cells), traced
    /// once. Uniform regions (shields, slabs, blocks) then cost no near-field memory.
    pub share_uniform_rows: bool,
}

impl Default for HierarchicalOptions {
    fn default() -> Self {
        HierarchicalOptions {
            // Cheaper than the exact operator's default (3³ points × 48 directions): the near
            // field is the build's main cost at real sizes, and stays energy-conserving.
            near: NearQuadrature {
                radius: crate::zonal::kernel::DEFAULT_NEAR_RADIUS,
                points_per_axis: 3,
                directions: 48,
            },
            tolerance: 3e-4,
            // A link carrying all of a cell's light is refined to ρ ≤ 0.1 (1 % error there);
            // one carrying 1 % of it is left at the absolute bound. On Kobayashi's shield
            // (case ii) 1 % more links, the deep shield 14 % → 1 % (docs/validation.md).
            relative_tolerance: 1e-2,
            max_opening: 0.8,
            share_uniform_rows: true,
        }
    }
}

/// One level of the cluster pyramid.
#[derive(Clone, Debug)]
struct Level {
    dims: [usize; 3],
    /// Cells per cluster edge, `2^l`.
    span: usize,
    alpha_sum: Vec<f64>,
    beta_max: Vec<f64>,
    centroid: Vec<DVec3>,
    /// Per-axis variance of the cells' points about the centroid (α-weighted, each cell's own
    /// `h²/12` included); empty at level 0, where it is `h²/12` for every cell.
    spread: Vec<f64>,
    sigma_mean: Vec<f32>,
    /// Links into each cluster (receiver-sorted): `link_ptr[A]..link_ptr[A+1]`.
    link_ptr: Vec<usize>,
    link_src: Vec<u32>,
    link_k: Vec<f32>,
}

impl Level {
    fn count(&self) -> usize {
        self.dims[0] * self.dims[1] * self.dims[2]
    }
    fn coords(&self, c: usize) -> [usize; 3] {
        [
            c % self.dims[0],
            (c / self.dims[0]) % self.dims[1],
            c / (self.dims[0] * self.dims[1]),
        ]
    }
    fn index(&self, x: [usize; 3]) -> usize {
        x[0] + self.dims[0] * (x[1] + self.dims[1] * x[2])
    }
}

/// The hierarchical zonal operator `K = diag(a)·F`.
///
/// # Invariants
/// Built only by [`HierarchicalOperator::build`], from one channel of a valid [`Medium`]; the
/// fields are private and nothing changes them afterwards, so the pyramid, the near field,
/// the energy scaling `d` and the albedo all describe that channel's `n` cells, and the
/// symmetriser weights `w_i = 1/(a_i σt_i)` are those of this albedo and σt. (As for
/// [`FormFactorMatrix`](crate::FormFactorMatrix): another albedo means another build, or a
/// uniform factor applied outside, which keeps `w`.)
#[derive(Clone, Debug)]
pub struct HierarchicalOperator {
    grid: Grid,
    albedo: Vec<f64>,
    report: BuildReport,
    /// Unordered cluster links per level (level 0 = cell pairs beyond the near radius).
    links_per_level: Vec<usize>,
    levels: Vec<Level>,
    alpha: Vec<f64>,
    beta: Vec<f64>,
    /// Symmetric energy correction `d` (1 almost everywhere).
    scale: Vec<f64>,
    near: NearField,
    weights: Option<Vec<f64>>,
    /// Coarse aggregates for the solver's two-level methods: the clusters of level
    /// [`COARSE_LEVEL`] (blocks of `2^COARSE_LEVEL` cells per edge).
    aggregates: Vec<u32>,
}

/// Pyramid level whose clusters are the solver's coarse aggregates: 8×8×8-cell blocks, so the
/// dense coarse matrix stays small (384 aggregates for 64×64×48) and its LU cheap. (4×4×4
/// blocks, 3072 aggregates, cost seconds of LU and saved only 3 of 14 CG iterations on
/// `data/cloud.toml`: see docs/albedo.md.)
pub const COARSE_LEVEL: usize = 3;

/// What refining one chunk of candidate pairs made: links at the level refined and the pairs
/// to refine at the next level (at level 1: the pairs to split into leaf pairs).
#[derive(Default)]
struct Refined {
    links: Vec<(u32, u32, f32)>,
    refine: Vec<(u32, u32)>,
}

/// Candidate pairs refined per task.
const CANDIDATE_CHUNK: usize = 1024;
/// Level-1 pairs split into leaf links per batch (a batch's links, about 30 per pair, are
/// held once before they are written into the link arrays).
const LEAF_BATCH: usize = 1 << 16;

impl HierarchicalOperator {
    /// Builds the operator for channel `channel` of `medium`, its links' error bounded relative
    /// to the largest transfer (`m_AB ρ² ≤ tolerance`).
    pub fn build(
        medium: &Medium,
        channel: usize,
        options: &HierarchicalOptions,
    ) -> Result<Self, FormFactorError> {
        Self::build_with_importance(medium, channel, options, None)
    }

    /// As [`HierarchicalOperator::build`], with each link's error bounded also relative to its
    /// receivers' own values: `importance` estimates every cell's solved source `g` (the
    /// first-collision source will do), and a link from `B` into `A` is kept only when, besides
    /// the absolute bound, `s ρ² ≤ relative_tolerance` with
    /// `s = K β_B Σ_B g / min_A (g/α)`, the largest share of a receiver's own value the link
    /// carries (`g/α` floored at [`IMPORTANCE_FLOOR`] of its largest value).
    pub fn build_with_importance(
        medium: &Medium,
        channel: usize,
        options: &HierarchicalOptions,
        importance: Option<&[f64]>,
    ) -> Result<Self, FormFactorError> {
        let channel = channel_of(medium, channel)?;
        let grid = medium.grid();
        validate_near(&options.near)?;
        for (name, bound) in [
            ("tolerance", options.tolerance),
            ("relative_tolerance", options.relative_tolerance),
        ] {
            if !(bound.is_finite() && bound > 0.0) {
                return Err(FormFactorError::Option {
                    name,
                    reason: format!("{bound} must be finite and > 0"),
                });
            }
        }
        if let Some(w) = importance {
            validate_importance(grid, w)?;
        }
        if !(options.max_opening > 0.0 && options.max_opening <= 2.0) {
            return Err(FormFactorError::Option {
                name: "max_opening",
                reason: format!("{} must be in (0, 2]", options.max_opening),
            });
        }
        let start = Instant::now();
        let sigma_t = &channel.sigma_t;
        let h = grid.cell_size;
        let n = grid.cell_count();
        let active = active_cells(sigma_t);
        let alpha: Vec<f64> = sigma_t.iter().map(|&s| interception(s as f64, h)).collect();
        let beta: Vec<f64> = sigma_t
            .iter()
            .map(|&s| if s > 0.0 { escape(s as f64, h) } else { 0.0 })
            .collect();

        // Near field at leaf level: symmetrised rows over the (2R+1)³ neighbourhood, one
        // shared row per σt for cells whose neighbourhood is uniform.
        let stencil = NearStencil::new(&options.near);
        let radius = options.near.radius;
        let ring_radius = ring_radius(radius);
        let uniform = options
            .share_uniform_rows
            .then(|| uniform_neighbourhoods(grid, sigma_t, radius));
        let columns = NearColumns::build(grid, sigma_t, &stencil, &active, uniform.as_deref());
        drop(uniform);
        // Cells whose ring (the leaf pairs just beyond R that refinement always reaches) is
        // shared too: uniform out to the ring's radius.
        let ring_cells: Vec<bool> = if options.share_uniform_rows {
            uniform_neighbourhoods(grid, sigma_t, ring_radius)
        } else {
            Vec::new()
        };
        let (near, near_colsum) =
            NearField::build(grid, sigma_t, &stencil, &columns, &active, &ring_cells);
        drop(columns);

        // The pyramid.
        let cell_spread = h * h / 12.0;
        let mut levels = vec![Level {
            dims: grid.dims,
            span: 1,
            alpha_sum: alpha.clone(),
            beta_max: beta.clone(),
            centroid: (0..n).map(|i| grid.cell_center(i)).collect(),
            spread: Vec::new(),
            sigma_mean: sigma_t.clone(),
            link_ptr: Vec::new(),
            link_src: Vec::new(),
            link_k: Vec::new(),
        }];
        while levels.last().unwrap().dims.iter().any(|&d| d > 1) {
            let fine = levels.last().unwrap();
            let dims = fine.dims.map(|d| d.div_ceil(2));
            let mut level = Level {
                dims,
                span: fine.span * 2,
                alpha_sum: Vec::new(),
                beta_max: Vec::new(),
                centroid: Vec::new(),
                spread: Vec::new(),
                sigma_mean: Vec::new(),
                link_ptr: Vec::new(),
                link_src: Vec::new(),
                link_k: Vec::new(),
            };
            let stats: Vec<(f64, f64, DVec3, f64, f32)> = (0..level.count())
                .into_par_iter()
                .map(|c| {
                    let (mut a, mut b, mut m, mut s, mut cnt) =
                        (0.0, 0.0f64, DVec3::ZERO, 0.0f64, 0usize);
                    for ch in children(&level, fine, c) {
                        a += fine.alpha_sum[ch];
                        b = b.max(fine.beta_max[ch]);
                        m += fine.centroid[ch] * fine.alpha_sum[ch];
                        let cells = cells_in(grid, fine, ch);
                        s += fine.sigma_mean[ch] as f64 * cells as f64;
                        cnt += cells;
                    }
                    let centroid = if a > 0.0 { m / a } else { DVec3::ZERO };
                    // Parallel axes: a child's spread plus its centroid's offset (per axis).
                    let mut spread = 0.0;
                    if a > 0.0 {
                        for ch in children(&level, fine, c) {
                            let own = fine.spread.get(ch).copied().unwrap_or(cell_spread);
                            let offset = (fine.centroid[ch] - centroid).length_squared() / 3.0;
                            spread += fine.alpha_sum[ch] * (own + offset);
                        }
                        spread /= a;
                    }
                    (a, b, centroid, spread, (s / cnt as f64) as f32)
                })
                .collect();
            for (a, b, c, v, s) in stats {
                level.spread.push(v);
                level.alpha_sum.push(a);
                level.beta_max.push(b);
                level.centroid.push(c);
                level.sigma_mean.push(s);
            }
            levels.push(level);
        }

        let importance = importance.map(|w| ImportancePyramid::new(&levels, &alpha, w));

        // Refinement, level by level from the root pair.
        let top = levels.len() - 1;
        let g = geometry_factor(h);
        // Cluster links per level (1 and above), in the chunks of candidates that made them.
        let mut unordered: Vec<Vec<Vec<(u32, u32, f32)>>> = vec![Vec::new(); levels.len()];
        let mut candidates: Vec<(u32, u32)> = if levels[top].alpha_sum[0] > 0.0 {
            vec![(0, 0)]
        } else {
            vec![]
        };
        for l in (1..=top).rev() {
            let level = &levels[l];
            let fine = &levels[l - 1];
            let parts: Vec<Refined> = candidates
                .par_chunks(CANDIDATE_CHUNK)
                .map(|chunk| {
                    let mut part = Refined::default();
                    for &(a, b) in chunk {
                        let (a, b) = (a as usize, b as usize);
                        // Refined whatever the oracle says (the pair is near).
                        let forced = a == b || box_gap(grid, level, a, b) <= radius;
                        if !forced {
                            let d = (level.centroid[a] - level.centroid[b]).length();
                            let rad = 3f64.sqrt() * 0.5 * level.span as f64 * h;
                            let rho = 2.0 * rad / d;
                            if rho <= options.max_opening {
                                let t = cluster_transmittance(grid, sigma_t, level, a, b);
                                let k = g * t / (d * d) * pair_mean_factor(level, a, b, d);
                                let m = k
                                    * (level.alpha_sum[a] * level.beta_max[b])
                                        .max(level.alpha_sum[b] * level.beta_max[a]);
                                if m * rho * rho <= options.tolerance
                                    && importance.as_ref().is_none_or(|w| {
                                        w.share(l, level, a, b, k) * rho * rho
                                            <= options.relative_tolerance
                                    })
                                {
                                    part.links.push((a as u32, b as u32, k as f32));
                                    continue;
                                }
                            }
                        }
                        if l == 1 {
                            // Split into leaf pairs below, straight into the link arrays.
                            part.refine.push((a as u32, b as u32));
                            continue;
                        }
                        let (ca, na) = active_children(level, fine, a);
                        let (cb, nb) = active_children(level, fine, b);
                        for &x in &ca[..na] {
                            for &y in &cb[..nb] {
                                if a == b && y < x {
                                    continue;
                                }
                                part.refine.push((x as u32, y as u32));
                            }
                        }
                    }
                    part.links.shrink_to_fit();
                    part
                })
                .collect();
            candidates = Vec::with_capacity(parts.iter().map(|p| p.refine.len()).sum());
            for part in parts {
                candidates.extend_from_slice(&part.refine);
                if !part.links.is_empty() {
                    unordered[l].push(part.links);
                }
            }
        }
        // Leaf pairs of the level-1 pairs left: near (the near rows), in two cells' shared
        // rings, or a far link with the exact far estimate. Counted first, then computed in
        // batches and written straight into the receiver-sorted arrays (the most numerous
        // links, never held twice). A one-cell grid has no level 1: its near row is all.
        if top == 0 {
            candidates.clear();
        }
        let leaves = LeafPairs {
            grid,
            level: &levels[top.min(1)],
            fine: &levels[0],
            ring_cells: &ring_cells,
            radius,
        };
        let counts: Vec<AtomicU32> = (0..n).map(|_| AtomicU32::new(0)).collect();
        candidates.par_iter().for_each(|&(a, b)| {
            leaves.each(a as usize, b as usize, |x, y| {
                counts[x].fetch_add(1, Ordering::Relaxed);
                counts[y].fetch_add(1, Ordering::Relaxed);
            })
        });
        let mut leaf_links = LinkFill::new(counts.into_iter().map(|c| c.into_inner() as usize));
        for batch in candidates.chunks(LEAF_BATCH) {
            let parts: Vec<Vec<(u32, u32, f32)>> = batch
                .par_chunks(CANDIDATE_CHUNK)
                .map(|chunk| {
                    let mut links = Vec::new();
                    for &(a, b) in chunk {
                        leaves.each(a as usize, b as usize, |x, y| {
                            let k = far_entry(grid, sigma_t, x, y) / (alpha[x] * beta[y]);
                            links.push((x as u32, y as u32, k as f32));
                        });
                    }
                    links
                })
                .collect();
            parts
                .into_iter()
                .flatten()
                .for_each(|link| leaf_links.push(link));
        }
        drop(candidates);
        let mut links_per_level: Vec<usize> = unordered
            .iter()
            .map(|chunks| chunks.iter().map(Vec::len).sum())
            .collect();
        links_per_level[0] = leaf_links.src.len() / 2;
        leaf_links.into_level(&mut levels[0]);
        // The cluster links, counted from their chunks.
        for (level, chunks) in levels.iter_mut().zip(unordered).skip(1) {
            let mut counts = vec![0usize; level.count()];
            for &(a, b, _) in chunks.iter().flatten() {
                counts[a as usize] += 1;
                counts[b as usize] += 1;
            }
            let mut links = LinkFill::new(counts);
            chunks
                .into_iter()
                .flatten()
                .for_each(|link| links.push(link));
            links.into_level(level);
        }

        let mut op = HierarchicalOperator {
            grid: *grid,
            albedo: albedo_vec(channel),
            report: BuildReport {
                active_cells: active.len(),
                min_scale: 1.0,
                near_rays: stencil.rays(),
                ..Default::default()
            },
            links_per_level,
            levels,
            alpha,
            beta,
            scale: vec![1.0; n],
            near,
            weights: None,
            aggregates: block_aggregates(grid, COARSE_LEVEL),
        };

        // Per-column energy accounting: c_j = near_j + β_j Σ_levels Σ_links K α_sum(other end).
        let far_col = op.pull_push(|_, level, c| {
            (level.link_ptr[c]..level.link_ptr[c + 1])
                .map(|p| level.link_k[p] as f64 * level.alpha_sum[level.link_src[p] as usize])
                .sum()
        });
        let column_sums: Vec<f64> = (0..n)
            .map(|j| near_colsum[j] + op.beta[j] * far_col[j])
            .collect();
        for (j, &c) in column_sums.iter().enumerate() {
            op.report.max_column_sum_raw = op.report.max_column_sum_raw.max(c);
            if c > 1.0 {
                op.scale[j] = 1.0 / c;
                op.report.cells_scaled += 1;
                op.report.min_scale = op.report.min_scale.min(op.scale[j]);
            }
        }
        op.report.entries = op.near.stored_entries() + op.links_per_level.iter().sum::<usize>();
        op.weights = symmetrizer_weights(sigma_t, &op.albedo);
        op.report.seconds = start.elapsed().as_secs_f64();
        Ok(op)
    }

    pub fn grid(&self) -> &Grid {
        &self.grid
    }

    /// The albedo per cell, the `a` of `K = diag(a)·F`.
    pub fn albedo(&self) -> &[f64] {
        &self.albedo
    }

    /// What the build did.
    pub fn report(&self) -> &BuildReport {
        &self.report
    }

    /// Unordered cluster links per level (level 0 = cell pairs beyond the near radius).
    pub fn links_per_level(&self) -> &[usize] {
        &self.links_per_level
    }

    /// Total unordered links (all levels, leaf far pairs included).
    pub fn link_count(&self) -> usize {
        self.links_per_level.iter().sum()
    }

    /// Stored near-field entries (the shared rows' once each).
    pub fn near_entries(&self) -> usize {
        self.near.stored_entries()
    }

    /// Non-empty cells whose near-field row is shared (their neighbourhood is uniform).
    pub fn shared_near_rows(&self) -> usize {
        self.near.shared_cells
    }

    /// Bytes held by the operator's arrays.
    pub fn memory_bytes(&self) -> usize {
        let lv: usize = self
            .levels
            .iter()
            .map(|l| l.count() * (8 + 8 + 24 + 4 + 8) + l.link_src.len() * 8)
            .sum();
        lv + self.near.memory_bytes() + self.alpha.len() * 8 * 5
    }

    /// Evaluates `value(level, cluster)` for every cluster and sums it down to the cells:
    /// `out_i = Σ_levels value(level, cluster of i)`.
    fn pull_push(&self, value: impl Fn(usize, &Level, usize) -> f64 + Sync) -> Vec<f64> {
        let top = self.levels.len() - 1;
        let mut acc: Vec<f64> = (0..self.levels[top].count())
            .map(|c| value(top, &self.levels[top], c))
            .collect();
        for l in (0..top).rev() {
            let level = &self.levels[l];
            let parent = &acc;
            acc = (0..level.count())
                .into_par_iter()
                .map(|c| {
                    let x = level.coords(c);
                    let p = self.levels[l + 1].index([x[0] / 2, x[1] / 2, x[2] / 2]);
                    parent[p] + value(l, level, c)
                })
                .collect();
        }
        acc
    }

    /// `far_i = α_i Σ_levels Σ_links K u_src` with `u` the pyramid of `Σ β_j x_j`.
    fn far_field(&self, x: &[f64]) -> Vec<f64> {
        // Pull: u at every level.
        let mut u: Vec<Vec<f64>> = Vec::with_capacity(self.levels.len());
        u.push(x.iter().zip(&self.beta).map(|(x, b)| x * b).collect());
        for l in 1..self.levels.len() {
            let (level, fine) = (&self.levels[l], &self.levels[l - 1]);
            let below = &u[l - 1];
            let up: Vec<f64> = (0..level.count())
                .into_par_iter()
                .map(|c| children(level, fine, c).map(|ch| below[ch]).sum())
                .collect();
            u.push(up);
        }
        let mut far = self.pull_push(|l, level, c| {
            let ul = &u[l];
            let mut acc = 0.0;
            for p in level.link_ptr[c]..level.link_ptr[c + 1] {
                acc += level.link_k[p] as f64 * ul[level.link_src[p] as usize];
            }
            acc
        });
        far.par_iter_mut()
            .zip(&self.alpha)
            .for_each(|(f, a)| *f *= a);
        far
    }

    /// `y = F x` (without the albedo).
    pub fn apply_form_factors(&self, x: &[f64], y: &mut [f64]) {
        let xs: Vec<f64> = x.iter().zip(&self.scale).map(|(x, d)| x * d).collect();
        let far = self.far_field(&xs);
        y.par_iter_mut().enumerate().for_each(|(i, yi)| {
            *yi = self.scale[i] * (far[i] + self.near_dot(i, &xs));
        });
    }

    #[inline]
    fn near_dot(&self, i: usize, xs: &[f64]) -> f64 {
        self.near.dot(i, xs)
    }

    /// Column sums `Σ_i F_ij`, by applying the transpose to ones (`Fᵀ1 = diag(σt)⁻¹ F σt`
    /// by reciprocity, with the σt the operator was built for); inactive columns are 0.
    pub fn column_sums(&self) -> Vec<f64> {
        // The finest pyramid level's "mean" σt is the cells' own.
        let s: Vec<f64> = self.levels[0]
            .sigma_mean
            .iter()
            .map(|&s| s as f64)
            .collect();
        let mut y = vec![0.0; s.len()];
        self.apply_form_factors(&s, &mut y);
        y.iter()
            .zip(&s)
            .map(|(y, s)| if *s > 0.0 { y / s } else { 0.0 })
            .collect()
    }
}

/// The Chebyshev radius of the leaf pairs that refinement always reaches beyond the near
/// radius `R`: the cells of level-1 clusters at most `R` cells apart, `2⌊(R+1)/2⌋ + 1` (5
/// for R = 4). Which of them a cell pairs with depends on its parity (see [`NearField`]).
fn ring_radius(radius: usize) -> usize {
    2 * radius.div_ceil(2) + 1
}

/// The near field's rows: stored per cell (CSR), or for cells with a uniform neighbourhood
/// one dense `(2R+1)³` row per σt, applied over the neighbourhood clipped to the grid.
///
/// A cell uniform out to the [ring radius](ring_radius) also takes its *ring* from its σt's
/// shared row: the leaf pairs beyond R whose level-1 clusters are at most R cells apart, which
/// refinement always splits to leaves (their far estimates, otherwise stored as links). Which
/// cells those are depends only on the cell's parity per axis: with level-1 offset
/// `⌊(p + o)/2⌋` in `[−D, D]`, `D = ⌊(R+1)/2⌋`, the offset `o` ranges over
/// `[−2D − p, 2D + 1 − p]`. Both ends of a ring pair must be ring cells (`ring_mask`), as the
/// build skips exactly those links.
#[derive(Clone, Debug)]
struct NearField {
    grid: Grid,
    radius: usize,
    ring_radius: usize,
    ptr: Vec<usize>,
    col: Vec<u32>,
    /// Single precision, as the links' factors: the rows hold most of the near field's
    /// memory, and the quadrature behind them is good to about 1e-3.
    val: Vec<f32>,
    /// Per cell: its shared row in `shared`, or `u32::MAX` (its row is in the CSR arrays).
    shared_of: Vec<u32>,
    shared: Vec<Vec<f64>>,
    /// Per shared row: the far estimates over the ring's `(2·ring_radius + 1)³` box (zero
    /// within R).
    ring: Vec<Vec<f64>>,
    /// 1 for cells whose ring is shared, else 0 (empty when no cell's is).
    ring_mask: Vec<f64>,
    shared_cells: usize,
}

impl NearField {
    /// The rows of the `active` cells from their raw columns, and each cell's near column sum
    /// `Σ_j F_ji` (by reciprocity `Σ_j σt_j/σt_i F_ij`). `ring_cells` marks the cells whose
    /// ring is shared (empty: none).
    fn build(
        grid: &Grid,
        sigma_t: &[f32],
        stencil: &NearStencil,
        columns: &NearColumns,
        active: &[usize],
        ring_cells: &[bool],
    ) -> (NearField, Vec<f64>) {
        let n = grid.cell_count();
        let slots = stencil.slots();
        let ring_radius = ring_radius(stencil.radius);
        let mut near = NearField {
            grid: *grid,
            radius: stencil.radius,
            ring_radius,
            ptr: vec![0; n + 1],
            col: Vec::new(),
            val: Vec::new(),
            shared_of: vec![u32::MAX; n],
            shared: (0..columns.shared_sigma().len())
                .map(|k| columns.shared_row(k))
                .collect(),
            ring: Vec::new(),
            ring_mask: Vec::new(),
            shared_cells: 0,
        };
        let is_active = |j: u32| j != u32::MAX && sigma_t[j as usize] > 0.0;
        // Row lengths first, so the rows are written once, in place.
        let own: Vec<usize> = active
            .iter()
            .copied()
            .filter(|&i| columns.shared_of(i).is_none())
            .collect();
        let lengths: Vec<usize> = own
            .par_iter()
            .map_init(
                || vec![0u32; slots],
                |nb, &i| {
                    stencil.neighbours(grid, i, nb);
                    nb.iter().filter(|&&j| is_active(j)).count()
                },
            )
            .collect();
        for (&i, &len) in own.iter().zip(&lengths) {
            near.ptr[i + 1] = len;
        }
        for i in 0..n {
            near.ptr[i + 1] += near.ptr[i];
        }
        near.col = vec![0; near.ptr[n]];
        near.val = vec![0.0; near.ptr[n]];
        let mut rows: Vec<(usize, &mut [u32], &mut [f32])> = Vec::with_capacity(own.len());
        let (mut col_rest, mut val_rest) = (&mut near.col[..], &mut near.val[..]);
        for (&i, &len) in own.iter().zip(&lengths) {
            let (c, cr) = std::mem::take(&mut col_rest).split_at_mut(len);
            let (v, vr) = std::mem::take(&mut val_rest).split_at_mut(len);
            rows.push((i, c, v));
            (col_rest, val_rest) = (cr, vr);
        }
        let own_colsums: Vec<f64> = rows
            .into_par_iter()
            .map_init(
                || vec![0u32; slots],
                |nb, (i, cols, vals)| {
                    stencil.neighbours(grid, i, nb);
                    let mut colsum = 0.0;
                    let mut k = 0;
                    for (slot, &j) in nb.iter().enumerate() {
                        if !is_active(j) {
                            continue;
                        }
                        let f = columns.entry(sigma_t, i, j as usize, slot) as f32;
                        colsum += f as f64 * sigma_t[j as usize] as f64 / sigma_t[i] as f64;
                        cols[k] = j;
                        vals[k] = f;
                        k += 1;
                    }
                    colsum
                },
            )
            .collect();
        let mut colsum = vec![0.0; n];
        for (&i, c) in own.iter().zip(own_colsums) {
            colsum[i] = c;
        }
        for &i in active {
            if let Some(k) = columns.shared_of(i) {
                near.shared_of[i] = k as u32;
                near.shared_cells += 1;
            }
        }
        // The rings: far estimates in a uniform medium of each shared σt (a ring cell is
        // uniform out to the ring, so its far estimates are these).
        if ring_cells.iter().any(|&r| r) {
            let w = 2 * ring_radius + 1;
            let box_grid = Grid {
                dims: [w; 3],
                cell_size: grid.cell_size,
            };
            let centre = box_grid.index(ring_radius, ring_radius, ring_radius);
            near.ring = columns
                .shared_sigma()
                .iter()
                .map(|&sigma| {
                    let uniform = vec![sigma; w * w * w];
                    (0..w * w * w)
                        .map(|slot| {
                            let c = box_grid.coords(slot);
                            let cheb = c
                                .iter()
                                .map(|&v| v.abs_diff(ring_radius))
                                .max()
                                .unwrap_or(0);
                            if cheb > stencil.radius {
                                far_entry(&box_grid, &uniform, centre, slot)
                            } else {
                                0.0
                            }
                        })
                        .collect()
                })
                .collect();
            near.ring_mask = ring_cells
                .iter()
                .zip(&near.shared_of)
                .map(|(&r, &k)| if r && k != u32::MAX { 1.0 } else { 0.0 })
                .collect();
        }
        // Shared rows: σt is the same at both ends.
        for &i in active {
            if near.shared_of[i] != u32::MAX {
                let mut c = 0.0;
                near.for_each(i, |_, f| c += f);
                colsum[i] = c;
            }
        }
        (near, colsum)
    }

    /// `Σ_j F_ij x_j` over the near neighbours (and the ring) of `i`.
    #[inline]
    fn dot(&self, i: usize, xs: &[f64]) -> f64 {
        let k = self.shared_of[i];
        if k == u32::MAX {
            let mut acc = 0.0;
            for p in self.ptr[i]..self.ptr[i + 1] {
                acc += self.val[p] as f64 * xs[self.col[p] as usize];
            }
            return acc;
        }
        let mut acc = 0.0;
        let row = &self.shared[k as usize];
        self.runs(i, self.radius, [None; 3], |slot, j, len, _| {
            acc += dot(&row[slot..slot + len], &xs[j..j + len]);
        });
        if self.has_ring(i) {
            let ring = &self.ring[k as usize];
            let mask = &self.ring_mask;
            self.ring_runs(i, |slot, j, len| {
                let (r, x, m) = (&ring[slot..slot + len], &xs[j..j + len], &mask[j..j + len]);
                acc += r
                    .iter()
                    .zip(x)
                    .zip(m)
                    .map(|((r, x), m)| r * m * x)
                    .sum::<f64>();
            });
        }
        acc
    }

    #[inline]
    fn has_ring(&self, i: usize) -> bool {
        self.ring_mask.get(i).is_some_and(|&m| m > 0.0)
    }

    /// Calls `f(j, F_ij)` for every near (and ring) entry of row `i`.
    fn for_each(&self, i: usize, mut f: impl FnMut(usize, f64)) {
        let k = self.shared_of[i];
        if k == u32::MAX {
            for p in self.ptr[i]..self.ptr[i + 1] {
                f(self.col[p] as usize, self.val[p] as f64);
            }
            return;
        }
        let row = &self.shared[k as usize];
        self.runs(i, self.radius, [None; 3], |slot, j, len, _| {
            for t in 0..len {
                f(j + t, row[slot + t]);
            }
        });
        if self.has_ring(i) {
            let ring = &self.ring[k as usize];
            self.ring_runs(i, |slot, j, len| {
                for t in 0..len {
                    if self.ring_mask[j + t] > 0.0 {
                        f(j + t, ring[slot + t]);
                    }
                }
            });
        }
    }

    /// The ring's x-runs for cell `i`: the parity box of its level-1 cluster's near clusters,
    /// clipped to the grid, without its cells within R (zero in the ring's row): the box's
    /// rows within R in y and z keep only their two ends.
    fn ring_runs(&self, i: usize, mut run: impl FnMut(usize, usize, usize)) {
        let r = self.radius as i64;
        let reach = self.ring_radius as i64 - 1;
        let bounds = self.grid.coords(i).map(|v| {
            let p = (v % 2) as i64;
            Some((-reach - p, reach + 1 - p))
        });
        self.runs(i, self.ring_radius, bounds, |slot, j, len, [x0, dy, dz]| {
            if dy.abs() > r || dz.abs() > r {
                return run(slot, j, len);
            }
            let x1 = x0 + len as i64 - 1;
            let below = x1.min(-r - 1);
            if below >= x0 {
                run(slot, j, (below - x0 + 1) as usize);
            }
            let above = x0.max(r + 1);
            if above <= x1 {
                let skip = (above - x0) as usize;
                run(slot + skip, j + skip, (x1 - above + 1) as usize);
            }
        });
    }

    /// For cell `i` and a dense box row of `radius`: `run(slot, j, len, [dx, dy, dz])` for
    /// each x-run of the box (limited per axis to `bounds`, if given) clipped to the grid:
    /// `len` slots from `slot` match `len` cells from `j`, the first at offset `(dx, dy, dz)`.
    #[inline]
    fn runs(
        &self,
        i: usize,
        radius: usize,
        bounds: [Option<(i64, i64)>; 3],
        mut run: impl FnMut(usize, usize, usize, [i64; 3]),
    ) {
        let d = self.grid.dims;
        let r = radius as i64;
        let w = 2 * radius + 1;
        let c = self.grid.coords(i).map(|v| v as i64);
        let range = |a: usize| {
            let (lo, hi) = bounds[a].unwrap_or((-r, r));
            (lo.max(-c[a]), hi.min(d[a] as i64 - 1 - c[a]))
        };
        let ((x0, x1), (y0, y1), (z0, z1)) = (range(0), range(1), range(2));
        if x1 < x0 {
            return;
        }
        let len = (x1 - x0 + 1) as usize;
        for dz in z0..=z1 {
            for dy in y0..=y1 {
                let slot = (x0 + r) as usize + w * ((dy + r) as usize + w * (dz + r) as usize);
                let j = (c[0] + x0) as usize
                    + d[0] * ((c[1] + dy) as usize + d[1] * (c[2] + dz) as usize);
                run(slot, j, len, [x0, dy, dz]);
            }
        }
    }

    /// Entries held: the per-cell rows' and each shared row (and ring) once.
    fn stored_entries(&self) -> usize {
        self.val.len()
            + self.shared.iter().map(Vec::len).sum::<usize>()
            + self.ring.iter().map(Vec::len).sum::<usize>()
    }

    fn memory_bytes(&self) -> usize {
        let shared: usize = self
            .shared
            .iter()
            .chain(&self.ring)
            .map(|r| r.len() * 8)
            .sum();
        self.val.len() * 8
            + self.ptr.len() * 8
            + self.shared_of.len() * 4
            + self.ring_mask.len() * 8
            + shared
    }
}

#[inline]
fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(a, b)| a * b).sum()
}

/// One level's receiver-sorted directed links as they are written: each unordered link
/// `(a, b, K)` goes in both ways, `a ← b` and `b ← a`, at the next free place of its
/// receiver's row (rows sized beforehand by counting).
struct LinkFill {
    ptr: Vec<usize>,
    next: Vec<usize>,
    src: Vec<u32>,
    k: Vec<f32>,
}

impl LinkFill {
    /// Rows of `counts` directed links each, one per cluster of the level.
    fn new(counts: impl IntoIterator<Item = usize>) -> LinkFill {
        let mut ptr = vec![0usize];
        for c in counts {
            ptr.push(ptr[ptr.len() - 1] + c);
        }
        let total = ptr[ptr.len() - 1];
        LinkFill {
            next: ptr[..ptr.len() - 1].to_vec(),
            ptr,
            src: vec![0; total],
            k: vec![0.0; total],
        }
    }

    #[inline]
    fn push(&mut self, (a, b, k): (u32, u32, f32)) {
        for (receiver, source) in [(a, b), (b, a)] {
            let p = &mut self.next[receiver as usize];
            self.src[*p] = source;
            self.k[*p] = k;
            *p += 1;
        }
    }

    fn into_level(self, level: &mut Level) {
        level.link_ptr = self.ptr;
        level.link_src = self.src;
        level.link_k = self.k;
    }
}

/// The leaf pairs a level-1 pair splits into that are far links: not near (within R), and
/// not in both cells' shared rings ([`NearField`]).
struct LeafPairs<'a> {
    grid: &'a Grid,
    level: &'a Level,
    fine: &'a Level,
    ring_cells: &'a [bool],
    radius: usize,
}

impl LeafPairs<'_> {
    /// Calls `pair(x, y)` for each far leaf pair of level-1 pair `(a, b)` (each unordered
    /// pair once).
    fn each(&self, a: usize, b: usize, mut pair: impl FnMut(usize, usize)) {
        let (level, fine, radius) = (self.level, self.fine, self.radius);
        // Refinement always splits near level-1 pairs, so their leaf pairs are the rings.
        let forced = a == b || box_gap(self.grid, level, a, b) <= radius;
        let ring = |c: usize| self.ring_cells.get(c).is_some_and(|&r| r);
        let (ca, na) = active_children(level, fine, a);
        let (cb, nb) = active_children(level, fine, b);
        for &x in &ca[..na] {
            for &y in &cb[..nb] {
                let in_rings = forced && ring(x) && ring(y);
                if (a != b || y > x) && !in_rings && box_gap(self.grid, fine, x, y) > radius {
                    pair(x, y);
                }
            }
        }
    }
}

/// Smallest importance the oracle uses, as a fraction of the largest: cells below it are
/// treated as this bright (a link's error relative to a cell at 10⁻⁸ of the peak would ask for
/// every pair into it).
pub const IMPORTANCE_FLOOR: f64 = 1e-6;

/// Refuses an importance that is not one finite value ≥ 0 per cell, before the build's work.
fn validate_importance(grid: &Grid, importance: &[f64]) -> Result<(), FormFactorError> {
    let reason = if importance.len() != grid.cell_count() {
        format!(
            "{} values for {} cells",
            importance.len(),
            grid.cell_count()
        )
    } else if let Some(bad) = importance.iter().find(|v| !(v.is_finite() && **v >= 0.0)) {
        format!("{bad}: every value must be finite and ≥ 0")
    } else {
        return Ok(());
    };
    Err(FormFactorError::Option {
        name: "importance",
        reason,
    })
}

/// Per level and cluster, what the relative bound reads: the importance's sum `Σ g` (what a
/// cluster sends) and the smallest `g/α` of its active cells (its dimmest receiver), with
/// `g/α` floored at [`IMPORTANCE_FLOOR`] of its largest value.
struct ImportancePyramid {
    sum: Vec<Vec<f64>>,
    min: Vec<Vec<f64>>,
}

impl ImportancePyramid {
    fn new(levels: &[Level], alpha: &[f64], importance: &[f64]) -> Self {
        // Per unit interception (a flux, not a source): a cell's share of a link is
        // `α_i K Σ β_j g_j / g_i`, so what bounds it is `g/α`.
        let per_alpha = |i: usize| {
            if alpha[i] > 0.0 {
                importance[i] / alpha[i]
            } else {
                0.0
            }
        };
        let peak = (0..alpha.len()).map(per_alpha).fold(0.0f64, f64::max);
        let floor = if peak > 0.0 {
            peak * IMPORTANCE_FLOOR
        } else {
            1.0
        };
        let min0: Vec<f64> = (0..alpha.len()).map(|i| per_alpha(i).max(floor)).collect();
        let sum0: Vec<f64> = min0.iter().zip(alpha).map(|(u, a)| u * a).collect();
        let (mut sum, mut min) = (vec![sum0], vec![min0]);
        for l in 1..levels.len() {
            let (level, fine) = (&levels[l], &levels[l - 1]);
            let (s, m): (Vec<f64>, Vec<f64>) = (0..level.count())
                .into_par_iter()
                .map(|c| {
                    let (mut total, mut low) = (0.0, f64::INFINITY);
                    for ch in children(level, fine, c).filter(|&ch| fine.alpha_sum[ch] > 0.0) {
                        total += sum[l - 1][ch];
                        low = low.min(min[l - 1][ch]);
                    }
                    (total, low)
                })
                .unzip();
            sum.push(s);
            min.push(m);
        }
        ImportancePyramid { sum, min }
    }

    /// The largest share of one receiving cell's own light the link `A–B` of `level` (index
    /// `l`, factor `k`) carries, either way: `k β_B Σ_B g / min_A (g/α)`.
    fn share(&self, l: usize, level: &Level, a: usize, b: usize, k: f64) -> f64 {
        let (sum, min) = (&self.sum[l], &self.min[l]);
        k * (level.beta_max[b] * sum[b] / min[a]).max(level.beta_max[a] * sum[a] / min[b])
    }
}

/// The children of cluster `c` that hold medium, without allocating.
fn active_children(level: &Level, fine: &Level, c: usize) -> ([usize; 8], usize) {
    let (mut out, mut count) = ([0usize; 8], 0);
    for ch in children(level, fine, c).filter(|&ch| fine.alpha_sum[ch] > 0.0) {
        out[count] = ch;
        count += 1;
    }
    (out, count)
}

/// Children (at `fine`) of cluster `c` of `level`.
fn children<'a>(level: &Level, fine: &'a Level, c: usize) -> impl Iterator<Item = usize> + 'a {
    let x = level.coords(c);
    (0..8usize).filter_map(move |k| {
        let y = [
            2 * x[0] + (k & 1),
            2 * x[1] + ((k >> 1) & 1),
            2 * x[2] + (k >> 2),
        ];
        (y[0] < fine.dims[0] && y[1] < fine.dims[1] && y[2] < fine.dims[2]).then(|| fine.index(y))
    })
}

/// Leaf cells covered by cluster `c` of `level` (clipped at the grid).
fn cells_in(grid: &Grid, level: &Level, c: usize) -> usize {
    let x = level.coords(c);
    (0..3)
        .map(|a| level.span.min(grid.dims[a] - x[a] * level.span))
        .product()
}

/// Smallest Chebyshev index offset between a cell of one cluster and a cell of the other
/// (for two leaves, their Chebyshev offset); pairs with more than R are far.
fn box_gap(grid: &Grid, level: &Level, a: usize, b: usize) -> usize {
    let (xa, xb) = (level.coords(a), level.coords(b));
    let s = level.span;
    let mut gap = 0usize;
    for ax in 0..3 {
        let (a0, a1) = (xa[ax] * s, ((xa[ax] + 1) * s).min(grid.dims[ax]) - 1);
        let (b0, b1) = (xb[ax] * s, ((xb[ax] + 1) * s).min(grid.dims[ax]) - 1);
        let d = b0.saturating_sub(a1).max(a0.saturating_sub(b1));
        gap = gap.max(d);
    }
    gap
}

/// The mean transmittance between clusters `a` and `b` of `level` outside their end cells'
/// self-shielding depth (which the cell factors α, β hold; see
/// [`crate::zonal::kernel::depth_between_cells`]): `e^{−τ}` averaged over four lines parallel to the centroids' line,
/// shifted across it by `±√2 σ` along two perpendicular axes, with `σ² = (v_A + v_B)/3` the
/// mean transverse variance of a segment between the clusters' points (`v` the clusters'
/// per-axis spreads), depths traced through the data grid's σt. One centroid line through
/// the clusters' mean σt (the code before) both smoothed the medium and took `e^{−τ̄}` for
/// the mean of `e^{−τ}`, which is larger (`e^{−τ}` is convex): in dense, clumpy media the
/// links lost light at every order.
fn cluster_transmittance(grid: &Grid, sigma_t: &[f32], level: &Level, a: usize, b: usize) -> f64 {
    let (a, b) = if a < b { (a, b) } else { (b, a) };
    let (ca, cb) = (level.centroid[a], level.centroid[b]);
    let axis = cb - ca;
    let r = axis.length();
    let dir = axis / r;
    let u = dir.any_orthonormal_vector();
    let v = dir.cross(u);
    let shift = std::f64::consts::SQRT_2 * ((level.spread[a] + level.spread[b]) / 3.0).sqrt();
    let ends = self_shielding_depth(grid.cell_size)
        * (level.sigma_mean[a] as f64 + level.sigma_mean[b] as f64);
    let mut sum = 0.0;
    for offset in [u * shift, -u * shift, v * shift, -v * shift] {
        let tau = grid.optical_depth(sigma_t, &Ray::new(ca + offset, dir), 0.0, r);
        sum += (-(tau - ends).max(0.0)).exp();
    }
    0.25 * sum
}

/// The mean of `e^{−σ r}/r²` over the pairs of points of clusters `a` and `b` (centroids `d`
/// apart) against its value at `d`, to second order in the points' offsets: `1 + (v/2) ∇²`
/// of the radial kernel, `∇²(e^{−σr}/r²) = (σ² + 2σ/r + 2/r²) e^{−σr}/r²`. The `2/r²` part
/// (`1/r²` is subharmonic) takes both clusters' spread; the `σ` parts — the attenuation's
/// convexity as a point moves along the line inside its own cluster — each cluster's spread
/// `v_c` with its own mean σt. Without them a uniform 24³ block at σt h = 0.5 lost 0.7 % of
/// each cell's light to its far links.
fn pair_mean_factor(level: &Level, a: usize, b: usize, d: f64) -> f64 {
    let end = |c: usize| {
        let sigma = level.sigma_mean[c] as f64;
        level.spread[c] * (0.5 * sigma * sigma + sigma / d)
    };
    1.0 + (level.spread[a] + level.spread[b]) / (d * d) + end(a) + end(b)
}

/// Cell → index of its `2^level`-cell block (x-fastest over the blocks).
fn block_aggregates(grid: &Grid, level: usize) -> Vec<u32> {
    let d = grid.dims;
    let bd = [0, 1, 2].map(|a| d[a].div_ceil(1 << level));
    (0..grid.cell_count())
        .map(|i| {
            let x = [i % d[0], (i / d[0]) % d[1], i / (d[0] * d[1])];
            ((x[0] >> level) + bd[0] * ((x[1] >> level) + bd[1] * (x[2] >> level))) as u32
        })
        .collect()
}

/// Per cluster of one level, the sparse list `(aggregate, Σ weight)` over its cells (CSR).
struct AggregateWeights {
    ptr: Vec<usize>,
    entries: Vec<(u32, f64)>,
}

impl AggregateWeights {
    fn of_cells(aggs: &[u32], weight: impl Fn(usize) -> f64) -> Self {
        AggregateWeights {
            ptr: (0..=aggs.len()).collect(),
            entries: aggs
                .iter()
                .enumerate()
                .map(|(i, &a)| (a, weight(i)))
                .collect(),
        }
    }

    fn get(&self, c: usize) -> &[(u32, f64)] {
        &self.entries[self.ptr[c]..self.ptr[c + 1]]
    }

    /// The next level up: each cluster merges its children's lists.
    fn parent(&self, level: &Level, fine: &Level) -> Self {
        let mut ptr = Vec::with_capacity(level.count() + 1);
        let mut entries = Vec::new();
        let mut buf: Vec<(u32, f64)> = Vec::new();
        ptr.push(0);
        for c in 0..level.count() {
            buf.clear();
            for ch in children(level, fine, c) {
                buf.extend_from_slice(self.get(ch));
            }
            buf.sort_unstable_by_key(|e| e.0);
            let start = entries.len();
            for &(a, v) in &buf {
                match entries[start..].last_mut() {
                    Some((last, acc)) if *last == a => *acc += v,
                    _ => entries.push((a, v)),
                }
            }
            ptr.push(entries.len());
        }
        AggregateWeights { ptr, entries }
    }
}

impl TransportOperator for HierarchicalOperator {
    fn len(&self) -> usize {
        self.albedo.len()
    }

    fn apply(&self, x: &[f64], y: &mut [f64]) {
        self.apply_form_factors(x, y);
        y.par_iter_mut()
            .zip(&self.albedo)
            .for_each(|(y, a)| *y *= a);
    }

    /// Gauss–Seidel on the near field in cell order, with the far field (links) evaluated
    /// once per sweep from the current iterate (block Jacobi for the far part).
    fn sweep_in_place(&self, g: &mut [f64], source: &[f64], omega: f64) -> bool {
        let xs: Vec<f64> = g.iter().zip(&self.scale).map(|(x, d)| x * d).collect();
        let far = self.far_field(&xs);
        let mut xs = xs;
        for i in 0..g.len() {
            let kg = self.albedo[i] * self.scale[i] * (far[i] + self.near_dot(i, &xs));
            g[i] = (1.0 - omega) * g[i] + omega * (source[i] + kg);
            xs[i] = g[i] * self.scale[i];
        }
        true
    }

    fn symmetrizer(&self) -> Option<&[f64]> {
        self.weights.as_deref()
    }

    fn coarse_aggregates(&self) -> Option<&[u32]> {
        Some(&self.aggregates)
    }

    /// Cell-centred finite volumes: face conductance `2 D_i D_j / ((D_i + D_j) h²)` between
    /// cells of the medium, Marshak vacuum faces `D / (h (h/2 + 2D))` towards empty cells and
    /// the grid's edges.
    fn diffusion(&self) -> Option<solver::Diffusion> {
        // σt per cell is the finest pyramid level's mean.
        let sigma_cells = &self.levels[0].sigma_mean;
        let grid = &self.grid;
        let h = grid.cell_size;
        let d = grid.dims;
        let n = self.len();
        let coef = |i: usize| 1.0 / (3.0 * sigma_cells[i] as f64);
        let stride = [1, d[0], d[0] * d[1]];
        let mut row_ptr = Vec::with_capacity(n + 1);
        let mut col = Vec::new();
        let mut val = Vec::new();
        row_ptr.push(0);
        for i in 0..n {
            if sigma_cells[i] > 0.0 {
                let x = [i % d[0], (i / d[0]) % d[1], i / (d[0] * d[1])];
                let di = coef(i);
                let mut diag = 0.0;
                for ax in 0..3 {
                    for up in [false, true] {
                        let neighbour = if up {
                            (x[ax] + 1 < d[ax]).then(|| i + stride[ax])
                        } else {
                            (x[ax] > 0).then(|| i - stride[ax])
                        };
                        match neighbour.filter(|&j| sigma_cells[j] > 0.0) {
                            Some(j) => {
                                let dj = coef(j);
                                let c = 2.0 * di * dj / ((di + dj) * h * h);
                                diag += c;
                                col.push(j as u32);
                                val.push(-c);
                            }
                            None => diag += di / (h * (0.5 * h + 2.0 * di)),
                        }
                    }
                }
                col.push(i as u32);
                val.push(diag);
            }
            row_ptr.push(col.len());
        }
        let sigma_t: Vec<f64> = sigma_cells.iter().map(|&s| s as f64).collect();
        let sigma_s = sigma_t
            .iter()
            .zip(&self.albedo)
            .map(|(s, a)| s * a)
            .collect();
        // Valid by construction (σt of a checked medium, albedo in [0, 1], conductances ≥ 0);
        // `None` rather than a panic should that ever change.
        solver::Diffusion::new(sigma_t, sigma_s, row_ptr, col, val).ok()
    }

    /// `Pᵀ W K P` exactly, from the near entries and the cluster links (no application of
    /// `K`): a link `A ← B` adds `K_AB (Σ_{i∈A∩c} w_i a_i d_i α_i)(Σ_{j∈B∩d} β_j d_j)` to
    /// entry `(c, d)`, with the per-cluster sums merged up the pyramid.
    fn coarse_operator(
        &self,
        aggregates: &[u32],
        n_coarse: usize,
        row_weights: Option<&[f64]>,
    ) -> Option<Vec<f64>> {
        let n = self.len();
        if aggregates.len() != n
            || row_weights.is_some_and(|w| w.len() != n)
            || aggregates.iter().any(|&a| a as usize >= n_coarse)
        {
            return None;
        }
        let nc = n_coarse;
        let recv: Vec<f64> = (0..n)
            .map(|i| row_weights.map_or(1.0, |w| w[i]) * self.albedo[i] * self.scale[i])
            .collect();
        let mut receivers = vec![AggregateWeights::of_cells(aggregates, |i| {
            recv[i] * self.alpha[i]
        })];
        let mut sources = vec![AggregateWeights::of_cells(aggregates, |j| {
            self.beta[j] * self.scale[j]
        })];
        for l in 1..self.levels.len() {
            let (level, fine) = (&self.levels[l], &self.levels[l - 1]);
            receivers.push(receivers[l - 1].parent(level, fine));
            sources.push(sources[l - 1].parent(level, fine));
        }
        // Work split by receiver cell / cluster into one dense accumulator per task.
        let tasks = rayon::current_num_threads().max(1);
        let partial = |t: usize| -> Vec<f64> {
            let mut kc = vec![0.0; nc * nc];
            let part = |len: usize| (t * len / tasks)..((t + 1) * len / tasks);
            for i in part(n) {
                let row = aggregates[i] as usize * nc;
                self.near.for_each(i, |j, f| {
                    kc[row + aggregates[j] as usize] += recv[i] * f * self.scale[j];
                });
            }
            for (l, level) in self.levels.iter().enumerate() {
                for a in part(level.count()) {
                    let into = receivers[l].get(a);
                    if into.is_empty() {
                        continue;
                    }
                    for p in level.link_ptr[a]..level.link_ptr[a + 1] {
                        let k = level.link_k[p] as f64;
                        let from = sources[l].get(level.link_src[p] as usize);
                        for &(c, wa) in into {
                            let row = &mut kc[c as usize * nc..][..nc];
                            for &(d, wb) in from {
                                row[d as usize] += k * wa * wb;
                            }
                        }
                    }
                }
            }
            kc
        };
        let kc = (0..tasks)
            .into_par_iter()
            .map(partial)
            .reduce_with(|mut a, b| {
                a.iter_mut().zip(&b).for_each(|(x, y)| *x += y);
                a
            })?;
        Some(kc)
    }
}
