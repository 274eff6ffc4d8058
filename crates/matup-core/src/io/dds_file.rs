//! DDS files through the `dds` crate (image-rs's decoder and BC1–BC7 encoders): the top level
//! of a 2D texture read as a map, and a map written back in its file's format, with a mip
//! chain made here, because the crate's resizer knows neither sRGB colour nor normals.

use std::io::Write;
use std::path::Path;

use dds::header::{Dx10Header, Dx9Header, DxgiFormat, Header};
use dds::{
    Channels, ColorFormat, CompressionQuality, Decoder, Encoder, ImageView, ImageViewMut,
    Precision, Size,
};

use crate::color::{linear_to_srgb, srgb_to_linear};
use crate::file_format::{BlockQuality, DdsCodec, DdsFormat, DDS_CODECS};
use crate::layout::Stored;
use crate::map::Map;
use crate::{Error, Result};

/// Reads the top level of a DDS texture: grey, RGB or RGBA as its format holds them (a BC1
/// texture without punched-through texels as RGB); a two-channel normal format's x and y
/// with z rebuilt in B, stored as normals are, `(z + 1) / 2`. `check_size(width, height)`
/// may refuse the texture from its header, before it is decoded. Returns the map, its format
/// and what was read leniently, for the run's notes ([`lenient_dx10_header`]).
pub(crate) fn read_dds(
    path: &Path,
    check_size: impl Fn(usize, usize) -> Result<()>,
) -> Result<(Map, DdsFormat, Vec<String>)> {
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    decode_dds_checked(bytes, path, check_size)
}

/// A DDS file's bytes decoded as [`read_dds`] reads them (`path` names it in errors); its
/// map and format.
pub(crate) fn decode_dds(bytes: Vec<u8>, path: &Path) -> Result<(Map, DdsFormat)> {
    decode_dds_checked(bytes, path, |_, _| Ok(())).map(|(map, format, _)| (map, format))
}

fn decode_dds_checked(
    mut bytes: Vec<u8>,
    path: &Path,
    check_size: impl Fn(usize, usize) -> Result<()>,
) -> Result<(Map, DdsFormat, Vec<String>)> {
    let notes = lenient_dx10_header(&mut bytes);
    let mut decoder = Decoder::new(std::io::Cursor::new(bytes))
        .map_err(|e| Error::file(path, format!("not a readable DDS file: {e}")))?;
    let header = decoder.header().clone();
    let Some(codec) = DdsCodec::of(decoder.format()) else {
        return Err(Error::file(
            path,
            format!(
                "DDS surface format {:?} is not one matup writes back; it reads {}",
                decoder.format(),
                DDS_CODECS.map(|row| row.0.to_ascii_uppercase()).join(", ")
            ),
        ));
    };
    let layout = decoder.layout();
    if !layout.is_texture() {
        // Which header field decided it, in its words.
        let array_size = header.dx10().map_or(1, |d| d.array_size);
        let what = if layout.is_cube_map() {
            "a cube map (the header's cube-map flags)".to_string()
        } else if layout.is_texture_array() {
            format!("a texture array (the DX10 header's array size {array_size})")
        } else {
            "a volume texture (the header's depth)".to_string()
        };
        return Err(Error::file(path, format!("{what}, not a single 2D map")));
    }
    let size = decoder.main_size();
    let (w, h) = (size.width as usize, size.height as usize);
    check_size(w, h)?;
    let mut bytes = vec![0u8; w * h * 16];
    let view = ImageViewMut::new(&mut bytes, size, ColorFormat::RGBA_F32)
        .expect("a buffer of the texture's size");
    decoder
        .read_surface(view)
        .map_err(|e| Error::file(path, format!("cannot decode: {e}")))?;
    let rgba: Vec<f32> = (bytes.chunks_exact(4))
        .map(|b| f32::from_ne_bytes([b[0], b[1], b[2], b[3]]))
        .collect();
    let opaque = || rgba.chunks_exact(4).all(|t| t[3] >= 1.0);
    let channels = match codec.channels() {
        4 if codec.name() == "bc1" && opaque() => 3,
        2 => 3,
        n => n,
    };
    let map = Map::from_fn(w, h, channels, |c, y, x| {
        let texel = &rgba[(y * w + x) * 4..][..4];
        if codec.channels() == 2 && c == 2 {
            rebuilt_z(texel[0], texel[1])
        } else {
            texel[c]
        }
    });
    let format = DdsFormat {
        codec: Some(codec),
        srgb: Some(header.is_srgb()),
        dx10: header.dx10().is_some(),
        mipmaps: header.mipmap_count().get() > 1,
    };
    Ok((map, format, notes))
}

