//! Material libraries: every material under a folder upscaled into the mirrored path of an
//! output folder, resumable, split among workers that share only a file system.
//!
//! A material is done when its output folder holds a `run.json` with the same settings
//! fingerprint; one that failed holds an `error.json` instead. A worker claims a material
//! before working on it ([`claim`]) and takes the materials of its [`Shard`]; the summary
//! ([`summary`]) is read back from the output folder, so any worker can write it.

pub mod claim;
pub mod library;
mod records;
pub mod shard;
pub mod summary;

use std::collections::VecDeque;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::thread::ScopedJoinHandle;
use std::time::{Instant, SystemTime, UNIX_EPOCH};

use sha2::{Digest, Sha256};

pub use claim::{ClaimTiming, Holder};
pub use library::{find_materials, material_name, Library};
pub use shard::Shard;
pub use summary::{Row, Status};

use records::{read_failure, read_result, unix_seconds, Failure, FAILURE_FILE};

use crate::folder::upscale_to_folder;
use crate::model::{is_model_file, model_files, upscale_model};
use crate::view::write_run_view;
use matup_core::io::{is_image_file, load_material, write_atomic, LoadOptions, SaveOptions};
use matup_core::progress::{Progress, Silent};
use matup_core::{Error, Result};
use matup_method::plan::check_settings;
use matup_method::Config;

/// How a batch runs.
#[derive(Clone, Debug, Default)]
pub struct BatchOptions {
    pub config: Config,
    pub save: SaveOptions,
    /// How each material is loaded (its explicit `paths` are not used).
    pub load: LoadOptions,
    /// Take only this shard's materials (all when `None`).
    pub shard: Option<Shard>,
    pub claims: ClaimTiming,
    /// Also write each material's `view.html` (linked from `index.html`).
    pub view: bool,
    /// Heap each material's output is made within (none: whole), shared by the materials in
    /// flight.
    pub memory_limit: Option<u64>,
    /// Materials worked on at once (0 or 1: one at a time). On a GPU, 2: one material's files
    /// are encoded and written on the CPU while the next is upscaled on the GPU. On the CPU
    /// one material already fills every core.
    pub in_flight: usize,
}

/// What this worker did with one material.
#[derive(Clone, Debug, PartialEq)]
pub enum Outcome {
    Upscaled,
    /// Done earlier with the same settings (by any worker).
    AlreadyDone,
    Failed(String),
    /// Another worker failed on it since this batch began (it is not tried twice in a run).
    FailedElsewhere(String),
    /// A live worker holds its claim.
    HeldBy(Holder),
    /// This worker's claim went stale and another took it over; the other finishes it.
    LostClaim,
    /// Stopped by the user (Ctrl-C); its checkpoint resumes it.
    Interrupted,
}

impl Outcome {
    /// A short name: upscaled, already-done, failed, failed-elsewhere, held-elsewhere,
    /// lost-claim or interrupted.
    pub fn label(&self) -> &'static str {
        match self {
            Outcome::Upscaled => "upscaled",
            Outcome::AlreadyDone => "already-done",
            Outcome::Failed(_) => "failed",
            Outcome::FailedElsewhere(_) => "failed-elsewhere",
            Outcome::HeldBy(_) => "held-elsewhere",
            Outcome::LostClaim => "lost-claim",
            Outcome::Interrupted => "interrupted",
        }
    }

    /// The error or who holds the material, where there is something to say.
    pub fn detail(&self) -> Option<String> {
        match self {
            Outcome::Failed(e) | Outcome::FailedElsewhere(e) => Some(e.clone()),
            Outcome::HeldBy(holder) => Some(format!("claimed by {holder}")),
            Outcome::LostClaim => Some("another worker took the claim over".into()),
            _ => None,
        }
    }

    pub fn is_failure(&self) -> bool {
        matches!(self, Outcome::Failed(_) | Outcome::FailedElsewhere(_))
    }
}

/// One material this worker looked at.
#[derive(Clone, Debug)]
pub struct Handled {
    pub material: String,
    pub outcome: Outcome,
    pub seconds: f64,
}

