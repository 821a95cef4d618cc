//! Direction bins on the faces of a cube: Max's 96 bins (n = 4) and the same construction
//! for `6·n²` bins, with closed-form solid angles.
//!
//! Face `f` (0..6) is the face of the cube `[-1, 1]³` on axis `f / 2` with sign `+` for even
//! `f`; its `n × n` squares are indexed `(i, j)` along the face's `u = axis+1`, `v = axis+2`
//! (mod 3) coordinates. Bin index: `f·n² + i·n + j`. Each bin is the cone from the cube's
//! centre through one square.

use glam::DVec3;

use super::OrdinatesError;

/// Discrete-ordinates bin counts volrad supports: the `6 n²` faces of an `n³` block of cubes.
pub const VALID_BINS: [usize; 12] = [6, 24, 54, 96, 150, 216, 294, 384, 486, 600, 726, 864];

/// The bin counts [`auto_bin_count`] chooses from, each the smallest measured to reach its
/// error class (docs/validation.md, the cloud24 orbit): Max's 96 up to `g` =
/// [`AUTO_BINS_ISOTROPIC_BELOW`], 216 up to [`AUTO_BINS_MODERATE_UP_TO`], 864 beyond; 600
/// and 384 are the steps down where the transport grid leaves no room for 864.
pub const AUTO_BIN_STEPS: [usize; 5] = [96, 216, 384, 600, 864];

/// Mean cosines up to this take Max's 96 bins: at g = 0 they are within 2 % per view; the
/// error that more bins remove grows with the forward peak.
pub const AUTO_BINS_ISOTROPIC_BELOW: f64 = 0.3;

/// Mean cosines up to this take 216 bins (g = 0.6: 2.7 % per view and +0.6 % in the mean
/// against 3.1 % and +2.0 % with 96); beyond it 864 (g = 0.85: 2.5 %, −0.4 … +0.7 % in the
/// means, against 2.6 %, 0.0 … +1.1 % with 600, 2.9 %, +0.2 … +1.8 % with 384, 6.3 %,
/// +3.1 % with 216 and 7.6 %, +8.1 % with 96: the bins' angular error falls about as
/// 1 / bins).
pub const AUTO_BINS_MODERATE_UP_TO: f64 = 0.7;

/// The most sweep work [`auto_bin_count`] grows the bins to, in transport cell-bins
/// ([`auto_bins_work`]): 80 Mi, what every sweep crosses (the solver state is the cells with
/// medium × bins, [`OrdinatesOperator::state_cells`](super::OrdinatesOperator::state_cells):
/// a cloud's is a tenth of this). The 64 × 64 × 48 transport grid of the large samples takes
/// 384 bins (75.5 M; 78 s and 516 MiB for the 192 × 192 × 144 cloud, docs/performance.md), a
/// 48 × 48 × 36 one 600, a 40 × 40 × 30 one 864, one of 96 × 96 × 72 keeps 96. Past it the
/// bins stay where the sweeps' work stays bounded (never under 96, whose cost the memory
/// check reports).
pub const AUTO_BINS_MAX_CELL_BINS: usize = 80 << 20;

/// The sweeps' work of `bins` bins on `cells` transport cells as [`AUTO_BINS_MAX_CELL_BINS`]
/// counts it: cells × bins, each cell-bin above 384 bins weighted `(bins / 384)^¼` because
/// the scattering product (bins² per cell) takes a growing share: 864 bins cost 1.24× per
/// cell-bin what 384 do (the cloud24 at g = 0.85: 10.3 s against 3.7 s for 2.25× the bins).
pub fn auto_bins_work(cells: usize, bins: usize) -> f64 {
    let weight = (bins as f64 / 384.0).max(1.0).powf(0.25);
    cells as f64 * bins as f64 * weight
}

