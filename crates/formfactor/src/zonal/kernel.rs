//! The shared far-field kernel (thick-cell estimate) and the near-field ray stencil.
//!
//! Far pairs: `F_ij = α_i β_j G T_ij / r²` with the isotropic mean chord `ℓ̄ = 2h/3` of a cube,
//! `α = 1 − e^{−σt ℓ̄}` (interception), `β = α / (σt ℓ̄)` (mean escape from the emitting
//! cell), `G = (S/4)/(4π) = 1.5 h² / 4π` (mean projected area over 4π) and `T_ij` the
//! transmittance between the cells along the centre line, end cells excluded. It is exactly
//! reciprocal: `F_ij / σt_i = ℓ̄ β_i β_j G T / r²` is symmetric, and tends to Rushmeier's
//! `σt_i V T / 4π r²` for thin cells.
//!
//! Near pairs (Chebyshev offset ≤ R) use the identity
//! `F_ij = E_{y∈j, ω}[T(y → i) (1 − e^{−σt_i ℓ_i})]`: rays from stratified points of the source
//! cell in quasi-uniform directions, whose lattice geometry (cell offset, length) is traced once
//! for the canonical neighbourhood and reused for every cell. Energy is conserved ray by ray.

use std::f64::consts::PI;

use glam::DVec3;
use medium::{traversal::Ray, Grid};

/// Mean chord of a cube of side `h` over isotropic uniform rays: `4V/S = 2h/3`.
#[inline]
pub(crate) fn mean_chord(h: f64) -> f64 {
    2.0 * h / 3.0
}

/// `α = 1 − e^{−σt ℓ̄}`, the chance that a ray from afar is extinguished in the cell.
#[inline]
pub(crate) fn interception(sigma_t: f64, h: f64) -> f64 {
    -(-sigma_t * mean_chord(h)).exp_m1()
}

/// `β = (1 − e^{−τ})/τ`, `τ = σt ℓ̄`: the mean escape of light emitted uniformly in the cell.
#[inline]
pub(crate) fn escape(sigma_t: f64, h: f64) -> f64 {
    let tau = sigma_t * mean_chord(h);
    if tau < 1e-8 {
        1.0 - 0.5 * tau
    } else {
        -(-tau).exp_m1() / tau
    }
}

/// `G = 1.5 h² / 4π`.
#[inline]
pub(crate) fn geometry_factor(h: f64) -> f64 {
    1.5 * h * h / (4.0 * PI)
}

/// Optical depth between two distinct cells along their centre line, end cells excluded.
/// Always traced from the lower index to the higher so that `τ_ij = τ_ji` bit for bit.
pub(crate) fn depth_between_cells(grid: &Grid, sigma_t: &[f32], i: usize, j: usize) -> f64 {
    let (a, b) = if i < j { (i, j) } else { (j, i) };
    let ca = grid.cell_center(a);
    let cb = grid.cell_center(b);
    let r = (cb - ca).length();
    let ray = Ray::new(ca, cb - ca);
    grid.traverse(&ray, 0.0, r)
        .filter(|s| s.cell != a && s.cell != b)
        .map(|s| sigma_t[s.cell] as f64 * s.length())
        .sum()
}

/// Quadrature of the near-field ray stencil.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct NearQuadrature {
    /// Neighbourhood radius R in cells: pairs with Chebyshev offset ≤ R are near.
    pub radius: usize,
    /// Emission points per axis in the source cell (stratified, jittered).
    pub points_per_axis: usize,
    /// Directions per point (a Fibonacci sphere randomly rotated per point, antipodes paired).
    pub directions: usize,
}

/// Near-field radius (cells) of the defaults. The far-field estimate uses the mean chord,
/// which overestimates interception by optically thick cells (1 − e^{−σℓ} is concave in ℓ);
/// at 2–3 cells that bias compounds over scattering orders. Measured on the cloud24 reference
/// (albedo 0.99, Mitsuba): radius 2 → 6.0 % RMS image error (+5.5 % mean), 3 → 2.5 %,
/// 4 → 1.8 % (+0.8 % mean).
pub const DEFAULT_NEAR_RADIUS: usize = 4;

impl Default for NearQuadrature {
    fn default() -> Self {
        NearQuadrature {
            radius: DEFAULT_NEAR_RADIUS,
            points_per_axis: 6,
            directions: 64,
        }
    }
}

/// Precomputed rays through the canonical `(2R+1)³` neighbourhood: per ray the list of
/// (offset slot, length in cells) up to where the ray leaves the neighbourhood.
#[derive(Clone, Debug)]
pub(crate) struct NearStencil {
    pub radius: usize,
    pub width: usize,
    pub ray_start: Vec<u32>,
    pub seg_slot: Vec<u16>,
    pub seg_length: Vec<f64>,
}

fn splitmix(state: &mut u64) -> f64 {
    *state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
    let mut z = *state;
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^= z >> 31;
    (z >> 11) as f64 / (1u64 << 53) as f64
}

