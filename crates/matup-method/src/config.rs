//! The configuration of an upscale run: every hyper-parameter, with METHOD.md's values as
//! defaults, readable from TOML (`deny_unknown_fields`: a typo is an error, not a silent
//! default) and settable from the CLI.

use std::fmt;
use std::str::FromStr;

use serde::{Deserialize, Deserializer, Serialize, Serializer};

pub use crate::per_map::{EnsembleMaps, MapPasses, SelfEnsemble, UpsampledMaps};
use matup_core::loss::LossNorm;
use matup_core::resample::Kernel;
use matup_core::{Error, Result};

/// Settings with a parameter or aliases (`leaky-relu:0.1`, a kernel's name as a residual base)
/// parse and print by hand; serde goes through those (and their messages), so values read the
/// same in TOML as on the CLI.
macro_rules! serde_through_strings {
    ($($t:ty),*) => {$(
        impl Serialize for $t {
            fn serialize<S: Serializer>(&self, s: S) -> std::result::Result<S::Ok, S::Error> {
                as_string::serialize(self, s)
            }
        }
        impl<'de> Deserialize<'de> for $t {
            fn deserialize<D: Deserializer<'de>>(d: D) -> std::result::Result<Self, D::Error> {
                as_string::deserialize(d)
            }
        }
    )*};
}

/// Settings that are plain names take their string forms from serde (kebab-case), the same
/// in TOML, on the CLI and in messages: an unknown name is refused with the names known.
macro_rules! strings_through_serde {
    ($($t:ty: $what:literal),*) => {$(
        serde_plain::derive_display_from_serialize!($t);
        serde_plain::derive_fromstr_from_deserialize!(
            $t,
            |e| -> Error { Error::Invalid(format!("{}: {e}", $what)) }
        );
    )*};
}

/// The same as a field attribute (`#[serde(with = "as_string")]`), for matup-core's types,
/// which this crate may not implement serde's traits for.
mod as_string {
    use std::fmt::Display;
    use std::str::FromStr;

    use serde::{Deserialize, Deserializer, Serializer};

    pub fn serialize<T: Display, S: Serializer>(
        value: &T,
        s: S,
    ) -> std::result::Result<S::Ok, S::Error> {
        s.collect_str(value)
    }

    pub fn deserialize<'de, T, D>(d: D) -> std::result::Result<T, D::Error>
    where
        T: FromStr,
        T::Err: Display,
        D: Deserializer<'de>,
    {
        String::deserialize(d)?
            .parse()
            .map_err(serde::de::Error::custom)
    }
}

serde_through_strings!(Activation, Interpolation, ResidualBase, Chroma, TargetSize);
strings_through_serde!(
    Schedule: "schedule",
    Chain: "chain",
    TargetKind: "targets",
    Selection: "selection",
    Backend: "backend"
);

/// The hidden layers' nonlinearity.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Activation {
    LeakyRelu(f32),
    Relu,
    Gelu,
    Silu,
}

impl FromStr for Activation {
    type Err = Error;
    /// `leaky-relu` (slope 0.01), `leaky-relu:SLOPE`, `relu`, `gelu`, `silu`.
    fn from_str(s: &str) -> Result<Self> {
        match s {
            "leaky-relu" => Ok(Activation::LeakyRelu(0.01)),
            "relu" => Ok(Activation::Relu),
            "gelu" => Ok(Activation::Gelu),
            "silu" => Ok(Activation::Silu),
            _ => s
                .strip_prefix("leaky-relu:")
                .and_then(|v| v.parse::<f32>().ok())
                // A negative slope is not a leaky ReLU (and the dense layers' backward reads
                // the sign of the pre-activation from the output's, true only for slope ≥ 0).
                .filter(|slope| slope.is_finite() && *slope >= 0.0)
                .map(Activation::LeakyRelu)
                .ok_or_else(|| {
                    Error::Invalid(format!(
                        "unknown activation '{s}'; use leaky-relu, leaky-relu:SLOPE (SLOPE ≥ 0), relu, gelu or silu"
                    ))
                }),
        }
    }
}

impl fmt::Display for Activation {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Activation::LeakyRelu(s) if *s == 0.01 => f.write_str("leaky-relu"),
            Activation::LeakyRelu(s) => write!(f, "leaky-relu:{s}"),
            Activation::Relu => f.write_str("relu"),
            Activation::Gelu => f.write_str("gelu"),
            Activation::Silu => f.write_str("silu"),
        }
    }
}

