//! DDS encoding: how long each block format takes to write a map with its full mip chain, at
//! each `--block-quality`, and how close its top level decodes to the map (PSNR over the
//! channels the format stores, 8-bit scale). Colour maps are written BC1 and BC7, normal maps
//! BC5, grey maps BC4, as `--format dds` and `dds-bc1` would.
//!
//! `cargo run --release --example dds_encode -- MAP.png...`

use std::path::Path;
use std::time::Instant;

use matup::io::{ImageWriter, WriteHints};
use matup::layout::Stored;
use matup::material::{BlockQuality, FileFormat, NormalConvention};

fn main() {
    let dir = tempfile::tempdir().expect("a temporary folder");
    println!("| map | format | quality | encode, mips included (s) | PSNR of the top level (dB) |");
    println!("|---|---|---|---|---|");
    for file in std::env::args().skip(1) {
        let path = Path::new(&file);
        let image = image::open(path).expect("a readable image");
        let normal = file.to_ascii_lowercase().contains("normal");
        let grey = image.color().channel_count() == 1;
        let (w, h) = (image.width() as usize, image.height() as usize);
        let channels = if grey { 1 } else { 3 };
        let samples: Vec<f32> = if grey {
            image.to_luma32f().into_raw()
        } else {
            image.to_rgb32f().into_raw()
        };
        let (codecs, stored): (&[&str], Stored) = match (normal, grey) {
            (true, _) => (&["bc5"], Stored::Normal(NormalConvention::OpenGl)),
            (_, true) => (&["bc4"], Stored::Linear),
            _ => (&["bc1", "bc7"], Stored::Srgb),
        };
        let name = format!(
            "{}/{}",
            path.parent()
                .and_then(|p| p.file_name())
                .unwrap_or_default()
                .to_string_lossy(),
            path.file_name().unwrap().to_string_lossy()
        );
        for codec in codecs {
            for quality in [
                BlockQuality::Fast,
                BlockQuality::Normal,
                BlockQuality::High,
                BlockQuality::Max,
            ] {
                let out = dir.path().join("map.dds");
                // As `--format dds-NAME` writes it: DX10 header, full mip chain.
                let format: FileFormat = format!("dds-{codec}").parse().expect("a DDS format");
                let hints = WriteHints {
                    stored: vec![stored; channels],
                    block_quality: quality,
                };
                let start = Instant::now();
                let mut writer = ImageWriter::create_with(&out, w, h, channels, format, hints)
                    .expect("a DDS writer");
                let planes: Vec<Vec<f32>> = (0..channels)
                    .map(|c| samples.iter().skip(c).step_by(channels).copied().collect())
                    .collect();
                let planes: Vec<&[f32]> = planes.iter().map(Vec::as_slice).collect();
                writer.write_planes(&planes, |_, v| v).expect("rows");
                writer.finish().expect("a DDS file");
                let seconds = start.elapsed().as_secs_f64();
                let decoded = decode_top(&out);
                let stored_channels = if *codec == "bc5" { 2 } else { channels };
                let mse = (0..w * h)
                    .flat_map(|i| (0..stored_channels).map(move |c| (i, c)))
                    .map(|(i, c)| {
                        let d = 255.0 * (decoded[i * 4 + c] - samples[i * channels + c]);
                        (d * d) as f64
                    })
                    .sum::<f64>()
                    / (w * h * stored_channels) as f64;
                let psnr = 10.0 * (255.0f64 * 255.0 / mse.max(1e-12)).log10();
                println!("| {name} | {codec} | {quality} | {seconds:.2} | {psnr:.2} |");
            }
        }
    }
}

/// The top level of a DDS file as RGBA floats.
fn decode_top(path: &Path) -> Vec<f32> {
    let file = std::fs::File::open(path).expect("the written file");
    let mut decoder = dds::Decoder::new(std::io::BufReader::new(file)).expect("a DDS file");
    let size = decoder.main_size();
    let mut bytes = vec![0u8; size.pixels() as usize * 16];
    let view = dds::ImageViewMut::new(&mut bytes, size, dds::ColorFormat::RGBA_F32).unwrap();
    decoder.read_surface(view).expect("a decodable top level");
    bytes
        .chunks_exact(4)
        .map(|b| f32::from_ne_bytes([b[0], b[1], b[2], b[3]]))
        .collect()
}
