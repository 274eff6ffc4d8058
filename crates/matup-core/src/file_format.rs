//! The image file formats matup reads and writes, with their bit depths and, for DDS, the
//! block codecs and their quality.

use std::fmt;
use std::str::FromStr;

use crate::{Error, Result};

/// An image file format and bit depth.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum FileFormat {
    Png8,
    Png16,
    Jpeg,
    ExrHalf,
    ExrFloat,
    Tiff8,
    Tiff16,
    /// 32-bit float TIFF: linear values, as EXR.
    TiffFloat,
    /// 8-bit TGA (game engines' format), uncompressed.
    Tga,
    /// 8-bit TGA, run-length encoded, each scanline's packets its own (TGA 2.0).
    TgaRle,
    /// 8-bit BMP (older games' format).
    Bmp,
    /// Lossy WebP (the web's format; glTF's `EXT_texture_webp`), 8-bit, alpha kept losslessly.
    WebpLossy,
    /// Lossless WebP, 8-bit.
    WebpLossless,
    /// DirectDraw Surface: block-compressed (BC1–BC7) or uncompressed, with or without mips.
    Dds(DdsFormat),
}

/// How a DDS file stores its texture: the surface format, the header's sRGB flag, which header
/// it has and whether it carries a mip chain. Read from a file, it is written back the same.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct DdsFormat {
    /// The surface format; `None` chooses one a file when written: BC5 for normals, BC4 for
    /// one channel, BC7 otherwise.
    pub codec: Option<DdsCodec>,
    /// Whether the header marks the texture sRGB; `None`: where its colour is sRGB-encoded.
    pub srgb: Option<bool>,
    /// A DX10 header (the only one BC7 and sRGB have); else the legacy DX9 one.
    pub dx10: bool,
    /// A full mip chain, made from the written map.
    pub mipmaps: bool,
}

/// The DDS surface formats matup reads and writes back: the block formats BC1–BC5 and BC7 and
/// the common uncompressed ones. Each row: its name for `--format dds-NAME`, the format, the
/// channels its texture holds (two for the normal formats, whose z is rebuilt), whether it
/// stores floats.
pub const DDS_CODECS: [(&str, DdsCodec, usize, bool); 24] = {
    use dds::Format as F;
    [
        ("bc1", DdsCodec(F::BC1_UNORM), 4, false),
        ("bc2", DdsCodec(F::BC2_UNORM), 4, false),
        ("bc3", DdsCodec(F::BC3_UNORM), 4, false),
        ("bc4", DdsCodec(F::BC4_UNORM), 1, false),
        ("bc5", DdsCodec(F::BC5_UNORM), 2, false),
        ("bc7", DdsCodec(F::BC7_UNORM), 4, false),
        ("rgba8", DdsCodec(F::R8G8B8A8_UNORM), 4, false),
        ("bgra8", DdsCodec(F::B8G8R8A8_UNORM), 4, false),
        ("bgrx8", DdsCodec(F::B8G8R8X8_UNORM), 3, false),
        ("rgb8", DdsCodec(F::R8G8B8_UNORM), 3, false),
        ("bgr8", DdsCodec(F::B8G8R8_UNORM), 3, false),
        ("r8", DdsCodec(F::R8_UNORM), 1, false),
        ("rg8", DdsCodec(F::R8G8_UNORM), 2, false),
        ("r16", DdsCodec(F::R16_UNORM), 1, false),
        ("rg16", DdsCodec(F::R16G16_UNORM), 2, false),
        ("rgba16", DdsCodec(F::R16G16B16A16_UNORM), 4, false),
        ("b5g6r5", DdsCodec(F::B5G6R5_UNORM), 3, false),
        ("bgr5a1", DdsCodec(F::B5G5R5A1_UNORM), 4, false),
        ("bgra4", DdsCodec(F::B4G4R4A4_UNORM), 4, false),
        ("rgb10a2", DdsCodec(F::R10G10B10A2_UNORM), 4, false),
        ("r16f", DdsCodec(F::R16_FLOAT), 1, true),
        ("rgba16f", DdsCodec(F::R16G16B16A16_FLOAT), 4, true),
        ("r32f", DdsCodec(F::R32_FLOAT), 1, true),
        ("rgba32f", DdsCodec(F::R32G32B32A32_FLOAT), 4, true),
    ]
};

/// A DDS surface format matup reads and writes (a row of [`DDS_CODECS`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct DdsCodec(pub dds::Format);

