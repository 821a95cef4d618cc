//! What a solve will cost in memory, and the check that refuses one that cannot fit before any
//! work starts.
//!
//! [`solve_peak`] predicts the peak resident memory of solving a scene with given settings as
//! a sum of named parts (the process, the medium, the light pass, each method's operator and
//! state, the iteration's work vectors, what further channels keep). Its coefficients are the
//! measured bytes per unit of what each method allocates; `benches/memory.py` compares the
//! prediction with the measured peak of `volrad solve` on every method (docs/performance.md,
//! "Memory"). [`check_solve`] compares the prediction with a limit — `--max-memory`, the
//! service's per-job limit, or the memory the machine has available — and, when it does not
//! fit, says what would.

use std::fmt;

use anyhow::{bail, Result};
use medium::coarsening::{Coarsening, MAX_TRANSPORT_SCALE, MAX_TRANSPORT_SPLIT};
use medium::Grid;
use scene::{BinCount, Scene, SolveMethod, SolveSettings, TransportRefinement, TransportScale};

/// One term of a prediction.
#[derive(Clone, Debug, serde::Serialize)]
pub struct MemoryPart {
    pub what: &'static str,
    pub bytes: u64,
}

/// A predicted peak of resident memory, in named parts.
#[derive(Clone, Debug, serde::Serialize)]
pub struct MemoryEstimate {
    parts: Vec<MemoryPart>,
}

impl MemoryEstimate {
    pub fn total(&self) -> u64 {
        self.parts.iter().map(|p| p.bytes).sum()
    }

    pub fn parts(&self) -> &[MemoryPart] {
        &self.parts
    }

    /// The largest part (what a refusal names as the cause).
    pub fn largest(&self) -> &MemoryPart {
        self.parts
            .iter()
            .max_by_key(|p| p.bytes)
            .expect("an estimate has the process part at least")
    }
}

/// The process itself: code, thread stacks, allocator arenas, the runtime (measured: a solve
/// of a tiny scene peaks at 22–25 MiB).
const PROCESS_BYTES: u64 = 22 << 20;
/// The time model's kernel ([`super::timing::machine_factor`]), where it runs: its operator
/// and vectors, freed before the solve allocates (measured: 4.5 MiB more on a 16 × 16 × 12
/// zonal solve; a large solve reuses the memory).
const TIME_KERNEL_BYTES: u64 = 4 << 20;
/// Per cell and channel, every method: the light pass's fields and σt copy and the
/// solution's first-bounce data (measured with method `none`: 58–64 bytes beside the medium
/// on the 192 × 192 × 144 and 384 × 384 × 288 clouds, the solution file streamed from them).
const LIGHT_PASS_BYTES_PER_CELL: u64 = 60;
/// Per data cell and channel, what a solve on a coarser transport grid keeps of the light
/// pass and the solution while the transport grid is solved (measured: 24–35 bytes beside the
/// medium's 8 on 192 × 192 × 144 and 384 × 384 × 288 clouds); the light pass's working
/// buffers (`LIGHT_PASS_BYTES_PER_CELL`) come and go before.
const LIGHT_PASS_KEPT_BYTES_PER_CELL: u64 = 24;
/// Exact zonal: per pair of non-empty cells — the CSR matrix (value and column index) and the
/// rows it is assembled from.
const ZONAL_BYTES_PER_PAIR: u64 = 32;
/// Hierarchical zonal: per far link ([`Occupancy::hierarchy_links`]: its stored transfer
/// both ways, and its share of the build's candidates), per entry of the near-field rows
/// stored rather than shared ([`NearRows::stored_entries`]), per non-empty cell (the
/// cluster tree, the diffusion operator), per cell of the grid, and what the build holds
/// whatever the grid. Fitted (relative least squares) to the operator's part of the peaks
/// of `benches/memory.py --only zonal-hierarchical` on 2026-12-06 — 32 × 32 × 24, 64 × 64 ×
/// 48 and 192 × 192 × 144 clouds, uniform 24³ and 40³ blocks, `data/cloud.toml`,
/// `data/fire-scattering.toml` — and Kobayashi's 60³ source in a void (1,772 MiB,
/// `examples/source_in_void.rs --case ii --method zonal-hierarchical`): within −15 … +11 %
/// of the operator, −11 … +7 % of the peak. Per non-empty cell alone (5,500 bytes, before),
/// the 192-class cloud's transport grid, whose thicker cells have 40 % fewer far links
/// than the 64 × 64 × 48 cloud's, was +39 % (+22 % of the peak).
const HIERARCHICAL_BYTES_PER_FAR_LINK: u64 = 16;
const HIERARCHICAL_NEAR_BYTES_PER_STORED_ENTRY: u64 = 6;
const HIERARCHICAL_BYTES_PER_OCCUPIED_CELL: u64 = 1_400;
const HIERARCHICAL_BYTES_PER_CELL: u64 = 300;
const HIERARCHICAL_FIXED_BYTES: u64 = 40 << 20;
/// Hierarchical zonal: each further channel builds its operator again while the allocator
/// still holds part of the last one's pages (measured: 5–30 % of the operator per channel,
/// varying from run to run; 0.25 fits the three-channel 32 × 32 × 24 cloud of
/// `benches/memory.py` and `data/fire-scattering.toml` with the operator counted by its far
/// links, 0.1 did with the operator per non-empty cell, which was larger on small clouds).
const HIERARCHICAL_FURTHER_CHANNEL_FRACTION: f64 = 0.25;
/// Discrete ordinates: per cell with medium and bin (the state: empty cells carry none), the
/// system's source and the iterate (f64, 16 bytes;
/// fitted 18 on the generated clouds of `benches/memory.py`, whose peaks vary by 10 % from
/// run to run); the iteration's vectors come on top (Gauss–Seidel's one), and a sky's
/// uncollided light. The sweeps hold one group of bins at a time (per cell, below), and the
/// solved field is let go as its f32 copy is made.
const ORDINATES_BYTES_PER_CELL_BIN: u64 = 18;
/// Discrete ordinates: per cell with medium and bin, the uncollided light of a sky (kept through the
/// solve, added to the solution after).
const ORDINATES_SKY_BYTES_PER_CELL_BIN: u64 = 8;
/// Discrete ordinates: what each further channel keeps, per non-empty cell and bin (the
/// higher orders toward each bin, f32, kept for the cells that scatter: 4 bytes, with the
/// allocator's slack the old dense field's fit had, 10 for 8) and per cell (the bins'
/// fluence and the rows' index); the solution file is streamed from them.
const ORDINATES_STORED_BYTES_PER_OCCUPIED_CELL_BIN: u64 = 5;
const ORDINATES_STORED_BYTES_PER_CELL: u64 = 8;
/// Discrete ordinates: what the allocator still holds of a channel's solve when the next
/// channel's begins, per cell with medium and bin. Fitted per cell and bin while the state
/// held every cell, between two three-channel scenes of `benches/memory.py --only
/// discrete-ordinates`: the 32 × 32 × 24 cloud (216 bins) peaked 40–75 MiB above its
/// one-channel self from run to run (4–7 bytes per cell and bin and further channel),
/// `data/cloud-sky.toml` within 2 % of the model without this term; counted per cell with
/// medium since the state is, the three-channel cloud −6 % and the cloud-sky +4 %.
const ORDINATES_FURTHER_CHANNEL_BYTES_PER_CELL_BIN: u64 = 6;
/// Discrete ordinates: per cell, the sweep's coefficient tables and one group's densities
/// and per-piece outputs.
const ORDINATES_BYTES_PER_CELL: u64 = 200;
/// Discrete ordinates: what a solve holds beyond its state and per-cell buffers, once, and
/// per transport cell and bin (empty cells too; in quarter bytes): the operator's build
/// (coefficients per distinct σt and class of pieces, the phase matrix and its gather's
/// weights) and the pages the allocator keeps of the transient buffers. Fitted when the state
/// came to hold the cells with medium alone, on `benches/memory.py --only
/// discrete-ordinates`'s clouds (24–384 bins, 32 × 32 × 24 to the 192-class transport grid)
/// and its uniform block (−12 … +13 %; without these terms −43 … −2 %).
const ORDINATES_FIXED_BYTES: u64 = 18 << 20;
const ORDINATES_QUARTER_BYTES_PER_SWEPT_CELL_BIN: u64 = 7;
/// Two-pass: per cell and direction bin, and per non-empty cell and bin. Four f64 tallies,
/// their sum and the f32 source are allocated dense (44 bytes per cell and bin), but zeroed
/// pages become resident only where photons deposit power, so the measured peak sits between
/// the non-empty and the whole grid (fitted: 28 + 11 bytes).
const TWO_PASS_BYTES_PER_CELL_BIN: u64 = 28;
const TWO_PASS_BYTES_PER_OCCUPIED_CELL_BIN: u64 = 11;
/// Two-pass: what each further channel keeps, per cell and bin (its tallied field and the
/// record's copy the solution file is written from).
const TWO_PASS_STORED_BYTES_PER_CELL_BIN: u64 = 18;

