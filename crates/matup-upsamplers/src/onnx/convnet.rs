//! matup's own executor for convolutional super-resolution graphs.
//!
//! SR networks are chains of stride-1 convolutions, per-texel activations and arithmetic,
//! channel concatenations and a final pixel shuffle or nearest resize. tract runs them, but its
//! 3×3 convolutions reach about a fifth of onnxruntime's speed on our CPUs (see
//! docs/experiments/2026-11-21-onnx-executor-speed.md), and no pure-Rust runtime does better (candle-onnx needs protoc
//! to build). This executor reads the ONNX graph itself and runs those few operators on
//! texel-major feature maps ([`super::nhwc`]): 3×3 convolutions by Winograd's algorithm
//! ([`super::winograd`]), all matrix products on matup-simd's `gemm`. Graphs with any other
//! operator or attribute are refused with the reason, and the caller runs them with tract.

use std::collections::HashMap;

use tract_onnx::data_resolver::MmapDataResolver;
use tract_onnx::pb::{
    tensor_proto::DataType, GraphProto, ModelProto, NodeProto, TensorProto, ValueInfoProto,
};

use super::conv::Conv;
use super::nhwc::{self, Arith, Features, Padding, PerTexel};

/// Why a graph cannot run here.
#[derive(Debug)]
pub struct Unsupported(pub String);

impl std::fmt::Display for Unsupported {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}

/// One operation of a network. `C` is how a convolution is held: [`RawConv`] as the file
/// gives it ([`Graph`]), or prepared for this executor's operations ([`ConvNet`]).
#[derive(Clone, Debug)]
pub enum Op<C> {
    /// A convolution, then per-texel operations on its output.
    Conv(C, Vec<PerTexel>),
    /// Per-texel operations in order.
    PerTexel(Vec<PerTexel>),
    /// Arithmetic between two maps of one shape.
    Arith(Arith),
    /// Maps joined along the channels.
    Concat,
    /// Channels moved into `block × block` texels (`crd`: PyTorch's pixel shuffle).
    DepthToSpace {
        block: usize,
        crd: bool,
    },
    ResizeNearest(usize),
}

/// An operation reading value slots `inputs` (slot 0 is the network's input) and writing
/// slot `output`.
#[derive(Clone, Debug)]
pub struct Step<C> {
    pub op: Op<C>,
    pub inputs: Vec<usize>,
    pub output: usize,
}

/// A stride-1 convolution that keeps the size, as the file holds it: ONNX's
/// `[cout, cin, kh, kw]` weights, and the names of the initialisers they came from (none when
/// computed in the graph, a `Cast` say), so that a trainer can write them back.
#[derive(Clone, Debug)]
pub struct RawConv {
    pub shape: [usize; 4],
    pub weights: Vec<f32>,
    pub bias: Option<Vec<f32>>,
    pub weights_name: Option<String>,
    pub bias_name: Option<String>,
}

/// A network of the operators this executor runs, per-texel work fused into the steps that
/// feed it, convolutions as the file gives them: what [`ConvNet`] prepares for its operations,
/// and what a trainer rebuilds in another framework (matup-learn).
#[derive(Clone, Debug)]
pub struct Graph {
    pub steps: Vec<Step<RawConv>>,
    /// The number of value slots.
    pub values: usize,
    /// The slot holding the RGB output.
    pub output: usize,
}

/// A graph this executor runs: one RGB input, one RGB output.
#[derive(Debug)]
pub struct ConvNet {
    steps: Vec<Step<Conv>>,
    /// Per value: the last step that reads it (then its memory is freed).
    last_use: Vec<usize>,
    output: usize,
}

/// What a name in the graph stands for while it is read.
#[derive(Clone, Debug)]
enum Known {
    /// A feature map: its value slot, channels, and size as a multiple of the input's.
    Map {
        slot: usize,
        channels: usize,
        scale: usize,
    },
    Constant(Constant),
}

/// A float constant of the graph: its shape and values.
#[derive(Clone, Debug)]
struct Constant {
    shape: Vec<usize>,
    data: Vec<f32>,
}

