//! Loading and saving materials: naming schemes, conventions, formats, and every bad input.

mod common;

use std::fs;
use std::path::{Path, PathBuf};

use matup::material::{FileFormat, MapKind, Material, NormalConvention};
use matup::progress::Silent;
use matup::{load_material, save_material, LoadOptions, Map, MaterialPaths, SaveOptions};

fn load(folder: &Path) -> matup::Result<Material> {
    load_material(Some(folder), &LoadOptions::default())
}

fn sample() -> Material {
    load(&common::sample_material()).unwrap()
}

/// Mean angle between two unit normal maps, in degrees.
fn mean_angle_degrees(a: &Map, b: &Map) -> f64 {
    let n = a.texels();
    (0..n)
        .map(|i| {
            let d: f32 = (0..3).map(|c| a.plane(c)[i] * b.plane(c)[i]).sum();
            (d.clamp(-1.0, 1.0) as f64).acos().to_degrees()
        })
        .sum::<f64>()
        / n as f64
}

/// Saves `material` in `format` / `convention` into a fresh folder and returns it.
fn saved(
    material: &Material,
    format: FileFormat,
    convention: NormalConvention,
) -> tempfile::TempDir {
    let dir = tempfile::tempdir().unwrap();
    save_material(
        material,
        dir.path(),
        &SaveOptions {
            format: Some(format),
            normal_convention: Some(convention),
            ..SaveOptions::default()
        },
    )
    .unwrap();
    dir
}

/// The material in `dir`, its normals read in `convention` (`--normal-convention`).
fn load_as(dir: &Path, convention: NormalConvention) -> Material {
    let options = LoadOptions {
        normal_convention: Some(convention),
        ..Default::default()
    };
    load_material(Some(dir), &options).unwrap()
}

fn copy(from: &Path, to_dir: &Path, name: &str) -> PathBuf {
    let to = to_dir.join(name);
    fs::copy(from, &to).unwrap();
    to
}

fn error_of(result: matup::Result<Material>) -> String {
    match result {
        Ok(_) => panic!("expected an error"),
        Err(e) => e.to_string(),
    }
}

#[test]
fn loads_real_materials_with_method_conventions() {
    for name in [
        "ambientcg_Metal053C",
        "ambientcg_PavingStones092",
        "polyhaven_denim_fabric",
        "polyhaven_wood_cabinet_worn_long",
        "victorian_wood",
    ] {
        let (folder, size) = match name {
            "victorian_wood" => (common::sample_material(), 128),
            _ => (common::test_material(name), 256),
        };
        let m = load(&folder).unwrap();
        assert_eq!((m.width(), m.height_px()), (size, size), "{name}");
        assert!(m.base_color.data().iter().all(|v| (0.0..=1.0).contains(v)));
        assert!(
            m.roughness.data().iter().all(|v| (0.0..=1.0).contains(v)),
            "{name}: roughness in [0, 1]"
        );
        for i in 0..m.normal.texels() {
            let n: [f32; 3] = m.normal.texel(i);
            let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
            assert!((len - 1.0).abs() < 1e-5, "{name}: normals are unit length");
        }
        assert!(m.height.is_some(), "{name} has a height map");
        assert_eq!(
            m.origin.as_ref().unwrap().normal_convention,
            NormalConvention::DirectX
        );
    }
    // The metallic statistics the set's source.txt gives (a box filter keeps the mean).
    let metal = load(&common::test_material("ambientcg_Metal053C")).unwrap();
    assert!(
        (metal.metallic.mean(0) - 0.54).abs() < 0.01,
        "{}",
        metal.metallic.mean(0)
    );
    let denim = load(&common::test_material("polyhaven_denim_fabric")).unwrap();
    assert!(denim.metallic.data().iter().all(|&v| v == 0.0));
}

#[test]
fn base_colour_is_decoded_from_srgb() {
    let m = sample();
    let dir = saved(&m, FileFormat::ExrFloat, NormalConvention::DirectX);
    let from_exr = load(dir.path()).unwrap();
    // EXR stores linear values: what was decoded from sRGB comes back unchanged.
    assert!(common::max_abs_diff(&m.base_color, &from_exr.base_color) < 1e-6);
    // An sRGB mid-grey (128/255) is linear 0.2158.
    assert!((matup::color::srgb_to_linear(128.0 / 255.0) - 0.2158).abs() < 1e-4);
}

