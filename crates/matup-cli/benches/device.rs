//! The CPU and a GPU side by side: `matup upscale` and `matup batch` with the defaults on
//! `--device cpu` and `--device cuda`, one process per run. Prints a table: seconds (end to
//! end, and the per-map SR stage: each map through the network under the self-ensemble's
//! passes, encoded for it and decoded, the back-projection not included), peak host memory (the process's high-water mark), peak
//! GPU memory (nvidia-smi, sampled every 100 ms, less what was in use before the run), and for
//! a row run on both devices the largest difference between their maps as 8-bit files store
//! them.
//!
//! `cargo bench -p matup-cli --features cuda --bench device`
//!
//! Rows: the README's main job (the shipped 128² sample → 512²); a 1K² material → 4K²; the
//! same repeated 2 × 2 → 8K² and 4 × 4 → 16K²; a library of 100 materials (128² crops of the
//! repository's test materials) through `matup batch`. Settings, by environment variable:
//! - `MATUP_BIN`: the `matup` binary to run (default: this build's);
//! - `MATUP_REPO`: the repository whose sample and test materials the rows read (default:
//!   this build's);
//! - `MATUP_BENCH_MATERIAL`: the 1K² material (default `../shared/materials/ambientcg_Metal053C`);
//! - `MATUP_BENCH_ROWS`: which rows, of `main,1k,2k,4k,library` (default all);
//! - `MATUP_BENCH_CPU_ROWS`: the rows also run on the CPU (default `main,1k,2k,library`:
//!   4K² → 16K² takes about 11 minutes on 2 cores);
//! - `MATUP_BENCH_HOST_ROWS`: the rows also run with `--upsampler bicubic` on the CPU (default
//!   `1k`): the CPU's part of the path alone, what a GPU's host does besides the network;
//! - `MATUP_BENCH_DEVICES`: the devices run beside the CPU, `;` between them (default `cuda`
//!   where nvidia-smi answers; `gpu:0` or `gpu:nvidia` runs the GPU engine through Vulkan);
//! - `MATUP_BENCH_GPU_VARIANTS`: options of the network (`;` between variants, e.g.
//!   `precision=tf32;precision=f16`) each also run on the GPU, on the rows of
//!   `MATUP_BENCH_VARIANT_ROWS` (default `1k`), their maps compared with the CPU's.

mod common;

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use common::stage;
use matup_core::io::encode_map;
use matup_core::map::Map;
use matup_core::material::{MapKind, Material, NormalConvention};
use matup_core::{load_material, save_material, LoadOptions, SaveOptions};
use matup_method::plan::MATERIAL_NETWORK;

/// The repository's root: `MATUP_REPO`, for a bench binary carried to another machine, else
/// this build's.
fn repo() -> PathBuf {
    std::env::var_os("MATUP_REPO").map_or(
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../.."),
        PathBuf::from,
    )
}

fn matup() -> PathBuf {
    std::env::var_os("MATUP_BIN").map_or(PathBuf::from(env!("CARGO_BIN_EXE_matup")), PathBuf::from)
}

/// One run's measurements.
struct Measured {
    seconds: f64,
    /// The per-map SR stage (`residual base` in run.json), summed over the run's reports.
    sr_stage_seconds: f64,
    host_mib: f64,
    gpu_mib: Option<f64>,
}

/// GPU memory in use now, in MiB, summed over the GPUs (None without nvidia-smi).
fn gpu_memory_used() -> Option<f64> {
    let o = Command::new("nvidia-smi")
        .args(["--query-gpu=memory.used", "--format=csv,noheader,nounits"])
        .output()
        .ok()?;
    let text = String::from_utf8_lossy(&o.stdout);
    o.status.success().then(|| {
        text.lines()
            .filter_map(|l| l.trim().parse::<f64>().ok())
            .sum()
    })
}

