//! Reading and writing single image files (PNG 8/16-bit, JPEG, EXR half/float, TIFF 8/16-bit
//! and float, TGA, BMP, WebP, DDS): formats live at this edge; everything inside is a planar f32
//! [`Map`].

use std::fs::File;
use std::io::{Cursor, Read};
use std::path::Path;

use exr::prelude as ex;
use exr::prelude::traits::*;
use image::{DynamicImage, ImageFormat, ImageReader};

use crate::color::to_u8;
use crate::map::Map;
use crate::material::FileFormat;
use crate::{Error, Result};

/// An image as stored: its values (integers scaled to [0, 1], EXR as is), grey or RGB with
/// or without alpha (the last channel), and its format.
pub struct ImageFile {
    pub map: Map,
    pub format: FileFormat,
    /// What was read leniently, for the run's notes (a DDS header written loosely).
    pub notes: Vec<String>,
}

/// The file extensions matup reads.
pub const IMAGE_EXTENSIONS: [&str; 10] = [
    "png", "jpg", "jpeg", "exr", "tif", "tiff", "tga", "bmp", "webp", "dds",
];

/// The width and height of an encoded PNG, JPEG, TGA, BMP or WebP image, from its header.
pub fn encoded_size(bytes: &[u8]) -> Option<(u32, u32)> {
    if bytes.starts_with(b"RIFF") {
        let features = webp::BitstreamFeatures::new(bytes)?;
        return Some((features.width(), features.height()));
    }
    ImageReader::new(Cursor::new(bytes))
        .with_guessed_format()
        .ok()?
        .into_dimensions()
        .ok()
}

/// Whether `path` names a file of a format matup reads (by its extension, any case).
pub fn is_image_file(path: &Path) -> bool {
    path.extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| IMAGE_EXTENSIONS.contains(&e.to_ascii_lowercase().as_str()))
}

/// Whether `path`'s extension is one of `extensions` (any case).
pub(super) fn has_extension(path: &Path, extensions: &[&str]) -> bool {
    path.extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| extensions.iter().any(|x| e.eq_ignore_ascii_case(x)))
}

/// Reads an image, refusing (from the header, before decoding) images with more than
/// `max_texels` texels. Channels as stored: grey, grey + alpha, RGB or RGBA.
pub fn read_image(path: &Path, max_texels: u64) -> Result<ImageFile> {
    if !path.is_file() {
        return Err(Error::file(path, "no such file"));
    }
    if has_extension(path, &["exr"]) {
        read_exr(path, max_texels)
    } else if has_extension(path, &["tif", "tiff"]) {
        read_tiff(path, max_texels)
    } else if has_extension(path, &["dds"]) {
        read_dds(path, max_texels)
    } else if has_extension(path, &["webp"]) {
        read_webp(path, max_texels)
    } else {
        read_with_image_crate(path, max_texels)
    }
}

fn check_size(path: &Path, width: usize, height: usize, max_texels: u64) -> Result<()> {
    if width == 0 || height == 0 {
        return Err(Error::file(
            path,
            format!("image is empty ({width}×{height})"),
        ));
    }
    if (width as u64) * (height as u64) > max_texels {
        return Err(Error::file(
            path,
            format!(
                "image is {width}×{height} = {} texels, over the limit of {max_texels} \
                 (raise it with --max-texels)",
                width as u64 * height as u64
            ),
        ));
    }
    Ok(())
}

