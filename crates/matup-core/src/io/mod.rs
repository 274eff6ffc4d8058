//! Loading a material from a folder (or explicit files) and saving one. Image formats stay
//! at this edge: the rest of matup sees only [`Material`].

mod discover;
mod image_file;
mod stream;

use rayon::prelude::*;
use std::borrow::Cow;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

pub use discover::{discover, Discovered, Role};
pub use image_file::{is_image_file, write_atomic, IMAGE_EXTENSIONS};
pub use stream::ImageWriter;

use crate::color::{linear_to_srgb, srgb_to_linear};
use crate::map::Map;
use crate::material::{
    normalize_normals, Carried, Extra, FileFormat, MapKind, Material, MaterialOrigin,
    NormalConvention, MIN_ROUGHNESS,
};
use crate::{Error, Result};
pub use image_file::encode_png8;
use image_file::{read_image, write_image, ImageFile};

/// Explicit files for some maps; they win over what folder discovery finds.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct MaterialPaths {
    pub base_color: Option<PathBuf>,
    pub normal: Option<PathBuf>,
    pub roughness: Option<PathBuf>,
    pub gloss: Option<PathBuf>,
    pub metallic: Option<PathBuf>,
    pub height: Option<PathBuf>,
    /// Packed occlusion (R), roughness (G), metallic (B).
    pub packed: Option<PathBuf>,
    pub anisotropy: Option<PathBuf>,
    pub anisotropy_angle: Option<PathBuf>,
}

impl MaterialPaths {
    fn get(&self, role: Role) -> Option<&PathBuf> {
        match role {
            Role::BaseColor => self.base_color.as_ref(),
            Role::Normal => self.normal.as_ref(),
            Role::Roughness => self.roughness.as_ref(),
            Role::Gloss => self.gloss.as_ref(),
            Role::Metallic => self.metallic.as_ref(),
            Role::Height => self.height.as_ref(),
            Role::Packed => self.packed.as_ref(),
            Role::Anisotropy => self.anisotropy.as_ref(),
            Role::AnisotropyAngle => self.anisotropy_angle.as_ref(),
        }
    }
}

/// Default for [`LoadOptions::max_texels`]: 8192² texels per map.
pub const DEFAULT_MAX_TEXELS: u64 = 8192 * 8192;

/// How to load a material.
#[derive(Clone, Debug, PartialEq)]
pub struct LoadOptions {
    pub paths: MaterialPaths,
    /// Convention of normal maps whose file name does not say (DirectX when `None`); also the
    /// one preferred when a folder holds both.
    pub normal_convention: Option<NormalConvention>,
    /// Images with more texels are refused from their header, before decoding.
    pub max_texels: u64,
}

impl Default for LoadOptions {
    fn default() -> Self {
        LoadOptions {
            paths: MaterialPaths::default(),
            normal_convention: None,
            max_texels: DEFAULT_MAX_TEXELS,
        }
    }
}

