//! Where ×16's block grid comes from: the base colour's block-edge ratio on the 16-texel grid
//! (and its RMSE against the truth) for the defaults (each ×4 level back-projected and
//! chroma-clamped onto its own input), for both levels left unprojected, for those then
//! projected once onto the ×16 input, and for bicubic. Each whole material is box-filtered
//! ÷16 and upscaled ×16, wrapped (docs/experiments/2026-11-26-seamless-by-default.md).
//!
//! `cargo run --release --example x16_projection -- MATERIAL_FOLDER...`

use matup::config::Config;
use matup::eval::metrics::block_edge_ratio;
use matup::features::features;
use matup::plan::MATERIAL_NETWORK;
use matup::progress::Silent;
use matup::resample::Border;
use matup::residual::project_onto_input;
use matup::{load_material, Map, RunOptions};

fn main() -> matup::Result<()> {
    let scale = 16;
    let config = |back_project: bool| {
        let mut c = Config {
            scale,
            seed: 1,
            tileable: Some(true),
            ..Config::default()
        };
        c.filter.back_project = back_project;
        c.filter.clamp_chroma = back_project;
        // `auto` picks the material network only where the maps are back-projected: named,
        // every column runs the defaults' network and differs only in the projection.
        c.upsampler = MATERIAL_NETWORK.into();
        c
    };
    println!(
        "| material | truth | defaults | neither | neither, then projected once at ×16 | bicubic |"
    );
    println!("|---|---|---|---|---|---|");
    for folder in std::env::args().skip(1) {
        let truth = load_material(Some(std::path::Path::new(&folder)), &Default::default())?;
        let lr = truth.box_downsample(scale);
        let run = |c: &Config| matup::upscale(&lr, c, &RunOptions::default(), &Silent);
        let ratio = |m: &Map| format!("{:.2}", block_edge_ratio(m, scale));
        let defaults = run(&config(true))?.0;
        let neither = run(&config(false))?.0;
        let mut feats = features(&neither);
        project_onto_input(&mut feats, &lr, &config(true).filter, scale, Border::Wrap);
        let colour = Map::from_fn(feats.width(), feats.height(), 3, |c, y, x| {
            feats.get(c, y, x)
        });
        let bicubic = matup::resample::upsample(
            &lr.base_color,
            scale,
            matup::Kernel::Bicubic { a: -0.5 },
            Border::Wrap,
        );
        let err = |m: &Map| {
            let d: f64 = (m.data().iter().zip(truth.base_color.data()))
                .map(|(a, b)| ((a - b) as f64).powi(2))
                .sum::<f64>()
                / m.data().len() as f64;
            format!("{:.4}", d.sqrt())
        };
        let name = std::path::Path::new(&folder)
            .file_name()
            .unwrap()
            .to_string_lossy();
        println!(
            "| {} | {} | {} ({}) | {} ({}) | {} ({}) | {} ({}) |",
            name,
            ratio(&truth.base_color),
            ratio(&defaults.base_color),
            err(&defaults.base_color),
            ratio(&neither.base_color),
            err(&neither.base_color),
            ratio(&colour),
            err(&colour),
            ratio(&bicubic),
            err(&bicubic)
        );
    }
    Ok(())
}
