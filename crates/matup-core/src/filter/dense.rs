//! A dense layer, `act(x·Wᵀ + b)`, as one candle op with an explicit backward. Built from
//! candle's `matmul`, `broadcast_add` and an activation it is three ops with a temporary each,
//! and candle's 128×128 products run on one thread (splitting them costs more than it gains).
//! Here the batch's rows are split across matup's threads instead: no row depends on another,
//! so each thread runs its rows through the whole layer, both ways, with no synchronisation.

use candle_core::{CpuStorage, CustomOp3, Layout, Shape, Tensor};
use rayon::prelude::*;

use crate::gemm::gemm;
use crate::op::contiguous_f32;

/// The layer's activation: leaky ReLU `max(z, slope·z)` (0 ≤ slope < 1; ReLU at 0), or
/// none (the output layer).
#[derive(Clone, Copy, Debug)]
pub struct Dense {
    pub slope: Option<f32>,
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
        let (outputs, w_inputs) = wl.shape().dims2()?;
        if w_inputs != inputs || bl.shape().elem_count() != outputs {
            candle_core::bail!(
                "dense layer: input {:?}, weights {:?}, bias {:?} do not fit",
                xl.shape(),
                wl.shape(),
                bl.shape()
            );
        }
        let (x, w, b) = (
            contiguous_f32(xs, xl)?,
            contiguous_f32(ws, wl)?,
            contiguous_f32(bs, bl)?,
        );
        let chunk = Self::chunk(rows);
        let mut y = vec![0f32; rows * outputs];
        y.par_chunks_mut(chunk * outputs)
            .zip(x.par_chunks(chunk * inputs))
            .for_each(|(y, x)| {
                // y (r×O) = x (r×I) · Wᵀ (I×O, read from W's rows).
                let r = x.len() / inputs;
                gemm(
                    (r, inputs, outputs),
                    x,
                    (inputs, 1),
                    w,
                    (1, inputs),
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
        _b: &Tensor,
        res: &Tensor,
        grad_res: &Tensor,
    ) -> candle_core::Result<(Option<Tensor>, Option<Tensor>, Option<Tensor>)> {
        let (rows, inputs) = x.dims2()?;
        let (outputs, _) = w.dims2()?;
        let (xv, wv) = (values(x)?, values(w)?);
        // Through the activation: z > 0 exactly where the output is > 0 (slope ≥ 0).
        let mut gz = values(grad_res)?;
        if let Some(slope) = self.slope {
            for (g, y) in gz.iter_mut().zip(values(res)?) {
                if y <= 0.0 {
                    *g *= slope;
                }
            }
        }
        let chunk = Self::chunk(rows);
        // dx (r×I) = dz (r×O) · W (O×I), by rows of the batch.
        let mut gx = vec![0f32; rows * inputs];
        gx.par_chunks_mut(chunk * inputs)
            .zip(gz.par_chunks(chunk * outputs))
            .for_each(|(gx, gz)| {
                let r = gz.len() / outputs;
                gemm(
                    (r, outputs, inputs),
                    gz,
                    (outputs, 1),
                    &wv,
                    (inputs, 1),
                    0.0,
                    gx,
                    inputs,
                );
            });
        // dW (O×I) = dzᵀ (O×r) · x (r×I), by rows of W (columns of dz).
        let out_chunk = Self::chunk(outputs);
        let mut gw = vec![0f32; outputs * inputs];
        gw.par_chunks_mut(out_chunk * inputs)
            .enumerate()
            .for_each(|(i, gw)| {
                let first = i * out_chunk;
                let o = gw.len() / inputs;
                gemm(
                    (o, rows, inputs),
                    &gz[first..],
                    (1, outputs),
                    &xv,
                    (inputs, 1),
                    0.0,
                    gw,
                    inputs,
                );
            });
        let mut gb = vec![0f32; outputs];
        for row in gz.chunks_exact(outputs) {
            for (s, g) in gb.iter_mut().zip(row) {
                *s += g;
            }
        }
        let device = x.device();
        Ok((
            Some(Tensor::from_vec(gx, (rows, inputs), device)?),
            Some(Tensor::from_vec(gw, (outputs, inputs), device)?),
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
    /// without an activation, for a batch that does not split evenly across threads.
    #[test]
    fn equals_candles_composition() {
        let (rows, inputs, outputs) = (13, 9, 5);
        for slope in [Some(0.01), Some(0.0), None] {
            let x = var(pseudo_random(rows * inputs, 1), (rows, inputs));
            let w = var(pseudo_random(outputs * inputs, 2), (outputs, inputs));
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
                .apply_op3(w.as_tensor(), b.as_tensor(), Dense { slope })
                .unwrap();
            let z = x
                .as_tensor()
                .matmul(&w.as_tensor().t().unwrap())
                .unwrap()
                .broadcast_add(b.as_tensor())
                .unwrap();
            let plain = match slope {
                Some(s) => z.maximum(&z.affine(s as f64, 0.0).unwrap()).unwrap(),
                None => z,
            };
            let close = |a: &Tensor, b: &Tensor, what: &str| {
                let (a, b) = (values(a).unwrap(), values(b).unwrap());
                for (i, (p, q)) in a.iter().zip(&b).enumerate() {
                    assert!((p - q).abs() < 1e-5, "{what} {slope:?} [{i}]: {p} vs {q}");
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
            for (v, what) in [(&x, "dx"), (&w, "dW"), (&b, "db")] {
                close(
                    g_fused.get(v.as_tensor()).unwrap(),
                    g_plain.get(v.as_tensor()).unwrap(),
                    what,
                );
            }
        }
    }
}
