//! What `matup upscale` does with the network's outputs by default, as differentiable candle
//! operations, so that training sees what users get: each map decoded as the per-map upsampler
//! decodes it (`matup_method::per_map::upscale_per_map`), the 7 features back-projected onto the
//! LR features (`matup_method::residual::back_project`), decoded to shading parameters
//! (`matup_method::filter::decode`), rendered with the shading model's tensor form and shown
//! through the display transform. The tests hold each step equal to matup's own code. The
//! defaults' last step, clamping each texel's chroma into its input's range
//! (`matup_method::chroma`), is not modelled: it touches only texels whose hue the network
//! invented, and a network trained without it is judged with it.

use candle_core::{Device, Tensor, D};
use matup_core::device_maps::Separable;
use matup_core::resample::{upsample_matrix, Border, Kernel, Shrink};
use matup_core::tensor_shading::{display, LightTensors, SvbrdfTensors, TensorShading};
use matup_method::features::ALPHA;
use matup_method::filter::decode::decode_tensors;
use matup_method::filter::FEATURES;
use matup_method::residual::settled_part_on_device;

/// Rounds of back-projection, as `matup_method::residual` runs them.
pub const BACK_PROJECTIONS: usize = 3;

/// The images the per-map upsampler sends through the network for `B` materials, in this
/// order per material (`[4B, 3, h, w]`).
pub const IMAGES_PER_MATERIAL: usize = 4;

/// sRGB-encoded → linear, as `matup_core::color::srgb_to_linear`.
fn srgb_to_linear(v: &Tensor) -> candle_core::Result<Tensor> {
    const KNEE: f64 = 0.04045;
    let linear = (v / 12.92)?;
    // The power only where it is used, so its gradient stays finite.
    let curve = ((v.maximum(KNEE)? + 0.055)? / 1.055)?.powf(2.4)?;
    v.le(KNEE)?.where_cond(&linear, &curve)
}

/// The network's `[4B, 3, H, W]` outputs decoded as the per-map upsampler decodes them, with
/// the material's invariants restored, as the 7 filter features `[B, 7, H, W]`.
pub fn decode_outputs(outputs: &Tensor) -> candle_core::Result<Tensor> {
    let (n, _, h, w) = outputs.dims4()?;
    let b = n / IMAGES_PER_MATERIAL;
    let per_material = outputs.reshape((b, IMAGES_PER_MATERIAL, 3, h, w))?;
    let image = |k: usize| per_material.narrow(1, k, 1)?.squeeze(1);
    let base = srgb_to_linear(&image(0)?.clamp(0f32, 1f32)?)?.clamp(0f32, 1f32)?;
    let normal = decode_normal_image(&image(1)?)?;
    let grey = |k: usize| image(k)?.mean_keepdim(1);
    let roughness = grey(2)?.clamp(0f32, 1f32)?;
    let metallic = grey(3)?.clamp(0f32, 1f32)?;
    let alpha = roughness.sqr()?;
    Tensor::cat(&[&base, &metallic, &normal.narrow(1, 0, 2)?, &alpha], 1)
}

/// Normal-map images `[B, 3, H, W]` (DirectX encoding, `(n + 1) / 2`) → unit normals,
/// renormalised as the per-map upsampler renormalises them (a zero vector cannot come out of
/// `2v − 1` in practice; the floor only keeps the division finite).
pub fn decode_normal_image(image: &Tensor) -> candle_core::Result<Tensor> {
    let normal = image.affine(2.0, -1.0)?;
    let length = normal.sqr()?.sum_keepdim(1)?.maximum(1e-20f32)?.sqrt()?;
    normal.broadcast_div(&length)
}

/// The normals of shading parameters from normal features `[B, 2, H, W]` (x and y),
/// `[B·H·W, 3]` texel by texel, as the filter's decode rebuilds them.
pub fn normal_params(xy: &Tensor) -> candle_core::Result<Tensor> {
    let xy = xy.permute((0, 2, 3, 1))?.flatten_to(2)?;
    let t = xy.dim(0)?;
    let features = Tensor::cat(
        &[
            &Tensor::zeros((t, 4), xy.dtype(), xy.device())?,
            &xy,
            &Tensor::ones((t, 1), xy.dtype(), xy.device())?,
        ],
        1,
    )?;
    let (params, _) = decode_tensors(&features.zeros_like()?, &features, &[None; FEATURES])?;
    params.narrow(1, 4, 3)
}

