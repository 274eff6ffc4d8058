//! Folders as real exporters write them (glTF, Unreal packed, Unity HDRP, Megascans and its
//! Unreal packing, Poly Haven, ambientCG, Substance Designer, a game mod's TGA folder, and an
//! OpenGL folder whose names say nothing), each
//! built from a real material of `tests/data` under that exporter's names, formats and
//! packing. Each must (a) render as the same decoded data does in matup's own layout, and (b)
//! come back ×4 file for file: the same names, formats, channels and bit depths, each channel
//! box-filtering back to its input.
//!
//! The layouts are written out here by hand, from each exporter's documentation
//! (`docs/materials.md`), independently of matup's own table.

mod common;

use std::path::Path;

use image::{DynamicImage, ImageEncoder};
use matup::config::{Config, InputQuality};
use matup::io::Names;
use matup::material::Material;
use matup::{load_material, shading_model, LightSetSpec, LoadOptions, Map, SaveOptions};

const SIZE: usize = 64;

/// What a channel of an exporter's file holds, as 8-bit stored values.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Src {
    /// Base colour channel (sRGB).
    Base(usize),
    /// Normal x, y or z as DirectX colours; y flipped for OpenGL.
    NormalDx(usize),
    NormalGl(usize),
    Rough,
    /// 1 − roughness (gloss, smoothness).
    Smooth,
    Metal,
    Height,
    /// Occlusion-like data (derived from the height: a real material's texture).
    Occlusion,
    /// Emission-like colour (the base colour, darker).
    Emit(usize),
    Const(u8),
}

struct File {
    name: &'static str,
    channels: Vec<Src>,
}

fn file(name: &'static str, channels: &[Src]) -> File {
    File {
        name,
        channels: channels.to_vec(),
    }
}

/// The stored 8-bit values of a real material's maps, 64² from its corner.
struct Source {
    base: [Vec<u8>; 3],
    normal_dx: [Vec<u8>; 3],
    rough: Vec<u8>,
    metal: Vec<u8>,
    height: Vec<u8>,
}

fn source() -> Source {
    let dir = common::test_material("ambientcg_Metal053C");
    let read = |name: &str, channels: usize| -> Vec<Vec<u8>> {
        let image = image::open(dir.join(name)).unwrap();
        let bytes: Vec<u8> = match channels {
            1 => image.to_luma8().into_raw(),
            _ => image.to_rgb8().into_raw(),
        };
        let w = image.width() as usize;
        (0..channels)
            .map(|c| {
                (0..SIZE * SIZE)
                    .map(|i| bytes[((i / SIZE) * w + i % SIZE) * channels + c])
                    .collect()
            })
            .collect()
    };
    let [b0, b1, b2]: [Vec<u8>; 3] = read("baseColor.png", 3).try_into().unwrap();
    let [n0, n1, n2]: [Vec<u8>; 3] = read("normal.png", 3).try_into().unwrap();
    Source {
        base: [b0, b1, b2],
        normal_dx: [n0, n1, n2],
        rough: read("roughness.png", 1).remove(0),
        metal: read("metallic.png", 1).remove(0),
        height: read("height.png", 1).remove(0),
    }
}

impl Source {
    fn channel(&self, src: Src) -> Vec<u8> {
        match src {
            Src::Base(c) => self.base[c].clone(),
            Src::NormalDx(c) => self.normal_dx[c].clone(),
            Src::NormalGl(1) => self.normal_dx[1].iter().map(|v| 255 - v).collect(),
            Src::NormalGl(c) => self.normal_dx[c].clone(),
            Src::Rough => self.rough.clone(),
            Src::Smooth => self.rough.iter().map(|v| 255 - v).collect(),
            Src::Metal => self.metal.clone(),
            Src::Height => self.height.clone(),
            Src::Occlusion => (self.height.iter())
                .map(|&h| (96 + h as u32 * 5 / 8).min(255) as u8)
                .collect(),
            Src::Emit(c) => self.base[c].iter().map(|v| v / 2).collect(),
            Src::Const(v) => vec![v; SIZE * SIZE],
        }
    }
}

