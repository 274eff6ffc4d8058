//! Recognising which file in a folder holds which map, from the naming schemes in common use
//! (`baseColor.png`, ambientCG `*_Color.jpg` / `*_NormalGL.png`, Poly Haven
//! `*_diff_1k.jpg` / `*_nor_dx_1k.exr`, packed glTF `*_arm_*` / `*_orm_*`, …).

use std::collections::BTreeMap;
use std::fmt;
use std::path::{Path, PathBuf};

use super::image_file::{is_image_file, IMAGE_EXTENSIONS};
use crate::material::NormalConvention;
use crate::{Error, Result};

/// What a file in a material folder holds.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub enum Role {
    BaseColor,
    Normal,
    Roughness,
    /// Glossiness: roughness = 1 − gloss.
    Gloss,
    Metallic,
    Height,
    /// glTF-style packing: occlusion (R), roughness (G), metallic (B).
    Packed,
    Anisotropy,
    AnisotropyAngle,
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
            Role::Packed => "packed occlusion/roughness/metallic",
            Role::Anisotropy => "anisotropy",
            Role::AnisotropyAngle => "anisotropy direction",
        })
    }
}

/// Name parts of maps that matup does not render with: such files are carried along (upsampled
/// and written back, see [`Discovered::extras`]), never read as one of the roles.
const CARRIED: &[&str] = &[
    "ao",
    "ambientocclusion",
    "occlusion",
    "opacity",
    "alpha",
    "emission",
    "emissive",
    "specular",
    "spec",
    "sheen",
    "subsurface",
    "sss",
    "translucency",
    "transmission",
    "cavity",
    "mask",
    "idmask",
    "curvature",
];

/// Name parts of images that are no maps (pictures of the material): skipped.
const NOT_MAPS: &[&str] = &["preview", "thumbnail", "thumb", "swatch", "icon"];

/// The name parts of each role, checked in this order (specific before generic).
pub const ROLE_WORDS: &[(Role, &[&str])] = &[
    (Role::Packed, &["arm", "orm"]),
    (
        Role::Normal,
        &["normal", "normals", "normalmap", "nor", "nrm", "norm"],
    ),
    (Role::Gloss, &["gloss", "glossiness", "glossy"]),
    (Role::Roughness, &["roughness", "rough", "rgh"]),
    (Role::Metallic, &["metallic", "metalness", "metal", "mtl"]),
    (
        Role::Height,
        &["height", "heightmap", "displacement", "disp", "bump"],
    ),
    (Role::Anisotropy, &["anisotropy", "aniso"]),
    (
        Role::BaseColor,
        &[
            "basecolor",
            "basecolour",
            "albedo",
            "diffuse",
            "diff",
            "color",
            "colour",
            "col",
        ],
    ),
];

const ANISOTROPY_DIRECTION_WORDS: &[&str] = &["direction", "dir", "angle", "rotation"];
const OPENGL_WORDS: &[&str] = &["gl", "opengl", "ogl"];
const DIRECTX_WORDS: &[&str] = &["dx", "directx"];

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

/// A file's role and, for normal maps, the convention its name states.
#[derive(Clone, Debug, PartialEq)]
pub struct Recognised {
    pub role: Role,
    pub convention: Option<NormalConvention>,
}

/// What a file of a material folder is, from its name.
#[derive(Clone, Debug, PartialEq)]
enum Kind {
    Role(Recognised),
    /// A map matup carries along: a known kind it does not render with, or an unknown name.
    Carried,
    /// A picture of the material, no map.
    NotAMap,
}

/// What a file whose name parts (shared material-name prefix removed) are `parts` holds.
fn classify(parts: &[String]) -> Kind {
    // Words and adjacent pairs glued together, so "base_color" reads as "basecolor" too.
    let mut candidates: Vec<String> = parts.to_vec();
    candidates.extend(parts.windows(2).map(|w| format!("{}{}", w[0], w[1])));
    let has = |list: &[&str]| candidates.iter().any(|c| list.contains(&c.as_str()));
    // A file named after the material alone is its picture (ambientCG's `Leather025.png`).
    if parts.is_empty() || has(NOT_MAPS) {
        return Kind::NotAMap;
    }
    if has(CARRIED) {
        return Kind::Carried;
    }
    match recognise(&candidates) {
        Some(r) => Kind::Role(r),
        None => Kind::Carried,
    }
}

/// The role named by `candidates` (name parts and adjacent pairs), if any.
fn recognise(candidates: &[String]) -> Option<Recognised> {
    let has = |list: &[&str]| candidates.iter().any(|c| list.contains(&c.as_str()));
    let (role, _) = ROLE_WORDS.iter().find(|(_, list)| has(list))?;
    let role = if *role == Role::Anisotropy && has(ANISOTROPY_DIRECTION_WORDS) {
        Role::AnisotropyAngle
    } else {
        *role
    };
    let convention = (role == Role::Normal)
        .then(|| {
            if has(OPENGL_WORDS) || has(&["normalgl", "norgl"]) {
                Some(NormalConvention::OpenGl)
            } else if has(DIRECTX_WORDS) || has(&["normaldx", "nordx"]) {
                Some(NormalConvention::DirectX)
            } else {
                None
            }
        })
        .flatten();
    Some(Recognised { role, convention })
}

