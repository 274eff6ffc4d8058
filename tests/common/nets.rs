//! Small random networks with the operators, attributes and layouts of the SR networks matup
//! runs (SPAN: mean subtraction, ×255, convolutions with SiLU, sigmoid attention, a channel
//! concatenation, a pixel shuffle; Real-ESRGAN ×4plus: float16 weights cast to float, dense
//! blocks of leaky-ReLU convolutions, residuals scaled by 0.2, two nearest ×2 resizes), written
//! as ONNX files with their sidecars. Their weights are random: they test the executors and
//! the tiling, not the quality of an upsampler.

use std::path::{Path, PathBuf};

use prost::Message;
use rand::{Rng, SeedableRng};
use tract_onnx::pb::tensor_proto::DataType;
use tract_onnx::pb::tensor_shape_proto::{dimension::Value, Dimension};
use tract_onnx::pb::{
    type_proto, AttributeProto, GraphProto, ModelProto, NodeProto, OperatorSetIdProto, TensorProto,
    TensorShapeProto, TypeProto, ValueInfoProto,
};

/// A graph being built: nodes in order, initialisers, fresh names.
struct Builder {
    nodes: Vec<NodeProto>,
    initializers: Vec<TensorProto>,
    names: usize,
    rng: rand::rngs::StdRng,
    /// Weights stored as float16 and cast to float (as Real-ESRGAN's file does).
    half_weights: bool,
}

fn int_attribute(name: &str, value: i64) -> AttributeProto {
    AttributeProto {
        name: name.into(),
        r#type: 2, // INT
        i: value,
        ..Default::default()
    }
}

fn ints_attribute(name: &str, values: &[i64]) -> AttributeProto {
    AttributeProto {
        name: name.into(),
        r#type: 7, // INTS
        ints: values.to_vec(),
        ..Default::default()
    }
}

fn float_attribute(name: &str, value: f32) -> AttributeProto {
    AttributeProto {
        name: name.into(),
        r#type: 1, // FLOAT
        f: value,
        ..Default::default()
    }
}

fn string_attribute(name: &str, value: &str) -> AttributeProto {
    AttributeProto {
        name: name.into(),
        r#type: 3, // STRING
        s: value.as_bytes().to_vec(),
        ..Default::default()
    }
}

impl Builder {
    fn new(seed: u64, half_weights: bool) -> Builder {
        Builder {
            nodes: Vec::new(),
            initializers: Vec::new(),
            names: 0,
            rng: rand::rngs::StdRng::seed_from_u64(seed),
            half_weights,
        }
    }

    fn name(&mut self, what: &str) -> String {
        self.names += 1;
        format!("{what}_{}", self.names)
    }

    fn node(&mut self, op: &str, inputs: &[&str], attributes: Vec<AttributeProto>) -> String {
        let output = self.name(op);
        self.nodes.push(NodeProto {
            op_type: op.into(),
            name: output.clone(),
            input: inputs.iter().map(|s| s.to_string()).collect(),
            output: vec![output.clone()],
            attribute: attributes,
            ..Default::default()
        });
        output
    }

    /// A float initialiser.
    fn constant(&mut self, dims: &[i64], data: Vec<f32>) -> String {
        let name = self.name("constant");
        self.initializers.push(TensorProto {
            name: name.clone(),
            dims: dims.to_vec(),
            data_type: DataType::Float as i32,
            float_data: data,
            ..Default::default()
        });
        name
    }

    /// Weights: a float initialiser, or a float16 one cast to float.
    fn weights(&mut self, dims: &[i64], data: Vec<f32>) -> String {
        if !self.half_weights {
            return self.constant(dims, data);
        }
        let name = self.name("weights_f16");
        self.initializers.push(TensorProto {
            name: name.clone(),
            dims: dims.to_vec(),
            data_type: DataType::Float16 as i32,
            raw_data: data
                .iter()
                .flat_map(|&v| half::f16::from_f32(v).to_le_bytes())
                .collect(),
            ..Default::default()
        });
        self.node("Cast", &[&name], vec![int_attribute("to", 1)])
    }

