//! No artefact a user can see: game textures built like Khronos' DamagedHelmet (grey speckle
//! on a light ground, its colour a JPEG, diagonal stripes whose normals' blue channel
//! disagrees with red and green) come back from the defaults with no more invented structure
//! than bicubic draws; an atlas of islands on black box-filters back to its input.

use std::collections::BTreeMap;
use std::path::Path;

use matup::config::{Config, InputQuality};
use matup::eval::metrics::{new_structure, NewStructure};
use matup::per_map::upscale_per_map;
use matup::progress::Silent;
use matup::report::RunReport;
use matup::resample::{Border, Kernel};
use matup::upsample::KernelUpsampler;
use matup::{load_material, LoadOptions, RunOptions};

const SIDE: u32 = 64;

/// A small deterministic generator: the same "random" texels on every machine.
fn noise(i: u32, salt: u32) -> f32 {
    let mut x = i.wrapping_mul(0x9E37_79B9) ^ salt.wrapping_mul(0x85EB_CA6B);
    x ^= x >> 15;
    x = x.wrapping_mul(0x2C1B_3C6D);
    x ^= x >> 12;
    (x & 0xFFFF) as f32 / 65535.0
}

/// Writes the game texture's four maps as 8-bit PNGs into `folder`.
fn write_game_texture(folder: &std::path::Path) {
    let (w, h) = (SIDE, SIDE);
    let level = |v: f32| v.round().clamp(0.0, 255.0) as u8;
    // Base colour: a light painted ground with grey grime specks (one texel in 9), and the
    // ±4-level noise a JPEG leaves.
    let colour = image::RgbImage::from_fn(w, h, |x, y| {
        let i = y * w + x;
        let speck = noise(i, 1) < 0.11;
        let ground = 200.0 + 8.0 * noise(i, 2) - 4.0;
        let v = if speck {
            ground - 40.0 - 50.0 * noise(i, 3)
        } else {
            ground
        };
        image::Rgb([level(v + 6.0), level(v + 3.0), level(v)])
    });
    // As DamagedHelmet's albedo is stored: a JPEG of quality 85.
    let file = std::fs::File::create(folder.join("basecolor.jpg")).unwrap();
    let jpeg = image::codecs::jpeg::JpegEncoder::new_with_quality(file, 85);
    colour.write_with_encoder(jpeg).unwrap();
    // Normals: diagonal stripes (a groove every 8 texels, its sides tilted 40°) whose blue
    // channel jumps as a baked, compressed texture's does: lengths 0.6–1.25.
    let normal = image::RgbImage::from_fn(w, h, |x, y| {
        let i = y * w + x;
        let phase = (x + y) % 8;
        let tilt: f32 = match phase {
            0..=1 => 0.64,
            2..=3 => -0.64,
            _ => 0.0,
        };
        let (nx, ny) = (tilt / 2f32.sqrt(), tilt / 2f32.sqrt());
        let z = (1.0 - tilt * tilt).sqrt();
        let z = if tilt != 0.0 {
            z * (0.6 + 0.7 * noise(i, 4))
        } else {
            z
        };
        let encode = |v: f32| level(127.5 * (v + 1.0));
        image::Rgb([encode(nx), encode(ny), encode(z.min(1.0))])
    });
    normal.save(folder.join("normal.png")).unwrap();
    // Roughness: grime specks rougher; metallic: a few painted-off patches of bare metal.
    let grey = |f: &dyn Fn(u32) -> f32| {
        image::GrayImage::from_fn(w, h, |x, y| image::Luma([level(f(y * w + x))]))
    };
    grey(&|i| 120.0 + 20.0 * noise(i, 5) + if noise(i, 1) < 0.11 { 70.0 } else { 0.0 })
        .save(folder.join("roughness.png"))
        .unwrap();
    grey(&|i| {
        if noise(i / 4, 6) < 0.05 {
            230.0
        } else {
            10.0 + 6.0 * noise(i, 7)
        }
    })
    .save(folder.join("metallic.png"))
    .unwrap();
}

/// The new structure of the defaults' ×4 of the material in `folder`, and of bicubic's as a
/// user runs it (each map through it on its own), both with mirrored borders (a crop, an
/// atlas).
fn defaults_and_bicubic(folder: &Path) -> (Structures, Structures, RunReport) {
    run_and_bicubic(folder, InputQuality::Auto)
}

/// [`defaults_and_bicubic`] with the input read as `quality` says.
fn run_and_bicubic(folder: &Path, quality: InputQuality) -> (Structures, Structures, RunReport) {
    let lr = load_material(Some(folder), &LoadOptions::default()).unwrap();
    let config = Config {
        tileable: Some(false),
        seed: 1,
        input_quality: quality,
        ..Config::default()
    };
    let (out, report) = matup::upscale(&lr, &config, &RunOptions::default(), &Silent).unwrap();
    let kernel = KernelUpsampler::new(Kernel::Bicubic { a: -0.5 });
    let plain = upscale_per_map(&lr, &kernel, 4, Border::Mirror).unwrap();
    (
        new_structure(&lr, &out, None, Border::Mirror).unwrap(),
        new_structure(&lr, &plain, None, Border::Mirror).unwrap(),
        report,
    )
}

/// Each map's [`NewStructure`], by its file stem.
type Structures = BTreeMap<String, NewStructure>;

