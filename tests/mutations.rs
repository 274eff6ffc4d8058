//! Bad input, as users meet it: 2,400 damaged map files (truncated, bytes flipped, header fields
//! changed, junk appended) in every format matup reads, and in the packed layouts of glTF,
//! Unreal and Unity, go through the material loader and `matup upscale`'s folder-to-folder run. Each either loads and upscales, or is refused with
//! an error that names the file; nothing panics, and the input folder is never touched.
//! `.ci/run` runs this test with its output shown, so CI prints the counts.

mod common;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use matup::config::Config;
use matup::io::Names;
use matup::material::{DdsFormat, FileFormat};
use matup::progress::Silent;
use matup::{load_material, save_material, LoadOptions, SaveOptions};
use rand::{Rng, SeedableRng};

const FORMATS: [FileFormat; 9] = [
    FileFormat::Png8,
    FileFormat::Jpeg,
    FileFormat::WebpLossy,
    FileFormat::ExrHalf,
    FileFormat::Tiff16,
    FileFormat::Tga,
    // Run-length packets are where a damaged TGA's lengths lie.
    FileFormat::TgaRle,
    FileFormat::Bmp,
    // `--format dds`: BC7 colour, BC5 normals, BC4 grey, with mip chains.
    FileFormat::Dds(DdsFormat {
        codec: None,
        srgb: None,
        dx10: true,
        mipmaps: true,
    }),
];

/// How a file is damaged.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
enum Damage {
    /// Cut short at a random length.
    Truncated,
    /// One to eight bytes anywhere set to random values.
    BytesFlipped,
    /// One to four bytes of the first 64 (where every format keeps its header: sizes, bit
    /// depths, channel counts, offsets) set to random values.
    HeaderChanged,
    /// 1 to 4096 random bytes added at the end.
    JunkAppended,
}

const DAMAGES: [Damage; 4] = [
    Damage::Truncated,
    Damage::BytesFlipped,
    Damage::HeaderChanged,
    Damage::JunkAppended,
];

fn damaged(bytes: &[u8], damage: Damage, rng: &mut impl Rng) -> Vec<u8> {
    let mut out = bytes.to_vec();
    match damage {
        Damage::Truncated => out.truncate(rng.random_range(0..bytes.len())),
        Damage::BytesFlipped => {
            for _ in 0..rng.random_range(1..=8) {
                let i = rng.random_range(0..out.len());
                out[i] = rng.random();
            }
        }
        Damage::HeaderChanged => {
            for _ in 0..rng.random_range(1..=4) {
                let i = rng.random_range(0..out.len().min(64));
                out[i] = rng.random();
            }
        }
        Damage::JunkAppended => {
            let n = rng.random_range(1..=4096);
            out.extend((0..n).map(|_| rng.random::<u8>()));
        }
    }
    out
}

/// Every file of a folder and its bytes.
/// A GLB model (no geometry) whose embedded images are `folder`'s base colour, normal and
/// roughness (as occlusion) PNG files.
fn glb_of(folder: &Path, scratch: &Path) -> Vec<u8> {
    let mut bin = Vec::new();
    let mut views = Vec::new();
    for name in ["baseColor.png", "normal.png", "roughness.png"] {
        let bytes = std::fs::read(folder.join(name)).unwrap();
        views.push(
            serde_json::json!({"buffer": 0, "byteOffset": bin.len(), "byteLength": bytes.len()}),
        );
        bin.extend_from_slice(&bytes);
        bin.resize(bin.len().div_ceil(4) * 4, 0);
    }
    let json = serde_json::json!({
        "asset": {"version": "2.0"},
        "bufferViews": views,
        "buffers": [{"byteLength": bin.len()}],
        "images": (0..3).map(|i| serde_json::json!({"bufferView": i, "mimeType": "image/png"})).collect::<Vec<_>>(),
        "textures": (0..3).map(|i| serde_json::json!({"source": i})).collect::<Vec<_>>(),
        "materials": [{"pbrMetallicRoughness": {"baseColorTexture": {"index": 0}},
                       "normalTexture": {"index": 1}, "occlusionTexture": {"index": 2}}]
    });
    let bytes = common::glb_bytes(&json, bin);
    // It upscales undamaged.
    let model = scratch.join("template.glb");
    std::fs::write(&model, &bytes).unwrap();
    matup::apps::model::upscale_model(
        &model,
        &Config {
            upsampler: "bilinear".into(),
            ..Config::default()
        },
        &scratch.join("template-glb-out"),
        &SaveOptions::default(),
        &LoadOptions::default(),
        None,
        &Silent,
    )
    .unwrap();
    bytes
}

fn snapshot(folder: &Path) -> BTreeMap<PathBuf, Vec<u8>> {
    std::fs::read_dir(folder)
        .unwrap()
        .map(|e| {
            let path = e.unwrap().path();
            let bytes = std::fs::read(&path).unwrap();
            (path, bytes)
        })
        .collect()
}

