//! `matup upscale`: the method end to end.

use std::path::PathBuf;

use anyhow::Context;
use clap::Args;
use matup_apps::folder::{upscale_to_folder, FolderRun};
use matup_apps::model::{is_model_file, upscale_model, ModelRun, RUNS_FOLDER};
use matup_apps::view::write_run_view;
use matup_core::io::Names;
use matup_core::{BlockQuality, FileFormat, LossNorm, SaveOptions};
use matup_method::bands::default_memory_limit;
use matup_method::config::{
    Activation, Backend, Chain, EnsembleMaps, InputQuality, Interpolation, ResidualBase, Schedule,
    Selection, TargetKind, TargetSize, UpsampledMaps,
};
use matup_method::report::RunReport;
use matup_method::train::Stop;
use matup_method::Config;

use crate::material_args::MaterialArgs;
use crate::progress_bars::Bars;

#[derive(Args, Debug)]
pub struct UpscaleArgs {
    #[command(flatten)]
    pub material: MaterialArgs,
    /// Output folder (created; never the input folder).
    #[arg(short, long)]
    pub output: PathBuf,
    #[command(flatten)]
    pub settings: SettingsArgs,
    /// Continue from the last checkpoint in the output folder.
    #[arg(long)]
    pub resume: bool,
    /// No progress bars or summary.
    #[arg(long)]
    pub quiet: bool,
    /// Print run.json to stdout.
    #[arg(long)]
    pub json: bool,
    /// Also write view.html: the result relightable in a browser, against bilinear ×N.
    #[arg(long)]
    pub view: bool,
}

