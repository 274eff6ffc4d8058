//! Colour transfer functions: sRGB encoding and the display transform renders are compared in.

use candle_core::Tensor;
use matup_simd::simd::{fast_exp, fast_ln};

/// sRGB-encoded value in [0, 1] → linear.
#[inline]
pub fn srgb_to_linear(v: f32) -> f32 {
    if v <= 0.04045 {
        v / 12.92
    } else {
        ((v + 0.055) / 1.055).powf(2.4)
    }
}

/// The sRGB transfer curve and its slope at a linear value `v` in [0, 1], from
/// `power = v^(1/2.4)`: the one definition of the curve (file encoding, display and its
/// gradient). The slope of `1.055·v^(1/2.4) − 0.055` is `1.055·v^(1/2.4) / (2.4·v)`.
#[inline(always)]
fn srgb_from_power(v: f32, power: f32) -> (f32, f32) {
    let curve = (1.055 * power - 0.055, 1.055 * power / (2.4 * v));
    if v <= 0.003_130_8 {
        (12.92 * v, 12.92)
    } else {
        curve
    }
}

/// The sRGB curve and its slope for a linear value in [0, 1], with the standard library's
/// `powf` (fastest in scalar code: file encoding, renders).
#[inline]
pub fn srgb_encode(v: f32) -> (f32, f32) {
    let v = v.max(0.0);
    srgb_from_power(v, v.powf(1.0 / 2.4))
}

/// [`srgb_encode`] with the power as `exp(ln v / 2.4)` from `matup_simd::simd`, which has no
/// call or branch, so that loops over many values (the training loss's lights) vectorise.
/// Within 10⁻⁶ of [`srgb_encode`] (tested).
#[inline(always)]
pub fn srgb_encode_vectorisable(v: f32) -> (f32, f32) {
    let v = v.max(0.0);
    srgb_from_power(v, fast_exp(fast_ln(v) * (1.0 / 2.4)))
}

/// Linear value → sRGB-encoded, for values in [0, 1].
#[inline]
pub fn linear_to_srgb(v: f32) -> f32 {
    srgb_encode(v).0
}

/// [`srgb_to_linear`] of every value of `t`, on its device.
pub fn srgb_to_linear_tensor(t: &Tensor) -> candle_core::Result<Tensor> {
    let curve = ((t + 0.055)? / 1.055)?.powf(2.4)?;
    t.le(0.04045)?.where_cond(&(t / 12.92)?, &curve)
}

/// [`linear_to_srgb`] of every value of `t`, on its device.
pub fn linear_to_srgb_tensor(t: &Tensor) -> candle_core::Result<Tensor> {
    let v = t.maximum(0f32)?;
    // The exponent as the host's f32 holds it.
    let curve = v.powf((1.0f32 / 2.4) as f64)?.affine(1.055, -0.055)?;
    v.le(0.003_130_8)?.where_cond(&(&v * 12.92)?, &curve)
}

/// A [0, 1] value as 8 bits, rounded (truncation would drift flat normals and dark colours
/// down by half a step); values outside are clamped.
#[inline]
pub fn to_u8(v: f32) -> u8 {
    (v.clamp(0.0, 1.0) * 255.0).round() as u8
}

/// Reinhard tone mapping `t / (1 + t)`, then the sRGB curve `encode`: the display transform
/// and its derivative with respect to the radiance.
#[inline(always)]
fn display_through(radiance: f32, encode: impl Fn(f32) -> (f32, f32)) -> (f32, f32) {
    // Radiance is never negative in practice; below 0 the clamp has no gradient.
    let t = radiance.max(0.0);
    let inv = 1.0 / (1.0 + t);
    let (value, slope) = encode(t * inv);
    (
        value,
        if radiance > 0.0 {
            slope * inv * inv
        } else {
            0.0
        },
    )
}

/// The display transform of METHOD.md: Reinhard tone mapping `t / (1 + t)`, then the sRGB
/// transfer curve, per channel. Renders are compared after it.
#[inline]
pub fn display(radiance: f32) -> f32 {
    display_through(radiance, srgb_encode).0
}

/// [`display`] and its derivative with respect to the radiance, vectorisable (through
/// [`srgb_encode_vectorisable`]): the training loss's form.
#[inline(always)]
pub fn display_with_derivative(radiance: f32) -> (f32, f32) {
    display_through(radiance, srgb_encode_vectorisable)
}

#[cfg(test)]
mod tests {
    #[test]
    fn the_curves_on_a_device_are_the_hosts() {
        let values: Vec<f32> = (0..=1000)
            .map(|i| i as f32 / 1000.0)
            .chain([0.002, 0.04])
            .collect();
        let t = candle_core::Tensor::new(&values[..], &candle_core::Device::Cpu).unwrap();
        let to_linear = super::srgb_to_linear_tensor(&t)
            .unwrap()
            .to_vec1::<f32>()
            .unwrap();
        let to_srgb = super::linear_to_srgb_tensor(&t)
            .unwrap()
            .to_vec1::<f32>()
            .unwrap();
        for (k, &v) in values.iter().enumerate() {
            assert!(
                (to_linear[k] - super::srgb_to_linear(v)).abs() < 1e-6,
                "{v}"
            );
            assert!((to_srgb[k] - super::linear_to_srgb(v)).abs() < 1e-6, "{v}");
        }
    }

    use super::*;

    #[test]
    fn vectorisable_srgb_matches_the_exact_curve() {
        let mut worst = 0.0f32;
        for k in 0..=100_000 {
            let v = k as f32 / 100_000.0;
            let ((value, slope), (exact, exact_slope)) =
                (srgb_encode_vectorisable(v), srgb_encode(v));
            worst = worst
                .max((value - exact).abs())
                .max((slope - exact_slope).abs() / exact_slope);
        }
        assert!(worst < 1e-6, "{worst}");
    }

    #[test]
    fn srgb_round_trips() {
        for i in 0..=100 {
            let v = i as f32 / 100.0;
            assert!((linear_to_srgb(srgb_to_linear(v)) - v).abs() < 1e-5);
        }
    }

    #[test]
    fn display_derivative_matches_finite_differences() {
        for &t in &[1e-4f32, 0.002, 0.01, 0.3, 1.0, 5.0, 40.0] {
            let h = t * 1e-3;
            let fd = (display(t + h) as f64 - display(t - h) as f64) / (2.0 * h as f64);
            let (_, d) = display_with_derivative(t);
            assert!(
                ((d as f64 - fd) / fd).abs() < 1e-2,
                "t={t}: analytic {d}, numeric {fd}"
            );
        }
    }
}
