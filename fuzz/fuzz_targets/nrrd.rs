#![no_main]
//! `cargo fuzz run nrrd`: `volrad::fuzzing::nrrd` on every input (see docs/reliability.md).

libfuzzer_sys::fuzz_target!(|data: &[u8]| volrad::fuzzing::nrrd(data));
