//! A glTF 2.0 model read and written back: its JSON, buffers and images, the role each
//! texture plays in its materials, the images grouped into runs, the atlases among them, and
//! the model written with only its images new.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Component, Path, PathBuf};

use base64::Engine;
use serde_json::Value;

use matup_core::io::{encoded_size, write_atomic};
use matup_core::{Error, Result};

/// Extension textures that hold colour (sRGB); the others hold data.
pub(super) const COLOUR_EXTENSION_TEXTURES: &[&str] = &[
    "sheenColorTexture",
    "specularColorTexture",
    "diffuseTexture",
    "specularGlossinessTexture",
];

/// What a texture holds in its material.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Role {
    BaseColor,
    Normal,
    /// `metallicRoughness`; `occlusion` where `occlusionTexture` is the same image.
    MetallicRoughness {
        occlusion: bool,
    },
    Carried {
        data: bool,
    },
}

/// A model as read: its JSON, its binary chunk (GLB) and the folder its URIs are relative to.
pub(super) struct Model {
    pub(super) path: PathBuf,
    pub(super) json: Value,
    pub(super) bin: Option<Vec<u8>>,
    pub(super) folder: PathBuf,
}

/// The texture coordinate sets a material's textures read, or `None` where it has none or one
/// is transformed (`KHR_texture_transform`): then where it reads on its textures is not known
/// from its UVs alone.
pub(super) fn texture_coordinate_sets(material: &Value) -> Option<Vec<u32>> {
    let mut sets = Vec::new();
    let mut transformed = false;
    visit_texture_infos(material, &mut |info, _| {
        sets.push(info["texCoord"].as_u64().unwrap_or(0) as u32);
        transformed |= !info["extensions"]["KHR_texture_transform"].is_null();
    });
    sets.sort();
    sets.dedup();
    (!transformed && !sets.is_empty()).then_some(sets)
}

/// Whether `uvs` stay within one copy of the texture on both axes ([`within_one_copy`]).
pub(super) fn uvs_within_one_copy(uvs: impl Iterator<Item = [f32; 2]>) -> bool {
    let mut range = [[f32::INFINITY, f32::NEG_INFINITY]; 2];
    for uv in uvs {
        for (axis, value) in uv.into_iter().enumerate() {
            range[axis] = [range[axis][0].min(value), range[axis][1].max(value)];
        }
    }
    range.iter().all(|&[lo, hi]| within_one_copy(lo, hi))
}

/// UVs that never pass more than a rounding error into a neighbouring copy of the texture
/// (its unit square): DamagedHelmet's V runs over 1.0005–1.9987, one copy.
pub(super) fn within_one_copy(lo: f32, hi: f32) -> bool {
    const SLACK: f32 = 1e-3;
    lo.is_finite() && hi.is_finite() && (lo + SLACK).floor() == (hi - SLACK).floor()
}

/// Stems made unique (as files on a case-blind disk) with the image's number, and kept off
/// the names of the run's own files (`preview.png`, `run.json`) written beside them.
pub(super) fn unique_stems(images: &mut [Image]) {
    let key = |stem: &str| stem.to_lowercase();
    let mut count: BTreeMap<String, usize> = BTreeMap::new();
    for image in images.iter() {
        *count.entry(key(&image.stem)).or_default() += 1;
    }
    for (i, image) in images.iter_mut().enumerate() {
        let stem = key(&image.stem);
        if count[&stem] > 1 || stem == "preview" || stem == "run" {
            image.stem = format!("{}-{i}", image.stem);
        }
    }
}

/// Whether two paths name one folder.
pub(super) fn same_folder(a: &Path, b: &Path) -> bool {
    let resolved = |p: &Path| p.canonicalize().ok();
    let b = if b.as_os_str().is_empty() {
        Path::new(".")
    } else {
        b
    };
    resolved(a).is_some() && resolved(a) == resolved(b)
}

