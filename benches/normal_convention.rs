//! How well matup finds a normal map's convention from the maps (docs/experiments/
//! 2026-11-26-normal-convention.md): every material of `tests/data`, the shipped sample and
//! `../shared` (materials and corpus; all DirectX), box-filtered to 64²–1K², given in both
//! conventions, with and without its height map. Prints each case's call and evidence, then
//! the share right per size and signal.
//!
//! `cargo bench --bench normal_convention` (`MATUP_CONVENTION_SIZES=64,128` picks the sizes).

use std::path::PathBuf;

use matup::normal_convention::{measure, Signal};
use matup::{load_material, LoadOptions, Map, NormalConvention};

fn folders() -> Vec<(String, PathBuf)> {
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let mut out = vec![(
        "sample victorian_wood".to_string(),
        root.join("samples/victorian_wood"),
    )];
    for (set, dir) in [
        ("tests/data", root.join("tests/data/materials")),
        ("shared/materials", root.join("../shared/materials")),
        ("shared/corpus", root.join("../shared/corpus")),
    ] {
        let Ok(entries) = std::fs::read_dir(&dir) else {
            eprintln!("{} is missing: skipped", dir.display());
            continue;
        };
        let mut found: Vec<PathBuf> = entries
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| p.is_dir())
            .collect();
        found.sort();
        out.extend(found.into_iter().map(|p| {
            (
                format!("{set} {}", p.file_name().unwrap().to_string_lossy()),
                p,
            )
        }));
    }
    out
}

/// `map` box-filtered to `size` texels wide (renormalised when it holds normals).
fn to_size(map: &Map, size: usize, normals: bool) -> Option<Map> {
    if map.width() < size || !map.width().is_multiple_of(size) {
        return None;
    }
    let mut out = matup::resample::box_downsample(map, map.width() / size);
    if normals {
        matup::material::normalize_normals(&mut out);
    }
    Some(out)
}

fn main() {
    let sizes: Vec<usize> = std::env::var("MATUP_CONVENTION_SIZES")
        .unwrap_or_else(|_| "64,128,256,512,1024".into())
        .split(',')
        .map(|s| s.trim().parse().expect("sizes"))
        .collect();
    // (size, with height) → (right, weak, wrong while not weak, cases)
    let mut tally = std::collections::BTreeMap::<(usize, bool), [usize; 4]>::new();
    println!("| material | size | height | given | called | weak | evidence |");
    println!("|---|---|---|---|---|---|---|");
    for (name, folder) in folders() {
        let options = LoadOptions {
            normal_convention: Some(NormalConvention::DirectX),
            ..Default::default()
        };
        let material = match load_material(Some(&folder), &options) {
            Ok(m) => m,
            Err(e) => {
                eprintln!("{name}: {e}");
                continue;
            }
        };
        for &size in &sizes {
            let Some(directx) = to_size(&material.normal, size, true) else {
                continue;
            };
            let height = material
                .height
                .as_ref()
                .and_then(|h| to_size(h, size, false));
            let mut opengl = directx.clone();
            opengl.plane_mut(1).iter_mut().for_each(|v| *v = -*v);
            for (given, normals) in [
                (NormalConvention::DirectX, &directx),
                (NormalConvention::OpenGl, &opengl),
            ] {
                for with_height in [true, false] {
                    if with_height && height.is_none() {
                        continue;
                    }
                    let measured = measure(normals, height.as_ref().filter(|_| with_height));
                    let right = measured.convention == given;
                    let t = tally.entry((size, with_height)).or_default();
                    t[0] += right as usize;
                    t[1] += measured.weak as usize;
                    t[2] += (!right && !measured.weak) as usize;
                    t[3] += 1;
                    let evidence = match measured.signal {
                        Signal::Height { y, x } => format!("height: y {y:+.3}, x {x:+.3}"),
                        Signal::Curl { ratio } => format!("curl ratio {ratio:.3}"),
                    };
                    println!(
                        "| {name} | {size} | {} | {given} | {} | {} | {evidence} |",
                        if with_height { "yes" } else { "no" },
                        measured.convention,
                        if measured.weak { "weak" } else { "" },
                    );
                }
            }
        }
    }
    println!();
    println!("| size | height given | right | weak (said so) | wrong and not weak | cases |");
    println!("|---|---|---|---|---|---|");
    for ((size, with_height), [right, weak, wrong_strong, n]) in &tally {
        println!(
            "| {size} | {} | {right}/{n} ({:.1}%) | {weak} | {wrong_strong} | {n} |",
            if *with_height { "yes" } else { "no" },
            100.0 * *right as f64 / *n as f64
        );
    }
}