/// Where the DX10 header's fields lie in a DDS file: after the magic (4 bytes), the header
/// (124) and its pixel format's four-character code at 84.
const FOURCC: usize = 84;
const DXGI_FORMAT: usize = 128;
const ARRAY_SIZE: usize = 140;

/// The typeless block and 8-bit formats (DXGI numbers) and the UNORM twin each is read as.
const TYPELESS_AS_UNORM: [(u32, u32, &str); 7] = [
    (70, 71, "BC1"),
    (73, 74, "BC2"),
    (76, 77, "BC3"),
    (79, 80, "BC4"),
    (82, 83, "BC5"),
    (94, 95, "BC6H"),
    (97, 98, "BC7"),
];

/// A DX10 header as loose writers leave it, made what it means: an array size of 0 (Pillow
/// writes it so) is one texture, and a typeless block format is its UNORM twin. Returns what
/// it changed, in words; anything else that cannot be one 2D map is still refused by the
/// decoder's layout.
fn lenient_dx10_header(bytes: &mut [u8]) -> Vec<String> {
    let mut notes = Vec::new();
    if bytes.len() < ARRAY_SIZE + 4 || &bytes[FOURCC..FOURCC + 4] != b"DX10" {
        return notes;
    }
    let field = |b: &[u8], at: usize| u32::from_le_bytes([b[at], b[at + 1], b[at + 2], b[at + 3]]);
    if field(bytes, ARRAY_SIZE) == 0 {
        bytes[ARRAY_SIZE..ARRAY_SIZE + 4].copy_from_slice(&1u32.to_le_bytes());
        notes.push("DX10 header's array size 0 read as 1 (one texture)".to_string());
    }
    let format = field(bytes, DXGI_FORMAT);
    if let Some((_, unorm, name)) = TYPELESS_AS_UNORM.iter().find(|(t, ..)| *t == format) {
        bytes[DXGI_FORMAT..DXGI_FORMAT + 4].copy_from_slice(&unorm.to_le_bytes());
        notes.push(format!("DXGI format {name}_TYPELESS read as {name}_UNORM"));
    }
    notes
}

/// The stored z of a unit normal whose stored x and y are `r` and `g`.
fn rebuilt_z(r: f32, g: f32) -> f32 {
    let (x, y) = (2.0 * r - 1.0, 2.0 * g - 1.0);
    0.5 * ((1.0 - x * x - y * y).max(0.0).sqrt() + 1.0)
}

