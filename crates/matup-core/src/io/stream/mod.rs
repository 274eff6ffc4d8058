//! Image files written in bands of rows, top to bottom, so an output never has to be whole in
//! memory: PNG through the `png` crate's stream writer, EXR block by block through `exr`'s
//! block writer (on a thread of its own, because `exr` pulls the blocks from a closure while
//! matup pushes bands). JPEG, TGA, BMP, TIFF and DDS have no row-wise encoder among the chosen
//! crates (the `tiff` crate writes strips one by one, but compresses only whole images; a DDS mip
//! chain needs the whole top level): their samples are gathered at the file's bit depth (3 bytes a texel for 8-bit RGB) and encoded at
//! the end. Every file goes to a temporary file beside its path, renamed over it once complete.

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};
use std::sync::mpsc::{sync_channel, SyncSender};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;

use exr::block::writer::ChunksWriter;
use exr::prelude as ex;
use image::DynamicImage;
use rayon::prelude::*;
use tempfile::NamedTempFile;

use crate::color::to_u8;
use crate::layout::Stored;
use crate::map::Map;
use crate::material::{BlockQuality, FileFormat, SampleDepth};
use crate::{Error, Result};

mod encoders;
#[cfg(test)]
mod tests;

use encoders::{as_rgba, write_tga_rle, write_tiff, write_webp};

/// Writes one image file (grey or RGB, either with alpha as its last channel; values in the
/// file's encoding: [0, 1] for integer formats) band by band: [`ImageWriter::write_rows`] with every row once, in order, then
/// [`ImageWriter::finish`]. Dropped unfinished, it leaves nothing at `path`.
pub struct ImageWriter {
    path: PathBuf,
    width: usize,
    height: usize,
    channels: usize,
    format: FileFormat,
    hints: WriteHints,
    rows_written: usize,
    /// The file being written; `None` for an image kept in memory.
    temporary: Option<NamedTempFile>,
    encoder: Encoder,
}

/// An image an [`ImageWriter::in_memory`] gathered: its samples as its file would store them
/// before encoding (at the format's [`SampleDepth`], texel by texel).
#[derive(Clone, Debug, PartialEq)]
pub struct StoredImage {
    /// The file name it stands for.
    pub name: String,
    pub format: FileFormat,
    pub width: usize,
    pub height: usize,
    pub channels: usize,
    pub samples: Samples,
}

/// What formats that filter or compress a file need to know beyond its values: how each
/// channel is stored (a DDS mip chain averages sRGB colour in linear light and renormalises
/// normals; `dds` picks BC5 for normals) and how hard block encoders search.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct WriteHints {
    /// One a channel; missing ones are taken as [`Stored::Linear`].
    pub stored: Vec<Stored>,
    pub block_quality: BlockQuality,
}

enum Encoder {
    Png {
        stream: Option<Box<png::StreamWriter<'static, Recording>>>,
        sixteen_bits: bool,
        error: Arc<Mutex<Option<std::io::Error>>>,
    },
    /// JPEG, TGA, BMP, TIFF or DDS: samples gathered for an encoder of whole images.
    Gathered(Samples),
    Exr {
        bands: Option<SyncSender<Map>>,
        thread: Option<JoinHandle<std::result::Result<(), String>>>,
    },
}

/// Samples at a file's [`SampleDepth`]: interleaved where gathered for an encoder, one
/// channel's where handed to [`ImageWriter::write_channels`].
#[derive(Clone, Debug, PartialEq)]
pub enum Samples {
    U8(Vec<u8>),
    U16(Vec<u16>),
    F32(Vec<f32>),
}

