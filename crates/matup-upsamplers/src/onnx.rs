//! `onnx`: a pre-trained RGB super-resolution network from an ONNX file, run on the CPU with
//! tract. Facts the file does not state (scale, value range, channel order, tiling, licence)
//! come from a sidecar `NAME.toml` next to `NAME.onnx`; the scale is checked against the
//! network's real output on a probe input.
//!
//! Images are processed in tiles read with `overlap` texels of context on every side (wrapping
//! around for tileable materials), several tiles per call, and blended with feathered weights
//! where their kept regions overlap, so memory stays bounded and no seam shows. The optimised
//! tract plan is built once per input shape and reused.

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};

use matup_core::plugin::{option_value, parse_options, PluginOption};
use matup_core::resample::Border;
use matup_core::upsample::{RgbUpsampler, UpsamplerRegistration};
use matup_core::{Error, Map, Result};
use serde::Deserialize;
use tract_linalg::multithread::{multithread_tract_scope, Executor};
use tract_onnx::prelude::*;

/// What a sidecar `NAME.toml` says about `NAME.onnx`.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ModelInfo {
    pub scale: usize,
    #[serde(default = "unit_range")]
    pub input_range: [f32; 2],
    #[serde(default = "unit_range")]
    pub output_range: [f32; 2],
    #[serde(default = "rgb")]
    pub channel_order: String,
    #[serde(default = "default_tile")]
    pub tile: usize,
    #[serde(default)]
    pub overlap: usize,
    #[serde(default = "default_batch")]
    pub batch: usize,
    #[serde(default)]
    pub licence: String,
    #[serde(default)]
    pub source: String,
    #[serde(default)]
    pub description: String,
}

fn unit_range() -> [f32; 2] {
    [0.0, 1.0]
}
fn rgb() -> String {
    "rgb".into()
}
fn default_tile() -> usize {
    128
}
fn default_batch() -> usize {
    4
}

