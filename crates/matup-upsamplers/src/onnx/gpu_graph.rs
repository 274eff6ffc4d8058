//! The executor's graph ([`Graph`]) on a GPU through wgpu: the same steps as matup's CPU
//! executor, each a compute shader written for it (`gpu_kernels.wgsl`) on planar
//! `[batch, channels, height, width]` maps (f32, or f16 on request). Written here rather
//! than taken from a tensor crate on wgpu (burn's): a network of this graph needs seven
//! kernels, and the study (docs/experiments/2026-12-02-gpu-engine.md) weighs the two.
//!
//! The weights are uploaded once, when the network is loaded; a call uploads a batch of tiles,
//! records every step in one command buffer, and reads the output back. The maps' buffers are
//! kept between calls and reused, so tiles of one size allocate nothing after the first call.

use std::sync::{Arc, Mutex};

use wgpu::util::DeviceExt;

use super::convnet::{last_uses, Graph, Op, RawConv, Step};
use super::nhwc::{Arith, Padding, PerTexel};
use crate::gpu::Gpu;

/// Why the engine does not run a graph, or a call failed.
#[derive(Debug)]
pub enum GpuError {
    /// An operation of the graph the kernels do not cover, named.
    Unsupported(String),
    /// The device ran out of memory for a call: fewer tiles a call, or smaller tiles, may fit.
    OutOfMemory(String),
    /// The device was lost or a call failed otherwise.
    Failed(String),
}

impl std::fmt::Display for GpuError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            GpuError::Unsupported(why) => write!(f, "the GPU engine cannot run it: {why}"),
            GpuError::OutOfMemory(why) => write!(f, "out of GPU memory: {why}"),
            GpuError::Failed(why) => f.write_str(why),
        }
    }
}

/// The largest convolution kernel side the `conv` kernel stages (its `MAX_K`).
const MAX_KERNEL: usize = 5;

/// A convolution's weights, then its bias, on the device.
struct DeviceConv {
    weights: wgpu::Buffer,
    shape: [usize; 4],
}

/// The kernels, one pipeline each, sharing one layout.
struct Kernels {
    layout: wgpu::BindGroupLayout,
    conv: wgpu::ComputePipeline,
    per_texel: wgpu::ComputePipeline,
    arithmetic: wgpu::ComputePipeline,
    depth_to_space: wgpu::ComputePipeline,
    resize_nearest: wgpu::ComputePipeline,
    copy_channels: wgpu::ComputePipeline,
}

/// A network on a wgpu adapter.
pub struct GpuNet {
    gpu: Arc<Gpu>,
    kernels: Kernels,
    steps: Vec<Step<Option<DeviceConv>>>,
    /// Per step, its per-texel chain as the kernels read it.
    chains: Vec<wgpu::Buffer>,
    /// Per value slot: channels, and size as a multiple of the input's.
    shapes: Vec<(usize, usize)>,
    last_use: Vec<usize>,
    output: usize,
    /// Bound where a kernel reads nothing.
    unused: wgpu::Buffer,
    /// Buffers of maps freed by earlier calls, for the next ones.
    pool: Mutex<Vec<wgpu::Buffer>>,
    /// Whether the maps are held in half precision (f16; sums stay f32).
    half: bool,
}

/// The uniform every kernel reads (`Params` in the shader).
#[repr(C)]
#[derive(Clone, Copy, Default, bytemuck::Pod, bytemuck::Zeroable)]
struct Params {
    width: u32,
    height: u32,
    channels_in: u32,
    channels_out: u32,
    kernel_h: u32,
    kernel_w: u32,
    mode: u32,
    groups: u32,
    count: u32,
    offset: u32,
    pad: [u32; 2],
}

/// Per value slot of `graph`: its channels and its size as a multiple of the input's.
pub fn value_shapes(graph: &Graph) -> Vec<(usize, usize)> {
    let mut shapes = vec![(0, 1); graph.values];
    shapes[0] = (3, 1);
    for step in &graph.steps {
        let (c, s) = shapes[step.inputs[0]];
        shapes[step.output] = match &step.op {
            Op::Conv(conv, _) => (conv.shape[0], s),
            Op::PerTexel(_) | Op::Arith(_) => (c, s),
            Op::Concat => (step.inputs.iter().map(|&v| shapes[v].0).sum(), s),
            Op::DepthToSpace { block, .. } => (c / (block * block), s * block),
            Op::ResizeNearest(f) => (c, s * f),
        };
    }
    shapes
}

