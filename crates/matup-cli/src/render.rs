//! `matup render`: a preview of a material under the training lights.

use std::path::PathBuf;

use anyhow::{bail, Context};
use clap::Args;
use matup_core::io::{check_output_folder, save_png};
use matup_core::render::{render, RenderOptions};
use matup_core::{shading_model, LightSetSpec, PluginSpec};
use matup_draw::contact_sheet;

use crate::material_args::MaterialArgs;

#[derive(Args, Debug)]
pub struct RenderArgs {
    #[command(flatten)]
    pub material: MaterialArgs,
    /// Output PNG.
    #[arg(short, long)]
    pub output: PathBuf,
    /// Render under this one light of the training set (0-based).
    #[arg(long, conflicts_with = "sheet")]
    pub light: Option<usize>,
    /// Render a contact sheet of this many lights spread over the training set.
    #[arg(long, default_value_t = 16)]
    pub sheet: usize,
    /// Shading model (see `matup list`).
    #[arg(long, default_value = "ggx")]
    pub shading: PluginSpec,
    /// Number of training lights.
    #[arg(long, default_value_t = 100)]
    pub lights: usize,
    /// Distance of the lights from the origin.
    #[arg(long, default_value_t = 1.4)]
    pub light_distance: f32,
    /// Render at the map's resolution without 2×2 supersampling.
    #[arg(long)]
    pub no_supersample: bool,
}

pub fn run(args: &RenderArgs) -> anyhow::Result<()> {
    let material = args.material.load()?;
    let output_folder = match args.output.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    };
    check_output_folder(&output_folder, material.origin.as_ref())?;
    let model = shading_model(&args.shading)?;
    let lights = LightSetSpec {
        count: args.lights,
        distance: args.light_distance,
        ..Default::default()
    }
    .build();
    if lights.is_empty() {
        bail!("--lights must be at least 1");
    }
    let chosen: Vec<usize> = match args.light {
        Some(k) if k >= lights.len() => {
            bail!(
                "--light {k} is out of range: the set has lights 0 to {}",
                lights.len() - 1
            )
        }
        Some(k) => vec![k],
        None => {
            let n = args.sheet.clamp(1, lights.len());
            (0..n).map(|i| i * lights.len() / n).collect()
        }
    };
    let selected: Vec<_> = chosen.iter().map(|&k| lights[k]).collect();
    let options = RenderOptions {
        supersample: !args.no_supersample,
        ..Default::default()
    };
    let renders = render(&material, model.as_ref(), &selected, options);
    let image = if renders.len() == 1 {
        renders.into_iter().next().unwrap()
    } else {
        let columns = (renders.len() as f64).sqrt().ceil() as usize;
        contact_sheet(&renders, columns, 2)
    };
    std::fs::create_dir_all(&output_folder)
        .with_context(|| format!("cannot create {}", output_folder.display()))?;
    save_png(&args.output, &image)?;
    println!(
        "wrote {} ({}×{}, {} light{})",
        args.output.display(),
        image.width(),
        image.height(),
        chosen.len(),
        if chosen.len() == 1 { "" } else { "s" }
    );
    Ok(())
}
