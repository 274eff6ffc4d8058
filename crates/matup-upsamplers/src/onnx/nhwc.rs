//! The operations of [`super::convnet`] on one image's feature maps, stored texel-major
//! (NHWC): a texel's channels are adjacent, so a "same" convolution is a few matrix products
//! over shifted views of the padded input, with no im2col copy (see [`super::conv::Conv`]).

use rayon::prelude::*;

use matup_simd::denormals::flushing_denormals;
use matup_simd::simd::fast_exp;
use matup_simd::with_avx2;

/// `height × width` texels of `channels` values each, texel-major.
#[derive(Clone, Debug, PartialEq)]
pub struct Features {
    pub height: usize,
    pub width: usize,
    pub channels: usize,
    pub data: Vec<f32>,
}

/// What a convolution reads outside the image.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Padding {
    /// Zeros, as ONNX specifies.
    Zero,
    /// The image repeats. For a network of stride-1 convolutions and per-texel operations this
    /// gives exactly what tiles of an endlessly repeated image would give, with no context.
    Wrap,
}

/// Elements per parallel chunk of the per-texel operations (a multiple of any channel count
/// is used).
const CHUNK: usize = 1 << 14;

/// Arithmetic between two values.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Arith {
    Add,
    Sub,
    Mul,
    Div,
}

/// An operation on each value of a map on its own (its channel aside).
#[derive(Clone, Debug, PartialEq)]
pub enum PerTexel {
    Sigmoid,
    /// x · sigmoid(x).
    Silu,
    Relu,
    LeakyRelu(f32),
    Clip(f32, f32),
    /// Negative values times a slope per channel (one value: every channel).
    PRelu(Vec<f32>),
    /// Arithmetic with a constant per channel (one value: every channel), the constant first
    /// when `constant_first` (as in `c − x`).
    Constant {
        arith: Arith,
        constant: Vec<f32>,
        constant_first: bool,
    },
}

impl PerTexel {
    /// Applies the operation to whole texels of `channels` values.
    pub(super) fn apply(&self, data: &mut [f32], channels: usize) {
        with_avx2!(apply_per_texel(self, data, channels))
    }
}

/// [`PerTexel::apply`]. Each case is a plain loop over the slice, so that it vectorises.
#[inline(always)]
fn apply_per_texel(op: &PerTexel, data: &mut [f32], channels: usize) {
    let c = channels;
    match op {
        PerTexel::Sigmoid => data.iter_mut().for_each(|v| *v = sigmoid(*v)),
        PerTexel::Silu => data.iter_mut().for_each(|v| *v *= sigmoid(*v)),
        PerTexel::Relu => data.iter_mut().for_each(|v| *v = v.max(0.0)),
        PerTexel::LeakyRelu(a) => data
            .iter_mut()
            .for_each(|v| *v = if *v < 0.0 { a * *v } else { *v }),
        PerTexel::Clip(lo, hi) => data.iter_mut().for_each(|v| *v = v.max(*lo).min(*hi)),
        PerTexel::PRelu(s) => with_per_channel(data, c, s, |v, s| if v < 0.0 { s * v } else { v }),
        // One loop per case, each without a branch inside.
        PerTexel::Constant {
            arith,
            constant: k,
            constant_first,
        } => match (arith, constant_first) {
            (Arith::Add, _) => with_per_channel(data, c, k, |v, k| v + k),
            (Arith::Mul, _) => with_per_channel(data, c, k, |v, k| v * k),
            (Arith::Sub, false) => with_per_channel(data, c, k, |v, k| v - k),
            (Arith::Sub, true) => with_per_channel(data, c, k, |v, k| k - v),
            (Arith::Div, false) => with_per_channel(data, c, k, |v, k| v / k),
            (Arith::Div, true) => with_per_channel(data, c, k, |v, k| k / v),
        },
    }
}