/// The folders searched for `onnx:NAME`: `$MATUP_MODELS` (`:`-separated), `./models`, and the
/// `models/` folder of the matup source tree this was built from.
pub fn model_dirs() -> Vec<PathBuf> {
    let mut dirs: Vec<PathBuf> = std::env::var("MATUP_MODELS")
        .map(|v| std::env::split_paths(&v).collect())
        .unwrap_or_default();
    dirs.push(PathBuf::from("models"));
    dirs.push(PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../models"));
    dirs
}

/// Every `NAME.onnx` with a sidecar in the model folders: (name, path, sidecar).
pub fn available_models() -> Vec<(String, PathBuf, ModelInfo)> {
    let mut found: Vec<(String, PathBuf, ModelInfo)> = Vec::new();
    for dir in model_dirs() {
        let Ok(entries) = std::fs::read_dir(&dir) else {
            continue;
        };
        let mut paths: Vec<PathBuf> = entries.filter_map(|e| e.ok().map(|e| e.path())).collect();
        paths.sort();
        for path in paths {
            if path.extension().is_some_and(|e| e == "onnx") {
                let name = path
                    .file_stem()
                    .unwrap_or_default()
                    .to_string_lossy()
                    .into_owned();
                if found.iter().any(|f| f.0 == name) {
                    continue; // an earlier folder wins
                }
                if let Ok(info) = read_sidecar(&path) {
                    found.push((name, path, info));
                }
            }
        }
    }
    found
}

/// A path (`…/x.onnx`) as given, or a model name looked up in the model folders.
fn resolve(model: &str) -> Result<PathBuf> {
    if model.ends_with(".onnx") || model.contains(std::path::MAIN_SEPARATOR) {
        return Ok(PathBuf::from(model));
    }
    for dir in model_dirs() {
        let path = dir.join(format!("{model}.onnx"));
        if path.is_file() {
            return Ok(path);
        }
    }
    let known: Vec<String> = available_models().into_iter().map(|m| m.0).collect();
    Err(Error::Plugin {
        plugin: "onnx".into(),
        message: format!(
            "no model '{model}' in {}; known models: {}",
            model_dirs()
                .iter()
                .map(|d| d.display().to_string())
                .collect::<Vec<_>>()
                .join(", "),
            if known.is_empty() {
                "none".into()
            } else {
                known.join(", ")
            }
        ),
    })
}

fn sidecar_path(model: &Path) -> PathBuf {
    model.with_extension("toml")
}

fn read_sidecar(model: &Path) -> Result<ModelInfo> {
    let path = sidecar_path(model);
    let text = std::fs::read_to_string(&path).map_err(|e| Error::Plugin {
        plugin: "onnx".into(),
        message: format!(
            "{}: cannot read the model's sidecar ({e}); it states the scale and value ranges",
            path.display()
        ),
    })?;
    toml::from_str(&text).map_err(|e| Error::Plugin {
        plugin: "onnx".into(),
        message: format!("{}: {e}", path.display()),
    })
}

type Plan = Arc<TypedRunnableModel>;

/// A loaded network and its plans by input shape.
pub struct OnnxUpsampler {
    path: PathBuf,
    pub info: ModelInfo,
    model: InferenceModel,
    plans: Mutex<HashMap<[usize; 3], Plan>>,
    executor: Executor,
}

fn model_error(path: &Path, what: &str, e: impl std::fmt::Display) -> Error {
    Error::Plugin {
        plugin: "onnx".into(),
        message: format!("{}: {what}: {e}", path.display()),
    }
}

/// tract's matrix products split across `threads` threads (measured on 2 cores: SPAN ×4 on a
/// 128² render took 0.74 s on one thread, 0.35 s on two). Running tiles concurrently on
/// single-threaded plans measured the same, so the simpler multithreaded product is used.
fn executor(threads: usize) -> Executor {
    if threads > 1 {
        Executor::multithread_with_name(threads, "matup-onnx")
    } else {
        Executor::SingleThread
    }
}

impl OnnxUpsampler {
    /// Loads `path` and its sidecar, checks the input layout, and probes the real scale.
    pub fn load(path: &Path) -> Result<OnnxUpsampler> {
        if !path.is_file() {
            return Err(model_error(path, "cannot open", "no such file"));
        }
        let info = read_sidecar(path)?;
        if info.scale == 0
            || info.tile == 0
            || info.batch == 0
            || !matches!(info.channel_order.as_str(), "rgb" | "bgr")
        {
            return Err(model_error(
                path,
                "invalid sidecar",
                "scale, tile and batch must be positive, channel_order rgb or bgr",
            ));
        }
        let model = tract_onnx::onnx()
            .model_for_path(path)
            .map_err(|e| model_error(path, "not a readable ONNX model", format!("{e:#}")))?;
        if model.inputs.len() != 1 || model.outputs.len() != 1 {
            return Err(model_error(
                path,
                "unsupported network",
                format!(
                    "{} inputs and {} outputs (want 1 and 1)",
                    model.inputs.len(),
                    model.outputs.len()
                ),
            ));
        }
        let upsampler = OnnxUpsampler {
            path: path.to_path_buf(),
            info,
            model,
            plans: Mutex::new(HashMap::new()),
            // As many as the pool matup runs on (`RAYON_NUM_THREADS`, or one per core).
            executor: executor(rayon::current_num_threads()),
        };
        // Probe: the output must be the input times the sidecar's scale, 3 channels.
        let probe = Map::filled(8, 8, 3, 0.5);
        let out = upsampler.run_batch(&[probe_tile(&probe)], 8, 8)?;
        let got = out[0].width() / 8;
        if got != upsampler.info.scale || out[0].height() != 8 * got {
            return Err(model_error(
                path,
                "scale mismatch",
                format!(
                    "the sidecar says ×{}, the network upsamples an 8×8 probe to {}×{}",
                    upsampler.info.scale,
                    out[0].width(),
                    out[0].height()
                ),
            ));
        }
        Ok(upsampler)
    }

    fn plan(&self, batch: usize, h: usize, w: usize) -> Result<Plan> {
        let key = [batch, h, w];
        if let Some(p) = self.plans.lock().unwrap().get(&key) {
            return Ok(p.clone());
        }
        let plan = self
            .model
            .clone()
            .with_input_fact(0, f32::fact([batch, 3, h, w]).into())
            .and_then(|m| m.into_optimized())
            .and_then(|m| m.into_runnable())
            .map_err(|e| {
                model_error(
                    &self.path,
                    "cannot run on [batch, 3, height, width] RGB input",
                    format!("{e:#}"),
                )
            })?;
        self.plans.lock().unwrap().insert(key, plan.clone());
        Ok(plan)
    }

    /// Runs the network on tiles of one shape (each 3 planes of `h × w`, values in [0, 1]).
    fn run_batch(&self, tiles: &[Vec<f32>], h: usize, w: usize) -> Result<Vec<Map>> {
        let [lo, hi] = self.info.input_range;
        let bgr = self.info.channel_order == "bgr";
        let n = h * w;
        let mut data = Vec::with_capacity(tiles.len() * 3 * n);
        for tile in tiles {
            for c in 0..3 {
                let src = if bgr { 2 - c } else { c };
                data.extend(
                    tile[src * n..(src + 1) * n]
                        .iter()
                        .map(|v| lo + v * (hi - lo)),
                );
            }
        }
        let input: Tensor = tract_ndarray::Array4::from_shape_vec((tiles.len(), 3, h, w), data)
            .map_err(|e| model_error(&self.path, "input", e))?
            .into();
        let plan = self.plan(tiles.len(), h, w)?;
        let outputs =
            multithread_tract_scope(self.executor.clone(), || plan.run(tvec!(input.into())))
                .map_err(|e| model_error(&self.path, "inference failed", format!("{e:#}")))?;
        let view = outputs[0]
            .to_plain_array_view::<f32>()
            .map_err(|e| model_error(&self.path, "output", e))?;
        let shape = view.shape().to_vec();
        if shape.len() != 4 || shape[0] != tiles.len() || shape[1] != 3 {
            return Err(model_error(
                &self.path,
                "unsupported output",
                format!("shape {shape:?}, want [batch, 3, height, width]"),
            ));
        }
        let [olo, ohi] = self.info.output_range;
        let (oh, ow) = (shape[2], shape[3]);
        Ok((0..tiles.len())
            .map(|b| {
                Map::from_fn(ow, oh, 3, |c, y, x| {
                    let src = if bgr { 2 - c } else { c };
                    ((view[[b, src, y, x]] - olo) / (ohi - olo)).clamp(0.0, 1.0)
                })
            })
            .collect())
    }
}

fn probe_tile(map: &Map) -> Vec<f32> {
    map.data().to_vec()
}

/// Start of each tile along an axis of `len` texels, tiles of `tile` (the last one shifted
/// back to end at the edge).
fn tile_starts(len: usize, tile: usize) -> Vec<usize> {
    let tile = tile.min(len);
    let mut starts: Vec<usize> = (0..len.div_ceil(tile))
        .map(|k| (k * tile).min(len - tile))
        .collect();
    starts.dedup();
    starts
}

/// Feathering weight of an output texel at LR coordinate `u` (relative to the tile's core,
/// which spans [0, core)) with `margin` LR texels kept on each side: 1 inside the core,
/// falling linearly to near 0 at the kept region's edge.
fn feather(u: f32, core: f32, margin: f32) -> f32 {
    if margin <= 0.0 {
        return if (0.0..core).contains(&u) { 1.0 } else { 0.0 };
    }
    let d = (u + margin).min(core + margin - u);
    (d / margin).clamp(0.0, 1.0)
}

/// Along one axis of a tile whose core starts at LR texel `origin` and is `core` long (read
/// with `overlap` texels of context, keeping `margin` of them), the output texels that land in
/// the image (`len` LR texels, ×`scale`): (index in the tile's output, index in the image's
/// output, feathering weight).
fn kept_texels(
    origin: usize,
    core: usize,
    len: usize,
    overlap: usize,
    margin: usize,
    scale: usize,
) -> Vec<(usize, usize, f32)> {
    (0..(core + 2 * overlap) * scale)
        .filter_map(|t| {
            // LR coordinate of this output texel relative to the tile's core.
            let u = (t as f32 + 0.5) / scale as f32 - overlap as f32;
            let weight = feather(u, core as f32, margin as f32);
            let global = (origin * scale + t) as isize - (overlap * scale) as isize;
            (weight > 0.0 && global >= 0 && global < (len * scale) as isize).then_some((
                t,
                global as usize,
                weight,
            ))
        })
        .collect()
}

impl RgbUpsampler for OnnxUpsampler {
    fn native_scale(&self) -> Option<usize> {
        Some(self.info.scale)
    }

    fn upsample(&self, images: &[Map], scale: usize, border: Border) -> Result<Vec<Map>> {
        let s = self.info.scale;
        if scale != s {
            return Err(Error::Unsupported {
                plugin: format!("onnx:{}", self.path.display()),
                what: format!("scale ×{scale} (the network upsamples ×{s})"),
            });
        }
        let mut results = Vec::with_capacity(images.len());
        let o = self.info.overlap;
        // Tiles keep `margin` texels of their context, blended with their neighbours'.
        let margin = o / 2;
        for image in images {
            let (w, h) = (image.width(), image.height());
            let (th, tw) = (self.info.tile.min(h), self.info.tile.min(w));
            let (ph, pw) = (th + 2 * o, tw + 2 * o);
            let origins: Vec<(usize, usize)> = tile_starts(h, th)
                .into_iter()
                .flat_map(|y| tile_starts(w, tw).into_iter().map(move |x| (y, x)))
                .collect();
            let mut acc = vec![0f32; 3 * h * s * w * s];
            let mut weight = vec![0f32; h * s * w * s];
            for group in origins.chunks(self.info.batch) {
                let tiles: Vec<Vec<f32>> = group
                    .iter()
                    .map(|&(y0, x0)| {
                        let mut t = Vec::with_capacity(3 * ph * pw);
                        for c in 0..3 {
                            for ty in 0..ph {
                                let y = border.index(y0 as isize + ty as isize - o as isize, h);
                                for tx in 0..pw {
                                    let x = border.index(x0 as isize + tx as isize - o as isize, w);
                                    t.push(image.get(c, y, x));
                                }
                            }
                        }
                        t
                    })
                    .collect();
                let outputs = self.run_batch(&tiles, ph, pw)?;
                for (&(y0, x0), out) in group.iter().zip(&outputs) {
                    let rows = kept_texels(y0, th, h, o, margin, s);
                    let columns = kept_texels(x0, tw, w, o, margin, s);
                    for &(oy, gy, wy) in &rows {
                        for &(ox, gx, wx) in &columns {
                            let k = gy * w * s + gx;
                            let wt = wy * wx;
                            weight[k] += wt;
                            for c in 0..3 {
                                acc[c * h * s * w * s + k] += wt * out.get(c, oy, ox);
                            }
                        }
                    }
                }
            }
            let n = h * s * w * s;
            for (k, &wsum) in weight.iter().enumerate() {
                for c in 0..3 {
                    acc[c * n + k] /= wsum.max(1e-12);
                }
            }
            results.push(Map::from_planar(w * s, h * s, 3, acc));
        }
        Ok(results)
    }
}

const OPTIONS: &[PluginOption] = &[
    PluginOption {
        key: "tile",
        default: "",
        help: "LR texels per tile side (default: the sidecar's)",
    },
    PluginOption {
        key: "overlap",
        default: "",
        help: "LR texels of context around each tile (default: the sidecar's)",
    },
    PluginOption {
        key: "batch",
        default: "",
        help: "tiles per network call (default: the sidecar's)",
    },
    PluginOption {
        key: "threads",
        default: "",
        help: "threads for the network's matrix products (default: matup's thread count)",
    },
];

/// `onnx:MODEL[,tile=N,overlap=N,batch=N,threads=N]`, MODEL a path to a `.onnx` file or a name in the
/// model folders.
fn create(argument: Option<&str>) -> Result<Box<dyn RgbUpsampler>> {
    let argument = argument.unwrap_or("");
    let (model, options) = argument.split_once(',').unwrap_or((argument, ""));
    if model.is_empty() {
        return Err(Error::Plugin {
            plugin: "onnx".into(),
            message: "name a model: onnx:PATH.onnx or onnx:NAME (see matup list)".into(),
        });
    }
    let mut upsampler = OnnxUpsampler::load(&resolve(model)?)?;
    let values = parse_options("onnx", Some(options), OPTIONS)?;
    for (key, slot) in [
        ("tile", &mut upsampler.info.tile),
        ("overlap", &mut upsampler.info.overlap),
        ("batch", &mut upsampler.info.batch),
    ] {
        if !values[key].is_empty() {
            *slot = option_value("onnx", &values, key)?;
        }
    }
    if !values["threads"].is_empty() {
        upsampler.executor = executor(option_value("onnx", &values, "threads")?);
    }
    if upsampler.info.tile == 0 || upsampler.info.batch == 0 {
        return Err(Error::Plugin {
            plugin: "onnx".into(),
            message: "tile and batch must be positive".into(),
        });
    }
    Ok(Box::new(upsampler))
}

inventory::submit! {
    UpsamplerRegistration {
        name: "onnx",
        description: "a pre-trained SR network: onnx:PATH.onnx or onnx:NAME from the model folders (tract, CPU)",
        options: OPTIONS,
        create,
    }
}