fn unsupported<T>(what: impl Into<String>) -> Result<T, Unsupported> {
    Err(Unsupported(what.into()))
}

/// A float constant of the file (32- or 16-bit), or `None` for other types.
fn float_constant(t: &TensorProto) -> Result<Option<Known>, Unsupported> {
    if t.data_type != DataType::Float as i32 && t.data_type != DataType::Float16 as i32 {
        return Ok(None);
    }
    let array = tract_onnx::tensor::load_tensor(&MmapDataResolver, t, None)
        .and_then(|t| t.cast_to::<f32>()?.into_owned().into_plain_array::<f32>())
        .map_err(|e| Unsupported(format!("constant '{}': {e}", t.name)))?;
    Ok(Some(Known::Constant(Constant {
        shape: array.shape().to_vec(),
        data: array.iter().copied().collect(),
    })))
}

fn attribute<'a>(node: &'a NodeProto, name: &str) -> Option<&'a tract_onnx::pb::AttributeProto> {
    node.attribute.iter().find(|a| a.name == name)
}

fn int_attribute(node: &NodeProto, name: &str, default: i64) -> i64 {
    attribute(node, name).map_or(default, |a| a.i)
}

fn ints_attribute(node: &NodeProto, name: &str) -> Option<Vec<i64>> {
    attribute(node, name).map(|a| a.ints.clone())
}

fn string_attribute(node: &NodeProto, name: &str, default: &str) -> String {
    attribute(node, name).map_or(default.to_string(), |a| {
        String::from_utf8_lossy(&a.s).into_owned()
    })
}

/// Reads the graph's nodes in order (ONNX stores them topologically sorted).
struct Builder {
    known: HashMap<String, Known>,
    steps: Vec<Step<RawConv>>,
    values: usize,
    /// Names that are initialisers of the file (not computed by a node).
    initializers: std::collections::HashSet<String>,
}

impl Builder {
    fn get(&self, node: &NodeProto, index: usize) -> Result<&Known, Unsupported> {
        let name = node.input.get(index).filter(|n| !n.is_empty());
        let Some(name) = name else {
            return unsupported(format!(
                "{} '{}': input {index} is missing",
                node.op_type, node.name
            ));
        };
        self.known.get(name).ok_or_else(|| {
            Unsupported(format!(
                "{} '{}': input '{name}' is neither a feature map nor a float constant",
                node.op_type, node.name
            ))
        })
    }

    fn map(&self, node: &NodeProto, index: usize) -> Result<(usize, usize, usize), Unsupported> {
        match self.get(node, index)? {
            Known::Map {
                slot,
                channels,
                scale,
            } => Ok((*slot, *channels, *scale)),
            Known::Constant(_) => unsupported(format!(
                "{} '{}': input {index} is a constant, not a feature map",
                node.op_type, node.name
            )),
        }
    }

    fn constant(&self, node: &NodeProto, index: usize) -> Result<Option<Constant>, Unsupported> {
        if node.input.get(index).is_none_or(|n| n.is_empty()) {
            return Ok(None);
        }
        match self.get(node, index)? {
            Known::Constant(c) => Ok(Some(c.clone())),
            Known::Map { .. } => unsupported(format!(
                "{} '{}': input {index} must be a constant",
                node.op_type, node.name
            )),
        }
    }

    fn scalar(&self, node: &NodeProto, index: usize, default: f32) -> Result<f32, Unsupported> {
        match self.constant(node, index)? {
            None => Ok(default),
            Some(Constant { data, .. }) if data.len() == 1 => Ok(data[0]),
            Some(_) => unsupported(format!(
                "{} '{}': input {index} is not a scalar",
                node.op_type, node.name
            )),
        }
    }

    /// Adds a step writing a new map named by the node's output.
    fn push(
        &mut self,
        node: &NodeProto,
        op: Op<RawConv>,
        inputs: Vec<usize>,
        channels: usize,
        scale: usize,
    ) {
        let output = self.values;
        self.values += 1;
        self.steps.push(Step { op, inputs, output });
        self.known.insert(
            node.output[0].clone(),
            Known::Map {
                slot: output,
                channels,
                scale,
            },
        );
    }