/// The filter down from the network's native scale to a smaller one, as matup's route makes
/// it (`matup_core::upsample::serving_smaller_scales`): each output image area-shrunk before
/// it is decoded, by the device path's own resampling (`device_maps::Separable`), whose matrix
/// products candle differentiates.
pub struct Route(Separable);

impl Route {
    /// For LR images of `size × size` upsampled ×`native` and shrunk to ×`scale`.
    pub fn new(
        size: usize,
        native: usize,
        scale: usize,
        border: Border,
        device: &Device,
    ) -> candle_core::Result<Route> {
        let [from, to] = [native, scale].map(|s| [size * s; 2]);
        Ok(Route(Separable::shrink(
            from,
            to,
            Shrink::Area,
            border,
            device,
        )?))
    }

    /// Images `[N, C, native · h, native · w]` → `[N, C, scale · h, scale · w]`.
    pub fn apply(&self, images: &Tensor) -> candle_core::Result<Tensor> {
        let (n, c, h, w) = images.dims4()?;
        let shrunk = self.0.apply(&images.reshape((n * c, h, w))?)?;
        let (_, oh, ow) = shrunk.dims3()?;
        shrunk.reshape((n, c, oh, ow))
    }
}

/// Back-projection onto the LR features as matrix products: the box filter as a mean of
/// `scale × scale` blocks, the bilinear spread as `U · M · Uᵀ` with `U` the weights of matup's
/// own bilinear upsampling (`upsample_matrix`: borders as `upsample` handles them). The
/// differentiable, batched form of `matup_method::residual::back_project_on_device`, which
/// inference uses: training needs floors that keep gradients finite.
pub struct BackProjection {
    scale: usize,
    /// `[H, h]`.
    spread: Tensor,
    spread_t: Tensor,
    lo: Tensor,
    hi: Tensor,
}

impl BackProjection {
    /// For LR maps of `size × size` upsampled by `scale`.
    pub fn new(
        size: usize,
        scale: usize,
        border: Border,
        device: &Device,
    ) -> candle_core::Result<Self> {
        let u = Tensor::from_vec(
            upsample_matrix(size, scale, Kernel::Bilinear, border),
            (size * scale, size),
            device,
        )?;
        let range = |f: fn(usize) -> f32| {
            Tensor::from_vec(
                (0..FEATURES).map(f).collect::<Vec<f32>>(),
                (1, FEATURES, 1, 1),
                device,
            )
        };
        Ok(BackProjection {
            scale,
            spread_t: u.t()?.contiguous()?,
            spread: u,
            lo: range(|k| feature_range(k).0)?,
            hi: range(|k| feature_range(k).1)?,
        })
    }

    /// `hr` `[B, 7, H, W]` corrected so that its box-downsample comes back to `lr`
    /// `[B, 7, h, w]`, values kept in their ranges.
    pub fn apply(&self, hr: &Tensor, lr: &Tensor) -> candle_core::Result<Tensor> {
        self.apply_features(hr, lr, 0)
    }