impl Samples {
    pub fn len(&self) -> usize {
        match self {
            Samples::U8(s) => s.len(),
            Samples::U16(s) => s.len(),
            Samples::F32(s) => s.len(),
        }
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    pub fn depth(&self) -> SampleDepth {
        match self {
            Samples::U8(_) => SampleDepth::U8,
            Samples::U16(_) => SampleDepth::U16,
            Samples::F32(_) => SampleDepth::F32,
        }
    }
}

/// One channel's rows for [`ImageWriter::write_channels`].
pub enum ChannelRows<'a> {
    /// Values, to be stored as the writer's `encode` says.
    Values(&'a [f32]),
    /// Samples already stored at the file's depth.
    Stored(&'a Samples),
}

impl ChannelRows<'_> {
    fn len(&self) -> usize {
        match self {
            ChannelRows::Values(p) => p.len(),
            ChannelRows::Stored(s) => s.len(),
        }
    }

    /// The depth of stored samples (`None`: values).
    fn depth(&self) -> Option<SampleDepth> {
        match self {
            ChannelRows::Values(_) => None,
            ChannelRows::Stored(s) => Some(s.depth()),
        }
    }
}

/// The temporary file as the PNG encoder's output, keeping the first I/O error: the encoder
/// writes its last chunk when dropped, where it cannot report one.
struct Recording {
    file: File,
    error: Arc<Mutex<Option<std::io::Error>>>,
}

impl Write for Recording {
    fn write(&mut self, bytes: &[u8]) -> std::io::Result<usize> {
        self.file.write(bytes).inspect_err(|e| self.record(e))
    }
    fn flush(&mut self) -> std::io::Result<()> {
        self.file.flush().inspect_err(|e| self.record(e))
    }
}

impl Recording {
    fn record(&self, e: &std::io::Error) {
        let mut slot = self.error.lock().unwrap();
        if slot.is_none() {
            *slot = Some(std::io::Error::new(e.kind(), e.to_string()));
        }
    }
}

impl ImageWriter {
    /// Starts `path`, `width × height` texels of `channels` (grey, grey + alpha, RGB, RGBA) in
    /// `format`. JPEG holds no alpha: a file of 2 or 4 channels in it is refused.
    pub fn create(
        path: &Path,
        width: usize,
        height: usize,
        channels: usize,
        format: FileFormat,
    ) -> Result<ImageWriter> {
        Self::create_with(path, width, height, channels, format, WriteHints::default())
    }

    /// [`ImageWriter::create`] with what the format needs to know of the channels.
    pub fn create_with(
        path: &Path,
        width: usize,
        height: usize,
        channels: usize,
        format: FileFormat,
        hints: WriteHints,
    ) -> Result<ImageWriter> {
        Self::check(path, width, height, channels, format)?;
        let temporary = temporary_beside(path)?;
        let file = || {
            temporary
                .as_file()
                .try_clone()
                .map_err(|e| Error::io(path, e))
        };
        let encoder = match format {
            FileFormat::Png8 | FileFormat::Png16 => {
                let error = Arc::new(Mutex::new(None));
                let output = Recording {
                    file: file()?,
                    error: error.clone(),
                };
                let mut encoder = png::Encoder::new(output, width as u32, height as u32);
                encoder.set_color(match channels {
                    1 => png::ColorType::Grayscale,
                    2 => png::ColorType::GrayscaleAlpha,
                    3 => png::ColorType::Rgb,
                    _ => png::ColorType::Rgba,
                });
                let sixteen_bits = format == FileFormat::Png16;
                encoder.set_depth(if sixteen_bits {
                    png::BitDepth::Sixteen
                } else {
                    png::BitDepth::Eight
                });
                // As the image crate writes PNG: fast deflate, adaptive filters.
                encoder.set_compression(png::Compression::Fast);
                encoder.set_filter(png::Filter::Adaptive);
                let stream = encoder
                    .write_header()
                    .and_then(|w| w.into_stream_writer_with_size(1 << 20))
                    .map_err(|e| Error::file(path, e.to_string()))?;
                Encoder::Png {
                    stream: Some(Box::new(stream)),
                    sixteen_bits,
                    error,
                }
            }
            FileFormat::Jpeg
            | FileFormat::Tga
            | FileFormat::TgaRle
            | FileFormat::Bmp
            | FileFormat::Tiff8
            | FileFormat::WebpLossy
            | FileFormat::WebpLossless => {
                Encoder::Gathered(Samples::U8(Vec::with_capacity(width * height * channels)))
            }
            FileFormat::Tiff16 => {
                Encoder::Gathered(Samples::U16(Vec::with_capacity(width * height * channels)))
            }
            FileFormat::TiffFloat | FileFormat::Dds(_) => {
                Encoder::Gathered(Samples::F32(Vec::with_capacity(width * height * channels)))
            }
            FileFormat::ExrHalf | FileFormat::ExrFloat => {
                let (bands, receive) = sync_channel::<Map>(1);
                let output = BufWriter::new(file()?);
                let half = format == FileFormat::ExrHalf;
                let thread = std::thread::spawn(move || {
                    write_exr(output, width, height, channels, half, receive)
                });
                Encoder::Exr {
                    bands: Some(bands),
                    thread: Some(thread),
                }
            }
        };
        Ok(ImageWriter {
            path: path.to_path_buf(),
            width,
            height,
            channels,
            format,
            hints,
            rows_written: 0,
            temporary: Some(temporary),
            encoder,
        })
    }

