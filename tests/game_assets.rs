//! Game and web assets: a DDS material (BC1 colour, BC5 normal, BC4 roughness with a mip
//! chain), built here with the `dds` crate from a real material of `tests/data`, must read as
//! the same data decoded into PNG files, and come back ×4 in each file's own DDS format; glTF
//! models, their PNG, JPEG and WebP textures upscaled in their roles.

mod common;

use std::path::Path;

use dds::header::Header;
use dds::{ColorFormat, Decoder, Encoder, ImageView, ImageViewMut, Size};
use image::ImageEncoder;
use matup::config::{Config, InputQuality};
use matup::progress::Silent;
use matup::{load_material, save_material, shading_model, LightSetSpec, LoadOptions, SaveOptions};

const SIZE: usize = 64;

/// The 8-bit stored values of a real material's map, `SIZE`² from its corner, as RGBA.
fn corner_rgba(name: &str) -> Vec<u8> {
    let image = image::open(common::test_material("ambientcg_Bricks059").join(name))
        .unwrap()
        .to_rgba8();
    let w = image.width() as usize;
    let raw = image.into_raw();
    (0..SIZE * SIZE)
        .flat_map(|i| {
            let at = ((i / SIZE) * w + i % SIZE) * 4;
            raw[at..at + 4].to_vec()
        })
        .collect()
}

/// Writes RGBA samples as a DDS file of `format`, sRGB-flagged or not, with a full mip chain
/// made by the `dds` crate or none.
fn write_dds(path: &Path, rgba: &[u8], format: dds::Format, srgb: bool, mipmaps: bool) {
    let mut header = Header::new_image(SIZE as u32, SIZE as u32, format);
    if let (true, Header::Dx10(dx10)) = (srgb, &mut header) {
        dx10.dxgi_format = dx10.dxgi_format.to_srgb();
    }
    if mipmaps {
        header = header.with_mipmaps();
    }
    let file = std::fs::File::create(path).unwrap();
    let mut encoder = Encoder::new(file, format, &header).unwrap();
    encoder.mipmaps.generate = mipmaps;
    let size = Size::new(SIZE as u32, SIZE as u32);
    let view = ImageView::new(rgba, size, ColorFormat::RGBA_U8).unwrap();
    encoder.write_surface(view).unwrap();
    encoder.finish().unwrap();
}

/// A DDS file's format, sRGB flag, mip count and top level as RGBA planes.
struct Decoded {
    format: dds::Format,
    srgb: bool,
    mipmaps: u32,
    width: usize,
    planes: [Vec<f32>; 4],
}

fn decode(path: &Path) -> Decoded {
    let file = std::fs::File::open(path)
        .unwrap_or_else(|e| panic!("{} did not come back: {e}", path.display()));
    let mut decoder = Decoder::new(std::io::BufReader::new(file)).unwrap();
    let size = decoder.main_size();
    let mut bytes = vec![0u8; size.pixels() as usize * 16];
    let view = ImageViewMut::new(&mut bytes, size, ColorFormat::RGBA_F32).unwrap();
    decoder.read_surface(view).unwrap();
    let values: Vec<f32> = (bytes.chunks_exact(4))
        .map(|b| f32::from_ne_bytes([b[0], b[1], b[2], b[3]]))
        .collect();
    Decoded {
        format: decoder.format(),
        srgb: decoder.header().is_srgb(),
        mipmaps: decoder.header().mipmap_count().get(),
        width: size.width as usize,
        planes: std::array::from_fn(|c| values.iter().skip(c).step_by(4).copied().collect()),
    }
}

/// Writes planes (values in [0, 1]) as a 16-bit PNG: grey or RGB.
fn write_png16(path: &Path, planes: &[&[f32]]) {
    let samples: Vec<u8> = (0..SIZE * SIZE)
        .flat_map(|i| planes.iter().map(move |p| p[i]))
        .flat_map(|v| ((v.clamp(0.0, 1.0) * 65535.0).round() as u16).to_ne_bytes())
        .collect();
    let colour = match planes.len() {
        1 => image::ExtendedColorType::L16,
        _ => image::ExtendedColorType::Rgb16,
    };
    let out = std::fs::File::create(path).unwrap();
    image::codecs::png::PngEncoder::new(out)
        .write_image(&samples, SIZE as u32, SIZE as u32, colour)
        .unwrap();
}

