//! Helpers shared by the integration tests.
#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

use matup::config::Config;
use matup::material::{Extra, MapKind, Material};
use matup::progress::Progress;
use matup::{FileFormat, Map, RunOptions};

pub mod nets;

/// Upscales `material` into `out` as `matup upscale` does without its run options: no resume,
/// no memory limit, no fingerprint, no progress shown.
pub fn upscale_into(
    material: &Material,
    config: &Config,
    out: &Path,
    save: &matup::SaveOptions,
) -> matup::Result<matup::folder::FolderRun> {
    matup::folder::upscale_to_folder(
        material,
        config,
        out,
        save,
        false,
        None,
        None,
        &matup::progress::Silent,
    )
}

/// A real material the repository ships for its tests: `tests/data/materials/<name>`, 256²
/// box-filtered from the 1024² set of that name (`tests/data/README.md`).
pub fn test_material(name: &str) -> PathBuf {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data/materials")
        .join(name);
    assert!(path.is_dir(), "{} is missing", path.display());
    path
}

/// [`test_material`] `name` loaded as matup reads a folder.
pub fn load_test_material(name: &str) -> Material {
    matup::load_material(Some(&test_material(name)), &Default::default()).unwrap()
}

/// The names of every material in `tests/data/materials`, sorted.
pub fn test_material_names() -> Vec<String> {
    let folder = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/data/materials");
    let mut names: Vec<String> = std::fs::read_dir(&folder)
        .unwrap()
        .filter_map(|e| e.ok())
        .filter(|e| e.path().is_dir())
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    names
}

/// The sample material shipped with the repository.
pub fn sample_material() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("samples/victorian_wood")
}

/// `material` with two maps carried along, made from its base colour: an occlusion map (grey,
/// from green) and a soft base-colour alpha (from red, doubled, 1 at most).
pub fn with_occlusion_and_alpha(mut material: Material) -> Material {
    let colour = material.base_color.clone();
    let (w, h) = (colour.width(), colour.height());
    let occlusion = Map::from_fn(w, h, 1, |_, y, x| 0.5 + 0.5 * colour.get(1, y, x));
    let alpha = Map::from_fn(w, h, 1, |_, y, x| (colour.get(0, y, x) * 2.0).min(1.0));
    material.carried.extras.push(Extra {
        name: "occlusion".into(),
        source: "occlusion.png".into(),
        format: FileFormat::Png8,
        map: occlusion,
        alpha: None,
    });
    material.carried.alpha.insert(MapKind::BaseColor, alpha);
    material
}

/// The largest absolute difference between two maps of one shape.
pub fn max_abs_diff(a: &Map, b: &Map) -> f32 {
    assert_eq!(
        (a.width(), a.height(), a.channels()),
        (b.width(), b.height(), b.channels())
    );
    a.data()
        .iter()
        .zip(b.data())
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f32::max)
}

/// How far, in 8-bit levels, each texel of square `input` lies from the mean of the
/// `factor × factor` block of `output` (a ×`factor` upscale of it, `width` texels wide) above
/// it: in linear light for sRGB `colour`, as stored otherwise.
pub fn box_back_levels(
    input: &[f32],
    output: &[f32],
    width: usize,
    factor: usize,
    colour: bool,
) -> Vec<f32> {
    let linear = |v: f32| {
        if colour {
            matup::color::srgb_to_linear(v)
        } else {
            v
        }
    };
    let stored = |v: f32| {
        if colour {
            matup::color::linear_to_srgb(v)
        } else {
            v
        }
    };
    let (small, f) = (width / factor, factor);
    (0..small * small)
        .map(|i| {
            let (y, x) = (i / small, i % small);
            let block = (0..f * f).map(|k| linear(output[(f * y + k / f) * width + f * x + k % f]));
            (stored(block.sum::<f32>() / (f * f) as f32) - input[i]).abs() * 255.0
        })
        .collect()
}

/// A GLB file: the `json` chunk and the binary chunk `bin`.
pub fn glb_bytes(json: &serde_json::Value, bin: Vec<u8>) -> Vec<u8> {
    let glb = gltf::binary::Glb {
        header: gltf::binary::Header {
            magic: *b"glTF",
            version: 2,
            length: 0, // to_vec writes the real one
        },
        json: serde_json::to_vec(json).unwrap().into(),
        bin: Some(bin.into()),
    };
    glb.to_vec().unwrap()
}

/// Asks training to stop once `limit` steps are done.
pub struct StopAfter {
    steps: AtomicU64,
    limit: u64,
}

impl StopAfter {
    pub fn new(limit: u64) -> StopAfter {
        StopAfter {
            steps: AtomicU64::new(0),
            limit,
        }
    }
}

impl Progress for StopAfter {
    fn advance(&self, done: u64, loss: Option<f64>) {
        if loss.is_some() {
            self.steps.fetch_add(done, Ordering::SeqCst);
        }
    }
    fn cancelled(&self) -> bool {
        self.steps.load(Ordering::SeqCst) >= self.limit
    }
}

/// Runs `config` on `lr` with checkpoints in `folder` and interrupts it after `steps`
/// training steps, which must fall in its second epoch; returns the options that resume it.
pub fn interrupt_in_second_epoch(
    lr: &Material,
    config: &Config,
    folder: &Path,
    steps: u64,
) -> RunOptions {
    let options = RunOptions {
        checkpoint_folder: Some(folder.to_path_buf()),
        resume: true,
        ..Default::default()
    };
    let stop = StopAfter::new(steps);
    let error = matup::upscale(lr, config, &options, &stop).unwrap_err();
    assert!(
        matches!(error, matup::Error::Cancelled { epochs_done: 1 }),
        "{error}"
    );
    options
}
