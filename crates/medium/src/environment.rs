//! Light from every direction at infinity — a uniform environment or an analytic sky — and its
//! uncollided radiance inside the grid.
//!
//! An [`Environment`] gives, per colour channel, the radiance arriving from each direction
//! outside the grid. Inside, its uncollided part in cell `i`, travelling along `ω`, is
//! `L(ω) ⟨T(ω)⟩_i`, with `⟨T(ω)⟩_i` the cell average of the transmittance from the grid's
//! edge along `ω` — the light pass of a directional light
//! ([`directional_cell_transmittance`]). Unlike a light's, an environment's first bounce is
//! smooth in direction, so the solvers carry it in their solved fields rather than in the
//! render's exact single scattering.
//!
//! The sky is Preetham, Shirley & Smits' analytic daylight model (SIGGRAPH 1999): the Perez
//! distribution of luminance and chromaticity over the sky for a turbidity and a sun position,
//! converted to linear sRGB. Below the horizon it shows a Lambertian ground lit by the sky and
//! the sun (not shadowed by the medium).

use std::f64::consts::PI;

use std::sync::Arc;

use glam::DVec3;
use serde::{Deserialize, Serialize};

use crate::environment_map::EnvironmentMap;
use crate::light_pass::directional_cell_transmittance;
use crate::{Grid, MediumError};

/// Rays per cell side of each direction's transmittance pass (as the light pass's default).
const RAYS_PER_CELL: usize = 4;

/// The light arriving from outside the grid from every direction.
///
/// # Invariants
/// Radiances are finite and ≥ 0; a sky's parameters are in range and its normalisation is
/// finite (checked by [`Environment::uniform`], [`Environment::uniform_rgb`] and
/// [`Environment::sky`]).
#[derive(Clone, Debug, PartialEq)]
pub struct Environment {
    kind: Kind,
}

// One per scene, copied only into render settings: the sky's size (its coefficients kept
// ready to evaluate) does not matter.
#[allow(clippy::large_enum_variant)]
#[derive(Clone, Debug, PartialEq)]
enum Kind {
    Uniform {
        radiance: [f64; 3],
    },
    Sky(Sky),
    /// Shared: renders and solves copy the environment, not its texels.
    Map(Arc<EnvironmentMap>),
}

/// What an environment is made from (what a scene says; [`Environment::new`] checks it).
#[derive(Clone, Debug, PartialEq)]
pub enum EnvironmentSpec {
    /// The same radiance (linear RGB) from every direction.
    Uniform { radiance: [f64; 3] },
    /// Preetham's sky with a ground below the horizon.
    Sky(SkySpec),
    /// An equirectangular map (checked when it was made).
    Map(Arc<EnvironmentMap>),
}

/// What a sky is made from (scene keys of `[[light]] kind = "sky"`).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct SkySpec {
    /// Atmospheric turbidity: 2 (very clear) to 10 (hazy).
    pub turbidity: f64,
    /// Sun elevation above the horizon, degrees, in (0, 90].
    pub sun_elevation_degrees: f64,
    /// Sun azimuth, degrees, counter-clockwise about `up` from the horizontal reference axis
    /// (the projection of +x, or of +y when `up` is along x).
    pub sun_azimuth_degrees: f64,
    /// The world's up direction (normalised on construction).
    pub up: DVec3,
    /// Irradiance of the sun on a plane facing it (the directional light the sky places).
    pub sun_irradiance: f64,
    /// The sky's irradiance on a horizontal plane (luminance) as a fraction of the sun's
    /// `sun_irradiance`: how bright the sky is next to the sun (a clear day about 0.15).
    pub sky_fraction: f64,
    /// Albedo of the ground below the horizon, in [0, 1].
    pub ground_albedo: f64,
}

impl Default for SkySpec {
    fn default() -> Self {
        SkySpec {
            turbidity: 3.0,
            sun_elevation_degrees: 35.0,
            sun_azimuth_degrees: 0.0,
            up: DVec3::Z,
            sun_irradiance: 1.0,
            sky_fraction: 0.15,
            ground_albedo: 0.3,
        }
    }
}