/// Vectors of the system's length an iteration keeps beside the solution and right-hand side.
/// GMRES's basis grows by one vector per iteration up to its restart length: its figure is
/// that bound, reached by a solve that runs a whole restart cycle.
/// Vectors of one per unknown a ground–medium round keeps beside the solve's own.
const GROUND_VECTORS: u64 = 4;

fn work_vectors(iteration: &solver::Method, max_iterations: usize) -> u64 {
    use solver::Method as M;
    match iteration {
        // Jacobi's next iterate; the sweeps' iterate before the sweep, then the residual.
        M::Jacobi | M::GaussSeidel | M::Sor { .. } => 1,
        M::Gmres { restart } => (*restart).min(max_iterations) as u64 + 2,
        M::BiCgStab => 6,
        M::ConjugateGradient => 3,
        M::CoarseCg | M::TwoLevelCg { .. } | M::DsaCg => 5,
        M::CoarseCorrected { .. } => 1,
    }
}

/// What the solve's size depends on, read once from the scene.
struct Sizes {
    /// The data grid's cells (the light pass, the render's first bounce).
    cells: u64,
    /// The transport grid's cells and non-empty cells (what the solve's state grows with).
    transport_cells: u64,
    transport_occupied: u64,
    /// The hierarchy's links beyond the near field, and the entries of the near-field rows
    /// it stores (one row per non-empty transport cell whose row is not shared); 0 for the
    /// other methods, which do not count them.
    transport_far_links: u64,
    transport_near_entries: u64,
    /// Data cells per side of a transport cell.
    scale: usize,
    /// Transport cells per side of a data cell.
    split: usize,
    channels: u64,
}

impl Sizes {
    fn of(scene: &Scene, settings: &SolveSettings, occupancy: &Occupancy, scale: usize) -> Sizes {
        let medium = &scene.medium;
        let split = transport_split(scene, settings);
        // A split grid has split³ transport cells per data cell.
        let parts = (split * split * split) as u64;
        let links = (settings.method == SolveMethod::ZonalHierarchical)
            .then(|| occupancy.hierarchy_links(scale, split));
        Sizes {
            cells: medium.grid().cell_count() as u64,
            transport_cells: transport_cell_count(scene, settings) as u64,
            transport_occupied: occupancy.at(scale) as u64 * parts,
            transport_far_links: links.map_or(0, |l| l.far as u64),
            transport_near_entries: links.map_or(0, |l| l.near_entries as u64),
            scale,
            split,
            channels: medium.channels().len() as u64,
        }
    }
}

/// Where a medium is non-empty (σt > 0 in any channel), to count its non-empty cells on the
/// data grid and on any transport grid: what the zonal operators and the two-pass tallies
/// grow with; and how many of them the hierarchy's shared near rows cover.
pub struct Occupancy<'a> {
    medium: &'a medium::Medium,
    occupied: Vec<bool>,
    /// What the memory check, its alternatives, the predicted time and `volrad info` all ask,
    /// counted once per transport grid: [`at`](Occupancy::at) per scale (a scan of every
    /// data cell; `volrad info --method zonal-hierarchical` on the 384-class cloud made five,
    /// 3.75–4.57 s in all, against 3.46–3.80 s with one per scale),
    /// [`hierarchy_near_rows`](Occupancy::hierarchy_near_rows) per scale and
    /// [`hierarchy_links`](Occupancy::hierarchy_links) per scale and split.
    counts: Memo<usize, usize>,
    near_rows: Memo<usize, NearRows>,
    links: Memo<(usize, usize), HierarchyLinks>,
}

/// Values computed once per key and kept.
struct Memo<K, V>(std::sync::Mutex<Vec<(K, V)>>);

impl<K: PartialEq + Copy, V: Copy> Memo<K, V> {
    fn new() -> Self {
        Memo(std::sync::Mutex::new(Vec::new()))
    }

    /// The value kept for `key`, or `make`'s, kept. (`make` may ask other memos, not this
    /// one: it runs under this one's lock.)
    fn get_or(&self, key: K, make: impl FnOnce() -> V) -> V {
        let mut known = self.0.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(&(_, value)) = known.iter().find(|(k, _)| *k == key) {
            return value;
        }
        let value = make();
        known.push((key, value));
        value
    }
}