    /// An image like the file [`ImageWriter::create_with`] writes, kept in memory: its samples
    /// (as the file stores them before a lossy or block format's encoding) come back from
    /// [`ImageWriter::into_stored`]. `path` names it.
    pub fn in_memory(
        path: &Path,
        width: usize,
        height: usize,
        channels: usize,
        format: FileFormat,
        hints: WriteHints,
    ) -> Result<ImageWriter> {
        Self::check(path, width, height, channels, format)?;
        let texels = width * height * channels;
        let samples = match format.sample_depth() {
            SampleDepth::U8 => Samples::U8(Vec::with_capacity(texels)),
            SampleDepth::U16 => Samples::U16(Vec::with_capacity(texels)),
            SampleDepth::F32 => Samples::F32(Vec::with_capacity(texels)),
        };
        Ok(ImageWriter {
            path: path.to_path_buf(),
            width,
            height,
            channels,
            format,
            hints,
            rows_written: 0,
            temporary: None,
            encoder: Encoder::Gathered(samples),
        })
    }

    /// Whether `format` holds an image of `width × height` texels of `channels`.
    fn check(
        path: &Path,
        width: usize,
        height: usize,
        channels: usize,
        format: FileFormat,
    ) -> Result<()> {
        if !(1..=4).contains(&channels) {
            return Err(Error::file(
                path,
                format!("{channels} channels: files hold grey or RGB, with or without alpha"),
            ));
        }
        check_side(path, format, width, height)?;
        if format == FileFormat::Jpeg && channels.is_multiple_of(2) {
            return Err(Error::file(
                path,
                "JPEG holds no alpha channel; write this map as PNG, TIFF, TGA or EXR (--format)",
            ));
        }
        Ok(())
    }

    /// The file it writes.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The format the file is written in.
    pub fn format(&self) -> FileFormat {
        self.format
    }

    /// Appends `rows` (as wide as the image, as many channels) below the rows written so far.
    pub fn write_rows(&mut self, rows: &Map) -> Result<()> {
        let planes: Vec<&[f32]> = (0..rows.channels()).map(|c| rows.plane(c)).collect();
        self.write_planes(&planes, |_, v| v)
    }

    /// Appends rows given as one plane a channel (each a whole number of rows as wide as the
    /// image), each value stored as `encode(channel, value)`.
    pub fn write_planes(
        &mut self,
        planes: &[&[f32]],
        encode: impl Fn(usize, f32) -> f32 + Sync,
    ) -> Result<()> {
        let channels: Vec<ChannelRows> = planes.iter().map(|p| ChannelRows::Values(p)).collect();
        self.write_channels(&channels, encode)
    }

