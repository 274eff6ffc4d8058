//! A trained network as matup loads it: the ONNX file (the base model's graph, the trained
//! weights) and its sidecar, both written atomically.

use std::path::Path;

use matup_core::io::write_atomic;
use matup_core::{Error, Result};

use crate::config::LearnConfig;
use crate::net::TrainableNet;

/// Writes `path` (`NAME.onnx`) and its sidecar `NAME.toml`: the base model's sidecar with the
/// source and description saying how the weights were trained.
pub fn export(
    net: &TrainableNet,
    path: &Path,
    config: &LearnConfig,
    iteration: usize,
) -> Result<()> {
    let base_sidecar = config.base_model.with_extension("toml");
    let text = std::fs::read_to_string(&base_sidecar)
        .map_err(|e| Error::Invalid(format!("{}: {e}", base_sidecar.display())))?;
    let mut sidecar: toml::Table = toml::from_str(&text)
        .map_err(|e| Error::Invalid(format!("{}: {e}", base_sidecar.display())))?;
    let base_name = config
        .base_model
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    sidecar.insert(
        "description".into(),
        format!(
            "{base_name} fine-tuned by `matup learn` for {iteration} steps on {} materials, \
             box-filtered ×{}, with a {} render loss through back-projection (normal weight {})",
            config.train.len(),
            config.scale,
            config.loss,
            config.normal_weight
        )
        .into(),
    );
    let source = sidecar
        .get("source")
        .and_then(|s| s.as_str())
        .unwrap_or("")
        .to_string();
    sidecar.insert(
        "source".into(),
        format!("weights trained by matup learn from {base_name} ({source})").into(),
    );
    write_atomic(path, &net.to_onnx()?)?;
    write_atomic(
        &path.with_extension("toml"),
        toml::to_string(&sidecar)
            .expect("a table serialises")
            .as_bytes(),
    )
}
