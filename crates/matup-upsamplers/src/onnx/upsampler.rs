//! A loaded network ([`OnnxUpsampler`]) and the engines that run it: matup's executor, tract,
//! or the executor's graph as candle operations on a device.

use std::collections::HashMap;
use std::path::Path;
use std::sync::{Arc, Mutex};

use matup_core::resample::Border;
use matup_core::upsample::{RgbUpsampler, Unwatched, Watch};
use matup_core::{Error, Map, Result};
use tract_linalg::multithread::{multithread_tract_scope, Executor};
use tract_onnx::pb::ModelProto;
use tract_onnx::prelude::*;

use super::candle_graph::{unit_rgb, Precision, TensorNet};
use super::convnet::{self, ConvNet, Graph};
use super::gpu_graph::{GpuError, GpuNet};
use super::nhwc::{Features, Padding};
use super::source::{ModelInfo, ModelSource};
use crate::tiled::{
    by_size, upsample_tiled, upsample_tiled_on_device, PieceCount, TileAxis, Tiling,
};

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

/// Which engine runs a network: `auto` picks matup's executor where the graph allows;
/// `Candle` runs the executor's graph as candle operations on a device (`cpu`, `cuda`,
/// `cuda:N`) at a precision; `Gpu` runs it on the wgpu adapter `index` (`matup list`), or
/// where it cannot and `or_cpu`, as `auto` does on the CPU. `why` says why it runs there.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum EngineChoice {
    Auto,
    Matup,
    Tract,
    Candle(String, Precision),
    Gpu {
        index: usize,
        or_cpu: bool,
        why: String,
        /// Maps in half precision (the adapter's `shader-f16`).
        half: bool,
    },
}