#[test]
fn a_dds_material_reads_as_its_data_and_comes_back_in_its_own_formats() {
    let dir = tempfile::tempdir().unwrap();
    let (input, twin, out) = (
        dir.path().join("in"),
        dir.path().join("twin"),
        dir.path().join("out"),
    );
    std::fs::create_dir(&input).unwrap();
    std::fs::create_dir(&twin).unwrap();
    // (file, source, format, sRGB, mip chain, the channels that carry the map)
    let files = [
        (
            "baseColor.dds",
            "baseColor.png",
            dds::Format::BC1_UNORM,
            true,
            false,
            3,
        ),
        (
            "normal.dds",
            "normal.png",
            dds::Format::BC5_UNORM,
            false,
            false,
            2,
        ),
        (
            "roughness.dds",
            "roughness.png",
            dds::Format::BC4_UNORM,
            false,
            true,
            1,
        ),
    ];
    for (name, source, format, srgb, mipmaps, _) in files {
        write_dds(
            &input.join(name),
            &corner_rgba(source),
            format,
            srgb,
            mipmaps,
        );
    }

    // Its PNG twin: the DDS files' top levels decoded here, z rebuilt from x and y.
    let base = decode(&input.join("baseColor.dds"));
    let normal = decode(&input.join("normal.dds"));
    let rough = decode(&input.join("roughness.dds"));
    let z: Vec<f32> = (normal.planes[0].iter().zip(&normal.planes[1]))
        .map(|(r, g)| {
            let (x, y) = (2.0 * r - 1.0, 2.0 * g - 1.0);
            0.5 * ((1.0 - x * x - y * y).max(0.0).sqrt() + 1.0)
        })
        .collect();
    let [b0, b1, b2, _] = &base.planes;
    write_png16(&twin.join("baseColor.png"), &[b0, b1, b2]);
    write_png16(
        &twin.join("normal.png"),
        &[&normal.planes[0], &normal.planes[1], &z],
    );
    write_png16(&twin.join("roughness.png"), &[&rough.planes[0]]);

    let material = load_material(Some(&input), &LoadOptions::default()).unwrap();
    let expected = load_material(Some(&twin), &LoadOptions::default()).unwrap();
    // Block-compressed: read as degraded, as `--input-quality auto` routes it.
    let lossy: Vec<String> = material.lossy.values().cloned().collect();
    assert_eq!(
        lossy,
        [
            "BC1 blocks (baseColor.dds)",
            "BC5 blocks (normal.dds)",
            "BC4 blocks (roughness.dds)"
        ]
    );
    assert!(expected.lossy.is_empty());
    let model = shading_model(&"ggx".parse().unwrap()).unwrap();
    let same = matup::eval::metrics::evaluate(
        &expected,
        &material,
        1,
        model.as_ref(),
        &LightSetSpec::default(),
    )
    .unwrap();
    println!(
        "render PSNR against the PNG twin: {:.1} dB",
        same.render_psnr
    );
    assert!(
        same.render_psnr >= 40.0,
        "render PSNR {:.1} dB against the decoded PNG twin",
        same.render_psnr
    );

    // Told the maps are clean, the defaults back-project them: every block comes back to its
    // input. By default they are read as degraded and not projected (below).
    let clean = Config {
        input_quality: InputQuality::Clean,
        ..Config::default()
    };
    common::upscale_into(&material, &clean, &out, &SaveOptions::default()).unwrap();
    let mut off = Vec::new();
    for (name, _, format, srgb, mipmaps, channels) in files {
        let before = decode(&input.join(name));
        let after = decode(&out.join(name));
        assert_eq!(after.format, format, "{name} keeps its block format");
        assert_eq!(after.srgb, srgb, "{name} keeps its sRGB flag");
        assert_eq!(after.width, 4 * SIZE, "{name}");
        // 256 → 1: nine levels where the input had a chain.
        assert_eq!(after.mipmaps, if mipmaps { 9 } else { 1 }, "{name}");
        for c in 0..channels {
            let levels =
                common::box_back_levels(&before.planes[c], &after.planes[c], 4 * SIZE, 4, srgb);
            let worst = levels.into_iter().fold(0.0, f32::max);
            println!("{name} channel {c}: box-filters back within {worst:.2} levels");
            if worst > 6.0 {
                off.push(format!("{name} channel {c}: {worst:.2} levels"));
            }
        }
    }
    assert!(off.is_empty(), "{off:#?}");

    // The defaults: the network for degraded maps, unprojected. The files come back in their
    // formats, each map in its role: on average within a few levels of its input, block by
    // block (what the compression put there is not all put back).
    let routed = dir.path().join("routed");
    let report = common::upscale_into(
        &material,
        &Config::default(),
        &routed,
        &SaveOptions::default(),
    )
    .unwrap()
    .report;
    assert_eq!(report.upsampler_used, "onnx:span_x4_degraded");
    assert!(
        report.input_route.starts_with("input: degraded"),
        "{}",
        report.input_route
    );
    for (name, _, format, srgb, _, channels) in files {
        let (before, after) = (decode(&input.join(name)), decode(&routed.join(name)));
        assert_eq!((after.format, after.srgb), (format, srgb), "{name}");
        for c in 0..channels {
            let levels =
                common::box_back_levels(&before.planes[c], &after.planes[c], 4 * SIZE, 4, srgb);
            let mean = levels.iter().sum::<f32>() / levels.len() as f32;
            println!(
                "{name} channel {c}, routed: box-filters back within {mean:.2} levels on average"
            );
            assert!(
                mean < 3.0,
                "{name} channel {c}: {mean:.2} levels on average"
            );
        }
    }

    // PNG in, `--format dds` out: BC7 colour flagged sRGB, BC5 normals, BC4 grey, each with
    // a full mip chain.
    let converted = dir.path().join("converted");
    let save = SaveOptions {
        format: Some("dds".parse().unwrap()),
        ..Default::default()
    };
    common::upscale_into(&expected, &Config::default(), &converted, &save).unwrap();
    for (name, format, srgb) in [
        ("baseColor.dds", dds::Format::BC7_UNORM, true),
        ("normal.dds", dds::Format::BC5_UNORM, false),
        ("roughness.dds", dds::Format::BC4_UNORM, false),
    ] {
        let written = decode(&converted.join(name));
        assert_eq!((written.format, written.srgb), (format, srgb), "{name}");
        assert_eq!((written.width, written.mipmaps), (4 * SIZE, 9), "{name}");
    }
}

