//! `ggx-aniso`: anisotropic GGX (Burley's parameterisation), identical to `ggx` where the
//! anisotropy is 0. Written once over [`Real`], so the Jacobian comes from dual numbers.

use std::f32::consts::PI;

use matup_core::material::MIN_ALPHA;
use matup_core::shading::{ShadingModel, ShadingModelRegistration, Svbrdf};
use matup_core::tensor_shading::TensorShading;
use matup_core::{LightSample, Result};

use crate::dual::{Dual, Real};
use glam::Vec3;

use crate::clamps::{half_vector, DENOMINATOR_MIN, DOT_MAX, DOT_MIN, TINY_LENGTH2};

/// Anisotropic GGX: roughness `alpha_t = alpha·(1 + k)` along the tangent and
/// `alpha_b = alpha·(1 − k)` along the bitangent (each ≥ 2e-3), the tangent at
/// `anisotropy_angle` from +x projected onto the tangent plane. Anisotropic Smith
/// height-correlated visibility, Schlick Fresnel, the same diffuse as `ggx`.
pub struct GgxAniso;

/// A 3-vector of plain or dual numbers. glam's vectors hold only f32 or f64, so the few
/// operations this model needs over [`Real`] are written here.
type V<S> = [S; 3];

fn dot<S: Real>(a: V<S>, b: V<S>) -> S {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

fn dot_const<S: Real>(a: V<S>, b: Vec3) -> S {
    a[0] * S::constant(b.x) + a[1] * S::constant(b.y) + a[2] * S::constant(b.z)
}

fn normalize<S: Real>(v: V<S>) -> V<S> {
    let len = dot(v, v).at_least(TINY_LENGTH2).sqrt();
    v.map(|c| c / len)
}

fn cross<S: Real>(a: V<S>, b: V<S>) -> V<S> {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

fn radiance<S: Real>(p: [S; Svbrdf::LEN], light: &LightSample) -> [S; 3] {
    let c = S::constant;
    let l = Vec3::from(light.direction);
    let h = half_vector(l);
    let base = [p[0], p[1], p[2]];
    let m = p[3];
    let n = normalize([p[4], p[5], p[6]]);
    let (alpha, k, theta) = (p[7], p[8], p[9]);

    let noh_raw = dot_const(n, h);
    let loh = l.dot(h).clamp(DOT_MIN, DOT_MAX);
    let chi = if noh_raw.value() > 0.0 && l.dot(h) > 0.0 {
        1.0
    } else {
        0.0
    };
    let nol = dot_const(n, l).clamp_to(DOT_MIN, DOT_MAX);
    let nov = n[2].clamp_to(DOT_MIN, DOT_MAX);
    let noh = noh_raw.clamp_to(DOT_MIN, DOT_MAX);

    // Tangent frame: the direction θ projected onto the tangent plane (Gram–Schmidt).
    let t0 = [theta.cos(), theta.sin(), c(0.0)];
    let along = dot(t0, n);
    let t = normalize([
        t0[0] - along * n[0],
        t0[1] - along * n[1],
        t0[2] - along * n[2],
    ]);
    let b = cross(n, t);

    let a = alpha.clamp_to(MIN_ALPHA, 1.0);
    let k = k.clamp_to(-1.0, 1.0);
    let at = (a * (c(1.0) + k)).at_least(MIN_ALPHA);
    let ab = (a * (c(1.0) - k)).at_least(MIN_ALPHA);

    let (toh, boh) = (dot_const(t, h), dot_const(b, h));
    let q = toh * toh / (at * at) + boh * boh / (ab * ab) + noh * noh;
    let d = c(1.0) / (c(PI) * at * ab * q * q).at_least(DENOMINATOR_MIN);

    let (tol, bol) = (dot_const(t, l), dot_const(b, l));
    let (tov, bov) = (t[2], b[2]);
    let lambda_v = (at * tov * at * tov + ab * bov * ab * bov + nov * nov).sqrt();
    let lambda_l = (at * tol * at * tol + ab * bol * ab * bol + nol * nol).sqrt();
    let vis = c(0.5) / (nol * lambda_v + nov * lambda_l).at_least(DENOMINATOR_MIN);

    let schlick = (1.0 - loh).powi(5);
    let spec = c(chi) * d * vis;
    std::array::from_fn(|ch| {
        let f0 = c(0.04) * (c(1.0) - m) + m * base[ch];
        let fresnel = f0 * c(1.0 - schlick) + c(schlick);
        let diffuse = (c(1.0) - m) * base[ch] / c(PI);
        c(light.intensity) * nol * (diffuse + spec * fresnel)
    })
}

impl ShadingModel for GgxAniso {
    fn shade(&self, p: &Svbrdf, light: &LightSample) -> [f32; 3] {
        radiance(p.to_array(), light)
    }

    fn shade_jacobian(&self, p: &Svbrdf, light: &LightSample) -> Option<([f32; 3], [Svbrdf; 3])> {
        let params = p.to_array();
        let duals: [Dual; Svbrdf::LEN] = std::array::from_fn(|i| Dual::variable(params[i], i));
        let out = radiance(duals, light);
        Some((
            out.map(|d| d.value),
            out.map(|d| Svbrdf::from_array(d.grad)),
        ))
    }

    fn tensor_form(&self) -> Option<&dyn TensorShading> {
        Some(self)
    }
}

fn create(argument: Option<&str>) -> Result<Box<dyn ShadingModel>> {
    matup_core::plugin::parse_options("ggx-aniso", argument, &[])?;
    Ok(Box::new(GgxAniso))
}

inventory::submit! {
    ShadingModelRegistration {
        name: "ggx-aniso",
        description: "anisotropic GGX; reads optional anisotropy strength and direction maps, equals ggx where they are 0",
        options: &[],
        create,
    }
}
