//! The scattered part of the source term, plugged into the renderer from outside.
//!
//! The renderer integrates `Q = e + Q_s` along each view ray. It owns the emission `e`; the
//! scattered part `Q_s(x, ω)` (single scattering, the multiple-scattering solution, ...) comes
//! through [`InScattering`], so new kinds of scattered light need no change to the renderer.
//!
//! Direction convention: light FLOWS toward the eye, along `−ray.direction`. That is the `ω`
//! to hand to phase functions (`cosθ = ω·ω'` with both directions of light flow).

use glam::DVec3;

use crate::render::Trilinear;
pub use medium::traversal::segment_weight;
use medium::traversal::{Ray, Segment};
use medium::Grid;

/// The part of a view ray inside one cell, as the renderer hands it to the sources, with the
/// segment's constant-source weight and attenuation already computed (one `exp` shared by
/// every source).
#[derive(Clone, Copy, Debug)]
pub struct ViewSegment<'r> {
    pub ray: &'r Ray,
    pub cell: usize,
    /// The cell's `[i, j, k]`.
    pub coords: [usize; 3],
    pub t0: f64,
    pub t1: f64,
    /// σt of the cell as the view ray sees it.
    pub sigma_t: f64,
    /// `∫_{t0}^{t1} e^{−σt (t−t0)} dt = (1 − e^{−σt Δs})/σt`.
    pub weight: f64,
    /// `e^{−σt Δs}`.
    pub attenuation: f64,
}

impl<'r> ViewSegment<'r> {
    /// A segment with its weight and attenuation computed here (the renderer computes them
    /// once for emission and every source).
    #[inline]
    pub fn new(ray: &'r Ray, segment: &Segment, sigma_t: f64) -> Self {
        Self::new_with::<false>(ray, segment, sigma_t)
    }

    /// [`ViewSegment::new`] with `exp` inlined for FMA-compiled callers (`FMA` true).
    #[inline(always)]
    pub(crate) fn new_with<const FMA: bool>(ray: &'r Ray, segment: &Segment, sigma_t: f64) -> Self {
        let (t0, t1) = (segment.t_enter, segment.t_exit);
        let (weight, attenuation) = weight_and_attenuation_with::<FMA>(sigma_t, t1 - t0);
        ViewSegment {
            ray,
            cell: segment.cell,
            coords: segment.coords,
            t0,
            t1,
            sigma_t,
            weight,
            attenuation,
        }
    }

    #[inline]
    pub fn length(&self) -> f64 {
        self.t1 - self.t0
    }
}

/// `((1 − e^{−τ})/σt, e^{−τ})` with `τ = σt Δs`, from one `exp`: the source weight of a
/// segment and its attenuation. Below τ = 1e-3 the weight comes from its series (four terms,
/// relative error < τ⁴/120 ≈ 1e-14) to avoid cancellation in `1 − e^{−τ}`.
#[inline]
pub fn weight_and_attenuation(sigma: f64, length: f64) -> (f64, f64) {
    weight_and_attenuation_with::<false>(sigma, length)
}

/// [`weight_and_attenuation`] with `exp` inlined for FMA-compiled callers (`FMA` true).
#[inline(always)]
pub(crate) fn weight_and_attenuation_with<const FMA: bool>(sigma: f64, length: f64) -> (f64, f64) {
    let tau = sigma * length;
    if tau <= 0.0 {
        return (length, 1.0);
    }
    let attenuation = crate::exponential::exp::<FMA>(-tau);
    let weight = if tau > 1e-3 {
        (1.0 - attenuation) / sigma
    } else {
        length * (1.0 - tau * (0.5 - tau * (1.0 / 6.0 - tau * (1.0 / 24.0))))
    };
    (weight, attenuation)
}

/// Per-ray scratch that one source may use to pass values from a segment to the next
/// (the first bounce keeps the light's transmittance at the segment's end, so the next
/// segment, which starts there, need not recompute it). The renderer starts each ray with
/// [`RayCarry::default`]. Sources that share a ray claim it by address, so two sources never
/// read each other's values.
#[derive(Clone, Copy, Debug)]
pub struct RayCarry {
    owner: usize,
    /// Where the values were taken (NaN: nowhere yet).
    pub t: f64,
    pub values: [f64; RayCarry::SLOTS],
}

