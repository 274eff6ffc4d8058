//! How well matup reads a lossy storage's trace in maps saved again losslessly
//! (`matup::texel_trace`), which `input_quality = "auto"` routes as degraded: clean maps (none
//! should be read), and the same maps through BC1, BC3, BC4, BC5, JPEG and dithering to 32
//! levels, cropped off their grids (each should be). Maps at the sizes the measurements use: a
//! 256² crop, a 512² crop box-filtered to 128², and the whole material box-filtered to 128²
//! read as tileable, as it is and rolled by (37, 53). A clean material counts as misread where
//! any of its four rendered maps is read (and for few levels, its height too, which the route
//! reads as a witness); a degraded one as found where the map named in the column is. Then, at
//! each size, the materials read as lying over one noise, clean and degraded.
//! `--real DIR` (repeatable) prints what the detectors read on a material folder as it is;
//! `--noise-only` prints the noise tables alone.
//!
//! `cargo run --release --example texel_traces -- [--real DIR]... SET_FOLDER...`
//! (e.g. `../shared/materials ../shared/corpus`).

use std::path::{Path, PathBuf};

use matup::degrade::{BlockFormat, Degradation, DitherMethod, Subsampling};
use matup::material::MapKind;
use matup::texel_trace::{noise_floor, quantised_trace, texel_trace, QuantisedTrace, TexelTrace};
use matup::{load_material, Map, Material};
use rand::SeedableRng;

/// The maps read (the noise table also reads the first three alone: no metallic map).
const MAPS: [MapKind; 4] = [
    MapKind::BaseColor,
    MapKind::Normal,
    MapKind::Roughness,
    MapKind::Metallic,
];

/// Each degraded column: its name, the map it reads, what it went through.
fn columns() -> Vec<(&'static str, MapKind, Degradation)> {
    let block = Degradation::Block;
    let jpeg = |quality| Degradation::Jpeg {
        quality,
        subsampling: Subsampling::Half,
    };
    let dither = |method| Degradation::Dither { levels: 32, method };
    vec![
        ("BC1 colour", MapKind::BaseColor, block(BlockFormat::Bc1)),
        ("BC3 colour", MapKind::BaseColor, block(BlockFormat::Bc3)),
        ("BC1 normal", MapKind::Normal, block(BlockFormat::Bc1)),
        ("BC5 normal", MapKind::Normal, block(BlockFormat::Bc5)),
        ("BC4 roughness", MapKind::Roughness, block(BlockFormat::Bc4)),
        ("JPEG 90 colour", MapKind::BaseColor, jpeg(90)),
        ("JPEG 75 colour", MapKind::BaseColor, jpeg(75)),
        ("JPEG 75 normal", MapKind::Normal, jpeg(75)),
        (
            "dither 32 colour (FS)",
            MapKind::BaseColor,
            dither(DitherMethod::ErrorDiffusion),
        ),
        (
            "dither 32 colour (ordered)",
            MapKind::BaseColor,
            dither(DitherMethod::Ordered),
        ),
        (
            "dither 32 roughness (FS)",
            MapKind::Roughness,
            dither(DitherMethod::ErrorDiffusion),
        ),
    ]
}

/// A way of cutting a material's input from its folder: name, cut, read as tileable.
type Cut = (&'static str, fn(&Material) -> Material, bool);

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let (mut real, mut sets, mut noise_only) = (Vec::new(), Vec::new(), false);
    let mut args = args.into_iter();
    while let Some(arg) = args.next() {
        match arg.as_str() {
            "--real" => real.push(PathBuf::from(args.next().ok_or("--real needs a folder")?)),
            "--noise-only" => noise_only = true,
            _ => sets.push(PathBuf::from(arg)),
        }
    }
    for folder in &real {
        let m = load_material(Some(folder), &Default::default())?;
        for (label, cut) in [
            (
                "as it is",
                (|m: &Material| m.clone()) as fn(&Material) -> Material,
            ),
            ("512² → 128²", cut_box),
        ] {
            let m = cut(&m);
            for kind in MAPS {
                let trace = texel_trace(kind, m.map(kind).expect("rendered"), false);
                println!("{} ({label}) {kind}: {trace:?}", folder.display());
            }
        }
    }
    if sets.is_empty() {
        return Ok(());
    }
    let materials = material_folders(&sets)?;
    let cuts: [Cut; 4] = [
        ("256² crop", cut_crop, false),
        ("512² → 128² (box)", cut_box, false),
        ("whole → 128² (box), tileable", cut_whole, true),
        (
            "the same rolled (37, 53)",
            |m| roll(&cut_whole(m), [37, 53]),
            true,
        ),
    ];
    if !noise_only {
        block_table(&materials, &cuts)?;
    }
    for cut in cuts {
        noise_table(&materials, cut)?;
    }
    Ok(())
}

