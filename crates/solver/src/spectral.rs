//! Spectral radius of `K` by power iteration, and the Jacobi iteration count it predicts.

use serde::{Deserialize, Serialize};

use crate::operator::TransportOperator;
use crate::vecops::Reducer;

/// Result of [`spectral_radius`].
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct SpectralEstimate {
    /// Estimated spectral radius `ρ(K)` (the growth factor `‖K x‖ / ‖x‖` of the last step).
    pub rho: f64,
    /// Power-iteration steps taken (applications of `K`).
    pub iterations: usize,
    /// Whether successive estimates agreed to the tolerance.
    pub converged: bool,
}

/// Power iteration on `K` from a deterministic, strictly positive start vector (so the
/// Perron vector of a non-negative operator is never missed). Stops when successive growth
/// factors agree to `tolerance` (relative) or after `max_iterations` steps. The estimate
/// converges like `|λ₂/λ₁|^k`; for operators whose dominant eigenvalues form a complex pair
/// or a ± pair the growth factor oscillates and `converged` stays false.
pub fn spectral_radius(
    op: &dyn TransportOperator,
    max_iterations: usize,
    tolerance: f64,
) -> SpectralEstimate {
    power_iteration(op, max_iterations, tolerance, &|| false).unwrap_or(SpectralEstimate {
        rho: f64::NAN,
        iterations: 0,
        converged: false,
    })
}

/// [`spectral_radius`] that checks `control` before each application of `K` and gives
/// `None` once it is cancelled (a prediction's probe, which a Ctrl-C should stop within one
/// step rather than after all of them).
pub fn spectral_radius_cancellable(
    op: &dyn TransportOperator,
    max_iterations: usize,
    tolerance: f64,
    control: &crate::SolveControl,
) -> Option<SpectralEstimate> {
    power_iteration(op, max_iterations, tolerance, &|| control.is_cancelled())
}

fn power_iteration(
    op: &dyn TransportOperator,
    max_iterations: usize,
    tolerance: f64,
    stop: &dyn Fn() -> bool,
) -> Option<SpectralEstimate> {
    let n = op.len();
    if n == 0 {
        return Some(SpectralEstimate {
            rho: 0.0,
            iterations: 0,
            converged: true,
        });
    }
    let mut red = Reducer::new(n);
    // 1 plus a small deterministic perturbation (golden-ratio sequence) to break symmetry.
    let mut x: Vec<f64> = (0..n)
        .map(|i| 1.0 + 0.25 * ((i as f64 * 0.618_033_988_749_895).fract() - 0.5))
        .collect();
    let norm = red.norm(&x);
    x.iter_mut().for_each(|v| *v /= norm);
    let mut y = vec![0.0; n];
    let mut previous = f64::NAN;
    let mut rho = 0.0;
    for k in 1..=max_iterations {
        if stop() {
            return None;
        }
        op.apply(&x, &mut y);
        rho = red.norm(&y);
        if !rho.is_finite() {
            return Some(SpectralEstimate {
                rho,
                iterations: k,
                converged: false,
            });
        }
        if rho == 0.0 {
            // K x = 0: x is in the null space; for a nilpotent or zero operator ρ = 0.
            return Some(SpectralEstimate {
                rho: 0.0,
                iterations: k,
                converged: true,
            });
        }
        if (rho - previous).abs() <= tolerance * rho {
            return Some(SpectralEstimate {
                rho,
                iterations: k,
                converged: true,
            });
        }
        previous = rho;
        let inv = 1.0 / rho;
        for (xi, yi) in x.iter_mut().zip(&y) {
            *xi = yi * inv;
        }
    }
    Some(SpectralEstimate {
        rho,
        iterations: max_iterations,
        converged: false,
    })
}

/// Jacobi iterations to reduce the residual by `tolerance` at spectral radius `rho`:
/// `ceil(ln tol / ln ρ)`. `None` when `ρ ≥ 1` (Jacobi does not converge) or inputs are not
/// finite; `Some(1)` for `ρ = 0`.
pub fn predicted_iterations(rho: f64, tolerance: f64) -> Option<usize> {
    if !(rho.is_finite() && tolerance.is_finite() && rho >= 0.0 && tolerance > 0.0) || rho >= 1.0 {
        return None;
    }
    if tolerance >= 1.0 {
        return Some(0);
    }
    if rho == 0.0 {
        return Some(1);
    }
    // The small allowance keeps exact powers (ρ = 0.1, tol = 1e-5 → 5) from rounding up.
    Some((tolerance.ln() / rho.ln() - 1e-9).ceil() as usize)
}