/// Learning-rate schedule over the run.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Schedule {
    /// The paper's: the same rate throughout.
    Constant,
    /// Cosine decay from the rate to 0 over all steps.
    Cosine,
}

/// How ×16 (and ×8) is reached.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Chain {
    /// Run the whole method again on the ×4 result (sharper; the default).
    TwoLevel,
    /// Apply the trained ×4 filter again to its own output.
    Single,
}

/// An interpolation kernel named in a configuration: `bilinear`, `bicubic`, `lanczos3`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Interpolation(pub Kernel);

impl FromStr for Interpolation {
    type Err = Error;
    fn from_str(s: &str) -> Result<Self> {
        match s {
            "bilinear" => Ok(Interpolation(Kernel::Bilinear)),
            "bicubic" => Ok(Interpolation(Kernel::Bicubic { a: -0.5 })),
            "lanczos3" => Ok(Interpolation(Kernel::Lanczos3)),
            _ => Err(Error::Invalid(format!(
                "unknown interpolation '{s}'; use bilinear, bicubic or lanczos3"
            ))),
        }
    }
}

impl fmt::Display for Interpolation {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        self.0.fmt(f)
    }
}

/// An output size asked for instead of a scale: `4096` or `4K` (a square's side; K is 1024
/// texels), or `4096x2048`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct TargetSize {
    pub width: usize,
    /// `None`: the side of a square.
    pub height: Option<usize>,
}

impl FromStr for TargetSize {
    type Err = Error;
    fn from_str(s: &str) -> Result<Self> {
        let side = |t: &str| -> Option<usize> {
            let t = t.trim();
            let n = match t.strip_suffix(['K', 'k']) {
                Some(k) => k.parse::<usize>().ok()?.checked_mul(1024)?,
                None => t.parse().ok()?,
            };
            (n > 0).then_some(n)
        };
        let parsed = match s.split_once(['x', '×']) {
            Some((w, h)) => side(w).zip(side(h)).map(|(w, h)| TargetSize {
                width: w,
                height: Some(h),
            }),
            None => side(s).map(|w| TargetSize {
                width: w,
                height: None,
            }),
        };
        parsed.ok_or_else(|| {
            Error::Invalid(format!("size '{s}': give texels as 4096, 4K or 4096x2048"))
        })
    }
}

impl fmt::Display for TargetSize {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self.height {
            Some(h) => write!(f, "{}x{h}", self.width),
            None => write!(f, "{}", self.width),
        }
    }
}

/// What the filter's residual is added to (and what the prior pulls toward).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum ResidualBase {
    /// The LR maps upsampled by a classical kernel (the paper's: bilinear).
    Kernel(Kernel),
    /// Each LR map upsampled on its own by the run's RGB upsampler, as a picture (base colour
    /// sRGB-encoded, normals as colours, grey maps as grey images), then decoded.
    Upsampler,
}

impl FromStr for ResidualBase {
    type Err = Error;
    fn from_str(s: &str) -> Result<Self> {
        match s {
            "upsampler" => Ok(ResidualBase::Upsampler),
            _ => match s.parse::<Interpolation>() {
                Ok(Interpolation(k)) => Ok(ResidualBase::Kernel(k)),
                Err(_) => Err(Error::Invalid(format!(
                    "unknown residual base '{s}'; use bilinear, bicubic, lanczos3 or upsampler"
                ))),
            },
        }
    }
}

impl fmt::Display for ResidualBase {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            ResidualBase::Kernel(k) => k.fmt(f),
            ResidualBase::Upsampler => f.write_str("upsampler"),
        }
    }
}

/// Where the per-map path's base colour takes its chroma from.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Chroma {
    /// The run's RGB upsampler, as it upsamples the colour.
    Upsampler,
    /// A classical kernel on the LR base colour, with the upsampler's luma carried over (a
    /// network may sharpen brightness but then adds no hue of its own).
    Kernel(Kernel),
}

impl FromStr for Chroma {
    type Err = Error;
    fn from_str(s: &str) -> Result<Self> {
        match s.parse::<ResidualBase>() {
            Ok(ResidualBase::Upsampler) => Ok(Chroma::Upsampler),
            Ok(ResidualBase::Kernel(k)) => Ok(Chroma::Kernel(k)),
            Err(_) => Err(Error::Invalid(format!(
                "unknown base colour chroma '{s}'; use upsampler, bilinear, bicubic or lanczos3"
            ))),
        }
    }
}