/// A sky ready to evaluate: the spec, its frame and the normalised Perez model.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
struct Sky {
    spec: SkySpec,
    up: DVec3,
    /// Unit vector toward the sun.
    to_sun: DVec3,
    /// Perez coefficients A..E for Y, x and y.
    perez: [[f64; 5]; 3],
    /// Zenith values of Y, x and y over the Perez function at the zenith, `F(0, θs)`: the
    /// factor of `F(θ, γ)` in each lookup.
    zenith_over_f0: [f64; 3],
    /// Factor from the model's Y to radiance.
    scale: f64,
    /// Radiance of the ground per channel.
    ground: [f64; 3],
    /// The largest radiance per channel (linear sRGB), for renders' termination bound.
    max_rgb: [f64; 3],
}

impl Environment {
    /// The environment `spec` describes, checked.
    pub fn new(spec: EnvironmentSpec) -> Result<Self, MediumError> {
        match spec {
            EnvironmentSpec::Uniform { radiance } => Self::uniform_rgb(radiance),
            EnvironmentSpec::Sky(sky) => Self::sky(sky),
            EnvironmentSpec::Map(map) => Ok(Self::map(map)),
        }
    }

    /// What it was made from.
    pub fn spec(&self) -> EnvironmentSpec {
        match &self.kind {
            Kind::Uniform { radiance } => EnvironmentSpec::Uniform {
                radiance: *radiance,
            },
            Kind::Sky(s) => EnvironmentSpec::Sky(s.spec),
            Kind::Map(m) => EnvironmentSpec::Map(m.clone()),
        }
    }

    /// A uniform grey environment: radiance `radiance` from every direction (Mitsuba's
    /// `constant` emitter). Inside a non-absorbing medium (albedo 1) the radiance is
    /// `radiance` everywhere: the white furnace.
    pub fn uniform(radiance: f64) -> Result<Self, MediumError> {
        Self::uniform_rgb([radiance; 3])
    }

    /// A uniform environment of radiance `rgb` (linear, per channel).
    pub fn uniform_rgb(rgb: [f64; 3]) -> Result<Self, MediumError> {
        if let Some(v) = rgb.iter().find(|v| !(v.is_finite() && **v >= 0.0)) {
            return Err(MediumError::invalid(
                "environment radiance",
                format!("{v} must be finite and ≥ 0"),
            ));
        }
        Ok(Environment {
            kind: Kind::Uniform { radiance: rgb },
        })
    }

    /// Preetham's sky for `spec` (see the module doc), with a ground below the horizon.
    pub fn sky(spec: SkySpec) -> Result<Self, MediumError> {
        Ok(Environment {
            kind: Kind::Sky(Sky::new(spec)?),
        })
    }

    /// An environment map (`crate::environment_map`).
    pub fn map(map: Arc<EnvironmentMap>) -> Self {
        Environment {
            kind: Kind::Map(map),
        }
    }

    /// The uniform radiance per channel, when the environment is uniform.
    pub fn uniform_radiance(&self) -> Option<[f64; 3]> {
        match &self.kind {
            Kind::Uniform { radiance } => Some(*radiance),
            Kind::Map(m) => m.uniform_rgb(),
            Kind::Sky(_) => None,
        }
    }

    /// Whether the channels differ (a grey medium is then solved in three channels).
    pub fn is_coloured(&self) -> bool {
        match &self.kind {
            Kind::Uniform {
                radiance: [r, g, b],
            } => r != g || g != b,
            Kind::Sky(_) => true,
            Kind::Map(m) => m.is_coloured(),
        }
    }

    /// The unit vector toward the sun, and its irradiance, for a sky (the directional light
    /// a scene places with it).
    pub fn sun(&self) -> Option<(DVec3, f64)> {
        match &self.kind {
            Kind::Sky(s) => Some((s.to_sun, s.spec.sun_irradiance)),
            Kind::Uniform { .. } | Kind::Map(_) => None,
        }
    }

