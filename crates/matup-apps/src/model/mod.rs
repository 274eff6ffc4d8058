//! glTF 2.0 models (`.gltf` with its files, or `.glb`) upscaled whole. The model's materials
//! say what each texture holds, so nothing is guessed: base colour, `metallicRoughness`
//! (roughness in G, metallic in B, R kept, or occlusion where `occlusionTexture` shares the
//! image), OpenGL normals, occlusion (R) and emission (colour); the textures of `KHR_materials_*`
//! extensions are carried, colour or data as their specifications say. Images are PNG, JPEG
//! or WebP (`EXT_texture_webp`, whose PNG or JPEG fallbacks are upscaled too). Each image is
//! upscaled once, with the first material that uses it, and the model comes back as it was:
//! every JSON field and extension kept, geometry bytes where they were, only the images new.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use matup_core::io::{MaterialPaths, Names};
use matup_core::progress::Progress;
use matup_core::{layout::Packing, SaveOptions};
use matup_core::{load_material, Error, LoadOptions, NormalConvention, Result};
use matup_method::plan::check_settings;
use matup_method::report::RunReport;
use matup_method::Config;

use crate::folder::upscale_to_folder;

mod gltf;

use gltf::{has_extension, is_glb, same_folder, Model, Role};

/// Where a model's per-material runs leave their preview and `run.json`, inside the output.
pub const RUNS_FOLDER: &str = "matup-runs";

/// The working folder inside the output where images are unpacked and upscaled (removed once
/// the model is written).
const WORK_FOLDER: &str = ".matup-model";

/// Whether `path` names a glTF model (`.gltf` or `.glb`, any case).
pub fn is_model_file(path: &Path) -> bool {
    has_extension(path, "gltf") || is_glb(path)
}

/// The files a model's result depends on: the model and the images and buffers its URIs name.
pub fn model_files(path: &Path) -> Result<Vec<PathBuf>> {
    let model = Model::read(path)?;
    let mut files = vec![path.to_path_buf()];
    for key in ["images", "buffers"] {
        for entry in model.array(key) {
            if let Some(uri) = entry["uri"].as_str().filter(|u| !u.starts_with("data:")) {
                files.push(model.file_of(uri)?);
            }
        }
    }
    Ok(files)
}

/// What [`upscale_model`] did.
pub struct ModelRun {
    /// The model, then the image and buffer files beside it, then each run's preview and
    /// `run.json`.
    pub written: Vec<PathBuf>,
    /// One run per group of images upscaled together, with its label.
    pub runs: Vec<(String, RunReport)>,
    /// What the reader should know: images shared across roles, unused images.
    pub notes: Vec<String>,
}

/// Upscales every texture of the model at `path` into `out` (created; never the model's own
/// folder): `out/<model file>` with its images and buffers, each run's preview and `run.json`
/// under `out/matup-runs/`. Each image keeps its format: `save.format` is refused.
pub fn upscale_model(
    path: &Path,
    config: &Config,
    out: &Path,
    save: &SaveOptions,
    load: &LoadOptions,
    memory_limit: Option<u64>,
    progress: &dyn Progress,
) -> Result<ModelRun> {
    if let Some(format) = save.format {
        return Err(Error::Invalid(format!(
            "--format {format}: a model's images keep their own formats (its JSON names them); \
             leave --format out"
        )));
    }
    // Settings that cannot run are refused before the output folder is made; each group's
    // run then plans its own material.
    check_settings(config)?;
    let model = Model::read(path)?;
    if same_folder(out, &model.folder) {
        return Err(Error::file(
            out,
            "is the model's own folder; write the upscaled model elsewhere",
        ));
    }
    // Everything the model needs is read before any work: a missing buffer or image is
    // reported now, not after an hour of upscaling.
    let buffers = model.buffers()?;
    let images = model.images(&buffers)?;
    let groups = model.groups(&images)?;
    let atlases = model.atlases(&buffers);

    std::fs::create_dir_all(out).map_err(|e| Error::io(out, e))?;
    // A killed run's working folder is cleared first; this run's goes when it ends, however
    // it ends (an error, Ctrl-C).
    let work = WorkFolder(out.join(WORK_FOLDER));
    let _ = std::fs::remove_dir_all(&work.0);
    let work = &work.0;
    let mut upscaled: BTreeMap<usize, Vec<u8>> = BTreeMap::new();
    let mut runs = Vec::new();
    let mut written = Vec::new();
    let save = SaveOptions {
        names: Names::Keep,
        normal_convention: None,
        ..save.clone()
    };
    for (g, group) in groups.groups.iter().enumerate() {
        if progress.cancelled() {
            return Err(Error::Interrupted);
        }
        progress.note(&format!(
            "{}: {}",
            group.label,
            (group.uses.iter())
                .map(|&(image, role)| format!("{} as {}", images[image].name, role.words()))
                .collect::<Vec<_>>()
                .join(", ")
        ));
        let input = work.join(format!("in-{g}"));
        let output = work.join(format!("out-{g}"));
        std::fs::create_dir_all(&input).map_err(|e| Error::io(&input, e))?;
        let mut paths = MaterialPaths::default();
        for &(image, role) in &group.uses {
            let file = input.join(images[image].file_name());
            std::fs::write(&file, &images[image].bytes).map_err(|e| Error::io(&file, e))?;
            match role {
                Role::BaseColor => paths.base_color = Some(file),
                Role::Normal => paths.normal = Some(file),
                Role::MetallicRoughness { occlusion } => {
                    let key = if occlusion { "orm" } else { "gltf" };
                    paths.packed = Some(file);
                    paths.packing = Some(key.parse::<Packing>()?);
                }
                Role::Carried { data } => paths.carried.push((file, data)),
            }
        }
        let options = LoadOptions {
            paths,
            normal_convention: Some(NormalConvention::OpenGl),
            max_texels: load.max_texels,
        };
        let mut material = load_material(None, &options)
            .map_err(|e| Error::file(path, format!("{}: {e}", group.label)))?;
        // A UV atlas is not wrapped: islands across its edges are no neighbours.
        let atlas = (group.material).is_some_and(|m| atlases.contains(&m));
        if let Some(origin) = material.origin.as_mut() {
            // A texture whose file name says DirectX is read so, and the run says why.
            if origin.normal_convention == NormalConvention::OpenGl {
                origin.normal_evidence = "glTF's own: its specification says OpenGL".into();
            }
            origin.tiling = atlas.then(|| {
                (
                    false,
                    "a UV atlas: every primitive of its material reads one copy of it".into(),
                )
            });
        }
        let run = upscale_to_folder(
            &material,
            config,
            &output,
            &save,
            false,
            memory_limit,
            None,
            progress,
        )?;
        for &(image, _) in &group.uses {
            let file = output.join(images[image].file_name());
            let bytes = std::fs::read(&file).map_err(|e| Error::io(&file, e))?;
            upscaled.insert(image, bytes);
        }
        let kept = out.join(RUNS_FOLDER).join(&group.label);
        std::fs::create_dir_all(&kept).map_err(|e| Error::io(&kept, e))?;
        for name in ["preview.png", "run.json"] {
            let to = kept.join(name);
            std::fs::rename(output.join(name), &to).map_err(|e| Error::io(&to, e))?;
            written.push(to);
        }
        runs.push((group.label.clone(), run.report));
    }
    let mut files = model.write(&images, &upscaled, &buffers, out)?;
    files.append(&mut written);
    Ok(ModelRun {
        written: files,
        runs,
        notes: groups.notes,
    })
}

