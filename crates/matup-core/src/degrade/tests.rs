//! What each degradation does, measured in the file's 8-bit levels.

use super::*;
use crate::color::srgb_to_linear;
use rand::rngs::StdRng;
use rand::SeedableRng;

fn rng() -> StdRng {
    StdRng::seed_from_u64(7)
}

/// A grey map of smooth, varied values (two crossing ramps and a slow wave), [0.1, 0.9].
fn smooth_grey(size: usize) -> Map {
    Map::from_fn(size, size, 1, |_, y, x| {
        let (u, v) = (x as f32 / size as f32, y as f32 / size as f32);
        0.5 + 0.25 * (u - v) + 0.15 * (6.0 * u).sin() * (5.0 * v).cos()
    })
}

/// A linear colour map with texel-scale detail (what JPEG and BC1 lose).
fn detailed_colour(size: usize) -> Map {
    Map::from_fn(size, size, 3, |c, y, x| {
        let hash = ((x * 7919 + y * 104_729 + c * 31) % 251) as f32 / 251.0;
        srgb_to_linear(0.3 + 0.4 * hash)
    })
}

fn stored_error(kind: MapKind, a: &Map, b: &Map) -> f64 {
    let (sa, sb) = (to_stored(kind, a), to_stored(kind, b));
    let sum: f64 = (sa.data().iter().zip(sb.data()))
        .map(|(x, y)| ((x - y) * 255.0).abs() as f64)
        .sum();
    sum / sa.data().len() as f64
}

fn mean_and_sd(values: &[f32]) -> (f64, f64) {
    let n = values.len() as f64;
    let mean = values.iter().map(|&v| v as f64).sum::<f64>() / n;
    let var = values
        .iter()
        .map(|&v| (v as f64 - mean).powi(2))
        .sum::<f64>()
        / n;
    (mean, var.sqrt())
}

/// Mean absolute step between neighbouring columns across `block`-texel edges, over the mean
/// step inside blocks.
fn block_edge_ratio(map: &Map, block: usize) -> f64 {
    let (w, plane) = (map.width(), map.plane(0));
    let (mut edge, mut inner, mut ne, mut ni) = (0.0f64, 0.0f64, 0usize, 0usize);
    for y in 0..map.height() {
        for x in 1..w {
            let step = (plane[y * w + x] - plane[y * w + x - 1]).abs() as f64;
            if x % block == 0 {
                edge += step;
                ne += 1;
            } else {
                inner += step;
                ni += 1;
            }
        }
    }
    (edge / ne as f64) / (inner / ni as f64)
}

#[test]
fn block_compression_loses_what_its_format_cannot_hold() {
    let grey = smooth_grey(64);
    let error = |format| {
        let out = Degradation::Block(format)
            .apply(MapKind::Roughness, &grey, &mut rng())
            .unwrap();
        stored_error(MapKind::Roughness, &grey, &out)
    };
    // BC4 keeps 8-bit endpoints and 8 steps a block; BC1 5–6-bit endpoints and 4 steps.
    let (bc4, bc1) = (error(BlockFormat::Bc4), error(BlockFormat::Bc1));
    assert!(bc4 < 1.0, "BC4 of a smooth grey map: {bc4:.2} levels");
    assert!(bc1 > bc4 && bc1 < 6.0, "BC1 {bc1:.2}, BC4 {bc4:.2} levels");
    // Colour with texel detail: BC1's 4 colours on a line per block lose several levels.
    let colour = detailed_colour(64);
    let out = Degradation::Block(BlockFormat::Bc1)
        .apply(MapKind::BaseColor, &colour, &mut rng())
        .unwrap();
    let bc1 = stored_error(MapKind::BaseColor, &colour, &out);
    assert!(
        (3.0..40.0).contains(&bc1),
        "BC1 of detailed colour: {bc1:.2} levels"
    );
}

#[test]
fn bc5_normals_stay_unit_and_close() {
    let normal = Map::from_fn(32, 32, 3, |c, y, x| {
        let (nx, ny) = (0.4 * (x as f32 * 0.3).sin(), 0.3 * (y as f32 * 0.2).cos());
        [nx, ny, (1.0 - nx * nx - ny * ny).sqrt()][c]
    });
    let out = Degradation::Block(BlockFormat::Bc5)
        .apply(MapKind::Normal, &normal, &mut rng())
        .unwrap();
    let mut worst = 0.0f32;
    for i in 0..normal.texels() {
        let a: [f32; 3] = normal.texel(i);
        let b: [f32; 3] = out.texel(i);
        let length = (b[0] * b[0] + b[1] * b[1] + b[2] * b[2]).sqrt();
        assert!((length - 1.0).abs() < 1e-4, "texel {i}: length {length}");
        let cos = a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
        worst = worst.max(cos.min(1.0).acos().to_degrees());
    }
    assert!(worst > 0.0 && worst < 3.0, "worst angle {worst}°");
}

