//! Finding the materials of a library: every folder under it whose image files matup
//! recognises as maps, and every glTF model (whose folder's images, and folders below, are
//! the model's own).

use std::path::{Path, PathBuf};

use walkdir::WalkDir;

use matup_core::io::{discover, is_image_file, FileRole};
use matup_core::material::NormalConvention;
use matup_core::{Error, Result};

use crate::model::is_model_file;

/// The materials under a library folder, and the folders passed over.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Library {
    pub root: PathBuf,
    /// Folders holding a material, relative to the root ("" for the root itself), and glTF
    /// model files, in walking order (sorted by name).
    pub materials: Vec<PathBuf>,
    /// Folders holding files but no material, with why.
    pub skipped: Vec<(PathBuf, String)>,
}

/// A material's relative path with '/' separators ("." for the library root): its name in
/// summaries and the key its shard is chosen by, the same on every operating system.
pub fn material_name(relative: &Path) -> String {
    let parts: Vec<String> = relative
        .components()
        .map(|c| c.as_os_str().to_string_lossy().into_owned())
        .collect();
    if parts.is_empty() {
        ".".into()
    } else {
        parts.join("/")
    }
}

/// Walks `root` (following no links, in name order, hidden folders left out) and sorts its
/// folders into materials and the rest. `exclude` (the output folder, when it lies inside
/// the library) is not entered. A folder whose maps conflict (two base colours) is still a
/// material: loading it fails with the reason, and the batch records that.
pub fn find_materials(root: &Path, exclude: Option<&Path>) -> Result<Library> {
    if !root.is_dir() {
        return Err(Error::file(root, "library folder not found"));
    }
    let exclude = exclude.and_then(|p| p.canonicalize().ok());
    let mut library = Library {
        root: root.to_path_buf(),
        ..Default::default()
    };
    let mut walk = WalkDir::new(root)
        .sort_by_file_name()
        .into_iter()
        .filter_entry(|e| {
            let hidden = e.depth() > 0 && e.file_name().to_string_lossy().starts_with('.');
            let excluded = exclude
                .as_ref()
                .is_some_and(|x| e.path().canonicalize().is_ok_and(|p| &p == x));
            e.file_type().is_dir() && !hidden && !excluded
        });
    while let Some(entry) = walk.next() {
        let entry = entry.map_err(|e| {
            let path = e.path().unwrap_or(root).to_path_buf();
            Error::file(&path, format!("cannot read the library: {e}"))
        })?;
        let folder = entry.path();
        let relative = folder
            .strip_prefix(root)
            .expect("walkdir yields paths under its root")
            .to_path_buf();
        let files: Vec<PathBuf> = std::fs::read_dir(folder)
            .map_err(|e| Error::io(folder, e))?
            .filter_map(|e| e.ok())
            .filter(|e| e.file_type().is_ok_and(|t| t.is_file()))
            .map(|e| e.path())
            .filter(|p| {
                !p.file_name()
                    .is_some_and(|n| n.to_string_lossy().starts_with('.'))
            })
            .collect();
        if files.is_empty() {
            continue; // a folder of folders (a category), or empty
        }
        let mut models: Vec<PathBuf> = files.iter().filter(|p| is_model_file(p)).cloned().collect();
        if !models.is_empty() {
            models.sort();
            (library.materials)
                .extend(models.iter().map(|m| relative.join(m.file_name().unwrap())));
            walk.skip_current_dir(); // its folders hold the models' textures
            continue;
        }
        let images = files.iter().filter(|p| is_image_file(p)).count();
        if images == 0 {
            library
                .skipped
                .push((relative, "no image files".to_string()));
            continue;
        }
        // Images that only ride along (a photo, an unnamed picture) do not make a material:
        // one file must be a map or a packed file.
        let holds_a_map = |files: &[(PathBuf, FileRole)]| {
            files
                .iter()
                .any(|(_, role)| !matches!(role, FileRole::Carried { .. }))
        };
        match discover(folder, NormalConvention::default()) {
            Ok(found) if !holds_a_map(&found.files) => library.skipped.push((
                relative,
                format!("{images} image file(s), none named as a material map"),
            )),
            _ => library.materials.push(relative),
        }
    }
    Ok(library)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn finds_materials_and_lists_the_rest() {
        let dir = tempfile::tempdir().unwrap();
        let root = dir.path();
        let touch = |rel: &str| {
            let p = root.join(rel);
            std::fs::create_dir_all(p.parent().unwrap()).unwrap();
            std::fs::write(p, b"").unwrap();
        };
        touch("wood/oak/oak_basecolor.png");
        touch("props/chair.gltf");
        touch("props/chair.glb");
        touch("props/textures/chair_baseColor.png");
        touch("wood/oak/oak_normal.png");
        touch("metal/plate/Color.jpg");
        touch("docs/readme.txt");
        touch("photos/holiday.jpg");
        touch("out/copy/baseColor.png");
        touch(".cache/baseColor.png");
        std::fs::create_dir_all(root.join("empty")).unwrap();
        let library = find_materials(root, Some(&root.join("out"))).unwrap();
        assert_eq!(
            library.materials,
            vec![
                PathBuf::from("metal/plate"),
                PathBuf::from("props/chair.glb"),
                PathBuf::from("props/chair.gltf"),
                PathBuf::from("wood/oak")
            ]
        );
        let skipped: Vec<&str> = library
            .skipped
            .iter()
            .map(|s| s.0.to_str().unwrap())
            .collect();
        assert_eq!(skipped, vec!["docs", "photos"]);
        assert_eq!(material_name(&library.materials[3]), "wood/oak");
        assert_eq!(material_name(Path::new("")), ".");
    }
}
