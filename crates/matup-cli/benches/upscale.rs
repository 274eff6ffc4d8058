//! End-to-end timing of `matup upscale`, as users run it (the real binary, one process per
//! row, so each row's peak memory is its own). Prints a table.
//!
//! `cargo bench -p matup-cli --bench upscale`
//!
//! Timing rows: the README's main job (matup's defaults on the shipped 128² sample: per-map
//! SPAN, each map under two symmetries averaged, back-projected, no training), and the same
//! with one pass (the self-ensemble's cost); METHOD.md's paper settings (`configs/paper.toml`) on
//! the sample with `lanczos3`, the fixed 10 epochs and with early stopping; the defaults' cost
//! per output megatexel at 256², 512² and 1K² outputs, and the training's (paper settings,
//! 1 epoch each); with `MATUP_BENCH_4K=1`, also 1K² → 4K² with the defaults, with one pass,
//! and 1 epoch on 262 144 sampled texels; with `MATUP_BENCH_SHARED_1K=1`, every 1K² material
//! of `../shared/materials` → 4K² with the defaults (the CPU's time budget: 60 s each on 2
//! cores). `MATUP_BENCH_EPOCHS` overrides the 10 epochs of the paper rows.
//!
//! Then the quality of the same settings (`matup sweep`): the four shared materials cropped
//! to 512² → 128² → ×4, SPAN, render PSNR / FLIP under 16 held-out lights, means over the
//! materials (`MATUP_BENCH_QUALITY=0` skips it; it takes about 6 minutes on 2 cores).

mod common;

use std::path::{Path, PathBuf};
use std::process::Command;

use common::stage;
use matup_core::{load_material, save_material, LoadOptions, SaveOptions};

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../..")
}

struct Row {
    name: String,
    output: usize,
    report: serde_json::Value,
}

fn run(name: &str, material: &Path, output: usize, extra: &[&str]) -> Row {
    let out = tempfile::tempdir().unwrap();
    let mut args = vec![
        "upscale",
        material.to_str().unwrap(),
        "-o",
        out.path().to_str().unwrap(),
        "--json",
    ];
    args.extend_from_slice(extra);
    let o = Command::new(env!("CARGO_BIN_EXE_matup"))
        .args(&args)
        .output()
        .unwrap();
    assert!(
        o.status.success(),
        "{name}: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    Row {
        name: name.to_string(),
        output,
        report: serde_json::from_slice(&o.stdout).unwrap(),
    }
}

/// A shared material (`../shared/materials/NAME`) box-filtered to `size`², saved as PNG in a temporary folder.
fn downsampled(name: &str, size: usize) -> tempfile::TempDir {
    let folder = repo().join("../shared/materials").join(name);
    if !folder.is_dir() {
        eprintln!(
            "{} is missing: the 1K² rows read the shared material sets; put them \
             (../shared/materials) beside the repository",
            folder.display()
        );
        std::process::exit(2);
    }
    let m = load_material(Some(&folder), &LoadOptions::default()).unwrap();
    let dir = tempfile::tempdir().unwrap();
    save_material(
        &m.box_downsample(m.width() / size),
        dir.path(),
        &SaveOptions::default(),
    )
    .unwrap();
    dir
}

/// The materials of `../shared/materials` whose maps are `side`² texels: (name, folder).
fn shared_materials_of_side(side: usize) -> Vec<(String, PathBuf)> {
    let root = repo().join("../shared/materials");
    let Ok(entries) = std::fs::read_dir(&root) else {
        eprintln!(
            "{} is missing: the shared 1K² rows read it; put the shared material sets there",
            root.display()
        );
        std::process::exit(2);
    };
    let mut found: Vec<(String, PathBuf)> = entries
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| {
            load_material(Some(p), &LoadOptions::default())
                .is_ok_and(|m| (m.width(), m.height_px()) == (side, side))
        })
        .map(|p| (p.file_name().unwrap().to_string_lossy().into_owned(), p))
        .collect();
    found.sort();
    found
}

/// The flags of METHOD.md's settings (`configs/paper.toml`, `paper`) with `lanczos3` targets,
/// `epochs` epochs and `extra`.
fn paper_args<'a>(paper: &'a str, epochs: &'a str, extra: &[&'a str]) -> Vec<&'a str> {
    let mut args = vec![
        "--config",
        paper,
        "--upsampler",
        "lanczos3",
        "--epochs",
        epochs,
    ];
    args.extend_from_slice(extra);
    args
}