/// `v = f(v, values[channel])` over whole texels of `channels` values (one value: every
/// channel).
#[inline(always)]
fn with_per_channel(
    data: &mut [f32],
    channels: usize,
    values: &[f32],
    f: impl Fn(f32, f32) -> f32,
) {
    if let [k] = values {
        data.iter_mut().for_each(|v| *v = f(*v, *k));
    } else {
        debug_assert_eq!(values.len(), channels);
        for texel in data.chunks_exact_mut(channels) {
            texel
                .iter_mut()
                .zip(values)
                .for_each(|(v, k)| *v = f(*v, *k));
        }
    }
}

/// Applies `chain` in order to a map's values, a cache-sized chunk at a time, in parallel.
pub fn per_texel(chain: &[PerTexel], x: &mut Features) {
    let c = x.channels;
    x.data
        .par_chunks_mut(CHUNK.div_ceil(c) * c)
        .for_each(|chunk| chain.iter().for_each(|op| op.apply(chunk, c)));
}

/// `a[i] = arith(a[i], b[i])` for maps of one shape, in parallel chunks.
pub fn arith_in_place(a: &mut [f32], b: &[f32], arith: Arith) {
    fn zip(a: &mut [f32], b: &[f32], f: impl Fn(f32, f32) -> f32 + Sync) {
        a.par_chunks_mut(CHUNK)
            .zip(b.par_chunks(CHUNK))
            .for_each(|(a, b)| a.iter_mut().zip(b).for_each(|(a, b)| *a = f(*a, *b)));
    }
    // One loop per case, each without a branch inside.
    match arith {
        Arith::Add => zip(a, b, |a, b| a + b),
        Arith::Sub => zip(a, b, |a, b| a - b),
        Arith::Mul => zip(a, b, |a, b| a * b),
        Arith::Div => zip(a, b, |a, b| a / b),
    }
}

/// The logistic function 1 / (1 + e^−x).
#[inline(always)]
pub fn sigmoid(x: f32) -> f32 {
    1.0 / (1.0 + fast_exp(-x))
}

/// A `height × width × channels` map computed in parallel blocks of `rows_per_block` rows:
/// `compute(scratch, first row, block)` fills a block (each thread keeps its own scratch),
/// then `then` runs on it while it is in cache.
pub(super) fn in_row_blocks<S: Default + Send>(
    height: usize,
    width: usize,
    channels: usize,
    rows_per_block: usize,
    then: &[PerTexel],
    compute: impl Fn(&mut S, usize, &mut [f32]) + Sync,
) -> Features {
    let mut data = vec![0.0; height * width * channels];
    data.par_chunks_mut(rows_per_block * width * channels)
        .enumerate()
        .for_each_init(S::default, |scratch, (block, out)| {
            flushing_denormals(|| {
                compute(scratch, block * rows_per_block, out);
                then.iter().for_each(|op| op.apply(out, channels));
            })
        });
    Features {
        height,
        width,
        channels,
        data,
    }
}

/// `x` with `rows.0` rows above, `rows.1` below, `columns.0` columns left and `columns.1`
/// right, read as `padding` says.
pub(super) fn pad(
    x: &Features,
    rows: (usize, usize),
    columns: (usize, usize),
    padding: Padding,
) -> Vec<f32> {
    let (h, w, c) = (x.height, x.width, x.channels);
    let (py, px) = (rows.0, columns.0);
    let pw = w + columns.0 + columns.1;
    let mut out = vec![0.0; (h + rows.0 + rows.1) * pw * c];
    let source = |i: usize, n: usize, p: usize| -> Option<usize> {
        let i = i as isize - p as isize;
        match padding {
            Padding::Zero => (0..n as isize).contains(&i).then_some(i as usize),
            Padding::Wrap => Some(i.rem_euclid(n as isize) as usize),
        }
    };
    for (row, dst) in out.chunks_exact_mut(pw * c).enumerate() {
        let Some(y) = source(row, h, py) else {
            continue;
        };
        let line = &x.data[y * w * c..(y + 1) * w * c];
        dst[px * c..(px + w) * c].copy_from_slice(line);
        for col in (0..px).chain(px + w..pw) {
            if let Some(sx) = source(col, w, px) {
                dst[col * c..(col + 1) * c].copy_from_slice(&line[sx * c..(sx + 1) * c]);
            }
        }
    }
    out
}

