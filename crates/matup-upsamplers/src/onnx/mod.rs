//! `onnx`: a pre-trained RGB super-resolution network from an ONNX file, run on the CPU.
//! Facts the file does not state (scale, value range, channel order, tiling, licence) come
//! from a sidecar `NAME.toml` next to `NAME.onnx`; the scale is checked against the network's
//! real output on a probe input.
//!
//! Two engines run the graph: matup's own executor for convolutional SR graphs ([`convnet`],
//! several times faster on CPUs), used whenever the graph's operators allow, and tract for
//! every other graph; the optimised tract plan is built once per input shape and reused.
//!
//! Images are processed in tiles read with `overlap` texels of context on every side (wrapping
//! around for tileable materials), several tiles per call, and blended with feathered weights
//! where their kept regions overlap, so memory stays bounded and no seam shows. A tileable
//! image that fits in one tile runs whole on matup's executor, its convolutions wrapping
//! around, which needs no context at all.

mod conv;
mod convnet;
mod kernels;
mod source;
mod winograd;

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};

use matup_core::plugin::{option_value, parse_options, PluginOption};
use matup_core::resample::Border;
use matup_core::upsample::{RgbUpsampler, UpsamplerRegistration};
use matup_core::{Error, Map, Result};
use rayon::prelude::*;
use serde::Deserialize;
use tract_linalg::multithread::{multithread_tract_scope, Executor};
use tract_onnx::prelude::*;

use convnet::ConvNet;
pub use convnet::{Graph, Op, RawConv, Step, Unsupported};
pub use kernels::{Arith, PerTexel};
use kernels::{Features, Padding};
pub use source::{
    available_models, model_dirs, read_sidecar, read_sidecar_file, resolve, BuiltIn, ModelSource,
    BUILT_IN,
};
pub use tract_onnx::pb::ModelProto;

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

type Plan = Arc<TypedRunnableModel>;

/// The ONNX file at `path` and its graph, if matup's executor runs it (what a trainer can
/// rebuild and write back).
pub fn read_graph(path: &Path) -> Result<(ModelProto, Graph)> {
    let source = ModelSource::File(path.to_path_buf());
    let proto = source.proto()?;
    let graph =
        Graph::from_model(&proto).map_err(|e| source.error("matup's executor cannot run it", e))?;
    Ok((proto, graph))
}

/// Which engine runs a network: `auto` picks matup's executor where the graph allows.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum EngineChoice {
    Auto,
    Matup,
    Tract,
}

/// What runs the network.
enum Engine {
    /// matup's executor ([`convnet`]), on `pool` (matup's own thread pool when `None`).
    Matup {
        net: ConvNet,
        pool: Option<rayon::ThreadPool>,
    },
    /// tract, with its plans by input shape [batch, height, width], and why matup's
    /// executor does not run the graph.
    Tract {
        because: String,
        model: Box<InferenceModel>,
        plans: Mutex<HashMap<[usize; 3], Plan>>,
        executor: Executor,
    },
}

/// A loaded network.
pub struct OnnxUpsampler {
    source: ModelSource,
    pub info: ModelInfo,
    engine: Engine,
    /// The input's batch, height and width where the network fixes them.
    fixed: [Option<usize>; 3],
}

