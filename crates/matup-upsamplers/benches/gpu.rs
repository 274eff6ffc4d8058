//! The GPU engine (wgpu) against matup's CPU executor, side by side in one process: the shipped
//! network (`span_x4_materials`) on a real base-colour map, per 256² tile (a batch of tiles a
//! call, as a run makes them) and per 1K² → 4K² image (the network's share of one map's pass;
//! a material runs its maps and the self-ensemble's passes on top). Prints a table: engine,
//! adapter, tile, median seconds per 256² tile and per 1K² image, and the largest difference
//! from the CPU engine's output. A software adapter (lavapipe, llvmpipe, WARP) is a check of
//! correctness, not of speed, and its rows say so; it runs 64² tiles and no 1K² image (a 256²
//! tile of SPAN took over 10 minutes on lavapipe on 2 busy cores).
//!
//! `cargo bench -p matup-upsamplers --bench gpu`. Settings, by environment variable:
//! - `MATUP_BENCH_ADAPTERS`: which adapters (`gpu:N` or `gpu:NAME`, `;` between them; default
//!   every adapter wgpu offers);
//! - `MATUP_BENCH_1K`: `0` skips the 1K² image (on a software adapter it takes minutes).

mod common;

use std::path::PathBuf;
use std::time::Duration;

use common::median_seconds;

use matup_core::{load_material, upsampler, Border, LoadOptions, Map, PluginSpec};
use matup_upsamplers::gpu;

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../..")
}

/// A real 1K² base colour: a tuning material where `../shared` is beside the checkout, else the
/// shipped sample tiled up to 1K².
fn image_1k() -> Map {
    let shared = repo().join("../shared/materials/ambientcg_Metal053C");
    if let Ok(m) = load_material(Some(&shared), &LoadOptions::default()) {
        return m.base_color.crop(0, 0, 1024, 1024);
    }
    let sample = load_material(
        Some(&repo().join("samples/victorian_wood")),
        &Default::default(),
    )
    .unwrap()
    .base_color;
    let (w, h) = (sample.width(), sample.height());
    Map::from_fn(1024, 1024, 3, |c, y, x| sample.get(c, y % h, x % w))
}

fn largest_difference(a: &Map, b: &Map) -> f32 {
    (a.data().iter().zip(b.data()))
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f32::max)
}

fn main() {
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    let full = image_1k();
    let tile_image = full.crop(0, 0, 256, 256);
    let with_1k = std::env::var("MATUP_BENCH_1K").map_or(true, |v| v != "0");
    let adapters: Vec<String> = match std::env::var("MATUP_BENCH_ADAPTERS") {
        Ok(list) => list.split(';').map(str::to_string).collect(),
        Err(_) => (gpu::adapters().iter())
            .map(|a| format!("gpu:{}", a.index))
            .collect(),
    };
    let mut engines = vec![("cpu".to_string(), "matup on the CPU".to_string(), false)];
    for spec in adapters {
        let pick = match matup_core::device::DeviceSpec::parse(&spec) {
            Ok(matup_core::device::DeviceSpec::Gpu(pick)) => pick,
            _ => panic!("MATUP_BENCH_ADAPTERS: '{spec}' is not gpu:N or gpu:NAME"),
        };
        let adapter = gpu::find(&pick).unwrap();
        let software = adapter.kind == gpu::AdapterKind::Software;
        let name = format!(
            "{} ({}, {})",
            adapter.name,
            adapter.backend,
            adapter.kind.name()
        );
        engines.push((format!("gpu:{}", adapter.index), name, software));
    }
    let network = "onnx:span_x4_materials";
    let run = |device: &str, image: &Map| -> Map {
        let spec = format!("{network},tile={},device={device}", image.width().min(256));
        let up = upsampler(&spec.parse::<PluginSpec>().unwrap()).unwrap();
        up.upsample(std::slice::from_ref(image), 4, Border::Mirror)
            .unwrap()
            .remove(0)
    };
    let small_tile = full.crop(0, 0, 64, 64);
    let reference_tile = run("cpu", &tile_image);
    let reference_small = run("cpu", &small_tile);
    let reference_1k = with_1k.then(|| run("cpu", &full));
    let mut rows = Vec::new();
    for (device, name, software) in &engines {
        let (tile_image, reference_tile, side) = match software {
            true => (&small_tile, &reference_small, 64),
            false => (&tile_image, &reference_tile, 256),
        };
        let spec = format!("{network},tile={side},device={device}");
        let up = upsampler(&spec.parse::<PluginSpec>().unwrap()).unwrap();
        let time = |image: &Map| {
            median_seconds(
                || {
                    up.upsample(std::slice::from_ref(image), 4, Border::Mirror)
                        .unwrap();
                },
                Duration::from_secs(60),
            )
            .0
        };
        let tile_seconds = time(tile_image);
        let mut worst = largest_difference(reference_tile, &run(device, tile_image));
        let image_seconds = match &reference_1k {
            Some(reference) if !software => {
                worst = worst.max(largest_difference(reference, &run(device, &full)));
                format!("{:.2}", time(&full))
            }
            _ => "not run".into(),
        };
        let engine = if device == "cpu" { "matup" } else { "wgpu" };
        let note = if *software {
            ": a check of correctness, not of speed"
        } else {
            ""
        };
        eprintln!("{engine} {name}: {tile_seconds:.3} s a tile, {image_seconds} s a 1K² image");
        rows.push(format!(
            "| {engine} | {name}{note} | {side}² + {} context | {tile_seconds:.3} | {image_seconds} | {:.1e} ({:.2} levels) |",
            up.context(),
            worst,
            worst * 255.0
        ));
    }
    println!(
        "\n{network} ×4, the CPU's {cores} cores and each adapter (median seconds; the \
         largest difference from the CPU engine's output, values in [0, 1])\n"
    );
    println!("| engine | adapter | tile | s / tile | s / 1K² → 4K² image | largest difference |");
    println!("|---|---|---|---|---|---|");
    for row in rows {
        println!("{row}");
    }
}
