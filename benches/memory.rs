//! Where the memory of a large upscale goes, stage by stage (issue "Outputs of any size in
//! bounded memory"). A shared 1K² material, tiled N×N, goes through the defaults ×4 as
//! `matup upscale` runs them (pipeline, maps saved, preview), once as tileable and once not;
//! a counting allocator records the heap's peak within each stage and what stays live after it,
//! and a last table splits each run's time into the pipeline's stages (summed over bands) and
//! the rest (reading the bands, writing the files).
//!
//! `cargo bench --bench memory` runs N = 1 (1K² → 4K²); `MATUP_MEMORY_TILES=1,2,4` adds
//! 2K² → 8K² and 4K² → 16K², `MATUP_MEMORY_MATERIAL=folder` picks another material,
//! `MATUP_MEMORY_LIMIT=MiB` (or `none`; or one per size, `4096,4096,8192`) sets
//! `--memory-limit` (default: matup's), and
//! `MATUP_MEMORY_COMPARE=1,2` also runs those sizes whole (N = 1, 2) and reports how far
//! apart the maps' files are, `MATUP_MEMORY_TILEABLE=yes` or `no` runs only that case, and
//! `MATUP_MEMORY_PLOT=file.png` draws heap peak and time per texel against the output's size.

use std::alloc::{GlobalAlloc, Layout};

use mimalloc::MiMalloc;
use std::path::PathBuf;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Mutex;
use std::time::Instant;

use matup::bands::default_memory_limit;
use matup::folder::upscale_to_folder;
use matup::material::Material;
use matup::progress::Progress;
use matup::report::peak_memory_mib;
use matup::{load_material, Config, LoadOptions, Map, SaveOptions};

/// The allocator `matup` links (mimalloc), counting the bytes live and the most live since the
/// last reset. Counting over glibc's malloc instead made the same run 1.35× slower (50.7 s
/// against the CLI's 37.5 s, 1K² → 4K²), so the bench would not time what users run.
struct Counting;

static LIVE: AtomicUsize = AtomicUsize::new(0);
static PEAK: AtomicUsize = AtomicUsize::new(0);

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        let p = unsafe { MiMalloc.alloc(layout) };
        if !p.is_null() {
            grew(layout.size());
        }
        p
    }
    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        let p = unsafe { MiMalloc.alloc_zeroed(layout) };
        if !p.is_null() {
            grew(layout.size());
        }
        p
    }
    unsafe fn dealloc(&self, p: *mut u8, layout: Layout) {
        unsafe { MiMalloc.dealloc(p, layout) };
        LIVE.fetch_sub(layout.size(), Ordering::Relaxed);
    }
    unsafe fn realloc(&self, p: *mut u8, layout: Layout, size: usize) -> *mut u8 {
        let q = unsafe { MiMalloc.realloc(p, layout, size) };
        if !q.is_null() {
            LIVE.fetch_sub(layout.size(), Ordering::Relaxed);
            grew(size);
        }
        q
    }
}

fn grew(bytes: usize) {
    let live = LIVE.fetch_add(bytes, Ordering::Relaxed) + bytes;
    PEAK.fetch_max(live, Ordering::Relaxed);
}

#[global_allocator]
static ALLOCATOR: Counting = Counting;

const MIB: f64 = 1024.0 * 1024.0;

/// One stage's row: name, seconds, heap peak within it and heap live after it (MiB).
type Row = (String, f64, f64, f64);

/// One run's time: its name, the pipeline's stages (name, seconds summed over bands), its
/// total seconds and its output texels.
type Breakdown = (String, Vec<(String, f64)>, f64, f64);

/// Closes a stage whenever the pipeline reports the next one.
struct Stages {
    open: Mutex<Option<(String, Instant)>>,
    rows: Mutex<Vec<Row>>,
}

impl Stages {
    fn new() -> Self {
        Stages {
            open: Mutex::new(None),
            rows: Mutex::new(Vec::new()),
        }
    }

    fn begin(&self, name: &str) {
        self.end();
        PEAK.store(LIVE.load(Ordering::Relaxed), Ordering::Relaxed);
        *self.open.lock().unwrap() = Some((name.to_string(), Instant::now()));
    }

