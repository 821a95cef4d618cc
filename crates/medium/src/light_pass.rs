//! The light pass (Kajiya & Von Herzen's first pass): each light's irradiance times its
//! transmittance `T_L` through the grid, as exact-bookkeeping cell averages (the source term
//! `E` of every multiple-scattering solve) and as per-corner transmittance (for renders).
//!
//! Cell averages come from a dense lattice of rays that tile the light's beam exactly: for a
//! directional light, `m × m` parallel rays per cell on every grid face the light enters
//! through, each carrying the power of its tube `E0 |d·n| δ²`; for point and spot lights, rays
//! through the pixels of a cube map around the light, each carrying `I·Ω_pixel` (exact pixel
//! solid angles). Each ray deposits the exact per-segment integral `T_enter (1 − e^{−σt ℓ})/σt`
//! into the cells it crosses, so the power extinguished along a ray is exactly what it loses:
//! power entering = Σ extinguished + power leaving, to rounding. With light along a grid axis
//! one ray per cell (`m = 1`) already gives the exact cell average; oblique light converges as
//! `O(1/m²)` (errors come only from ray tubes straddling cell edges).
//!
//! A directional light is one sweep through the layers perpendicular to the dominant axis of
//! its direction. Rays that are whole-cell lateral translates of one another (a family: one
//! per sub-cell offset on the entry face; one per sub-cell offset and layer on each side face)
//! cross every layer at the same sub-cell position, so the split of a layer crossing among at
//! most three cells is computed once per family and layer and applied to whole rows of rays
//! (vectorised; the exponential only where σt > 0). Families run in parallel.
//!
//! Corner optical depth is exact. For a directional light the backward rays from all corners
//! of a plane cross each layer at the same sub-cell position too, so each plane is a sum of
//! shared pieces `ℓ σt` over rows of corners; for point and spot lights, one backward ray per
//! corner. (Interpolating each plane's depths from the previous plane would be cheaper but
//! blurs shadow edges.) Inside a cell, [`LightPass::transmittance_at`] continues the corner
//! field with the exact exponential:
//! `T_L(x) = T(exit point, bilinear on that face's corners) · e^{−σt d}`.

use std::f64::consts::PI;
use std::sync::Arc;

use glam::DVec3;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::fma::mul_add;
use crate::traversal::Ray;
use crate::{ChannelMedium, Grid, Light, Medium, MediumError};

/// Most lights one light pass takes: each costs a sweep through the grid and its own
/// stored fields (a scene's `[[light]]` count is bounded by it).
pub const MAX_LIGHTS: usize = 1024;

/// Tuning of the light pass.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct LightPassOptions {
    /// Rays per cell side (`m`): a directional light sends `m²` rays per cell of each face it
    /// enters through (1 is exact for axis-aligned light); point lights aim for rays `h/2m`
    /// apart at the far side of the grid.
    pub rays_per_cell: usize,
    /// Largest cube-map face resolution for point and spot lights (bounds their cost).
    pub max_cube_resolution: usize,
}

impl Default for LightPassOptions {
    fn default() -> Self {
        LightPassOptions {
            rays_per_cell: 4,
            max_cube_resolution: 1024,
        }
    }
}

/// Power bookkeeping of one light (in the units of irradiance × area).
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct LightEnergy {
    /// Power entering the grid (for a light inside the grid: all the power it emits).
    pub entering: f64,
    /// Power extinguished in the grid, `Σ σt_i V cell_irradiance_i`.
    pub extinguished: f64,
    /// Power leaving the grid unextinguished.
    pub leaving: f64,
}

impl LightEnergy {
    /// `|entering − extinguished − leaving| / entering` (0 when nothing enters).
    pub fn relative_imbalance(&self) -> f64 {
        if self.entering == 0.0 {
            return 0.0;
        }
        (self.entering - self.extinguished - self.leaving).abs() / self.entering
    }
}

/// One light's result.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct LightField {
    pub light: Light,
    /// `(1/V) ∫_{V_i} E_light(x) T_L(x) dx` per cell (irradiance on a plane perpendicular to
    /// the flow, times transmittance). The power extinguished in cell `i` is
    /// `σt_i V cell_irradiance_i`.
    pub cell_irradiance: Vec<f32>,
    /// Optical depth toward the light, `τ = −ln T_L`, at every cell corner, indexed by
    /// [`Grid::corner_index`] (no `1/r²`, no cone). Stored as depth, not transmittance, because
    /// renders interpolate it across cell faces: τ varies about linearly there while `T_L`
    /// varies exponentially, and linear interpolation of `T_L` overestimates it. Shared: a
    /// render's light-depth lattice reads the same array (a copy is 171 MB on a 384-class
    /// cloud).
    pub corner_optical_depth: Arc<Vec<f32>>,
    pub energy: LightEnergy,
}

/// The light pass for one colour channel: one [`LightField`] per light, in the scene's order.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct LightPass {
    pub grid: Grid,
    /// The channel's σt, kept to continue `T_L` inside cells.
    pub sigma_t: Vec<f32>,
    pub fields: Vec<LightField>,
}

/// `∫_0^ℓ e^{−σ s} ds` and `1 − e^{−σℓ}` (interception) from one `exp_m1`.
#[inline]
fn segment_integrals(sigma: f64, length: f64) -> (f64, f64) {
    let tau = sigma * length;
    if tau < 1e-12 {
        (length * (1.0 - 0.5 * tau), tau)
    } else {
        let intercepted = -(-tau).exp_m1();
        (intercepted / sigma, intercepted)
    }
}

/// Accumulator of one batch of rays: per-cell `∫ E T dx` (times V) and the power balance.
struct Deposit {
    cell_integral: Vec<f64>,
    entering: f64,
    leaving: f64,
}

impl Deposit {
    fn new(cells: usize) -> Self {
        Deposit {
            cell_integral: vec![0.0; cells],
            entering: 0.0,
            leaving: 0.0,
        }
    }

