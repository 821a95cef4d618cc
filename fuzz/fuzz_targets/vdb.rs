#![no_main]
//! `cargo fuzz run vdb`: `volrad::fuzzing::vdb` on every input (see docs/reliability.md).

libfuzzer_sys::fuzz_target!(|data: &[u8]| volrad::fuzzing::vdb(data));
