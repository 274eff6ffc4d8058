//! The residual base's tests: back-projection and the settling of blocks onto their input.

use super::*;
use matup_core::resample::box_downsample;

/// Features with variation in every channel, valid ranges.
fn lr_features(size: usize) -> Map {
    Map::from_fn(size, size, FEATURES, |c, y, x| {
        let v = ((x * 3 + y * 5 + c * 7) % 11) as f32 / 10.0;
        match c {
            4 | 5 => 0.4 * (v - 0.5),
            6 => 0.05 + 0.9 * v,
            _ => 0.1 + 0.8 * v,
        }
    })
}

#[test]
fn back_projection_is_rounds_of_box_downsample_and_bilinear_spread() {
    // The fused rounds compute what the two resampling steps compute apart, bit for bit:
    // odd sizes and more rows than one parallel task takes, both borders.
    let lr = Map::from_fn(13, 37, FEATURES, |c, y, x| {
        let v = ((x * 5 + y * 3 + c * 11) % 13) as f32 / 12.0;
        if c == 4 || c == 5 {
            v - 0.5
        } else {
            v
        }
    });
    for border in [Border::Wrap, Border::Mirror] {
        let start =
            upsample(&lr, 4, Kernel::Bicubic { a: -0.5 }, border).map_values(|v| 0.9 * v + 0.03);
        let mut fused = start.clone();
        back_project_within(&mut fused, &lr, 4, border, stored_range);
        let mut apart = start;
        for _ in 0..BACK_PROJECTIONS {
            let seen = box_downsample(&apart, 4);
            for c in 0..FEATURES {
                let mismatch: Vec<f32> = (lr.plane(c).iter().zip(seen.plane(c)))
                    .map(|(l, s)| l - s)
                    .collect();
                let mismatch = Map::from_planar(lr.width(), lr.height(), 1, mismatch);
                let correction = upsample(&mismatch, 4, Kernel::Bilinear, border);
                let (lo, hi) = stored_range(c);
                for (v, f) in apart.plane_mut(c).iter_mut().zip(correction.data()) {
                    *v = (*v + f).clamp(lo, hi);
                }
            }
        }
        settle_blocks(&mut apart, &lr, 4, 0..FEATURES, stored_range);
        assert_eq!(fused.data(), apart.data(), "{border}");
    }
}

#[test]
fn settled_blocks_average_to_their_input_even_where_texels_are_pinned() {
    // LR texels at the range's ends and beside them, and a block upsampled far off.
    let lr = Map::from_fn(6, 4, 1, |_, y, x| {
        [0.0, 1.0, 0.98, 0.02, 0.5, 0.3][(x + y) % 6]
    });
    let mut hr = upsample(&lr, 4, Kernel::Bicubic { a: -0.5 }, Border::Mirror)
        .map_values(|v| (0.8 * v + 0.1).clamp(0.0, 1.0));
    back_project_within(&mut hr, &lr, 4, Border::Mirror, |_| (0.0, 1.0));
    let seen = box_downsample(&hr, 4);
    let worst = (seen.data().iter().zip(lr.data()))
        .map(|(a, b)| (a - b).abs())
        .fold(0.0, f32::max);
    assert!(worst <= SETTLE_ABOVE + 1e-6, "{worst}");
    assert!(hr.data().iter().all(|v| (0.0..=1.0).contains(v)));
    // Where the rounds alone leave a block: they cannot lift 0.9 to 1 in four texels of
    // a block of a pinned 1.0 beside a 0.0.
    let mut rounds_only = upsample(&lr, 4, Kernel::Bicubic { a: -0.5 }, Border::Mirror)
        .map_values(|v| (0.8 * v + 0.1).clamp(0.0, 1.0));
    let before = box_downsample(&rounds_only, 4);
    settle_blocks(&mut rounds_only, &lr, 4, 0..1, |_| (0.0, 1.0));
    let after = box_downsample(&rounds_only, 4);
    for (i, (b, a)) in before.data().iter().zip(after.data()).enumerate() {
        let want = lr.data()[i];
        let miss = (b - want).abs();
        if miss >= 2.0 * SETTLE_ABOVE {
            assert!((a - want).abs() < 1e-5, "block {i}: {b} → {a}, want {want}");
        } else if miss > SETTLE_ABOVE {
            assert!((a - want).abs() <= SETTLE_ABOVE, "block {i}: {b} → {a}");
        } else {
            assert_eq!(a, b, "block {i} was within reach and is left as it was");
        }
    }
}

