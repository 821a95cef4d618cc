//! The iterative methods, each driven by the shared [`Monitor`](crate::solve::Monitor).

pub(crate) mod coarse;
mod dense;
pub(crate) mod krylov;
pub(crate) mod multigrid;
pub(crate) mod stationary;
