//! Writing a material's files a band of rows at a time, each file through its layout: the
//! input's own layout (every file under its name, with its channels, formats and storage), or
//! matup's (one file a map).

use std::path::{Path, PathBuf};

use candle_core::Tensor;
use rayon::prelude::*;

use super::read::file_stem;
use super::stream::{ChannelRows, ImageWriter, Samples, StoredImage, WriteHints};
use crate::device_maps::stored_samples;
use crate::layout::{Channel, Holds, Stored};
use crate::material::{
    BlockQuality, FileFormat, MapKind, Material, MaterialOrigin, NormalConvention,
};
use crate::output_band::OutputBand;
use crate::{Error, Result};

/// How to save a material.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SaveOptions {
    /// Format of every map; by default each map keeps the format it was loaded from (PNG 8-bit
    /// for maps with no source).
    pub format: Option<FileFormat>,
    /// Convention of the written normal map; by default the input's.
    pub normal_convention: Option<NormalConvention>,
    /// The names the maps are written under.
    pub names: Names,
    /// How hard DDS files' block encoders search.
    pub block_quality: BlockQuality,
}

/// The names a material's maps are written under.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Names {
    /// The input's own file names (a resolution tag such as `_1K` rewritten to the output's
    /// size), so the output folder drops in where the input was, as per-map upscalers do; a
    /// packed occlusion/roughness/metallic file comes back packed, a gloss map as gloss.
    #[default]
    Keep,
    /// matup's: `baseColor`, `normal`, `roughness`, `metallic`, `height` (packed and gloss
    /// inputs unpacked and converted); other maps keep theirs.
    Matup,
}

serde_plain::derive_display_from_serialize!(Names);
serde_plain::derive_fromstr_from_deserialize!(Names, |e| -> Error {
    Error::Invalid(format!("names: {e}"))
});

/// Writes a material's maps a band of rows at a time, top to bottom, as [`super::save_material`]
/// writes a whole one (which is one band): the same files, formats and encodings, for outputs
/// that are never whole in memory. The files appear when [`MaterialWriter::finish`] completes
/// them; dropped before, it leaves none.
pub struct MaterialWriter {
    out_dir: PathBuf,
    size: [usize; 2],
    origin: Option<MaterialOrigin>,
    options: SaveOptions,
    /// Opened with the first band, which says what maps there are.
    files: Vec<FileWriter>,
    /// Files another writer wrote into the folder, which this one must not overwrite.
    taken: Vec<PathBuf>,
    /// The files are kept in memory ([`MaterialWriter::in_memory`]), not written.
    in_memory: bool,
}

/// A file to write: what each channel holds and how it is stored.
struct PlannedFile {
    stem: String,
    format: FileFormat,
    /// The file it comes back as, whose extension's spelling (`.tiff`, `.TGA`, `.jpeg`) the
    /// output keeps where it writes the same format.
    source: Option<PathBuf>,
    channels: Vec<Channel>,
    /// A map the input did not have is written only if it differs from its stand-in.
    stand_in: Option<(MapKind, &'static [f32])>,
}

struct FileWriter {
    channels: Vec<Channel>,
    file: ImageWriter,
    stand_in: Option<(MapKind, &'static [f32])>,
    all_stand_in: bool,
}

const TWO_FILES_IN_ONE: &str = "two of the input's files would be written to this file; rename \
                                one, or use matup's names (--names matup)";

impl MaterialWriter {
    /// For a material of `size` ([width, height]) from `origin` (whose layout, formats, names
    /// and normal convention it keeps unless `options` say otherwise) into `out_dir` (created;
    /// never the input folder nor inside it).
    pub fn new(
        out_dir: &Path,
        size: [usize; 2],
        origin: Option<&MaterialOrigin>,
        options: &SaveOptions,
    ) -> Result<MaterialWriter> {
        check_output_folder(out_dir, origin)?;
        Self::check_sizes(out_dir, size, origin, options)?;
        std::fs::create_dir_all(out_dir).map_err(|e| Error::io(out_dir, e))?;
        Ok(MaterialWriter {
            out_dir: out_dir.to_path_buf(),
            size,
            origin: origin.cloned(),
            options: options.clone(),
            files: Vec::new(),
            taken: Vec::new(),
            in_memory: false,
        })
    }