impl DdsCodec {
    fn row(self) -> &'static (&'static str, DdsCodec, usize, bool) {
        (DDS_CODECS.iter())
            .find(|row| row.1 == self)
            .expect("a DdsCodec is a row of DDS_CODECS")
    }

    /// The codec of `format`, if matup reads and writes it.
    pub fn of(format: dds::Format) -> Option<DdsCodec> {
        (DDS_CODECS.iter())
            .find(|row| row.1 .0 == format)
            .map(|row| row.1)
    }

    /// The codec `--format dds-NAME` names.
    pub fn named(name: &str) -> Option<DdsCodec> {
        (DDS_CODECS.iter())
            .find(|row| row.0 == name)
            .map(|row| row.1)
    }

    pub fn name(self) -> &'static str {
        self.row().0
    }

    /// The channels a texture of this format holds: 1, 2 (x and y of a normal), 3 or 4.
    pub fn channels(self) -> usize {
        self.row().2
    }

    pub fn is_float(self) -> bool {
        self.row().3
    }

    /// "BC1 blocks" for the block formats that lose what their blocks cannot hold (BC1–BC5;
    /// BC7 keeps maps within a level or two); `None` for the others.
    pub fn lossy_storage(self) -> Option<String> {
        let name = self.name();
        ["bc1", "bc2", "bc3", "bc4", "bc5"]
            .contains(&name)
            .then(|| format!("{} blocks", name.to_uppercase()))
    }
}

/// How hard the block encoders (BC1–BC7) search: slower is closer to the uncompressed map.
#[derive(
    Clone, Copy, Debug, Default, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize,
)]
#[serde(rename_all = "lowercase")]
pub enum BlockQuality {
    Fast,
    #[default]
    Normal,
    High,
    /// The most thorough search (BC7 at several times `high`'s time).
    Max,
}

serde_plain::derive_display_from_serialize!(BlockQuality);
serde_plain::derive_fromstr_from_deserialize!(BlockQuality, |e| -> Error {
    Error::Invalid(format!("block quality: {e}; use fast, normal, high or max"))
});

/// The type of a file's samples as matup hands them to its encoder: integers of 8 or 16 bits
/// (values in [0, 1] scaled, rounded), or floats (EXR, float TIFF, and DDS, whose encoder
/// takes values and makes its mips and blocks from them).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SampleDepth {
    U8,
    U16,
    F32,
}

impl FileFormat {
    /// What lossy storage in this format did to a map's texels, where it was lossy: "JPEG",
    /// "lossy WebP", "BC1 blocks" ([`DdsCodec::lossy_storage`]). `None` for lossless files.
    pub fn lossy_storage(self) -> Option<String> {
        match self {
            FileFormat::Jpeg => Some("JPEG".into()),
            FileFormat::WebpLossy => Some("lossy WebP".into()),
            FileFormat::Dds(DdsFormat {
                codec: Some(codec), ..
            }) => codec.lossy_storage(),
            _ => None,
        }
    }

    /// Whether a lossy storage as [`FileFormat::lossy_storage`] words it ("JPEG
    /// (albedo.jpg)", "JPEG (simulated: jpeg75)": a [`crate::Material::lossy`] entry) was a
    /// JPEG.
    pub fn is_jpeg_storage(storage: &str) -> bool {
        storage.split(" (").next() == FileFormat::Jpeg.lossy_storage().as_deref()
    }

    /// The type of the samples the file's encoder takes.
    pub fn sample_depth(self) -> SampleDepth {
        match self {
            FileFormat::Png8
            | FileFormat::Jpeg
            | FileFormat::Tiff8
            | FileFormat::Tga
            | FileFormat::TgaRle
            | FileFormat::Bmp
            | FileFormat::WebpLossy
            | FileFormat::WebpLossless => SampleDepth::U8,
            FileFormat::Png16 | FileFormat::Tiff16 => SampleDepth::U16,
            FileFormat::ExrHalf | FileFormat::ExrFloat | FileFormat::TiffFloat => SampleDepth::F32,
            FileFormat::Dds(_) => SampleDepth::F32,
        }
    }