/// The textures of a glTF material built from a real material: (file, PNG bytes).
fn gltf_textures() -> Vec<(&'static str, Vec<u8>)> {
    let base = corner_rgba("baseColor.png");
    let normal = corner_rgba("normal.png");
    let rough = corner_rgba("roughness.png");
    let metal = corner_rgba("metallic.png");
    let height = corner_rgba("height.png");
    let texel = |bytes: &Vec<u8>, i: usize, c: usize| bytes[i * 4 + c];
    let n = SIZE * SIZE;
    let rgb = |f: &dyn Fn(usize, usize) -> u8| -> Vec<u8> {
        (0..n)
            .flat_map(|i| (0..3).map(move |c| (i, c)))
            .map(|(i, c)| f(i, c))
            .collect()
    };
    let png = |samples: Vec<u8>, channels: usize| {
        let colour = if channels == 1 {
            image::ExtendedColorType::L8
        } else {
            image::ExtendedColorType::Rgb8
        };
        let mut bytes = Vec::new();
        image::codecs::png::PngEncoder::new(&mut bytes)
            .write_image(&samples, SIZE as u32, SIZE as u32, colour)
            .unwrap();
        bytes
    };
    vec![
        ("baseColor.png", png(rgb(&|i, c| texel(&base, i, c)), 3)),
        // glTF's normals point green up (OpenGL); the source's are DirectX.
        (
            "normal.png",
            png(
                rgb(&|i, c| {
                    if c == 1 {
                        255 - texel(&normal, i, 1)
                    } else {
                        texel(&normal, i, c)
                    }
                }),
                3,
            ),
        ),
        // R unused (255 here, as some exporters fill it), G roughness, B metallic.
        (
            "metallicRoughness.png",
            png(
                rgb(&|i, c| [255, texel(&rough, i, 0), texel(&metal, i, 0)][c]),
                3,
            ),
        ),
        (
            "occlusion.png",
            png(
                (0..n)
                    .map(|i| (96 + texel(&height, i, 0) as u32 * 5 / 8) as u8)
                    .collect(),
                1,
            ),
        ),
        ("emissive.png", png(rgb(&|i, c| texel(&base, i, c) / 2), 3)),
    ]
}

