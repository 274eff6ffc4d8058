//! Which way a normal map's green channel points, measured from the maps when neither the
//! file's name nor its exporter says (docs/experiments/2026-11-26-normal-convention.md).
//!
//! Two signals, both on the normals read as DirectX (matup's frame: y down the rows):
//! - with a height map, the normals' y leans against the height's slope down the rows
//!   (`n ∝ (−∂h/∂x, −∂h/∂y, 1)`): negatively correlated in DirectX, positively in OpenGL;
//! - without one, the slopes `(−n_x/n_z, −n_y/n_z)` of a true normal map are a gradient, so
//!   their curl is small; read in the wrong convention, y's sign flips and the curl grows.

use std::fmt;

use crate::map::Map;
use crate::map_kind::NormalConvention;

/// The height signal is used when the height explains the normals across the rows at least
/// this well (|correlation| of x with the height's slope along the rows) and the signal down
/// the rows is at least as strong as [`MIN_HEIGHT_CORRELATION`].
const MIN_HEIGHT_AGREEMENT: f32 = 0.1;
/// The least |correlation| of y with the height's slope down the rows that decides.
const MIN_HEIGHT_CORRELATION: f32 = 0.1;
/// Curl ratios between the conventions below this are weak evidence.
pub const WEAK_CURL_RATIO: f32 = 1.25;

/// What the maps say about a normal map's convention.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Measured {
    pub convention: NormalConvention,
    pub signal: Signal,
    /// Whether the evidence is too weak to trust (the convention is then a guess).
    pub weak: bool,
}

/// The evidence a measurement rests on.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Signal {
    /// Correlation of the normals' y (read as DirectX) with the height's slope down the rows
    /// (negative: DirectX), and of x with the slope along them.
    Height { y: f32, x: f32 },
    /// Mean |curl| of the slopes read in OpenGL over that read in DirectX (above 1: DirectX).
    Curl { ratio: f32 },
}

impl fmt::Display for Signal {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Signal::Height { y, .. } => write!(
                f,
                "the normals' green against the height's slope down the rows: correlation \
                 {y:+.2}"
            ),
            Signal::Curl { ratio } => write!(
                f,
                "the normals' curl read as OpenGL over read as DirectX: {ratio:.2}"
            ),
        }
    }
}

/// Measures the convention of `normal` (unit normals decoded as DirectX): from `height` when
/// it explains the normals, else from the curl of the normals' slopes when that is clear, else
/// (both weak) from the height's lean if there is one, said to be weak.
pub fn measure(normal: &Map, height: Option<&Map>) -> Measured {
    let from_sign = |downward: bool| {
        if downward {
            NormalConvention::DirectX
        } else {
            NormalConvention::OpenGl
        }
    };
    let height = height
        .filter(|h| (h.width(), h.height()) == (normal.width(), normal.height()))
        .map(|h| height_correlations(normal, h));
    if let Some((y, x)) = height {
        if x <= -MIN_HEIGHT_AGREEMENT && y.abs() >= MIN_HEIGHT_CORRELATION {
            return Measured {
                convention: from_sign(y < 0.0),
                signal: Signal::Height { y, x },
                weak: false,
            };
        }
    }
    let ratio = curl_ratio(normal);
    let curl = Measured {
        convention: from_sign(ratio >= 1.0),
        signal: Signal::Curl { ratio },
        weak: ratio.max(1.0 / ratio) < WEAK_CURL_RATIO,
    };
    match height {
        // Both weak: the height's lean, where it leans the right way across the rows, was
        // right more often than the curl (the study).
        Some((y, x)) if curl.weak && x < 0.0 && y != 0.0 => Measured {
            convention: from_sign(y < 0.0),
            signal: Signal::Height { y, x },
            weak: true,
        },
        _ => curl,
    }
}

/// Correlations of the normals' y with `∂h/∂row` and of x with `∂h/∂column` (central
/// differences, interior texels).
pub fn height_correlations(normal: &Map, height: &Map) -> (f32, f32) {
    let (w, h) = (normal.width(), normal.height());
    let heights = height.plane(0);
    let mut along_rows = Correlation::default();
    let mut down_rows = Correlation::default();
    for y in 1..h.saturating_sub(1) {
        for x in 1..w.saturating_sub(1) {
            let i = y * w + x;
            let dx = heights[i + 1] - heights[i - 1];
            let dy = heights[i + w] - heights[i - w];
            along_rows.add(normal.plane(0)[i] as f64, dx as f64);
            down_rows.add(normal.plane(1)[i] as f64, dy as f64);
        }
    }
    (down_rows.value(), along_rows.value())
}