/// A per-texel chain as the kernels read it (the shader's header says how).
fn chain_words(chain: &[PerTexel]) -> Vec<u32> {
    let mut words = vec![chain.len() as u32];
    let values = |words: &mut Vec<u32>, v: &[f32]| {
        words.push(v.len() as u32);
        words.extend(v.iter().map(|x| x.to_bits()));
    };
    for op in chain {
        match op {
            PerTexel::Sigmoid => words.push(0),
            PerTexel::Silu => words.push(1),
            PerTexel::Relu => words.push(2),
            PerTexel::LeakyRelu(a) => words.extend([3, a.to_bits()]),
            // Infinite bounds as the largest finite ones: shaders may assume no infinities.
            PerTexel::Clip(lo, hi) => {
                words.extend([4, lo.max(f32::MIN).to_bits(), hi.min(f32::MAX).to_bits()])
            }
            PerTexel::PRelu(slopes) => {
                words.push(5);
                values(&mut words, slopes);
            }
            PerTexel::Constant {
                arith,
                constant,
                constant_first,
            } => {
                words.push(6 + 2 * arith_code(*arith) + u32::from(*constant_first));
                values(&mut words, constant);
            }
        }
    }
    words
}

fn arith_code(arith: Arith) -> u32 {
    match arith {
        Arith::Add => 0,
        Arith::Sub => 1,
        Arith::Mul => 2,
        Arith::Div => 3,
    }
}

fn storage(binding: u32, read_only: bool) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility: wgpu::ShaderStages::COMPUTE,
        ty: wgpu::BindingType::Buffer {
            ty: wgpu::BufferBindingType::Storage { read_only },
            has_dynamic_offset: false,
            min_binding_size: None,
        },
        count: None,
    }
}

impl Kernels {
    /// The kernels, their maps f16 where `half`.
    fn new(device: &wgpu::Device, half: bool) -> Kernels {
        let source = include_str!("gpu_kernels.wgsl");
        let source = match half {
            true => source.replacen("alias Value = f32;", "enable f16;\nalias Value = f16;", 1),
            false => source.to_string(),
        };
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("matup kernels"),
            source: wgpu::ShaderSource::Wgsl(source.into()),
        });
        let uniform = wgpu::BindGroupLayoutEntry {
            binding: 0,
            visibility: wgpu::ShaderStages::COMPUTE,
            ty: wgpu::BindingType::Buffer {
                ty: wgpu::BufferBindingType::Uniform,
                has_dynamic_offset: false,
                min_binding_size: None,
            },
            count: None,
        };
        let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("matup kernels"),
            entries: &[
                uniform,
                storage(1, true),
                storage(2, true),
                storage(3, true),
                storage(4, true),
                storage(5, false),
            ],
        });
        let pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("matup kernels"),
            bind_group_layouts: &[Some(&layout)],
            immediate_size: 0,
        });
        let pipeline = |entry: &str| {
            device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                label: Some(entry),
                layout: Some(&pipeline_layout),
                module: &module,
                entry_point: Some(entry),
                compilation_options: Default::default(),
                cache: None,
            })
        };
        Kernels {
            conv: pipeline("conv"),
            per_texel: pipeline("per_texel"),
            arithmetic: pipeline("arithmetic"),
            depth_to_space: pipeline("depth_to_space"),
            resize_nearest: pipeline("resize_nearest"),
            copy_channels: pipeline("copy_channels"),
            layout,
        }
    }
}

