//! The executor's graphs ([`Graph`]) as candle operations on `[B, C, H, W]` tensors: what
//! runs a network on a GPU (`device=cuda`), and what matup-learn trains. The steps are the
//! executor's own, so the GPU runs exactly the network the CPU runs, and what is trained is
//! exactly what `matup upscale` runs.

use candle_core::{DType, Device, Tensor};

use super::convnet::{last_uses, Graph, Op, Step};
use super::nhwc::{Arith, Padding, PerTexel};
use super::source::ModelInfo;

/// Runs `steps` on `input`, the network's input values (slot 0) as `[B, C, H, W]`;
/// `convolve(index, x)` computes step `index`'s convolution (the caller holds the weights:
/// uploaded for inference, trainable variables for training), and its per-texel chain is
/// applied after. Each value is dropped after the last step that reads it, so a GPU holds
/// only the maps still needed.
pub fn run_steps<C>(
    steps: &[Step<C>],
    values: usize,
    output: usize,
    input: Tensor,
    mut convolve: impl FnMut(usize, &Tensor) -> candle_core::Result<Tensor>,
) -> candle_core::Result<Tensor> {
    let last_use = last_uses(steps, values, output);
    let mut slots: Vec<Option<Tensor>> = vec![None; values];
    slots[0] = Some(input);
    for (index, step) in steps.iter().enumerate() {
        let input = |k: usize| {
            slots[step.inputs[k]]
                .clone()
                .expect("steps come in the order they are computed")
        };
        let out = match &step.op {
            Op::Conv(_, then) => per_texel(&convolve(index, &input(0))?, then)?,
            Op::PerTexel(chain) => per_texel(&input(0), chain)?,
            Op::Arith(a) => {
                let (x, y) = (input(0), input(1));
                match a {
                    Arith::Add => (x + y)?,
                    Arith::Sub => (x - y)?,
                    Arith::Mul => (x * y)?,
                    Arith::Div => (x / y)?,
                }
            }
            Op::Concat => {
                let parts: Vec<Tensor> = (0..step.inputs.len()).map(input).collect();
                Tensor::cat(&parts, 1)?
            }
            Op::DepthToSpace { block, crd } => depth_to_space(&input(0), *block, *crd)?,
            Op::ResizeNearest(f) => {
                let (_, _, h, w) = input(0).dims4()?;
                input(0).upsample_nearest2d(h * f, w * f)?
            }
        };
        slots[step.output] = Some(out);
        for &v in &step.inputs {
            if last_use[v] == index {
                slots[v] = None;
            }
        }
    }
    Ok(slots[output].take().expect("the output is computed"))
}

/// The per-texel operations of `chain` on `x`, in order.
pub fn per_texel(x: &Tensor, chain: &[PerTexel]) -> candle_core::Result<Tensor> {
    let mut x = x.clone();
    for op in chain {
        let channels = x.dim(1)?;
        let per_channel = |values: &[f32]| -> candle_core::Result<Tensor> {
            let n = values.len();
            debug_assert!(n == 1 || n == channels);
            Tensor::from_slice(values, (1, n, 1, 1), x.device())?.to_dtype(x.dtype())
        };
        x = match op {
            // As (tanh(x/2) + 1)/2: 1/(1 + e^−x) overflows for very negative x, and its
            // gradient becomes 0·∞.
            PerTexel::Sigmoid => ((x * 0.5)?.tanh()? + 1.0)?.affine(0.5, 0.0)?,
            PerTexel::Silu => x.silu()?,
            PerTexel::Relu => x.relu()?,
            PerTexel::LeakyRelu(a) => {
                let negative = x.minimum(0f32)?;
                (x.relu()? + (negative * *a as f64)?)?
            }
            PerTexel::Clip(lo, hi) => x.clamp(*lo, *hi)?,
            PerTexel::PRelu(slope) => {
                let negative = x.minimum(0f32)?.broadcast_mul(&per_channel(slope)?)?;
                (x.relu()? + negative)?
            }
            PerTexel::Constant {
                arith,
                constant,
                constant_first,
            } => {
                let c = per_channel(constant)?;
                match (arith, constant_first) {
                    (Arith::Add, _) => x.broadcast_add(&c)?,
                    (Arith::Mul, _) => x.broadcast_mul(&c)?,
                    (Arith::Sub, false) => x.broadcast_sub(&c)?,
                    (Arith::Sub, true) => c.broadcast_sub(&x)?,
                    (Arith::Div, false) => x.broadcast_div(&c)?,
                    (Arith::Div, true) => c.broadcast_div(&x)?,
                }
            }
        };
    }
    Ok(x)
}