    fn alias(&mut self, node: &NodeProto) -> Result<(), Unsupported> {
        let input = self.get(node, 0)?.clone();
        self.known.insert(node.output[0].clone(), input);
        Ok(())
    }

    fn node(&mut self, node: &NodeProto) -> Result<(), Unsupported> {
        if !(node.domain.is_empty() || node.domain == "ai.onnx") || node.output.len() != 1 {
            return unsupported(format!(
                "operator {}::{} ('{}')",
                node.domain, node.op_type, node.name
            ));
        }
        let described = || format!("{} '{}'", node.op_type, node.name);
        match node.op_type.as_str() {
            "Constant" => {
                let value = attribute(node, "value").and_then(|a| a.t.as_ref());
                let known = match (value, attribute(node, "value_float")) {
                    (Some(t), _) => float_constant(t)?,
                    (None, Some(a)) => Some(Known::Constant(Constant {
                        shape: vec![],
                        data: vec![a.f],
                    })),
                    _ => None,
                };
                let Some(known) = known else {
                    return unsupported(format!("{}: not a float constant", described()));
                };
                self.known.insert(node.output[0].clone(), known);
            }
            "Identity" => self.alias(node)?,
            // Every map here is f32 already, and constants were read as f32.
            "Cast" if int_attribute(node, "to", 0) == DataType::Float as i64 => self.alias(node)?,
            "Conv" => {
                let (slot, channels, scale) = self.map(node, 0)?;
                let Some(Constant {
                    shape,
                    data: weights,
                }) = self.constant(node, 1)?
                else {
                    return unsupported(format!("{}: no weights", described()));
                };
                let bias = self.constant(node, 2)?.map(|b| b.data);
                let [cout, cin, kh, kw] = shape[..] else {
                    return unsupported(format!(
                        "{}: weights of shape {shape:?}, not 2-D",
                        described()
                    ));
                };
                let ones = |name: &str| {
                    ints_attribute(node, name).is_none_or(|v| v.iter().all(|&s| s == 1))
                };
                let same = [kh / 2, kw / 2, kh / 2, kw / 2].map(|p| p as i64).to_vec();
                let size_kept = kh % 2 == 1
                    && kw % 2 == 1
                    && ints_attribute(node, "pads").unwrap_or_else(|| vec![0; 4]) == same
                    && ints_attribute(node, "kernel_shape")
                        .is_none_or(|k| k == [kh as i64, kw as i64])
                    && string_attribute(node, "auto_pad", "NOTSET") == "NOTSET";
                if int_attribute(node, "group", 1) != 1
                    || !ones("strides")
                    || !ones("dilations")
                    || !size_kept
                {
                    return unsupported(format!(
                        "{}: only ungrouped stride-1 convolutions that keep the size",
                        described()
                    ));
                }
                if cin != channels || bias.as_ref().is_some_and(|b| b.len() != cout) {
                    return unsupported(format!(
                        "{}: {channels} channels in, weights for {cin}",
                        described()
                    ));
                }
                let initializer = |index: usize| {
                    node.input
                        .get(index)
                        .filter(|n| self.initializers.contains(*n))
                        .cloned()
                };
                let conv = RawConv {
                    shape: [cout, cin, kh, kw],
                    weights,
                    bias,
                    weights_name: initializer(1),
                    bias_name: initializer(2),
                };
                self.push(node, Op::Conv(conv, Vec::new()), vec![slot], cout, scale);
            }
            "Sigmoid" | "Relu" | "LeakyRelu" | "Clip" | "PRelu" => {
                let (slot, channels, scale) = self.map(node, 0)?;
                let op = match node.op_type.as_str() {
                    "Sigmoid" => PerTexel::Sigmoid,
                    "Relu" => PerTexel::Relu,
                    "LeakyRelu" => {
                        PerTexel::LeakyRelu(attribute(node, "alpha").map_or(0.01, |a| a.f))
                    }
                    "Clip" => {
                        // Opset 11 moved the bounds from attributes to inputs.
                        let bound = |index, name, default| match attribute(node, name) {
                            Some(a) => Ok(a.f),
                            None => self.scalar(node, index, default),
                        };
                        PerTexel::Clip(
                            bound(1, "min", f32::NEG_INFINITY)?,
                            bound(2, "max", f32::INFINITY)?,
                        )
                    }
                    _ => {
                        let Some(Constant { shape, data: slope }) = self.constant(node, 1)? else {
                            return unsupported(format!("{}: no slope", described()));
                        };
                        PerTexel::PRelu(per_channel(&shape, slope, channels).ok_or_else(|| {
                            Unsupported(format!("{}: a slope of shape {shape:?}", described()))
                        })?)
                    }
                };
                self.push(node, Op::PerTexel(vec![op]), vec![slot], channels, scale);
            }
            "Add" | "Sub" | "Mul" | "Div" => {
                let arith = match node.op_type.as_str() {
                    "Add" => Arith::Add,
                    "Sub" => Arith::Sub,
                    "Mul" => Arith::Mul,
                    _ => Arith::Div,
                };
                match (self.get(node, 0)?.clone(), self.get(node, 1)?.clone()) {
                    (
                        Known::Map {
                            slot: a,
                            channels,
                            scale,
                        },
                        Known::Map {
                            slot: b,
                            channels: cb,
                            scale: sb,
                        },
                    ) => {
                        if (channels, scale) != (cb, sb) {
                            return unsupported(format!(
                                "{}: maps of different shapes",
                                described()
                            ));
                        }
                        self.push(node, Op::Arith(arith), vec![a, b], channels, scale);
                    }
                    (
                        Known::Map {
                            slot,
                            channels,
                            scale,
                        },
                        Known::Constant(Constant { shape, data }),
                    )
                    | (
                        Known::Constant(Constant { shape, data }),
                        Known::Map {
                            slot,
                            channels,
                            scale,
                        },
                    ) => {
                        let constant_first = matches!(self.get(node, 0)?, Known::Constant(_));
                        let constant = per_channel(&shape, data, channels).ok_or_else(|| {
                            Unsupported(format!("{}: a constant of shape {shape:?}", described()))
                        })?;
                        let op = PerTexel::Constant {
                            arith,
                            constant,
                            constant_first,
                        };
                        self.push(node, Op::PerTexel(vec![op]), vec![slot], channels, scale);
                    }
                    _ => return unsupported(format!("{}: arithmetic on constants", described())),
                }
            }
            "Concat" if matches!(int_attribute(node, "axis", 0), 1 | -3) => {
                let parts = (0..node.input.len())
                    .map(|i| self.map(node, i))
                    .collect::<Result<Vec<_>, _>>()?;
                if parts.iter().any(|p| p.2 != parts[0].2) {
                    return unsupported(format!("{}: maps of different sizes", described()));
                }
                let channels = parts.iter().map(|p| p.1).sum();
                let slots = parts.iter().map(|p| p.0).collect();
                self.push(node, Op::Concat, slots, channels, parts[0].2);
            }
            "DepthToSpace" => {
                let (slot, channels, scale) = self.map(node, 0)?;
                let block = int_attribute(node, "blocksize", 0).max(0) as usize;
                let mode = string_attribute(node, "mode", "DCR");
                if block == 0
                    || channels % (block * block) != 0
                    || !matches!(mode.as_str(), "CRD" | "DCR")
                {
                    return unsupported(format!(
                        "{}: block {block}, mode {mode}, {channels} channels",
                        described()
                    ));
                }
                let op = Op::DepthToSpace {
                    block,
                    crd: mode == "CRD",
                };
                self.push(
                    node,
                    op,
                    vec![slot],
                    channels / (block * block),
                    scale * block,
                );
            }
            "Resize" => {
                let (slot, channels, scale) = self.map(node, 0)?;
                let nearest_floor = string_attribute(node, "mode", "nearest") == "nearest"
                    && string_attribute(node, "coordinate_transformation_mode", "half_pixel")
                        == "asymmetric"
                    && string_attribute(node, "nearest_mode", "round_prefer_floor") == "floor";
                // Opset 10 has (X, scales); later (X, roi, scales, sizes).
                let scales = self.constant(node, if node.input.len() == 2 { 1 } else { 2 })?;
                let factor = match scales {
                    Some(Constant { data: s, .. })
                        if s.len() == 4
                            && s[0] == 1.0
                            && s[1] == 1.0
                            && s[2] == s[3]
                            && s[2].fract() == 0.0
                            && s[2] >= 1.0 =>
                    {
                        s[2] as usize
                    }
                    _ => 0,
                };
                if !nearest_floor || factor == 0 {
                    return unsupported(format!(
                        "{}: only nearest (asymmetric, floor) by one integer factor given as scales",
                        described()
                    ));
                }
                self.push(
                    node,
                    Op::ResizeNearest(factor),
                    vec![slot],
                    channels,
                    scale * factor,
                );
            }
            other => return unsupported(format!("operator {other} ('{}')", node.name)),
        }
        Ok(())
    }
}