    /// Radiance in channel `channel` (of `channels`: 1 takes the luminance, 3 are linear
    /// sRGB) of the light travelling along unit `direction` (arriving from `−direction`).
    #[inline]
    pub fn radiance_along(&self, direction: DVec3, channel: usize, channels: usize) -> f64 {
        match &self.kind {
            Kind::Uniform { radiance } => pick(radiance, channel, channels),
            Kind::Sky(s) => pick(&s.rgb_from(-direction), channel, channels),
            Kind::Map(m) => pick(&m.rgb_from(-direction), channel, channels),
        }
    }

    /// The environment's map, when it is one (the solvers splat its texels onto their
    /// direction bins rather than sample it at their centres).
    pub fn as_map(&self) -> Option<&EnvironmentMap> {
        match &self.kind {
            Kind::Map(m) => Some(m),
            _ => None,
        }
    }

    /// The largest radiance it sends in a channel (a bound for renders' early termination).
    pub fn max_radiance(&self, channel: usize, channels: usize) -> f64 {
        match &self.kind {
            Kind::Uniform { radiance } => pick(radiance, channel, channels),
            // (For one channel the luminance of the per-channel maxima: a bound as well.)
            Kind::Sky(s) => pick(&s.max_rgb, channel, channels),
            Kind::Map(m) => pick(&m.max_rgb(), channel, channels),
        }
    }

    /// Whether it sends no light at all.
    pub fn is_dark(&self) -> bool {
        match &self.kind {
            Kind::Uniform { radiance } => *radiance == [0.0; 3],
            Kind::Sky(_) => false,
            Kind::Map(m) => m.max_rgb() == [0.0; 3],
        }
    }

    /// The uncollided fluence `Σ_k Ω_k L_k ⟨T(ω_k)⟩_i` per cell, over the quadrature of
    /// travel `directions` with solid angles `solid_angles` (which should add up to 4π) and
    /// the radiance `radiances[k]` arriving along each (the environment's in one channel: at
    /// the direction, or its mean over the direction's bin); `σt` per cell, one
    /// transmittance pass per direction with light.
    pub fn uncollided_fluence(
        grid: &Grid,
        sigma_t: &[f32],
        directions: &[DVec3],
        solid_angles: &[f64],
        radiances: &[f64],
    ) -> Result<Vec<f64>, MediumError> {
        if directions.len() != solid_angles.len() || directions.len() != radiances.len() {
            return Err(MediumError::invalid(
                "environment quadrature",
                format!(
                    "{} directions, {} solid angles and {} radiances",
                    directions.len(),
                    solid_angles.len(),
                    radiances.len()
                ),
            ));
        }
        let mut fluence = vec![0.0; grid.cell_count()];
        for ((&direction, &omega), &radiance) in directions.iter().zip(solid_angles).zip(radiances)
        {
            if radiance == 0.0 {
                continue;
            }
            let t = directional_cell_transmittance(grid, sigma_t, direction, RAYS_PER_CELL)?;
            for (f, ti) in fluence.iter_mut().zip(&t) {
                *f += omega * radiance * ti;
            }
        }
        Ok(fluence)
    }
}

/// The horizontal frame about unit `up` that skies and maps measure azimuth in: the
/// projection of +x (of +y when `up` is along x), and `up ×` it.
pub(crate) fn horizontal_frame(up: DVec3) -> (DVec3, DVec3) {
    let reference = if up.x.abs() > 0.9 { DVec3::Y } else { DVec3::X };
    let e1 = (reference - up * reference.dot(up)).normalize();
    (e1, up.cross(e1))
}

/// Channel `c` of an RGB triple for a `channels`-channel medium: the luminance for one.
#[inline]
pub fn pick(rgb: &[f64; 3], c: usize, channels: usize) -> f64 {
    if channels == 1 {
        luminance(rgb)
    } else {
        rgb[c.min(2)]
    }
}

/// Rec. 709 / sRGB luminance of linear RGB.
#[inline]
pub fn luminance(rgb: &[f64; 3]) -> f64 {
    0.2126 * rgb[0] + 0.7152 * rgb[1] + 0.0722 * rgb[2]
}

