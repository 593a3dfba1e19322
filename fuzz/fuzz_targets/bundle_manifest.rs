//! A bundle manifest.
#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    let _ = pvrnn_dataset::bundle::BundleManifest::parse(data, "fuzzed bundle.json");
});
