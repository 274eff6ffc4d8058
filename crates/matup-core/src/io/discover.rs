//! Recognising what each file in a folder holds, from the names exporters write
//! (`baseColor.png`, ambientCG `*_Color.jpg` / `*_NormalGL.png`, Poly Haven `*_diff_1k.jpg` /
//! `*_arm_1k.png`, glTF `*_metallicRoughness.png`, Unreal `*_OcclusionRoughnessMetallic.png`,
//! Unity `*_BaseMap.png` / `*_MaskMap.png`, Megascans `*_Albedo.jpg` / `*_Gloss.jpg`, …).

use std::collections::BTreeMap;
use std::fmt;
use std::path::{Path, PathBuf};

use super::image_file::{has_extension, is_image_file, IMAGE_EXTENSIONS};
use crate::layout::{packing_of_name, Packing, Stored};
use crate::material::{MapKind, NormalConvention};
use crate::{Error, Result};

/// A map a file can hold whole.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub enum Role {
    BaseColor,
    Normal,
    Roughness,
    /// Glossiness: roughness = 1 − gloss. A roughness map beside it wins.
    Gloss,
    Metallic,
    Height,
    /// A bump map: the height where no height or displacement map is given.
    Bump,
    Anisotropy,
    AnisotropyAngle,
}

impl Role {
    /// The map a file of this role supplies, and how it stores it (integer files: `float`
    /// false). Normals are read as DirectX until their convention is settled.
    pub fn supplies(self, float: bool) -> (MapKind, Stored) {
        let kind = match self {
            Role::BaseColor => MapKind::BaseColor,
            Role::Normal => MapKind::Normal,
            Role::Roughness | Role::Gloss => MapKind::Roughness,
            Role::Metallic => MapKind::Metallic,
            Role::Height | Role::Bump => MapKind::Height,
            Role::Anisotropy => MapKind::Anisotropy,
            Role::AnisotropyAngle => MapKind::AnisotropyAngle,
        };
        let stored = match self {
            Role::Gloss => Stored::Inverted,
            _ => Stored::of(kind, float, NormalConvention::DirectX),
        };
        (kind, stored)
    }
}

impl fmt::Display for Role {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Role::BaseColor => "base colour",
            Role::Normal => "normal",
            Role::Roughness => "roughness",
            Role::Gloss => "gloss",
            Role::Metallic => "metallic",
            Role::Height => "height",
            Role::Bump => "bump",
            Role::Anisotropy => "anisotropy",
            Role::AnisotropyAngle => "anisotropy direction",
        })
    }
}

/// What a file of a material folder holds.
#[derive(Clone, Debug, PartialEq)]
pub enum FileRole {
    /// A whole map, with the normal convention its name states.
    Map {
        role: Role,
        convention: Option<NormalConvention>,
    },
    /// Channels packed by a convention.
    Packed(Packing),
    /// A map matup carries along. `data`: its name says it holds data (occlusion, masks),
    /// whose channels are never colour; otherwise RGB with channels that differ is colour.
    Carried { data: bool },
}

/// Name parts of maps that hold data matup does not render with: carried, each channel as
/// data.
const CARRIED_DATA: &[&str] = &[
    "ao",
    "ambientocclusion",
    "occlusion",
    "opacity",
    "alpha",
    "transparency",
    "mask",
    "detailmask",
    "cavity",
    "curvature",
    "thickness",
    "transmission",
];

/// Name parts of maps matup carries whose RGB may be colour (emission, sheen, Megascans'
/// specular and translucency).
const CARRIED_COLOUR: &[&str] = &[
    "emission",
    "emissive",
    "emissivecolormap",
    "specular",
    "spec",
    "sheen",
    "subsurface",
    "sss",
    "translucency",
    "idmask",
    "id",
];

/// Name parts of images that are no maps (pictures of the material): skipped.
const NOT_MAPS: &[&str] = &["preview", "thumbnail", "thumb", "swatch", "icon", "render"];

