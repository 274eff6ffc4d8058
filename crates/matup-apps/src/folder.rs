//! One material in, one output folder out: what `matup upscale` does, and `matup batch` for
//! each material of a library. The maps, `preview.png` and `run.json` are each written
//! atomically, `run.json` last, so a folder with a `run.json` holds a finished run.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use matup_core::io::{
    check_output_folder, file_name, load_material, save_png, write_atomic, LoadOptions,
    MaterialPaths, MaterialWriter, SaveOptions, StoredImage,
};
use matup_core::material::{Material, OtherSizeFile};
use matup_core::progress::Progress;
use matup_core::{Error, Result};
use matup_method::config::TargetSize;
use matup_method::pipeline::upscale_streamed;
use matup_method::plan::Plan;
use matup_method::preview::{preview_of_centre, PreviewWindow};
use matup_method::report::{peak_memory_mib, OtherSizeRun, RunReport};
use matup_method::Config;
use matup_method::RunOptions;

/// The checkpoint folder of a run inside its output folder (removed once the run finishes).
pub const CHECKPOINT_FOLDER: &str = ".matup-checkpoint";

/// What [`upscale_to_folder`] wrote.
pub struct FolderRun {
    pub report: RunReport,
    /// The maps, `preview.png`, the files of other sizes, then `run.json`.
    pub written: Vec<PathBuf>,
}

/// Upscales `material` into `out` (created; never the input folder): the maps in `save`'s
/// formats, written band by band as the pipeline finishes them (within `memory_limit` bytes
/// of heap, when given), `preview.png` and `run.json` (carrying `fingerprint`, when given, as
/// `settings_fingerprint`). Training checkpoints go to `out/.matup-checkpoint`; with `resume`
/// a run continues from them.
#[allow(clippy::too_many_arguments)]
pub fn upscale_to_folder(
    material: &Material,
    config: &Config,
    out: &Path,
    save: &SaveOptions,
    resume: bool,
    memory_limit: Option<u64>,
    fingerprint: Option<String>,
    progress: &dyn Progress,
) -> Result<FolderRun> {
    check_output_folder(out, material.origin.as_ref())?;
    if out.exists() && !out.is_dir() {
        return Err(Error::file(out, "output exists and is not a folder"));
    }
    // Settings that cannot run (an unknown upsampler or shading model, a size that cannot be
    // reached) are refused before the folder is made.
    let plan = Plan::new(material, config)?;
    let size = plan.output_size([material.width(), material.height_px()]);
    std::fs::create_dir_all(out).map_err(|e| Error::io(out, e))?;
    let checkpoints = out.join(CHECKPOINT_FOLDER);
    let options = RunOptions {
        checkpoint_folder: Some(checkpoints.clone()),
        resume,
        oracle: None,
        memory_limit,
    };
    let mut maps = MaterialWriter::new(out, size, material.origin.as_ref(), save)?;
    let mut centre = PreviewWindow::new(size);
    let mut report = upscale_streamed(material, &plan, &options, progress, &mut |first, band| {
        centre.add(first, band)?;
        maps.write_band(band)
    })?;
    report.settings_fingerprint = fingerprint;

    let mut written = maps.finish()?;
    let centre = centre.finish().expect("a run makes at least one band");
    let sheet = preview_of_centre(material, &centre, size, &plan)?;
    let preview_path = out.join("preview.png");
    save_png(&preview_path, &sheet)?;
    written.push(preview_path);
    let (other_sizes, mut other_files) =
        upscale_other_sizes(material, &plan, out, save, &options, &written, progress)?;
    report.other_sizes = other_sizes;
    written.append(&mut other_files);
    // The peak after the maps, the preview and the other sizes, not only the pipeline's.
    report.peak_memory_mib = peak_memory_mib();
    let json = serde_json::to_string_pretty(&report)
        .map_err(|e| Error::Invalid(format!("run.json: {e}")))?;
    let run_json = out.join("run.json");
    write_atomic(&run_json, json.as_bytes())?;
    written.push(run_json);
    let _ = std::fs::remove_dir_all(&checkpoints); // finished: nothing to resume
    Ok(FolderRun { report, written })
}

/// What [`upscale_in_memory`] made.
pub struct MemoryRun {
    pub report: RunReport,
    /// The maps' files, in the order [`upscale_to_folder`] writes them.
    pub images: Vec<StoredImage>,
}

