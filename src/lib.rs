//! `volrad`: the command line and service on top of the library crates (`medium`,
//! `formfactor`, `solver`, `gather`). Only this crate knows files of solutions, the command
//! line, HTTP and JSON.

/// Every binary that links volrad (the CLI, the service, the benches) allocates through
/// mimalloc: freed memory stays with the process for reuse, where glibc returns large blocks
/// to the kernel and each new light pass or render then pays page faults for fresh pages
/// (about a third of a light pass's time on this machine; docs/performance.md).
#[global_allocator]
static ALLOCATOR: mimalloc::MiMalloc = mimalloc::MiMalloc;

pub mod app;
pub mod bench_albedo;
pub mod cli;
pub mod commands;
pub mod engine;
pub mod fuzzing;
pub mod info;
pub mod progress;
pub mod service;
pub mod validate;
pub mod views;