/// Loads the material in `folder` (maps recognised by name; see [`discover`]), with explicit
/// files from `options.paths` taking precedence. `folder` may be `None` when the maps are
/// given explicitly. Any of base colour, normal, roughness and metallic may be missing: its
/// [`MapKind::stand_in`] takes its place ([`Material::stand_ins`] says which). Alpha
/// channels and the folder's other maps are carried ([`Material::carried`]); other maps of
/// another size are left out, and [`MaterialOrigin::left_out`] says so.
pub fn load_material(folder: Option<&Path>, options: &LoadOptions) -> Result<Material> {
    let preferred = options.normal_convention.unwrap_or_default();
    let discovered = match folder {
        Some(f) => discover(f, preferred)?,
        None => Discovered::default(),
    };
    let origin_folder = folder
        .map(Path::to_path_buf)
        .or_else(|| {
            options
                .paths
                .base_color
                .as_ref()
                .and_then(|p| p.parent().map(Path::to_path_buf))
        })
        .unwrap_or_else(|| PathBuf::from("."));
    let pick = |role: Role| -> Option<(PathBuf, Option<NormalConvention>)> {
        match options.paths.get(role) {
            Some(p) => Some((p.clone(), None)),
            None => discovered.files.get(&role).cloned(),
        }
    };

    let mut reader = Reader {
        max_texels: options.max_texels,
        files: BTreeMap::new(),
        sizes: Vec::new(),
        packed_format: FileFormat::Png8,
        alpha: BTreeMap::new(),
        left_out: Vec::new(),
    };

    let base_color = match pick(Role::BaseColor) {
        Some((path, _)) => {
            let map = reader.read(MapKind::BaseColor, &path, Layout::Color)?;
            Some(if reader.format(MapKind::BaseColor).is_float() {
                map
            } else {
                map.map_values(srgb_to_linear)
            })
        }
        None => None,
    };

    let normal_pick = pick(Role::Normal);
    let convention = normal_pick
        .as_ref()
        .and_then(|(_, named)| *named)
        .unwrap_or(preferred);
    let normal = match &normal_pick {
        Some((path, _)) => {
            let mut normal = reader.read(MapKind::Normal, path, Layout::Vector)?;
            decode_normals(&mut normal, convention);
            Some(normal)
        }
        None => None,
    };

    // Dedicated maps win over glossiness, which wins over packed channels: the packed file is
    // read only when it supplies something; otherwise it is carried as it is.
    let packed_file = pick(Role::Packed).map(|(p, _)| p);
    let packed_supplies = pick(Role::Metallic).is_none()
        || (pick(Role::Roughness).is_none() && pick(Role::Gloss).is_none());
    let packed = packed_file.clone().filter(|_| packed_supplies);
    let packed_map = match &packed {
        Some(p) => Some(reader.read_packed(p)?),
        None => None,
    };

    let roughness_from_gloss = pick(Role::Roughness).is_none() && pick(Role::Gloss).is_some();
    let roughness = if let Some((p, _)) = pick(Role::Roughness) {
        Some(reader.read(MapKind::Roughness, &p, Layout::Scalar)?)
    } else if let Some((p, _)) = pick(Role::Gloss) {
        let gloss = reader.read(MapKind::Roughness, &p, Layout::Scalar)?;
        Some(gloss.map_values(|g| 1.0 - g))
    } else if let (Some(p), Some(m)) = (&packed, &packed_map) {
        reader.note(MapKind::Roughness, p, reader.packed_format);
        Some(m.select_channels(&[1]))
    } else {
        None
    };

    let metallic = if let Some((p, _)) = pick(Role::Metallic) {
        Some(reader.read(MapKind::Metallic, &p, Layout::Scalar)?)
    } else if let (Some(p), Some(m)) = (&packed, &packed_map) {
        reader.note(MapKind::Metallic, p, reader.packed_format);
        Some(m.select_channels(&[2]))
    } else {
        None
    };

    let height = match pick(Role::Height) {
        Some((p, _)) => Some(reader.read(MapKind::Height, &p, Layout::Scalar)?),
        None => None,
    };
    let anisotropy = match pick(Role::Anisotropy) {
        Some((p, _)) => Some(reader.read(MapKind::Anisotropy, &p, Layout::Scalar)?),
        None => None,
    };
    let anisotropy_angle = match pick(Role::AnisotropyAngle) {
        Some((p, _)) => Some(
            reader
                .read(MapKind::AnisotropyAngle, &p, Layout::Scalar)?
                .map_values(|v| v * std::f32::consts::TAU),
        ),
        None => None,
    };

    let Some((w, h)) = reader.size() else {
        return Err(Error::material(
            &origin_folder,
            format!(
                "no material maps found; looked for file names containing {} (or pass the \
                 files explicitly)",
                discover::looked_for(&[Role::BaseColor, Role::Normal, Role::Roughness])
            ),
        ));
    };
    reader.check_sizes(&origin_folder)?;

    // The packed file's occlusion channel, when it supplied roughness or metallic; the whole
    // file when it did not; and every other map of the folder.
    let mut extras = Vec::new();
    let mut left_out = std::mem::take(&mut reader.left_out);
    if let (Some(path), Some(m)) = (&packed, &packed_map) {
        extras.push(Extra {
            name: "occlusion".into(),
            source: path.clone(),
            format: reader.packed_format,
            map: m.select_channels(&[0]),
            alpha: None,
        });
    }
    let unread_packed = packed_file.filter(|_| !packed_supplies);
    for path in unread_packed.iter().chain(&discovered.extras) {
        match read_extra(path, options.max_texels, (w, h))? {
            Ok(extra) => extras.push(extra),
            Err(why) => left_out.push(why),
        }
    }

    let stand_in = |kind: MapKind, channels: usize| {
        let value = kind.stand_in().expect("the core maps have stand-ins");
        Map::from_fn(w, h, channels, |c, _, _| value[c])
    };
    Ok(Material {
        base_color: base_color.unwrap_or_else(|| stand_in(MapKind::BaseColor, 3)),
        normal: normal.unwrap_or_else(|| stand_in(MapKind::Normal, 3)),
        roughness: roughness
            .unwrap_or_else(|| stand_in(MapKind::Roughness, 1))
            .map_values(|r| r.clamp(MIN_ROUGHNESS, 1.0)),
        metallic: metallic
            .unwrap_or_else(|| stand_in(MapKind::Metallic, 1))
            .map_values(|m| m.clamp(0.0, 1.0)),
        height,
        anisotropy,
        anisotropy_angle,
        carried: Carried {
            alpha: reader.alpha,
            extras,
        },
        origin: Some(MaterialOrigin {
            folder: origin_folder,
            files: reader.files,
            normal_convention: convention,
            size: [w, h],
            packed,
            roughness_from_gloss,
            other_normals: (discovered.other_normals.iter())
                .filter_map(|(path, convention)| Some((path.clone(), (*convention)?)))
                .collect(),
            left_out,
        }),
    })
}

