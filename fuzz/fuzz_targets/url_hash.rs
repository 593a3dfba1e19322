//! A URL hash, read and kept within a small bundle's range.
#![no_main]
use std::sync::OnceLock;

fn standard() -> &'static pvrnn_explorer::Condition {
    static C: OnceLock<pvrnn_explorer::Condition> = OnceLock::new();
    C.get_or_init(|| pvrnn_explorer::Condition::standard(&pvrnn_core::ModelConfig::default()))
}

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    if let Ok(hash) = std::str::from_utf8(data) {
        let view = pvrnn_explorer::ViewState::from_hash(
            hash,
            &pvrnn_explorer::ViewState::default(),
            *standard(),
        );
        let _ = view.to_hash();
    }
});