/// An image of the model: its bytes, format and size.
pub(super) struct Image {
    pub(super) bytes: Vec<u8>,
    pub(super) encoding: Encoding,
    pub(super) size: (u32, u32),
    /// Where it is stored, for messages: its URI or bufferView.
    pub(super) name: String,
    /// The stem of its file while it is upscaled: its URI's or its name's, so that the run's
    /// notes name `Default_albedo`, not a number.
    pub(super) stem: String,
}

/// The image formats a glTF model holds that matup writes back: the core PNG and JPEG, and
/// WebP (`EXT_texture_webp`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Encoding {
    Png,
    Jpeg,
    Webp,
}

impl Encoding {
    /// The format of an image's bytes, from their signature.
    pub(super) fn of(bytes: &[u8]) -> Option<Encoding> {
        if bytes.starts_with(b"\x89PNG") {
            Some(Encoding::Png)
        } else if bytes.starts_with(&[0xFF, 0xD8]) {
            Some(Encoding::Jpeg)
        } else if bytes.starts_with(b"RIFF") && bytes.get(8..12) == Some(b"WEBP") {
            Some(Encoding::Webp)
        } else {
            None
        }
    }
}

impl Image {
    /// Its file's name while it is upscaled: its stem, with the extension of its bytes.
    pub(super) fn file_name(&self) -> String {
        let extension = match self.encoding {
            Encoding::Png => "png",
            Encoding::Jpeg => "jpg",
            Encoding::Webp => "webp",
        };
        format!("{}.{extension}", self.stem)
    }

    pub(super) fn mime(&self) -> &'static str {
        match self.encoding {
            Encoding::Png => "image/png",
            Encoding::Jpeg => "image/jpeg",
            Encoding::Webp => "image/webp",
        }
    }
}

/// Images upscaled together: one material's images of one size that no earlier group took.
pub(super) struct Group {
    pub(super) label: String,
    pub(super) uses: Vec<(usize, Role)>,
    /// The material whose images these are (none for the images no material uses).
    pub(super) material: Option<usize>,
}

pub(super) struct Groups {
    pub(super) groups: Vec<Group>,
    pub(super) notes: Vec<String>,
}

impl Role {
    pub(super) fn words(self) -> &'static str {
        match self {
            Role::BaseColor => "base colour",
            Role::Normal => "normal (OpenGL)",
            Role::MetallicRoughness { occlusion: false } => "metallicRoughness",
            Role::MetallicRoughness { occlusion: true } => "occlusion/roughness/metallic",
            Role::Carried { data: true } => "data",
            Role::Carried { data: false } => "colour",
        }
    }
}

impl Model {
    pub(super) fn read(path: &Path) -> Result<Model> {
        let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
        let (json, bin) = if is_glb(path) {
            // The `gltf` crate subtracts the header's size from the length the header states
            // unchecked (a panic where overflow is checked, found by fuzzing): refused first.
            const HEADER: usize = 12;
            if let Some(stated) = bytes
                .get(8..HEADER)
                .map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
            {
                if (stated as usize) < HEADER {
                    return Err(Error::file(
                        path,
                        format!(
                            "not a readable GLB file: its header states a length of {stated} \
                             bytes, less than the header's own {HEADER}"
                        ),
                    ));
                }
            }
            let glb = gltf::binary::Glb::from_slice(&bytes)
                .map_err(|e| Error::file(path, format!("not a readable GLB file: {e}")))?;
            (glb.json.into_owned(), glb.bin.map(|b| b.into_owned()))
        } else {
            (bytes, None)
        };
        let json: Value = serde_json::from_slice(&json)
            .map_err(|e| Error::file(path, format!("not readable glTF JSON: {e}")))?;
        let version = json["asset"]["version"].as_str().unwrap_or("");
        if !version.starts_with("2.") {
            return Err(Error::file(
                path,
                format!("glTF version '{version}': matup reads glTF 2.0"),
            ));
        }
        Ok(Model {
            path: path.to_path_buf(),
            json,
            bin,
            folder: path.parent().unwrap_or(Path::new("")).to_path_buf(),
        })
    }