/// `x`'s three channels `[B, 3, H, W]` in the order a network with `info` takes them, or,
/// the same permutation, its output's back in RGB order: a BGR network's first and last swap.
pub fn in_channel_order(x: &Tensor, info: &ModelInfo) -> candle_core::Result<Tensor> {
    if info.channel_order == "bgr" {
        Tensor::cat(
            &[x.narrow(1, 2, 1)?, x.narrow(1, 1, 1)?, x.narrow(1, 0, 1)?],
            1,
        )
    } else {
        Ok(x.clone())
    }
}

/// A network's output `[B, 3, H, W]` as RGB in [0, 1]: its channel order undone, its output
/// range mapped, clamped.
pub fn unit_rgb(out: &Tensor, info: &ModelInfo) -> candle_core::Result<Tensor> {
    let [olo, ohi] = info.output_range;
    in_channel_order(out, info)?
        .affine(1.0 / (ohi - olo) as f64, -(olo / (ohi - olo)) as f64)?
        .clamp(0f32, 1f32)
}

/// `[B, C·r², H, W]` → `[B, C, H·r, W·r]`: CRD is PyTorch's pixel shuffle (channel, row,
/// column), DCR ONNX's default (row, column, channel).
pub fn depth_to_space(x: &Tensor, r: usize, crd: bool) -> candle_core::Result<Tensor> {
    let (b, c, h, w) = x.dims4()?;
    let c = c / (r * r);
    let spread = if crd {
        x.reshape(&[b, c, r, r, h, w][..])?
            .permute(&[0, 1, 4, 2, 5, 3][..])?
    } else {
        x.reshape(&[b, r, r, c, h, w][..])?
            .permute(&[0, 3, 4, 1, 5, 2][..])?
    };
    spread.reshape((b, c, h * r, w * r))
}

/// `x` extended by `by` texels beyond each edge along `dim`, the image repeating.
fn wrapped(x: &Tensor, dim: usize, by: usize) -> candle_core::Result<Tensor> {
    if by == 0 {
        return Ok(x.clone());
    }
    let n = x.dim(dim)?;
    let indices: Vec<u32> = (-(by as isize)..(n + by) as isize)
        .map(|i| i.rem_euclid(n as isize) as u32)
        .collect();
    x.index_select(&Tensor::from_vec(indices, n + 2 * by, x.device())?, dim)
}

/// One convolution's weights on the device: ONNX's `[cout, cin, kh, kw]` and the bias as
/// `[1, cout, 1, 1]`.
struct Kernel {
    weights: Tensor,
    bias: Option<Tensor>,
}

/// What a [`TensorNet`] computes in.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Precision {
    /// f32 throughout.
    #[default]
    F32,
    /// f32 values, the convolutions' matrix products on a GPU's tensor cores with TF32 inputs
    /// (10-bit mantissas), accumulating in f32: cuBLAS's setting, a GPU's alone.
    Tf32,
    /// Half-size values and weights; the matrix products accumulate in f32 (candle's cuBLAS
    /// default for them).
    F16,
    /// As f16, with 8-bit mantissas and f32's range; a GPU's alone.
    Bf16,
}

