//! `onnx`: a pre-trained RGB super-resolution network from an ONNX file, run on the CPU.
//! Facts the file does not state (scale, value range, channel order, tiling, licence) come
//! from a sidecar `NAME.toml` next to `NAME.onnx`; the scale is checked against the network's
//! real output on a probe input.
//!
//! Four engines run the graph: matup's own executor for convolutional SR graphs (`convnet`,
//! several times faster on CPUs), used whenever the graph's operators allow, and tract for
//! every other graph (the optimised tract plan is built once per input shape and reused); on
//! a GPU adapter (`device=gpu…`, or `auto` where one is), the executor's graph as compute
//! shaders through wgpu (`gpu_graph`); on CUDA (`device=cuda`), the executor's graph as candle
//! operations (`candle_graph`). The GPU engines run many tiles a call.
//!
//! Images are processed in tiles ([`crate::tiled`]) read with `overlap` texels of context on
//! every side, several tiles per call, and blended where their kept regions overlap. A
//! tileable image that fits in one tile runs whole on matup's executor, its convolutions
//! wrapping around, which needs no context at all.
//!
//! Rooms: `upsampler` loads a network and runs it on one of the engines; `plugin` is the
//! `onnx` upsampler's options and the process's cache of loaded networks; `source` finds a
//! model and reads its sidecar; `convnet` (with `conv`, `winograd` and `nhwc`, its
//! operations on texel-major feature maps) is matup's executor; `gpu_graph` (with
//! `gpu_kernels.wgsl`) is its graph on wgpu; `candle_graph` is its graph as candle operations.

mod candle_graph;
mod conv;
mod convnet;
mod gpu_graph;
mod nhwc;
mod plugin;
mod source;
mod upsampler;
mod winograd;

pub use candle_graph::{
    depth_to_space, in_channel_order, per_texel, run_steps, unit_rgb, Precision, TensorNet,
};
pub use convnet::{Graph, Op, RawConv, Step, Unsupported};
pub use gpu_graph::{GpuError, GpuNet};
pub use nhwc::{Arith, Padding, PerTexel};
pub use source::{
    available_models, model_dirs, read_sidecar, read_sidecar_file, resolve, BuiltIn, ModelInfo,
    ModelSource, BUILT_IN,
};
pub use tract_onnx::pb::ModelProto;
pub use upsampler::{read_graph, EngineChoice, OnnxUpsampler};
