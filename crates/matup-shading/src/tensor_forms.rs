//! The built-in models' tensor forms (`ShadingModel::tensor_form`): the same formulas as
//! their scalar forms, over `[T, L, ·]` tensors, with the same clamps (METHOD.md).

use std::f64::consts::PI;

use matup_core::candle_core::{DType, Result, Tensor};
use matup_core::material::MIN_ALPHA;
use matup_core::tensor_shading::{
    dot, normalize, view, LightTensors, SvbrdfTensors, TensorShading,
};

use crate::clamps::{DENOMINATOR_MIN, DOT_MAX, DOT_MIN};
use crate::{Ggx, GgxAniso, Lambert};

/// A cosine clamped to [`DOT_MIN`, `DOT_MAX`] (no gradient where clamped).
fn clamp_dot(x: &Tensor) -> Result<Tensor> {
    x.clamp(DOT_MIN, DOT_MAX)
}

/// `1 − x`.
fn one_minus(x: &Tensor) -> Result<Tensor> {
    x.affine(-1.0, 1.0)
}

/// What every GGX lobe needs: the unit normal `[T, 1, 3]`, the half vectors `[T, L, 3]`, the
/// clamped N·L, N·V, N·H `[T, L, 1]` (N·V `[T, 1, 1]`), the Schlick weight `(1 − L·H)⁵` and
/// the Heaviside χ on N·H and L·H (before clamping).
struct Lobe {
    n: Tensor,
    h: Tensor,
    nol: Tensor,
    nov: Tensor,
    noh: Tensor,
    schlick: Tensor,
    chi: Tensor,
}

fn lobe(p: &SvbrdfTensors, lights: &LightTensors) -> Result<Lobe> {
    let l = &lights.direction;
    let n = normalize(&p.normal)?;
    let h = normalize(&l.broadcast_add(&view(l.device())?)?)?;
    let noh_raw = dot(&n, &h)?;
    let loh_raw = dot(l, &h)?;
    let chi =
        (noh_raw.gt(0f32)?.to_dtype(DType::F32)? * loh_raw.gt(0f32)?.to_dtype(DType::F32)?)?;
    Ok(Lobe {
        nol: clamp_dot(&dot(&n, l)?)?,
        nov: clamp_dot(&n.narrow(2, 2, 1)?)?,
        noh: clamp_dot(&noh_raw)?,
        schlick: one_minus(&clamp_dot(&loh_raw)?)?.powf(5.0)?,
        chi,
        n,
        h,
    })
}

/// `I · N·L · ((1 − m)·base/π + χ·D·V·F)` with `F0 = 0.04(1 − m) + m·base`: the radiance of
/// every GGX lobe given its `D·V` (`[T, L, 1]`).
fn cook_torrance(
    p: &SvbrdfTensors,
    lights: &LightTensors,
    k: &Lobe,
    dv: &Tensor,
) -> Result<Tensor> {
    let (m, b) = (&p.metallic, &p.base_color);
    let f0 = m.affine(-0.04, 0.04)?.broadcast_add(&m.broadcast_mul(b)?)?;
    let fresnel = f0
        .broadcast_mul(&one_minus(&k.schlick)?)?
        .broadcast_add(&k.schlick)?;
    let diffuse = (one_minus(m)?.broadcast_mul(b)? / PI)?;
    let spec = (&k.chi * dv)?;
    fresnel
        .broadcast_mul(&spec)?
        .broadcast_add(&diffuse)?
        .broadcast_mul(&k.nol)?
        .broadcast_mul(&lights.intensity)
}