/// An extra map of a material `size` texels wide and tall: `Ok(Err(why))` when it is left
/// out for a size of its own (a picture, a map of another resolution).
fn read_extra(
    path: &Path,
    max_texels: u64,
    size: (usize, usize),
) -> Result<std::result::Result<Extra, String>> {
    let file = read_image(path, max_texels)?;
    let name = path.file_name().unwrap_or_default().to_string_lossy();
    if (file.map.width(), file.map.height()) != size {
        return Ok(Err(format!(
            "{name}: {}×{}, the material's maps are {}×{}",
            file.map.width(),
            file.map.height(),
            size.0,
            size.1
        )));
    }
    let format = file.format;
    let (map, alpha) = file.split_alpha();
    let map = if map.channels() == 3 && !format.is_float() {
        map.map_values(srgb_to_linear)
    } else {
        map
    };
    Ok(Ok(Extra {
        name: path
            .file_stem()
            .unwrap_or_default()
            .to_string_lossy()
            .into_owned(),
        source: path.to_path_buf(),
        format,
        map,
        alpha,
    }))
}

/// The channel layout a map needs.
#[derive(Clone, Copy, PartialEq)]
enum Layout {
    /// RGB; grey is replicated.
    Color,
    /// RGB, nothing else (normals).
    Vector,
    /// One channel; of an RGB file the red channel is used.
    Scalar,
}

/// Reads the maps of one material, remembering files, formats, sizes and alpha channels.
struct Reader {
    max_texels: u64,
    files: BTreeMap<MapKind, (PathBuf, FileFormat)>,
    sizes: Vec<(PathBuf, usize, usize)>,
    packed_format: FileFormat,
    alpha: BTreeMap<MapKind, Map>,
    /// What of the files read is not kept, and why.
    left_out: Vec<String>,
}

impl Reader {
    fn load(&mut self, path: &Path) -> Result<ImageFile> {
        let file = read_image(path, self.max_texels)?;
        self.sizes
            .push((path.to_path_buf(), file.map.width(), file.map.height()));
        Ok(file)
    }

    fn note(&mut self, kind: MapKind, path: &Path, format: FileFormat) {
        self.files.insert(kind, (path.to_path_buf(), format));
    }

    fn format(&self, kind: MapKind) -> FileFormat {
        self.files[&kind].1
    }

    /// The size of the maps read so far: that of the first.
    fn size(&self) -> Option<(usize, usize)> {
        self.sizes.first().map(|(_, w, h)| (*w, *h))
    }

