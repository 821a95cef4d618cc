//! Solve options: the iterative method (parsed from strings such as `"sor:1.5"`) and the
//! stopping rule.

use std::fmt;
use std::str::FromStr;

use serde::{Deserialize, Serialize};

/// The smoother inside a [`Method::CoarseCorrected`] two-level iteration.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub enum Smoother {
    Jacobi,
    GaussSeidel,
    Sor { omega: f64 },
}

/// An iterative method for `(I − K) g = E`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub enum Method {
    /// `g ← E + K g`; one operator application per iteration, parallel inside `apply`.
    Jacobi,
    /// In-place sweeps (rows or the operator's own sweep); sequential.
    GaussSeidel,
    /// Over-relaxed Gauss–Seidel, `0 < ω < 2`.
    Sor { omega: f64 },
    /// Restarted GMRES(m) with modified Gram–Schmidt; one application per iteration.
    Gmres { restart: usize },
    /// BiCGSTAB; two applications per iteration.
    BiCgStab,
    /// Conjugate gradients in the inner product `⟨x, y⟩_w = Σ w_i x_i y_i`, where
    /// `diag(w) K` is symmetric ([`TransportOperator::symmetrizer`](crate::TransportOperator::symmetrizer)).
    /// Needs `I − K` positive definite in that product, i.e. spectral radius below 1.
    ConjugateGradient,
    /// Conjugate gradients (as [`ConjugateGradient`](Self::ConjugateGradient)) preconditioned
    /// by the coarse-grid correction: `M⁻¹ = I + P (Pᵀ W (I − K) P)⁻¹ Pᵀ W`, self-adjoint in
    /// the same inner product. Aggregates as for [`CoarseCorrected`](Self::CoarseCorrected).
    CoarseCg,
    /// Conjugate gradients (as [`ConjugateGradient`](Self::ConjugateGradient)) preconditioned
    /// by the balancing two-level preconditioner
    /// `M⁻¹ = (I − Π) S (I − Π) + P (Pᵀ W (I − K) P)⁻¹ Pᵀ W`, where `Π = P (Pᵀ W P)⁻¹ Pᵀ W`
    /// is the W-orthogonal projection onto piecewise-constant vectors and
    /// `S = Σ_{j≤smoothing} K^j` smooths the rest. The coarse part is solved exactly on the
    /// operator's aggregates (a coarse-mesh balance), the rest by the fine iteration; each
    /// iteration costs `1 + smoothing` applications of `K` and one dense coarse solve.
    TwoLevelCg { smoothing: usize },
    /// Conjugate gradients preconditioned by diffusion-synthetic acceleration,
    /// `M⁻¹ = I + σs (σt − σs − ∇·D∇)⁻¹` from the operator's
    /// [`diffusion`](crate::TransportOperator::diffusion) approximation.
    DsaCg,
    /// Two-level iteration: a Galerkin coarse-grid correction on aggregates followed by one
    /// sweep of `inner`. With piecewise-constant prolongation and summation restriction the
    /// coarse equations are the energy balance of each aggregate: this is additive
    /// coarse-mesh rebalance, the transport-practice accelerator.
    CoarseCorrected { inner: Smoother },
}

/// Largest smoothing degree of [`Method::TwoLevelCg`] (each costs an application of `K`).
pub const MAX_TWO_LEVEL_SMOOTHING: usize = 8;

/// Default restart length for `"gmres"` without a number.
pub const DEFAULT_GMRES_RESTART: usize = 30;

/// Largest GMRES restart length: GMRES(m) keeps `m + 1` vectors of the unknowns' length, so
/// the bound keeps a typo (`gmres:100000000`) from asking for terabytes.
pub const MAX_GMRES_RESTART: usize = 1000;

/// How to stop and what to record.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SolveOptions {
    pub method: Method,
    /// Stop when `‖g − E − K g‖₂ / ‖E‖₂` is at or below this (absolute residual if `E = 0`).
    pub tolerance: f64,
    /// Iterations at most (see [`SolveReport::iterations`](crate::SolveReport::iterations)).
    pub max_iterations: usize,
    /// Keep the residual of every iteration in the report.
    pub record_history: bool,
}

impl Default for SolveOptions {
    fn default() -> Self {
        Self {
            method: Method::Jacobi,
            tolerance: 1e-5,
            max_iterations: 1000,
            record_history: true,
        }
    }
}

impl Method {
    /// The method's canonical string (parses back with [`FromStr`]).
    pub fn name(&self) -> String {
        self.to_string()
    }
}

impl fmt::Display for Smoother {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Smoother::Jacobi => write!(f, "jacobi"),
            Smoother::GaussSeidel => write!(f, "gs"),
            Smoother::Sor { omega } => write!(f, "sor:{omega}"),
        }
    }
}

