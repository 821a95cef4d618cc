#![no_main]
//! `cargo fuzz run render_query`: `volrad::fuzzing::render_query` on every input (see docs/reliability.md).

libfuzzer_sys::fuzz_target!(|data: &[u8]| volrad::fuzzing::render_query(data));