#[test]
fn a_speckled_jpeg_game_texture_takes_the_jpeg_route_which_invents_less() {
    let dir = tempfile::tempdir().unwrap();
    write_game_texture(dir.path());
    let (defaults, bicubic, report) = defaults_and_bicubic(dir.path());
    // Its colour is a JPEG: the network for JPEG maps runs on it, projected onto the input's
    // low frequencies alone; its PNG maps run as a clean material's.
    assert_eq!(
        report.upsampler_used,
        "onnx:span_x4_jpeg; normal, roughness, metallic: onnx:span_x4_materials"
    );
    assert!(report
        .input_route
        .contains("base colour from JPEG (basecolor.jpg)"));
    let (told_clean, _, _) = run_and_bicubic(dir.path(), InputQuality::Clean);
    for (map, ours) in &defaults {
        let (clean, theirs) = (told_clean[map].invented.share, bicubic[map].invented.share);
        println!(
            "{map}: invented structure {:.4} (the clean route's {clean:.4}, bicubic's {theirs:.4})",
            ours.invented.share
        );
        if map != "baseColor" {
            assert_eq!(
                *ours, told_clean[map],
                "{map}: a PNG beside the JPEG runs as clean"
            );
            continue;
        }
        // Detail finer than a texel where the input is flat within its noise, that the input's
        // bilinear upsampling lacks: less than the clean network draws out of the same map.
        // (Bicubic draws less still: the study's limit.)
        assert!(
            ours.invented.share < clean,
            "{map}: {} against {clean}",
            ours.invented.share
        );
    }
    // The speckle is there to be drawn: the measure is not blind to it.
    let colour = defaults["baseColor"].invented;
    assert!(colour.flat_share > 0.5 && colour.noise_levels > 1.0 && colour.share > 0.0);
}

/// Writes an atlas as a model's baker leaves it into `folder`: islands of painted, grimy
/// surface with hard edges on black (colour, roughness and metallic zero between the islands,
/// normals flat there).
fn write_atlas(folder: &std::path::Path) {
    let (w, h) = (SIDE, SIDE);
    let level = |v: f32| v.round().clamp(0.0, 255.0) as u8;
    // Islands: two rectangles, a disc and a thin strip (a seam's width of a few texels).
    let island = |x: u32, y: u32| -> Option<u32> {
        let (fx, fy) = (x as f32, y as f32);
        if (3..29).contains(&x) && (4..22).contains(&y) {
            Some(0)
        } else if (34..61).contains(&x) && (6..30).contains(&y) {
            Some(1)
        } else if (fx - 20.0).powi(2) + (fy - 46.0).powi(2) < 14.0f32.powi(2) {
            Some(2)
        } else if (40..59).contains(&x) && (38..41).contains(&y) {
            Some(3)
        } else {
            None
        }
    };
    let colour = image::RgbImage::from_fn(w, h, |x, y| match island(x, y) {
        None => image::Rgb([0, 0, 0]),
        Some(k) => {
            let i = y * w + x;
            let ground = [170.0, 120.0, 215.0, 90.0][k as usize] + 30.0 * noise(i, 8) - 15.0;
            let v = if noise(i, 9) < 0.1 {
                ground - 60.0
            } else {
                ground
            };
            image::Rgb([level(v + 10.0), level(v), level(v - 25.0)])
        }
    });
    colour.save(folder.join("basecolor.png")).unwrap();
    let normal = image::RgbImage::from_fn(w, h, |x, y| match island(x, y) {
        None => image::Rgb([128, 128, 255]),
        Some(_) => {
            let tilt = 0.4 * (noise(y * w + x, 10) - 0.5);
            let z = (1.0 - tilt * tilt).sqrt();
            let encode = |v: f32| level(127.5 * (v + 1.0));
            image::Rgb([encode(tilt), encode(0.0), encode(z)])
        }
    });
    normal.save(folder.join("normal.png")).unwrap();
    let grey = |inside: &dyn Fn(u32, u32) -> f32| {
        image::GrayImage::from_fn(w, h, |x, y| {
            image::Luma([island(x, y).map_or(0, |_| level(inside(x, y)))])
        })
    };
    grey(&|x, y| 140.0 + 60.0 * noise(y * w + x, 11))
        .save(folder.join("roughness.png"))
        .unwrap();
    grey(&|x, y| {
        if island(x, y) == Some(1) {
            235.0
        } else {
            5.0 + 10.0 * noise(y * w + x, 12)
        }
    })
    .save(folder.join("metallic.png"))
    .unwrap();
}

#[test]
fn an_atlas_of_islands_on_black_box_filters_back_block_by_block() {
    let dir = tempfile::tempdir().unwrap();
    write_atlas(dir.path());
    // Mirrored, as a UV atlas is: islands across its edges are no neighbours.
    let (defaults, bicubic, report) = defaults_and_bicubic(dir.path());
    assert_eq!(
        report.upsampler_used, "onnx:span_x4_materials",
        "clean PNGs"
    );
    // The measure sees what a plain resampler does at the islands' edges: bicubic's blocks
    // there ring and do not average back to their input.
    assert!(
        bicubic["baseColor"].box_back_worst > 4.0,
        "{:?}",
        bicubic["baseColor"]
    );
    for map in ["baseColor", "roughness", "metallic"] {
        let n = defaults[map];
        println!("{map}: {n:?}");
        // Every 4×4 block, not only their mean: a black blob or a noise patch is a few blocks.
        assert!(
            n.box_back_worst <= 2.0,
            "{map}: worst block {}",
            n.box_back_worst
        );
        assert!(n.box_back_mean <= 0.5, "{map}: mean {}", n.box_back_mean);
    }
}