impl fmt::Display for Chroma {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Chroma::Kernel(k) => ResidualBase::Kernel(*k).fmt(f),
            Chroma::Upsampler => ResidualBase::Upsampler.fmt(f),
        }
    }
}

/// The renders the filter is trained to reproduce.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum TargetKind {
    /// The paper's: each LR render upsampled by the RGB upsampler S, `S(r_ω)`.
    Direct,
    /// Detail transfer: `R_ω(M_base) + S(r_ω) − B(r_ω)`, the renders of the residual base
    /// plus what S adds to each render beyond B, the base's own upsampler (its kernel, or S
    /// itself for a per-map `upsampler` base, whose targets are then its own renders).
    /// Unlike `S(r_ω)` these are unbiased where S adds nothing: shading is nonlinear, so an
    /// interpolated render is not the render of the interpolated maps.
    Detail,
}

/// Whether a run chooses its settings by validating candidates one scale down.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Selection {
    /// Run the configuration as given.
    Off,
    /// Score the candidate settings on the LR material downsampled once more (where the LR
    /// material is the truth) and run the best.
    Auto,
    /// As `Auto`, with only the upsampler as candidates: the configured one and each of
    /// [`Config::select_upsamplers`], the settings otherwise as given.
    Upsampler,
}

/// The light set the renders are made under.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct LightsConfig {
    pub count: usize,
    pub distance: f32,
    pub intensity: f32,
    pub falloff: bool,
}

impl Default for LightsConfig {
    fn default() -> Self {
        LightsConfig {
            count: 100,
            distance: 1.4,
            intensity: 8.0,
            falloff: false,
        }
    }
}

impl LightsConfig {
    /// The training light set these settings describe.
    pub fn build(&self) -> Vec<matup_core::lights::Light> {
        matup_core::lights::LightSetSpec {
            count: self.count,
            distance: self.distance,
            intensity: self.intensity,
            falloff: self.falloff,
            ..Default::default()
        }
        .build()
    }
}

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
}

impl FilterConfig {
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

/// `tileable`: a boolean, or `"auto"` (decided from the edges).
fn tiling<'de, D: Deserializer<'de>>(d: D) -> std::result::Result<Option<bool>, D::Error> {
    #[derive(Deserialize)]
    #[serde(untagged)]
    enum Tiling {
        Given(bool),
        Word(String),
    }
    // `null` (run.json's "auto") too.
    match Option::<Tiling>::deserialize(d)? {
        None => Ok(None),
        Some(Tiling::Given(t)) => Ok(Some(t)),
        Some(Tiling::Word(w)) if w == "auto" => Ok(None),
        Some(Tiling::Word(w)) => Err(serde::de::Error::custom(format!(
            "tileable = \"{w}\": use true, false or \"auto\""
        ))),
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
            // Measured (docs/experiments/2026-11-28-no-new-structure.md): no texel of
            // DamagedHelmet's colour, roughness or metallic 16 levels past its input around
            // it; −0.034 dB on the shared set (Tiles012 −0.34), +0.001 on the val sets.
            neighbourhood_margin: NEIGHBOURHOOD_MARGIN,
        }
    }
}

/// The default [`FilterConfig::neighbourhood_margin`].
pub const NEIGHBOURHOOD_MARGIN: f32 = 0.06;

/// Weights of the map-space prior `Σ_k w_k (f_k − base_k)²`, averaged over texels: each
/// pulls a feature of the output toward the residual base.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct PriorConfig {
    /// On each channel of the linear base colour.
    pub base_color: f32,
    /// α of METHOD.md's metallic regulariser.
    pub metallic: f32,
    /// On the normal's x and y.
    pub normal: f32,
    /// On alpha (roughness²).
    pub roughness: f32,
}

impl Default for PriorConfig {
    fn default() -> Self {
        PriorConfig {
            base_color: 0.0,
            metallic: 0.1,
            normal: 0.0,
            roughness: 0.0,
        }
    }
}