impl fmt::Display for Method {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Method::Jacobi => write!(f, "jacobi"),
            Method::GaussSeidel => write!(f, "gauss-seidel"),
            Method::Sor { omega } => write!(f, "sor:{omega}"),
            Method::Gmres { restart } => write!(f, "gmres:{restart}"),
            Method::BiCgStab => write!(f, "bicgstab"),
            Method::ConjugateGradient => write!(f, "cg"),
            Method::CoarseCg => write!(f, "coarse-cg"),
            Method::DsaCg => write!(f, "dsa-cg"),
            Method::TwoLevelCg { smoothing: 0 } => write!(f, "two-level-cg"),
            Method::TwoLevelCg { smoothing } => write!(f, "two-level-cg:{smoothing}"),
            Method::CoarseCorrected { inner } => write!(f, "coarse-{inner}"),
        }
    }
}

/// A method string that could not be parsed.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("unknown iteration {input:?}: {reason} (expected one of jacobi, gauss-seidel, sor:OMEGA, gmres[:RESTART], bicgstab, cg, coarse-cg, two-level-cg[:SMOOTHING], dsa-cg, coarse-jacobi, coarse-gs, coarse-sor:OMEGA)")]
pub struct ParseMethodError {
    pub input: String,
    pub reason: String,
}

fn parse_omega(input: &str, text: Option<&str>) -> Result<f64, ParseMethodError> {
    let err = |reason: &str| ParseMethodError {
        input: input.to_string(),
        reason: reason.to_string(),
    };
    let text = text.ok_or_else(|| err("SOR needs a relaxation factor, e.g. sor:1.5"))?;
    let omega: f64 = text
        .parse()
        .map_err(|_| err("the relaxation factor is not a number"))?;
    if !(omega > 0.0 && omega < 2.0) {
        return Err(err(
            "the relaxation factor must lie strictly between 0 and 2",
        ));
    }
    Ok(omega)
}

impl FromStr for Method {
    type Err = ParseMethodError;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let lower = s.trim().to_ascii_lowercase();
        let (name, arg) = match lower.split_once(':') {
            Some((n, a)) => (n, Some(a.trim())),
            None => (lower.as_str(), None),
        };
        let err = |reason: &str| ParseMethodError {
            input: s.to_string(),
            reason: reason.to_string(),
        };
        let no_arg = |m: Method| match arg {
            None => Ok(m),
            Some(_) => Err(err("this method takes no parameter")),
        };
        match name.trim() {
            "jacobi" => no_arg(Method::Jacobi),
            "gauss-seidel" | "gs" | "gaussseidel" => no_arg(Method::GaussSeidel),
            "sor" => Ok(Method::Sor {
                omega: parse_omega(s, arg)?,
            }),
            "gmres" => {
                let restart = match arg {
                    None => DEFAULT_GMRES_RESTART,
                    Some(t) => t
                        .parse::<usize>()
                        .ok()
                        .filter(|&m| (1..=MAX_GMRES_RESTART).contains(&m))
                        .ok_or_else(|| {
                            err(&format!(
                                "the GMRES restart must be a whole number from 1 to \
                                 {MAX_GMRES_RESTART}"
                            ))
                        })?,
                };
                Ok(Method::Gmres { restart })
            }
            "bicgstab" => no_arg(Method::BiCgStab),
            "cg" | "conjugate-gradient" => no_arg(Method::ConjugateGradient),
            "coarse-cg" => no_arg(Method::CoarseCg),
            "dsa-cg" => no_arg(Method::DsaCg),
            "two-level-cg" => {
                let smoothing = match arg {
                    None => 0,
                    Some(t) => t
                        .parse::<usize>()
                        .ok()
                        .filter(|&m| m <= MAX_TWO_LEVEL_SMOOTHING)
                        .ok_or_else(|| {
                            err(&format!(
                                "the two-level smoothing must be an integer from 0 to \
                                 {MAX_TWO_LEVEL_SMOOTHING}"
                            ))
                        })?,
                };
                Ok(Method::TwoLevelCg { smoothing })
            }
            "coarse-jacobi" => no_arg(Method::CoarseCorrected {
                inner: Smoother::Jacobi,
            }),
            "coarse-gs" | "coarse-gauss-seidel" => no_arg(Method::CoarseCorrected {
                inner: Smoother::GaussSeidel,
            }),
            "coarse-sor" => Ok(Method::CoarseCorrected {
                inner: Smoother::Sor {
                    omega: parse_omega(s, arg)?,
                },
            }),
            _ => Err(err("no such method")),
        }
    }
}
