#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| m2smap::fuzzing::mapper_frame(data));