impl Precision {
    pub const ALL: [Precision; 4] = [
        Precision::F32,
        Precision::Tf32,
        Precision::F16,
        Precision::Bf16,
    ];

    /// The precision `precision=` names.
    pub fn parse(name: &str) -> Option<Precision> {
        Precision::ALL.into_iter().find(|p| p.name() == name)
    }

    /// The name `precision=` takes.
    pub fn name(self) -> &'static str {
        match self {
            Precision::F32 => "f32",
            Precision::Tf32 => "tf32",
            Precision::F16 => "f16",
            Precision::Bf16 => "bf16",
        }
    }

    /// The dtype values and weights are held in.
    pub fn dtype(self) -> DType {
        match self {
            Precision::F32 | Precision::Tf32 => DType::F32,
            Precision::F16 => DType::F16,
            Precision::Bf16 => DType::BF16,
        }
    }
}

/// A network of matup's executor as candle operations on one device, its weights uploaded
/// once, computing at `precision`.
pub struct TensorNet {
    graph: Graph,
    kernels: Vec<Option<Kernel>>,
    device: Device,
    precision: Precision,
}

impl TensorNet {
    /// `graph` with its convolution weights uploaded to `device`, to run at `precision`
    /// (TF32 only on a GPU).
    pub fn new(
        graph: Graph,
        device: &Device,
        precision: Precision,
    ) -> candle_core::Result<TensorNet> {
        match precision {
            Precision::Tf32 | Precision::Bf16 if !device.is_cuda() => candle_core::bail!(
                "precision {} runs on a GPU alone (candle's CPU has no such matrix product): \
                 on the CPU use f32 or f16",
                precision.name()
            ),
            _ => {}
        }
        let dtype = precision.dtype();
        let kernels = (graph.steps.iter())
            .map(|step| {
                let Op::Conv(conv, _) = &step.op else {
                    return Ok(None);
                };
                let [cout, cin, kh, kw] = conv.shape;
                Ok(Some(Kernel {
                    weights: Tensor::from_slice(&conv.weights, (cout, cin, kh, kw), device)?
                        .to_dtype(dtype)?,
                    bias: (conv.bias.as_ref())
                        .map(|b| Tensor::from_slice(b, (1, cout, 1, 1), device)?.to_dtype(dtype))
                        .transpose()?,
                }))
            })
            .collect::<candle_core::Result<_>>()?;
        Ok(TensorNet {
            graph,
            kernels,
            device: device.clone(),
            precision,
        })
    }

    pub fn device(&self) -> &Device {
        &self.device
    }

    /// [`tile_cost`] of this network, in its own dtype.
    pub fn tile_cost(&self, h: usize, w: usize) -> TileCost {
        tile_cost(&self.graph, h, w, self.precision.dtype())
    }

    /// The network on `input` (`[B, 3, H, W]`, the network's own value range and channel
    /// order), its convolutions padding as `padding` says; the output is f32 whatever the
    /// network computes in.
    pub fn run(&self, input: Tensor, padding: Padding) -> candle_core::Result<Tensor> {
        let g = &self.graph;
        let input = input.to_dtype(self.precision.dtype())?;
        let _tf32 = Tf32::allowed_while(self.precision == Precision::Tf32);
        let out = run_steps(&g.steps, g.values, g.output, input, |index, x| {
            let k = self.kernels[index]
                .as_ref()
                .expect("a convolution step has weights");
            let (_, _, kh, kw) = k.weights.dims4()?;
            // candle's conv2d pads both axes alike; other cases are padded here.
            let y = match padding {
                Padding::Zero if kh == kw => x.conv2d(&k.weights, kh / 2, 1, 1, 1)?,
                Padding::Zero => x
                    .pad_with_zeros(2, kh / 2, kh / 2)?
                    .pad_with_zeros(3, kw / 2, kw / 2)?
                    .conv2d(&k.weights, 0, 1, 1, 1)?,
                Padding::Wrap => {
                    wrapped(&wrapped(x, 2, kh / 2)?, 3, kw / 2)?.conv2d(&k.weights, 0, 1, 1, 1)?
                }
            };
            match &k.bias {
                Some(b) => y.broadcast_add(b),
                None => Ok(y),
            }
        })?;
        out.to_dtype(DType::F32)
    }
}