/// The graph's inputs fed at run time (older files list the initialisers among the inputs
/// too).
pub(super) fn data_inputs(graph: &GraphProto) -> impl Iterator<Item = &ValueInfoProto> {
    graph
        .input
        .iter()
        .filter(|i| !graph.initializer.iter().any(|t| t.name == i.name))
}

/// A constant that broadcasts over an NCHW map of `channels` channels as one value per
/// channel (shape […, C, 1, 1]) or one value in all.
fn per_channel(shape: &[usize], data: Vec<f32>, channels: usize) -> Option<Vec<f32>> {
    if data.len() == 1 {
        return Some(data);
    }
    let mut aligned = vec![1; 4usize.saturating_sub(shape.len())];
    aligned.extend_from_slice(shape);
    (aligned.len() == 4
        && aligned[0] == 1
        && aligned[1] == channels
        && aligned[2] == 1
        && aligned[3] == 1)
        .then_some(data)
}

impl Graph {
    /// The graph of `model` if every operator in it runs here.
    pub fn from_model(model: &ModelProto) -> Result<Graph, Unsupported> {
        let Some(graph) = &model.graph else {
            return unsupported("no graph");
        };
        let mut builder = Builder {
            known: HashMap::new(),
            steps: Vec::new(),
            values: 1,
            initializers: graph.initializer.iter().map(|t| t.name.clone()).collect(),
        };
        for t in &graph.initializer {
            if let Some(constant) = float_constant(t)? {
                builder.known.insert(t.name.clone(), constant);
            }
        }
        let inputs: Vec<&str> = data_inputs(graph).map(|i| i.name.as_str()).collect();
        let ([input], [output]) = (&inputs[..], &graph.output[..]) else {
            return unsupported("not one input and one output");
        };
        builder.known.insert(
            input.to_string(),
            Known::Map {
                slot: 0,
                channels: 3,
                scale: 1,
            },
        );
        for node in &graph.node {
            builder.node(node)?;
        }
        let output = match builder.known.get(&output.name) {
            Some(Known::Map {
                slot, channels: 3, ..
            }) => *slot,
            _ => return unsupported("the output is not a 3-channel map of the input"),
        };
        Ok(Graph {
            steps: fuse(builder.steps, output),
            values: builder.values,
            output,
        })
    }
}

