//! Outputs made in bands of rows within a memory limit equal the whole-image path: matup's
//! defaults (each map through SPAN ×4, back-projected, height rebuilt from the normals) on a
//! real material, ×4 and ×16, tileable and not, every map within 1/255 of the whole run's as
//! its file stores it (base colour in sRGB, normals as colours).

mod common;

use matup::color::linear_to_srgb;
use matup::config::Config;
use matup::material::{MapKind, Material};
use matup::pipeline::upscale;
use matup::progress::Silent;
use matup::{Map, RunOptions};

/// A map's values as its 8-bit file holds them, before rounding.
fn as_stored(kind: MapKind, map: &Map) -> Map {
    match kind {
        MapKind::BaseColor => map.clone().map_values(linear_to_srgb),
        MapKind::Normal => map.clone().map_values(|v| 0.5 * (v + 1.0)),
        _ => map.clone(),
    }
}

#[test]
fn bands_equal_the_whole_image() {
    let truth = matup::load_material(
        Some(&common::shared_material("polyhaven_coast_sand_rocks_02")),
        &Default::default(),
    )
    .unwrap();
    // 128² → 512² in one level, 32² → 512² in two (the second in bands).
    for (scale, side) in [(4, 128), (16, 32)] {
        let lr = truth.box_downsample(truth.width() / side);
        for tileable in [false, true] {
            let config = Config {
                scale,
                tileable: Some(tileable),
                ..Config::default()
            };
            let whole = upscale(&lr, &config, &RunOptions::default(), &Silent).unwrap();
            // 20 MiB: bands of about 100 output rows at 512 wide.
            let limited = RunOptions {
                memory_limit: Some(20 << 20),
                ..RunOptions::default()
            };
            let (banded, report) = upscale(&lr, &config, &limited, &Silent).unwrap();
            let bands = report.levels.last().unwrap().bands;
            assert!(bands >= 4, "×{scale}, tileable {tileable}: {bands} bands");
            assert_eq!(whole.1.levels.last().unwrap().bands, 1);
            for kind in MapKind::ALL {
                let (Some(a), Some(b)) = (whole.0.map(kind), banded.map(kind)) else {
                    assert!(whole.0.map(kind).is_none() && banded.map(kind).is_none());
                    continue;
                };
                let worst = common::max_abs_diff(&as_stored(kind, a), &as_stored(kind, b));
                println!("×{scale}, tileable {tileable}, {bands} bands, {kind}: {worst:.2e}");
                assert!(
                    worst <= 1.0 / 255.0,
                    "×{scale}, tileable {tileable}, {kind}: {worst}"
                );
            }
        }
    }
}

/// Not a material's worth of memory: the limit is refused with the sizes in the message.
#[test]
fn a_limit_too_low_for_any_band_says_what_it_needs() {
    let lr = Material::uniform(256, [0.5; 3], 0.5, 0.0);
    let config = Config {
        upsampler: "bicubic".into(),
        ..Config::default()
    };
    let options = RunOptions {
        memory_limit: Some(8 << 20),
        ..RunOptions::default()
    };
    let error = upscale(&lr, &config, &options, &Silent)
        .unwrap_err()
        .to_string();
    assert!(
        error.contains("8 MiB") && error.contains("256×256 → 1024×1024"),
        "{error}"
    );
}