/// One exporter's packed layout: its packed file, how a texel of it is made of roughness and
/// metallic, and its base colour and normal files' names.
struct PackedLayout {
    name: &'static str,
    packed: &'static str,
    texel: fn(u8, u8) -> [u8; 4],
    /// 3 (RGB) or 4 (RGBA): the packed file's channels, and the base colour's.
    channels: usize,
    base_color: &'static str,
    normal: &'static str,
}

/// glTF's metallicRoughness (G roughness, B metallic), Unreal's OcclusionRoughnessMetallic,
/// Unity HDRP's RGBA base map and mask map (R metallic, G occlusion, B detail mask, A
/// smoothness).
const PACKED_LAYOUTS: [PackedLayout; 3] = [
    PackedLayout {
        name: "glTF",
        packed: "Mat_metallicRoughness.png",
        texel: |r, m| [255, r, m, 0],
        channels: 3,
        base_color: "Mat_baseColor.png",
        normal: "Mat_Normal.png",
    },
    PackedLayout {
        name: "Unreal",
        packed: "T_Mat_OcclusionRoughnessMetallic.png",
        texel: |r, m| [255, r, m, 0],
        channels: 3,
        base_color: "T_Mat_BaseColor.png",
        normal: "T_Mat_Normal.png",
    },
    PackedLayout {
        name: "Unity",
        packed: "Mat_MaskMap.png",
        texel: |r, m| [m, 255, 255, 255 - r],
        channels: 4,
        base_color: "Mat_BaseMap.png",
        normal: "Mat_Normal.png",
    },
];

/// Each of [`PACKED_LAYOUTS`], made of the maps of `matup` (a folder in matup's own PNG
/// layout), in a folder of its own in `dir`.
fn packed_layouts(matup: &Path, dir: &Path) -> Vec<(&'static str, PathBuf)> {
    let open = |name: &str| image::open(matup.join(name)).unwrap();
    let (rough, metal) = (
        open("roughness.png").to_luma8(),
        open("metallic.png").to_luma8(),
    );
    let base = open("baseColor.png");
    let (w, h) = rough.dimensions();
    PACKED_LAYOUTS
        .iter()
        .map(|layout| {
            let folder = dir.join(format!("template-{}", layout.name));
            std::fs::create_dir_all(&folder).unwrap();
            let data: Vec<u8> = (rough.pixels().zip(metal.pixels()))
                .flat_map(|(r, m)| (layout.texel)(r.0[0], m.0[0])[..layout.channels].to_vec())
                .collect();
            let (packed, base): (image::DynamicImage, image::DynamicImage) = match layout.channels {
                3 => (
                    image::RgbImage::from_raw(w, h, data).unwrap().into(),
                    base.clone(),
                ),
                _ => (
                    image::RgbaImage::from_raw(w, h, data).unwrap().into(),
                    base.to_rgba8().into(),
                ),
            };
            packed.save(folder.join(layout.packed)).unwrap();
            base.save(folder.join(layout.base_color)).unwrap();
            std::fs::copy(matup.join("normal.png"), folder.join(layout.normal)).unwrap();
            (layout.name, folder)
        })
        .collect()
}

/// What happened to one damaged file.
enum Outcome {
    Upscaled,
    Refused,
}

/// What a run on damaged input did: upscaled, with every one of `outputs` written, or refused
/// with a message naming `name`; `None` if it panicked.
fn judge<T>(
    run: std::thread::Result<matup::Result<T>>,
    what: &str,
    name: &str,
    outputs: &[PathBuf],
) -> Option<Outcome> {
    match run.ok()? {
        Ok(_) => {
            for output in outputs {
                assert!(output.is_file(), "{what}: upscaled, so {output:?} written");
            }
            Some(Outcome::Upscaled)
        }
        Err(e) => {
            let message = e.to_string();
            assert!(message.contains(name), "{what}: '{message}' names no file");
            Some(Outcome::Refused)
        }
    }
}