    pub(super) fn bad(&self, what: impl std::fmt::Display) -> Error {
        Error::file(&self.path, what.to_string())
    }

    pub(super) fn array(&self, key: &str) -> &[Value] {
        self.json[key].as_array().map_or(&[], Vec::as_slice)
    }

    /// The bytes of buffer `index`: the GLB's binary chunk, a data URI or a file beside the
    /// model.
    pub(super) fn buffer(&self, index: usize) -> Result<Vec<u8>> {
        let buffer = (self.array("buffers").get(index))
            .ok_or_else(|| self.bad(format!("buffer {index} does not exist")))?;
        match buffer["uri"].as_str() {
            None => (self.bin.clone()).ok_or_else(|| {
                self.bad(format!(
                    "buffer {index} has no URI and the file no binary chunk"
                ))
            }),
            Some(uri) => self.uri_bytes(uri),
        }
    }

    /// The file a (non-data) URI names, inside the model's folder: by its path, and where
    /// symbolic links lead (a link out of the folder could read any file of the user's).
    pub(super) fn file_of(&self, uri: &str) -> Result<PathBuf> {
        let file = self
            .folder
            .join(relative_path(uri).map_err(|e| self.bad(e))?);
        let folder = self.folder.canonicalize();
        match (folder, file.canonicalize()) {
            (Ok(folder), Ok(target)) if !target.starts_with(&folder) => Err(self.bad(format!(
                "URI '{uri}' is a link to {}, outside the model's folder; matup reads only inside it",
                target.display()
            ))),
            // A file that does not exist is reported where it is read.
            _ => Ok(file),
        }
    }

    pub(super) fn uri_bytes(&self, uri: &str) -> Result<Vec<u8>> {
        if let Some(data) = uri.strip_prefix("data:") {
            let (_, encoded) = data
                .split_once(";base64,")
                .ok_or_else(|| self.bad("a data URI that is not base64"))?;
            return base64::engine::general_purpose::STANDARD
                .decode(encoded)
                .map_err(|e| self.bad(format!("a data URI that does not decode: {e}")));
        }
        let file = self.file_of(uri)?;
        std::fs::read(&file).map_err(|e| {
            self.bad(format!(
                "'{uri}', which the model names, cannot be read at {}: {e}",
                file.display()
            ))
        })
    }

    /// Every image of the model, read and checked to be PNG or JPEG.
    pub(super) fn images(&self, buffers: &[Vec<u8>]) -> Result<Vec<Image>> {
        let mut images = Vec::new();
        for (i, image) in self.array("images").iter().enumerate() {
            let (bytes, name) = match (image["uri"].as_str(), image["bufferView"].as_u64()) {
                (Some(uri), _) => {
                    let name = if uri.starts_with("data:") {
                        format!("image {i} (data URI)")
                    } else {
                        format!("image {i} ({uri})")
                    };
                    (self.uri_bytes(uri)?, name)
                }
                (None, Some(view)) => (
                    self.view_bytes(view as usize, buffers)?,
                    format!("image {i} (bufferView {view})"),
                ),
                (None, None) => return Err(self.bad(format!("image {i} has no URI or bufferView"))),
            };
            let encoding = Encoding::of(&bytes).ok_or_else(|| {
                self.bad(format!(
                    "{name} is neither PNG, JPEG nor WebP: matup upscales glTF's core image \
                     formats and EXT_texture_webp's"
                ))
            })?;
            let size = encoded_size(&bytes)
                .ok_or_else(|| self.bad(format!("{name} is not a readable image")))?;
            let uri_stem = (image["uri"].as_str())
                .filter(|uri| !uri.starts_with("data:"))
                .and_then(|uri| Some(relative_path(uri).ok()?.file_stem()?.to_str()?.to_owned()));
            let stem = uri_stem
                .or_else(|| image["name"].as_str().map(str::to_owned))
                .map(|stem| sanitised(&stem))
                .filter(|stem| !stem.is_empty())
                .unwrap_or_else(|| format!("image-{i}"));
            images.push(Image {
                bytes,
                encoding,
                size,
                name,
                stem,
            });
        }
        unique_stems(&mut images);
        Ok(images)
    }

