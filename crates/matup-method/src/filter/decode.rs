//! From the filter's answer to shading parameters: residual plus base, clamps, and the normal
//! rebuilt from (nx, ny) (METHOD.md), with the adjoint for training. Training and inference
//! both decode through here.

use candle_core::Tensor;

use super::FEATURES;
use matup_core::shading::Svbrdf;

/// Longest (nx, ny) before the normal is rebuilt.
const MAX_TANGENT_LENGTH: f32 = 0.999;
/// Floor of nz² in the rebuild.
const MIN_NZ2: f32 = 1e-3;

/// A decoded texel and what its backward pass needs.
#[derive(Clone, Copy, Debug)]
pub struct Decoded {
    pub params: Svbrdf,
    /// 1 where a feature passed through unclamped and is learned, 0 otherwise.
    mask: [f32; FEATURES],
    /// d normal / d (feature 4, feature 5).
    normal_jacobian: [[f32; 3]; 2],
}

/// Decodes raw residuals at a texel whose residual base is `base`; features in `fixed` are
/// held at that constant (a constant map is kept, not learned).
#[inline]
pub fn decode(raw: &[f32], base: &[f32], fixed: &[Option<f32>; FEATURES]) -> Decoded {
    let mut mask = [0f32; FEATURES];
    let v: [f32; FEATURES] = std::array::from_fn(|k| match fixed[k] {
        Some(c) => c,
        None => {
            mask[k] = 1.0;
            base[k] + raw[k]
        }
    });
    let clamp = |k: usize, lo: f32, hi: f32, mask: &mut [f32; FEATURES]| {
        if v[k] < lo || v[k] > hi {
            mask[k] = 0.0;
        }
        v[k].clamp(lo, hi)
    };
    let base_color = [
        clamp(0, 0.0, 1.0, &mut mask),
        clamp(1, 0.0, 1.0, &mut mask),
        clamp(2, 0.0, 1.0, &mut mask),
    ];
    let metallic = clamp(3, 0.0, 1.0, &mut mask);
    // Down to 0, as roughness maps are kept: the shading models clamp alpha where they render.
    let alpha = clamp(6, 0.0, 1.0, &mut mask);

    // (x, y) scaled to length ≤ 0.999, then z = √max(1 − x² − y², 1e-3).
    let (x, y) = (v[4], v[5]);
    let len = (x * x + y * y).sqrt();
    let (tx, ty, j) = if len > MAX_TANGENT_LENGTH {
        let s = MAX_TANGENT_LENGTH / len;
        let (ux, uy) = (x / len, y / len);
        (
            s * x,
            s * y,
            [
                [s * (1.0 - ux * ux), -s * ux * uy],
                [-s * ux * uy, s * (1.0 - uy * uy)],
            ],
        )
    } else {
        (x, y, [[1.0, 0.0], [0.0, 1.0]])
    };
    let z2 = 1.0 - tx * tx - ty * ty;
    let (z, dz) = if z2 > MIN_NZ2 {
        let z = z2.sqrt();
        (z, [-tx / z, -ty / z])
    } else {
        (MIN_NZ2.sqrt(), [0.0, 0.0])
    };
    // j[r][k] = d(tangent r)/d(feature 4 + k).
    let normal_jacobian = std::array::from_fn(|k| {
        let (dtx, dty) = (j[0][k], j[1][k]);
        [dtx, dty, dz[0] * dtx + dz[1] * dty]
    });
    Decoded {
        params: Svbrdf {
            base_color,
            metallic,
            normal: [tx, ty, z],
            alpha,
            anisotropy: 0.0,
            anisotropy_angle: 0.0,
        },
        mask,
        normal_jacobian,
    }
}

/// [`decode`] for a batch as candle operations (the tensor training backend): raw
/// residuals `[B, 7]` on base `[B, 7]` → the `[B, 10]` shading parameters and the decoded
/// `[B, 7]` features, differentiable by candle's autograd. Where the scalar form masks a
/// clamped value's gradient, the clamps here do the same.
pub fn decode_tensors(
    raw: &Tensor,
    base: &Tensor,
    fixed: &[Option<f32>; FEATURES],
) -> candle_core::Result<(Tensor, Tensor)> {
    let v = (raw + base)?;
    let b = v.dim(0)?;
    let feature = |k: usize| match fixed[k] {
        Some(c) => Tensor::full(c, (b, 1), v.device()),
        None => v.narrow(1, k, 1),
    };
    let base_color = Tensor::cat(&[feature(0)?, feature(1)?, feature(2)?], 1)?.clamp(0f32, 1f32)?;
    let metallic = feature(3)?.clamp(0f32, 1f32)?;
    let alpha = feature(6)?.clamp(0f32, 1f32)?;
    // (x, y) scaled to length ≤ 0.999, then z = √max(1 − x² − y², 1e-3). The length is
    // floored so that the unused branch of the minimum keeps a finite gradient at 0.
    let (x, y) = (feature(4)?, feature(5)?);
    let length = (x.sqr()? + y.sqr()?)?.maximum(1e-12f32)?.sqrt()?;
    let shrink = (length.recip()? * MAX_TANGENT_LENGTH as f64)?.minimum(1f32)?;
    let (tx, ty) = ((x * &shrink)?, (y * &shrink)?);
    let z = (tx.sqr()? + ty.sqr()?)?
        .affine(-1.0, 1.0)?
        .maximum(MIN_NZ2)?
        .sqrt()?;
    let params = Tensor::cat(
        &[
            &base_color,
            &metallic,
            &tx,
            &ty,
            &z,
            &alpha,
            &Tensor::zeros((b, 2), v.dtype(), v.device())?,
        ],
        1,
    )?;
    let features = Tensor::cat(&[&base_color, &metallic, &tx, &ty, &alpha], 1)?;
    Ok((params, features))
}

