//! Each detector on real maps the repository ships: clean, and through this repository's own
//! encoders and decoders, at offsets and sizes.

use super::*;
use crate::degrade::{BlockFormat, Degradation, Subsampling};
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

const MATERIALS: [&str; 3] = [
    "ambientcg_Bricks059",
    "ambientcg_Rock035",
    "ambientcg_Leather025",
];

const KINDS: [MapKind; 3] = [MapKind::BaseColor, MapKind::Roughness, MapKind::Normal];

fn through(degradation: Degradation, kind: MapKind, map: &Map) -> Map {
    let mut rng = rand::rngs::StdRng::seed_from_u64(0);
    degradation.apply(kind, map, &mut rng).unwrap()
}

fn as_jpeg(kind: MapKind, map: &Map, quality: u8) -> Map {
    let jpeg = Degradation::Jpeg {
        quality,
        subsampling: Subsampling::Half,
    };
    through(jpeg, kind, map)
}

/// `map` rolled by `[dx, dy]` texels, wrapping around.
fn rolled(map: &Map, [dx, dy]: [usize; 2]) -> Map {
    let (w, h) = (map.width(), map.height());
    Map::from_fn(w, h, map.channels(), |c, y, x| {
        map.plane(c)[((y + h - dy % h) % h) * w + (x + w - dx % w) % w]
    })
}

#[test]
fn clean_maps_show_no_trace() {
    for name in MATERIALS {
        let m = material(name);
        for kind in KINDS {
            let map = m.map(kind).unwrap();
            for tileable in [false, true] {
                assert_eq!(texel_trace(kind, map, tileable), None, "{name} {kind}");
            }
            // And box-filtered down, as measurements make their inputs.
            let small = crate::resample::box_downsample(map, 2);
            assert_eq!(texel_trace(kind, &small, false), None, "{name} {kind} ÷2");
        }
    }
}

#[test]
fn a_jpeg_saved_again_losslessly_shows_its_grid() {
    for name in MATERIALS {
        let m = material(name);
        // A model's JPEG texture, cropped off its grid and kept as a lossless file.
        let colour = as_jpeg(MapKind::BaseColor, &m.base_color, 85).crop(3, 5, 200, 180);
        let trace = jpeg_trace(MapKind::BaseColor, &colour, false);
        let trace = trace.unwrap_or_else(|| panic!("{name}: JPEG 85 not found"));
        // The grid of the JPEG, 8 − 3 and 8 − 5 texels into the crop.
        assert_eq!(trace.offset, [5, 3], "{name}");
        assert!(
            trace.strength > 3.0 && trace.contrast > 8.0,
            "{name}: {trace:?}"
        );
        // On a map wider than the window read, the offset is still the map's own: the JPEG
        // placed 20 texels in, its grid at 20 % 8 = 4.
        let jpeg = as_jpeg(MapKind::BaseColor, &m.base_color, 85);
        let at = |v: usize| (v + 256 - 20) % 256;
        let wide = Map::from_fn(600, 600, 3, |c, y, x| jpeg.plane(c)[at(y) * 256 + at(x)]);
        let trace = jpeg_trace(MapKind::BaseColor, &wide, false).expect("found past the window");
        assert_eq!(trace.offset, [4, 4], "{name}");
    }
}

#[test]
fn bc_blocks_decoded_and_saved_losslessly_show_their_palette_at_their_offset() {
    let cases = [
        (MapKind::BaseColor, BlockFormat::Bc1, "BC1/BC3"),
        (MapKind::BaseColor, BlockFormat::Bc3, "BC1/BC3"),
        (MapKind::Normal, BlockFormat::Bc1, "BC1/BC3"),
        (MapKind::Normal, BlockFormat::Bc5, "BC5"),
        (MapKind::Roughness, BlockFormat::Bc4, "BC4"),
    ];
    for name in MATERIALS {
        let m = material(name);
        for (kind, format, formats) in cases {
            let decoded = through(Degradation::Block(format), kind, m.map(kind).unwrap());
            // Crops off the grid (an atlas's tile, a cropped texture), at several sizes.
            for (x0, y0, w, h) in [
                (0, 0, 256, 256),
                (1, 3, 128, 128),
                (2, 1, 64, 64),
                (3, 2, 201, 95),
            ] {
                let crop = decoded.crop(x0, y0, w, h);
                let trace = block_trace(kind, &crop, false);
                let Some(trace) = trace else {
                    panic!("{name} {kind} {format:?} at ({x0}, {y0}) {w}×{h}: not found");
                };
                assert_eq!(trace.palette.formats(), formats, "{name} {kind} {format:?}");
                let offset = [(4 - x0) % 4, (4 - y0) % 4];
                assert_eq!(
                    trace.offset, offset,
                    "{name} {kind} {format:?} at ({x0}, {y0})"
                );
                assert!(
                    trace.fit > 0.9 && trace.fit - trace.median_fit > 0.5,
                    "{name} {kind}: {trace:?}"
                );
                // The combined reading says blocks, not a JPEG.
                let found = texel_trace(kind, &crop, false).expect("found");
                assert!(!found.is_jpeg(), "{name} {kind}: {found}");
            }
        }
    }
}