impl PriorConfig {
    /// The weight of each of the filter's 7 features.
    pub fn feature_weights(&self) -> [f32; 7] {
        let (b, n) = (self.base_color, self.normal);
        [b, b, b, self.metallic, n, n, self.roughness]
    }

    /// Sets weights from `KEY=W,KEY=W` (keys base_color, metallic, normal, roughness).
    pub fn set(&mut self, assignments: &str) -> Result<()> {
        for part in assignments.split(',').filter(|p| !p.trim().is_empty()) {
            let bad = || {
                Error::Invalid(format!(
                    "prior '{part}': use KEY=WEIGHT with KEY base_color, metallic, normal or roughness and WEIGHT ≥ 0"
                ))
            };
            let (key, value) = part.split_once('=').ok_or_else(bad)?;
            let value: f32 = value.trim().parse().map_err(|_| bad())?;
            let slot = match key.trim() {
                "base_color" => &mut self.base_color,
                "metallic" => &mut self.metallic,
                "normal" => &mut self.normal,
                "roughness" => &mut self.roughness,
                _ => return Err(bad()),
            };
            *slot = value;
        }
        Ok(())
    }
}

/// Why a tensor-backend run refuses β and γ (their ops have CPU kernels only).
pub(crate) const FUSED_ONLY_TERMS: &str = "train.lr_consistency (β) and train.cross_scale (γ) are trained by the fused backend only (train.backend = fused, on the CPU)";

/// How training steps are computed.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Backend {
    /// `fused` on the CPU, `tensor` on any other device.
    Auto,
    /// matup's CPU kernels: the render loss with each model's hand-derived gradient.
    Fused,
    /// candle tensor operations on any device, differentiated by candle's autograd (the
    /// shading model needs a tensor form).
    Tensor,
}

impl Backend {
    /// The backend `auto` stands for, on the CPU or not.
    pub fn resolve(self, on_cpu: bool) -> Backend {
        match self {
            Backend::Auto if on_cpu => Backend::Fused,
            Backend::Auto => Backend::Tensor,
            other => other,
        }
    }
}

/// Training.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TrainConfig {
    /// Passes over every output texel; 0 (the default) trains no filter, and the residual
    /// base is the result. Measured on the shared materials, a filter trained on renders
    /// upsampled by the shipped SPAN network does not improve on a back-projected per-map
    /// base (docs/experiments/2026-11-21-quality-against-per-map.md).
    pub epochs: usize,
    /// Texels per step.
    pub batch_size: usize,
    pub learning_rate: f64,
    /// Multiply the learning rate by `batch_size / 128` (linear scaling).
    pub scale_learning_rate: bool,
    pub schedule: Schedule,
    #[serde(with = "as_string")]
    pub loss: LossNorm,
    pub targets: TargetKind,
    /// Map-space prior: weights pulling each feature toward the residual base (METHOD.md's
    /// metallic regulariser is `metallic = 0.1` with a bilinear base).
    pub prior: PriorConfig,
    /// β: weight of the LR-consistency term `mean ‖box_downsample(M_SR) − M_LR‖²` (0: off).
    pub lr_consistency: f32,
    /// γ: weight of cross-scale self-supervision on exact pairs one scale down (0: off).
    pub cross_scale: f32,
    /// Train on this many randomly chosen texels per epoch instead of all of them.
    pub texels_per_epoch: Option<usize>,
    /// Stop before `epochs` when a held-out validation loss stops improving.
    pub early_stop: EarlyStopConfig,
    /// How the steps are computed.
    pub backend: Backend,
}

/// Convergence-based stopping: `train.epochs` is a maximum. A fixed set of texels is held out
/// of training; every `1 / checks_per_epoch` of an epoch the objective is evaluated on them,
/// and training stops after `patience` checks in a row that did not lower the best value so
/// far by at least `min_gain` of it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct EarlyStopConfig {
    /// false: train every epoch (the paper's fixed schedule).
    pub enabled: bool,
    /// Output texels held out to validate on (at most a tenth of the level's texels).
    pub validation_texels: usize,
    pub checks_per_epoch: usize,
    pub patience: usize,
    /// The relative gain a check must make to count as progress.
    pub min_gain: f64,
}

