//! Loading a material from a folder (or explicit files) and saving one. Image formats stay
//! at this edge: the rest of matup sees only [`Material`].

mod discover;
mod image_file;
mod stream;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

pub use discover::{discover, Discovered, Role};
pub use image_file::{is_image_file, write_atomic, IMAGE_EXTENSIONS};
pub use stream::ImageWriter;

use crate::color::{linear_to_srgb, srgb_to_linear};
use crate::map::Map;
use crate::material::{
    normalize_normals, FileFormat, MapKind, Material, MaterialOrigin, NormalConvention,
    MIN_ROUGHNESS,
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
/// files from `options.paths` taking precedence. `folder` may be `None` when base colour,
/// normal and roughness are all given explicitly.
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
    let missing = |what: &str, roles: &[Role]| {
        Error::material(
            &origin_folder,
            format!(
                "no {what} map found; looked for file names containing {} (or pass the file explicitly)",
                discover::looked_for(roles)
            ),
        )
    };

    let mut reader = Reader {
        max_texels: options.max_texels,
        files: BTreeMap::new(),
        sizes: Vec::new(),
        packed_format: FileFormat::Png8,
    };

    let (base_path, _) =
        pick(Role::BaseColor).ok_or_else(|| missing("base colour", &[Role::BaseColor]))?;
    let base_color = reader.read(MapKind::BaseColor, &base_path, Layout::Color)?;
    let base_linear = reader.format(MapKind::BaseColor).is_float();
    let base_color = if base_linear {
        base_color
    } else {
        base_color.map_values(srgb_to_linear)
    };

    let (normal_path, named_convention) =
        pick(Role::Normal).ok_or_else(|| missing("normal", &[Role::Normal]))?;
    let convention = named_convention.unwrap_or(preferred);
    let mut normal = reader.read(MapKind::Normal, &normal_path, Layout::Vector)?;
    decode_normals(&mut normal, convention);

    // Dedicated maps win over glossiness, which wins over packed channels: the packed file is
    // read only when it supplies something.
    let packed = pick(Role::Packed).map(|(p, _)| p).filter(|_| {
        pick(Role::Metallic).is_none()
            || (pick(Role::Roughness).is_none() && pick(Role::Gloss).is_none())
    });
    let packed_map = match &packed {
        Some(p) => Some(reader.read_packed(p)?),
        None => None,
    };

    let roughness = if let Some((p, _)) = pick(Role::Roughness) {
        reader.read(MapKind::Roughness, &p, Layout::Scalar)?
    } else if let Some((p, _)) = pick(Role::Gloss) {
        reader
            .read(MapKind::Roughness, &p, Layout::Scalar)?
            .map_values(|g| 1.0 - g)
    } else if let (Some(p), Some(m)) = (&packed, &packed_map) {
        reader.note(MapKind::Roughness, p, reader.packed_format);
        m.select_channels(&[1])
    } else {
        return Err(missing(
            "roughness",
            &[Role::Roughness, Role::Gloss, Role::Packed],
        ));
    };
    let roughness = roughness.map_values(|r| r.clamp(MIN_ROUGHNESS, 1.0));

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

    reader.check_sizes(&origin_folder)?;
    let (w, h) = (base_color.width(), base_color.height());
    let metallic = metallic
        .unwrap_or_else(|| Map::filled(w, h, 1, 0.0))
        .map_values(|m| m.clamp(0.0, 1.0));
    Ok(Material {
        base_color,
        normal,
        roughness,
        metallic,
        height,
        anisotropy,
        anisotropy_angle,
        origin: Some(MaterialOrigin {
            folder: origin_folder,
            files: reader.files,
            normal_convention: convention,
        }),
    })
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

/// Reads the maps of one material, remembering files, formats and sizes.
struct Reader {
    max_texels: u64,
    files: BTreeMap<MapKind, (PathBuf, FileFormat)>,
    sizes: Vec<(PathBuf, usize, usize)>,
    packed_format: FileFormat,
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

    fn read(&mut self, kind: MapKind, path: &Path, layout: Layout) -> Result<Map> {
        let file = self.load(path)?;
        self.note(kind, path, file.format);
        let map = file.map;
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
        if file.map.channels() != 3 {
            return Err(Error::file(
                path,
                "unsupported channel layout for a packed occlusion/roughness/metallic map: \
                 it needs RGB, this file is grey",
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
}

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

/// Saves every map of `material` into `out_dir` (created if needed) as
/// `baseColor.<ext>`, `normal.<ext>`, `roughness.<ext>`, `metallic.<ext>`, `height.<ext>`,
/// each written atomically. Metallic is written when the input had one or it is not all zero.
/// Returns the written files.
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
    /// Opened with the first band, which says what maps there are.
    maps: Vec<MapWriter>,
}

struct MapWriter {
    kind: MapKind,
    file: ImageWriter,
    /// A metallic map the input did not have is written only if it is not all zero.
    only_if_nonzero: bool,
    all_zero: bool,
}

impl MaterialWriter {
    /// For a material of `size` ([width, height]) from `origin` (whose formats and normal
    /// convention it keeps unless `options` say otherwise) into `out_dir` (created; never the
    /// input folder).
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
            maps: Vec::new(),
        })
    }

    /// Appends `band`'s rows (every map, as wide as the material) below those written so far.
    pub fn write_rows(&mut self, band: &Material) -> Result<()> {
        if self.maps.is_empty() {
            self.open(band)?;
        }
        let formats: Vec<FileFormat> = self.maps.iter().map(|m| self.format_of(m.kind)).collect();
        for (map, format) in self.maps.iter_mut().zip(formats) {
            let rows = band.map(map.kind).ok_or_else(|| {
                Error::Invalid(format!("a band of the output lacks its {} map", map.kind))
            })?;
            if map.only_if_nonzero && map.all_zero {
                map.all_zero = rows.data().iter().all(|&v| v == 0.0);
            }
            map.file.write_rows(&encode_map(
                map.kind,
                rows,
                format.is_float(),
                self.convention,
            ))?;
        }
        Ok(())
    }

    /// Completes every file; returns their paths.
    pub fn finish(self) -> Result<Vec<PathBuf>> {
        let mut written = Vec::new();
        for map in self.maps {
            if map.only_if_nonzero && map.all_zero {
                continue; // dropped: its temporary file goes with it
            }
            written.push(map.file.finish()?);
        }
        Ok(written)
    }

    fn format_of(&self, kind: MapKind) -> FileFormat {
        self.format
            .or(self
                .origin
                .as_ref()
                .and_then(|o| o.files.get(&kind).map(|f| f.1)))
            .unwrap_or(FileFormat::Png8)
    }

    fn open(&mut self, band: &Material) -> Result<()> {
        let [w, h] = self.size;
        for kind in MapKind::ALL {
            let Some(map) = band.map(kind) else {
                continue;
            };
            let format = self.format_of(kind);
            let path = self
                .out_dir
                .join(format!("{}.{}", kind.file_stem(), format.extension()));
            let had_source = self
                .origin
                .as_ref()
                .is_some_and(|o| o.files.contains_key(&kind));
            self.maps.push(MapWriter {
                kind,
                file: ImageWriter::create(&path, w, h, map.channels(), format)?,
                only_if_nonzero: kind == MapKind::Metallic && !had_source,
                all_zero: true,
            });
        }
        Ok(())
    }
}

/// A map's values as its file stores them: sRGB base colour in integer formats, normals as
/// colours in `convention`, anisotropy directions as turns.
fn encode_map(kind: MapKind, map: &Map, float: bool, convention: NormalConvention) -> Map {
    match kind {
        MapKind::BaseColor if !float => map.clone().map_values(linear_to_srgb),
        MapKind::Normal => encode_normals(map, convention),
        MapKind::AnisotropyAngle => map
            .clone()
            .map_values(|a| (a / std::f32::consts::TAU).rem_euclid(1.0)),
        _ => map.clone(),
    }
}

/// Unit normals → [0, 1] encoding in `convention`.
pub fn encode_normals(normal: &Map, convention: NormalConvention) -> Map {
    let flip = if convention == NormalConvention::OpenGl {
        -1.0
    } else {
        1.0
    };
    let n = normal.texels();
    let mut out = normal.clone();
    for (i, v) in out.data_mut().iter_mut().enumerate() {
        let sign = if i / n == 1 { flip } else { 1.0 };
        *v = 0.5 * (sign * *v + 1.0);
    }
    out
}

/// Writes a display-space RGB image (a render or a preview) as an 8-bit PNG, atomically.
pub fn save_png(path: &Path, image: &Map) -> Result<()> {
    write_image(path, image, FileFormat::Png8)
}