/// Writes a `width × height` texture of `channels` interleaved `samples` (values as stored:
/// [0, 1] but for float formats) as a DDS file of `format`, each channel stored as `stored`
/// says (which the mip chain's filter needs), the block formats searched at `quality`.
#[allow(clippy::too_many_arguments)]
pub(crate) fn write_dds(
    out: impl Write,
    width: usize,
    height: usize,
    channels: usize,
    samples: Vec<f32>,
    format: DdsFormat,
    stored: &[Stored],
    quality: BlockQuality,
) -> std::result::Result<(), String> {
    let codec = format
        .codec
        .unwrap_or_else(|| chosen_codec(channels, stored));
    let srgb = format
        .srgb
        .unwrap_or_else(|| stored.contains(&Stored::Srgb));
    let header = header(width as u32, height as u32, codec, srgb, format.dx10)?;
    let header = if format.mipmaps {
        header.with_mipmaps()
    } else {
        header
    };
    let levels = header.mipmap_count().get();
    let mut encoder =
        Encoder::new(out, codec.0, &header).map_err(|e| format!("cannot encode: {e}"))?;
    encoder.encoding.quality = match quality {
        BlockQuality::Fast => CompressionQuality::Fast,
        BlockQuality::Normal => CompressionQuality::Normal,
        BlockQuality::High => CompressionQuality::High,
        BlockQuality::Max => CompressionQuality::Unreasonable,
    };
    let mut level = Level {
        width,
        height,
        channels,
        samples,
    };
    if !codec.is_float() {
        level
            .samples
            .iter_mut()
            .for_each(|v| *v = v.clamp(0.0, 1.0));
    }
    for index in 0..levels {
        if index > 0 {
            level = level.halved(stored);
        }
        let (color, rgba);
        let data: &[f32] = match channels {
            1 => {
                color = ColorFormat::new(Channels::Grayscale, Precision::F32);
                &level.samples
            }
            3 => {
                color = ColorFormat::RGB_F32;
                &level.samples
            }
            4 => {
                color = ColorFormat::RGBA_F32;
                &level.samples
            }
            // Grey and alpha: the grey in R, G and B.
            _ => {
                color = ColorFormat::RGBA_F32;
                rgba = (level.samples.chunks_exact(2))
                    .flat_map(|la| [la[0], la[0], la[0], la[1]])
                    .collect::<Vec<f32>>();
                &rgba
            }
        };
        let bytes: Vec<u8> = data.iter().flat_map(|v| v.to_ne_bytes()).collect();
        let size = Size::new(level.width as u32, level.height as u32);
        let view = ImageView::new(&bytes, size, color).expect("a level of its own size");
        encoder
            .write_surface(view)
            .map_err(|e| format!("cannot encode level {index}: {e}"))?;
    }
    encoder.finish().map_err(|e| format!("cannot encode: {e}"))
}

/// Refuses a file of `channels` stored as `stored` in a DDS format that would drop one of
/// them (a normal's z excepted: two-channel formats rebuild it).
pub(crate) fn check_fits(
    channels: usize,
    format: DdsFormat,
    stored: &[Stored],
) -> std::result::Result<(), String> {
    let codec = format
        .codec
        .unwrap_or_else(|| chosen_codec(channels, stored));
    let normal_xy = codec.channels() == 2
        && channels == 3
        && !stored.is_empty()
        && stored.iter().all(|s| matches!(s, Stored::Normal(_)));
    if channels > codec.channels() && !normal_xy {
        return Err(format!(
            "DDS {} holds {} channel(s), this map has {channels}; write it in a format that \
             holds them all (--format dds picks one a file)",
            codec.name().to_ascii_uppercase(),
            codec.channels()
        ));
    }
    Ok(())
}

/// The format `dds` (no format named) writes a file in: BC5 for a normal map, BC4 for one
/// channel, BC7 for the rest.
fn chosen_codec(channels: usize, stored: &[Stored]) -> DdsCodec {
    let named = |name| DdsCodec::named(name).expect("a row of DDS_CODECS");
    if !stored.is_empty() && stored.iter().all(|s| matches!(s, Stored::Normal(_))) {
        named("bc5")
    } else if channels == 1 {
        named("bc4")
    } else {
        named("bc7")
    }
}

/// A texture's header: DX10 where asked or where only DX10 can say the format or sRGB; the
/// legacy DX9 one where asked or where DX10 has no such format (24-bit RGB).
fn header(
    width: u32,
    height: u32,
    codec: DdsCodec,
    srgb: bool,
    dx10: bool,
) -> std::result::Result<Header, String> {
    let modern = DxgiFormat::try_from(codec.0).ok();
    let legacy = dds::header::Dx9PixelFormat::try_from(codec.0).ok();
    match (modern, legacy) {
        (Some(dxgi), None) => Ok(dx10_header(width, height, dxgi, srgb)),
        (Some(dxgi), Some(_)) if dx10 || srgb => Ok(dx10_header(width, height, dxgi, srgb)),
        (_, Some(pixel_format)) => Ok(Header::Dx9(Dx9Header::new_image(
            width,
            height,
            pixel_format,
        ))),
        (None, None) => Err(format!("DDS format {} has no header", codec.name())),
    }
}

fn dx10_header(width: u32, height: u32, dxgi: DxgiFormat, srgb: bool) -> Header {
    let dxgi = if srgb { dxgi.to_srgb() } else { dxgi };
    Header::Dx10(Dx10Header::new_image(width, height, dxgi))
}