    /// [`MaterialWriter::new`]'s files kept in memory, under their names alone: what each
    /// would store, before a lossy or block format's encoding, comes back from
    /// [`MaterialWriter::finish_in_memory`].
    pub fn in_memory(
        size: [usize; 2],
        origin: Option<&MaterialOrigin>,
        options: &SaveOptions,
    ) -> Result<MaterialWriter> {
        let names = PathBuf::new();
        Self::check_sizes(&names, size, origin, options)?;
        Ok(MaterialWriter {
            out_dir: names,
            size,
            origin: origin.cloned(),
            options: options.clone(),
            files: Vec::new(),
            taken: Vec::new(),
            in_memory: true,
        })
    }

    /// A size the files' formats cannot hold is refused before any work, not when the first
    /// band is written.
    fn check_sizes(
        out_dir: &Path,
        [w, h]: [usize; 2],
        origin: Option<&MaterialOrigin>,
        options: &SaveOptions,
    ) -> Result<()> {
        match options.format {
            Some(format) => super::stream::check_side(out_dir, format, w, h),
            None => (origin.map_or(&[][..], |o| o.layout.as_slice()).iter())
                .try_for_each(|file| super::stream::check_side(&file.path, file.format, w, h)),
        }
    }

    /// The writer, refusing to write any of `taken` (another material's files in the same
    /// folder; checked as it finishes, since a stand-in map may go unwritten).
    pub fn beside(mut self, taken: &[PathBuf]) -> MaterialWriter {
        self.taken = taken.to_vec();
        self
    }

    /// Appends `band`'s rows (every map, as wide as the material) below those written so far.
    pub fn write_rows(&mut self, band: &Material) -> Result<()> {
        self.write(band, &[])
    }

    /// [`MaterialWriter::write_rows`] of a band whose maps may be held on a device: those are
    /// encoded into the files' samples there, and only the samples come back.
    pub fn write_band(&mut self, band: &OutputBand) -> Result<()> {
        let (material, on_device) = band.parts();
        self.write(material, on_device)
    }

    /// The rows of `band`, but the maps of `on_device`, which are held there (`band`'s maps
    /// of their kinds are placeholders that give their channels).
    fn write(&mut self, band: &Material, on_device: &[(MapKind, Tensor)]) -> Result<()> {
        if self.files.is_empty() {
            self.open(band)?;
        }
        let held = |kind: MapKind| on_device.iter().find(|(k, _)| *k == kind).map(|(_, t)| t);
        let lacks =
            || Error::Invalid("a band of the output lacks one of the material's maps".into());
        // The files are independent: each encoded and compressed on its own thread (a 4K²
        // PNG's compression is single-threaded and takes seconds).
        self.files.par_iter_mut().try_for_each(|file| {
            let depth = file.file.format().sample_depth();
            // Each channel of a map on the device as the file's samples, made there.
            let stored: Vec<Option<Samples>> = (file.channels.iter())
                .map(|c| match c.holds {
                    Holds::Map(kind, component) => held(kind)
                        .map(|t| {
                            let plane = t.narrow(0, component.min(t.dim(0)? - 1), 1)?;
                            stored_samples(&plane, c.stored, component, depth)
                        })
                        .transpose(),
                    _ => Ok(None),
                })
                .collect::<candle_core::Result<_>>()?;
            let rows = (file.channels.iter().zip(&stored))
                .map(|(c, stored)| match stored {
                    Some(samples) => Some(ChannelRows::Stored(samples)),
                    None => plane(band, c.holds).map(ChannelRows::Values),
                })
                .collect::<Option<Vec<ChannelRows>>>()
                .ok_or_else(lacks)?;
            if let (Some((kind, value)), true) = (file.stand_in, file.all_stand_in) {
                file.all_stand_in = match held(kind) {
                    Some(t) => all_within(t, value)?,
                    None => {
                        let map = band.map(kind).expect("a planned map");
                        (0..map.channels())
                            .all(|c| (map.plane(c).iter()).all(|&v| (v - value[c]).abs() <= 1e-5))
                    }
                };
            }
            let channels = &file.channels;
            file.file.write_channels(&rows, |c, v| {
                channels[c].stored.encode(component(channels[c]), v)
            })
        })
    }