impl<'a> Occupancy<'a> {
    pub fn of(medium: &'a medium::Medium) -> Occupancy<'a> {
        Occupancy {
            medium,
            occupied: (0..medium.grid().cell_count())
                .map(|i| medium.channels().iter().any(|c| c.sigma_t[i] > 0.0))
                .collect(),
            counts: Memo::new(),
            near_rows: Memo::new(),
            links: Memo::new(),
        }
    }

    /// The non-empty cells of the transport grid at `scale` whose near-field row the
    /// hierarchical operator shares with every cell of the same σt (their near neighbourhood
    /// is uniform: `formfactor::zonal::uniform_neighbourhoods`), the fewest over the channels.
    /// Such cells cost the operator no near-field memory and no near-field build time.
    pub fn hierarchy_shared_rows(&self, scale: usize) -> usize {
        self.hierarchy_near_rows(scale).shared
    }

    /// The hierarchy's near field on the transport grid at `scale`: the rows it shares
    /// ([`hierarchy_shared_rows`](Self::hierarchy_shared_rows)) and the entries of those it
    /// stores.
    pub fn hierarchy_near_rows(&self, scale: usize) -> NearRows {
        self.near_rows.get_or(scale, || {
            let rows = near_rows_of(self.medium, scale);
            tracing::debug!(scale, ?rows, "the hierarchy's near field, counted");
            rows
        })
    }

    /// The hierarchy's far links and stored near entries on the transport grid at `scale`
    /// with `split` transport cells per side of a data cell ([`far_links_per_occupied_cell`];
    /// a split cell is `split` times thinner).
    pub fn hierarchy_links(&self, scale: usize, split: usize) -> HierarchyLinks {
        self.links
            .get_or((scale, split), || self.hierarchy_links_of(scale, split))
    }

    /// [`hierarchy_links`](Self::hierarchy_links), counted.
    fn hierarchy_links_of(&self, scale: usize, split: usize) -> HierarchyLinks {
        let parts = split.pow(3) as f64;
        let near = self.hierarchy_near_rows(scale);
        let occupied = self.at(scale) as f64 * parts;
        let cells = Coarsening::cell_count_of(self.medium.grid(), scale) as f64 * parts;
        let fill = occupied / cells.max(1.0);
        let side = near.mean_optical_side / parts.cbrt();
        let far = occupied * far_links_per_occupied_cell(occupied, fill, side);
        let near_entries = near.stored_entries as f64 * parts;
        // `benches/far_links.py` compares these with the build's `hierarchy built` line.
        tracing::debug!(
            occupied,
            fill,
            mean_optical_side = side,
            far_links = far,
            near_entries,
            "the hierarchy's links, predicted"
        );
        HierarchyLinks { far, near_entries }
    }

    /// Non-empty cells of the transport grid at `scale` (1: the data grid's).
    pub fn at(&self, scale: usize) -> usize {
        self.counts.get_or(scale, || {
            self.on_transport_grid(scale, |i| self.occupied[i])
                .iter()
                .filter(|&&o| o)
                .count()
        })
    }

    /// The cells of the transport grid at `scale` that the discrete-ordinates scattering
    /// product multiplies each sweep ([`formfactor::ordinates::scattering_product_cells`]):
    /// those with medium of blocks that hold a scattering cell (σt > 0 and albedo > 0 in any
    /// channel).
    pub fn ordinates_product_cells(&self, scale: usize) -> usize {
        let with_medium = self.on_transport_grid(scale, |i| self.occupied[i]);
        let scatters = self.on_transport_grid(scale, |i| {
            self.medium
                .channels()
                .iter()
                .any(|c| c.sigma_t[i] > 0.0 && c.albedo.get(i) > 0.0)
        });
        formfactor::ordinates::scattering_product_cells(&with_medium, &scatters)
    }

    /// Per cell of the transport grid at `scale`: whether any of its data cells is `marked`
    /// (empty when the scale does not fit the grid).
    fn on_transport_grid(&self, scale: usize, marked: impl Fn(usize) -> bool) -> Vec<bool> {
        let n = self.medium.grid().cell_count();
        if scale == 1 {
            return (0..n).map(marked).collect();
        }
        let Ok(k) = Coarsening::new(self.medium.grid(), scale) else {
            return Vec::new();
        };
        let mut block = vec![false; k.transport().cell_count()];
        for i in (0..n).filter(|&i| marked(i)) {
            block[k.coarse_cell_of(i)] = true;
        }
        block
    }
}

/// The hierarchical operator's near field on one transport grid, counted from the medium,
/// and the optical size of its non-empty cells (what sets how far its far field's links
/// reach: the time model's far links per cell).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct NearRows {
    /// Non-empty cells whose row is shared ([`Occupancy::hierarchy_shared_rows`]).
    pub shared: usize,
    /// Entries of the rows stored one per cell: for each non-empty cell whose row is not
    /// shared, the non-empty cells within the near radius (Chebyshev), itself included.
    pub stored_entries: u64,
    /// The mean optical side `σt h` of the non-empty cells (0 when there are none).
    pub mean_optical_side: f64,
}

/// What [`Occupancy::hierarchy_links`] predicts of the hierarchical operator.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HierarchyLinks {
    /// Links beyond the near field (cluster links and leaf links).
    pub far: f64,
    /// Entries of the near rows stored one per cell.
    pub near_entries: f64,
}

/// Links of the hierarchical operator beyond the near field per non-empty cell (what its
/// memory and build time grow with, beside the stored near entries), for
/// `occupied` non-empty cells filling the share `fill` of the grid with a mean optical side
/// `side` (σt h). They grow with the log of the cells (each level of the cluster tree adds its
/// interactions) and fall as the cells grow optically thick (the transmittance between
/// clusters lets the oracle take coarser links): sparse clouds and compact blocks follow
/// different lines, blended by `fill`. Fitted to the `links_per_level` of
/// `RUST_LOG=info volrad solve`'s `hierarchy built` line on seed-2 clouds (12–14 % filled)
/// of 3 × 10³ to 2.7 × 10⁴ non-empty cells at mean sides 0.06 to 1.3 — data grids at
/// `sigma_t_scale` 0.25, 1 and 4 and the transport grids of 96-, 192- and 384-class clouds —
/// within 3 %, and to uniform 24³ and 40³ blocks; held out, a split cloud −2 % and
/// `data/cloud-large.toml` −10 % (`benches/far_links.py`; docs/performance.md, *Time*).
pub(crate) fn far_links_per_occupied_cell(occupied: f64, fill: f64, side: f64) -> f64 {
    let levels = occupied.max(2.0).log2();
    // Sparse clouds at a mean side of 0.24, scaled by how their links thin out with it.
    let thin = (side.max(1e-3) / 0.24).min(1.0).powf(-0.14);
    let thick = (side.clamp(0.24, 1.0) / 0.24).powf(-0.62);
    let sparse = (70.9 * levels - 606.4).max(30.0) * thin * thick;
    let compact = (30.2 * levels - 165.0).max(30.0);
    let fill = fill.clamp(0.0, 1.0);
    (1.0 - fill) * sparse + fill * compact
}