/// The settings of a run, shared by `upscale` and `batch`: a TOML file, flags over it, and
/// the output format.
#[derive(Args, Debug)]
pub struct SettingsArgs {
    /// A TOML configuration; flags given here override it.
    #[arg(long, value_name = "FILE")]
    pub config: Option<PathBuf>,
    /// Upsampling factor: 2, 3, 4, 8 (×4, then ×2) or 16 (two ×4 levels). Every scale runs
    /// the ×4 network: ×2 and ×3 through ×4 and an area filter down.
    #[arg(long)]
    pub scale: Option<String>,
    /// An output size instead of a scale: 4096, 4K, or 4096x2048 for a non-square input. The
    /// smallest scale that reaches it runs; a size between scales is then area-shrunk to.
    #[arg(long, value_name = "TEXELS", conflicts_with = "scale")]
    pub size: Option<TargetSize>,
    /// How ×16 is reached: two-level (train again on the ×4 result) or single (reuse the ×4 filter).
    #[arg(long)]
    pub chain: Option<Chain>,
    /// RGB upsampler of the renders (see `matup list`); default `auto`: the shipped SR network,
    /// tuned for materials (onnx:span_x4_materials) where no filter is trained and the maps are
    /// back-projected, for JPEG maps (onnx:span_x4_jpeg) where the input is a JPEG, and for
    /// degraded maps (onnx:span_x4_degraded) where it is otherwise degraded; else stock
    /// (onnx:span_x4_ch48), where it applies, else lanczos3.
    #[arg(long)]
    pub upsampler: Option<String>,
    /// Whether the input maps are clean or degraded: auto (each map by its storage: JPEG by
    /// its file or its texels, degraded where a lossy WebP or BC1–BC5 blocks by its file or
    /// its texels, few levels (dithered or posterised) or noise under every map by its
    /// texels, clean otherwise), or every map clean, jpeg, or degraded (maps once compressed,
    /// resized and saved again losslessly). Degraded maps run the network trained on degraded
    /// inputs and are not back-projected (a noisy material's normals blended with the clean
    /// route's where they vary far past the noise); JPEG maps run the one trained on JPEG
    /// inputs, a JPEG base colour projected onto the input's low frequencies alone; clean maps
    /// beside them run as in a clean material. A settings file's [map_input_quality] decides
    /// map by map.
    #[arg(long, value_name = "auto|clean|jpeg|degraded")]
    pub input_quality: Option<InputQuality>,
    /// Shading model (see `matup list`).
    #[arg(long)]
    pub shading: Option<String>,
    /// Treat the material as tileable (wrap-around windows; tileable output).
    #[arg(long, conflicts_with = "no_tileable")]
    pub tileable: bool,
    /// Treat the material as not tileable (mirrored windows).
    #[arg(long)]
    pub no_tileable: bool,
    /// Do not skip work the material seems not to need (constant maps, dark lights).
    #[arg(long)]
    pub no_skip: bool,
    /// Seed of the initialisation and the texel order (deterministic for a thread count).
    #[arg(long)]
    pub seed: Option<u64>,
    /// Number of training lights.
    #[arg(long)]
    pub lights: Option<usize>,
    /// Distance of the lights from the origin.
    #[arg(long)]
    pub light_distance: Option<f32>,
    /// Filter window side N (odd), in output texels.
    #[arg(long)]
    pub window: Option<usize>,
    /// Width of the hidden layers.
    #[arg(long)]
    pub hidden_width: Option<usize>,
    /// Number of hidden layers.
    #[arg(long)]
    pub hidden_layers: Option<usize>,
    /// leaky-relu, leaky-relu:SLOPE, relu, gelu or silu.
    #[arg(long)]
    pub activation: Option<Activation>,
    /// Upsampler of the LR maps feeding the filter window: bilinear, bicubic, lanczos3.
    #[arg(long)]
    pub input_interpolation: Option<Interpolation>,
    /// What the residual is added to: bilinear, bicubic, lanczos3 (the LR maps interpolated),
    /// or upsampler (each LR map through the RGB upsampler on its own).
    #[arg(long)]
    pub residual_base: Option<ResidualBase>,
    /// Back-project the residual base onto the LR maps (its box-downsample made equal to
    /// them; the default).
    #[arg(long, conflicts_with = "no_back_project")]
    pub back_project: bool,
    /// Use the residual base as upsampled, without back-projection.
    #[arg(long)]
    pub no_back_project: bool,
    /// Upsample the maps under N symmetries of the square (2, 4 or 8; 8 if N is left out; 1
    /// for none) and average them (geometric self-ensemble; N times the upsampler's time on
    /// the maps it covers).
    #[arg(long, value_name = "N", num_args = 0..=1, default_missing_value = "8")]
    pub self_ensemble: Option<usize>,
    /// The maps the self-ensemble covers: all, or normal (the normal map alone).
    #[arg(long, value_name = "MAPS")]
    pub self_ensemble_maps: Option<EnsembleMaps>,
    /// The maps the upsampler runs on, the others through Lanczos-3: all, normal (the normal
    /// map alone, in about a quarter of a network's time), or auto (the default: every map, but
    /// the normal map alone at ×8's ×2 level where the upsampler is a network).
    #[arg(long, value_name = "MAPS")]
    pub upsampled_maps: Option<UpsampledMaps>,
    /// Learning rate.
    #[arg(long)]
    pub lr: Option<f64>,
    /// Texels per step.
    #[arg(long)]
    pub batch_size: Option<usize>,
    /// Scale the learning rate by batch-size / 128.
    #[arg(long)]
    pub scale_lr: bool,
    /// constant or cosine.
    #[arg(long)]
    pub schedule: Option<Schedule>,
    /// Training epochs at most (default 0: no filter is trained; the residual base is the
    /// result). Training stops earlier when a held-out loss stops improving.
    #[arg(long)]
    pub epochs: Option<usize>,
    /// How training steps run: fused (matup's own CPU code), tensor (candle operations, any
    /// device; the shading model needs a tensor form) or auto (fused on the CPU, tensor on a
    /// GPU).
    #[arg(long)]
    pub backend: Option<Backend>,
    /// Where the networks run: auto (the default: CUDA in a CUDA build, else the first
    /// hardware GPU adapter, discrete before integrated, else the CPU), cpu, gpu (the first
    /// adapter), gpu:N or gpu:NAME (an adapter `matup list` shows, by index or part of its
    /// name), cuda or cuda:N (a build with --features cuda, where training runs too).
    #[arg(long)]
    pub device: Option<String>,
    /// Stop training when the held-out loss stops improving (the default).
    #[arg(long, conflicts_with = "no_early_stop")]
    pub early_stop: bool,
    /// Train every one of --epochs (the paper's fixed schedule).
    #[arg(long)]
    pub no_early_stop: bool,
    /// l21, l11, l22 or lpq:P,Q.
    #[arg(long)]
    pub loss: Option<LossNorm>,
    /// Training targets: direct (the upsampled renders) or detail (the residual base's renders
    /// plus what the upsampler adds to each render beyond the base's own upsampler).
    #[arg(long)]
    pub targets: Option<TargetKind>,
    /// Prior weights pulling features toward the residual base, e.g.
    /// `metallic=0.1,normal=1` (keys base_color, metallic, normal, roughness).
    #[arg(long, value_name = "KEY=W,...")]
    pub prior: Option<String>,
    /// auto: choose the settings by validating candidates one scale down; upsampler: choose
    /// only the upsampler, among --upsampler and each --select-upsampler; off: as given.
    #[arg(long)]
    pub select: Option<Selection>,
    /// One more upsampler for --select to validate (repeatable), e.g. a fine-tuned network
    /// beside the stock one: `--select upsampler --select-upsampler onnx:tuned.onnx`.
    #[arg(long = "select-upsampler", value_name = "SPEC")]
    pub select_upsamplers: Vec<String>,
    /// β, weight of the LR-consistency term.
    #[arg(long)]
    pub lr_consistency: Option<f32>,
    /// γ, weight of cross-scale self-supervision.
    #[arg(long)]
    pub cross_scale: Option<f32>,
    /// Train on this many random texels per epoch.
    #[arg(long)]
    pub texels_per_epoch: Option<usize>,
    /// Output format of every map (png, png16, jpg, exr-half, exr-float, tiff, tiff16,
    /// tiff-float, tga, tga-rle, bmp, webp (lossy), webp-lossless; dds: BC7, BC5 for normals, BC4 for one channel; dds-bc1, dds-bc3,
    /// dds-bc4, dds-bc5, dds-bc7, dds-rgba8 and the other DDS formats, all with mip chains);
    /// default: the input's.
    #[arg(long)]
    pub format: Option<FileFormat>,
    /// How hard DDS block encoders (BC1–BC7) search: fast, normal, high or max (slower is
    /// closer to the upscaled map).
    #[arg(long, default_value_t = BlockQuality::Normal)]
    pub block_quality: BlockQuality,
    /// The names maps are written under: keep (the input's own, a resolution tag such as _1K
    /// rewritten to the output's size; packed and gloss files come back as such) or matup
    /// (baseColor, normal, roughness, metallic, height). Maps matup does not render with
    /// always keep theirs.
    #[arg(long, default_value_t = Names::Keep)]
    pub names: Names,
    /// Heap the output is made within, e.g. 4G or 512M (binary units; a bare number is MiB).
    /// Larger outputs are made in bands of rows and written as they finish. Default: a
    /// quarter of the machine's memory, between 1G and 16G.
    #[arg(long, value_parser = parse_memory)]
    pub memory_limit: Option<u64>,
}

