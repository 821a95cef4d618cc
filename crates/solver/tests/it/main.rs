//! The `solver` crate's integration tests: one test binary, a module per area.

mod common;

mod behaviour;
mod methods_agree;