    /// [`ImageWriter::write_planes`] where some channels come as samples already stored at
    /// the file's [`SampleDepth`] (encoded where the maps are: a GPU's memory), taken as they
    /// are; `encode` stores the others.
    pub fn write_channels(
        &mut self,
        channels: &[ChannelRows],
        encode: impl Fn(usize, f32) -> f32 + Sync,
    ) -> Result<()> {
        let lengths: Vec<usize> = channels.iter().map(ChannelRows::len).collect();
        let rows = lengths.first().map_or(0, |n| n / self.width.max(1));
        if channels.len() != self.channels
            || lengths.iter().any(|&n| n != rows * self.width)
            || self.rows_written + rows > self.height
        {
            return Err(Error::file(
                &self.path,
                format!(
                    "rows that do not fit the file ({} planes of {lengths:?} values for {} \
                     channels of {}×{}, {} rows written)",
                    channels.len(),
                    self.channels,
                    self.width,
                    self.height,
                    self.rows_written
                ),
            ));
        }
        let depth = self.format.sample_depth();
        if let Some(other) = (channels.iter()).find_map(|c| c.depth().filter(|&d| d != depth)) {
            return Err(Error::file(
                &self.path,
                format!("samples of {other:?} for a file of {depth:?} samples"),
            ));
        }
        self.rows_written += rows;
        let w = self.width;
        // Each sample at the file's depth: stored ones as they come, values encoded.
        let u8_at = |c: usize, i: usize| match &channels[c] {
            ChannelRows::Values(p) => to_u8(encode(c, p[i])),
            ChannelRows::Stored(Samples::U8(s)) => s[i],
            ChannelRows::Stored(_) => unreachable!("depths checked"),
        };
        let u16_at = |c: usize, i: usize| match &channels[c] {
            ChannelRows::Values(p) => to_u16(encode(c, p[i])),
            ChannelRows::Stored(Samples::U16(s)) => s[i],
            ChannelRows::Stored(_) => unreachable!("depths checked"),
        };
        let f32_at = |c: usize, i: usize| match &channels[c] {
            ChannelRows::Values(p) => encode(c, p[i]),
            ChannelRows::Stored(Samples::F32(s)) => s[i],
            ChannelRows::Stored(_) => unreachable!("depths checked"),
        };
        let n = channels.len();
        match &mut self.encoder {
            Encoder::Png {
                stream,
                sixteen_bits,
                ..
            } => {
                let bytes: Vec<u8> = if *sixteen_bits {
                    interleaved(n, rows, w, |c, i| u16_at(c, i).to_be_bytes()).into_flattened()
                } else {
                    interleaved(n, rows, w, u8_at)
                };
                let stream = stream.as_mut().expect("open until finished");
                stream
                    .write_all(&bytes)
                    .map_err(|e| Error::io(&self.path, e))
            }
            Encoder::Gathered(samples) => {
                match samples {
                    Samples::U8(s) => s.append(&mut interleaved(n, rows, w, u8_at)),
                    Samples::U16(s) => s.append(&mut interleaved(n, rows, w, u16_at)),
                    Samples::F32(s) => s.append(&mut interleaved(n, rows, w, f32_at)),
                }
                Ok(())
            }
            Encoder::Exr { bands, .. } => {
                let data: Vec<f32> = (0..n)
                    .flat_map(|c| (0..rows * w).map(move |i| (c, i)))
                    .map(|(c, i)| f32_at(c, i))
                    .collect();
                let band = Map::from_planar(w, rows, n, data);
                let sent = bands.as_ref().expect("open until finished").send(band);
                // The writer thread stopped early: its error comes with `finish`.
                if sent.is_err() {
                    return self.exr_error();
                }
                Ok(())
            }
        }
    }

    /// Every row must have been written.
    fn check_complete(&self) -> Result<()> {
        if self.rows_written != self.height {
            return Err(Error::file(
                &self.path,
                format!(
                    "{} of {} rows were written; the file is incomplete",
                    self.rows_written, self.height
                ),
            ));
        }
        Ok(())
    }

    /// The samples of an image made by [`ImageWriter::in_memory`] (every row written).
    pub fn into_stored(self) -> Result<StoredImage> {
        self.check_complete()?;
        match (self.temporary, self.encoder) {
            (None, Encoder::Gathered(samples)) => Ok(StoredImage {
                name: super::file_name(&self.path),
                format: self.format,
                width: self.width,
                height: self.height,
                channels: self.channels,
                samples,
            }),
            _ => Err(Error::file(
                &self.path,
                "written to a file, not kept in memory: ImageWriter::finish completes it",
            )),
        }
    }