/// The working folder, removed when dropped: on success, on an error and on Ctrl-C alike.
struct WorkFolder(PathBuf);

impl Drop for WorkFolder {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

#[cfg(test)]
mod tests {
    use super::gltf::*;
    use super::*;
    use serde_json::Value;

    fn model(json: Value) -> Model {
        Model {
            path: PathBuf::from("model.gltf"),
            json,
            bin: None,
            folder: PathBuf::new(),
        }
    }

    fn images(sizes: &[u32]) -> Vec<Image> {
        (sizes.iter().enumerate())
            .map(|(i, &s)| Image {
                bytes: Vec::new(),
                encoding: Encoding::Png,
                size: (s, s),
                name: format!("image {i}"),
                stem: format!("image-{i}"),
            })
            .collect()
    }

    #[test]
    fn shared_images_are_upscaled_once_and_an_orm_image_is_one_file() {
        let json = serde_json::json!({
            "asset": {"version": "2.0"},
            "textures": [{"source": 0}, {"source": 1}, {"source": 2}, {"source": 3}],
            "materials": [
                {"name": "a b", "pbrMetallicRoughness": {
                    "baseColorTexture": {"index": 0},
                    "metallicRoughnessTexture": {"index": 2}},
                 "occlusionTexture": {"index": 2},
                 "normalTexture": {"index": 1}},
                {"pbrMetallicRoughness": {"baseColorTexture": {"index": 3}},
                 "normalTexture": {"index": 1},
                 "extensions": {"KHR_materials_sheen": {"sheenColorTexture": {"index": 2},
                                                        "sheenRoughnessTexture": {"index": 3}}}}
            ]
        });
        let groups = model(json).groups(&images(&[64, 64, 64, 32, 8])).unwrap();
        let uses: Vec<(&str, Vec<(usize, Role)>)> = (groups.groups.iter())
            .map(|g| (g.label.as_str(), g.uses.clone()))
            .collect();
        assert_eq!(
            uses,
            [
                (
                    "0-a_b",
                    vec![
                        (0, Role::BaseColor),
                        (2, Role::MetallicRoughness { occlusion: true }),
                        (1, Role::Normal),
                    ]
                ),
                // The shared normal and the first material's ORM are not upscaled again.
                ("material-1", vec![(3, Role::BaseColor)]),
                // An image no material uses is still upscaled.
                ("unused-images", vec![(4, Role::Carried { data: false })]),
            ]
        );
        // The ORM image as sheen colour, and image 3 as sheen roughness, are said.
        assert_eq!(groups.notes.len(), 3, "{:?}", groups.notes);
    }