/// A quad's positions, texture coordinates and indices: the geometry every model carries.
fn quad_geometry() -> Vec<u8> {
    quad_geometry_repeating(1.0)
}

/// [`quad_geometry`] with its UVs running over `repeats` copies of the texture on each axis.
fn quad_geometry_repeating(repeats: f32) -> Vec<u8> {
    let positions: [f32; 12] = [0., 0., 0., 1., 0., 0., 1., 1., 0., 0., 1., 0.];
    let uvs: [f32; 8] = [0., 1., 1., 1., 1., 0., 0., 0.].map(|v: f32| v * repeats);
    let indices: [u16; 6] = [0, 1, 2, 0, 2, 3];
    let mut bytes: Vec<u8> = positions.iter().flat_map(|v| v.to_le_bytes()).collect();
    bytes.extend(uvs.iter().flat_map(|v| v.to_le_bytes()));
    bytes.extend(indices.iter().flat_map(|v| v.to_le_bytes()));
    bytes
}

/// The model's JSON: one mesh, one material with all five roles and an extension the
/// reader must keep; images as `images` says.
fn model_json(
    images: serde_json::Value,
    buffer: serde_json::Value,
    views: &[serde_json::Value],
) -> serde_json::Value {
    let mut buffer_views = vec![
        serde_json::json!({"buffer": 0, "byteOffset": 0, "byteLength": 48, "target": 34962}),
        serde_json::json!({"buffer": 0, "byteOffset": 48, "byteLength": 32, "target": 34962}),
        serde_json::json!({"buffer": 0, "byteOffset": 80, "byteLength": 12, "target": 34963}),
    ];
    buffer_views.extend_from_slice(views);
    let texture = |i: usize| serde_json::json!({"index": i});
    serde_json::json!({
        "asset": {"version": "2.0", "generator": "matup tests"},
        "extensionsUsed": ["KHR_materials_emissive_strength"],
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0, "name": "quad"}],
        "meshes": [{"primitives": [{
            "attributes": {"POSITION": 0, "TEXCOORD_0": 1},
            "indices": 2,
            "material": 0
        }]}],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3",
             "min": [0, 0, 0], "max": [1, 1, 0]},
            {"bufferView": 1, "componentType": 5126, "count": 4, "type": "VEC2"},
            {"bufferView": 2, "componentType": 5123, "count": 6, "type": "SCALAR"}
        ],
        "bufferViews": buffer_views,
        "buffers": [buffer],
        "materials": [{
            "name": "Bricks",
            "pbrMetallicRoughness": {
                "baseColorTexture": texture(0),
                "metallicRoughnessTexture": texture(2),
                "roughnessFactor": 1.0
            },
            "normalTexture": {"index": 1, "scale": 0.8},
            "occlusionTexture": {"index": 3, "strength": 1.0},
            "emissiveTexture": texture(4),
            "emissiveFactor": [1, 1, 1],
            "extensions": {"KHR_materials_emissive_strength": {"emissiveStrength": 2.0}},
            "extras": {"kept": true}
        }],
        "textures": (0..5).map(|i| serde_json::json!({"source": i, "sampler": 0})).collect::<Vec<_>>(),
        "samplers": [{"magFilter": 9729, "minFilter": 9987}],
        "images": images
    })
}

/// An image file's bytes decoded: WebP by libwebp (as matup reads it), others by `image`.
fn decoded(bytes: &[u8]) -> image::DynamicImage {
    if !bytes.starts_with(b"RIFF") {
        return image::load_from_memory(bytes).unwrap();
    }
    let webp = webp::Decoder::new(bytes).decode().expect("a WebP image");
    let (w, h) = (webp.width(), webp.height());
    if webp.is_alpha() {
        image::DynamicImage::ImageRgba8(image::RgbaImage::from_raw(w, h, webp.to_vec()).unwrap())
    } else {
        image::DynamicImage::ImageRgb8(image::RgbImage::from_raw(w, h, webp.to_vec()).unwrap())
    }
}

