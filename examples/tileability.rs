//! How well matup tells a tileable input from a crop: a labelled set built from the material
//! sets beside the repository (every whole material is tileable; crops at random offsets are
//! not), at the sizes users feed, scored by the defaults' decision (`decide_tileable`) per size
//! and per category.
//! `--features FILE` also writes each sample's edge statistics as CSV, for studying signals.
//!
//! `cargo run --release --example tileability -- [--features FILE] SET_FOLDER...`
//! (e.g. `../shared/materials ../shared/corpus`).

use std::collections::BTreeMap;
use std::io::Write;
use std::path::{Path, PathBuf};

use matup::map::{Dihedral, Map};
use matup::material::MapKind;
use matup::tileable::{decide_tileable, judged_maps};
use matup::{load_material, Material};
use rand::{Rng, SeedableRng};

/// How a map's rows (or columns) differ: across the wrap-around edge, between interior
/// neighbours, and between rows half the map apart (unrelated content).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EdgeStats {
    /// Mean |difference| between the last row and the first.
    pub edge: f32,
    pub neighbour_median: f32,
    pub neighbour_p90: f32,
    pub neighbour_max: f32,
    /// Median of the mean |difference| between rows half the map apart.
    pub far_median: f32,
    /// How closely the pair (last row, first row) repeats an interior pair of neighbours
    /// (row k, row k + 1), the best k: the mean of their two differences.
    pub repeat: f32,
    /// The correlation of the rows' structure (their differences along the row) across the
    /// edge, and its median between interior neighbours and between rows half the map apart.
    pub structure_edge: f32,
    pub structure_neighbour_median: f32,
    pub structure_far_median: f32,
}

/// Mean |difference| between rows `a` and `b` of `map`, over columns and channels.
fn row_difference(map: &Map, a: usize, b: usize) -> f32 {
    matup::resample::row_difference(map, a, b) as f32
}

/// The correlation of rows `a` and `b`'s differences along the row (where structures such as
/// joints and edges cross them), over channels.
fn structure_correlation(map: &Map, a: usize, b: usize) -> f32 {
    let w = map.width();
    let (mut ab, mut aa, mut bb) = (0.0f64, 0.0f64, 0.0f64);
    for c in 0..map.channels() {
        let plane = map.plane(c);
        let (ra, rb) = (&plane[a * w..(a + 1) * w], &plane[b * w..(b + 1) * w]);
        for x in 0..w - 1 {
            let (da, db) = ((ra[x + 1] - ra[x]) as f64, (rb[x + 1] - rb[x]) as f64);
            ab += da * db;
            aa += da * da;
            bb += db * db;
        }
    }
    if aa * bb <= 1e-20 {
        return 0.0;
    }
    (ab / (aa * bb).sqrt()) as f32
}

fn quantile(sorted: &[f32], q: f32) -> f32 {
    sorted[((sorted.len() - 1) as f32 * q).round() as usize]
}

/// [`EdgeStats`] of `map`'s rows.
fn row_statistics(map: &Map) -> EdgeStats {
    let h = map.height();
    let mut neighbours: Vec<f32> = (0..h - 1).map(|k| row_difference(map, k, k + 1)).collect();
    let mut far: Vec<f32> = (0..h)
        .map(|k| row_difference(map, k, (k + h / 2) % h))
        .collect();
    neighbours.sort_by(f32::total_cmp);
    far.sort_by(f32::total_cmp);
    let repeat = (3..h.saturating_sub(4))
        .map(|k| 0.5 * (row_difference(map, h - 1, k) + row_difference(map, 0, k + 1)))
        .fold(f32::INFINITY, f32::min);
    let mut structure_neighbours: Vec<f32> = (0..h - 1)
        .map(|k| structure_correlation(map, k, k + 1))
        .collect();
    let mut structure_far: Vec<f32> = (0..h)
        .map(|k| structure_correlation(map, k, (k + h / 2) % h))
        .collect();
    structure_neighbours.sort_by(f32::total_cmp);
    structure_far.sort_by(f32::total_cmp);
    EdgeStats {
        structure_edge: structure_correlation(map, h - 1, 0),
        structure_neighbour_median: quantile(&structure_neighbours, 0.5),
        structure_far_median: quantile(&structure_far, 0.5),
        repeat,
        edge: row_difference(map, h - 1, 0),
        neighbour_median: quantile(&neighbours, 0.5),
        neighbour_p90: quantile(&neighbours, 0.9),
        neighbour_max: quantile(&neighbours, 1.0),
        far_median: quantile(&far, 0.5),
    }
}

/// [`EdgeStats`] of each varying map, for its rows and its columns.
pub fn edge_statistics(material: &Material) -> Vec<(MapKind, [EdgeStats; 2])> {
    let mut out = Vec::new();
    for (kind, map) in judged_maps(material) {
        let columns = map.transformed(Dihedral::TRANSPOSE);
        out.push((kind, [row_statistics(&map), row_statistics(&columns)]));
    }
    out
}

/// The category a material's name puts it in.
fn category(name: &str) -> &'static str {
    let grid = [
        "tiles",
        "bricks",
        "paving",
        "woodfloor",
        "plates",
        "plate_",
        "floor_tiles",
        "diamondplate",
    ];
    let metal = ["metal", "steel", "ornament"];
    let lower = name.to_ascii_lowercase();
    if grid.iter().any(|g| lower.contains(g)) {
        "grid"
    } else if metal.iter().any(|m| lower.contains(m)) {
        "metal"
    } else {
        "organic"
    }
}

/// One labelled input: a material at a size, whole or cropped.
struct Sample {
    name: String,
    category: &'static str,
    size: usize,
    tileable: bool,
    material: Material,
}