/// The [batch, height, width] an ONNX file's input declares, `None` where it is symbolic.
fn fixed_input(model: &ModelProto) -> [Option<usize>; 3] {
    use tract_onnx::pb::{tensor_shape_proto::dimension::Value, type_proto};
    let input = model
        .graph
        .as_ref()
        .and_then(|g| convnet::data_inputs(g).next());
    let Some(type_proto::Value::TensorType(tensor)) = input
        .and_then(|i| i.r#type.as_ref())
        .and_then(|t| t.value.as_ref())
    else {
        return [None; 3];
    };
    let dims: Vec<Option<usize>> = tensor
        .shape
        .iter()
        .flat_map(|s| &s.dim)
        .map(|d| match d.value {
            Some(Value::DimValue(v)) => usize::try_from(v).ok(),
            _ => None,
        })
        .collect();
    match dims.as_slice() {
        [b, _, h, w] => [*b, *h, *w],
        _ => [None; 3],
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
    /// Loads `path` and its sidecar, picks the engine, and probes the real scale.
    pub fn load(path: &Path, choice: EngineChoice) -> Result<OnnxUpsampler> {
        OnnxUpsampler::load_source(ModelSource::File(path.to_path_buf()), None, choice)
    }

    /// Loads the network `source`, described by `sidecar` where given (else its own sidecar),
    /// picks the engine, and probes the real scale.
    pub fn load_source(
        source: ModelSource,
        sidecar: Option<&Path>,
        choice: EngineChoice,
    ) -> Result<OnnxUpsampler> {
        let proto = source.proto()?;
        let info = source.info(sidecar)?;
        if info.scale == 0
            || info.tile == 0
            || info.batch == 0
            || !matches!(info.channel_order.as_str(), "rgb" | "bgr")
        {
            return Err(source.error(
                "invalid sidecar",
                "scale, tile and batch must be positive, channel_order rgb or bgr",
            ));
        }
        let native = match choice {
            EngineChoice::Tract => Err("engine=tract was asked for".to_string()),
            _ => ConvNet::from_model(&proto).map_err(|e| e.to_string()),
        };
        let engine = match native {
            Ok(net) => Engine::Matup { net, pool: None },
            Err(why) if choice == EngineChoice::Matup => {
                return Err(source.error("matup's executor cannot run it", why))
            }
            Err(why) => tract_engine(&source, why)?,
        };
        let upsampler = OnnxUpsampler {
            source,
            info,
            engine,
            fixed: fixed_input(&proto),
        };
        // Probe: the output must be the input times the sidecar's scale, 3 channels.
        let fixed = upsampler.fixed;
        let (ph, pw) = (fixed[1].unwrap_or(8), fixed[2].unwrap_or(8));
        let probe = vec![0.5; 3 * ph * pw];
        let out =
            upsampler.run_batch(&vec![probe; fixed[0].unwrap_or(1)], ph, pw, Padding::Zero)?;
        let got = out[0].width() / pw;
        if got != upsampler.info.scale || out[0].height() != ph * got {
            return Err(upsampler.source.error(
                "scale mismatch",
                format!(
                    "the sidecar says ×{}, the network upsamples a {pw}×{ph} probe to {}×{}",
                    upsampler.info.scale,
                    out[0].width(),
                    out[0].height()
                ),
            ));
        }
        Ok(upsampler)
    }

    /// "matup", or "tract" and why matup's executor does not run the graph.
    pub fn engine(&self) -> String {
        match &self.engine {
            Engine::Matup { .. } => "matup".into(),
            Engine::Tract { because, .. } => format!("tract ({because})"),
        }
    }

    /// Runs on `threads` threads instead of matup's thread count.
    fn set_threads(&mut self, threads: usize) -> Result<()> {
        match &mut self.engine {
            Engine::Matup { pool, .. } => {
                let built = rayon::ThreadPoolBuilder::new()
                    .num_threads(threads)
                    .thread_name(|i| format!("matup-onnx-{i}"))
                    .build()
                    .map_err(|e| self.source.error("threads", e))?;
                *pool = Some(built);
            }
            Engine::Tract { executor: e, .. } => *e = executor(threads),
        }
        Ok(())
    }

    fn plan(&self, batch: usize, h: usize, w: usize) -> Result<Plan> {
        let Engine::Tract { model, plans, .. } = &self.engine else {
            unreachable!("plans are tract's");
        };
        let key = [batch, h, w];
        if let Some(p) = plans.lock().unwrap().get(&key) {
            return Ok(p.clone());
        }
        let plan = model
            .as_ref()
            .clone()
            .with_input_fact(0, f32::fact([batch, 3, h, w]).into())
            .and_then(|m| m.into_optimized())
            .and_then(|m| m.into_runnable())
            .map_err(|e| {
                self.source.error(
                    "cannot run on [batch, 3, height, width] RGB input",
                    format!("{e:#}"),
                )
            })?;
        plans.lock().unwrap().insert(key, plan.clone());
        Ok(plan)
    }

    /// Runs the network on tiles of one shape (each 3 planes of `h × w`, values in [0, 1]);
    /// matup's executor pads its convolutions as `padding` says, tract with zeros.
    fn run_batch(
        &self,
        tiles: &[Vec<f32>],
        h: usize,
        w: usize,
        padding: Padding,
    ) -> Result<Vec<Map>> {
        let [lo, hi] = self.info.input_range;
        let [olo, ohi] = self.info.output_range;
        let bgr = self.info.channel_order == "bgr";
        // The network's channel for RGB channel `c` (the same map both ways).
        let channel = |c: usize| if bgr { 2 - c } else { c };
        let output = |v: f32| ((v - olo) / (ohi - olo)).clamp(0.0, 1.0);
        let n = h * w;
        match &self.engine {
            Engine::Matup { net, pool } => {
                let run = |tile: &Vec<f32>| {
                    let input = Features {
                        height: h,
                        width: w,
                        channels: 3,
                        data: (0..n)
                            .flat_map(|t| {
                                (0..3).map(move |c| lo + tile[channel(c) * n + t] * (hi - lo))
                            })
                            .collect(),
                    };
                    let out = net.run(input, padding);
                    Map::from_fn(out.width, out.height, 3, |c, y, x| {
                        output(out.data[(y * out.width + x) * 3 + channel(c)])
                    })
                };
                Ok(match pool {
                    Some(pool) => pool.install(|| tiles.iter().map(run).collect()),
                    None => tiles.iter().map(run).collect(),
                })
            }
            Engine::Tract { executor, .. } => {
                let mut data = Vec::with_capacity(tiles.len() * 3 * n);
                for tile in tiles {
                    for c in 0..3 {
                        let src = channel(c);
                        data.extend(
                            tile[src * n..(src + 1) * n]
                                .iter()
                                .map(|v| lo + v * (hi - lo)),
                        );
                    }
                }
                let input: Tensor =
                    tract_ndarray::Array4::from_shape_vec((tiles.len(), 3, h, w), data)
                        .map_err(|e| self.source.error("input", e))?
                        .into();
                let plan = self.plan(tiles.len(), h, w)?;
                let outputs =
                    multithread_tract_scope(executor.clone(), || plan.run(tvec!(input.into())))
                        .map_err(|e| self.source.error("inference failed", format!("{e:#}")))?;
                let view = outputs[0]
                    .to_plain_array_view::<f32>()
                    .map_err(|e| self.source.error("output", e))?;
                let shape = view.shape().to_vec();
                if shape.len() != 4 || shape[0] != tiles.len() || shape[1] != 3 {
                    return Err(self.source.error(
                        "unsupported output",
                        format!("shape {shape:?}, want [batch, 3, height, width]"),
                    ));
                }
                let (oh, ow) = (shape[2], shape[3]);
                Ok((0..tiles.len())
                    .map(|b| Map::from_fn(ow, oh, 3, |c, y, x| output(view[[b, channel(c), y, x]])))
                    .collect())
            }
        }
    }
}

/// tract's engine for the network `source`, which matup's executor does not run `because`.
fn tract_engine(source: &ModelSource, because: String) -> Result<Engine> {
    let model = source.tract_model()?;
    if model.inputs.len() != 1 || model.outputs.len() != 1 {
        return Err(source.error(
            "unsupported network",
            format!(
                "{} inputs and {} outputs (want 1 and 1)",
                model.inputs.len(),
                model.outputs.len()
            ),
        ));
    }
    Ok(Engine::Tract {
        because,
        model: Box::new(model),
        plans: Mutex::new(HashMap::new()),
        // As many as the pool matup runs on (`RAYON_NUM_THREADS`, or one per core).
        executor: executor(rayon::current_num_threads()),
    })
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

/// How tiles cover one axis of an image: cores of `core` LR texels, each read in a window of
/// `window` texels that starts `before` texels ahead of the core (the context).
#[derive(Clone, Copy, Debug)]
struct TileAxis {
    core: usize,
    before: usize,
    window: usize,
}

/// Along one axis of a tile whose core starts at LR texel `origin`, keeping `margin` texels of
/// context on each side, the output texels that land in the image (`len` LR texels,
/// ×`scale`): a contiguous run of them, where it starts in the tile's output and in the
/// image's, and each texel's feathering weight.
fn kept_texels(origin: usize, axis: TileAxis, len: usize, margin: usize, scale: usize) -> Kept {
    let mut kept = Kept {
        in_tile: 0,
        in_image: 0,
        weights: Vec::new(),
    };
    for t in 0..axis.window * scale {
        // LR coordinate of this output texel relative to the tile's core.
        let u = (t as f32 + 0.5) / scale as f32 - axis.before as f32;
        let weight = feather(u, axis.core as f32, margin as f32);
        let global = (origin * scale + t) as isize - (axis.before * scale) as isize;
        if weight > 0.0 && global >= 0 && global < (len * scale) as isize {
            if kept.weights.is_empty() {
                (kept.in_tile, kept.in_image) = (t, global as usize);
            }
            kept.weights.push(weight);
        }
    }
    kept
}

/// One tile's output texels kept along an axis: `weights.len()` of them from `in_tile` in the
/// tile's output, landing from `in_image` in the image's.
struct Kept {
    in_tile: usize,
    in_image: usize,
    weights: Vec<f32>,
}

/// The kept texels of every tile along an axis (tiles starting at `starts`), each weight
/// divided by the sum of all tiles' weights at its texel. Tiles cover the image as a grid, so
/// a texel's 2-D weights sum to (sum over rows) × (sum over columns): with both axes
/// normalised, the tiles' weighted outputs add up to the blend with no division after, and
/// no image-sized plane of weights (it was a fourth stream of stores, 4 bytes an output texel).
fn blend_weights(
    starts: &[usize],
    axis: TileAxis,
    len: usize,
    margin: usize,
    scale: usize,
) -> Vec<Kept> {
    let mut kept: Vec<Kept> = (starts.iter())
        .map(|&origin| kept_texels(origin, axis, len, margin, scale))
        .collect();
    let mut total = vec![0f32; len * scale];
    for k in &kept {
        for (sum, w) in total[k.in_image..].iter_mut().zip(&k.weights) {
            *sum += w;
        }
    }
    for k in &mut kept {
        for (w, sum) in k.weights.iter_mut().zip(&total[k.in_image..]) {
            *w /= sum.max(1e-12);
        }
    }
    kept
}

impl OnnxUpsampler {
    /// The tiling of an axis of `len` texels: even cores of at most the sidecar's `tile`, with
    /// `overlap` texels of context on each side; for a network with a fixed input size (`fixed`),
    /// windows of exactly that size, their cores as large as the overlap allows (or the whole
    /// axis, with more context, when it is shorter).
    fn tile_axis(&self, len: usize, fixed: Option<usize>) -> Result<TileAxis> {
        let o = self.info.overlap;
        match fixed {
            None => {
                // As few tiles as `tile` allows, their cores evened out: 840 texels in tiles
                // of 256 run four cores of 210, not three of 256 and a fourth shifted back
                // over the third (a band of rows of a larger output ends so, 12 % more work
                // at 2K² → 8K² in 2 bands).
                let count = len.div_ceil(self.info.tile.max(1));
                let core = len.div_ceil(count.max(1));
                Ok(TileAxis {
                    core,
                    before: o,
                    window: core + 2 * o,
                })
            }
            Some(window) if window > 2 * o => {
                let core = (window - 2 * o).min(len);
                Ok(TileAxis {
                    core,
                    before: (window - core) / 2,
                    window,
                })
            }
            Some(window) => Err(self.source.error(
                "cannot tile",
                format!(
                    "the network takes fixed {window}-texel tiles, too small for {o} texels \
                     of overlap on both sides; lower `overlap`"
                ),
            )),
        }
    }
}

impl OnnxUpsampler {
    /// Whether a `w × h` image with `border` runs as one tile with wrapping convolutions: it
    /// is tileable, fits in a tile, the network takes any size, and matup's executor runs it.
    fn runs_whole_wrapping(&self, w: usize, h: usize, border: Border) -> bool {
        border == Border::Wrap
            && w.max(h) <= self.info.tile
            && self.fixed[1..] == [None, None]
            && matches!(self.engine, Engine::Matup { .. })
    }
}

impl RgbUpsampler for OnnxUpsampler {
    fn native_scale(&self) -> Option<usize> {
        Some(self.info.scale)
    }

    /// The sidecar's overlap: the context each tile is run with.
    fn context(&self) -> usize {
        self.info.overlap
    }

    /// The sidecar's tile (or the network's fixed input less its overlap).
    fn tile(&self) -> Option<usize> {
        match self.fixed[1] {
            Some(window) => window.checked_sub(2 * self.info.overlap).filter(|&c| c > 0),
            None => Some(self.info.tile),
        }
    }

    fn upsample(&self, images: &[Map], scale: usize, border: Border) -> Result<Vec<Map>> {
        let s = self.info.scale;
        if scale != s {
            return Err(Error::Unsupported {
                plugin: format!("onnx:{}", self.source),
                what: format!("scale ×{scale} (the network upsamples ×{s})"),
            });
        }
        let mut results = Vec::with_capacity(images.len());
        // Tiles keep half their context, blended with their neighbours'.
        let margin = self.info.overlap / 2;
        // A network with a fixed batch gets exactly that many tiles per call.
        let batch = self.fixed[0].unwrap_or(self.info.batch);
        for image in images {
            let (w, h) = (image.width(), image.height());
            if self.runs_whole_wrapping(w, h, border) {
                let planes = image.data()[..3 * w * h].to_vec();
                results.extend(self.run_batch(&[planes], h, w, Padding::Wrap)?);
                continue;
            }
            let rows = self.tile_axis(h, self.fixed[1])?;
            let columns = self.tile_axis(w, self.fixed[2])?;
            let row_starts = tile_starts(h, rows.core);
            let column_starts = tile_starts(w, columns.core);
            let kept_rows = blend_weights(&row_starts, rows, h, margin, s);
            let kept_columns = blend_weights(&column_starts, columns, w, margin, s);
            // Tiles by (index of their row, index of their column).
            let grid: Vec<(usize, usize)> = (0..row_starts.len())
                .flat_map(|i| (0..column_starts.len()).map(move |j| (i, j)))
                .collect();
            let (out_w, out_h) = (w * s, h * s);
            let mut acc = vec![0f32; 3 * out_w * out_h];
            for group in grid.chunks(batch) {
                let mut tiles: Vec<Vec<f32>> = group
                    .iter()
                    .map(|&(i, j)| {
                        let (y0, x0) = (row_starts[i], column_starts[j]);
                        let mut t = Vec::with_capacity(3 * rows.window * columns.window);
                        for c in 0..3 {
                            for ty in 0..rows.window {
                                let y = border
                                    .index(y0 as isize + ty as isize - rows.before as isize, h);
                                for tx in 0..columns.window {
                                    let x = border.index(
                                        x0 as isize + tx as isize - columns.before as isize,
                                        w,
                                    );
                                    t.push(image.get(c, y, x));
                                }
                            }
                        }
                        t
                    })
                    .collect();
                if self.fixed[0].is_some() {
                    // Fill the fixed batch with copies; their outputs are not used.
                    let last = tiles.last().expect("chunks are not empty").clone();
                    tiles.resize(batch, last);
                }
                let outputs = self.run_batch(&tiles, rows.window, columns.window, Padding::Zero)?;
                // One channel a thread, row by row: each tile's kept row is one contiguous
                // run of its plane. Writing the three planes and a weight plane at once (each
                // 256 MB apart at 8K²) cost 7.5× the time per texel at 8K² that it did at 4K²
                // (perf), 14 s of 2K² → 8K²'s 174.
                acc.par_chunks_mut((out_w * out_h).max(1))
                    .enumerate()
                    .for_each(|(c, plane)| {
                        for (&(i, j), out) in group.iter().zip(&outputs) {
                            let (rows, columns) = (&kept_rows[i], &kept_columns[j]);
                            let tile = out.plane(c);
                            for (dy, &wy) in rows.weights.iter().enumerate() {
                                let from = (rows.in_tile + dy) * out.width() + columns.in_tile;
                                let to = (rows.in_image + dy) * out_w + columns.in_image;
                                let n = columns.weights.len();
                                let (src, dst) = (&tile[from..from + n], &mut plane[to..to + n]);
                                for ((d, &v), &wx) in dst.iter_mut().zip(src).zip(&columns.weights)
                                {
                                    *d += wy * wx * v;
                                }
                            }
                        }
                    });
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
        help: "threads for the network (default: matup's thread count)",
    },
    PluginOption {
        key: "engine",
        default: "auto",
        help: "what runs the network: matup (its own executor), tract, or auto (matup where the graph allows)",
    },
    PluginOption {
        key: "sidecar",
        default: "",
        help: "the model's sidecar TOML (default: NAME.toml beside NAME.onnx)",
    },
];

/// `onnx:MODEL[,tile=N,overlap=N,batch=N,threads=N,engine=E,sidecar=PATH]`, MODEL a path to a `.onnx` file or a name in the
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
    let values = parse_options("onnx", Some(options), OPTIONS)?;
    let choice = match values["engine"].as_str() {
        "auto" => EngineChoice::Auto,
        "matup" => EngineChoice::Matup,
        "tract" => EngineChoice::Tract,
        other => {
            return Err(Error::Plugin {
                plugin: "onnx".into(),
                message: format!("engine '{other}': known engines are auto, matup, tract"),
            })
        }
    };
    let sidecar = match values["sidecar"].as_str() {
        "" => None,
        given => Some(PathBuf::from(given)),
    };
    let mut upsampler = OnnxUpsampler::load_source(resolve(model)?, sidecar.as_deref(), choice)?;
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
        upsampler.set_threads(option_value("onnx", &values, "threads")?)?;
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
        description: "a pre-trained SR network: onnx:PATH.onnx or onnx:NAME from the model folders (CPU)",
        options: OPTIONS,
        create,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn blend_weights_sum_to_one_at_every_output_texel() {
        // 100 LR texels in cores of 24 (the last shifted back to the edge) with 22 of context,
        // half of it kept and feathered; one tile covering all; no context.
        for (len, core, overlap, scale) in [(100, 24, 22, 4), (100, 100, 22, 2), (50, 16, 0, 4)] {
            let axis = TileAxis {
                core,
                before: overlap,
                window: core + 2 * overlap,
            };
            let starts = tile_starts(len, core);
            let kept = blend_weights(&starts, axis, len, overlap / 2, scale);
            let mut sums = vec![0f32; len * scale];
            for k in &kept {
                assert!(k.in_tile + k.weights.len() <= axis.window * scale);
                for (s, w) in sums[k.in_image..].iter_mut().zip(&k.weights) {
                    *s += w;
                }
            }
            let worst = sums.iter().map(|s| (s - 1.0).abs()).fold(0.0, f32::max);
            assert!(worst < 1e-6, "{len}, {core}, {overlap}: off by {worst}");
        }
    }
}
