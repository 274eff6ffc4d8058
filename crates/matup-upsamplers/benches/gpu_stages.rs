//! Where the SR stage's time goes on a GPU: the per-map path's eight 1K² images (four maps,
//! two self-ensemble passes) through `span_x4_materials` on the candle engine, outputs left on
//! the device (the default path's) and brought to the host, against the network's arithmetic
//! alone on the same tiles, the download of the eight outputs, and the download of one
//! material's 7 features at the output size (what the default path brings back). Each the
//! median of three, the device synchronised around each timing. Prints a table.
//!
//! `cargo bench -p matup-upsamplers --features cuda --bench gpu_stages` (`MATUP_BENCH_DEVICE`:
//! `cuda` by default, or `cpu` for a small check of the bench itself; `MATUP_BENCH_SIZE`: the
//! LR side, default 1024 on a GPU, 128 on the CPU).

mod common;

use std::time::Duration;

use common::median_seconds;

use candle_core::{DType, Tensor};
use matup_core::upsample::RgbUpsampler;
use matup_core::{Border, Map};
use matup_upsamplers::onnx::{
    resolve, EngineChoice, Graph, OnnxUpsampler, Padding, Precision, TensorNet,
};

/// Median seconds of three calls of `f`, after one untimed.
fn median(f: impl FnMut()) -> f64 {
    median_seconds(f, Duration::MAX).0
}

fn main() {
    let device_name = std::env::var("MATUP_BENCH_DEVICE").unwrap_or_else(|_| "cuda".into());
    let device = matup_core::device::parse_device(&device_name).unwrap();
    let size: usize = std::env::var("MATUP_BENCH_SIZE")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(if device.is_cuda() { 1024 } else { 128 });
    let images: Vec<Map> = (0..8)
        .map(|k| {
            Map::from_fn(size, size, 3, |c, y, x| {
                let v = ((x * 7 + y * 13 + c * 5 + k * 3) % 97) as f32 / 96.0;
                0.25 + 0.5 * v
            })
        })
        .collect();
    let sync = || device.synchronize().unwrap();
    let source = resolve("span_x4_materials").unwrap();
    let choice = EngineChoice::Candle(device_name.clone(), Precision::F32);
    let up = OnnxUpsampler::load_source(source.clone(), None, choice).unwrap();
    let (tile, overlap) = (up.info.tile, up.info.overlap);
    let scale = up.info.scale;

    // The whole call, as the default path makes it: eight images, outputs left on the device.
    let on_device = median(|| {
        up.upsample_on_device(&images, scale, Border::Mirror)
            .unwrap();
        sync();
    });
    // The same, outputs brought to the host.
    let whole = median(|| {
        up.upsample(&images, scale, Border::Mirror).unwrap();
    });

    // The network alone on the same number of windows, in batches of 32, on the device.
    let tiles_per_image = size.div_ceil(tile).pow(2);
    let windows = 8 * tiles_per_image;
    let side = tile.min(size) + 2 * overlap;
    let graph = Graph::from_model(&source.proto().unwrap()).unwrap();
    let net = TensorNet::new(graph, &device, Precision::F32).unwrap();
    let batch = Tensor::full(0.5f32, (32.min(windows), 3, side, side), &device).unwrap();
    let network = median(|| {
        for _ in 0..windows.div_ceil(32) {
            net.run(batch.clone(), Padding::Zero).unwrap();
        }
        sync();
    });

    // The outputs' download: eight 3-plane images at the output size.
    let out_side = size * scale;
    let outputs = Tensor::zeros((8, 3, out_side, out_side), DType::F32, &device).unwrap();
    sync();
    let download = median(|| {
        outputs.flatten_all().unwrap().to_vec1::<f32>().unwrap();
    });

    // What the default path brings back: one material's 7 features.
    let features = Tensor::zeros((7, out_side, out_side), DType::F32, &device).unwrap();
    sync();
    let features_download = median(|| {
        matup_core::device_maps::download(&features).unwrap();
    });

    println!(
        "\nspan_x4_materials on {device_name}: 8 images of {size}², tiles of {tile} with {overlap} of \
         context ({windows} windows of {side}²), {} host threads\n",
        rayon::current_num_threads()
    );
    println!("| part | seconds (median of 3) |");
    println!("|---|---|");
    println!("| the whole call, outputs left on the device | {on_device:.3} |");
    println!("| the whole call, outputs on the host | {whole:.3} |");
    println!("| the network alone, batches of 32 windows | {network:.3} |");
    println!("| downloading 8 outputs ({out_side}² × 3) | {download:.3} |");
    println!("| downloading one material's 7 features ({out_side}²) | {features_download:.3} |");
}