    /// Follows one ray tube of `power` through the grid from `t = 0`.
    #[inline]
    fn trace(&mut self, grid: &Grid, sigma_t: &[f32], ray: &Ray, power: f64) {
        if grid.clip(ray, 0.0, f64::INFINITY).is_none() {
            return;
        }
        self.entering += power;
        let mut transmittance = power;
        for seg in grid.traverse(ray, 0.0, f64::INFINITY) {
            let len = seg.length();
            if len <= 0.0 {
                continue;
            }
            let sigma = sigma_t[seg.cell] as f64;
            let (integral, intercepted) = segment_integrals(sigma, len);
            self.cell_integral[seg.cell] += transmittance * integral;
            transmittance -= transmittance * intercepted;
        }
        self.leaving += transmittance;
    }

    fn merge(mut self, other: Deposit) -> Deposit {
        for (a, b) in self.cell_integral.iter_mut().zip(&other.cell_integral) {
            *a += b;
        }
        self.entering += other.entering;
        self.leaving += other.leaving;
        self
    }
}

/// Runs `work(batch, deposit)` for batches `0..batches` in a fixed number of parallel
/// chunks, summed in a fixed order (deterministic on a given machine).
fn deposit_parallel(
    cells: usize,
    batches: usize,
    work: impl Fn(usize, &mut Deposit) + Sync,
) -> Deposit {
    let chunks = rayon::current_num_threads().max(4).min(batches.max(1));
    let per_chunk = batches.div_ceil(chunks);
    let parts: Vec<Deposit> = (0..chunks)
        .into_par_iter()
        .map(|c| {
            let mut dep = Deposit::new(cells);
            for b in (c * per_chunk)..((c + 1) * per_chunk).min(batches) {
                work(b, &mut dep);
            }
            dep
        })
        .collect();
    parts
        .into_iter()
        .reduce(Deposit::merge)
        .unwrap_or_else(|| Deposit::new(cells))
}

/// Interception `1 − e^{−x}` for `x ≥ 0`, to a relative 1e-9 also for small `x` (the ray
/// loses exactly what the cell is credited, whatever this error). Branch-free so that loops
/// over rays vectorise: `e^{−x} = 2^k e^r` with `|r| ≤ ln2/2` (magic-number rounding for
/// `k`), `e^r − 1 = r Σ_{n<8} r^n/(n+1)!` (Estrin's scheme: a short dependency chain), and
/// `1 − e^{−x} = (1 − 2^k) − 2^k (e^r − 1)`, exact in the series when `k = 0`. `x` is capped
/// at 700, where `e^{−x}` no longer matters.
/// (Not the renders' table `exp` of gather's exponential.rs: `1 − e^{−x}` from it would
/// lose the digits of thin cells, and its table load and range branch keep loops scalar.)
#[inline(always)]
fn interception<const FMA: bool>(x: f64) -> f64 {
    const MAGIC: f64 = 6_755_399_441_055_744.0; // 1.5 · 2^52
    let y = -x.min(700.0);
    let shifted = mul_add::<FMA>(y, std::f64::consts::LOG2_E, MAGIC);
    let k = shifted - MAGIC;
    let r = mul_add::<FMA>(-k, std::f64::consts::LN_2, y);
    let (r2, r4) = (r * r, (r * r) * (r * r));
    let c01 = mul_add::<FMA>(r, 0.5, 1.0);
    let c23 = mul_add::<FMA>(r, 1.0 / 24.0, 1.0 / 6.0);
    let c45 = mul_add::<FMA>(r, 1.0 / 720.0, 1.0 / 120.0);
    let c67 = mul_add::<FMA>(r, 1.0 / 40320.0, 1.0 / 5040.0);
    let low = mul_add::<FMA>(c23, r2, c01);
    let high = mul_add::<FMA>(c67, r2, c45);
    let r_expm1 = r * mul_add::<FMA>(high, r4, low);
    // The low mantissa bits of `shifted` hold k (two's complement): k + 1023 into the exponent.
    let two_k = f64::from_bits(shifted.to_bits().wrapping_add(1023) << 52);
    mul_add::<FMA>(-two_k, r_expm1, 1.0 - two_k)
}

/// The frame of a directional light's layer sweep: layers `l = 0..na` perpendicular to the
/// dominant axis of the light direction, in the order the light crosses them; lateral
/// coordinates `(u, v)` oriented so the light moves by `shift ≥ 0` cells per layer. Arrays in
/// this frame are laid out `u + nu (v + nv l)` (u contiguous).
#[derive(Clone, Copy, Debug)]
struct SweepFrame {
    /// Grid axes of `(u, v, l)`.
    axes: [usize; 3],
    /// `(nu, nv, na)`.
    n: [usize; 3],
    /// Per frame axis: the frame coordinate runs against the grid index.
    flipped: [bool; 3],
    /// Lateral cells moved per layer, `|d_u/d_a|`, `|d_v/d_a|`, both in `[0, 1]`.
    shift: [f64; 2],
    /// Path length through one layer, `h / |d_a|`.
    layer_length: f64,
}

impl SweepFrame {
    fn new(grid: &Grid, direction: DVec3) -> SweepFrame {
        let a = (0..3)
            .max_by(|&x, &y| direction[x].abs().total_cmp(&direction[y].abs()))
            .unwrap_or(2);
        let (p, q) = ((a + 1) % 3, (a + 2) % 3);
        // The lateral axis with the smaller memory stride is contiguous.
        let (u, v) = if p < q { (p, q) } else { (q, p) };
        let axes = [u, v, a];
        let da = direction[a].abs();
        SweepFrame {
            axes,
            n: axes.map(|x| grid.dims[x]),
            // `-0.0 < 0.0` is false: an axis the light does not move along is never flipped.
            flipped: axes.map(|x| direction[x] < 0.0),
            shift: [direction[u].abs() / da, direction[v].abs() / da],
            layer_length: grid.cell_size / da,
        }
    }

    /// The same sweep with u and v exchanged (v contiguous).
    fn transposed(&self) -> SweepFrame {
        SweepFrame {
            axes: [self.axes[1], self.axes[0], self.axes[2]],
            n: [self.n[1], self.n[0], self.n[2]],
            flipped: [self.flipped[1], self.flipped[0], self.flipped[2]],
            shift: [self.shift[1], self.shift[0]],
            layer_length: self.layer_length,
        }
    }

