//! `matup eval`: how close a material is to a reference, in renders and in maps.

use clap::Args;
use matup_core::{load_material, shading_model, LightSetSpec, LoadOptions, PluginSpec};
use matup_eval::metrics::{evaluate, Evaluation};

#[derive(Args, Debug)]
pub struct EvalArgs {
    /// The reference (true) material's folder.
    #[arg(long)]
    pub reference: std::path::PathBuf,
    /// The material to judge, of the same size.
    #[arg(long)]
    pub candidate: std::path::PathBuf,
    /// Held-out lights (a Hammersley hemisphere set, unlike the training set).
    #[arg(long, default_value_t = 16)]
    pub lights: usize,
    /// Shading model of the renders.
    #[arg(long, default_value = "ggx")]
    pub shading: PluginSpec,
    /// Print the numbers as JSON on stdout instead of a table.
    #[arg(long)]
    pub json: bool,
}

pub fn run(args: &EvalArgs) -> anyhow::Result<()> {
    anyhow::ensure!(args.lights > 0, "--lights must be at least 1");
    let reference = load_material(Some(&args.reference), &LoadOptions::default())?;
    let candidate = load_material(Some(&args.candidate), &LoadOptions::default())?;
    let model = shading_model(&args.shading)?;
    let e = evaluate(
        &reference,
        &candidate,
        model.as_ref(),
        &LightSetSpec::held_out(args.lights),
    )?;
    if args.json {
        println!("{}", serde_json::to_string_pretty(&e)?);
    } else {
        print_table(&e);
    }
    Ok(())
}

fn print_table(e: &Evaluation) {
    let rows = [
        ("render PSNR (dB)", format!("{:.2}", e.render_psnr)),
        ("render SSIM", format!("{:.4}", e.render_ssim)),
        ("render FLIP", format!("{:.4}", e.render_flip)),
        (
            "render sharpness (reference)",
            format!(
                "{:.4} ({:.4})",
                e.render_sharpness, e.reference_render_sharpness
            ),
        ),
        (
            "base colour RMSE (linear)",
            format!("{:.4}", e.base_color_rmse),
        ),
        (
            "normal error (degrees)",
            format!("{:.2}", e.normal_error_degrees),
        ),
        ("roughness RMSE", format!("{:.4}", e.roughness_rmse)),
        ("metallic RMSE", format!("{:.4}", e.metallic_rmse)),
        (
            "seam ratio (reference)",
            format!("{:.2} ({:.2})", e.seam_ratio, e.reference_seam_ratio),
        ),
    ];
    println!("{} held-out lights", e.lights);
    for (name, value) in rows {
        println!("{name:<28} {value:>12}");
    }
}
