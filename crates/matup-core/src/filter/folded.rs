//! The filter's first layer, folded per sub-pixel phase. The layer reads an N×N×C window of
//! upsampled features; since upsampling is a fixed linear map per phase, its weights fold into
//! one K×K×C matrix per phase (≈ 8× fewer multiply-adds at N = 17, K = 6). Folding costs
//! O(weights), once per step; the backward pass unfolds the phase gradients the same way.
//!
//! Layouts: weights `[dy][dx][c][h]`, folded weights `[a][b][c][h]` per phase (the transposed
//! K·K·C × H matrix, as the product wants it), windows `[a][b][c]`. Rows of C·H values are
//! the unit of every step, so no stage reorders single values.

use std::sync::Arc;

use candle_core::{CpuStorage, CustomOp1, Layout, Shape, Tensor};
use rayon::prelude::*;

use super::geometry::WindowGeometry;
use crate::gemm::product;

#[inline]
fn axpy(alpha: f32, x: &[f32], y: &mut [f32]) {
    for (y, x) in y.iter_mut().zip(x) {
        *y += alpha * x;
    }
}

/// Writes `Σ wt·x` over `terms` into `out` (zeros where there are none). The first term is
/// assigned, not added, so no buffer needs zero-filling first.
fn combine_into<'a>(out: &mut [f32], mut terms: impl Iterator<Item = (f32, &'a [f32])>) {
    match terms.next() {
        Some((wt, x)) => out.iter_mut().zip(x).for_each(|(o, x)| *o = wt * x),
        None => out.fill(0.0),
    }
    for (wt, x) in terms {
        axpy(wt, x, out);
    }
}

