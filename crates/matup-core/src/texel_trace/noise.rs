//! Noise's trace, which has no grid: a scan's sensor noise, or noise added after, shows where a
//! map is flattest, where a texture's own detail does not hide it. Each 16×16 patch is read
//! through a kernel blind to planes and gentle slopes (Immerkær's 3×3 Laplacian difference,
//! whose response to Gaussian noise of σ has a mean magnitude of 6σ·√(2/π)), at the map's
//! scale and at half of it. Noise is white: at half the scale it reads half as much. A
//! texture's own detail is not: it reads about as much at both scales. The map's reading is
//! that of its flattest tenth of patches.

use super::levels::{Levels, Reach};
use crate::map::Map;
use crate::map_kind::MapKind;

/// The side of the patches read.
const PATCH: usize = 16;

/// What is read: a tileable map whole up to 512², else its centre 512².
const REACH: Reach = Reach {
    whole: 512,
    window: 512,
};

/// The share of patches read as the map's: the flattest tenth.
const FLATTEST: f64 = 0.1;

/// A map's noise as its flattest patches read it.
#[derive(Clone, Debug, PartialEq)]
pub struct NoiseReading {
    /// Their noise at the map's scale, in 8-bit levels (σ; pure noise reads about a tenth
    /// low, its flattest patches drawn below σ).
    pub sigma: f64,
    /// What they read at half the scale over what they read at the map's: 0.5 for white
    /// noise, about 1 for a texture's own detail.
    pub scale_ratio: f64,
}

/// What `map`'s flattest patches read (see the module's text); `None` for a map too small to
/// tell (fewer than 16 patches). Colour maps: each channel read apart, the median channel's;
/// normals: x and y; grey maps: their value. `tileable`: patches wrap around the map's edges.
pub fn noise_reading(kind: MapKind, map: &Map, tileable: bool) -> Option<NoiseReading> {
    let channels: &[usize] = match map.channels() {
        _ if kind == MapKind::Normal => &[0, 1],
        n if n >= 3 => &[0, 1, 2],
        _ => &[0],
    };
    // Half-scale patches read 2 texels past their 16 (the kernel's reach at half scale).
    let levels = Levels::of(kind, map, channels, REACH, tileable, 4);
    let fit = |n: usize| {
        if levels.wrap {
            n / PATCH
        } else {
            n.saturating_sub(4) / PATCH
        }
    };
    let (pw, ph) = (fit(levels.width), fit(levels.height));
    if pw * ph < 16 {
        return None;
    }
    let mut readings: Vec<NoiseReading> = (0..channels.len())
        .map(|c| {
            let half = half_scale(&levels, c);
            let mut patches: Vec<(f64, f64)> = (0..pw * ph)
                .map(|p| {
                    let [x, y] = [p % pw * PATCH, p / pw * PATCH];
                    let fine = kernel_sigma(PATCH, |i, j| levels.at(c, x + i, y + j));
                    let coarse = kernel_sigma(PATCH / 2, |i, j| half.at(x / 2 + i, y / 2 + j));
                    (fine, coarse)
                })
                .collect();
            patches.sort_by(|a, b| a.0.total_cmp(&b.0));
            let flattest = &patches[..((patches.len() as f64 * FLATTEST) as usize).max(4)];
            let median = |mut v: Vec<f64>| {
                v.sort_by(f64::total_cmp);
                v[v.len() / 2]
            };
            let sigma = median(flattest.iter().map(|p| p.0).collect());
            let scale_ratio = median(flattest.iter().map(|p| p.1 / p.0.max(1e-6)).collect());
            NoiseReading { sigma, scale_ratio }
        })
        .collect();
    readings.sort_by(|a, b| a.sigma.total_cmp(&b.sigma));
    Some(readings.swap_remove(readings.len() / 2))
}

/// Channel `c` of `levels` at half its scale (each 2×2 texels' mean), as far as it is read.
struct HalfScale {
    values: Vec<f32>,
    stride: usize,
}

impl HalfScale {
    fn at(&self, x: usize, y: usize) -> f32 {
        self.values[y * self.stride + x]
    }
}

fn half_scale(levels: &Levels, c: usize) -> HalfScale {
    let rows = levels.planes[c].len() / levels.stride;
    let (w, h) = (levels.stride / 2, rows / 2);
    let values = (0..w * h)
        .map(|i| {
            let (x, y) = (2 * (i % w), 2 * (i / w));
            let sum = levels.at(c, x, y)
                + levels.at(c, x + 1, y)
                + levels.at(c, x, y + 1)
                + levels.at(c, x + 1, y + 1);
            sum / 4.0
        })
        .collect();
    HalfScale { values, stride: w }
}

/// The noise σ a `side`² patch of kernel outputs reads, `value(i, j)` its texels from its
/// corner (each output centred one texel further in).
fn kernel_sigma(side: usize, value: impl Fn(usize, usize) -> f32) -> f64 {
    let mut sum = 0.0f64;
    for py in 0..side {
        for px in 0..side {
            sum += immerkaer_response(|kx, ky| value(px + kx, py + ky)).abs() as f64;
        }
    }
    let mean = sum / (side * side) as f64;
    mean * (std::f64::consts::FRAC_PI_2).sqrt() / IMMERKAER_GAIN as f64
}

/// Immerkær's Laplacian difference (1995) on the 3×3 texels `value(x, y)` (x, y in 0..3):
/// nothing on planes and gentle slopes; on Gaussian noise of σ, a response of deviation
/// [`IMMERKAER_GAIN`]`· σ`.
pub fn immerkaer_response(value: impl Fn(usize, usize) -> f32) -> f32 {
    const KERNEL: [[f32; 3]; 3] = [[1.0, -2.0, 1.0], [-2.0, 4.0, -2.0], [1.0, -2.0, 1.0]];
    let mut response = 0.0;
    for (y, row) in KERNEL.iter().enumerate() {
        for (x, k) in row.iter().enumerate() {
            response += k * value(x, y);
        }
    }
    response
}

/// The deviation of [`immerkaer_response`] on noise of deviation 1: √(Σ k²) = 6.
pub const IMMERKAER_GAIN: f32 = 6.0;
