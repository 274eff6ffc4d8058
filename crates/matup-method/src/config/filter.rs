//! The `[filter]` settings: the per-material filter, its residual base and the per-map
//! upsampling's passes.

use serde::{Deserialize, Deserializer, Serialize};

use super::values::{Activation, Chroma, Interpolation, ResidualBase};
use crate::per_map::{EnsembleMaps, MapPasses, SelfEnsemble, UpsampledMaps};
use matup_core::material::MapKind;
use matup_core::resample::Kernel;

/// The per-material filter.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct FilterConfig {
    /// Side of the square input window, in output texels (odd).
    pub window: usize,
    pub hidden_width: usize,
    pub hidden_layers: usize,
    pub activation: Activation,
    /// The upsampler of the LR maps that builds the input window.
    pub input: Interpolation,
    /// What the residual output is added to.
    pub residual_base: ResidualBase,
    /// Back-project the residual base onto the LR maps first (its box-downsample made equal
    /// to them).
    pub back_project: bool,
    /// Upsample the maps for the residual base under this many symmetries of the square
    /// (1, 2, 4 or 8), each turned back, and average them (geometric self-ensemble): each
    /// symmetry past the first is one more pass of the upsampler over the maps
    /// `self_ensemble_maps` names. `true` reads as 8, `false` as 1. A kernel's residual base
    /// is the same under every symmetry, so there it changes nothing and costs nothing.
    #[serde(deserialize_with = "symmetry_count")]
    pub self_ensemble: usize,
    /// The maps the self-ensemble covers: "all", or "normal" (the normal map alone).
    pub self_ensemble_maps: EnsembleMaps,
    /// The maps an `upsampler` residual base runs through the upsampler, the others through
    /// Lanczos-3: "all", "normal" (the normal map alone), or "auto" (every map, but the normal
    /// map alone at ×8's ×2 level where the upsampler is a network).
    pub upsampled_maps: UpsampledMaps,
    /// Where an `upsampler` residual base's base colour takes its chroma from: "upsampler",
    /// or a kernel ("bilinear", "bicubic", "lanczos3") on the LR colour, the upsampler's
    /// luma kept.
    pub base_color_chroma: Chroma,
    /// Clamp each texel's base-colour chroma into that of its LR texel's 3×3 neighbourhood
    /// (its luma kept), after back-projection: no hue the input lacks around it.
    pub clamp_chroma: bool,
    /// With `clamp_chroma` and `back_project`: bring the clamped colours back to their input
    /// by back-projection (a smooth spread) between the later clamps, instead of settling each
    /// block alone, which moves whole blocks apart and draws the input's texel grid.
    pub clamp_back_project: bool,
    /// With `back_project`: how far (in stored [0, 1] values, sRGB for colour) each texel of
    /// the base colour, metallic and roughness may lie past the range of its LR texel's 3×3
    /// neighbourhood, channel by channel, once back-projected; 1 keeps all. Back-projection
    /// pays for a network's dark stroke with bright texels around it and pins texels at 0:
    /// structure the input has nowhere near (docs/experiments/2026-11-28-no-new-structure.md).
    pub neighbourhood_margin: f32,
    /// With `back_project`, above 0: bring the base colour back to its input's low
    /// frequencies alone (its mismatch blurred by a Gaussian of this many LR texels, kept to
    /// the input's edges), with the input's chroma and the upsampler's detail past the blur in
    /// luma alone; 0 projects it exactly. A JPEG's noise and blocks are its input's high
    /// frequencies, while its regions' colours hold.
    pub projection_blur: f32,
    /// Above 0: noise of this σ (8-bit levels of the files' values) lies under the input, and
    /// the normal map is blended from two upsamplings of it: this run's where the input's
    /// normals are flat within the noise, the clean route's (the clean route's upsampler,
    /// projected exactly) where they vary far past it (`crate::normal_blend::NormalBlend`). A network for
    /// degraded maps takes the noise away but softens bevels and grout, which carry a tiled
    /// material's shading; the clean route keeps them. The route sets it to the noise it
    /// reads under a material's maps (`crate::plan::InputRoute`).
    pub normal_blend_noise: f32,
    /// With `back_project`: the maps left as the upsampler made them, by file stem
    /// (`baseColor`, `normal`, `roughness`, `metallic`). The route of lossy maps adds them
    /// (`crate::plan::InputRoute`): projecting a JPEG's normals or a BC block's colour would
    /// put its blocks and noise back.
    pub unprojected_maps: Vec<MapKind>,
}