/// PNG, JPEG, TGA and BMP.
fn read_with_image_crate(path: &Path, max_texels: u64) -> Result<ImageFile> {
    let open = || -> Result<ImageReader<_>> {
        ImageReader::open(path)
            .map_err(|e| Error::io(path, e))?
            .with_guessed_format()
            .map_err(|e| Error::io(path, e))
    };
    let header = open()?;
    let kind = header.format();
    let (w, h) = header
        .into_dimensions()
        .map_err(|e| Error::file(path, format!("not a readable image: {e}")))?;
    check_size(path, w as usize, h as usize, max_texels)?;

    let mut reader = open()?;
    reader.no_limits(); // the texel limit above is ours; the decoder's would refuse big maps
    let image = reader
        .decode()
        .map_err(|e| Error::file(path, format!("cannot decode: {e}")))?;
    let image = match (kind, image) {
        (Some(ImageFormat::Bmp), DynamicImage::ImageRgb8(rgb)) if has_grey_palette(path)? => {
            bmp_palette_grey(rgb)
        }
        (_, image) => image,
    };
    let sixteen = matches!(
        image,
        DynamicImage::ImageLuma16(_)
            | DynamicImage::ImageLumaA16(_)
            | DynamicImage::ImageRgb16(_)
            | DynamicImage::ImageRgba16(_)
    );
    let format = match kind {
        Some(ImageFormat::Jpeg) => FileFormat::Jpeg,
        Some(ImageFormat::Png) if sixteen => FileFormat::Png16,
        Some(ImageFormat::Png) => FileFormat::Png8,
        Some(ImageFormat::Tga) if tga_is_run_length_encoded(path)? => FileFormat::TgaRle,
        Some(ImageFormat::Tga) => FileFormat::Tga,
        Some(ImageFormat::Bmp) => FileFormat::Bmp,
        other => {
            return Err(Error::file(
                path,
                format!(
                    "unsupported image format {other:?}; use PNG, JPEG, EXR, TIFF, TGA, BMP, WebP or DDS"
                ),
            ))
        }
    };
    let channels = image.color().channel_count() as usize;
    let (w, h) = (w as usize, h as usize);
    let interleaved: Vec<f32> = match &image {
        DynamicImage::ImageLuma8(b) => b.as_raw().iter().map(|&v| v as f32 / 255.0).collect(),
        DynamicImage::ImageLumaA8(b) => b.as_raw().iter().map(|&v| v as f32 / 255.0).collect(),
        DynamicImage::ImageRgb8(b) => b.as_raw().iter().map(|&v| v as f32 / 255.0).collect(),
        DynamicImage::ImageRgba8(b) => b.as_raw().iter().map(|&v| v as f32 / 255.0).collect(),
        DynamicImage::ImageLuma16(b) => b.as_raw().iter().map(|&v| v as f32 / 65535.0).collect(),
        DynamicImage::ImageLumaA16(b) => b.as_raw().iter().map(|&v| v as f32 / 65535.0).collect(),
        DynamicImage::ImageRgb16(b) => b.as_raw().iter().map(|&v| v as f32 / 65535.0).collect(),
        DynamicImage::ImageRgba16(b) => b.as_raw().iter().map(|&v| v as f32 / 65535.0).collect(),
        other => {
            return Err(Error::file(
                path,
                format!("unsupported channel layout {:?}", other.color()),
            ))
        }
    };
    let map = Map::from_fn(w, h, channels, |c, y, x| {
        interleaved[(y * w + x) * channels + c]
    });
    Ok(ImageFile {
        map,
        format,
        notes: Vec::new(),
    })
}

/// Whether a BMP file's colour table is all grey (R = G = B in every entry): an 8-bit grey
/// map, which the image crate decodes through its palette to RGB.
/// Whether a TGA file's image type (its header's third byte: 9, 10 or 11) is run-length
/// encoded, so that it is written back so.
fn tga_is_run_length_encoded(path: &Path) -> Result<bool> {
    let mut header = [0u8; 3];
    let mut file = File::open(path).map_err(|e| Error::io(path, e))?;
    file.read_exact(&mut header)
        .map_err(|e| Error::io(path, e))?;
    Ok(matches!(header[2], 9..=11))
}

fn has_grey_palette(path: &Path) -> Result<bool> {
    let file = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
    let decoder = image::codecs::bmp::BmpDecoder::new(std::io::BufReader::new(file))
        .map_err(|e| Error::file(path, format!("cannot decode: {e}")))?;
    Ok(decoder
        .get_palette()
        .is_some_and(|palette| palette.iter().all(|&[r, g, b]| r == g && g == b)))
}

