//! The entry point [`solve`]: input checks, dispatch to a method, and the shared stopping
//! rule (tolerance, iteration cap, divergence, stagnation, cancellation).

use std::time::Instant;

use crate::control::SolveControl;
use crate::error::SolveError;
use crate::methods;
use crate::methods::krylov::Preconditioner;
use crate::operator::TransportOperator;
use crate::options::{Method, Smoother, SolveOptions, MAX_GMRES_RESTART, MAX_TWO_LEVEL_SMOOTHING};
use crate::report::{SolveReport, StopReason};
use crate::vecops::{residual_in_place, Reducer};

/// Iterations without a 0.1 % improvement of the best residual before a solve is declared
/// stagnated. Long enough that Jacobi at spectral radius 0.99999 still counts as progressing.
pub const STAGNATION_WINDOW: usize = 200;

/// Residual growth (relative to the first residual) taken as divergence.
pub const DIVERGENCE_FACTOR: f64 = 1e6;

/// Solves `(I − K) g = E` with `K = op`, `E = source`, starting from `initial` (zero if
/// `None`). Non-convergence is reported in the [`SolveReport`], not as an error; errors are
/// for wrong lengths, non-finite input, bad options, and a method the operator cannot support.
pub fn solve(
    op: &dyn TransportOperator,
    source: &[f64],
    initial: Option<&[f64]>,
    options: &SolveOptions,
    control: &SolveControl,
) -> Result<(Vec<f64>, SolveReport), SolveError> {
    let n = op.len();
    check_vector("source", source, n)?;
    if let Some(x0) = initial {
        check_vector("initial guess", x0, n)?;
    }
    check_options(options)?;
    let method = options.method;
    if matches!(
        method,
        Method::ConjugateGradient | Method::CoarseCg | Method::TwoLevelCg { .. } | Method::DsaCg
    ) {
        let Some(w) = op.symmetrizer() else {
            return Err(SolveError::Unsupported {
                method: method.name(),
                needs: "a symmetrizer (weights w with diag(w)·K symmetric)",
            });
        };
        check_weights(w, n)?;
    }

    let start = Instant::now();
    let mut g = initial.map_or_else(|| vec![0.0; n], <[f64]>::to_vec);
    let mut red = Reducer::new(n);
    let source_norm = red.norm(source);
    let scale = if source_norm > 0.0 { source_norm } else { 1.0 };
    let mut ctx = Ctx {
        op,
        source,
        scale,
        red,
        mon: Monitor::new(options, control),
        applications: 0,
        sweeps: 0,
    };

    let stop = match method {
        Method::Jacobi => methods::stationary::jacobi(&mut ctx, &mut g),
        Method::GaussSeidel => methods::stationary::sweeps(&mut ctx, &mut g, 1.0)?,
        Method::Sor { omega } => methods::stationary::sweeps(&mut ctx, &mut g, omega)?,
        Method::Gmres { restart } => methods::krylov::gmres(&mut ctx, &mut g, restart),
        Method::BiCgStab => methods::krylov::bicgstab(&mut ctx, &mut g),
        Method::ConjugateGradient => {
            let w = op.symmetrizer().expect("checked above");
            methods::krylov::cg(&mut ctx, &mut g, w, Preconditioner::Identity)
        }
        Method::CoarseCg => {
            let w = op.symmetrizer().expect("checked above");
            let coarse = methods::coarse::CoarseSpace::new(&mut ctx, Some(w))?;
            methods::krylov::cg(&mut ctx, &mut g, w, Preconditioner::Coarse(coarse))
        }
        Method::DsaCg => {
            let w = op.symmetrizer().expect("checked above");
            let Some(d) = op.diffusion() else {
                return Err(SolveError::Unsupported {
                    method: method.name(),
                    needs: "a diffusion approximation (grid and σt)",
                });
            };
            if d.len() != n {
                return Err(SolveError::InvalidOperatorData {
                    what: "diffusion approximation",
                    reason: format!("{} unknowns for an operator of {n}", d.len()),
                });
            }
            let pre = Preconditioner::Dsa(Box::new(methods::krylov::Dsa::new(d)?));
            methods::krylov::cg(&mut ctx, &mut g, w, pre)
        }
        Method::TwoLevelCg { smoothing } => {
            let w = op.symmetrizer().expect("checked above");
            let coarse = methods::coarse::CoarseSpace::new(&mut ctx, Some(w))?;
            if !coarse.is_active() {
                tracing::warn!("two-level-cg: no coarse solve, plain (smoothed) CG");
            }
            let pre = Preconditioner::two_level(coarse, smoothing, n);
            methods::krylov::cg(&mut ctx, &mut g, w, pre)
        }
        Method::CoarseCorrected { inner } => {
            methods::coarse::two_level(&mut ctx, &mut g, inner, method.name())?
        }
    };

    let final_residual = match stop.true_residual {
        Some(r) => r,
        None => ctx.true_residual(&g),
    };
    // A recurrence may claim convergence the true residual does not confirm.
    let mut reason =
        if stop.reason == StopReason::Converged && !(final_residual <= options.tolerance) {
            StopReason::MaxIterations
        } else {
            stop.reason
        };
    // A residual is only meaningful above its rounding floor: if the iterate has grown so
    // large that `E` vanishes in the rounding of `g − K g`, a tiny residual proves nothing.
    let rounding_floor = 8.0 * f64::EPSILON * ctx.red.norm(&g) / ctx.scale;
    if reason == StopReason::Converged && rounding_floor > options.tolerance {
        tracing::warn!(
            rounding_floor,
            "solution grew beyond the residual's precision"
        );
        reason = StopReason::Diverged;
    }
    let seconds = start.elapsed().as_secs_f64();
    let iterations = ctx.mon.iterations;
    let report = SolveReport {
        method: method.name(),
        iterations,
        converged: reason == StopReason::Converged,
        final_residual,
        residual_history: std::mem::take(&mut ctx.mon.history),
        seconds,
        seconds_per_iteration: if iterations > 0 {
            seconds / iterations as f64
        } else {
            0.0
        },
        operator_applications: ctx.applications,
        operator_sweeps: ctx.sweeps,
        cancelled: reason == StopReason::Cancelled,
        stop_reason: reason,
    };
    tracing::debug!(
        method = %report.method,
        iterations,
        residual = final_residual,
        reason = ?reason,
        "solve finished"
    );
    Ok((g, report))
}