#[test]
fn back_projection_brings_the_box_downsample_back_to_the_input() {
    let lr = lr_features(12);
    for border in [Border::Wrap, Border::Mirror] {
        // A blurred base: bilinear interpolation does not average back to its input.
        let mut hr = upsample(&lr, 4, Kernel::Bilinear, border);
        // Mean absolute mismatch of the box-downsample, as the files store the values
        // (roughness, not alpha; the test map changes every texel, the hardest case for a
        // bilinear back-projection).
        let stored = |map: &Map| {
            let mut map = map.clone();
            map.plane_mut(ALPHA).iter_mut().for_each(|a| *a = a.sqrt());
            map
        };
        let error = |hr: &Map| {
            let seen = box_downsample(&stored(hr), 4);
            (seen.data().iter().zip(stored(&lr).data()))
                .map(|(a, b)| (a - b).abs())
                .sum::<f32>()
                / lr.data().len() as f32
        };
        let before = error(&hr);
        let every = projected_features(&FilterConfig::default());
        back_project(&mut hr, &lr, 4, border, 1.0, &every);
        let after = error(&hr);
        println!("{border}: mismatch {before:.4} → {after:.4}");
        assert!(before > 0.02, "{border}: {before}");
        assert!(after < 0.3 * before, "{border}: {before} → {after}");
        for (c, plane) in hr.data().chunks(hr.texels()).enumerate() {
            let (lo, hi) = stored_range(c);
            assert!(plane.iter().all(|v| (lo..=hi).contains(v)), "feature {c}");
        }
    }
}

#[test]
fn a_low_pass_projection_takes_back_a_colour_drift_and_leaves_fine_detail_and_other_maps() {
    // A smooth input, and a base that box-filters to it plus a drift of the whole colour
    // (+0.1) and a fine ±0.03 checker (detail the input's storage lost, set right), both
    // sRGB-encoded, as the projection compares colours.
    let size = 32;
    let lr = Map::from_fn(size, size, FEATURES, |c, y, x| match c {
        4 | 5 => 0.1,
        _ => 0.3 + 0.2 * (x + y) as f32 / (2 * size) as f32,
    });
    let checker = |y: usize, x: usize| {
        if (x + y).is_multiple_of(2) {
            0.03
        } else {
            -0.03
        }
    };
    let seen = Map::from_fn(size, size, FEATURES, |c, y, x| match c {
        0..=2 => srgb_to_linear(linear_to_srgb(lr.get(c, y, x)) + 0.1 + checker(y, x)),
        _ => lr.get(c, y, x) + 0.05,
    });
    let target = projection_target(&box_colour(&seen), &lr, Border::Mirror, 16.0);
    for c in 0..3 {
        for (y, x) in [(3, 4), (16, 16), (28, 30)] {
            // The drift is taken back, the checker kept (within the blur's leak of it).
            let kept = linear_to_srgb(target.get(c, y, x)) - linear_to_srgb(lr.get(c, y, x));
            assert!(
                (kept - checker(y, x)).abs() < 0.005,
                "{c} ({y}, {x}): {kept}"
            );
        }
    }
    // A base whose colour drifted is brought back to the target in its colour alone: the
    // other maps are left as the base has them.
    let base = upsample(&seen, 4, Kernel::Bilinear, Border::Mirror);
    let mut projected = base.clone();
    back_project_channels(
        &mut projected,
        &target,
        4,
        Border::Mirror,
        0..3,
        stored_range,
    );
    for c in 3..FEATURES {
        assert_eq!(projected.plane(c), base.plane(c), "feature {c}");
    }
    let colour = box_downsample(&projected, 4);
    let (y, x) = (16, 16);
    assert!((colour.get(0, y, x) - target.get(0, y, x)).abs() < 0.01);
}