/// Checks each upscaled texture: 4× the size, in its channels, each channel box-filtering
/// back to its input (colour in linear light) within 2 levels (4 for `lossy` files, whose
/// encoding adds its own error; one more for metallicRoughness, whose roughness the pipeline
/// keeps off 0), metallicRoughness's unused R kept exactly.
fn check_textures(
    textures: &[(&str, Vec<u8>)],
    upscaled: &dyn Fn(usize) -> Vec<u8>,
    lossy: bool,
) -> Vec<String> {
    let levels = if lossy { 4.0 } else { 2.0 };
    let mut off = Vec::new();
    for (i, (name, before)) in textures.iter().enumerate() {
        let stem = name.split('.').next().unwrap();
        let before = decoded(before);
        let after = decoded(&upscaled(i));
        assert_eq!(after.color(), before.color(), "{name}");
        assert_eq!(after.width() as usize, 4 * SIZE, "{name}");
        let channels = before.color().channel_count() as usize;
        let colour = matches!(stem, "baseColor" | "emissive");
        for c in 0..channels {
            if stem == "normal" && c == 2 {
                continue; // z is renormalised: x and y carry the normal
            }
            // A normal is read as its unit vector: a lossy file's x, y and z can disagree, so
            // there its channels are compared as matup reads them (`normals_from_file`).
            let plane = |image: &image::DynamicImage| -> Vec<f32> {
                let values = image.to_rgba32f().into_raw();
                if stem != "normal" || !lossy {
                    return values.chunks_exact(4).map(|t| t[c]).collect();
                }
                let (w, h) = (image.width() as usize, image.height() as usize);
                let mut normals =
                    matup::Map::from_fn(w, h, 3, |k, y, x| 2.0 * values[(y * w + x) * 4 + k] - 1.0);
                matup::material::normals_from_file(&mut normals);
                normals.plane(c).iter().map(|v| 0.5 * v + 0.5).collect()
            };
            let worst =
                common::box_back_levels(&plane(&before), &plane(&after), 4 * SIZE, 4, colour)
                    .into_iter()
                    .fold(0.0, f32::max);
            println!("{name} channel {c}: box-filters back within {worst:.2} levels");
            let levels = if stem == "metallicRoughness" {
                levels + 1.0
            } else {
                levels
            };
            if worst > levels {
                off.push(format!("{name} channel {c}: {worst:.2} levels"));
            }
            if stem == "metallicRoughness" && c == 0 {
                assert!(plane(&after).iter().all(|&v| v == 1.0), "its R kept");
            }
        }
    }
    off
}

/// `matup upscale MODEL -o OUT` with the defaults.
fn upscale_model_with_defaults(model: &Path, out: &Path) -> matup::apps::model::ModelRun {
    upscale_model_with(model, out, &Config::default())
}

/// `matup upscale MODEL -o OUT` with `config`.
fn upscale_model_with(model: &Path, out: &Path, config: &Config) -> matup::apps::model::ModelRun {
    matup::apps::model::upscale_model(
        model,
        config,
        out,
        &SaveOptions::default(),
        &LoadOptions::default(),
        None,
        &Silent,
    )
    .unwrap()
}

