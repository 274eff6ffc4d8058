//! Nothing left behind: every map of a material folder comes back upscaled (alpha channels,
//! occlusion, opacity, emission), and materials with only some of the maps upscale.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use matup_core::io::{load_material, save_material, ImageWriter, SaveOptions};
use matup_core::material::{FileFormat, MapKind, Material};
use matup_core::resample::box_downsample;
use matup_core::Map;

fn matup(args: &[&str]) -> Output {
    let o = Command::new(env!("CARGO_BIN_EXE_matup"))
        .args(args)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    o
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// 64² of a real material the repository ships (leather: every map but metallic varies),
/// saved as PNG into `folder`.
fn leather(folder: &Path) -> Material {
    let source = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../tests/data/materials/ambientcg_Leather025");
    let mut m = load_material(Some(&source), &Default::default())
        .unwrap()
        .crop(40, 72, 64, 64);
    m.origin = None;
    save_material(&m, folder, &SaveOptions::default()).unwrap();
    m
}

fn write(path: &Path, map: &Map, format: FileFormat) {
    let mut w =
        ImageWriter::create(path, map.width(), map.height(), map.channels(), format).unwrap();
    w.write_rows(map).unwrap();
    w.finish().unwrap();
}

/// The mean and largest |difference| between `hr` box-filtered ×4 and `lr`.
fn shrink_error(hr: &Map, lr: &Map) -> (f32, f32) {
    let seen = box_downsample(hr, 4);
    let d: Vec<f32> = (seen.data().iter().zip(lr.data()))
        .map(|(a, b)| (a - b).abs())
        .collect();
    (
        d.iter().sum::<f32>() / d.len() as f32,
        d.iter().copied().fold(0.0, f32::max),
    )
}

/// The names of the files in `folder` that `keep` keeps, sorted.
fn files(folder: &Path, keep: impl Fn(&str) -> bool) -> Vec<String> {
    let mut names: Vec<String> = std::fs::read_dir(folder)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| keep(n))
        .collect();
    names.sort();
    names
}

/// The maps matup wrote into `folder` as PNG (its preview aside).
fn png_maps(folder: &Path) -> Vec<String> {
    files(folder, |n| n.ends_with(".png") && n != "preview.png")
}

/// A disc of alpha 1 on 0 (a cutout), 64².
fn disc() -> Map {
    Map::from_fn(64, 64, 1, |_, y, x| {
        let (dx, dy) = (x as f32 - 30.5, y as f32 - 33.5);
        ((dx * dx + dy * dy).sqrt() < 21.0) as u8 as f32
    })
}

#[test]
fn an_rgba_cutout_keeps_binary_alpha_aligned_with_its_colour() {
    let dir = tempfile::tempdir().unwrap();
    let input = dir.path().join("in");
    let m = leather(&input);
    let alpha = disc();
    let colour = m
        .base_color
        .clone()
        .map_values(matup_core::color::linear_to_srgb);
    write(
        &input.join("baseColor.png"),
        &Map::stack(&[&colour, &alpha]),
        FileFormat::Png8,
    );
    let out = dir.path().join("out");
    matup(&[
        "upscale",
        input.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
    ]);

    let up = load_material(Some(&out), &Default::default()).unwrap();
    let a = &up.carried.alpha[&MapKind::BaseColor];
    assert_eq!((a.width(), a.height()), (256, 256));
    assert!(
        a.data().iter().all(|&v| v == 0.0 || v == 1.0),
        "alpha is 0 or 1"
    );
    // Aligned: the cutout's edge where the input's is, inside and outside whole.
    let (mean, _) = shrink_error(a, &alpha);
    println!("alpha: box-shrink differs from the input by {mean:.4} on average");
    assert!(mean < 0.03, "{mean}");
    for y in 1..63 {
        for x in 1..63 {
            let around: Vec<f32> = (0..9)
                .map(|k| alpha.get(0, y + k / 3 - 1, x + k % 3 - 1))
                .collect();
            if around.iter().all(|&v| v == around[0]) {
                for (dy, dx) in (0..16).map(|k| (k / 4, k % 4)) {
                    assert_eq!(a.get(0, 4 * y + dy, 4 * x + dx), around[0], "({x}, {y})");
                }
            }
        }
    }
    // The colour under it is the material's, upscaled and back-projected.
    let (mean, _) = shrink_error(&up.base_color, &m.base_color);
    assert!(mean < 0.01, "{mean}");
}

