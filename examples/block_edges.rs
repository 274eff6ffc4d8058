//! How strongly upscaled base colours show the input's texel grid: the block-edge ratio
//! (`matup_eval::metrics::block_edge_ratio`: steps across the input texels' edges over steps
//! inside them) of matup's defaults, the same without back-projection, and plain resamplers
//! per map, for each material box-filtered ÷SCALE from its whole and upscaled ×SCALE. The
//! last matup column settles the chroma clamp's colours block by block instead of bringing
//! them back by back-projection (`filter.clamp_back_project = false`). With
//! `--upsampler SPEC` every column but the plain resamplers' runs that upsampler (another
//! network) instead of the defaults' own.
//!
//! `cargo run --release --example block_edges -- SCALE [--upsampler SPEC] MATERIAL_FOLDER...`

use matup::config::Config;
use matup::eval::metrics::block_edge_ratio;
use matup::per_map::upscale_per_map;
use matup::plan::MATERIAL_NETWORK;
use matup::progress::Silent;
use matup::resample::Border;
use matup::{load_material, upsampler, Material, RunOptions};

fn main() -> matup::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let scale: usize = args[0].parse().expect("SCALE is a whole number");
    let (upsampler_spec, folders) = match args.get(1).map(String::as_str) {
        Some("--upsampler") => (Some(args[2].clone()), &args[3..]),
        _ => (None, &args[1..]),
    };
    let defaults = |back_project: bool, clamp_chroma: bool| {
        let mut c = Config {
            scale,
            seed: 1,
            ..Config::default()
        };
        // `auto` picks the material network only where the maps are back-projected: named,
        // every column runs the same network and differs only in the stages.
        c.upsampler = upsampler_spec.clone().unwrap_or(MATERIAL_NETWORK.into());
        c.filter.back_project = back_project;
        c.filter.clamp_chroma = clamp_chroma;
        c
    };
    let plain = ["bicubic", "lanczos3", "bilinear"];
    println!(
        "| material (÷{scale} → ×{scale}) | truth | defaults | no chroma clamp | not back-projected | neither | {} | clamp settled by blocks |",
        plain.join(" | ")
    );
    println!(
        "|---|---|---|---|---|---|{}---|",
        "---|".repeat(plain.len())
    );
    for folder in folders {
        let truth = load_material(Some(std::path::Path::new(folder)), &Default::default())?;
        let lr = truth.box_downsample(scale);
        let ratio = |m: &Material| format!("{:.2}", block_edge_ratio(&m.base_color, scale));
        let run = |c: &Config| matup::upscale(&lr, c, &RunOptions::default(), &Silent);
        let mut cells = vec![
            ratio(&truth),
            ratio(&run(&defaults(true, true))?.0),
            ratio(&run(&defaults(true, false))?.0),
            ratio(&run(&defaults(false, true))?.0),
            ratio(&run(&defaults(false, false))?.0),
        ];
        for name in plain {
            let up = upsampler(&name.parse()?)?;
            cells.push(ratio(&upscale_per_map(
                &lr,
                up.as_ref(),
                scale,
                Border::Wrap,
            )?));
        }
        let name = std::path::Path::new(folder)
            .file_name()
            .unwrap()
            .to_string_lossy();
        let mut settled_by_blocks = defaults(true, true);
        settled_by_blocks.filter.clamp_back_project = false;
        cells.push(ratio(&run(&settled_by_blocks)?.0));
        println!("| {name} | {} |", cells.join(" | "));
    }
    Ok(())
}
