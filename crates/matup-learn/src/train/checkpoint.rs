//! A training run's folder: its files, the checkpoint that resumes a run exactly (the
//! network's tensors and the optimiser's moments) and the CSV logs kept in step with it.

use std::collections::HashMap;
use std::io::Write;
use std::path::{Path, PathBuf};

use candle_core::{Device, Var};
use matup_core::io::write_atomic;
use matup_core::{Error, Result};
use serde::{Deserialize, Serialize};

use crate::config::LearnConfig;
use matup_method::train::adam::Adam;

/// What a checkpoint records beside its tensors.
#[derive(Debug, Serialize, Deserialize, PartialEq)]
pub(super) struct CheckpointInfo {
    pub(super) iteration: usize,
    /// The configuration it was trained with (a resume must use the same).
    pub(super) config: LearnConfig,
    /// Mean validation render PSNR of the best export so far, and its iteration.
    pub(super) best: Option<(f64, usize)>,
}

/// A run folder's files.
pub struct RunFiles {
    pub dir: PathBuf,
}

impl RunFiles {
    fn path(&self, name: &str) -> PathBuf {
        self.dir.join(name)
    }
    pub fn checkpoint(&self) -> PathBuf {
        self.path("checkpoint.safetensors")
    }
    pub fn checkpoint_info(&self) -> PathBuf {
        self.path("checkpoint.json")
    }
    /// Per step: iteration, loss, render loss, normal term, seconds.
    pub fn train_log(&self) -> PathBuf {
        self.path("train.csv")
    }
    /// Per validation: iteration, material and its numbers (`mean` for the mean).
    pub fn val_log(&self) -> PathBuf {
        self.path("val.csv")
    }
    /// The exported network with the best mean validation PSNR (`best.onnx`, `best.toml`).
    pub fn best(&self) -> PathBuf {
        self.path("best.onnx")
    }
    /// The last exported network (what validation ran).
    pub fn last(&self) -> PathBuf {
        self.path("last.onnx")
    }
}

/// Saves the network's tensors and the optimiser's moments, then the info (the info last: a
/// checkpoint is whole once its info names its iteration).
pub(super) fn save_checkpoint(
    files: &RunFiles,
    vars: &[Var],
    adam: &Adam,
    config: &LearnConfig,
    iteration: usize,
    best: Option<(f64, usize)>,
) -> Result<()> {
    let mut tensors = HashMap::new();
    for (i, var) in vars.iter().enumerate() {
        tensors.insert(format!("w{i}"), var.as_tensor().clone());
        tensors.insert(format!("m{i}"), adam.m[i].clone());
        tensors.insert(format!("v{i}"), adam.v[i].clone());
    }
    let tmp = files.dir.join(".checkpoint.safetensors.tmp");
    candle_core::safetensors::save(&tensors, &tmp)?;
    std::fs::rename(&tmp, files.checkpoint()).map_err(|e| Error::io(&files.checkpoint(), e))?;
    write_atomic(
        &files.checkpoint_info(),
        serde_json::to_string_pretty(&CheckpointInfo {
            iteration,
            config: config.clone(),
            best,
        })
        .expect("serialisable")
        .as_bytes(),
    )
}

/// Restores a checkpoint into the network and optimiser; its iteration and best export.
pub(super) fn load_checkpoint(
    files: &RunFiles,
    vars: &[Var],
    adam: &mut Adam,
    config: &LearnConfig,
    device: &Device,
) -> Result<Option<CheckpointInfo>> {
    let Ok(text) = std::fs::read_to_string(files.checkpoint_info()) else {
        return Ok(None);
    };
    let info: CheckpointInfo = serde_json::from_str(&text)
        .map_err(|e| Error::file(&files.checkpoint_info(), e.to_string()))?;
    // The step count may change between calls (a run is extended by asking for more).
    let settings = |c: &LearnConfig| LearnConfig {
        iterations: 0,
        ..c.clone()
    };
    if settings(&info.config) != settings(config) {
        return Err(Error::Invalid(format!(
            "{} was trained with other settings; use a new run folder, or the configuration in {}",
            files.dir.display(),
            files.checkpoint_info().display()
        )));
    }
    let tensors = candle_core::safetensors::load(files.checkpoint(), device)?;
    let get = |name: String| {
        tensors.get(&name).cloned().ok_or_else(|| {
            Error::Invalid(format!(
                "{}: no tensor {name}",
                files.checkpoint().display()
            ))
        })
    };
    for (i, var) in vars.iter().enumerate() {
        var.set(&get(format!("w{i}"))?)?;
        adam.m[i] = get(format!("m{i}"))?;
        adam.v[i] = get(format!("v{i}"))?;
    }
    adam.step = info.iteration;
    Ok(Some(info))
}

/// Keeps the header of a CSV log and the rows `keep` picks (what a checkpoint had seen), so
/// that a resumed run's log reads as an uninterrupted one's.
pub(super) fn truncate_log(path: &Path, keep: impl Fn(&str) -> bool) -> Result<()> {
    let Ok(text) = std::fs::read_to_string(path) else {
        return Ok(());
    };
    let kept: String = text
        .lines()
        .enumerate()
        .filter(|(i, line)| *i == 0 || keep(line))
        .map(|(_, line)| format!("{line}\n"))
        .collect();
    write_atomic(path, kept.as_bytes())
}

pub(super) fn append(path: &Path, header: &str, line: &str) -> Result<()> {
    let new = !path.exists();
    let mut f = std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(path)
        .map_err(|e| Error::io(path, e))?;
    let text = if new {
        format!("{header}\n{line}\n")
    } else {
        format!("{line}\n")
    };
    f.write_all(text.as_bytes()).map_err(|e| Error::io(path, e))
}

pub(super) fn iteration_of(line: &str) -> usize {
    line.split(',')
        .next()
        .and_then(|v| v.parse().ok())
        .unwrap_or(usize::MAX)
}
