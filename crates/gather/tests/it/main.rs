//! The `gather` crate's integration tests: one test binary, a module per area.

mod camera;
mod images;
mod single_scatter;
mod transport;
