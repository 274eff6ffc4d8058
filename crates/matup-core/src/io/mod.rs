//! Loading a material from a folder (or explicit files) and saving one. Image formats stay
//! at this edge: the rest of matup sees only [`Material`]. Both go through the material's
//! layout ([`crate::layout`]): what each channel of each file holds and how it is stored.

pub(crate) mod dds_file;
mod discover;
mod image_file;
mod read;
// The crate's device maps name `stream::Samples` where it is defined, not through this file.
pub(crate) mod stream;
mod write;

use std::borrow::Cow;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

pub use discover::{discover, discover_among, file_name, Discovered, FileRole, Role};
pub use image_file::{
    encoded_size, is_image_file, read_image, write_atomic, write_image, ImageFile, IMAGE_EXTENSIONS,
};
pub use stream::{ChannelRows, ImageWriter, Samples, StoredImage, WriteHints};
pub use write::{check_output_folder, retag, MaterialWriter, Names, SaveOptions};

use crate::layout::{Packing, Stored};
use crate::map::Map;
use crate::material::{
    normalize_normals, Carried, FileFormat, MapKind, Material, MaterialOrigin, NormalConvention,
};
use crate::normal_convention;
use crate::{Error, Result};
pub use image_file::encode_png8;
use read::Reader;

/// Explicit files for some maps; they win over what folder discovery finds, and a file of the
/// folder they replace comes back as data.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct MaterialPaths {
    pub base_color: Option<PathBuf>,
    pub normal: Option<PathBuf>,
    pub roughness: Option<PathBuf>,
    pub gloss: Option<PathBuf>,
    pub metallic: Option<PathBuf>,
    pub height: Option<PathBuf>,
    /// A packed file: channels as [`MaterialPaths::packing`] says, else as its name says,
    /// else occlusion (R), roughness (G), metallic (B).
    pub packed: Option<PathBuf>,
    pub packing: Option<Packing>,
    pub anisotropy: Option<PathBuf>,
    pub anisotropy_angle: Option<PathBuf>,
    /// Files carried along (upscaled, not rendered with), each with whether it holds data
    /// (occlusion, masks: linear) rather than colour (emission: sRGB in integer files).
    pub carried: Vec<(PathBuf, bool)>,
}

impl MaterialPaths {
    /// The files given, with what each holds and the flag that gave it.
    fn files(&self) -> Vec<(PathBuf, FileRole, String)> {
        let maps = [
            (Role::BaseColor, &self.base_color, "--base-color"),
            (Role::Normal, &self.normal, "--normal"),
            (Role::Roughness, &self.roughness, "--roughness"),
            (Role::Gloss, &self.gloss, "--gloss"),
            (Role::Metallic, &self.metallic, "--metallic"),
            (Role::Height, &self.height, "--height"),
            (Role::Anisotropy, &self.anisotropy, "--anisotropy"),
            (
                Role::AnisotropyAngle,
                &self.anisotropy_angle,
                "--anisotropy-angle",
            ),
        ];
        let mut files: Vec<(PathBuf, FileRole, String)> = Vec::new();
        for (role, path, flag) in maps {
            if let Some(path) = path {
                // A normal map's name may still say its convention.
                let convention = match discover::role_of_name(path) {
                    Some(FileRole::Map { convention, .. }) => convention,
                    _ => None,
                };
                files.push((
                    path.clone(),
                    FileRole::Map { role, convention },
                    flag.into(),
                ));
            }
        }
        if let Some(path) = &self.packed {
            let packing = (self.packing.clone())
                .or_else(|| match discover::role_of_name(path) {
                    Some(FileRole::Packed(p)) => Some(p),
                    _ => None,
                })
                .unwrap_or_else(|| "orm".parse().expect("a packing"));
            let flag = format!("--packed, {}", packing.name);
            files.push((path.clone(), FileRole::Packed(packing), flag));
        }
        for (path, data) in &self.carried {
            let role = FileRole::Carried { data: *data };
            files.push((path.clone(), role, "carried".into()));
        }
        files
    }
}

/// Default for [`LoadOptions::max_texels`]: 8192² texels per map.
pub const DEFAULT_MAX_TEXELS: u64 = 8192 * 8192;

