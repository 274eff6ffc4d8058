//! A network of matup's ONNX executor rebuilt from candle operations, its convolution weights
//! trainable, and written back into the ONNX file it came from. The graph is the executor's own
//! ([`Graph`]), so what is trained is exactly what `matup upscale` runs.

use std::path::Path;

use candle_core::{Device, Tensor, Var};
use matup_core::resample::Border;
use matup_core::{Error, Result};
use matup_upsamplers::onnx::{
    in_channel_order, read_graph, read_sidecar, run_steps, unit_rgb, Graph, ModelInfo, ModelProto,
    Op, RawConv,
};
use prost::Message;
use tract_onnx::pb::tensor_proto::DataType;

use crate::config::Trained;

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
    /// A joint network's extra input: the index of the convolution that reads the network's
    /// input and its weights for the height channel (see [`TrainableNet::add_height_guide`]).
    height_guide: Option<(usize, ConvWeights)>,
}

fn invalid(path: &Path, what: impl std::fmt::Display) -> Error {
    Error::file(path, what.to_string())
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
            convs.push(Some(conv_weights(conv, device)?));
        }
        Ok(TrainableNet {
            graph,
            convs,
            proto,
            info,
            height_guide: None,
        })
    }

    /// Makes the network joint: a height map read beside the RGB input by the first
    /// convolution, through weights of its own that start at zero (so the network starts as
    /// it was). The convolution must read the input through per-texel steps only (SPAN's
    /// normalisation), so that the height enters where the colours do.
    pub fn add_height_guide(&mut self) -> Result<()> {
        let producer = |value: usize| self.graph.steps.iter().position(|s| s.output == value);
        let Some(entry) = self
            .graph
            .steps
            .iter()
            .position(|s| matches!(s.op, Op::Conv(..)))
        else {
            return Err(Error::Invalid("the network has no convolution".into()));
        };
        let mut value = self.graph.steps[entry].inputs[0];
        while value != 0 {
            match producer(value).map(|i| &self.graph.steps[i]) {
                Some(step) if matches!(step.op, Op::PerTexel(_)) => value = step.inputs[0],
                _ => {
                    return Err(Error::Invalid(
                        "the network's first convolution does not read its input through per-texel steps only: no place for a height channel".into(),
                    ))
                }
            }
        }
        let w = self.convs[entry].as_ref().expect("a conv step has weights");
        let (kh, kw) = w.kernel;
        let cout = w.weights.dim(0)?;
        let device = w.weights.device().clone();
        let zeros = Var::zeros((cout, kh * kw), candle_core::DType::F32, &device)?;
        self.height_guide = Some((
            entry,
            ConvWeights {
                weights: zeros,
                bias: None,
                kernel: (kh, kw),
                cin: 1,
            },
        ));
        Ok(())
    }

    /// Whether the network reads a height map beside its RGB input.
    pub fn has_height_guide(&self) -> bool {
        self.height_guide.is_some()
    }

    /// The tensors a run that trains only `trained` keeps as they are.
    pub fn frozen_vars(&self, trained: Trained) -> Vec<Var> {
        let convs: Vec<&ConvWeights> = self.convs.iter().flatten().collect();
        match trained {
            Trained::All => Vec::new(),
            Trained::Biases => (convs.iter().map(|c| c.weights.clone()))
                .chain(self.height_guide.as_ref().map(|(_, w)| w.weights.clone()))
                .collect(),
            Trained::LastLayer => {
                let last = convs.len().saturating_sub(1);
                (convs.iter().take(last).copied())
                    .chain(self.height_guide.as_ref().map(|(_, w)| w))
                    .flat_map(|c| std::iter::once(c.weights.clone()).chain(c.bias.clone()))
                    .collect()
            }
        }
    }

    /// The trainable tensors, in a fixed order (checkpoints and the optimiser use it).
    pub fn vars(&self) -> Vec<Var> {
        self.convs
            .iter()
            .flatten()
            .chain(self.height_guide.as_ref().map(|(_, w)| w))
            .flat_map(|c| std::iter::once(c.weights.clone()).chain(c.bias.clone()))
            .collect()
    }

    /// Upsamples `[B, 3, h, w]` RGB images in [0, 1] (the executor's input convention: the
    /// sidecar's ranges and channel order applied here), zero padding at the borders.
    pub fn forward(&self, images: &Tensor) -> candle_core::Result<Tensor> {
        self.forward_guided(images, None)
    }

    /// [`TrainableNet::forward`] for a joint network: `height` `[B, 1, h, w]` beside the
    /// images (required when the network has a height guide, ignored otherwise).
    pub fn forward_guided(
        &self,
        images: &Tensor,
        height: Option<&Tensor>,
    ) -> candle_core::Result<Tensor> {
        let guide = match (&self.height_guide, height) {
            (Some(g), Some(h)) => Some((g, h)),
            (Some(_), None) => {
                return Err(candle_core::Error::Msg(
                    "a height-guided network needs the height map".into(),
                ))
            }
            (None, _) => None,
        };
        let [lo, hi] = self.info.input_range;
        let input = in_channel_order(&images.affine((hi - lo) as f64, lo as f64)?, &self.info)?;
        let g = &self.graph;
        let out = run_steps(&g.steps, g.values, g.output, input, |index, x| {
            let w = self.convs[index].as_ref().expect("a conv step has weights");
            let y = convolve(x, w)?;
            match guide {
                Some(((entry, g), height)) if *entry == index => y + convolve(height, g)?,
                _ => Ok(y),
            }
        })?;
        unit_rgb(&out, &self.info)
    }

    /// [`TrainableNet::forward_guided`] as matup's executor runs a whole image: read with
    /// `context` texels beyond each edge taken as `border` says (as the executor's tiles read
    /// theirs), the output cropped back to the image's.
    pub fn forward_bordered(
        &self,
        images: &Tensor,
        height: Option<&Tensor>,
        context: usize,
        border: Border,
    ) -> candle_core::Result<Tensor> {
        let pad = |x: &Tensor| -> candle_core::Result<Tensor> {
            let (_, _, h, w) = x.dims4()?;
            let indices = |n: usize| {
                let reach = context as isize;
                let i: Vec<u32> = (-reach..n as isize + reach)
                    .map(|i| border.index(i, n) as u32)
                    .collect();
                Tensor::from_vec(i, n + 2 * context, x.device())
            };
            x.index_select(&indices(h)?, 2)?
                .index_select(&indices(w)?, 3)
        };
        let height = height.map(pad).transpose()?;
        let out = self.forward_guided(&pad(images)?, height.as_ref())?;
        let (_, _, h, w) = images.dims4()?;
        let s = self.info.scale;
        out.narrow(2, context * s, h * s)?
            .narrow(3, context * s, w * s)
    }

    /// The ONNX file with the current weights written into its initialisers: the same graph,
    /// so matup's executor runs it as it ran the original.
    pub fn to_onnx(&self) -> Result<Vec<u8>> {
        if self.has_height_guide() {
            return Err(Error::Invalid(
                "a height-guided network has no ONNX form here: matup's executor runs RGB networks"
                    .into(),
            ));
        }
        let mut proto = self.proto.clone();
        let graph = proto.graph.as_mut().expect("read_graph checked the graph");
        for (step, weights) in self.graph.steps.iter().zip(&self.convs) {
            let (Op::Conv(conv, _), Some(w)) = (&step.op, weights) else {
                continue;
            };
            let onnx = onnx_layout(w)?;
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
            if let Some(bias) = bias? {
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