    /// A map's colour channels in `layout`; its alpha channel, if any, is kept aside.
    fn read(&mut self, kind: MapKind, path: &Path, layout: Layout) -> Result<Map> {
        let file = self.load(path)?;
        self.note(kind, path, file.format);
        let (map, alpha) = file.split_alpha();
        if let Some(alpha) = alpha {
            self.alpha.insert(kind, alpha);
        }
        match (layout, map.channels()) {
            (Layout::Color, 1) => Ok(map.select_channels(&[0, 0, 0])),
            (Layout::Color | Layout::Vector, 3) => Ok(map),
            (Layout::Scalar, 1) => Ok(map),
            (Layout::Scalar, 3) => Ok(map.select_channels(&[0])),
            (_, n) => Err(Error::file(
                path,
                format!(
                    "unsupported channel layout for a {kind} map: {n} channel{} \
                     (a {kind} map needs {})",
                    if n == 1 { "" } else { "s" },
                    match layout {
                        Layout::Vector => "RGB",
                        Layout::Color => "RGB or grey",
                        Layout::Scalar => "grey or RGB",
                    }
                ),
            )),
        }
    }

    fn read_packed(&mut self, path: &Path) -> Result<Map> {
        let file = self.load(path)?;
        if file.map.channels() < 3 {
            return Err(Error::file(
                path,
                "unsupported channel layout for a packed occlusion/roughness/metallic map: \
                 it needs RGB, this file is grey",
            ));
        }
        if file.map.channels() == 4 {
            self.left_out.push(format!(
                "{}: its alpha channel (a packed file's fourth channel is not kept)",
                path.file_name().unwrap_or_default().to_string_lossy()
            ));
        }
        self.packed_format = file.format;
        Ok(file.map)
    }

    fn check_sizes(&self, folder: &Path) -> Result<()> {
        let (_, w, h) = &self.sizes[0];
        if self.sizes.iter().all(|(_, sw, sh)| (sw, sh) == (w, h)) {
            return Ok(());
        }
        let list: Vec<String> = self
            .sizes
            .iter()
            .map(|(p, w, h)| {
                format!(
                    "{} is {w}×{h}",
                    p.file_name().unwrap_or_default().to_string_lossy()
                )
            })
            .collect();
        Err(Error::material(
            folder,
            format!("maps differ in size: {}", list.join(", ")),
        ))
    }
}

/// Encoded [0, 1] normals → unit vectors in matup's (DirectX) frame.
pub fn decode_normals(normal: &mut Map, convention: NormalConvention) {
    let n = normal.texels();
    let data = normal.data_mut();
    let flip = if convention == NormalConvention::OpenGl {
        -1.0
    } else {
        1.0
    };
    for i in 0..n {
        data[i] = 2.0 * data[i] - 1.0;
        data[n + i] = flip * (2.0 * data[n + i] - 1.0);
        data[2 * n + i] = 2.0 * data[2 * n + i] - 1.0;
    }
    normalize_normals(normal);
}

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

/// Refuses an output folder that is (or holds a source file of) the input.
pub fn check_output_folder(out_dir: &Path, origin: Option<&MaterialOrigin>) -> Result<()> {
    let Some(origin) = origin else { return Ok(()) };
    let Ok(out) = out_dir.canonicalize() else {
        return Ok(()); // does not exist yet, so it is not the input folder
    };
    let inputs = std::iter::once(origin.folder.clone()).chain(
        origin
            .files
            .values()
            .filter_map(|(p, _)| p.parent().map(Path::to_path_buf)),
    );
    for input in inputs {
        if input.canonicalize().is_ok_and(|i| i == out) {
            return Err(Error::file(
                out_dir,
                "output folder is the input folder; matup never writes into its input, choose another",
            ));
        }
    }
    Ok(())
}

/// Saves every map of `material` into `out_dir` (created if needed), each with its alpha
/// channel if its input had one, under the input's names or matup's ([`Names`]), the carried
/// extra maps under their own; each written atomically. A map the input lacked is written only
/// if it differs from its stand-in. Returns the written files.
pub fn save_material(
    material: &Material,
    out_dir: &Path,
    options: &SaveOptions,
) -> Result<Vec<PathBuf>> {
    let mut writer = MaterialWriter::new(
        out_dir,
        [material.width(), material.height_px()],
        material.origin.as_ref(),
        options,
    )?;
    writer.write_rows(material)?;
    writer.finish()
}