#[test]
fn ambientcg_names_with_both_normal_conventions() {
    let m = sample();
    let dx = saved(&m, FileFormat::Png8, NormalConvention::DirectX);
    let gl = saved(&m, FileFormat::Png8, NormalConvention::OpenGl);
    let jpg = saved(&m, FileFormat::Jpeg, NormalConvention::DirectX);
    let dir = tempfile::tempdir().unwrap();
    let p = "Wood066_1K-JPG";
    copy(
        &jpg.path().join("baseColor.jpg"),
        dir.path(),
        &format!("{p}_Color.jpg"),
    );
    copy(
        &gl.path().join("normal.png"),
        dir.path(),
        &format!("{p}_NormalGL.png"),
    );
    copy(
        &dx.path().join("normal.png"),
        dir.path(),
        &format!("{p}_NormalDX.png"),
    );
    copy(
        &jpg.path().join("roughness.jpg"),
        dir.path(),
        &format!("{p}_Roughness.jpg"),
    );
    copy(
        &jpg.path().join("metallic.jpg"),
        dir.path(),
        &format!("{p}_Metalness.jpg"),
    );
    copy(
        &dx.path().join("height.png"),
        dir.path(),
        &format!("{p}_Displacement.png"),
    );
    copy(
        &dx.path().join("height.png"),
        dir.path(),
        &format!("{p}_AmbientOcclusion.png"),
    );
    copy(&dx.path().join("baseColor.png"), dir.path(), "Wood066.png"); // the preview

    let default = load(dir.path()).unwrap();
    let origin = default.origin.as_ref().unwrap();
    assert_eq!(
        origin
            .source(MapKind::Normal)
            .unwrap()
            .path
            .file_name()
            .unwrap(),
        "Wood066_1K-JPG_NormalDX.png"
    );
    assert_eq!(
        origin
            .source(MapKind::BaseColor)
            .unwrap()
            .path
            .file_name()
            .unwrap(),
        "Wood066_1K-JPG_Color.jpg"
    );
    assert_eq!(
        origin
            .source(MapKind::Height)
            .unwrap()
            .path
            .file_name()
            .unwrap(),
        "Wood066_1K-JPG_Displacement.png"
    );
    assert_eq!(
        origin.source(MapKind::BaseColor).unwrap().format,
        FileFormat::Jpeg
    );

    let opengl = load_as(dir.path(), NormalConvention::OpenGl);
    assert_eq!(
        (opengl.origin.as_ref().unwrap().source(MapKind::Normal))
            .unwrap()
            .path
            .file_name()
            .unwrap(),
        "Wood066_1K-JPG_NormalGL.png"
    );
    // Both files decode to the same geometry as the original.
    assert!(mean_angle_degrees(&default.normal, &m.normal) < 0.3);
    assert!(mean_angle_degrees(&opengl.normal, &m.normal) < 0.3);
    // JPEG is lossy, but close.
    assert!(common::max_abs_diff(&default.base_color, &m.base_color) < 0.08);
}

#[test]
fn normal_convention_comes_from_the_file_name_or_the_option() {
    let m = sample();
    let gl = saved(&m, FileFormat::Png8, NormalConvention::OpenGl);
    let dir = tempfile::tempdir().unwrap();
    for f in ["baseColor.png", "roughness.png"] {
        copy(&gl.path().join(f), dir.path(), f);
    }
    copy(&gl.path().join("normal.png"), dir.path(), "normal.png");
    // The name does not say, nor does an exporter: measured from the maps (no height here:
    // the curl of the normals' slopes), unless told.
    let measured = load(dir.path()).unwrap();
    let origin = measured.origin.as_ref().unwrap();
    assert_eq!(origin.normal_convention, NormalConvention::OpenGl);
    assert!(
        origin.normal_evidence.starts_with("measured"),
        "{}",
        origin.normal_evidence
    );
    assert!(mean_angle_degrees(&measured.normal, &m.normal) < 0.3);
    let as_gl = load_as(dir.path(), NormalConvention::OpenGl);
    assert!(mean_angle_degrees(&as_gl.normal, &m.normal) < 0.3);
    let as_dx = load_as(dir.path(), NormalConvention::DirectX);
    let flipped = Map::from_fn(128, 128, 3, |c, y, x| {
        if c == 1 {
            -as_dx.normal.get(c, y, x)
        } else {
            as_dx.normal.get(c, y, x)
        }
    });
    assert!(mean_angle_degrees(&flipped, &m.normal) < 0.3);
    // Saved in the input's convention by default.
    let out = tempfile::tempdir().unwrap();
    save_material(&as_gl, out.path(), &SaveOptions::default()).unwrap();
    let reread = load_as(out.path(), NormalConvention::OpenGl);
    assert!(mean_angle_degrees(&reread.normal, &m.normal) < 0.3);
}

#[test]
fn polyhaven_names_with_packed_arm_and_exr_normal() {
    let m = sample();
    let exr = saved(&m, FileFormat::ExrHalf, NormalConvention::OpenGl);
    let png = saved(&m, FileFormat::Png8, NormalConvention::DirectX);
    let dir = tempfile::tempdir().unwrap();
    copy(
        &png.path().join("baseColor.png"),
        dir.path(),
        "wood_cabinet_diff_1k.png",
    );
    copy(
        &exr.path().join("normal.exr"),
        dir.path(),
        "wood_cabinet_nor_gl_1k.exr",
    );
    copy(
        &png.path().join("height.png"),
        dir.path(),
        "wood_cabinet_disp_1k.png",
    );
    // Packed occlusion / roughness / metallic.
    let arm: Vec<u8> = (0..128 * 128)
        .flat_map(|i| {
            let q = |v: f32| (v * 255.0).round() as u8;
            [200, q(m.roughness.data()[i]), q(m.metallic.data()[i])]
        })
        .collect();
    image::RgbImage::from_raw(128, 128, arm)
        .unwrap()
        .save(dir.path().join("wood_cabinet_arm_1k.png"))
        .unwrap();

    let loaded = load(dir.path()).unwrap();
    let origin = loaded.origin.as_ref().unwrap();
    assert_eq!(
        origin.normal_convention,
        NormalConvention::OpenGl,
        "nor_gl says OpenGL"
    );
    assert_eq!(
        origin.source(MapKind::Normal).unwrap().format,
        FileFormat::ExrHalf
    );
    assert_eq!(
        origin
            .source(MapKind::Roughness)
            .unwrap()
            .path
            .file_name()
            .unwrap(),
        "wood_cabinet_arm_1k.png"
    );
    assert!(mean_angle_degrees(&loaded.normal, &m.normal) < 0.1);
    assert!(common::max_abs_diff(&loaded.roughness, &m.roughness) < 0.5 / 255.0 + 1e-6);
    assert!(common::max_abs_diff(&loaded.metallic, &m.metallic) < 0.5 / 255.0 + 1e-6);
}