impl TensorShading for Ggx {
    fn shade(&self, p: &SvbrdfTensors, lights: &LightTensors) -> Result<Tensor> {
        let k = lobe(p, lights)?;
        let a2 = p.alpha.clamp(MIN_ALPHA, 1.0f32)?.sqr()?;
        let den0 = (k.noh.sqr()?.broadcast_mul(&(&a2 - 1.0)?)? + 1.0)?;
        let d = a2.broadcast_div(&(den0.sqr()? * PI)?.maximum(DENOMINATOR_MIN)?)?;
        let rough = one_minus(&a2)?;
        let gv = k.nov.sqr()?.mul(&rough)?.add(&a2)?.sqrt()?;
        let gl = k
            .nol
            .sqr()?
            .broadcast_mul(&rough)?
            .broadcast_add(&a2)?
            .sqrt()?;
        let vden = (k.nol.broadcast_mul(&gv)? + gl.broadcast_mul(&k.nov)?)?;
        let vis = (vden.maximum(DENOMINATOR_MIN)?.recip()? * 0.5)?;
        cook_torrance(p, lights, &k, &(d * vis)?)
    }
}

/// `a × b` along the last dimension (broadcasting).
fn cross(a: &Tensor, b: &Tensor) -> Result<Tensor> {
    let c = |t: &Tensor, i: usize| t.narrow(2, i, 1);
    let (a0, a1, a2) = (c(a, 0)?, c(a, 1)?, c(a, 2)?);
    let (b0, b1, b2) = (c(b, 0)?, c(b, 1)?, c(b, 2)?);
    Tensor::cat(
        &[
            (a1.broadcast_mul(&b2)? - a2.broadcast_mul(&b1)?)?,
            (a2.broadcast_mul(&b0)? - a0.broadcast_mul(&b2)?)?,
            (a0.broadcast_mul(&b1)? - a1.broadcast_mul(&b0)?)?,
        ],
        2,
    )
}

impl TensorShading for GgxAniso {
    fn shade(&self, p: &SvbrdfTensors, lights: &LightTensors) -> Result<Tensor> {
        let k = lobe(p, lights)?;
        let l = &lights.direction;
        // Tangent frame: the direction θ projected onto the tangent plane (Gram–Schmidt).
        let theta = &p.anisotropy_angle;
        let t0 = Tensor::cat(&[theta.cos()?, theta.sin()?, theta.zeros_like()?], 2)?;
        let t = normalize(&(&t0 - dot(&t0, &k.n)?.broadcast_mul(&k.n)?)?)?;
        let b = cross(&k.n, &t)?;

        let a = p.alpha.clamp(MIN_ALPHA, 1.0f32)?;
        let aniso = p.anisotropy.clamp(-1.0f32, 1.0f32)?;
        let at = (&a * (&aniso + 1.0)?)?.maximum(MIN_ALPHA)?;
        let ab = (&a * one_minus(&aniso)?)?.maximum(MIN_ALPHA)?;

        let (toh, boh) = (dot(&t, &k.h)?, dot(&b, &k.h)?);
        let q = (toh.sqr()?.broadcast_div(&at.sqr()?)?
            + boh.sqr()?.broadcast_div(&ab.sqr()?)?
            + k.noh.sqr()?)?;
        let d = ((&at * &ab)? * PI)?
            .broadcast_mul(&q.sqr()?)?
            .maximum(DENOMINATOR_MIN)?
            .recip()?;

        let (tol, bol) = (dot(&t, l)?, dot(&b, l)?);
        let (tov, bov) = (t.narrow(2, 2, 1)?, b.narrow(2, 2, 1)?);
        let lambda_v = ((&at * &tov)?.sqr()? + (&ab * &bov)?.sqr()? + k.nov.sqr()?)?.sqrt()?;
        let lambda_l =
            (tol.broadcast_mul(&at)?.sqr()? + bol.broadcast_mul(&ab)?.sqr()? + k.nol.sqr()?)?
                .sqrt()?;
        let vden = (k.nol.broadcast_mul(&lambda_v)? + lambda_l.broadcast_mul(&k.nov)?)?;
        let vis = (vden.maximum(DENOMINATOR_MIN)?.recip()? * 0.5)?;
        cook_torrance(p, lights, &k, &(d * vis)?)
    }
}

impl TensorShading for Lambert {
    fn shade(&self, p: &SvbrdfTensors, lights: &LightTensors) -> Result<Tensor> {
        let n = normalize(&p.normal)?;
        let nol = clamp_dot(&dot(&n, &lights.direction)?)?;
        (p.base_color.broadcast_mul(&nol)? / PI)?.broadcast_mul(&lights.intensity)
    }
}
