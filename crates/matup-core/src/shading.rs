//! The `ShadingModel` plugin trait and its registry (the texel parameters it shades are
//! [`crate::svbrdf`]'s).

use crate::color::{display, display_with_derivative};
use crate::lights::{Light, LightSample};
use crate::loss::LossNorm;
use crate::plugin::{find_registration, sorted_registry, PluginOption, PluginSpec, Registration};
use crate::tensor_shading::TensorShading;
use crate::{Error, Result};

pub use crate::svbrdf::{Svbrdf, Texel, VIEW};

/// A shading model: outgoing radiance towards the viewer for a texel lit by a point light,
/// with its analytic derivatives. Implementations are plain Rust, called per texel and light
/// from parallel loops; the provided methods fuse them with the display transform and the
/// loss, so nothing of size texels × lights is ever stored.
pub trait ShadingModel: Send + Sync {
    /// Linear RGB radiance towards [`VIEW`].
    fn shade(&self, texel: &Svbrdf, light: &LightSample) -> [f32; 3];

    /// The radiance and its hand-derived Jacobian: `jacobian[c]` holds
    /// `d radiance[c] / d parameter` for every parameter of [`Svbrdf`]; the fused CPU backend
    /// trains with it. `None` (the default): the model has no Jacobian of its own and trains
    /// with the tensor backend, through its [`tensor_form`](Self::tensor_form).
    fn shade_jacobian(
        &self,
        texel: &Svbrdf,
        light: &LightSample,
    ) -> Option<([f32; 3], [Svbrdf; 3])> {
        let _ = (texel, light);
        None
    }

    /// Whether [`shade_jacobian`](Self::shade_jacobian) answers, so the fused backend can
    /// train the model.
    fn has_jacobian(&self) -> bool {
        let light = LightSample {
            direction: VIEW,
            intensity: 1.0,
        };
        self.shade_jacobian(&Svbrdf::default(), &light).is_some()
    }

    /// Display-space colour of one texel under each light (`out[i]` for `lights[i]`).
    fn render_texel(&self, texel: &Texel, lights: &[Light], out: &mut [[f32; 3]]) {
        for (light, o) in lights.iter().zip(out.iter_mut()) {
            let rgb = self.shade(&texel.params, &light.sample_at(texel.position));
            *o = rgb.map(display);
        }
    }

    /// The fused render + loss of one texel: `Σ_ω norm(display(render_ω) − target_ω)` over the
    /// lights, and, when `grad` is given, its gradient with respect to the texel's parameters
    /// added into `grad`. One pass, no temporaries. Models may override it with a faster
    /// equivalent of [`texel_loss`].
    fn texel_loss(
        &self,
        texel: &Texel,
        lights: &[Light],
        targets: &[[f32; 3]],
        norm: &LossNorm,
        grad: Option<&mut Svbrdf>,
    ) -> f32 {
        texel_loss(self, texel, lights, targets, norm, grad)
    }

    /// The model's tensor form, if it has one: batches of texels × lights as candle
    /// operations, which the tensor training backend (`--backend tensor`, and any GPU)
    /// differentiates with candle's autograd.
    fn tensor_form(&self) -> Option<&dyn TensorShading> {
        None
    }
}

/// The generic fused render + loss of [`ShadingModel::texel_loss`], light by light. With
/// `grad` and a model without a Jacobian the loss is NaN (train it with the tensor backend).
#[inline]
pub fn texel_loss<M: ShadingModel + ?Sized>(
    model: &M,
    texel: &Texel,
    lights: &[Light],
    targets: &[[f32; 3]],
    norm: &LossNorm,
    grad: Option<&mut Svbrdf>,
) -> f32 {
    debug_assert_eq!(lights.len(), targets.len());
    let mut total = 0.0;
    match grad {
        None => {
            for (light, target) in lights.iter().zip(targets) {
                let rgb = model.shade(&texel.params, &light.sample_at(texel.position));
                let e = std::array::from_fn(|c| display(rgb[c]) - target[c]);
                total += norm.eval(e).0;
            }
        }
        Some(grad) => {
            for (light, target) in lights.iter().zip(targets) {
                let Some((rgb, jacobian)) =
                    model.shade_jacobian(&texel.params, &light.sample_at(texel.position))
                else {
                    return f32::NAN;
                };
                let shown = rgb.map(display_with_derivative);
                let e = std::array::from_fn(|c| shown[c].0 - target[c]);
                let (loss, de) = norm.eval(e);
                total += loss;
                for c in 0..3 {
                    grad.add_scaled(&jacobian[c], de[c] * shown[c].1);
                }
            }
        }
    }
    total
}

/// A shading model's entry in the registry; submit one with `inventory::submit!`.
pub struct ShadingModelRegistration {
    pub name: &'static str,
    pub description: &'static str,
    pub options: &'static [PluginOption],
    /// Builds the model from the spec's argument (its options).
    pub create: fn(argument: Option<&str>) -> Result<Box<dyn ShadingModel>>,
}

inventory::collect!(ShadingModelRegistration);

impl Registration for ShadingModelRegistration {
    fn name(&self) -> &'static str {
        self.name
    }
}

/// Every registered shading model, sorted by name.
pub fn shading_models() -> Result<Vec<&'static ShadingModelRegistration>> {
    sorted_registry(
        "shading model",
        inventory::iter::<ShadingModelRegistration>.into_iter(),
    )
}

/// Builds the shading model a spec names (`ggx`, `ggx-aniso`, …).
pub fn shading_model(spec: &PluginSpec) -> Result<Box<dyn ShadingModel>> {
    let registration = find_registration("shading model", shading_models()?, &spec.name)?;
    (registration.create)(spec.argument.as_deref())
}

/// The tensor form of `model`, or an error saying it has none.
pub fn tensor_form(model: &dyn ShadingModel) -> Result<&dyn TensorShading> {
    model.tensor_form().ok_or_else(|| {
        Error::Invalid(
            "the shading model has no tensor form, so the tensor backend cannot train it; use --backend fused (on the CPU)".into(),
        )
    })
}
