#![no_main]
//! `cargo fuzz run scene_json`: `volrad::fuzzing::scene_json` on every input (see docs/reliability.md).

libfuzzer_sys::fuzz_target!(|data: &[u8]| volrad::fuzzing::scene_json(data));
