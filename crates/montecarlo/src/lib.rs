//! `montecarlo`: stochastic light transport through volrad's piecewise-constant media.
//!
//! - [`path_trace()`] / [`path_trace_with_error`] / [`path_trace_image`] ([`path_trace`](mod@path_trace)):
//!   the unbiased volumetric path tracer (exact per-cell free paths, next-event estimation,
//!   Russian roulette), the reference for every deterministic method.
//! - [`energetize`] ([`two_pass`]): Blasi & Wuethrich's two-pass method; the stored
//!   [`TwoPassSolution`] is a [`gather::InScattering`] for the rendering pass.
//! - [`flight`]: exact free-flight sampling and transmittance along [`medium::Grid::traverse`].
//! - [`compare`](mod@compare): render against a noisy reference, both noises taken out (the
//!   one image comparison of volrad).
//! - [`rng`]: deterministic per-task random streams.

pub mod compare;
pub mod directions;
pub mod error;
pub mod flight;
pub mod path_trace;
pub mod rng;
pub mod two_pass;

pub use compare::{compare, compare_images, Comparison, NoisyImage};
pub use directions::DirectionBins;
pub use error::MonteCarloError;
pub use path_trace::{
    path_trace, path_trace_image, path_trace_with_error, PathTraceOptions, PathTraced, PathTracer,
};
pub use two_pass::{
    energetize, with_extinction_scale, EnergetizeOptions, PhotonEnergy, TwoPassSolution,
};
