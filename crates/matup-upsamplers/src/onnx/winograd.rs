//! 3×3 convolutions by Winograd's minimal filtering F(2×2, 3×3) (Lavin & Gray 2016, the
//! algorithm onnxruntime and ncnn use for them): each 2×2 block of outputs comes from a 4×4
//! block of inputs through 16 products instead of 36, so a layer is 16 matrix products of
//! (blocks × cin) by (cin × cout) between cheap transforms, 2.25× fewer multiply-adds than
//! direct convolution. In f32 the result differs from the direct sum by rounding only (the
//! transforms' coefficients are 0, ±1 and ±½).
//!
//! Channels are processed 8 at a time as `[f32; 8]` lanes, which the compiler vectorises.

use matup_simd::gemm::gemm;
use matup_simd::with_avx2;

use super::nhwc::{in_row_blocks, pad, Features, Padding, PerTexel};

/// Channels per lane group; Winograd is used where both channel counts are multiples of it.
pub const LANES: usize = 8;
/// Blocks per matrix product at least: enough rows for the products to run at full speed.
const MIN_BLOCKS: usize = 128;

type Lanes = [f32; LANES];

#[inline(always)]
fn load(s: &[f32], at: usize) -> Lanes {
    s[at..at + LANES].try_into().expect("a lane group")
}

#[inline(always)]
fn store(s: &mut [f32], at: usize, v: Lanes) {
    s[at..at + LANES].copy_from_slice(&v);
}

// Plain loops rather than `array::from_fn`, which is not always inlined (and so not
// compiled for AVX2 inside `with_avx2!`).
#[inline(always)]
fn add(mut a: Lanes, b: Lanes) -> Lanes {
    a.iter_mut().zip(b).for_each(|(a, b)| *a += b);
    a
}

#[inline(always)]
fn sub(mut a: Lanes, b: Lanes) -> Lanes {
    a.iter_mut().zip(b).for_each(|(a, b)| *a -= b);
    a
}

/// Bᵀ·d for four inputs along one axis.
#[inline(always)]
fn input_1d(d: [Lanes; 4]) -> [Lanes; 4] {
    [
        sub(d[0], d[2]),
        add(d[1], d[2]),
        sub(d[2], d[1]),
        sub(d[1], d[3]),
    ]
}

/// Aᵀ·m for four products along one axis.
#[inline(always)]
fn output_1d(m: [Lanes; 4]) -> [Lanes; 2] {
    [add(add(m[0], m[1]), m[2]), sub(sub(m[1], m[2]), m[3])]
}

/// The transformed kernel G·g·Gᵀ of a 3×3 convolution: 16 matrices `cin × cout`,
/// `[k][ci][co]`, k = 4·row + column of the 4×4 transformed kernel.
#[derive(Clone, Debug)]
pub struct Weights(Vec<f32>);

impl Weights {
    /// From ONNX's weights `[cout][cin][3][3]`.
    pub fn new(onnx_weights: &[f32], cout: usize, cin: usize) -> Weights {
        // G = [1 0 0; ½ ½ ½; ½ −½ ½; 0 0 1].
        let g = |a: [f32; 3]| {
            [
                a[0],
                (a[0] + a[1] + a[2]) / 2.0,
                (a[0] - a[1] + a[2]) / 2.0,
                a[2],
            ]
        };
        let mut u = vec![0.0; 16 * cin * cout];
        for co in 0..cout {
            for ci in 0..cin {
                let k = &onnx_weights[(co * cin + ci) * 9..][..9];
                // G·k (4×3), then (G·k)·Gᵀ (4×4).
                let columns: [[f32; 4]; 3] = std::array::from_fn(|x| g([k[x], k[3 + x], k[6 + x]]));
                for r in 0..4 {
                    let row = g([columns[0][r], columns[1][r], columns[2][r]]);
                    for (c, v) in row.into_iter().enumerate() {
                        u[((r * 4 + c) * cin + ci) * cout + co] = v;
                    }
                }
            }
        }
        Weights(u)
    }