/// `n` directions spread evenly over the sphere (a Fibonacci lattice).
pub(crate) fn fibonacci_directions(n: usize) -> impl Iterator<Item = DVec3> {
    let golden = PI * (3.0 - 5f64.sqrt());
    (0..n).map(move |i| {
        let z = 1.0 - (2.0 * i as f64 + 1.0) / n as f64;
        let r = (1.0 - z * z).max(0.0).sqrt();
        let phi = golden * i as f64;
        DVec3::new(r * phi.cos(), r * phi.sin(), z)
    })
}

/// The Perez luminance distribution `(1 + A e^{B/cos θ}) (1 + C e^{D γ} + E cos² γ)`.
#[inline]
fn perez(c: &[f64; 5], cos_theta: f64, gamma: f64) -> f64 {
    let [a, b, cc, d, e] = *c;
    (1.0 + a * (b / cos_theta.max(0.01)).exp())
        * (1.0 + cc * (d * gamma).exp() + e * gamma.cos().powi(2))
}

impl Sky {
    fn new(spec: SkySpec) -> Result<Sky, MediumError> {
        let bad = |what: &'static str, message: String| Err(MediumError::invalid(what, message));
        let t = spec.turbidity;
        if !(2.0..=10.0).contains(&t) {
            return bad(
                "sky turbidity",
                format!("{t}: expected 2 (clear) to 10 (hazy)"),
            );
        }
        let elevation = spec.sun_elevation_degrees;
        if !(elevation > 0.0 && elevation <= 90.0) {
            return bad(
                "sky sun_elevation_degrees",
                format!(
                    "{elevation}: expected (0, 90] (the model needs the sun above the horizon)"
                ),
            );
        }
        if !spec.sun_azimuth_degrees.is_finite() {
            return bad("sky sun_azimuth_degrees", "must be finite".into());
        }
        for (v, what) in [
            (spec.sun_irradiance, "sky sun_irradiance"),
            (spec.sky_fraction, "sky sky_fraction"),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return bad(what, format!("{v} must be finite and ≥ 0"));
            }
        }
        if !(0.0..=1.0).contains(&spec.ground_albedo) {
            return bad(
                "sky ground_albedo",
                format!("{}: expected 0 to 1", spec.ground_albedo),
            );
        }
        let len = spec.up.length();
        if !(len.is_finite() && len > 1e-12) {
            return bad("sky up", format!("{:?} has no direction", spec.up));
        }
        let up = spec.up / len;
        let (e1, e2) = horizontal_frame(up);
        let (el, az) = (
            elevation.to_radians(),
            spec.sun_azimuth_degrees.to_radians(),
        );
        let to_sun = (el.cos() * (az.cos() * e1 + az.sin() * e2) + el.sin() * up).normalize();
        let theta_s = PI / 2.0 - el;
        let perez = [
            [
                0.1787 * t - 1.4630,
                -0.3554 * t + 0.4275,
                -0.0227 * t + 5.3251,
                0.1206 * t - 2.5771,
                -0.0670 * t + 0.3703,
            ],
            [
                -0.0193 * t - 0.2592,
                -0.0665 * t + 0.0008,
                -0.0004 * t + 0.2125,
                -0.0641 * t - 0.8989,
                -0.0033 * t + 0.0452,
            ],
            [
                -0.0167 * t - 0.2608,
                -0.0950 * t + 0.0092,
                -0.0079 * t + 0.2102,
                -0.0441 * t - 1.6537,
                -0.0109 * t + 0.0529,
            ],
        ];
        let chi = (4.0 / 9.0 - t / 120.0) * (PI - 2.0 * theta_s);
        let y_zenith = (4.0453 * t - 4.9710) * chi.tan() - 0.2155 * t + 2.4192;
        let cubic =
            |c: [f64; 4]| c[0] * theta_s.powi(3) + c[1] * theta_s.powi(2) + c[2] * theta_s + c[3];
        let x_zenith = t * t * cubic([0.00166, -0.00375, 0.00209, 0.0])
            + t * cubic([-0.02903, 0.06377, -0.03202, 0.00394])
            + cubic([0.11693, -0.21196, 0.06052, 0.25886]);
        let yc_zenith = t * t * cubic([0.00275, -0.00610, 0.00317, 0.0])
            + t * cubic([-0.04214, 0.08970, -0.04153, 0.00516])
            + cubic([0.15346, -0.26756, 0.06670, 0.26688]);
        let mut sky = Sky {
            spec,
            up,
            to_sun,
            perez,
            zenith_over_f0: [
                y_zenith / self::perez(&perez[0], 1.0, theta_s),
                x_zenith / self::perez(&perez[1], 1.0, theta_s),
                yc_zenith / self::perez(&perez[2], 1.0, theta_s),
            ],
            scale: 1.0,
            ground: [0.0; 3],
            max_rgb: [0.0; 3],
        };
        // Normalise: the sky's horizontal irradiance (luminance) is `sky_fraction` of the
        // sun's irradiance. Midpoint rule in (cos θ, φ) over the upper hemisphere.
        let (n_mu, n_phi) = (64, 128);
        let mut horizontal = [0.0f64; 3];
        for i in 0..n_mu {
            let mu = (i as f64 + 0.5) / n_mu as f64;
            let s = (1.0 - mu * mu).sqrt();
            for j in 0..n_phi {
                let phi = 2.0 * PI * (j as f64 + 0.5) / n_phi as f64;
                let d = mu * up + s * (phi.cos() * e1 + phi.sin() * e2);
                let rgb = sky.rgb_from(d);
                for (h, v) in horizontal.iter_mut().zip(rgb) {
                    *h += v * mu * (2.0 * PI / (n_mu * n_phi) as f64);
                }
            }
        }
        let y = luminance(&horizontal);
        if !(y.is_finite() && y > 0.0) {
            return bad(
                "sky",
                format!("the model gives no light for turbidity {t}, elevation {elevation}°"),
            );
        }
        sky.scale = spec.sky_fraction * spec.sun_irradiance / y;
        let sun_horizontal = spec.sun_irradiance * el.sin();
        sky.ground = horizontal.map(|h| spec.ground_albedo * (h * sky.scale + sun_horizontal) / PI);
        // The Perez maximum is at the sun or at the horizon below it; a fine scan of the sky,
        // the sun and the ground, with a margin, bounds it well enough for a termination rule.
        let mut max_rgb = sky.ground;
        for d in fibonacci_directions(4096).chain([to_sun]) {
            for (m, v) in max_rgb.iter_mut().zip(sky.rgb_from(d)) {
                *m = m.max(v);
            }
        }
        sky.max_rgb = max_rgb.map(|m| m * 1.05);
        Ok(sky)
    }

    /// Linear sRGB radiance arriving from unit direction `from` (pointing at the sky).
    fn rgb_from(&self, from: DVec3) -> [f64; 3] {
        let cos_theta = from.dot(self.up);
        if cos_theta <= 0.0 {
            return self.ground;
        }
        let gamma = from.dot(self.to_sun).clamp(-1.0, 1.0).acos();
        let value = |k: usize| self.zenith_over_f0[k] * perez(&self.perez[k], cos_theta, gamma);
        let (big_y, x, y) = (value(0) * self.scale, value(1), value(2));
        if y.is_nan() || y <= 0.0 {
            return [0.0; 3];
        }
        // xyY → XYZ → linear sRGB (D65).
        let big_x = x * big_y / y;
        let big_z = (1.0 - x - y) * big_y / y;
        [
            3.2406 * big_x - 1.5372 * big_y - 0.4986 * big_z,
            -0.9689 * big_x + 1.8758 * big_y + 0.0415 * big_z,
            0.0557 * big_x - 0.2040 * big_y + 1.0570 * big_z,
        ]
        .map(|v| v.max(0.0))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn negative_or_infinite_radiance_is_refused() {
        assert!(Environment::uniform(-1.0).is_err());
        assert!(Environment::uniform(f64::INFINITY).is_err());
        assert!(Environment::uniform(0.0).unwrap().is_dark());
        assert!(!Environment::uniform(0.5).unwrap().is_coloured());
        assert!(Environment::uniform_rgb([0.1, 0.2, 0.3])
            .unwrap()
            .is_coloured());
    }

    #[test]
    fn uncollided_fluence_in_a_column_falls_as_beer_lambert() {
        // A column of 4 cells of σt = 0.5 along z, light travelling ±z: the cell average over
        // cell k is e^{−0.5 k} (1 − e^{−0.5}) / 0.5 going up.
        let grid = Grid::new([1, 1, 4], 1.0).unwrap();
        let mean = (1.0 - (-0.5f64).exp()) / 0.5;
        let fluence = Environment::uncollided_fluence(
            &grid,
            &[0.5; 4],
            &[DVec3::Z, -DVec3::Z],
            &[1.0, 3.0],
            &[2.0, 2.0],
        )
        .unwrap();
        for (k, f) in fluence.iter().enumerate() {
            let up = 2.0 * (-0.5 * k as f64).exp() * mean;
            let down = 2.0 * (-0.5 * (3 - k) as f64).exp() * mean;
            assert!((f - (up + 3.0 * down)).abs() < 1e-9, "cell {k}: {f}");
        }
        assert!(Environment::uncollided_fluence(
            &grid,
            &[0.5; 4],
            &[DVec3::Z],
            &[1.0, 3.0],
            &[2.0]
        )
        .is_err());
    }

    fn sky(spec: SkySpec) -> (Environment, Sky) {
        let env = Environment::sky(spec).unwrap();
        let Kind::Sky(s) = env.kind else {
            panic!("not a sky")
        };
        (env, s)
    }

    #[test]
    fn the_sky_is_blue_brightest_near_the_sun_and_normalised() {
        let spec = SkySpec::default();
        let (env, s) = sky(spec);
        // Blue overhead (scattering favours short wavelengths), away from the sun.
        let zenith = s.rgb_from(DVec3::Z);
        assert!(zenith[2] > zenith[0], "zenith {zenith:?}");
        // Brighter near the sun than opposite it at the same elevation.
        let (sun, _) = env.sun().unwrap();
        let opposite = DVec3::new(-sun.x, -sun.y, sun.z);
        assert!(
            luminance(&s.rgb_from((sun + 0.1 * DVec3::Z).normalize()))
                > luminance(&s.rgb_from(opposite))
        );
        // The sun at 35° elevation, azimuth 0: toward +x and up.
        assert!(
            (sun.z - 35f64.to_radians().sin()).abs() < 1e-12 && sun.x > 0.0 && sun.y.abs() < 1e-12
        );
        // Horizontal irradiance of the sky is sky_fraction × sun irradiance (luminance).
        let mut e = 0.0;
        let n = 200_000;
        for d in fibonacci_directions(n) {
            if d.z > 0.0 {
                e += env.radiance_along(-d, 0, 1) * d.z * 4.0 * PI / n as f64;
            }
        }
        assert!(
            (e - 0.15).abs() < 0.15 * 0.01,
            "horizontal sky irradiance {e}"
        );
        // Below the horizon, the ground: albedo × (sky + sun on the horizontal) / π.
        let ground = env.radiance_along(DVec3::Z, 0, 1);
        let expected = 0.3 * (0.15 + 35f64.to_radians().sin()) / PI;
        assert!(
            (ground - expected).abs() < 1e-3 * expected,
            "{ground} vs {expected}"
        );
    }

    #[test]
    fn sky_parameters_out_of_range_are_refused() {
        for spec in [
            SkySpec {
                turbidity: 1.0,
                ..SkySpec::default()
            },
            SkySpec {
                sun_elevation_degrees: 0.0,
                ..SkySpec::default()
            },
            SkySpec {
                sun_elevation_degrees: 91.0,
                ..SkySpec::default()
            },
            SkySpec {
                ground_albedo: 1.5,
                ..SkySpec::default()
            },
            SkySpec {
                sky_fraction: -0.1,
                ..SkySpec::default()
            },
            SkySpec {
                up: DVec3::ZERO,
                ..SkySpec::default()
            },
        ] {
            assert!(Environment::sky(spec).is_err(), "{spec:?}");
        }
    }
}
