//! Phase functions, normalised over the sphere: `∫ p(ω·ω') dω = 1`.
//!
//! Convention (physics.md): `cos θ = ω·ω'` where both are directions of light *flow*, so
//! `g > 0` scatters forward (Max eq. 10).

use std::f64::consts::PI;

use glam::DVec3;
use rand::Rng;
use serde::{Deserialize, Serialize};

use crate::MediumError;

const INV_4PI: f64 = 1.0 / (4.0 * PI);

/// The phase functions volrad supports, dispatched by `match` (no trait objects in hot loops).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum PhaseFunction {
    #[default]
    Isotropic,
    /// Henyey–Greenstein with asymmetry `g ∈ (-1, 1)`.
    HenyeyGreenstein { g: f64 },
    /// Blinn's (1982) phase function of large diffuse (Lambertian) spheres (Max §V).
    LambertianSphere,
    /// Blasi & Wuethrich's two-lobe mix `r·HG(g1) + (1−r)·HG(g2)`, typically one forward and
    /// one backward lobe.
    TwoLobe { r: f64, g1: f64, g2: f64 },
}

#[inline]
fn hg(g: f64, cos_theta: f64) -> f64 {
    let denom = 1.0 + g * g - 2.0 * g * cos_theta;
    INV_4PI * (1.0 - g * g) / (denom * denom.sqrt())
}

/// Inverse CDF of HG in `cos θ` for a uniform `u ∈ [0, 1)`.
#[inline]
fn hg_sample_cos(g: f64, u: f64) -> f64 {
    if g.abs() < 1e-4 {
        return 1.0 - 2.0 * u;
    }
    let s = (1.0 - g * g) / (1.0 - g + 2.0 * g * u);
    ((1.0 + g * g - s * s) / (2.0 * g)).clamp(-1.0, 1.0)
}

/// The lobe [`PhaseFunction::eval_from_lobe`] takes an incident field of scalar flux `fluence`
/// and net flux vector `current` to be: its mean cosine `|J| / φ` (at most 1) and its axis
/// (`J`'s direction; +z, which no lobe of mean cosine 0 depends on, where `J` vanishes).
pub fn incident_lobe(fluence: f64, current: DVec3) -> (f64, DVec3) {
    let length = current.length();
    if !(fluence > 0.0 && length > 0.0) {
        return (0.0, DVec3::Z);
    }
    ((length / fluence).min(1.0), current / length)
}

impl PhaseFunction {
    /// Refuses parameters for which the function is not a normalisable density.
    pub fn validate(&self) -> Result<(), MediumError> {
        let g_ok = |g: f64| g.is_finite() && g.abs() < 1.0;
        match *self {
            PhaseFunction::HenyeyGreenstein { g } if !g_ok(g) => Err(MediumError::invalid(
                "phase",
                format!("Henyey–Greenstein g = {g}: |g| must be below 1"),
            )),
            PhaseFunction::TwoLobe { r, g1, g2 } if !(g_ok(g1) && g_ok(g2)) => {
                Err(MediumError::invalid(
                    "phase",
                    format!("two-lobe g1 = {g1}, g2 = {g2}: |g| must be below 1 (r = {r})"),
                ))
            }
            PhaseFunction::TwoLobe { r, .. } if !(0.0..=1.0).contains(&r) => {
                Err(MediumError::invalid(
                    "phase",
                    format!("two-lobe weight r = {r} is outside [0, 1]"),
                ))
            }
            _ => Ok(()),
        }
    }

    pub fn is_isotropic(&self) -> bool {
        match *self {
            PhaseFunction::Isotropic => true,
            PhaseFunction::HenyeyGreenstein { g } => g == 0.0,
            PhaseFunction::TwoLobe { r, g1, g2 } => {
                (r == 1.0 || g2 == 0.0) && (r == 0.0 || g1 == 0.0)
            }
            PhaseFunction::LambertianSphere => false,
        }
    }

    /// Density per steradian for the cosine between the incoming and outgoing flow directions.
    #[inline]
    pub fn eval(&self, cos_theta: f64) -> f64 {
        match *self {
            PhaseFunction::Isotropic => INV_4PI,
            PhaseFunction::HenyeyGreenstein { g } => hg(g, cos_theta),
            PhaseFunction::TwoLobe { r, g1, g2 } => {
                r * hg(g1, cos_theta) + (1.0 - r) * hg(g2, cos_theta)
            }
            PhaseFunction::LambertianSphere => {
                // Blinn's P(α) = 8/(3π) (sin α + (π − α) cos α), α = π − θ the phase angle.
                let alpha = PI - cos_theta.clamp(-1.0, 1.0).acos();
                INV_4PI * 8.0 / (3.0 * PI) * (alpha.sin() + (PI - alpha) * alpha.cos())
            }
        }
    }