    /// The convolution of `x` with this kernel (`cout` outputs) and `bias`, one texel of
    /// padding as `padding` says, then `then` on the output rows while they are in cache.
    pub fn apply(
        &self,
        x: &Features,
        bias: &[f32],
        padding: Padding,
        cout: usize,
        then: &[PerTexel],
    ) -> Features {
        let (h, w, cin) = (x.height, x.width, x.channels);
        let bw = w.div_ceil(2);
        // One texel around, and one more after an odd size so the last blocks are whole
        // (their extra outputs are thrown away).
        let padded = pad(x, (1, 1 + h % 2), (1, 1 + w % 2), padding);
        let pw = 2 * bw + 2;
        let block_rows = MIN_BLOCKS.div_ceil(bw);
        in_row_blocks(
            h,
            w,
            cout,
            2 * block_rows,
            then,
            |(v, m): &mut (Vec<f32>, Vec<f32>), y0, out| {
                let rows = out.len() / (w * cout);
                let blocks = rows.div_ceil(2) * bw;
                v.resize(blocks * 16 * cin, 0.0);
                m.resize(blocks * 16 * cout, 0.0);
                with_avx2!(input_transform(&padded, pw, cin, y0 / 2, bw, v));
                // M_k = V_k · U_k for each of the 16 positions.
                for k in 0..16 {
                    gemm(
                        (blocks, cin, cout),
                        &v[k * cin..],
                        (16 * cin, 1),
                        &self.0[k * cin * cout..],
                        (cout, 1),
                        0.0,
                        &mut m[k * cout..],
                        16 * cout,
                    );
                }
                with_avx2!(output_transform(m, bias, cout, bw, w, out));
            },
        )
    }
}

/// The four lane groups at `at`, `at + step`, `at + 2·step`, `at + 3·step`.
#[inline(always)]
fn four(s: &[f32], at: usize, step: usize) -> [Lanes; 4] {
    [
        load(s, at),
        load(s, at + step),
        load(s, at + 2 * step),
        load(s, at + 3 * step),
    ]
}

/// The 4×4 matrix `t` transposed.
#[inline(always)]
fn transpose(t: [[Lanes; 4]; 4]) -> [[Lanes; 4]; 4] {
    [
        [t[0][0], t[1][0], t[2][0], t[3][0]],
        [t[0][1], t[1][1], t[2][1], t[3][1]],
        [t[0][2], t[1][2], t[2][2], t[3][2]],
        [t[0][3], t[1][3], t[2][3], t[3][3]],
    ]
}

/// V = Bᵀ·d·B for each 4×4 input block of a chunk whose first block row is `by0`, stored
/// `[block][k][ci]` in `v` (`pw` padded texels per row, `bw` blocks per row).
#[inline(always)]
fn input_transform(padded: &[f32], pw: usize, cin: usize, by0: usize, bw: usize, v: &mut [f32]) {
    let row = pw * cin;
    for b in 0..v.len() / (16 * cin) {
        let (by, bx) = (by0 + b / bw, b % bw);
        for g in (0..cin).step_by(LANES) {
            // Column c of d, down its rows, then Bᵀ along them.
            let at = (2 * by * pw + 2 * bx) * cin + g;
            let t = [
                input_1d(four(padded, at, row)),
                input_1d(four(padded, at + cin, row)),
                input_1d(four(padded, at + 2 * cin, row)),
                input_1d(four(padded, at + 3 * cin, row)),
            ];
            // Now along each row of Bᵀ·d.
            let t = transpose(t);
            for (r, t) in t.into_iter().enumerate() {
                for (c, lanes) in input_1d(t).into_iter().enumerate() {
                    store(v, (b * 16 + r * 4 + c) * cin + g, lanes);
                }
            }
        }
    }
}

/// Y = Aᵀ·M·A + bias for each block of a chunk, written where it lands in the chunk's `out`
/// rows (`w` texels each; `bw` blocks per row).
#[inline(always)]
fn output_transform(m: &[f32], bias: &[f32], cout: usize, bw: usize, w: usize, out: &mut [f32]) {
    let rows = out.len() / (w * cout);
    for b in 0..m.len() / (16 * cout) {
        let (ry, bx) = (2 * (b / bw), b % bw);
        for g in (0..cout).step_by(LANES) {
            let bias = load(bias, g);
            // Column c of M, down its rows (4 products apart), then Aᵀ along them.
            let at = b * 16 * cout + g;
            let row = 4 * cout;
            let t = [
                output_1d(four(m, at, row)),
                output_1d(four(m, at + cout, row)),
                output_1d(four(m, at + 2 * cout, row)),
                output_1d(four(m, at + 3 * cout, row)),
            ];
            // Now along each of the two rows of Aᵀ·M.
            let t = [
                [t[0][0], t[1][0], t[2][0], t[3][0]],
                [t[0][1], t[1][1], t[2][1], t[3][1]],
            ];
            for (r, t) in t.into_iter().enumerate() {
                for (c, lanes) in output_1d(t).into_iter().enumerate() {
                    let (y, x) = (ry + r, 2 * bx + c);
                    if y < rows && x < w {
                        store(out, (y * w + x) * cout + g, add(lanes, bias));
                    }
                }
            }
        }
    }
}
