//! A run's plan: the settings and the material made, once, into what the pipeline carries
//! out. The output size becomes a scale and its levels, each level gets its settings, the
//! tiling is decided, the shading model is loaded and the upsampler chosen; with `select` on,
//! each candidate setting is planned the same way. Every check and every choice of a run is
//! made here: the pipeline, the preview and a folder's images of other sizes receive the
//! plan (`matup upscale`, batches and the Python package reach them through folder runs).

use std::sync::Arc;

use crate::config::{Config, InputQuality, Selection, TargetSize, LEVEL_SCALES, SCALES};
use crate::features::FEATURE_MAPS;
use crate::select::candidates;
use matup_core::lights::Light;
use matup_core::material::{MapKind, Material};
use matup_core::resample::Border;
use matup_core::shading::{shading_model, ShadingModel};
use matup_core::texel_trace::{noise_floor, quantised_trace, texel_trace, TexelTrace};
use matup_core::tileable::decide_tileable;
use matup_core::upsample::{check_scale, upsampler, RgbUpsampler};
use matup_core::FileFormat;
use matup_core::Map;
use matup_core::{Error, PluginSpec, Result};

/// What a run of one material carries out.
#[derive(Clone)]
pub struct Plan {
    /// The size asked for, as given (the settings' `size`; the setup's is resolved).
    pub asked_size: Option<TargetSize>,
    pub reach: Reach,
    pub tiling: Tiling,
    /// Whether the input is read as clean or degraded, and why.
    pub input: InputRoute,
    pub shading: Arc<dyn ShadingModel>,
    /// The training light set the renders are made under (`[lights]`).
    pub lights: Vec<Light>,
    /// The settings as they run and the upsampler chosen for them.
    pub setup: Setup,
    /// With `select` on, each candidate setting's setup (`crate::select::candidates`), in
    /// order of preference; empty otherwise.
    pub candidates: Vec<(String, Setup)>,
}

/// Settings ready to run: validated, each level's settings derived and the upsampler chosen.
#[derive(Clone)]
pub struct Setup {
    /// The settings, with a size asked for resolved into the scale that reaches it (`size`
    /// none, `scale` that one).
    pub settings: Config,
    /// Each level's scale and settings, the first level first.
    pub levels: Vec<Level>,
    /// The upsampler `settings.upsampler` names, or for `auto` the one chosen.
    pub upsampler: Arc<dyn RgbUpsampler>,
    pub upsampler_name: String,
    /// With `auto`, the maps routed apart (`settings.map_input_quality`) whose upsampler is
    /// another.
    pub apart: Vec<MapUpsampler>,
    /// Where a noisy material's normals are blended with the clean route's
    /// (`filter.normal_blend_noise`), the clean route's upsampler: `auto`'s choice for a clean
    /// input, else the run's own.
    pub clean_normals: Option<MapUpsampler>,
}

/// A map routed apart and the upsampler that makes it.
#[derive(Clone)]
pub struct MapUpsampler {
    pub kind: MapKind,
    /// The upsampler's name, as the run reports it.
    pub name: String,
    pub upsampler: Arc<dyn RgbUpsampler>,
}

/// One ×`scale` level of a run, with the settings as it runs them ([`Config::at_level`]).
#[derive(Clone)]
pub struct Level {
    pub scale: usize,
    pub settings: Config,
}

/// Whether the material is taken to tile, and on what grounds.
#[derive(Clone, Debug, PartialEq)]
pub struct Tiling {
    pub tileable: bool,
    pub grounds: TilingGrounds,
}

/// Why a material is taken to tile or not.
#[derive(Clone, Debug, PartialEq)]
pub enum TilingGrounds {
    /// The settings say so (`tileable`, `--tileable`, `--no-tileable`).
    Given,
    /// Its source says so (an exporter's layout, a model's samplers), in words.
    Source(String),
    /// Its edges: the wrap-around step over its largest interior step
    /// (`matup_core::tileable::decide_tileable`).
    Edges(f32),
}

impl Tiling {
    /// The settings' word, else the material's source's, else its edges'.
    pub fn of(material: &Material, settings: &Config) -> Tiling {
        let source_says = (material.origin.as_ref()).and_then(|o| o.tiling.clone());
        let (tileable, grounds) = match (settings.tileable, source_says) {
            (Some(t), _) => (t, TilingGrounds::Given),
            (None, Some((t, why))) => (t, TilingGrounds::Source(why)),
            (None, None) => {
                let (tileable, evidence) = decide_tileable(material);
                (tileable, TilingGrounds::Edges(evidence))
            }
        };
        Tiling { tileable, grounds }
    }