    fn cell_count(&self) -> usize {
        self.n[0] * self.n[1] * self.n[2]
    }

    /// Calls `visit(frame_index, grid_index)` for every cell.
    fn for_each_cell(&self, grid: &Grid, visit: impl FnMut(usize, usize)) {
        let [nx, ny, _] = grid.dims;
        self.walk(self.n, [1, nx, nx * ny], visit);
    }

    /// Calls `visit(frame_index, grid_corner_index)` for every corner (frame corners laid out
    /// `u + (nu + 1) (v + (nv + 1) plane)`, plane 0 where the light enters).
    fn for_each_corner(&self, grid: &Grid, visit: impl FnMut(usize, usize)) {
        let [nx, ny, _] = grid.dims;
        self.walk(
            self.n.map(|n| n + 1),
            [1, nx + 1, (nx + 1) * (ny + 1)],
            visit,
        );
    }

    /// `counts` points per frame axis, `strides` per grid axis.
    fn walk(&self, counts: [usize; 3], strides: [usize; 3], mut visit: impl FnMut(usize, usize)) {
        // Grid index of frame point (0, 0, 0) and the signed grid step per frame axis.
        let mut origin = 0isize;
        let mut step = [0isize; 3];
        for f in 0..3 {
            let stride = strides[self.axes[f]] as isize;
            if self.flipped[f] {
                origin += (counts[f] as isize - 1) * stride;
                step[f] = -stride;
            } else {
                step[f] = stride;
            }
        }
        let mut frame_index = 0;
        for l in 0..counts[2] as isize {
            for v in 0..counts[1] as isize {
                let row = origin + l * step[2] + v * step[1];
                for u in 0..counts[0] as isize {
                    visit(frame_index, (row + u * step[0]) as usize);
                    frame_index += 1;
                }
            }
        }
    }
}

/// σt laid out in a sweep frame, and `1/σt` (0 where σt = 0) so that deposits multiply
/// instead of divide (f32: the cell averages are stored as f32 anyway).
/// Also, per row of cells along u, the span `[first, last + 1)` of cells with σt > 0
/// (`[0, 0)` when none): outside it rays only deposit, and clouds are mostly empty.
struct FrameMedium {
    frame: SweepFrame,
    sigma: Vec<f32>,
    inv_sigma: Vec<f32>,
    spans: Vec<[usize; 2]>,
}

/// The span of non-zero values in each row of `nu` values.
fn nonzero_spans(values: &[f32], nu: usize) -> Vec<[usize; 2]> {
    values
        .chunks_exact(nu)
        .map(|row| match row.iter().position(|&s| s > 0.0) {
            None => [0, 0],
            Some(first) => [
                first,
                nu - row.iter().rev().position(|&s| s > 0.0).unwrap_or(0),
            ],
        })
        .collect()
}

impl FrameMedium {
    fn new(grid: &Grid, sigma_t: &[f32], direction: DVec3) -> FrameMedium {
        let frame = SweepFrame::new(grid, direction);
        let mut sigma = vec![0.0f32; frame.cell_count()];
        frame.for_each_cell(grid, |f, g| sigma[f] = sigma_t[g]);
        let inv_sigma = sigma
            .iter()
            .map(|&s| if s > 0.0 { 1.0 / s } else { 0.0 })
            .collect();
        FrameMedium {
            frame,
            spans: nonzero_spans(&sigma, frame.n[0]),
            sigma,
            inv_sigma,
        }
    }

    /// The same medium in the transposed frame (v contiguous).
    fn transposed(&self) -> FrameMedium {
        let [nu, nv, _] = self.frame.n;
        let transpose = |values: &[f32]| {
            let mut out = vec![0.0f32; values.len()];
            for (dst, src) in out
                .chunks_exact_mut(nu * nv)
                .zip(values.chunks_exact(nu * nv))
            {
                for v in 0..nv {
                    for u in 0..nu {
                        dst[v + nv * u] = src[u + nu * v];
                    }
                }
            }
            out
        };
        let sigma = transpose(&self.sigma);
        FrameMedium {
            frame: self.frame.transposed(),
            spans: nonzero_spans(&sigma, nv),
            sigma,
            inv_sigma: transpose(&self.inv_sigma),
        }
    }
}

/// A family of parallel rays that are whole-cell lateral translates of one another: they
/// share their sub-cell position in every layer, hence the split of each layer crossing
/// among cells, computed once per layer for the whole family.
#[derive(Clone, Copy, Debug)]
struct RayFamily {
    /// Which frame the family is swept in (0: u contiguous, 1: transposed).
    frame: usize,
    /// The first layer the family crosses.
    first_layer: usize,
    /// Lateral position (cells) of ray `(0, 0)` on the plane where `first_layer` begins. A
    /// ray entering through a side face starts there outside the grid (negative
    /// coordinate); cells outside are skipped, so it is attenuated from its entry point on.
    start: [f64; 2],
    /// Rays along u and v: ray `(i, j)` starts at `start + (i, j)`.
    count: [usize; 2],
    /// Power of each ray's tube.
    power: f64,
}

/// One piece of a layer crossing inside one cell: cell offset from the cell the ray starts
/// the layer in, and the path length.
#[derive(Clone, Copy, Debug, Default)]
struct Piece {
    offset: [i64; 2],
    length: f64,
}

/// Splits the crossing of one layer by a ray at lateral fraction `frac` (in `[0, 1)²`,
/// moving by `shift` per layer, either sign) into at most three pieces.
#[inline(always)]
fn layer_pieces(frac: [f64; 2], shift: [f64; 2], layer_length: f64) -> ([Piece; 3], usize) {
    // Fractions of the layer where the ray crosses a lateral cell boundary.
    let mut breaks = [1.0f64; 2];
    for x in 0..2 {
        let end = frac[x] + shift[x];
        if shift[x] > 0.0 && end > 1.0 {
            breaks[x] = (1.0 - frac[x]) / shift[x];
        } else if shift[x] < 0.0 && end < 0.0 && frac[x] > 0.0 {
            breaks[x] = frac[x] / -shift[x];
        }
    }
    if breaks[1] < breaks[0] {
        breaks.swap(0, 1);
    }
    let bounds = [0.0, breaks[0], breaks[1], 1.0];
    let mut pieces = [Piece::default(); 3];
    let mut count = 0;
    for w in bounds.windows(2) {
        if w[1] > w[0] {
            let t = 0.5 * (w[0] + w[1]);
            pieces[count] = Piece {
                offset: [
                    (frac[0] + t * shift[0]).floor() as i64,
                    (frac[1] + t * shift[1]).floor() as i64,
                ],
                length: (w[1] - w[0]) * layer_length,
            };
            count += 1;
        }
    }
    (pieces, count)
}