impl Default for RayCarry {
    fn default() -> Self {
        RayCarry {
            owner: 0,
            t: f64::NAN,
            values: [0.0; RayCarry::SLOTS],
        }
    }
}

impl RayCarry {
    pub const SLOTS: usize = 12;

    /// Claims the carry for `owner` (any address unique to the source): `Some(true)` if it
    /// holds `owner`'s values from an earlier segment of this ray, `Some(false)` if it was
    /// empty and is now `owner`'s (`t` NaN), `None` if another source claimed it first (the
    /// caller then simply recomputes).
    #[inline]
    pub fn claim(&mut self, owner: usize) -> Option<bool> {
        if self.owner == owner {
            Some(true)
        } else if self.owner == 0 {
            self.owner = owner;
            self.t = f64::NAN;
            Some(false)
        } else {
            None
        }
    }
}

/// What a `trilinear` render finds at a step's midpoint, shared with the sources so they
/// need not find it again: the point, its cell-centred neighbours, and σt interpolated there
/// from the per-cell values the renderer reads.
pub struct StepSample<'a> {
    pub x: DVec3,
    pub corners: Trilinear,
    sigma_t: f64,
    /// The per-cell σt that `sigma_t` was interpolated from (empty: none).
    cells: &'a [f32],
}

impl<'a> StepSample<'a> {
    /// The sample at `x` of a `trilinear` medium whose extinction per cell is `sigma_t`.
    #[inline]
    pub fn new(grid: &Grid, sigma_t: &'a [f32], x: DVec3) -> Self {
        let corners = Trilinear::new(grid, x);
        let interpolated = corners.sample(|c| sigma_t[c] as f64);
        StepSample {
            x,
            corners,
            sigma_t: interpolated,
            cells: sigma_t,
        }
    }

    /// A sample whose σt, `sigma_t`, the caller interpolated from `cells` with `corners`.
    #[inline]
    pub(crate) fn interpolated(
        x: DVec3,
        corners: Trilinear,
        cells: &'a [f32],
        sigma_t: f64,
    ) -> Self {
        StepSample {
            x,
            corners,
            sigma_t,
            cells,
        }
    }

    /// σt at the point interpolated from the per-cell `cells`: the renderer's value when it
    /// read the same array (the usual case), else interpolated here — a view with rescaled
    /// extinction passes through another medium than the one the sources were solved in.
    #[inline]
    pub fn sigma_t_from(&self, cells: &[f32]) -> f64 {
        if std::ptr::eq(cells, self.cells) {
            self.sigma_t
        } else {
            self.corners.sample(|c| cells[c] as f64)
        }
    }
}

/// Scattered radiance per unit length, `Q_s(x, ω)`, for one colour channel.
///
/// `Q_s = σs · (in-scattered radiance)` vanishes where `σt = 0`, so the renderer never asks
/// about cells (or trilinear samples) with neither extinction nor emission, and skips empty
/// space wholesale.
pub trait InScattering: Sync {
    /// `∫_{t0}^{t1} e^{−σt (t−t0)} Q_s(ray(t), −ray.direction) dt` for the part of the ray
    /// inside one cell (σt constant there). The renderer multiplies by the transmittance from
    /// the eye to `t0`. Used by `nearest` renders, which integrate each cell exactly.
    /// `carry` lives for one ray: a source may keep what the next segment can reuse there.
    fn segment(&self, seg: &ViewSegment, carry: &mut RayCarry) -> f64;

    /// `Q_s` at point `x` (inside `cell`) for light flowing in direction `view_flow_dir`
    /// (`= −ray.direction`). Used by `trilinear` renders, which march in fixed steps.
    fn at(&self, x: DVec3, cell: usize, view_flow_dir: DVec3) -> f64;