/// What [`run_batch`] did and what the library looks like after it.
#[derive(Clone, Debug)]
pub struct BatchReport {
    pub library: Library,
    /// The materials this worker took (its shard), in order, as far as it got.
    pub handled: Vec<Handled>,
    /// Every material of the library, read back from the output folder at the end.
    pub summary: Vec<Row>,
    /// Whether the user stopped the batch (Ctrl-C) before this worker's share was done.
    pub interrupted: bool,
}

impl BatchReport {
    /// How many materials this worker tried failed.
    pub fn failures(&self) -> usize {
        self.handled
            .iter()
            .filter(|h| h.outcome.is_failure())
            .count()
    }
}

/// Progress of a batch. The material being upscaled reports through [`Progress`], as a
/// single run does.
pub trait BatchProgress: Progress {
    /// The worker will look at `count` materials.
    fn materials(&self, _count: usize) {}
    /// Work on a material begins.
    fn material_started(&self, _name: &str) {}
    /// A material is handled.
    fn material_done(&self, _handled: &Handled) {}
}

impl BatchProgress for Silent {}

/// Upscales every material of the library at `root` (this shard's) into the mirrored path
/// under `out`, then writes the summary (`batch.csv`, `batch.json`, `index.html`) into
/// `out`. A material that fails is recorded and the batch goes on; Ctrl-C (the progress's
/// `cancelled`) stops it after the current material's checkpoint.
pub fn run_batch(
    root: &Path,
    out: &Path,
    options: &BatchOptions,
    progress: &dyn BatchProgress,
) -> Result<BatchReport> {
    check_settings(&options.config)?;
    if let (Ok(r), Ok(o)) = (root.canonicalize(), out.canonicalize()) {
        if r == o {
            return Err(Error::file(
                out,
                "output folder is the library; matup never writes into its input, choose another",
            ));
        }
    }
    let library = find_materials(root, Some(out))?;
    std::fs::create_dir_all(out).map_err(|e| Error::io(out, e))?;
    let began = SystemTime::now();
    // A material whose files cannot be listed has no fingerprint: it fails with the reason.
    let fingerprints: Vec<std::result::Result<String, String>> = library
        .materials
        .iter()
        .map(|m| settings_fingerprint(&root.join(m), options).map_err(|e| e.to_string()))
        .collect();
    let mine: Vec<usize> = (0..library.materials.len())
        .filter(|&i| {
            let name = material_name(&library.materials[i]);
            options.shard.is_none_or(|s| s.takes(&name))
        })
        .collect();
    progress.materials(mine.len());

    // Each material in flight makes its output within its share of the memory limit.
    let in_flight = options.in_flight.max(1);
    let per_material = BatchOptions {
        memory_limit: options.memory_limit.map(|m| m / in_flight as u64),
        ..options.clone()
    };
    let mut handled = Vec::new();
    let mut interrupted = false;
    std::thread::scope(|scope| {
        // The materials being worked on, oldest first.
        let mut working: VecDeque<InFlight> = VecDeque::new();
        let mut finish_oldest = |working: &mut VecDeque<InFlight>| {
            let (material, start, worker) = working.pop_front().expect("one is in flight");
            let h = Handled {
                material,
                outcome: worker.join().unwrap_or_else(|_| {
                    Outcome::Failed("matup stopped on an internal error (a bug)".into())
                }),
                seconds: start.elapsed().as_secs_f64(),
            };
            progress.material_done(&h);
            let stop = h.outcome == Outcome::Interrupted;
            handled.push(h);
            stop
        };
        for &i in &mine {
            if working.len() == in_flight && finish_oldest(&mut working) {
                interrupted = true;
                break;
            }
            if progress.cancelled() {
                interrupted = true;
                break;
            }
            let relative = &library.materials[i];
            let name = material_name(relative);
            progress.material_started(&name);
            let fingerprint = &fingerprints[i];
            let per_material = &per_material;
            let worker = scope.spawn(move || match fingerprint {
                Ok(fingerprint) => handle_material(
                    &root.join(relative),
                    &out.join(relative),
                    fingerprint,
                    began,
                    per_material,
                    progress,
                ),
                Err(error) => Outcome::Failed(error.clone()),
            });
            working.push_back((name, Instant::now(), worker));
        }
        while !working.is_empty() {
            interrupted |= finish_oldest(&mut working);
        }
    });

    let summary = summary::summarize(&library, out, &fingerprints, options.claims);
    summary::write_summary(&library, out, &summary)?;
    Ok(BatchReport {
        library,
        handled,
        summary,
        interrupted,
    })
}