/// cuBLAS's TF32 setting, a process-wide flag in candle, allowed while this lives and put
/// back after (the training in the same process keeps its f32 products).
struct Tf32 {
    #[cfg(feature = "cuda")]
    before: bool,
}

impl Tf32 {
    fn allowed_while(allowed: bool) -> Tf32 {
        #[cfg(feature = "cuda")]
        {
            let before = candle_core::cuda::gemm_reduced_precision_f32();
            candle_core::cuda::set_gemm_reduced_precision_f32(allowed || before);
            Tf32 { before }
        }
        #[cfg(not(feature = "cuda"))]
        {
            let _ = allowed;
            Tf32 {}
        }
    }
}

#[cfg(feature = "cuda")]
impl Drop for Tf32 {
    fn drop(&mut self) {
        candle_core::cuda::set_gemm_reduced_precision_f32(self.before);
    }
}

/// What one `h × w` tile costs the device while the network runs.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct TileCost {
    /// Bytes at the peak: the values alive at each step (as [`run_steps`] frees them), its
    /// output, and its temporaries (the unfolded input of a convolution, candle's on CUDA being
    /// an im2col and a matrix product; a per-texel chain's intermediate maps).
    pub bytes: usize,
    /// Elements of the largest single tensor (the largest unfolded input, usually).
    pub largest: usize,
}

/// [`TileCost`] of `graph` on an `h × w` tile, its values held as `dtype`.
pub fn tile_cost(graph: &Graph, h: usize, w: usize, dtype: DType) -> TileCost {
    let last_use = last_uses(&graph.steps, graph.values, graph.output);
    // Per value: channels × the square of its scale, its floats per input texel.
    let mut floats = vec![0usize; graph.values];
    let mut scales = vec![1usize; graph.values];
    floats[0] = 3;
    let mut alive = 3;
    let mut peak = 0;
    let mut largest = 3;
    for (index, step) in graph.steps.iter().enumerate() {
        let v = step.inputs[0];
        let (c, s) = (floats[v] / (scales[v] * scales[v]), scales[v]);
        let ((channels, scale), temporary) = match &step.op {
            Op::Conv(conv, then) => {
                let [cout, cin, kh, kw] = conv.shape;
                (
                    (cout, s),
                    cin * kh * kw * s * s + 2 * then.len() * cout * s * s,
                )
            }
            Op::PerTexel(chain) => ((c, s), 2 * chain.len() * c * s * s),
            Op::Concat => {
                let sum = step.inputs.iter().map(|&v| floats[v] / (s * s)).sum();
                ((sum, s), 0)
            }
            Op::DepthToSpace { block, .. } => ((c / (block * block), s * block), c * s * s),
            Op::ResizeNearest(f) => ((c, s * f), 0),
            Op::Arith(_) => ((c, s), 0),
        };
        floats[step.output] = channels * scale * scale;
        scales[step.output] = scale;
        if let Op::Conv(conv, _) = &step.op {
            let [_, cin, kh, kw] = conv.shape;
            largest = largest.max(cin * kh * kw * s * s);
        }
        largest = largest.max(floats[step.output]);
        alive += floats[step.output];
        peak = peak.max(alive + temporary);
        for &v in &step.inputs {
            if last_use[v] == index {
                alive -= std::mem::take(&mut floats[v]);
            }
        }
    }
    TileCost {
        bytes: peak * h * w * dtype.size_in_bytes(),
        largest: largest * h * w,
    }
}
