//! volrad's integration tests: one test binary (one link of the whole program), a module
//! per area, shared fixtures in `fixtures`.

mod fixtures;

mod architecture;
mod bench_albedo;
mod cli;
mod emitters;
mod environment;
mod fuzz;
mod ground;
mod interpolation;
mod readme;
mod reference_cloud24;
mod service;
mod service_faults;
mod solution_file;
mod timing;
mod transport_grid;
mod validate;