#[test]
fn gloss_becomes_roughness_and_explicit_paths_win() {
    let m = sample();
    let png = saved(&m, FileFormat::Png8, NormalConvention::DirectX);
    let dir = tempfile::tempdir().unwrap();
    copy(
        &png.path().join("baseColor.png"),
        dir.path(),
        "baseColor.png",
    );
    copy(&png.path().join("normal.png"), dir.path(), "normal.png");
    let gloss: Vec<u8> = m
        .roughness
        .data()
        .iter()
        .map(|r| ((1.0 - r) * 255.0).round() as u8)
        .collect();
    image::GrayImage::from_raw(128, 128, gloss)
        .unwrap()
        .save(dir.path().join("gloss.png"))
        .unwrap();
    let loaded = load(dir.path()).unwrap();
    assert!(common::max_abs_diff(&loaded.roughness, &m.roughness) < 0.5 / 255.0 + 1e-6);

    // An explicit roughness file wins over the gloss map found in the folder.
    let other = tempfile::tempdir().unwrap();
    let flat: Vec<u8> = vec![128; 128 * 128];
    let flat_path = other.path().join("anything.png");
    image::GrayImage::from_raw(128, 128, flat)
        .unwrap()
        .save(&flat_path)
        .unwrap();
    let options = LoadOptions {
        paths: MaterialPaths {
            roughness: Some(flat_path),
            ..Default::default()
        },
        ..Default::default()
    };
    let loaded = load_material(Some(dir.path()), &options).unwrap();
    assert!(loaded
        .roughness
        .data()
        .iter()
        .all(|&r| (r - 128.0 / 255.0).abs() < 1e-6));
}

#[test]
fn formats_round_trip_and_are_kept_on_save() {
    let m = sample();
    let cases = [
        (FileFormat::Png8, 0.5 / 255.0 * 1.2, "png"),
        (FileFormat::Png16, 1e-4, "png"),
        (FileFormat::ExrHalf, 1e-3, "exr"),
        (FileFormat::ExrFloat, 1e-6, "exr"),
        (FileFormat::Tiff8, 0.5 / 255.0 * 1.2, "tif"),
        (FileFormat::Tiff16, 1e-4, "tif"),
        (FileFormat::TiffFloat, 1e-6, "tif"),
        (FileFormat::Tga, 0.5 / 255.0 * 1.2, "tga"),
        (FileFormat::Bmp, 0.5 / 255.0 * 1.2, "bmp"),
    ];
    for (format, tolerance, extension) in cases {
        let dir = saved(&m, format, NormalConvention::DirectX);
        let back = load(dir.path()).unwrap();
        for kind in [MapKind::Roughness, MapKind::Metallic, MapKind::Height] {
            let d = common::max_abs_diff(back.map(kind).unwrap(), m.map(kind).unwrap());
            assert!(d <= tolerance, "{format} {kind}: {d}");
        }
        assert!(
            mean_angle_degrees(&back.normal, &m.normal) < 0.3,
            "{format}"
        );
        assert_eq!(
            back.origin
                .as_ref()
                .unwrap()
                .source(MapKind::Roughness)
                .unwrap()
                .format,
            format
        );

        // Saved again without a format: each map keeps its input's format and extension.
        let again = tempfile::tempdir().unwrap();
        let written = save_material(&back, again.path(), &SaveOptions::default()).unwrap();
        assert!(
            written.iter().all(|p| p.extension().unwrap() == extension),
            "{written:?}"
        );
        let reread = load(again.path()).unwrap();
        assert_eq!(
            reread
                .origin
                .as_ref()
                .unwrap()
                .source(MapKind::BaseColor)
                .unwrap()
                .format,
            format
        );
    }
}

#[test]
fn a_16_bit_tiff_a_tga_and_a_bmp_material_upscale_into_their_own_formats() {
    use matup::config::Config;
    use matup::progress::Silent;
    let m = sample();
    let config = Config {
        upsampler: "bicubic".into(),
        ..Config::default()
    };
    // Each against the same run written as the PNG of its bit depth: the same values.
    for (format, extension, png) in [
        (FileFormat::Tiff16, "tif", FileFormat::Png16),
        (FileFormat::Tga, "tga", FileFormat::Png8),
        (FileFormat::Bmp, "bmp", FileFormat::Png8),
    ] {
        let input = saved(&m, format, NormalConvention::DirectX);
        let lr = load(input.path()).unwrap();
        let out = tempfile::tempdir().unwrap();
        common::upscale_into(&lr, &config, out.path(), &SaveOptions::default()).unwrap();
        let back = load(out.path()).unwrap();
        assert_eq!((back.width(), back.height_px()), (512, 512), "{format}");
        let (upscaled, _) = matup::upscale(&lr, &config, &Default::default(), &Silent).unwrap();
        let reference = load(saved(&upscaled, png, NormalConvention::DirectX).path()).unwrap();
        for kind in MapKind::ALL {
            let Some(map) = back.map(kind) else {
                continue;
            };
            let file = &back.origin.as_ref().unwrap().source(kind).unwrap();
            assert_eq!(file.format, format, "{format} {kind}: kept");
            assert_eq!(file.path.extension().unwrap(), extension);
            let worst = common::max_abs_diff(map, reference.map(kind).unwrap());
            assert!(worst < 1e-6, "{format} {kind}: {worst} from {png}");
        }
    }
}