impl ConvNet {
    /// The graph of `model` if every operator in it runs here.
    pub fn from_model(model: &ModelProto) -> Result<ConvNet, Unsupported> {
        let graph = Graph::from_model(model)?;
        let steps: Vec<Step<Conv>> = graph
            .steps
            .into_iter()
            .map(|step| Step {
                op: match step.op {
                    Op::Conv(c, then) => {
                        Op::Conv(Conv::new(&c.weights, c.bias.as_deref(), c.shape), then)
                    }
                    Op::PerTexel(chain) => Op::PerTexel(chain),
                    Op::Arith(a) => Op::Arith(a),
                    Op::Concat => Op::Concat,
                    Op::DepthToSpace { block, crd } => Op::DepthToSpace { block, crd },
                    Op::ResizeNearest(f) => Op::ResizeNearest(f),
                },
                inputs: step.inputs,
                output: step.output,
            })
            .collect();
        Ok(ConvNet {
            last_use: last_uses(&steps, graph.values, graph.output),
            steps,
            output: graph.output,
        })
    }

    /// Runs the network on one RGB image, convolutions padding as `padding` says.
    pub fn run(&self, input: Features, padding: Padding) -> Features {
        let mut values: Vec<Option<Features>> = vec![None; self.last_use.len()];
        values[0] = Some(input);
        for (i, step) in self.steps.iter().enumerate() {
            let input = |k: usize| written(&values, step.inputs[k]);
            let out = match &step.op {
                Op::Conv(conv, then) => conv.apply(input(0), padding, then),
                Op::Concat => nhwc::concat(&(0..step.inputs.len()).map(input).collect::<Vec<_>>()),
                Op::DepthToSpace { block, crd } => nhwc::depth_to_space(input(0), *block, *crd),
                Op::ResizeNearest(factor) => nhwc::resize_nearest(input(0), *factor),
                Op::PerTexel(chain) => {
                    let mut x = self.first_input(&mut values, i);
                    nhwc::per_texel(chain, &mut x);
                    x
                }
                Op::Arith(arith) => {
                    let mut x = self.first_input(&mut values, i);
                    let b = written(&values, step.inputs[1]);
                    nhwc::arith_in_place(&mut x.data, &b.data, *arith);
                    x
                }
            };
            values[step.output] = Some(out);
            for &v in &step.inputs {
                if self.last_use[v] == i {
                    values[v] = None;
                }
            }
        }
        values[self.output].take().expect("the output is computed")
    }

