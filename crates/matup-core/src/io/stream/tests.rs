//! The band writers' files read back whole, format by format.

use super::*;
use crate::io::image_file::read_image;

/// An RGB or grey test image with values across [0, 1].
fn image(channels: usize) -> Map {
    Map::from_fn(37, 23, channels, |c, y, x| {
        ((x * 7 + y * 13 + c * 29) % 101) as f32 / 100.0
    })
}

/// An image whose channels vary smoothly and together, as a photographed map's do.
fn smooth_image(channels: usize) -> Map {
    Map::from_fn(37, 23, channels, |c, y, x| {
        0.5 + 0.4 * (0.2 * x as f32 + 0.3 * y as f32 + 0.4 * c as f32).sin()
    })
}

fn write_in_bands(path: &Path, map: &Map, format: FileFormat, bands: &[usize]) {
    let mut writer =
        ImageWriter::create(path, map.width(), map.height(), map.channels(), format).unwrap();
    let mut first = 0;
    for &rows in bands {
        writer.write_rows(&map.rows(first, rows)).unwrap();
        first += rows;
    }
    writer.finish().unwrap();
}

#[test]
fn files_written_in_bands_read_back_as_written_whole() {
    let dir = tempfile::tempdir().unwrap();
    for format in [
        FileFormat::Png8,
        FileFormat::Png16,
        FileFormat::Jpeg,
        FileFormat::ExrHalf,
        FileFormat::ExrFloat,
        FileFormat::Tiff8,
        FileFormat::Tiff16,
        FileFormat::TiffFloat,
        FileFormat::Tga,
        FileFormat::TgaRle,
        FileFormat::Bmp,
        FileFormat::WebpLossy,
        FileFormat::WebpLossless,
    ] {
        // Grey, grey + alpha, RGB, RGBA.
        for channels in 1..=4 {
            // Lossy WebP keeps colour at half the resolution (4:2:0), so its image has the
            // smooth colour of real maps, not a stripe pattern of each channel's own.
            let map = if format == FileFormat::WebpLossy {
                smooth_image(channels)
            } else {
                image(channels)
            };
            let name = |how: &str| {
                dir.path()
                    .join(format!("{how}{channels}.{}", format.extension()))
            };
            if format == FileFormat::Jpeg && channels % 2 == 0 {
                let refused = write_whole(&name("whole"), &map, format).unwrap_err();
                assert!(
                    refused.to_string().contains("JPEG holds no alpha"),
                    "{refused}"
                );
                continue;
            }
            write_in_bands(&name("bands"), &map, format, &[10, 1, 9, 3]);
            write_whole(&name("whole"), &map, format).unwrap();
            let bands = read_image(&name("bands"), u64::MAX).unwrap().map;
            let mut whole = read_image(&name("whole"), u64::MAX).unwrap().map;
            assert!(bands == whole, "{format} ×{channels}");
            if whole.channels() == channels + 2 {
                // TIFF, BMP, TGA and WebP write grey + alpha as RGBA, WebP grey as RGB: the grey
                // in R, G and B, within the level by which the reader still takes them as
                // one grey (lossy WebP's colour conversion).
                let apart = (1..3)
                    .flat_map(|c| whole.plane(c).iter().zip(whole.plane(0)))
                    .map(|(a, b)| (a - b).abs())
                    .fold(0.0, f32::max);
                let allowed = if format == FileFormat::WebpLossy {
                    1.0 / 255.0
                } else {
                    0.0
                };
                assert!(apart <= allowed + 1e-7, "{format} ×{channels}: {apart}");
                whole = whole.select_channels(if channels == 1 { &[0] } else { &[0, 3] });
            }
            // And what was written, to the format's precision (JPEG is lossy).
            let tolerance = match format {
                FileFormat::Png8
                | FileFormat::Tiff8
                | FileFormat::Tga
                | FileFormat::TgaRle
                | FileFormat::Bmp
                | FileFormat::WebpLossless => 0.5 / 255.0,
                FileFormat::Png16 | FileFormat::Tiff16 => 0.5 / 65535.0,
                FileFormat::Jpeg | FileFormat::WebpLossy => 0.1,
                FileFormat::ExrHalf => 1e-3,
                FileFormat::ExrFloat | FileFormat::TiffFloat => 0.0,
                FileFormat::Dds(_) => unreachable!("DDS files are tested in dds_file"),
            };
            let read_as = read_image(&name("whole"), u64::MAX).unwrap().format;
            assert_eq!(read_as, format, "read back as the format written");
            let worst = (whole.data().iter().zip(map.data()))
                .map(|(a, b)| (a - b).abs())
                .fold(0.0, f32::max);
            println!("{format} ×{channels}: {worst}");
            assert!(worst <= tolerance + 1e-6, "{format} ×{channels}: {worst}");
        }
    }
}