#[test]
fn a_tileable_map_reads_the_same_at_every_roll() {
    let m = material("ambientcg_Tiles012");
    for kind in KINDS {
        let map = m.map(kind).unwrap();
        // The tile material box-filtered ÷8 from its 1K² (÷4 in the test data): read across
        // its edges, clean at every roll. Read as a crop, its normal map shows an 8-texel
        // pattern at offset (0, 0) that a roll takes away.
        let small = crate::resample::box_downsample(map, 2);
        for shift in [[0, 0], [37, 53], [5, 0]] {
            let rolled_small = rolled(&small, shift);
            assert_eq!(
                texel_trace(kind, &rolled_small, true),
                None,
                "{kind} ÷8 {shift:?}"
            );
        }
        let bc = through(Degradation::Block(BlockFormat::Bc1), kind, map);
        let jpeg = as_jpeg(kind, map, 75);
        let is_colour = kind == MapKind::BaseColor;
        for shift in [[0, 0], [37, 53], [1, 2], [255, 7]] {
            assert_eq!(
                texel_trace(kind, &rolled(map, shift), true),
                None,
                "{kind} {shift:?}"
            );
            let blocks = block_trace(kind, &rolled(&bc, shift), true).expect("BC1 found");
            let expected = [shift[0] % 4, shift[1] % 4];
            assert_eq!(blocks.offset, expected, "{kind} {shift:?}");
            // A JPEG's grid shows in the colour map (its smooth maps hide it).
            let grid = jpeg_trace(kind, &rolled(&jpeg, shift), true);
            if is_colour {
                let grid = grid.unwrap_or_else(|| panic!("{kind} JPEG 75 rolled {shift:?}"));
                assert_eq!(
                    grid.offset,
                    [shift[0] % 8, shift[1] % 8],
                    "{kind} {shift:?}"
                );
            }
        }
    }
}