/// [`Occupancy::hierarchy_near_rows`], counted; of the channel that shares the fewest rows.
fn near_rows_of(medium: &medium::Medium, scale: usize) -> NearRows {
    let radius = formfactor::HierarchicalOptions::default().near.radius;
    let coarse;
    let medium = if scale > 1 {
        match Coarsening::new(medium.grid(), scale).and_then(|k| k.medium(medium)) {
            Ok(m) => {
                coarse = m;
                &coarse
            }
            Err(_) => return NearRows::default(),
        }
    } else {
        medium
    };
    let grid = medium.grid();
    medium
        .channels()
        .iter()
        .map(|c| {
            let shared = formfactor::zonal::uniform_neighbourhoods(grid, &c.sigma_t, radius);
            let occupied: Vec<bool> = c.sigma_t.iter().map(|&s| s > 0.0).collect();
            let around = cells_within(grid.dims, &occupied, radius);
            let stored_entries = (0..occupied.len())
                .filter(|&i| occupied[i] && !shared[i])
                .map(|i| u64::from(around[i]))
                .sum();
            let (sides, count) = c
                .sigma_t
                .iter()
                .filter(|&&s| s > 0.0)
                .fold((0.0, 0usize), |(sum, n), &s| (sum + s as f64, n + 1));
            NearRows {
                shared: shared.iter().filter(|&&u| u).count(),
                stored_entries,
                mean_optical_side: sides * grid.cell_size / count.max(1) as f64,
            }
        })
        .min_by_key(|r| r.shared)
        .unwrap_or_default()
}

/// Per cell, the `marked` cells within Chebyshev distance `radius` (the `(2R+1)³` block
/// clipped to the grid), itself included: box sums of a summed-volume table.
fn cells_within(dims: [usize; 3], marked: &[bool], radius: usize) -> Vec<u32> {
    let [nx, ny, nz] = dims;
    // table[(x, y, z)] = marked cells in [0, x) × [0, y) × [0, z), on (n + 1)³ corners.
    let (sx, sy) = (nx + 1, (nx + 1) * (ny + 1));
    let mut table = vec![0u32; sy * (nz + 1)];
    for z in 0..nz {
        for y in 0..ny {
            for x in 0..nx {
                let here = u32::from(marked[x + nx * (y + ny * z)]);
                let at = |dx: usize, dy: usize, dz: usize| {
                    table[(x + dx) + sx * (y + dy) + sy * (z + dz)]
                };
                let value = here + at(0, 1, 1) + at(1, 0, 1) + at(1, 1, 0)
                    - at(0, 0, 1)
                    - at(0, 1, 0)
                    - at(1, 0, 0)
                    + at(0, 0, 0);
                table[(x + 1) + sx * (y + 1) + sy * (z + 1)] = value;
            }
        }
    }
    let mut out = Vec::with_capacity(marked.len());
    for z in 0..nz {
        for y in 0..ny {
            for x in 0..nx {
                let (x0, x1) = (x.saturating_sub(radius), (x + radius + 1).min(nx));
                let (y0, y1) = (y.saturating_sub(radius), (y + radius + 1).min(ny));
                let (z0, z1) = (z.saturating_sub(radius), (z + radius + 1).min(nz));
                let t = |x: usize, y: usize, z: usize| i64::from(table[x + sx * y + sy * z]);
                let sum = t(x1, y1, z1) - t(x0, y1, z1) - t(x1, y0, z1) - t(x1, y1, z0)
                    + t(x0, y0, z1)
                    + t(x0, y1, z0)
                    + t(x1, y0, z0)
                    - t(x0, y0, z0);
                out.push(sum as u32);
            }
        }
    }
    out
}

/// Transport grids up to this many cells (64³) are solved at the data's resolution by
/// `transport_scale = "auto"`; beyond, auto takes the smallest scale that brings the transport
/// grid within it (the size class whose solves take seconds to a minute and about 1–2 GB).
pub const AUTO_TRANSPORT_CELLS: usize = 1 << 18;

/// The transport scale a solve of `scene` with `settings` uses: the scene's, or for `auto`
/// the smallest that keeps the transport grid within [`AUTO_TRANSPORT_CELLS`]; 1 for methods
/// without a transport grid and for a split one ([`transport_split`]).
pub fn transport_scale(scene: &Scene, settings: &SolveSettings) -> usize {
    if !settings.method.solves_linear_system() || transport_split(scene, settings) > 1 {
        return 1;
    }
    match settings.transport_scale {
        TransportScale::Fixed(s) => s,
        TransportScale::Auto => smallest_scale_within(scene.medium.grid(), AUTO_TRANSPORT_CELLS),
    }
}

/// The smallest coarsening scale that keeps `grid` within `cells` cells
/// ([`MAX_TRANSPORT_SCALE`] if none does).
pub fn smallest_scale_within(grid: &Grid, cells: usize) -> usize {
    (1..=MAX_TRANSPORT_SCALE)
        .find(|&s| Coarsening::cell_count_of(grid, s) <= cells)
        .unwrap_or(MAX_TRANSPORT_SCALE)
}

/// Transport cells of optical depth above this are split by `transport_refinement =
/// "auto"`: a thicker cell carries its light too deep (the cloud24 orbit at σt × 4, cells up
/// to 4, discrete ordinates with the source linear in each cell: 3.1 % per view, −1.7 … +1.1 %
/// in the image mean; split in 2³: 2.0 %, −0.6 … +1.5 %; at σt × 1, cells up to 1: 1.2 %;
/// with a flat source 6.0 %, −4.0 … +3.5 % and 2.9 %, −1.4 … +2.4 %; the zonal methods keep
/// a flat source). The same for every phase function: a strong forward peak once split
/// from 0.5 (the cloud24 orbit at g = 0.85, cells up to 0.82: 4.3 % whole, 2.8 % split),
/// but with the sweep's linear face fluxes, the bins' diffusion matched and the beams' own
/// profiles whole cells are as good (2.9 % / +0.2 … +1.8 % whole, 2.9 % / +0.4 … +1.8 %
/// split, at a seventh of the solve; docs/validation.md).
pub const AUTO_SPLIT_CELL_OPTICAL_DEPTH: f64 = 1.0;

