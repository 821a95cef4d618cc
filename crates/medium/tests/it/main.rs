//! The `medium` crate's integration tests: one test binary, a module per area.

mod light_pass;
mod nifti;
mod optical;
mod vdb;
mod volume_generators;
mod volume_io;
