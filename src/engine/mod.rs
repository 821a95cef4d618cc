//! The engine: everything between a validated scene and a stored solution or an image —
//! the solve of every method ([`methods`]), the orchestration shared by the command line and
//! the service ([`pipeline`]), the scattered-light sources a render adds ([`sources`]), the
//! solution file ([`solution`]) and what a solve will cost in memory ([`budget`]) and time
//! ([`timing`]). It knows no command line and no HTTP: the front ends
//! (`cli`, `commands`, `service`, `validate`, `bench_albedo`) sit above it.

pub mod budget;
pub mod ground;
pub mod methods;
pub mod pipeline;
pub mod solution;
pub mod sources;
pub mod timing;

use std::sync::Arc;

/// Told the solve's predicted time ([`timing::solve_time`]) once its checks have passed,
/// before any work.
pub type PredictionFn = dyn Fn(&timing::TimeEstimate) + Send + Sync;

/// Progress and cancellation for a solve, shared with whoever started it.
#[derive(Clone, Default)]
pub struct SolveHooks {
    pub control: Arc<solver::SolveControl>,
    /// The memory the solve must fit in ([`budget::check_solve`], before any work); `None`
    /// checks nothing.
    pub memory_limit: Option<budget::MemoryLimit>,
    /// Who wants the predicted time (a progress bar, the service's status); `None`: nobody,
    /// and it is not computed.
    pub on_prediction: Option<Arc<PredictionFn>>,
}