/// The bin count volrad chooses for a medium whose phase function has mean cosine
/// `mean_cosine`, swept on `cells` transport cells: the steps of [`AUTO_BIN_STEPS`] by the
/// forward peak, the largest whose work ([`auto_bins_work`]) stays within
/// [`AUTO_BINS_MAX_CELL_BINS`], 96 at least.
pub fn auto_bin_count(mean_cosine: f64, cells: usize) -> usize {
    let wanted = if mean_cosine <= AUTO_BINS_ISOTROPIC_BELOW {
        AUTO_BIN_STEPS[0]
    } else if mean_cosine <= AUTO_BINS_MODERATE_UP_TO {
        AUTO_BIN_STEPS[1]
    } else {
        AUTO_BIN_STEPS[AUTO_BIN_STEPS.len() - 1]
    };
    AUTO_BIN_STEPS
        .into_iter()
        .rev()
        .filter(|&b| b <= wanted)
        .find(|&b| auto_bins_work(cells, b) <= AUTO_BINS_MAX_CELL_BINS as f64)
        .unwrap_or(AUTO_BIN_STEPS[0])
}

/// Largest face subdivision supported (`6·12² = 864` bins).
pub const MAX_FACE_DIVISIONS: usize = 12;

/// `atan(x y / (d √(x² + y² + d²)))`: the corner function whose signed sum over the four
/// corners of a rectangle on the plane at distance `d` is the rectangle's solid angle.
#[inline]
fn corner(x: f64, y: f64, d: f64) -> f64 {
    (x * y / (d * (x * x + y * y + d * d).sqrt())).atan()
}

/// Exact solid angle of the rectangle `[u1,u2] × [v1,v2]` on the plane at distance `d`,
/// seen from the origin.
pub fn rectangle_solid_angle(u1: f64, u2: f64, v1: f64, v2: f64, d: f64) -> f64 {
    corner(u2, v2, d) - corner(u1, v2, d) - corner(u2, v1, d) + corner(u1, v1, d)
}

/// A rectangle on one cube face, in the face's `(u, v)` coordinates.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FaceRect {
    pub face: usize,
    pub u: [f64; 2],
    pub v: [f64; 2],
}

impl FaceRect {
    /// The face's axis, sign and the axes of `u` and `v`.
    #[inline]
    pub fn frame(face: usize) -> (usize, f64, usize, usize) {
        let axis = face / 2;
        let sign = if face.is_multiple_of(2) { 1.0 } else { -1.0 };
        (axis, sign, (axis + 1) % 3, (axis + 2) % 3)
    }

    /// The (unnormalised) point `(u, v)` on the face.
    #[inline]
    pub fn point(&self, u: f64, v: f64) -> DVec3 {
        let (axis, sign, ua, va) = Self::frame(self.face);
        let mut p = [0.0; 3];
        p[axis] = sign;
        p[ua] = u;
        p[va] = v;
        DVec3::from_array(p)
    }

    pub fn solid_angle(&self) -> f64 {
        rectangle_solid_angle(self.u[0], self.u[1], self.v[0], self.v[1], 1.0)
    }

    /// `k × k` midpoint quadrature over the cone: unit directions at sub-square centres with
    /// their exact sub-square solid angles as weights (the weights sum exactly to the
    /// rectangle's solid angle).
    pub fn quadrature(&self, k: usize, out: &mut Vec<(DVec3, f64)>) {
        let k = k.max(1);
        let du = (self.u[1] - self.u[0]) / k as f64;
        let dv = (self.v[1] - self.v[0]) / k as f64;
        for a in 0..k {
            let u1 = self.u[0] + a as f64 * du;
            for b in 0..k {
                let v1 = self.v[0] + b as f64 * dv;
                let w = rectangle_solid_angle(u1, u1 + du, v1, v1 + dv, 1.0);
                let dir = self.point(u1 + 0.5 * du, v1 + 0.5 * dv).normalize();
                out.push((dir, w));
            }
        }
    }
}

/// A set of `6·n²` direction bins covering the sphere.
#[derive(Clone, Debug, PartialEq)]
pub struct DirectionBins {
    n: usize,
    rects: Vec<FaceRect>,
    solid_angles: Vec<f64>,
    centres: Vec<DVec3>,
    diffusion_loss: f64,
}

/// Sub-squares per side used to compute bin centres.
const CENTRE_QUADRATURE: usize = 32;

impl DirectionBins {
    /// The set of `count` bins: `count` must be `6 n²` with `1 ≤ n ≤ 12` ([`VALID_BINS`]).
    pub fn with_count(count: usize) -> Result<Self, OrdinatesError> {
        let n = (1..=MAX_FACE_DIVISIONS)
            .find(|n| 6 * n * n == count)
            .ok_or(OrdinatesError::BinCount(count))?;
        Self::cube(n)
    }