/// A grey-palette BMP's texels as the grey they are, so that the map comes back one channel
/// and is written back as 8-bit grey, as it came. Kept RGB if any texel is not grey (a colour
/// table that a 24-bit file carries but does not use).
fn bmp_palette_grey(rgb: image::RgbImage) -> DynamicImage {
    if rgb.pixels().all(|p| p[0] == p[1] && p[1] == p[2]) {
        DynamicImage::ImageLuma8(image::GrayImage::from_fn(
            rgb.width(),
            rgb.height(),
            |x, y| image::Luma([rgb.get_pixel(x, y)[0]]),
        ))
    } else {
        DynamicImage::ImageRgb8(rgb)
    }
}

/// WebP, read by libwebp as it is written ([`super::stream`]): the bitstream says whether the
/// image is lossless, so that it comes back the same way. Animations are refused.
fn read_webp(path: &Path, max_texels: u64) -> Result<ImageFile> {
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    let features = webp::BitstreamFeatures::new(&bytes)
        .ok_or_else(|| Error::file(path, "not a readable WebP file"))?;
    if features.has_animation() {
        return Err(Error::file(
            path,
            "an animated WebP; matup reads still images",
        ));
    }
    let (w, h) = (features.width() as usize, features.height() as usize);
    check_size(path, w, h, max_texels)?;
    let format = match features.format() {
        Some(webp::BitstreamFormat::Lossless) => FileFormat::WebpLossless,
        _ => FileFormat::WebpLossy,
    };
    let image = webp::Decoder::new(&bytes)
        .decode()
        .ok_or_else(|| Error::file(path, "cannot decode the WebP image"))?;
    let channels = if image.is_alpha() { 4 } else { 3 };
    let samples: &[u8] = &image;
    let map = Map::from_fn(w, h, channels, |c, y, x| {
        samples[(y * w + x) * channels + c] as f32 / 255.0
    });
    Ok(ImageFile {
        map,
        format,
        notes: Vec::new(),
    })
}

fn read_exr(path: &Path, max_texels: u64) -> Result<ImageFile> {
    let bad = |e: exr::error::Error| Error::file(path, format!("not a readable EXR file: {e}"));
    let meta = ex::MetaData::read_from_file(path, false).map_err(bad)?;
    let header = meta
        .headers
        .first()
        .ok_or_else(|| Error::file(path, "EXR file has no layers"))?;
    check_size(
        path,
        header.layer_size.width(),
        header.layer_size.height(),
        max_texels,
    )?;

    let image = ex::read()
        .no_deep_data()
        .largest_resolution_level()
        .all_channels()
        .first_valid_layer()
        .all_attributes()
        .from_file(path)
        .map_err(bad)?;
    let layer = &image.layer_data;
    let (w, h) = (layer.size.width(), layer.size.height());
    let channels = &layer.channel_data.list;
    let find = |name: &str| {
        channels
            .iter()
            .find(|c| c.name.to_string().eq_ignore_ascii_case(name))
    };
    let mut picked: Vec<_> = match (find("R"), find("G"), find("B"), find("Y")) {
        (Some(r), Some(g), Some(b), _) => vec![r, g, b],
        (_, _, _, Some(y)) => vec![y],
        _ if channels.len() == 1 => vec![&channels[0]],
        _ => {
            let names: Vec<String> = channels.iter().map(|c| c.name.to_string()).collect();
            return Err(Error::file(
                path,
                format!(
                    "unsupported channel layout: channels {}; expected R, G, B (and A) or a \
                     single grey channel (and A)",
                    names.join(", ")
                ),
            ));
        }
    };
    picked.extend(find("A").filter(|_| channels.len() > picked.len()));
    let half = picked
        .iter()
        .all(|c| matches!(c.sample_data, ex::FlatSamples::F16(_)));
    let mut data = Vec::with_capacity(w * h * picked.len());
    for channel in &picked {
        let start = data.len();
        data.extend(channel.sample_data.values_as_f32());
        check_finite(
            path,
            &data[start..],
            w,
            1,
            &format!("channel {}", channel.name),
        )?;
    }
    Ok(ImageFile {
        map: Map::from_planar(w, h, picked.len(), data),
        format: if half {
            FileFormat::ExrHalf
        } else {
            FileFormat::ExrFloat
        },
        notes: Vec::new(),
    })
}

