//! The configuration of an upscale run: every hyper-parameter, with METHOD.md's values as
//! defaults, readable from TOML (`deny_unknown_fields`: a typo is an error, not a silent
//! default) and settable from the CLI. Each TOML table has its module; `values` holds the
//! named values and their string forms. What a run makes of the settings is its plan
//! (`crate::plan`).

mod filter;
mod lights;
mod train;
mod values;

use std::collections::BTreeMap;

use serde::{Deserialize, Deserializer, Serialize};

use crate::features::FEATURE_MAPS;
pub use crate::per_map::{EnsembleMaps, MapPasses, SelfEnsemble, UpsampledMaps};
pub use filter::{FilterConfig, NEIGHBOURHOOD_MARGIN};
pub use lights::LightsConfig;
use matup_core::material::MapKind;
use matup_core::resample::Kernel;
use matup_core::{Error, Result};
pub(crate) use train::FUSED_ONLY_TERMS;
pub use train::{EarlyStopConfig, PriorConfig, TrainConfig};
pub use values::{
    Activation, Backend, Chain, Chroma, InputQuality, Interpolation, ResidualBase, Schedule,
    Selection, TargetKind, TargetSize,
};

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
    /// Where matup computes (`matup_core::device`): `auto` (CUDA in a CUDA build, else the
    /// first hardware GPU adapter, else the CPU), `cpu`, `gpu`, `gpu:N`, `gpu:NAME` (a wgpu
    /// adapter, `matup list`), `cuda` or `cuda:N` (a build with the `cuda` feature). The SR
    /// networks run there (the `onnx` upsampler's `device`); the filter trains on CUDA where
    /// the spec resolves to it, else on the CPU.
    pub device: String,
    /// Whether the input maps are clean or degraded by lossy storage (`auto`: each as its file
    /// says): a degraded map runs the network trained on degraded inputs, unprojected
    /// (`crate::plan::InputRoute`).
    pub input_quality: InputQuality,
    /// Per map, in place of `input_quality` (`[map_input_quality]`, maps by file stem:
    /// `normal = "clean"`): a glTF model's JPEG colour beside its PNG maps routes each apart.
    #[serde(skip_serializing_if = "BTreeMap::is_empty")]
    pub map_input_quality: BTreeMap<MapKind, InputQuality>,
    /// matup's networks run by other upsamplers: where the run would use `onnx:NAME`, the
    /// spec given for NAME runs instead (the Python package's callables running the same
    /// network through PyTorch on ComfyUI's GPU). The run reports both.
    pub networks: BTreeMap<String, String>,
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
            device: "auto".into(),
            input_quality: InputQuality::Auto,
            map_input_quality: BTreeMap::new(),
            networks: BTreeMap::new(),
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
    /// Whether the upsampler's only work is the per-map base, which is then the result (no
    /// filter trained, so no renders upsampled): the use the material networks
    /// (`crate::plan::MATERIAL_NETWORK`, `crate::plan::DEGRADED_NETWORK`) were trained for.
    pub fn upsamples_maps_only(&self) -> bool {
        self.filter.residual_base == ResidualBase::Upsampler && self.train.epochs == 0
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
        if f.window == 0 || f.window.is_multiple_of(2) {
            return bad(format!(
                "filter.window must be odd and positive, not {}",
                f.window
            ));
        }
        if f.hidden_width == 0 {
            return bad("filter.hidden_width must be positive".into());
        }
        f.self_ensemble().symmetries()?;
        if !(f.projection_blur >= 0.0 && f.projection_blur.is_finite()) {
            return bad(format!(
                "filter.projection_blur must be ≥ 0 (LR texels), not {}",
                f.projection_blur
            ));
        }
        if !(f.normal_blend_noise >= 0.0 && f.normal_blend_noise.is_finite()) {
            return bad(format!(
                "filter.normal_blend_noise must be ≥ 0 (8-bit levels), not {}",
                f.normal_blend_noise
            ));
        }
        let routed = (self.map_input_quality.keys()).chain(&f.unprojected_maps);
        if let Some(kind) = routed.into_iter().find(|k| !FEATURE_MAPS.contains(k)) {
            return bad(format!(
                "map_input_quality and filter.unprojected_maps name the maps the filter \
                 reads (baseColor, normal, roughness, metallic), not {}",
                kind.file_stem()
            ));
        }
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
        let on_cpu = matup_core::device::cuda_ordinal(&self.device)?.is_none();
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
    use matup_core::loss::LossNorm;

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
