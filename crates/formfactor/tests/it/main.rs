//! The `formfactor` crate's integration tests: one test binary, a module per area.

mod hierarchical;
mod hierarchical_coarse;
mod ordinates;
mod ordinates_slab;
mod ordinates_zonal;
mod zonal;
