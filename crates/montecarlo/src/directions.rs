//! Directions on the sphere sampled by meridians and parallels (Blasi & Wuethrich §3.2.4):
//! `n_theta` bands equal in `cos θ` about the z axis times `n_phi` equal sectors in
//! azimuth, so every bin has the same solid angle `4π / (n_theta · n_phi)`.

use std::f64::consts::PI;

use glam::DVec3;
use serde::{Deserialize, Serialize};

/// A lat-long direction grid with equal-area bins. `1 × 1` is the single sample that
/// suffices for isotropic scattering.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct DirectionBins {
    pub n_theta: usize,
    pub n_phi: usize,
}

impl DirectionBins {
    pub const ISOTROPIC: DirectionBins = DirectionBins {
        n_theta: 1,
        n_phi: 1,
    };

    #[inline]
    pub fn count(&self) -> usize {
        self.n_theta * self.n_phi
    }

    /// Solid angle of every bin.
    #[inline]
    pub fn solid_angle(&self) -> f64 {
        4.0 * PI / self.count() as f64
    }

    /// The bin holding unit direction `w`.
    #[inline]
    pub fn bin(&self, w: DVec3) -> usize {
        let band = (((1.0 - w.z) * 0.5 * self.n_theta as f64) as usize).min(self.n_theta - 1);
        if self.n_phi == 1 {
            return band;
        }
        let phi = w.y.atan2(w.x); // (−π, π]
        let sector = (((phi + PI) / (2.0 * PI) * self.n_phi as f64) as usize).min(self.n_phi - 1);
        band * self.n_phi + sector
    }

    /// The direction at fractional position `(u, v) ∈ [0, 1]²` inside bin `b` (equal-area
    /// coordinates: `u` along `cos θ`, `v` along φ). `(0.5, 0.5)` is the bin's centre.
    pub fn direction_in(&self, b: usize, u: f64, v: f64) -> DVec3 {
        let (band, sector) = (b / self.n_phi, b % self.n_phi);
        let cos_theta = 1.0 - 2.0 * (band as f64 + u) / self.n_theta as f64;
        let phi = -PI + 2.0 * PI * (sector as f64 + v) / self.n_phi as f64;
        let sin_theta = (1.0 - cos_theta * cos_theta).max(0.0).sqrt();
        DVec3::new(sin_theta * phi.cos(), sin_theta * phi.sin(), cos_theta)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bin_of_a_bins_points_is_that_bin() {
        let bins = DirectionBins {
            n_theta: 6,
            n_phi: 12,
        };
        for b in 0..bins.count() {
            for (u, v) in [(0.5, 0.5), (0.01, 0.99), (0.99, 0.01)] {
                assert_eq!(bins.bin(bins.direction_in(b, u, v)), b);
            }
        }
        assert_eq!(bins.bin(DVec3::Z) / bins.n_phi, 0);
        assert_eq!(bins.bin(-DVec3::Z) / bins.n_phi, bins.n_theta - 1);
    }
}
