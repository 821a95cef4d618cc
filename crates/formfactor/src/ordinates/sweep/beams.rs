//! The lights' first scattering inside each cell: its slopes from the beam, not from the
//! neighbours.
//!
//! A linear source's slopes are central differences of the neighbours' source function
//! ([`OrdinatesOperator::source_slopes`]). That suits the scattered light, which is smooth
//! from cell to cell, but not a beam's first scattering where cells are thick along the beam:
//! it falls off as `e^{−τ}` inside each cell, and across a cell of optical path 2.5 (σt h = 1
//! for a beam at μ0 = 0.4) the neighbours' differences make its slope nearly 3× too steep
//! inside the medium and 2.5× too flat in the lit cell, whose other neighbour is outside. The
//! first scattering's mean depth is then off by a fraction of a cell, and a thick medium's
//! transmission follows that depth (diffusion: `T ∝ z0 + z_e`): an oblique beam on layers of
//! optical depth 1 let 5 % too much light through a slab of τ = 64.
//!
//! The beam's profile inside a cell is known: `e^{−τ(x)}` with τ the optical depth toward the
//! light, about linear across the cell. Its first moment gives the linear source's exact
//! slope, `r(κ) = 6 (x̄ − ½)` for `κ` the change of τ across the cell
//! ([`exponential_half_change`]). [`BeamProfiles`] holds, per directional light, what that
//! changes against the neighbours' differences, and the first transport of the lights'
//! scattering ([`OrdinatesOperator::transport_external`]) adds it to the slopes.

use super::*;

/// Each directional light's first scattering inside each cell: what the beam's own profile
/// changes in a linear source's slopes against the neighbours' differences, per light, cell
/// and axis, with the bins' share of the light (the external density's bin-averaged phase
/// function). Made by [`OrdinatesOperator::beam_profiles`] or
/// [`OrdinatesOperator::beam_profiles_from_pass`] for that operator; empty (no change) when
/// its source is flat or [`OrdinatesOptions::beam_profiles`] is off.
#[derive(Clone, Debug, Default)]
pub struct BeamProfiles {
    bins: usize,
    cells: usize,
    /// Light-major, `lights × bins`: the bin-averaged phase function of each light.
    phase: Vec<f64>,
    /// Light-major, `lights × cells`: per axis, `τ_c (J r − D J)` of the light's source
    /// function at unit phase (`J = σs E / (σt* h)`), `r` the beam's relative half-change
    /// across the cell and `D` the neighbours' difference the sweep takes.
    correction: Vec<[f32; 3]>,
}

impl BeamProfiles {
    /// How many lights the profiles are of.
    pub fn lights(&self) -> usize {
        self.correction.len().checked_div(self.cells).unwrap_or(0)
    }

    /// Whether the profiles are of an operator with `cells` cells and `bins` bins.
    pub(super) fn fits(&self, cells: usize, bins: usize) -> bool {
        self.cells == cells && self.bins == bins
    }

    /// Adds cell `c`'s change for `bin` to `slopes` (signed per axis by `sign`, ±1 for a
    /// piece travelling forward or backward).
    #[inline(always)]
    pub(super) fn add_to(&self, c: usize, bin: usize, sign: [f64; 3], slopes: &mut [f64; 3]) {
        for (phase, correction) in self
            .phase
            .chunks_exact(self.bins)
            .zip(self.correction.chunks_exact(self.cells))
        {
            let w = phase[bin];
            let d = correction[c];
            for a in 0..3 {
                slopes[a] += sign[a] * w * d[a] as f64;
            }
        }
    }
}

/// The linear fit's half-change across a cell, relative to the mean, of `e^{−κ x}` over
/// `x ∈ [0, 1]`: `6 (x̄ − ½)` with `x̄ = 1/κ − 1/(e^κ − 1)` its mean position (the fit keeps
/// the first moment, so the source's mean depth). `−κ/2` for thin cells; beyond `|r| = 1`
/// (κ ≈ 2.2) the fit is negative at the far face, as a linear profile must be to keep the
/// moment.
pub fn exponential_half_change(kappa: f64) -> f64 {
    if kappa.abs() < 1e-2 {
        // x̄ − ½ = −κ/12 + κ³/720 − …
        -0.5 * kappa + kappa * kappa * kappa / 120.0
    } else {
        let mean = 1.0 / kappa - 1.0 / kappa.exp_m1();
        6.0 * (mean - 0.5)
    }
}

/// One directional light for [`OrdinatesOperator::beam_profiles`]: its direction of travel,
/// cell irradiance and the optical depth's change across each cell per axis.
pub type BeamLight<'a> = (DVec3, &'a [f64], &'a [[f64; 3]]);

/// One directional light for [`OrdinatesOperator::profiles_of`], read per cell where a pass
/// keeps it in its own form: its direction of travel, irradiance and the optical depth's
/// change across the cell per axis.
struct LightOf<'a> {
    direction: DVec3,
    irradiance: Box<dyn Fn(usize) -> f64 + Sync + 'a>,
    depth_change: Box<dyn Fn(usize) -> [f64; 3] + Sync + 'a>,
}

