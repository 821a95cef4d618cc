//! Light from every direction at infinity (a sky, a uniform environment), and its uncollided
//! radiance inside the grid.
//!
//! An [`Environment`] gives the radiance arriving from each direction outside the grid. Inside,
//! its uncollided part in cell `i`, travelling along `ω`, is `L(ω) ⟨T(ω)⟩_i`, with
//! `⟨T(ω)⟩_i` the cell average of the transmittance from the grid's edge along `ω` — the light
//! pass of a directional light ([`directional_cell_transmittance`]). The solvers take it on a
//! set of directions (their direction bins): unlike a light's, an environment's first bounce
//! is smooth in direction, so it is part of the solved field rather than of the render's exact
//! single scattering.

use glam::DVec3;
use serde::{Deserialize, Serialize};

use crate::light_pass::directional_cell_transmittance;
use crate::{Grid, MediumError};

/// Rays per cell side of each direction's transmittance pass (as the light pass's default).
const RAYS_PER_CELL: usize = 4;

/// The light arriving from outside the grid from every direction.
///
/// # Invariants
/// The radiance is finite and ≥ 0 (checked by [`Environment::uniform`]).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Environment {
    radiance: f64,
}

impl Environment {
    /// A uniform environment: radiance `radiance` from every direction (Mitsuba's `constant`
    /// emitter). Inside a non-absorbing medium (albedo 1) the radiance is `radiance`
    /// everywhere: the white furnace.
    pub fn uniform(radiance: f64) -> Result<Self, MediumError> {
        if !(radiance.is_finite() && radiance >= 0.0) {
            return Err(MediumError::invalid(
                "environment radiance",
                format!("{radiance} must be finite and ≥ 0"),
            ));
        }
        Ok(Environment { radiance })
    }

    /// The largest radiance it sends.
    pub fn radiance(&self) -> f64 {
        self.radiance
    }

    /// Radiance of the light travelling along unit `direction` (arriving from `−direction`).
    #[inline]
    pub fn radiance_along(&self, _direction: DVec3) -> f64 {
        self.radiance
    }

    /// Whether it sends no light at all.
    pub fn is_dark(&self) -> bool {
        self.radiance == 0.0
    }

    /// The uncollided radiance `L(ω_k) ⟨T(ω_k)⟩_i` per cell `i` and travel direction `ω_k`,
    /// cell-major (`i · K + k`, `K = directions.len()`): `σt` per cell, one transmittance pass
    /// per direction.
    pub fn uncollided_radiance(
        &self,
        grid: &Grid,
        sigma_t: &[f32],
        directions: &[DVec3],
    ) -> Result<Vec<f64>, MediumError> {
        let k = directions.len();
        let mut out = vec![0.0; grid.cell_count() * k];
        for (d, &direction) in directions.iter().enumerate() {
            let radiance = self.radiance_along(direction);
            if radiance == 0.0 {
                continue;
            }
            let t = directional_cell_transmittance(grid, sigma_t, direction, RAYS_PER_CELL)?;
            for (i, ti) in t.iter().enumerate() {
                out[i * k + d] = radiance * ti;
            }
        }
        Ok(out)
    }

    /// The uncollided fluence `Σ_k Ω_k L(ω_k) ⟨T(ω_k)⟩_i` per cell, over the quadrature of
    /// `directions` with solid angles `solid_angles` (which should add up to 4π).
    pub fn uncollided_fluence(
        &self,
        grid: &Grid,
        sigma_t: &[f32],
        directions: &[DVec3],
        solid_angles: &[f64],
    ) -> Result<Vec<f64>, MediumError> {
        if directions.len() != solid_angles.len() {
            return Err(MediumError::invalid(
                "environment quadrature",
                format!(
                    "{} directions but {} solid angles",
                    directions.len(),
                    solid_angles.len()
                ),
            ));
        }
        let mut fluence = vec![0.0; grid.cell_count()];
        for (&direction, &omega) in directions.iter().zip(solid_angles) {
            let radiance = self.radiance_along(direction);
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn negative_or_infinite_radiance_is_refused() {
        assert!(Environment::uniform(-1.0).is_err());
        assert!(Environment::uniform(f64::INFINITY).is_err());
        assert!(Environment::uniform(0.0).unwrap().is_dark());
    }

    #[test]
    fn uncollided_radiance_in_a_uniform_slab_falls_as_beer_lambert() {
        // A column of 4 cells of σt = 0.5 along z, light travelling +z: the cell average over
        // cell k is e^{−0.5 k} (1 − e^{−0.5}) / 0.5.
        let grid = Grid::new([1, 1, 4], 1.0).unwrap();
        let env = Environment::uniform(2.0).unwrap();
        let psi = env
            .uncollided_radiance(&grid, &[0.5; 4], &[DVec3::Z, -DVec3::Z])
            .unwrap();
        let mean = (1.0 - (-0.5f64).exp()) / 0.5;
        for k in 0..4 {
            let up = 2.0 * (-0.5 * k as f64).exp() * mean;
            let down = 2.0 * (-0.5 * (3 - k) as f64).exp() * mean;
            assert!(
                (psi[k * 2] - up).abs() < 1e-9,
                "cell {k}: {} vs {up}",
                psi[k * 2]
            );
            assert!((psi[k * 2 + 1] - down).abs() < 1e-9);
        }
        let fluence = env
            .uncollided_fluence(&grid, &[0.5; 4], &[DVec3::Z, -DVec3::Z], &[1.0, 3.0])
            .unwrap();
        assert!((fluence[0] - (psi[0] + 3.0 * psi[1])).abs() < 1e-12);
        assert!(env
            .uncollided_fluence(&grid, &[0.5; 4], &[DVec3::Z], &[1.0, 3.0])
            .is_err());
    }
}
