//! The `montecarlo` crate's integration tests: one test binary, a module per area.

mod mitsuba;
mod path_trace;
mod two_pass;