    /// The `6·n²` bins of an `n × n × n` block of cubes, `1 ≤ n ≤ 12`.
    pub fn cube(n: usize) -> Result<Self, OrdinatesError> {
        if !(1..=MAX_FACE_DIVISIONS).contains(&n) {
            return Err(OrdinatesError::FaceDivisions(n));
        }
        let mut rects = Vec::with_capacity(6 * n * n);
        let step = 2.0 / n as f64;
        for face in 0..6 {
            for i in 0..n {
                for j in 0..n {
                    // Edges from integers so that neighbouring squares share exact values.
                    let u = [-1.0 + i as f64 * step, -1.0 + (i + 1) as f64 * step];
                    let v = [-1.0 + j as f64 * step, -1.0 + (j + 1) as f64 * step];
                    rects.push(FaceRect { face, u, v });
                }
            }
        }
        let solid_angles: Vec<f64> = rects.iter().map(FaceRect::solid_angle).collect();
        let mut q = Vec::new();
        // ∫_bin ω dω per bin: its direction is the centre, its length what the bin keeps of
        // the second moment.
        let first_moments: Vec<DVec3> = rects
            .iter()
            .map(|r| {
                q.clear();
                r.quadrature(CENTRE_QUADRATURE, &mut q);
                q.iter().fold(DVec3::ZERO, |acc, &(d, w)| acc + d * w)
            })
            .collect();
        let kept: f64 = first_moments
            .iter()
            .zip(&solid_angles)
            .map(|(m, omega)| m.length_squared() / omega)
            .sum();
        Ok(DirectionBins {
            n,
            rects,
            solid_angles,
            centres: first_moments.iter().map(|m| m.normalize()).collect(),
            diffusion_loss: 1.0 - kept / (4.0 * std::f64::consts::PI),
        })
    }

    /// Max's 96 bins (the 16 squares on each face of a 4×4×4 block of cubes).
    pub fn max96() -> Self {
        Self::cube(4).expect("n = 4 is in range")
    }

    /// Squares per face side.
    pub fn face_divisions(&self) -> usize {
        self.n
    }

    /// Number of bins `M = 6 n²`.
    pub fn len(&self) -> usize {
        self.rects.len()
    }

    pub fn is_empty(&self) -> bool {
        self.rects.is_empty()
    }

    /// Exact solid angles `Ω_l`; they sum to 4π.
    pub fn solid_angles(&self) -> &[f64] {
        &self.solid_angles
    }

    /// Bin centres: the normalised solid-angle-weighted mean direction `∫_bin ω dω / |…|`.
    pub fn centres(&self) -> &[DVec3] {
        &self.centres
    }

    /// The fraction of the diffusion coefficient that radiance constant over each bin loses:
    /// `1 − Σ_l |m_l|² / (4π Ω_l)` with `m_l = ∫_bin ω dω`. The current such a field carries
    /// for a gradient of the fluence is `Σ_l m_l m_lᵀ / Ω_l` times it, against `∫ ω ωᵀ dω =
    /// 4π/3 I` for the continuous field (by symmetry of the cube's bins the tensor is a
    /// multiple of `I`): 2.4 % for Max's 96 bins, 1.1 % for 216, 0.6 % for 384.
    /// [`OrdinatesOptions::match_diffusion`](super::OrdinatesOptions::match_diffusion) makes
    /// it up.
    pub fn diffusion_loss(&self) -> f64 {
        self.diffusion_loss
    }

    /// The face rectangle of bin `l`.
    pub fn rect(&self, l: usize) -> FaceRect {
        self.rects[l]
    }

    /// The bin containing `direction` (any non-zero length). Points on a shared boundary go
    /// to the bin with the larger index along `u`/`v` and the lowest axis among tied faces.
    pub fn bin_of(&self, direction: DVec3) -> usize {
        let a = direction.abs().to_array();
        let axis = if a[0] >= a[1] && a[0] >= a[2] {
            0
        } else if a[1] >= a[2] {
            1
        } else {
            2
        };
        let d = direction.to_array();
        let face = 2 * axis + usize::from(d[axis] < 0.0);
        let (_, _, ua, va) = FaceRect::frame(face);
        let m = a[axis].max(f64::MIN_POSITIVE);
        let cell = |x: f64| {
            (((x / m + 1.0) * 0.5 * self.n as f64).floor().max(0.0) as usize).min(self.n - 1)
        };
        face * self.n * self.n + cell(d[ua]) * self.n + cell(d[va])
    }
}