    /// Mean cosine `⟨cos θ⟩` (the first Legendre moment).
    pub fn mean_cosine(&self) -> f64 {
        match *self {
            PhaseFunction::Isotropic => 0.0,
            PhaseFunction::HenyeyGreenstein { g } => g,
            PhaseFunction::TwoLobe { r, g1, g2 } => r * g1 + (1.0 - r) * g2,
            // ∫ p cos θ dω for Blinn's sphere: −4/9 (it scatters backward, like the Moon).
            PhaseFunction::LambertianSphere => -4.0 / 9.0,
        }
    }

    /// The light this phase function scatters toward `cos θ` from the axis of an incident
    /// field whose directions spread about that axis as a Henyey–Greenstein lobe of mean
    /// cosine `incident` (0: isotropic, 1: a beam), per unit of incident fluence. Exact for
    /// Henyey–Greenstein and the two-lobe mix, whose convolution with such a lobe is a
    /// Henyey–Greenstein of `g · incident` (the Legendre moments multiply: `g^l incident^l`);
    /// for other phase functions the lobe is taken as a beam of that share and an isotropic
    /// rest. Integrates to 1 over the sphere in both cases. What the light of emitting cells
    /// scatters on its first collision: the emitter pass gives each cell the field's fluence
    /// and flux vector, whose ratio is the mean cosine (docs/physics.md).
    pub fn eval_from_lobe(&self, incident: f64, cos_theta: f64) -> f64 {
        let a = incident.clamp(0.0, 1.0);
        match *self {
            PhaseFunction::Isotropic => INV_4PI,
            PhaseFunction::HenyeyGreenstein { g } => hg(g * a, cos_theta),
            PhaseFunction::TwoLobe { r, g1, g2 } => {
                r * hg(g1 * a, cos_theta) + (1.0 - r) * hg(g2 * a, cos_theta)
            }
            PhaseFunction::LambertianSphere => a * self.eval(cos_theta) + (1.0 - a) * INV_4PI,
        }
    }

    /// Samples `cos θ` from the density (importance sampling for Monte Carlo).
    pub fn sample_cos<R: Rng + ?Sized>(&self, rng: &mut R) -> f64 {
        match *self {
            PhaseFunction::Isotropic => 1.0 - 2.0 * rng.random::<f64>(),
            PhaseFunction::HenyeyGreenstein { g } => hg_sample_cos(g, rng.random()),
            PhaseFunction::TwoLobe { r, g1, g2 } => {
                let g = if rng.random::<f64>() < r { g1 } else { g2 };
                hg_sample_cos(g, rng.random())
            }
            PhaseFunction::LambertianSphere => {
                // Rejection against the uniform density; the acceptance rate is 3/8.
                let max = self.eval(-1.0);
                loop {
                    let c = 1.0 - 2.0 * rng.random::<f64>();
                    if rng.random::<f64>() * max <= self.eval(c) {
                        return c;
                    }
                }
            }
        }
    }

    /// Samples an outgoing flow direction for light arriving along `incoming` (unit).
    pub fn sample<R: Rng + ?Sized>(&self, incoming: DVec3, rng: &mut R) -> DVec3 {
        let cos_theta = self.sample_cos(rng);
        let phi = 2.0 * PI * rng.random::<f64>();
        rotate_about(incoming, cos_theta, phi)
    }
}

/// The unit vector at polar angle `acos(cos_theta)` and azimuth `phi` about unit `axis`.
pub fn rotate_about(axis: DVec3, cos_theta: f64, phi: f64) -> DVec3 {
    let sin_theta = (1.0 - cos_theta * cos_theta).max(0.0).sqrt();
    let (t, b) = axis.any_orthonormal_pair();
    (t * (sin_theta * phi.cos()) + b * (sin_theta * phi.sin()) + axis * cos_theta).normalize()
}