/// Appends the row `Σ wt·x` over `terms` (`len` long) to `out`. Buffers are built row by
/// row like this, each row zeroed while it is in L1, rather than zero-filled whole up front
/// (which cost ~5% of a training step in cache misses and page faults).
fn push_combination<'a>(
    out: &mut Vec<f32>,
    len: usize,
    terms: impl Iterator<Item = (f32, &'a [f32])>,
) {
    let start = out.len();
    out.resize(start + len, 0.0);
    combine_into(&mut out[start..], terms);
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

    /// The adjoint of [`fold`](Self::fold): per-phase gradients `[a][b][c][h]` (empty for
    /// phases absent from the batch) → the weights' gradient `[dy][dx][c][h]`.
    pub fn unfold(&self, phase_grads: &[Vec<f32>]) -> Vec<f32> {
        let g = &self.geometry;
        let (n, k, s, row) = (g.window, g.taps, g.scale, self.hidden * self.channels);
        // Stage 2 adjoint, per (px, b): dT[px][b][dy] = Σ_py Σ_a By_py[dy][a] · G[py, px][a][b].
        let stage2: Vec<Vec<f32>> = (0..s * k)
            .into_par_iter()
            .map(|pb| {
                let (px, b) = (pb / k, pb % k);
                let mut out = Vec::with_capacity(n * row); // [dy]
                for dy in 0..n {
                    let terms = (0..s)
                        .filter(|py| !phase_grads[py * s + px].is_empty())
                        .flat_map(|py| {
                            let grad = &phase_grads[py * s + px];
                            g.axis.weights[py]
                                .iter()
                                .filter(move |tap| tap.0 == dy)
                                .map(move |&(_, a, wt)| (wt, &grad[(a * k + b) * row..][..row]))
                        });
                    push_combination(&mut out, row, terms);
                }
                out
            })
            .collect();
        // Stage 1 adjoint, per dy: dW[dy][dx] = Σ_px Σ_b Bx_px[dx][b] · dT[px][b][dy].
        let stage2 = &stage2;
        let mut grad = vec![0f32; self.weight_len()];
        grad.par_chunks_mut(n * row)
            .enumerate()
            .for_each(|(dy, out)| {
                for (dx, out) in out.chunks_exact_mut(row).enumerate() {
                    let terms = (0..s).flat_map(|px| {
                        g.axis.weights[px]
                            .iter()
                            .filter(move |tap| tap.0 == dx)
                            .map(move |&(_, b, wt)| (wt, &stage2[px * k + b][dy * row..][..row]))
                    });
                    combine_into(out, terms);
                }
            });
        grad
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

    /// Per-phase weight gradients `Gφᵀ = xφᵀ · gφ` (`[a][b][c][h]`) for output gradients
    /// `[B][H]`; empty for phases absent from the batch.
    fn phase_gradients(
        &self,
        grad_out: &[f32],
        windows: &[f32],
        phases: &[usize],
    ) -> Vec<Vec<f32>> {
        let kkc = self.geometry.window_len(self.channels);
        let h = self.hidden;
        self.by_phase(phases)
            .par_iter()
            .map(|group| {
                if group.is_empty() {
                    return Vec::new();
                }
                let mut x = Vec::with_capacity(group.len() * kkc);
                let mut gy = Vec::with_capacity(group.len() * h);
                for &i in group {
                    x.extend_from_slice(&windows[i * kkc..][..kkc]);
                    gy.extend_from_slice(&grad_out[i * h..][..h]);
                }
                // Gᵀ (KKC×H) = xᵀ (KKC×n) · gy (n×H).
                product((kkc, group.len(), h), &x, (1, kkc), &gy, (h, 1))
            })
            .collect()
    }
}

/// The folded first layer as a candle op on its weights, for one batch of windows.
pub struct FoldedLinear {
    pub layer: FoldedLayer,
    /// `[B][K·K·C]`.
    pub windows: Arc<Vec<f32>>,
    pub phases: Arc<Vec<usize>>,
}

impl CustomOp1 for FoldedLinear {
    fn name(&self) -> &'static str {
        "matup-folded-linear"
    }

    fn cpu_fwd(
        &self,
        storage: &CpuStorage,
        layout: &Layout,
    ) -> candle_core::Result<(CpuStorage, Shape)> {
        let weights = crate::op::contiguous_f32(storage, layout)?;
        if weights.len() != self.layer.weight_len() {
            candle_core::bail!(
                "folded layer expects {} weights, got {}",
                self.layer.weight_len(),
                weights.len()
            );
        }
        let folded = self.layer.fold(weights);
        let out = self.layer.apply(&folded, &self.windows, &self.phases);
        Ok((
            CpuStorage::F32(out),
            Shape::from((self.phases.len(), self.layer.hidden)),
        ))
    }

    fn bwd(
        &self,
        arg: &Tensor,
        _res: &Tensor,
        grad_res: &Tensor,
    ) -> candle_core::Result<Option<Tensor>> {
        let grad_out = grad_res.flatten_all()?.to_vec1::<f32>()?;
        let phase_grads = self
            .layer
            .phase_gradients(&grad_out, &self.windows, &self.phases);
        let grad = self.layer.unfold(&phase_grads);
        Ok(Some(Tensor::from_vec(grad, arg.shape(), arg.device())?))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::filter::pseudo_random;
    use crate::resample::Kernel;

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

    /// unfold is the adjoint of fold: ⟨fold(W), G⟩ = ⟨W, unfold(G)⟩.
    #[test]
    fn unfold_is_the_adjoint_of_fold() {
        let l = layer();
        let weights = pseudo_random(l.weight_len(), 3);
        let grads: Vec<Vec<f32>> = (0..16)
            .map(|p| pseudo_random(l.folded_len(), 10 + p))
            .collect();
        let folded = l.fold(&weights);
        let lhs: f64 = folded
            .iter()
            .zip(&grads)
            .flat_map(|(f, g)| f.iter().zip(g))
            .map(|(a, b)| (*a as f64) * (*b as f64))
            .sum();
        let unfolded = l.unfold(&grads);
        let rhs: f64 = weights
            .iter()
            .zip(&unfolded)
            .map(|(a, b)| (*a as f64) * (*b as f64))
            .sum();
        assert!(
            (lhs - rhs).abs() < 1e-3 * lhs.abs().max(1.0),
            "{lhs} vs {rhs}"
        );
    }
}
