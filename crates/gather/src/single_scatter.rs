//! Single scattering (the first bounce) as an [`InScattering`] source, from a light pass:
//! `Q1(x, ω) = σs(x) Σ_l p(ω_l·ω) E_l T_l(x)`, with the medium's true phase function, the
//! light's flow direction `ω_l` and the view flow direction `ω = −ray.direction`.
//!
//! Along a view segment inside one cell the renderer needs `∫ e^{−σt (t−t0)} Q1 dt`. For a
//! directional light with shadows this is one closed form per piece of a trilinear depth
//! lattice ([`crate::light_depth`]; the phase factor `p(ω_l·ω) E_l` and the light at the
//! segment's end ride along the ray in the [`RayCarry`]). Otherwise (point and spot lights,
//! "Utah", gradient shading, or [`LightDepth::ExitFace`]) `T_l` inside a cell is the exit-face
//! value times `e^{−σt d(x)}`, so the integrand is close to one exponential `e^{−λ (t−t0)}`
//! with `λ = σt (1 + ∂d/∂t)`; the integral is taken by Gauss–Legendre in the variable
//! `u = (1 − e^{−λ(t−t0)})/λ`, which absorbs that exponential exactly: a thick cell is then
//! integrated as accurately as a thin one. Without shadows ("Utah", `T_L ≡ 1`) `λ = σt`.
//! The point samples of a `trilinear` render ([`InScattering::at`]) take `T_l` from the same
//! lattice where the light has one (continuous across cell faces), else the exit-face model.
//!
//! Optional gradient shading (Max eq. 11) adds `strength · max(∇f·ω′, 0) · E_l T_l` per light,
//! `ω′` the direction toward the light and `∇f` the central-difference gradient of the
//! medium's `data` (per cell).

use glam::DVec3;
use medium::light_pass::LightPass;
use medium::traversal::Ray;
use medium::{Light, Medium, PhaseFunction};

use std::borrow::Cow;