#[test]
fn every_extension_comes_back_spelled_as_it_was() {
    use matup::config::Config;
    use matup::io::write_image;
    let m = sample();
    let config = Config {
        upsampler: "bicubic".into(),
        ..Config::default()
    };
    // Every spelling the readers accept, in both cases: each file comes back under its own.
    let spellings = [
        ("png", FileFormat::Png8),
        ("jpg", FileFormat::Jpeg),
        ("jpeg", FileFormat::Jpeg),
        ("tif", FileFormat::Tiff8),
        ("tiff", FileFormat::Tiff8),
        ("tga", FileFormat::TgaRle),
        ("bmp", FileFormat::Bmp),
        ("webp", FileFormat::WebpLossless),
        ("exr", FileFormat::ExrFloat),
    ];
    for upper in [false, true] {
        for (extension, format) in spellings {
            let extension = match upper {
                true => extension.to_ascii_uppercase(),
                false => extension.to_string(),
            };
            let dir = tempfile::tempdir().unwrap();
            let name = format!("rock_basecolor.{extension}");
            let colour = match format.is_float() {
                true => m.base_color.clone(),
                false => m
                    .base_color
                    .clone()
                    .map_values(matup::color::linear_to_srgb),
            };
            write_image(&dir.path().join(&name), &colour, format).unwrap();
            let lr = load(dir.path()).unwrap();
            let out = tempfile::tempdir().unwrap();
            let run = common::upscale_into(&lr, &config, out.path(), &SaveOptions::default());
            let written: Vec<String> = (run.unwrap().written.iter())
                .filter_map(|p| p.file_name()?.to_str().map(String::from))
                .collect();
            assert!(written.contains(&name), "{name}: wrote {written:?}");
        }
    }
}

#[test]
fn a_packing_longer_than_its_file_is_refused_with_the_files_channel_count() {
    use matup::io::write_image;
    use matup::layout::Packing;
    let dir = tempfile::tempdir().unwrap();
    let packed = dir.path().join("rock_packed.png");
    let m = sample();
    let rgb = m.base_color.clone().map_values(|v| v.clamp(0.0, 1.0));
    write_image(&packed, &rgb, FileFormat::Png8).unwrap();
    let options = |letters: &str| LoadOptions {
        paths: MaterialPaths {
            packed: Some(packed.clone()),
            packing: Some(letters.parse::<Packing>().unwrap()),
            ..Default::default()
        },
        ..Default::default()
    };
    let e = error_of(matup::load_material(None, &options("ormh")));
    assert!(e.contains("needs 4 channels, this one has 3"), "{e}");
    let orh = matup::load_material(None, &options("orh")).unwrap();
    assert!(orh.height.is_some(), "orh reads B as the height");
}

#[test]
fn quantising_rounds_so_flat_normals_stay_flat() {
    let flat = Material::uniform(8, [0.5; 3], 0.5, 0.0);
    let dir = saved(&flat, FileFormat::Png8, NormalConvention::DirectX);
    let pixels = image::open(dir.path().join("normal.png"))
        .unwrap()
        .to_rgb8();
    // (0, 0, 1) → (127.5, 127.5, 255) rounds to 128, not 127.
    assert_eq!(pixels.get_pixel(3, 3).0, [128, 128, 255]);
}

// --- bad input -------------------------------------------------------------------------

/// A folder with the sample's maps as PNG, minus `skip`.
fn folder_without(skip: &[&str]) -> tempfile::TempDir {
    let dir = tempfile::tempdir().unwrap();
    for f in [
        "baseColor.png",
        "normal.png",
        "roughness.png",
        "metallic.png",
        "height.png",
    ] {
        if !skip.contains(&f) {
            copy(&common::sample_material().join(f), dir.path(), f);
        }
    }
    dir
}

#[test]
fn missing_maps_stand_in_and_a_folder_without_maps_lists_the_names_looked_for() {
    // Any map may be missing: a flat stand-in takes its place, and the material says which.
    for (missing, kind) in [
        ("baseColor.png", MapKind::BaseColor),
        ("normal.png", MapKind::Normal),
        ("roughness.png", MapKind::Roughness),
    ] {
        let m = load(folder_without(&[missing]).path()).unwrap();
        assert_eq!(m.stand_ins(), [kind], "{missing}");
        let map = m.map(kind).unwrap();
        let value = kind.stand_in().unwrap();
        assert_eq!((map.width(), map.height()), (128, 128));
        for (c, &v) in value.iter().enumerate() {
            assert!(map.plane(c).iter().all(|&x| x == v), "{missing}");
        }
    }
    let m = load(folder_without(&["metallic.png", "height.png"]).path()).unwrap();
    assert!(m.height.is_none() && m.metallic.data().iter().all(|&v| v == 0.0));
    // Height is optional; a missing metallic stands in as no metal, and is reported.
    assert_eq!(m.stand_ins(), [MapKind::Metallic]);
    // A folder of images none of which is a map.
    let dir = tempfile::tempdir().unwrap();
    image::GrayImage::new(8, 8)
        .save(dir.path().join("preview.png"))
        .unwrap();
    let e = error_of(load(dir.path()));
    assert!(
        e.contains("no material maps found") && e.contains("albedo") && e.contains("rough"),
        "{e}"
    );
}

