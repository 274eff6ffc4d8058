//! Hot loops written to vectorise: run-time dispatch to AVX2 + FMA, and branch-free `exp` and
//! `ln` (the standard library's are scalar calls, which stop a loop from vectorising).

/// Calls `f(args…)` compiled for AVX2 and FMA when the CPU has them. matup builds for
/// baseline x86-64, whose SSE2 halves the vector width of hot loops (the ONNX executor's
/// per-texel loops and Winograd transforms, the fused render + loss) and spills their
/// registers; `f` must be `#[inline(always)]` so that its body is compiled inside the AVX2
/// function. Results are the same either way (no operation is fused).
#[macro_export]
macro_rules! with_avx2 {
    ($f:ident($($arg:expr),* $(,)?)) => {{
        #[cfg(target_arch = "x86_64")]
        {
            if std::arch::is_x86_feature_detected!("avx2")
                && std::arch::is_x86_feature_detected!("fma")
            {
                #[target_feature(enable = "avx2,fma")]
                unsafe fn avx2<F: FnOnce() -> R, R>(f: F) -> R {
                    f()
                }
                // SAFETY: the CPU has AVX2 and FMA.
                unsafe { avx2(|| $f($($arg),*)) }
            } else {
                $f($($arg),*)
            }
        }
        #[cfg(not(target_arch = "x86_64"))]
        {
            $f($($arg),*)
        }
    }};
}

/// e^x in f32 as 2^n · p(r), r = x − n·ln 2, written branch-free so that it vectorises.
/// Relative error below 2·10⁻⁷ on [−87, 88] (tested); outside, x is clamped.
#[inline(always)]
pub fn fast_exp(x: f32) -> f32 {
    const LN2_HI: f32 = 0.693_145_75;
    const LN2_LO: f32 = 1.428_606_8e-6;
    // 1.5·2²³: adding it rounds to an integer n, which lands in the low bits of the sum (so
    // 2ⁿ is built with integer operations, which vectorise, unlike a float-to-int cast).
    const ROUND: f32 = 12_582_912.0;
    let x = x.clamp(-87.0, 88.0);
    let t = x * std::f32::consts::LOG2_E + ROUND;
    let n = t - ROUND;
    let two_to_n =
        f32::from_bits(t.to_bits().wrapping_sub(ROUND.to_bits()).wrapping_add(127) << 23);
    let r = (x - n * LN2_HI) - n * LN2_LO;
    // Taylor to r⁷/5040 (|r| ≤ ln2/2, so the first term left out is below 2·10⁻⁸).
    let p = 1.0
        + r * (1.0
            + r * (0.5
                + r * (1.0 / 6.0
                    + r * (1.0 / 24.0 + r * (1.0 / 120.0 + r * (1.0 / 720.0 + r / 5040.0))))));
    p * two_to_n
}

/// ln x in f32 for finite x > 0, as e·ln 2 + ln m with m ∈ [√½, √2), ln m from the series of
/// 2·atanh((m − 1)/(m + 1)); branch-free so that it vectorises. Error below
/// 2·10⁻⁷·max(1, |ln x|) for normal x (tested), about the f32 rounding of the result. 0 gives
/// ≈ −88.
#[inline(always)]
pub fn fast_ln(x: f32) -> f32 {
    let bits = x.to_bits();
    // Halve mantissas above √2 (and add one to the exponent) so that |s| ≤ 0.172 below.
    let high = (bits & 0x007f_ffff) > 0x0035_04f3;
    let exponent = ((bits >> 23) & 0xff) as i32 - 127 + high as i32;
    let m = f32::from_bits((bits & 0x007f_ffff) | if high { 0x3f00_0000 } else { 0x3f80_0000 });
    let s = (m - 1.0) / (m + 1.0);
    let s2 = s * s;
    // 2·(s + s³/3 + … + s⁹/9); the first term left out is below 10⁻⁹.
    let series = 2.0 * s * (1.0 + s2 * (1.0 / 3.0 + s2 * (0.2 + s2 * (1.0 / 7.0 + s2 / 9.0))));
    exponent as f32 * std::f32::consts::LN_2 + series
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fast_exp_matches_the_exact_one() {
        let mut worst = 0.0f64;
        for k in -80_000..=80_000 {
            let x = k as f32 * 1e-3;
            let exact = (x as f64).exp();
            worst = worst.max(((fast_exp(x) as f64 - exact) / exact).abs());
        }
        assert!(worst < 2e-7, "{worst}");
        assert!(fast_exp(-200.0) >= 0.0 && fast_exp(200.0).is_finite());
    }

    #[test]
    fn fast_ln_matches_the_exact_one() {
        let mut worst = 0.0f64;
        let mut x = 1e-30f32;
        while x < 1e30 {
            let exact = (x as f64).ln();
            worst = worst.max((fast_ln(x) as f64 - exact).abs() / exact.abs().max(1.0));
            x *= 1.000_37;
        }
        assert!(worst < 2e-7, "{worst}");
        assert_eq!(fast_ln(1.0), 0.0);
        assert!(fast_ln(0.0) < -80.0);
    }
}