/// Writes a material's maps a band of rows at a time, top to bottom, as [`save_material`]
/// writes a whole one (which is one band): the same files, formats and encodings, for outputs
/// that are never whole in memory. The files appear when [`MaterialWriter::finish`] completes
/// them; dropped before, it leaves none.
pub struct MaterialWriter {
    out_dir: PathBuf,
    size: [usize; 2],
    origin: Option<MaterialOrigin>,
    format: Option<FileFormat>,
    convention: NormalConvention,
    names: Names,
    /// Opened with the first band, which says what maps there are.
    maps: Vec<MapWriter>,
}

/// What a file holds of a band.
#[derive(Clone, Copy, PartialEq)]
enum Written {
    Core(MapKind),
    /// Roughness stored as glossiness (1 − roughness), as the input stored it.
    Gloss,
    /// The band's i-th extra map.
    Extra(usize),
    /// Occlusion (the i-th extra map, or none: white), roughness and metallic packed in RGB.
    Packed(Option<usize>),
    /// The normal map again, in the other convention.
    NormalIn(NormalConvention),
}

/// A file [`MaterialWriter`] will write: what of a band, under which stem, how.
struct PlannedFile {
    what: Written,
    stem: String,
    channels: usize,
    format: FileFormat,
    stand_in: Option<&'static [f32]>,
}

struct MapWriter {
    what: Written,
    file: ImageWriter,
    /// A map the input did not have is written only if it differs from its stand-in.
    stand_in: Option<&'static [f32]>,
    all_stand_in: bool,
}

impl MaterialWriter {
    /// For a material of `size` ([width, height]) from `origin` (whose formats, names and
    /// normal convention it keeps unless `options` say otherwise) into `out_dir` (created;
    /// never the input folder).
    pub fn new(
        out_dir: &Path,
        size: [usize; 2],
        origin: Option<&MaterialOrigin>,
        options: &SaveOptions,
    ) -> Result<MaterialWriter> {
        check_output_folder(out_dir, origin)?;
        std::fs::create_dir_all(out_dir).map_err(|e| Error::io(out_dir, e))?;
        let convention = options
            .normal_convention
            .or(origin.map(|o| o.normal_convention))
            .unwrap_or_default();
        Ok(MaterialWriter {
            out_dir: out_dir.to_path_buf(),
            size,
            origin: origin.cloned(),
            format: options.format,
            convention,
            names: options.names,
            maps: Vec::new(),
        })
    }

    /// Appends `band`'s rows (every map, as wide as the material) below those written so far.
    pub fn write_rows(&mut self, band: &Material) -> Result<()> {
        if self.maps.is_empty() {
            self.open(band)?;
        }
        let missing =
            || Error::Invalid("a band of the output lacks one of the material's maps".into());
        let convention = self.convention;
        // The files are independent: each map encoded and compressed on its own thread (a 4K²
        // PNG's compression is single-threaded and takes seconds).
        self.maps.par_iter_mut().try_for_each(|map| {
            let float = map.file.format().is_float();
            let (rows, storing, alpha) = match map.what {
                Written::Core(kind) => {
                    let rows = band.map(kind).ok_or_else(missing)?;
                    if let (Some(value), true) = (map.stand_in, map.all_stand_in) {
                        map.all_stand_in = (0..rows.channels())
                            .all(|c| (rows.plane(c).iter()).all(|&v| (v - value[c]).abs() <= 1e-5));
                    }
                    let storing = Storing::of(kind, float, convention);
                    (Cow::Borrowed(rows), storing, band.carried.alpha.get(&kind))
                }
                Written::Gloss => (
                    Cow::Borrowed(&band.roughness),
                    Storing::Gloss,
                    band.carried.alpha.get(&MapKind::Roughness),
                ),
                Written::Extra(i) => {
                    let extra = band.carried.extras.get(i).ok_or_else(missing)?;
                    let storing = storing_extra(&extra.map, float);
                    (Cow::Borrowed(&extra.map), storing, extra.alpha.as_ref())
                }
                Written::NormalIn(convention) => (
                    Cow::Borrowed(&band.normal),
                    Storing::NormalColours(convention),
                    None,
                ),
                Written::Packed(occlusion) => {
                    let occlusion = match occlusion {
                        Some(i) => band.carried.extras.get(i).ok_or_else(missing)?.map.clone(),
                        None => Map::filled(band.width(), band.height_px(), 1, 1.0),
                    };
                    let packed = Map::stack(&[&occlusion, &band.roughness, &band.metallic]);
                    (Cow::Owned(packed), Storing::AsIs, None)
                }
            };
            let rows = match alpha {
                Some(alpha) => Cow::Owned(Map::stack(&[&rows, alpha])),
                None => rows,
            };
            map.file.write_stored_rows(&rows, storing)
        })
    }