    fn end(&self) {
        if let Some((name, start)) = self.open.lock().unwrap().take() {
            let peak = PEAK.load(Ordering::Relaxed) as f64 / MIB;
            let live = LIVE.load(Ordering::Relaxed) as f64 / MIB;
            let seconds = start.elapsed().as_secs_f64();
            self.rows.lock().unwrap().push((name, seconds, peak, live));
        }
    }
}

impl Progress for Stages {
    fn stage(&self, name: &str, _total: u64) {
        self.begin(name);
    }
}

/// `material` repeated `n` × `n` times (every map, height included).
fn tiled(material: &Material, n: usize) -> Material {
    let repeat = |m: &Map| {
        let (w, h) = (m.width(), m.height());
        Map::from_fn(w * n, h * n, m.channels(), |c, y, x| m.get(c, y % h, x % w))
    };
    material.map_maps(repeat)
}

/// The 8-bit maps of two output folders, the largest difference in levels (PNG files).
fn max_level_difference(a: &std::path::Path, b: &std::path::Path) -> u8 {
    let mut worst = 0;
    for entry in std::fs::read_dir(a).expect("the output folder") {
        let path = entry.expect("a file").path();
        let name = path.file_name().unwrap().to_owned();
        if path.extension().is_none_or(|e| e != "png") || name == "preview.png" {
            continue;
        }
        let read = |p: &std::path::Path| image::open(p).expect("a PNG").into_rgb8().into_raw();
        let (x, y) = (read(&path), read(&b.join(&name)));
        assert_eq!(x.len(), y.len(), "{}", name.to_string_lossy());
        worst = (x.iter().zip(&y)).fold(worst, |w, (p, q)| w.max(p.abs_diff(*q)));
    }
    worst
}