/// `4G`, `512M`, `1.5G` or `2048` (MiB) as bytes.
fn parse_memory(text: &str) -> Result<u64, String> {
    let t = text.trim();
    let (number, unit) = match t.char_indices().find(|(_, c)| c.is_ascii_alphabetic()) {
        Some((i, _)) => (&t[..i], t[i..].to_ascii_lowercase()),
        None => (t, "m".to_string()),
    };
    let shift = match unit.trim_end_matches("ib").trim_end_matches('b') {
        "k" => 10,
        "m" => 20,
        "g" => 30,
        "t" => 40,
        _ => return Err(format!("unknown unit in {text:?}: use K, M, G or T")),
    };
    let value: f64 = number
        .trim()
        .parse()
        .map_err(|_| format!("{text:?} is not a size such as 4G or 512M"))?;
    if !(value > 0.0 && value.is_finite()) {
        return Err(format!("{text:?}: the limit must be positive"));
    }
    Ok((value * (1u64 << shift) as f64) as u64)
}

impl SettingsArgs {
    /// The memory limit given, or the default share of this machine.
    pub fn memory_limit(&self) -> u64 {
        self.memory_limit.unwrap_or_else(default_memory_limit)
    }
}

impl SettingsArgs {
    /// Defaults, then the TOML file, then the flags.
    pub fn config(&self) -> anyhow::Result<Config> {
        let mut c = match &self.config {
            Some(path) => {
                let text = std::fs::read_to_string(path)
                    .with_context(|| format!("cannot read {}", path.display()))?;
                Config::from_toml(&text, &path.display().to_string())?
            }
            None => Config::default(),
        };
        if let Some(s) = &self.scale {
            c.scale = s.parse().map_err(|_| {
                anyhow::anyhow!("--scale '{s}' is not a whole number; use 2, 3, 4, 8 or 16")
            })?;
        }
        if self.size.is_some() {
            c.size = self.size;
        }
        macro_rules! set {
            ($($flag:ident => $($field:ident).+),* $(,)?) => {$(
                if let Some(v) = self.$flag.clone() { c.$($field).+ = v; }
            )*};
        }
        set!(
            chain => chain, upsampler => upsampler, shading => shading, seed => seed,
            input_quality => input_quality,
            lights => lights.count, light_distance => lights.distance,
            window => filter.window, hidden_width => filter.hidden_width,
            hidden_layers => filter.hidden_layers, activation => filter.activation,
            input_interpolation => filter.input, residual_base => filter.residual_base,
            lr => train.learning_rate, batch_size => train.batch_size, schedule => train.schedule,
            epochs => train.epochs, loss => train.loss, targets => train.targets,
            backend => train.backend, device => device,
            select => select,
            lr_consistency => train.lr_consistency, cross_scale => train.cross_scale,
        );
        if !self.select_upsamplers.is_empty() {
            c.select_upsamplers = self.select_upsamplers.clone();
        }
        if let Some(p) = &self.prior {
            c.train.prior.set(p)?;
        }
        if let Some(t) = self.texels_per_epoch {
            c.train.texels_per_epoch = Some(t);
        }
        if self.scale_lr {
            c.train.scale_learning_rate = true;
        }
        if self.tileable {
            c.tileable = Some(true);
        }
        if self.no_tileable {
            c.tileable = Some(false);
        }
        if self.no_skip {
            c.skip = false;
        }
        if self.back_project {
            c.filter.back_project = true;
        }
        if self.no_back_project {
            c.filter.back_project = false;
        }
        if let Some(n) = self.self_ensemble {
            c.filter.self_ensemble = n;
        }
        if let Some(maps) = self.self_ensemble_maps {
            c.filter.self_ensemble_maps = maps;
        }
        if let Some(maps) = self.upsampled_maps {
            c.filter.upsampled_maps = maps;
        }
        if self.early_stop {
            c.train.early_stop.enabled = true;
        }
        if self.no_early_stop {
            c.train.early_stop.enabled = false;
        }
        Ok(c)
    }
}