    #[test]
    fn textures_of_other_sizes_are_upscaled_apart_and_bad_references_are_refused() {
        let json = serde_json::json!({
            "asset": {"version": "2.0"},
            "textures": [{"source": 0}, {"source": 1}, {"extensions": {"KHR_texture_basisu": {"source": 0}}}],
            "materials": [{"pbrMetallicRoughness": {"baseColorTexture": {"index": 0}},
                           "normalTexture": {"index": 1}}]
        });
        let groups = model(json.clone()).groups(&images(&[128, 64])).unwrap();
        let labels: Vec<&str> = groups.groups.iter().map(|g| g.label.as_str()).collect();
        assert_eq!(labels, ["material-0-64x64", "material-0-128x128"]);

        let mut basis = json.clone();
        basis["materials"][0]["emissiveTexture"] = serde_json::json!({"index": 2});
        let error = model(basis)
            .groups(&images(&[128, 64]))
            .err()
            .unwrap()
            .to_string();
        assert!(
            error.contains("model.gltf") && error.contains("texture 2"),
            "{error}"
        );

        let mut missing = json;
        missing["materials"][0]["emissiveTexture"] = serde_json::json!({"index": 9});
        let error = model(missing)
            .groups(&images(&[128, 64]))
            .err()
            .unwrap()
            .to_string();
        assert!(error.contains("texture 9 does not exist"), "{error}");
    }

    #[test]
    fn webp_textures_and_their_fallbacks_are_upscaled_in_runs_of_their_own() {
        // EXT_texture_webp as gltf-transform writes it: WebP images, each texture's core
        // `source` a PNG fallback; the normal has WebP only.
        let json = serde_json::json!({
            "asset": {"version": "2.0"},
            "extensionsUsed": ["EXT_texture_webp"],
            "textures": [
                {"source": 0, "extensions": {"EXT_texture_webp": {"source": 2}}},
                {"extensions": {"EXT_texture_webp": {"source": 3}}},
                {"source": 1, "extensions": {"EXT_texture_webp": {"source": 4}}}
            ],
            "materials": [{"pbrMetallicRoughness": {"baseColorTexture": {"index": 0},
                                                    "metallicRoughnessTexture": {"index": 2}},
                           "normalTexture": {"index": 1}}]
        });
        let groups = model(json).groups(&images(&[64; 5])).unwrap();
        let uses: Vec<(&str, Vec<(usize, Role)>)> = (groups.groups.iter())
            .map(|g| (g.label.as_str(), g.uses.clone()))
            .collect();
        let metallic_roughness = Role::MetallicRoughness { occlusion: false };
        assert_eq!(
            uses,
            [
                (
                    "material-0",
                    vec![
                        (2, Role::BaseColor),
                        (4, metallic_roughness),
                        (3, Role::Normal)
                    ]
                ),
                (
                    "material-0-fallback",
                    vec![(0, Role::BaseColor), (1, metallic_roughness)]
                ),
            ]
        );
        assert!(groups.notes.is_empty(), "{:?}", groups.notes);
    }

    #[test]
    fn uris_stay_inside_the_folder() {
        assert_eq!(
            relative_path("textures/a%20b.png").unwrap(),
            PathBuf::from("textures/a b.png")
        );
        assert!(relative_path("../a.png").is_err());
        assert!(relative_path("%2e%2e/a.png").is_err());
        assert!(relative_path("/etc/a.png").is_err());
    }

    #[test]
    fn a_glb_whose_header_states_less_than_itself_is_refused() {
        // The fuzzing finding (fuzz/regressions/glb), as a message a user can act on.
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("short.glb");
        let mut bytes = b"glTF".to_vec();
        bytes.extend(2u32.to_le_bytes());
        bytes.extend(1u32.to_le_bytes());
        bytes.extend(b"\xb8\x02\0\0JSON{}");
        std::fs::write(&path, &bytes).unwrap();
        let error = Model::read(&path).err().expect("refused").to_string();
        assert!(
            error.contains("short.glb") && error.contains("a length of 1 bytes"),
            "{error}"
        );
    }

    #[cfg(unix)]
    #[test]
    fn a_link_out_of_the_folder_is_refused() {
        let dir = tempfile::tempdir().unwrap();
        let (model, outside) = (dir.path().join("model"), dir.path().join("secret.png"));
        std::fs::create_dir(&model).unwrap();
        std::fs::write(&outside, b"not the model's").unwrap();
        std::fs::write(model.join("inside.png"), b"the model's").unwrap();
        std::os::unix::fs::symlink(&outside, model.join("link.png")).unwrap();
        std::os::unix::fs::symlink(model.join("inside.png"), model.join("near.png")).unwrap();
        let gltf = model.join("m.gltf");
        std::fs::write(&gltf, r#"{"asset": {"version": "2.0"}}"#).unwrap();
        let m = Model::read(&gltf).unwrap();
        let err = m.uri_bytes("link.png").unwrap_err().to_string();
        assert!(
            err.contains("outside the model's folder") && err.contains("link.png"),
            "{err}"
        );
        assert_eq!(m.uri_bytes("near.png").unwrap(), b"the model's");
        assert_eq!(m.uri_bytes("inside.png").unwrap(), b"the model's");
    }
}