fn main() {
    let repo = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let folder = std::env::var("MATUP_MEMORY_MATERIAL")
        .map(PathBuf::from)
        .unwrap_or_else(|_| repo.join("../shared/materials/ambientcg_Tiles036"));
    let tiles: Vec<usize> = std::env::var("MATUP_MEMORY_TILES")
        .unwrap_or_else(|_| "1".into())
        .split(',')
        .map(|s| {
            s.trim()
                .parse()
                .expect("MATUP_MEMORY_TILES: a list of integers")
        })
        .collect();
    // MiB, or "none" for whole levels, one for every size or one per size; default: matup's.
    let limits: Vec<Option<u64>> = match std::env::var("MATUP_MEMORY_LIMIT") {
        Ok(list) => list
            .split(',')
            .map(|l| match l.trim() {
                "none" => None,
                mib => Some(mib.parse::<u64>().expect("MATUP_MEMORY_LIMIT: MiB or none") << 20),
            })
            .collect(),
        Err(_) => vec![Some(default_memory_limit())],
    };
    let limit_of = |i: usize| limits[i.min(limits.len() - 1)];
    // Also run these sizes (tile counts) whole, no limit, and compare the maps' files.
    let compare: Vec<usize> = std::env::var("MATUP_MEMORY_COMPARE")
        .unwrap_or_default()
        .split(',')
        .filter_map(|n| n.trim().parse().ok())
        .collect();
    if !folder.is_dir() {
        eprintln!(
            "{} is missing: put the shared material sets (../shared/materials) beside the \
             repository, or name a material with MATUP_MEMORY_MATERIAL",
            folder.display()
        );
        std::process::exit(2);
    }
    let source = load_material(Some(&folder), &LoadOptions::default())
        .unwrap_or_else(|e| panic!("{}: {e}", folder.display()));
    let out = tempfile::tempdir().expect("a temporary folder");
    println!(
        "{} tiled N×N, defaults ×4 as `matup upscale` runs them (maps, preview, run.json), memory \
         limit {}, {} threads; heap in MiB (peak within the stage, live after it)\n",
        folder.display(),
        (limits.iter())
            .map(|l| l.map_or("none".into(), |l| format!("{} MiB", l >> 20)))
            .collect::<Vec<_>>()
            .join(", "),
        rayon::current_num_threads()
    );
    println!("| run | stage | seconds | heap peak | heap live after |");
    println!("|---|---|---|---|---|");
    let mut summary = Vec::new();
    // Each run's pipeline stages (summed over bands) and the rest (reading bands, writing).
    let mut breakdown: Vec<Breakdown> = Vec::new();
    let tilings: &[bool] = match std::env::var("MATUP_MEMORY_TILEABLE").as_deref() {
        Ok("yes") => &[true],
        Ok("no") => &[false],
        _ => &[true, false],
    };
    for (i, &n) in tiles.iter().enumerate() {
        let limit = limit_of(i);
        for &tileable in tilings {
            let input = tiled(&source, n);
            let config = Config {
                tileable: Some(tileable),
                ..Config::default()
            };
            let run = format!(
                "{}² → {}², {}",
                input.width(),
                4 * input.width(),
                if tileable { "tileable" } else { "not tileable" }
            );
            let texels = (16 * input.width() * input.height_px()) as f64;
            let timings = Mutex::new(Vec::new());
            let one = |limit: Option<u64>, tag: &str| {
                let stages = Stages::new();
                let start = Instant::now();
                stages.begin("start");
                let folder = out.path().join(format!("{n}-{tileable}-{tag}"));
                let run = upscale_to_folder(
                    &input,
                    &config,
                    &folder,
                    &SaveOptions::default(),
                    false,
                    limit,
                    None,
                    &stages,
                )
                .expect("the upscale runs");
                stages.end();
                let total = start.elapsed().as_secs_f64();
                let rows = stages.rows.into_inner().unwrap();
                let bands = run.report.levels.last().map_or(1, |l| l.bands);
                timings
                    .lock()
                    .unwrap()
                    .push((tag.to_string(), run.report.timings, total));
                (folder, rows, total, bands)
            };
            let (folder, rows, total, bands) = one(limit, "limited");
            let peak = rows.iter().map(|r| r.2).fold(0.0, f64::max);
            for (stage, seconds, peak, live) in &rows {
                println!("| {run} | {stage} | {seconds:.1} | {peak:.0} | {live:.0} |");
            }
            let mut whole_run = None;
            let difference = (compare.contains(&n) && bands > 1).then(|| {
                let (whole, rows, total, _) = one(None, "whole");
                let d = max_level_difference(&whole, &folder);
                std::fs::remove_dir_all(&whole).ok();
                let peak = rows.iter().map(|r| r.2).fold(0.0, f64::max);
                whole_run = Some((total, peak));
                d
            });
            std::fs::remove_dir_all(&folder).ok();
            let limit_mib = limit.map(|l| (l >> 20) as f64);
            let per_mtexel = |seconds: f64| seconds / texels * 1e6;
            for (tag, stages, total) in timings.into_inner().unwrap() {
                let name = if tag == "whole" {
                    format!("{run}, whole")
                } else {
                    run.clone()
                };
                breakdown.push((name, stages, total, texels));
            }
            if let Some((total, peak)) = whole_run {
                let name = format!("{run}, whole");
                summary.push((name, None, 1, total, per_mtexel(total), peak, None));
            }
            summary.push((
                run,
                limit_mib,
                bands,
                total,
                per_mtexel(total),
                peak,
                difference,
            ));
        }
    }
    if std::env::var("MATUP_MEMORY_PLOT").is_ok_and(|p| !p.is_empty()) {
        let path = PathBuf::from(std::env::var("MATUP_MEMORY_PLOT").unwrap());
        let points: Vec<_> = tiles
            .iter()
            .map(|&n| {
                let side = n * source.width();
                let prefix = format!("{side}² → ");
                // This size's runs within its limit (not the whole runs beside them).
                let rows: Vec<_> = (summary.iter())
                    .filter(|r| r.0.starts_with(&prefix) && !r.0.ends_with("whole"))
                    .collect();
                let mtexels = (16 * n * n * source.width() * source.height_px()) as f64 / 1e6;
                let peak = rows.iter().map(|r| r.5).fold(0.0, f64::max);
                let per = rows.iter().map(|r| r.4).fold(0.0, f64::max);
                (mtexels, peak, per, rows[0].1)
            })
            .collect();
        plot_growth(&points, &path).expect("the plot draws");
        println!("plot: {}", path.display());
    }
    println!(
        "\n| run | memory limit MiB | bands | seconds | seconds per output Mtexel | heap peak \
         MiB | maps vs whole (8-bit levels) |"
    );
    println!("|---|---|---|---|---|---|---|");
    for (run, limit, bands, seconds, per_mtexel, peak, difference) in &summary {
        let difference = difference.map_or("-".into(), |d| d.to_string());
        let limit = limit.map_or("none".into(), |l| format!("{l:.0}"));
        println!(
            "| {run} | {limit} | {bands} | {seconds:.1} | {per_mtexel:.2} | {peak:.0} | \
             {difference} |"
        );
    }
    println!("\n| run | stage | seconds | seconds per output Mtexel |");
    println!("|---|---|---|---|");
    for (run, stages, total, texels) in &breakdown {
        let staged: f64 = stages.iter().map(|s| s.1).sum();
        let rest = ("reading, writing and the rest".to_string(), total - staged);
        for (stage, seconds) in stages.iter().chain([&rest]) {
            let per = seconds / texels * 1e6;
            println!("| {run} | {stage} | {seconds:.1} | {per:.2} |");
        }
    }
    if let Some(rss) = peak_memory_mib() {
        println!("\nprocess peak resident memory over all runs: {rss:.0} MiB");
    }
}