/// The optical depth `σt h` of the thick cells of `medium`: the 99th percentile over its
/// non-empty cells, the largest over channels (a few denser cells do not set the grid).
pub fn thick_cell_optical_depth(medium: &medium::Medium) -> f64 {
    let h = medium.grid().cell_size;
    medium
        .channels()
        .iter()
        .map(|c| {
            let mut taus: Vec<f32> = c.sigma_t.iter().copied().filter(|&s| s > 0.0).collect();
            if taus.is_empty() {
                return 0.0;
            }
            let k = ((taus.len() - 1) as f64 * 0.99).round() as usize;
            let (_, tau, _) = taus.select_nth_unstable_by(k, f32::total_cmp);
            *tau as f64 * h
        })
        .fold(0.0, f64::max)
}

/// Transport cells per side of a data cell for the methods with a transport grid (1 for the
/// others): the scene's `transport_refinement`, or for `auto` the fewest that bring the
/// thick cells ([`thick_cell_optical_depth`]) to [`AUTO_SPLIT_CELL_OPTICAL_DEPTH`], as far as
/// the split grid stays within [`AUTO_TRANSPORT_CELLS`] (a grid past it is coarsened, not
/// split) and a scale above 1 is not asked for.
pub fn transport_split(scene: &Scene, settings: &SolveSettings) -> usize {
    if !settings.method.solves_linear_system() {
        return 1;
    }
    match settings.transport_refinement {
        TransportRefinement::Fixed(r) => r.max(1),
        TransportRefinement::Auto => {
            if matches!(settings.transport_scale, TransportScale::Fixed(s) if s > 1) {
                return 1;
            }
            let cells = scene.medium.grid().cell_count();
            // Only a grid that a split keeps within the size class needs the percentile
            // (this runs for every estimate; a large grid's answer is 1 without it).
            if cells.saturating_mul(8) > AUTO_TRANSPORT_CELLS {
                return 1;
            }
            let tau = thick_cell_optical_depth(&scene.medium);
            let wanted = (tau / AUTO_SPLIT_CELL_OPTICAL_DEPTH).ceil().max(1.0) as usize;
            (1..=wanted.min(MAX_TRANSPORT_SPLIT))
                .rev()
                .find(|&r| cells.saturating_mul(r * r * r) <= AUTO_TRANSPORT_CELLS)
                .unwrap_or(1)
        }
    }
}

/// The transport grid a solve of `scene` with `settings` solves multiple scattering on:
/// split ([`transport_split`]) or coarser ([`transport_scale`]) than the data grid, or the
/// data grid itself. A scale above 1 together with a split is refused.
pub fn transport_grid(scene: &Scene, settings: &SolveSettings) -> Result<Coarsening> {
    let grid = scene.medium.grid();
    if let Some(conflict) = settings.transport_conflict() {
        // A command-line override can meet a scene's fixed refinement.
        bail!("solve.transport_refinement: {conflict}");
    }
    let split = transport_split(scene, settings);
    if split > 1 {
        return Ok(Coarsening::split(grid, split)?);
    }
    Ok(Coarsening::new(grid, transport_scale(scene, settings))?)
}

/// The direction bins a discrete-ordinates solve of `scene` with `settings` sweeps: the
/// scene's, or for `auto` what [`formfactor::ordinates::auto_bin_count`] chooses for its
/// phase function on the transport grid.
pub fn direction_bins(scene: &Scene, settings: &SolveSettings) -> usize {
    settings
        .bins
        .count(&scene.medium.phase(), transport_cell_count(scene, settings))
}

/// The transport grid's cell count ([`transport_grid`]'s), without building it.
pub fn transport_cell_count(scene: &Scene, settings: &SolveSettings) -> usize {
    let grid = scene.medium.grid();
    Coarsening::cell_count_of(grid, transport_scale(scene, settings))
        * transport_split(scene, settings).pow(3)
}

/// The predicted peak resident memory of solving `scene` with `settings`; `occupancy` is
/// [`Occupancy::of`] its medium (a caller that has it passes it).
pub fn solve_peak(
    scene: &Scene,
    settings: &SolveSettings,
    occupancy: &Occupancy,
) -> MemoryEstimate {
    let scale = transport_scale(scene, settings);
    peak_of(
        &Sizes::of(scene, settings, occupancy, scale),
        scene,
        settings,
    )
}

