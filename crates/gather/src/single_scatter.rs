//! Single scattering (the first bounce) as an [`InScattering`] source, from a light pass:
//! `Q1(x, ω) = σs(x) Σ_l p(ω_l·ω) E_l T_l(x)`, with the medium's true phase function, the
//! light's flow direction `ω_l` and the view flow direction `ω = −ray.direction`.
//!
//! Along a view segment inside one cell the renderer needs `∫ e^{−σt (t−t0)} Q1 dt`. Inside a
//! cell `T_l` is the exit-face value times `e^{−σt d(x)}`, so the integrand is close to one
//! exponential `e^{−λ (t−t0)}` with `λ = σt (1 + ∂d/∂t)`. The integral is taken by
//! Gauss–Legendre in the variable `u = (1 − e^{−λ(t−t0)})/λ`, which absorbs that
//! exponential exactly: a thick cell is then integrated as accurately as a thin one. Without
//! shadows ("Utah", `T_L ≡ 1`) `λ = σt`.
//!
//! Optional gradient shading (Max eq. 11) adds `strength · max(∇f·ω′, 0) · E_l T_l` per light,
//! `ω′` the direction toward the light and `∇f` the central-difference gradient of the
//! medium's `data` (per cell).

use glam::DVec3;
use medium::light_pass::LightPass;
use medium::traversal::Ray;
use medium::{Light, Medium, PhaseFunction};
use rayon::prelude::*;

use crate::scattering::InScattering;
use crate::GatherError;

/// Gauss–Legendre nodes and weights on `[−1, 1]`, for 1 to 6 nodes (tabulated digits).
#[allow(clippy::excessive_precision)]
const GAUSS_LEGENDRE: [&[(f64, f64)]; 6] = [
    &[(0.0, 2.0)],
    &[
        (-0.577_350_269_189_625_8, 1.0),
        (0.577_350_269_189_625_8, 1.0),
    ],
    &[
        (-0.774_596_669_241_483_4, 0.555_555_555_555_555_6),
        (0.0, 0.888_888_888_888_888_9),
        (0.774_596_669_241_483_4, 0.555_555_555_555_555_6),
    ],
    &[
        (-0.861_136_311_594_052_6, 0.347_854_845_137_453_9),
        (-0.339_981_043_584_856_3, 0.652_145_154_862_546_1),
        (0.339_981_043_584_856_3, 0.652_145_154_862_546_1),
        (0.861_136_311_594_052_6, 0.347_854_845_137_453_9),
    ],
    &[
        (-0.906_179_845_938_664, 0.236_926_885_056_189_1),
        (-0.538_469_310_105_683_1, 0.478_628_670_499_366_5),
        (0.0, 0.568_888_888_888_888_9),
        (0.538_469_310_105_683_1, 0.478_628_670_499_366_5),
        (0.906_179_845_938_664, 0.236_926_885_056_189_1),
    ],
    &[
        (-0.932_469_514_203_152, 0.171_324_492_379_170_3),
        (-0.661_209_386_466_264_5, 0.360_761_573_048_138_6),
        (-0.238_619_186_083_196_9, 0.467_913_934_572_691),
        (0.238_619_186_083_196_9, 0.467_913_934_572_691),
        (0.661_209_386_466_264_5, 0.360_761_573_048_138_6),
        (0.932_469_514_203_152, 0.171_324_492_379_170_3),
    ],
];

/// How the first bounce is evaluated.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SingleScatterOptions {
    /// `true`: shadowed (Kajiya & Von Herzen, `T_L` from the light pass); `false`: "Utah"
    /// (`T_L ≡ 1`).
    pub shadows: bool,
    /// Gauss–Legendre nodes per cell segment (1–6).
    pub nodes: usize,
    /// Gradient shading strength (Max eq. 11); `None` for none. Needs the medium's `data`.
    pub gradient_strength: Option<f64>,
    /// How `T_L` of a directional light varies inside a cell (point and spot lights always
    /// use [`LightDepth::ExitFace`]).
    pub light_depth: LightDepth,
}