/// ONNX DepthToSpace: `block² · c` channels become `c` channels on a `block`-times finer grid.
/// Output channel `k` of sub-texel (i, j) reads input channel `k·block² + i·block + j` in
/// `crd` mode (PyTorch's PixelShuffle), `(i·block + j)·c + k` in DCR mode.
pub fn depth_to_space(x: &Features, block: usize, crd: bool) -> Features {
    let c = x.channels / (block * block);
    let (h, w) = (x.height * block, x.width * block);
    let mut data = vec![0.0; h * w * c];
    data.par_chunks_mut(w * c).enumerate().for_each(|(y, row)| {
        let (sy, i) = (y / block, y % block);
        for (xo, texel) in row.chunks_exact_mut(c).enumerate() {
            let (sx, j) = (xo / block, xo % block);
            let src = &x.data[(sy * x.width + sx) * x.channels..][..x.channels];
            for (k, v) in texel.iter_mut().enumerate() {
                let channel = if crd {
                    (k * block + i) * block + j
                } else {
                    (i * block + j) * c + k
                };
                *v = src[channel];
            }
        }
    });
    Features {
        height: h,
        width: w,
        channels: c,
        data,
    }
}

/// Nearest-neighbour upsampling by an integer `factor` (ONNX Resize, `nearest`,
/// `asymmetric` coordinates, `floor`): output texel (y, x) is input texel (y / f, x / f).
pub fn resize_nearest(x: &Features, factor: usize) -> Features {
    let c = x.channels;
    let (h, w) = (x.height * factor, x.width * factor);
    let mut data = vec![0.0; h * w * c];
    data.par_chunks_mut(w * c).enumerate().for_each(|(y, row)| {
        let line = &x.data[(y / factor) * x.width * c..][..x.width * c];
        for (xo, texel) in row.chunks_exact_mut(c).enumerate() {
            texel.copy_from_slice(&line[(xo / factor) * c..][..c]);
        }
    });
    Features {
        height: h,
        width: w,
        channels: c,
        data,
    }
}

/// The maps' channels side by side (ONNX Concat on the channel axis).
pub fn concat(parts: &[&Features]) -> Features {
    let (h, w) = (parts[0].height, parts[0].width);
    let c: usize = parts.iter().map(|p| p.channels).sum();
    let mut data = Vec::with_capacity(h * w * c);
    for t in 0..h * w {
        for p in parts {
            data.extend_from_slice(&p.data[t * p.channels..(t + 1) * p.channels]);
        }
    }
    Features {
        height: h,
        width: w,
        channels: c,
        data,
    }
}

#[cfg(test)]
mod tests {
    use super::super::conv::Conv;
    use super::*;

    fn pseudo_random(n: usize, seed: u32) -> Vec<f32> {
        let mut s = seed.wrapping_mul(2_654_435_761).max(1);
        (0..n)
            .map(|_| {
                s ^= s << 13;
                s ^= s >> 17;
                s ^= s << 5;
                (s % 2001) as f32 / 1000.0 - 1.0
            })
            .collect()
    }

    /// The convolution written from its definition.
    fn direct(x: &Features, w: &[f32], b: &[f32], shape: [usize; 4], padding: Padding) -> Vec<f32> {
        let [cout, cin, kh, kw] = shape;
        let (h, wd) = (x.height as isize, x.width as isize);
        let mut out = vec![0.0; x.height * x.width * cout];
        for y in 0..h {
            for xx in 0..wd {
                for co in 0..cout {
                    let mut s = b[co];
                    for ci in 0..cin {
                        for ky in 0..kh {
                            for kx in 0..kw {
                                let (mut sy, mut sx) = (
                                    y + ky as isize - kh as isize / 2,
                                    xx + kx as isize - kw as isize / 2,
                                );
                                if padding == Padding::Wrap {
                                    (sy, sx) = (sy.rem_euclid(h), sx.rem_euclid(wd));
                                } else if sy < 0 || sx < 0 || sy >= h || sx >= wd {
                                    continue;
                                }
                                s += w[((co * cin + ci) * kh + ky) * kw + kx]
                                    * x.data[((sy * wd + sx) as usize) * cin + ci];
                            }
                        }
                    }
                    out[((y * wd + xx) as usize) * cout + co] = s;
                }
            }
        }
        out
    }

