#![no_main]
//! `cargo fuzz run mitsuba_vol`: `volrad::fuzzing::mitsuba_vol` on every input (see docs/reliability.md).

libfuzzer_sys::fuzz_target!(|data: &[u8]| volrad::fuzzing::mitsuba_vol(data));