    /// Completes every file (each on its own thread: JPEG and TIFF are encoded here); returns
    /// their paths.
    pub fn finish(self) -> Result<Vec<PathBuf>> {
        self.maps
            .into_par_iter()
            // A stand-in never changed is dropped: its temporary file goes with it.
            .filter(|map| !(map.stand_in.is_some() && map.all_stand_in))
            .map(|map| map.file.finish())
            .collect()
    }

    /// The input file a map of `kind` came from, if it did.
    fn source(&self, kind: MapKind) -> Option<&(PathBuf, FileFormat)> {
        self.origin.as_ref().and_then(|o| o.files.get(&kind))
    }

    /// The format a map of `kind` is written in: the one asked for, else its input file's,
    /// else 8-bit PNG.
    fn format_of_source(&self, kind: MapKind) -> FileFormat {
        self.format
            .or(self.source(kind).map(|s| s.1))
            .unwrap_or(FileFormat::Png8)
    }

    /// The output stem of an input file: its own, with its resolution tag rewritten.
    fn kept_name(&self, source: &Path) -> String {
        let stem = source.file_stem().unwrap_or_default().to_string_lossy();
        match &self.origin {
            Some(o) => retag(&stem, o.size[0], self.size[0]),
            None => stem.into_owned(),
        }
    }

    fn open(&mut self, band: &Material) -> Result<()> {
        let keep = self.names == Names::Keep;
        let packed = self
            .origin
            .as_ref()
            .and_then(|o| o.packed.clone())
            .filter(|_| keep);
        let from_packed =
            |kind| packed.is_some() && self.source(kind).map(|s| &s.0) == packed.as_ref();
        let mut plan: Vec<PlannedFile> = Vec::new();
        for kind in MapKind::ALL {
            let Some(map) = band.map(kind) else {
                continue;
            };
            if from_packed(kind) {
                continue; // written packed below
            }
            let source = self.source(kind).cloned();
            let format = self.format_of_source(kind);
            let stem = match (&source, keep) {
                (Some((path, _)), true) => self.kept_name(path),
                _ => kind.file_stem().to_string(),
            };
            let gloss = keep
                && kind == MapKind::Roughness
                && self.origin.as_ref().is_some_and(|o| o.roughness_from_gloss);
            // Without an origin every map counts as given, but a metallic map of zeros.
            let had_source = match &self.origin {
                Some(_) => source.is_some(),
                None => kind != MapKind::Metallic,
            };
            let alpha = band.carried.alpha.contains_key(&kind) as usize;
            plan.push(PlannedFile {
                what: if gloss {
                    Written::Gloss
                } else {
                    Written::Core(kind)
                },
                stem,
                channels: map.channels() + alpha,
                format,
                stand_in: if had_source { None } else { kind.stand_in() },
            });
        }
        let mut occlusion = None;
        for (i, extra) in band.carried.extras.iter().enumerate() {
            if packed.as_ref() == Some(&extra.source) {
                occlusion = Some(i);
                continue;
            }
            let stem = match &self.origin {
                Some(o) => retag(&extra.name, o.size[0], self.size[0]),
                None => extra.name.clone(),
            };
            let channels = extra.map.channels() + extra.alpha.is_some() as usize;
            plan.push(PlannedFile {
                what: Written::Extra(i),
                stem,
                channels,
                format: self.format.unwrap_or(extra.format),
                stand_in: None,
            });
        }
        if keep {
            let others = self.origin.as_ref().map(|o| o.other_normals.clone());
            for (path, convention) in others.unwrap_or_default() {
                let format = self.format_of_source(MapKind::Normal);
                plan.push(PlannedFile {
                    what: Written::NormalIn(convention),
                    stem: self.kept_name(&path),
                    channels: 3,
                    format,
                    stand_in: None,
                });
            }
        }
        if let Some(path) = &packed {
            let format = self
                .format
                .or(self
                    .source(MapKind::Roughness)
                    .or(self.source(MapKind::Metallic))
                    .map(|s| s.1))
                .unwrap_or(FileFormat::Png8);
            plan.push(PlannedFile {
                what: Written::Packed(occlusion),
                stem: self.kept_name(path),
                channels: 3,
                format,
                stand_in: None,
            });
        }

        let [w, h] = self.size;
        let mut paths: Vec<PathBuf> = Vec::new();
        for PlannedFile {
            what,
            stem,
            channels,
            format,
            stand_in,
        } in plan
        {
            let path = self.out_dir.join(format!("{stem}.{}", format.extension()));
            if paths.contains(&path) {
                return Err(Error::file(
                    &path,
                    "two of the material's maps would be written to this file; rename one, or \
                     use matup's names (--names matup)",
                ));
            }
            paths.push(path.clone());
            self.maps.push(MapWriter {
                what,
                file: ImageWriter::create(&path, w, h, channels, format)?,
                stand_in,
                all_stand_in: true,
            });
        }
        Ok(())
    }
}