fn peak_of(s: &Sizes, scene: &Scene, settings: &SolveSettings) -> MemoryEstimate {
    let mut parts = vec![
        MemoryPart {
            what: "the process",
            bytes: PROCESS_BYTES
                + if super::timing::measures_the_machine(settings.method) {
                    TIME_KERNEL_BYTES
                } else {
                    0
                },
        },
        MemoryPart {
            what: "the medium",
            bytes: scene.medium.memory_bytes() as u64,
        },
        MemoryPart {
            what: "the light pass",
            bytes: s
                .cells
                .saturating_mul(s.channels)
                .saturating_mul(if s.scale > 1 {
                    LIGHT_PASS_KEPT_BYTES_PER_CELL
                } else {
                    LIGHT_PASS_BYTES_PER_CELL
                }),
        },
    ];
    if s.scale > 1 || s.split > 1 {
        parts.push(MemoryPart {
            what: "the transport grid's medium and light pass",
            bytes: s
                .transport_cells
                .saturating_mul(s.channels)
                .saturating_mul(LIGHT_PASS_BYTES_PER_CELL),
        });
    }
    // Channels are solved one after the other; each keeps its solved field.
    let per_channel = |bytes: u64, stored: u64| {
        bytes.saturating_add(stored.saturating_mul(s.channels.saturating_sub(1)))
    };
    // The zonal methods' unknowns are one per cell: the solution, the right-hand side and the
    // iteration's vectors.
    let zonal_vectors = MemoryPart {
        what: "the iteration's vectors",
        bytes: per_channel(
            s.transport_cells
                .saturating_mul(8)
                .saturating_mul(2 + work_vectors(&settings.iteration, settings.max_iterations)),
            s.transport_cells.saturating_mul(8),
        ),
    };
    match settings.method {
        SolveMethod::None | SolveMethod::SingleScatter => {}
        SolveMethod::Zonal => {
            let pairs = s.transport_occupied.saturating_mul(s.transport_occupied);
            parts.push(MemoryPart {
                what: "the zonal form-factor matrix (non-empty cells squared)",
                bytes: pairs.saturating_mul(ZONAL_BYTES_PER_PAIR),
            });
            parts.push(zonal_vectors);
        }
        SolveMethod::ZonalHierarchical => {
            let operator = s
                .transport_far_links
                .saturating_mul(HIERARCHICAL_BYTES_PER_FAR_LINK)
                .saturating_add(
                    s.transport_occupied
                        .saturating_mul(HIERARCHICAL_BYTES_PER_OCCUPIED_CELL),
                )
                .saturating_add(
                    s.transport_near_entries
                        .saturating_mul(HIERARCHICAL_NEAR_BYTES_PER_STORED_ENTRY),
                )
                .saturating_add(
                    s.transport_cells
                        .saturating_mul(HIERARCHICAL_BYTES_PER_CELL),
                )
                .saturating_add(HIERARCHICAL_FIXED_BYTES);
            parts.push(MemoryPart {
                what: "the hierarchical operator (its far links and stored near rows)",
                bytes: operator,
            });
            if s.channels > 1 {
                parts.push(MemoryPart {
                    what: "the further channels' operators (pages the allocator keeps)",
                    bytes: (operator as f64
                        * HIERARCHICAL_FURTHER_CHANNEL_FRACTION
                        * (s.channels - 1) as f64) as u64,
                });
            }
            parts.push(zonal_vectors);
        }
        SolveMethod::DiscreteOrdinates => {
            let bins = direction_bins(scene, settings) as u64;
            // The state is the cells with medium alone; light crosses the empty ones in the
            // sweeps' per-cell buffers.
            let unknowns = s.transport_occupied.saturating_mul(bins);
            let swept = s.transport_cells.saturating_mul(bins);
            parts.push(MemoryPart {
                what: "the discrete-ordinates state (cells with medium × direction bins)",
                bytes: per_channel(
                    unknowns
                        .saturating_mul(ORDINATES_BYTES_PER_CELL_BIN)
                        .saturating_add(s.transport_cells.saturating_mul(ORDINATES_BYTES_PER_CELL))
                        .saturating_add(
                            swept.saturating_mul(ORDINATES_QUARTER_BYTES_PER_SWEPT_CELL_BIN) / 4,
                        )
                        .saturating_add(ORDINATES_FIXED_BYTES),
                    s.transport_occupied
                        .saturating_mul(bins)
                        .saturating_mul(ORDINATES_STORED_BYTES_PER_OCCUPIED_CELL_BIN)
                        .saturating_add(
                            unknowns.saturating_mul(ORDINATES_FURTHER_CHANNEL_BYTES_PER_CELL_BIN),
                        )
                        .saturating_add(
                            s.transport_cells
                                .saturating_mul(ORDINATES_STORED_BYTES_PER_CELL),
                        ),
                ),
            });
            if scene.environment.as_ref().is_some_and(|e| !e.is_dark()) {
                parts.push(MemoryPart {
                    what: "the sky's uncollided light (cells with medium × direction bins)",
                    bytes: unknowns.saturating_mul(ORDINATES_SKY_BYTES_PER_CELL_BIN),
                });
            }
            // The emitters' light in direction bins, kept with the solution: at most
            // `EMITTER_BINNED_CELLS` of the cells with medium per emitting channel.
            let emitting = scene
                .medium
                .channels()
                .iter()
                .filter(|c| !c.emission.is_zero())
                .count() as u64;
            if emitting > 0 {
                let cells = s
                    .transport_occupied
                    .min(crate::engine::methods::EMITTER_BINNED_CELLS as u64);
                parts.push(MemoryPart {
                    what: "the emitters' light in direction bins (the widest-lit cells)",
                    bytes: cells
                        .saturating_mul(emitting)
                        .saturating_mul(4 * crate::engine::solution::EMITTER_BIN_VALUES as u64),
                });
            }
            let vectors = work_vectors(&settings.iteration, settings.max_iterations);
            if vectors > 0 {
                parts.push(MemoryPart {
                    what: "the iteration's vectors (cells with medium × direction bins each)",
                    bytes: unknowns.saturating_mul(8).saturating_mul(vectors),
                });
            }
        }
        SolveMethod::TwoPass => {
            let bins = crate::engine::methods::two_pass_bins(&scene.medium.phase());
            let bins = (bins.n_theta * bins.n_phi) as u64;
            let tallies = s.transport_cells.saturating_mul(bins);
            let occupied = s.transport_occupied.saturating_mul(bins);
            parts.push(MemoryPart {
                what: "the two-pass tallies (cells × direction bins)",
                bytes: per_channel(
                    tallies
                        .saturating_mul(TWO_PASS_BYTES_PER_CELL_BIN)
                        .saturating_add(
                            occupied.saturating_mul(TWO_PASS_BYTES_PER_OCCUPIED_CELL_BIN),
                        ),
                    tallies.saturating_mul(TWO_PASS_STORED_BYTES_PER_CELL_BIN),
                ),
            });
        }
    }
    if let Some(ground) = &scene.ground {
        // A round keeps the last solution to start the next from, the uncollided light from
        // outside, the solution with it and the source toward the ground (one vector per
        // unknown each); the patches hold a few numbers per channel.
        let unknowns = match settings.method {
            SolveMethod::DiscreteOrdinates => s
                .transport_occupied
                .saturating_mul(direction_bins(scene, settings) as u64),
            SolveMethod::Zonal | SolveMethod::ZonalHierarchical => s.transport_cells,
            SolveMethod::None | SolveMethod::SingleScatter | SolveMethod::TwoPass => 0,
        };
        let patches =
            medium::ground::GroundPatches::covering(ground, scene.medium.grid(), &scene.lights)
                .count() as u64;
        parts.push(MemoryPart {
            what: "the ground's coupling with the medium",
            bytes: unknowns
                .saturating_mul(8 * GROUND_VECTORS)
                .saturating_add(patches.saturating_mul(s.channels).saturating_mul(24)),
        });
    }
    if s.scale > 1 {
        // The light pass's own peak on the data grid comes before the transport solve's. The
        // channels are solved one after another: the last one's pass works beside what the
        // others kept.
        let total: u64 = parts.iter().map(|p| p.bytes).sum();
        let light_pass_peak = PROCESS_BYTES
            .saturating_add(scene.medium.memory_bytes() as u64)
            .saturating_add(
                s.cells.saturating_mul(
                    LIGHT_PASS_KEPT_BYTES_PER_CELL
                        .saturating_mul(s.channels.saturating_sub(1))
                        .saturating_add(LIGHT_PASS_BYTES_PER_CELL),
                ),
            );
        if light_pass_peak > total {
            parts.push(MemoryPart {
                what: "the light pass's working buffers on the data grid",
                bytes: light_pass_peak - total,
            });
        }
    }
    MemoryEstimate { parts }
}