#[test]
fn jpeg_loses_more_at_low_quality_and_draws_its_block_grid() {
    let colour = detailed_colour(64);
    let error = |quality, subsampling| {
        let out = Degradation::Jpeg {
            quality,
            subsampling,
        }
        .apply(MapKind::BaseColor, &colour, &mut rng())
        .unwrap();
        stored_error(MapKind::BaseColor, &colour, &out)
    };
    let (q40, q95) = (error(40, Subsampling::Full), error(95, Subsampling::Full));
    assert!(q40 > 2.0 * q95, "quality 40: {q40:.2}, 95: {q95:.2} levels");
    assert!(
        error(75, Subsampling::Half) > error(75, Subsampling::Full),
        "4:2:0 loses the chroma that 4:4:4 keeps"
    );
    // On a smooth map a low quality steps at the 8-texel block edges.
    let grey = smooth_grey(128);
    let out = Degradation::Jpeg {
        quality: 20,
        subsampling: Subsampling::Half,
    }
    .apply(MapKind::Roughness, &grey, &mut rng())
    .unwrap();
    let (before, after) = (block_edge_ratio(&grey, 8), block_edge_ratio(&out, 8));
    assert!(
        (before - 1.0).abs() < 0.1 && after > 1.5,
        "block-edge ratio {before:.2} → {after:.2}"
    );
}

#[test]
fn dithering_keeps_the_mean_on_few_levels() {
    let ramp = Map::from_fn(64, 64, 1, |_, _, x| x as f32 / 63.0 * 0.8 + 0.1);
    for method in [DitherMethod::Ordered, DitherMethod::ErrorDiffusion] {
        let out = Degradation::Dither { levels: 4, method }
            .apply(MapKind::Metallic, &ramp, &mut rng())
            .unwrap();
        let mut values: Vec<i32> = out
            .data()
            .iter()
            .map(|v| (v * 3.0).round() as i32)
            .collect();
        assert!(out
            .data()
            .iter()
            .all(|v| ((v * 3.0) - (v * 3.0).round()).abs() < 1e-5));
        values.sort();
        values.dedup();
        assert!(values.len() <= 4, "{method:?}: {values:?}");
        // Each 8-column stripe keeps its mean within 6 levels (not rounded to the nearest).
        for stripe in 0..8 {
            let mean = |m: &Map| {
                let mut sum = 0.0;
                for y in 0..64 {
                    for x in stripe * 8..stripe * 8 + 8 {
                        sum += m.plane(0)[y * 64 + x];
                    }
                }
                sum / 512.0 * 255.0
            };
            let (a, b) = (mean(&ramp), mean(&out));
            assert!(
                (a - b).abs() < 6.0,
                "{method:?} stripe {stripe}: {a:.1} → {b:.1}"
            );
        }
    }
}

#[test]
fn noise_has_the_strength_it_is_given() {
    let grey = Map::filled(128, 128, 1, 0.5);
    let out = Degradation::GaussianNoise { sigma: 4.0 }
        .apply(MapKind::Height, &grey, &mut rng())
        .unwrap();
    let (mean, sd) = mean_and_sd(out.data());
    assert!(
        (mean - 0.5).abs() < 0.002 && (sd * 255.0 - 4.0).abs() < 0.3,
        "{mean} {sd}"
    );
    // Shot noise: variance v / peak.
    let out = Degradation::PoissonNoise { peak: 200.0 }
        .apply(MapKind::Height, &grey, &mut rng())
        .unwrap();
    let (mean, sd) = mean_and_sd(out.data());
    let expected = (0.5f64 / 200.0).sqrt();
    assert!(
        (mean - 0.5).abs() < 0.003 && (sd / expected - 1.0).abs() < 0.08,
        "{mean} {sd}"
    );
    // The same seed draws the same noise.
    let again = Degradation::PoissonNoise { peak: 200.0 }
        .apply(MapKind::Height, &grey, &mut rng())
        .unwrap();
    assert_eq!(out, again);
}