    /// Completes every file (each on its own thread: JPEG and TIFF are encoded here); returns
    /// their paths.
    pub fn finish(self) -> Result<Vec<PathBuf>> {
        let taken = self.taken.clone();
        let kept = self.kept();
        if let Some(file) = kept
            .iter()
            .find(|f| taken.iter().any(|t| t == f.file.path()))
        {
            return Err(Error::file(file.file.path(), TWO_FILES_IN_ONE));
        }
        kept.into_par_iter()
            .map(|file| file.file.finish())
            .collect()
    }

    /// The images of a [`MaterialWriter::in_memory`], in the order files would be written.
    pub fn finish_in_memory(self) -> Result<Vec<StoredImage>> {
        self.kept()
            .into_iter()
            .map(|file| file.file.into_stored())
            .collect()
    }

    /// The files to complete: a stand-in never changed is dropped (its temporary file goes
    /// with it).
    fn kept(self) -> Vec<FileWriter> {
        (self.files.into_iter())
            .filter(|file| !(file.stand_in.is_some() && file.all_stand_in))
            .collect()
    }

    /// The files of the input's layout, under their names (a resolution tag rewritten).
    fn kept_files(&self, origin: &MaterialOrigin) -> Vec<PlannedFile> {
        let convention = self.options.normal_convention;
        let mut normal_seen = false;
        (origin.layout.iter())
            .map(|file| {
                let mut channels = file.channels.clone();
                // The file normals are read from is written in the convention asked for.
                if let (Some(convention), true, false) =
                    (convention, file.holds(MapKind::Normal), normal_seen)
                {
                    normal_seen = true;
                    for channel in channels.iter_mut() {
                        if let Stored::Normal(_) = channel.stored {
                            channel.stored = Stored::Normal(convention);
                        }
                    }
                }
                let format = self.options.format.unwrap_or(file.format);
                // Colour is sRGB-encoded in integer files and linear in float ones.
                let is_colour = |holds: Holds| match holds {
                    Holds::Map(kind, _) => kind == MapKind::BaseColor,
                    Holds::Carried(_, c) => c > 0 || (file.channels.iter()).any(|other| {
                        matches!((holds, other.holds), (Holds::Carried(e, _), Holds::Carried(o, 1)) if e == o)
                    }),
                    _ => false,
                };
                for channel in channels.iter_mut() {
                    if is_colour(channel.holds) {
                        channel.stored = if format.is_float() {
                            Stored::Linear
                        } else {
                            Stored::Srgb
                        };
                    }
                }
                PlannedFile {
                    stem: self.retagged(&file_stem(&file.path)),
                    format,
                    source: Some(file.path.clone()),
                    channels,
                    stand_in: None,
                }
            })
            .collect()
    }

    /// One file a map and a file a carried map, under matup's names (carried maps under
    /// theirs), for the maps of `band` that `kept` does not write.
    fn matup_files(&self, band: &Material, kept: &[PlannedFile]) -> Vec<PlannedFile> {
        let writes = |holds: &dyn Fn(Holds) -> bool| {
            kept.iter()
                .any(|f| f.channels.iter().any(|c| holds(c.holds)))
        };
        let source = |kind| self.origin.as_ref().and_then(|o| o.source(kind));
        let convention = (self.options.normal_convention)
            .or(self.origin.as_ref().map(|o| o.normal_convention))
            .unwrap_or_default();
        let mut files = Vec::new();
        for kind in MapKind::ALL {
            let Some(map) = band.map(kind) else { continue };
            if writes(&|h| matches!(h, Holds::Map(k, _) if k == kind)) {
                continue;
            }
            let format = (self.options.format)
                .or(source(kind).map(|f| f.format))
                .unwrap_or(FileFormat::Png8);
            let stored = Stored::of(kind, format.is_float(), convention);
            let mut channels: Vec<Channel> = (0..map.channels())
                .map(|c| Channel {
                    holds: Holds::Map(kind, c),
                    stored,
                })
                .collect();
            if band.carried.alpha.contains_key(&kind) {
                channels.push(Channel {
                    holds: Holds::Alpha(kind),
                    stored: Stored::Linear,
                });
            }
            // Without an origin every map counts as given, but a metallic map of zeros.
            let had_source = match &self.origin {
                Some(_) => source(kind).is_some(),
                None => kind != MapKind::Metallic,
            };
            files.push(PlannedFile {
                stem: kind.file_stem().to_string(),
                format,
                source: source(kind).map(|f| f.path.clone()),
                channels,
                stand_in: (!had_source)
                    .then(|| kind.stand_in().map(|v| (kind, v)))
                    .flatten(),
            });
        }
        for (e, extra) in band.carried.extras.iter().enumerate() {
            if writes(&|h| matches!(h, Holds::Carried(i, _) if i == e)) {
                continue;
            }
            let format = self.options.format.unwrap_or(extra.format);
            // Carried RGB is colour (data is carried a channel a map).
            let stored = if extra.map.channels() == 3 && !format.is_float() {
                Stored::Srgb
            } else {
                Stored::Linear
            };
            let mut channels: Vec<Channel> = (0..extra.map.channels())
                .map(|c| Channel {
                    holds: Holds::Carried(e, c),
                    stored,
                })
                .collect();
            if extra.alpha.is_some() {
                channels.push(Channel {
                    holds: Holds::CarriedAlpha(e),
                    stored: Stored::Linear,
                });
            }
            files.push(PlannedFile {
                stem: self.retagged(&extra.name),
                format,
                source: Some(extra.source.clone()),
                channels,
                stand_in: None,
            });
        }
        files
    }

