//! `matup bench` and `matup sweep`: experiments over true materials, with a results table,
//! `results.csv`, `results.json` and `time_vs_error.png` in the output folder.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use anyhow::Context;
use clap::Args;
use matup_apps::experiment::{run_experiment, Experiment, Row};

use crate::plot::plot_time_vs_error;
use crate::progress_bars::Bars;

#[derive(Args, Debug)]
pub struct BenchArgs {
    /// Folders of true (HR) materials.
    #[arg(required = true)]
    pub materials: Vec<PathBuf>,
    /// Output folder for results.csv, results.json and time_vs_error.png.
    #[arg(short, long, default_value = "bench-results")]
    pub output: PathBuf,
    /// HR → LR factor, and the upscale factor.
    #[arg(long, default_value_t = 4)]
    pub factor: usize,
    /// Use only the top-left N×N texels of each material.
    #[arg(long)]
    pub crop: Option<usize>,
    /// Per-map baselines, comma-separated (default: bilinear, bicubic, lanczos3 and the
    /// shipped SR network when it loads).
    #[arg(long, value_delimiter = ',')]
    pub baselines: Option<Vec<String>>,
    /// RGB upsamplers of matup's renders, one matup run each (default: lanczos3 and the
    /// shipped SR network when it loads).
    #[arg(long, value_delimiter = ',')]
    pub upsamplers: Option<Vec<String>>,
    /// matup settings (a TOML file, keys as in `matup upscale --config`).
    #[arg(long, value_name = "FILE")]
    pub config: Option<PathBuf>,
    /// Training epochs of every matup run (overrides the config).
    #[arg(long)]
    pub epochs: Option<usize>,
    /// Where every matup run computes: cpu, cuda or cuda:N (overrides the config; the per-map
    /// baselines run on the CPU).
    #[arg(long)]
    pub device: Option<String>,
    /// Also train matup on exact renders of the truth: the method's ceiling.
    #[arg(long)]
    pub oracle: bool,
    /// Held-out lights of the evaluation.
    #[arg(long, default_value_t = 16)]
    pub eval_lights: usize,
    /// Degrade each LR input first, against its clean truth: bc1, bc3, bc4, bc5, dds (as games
    /// ship them), jpegQ, jpegQ-444, noiseS, poissonP, blurS, haloA, ditherN, ditherN-fs, each
    /// saved again as PNG with '-png' after (bc1-png), half (resized to half after storing,
    /// the input cut twice as large first: jpeg75+half), several joined by '+', each on one
    /// map alone after '@' (jpeg75@baseColor); comma-separated for several runs of each
    /// material ("clean" for none).
    #[arg(long, value_delimiter = ',')]
    pub degrade: Vec<String>,
    /// Keep every method's maps (outputs/MATERIAL/METHOD/, the truth beside them) and write
    /// outputs/MATERIAL/view.html, a relightable page where a menu picks the method.
    #[arg(long)]
    pub view: bool,
    #[arg(long)]
    pub quiet: bool,
}

#[derive(Args, Debug)]
pub struct SweepArgs {
    /// The experiment file (see sweeps/*.toml).
    pub experiment: PathBuf,
    /// Output folder (default: results/NAME, NAME the file's stem).
    #[arg(short, long)]
    pub output: Option<PathBuf>,
    /// Where every matup run computes: cpu, cuda or cuda:N (overrides the file's `device`;
    /// the per-map baselines run on the CPU).
    #[arg(long)]
    pub device: Option<String>,
    #[arg(long)]
    pub quiet: bool,
}

/// The shipped SR network's spec, when this build has it and it loads.
fn shipped_network() -> Option<String> {
    let spec = matup_method::plan::AUTO_UPSAMPLERS[0];
    spec.parse()
        .ok()
        .and_then(|s| matup_core::upsampler(&s).ok())
        .map(|_| spec.to_string())
}