    /// How the borders are read: wrapped where the material tiles, mirrored otherwise.
    pub fn border(&self) -> Border {
        Border::for_tiling(self.tileable)
    }
}

/// Whether a run reads its input as clean, as JPEG or as otherwise degraded by lossy storage,
/// map by map, and on what grounds. A degraded map runs [`DEGRADED_NETWORK`] (where the
/// upsampler is `auto`) and is not back-projected: projection makes the output box-filter back
/// to the input, which puts its blocks and noise back. Where the trace is noise read under
/// every map, the normal map is blended with the clean route's where the input's normals vary
/// far past the noise (`filter.normal_blend_noise`). A JPEG one runs [`JPEG_NETWORK`], a JPEG
/// base colour brought back to the input's low frequencies alone ([`JPEG_PROJECTION_BLUR`]),
/// the other JPEG maps unprojected (docs/experiments/2026-11-29-degraded-inputs.md). A clean
/// map beside them runs as in a clean material: the material network, projected exactly.
#[derive(Clone, Debug, PartialEq)]
pub struct InputRoute {
    /// What the material is taken to be, from its filter's maps: clean where all are, JPEG
    /// where every lossy one is a JPEG, degraded otherwise (never `auto`).
    pub quality: InputQuality,
    /// What each of the filter's maps is taken to be, in feature order (never `auto`).
    pub maps: Vec<(MapKind, InputQuality)>,
    /// Whether the settings said so for every map (`input_quality`, `--input-quality`,
    /// `map_input_quality`); else the files did for some.
    pub given: bool,
    /// The maps stored lossily or noisy, each with what it went through: its file's format
    /// (`Material::lossy`), or BC blocks, a JPEG's grid or noise under every map in its texels
    /// (`matup_core::texel_trace`).
    pub lossy: Vec<String>,
    /// The σ (8-bit levels) of the noise read under every map, where the route takes the
    /// normal map as degraded for it: its normals are then blended with the clean route's.
    pub normal_noise: Option<f32>,
}

/// How far, in LR texels, a JPEG input's mismatch is blurred (kept to its edges) before the
/// projection brings the output back to it (`filter.projection_blur`): what the network sets
/// right in a region is kept, a drift of the whole region is not (DamagedHelmet's white paint
/// 13 levels brighter unprojected; docs/experiments/2026-11-29-degraded-inputs.md).
pub const JPEG_PROJECTION_BLUR: f32 = 16.0;

impl InputRoute {
    /// Each map by the settings' word for it (`map_input_quality`, else `input_quality`), else
    /// by its file's, else by its texels' (read across its edges where it is `tileable`).
    pub fn of(material: &Material, settings: &Config, tileable: bool) -> InputRoute {
        let stored = lossy_maps(material, tileable);
        let word =
            |kind| (settings.map_input_quality.get(&kind)).unwrap_or(&settings.input_quality);
        // A map the material lacks (its stand-in, flat) is none of them: it goes with the
        // material, not apart.
        let stand_ins = material.stand_ins();
        let quality_of = |kind| match *word(kind) {
            _ if stand_ins.contains(&kind) => None,
            InputQuality::Auto => Some(match stored.iter().find(|m| m.kind == kind) {
                None => InputQuality::Clean,
                Some(m) if m.jpeg => InputQuality::Jpeg,
                Some(_) => InputQuality::Degraded,
            }),
            given => Some(given),
        };
        let quality = material_quality(FEATURE_MAPS.into_iter().filter_map(quality_of));
        let maps = (FEATURE_MAPS.into_iter())
            .map(|kind| (kind, quality_of(kind).unwrap_or(quality)))
            .collect();
        let given = FEATURE_MAPS.iter().all(|&k| *word(k) != InputQuality::Auto);
        let mut lossy: Vec<String> = (stored.iter())
            .filter(|m| word(m.kind) == &InputQuality::Auto)
            .map(|m| m.what.clone())
            .collect();
        // Noise under every map is said once.
        lossy.dedup();
        let normal_noise = (stored.iter())
            .filter(|m| m.kind == MapKind::Normal && word(m.kind) == &InputQuality::Auto)
            .find_map(|m| m.noise)
            .map(|sigma| sigma as f32);
        InputRoute {
            quality,
            maps,
            given,
            lossy,
            normal_noise,
        }
    }

    /// Whether any map is read as lossily stored, JPEG or otherwise.
    pub fn degraded(&self) -> bool {
        self.quality != InputQuality::Clean
    }