/// What runs the network.
enum Engine {
    /// matup's executor ([`convnet`]), on `pool` (matup's own thread pool when `None`).
    Matup {
        net: ConvNet,
        pool: Option<rayon::ThreadPool>,
    },
    /// The executor's graph as candle operations on a device, and how many tiles of the
    /// sidecar's size fit in its memory.
    Candle { net: TensorNet, free: usize },
    /// The executor's graph as compute shaders on a wgpu adapter.
    Gpu(GpuNet),
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
    /// Whether `batch=N` was given (else a GPU runs as many tiles a call as fit).
    pub(super) batch_given: bool,
    /// Why the network runs where it does (`device=auto` found no hardware adapter, …).
    pub(super) why: String,
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
        let cpu = |choice: &EngineChoice| match ConvNet::from_model(&proto) {
            Ok(net) => Ok(Engine::Matup { net, pool: None }),
            Err(why) if *choice == EngineChoice::Matup => {
                Err(source.error("matup's executor cannot run it", why))
            }
            Err(why) => tract_engine(&source, why.to_string()),
        };
        let mut why = String::new();
        let engine = match &choice {
            EngineChoice::Candle(device, precision) => {
                candle_engine(&source, &proto, device, *precision)?
            }
            EngineChoice::Tract => tract_engine(&source, "engine=tract was asked for".into())?,
            EngineChoice::Auto | EngineChoice::Matup => cpu(&choice)?,
            EngineChoice::Gpu {
                index,
                or_cpu,
                why: because,
                half,
            } => match gpu_engine(&source, &proto, *index, *half) {
                Ok(engine) => {
                    why = because.clone();
                    engine
                }
                Err(e) if *or_cpu => {
                    why = format!("{because}, but {e}; the CPU runs it");
                    cpu(&EngineChoice::Auto)?
                }
                Err(e) => return Err(e),
            },
        };
        let upsampler = OnnxUpsampler {
            source,
            info,
            engine,
            fixed: fixed_input(&proto),
            batch_given: false,
            why,
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

    /// "matup", "candle on DEVICE", "wgpu on ADAPTER", or "tract" and why matup's executor
    /// does not run the graph.
    pub fn engine(&self) -> String {
        match &self.engine {
            Engine::Matup { .. } => "matup".into(),
            Engine::Candle { net, .. } => format!("candle on {}", device_name(net.device())),
            Engine::Gpu(net) => {
                let s = &net.gpu().summary;
                let half = if net.half() { ", f16" } else { "" };
                format!(
                    "wgpu on {} ({}, {}{half})",
                    s.name,
                    s.backend,
                    s.kind.name()
                )
            }
            Engine::Tract { because, .. } => format!("tract ({because})"),
        }
    }

    /// Where the network runs and why: `wgpu on llvmpipe (…) (Vulkan, software adapter):
    /// device=gpu:llvmpipe asked for it`, `matup on the CPU: device=auto found no hardware GPU
    /// adapter`.
    pub fn placement(&self) -> String {
        let engine = match &self.engine {
            Engine::Matup { .. } => "matup on the CPU".to_string(),
            _ => self.engine(),
        };
        match self.why.as_str() {
            "" => engine,
            why => format!("{engine}: {why}"),
        }
    }

    /// Runs on `threads` threads instead of matup's thread count.
    pub(super) fn set_threads(&mut self, threads: usize) -> Result<()> {
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
            // The device computes; the host's threads only cut and blend tiles.
            Engine::Candle { .. } | Engine::Gpu(_) => {}
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

    /// Images of 3 planes each, values in [0, 1], as one [batch, 3, h, w] array in the
    /// network's range and channel order.
    fn network_input(&self, images: &[&[f32]]) -> Vec<f32> {
        let [lo, hi] = self.info.input_range;
        let bgr = self.info.channel_order == "bgr";
        let mut data = Vec::with_capacity(images.iter().map(|i| i.len()).sum());
        for image in images {
            let n = image.len() / 3;
            for c in 0..3 {
                let src = if bgr { 2 - c } else { c };
                data.extend(
                    image[src * n..(src + 1) * n]
                        .iter()
                        .map(|v| lo + v * (hi - lo)),
                );
            }
        }
        data
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
        let network_input = |tiles: &[Vec<f32>]| {
            let planes: Vec<&[f32]> = tiles.iter().map(|t| &t[..]).collect();
            self.network_input(&planes)
        };
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
            Engine::Gpu(net) => {
                let out = self.run_on_gpu(net, tiles, h, w, padding)?;
                let (oh, ow) = (h * net.scale(), w * net.scale());
                let plane = oh * ow;
                Ok((out.chunks(3 * plane))
                    .map(|planes| {
                        Map::from_fn(ow, oh, 3, |c, y, x| {
                            output(planes[channel(c) * plane + y * ow + x])
                        })
                    })
                    .collect())
            }
            Engine::Candle { net, .. } => {
                let out = self.run_on_device(net, tiles, h, w, padding)?;
                let failed = |e: candle_core::Error| self.source.error("inference failed", e);
                let (_, _, oh, ow) = out.dims4().map_err(failed)?;
                let data = (out.flatten_all().and_then(|t| t.to_vec1::<f32>())).map_err(failed)?;
                Ok((data.chunks(3 * oh * ow))
                    .map(|planes| Map::from_planar(ow, oh, 3, planes.to_vec()))
                    .collect())
            }
            Engine::Tract { executor, .. } => {
                let input: Tensor = tract_ndarray::Array4::from_shape_vec(
                    (tiles.len(), 3, h, w),
                    network_input(tiles),
                )
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

impl OnnxUpsampler {
    /// The network's output planes (its range and channel order) for `tiles` on a wgpu
    /// adapter. Where its memory does not hold the call, the tiles run in halves, down to one
    /// a call; past that the error says so.
    fn run_on_gpu(
        &self,
        net: &GpuNet,
        tiles: &[Vec<f32>],
        h: usize,
        w: usize,
        padding: Padding,
    ) -> Result<Vec<f32>> {
        let planes: Vec<&[f32]> = tiles.iter().map(|t| &t[..]).collect();
        match net.run(&self.network_input(&planes), tiles.len(), h, w, padding) {
            Ok(out) => Ok(out),
            Err(GpuError::OutOfMemory(_)) if tiles.len() > 1 => {
                let (first, second) = tiles.split_at(tiles.len() / 2);
                let mut out = self.run_on_gpu(net, first, h, w, padding)?;
                out.extend(self.run_on_gpu(net, second, h, w, padding)?);
                Ok(out)
            }
            Err(e @ GpuError::OutOfMemory(_)) => Err(self.source.error(
                "inference failed",
                format!(
                    "{e}; one {w}×{h} tile does not fit: lower the onnx upsampler's tile \
                     (onnx:NAME,tile=N) or run on the CPU (--device cpu)"
                ),
            )),
            Err(e) => Err(self.source.error("inference failed", e)),
        }
    }

    /// [`OnnxUpsampler::run_batch`] on the candle engine's device, the outputs left there:
    /// `[batch, 3, h·scale, w·scale]`, values in [0, 1].
    fn run_on_device(
        &self,
        net: &TensorNet,
        tiles: &[Vec<f32>],
        h: usize,
        w: usize,
        padding: Padding,
    ) -> Result<candle_core::Tensor> {
        let failed = |e: candle_core::Error| self.source.error("inference failed", e);
        let planes: Vec<&[f32]> = tiles.iter().map(|t| &t[..]).collect();
        let input = candle_core::Tensor::from_vec(
            self.network_input(&planes),
            (tiles.len(), 3, h, w),
            net.device(),
        )
        .map_err(failed)?;
        let out = net.run(input, padding).map_err(failed)?;
        let (b, c, _, _) = out.dims4().map_err(failed)?;
        if b != tiles.len() || c != 3 {
            return Err(self.source.error(
                "unsupported output",
                format!("shape {:?}, want [batch, 3, height, width]", out.dims()),
            ));
        }
        unit_rgb(&out, &self.info).map_err(failed)
    }

    /// The images `same` of `images` (all of one size), run whole, as the calls that run
    /// them: each call's images as their three planes.
    fn whole_calls<'a>(
        &'a self,
        images: &'a [Map],
        same: &'a [usize],
    ) -> impl Iterator<Item = Vec<Vec<f32>>> + 'a {
        let (w, h) = (images[same[0]].width(), images[same[0]].height());
        same.chunks(self.tiles_per_call(h, w)).map(move |call| {
            (call.iter())
                .map(|&k| images[k].data()[..3 * w * h].to_vec())
                .collect()
        })
    }

    /// Refuses any scale but the network's.
    fn check_scale(&self, scale: usize) -> Result<()> {
        let s = self.info.scale;
        if scale != s {
            return Err(Error::Unsupported {
                plugin: format!("onnx:{}", self.source),
                what: format!("scale ×{scale} (the network upsamples ×{s})"),
            });
        }
        Ok(())
    }
}

/// `cpu`, `cuda:N`: how `--device` names a candle device.
fn device_name(device: &candle_core::Device) -> String {
    match device.location() {
        candle_core::DeviceLocation::Cuda { gpu_id } => format!("cuda:{gpu_id}"),
        candle_core::DeviceLocation::Cpu => "cpu".into(),
        other => format!("{other:?}"),
    }
}

/// Bytes of memory free on `device` for the network's tiles: on a GPU, what its driver reports
/// free now; on the CPU, the 1 GiB that a host batch of tiles is allowed.
fn free_memory(device: &candle_core::Device) -> candle_core::Result<usize> {
    Ok(matup_core::device_maps::free_memory(device)?.map_or(1 << 30, |free| free as usize))
}

/// The candle engine for `proto` on `device`: the executor's graph, its weights uploaded once,
/// and the device's free memory, which sets how many tiles a call runs.
fn candle_engine(
    source: &ModelSource,
    proto: &ModelProto,
    device: &str,
    precision: Precision,
) -> Result<Engine> {
    let graph =
        Graph::from_model(proto).map_err(|e| source.error("matup's executor cannot run it", e))?;
    if matup_core::device::cuda_ordinal(device)?.is_some() {
        keep_f32_convolutions(precision);
    }
    let device = matup_core::device::parse_device(device)?;
    let on = format!("on {}", device_name(&device));
    let failed = |e: candle_core::Error| source.error(&on, e);
    let net = TensorNet::new(graph, &device, precision).map_err(failed)?;
    let free = free_memory(&device).map_err(failed)?;
    Ok(Engine::Candle { net, free })
}

/// cuDNN (the `cudnn` feature) runs f32 convolutions with TF32 inputs on Ampere and later
/// GPUs unless told not to: on an H200 that put a few texels of Metal053C's maps 5 levels off
/// the CPU's, against 1 with `NVIDIA_TF32_OVERRIDE=0` (docs/experiments/
/// 2026-11-26-gpu-time-and-precision.md). NVIDIA's libraries read that variable when they
/// start, so it is set before the device is opened, unless `precision=tf32` asks for TF32 or
/// the user set it.
fn keep_f32_convolutions(precision: Precision) {
    if precision != Precision::Tf32 && std::env::var_os("NVIDIA_TF32_OVERRIDE").is_none() {
        std::env::set_var("NVIDIA_TF32_OVERRIDE", "0");
    }
}

/// The GPU engine for `proto` on wgpu adapter `index`: the executor's graph, its weights
/// uploaded once; refused, naming the operation, where its kernels do not cover the graph.
fn gpu_engine(
    source: &ModelSource,
    proto: &ModelProto,
    index: usize,
    half: bool,
) -> Result<Engine> {
    let graph =
        Graph::from_model(proto).map_err(|e| source.error("the GPU engine cannot run it", e))?;
    let gpu = crate::gpu::open(index)?;
    let net = GpuNet::new(graph, gpu, half).map_err(|e| source.error("on the GPU", e))?;
    Ok(Engine::Gpu(net))
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

impl OnnxUpsampler {
    /// The tiling of an axis of `len` texels: even cores of at most the sidecar's `tile`, with
    /// `overlap` texels of context on each side ([`TileAxis::even`]); for a network with a fixed input size (`fixed`),
    /// windows of exactly that size, their cores as large as the overlap allows (or the whole
    /// axis, with more context, when it is shorter).
    fn tile_axis(&self, len: usize, fixed: Option<usize>) -> Result<TileAxis> {
        let o = self.info.overlap;
        match fixed {
            None => Ok(TileAxis::even(len, self.info.tile, o)),
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
            && matches!(
                self.engine,
                Engine::Matup { .. } | Engine::Candle { .. } | Engine::Gpu(_)
            )
    }
}

impl RgbUpsampler for OnnxUpsampler {
    fn native_scale(&self) -> Option<usize> {
        Some(self.info.scale)
    }

    /// The candle engine (a GPU's): the self-ensemble's passes fill its batch together. So
    /// on candle's CPU device too, which tests the GPU's path where there is no GPU.
    fn batches_images(&self) -> bool {
        matches!(self.engine, Engine::Candle { .. } | Engine::Gpu(_))
    }

    fn placement(&self) -> Option<String> {
        Some(OnnxUpsampler::placement(self))
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

    /// Images of one size share calls: their tiles (or, run whole, the images) are queued
    /// together and run as many a call as the engine takes, so the self-ensemble's passes and
    /// a material's renders fill a GPU's batch.
    fn upsample(&self, images: &[Map], scale: usize, border: Border) -> Result<Vec<Map>> {
        self.upsample_watched(images, scale, border, &Unwatched)
    }

    /// [`RgbUpsampler::upsample`], `watch` told after each call of the network.
    fn upsample_watched(
        &self,
        images: &[Map],
        scale: usize,
        border: Border,
        watch: &dyn Watch,
    ) -> Result<Vec<Map>> {
        if let Engine::Candle { .. } = &self.engine {
            let outputs = self.upsample_on_device_watched(images, scale, border, watch)?;
            return (outputs.iter())
                .map(|t| {
                    matup_core::device_maps::download(t)
                        .map_err(|e| self.source.error("inference failed", e))
                })
                .collect();
        }
        self.check_scale(scale)?;
        by_size(images, |same| {
            let (w, h) = (images[same[0]].width(), images[same[0]].height());
            if self.runs_whole_wrapping(w, h, border) {
                let mut count = PieceCount::new(watch, same.len());
                let mut outputs = Vec::with_capacity(same.len());
                for planes in self.whole_calls(images, same) {
                    outputs.extend(self.run_batch(&planes, h, w, Padding::Wrap)?);
                    count.add(planes.len())?;
                }
                Ok(outputs)
            } else {
                let same_images: Vec<&Map> = same.iter().map(|&k| &images[k]).collect();
                let tiling = self.tiling(w, h, same.len())?;
                let batch = self.tiles_per_call(tiling.rows.window, tiling.columns.window);
                upsample_tiled(
                    &same_images,
                    border,
                    tiling,
                    batch,
                    self.fixed[0].is_some(),
                    &mut |tiles, [h, w]| self.run_batch(tiles, h, w, Padding::Zero),
                    watch,
                )
            }
        })
    }

    /// The candle engine's device.
    fn device(&self) -> Option<candle_core::Device> {
        match &self.engine {
            Engine::Candle { net, .. } => Some(net.device().clone()),
            _ => None,
        }
    }

    /// [`RgbUpsampler::upsample`] on the candle engine, each output blended on the device and
    /// left there.
    fn upsample_on_device(
        &self,
        images: &[Map],
        scale: usize,
        border: Border,
    ) -> Result<Vec<candle_core::Tensor>> {
        self.upsample_on_device_watched(images, scale, border, &Unwatched)
    }

    /// [`RgbUpsampler::upsample_on_device`], `watch` told after each call of the network.
    fn upsample_on_device_watched(
        &self,
        images: &[Map],
        scale: usize,
        border: Border,
        watch: &dyn Watch,
    ) -> Result<Vec<candle_core::Tensor>> {
        let Engine::Candle { net, .. } = &self.engine else {
            return Err(self.source.error(
                "keeps no outputs on a device",
                "only the candle engine (engine=candle or a GPU) does",
            ));
        };
        self.check_scale(scale)?;
        let failed = |e: candle_core::Error| self.source.error("inference failed", e);
        by_size(images, |same| {
            let (w, h) = (images[same[0]].width(), images[same[0]].height());
            if self.runs_whole_wrapping(w, h, border) {
                let mut count = PieceCount::new(watch, same.len());
                let mut outputs = Vec::with_capacity(same.len());
                for planes in self.whole_calls(images, same) {
                    let out = self.run_on_device(net, &planes, h, w, Padding::Wrap)?;
                    for b in 0..planes.len() {
                        outputs.push(out.get(b).map_err(failed)?);
                    }
                    count.add(planes.len())?;
                }
                Ok(outputs)
            } else {
                let same_images: Vec<&Map> = same.iter().map(|&k| &images[k]).collect();
                self.upsample_tiled_on_device(net, &same_images, border, watch)
            }
        })
    }
}

impl OnnxUpsampler {
    /// The [`Tiling`] of `images` images of `w × h`.
    fn tiling(&self, w: usize, h: usize, images: usize) -> Result<Tiling> {
        let rows = self.tile_axis(h, self.fixed[1])?;
        let columns = self.tile_axis(w, self.fixed[2])?;
        let (s, o) = (self.info.scale, self.info.overlap);
        Ok(Tiling::new([w, h], images, [rows, columns], o, s))
    }

    /// [`upsample_tiled_on_device`] on the candle engine: the images uploaded in the
    /// network's range and channel order, each call's output mapped to [0, 1].
    fn upsample_tiled_on_device(
        &self,
        net: &TensorNet,
        images: &[&Map],
        border: Border,
        watch: &dyn Watch,
    ) -> Result<Vec<candle_core::Tensor>> {
        let failed = |e: candle_core::Error| self.source.error("inference failed", e);
        let (w, h) = (images[0].width(), images[0].height());
        let tiling = self.tiling(w, h, images.len())?;
        let planes: Vec<&[f32]> = images.iter().map(|m| &m.data()[..3 * w * h]).collect();
        let uploaded = candle_core::Tensor::from_vec(
            self.network_input(&planes),
            (images.len(), 3, h, w),
            net.device(),
        )
        .map_err(failed)?;
        let batch = self.tiles_per_call(tiling.rows.window, tiling.columns.window);
        let mut count = PieceCount::new(watch, tiling.grid.len());
        // Where the watch stops the call: its error, carried past candle's.
        let mut stopped = None;
        let outputs = upsample_tiled_on_device(
            &uploaded,
            border,
            tiling,
            batch,
            self.fixed[0],
            &mut |windows| {
                let tiles = windows.dim(0)?;
                let outputs = unit_rgb(&net.run(windows, Padding::Zero)?, &self.info)?;
                if let Err(e) = count.add(tiles) {
                    stopped = Some(e);
                    return Err(candle_core::Error::Msg("stopped".into()));
                }
                Ok(outputs)
            },
        );
        outputs.map_err(|e| stopped.unwrap_or_else(|| failed(e)))
    }
}

/// Bytes of maps one call on a wgpu adapter holds at its peak (wgpu does not say how much of
/// the adapter's memory is free): 1 GiB, 40 of SPAN's 256² tiles.
const GPU_CALL_BUDGET: u64 = 1 << 30;

impl OnnxUpsampler {
    /// How many `h × w` inputs one call runs: the network's fixed batch, or as many as the
    /// GPU's memory holds, or the sidecar's batch.
    fn tiles_per_call(&self, h: usize, w: usize) -> usize {
        match (self.fixed[0], &self.engine) {
            (Some(fixed), _) => fixed,
            (None, Engine::Candle { net, free }) if !self.batch_given => {
                let cost = net.tile_cost(h, w);
                // The output's three copies (mapped to [0, 1], channels in order, weighted).
                let out = 3 * 3 * h * w * self.info.scale.pow(2) * 4;
                // Half the GPU's free memory (the rest for others and the row being blended),
                // and every tensor under 2³¹ elements (candle's CUDA kernels index in 32 bits).
                let in_memory = free / 2 / (cost.bytes + out).max(1);
                let indexable = (i32::MAX as usize) / cost.largest.max(1);
                in_memory.min(indexable).max(1)
            }
            (None, Engine::Gpu(net)) if !self.batch_given => {
                net.tiles_per_call(h, w, GPU_CALL_BUDGET)
            }
            (None, _) => self.info.batch,
        }
    }
}