    /// A 3×3 convolution that keeps the size, weights of standard deviation `gain / √(9·cin)`.
    fn conv(&mut self, x: &str, cin: usize, cout: usize, gain: f32, bias: f32) -> String {
        let spread = gain * (3.0 / (9.0 * cin as f32)).sqrt(); // uniform: σ = spread / √3
        let w: Vec<f32> = (0..cout * cin * 9)
            .map(|_| self.rng.random_range(-spread..spread))
            .collect();
        let b: Vec<f32> = (0..cout)
            .map(|_| bias + self.rng.random_range(-0.05..0.05))
            .collect();
        let w = self.weights(&[cout as i64, cin as i64, 3, 3], w);
        let b = self.weights(&[cout as i64], b);
        self.node(
            "Conv",
            &[x, &w, &b],
            vec![
                ints_attribute("dilations", &[1, 1]),
                ints_attribute("kernel_shape", &[3, 3]),
                ints_attribute("pads", &[1, 1, 1, 1]),
                ints_attribute("strides", &[1, 1]),
            ],
        )
    }

    fn silu(&mut self, x: &str) -> String {
        let s = self.node("Sigmoid", &[x], vec![]);
        self.node("Mul", &[x, &s], vec![])
    }

    fn leaky_relu(&mut self, x: &str) -> String {
        self.node("LeakyRelu", &[x], vec![float_attribute("alpha", 0.2)])
    }

    fn concat(&mut self, parts: &[&str]) -> String {
        self.node("Concat", parts, vec![int_attribute("axis", 1)])
    }

    fn scaled(&mut self, x: &str, by: f32) -> String {
        let c = self.constant(&[], vec![by]);
        self.node("Mul", &[x, &c], vec![])
    }

    /// `Clip(x, 0, 1)` then `Identity` into the graph's output, as both exports end.
    fn finish(mut self, x: &str) -> ModelProto {
        let lo = self.constant(&[], vec![0.0]);
        let hi = self.constant(&[], vec![1.0]);
        let clipped = self.node("Clip", &[x, &lo, &hi], vec![]);
        self.nodes.push(NodeProto {
            op_type: "Identity".into(),
            name: "output_identity".into(),
            input: vec![clipped],
            output: vec!["output".into()],
            ..Default::default()
        });
        let image = |name: &str| ValueInfoProto {
            name: name.into(),
            r#type: Some(TypeProto {
                value: Some(type_proto::Value::TensorType(type_proto::Tensor {
                    elem_type: DataType::Float as i32,
                    shape: Some(TensorShapeProto {
                        dim: ["batch", "3", "height", "width"]
                            .iter()
                            .map(|d| Dimension {
                                value: Some(match d.parse::<i64>() {
                                    Ok(v) => Value::DimValue(v),
                                    Err(_) => Value::DimParam(d.to_string()),
                                }),
                                ..Default::default()
                            })
                            .collect(),
                    }),
                })),
                ..Default::default()
            }),
            ..Default::default()
        };
        ModelProto {
            ir_version: 8,
            opset_import: vec![OperatorSetIdProto {
                domain: String::new(),
                version: 17,
            }],
            graph: Some(GraphProto {
                name: "matup-test-network".into(),
                node: self.nodes,
                initializer: self.initializers,
                input: vec![image("input")],
                output: vec![image("output")],
                ..Default::default()
            }),
            ..Default::default()
        }
    }
}