/// Heap peak and seconds per output Mtexel against the output's size (Mtexels, log scale),
/// one point per size (the worst of its runs), each size's memory limit a red cross.
fn plot_growth(
    points: &[(f64, f64, f64, Option<f64>)],
    path: &std::path::Path,
) -> Result<(), Box<dyn std::error::Error>> {
    use plotters::prelude::*;
    let _ = plotters::style::register_font(
        "sans-serif",
        plotters::style::FontStyle::Normal,
        matup::draw::text::FONT,
    );
    let root = BitMapBackend::new(path, (1200, 500)).into_drawing_area();
    root.fill(&WHITE)?;
    let (left, right) = root.split_horizontally(600);
    let x_max = points.iter().map(|p| p.0).fold(1.0, f64::max) * 2.0;
    let x_range = (1.0..x_max).log_scale();
    let heap_max = points
        .iter()
        .map(|p| p.1)
        .chain(points.iter().filter_map(|p| p.3))
        .fold(1.0, f64::max)
        * 1.2;
    let mut chart = ChartBuilder::on(&left)
        .caption("heap peak (MiB) against output size", ("sans-serif", 20))
        .margin(20)
        .x_label_area_size(40)
        .y_label_area_size(60)
        .build_cartesian_2d(x_range.clone(), 0.0..heap_max)?;
    chart.configure_mesh().x_desc("output Mtexels").draw()?;
    chart.draw_series(LineSeries::new(points.iter().map(|p| (p.0, p.1)), &BLUE))?;
    chart.draw_series(
        points
            .iter()
            .map(|p| Circle::new((p.0, p.1), 4, BLUE.filled())),
    )?;
    chart
        .draw_series(
            points
                .iter()
                .filter_map(|p| p.3.map(|l| Cross::new((p.0, l), 6, RED.stroke_width(2)))),
        )?
        .label("--memory-limit")
        .legend(|(x, y)| Cross::new((x + 10, y), 6, RED.stroke_width(2)));
    {
        chart
            .configure_series_labels()
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK)
            .position(SeriesLabelPosition::UpperLeft)
            .draw()?;
    }
    let per_max = points.iter().map(|p| p.2).fold(0.1, f64::max) * 1.3;
    let mut chart = ChartBuilder::on(&right)
        .caption("seconds per output Mtexel", ("sans-serif", 20))
        .margin(20)
        .x_label_area_size(40)
        .y_label_area_size(60)
        .build_cartesian_2d(x_range, 0.0..per_max)?;
    chart.configure_mesh().x_desc("output Mtexels").draw()?;
    chart.draw_series(LineSeries::new(points.iter().map(|p| (p.0, p.2)), &BLUE))?;
    chart.draw_series(
        points
            .iter()
            .map(|p| Circle::new((p.0, p.2), 4, BLUE.filled())),
    )?;
    root.present()?;
    Ok(())
}
