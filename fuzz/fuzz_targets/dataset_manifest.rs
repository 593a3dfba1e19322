//! A dataset manifest (its sequence files missing): an error or a dataset, never a panic.
#![no_main]
libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    if let Ok(text) = std::str::from_utf8(data) {
        let _ = pvrnn_dataset::Dataset::from_parts(text, |name| {
            Err(pvrnn_dataset::Error::Format {
                what: name.into(),
                detail: "not provided".into(),
            })
        });
    }
});
