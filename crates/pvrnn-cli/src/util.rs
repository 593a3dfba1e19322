//! Shared helpers: thread pool, configuration files, progress bars.

use std::path::Path;
use std::time::Duration;

use anyhow::{Context, Result};
use indicatif::{ProgressBar, ProgressStyle};
use pvrnn_core::ModelConfig;

pub fn set_threads(threads: Option<usize>) -> Result<()> {
    if let Some(n) = threads {
        anyhow::ensure!(n >= 1, "--threads must be at least 1");
        rayon::ThreadPoolBuilder::new()
            .num_threads(n)
            .build_global()
            .context("could not start the thread pool")?;
    }
    Ok(())
}

/// Reads a TOML configuration. Fields it leaves out keep the paper's defaults, at any depth
/// (so `[executive]\nd = 20` changes only d); unknown fields are errors.
pub fn load_config(path: Option<&Path>) -> Result<ModelConfig> {
    let Some(path) = path else {
        return Ok(ModelConfig::default());
    };
    let text = std::fs::read_to_string(path)
        .with_context(|| format!("{}: cannot read", path.display()))?;
    let user: toml::Value =
        toml::from_str(&text).with_context(|| format!("{}: not valid TOML", path.display()))?;
    let mut merged =
        toml::Value::try_from(ModelConfig::default()).expect("default config serialises");
    merge(&mut merged, user);
    let config: ModelConfig = merged
        .try_into()
        .with_context(|| format!("{}: not a valid pvrnn configuration", path.display()))?;
    config
        .validate()
        .with_context(|| format!("{}", path.display()))?;
    Ok(config)
}

fn merge(base: &mut toml::Value, over: toml::Value) {
    match (base, over) {
        (toml::Value::Table(b), toml::Value::Table(o)) => {
            for (k, v) in o {
                match b.get_mut(&k) {
                    Some(slot) => merge(slot, v),
                    None => {
                        b.insert(k, v);
                    }
                }
            }
        }
        (slot, v) => *slot = v,
    }
}

pub fn config_to_toml(config: &ModelConfig) -> String {
    toml::to_string_pretty(config).expect("configuration serialises to TOML")
}

/// A progress bar on stderr (hidden when stderr is not a terminal).
pub fn progress(len: u64, what: &str) -> ProgressBar {
    let bar = ProgressBar::new(len);
    bar.set_style(
        ProgressStyle::with_template(&format!(
            "{what} {{bar:30}} {{pos}}/{{len}} [{{elapsed_precise}} < {{eta_precise}}] {{msg}}"
        ))
        .expect("valid template"),
    );
    bar.enable_steady_tick(Duration::from_millis(200));
    bar
}

/// Parses `on`/`off`.
pub fn on_off(s: &str) -> Result<bool, String> {
    match s {
        "on" | "true" | "yes" => Ok(true),
        "off" | "false" | "no" => Ok(false),
        _ => Err(format!("expected on or off, got `{s}`")),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn partial_toml_overrides_only_what_it_names() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("c.toml");
        std::fs::write(
            &p,
            "kl_weight = 0.01\n[executive]\nd = 20\n[inference]\nwindow = 10\n",
        )
        .unwrap();
        let c = load_config(Some(&p)).unwrap();
        assert_eq!(c.kl_weight, 0.01);
        assert_eq!(c.executive.d, 20);
        assert_eq!(c.executive.z, 30);
        assert_eq!(c.inference.window, 10);
        assert_eq!(c.inference.iterations, 50);
        std::fs::write(&p, "[executive]\nsize = 20\n").unwrap();
        let e = format!("{:#}", load_config(Some(&p)).unwrap_err());
        assert!(e.contains("size"), "{e}");
        std::fs::write(&p, "[executive]\ntau = [0.5, 2.0]\n").unwrap();
        let e = format!("{:#}", load_config(Some(&p)).unwrap_err());
        assert!(e.contains("executive.tau"), "{e}");
    }

    #[test]
    fn default_config_round_trips_through_toml() {
        let text = config_to_toml(&ModelConfig::default());
        let back: ModelConfig = toml::from_str(&text).unwrap();
        assert_eq!(back, ModelConfig::default());
    }
}
