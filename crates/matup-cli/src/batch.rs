//! `matup batch`: every material of a library, resumable and shardable across a cluster.

use std::path::PathBuf;
use std::time::Duration;

use anyhow::bail;
use clap::Args;
use matup_apps::batch::{material_name, run_batch, BatchOptions, ClaimTiming, Shard};
use matup_core::SaveOptions;

use crate::material_args::LoadArgs;
use crate::progress_bars::BatchBars;
use crate::upscale::SettingsArgs;

#[derive(Args, Debug)]
pub struct BatchArgs {
    /// Library folder: every folder under it that holds a material's maps is upscaled.
    pub library: PathBuf,
    /// Output folder: each material goes to its mirrored path here, with batch.csv,
    /// batch.json and index.html beside them.
    #[arg(short, long)]
    pub output: PathBuf,
    #[command(flatten)]
    pub settings: SettingsArgs,
    #[command(flatten)]
    pub load: LoadArgs,
    /// Take shard I of N (I from 0), e.g. 0/3. Without it, a Slurm array task or a Kubernetes
    /// Indexed Job (with --shards) takes its shard from the environment.
    #[arg(long, value_name = "I/N")]
    pub shard: Option<Shard>,
    /// Number of shards, for JOB_COMPLETION_INDEX (Kubernetes does not export the count); it
    /// also overrides SLURM_ARRAY_TASK_COUNT.
    #[arg(long, value_name = "N")]
    pub shards: Option<usize>,
    /// A material claimed by a worker that has not heartbeated for this many seconds is taken
    /// over (a claim of a finished process on this machine at once).
    #[arg(long, default_value_t = 600, value_name = "SECONDS")]
    pub claim_timeout: u64,
    /// Also write each material's view.html (a relightable before/after page), linked from
    /// index.html.
    #[arg(long)]
    pub view: bool,
    /// No progress bars or summary.
    #[arg(long)]
    pub quiet: bool,
    /// Print what this worker did as JSON to stdout.
    #[arg(long)]
    pub json: bool,
}

pub fn run(args: &BatchArgs) -> anyhow::Result<()> {
    let shard = match args.shard {
        Some(s) => Some(s),
        None => Shard::from_scheduler(|k| std::env::var(k).ok(), args.shards)?,
    };
    if args.shards.is_some() && shard.is_none() {
        bail!("--shards needs a shard index: --shard I/N, SLURM_ARRAY_TASK_ID or JOB_COMPLETION_INDEX");
    }
    anyhow::ensure!(
        args.claim_timeout > 0,
        "--claim-timeout must be at least 1 second"
    );
    let config = args.settings.config()?;
    // On a GPU one material's files are written while the next is upscaled.
    let in_flight = if matup_core::device::cuda_ordinal(&config.device)?.is_some() {
        2
    } else {
        1
    };
    let options = BatchOptions {
        config,
        save: SaveOptions {
            format: args.settings.format,
            normal_convention: None,
            names: args.settings.names,
            block_quality: args.settings.block_quality,
        },
        load: args.load.options(Default::default()),
        shard,
        claims: ClaimTiming::with_timeout(Duration::from_secs(args.claim_timeout)),
        view: args.view,
        memory_limit: Some(args.settings.memory_limit()),
        in_flight,
    };
    let bars = BatchBars::new(args.quiet || args.json);
    if let Some(s) = shard {
        bars.note_now(&format!("shard {s}"));
    }
    let report = run_batch(&args.library, &args.output, &options, &bars)?;
    bars.finish();

    if args.json {
        let handled: Vec<serde_json::Value> = report
            .handled
            .iter()
            .map(|h| {
                serde_json::json!({
                    "material": h.material,
                    "outcome": h.outcome.label(),
                    "detail": h.outcome.detail(),
                    "seconds": h.seconds,
                })
            })
            .collect();
        let json = serde_json::json!({
            "shard": shard.map(|s| s.to_string()),
            "handled": handled,
            "skipped_folders": report.library.skipped.iter()
                .map(|(f, why)| serde_json::json!({"folder": material_name(f), "reason": why}))
                .collect::<Vec<_>>(),
        });
        println!("{}", serde_json::to_string_pretty(&json)?);
    } else if !args.quiet {
        let count = |label: &str| {
            report
                .handled
                .iter()
                .filter(|h| h.outcome.label() == label)
                .count()
        };
        println!(
            "{} material(s) in this worker's share of {}: {} upscaled, {} already done, {} failed, {} held by other workers",
            report.handled.len(),
            report.library.materials.len(),
            count("upscaled"),
            count("already-done"),
            report.failures(),
            count("held-elsewhere") + count("lost-claim"),
        );
        for (folder, why) in &report.library.skipped {
            println!("  no material in {}: {why}", material_name(folder));
        }
        for h in &report.handled {
            if let Some(detail) = h.outcome.detail() {
                println!("  {}: {} ({detail})", h.material, h.outcome.label());
            }
        }
        for file in ["batch.csv", "batch.json", "index.html"] {
            println!("wrote {}", args.output.join(file).display());
        }
    }
    if report.interrupted {
        bail!("interrupted; run the same command again to finish the library");
    }
    let failed = report.failures();
    if failed > 0 {
        bail!(
            "{failed} material(s) failed; their errors are in {}",
            args.output.join("batch.csv").display()
        );
    }
    Ok(())
}