/// A material being worked on: its name, when it began, and its worker.
type InFlight<'scope> = (String, Instant, ScopedJoinHandle<'scope, Outcome>);

/// One material: skipped when done, else claimed, loaded, upscaled and released.
fn handle_material(
    input: &Path,
    output: &Path,
    fingerprint: &str,
    batch_began: SystemTime,
    options: &BatchOptions,
    progress: &dyn Progress,
) -> Outcome {
    if read_result(output, fingerprint).is_some() {
        return match add_missing_view(input, output, options) {
            Ok(()) => Outcome::AlreadyDone,
            Err(e) => Outcome::Failed(e.to_string()),
        };
    }
    let claim = match claim::claim(output, options.claims) {
        Ok(claim::Claimed::Yes(c)) => c,
        Ok(claim::Claimed::HeldBy(holder)) => return Outcome::HeldBy(holder),
        Err(e) => return Outcome::Failed(e.to_string()),
    };
    // Another worker may have finished or failed it between our look and our claim.
    if read_result(output, fingerprint).is_some() {
        claim.release();
        return Outcome::AlreadyDone;
    }
    if let Some(f) = read_failure(output, fingerprint) {
        if f.failed_since(batch_began) {
            claim.release();
            return Outcome::FailedElsewhere(f.error);
        }
    }
    remove_partial_writes(output);
    let watch = ClaimWatch {
        inner: progress,
        lost: &claim.lost_flag(),
    };
    let outcome = if is_model_file(input) {
        upscale_model_in_batch(input, output, fingerprint, options, &watch)
    } else {
        upscale_material_in_batch(input, output, fingerprint, options, &watch)
    };
    let outcome = match outcome {
        Ok(_) => {
            let _ = std::fs::remove_file(output.join(FAILURE_FILE));
            Outcome::Upscaled
        }
        Err(Error::Cancelled { .. }) if claim.lost() => Outcome::LostClaim,
        Err(Error::Cancelled { .. }) => Outcome::Interrupted,
        Err(e) => {
            let error = e.to_string();
            let record = Failure {
                error: error.clone(),
                settings_fingerprint: Some(fingerprint.to_string()),
                failed_at: unix_seconds(SystemTime::now()),
            };
            let json = serde_json::to_vec_pretty(&record).expect("a failure serialises");
            match write_atomic(&output.join(FAILURE_FILE), &json) {
                Ok(()) => Outcome::Failed(error),
                Err(w) => Outcome::Failed(format!("{error} (and recording it failed: {w})")),
            }
        }
    };
    claim.release();
    outcome
}

/// A material folder into `output`: its maps, preview and `run.json` (and page, with `view`).
fn upscale_material_in_batch(
    input: &Path,
    output: &Path,
    fingerprint: &str,
    options: &BatchOptions,
    progress: &dyn Progress,
) -> Result<()> {
    let material = load_material(Some(input), &options.load)?;
    upscale_to_folder(
        &material,
        &options.config,
        output,
        &options.save,
        true,
        options.memory_limit,
        Some(fingerprint.to_string()),
        progress,
    )?;
    if options.view {
        write_run_view(&material, output)?;
    }
    Ok(())
}