    /// [`BackProjection::apply`] to some of the features: `hr` `[B, C, H, W]` and `lr`
    /// `[B, C, h, w]` hold features `first..first + C` (each is back-projected on its own).
    pub fn apply_features(
        &self,
        hr: &Tensor,
        lr: &Tensor,
        first: usize,
    ) -> candle_core::Result<Tensor> {
        let count = hr.dim(1)?;
        let (lo, hi) = (
            self.lo.narrow(1, first, count)?,
            self.hi.narrow(1, first, count)?,
        );
        // Alpha (feature 6) corrected as the roughness r it is stored as, as
        // `matup_method::residual::back_project` does; floored so that √'s gradient stays
        // finite at 0.
        let alpha = (first..first + count).position(|k| k == ALPHA);
        let as_roughness = |x: &Tensor| -> candle_core::Result<Tensor> {
            match alpha {
                Some(a) => {
                    let r = x.narrow(1, a, 1)?.maximum(1e-12f32)?.sqrt()?;
                    x.slice_assign(&[0..x.dim(0)?, a..a + 1, 0..x.dim(2)?, 0..x.dim(3)?], &r)
                }
                None => Ok(x.clone()),
            }
        };
        let lr = &as_roughness(lr)?;
        let mut hr = as_roughness(hr)?;
        for _ in 0..BACK_PROJECTIONS {
            let mismatch = (lr - hr.avg_pool2d(self.scale)?)?;
            let correction = self
                .spread
                .broadcast_matmul(&mismatch.broadcast_matmul(&self.spread_t)?)?;
            hr = (hr + correction)?
                .broadcast_maximum(&lo)?
                .broadcast_minimum(&hi)?;
        }
        let hr = self.settle(&hr, lr, &lo, &hi)?;
        match alpha {
            Some(a) => {
                let (b, _, h, w) = hr.dims4()?;
                let squared = hr.narrow(1, a, 1)?.sqr()?;
                hr.slice_assign(&[0..b, a..a + 1, 0..h, 0..w], &squared)
            }
            None => Ok(hr),
        }
    }
}

impl BackProjection {
    /// `matup_method::residual::settle_blocks` on `hr` `[B, C, H, W]`: each block whose mean
    /// misses its `lr` texel by more than `SETTLE_ABOVE` gets the miss (its `settled_part`)
    /// shared in proportion to each texel's room toward the end of `[lo, hi]` it moves to.
    fn settle(
        &self,
        hr: &Tensor,
        lr: &Tensor,
        lo: &Tensor,
        hi: &Tensor,
    ) -> candle_core::Result<Tensor> {
        let (_, _, h, w) = hr.dims4()?;
        let blocks = |t: &Tensor| t.upsample_nearest2d(h, w);
        let n = (self.scale * self.scale) as f64;
        let miss = blocks(&settled_part_on_device(
            &(lr - hr.avg_pool2d(self.scale)?)?,
        )?)?;
        let up = miss.ge(0f32)?;
        let end = up.where_cond(&hi.broadcast_as(hr.shape())?, &lo.broadcast_as(hr.shape())?)?;
        let room = (end - hr)?.abs()?;
        let total = blocks(&(room.avg_pool2d(self.scale)? * n)?)?;
        // A block without room is left as it is. Its share is divided by 1, not by a tiny
        // floor: the gradient of the branch not taken is multiplied by 0, and 0 · ∞ (a floor
        // squared underflows) is NaN in every weight. A block with less room than `ROOM`
        // moves by less than that, so leaving it too changes nothing anyone can see.
        const ROOM: f32 = 1e-12;
        let has_room = total.gt(ROOM)?;
        let divisor = has_room.where_cond(&total, &total.ones_like()?)?;
        let settled = (hr + (&miss * n)?.mul(&room)?.div(&divisor)?)?
            .broadcast_maximum(lo)?
            .broadcast_minimum(hi)?;
        let off = miss.ne(0f32)?.mul(&has_room)?;
        off.where_cond(&settled, hr)
    }
}

/// The range a feature's values may take as stored, as `matup_method::residual` keeps them.
fn feature_range(feature: usize) -> (f32, f32) {
    match feature {
        4 | 5 => (-1.0, 1.0),
        _ => (0.0, 1.0),
    }
}

/// Display-space renders `[T, L, 3]` of shading parameters `[T, 10]`.
pub fn shown(
    model: &dyn TensorShading,
    params: &Tensor,
    lights: &LightTensors,
) -> candle_core::Result<Tensor> {
    display(&model.shade(&SvbrdfTensors::from_params(params)?, lights)?)
}

/// Mean chordal distance `|a − b|` between the normals of parameters `[T, 10]`: `2·sin(θ/2)`
/// for unit normals, monotone in the angle θ (candle has no `acos`), floored so that its
/// gradient stays finite where the normals agree.
pub fn normal_chord(a: &Tensor, b: &Tensor) -> candle_core::Result<Tensor> {
    let d = (a.narrow(1, 4, 3)? - b.narrow(1, 4, 3)?)?;
    d.sqr()?
        .sum(D::Minus1)?
        .maximum(1e-12f32)?
        .sqrt()?
        .mean_all()
}
