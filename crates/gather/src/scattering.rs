//! The scattered part of the source term, plugged into the renderer from outside.
//!
//! The renderer integrates `Q = e + Q_s` along each view ray. It owns the emission `e`; the
//! scattered part `Q_s(x, ω)` (single scattering, the multiple-scattering solution, ...) comes
//! through [`InScattering`], so new kinds of scattered light need no change to the renderer.
//!
//! Direction convention: light FLOWS toward the eye, along `−ray.direction`. That is the `ω`
//! to hand to phase functions (`cosθ = ω·ω'` with both directions of light flow).

use glam::DVec3;
use medium::traversal::Ray;

/// Scattered radiance per unit length, `Q_s(x, ω)`, for one colour channel.
///
/// `Q_s = σs · (in-scattered radiance)` vanishes where `σt = 0`, so the renderer never asks
/// about cells (or trilinear samples) with neither extinction nor emission, and skips empty
/// space wholesale.
pub trait InScattering: Sync {
    /// `∫_{t0}^{t1} e^{−σt (t−t0)} Q_s(ray(t), −ray.direction) dt` for the part of the ray
    /// inside `cell` (σt constant there). The renderer multiplies by the transmittance from
    /// the eye to `t0`. Used by `nearest` renders, which integrate each cell exactly.
    fn segment(&self, cell: usize, ray: &Ray, t0: f64, t1: f64, sigma_t: f64) -> f64;

    /// `Q_s` at point `x` (inside `cell`) for light flowing in direction `view_flow_dir`
    /// (`= −ray.direction`). Used by `trilinear` renders, which march in fixed steps.
    fn at(&self, x: DVec3, cell: usize, view_flow_dir: DVec3) -> f64;

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

/// No scattered light (emission/absorption models, or a medium with albedo 0).
impl InScattering for () {
    #[inline]
    fn segment(&self, _: usize, _: &Ray, _: f64, _: f64, _: f64) -> f64 {
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
    fn segment(&self, cell: usize, ray: &Ray, t0: f64, t1: f64, sigma_t: f64) -> f64 {
        self.as_ref()
            .map_or(0.0, |s| s.segment(cell, ray, t0, t1, sigma_t))
    }
    #[inline]
    fn at(&self, x: DVec3, cell: usize, w: DVec3) -> f64 {
        self.as_ref().map_or(0.0, |s| s.at(x, cell, w))
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
    fn segment(&self, cell: usize, ray: &Ray, t0: f64, t1: f64, sigma_t: f64) -> f64 {
        (**self).segment(cell, ray, t0, t1, sigma_t)
    }
    #[inline]
    fn at(&self, x: DVec3, cell: usize, w: DVec3) -> f64 {
        (**self).at(x, cell, w)
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
    fn segment(&self, cell: usize, ray: &Ray, t0: f64, t1: f64, sigma_t: f64) -> f64 {
        (**self).segment(cell, ray, t0, t1, sigma_t)
    }
    #[inline]
    fn at(&self, x: DVec3, cell: usize, w: DVec3) -> f64 {
        (**self).at(x, cell, w)
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
    fn segment(&self, cell: usize, ray: &Ray, t0: f64, t1: f64, sigma_t: f64) -> f64 {
        self.parts
            .iter()
            .map(|s| s.segment(cell, ray, t0, t1, sigma_t))
            .sum()
    }
    #[inline]
    fn at(&self, x: DVec3, cell: usize, w: DVec3) -> f64 {
        self.parts.iter().map(|s| s.at(x, cell, w)).sum()
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
    fn segment(&self, cell: usize, ray: &Ray, t0: f64, t1: f64, sigma_t: f64) -> f64 {
        self.0.segment(cell, ray, t0, t1, sigma_t) + self.1.segment(cell, ray, t0, t1, sigma_t)
    }
    #[inline]
    fn at(&self, x: DVec3, cell: usize, w: DVec3) -> f64 {
        self.0.at(x, cell, w) + self.1.at(x, cell, w)
    }
    fn max_source(&self) -> f64 {
        self.0.max_source() + self.1.max_source()
    }
    fn is_zero(&self) -> bool {
        self.0.is_zero() && self.1.is_zero()
    }
}

/// `∫_0^{Δs} e^{−σt s} ds = (1 − e^{−σt Δs}) / σt` (`= Δs` when `σt Δs` is tiny), the weight
/// of a constant source over one segment. Shared with [`InScattering`] implementations that
/// have a per-cell constant source.
#[inline]
pub fn segment_weight(sigma_t: f64, length: f64) -> f64 {
    let tau = sigma_t * length;
    if tau < 1e-8 {
        // Series: Δs (1 − τ/2); the relative error of dropping τ²/6 is below 1e-16.
        length * (1.0 - 0.5 * tau)
    } else {
        -(-tau).exp_m1() / sigma_t
    }
}

/// A source that is the same constant in every cell and direction: handy for tests and as
/// an ambient term.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct UniformSource(pub f64);

impl InScattering for UniformSource {
    #[inline]
    fn segment(&self, _: usize, _: &Ray, t0: f64, t1: f64, sigma_t: f64) -> f64 {
        self.0 * segment_weight(sigma_t, t1 - t0)
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