/// [`LightDepth::Auto`] takes the trilinear model when its cell means of `T_L` match the
/// light pass's exact ones to this (extinction-weighted relative L1) error. The error and the
/// model chosen are logged at debug level (`RUST_LOG=gather=debug volrad render ...`).
pub const TRILINEAR_CELL_MEAN_TOLERANCE: f64 = 0.02;

/// A cell's eight corner optical depths toward one light, for trilinear interpolation.
/// Trilinear is continuous across cell faces (no seams between cells in an image) and exact
/// wherever the depth is linear, as in a homogeneous slab.
struct CellCornerDepths {
    /// The cell's lower corner in world space.
    lo: DVec3,
    /// `d[i + 2j + 4k]` at corner offset `(i, j, k)`.
    d: [f64; 8],
}

impl CellCornerDepths {
    #[inline]
    fn load(pass: &LightPass, l: usize, cell: usize) -> Self {
        let grid = &pass.grid;
        let [i, j, k] = grid.coords(cell);
        let sy = grid.dims[0] + 1;
        let sz = sy * (grid.dims[1] + 1);
        let c = grid.corner_index(i, j, k);
        let v = |o: usize| pass.fields[l].corner_optical_depth[c + o] as f64;
        CellCornerDepths {
            // From the coordinates already at hand: `cell_min` would divide again.
            lo: DVec3::new(i as f64, j as f64, k as f64) * grid.cell_size,
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

    /// The depth at fractional position `f` in the cell (clamped to it).
    #[inline]
    fn at(&self, f: DVec3) -> f64 {
        let f = f.clamp(DVec3::ZERO, DVec3::ONE);
        let d = &self.d;
        let x00 = d[0] + f.x * (d[1] - d[0]);
        let x10 = d[2] + f.x * (d[3] - d[2]);
        let x01 = d[4] + f.x * (d[5] - d[4]);
        let x11 = d[6] + f.x * (d[7] - d[6]);
        let y0 = x00 + f.y * (x10 - x00);
        let y1 = x01 + f.y * (x11 - x01);
        y0 + f.z * (y1 - y0)
    }
}

/// How far the trilinear corner model's cell means of `T_L` stray from the light pass's exact
/// cell averages (`cell_irradiance / E`) for directional light `l`: `Σ σt |T̄_model − T̄| /
/// Σ σt T̄` over the cells that extinguish. The model's mean is 2×2×2-point Gauss–Legendre.
/// Point and spot lights always use the exit-face model, so they count as 0.
fn trilinear_model_error(pass: &LightPass, l: usize) -> f64 {
    let field = &pass.fields[l];
    let Light::Directional { irradiance, .. } = field.light else {
        return 0.0;
    };
    if irradiance <= 0.0 {
        return 0.0;
    }
    let nodes = [0.5 - 0.5 / 3f64.sqrt(), 0.5 + 0.5 / 3f64.sqrt()];
    let (err, total) = pass
        .sigma_t
        .par_iter()
        .enumerate()
        .filter(|(_, &sigma)| sigma > 0.0)
        .map(|(cell, &sigma)| {
            let depths = CellCornerDepths::load(pass, l, cell);
            let mut mean = 0.0;
            for fz in nodes {
                for fy in nodes {
                    for fx in nodes {
                        mean += (-depths.at(DVec3::new(fx, fy, fz))).exp();
                    }
                }
            }
            let exact = field.cell_irradiance[cell] as f64 / irradiance;
            (
                sigma as f64 * (0.125 * mean - exact).abs(),
                sigma as f64 * exact,
            )
        })
        .reduce(|| (0.0, 0.0), |a, b| (a.0 + b.0, a.1 + b.1));
    if total > 0.0 {
        err / total
    } else {
        0.0
    }
}

/// The in-cell model of a directional light's optical depth, for `nearest` renders.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LightDepth {
    /// [`LightDepth::CornerTrilinear`] when its cell means of `T_L` reproduce the light
    /// pass's exact cell averages (within [`TRILINEAR_CELL_MEAN_TOLERANCE`]), else
    /// [`LightDepth::ExitFace`]: smooth, finely resolved media pass; coarse grids and
    /// white-noise densities, where `ln T_L` is far from linear inside a cell, do not. The
    /// test `auto_light_depth_stays_within_one_percent_of_exit_face` bounds the image error.
    Auto,
    /// Trilinear in the light pass's corner depths, linear along each view segment: one
    /// closed form per segment.
    CornerTrilinear,
    /// Bilinear on the face where the ray toward the light leaves the cell plus the exact
    /// in-cell attenuation, split where that face changes and integrated by Gauss–Legendre:
    /// about four times the work, for cells too thick for the trilinear model.
    ExitFace,
}

impl Default for SingleScatterOptions {
    fn default() -> Self {
        SingleScatterOptions {
            shadows: true,
            nodes: 3,
            gradient_strength: None,
            light_depth: LightDepth::Auto,
        }
    }
}

/// The first-bounce source for one colour channel.
pub struct SingleScatter<'a> {
    pass: &'a LightPass,
    sigma_t: &'a [f32],
    albedo: &'a medium::CellValues,
    phase: PhaseFunction,
    options: SingleScatterOptions,
    /// Per-cell `∇f` of the data (gradient shading only).
    gradient: Vec<DVec3>,
    max_source: f64,
}

