//! JPEG's trace: a JPEG stores each 8×8 block's DCT coefficients rounded to multiples of a
//! quantisation step; decoded, re-encoded as 8-bit RGB and transformed again on the same grid,
//! the coefficients still sit near those multiples, and on no other grid offset do they.

use super::levels::{Levels, Reach};
use crate::map::Map;
use crate::map_kind::MapKind;

/// The coefficients tested (row, column frequency): low and middle ones, which JPEG quantises
/// by steps of 2–24 at the qualities maps are shipped in and which textures fill.
const FREQUENCIES: [(usize, usize); 11] = [
    (0, 1),
    (1, 0),
    (1, 1),
    (0, 2),
    (2, 0),
    (1, 2),
    (2, 1),
    (2, 2),
    (0, 3),
    (3, 0),
    (3, 3),
];

/// The quantisation steps tried, in levels of the DCT of 8-bit values.
const STEPS: std::ops::RangeInclusive<usize> = 2..=24;

/// Coefficients a step needs before its evidence counts: fewer say nothing either way.
const MIN_SAMPLES: usize = 32;

/// What is read: a tileable map whole up to 512² (4096 blocks at each offset), else its centre
/// 256²: enough blocks (1024) to tell, at a bounded cost on any map.
const REACH: Reach = Reach {
    whole: 512,
    window: 256,
};

/// The evidence a JPEG grid needs, per 8×8 block of the window, at its best offset.
/// Measured (docs/experiments/2026-11-29-degraded-inputs.md): DamagedHelmet's base colour
/// crops (quality 85) read 3.7–5.6; clean maps at most 4.4, but then on every offset alike.
const MIN_STRENGTH: f64 = 1.5;

/// How many times the best offset's evidence must exceed the median offset's: a JPEG grid is
/// at one offset, a texture's own regularity at all of them.
const MIN_CONTRAST: f64 = 4.0;

/// A JPEG grid found in a map's texels.
#[derive(Clone, Debug, PartialEq)]
pub struct JpegTrace {
    /// The grid's offset from the map's top-left texel: [x, y], each 0–7.
    pub offset: [usize; 2],
    /// The evidence at that offset, per block (see [`MIN_STRENGTH`]).
    pub strength: f64,
    /// That evidence over the median offset's (see [`MIN_CONTRAST`]).
    pub contrast: f64,
}

/// JPEG's 8×8 grid in `map` (a map of `kind`), if its texels show one: the values a file
/// would store (sRGB colour, normals as colours) are taken as JPEG's luma, and each of the 64
/// grid offsets is tested for DCT coefficients clustered at multiples of a step. `tileable`:
/// blocks wrap around the map's edges.
pub fn jpeg_trace(kind: MapKind, map: &Map, tileable: bool) -> Option<JpegTrace> {
    let channels: &[usize] = if map.channels() >= 3 {
        &[0, 1, 2]
    } else {
        &[0]
    };
    let levels = Levels::of(kind, map, channels, REACH, tileable, 7);
    let [bw, bh] = levels.blocks(8);
    if bw * bh < 16 {
        return None;
    }
    let luma = stored_luma(&levels);
    let evidence: Vec<f64> = (0..64)
        .map(|o| grid_evidence(&luma, levels.stride, [bw, bh], [o % 8, o / 8]))
        .collect();
    let (best, &strongest) = (evidence.iter().enumerate())
        .max_by(|a, b| a.1.total_cmp(b.1))
        .expect("64 offsets");
    let mut sorted = evidence.clone();
    sorted.sort_by(f64::total_cmp);
    let median = sorted[32].max(1.0);
    let trace = JpegTrace {
        offset: levels.map_offset([best % 8, best / 8], 8),
        strength: strongest / (bw * bh) as f64,
        contrast: strongest / median,
    };
    (trace.strength >= MIN_STRENGTH && trace.contrast >= MIN_CONTRAST).then_some(trace)
}

/// JPEG's luma of the levels read (`Y − 128` of the 8-bit values a file stores), row-major
/// as they are: grey maps as their value.
fn stored_luma(levels: &Levels) -> Vec<f64> {
    let level = |c: usize, i: usize| levels.planes[c][i].round() as f64;
    (0..levels.planes[0].len())
        .map(|i| match levels.planes.len() {
            1 => level(0, i),
            _ => 0.299 * level(0, i) + 0.587 * level(1, i) + 0.114 * level(2, i),
        })
        .map(|y| y - 128.0)
        .collect()
}

/// The evidence of a JPEG grid at `offset`: for each tested frequency, the strongest step's
/// Rayleigh statistic `|Σ e^(2πi c/q)|² / n` over the coefficients `c` a step `q` would not
/// round to zero (about 1 where they are spread evenly, about `n` where they sit on the
/// step's multiples), summed over the frequencies.
fn grid_evidence(luma: &[f64], stride: usize, [bw, bh]: [usize; 2], [ox, oy]: [usize; 2]) -> f64 {
    let basis = dct_basis();
    let mut coefficients = vec![Vec::with_capacity(bw * bh); FREQUENCIES.len()];
    let mut block = [[0.0; 8]; 8];
    for by in 0..bh {
        for bx in 0..bw {
            for (r, row) in block.iter_mut().enumerate() {
                let start = (oy + by * 8 + r) * stride + ox + bx * 8;
                row.copy_from_slice(&luma[start..start + 8]);
            }
            for (f, &(u, v)) in FREQUENCIES.iter().enumerate() {
                let mut c = 0.0;
                for (r, row) in block.iter().enumerate() {
                    let along: f64 = (row.iter().zip(&basis[v])).map(|(a, b)| a * b).sum();
                    c += basis[u][r] * along;
                }
                coefficients[f].push(c);
            }
        }
    }
    (coefficients.iter())
        .map(|cs| STEPS.map(|q| rayleigh(cs, q as f64)).fold(0.0, f64::max))
        .sum()
}

/// `|Σ e^(2πi c/q)|² / n` over the coefficients `c` of `cs` past `q / 2`; 0 with fewer than
/// [`MIN_SAMPLES`].
fn rayleigh(cs: &[f64], q: f64) -> f64 {
    let (mut re, mut im, mut n) = (0.0, 0.0, 0usize);
    for &c in cs.iter().filter(|c| c.abs() > q / 2.0) {
        let angle = std::f64::consts::TAU * c / q;
        re += angle.cos();
        im += angle.sin();
        n += 1;
    }
    if n < MIN_SAMPLES {
        return 0.0;
    }
    (re * re + im * im) / n as f64
}

/// JPEG's orthonormal 8-point DCT-II basis: `basis[u][x]`.
fn dct_basis() -> [[f64; 8]; 8] {
    let mut basis = [[0.0; 8]; 8];
    for (u, row) in basis.iter_mut().enumerate() {
        let scale = if u == 0 { (1.0f64 / 8.0).sqrt() } else { 0.5 };
        for (x, b) in row.iter_mut().enumerate() {
            *b = scale * ((2 * x + 1) as f64 * u as f64 * std::f64::consts::PI / 16.0).cos();
        }
    }
    basis
}
