//! Where the memory of a large upscale goes, stage by stage (issue "Outputs of any size in
//! bounded memory"). A shared 1K² material, tiled N×N, goes through the defaults ×4 as
//! `matup upscale` runs them (pipeline, maps saved, preview), once as tileable and once not;
//! a counting allocator records the heap's peak within each stage and what stays live after it.
//!
//! `cargo bench --bench memory` runs N = 1 (1K² → 4K²); `MATUP_MEMORY_TILES=1,2` adds
//! 2K² → 8K², `MATUP_MEMORY_MATERIAL=folder` picks another material.

use std::alloc::{GlobalAlloc, Layout, System};
use std::path::PathBuf;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Mutex;
use std::time::Instant;

use matup::io::save_png;
use matup::material::Material;
use matup::pipeline::{peak_memory_mib, preview};
use matup::progress::Progress;
use matup::{load_material, save_material, Config, LoadOptions, Map, RunOptions, SaveOptions};

/// The system allocator, counting the bytes live and the most live since the last reset.
struct Counting;

static LIVE: AtomicUsize = AtomicUsize::new(0);
static PEAK: AtomicUsize = AtomicUsize::new(0);

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        let p = unsafe { System.alloc(layout) };
        if !p.is_null() {
            grew(layout.size());
        }
        p
    }
    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        let p = unsafe { System.alloc_zeroed(layout) };
        if !p.is_null() {
            grew(layout.size());
        }
        p
    }
    unsafe fn dealloc(&self, p: *mut u8, layout: Layout) {
        unsafe { System.dealloc(p, layout) };
        LIVE.fetch_sub(layout.size(), Ordering::Relaxed);
    }
    unsafe fn realloc(&self, p: *mut u8, layout: Layout, size: usize) -> *mut u8 {
        let q = unsafe { System.realloc(p, layout, size) };
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
    let source = load_material(Some(&folder), &LoadOptions::default())
        .unwrap_or_else(|e| panic!("{}: {e}", folder.display()));
    let out = tempfile::tempdir().expect("a temporary folder");
    println!(
        "{} tiled N×N, defaults ×4, {} threads; heap in MiB (peak within the stage, live after it)\n",
        folder.display(),
        rayon::current_num_threads()
    );
    println!("| run | stage | seconds | heap peak | heap live after |");
    println!("|---|---|---|---|---|");
    let mut summary = Vec::new();
    for &n in &tiles {
        for tileable in [true, false] {
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
            let stages = Stages::new();
            let start = Instant::now();
            stages.begin("start");
            let (result, _) = matup::upscale(&input, &config, &RunOptions::default(), &stages)
                .expect("the upscale runs");
            stages.begin("save maps");
            let folder = out.path().join(format!("{n}-{tileable}"));
            save_material(&result, &folder, &SaveOptions::default()).expect("the maps save");
            stages.begin("preview");
            let sheet = preview(&input, &result, &config, tileable).expect("the preview draws");
            save_png(&folder.join("preview.png"), &sheet).expect("the preview saves");
            stages.end();
            let total = start.elapsed().as_secs_f64();
            drop((result, sheet));
            std::fs::remove_dir_all(&folder).ok();
            let rows = stages.rows.into_inner().unwrap();
            let peak = rows.iter().map(|r| r.2).fold(0.0, f64::max);
            for (stage, seconds, peak, live) in &rows {
                println!("| {run} | {stage} | {seconds:.1} | {peak:.0} | {live:.0} |");
            }
            summary.push((run, total, peak));
        }
    }
    println!("\n| run | seconds | heap peak MiB |");
    println!("|---|---|---|");
    for (run, seconds, peak) in summary {
        println!("| {run} | {seconds:.1} | {peak:.0} |");
    }
    if let Some(rss) = peak_memory_mib() {
        println!("\nprocess peak resident memory over all runs: {rss:.0} MiB");
    }
}