/// Upscales `material` as [`upscale_to_folder`] does, its files kept in memory rather than
/// written: each as its file stores it (PNG, EXR and TIFF exactly; a lossy or block format
/// before its encoding). There is no preview, `run.json` or checkpoint; a material with
/// images of another size (which are loaded again from disk) is refused.
pub fn upscale_in_memory(
    material: &Material,
    config: &Config,
    save: &SaveOptions,
    memory_limit: Option<u64>,
    progress: &dyn Progress,
) -> Result<MemoryRun> {
    if let Some(other) = material.origin.as_ref().and_then(|o| o.other_sizes.first()) {
        return Err(Error::file(
            &other.path,
            "another size than the maps: upscaled apart, it needs the folder on disk",
        ));
    }
    let plan = Plan::new(material, config)?;
    let size = plan.output_size([material.width(), material.height_px()]);
    let options = RunOptions {
        checkpoint_folder: None,
        resume: false,
        oracle: None,
        memory_limit,
    };
    let mut maps = MaterialWriter::in_memory(size, material.origin.as_ref(), save)?;
    let report = upscale_streamed(material, &plan, &options, progress, &mut |_, band| {
        maps.write_band(band)
    })?;
    Ok(MemoryRun {
        report,
        images: maps.finish_in_memory()?,
    })
}

/// The folder's images of another size than its maps
/// ([`MaterialOrigin::other_sizes`](matup_core::material::MaterialOrigin::other_sizes)), each
/// size loaded as a material of its own and upscaled by the factor that takes the maps to
/// their output size, into `out` under their own names, none of them a file of `taken`: the
/// runs and the files written.
fn upscale_other_sizes(
    material: &Material,
    plan: &Plan,
    out: &Path,
    save: &SaveOptions,
    options: &RunOptions,
    taken: &[PathBuf],
    progress: &dyn Progress,
) -> Result<(Vec<OtherSizeRun>, Vec<PathBuf>)> {
    let (mut runs, mut written) = (Vec::new(), Vec::new());
    let Some(origin) = &material.origin else {
        return Ok((runs, written));
    };
    let mut by_size: BTreeMap<[usize; 2], Vec<&OtherSizeFile>> = BTreeMap::new();
    for file in &origin.other_sizes {
        by_size.entry(file.size).or_default().push(file);
    }
    let input = [material.width(), material.height_px()];
    let maps_output = plan.output_size(input);
    for (size, files) in by_size {
        let names: Vec<String> = files.iter().map(|f| file_name(&f.path)).collect();
        let [w, h] = size;
        progress.note(&format!(
            "{} ({w}×{h}, another size than the material's {}×{}): upscaled apart, by the \
             same factor",
            names.join(", "),
            input[0],
            input[1]
        ));
        let paths = MaterialPaths {
            carried: files.iter().map(|f| (f.path.clone(), f.data)).collect(),
            ..MaterialPaths::default()
        };
        // Their texel count passed the limit when the folder was read.
        let load = LoadOptions {
            paths,
            normal_convention: None,
            max_texels: u64::MAX,
        };
        let part = load_material(None, &load)?;
        // A size asked for holds for the maps: these keep the ratio it gave them.
        let part_output = plan.asked_size.map(|_| {
            let side = |i: usize| (size[i] * maps_output[i] + input[i] / 2) / input[i];
            TargetSize {
                width: side(0),
                height: Some(side(1)),
            }
        });
        let plan = plan.for_other_material(&part, part_output)?;
        let part_size = plan.output_size(size);
        let options = RunOptions {
            checkpoint_folder: (options.checkpoint_folder.as_ref())
                .map(|c| c.join(format!("other-size-{w}x{h}"))),
            resume: options.resume,
            oracle: None,
            memory_limit: options.memory_limit,
        };
        let taken: Vec<PathBuf> = (taken.iter()).chain(&written).cloned().collect();
        let mut maps =
            MaterialWriter::new(out, part_size, part.origin.as_ref(), save)?.beside(&taken);
        let report = upscale_streamed(&part, &plan, &options, progress, &mut |_, band| {
            maps.write_band(band)
        })?;
        written.append(&mut maps.finish()?);
        runs.push(OtherSizeRun {
            files: names,
            input_size: size,
            output_size: part_size,
            upsampler_used: report.upsampler_used,
            route: report.route,
            tileable: report.tileable,
            carried: report.carried,
        });
    }
    Ok((runs, written))
}
