//! The training loop: each step's loss ([`loss`]) stepped by Adam
//! (`matup_method::train::adam`), checkpoints that resume exactly ([`checkpoint`]), and
//! validation of the exported network by `matup upscale` itself ([`validation`]).

mod checkpoint;
mod loss;
mod validation;

pub use checkpoint::RunFiles;
pub use loss::{centre, shipped_maps, StepLoss, Trainer};
pub use validation::{
    means, one_pass_defaults, validate, validate_normals, validation_set, Score, ValMaterial,
};

use std::path::Path;
use std::time::Instant;

use candle_core::Device;
use matup_core::progress::Progress;
use matup_core::{Error, Result};

use crate::config::{LearnConfig, Target};
use crate::export::export;
use checkpoint::{append, iteration_of, load_checkpoint, save_checkpoint, truncate_log};
use matup_method::train::adam::Adam;
use validation::log_validation;

/// How a call to [`train`] ended.
#[derive(Debug)]
pub struct Summary {
    pub iterations: usize,
    pub resumed_from: Option<usize>,
    /// The best mean validation render PSNR and its iteration.
    pub best: Option<(f64, usize)>,
    pub seconds: f64,
}

/// Trains (or resumes) the run in `dir` up to `config.iterations` steps, checkpointing every
/// `checkpoint_every` steps and validating every `validate_every` (and at the start and the
/// end), keeping the best export as `best.onnx`. Stops cleanly, checkpoint written, when
/// `progress` says cancelled.
pub fn train(
    config: &LearnConfig,
    dir: &Path,
    device: &Device,
    progress: &dyn Progress,
) -> Result<Summary> {
    let start = Instant::now();
    // The data and network first: a run that cannot start leaves no folder behind.
    let trainer = Trainer::new(config, device)?;
    std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
    let files = RunFiles {
        dir: dir.to_path_buf(),
    };
    let vars = trainer.net.vars();
    let frozen = trainer.net.frozen_vars(config.trained);
    let mut adam = Adam::new(&vars, config.learning_rate, config.anchor_weight)?;
    let info = load_checkpoint(&files, &vars, &mut adam, config, device)?;
    let resumed_from = info.as_ref().map(|i| i.iteration);
    let mut iteration = resumed_from.unwrap_or(0);
    let mut best = info.and_then(|i| i.best);
    if let Some(i) = resumed_from {
        progress.note(&format!("resuming {} at step {i}", dir.display()));
    }
    // A resumed run keeps the rows its checkpoint had seen; a new one (into a folder holding
    // an earlier run's logs, as when a run is recreated) keeps none.
    let seen = |line: &str| resumed_from.is_some_and(|i| iteration_of(line) <= i);
    truncate_log(&files.train_log(), seen)?;
    truncate_log(&files.val_log(), seen)?;

    let set = if config.validate_every > 0 {
        validation_set(config)?
    } else {
        Vec::new()
    };
    let validate_now = |iteration: usize, best: &mut Option<(f64, usize)>| -> Result<()> {
        if set.is_empty() {
            return Ok(());
        }
        progress.stage(&format!("validate step {iteration}"), set.len() as u64);
        let evaluations = if config.target == Target::Normals {
            // In candle: a height-guided network has no ONNX form.
            validate_normals(&trainer.net, &set, config.val_lights)?
        } else {
            export(&trainer.net, &files.last(), config, iteration)?;
            validate(
                config.target,
                &format!("onnx:{}", files.last().display()),
                &set,
                config.val_lights,
            )?
        };
        progress.advance(set.len() as u64, None);
        log_validation(&files, iteration, &evaluations)?;
        let (psnr, flip) = means(&evaluations);
        progress.note(&format!(
            "step {iteration}: validation render PSNR {psnr:.3} dB, FLIP {flip:.4}"
        ));
        if best.is_none_or(|(b, _)| psnr > b) {
            *best = Some((psnr, iteration));
            if !trainer.net.has_height_guide() {
                export(&trainer.net, &files.best(), config, iteration)?;
            }
        }
        Ok(())
    };
    if resumed_from.is_none() {
        validate_now(0, &mut best)?;
    }

    progress.stage("train", config.iterations as u64);
    progress.advance(iteration as u64, None);
    while iteration < config.iterations {
        if progress.cancelled() {
            save_checkpoint(&files, &vars, &adam, config, iteration, best)?;
            return Err(Error::Cancelled {
                epochs_done: iteration,
            });
        }
        let step_start = Instant::now();
        let (loss, numbers) = trainer.loss(iteration)?;
        if !numbers.loss.is_finite() {
            return Err(Error::Invalid(format!(
                "step {}: the loss is {}; training diverged (lower learning_rate), the last checkpoint in {} is intact",
                iteration + 1,
                numbers.loss,
                dir.display()
            )));
        }
        let mut grads = loss.backward()?;
        // A frozen tensor has no gradient, so Adam leaves it (and its moments) as they are.
        for var in &frozen {
            grads.remove(var.as_tensor());
        }
        adam.update(&vars, &grads)?;
        iteration += 1;
        append(
            &files.train_log(),
            "iteration,loss,render_loss,normal_term,seconds",
            &format!(
                "{iteration},{:.6},{:.6},{:.6},{:.3}",
                numbers.loss,
                numbers.render,
                numbers.normal,
                step_start.elapsed().as_secs_f64()
            ),
        )?;
        progress.advance(1, Some(numbers.loss));
        let validating = config.validate_every > 0
            && (iteration % config.validate_every == 0 || iteration == config.iterations);
        if validating {
            validate_now(iteration, &mut best)?;
            progress.stage("train", config.iterations as u64);
            progress.advance(iteration as u64, None);
        }
        if validating || iteration % config.checkpoint_every == 0 || iteration == config.iterations
        {
            save_checkpoint(&files, &vars, &adam, config, iteration, best)?;
        }
    }
    Ok(Summary {
        iterations: iteration,
        resumed_from,
        best,
        seconds: start.elapsed().as_secs_f64(),
    })
}
