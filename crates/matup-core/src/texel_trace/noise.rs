//! Noise's trace, which has no grid: a scan's sensor noise, or noise added after, shows where a
//! map is flattest, where a texture's own detail does not hide it. Each texel's 16×16 patch
//! is read through a kernel blind to planes and gentle slopes (Immerkær's 3×3 Laplacian
//! difference, whose response to Gaussian noise of σ has a mean magnitude of 6σ·√(2/π)), at
//! the map's scale and at half of it (each 2×2 texels' mean, the kernel's taps 2 texels apart).
//! Noise is white: at half the scale it reads half as much. A texture's own detail is not: it
//! reads about as much at both scales. A map's reading is that of its flattest tenth of
//! patches. A patch at every texel, not on a grid: a tileable map rolled reads the same.
//!
//! One map alone does not tell noise from a fine grain: box-filtered to 128², a fabric's or an
//! asphalt's grain is about as white as noise (docs/experiments/2026-12-02-texel-traces.md).
//! A material does ([`noise_floor`]): noise lies under every map alike, while a clean
//! material's maps are not all grainy; most have a smooth or constant one.

use std::ops::RangeInclusive;

use super::levels::{Levels, Reach};
use crate::map::Map;
use crate::map_kind::MapKind;

/// The side of the patches read.
const PATCH: usize = 16;

/// How far past its patch a patch's reading reaches: the half-scale kernel's taps, 2 texels
/// apart, on 2×2 means.
const REACH_PAST: usize = 6;

/// The least side of a map read.
const MIN_SIDE: usize = 64;

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
    /// The share of their texels at black or white, where noise is clipped and reads about
    /// half as much (a metallic map at 0).
    pub clipped: f64,
    /// What the median patch reads over what the flattest read: about 1 where the whole map
    /// is as flat as its flattest patches (a flat map under noise), more where it has texture.
    pub spread: f64,
}

/// The least σ, in 8-bit levels, that noise under every map must read: σ 3 of noise reads
/// 2.6–2.9, clean maps' flattest patches 0–1.5 but for fine grains.
const FLOOR: f64 = 2.2;

/// The share of clipped texels past which a map need only read half of [`FLOOR`].
const CLIPPED: f64 = 0.1;

/// The half-scale ratios of a map read as white: as white as noise (0.5), and no whiter: a
/// weave at a 2-texel period reads below 0.35.
const WHITE: RangeInclusive<f64> = 0.35..=0.9;

/// A witness to noise, one map flat but for it: all its patches read within 1.5× its
/// flattest, and about as white as noise alone reads (half-scale ratio ≤ 0.7); or a map
/// clipped at black or white (a constant metallic map under noise). Without a witness and the
/// band's lower end, 4 of the 109 clean materials read as noisy at 128² where the metallic
/// map is left out (fine grains in every map), 1 with them.
const WITNESS_SPREAD: f64 = 1.5;
const WITNESS_WHITE: RangeInclusive<f64> = 0.35..=0.7;

/// How many of its maps must read white: three, since one grainy map may be as white as noise.
const WHITE_MAPS: usize = 3;

/// How many maps a material needs: four. With three (no metallic map), the fine grain of all
/// three read as noise on 6 of 109 clean materials at 128², against none with four
/// (docs/experiments/2026-12-02-texel-traces.md).
const MIN_MAPS: usize = 4;

/// Noise found under every map of a material.
#[derive(Clone, Debug, PartialEq)]
pub struct NoiseFloor {
    /// The least its unclipped maps' flattest patches read, in 8-bit levels.
    pub sigma: f64,
    /// The maps read.
    pub maps: usize,
}

impl std::fmt::Display for NoiseFloor {
    /// "noise of σ 2.7 levels under all 4 maps".
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let (sigma, maps) = (self.sigma, self.maps);
        write!(f, "noise of σ {sigma:.1} levels under all {maps} maps")
    }
}

/// Whether `maps` (each of its kind; a material's own maps, not stand-ins) read as lying over
/// one noise: every map's flattest patches read at least [`FLOOR`] (half of it where they are
/// clipped), at least [`WHITE_MAPS`] of them white, and one of them a witness (a map flat but
/// for the noise). `None` for a clean material, or one of fewer than [`MIN_MAPS`] maps large
/// enough to read. `tileable`: patches wrap around.
pub fn noise_floor(maps: &[(MapKind, &Map)], tileable: bool) -> Option<NoiseFloor> {
    let readings: Vec<NoiseReading> = (maps.iter())
        .map(|&(kind, map)| noise_reading(kind, map, tileable))
        .collect::<Option<_>>()?;
    if readings.len() < MIN_MAPS {
        return None;
    }
    let above_floor = |r: &NoiseReading| {
        let floor = if r.clipped >= CLIPPED {
            FLOOR / 2.0
        } else {
            FLOOR
        };
        r.sigma >= floor
    };
    let white = (readings.iter())
        .filter(|r| WHITE.contains(&r.scale_ratio))
        .count();
    let witness = |r: &NoiseReading| {
        r.clipped >= CLIPPED
            || (r.spread <= WITNESS_SPREAD && WITNESS_WHITE.contains(&r.scale_ratio))
    };
    if !readings.iter().all(above_floor) || white < WHITE_MAPS || !readings.iter().any(witness) {
        return None;
    }
    // The least σ of the unclipped maps (of all, where every map is clipped).
    let least = |clipped_too: bool| {
        (readings.iter())
            .filter(|r| clipped_too || r.clipped < CLIPPED)
            .map(|r| r.sigma)
            .fold(f64::INFINITY, f64::min)
    };
    let sigma = Some(least(false)).filter(|s| s.is_finite());
    Some(NoiseFloor {
        sigma: sigma.unwrap_or_else(|| least(true)),
        maps: readings.len(),
    })
}