impl Default for EarlyStopConfig {
    fn default() -> Self {
        EarlyStopConfig {
            enabled: true,
            validation_texels: 8192,
            checks_per_epoch: 4,
            // Chosen on 256² and 512² crops of the four shared materials with the paper's
            // settings (docs/experiments/2026-11-23-early-stopping.md): 2 checks or a 0.2–0.5% gain
            // stopped too soon (−0.04 to −0.08 dB on average).
            patience: 4,
            min_gain: 1e-3,
        }
    }
}

impl Default for TrainConfig {
    fn default() -> Self {
        TrainConfig {
            epochs: 0,
            batch_size: 128,
            learning_rate: 1e-4,
            scale_learning_rate: false,
            schedule: Schedule::Constant,
            loss: LossNorm::L21,
            targets: TargetKind::Detail,
            prior: PriorConfig::default(),
            lr_consistency: 0.0,
            cross_scale: 0.0,
            texels_per_epoch: None,
            early_stop: EarlyStopConfig::default(),
            backend: Backend::Auto,
        }
    }
}

/// Everything an upscale run needs to know besides the material.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Config {
    /// 2, 3 or 4 (one level), 8 (×4, then ×2) or 16 (two ×4 levels).
    pub scale: usize,
    /// An output size in texels instead of `scale`: the smallest scale that reaches it runs,
    /// and a whole output larger than it is area-shrunk to it (`crate::plan::Reach`).
    pub size: Option<TargetSize>,
    pub chain: Chain,
    /// The RGB upsampler of the renders (`NAME[:ARGUMENT]`), or `auto`: the best the build
    /// has, which the run's plan chooses (`crate::plan::choose_upsampler`).
    pub upsampler: String,
    /// The shading model (`NAME[:OPTIONS]`).
    pub shading: String,
    /// Whether the material tiles: `true`, `false`, or absent (`"auto"`): wrapped unless its
    /// edges show it is a crop (`matup_core::tileable::decide_tileable`).
    #[serde(deserialize_with = "tiling")]
    pub tileable: Option<bool>,
    /// Skip work the material cannot use (constant channels, dark lights).
    pub skip: bool,
    pub seed: u64,
    /// `auto`: choose among candidate settings by validating them one scale down;
    /// `upsampler`: among upsamplers only.
    pub select: Selection,
    /// More upsamplers for the selection to validate (`NAME[:ARGUMENT]`), each in place of
    /// `upsampler` with the settings otherwise as given: a network fine-tuned for some
    /// materials beside the stock one, kept only where it validates better.
    pub select_upsamplers: Vec<String>,
    pub lights: LightsConfig,
    pub filter: FilterConfig,
    pub train: TrainConfig,
    /// Where matup computes with tensors: `cpu`, `cuda` or `cuda:N` (a build with the `cuda`
    /// feature). On a GPU the SR networks run there (the `onnx` upsampler's `device`), and the
    /// filter trains there.
    pub device: String,
}

impl Default for Config {
    fn default() -> Self {
        Config {
            scale: 4,
            size: None,
            chain: Chain::TwoLevel,
            upsampler: "auto".into(),
            shading: "ggx".into(),
            tileable: None,
            skip: true,
            seed: 0,
            select: Selection::Off,
            select_upsamplers: Vec::new(),
            lights: LightsConfig::default(),
            filter: FilterConfig::default(),
            train: TrainConfig::default(),
            device: "cpu".into(),
        }
    }
}

/// The scales one level of the method handles.
pub const LEVEL_SCALES: [usize; 3] = [2, 3, 4];

/// The whole factors matup upsamples by: one level of [`LEVEL_SCALES`], or two levels (×8 as
/// ×4 then ×2, ×16 as two ×4). `what` names the value in the error (`scale`, `factor`).
pub fn check_supported_scale(scale: usize, what: &str) -> Result<()> {
    if SCALES.contains(&scale) {
        Ok(())
    } else {
        Err(Error::Invalid(format!(
            "unsupported {what} ×{scale}; use 2, 3, 4, 8 or 16"
        )))
    }
}

/// Every whole factor matup upsamples by.
pub const SCALES: [usize; 5] = [2, 3, 4, 8, 16];

impl Config {
    /// Whether the upsampler's only work is the per-map base back-projected onto the LR maps,
    /// which is then the result (no filter trained, so no renders upsampled): the use the
    /// material network (`crate::plan::MATERIAL_NETWORK`) was trained and measured for.
    pub fn upsamples_maps_only(&self) -> bool {
        self.filter.residual_base == ResidualBase::Upsampler
            && self.filter.back_project
            && self.train.epochs == 0
    }

