//! Errors of the Monte Carlo crate: small, matchable, and naming what was wrong.

/// Everything that can go wrong when setting up a Monte Carlo run.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum MonteCarloError {
    /// A colour channel the medium does not have.
    #[error("channel {channel} requested of a medium with {channels} channel(s)")]
    Channel { channel: usize, channels: usize },
    /// Options that cannot produce a result (zero samples, zero photons, bad factors...).
    #[error("invalid Monte Carlo options: {0}")]
    Options(String),
    /// A light with non-finite or negative parameters.
    #[error("light {index}: {message}")]
    Light { index: usize, message: String },
    /// A stored solution that does not fit the medium it is used with.
    #[error("two-pass solution does not fit: {0}")]
    Mismatch(String),
    /// The caller's progress callback asked to stop.
    #[error("cancelled")]
    Cancelled,
    #[error(transparent)]
    Gather(#[from] gather::GatherError),
}