#[test]
fn dithered_and_posterised_maps_show_their_levels_at_any_crop_and_roll() {
    use crate::degrade::DitherMethod;
    let fs32 = Degradation::Dither {
        levels: 32,
        method: DitherMethod::ErrorDiffusion,
    };
    // Leather025's light, flat base colour (10 levels wide) keeps 2 or 3 levels of 32 a
    // channel: as few as a mask's, too few to tell.
    let leather = material("ambientcg_Leather025");
    let flat = through(fs32, MapKind::BaseColor, &leather.base_color);
    assert_eq!(quantised_trace(MapKind::BaseColor, &flat, false), None);
    for name in ["ambientcg_Bricks059", "ambientcg_Rock035"] {
        let m = material(name);
        for kind in [MapKind::BaseColor, MapKind::Roughness] {
            let map = m.map(kind).unwrap();
            for (levels, method) in [
                (32, DitherMethod::ErrorDiffusion),
                (32, DitherMethod::Ordered),
                (16, DitherMethod::ErrorDiffusion),
                (64, DitherMethod::Ordered),
            ] {
                let dithered = through(Degradation::Dither { levels, method }, kind, map);
                for (x0, y0, w, h) in [(0, 0, 256, 256), (3, 5, 120, 97)] {
                    let crop = dithered.crop(x0, y0, w, h);
                    let Some(TexelTrace::Quantised(trace)) = texel_trace(kind, &crop, false) else {
                        panic!("{name} {kind} {levels} levels {method:?} at ({x0}, {y0})");
                    };
                    // A channel too flat to tell is the only one not read.
                    assert!(
                        (trace.levels.iter()).all(|&l| l == Some(levels as usize) || l.is_none()),
                        "{name} {kind} {levels} {method:?}: {trace:?}"
                    );
                }
                let read = |map: &Map| quantised_trace(kind, map, true);
                assert_eq!(
                    read(&rolled(&dithered, [37, 53])),
                    read(&dithered),
                    "{name}"
                );
            }
        }
        // A 16-bit texture widened to 8 bits as GPUs do (RGB565: 5, 6, 5 bits, the top bits
        // repeated below), read as 32/64/32 levels.
        let widen = |v: f32, bits: u32| {
            let q = (v * ((1 << bits) - 1) as f32).round() as u32;
            ((q << (8 - bits)) | (q >> (2 * bits - 8))) as f32 / 255.0
        };
        let stored = &m.base_color;
        let rgb565 = Map::from_fn(256, 256, 3, |c, y, x| {
            let srgb = MapKind::BaseColor.stored(c, stored.plane(c)[y * 256 + x]);
            let widened = widen(srgb, if c == 1 { 6 } else { 5 });
            MapKind::BaseColor.from_stored(c, widened)
        });
        let found = quantised_trace(MapKind::BaseColor, &rgb565, false).expect("RGB565 read");
        assert_eq!(found.levels, vec![Some(32), Some(64), Some(32)], "{name}");
        assert_eq!(
            TexelTrace::Quantised(found).to_string(),
            "32/64/32 levels a channel (dithered or posterised)"
        );
        // Normals are renormalised when read, off any ladder: not read.
        let normal = through(fs32, MapKind::Normal, &m.normal);
        assert_eq!(quantised_trace(MapKind::Normal, &normal, false), None);
    }
}

#[test]
fn noise_reads_at_its_strength_and_halves_at_half_the_scale() {
    let noisy = |map: &Map, kind: MapKind, sigma: f32| {
        through(Degradation::GaussianNoise { sigma }, kind, map)
    };
    // On a flat map, the noise itself (a little low: the flattest patches), and half of it at
    // half the scale.
    let flat = Map::from_fn(128, 128, 1, |_, _, _| 0.5);
    let read = noise_reading(
        MapKind::Roughness,
        &noisy(&flat, MapKind::Roughness, 3.0),
        true,
    );
    let read = read.expect("128² is enough");
    assert!((2.5..3.1).contains(&read.sigma), "{read:?}");
    assert!((0.4..0.6).contains(&read.scale_ratio), "{read:?}");
    // On real maps: more with more noise, and whiter.
    for name in MATERIALS {
        let m = material(name);
        for kind in KINDS {
            let map = m.map(kind).unwrap();
            let [clean, two, four] = [0.0, 2.0, 4.0].map(|s| {
                let map = if s > 0.0 {
                    noisy(map, kind, s)
                } else {
                    map.clone()
                };
                noise_reading(kind, &map, false).unwrap()
            });
            assert!(
                clean.sigma < two.sigma && two.sigma < four.sigma,
                "{name} {kind}: {clean:?} {four:?}"
            );
            assert!(
                four.scale_ratio < clean.scale_ratio,
                "{name} {kind}: {clean:?} {four:?}"
            );
        }
    }
    assert_eq!(
        noise_reading(MapKind::Roughness, &flat.crop(0, 0, 40, 40), false),
        None
    );
}

/// Every material the repository ships, box-filtered to 128² as measurements make inputs.
fn shipped_at_128() -> Vec<(String, Material)> {
    let folder =
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/data/materials");
    let mut names: Vec<String> = std::fs::read_dir(folder)
        .unwrap()
        .filter_map(|e| Some(e.ok()?.file_name().to_str()?.to_string()))
        .filter(|n| !n.ends_with(".md"))
        .collect();
    names.sort();
    (names.into_iter())
        .map(|n| {
            let m = material(&n).box_downsample(2);
            (n, m)
        })
        .collect()
}

/// The maps the route reads for noise: base colour, normal, roughness, metallic, height.
const ALL_FIVE: [MapKind; 5] = [
    MapKind::BaseColor,
    MapKind::Normal,
    MapKind::Roughness,
    MapKind::Metallic,
    MapKind::Height,
];