    /// `settings` as this route runs them: `input_quality` decided, each map apart from the
    /// material's in `map_input_quality`, degraded maps and JPEG maps other than the base
    /// colour not back-projected (none at all where no map is), a JPEG base colour projected
    /// onto its low frequencies, a normal map read as noisy blended with the clean route's.
    pub fn settings(&self, settings: &Config) -> Config {
        let mut config = settings.clone();
        config.input_quality = self.quality;
        config.map_input_quality = (self.maps.iter())
            .filter(|&&(_, q)| q != self.quality)
            .copied()
            .collect();
        let filter = &mut config.filter;
        for &(kind, quality) in &self.maps {
            match (quality, kind) {
                (InputQuality::Clean, _) => {}
                (InputQuality::Jpeg, MapKind::BaseColor) => {
                    filter.projection_blur = JPEG_PROJECTION_BLUR
                }
                _ if filter.unprojected_maps.contains(&kind) => {}
                _ => filter.unprojected_maps.push(kind),
            }
        }
        if FEATURE_MAPS
            .iter()
            .all(|k| filter.unprojected_maps.contains(k))
        {
            // Nothing projected: the height and the carried maps neither, as before maps
            // were routed apart.
            filter.back_project = false;
            filter.unprojected_maps.clear();
        }
        if let Some(sigma) = self.normal_noise {
            filter.normal_blend_noise = sigma;
        }
        config
    }

    /// The route taken, why, and how to decide otherwise, in words.
    pub fn describe(&self) -> String {
        let how = |quality, kinds: &Vec<String>| match quality {
            InputQuality::Jpeg => format!(
                "the base colour projected onto its low frequencies alone (σ \
                 {JPEG_PROJECTION_BLUR} texels), other JPEG maps not projected, run by the \
                 network for JPEG maps where the upsampler is auto"
            ),
            InputQuality::Degraded => {
                let degraded = "not back-projected, run by the network for degraded maps where \
                                the upsampler is auto";
                let normal = MapKind::Normal.to_string();
                match self.normal_noise {
                    Some(sigma) if kinds.contains(&normal) => {
                        format!(
                            "{degraded}, the normals blended with the clean route's where they \
                             vary far past the noise (σ {sigma:.1} levels)"
                        )
                    }
                    _ => degraded.to_string(),
                }
            }
            _ => "projected exactly, run by the material network where the upsampler is auto"
                .to_string(),
        };
        let name = |quality| match quality {
            InputQuality::Jpeg => "JPEG",
            InputQuality::Degraded => "degraded",
            _ => "clean",
        };
        // Each quality with its maps, where the maps differ.
        let by_quality = maps_by(self.maps.iter().map(|&(kind, q)| (q, kind)));
        let given = if self.given { " (as given)" } else { "" };
        let route = match by_quality.as_slice() {
            [(InputQuality::Clean, _)] => format!("clean{given}"),
            [(quality, kinds)] => format!("{}{given}: {}", name(*quality), how(*quality, kinds)),
            _ => {
                let each = (by_quality.iter()).map(|(quality, kinds)| {
                    format!(
                        "{} {}: {}",
                        name(*quality),
                        kinds.join(", "),
                        how(*quality, kinds)
                    )
                });
                format!("{}{given}", each.collect::<Vec<_>>().join("; "))
            }
        };
        match (self.degraded(), self.given) {
            (_, true) => format!("input: {route}"),
            (true, false) => format!(
                "input: {route}; read as degraded: {}; --input-quality clean decides otherwise",
                self.lossy.join("; ")
            ),
            (false, false) => "input: clean (no map was stored lossily or read as noisy; \
                               --input-quality degraded decides otherwise)"
                .to_string(),
        }
    }
}

/// What a material is taken to be, from its maps' `qualities`: clean where all are, JPEG where
/// every lossy one is, degraded otherwise.
fn material_quality(qualities: impl Iterator<Item = InputQuality>) -> InputQuality {
    let lossy: Vec<InputQuality> = qualities.filter(|&q| q != InputQuality::Clean).collect();
    if lossy.is_empty() {
        InputQuality::Clean
    } else if lossy.iter().all(|&q| q == InputQuality::Jpeg) {
        InputQuality::Jpeg
    } else {
        InputQuality::Degraded
    }
}

/// A map of a material stored lossily.
struct LossyMap {
    kind: MapKind,
    /// Its storage, in words.
    what: String,
    jpeg: bool,
    /// Whether its texels lie on few levels a channel (dithered or posterised).
    few_levels: bool,
    /// The σ of the noise read under every map, where that is its trace.
    noise: Option<f64>,
}