/// Largest value of the phase function over `cos θ ∈ [−1, 1]` (ends plus a fine scan).
fn phase_max(phase: &PhaseFunction) -> f64 {
    (0..=400)
        .map(|i| phase.eval(-1.0 + i as f64 / 200.0))
        .fold(0.0, f64::max)
}

/// Central-difference gradient of `data` per cell (one-sided at the grid's faces).
fn data_gradient(grid: &medium::Grid, data: &[f32]) -> Vec<DVec3> {
    let dims = grid.dims;
    let h = grid.cell_size;
    (0..grid.cell_count())
        .map(|cell| {
            let c = grid.coords(cell);
            let mut g = DVec3::ZERO;
            for a in 0..3 {
                if dims[a] < 2 {
                    continue;
                }
                let (mut lo, mut hi) = (c, c);
                lo[a] = c[a].saturating_sub(1);
                hi[a] = (c[a] + 1).min(dims[a] - 1);
                let span = (hi[a] - lo[a]) as f64 * h;
                g[a] = (data[grid.index(hi[0], hi[1], hi[2])]
                    - data[grid.index(lo[0], lo[1], lo[2])]) as f64
                    / span;
            }
            g
        })
        .collect()
}

impl<'a> SingleScatter<'a> {
    /// `pass` must be the light pass of `medium.channels[channel]`.
    pub fn new(
        medium: &'a Medium,
        channel: usize,
        pass: &'a LightPass,
        options: SingleScatterOptions,
    ) -> Result<Self, GatherError> {
        let ch = medium.channels.get(channel).ok_or_else(|| {
            GatherError::Render(format!(
                "channel {channel} requested of a medium with {}",
                medium.channels.len()
            ))
        })?;
        if pass.grid != medium.grid || pass.sigma_t.len() != ch.sigma_t.len() {
            return Err(GatherError::Render(
                "the light pass was computed for a different grid".into(),
            ));
        }
        if !(1..=GAUSS_LEGENDRE.len()).contains(&options.nodes) {
            return Err(GatherError::Render(format!(
                "{} quadrature nodes per segment (1 to {} supported)",
                options.nodes,
                GAUSS_LEGENDRE.len()
            )));
        }
        let gradient = match options.gradient_strength {
            None => Vec::new(),
            Some(s) if !(s.is_finite() && s >= 0.0) => {
                return Err(GatherError::Render(format!(
                    "gradient shading strength {s} must be finite and ≥ 0"
                )))
            }
            Some(_) => match &medium.data {
                Some(data) => data_gradient(&medium.grid, data),
                None => {
                    return Err(GatherError::Render(
                        "gradient shading needs the medium's data values".into(),
                    ))
                }
            },
        };
        let max_sigma_s = (0..ch.sigma_t.len())
            .map(|i| ch.sigma_s(i) as f64)
            .fold(0.0, f64::max);
        let max_irradiance: f64 = (0..pass.fields.len()).map(|l| pass.max_irradiance(l)).sum();
        let gradient_max = options.gradient_strength.unwrap_or(0.0)
            * gradient.iter().map(|g| g.length()).fold(0.0, f64::max);
        let per_irradiance = max_sigma_s * phase_max(&medium.phase) + gradient_max;
        // No scatterers means no source, even next to a point light (0 × ∞).
        let max_source = if per_irradiance == 0.0 {
            0.0
        } else {
            max_irradiance * per_irradiance
        };
        let mut options = options;
        if options.light_depth == LightDepth::Auto {
            let worst = (0..pass.fields.len())
                .map(|l| trilinear_model_error(pass, l))
                .fold(0.0, f64::max);
            options.light_depth = if worst <= TRILINEAR_CELL_MEAN_TOLERANCE {
                LightDepth::CornerTrilinear
            } else {
                LightDepth::ExitFace
            };
            tracing::debug!(
                trilinear_cell_mean_error = worst,
                chosen = ?options.light_depth,
                "first-bounce light depth model"
            );
        }
        Ok(SingleScatter {
            pass,
            sigma_t: &ch.sigma_t,
            albedo: &ch.albedo,
            phase: medium.phase,
            options,
            gradient,
            max_source,
        })
    }

