//! Noise's trace, which has no grid: a scan's sensor noise, or noise added after, shows where a
//! map is flattest, where a texture's own detail does not hide it. Each 8×8 patch's noise is
//! read through a kernel blind to planes and gentle slopes (Immerkær's 3×3 Laplacian
//! difference, whose response to Gaussian noise of σ has a mean magnitude of 6σ·√(2/π)); the
//! map's is a low quantile of its patches', the flattest ones.

use super::Levels;
use crate::map::Map;
use crate::map_kind::MapKind;

/// The side of the patches read.
const PATCH: usize = 8;

/// The largest side read (a larger map's centre).
const WINDOW: usize = 512;

/// The quantile of the patches' noise taken as the map's: the flattest tenth.
const QUANTILE: f64 = 0.1;

/// A map's noise, in 8-bit levels (σ), read from its flattest patches (see the module's
/// text); `None` for a map too small to tell (fewer than 16 patches). Colour maps: the median
/// of their channels'; normals: of x and y; grey maps: their value's. `tileable`: patches wrap
/// around the map's edges.
pub fn noise_level(kind: MapKind, map: &Map, tileable: bool) -> Option<f64> {
    let channels: &[usize] = match map.channels() {
        _ if kind == MapKind::Normal => &[0, 1],
        n if n >= 3 => &[0, 1, 2],
        _ => &[0],
    };
    let levels = Levels::of(kind, map, channels, WINDOW, tileable, 2);
    // Patches of PATCH² kernel outputs, each reading one texel around it.
    let reach = |n: usize| {
        if levels.wrap {
            n / PATCH
        } else {
            n.saturating_sub(2) / PATCH
        }
    };
    let (pw, ph) = (reach(levels.width), reach(levels.height));
    if pw * ph < 16 {
        return None;
    }
    let mut per_channel: Vec<f64> = (0..channels.len())
        .map(|c| {
            let mut patches: Vec<f64> = (0..pw * ph)
                .map(|p| patch_noise(&levels, c, [p % pw * PATCH, p / pw * PATCH]))
                .collect();
            patches.sort_by(f64::total_cmp);
            patches[((patches.len() as f64 * QUANTILE) as usize).min(patches.len() - 1)]
        })
        .collect();
    per_channel.sort_by(f64::total_cmp);
    Some(per_channel[per_channel.len() / 2])
}

/// The noise σ of channel `c`'s patch whose kernel outputs start at `[x, y]`: each output
/// centred one texel further in.
fn patch_noise(levels: &Levels, c: usize, [x, y]: [usize; 2]) -> f64 {
    const KERNEL: [[f32; 3]; 3] = [[1.0, -2.0, 1.0], [-2.0, 4.0, -2.0], [1.0, -2.0, 1.0]];
    let mut sum = 0.0f64;
    for py in 0..PATCH {
        for px in 0..PATCH {
            let mut response = 0.0f32;
            for (ky, row) in KERNEL.iter().enumerate() {
                for (kx, k) in row.iter().enumerate() {
                    response += k * levels.at(c, x + px + kx, y + py + ky);
                }
            }
            sum += response.abs() as f64;
        }
    }
    let mean = sum / (PATCH * PATCH) as f64;
    mean * (std::f64::consts::FRAC_PI_2).sqrt() / 6.0
}