#[test]
fn every_map_of_the_folder_comes_back_at_four_times_aligned() {
    let dir = tempfile::tempdir().unwrap();
    let input = dir.path().join("Leather_1K");
    let m = leather(&input);
    // Occlusion (8-bit grey), opacity (16-bit grey, soft), emission (RGB JPEG), as a raw
    // download names them; a preview and a text file that are no maps.
    let ao = m
        .height
        .as_ref()
        .unwrap()
        .clone()
        .map_values(|h| 0.3 + 0.7 * h);
    let opacity = Map::from_fn(64, 64, 1, |_, y, x| (0.2 + 0.012 * (x + y) as f32).min(1.0));
    let emission = Map::from_fn(64, 64, 3, |c, y, x| {
        [0.9, 0.4, 0.1][c] * ((x / 8 + y / 8) % 2) as f32
    });
    write(
        &input.join("Leather_1K_AmbientOcclusion.png"),
        &ao,
        FileFormat::Png8,
    );
    write(
        &input.join("Leather_1K_Opacity.png"),
        &opacity,
        FileFormat::Png16,
    );
    write(
        &input.join("Leather_1K_Emission.jpg"),
        &emission,
        FileFormat::Jpeg,
    );
    write(
        &input.join("Leather_1K_preview.png"),
        &emission,
        FileFormat::Png8,
    );
    std::fs::write(input.join("notes.txt"), "not a map").unwrap();
    let out = dir.path().join("out");
    matup(&[
        "upscale",
        input.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
    ]);

    let run: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("run.json")).unwrap()).unwrap();
    let listed = run["carried"].to_string();
    assert_eq!(
        files(&out, |_| true),
        [
            // The resolution tag is no 1K's (64²): names as they were.
            "Leather_1K_AmbientOcclusion.png",
            "Leather_1K_Emission.jpg",
            "Leather_1K_Opacity.png",
            "baseColor.png",
            "height.png",
            "normal.png",
            "preview.png",
            "roughness.png",
            "run.json",
        ]
    );
    let up = load_material(Some(&out), &Default::default()).unwrap();
    let inputs = load_material(Some(&input), &Default::default()).unwrap();
    assert_eq!(up.carried.extras.len(), 3);
    for (e, lr) in up.carried.extras.iter().zip(&inputs.carried.extras) {
        assert_eq!(e.name, lr.name);
        assert!(
            listed.contains(&e.name),
            "run.json lists {}: {listed}",
            e.name
        );
        assert_eq!((e.map.width(), e.map.height()), (256, 256));
        assert_eq!(e.map.channels(), lr.map.channels(), "{}", e.name);
        assert_eq!(e.format, lr.format, "{}: format and depth kept", e.name);
        let (mean, max) = shrink_error(&e.map, &lr.map);
        println!(
            "{}: box-shrink off by {mean:.4} on average, {max:.4} at most",
            e.name
        );
        assert!(mean < 0.004 && max < 0.05, "{}: {mean} {max}", e.name);
    }
}