/// A uniformly random rotation (Shoemake's quaternion method).
fn random_rotation(state: &mut u64) -> glam::DQuat {
    let (u1, u2, u3) = (splitmix(state), splitmix(state), splitmix(state));
    let (a, b) = ((1.0 - u1).sqrt(), u1.sqrt());
    glam::DQuat::from_xyzw(
        a * (2.0 * PI * u2).sin(),
        a * (2.0 * PI * u2).cos(),
        b * (2.0 * PI * u3).sin(),
        b * (2.0 * PI * u3).cos(),
    )
    .normalize()
}

impl NearStencil {
    pub fn new(q: &NearQuadrature) -> Self {
        let width = 2 * q.radius + 1;
        let lattice = Grid {
            dims: [width; 3],
            cell_size: 1.0,
        };
        // Half the directions on a Fibonacci sphere, plus their antipodes.
        let half = q.directions.div_ceil(2).max(1);
        let golden = PI * (3.0 - 5f64.sqrt());
        let base: Vec<DVec3> = (0..half)
            .map(|k| {
                let z = 1.0 - (2.0 * k as f64 + 1.0) / (2 * half) as f64;
                let rho = (1.0 - z * z).max(0.0).sqrt();
                let phi = golden * k as f64;
                DVec3::new(rho * phi.cos(), rho * phi.sin(), z)
            })
            .collect();
        let n = q.points_per_axis.max(1);
        let mut state = 0x5EED_F0F0_u64;
        let mut ray_start = vec![0u32];
        let (mut seg_slot, mut seg_length) = (Vec::new(), Vec::new());
        for pk in 0..n {
            for pj in 0..n {
                for pi in 0..n {
                    let jitter = DVec3::new(
                        splitmix(&mut state),
                        splitmix(&mut state),
                        splitmix(&mut state),
                    );
                    let local = (DVec3::new(pi as f64, pj as f64, pk as f64) + jitter) / n as f64;
                    let origin = local + q.radius as f64;
                    let rot = random_rotation(&mut state);
                    for d in &base {
                        let w = rot * *d;
                        for dir in [w, -w] {
                            let ray = Ray::new(origin, dir);
                            for s in lattice.traverse(&ray, 0.0, f64::INFINITY) {
                                if s.length() > 0.0 {
                                    seg_slot.push(s.cell as u16);
                                    seg_length.push(s.length());
                                }
                            }
                            ray_start.push(seg_slot.len() as u32);
                        }
                    }
                }
            }
        }
        NearStencil {
            radius: q.radius,
            width,
            ray_start,
            seg_slot,
            seg_length,
        }
    }

    pub fn slots(&self) -> usize {
        self.width * self.width * self.width
    }

    pub fn rays(&self) -> usize {
        self.ray_start.len() - 1
    }

    /// Offset of a slot from the centre cell.
    pub fn slot_offset(&self, slot: usize) -> [i64; 3] {
        let w = self.width;
        let r = self.radius as i64;
        [
            (slot % w) as i64 - r,
            ((slot / w) % w) as i64 - r,
            (slot / (w * w)) as i64 - r,
        ]
    }

    /// Global cell of each slot around `cell`, `u32::MAX` outside the grid.
    pub fn neighbours(&self, grid: &Grid, cell: usize, out: &mut [u32]) {
        let c = grid.coords(cell);
        for (slot, o) in out.iter_mut().enumerate() {
            let off = self.slot_offset(slot);
            let mut idx = [0usize; 3];
            let mut inside = true;
            for a in 0..3 {
                let v = c[a] as i64 + off[a];
                if v < 0 || v >= grid.dims[a] as i64 {
                    inside = false;
                    break;
                }
                idx[a] = v as usize;
            }
            *o = if inside {
                grid.index(idx[0], idx[1], idx[2]) as u32
            } else {
                u32::MAX
            };
        }
    }

    /// Column `F_{·j}` of the near field for source cell `j`: `column[slot]` receives the
    /// fraction of j's isotropic uniform emission extinguished in that neighbour. Returns
    /// the mean transmittance of the rays leaving the neighbourhood.
    pub fn column(&self, sigma_t: &[f32], h: f64, neighbours: &[u32], column: &mut [f64]) -> f64 {
        column.iter_mut().for_each(|c| *c = 0.0);
        let mut escaped = 0.0;
        for r in 0..self.rays() {
            let (s0, s1) = (self.ray_start[r] as usize, self.ray_start[r + 1] as usize);
            let mut t = 1.0f64;
            for s in s0..s1 {
                let slot = self.seg_slot[s] as usize;
                let cell = neighbours[slot];
                if cell == u32::MAX {
                    continue;
                }
                let sigma = sigma_t[cell as usize] as f64;
                if sigma > 0.0 {
                    let e = (-sigma * self.seg_length[s] * h).exp();
                    column[slot] += t * (1.0 - e);
                    t *= e;
                    // What is left of the ray is below any quadrature error: it counts as
                    // escaped (never deposited), so column sums stay ≤ 1.
                    if t < 1e-9 {
                        break;
                    }
                }
            }
            escaped += t;
        }
        let inv = 1.0 / self.rays() as f64;
        column.iter_mut().for_each(|c| *c *= inv);
        escaped * inv
    }
}
