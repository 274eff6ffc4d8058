//! The filter's first layer, folded per sub-pixel phase, for inference. The layer reads an
//! N×N×C window of upsampled features; since upsampling is a fixed linear map per phase, its
//! weights fold into one K×K×C matrix per phase (≈ 8× fewer multiply-adds at N = 17, K = 6)
//! that serves every texel of the output. (Training reads the upsampled windows instead,
//! [`super::input`]: with weights that change every 128 texels, folding does not pay.)
//!
//! Layouts: weights `[dy][dx][c][h]`, folded weights `[a][b][c][h]` per phase (the transposed
//! K·K·C × H matrix, as the product wants it), windows `[a][b][c]`. Rows of C·H values are
//! the unit of every step, so no stage reorders single values.

use std::sync::Arc;

use rayon::prelude::*;

use super::geometry::WindowGeometry;
use matup_simd::gemm::product;

#[inline]
fn axpy(alpha: f32, x: &[f32], y: &mut [f32]) {
    for (y, x) in y.iter_mut().zip(x) {
        *y += alpha * x;
    }
}

/// Appends the row `Σ wt·x` over `terms` (`len` long, zeros where there are none) to `out`.
fn push_combination<'a>(
    out: &mut Vec<f32>,
    len: usize,
    terms: impl Iterator<Item = (f32, &'a [f32])>,
) {
    let start = out.len();
    out.resize(start + len, 0.0);
    for (wt, x) in terms {
        axpy(wt, x, &mut out[start..]);
    }
}

/// The first layer's shape.
#[derive(Clone, Debug)]
pub struct FoldedLayer {
    pub geometry: Arc<WindowGeometry>,
    /// Input channels C.
    pub channels: usize,
    /// Output width H.
    pub hidden: usize,
}

impl FoldedLayer {
    /// Number of weights (N·N·H·C).
    pub fn weight_len(&self) -> usize {
        self.geometry.window * self.geometry.window * self.hidden * self.channels
    }

    /// Length of one phase's folded matrix (H·K·K·C).
    fn folded_len(&self) -> usize {
        self.hidden * self.geometry.window_len(self.channels)
    }

    /// Folds `weights` (`[dy][dx][c][h]`) into one `[a][b][c][h]` matrix per phase.
    ///
    /// Every step is an axpy on rows of C·H values, ordered so each parallel task's working
    /// set (≈ 40 rows) stays in L2.
    pub fn fold(&self, weights: &[f32]) -> Vec<Vec<f32>> {
        let g = &self.geometry;
        let (n, k, s, row) = (g.window, g.taps, g.scale, self.hidden * self.channels);
        // Stage 1, per window row dy: T[px][b][dy] = Σ_dx Bx_px[dx][b] · W[dy][dx].
        let stage1: Vec<Vec<f32>> = (0..n)
            .into_par_iter()
            .map(|dy| {
                let w = &weights[dy * n * row..][..n * row];
                let mut out = Vec::with_capacity(s * k * row); // [px][b]
                for px in 0..s {
                    for b in 0..k {
                        let terms = g.axis.weights[px]
                            .iter()
                            .filter(|tap| tap.1 == b)
                            .map(|&(dx, _, wt)| (wt, &w[dx * row..][..row]));
                        push_combination(&mut out, row, terms);
                    }
                }
                out
            })
            .collect();
        // Stage 2, per (px, b): F[py, px][a][b] = Σ_dy By_py[dy][a] · T[px][b][dy].
        let stage2: Vec<Vec<f32>> = (0..s * k)
            .into_par_iter()
            .map(|pb| {
                let mut out = Vec::with_capacity(s * k * row); // [py][a]
                for py in 0..s {
                    for a in 0..k {
                        let terms = g.axis.weights[py]
                            .iter()
                            .filter(|tap| tap.1 == a)
                            .map(|&(dy, _, wt)| (wt, &stage1[dy][pb * row..][..row]));
                        push_combination(&mut out, row, terms);
                    }
                }
                out
            })
            .collect();
        (0..s * s)
            .map(|phase| {
                let (py, px) = (phase / s, phase % s);
                let mut out = Vec::with_capacity(self.folded_len());
                for a in 0..k {
                    for b in 0..k {
                        out.extend_from_slice(&stage2[px * k + b][(py * k + a) * row..][..row]);
                    }
                }
                out
            })
            .collect()
    }

    /// Texel indices of a batch grouped by phase.
    fn by_phase(&self, phases: &[usize]) -> Vec<Vec<usize>> {
        let mut groups = vec![Vec::new(); self.geometry.phases()];
        for (i, &p) in phases.iter().enumerate() {
            groups[p].push(i);
        }
        groups
    }

    /// The layer's output `[B][H]` for windows `[B][K·K·C]` of the given phases.
    pub fn apply(&self, folded: &[Vec<f32>], windows: &[f32], phases: &[usize]) -> Vec<f32> {
        let kkc = self.geometry.window_len(self.channels);
        let h = self.hidden;
        let groups = self.by_phase(phases);
        let results: Vec<(usize, Vec<f32>)> = groups
            .par_iter()
            .enumerate()
            .filter(|(_, g)| !g.is_empty())
            .map(|(phase, group)| {
                let mut x = Vec::with_capacity(group.len() * kkc);
                for &i in group {
                    x.extend_from_slice(&windows[i * kkc..][..kkc]);
                }
                // y (n×H) = x (n×KKC) · Fᵀ (KKC×H, row-major).
                let y = product((group.len(), kkc, h), &x, (kkc, 1), &folded[phase], (h, 1));
                (phase, y)
            })
            .collect();
        let mut out = vec![0f32; phases.len() * h];
        for (phase, y) in results {
            for (row, &i) in groups[phase].iter().enumerate() {
                out[i * h..][..h].copy_from_slice(&y[row * h..][..h]);
            }
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::filter::pseudo_random;
    use matup_core::resample::Kernel;

    fn layer() -> FoldedLayer {
        FoldedLayer {
            geometry: Arc::new(WindowGeometry::new(4, 5, Kernel::Bilinear)),
            channels: 2,
            hidden: 3,
        }
    }

    /// The folded layer equals the plain layer on the unfolded window.
    #[test]
    fn folded_layer_equals_the_plain_layer() {
        let l = layer();
        let g = &l.geometry;
        let (n, k, c, h) = (g.window, g.taps, l.channels, l.hidden);
        let weights = pseudo_random(l.weight_len(), 1);
        let folded = l.fold(&weights);
        for phase in 0..g.phases() {
            let (py, px) = (phase / 4, phase % 4);
            let window = pseudo_random(k * k * c, phase as u32);
            let out = l.apply(&folded, &window, &[phase]);
            for hh in 0..h {
                let mut want = 0.0;
                for &(dy, a, wy) in &g.axis.weights[py] {
                    for &(dx, b, wx) in &g.axis.weights[px] {
                        for cc in 0..c {
                            let w = weights[((dy * n + dx) * c + cc) * h + hh];
                            want += w * wy * wx * window[(a * k + b) * c + cc];
                        }
                    }
                }
                assert!(
                    (out[hh] - want).abs() < 1e-4,
                    "phase {phase} h {hh}: {} vs {want}",
                    out[hh]
                );
            }
        }
    }
}