    /// METHOD.md's settings, the paper's: the filter trained for 10 epochs on the renders
    /// upsampled by the RGB upsampler, added to bilinearly upsampled maps.
    pub fn paper() -> Config {
        let mut c = Config::default();
        c.filter.residual_base = ResidualBase::Kernel(Kernel::Bilinear);
        c.filter.back_project = false;
        c.filter.clamp_chroma = false;
        c.train.targets = TargetKind::Direct;
        c.train.epochs = 10;
        c.train.early_stop.enabled = false;
        c
    }

    /// Parses TOML; `origin` (a file name) prefixes errors, which carry the line and key.
    pub fn from_toml(text: &str, origin: &str) -> Result<Config> {
        let config: Config = toml::from_str(text).map_err(|e| {
            // A `device` under [train] gets a pointer to where it belongs.
            let moved = toml::from_str::<toml::Table>(text).is_ok_and(|t| {
                (t.get("train").and_then(|t| t.as_table()))
                    .is_some_and(|t| t.contains_key("device"))
            });
            let hint = if moved {
                "\n`device` is a top-level setting (it places the SR network too): move it out of \
                 [train]"
            } else {
                ""
            };
            Error::Invalid(format!("{origin}: {e}{hint}"))
        })?;
        config.validate()?;
        Ok(config)
    }

    /// The configuration as TOML.
    pub fn to_toml(&self) -> String {
        toml::to_string(self).expect("a Config always serialises")
    }

    /// These settings as level `level` (0 for the first) of ×`scale` runs them with an
    /// upsampler of `native_scale`: the maps it upsamples decided ([`UpsampledMaps::at_level`]).
    pub fn at_level(&self, level: usize, scale: usize, native_scale: Option<usize>) -> Config {
        let mut config = self.clone();
        let maps = &mut config.filter.upsampled_maps;
        *maps = maps.at_level(level, scale, native_scale);
        config
    }