    /// Light `l`'s flow direction and irradiance (times `T_L` with shadows) at `x`.
    #[inline]
    fn light_at(&self, l: usize, x: DVec3, cell: usize) -> (DVec3, f64) {
        if self.options.shadows {
            self.pass.irradiance_at(l, x, cell)
        } else {
            self.pass.unshadowed_at(l, x)
        }
    }

    /// Light `l`'s contribution to the source at `x` for view flow `w`.
    #[inline]
    fn source_from(&self, l: usize, x: DVec3, cell: usize, w: DVec3, sigma_s: f64) -> f64 {
        let (flow, e) = self.light_at(l, x, cell);
        if e == 0.0 {
            return 0.0;
        }
        let mut q = sigma_s * self.phase.eval(flow.dot(w));
        if let Some(strength) = self.options.gradient_strength {
            q += strength * self.gradient[cell].dot(-flow).max(0.0);
        }
        q * e
    }

    /// The mean rate at which `−ln T_L` grows along the view ray over `[a, b]` (a piece with one
    /// exit face): the secant of the exact `ln T_L`, which is close to linear there (in-cell
    /// attenuation plus the log-bilinear face value of the light pass).
    fn log_transmittance_rate(&self, l: usize, cell: usize, ray: &Ray, a: f64, b: f64) -> f64 {
        let depth = |t: f64| self.pass.optical_depth_at(l, ray.at(t), cell);
        (depth(b) - depth(a)) / (b - a)
    }
}

/// `∫_0^len e^{−λ s} f(s) ds` by `nodes`-point Gauss–Legendre in `u = (1 − e^{−λ s})/λ`, which
/// absorbs the exponential exactly, so `f` need only be smooth.
#[inline]
fn exponential_quadrature(
    lambda: f64,
    len: f64,
    nodes: usize,
    mut f: impl FnMut(f64) -> f64,
) -> f64 {
    let flat = (lambda * len).abs() < 1e-9;
    let big_w = if flat {
        len
    } else {
        -(-lambda * len).exp_m1() / lambda
    };
    let mut sum = 0.0;
    for &(xi, wi) in GAUSS_LEGENDRE[nodes - 1] {
        let u = 0.5 * big_w * (xi + 1.0);
        let s = if flat {
            u
        } else {
            -(-lambda * u).ln_1p() / lambda
        };
        sum += wi * f(s.clamp(0.0, len));
    }
    0.5 * big_w * sum
}

/// `∫_0^len e^{−λ s} ds = (1 − e^{−λ len})/λ` for `λ` of either sign (a view ray running
/// toward the light sees `T_L` grow), by its series where `|λ len|` is tiny.
#[inline]
fn exponential_weight(lambda: f64, len: f64) -> f64 {
    let x = lambda * len;
    if x.abs() < 1e-6 {
        len * (1.0 - 0.5 * x)
    } else {
        -(-x).exp_m1() / lambda
    }
}