#[test]
fn damaged_files_are_upscaled_or_refused_by_name_and_never_panic() {
    // A 16² crop of the sample, saved in each format: five maps, each a file to damage.
    let sample = load_material(Some(&common::sample_material()), &Default::default())
        .unwrap()
        .crop(40, 40, 16, 16);
    let scratch = tempfile::tempdir().unwrap();
    let config = Config {
        upsampler: "bilinear".into(),
        tileable: Some(false),
        ..Config::default()
    };
    // A texel limit a damaged header's size meets quickly (it is checked before decoding).
    let load_options = LoadOptions {
        max_texels: 1 << 16,
        ..LoadOptions::default()
    };
    let mut rng = rand::rngs::StdRng::seed_from_u64(7);
    let mut counts: BTreeMap<(String, Damage), [usize; 2]> = BTreeMap::new();
    let mut panics = Vec::new();
    // Every format in matup's own layout (five maps), then the packed layouts (three files).
    let mut templates: Vec<(String, PathBuf)> = FORMATS
        .iter()
        .map(|&format| {
            let template = scratch.path().join(format!("template-{format}"));
            let options = SaveOptions {
                format: Some(format),
                ..SaveOptions::default()
            };
            save_material(&sample, &template, &options).unwrap();
            assert_eq!(snapshot(&template).len(), 5, "{format}: five maps");
            (format.to_string(), template)
        })
        .collect();
    let png = templates[0].1.clone();
    for (name, folder) in packed_layouts(&png, scratch.path()) {
        assert_eq!(snapshot(&folder).len(), 3, "{name}: three files");
        templates.push((format!("{name} packed"), folder));
    }
    let save_options = SaveOptions {
        names: Names::Keep,
        ..SaveOptions::default()
    };
    for (format, template) in &templates {
        let files: Vec<PathBuf> = snapshot(template).into_keys().collect();
        for damage in DAMAGES {
            for case in 0..50 {
                let folder = scratch
                    .path()
                    .join(format!("input-{format}").replace(' ', "-"));
                let out = scratch
                    .path()
                    .join(format!("output-{format}").replace(' ', "-"));
                let _ = std::fs::remove_dir_all(&folder);
                let _ = std::fs::remove_dir_all(&out);
                std::fs::create_dir(&folder).unwrap();
                let victim = &files[case % files.len()];
                let name = victim.file_name().unwrap().to_string_lossy().into_owned();
                for file in &files {
                    let bytes = std::fs::read(file).unwrap();
                    let bytes = if file == victim {
                        damaged(&bytes, damage, &mut rng)
                    } else {
                        bytes
                    };
                    std::fs::write(folder.join(file.file_name().unwrap()), bytes).unwrap();
                }
                let before = snapshot(&folder);
                let run = std::panic::catch_unwind(|| {
                    let material = load_material(Some(&folder), &load_options)?;
                    common::upscale_into(&material, &config, &out, &save_options)
                });
                let what = format!("{format} {damage:?} #{case} ({name})");
                let outputs: Vec<PathBuf> = files
                    .iter()
                    .map(|f| out.join(f.file_name().unwrap()))
                    .collect();
                let Some(outcome) = judge(run, &what, &name, &outputs) else {
                    panics.push(what);
                    continue;
                };
                assert!(
                    snapshot(&folder) == before,
                    "{what}: the input folder changed"
                );
                let tally = counts.entry((format.to_string(), damage)).or_default();
                tally[matches!(outcome, Outcome::Refused) as usize] += 1;
            }
        }
    }
    // A GLB model of the PNG template's maps: base colour, normals, roughness as occlusion.
    let glb = glb_of(&png, scratch.path());
    for damage in DAMAGES {
        for case in 0..50 {
            let folder = scratch.path().join("input-glb");
            let out = scratch.path().join("output-glb");
            let _ = std::fs::remove_dir_all(&folder);
            let _ = std::fs::remove_dir_all(&out);
            std::fs::create_dir(&folder).unwrap();
            let model = folder.join("model.glb");
            std::fs::write(&model, damaged(&glb, damage, &mut rng)).unwrap();
            let before = snapshot(&folder);
            let run = std::panic::catch_unwind(|| {
                matup::apps::model::upscale_model(
                    &model,
                    &config,
                    &out,
                    &SaveOptions::default(),
                    &load_options,
                    None,
                    &Silent,
                )
            });
            let what = format!("glb {damage:?} #{case}");
            let written = [out.join("model.glb")];
            let Some(outcome) = judge(run, &what, "model.glb", &written) else {
                panics.push(what);
                continue;
            };
            assert!(
                snapshot(&folder) == before,
                "{what}: the input folder changed"
            );
            let tally = counts.entry(("glb model".into(), damage)).or_default();
            tally[matches!(outcome, Outcome::Refused) as usize] += 1;
        }
    }
    println!("damaged files: upscaled / refused by name");
    for ((format, damage), [upscaled, refused]) in &counts {
        let damage = format!("{damage:?}");
        println!("  {format:<13} {damage:<14} {upscaled:>3} / {refused:>3}");
    }
    let (upscaled, refused) = counts
        .values()
        .fold((0, 0), |(u, r), [a, b]| (u + a, r + b));
    println!(
        "{} files: {upscaled} upscaled, {refused} refused by name, {} panics",
        upscaled + refused + panics.len(),
        panics.len()
    );
    assert!(panics.is_empty(), "panics: {panics:?}");
    // 200 cases a template, and 200 of the model.
    assert_eq!(upscaled + refused, 200 * (templates.len() + 1));
    // Both happen: damage a decoder cannot see (a flipped JPEG byte) upscales, a truncated
    // file is refused.
    assert!(upscaled > 0 && refused > 0);
}