/// The name parts of each role, checked in this order (specific before generic).
pub const ROLE_WORDS: &[(Role, &[&str])] = &[
    (
        Role::Normal,
        &[
            "normal",
            "normals",
            "normalmap",
            "nor",
            "nrm",
            "norm",
            // Unity's material property for the normal map.
            "bumpmap",
            // Games' suffix (`rock01_n.dds`).
            "n",
        ],
    ),
    (
        Role::Gloss,
        &["gloss", "glossiness", "glossy", "smoothness"],
    ),
    (Role::Roughness, &["roughness", "rough", "rgh"]),
    (Role::Metallic, &["metallic", "metalness", "metal", "mtl"]),
    (
        Role::Height,
        &[
            "height",
            "heightmap",
            "displacement",
            "disp",
            "parallax",
            // Games' suffix (`rock01_h.dds`), beside _d, _n and _s.
            "h",
        ],
    ),
    (Role::Bump, &["bump"]),
    (Role::Anisotropy, &["anisotropy", "aniso"]),
    (
        Role::BaseColor,
        &[
            "basecolor",
            "basecolour",
            "basecolormap",
            "basemap",
            "maintex",
            "albedo",
            "albedotransparency",
            "diffuse",
            "diff",
            "color",
            "colour",
            "col",
            // Games' suffix (`rock01_d.dds`).
            "d",
        ],
    ),
];

/// Name parts only one exporter writes, with the normal convention it writes normals in
/// (packed files name theirs in [`crate::layout::PACKINGS`]).
const EXPORTER_WORDS: &[(&str, &str, NormalConvention)] = &[
    ("basemap", "Unity", NormalConvention::OpenGl),
    ("maintex", "Unity", NormalConvention::OpenGl),
    ("albedotransparency", "Unity", NormalConvention::OpenGl),
];

const ANISOTROPY_DIRECTION_WORDS: &[&str] = &["direction", "dir", "angle", "rotation"];
const OPENGL_WORDS: &[&str] = &["gl", "opengl", "ogl", "normalgl", "norgl"];
const DIRECTX_WORDS: &[&str] = &["dx", "directx", "normaldx", "nordx"];

/// Image formats matup does not read: a file of one in a material folder is refused by name,
/// never passed over.
const UNREAD_IMAGE_EXTENSIONS: &[&str] = &["ktx", "ktx2", "psd", "hdr", "gif", "avif"];

/// Splits a file stem into lowercase words at separators and lower→upper case changes
/// (`PavingStones092_1K-JPG_NormalGL` → paving, stones092, 1k, jpg, normal, gl).
fn words(stem: &str) -> Vec<String> {
    let mut out = Vec::new();
    let mut current = String::new();
    let mut previous_lower = false;
    for ch in stem.chars() {
        if !ch.is_alphanumeric() {
            if !current.is_empty() {
                out.push(std::mem::take(&mut current));
            }
            previous_lower = false;
            continue;
        }
        if ch.is_uppercase() && previous_lower && !current.is_empty() {
            out.push(std::mem::take(&mut current));
        }
        previous_lower = ch.is_lowercase();
        current.extend(ch.to_lowercase());
    }
    if !current.is_empty() {
        out.push(current);
    }
    out
}

/// Name parts and runs of two and three adjacent ones glued together, so "base_color",
/// "BaseColorMap" and "OcclusionRoughnessMetallic" read as one part too.
fn candidates(parts: &[String]) -> Vec<String> {
    let mut out: Vec<String> = parts.to_vec();
    out.extend(parts.windows(2).map(|w| w.concat()));
    out.extend(parts.windows(3).map(|w| w.concat()));
    out
}

/// What a file whose name parts (shared material-name prefix removed) are `parts` holds;
/// `None` for a picture of the material.
fn classify(parts: &[String]) -> Option<FileRole> {
    let candidates = candidates(parts);
    let has = |list: &[&str]| candidates.iter().any(|c| list.contains(&c.as_str()));
    // A file named after the material alone is its picture (ambientCG's `Leather025.png`).
    if parts.is_empty() || has(NOT_MAPS) {
        return None;
    }
    // Packings first: their names hold role words ("metallicRoughness", "MaskMap").
    if let Some(packing) = packing_of_name(&candidates, parts) {
        return Some(FileRole::Packed(packing));
    }
    // A role named by glued words ("AlbedoTransparency", "BaseColorMap") is more specific
    // than a carried map's single word ("transparency").
    let glued = &candidates[parts.len()..];
    let glued_role = ROLE_WORDS
        .iter()
        .find(|(_, list)| glued.iter().any(|c| list.contains(&c.as_str())));
    if has(CARRIED_DATA) && glued_role.is_none() {
        return Some(FileRole::Carried { data: true });
    }
    if has(CARRIED_COLOUR) && glued_role.is_none() {
        return Some(FileRole::Carried { data: false });
    }
    let Some((role, _)) = glued_role.or_else(|| ROLE_WORDS.iter().find(|(_, list)| has(list)))
    else {
        return Some(FileRole::Carried { data: false });
    };
    let role = if *role == Role::Anisotropy && has(ANISOTROPY_DIRECTION_WORDS) {
        Role::AnisotropyAngle
    } else {
        *role
    };
    let convention = if role != Role::Normal {
        None
    } else if has(OPENGL_WORDS) {
        Some(NormalConvention::OpenGl)
    } else if has(DIRECTX_WORDS) {
        Some(NormalConvention::DirectX)
    } else {
        None
    };
    Some(FileRole::Map { role, convention })
}