/// A glTF model into `output`: the model with its files, each run's preview and report, and
/// a `run.json` that marks it done for these settings.
fn upscale_model_in_batch(
    input: &Path,
    output: &Path,
    fingerprint: &str,
    options: &BatchOptions,
    progress: &dyn Progress,
) -> Result<()> {
    let start = Instant::now();
    let run = upscale_model(
        input,
        &options.config,
        output,
        &options.save,
        &options.load,
        options.memory_limit,
        progress,
    )?;
    let first = run.runs.first().map(|(_, report)| report);
    let done = serde_json::json!({
        "settings_fingerprint": fingerprint,
        "total_seconds": start.elapsed().as_secs_f64(),
        "skipped": run.notes,
        "input_size": first.map(|r| r.input_size),
        "output_size": first.map(|r| r.output_size),
        "model_runs": run.runs.iter().map(|(label, _)| label).collect::<Vec<_>>(),
    });
    let json = serde_json::to_vec_pretty(&done).expect("a report serialises");
    write_atomic(&output.join("run.json"), &json)
}

/// With `view`, writes the page of a material done earlier without one (it needs no claim:
/// any worker writes the same page, atomically).
fn add_missing_view(input: &Path, output: &Path, options: &BatchOptions) -> Result<()> {
    // A model's previews are its runs' (`matup-runs/`); it has no page.
    if options.view && !is_model_file(input) && !output.join("view.html").is_file() {
        let material = load_material(Some(input), &options.load)?;
        write_run_view(&material, output)?;
    }
    Ok(())
}

/// Removes the temporary files of atomic writes that a killed worker left in `folder`
/// (`write_atomic`'s `.matup-*.tmp`); only the claim's holder writes there.
fn remove_partial_writes(folder: &Path) {
    let Ok(entries) = std::fs::read_dir(folder) else {
        return;
    };
    for entry in entries.filter_map(|e| e.ok()) {
        let name = entry.file_name();
        let name = name.to_string_lossy();
        if name.starts_with(".matup-") && name.ends_with(".tmp") {
            let _ = std::fs::remove_file(entry.path());
        }
    }
}

/// Forwards a material's progress, and cancels its run once its claim is lost.
struct ClaimWatch<'a> {
    inner: &'a dyn Progress,
    lost: &'a AtomicBool,
}

impl Progress for ClaimWatch<'_> {
    fn stage(&self, name: &str, total: u64) {
        self.inner.stage(name, total)
    }
    fn advance(&self, done: u64, loss: Option<f64>) {
        self.inner.advance(done, loss)
    }
    fn note(&self, message: &str) {
        self.inner.note(message)
    }
    fn cancelled(&self) -> bool {
        self.lost.load(Ordering::SeqCst) || self.inner.cancelled()
    }
}

/// A digest of what a material's (or model's) result depends on: matup's version, the
/// settings, how it is loaded and saved, and its files (names, sizes, modification times, so an
/// edited map is upscaled again).
pub fn settings_fingerprint(folder: &Path, options: &BatchOptions) -> Result<String> {
    let mut h = Sha256::new();
    h.update(env!("CARGO_PKG_VERSION"));
    h.update(options.config.to_toml());
    h.update(format!(
        "{:?} {:?} {:?} {} {}",
        options.save.format,
        options.save.normal_convention,
        options.load.normal_convention,
        options.load.max_texels,
        options.save.block_quality
    ));
    // A model depends on the files its URIs name, a material on its folder's images.
    let files: Vec<PathBuf> = if is_model_file(folder) {
        model_files(folder)?
    } else {
        std::fs::read_dir(folder)
            .map_err(|e| Error::io(folder, e))?
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| is_image_file(p))
            .collect()
    };
    let mut files = files;
    files.sort();
    for file in files {
        let meta = std::fs::metadata(&file).map_err(|e| Error::io(&file, e))?;
        let modified = meta
            .modified()
            .ok()
            .and_then(|t| t.duration_since(UNIX_EPOCH).ok())
            .map_or(0, |d| d.as_nanos());
        h.update(file.file_name().unwrap_or_default().as_encoded_bytes());
        h.update(format!(" {} {modified}\n", meta.len()));
    }
    let digest = h.finalize();
    Ok(digest[..8].iter().map(|b| format!("{b:02x}")).collect())
}
