//! Where a network comes from: a `NAME.onnx` file with its sidecar `NAME.toml` in a model
//! folder, or one of the networks built into matup, so that an installed `matup` runs its
//! defaults from any folder.

use std::fmt;
use std::path::{Path, PathBuf};

use matup_core::{Error, Result};
use tract_onnx::prelude::*;

use serde::Deserialize;
use tract_onnx::pb::ModelProto;

/// What a sidecar `NAME.toml` says about `NAME.onnx`.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ModelInfo {
    pub scale: usize,
    #[serde(default = "unit_range")]
    pub input_range: [f32; 2],
    #[serde(default = "unit_range")]
    pub output_range: [f32; 2],
    #[serde(default = "rgb")]
    pub channel_order: String,
    #[serde(default = "default_tile")]
    pub tile: usize,
    #[serde(default)]
    pub overlap: usize,
    #[serde(default = "default_batch")]
    pub batch: usize,
    #[serde(default)]
    pub licence: String,
    #[serde(default)]
    pub source: String,
    #[serde(default)]
    pub description: String,
}

fn unit_range() -> [f32; 2] {
    [0.0, 1.0]
}
fn rgb() -> String {
    "rgb".into()
}
fn default_tile() -> usize {
    128
}
fn default_batch() -> usize {
    4
}

/// A network compiled into matup: its ONNX bytes and its sidecar's text.
#[derive(Debug)]
pub struct BuiltIn {
    pub name: &'static str,
    pub onnx: &'static [u8],
    pub sidecar: &'static str,
}

/// The networks matup's defaults name: the SPAN ×4 tuned for material maps
/// (`onnx:span_x4_materials`, the default at every scale), its tuning for maps from lossy files
/// (`onnx:span_x4_degraded`, the default where the input is degraded), its tuning for JPEG
/// maps (`onnx:span_x4_jpeg`, the default where every lossy map is a JPEG) and stock SPAN ×4
/// (`onnx:span_x4_ch48`). `models/README.md` is their model card.
pub const BUILT_IN: [BuiltIn; 4] = [
    BuiltIn {
        name: "span_x4_materials",
        onnx: include_bytes!("../../../../models/span_x4_materials.onnx"),
        sidecar: include_str!("../../../../models/span_x4_materials.toml"),
    },
    BuiltIn {
        name: "span_x4_ch48",
        onnx: include_bytes!("../../../../models/span_x4_ch48.onnx"),
        sidecar: include_str!("../../../../models/span_x4_ch48.toml"),
    },
    BuiltIn {
        name: "span_x4_degraded",
        onnx: include_bytes!("../../../../models/span_x4_degraded.onnx"),
        sidecar: include_str!("../../../../models/span_x4_degraded.toml"),
    },
    BuiltIn {
        name: "span_x4_jpeg",
        onnx: include_bytes!("../../../../models/span_x4_jpeg.onnx"),
        sidecar: include_str!("../../../../models/span_x4_jpeg.toml"),
    },
];

/// A network's graph: a file, or built into matup.
#[derive(Clone, Debug)]
pub enum ModelSource {
    File(PathBuf),
    BuiltIn(&'static BuiltIn),
}

impl fmt::Display for ModelSource {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            ModelSource::File(path) => write!(f, "{}", path.display()),
            ModelSource::BuiltIn(b) => write!(f, "{} (built into matup)", b.name),
        }
    }
}

impl ModelSource {
    /// The file, if the network is one.
    pub fn path(&self) -> Option<&Path> {
        match self {
            ModelSource::File(path) => Some(path),
            ModelSource::BuiltIn(_) => None,
        }
    }

    /// The sidecar: `sidecar` where given, else `NAME.toml` beside a file, or the built-in's.
    pub fn info(&self, sidecar: Option<&Path>) -> Result<ModelInfo> {
        match (self, sidecar) {
            (_, Some(path)) => read_sidecar_file(path),
            (ModelSource::File(path), None) => read_sidecar(path),
            (ModelSource::BuiltIn(b), None) => toml::from_str(b.sidecar).map_err(|e| {
                self.error("invalid built-in sidecar", e) // a build of matup with a bad file
            }),
        }
    }

    /// The files a load of it reads: the model and its sidecar (`sidecar` where given, else
    /// `NAME.toml` beside it); a built-in's given sidecar only.
    pub fn files(&self, sidecar: Option<&Path>) -> Vec<PathBuf> {
        let model = match self {
            ModelSource::File(path) => Some(path.clone()),
            ModelSource::BuiltIn(_) => None,
        };
        let sidecar = sidecar
            .map(Path::to_path_buf)
            .or_else(|| model.as_deref().map(sidecar_path));
        model.into_iter().chain(sidecar).collect()
    }

    /// The ONNX model as read from the protobuf.
    pub fn proto(&self) -> Result<ModelProto> {
        let read = match self {
            ModelSource::File(path) => {
                if !path.is_file() {
                    return Err(self.error("cannot open", "no such file"));
                }
                tract_onnx::onnx().proto_model_for_path(path)
            }
            ModelSource::BuiltIn(b) => tract_onnx::onnx().proto_model_for_read(&mut &b.onnx[..]),
        };
        read.map_err(|e| self.error("not a readable ONNX model", format!("{e:#}")))
    }

    /// The model as tract builds it.
    pub fn tract_model(&self) -> Result<InferenceModel> {
        let read = match self {
            ModelSource::File(path) => tract_onnx::onnx().model_for_path(path),
            ModelSource::BuiltIn(b) => tract_onnx::onnx().model_for_read(&mut &b.onnx[..]),
        };
        read.map_err(|e| self.error("not a readable ONNX model", format!("{e:#}")))
    }

