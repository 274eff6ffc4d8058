//! The `matup` command: a thin layer over the matup libraries. It parses arguments, calls
//! the library, and turns errors into messages and exit codes.
//!
//! It is a library too, so that a binary linking more plugins (a researcher's upsampler or
//! shading model) gets the whole command line with one call: see `examples/nearest-upsampler`.

mod batch;
mod downsample;
mod eval;
mod experiment;
#[cfg(feature = "onnx")]
mod learn;
mod list;
mod material_args;
mod plot;
mod progress_bars;
mod render;
mod upscale;
mod view;

use std::process::ExitCode;

use clap::{Parser, Subcommand};

// Training allocates and frees the same few buffers every step; glibc's malloc serves
// buffers over 128 KiB with mmap and page-faults them in anew each time (measured: a
// 3.0 ms unfold became 0.5 ms with mimalloc).
#[global_allocator]
static ALLOCATOR: mimalloc::MiMalloc = mimalloc::MiMalloc;

/// mimalloc's `purge_delay` option (mimalloc.h, v3).
const MI_OPTION_PURGE_DELAY: libmimalloc_sys::mi_option_t = 15;

/// Freed memory stays with the process for a second before mimalloc returns it (its default is
/// 10 ms), unless `MIMALLOC_PURGE_DELAY` says otherwise. The per-map path frees and allocates
/// output-size maps (64–192 MB at 4K²) one after another, and each fresh one was page-faulted
/// and zeroed by the kernel anew: a third of a 1K² → 4K² run's CPU time in perf. Kept, they
/// are reused: that run's CPU stages (bicubic upsampler) went from 6.4 to 4.7 s on 2 cores,
/// with a peak resident memory no higher (1259 against 1301 MB).
fn keep_freed_memory_a_while() {
    if std::env::var_os("MIMALLOC_PURGE_DELAY").is_none() {
        // SAFETY: sets one of mimalloc's integer options, which it reads at its next purge.
        unsafe { libmimalloc_sys::mi_option_set(MI_OPTION_PURGE_DELAY, 1000) };
    }
}

// Link every built-in plugin so the registries see them.
use matup_shading as _;
use matup_upsamplers as _;

#[derive(Parser)]
#[command(
    name = "matup",
    version,
    about = "Upsample physically based materials (SVBRDF maps)"
)]
struct Cli {
    /// A folder of ONNX models (with sidecars), searched first for onnx:NAME.
    #[arg(long, global = true, value_name = "DIR")]
    models_dir: Option<std::path::PathBuf>,
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// List every registered upsampler and shading model with its options.
    List,
    /// Upsample a material ×4 (or ×2, ×3, ×16): every map of its folder.
    Upscale(Box<upscale::UpscaleArgs>),
    /// Upsample every material of a library (folders of maps), resumable and shardable.
    Batch(Box<batch::BatchArgs>),
    /// Write a relightable before/after page (view.html) for an upscaled material.
    View(view::ViewArgs),
    /// Render a material under one light or a contact sheet of the training lights.
    Render(Box<render::RenderArgs>),
    /// Compare a material with a reference: renders under held-out lights, maps, seams.
    Eval(eval::EvalArgs),
    /// Make the LR material a lower-resolution capture would give (box filter).
    Downsample(Box<downsample::DownsampleArgs>),
    /// Downsample true materials, upscale them with baselines and matup, evaluate, plot.
    Bench(Box<experiment::BenchArgs>),
    /// Run an experiment file: matup over a grid of settings, resumable.
    Sweep(experiment::SweepArgs),
    /// Train a super-resolution network for material maps in render space, resumable.
    #[cfg(feature = "onnx")]
    Learn(Box<learn::LearnArgs>),
}

/// matup's own loops run on the global rayon pool, one thread per core. candle splits every
/// matrix product across `RAYON_NUM_THREADS` threads, which for 128×128 products costs more
/// than it gains (measured: 2.0 ms per training step with 2 threads, 1.0 ms with one; the
/// filter's layers now split their rows themselves, `filter/dense.rs`), so once the pool
/// exists candle is told to use one thread.
fn configure_threads() {
    let threads = std::env::var("RAYON_NUM_THREADS")
        .ok()
        .and_then(|v| v.parse().ok())
        .filter(|&n: &usize| n > 0)
        .unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get()));
    // Only fails if a pool exists already, which is then used as it is.
    let _ = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build_global();
    // SAFETY: called at the start of main, before any other thread of ours exists.
    unsafe { std::env::set_var("RAYON_NUM_THREADS", "1") };
}

/// Runs the `matup` command line on this process's arguments with every plugin linked into
/// the binary.
pub fn main() -> ExitCode {
    configure_threads();
    keep_freed_memory_a_while();
    let cli = Cli::parse();
    if let Some(dir) = &cli.models_dir {
        let mut dirs = vec![dir.clone()];
        dirs.extend(
            std::env::var_os("MATUP_MODELS")
                .map(|v| std::env::split_paths(&v).collect::<Vec<_>>())
                .unwrap_or_default(),
        );
        // SAFETY: no thread of ours reads the environment concurrently (the pool is idle).
        unsafe {
            std::env::set_var(
                "MATUP_MODELS",
                std::env::join_paths(dirs).expect("folder names without separators"),
            )
        };
    }
    let result = match cli.command {
        Command::List => list::run(),
        Command::Upscale(args) => upscale::run(&args),
        Command::Batch(args) => batch::run(&args),
        Command::View(args) => view::run(&args),
        Command::Render(args) => render::run(&args),
        Command::Eval(args) => eval::run(&args),
        Command::Downsample(args) => downsample::run(&args),
        Command::Bench(args) => experiment::bench(&args),
        Command::Sweep(args) => experiment::sweep(&args),
        #[cfg(feature = "onnx")]
        Command::Learn(args) => learn::run(&args),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}