/// DDS through [`super::dds_file`], its float formats checked for non-finite values.
fn read_dds(path: &Path, max_texels: u64) -> Result<ImageFile> {
    let (map, dds, notes) =
        super::dds_file::read_dds(path, |w, h| check_size(path, w, h, max_texels))?;
    let format = FileFormat::Dds(dds);
    if format.is_float() {
        for c in 0..map.channels() {
            check_finite(path, map.plane(c), map.width(), 1, &format!("channel {c}"))?;
        }
    }
    Ok(ImageFile { map, format, notes })
}

/// Refuses `values` (`channels` interleaved, rows `width` texels long) if one is NaN or
/// infinite, naming the texel.
fn check_finite(
    path: &Path,
    values: &[f32],
    width: usize,
    channels: usize,
    what: &str,
) -> Result<()> {
    match values.iter().position(|v| !v.is_finite()) {
        None => Ok(()),
        Some(i) => Err(Error::file(
            path,
            format!(
                "{what} holds a non-finite value ({}) at texel ({}, {})",
                values[i],
                (i / channels) % width,
                (i / channels) / width
            ),
        )),
    }
}

/// TIFF through the tiff crate: grey or RGB, with or without alpha, 8 or 16-bit integers, or 16, 32 or
/// 64-bit floats (read as float, linear); strips or tiles, chunky or planar.
fn read_tiff(path: &Path, max_texels: u64) -> Result<ImageFile> {
    use tiff::decoder::{Decoder, DecodingResult, Limits};
    use tiff::tags::{PlanarConfiguration, Tag};
    use tiff::ColorType;

    let bad = |e: tiff::TiffError| Error::file(path, format!("not a readable TIFF file: {e}"));
    let file = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
    // The texel limit below is ours; the decoder's would refuse big maps.
    let mut decoder = Decoder::new(std::io::BufReader::new(file))
        .map_err(bad)?
        .with_limits(Limits::unlimited());
    let (w, h) = decoder.dimensions().map_err(bad)?;
    let (w, h) = (w as usize, h as usize);
    check_size(path, w, h, max_texels)?;
    let channels = match decoder.colortype().map_err(bad)? {
        ColorType::Gray(_) => 1,
        ColorType::GrayA(_) => 2,
        ColorType::RGB(_) => 3,
        ColorType::RGBA(_) => 4,
        other => {
            return Err(Error::file(
                path,
                format!("unsupported TIFF colour type {other:?}; use grey or RGB (with alpha)"),
            ))
        }
    };
    let planar = decoder
        .find_tag(Tag::PlanarConfiguration)
        .map_err(bad)?
        .and_then(|v| v.into_u16().ok())
        == Some(PlanarConfiguration::Planar.to_u16());
    // Every plane of a planar image (`read_image` would give the first alone).
    let mut decoded = DecodingResult::U8(Vec::new());
    decoder
        .read_image_to_buffer(&mut decoded)
        .map_err(|e| Error::file(path, format!("cannot decode: {e}")))?;
    let (values, format): (Vec<f32>, FileFormat) = match decoded {
        DecodingResult::U8(v) => (
            v.iter().map(|&x| x as f32 / 255.0).collect(),
            FileFormat::Tiff8,
        ),
        DecodingResult::U16(v) => (
            v.iter().map(|&x| x as f32 / 65535.0).collect(),
            FileFormat::Tiff16,
        ),
        DecodingResult::F16(v) => (
            v.iter().map(|x| x.to_f32()).collect(),
            FileFormat::TiffFloat,
        ),
        DecodingResult::F32(v) => (v, FileFormat::TiffFloat),
        DecodingResult::F64(v) => (v.iter().map(|&x| x as f32).collect(), FileFormat::TiffFloat),
        _ => {
            return Err(Error::file(
                path,
                "unsupported TIFF samples; use 8 or 16-bit unsigned integers or floats",
            ))
        }
    };
    if values.len() < w * h * channels {
        return Err(Error::file(
            path,
            format!(
                "the TIFF decodes to {} samples, fewer than {w}×{h}×{channels}",
                values.len()
            ),
        ));
    }
    if format.is_float() {
        check_finite(path, &values[..w * h * channels], w, channels, "the image")?;
    }
    let n = w * h;
    let map = Map::from_fn(w, h, channels, |c, y, x| {
        let i = y * w + x;
        values[if planar { c * n + i } else { i * channels + c }]
    });
    Ok(ImageFile {
        map,
        format,
        notes: Vec::new(),
    })
}

