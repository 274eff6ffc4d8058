//! `ggx`: the Cook–Torrance model of METHOD.md, with a hand-derived Jacobian (it is the
//! training hot path).

use std::f32::consts::PI;

use matup_core::material::MIN_ALPHA;
use matup_core::shading::{ShadingModel, ShadingModelRegistration, Svbrdf, VIEW};
use matup_core::{LightSample, Result};

use crate::vec3::*;

/// Cook–Torrance with GGX distribution, Smith height-correlated visibility and Schlick
/// Fresnel; Lambertian diffuse `(1 − m)·base/π`, `F0 = 0.04(1 − m) + m·base`.
pub struct Ggx;

/// Everything about one texel and light that does not depend on the colour channel.
struct Lobe {
    n: V3,
    normal_len: f32,
    h: V3,
    nol: f32,
    nol_free: f32,
    nov: f32,
    nov_free: f32,
    noh: f32,
    noh_free: f32,
    /// Schlick weight `(1 − L·H)⁵`.
    schlick: f32,
    /// Heaviside on N·H and L·H (before clamping).
    chi: f32,
    a: f32,
    a_free: f32,
    d: f32,
    vis: f32,
}

#[inline]
fn lobe(p: &Svbrdf, light: &LightSample) -> Lobe {
    let l = light.direction;
    let (n, normal_len) = normalize(p.normal);
    let h = half_vector(l);
    let (noh_raw, loh_raw) = (dot(n, h), dot(l, h));
    let chi = if noh_raw > 0.0 && loh_raw > 0.0 {
        1.0
    } else {
        0.0
    };
    let (nol, nol_free) = clamp_dot(dot(n, l));
    let (nov, nov_free) = clamp_dot(dot(n, VIEW));
    let (noh, noh_free) = clamp_dot(noh_raw);
    let (loh, _) = clamp_dot(loh_raw);
    let (a, a_free) = if p.alpha < MIN_ALPHA {
        (MIN_ALPHA, 0.0)
    } else if p.alpha > 1.0 {
        (1.0, 0.0)
    } else {
        (p.alpha, 1.0)
    };
    let a2 = a * a;
    let den0 = noh * noh * (a2 - 1.0) + 1.0;
    let d = a2 / (PI * den0 * den0).max(DENOMINATOR_MIN);
    let gv = (nov * nov * (1.0 - a2) + a2).sqrt();
    let gl = (nol * nol * (1.0 - a2) + a2).sqrt();
    let vis = 0.5 / (nol * gv + nov * gl).max(DENOMINATOR_MIN);
    let one_minus = 1.0 - loh;
    let schlick = one_minus * one_minus * one_minus * one_minus * one_minus;
    Lobe {
        n,
        normal_len,
        h,
        nol,
        nol_free,
        nov,
        nov_free,
        noh,
        noh_free,
        schlick,
        chi,
        a,
        a_free,
        d,
        vis,
    }
}

impl ShadingModel for Ggx {
    #[inline]
    fn shade(&self, p: &Svbrdf, light: &LightSample) -> [f32; 3] {
        let k = lobe(p, light);
        let m = p.metallic;
        let spec = k.chi * k.d * k.vis;
        std::array::from_fn(|c| {
            let b = p.base_color[c];
            let f0 = 0.04 * (1.0 - m) + m * b;
            let fresnel = f0 * (1.0 - k.schlick) + k.schlick;
            light.intensity * k.nol * ((1.0 - m) * b / PI + spec * fresnel)
        })
    }

    #[inline]
    fn shade_jacobian(&self, p: &Svbrdf, light: &LightSample) -> ([f32; 3], [Svbrdf; 3]) {
        let k = lobe(p, light);
        let (m, intensity, l) = (p.metallic, light.intensity, light.direction);
        let a2 = k.a * k.a;
        let spec = k.chi * k.d * k.vis;

        // Derivatives of D and V through the clamped cosines and a² (zero where a floor bit).
        let den0 = k.noh * k.noh * (a2 - 1.0) + 1.0;
        let den = PI * den0 * den0;
        let den_free = if den > DENOMINATOR_MIN { 1.0 } else { 0.0 };
        let den_clamped = den.max(DENOMINATOR_MIN);
        let dd_dden = -a2 / (den_clamped * den_clamped) * den_free;
        let dd_dnoh = dd_dden * PI * 2.0 * den0 * 2.0 * k.noh * (a2 - 1.0);
        let dd_da2 = 1.0 / den_clamped + dd_dden * PI * 2.0 * den0 * k.noh * k.noh;

        let gv = (k.nov * k.nov * (1.0 - a2) + a2).sqrt();
        let gl = (k.nol * k.nol * (1.0 - a2) + a2).sqrt();
        let vden = k.nol * gv + k.nov * gl;
        let vden_free = if vden > DENOMINATOR_MIN { 1.0 } else { 0.0 };
        let dvis_dvden = -2.0 * k.vis * k.vis * vden_free; // d(0.5/x)/dx = −0.5/x² = −2·vis²
        let dvden_dnol = gv + k.nov * k.nol * (1.0 - a2) / gl;
        let dvden_dnov = k.nol * k.nov * (1.0 - a2) / gv + gl;
        let dvden_da2 =
            k.nol * (1.0 - k.nov * k.nov) / (2.0 * gv) + k.nov * (1.0 - k.nol * k.nol) / (2.0 * gl);

        // Gradient of D·V with respect to the unit normal (channel independent), and to alpha.
        let dv = k.d * dvis_dvden;
        let l_free = scale(l, k.nol_free);
        let g_spec = add_scaled(
            add_scaled(
                scale(l_free, dv * dvden_dnol),
                VIEW,
                dv * dvden_dnov * k.nov_free,
            ),
            k.h,
            k.vis * dd_dnoh * k.noh_free,
        );
        let dspec_dalpha = (dd_da2 * k.vis + dv * dvden_da2) * 2.0 * k.a * k.a_free;

        let mut rgb = [0.0; 3];
        let mut jac = [Svbrdf::default(); 3];
        for c in 0..3 {
            let b = p.base_color[c];
            let f0 = 0.04 * (1.0 - m) + m * b;
            let fresnel = f0 * (1.0 - k.schlick) + k.schlick;
            let diffuse = (1.0 - m) * b / PI;
            rgb[c] = intensity * k.nol * (diffuse + spec * fresnel);

            let j = &mut jac[c];
            j.base_color[c] = intensity * k.nol * ((1.0 - m) / PI + spec * m * (1.0 - k.schlick));
            j.metallic = intensity * k.nol * (-b / PI + spec * (1.0 - k.schlick) * (b - 0.04));
            // radiance = I·NoL·diffuse + I·NoL·F·χ·D·V
            let through_nol = intensity * (diffuse + spec * fresnel);
            let through_spec = intensity * k.nol * fresnel * k.chi;
            let g_unit = add_scaled(scale(l_free, through_nol), g_spec, through_spec);
            j.normal = normalize_backward(g_unit, k.n, k.normal_len);
            j.alpha = through_spec * dspec_dalpha;
        }
        (rgb, jac)
    }
}

fn create(argument: Option<&str>) -> Result<Box<dyn ShadingModel>> {
    matup_core::plugin::parse_options("ggx", argument, &[])?;
    Ok(Box::new(Ggx))
}

inventory::submit! {
    ShadingModelRegistration {
        name: "ggx",
        description: "Cook–Torrance GGX (Smith height-correlated, Schlick), METHOD.md's reference model",
        options: &[],
        create,
    }
}
