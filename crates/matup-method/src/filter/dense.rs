//! A dense layer, `act(x·Wᵀ + b)`, as one candle op with an explicit backward. Built from
//! candle's `matmul`, `broadcast_add` and an activation it is three ops with a temporary each,
//! and candle's 128×128 products run on one thread (splitting them costs more than it gains).
//! Here the batch's rows are split across matup's threads instead: no row depends on another,
//! so each thread runs its rows through the whole layer, both ways, with no synchronisation.

use candle_core::{CpuStorage, CustomOp3, Layout, Shape, Tensor};
use rayon::prelude::*;

use crate::texel_loss_op::{contiguous_f32, storage_f32};
use matup_simd::gemm::gemm;

/// How a layer's `O × I` weight matrix is stored.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum WeightLayout {
    /// `[out][in]`, as the hidden layers store theirs (as candle's `Linear` does).
    OutputMajor,
    /// `[in][out]`: the first layer's `[dy][dx][c][h]`, which folding reads in rows of C·H.
    InputMajor,
}

impl WeightLayout {
    /// (row, column) strides of the weights viewed as the `O × I` matrix W.
    fn strides(self, inputs: usize, outputs: usize) -> (usize, usize) {
        match self {
            WeightLayout::OutputMajor => (inputs, 1),
            WeightLayout::InputMajor => (1, outputs),
        }
    }

    /// The weights' shape as a tensor.
    fn dims(self, inputs: usize, outputs: usize) -> (usize, usize) {
        match self {
            WeightLayout::OutputMajor => (outputs, inputs),
            WeightLayout::InputMajor => (inputs, outputs),
        }
    }
}

/// The layer's activation, leaky ReLU `max(z, slope·z)` (0 ≤ slope < 1; ReLU at 0) or none
/// (the output layer), and how its weights are stored. The input's gradient is computed only
/// when the input is itself computed from weights (not for the filter's input windows).
#[derive(Clone, Copy, Debug)]
pub struct Dense {
    pub slope: Option<f32>,
    pub layout: WeightLayout,
}

impl Dense {
    /// Rows per thread for a batch of `rows`.
    fn chunk(rows: usize) -> usize {
        rows.div_ceil(rayon::current_num_threads()).max(1)
    }
}

/// The f32 values of a tensor that may not be contiguous.
fn values(t: &Tensor) -> candle_core::Result<Vec<f32>> {
    t.flatten_all()?.to_vec1::<f32>()
}