/// The filter's maps of `material` stored lossily: those its files' formats say
/// (`Material::lossy`), those whose texels show BC blocks, a JPEG's grid or few levels, and
/// where a grid or few levels are found so, the maps saved losslessly beside them:
/// - a JPEG's grid in a lossless file means a set saved again (DamagedHelmet's crops kept as
///   PNG), and the grid shows less in smooth maps (crop C's metallic map, its grid unseen, drew
///   6.7× bicubic's invented structure through the material network;
///   docs/experiments/2026-11-29-degraded-inputs.md);
/// - few levels mean a set dithered or posterised together (a 16-bit game texture set), whose
///   normals (renormalised when read) and narrow maps show no ladder: left clean beside a
///   dithered colour, they cost 2.4 dB on Metal053C (docs/experiments/2026-12-02-texel-traces.md).
///   The height is read as a witness too.
///
/// A BC map's neighbours are read for themselves: BC4 blocks hide in smooth maps because they
/// cost them nothing.
fn lossy_maps(material: &Material, tileable: bool) -> Vec<LossyMap> {
    let mut lossy: Vec<LossyMap> = (material.lossy.iter())
        .filter(|(kind, _)| FEATURE_MAPS.contains(kind))
        .map(|(&kind, storage)| LossyMap {
            kind,
            what: format!("{kind} from {storage}"),
            jpeg: FileFormat::is_jpeg_storage(storage),
            few_levels: false,
            noise: None,
        })
        .collect();
    let stand_ins = material.stand_ins();
    let by_texels: Vec<LossyMap> = (FEATURE_MAPS.into_iter())
        .filter(|kind| !material.lossy.contains_key(kind))
        .filter_map(|kind| {
            let trace = texel_trace(kind, material.map(kind)?, tileable)?;
            Some(LossyMap {
                kind,
                what: format!("{trace} found in {}'s texels", file_name(material, kind)),
                jpeg: trace.is_jpeg(),
                few_levels: matches!(trace, TexelTrace::Quantised(_)),
                noise: None,
            })
        })
        .collect();
    let height_levels = (!stand_ins.contains(&MapKind::Height))
        .then(|| material.map(MapKind::Height))
        .flatten()
        .and_then(|height| quantised_trace(MapKind::Height, height, tileable))
        .map(|trace| LossyMap {
            kind: MapKind::Height,
            what: format!(
                "{} found in {}'s texels",
                TexelTrace::Quantised(trace),
                file_name(material, MapKind::Height)
            ),
            jpeg: false,
            few_levels: true,
            noise: None,
        });
    let beside_what = if by_texels.iter().any(|m| m.jpeg) {
        Some(("a JPEG, as a JPEG of the same set", true))
    } else if by_texels.iter().chain(&height_levels).any(|m| m.few_levels) {
        Some((
            "a map of few levels, as one set dithered or posterised",
            false,
        ))
    } else {
        None
    };
    let beside: Vec<LossyMap> = match beside_what {
        Some((what, jpeg)) => (FEATURE_MAPS.into_iter())
            .filter(|kind| !material.lossy.contains_key(kind) && !stand_ins.contains(kind))
            .filter(|kind| by_texels.iter().all(|m| m.kind != *kind))
            .map(|kind| LossyMap {
                kind,
                what: format!("{kind} saved losslessly beside {what}"),
                jpeg,
                few_levels: false,
                noise: None,
            })
            .collect(),
        None => Vec::new(),
    };
    lossy.extend(by_texels);
    lossy.extend(height_levels);
    lossy.extend(beside);
    let noisy = noisy_maps(material, tileable, &lossy);
    lossy.extend(noisy);
    lossy
}

/// The name of the file `material`'s map of `kind` came from, else the map's name.
fn file_name(material: &Material, kind: MapKind) -> String {
    (material.origin.as_ref())
        .and_then(|o| o.source(kind))
        .and_then(|f| f.path.file_name())
        .map_or_else(
            || kind.to_string(),
            |name| name.to_string_lossy().into_owned(),
        )
}