#[test]
fn maps_of_different_sizes_are_listed() {
    let dir = folder_without(&["roughness.png"]);
    image::GrayImage::new(64, 64)
        .save(dir.path().join("roughness.png"))
        .unwrap();
    let e = error_of(load(dir.path()));
    assert!(
        e.contains("differ in size")
            && e.contains("roughness.png is 64×64")
            && e.contains("baseColor.png is 128×128"),
        "{e}"
    );
}

#[test]
fn corrupt_and_truncated_files_are_named() {
    let dir = folder_without(&["normal.png"]);
    fs::write(
        dir.path().join("normal.png"),
        b"this is not a PNG file at all",
    )
    .unwrap();
    let e = error_of(load(dir.path()));
    assert!(
        e.contains("normal.png")
            && (e.contains("not a readable image") || e.contains("cannot decode")),
        "{e}"
    );

    let dir = folder_without(&["baseColor.png"]);
    let bytes = fs::read(common::sample_material().join("baseColor.png")).unwrap();
    fs::write(dir.path().join("baseColor.png"), &bytes[..bytes.len() / 3]).unwrap();
    let e = error_of(load(dir.path()));
    assert!(
        e.contains("baseColor.png") && e.contains("cannot decode"),
        "{e}"
    );

    let dir = folder_without(&["height.png"]);
    fs::write(dir.path().join("height.exr"), b"garbage").unwrap();
    let e = error_of(load(dir.path()));
    assert!(
        e.contains("height.exr") && e.contains("not a readable EXR"),
        "{e}"
    );
}

#[test]
fn unsupported_channel_layouts_are_refused() {
    let dir = folder_without(&["normal.png"]);
    image::GrayImage::new(128, 128)
        .save(dir.path().join("normal.png"))
        .unwrap();
    let e = error_of(load(dir.path()));
    assert!(
        e.contains("normal.png") && e.contains("1 channel") && e.contains("needs RGB"),
        "{e}"
    );
}

#[test]
fn images_over_the_size_limit_are_refused_from_the_header() {
    let options = LoadOptions {
        max_texels: 100 * 100,
        ..Default::default()
    };
    let e = error_of(load_material(Some(&common::sample_material()), &options));
    assert!(
        e.contains("128×128") && e.contains("over the limit of 10000"),
        "{e}"
    );
}

#[test]
fn non_finite_exr_values_are_refused() {
    use exr::prelude::*;
    let dir = folder_without(&["roughness.png"]);
    let mut values = vec![0.5f32; 128 * 128];
    values[130] = f32::NAN;
    let channel = AnyChannel::new("Y", FlatSamples::F32(values));
    let layer = Layer::new(
        (128, 128),
        LayerAttributes::default(),
        Encoding::UNCOMPRESSED,
        AnyChannels::sort(smallvec::smallvec![channel]),
    );
    Image::from_layer(layer)
        .write()
        .to_file(dir.path().join("roughness.exr"))
        .unwrap();
    let e = error_of(load(dir.path()));
    assert!(
        e.contains("roughness.exr") && e.contains("non-finite") && e.contains("(2, 1)"),
        "{e}"
    );
}

#[test]
fn empty_and_missing_folders_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    fs::write(dir.path().join("notes.txt"), "no images here").unwrap();
    let e = error_of(load(dir.path()));
    assert!(e.contains("no image files"), "{e}");
    let e = error_of(load(&dir.path().join("nope")));
    assert!(e.contains("nope") && e.contains("no such folder"), "{e}");
}

#[test]
fn two_files_claiming_one_map_are_named() {
    let dir = folder_without(&[]);
    copy(
        &common::sample_material().join("baseColor.png"),
        dir.path(),
        "albedo.png",
    );
    let e = error_of(load(dir.path()));
    assert!(
        e.contains("2 files claim the base colour map")
            && e.contains("albedo.png")
            && e.contains("baseColor.png"),
        "{e}"
    );
}

fn listing(dir: &Path) -> Vec<(String, u64)> {
    let mut v: Vec<_> = fs::read_dir(dir)
        .unwrap()
        .map(|e| {
            let e = e.unwrap();
            (
                e.file_name().to_string_lossy().into_owned(),
                e.metadata().unwrap().len(),
            )
        })
        .collect();
    v.sort();
    v
}

#[test]
fn never_writes_into_the_input_folder() {
    let dir = folder_without(&[]);
    let before = listing(dir.path());
    let m = load(dir.path()).unwrap();
    let e = save_material(&m, dir.path(), &SaveOptions::default())
        .unwrap_err()
        .to_string();
    assert!(e.contains("input folder"), "{e}");
    // Spelled differently, still the same folder.
    let same = dir
        .path()
        .join(".")
        .join("..")
        .join(dir.path().file_name().unwrap());
    assert!(save_material(&m, &same, &SaveOptions::default()).is_err());
    assert_eq!(listing(dir.path()), before);
}

#[test]
fn unwritable_output_is_an_error_and_writes_leave_no_temporaries() {
    let m = sample();
    let dir = tempfile::tempdir().unwrap();
    let blocker = dir.path().join("file");
    fs::write(&blocker, "x").unwrap();
    let e = save_material(&m, &blocker, &SaveOptions::default())
        .unwrap_err()
        .to_string();
    assert!(e.contains("file"), "{e}");

    let out = dir.path().join("out");
    let written = save_material(&m, &out, &SaveOptions::default()).unwrap();
    assert_eq!(written.len(), 5);
    let names: Vec<String> = listing(&out).into_iter().map(|(n, _)| n).collect();
    assert_eq!(
        names,
        [
            "baseColor.png",
            "height.png",
            "metallic.png",
            "normal.png",
            "roughness.png"
        ]
    );
}

