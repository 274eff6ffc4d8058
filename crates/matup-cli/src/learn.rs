//! `matup learn`: train a super-resolution network for material maps in render space.

use std::path::PathBuf;

use clap::Args;
use matup_core::device::parse_device;
use matup_learn::config::Target;
use matup_learn::{train, LearnConfig};

use crate::plot::plot_learning_curves;
use crate::progress_bars::Bars;

#[derive(Args, Debug)]
pub struct LearnArgs {
    /// The run's settings (a TOML file such as configs/learn/span_x4_materials.toml).
    pub config: PathBuf,
    /// The run folder: checkpoints, train.csv, val.csv, curves.png, best.onnx and last.onnx.
    /// A folder holding a checkpoint of the same settings is resumed.
    #[arg(short, long)]
    pub output: PathBuf,
    /// Train up to this many steps instead of the configuration's.
    #[arg(long)]
    pub iterations: Option<usize>,
    /// Where candle trains: cpu, cuda or cuda:N (CUDA needs the cuda feature).
    #[arg(long, default_value = "cpu")]
    pub device: String,
    /// No progress bars.
    #[arg(short, long)]
    pub quiet: bool,
    /// Train nothing: write OUTPUT/blend-ALPHA.onnx, every weight (1 − ALPHA) · the base
    /// model's + ALPHA · OUTPUT/best.onnx's (weight-space interpolation, WiSE-FT).
    #[arg(long, value_name = "ALPHA")]
    pub blend: Option<f64>,
    /// With --blend: interpolate from this network (of the same graph) instead of the base
    /// model, e.g. models/span_x4_ch48.onnx for a run that started from another fine-tune;
    /// writes OUTPUT/blend-ALPHA-NAME.onnx.
    #[arg(long, value_name = "MODEL", requires = "blend")]
    pub blend_with: Option<PathBuf>,
    /// With --blend: add ALPHA · (OUTPUT/best.onnx − CONTROL) to the start instead, CONTROL
    /// the export of a control run (same start, seed and steps, without the term under
    /// study), keeping the term's change without the drift tuning brings alone;
    /// writes OUTPUT/blend-ALPHA[-NAME]-minus-RUN.onnx.
    #[arg(long, value_name = "CONTROL", requires = "blend")]
    pub blend_minus: Option<PathBuf>,
}

pub fn run(args: &LearnArgs) -> anyhow::Result<()> {
    let mut config = LearnConfig::load(&args.config)?;
    if let Some(n) = args.iterations {
        config.iterations = n;
    }
    if let Some(alpha) = args.blend {
        let path = matup_learn::export::blend(
            &config,
            &args.output,
            alpha,
            args.blend_with.as_deref(),
            args.blend_minus.as_deref(),
        )?;
        eprintln!("wrote {}", path.display());
        return Ok(());
    }
    let device = parse_device(&args.device)?;
    // The network's matrix products are large: candle may split them over every core
    // (`configure_threads` limits it to one thread for the filter's small products).
    // SAFETY: no thread of ours reads the environment now (the pool is idle).
    unsafe {
        std::env::set_var(
            "RAYON_NUM_THREADS",
            rayon::current_num_threads().to_string(),
        )
    };
    let bars = Bars::new(args.quiet);
    let summary = train(&config, &args.output, &device, &bars);
    bars.finish();
    // Drawn whether the run finished or stopped: the curves so far.
    if args.output.join("train.csv").is_file() {
        let validated = match config.target {
            Target::Maps => "matup upscale's defaults",
            Target::Renders => "upsampled renders",
            Target::Normals => "the truth with the network's normals",
        };
        plot_learning_curves(&args.output, validated)?;
    }
    let summary = match summary {
        Err(matup_core::Error::Cancelled { epochs_done }) => anyhow::bail!(
            "interrupted after step {epochs_done}, its checkpoint written; run the same command again to continue"
        ),
        other => other?,
    };
    eprintln!(
        "{} steps{} in {:.0} s; {}",
        summary.iterations,
        summary
            .resumed_from
            .map_or(String::new(), |i| format!(" (resumed at {i})")),
        summary.seconds,
        match summary.best {
            Some((psnr, at)) => format!(
                "best validation render PSNR {psnr:.3} dB at step {at}: {}",
                args.output.join("best.onnx").display()
            ),
            None => "no validation".into(),
        }
    );
    Ok(())
}