/// Sweeps one family through its layers, depositing `∫ T ds` into `cell_integral` (frame
/// layout); returns the power the family carries out of the grid.
#[inline(always)]
fn sweep_family_body<const FMA: bool>(
    medium: &FrameMedium,
    family: &RayFamily,
    transmitted: &mut Vec<f64>,
    cell_integral: &mut [f64],
) -> f64 {
    let frame = &medium.frame;
    let [nu, nv, na] = frame.n;
    let [cu, cv] = family.count;
    transmitted.clear();
    transmitted.resize(cu * cv, family.power);
    for layer in family.first_layer..na {
        let travelled = (layer - family.first_layer) as f64;
        let pos = [
            family.start[0] + travelled * frame.shift[0],
            family.start[1] + travelled * frame.shift[1],
        ];
        let base = [pos[0].floor(), pos[1].floor()];
        if base[0] >= nu as f64 || base[1] >= nv as f64 {
            break; // every ray has left through a side face
        }
        let (pieces, count) = layer_pieces(
            [pos[0] - base[0], pos[1] - base[1]],
            frame.shift,
            frame.layer_length,
        );
        let layer_base = nu * nv * layer;
        for piece in &pieces[..count] {
            // Ray (i, j) is in frame cell (i + ou, j + ov) of this layer.
            let ou = base[0] as i64 + piece.offset[0];
            let ov = base[1] as i64 + piece.offset[1];
            let i_lo = (-ou).max(0) as usize;
            let i_hi = (nu as i64 - ou).clamp(0, cu as i64) as usize;
            let j_lo = (-ov).max(0) as usize;
            let j_hi = (nv as i64 - ov).clamp(0, cv as i64) as usize;
            if i_lo >= i_hi {
                continue;
            }
            let length = piece.length;
            for j in j_lo..j_hi {
                let v = (j as i64 + ov) as usize;
                let row = layer_base + nu * v;
                // Cells u_lo..u_hi of this row; only those within the σt > 0 span attenuate.
                let (u_lo, u_hi) = ((i_lo as i64 + ou) as usize, (i_hi as i64 + ou) as usize);
                let [first, end] = medium.spans[nv * layer + v];
                let first = first.clamp(u_lo, u_hi);
                let end = end.clamp(first, u_hi);
                let rays = &mut transmitted[cu * j + i_lo..cu * j + i_hi];
                let (before, rest) = rays.split_at_mut(first - u_lo);
                let (inside, after) = rest.split_at_mut(end - first);
                let integral = &mut cell_integral[row..row + nu];
                let (integral_before, integral_rest) =
                    integral[u_lo..u_hi].split_at_mut(first - u_lo);
                let (integral_inside, integral_after) = integral_rest.split_at_mut(end - first);
                for (rays, integral) in [(before, integral_before), (after, integral_after)] {
                    for (t, c) in rays.iter().zip(integral.iter_mut()) {
                        *c = mul_add::<FMA>(*t, length, *c);
                    }
                }
                let sigma = &medium.sigma[row + first..row + end];
                let inv_sigma = &medium.inv_sigma[row + first..row + end];
                for (((t, &s), &inv), c) in inside
                    .iter_mut()
                    .zip(sigma)
                    .zip(inv_sigma)
                    .zip(integral_inside.iter_mut())
                {
                    // Exact per-cell bookkeeping: what the ray loses, the cell extinguishes.
                    let intercepted = interception::<FMA>(s as f64 * length);
                    let per_sigma = if s > 0.0 {
                        intercepted * inv as f64
                    } else {
                        length
                    };
                    *c = mul_add::<FMA>(*t, per_sigma, *c);
                    *t = mul_add::<FMA>(-*t, intercepted, *t);
                }
            }
        }
    }
    transmitted.iter().sum()
}

/// [`sweep_family_body`] compiled for AVX2 and FMA (four rays per instruction).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
fn sweep_family_avx2(
    medium: &FrameMedium,
    family: &RayFamily,
    transmitted: &mut Vec<f64>,
    cell_integral: &mut [f64],
) -> f64 {
    sweep_family_body::<true>(medium, family, transmitted, cell_integral)
}

/// [`sweep_family_body`], on AVX2 and FMA when the CPU has them (results then differ from
/// the portable build's in the last bits only; each is deterministic).
fn sweep_family(
    medium: &FrameMedium,
    family: &RayFamily,
    transmitted: &mut Vec<f64>,
    cell_integral: &mut [f64],
) -> f64 {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma") {
        // SAFETY: the CPU supports AVX2 and FMA, checked on the line above.
        return unsafe { sweep_family_avx2(medium, family, transmitted, cell_integral) };
    }
    sweep_family_body::<false>(medium, family, transmitted, cell_integral)
}