    /// Every buffer's bytes, in order; an error names the first that cannot be read.
    pub(super) fn buffers(&self) -> Result<Vec<Vec<u8>>> {
        (0..self.array("buffers").len())
            .map(|b| self.buffer(b))
            .collect()
    }

    /// Buffer `index` of `buffers` ([`Model::buffers`]).
    pub(super) fn loaded<'a>(&self, buffers: &'a [Vec<u8>], index: usize) -> Result<&'a [u8]> {
        (buffers.get(index).map(Vec::as_slice))
            .ok_or_else(|| self.bad(format!("buffer {index} does not exist")))
    }

    /// The materials every primitive drawn with reads its textures' UVs within one copy of
    /// them (one unit square, on both axes): UV atlases, whose edges are no neighbours. A
    /// material is left out where any UVs cross a copy's edge (a texture tiled over a floor), a
    /// texture is transformed (`KHR_texture_transform`), no primitive uses it, or the UVs
    /// cannot be read: its edges then decide.
    pub(super) fn atlases(&self, buffers: &[Vec<u8>]) -> BTreeSet<usize> {
        let Some(document) = serde_json::from_value(self.json.clone())
            .ok()
            .and_then(|root| gltf::Document::from_json(root).ok())
        else {
            return BTreeSet::new();
        };
        let materials = self.array("materials");
        // Each material drawn: whether every primitive so far read one copy.
        let mut one_copy: BTreeMap<usize, bool> = BTreeMap::new();
        for primitive in document.meshes().flat_map(|mesh| mesh.primitives()) {
            let Some(m) = primitive.material().index() else {
                continue;
            };
            let reader = primitive.reader(|b| buffers.get(b.index()).map(Vec::as_slice));
            let within = texture_coordinate_sets(&materials[m]).is_some_and(|sets| {
                sets.iter().all(|&set| {
                    reader
                        .read_tex_coords(set)
                        .is_some_and(|uvs| uvs_within_one_copy(uvs.into_f32()))
                })
            });
            *one_copy.entry(m).or_insert(true) &= within;
        }
        (one_copy.into_iter())
            .filter_map(|(m, within)| within.then_some(m))
            .collect()
    }

    pub(super) fn view_bytes(&self, index: usize, buffers: &[Vec<u8>]) -> Result<Vec<u8>> {
        let view = (self.array("bufferViews").get(index))
            .ok_or_else(|| self.bad(format!("bufferView {index} does not exist")))?;
        let buffer = self.loaded(buffers, view["buffer"].as_u64().unwrap_or(0) as usize)?;
        let start = view["byteOffset"].as_u64().unwrap_or(0) as usize;
        let length = view["byteLength"].as_u64().unwrap_or(0) as usize;
        (buffer.get(start..start.saturating_add(length)))
            .map(<[u8]>::to_vec)
            .ok_or_else(|| self.bad(format!("bufferView {index} runs past its buffer")))
    }

    /// The image a texture shows, one of `images`: the WebP image of `EXT_texture_webp` where
    /// it names one, else the core `source`. With `fallback`, the core `source` of a texture
    /// that names a WebP image too (for viewers without WebP), if it has one.
    pub(super) fn texture_image(
        &self,
        texture: usize,
        images: usize,
        fallback: bool,
    ) -> Result<Option<usize>> {
        let t = (self.array("textures").get(texture))
            .ok_or_else(|| self.bad(format!("texture {texture} does not exist")))?;
        let webp = t["extensions"]["EXT_texture_webp"]["source"].as_u64();
        let core = t["source"].as_u64();
        let source = if fallback {
            webp.and(core)
        } else {
            webp.or(core)
        };
        let Some(source) = source.map(|s| s as usize) else {
            if fallback {
                return Ok(None);
            }
            return Err(self.bad(format!(
                "texture {texture} has no PNG, JPEG or WebP source (only another extension's \
                 image): matup upscales glTF's core image formats and EXT_texture_webp's"
            )));
        };
        if source >= images {
            return Err(self.bad(format!(
                "texture {texture} shows image {source}, which does not exist"
            )));
        }
        Ok(Some(source))
    }

    /// Each material's images by role, split by size, each image in the first group that
    /// uses it; images no material uses come last, carried as colour.
    pub(super) fn groups(&self, images: &[Image]) -> Result<Groups> {
        let mut taken: BTreeMap<usize, (String, Role)> = BTreeMap::new();
        let mut groups = Vec::new();
        let mut notes = Vec::new();
        for (m, material) in self.array("materials").iter().enumerate() {
            let material_name = material["name"]
                .as_str()
                .map_or(format!("material-{m}"), |n| format!("{m}-{}", sanitised(n)));
            // The images the material shows, then the fallbacks of its WebP textures: the same
            // maps in another file, so a run of their own.
            for fallback in [false, true] {
                let name = if fallback {
                    format!("{material_name}-fallback")
                } else {
                    material_name.clone()
                };
                let mut uses: Vec<(usize, Role)> = Vec::new();
                for (texture, role) in material_textures(material) {
                    let Some(image) = self.texture_image(texture, images.len(), fallback)? else {
                        continue;
                    };
                    if let Some((owner, first)) = taken.get(&image) {
                        if *first != role {
                            notes.push(format!(
                                "{}: used as {} by {name}, upscaled as {} with {owner}",
                                images[image].name,
                                role.words(),
                                first.words()
                            ));
                        }
                        continue;
                    }
                    match uses.iter_mut().find(|(i, _)| *i == image) {
                        // occlusionTexture in the metallicRoughness image: an ORM file.
                        Some((_, r @ Role::MetallicRoughness { .. }))
                            if role == (Role::Carried { data: true }) =>
                        {
                            *r = Role::MetallicRoughness { occlusion: true }
                        }
                        Some((_, first)) => {
                            if *first != role {
                                notes.push(format!(
                                    "{}: used as {} and as {} by {name}, upscaled as {}",
                                    images[image].name,
                                    first.words(),
                                    role.words(),
                                    first.words()
                                ));
                            }
                        }
                        None => uses.push((image, role)),
                    }
                }
                for &(image, role) in &uses {
                    taken.insert(image, (name.clone(), role));
                }
                groups.extend(by_size(&name, Some(m), uses, images));
            }
        }
        let unused: Vec<(usize, Role)> = (0..images.len())
            .filter(|i| !taken.contains_key(i))
            .map(|i| (i, Role::Carried { data: false }))
            .collect();
        if !unused.is_empty() {
            notes.push(format!(
                "{} image(s) no material uses, upscaled as colour",
                unused.len()
            ));
            groups.extend(by_size("unused-images", None, unused, images));
        }
        Ok(Groups { groups, notes })
    }

    /// Writes the model into `out` with the upscaled images: external images at their URIs,
    /// data URIs re-encoded, images in buffers appended to their buffer (the bytes before them,
    /// which hold the geometry, unchanged); buffers in files copied or rewritten.
    pub(super) fn write(
        &self,
        images: &[Image],
        upscaled: &BTreeMap<usize, Vec<u8>>,
        buffers: &[Vec<u8>],
        out: &Path,
    ) -> Result<Vec<PathBuf>> {
        let mut json = self.json.clone();
        let mut written = Vec::new();
        // Buffers that hold images: their bytes up to the last view that is not an image's,
        // then the new images.
        let image_views: BTreeMap<usize, usize> = (self.array("images").iter().enumerate())
            .filter_map(|(i, image)| Some((image["bufferView"].as_u64()? as usize, i)))
            .collect();
        let views = self.array("bufferViews");
        let mut rewritten: BTreeMap<usize, Vec<u8>> = BTreeMap::new();
        for &view in image_views.keys() {
            let b = views[view]["buffer"].as_u64().unwrap_or(0) as usize;
            if rewritten.contains_key(&b) {
                continue;
            }
            let mut bytes = self.loaded(buffers, b)?.to_vec();
            let kept = (views.iter().enumerate())
                .filter(|(v, view)| {
                    !image_views.contains_key(v)
                        && view["buffer"].as_u64().unwrap_or(0) as usize == b
                })
                .map(|(_, view)| {
                    view["byteOffset"].as_u64().unwrap_or(0)
                        + view["byteLength"].as_u64().unwrap_or(0)
                })
                .max()
                .unwrap_or(0) as usize;
            bytes.truncate(kept.div_ceil(4) * 4);
            rewritten.insert(b, bytes);
        }
        for (&view, &image) in &image_views {
            let b = views[view]["buffer"].as_u64().unwrap_or(0) as usize;
            let buffer = rewritten.get_mut(&b).expect("a buffer of an image");
            buffer.resize(buffer.len().div_ceil(4) * 4, 0);
            let entry = &mut json["bufferViews"][view];
            entry["byteOffset"] = Value::from(buffer.len());
            entry["byteLength"] = Value::from(upscaled[&image].len());
            buffer.extend_from_slice(&upscaled[&image]);
        }
        for (i, image) in self.array("images").iter().enumerate() {
            let Some(uri) = image["uri"].as_str() else {
                continue;
            };
            if uri.starts_with("data:") {
                let encoded = base64::engine::general_purpose::STANDARD.encode(&upscaled[&i]);
                json["images"][i]["uri"] =
                    Value::from(format!("data:{};base64,{encoded}", images[i].mime()));
            } else {
                let file = out.join(relative_path(uri).map_err(|e| self.bad(e))?);
                write_file(&file, &upscaled[&i])?;
                written.push(file);
            }
        }
        // Buffers: the GLB's chunk, data URIs and files, each rewritten if it held images,
        // else copied byte for byte.
        let mut bin = self.bin.clone();
        for (b, buffer) in self.array("buffers").iter().enumerate() {
            let new = rewritten.get(&b);
            if let Some(bytes) = new {
                json["buffers"][b]["byteLength"] = Value::from(bytes.len());
            }
            match buffer["uri"].as_str() {
                None => {
                    if let Some(bytes) = new {
                        bin = Some(bytes.clone());
                    }
                }
                Some(uri) if uri.starts_with("data:") => {
                    if let Some(bytes) = new {
                        let encoded = base64::engine::general_purpose::STANDARD.encode(bytes);
                        json["buffers"][b]["uri"] =
                            Value::from(format!("data:application/octet-stream;base64,{encoded}"));
                    }
                }
                Some(uri) => {
                    let file = out.join(relative_path(uri).map_err(|e| self.bad(e))?);
                    let bytes = match new {
                        Some(bytes) => bytes.clone(),
                        None => self.loaded(buffers, b)?.to_vec(),
                    };
                    write_file(&file, &bytes)?;
                    written.push(file);
                }
            }
        }
        let text = serde_json::to_vec(&json).map_err(|e| self.bad(e))?;
        let model = out.join(self.path.file_name().expect("a model file"));
        let bytes = if is_glb(&self.path) {
            let glb = gltf::binary::Glb {
                // `to_vec` writes the real length.
                header: gltf::binary::Header {
                    magic: *b"glTF",
                    version: 2,
                    length: 0,
                },
                json: text.into(),
                bin: bin.map(Into::into),
            };
            glb.to_vec().map_err(|e| self.bad(e))?
        } else {
            text
        };
        write_atomic(&model, &bytes)?;
        written.insert(0, model);
        Ok(written)
    }
}