/// Where one noise lies under all of the material's own maps, its height too
/// ([`matup_core::texel_trace::noise_floor`]; stand-ins are flat, not clean), the filter maps
/// not read as lossily stored already: noise costs the material network as blocks do (σ 3 of
/// noise, docs/experiments/2026-12-02-texel-traces.md).
fn noisy_maps(material: &Material, tileable: bool, lossy: &[LossyMap]) -> Vec<LossyMap> {
    let stand_ins = material.stand_ins();
    let own: Vec<(MapKind, &Map)> = (FEATURE_MAPS.into_iter().chain([MapKind::Height]))
        .filter(|kind| !stand_ins.contains(kind))
        .filter_map(|kind| Some((kind, material.map(kind)?)))
        .collect();
    let Some(floor) = noise_floor(&own, tileable) else {
        return Vec::new();
    };
    (own.into_iter())
        .filter(|(kind, _)| FEATURE_MAPS.contains(kind))
        .filter(|(kind, _)| lossy.iter().all(|m| m.kind != *kind))
        .map(|(kind, _)| LossyMap {
            kind,
            what: format!("{floor}, found in their texels"),
            jpeg: false,
            few_levels: false,
            noise: Some(floor.sigma),
        })
        .collect()
}

impl Plan {
    /// Plans a run of `material` with `settings`: refused, saying why, where the settings
    /// cannot run (a bad value, an unknown or unfitting upsampler or shading model, a size
    /// that cannot be reached).
    pub fn new(material: &Material, settings: &Config) -> Result<Plan> {
        settings.validate()?;
        let reach = Reach::of(settings, [material.width(), material.height_px()])?;
        let tiling = Tiling::of(material, settings);
        let input = InputRoute::of(material, settings, tiling.tileable);
        let resolved = Config {
            scale: reach.scale,
            size: None,
            ..input.settings(settings)
        };
        let candidates = match resolved.select {
            Selection::Off => Vec::new(),
            _ => (candidates(&resolved).into_iter())
                .map(|c| Ok((c.name, Setup::new(c.config)?)))
                .collect::<Result<_>>()?,
        };
        Ok(Plan {
            asked_size: settings.size,
            reach,
            tiling,
            input,
            shading: Arc::from(shading_model(&settings.shading.parse::<PluginSpec>()?)?),
            lights: settings.lights.build(),
            setup: Setup::new(resolved)?,
            candidates,
        })
    }

    /// This plan for another material (a folder's images of another size than its maps),
    /// upsampled to `size` where one is asked for: its own reach and tiling, the same setup
    /// where the reach's scale is the same.
    pub fn for_other_material(
        &self,
        material: &Material,
        size: Option<TargetSize>,
    ) -> Result<Plan> {
        let settings = Config {
            size,
            ..self.reported_settings()
        };
        let reach = Reach::of(&settings, [material.width(), material.height_px()])?;
        if reach.scale != self.reach.scale {
            return Plan::new(material, &settings);
        }
        Ok(Plan {
            asked_size: size,
            reach,
            tiling: Tiling::of(material, &settings),
            ..self.clone()
        })
    }

    /// The output's size for the `input`-sized material planned: [width, height].
    pub fn output_size(&self, input: [usize; 2]) -> [usize; 2] {
        self.reach.output_size(input)
    }

    /// The settings as the run reports them: as run, with the size asked for.
    pub fn reported_settings(&self) -> Config {
        Config {
            size: self.asked_size,
            ..self.setup.settings.clone()
        }
    }
}

impl Setup {
    /// The setup of `settings`, already validated and resolved to a scale.
    fn new(settings: Config) -> Result<Setup> {
        let (upsampler_name, upsampler) = choose_upsampler(&settings)?;
        let apart = upsamplers_apart(&settings, &upsampler_name)?;
        let clean_normals = match settings.filter.normal_blend_noise > 0.0 {
            false => None,
            true if settings.upsampler != "auto" => None,
            true => {
                // As the clean route runs: back-projected.
                let mut clean = Config {
                    input_quality: InputQuality::Clean,
                    map_input_quality: Default::default(),
                    ..settings.clone()
                };
                clean.filter.back_project = true;
                let (name, upsampler) = choose_upsampler(&clean)?;
                Some(MapUpsampler {
                    kind: MapKind::Normal,
                    name,
                    upsampler: Arc::from(upsampler),
                })
            }
        };
        let levels = (levels_of(settings.scale).into_iter().enumerate())
            .map(|(level, scale)| Level {
                scale,
                settings: settings.at_level(level, scale, upsampler.native_scale()),
            })
            .collect();
        Ok(Setup {
            settings,
            levels,
            upsampler: Arc::from(upsampler),
            upsampler_name,
            apart,
            clean_normals,
        })
    }

