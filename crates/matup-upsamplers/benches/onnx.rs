//! Per-render upsampling time of each ONNX model matup knows: the shipped SPAN ×4 and, from
//! `../shared/models` when it is there, SPAN ×2 and Real-ESRGAN ×4. Each model runs on 128²
//! and 512² LR images (a real base-colour map): whole, as one tile without context, treated as
//! tileable (matup's executor wraps its convolutions around, tract pads with zeros); and, not
//! tileable, in the sidecar's tiles with mirrored context. Each on matup's executor and on
//! tract, on 1 and 2 threads. Prints a table of medians.
//!
//! `cargo bench -p matup-upsamplers --bench onnx` (`MATUP_BENCH_SLOW=1` adds Real-ESRGAN at
//! 512², several minutes).

mod common;

use std::path::{Path, PathBuf};
use std::time::Duration;

use common::median_seconds;

use matup_core::{load_material, upsampler, Border, LoadOptions, Map, PluginSpec};
use matup_upsamplers as _;

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../..")
}

struct Model {
    name: &'static str,
    path: PathBuf,
    scale: usize,
    tile: usize,
    overlap: usize,
}

/// The shared models have no sidecars: write them into `dir` next to a copy of the network.
fn shared_model(dir: &Path, name: &'static str, scale: usize, overlap: usize) -> Option<Model> {
    let source = repo().join("../shared/models").join(format!("{name}.onnx"));
    if !source.is_file() {
        return None;
    }
    let path = dir.join(format!("{name}.onnx"));
    std::fs::copy(&source, &path).unwrap();
    std::fs::write(
        path.with_extension("toml"),
        format!("scale = {scale}\ntile = 128\noverlap = {overlap}\n"),
    )
    .unwrap();
    Some(Model {
        name,
        path,
        scale,
        tile: 128,
        overlap,
    })
}

fn main() {
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    let slow = std::env::var("MATUP_BENCH_SLOW").is_ok_and(|v| v == "1");
    let shared = tempfile::tempdir().unwrap();
    let mut models = vec![Model {
        name: "span_x4_ch48",
        path: repo().join("models/span_x4_ch48.onnx"),
        scale: 4,
        tile: 128,
        overlap: 22,
    }];
    // SPAN's receptive-field radius is 21 LR texels; Real-ESRGAN's is far larger, and 10 is
    // what its own ncnn app pads tiles with (../shared/models/README.md).
    models.extend(shared_model(shared.path(), "span_x2_ch48", 2, 22));
    models.extend(shared_model(shared.path(), "realesrgan_x4plus", 4, 10));

    let wood = load_material(
        Some(&repo().join("../shared/materials/polyhaven_wood_cabinet_worn_long")),
        &LoadOptions::default(),
    )
    .map(|m| m.base_color)
    .unwrap_or_else(|_| {
        load_material(
            Some(&repo().join("samples/victorian_wood")),
            &Default::default(),
        )
        .unwrap()
        .base_color
    });

    let mut rows = Vec::new();
    for model in &models {
        for lr in [128, 512] {
            if lr > wood.width() || (model.name.starts_with("realesrgan") && lr > 128 && !slow) {
                continue;
            }
            let image: Map = wood.crop(0, 0, lr, lr);
            let tiled = format!(
                "{}² tiles + {} context, mirrored",
                model.tile, model.overlap
            );
            for (tiling, tile, overlap, border) in [
                ("whole, tileable".to_string(), lr, 0, Border::Wrap),
                (tiled, model.tile, model.overlap, Border::Mirror),
            ] {
                for (engine, threads) in [("matup", 1), ("matup", 2), ("tract", 1), ("tract", 2)] {
                    let spec = format!(
                        "onnx:{},tile={tile},overlap={overlap},threads={threads},engine={engine}",
                        model.path.display()
                    );
                    let up = upsampler(&spec.parse::<PluginSpec>().unwrap())
                        .unwrap_or_else(|e| panic!("{spec}: {e}"));
                    let (seconds, runs) = median_seconds(
                        || {
                            up.upsample(std::slice::from_ref(&image), model.scale, border)
                                .unwrap();
                        },
                        Duration::from_secs(30),
                    );
                    eprintln!(
                        "{} {lr}² {tiling} {engine} {threads}t: {seconds:.3} s",
                        model.name
                    );
                    rows.push(format!(
                        "| {} | {lr}² | {tiling} | {engine} | {threads} | {seconds:.3} | {:.1} | {runs} |",
                        model.name,
                        100.0 * seconds * (128.0 * 128.0) / (lr * lr) as f64,
                    ));
                }
            }
        }
    }

    println!("\nONNX upsampling, {cores} cores (median seconds per render)\n");
    println!(
        "| model | LR size | tiling | engine | threads | s / render | s / 100 renders of 128² | runs |"
    );
    println!("|---|---|---|---|---|---|---|---|");
    for row in rows {
        println!("{row}");
    }
}