/// How many clean materials are read as BC, JPEG or few levels, and how many degraded maps
/// are found, at each cut.
fn block_table(materials: &[PathBuf], cuts: &[Cut]) -> Result<(), Box<dyn std::error::Error>> {
    let columns = columns();
    let names: Vec<&str> = columns.iter().map(|c| c.0).collect();
    println!(
        "| input | materials | clean: read as BC | clean: read as JPEG | clean: read as few \
         levels | {} | dither 32 (FS), every map: the set read |",
        names.join(" | ")
    );
    println!("|---|---|---|---|---|{}---|", "---|".repeat(columns.len()));
    for &(label, cut, tileable) in cuts {
        let (mut as_bc, mut as_jpeg, mut as_few, mut dithered_sets) = (0, 0, 0, 0);
        let mut found = vec![0usize; columns.len()];
        let mut misreads = Vec::new();
        for (n, folder) in materials.iter().enumerate() {
            let m = cut(&load_material(Some(folder), &Default::default())?);
            let traces: Vec<_> = (MAPS.iter())
                .filter_map(|&k| Some((k, texel_trace(k, m.map(k)?, tileable)?)))
                .collect();
            let read_as =
                |is: fn(&TexelTrace) -> bool| usize::from(traces.iter().any(|(_, t)| is(t)));
            as_bc += read_as(|t| matches!(t, TexelTrace::Blocks(_)));
            as_jpeg += read_as(|t| matches!(t, TexelTrace::Jpeg(_)));
            let height_levels = few_levels_in_height(&m, tileable);
            as_few += usize::from(
                height_levels.is_some() || read_as(|t| matches!(t, TexelTrace::Quantised(_))) > 0,
            );
            if let Some(levels) = height_levels {
                misreads.push(format!("{}: height {levels:?}", folder.display()));
            }
            if !traces.is_empty() {
                misreads.push(format!("{}: {traces:?}", folder.display()));
            }
            // Every map dithered, as a 16-bit set: read where any map shows its levels.
            let mut rng = rand::rngs::StdRng::seed_from_u64(n as u64);
            let set = matup::degrade::degrade_material(&m, &"dither32-fs".parse()?, &mut rng)?;
            let shown = (MAPS.iter()).any(|&k| {
                set.map(k)
                    .and_then(|map| texel_trace(k, map, tileable))
                    .is_some()
            });
            dithered_sets += usize::from(shown || few_levels_in_height(&set, tileable).is_some());
            for (i, (_, kind, degradation)) in columns.iter().enumerate() {
                let mut rng = rand::rngs::StdRng::seed_from_u64(n as u64);
                let map = degradation.apply(*kind, m.map(*kind).expect("rendered"), &mut rng)?;
                // Off the grid where the input is a crop: 3 and 5 texels in.
                let map = if tileable { map } else { off_grid(&map) };
                found[i] += usize::from(texel_trace(*kind, &map, tileable).is_some());
            }
        }
        let n = materials.len();
        let cells: Vec<String> = found.iter().map(|f| format!("{f}/{n}")).collect();
        println!(
            "| {label} | {n} | {as_bc}/{n} | {as_jpeg}/{n} | {as_few}/{n} | {} | \
             {dithered_sets}/{n} |",
            cells.join(" | ")
        );
        for line in misreads {
            eprintln!("{label}, clean, read: {line}");
        }
    }
    Ok(())
}

/// Few levels in `m`'s height, which the route reads as a witness for the set.
fn few_levels_in_height(m: &Material, tileable: bool) -> Option<QuantisedTrace> {
    quantised_trace(MapKind::Height, m.map(MapKind::Height)?, tileable)
}

