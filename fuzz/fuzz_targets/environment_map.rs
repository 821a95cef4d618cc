#![no_main]
//! `cargo fuzz run environment_map`: `volrad::fuzzing::environment_map` on every input (see
//! docs/reliability.md).

libfuzzer_sys::fuzz_target!(|data: &[u8]| volrad::fuzzing::environment_map(data));
