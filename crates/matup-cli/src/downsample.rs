//! `matup downsample`: the LR material a lower-resolution capture of a material would give.

use std::path::PathBuf;

use clap::Args;
use matup_core::io::check_output_folder;
use matup_core::{save_material, SaveOptions};

use crate::material_args::MaterialArgs;

#[derive(Args, Debug)]
pub struct DownsampleArgs {
    #[command(flatten)]
    pub material: MaterialArgs,
    /// Output folder (not the input folder).
    #[arg(short, long)]
    pub output: PathBuf,
    /// Each output texel averages `factor × factor` input texels.
    #[arg(long, default_value_t = 4)]
    pub factor: usize,
}

/// Box-filters every map: base colour in linear space, normals averaged then renormalised,
/// roughness, metallic and height averaged. Written in the input's formats.
pub fn run(args: &DownsampleArgs) -> anyhow::Result<()> {
    let material = args.material.load()?;
    let f = args.factor;
    anyhow::ensure!(f >= 1, "--factor must be at least 1");
    anyhow::ensure!(
        material.width() % f == 0 && material.height_px() % f == 0,
        "{}: {}×{} is not divisible by --factor {f}",
        args.material.material.display(),
        material.width(),
        material.height_px()
    );
    check_output_folder(&args.output, material.origin.as_ref())?;
    let written = save_material(
        &material.box_downsample(f),
        &args.output,
        &SaveOptions::default(),
    )?;
    for path in written {
        eprintln!("wrote {}", path.display());
    }
    Ok(())
}