    /// Step `i`'s first input, to be written in place: taken when no later step reads it
    /// (and the step reads it only once), else a copy.
    fn first_input(&self, values: &mut [Option<Features>], i: usize) -> Features {
        let inputs = &self.steps[i].inputs;
        let v = inputs[0];
        if self.last_use[v] == i && !inputs[1..].contains(&v) {
            values[v]
                .take()
                .expect("values are written before they are read")
        } else {
            written(values, v).clone()
        }
    }
}

/// Per value slot, the index of the last step that reads it (then its memory can go); the
/// output's is `usize::MAX`.
pub(super) fn last_uses<C>(steps: &[Step<C>], values: usize, output: usize) -> Vec<usize> {
    let mut last_use = vec![0; values];
    for (i, step) in steps.iter().enumerate() {
        for &v in &step.inputs {
            last_use[v] = i;
        }
    }
    last_use[output] = usize::MAX;
    last_use
}

fn written(values: &[Option<Features>], v: usize) -> &Features {
    values[v]
        .as_ref()
        .expect("values are written before they are read")
}

/// Fuses per-texel work into fewer passes over memory:
/// - `x · sigmoid(x)` (a `Mul` of a map and its own sigmoid) becomes one SiLU;
/// - per-texel steps whose input nothing else reads join the step that made it: a
///   convolution applies them to its output rows while they are in cache, and chains merge.
fn fuse<C>(mut steps: Vec<Step<C>>, output: usize) -> Vec<Step<C>> {
    let readers = |steps: &[Step<C>], v: usize| {
        steps.iter().filter(|s| s.inputs.contains(&v)).count() + usize::from(v == output)
    };
    let producer = |steps: &[Step<C>], v: usize| steps.iter().position(|s| s.output == v);
    // SiLU.
    for i in 0..steps.len() {
        let Op::Arith(Arith::Mul) = steps[i].op else {
            continue;
        };
        for (x, s) in [(0, 1), (1, 0)] {
            let (x, s) = (steps[i].inputs[x], steps[i].inputs[s]);
            let sigmoid_of_x = producer(&steps, s).is_some_and(|p| {
                matches!(&steps[p].op, Op::PerTexel(c) if c[..] == [PerTexel::Sigmoid])
                    && steps[p].inputs == [x]
            });
            if sigmoid_of_x && readers(&steps, s) == 1 {
                steps[i].op = Op::PerTexel(vec![PerTexel::Silu]);
                steps[i].inputs = vec![x];
                break;
            }
        }
    }
    // Steps whose output nobody reads any more (the sigmoids SiLU replaced).
    while let Some(dead) = (0..steps.len()).find(|&i| readers(&steps, steps[i].output) == 0) {
        steps.remove(dead);
    }
    // Chains into their producers.
    let mut i = 0;
    while i < steps.len() {
        let fusable = match (&steps[i].op, producer(&steps, steps[i].inputs[0])) {
            (Op::PerTexel(_), Some(p)) => {
                readers(&steps, steps[i].inputs[0]) == 1
                    && matches!(steps[p].op, Op::Conv(..) | Op::PerTexel(_))
            }
            _ => false,
        };
        if !fusable {
            i += 1;
            continue;
        }
        let step = steps.remove(i);
        let Op::PerTexel(chain) = step.op else {
            unreachable!("only per-texel steps are fused");
        };
        let p = producer(&steps, step.inputs[0]).expect("checked above");
        match &mut steps[p].op {
            Op::Conv(_, then) | Op::PerTexel(then) => then.extend(chain),
            _ => unreachable!("checked above"),
        }
        steps[p].output = step.output;
    }
    steps
}