/// Features `[7, H, W]` of one material → shading parameters `[H·W, 10]`, constant features
/// held (`fixed`), as inference decodes the residual base (no filter: no residuals).
pub fn shading_params(
    features: &Tensor,
    fixed: &[Option<f32>; FEATURES],
) -> candle_core::Result<Tensor> {
    let texel_major = features.flatten_from(1)?.t()?;
    let zeros = texel_major.zeros_like()?;
    Ok(decode_tensors(&zeros, &texel_major, fixed)?.0)
}

impl Decoded {
    /// The decoded texel as the 7 features, in [`FEATURES`] order (normal x and y after the
    /// rebuild).
    pub fn features(&self) -> [f32; FEATURES] {
        let p = &self.params;
        [
            p.base_color[0],
            p.base_color[1],
            p.base_color[2],
            p.metallic,
            p.normal[0],
            p.normal[1],
            p.alpha,
        ]
    }

    /// The gradient with respect to the raw residuals, given the gradient with respect to the
    /// decoded parameters.
    #[inline]
    pub fn backward(&self, grad: &Svbrdf) -> [f32; FEATURES] {
        let n = &grad.normal;
        let through_normal = |k: usize| {
            let j = &self.normal_jacobian[k];
            n[0] * j[0] + n[1] * j[1] + n[2] * j[2]
        };
        [
            grad.base_color[0] * self.mask[0],
            grad.base_color[1] * self.mask[1],
            grad.base_color[2] * self.mask[2],
            grad.metallic * self.mask[3],
            through_normal(0) * self.mask[4],
            through_normal(1) * self.mask[5],
            grad.alpha * self.mask[6],
        ]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn objective(d: &Decoded, w: &[f32; 8]) -> f32 {
        let p = &d.params;
        let v = [
            p.base_color[0],
            p.base_color[1],
            p.base_color[2],
            p.metallic,
            p.normal[0],
            p.normal[1],
            p.normal[2],
            p.alpha,
        ];
        v.iter().zip(w).map(|(a, b)| a * b).sum()
    }

    #[test]
    fn backward_matches_finite_differences() {
        let w = [0.3, -0.7, 1.1, 0.5, 0.9, -1.3, 0.8, 0.4];
        let none = [None; FEATURES];
        let cases: [[f32; 7]; 3] = [
            [0.4, 0.5, 0.6, 0.2, 0.3, -0.2, 0.3],  // everything inside
            [0.4, 0.5, 0.6, 0.2, 0.8, -0.7, 0.3],  // tangent longer than 0.999
            [0.4, 0.5, 0.6, 0.2, 0.6, -0.75, 0.3], // near the nz floor but inside
        ];
        for raw in cases {
            let base = [0.0; FEATURES];
            let d = decode(&raw, &base, &none);
            let g = Svbrdf {
                base_color: [w[0], w[1], w[2]],
                metallic: w[3],
                normal: [w[4], w[5], w[6]],
                alpha: w[7],
                ..Default::default()
            };
            let analytic = d.backward(&g);
            for k in 0..FEATURES {
                let h = 1e-3;
                let mut a = raw;
                let mut b = raw;
                a[k] += h;
                b[k] -= h;
                let fd = (objective(&decode(&a, &base, &none), &w)
                    - objective(&decode(&b, &base, &none), &w))
                    / (2.0 * h);
                assert!(
                    (fd - analytic[k]).abs() < 2e-3,
                    "{raw:?} feature {k}: {fd} vs {}",
                    analytic[k]
                );
            }
        }
    }

    #[test]
    fn clamps_and_fixed_features_stop_gradients() {
        let mut fixed = [None; FEATURES];
        fixed[3] = Some(0.0);
        let d = decode(
            &[1.5, 0.5, 0.5, 0.7, 0.0, 0.0, -1.0],
            &[0.0; FEATURES],
            &fixed,
        );
        assert_eq!(d.params.base_color[0], 1.0);
        assert_eq!(d.params.metallic, 0.0, "fixed metallic stays constant");
        assert_eq!(d.params.alpha, 0.0);
        assert_eq!(d.params.normal, [0.0, 0.0, 1.0]);
        let g = d.backward(&Svbrdf {
            base_color: [1.0; 3],
            metallic: 1.0,
            alpha: 1.0,
            ..Default::default()
        });
        assert_eq!((g[0], g[1], g[3], g[6]), (0.0, 1.0, 0.0, 0.0));
    }
}
