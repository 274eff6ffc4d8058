//! Loss norms over the per-light RGB errors of a texel, in display space.

use std::fmt;
use std::str::FromStr;

use crate::{Error, Result};

/// The norm that turns the display-space RGB errors `e_ω` of one texel under every light into
/// a loss: `Σ_ω ‖e_ω‖_p^q`. `L21` (p = 2, q = 1) is METHOD.md's l2,1 norm: sparse across
/// lights, so an outlier light costs little. `L22` is the squared error (MSE up to a factor).
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub enum LossNorm {
    #[default]
    L21,
    L11,
    L22,
    /// General `‖e‖_p^q` with p ≥ 1, q > 0.
    Lpq {
        p: f32,
        q: f32,
    },
}

/// Below this squared length an error counts as zero (its gradient is zero, not NaN).
const TINY: f32 = 1e-20;

impl LossNorm {
    /// The loss of one light's error `e` (rendered − target) and its gradient with respect to `e`.
    #[inline]
    pub fn eval(&self, e: [f32; 3]) -> (f32, [f32; 3]) {
        match *self {
            LossNorm::L21 => {
                // Without a return, so that loops over lights stay branch-free.
                let n2 = e[0] * e[0] + e[1] * e[1] + e[2] * e[2];
                let tiny = n2 <= TINY;
                let n = n2.max(TINY).sqrt();
                (n, e.map(|v| if tiny { 0.0 } else { v / n }))
            }
            LossNorm::L11 => (
                e[0].abs() + e[1].abs() + e[2].abs(),
                e.map(|v| if v == 0.0 { 0.0 } else { v.signum() }),
            ),
            LossNorm::L22 => (e[0] * e[0] + e[1] * e[1] + e[2] * e[2], e.map(|v| 2.0 * v)),
            LossNorm::Lpq { p, q } => {
                let sum: f32 = e.iter().map(|v| v.abs().powf(p)).sum();
                if sum <= TINY {
                    return (0.0, [0.0; 3]);
                }
                let n = sum.powf(1.0 / p);
                let outer = q * n.powf(q - 1.0) * n.powf(1.0 - p);
                (
                    n.powf(q),
                    e.map(|v| outer * v.signum() * v.abs().powf(p - 1.0)),
                )
            }
        }
    }
}

impl FromStr for LossNorm {
    type Err = Error;
    /// `l21`, `l11`, `l22`, or `lpq:P,Q` (e.g. `lpq:1.5,1`).
    fn from_str(s: &str) -> Result<Self> {
        let bad = || {
            Error::Invalid(format!(
                "unknown loss norm '{s}'; use l21, l11, l22 or lpq:P,Q (P ≥ 1, Q > 0)"
            ))
        };
        match s {
            "l21" => Ok(LossNorm::L21),
            "l11" => Ok(LossNorm::L11),
            "l22" => Ok(LossNorm::L22),
            _ => {
                let rest = s.strip_prefix("lpq:").ok_or_else(bad)?;
                let (p, q) = rest.split_once(',').ok_or_else(bad)?;
                let p: f32 = p.trim().parse().map_err(|_| bad())?;
                let q: f32 = q.trim().parse().map_err(|_| bad())?;
                if !(p >= 1.0 && q > 0.0 && p.is_finite() && q.is_finite()) {
                    return Err(bad());
                }
                Ok(LossNorm::Lpq { p, q })
            }
        }
    }
}

impl fmt::Display for LossNorm {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            LossNorm::L21 => f.write_str("l21"),
            LossNorm::L11 => f.write_str("l11"),
            LossNorm::L22 => f.write_str("l22"),
            LossNorm::Lpq { p, q } => write!(f, "lpq:{p},{q}"),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn general_norm_agrees_with_named_ones() {
        let e = [0.3, -0.1, 0.05];
        for (named, p, q) in [
            (LossNorm::L21, 2.0, 1.0),
            (LossNorm::L11, 1.0, 1.0),
            (LossNorm::L22, 2.0, 2.0),
        ] {
            let (a, ga) = named.eval(e);
            let (b, gb) = LossNorm::Lpq { p, q }.eval(e);
            assert!((a - b).abs() < 1e-5, "{named}: {a} vs {b}");
            for c in 0..3 {
                assert!((ga[c] - gb[c]).abs() < 1e-4, "{named} grad {c}");
            }
        }
    }

    #[test]
    fn gradients_match_finite_differences() {
        let e = [0.3f32, -0.2, 0.07];
        for norm in [
            LossNorm::L21,
            LossNorm::L22,
            LossNorm::Lpq { p: 1.5, q: 0.7 },
        ] {
            let (_, g) = norm.eval(e);
            for c in 0..3 {
                let h = 1e-3;
                let mut a = e;
                let mut b = e;
                a[c] += h;
                b[c] -= h;
                let fd = (norm.eval(a).0 - norm.eval(b).0) / (2.0 * h);
                assert!((fd - g[c]).abs() < 2e-3, "{norm} c={c}: {fd} vs {}", g[c]);
            }
        }
    }

    #[test]
    fn zero_error_has_zero_gradient() {
        for norm in [
            LossNorm::L21,
            LossNorm::L11,
            LossNorm::L22,
            LossNorm::Lpq { p: 3.0, q: 0.5 },
        ] {
            let (l, g) = norm.eval([0.0; 3]);
            assert!(l.is_finite() && l < 1e-9);
            assert_eq!(g, [0.0; 3]);
        }
    }

    #[test]
    fn parses_and_prints() {
        for s in ["l21", "l11", "l22", "lpq:1.5,1"] {
            assert_eq!(s.parse::<LossNorm>().unwrap().to_string(), s);
        }
        assert!("lpq:0.5,1".parse::<LossNorm>().is_err());
        assert!("l3".parse::<LossNorm>().is_err());
    }
}
