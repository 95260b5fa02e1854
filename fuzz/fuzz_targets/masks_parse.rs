#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| m2smap::fuzzing::masks_parse(data));