/// Writes a grey or RGB map, either with alpha (values already in the file's encoding: [0, 1] for integer
/// formats) atomically, as one band of [`super::stream::ImageWriter`].
pub fn write_image(path: &Path, map: &Map, format: FileFormat) -> Result<()> {
    super::stream::write_whole(path, map, format)
}

/// `map` (values in [0, 1], grey or RGB) as the bytes of an 8-bit PNG file (in memory, for
/// pages that embed images).
pub fn encode_png8(map: &Map) -> std::result::Result<Vec<u8>, String> {
    let (w, h, ch) = (map.width(), map.height(), map.channels());
    assert!(ch == 1 || ch == 3, "only grey and RGB maps are written");
    let n = map.texels();
    let raw: Vec<u8> = (0..n)
        .flat_map(|i| (0..ch).map(move |c| to_u8(map.data()[c * n + i])))
        .collect();
    let image = if ch == 1 {
        DynamicImage::ImageLuma8(image::GrayImage::from_raw(w as u32, h as u32, raw).unwrap())
    } else {
        DynamicImage::ImageRgb8(image::RgbImage::from_raw(w as u32, h as u32, raw).unwrap())
    };
    let mut out = Cursor::new(Vec::new());
    image
        .write_to(&mut out, ImageFormat::Png)
        .map_err(|e| e.to_string())?;
    Ok(out.into_inner())
}

/// Writes `bytes` to `path` so that readers see the old file or the whole new one, never a
/// part: a temporary file in the same folder, synced, then renamed over `path`.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<()> {
    use std::io::Write;
    let mut tmp = super::stream::temporary_beside(path)?;
    tmp.write_all(bytes).map_err(|e| Error::io(path, e))?;
    super::stream::persist(tmp, path)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A BMP as another program writes it: through the image crate's encoder.
    fn bmp(path: &Path, image: DynamicImage) {
        image.save_with_format(path, ImageFormat::Bmp).unwrap();
    }

    #[test]
    fn a_grey_palette_bmp_reads_as_one_channel_and_a_24_bit_one_as_rgb() {
        let dir = tempfile::tempdir().unwrap();
        let grey = image::GrayImage::from_fn(7, 5, |x, y| image::Luma([(x * 40 + y * 3) as u8]));
        // Written as an 8-bit file with a grey colour table.
        bmp(
            &dir.path().join("grey.bmp"),
            DynamicImage::ImageLuma8(grey.clone()),
        );
        // The same greys as 24-bit RGB: no table, kept RGB as stored.
        let rgb = DynamicImage::ImageLuma8(grey.clone()).to_rgb8();
        bmp(&dir.path().join("rgb.bmp"), DynamicImage::ImageRgb8(rgb));

        let read = read_image(&dir.path().join("grey.bmp"), u64::MAX).unwrap();
        assert_eq!((read.format, read.map.channels()), (FileFormat::Bmp, 1));
        let expected = grey.pixels().map(|p| p[0] as f32 / 255.0);
        assert!(read.map.plane(0).iter().copied().eq(expected));

        let read = read_image(&dir.path().join("rgb.bmp"), u64::MAX).unwrap();
        assert_eq!((read.format, read.map.channels()), (FileFormat::Bmp, 3));
        assert_eq!(read.map.plane(0), read.map.plane(2));
    }
}