    /// Completes the file (every row must have been written) and moves it to its path.
    pub fn finish(mut self) -> Result<PathBuf> {
        self.check_complete()?;
        let Some(temporary) = self.temporary.take() else {
            return Err(Error::file(
                &self.path,
                "kept in memory, not written to a file: ImageWriter::into_stored gives it",
            ));
        };
        match &mut self.encoder {
            Encoder::Png { stream, error, .. } => {
                let stream = stream.take().expect("open until finished");
                stream
                    .finish()
                    .map_err(|e| Error::file(&self.path, e.to_string()))?;
                // The end chunk was written as the encoder dropped: any failure was recorded.
                if let Some(e) = error.lock().unwrap().take() {
                    return Err(Error::io(&self.path, e));
                }
            }
            Encoder::Gathered(samples) => {
                let samples = std::mem::replace(samples, Samples::U8(Vec::new()));
                let mut out = BufWriter::new(
                    temporary
                        .as_file()
                        .try_clone()
                        .map_err(|e| Error::io(&self.path, e))?,
                );
                encode_whole(
                    &mut out,
                    self.width,
                    self.height,
                    self.channels,
                    self.format,
                    samples,
                    &self.hints,
                )
                .map_err(|e| Error::file(&self.path, e))?;
                out.flush().map_err(|e| Error::io(&self.path, e))?;
            }
            Encoder::Exr { bands, .. } => {
                drop(bands.take());
                self.exr_error()?;
            }
        }
        let path = self.path.clone();
        persist(temporary, &path)?;
        Ok(path)
    }