impl GpuNet {
    /// `graph` on `gpu`, its weights uploaded, its maps held in half precision where `half`
    /// (the adapter must have `shader-f16`); refused, naming the operation, where a kernel
    /// does not cover it.
    pub fn new(graph: Graph, gpu: Arc<Gpu>, half: bool) -> Result<GpuNet, GpuError> {
        if half && !gpu.summary.shader_f16 {
            return Err(GpuError::Unsupported(format!(
                "half precision: {} has no shader-f16",
                gpu.summary.name
            )));
        }
        for step in &graph.steps {
            if let Op::Conv(conv, _) = &step.op {
                let [_, _, kh, kw] = conv.shape;
                if kh.max(kw) > MAX_KERNEL {
                    return Err(GpuError::Unsupported(format!(
                        "Conv with a {kh}×{kw} kernel (the GPU engine's convolutions reach \
                         {MAX_KERNEL}×{MAX_KERNEL})"
                    )));
                }
            }
        }
        let device = &gpu.device;
        let upload = |label: &str, words: &[u8]| {
            device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some(label),
                contents: words,
                usage: wgpu::BufferUsages::STORAGE,
            })
        };
        let error = device.push_error_scope(wgpu::ErrorFilter::Validation);
        let kernels = Kernels::new(device, half);
        let shapes = value_shapes(&graph);
        let mut chains = Vec::with_capacity(graph.steps.len());
        let steps = (graph.steps.iter())
            .map(|step| {
                let (conv, chain): (Option<&RawConv>, &[PerTexel]) = match &step.op {
                    Op::Conv(c, then) => (Some(c), then),
                    Op::PerTexel(chain) => (None, chain),
                    _ => (None, &[]),
                };
                chains.push(upload("chain", bytemuck::cast_slice(&chain_words(chain))));
                let conv = conv.map(|c| {
                    let mut taps = c.weights.clone();
                    taps.extend(c.bias.clone().unwrap_or_else(|| vec![0.0; c.shape[0]]));
                    DeviceConv {
                        weights: upload("weights", bytemuck::cast_slice(&taps)),
                        shape: c.shape,
                    }
                });
                Step {
                    op: match &step.op {
                        Op::Conv(_, then) => Op::Conv(conv, then.clone()),
                        Op::PerTexel(c) => Op::PerTexel(c.clone()),
                        Op::Arith(a) => Op::Arith(*a),
                        Op::Concat => Op::Concat,
                        Op::DepthToSpace { block, crd } => Op::DepthToSpace {
                            block: *block,
                            crd: *crd,
                        },
                        Op::ResizeNearest(f) => Op::ResizeNearest(*f),
                    },
                    inputs: step.inputs.clone(),
                    output: step.output,
                }
            })
            .collect();
        let unused = upload("unused", &[0; 16]);
        if let Some(e) = pollster::block_on(error.pop()) {
            return Err(GpuError::Failed(format!(
                "the GPU engine's kernels on {}: {e}",
                gpu.summary.name
            )));
        }
        Ok(GpuNet {
            kernels,
            last_use: last_uses(&graph.steps, graph.values, graph.output),
            steps,
            chains,
            shapes,
            output: graph.output,
            unused,
            pool: Mutex::new(Vec::new()),
            half,
            gpu,
        })
    }

    pub fn gpu(&self) -> &Gpu {
        &self.gpu
    }

    /// Whether the maps are held in half precision.
    pub fn half(&self) -> bool {
        self.half
    }

    /// Bytes of value slot `v` in a call of `batch` tiles of `h × w`: 4 or 2 a value, rounded
    /// up to whole words (what wgpu binds and copies).
    fn value_bytes(&self, v: usize, batch: usize, h: usize, w: usize) -> u64 {
        let (c, s) = self.shapes[v];
        let size = if self.half { 2 } else { 4 };
        ((batch * c * h * s * w * s * size) as u64).next_multiple_of(4)
    }

    /// The network's scale (the output's size over the input's).
    pub fn scale(&self) -> usize {
        self.shapes[self.output].1
    }

    /// Bytes of the largest map of a call of `batch` tiles of `h × w`, and of all maps alive
    /// at once at the peak.
    pub fn call_bytes(&self, batch: usize, h: usize, w: usize) -> (u64, u64) {
        let bytes = |v: usize| self.value_bytes(v, batch, h, w);
        let largest = (0..self.shapes.len()).map(bytes).max().unwrap_or(0);
        let mut alive: u64 = bytes(0);
        let mut peak = alive;
        for (i, step) in self.steps.iter().enumerate() {
            alive += bytes(step.output);
            peak = peak.max(alive);
            for &v in &step.inputs {
                if self.last_use[v] == i {
                    alive -= bytes(v);
                }
            }
        }
        (largest, peak)
    }

    /// The most tiles of `h × w` one call takes: its largest map within one buffer binding,
    /// and all maps alive at once within `budget` bytes.
    pub fn tiles_per_call(&self, h: usize, w: usize, budget: u64) -> usize {
        let (largest, peak) = self.call_bytes(1, h, w);
        let limits = &self.gpu.limits;
        let binding = limits
            .max_storage_buffer_binding_size
            .min(limits.max_buffer_size);
        let by_binding = binding / largest.max(1);
        let by_budget = budget / peak.max(1);
        // The convolution's dispatch counts images × output-channel groups in one dimension.
        let groups = self
            .shapes
            .iter()
            .map(|s| s.0.div_ceil(8))
            .max()
            .unwrap_or(1);
        let by_dispatch = limits.max_compute_workgroups_per_dimension as usize / groups.max(1);
        (by_binding.min(by_budget) as usize).min(by_dispatch).max(1)
    }

    /// A buffer of at least `bytes` for a map: from `free` (this call's freed buffers), the
    /// pool (earlier calls'), or new.
    fn buffer(&self, bytes: u64, free: &mut Vec<wgpu::Buffer>) -> wgpu::Buffer {
        let fits = |b: &wgpu::Buffer| b.size() == bytes;
        if let Some(i) = free.iter().position(fits) {
            return free.swap_remove(i);
        }
        let mut pool = self.pool.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(i) = pool.iter().position(fits) {
            return pool.swap_remove(i);
        }
        self.gpu.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("map"),
            size: bytes,
            usage: wgpu::BufferUsages::STORAGE
                | wgpu::BufferUsages::COPY_SRC
                | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        })
    }

    /// Runs the network on `input`, `batch` images of 3 planes of `h × w` (the network's range
    /// and channel order), its convolutions padding as `padding` says; returns the output's
    /// planes, `[batch, 3, h·scale, w·scale]`.
    pub fn run(
        &self,
        input: &[f32],
        batch: usize,
        h: usize,
        w: usize,
        padding: Padding,
    ) -> Result<Vec<f32>, GpuError> {
        assert_eq!(input.len(), batch * 3 * h * w, "3 planes of h × w an image");
        let device = &self.gpu.device;
        let out_of_memory = device.push_error_scope(wgpu::ErrorFilter::OutOfMemory);
        let invalid = device.push_error_scope(wgpu::ErrorFilter::Validation);
        let result = self.record_and_run(input, batch, h, w, padding);
        let invalid = pollster::block_on(invalid.pop());
        let out_of_memory = pollster::block_on(out_of_memory.pop());
        let what = || format!("{batch} tiles of {w}×{h} on {}", self.gpu.summary.name);
        if let Some(e) = out_of_memory {
            return Err(GpuError::OutOfMemory(format!("{}: {e}", what())));
        }
        if let Some(e) = invalid {
            return Err(GpuError::Failed(format!("{}: {e}", what())));
        }
        result
    }

    fn record_and_run(
        &self,
        input: &[f32],
        batch: usize,
        h: usize,
        w: usize,
        padding: Padding,
    ) -> Result<Vec<f32>, GpuError> {
        let device = &self.gpu.device;
        let bytes = |v: usize| self.value_bytes(v, batch, h, w);
        let mut free = Vec::new();
        let mut values: Vec<Option<wgpu::Buffer>> = vec![None; self.shapes.len()];
        let first = self.buffer(bytes(0), &mut free);
        let mut upload: Vec<u8> = match self.half {
            true => (input.iter())
                .flat_map(|v| half::f16::from_f32(*v).to_le_bytes())
                .collect(),
            false => bytemuck::cast_slice(input).to_vec(),
        };
        upload.resize(bytes(0) as usize, 0);
        self.gpu.queue.write_buffer(&first, 0, &upload);
        values[0] = Some(first);
        let mut encoder = device.create_command_encoder(&Default::default());
        for (i, step) in self.steps.iter().enumerate() {
            let out = self.buffer(bytes(step.output), &mut free);
            let value = |k: usize| {
                values[step.inputs[k]]
                    .as_ref()
                    .expect("values are written before they are read")
            };
            let (c, s) = self.shapes[step.inputs[0]];
            let (co, so) = self.shapes[step.output];
            let (sh, sw) = ((h * s) as u32, (w * s) as u32);
            let count = (batch * co * h * so * w * so) as u32;
            let base = Params {
                width: sw,
                height: sh,
                channels_in: c as u32,
                channels_out: co as u32,
                count,
                ..Params::default()
            };
            match &step.op {
                Op::Conv(conv, _) => {
                    let conv = conv.as_ref().expect("a convolution has weights");
                    let [cout, _, kh, kw] = conv.shape;
                    let groups = cout.div_ceil(8) as u32;
                    let params = Params {
                        kernel_h: kh as u32,
                        kernel_w: kw as u32,
                        mode: u32::from(padding == Padding::Wrap),
                        groups,
                        offset: conv.weights.size() as u32 / 4 - cout as u32,
                        ..base
                    };
                    let bind = [value(0), &self.unused, &conv.weights, &self.chains[i], &out];
                    let size = [sw.div_ceil(8), sh.div_ceil(8), batch as u32 * groups];
                    self.dispatch(&mut encoder, &self.kernels.conv, params, bind, size);
                }
                Op::PerTexel(_) => {
                    let bind = [value(0), &self.unused, &self.unused, &self.chains[i], &out];
                    self.elementwise(&mut encoder, &self.kernels.per_texel, base, bind);
                }
                Op::Arith(arith) => {
                    let params = Params {
                        mode: arith_code(*arith),
                        ..base
                    };
                    let bind = [value(0), value(1), &self.unused, &self.unused, &out];
                    self.elementwise(&mut encoder, &self.kernels.arithmetic, params, bind);
                }
                Op::Concat => {
                    // A kernel, not buffer copies: an f16 part of an odd plane does not
                    // start on a whole word.
                    let mut at = 0;
                    for k in 0..step.inputs.len() {
                        let part = self.shapes[step.inputs[k]].0;
                        let params = Params {
                            channels_in: part as u32,
                            offset: at as u32,
                            count: (batch * part * h * s * w * s) as u32,
                            ..base
                        };
                        let bind = [value(k), &self.unused, &self.unused, &self.unused, &out];
                        self.elementwise(&mut encoder, &self.kernels.copy_channels, params, bind);
                        at += part;
                    }
                }
                Op::DepthToSpace { block, crd } => {
                    let params = Params {
                        kernel_w: *block as u32,
                        mode: u32::from(*crd),
                        ..base
                    };
                    let bind = [value(0), &self.unused, &self.unused, &self.unused, &out];
                    self.elementwise(&mut encoder, &self.kernels.depth_to_space, params, bind);
                }
                Op::ResizeNearest(factor) => {
                    let params = Params {
                        kernel_w: *factor as u32,
                        ..base
                    };
                    let bind = [value(0), &self.unused, &self.unused, &self.unused, &out];
                    self.elementwise(&mut encoder, &self.kernels.resize_nearest, params, bind);
                }
            }
            values[step.output] = Some(out);
            for &v in &step.inputs {
                if self.last_use[v] == i {
                    // Later steps of this call may take it: the queue runs them in order.
                    free.extend(values[v].take());
                }
            }
        }
        let output = values[self.output].take().expect("the output is computed");
        let readback = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("readback"),
            size: output.size(),
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        encoder.copy_buffer_to_buffer(&output, 0, &readback, 0, output.size());
        self.gpu.queue.submit([encoder.finish()]);
        let (sender, receiver) = std::sync::mpsc::channel();
        readback.map_async(wgpu::MapMode::Read, .., move |r| {
            let _ = sender.send(r);
        });
        device
            .poll(wgpu::PollType::wait_indefinitely())
            .map_err(|e| GpuError::Failed(format!("waiting for the GPU: {e}")))?;
        match receiver.recv() {
            Ok(Ok(())) => {}
            _ => {
                return Err(GpuError::Failed(
                    "the GPU's output could not be read back (device lost?)".into(),
                ))
            }
        }
        let data = {
            let view = readback
                .get_mapped_range(..)
                .map_err(|e| GpuError::Failed(format!("reading the GPU's output: {e}")))?;
            let (c, s) = self.shapes[self.output];
            let values = batch * c * h * s * w * s;
            match self.half {
                true => (view[..2 * values].chunks_exact(2))
                    .map(|b| half::f16::from_le_bytes([b[0], b[1]]).to_f32())
                    .collect(),
                false => bytemuck::cast_slice::<u8, f32>(&view)[..values].to_vec(),
            }
        };
        readback.unmap();
        free.push(output);
        let mut pool = self.pool.lock().unwrap_or_else(|e| e.into_inner());
        pool.extend(free);
        Ok(data)
    }

    /// Records one dispatch of `pipeline` over `size` workgroups, its bindings 1–5 `bind`.
    fn dispatch(
        &self,
        encoder: &mut wgpu::CommandEncoder,
        pipeline: &wgpu::ComputePipeline,
        params: Params,
        bind: [&wgpu::Buffer; 5],
        size: [u32; 3],
    ) {
        let device = &self.gpu.device;
        let uniform = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("params"),
            contents: bytemuck::bytes_of(&params),
            usage: wgpu::BufferUsages::UNIFORM,
        });
        let mut entries = vec![wgpu::BindGroupEntry {
            binding: 0,
            resource: uniform.as_entire_binding(),
        }];
        entries.extend(
            (bind.iter().enumerate()).map(|(k, b)| wgpu::BindGroupEntry {
                binding: k as u32 + 1,
                resource: b.as_entire_binding(),
            }),
        );
        let group = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: None,
            layout: &self.kernels.layout,
            entries: &entries,
        });
        let mut pass = encoder.begin_compute_pass(&Default::default());
        pass.set_pipeline(pipeline);
        pass.set_bind_group(0, &group, &[]);
        pass.dispatch_workgroups(size[0], size[1], size[2]);
    }

    /// [`GpuNet::dispatch`] of an element-wise kernel over `params.count` values, 256 a
    /// workgroup, in rows of at most the device's workgroups per dimension.
    fn elementwise(
        &self,
        encoder: &mut wgpu::CommandEncoder,
        pipeline: &wgpu::ComputePipeline,
        params: Params,
        bind: [&wgpu::Buffer; 5],
    ) {
        let groups = params.count.div_ceil(256).max(1);
        let row = groups.min(self.gpu.limits.max_compute_workgroups_per_dimension);
        let params = Params {
            groups: row,
            ..params
        };
        self.dispatch(
            encoder,
            pipeline,
            params,
            bind,
            [row, groups.div_ceil(row), 1],
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::onnx::convnet::ConvNet;
    use crate::onnx::nhwc::Features;
    use tract_onnx::pb::{
        tensor_proto::DataType, AttributeProto, GraphProto, ModelProto, NodeProto, TensorProto,
        ValueInfoProto,
    };

    fn node(op: &str, inputs: &[&str], output: &str, attributes: Vec<AttributeProto>) -> NodeProto {
        NodeProto {
            op_type: op.into(),
            input: inputs.iter().map(|s| s.to_string()).collect(),
            output: vec![output.into()],
            attribute: attributes,
            ..Default::default()
        }
    }

    fn ints(name: &str, v: &[i64]) -> AttributeProto {
        AttributeProto {
            name: name.into(),
            ints: v.to_vec(),
            ..Default::default()
        }
    }

    fn int(name: &str, i: i64) -> AttributeProto {
        AttributeProto {
            name: name.into(),
            i,
            ..Default::default()
        }
    }

    fn text(name: &str, s: &str) -> AttributeProto {
        AttributeProto {
            name: name.into(),
            s: s.as_bytes().to_vec(),
            ..Default::default()
        }
    }

    fn float(name: &str, f: f32) -> AttributeProto {
        AttributeProto {
            name: name.into(),
            f,
            ..Default::default()
        }
    }

    /// A constant of `shape`, values spread over [−0.6, 0.6] by a hash of their index.
    fn constant(name: &str, shape: &[usize]) -> TensorProto {
        let n: usize = shape.iter().product();
        TensorProto {
            name: name.into(),
            dims: shape.iter().map(|&d| d as i64).collect(),
            data_type: DataType::Float as i32,
            float_data: (0..n)
                .map(|k| ((k * 7919 + name.len() * 31) % 97) as f32 / 80.0 - 0.6)
                .collect(),
            ..Default::default()
        }
    }

    fn model(nodes: Vec<NodeProto>, constants: Vec<TensorProto>, output: &str) -> ModelProto {
        let value = |name: &str| ValueInfoProto {
            name: name.into(),
            ..Default::default()
        };
        ModelProto {
            graph: Some(GraphProto {
                node: nodes,
                initializer: constants,
                input: vec![value("x")],
                output: vec![value(output)],
                ..Default::default()
            }),
            ..Default::default()
        }
    }

    /// A stride-1 "same" convolution node `output = conv(input)` of `cout × cin × k × k`.
    fn conv(
        input: &str,
        output: &str,
        cin: usize,
        cout: usize,
        k: usize,
    ) -> (NodeProto, Vec<TensorProto>) {
        let p = (k / 2) as i64;
        let (w, b) = (format!("{output}_w"), format!("{output}_b"));
        (
            node(
                "Conv",
                &[input, &w, &b],
                output,
                vec![ints("pads", &[p, p, p, p])],
            ),
            vec![constant(&w, &[cout, cin, k, k]), constant(&b, &[cout])],
        )
    }

    /// `graph` on the GPU (its maps f16 where `half`) against matup's CPU executor on a
    /// `w × h` image of `batch` tiles, under both paddings: the largest difference.
    fn largest_difference(
        gpu: &Arc<Gpu>,
        proto: &ModelProto,
        half: bool,
        batch: usize,
        h: usize,
        w: usize,
    ) -> f32 {
        let cpu = ConvNet::from_model(proto).unwrap();
        let net = GpuNet::new(Graph::from_model(proto).unwrap(), gpu.clone(), half).unwrap();
        let planes: Vec<f32> = (0..batch * 3 * h * w)
            .map(|k| ((k * 2654435761usize) % 1000) as f32 / 1000.0)
            .collect();
        let mut worst = 0f32;
        for padding in [Padding::Zero, Padding::Wrap] {
            let out = net.run(&planes, batch, h, w, padding).unwrap();
            let per_image = out.len() / batch;
            for b in 0..batch {
                let n = h * w;
                let image = &planes[b * 3 * n..(b + 1) * 3 * n];
                let input = Features {
                    height: h,
                    width: w,
                    channels: 3,
                    data: (0..n)
                        .flat_map(|t| (0..3).map(move |c| image[c * n + t]))
                        .collect(),
                };
                let want = cpu.run(input, padding);
                let plane = want.height * want.width;
                let got = &out[b * per_image..(b + 1) * per_image];
                for (t, texel) in want.data.chunks(want.channels).enumerate() {
                    for (c, v) in texel.iter().enumerate() {
                        assert!(v.is_finite() && got[c * plane + t].is_finite());
                        worst = worst.max((got[c * plane + t] - v).abs());
                    }
                }
            }
        }
        worst
    }

    fn test_gpu() -> Option<Arc<Gpu>> {
        crate::gpu::test_adapter().map(|a| crate::gpu::open(a.index).unwrap())
    }

    #[test]
    fn every_operation_matches_the_cpu_executor() {
        let Some(gpu) = test_gpu() else { return };
        // Convolutions of each kernel size, with each per-texel operation fused after them
        // or run on their own, arithmetic between maps and with constants both ways round,
        // a concatenation, both depth-to-space orders and a nearest resize.
        let (c1, mut constants) = conv("x", "a", 3, 12, 3);
        let (c2, k2) = conv("a", "b", 12, 12, 1);
        let (c3, k3) = conv("b", "c", 12, 9, 5);
        let (c4, k4) = conv("j", "k", 21, 12, 3);
        constants.extend(k2.into_iter().chain(k3).chain(k4));
        constants.push(constant("slope", &[1, 12, 1, 1]));
        constants.push(constant("shift", &[1, 12, 1, 1]));
        constants.push(constant("one", &[1]));
        let nodes = vec![
            c1,
            node("Sigmoid", &["a"], "a_s", vec![]),
            node("Mul", &["a", "a_s"], "a_silu", vec![]),
            c2,
            node("LeakyRelu", &["b"], "b_l", vec![float("alpha", 0.2)]),
            node("PRelu", &["b_l", "slope"], "b_p", vec![]),
            node("Sub", &["shift", "b_p"], "b_s", vec![]),
            node("Div", &["b_s", "one"], "b_d", vec![]),
            c3,
            node("Relu", &["c"], "c_r", vec![]),
            node("Concat", &["a_silu", "c_r"], "j", vec![int("axis", 1)]),
            c4,
            node(
                "Clip",
                &["k"],
                "k_c",
                vec![float("min", -0.5), float("max", 0.75)],
            ),
            node("Add", &["k_c", "b_d"], "m", vec![]),
            node("Mul", &["m", "a"], "n", vec![]),
            node("Sigmoid", &["n"], "n_s", vec![]),
            node("Sub", &["n_s", "b"], "o", vec![]),
            node("Div", &["o", "one"], "o_d", vec![]),
            node(
                "DepthToSpace",
                &["o_d"],
                "d",
                vec![int("blocksize", 2), text("mode", "DCR")],
            ),
        ];
        let mut crd = nodes.clone();
        crd.last_mut().unwrap().attribute[1] = text("mode", "CRD");
        let mut resized = nodes[..nodes.len() - 1].to_vec();
        constants.push(TensorProto {
            name: "scales".into(),
            dims: vec![4],
            data_type: DataType::Float as i32,
            float_data: vec![1.0, 1.0, 2.0, 2.0],
            ..Default::default()
        });
        let (c5, k5) = conv("o_d", "o3", 12, 3, 3);
        constants.extend(k5);
        resized.push(c5);
        resized.push(node(
            "Resize",
            &["o3", "", "scales"],
            "r",
            vec![
                text("mode", "nearest"),
                text("coordinate_transformation_mode", "asymmetric"),
                text("nearest_mode", "floor"),
            ],
        ));
        for (nodes, output) in [(nodes, "d"), (crd, "d"), (resized, "r")] {
            // DepthToSpace of 12 channels by 2 gives 3: an RGB output, as the executor wants.
            let proto = model(nodes, constants.clone(), output);
            for (batch, h, w) in [(1, 13, 11), (3, 8, 20)] {
                let worst = largest_difference(&gpu, &proto, false, batch, h, w);
                assert!(worst < 2e-5, "{output}, {batch} of {w}×{h}: {worst}");
                eprintln!("{output}, {batch} of {w}×{h}: largest difference {worst:.2e}");
                // Maps held in f16 (odd planes, so no part of a concatenation starts on a word).
                if gpu.summary.shader_f16 {
                    let worst = largest_difference(&gpu, &proto, true, batch, h, w);
                    eprintln!("{output}, {batch} of {w}×{h}, f16: largest difference {worst:.2e}");
                    assert!(worst < 2e-2, "{output}, {batch} of {w}×{h}, f16: {worst}");
                }
            }
        }
    }

    #[test]
    fn a_kernel_past_the_engines_reach_is_refused_by_name() {
        let Some(gpu) = test_gpu() else { return };
        let (c, k) = conv("x", "y", 3, 3, 7);
        let proto = model(vec![c], k, "y");
        let e = GpuNet::new(Graph::from_model(&proto).unwrap(), gpu, false)
            .err()
            .unwrap()
            .to_string();
        assert!(e.contains("Conv with a 7×7 kernel"), "{e}");
    }
}