/// Directional light: `m × m` rays per cell on each face the light enters through (tubes of
/// power `E0 |d·n| δ²` that tile the beam exactly), swept layer by layer along the dominant
/// axis in families that share each layer's split among cells. The families entering through
/// the face along u run in a transposed frame, so that every family's rays are contiguous.
fn directional_deposit(
    grid: &Grid,
    medium: &FrameMedium,
    direction: DVec3,
    irradiance: f64,
    m: usize,
) -> Deposit {
    let frame = medium.frame;
    let transposed = medium.transposed();
    let media = [medium, &transposed];
    let [nu, nv, na] = frame.n;
    let delta = grid.cell_size / m as f64;
    let tube = irradiance * delta * delta;
    let [du, dv, da] = frame.axes.map(|x| direction[x].abs());
    let sub = |p: usize| (p as f64 + 0.5) / m as f64;
    let mut families = Vec::with_capacity(m * m * (1 + 2 * na));
    // The entry face perpendicular to the sweep: m² families of nu × nv rays.
    for q in 0..m {
        for p in 0..m {
            families.push(RayFamily {
                frame: 0,
                first_layer: 0,
                start: [sub(p), sub(q)],
                count: [nu, nv],
                power: tube * da,
            });
        }
    }
    // Side faces: a ray entering at depth `l + sub(r)` starts on layer l's plane outside the
    // grid, `sub(r) · shift` before the face.
    for layer in 0..na {
        for r in 0..m {
            let back = sub(r);
            for p in 0..m {
                if dv > 0.0 {
                    families.push(RayFamily {
                        frame: 0,
                        first_layer: layer,
                        start: [sub(p) - back * frame.shift[0], -back * frame.shift[1]],
                        count: [nu, 1],
                        power: tube * dv,
                    });
                }
                if du > 0.0 {
                    families.push(RayFamily {
                        frame: 1,
                        first_layer: layer,
                        start: [sub(p) - back * frame.shift[1], -back * frame.shift[0]],
                        count: [nv, 1],
                        power: tube * du,
                    });
                }
            }
        }
    }
    // Families interleaved over one chunk per thread (the entry face's large families spread
    // evenly; each chunk holds two grid-sized sums, so no more chunks than threads), summed
    // in a fixed order: deterministic for a given thread count.
    let chunks = rayon::current_num_threads().clamp(1, families.len());
    let mut parts: Vec<([Vec<f64>; 2], f64, f64)> = (0..chunks)
        .into_par_iter()
        .map(|c| {
            let mut integrals = [0, 1].map(|_| vec![0.0f64; frame.cell_count()]);
            let mut transmitted = Vec::with_capacity(nu * nv);
            let (mut entering, mut leaving) = (0.0, 0.0);
            for family in families.iter().skip(c).step_by(chunks) {
                entering += family.power * (family.count[0] * family.count[1]) as f64;
                leaving += sweep_family(
                    media[family.frame],
                    family,
                    &mut transmitted,
                    &mut integrals[family.frame],
                );
            }
            (integrals, entering, leaving)
        })
        .collect();
    let mut dep = Deposit::new(grid.cell_count());
    let (mut totals, entering, leaving) = parts.swap_remove(0);
    (dep.entering, dep.leaving) = (entering, leaving);
    for (integrals, entering, leaving) in parts {
        for (total, part) in totals.iter_mut().zip(&integrals) {
            for (t, v) in total.iter_mut().zip(part) {
                *t += v;
            }
        }
        dep.entering += entering;
        dep.leaving += leaving;
    }
    // The transposed frame's sums into the first frame (layer by layer, cache-resident),
    // then one pass to grid order.
    let [main, side] = &mut totals;
    for (dst, src) in main
        .chunks_exact_mut(nu * nv)
        .zip(side.chunks_exact(nu * nv))
    {
        for v in 0..nv {
            for u in 0..nu {
                dst[u + nu * v] += src[v + nv * u];
            }
        }
    }
    frame.for_each_cell(grid, |f, g| dep.cell_integral[g] = main[f]);
    dep
}

/// Cell averages `⟨T⟩_i` of the transmittance from the grid's edge along unit `direction`
/// (the direction light travels): the light pass of a directional light of unit irradiance,
/// with `rays_per_cell²` rays per cell face (one for an axis-aligned direction, which is
/// exact). An environment's uncollided radiance in a cell is its radiance times this.
pub fn directional_cell_transmittance(
    grid: &Grid,
    sigma_t: &[f32],
    direction: DVec3,
    rays_per_cell: usize,
) -> Result<Vec<f64>, MediumError> {
    if sigma_t.len() != grid.cell_count() {
        return Err(MediumError::invalid(
            "transmittance pass",
            format!(
                "{} σt values for {} cells",
                sigma_t.len(),
                grid.cell_count()
            ),
        ));
    }
    let length = direction.length();
    if !(length.is_finite() && length > 1e-12) {
        return Err(MediumError::invalid(
            "transmittance pass",
            format!("direction {direction:?} has no direction"),
        ));
    }
    let direction = direction / length;
    let axis_aligned = (0..3).filter(|&a| direction[a] != 0.0).count() == 1;
    let m = if axis_aligned {
        1
    } else {
        rays_per_cell.max(1)
    };
    let medium = FrameMedium::new(grid, sigma_t, direction);
    let volume = grid.cell_volume();
    let mut deposit = directional_deposit(grid, &medium, direction, 1.0, m);
    for v in &mut deposit.cell_integral {
        *v /= volume;
    }
    Ok(deposit.cell_integral)
}

/// `∫∫ dx dy / (1 + x² + y²)^{3/2}` primitive: the solid angle of `[0,x]×[0,y]` on the
/// plane at unit distance.
#[inline]
fn rect_solid_angle(x: f64, y: f64) -> f64 {
    (x * y / (1.0 + x * x + y * y).sqrt()).atan()
}