#[cfg(test)]
mod tests {
    use super::*;

    fn graph(nodes: Vec<NodeProto>, output: &str) -> ModelProto {
        let value = |name: &str| ValueInfoProto {
            name: name.into(),
            ..Default::default()
        };
        ModelProto {
            graph: Some(GraphProto {
                node: nodes,
                input: vec![value("x")],
                output: vec![value(output)],
                ..Default::default()
            }),
            ..Default::default()
        }
    }

    fn node(op: &str, inputs: &[&str], output: &str) -> NodeProto {
        NodeProto {
            op_type: op.into(),
            input: inputs.iter().map(|s| s.to_string()).collect(),
            output: vec![output.into()],
            ..Default::default()
        }
    }

    #[test]
    fn a_map_read_twice_by_one_step_is_not_taken_from_under_it() {
        // y = x·x, then z = y + x (x read after the square, y read once).
        let net = ConvNet::from_model(&graph(
            vec![node("Mul", &["x", "x"], "y"), node("Add", &["y", "x"], "z")],
            "z",
        ))
        .unwrap();
        let x = Features {
            height: 1,
            width: 2,
            channels: 3,
            data: vec![1.0, 2.0, 3.0, -1.0, 0.5, 0.0],
        };
        let z = net.run(x.clone(), Padding::Zero);
        let want: Vec<f32> = x.data.iter().map(|v| v * v + v).collect();
        assert_eq!(z.data, want);
        // And x·x alone, x read only there.
        let square = ConvNet::from_model(&graph(vec![node("Mul", &["x", "x"], "y")], "y")).unwrap();
        let y = square.run(x.clone(), Padding::Zero);
        assert_eq!(y.data, x.data.iter().map(|v| v * v).collect::<Vec<_>>());
    }

    #[test]
    fn silu_is_fused_into_the_convolution_and_unknown_operators_are_named() {
        let mut conv = node("Conv", &["x", "w"], "c");
        conv.attribute.push(tract_onnx::pb::AttributeProto {
            name: "pads".into(),
            ints: vec![1, 1, 1, 1],
            ..Default::default()
        });
        let mut model = graph(
            vec![
                conv,
                node("Sigmoid", &["c"], "s"),
                node("Mul", &["c", "s"], "y"),
            ],
            "y",
        );
        let weights = TensorProto {
            name: "w".into(),
            dims: vec![3, 3, 3, 3],
            data_type: DataType::Float as i32,
            float_data: (0..81).map(|k| (k % 7) as f32 / 10.0 - 0.3).collect(),
            ..Default::default()
        };
        model.graph.as_mut().unwrap().initializer.push(weights);
        let net = ConvNet::from_model(&model).unwrap();
        assert_eq!(net.steps.len(), 1);
        assert!(matches!(&net.steps[0].op, Op::Conv(_, then) if then[..] == [PerTexel::Silu]));

        model.graph.as_mut().unwrap().node[1].op_type = "Softplus".into();
        let e = ConvNet::from_model(&model).unwrap_err().to_string();
        assert!(e.contains("operator Softplus"), "{e}");
    }
}