    /// Rejects values the method cannot run with, saying which and why.
    pub fn validate(&self) -> Result<()> {
        let bad = |m: String| Err(Error::Invalid(m));
        check_supported_scale(self.scale, "scale")?;
        if self.chain == Chain::Single && self.scale == 8 {
            return bad(
                "chain = \"single\" applies the ×4 level's filter again at ×4: it reaches ×16, not ×8 (use two-level)".into(),
            );
        }
        let f = &self.filter;
        if f.window == 0 || f.window % 2 == 0 {
            return bad(format!(
                "filter.window must be odd and positive, not {}",
                f.window
            ));
        }
        if f.hidden_width == 0 {
            return bad("filter.hidden_width must be positive".into());
        }
        f.self_ensemble().symmetries()?;
        if !self.select_upsamplers.is_empty() && self.select == Selection::Off {
            return bad(
                "select_upsamplers are candidates for the selection: set select = \"upsampler\" (or \"auto\")".into(),
            );
        }
        if self.select == Selection::Upsampler && self.select_upsamplers.is_empty() {
            return bad(
                "select = \"upsampler\" chooses among upsamplers: name at least one in select_upsamplers (--select-upsampler)".into(),
            );
        }
        let t = &self.train;
        if t.batch_size == 0 {
            return bad("train.batch_size must be positive".into());
        }
        if !(t.learning_rate > 0.0 && t.learning_rate.is_finite()) {
            return bad(format!(
                "train.learning_rate must be positive, not {}",
                t.learning_rate
            ));
        }
        for (name, v) in [
            ("train.prior.base_color", t.prior.base_color),
            ("train.prior.metallic", t.prior.metallic),
            ("train.prior.normal", t.prior.normal),
            ("train.prior.roughness", t.prior.roughness),
            ("train.lr_consistency", t.lr_consistency),
            ("train.cross_scale", t.cross_scale),
        ] {
            if !(v >= 0.0 && v.is_finite()) {
                return bad(format!("{name} must be ≥ 0, not {v}"));
            }
        }
        if self.lights.count == 0 {
            return bad("lights.count must be at least 1".into());
        }
        let on_cpu = matup_core::tensor::cuda_ordinal(&self.device)?.is_none();
        let tensor = t.backend.resolve(on_cpu) == Backend::Tensor;
        if t.backend == Backend::Fused && !on_cpu {
            return bad(format!(
                "train.backend fused runs on the CPU only; use tensor (or auto) with device {}",
                self.device
            ));
        }
        // Refused up front, whatever the settings would run: a run that trains nothing must
        // not pass silently on the CPU.
        if !on_cpu && !cfg!(feature = "cuda") {
            return bad(format!(
                "device {}: this build has no CUDA support; build matup with \
                 --features cuda (docs/cuda.md)",
                self.device
            ));
        }
        if tensor && (t.lr_consistency > 0.0 || t.cross_scale > 0.0) {
            return bad(FUSED_ONLY_TERMS.into());
        }
        let e = &t.early_stop;
        if e.enabled {
            if e.validation_texels == 0 || e.checks_per_epoch == 0 || e.patience == 0 {
                return bad("train.early_stop: validation_texels, checks_per_epoch and patience must be positive (or enabled = false)".into());
            }
            if !(e.min_gain >= 0.0 && e.min_gain < 1.0) {
                return bad(format!(
                    "train.early_stop.min_gain must be in [0, 1), not {}",
                    e.min_gain
                ));
            }
        }
        if t.texels_per_epoch == Some(0) {
            return bad("train.texels_per_epoch must be positive".into());
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_self_ensemble_is_a_count_of_symmetries_or_a_switch_for_all_eight() {
        let read = |line: &str| Config::from_toml(&format!("[filter]\n{line}\n"), "test.toml");
        let ensemble = |line: &str| read(line).unwrap().filter.self_ensemble();
        assert_eq!(ensemble("self_ensemble = true").symmetries, 8);
        assert_eq!(ensemble("self_ensemble = false").symmetries, 1);
        let two = ensemble("self_ensemble = 2\nself_ensemble_maps = \"normal\"");
        assert_eq!((two.symmetries, two.maps), (2, EnsembleMaps::Normal));
        let err = read("self_ensemble = 3").unwrap_err().to_string();
        assert!(err.contains("not 3"), "{err}");
        assert_eq!(
            Config::default().filter.self_ensemble(),
            SelfEnsemble {
                symmetries: 2,
                maps: EnsembleMaps::All
            }
        );
    }

    #[test]
    fn tileable_is_true_false_or_auto() {
        let read = |line: &str| Config::from_toml(&format!("{line}\n"), "test.toml");
        assert_eq!(read("tileable = true").unwrap().tileable, Some(true));
        assert_eq!(read("tileable = false").unwrap().tileable, Some(false));
        assert_eq!(read("tileable = \"auto\"").unwrap().tileable, None);
        assert_eq!(read("").unwrap().tileable, None);
        let e = read("tileable = \"maybe\"").unwrap_err().to_string();
        assert!(e.contains("true, false or \"auto\""), "{e}");
        // run.json writes "auto" as null, and reads it back.
        let json = serde_json::to_string(&Config::default()).unwrap();
        let back: Config = serde_json::from_str(&json).unwrap();
        assert_eq!(back.tileable, None);
    }

    #[test]
    fn a_device_under_train_says_where_it_moved() {
        let e = Config::from_toml("[train]\ndevice = \"cpu\"\n", "old.toml").unwrap_err();
        assert!(e.to_string().contains("move it out of [train]"), "{e}");
        let c = Config::from_toml("device = \"cpu\"\n", "new.toml").unwrap();
        assert_eq!(c.device, "cpu");
    }

    #[test]
    fn paper_settings_are_method_md() {
        let c = Config::paper();
        assert_eq!(
            c.filter.residual_base,
            ResidualBase::Kernel(Kernel::Bilinear)
        );
        assert!(!c.filter.back_project);
        assert!(
            !c.filter.clamp_chroma,
            "the paper adds nothing to its filter's colours"
        );
        assert!(!c.train.early_stop.enabled, "the paper trains every epoch");
        assert_eq!(c.train.targets, TargetKind::Direct);
        assert_eq!(
            (
                c.filter.window,
                c.filter.hidden_width,
                c.filter.hidden_layers
            ),
            (17, 128, 4)
        );
        assert_eq!(
            (c.train.epochs, c.train.batch_size, c.train.learning_rate),
            (10, 128, 1e-4)
        );
        assert_eq!(c.train.loss, LossNorm::L21);
        assert_eq!(c.train.prior, PriorConfig::default());
        assert_eq!(c.train.prior.metallic, 0.1);
        assert_eq!(c.lights.count, 100);
        // The defaults differ from the paper only where measurement chose otherwise.
        let d = Config::default();
        assert_eq!(
            Config {
                filter: FilterConfig {
                    residual_base: ResidualBase::Upsampler,
                    back_project: true,
                    clamp_chroma: true,
                    ..c.filter.clone()
                },
                train: TrainConfig {
                    epochs: 0,
                    targets: TargetKind::Detail,
                    early_stop: EarlyStopConfig::default(),
                    ..c.train.clone()
                },
                ..c
            },
            d
        );
    }

    #[test]
    fn the_shipped_paper_file_is_the_paper() {
        let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../../configs/paper.toml");
        let text = std::fs::read_to_string(path).unwrap();
        assert_eq!(Config::from_toml(&text, path).unwrap(), Config::paper());
    }

    #[test]
    fn settings_parse_and_print_alike() {
        for s in ["bilinear", "bicubic", "lanczos3", "upsampler"] {
            assert_eq!(s.parse::<ResidualBase>().unwrap().to_string(), s);
        }
        for s in ["direct", "detail"] {
            assert_eq!(s.parse::<TargetKind>().unwrap().to_string(), s);
        }
        assert_eq!("two-level".parse::<Chain>().unwrap(), Chain::TwoLevel);
        assert_eq!(Chain::TwoLevel.to_string(), "two-level");
        assert_eq!(Backend::Fused.to_string(), "fused");
        assert_eq!(
            "normal".parse::<EnsembleMaps>().unwrap(),
            EnsembleMaps::Normal
        );
        // An unknown name is refused with the setting and the names it takes, from serde.
        let e = "fast".parse::<Backend>().unwrap_err().to_string();
        assert!(
            e.contains("backend") && e.contains("`fused`") && e.contains("`tensor`"),
            "{e}"
        );
        let e = "Cosine".parse::<Schedule>().unwrap_err().to_string();
        assert!(e.contains("`constant` or `cosine`"), "{e}");
        // TOML reads the same names.
        let c = Config::from_toml("[train]\nschedule = \"cosine\"\n", "t.toml").unwrap();
        assert_eq!(c.train.schedule, Schedule::Cosine);
        assert!("upscaler".parse::<ResidualBase>().is_err());
        let mut p = PriorConfig::default();
        p.set("normal=2, roughness=0.5").unwrap();
        assert_eq!(p.feature_weights(), [0.0, 0.0, 0.0, 0.1, 2.0, 2.0, 0.5]);
        let e = p.set("gloss=1").unwrap_err().to_string();
        assert!(e.contains("gloss") && e.contains("base_color"), "{e}");
    }

    #[test]
    fn toml_round_trips_and_rejects_unknown_keys() {
        let c = Config::default();
        assert_eq!(Config::from_toml(&c.to_toml(), "x.toml").unwrap(), c);
        let c = Config::from_toml(
            "scale = 16\n[train]\nloss = \"lpq:1.5,1\"\nepochs = 3\n",
            "a.toml",
        )
        .unwrap();
        assert_eq!(c.train.loss, LossNorm::Lpq { p: 1.5, q: 1.0 });
        assert_eq!(c.scale, 16);
        let e = Config::from_toml("scale = 8\nchain = \"single\"\n", "d.toml").unwrap_err();
        assert!(e.to_string().contains("not ×8"), "{e}");
        for scale in [5, 6, 12, 32] {
            assert!(check_supported_scale(scale, "scale").is_err(), "×{scale}");
        }
        let e = Config::from_toml("[train]\nepoch = 3\n", "b.toml")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("b.toml") && e.contains("epoch") && e.contains("line 2"),
            "{e}"
        );
        let e = Config::from_toml("[filter]\nactivation = \"leaky-relu:-0.5\"\n", "d.toml")
            .unwrap_err()
            .to_string();
        assert!(e.contains("d.toml") && e.contains("SLOPE ≥ 0"), "{e}");
        assert_eq!(
            "leaky-relu:0.2".parse::<Activation>().unwrap(),
            Activation::LeakyRelu(0.2)
        );
        let e = Config::from_toml("scale = 5\n", "c.toml")
            .unwrap_err()
            .to_string();
        assert!(e.contains("unsupported scale"), "{e}");
    }
}