    /// Joins the EXR thread and returns what it failed with.
    fn exr_error(&mut self) -> Result<()> {
        if let Encoder::Exr { bands, thread } = &mut self.encoder {
            drop(bands.take());
            if let Some(thread) = thread.take() {
                let outcome = thread
                    .join()
                    .unwrap_or_else(|_| Err("the EXR writer panicked".into()));
                outcome.map_err(|message| Error::file(&self.path, message))?;
            }
        }
        Ok(())
    }
}

/// The EXR writer thread: a scan-line file (ZIP, 16 lines per block, increasing order, as
/// `exr`'s SMALL_LOSSLESS), each block built from the bands as they arrive.
fn write_exr(
    output: BufWriter<File>,
    width: usize,
    height: usize,
    channels: usize,
    half: bool,
    bands: std::sync::mpsc::Receiver<Map>,
) -> std::result::Result<(), String> {
    // The file's channels are sorted by name; `plane[i]` is the map's channel for the i-th.
    let (names, plane): (&[&str], &[usize]) = match channels {
        1 => (&["Y"], &[0]),
        2 => (&["A", "Y"], &[1, 0]),
        3 => (&["B", "G", "R"], &[2, 1, 0]),
        _ => (&["A", "B", "G", "R"], &[3, 2, 1, 0]),
    };
    let sample_type = if half {
        ex::SampleType::F16
    } else {
        ex::SampleType::F32
    };
    let list: ex::SmallVec<[ex::ChannelDescription; 5]> = names
        .iter()
        .map(|n| ex::ChannelDescription::named(*n, sample_type))
        .collect();
    let header = exr::meta::header::Header::new("".into(), (width, height), list).with_encoding(
        ex::Compression::ZIP16,
        exr::meta::BlockDescription::ScanLines,
        ex::LineOrder::Increasing,
    );
    let mut header = header;
    header.own_attributes.layer_name = None; // one layer: no name, as exr writes one
    let channel_list = header.channels.clone();
    let mut band: Option<Map> = None;
    let mut band_first = 0usize;
    exr::block::write(
        output,
        ex::SmallVec::from_elem(header, 1),
        true,
        |meta, chunks| {
            let mut compressor = chunks.sequential_blocks_compressor(&meta);
            let blocks: Vec<_> = meta.enumerate_ordered_header_block_indices().collect();
            for (index, block_index) in blocks {
                let mut failed = None;
                let block =
                    exr::block::UncompressedBlock::from_lines(&channel_list, block_index, |line| {
                        let y = line.location.position.y();
                        // Bands arrive in order; a line below the current band needs the next.
                        while band.as_ref().is_none_or(|b| y >= band_first + b.height()) {
                            if let Some(b) = band.take() {
                                band_first += b.height();
                            }
                            match bands.recv() {
                                Ok(next) => band = Some(next),
                                Err(_) => {
                                    failed = Some("the rows ended before the image");
                                    return;
                                }
                            }
                        }
                        let b = band.as_ref().unwrap();
                        let x0 = line.location.position.x();
                        let row = &b.plane(plane[line.location.channel])
                            [(y - band_first) * width + x0..][..line.location.sample_count];
                        let written = if half {
                            line.write_samples(|i| ex::f16::from_f32(row[i]))
                        } else {
                            line.write_samples(|i| row[i])
                        };
                        if written.is_err() {
                            failed = Some("a line could not be encoded");
                        }
                    });
                if let Some(why) = failed {
                    return Err(exr::error::Error::Invalid(why.into()));
                }
                compressor.compress_block(index, block)?;
            }
            Ok(())
        },
    )
    .map_err(|e| e.to_string())
}

/// Encodes a whole image of gathered samples: JPEG (quality 95), TGA, BMP or WebP from 8-bit
/// samples, TIFF (LZW, as image editors write it) at its depth, DDS from floats. The `tiff`
/// crate writes no grey + alpha, so such a TIFF (and a BMP or TGA) is written RGBA with the
/// grey in all three colour channels.
fn encode_whole(
    out: &mut BufWriter<File>,
    width: usize,
    height: usize,
    channels: usize,
    format: FileFormat,
    samples: Samples,
    hints: &WriteHints,
) -> std::result::Result<(), String> {
    use tiff::encoder::colortype::*;
    let (w, h) = (width as u32, height as u32);
    let written = match (format, samples) {
        (FileFormat::Tiff8, Samples::U8(raw)) => match channels {
            1 => write_tiff::<Gray8>(out, w, h, &raw),
            3 => write_tiff::<RGB8>(out, w, h, &raw),
            _ => write_tiff::<RGBA8>(out, w, h, &as_rgba(channels, raw)),
        },
        (FileFormat::Tiff16, Samples::U16(raw)) => match channels {
            1 => write_tiff::<Gray16>(out, w, h, &raw),
            3 => write_tiff::<RGB16>(out, w, h, &raw),
            _ => write_tiff::<RGBA16>(out, w, h, &as_rgba(channels, raw)),
        },
        (FileFormat::TiffFloat, Samples::F32(raw)) => match channels {
            1 => write_tiff::<Gray32Float>(out, w, h, &raw),
            3 => write_tiff::<RGB32Float>(out, w, h, &raw),
            _ => write_tiff::<RGBA32Float>(out, w, h, &as_rgba(channels, raw)),
        },
        (FileFormat::Dds(dds), Samples::F32(raw)) => {
            return super::dds_file::write_dds(
                out,
                width,
                height,
                channels,
                raw,
                dds,
                &hints.stored,
                hints.block_quality,
            );
        }
        (
            FileFormat::Jpeg | FileFormat::Tga | FileFormat::TgaRle | FileFormat::Bmp,
            Samples::U8(raw),
        ) => {
            // Grey + alpha goes as RGBA: the image crate's BMP encoder drops grey's alpha,
            // and a 16-bit grey TGA, though TGA 2.0 allows it, is read as grey alone and wrong
            // by ImageMagick 6 and by importers that take 8-bit grey only.
            let (channels, raw) = match (format, channels) {
                (FileFormat::Bmp | FileFormat::Tga | FileFormat::TgaRle, 2) => (4, as_rgba(2, raw)),
                _ => (channels, raw),
            };
            let image = match channels {
                1 => DynamicImage::ImageLuma8(image::GrayImage::from_raw(w, h, raw).unwrap()),
                2 => DynamicImage::ImageLumaA8(image::GrayAlphaImage::from_raw(w, h, raw).unwrap()),
                3 => DynamicImage::ImageRgb8(image::RgbImage::from_raw(w, h, raw).unwrap()),
                _ => DynamicImage::ImageRgba8(image::RgbaImage::from_raw(w, h, raw).unwrap()),
            };
            return match format {
                FileFormat::Tga => {
                    let tga = image::codecs::tga::TgaEncoder::new(out).disable_rle();
                    image.write_with_encoder(tga)
                }
                FileFormat::TgaRle => write_tga_rle(out, &image),
                FileFormat::Bmp => {
                    image.write_with_encoder(image::codecs::bmp::BmpEncoder::new(out))
                }
                _ => {
                    let jpeg = image::codecs::jpeg::JpegEncoder::new_with_quality(out, 95);
                    image.write_with_encoder(jpeg)
                }
            }
            .map_err(|e| e.to_string());
        }
        (FileFormat::WebpLossy | FileFormat::WebpLossless, Samples::U8(raw)) => {
            let lossless = format == FileFormat::WebpLossless;
            return write_webp(out, w, h, channels, raw, lossless);
        }
        _ => unreachable!("ImageWriter::create gathers each format at its own depth"),
    };
    written.map_err(|e| e.to_string())
}

/// Refuses a `width`×`height` image in a format whose sides are shorter, naming `path`.
pub(crate) fn check_side(
    path: &Path,
    format: FileFormat,
    width: usize,
    height: usize,
) -> Result<()> {
    match format.max_side() {
        Some(most) if width.max(height) > most => Err(Error::file(
            path,
            format!(
                "{width}×{height} is larger than {format} holds (at most {most} texels a side); \
                 write it as PNG, TIFF or EXR (--format)"
            ),
        )),
        _ => Ok(()),
    }
}

/// A temporary file in `path`'s folder (so the rename that completes it stays on one disk).
pub(crate) fn temporary_beside(path: &Path) -> Result<NamedTempFile> {
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    tempfile::Builder::new()
        .prefix(".matup-")
        .suffix(".tmp")
        .tempfile_in(dir)
        .map_err(|e| Error::io(path, e))
}

/// Syncs the temporary file and renames it over `path` (readers see the old file or the
/// whole new one); outputs get ordinary permissions, not a temporary file's 0600.
pub(crate) fn persist(temporary: NamedTempFile, path: &Path) -> Result<()> {
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        temporary
            .as_file()
            .set_permissions(std::fs::Permissions::from_mode(0o644))
            .map_err(|e| Error::io(path, e))?;
    }
    temporary
        .as_file()
        .sync_all()
        .map_err(|e| Error::io(path, e))?;
    temporary
        .persist(path)
        .map_err(|e| Error::io(path, e.error))?;
    Ok(())
}

