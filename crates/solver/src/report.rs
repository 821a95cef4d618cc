//! What a solve reports: iterations, residuals, time, and why it stopped.

use serde::{Deserialize, Serialize};

/// Why the iteration stopped.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum StopReason {
    /// The relative residual of the returned vector is at or below the tolerance.
    Converged,
    /// `max_iterations` reached first.
    MaxIterations,
    /// The caller cancelled through [`SolveControl::cancel`](crate::SolveControl::cancel).
    Cancelled,
    /// The residual became NaN/infinite or grew beyond 10⁶ × its first value.
    Diverged,
    /// No progress: the best residual fell by less than 0.1 % over
    /// [`STAGNATION_WINDOW`](crate::STAGNATION_WINDOW) iterations, or a Krylov method broke
    /// down (e.g. conjugate gradients met non-positive curvature) and could not restart.
    Stagnated,
}

impl StopReason {
    /// The name in JSON output and reports (`converged`, `max-iterations`, `cancelled`,
    /// `diverged`, `stagnated`): an explicit spelling, independent of the Rust identifier.
    pub fn name(self) -> &'static str {
        match self {
            StopReason::Converged => "converged",
            StopReason::MaxIterations => "max-iterations",
            StopReason::Cancelled => "cancelled",
            StopReason::Diverged => "diverged",
            StopReason::Stagnated => "stagnated",
        }
    }
}

impl std::fmt::Display for StopReason {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// The record of one solve (stored in solution files).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SolveReport {
    /// Canonical method string, e.g. `"sor:1.5"`.
    pub method: String,
    /// Completed iterations: Jacobi updates, sweeps, Krylov steps (one Arnoldi step, one
    /// BiCGSTAB step, one CG step) or two-level cycles.
    pub iterations: usize,
    pub converged: bool,
    /// True relative residual `‖g − E − K g‖₂ / ‖E‖₂` of the returned vector (computed with an
    /// explicit application of `K`, never a recurrence).
    pub final_residual: f64,
    /// Relative residual after 0, 1, 2, … iterations (empty unless `record_history`). For
    /// Jacobi and the two-level method these are true residuals; Krylov methods record their
    /// recurrence/least-squares estimate; Gauss–Seidel and SOR record the sweep's update norm
    /// `‖Δg‖ / (ω ‖E‖)` except where the true residual was computed to confirm convergence.
    pub residual_history: Vec<f64>,
    pub seconds: f64,
    /// `seconds / iterations` (setup such as a coarse factorisation included).
    pub seconds_per_iteration: f64,
    /// Applications of `K` (including residual checks and coarse-operator probing).
    pub operator_applications: usize,
    /// In-place sweeps (Gauss–Seidel, SOR, smoothers).
    pub operator_sweeps: usize,
    pub cancelled: bool,
    pub stop_reason: StopReason,
}

impl SolveReport {
    /// The report of a system that needed no iteration (nothing couples the unknowns, so
    /// `g = E` exactly): converged, zero residual, no operator applied.
    pub fn without_iterations(method: impl Into<String>) -> SolveReport {
        SolveReport {
            method: method.into(),
            iterations: 0,
            converged: true,
            final_residual: 0.0,
            residual_history: vec![0.0],
            seconds: 0.0,
            seconds_per_iteration: 0.0,
            operator_applications: 0,
            operator_sweeps: 0,
            cancelled: false,
            stop_reason: StopReason::Converged,
        }
    }
}