/// Point or spot light: one ray per pixel of an `n × n` cube map around `position`.
fn point_deposit(
    grid: &Grid,
    sigma_t: &[f32],
    position: DVec3,
    intensity: f64,
    cone: Option<(DVec3, f64)>,
    options: &LightPassOptions,
) -> Deposit {
    let ext = grid.extent();
    let r_max = (0..8)
        .map(|k| {
            let corner = DVec3::new(
                if k & 1 == 0 { 0.0 } else { ext.x },
                if k & 2 == 0 { 0.0 } else { ext.y },
                if k & 4 == 0 { 0.0 } else { ext.z },
            );
            (corner - position).length()
        })
        .fold(0.0, f64::max);
    // Pixel angular size ≤ 2/n; aim for rays h/(2m) apart at r_max (diverging rays are
    // sparsest there; point lights are rare and cheap next to their corner rays).
    let m = options.rays_per_cell.max(1) as f64;
    // Even, so that no pixel centre lies on the axis planes through the light: a light on a
    // cell face would otherwise send a whole column of rays exactly along that face.
    let n = ((4.0 * m * r_max / grid.cell_size).ceil() as usize)
        .clamp(8, options.max_cube_resolution.max(8))
        .next_multiple_of(2);
    let step = 2.0 / n as f64;
    // Batches: (face, pixel row).
    deposit_parallel(grid.cell_count(), 6 * n, |batch, dep| {
        let (face, row) = (batch / n, batch % n);
        let axis = face / 2;
        let sign = if face % 2 == 0 { 1.0 } else { -1.0 };
        let (ua, va) = ((axis + 1) % 3, (axis + 2) % 3);
        let y0 = -1.0 + row as f64 * step;
        let y1 = y0 + step;
        for col in 0..n {
            let x0 = -1.0 + col as f64 * step;
            let x1 = x0 + step;
            let omega =
                rect_solid_angle(x1, y1) - rect_solid_angle(x0, y1) - rect_solid_angle(x1, y0)
                    + rect_solid_angle(x0, y0);
            let mut d = DVec3::ZERO;
            d[axis] = sign;
            d[ua] = 0.5 * (x0 + x1);
            d[va] = 0.5 * (y0 + y1);
            let d = d.normalize();
            if let Some((spot_axis, cos_half)) = cone {
                if d.dot(spot_axis) < cos_half {
                    continue;
                }
            }
            let ray = Ray {
                origin: position,
                direction: d,
            };
            dep.trace(grid, sigma_t, &ray, intensity * omega);
        }
    })
}

/// The exact optical depth toward a directional light travelling along `direction` at every
/// cell corner ([`Grid::corner_index`]), as [`LightPass::compute`] stores it, without the cell
/// averages that cost most of a light pass: for a finer corner lattice over the same medium.
pub fn directional_corner_depths(
    grid: &Grid,
    sigma_t: &[f32],
    direction: DVec3,
) -> Result<Vec<f32>, MediumError> {
    if sigma_t.len() != grid.cell_count() {
        return Err(MediumError::invalid(
            "light pass",
            format!(
                "{} σt values for a grid of {} cells",
                sigma_t.len(),
                grid.cell_count()
            ),
        ));
    }
    let Light::Directional { direction, .. } = (Light::Directional {
        direction,
        irradiance: 1.0,
    })
    .validated()?
    else {
        unreachable!("validated keeps the kind")
    };
    let medium = FrameMedium::new(grid, sigma_t, direction);
    Ok(directional_corner_optical_depth(grid, &medium))
}

/// Exact optical depth toward the light (`−ln T_L`) at every corner for a directional light,
/// plane by plane in the sweep frame. The backward ray from any corner crosses its `q`-th
/// layer at the same sub-cell position for every corner (all corners sit on the lattice), so
/// the split of that crossing among at most three cells is computed once per `q` and applied
/// to whole rows of corners: the optical depth is a sum of `length × σt` over shared pieces,
/// with no per-ray traversal. Exact (an interpolating sweep would blur shadow edges).
fn directional_corner_optical_depth(grid: &Grid, medium: &FrameMedium) -> Vec<f32> {
    let frame = medium.frame;
    let [nu, nv, na] = frame.n;
    let plane_size = (nu + 1) * (nv + 1);
    let mut depths = vec![0.0f64; plane_size * (na + 1)];
    depths
        .par_chunks_mut(plane_size)
        .enumerate()
        .for_each(|(plane, tau)| corner_plane(medium, plane, tau));
    let mut out = vec![0.0f32; grid.corner_count()];
    frame.for_each_corner(grid, |f, g| out[g] = depths[f] as f32);
    out
}

/// Optical depths of one plane of corners (`tau`, zeroed, `u + (nu + 1) v`).
#[inline(always)]
fn corner_plane_body(medium: &FrameMedium, plane: usize, tau: &mut [f64]) {
    let frame = medium.frame;
    let [nu, nv, _] = frame.n;
    let back = [-frame.shift[0], -frame.shift[1]];
    let (nu_i, nv_i) = (nu as i64, nv as i64);
    for q in 0..plane {
        let layer = plane - 1 - q;
        let pos = [q as f64 * back[0], q as f64 * back[1]];
        let base = [pos[0].floor(), pos[1].floor()];
        if base[0] + 1.0 < -(nu as f64) || base[1] + 1.0 < -(nv as f64) {
            break; // every backward ray has left through a side face
        }
        let (pieces, count) = layer_pieces(
            [pos[0] - base[0], pos[1] - base[1]],
            back,
            frame.layer_length,
        );
        let layer_base = nu * nv * layer;
        for piece in &pieces[..count] {
            // Corner (i, j) reads cell (i + ou, j + ov). A ray running along a boundary face
            // (no lateral motion on that axis) counts the cell inside, as the traversal does:
            // the last corner row or column reads the last cell.
            let ou = base[0] as i64 + piece.offset[0];
            let ov = base[1] as i64 + piece.offset[1];
            let i_lo = (-ou).max(0);
            let i_hi = (nu_i - ou).min(nu_i + 1); // exclusive
            let j_lo = (-ov).max(0);
            let j_hi = if back[1] == 0.0 {
                nv_i + 1
            } else {
                (nv_i - ov).min(nv_i + 1)
            };
            if i_lo >= i_hi {
                continue;
            }
            let length = piece.length;
            for j in j_lo..j_hi {
                let cell_row = layer_base + nu * (j + ov).min(nv_i - 1) as usize;
                let corner_row = (nu + 1) * j as usize;
                let sigma =
                    &medium.sigma[cell_row + (i_lo + ou) as usize..cell_row + (i_hi + ou) as usize];
                let depth = &mut tau[corner_row + i_lo as usize..corner_row + i_hi as usize];
                for (t, &s) in depth.iter_mut().zip(sigma) {
                    *t += length * s as f64;
                }
                if back[0] == 0.0 {
                    tau[corner_row + nu] += length * medium.sigma[cell_row + nu - 1] as f64;
                }
            }
        }
    }
}

/// [`corner_plane_body`] compiled for AVX2 (no FMA: the same results as the portable build).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn corner_plane_avx2(medium: &FrameMedium, plane: usize, tau: &mut [f64]) {
    corner_plane_body(medium, plane, tau)
}

