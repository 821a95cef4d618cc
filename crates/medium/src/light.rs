//! Light sources: directional, point, and Blasi & Wuethrich's local spot sources.

use glam::DVec3;
use serde::{Deserialize, Serialize};

use crate::MediumError;

/// A light outside or inside the volume. Radiometric quantities are per colour channel only
/// through the medium; lights are white (a scene colours light through albedo and σt).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Light {
    /// Parallel light travelling along unit `direction`, with irradiance `irradiance` on a
    /// plane perpendicular to it.
    Directional { direction: DVec3, irradiance: f64 },
    /// Isotropic point source of radiant intensity `intensity` (power per steradian).
    Point { position: DVec3, intensity: f64 },
    /// A spot: a point source emitting `intensity` within `half_angle` (radians) of unit `axis`.
    Spot {
        position: DVec3,
        axis: DVec3,
        half_angle: f64,
        intensity: f64,
    },
}

impl Light {
    /// Checks the parameters and normalises directions.
    pub fn validated(self) -> Result<Self, MediumError> {
        let finite = |v: DVec3| v.is_finite();
        let unit = |v: DVec3, what: &'static str| {
            let len = v.length();
            if !(len.is_finite() && len > 1e-12) {
                Err(MediumError::invalid(
                    what,
                    format!("{v:?} has no direction"),
                ))
            } else {
                Ok(v / len)
            }
        };
        let non_negative = |x: f64, what: &'static str| {
            if x.is_finite() && x >= 0.0 {
                Ok(x)
            } else {
                Err(MediumError::invalid(
                    what,
                    format!("{x} must be finite and ≥ 0"),
                ))
            }
        };
        Ok(match self {
            Light::Directional {
                direction,
                irradiance,
            } => Light::Directional {
                direction: unit(direction, "light direction")?,
                irradiance: non_negative(irradiance, "light irradiance")?,
            },
            Light::Point {
                position,
                intensity,
            } => {
                if !finite(position) {
                    return Err(MediumError::invalid("light position", "not finite"));
                }
                Light::Point {
                    position,
                    intensity: non_negative(intensity, "light intensity")?,
                }
            }
            Light::Spot {
                position,
                axis,
                half_angle,
                intensity,
            } => {
                if !finite(position) {
                    return Err(MediumError::invalid("light position", "not finite"));
                }
                if !(half_angle > 0.0 && half_angle <= std::f64::consts::PI) {
                    return Err(MediumError::invalid(
                        "light half_angle",
                        format!("{half_angle} rad must be in (0, π]"),
                    ));
                }
                Light::Spot {
                    position,
                    axis: unit(axis, "light axis")?,
                    half_angle,
                    intensity: non_negative(intensity, "light intensity")?,
                }
            }
        })
    }

    /// Direction of light flow arriving at `x` and the unshadowed irradiance there (on a
    /// plane perpendicular to the flow). Zero outside a spot's cone.
    #[inline]
    pub fn arriving_at(&self, x: DVec3) -> (DVec3, f64) {
        match *self {
            Light::Directional {
                direction,
                irradiance,
            } => (direction, irradiance),
            Light::Point {
                position,
                intensity,
            } => {
                let d = x - position;
                let r2 = d.length_squared().max(1e-300);
                (d / r2.sqrt(), intensity / r2)
            }
            Light::Spot {
                position,
                axis,
                half_angle,
                intensity,
            } => {
                let d = x - position;
                let r2 = d.length_squared().max(1e-300);
                let dir = d / r2.sqrt();
                let inside = dir.dot(axis) >= half_angle.cos();
                (dir, if inside { intensity / r2 } else { 0.0 })
            }
        }
    }
}