/// Bilinear interpolation weights between the bin centres of the face that `w` (non-zero)
/// points through, for `n` divisions per face side: `(bin, weight)` pairs summing to 1.
/// The centres are taken at the squares' midpoints in face coordinates (the true
/// solid-angle-weighted centres are within a fraction of a bin); between a face's outer
/// centres and its edges, linear extrapolation from the two outer centres.
#[inline]
pub fn face_bilinear(n: usize, w: DVec3) -> [(usize, f64); 4] {
    let a = w.abs();
    let axis = if a.x >= a.y && a.x >= a.z {
        0
    } else if a.y >= a.z {
        1
    } else {
        2
    };
    let face = 2 * axis + usize::from(w[axis] < 0.0);
    let (_, _, ua, va) = FaceRect::frame(face);
    let inv = 1.0 / a[axis];
    let base = face * n * n;
    if n == 1 {
        return [(base, 1.0), (base, 0.0), (base, 0.0), (base, 0.0)];
    }
    // Continuous coordinates with centres at integers; beyond the outer centres (near a
    // face edge) the outer pair extrapolates linearly rather than holding the edge value.
    let s = (w[ua] * inv + 1.0) * 0.5 * n as f64 - 0.5;
    let t = (w[va] * inv + 1.0) * 0.5 * n as f64 - 0.5;
    let (i0, j0) = (
        (s.floor().max(0.0) as usize).min(n - 2),
        (t.floor().max(0.0) as usize).min(n - 2),
    );
    let (i1, j1) = (i0 + 1, j0 + 1);
    let (fs, ft) = (s - i0 as f64, t - j0 as f64);
    [
        (base + i0 * n + j0, (1.0 - fs) * (1.0 - ft)),
        (base + i0 * n + j1, (1.0 - fs) * ft),
        (base + i1 * n + j0, fs * (1.0 - ft)),
        (base + i1 * n + j1, fs * ft),
    ]
}

/// A per-bin field of one cell looked up towards unit `w` between the bin centres of one cube
/// face ([`face_bilinear`]), as volrad's renderer reads the final gather's source: geometric
/// (bilinear in `ln`) between four positive centres, linear next to a zero centre and towards
/// a face's edges (extrapolated; never below 0). `value(l)` is bin `l`'s value and `ln(l)`
/// its logarithm (−∞ for 0; a caller that looks up one field often keeps them).
///
/// Why geometric: the gathered source of a forward-scattering medium falls off steeply with
/// the angle from the light, and linear interpolation of such a convex function overshoots
/// between centres (on the g = 0.85 cloud seen from 8 sides, back-lit views up to 2.5 points
/// too bright); an exponential fall-off is interpolated exactly in `ln`. Extrapolation stays
/// linear: `ln`-extrapolating a peak would grow without bound.
#[inline]
pub fn interpolate_bins(
    n: usize,
    w: DVec3,
    value: impl Fn(usize) -> f64,
    ln: impl Fn(usize) -> f64,
) -> f64 {
    interpolate_with(&face_bilinear(n, w), value, ln)
}

/// [`interpolate_bins`] with the direction's [`face_bilinear`] weights computed once (a
/// renderer looking one direction up in several cells).
#[inline]
pub fn interpolate_with(
    weights: &[(usize, f64); 4],
    value: impl Fn(usize) -> f64,
    ln: impl Fn(usize) -> f64,
) -> f64 {
    if weights
        .iter()
        .all(|&(l, weight)| weight >= 0.0 && ln(l) > f64::NEG_INFINITY)
    {
        return weights
            .iter()
            .map(|&(l, weight)| weight * ln(l))
            .sum::<f64>()
            .exp();
    }
    weights
        .iter()
        .map(|&(l, weight)| weight * value(l))
        .sum::<f64>()
        .max(0.0)
}