    /// An error about this network: `SOURCE: what: detail`.
    pub fn error(&self, what: &str, detail: impl fmt::Display) -> Error {
        Error::Plugin {
            plugin: "onnx".into(),
            message: format!("{self}: {what}: {detail}"),
        }
    }
}

/// The folders searched for `onnx:NAME` before the built-in networks: `$MATUP_MODELS`
/// (`:`-separated, as `--models-dir` sets it) and `./models`.
pub fn model_dirs() -> Vec<PathBuf> {
    let mut dirs: Vec<PathBuf> = std::env::var("MATUP_MODELS")
        .map(|v| std::env::split_paths(&v).collect())
        .unwrap_or_default();
    dirs.push(PathBuf::from("models"));
    dirs
}

/// Every network `onnx:NAME` finds, each name once (the first found wins): each `NAME.onnx`
/// with a readable sidecar in the model folders, then the built-in networks.
pub fn available_models() -> Vec<(String, ModelSource, ModelInfo)> {
    let mut found: Vec<(String, ModelSource, ModelInfo)> = Vec::new();
    for dir in model_dirs() {
        let Ok(entries) = std::fs::read_dir(&dir) else {
            continue;
        };
        let mut paths: Vec<PathBuf> = entries.filter_map(|e| e.ok().map(|e| e.path())).collect();
        paths.sort();
        for path in paths {
            if path.extension().is_some_and(|e| e == "onnx") {
                let name = path
                    .file_stem()
                    .unwrap_or_default()
                    .to_string_lossy()
                    .into_owned();
                if found.iter().any(|f| f.0 == name) {
                    continue;
                }
                if let Ok(info) = read_sidecar(&path) {
                    found.push((name, ModelSource::File(path), info));
                }
            }
        }
    }
    for b in &BUILT_IN {
        if !found.iter().any(|f| f.0 == b.name) {
            let source = ModelSource::BuiltIn(b);
            if let Ok(info) = source.info(None) {
                found.push((b.name.to_string(), source, info));
            }
        }
    }
    found
}

/// A path (`…/x.onnx`) as given, or a model name: a file in the model folders, else a
/// built-in network.
pub fn resolve(model: &str) -> Result<ModelSource> {
    if model.ends_with(".onnx") || model.contains(std::path::MAIN_SEPARATOR) {
        return Ok(ModelSource::File(PathBuf::from(model)));
    }
    for dir in model_dirs() {
        let path = dir.join(format!("{model}.onnx"));
        if path.is_file() {
            return Ok(ModelSource::File(path));
        }
    }
    if let Some(b) = BUILT_IN.iter().find(|b| b.name == model) {
        return Ok(ModelSource::BuiltIn(b));
    }
    let known: Vec<String> = available_models().into_iter().map(|m| m.0).collect();
    Err(Error::Plugin {
        plugin: "onnx".into(),
        message: format!(
            "no model '{model}' in {} or built into matup; known models: {}",
            model_dirs()
                .iter()
                .map(|d| d.display().to_string())
                .collect::<Vec<_>>()
                .join(", "),
            known.join(", ")
        ),
    })
}

/// Where `NAME.onnx`'s sidecar lies: `NAME.toml` beside it.
fn sidecar_path(model: &Path) -> PathBuf {
    model.with_extension("toml")
}

/// The sidecar `NAME.toml` of `NAME.onnx`.
pub fn read_sidecar(model: &Path) -> Result<ModelInfo> {
    read_sidecar_file(&sidecar_path(model))
}

/// A sidecar read from `path`, wherever it is (`onnx:MODEL,sidecar=PATH`: a network in a
/// folder the user cannot write to, described from elsewhere).
pub fn read_sidecar_file(path: &Path) -> Result<ModelInfo> {
    let text = std::fs::read_to_string(path).map_err(|e| Error::Plugin {
        plugin: "onnx".into(),
        message: format!(
            "{}: cannot read the model's sidecar ({e}); it states the scale and value ranges",
            path.display()
        ),
    })?;
    toml::from_str(&text).map_err(|e| Error::Plugin {
        plugin: "onnx".into(),
        message: format!("{}: {e}", path.display()),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_built_in_networks_are_the_shipped_files() {
        let models = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../models");
        for b in &BUILT_IN {
            let file = std::fs::read(models.join(format!("{}.onnx", b.name))).unwrap();
            assert!(
                file == b.onnx,
                "{}: the built-in bytes are the file's",
                b.name
            );
            let info = ModelSource::BuiltIn(b).info(None).unwrap();
            assert_eq!(info.scale, 4, "{}", b.name);
        }
    }

    #[test]
    fn a_name_finds_a_built_in_network_when_no_folder_has_it() {
        // The crate's folder has no models/ beside it.
        match resolve("span_x4_materials").unwrap() {
            ModelSource::BuiltIn(b) => assert_eq!(b.name, "span_x4_materials"),
            other => panic!("found {other}"),
        }
        let e = resolve("span_x9").unwrap_err().to_string();
        assert!(
            e.contains("span_x9") && e.contains("span_x4_materials") && e.contains("built into"),
            "{e}"
        );
        let listed = available_models();
        assert!(listed
            .iter()
            .any(|(name, source, _)| name == "span_x4_ch48" && source.path().is_none()));
    }
}