/// The files of a folder and what each holds.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Discovered {
    /// Every map file, in the order they are read: whole maps by role (roughness before gloss,
    /// height before bump; a normal map in the preferred convention before the other), then
    /// packed files, then carried maps. The first file that supplies a map is read for it.
    pub files: Vec<(PathBuf, FileRole)>,
    /// The exporter the names mark and the normal convention it writes, if they mark one.
    pub exporter: Option<(String, NormalConvention)>,
    /// Images taken for pictures of the material by their names (`preview`, the material's
    /// name alone): not read, and said so.
    pub pictures: Vec<PathBuf>,
}

/// Assigns the image files of `folder` to roles. When the normal map exists in both
/// conventions (ambientCG and Poly Haven ship both), the one in `preferred` comes first.
/// Two files claiming one role otherwise is an error naming both; an image in a format matup
/// does not read (DDS) is an error naming it.
pub fn discover(folder: &Path, preferred: NormalConvention) -> Result<Discovered> {
    if !folder.is_dir() {
        return Err(Error::material(
            folder,
            if folder.is_file() {
                "is a file; MATERIAL is the folder holding the maps (give single maps with \
                 --base-color, --normal, …)"
            } else {
                "no such folder"
            },
        ));
    }
    let mut paths: Vec<PathBuf> = std::fs::read_dir(folder)
        .map_err(|e| Error::io(folder, e))?
        .filter_map(|entry| entry.ok().map(|e| e.path()))
        .filter(|p| p.is_file())
        .collect();
    paths.sort();
    let stem_words = |p: &Path| words(&p.file_stem().unwrap_or_default().to_string_lossy());
    for path in &paths {
        let unread = path
            .extension()
            .and_then(|e| e.to_str())
            .is_some_and(|e| UNREAD_IMAGE_EXTENSIONS.contains(&e.to_ascii_lowercase().as_str()));
        if unread
            && !candidates(&stem_words(path))
                .iter()
                .any(|c| NOT_MAPS.contains(&c.as_str()))
        {
            return Err(Error::file(
                path,
                format!(
                    "matup does not read this format (it reads {}); convert it, or move it out \
                     of the folder",
                    IMAGE_EXTENSIONS.join(", ")
                ),
            ));
        }
    }
    let images: Vec<PathBuf> = paths.into_iter().filter(|p| is_image_file(p)).collect();
    discover_among(folder, &images, preferred)
}

