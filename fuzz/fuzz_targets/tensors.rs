//! Any safetensors file read as model inputs and as inference runs (default configuration).
#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    if let Ok(file) = pvrnn_core::io::TensorFile::from_bytes(data.to_vec(), "fuzzed file") {
        let _ = pvrnn_core::io::observations_from_file(&file);
        let _ = pvrnn_core::io::load_runs(&file, &pvrnn_core::ModelConfig::default());
    }
});
