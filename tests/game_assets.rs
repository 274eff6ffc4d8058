//! Game and web assets: a DDS material (BC1 colour, BC5 normal, BC4 roughness with a mip
//! chain), built here with the `dds` crate from a real material of `tests/data`, must read as
//! the same data decoded into PNG files, and come back ×4 in each file's own DDS format.

mod common;

use std::path::Path;

use dds::header::Header;
use dds::{ColorFormat, Decoder, Encoder, ImageView, ImageViewMut, Size};
use image::ImageEncoder;
use matup::apps::folder::upscale_to_folder;
use matup::config::Config;
use matup::progress::Silent;
use matup::{load_material, shading_model, LightSetSpec, LoadOptions, SaveOptions};

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

/// The mean of each 4×4 block of a plane `width` wide.
fn box4(values: &[f32], width: usize) -> Vec<f32> {
    let small = width / 4;
    (0..small * small)
        .map(|i| {
            let (y, x) = (i / small, i % small);
            let block = (0..16).map(|k| values[(4 * y + k / 4) * width + 4 * x + k % 4]);
            block.sum::<f32>() / 16.0
        })
        .collect()
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

    upscale_to_folder(
        &material,
        &Config::default(),
        &out,
        &SaveOptions::default(),
        false,
        None,
        None,
        &Silent,
    )
    .unwrap();
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
            let linear = |v: f32| {
                if srgb {
                    matup::color::srgb_to_linear(v)
                } else {
                    v
                }
            };
            let encode = |v: f32| {
                if srgb {
                    matup::color::linear_to_srgb(v)
                } else {
                    v
                }
            };
            let output: Vec<f32> = after.planes[c].iter().map(|&v| linear(v)).collect();
            let back = box4(&output, 4 * SIZE);
            let worst = (back.iter().zip(&before.planes[c]))
                .map(|(&a, &b)| (encode(a) - b).abs() * 255.0)
                .fold(0.0, f32::max);
            println!("{name} channel {c}: box-filters back within {worst:.2} levels");
            if worst > 6.0 {
                off.push(format!("{name} channel {c}: {worst:.2} levels"));
            }
        }
    }
    assert!(off.is_empty(), "{off:#?}");

    // PNG in, `--format dds` out: BC7 colour flagged sRGB, BC5 normals, BC4 grey, each with
    // a full mip chain.
    let converted = dir.path().join("converted");
    let save = SaveOptions {
        format: Some("dds".parse().unwrap()),
        ..Default::default()
    };
    upscale_to_folder(
        &expected,
        &Config::default(),
        &converted,
        &save,
        false,
        None,
        None,
        &Silent,
    )
    .unwrap();
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