#[test]
fn a_gltf_model_comes_back_as_the_same_model_with_every_texture_upscaled_in_its_role() {
    let dir = tempfile::tempdir().unwrap();
    let textures = gltf_textures();
    let geometry = quad_geometry();
    let input = dir.path().join("in");
    std::fs::create_dir_all(input.join("textures")).unwrap();
    std::fs::write(input.join("quad.bin"), &geometry).unwrap();
    for (name, bytes) in &textures {
        std::fs::write(input.join("textures").join(name), bytes).unwrap();
    }
    let images: Vec<serde_json::Value> = (textures.iter())
        .map(|(name, _)| serde_json::json!({"uri": format!("textures/{name}")}))
        .collect();
    let buffer = serde_json::json!({"uri": "quad.bin", "byteLength": geometry.len()});
    let json = model_json(serde_json::Value::from(images), buffer, &[]);
    std::fs::write(
        input.join("quad.gltf"),
        serde_json::to_vec_pretty(&json).unwrap(),
    )
    .unwrap();

    let out = dir.path().join("out");
    let run = upscale_model_with_defaults(&input.join("quad.gltf"), &out);
    assert_eq!(run.runs.len(), 1, "one material, one run");
    let written: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("quad.gltf")).unwrap()).unwrap();
    assert_eq!(
        written, json,
        "the JSON is the same, every field and extension kept"
    );
    assert_eq!(std::fs::read(out.join("quad.bin")).unwrap(), geometry);
    let off = check_textures(
        &textures,
        &|i| std::fs::read(out.join("textures").join(textures[i].0)).unwrap(),
        false,
    );
    assert!(off.is_empty(), "{off:#?}");
    assert!(out.join("matup-runs/0-Bricks/preview.png").is_file());
    // The input is untouched and nothing is left over in the output.
    assert_eq!(std::fs::read(input.join("quad.bin")).unwrap(), geometry);
    assert!(!out.join(".matup-model").exists());
}

#[test]
fn a_uv_atlas_is_not_wrapped_and_a_texture_tiled_over_the_model_is_judged_by_its_edges() {
    let dir = tempfile::tempdir().unwrap();
    let textures = gltf_textures();
    let images: Vec<serde_json::Value> = (textures.iter())
        .map(|(name, _)| serde_json::json!({"uri": name}))
        .collect();
    for (name, bytes) in &textures {
        std::fs::write(dir.path().join(name), bytes).unwrap();
    }
    let run = |repeats: f32| {
        let geometry = quad_geometry_repeating(repeats);
        std::fs::write(dir.path().join("quad.bin"), &geometry).unwrap();
        let buffer = serde_json::json!({"uri": "quad.bin", "byteLength": geometry.len()});
        let json = model_json(serde_json::Value::from(images.clone()), buffer, &[]);
        let model = dir.path().join("quad.gltf");
        std::fs::write(&model, serde_json::to_vec(&json).unwrap()).unwrap();
        let out = dir.path().join(format!("out-{repeats}"));
        let run = upscale_model_with_defaults(&model, &out);
        run.runs[0].1.clone()
    };
    // UVs over one copy of the textures: an atlas, whose edges are no neighbours.
    let atlas = run(1.0);
    assert!(!atlas.tileable);
    assert!(
        atlas
            .tiling_source
            .as_deref()
            .is_some_and(|s| s.contains("UV atlas")),
        "{:?}",
        atlas.tiling_source
    );
    assert_eq!(atlas.tiling_evidence, None);
    // Over three copies the texture repeats: its edges decide, as for a folder.
    let tiled = run(3.0);
    assert_eq!(tiled.tiling_source, None);
    assert!(tiled.tiling_evidence.is_some());
}

/// A GLB of the quad with `textures` embedded after its geometry: its JSON, its binary chunk
/// and the file's bytes.
fn glb_model(textures: &[(&str, Vec<u8>)]) -> (serde_json::Value, Vec<u8>, Vec<u8>) {
    let mut bin = quad_geometry();
    let mut views = Vec::new();
    for (_, bytes) in textures {
        bin.resize(bin.len().div_ceil(4) * 4, 0);
        views.push(
            serde_json::json!({"buffer": 0, "byteOffset": bin.len(), "byteLength": bytes.len()}),
        );
        bin.extend_from_slice(bytes);
    }
    let images: Vec<serde_json::Value> = (0..textures.len())
        .map(|i| serde_json::json!({"bufferView": 3 + i, "mimeType": "image/png"}))
        .collect();
    let json = model_json(
        serde_json::Value::from(images),
        serde_json::json!({"byteLength": bin.len()}),
        &views,
    );
    let bytes = common::glb_bytes(&json, bin.clone());
    (json, bin, bytes)
}