/// Writes `file` into `dir` from `source`: PNG (8 or 16-bit by its name's `16`) or JPEG
/// (quality 95), grey, grey + alpha, RGB or RGBA by its channel count.
fn write(dir: &Path, source: &Source, file: &File) {
    let planes: Vec<Vec<u8>> = file.channels.iter().map(|&s| source.channel(s)).collect();
    let n = planes.len();
    let interleaved: Vec<u8> = (0..SIZE * SIZE)
        .flat_map(|i| planes.iter().map(move |p| p[i]))
        .collect();
    let (w, h) = (SIZE as u32, SIZE as u32);
    let image = match n {
        1 => DynamicImage::ImageLuma8(image::GrayImage::from_raw(w, h, interleaved).unwrap()),
        3 => DynamicImage::ImageRgb8(image::RgbImage::from_raw(w, h, interleaved).unwrap()),
        _ => DynamicImage::ImageRgba8(image::RgbaImage::from_raw(w, h, interleaved).unwrap()),
    };
    let path = dir.join(file.name);
    if file.name.ends_with(".jpg") {
        let out = std::fs::File::create(&path).unwrap();
        let encoder = image::codecs::jpeg::JpegEncoder::new_with_quality(out, 95);
        image.write_with_encoder(encoder).unwrap();
    } else if file.name.contains("16") {
        let wide = DynamicImage::ImageLuma16(image.to_luma16());
        let out = std::fs::File::create(&path).unwrap();
        let png = image::codecs::png::PngEncoder::new(out);
        png.write_image(wide.as_bytes(), w, h, image::ExtendedColorType::L16)
            .unwrap();
    } else {
        image.save(&path).unwrap();
    }
}

/// One plane of an image file as [0, 1] values, channel `c` of its own channels.
fn plane(image: &DynamicImage, c: usize) -> Vec<f32> {
    let n = image.color().channel_count() as usize;
    let values = image.to_rgba32f().into_raw();
    let pick = if n <= 2 && c == 1 { 3 } else { c };
    values.chunks_exact(4).map(|t| t[pick]).collect()
}

/// The material the layout's files hold, decoded here by hand: the first file holding each
/// map gives it; missing maps are matup's stand-ins.
fn decoded(dir: &Path, files: &[File]) -> Material {
    let find = |want: &dyn Fn(Src) -> bool| -> Option<(DynamicImage, usize, Src)> {
        files.iter().find_map(|f| {
            let c = f.channels.iter().position(|&s| want(s))?;
            Some((image::open(dir.join(f.name)).unwrap(), c, f.channels[c]))
        })
    };
    let mut m = Material::uniform(SIZE, [0.214_041_14; 3], 0.5, 0.0);
    let to_map = |values: Vec<f32>| Map::from_planar(SIZE, SIZE, 1, values);
    let mut base = Vec::new();
    for c in 0..3 {
        if let Some((image, i, _)) = find(&|s| s == Src::Base(c)) {
            base.extend(
                plane(&image, i)
                    .into_iter()
                    .map(matup::color::srgb_to_linear),
            );
        }
    }
    if !base.is_empty() {
        m.base_color = Map::from_planar(SIZE, SIZE, 3, base);
    }
    let mut normal = Vec::new();
    for c in 0..3 {
        if let Some((image, i, src)) = find(&|s| s == Src::NormalDx(c) || s == Src::NormalGl(c)) {
            let flip = src == Src::NormalGl(1);
            normal.extend(plane(&image, i).into_iter().map(|v| {
                let v = 2.0 * v - 1.0;
                if flip {
                    -v
                } else {
                    v
                }
            }));
        }
    }
    if !normal.is_empty() {
        m.normal = Map::from_planar(SIZE, SIZE, 3, normal);
        matup::material::normalize_normals(&mut m.normal);
    }
    if let Some((image, i, src)) = find(&|s| s == Src::Rough || s == Src::Smooth) {
        let values = plane(&image, i);
        let inverted = src == Src::Smooth;
        m.roughness = to_map(values).map_values(move |v| if inverted { 1.0 - v } else { v });
    }
    if let Some((image, i, _)) = find(&|s| s == Src::Metal) {
        m.metallic = to_map(plane(&image, i));
    }
    if let Some((image, i, _)) = find(&|s| s == Src::Height) {
        m.height = Some(to_map(plane(&image, i)));
    }
    m
}

