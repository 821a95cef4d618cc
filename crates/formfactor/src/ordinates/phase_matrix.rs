//! The `M × M` bin-to-bin phase matrix `P_lj` (p averaged over `ω ∈ bin l`, `ω' ∈ bin j`),
//! renormalised so that `Σ_l P_lj Ω_l = 1` for every `j` (scattering keeps energy exactly).

use glam::DVec3;
use medium::PhaseFunction;
use rayon::prelude::*;

use super::bins::DirectionBins;

/// Dense `M × M` phase matrix, row-major (`values[l·M + j]` = `P_lj`, from bin `j` into `l`).
#[derive(Clone, Debug, PartialEq)]
pub struct PhaseMatrix {
    m: usize,
    values: Vec<f64>,
}

/// Sub-squares per bin side for the outgoing bin: about `5·10⁷` phase evaluations in all.
pub fn default_quadrature(bins: &DirectionBins) -> usize {
    let m = bins.len() as f64;
    ((5e7 / (m * m)).powf(0.25).floor() as usize).clamp(2, 12)
}

impl PhaseMatrix {
    /// Quadrature with `k × k` sub-squares in the outgoing bin `l` and `(k+1) × (k+1)` in the
    /// incoming bin `j` (different node sets, so the diagonal never evaluates a peaked `p`
    /// at `ω = ω'` only), then column renormalisation.
    pub fn new(bins: &DirectionBins, phase: &PhaseFunction, k: usize) -> Self {
        Self::from_density(bins, |mu| phase.eval(mu), k)
    }

    /// [`new`](Self::new) for any phase density of the scattering angle's cosine (it need not
    /// be normalised: the columns are renormalised).
    pub fn from_density(
        bins: &DirectionBins,
        density: impl Fn(f64) -> f64 + Sync,
        k: usize,
    ) -> Self {
        let m = bins.len();
        let quad = |kk: usize| -> Vec<Vec<(DVec3, f64)>> {
            (0..m)
                .map(|l| {
                    let mut q = Vec::new();
                    bins.rect(l).quadrature(kk, &mut q);
                    q
                })
                .collect()
        };
        let out_q = quad(k.max(1));
        let in_q = quad(k.max(1) + 1);
        let omega = bins.solid_angles();
        let mut values = vec![0.0; m * m];
        values.par_chunks_mut(m).enumerate().for_each(|(l, row)| {
            for (j, v) in row.iter_mut().enumerate() {
                let mut s = 0.0;
                for &(w_out, a) in &out_q[l] {
                    let mut inner = 0.0;
                    for &(w_in, b) in &in_q[j] {
                        inner += b * density(w_out.dot(w_in));
                    }
                    s += a * inner;
                }
                *v = s / (omega[l] * omega[j]);
            }
        });
        for j in 0..m {
            let total: f64 = (0..m).map(|l| values[l * m + j] * omega[l]).sum();
            for l in 0..m {
                values[l * m + j] /= total;
            }
        }
        PhaseMatrix { m, values }
    }

    /// Tilts every column `j` as `P_lj ← P_lj e^{α_j + β_j ω_l·ω_j}` (bin centres) so that,
    /// besides energy (`Σ_l P_lj Ω_l = 1`), the discrete mean cosine `Σ_l P_lj Ω_l ω_l·ω_j`
    /// equals `g` exactly (Hunter & Guo's idea of phase-function normalisation that keeps the
    /// asymmetry factor): coarse bins otherwise lose part of a forward peak's asymmetry.
    /// Columns where `g` is out of reach of the tilt are left energy-normalised.
    pub fn match_asymmetry(&mut self, bins: &DirectionBins, g: f64) {
        let m = self.m;
        let omega = bins.solid_angles();
        let c = bins.centres();
        for j in 0..m {
            let w: Vec<f64> = (0..m).map(|l| self.values[l * m + j] * omega[l]).collect();
            let mu: Vec<f64> = (0..m).map(|l| c[l].dot(c[j])).collect();
            // Mean cosine under the tilt β (monotone increasing in β).
            let mean = |beta: f64| -> f64 {
                let (mut z, mut zm) = (0.0, 0.0);
                for (wl, ml) in w.iter().zip(&mu) {
                    let e = wl * (beta * (ml - 1.0)).exp();
                    z += e;
                    zm += e * ml;
                }
                zm / z
            };
            let (mut lo, mut hi) = (-200.0f64, 200.0f64);
            if !(mean(lo) < g && mean(hi) > g) {
                continue;
            }
            for _ in 0..200 {
                let mid = 0.5 * (lo + hi);
                if mean(mid) < g {
                    lo = mid;
                } else {
                    hi = mid;
                }
            }
            let beta = 0.5 * (lo + hi);
            let z: f64 = w
                .iter()
                .zip(&mu)
                .map(|(wl, ml)| wl * (beta * (ml - 1.0)).exp())
                .sum();
            for (l, ml) in mu.iter().enumerate() {
                self.values[l * m + j] *= (beta * (ml - 1.0)).exp() / z;
            }
        }
    }