#[test]
fn an_unread_format_a_broken_dds_a_file_as_material_and_an_output_inside_the_input_are_refused_by_name(
) {
    let dir = folder_without(&[]);
    fs::write(dir.path().join("wood_Emission.ktx2"), b"KTX 20").unwrap();
    let refused = error_of(load(dir.path()));
    assert!(
        refused.contains("wood_Emission.ktx2") && refused.contains("does not read this format"),
        "{refused}"
    );
    fs::remove_file(dir.path().join("wood_Emission.ktx2")).unwrap();
    fs::write(dir.path().join("wood_Emission.dds"), b"DDS ").unwrap();
    let refused = error_of(load(dir.path()));
    assert!(
        refused.contains("wood_Emission.dds") && refused.contains("not a readable DDS file"),
        "{refused}"
    );
    fs::remove_file(dir.path().join("wood_Emission.dds")).unwrap();

    let refused = error_of(load(&dir.path().join("baseColor.png")));
    assert!(refused.contains("is a file"), "{refused}");

    let m = load(dir.path()).unwrap();
    let inside = dir.path().join("sub/out");
    let refused = save_material(&m, &inside, &SaveOptions::default())
        .unwrap_err()
        .to_string();
    assert!(refused.contains("inside the input folder"), "{refused}");
    assert!(
        !dir.path().join("sub").exists(),
        "nothing written into the input"
    );
}

#[test]
fn a_packed_file_given_by_a_relative_path_is_read_as_its_packing_says() {
    // A relative path from the working folder, as a user types it, to a folder that also
    // holds the file under a name matup recognises: it is read once, as --packing says.
    let dir = tempfile::tempdir_in(env!("CARGO_TARGET_TMPDIR")).unwrap();
    let m = sample();
    let rough = m.roughness.data();
    let metal = m.metallic.data();
    let (w, h) = (m.width() as u32, m.height_px() as u32);
    let packed = image::RgbImage::from_fn(w, h, |x, y| {
        let i = (y * w + x) as usize;
        let q = |v: f32| (v * 255.0).round() as u8;
        // R roughness, G metallic, B nothing: "rmx".
        image::Rgb([q(rough[i]), q(metal[i]), 77])
    });
    packed.save(dir.path().join("wood_rma.png")).unwrap();
    copy(
        &common::sample_material().join("baseColor.png"),
        dir.path(),
        "wood_color.png",
    );
    let cwd = std::env::current_dir().unwrap();
    let relative = dir
        .path()
        .strip_prefix(&cwd)
        .map(Path::to_path_buf)
        .unwrap_or_else(|_| {
            // The target folder lies outside the working folder: go up to the root and down.
            let ups: PathBuf = cwd.components().skip(1).map(|_| "..").collect();
            ups.join(dir.path().strip_prefix("/").unwrap())
        });
    assert!(relative.is_relative());
    let loaded = load_material(
        Some(&relative),
        &LoadOptions {
            paths: MaterialPaths {
                packed: Some(relative.join("wood_rma.png")),
                packing: Some("rmx".parse().unwrap()),
                ..Default::default()
            },
            ..Default::default()
        },
    )
    .unwrap();
    let origin = loaded.origin.as_ref().unwrap();
    assert_eq!(origin.layout.len(), 2, "{:?}", origin.sources());
    let worst_rough = common::max_abs_diff(&loaded.roughness, &m.roughness);
    let worst_metal = common::max_abs_diff(&loaded.metallic, &m.metallic);
    assert!(worst_rough <= 0.5 / 255.0 + 1e-6 && worst_metal <= 0.5 / 255.0 + 1e-6);
    // Saved, it is one packed file again, its unused B kept.
    let out = tempfile::tempdir().unwrap();
    save_material(&loaded, out.path(), &SaveOptions::default()).unwrap();
    let back = image::open(out.path().join("wood_rma.png"))
        .unwrap()
        .to_rgb8();
    assert_eq!(back.get_pixel(3, 5)[2], 77);
    assert_eq!(back.get_pixel(3, 5)[0], packed.get_pixel(3, 5)[0]);
}

/// `map`'s first channel as an 8-bit grey PNG at `path`.
fn save_grey(map: &Map, path: &Path) {
    let levels: Vec<u8> = (map.plane(0).iter())
        .map(|v| (v.clamp(0.0, 1.0) * 255.0).round() as u8)
        .collect();
    image::GrayImage::from_raw(map.width() as u32, map.height() as u32, levels)
        .unwrap()
        .save(path)
        .unwrap();
}

/// The 8-bit grey PNG at `path` as values in [0, 1], and its size.
fn grey_values(path: &Path) -> (Vec<f32>, [usize; 2]) {
    let image = image::open(path).unwrap().into_luma8();
    let size = [image.width() as usize, image.height() as usize];
    let values = image.into_raw().into_iter().map(|v| v as f32 / 255.0);
    (values.collect(), size)
}

/// How far, in levels, the grey PNG `input` lies at worst from `output` box-filtered
/// ÷`factor`.
fn box_back_worst(input: &Path, output: &Path, factor: usize) -> f32 {
    let ((input, _), (output, [width, _])) = (grey_values(input), grey_values(output));
    let levels = common::box_back_levels(&input, &output, width, factor, false);
    levels.into_iter().fold(0.0, f32::max)
}