/// Where a memory limit comes from, for messages.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LimitSource {
    /// The machine's available memory (Linux `MemAvailable`, or the cgroup's limit).
    Available,
    /// `--max-memory` (or Python's `max_memory`).
    Given,
    /// The service's per-solve limit.
    Service,
}

/// A limit a solve must fit under.
#[derive(Clone, Copy, Debug)]
pub struct MemoryLimit {
    pub bytes: u64,
    pub source: LimitSource,
}

impl MemoryLimit {
    /// `given` when set, else what the machine has available; `None` when neither is known.
    pub fn given_or_available(given: Option<u64>) -> Option<MemoryLimit> {
        match given {
            Some(bytes) => Some(MemoryLimit {
                bytes,
                source: LimitSource::Given,
            }),
            None => medium::resources::available_memory().map(|bytes| MemoryLimit {
                bytes,
                source: LimitSource::Available,
            }),
        }
    }
}

impl fmt::Display for MemoryLimit {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let size = human_bytes(self.bytes);
        match self.source {
            LimitSource::Available => write!(f, "this machine has {size} available"),
            LimitSource::Given => write!(f, "the limit is {size} (--max-memory)"),
            LimitSource::Service => write!(f, "the server allows {size} per solve"),
        }
    }
}

/// Refuses a solve whose predicted peak exceeds `limit`, naming the largest part and the
/// settings that would fit (fewer direction bins, another method, a coarser grid).
pub fn check_solve(
    scene: &Scene,
    settings: &SolveSettings,
    limit: Option<MemoryLimit>,
) -> Result<()> {
    let Some(limit) = limit else {
        return Ok(());
    };
    check_solve_occupied(scene, settings, limit, &Occupancy::of(&scene.medium))
}

/// [`check_solve`] for a caller that has the medium's [`Occupancy`] already.
pub fn check_solve_occupied(
    scene: &Scene,
    settings: &SolveSettings,
    limit: MemoryLimit,
    occupancy: &Occupancy,
) -> Result<()> {
    let estimate = solve_peak(scene, settings, occupancy);
    if estimate.total() <= limit.bytes {
        return Ok(());
    }
    let largest = estimate.largest();
    let fits = alternatives(occupancy, scene, settings, limit.bytes);
    let advice = if fits.is_empty() {
        "nothing fits on this grid: use a coarser grid (fewer cells)".to_string()
    } else {
        format!("what would fit: {}", fits.join("; "))
    };
    bail!(
        "solve.method: `{}` needs about {} ({} alone: {}) but {limit}; {advice}",
        settings.method.name(),
        human_bytes(estimate.total()),
        largest.what,
        human_bytes(largest.bytes),
    )
}

/// Settings close to `settings` whose predicted peak fits under `limit`, spelled as a user
/// would change them.
fn alternatives(
    occupancy: &Occupancy,
    scene: &Scene,
    settings: &SolveSettings,
    limit: u64,
) -> Vec<String> {
    let mut out = Vec::new();
    let with = |f: &dyn Fn(&mut SolveSettings)| {
        let mut other = settings.clone();
        f(&mut other);
        let bytes = solve_peak(scene, &other, occupancy).total();
        (bytes <= limit).then_some(bytes)
    };
    let split = transport_split(scene, settings);
    if split > 1 {
        let finer = (1..split).rev().find_map(|r| {
            with(&|o| o.transport_refinement = TransportRefinement::Fixed(r))
                .map(|bytes| (r, bytes))
        });
        if let Some((r, bytes)) = finer {
            out.push(format!(
                "transport_refinement = {r} (about {})",
                human_bytes(bytes)
            ));
        }
    }
    if settings.method.solves_linear_system() && split == 1 {
        let scale = transport_scale(scene, settings);
        let coarser = (scale + 1..=MAX_TRANSPORT_SCALE).find_map(|k| {
            with(&|o| o.transport_scale = TransportScale::Fixed(k)).map(|bytes| (k, bytes))
        });
        if let Some((k, bytes)) = coarser {
            out.push(format!(
                "transport_scale = {k} (about {}; the first bounce stays at full resolution)",
                human_bytes(bytes)
            ));
        }
    }
    if settings.method == SolveMethod::DiscreteOrdinates {
        if !matches!(
            settings.iteration,
            solver::Method::GaussSeidel | solver::Method::Sor { .. }
        ) {
            if let Some(bytes) = with(&|o| o.iteration = solver::Method::GaussSeidel) {
                out.push(format!(
                    "iteration = \"gauss-seidel\" (about {})",
                    human_bytes(bytes)
                ));
            }
        }
        let bins = direction_bins(scene, settings);
        let fewer = formfactor::ordinates::VALID_BINS
            .iter()
            .rev()
            .copied()
            .filter(|&b| b < bins)
            .find_map(|b| with(&|o| o.bins = BinCount::Fixed(b)).map(|bytes| (b, bytes)));
        if let Some((bins, bytes)) = fewer {
            out.push(format!("bins = {bins} (about {})", human_bytes(bytes)));
        }
    }
    for method in [
        SolveMethod::ZonalHierarchical,
        SolveMethod::DiscreteOrdinates,
        SolveMethod::TwoPass,
    ] {
        if method == settings.method {
            continue;
        }
        let mut other = SolveSettings {
            method,
            iteration: method.default_iteration(),
            ..settings.clone()
        };
        if method == SolveMethod::DiscreteOrdinates {
            other.bins = BinCount::Auto;
        }
        let bytes = solve_peak(scene, &other, occupancy).total();
        if bytes <= limit {
            out.push(format!(
                "method = \"{}\" (about {})",
                method.name(),
                human_bytes(bytes)
            ));
        }
    }
    out
}

/// Refuses an image whose pixels (f32 radiance per channel, the tone-mapped copy and the
/// encoder's buffer) would not fit in the memory the machine has available — a 65536² camera
/// is a valid scene key but 48 GiB of RGB pixels.
/// `limit` as for a solve (`--max-memory`, else what is available).
pub fn check_image(
    width: u32,
    height: u32,
    channels: usize,
    limit: Option<MemoryLimit>,
) -> Result<()> {
    let pixels = u64::from(width) * u64::from(height);
    let bytes = pixels.saturating_mul(channels as u64 * 4 * 2 + 4);
    if let Some(limit) = limit {
        if bytes > limit.bytes {
            bail!(
                "camera: a {width}×{height} image needs about {} but {limit}; render a smaller image",
                human_bytes(bytes)
            );
        }
    }
    Ok(())
}