    /// `stem` with the input's resolution tag rewritten for the output's size.
    fn retagged(&self, stem: &str) -> String {
        match &self.origin {
            Some(o) => retag(stem, o.size[0], self.size[0]),
            None => stem.to_string(),
        }
    }

    fn open(&mut self, band: &Material) -> Result<()> {
        let mut plan = match (&self.origin, self.options.names) {
            (Some(origin), Names::Keep) => self.kept_files(origin),
            _ => Vec::new(),
        };
        let rest = self.matup_files(band, &plan);
        plan.extend(rest);

        let [w, h] = self.size;
        let mut paths: Vec<PathBuf> = Vec::new();
        for planned in plan {
            let extension = planned.format.extension_as(planned.source.as_deref());
            let path = (self.out_dir).join(format!("{}.{extension}", planned.stem));
            if paths.contains(&path) {
                return Err(Error::file(&path, TWO_FILES_IN_ONE));
            }
            paths.push(path.clone());
            let channels = planned.channels.len();
            if !(1..=4).contains(&channels) {
                return Err(Error::file(
                    &path,
                    format!("{channels} channels: files hold 1 to 4"),
                ));
            }
            let stored: Vec<Stored> = planned.channels.iter().map(|c| c.stored).collect();
            // A DDS format asked for must hold every channel (a file written back in the
            // format it was read from holds them: a normal's rebuilt z is not stored).
            if let (Some(FileFormat::Dds(dds)), FileFormat::Dds(_)) =
                (self.options.format, planned.format)
            {
                super::dds_file::check_fits(channels, dds, &stored)
                    .map_err(|why| Error::file(&path, why))?;
            }
            let hints = WriteHints {
                stored,
                block_quality: self.options.block_quality,
            };
            let open = match self.in_memory {
                true => ImageWriter::in_memory,
                false => ImageWriter::create_with,
            };
            self.files.push(FileWriter {
                file: open(&path, w, h, channels, planned.format, hints)?,
                channels: planned.channels,
                stand_in: planned.stand_in,
                all_stand_in: true,
            });
        }
        Ok(())
    }
}

/// Whether every channel `c` of `t`, `[channels, rows, width]`, is within 10⁻⁵ of
/// `value[c]`, decided on `t`'s device.
fn all_within(t: &Tensor, value: &[f32]) -> candle_core::Result<bool> {
    let value = Tensor::from_slice(&value[..t.dim(0)?], (t.dim(0)?, 1, 1), t.device())?;
    let off = t.broadcast_sub(&value)?.abs()?.max_all()?;
    Ok(off.to_scalar::<f32>()? <= 1e-5)
}

/// The component of its map a channel holds (0 for alpha and carried data).
fn component(channel: Channel) -> usize {
    match channel.holds {
        Holds::Map(_, c) => c,
        _ => 0,
    }
}

/// The rows of `band` a channel holds; a grey base colour file's one channel is R.
fn plane(band: &Material, holds: Holds) -> Option<&[f32]> {
    match holds {
        Holds::Map(kind, c) => band.map(kind).map(|m| m.plane(c.min(m.channels() - 1))),
        Holds::Alpha(kind) => band.carried.alpha.get(&kind).map(|m| m.plane(0)),
        Holds::Carried(e, c) => band.carried.extras.get(e).map(|x| x.map.plane(c)),
        Holds::CarriedAlpha(e) => (band.carried.extras.get(e))
            .and_then(|x| x.alpha.as_ref())
            .map(|m| m.plane(0)),
    }
}

/// Refuses an output folder that is the input folder, lies inside it, or holds one of its
/// files.
pub fn check_output_folder(out_dir: &Path, origin: Option<&MaterialOrigin>) -> Result<()> {
    let Some(origin) = origin else { return Ok(()) };
    let out = resolved(out_dir);
    let inputs = std::iter::once(origin.folder.clone())
        .chain((origin.layout.iter()).filter_map(|f| f.path.parent().map(Path::to_path_buf)));
    for input in inputs {
        let Ok(input) = input.canonicalize() else {
            continue;
        };
        if out.starts_with(&input) {
            return Err(Error::file(
                out_dir,
                if out == input {
                    "output folder is the input folder; matup never writes into its input, \
                     choose another"
                } else {
                    "output folder is inside the input folder; matup never writes into its \
                     input, choose another"
                },
            ));
        }
    }
    Ok(())
}

/// `path` made absolute with its existing part's links resolved (the rest need not exist).
fn resolved(path: &Path) -> PathBuf {
    let absolute = std::path::absolute(path).unwrap_or_else(|_| path.to_path_buf());
    let mut existing = absolute.as_path();
    let mut rest = Vec::new();
    loop {
        if let Ok(real) = existing.canonicalize() {
            return rest.iter().rev().fold(real, |p, part| p.join(part));
        }
        match (existing.parent(), existing.file_name()) {
            (Some(parent), Some(name)) => {
                rest.push(name.to_os_string());
                existing = parent;
            }
            _ => return absolute,
        }
    }
}

/// `stem` with a resolution tag for `from` texels (`_1K`, `-2k-`: a word of a number and K,
/// the number `from / 1024`) rewritten for `to` texels, in the tag's case; other names as
/// they are.
pub fn retag(stem: &str, from: usize, to: usize) -> String {
    if !from.is_multiple_of(1024) || !to.is_multiple_of(1024) {
        return stem.to_string();
    }
    let bytes = stem.as_bytes();
    let is_word = |i: usize| bytes.get(i).is_some_and(u8::is_ascii_alphanumeric);
    let mut out = String::with_capacity(stem.len() + 1);
    let mut rest = 0; // the bytes before it are in `out`
    for (i, _) in stem.char_indices() {
        if i < rest || (i > 0 && is_word(i - 1)) {
            continue;
        }
        let k = i + bytes[i..].iter().take_while(|b| b.is_ascii_digit()).count();
        let tag = k > i
            && bytes.get(k).is_some_and(|b| b.eq_ignore_ascii_case(&b'k'))
            && !is_word(k + 1)
            && stem[i..k].parse::<usize>().ok() == Some(from / 1024);
        if tag {
            out.push_str(&stem[rest..i]);
            out.push_str(&(to / 1024).to_string());
            out.push(bytes[k] as char);
            rest = k + 1;
        }
    }
    out.push_str(&stem[rest..]);
    out
}

#[cfg(test)]
mod tests {
    use super::retag;

    #[test]
    fn resolution_tags_follow_the_output_size() {
        let cases = [
            (
                "Leather008_1K-JPG_AmbientOcclusion",
                1024,
                4096,
                "Leather008_4K-JPG_AmbientOcclusion",
            ),
            ("denim_fabric_ao_1k", 1024, 4096, "denim_fabric_ao_4k"),
            ("rock_2K_opacity", 2048, 32768, "rock_32K_opacity"),
            // Not the input's tag, not a tag, or no size in K.
            ("x_2k_ao", 1024, 4096, "x_2k_ao"),
            ("brick1k_ao", 1024, 4096, "brick1k_ao"),
            ("x_1kg", 1024, 4096, "x_1kg"),
            ("x_1K", 256, 1024, "x_1K"),
            ("émission_1K", 1024, 2048, "émission_2K"),
        ];
        for (stem, from, to, want) in cases {
            assert_eq!(retag(stem, from, to), want, "{stem}");
        }
    }
}
