//! One fuzz input through one of matup's readers: the bodies of the fuzz targets
//! (`fuzz/fuzz_targets/`), which `tests/fuzz_corpus.rs` also replays over the seed corpus and
//! every crash file, as ordinary tests. An input may be refused (an `Err` naming the file) but
//! must never panic, hang or exhaust memory; what is read must be what the reader promises.
//! Each entry says whether its input was accepted (read, or upscaled): every seed, a file that
//! matup wrote or an exporter's names, must be.
//!
//! The readers take paths, as users give them, so each input is written to a scratch folder
//! first (`TMPDIR` on a RAM disk keeps that cheap).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use matup_apps::model::upscale_model;
use matup_core::io::{discover, encode_png8, read_image};
use matup_core::progress::Silent;
use matup_core::{LoadOptions, Map, NormalConvention, SaveOptions};
use matup_method::plan::{levels_of, Reach};
use matup_method::Config;

// Linked for their registrations: the kernel upsamplers and the shading models a model's run
// uses.
extern crate matup_shading;
extern crate matup_upsamplers;

/// The largest image an input may claim, in texels: small, so that fuzzing spends its time in
/// the parsers rather than in decoding big images (the refusal itself is under test too).
const MAX_TEXELS: u64 = 1 << 16;

/// A DDS file: the header, its DX10 extension and every block format's decoder.
pub fn dds(data: &[u8]) -> bool {
    read_as(data, "map.dds")
}

/// A TGA file, plain or run-length encoded.
pub fn tga(data: &[u8]) -> bool {
    read_as(data, "map.tga")
}

/// The other formats matup reads (PNG, JPEG, BMP, TIFF, EXR, WebP): the first byte picks the
/// extension, the rest is the file.
pub fn image(data: &[u8]) -> bool {
    const OTHERS: [&str; 6] = ["png", "jpg", "bmp", "tif", "exr", "webp"];
    data.split_first().is_some_and(|(&pick, bytes)| {
        read_as(
            bytes,
            &format!("map.{}", OTHERS[pick as usize % OTHERS.len()]),
        )
    })
}

/// A `.gltf` model's JSON, beside a small PNG (`t.png`) and a buffer (`b.bin`) its URIs may
/// name, upscaled whole ×2 with bilinear.
pub fn gltf(data: &[u8]) -> bool {
    let scratch = scratch();
    let folder = scratch.path().join("model");
    std::fs::create_dir(&folder).unwrap();
    std::fs::write(folder.join("t.png"), small_png()).unwrap();
    std::fs::write(folder.join("b.bin"), [0u8; 64]).unwrap();
    std::fs::write(folder.join("model.gltf"), data).unwrap();
    upscale_whole(&folder.join("model.gltf"), scratch.path())
}

/// A `.glb` model (JSON and binary chunks), upscaled whole ×2 with bilinear.
pub fn glb(data: &[u8]) -> bool {
    let scratch = scratch();
    let folder = scratch.path().join("model");
    std::fs::create_dir(&folder).unwrap();
    std::fs::write(folder.join("model.glb"), data).unwrap();
    upscale_whole(&folder.join("model.glb"), scratch.path())
}

/// Folder discovery and the layout table: one file name per line in, roles out. Every file
/// given a role is one of the folder's, and none is given two.
pub fn discovery(data: &[u8]) -> bool {
    let scratch = scratch();
    let text = String::from_utf8_lossy(data);
    let mut names = Vec::new();
    for name in text.lines().take(24) {
        // Names a file system takes: no separators, no NUL, not `.` or `..`, not too long.
        let usable = !name.is_empty()
            && name.len() <= 120
            && name != "."
            && name != ".."
            && !name.contains(['/', '\\', '\0']);
        if usable && std::fs::write(scratch.path().join(name), b"").is_ok() {
            names.push(name.to_string());
        }
    }
    let mut accepted = true;
    for convention in [NormalConvention::OpenGl, NormalConvention::DirectX] {
        let Ok(found) = discover(scratch.path(), convention) else {
            accepted = false;
            continue;
        };
        let mut seen = BTreeMap::new();
        for (path, role) in &found.files {
            let name = path.file_name().unwrap().to_string_lossy().to_string();
            assert!(names.contains(&name), "{name} is not in the folder");
            assert!(
                seen.insert(name.clone(), role).is_none(),
                "{name} is given two roles"
            );
        }
        for picture in &found.pictures {
            let name = picture.file_name().unwrap().to_string_lossy().to_string();
            assert!(!seen.contains_key(&name), "{name} is a map and a picture");
        }
    }
    accepted
}