impl SingleScatter<'_> {
    /// `∫_{t0}^{t1} e^{−σt (t−t0)} T_L(ray(t)) dt` for directional light `l` over a whole
    /// cell segment, with `ln T_L` taken linear along the segment between its trilinear
    /// end values: one closed form, no quadrature.
    #[inline]
    fn directional_segment(
        &self,
        l: usize,
        cell: usize,
        ray: &Ray,
        t0: f64,
        t1: f64,
        sigma_t: f64,
    ) -> f64 {
        let len = t1 - t0;
        let depths = CellCornerDepths::load(self.pass, l, cell);
        let lo = depths.lo;
        let inv_h = 1.0 / self.pass.grid.cell_size;
        let (da, db) = (
            depths.at((ray.at(t0) - lo) * inv_h),
            depths.at((ray.at(t1) - lo) * inv_h),
        );
        (-da).exp() * exponential_weight(sigma_t + (db - da) / len, len)
    }

    /// `∫_a^b e^{−σt (t−a)} T_L(ray(t)) dt` for a directional light over a piece with one exit
    /// face. There `ln T_L` is exactly quadratic in `t` (linear in-cell attenuation plus the
    /// face's bilinear optical depth at an exit point moving linearly), so three evaluations
    /// fix it; the linear part is absorbed into the Gauss–Legendre variable and the quadratic
    /// remainder evaluated at the nodes. Three `transmittance_at` calls instead of five.
    #[inline]
    fn directional_piece(
        &self,
        l: usize,
        cell: usize,
        ray: &Ray,
        a: f64,
        b: f64,
        sigma_t: f64,
    ) -> f64 {
        let len = b - a;
        let ln_t = |t: f64| -self.pass.optical_depth_at(l, ray.at(t), cell);
        let (la, lm, lb) = (ln_t(a), ln_t(0.5 * (a + b)), ln_t(b));
        // ln T(a + s) = la − r s + c2 s (s − len).
        let r = (la - lb) / len;
        let c2 = 2.0 * (la - 2.0 * lm + lb) / (len * len);
        la.exp()
            * exponential_quadrature(sigma_t + r, len, self.options.nodes, |s| {
                (c2 * s * (s - len)).exp()
            })
    }

    /// `∫_a^b e^{−σt (t−a)} Q1_l(ray(t)) dt` by Gauss–Legendre in `u = (1 − e^{−λ(t−a)})/λ`,
    /// `λ = σt + extra` (`extra`: the rate of `−ln T_L` along the piece), putting back at each
    /// node the part of `e^{−λ(t−a)}` beyond `e^{−σt (t−a)}`.
    #[allow(clippy::too_many_arguments)]
    #[inline]
    fn piece(
        &self,
        l: usize,
        cell: usize,
        ray: &Ray,
        a: f64,
        b: f64,
        sigma_t: f64,
        sigma_s: f64,
        extra: f64,
    ) -> f64 {
        let w = -ray.direction;
        exponential_quadrature(sigma_t + extra, b - a, self.options.nodes, |s| {
            self.source_from(l, ray.at(a + s), cell, w, sigma_s) * (extra * s).exp()
        })
    }

    /// Points of `(t0, t1)` where the face through which the ray toward light `l` leaves
    /// `cell` changes (exact for directional light; for point lights the direction at the
    /// segment's midpoint stands in). At most three, sorted.
    fn exit_face_breaks(
        &self,
        l: usize,
        cell: usize,
        ray: &Ray,
        t0: f64,
        t1: f64,
    ) -> ([f64; 3], usize) {
        let to_light = match self.pass.fields[l].light {
            Light::Directional { direction, .. } => -direction,
            Light::Point { position, .. } | Light::Spot { position, .. } => {
                (position - ray.at(0.5 * (t0 + t1))).normalize_or_zero()
            }
        };
        let grid = &self.pass.grid;
        let lo = grid.cell_min(cell);
        let h = grid.cell_size;
        // Exit distance along each axis as α + β t.
        let mut lines = [(0.0, 0.0, false); 3];
        for a in 0..3 {
            let d = to_light[a];
            if d != 0.0 {
                let bound = if d > 0.0 { lo[a] + h } else { lo[a] };
                lines[a] = ((bound - ray.origin[a]) / d, -ray.direction[a] / d, true);
            }
        }
        let mut breaks = [0.0; 3];
        let mut count = 0;
        for (a, b) in [(0, 1), (0, 2), (1, 2)] {
            let ((aa, ba, ua), (ab, bb, ub)) = (lines[a], lines[b]);
            if ua && ub && ba != bb {
                let t = (ab - aa) / (ba - bb);
                if t > t0 && t < t1 {
                    breaks[count] = t;
                    count += 1;
                }
            }
        }
        breaks[..count].sort_by(f64::total_cmp);
        (breaks, count)
    }
}