    /// Where each upsampler that says so computes, and why, once each:
    /// `onnx:span_x4_materials: wgpu on llvmpipe (…) (Vulkan, software adapter): device=gpu:llvmpipe asked for it`.
    pub fn placements(&self) -> Vec<String> {
        let mut lines: Vec<String> = Vec::new();
        let chosen = std::iter::once((&self.upsampler_name, &self.upsampler))
            .chain(self.apart.iter().map(|a| (&a.name, &a.upsampler)))
            .chain(self.clean_normals.iter().map(|c| (&c.name, &c.upsampler)));
        for (name, upsampler) in chosen {
            if let Some(placement) = upsampler.placement() {
                let line = format!("{name}: {placement}");
                if !lines.contains(&line) {
                    lines.push(line);
                }
            }
        }
        lines
    }

    /// The upsamplers that make the maps, in words: the run's, then each other one with the
    /// maps it makes (`onnx:span_x4_jpeg; normal, metallic: onnx:span_x4_materials`), then the
    /// clean route's for a noisy material's normals.
    pub fn upsamplers_used(&self) -> String {
        let mut words = self.upsampler_name.clone();
        for (name, kinds) in maps_by(self.apart.iter().map(|a| (a.name.as_str(), a.kind))) {
            words += &format!("; {}: {name}", kinds.join(", "));
        }
        if let Some(clean) = &self.clean_normals {
            words += &format!("; normal, blended in past the noise: {}", clean.name);
        }
        words
    }
}

/// Maps grouped by what they share (a quality, an upsampler's name), in order of first
/// appearance, each map in words.
fn maps_by<K: PartialEq>(pairs: impl Iterator<Item = (K, MapKind)>) -> Vec<(K, Vec<String>)> {
    let mut groups: Vec<(K, Vec<String>)> = Vec::new();
    for (key, kind) in pairs {
        match groups.iter_mut().find(|(k, _)| *k == key) {
            Some((_, kinds)) => kinds.push(kind.to_string()),
            None => groups.push((key, vec![kind.to_string()])),
        }
    }
    groups
}

/// Where `upsampler` is `auto`, the maps `map_input_quality` routes apart whose choice
/// ([`choose_upsampler`] for their quality) is not `run_name`'s, each with it, loaded once for
/// each quality.
fn upsamplers_apart(settings: &Config, run_name: &str) -> Result<Vec<MapUpsampler>> {
    let mut apart = Vec::new();
    if settings.upsampler != "auto" {
        return Ok(apart);
    }
    // Each quality's choice, loaded once.
    let mut chosen: Vec<(InputQuality, MapUpsampler)> = Vec::new();
    for (&kind, &quality) in &settings.map_input_quality {
        if quality == settings.input_quality {
            continue;
        }
        let made = match chosen.iter().find(|(q, _)| *q == quality) {
            Some((_, made)) => made.clone(),
            None => {
                let for_quality = Config {
                    input_quality: quality,
                    ..settings.clone()
                };
                let (name, upsampler) = choose_upsampler(&for_quality)?;
                let upsampler = Arc::from(upsampler);
                chosen.push((
                    quality,
                    MapUpsampler {
                        kind,
                        name,
                        upsampler,
                    },
                ));
                chosen.last().expect("just pushed").1.clone()
            }
        };
        if made.name != run_name {
            apart.push(MapUpsampler { kind, ..made });
        }
    }
    Ok(apart)
}

/// Refuses settings that cannot run on any material (a bad value, an unknown upsampler or
/// shading model) before a sweep or a batch begins: the checks of [`Plan::new`] that do not
/// depend on the material.
pub fn check_settings(settings: &Config) -> Result<()> {
    settings.validate()?;
    shading_model(&settings.shading.parse::<PluginSpec>()?)?;
    choose_upsampler(settings)?;
    Ok(())
}

/// How a run reaches its output size: the whole scale its levels make, and the size that
/// output is then shrunk to where the size asked for is no whole scale.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Reach {
    pub scale: usize,
    pub shrink_to: Option<[usize; 2]>,
}

