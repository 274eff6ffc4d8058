//! `matup eval`: how close a material is to a reference, in renders and in maps; without a
//! reference, whether each of its maps tiles.

use std::collections::BTreeMap;

use clap::Args;
use matup_core::{load_material, shading_model, LightSetSpec, LoadOptions, PluginSpec};
use matup_eval::metrics::{evaluate, map_seams, Evaluation};

#[derive(Args, Debug)]
pub struct EvalArgs {
    /// The reference (true) material's folder. Without one, only the candidate's seams are
    /// reported.
    #[arg(long)]
    pub reference: Option<std::path::PathBuf>,
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
    let candidate = load_material(Some(&args.candidate), &LoadOptions::default())?;
    let Some(reference_folder) = &args.reference else {
        let seams = map_seams(&candidate);
        if args.json {
            let report = serde_json::json!({ "map_seams": seams });
            println!("{}", serde_json::to_string_pretty(&report)?);
        } else {
            print_seams(&seams, None);
        }
        return Ok(());
    };
    let reference = load_material(Some(reference_folder), &LoadOptions::default())?;
    // Renders need every map: say which ones stood in.
    for (folder, material) in [
        (reference_folder, &reference),
        (&args.candidate, &candidate),
    ] {
        for kind in material.stand_ins() {
            eprintln!(
                "{}: no {kind} map; {} stands in for it in the renders",
                folder.display(),
                kind.stand_in_words()
            );
        }
    }
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
    print_seams(&e.map_seams, Some(&e.reference_map_seams));
}

/// Each map's wrap-around seam ratio (and the reference's): about 1 where copies join
/// without a seam.
fn print_seams(seams: &BTreeMap<String, f64>, reference: Option<&BTreeMap<String, f64>>) {
    println!("wrap-around seam ratio per map (about 1: tiles without a seam)");
    for (map, ratio) in seams {
        let value = match reference.and_then(|r| r.get(map)) {
            Some(r) => format!("{ratio:.2} ({r:.2})"),
            None => format!("{ratio:.2}"),
        };
        println!("  {map:<26} {value:>12}");
    }
}