#[test]
fn materials_with_some_maps_upscale_with_what_they_have() {
    let dir = tempfile::tempdir().unwrap();
    let full = dir.path().join("full");
    leather(&full);
    for (name, maps) in [
        ("colour", &["baseColor.png"][..]),
        ("colour_normal", &["baseColor.png", "normal.png"][..]),
    ] {
        let input = dir.path().join(name);
        std::fs::create_dir_all(&input).unwrap();
        for map in maps {
            std::fs::copy(full.join(map), input.join(map)).unwrap();
        }
        let out = dir.path().join(format!("{name}_out"));
        let o = matup(&[
            "upscale",
            input.to_str().unwrap(),
            "-o",
            out.to_str().unwrap(),
        ]);
        assert!(
            stderr(&o)
                .contains("no roughness map: roughness 0.5 stands in for it; none is written"),
            "{}",
            stderr(&o)
        );
        assert_eq!(
            png_maps(&out),
            maps,
            "{name}: the maps it has, no stand-ins"
        );
        let lr = load_material(Some(&input), &Default::default()).unwrap();
        let up = load_material(Some(&out), &Default::default()).unwrap();
        assert_eq!(up.width(), 256);
        let (mean, _) = shrink_error(&up.base_color, &lr.base_color);
        assert!(mean < 0.01, "{name}: {mean}");
    }

    // The paper's fit renders the material: it says what stood in.
    let out = dir.path().join("paper_out");
    let config = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../configs/paper.toml");
    let o = matup(&[
        "upscale",
        dir.path().join("colour").to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
        "--config",
        config.to_str().unwrap(),
        "--upsampler",
        "bicubic",
        "--lights",
        "4",
        "--epochs",
        "1",
    ]);
    let text = stderr(&o);
    for kind in ["normal", "roughness"] {
        assert!(
            text.contains(&format!("no {kind} map:"))
                && text.contains("in the renders this run fits to"),
            "{text}"
        );
    }
}

#[test]
fn a_raw_ambientcg_download_comes_back_complete_under_its_own_names() {
    let dir = tempfile::tempdir().unwrap();
    let canonical = dir.path().join("canonical");
    let m = leather(&canonical);
    // As ambientCG ships it: JPEGs named MATERIAL_SIZE-JPG_MAP, the normal map in OpenGL's
    // convention and DirectX's, occlusion beside, a preview named after the material and a
    // MaterialX file.
    let raw = dir.path().join("Leather025_1K-JPG");
    std::fs::create_dir_all(&raw).unwrap();
    let stem = |map: &str| raw.join(format!("Leather025_1K-JPG_{map}.jpg"));
    let mut normal_gl =
        matup_core::io::encode_normals(&m.normal, matup_core::NormalConvention::OpenGl);
    normal_gl
        .data_mut()
        .iter_mut()
        .for_each(|v| *v = v.clamp(0.0, 1.0));
    let colour = m
        .base_color
        .clone()
        .map_values(matup_core::color::linear_to_srgb);
    let height = m.height.clone().unwrap();
    write(&stem("Color"), &colour, FileFormat::Jpeg);
    write(&stem("NormalGL"), &normal_gl, FileFormat::Jpeg);
    let mut normal_dx =
        matup_core::io::encode_normals(&m.normal, matup_core::NormalConvention::DirectX);
    normal_dx
        .data_mut()
        .iter_mut()
        .for_each(|v| *v = v.clamp(0.0, 1.0));
    write(&stem("NormalDX"), &normal_dx, FileFormat::Jpeg);
    write(&stem("Roughness"), &m.roughness, FileFormat::Jpeg);
    write(&stem("Displacement"), &height, FileFormat::Jpeg);
    write(
        &stem("AmbientOcclusion"),
        &height.clone().map_values(|h| 0.4 + 0.6 * h),
        FileFormat::Jpeg,
    );
    write(&raw.join("Leather025.png"), &colour, FileFormat::Png8);
    std::fs::write(raw.join("Leather025_1K-JPG.mtlx"), "<materialx/>").unwrap();

    let listing = |folder: &Path| files(folder, |n| n.ends_with(".jpg"));
    let out = dir.path().join("out");
    matup(&[
        "upscale",
        raw.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
    ]);
    assert_eq!(
        listing(&out),
        listing(&raw),
        "every map, under its own name"
    );
    let up = load_material(Some(&out), &Default::default()).unwrap();
    assert_eq!((up.width(), up.carried.extras.len()), (256, 1));
    // Both normal maps: one upscaled normal map, in each file's own convention.
    let green = |file: &str| -> Vec<i32> {
        let image = image::open(out.join(file)).unwrap().to_rgb8();
        image.pixels().map(|p| p[1] as i32).collect()
    };
    let (gl, dx) = (
        green("Leather025_1K-JPG_NormalGL.jpg"),
        green("Leather025_1K-JPG_NormalDX.jpg"),
    );
    let flipped = gl
        .iter()
        .zip(&dx)
        .filter(|(g, d)| (*g + *d - 255).abs() > 6)
        .count();
    assert!(
        flipped < gl.len() / 100,
        "{flipped} texels' green is not flipped"
    );

    // matup's names on request; occlusion keeps its own.
    let out = dir.path().join("out_matup");
    matup(&[
        "upscale",
        raw.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
        "--names",
        "matup",
    ]);
    // Matup's names write one normal map, in the convention read (DirectX, preferred).
    assert_eq!(
        listing(&out),
        [
            "Leather025_1K-JPG_AmbientOcclusion.jpg",
            "baseColor.jpg",
            "height.jpg",
            "normal.jpg",
            "roughness.jpg"
        ]
    );
}