#[test]
fn images_of_another_size_come_back_upscaled_apart_by_the_same_factor() {
    use matup::config::{Config, TargetSize};
    // A real material's 256² maps, with an occlusion map at half their size and a mask at a
    // quarter beside them (made from its height), as packs that bake these smaller ship them.
    let source = common::test_material("ambientcg_Leather025");
    let dir = tempfile::tempdir().unwrap();
    for f in ["baseColor.png", "normal.png", "roughness.png", "height.png"] {
        copy(&source.join(f), dir.path(), f);
    }
    let height = load(&source).unwrap().height.unwrap();
    let occlusion = matup::resample::box_downsample(&height, 2);
    save_grey(&occlusion, &dir.path().join("ambientOcclusion.png"));
    save_grey(
        &matup::resample::box_downsample(&height, 4),
        &dir.path().join("mask.png"),
    );
    let material = load(dir.path()).unwrap();
    assert_eq!((material.width(), material.carried.extras.len()), (256, 0));

    let out = tempfile::tempdir().unwrap();
    let config = Config {
        scale: 2,
        ..Config::default()
    };
    let run = common::upscale_into(&material, &config, out.path(), &SaveOptions::default());
    let report = run.unwrap().report;
    // Every file back, each ×2 and consistent with its input.
    for (name, size) in [
        ("baseColor.png", 512),
        ("ambientOcclusion.png", 256),
        ("mask.png", 128),
    ] {
        let (input, output) = (dir.path().join(name), out.path().join(name));
        assert_eq!(grey_values(&output).1, [size, size], "{name}");
        if name != "baseColor.png" {
            let worst = box_back_worst(&input, &output, 2);
            assert!(worst <= 2.0, "{name}: {worst} levels from its input");
        }
    }
    let sizes: Vec<([usize; 2], [usize; 2], &str)> = (report.other_sizes.iter())
        .map(|r| (r.input_size, r.output_size, r.files[0].as_str()))
        .collect();
    assert_eq!(
        sizes,
        [
            ([64, 64], [128, 128], "mask.png"),
            ([128, 128], [256, 256], "ambientOcclusion.png")
        ]
    );

    // A size asked for holds for the maps; the others keep the ratio (256² → 640², ×2.5).
    let out = tempfile::tempdir().unwrap();
    let config = Config {
        size: Some(TargetSize {
            width: 640,
            height: None,
        }),
        upsampler: "bicubic".into(),
        ..Config::default()
    };
    common::upscale_into(&material, &config, out.path(), &SaveOptions::default()).unwrap();
    for (name, side) in [
        ("height.png", 640),
        ("ambientOcclusion.png", 320),
        ("mask.png", 160),
    ] {
        let (_, size) = grey_values(&out.path().join(name));
        assert_eq!(size, [side, side], "{name}");
    }
}

#[test]
fn a_folder_of_textures_of_many_sizes_comes_back_whole() {
    // Textures as a game's dump names them, none a map matup knows, in three sizes: the first
    // image's size is a material of carried images, each other size one of its own.
    let height = load(&common::test_material("ambientcg_Rock029"))
        .unwrap()
        .height
        .unwrap();
    let dir = tempfile::tempdir().unwrap();
    let files = [
        ("tex1_128x128_5f3a.png", 1),
        ("tex1_64x64_9c1e.png", 2),
        ("tex1_64x64_a07b.png", 2),
        ("tex1_32x32_e4d2.png", 4),
    ];
    for (name, factor) in files {
        let map = matup::resample::box_downsample(&height, 2 * factor);
        save_grey(&map, &dir.path().join(name));
    }
    let material = load(dir.path()).unwrap();
    assert_eq!(material.width(), 128);
    let out = tempfile::tempdir().unwrap();
    let config = matup::config::Config {
        upsampler: "bicubic".into(),
        ..Default::default()
    };
    let run = common::upscale_into(&material, &config, out.path(), &SaveOptions::default());
    assert_eq!(run.unwrap().report.other_sizes.len(), 2);
    for (name, _) in files {
        let (input, output) = (dir.path().join(name), out.path().join(name));
        assert_eq!(
            grey_values(&output).1,
            grey_values(&input).1.map(|s| 4 * s),
            "{name}"
        );
        let worst = box_back_worst(&input, &output, 4);
        assert!(worst <= 2.0, "{name}: {worst} levels from its input");
    }

    // Two sizes whose files one format would give one name: refused by that name, the
    // first one's file kept.
    let dir = tempfile::tempdir().unwrap();
    for name in ["stone_mask.png", "stone_grime.png"] {
        save_grey(
            &matup::resample::box_downsample(&height, 4),
            &dir.path().join(name),
        );
    }
    let small = matup::resample::box_downsample(&height, 8);
    let levels = small
        .plane(0)
        .iter()
        .map(|v| (v * 255.0).round() as u8)
        .collect();
    image::GrayImage::from_raw(32, 32, levels)
        .unwrap()
        .save(dir.path().join("stone_mask.tga"))
        .unwrap();
    let out = tempfile::tempdir().unwrap();
    let save = SaveOptions {
        format: Some(FileFormat::Png8),
        ..SaveOptions::default()
    };
    let material = load(dir.path()).unwrap();
    let e = common::upscale_into(&material, &config, out.path(), &save)
        .err()
        .unwrap();
    let e = e.to_string();
    assert!(
        e.contains("stone_mask.png") && e.contains("two of the input's files"),
        "{e}"
    );
    assert_eq!(
        grey_values(&out.path().join("stone_mask.png")).1,
        [256, 256]
    );
}

