//! `lambert`: diffuse only, for ablations and fast previews.

use std::f32::consts::PI;

use matup_core::shading::{ShadingModel, ShadingModelRegistration, Svbrdf};
use matup_core::tensor_shading::TensorShading;
use matup_core::{LightSample, Result};

use glam::Vec3;

use crate::clamps::{clamp_dot, normalize, normalize_backward};

/// Lambertian reflection of the base colour: `I · N·L · base / π`. Metallic and roughness
/// are ignored.
pub struct Lambert;

impl ShadingModel for Lambert {
    fn shade(&self, p: &Svbrdf, light: &LightSample) -> [f32; 3] {
        let (n, _) = normalize(p.normal.into());
        let (nol, _) = clamp_dot(n.dot(light.direction.into()));
        p.base_color.map(|b| light.intensity * nol * b / PI)
    }

    fn shade_jacobian(&self, p: &Svbrdf, light: &LightSample) -> Option<([f32; 3], [Svbrdf; 3])> {
        let l = Vec3::from(light.direction);
        let (n, len) = normalize(p.normal.into());
        let (nol, free) = clamp_dot(n.dot(l));
        let mut jac = [Svbrdf::default(); 3];
        for (c, j) in jac.iter_mut().enumerate() {
            let b = p.base_color[c];
            j.base_color[c] = light.intensity * nol / PI;
            let g_unit = l * (light.intensity * b / PI * free);
            j.normal = normalize_backward(g_unit, n, len).into();
        }
        Some((p.base_color.map(|b| light.intensity * nol * b / PI), jac))
    }

    fn tensor_form(&self) -> Option<&dyn TensorShading> {
        Some(self)
    }
}

fn create(argument: Option<&str>) -> Result<Box<dyn ShadingModel>> {
    matup_core::plugin::parse_options("lambert", argument, &[])?;
    Ok(Box::new(Lambert))
}

inventory::submit! {
    ShadingModelRegistration {
        name: "lambert",
        description: "Lambertian diffuse only (base colour / π); for ablations and fast previews",
        options: &[],
        create,
    }
}
