//! How well matup finds a JPEG's grid in maps saved again losslessly (`matup::jpeg_trace`),
//! which `input_quality = "auto"` reads as degraded: clean maps (none should be found), and the
//! same maps through JPEG at several qualities, cropped off the grid (each should be). Maps at
//! the two sizes the measurements use: a 256² crop of the material and a 512² crop box-filtered
//! to 128². A material counts as found where any of its four rendered maps is.
//! `--real DIR` (repeatable) prints what the detector reads on a material folder as it is.
//!
//! `cargo run --release --example jpeg_traces -- [--real DIR]... SET_FOLDER...`
//! (e.g. `../shared/materials ../shared/corpus`).

use std::path::{Path, PathBuf};

use matup::degrade::{Degradation, Subsampling};
use matup::jpeg_trace::jpeg_trace;
use matup::material::MapKind;
use matup::{load_material, Material};
use rand::SeedableRng;

const MAPS: [MapKind; 4] = [
    MapKind::BaseColor,
    MapKind::Normal,
    MapKind::Roughness,
    MapKind::Metallic,
];
const QUALITIES: [u8; 4] = [95, 90, 75, 50];

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let mut real = Vec::new();
    let mut sets = Vec::new();
    let mut i = 0;
    while i < args.len() {
        if args[i] == "--real" {
            real.push(PathBuf::from(
                args.get(i + 1).ok_or("--real needs a folder")?,
            ));
            i += 2;
        } else {
            sets.push(PathBuf::from(&args[i]));
            i += 1;
        }
    }
    for folder in &real {
        let m = load_material(Some(folder), &Default::default())?;
        for kind in MAPS {
            println!("{} {kind}: {:?}", folder.display(), trace_of(&m, kind));
        }
    }
    let materials = material_folders(&sets)?;
    println!("| input | materials | clean: found | JPEG 95 | JPEG 90 | JPEG 75 | JPEG 50 |");
    println!("|---|---|---|---|---|---|---|");
    for (label, cut) in [
        ("256² crop", cut_crop as fn(&Material) -> Material),
        ("512² → 128² (box)", cut_box),
    ] {
        let mut found = [0usize; 1 + QUALITIES.len()];
        let mut clean_found = Vec::new();
        for (n, folder) in materials.iter().enumerate() {
            let m = cut(&load_material(Some(folder), &Default::default())?);
            let clean: Vec<_> = MAPS.iter().filter_map(|&k| trace_of(&m, k)).collect();
            if !clean.is_empty() {
                found[0] += 1;
                clean_found.push(format!("{}: {clean:?}", folder.display()));
            }
            for (q, &quality) in QUALITIES.iter().enumerate() {
                let jpeg = as_jpeg(&m, quality, n as u64);
                found[q + 1] += usize::from(MAPS.iter().any(|&k| trace_of(&jpeg, k).is_some()));
            }
        }
        let n = materials.len();
        let cells: Vec<String> = found.iter().map(|f| format!("{f}/{n}")).collect();
        println!("| {label} | {n} | {} |", cells.join(" | "));
        for line in clean_found {
            eprintln!("{label}, clean, found: {line}");
        }
    }
    Ok(())
}

/// The detector's strength and contrast on one map, where it finds a grid.
fn trace_of(m: &Material, kind: MapKind) -> Option<(f64, f64, [usize; 2])> {
    let trace = jpeg_trace(kind, m.map(kind)?)?;
    Some((trace.strength, trace.contrast, trace.offset))
}

/// Every map of `m` through JPEG at `quality` (4:2:0), then cropped 3 and 5 texels off the
/// grid, as a crop of a model's texture is.
fn as_jpeg(m: &Material, quality: u8, seed: u64) -> Material {
    let jpeg = Degradation::Jpeg {
        quality,
        subsampling: Subsampling::Half,
    };
    let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
    let mut out = m.clone();
    for kind in MAPS {
        let map = out.map_mut(kind).expect("always present");
        *map = jpeg.apply(kind, map, &mut rng).expect("JPEG round trip");
    }
    let (w, h) = (m.width() - 8, m.height_px() - 8);
    out.crop(3, 5, w, h)
}

fn cut_crop(m: &Material) -> Material {
    m.crop(0, 0, m.width().min(256), m.height_px().min(256))
}

fn cut_box(m: &Material) -> Material {
    let side = m.width().min(m.height_px()).min(512) / 4 * 4;
    m.crop(0, 0, side, side).box_downsample(4)
}

/// The material folders of each set (a folder of folders) or each folder given.
fn material_folders(sets: &[PathBuf]) -> std::io::Result<Vec<PathBuf>> {
    let mut folders = Vec::new();
    for set in sets {
        let mut inner: Vec<PathBuf> = std::fs::read_dir(set)?
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| p.is_dir())
            .collect();
        inner.sort();
        if inner.is_empty() {
            folders.push(set.clone());
        } else {
            folders.extend(inner.into_iter().filter(|p| has_maps(p)));
        }
    }
    Ok(folders)
}

fn has_maps(folder: &Path) -> bool {
    std::fs::read_dir(folder).is_ok_and(|mut d| {
        d.any(|e| {
            e.is_ok_and(|e| {
                e.path()
                    .extension()
                    .is_some_and(|x| x == "png" || x == "jpg")
            })
        })
    })
}