    /// [`at`](Self::at) at a `trilinear` render's step, with what the renderer has already
    /// found there (the cell-centred neighbours and the interpolated σt): sources that
    /// reconstruct between cells use them instead of finding them again.
    #[inline]
    fn at_step(&self, step: &StepSample, view_flow_dir: DVec3) -> f64 {
        self.at(step.x, step.corners.cell(), view_flow_dir)
    }

    /// [`at_step`](Self::at_step) at two consecutive steps of a march in thin medium (the
    /// renderer's *quads*). A source may share what is the same at both (a directional
    /// light's `exp`, a lookup of the solved field); the default evaluates each step.
    #[inline]
    fn at_step_pair(&self, steps: &[StepSample; 2], view_flow_dir: DVec3) -> [f64; 2] {
        each_step(self, steps, view_flow_dir)
    }

    /// An upper bound on `Q_s` anywhere in the medium, for any direction. The renderer's
    /// early termination uses it to bound what the rest of a ray could still add; the default
    /// (infinity) makes the renderer fall back to stopping at a fixed transmittance.
    fn max_source(&self) -> f64 {
        f64::INFINITY
    }

    /// True when `Q_s ≡ 0`, so the renderer may skip calling this at all.
    fn is_zero(&self) -> bool {
        false
    }
}

/// [`InScattering::at_step`] at each of `steps`: the default of
/// [`InScattering::at_step_pair`], for sources that override it only in some cases.
#[inline]
pub fn each_step<S: InScattering + ?Sized>(
    source: &S,
    steps: &[StepSample; 2],
    w: DVec3,
) -> [f64; 2] {
    [source.at_step(&steps[0], w), source.at_step(&steps[1], w)]
}

/// No scattered light (emission/absorption models, or a medium with albedo 0).
impl InScattering for () {
    #[inline]
    fn segment(&self, _: &ViewSegment, _: &mut RayCarry) -> f64 {
        0.0
    }
    #[inline]
    fn at(&self, _: DVec3, _: usize, _: DVec3) -> f64 {
        0.0
    }
    fn max_source(&self) -> f64 {
        0.0
    }
    fn is_zero(&self) -> bool {
        true
    }
}

/// `None` is no scattered light.
impl<S: InScattering> InScattering for Option<S> {
    #[inline]
    fn segment(&self, seg: &ViewSegment, carry: &mut RayCarry) -> f64 {
        self.as_ref().map_or(0.0, |s| s.segment(seg, carry))
    }
    #[inline]
    fn at(&self, x: DVec3, cell: usize, w: DVec3) -> f64 {
        self.as_ref().map_or(0.0, |s| s.at(x, cell, w))
    }
    #[inline]
    fn at_step(&self, step: &StepSample, w: DVec3) -> f64 {
        self.as_ref().map_or(0.0, |s| s.at_step(step, w))
    }
    #[inline]
    fn at_step_pair(&self, steps: &[StepSample; 2], w: DVec3) -> [f64; 2] {
        self.as_ref().map_or([0.0; 2], |s| s.at_step_pair(steps, w))
    }
    fn max_source(&self) -> f64 {
        self.as_ref().map_or(0.0, |s| s.max_source())
    }
    fn is_zero(&self) -> bool {
        match self {
            None => true,
            Some(s) => s.is_zero(),
        }
    }
}

impl<S: InScattering + ?Sized> InScattering for &S {
    #[inline]
    fn segment(&self, seg: &ViewSegment, carry: &mut RayCarry) -> f64 {
        (**self).segment(seg, carry)
    }
    #[inline]
    fn at(&self, x: DVec3, cell: usize, w: DVec3) -> f64 {
        (**self).at(x, cell, w)
    }
    #[inline]
    fn at_step(&self, step: &StepSample, w: DVec3) -> f64 {
        (**self).at_step(step, w)
    }
    #[inline]
    fn at_step_pair(&self, steps: &[StepSample; 2], w: DVec3) -> [f64; 2] {
        (**self).at_step_pair(steps, w)
    }
    fn max_source(&self) -> f64 {
        (**self).max_source()
    }
    fn is_zero(&self) -> bool {
        (**self).is_zero()
    }
}