    /// Raises every column's discrete mean cosine to `g` by moving scattering from the bins
    /// nearest the forward direction into the bin itself (no change of bin): a uniform
    /// fraction `t ≤ 1` of each bin in the smallest forward neighbourhood
    /// `{l : ω_l·ω_j ≥ μ_k}` that can make up the deficit. Side and back scattering stay
    /// as the quadrature gave them, where a tilt `e^{β ω_l·ω_j}` thins the back to make up a
    /// forward deficit. Columns whose mean cosine is at or above `g` already, or whose
    /// forward neighbours cannot make it up, are tilted by [`match_asymmetry`](Self::match_asymmetry)'s rule.
    pub fn match_asymmetry_forward(&mut self, bins: &DirectionBins, g: f64) {
        let m = self.m;
        let omega = bins.solid_angles();
        let c = bins.centres();
        let mut untouched = Vec::new();
        for j in 0..m {
            // w_l: the share of column j scattered into bin l (Σ w = 1).
            let w: Vec<f64> = (0..m).map(|l| self.values[l * m + j] * omega[l]).collect();
            let mu: Vec<f64> = (0..m).map(|l| c[l].dot(c[j])).collect();
            let mean: f64 = w.iter().zip(&mu).map(|(a, b)| a * b).sum();
            let deficit = g - mean;
            if deficit <= 0.0 {
                untouched.push(j);
                continue;
            }
            let mut order: Vec<usize> = (0..m).filter(|&l| l != j).collect();
            order.sort_by(|&a, &b| mu[b].total_cmp(&mu[a]));
            // Grow the neighbourhood a ring of equal cosines at a time.
            let mut gain = 0.0;
            let mut end = 0;
            let mut found = None;
            while end < order.len() {
                let ring = mu[order[end]];
                while end < order.len() && mu[order[end]] >= ring - 1e-12 {
                    let l = order[end];
                    gain += w[l] * (1.0 - mu[l]);
                    end += 1;
                }
                if gain >= deficit {
                    found = Some((end, deficit / gain));
                    break;
                }
            }
            let Some((end, t)) = found else {
                untouched.push(j);
                continue;
            };
            let mut moved = 0.0;
            for &l in &order[..end] {
                let share = t * w[l];
                moved += share;
                self.values[l * m + j] -= share / omega[l];
            }
            self.values[j * m + j] += moved / omega[j];
        }
        if !untouched.is_empty() {
            let mut tilted = self.clone();
            tilted.match_asymmetry(bins, g);
            for j in untouched {
                for l in 0..m {
                    self.values[l * m + j] = tilted.values[l * m + j];
                }
            }
        }
    }

    /// With [`default_quadrature`].
    pub fn with_default_quadrature(bins: &DirectionBins, phase: &PhaseFunction) -> Self {
        Self::new(bins, phase, default_quadrature(bins))
    }

    pub fn len(&self) -> usize {
        self.m
    }

    pub fn is_empty(&self) -> bool {
        self.m == 0
    }

    /// `P_lj`: density per steradian of scattering from bin `j` into bin `l`.
    #[inline]
    pub fn get(&self, l: usize, j: usize) -> f64 {
        self.values[l * self.m + j]
    }