/// The files of a folder assigned to roles.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Discovered {
    pub files: BTreeMap<Role, (PathBuf, Option<NormalConvention>)>,
    /// The other images that are maps (occlusion, opacity, emission, unknown names), sorted:
    /// carried along. Previews and thumbnails are not among them.
    pub extras: Vec<PathBuf>,
    /// Normal maps in the other convention beside the one taken (ambientCG ships `NormalGL`
    /// and `NormalDX`), with the convention their names state.
    pub other_normals: Vec<(PathBuf, Option<NormalConvention>)>,
}

/// Assigns the image files of `folder` to roles. When a normal map exists in both
/// conventions (ambientCG and Poly Haven ship both), the one in `preferred` is taken; a
/// dedicated roughness or metallic map wins over a packed one. Two files claiming the same
/// role otherwise is an error naming both.
pub fn discover(folder: &Path, preferred: NormalConvention) -> Result<Discovered> {
    if !folder.is_dir() {
        return Err(Error::material(folder, "no such folder"));
    }
    let mut images: Vec<PathBuf> = std::fs::read_dir(folder)
        .map_err(|e| Error::io(folder, e))?
        .filter_map(|entry| entry.ok().map(|e| e.path()))
        .filter(|p| p.is_file() && is_image_file(p))
        .collect();
    images.sort();
    if images.is_empty() {
        return Err(Error::material(
            folder,
            format!(
                "folder holds no image files (looked for {})",
                IMAGE_EXTENSIONS.join(", ")
            ),
        ));
    }

    let stems: Vec<Vec<String>> = images
        .iter()
        .map(|p| words(&p.file_stem().unwrap_or_default().to_string_lossy()))
        .collect();
    // The material's own name ("metal_plate_…") is a prefix shared by every file; its words
    // must not be read as roles.
    let shared = if stems.len() > 1 {
        (0..)
            .take_while(|&i| stems.iter().all(|s| s.len() > i && s[i] == stems[0][i]))
            .count()
    } else {
        0
    };

    let mut claims: BTreeMap<Role, Vec<(PathBuf, Option<NormalConvention>)>> = BTreeMap::new();
    let mut extras = Vec::new();
    for (path, parts) in images.iter().zip(&stems) {
        let parts = &parts[shared.min(parts.len())..];
        match classify(parts) {
            Kind::Role(r) => claims
                .entry(r.role)
                .or_default()
                .push((path.clone(), r.convention)),
            Kind::Carried => extras.push(path.clone()),
            Kind::NotAMap => {}
        }
    }

    let mut files = BTreeMap::new();
    let mut other_normals = Vec::new();
    for (role, mut candidates) in claims {
        if role == Role::Normal && candidates.len() > 1 {
            // Keep the preferred convention if that settles it.
            let preferred_only: Vec<_> = candidates
                .iter()
                .filter(|c| c.1 == Some(preferred))
                .cloned()
                .collect();
            let conventions: Vec<_> = candidates.iter().map(|c| c.1).collect();
            if preferred_only.len() == 1 && conventions.iter().all(|c| c.is_some()) {
                // The other convention's file is the same normals: written back, not read.
                other_normals.extend(
                    candidates
                        .iter()
                        .filter(|c| c.1 != Some(preferred))
                        .cloned(),
                );
                candidates = preferred_only;
            }
        }
        if candidates.len() > 1 {
            let names: Vec<String> = candidates
                .iter()
                .map(|c| {
                    c.0.file_name()
                        .unwrap_or_default()
                        .to_string_lossy()
                        .into_owned()
                })
                .collect();
            return Err(Error::material(
                folder,
                format!(
                    "{} files claim the {role} map: {}; name the one to use explicitly",
                    names.len(),
                    names.join(", ")
                ),
            ));
        }
        files.insert(role, candidates.pop().unwrap());
    }
    Ok(Discovered {
        files,
        extras,
        other_normals,
    })
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

    fn role_of(name: &str) -> Option<(Role, Option<NormalConvention>)> {
        match classify(&words(name)) {
            Kind::Role(r) => Some((r.role, r.convention)),
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
            ("normal", Some((Normal, None))),
            ("x_NormalGL", Some((Normal, Some(OpenGl)))),
            ("x_NormalDX", Some((Normal, Some(DirectX)))),
            ("x_nor_gl_1k", Some((Normal, Some(OpenGl)))),
            ("x_nor_dx_1k", Some((Normal, Some(DirectX)))),
            ("x_Roughness", Some((Roughness, None))),
            ("x_rough_2k", Some((Roughness, None))),
            ("x_gloss", Some((Gloss, None))),
            ("x_Metalness", Some((Metallic, None))),
            ("x_metal_1k", Some((Metallic, None))),
            ("x_Displacement", Some((Height, None))),
            ("x_disp_1k", Some((Height, None))),
            ("x_arm_1k", Some((Packed, None))),
            ("x_ORM", Some((Packed, None))),
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
    fn maps_without_a_role_are_carried_and_pictures_are_not() {
        for name in [
            "x_AmbientOcclusion",
            "x_ao_1k",
            "x_Opacity",
            "x_Emission",
            "x_wear",
        ] {
            assert_eq!(classify(&words(name)), Kind::Carried, "{name}");
        }
        for name in ["x_preview", "Thumbnail", "x_swatch_1k", ""] {
            assert_eq!(classify(&words(name)), Kind::NotAMap, "{name}");
        }
    }
}
