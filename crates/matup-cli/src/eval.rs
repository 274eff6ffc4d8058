//! `matup eval`: how close a material is to a reference, in renders and in maps; without a
//! reference, whether each of its maps tiles.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use clap::Args;
use matup_core::resample::{Border, SeamSteps};
use matup_core::tileable::decide_tileable;
use matup_core::{load_material, shading_model, LightSetSpec, LoadOptions, Material, PluginSpec};
use matup_eval::metrics::{
    evaluate, false_colour, map_block_edges, map_seam_steps, new_structure, seam_ratios,
    worst_invented_structure, worst_new_structure, Evaluation, FalseColour, NewStructure,
    NEW_STRUCTURE_DEGREES, NEW_STRUCTURE_LEVELS,
};

#[derive(Args, Debug)]
pub struct EvalArgs {
    /// The reference (true) material's folder. Without one, only the candidate's seams (and
    /// false colour, given the input) are reported.
    #[arg(long)]
    pub reference: Option<std::path::PathBuf>,
    /// The material to judge, of the same size.
    #[arg(long)]
    pub candidate: std::path::PathBuf,
    /// The material the candidate was upscaled from, for its false colour (hues the input
    /// has nowhere near). Default: the input folder `run.json` in the candidate's folder
    /// names, if there is one.
    #[arg(long)]
    pub input: Option<std::path::PathBuf>,
    /// The scale the candidate was upscaled by: seams and block edges are measured on its
    /// input's texel grid. Default: the candidate's width over the input's, else 1.
    #[arg(long)]
    pub scale: Option<usize>,
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
    let run = run_json(&args.candidate);
    let run_input = run
        .as_ref()
        .and_then(|r| r["input_folder"].as_str().map(PathBuf::from));
    let input = match args.input.clone().or(run_input.filter(|f| f.is_dir())) {
        Some(folder) => Some(load_material(Some(&folder), &LoadOptions::default())?),
        None => None,
    };
    let scale = match (args.scale, &input) {
        (Some(s), _) => s.max(1),
        (None, Some(lr)) if candidate.width() % lr.width() == 0 => candidate.width() / lr.width(),
        _ => 1,
    };
    // Neighbours wrap around where the output was made wrapped: as its run.json says, else
    // as the defaults decide.
    let made_tileable = run.as_ref().and_then(|r| r["tileable"].as_bool());
    let border =
        |lr: &Material| Border::for_tiling(made_tileable.unwrap_or_else(|| decide_tileable(lr).0));
    let Some(reference_folder) = &args.reference else {
        let seam_steps = map_seam_steps(&candidate, scale);
        let seams = seam_ratios(&seam_steps);
        let block_edges = map_block_edges(&candidate, scale);
        let false_colour = (input.as_ref())
            .map(|lr| false_colour(&lr.base_color, &candidate.base_color, None, border(lr)))
            .transpose()?;
        let new = (input.as_ref())
            .map(|lr| new_structure(lr, &candidate, None, border(lr)))
            .transpose()?;
        if args.json {
            let report = serde_json::json!({
                "scale": scale,
                "map_seams": seams,
                "map_seam_steps": seam_steps,
                "map_block_edges": block_edges,
                "false_colour": false_colour,
                "new_structure": new,
                "new_structure_worst": new.as_ref().map(worst_new_structure),
                "invented_structure_worst": new.as_ref().map(worst_invented_structure),
            });
            println!("{}", serde_json::to_string_pretty(&report)?);
        } else {
            print_seams(&seam_steps, None, scale);
            print_block_edges(&block_edges, None, scale);
            print_false_colour(false_colour.as_ref(), "against the input alone");
            print_new_structure(new.as_ref());
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
    let mut e = evaluate(
        &reference,
        &candidate,
        scale,
        model.as_ref(),
        &LightSetSpec::held_out(args.lights),
    )?;
    e.false_colour = (input.as_ref())
        .map(|lr| {
            let truth = Some(&reference.base_color);
            false_colour(&lr.base_color, &candidate.base_color, truth, border(lr))
        })
        .transpose()?;
    if let Some(lr) = &input {
        e.new_structure = new_structure(lr, &candidate, Some(&reference), border(lr))?;
        e.new_structure_worst = Some(worst_new_structure(&e.new_structure));
        e.invented_structure_worst = Some(worst_invented_structure(&e.new_structure));
    }
    if args.json {
        println!("{}", serde_json::to_string_pretty(&e)?);
    } else {
        print_table(&e);
    }
    Ok(())
}

/// The `run.json` in a matup output's folder, if it has one.
fn run_json(candidate: &Path) -> Option<serde_json::Value> {
    let text = std::fs::read_to_string(candidate.join("run.json")).ok()?;
    serde_json::from_str(&text).ok()
}

fn print_false_colour(f: Option<&FalseColour>, how: &str) {
    match f {
        Some(f) => println!(
            "{:<28} {:>12}",
            format!("false colour ({how})"),
            format!(
                "{} texels ({:.3}%)",
                f.false_colour_texels,
                100.0 * f.false_colour_rate
            )
        ),
        None => println!("false colour: needs the input (--input, or a run.json that names it)"),
    }
}

/// Each map's new structure and box-back error, against the input.
fn print_new_structure(maps: Option<&BTreeMap<String, NewStructure>>) {
    let Some(maps) = maps else {
        println!("new structure: needs the input (--input, or a run.json that names it)");
        return;
    };
    println!(
        "new structure per map: texels more than {NEW_STRUCTURE_LEVELS} levels outside every \
         input texel around them (luminance / any channel; normals: turned more than \
         {NEW_STRUCTURE_DEGREES}° from every input normal around them), and the blocks \
         box-filtered back against their input texel (levels, mean / worst); and invented \
         structure: texels drawn where the input is flat within its noise, which a smooth \
         upsampling (and the reference, where given) lacks"
    );
    for (map, n) in maps {
        let angle = n
            .normal_angle
            .map_or(String::new(), |a| format!(", angle {:.3}%", 100.0 * a));
        println!(
            "  {map:<12} {:.3}% / {:.3}%{angle}; box-back {:.2} / {:.2}; invented {:.3}% \
             (input flat {:.0}%, noise {:.1} levels)",
            100.0 * n.luminance,
            100.0 * n.channel,
            n.box_back_mean,
            n.box_back_worst,
            100.0 * n.invented.share,
            100.0 * n.invented.flat_share,
            n.invented.noise_levels
        );
    }
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
    print_seams(
        &e.map_seam_steps,
        Some(&e.reference_map_seam_steps),
        e.scale,
    );
    print_block_edges(
        &e.map_block_edges,
        Some(&e.reference_map_block_edges),
        e.scale,
    );
    print_false_colour(
        e.false_colour.as_ref(),
        "hues neither input nor reference has",
    );
    print_new_structure((e.false_colour.is_some()).then_some(&e.new_structure));
}

/// Each map's wrap-around seam ratio (and the reference's), about 1 where copies join without
/// a seam, and its two parts: a ratio above the reference's comes from a larger wrap-around
/// step or from a smoother interior.
fn print_seams(
    steps: &BTreeMap<String, SeamSteps>,
    reference: Option<&BTreeMap<String, SeamSteps>>,
    scale: usize,
) {
    let phase = if scale > 1 {
        format!(", against interior steps every {scale} texels")
    } else {
        String::new()
    };
    println!(
        "wrap-around seam ratio per map (about 1: tiles without a seam{phase}) = the wrap-around \
         step / the mean interior step"
    );
    for (map, s) in steps {
        let (ratio, parts) = match reference.and_then(|r| r.get(map)) {
            Some(r) => (
                format!("{:.2} ({:.2})", s.ratio(), r.ratio()),
                format!(
                    "{:.4} / {:.4} ({:.4} / {:.4})",
                    s.wrap, s.interior, r.wrap, r.interior
                ),
            ),
            None => (
                format!("{:.2}", s.ratio()),
                format!("{:.4} / {:.4}", s.wrap, s.interior),
            ),
        };
        println!("  {map:<26} {ratio:>12} = {parts}");
    }
}

/// Each map's block-edge ratio (and the reference's), at scales above 1.
fn print_block_edges(
    edges: &BTreeMap<String, f64>,
    reference: Option<&BTreeMap<String, f64>>,
    scale: usize,
) {
    if edges.is_empty() {
        return;
    }
    println!(
        "block-edge ratio per map (steps across the input's {scale}-texel grid over steps inside it)"
    );
    print_per_map(edges, reference);
}

fn print_per_map(values: &BTreeMap<String, f64>, reference: Option<&BTreeMap<String, f64>>) {
    for (map, ratio) in values {
        let value = match reference.and_then(|r| r.get(map)) {
            Some(r) => format!("{ratio:.2} ({r:.2})"),
            None => format!("{ratio:.2}"),
        };
        println!("  {map:<26} {value:>12}");
    }
}