/// How an extra map is stored: RGB sRGB-encoded in integer formats.
fn storing_extra(map: &Map, float: bool) -> Storing {
    if map.channels() == 3 && !float {
        Storing::Srgb
    } else {
        Storing::AsIs
    }
}

/// `stem` with a resolution tag for `from` texels (`_1K`, `-2k-`: a word of a number and K,
/// the number `from / 1024`) rewritten for `to` texels, in the tag's case; other names as
/// they are.
pub fn retag(stem: &str, from: usize, to: usize) -> String {
    if from % 1024 != 0 || to % 1024 != 0 {
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

/// How a map's values become its file's, value by value: sRGB base colour (and colour maps
/// carried along) in integer formats, normals as colours in a convention, anisotropy
/// directions as turns, gloss as one minus roughness. Channels past a map's own (an alpha
/// stacked on it) are stored as they are. Applied as a file's samples are made, a map needs no
/// encoded copy (at 4K² 64 MB a channel).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Storing {
    AsIs,
    Srgb,
    NormalColours(NormalConvention),
    Turns,
    Gloss,
}

impl Storing {
    /// How a map of `kind` is stored in a file of a float (`float`) or integer format.
    pub fn of(kind: MapKind, float: bool, convention: NormalConvention) -> Storing {
        match kind {
            MapKind::BaseColor if !float => Storing::Srgb,
            MapKind::Normal => Storing::NormalColours(convention),
            MapKind::AnisotropyAngle => Storing::Turns,
            _ => Storing::AsIs,
        }
    }

    /// The stored value of `v`, a value of channel `channel`.
    #[inline]
    pub fn value(self, channel: usize, v: f32) -> f32 {
        match self {
            Storing::Srgb if channel < 3 => linear_to_srgb(v),
            Storing::NormalColours(convention) if channel < 3 => {
                let flip = channel == 1 && convention == NormalConvention::OpenGl;
                0.5 * (if flip { -v } else { v } + 1.0)
            }
            Storing::Turns if channel == 0 => (v / std::f32::consts::TAU).rem_euclid(1.0),
            Storing::Gloss if channel == 0 => 1.0 - v,
            _ => v,
        }
    }

    /// `map` as its file stores it (borrowed where nothing changes).
    pub fn apply(self, map: &Map) -> Cow<'_, Map> {
        match self {
            Storing::AsIs => Cow::Borrowed(map),
            _ => Cow::Owned(Map::from_fn(
                map.width(),
                map.height(),
                map.channels(),
                |c, y, x| self.value(c, map.get(c, y, x)),
            )),
        }
    }
}

/// A map's values as its file stores them ([`Storing`]).
pub fn encode_map(
    kind: MapKind,
    map: &Map,
    float: bool,
    convention: NormalConvention,
) -> Cow<'_, Map> {
    Storing::of(kind, float, convention).apply(map)
}

/// Unit normals → [0, 1] encoding in `convention`.
pub fn encode_normals(normal: &Map, convention: NormalConvention) -> Map {
    Storing::NormalColours(convention)
        .apply(normal)
        .into_owned()
}

/// Writes a display-space RGB image (a render or a preview) as an 8-bit PNG, atomically.
pub fn save_png(path: &Path, image: &Map) -> Result<()> {
    write_image(path, image, FileFormat::Png8)
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
