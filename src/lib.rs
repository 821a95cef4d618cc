//! `volrad`: the command line and service on top of the library crates.