/// [`discover`] of the images `images` (sorted by name), the files of `folder` or images held
/// in memory under names a folder would give them.
pub fn discover_among(
    folder: &Path,
    images: &[PathBuf],
    preferred: NormalConvention,
) -> Result<Discovered> {
    if images.is_empty() {
        return Err(Error::material(
            folder,
            format!(
                "folder holds no image files (looked for {})",
                IMAGE_EXTENSIONS.join(", ")
            ),
        ));
    }
    let stem_words = |p: &Path| words(&p.file_stem().unwrap_or_default().to_string_lossy());
    let stems: Vec<Vec<String>> = images.iter().map(|p| stem_words(p)).collect();
    // The material's own name ("metal_plate_…") is a prefix shared by every file; its words
    // must not be read as roles.
    let shared = if stems.len() > 1 {
        (0..)
            .take_while(|&i| stems.iter().all(|s| s.len() > i && s[i] == stems[0][i]))
            .count()
    } else {
        0
    };

    let mut maps: BTreeMap<Role, Vec<(PathBuf, Option<NormalConvention>)>> = BTreeMap::new();
    let mut packed = Vec::new();
    let mut carried = Vec::new();
    let mut pictures = Vec::new();
    let mut exporter = None;
    for (path, parts) in images.iter().zip(&stems) {
        let parts = &parts[shared.min(parts.len())..];
        let names = candidates(parts);
        if let Some((_, name, convention)) = EXPORTER_WORDS
            .iter()
            .find(|(word, _, _)| names.iter().any(|c| c == word))
        {
            exporter.get_or_insert((name.to_string(), *convention));
        }
        // Games name a texture's colour after it alone (`rock01.dds` beside `rock01_n.dds`,
        // `rock01.tga` in a mod's sources); a picture of a material is never in a game
        // engine's texture format.
        let colour_by_name = parts.is_empty() && has_extension(path, &["dds", "tga"]);
        let role = classify(parts).or_else(|| {
            colour_by_name.then_some(FileRole::Map {
                role: Role::BaseColor,
                convention: None,
            })
        });
        match role {
            Some(FileRole::Map { role, convention }) => maps
                .entry(role)
                .or_default()
                .push((path.clone(), convention)),
            Some(FileRole::Packed(p)) => {
                if let Some(convention) = p.normals {
                    exporter.get_or_insert((p.name.clone(), convention));
                }
                packed.push((path.clone(), FileRole::Packed(p)));
            }
            Some(role) => carried.push((path.clone(), role)),
            None => pictures.push(path.clone()),
        }
    }

    let mut files = Vec::new();
    for (role, mut claims) in maps {
        if role == Role::Normal && claims.len() > 1 {
            // The same normals in both conventions: the preferred one is read, the other
            // written back from it.
            let named: Vec<_> = claims.iter().filter_map(|c| c.1).collect();
            let distinct = named.len() == claims.len()
                && named.iter().filter(|&&c| c == preferred).count() == 1
                && named.iter().filter(|&&c| c != preferred).count() == 1;
            if distinct {
                claims.sort_by_key(|c| c.1 != Some(preferred));
                files.extend(
                    claims
                        .into_iter()
                        .map(|(path, convention)| (path, FileRole::Map { role, convention })),
                );
                continue;
            }
        }
        if claims.len() > 1 {
            let names: Vec<String> = claims.iter().map(|c| file_name(&c.0)).collect();
            return Err(Error::material(
                folder,
                format!(
                    "{} files claim the {role} map: {}; name the one to use explicitly",
                    names.len(),
                    names.join(", ")
                ),
            ));
        }
        let (path, convention) = claims.pop().expect("a claim per role");
        files.push((path, FileRole::Map { role, convention }));
    }
    files.extend(packed);
    files.extend(carried);
    Ok(Discovered {
        files,
        exporter,
        pictures,
    })
}

/// What a file holds by its own name alone (an explicit file, no folder around it).
pub(crate) fn role_of_name(path: &Path) -> Option<FileRole> {
    classify(&words(
        &path.file_stem().unwrap_or_default().to_string_lossy(),
    ))
}

/// A path's file name, as errors and notes name files.
pub fn file_name(path: &Path) -> String {
    path.file_name()
        .unwrap_or_default()
        .to_string_lossy()
        .into_owned()
}

