//! What a run did: the report written as `run.json` and printed as the CLI's summary, with
//! the stage timings and the memory it is made of.

use std::path::PathBuf;
use std::time::Instant;

use serde::Serialize;

use crate::config::Config;
use crate::select::SelectionReport;
use crate::train::TrainStats;
use matup_core::Result;

/// What a run did, for `run.json` and the CLI summary.
#[derive(Clone, Debug, Serialize)]
pub struct RunReport {
    pub matup_version: &'static str,
    /// The folder the input was loaded from, when it came from one.
    pub input_folder: Option<PathBuf>,
    pub input_size: [usize; 2],
    pub output_size: [usize; 2],
    pub config: Config,
    /// The RGB upsampler that ran (what `auto` chose).
    pub upsampler_used: String,
    /// Where each network ran (a GPU adapter by the name its driver gives, or the CPU) and
    /// why (`Setup::placements`).
    #[serde(default)]
    pub network_devices: Vec<String>,
    /// How the output size was reached: `×4`, or a size asked for (`×2, then area-shrunk to
    /// 1536×1536`); each level's route is in `levels`.
    pub route: String,
    pub tileable: bool,
    /// The evidence the tileability was decided from (absent when it was given): the
    /// wrap-around step over the largest interior step, the lesser axis
    /// (`matup_core::tileable::decide_tileable`).
    pub tiling_evidence: Option<f32>,
    /// Why the source decided the tiling, where it did (a glTF model's UV atlas).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub tiling_source: Option<String>,
    /// Whether the input was read as clean or degraded, and why (`crate::plan::InputRoute`).
    #[serde(default)]
    pub input_route: String,
    /// How the settings were chosen, with `select = "auto"` (`config` is the chosen one).
    pub selection: Option<SelectionReport>,
    pub levels: Vec<LevelReport>,
    /// Seconds per stage, in order.
    pub timings: Vec<(String, f64)>,
    pub total_seconds: f64,
    /// Mean training loss of the last epoch of the last level.
    pub final_loss: Option<f64>,
    /// Work skipped because the material could not use it.
    pub skipped: Vec<String>,
    /// The maps carried beside the rendered ones (alpha channels, occlusion, opacity, …) and
    /// how each was upsampled.
    pub carried: Vec<String>,
    /// For every map read, the file and channels it came from and how they were stored; how
    /// the normal convention was found; what a flag replaced.
    pub sources: Vec<String>,
    /// Maps the input lacks, and what stood in for them.
    pub stand_ins: Vec<String>,
    /// The folder's images of another size than its maps, upscaled after them, a run for
    /// each size (filled in by the caller that writes them: `matup_apps::folder`).
    pub other_sizes: Vec<OtherSizeRun>,
    /// The heap the output's bands were planned within (`--memory-limit`), in MiB; none: one
    /// band per level.
    pub memory_limit_mib: Option<f64>,
    /// Peak resident memory of the process (Linux), in MiB.
    pub peak_memory_mib: Option<f64>,
    pub threads: usize,
    /// A digest of the settings and input files, written by `matup batch` to tell a finished
    /// material from one to redo.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub settings_fingerprint: Option<String>,
}

/// The run of a folder's images of one size that is not its maps'.
#[derive(Clone, Debug, Serialize)]
pub struct OtherSizeRun {
    /// The files' names.
    pub files: Vec<String>,
    pub input_size: [usize; 2],
    pub output_size: [usize; 2],
    pub upsampler_used: String,
    pub route: String,
    pub tileable: bool,
    /// How each map was upsampled, as [`RunReport::carried`].
    pub carried: Vec<String>,
}

/// One level (one ×s step) of a run.
#[derive(Clone, Debug, Serialize)]
pub struct LevelReport {
    pub scale: usize,
    /// What made the level's maps: `×2 by onnx:span_x4_materials at ×4, then ÷2 by area
    /// (2 passes), back-projected`.
    pub route: String,
    pub input_size: [usize; 2],
    pub output_size: [usize; 2],
    pub lights_used: usize,
    /// Features held constant instead of learned.
    pub constant_features: Vec<&'static str>,
    pub training: TrainStats,
    /// The bands of rows the output was made in (1: whole).
    pub bands: usize,
}

pub(crate) fn timed<T>(
    timings: &mut Vec<(String, f64)>,
    name: String,
    f: impl FnOnce() -> Result<T>,
) -> Result<T> {
    let start = Instant::now();
    let out = f()?;
    let seconds = start.elapsed().as_secs_f64();
    // A stage run once per band adds up under one name.
    match timings.iter_mut().find(|(n, _)| *n == name) {
        Some((_, total)) => *total += seconds,
        None => timings.push((name, seconds)),
    }
    Ok(out)
}

/// Peak resident memory from `/proc/self/status` (VmHWM), where there is one.
pub fn peak_memory_mib() -> Option<f64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kib: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kib / 1024.0)
}
