//! A network of matup's ONNX executor rebuilt from candle operations, its convolution weights
//! trainable, and written back into the ONNX file it came from. The graph is the executor's own
//! ([`Graph`]), so what is trained is exactly what `matup upscale` runs.

use std::path::Path;

use candle_core::{Device, Tensor, Var};
use matup_core::{Error, Result};
use matup_upsamplers::onnx::{
    read_graph, read_sidecar, Arith, Graph, ModelInfo, ModelProto, Op, PerTexel, RawConv,
};
use prost::Message;
use tract_onnx::pb::tensor_proto::DataType;

/// One convolution's trainable weights.
struct ConvWeights {
    /// `[cout, kh·kw·cin]`, column `(ky·kw + kx)·cin + ci`: the layout of the unfolded input.
    weights: Var,
    bias: Option<Var>,
    kernel: (usize, usize),
    cin: usize,
}

/// An ONNX super-resolution network as candle operations.
pub struct TrainableNet {
    graph: Graph,
    /// Per step, the weights of its convolution (if it is one).
    convs: Vec<Option<ConvWeights>>,
    proto: ModelProto,
    pub info: ModelInfo,
}

fn invalid(path: &Path, what: impl std::fmt::Display) -> Error {
    Error::Invalid(format!("{}: {what}", path.display()))
}

/// Candle errors as matup's.
pub(crate) fn candle(e: candle_core::Error) -> Error {
    Error::Invalid(format!("candle: {e}"))
}

impl TrainableNet {
    /// Loads `path` (and its sidecar). Every convolution's weights must be float32
    /// initialisers of the file, so that training can write them back.
    pub fn load(path: &Path, device: &Device) -> Result<TrainableNet> {
        let info = read_sidecar(path)?;
        let (proto, graph) = read_graph(path)?;
        let mut convs = Vec::with_capacity(graph.steps.len());
        for step in &graph.steps {
            let Op::Conv(conv, _) = &step.op else {
                convs.push(None);
                continue;
            };
            for name in [
                Some(&conv.weights_name),
                conv.bias.as_ref().map(|_| &conv.bias_name),
            ]
            .into_iter()
            .flatten()
            {
                let Some(name) = name else {
                    return Err(invalid(path, "a convolution's weights are computed in the graph, not stored: they cannot be trained"));
                };
                let stored = proto
                    .graph
                    .as_ref()
                    .and_then(|g| g.initializer.iter().find(|t| &t.name == name));
                if stored.is_none_or(|t| t.data_type != DataType::Float as i32) {
                    return Err(invalid(
                        path,
                        format!(
                            "initialiser '{name}' is not float32; only float32 weights are trained"
                        ),
                    ));
                }
            }
            convs.push(Some(conv_weights(conv, device).map_err(candle)?));
        }
        Ok(TrainableNet {
            graph,
            convs,
            proto,
            info,
        })
    }

    /// The trainable tensors, in a fixed order (checkpoints and the optimiser use it).
    pub fn vars(&self) -> Vec<Var> {
        self.convs
            .iter()
            .flatten()
            .flat_map(|c| std::iter::once(c.weights.clone()).chain(c.bias.clone()))
            .collect()
    }