/// How to load a material.
#[derive(Clone, Debug, PartialEq)]
pub struct LoadOptions {
    pub paths: MaterialPaths,
    /// Convention of normal maps whose file name does not say (found from the exporter or
    /// measured when `None`); also the one preferred when a folder holds both.
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

/// Loads the material in `folder` (files recognised by name; see [`discover`]), with explicit
/// files from `options.paths` taking precedence. `folder` may be `None` when the maps are
/// given explicitly. Any of base colour, normal, roughness and metallic may be missing: its
/// [`MapKind::stand_in`] takes its place ([`Material::stand_ins`] says which). Alpha
/// channels, packed channels matup does not render with and the folder's other maps are
/// carried ([`Material::carried`]); carried images of another size than the maps (than the
/// first carried image's, where there are no maps) are set aside, each size a material of its
/// own ([`MaterialOrigin::other_sizes`]). The normal convention comes from the file's
/// name, else `options`, else the exporter the names mark, else the maps
/// ([`MaterialOrigin::normal_evidence`] says which).
pub fn load_material(folder: Option<&Path>, options: &LoadOptions) -> Result<Material> {
    let preferred = options.normal_convention.unwrap_or_default();
    let discovered = match folder {
        Some(f) => discover(f, preferred)?,
        None => Discovered::default(),
    };
    load_discovered(folder, discovered, options, BTreeMap::new())
}

/// The material a folder holding `images` would be, each image already decoded (a Python
/// caller's arrays) under the file name it would have there (`basecolor.png`): loaded as
/// [`load_material`] loads that folder, names deciding roles as they do there, no file read.
/// `folder` names the material in messages; `options.paths` are not used.
pub fn load_material_from_images(
    folder: &Path,
    images: Vec<(String, ImageFile)>,
    options: &LoadOptions,
) -> Result<Material> {
    let mut in_memory = BTreeMap::new();
    for (name, image) in images {
        let path = folder.join(&name);
        if Path::new(&name).file_name() != Some(name.as_ref()) || !is_image_file(&path) {
            return Err(Error::file(
                &path,
                format!(
                    "not an image file's name (a name and one of the extensions {})",
                    IMAGE_EXTENSIONS.join(", ")
                ),
            ));
        }
        if in_memory.insert(path.clone(), image).is_some() {
            return Err(Error::file(&path, "two images under one name"));
        }
    }
    let names: Vec<PathBuf> = in_memory.keys().cloned().collect();
    let preferred = options.normal_convention.unwrap_or_default();
    let discovered = discover_among(folder, &names, preferred)?;
    let options = LoadOptions {
        paths: MaterialPaths::default(),
        ..options.clone()
    };
    let material = load_discovered(Some(folder), discovered, &options, in_memory)?;
    // A folder's files of another size are loaded again from disk as a material of their
    // own; these have no file to be loaded from.
    if let Some(other) = material.origin.as_ref().and_then(|o| o.other_sizes.first()) {
        let [w, h] = other.size;
        return Err(Error::file(
            &other.path,
            format!(
                "{w}×{h}, another size than the maps' {}×{}: every image must be one size",
                material.width(),
                material.height_px()
            ),
        ));
    }
    Ok(material)
}

/// [`load_material`] of the files `discovered` in `folder` and those `options` name, the
/// images of `in_memory` taken from there.
fn load_discovered(
    folder: Option<&Path>,
    discovered: Discovered,
    options: &LoadOptions,
    in_memory: BTreeMap<PathBuf, ImageFile>,
) -> Result<Material> {
    let preferred = options.normal_convention.unwrap_or_default();
    let explicit = options.paths.files();
    let origin_folder = folder
        .map(Path::to_path_buf)
        .or_else(|| (explicit.first()).and_then(|(p, ..)| p.parent().map(Path::to_path_buf)))
        .unwrap_or_else(|| PathBuf::from("."));

    // Explicit files first, so they supply their maps; a file of the folder given explicitly
    // is read once, as the flag says.
    let mut notes = Vec::new();
    let mut files: Vec<(PathBuf, FileRole, String)> = Vec::new();
    for (path, role, flag) in explicit {
        if !path.is_file() {
            return Err(Error::file(
                &path,
                format!("no such file (given by {flag})"),
            ));
        }
        files.push((path, role, flag));
    }
    // Pictures are passed over by their names: the run says which, and how to read one.
    for picture in &discovered.pictures {
        if !files.iter().any(|(p, ..)| same_file(p, picture)) {
            let name = file_name(picture);
            notes.push(format!(
                "{name}: taken by its name for a picture of the material, not upscaled \
                 (--base-color {name}, or another map's flag, reads it as that map)"
            ));
        }
    }
    for (path, role) in discovered.files {
        if files.iter().any(|(p, ..)| same_file(p, &path)) {
            continue;
        }
        if let FileRole::Map { role: r, .. } = &role {
            let kind = r.supplies(false).0;
            let given = files.iter().find(|(_, given, _)| {
                matches!(given, FileRole::Map { role, .. } if role.supplies(false).0 == kind)
            });
            if let (Some((given, _, flag)), true) = (given, kind != MapKind::Normal) {
                notes.push(format!(
                    "{flag} {} replaces {} as the {kind} map; {} comes back as data, upscaled \
                     on its own",
                    file_name(given),
                    file_name(&path),
                    file_name(&path)
                ));
            }
        }
        let how = match &role {
            FileRole::Packed(p) => p.name.clone(),
            _ => "name".to_string(),
        };
        files.push((path, role, how));
    }

    // The maps' files first: their size is the material's, which carried files must share.
    files.sort_by_key(|(_, role, _)| matches!(role, FileRole::Carried { .. }));
    let mut reader = Reader::new(options.max_texels);
    reader.in_memory = in_memory;
    for (path, role, how) in &files {
        reader.read(path, role, how)?;
    }
    // Files carried alone (a model's emission texture) are a material of their own size.
    let Some((w, h)) = reader.size else {
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
    notes.append(&mut reader.notes);

    let height = reader.map(MapKind::Height);
    let mut normal = reader.map(MapKind::Normal);
    // The normal files and the conventions their names state, the one read first.
    let named: Vec<Option<NormalConvention>> = (files.iter())
        .filter_map(|(_, role, _)| match role {
            FileRole::Map {
                role: Role::Normal,
                convention,
            } => Some(*convention),
            _ => None,
        })
        .collect();
    let (convention, evidence) = match &normal {
        None => (preferred, "no normal map".to_string()),
        Some(n) => settle_convention(
            named.first().copied().flatten(),
            options.normal_convention,
            discovered.exporter.as_ref(),
            n,
            height.as_ref(),
        ),
    };
    if let (Some(n), NormalConvention::OpenGl) = (normal.as_mut(), convention) {
        n.plane_mut(1).iter_mut().for_each(|v| *v = -*v);
    }
    // Each normal file's convention in the layout: the one settled for the file read (the
    // first), its name's for the others (written from it).
    let mut conventions = (named.iter().enumerate()).map(|(i, named)| {
        if i == 0 {
            convention
        } else {
            named.unwrap_or(convention)
        }
    });
    for file in (reader.layout.iter_mut()).filter(|f| f.holds(MapKind::Normal)) {
        let this = conventions.next().unwrap_or(convention);
        for channel in file.channels.iter_mut() {
            if let Stored::Normal(_) = channel.stored {
                channel.stored = Stored::Normal(this);
            }
        }
    }

    let stand_in = |kind: MapKind, channels: usize| {
        let value = kind.stand_in().expect("the core maps have stand-ins");
        Map::from_fn(w, h, channels, |c, _, _| value[c])
    };
    let material = Material {
        base_color: reader
            .map(MapKind::BaseColor)
            .unwrap_or_else(|| stand_in(MapKind::BaseColor, 3)),
        normal: normal.unwrap_or_else(|| stand_in(MapKind::Normal, 3)),
        roughness: reader
            .map(MapKind::Roughness)
            .unwrap_or_else(|| stand_in(MapKind::Roughness, 1))
            .map_values(|r| r.clamp(0.0, 1.0)),
        metallic: reader
            .map(MapKind::Metallic)
            .unwrap_or_else(|| stand_in(MapKind::Metallic, 1))
            .map_values(|m| m.clamp(0.0, 1.0)),
        height,
        anisotropy: reader.map(MapKind::Anisotropy),
        anisotropy_angle: reader.map(MapKind::AnisotropyAngle),
        carried: Carried {
            alpha: std::mem::take(&mut reader.alpha),
            extras: std::mem::take(&mut reader.extras),
        },
        origin: Some(MaterialOrigin {
            folder: origin_folder,
            layout: reader.layout,
            normal_convention: convention,
            normal_evidence: evidence,
            size: [w, h],
            other_sizes: reader.other_sizes,
            notes,
            tiling: None,
        }),
        lossy: Default::default(),
    };
    let lossy = (material.origin.as_ref())
        .map(lossy_maps)
        .unwrap_or_default();
    Ok(Material { lossy, ..material })
}

/// The maps of `origin` read from lossy files, with what the file was: "JPEG
/// (Default_albedo.jpg)" ([`crate::file_format::FileFormat::lossy_storage`]).
fn lossy_maps(origin: &MaterialOrigin) -> std::collections::BTreeMap<MapKind, String> {
    (MapKind::ALL.into_iter())
        .filter_map(|kind| {
            let file = origin.source(kind)?;
            let storage = file.format.lossy_storage()?;
            let name = file.path.file_name().unwrap_or_default().to_string_lossy();
            Some((kind, format!("{storage} ({name})")))
        })
        .collect()
}

/// The convention of the normal map read, and the evidence for it: its name, else the option,
/// else the exporter, else the maps.
fn settle_convention(
    named: Option<NormalConvention>,
    option: Option<NormalConvention>,
    exporter: Option<&(String, NormalConvention)>,
    normal: &Map,
    height: Option<&Map>,
) -> (NormalConvention, String) {
    if let Some(c) = named {
        return (c, "the file's name says so".into());
    }
    if let Some(c) = option {
        return (c, "as given (--normal-convention)".into());
    }
    if let Some((exporter, c)) = exporter {
        return (*c, format!("{exporter} files hold {c} normals"));
    }
    let measured = normal_convention::measure(normal, height);
    let mut evidence = format!("measured: {}", measured.signal);
    if measured.weak {
        evidence += "; weak evidence, a guess: --normal-convention decides";
    }
    (measured.convention, evidence)
}

/// Whether two paths name one file (either relative to the working folder).
fn same_file(a: &Path, b: &Path) -> bool {
    match (a.canonicalize(), b.canonicalize()) {
        (Ok(a), Ok(b)) => a == b,
        _ => a == b,
    }
}

/// Encoded [0, 1] normals → unit vectors in matup's (DirectX) frame.
pub fn decode_normals(normal: &mut Map, convention: NormalConvention) {
    let stored = Stored::Normal(convention);
    let n = normal.texels();
    for c in 0..3 {
        (normal.data_mut()[c * n..(c + 1) * n].iter_mut()).for_each(|v| *v = stored.decode(c, *v));
    }
    normalize_normals(normal);
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

/// A map's values as a file in matup's layout stores them ([`Stored::of`]).
pub fn encode_map(
    kind: MapKind,
    map: &Map,
    float: bool,
    convention: NormalConvention,
) -> Cow<'_, Map> {
    let stored = Stored::of(kind, float, convention);
    if stored == Stored::Linear {
        return Cow::Borrowed(map);
    }
    Cow::Owned(Map::from_fn(
        map.width(),
        map.height(),
        map.channels(),
        |c, y, x| stored.encode(c, map.get(c, y, x)),
    ))
}

/// Unit normals → [0, 1] encoding in `convention`.
pub fn encode_normals(normal: &Map, convention: NormalConvention) -> Map {
    encode_map(MapKind::Normal, normal, false, convention).into_owned()
}

/// Writes a display-space RGB image (a render or a preview) as an 8-bit PNG, atomically.
pub fn save_png(path: &Path, image: &Map) -> Result<()> {
    write_image(path, image, FileFormat::Png8)
}
