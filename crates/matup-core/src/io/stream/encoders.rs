//! Whole-image encoders that the image crate lacks or writes otherwise: TGA with its
//! run-length packets within scanlines, WebP through libwebp, TIFF with LZW.

use std::fs::File;
use std::io::{BufWriter, Write};

use image::DynamicImage;

/// A run-length encoded TGA whose packets never cross a scanline, as TGA 2.0 requires (the
/// image crate's encoder runs them on across rows, which Pillow refuses as a buffer overrun):
/// each row encoded alone by the image crate's encoder, its packets kept, under one header
/// for the whole image, which is the first row's with the height set.
pub(super) fn write_tga_rle(
    out: &mut BufWriter<File>,
    image: &DynamicImage,
) -> image::ImageResult<()> {
    const HEADER: usize = 18;
    const HEIGHT: usize = 14;
    let mut data = Vec::new();
    for y in 0..image.height() {
        let mut row = Vec::new();
        let encoder = image::codecs::tga::TgaEncoder::new(&mut row);
        image
            .crop_imm(0, y, image.width(), 1)
            .write_with_encoder(encoder)?;
        if y == 0 {
            row[HEIGHT..HEIGHT + 2].copy_from_slice(&(image.height() as u16).to_le_bytes());
            data.extend_from_slice(&row);
        } else {
            data.extend_from_slice(&row[HEADER..]);
        }
    }
    out.write_all(&data).map_err(image::ImageError::IoError)
}

/// Lossy WebP's quality: JPEG's number. Its half-resolution colour still costs a normal map
/// about twice JPEG's error (docs/experiments/2026-11-27-webp-encoding.md).
pub(super) const WEBP_QUALITY: f32 = 95.0;

/// A whole WebP, lossy or lossless, grey written as RGB (WebP holds no grey). libwebp (the
/// `webp` crate) writes it: the image crate encodes lossless WebP only, and a lossy input comes
/// back lossy. Colours under fully transparent texels are kept (`exact`), as every other format
/// keeps them, instead of libwebp's default of replacing them to save bytes.
pub(super) fn write_webp(
    out: &mut BufWriter<File>,
    width: u32,
    height: u32,
    channels: usize,
    samples: Vec<u8>,
    lossless: bool,
) -> std::result::Result<(), String> {
    let (samples, layout) = match channels {
        1 => (
            samples.iter().flat_map(|&v| [v, v, v]).collect(),
            webp::PixelLayout::Rgb,
        ),
        2 => (as_rgba(2, samples), webp::PixelLayout::Rgba),
        3 => (samples, webp::PixelLayout::Rgb),
        _ => (samples, webp::PixelLayout::Rgba),
    };
    let mut config =
        webp::WebPConfig::new().map_err(|()| "libwebp has no default configuration")?;
    config.lossless = lossless.into();
    // Lossless, `quality` is how hard libwebp compresses; its default.
    config.quality = if lossless { 75.0 } else { WEBP_QUALITY };
    config.exact = 1;
    // Lossy WebP keeps colour at half the resolution; libwebp's sharper conversion to it keeps
    // a normal map's 4×4 means within 3.6 levels of its input, against 6.2 without
    // (docs/experiments/2026-11-27-webp-encoding.md).
    config.use_sharp_yuv = 1;
    let encoded = webp::Encoder::new(&samples, layout, width, height)
        .encode_advanced(&config)
        .map_err(|e| format!("the WebP encoder failed: {e:?}"))?;
    out.write_all(&encoded).map_err(|e| e.to_string())
}

/// A whole TIFF of colour type `C` (LZW, as image editors write it).
pub(super) fn write_tiff<C>(
    out: &mut BufWriter<File>,
    width: u32,
    height: u32,
    samples: &[C::Inner],
) -> tiff::TiffResult<()>
where
    C: tiff::encoder::colortype::ColorType,
    [C::Inner]: tiff::encoder::TiffValue,
{
    use tiff::encoder::{Compression, TiffEncoder};
    TiffEncoder::new(out)?
        .with_compression(Compression::Lzw)
        .write_image::<C>(width, height, samples)
}

/// Interleaved grey + alpha or RGBA samples as RGBA (grey copied into R, G and B).
pub(super) fn as_rgba<T: Copy>(channels: usize, samples: Vec<T>) -> Vec<T> {
    if channels == 4 {
        return samples;
    }
    (samples.chunks_exact(2))
        .flat_map(|ga| [ga[0], ga[0], ga[0], ga[1]])
        .collect()
}