/// What `map`'s flattest patches read (see the module's text); `None` for a map too small to
/// tell (under 64 texels a side). Colour maps: each channel read apart, the median channel's;
/// normals: x and y; grey maps: their value. `tileable`: patches wrap around the map's edges.
pub fn noise_reading(kind: MapKind, map: &Map, tileable: bool) -> Option<NoiseReading> {
    if map.width() < MIN_SIDE || map.height() < MIN_SIDE {
        return None;
    }
    let channels: &[usize] = match map.channels() {
        _ if kind == MapKind::Normal => &[0, 1],
        n if n >= 3 => &[0, 1, 2],
        _ => &[0],
    };
    let pad = PATCH + REACH_PAST;
    let levels = Levels::of(kind, map, channels, REACH, tileable, pad);
    // A patch at every texel where the map wraps, else at every texel whose reach fits.
    let fit = |n: usize| if levels.wrap { n } else { n + 1 - pad };
    let (pw, ph) = (fit(levels.width), fit(levels.height));
    let mut readings: Vec<NoiseReading> = (0..channels.len())
        .map(|c| channel_reading(&levels, c, [pw, ph]))
        .collect();
    readings.sort_by(|a, b| a.sigma.total_cmp(&b.sigma));
    Some(readings.swap_remove(readings.len() / 2))
}

/// Channel `c`'s reading from the patches whose corners are the first `[pw, ph]` texels.
fn channel_reading(levels: &Levels, c: usize, [pw, ph]: [usize; 2]) -> NoiseReading {
    let rows = levels.planes[c].len() / levels.stride;
    let (w, h) = (levels.stride, rows);
    let at = |x: usize, y: usize| levels.at(c, x, y);
    // Each texel's kernel responses (the kernel's corner there), and whether it is clipped.
    let fine = Sums::of(w - 2, h - 2, |x, y| {
        immerkaer_response(|i, j| at(x + i, y + j)).abs() as f64
    });
    let mean2 =
        |x: usize, y: usize| (at(x, y) + at(x + 1, y) + at(x, y + 1) + at(x + 1, y + 1)) / 4.0;
    let coarse = Sums::of(w - REACH_PAST, h - REACH_PAST, |x, y| {
        immerkaer_response(|i, j| mean2(x + 2 * i, y + 2 * j)).abs() as f64
    });
    let clipped = Sums::of(w, h, |x, y| {
        let v = at(x, y);
        f64::from(u8::from(v <= 0.5 || v >= 254.5))
    });
    let to_sigma = (std::f64::consts::FRAC_PI_2).sqrt() / IMMERKAER_GAIN as f64;
    let area = (PATCH * PATCH) as f64;
    let mut patches: Vec<[f64; 3]> = (0..pw * ph)
        .map(|i| {
            let (x, y) = (i % pw, i / pw);
            [
                fine.patch(x, y, PATCH) / area * to_sigma,
                coarse.patch(x, y, PATCH) / area * to_sigma,
                clipped.patch(x, y, PATCH + 2) / ((PATCH + 2) * (PATCH + 2)) as f64,
            ]
        })
        .collect();
    patches.sort_by(|a, b| a[0].total_cmp(&b[0]));
    let flattest = &patches[..((patches.len() as f64 * FLATTEST) as usize).max(4)];
    let median = |mut v: Vec<f64>| {
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    let sigma = median(flattest.iter().map(|p| p[0]).collect());
    NoiseReading {
        sigma,
        scale_ratio: median(flattest.iter().map(|p| p[1] / p[0].max(1e-6)).collect()),
        clipped: median(flattest.iter().map(|p| p[2]).collect()),
        spread: patches[patches.len() / 2][0] / sigma.max(1e-6),
    }
}

/// A summed-area table of a `w × h` field: any square's sum in four lookups.
struct Sums {
    table: Vec<f64>,
    stride: usize,
}

impl Sums {
    fn of(w: usize, h: usize, value: impl Fn(usize, usize) -> f64) -> Sums {
        let stride = w + 1;
        let mut table = vec![0.0; stride * (h + 1)];
        for y in 0..h {
            let mut row = 0.0;
            for x in 0..w {
                row += value(x, y);
                table[(y + 1) * stride + x + 1] = table[y * stride + x + 1] + row;
            }
        }
        Sums { table, stride }
    }

    /// The sum over the `side`² square whose corner is `(x, y)`.
    fn patch(&self, x: usize, y: usize, side: usize) -> f64 {
        let t = |x: usize, y: usize| self.table[y * self.stride + x];
        t(x + side, y + side) - t(x, y + side) - t(x + side, y) + t(x, y)
    }
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