const SIZES: [usize; 5] = [64, 128, 256, 512, 1024];
/// Crops per material and size, each at a random offset.
const CROPS: usize = 2;

/// The whole material box-filtered to each size (tileable), and crops at random offsets of
/// half its width box-filtered to each size up to that (not tileable).
fn samples(name: &str, whole: &Material, rng: &mut impl Rng) -> Vec<Sample> {
    let mut out = Vec::new();
    let side = whole.width().min(whole.height_px());
    let sample = |material: Material, size, tileable| Sample {
        name: name.to_string(),
        category: category(name),
        size,
        tileable,
        material,
    };
    for size in SIZES
        .into_iter()
        .filter(|&s| s <= side && side.is_multiple_of(s))
    {
        out.push(sample(whole.box_downsample(side / size), size, true));
        let crop = side / 2;
        if size > crop {
            continue;
        }
        for _ in 0..CROPS {
            // An offset that is no multiple of the crop, so no crop is a whole period.
            let (x, y) = loop {
                let (x, y) = (
                    rng.random_range(1..side - crop),
                    rng.random_range(1..side - crop),
                );
                if x % 8 != 0 && y % 8 != 0 {
                    break (x, y);
                }
            };
            let cut = whole.crop(x, y, crop, crop).box_downsample(crop / size);
            out.push(sample(cut, size, false));
        }
    }
    out
}

fn material_folders(sets: &[PathBuf]) -> Vec<PathBuf> {
    let mut folders = Vec::new();
    for set in sets {
        let Ok(entries) = std::fs::read_dir(set) else {
            eprintln!(
                "{} is missing: put the material sets there (../shared/materials and \
                 ../shared/corpus beside the repository)",
                set.display()
            );
            std::process::exit(2);
        };
        let mut found: Vec<PathBuf> = entries
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| p.is_dir())
            .collect();
        found.sort();
        folders.extend(found);
    }
    folders
}

fn write_features(path: &Path, samples: &[(Sample, (bool, f32))]) -> std::io::Result<()> {
    let mut file = std::io::BufWriter::new(std::fs::File::create(path)?);
    writeln!(
        file,
        "material,category,size,tileable,map,axis,edge,neighbour_median,neighbour_p90,neighbour_max,far_median,repeat,s_edge,s_neighbour,s_far"
    )?;
    for (s, _) in samples {
        for (map, stats) in edge_statistics(&s.material) {
            for (axis, e) in [("rows", stats[0]), ("cols", stats[1])] {
                writeln!(
                    file,
                    "{},{},{},{},{map:?},{axis},{},{},{},{},{},{},{},{},{}",
                    s.name,
                    s.category,
                    s.size,
                    s.tileable,
                    e.edge,
                    e.neighbour_median,
                    e.neighbour_p90,
                    e.neighbour_max,
                    e.far_median,
                    e.repeat,
                    e.structure_edge,
                    e.structure_neighbour_median,
                    e.structure_far_median
                )?;
            }
        }
    }
    Ok(())
}

fn main() {
    let mut args: Vec<String> = std::env::args().skip(1).collect();
    let features = match args.iter().position(|a| a == "--features") {
        Some(i) => {
            let path = args.get(i + 1).cloned().expect("--features FILE");
            args.drain(i..=i + 1);
            Some(PathBuf::from(path))
        }
        None => None,
    };
    if args.is_empty() {
        eprintln!("usage: tileability [--features FILE] SET_FOLDER...");
        std::process::exit(2);
    }
    let sets: Vec<PathBuf> = args.iter().map(PathBuf::from).collect();
    let mut rng = rand::rngs::StdRng::seed_from_u64(39);
    let mut labelled: Vec<(Sample, (bool, f32))> = Vec::new();
    for folder in material_folders(&sets) {
        let name = folder.file_name().unwrap().to_string_lossy().into_owned();
        let whole = load_material(Some(&folder), &Default::default())
            .unwrap_or_else(|e| panic!("{}: {e}", folder.display()));
        for s in samples(&name, &whole, &mut rng) {
            let verdict = decide_tileable(&s.material);
            labelled.push((s, verdict));
        }
    }
    if let Some(path) = features {
        write_features(&path, &labelled).expect("the features file");
    }
    // Right / all, per size and category, and the wrong ones.
    let mut table: BTreeMap<(usize, &str, bool), [usize; 2]> = BTreeMap::new();
    let mut wrong = Vec::new();
    for (s, verdict) in &labelled {
        let right = verdict.0 == s.tileable;
        for cat in [s.category, "all"] {
            let cell = table.entry((s.size, cat, s.tileable)).or_default();
            cell[0] += right as usize;
            cell[1] += 1;
        }
        if !right {
            wrong.push(format!(
                "  {} {}² {}: called {} ({})",
                s.name,
                s.size,
                if s.tileable { "whole" } else { "crop" },
                verdict.0,
                verdict.1
            ));
        }
    }
    println!("| size | category | whole materials called tileable | crops called not tileable | accuracy |");
    println!("|---|---|---|---|---|");
    for size in SIZES {
        for cat in ["grid", "metal", "organic", "all"] {
            let get = |t| table.get(&(size, cat, t)).copied().unwrap_or_default();
            let (w, c) = (get(true), get(false));
            if w[1] + c[1] == 0 {
                continue;
            }
            let acc = 100.0 * (w[0] + c[0]) as f64 / (w[1] + c[1]) as f64;
            println!(
                "| {size}² | {cat} | {}/{} | {}/{} | {acc:.1}% |",
                w[0], w[1], c[0], c[1]
            );
        }
    }
    println!("\n{} of {} wrong:", wrong.len(), labelled.len());
    for w in wrong {
        println!("{w}");
    }
}