pub(super) fn is_glb(path: &Path) -> bool {
    has_extension(path, "glb")
}

pub(super) fn has_extension(path: &Path, extension: &str) -> bool {
    (path.extension().and_then(|e| e.to_str())).is_some_and(|e| e.eq_ignore_ascii_case(extension))
}

/// Writes `bytes` to `file` atomically, making its folder.
pub(super) fn write_file(file: &Path, bytes: &[u8]) -> Result<()> {
    if let Some(parent) = file.parent() {
        std::fs::create_dir_all(parent).map_err(|e| Error::io(parent, e))?;
    }
    write_atomic(file, bytes)
}

/// A URI relative to the model as a path that stays inside the model's folder (and the
/// output's): percent-decoded, no root, no `..`.
pub(super) fn relative_path(uri: &str) -> std::result::Result<PathBuf, String> {
    let decoded = percent_encoding::percent_decode_str(uri)
        .decode_utf8()
        .map_err(|_| format!("URI '{uri}' is not UTF-8"))?;
    let path = PathBuf::from(decoded.as_ref());
    if path
        .components()
        .all(|c| matches!(c, Component::Normal(_) | Component::CurDir))
    {
        Ok(path)
    } else {
        Err(format!(
            "URI '{uri}' leaves the model's folder; matup writes only inside the output folder"
        ))
    }
}