#[test]
fn blur_smooths_and_halos_overshoot_edges() {
    let noise = Degradation::GaussianNoise { sigma: 20.0 }
        .apply(MapKind::Height, &Map::filled(64, 64, 1, 0.5), &mut rng())
        .unwrap();
    let blurred = Degradation::Blur { sigma: 1.0 }
        .apply(MapKind::Height, &noise, &mut rng())
        .unwrap();
    let ((m0, s0), (m1, s1)) = (mean_and_sd(noise.data()), mean_and_sd(blurred.data()));
    assert!(
        (m0 - m1).abs() < 0.002 && s1 < 0.5 * s0,
        "sd {s0:.4} → {s1:.4}"
    );
    let step = Map::from_fn(32, 8, 1, |_, _, x| if x < 16 { 0.3 } else { 0.7 });
    let halo = Degradation::Halo {
        sigma: 1.5,
        amount: 0.8,
    }
    .apply(MapKind::Roughness, &step, &mut rng())
    .unwrap();
    let row = &halo.plane(0)[..32];
    assert!(row[15] < 0.25 && row[16] > 0.75, "{:?}", &row[12..20]);
    assert!(
        (row[2] - 0.3).abs() < 1e-3 && (row[29] - 0.7).abs() < 1e-3,
        "flat far away"
    );
}

#[test]
fn named_degradations_parse_and_reach_every_stored_map() {
    for (name, bc) in [("bc1", None), ("dds", Some(BlockFormat::Bc5))] {
        let d: MaterialDegradation = name.parse().unwrap();
        assert_eq!(d.to_string(), name);
        if let Some(bc) = bc {
            assert_eq!(d.for_kind(MapKind::Normal), vec![Degradation::Block(bc)]);
            assert_eq!(
                d.for_kind(MapKind::Roughness),
                vec![Degradation::Block(BlockFormat::Bc4)]
            );
        }
    }
    let d: MaterialDegradation = "blur0.7+jpeg60-444".parse().unwrap();
    assert_eq!(
        d.for_kind(MapKind::BaseColor),
        vec![
            Degradation::Blur { sigma: 0.7 },
            Degradation::Jpeg {
                quality: 60,
                subsampling: Subsampling::Full
            }
        ]
    );
    // A step on some maps alone: the others skip it.
    let d: MaterialDegradation = "noise2+jpeg75@baseColor+jpeg75@roughness".parse().unwrap();
    let noise = Degradation::GaussianNoise { sigma: 2.0 };
    let jpeg = Degradation::Jpeg {
        quality: 75,
        subsampling: Subsampling::Half,
    };
    assert_eq!(d.for_kind(MapKind::BaseColor), vec![noise, jpeg]);
    assert_eq!(d.for_kind(MapKind::Roughness), vec![noise, jpeg]);
    assert_eq!(d.for_kind(MapKind::Normal), vec![noise]);
    let bad_map = "jpeg75@albedo".parse::<MaterialDegradation>().unwrap_err();
    assert!(bad_map.to_string().contains("no map 'albedo'"), "{bad_map}");
    for bad in ["jpeg0", "jpeg101", "noise-1", "dither1", "bc7", ""] {
        let message = bad.parse::<MaterialDegradation>().unwrap_err().to_string();
        assert!(message.contains(&format!("'{bad}'")), "{message}");
    }
    // Mid values, so that no noise is clipped at 0 or 1.
    let mut material = Material::uniform(32, [0.5; 3], 0.5, 0.5);
    material.base_color = detailed_colour(32);
    material.height = Some(smooth_grey(32));
    let degraded = degrade_material(&material, &"noise3".parse().unwrap(), &mut rng()).unwrap();
    for kind in STORED_KINDS {
        let (a, b) = (material.map(kind).unwrap(), degraded.map(kind).unwrap());
        let moved = stored_error(kind, a, b);
        assert!((1.5..4.0).contains(&moved), "{kind:?}: {moved:.2} levels");
    }
}

