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
//! Corner transmittance is exact: one backward ray per corner toward the light. Inside a cell,
//! [`LightPass::transmittance_at`] continues the corner field with the exact exponential:
//! `T_L(x) = T(exit point, bilinear on that face's corners) · e^{−σt d}`.

use std::f64::consts::PI;

use glam::DVec3;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::traversal::Ray;
use crate::{ChannelMedium, Grid, Light, MediumError};

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
    /// varies exponentially, and linear interpolation of `T_L` overestimates it.
    pub corner_optical_depth: Vec<f32>,
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

/// Directional light: `m × m` rays per cell on each face the light enters through.
fn directional_deposit(
    grid: &Grid,
    sigma_t: &[f32],
    direction: DVec3,
    irradiance: f64,
    m: usize,
) -> Deposit {
    let h = grid.cell_size;
    let delta = h / m as f64;
    let ext = grid.extent();
    // Per entry face: the fixed axis and the two lattice axes, one batch per lattice row.
    let faces: Vec<(usize, usize, usize)> = (0..3)
        .filter(|&a| direction[a] != 0.0)
        .map(|a| (a, (a + 1) % 3, (a + 2) % 3))
        .collect();
    let rows: Vec<(usize, usize)> = faces
        .iter()
        .flat_map(|&(a, _, c)| (0..grid.dims[c] * m).map(move |r| (a, r)))
        .collect();
    deposit_parallel(grid.cell_count(), rows.len(), |batch, dep| {
        let (a, row) = rows[batch];
        let (b, c) = ((a + 1) % 3, (a + 2) % 3);
        let power = irradiance * direction[a].abs() * delta * delta;
        let mut p = DVec3::ZERO;
        p[a] = if direction[a] > 0.0 { 0.0 } else { ext[a] };
        p[c] = (row as f64 + 0.5) * delta;
        for col in 0..grid.dims[b] * m {
            p[b] = (col as f64 + 0.5) * delta;
            // Start one cell outside so the clip finds the entry point robustly.
            let ray = Ray {
                origin: p - direction * h,
                direction,
            };
            dep.trace(grid, sigma_t, &ray, power);
        }
    })
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

/// One cell's share of a backward ray's crossing of a layer: lateral cell offsets from the
/// corner the ray started at, and the length inside that cell.
#[derive(Clone, Copy, Debug)]
struct StencilEntry {
    offset: [i64; 2],
    length: f64,
}

/// Exact optical depth toward the light (`−ln T_L`) at every corner for a directional light, layer by layer along the dominant
/// axis. The backward ray from any corner crosses its `q`-th layer at the same sub-cell
/// position for every corner (all corners sit on the lattice), so the split of that crossing
/// among at most three cells is computed once per `q` and applied to every corner: the
/// optical depth is a sum of `length × σt` over precomputed stencils, with no per-ray DDA.
fn directional_corner_optical_depth(grid: &Grid, sigma_t: &[f32], direction: DVec3) -> Vec<f32> {
    let back = -direction;
    let a = (0..3)
        .max_by(|&x, &y| back[x].abs().total_cmp(&back[y].abs()))
        .unwrap_or(2);
    let (b, c) = match a {
        0 => (1, 2),
        1 => (0, 2),
        _ => (0, 1),
    };
    let dims = grid.dims;
    let (na, nb, nc) = (dims[a], dims[b], dims[c]);
    let cell_stride = [1, dims[0], dims[0] * dims[1]];
    let corner_stride = [1, dims[0] + 1, (dims[0] + 1) * (dims[1] + 1)];
    let ra = back[a].abs();
    // Lateral displacement per layer, in cells, and the path length per layer.
    let shift = [back[b] / ra, back[c] / ra];
    let layer_length = grid.cell_size / ra;
    let upward = back[a] > 0.0;
    let stencils: Vec<Vec<StencilEntry>> = (1..=na)
        .map(|q| {
            let s0 = [shift[0] * (q - 1) as f64, shift[1] * (q - 1) as f64];
            let mut breaks = vec![0.0, 1.0];
            for x in 0..2 {
                if shift[x] != 0.0 {
                    let s1 = s0[x] + shift[x];
                    let (lo, hi) = (s0[x].min(s1), s0[x].max(s1));
                    let n = lo.floor() + 1.0;
                    if n < hi {
                        breaks.push((n - s0[x]) / shift[x]);
                    }
                }
            }
            breaks.sort_by(f64::total_cmp);
            breaks
                .windows(2)
                .filter(|w| w[1] > w[0])
                .map(|w| {
                    let t = 0.5 * (w[0] + w[1]);
                    StencilEntry {
                        offset: [
                            (s0[0] + t * shift[0]).floor() as i64,
                            (s0[1] + t * shift[1]).floor() as i64,
                        ],
                        length: (w[1] - w[0]) * layer_length,
                    }
                })
                .collect()
        })
        .collect();
    // Rows of corners along b (the lateral axis with the smaller memory stride) for each c:
    // for one layer and one stencil entry, a row reads a contiguous run of σt.
    let (nb_i, nc_i) = (nb as i64, nc as i64);
    let planes: Vec<Vec<f32>> = (0..=na)
        .into_par_iter()
        .map(|k| {
            let layers = if upward { na - k } else { k };
            let mut tau = vec![0.0f64; (nb + 1) * (nc + 1)];
            for (q, stencil) in stencils.iter().enumerate().take(layers) {
                let layer = if upward { k + q } else { k - 1 - q };
                let layer_base = layer * cell_stride[a];
                for e in stencil {
                    let [ob, oc] = e.offset;
                    // Corners whose cell lies inside; a ray running along a boundary face
                    // (no lateral motion on that axis) counts the cells inside, as the DDA
                    // does. Cells outside contribute nothing: a ray that left never returns.
                    let (b_lo, b_hi) = if shift[0] == 0.0 {
                        (0, nb_i)
                    } else {
                        ((-ob).max(0), (nb_i - 1 - ob).min(nb_i))
                    };
                    let (c_lo, c_hi) = if shift[1] == 0.0 {
                        (0, nc_i)
                    } else {
                        ((-oc).max(0), (nc_i - 1 - oc).min(nc_i))
                    };
                    for ic in c_lo..=c_hi {
                        let cc = (ic + oc).min(nc_i - 1) as usize;
                        let row_base = layer_base + cc * cell_stride[c];
                        let row = &mut tau[(nb + 1) * ic as usize..(nb + 1) * (ic as usize + 1)];
                        for ib in b_lo..=b_hi {
                            let cb = (ib + ob).min(nb_i - 1) as usize;
                            row[ib as usize] +=
                                e.length * sigma_t[row_base + cb * cell_stride[b]] as f64;
                        }
                    }
                }
            }
            tau.iter().map(|&t| t as f32).collect()
        })
        .collect();
    let mut out = vec![0.0f32; grid.corner_count()];
    for (k, plane) in planes.iter().enumerate() {
        for ic in 0..=nc {
            for ib in 0..=nb {
                out[k * corner_stride[a] + ib * corner_stride[b] + ic * corner_stride[c]] =
                    plane[ib + (nb + 1) * ic];
            }
        }
    }
    out
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

impl LightPass {
    /// The light pass with default options (see [`LightPassOptions`]).
    pub fn compute(
        grid: &Grid,
        channel: &ChannelMedium,
        lights: &[Light],
    ) -> Result<LightPass, MediumError> {
        Self::compute_with(grid, channel, lights, &LightPassOptions::default())
    }

    /// The light pass for every light of one colour channel.
    pub fn compute_with(
        grid: &Grid,
        channel: &ChannelMedium,
        lights: &[Light],
        options: &LightPassOptions,
    ) -> Result<LightPass, MediumError> {
        let cells = grid.cell_count();
        if channel.sigma_t.len() != cells {
            return Err(MediumError::invalid(
                "light pass",
                format!("{} σt values for {cells} cells", channel.sigma_t.len()),
            ));
        }
        if let Some(i) = channel
            .sigma_t
            .iter()
            .position(|s| !(s.is_finite() && *s >= 0.0))
        {
            return Err(MediumError::invalid(
                "light pass",
                format!("cell {i} has σt = {}", channel.sigma_t[i]),
            ));
        }
        if options.rays_per_cell == 0 {
            return Err(MediumError::invalid(
                "light pass",
                "rays_per_cell must be ≥ 1",
            ));
        }
        let sigma_t = &channel.sigma_t;
        let volume = grid.cell_volume();
        let mut fields = Vec::with_capacity(lights.len());
        for light in lights {
            let light = light.validated()?;
            let deposit = match light {
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
                    directional_deposit(grid, sigma_t, direction, irradiance, m)
                }
                Light::Point {
                    position,
                    intensity,
                } => point_deposit(grid, sigma_t, position, intensity, None, options),
                Light::Spot {
                    position,
                    axis,
                    half_angle,
                    intensity,
                } => point_deposit(
                    grid,
                    sigma_t,
                    position,
                    intensity,
                    Some((axis, half_angle.cos())),
                    options,
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
                corner_optical_depth: match light {
                    Light::Directional { direction, .. } => {
                        directional_corner_optical_depth(grid, sigma_t, direction)
                    }
                    _ => corner_optical_depth(grid, sigma_t, &light),
                },
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
    /// (first bounce folded into the emission, isotropic scattering). `channel` must be the
    /// one this pass was computed for.
    pub fn zonal_source(&self, channel: &ChannelMedium) -> Vec<f64> {
        self.total_cell_irradiance()
            .into_iter()
            .enumerate()
            .map(|(i, e)| {
                channel.emission.get(i) as f64
                    + channel.albedo.get(i) as f64 * channel.sigma_t[i] as f64 * e / (4.0 * PI)
            })
            .collect()
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