    /// Upsamples `[B, 3, h, w]` RGB images in [0, 1] (the executor's input convention: the
    /// sidecar's ranges and channel order applied here), zero padding at the borders.
    pub fn forward(&self, images: &Tensor) -> candle_core::Result<Tensor> {
        let [lo, hi] = self.info.input_range;
        let [olo, ohi] = self.info.output_range;
        let bgr = self.info.channel_order == "bgr";
        let swap = |x: &Tensor| -> candle_core::Result<Tensor> {
            if bgr {
                Tensor::cat(
                    &[x.narrow(1, 2, 1)?, x.narrow(1, 1, 1)?, x.narrow(1, 0, 1)?],
                    1,
                )
            } else {
                Ok(x.clone())
            }
        };
        let input = swap(&images.affine((hi - lo) as f64, lo as f64)?)?;
        let mut values: Vec<Option<Tensor>> = vec![None; self.graph.values];
        values[0] = Some(input);
        for (step, conv) in self.graph.steps.iter().zip(&self.convs) {
            let input = |k: usize| {
                values[step.inputs[k]]
                    .clone()
                    .expect("steps come in the order they are computed")
            };
            let out = match &step.op {
                Op::Conv(_, then) => {
                    let w = conv.as_ref().expect("a conv step has weights");
                    per_texel(&convolve(&input(0), w)?, then)?
                }
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
            values[step.output] = Some(out);
        }
        let out = values[self.graph.output]
            .take()
            .expect("the output is computed");
        swap(&out)?
            .affine(1.0 / (ohi - olo) as f64, -(olo / (ohi - olo)) as f64)?
            .clamp(0f32, 1f32)
    }

    /// The ONNX file with the current weights written into its initialisers: the same graph,
    /// so matup's executor runs it as it ran the original.
    pub fn to_onnx(&self) -> Result<Vec<u8>> {
        let mut proto = self.proto.clone();
        let graph = proto.graph.as_mut().expect("read_graph checked the graph");
        for (step, weights) in self.graph.steps.iter().zip(&self.convs) {
            let (Op::Conv(conv, _), Some(w)) = (&step.op, weights) else {
                continue;
            };
            let onnx = onnx_layout(w).map_err(candle)?;
            let bias = w
                .bias
                .as_ref()
                .map(|b| b.as_tensor().to_vec1::<f32>())
                .transpose();
            let mut write = |name: &Option<String>, values: Vec<f32>| {
                let name = name.as_ref().expect("checked on load");
                let t = graph
                    .initializer
                    .iter_mut()
                    .find(|t| &t.name == name)
                    .expect("checked on load");
                t.raw_data = values.iter().flat_map(|v| v.to_le_bytes()).collect();
                t.float_data.clear();
            };
            write(&conv.weights_name, onnx);
            if let Some(bias) = bias.map_err(candle)? {
                write(&conv.bias_name, bias);
            }
        }
        Ok(proto.encode_to_vec())
    }
}

fn conv_weights(conv: &RawConv, device: &Device) -> candle_core::Result<ConvWeights> {
    let [cout, cin, kh, kw] = conv.shape;
    // ONNX [cout][cin][ky][kx] → [cout][ky][kx][cin].
    let w = Tensor::from_slice(&conv.weights, (cout, cin, kh, kw), device)?
        .permute((0, 2, 3, 1))?
        .reshape((cout, kh * kw * cin))?;
    Ok(ConvWeights {
        weights: Var::from_tensor(&w)?,
        bias: conv
            .bias
            .as_ref()
            .map(|b| Var::from_slice(b, cout, device))
            .transpose()?,
        kernel: (kh, kw),
        cin,
    })
}

/// The weights back in ONNX's `[cout][cin][ky][kx]` order, flattened.
fn onnx_layout(w: &ConvWeights) -> candle_core::Result<Vec<f32>> {
    let (kh, kw) = w.kernel;
    let cout = w.weights.dim(0)?;
    w.weights
        .reshape((cout, kh, kw, w.cin))?
        .permute((0, 3, 1, 2))?
        .flatten_all()?
        .to_vec1()
}

/// A stride-1 convolution keeping the size, zero padded, as one matrix product over the
/// unfolded input. Written with candle's tensor operations rather than its `conv2d`: the
/// backward of `conv2d` runs candle's direct `conv_transpose2d` loop on the CPU, which measured
/// slower here in a scratch comparison (21 SPAN-sized layers with SiLU, batch 12 of 32²,
/// forward and backward, 2 cores, 3 runs: 2.3–2.6 s with `conv2d`, 1.6–2.5 s unfolded).
fn convolve(x: &Tensor, w: &ConvWeights) -> candle_core::Result<Tensor> {
    let (b, c, h, wd) = x.dims4()?;
    let (kh, kw) = w.kernel;
    let cout = w.weights.dim(0)?;
    let columns = if (kh, kw) == (1, 1) {
        x.reshape((b, c, h * wd))?
    } else {
        let padded = x
            .pad_with_zeros(2, kh / 2, kh / 2)?
            .pad_with_zeros(3, kw / 2, kw / 2)?;
        let mut shifted = Vec::with_capacity(kh * kw);
        for dy in 0..kh {
            for dx in 0..kw {
                shifted.push(padded.narrow(2, dy, h)?.narrow(3, dx, wd)?);
            }
        }
        Tensor::cat(&shifted, 1)?.reshape((b, kh * kw * c, h * wd))?
    };
    let mut y = w.weights.as_tensor().broadcast_left(b)?.matmul(&columns)?;
    if let Some(bias) = &w.bias {
        y = y.broadcast_add(&bias.as_tensor().reshape((1, cout, 1))?)?;
    }
    y.reshape((b, cout, h, wd))
}

fn per_texel(x: &Tensor, chain: &[PerTexel]) -> candle_core::Result<Tensor> {
    let mut x = x.clone();
    for op in chain {
        let channels = x.dim(1)?;
        let per_channel = |values: &[f32]| -> candle_core::Result<Tensor> {
            let n = values.len();
            debug_assert!(n == 1 || n == channels);
            Tensor::from_slice(values, (1, n, 1, 1), x.device())
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

/// `[B, C·r², H, W]` → `[B, C, H·r, W·r]`: CRD is PyTorch's pixel shuffle (channel, row,
/// column), DCR ONNX's default (row, column, channel).
fn depth_to_space(x: &Tensor, r: usize, crd: bool) -> candle_core::Result<Tensor> {
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