    /// Row-major values.
    pub fn values(&self) -> &[f64] {
        &self.values
    }

    /// `Σ_l P_lj Ω_l` for column `j` (1 after renormalisation).
    pub fn column_energy(&self, bins: &DirectionBins, j: usize) -> f64 {
        let omega = bins.solid_angles();
        (0..self.m).map(|l| self.get(l, j) * omega[l]).sum()
    }

    /// Discrete mean cosine of column `j`: `Σ_l P_lj Ω_l (ω_l·ω_j)`.
    pub fn mean_cosine(&self, bins: &DirectionBins, j: usize) -> f64 {
        let omega = bins.solid_angles();
        let c = bins.centres();
        (0..self.m)
            .map(|l| self.get(l, j) * omega[l] * c[l].dot(c[j]))
            .sum()
    }
}

/// Bin averages `p̄_l(d) = (1/Ω_l) ∫_{bin l} p(ω·d) dω` for light flowing along unit `d`,
/// `k × k` sub-squares per bin, renormalised so that `Σ_l p̄_l Ω_l = 1` exactly.
pub fn bin_averaged_phase(
    bins: &DirectionBins,
    phase: &PhaseFunction,
    direction: DVec3,
    k: usize,
) -> Vec<f64> {
    let d = direction.normalize();
    let mut q = Vec::new();
    let mut p: Vec<f64> = (0..bins.len())
        .map(|l| {
            q.clear();
            bins.rect(l).quadrature(k, &mut q);
            q.iter()
                .map(|&(w, a)| a * phase.eval(w.dot(d)))
                .sum::<f64>()
                / bins.solid_angles()[l]
        })
        .collect();
    let total: f64 = p.iter().zip(bins.solid_angles()).map(|(a, b)| a * b).sum();
    p.iter_mut().for_each(|v| *v /= total);
    p
}

/// Accuracy of a phase matrix against its continuous phase function.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PhaseMatrixError {
    /// Largest `|Σ_l P_lj Ω_l − 1|` over columns.
    pub energy: f64,
    /// Solid-angle-weighted mean over `j` of the discrete mean cosine `Σ_l P_lj Ω_l (ω_l·ω_j)`
    /// (bin centres), against the continuous `g`.
    pub mean_cosine: f64,
    /// Largest relative error of once-scattered bin radiance for a beam along each of a set
    /// of test directions: `P` applied to the beam's bin vs `p̄_l(d)` (the continuous phase
    /// function averaged over each bin), over bins where `p̄` exceeds 1 % of its maximum.
    pub single_scatter_max_rel: f64,
}

/// Measures [`PhaseMatrixError`] with beams along every bin centre.
pub fn phase_matrix_error(
    bins: &DirectionBins,
    matrix: &PhaseMatrix,
    phase: &PhaseFunction,
) -> PhaseMatrixError {
    let m = bins.len();
    let omega = bins.solid_angles();
    let energy = (0..m)
        .map(|j| (matrix.column_energy(bins, j) - 1.0).abs())
        .fold(0.0, f64::max);
    let mean_cosine = (0..m)
        .map(|j| matrix.mean_cosine(bins, j) * omega[j])
        .sum::<f64>()
        / (4.0 * std::f64::consts::PI);
    let single_scatter_max_rel = (0..m)
        .into_par_iter()
        .map(|j| {
            // A beam spread uniformly over bin j: the exact once-scattered bin average is
            // P_exact[:, j]; compare against p̄ at the centre direction, which is what a beam
            // along the bin's centre gives — both are "continuous" answers for a beam in bin j,
            // the difference between them being the discretisation the solver makes.
            let exact = bin_averaged_phase(bins, phase, bins.centres()[j], 12);
            let max = exact.iter().copied().fold(0.0, f64::max);
            (0..m)
                .filter(|&l| exact[l] > 0.01 * max)
                .map(|l| (matrix.get(l, j) - exact[l]).abs() / exact[l])
                .fold(0.0, f64::max)
        })
        .reduce(|| 0.0, f64::max);
    PhaseMatrixError {
        energy,
        mean_cosine,
        single_scatter_max_rel,
    }
}