#[test]
fn a_glb_model_comes_back_with_its_geometry_bytes_and_new_embedded_textures() {
    let dir = tempfile::tempdir().unwrap();
    let textures = gltf_textures();
    let (json, bin, glb) = glb_model(&textures);
    let model = dir.path().join("quad.glb");
    std::fs::write(&model, glb).unwrap();

    let out = dir.path().join("out");
    upscale_model_with_defaults(&model, &out);
    let bytes = std::fs::read(out.join("quad.glb")).unwrap();
    let written = gltf::binary::Glb::from_slice(&bytes).unwrap();
    let written_json: serde_json::Value = serde_json::from_slice(&written.json).unwrap();
    let written_bin = written.bin.unwrap().into_owned();
    // Equal apart from where the images are.
    let without_images = |mut j: serde_json::Value| {
        for v in 3..8 {
            j["bufferViews"][v]["byteOffset"] = serde_json::Value::Null;
            j["bufferViews"][v]["byteLength"] = serde_json::Value::Null;
        }
        j["buffers"][0]["byteLength"] = serde_json::Value::Null;
        j
    };
    assert_eq!(without_images(written_json.clone()), without_images(json));
    // The BIN chunk is padded to 4 bytes; the buffer's length is its data's.
    let length = written_json["buffers"][0]["byteLength"].as_u64().unwrap() as usize;
    assert_eq!(length.div_ceil(4) * 4, written_bin.len());
    assert_eq!(
        &written_bin[..92],
        &bin[..92],
        "the geometry's bytes where they were"
    );
    let view = |i: usize| {
        let v = &written_json["bufferViews"][3 + i];
        let (start, length) = (
            v["byteOffset"].as_u64().unwrap() as usize,
            v["byteLength"].as_u64().unwrap() as usize,
        );
        written_bin[start..start + length].to_vec()
    };
    let off = check_textures(&textures, &view, false);
    assert!(off.is_empty(), "{off:#?}");
}

/// WebP bytes of a texture's PNG (grey written as RGB, as WebP holds no grey): lossless, or
/// lossy at quality 90, as web pipelines (gltf-transform, squoosh) write them.
fn webp_of(png: &[u8], lossless: bool) -> Vec<u8> {
    let rgb = image::load_from_memory(png).unwrap().to_rgb8();
    let encoder = webp::Encoder::from_rgb(rgb.as_raw(), SIZE as u32, SIZE as u32);
    let encoded = if lossless {
        encoder.encode_lossless()
    } else {
        encoder.encode(90.0)
    };
    encoded.to_vec()
}

fn is_lossless(webp: &[u8]) -> bool {
    let features = webp::BitstreamFeatures::new(webp).expect("a WebP image");
    matches!(features.format(), Some(webp::BitstreamFormat::Lossless))
}

#[test]
fn a_web_model_keeps_its_webp_textures_webp_and_its_fallbacks_in_their_own_formats() {
    // EXT_texture_webp as gltf-transform writes it: each texture shows a WebP image and keeps
    // its PNG as the fallback. The metallicRoughness WebP is lossless, the others lossy.
    let dir = tempfile::tempdir().unwrap();
    let pngs = gltf_textures();
    let webps: Vec<(String, Vec<u8>)> = (pngs.iter())
        .map(|(name, png)| {
            let stem = name.split('.').next().unwrap();
            (
                format!("{stem}.webp"),
                webp_of(png, stem == "metallicRoughness"),
            )
        })
        .collect();
    let geometry = quad_geometry();
    let input = dir.path().join("in");
    std::fs::create_dir_all(&input).unwrap();
    std::fs::write(input.join("quad.bin"), &geometry).unwrap();
    let files: Vec<(&str, &Vec<u8>)> = (pngs.iter().map(|(n, b)| (*n, b)))
        .chain(webps.iter().map(|(n, b)| (n.as_str(), b)))
        .collect();
    for (name, bytes) in &files {
        std::fs::write(input.join(name), bytes).unwrap();
    }
    let images: Vec<serde_json::Value> = (files.iter())
        .map(|(name, _)| serde_json::json!({"uri": name}))
        .collect();
    let buffer = serde_json::json!({"uri": "quad.bin", "byteLength": geometry.len()});
    let mut json = model_json(serde_json::Value::from(images), buffer, &[]);
    for (i, texture) in (json["textures"].as_array_mut().unwrap().iter_mut()).enumerate() {
        texture["extensions"] = serde_json::json!({"EXT_texture_webp": {"source": 5 + i}});
    }
    json["extensionsUsed"] =
        serde_json::json!(["KHR_materials_emissive_strength", "EXT_texture_webp"]);
    std::fs::write(input.join("quad.gltf"), serde_json::to_vec(&json).unwrap()).unwrap();

    let out = dir.path().join("out");
    // Lossy WebP reads as degraded, whose outputs are not projected; told the maps are clean,
    // each texture box-filters back to its input, which checks that it kept its role.
    let clean = Config {
        input_quality: InputQuality::Clean,
        ..Config::default()
    };
    let run = upscale_model_with(&input.join("quad.gltf"), &out, &clean);
    let labels: Vec<&str> = run.runs.iter().map(|(label, _)| label.as_str()).collect();
    assert_eq!(labels, ["0-Bricks", "0-Bricks-fallback"]);
    let written: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("quad.gltf")).unwrap()).unwrap();
    assert_eq!(written, json, "every field and extension kept");

    let read = |name: &str| std::fs::read(out.join(name)).unwrap();
    let off = check_textures(&pngs, &|i| read(pngs[i].0), false);
    assert!(off.is_empty(), "{off:#?}");
    let webp_textures: Vec<(&str, Vec<u8>)> = (webps.iter())
        .map(|(n, b)| (n.as_str(), b.clone()))
        .collect();
    for (name, before) in &webp_textures {
        assert_eq!(is_lossless(&read(name)), is_lossless(before), "{name}");
    }
    // The metallicRoughness WebP is lossless; all five are held to the lossy allowance.
    let off = check_textures(&webp_textures, &|i| read(webp_textures[i].0), true);
    assert!(off.is_empty(), "{off:#?}");
}