impl<S: InScattering + ?Sized> InScattering for Box<S> {
    #[inline]
    fn segment(&self, seg: &ViewSegment, carry: &mut RayCarry) -> f64 {
        (**self).segment(seg, carry)
    }
    #[inline]
    fn at(&self, x: DVec3, cell: usize, w: DVec3) -> f64 {
        (**self).at(x, cell, w)
    }
    #[inline]
    fn at_step(&self, step: &StepSample, w: DVec3) -> f64 {
        (**self).at_step(step, w)
    }
    #[inline]
    fn at_step_pair(&self, steps: &[StepSample; 2], w: DVec3) -> [f64; 2] {
        (**self).at_step_pair(steps, w)
    }
    fn max_source(&self) -> f64 {
        (**self).max_source()
    }
    fn is_zero(&self) -> bool {
        (**self).is_zero()
    }
}

/// The sum of several scattered sources, e.g. first bounce (true phase function) plus the
/// higher orders from a solution.
pub struct ScatteringSum<'a> {
    pub parts: Vec<&'a dyn InScattering>,
}

impl<'a> ScatteringSum<'a> {
    pub fn new(parts: Vec<&'a dyn InScattering>) -> Self {
        ScatteringSum { parts }
    }
}

impl InScattering for ScatteringSum<'_> {
    #[inline]
    fn segment(&self, seg: &ViewSegment, carry: &mut RayCarry) -> f64 {
        self.parts.iter().map(|s| s.segment(seg, carry)).sum()
    }
    #[inline]
    fn at(&self, x: DVec3, cell: usize, w: DVec3) -> f64 {
        self.parts.iter().map(|s| s.at(x, cell, w)).sum()
    }
    #[inline]
    fn at_step(&self, step: &StepSample, w: DVec3) -> f64 {
        self.parts.iter().map(|s| s.at_step(step, w)).sum()
    }
    #[inline]
    fn at_step_pair(&self, steps: &[StepSample; 2], w: DVec3) -> [f64; 2] {
        self.parts.iter().fold([0.0; 2], |[a, b], s| {
            let [p, q] = s.at_step_pair(steps, w);
            [a + p, b + q]
        })
    }
    fn max_source(&self) -> f64 {
        self.parts.iter().map(|s| s.max_source()).sum()
    }
    fn is_zero(&self) -> bool {
        self.parts.iter().all(|s| s.is_zero())
    }
}

/// A pair of sources adds up, without the `dyn` indirection of [`ScatteringSum`].
impl<A: InScattering, B: InScattering> InScattering for (A, B) {
    #[inline]
    fn segment(&self, seg: &ViewSegment, carry: &mut RayCarry) -> f64 {
        self.0.segment(seg, carry) + self.1.segment(seg, carry)
    }
    #[inline]
    fn at(&self, x: DVec3, cell: usize, w: DVec3) -> f64 {
        self.0.at(x, cell, w) + self.1.at(x, cell, w)
    }
    #[inline]
    fn at_step(&self, step: &StepSample, w: DVec3) -> f64 {
        self.0.at_step(step, w) + self.1.at_step(step, w)
    }
    #[inline]
    fn at_step_pair(&self, steps: &[StepSample; 2], w: DVec3) -> [f64; 2] {
        let ([a, b], [p, q]) = (self.0.at_step_pair(steps, w), self.1.at_step_pair(steps, w));
        [a + p, b + q]
    }
    fn max_source(&self) -> f64 {
        self.0.max_source() + self.1.max_source()
    }
    fn is_zero(&self) -> bool {
        self.0.is_zero() && self.1.is_zero()
    }
}

/// A source that is the same constant in every cell and direction: handy for tests and as
/// an ambient term.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct UniformSource(pub f64);

impl InScattering for UniformSource {
    #[inline]
    fn segment(&self, seg: &ViewSegment, _: &mut RayCarry) -> f64 {
        self.0 * seg.weight
    }
    #[inline]
    fn at(&self, _: DVec3, _: usize, _: DVec3) -> f64 {
        self.0
    }
    fn max_source(&self) -> f64 {
        self.0
    }
    fn is_zero(&self) -> bool {
        self.0 == 0.0
    }
}