impl Reach {
    /// How a run of an `input`-sized material reaches its output: the settings' `scale`, or
    /// where a `size` is asked for, the smallest supported scale that reaches it and the
    /// shrink to it. A size smaller than the input, past ×16, or of another shape than the
    /// input is refused.
    pub fn of(settings: &Config, input: [usize; 2]) -> Result<Reach> {
        let Some(size) = settings.size else {
            return Ok(Reach {
                scale: settings.scale,
                shrink_to: None,
            });
        };
        let [w, h] = input;
        let target = match size.height {
            Some(height) => [size.width, height],
            None if w == h => [size.width; 2],
            None => {
                return Err(Error::Invalid(format!(
                    "size {size}: the input is {w}×{h}, not square; give both sides \
                     (--size {}x{}) or a --scale",
                    size.width,
                    size.width * h / w
                )))
            }
        };
        // Sides rounded by one texel to keep the shape are the same ratio.
        if target[0].abs_diff(target[1] * w / h) > 1 && target[1].abs_diff(target[0] * h / w) > 1 {
            return Err(Error::Invalid(format!(
                "size {size}: {}×{} is not the shape of the {w}×{h} input",
                target[0], target[1]
            )));
        }
        if target[0] <= w || target[1] <= h {
            return Err(Error::Invalid(format!(
                "size {size}: not larger than the {w}×{h} input (matup upsamples only)"
            )));
        }
        let reaches = |s: usize| w * s >= target[0] && h * s >= target[1];
        let Some(&scale) = SCALES.iter().find(|&&s| reaches(s)) else {
            return Err(Error::Invalid(format!(
                "size {size}: more than ×16 of the {w}×{h} input"
            )));
        };
        let exact = [w * scale, h * scale] == target;
        Ok(Reach {
            scale,
            shrink_to: (!exact).then_some(target),
        })
    }

    /// The output's size for an input of `input` texels.
    pub fn output_size(&self, input: [usize; 2]) -> [usize; 2] {
        self.shrink_to.unwrap_or(input.map(|n| n * self.scale))
    }

    /// The route in words, for the note and `run.json`: `×4` or `×2, then area-shrunk to
    /// 1536×1536`.
    pub fn describe(&self) -> String {
        match self.shrink_to {
            Some([w, h]) => format!("×{}, then area-shrunk to {w}×{h}", self.scale),
            None => format!("×{}", self.scale),
        }
    }
}

/// SPAN tuned for material maps (models/README.md has its card). It was trained and measured
/// through the per-map base back-projected onto the LR maps, and only there beats stock SPAN:
/// each map on its own it loses (docs/experiments/2026-11-25-blend-default.md), and renders are not what it
/// learned. So `auto` runs it first only where [`Config::upsamples_maps_only`], back-projected.
pub const MATERIAL_NETWORK: &str = "onnx:span_x4_materials";

/// SPAN tuned for material maps further, on inputs degraded as lossy files degrade them (JPEG,
/// BC blocks, noise; models/README.md has its card), its outputs scored unprojected. `auto`
/// runs it first where the input is degraded ([`InputRoute`]) and the per-map base is the result.
pub const DEGRADED_NETWORK: &str = "onnx:span_x4_degraded";

/// SPAN tuned further on JPEG inputs alone, from [`DEGRADED_NETWORK`] (models/README.md has
/// its card). `auto` runs it first where every lossy map is a JPEG ([`InputRoute`]), its base
/// colour projected onto the input's low frequencies.
pub const JPEG_NETWORK: &str = "onnx:span_x4_jpeg";

/// What `upsampler = "auto"` tries otherwise (and after [`MATERIAL_NETWORK`], where a models
/// folder lacks it), best first: stock SPAN, then Lanczos.
pub const AUTO_UPSAMPLERS: [&str; 2] = ["onnx:span_x4_ch48", "lanczos3"];

/// The levels that make a supported `scale`: the scale itself for one level, else ×4 and then
/// the rest (a network's ×4 goes first, on the smaller input).
pub fn levels_of(scale: usize) -> Vec<usize> {
    if LEVEL_SCALES.contains(&scale) {
        vec![scale]
    } else {
        vec![4, scale / 4]
    }
}

/// `spec` on the run's `device`: an ONNX network that names no device of its own runs there
/// (the other upsamplers run on the CPU).
pub fn on_device(mut spec: PluginSpec, device: &str) -> PluginSpec {
    let names_one = (spec.argument.iter()).any(|a| a.split(',').any(|o| o.starts_with("device=")));
    if spec.name == "onnx" && !names_one {
        let argument = spec.argument.take().unwrap_or_default();
        spec.argument = Some(format!("{argument},device={device}"));
    }
    spec
}