impl InScattering for SingleScatter<'_> {
    fn segment(&self, cell: usize, ray: &Ray, t0: f64, t1: f64, sigma_t: f64) -> f64 {
        if t1 <= t0 {
            return 0.0;
        }
        let sigma_s = self.sigma_t[cell] as f64 * self.albedo.get(cell) as f64;
        if sigma_s == 0.0 && self.options.gradient_strength.is_none() {
            return 0.0;
        }
        let mut total = 0.0;
        for l in 0..self.pass.fields.len() {
            if let Light::Directional {
                direction,
                irradiance,
            } = self.pass.fields[l].light
            {
                if self.options.shadows
                    && self.options.gradient_strength.is_none()
                    && self.options.light_depth == LightDepth::CornerTrilinear
                {
                    let q = sigma_s * self.phase.eval(direction.dot(-ray.direction)) * irradiance;
                    total += q * self.directional_segment(l, cell, ray, t0, t1, sigma_t);
                    continue;
                }
            }
            if !self.options.shadows {
                total += self.piece(l, cell, ray, t0, t1, sigma_t, sigma_s, 0.0);
                continue;
            }
            // Split where the exit face toward the light changes: the exponential rate of
            // T_L changes there. A point light's direction turns along the segment, so its
            // breaks are found per sub-segment of optical length ≤ 1/2.
            let subs = match self.pass.fields[l].light {
                Light::Directional { .. } => 1,
                _ => ((self.sigma_t[cell] as f64 * (t1 - t0) * 2.0).ceil() as usize).clamp(1, 8),
            };
            for k in 0..subs {
                let sa = t0 + (t1 - t0) * k as f64 / subs as f64;
                let sb = if k + 1 == subs {
                    t1
                } else {
                    t0 + (t1 - t0) * (k + 1) as f64 / subs as f64
                };
                let (breaks, count) = self.exit_face_breaks(l, cell, ray, sa, sb);
                let mut a = sa;
                for &b in breaks[..count].iter().chain(std::iter::once(&sb)) {
                    if b > a {
                        let weight = (-sigma_t * (a - t0)).exp();
                        let part = match self.pass.fields[l].light {
                            Light::Directional {
                                direction,
                                irradiance,
                            } if self.options.gradient_strength.is_none() => {
                                let q = sigma_s
                                    * self.phase.eval(direction.dot(-ray.direction))
                                    * irradiance;
                                q * self.directional_piece(l, cell, ray, a, b, sigma_t)
                            }
                            _ => {
                                let rate = self.log_transmittance_rate(l, cell, ray, a, b);
                                self.piece(l, cell, ray, a, b, sigma_t, sigma_s, rate)
                            }
                        };
                        total += weight * part;
                        a = b;
                    }
                }
            }
        }
        total
    }

    fn at(&self, x: DVec3, cell: usize, view_flow_dir: DVec3) -> f64 {
        let sigma_s = self.sigma_t[cell] as f64 * self.albedo.get(cell) as f64;
        (0..self.pass.fields.len())
            .map(|l| self.source_from(l, x, cell, view_flow_dir, sigma_s))
            .sum()
    }

    fn max_source(&self) -> f64 {
        self.max_source
    }

    fn is_zero(&self) -> bool {
        self.max_source == 0.0
    }
}