pub fn bench(args: &BenchArgs) -> anyhow::Result<()> {
    let network = shipped_network();
    let with_network = |mut v: Vec<String>| {
        v.extend(network.clone());
        v
    };
    let mut base = match &args.config {
        Some(path) => {
            let text = std::fs::read_to_string(path)
                .with_context(|| format!("cannot read {}", path.display()))?;
            // Checked as a whole configuration first: unknown keys name the line.
            matup_method::Config::from_toml(&text, &path.display().to_string())?;
            toml::from_str::<toml::Table>(&text)?
        }
        None => toml::Table::new(),
    };
    if let Some(e) = args.epochs {
        let train = base
            .entry("train")
            .or_insert_with(|| toml::Value::Table(toml::Table::new()));
        if let Some(t) = train.as_table_mut() {
            t.insert("epochs".into(), toml::Value::Integer(e as i64));
        }
    }
    if let Some(device) = &args.device {
        base.insert("device".into(), toml::Value::String(device.clone()));
    }
    let upsamplers = args
        .upsamplers
        .clone()
        .unwrap_or_else(|| with_network(vec!["lanczos3".into()]));
    let experiment = Experiment {
        materials: args.materials.clone(),
        factor: args.factor,
        crop: args.crop,
        crop_at: 0,
        eval_lights: args.eval_lights,
        eval_shading: "ggx".into(),
        baselines: args.baselines.clone().unwrap_or_else(|| {
            with_network(vec!["bilinear".into(), "bicubic".into(), "lanczos3".into()])
        }),
        oracle: args.oracle,
        base,
        axes: BTreeMap::from([(
            "upsampler".to_string(),
            upsamplers.into_iter().map(toml::Value::String).collect(),
        )]),
        mode: Default::default(),
        degrade: args.degrade.clone(),
        view: args.view,
    };
    execute(&experiment, &args.output, args.quiet)
}

pub fn sweep(args: &SweepArgs) -> anyhow::Result<()> {
    let mut experiment = Experiment::from_file(&args.experiment)?;
    if let Some(device) = &args.device {
        (experiment.base).insert("device".into(), toml::Value::String(device.clone()));
    }
    let output = args.output.clone().unwrap_or_else(|| {
        Path::new("results").join(args.experiment.file_stem().unwrap_or_default())
    });
    execute(&experiment, &output, args.quiet)
}

fn execute(experiment: &Experiment, output: &Path, quiet: bool) -> anyhow::Result<()> {
    let runs = experiment.runs()?;
    for m in &experiment.materials {
        // Only folders that exist can be the same (a missing material fails its own runs).
        let same = matches!((output.canonicalize(), m.canonicalize()), (Ok(a), Ok(b)) if a == b);
        anyhow::ensure!(
            !same,
            "{}: the output folder is a material folder; matup never writes into its input",
            output.display()
        );
    }
    let bars = Bars::new(quiet);
    if !quiet {
        eprintln!("{} runs; results in {}", runs.len(), output.display());
    }
    let rows = run_experiment(experiment, &runs, output, &bars);
    bars.finish();
    let rows = match rows {
        Err(matup_core::Error::Cancelled { .. }) => anyhow::bail!(
            "interrupted; run the same command again to continue (finished runs are skipped, \
             the interrupted one resumes from its last epoch)"
        ),
        other => other?,
    };
    plot_time_vs_error(&rows, &output.join("time_vs_error.png"))?;
    print_table(&rows);
    let failures: Vec<&Row> = rows.iter().filter(|r| r.error.is_some()).collect();
    if !failures.is_empty() {
        eprintln!("\n{} run(s) failed:", failures.len());
        for r in &failures {
            eprintln!("  {}: {}", r.id, r.error.as_deref().unwrap_or(""));
        }
    }
    eprintln!(
        "\nwrote {}, {} and {}",
        output.join("results.csv").display(),
        output.join("results.json").display(),
        output.join("time_vs_error.png").display()
    );
    if experiment.view {
        eprintln!(
            "wrote every method's maps and a view.html per material in {}",
            output.join("outputs").display()
        );
    }
    Ok(())
}

/// A Markdown table of the finished runs.
fn print_table(rows: &[Row]) {
    println!("| run | seconds | PSNR dB | SSIM | FLIP | sharpness / truth's | base colour RMSE | normal ° | roughness RMSE | metallic RMSE | seam |");
    println!("|---|---|---|---|---|---|---|---|---|---|---|");
    for r in rows.iter().filter(|r| r.error.is_none()) {
        println!(
            "| {} | {:.1} | {:.2} | {:.4} | {:.4} | {:.3} | {:.4} | {:.2} | {:.4} | {:.4} | {:.2} |",
            r.id,
            r.seconds,
            r.metric("render_psnr"),
            r.metric("render_ssim"),
            r.metric("render_flip"),
            r.metric("render_sharpness") / r.metric("reference_render_sharpness"),
            r.metric("base_color_rmse"),
            r.metric("normal_error_degrees"),
            r.metric("roughness_rmse"),
            r.metric("metallic_rmse"),
            r.metric("seam_ratio"),
        );
    }
}
