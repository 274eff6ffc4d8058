#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    matup_fuzz::dds(data);
});