/// What `noise_floor` reads under `kinds` of `m`.
fn floor_of(m: &Material, kinds: &[MapKind], tileable: bool) -> Option<NoiseFloor> {
    let maps: Vec<(MapKind, &Map)> = kinds.iter().map(|&k| (k, m.map(k).unwrap())).collect();
    noise_floor(&maps, tileable)
}

#[test]
fn noise_under_every_map_is_read_and_clean_materials_are_not() {
    let materials = shipped_at_128();
    assert_eq!(materials.len(), 14);
    // All five maps, the four of the filter, and four without the metallic map.
    let no_metallic = [ALL_FIVE[0], ALL_FIVE[1], ALL_FIVE[2], ALL_FIVE[4]];
    let sets: [&[MapKind]; 3] = [&ALL_FIVE, &ALL_FIVE[..4], &no_metallic];
    let mut found = [0; 3];
    for (n, (name, clean)) in materials.iter().enumerate() {
        let mut rng = rand::rngs::StdRng::seed_from_u64(n as u64);
        let noisy = |d: &str, rng: &mut rand::rngs::StdRng| {
            crate::degrade::degrade_material(clean, &d.parse().unwrap(), rng).unwrap()
        };
        let inputs = [
            noisy("noise1", &mut rng),
            noisy("jpeg75", &mut rng),
            noisy("blur0.7", &mut rng),
        ];
        let three = noisy("noise3", &mut rng);
        for (i, kinds) in sets.iter().enumerate() {
            assert_eq!(floor_of(clean, kinds, false), None, "{name} {kinds:?}");
            // σ 1 hides under the maps' own texture; JPEG and blur are no noise.
            for input in &inputs {
                assert_eq!(floor_of(input, kinds, false), None, "{name} {kinds:?}");
            }
            if let Some(floor) = floor_of(&three, kinds, false) {
                assert!((2.2..5.0).contains(&floor.sigma), "{name}: {floor}");
                let maps = format!("all {} maps", kinds.len());
                assert_eq!(
                    floor.to_string().split(" under ").nth(1),
                    Some(maps.as_str())
                );
                found[i] += 1;
            }
        }
    }
    // Fewer without the metallic map: a flat map must witness the noise, and fewer have one.
    assert!(
        found[0] >= 12 && found[1] >= 12 && found[2] >= 9,
        "σ 3 of noise read under {found:?} of 14"
    );
    // Three maps are not enough to tell noise from a grain in all three, nor are two
    // (Leather025, read with four).
    let (_, m) = &materials[1];
    let mut rng = rand::rngs::StdRng::seed_from_u64(0);
    let noisy = crate::degrade::degrade_material(m, &"noise4".parse().unwrap(), &mut rng);
    let noisy = noisy.unwrap();
    assert!(floor_of(&noisy, &ALL_FIVE[..4], false).is_some());
    assert_eq!(floor_of(&noisy, &ALL_FIVE[..3], false), None);
    assert_eq!(floor_of(&noisy, &ALL_FIVE[..2], false), None);
}

#[test]
fn a_noise_floor_reads_alike_at_any_roll_of_a_tileable_material() {
    // A patch at every texel: rolled, the material reads the same, but for the order of sums.
    let roll_all = |m: &Material, by: [usize; 2]| {
        let mut out = m.clone();
        for kind in ALL_FIVE {
            *out.map_mut(kind).unwrap() = rolled(m.map(kind).unwrap(), by);
        }
        out
    };
    for (n, (name, clean)) in shipped_at_128().iter().enumerate() {
        let mut rng = rand::rngs::StdRng::seed_from_u64(n as u64);
        let noisy = crate::degrade::degrade_material(clean, &"noise3".parse().unwrap(), &mut rng);
        for m in [clean.clone(), noisy.unwrap()] {
            let read = floor_of(&m, &ALL_FIVE, true);
            for by in [[37, 53], [8, 120]] {
                let again = floor_of(&roll_all(&m, by), &ALL_FIVE, true);
                assert_eq!(
                    read.is_some(),
                    again.is_some(),
                    "{name} {by:?}: {read:?} {again:?}"
                );
                if let (Some(a), Some(b)) = (&read, &again) {
                    assert!((a.sigma - b.sigma).abs() < 1e-6, "{name} {by:?}: {a} {b}");
                }
            }
        }
    }
}