/// A SPAN ×`scale` of `channels` features and two attention blocks.
pub fn span(scale: usize, channels: usize, seed: u64) -> ModelProto {
    let mut g = Builder::new(seed, false);
    let mean = g.constant(&[1, 3, 1, 1], vec![0.4488, 0.4371, 0.4040]);
    let centred = g.node("Sub", &["input", &mean], vec![]);
    let scaled = g.scaled(&centred, 255.0);
    let first = g.conv(&scaled, 3, channels, 1.0 / 255.0, 0.0);
    let mut blocks = Vec::new();
    let mut x = first.clone();
    for _ in 0..2 {
        let c1 = g.conv(&x, channels, channels, 1.0, 0.0);
        let a1 = g.silu(&c1);
        let c2 = g.conv(&a1, channels, channels, 1.0, 0.0);
        let a2 = g.silu(&c2);
        let c3 = g.conv(&a2, channels, channels, 1.0, 0.0);
        let out = g.node("Add", &[&c3, &x], vec![]);
        let sig = g.node("Sigmoid", &[&c3], vec![]);
        let half = g.constant(&[], vec![0.5]);
        let attention = g.node("Sub", &[&sig, &half], vec![]);
        x = g.node("Mul", &[&out, &attention], vec![]);
        blocks.push(x.clone());
    }
    let last = g.conv(&x, channels, channels, 1.0, 0.0);
    let joined = g.concat(&[&first, &last, &blocks[0], &blocks[1]]);
    let fused = g.conv(&joined, 4 * channels, channels, 1.0, 0.0);
    let shuffled_channels = 3 * scale * scale;
    let up = g.conv(&fused, channels, shuffled_channels, 0.3, 0.5);
    let shuffled = g.node(
        "DepthToSpace",
        &[&up],
        vec![
            int_attribute("blocksize", scale as i64),
            string_attribute("mode", "CRD"),
        ],
    );
    g.finish(&shuffled)
}

/// A Real-ESRGAN ×4plus of `channels` features, `growth` channels per dense layer and one
/// residual-in-residual block.
pub fn realesrgan_x4(channels: usize, growth: usize, seed: u64) -> ModelProto {
    let mut g = Builder::new(seed, true);
    let first = g.conv("input", 3, channels, 1.0, 0.0);
    let mut x = first.clone();
    for _ in 0..2 {
        // A dense block: each layer reads the block's input and every layer before it.
        let mut parts = vec![x.clone()];
        for layer in 0..3 {
            let input = g.concat(&parts.iter().map(String::as_str).collect::<Vec<_>>());
            let cin = channels + layer * growth;
            let c = g.conv(&input, cin, growth, 1.0, 0.0);
            parts.push(g.leaky_relu(&c));
        }
        let input = g.concat(&parts.iter().map(String::as_str).collect::<Vec<_>>());
        let out = g.conv(&input, channels + 3 * growth, channels, 1.0, 0.0);
        let residual = g.scaled(&out, 0.2);
        x = g.node("Add", &[&residual, &x], vec![]);
    }
    let trunk = g.conv(&x, channels, channels, 1.0, 0.0);
    let mut x = g.node("Add", &[&trunk, &first], vec![]);
    for _ in 0..2 {
        let scales = g.constant(&[4], vec![1.0, 1.0, 2.0, 2.0]);
        let resized = g.node(
            "Resize",
            &[&x, "", &scales],
            vec![
                string_attribute("coordinate_transformation_mode", "asymmetric"),
                string_attribute("mode", "nearest"),
                string_attribute("nearest_mode", "floor"),
            ],
        );
        let c = g.conv(&resized, channels, channels, 1.0, 0.0);
        x = g.leaky_relu(&c);
    }
    let hr = g.conv(&x, channels, channels, 1.0, 0.0);
    let hr = g.leaky_relu(&hr);
    let last = g.conv(&hr, channels, 3, 0.3, 0.5);
    g.finish(&last)
}

/// Writes `model` as `dir/NAME.onnx` with a sidecar (×`scale`, `overlap` texels of context,
/// 64² tiles); returns the ONNX file's path.
pub fn write(dir: &Path, name: &str, model: &ModelProto, scale: usize, overlap: usize) -> PathBuf {
    let path = dir.join(format!("{name}.onnx"));
    std::fs::write(&path, model.encode_to_vec()).unwrap();
    std::fs::write(
        path.with_extension("toml"),
        format!(
            "description = \"a random network for matup's tests\"\nscale = {scale}\n\
             overlap = {overlap}\ntile = 64\n"
        ),
    )
    .unwrap();
    path
}