#[test]
fn an_output_larger_than_webp_holds_is_refused_before_any_work() {
    // ×16 of 1024² is 16384², one texel past WebP's sides.
    let dir = tempfile::tempdir().unwrap();
    let input = dir.path().join("in");
    let material = matup::Material::uniform(1024, [0.5, 0.4, 0.3], 0.5, 0.0);
    let webp = SaveOptions {
        format: Some("webp-lossless".parse().unwrap()),
        ..SaveOptions::default()
    };
    save_material(&material, &input, &webp).unwrap();
    let lr = load_material(Some(&input), &LoadOptions::default()).unwrap();
    let config = Config {
        scale: 16,
        ..Config::default()
    };
    let out = dir.path().join("out");
    let error = common::upscale_into(&lr, &config, &out, &SaveOptions::default())
        .err()
        .expect("refused")
        .to_string();
    assert!(
        error.contains("baseColor.webp")
            && error.contains("16384×16384")
            && error.contains("at most 16383"),
        "{error}"
    );
    assert!(
        !out.exists() || std::fs::read_dir(&out).unwrap().count() == 0,
        "nothing written"
    );
}

#[test]
fn batch_finds_models_beside_material_folders_and_resumes_them() {
    use matup::apps::batch::{run_batch, BatchOptions, Outcome};
    let dir = tempfile::tempdir().unwrap();
    let library = dir.path().join("library");
    std::fs::create_dir_all(library.join("props/textures")).unwrap();
    let textures = gltf_textures();
    std::fs::write(library.join("props/quad.glb"), glb_model(&textures).2).unwrap();
    // An image beside the model is the model's, not a material of its own.
    std::fs::write(library.join("props/textures/baseColor.png"), &textures[0].1).unwrap();
    let options = BatchOptions {
        config: Config {
            upsampler: "bilinear".into(),
            ..Config::default()
        },
        save: SaveOptions::default(),
        load: LoadOptions::default(),
        shard: None,
        claims: Default::default(),
        view: false,
        memory_limit: None,
        in_flight: 1,
    };
    let out = dir.path().join("out");
    let first = run_batch(&library, &out, &options, &Silent).unwrap();
    let outcomes: Vec<(&str, &Outcome)> = (first.handled.iter())
        .map(|h| (h.material.as_str(), &h.outcome))
        .collect();
    assert_eq!(outcomes, [("props/quad.glb", &Outcome::Upscaled)]);
    assert!(out.join("props/quad.glb/quad.glb").is_file());
    let again = run_batch(&library, &out, &options, &Silent).unwrap();
    assert_eq!(again.handled[0].outcome, Outcome::AlreadyDone);
}
