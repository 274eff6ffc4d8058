//! A clone of the repository passes its tests alone: no test reads the `shared` folder that
//! sits beside the repository on the developers' machines and in CI (benches, sweeps and
//! `matup learn` may).

use std::path::{Path, PathBuf};

/// Every `.rs` file under `dir`.
fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    for entry in entries {
        let path = entry.unwrap().path();
        if path.is_dir() {
            rust_files(&path, out);
        } else if path.extension().is_some_and(|e| e == "rs") {
            out.push(path);
        }
    }
}

/// The test code of every package: its `tests/` folder, each source file's `#[cfg(test)]`
/// part, and the `tests.rs` files that hold a module's tests.
fn test_sources(root: &Path) -> Vec<(PathBuf, String)> {
    let mut packages = vec![root.to_path_buf()];
    for group in ["crates", "examples"] {
        for entry in std::fs::read_dir(root.join(group)).unwrap() {
            let path = entry.unwrap().path();
            if path.join("Cargo.toml").is_file() {
                packages.push(path);
            }
        }
    }
    let mut sources = Vec::new();
    for package in packages {
        let mut files = Vec::new();
        rust_files(&package.join("tests"), &mut files);
        for file in files {
            let text = std::fs::read_to_string(&file).unwrap();
            sources.push((file, text));
        }
        let mut files = Vec::new();
        rust_files(&package.join("src"), &mut files);
        for file in files {
            let text = std::fs::read_to_string(&file).unwrap();
            // A module's tests in a file of their own (`stream/tests.rs`) are test code whole.
            if file.file_name().is_some_and(|n| n == "tests.rs") {
                sources.push((file, text));
            } else if let Some((_, tests)) = text.split_once("#[cfg(test)]") {
                sources.push((file, tests.to_string()));
            }
        }
    }
    sources
}

/// The files whose test code names `needle`.
fn naming(sources: &[(PathBuf, String)], needle: &str) -> Vec<String> {
    sources
        .iter()
        .filter(|(_, text)| text.contains(needle))
        .map(|(file, _)| file.display().to_string())
        .collect()
}

#[test]
fn no_test_reads_the_shared_folder_beside_the_repository() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let sources = test_sources(root);
    // This file, the facade's tests, a crate's tests and a crate's unit tests are all seen.
    for part in [
        "tests/self_contained.rs",
        "crates/matup-cli/tests/cli.rs",
        "crates/matup-core/src/io/image_file.rs",
        "crates/matup-core/src/io/stream/tests.rs",
    ] {
        assert!(
            sources.iter().any(|(file, _)| file.ends_with(part)),
            "{part} is scanned"
        );
    }
    // Spelled in pieces, so that this file does not name it.
    let shared = ["..", "shared"].join("/");
    assert!(
        naming(&sources, "self_contained").len() == 1,
        "the scan reads the text"
    );
    let offenders = naming(&sources, &shared);
    assert!(
        offenders.is_empty(),
        "tests name {shared}, which a clone of the repository does not have: {offenders:?}"
    );
}