#[test]
fn a_webp_wider_than_the_format_holds_is_refused_before_any_row() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("wide.webp");
    let wide = ImageWriter::create(&path, 16384, 4, 3, FileFormat::WebpLossy);
    let error = wide.err().expect("refused").to_string();
    assert!(
        error.contains("16384×4") && error.contains("at most 16383"),
        "{error}"
    );
    assert!(ImageWriter::create(&path, 16383, 4, 3, FileFormat::WebpLossless).is_ok());
}

#[test]
fn an_unfinished_file_is_an_error_and_leaves_nothing() {
    let dir = tempfile::tempdir().unwrap();
    for format in [FileFormat::Png8, FileFormat::ExrHalf, FileFormat::Tiff16] {
        let path = dir.path().join(format!("short.{}", format.extension()));
        let map = image(3);
        let mut writer = ImageWriter::create(&path, 37, 23, 3, format).unwrap();
        writer.write_rows(&map.rows(0, 20)).unwrap();
        let error = writer.finish().unwrap_err().to_string();
        assert!(error.contains("20 of 23 rows"), "{error}");
        assert!(!path.exists());
    }
    // Nor any temporary file.
    assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0);
}

/// The packets of a run-length encoded TGA's pixel data, each as (first pixel, pixels).
fn tga_packets(bytes: &[u8], bytes_per_pixel: usize) -> Vec<(usize, usize)> {
    let (mut at, mut pixel, mut packets) = (18 + bytes[0] as usize, 0, Vec::new());
    while at < bytes.len() {
        let count = (bytes[at] & 0x7f) as usize + 1;
        let run = bytes[at] & 0x80 != 0;
        at += 1 + if run {
            bytes_per_pixel
        } else {
            count * bytes_per_pixel
        };
        packets.push((pixel, count));
        pixel += count;
    }
    packets
}

#[test]
fn a_run_length_encoded_tga_keeps_its_packets_within_scanlines() {
    // Rows of one colour run past the row's end in the image crate's own encoder; an
    // uncompressed TGA is written uncompressed.
    let dir = tempfile::tempdir().unwrap();
    let (w, h) = (37, 5);
    for channels in 1..=4 {
        let map = Map::from_fn(w, h, channels, |c, y, x| {
            if x < 30 {
                (y * 40 + c * 10) as f32 / 255.0
            } else {
                (x * 3) as f32 / 255.0
            }
        });
        let rle = dir.path().join(format!("rle{channels}.tga"));
        write_whole(&rle, &map, FileFormat::TgaRle).unwrap();
        let bytes = std::fs::read(&rle).unwrap();
        // Grey + alpha as RGBA (ImageMagick 6 misreads 16-bit grey).
        assert_eq!(
            bytes[2],
            if channels == 1 { 11 } else { 10 },
            "a run-length type"
        );
        assert_eq!(u16::from_le_bytes([bytes[14], bytes[15]]) as usize, h);
        let bytes_per_pixel = [1, 4, 3, 4][channels - 1];
        let packets = tga_packets(&bytes, bytes_per_pixel);
        for (first, count) in &packets {
            assert_eq!(
                first / w,
                (first + count - 1) / w,
                "{channels}: a packet crosses a row"
            );
        }
        assert_eq!(packets.iter().map(|p| p.1).sum::<usize>(), w * h);
        let back = read_image(&rle, u64::MAX).unwrap();
        assert_eq!(back.format, FileFormat::TgaRle);
        let back = match channels {
            2 => back.map.select_channels(&[0, 3]),
            _ => back.map,
        };
        let worst =
            (back.data().iter().zip(map.data())).fold(0f32, |m, (a, b)| m.max((a - b).abs()));
        assert!(worst <= 0.5 / 255.0, "{channels}: {worst}");
        let plain = dir.path().join(format!("plain{channels}.tga"));
        write_whole(&plain, &map, FileFormat::Tga).unwrap();
        assert_eq!(
            std::fs::read(&plain).unwrap()[2],
            if channels == 1 { 3 } else { 2 }
        );
    }
}