impl FilterConfig {
    /// Whether the residual base's map of `kind` is projected onto its input.
    pub fn projects(&self, kind: MapKind) -> bool {
        self.back_project && !self.unprojected_maps.contains(&kind)
    }

    /// Whether the base colour is projected onto its input's low frequencies alone
    /// (`projection_blur`).
    pub fn projects_low_pass(&self) -> bool {
        self.projects(MapKind::BaseColor) && self.projection_blur > 0.0
    }

    /// How the per-map path runs the upsampler, as these settings ask.
    pub fn map_passes(&self) -> MapPasses {
        MapPasses {
            ensemble: self.self_ensemble(),
            upsampled: self.upsampled_maps,
        }
    }

    /// The self-ensemble these settings ask for.
    pub fn self_ensemble(&self) -> SelfEnsemble {
        SelfEnsemble {
            symmetries: self.self_ensemble,
            maps: self.self_ensemble_maps,
        }
    }
}

/// A self-ensemble's size, written as a count or, as before counts, as a switch (`true`: all
/// eight symmetries).
fn symmetry_count<'de, D: Deserializer<'de>>(d: D) -> std::result::Result<usize, D::Error> {
    #[derive(Deserialize)]
    #[serde(untagged)]
    enum Count {
        Switch(bool),
        Symmetries(usize),
    }
    Ok(match Count::deserialize(d)? {
        Count::Switch(on) => {
            if on {
                8
            } else {
                1
            }
        }
        Count::Symmetries(n) => n,
    })
}

impl Default for FilterConfig {
    fn default() -> Self {
        FilterConfig {
            window: 17,
            hidden_width: 128,
            hidden_layers: 4,
            activation: Activation::LeakyRelu(0.01),
            input: Interpolation(Kernel::Bilinear),
            residual_base: ResidualBase::Upsampler,
            back_project: true,
            // Measured (docs/experiments/2026-11-25-self-ensemble.md): the half turn's pair
            // lifts the val sets past the bar at twice the upsampler's time; the time
            // budgets (2 s for the main job, 60 s for 1K² → 4K²) hold two passes, not four.
            self_ensemble: 2,
            self_ensemble_maps: EnsembleMaps::All,
            // Measured (docs/experiments/2026-11-27-x2-at-the-cost-of-x4.md): at ×2 the
            // normals alone keep ×2 of a 1K² material within the time of ×4 of a 512² one.
            upsampled_maps: UpsampledMaps::Auto,
            base_color_chroma: Chroma::Upsampler,
            // Measured (docs/experiments/2026-11-25-false-colour.md): no false colour left on
            // the shared and val sets, render PSNR +0.004 / +0.008 dB, FLIP lower.
            clamp_chroma: true,
            // Measured (docs/experiments/2026-11-26-seamless-by-default.md): with the shipped
            // network, ×16 block edges at or below bicubic's on all 11 shared materials; settling
            // instead leaves denim_fabric's above it and victorian_wood's just below.
            clamp_back_project: true,
            // Off (docs/experiments/2026-11-29-degraded-inputs.md): the strokes it was added
            // against come from degraded inputs, which now run the network trained on them; on
            // clean inputs it cost Tiles012 0.34 dB and a partly metallic facade 1.66 dB.
            neighbourhood_margin: NEIGHBOURHOOD_MARGIN,
            projection_blur: 0.0,
            normal_blend_noise: 0.0,
            unprojected_maps: Vec::new(),
        }
    }
}

/// The default [`FilterConfig::neighbourhood_margin`]: every value kept.
pub const NEIGHBOURHOOD_MARGIN: f32 = 1.0;
