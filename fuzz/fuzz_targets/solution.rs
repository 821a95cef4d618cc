#![no_main]
//! `cargo fuzz run solution`: `volrad::fuzzing::solution` on every input (see docs/reliability.md).

libfuzzer_sys::fuzz_target!(|data: &[u8]| volrad::fuzzing::solution(data));
