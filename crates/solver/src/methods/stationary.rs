//! Jacobi, Gauss–Seidel and SOR.

use crate::error::SolveError;
use crate::options::Method;
use crate::report::StopReason;
use crate::solve::{Ctx, Stop};

/// `g ← E + K g`. One application per iteration gives both the residual of the current
/// iterate (`r = E + K g − g`) and the next iterate; the returned vector is the one whose
/// residual was measured.
pub(crate) fn jacobi(ctx: &mut Ctx<'_>, g: &mut Vec<f64>) -> Stop {
    let n = g.len();
    let mut next = vec![0.0; n];
    let mut k = 0;
    loop {
        ctx.apply(g, &mut next);
        let source = ctx.source;
        let gv: &[f64] = g;
        // Fused: residual norm of g, and next = E + K g in place.
        let r2 = ctx.red.update(&mut next, |off, chunk| {
            let mut s = 0.0;
            for (i, v) in chunk.iter_mut().enumerate() {
                let j = off + i;
                let new = source[j] + *v;
                let r = new - gv[j];
                s += r * r;
                *v = new;
            }
            s
        });
        let rel = r2.sqrt() / ctx.scale;
        if let Some(reason) = ctx.mon.observe(k, rel) {
            return Stop {
                reason,
                true_residual: Some(rel),
            };
        }
        std::mem::swap(g, &mut next);
        k += 1;
    }
}

/// Gauss–Seidel (`omega = 1`) or SOR sweeps through [`TransportOperator::sweep_in_place`].
///
/// A sweep does not yield the residual of its result, and computing it costs an extra
/// application, so the update norm `‖Δg‖ / (ω ‖E‖)` stands in for it; the true residual is
/// computed whenever the (calibrated) update norm falls below the tolerance, and convergence
/// is only declared on the true residual.
pub(crate) fn sweeps(ctx: &mut Ctx<'_>, g: &mut [f64], omega: f64) -> Result<Stop, SolveError> {
    let n = g.len();
    // One vector beside g: the iterate before the sweep, then (when it is measured) the
    // residual. The discrete ordinates' cells × bins make each such vector large.
    let mut work = vec![0.0; n];
    let rel0 = ctx.residual(g, &mut work);
    if let Some(reason) = ctx.mon.observe(0, rel0) {
        return Ok(Stop {
            reason,
            true_residual: Some(rel0),
        });
    }
    // Largest seen ratio true residual / update norm, so the estimate stays conservative.
    let mut calibration: f64 = 1.0;
    let mut k = 0;
    loop {
        work.copy_from_slice(g);
        if !ctx.op.sweep_in_place(g, ctx.source, omega) {
            let method = if omega == 1.0 {
                Method::GaussSeidel
            } else {
                Method::Sor { omega }
            };
            return Err(SolveError::Unsupported {
                method: method.name(),
                needs: "row access or an in-place sweep",
            });
        }
        ctx.sweeps += 1;
        k += 1;
        let gv: &[f64] = g;
        let d2 = ctx.red.sum(n, |rg| {
            gv[rg.clone()]
                .iter()
                .zip(&work[rg])
                .map(|(a, b)| (a - b) * (a - b))
                .sum()
        });
        let estimate = d2.sqrt() / (omega * ctx.scale) * calibration;
        let mut observed = estimate;
        let mut true_rel = None;
        if estimate <= ctx.mon.tolerance && estimate.is_finite() {
            let rel = ctx.residual(g, &mut work);
            if estimate > 0.0 {
                calibration = calibration.max(calibration * rel / estimate * 1.5);
            }
            observed = rel;
            true_rel = Some(rel);
        }
        if let Some(reason) = ctx.mon.observe(k, observed) {
            let true_residual = true_rel
                .or_else(|| (reason != StopReason::Converged).then(|| ctx.residual(g, &mut work)));
            return Ok(Stop {
                reason,
                true_residual,
            });
        }
    }
}