/// Every layout: its name, files, and the normal convention its files are in.
fn layouts() -> Vec<(&'static str, Vec<File>)> {
    use Src::*;
    let rgb = |f: fn(usize) -> Src| [f(0), f(1), f(2)];
    vec![
        (
            "glTF 2.0",
            vec![
                file("Mat_baseColor.png", &rgb(Base)),
                file("Mat_normal.png", &rgb(NormalGl)),
                // R is unused by the specification; exporters often put occlusion there.
                file("Mat_metallicRoughness.png", &[Occlusion, Rough, Metal]),
                file("Mat_occlusion.png", &[Occlusion]),
                file("Mat_emissive.png", &rgb(Emit)),
            ],
        ),
        (
            "Unreal packed (Substance 3D Painter)",
            vec![
                file("T_Mat_BaseColor.png", &rgb(Base)),
                file("T_Mat_Normal.png", &rgb(NormalDx)),
                file(
                    "T_Mat_OcclusionRoughnessMetallic.png",
                    &[Occlusion, Rough, Metal],
                ),
            ],
        ),
        (
            "Unity HDRP",
            vec![
                file("Mat_BaseMap.png", &[Base(0), Base(1), Base(2), Const(255)]),
                file("Mat_Normal.png", &rgb(NormalGl)),
                file("Mat_MaskMap.png", &[Metal, Occlusion, Const(255), Smooth]),
            ],
        ),
        (
            "Megascans",
            vec![
                file("tbkpeb3_2K_Albedo.jpg", &rgb(Base)),
                file("tbkpeb3_2K_Normal.jpg", &rgb(NormalGl)),
                file("tbkpeb3_2K_Roughness.jpg", &[Rough]),
                file("tbkpeb3_2K_Gloss.jpg", &[Smooth]),
                file("tbkpeb3_2K_Displacement.jpg", &[Height]),
                file("tbkpeb3_2K_Bump.jpg", &[Height]),
                // Grey data stored as RGB.
                file("tbkpeb3_2K_AO.jpg", &[Occlusion, Occlusion, Occlusion]),
                file("tbkpeb3_2K_Cavity.jpg", &[Occlusion]),
                file("tbkpeb3_2K_Specular.jpg", &rgb(Emit)),
            ],
        ),
        (
            "Poly Haven",
            vec![
                file("rock_wall_diff_1k.jpg", &rgb(Base)),
                file("rock_wall_nor_gl_1k.png", &rgb(NormalGl)),
                file("rock_wall_nor_dx_1k.png", &rgb(NormalDx)),
                file("rock_wall_rough_1k.jpg", &[Rough]),
                file("rock_wall_arm_1k.png", &[Occlusion, Rough, Metal]),
                file("rock_wall_disp_1k.png", &[Height]),
            ],
        ),
        (
            "ambientCG",
            vec![
                file("Metal053C_1K-PNG_Color.png", &rgb(Base)),
                file("Metal053C_1K-PNG_NormalGL.png", &rgb(NormalGl)),
                file("Metal053C_1K-PNG_NormalDX.png", &rgb(NormalDx)),
                file("Metal053C_1K-PNG_Roughness.png", &[Rough]),
                file("Metal053C_1K-PNG_Metalness.png", &[Metal]),
                file("Metal053C_1K-PNG_Displacement.png", &[Height]),
                file("Metal053C_1K-PNG_AmbientOcclusion.png", &[Occlusion]),
            ],
        ),
        (
            "Substance Designer",
            vec![
                file("rust_basecolor.png", &rgb(Base)),
                file("rust_normal.png", &rgb(NormalDx)),
                file("rust_roughness.png", &[Rough]),
                file("rust_metallic.png", &[Metal]),
                file("rust_height16.png", &[Height]),
                file("rust_ambientocclusion.png", &[Occlusion]),
            ],
        ),
        (
            "Megascans for Unreal (ORDp packing)",
            vec![
                file("T_tbkpeb3_4K_D.png", &rgb(Base)),
                file("T_tbkpeb3_4K_N.png", &rgb(NormalDx)),
                file("T_tbkpeb3_4K_ORDp.png", &[Occlusion, Rough, Height]),
            ],
        ),
        (
            "A game mod's TGA textures (_n, _h, _s suffixes)",
            vec![
                file("rock01.tga", &rgb(Base)),
                file("rock01_n.tga", &rgb(NormalDx)),
                file("rock01_h.tga", &[Height]),
                // Specular: carried as the folder's other maps are.
                file("rock01_s.tga", &[Occlusion]),
            ],
        ),
        (
            "OpenGL folder, names that say nothing",
            vec![
                file("albedo.png", &rgb(Base)),
                file("normal.png", &rgb(NormalGl)),
                file("rough.png", &[Rough]),
                file("metal.png", &[Metal]),
                file("height.png", &[Height]),
            ],
        ),
    ]
}

