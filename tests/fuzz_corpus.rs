//! The fuzz targets' inputs replayed as ordinary tests (fuzzing itself does not run in CI).
//! Each goes through its fuzz target's own entry (`fuzz/src/lib.rs`), which asserts what the
//! reader promises: refused by name, or read as claimed; never a panic.
//! - `fuzz/seeds/TARGET`, made from `tests/data` by `scripts/fuzz.sh seeds` (files matup
//!   wrote in every format, models, exporters' folder names, settings files): each is accepted.
//! - `fuzz/corpus/TARGET` (what fuzzing kept) and `fuzz/regressions/TARGET` (its findings,
//!   fixed): each is accepted or refused, and nothing panics.

use std::panic::{catch_unwind, AssertUnwindSafe};
use std::path::{Path, PathBuf};

#[path = "../fuzz/src/lib.rs"]
mod entries;

/// The files of `fuzz/FOLDER/TARGET`, sorted (none where it does not exist).
fn inputs(folder: &str, target: &str) -> Vec<PathBuf> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("fuzz")
        .join(folder)
        .join(target);
    let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
        .map(|listing| listing.map(|e| e.unwrap().path()).collect())
        .unwrap_or_default();
    files.sort();
    files
}

/// Whether `entry` accepts the file; a panic names it. A file gone since the folder was listed
/// (a fuzzer running beside the tests shrinks its corpus in place) is skipped.
fn run(entry: fn(&[u8]) -> bool, file: &Path) -> bool {
    let bytes = match std::fs::read(file) {
        Ok(bytes) => bytes,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return false,
        Err(e) => panic!("{}: {e}", file.display()),
    };
    catch_unwind(AssertUnwindSafe(|| entry(&bytes)))
        .unwrap_or_else(|_| panic!("{} panicked", file.display()))
}

/// Every seed of `target` accepted (at least `seeds` of them), then every kept input and
/// finding run.
fn replay(target: &str, entry: fn(&[u8]) -> bool, seeds: usize) {
    let files = inputs("seeds", target);
    assert!(files.len() >= seeds, "{target}: {} seeds", files.len());
    for file in files {
        assert!(run(entry, &file), "{} was refused", file.display());
    }
    for folder in ["corpus", "regressions"] {
        for file in inputs(folder, target) {
            run(entry, &file);
        }
    }
}

#[test]
fn dds_inputs() {
    // Every DDS format matup writes, from three materials' maps.
    replay("dds", entries::dds, 200);
}

#[test]
fn tga_inputs() {
    replay("tga", entries::tga, 30);
}

#[test]
fn other_image_inputs() {
    replay("image", entries::image, 150);
}

#[test]
fn gltf_inputs() {
    replay("gltf", entries::gltf, 2);
}

#[test]
fn glb_inputs() {
    replay("glb", entries::glb, 1);
}

#[test]
fn discovery_inputs() {
    replay("discovery", entries::discovery, 20);
}

#[test]
fn settings_inputs() {
    replay("settings", entries::settings, 3);
}
