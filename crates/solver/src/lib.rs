//! `solver`: iterative solution of the transport system `g = E + K g` on an abstract
//! [`TransportOperator`]. It knows nothing of grids, cells or directions: the operator may be a
//! sparse form-factor matrix, a hierarchical link set or a discrete-ordinates sweep.
//!
//! Methods ([`Method`]): Jacobi, Gauss–Seidel, SOR, GMRES(m), BiCGSTAB, conjugate gradients
//! (for operators with a [`symmetrizer`](TransportOperator::symmetrizer)), a two-level
//! coarse-corrected iteration (additive coarse-mesh rebalance on aggregates, the physics-style
//! accelerator) and conjugate gradients preconditioned by that coarse correction.
//!
//! Entry points: [`solve`], [`spectral_radius`], [`predicted_iterations`]. Non-convergence is
//! reported in [`SolveReport`] (`converged`, [`StopReason`]), never hidden and never an error.

// `!(x > 0.0)` is used on purpose: it is also true for NaN.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

pub mod control;
pub mod dense;
pub mod error;
mod methods;
pub mod operator;
pub mod options;
pub mod report;
mod solve;
pub mod spectral;
mod vecops;

pub use control::{ProgressFn, SolveControl};
pub use dense::{DenseOperator, DenseSizeError};
pub use error::SolveError;
pub use methods::coarse::{
    contiguous_aggregates, DEFAULT_AGGREGATE_SIZE, MAX_DEFAULT_AGGREGATES,
    PROBED_DEFAULT_AGGREGATES,
};
pub use methods::multigrid::DiffusionMultigrid;
pub use operator::{Diffusion, RowAccess, TransportOperator};
pub use options::{
    Method, ParseMethodError, Smoother, SolveOptions, DEFAULT_GMRES_RESTART, MAX_GMRES_RESTART,
    MAX_TWO_LEVEL_SMOOTHING,
};
pub use report::{SolveReport, StopReason};
pub use solve::{solve, DIVERGENCE_FACTOR, STAGNATION_WINDOW};
pub use spectral::{
    predicted_iterations, spectral_radius, spectral_radius_cancellable, SpectralEstimate,
};
