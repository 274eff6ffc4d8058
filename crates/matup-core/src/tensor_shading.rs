//! The tensor form of shading and its loss: a batch of texels × lights as candle tensors, on
//! any candle device, differentiated by candle's autograd. The fused CPU path
//! ([`crate::shading::texel_loss`] over the models' hand-derived Jacobians) computes the same
//! numbers texel by texel; `tests/shading.rs` holds the two equal for every model that has
//! both forms.

use candle_core::{Device, Tensor, D};

use crate::lights::Light;
use crate::loss::LossNorm;
use crate::svbrdf::{Svbrdf, VIEW};

/// Shading parameters of `T` texels, each `[T, 1, k]` so that they broadcast over lights.
pub struct SvbrdfTensors {
    /// Linear base colour, `[T, 1, 3]`.
    pub base_color: Tensor,
    pub metallic: Tensor,
    /// Tangent-space normal, not necessarily unit length, `[T, 1, 3]`.
    pub normal: Tensor,
    /// GGX alpha (roughness²).
    pub alpha: Tensor,
    pub anisotropy: Tensor,
    pub anisotropy_angle: Tensor,
}

impl SvbrdfTensors {
    /// From a `[T, 10]` tensor in [`Svbrdf::to_array`] order.
    pub fn from_params(params: &Tensor) -> candle_core::Result<SvbrdfTensors> {
        let part = |start: usize, len: usize| params.narrow(1, start, len)?.unsqueeze(1);
        Ok(SvbrdfTensors {
            base_color: part(0, 3)?,
            metallic: part(3, 1)?,
            normal: part(4, 3)?,
            alpha: part(7, 1)?,
            anisotropy: part(8, 1)?,
            anisotropy_angle: part(9, 1)?,
        })
    }
}

/// The lights as seen from `T` shading points: unit directions `[T, L, 3]` and intensities
/// `[T, L, 1]`. They do not depend on the learned parameters, so they are computed on the CPU
/// exactly as the fused path computes them ([`Light::sample_at`]) and uploaded.
pub struct LightTensors {
    pub direction: Tensor,
    pub intensity: Tensor,
}

impl LightTensors {
    /// `lights` seen from each of `positions`.
    pub fn new(
        lights: &[Light],
        positions: &[[f32; 3]],
        device: &Device,
    ) -> candle_core::Result<LightTensors> {
        let (t, l) = (positions.len(), lights.len());
        let mut direction = Vec::with_capacity(t * l * 3);
        let mut intensity = Vec::with_capacity(t * l);
        for &p in positions {
            for light in lights {
                let s = light.sample_at(p);
                direction.extend_from_slice(&s.direction);
                intensity.push(s.intensity);
            }
        }
        Ok(LightTensors {
            direction: Tensor::from_vec(direction, (t, l, 3), device)?,
            intensity: Tensor::from_vec(intensity, (t, l, 1), device)?,
        })
    }
}

/// A shading model's tensor form (`ShadingModel::tensor_form`).
pub trait TensorShading: Send + Sync {
    /// Linear RGB radiance towards [`VIEW`], `[T, L, 3]`, made of candle operations (so
    /// that candle's autograd differentiates it).
    fn shade(&self, texels: &SvbrdfTensors, lights: &LightTensors) -> candle_core::Result<Tensor>;
}

/// `Σ_k a_k b_k` over the last dimension (broadcasting), kept as a dimension of 1.
pub fn dot(a: &Tensor, b: &Tensor) -> candle_core::Result<Tensor> {
    a.broadcast_mul(b)?.sum_keepdim(D::Minus1)
}

/// `v / sqrt(max(|v|², 1e-20))` along the last dimension, as the scalar models normalise.
pub fn normalize(v: &Tensor) -> candle_core::Result<Tensor> {
    v.broadcast_div(&dot(v, v)?.maximum(1e-20f32)?.sqrt()?)
}

/// The view direction as a `[1, 1, 3]` tensor.
pub fn view(device: &Device) -> candle_core::Result<Tensor> {
    Tensor::new(&[[VIEW]], device)
}

/// The display transform of METHOD.md (Reinhard, then the sRGB curve) on radiance.
pub fn display(radiance: &Tensor) -> candle_core::Result<Tensor> {
    // Below 0 the clamp has no gradient, as in the scalar form.
    let t = radiance.relu()?;
    let x = (&t / (&t + 1.0)?)?;
    const KNEE: f64 = 0.003_130_8;
    let linear = (&x * 12.92)?;
    // The power only where it is used, so its gradient stays finite at 0.
    let curve = ((x.maximum(KNEE)?.powf(1.0 / 2.4)? * 1.055)? - 0.055)?;
    x.le(KNEE)?.where_cond(&linear, &curve)
}

/// A loss norm of display-space errors `[T, L, 3]`: `[T, L]`.
pub fn loss_norm(norm: &LossNorm, e: &Tensor) -> candle_core::Result<Tensor> {
    // Below this squared length an error counts as zero (as in `LossNorm::eval`).
    const TINY: f64 = 1e-20;
    match *norm {
        LossNorm::L21 => e.sqr()?.sum(D::Minus1)?.maximum(TINY)?.sqrt(),
        LossNorm::L11 => e.abs()?.sum(D::Minus1),
        LossNorm::L22 => e.sqr()?.sum(D::Minus1),
        LossNorm::Lpq { p, q } => e
            .abs()?
            .powf(p as f64)?
            .sum(D::Minus1)?
            .maximum(TINY)?
            .powf((q / p) as f64),
    }
}

/// Per texel, `Σ_ω norm(display(render_ω) − target_ω)` over the lights: `[T]`. The tensor
/// equivalent of [`crate::shading::texel_loss`] for `T` texels at once.
pub fn texel_losses(
    model: &dyn TensorShading,
    texels: &SvbrdfTensors,
    lights: &LightTensors,
    targets: &Tensor,
    norm: &LossNorm,
) -> candle_core::Result<Tensor> {
    let shown = display(&model.shade(texels, lights)?)?;
    loss_norm(norm, &(shown - targets)?)?.sum(D::Minus1)
}

/// `[T, 10]` parameters of `texels` as one tensor (tests and tools).
pub fn params_tensor(texels: &[Svbrdf], device: &Device) -> candle_core::Result<Tensor> {
    let flat: Vec<f32> = texels.iter().flat_map(|p| p.to_array()).collect();
    Tensor::from_vec(flat, (texels.len(), Svbrdf::LEN), device)
}