/// `rows` rows `width` wide of `channels` channels, each sample `sample(channel, index in
/// its plane)`, interleaved texel by texel (as files store them), a row a task on rayon's
/// threads.
pub(crate) fn interleaved<T: Copy + Default + Send>(
    channels: usize,
    rows: usize,
    width: usize,
    sample: impl Fn(usize, usize) -> T + Sync,
) -> Vec<T> {
    let mut out = vec![T::default(); rows * width * channels];
    out.par_chunks_mut((width * channels).max(1))
        .enumerate()
        .for_each(|(y, row)| {
            for (x, texel) in row.chunks_exact_mut(channels).enumerate() {
                for (c, value) in texel.iter_mut().enumerate() {
                    *value = sample(c, y * width + x);
                }
            }
        });
    out
}

/// A [0, 1] value as a 16-bit sample (rounded, clamped).
fn to_u16(v: f32) -> u16 {
    (v.clamp(0.0, 1.0) * 65535.0).round() as u16
}

/// Writes a whole image: one band.
pub(crate) fn write_whole(path: &Path, map: &Map, format: FileFormat) -> Result<()> {
    let mut writer = ImageWriter::create(path, map.width(), map.height(), map.channels(), format)?;
    writer.write_rows(map)?;
    writer.finish()?;
    Ok(())
}
