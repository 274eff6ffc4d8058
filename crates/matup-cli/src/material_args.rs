//! The arguments every command that reads a material shares.

use std::path::PathBuf;

use anyhow::Context;
use clap::Args;
use matup_core::io::DEFAULT_MAX_TEXELS;
use matup_core::layout::Packing;
use matup_core::{load_material, LoadOptions, Material, MaterialPaths, NormalConvention};

#[derive(Args, Debug, Clone)]
pub struct MaterialArgs {
    /// Folder holding the material's maps (recognised by name: baseColor/albedo/…_Color,
    /// normal/…_NormalGL/…_nor_dx_…, roughness, metallic, height, packed …_arm_…; any may be
    /// missing). Its other maps (occlusion, opacity, emission, …) come back upscaled too.
    /// `matup upscale` also takes a glTF model (`.gltf`, `.glb`), upscaled whole.
    pub material: PathBuf,
    #[command(flatten)]
    pub load: LoadArgs,
    /// Base colour file (overrides what is found in the folder).
    #[arg(long, value_name = "FILE")]
    pub base_color: Option<PathBuf>,
    /// Normal map file.
    #[arg(long, value_name = "FILE")]
    pub normal: Option<PathBuf>,
    /// Roughness file.
    #[arg(long, value_name = "FILE")]
    pub roughness: Option<PathBuf>,
    /// Glossiness file (roughness = 1 − gloss).
    #[arg(long, value_name = "FILE")]
    pub gloss: Option<PathBuf>,
    /// Metallic file.
    #[arg(long, value_name = "FILE")]
    pub metallic: Option<PathBuf>,
    /// Height (displacement) file.
    #[arg(long, value_name = "FILE")]
    pub height: Option<PathBuf>,
    /// A packed file: its channels as --packing says, else as its name says (glTF
    /// metallicRoughness, Unreal OcclusionRoughnessMetallic, Unity MaskMap, ORM, RMA, …), else
    /// occlusion (R) / roughness (G) / metallic (B).
    #[arg(long, value_name = "FILE")]
    pub packed: Option<PathBuf>,
    /// What the --packed file's channels hold: gltf, unreal, hdrp-mask,
    /// unity-metallic-smoothness, megascans-unreal, or one to four of the channels' letters in
    /// order, each once (o or a occlusion, r roughness, m metallic, h height, x nothing: orm,
    /// rma, xrm, orh), no more than the file has channels.
    #[arg(long, value_name = "PACKING", requires = "packed")]
    pub packing: Option<Packing>,
}

/// How maps are read, for one material or a library.
#[derive(Args, Debug, Clone)]
pub struct LoadArgs {
    /// Convention of normal maps whose name does not say GL or DX (by default the exporter's,
    /// where the names mark one, else measured from the maps).
    #[arg(long, value_name = "directx|opengl")]
    pub normal_convention: Option<NormalConvention>,
    /// Refuse images with more texels than this (checked before decoding).
    #[arg(long, default_value_t = DEFAULT_MAX_TEXELS)]
    pub max_texels: u64,
}

impl LoadArgs {
    pub fn options(&self, paths: MaterialPaths) -> LoadOptions {
        LoadOptions {
            paths,
            normal_convention: self.normal_convention,
            max_texels: self.max_texels,
        }
    }
}

impl MaterialArgs {
    pub fn load(&self) -> anyhow::Result<Material> {
        let options = self.load.options(MaterialPaths {
            base_color: self.base_color.clone(),
            normal: self.normal.clone(),
            roughness: self.roughness.clone(),
            gloss: self.gloss.clone(),
            metallic: self.metallic.clone(),
            height: self.height.clone(),
            packed: self.packed.clone(),
            packing: self.packing.clone(),
            ..Default::default()
        });
        load_material(Some(&self.material), &options)
            .with_context(|| format!("cannot load the material in {}", self.material.display()))
    }
}
