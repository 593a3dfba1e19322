//! A model file: an error or a model, never a panic.
#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    let _ = pvrnn_core::io::model_from_bytes(data.to_vec(), "fuzzed model");
});