impl CustomOp3 for Dense {
    fn name(&self) -> &'static str {
        "matup-dense"
    }

    fn cpu_fwd(
        &self,
        xs: &CpuStorage,
        xl: &Layout,
        ws: &CpuStorage,
        wl: &Layout,
        bs: &CpuStorage,
        bl: &Layout,
    ) -> candle_core::Result<(CpuStorage, Shape)> {
        let (rows, inputs) = xl.shape().dims2()?;
        let outputs = bl.shape().elem_count();
        if wl.shape().dims2()? != self.layout.dims(inputs, outputs) {
            candle_core::bail!(
                "dense layer: input {:?}, weights {:?} ({:?}), bias {:?} do not fit",
                xl.shape(),
                wl.shape(),
                self.layout,
                bl.shape()
            );
        }
        let (x, w, b) = (
            contiguous_f32(xs, xl)?,
            contiguous_f32(ws, wl)?,
            contiguous_f32(bs, bl)?,
        );
        let (w_rows, w_cols) = self.layout.strides(inputs, outputs);
        let chunk = Self::chunk(rows);
        let mut y = vec![0f32; rows * outputs];
        y.par_chunks_mut(chunk * outputs)
            .zip(x.par_chunks(chunk * inputs))
            .for_each(|(y, x)| {
                // y (r×O) = x (r×I) · Wᵀ (I×O).
                let r = x.len() / inputs;
                gemm(
                    (r, inputs, outputs),
                    x,
                    (inputs, 1),
                    w,
                    (w_cols, w_rows),
                    0.0,
                    y,
                    outputs,
                );
                for row in y.chunks_exact_mut(outputs) {
                    for (v, bias) in row.iter_mut().zip(b) {
                        let z = *v + bias;
                        *v = match self.slope {
                            Some(slope) if z <= 0.0 => slope * z,
                            _ => z,
                        };
                    }
                }
            });
        Ok((CpuStorage::F32(y), Shape::from((rows, outputs))))
    }

    fn bwd(
        &self,
        x: &Tensor,
        w: &Tensor,
        b: &Tensor,
        res: &Tensor,
        grad_res: &Tensor,
    ) -> candle_core::Result<(Option<Tensor>, Option<Tensor>, Option<Tensor>)> {
        let (rows, inputs) = x.dims2()?;
        let outputs = b.elem_count();
        // The operands are read in place: the first layer's are megabytes.
        let (x, w, res) = (x.contiguous()?, w.contiguous()?, res.contiguous()?);
        let ((xs, xl), (ws, wl)) = (x.storage_and_layout(), w.storage_and_layout());
        let (xv, wv) = (storage_f32(&xs, xl)?, storage_f32(&ws, wl)?);
        let (w_rows, w_cols) = self.layout.strides(inputs, outputs);
        // Through the activation: z > 0 exactly where the output is > 0 (slope ≥ 0).
        let mut gz = values(grad_res)?;
        if let Some(slope) = self.slope {
            let (ys, yl) = res.storage_and_layout();
            for (g, y) in gz.iter_mut().zip(storage_f32(&ys, yl)?) {
                if *y <= 0.0 {
                    *g *= slope;
                }
            }
        }
        let chunk = Self::chunk(rows);
        let device = x.device();
        // dx (r×I) = dz (r×O) · W (O×I), by rows of the batch.
        let gx = if x.track_op() {
            let mut gx = vec![0f32; rows * inputs];
            gx.par_chunks_mut(chunk * inputs)
                .zip(gz.par_chunks(chunk * outputs))
                .for_each(|(gx, gz)| {
                    let r = gz.len() / outputs;
                    gemm(
                        (r, outputs, inputs),
                        gz,
                        (outputs, 1),
                        wv,
                        (w_rows, w_cols),
                        0.0,
                        gx,
                        inputs,
                    );
                });
            Some(Tensor::from_vec(gx, (rows, inputs), device)?)
        } else {
            None
        };
        // dW in the weights' layout: a (M×r)ᵀ · c (r×N), M×N = O×I (dzᵀ·x) or I×O (xᵀ·dz),
        // by rows of dW.
        let (m, n, a, c) = match self.layout {
            WeightLayout::OutputMajor => (outputs, inputs, &gz[..], xv),
            WeightLayout::InputMajor => (inputs, outputs, xv, &gz[..]),
        };
        let m_chunk = Self::chunk(m);
        let mut gw = vec![0f32; m * n];
        gw.par_chunks_mut(m_chunk * n)
            .enumerate()
            .for_each(|(i, gw)| {
                let first = i * m_chunk;
                gemm(
                    (gw.len() / n, rows, n),
                    &a[first..],
                    (1, m),
                    c,
                    (n, 1),
                    0.0,
                    gw,
                    n,
                );
            });
        let mut gb = vec![0f32; outputs];
        for row in gz.chunks_exact(outputs) {
            for (s, g) in gb.iter_mut().zip(row) {
                *s += g;
            }
        }
        Ok((
            gx,
            Some(Tensor::from_vec(gw, w.shape(), device)?),
            Some(Tensor::from_vec(gb, outputs, device)?),
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::filter::pseudo_random;
    use candle_core::{Device, Var};

    fn var(values: Vec<f32>, shape: (usize, usize)) -> Var {
        Var::from_tensor(&Tensor::from_vec(values, shape, &Device::Cpu).unwrap()).unwrap()
    }

    /// The fused layer gives candle's own composition's values and gradients, with and
    /// without an activation, in both weight layouts, for a batch that does not split evenly
    /// across threads.
    #[test]
    fn equals_candles_composition() {
        let (rows, inputs, outputs) = (13, 9, 5);
        for layout in [WeightLayout::OutputMajor, WeightLayout::InputMajor] {
            for slope in [Some(0.01), Some(0.0), None] {
                let x = var(pseudo_random(rows * inputs, 1), (rows, inputs));
                let w = var(
                    pseudo_random(outputs * inputs, 2),
                    layout.dims(inputs, outputs),
                );
                let b = Var::from_tensor(
                    &Tensor::from_vec(pseudo_random(outputs, 3), outputs, &Device::Cpu).unwrap(),
                )
                .unwrap();
                let weights = Tensor::from_vec(
                    pseudo_random(rows * outputs, 4),
                    (rows, outputs),
                    &Device::Cpu,
                )
                .unwrap();

                let fused = x
                    .as_tensor()
                    .apply_op3(w.as_tensor(), b.as_tensor(), Dense { slope, layout })
                    .unwrap();
                let w_in_out = match layout {
                    WeightLayout::OutputMajor => w.as_tensor().t().unwrap(),
                    WeightLayout::InputMajor => w.as_tensor().clone(),
                };
                let z = x
                    .as_tensor()
                    .matmul(&w_in_out)
                    .unwrap()
                    .broadcast_add(b.as_tensor())
                    .unwrap();
                let plain = match slope {
                    Some(s) => z.maximum(&z.affine(s as f64, 0.0).unwrap()).unwrap(),
                    None => z,
                };
                let what = format!("{layout:?} {slope:?}");
                let close = |a: &Tensor, b: &Tensor, part: &str| {
                    let (a, b) = (values(a).unwrap(), values(b).unwrap());
                    assert_eq!(a.len(), b.len());
                    for (i, (p, q)) in a.iter().zip(&b).enumerate() {
                        assert!((p - q).abs() < 1e-5, "{what} {part} [{i}]: {p} vs {q}");
                    }
                };
                close(&fused, &plain, "forward");
                let g_fused = (fused * &weights)
                    .unwrap()
                    .sum_all()
                    .unwrap()
                    .backward()
                    .unwrap();
                let g_plain = (plain * &weights)
                    .unwrap()
                    .sum_all()
                    .unwrap()
                    .backward()
                    .unwrap();
                for (v, part) in [(&x, "dx"), (&w, "dW"), (&b, "db")] {
                    close(
                        g_fused.get(v.as_tensor()).unwrap(),
                        g_plain.get(v.as_tensor()).unwrap(),
                        part,
                    );
                }
            }
        }
    }

    /// An input that no weight produced (the filter's windows) gets no gradient: its product
    /// is the largest of the first layer's backward pass, and nothing reads it.
    #[test]
    fn skips_the_gradient_of_a_constant_input() {
        let (rows, inputs, outputs) = (4, 6, 3);
        let x = Tensor::from_vec(
            pseudo_random(rows * inputs, 1),
            (rows, inputs),
            &Device::Cpu,
        )
        .unwrap();
        let w = var(pseudo_random(outputs * inputs, 2), (inputs, outputs));
        let b = Tensor::from_vec(pseudo_random(outputs, 3), outputs, &Device::Cpu).unwrap();
        let first = Dense {
            slope: None,
            layout: WeightLayout::InputMajor,
        };
        let y = x.apply_op3(w.as_tensor(), &b, first).unwrap();
        let grads = y.sum_all().unwrap().backward().unwrap();
        assert!(grads.get(&x).is_none());
        // d(Σ y)/dW[i][o] = Σ_rows x[r][i].
        let x_sums: Vec<f32> = (0..inputs)
            .map(|i| (0..rows).map(|r| values(&x).unwrap()[r * inputs + i]).sum())
            .collect();
        let dw = values(grads.get(w.as_tensor()).unwrap()).unwrap();
        for i in 0..inputs {
            for o in 0..outputs {
                assert!((dw[i * outputs + o] - x_sums[i]).abs() < 1e-5);
            }
        }
    }
}