/// The configured upsampler, or for `auto` the first that loads and supports every level's
/// scale: where the configuration only upsamples maps, [`JPEG_NETWORK`] (then
/// [`DEGRADED_NETWORK`]) for a JPEG input, [`DEGRADED_NETWORK`] for an otherwise degraded one,
/// else [`MATERIAL_NETWORK`] where the maps are back-projected; then [`AUTO_UPSAMPLERS`].
pub fn choose_upsampler(config: &Config) -> Result<(String, Box<dyn RgbUpsampler>)> {
    let levels = levels_of(config.scale);
    // The upsampler `spec` names, or the one `config.networks` runs in its place, with the
    // name the run reports.
    let fits = |spec: &str| -> Result<(String, Box<dyn RgbUpsampler>)> {
        let (name, spec) = match run_instead(config, spec) {
            Some(instead) => (format!("{spec} as {instead}"), instead.as_str()),
            None => (spec.to_string(), spec),
        };
        let spec = on_device(spec.parse()?, &config.device);
        let up = upsampler(&spec)?;
        for &s in &levels {
            check_scale(&spec.name, up.as_ref(), s)?;
        }
        Ok((name, up))
    };
    if config.upsampler != "auto" {
        return fits(&config.upsampler);
    }
    // Each material network where it was trained for: the clean one back-projected, the
    // JPEG and degraded ones as their routes run them.
    let material: &[&str] = match config.input_quality {
        InputQuality::Jpeg => &[JPEG_NETWORK, DEGRADED_NETWORK],
        InputQuality::Degraded => &[DEGRADED_NETWORK],
        _ if config.filter.back_project => &[MATERIAL_NETWORK],
        _ => &[],
    };
    let material = material.iter().filter(|_| config.upsamples_maps_only());
    // A GPU adapter named: a network that cannot run there is an error, not Lanczos in its
    // place.
    let names_an_adapter = matches!(
        matup_core::device::DeviceSpec::parse(&config.device),
        Ok(matup_core::device::DeviceSpec::Gpu(_))
    );
    let mut last = None;
    for &spec in material.chain(&AUTO_UPSAMPLERS) {
        match fits(spec) {
            Ok(chosen) => return Ok(chosen),
            // What the caller gave must run: no other upsampler in its place.
            Err(e) if run_instead(config, spec).is_some() => return Err(e),
            Err(e) if names_an_adapter && spec.starts_with("onnx:") => return Err(e),
            Err(e) => last = Some(e),
        }
    }
    Err(last.expect("AUTO_UPSAMPLERS is not empty"))
}

/// The upsampler `config.networks` runs where `spec` names one of matup's networks.
fn run_instead<'a>(config: &'a Config, spec: &str) -> Option<&'a String> {
    (spec.strip_prefix("onnx:")).and_then(|name| config.networks.get(name))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_size_is_reached_by_the_smallest_scale_past_it() {
        let with = |size: &str| Config {
            size: Some(size.parse().unwrap()),
            ..Config::default()
        };
        let reach = |size: &str, input: [usize; 2]| Reach::of(&with(size), input);
        let exact = |scale| Reach {
            scale,
            shrink_to: None,
        };
        assert_eq!(reach("4K", [1024, 1024]).unwrap(), exact(4));
        assert_eq!(reach("2048", [1024, 1024]).unwrap(), exact(2));
        assert_eq!(reach("8192x4096", [1024, 512]).unwrap(), exact(8));
        // Between scales: the next one past, then shrunk.
        let between = reach("1536", [1024, 1024]).unwrap();
        assert_eq!(between.scale, 2);
        assert_eq!(between.shrink_to, Some([1536, 1536]));
        assert_eq!(between.output_size([1024, 1024]), [1536, 1536]);
        assert_eq!(between.describe(), "×2, then area-shrunk to 1536×1536");
        assert_eq!(reach("400", [128, 128]).unwrap().scale, 4);
        // Refused, saying why.
        for (size, input, why) in [
            ("1K", [1024, 1024], "not larger"),
            ("512", [1024, 1024], "not larger"),
            ("17K", [1024, 1024], "more than ×16"),
            ("2048", [1024, 512], "not square"),
            ("2048x2048", [1024, 512], "not the shape"),
        ] {
            let e = reach(size, input).unwrap_err().to_string();
            assert!(e.contains(why), "{size} of {input:?}: {e}");
        }
        for bad in ["", "0", "4M", "x512", "1.5K"] {
            assert!(bad.parse::<TargetSize>().is_err(), "{bad}");
        }
        // A scale alone is its own reach; the size round-trips through TOML.
        assert_eq!(Reach::of(&Config::default(), [64, 64]).unwrap(), exact(4));
        let c = with("4096x2048");
        assert_eq!(Config::from_toml(&c.to_toml(), "s.toml").unwrap(), c);
        assert_eq!(levels_of(16), vec![4, 4]);
        assert_eq!(levels_of(8), vec![4, 2]);
        assert_eq!(levels_of(3), vec![3]);
    }
}