impl OrdinatesOperator {
    /// The profiles of directional `lights` (direction of travel, cell irradiance `E T_L`
    /// as the external density takes it, and per cell the change across it of the optical
    /// depth toward the light along each grid axis, upper face less lower face).
    pub fn beam_profiles(&self, lights: &[BeamLight]) -> Result<BeamProfiles, OrdinatesError> {
        let n = self.grid.cell_count();
        for &(_, irradiance, depth_change) in lights {
            for (what, got) in [
                ("cell irradiance", irradiance.len()),
                ("optical depth change", depth_change.len()),
            ] {
                if got != n {
                    return Err(OrdinatesError::Length {
                        what,
                        got,
                        expected: n,
                    });
                }
            }
        }
        let lights: Vec<LightOf> = lights
            .iter()
            .map(|&(direction, e, k)| LightOf {
                direction,
                irradiance: Box::new(move |c| e[c]),
                depth_change: Box::new(move |c| k[c]),
            })
            .collect();
        Ok(self.profiles_of(&lights))
    }

    /// [`beam_profiles`](Self::beam_profiles) of a light pass's directional lights (the
    /// pass must be for this operator's grid), the optical depth's change across each cell
    /// from the pass's corner depths (the mean of the cell's four edges along each axis).
    /// Point and spot lights keep the neighbours' slopes.
    pub fn beam_profiles_from_pass(
        &self,
        pass: &LightPass,
    ) -> Result<BeamProfiles, OrdinatesError> {
        self.check_pass(pass)?;
        let grid = self.grid;
        let mut lights: Vec<LightOf> = Vec::new();
        for f in &pass.fields {
            let Light::Directional { direction, .. } = f.light else {
                continue;
            };
            let depth = f.corner_optical_depth.as_slice();
            if depth.len() != grid.corner_count() {
                return Err(OrdinatesError::Length {
                    what: "corner optical depth",
                    got: depth.len(),
                    expected: grid.corner_count(),
                });
            }
            let irradiance = f.cell_irradiance.as_slice();
            let depth_change = move |c: usize| {
                let [i, j, k] = grid.coords(c);
                let at = |di: usize, dj: usize, dk: usize| {
                    depth[grid.corner_index(i + di, j + dj, k + dk)] as f64
                };
                let mut d = [0.0; 3];
                for u in 0..2 {
                    for v in 0..2 {
                        d[0] += at(1, u, v) - at(0, u, v);
                        d[1] += at(u, 1, v) - at(u, 0, v);
                        d[2] += at(u, v, 1) - at(u, v, 0);
                    }
                }
                d.map(|x| 0.25 * x)
            };
            lights.push(LightOf {
                direction,
                irradiance: Box::new(move |c| irradiance[c] as f64),
                depth_change: Box::new(depth_change),
            });
        }
        Ok(self.profiles_of(&lights))
    }

    /// The profiles of `lights`: empty with a flat source or the option off.
    fn profiles_of(&self, lights: &[LightOf]) -> BeamProfiles {
        if !(self.linear_source() && self.options.beam_profiles) || lights.is_empty() {
            return BeamProfiles::default();
        }
        let n = self.grid.cell_count();
        let m = self.bins.len();
        let mut phase = Vec::with_capacity(lights.len() * m);
        let mut correction = vec![[0.0f32; 3]; lights.len() * n];
        for (light, out) in lights.iter().zip(correction.chunks_exact_mut(n)) {
            phase.extend(bin_averaged_phase(
                &self.bins,
                &self.phase,
                light.direction,
                self.options.first_bounce_quadrature,
            ));
            // The light's source function at unit phase, as the sweep's column holds it.
            let source_function: Vec<f64> = (0..n)
                .into_par_iter()
                .map(|c| {
                    let tau = self.level_tau[self.cell_level[c] as usize];
                    self.sigma_s[c] * (light.irradiance)(c) * per_optical_side(tau)
                })
                .collect();
            out.par_iter_mut().enumerate().for_each(|(c, d)| {
                let tau = self.level_tau[self.cell_level[c] as usize];
                let own = source_function[c];
                if tau <= 0.0 || own == 0.0 {
                    return;
                }
                let differences =
                    self.central_differences(&source_function, c, self.grid.coords(c));
                let change = (light.depth_change)(c);
                for a in 0..3 {
                    let exact = own * exponential_half_change(change[a]);
                    d[a] = (tau * (exact - differences[a])) as f32;
                }
            });
        }
        BeamProfiles {
            bins: m,
            cells: n,
            phase,
            correction,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::exponential_half_change;

    /// The fit's slope is the first moment of the exponential, by quadrature.
    #[test]
    fn half_change_keeps_the_first_moment() {
        for kappa in [-6.0, -2.5, -0.3, -0.005, 0.0, 0.004, 0.2, 1.0, 2.5, 10.0] {
            let n = 20_000;
            let (mut zeroth, mut first) = (0.0, 0.0);
            for i in 0..n {
                let x = (i as f64 + 0.5) / n as f64;
                let f = (-kappa * x).exp();
                zeroth += f;
                first += (x - 0.5) * f;
            }
            let expected = 6.0 * first / zeroth;
            let r = exponential_half_change(kappa);
            assert!(
                (r - expected).abs() < 1e-6 * (1.0 + expected.abs()),
                "κ {kappa}: {r} against {expected}"
            );
        }
    }
}