/// `1.5 GiB`, `640 MiB`.
pub fn human_bytes(bytes: u64) -> String {
    const GIB: f64 = (1u64 << 30) as f64;
    const MIB: f64 = (1u64 << 20) as f64;
    let b = bytes as f64;
    if b >= GIB {
        format!("{:.1} GiB", b / GIB)
    } else {
        format!("{:.0} MiB", (b / MIB).max(1.0))
    }
}

/// Parses a size as `--max-memory` takes it: bytes, or a number with K, M, G or T (powers of
/// 1024, an optional `iB` or `B`), e.g. `512M`, `4G`, `1.5GiB`.
pub fn parse_size(text: &str) -> Result<u64, String> {
    let t = text.trim();
    let split = t
        .find(|c: char| !(c.is_ascii_digit() || c == '.'))
        .unwrap_or(t.len());
    let (number, unit) = t.split_at(split);
    let value: f64 = number
        .parse()
        .map_err(|_| format!("`{text}`: expected a size such as 512M, 4G or 1.5GiB"))?;
    let scale: u64 = match unit.trim().to_ascii_lowercase().as_str() {
        "" | "b" => 1,
        "k" | "kb" | "kib" => 1 << 10,
        "m" | "mb" | "mib" => 1 << 20,
        "g" | "gb" | "gib" => 1 << 30,
        "t" | "tb" | "tib" => 1 << 40,
        other => {
            return Err(format!(
                "`{text}`: unknown unit `{other}` (expected K, M, G or T)"
            ))
        }
    };
    let bytes = value * scale as f64;
    if !(bytes >= 1.0 && bytes < u64::MAX as f64) {
        return Err(format!("`{text}`: expected a size of at least 1 byte"));
    }
    Ok(bytes as u64)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sizes_parse_with_binary_units_and_bad_ones_are_refused() {
        assert_eq!(parse_size("4096"), Ok(4096));
        assert_eq!(parse_size("512M"), Ok(512 << 20));
        assert_eq!(parse_size("4G"), Ok(4 << 30));
        assert_eq!(parse_size("1.5GiB"), Ok(3 << 29));
        assert_eq!(parse_size(" 2 t "), Ok(2 << 40));
        for bad in ["", "G", "lots", "4X", "0", "-1G", "1e30T"] {
            assert!(parse_size(bad).is_err(), "{bad}");
        }
    }

    #[test]
    fn the_prediction_grows_with_what_each_method_stores() {
        let scene = |method: &str, bins: usize, dims: usize| {
            let text = format!(
                "[volume]\ngenerator = {{ kind = \"cloud\", seed = 1 }}\ndims = [{dims}, {dims}, {dims}]\n\
                 [medium]\nalbedo = 0.9\nphase = {{ kind = \"henyey-greenstein\", g = 0.6 }}\n\
                 [[light]]\nkind = \"directional\"\ndirection = [0, 0, -1]\nirradiance = 1.0\n\
                 [solve]\nmethod = \"{method}\"\nbins = {bins}\n"
            );
            Scene::from_toml_str(&text, std::path::Path::new("."), std::path::Path::new("t"))
                .unwrap()
        };
        let peak = |s: &Scene| solve_peak(s, &s.solve, &Occupancy::of(&s.medium)).total();
        let small = scene("discrete-ordinates", 24, 16);
        let more_bins = scene("discrete-ordinates", 384, 16);
        let more_cells = scene("discrete-ordinates", 24, 32);
        let state = |s: &Scene| {
            let estimate = solve_peak(s, &s.solve, &Occupancy::of(&s.medium));
            estimate.total() - estimate.parts()[0].bytes
        };
        // The state is the cells with medium × bins, at least the source and the iterate (f64
        // each): 16× the bins add that much per cell with medium, and less than a state of
        // every cell would (the empty cells are 88 % of the cloud's).
        let cells = small.medium.grid().cell_count() as u64;
        let with_medium = Occupancy::of(&small.medium).at(1) as u64;
        assert!(with_medium > 0 && with_medium < cells / 4);
        let added = state(&more_bins) - state(&small);
        let (cell_bins, every_cell_bin) = (with_medium * (384 - 24), cells * (384 - 24));
        assert!(
            (16 * cell_bins..16 * every_cell_bin).contains(&added),
            "{added} bytes for {cell_bins} cell-bins with medium"
        );
        // 8× the cells: at least the state of the cells with medium they add.
        let more_medium = Occupancy::of(&more_cells.medium).at(1) as u64 - with_medium;
        assert!(more_medium > 6 * with_medium);
        assert!(state(&more_cells) - state(&small) > 16 * 24 * more_medium);
        // Exact zonal grows with the square of the non-empty cells.
        let z16 = scene("zonal", 24, 16);
        let z32 = scene("zonal", 24, 32);
        assert!(state(&z32) > 30 * state(&z16));
        // A solve that fits is not refused; one over the limit is, naming the cause.
        let limit = |bytes| {
            Some(MemoryLimit {
                bytes,
                source: LimitSource::Given,
            })
        };
        // (On 32³ cells, where the state is more than the process.)
        let big = scene("discrete-ordinates", 384, 32);
        assert!(check_solve(&big, &big.solve, limit(peak(&big))).is_ok());
        let err = check_solve(&big, &big.solve, limit(peak(&more_cells)))
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("direction bins") && err.contains("bins = 24"),
            "{err}"
        );
    }

    #[test]
    fn the_near_fields_neighbours_are_counted_as_a_walk_over_each_block_counts_them() {
        let dims = [7, 5, 6];
        let n = dims[0] * dims[1] * dims[2];
        // A scattered pattern, not symmetric in any axis.
        let marked: Vec<bool> = (0..n).map(|i| (i * 7 + i / 9) % 5 < 2).collect();
        for radius in [0, 1, 2, 4] {
            let fast = cells_within(dims, &marked, radius);
            for (i, &count) in fast.iter().enumerate() {
                let c = [
                    i % dims[0],
                    (i / dims[0]) % dims[1],
                    i / (dims[0] * dims[1]),
                ];
                let mut walked = 0;
                for (j, &m) in marked.iter().enumerate() {
                    let d = [
                        j % dims[0],
                        (j / dims[0]) % dims[1],
                        j / (dims[0] * dims[1]),
                    ];
                    if m && (0..3).all(|a| c[a].abs_diff(d[a]) <= radius) {
                        walked += 1;
                    }
                }
                assert_eq!(count, walked, "cell {c:?}, radius {radius}");
            }
        }
    }
}