pub fn run(args: &UpscaleArgs) -> anyhow::Result<()> {
    let config = args.settings.config()?;
    let save = SaveOptions {
        format: args.settings.format,
        normal_convention: None,
        names: args.settings.names,
        block_quality: args.settings.block_quality,
    };
    if is_model_file(&args.material.material) {
        return run_model(args, &config, &save);
    }
    let material = args.material.load()?;
    let bars = Bars::new(args.quiet || args.json);
    let FolderRun {
        report,
        mut written,
    } = upscale_to_folder(
        &material,
        &config,
        &args.output,
        &save,
        args.resume,
        Some(args.settings.memory_limit()),
        None,
        &bars,
    )?;
    bars.finish();
    let json = serde_json::to_string_pretty(&report)?;
    if args.view {
        written.push(write_run_view(&material, &args.output)?);
    }

    if args.json {
        println!("{json}");
    } else if !args.quiet {
        println!(
            "{}{}, peak memory {}",
            size_route_and_time(&report),
            report
                .final_loss
                .map_or(String::new(), |l| format!(" (final loss {l:.5})")),
            report
                .peak_memory_mib
                .map_or("-".into(), |m| format!("{m:.0} MiB")),
        );
        for (i, level) in report.levels.iter().enumerate() {
            println!("  level {}: {}", i + 1, level.route);
        }
        for (stage, seconds) in &report.timings {
            println!("  {stage:<28} {seconds:>7.2} s");
        }
        if let Some(selection) = &report.selection {
            println!(
                "  settings chosen one scale down ({}×{}): {}",
                selection.validation_size[0], selection.validation_size[1], selection.chosen
            );
            for c in &selection.candidates {
                println!(
                    "    {:<30} render PSNR {:6.2} dB, FLIP {:.4}, {:.1} s",
                    c.name, c.render_psnr, c.render_flip, c.seconds
                );
            }
        }
        for (i, level) in report.levels.iter().enumerate() {
            let t = &level.training;
            if t.stopped != Stop::NotTrained {
                println!(
                    "  level {}: trained {:.2} of {} epochs ({} backend, {}), {}",
                    i + 1,
                    t.epochs_trained,
                    config.train.epochs,
                    t.backend,
                    t.device,
                    t.stopped
                );
            }
        }
        for s in &report.skipped {
            println!("  skipped: {s}");
        }
        for path in &written {
            println!("wrote {}", path.display());
        }
    }
    Ok(())
}