/// The name parts matup looks for, for an error message about a missing map.
pub fn looked_for(roles: &[Role]) -> String {
    roles
        .iter()
        .flat_map(|r| ROLE_WORDS.iter().filter(move |(role, _)| role == r))
        .flat_map(|(_, words)| words.iter().copied())
        .collect::<Vec<_>>()
        .join(", ")
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::layout::Packed;

    fn role_of(name: &str) -> Option<(Role, Option<NormalConvention>)> {
        match classify(&words(name)) {
            Some(FileRole::Map { role, convention }) => Some((role, convention)),
            _ => None,
        }
    }

    fn packing_of(name: &str) -> Option<Vec<Packed>> {
        match classify(&words(name)) {
            Some(FileRole::Packed(p)) => Some(p.channels),
            _ => None,
        }
    }

    #[test]
    fn splits_words() {
        assert_eq!(
            words("PavingStones092_1K-JPG_NormalGL"),
            ["paving", "stones092", "1k", "jpg", "normal", "gl"]
        );
        assert_eq!(words("baseColor"), ["base", "color"]);
        assert_eq!(
            words("denim_fabric_nor_gl_1k"),
            ["denim", "fabric", "nor", "gl", "1k"]
        );
    }

    #[test]
    fn recognises_common_schemes() {
        use NormalConvention::*;
        use Role::*;
        let cases = [
            ("baseColor", Some((BaseColor, None))),
            ("base_color", Some((BaseColor, None))),
            ("albedo", Some((BaseColor, None))),
            ("Diffuse", Some((BaseColor, None))),
            ("x_Color", Some((BaseColor, None))),
            ("x_diff_1k", Some((BaseColor, None))),
            ("x_BaseMap", Some((BaseColor, None))),
            ("x_BaseColorMap", Some((BaseColor, None))),
            ("x_MainTex", Some((BaseColor, None))),
            ("x_AlbedoTransparency", Some((BaseColor, None))),
            ("normal", Some((Normal, None))),
            ("x_NormalGL", Some((Normal, Some(OpenGl)))),
            ("x_NormalDX", Some((Normal, Some(DirectX)))),
            ("x_nor_gl_1k", Some((Normal, Some(OpenGl)))),
            ("x_nor_dx_1k", Some((Normal, Some(DirectX)))),
            ("x_BumpMap", Some((Normal, None))),
            ("x_Roughness", Some((Roughness, None))),
            ("x_rough_2k", Some((Roughness, None))),
            ("x_gloss", Some((Gloss, None))),
            ("x_Metalness", Some((Metallic, None))),
            ("x_metal_1k", Some((Metallic, None))),
            ("x_Displacement", Some((Height, None))),
            ("x_disp_1k", Some((Height, None))),
            ("x_Bump", Some((Bump, None))),
            ("x_AmbientOcclusion", None),
            ("x_ao_1k", None),
            ("x_Opacity", None),
            ("x_preview", None),
            ("x_anisotropy", Some((Anisotropy, None))),
            ("x_anisotropy_direction", Some((AnisotropyAngle, None))),
        ];
        for (name, want) in cases {
            assert_eq!(role_of(name), want, "{name}");
        }
    }

    #[test]
    fn recognises_packed_files_by_their_conventions() {
        use Packed::*;
        let cases = [
            ("x_metallicRoughness", vec![Unused, Roughness, Metallic]),
            (
                "x_OcclusionRoughnessMetallic",
                vec![Occlusion, Roughness, Metallic],
            ),
            ("x_arm_1k", vec![Occlusion, Roughness, Metallic]),
            ("x_ORM", vec![Occlusion, Roughness, Metallic]),
            ("x_RMA", vec![Roughness, Metallic, Occlusion]),
            (
                "x_MaskMap",
                vec![Metallic, Occlusion, DetailMask, Smoothness],
            ),
            (
                "x_MetallicSmoothness",
                vec![Metallic, Unused, Unused, Smoothness],
            ),
            (
                "x_MetallicGlossMap",
                vec![Metallic, Unused, Unused, Smoothness],
            ),
        ];
        for (name, want) in cases {
            assert_eq!(packing_of(name), Some(want), "{name}");
        }
    }

    #[test]
    fn maps_without_a_role_are_carried_and_pictures_are_not() {
        for (name, data) in [
            ("x_AmbientOcclusion", true),
            ("x_ao_1k", true),
            ("x_Opacity", true),
            ("x_Cavity", true),
            ("x_Emission", false),
            ("x_Emissive", false),
            ("x_Specular", false),
            ("x_Translucency", false),
            ("x_wear", false),
        ] {
            assert_eq!(
                classify(&words(name)),
                Some(FileRole::Carried { data }),
                "{name}"
            );
        }
        for name in ["x_preview", "Thumbnail", "x_swatch_1k", ""] {
            assert_eq!(classify(&words(name)), None, "{name}");
        }
    }

    #[test]
    fn game_textures_are_named_by_suffix_and_colour_by_the_texture_alone() {
        let dir = tempfile::tempdir().unwrap();
        for name in ["rock01.dds", "rock01_n.dds", "rock01_s.dds"] {
            std::fs::write(dir.path().join(name), b"").unwrap();
        }
        let found = discover(dir.path(), NormalConvention::DirectX).unwrap();
        let roles: Vec<(String, FileRole)> = (found.files.into_iter())
            .map(|(p, r)| (file_name(&p), r))
            .collect();
        let map = |role| FileRole::Map {
            role,
            convention: None,
        };
        assert!(
            roles.contains(&("rock01.dds".into(), map(Role::BaseColor))),
            "{roles:?}"
        );
        assert!(
            roles.contains(&("rock01_n.dds".into(), map(Role::Normal))),
            "{roles:?}"
        );
        // So is a TGA (a mod's sources); a PNG named after the material alone is still its
        // picture, and listed as one.
        std::fs::rename(dir.path().join("rock01.dds"), dir.path().join("rock01.tga")).unwrap();
        let found = discover(dir.path(), NormalConvention::DirectX).unwrap();
        let colour = (found.files.iter()).find(|(_, r)| *r == map(Role::BaseColor));
        assert_eq!(
            colour.map(|(p, _)| file_name(p)).as_deref(),
            Some("rock01.tga")
        );
        std::fs::rename(dir.path().join("rock01.tga"), dir.path().join("rock01.png")).unwrap();
        let found = discover(dir.path(), NormalConvention::DirectX).unwrap();
        assert!(found
            .files
            .iter()
            .all(|(p, _)| file_name(p) != "rock01.png"));
        assert_eq!(found.pictures, [dir.path().join("rock01.png")]);
    }
}
