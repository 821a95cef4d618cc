//! Discrete ordinates (Max 1995 §VII.D): radiance in `M` direction bins per cell, for
//! anisotropic multiple scattering.
//!
//! - [`bins`]: Max's 96 cube-face bins and the `6·n²` family, closed-form solid angles.
//! - [`phase_matrix`]: the renormalised bin-to-bin phase matrix.
//! - [`sweep`]: the matrix-free operator `K` (scatter once, transport by per-bin sweeps that
//!   spread each bin's flux over its solid angle), the first-bounce source and energy tallies.
//! - [`assembled`]: the same operator as an explicit sparse matrix, for small grids.
//!
//! Unknowns `I[cell·M + l]`: scattered radiance (the unscattered beam excluded) averaged over
//! the cell and over bin `l`. The system is `I = T(S1 + e) + K I`.

pub mod assembled;
pub mod bins;
mod faces;
pub mod phase_matrix;
pub mod sweep;

pub use assembled::AssembledOrdinates;
pub use bins::{
    auto_bin_count, auto_bins_work, DirectionBins, AUTO_BINS_MAX_CELL_BINS,
    AUTO_BINS_MODERATE_UP_TO, AUTO_BIN_STEPS, MAX_FACE_DIVISIONS, VALID_BINS,
};
pub use faces::gauss_legendre_unit;
pub use phase_matrix::PhaseMatrix;
pub use sweep::{
    default_forward_truncation_degrees, exponential_half_change, forward_peak_fraction,
    forward_truncation_fraction, scattering_product_cells, BeamLight, BeamProfiles, EnergyBalance,
    OrdinatesOperator, OrdinatesOptions, SweepEnergy, SweepSolve, Uncollided,
    MAX_TRANSPORT_REFINEMENT,
};

/// What was wrong with an ordinates set-up.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum OrdinatesError {
    #[error("face divisions n = {0}: must be in 1..={MAX_FACE_DIVISIONS}")]
    FaceDivisions(usize),
    #[error("{0} bins: expected 6 n² for n = 1..={MAX_FACE_DIVISIONS} ({VALID_BINS:?})")]
    BinCount(usize),
    #[error("channel {channel} does not exist (the medium has {channels})")]
    Channel { channel: usize, channels: usize },
    #[error("{what}: {got} values, expected {expected}")]
    Length {
        what: &'static str,
        got: usize,
        expected: usize,
    },
    #[error("invalid medium: {0}")]
    Medium(String),
    #[error("the light pass was computed for another grid")]
    ForeignLightPass,
    #[error("invalid option: {0}")]
    Option(String),
}