/// One level of a mip chain: interleaved samples as stored.
struct Level {
    width: usize,
    height: usize,
    channels: usize,
    samples: Vec<f32>,
}

impl Level {
    /// The next level, half as large a side (at least 1): each texel the mean of the 2 × 2
    /// it covers, taken where it is linear (sRGB colour decoded), normals renormalised.
    fn halved(&self, stored: &[Stored]) -> Level {
        let (w, h, ch) = (self.width, self.height, self.channels);
        let (w2, h2) = ((w / 2).max(1), (h / 2).max(1));
        let linear = |c: usize, v: f32| match stored.get(c) {
            Some(Stored::Srgb) => srgb_to_linear(v),
            Some(Stored::Normal(_)) => 2.0 * v - 1.0,
            _ => v,
        };
        let stored_as = |c: usize, v: f32| match stored.get(c) {
            Some(Stored::Srgb) => linear_to_srgb(v),
            Some(Stored::Normal(_)) => 0.5 * (v + 1.0),
            _ => v,
        };
        let normal: Vec<usize> = (0..ch)
            .filter(|&c| matches!(stored.get(c), Some(Stored::Normal(_))))
            .collect();
        let mut samples = vec![0.0; w2 * h2 * ch];
        let mut texel = vec![0.0f32; ch];
        for y in 0..h2 {
            for x in 0..w2 {
                let rows = [(2 * y).min(h - 1), (2 * y + 1).min(h - 1)];
                let columns = [(2 * x).min(w - 1), (2 * x + 1).min(w - 1)];
                for (c, value) in texel.iter_mut().enumerate() {
                    *value = 0.25
                        * (rows.iter())
                            .flat_map(|&yy| columns.map(|xx| (yy * w + xx) * ch + c))
                            .map(|i| linear(c, self.samples[i]))
                            .sum::<f32>();
                }
                if normal.len() == 3 {
                    let length = normal.iter().map(|&c| texel[c] * texel[c]).sum::<f32>();
                    if length > 0.0 {
                        normal.iter().for_each(|&c| texel[c] /= length.sqrt());
                    }
                }
                for (c, &value) in texel.iter().enumerate() {
                    samples[(y * w2 + x) * ch + c] = stored_as(c, value);
                }
            }
        }
        Level {
            width: w2,
            height: h2,
            channels: ch,
            samples,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::file_format::FileFormat;
    use crate::io::image_file::read_image;
    use crate::io::stream::{write_whole, ImageWriter, WriteHints};
    use crate::map_kind::NormalConvention;

    /// A smooth test image (block formats are judged on content like a map's).
    fn image(channels: usize, size: usize) -> Map {
        Map::from_fn(size, size, channels, |c, y, x| {
            let t = (x as f32 * 0.11 + y as f32 * 0.07 + c as f32).sin();
            0.5 + 0.4 * t
        })
    }

    fn format(name: &str) -> DdsFormat {
        match name.parse::<FileFormat>().unwrap() {
            FileFormat::Dds(dds) => dds,
            other => panic!("{other} is not DDS"),
        }
    }

    fn write(path: &Path, map: &Map, dds: DdsFormat, stored: Vec<Stored>) {
        let (w, h, ch) = (map.width(), map.height(), map.channels());
        let hints = WriteHints {
            stored,
            block_quality: BlockQuality::Normal,
        };
        let mut writer =
            ImageWriter::create_with(path, w, h, ch, FileFormat::Dds(dds), hints).unwrap();
        writer.write_rows(map).unwrap();
        writer.finish().unwrap();
    }

    /// Every level of a DDS texture, decoded as RGBA.
    fn levels(path: &Path) -> Vec<Map> {
        let file = std::fs::File::open(path).unwrap();
        let mut decoder = Decoder::new(std::io::BufReader::new(file)).unwrap();
        let mut out = Vec::new();
        while let Some(info) = decoder.surface_info() {
            let size = info.size();
            let mut bytes = vec![0u8; size.pixels() as usize * 16];
            let view = ImageViewMut::new(&mut bytes, size, ColorFormat::RGBA_F32).unwrap();
            decoder.read_surface(view).unwrap();
            let values: Vec<f32> = (bytes.chunks_exact(4))
                .map(|b| f32::from_ne_bytes([b[0], b[1], b[2], b[3]]))
                .collect();
            let (w, h) = (size.width as usize, size.height as usize);
            out.push(Map::from_fn(w, h, 4, |c, y, x| values[(y * w + x) * 4 + c]));
        }
        out
    }

    fn worst(a: &Map, b: &Map) -> f32 {
        (a.data().iter().zip(b.data()))
            .map(|(x, y)| (x - y).abs())
            .fold(0.0, f32::max)
    }

    #[test]
    fn every_format_reads_back_as_written_in_its_own_format() {
        let dir = tempfile::tempdir().unwrap();
        for (name, codec, channels, _) in DDS_CODECS {
            // Two-channel formats hold a normal's x and y; the rest grey, RGB or RGBA.
            let map = if channels == 2 {
                let mut n = image(3, 32);
                let m = n.texels();
                for i in 0..m {
                    // x and y within ±0.4: a normal well clear of the horizon.
                    n.data_mut()[i] = 0.5 + 0.5 * (n.data()[i] - 0.5);
                    n.data_mut()[m + i] = 0.5 + 0.5 * (n.data()[m + i] - 0.5);
                    let (r, g) = (n.data()[i], n.data()[m + i]);
                    n.data_mut()[2 * m + i] = rebuilt_z(r, g);
                }
                n
            } else if name == "bc1" {
                image(3, 32) // its alpha is one bit: opaque, read as RGB
            } else {
                image(channels, 32)
            };
            let path = dir.path().join(format!("{name}.dds"));
            let stored = match channels {
                2 => vec![Stored::Normal(NormalConvention::DirectX); 3],
                _ => vec![],
            };
            write(&path, &map, format(&format!("dds-{name}")), stored);
            let read = read_image(&path, u64::MAX).unwrap();
            let FileFormat::Dds(read_as) = read.format else {
                panic!("{name}: read as {}", read.format)
            };
            assert_eq!(read_as.codec, Some(codec), "{name}");
            assert!(read_as.mipmaps && read_as.srgb == Some(false), "{name}");
            // 24-bit RGB has no DX10 format: its header is the legacy one.
            let legacy_only = matches!(name, "rgb8" | "bgr8");
            assert_eq!(read_as.dx10, !legacy_only, "{name}");
            assert_eq!(read.map.channels(), map.channels(), "{name}");
            let tolerance = match name {
                "bc1" | "bc2" | "bc3" | "bc7" | "bc4" | "bc5" => 0.06,
                "b5g6r5" => 0.5 / 31.0,
                "bgr5a1" => 0.5, // its alpha has 1 bit
                "bgra4" => 0.5 / 15.0 + 1e-6,
                "rgb10a2" => 0.5 / 3.0, // its alpha has 2 bits
                "r16" | "rg16" | "rgba16" | "r32f" | "rgba32f" => 1e-4,
                "r16f" | "rgba16f" => 1e-3,
                _ => 0.5 / 255.0 + 1e-6,
            };
            let error = worst(&read.map, &map);
            assert!(error <= tolerance, "{name}: {error}");
        }
    }

    #[test]
    fn block_formats_keep_maps_close() {
        // Mean error well under what a level of 8-bit storage would show on a render.
        let dir = tempfile::tempdir().unwrap();
        for (name, expected) in [("bc1", 0.012), ("bc7", 0.004), ("bc4", 0.006)] {
            let map = image(if name == "bc4" { 1 } else { 3 }, 64);
            let path = dir.path().join(format!("{name}.dds"));
            write(&path, &map, format(&format!("dds-{name}")), vec![]);
            let read = read_image(&path, u64::MAX).unwrap().map;
            let mean = (read.data().iter().zip(map.data()))
                .map(|(a, b)| (a - b).abs())
                .sum::<f32>()
                / map.data().len() as f32;
            assert!(mean < expected, "{name}: mean error {mean}");
        }
    }

    #[test]
    fn mip_chains_average_colour_in_linear_light_and_renormalise_normals() {
        let dir = tempfile::tempdir().unwrap();
        // sRGB black and white texels: the next level is linear grey 0.5 (sRGB 0.735), not
        // sRGB 0.5.
        let checker = Map::from_fn(8, 8, 3, |_, y, x| ((x + y) % 2) as f32);
        let path = dir.path().join("colour.dds");
        write(&path, &checker, format("dds-rgba8"), vec![Stored::Srgb; 3]);
        let chain = levels(&path);
        assert_eq!(
            chain.iter().map(|l| l.width()).collect::<Vec<_>>(),
            [8, 4, 2, 1]
        );
        for level in &chain[1..] {
            let expected = linear_to_srgb(0.5);
            assert!(
                (level.get(0, 0, 0) - expected).abs() <= 0.5 / 255.0,
                "{level:?}"
            );
        }
        // The header says sRGB where the colour is sRGB-encoded.
        let FileFormat::Dds(read_as) = read_image(&path, u64::MAX).unwrap().format else {
            unreachable!()
        };
        assert_eq!(read_as.srgb, Some(true));

        // Normals tilted left and right average to straight up, of unit length.
        let s = 0.6f32;
        let normals = Map::from_fn(8, 8, 3, |c, _, x| {
            let v = [if x % 2 == 0 { s } else { -s }, 0.0, 0.8][c];
            0.5 * (v + 1.0)
        });
        let path = dir.path().join("normal.dds");
        let stored = vec![Stored::Normal(NormalConvention::DirectX); 3];
        write(&path, &normals, format("dds-rgba16"), stored.clone());
        let next = &levels(&path)[1];
        let n: Vec<f32> = (0..3).map(|c| 2.0 * next.get(c, 1, 1) - 1.0).collect();
        assert!(n[0].abs() < 1e-4 && n[1].abs() < 1e-4, "{n:?}");
        assert!((n[2] - 1.0).abs() < 1e-4, "{n:?}");

        // `dds` alone picks BC5 for normals, and only x and y are stored.
        let path = dir.path().join("auto.dds");
        write(&path, &normals, format("dds"), stored);
        let read = read_image(&path, u64::MAX).unwrap();
        let FileFormat::Dds(read_as) = read.format else {
            unreachable!()
        };
        assert_eq!(read_as.codec.map(|c| c.name()), Some("bc5"));
        assert!((read.map.get(2, 0, 0) - 0.9).abs() < 0.01, "z rebuilt");
    }

    #[test]
    fn a_format_asked_for_that_would_drop_a_channel_is_refused_before_writing() {
        let dir = tempfile::tempdir().unwrap();
        let material = crate::material::Material::uniform(8, [0.2, 0.4, 0.6], 0.5, 0.0);
        let options = crate::io::SaveOptions {
            format: Some(FileFormat::Dds(format("dds-bc5"))),
            ..Default::default()
        };
        let out = dir.path().join("out");
        let error = crate::io::save_material(&material, &out, &options)
            .err()
            .unwrap()
            .to_string();
        assert!(
            error.contains("baseColor.dds") && error.contains("BC5 holds 2"),
            "{error}"
        );
        assert_eq!(
            std::fs::read_dir(&out).unwrap().count(),
            0,
            "nothing written"
        );
        // Normals' z is rebuilt from x and y: BC5 takes them.
        let normals = vec![Stored::Normal(NormalConvention::OpenGl); 3];
        assert!(check_fits(3, format("dds-bc5"), &normals).is_ok());
        assert!(check_fits(2, format("dds-bc4"), &[Stored::Linear; 2]).is_err());
        assert!(check_fits(2, format("dds"), &[Stored::Linear; 2]).is_ok());
    }

    #[test]
    fn a_two_channel_texture_of_any_role_comes_back_in_its_format() {
        // A BC5 file named as colour: its third channel is rebuilt, not stored.
        let dir = tempfile::tempdir().unwrap();
        let input = dir.path().join("in");
        std::fs::create_dir(&input).unwrap();
        write(
            &input.join("baseColor.dds"),
            &image(3, 16),
            format("dds-bc5"),
            vec![],
        );
        let material = crate::io::load_material(Some(&input), &Default::default()).unwrap();
        let out = dir.path().join("out");
        crate::io::save_material(&material, &out, &Default::default()).unwrap();
        let FileFormat::Dds(read_as) = read_image(&out.join("baseColor.dds"), u64::MAX)
            .unwrap()
            .format
        else {
            unreachable!()
        };
        assert_eq!(read_as.codec.map(|c| c.name()), Some("bc5"));
    }

    #[test]
    fn a_legacy_header_without_mips_is_kept() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("legacy.dds");
        let legacy = DdsFormat {
            dx10: false,
            mipmaps: false,
            ..format("dds-bc1")
        };
        write(&path, &image(3, 16), legacy, vec![]);
        assert_eq!(levels(&path).len(), 1);
        let bytes = std::fs::read(&path).unwrap();
        assert_eq!(&bytes[84..88], b"DXT1", "the DX9 FourCC");
        let read = read_image(&path, u64::MAX).unwrap();
        assert_eq!(
            read.format,
            FileFormat::Dds(DdsFormat {
                srgb: Some(false),
                ..legacy
            })
        );
        assert_eq!(read.map.channels(), 3, "an opaque BC1 reads as RGB");
    }

    #[test]
    fn cube_maps_and_damaged_files_are_refused_by_name() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("sky.dds");
        let header = Header::new_cube_map(4, 4, dds::Format::R8G8B8A8_UNORM);
        let mut encoder = Encoder::new(
            std::fs::File::create(&path).unwrap(),
            dds::Format::R8G8B8A8_UNORM,
            &header,
        )
        .unwrap();
        let face = vec![0u8; 4 * 4 * 4];
        for _ in 0..6 {
            let view = ImageView::new(&face, Size::new(4, 4), ColorFormat::RGBA_U8).unwrap();
            encoder.write_surface(view).unwrap();
        }
        encoder.finish().unwrap();
        let error = read_image(&path, u64::MAX).err().unwrap().to_string();
        assert!(
            error.contains("sky.dds") && error.contains("cube map"),
            "{error}"
        );

        let cut = dir.path().join("cut.dds");
        write_whole(&cut, &image(3, 16), FileFormat::Dds(format("dds-bc7"))).unwrap();
        let bytes = std::fs::read(&cut).unwrap();
        std::fs::write(&cut, &bytes[..bytes.len() / 2]).unwrap();
        let error = read_image(&cut, u64::MAX).err().unwrap().to_string();
        assert!(
            error.contains("cut.dds") && error.contains("cannot decode"),
            "{error}"
        );
    }