fn check_vector(what: &'static str, v: &[f64], n: usize) -> Result<(), SolveError> {
    if v.len() != n {
        return Err(SolveError::WrongLength {
            what,
            len: v.len(),
            expected: n,
        });
    }
    if let Some((index, &value)) = v.iter().enumerate().find(|(_, x)| !x.is_finite()) {
        return Err(SolveError::NonFinite { what, index, value });
    }
    Ok(())
}

fn check_weights(w: &[f64], n: usize) -> Result<(), SolveError> {
    if w.len() != n {
        return Err(SolveError::InvalidOperatorData {
            what: "symmetrizer",
            reason: format!("length {} for {n} unknowns", w.len()),
        });
    }
    if let Some((i, x)) = w
        .iter()
        .enumerate()
        .find(|(_, x)| !(x.is_finite() && **x > 0.0))
    {
        return Err(SolveError::InvalidOperatorData {
            what: "symmetrizer",
            reason: format!("weight {x} at index {i} is not positive and finite"),
        });
    }
    Ok(())
}

fn check_options(o: &SolveOptions) -> Result<(), SolveError> {
    if !(o.tolerance.is_finite() && o.tolerance > 0.0) {
        return Err(SolveError::InvalidOptions(format!(
            "tolerance must be positive and finite, not {}",
            o.tolerance
        )));
    }
    let bad_omega = |w: f64| !(w > 0.0 && w < 2.0);
    match o.method {
        Method::Sor { omega }
        | Method::CoarseCorrected {
            inner: Smoother::Sor { omega },
        } if bad_omega(omega) => Err(SolveError::InvalidOptions(format!(
            "SOR relaxation factor must lie in (0, 2), not {omega}"
        ))),
        Method::TwoLevelCg { smoothing } if smoothing > MAX_TWO_LEVEL_SMOOTHING => {
            Err(SolveError::InvalidOptions(format!(
                "two-level smoothing must be at most {MAX_TWO_LEVEL_SMOOTHING}, not {smoothing}"
            )))
        }
        Method::Gmres { restart } if !(1..=MAX_GMRES_RESTART).contains(&restart) => {
            Err(SolveError::InvalidOptions(format!(
                "GMRES restart must be from 1 to {MAX_GMRES_RESTART}, not {restart}"
            )))
        }
        _ => Ok(()),
    }
}

