//! The bundle manifest, `bundle.json`: what the explorer opens (a model, a dataset folder's
//! manifest, runs computed in advance, and the model's card). One definition for the CLI
//! that writes it (`pvrnn bundle`) and the explorer that reads it.

use serde::{Deserialize, Serialize};

use crate::card::ModelCard;
use crate::{Result, format_err};

pub const BUNDLE_MANIFEST: &str = "bundle.json";
pub const BUNDLE_FORMAT: &str = "pvrnn-bundle/1";
/// The layout version this build writes and reads; a newer bundle is refused by name.
pub const BUNDLE_VERSION: u32 = 1;

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct BundleManifest {
    pub format: String,
    /// Bumped when the layout changes in a way older readers would misread (bundles from
    /// before the field are version 1).
    #[serde(default = "first_version")]
    pub version: u32,
    #[serde(default)]
    pub description: String,
    /// The model file.
    pub model: String,
    /// The dataset manifest (its sequence files lie beside it).
    pub dataset: String,
    /// Runs files, one per precomputed condition (older bundles name a single file).
    #[serde(default, deserialize_with = "one_or_many")]
    pub runs: Vec<String>,
    /// How the model was trained and how it scores.
    #[serde(default)]
    pub card: Option<ModelCard>,
}

fn first_version() -> u32 {
    1
}

fn one_or_many<'de, D: serde::Deserializer<'de>>(d: D) -> Result<Vec<String>, D::Error> {
    #[derive(Deserialize)]
    #[serde(untagged)]
    enum OneOrMany {
        One(String),
        Many(Vec<String>),
    }
    Ok(match Option::<OneOrMany>::deserialize(d)? {
        None => Vec::new(),
        Some(OneOrMany::One(s)) => vec![s],
        Some(OneOrMany::Many(v)) => v,
    })
}

impl BundleManifest {
    /// A manifest of this build's format and version.
    pub fn new(
        description: String,
        model: String,
        dataset: String,
        runs: Vec<String>,
        card: Option<ModelCard>,
    ) -> Self {
        Self {
            format: BUNDLE_FORMAT.into(),
            version: BUNDLE_VERSION,
            description,
            model,
            dataset,
            runs,
            card,
        }
    }

    /// Reads and checks a manifest; `what` names it in errors.
    pub fn parse(bytes: &[u8], what: &str) -> Result<Self> {
        let m: Self = serde_json::from_slice(bytes)
            .map_err(|e| format_err(what, format!("not a bundle manifest: {e}")))?;
        if m.format != BUNDLE_FORMAT {
            return Err(format_err(
                what,
                format!("format `{}`, expected `{BUNDLE_FORMAT}`", m.format),
            ));
        }
        if m.version > BUNDLE_VERSION {
            return Err(format_err(
                what,
                format!(
                    "bundle version {} is newer than this build reads ({BUNDLE_VERSION}); update pvrnn",
                    m.version
                ),
            ));
        }
        for (role, file) in std::iter::once(("model", &m.model))
            .chain(std::iter::once(("dataset", &m.dataset)))
            .chain(m.runs.iter().map(|r| ("runs", r)))
        {
            // Files lie in the bundle folder: no paths out of it.
            if file.is_empty() || file.contains(['/', '\\']) || file == ".." {
                return Err(format_err(
                    what,
                    format!("the {role} file `{file}` is not a file name in the bundle folder"),
                ));
            }
        }
        Ok(m)
    }

    pub fn to_json(&self) -> String {
        serde_json::to_string_pretty(self).expect("a manifest is plain data")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trips_and_reads_older_and_refuses_newer_bundles() {
        let card = ModelCard {
            iteration: Some(10_000),
            training_data: "18 sequences".into(),
            ..ModelCard::default()
        };
        let m = BundleManifest::new(
            "a model".into(),
            "model.safetensors".into(),
            "dataset.json".into(),
            vec!["runs-a.safetensors".into(), "runs-b.safetensors".into()],
            Some(card),
        );
        assert_eq!(
            BundleManifest::parse(m.to_json().as_bytes(), "b").unwrap(),
            m
        );
        // Written before the version field, with a single runs file.
        let old = br#"{"format": "pvrnn-bundle/1", "model": "m.safetensors", "dataset": "dataset.json", "runs": "r.safetensors"}"#;
        let old = BundleManifest::parse(old, "old").unwrap();
        assert_eq!((old.version, old.runs.len()), (1, 1));
        let newer = m.to_json().replace("\"version\": 1", "\"version\": 2");
        let e = BundleManifest::parse(newer.as_bytes(), "newer")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("newer:") && e.contains("version 2 is newer"),
            "{e}"
        );
        let escape = m.to_json().replace("model.safetensors", "../secret");
        let e = BundleManifest::parse(escape.as_bytes(), "b")
            .unwrap_err()
            .to_string();
        assert!(e.contains("`../secret`"), "{e}");
        let e = BundleManifest::parse(b"{}", "empty")
            .unwrap_err()
            .to_string();
        assert!(e.contains("empty: not a bundle manifest"), "{e}");
    }
}