    #[test]
    fn convolution_matches_its_definition() {
        // Kernels of 3², 1² and 5×3, zero and wrap padding, an image whose rows do not fill
        // the last block, and fewer rows than the padding needs to wrap twice.
        for (shape, (h, w)) in [
            ([5, 4, 3, 3], (19, 7)),
            ([6, 7, 1, 1], (9, 11)),
            ([3, 2, 5, 3], (4, 6)),
            ([2, 3, 3, 3], (1, 1)),
            // Winograd: odd and even sizes, one block, several parallel chunks.
            ([16, 8, 3, 3], (7, 9)),
            ([8, 16, 3, 3], (1, 1)),
            ([8, 8, 3, 3], (40, 33)),
        ] {
            let [cout, cin, kh, kw] = shape;
            let x = Features {
                height: h,
                width: w,
                channels: cin,
                data: pseudo_random(h * w * cin, 1),
            };
            let weights = pseudo_random(cout * cin * kh * kw, 2);
            let bias = pseudo_random(cout, 3);
            let conv = Conv::new(&weights, Some(&bias), shape);
            for padding in [Padding::Zero, Padding::Wrap] {
                let got = conv.apply(&x, padding, &[PerTexel::Relu]);
                let want = direct(&x, &weights, &bias, shape, padding)
                    .into_iter()
                    .map(|v| v.max(0.0));
                let err = got
                    .data
                    .iter()
                    .zip(want)
                    .map(|(a, b)| (a - b).abs())
                    .fold(0.0f32, f32::max);
                assert!(err < 1e-5, "{shape:?} {h}×{w} {padding:?}: {err}");
            }
        }
    }

    #[test]
    fn fast_sigmoid_matches_the_exact_one() {
        let mut worst = 0.0f32;
        for k in -200_000..=200_000 {
            let x = k as f32 * 1e-4;
            let exact = 1.0 / (1.0 + (-x as f64).exp());
            worst = worst.max((sigmoid(x) as f64 - exact).abs() as f32);
        }
        assert!(worst < 3e-7, "{worst}");
        assert!((0.0..1e-37).contains(&sigmoid(-1000.0)));
        assert_eq!(sigmoid(1000.0), 1.0);
    }

    #[test]
    fn depth_to_space_and_nearest_resize_place_texels_as_onnx_says() {
        // 2×1 texels of 2²·2 channels, channel k of texel x holding 10·x + k.
        let x = Features {
            height: 1,
            width: 2,
            channels: 8,
            data: (0..2)
                .flat_map(|t| (0..8).map(move |k| (10 * t + k) as f32))
                .collect(),
        };
        let crd = depth_to_space(&x, 2, true);
        let dcr = depth_to_space(&x, 2, false);
        assert_eq!((crd.height, crd.width, crd.channels), (2, 4, 2));
        // Output (y, x, c): CRD reads channel c·4 + (y % 2)·2 + x % 2, DCR ((y%2)·2 + x%2)·2 + c.
        assert_eq!(crd.data[0..8], [0.0, 4.0, 1.0, 5.0, 10.0, 14.0, 11.0, 15.0]);
        assert_eq!(
            dcr.data[8..16],
            [4.0, 5.0, 6.0, 7.0, 14.0, 15.0, 16.0, 17.0]
        );
        let up = resize_nearest(&crd, 3);
        assert_eq!((up.height, up.width), (6, 12));
        assert_eq!(
            up.data[(5 * 12 + 11) * 2..][..2],
            crd.data[(4 + 3) * 2..][..2]
        );
        let both = concat(&[&crd, &dcr]);
        assert_eq!(
            both.data[4..8],
            [crd.data[2], crd.data[3], dcr.data[2], dcr.data[3]]
        );
    }
}
