//! Caller-side control of a running solve: cancellation and progress reports.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

/// Progress callback: `(iteration, relative residual)`, called once per iteration.
pub type ProgressFn = dyn Fn(usize, f64) + Send + Sync;
/// Phase callback: what the solve does now, before its iterations (`"building the
/// hierarchical form factors"`), called as each phase starts.
pub type PhaseFn = dyn Fn(&str) + Send + Sync;

/// Cancellation flag and optional progress callback shared with a running solve.
#[derive(Clone, Default)]
pub struct SolveControl {
    cancel: Arc<AtomicBool>,
    progress: Option<Arc<ProgressFn>>,
    phase: Option<Arc<PhaseFn>>,
}

impl SolveControl {
    pub fn new() -> Self {
        Self::default()
    }

    /// Uses an existing flag (e.g. one a service flips from another thread).
    pub fn with_flag(flag: Arc<AtomicBool>) -> Self {
        Self {
            cancel: flag,
            progress: None,
            phase: None,
        }
    }

    pub fn with_phase(mut self, phase: impl Fn(&str) + Send + Sync + 'static) -> Self {
        self.phase = Some(Arc::new(phase));
        self
    }

    /// Announces the phase a solve enters (the steps before the iterations, which can take
    /// longer than them); the iterations report through the progress callback.
    pub fn phase(&self, name: &str) {
        if let Some(p) = &self.phase {
            p(name);
        }
    }

    pub fn with_progress(mut self, progress: impl Fn(usize, f64) + Send + Sync + 'static) -> Self {
        self.progress = Some(Arc::new(progress));
        self
    }

    /// Asks the solve to stop at the next iteration; it returns its current iterate with
    /// `StopReason::Cancelled`.
    pub fn cancel(&self) {
        self.cancel.store(true, Ordering::Relaxed);
    }

    pub fn is_cancelled(&self) -> bool {
        self.cancel.load(Ordering::Relaxed)
    }

    /// The shared flag, to hand to another thread.
    pub fn flag(&self) -> Arc<AtomicBool> {
        Arc::clone(&self.cancel)
    }

    pub(crate) fn report(&self, iteration: usize, residual: f64) {
        if let Some(p) = &self.progress {
            p(iteration, residual);
        }
    }
}

impl std::fmt::Debug for SolveControl {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SolveControl")
            .field("cancelled", &self.is_cancelled())
            .field("progress", &self.progress.is_some())
            .field("phase", &self.phase.is_some())
            .finish()
    }
}