/// [`corner_plane_body`], on AVX2 when the CPU has it.
fn corner_plane(medium: &FrameMedium, plane: usize, tau: &mut [f64]) {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: the CPU supports AVX2, checked on the line above.
        return unsafe { corner_plane_avx2(medium, plane, tau) };
    }
    corner_plane_body(medium, plane, tau)
}

/// Optical depth toward the light at every corner: one backward ray per corner (point and
/// spot).
fn corner_optical_depth(grid: &Grid, sigma_t: &[f32], light: &Light) -> Vec<f32> {
    let [nx, ny, _] = grid.dims;
    let h = grid.cell_size;
    let plane = (nx + 1) * (ny + 1);
    let mut out = vec![0.0f32; grid.corner_count()];
    out.par_chunks_mut(plane).enumerate().for_each(|(k, slab)| {
        for j in 0..=ny {
            for i in 0..=nx {
                let x = DVec3::new(i as f64, j as f64, k as f64) * h;
                let (ray, t_max) = match *light {
                    Light::Directional { direction, .. } => (
                        Ray {
                            origin: x,
                            direction: -direction,
                        },
                        f64::INFINITY,
                    ),
                    Light::Point { position, .. } | Light::Spot { position, .. } => {
                        let to_light = position - x;
                        let r = to_light.length();
                        if r == 0.0 {
                            slab[i + (nx + 1) * j] = 0.0;
                            continue;
                        }
                        (
                            Ray {
                                origin: x,
                                direction: to_light / r,
                            },
                            r,
                        )
                    }
                };
                slab[i + (nx + 1) * j] = grid.optical_depth(sigma_t, &ray, 0.0, t_max) as f32;
            }
        }
    });
    out
}

/// Channel `c` of `medium`, or an error naming the channels there are.
fn channel_of(medium: &Medium, c: usize) -> Result<&ChannelMedium, MediumError> {
    medium.channels().get(c).ok_or_else(|| {
        MediumError::invalid(
            "light pass",
            format!(
                "channel {c} of a {}-channel medium",
                medium.channels().len()
            ),
        )
    })
}

impl LightPass {
    /// The light pass of channel `c` of `medium` with default options (see
    /// [`LightPassOptions`]).
    pub fn compute(medium: &Medium, c: usize, lights: &[Light]) -> Result<LightPass, MediumError> {
        Self::compute_with(medium, c, lights, &LightPassOptions::default())
    }

    /// The light pass for every light of colour channel `c` of `medium`, on the medium's grid.
    ///
    /// The medium is not checked again: a [`Medium`] is valid by construction (its σt has one
    /// finite value ≥ 0 per cell). What is checked here is what the medium does not vouch
    /// for: the channel index (an error, not a panic, when out of range), the lights (at most
    /// [`MAX_LIGHTS`], each valid) and `options.rays_per_cell ≥ 1`.
    pub fn compute_with(
        medium: &Medium,
        c: usize,
        lights: &[Light],
        options: &LightPassOptions,
    ) -> Result<LightPass, MediumError> {
        let channel = channel_of(medium, c)?;
        if lights.len() > MAX_LIGHTS {
            return Err(MediumError::invalid(
                "light pass",
                format!("{} lights: at most {MAX_LIGHTS}", lights.len()),
            ));
        }
        if options.rays_per_cell == 0 {
            return Err(MediumError::invalid(
                "light pass",
                "rays_per_cell must be ≥ 1",
            ));
        }
        let grid = medium.grid();
        let sigma_t = &channel.sigma_t;
        let volume = grid.cell_volume();
        let mut fields = Vec::with_capacity(lights.len());
        for light in lights {
            let light = light.validated()?;
            let (deposit, corner_optical_depth) = match light {
                Light::Directional {
                    direction,
                    irradiance,
                } => {
                    // Light along an axis is exact with one ray per cell.
                    let axis_aligned = (0..3).filter(|&a| direction[a] != 0.0).count() == 1;
                    let m = if axis_aligned {
                        1
                    } else {
                        options.rays_per_cell
                    };
                    let medium = FrameMedium::new(grid, sigma_t, direction);
                    (
                        directional_deposit(grid, &medium, direction, irradiance, m),
                        directional_corner_optical_depth(grid, &medium),
                    )
                }
                Light::Point {
                    position,
                    intensity,
                } => (
                    point_deposit(grid, sigma_t, position, intensity, None, options),
                    corner_optical_depth(grid, sigma_t, &light),
                ),
                Light::Spot {
                    position,
                    axis,
                    half_angle,
                    intensity,
                } => (
                    point_deposit(
                        grid,
                        sigma_t,
                        position,
                        intensity,
                        Some((axis, half_angle.cos())),
                        options,
                    ),
                    corner_optical_depth(grid, sigma_t, &light),
                ),
            };
            let extinguished: f64 = deposit
                .cell_integral
                .iter()
                .zip(sigma_t)
                .map(|(&v, &s)| v * s as f64)
                .sum();
            let cell_irradiance = deposit
                .cell_integral
                .iter()
                .map(|&v| (v / volume) as f32)
                .collect();
            fields.push(LightField {
                light,
                cell_irradiance,
                corner_optical_depth: Arc::new(corner_optical_depth),
                energy: LightEnergy {
                    entering: deposit.entering,
                    extinguished,
                    leaving: deposit.leaving,
                },
            });
        }
        Ok(LightPass {
            grid: *grid,
            sigma_t: sigma_t.clone(),
            fields,
        })
    }

    /// `Σ_lights cell_irradiance` per cell (f64), the light side of the zonal source.
    pub fn total_cell_irradiance(&self) -> Vec<f64> {
        let mut total = vec![0.0f64; self.grid.cell_count()];
        for f in &self.fields {
            for (t, &v) in total.iter_mut().zip(&f.cell_irradiance) {
                *t += v as f64;
            }
        }
        total
    }