/// Settings as a TOML file: what parses and validates prints back to the same settings, and
/// plans a run for any input size without panicking.
pub fn settings(data: &[u8]) -> bool {
    let Ok(text) = std::str::from_utf8(data) else {
        return false;
    };
    let Ok(config) = Config::from_toml(text, "fuzz.toml") else {
        return false;
    };
    let printed = config.to_toml();
    let again = Config::from_toml(&printed, "printed.toml")
        .unwrap_or_else(|e| panic!("settings that validated do not read back: {e}\n{printed}"));
    assert_eq!(
        again.to_toml(),
        printed,
        "settings change when printed twice"
    );
    let _ = levels_of(config.scale);
    for input in [[1, 1], [16, 16], [64, 32], [4096, 4096]] {
        let _ = Reach::of(&config, input);
    }
    true
}

/// `bytes` written as `name` in a scratch folder and read as an image: refused, or a map of
/// the size and channels it claims.
fn read_as(bytes: &[u8], name: &str) -> bool {
    let scratch = scratch();
    let path = scratch.path().join(name);
    std::fs::write(&path, bytes).unwrap();
    let Ok(file) = read_image(&path, MAX_TEXELS) else {
        return false;
    };
    let map = &file.map;
    assert!(map.width() > 0 && map.height() > 0, "{name}: an empty map");
    assert!((map.width() * map.height()) as u64 <= MAX_TEXELS);
    assert!(
        (1..=4).contains(&map.channels()),
        "{name}: {} channels",
        map.channels()
    );
    assert_eq!(map.data().len(), map.texels() * map.channels());
    true
}

/// Upscales the model at `path` into `scratch/out`: refused, or written there and nowhere
/// else, its own folder untouched.
fn upscale_whole(path: &Path, scratch: &Path) -> bool {
    let folder = path.parent().unwrap();
    let before = snapshot(folder);
    let out = scratch.join("out");
    let config = Config {
        scale: 2,
        upsampler: "bilinear".into(),
        ..Config::default()
    };
    let load = LoadOptions {
        max_texels: MAX_TEXELS,
        ..LoadOptions::default()
    };
    let run = upscale_model(
        path,
        &config,
        &out,
        &SaveOptions::default(),
        &load,
        None,
        &Silent,
    );
    if let Ok(run) = &run {
        for file in &run.written {
            assert!(file.starts_with(&out), "{} is outside -o", file.display());
            assert!(file.is_file(), "{} was not written", file.display());
        }
    }
    assert!(before == snapshot(folder), "the model's folder changed");
    let entries: Vec<PathBuf> = (std::fs::read_dir(scratch).unwrap())
        .map(|e| e.unwrap().path())
        .collect();
    assert!(
        entries.iter().all(|e| *e == out || e == folder),
        "a file was written beside the output: {entries:?}"
    );
    run.is_ok()
}

/// Every file of `folder` with its bytes.
fn snapshot(folder: &Path) -> BTreeMap<PathBuf, Vec<u8>> {
    (std::fs::read_dir(folder).unwrap())
        .map(|e| e.unwrap().path())
        .map(|p| {
            let bytes = std::fs::read(&p).unwrap_or_default();
            (p, bytes)
        })
        .collect()
}

fn scratch() -> tempfile::TempDir {
    tempfile::tempdir().expect("a scratch folder")
}

/// A 4×4 RGB PNG, the texture a fuzzed `.gltf` may name.
fn small_png() -> &'static [u8] {
    static PNG: OnceLock<Vec<u8>> = OnceLock::new();
    PNG.get_or_init(|| {
        let mut map = Map::filled(4, 4, 3, 0.5);
        for (i, v) in map.data_mut().iter_mut().enumerate() {
            *v = (i % 7) as f32 / 7.0;
        }
        encode_png8(&map).expect("a PNG")
    })
}