/// `matup upscale model.gltf|model.glb -o OUT`: every texture of the model in its role.
fn run_model(args: &UpscaleArgs, config: &Config, save: &SaveOptions) -> anyhow::Result<()> {
    let model = &args.material.material;
    anyhow::ensure!(
        !args.view && !args.resume,
        "--view and --resume are for material folders; a model's previews are in \
         OUT/{RUNS_FOLDER}"
    );
    let bars = Bars::new(args.quiet || args.json);
    let load = args.material.load.options(Default::default());
    let ModelRun {
        written,
        runs,
        notes,
    } = upscale_model(
        model,
        config,
        &args.output,
        save,
        &load,
        Some(args.settings.memory_limit()),
        &bars,
    )
    .with_context(|| format!("cannot upscale the model {}", model.display()))?;
    bars.finish();
    if args.json {
        let reports: serde_json::Map<String, serde_json::Value> = (runs.iter())
            .map(|(label, report)| Ok((label.clone(), serde_json::to_value(report)?)))
            .collect::<anyhow::Result<_>>()?;
        println!("{}", serde_json::to_string_pretty(&reports)?);
    } else if !args.quiet {
        for (label, report) in &runs {
            println!("{label}: {}", size_route_and_time(report));
        }
        for note in &notes {
            println!("  note: {note}");
        }
        for path in &written {
            println!("wrote {}", path.display());
        }
    }
    Ok(())
}

/// "256×256 → 1024×1024 (×4) in 4.1 s": a run's sizes, route and time.
fn size_route_and_time(report: &RunReport) -> String {
    format!(
        "{}×{} → {}×{} ({}) in {:.1} s",
        report.input_size[0],
        report.input_size[1],
        report.output_size[0],
        report.output_size[1],
        report.route,
        report.total_seconds,
    )
}