#[cfg(test)]
mod tests {
    #[test]
    fn a_lobe_of_incident_light_scatters_as_its_moments_say() {
        let phases = [
            PhaseFunction::Isotropic,
            PhaseFunction::HenyeyGreenstein { g: 0.85 },
            PhaseFunction::HenyeyGreenstein { g: -0.3 },
            PhaseFunction::TwoLobe {
                r: 0.7,
                g1: 0.8,
                g2: -0.4,
            },
            PhaseFunction::LambertianSphere,
        ];
        // Midpoint rule in cos θ: ∫ f dω = 2π ∫ f dμ.
        let steps = 200_000;
        let integral = |f: &dyn Fn(f64) -> f64| -> f64 {
            (0..steps)
                .map(|k| {
                    let mu = -1.0 + (k as f64 + 0.5) * 2.0 / steps as f64;
                    f(mu) * 2.0 / steps as f64
                })
                .sum::<f64>()
                * 2.0
                * PI
        };
        for p in phases {
            for a in [0.0, 0.3, 0.7, 1.0] {
                let norm = integral(&|mu| p.eval_from_lobe(a, mu));
                assert!((norm - 1.0).abs() < 1e-3, "{p:?}, incident {a}: ∫ = {norm}");
                // The scattered light's mean cosine about the axis is the phase function's
                // times the incident lobe's (the first Legendre moments multiply).
                let mean = integral(&|mu| mu * p.eval_from_lobe(a, mu));
                let want = p.mean_cosine() * a;
                assert!(
                    (mean - want).abs() < 2e-3,
                    "{p:?}, incident {a}: {mean} vs {want}"
                );
            }
            // A beam scatters as the phase function itself; an isotropic field isotropically.
            for mu in [-0.9, 0.0, 0.5, 0.99] {
                assert!((p.eval_from_lobe(1.0, mu) - p.eval(mu)).abs() < 1e-12);
                assert!((p.eval_from_lobe(0.0, mu) - INV_4PI).abs() < 1e-12);
            }
        }
    }

    use super::*;
    use rand::SeedableRng;

    fn all() -> Vec<PhaseFunction> {
        vec![
            PhaseFunction::Isotropic,
            PhaseFunction::HenyeyGreenstein { g: 0.6 },
            PhaseFunction::HenyeyGreenstein { g: -0.3 },
            PhaseFunction::HenyeyGreenstein { g: 0.85 },
            PhaseFunction::LambertianSphere,
            PhaseFunction::TwoLobe {
                r: 0.7,
                g1: 0.8,
                g2: -0.4,
            },
        ]
    }

    /// ∫ f(cos θ) dω by Gauss–Legendre-free composite Simpson on a fine grid in cos θ.
    fn integrate(f: impl Fn(f64) -> f64) -> f64 {
        let n = 200_000;
        let h = 2.0 / n as f64;
        let mut s = f(-1.0) + f(1.0);
        for i in 1..n {
            let x = -1.0 + i as f64 * h;
            s += if i % 2 == 1 { 4.0 } else { 2.0 } * f(x);
        }
        2.0 * PI * s * h / 3.0
    }

    #[test]
    fn normalised_over_the_sphere() {
        for p in all() {
            let total = integrate(|c| p.eval(c));
            assert!((total - 1.0).abs() < 1e-6, "{p:?} integrates to {total}");
        }
    }

    #[test]
    fn mean_cosine_matches_quadrature() {
        for p in all() {
            let m = integrate(|c| p.eval(c) * c);
            assert!(
                (m - p.mean_cosine()).abs() < 1e-6,
                "{p:?}: {m} vs {}",
                p.mean_cosine()
            );
        }
    }

    #[test]
    fn sampling_matches_density() {
        // Histogram of sampled cos θ in 20 bins against the integrated density per bin.
        let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(11);
        let bins = 20;
        let n = 400_000;
        for p in all() {
            let mut hist = vec![0usize; bins];
            for _ in 0..n {
                let c = p.sample_cos(&mut rng);
                let b = (((c + 1.0) / 2.0) * bins as f64).min(bins as f64 - 1.0) as usize;
                hist[b] += 1;
            }
            for (b, &count) in hist.iter().enumerate() {
                let lo = -1.0 + 2.0 * b as f64 / bins as f64;
                let hi = lo + 2.0 / bins as f64;
                let expected = integrate(|c| if c >= lo && c < hi { p.eval(c) } else { 0.0 });
                let got = count as f64 / n as f64;
                let sigma = (expected * (1.0 - expected) / n as f64).sqrt();
                assert!(
                    (got - expected).abs() < 5.0 * sigma + 1e-4,
                    "{p:?} bin {b}: sampled {got}, density {expected}"
                );
            }
        }
    }

    #[test]
    fn sampled_direction_has_requested_cosine() {
        let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(3);
        let axis = DVec3::new(0.3, -0.8, 0.52).normalize();
        for _ in 0..1000 {
            let c: f64 = 1.0 - 2.0 * rng.random::<f64>();
            let d = rotate_about(axis, c, rng.random::<f64>() * 6.0);
            assert!((d.length() - 1.0).abs() < 1e-12);
            assert!((d.dot(axis) - c).abs() < 1e-9);
        }
    }

    #[test]
    fn refuses_bad_parameters() {
        assert!(PhaseFunction::HenyeyGreenstein { g: 1.0 }
            .validate()
            .is_err());
        assert!(PhaseFunction::HenyeyGreenstein { g: f64::NAN }
            .validate()
            .is_err());
        assert!(PhaseFunction::TwoLobe {
            r: 1.5,
            g1: 0.1,
            g2: 0.1
        }
        .validate()
        .is_err());
        assert!(PhaseFunction::HenyeyGreenstein { g: -0.99 }
            .validate()
            .is_ok());
    }
}