/// A material name as a folder name: letters, digits, `-` and `_`.
pub(super) fn sanitised(name: &str) -> String {
    name.chars()
        .map(|c| {
            if c.is_alphanumeric() || c == '-' || c == '_' {
                c
            } else {
                '_'
            }
        })
        .collect()
}

/// `uses` split by image size (a material's textures may differ in size), each part labelled.
pub(super) fn by_size(
    name: &str,
    material: Option<usize>,
    uses: Vec<(usize, Role)>,
    images: &[Image],
) -> Vec<Group> {
    let mut sizes: Vec<(u32, u32)> = uses.iter().map(|&(i, _)| images[i].size).collect();
    sizes.sort();
    sizes.dedup();
    (sizes.iter())
        .map(|&size| Group {
            label: if sizes.len() == 1 {
                name.to_string()
            } else {
                format!("{name}-{}x{}", size.0, size.1)
            },
            uses: (uses.iter().copied())
                .filter(|&(i, _)| images[i].size == size)
                .collect(),
            material,
        })
        .collect()
}

/// The textures a material uses, each with its role: the core ones, then every
/// `…Texture` of its extensions.
pub(super) fn material_textures(material: &Value) -> Vec<(usize, Role)> {
    let mut found = Vec::new();
    visit_texture_infos(material, &mut |info, role| {
        if let Some(index) = info["index"].as_u64() {
            found.push((index as usize, role));
        }
    });
    found
}

/// Each texture info of a material (its object: `index`, `texCoord`, extensions) with the
/// role of its texture, in [`material_textures`]' order.
pub(super) fn visit_texture_infos(material: &Value, visit: &mut dyn FnMut(&Value, Role)) {
    let pbr = &material["pbrMetallicRoughness"];
    let core = [
        (&pbr["baseColorTexture"], Role::BaseColor),
        (
            &pbr["metallicRoughnessTexture"],
            Role::MetallicRoughness { occlusion: false },
        ),
        (&material["normalTexture"], Role::Normal),
        (&material["occlusionTexture"], Role::Carried { data: true }),
        (&material["emissiveTexture"], Role::Carried { data: false }),
    ];
    for (info, role) in core {
        if info.is_object() {
            visit(info, role);
        }
    }
    pub(super) fn walk(value: &Value, visit: &mut dyn FnMut(&Value, Role)) {
        if let Value::Object(map) = value {
            for (key, value) in map {
                if key.ends_with("Texture") && value["index"].is_u64() {
                    let data = !COLOUR_EXTENSION_TEXTURES.contains(&key.as_str());
                    visit(value, Role::Carried { data });
                } else {
                    walk(value, visit);
                }
            }
        }
    }
    walk(&material["extensions"], visit);
}