/// How many materials read as lying over one noise (`matup::texel_trace::noise_floor`), clean
/// and through each noise and each trace without a grid: with all their maps as the route reads
/// them (base colour, normal, roughness, metallic, and height where they have one), with the
/// four alone, without the metallic map (many folders have none), and with three (no metallic,
/// no height: never read, as the route needs four; shown for what three maps would read).
fn noise_table(
    materials: &[PathBuf],
    (label, cut, tileable): Cut,
) -> Result<(), Box<dyn std::error::Error>> {
    let inputs = [
        "clean", "noise1", "noise2", "noise3", "noise4", "jpeg75", "bc1", "blur0.7",
    ];
    println!();
    println!("Materials read as noisy (noise under every map), {label}");
    println!();
    println!("| maps | {} |", inputs.join(" | "));
    println!("|---|{}", "---|".repeat(inputs.len()));
    let loaded: Vec<Material> = (materials.iter())
        .map(|f| Ok(cut(&load_material(Some(f), &Default::default())?)))
        .collect::<Result<_, Box<dyn std::error::Error>>>()?;
    const HEIGHT: MapKind = MapKind::Height;
    let with_height = [MAPS[0], MAPS[1], MAPS[2], MAPS[3], HEIGHT];
    let no_metallic = [MAPS[0], MAPS[1], MAPS[2], HEIGHT];
    let rows: [(&str, &[MapKind]); 4] = [
        ("all, height too", &with_height),
        ("colour, normal, roughness, metallic", &MAPS),
        ("no metallic, height too", &no_metallic),
        ("colour, normal, roughness", &MAPS[..3]),
    ];
    for (row, kinds) in rows {
        let mut cells = Vec::new();
        for input in inputs {
            let mut found = 0;
            for (n, m) in loaded.iter().enumerate() {
                let mut rng = rand::rngs::StdRng::seed_from_u64(n as u64);
                let d = match input {
                    "clean" => m.clone(),
                    _ => matup::degrade::degrade_material(m, &input.parse()?, &mut rng)?,
                };
                let maps: Vec<_> = (kinds.iter())
                    .filter_map(|&k| Some((k, d.map(k)?)))
                    .collect();
                if let Some(floor) = noise_floor(&maps, tileable) {
                    found += 1;
                    if input == "clean" {
                        let name = materials[n].display();
                        eprintln!("{label}, {row}, clean, read: {name}: {floor}");
                    }
                }
            }
            cells.push(format!("{found}/{}", loaded.len()));
        }
        println!("| {row} | {} |", cells.join(" | "));
    }
    Ok(())
}

fn off_grid(map: &Map) -> Map {
    map.crop(3, 5, map.width() - 8, map.height() - 8)
}

fn roll(m: &Material, [dx, dy]: [usize; 2]) -> Material {
    let (w, h) = (m.width(), m.height_px());
    let mut out = m.clone();
    for kind in MAPS {
        let map = out.map_mut(kind).expect("rendered");
        let source = map.clone();
        *map = Map::from_fn(w, h, source.channels(), |c, y, x| {
            source.plane(c)[((y + h - dy % h) % h) * w + (x + w - dx % w) % w]
        });
    }
    out
}

fn cut_crop(m: &Material) -> Material {
    m.crop(0, 0, m.width().min(256), m.height_px().min(256))
}

fn cut_box(m: &Material) -> Material {
    let side = m.width().min(m.height_px()).min(512) / 4 * 4;
    m.crop(0, 0, side, side).box_downsample(4)
}

fn cut_whole(m: &Material) -> Material {
    m.box_downsample((m.width() / 128).max(1))
}

/// The material folders of each set (a folder of folders) or each folder given, those that
/// load (corpus-extra has sets whose maps differ in size; each skipped is said on stderr).
fn material_folders(sets: &[PathBuf]) -> std::io::Result<Vec<PathBuf>> {
    let mut loading = Vec::new();
    for folder in all_material_folders(sets)? {
        match load_material(Some(&folder), &Default::default()) {
            Ok(_) => loading.push(folder),
            Err(e) => eprintln!("skipped: {e}"),
        }
    }
    Ok(loading)
}

fn all_material_folders(sets: &[PathBuf]) -> std::io::Result<Vec<PathBuf>> {
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
