//! Tileable in, tileable out. A tileable input's output is seamless when the pipeline cannot
//! tell where the input's border was: upscaling the input moved by half its size must give the
//! output moved by half its size, every map, at every scale, whole and in bands. A seam would
//! show up as a difference along the middle.

mod common;

use matup::config::Config;
use matup::eval::metrics::{block_edge_ratio, false_colour};
use matup::material::Material;
use matup::progress::Silent;
use matup::resample::{box_downsample, Border};
use matup::{Map, MapKind, RunOptions};

/// The material moved by `d` texels on both axes, wrapping around.
fn rolled(m: &Material, d: usize) -> Material {
    let mut out = m.clone();
    for map in out.maps_mut() {
        let (w, h) = (map.width(), map.height());
        *map = Map::from_fn(w, h, map.channels(), |c, y, x| {
            map.get(c, (y + h - d) % h, (x + w - d) % w)
        });
    }
    out
}

/// A real grid material (its joints lie on the border) at `side`², with an occlusion map and
/// a base-colour alpha carried along.
fn tiles(side: usize) -> Material {
    let whole = common::load_test_material("ambientcg_Tiles036");
    common::with_occlusion_and_alpha(whole.box_downsample(whole.width() / side))
}

/// The largest difference, over every map, between `expected` and `got`.
fn worst_difference(expected: &Material, got: &Material) -> f32 {
    let maps: Vec<(&Map, &Map)> = expected.maps().zip(got.maps()).collect();
    assert_eq!(maps.len(), expected.maps().count());
    assert_eq!(
        maps.len(),
        7,
        "five maps, occlusion and alpha: {}",
        maps.len()
    );
    maps.iter()
        .map(|(a, b)| common::max_abs_diff(a, b))
        .fold(0.0, f32::max)
}

#[test]
fn a_tileable_grid_comes_back_seamless_at_every_scale() {
    // (scale, input side, memory limit): ×16 runs two levels; the limited ×4 runs in bands.
    for (scale, side, limit_mib) in [
        (2, 32, None),
        (3, 32, None),
        (4, 32, None),
        (16, 16, None),
        (4, 128, Some(24)),
    ] {
        let lr = tiles(side);
        let options = RunOptions {
            memory_limit: limit_mib.map(|m: u64| m << 20),
            ..RunOptions::default()
        };
        let run = |m: &Material, tileable: Option<bool>| {
            let config = Config {
                scale,
                tileable,
                seed: 1,
                ..Config::default()
            };
            matup::upscale(m, &config, &options, &Silent).unwrap()
        };
        // Decided tileable by default: the joints on the border are like the others.
        let (out, report) = run(&lr, None);
        assert!(report.tileable, "×{scale}");
        if limit_mib.is_some() {
            assert!(
                report.levels[0].bands >= 2,
                "{} bands",
                report.levels[0].bands
            );
        }
        let half = side / 2;
        let (moved, _) = run(&rolled(&lr, half), None);
        let seam = worst_difference(&rolled(&out, half * scale), &moved);
        println!("×{scale} from {side}²: moved input {seam:.2e}");
        assert!(seam <= 1e-5, "×{scale}: {seam}");
        if scale <= 4 && limit_mib.is_none() {
            // Mirrored borders treat the border as an edge: there the output does depend on
            // it, so the check above can fail (checked where runs are quick).
            let (mirrored, _) = run(&lr, Some(false));
            let (mirrored_moved, _) = run(&rolled(&lr, half), Some(false));
            let mirrored_seam = worst_difference(&rolled(&mirrored, half * scale), &mirrored_moved);
            println!("  mirrored {mirrored_seam:.3}");
            assert!(mirrored_seam > 0.02, "×{scale}: {mirrored_seam}");
        }
    }
}

/// No texel grid in the output: on a real material, box-filtered and upscaled ×4 and ×16 with
/// the defaults, the base colour's steps across the input's texel edges, over the steps inside
/// a texel, are no higher than a plain bicubic resampler's (the bar; the network that
/// shipped before drew 1.62 here at ×4, against bicubic's 1.33).
#[test]
fn the_defaults_draw_no_more_texel_grid_than_bicubic() {
    let whole = common::load_test_material("ambientcg_PavingStones092");
    let bicubic = matup::upsampler(&"bicubic".parse().unwrap()).unwrap();
    for scale in [4, 16] {
        let lr = whole.box_downsample(scale);
        let config = Config {
            scale,
            tileable: Some(true),
            seed: 1,
            ..Config::default()
        };
        let ours = matup::upscale(&lr, &config, &RunOptions::default(), &Silent)
            .unwrap()
            .0;
        let plain =
            matup::per_map::upscale_per_map(&lr, bicubic.as_ref(), scale, Border::Wrap).unwrap();
        let ratio = |m: &Material| block_edge_ratio(&m.base_color, scale);
        let (ours, plain) = (ratio(&ours), ratio(&plain));
        println!("×{scale}: block-edge ratio {ours:.3}, bicubic's {plain:.3}");
        assert!(ours <= plain, "×{scale}: {ours} against bicubic's {plain}");
    }
}

/// The chroma clamp's colours brought back to their input by back-projection
/// (`filter.clamp_back_project`) instead of block by block: fewer steps on the input's texel
/// edges, each block's mean still its input texel's, no false colour, the other maps as they
/// were.
#[test]
fn the_clamp_brought_back_smoothly_draws_less_grid() {
    let whole = common::load_test_material("ambientcg_PavingStones092");
    let lr = whole.box_downsample(4);
    let run = |smooth: bool| {
        let mut config = Config {
            scale: 4,
            tileable: Some(true),
            seed: 1,
            ..Config::default()
        };
        config.filter.clamp_back_project = smooth;
        matup::upscale(&lr, &config, &RunOptions::default(), &Silent)
            .unwrap()
            .0
    };
    let (blocks, smooth) = (run(false), run(true));
    let ratio = |m: &Material| block_edge_ratio(&m.base_color, 4);
    println!(
        "block-edge ratio: blocks settled {:.3}, brought back smoothly {:.3}",
        ratio(&blocks),
        ratio(&smooth)
    );
    assert!(ratio(&smooth) < ratio(&blocks) - 0.05);
    for out in [&blocks, &smooth] {
        let means = box_downsample(&out.base_color, 4);
        let off = common::max_abs_diff(&means, &lr.base_color);
        assert!(off <= 2e-4, "a block's mean is {off} off its input texel");
        let fc = false_colour(&lr.base_color, &out.base_color, None, Border::Wrap).unwrap();
        assert_eq!(fc.false_colour_texels, 0.0);
    }
    assert!(common::max_abs_diff(&blocks.base_color, &smooth.base_color) > 1e-3);
    for kind in [MapKind::Normal, MapKind::Roughness, MapKind::Metallic] {
        let (a, b) = (blocks.map(kind).unwrap(), smooth.map(kind).unwrap());
        assert_eq!(common::max_abs_diff(a, b), 0.0, "{kind:?}");
    }
}
