#![no_main]
//! `cargo fuzz run nifti`: `volrad::fuzzing::nifti` on every input (see docs/reliability.md).

libfuzzer_sys::fuzz_target!(|data: &[u8]| volrad::fuzzing::nifti(data));