/// The colour channels of `features` (the rest left zero), as `projection_target` reads them.
fn box_colour(features: &Map) -> Map {
    let mut colour = features.clone();
    for c in 3..FEATURES {
        colour.plane_mut(c).fill(0.0);
    }
    colour
}

#[test]
fn a_low_pass_projection_keeps_the_input_chroma_and_the_base_detail_in_luma_alone() {
    // A grey input, and a base with a fine checker in red alone: colour the input never had.
    let size = 32;
    let lr = Map::from_fn(size, size, FEATURES, |c, y, x| match c {
        0..=2 => 0.2 + 0.3 * x as f32 / size as f32 + 0.1 * y as f32 / size as f32,
        _ => 0.1,
    });
    let seen = Map::from_fn(size, size, FEATURES, |c, y, x| {
        let checker = if (x + y) % 2 == 0 { 0.05 } else { -0.05 };
        lr.get(c, y, x) + if c == 0 { checker } else { 0.0 }
    });
    let target = projection_target(&box_colour(&seen), &lr, Border::Mirror, 16.0);
    let mut moved = 0.0f32;
    for i in 0..size * size {
        let [r, g, b] = [0, 1, 2].map(|c| target.plane(c)[i]);
        // Grey stays grey: the detail is added to every channel alike.
        assert!(
            (r - g).abs() < 1e-6 && (b - g).abs() < 1e-6,
            "texel {i}: {r} {g} {b}"
        );
        moved += (g - lr.plane(1)[i]).abs();
    }
    // The red checker's luma (0.2126 of it, sRGB-encoded) is kept as detail, not taken back.
    let mean_moved = moved / (size * size) as f32;
    assert!(
        (0.005..0.02).contains(&mean_moved),
        "mean detail kept {mean_moved}"
    );
}

#[test]
fn a_band_with_the_context_of_a_low_pass_projection_makes_the_whole_runs_rows() {
    // A noisy colour (a JPEG's noise is high frequencies): its mismatch with a Lanczos base is
    // blurred over 3σ = 48 LR texels, so a band's colour reads that far.
    let size = 160;
    let noise = |i: usize| ((i as u32).wrapping_mul(2_654_435_761) >> 16) as f32 / 65_536.0;
    let mut lr = Material::uniform(size, [0.4; 3], 0.5, 0.0);
    lr.base_color = Map::from_fn(size, size, 3, |c, y, x| {
        0.2 + 0.6 * noise((y * size + x) * 3 + c)
    });
    let config = FilterConfig {
        residual_base: ResidualBase::Kernel(Kernel::Lanczos3),
        projection_blur: 16.0,
        ..FilterConfig::default()
    };
    // The kernel base needs no upsampler.
    let lanczos = matup_core::upsample::KernelUpsampler::new(Kernel::Lanczos3);
    let upsamplers = MapUpsamplers::one(&lanczos);
    let (scale, border) = (4, Border::Mirror);
    let whole = residual_base(&lr, &config, &upsamplers, scale, border).unwrap();
    let context = super::context(&config, &upsamplers);
    // A band of LR rows 72–87 made from its rows and `reach` rows either side: its colour's
    // largest difference from the whole run's.
    let band = |reach: usize| {
        let (first, rows) = (72, 16);
        let input = lr.crop(0, first - reach, size, rows + 2 * reach);
        let base = residual_base(&input, &config, &upsamplers, scale, border).unwrap();
        let w = size * scale;
        let mut worst = 0.0f32;
        for c in 0..3 {
            let ours = &base.plane(c)[reach * scale * w..][..rows * scale * w];
            let theirs = &whole.plane(c)[first * scale * w..][..rows * scale * w];
            for (a, b) in ours.iter().zip(theirs) {
                worst = worst.max((a - b).abs());
            }
        }
        worst
    };
    let (with_reach, without) = (band(context), band(context - gaussian_radius(16.0)));
    println!(
        "band's colour off the whole's: {with_reach:.1e}, without the blur's reach {without:.1e}"
    );
    assert!(with_reach < 1e-5, "{with_reach}");
    assert!(without > 1e-4, "{without}");
}