#[test]
fn lossy_storage_is_marked_as_a_lossy_file_would_be() {
    let material = Material::uniform(16, [0.5; 3], 0.5, 0.5);
    let marked = |name: &str| {
        let d: MaterialDegradation = name.parse().unwrap();
        degrade_material(&material, &d, &mut rng()).unwrap().lossy
    };
    let jpeg = marked("noise2+jpeg75");
    assert_eq!(
        jpeg.len(),
        STORED_KINDS.len() - 1,
        "no height map: {jpeg:?}"
    );
    assert_eq!(jpeg[&MapKind::BaseColor], "JPEG (simulated: noise2+jpeg75)");
    let colour_alone = marked("jpeg75@baseColor");
    assert_eq!(
        colour_alone.keys().collect::<Vec<_>>(),
        [&MapKind::BaseColor],
        "{colour_alone:?}"
    );
    let dds = marked("dds");
    assert_eq!(dds[&MapKind::Normal], "BC5 blocks (simulated: dds)");
    assert_eq!(dds[&MapKind::Roughness], "BC4 blocks (simulated: dds)");
    // Noise, blur, halos and dithering leave nothing a file's format tells.
    assert!(marked("noise3+blur0.5+halo0.5+dither32").is_empty());
    // Nor does a lossy file saved again as PNG, on the maps it reached; its texels are the
    // lossy file's.
    assert!(marked("bc1-png").is_empty() && marked("dds-png").is_empty());
    assert_eq!(
        marked("jpeg75-png@normal+jpeg75@baseColor")
            .keys()
            .collect::<Vec<_>>(),
        [&MapKind::BaseColor]
    );
    let d: MaterialDegradation = "jpeg75-444-png".parse().unwrap();
    assert_eq!(d.to_string(), "jpeg75-444-png");
    let jpeg = Degradation::Jpeg {
        quality: 75,
        subsampling: Subsampling::Full,
    };
    assert_eq!(
        d.for_kind(MapKind::Roughness),
        vec![jpeg, Degradation::SavedAsPng]
    );
    let mut detailed = material.clone();
    detailed.base_color = detailed_colour(16);
    let as_png = |name: &str| {
        let d: MaterialDegradation = name.parse().unwrap();
        degrade_material(&detailed, &d, &mut rng()).unwrap()
    };
    assert_eq!(as_png("bc1-png").base_color, as_png("bc1").base_color);
    // Averaged blocks are no longer what the file stored.
    let degraded = degrade_material(&material, &"bc1".parse().unwrap(), &mut rng()).unwrap();
    assert!(degraded.crop(0, 0, 8, 8).lossy.len() == 4);
    assert!(degraded.box_downsample(2).lossy.is_empty());
}

#[test]
fn half_resizes_after_storing_and_the_input_is_cut_larger_for_it() {
    let d: MaterialDegradation = "jpeg75+half".parse().unwrap();
    assert_eq!((d.shrink(), d.to_string().as_str()), (2, "jpeg75+half"));
    assert_eq!("jpeg75".parse::<MaterialDegradation>().unwrap().shrink(), 1);
    assert_eq!(
        "half+half".parse::<MaterialDegradation>().unwrap().shrink(),
        4
    );
    let mut truth = Material::uniform(64, [0.5; 3], 0.5, 0.5);
    truth.base_color = detailed_colour(64);
    truth.height = Some(smooth_grey(64));
    // Every map, the height too, comes out at 1/4: cut at 1/2, stored, halved.
    let input = degraded_input(&truth, 4, Some(&d), &mut rng()).unwrap();
    assert_eq!((input.width(), input.height_px()), (16, 16));
    assert_eq!(input.height.as_ref().map(|h| h.width()), Some(16));
    // Saved again after the resize: no file says JPEG, and the values are 8-bit levels.
    assert!(input.lossy.is_empty(), "{:?}", input.lossy);
    let stored = MapKind::Roughness.stored(0, input.roughness.plane(0)[37]) * 255.0;
    assert!((stored - stored.round()).abs() < 1e-3, "{stored}");
    // The JPEG's blocks are averaged, not gone: the input is not the clean one halved.
    let clean = degraded_input(&truth, 4, None, &mut rng()).unwrap();
    let moved = stored_error(MapKind::BaseColor, &clean.base_color, &input.base_color);
    assert!(moved > 0.3, "{moved:.2} levels");
    // Without a resize, the input is the truth box-filtered, then degraded.
    let plain: MaterialDegradation = "noise3".parse().unwrap();
    let direct = degrade_material(&truth.box_downsample(4), &plain, &mut rng()).unwrap();
    let via = degraded_input(&truth, 4, Some(&plain), &mut rng()).unwrap();
    assert_eq!(direct.base_color, via.base_color);
    // What cannot be: a factor half cannot divide, a resize of one map alone.
    let odd = degraded_input(&truth, 3, Some(&d), &mut rng()).unwrap_err();
    assert!(odd.to_string().contains("multiple of 2"), "{odd}");
    let one = "half@baseColor".parse::<MaterialDegradation>().unwrap_err();
    assert!(one.to_string().contains("resizes every map"), "{one}");
}