fn main() {
    // `cargo bench` passes `--bench`; nothing else to parse.
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    let epochs = std::env::var("MATUP_BENCH_EPOCHS").unwrap_or_else(|_| "10".into());
    let paper = repo().join("configs/paper.toml");
    let paper = paper.to_str().unwrap();
    let sample = repo().join("samples/victorian_wood");
    let mut rows = vec![
        run(
            "sample 128²→512², defaults (README main job)",
            &sample,
            512,
            &[],
        ),
        run(
            "sample 128²→512², defaults with one pass (--self-ensemble 1)",
            &sample,
            512,
            &["--self-ensemble", "1"],
        ),
        run(
            &format!("sample 128²→512², paper settings, lanczos3, {epochs} epochs"),
            &sample,
            512,
            &paper_args(paper, &epochs, &["--no-early-stop"]),
        ),
        run(
            &format!("sample 128²→512², paper settings, lanczos3, ≤ {epochs} epochs, early stop"),
            &sample,
            512,
            &paper_args(paper, &epochs, &["--early-stop"]),
        ),
    ];
    for lr in [64, 128, 256] {
        let dir = downsampled("polyhaven_wood_cabinet_worn_long", lr);
        rows.push(run(
            &format!("wood {lr}²→{}², defaults", 4 * lr),
            dir.path(),
            4 * lr,
            &[],
        ));
        rows.push(run(
            &format!("wood {lr}²→{}², paper settings, 1 epoch", 4 * lr),
            dir.path(),
            4 * lr,
            &paper_args(paper, "1", &[]),
        ));
    }
    if std::env::var("MATUP_BENCH_4K").is_ok_and(|v| v == "1") {
        let dir = downsampled("polyhaven_wood_cabinet_worn_long", 1024);
        rows.push(run("wood 1K²→4K², defaults", dir.path(), 4096, &[]));
        rows.push(run(
            "wood 1K²→4K², defaults with one pass (--self-ensemble 1)",
            dir.path(),
            4096,
            &["--self-ensemble", "1"],
        ));
        rows.push(run(
            "wood 1K²→4K², paper settings, 1 epoch of 262144 texels",
            dir.path(),
            4096,
            &paper_args(paper, "1", &["--texels-per-epoch", "262144"]),
        ));
    }

    if std::env::var("MATUP_BENCH_SHARED_1K").is_ok_and(|v| v == "1") {
        for (name, folder) in shared_materials_of_side(1024) {
            rows.push(run(
                &format!("{name} 1K²→4K², defaults"),
                &folder,
                4096,
                &[],
            ));
        }
    }

    println!("\nmatup upscale, {cores} cores (times in seconds; per-megatexel figures are per output megatexel)\n");
    println!("| run | residual base | back-projection | render LR | targets | train | epochs | train/epoch/MTx | infer | height | total | total/MTx | peak MiB |");
    println!("|---|---|---|---|---|---|---|---|---|---|---|---|---|");
    for row in &rows {
        let r = &row.report;
        let megatexels = (row.output * row.output) as f64 / 1e6;
        let train = stage(r, "train");
        let trained_epochs = r["levels"][0]["training"]["epochs_trained"]
            .as_f64()
            .unwrap_or(0.0);
        let texels_per_epoch = r["config"]["train"]["texels_per_epoch"]
            .as_f64()
            .map_or(megatexels, |t| t / 1e6);
        let total = r["total_seconds"].as_f64().unwrap();
        let per_epoch = if trained_epochs > 0.0 {
            format!("{:.2}", train / trained_epochs / texels_per_epoch)
        } else {
            "-".to_string()
        };
        println!(
            "| {} | {:.2} | {:.2} | {:.2} | {:.2} | {:.2} | {:.2} | {} | {:.2} | {:.2} | {:.1} | {:.1} | {:.0} |",
            row.name,
            stage(r, "residual base"),
            stage(r, "back-projection"),
            stage(r, "render LR"),
            stage(r, "targets"),
            train,
            trained_epochs,
            per_epoch,
            stage(r, "infer"),
            stage(r, "height"),
            total,
            total / megatexels,
            r["peak_memory_mib"].as_f64().unwrap_or(f64::NAN),
        );
    }

    if std::env::var("MATUP_BENCH_QUALITY").map_or(true, |v| v != "0") {
        quality();
    }
}

/// `sweeps/early_stop.toml` run by `matup sweep`: each method's mean render PSNR, FLIP,
/// seconds and epochs over the materials.
fn quality() {
    let out = tempfile::tempdir().unwrap();
    let o = Command::new(env!("CARGO_BIN_EXE_matup"))
        .args(["sweep", "--quiet", "-o"])
        .arg(out.path())
        .arg(repo().join("sweeps/early_stop.toml"))
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let text = std::fs::read_to_string(out.path().join("results.json")).unwrap();
    let rows: Vec<serde_json::Value> = serde_json::from_str(&text).unwrap();
    // Methods in the order they first appear; a run's id is `material/method`.
    let mut methods: Vec<(String, Vec<&serde_json::Value>)> = Vec::new();
    for row in &rows {
        let id = row["id"].as_str().unwrap();
        let method = id.split_once('/').map_or(id, |(_, m)| m).to_string();
        match methods.iter_mut().find(|(m, _)| *m == method) {
            Some((_, runs)) => runs.push(row),
            None => methods.push((method, vec![row])),
        }
    }
    println!("\nquality: sweeps/early_stop.toml (512² crops of the four shared materials → 128² → ×4, SPAN, 16 held-out lights), means over the materials\n");
    println!("| method | render PSNR dB | FLIP | seconds | epochs |");
    println!("|---|---|---|---|---|");
    for (method, runs) in &methods {
        let mean = |f: &dyn Fn(&serde_json::Value) -> f64| {
            runs.iter().map(|r| f(r)).sum::<f64>() / runs.len() as f64
        };
        let metric = |name: &'static str| {
            mean(&|r: &serde_json::Value| r["evaluation"][name].as_f64().unwrap_or(f64::NAN))
        };
        println!(
            "| {method} | {:.3} | {:.4} | {:.1} | {:.2} |",
            metric("render_psnr"),
            metric("render_flip"),
            mean(&|r: &serde_json::Value| r["seconds"].as_f64().unwrap()),
            mean(&|r: &serde_json::Value| r["epochs_trained"].as_f64().unwrap_or(0.0)),
        );
    }
}