/// Runs `matup ARGS`, sampling the process's peak host memory and the GPU's memory in use
/// while it runs.
fn measure(name: &str, args: &[&str]) -> (Measured, String) {
    let before = gpu_memory_used();
    let gpu_peak = Arc::new(AtomicU64::new(0));
    let done = Arc::new(AtomicBool::new(false));
    let sampler = before.map(|_| {
        let (peak, done) = (gpu_peak.clone(), done.clone());
        let mut smi = Command::new("nvidia-smi")
            .args([
                "--query-gpu=memory.used",
                "--format=csv,noheader,nounits",
                "-lms",
                "100",
            ])
            .stdout(Stdio::piped())
            .spawn()
            .expect("nvidia-smi answered a moment ago");
        let out = smi.stdout.take().unwrap();
        let reader = std::thread::spawn(move || {
            for line in BufReader::new(out).lines().map_while(|l| l.ok()) {
                if let Ok(mib) = line.trim().parse::<f64>() {
                    peak.fetch_max(mib as u64, Ordering::Relaxed);
                }
                if done.load(Ordering::Relaxed) {
                    break;
                }
            }
        });
        (smi, reader)
    });
    let start = Instant::now();
    let mut child = Command::new(matup())
        .args(args)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let status = format!("/proc/{}/status", child.id());
    let mut host_kib = 0u64;
    let stdout = child.stdout.take().unwrap();
    let collect = std::thread::spawn(move || {
        let mut s = String::new();
        std::io::Read::read_to_string(&mut BufReader::new(stdout), &mut s).map(|_| s)
    });
    while child.try_wait().unwrap().is_none() {
        // VmHWM: the process's peak resident memory so far.
        if let Ok(text) = std::fs::read_to_string(&status) {
            let hwm = text.lines().find_map(|l| l.strip_prefix("VmHWM:"));
            if let Some(kib) = hwm.and_then(|v| v.trim().trim_end_matches("kB").trim().parse().ok())
            {
                host_kib = host_kib.max(kib);
            }
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    let seconds = start.elapsed().as_secs_f64();
    let output = child.wait_with_output().unwrap();
    let stdout = collect.join().unwrap().unwrap();
    assert!(
        output.status.success(),
        "{name}: {}",
        String::from_utf8_lossy(&output.stderr)
    );
    done.store(true, Ordering::Relaxed);
    if let Some((mut smi, reader)) = sampler {
        let _ = smi.kill();
        let _ = reader.join();
    }
    let gpu_mib = before.map(|b| (gpu_peak.load(Ordering::Relaxed) as f64 - b).max(0.0));
    let measured = Measured {
        seconds,
        sr_stage_seconds: 0.0,
        host_mib: host_kib as f64 / 1024.0,
        gpu_mib,
    };
    (measured, stdout)
}

/// `matup upscale FOLDER` with the defaults and `settings`, its maps written to `out`.
fn upscale(name: &str, folder: &Path, out: &Path, settings: &[&str]) -> Measured {
    let (folder, out) = (folder.to_str().unwrap(), out.to_str().unwrap());
    let mut args = vec!["upscale", folder, "-o", out, "--json"];
    args.extend(settings);
    let (mut m, stdout) = measure(name, &args);
    let report: serde_json::Value = serde_json::from_str(&stdout).unwrap();
    m.sr_stage_seconds = stage(&report, "residual base");
    eprintln!("{name}: stages {}", report["timings"]);
    m
}

/// `matup batch LIBRARY` with the defaults and `settings`.
fn batch(name: &str, library: &Path, out: &Path, settings: &[&str]) -> Measured {
    let (library, out_dir) = (library.to_str().unwrap(), out.to_str().unwrap());
    let mut args = vec!["batch", library, "-o", out_dir, "--quiet"];
    args.extend(settings);
    let (mut m, _) = measure(name, &args);
    // Each material's run.json, beside its maps.
    let mut reports = vec![out.to_path_buf()];
    while let Some(dir) = reports.pop() {
        for entry in std::fs::read_dir(&dir).unwrap().flatten() {
            let path = entry.path();
            if path.is_dir() {
                reports.push(path);
            } else if path.file_name().is_some_and(|n| n == "run.json") {
                let text = std::fs::read_to_string(&path).unwrap();
                m.sr_stage_seconds += stage(&serde_json::from_str(&text).unwrap(), "residual base");
            }
        }
    }
    m
}

/// The largest difference, in 8-bit levels, between two outputs' maps as their files hold them.
fn levels_apart(a: &Path, b: &Path) -> f64 {
    let load = |p: &Path| load_material(Some(p), &LoadOptions::default()).unwrap();
    let (a, b) = (load(a), load(b));
    let mut worst = 0f32;
    for kind in MapKind::ALL {
        if let (Some(x), Some(y)) = (a.map(kind), b.map(kind)) {
            let stored =
                |m: &Map| encode_map(kind, m, false, NormalConvention::DirectX).into_owned();
            let (x, y) = (stored(x), stored(y));
            for (p, q) in x.data().iter().zip(y.data()) {
                worst = worst.max((p - q).abs());
            }
        }
    }
    (worst * 255.0) as f64
}

/// `m` repeated `k × k` times.
fn repeated(m: &Material, k: usize) -> Material {
    m.map_maps(|map| {
        let (w, h) = (map.width(), map.height());
        Map::from_fn(w * k, h * k, map.channels(), |c, y, x| {
            map.get(c, y % h, x % w)
        })
    })
}

/// 100 materials of 128²: crops of the repository's test materials at 8 offsets each.
fn library(dir: &Path) {
    let root = repo().join("tests/data/materials");
    let mut names: Vec<PathBuf> = std::fs::read_dir(&root)
        .unwrap()
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.is_dir())
        .collect();
    names.sort();
    let materials: Vec<Material> = (names.iter())
        .map(|p| load_material(Some(p), &LoadOptions::default()).unwrap())
        .collect();
    for i in 0..100 {
        let m = &materials[i % materials.len()];
        let offset = (i / materials.len()) * 16;
        let (x, y) = (offset % (m.width() - 128), offset % (m.height_px() - 128));
        let folder = dir.join(format!("material{i:03}"));
        save_material(&m.crop(x, y, 128, 128), &folder, &SaveOptions::default()).unwrap();
    }
}

fn main() {
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    let list = |var: &str, default: &str| -> Vec<String> {
        let v = std::env::var(var).unwrap_or_else(|_| default.into());
        v.split(',').map(|s| s.trim().to_string()).collect()
    };
    let rows = list("MATUP_BENCH_ROWS", "main,1k,2k,4k,library");
    let cpu_rows = list("MATUP_BENCH_CPU_ROWS", "main,1k,2k,library");
    let host_rows = list("MATUP_BENCH_HOST_ROWS", "1k");
    let variant_rows = list("MATUP_BENCH_VARIANT_ROWS", "1k");
    let variants: Vec<String> = std::env::var("MATUP_BENCH_GPU_VARIANTS")
        .unwrap_or_default()
        .split(';')
        .map(|s| s.trim().to_string())
        .filter(|s| !s.is_empty())
        .collect();
    let material = std::env::var_os("MATUP_BENCH_MATERIAL").map_or(
        repo().join("../shared/materials/ambientcg_Metal053C"),
        PathBuf::from,
    );
    let gpu = gpu_memory_used().is_some();
    let devices: Vec<String> = match std::env::var("MATUP_BENCH_DEVICES") {
        Ok(list) => list
            .split(';')
            .filter(|d| !d.is_empty())
            .map(String::from)
            .collect(),
        Err(_) if gpu => vec!["cuda".into()],
        Err(_) => vec![],
    };
    let scratch = tempfile::tempdir().unwrap();
    let inputs = scratch.path().join("inputs");
    let mut table = Vec::new();
    for row in &rows {
        let (name, input): (String, PathBuf) = match row.as_str() {
            "main" => (
                "sample 128² → 512² (README main job)".into(),
                repo().join("samples/victorian_wood"),
            ),
            "1k" | "2k" | "4k" => {
                let k = match row.as_str() {
                    "1k" => 1,
                    "2k" => 2,
                    _ => 4,
                };
                let m = load_material(Some(&material), &LoadOptions::default())
                    .unwrap_or_else(|e| panic!("{e}: set MATUP_BENCH_MATERIAL to a 1K² material"));
                let folder = inputs.join(row);
                save_material(&repeated(&m, k), &folder, &SaveOptions::default()).unwrap();
                let side = m.width() * k;
                let label = |s: usize| match s % 1024 {
                    0 => format!("{}K²", s / 1024),
                    _ => format!("{s}²"),
                };
                let name = material.file_name().unwrap().to_string_lossy();
                let name = format!(
                    "{name}{} {} → {}",
                    if k > 1 {
                        format!(" {k}×{k}")
                    } else {
                        String::new()
                    },
                    label(side),
                    label(4 * side)
                );
                (name, folder)
            }
            "library" => {
                let folder = inputs.join("library");
                library(&folder);
                (
                    "library of 100 materials, 128² → 512² (matup batch)".into(),
                    folder,
                )
            }
            other => panic!("unknown row '{other}': use main, 1k, 2k, 4k, library"),
        };
        // (what the table calls the run, its settings, whether its maps are compared)
        let mut runs: Vec<(String, Vec<String>, bool)> = vec![];
        let settings = |s: &[&str]| s.iter().map(|s| s.to_string()).collect::<Vec<_>>();
        if cpu_rows.contains(row) {
            runs.push(("cpu".into(), settings(&["--device", "cpu"]), true));
        }
        for device in &devices {
            runs.push((device.clone(), settings(&["--device", device]), true));
            if variant_rows.contains(row) && device.starts_with("cuda") {
                for options in &variants {
                    let upsampler = format!("{MATERIAL_NETWORK},{options}");
                    let run = settings(&["--device", device, "--upsampler", &upsampler]);
                    runs.push((format!("{device}, {options}"), run, true));
                }
            }
        }
        if host_rows.contains(row) {
            let bicubic = settings(&["--device", "cpu", "--upsampler", "bicubic"]);
            runs.push(("cpu, bicubic for the network".into(), bicubic, false));
        }
        let mut outputs = vec![];
        for (i, (device, settings, compared)) in runs.into_iter().enumerate() {
            let out = scratch.path().join(format!("{row}-{i}"));
            let label = format!("{name}, {device}");
            eprintln!("running {label}");
            let settings: Vec<&str> = settings.iter().map(|s| s.as_str()).collect();
            let m = if row == "library" {
                batch(&label, &input, &out, &settings)
            } else {
                upscale(&label, &input, &out, &settings)
            };
            if compared {
                outputs.push((device.clone(), out));
            }
            table.push((name.clone(), device, m));
        }
        // Every GPU run's maps against the CPU's (the first compared run, where it ran).
        if let (Some((first, cpu)), true) = (outputs.first(), row != "library") {
            for (device, out) in outputs.iter().skip(1).filter(|_| first == "cpu") {
                let apart = levels_apart(cpu, out);
                println!("{name}: {device} maps at most {apart:.2} of 255 from the CPU's");
            }
        }
    }
    println!(
        "\nmatup, defaults, {cores} CPU cores{}\n",
        if gpu { " and the GPU" } else { "" }
    );
    println!("| run | device | seconds | SR stage s | peak host MiB | peak GPU MiB |");
    println!("|---|---|---|---|---|---|");
    for (name, device, m) in &table {
        println!(
            "| {name} | {device} | {:.1} | {:.1} | {:.0} | {} |",
            m.seconds,
            m.sr_stage_seconds,
            m.host_mib,
            m.gpu_mib.map_or("-".into(), |g| format!("{g:.0}")),
        );
    }
}