#[test]
fn a_packed_file_comes_back_packed_with_its_occlusion() {
    let dir = tempfile::tempdir().unwrap();
    let canonical = dir.path().join("canonical");
    let m = leather(&canonical);
    let input = dir.path().join("crate");
    std::fs::create_dir_all(&input).unwrap();
    std::fs::copy(
        canonical.join("baseColor.png"),
        input.join("crate_albedo.png"),
    )
    .unwrap();
    std::fs::copy(canonical.join("normal.png"), input.join("crate_normal.png")).unwrap();
    let occlusion = m.height.clone().unwrap().map_values(|h| 0.5 + 0.5 * h);
    let metallic = Map::from_fn(64, 64, 1, |_, y, x| ((x / 16 + y / 16) % 2) as f32);
    write(
        &input.join("crate_orm.png"),
        &Map::stack(&[&occlusion, &m.roughness, &metallic]),
        FileFormat::Png8,
    );
    let out = dir.path().join("out");
    matup(&[
        "upscale",
        input.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
    ]);
    assert_eq!(
        files(&out, |_| true),
        [
            "crate_albedo.png",
            "crate_normal.png",
            "crate_orm.png",
            "preview.png",
            "run.json"
        ]
    );
    // The packed file holds what the same run writes unpacked under matup's names.
    let unpacked = dir.path().join("unpacked");
    matup(&[
        "upscale",
        input.to_str().unwrap(),
        "-o",
        unpacked.to_str().unwrap(),
        "--names",
        "matup",
    ]);
    let packed = load_material(Some(&out), &Default::default()).unwrap();
    let apart = load_material(Some(&unpacked), &Default::default()).unwrap();
    assert!(packed.roughness == apart.roughness && packed.metallic == apart.metallic);
    assert_eq!(apart.carried.extras[0].name, "occlusion");
    assert!(packed.carried.extras[0].map == apart.carried.extras[0].map);
    // And that is the input's maps upscaled, occlusion back-projected as the others.
    let lr = load_material(Some(&input), &Default::default()).unwrap();
    let (mean, _) = shrink_error(&packed.carried.extras[0].map, &lr.carried.extras[0].map);
    assert!(mean < 0.004, "occlusion {mean}");
}

#[test]
fn a_batch_upscales_partial_materials_with_what_each_has() {
    let dir = tempfile::tempdir().unwrap();
    let library = dir.path().join("library");
    let full = library.join("leather");
    leather(&full);
    let colour = library.join("decal");
    std::fs::create_dir_all(&colour).unwrap();
    std::fs::copy(full.join("baseColor.png"), colour.join("decal_albedo.png")).unwrap();
    let out = dir.path().join("out");
    matup(&[
        "batch",
        library.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
        "--quiet",
    ]);
    assert_eq!(png_maps(&out.join("decal")), ["decal_albedo.png"]);
    assert_eq!(png_maps(&out.join("leather")), png_maps(&full));
    let run: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("decal/run.json")).unwrap())
            .unwrap();
    assert!(
        run["stand_ins"].to_string().contains("no roughness map"),
        "{run}"
    );
}