use crate::exponential::exp;
use crate::light_depth::{DepthLattice, LightAt};
pub use crate::light_depth::{LightDepth, LightDepthModel, TRILINEAR_CELL_MEAN_TOLERANCE};
use crate::scattering::{each_step, InScattering, RayCarry, StepSample, ViewSegment};
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
    /// How each light's depth varies inside a cell (built here, or shared by the caller).
    depth: Cow<'a, LightDepthModel>,
    /// Per-cell `∇f` of the data (gradient shading only).
    gradient: Vec<DVec3>,
    max_source: f64,
    /// Every light takes the lattice path ([`SingleScatter::lattice_segment`]).
    lattices_only: bool,
    /// The medium is reconstructed trilinearly: `at` takes σs from the interpolated σt.
    trilinear: bool,
    /// The CPU has FMA: the lattice path runs [`SingleScatter::lattice_segment_fma`].
    fma: bool,
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
    /// `pass` must be the light pass of `medium.channels[channel]`. Builds the light-depth
    /// model that `options.light_depth` asks for (see [`SingleScatter::with_depth_model`] to
    /// share one across renders).
    pub fn new(
        medium: &'a Medium,
        channel: usize,
        pass: &'a LightPass,
        options: SingleScatterOptions,
    ) -> Result<Self, GatherError> {
        // Unshadowed ("Utah") light has no depth to model.
        let policy = if options.shadows {
            options.light_depth
        } else {
            LightDepth::ExitFace
        };
        let depth = LightDepthModel::build(pass, policy)?;
        Self::build(medium, channel, pass, options, Cow::Owned(depth))
    }

    /// As [`SingleScatter::new`] with a light-depth model built once for `pass` (by
    /// [`LightDepthModel::build`]); `options.light_depth` is not consulted.
    pub fn with_depth_model(
        medium: &'a Medium,
        channel: usize,
        pass: &'a LightPass,
        options: SingleScatterOptions,
        depth: &'a LightDepthModel,
    ) -> Result<Self, GatherError> {
        Self::build(medium, channel, pass, options, Cow::Borrowed(depth))
    }

    fn build(
        medium: &'a Medium,
        channel: usize,
        pass: &'a LightPass,
        options: SingleScatterOptions,
        depth: Cow<'a, LightDepthModel>,
    ) -> Result<Self, GatherError> {
        let ch = medium.channels().get(channel).ok_or_else(|| {
            GatherError::Render(format!(
                "channel {channel} requested of a medium with {}",
                medium.channels().len()
            ))
        })?;
        // The medium is valid by construction; a light pass (public fields) is not, and must
        // be for this grid, with one σt per cell.
        if pass.grid != *medium.grid() || pass.sigma_t.len() != pass.grid.cell_count() {
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
            Some(_) => match &medium.data() {
                Some(data) => data_gradient(medium.grid(), data),
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
        let per_irradiance = max_sigma_s * phase_max(&medium.phase()) + gradient_max;
        // No scatterers means no source, even next to a point light (0 × ∞).
        let max_source = if per_irradiance == 0.0 {
            0.0
        } else {
            max_irradiance * per_irradiance
        };
        let lattices_only = options.shadows
            && options.gradient_strength.is_none()
            && pass.fields.len() <= CARRIED_LIGHTS
            && (0..pass.fields.len()).all(|l| depth.lattice(l).is_some());
        Ok(SingleScatter {
            trilinear: medium.interpolation() == medium::Interpolation::Trilinear,
            lattices_only,
            fma: medium::fma::available(),
            pass,
            sigma_t: &ch.sigma_t,
            albedo: &ch.albedo,
            phase: medium.phase(),
            options,
            depth,
            gradient,
            max_source,
        })
    }

    /// `Q1` at `x` in `cell` with extinction `sigma_t` there: every light's first bounce.
    #[inline]
    fn source_at(&self, x: DVec3, cell: usize, view_flow_dir: DVec3, sigma_t: f64) -> f64 {
        let coords = self.pass.grid.coords(cell);
        self.source_at_with::<false>(x, cell, coords, view_flow_dir, sigma_t)
    }

    /// [`SingleScatter::source_at`] in the cell at `coords`, the `exp`s as [`exp`]`::<FMA>`.
    #[inline(always)]
    fn source_at_with<const FMA: bool>(
        &self,
        x: DVec3,
        cell: usize,
        coords: [usize; 3],
        view_flow_dir: DVec3,
        sigma_t: f64,
    ) -> f64 {
        let sigma_s = sigma_t * self.albedo.get(cell) as f64;
        (0..self.pass.fields.len())
            .map(|l| self.source_from_with::<FMA>(l, x, cell, coords, view_flow_dir, sigma_s))
            .sum()
    }

    /// [`SingleScatter::source_from`] in the cell at `coords`, the `exp` as [`exp`]`::<FMA>`:
    /// light `l`'s first bounce, [`SingleScatter::light_at_with`] through
    /// [`SingleScatter::source_of`].
    #[inline(always)]
    fn source_from_with<const FMA: bool>(
        &self,
        l: usize,
        x: DVec3,
        cell: usize,
        coords: [usize; 3],
        view_flow_dir: DVec3,
        sigma_s: f64,
    ) -> f64 {
        let (flow, e) = self.light_at_with::<FMA>(l, x, cell, coords);
        self.source_of(flow, e, cell, view_flow_dir, sigma_s)
    }

    /// [`InScattering::at_step`] compiled with FMA (the light's `exp` inlined).
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "fma")]
    fn at_step_fma(&self, step: &StepSample, view_flow_dir: DVec3) -> f64 {
        self.source_at_with::<true>(
            step.x,
            step.corners.cell(),
            step.corners.coords(),
            view_flow_dir,
            step.sigma_t_from(self.sigma_t),
        )
    }

    /// [`InScattering::at_step_pair`] of a shadowed `trilinear` first bounce. A light on a
    /// depth lattice (a directional one) has the same direction and irradiance at both
    /// steps, and of `T_L` only the depths are read at each: one `exp` at their mean and a
    /// short series for the half difference give both transmittances (exact to about 1e-9
    /// where the depths differ by ≤ 0.2; a second `exp` beyond). Other lights, each step.
    #[inline(always)]
    fn pair_with<const FMA: bool>(
        &self,
        steps: &[StepSample; 2],
        view_flow_dir: DVec3,
    ) -> [f64; 2] {
        let [a, b] = steps;
        let (cell_a, cell_b) = (a.corners.cell(), b.corners.cell());
        let sigma_s_a = a.sigma_t_from(self.sigma_t) * self.albedo.get(cell_a) as f64;
        let sigma_s_b = b.sigma_t_from(self.sigma_t) * self.albedo.get(cell_b) as f64;
        let mut q = [0.0; 2];
        for (l, lattice) in self.depth.lattices().enumerate() {
            let Some(lattice) = lattice else {
                for (k, (s, sigma_s)) in [(a, sigma_s_a), (b, sigma_s_b)].into_iter().enumerate() {
                    let (cell, coords) = (s.corners.cell(), s.corners.coords());
                    q[k] +=
                        self.source_from_with::<FMA>(l, s.x, cell, coords, view_flow_dir, sigma_s);
                }
                continue;
            };
            let (flow, e) = self.pass.unshadowed_at(l, a.x);
            if e == 0.0 {
                continue;
            }
            let depth_a = lattice.depth_at_with::<FMA>(a.x, a.corners.coords());
            let depth_b = lattice.depth_at_with::<FMA>(b.x, b.corners.coords());
            let mean = exp::<FMA>(-0.5 * (depth_a + depth_b));
            let half = 0.5 * (depth_b - depth_a);
            let ratio = if half.abs() <= 0.1 {
                // e^{half} to within half⁶/720 ≈ 1.4e-9.
                1.0 + half
                    * (1.0 + half * (0.5 + half * (1.0 / 6.0 + half * (1.0 / 24.0 + half / 120.0))))
            } else {
                exp::<FMA>(half)
            };
            q[0] += self.source_of(flow, e * mean * ratio, cell_a, view_flow_dir, sigma_s_a);
            q[1] += self.source_of(flow, e * mean / ratio, cell_b, view_flow_dir, sigma_s_b);
        }
        q
    }

    /// [`SingleScatter::pair_with`] compiled with FMA.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "fma")]
    fn pair_fma(&self, steps: &[StepSample; 2], view_flow_dir: DVec3) -> [f64; 2] {
        self.pair_with::<true>(steps, view_flow_dir)
    }

    /// Light `l`'s flow direction and irradiance (times `T_L` with shadows) at `x` in the
    /// cell at `coords`, the `exp` as [`exp`]`::<FMA>`. A `trilinear` render takes `T_L` from
    /// the light's depth lattice where it has one, as the `nearest` segments do: the lattice
    /// is continuous across cell faces (the exit-face model is not, where σt changes steeply
    /// from cell to cell) and the more accurate of the two.
    #[inline(always)]
    fn light_at_with<const FMA: bool>(
        &self,
        l: usize,
        x: DVec3,
        cell: usize,
        coords: [usize; 3],
    ) -> (DVec3, f64) {
        if self.options.shadows {
            if let Some(lattice) = self.depth.lattice(l).filter(|_| self.trilinear) {
                let (flow, e) = self.pass.unshadowed_at(l, x);
                let depth = lattice.depth_at_with::<FMA>(x, coords);
                return (flow, e * exp::<FMA>(-depth));
            }
            self.pass.irradiance_at(l, x, cell)
        } else {
            self.pass.unshadowed_at(l, x)
        }
    }

    /// Light `l`'s contribution to the source at `x` for view flow `w`.
    #[inline]
    fn source_from(&self, l: usize, x: DVec3, cell: usize, w: DVec3, sigma_s: f64) -> f64 {
        let coords = self.pass.grid.coords(cell);
        self.source_from_with::<false>(l, x, cell, coords, w, sigma_s)
    }

    /// The source from light flowing along `flow` with irradiance `e` (shadowed) at a point of
    /// `cell` with scattering coefficient `sigma_s`, for view flow `w`.
    #[inline(always)]
    fn source_of(&self, flow: DVec3, e: f64, cell: usize, w: DVec3, sigma_s: f64) -> f64 {
        if e == 0.0 {
            return 0.0;
        }
        let mut q = sigma_s * self.phase.eval(flow.dot(w));
        if let Some(strength) = self.options.gradient_strength {
            q += strength * self.gradient[cell].dot(-flow).max(0.0);
        }
        q * e
    }

    /// `p(ω_l·ω) E_l` for directional light `l` and the view flow `ω = −ray.direction`: the
    /// same all along a ray.
    #[inline]
    fn directional_factor(&self, l: usize, ray: &Ray) -> f64 {
        match self.pass.fields[l].light {
            Light::Directional {
                direction,
                irradiance,
            } => self.phase.eval(direction.dot(-ray.direction)) * irradiance,
            _ => 0.0,
        }
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

impl SingleScatter<'_> {
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

/// Lights whose depth, transmittance and phase factor ride along a ray in the [`RayCarry`]:
/// slots `3l`, `3l + 1` hold `d` and `T_L` at the carry's `t`, slot `3l + 2` the per-ray
/// `p(ω_l·ω) E_l`.
const CARRIED_LIGHTS: usize = RayCarry::SLOTS / 3;

impl SingleScatter<'_> {
    /// The segment when every light has a depth lattice (shadows on, no gradient shading, at
    /// most [`CARRIED_LIGHTS`]): the common case, kept small so that it stays fast.
    #[inline(always)]
    fn lattice_segment<const FMA: bool>(&self, seg: &ViewSegment, carry: &mut RayCarry) -> f64 {
        if seg.t1 <= seg.t0 {
            return 0.0;
        }
        let sigma_s = self.sigma_t[seg.cell] as f64 * self.albedo.get(seg.cell) as f64;
        if sigma_s == 0.0 {
            return 0.0;
        }
        let claim = carry.claim(self as *const Self as usize);
        let (held, holds) = (claim == Some(true), claim.is_some());
        let continues = held && carry.t == seg.t0;
        let mut total = 0.0;
        for (l, lattice) in self.depth.lattices().enumerate() {
            if let Some(lattice) = lattice {
                total += self.lattice_light::<FMA>(l, lattice, seg, carry, held, holds, continues);
            }
        }
        if holds {
            carry.t = seg.t1;
        }
        sigma_s * total
    }

    /// Light `l`'s `p(ω_l·ω) E_l ∫ e^{−σt (t−t0)} T_L dt` over the segment from its lattice
    /// (times σs by the caller). `held`: the carry holds this ray's values; `carried`: light
    /// `l` may keep its values there; `continues`: the previous segment ended at `t0`.
    #[inline(always)]
    #[allow(clippy::too_many_arguments)]
    fn lattice_light<const FMA: bool>(
        &self,
        l: usize,
        lattice: &DepthLattice,
        seg: &ViewSegment,
        carry: &mut RayCarry,
        held: bool,
        carried: bool,
        continues: bool,
    ) -> f64 {
        let factor = if carried && held {
            carry.values[3 * l + 2]
        } else {
            let f = self.directional_factor(l, seg.ray);
            if carried {
                carry.values[3 * l + 2] = f;
            }
            f
        };
        let start = (continues && carried).then(|| LightAt {
            depth: carry.values[3 * l],
            transmittance: carry.values[3 * l + 1],
        });
        let (integral, end) = lattice.segment_body::<FMA>(seg, start);
        if carried {
            carry.values[3 * l] = end.depth;
            carry.values[3 * l + 1] = end.transmittance;
        }
        factor * integral
    }

    /// [`SingleScatter::lattice_segment`] compiled with FMA, the lattice's walk inlined into it
    /// (fused interpolation, inlined `exp`; the last bits differ from the portable build's).
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "fma")]
    fn lattice_segment_fma(&self, seg: &ViewSegment, carry: &mut RayCarry) -> f64 {
        self.lattice_segment::<true>(seg, carry)
    }

    /// Every other case: lights without lattices (point, spot, exit face), "Utah", gradient
    /// shading. Kept out of line so its bulk does not slow the lattice path.
    #[inline(never)]
    fn general_segment(&self, seg: &ViewSegment, carry: &mut RayCarry) -> f64 {
        let (cell, ray, t0, t1, sigma_t) = (seg.cell, seg.ray, seg.t0, seg.t1, seg.sigma_t);
        if t1 <= t0 {
            return 0.0;
        }
        let sigma_s = self.sigma_t[cell] as f64 * self.albedo.get(cell) as f64;
        if sigma_s == 0.0 && self.options.gradient_strength.is_none() {
            return 0.0;
        }
        let owner = self as *const Self as usize;
        // `held`: values from an earlier segment of this ray are ours; `holds`: we may write.
        let claim = carry.claim(owner);
        let (held, holds) = (claim == Some(true), claim.is_some());
        let continues = held && carry.t == t0;
        // Shadowed, no gradient shading: lattice lights take the closed-form segment.
        let lattice_path = self.options.shadows && self.options.gradient_strength.is_none();
        let mut total = 0.0;
        for l in 0..self.pass.fields.len() {
            // Only directional lights have lattices.
            if let Some(lattice) = self.depth.lattice(l).filter(|_| lattice_path) {
                let carried = holds && l < CARRIED_LIGHTS;
                total += sigma_s
                    * self.lattice_light::<false>(l, lattice, seg, carry, held, carried, continues);
                continue;
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
                            Light::Directional { .. }
                                if self.options.gradient_strength.is_none() =>
                            {
                                sigma_s
                                    * self.directional_factor(l, ray)
                                    * self.directional_piece(l, cell, ray, a, b, sigma_t)
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
        if holds {
            carry.t = t1;
        }
        total
    }
}

impl InScattering for SingleScatter<'_> {
    #[inline]
    fn segment(&self, seg: &ViewSegment, carry: &mut RayCarry) -> f64 {
        if self.lattices_only {
            #[cfg(target_arch = "x86_64")]
            if self.fma {
                // SAFETY: `fma` is set only where the CPU has FMA.
                return unsafe { self.lattice_segment_fma(seg, carry) };
            }
            self.lattice_segment::<false>(seg, carry)
        } else {
            self.general_segment(seg, carry)
        }
    }

    fn at(&self, x: DVec3, cell: usize, view_flow_dir: DVec3) -> f64 {
        if self.trilinear {
            let step = StepSample::new(&self.pass.grid, self.sigma_t, x);
            return self.at_step(&step, view_flow_dir);
        }
        self.source_at(x, cell, view_flow_dir, self.sigma_t[cell] as f64)
    }

    /// σs follows σt as the `trilinear` medium is reconstructed at x (the renderer's σt
    /// there, when it reads this medium's).
    #[inline]
    fn at_step(&self, step: &StepSample, view_flow_dir: DVec3) -> f64 {
        if !self.trilinear {
            return self.at(step.x, step.corners.cell(), view_flow_dir);
        }
        #[cfg(target_arch = "x86_64")]
        if self.fma {
            // SAFETY: `fma` is set only where the CPU has FMA.
            return unsafe { self.at_step_fma(step, view_flow_dir) };
        }
        let (cell, coords) = (step.corners.cell(), step.corners.coords());
        let sigma_t = step.sigma_t_from(self.sigma_t);
        self.source_at_with::<false>(step.x, cell, coords, view_flow_dir, sigma_t)
    }

    /// One `exp` for both steps per light on a depth lattice.
    #[inline]
    fn at_step_pair(&self, steps: &[StepSample; 2], view_flow_dir: DVec3) -> [f64; 2] {
        if !(self.trilinear && self.options.shadows) {
            return each_step(self, steps, view_flow_dir);
        }
        #[cfg(target_arch = "x86_64")]
        if self.fma {
            // SAFETY: `fma` is set only where the CPU has FMA.
            return unsafe { self.pair_fma(steps, view_flow_dir) };
        }
        self.pair_with::<false>(steps, view_flow_dir)
    }

    fn max_source(&self) -> f64 {
        self.max_source
    }

    fn is_zero(&self) -> bool {
        self.max_source == 0.0
    }
}