/// Mean |curl| of the slopes read as OpenGL over that read as DirectX, on 2×2 cells.
pub fn curl_ratio(normal: &Map) -> f32 {
    let (w, h) = (normal.width(), normal.height());
    let slope = |c: usize, i: usize| -normal.plane(c)[i] / normal.plane(2)[i].max(0.1);
    let (mut directx, mut opengl) = (0.0f64, 0.0f64);
    for y in 0..h.saturating_sub(1) {
        for x in 0..w.saturating_sub(1) {
            let [a, b, c, d] = [
                y * w + x,
                y * w + x + 1,
                (y + 1) * w + x,
                (y + 1) * w + x + 1,
            ];
            // ∂p/∂row and ∂q/∂column over the cell, p and q the slopes along x and y.
            let dp_drow = 0.5 * (slope(0, c) + slope(0, d) - slope(0, a) - slope(0, b));
            let dq_dcol = 0.5 * (slope(1, b) + slope(1, d) - slope(1, a) - slope(1, c));
            directx += (dp_drow - dq_dcol).abs() as f64;
            opengl += (dp_drow + dq_dcol).abs() as f64;
        }
    }
    if directx == 0.0 {
        return 1.0;
    }
    (opengl / directx) as f32
}

/// Pearson's correlation, accumulated.
#[derive(Default)]
struct Correlation {
    n: f64,
    a: f64,
    b: f64,
    aa: f64,
    bb: f64,
    ab: f64,
}

impl Correlation {
    fn add(&mut self, a: f64, b: f64) {
        self.n += 1.0;
        self.a += a;
        self.b += b;
        self.aa += a * a;
        self.bb += b * b;
        self.ab += a * b;
    }

    fn value(&self) -> f32 {
        let cov = self.ab - self.a * self.b / self.n.max(1.0);
        let va = self.aa - self.a * self.a / self.n.max(1.0);
        let vb = self.bb - self.b * self.b / self.n.max(1.0);
        if va <= 1e-12 || vb <= 1e-12 {
            return 0.0;
        }
        (cov / (va * vb).sqrt()) as f32
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::material::normalize_normals;

    /// Bumps whose slopes vary along both axes, and the DirectX normals of their heights.
    fn bumps(size: usize) -> (Map, Map) {
        let f = |x: f32, y: f32| {
            (x * 0.37).sin() * (y * 0.23).cos() + 0.5 * (x * 0.11 + y * 0.29).sin()
        };
        let height = Map::from_fn(size, size, 1, |_, y, x| 0.5 + 0.1 * f(x as f32, y as f32));
        let k = 4.0;
        let mut normal = Map::from_fn(size, size, 3, |c, y, x| {
            let (x, y) = (x as f32, y as f32);
            let dx = (f(x + 0.5, y) - f(x - 0.5, y)) * 0.1;
            let dy = (f(x, y + 0.5) - f(x, y - 0.5)) * 0.1;
            [-k * dx, -k * dy, 1.0][c]
        });
        normalize_normals(&mut normal);
        (normal, height)
    }

    fn flipped(normal: &Map) -> Map {
        let mut out = normal.clone();
        out.plane_mut(1).iter_mut().for_each(|v| *v = -*v);
        out
    }

    #[test]
    fn both_signals_tell_the_conventions_apart() {
        let (directx, height) = bumps(64);
        let opengl = flipped(&directx);
        for (normal, want) in [
            (&directx, NormalConvention::DirectX),
            (&opengl, NormalConvention::OpenGl),
        ] {
            let with_height = measure(normal, Some(&height));
            assert_eq!(with_height.convention, want);
            assert!(matches!(with_height.signal, Signal::Height { y, .. } if y.abs() > 0.9));
            let without = measure(normal, None);
            assert_eq!(without.convention, want);
            assert!(!without.weak, "{without:?}");
        }
    }

    #[test]
    fn a_flat_map_is_weak_evidence() {
        let flat = Map::from_fn(32, 32, 3, |c, _, _| [0.0, 0.0, 1.0][c]);
        let measured = measure(&flat, None);
        assert!(measured.weak);
        assert_eq!(measured.convention, NormalConvention::DirectX);
    }
}
