//! The executor's convolutions: stride 1, size kept, run by Winograd's algorithm
//! ([`super::winograd`]) where the shape allows, else as matrix products over shifted views of
//! the padded input.

use matup_simd::gemm::gemm;

use super::nhwc::{in_row_blocks, pad, Features, Padding, PerTexel};
use super::winograd;

/// Output rows per parallel block of a convolution: its partial sums stay in cache.
const CONV_ROWS: usize = 8;

/// A stride-1 convolution that keeps the image size: an odd `kh × kw` kernel with
/// (k − 1) / 2 texels of padding on every side.
#[derive(Clone, Debug)]
pub struct Conv {
    kh: usize,
    kw: usize,
    cin: usize,
    cout: usize,
    kernel: Kernel,
    bias: Vec<f32>,
}

/// A convolution's weights, laid out for the algorithm that runs it.
#[derive(Clone, Debug)]
enum Kernel {
    /// Kernel row `ky` as a `(kw·cin) × cout` matrix, row `kx·cin + ci` ([`Conv::shifted`]).
    Shifted(Vec<f32>),
    /// For 3×3 convolutions between channel counts of whole lane groups.
    Winograd(winograd::Weights),
}

impl Conv {
    /// From ONNX's weights, laid out `[cout][cin][kh][kw]`, and an optional bias.
    pub fn new(onnx_weights: &[f32], bias: Option<&[f32]>, shape: [usize; 4]) -> Conv {
        let [cout, cin, kh, kw] = shape;
        assert_eq!(onnx_weights.len(), cout * cin * kh * kw);
        assert!(kh % 2 == 1 && kw % 2 == 1, "the kernel keeps the size");
        let kernel =
            if (kh, kw) == (3, 3) && cin % winograd::LANES == 0 && cout % winograd::LANES == 0 {
                Kernel::Winograd(winograd::Weights::new(onnx_weights, cout, cin))
            } else {
                let mut rows = vec![0.0; onnx_weights.len()];
                for co in 0..cout {
                    for ci in 0..cin {
                        for ky in 0..kh {
                            for kx in 0..kw {
                                rows[((ky * kw + kx) * cin + ci) * cout + co] =
                                    onnx_weights[((co * cin + ci) * kh + ky) * kw + kx];
                            }
                        }
                    }
                }
                Kernel::Shifted(rows)
            };
        Conv {
            kh,
            kw,
            cin,
            cout,
            kernel,
            bias: bias.map_or_else(|| vec![0.0; cout], <[f32]>::to_vec),
        }
    }

    /// The convolution of `x` (`cin` channels), then `then` on the output rows while they
    /// are in cache.
    pub fn apply(&self, x: &Features, padding: Padding, then: &[PerTexel]) -> Features {
        assert_eq!(x.channels, self.cin, "the input has the kernel's channels");
        match &self.kernel {
            Kernel::Winograd(weights) => weights.apply(x, &self.bias, padding, self.cout, then),
            Kernel::Shifted(rows) => self.shifted(rows, x, padding, then),
        }
    }

    /// The input is padded to `pw = width + kw − 1` texels per row. Output texel (y, x),
    /// counted over padded rows as p = y·pw + x, reads kernel row ky from the kw·cin
    /// consecutive values that start at padded texel p + ky·pw: a matrix whose rows are p with
    /// a stride of `cin` values. So kernel row ky is one matrix product of that (overlapping)
    /// view with the row's weights, accumulated over ky. The kw − 1 rows computed past each
    /// image row's end are thrown away.
    fn shifted(
        &self,
        weights: &[f32],
        x: &Features,
        padding: Padding,
        then: &[PerTexel],
    ) -> Features {
        let (h, w) = (x.height, x.width);
        let (py, px) = (self.kh / 2, self.kw / 2);
        let padded = pad(x, (py, py), (px, px), padding);
        let pw = w + 2 * px;
        let (cin, cout) = (self.cin, self.cout);
        let row_weights = self.kw * cin * cout;
        in_row_blocks(
            h,
            w,
            cout,
            CONV_ROWS,
            then,
            |sums: &mut Vec<f32>, y0, out| {
                let rows = out.len() / (w * cout);
                // Padded-row texels from the block's first output to its last.
                let m = (rows - 1) * pw + w;
                sums.resize(m * cout, 0.0);
                for ky in 0..self.kh {
                    gemm(
                        (m, self.kw * cin, cout),
                        &padded[(y0 + ky) * pw * cin..],
                        (cin, 1),
                        &weights[ky * row_weights..],
                        (cout, 1),
                        if ky == 0 { 0.0 } else { 1.0 },
                        sums,
                        cout,
                    );
                }
                for r in 0..rows {
                    for (dst, src) in out[r * w * cout..(r + 1) * w * cout]
                        .chunks_exact_mut(cout)
                        .zip(sums[r * pw * cout..].chunks_exact(cout))
                    {
                        for ((d, s), b) in dst.iter_mut().zip(src).zip(&self.bias) {
                            *d = s + b;
                        }
                    }
                }
            },
        )
    }
}
