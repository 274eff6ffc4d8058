//! `blinn-phong`: a Lambertian diffuse lobe and a normalised Blinn–Phong specular lobe with
//! Schlick Fresnel, the shininess from alpha by `s = 2/α² − 2`. The model has no Jacobian:
//! it gives its radiance per texel (`shade`, for renders) and the same formula as candle
//! operations (`tensor_form`), which the tensor training backend differentiates.

use std::f32::consts::PI;

use matup_core::candle_core::{Result as CandleResult, Tensor};
use matup_core::material::MIN_ALPHA;
use matup_core::shading::{ShadingModel, ShadingModelRegistration, Svbrdf, VIEW};
use matup_core::tensor_shading::{
    dot, normalize, view, LightTensors, SvbrdfTensors, TensorShading,
};
use matup_core::{LightSample, Result};

/// Cosines are clamped as the built-in models clamp them.
const DOT_MIN: f32 = 1e-8;
const DOT_MAX: f32 = 0.9999;

pub struct BlinnPhong;

fn unit(v: [f32; 3]) -> [f32; 3] {
    let len = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).max(1e-20).sqrt();
    v.map(|c| c / len)
}

fn cosine(a: [f32; 3], b: [f32; 3]) -> f32 {
    (a[0] * b[0] + a[1] * b[1] + a[2] * b[2]).clamp(DOT_MIN, DOT_MAX)
}

impl ShadingModel for BlinnPhong {
    fn shade(&self, p: &Svbrdf, light: &LightSample) -> [f32; 3] {
        let (n, l) = (unit(p.normal), light.direction);
        let h = unit([l[0] + VIEW[0], l[1] + VIEW[1], l[2] + VIEW[2]]);
        let (nol, noh, loh) = (cosine(n, l), cosine(n, h), cosine(l, h));
        let a = p.alpha.clamp(MIN_ALPHA, 1.0);
        let s = 2.0 / (a * a) - 2.0;
        let specular = (s + 2.0) / (8.0 * PI) * (s * noh.ln()).exp();
        let schlick = (1.0 - loh).powi(5);
        let m = p.metallic;
        p.base_color.map(|b| {
            let f0 = 0.04 * (1.0 - m) + m * b;
            let fresnel = f0 + (1.0 - f0) * schlick;
            light.intensity * nol * ((1.0 - m) * b / PI + fresnel * specular)
        })
    }

    fn tensor_form(&self) -> Option<&dyn TensorShading> {
        Some(self)
    }
}

impl TensorShading for BlinnPhong {
    fn shade(&self, p: &SvbrdfTensors, lights: &LightTensors) -> CandleResult<Tensor> {
        let l = &lights.direction;
        let n = normalize(&p.normal)?;
        let h = normalize(&l.broadcast_add(&view(l.device())?)?)?;
        let cosine = |a: &Tensor, b: &Tensor| dot(a, b)?.clamp(DOT_MIN, DOT_MAX);
        let (nol, noh, loh) = (cosine(&n, l)?, cosine(&n, &h)?, cosine(l, &h)?);
        let a = p.alpha.clamp(MIN_ALPHA, 1f32)?;
        let s = (a.sqr()?.recip()? * 2.0)?.affine(1.0, -2.0)?;
        let specular = ((&s + 2.0)? / (8.0 * std::f64::consts::PI))?
            .broadcast_mul(&noh.log()?.broadcast_mul(&s)?.exp()?)?;
        let schlick = loh.affine(-1.0, 1.0)?.powf(5.0)?;
        let (m, b) = (&p.metallic, &p.base_color);
        let f0 = m.affine(-0.04, 0.04)?.broadcast_add(&m.broadcast_mul(b)?)?;
        let fresnel = f0.broadcast_add(&f0.affine(-1.0, 1.0)?.broadcast_mul(&schlick)?)?;
        let diffuse = (m.affine(-1.0, 1.0)?.broadcast_mul(b)? / std::f64::consts::PI)?;
        fresnel
            .broadcast_mul(&specular)?
            .broadcast_add(&diffuse)?
            .broadcast_mul(&nol)?
            .broadcast_mul(&lights.intensity)
    }
}

fn create(argument: Option<&str>) -> Result<Box<dyn ShadingModel>> {
    matup_core::plugin::parse_options("blinn-phong", argument, &[])?;
    Ok(Box::new(BlinnPhong))
}

matup_core::inventory::submit! {
    ShadingModelRegistration {
        name: "blinn-phong",
        description: "normalised Blinn–Phong with Lambert diffuse (example plugin; tensor form only: trains with --backend tensor)",
        options: &[],
        create,
    }
}