/// How a method ended; `true_residual` when it already computed it for the returned vector.
pub(crate) struct Stop {
    pub reason: StopReason,
    pub true_residual: Option<f64>,
}

/// Everything a method needs besides its own work vectors.
pub(crate) struct Ctx<'a> {
    pub op: &'a dyn TransportOperator,
    pub source: &'a [f64],
    /// `‖E‖₂` (1 if `E = 0`): residuals are divided by it.
    pub scale: f64,
    pub red: Reducer,
    pub mon: Monitor<'a>,
    pub applications: usize,
    pub sweeps: usize,
}

impl Ctx<'_> {
    pub fn apply(&mut self, x: &[f64], y: &mut [f64]) {
        self.op.apply(x, y);
        self.applications += 1;
    }

    /// Writes `r = E − (g − K g)` into `r` (which first holds `K g`: one vector, not two,
    /// for a system as large as the discrete ordinates' cells × bins); returns the relative
    /// residual.
    pub fn residual(&mut self, g: &[f64], r: &mut [f64]) -> f64 {
        self.apply(g, r);
        residual_in_place(&mut self.red, r, self.source, g).sqrt() / self.scale
    }

    /// Relative residual of `g`, allocating its own scratch (used once, at the end).
    pub fn true_residual(&mut self, g: &[f64]) -> f64 {
        let mut r = vec![0.0; g.len()];
        self.residual(g, &mut r)
    }
}

/// The shared stopping rule and history.
pub(crate) struct Monitor<'a> {
    control: &'a SolveControl,
    pub tolerance: f64,
    max_iterations: usize,
    record: bool,
    pub history: Vec<f64>,
    /// Completed iterations.
    pub iterations: usize,
    first: Option<f64>,
    best: f64,
    window_start: usize,
    window_anchor: f64,
}

impl<'a> Monitor<'a> {
    fn new(o: &SolveOptions, control: &'a SolveControl) -> Self {
        Self {
            control,
            tolerance: o.tolerance,
            max_iterations: o.max_iterations,
            record: o.record_history,
            history: Vec::new(),
            iterations: 0,
            first: None,
            best: f64::INFINITY,
            window_start: 0,
            window_anchor: f64::INFINITY,
        }
    }

    /// Records the residual after `iterations` iterations and decides whether to stop.
    /// `Converged` means "the method's estimate is below tolerance": methods with estimates
    /// confirm it with the true residual.
    pub fn observe(&mut self, iterations: usize, rel: f64) -> Option<StopReason> {
        self.iterations = iterations;
        if self.record {
            self.history.push(rel);
        }
        self.control.report(iterations, rel);
        if !rel.is_finite() {
            return Some(StopReason::Diverged);
        }
        if rel <= self.tolerance {
            return Some(StopReason::Converged);
        }
        let first = *self.first.get_or_insert(rel);
        if rel > DIVERGENCE_FACTOR * first {
            return Some(StopReason::Diverged);
        }
        if rel < self.best {
            self.best = rel;
        }
        if iterations >= self.window_start + STAGNATION_WINDOW {
            if self.best > self.window_anchor * (1.0 - 1e-3) {
                return Some(StopReason::Stagnated);
            }
            self.window_start = iterations;
            self.window_anchor = self.best;
        } else if self.window_anchor.is_infinite() {
            self.window_anchor = rel;
            self.window_start = iterations;
        }
        self.limits()
    }

    /// Cancellation and the iteration cap (for checks that record nothing).
    pub fn limits(&self) -> Option<StopReason> {
        if self.control.is_cancelled() {
            Some(StopReason::Cancelled)
        } else if self.iterations >= self.max_iterations {
            Some(StopReason::MaxIterations)
        } else {
            None
        }
    }
}
