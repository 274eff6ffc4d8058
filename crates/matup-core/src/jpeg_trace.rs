//! JPEG's trace in a map's texels: where a map was once a JPEG and was saved again losslessly
//! (a crop of a model's JPEG texture kept as PNG), its file no longer says so, but its texels
//! do. A JPEG stores each 8×8 block's DCT coefficients rounded to multiples of a quantisation
//! step; decoded, re-encoded as 8-bit RGB and transformed again on the same grid, the
//! coefficients still sit near those multiples, and on no other grid offset do they.
//!
//! Written here because no crate does it: image forensics libraries estimate quality from a
//! JPEG file's own tables, which a lossless copy no longer has.

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

/// The side of the window examined (the map's centre): enough blocks (1024) to tell, at a
/// fixed cost on any map.
const WINDOW: usize = 256;

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
/// grid offsets is tested for DCT coefficients clustered at multiples of a step.
pub fn jpeg_trace(kind: MapKind, map: &Map) -> Option<JpegTrace> {
    let ((luma, w, h), [x0, y0]) = (stored_luma(kind, map)?, window_origin(map));
    let evidence: Vec<f64> = (0..64)
        .map(|o| grid_evidence(&luma, w, h, [o % 8, o / 8]))
        .collect();
    let (best, &strongest) = (evidence.iter().enumerate())
        .max_by(|a, b| a.1.total_cmp(b.1))
        .expect("64 offsets");
    let mut sorted = evidence.clone();
    sorted.sort_by(f64::total_cmp);
    let median = sorted[32].max(1.0);
    let blocks = ((w / 8) * (h / 8)).max(1) as f64;
    let trace = JpegTrace {
        offset: [(x0 + best % 8) % 8, (y0 + best / 8) % 8],
        strength: strongest / blocks,
        contrast: strongest / median,
    };
    (trace.strength >= MIN_STRENGTH && trace.contrast >= MIN_CONTRAST).then_some(trace)
}

/// The window's JPEG luma (`Y − 128` of the 8-bit values a file stores), row-major, with its
/// width and height: grey maps as their value. `None` for a map too small for a grid test.
fn stored_luma(kind: MapKind, map: &Map) -> Option<(Vec<f64>, usize, usize)> {
    let (w, h) = (map.width().min(WINDOW), map.height().min(WINDOW));
    if w < 32 || h < 32 {
        return None;
    }
    let [x0, y0] = window_origin(map);
    let stored = |c: usize, i: usize| {
        let v = kind.stored(c, map.plane(c)[i]).clamp(0.0, 1.0);
        (v * 255.0).round() as f64
    };
    let mut luma = Vec::with_capacity(w * h);
    for y in y0..y0 + h {
        for x in x0..x0 + w {
            let i = y * map.width() + x;
            let value = if map.channels() >= 3 {
                0.299 * stored(0, i) + 0.587 * stored(1, i) + 0.114 * stored(2, i)
            } else {
                stored(0, i)
            };
            luma.push(value - 128.0);
        }
    }
    Some((luma, w, h))
}

/// The top-left texel of the window examined: the map's centre [`WINDOW`]².
fn window_origin(map: &Map) -> [usize; 2] {
    let (w, h) = (map.width().min(WINDOW), map.height().min(WINDOW));
    [(map.width() - w) / 2, (map.height() - h) / 2]
}

/// The evidence of a JPEG grid at `offset`: for each tested frequency, the strongest step's
/// Rayleigh statistic `|Σ e^(2πi c/q)|² / n` over the coefficients `c` a step `q` would not
/// round to zero (about 1 where they are spread evenly, about `n` where they sit on the
/// step's multiples), summed over the frequencies.
fn grid_evidence(luma: &[f64], w: usize, h: usize, [ox, oy]: [usize; 2]) -> f64 {
    let basis = dct_basis();
    let (bw, bh) = ((w - ox) / 8, (h - oy) / 8);
    let mut coefficients = vec![Vec::with_capacity(bw * bh); FREQUENCIES.len()];
    let mut block = [[0.0; 8]; 8];
    for by in 0..bh {
        for bx in 0..bw {
            for (r, row) in block.iter_mut().enumerate() {
                let start = (oy + by * 8 + r) * w + ox + bx * 8;
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::degrade::{Degradation, Subsampling};
    use crate::io::{load_material, LoadOptions};
    use crate::material::Material;
    use rand::SeedableRng;

    /// Real 256² crops the repository ships.
    fn material(name: &str) -> Material {
        let folder = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../../tests/data/materials")
            .join(name);
        load_material(Some(&folder), &LoadOptions::default()).unwrap()
    }

    fn as_jpeg(kind: MapKind, map: &Map, quality: u8) -> Map {
        let jpeg = Degradation::Jpeg {
            quality,
            subsampling: Subsampling::Half,
        };
        jpeg.apply(kind, map, &mut rand::rngs::StdRng::seed_from_u64(0))
            .unwrap()
    }

    #[test]
    fn a_jpeg_saved_again_losslessly_shows_its_grid_and_clean_maps_show_none() {
        for name in [
            "ambientcg_Bricks059",
            "ambientcg_Rock035",
            "ambientcg_Leather025",
        ] {
            let m = material(name);
            for kind in [MapKind::BaseColor, MapKind::Roughness, MapKind::Normal] {
                let map = m.map(kind).unwrap();
                assert_eq!(jpeg_trace(kind, map), None, "{name} {kind}: clean");
            }
            // A model's JPEG texture, cropped off its grid and kept as a lossless file.
            let colour = as_jpeg(MapKind::BaseColor, &m.base_color, 85).crop(3, 5, 200, 180);
            let trace = jpeg_trace(MapKind::BaseColor, &colour);
            let trace = trace.unwrap_or_else(|| panic!("{name}: JPEG 85 not found"));
            println!("{name}: {trace:?}");
            // The grid of the JPEG, 8 − 3 and 8 − 5 texels into the crop.
            assert_eq!(trace.offset, [5, 3], "{name}");
            // On a map wider than the window examined, the offset is still the map's own: the
            // JPEG placed 20 texels in, its grid at 20 % 8 = 4.
            let jpeg = as_jpeg(MapKind::BaseColor, &m.base_color, 85);
            let at = |v: usize| v.saturating_sub(20).min(255);
            let wide = Map::from_fn(300, 300, 3, |c, y, x| jpeg.plane(c)[at(y) * 256 + at(x)]);
            let trace = jpeg_trace(MapKind::BaseColor, &wide).expect("found past the window");
            assert_eq!(trace.offset, [4, 4], "{name}");
            assert!(trace.strength > 2.0 * MIN_STRENGTH, "{name}: {trace:?}");
        }
    }
}
