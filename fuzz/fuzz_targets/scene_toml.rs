#![no_main]
//! `cargo fuzz run scene_toml`: `volrad::fuzzing::scene_toml` on every input (see docs/reliability.md).

libfuzzer_sys::fuzz_target!(|data: &[u8]| volrad::fuzzing::scene_toml(data));
