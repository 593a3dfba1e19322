//! A checkpoint file (model, optimiser moments, learning state): an error or a learning run
//! that can continue, never a panic.
#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    let _ = pvrnn_core::io::checkpoint_from_bytes(data.to_vec(), "fuzzed checkpoint");
});