    /// The zonal source of physics.md, `E_i = e_i + a_i σt_i Σ_l cell_irradiance_{l,i} / 4π`
    /// (first bounce folded into the emission, isotropic scattering), from channel `c` of
    /// `medium`, which must be the channel this pass was computed for. The channel's arrays
    /// match its grid by the [`Medium`]'s invariants; an out-of-range `c` or a medium on
    /// another grid than this pass's is an error.
    pub fn zonal_source(&self, medium: &Medium, c: usize) -> Result<Vec<f64>, MediumError> {
        let channel = channel_of(medium, c)?;
        if *medium.grid() != self.grid {
            return Err(MediumError::invalid(
                "light pass",
                "the medium's grid is not the one this light pass was computed on",
            ));
        }
        Ok(self
            .total_cell_irradiance()
            .into_iter()
            .enumerate()
            .map(|(i, e)| {
                channel.emission.get(i) as f64
                    + channel.albedo.get(i) as f64 * channel.sigma_t[i] as f64 * e / (4.0 * PI)
            })
            .collect())
    }

    /// The light's transmittance `T_L(x)` for `x` inside `cell`: the corner field on the
    /// face where the ray toward the light leaves the cell (bilinear), times the exact
    /// `e^{−σt d}` inside the cell.
    #[inline]
    pub fn transmittance_at(&self, light_index: usize, x: DVec3, cell: usize) -> f64 {
        (-self.optical_depth_at(light_index, x, cell)).exp()
    }

    /// `−ln T_L(x)` for `x` inside `cell`: the optical depth toward the light, interpolated
    /// bilinearly on the exit face plus `σt d` inside the cell. Renders that need `ln T_L`
    /// call this and skip an `exp`/`ln` pair.
    #[inline]
    pub fn optical_depth_at(&self, light_index: usize, x: DVec3, cell: usize) -> f64 {
        let field = &self.fields[light_index];
        let grid = &self.grid;
        let h = grid.cell_size;
        let lo = grid.cell_min(cell);
        let x = x.clamp(lo, lo + h);
        let (to_light, dist_to_light) = match field.light {
            Light::Directional { direction, .. } => (-direction, f64::INFINITY),
            Light::Point { position, .. } | Light::Spot { position, .. } => {
                let v = position - x;
                let r = v.length();
                if r == 0.0 {
                    return 0.0;
                }
                (v / r, r)
            }
        };
        // Exit distance and face axis of the ray toward the light.
        let mut t_exit = f64::INFINITY;
        let mut face_axis = 0;
        for a in 0..3 {
            let d = to_light[a];
            let t = if d > 0.0 {
                (lo[a] + h - x[a]) / d
            } else if d < 0.0 {
                (lo[a] - x[a]) / d
            } else {
                continue;
            };
            if t < t_exit {
                t_exit = t;
                face_axis = a;
            }
        }
        let sigma = self.sigma_t[cell] as f64;
        if dist_to_light <= t_exit {
            // The light is inside this cell.
            return sigma * dist_to_light;
        }
        let t_exit = t_exit.max(0.0);
        let p = x + to_light * t_exit;
        let [ci, cj, ck] = grid.coords(cell);
        let mut base = [ci, cj, ck];
        if to_light[face_axis] > 0.0 {
            base[face_axis] += 1;
        }
        let (ua, va) = ((face_axis + 1) % 3, (face_axis + 2) % 3);
        let fu = ((p[ua] - lo[ua]) / h).clamp(0.0, 1.0);
        let fv = ((p[va] - lo[va]) / h).clamp(0.0, 1.0);
        let depth = |du: usize, dv: usize| {
            let mut c = base;
            c[ua] += du;
            c[va] += dv;
            field.corner_optical_depth[grid.corner_index(c[0], c[1], c[2])] as f64
        };
        let face_depth = (1.0 - fu) * (1.0 - fv) * depth(0, 0)
            + fu * (1.0 - fv) * depth(1, 0)
            + (1.0 - fu) * fv * depth(0, 1)
            + fu * fv * depth(1, 1);
        face_depth + sigma * t_exit
    }

    /// The light's flow direction at `x` and its irradiance there without shadows (the
    /// "Utah" model, `T_L ≡ 1`); zero outside a spot's cone.
    #[inline]
    pub fn unshadowed_at(&self, light_index: usize, x: DVec3) -> (DVec3, f64) {
        self.fields[light_index].light.arriving_at(x)
    }

    /// The light's flow direction at `x` (inside `cell`) and its irradiance times `T_L(x)`.
    #[inline]
    pub fn irradiance_at(&self, light_index: usize, x: DVec3, cell: usize) -> (DVec3, f64) {
        let (flow, e) = self.unshadowed_at(light_index, x);
        if e == 0.0 {
            return (flow, 0.0);
        }
        (flow, e * self.transmittance_at(light_index, x, cell))
    }

    /// The light's largest unshadowed irradiance anywhere in the grid (an upper bound for
    /// `irradiance_at`): `E0` for directional light, `I / r_min²` for point and spot lights.
    pub fn max_irradiance(&self, light_index: usize) -> f64 {
        match self.fields[light_index].light {
            Light::Directional { irradiance, .. } => irradiance,
            Light::Point {
                position,
                intensity,
            }
            | Light::Spot {
                position,
                intensity,
                ..
            } => {
                let nearest = position.clamp(DVec3::ZERO, self.grid.extent());
                let r2 = (nearest - position).length_squared();
                if r2 == 0.0 {
                    f64::INFINITY
                } else {
                    intensity / r2
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The vectorisable interception matches libm's `expm1` over the whole range, thin cells
    /// included (where `1 − e^{−x}` computed naively loses its digits), fused or not.
    #[test]
    fn interception_matches_expm1() {
        let mut x = 1e-14f64;
        while x < 2000.0 {
            let exact = -(-x).exp_m1();
            for (name, got) in [
                ("portable", interception::<false>(x)),
                ("fused", interception::<true>(x)),
            ] {
                assert!(
                    (got - exact).abs() <= 1e-9 * exact,
                    "{name}: x = {x}: {got} vs {exact}"
                );
            }
            x *= 1.37;
        }
        assert_eq!(interception::<false>(0.0), 0.0);
        assert_eq!(interception::<false>(1e9), 1.0);
    }
}
