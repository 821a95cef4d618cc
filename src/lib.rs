//! `volrad`: the command line and service on top of the library crates (`medium`,
//! `formfactor`, `solver`, `gather`). Only this crate knows files of solutions, the command
//! line, HTTP and JSON.

pub mod app;
pub mod bench_albedo;
pub mod cli;
pub mod commands;
pub mod compare;
pub mod info;
pub mod methods;
pub mod pipeline;
pub mod progress;
pub mod service;
pub mod solution;
pub mod validate;