    pub fn extension(self) -> &'static str {
        match self {
            FileFormat::Png8 | FileFormat::Png16 => "png",
            FileFormat::Jpeg => "jpg",
            FileFormat::ExrHalf | FileFormat::ExrFloat => "exr",
            FileFormat::Tiff8 | FileFormat::Tiff16 | FileFormat::TiffFloat => "tif",
            FileFormat::Tga | FileFormat::TgaRle => "tga",
            FileFormat::Bmp => "bmp",
            FileFormat::WebpLossy | FileFormat::WebpLossless => "webp",
            FileFormat::Dds(_) => "dds",
        }
    }

    /// The extension a file of this format is written with: `source`'s own, spelling and case
    /// kept (`.tiff`, `.TGA`, `.jpeg`), where it names this format; else [`Self::extension`].
    pub fn extension_as(self, source: Option<&std::path::Path>) -> String {
        let own = source
            .and_then(|p| p.extension())
            .and_then(|e| e.to_str())
            .filter(|e| {
                let lower = e.to_ascii_lowercase();
                let canonical = match lower.as_str() {
                    "jpeg" => "jpg",
                    "tiff" => "tif",
                    other => other,
                };
                canonical == self.extension()
            });
        own.unwrap_or(self.extension()).to_string()
    }

    /// The longest side the format can store, for the formats that limit it below sizes matup
    /// makes: WebP stores each side in 14 bits, JPEG and TGA in 16. BMP stores its file's size
    /// in 32 bits, which 32767² texels of RGBA still fit.
    pub fn max_side(self) -> Option<usize> {
        match self {
            FileFormat::WebpLossy | FileFormat::WebpLossless => Some(16383),
            FileFormat::Bmp => Some(32767),
            FileFormat::Jpeg | FileFormat::Tga | FileFormat::TgaRle => Some(65535),
            _ => None,
        }
    }

    /// Whether values are stored linearly as floats (EXR, float TIFF) rather than
    /// display-encoded integers.
    pub fn is_float(self) -> bool {
        matches!(
            self,
            FileFormat::ExrHalf | FileFormat::ExrFloat | FileFormat::TiffFloat
        ) || matches!(self, FileFormat::Dds(DdsFormat { codec: Some(c), .. }) if c.is_float())
    }
}

impl FromStr for FileFormat {
    type Err = Error;
    fn from_str(s: &str) -> Result<Self> {
        match s.to_ascii_lowercase().as_str() {
            "png" | "png8" => Ok(FileFormat::Png8),
            "png16" => Ok(FileFormat::Png16),
            "jpg" | "jpeg" => Ok(FileFormat::Jpeg),
            "exr" | "exr-half" | "exr16" => Ok(FileFormat::ExrHalf),
            "exr-float" | "exr32" => Ok(FileFormat::ExrFloat),
            "tif" | "tiff" | "tiff8" => Ok(FileFormat::Tiff8),
            "tiff16" => Ok(FileFormat::Tiff16),
            "tiff-float" | "tiff32" => Ok(FileFormat::TiffFloat),
            "tga" => Ok(FileFormat::Tga),
            "tga-rle" => Ok(FileFormat::TgaRle),
            "bmp" => Ok(FileFormat::Bmp),
            "webp" => Ok(FileFormat::WebpLossy),
            "webp-lossless" => Ok(FileFormat::WebpLossless),
            // A chosen DDS format has the DX10 header and a full mip chain, as engines load.
            "dds" => Ok(FileFormat::Dds(DdsFormat {
                codec: None,
                srgb: None,
                dx10: true,
                mipmaps: true,
            })),
            name => match name.strip_prefix("dds-").and_then(DdsCodec::named) {
                Some(codec) => Ok(FileFormat::Dds(DdsFormat {
                    codec: Some(codec),
                    srgb: None,
                    dx10: true,
                    mipmaps: true,
                })),
                None => Err(Error::Invalid(format!(
                    "unknown format '{s}'; use png, png16, jpg, exr-half, exr-float, tiff, \
                     tiff16, tiff-float, tga, bmp, webp, webp-lossless, dds (BC7, BC5 for normals, \
                     BC4 for one channel) or dds-FORMAT ({})",
                    DDS_CODECS.map(|row| row.0).join(", ")
                ))),
            },
        }
    }
}

impl fmt::Display for FileFormat {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            FileFormat::Png8 => "png",
            FileFormat::Png16 => "png16",
            FileFormat::Jpeg => "jpg",
            FileFormat::ExrHalf => "exr-half",
            FileFormat::ExrFloat => "exr-float",
            FileFormat::Tiff8 => "tiff",
            FileFormat::Tiff16 => "tiff16",
            FileFormat::TiffFloat => "tiff-float",
            FileFormat::Tga => "tga",
            FileFormat::TgaRle => "tga-rle",
            FileFormat::Bmp => "bmp",
            FileFormat::WebpLossy => "webp",
            FileFormat::WebpLossless => "webp-lossless",
            FileFormat::Dds(DdsFormat { codec: None, .. }) => "dds",
            FileFormat::Dds(DdsFormat { codec: Some(c), .. }) => {
                return write!(f, "dds-{}", c.name())
            }
        })
    }
}