#[test]
fn every_exporters_folder_renders_as_its_data_and_comes_back_file_for_file() {
    let source = source();
    let model = shading_model(&"ggx".parse().unwrap()).unwrap();
    // Told the maps are clean, so that every file box-filters back to its input (the check that
    // each came back in its role): a JPEG set (Megascans) is otherwise read as degraded, and
    // not projected.
    let config = Config {
        tileable: Some(false),
        input_quality: InputQuality::Clean,
        ..Default::default()
    };
    let mut off = Vec::new();
    for (layout, files) in layouts() {
        let dir = tempfile::tempdir().unwrap();
        let input = dir.path().join("in");
        std::fs::create_dir(&input).unwrap();
        for f in &files {
            write(&input, &source, f);
        }

        // (a) Read as the data it holds.
        let material = load_material(Some(&input), &LoadOptions::default())
            .unwrap_or_else(|e| panic!("{layout}: {e}"));
        let expected = decoded(&input, &files);
        let same = matup::eval::metrics::evaluate(
            &expected,
            &material,
            1,
            model.as_ref(),
            &LightSetSpec::default(),
        )
        .unwrap();
        assert!(
            same.render_psnr >= 50.0,
            "{layout}: render PSNR {:.1} dB against the decoded data ({:?})",
            same.render_psnr,
            material.origin.as_ref().unwrap().sources()
        );

        // (b) Every file back, as it was, ×4.
        let out = dir.path().join("out");
        let keep_names = SaveOptions {
            names: Names::Keep,
            ..Default::default()
        };
        common::upscale_into(&material, &config, &out, &keep_names)
            .unwrap_or_else(|e| panic!("{layout}: {e}"));
        for f in &files {
            let before = image::open(input.join(f.name)).unwrap();
            let after = image::open(out.join(f.name))
                .unwrap_or_else(|e| panic!("{layout}: {} did not come back: {e}", f.name));
            assert_eq!(
                after.color(),
                before.color(),
                "{layout}: {} in its channels and depth",
                f.name
            );
            assert_eq!(after.width() as usize, 4 * SIZE, "{layout}: {}", f.name);
            let levels = if f.name.ends_with(".jpg") { 3.0 } else { 2.0 };
            for (c, &src) in f.channels.iter().enumerate() {
                if matches!(src, Src::NormalDx(2) | Src::NormalGl(2)) {
                    continue; // z is renormalised: x and y carry the normal
                }
                let colour = matches!(src, Src::Base(_) | Src::Emit(_));
                let mut offs = common::box_back_levels(
                    &plane(&before, c),
                    &plane(&after, c),
                    4 * SIZE,
                    4,
                    colour,
                );
                offs.sort_by(f32::total_cmp);
                let (p90, worst) = (offs[offs.len() * 9 / 10], offs[offs.len() - 1]);
                println!(
                    "{layout}: {} channel {c} ({src:?}): {p90:.2} (90%), {worst:.2} (all) levels",
                    f.name
                );
                if worst > levels {
                    off.push(format!(
                        "{layout}: {} channel {c} ({src:?}) box-filters back {p90:.2} (90%), \
                         {worst:.2} (all) levels from its input",
                        f.name
                    ));
                }
                if let Src::Const(v) = src {
                    let exact = (plane(&after, c).iter()).all(|&x| (x * 255.0).round() as u8 == v);
                    assert!(exact, "{layout}: {} channel {c} stays constant", f.name);
                }
            }
        }
    }
    assert!(off.is_empty(), "{off:#?}");
}