#[test]
fn pictures_of_the_material_are_passed_over_by_name_and_the_run_names_them() {
    let dir = folder_without(&[]);
    image::RgbImage::new(64, 64)
        .save(dir.path().join("preview.png"))
        .unwrap();
    let origin = load(dir.path()).unwrap().origin.unwrap();
    assert!(
        (origin.notes.iter())
            .any(|n| n.starts_with("preview.png: taken by its name for a picture")),
        "{:?}",
        origin.notes
    );
    assert!((origin.layout.iter()).all(|f| !f.path.ends_with("preview.png")));
}

/// The images of `folder` as a caller holding them in memory gives them: file names and the
/// samples matup's reader decodes.
fn images_of(folder: &Path) -> Vec<(String, matup::io::ImageFile)> {
    let mut paths: Vec<PathBuf> = (fs::read_dir(folder).unwrap())
        .map(|e| e.unwrap().path())
        .filter(|p| matup::io::is_image_file(p))
        .collect();
    paths.sort();
    (paths.iter())
        .map(|p| {
            let name = p.file_name().unwrap().to_string_lossy().into_owned();
            (name, matup::io::read_image(p, u64::MAX).unwrap())
        })
        .collect()
}

#[test]
fn images_in_memory_upscale_to_the_samples_a_folder_run_writes() {
    // The sample with its base colour stored as a JPEG, as a web texture would be.
    let dir = tempfile::tempdir().unwrap();
    for entry in fs::read_dir(common::sample_material()).unwrap() {
        let path = entry.unwrap().path();
        fs::copy(&path, dir.path().join(path.file_name().unwrap())).unwrap();
    }
    let colour = dir.path().join("baseColor.png");
    image::open(&colour)
        .unwrap()
        .to_rgb8()
        .save(dir.path().join("baseColor.jpg"))
        .unwrap();
    fs::remove_file(&colour).unwrap();

    let config = matup::config::Config {
        upsampler: "lanczos3".into(),
        ..Default::default()
    };
    let save = SaveOptions::default();
    let out = tempfile::tempdir().unwrap();
    let from_disk = load(dir.path()).unwrap();
    common::upscale_into(&from_disk, &config, out.path(), &save).unwrap();

    let arrays = Path::new("arrays");
    let images = images_of(dir.path());
    let in_memory = matup::load_material_from_images(arrays, images, &LoadOptions::default());
    let in_memory = in_memory.unwrap();
    assert_eq!(in_memory.lossy, from_disk.lossy);
    assert!(in_memory.lossy.contains_key(&MapKind::BaseColor));
    let run = matup::folder::upscale_in_memory(&in_memory, &config, &save, None, &Silent);
    let run = run.unwrap();

    let names: Vec<&str> = run.images.iter().map(|i| i.name.as_str()).collect();
    let mut written: Vec<String> = (fs::read_dir(out.path()).unwrap())
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n != "preview.png" && n != "run.json")
        .collect();
    written.sort();
    let mut sorted = names.clone();
    sorted.sort();
    assert_eq!(sorted, written);
    for image in &run.images {
        assert_eq!([image.width, image.height], [512, 512], "{}", image.name);
        let file = matup::io::read_image(&out.path().join(&image.name), u64::MAX).unwrap();
        assert_eq!(image.format, file.format, "{}", image.name);
        let matup::io::Samples::U8(samples) = &image.samples else {
            panic!("{}: 8-bit samples expected", image.name)
        };
        // The file's samples texel by texel, as 8-bit levels.
        let map = &file.map;
        let stored: Vec<u8> = (0..map.texels() * map.channels())
            .map(|i| (map.plane(i % map.channels())[i / map.channels()] * 255.0).round() as u8)
            .collect();
        if image.format == FileFormat::Jpeg {
            // The samples before JPEG's lossy encoding, which the file holds after it.
            let mean = (samples.iter().zip(&stored))
                .map(|(&a, &b)| (a as f64 - b as f64).abs())
                .sum::<f64>()
                / samples.len() as f64;
            assert!(mean > 0.0 && mean < 3.0, "{}: {mean} levels", image.name);
        } else {
            assert!(samples == &stored, "{}", image.name);
        }
    }
}

#[test]
fn images_in_memory_are_refused_by_name_when_they_cannot_be_a_folder() {
    let arrays = Path::new("arrays");
    let mut images = images_of(&common::sample_material());
    let refused =
        |images: Vec<(String, matup::io::ImageFile)>| match matup::load_material_from_images(
            arrays,
            images,
            &LoadOptions::default(),
        ) {
            Ok(_) => panic!("refused"),
            Err(e) => e.to_string(),
        };
    let mut unnamed = images_of(&common::sample_material());
    unnamed[0].0 = "baseColor".into();
    let e = refused(unnamed);
    assert!(
        e.contains("baseColor") && e.contains("not an image file's name"),
        "{e}"
    );
    let small = Map::from_fn(64, 64, 1, |_, _, _| 0.5);
    images.push((
        "ambient_occlusion.png".into(),
        matup::io::ImageFile {
            map: small,
            format: FileFormat::Png8,
            notes: Vec::new(),
        },
    ));
    let e = refused(images);
    assert!(
        e.contains("ambient_occlusion.png") && e.contains("another size"),
        "{e}"
    );
}