    #[test]
    fn a_loose_dx10_header_reads_as_what_it_means_and_says_so() {
        // Pillow writes BC5 normals with an array size of 0 and BC5_TYPELESS.
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("normal.dds");
        let normal = Stored::Normal(NormalConvention::OpenGl);
        let map = image(3, 16);
        write(&path, &map, format("dds-bc5"), vec![normal; 3]);
        let strict = read_image(&path, u64::MAX).unwrap();
        assert!(strict.notes.is_empty());
        let mut bytes = std::fs::read(&path).unwrap();
        assert_eq!(&bytes[FOURCC..FOURCC + 4], b"DX10");
        bytes[ARRAY_SIZE..ARRAY_SIZE + 4].copy_from_slice(&0u32.to_le_bytes());
        bytes[DXGI_FORMAT..DXGI_FORMAT + 4].copy_from_slice(&82u32.to_le_bytes());
        std::fs::write(&path, &bytes).unwrap();
        let loose = read_image(&path, u64::MAX).unwrap();
        assert!(loose.map == strict.map, "the same texture");
        assert_eq!(
            loose.notes,
            [
                "DX10 header's array size 0 read as 1 (one texture)",
                "DXGI format BC5_TYPELESS read as BC5_UNORM"
            ]
        );
        // An array of two is still refused, by the header's field.
        bytes[ARRAY_SIZE..ARRAY_SIZE + 4].copy_from_slice(&2u32.to_le_bytes());
        std::fs::write(&path, &bytes).unwrap();
        let e = read_image(&path, u64::MAX).err().unwrap().to_string();
        assert!(e.contains("a texture array"), "{e}");
    }
}
