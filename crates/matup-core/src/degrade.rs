//! What the maps users bring have been through before they reach matup: block compression
//! (BC1, BC3, BC4, BC5, through matup's own DDS encoders), JPEG, dithering to few levels,
//! sensor noise, blur and sharpening halos. Each is applied to a map as its file stores it
//! (sRGB colour, normals as `(n + 1) / 2`, grey maps as values) and decoded back, so that
//! training (`matup learn`) and measurement (`matup bench`, `matup sweep`) see the inputs users
//! have, against a truth that stays clean.

use std::fmt;
use std::str::FromStr;

use rand::Rng;
use rand_distr::{Distribution, Normal, Poisson};
use serde::{Deserialize, Serialize};

use crate::file_format::{BlockQuality, DdsCodec, DdsFormat, FileFormat};
use crate::io::dds_file::{decode_dds, write_dds};
use crate::map::Map;
use crate::map_kind::MapKind;
use crate::material::Material;
use crate::resample::{gaussian_blur, Border};
use crate::{Error, Result};

/// A block-compression format of DDS files.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum BlockFormat {
    /// 4 bits a texel, RGB (DXT1): colour, and normals in older games.
    Bc1,
    /// RGB as BC1 with a separate alpha (DXT5).
    Bc3,
    /// One channel, 4 bits a texel: grey maps.
    Bc4,
    /// Two BC4 channels: normals' x and y, z rebuilt.
    Bc5,
}

impl BlockFormat {
    /// The DDS codec of this format.
    fn codec(self) -> DdsCodec {
        let name = match self {
            BlockFormat::Bc1 => "bc1",
            BlockFormat::Bc3 => "bc3",
            BlockFormat::Bc4 => "bc4",
            BlockFormat::Bc5 => "bc5",
        };
        DdsCodec::named(name).expect("a row of DDS_CODECS")
    }
}

/// JPEG's chroma subsampling.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum Subsampling {
    /// Chroma at half the resolution on both axes (most encoders' default).
    #[serde(rename = "420")]
    Half,
    /// Chroma at full resolution.
    #[serde(rename = "444")]
    Full,
}

/// How a map is dithered to few levels.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum DitherMethod {
    /// An 8 × 8 Bayer threshold matrix.
    Ordered,
    /// Floyd–Steinberg error diffusion.
    ErrorDiffusion,
}

/// One degradation of a stored map. Strengths are in the file's 8-bit levels and texels.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Degradation {
    /// Block compression (a grey map in BC1 or BC3 as grey RGB, a colour map in BC4 or BC5
    /// channel by channel).
    Block(BlockFormat),
    /// JPEG at `quality` (1–100); grey maps as grey JPEGs.
    Jpeg {
        quality: u8,
        subsampling: Subsampling,
    },
    /// Quantised to `levels` levels per channel.
    Dither { levels: u16, method: DitherMethod },
    /// Gaussian noise of standard deviation `sigma` levels.
    GaussianNoise { sigma: f32 },
    /// Photon (shot) noise: a value `v` becomes a Poisson count of mean `v · peak`, over `peak`.
    PoissonNoise { peak: f32 },
    /// A Gaussian blur of standard deviation `sigma` texels.
    Blur { sigma: f32 },
    /// An unsharp mask, `v + amount · (v − blur(v, sigma))`: the halos of oversharpened assets.
    Halo { sigma: f32, amount: f32 },
    /// Saved again as an 8-bit PNG: values rounded to 8 bits, and a lossy storage before it no
    /// longer in the file's format (a game's DDS unpacked, a JPEG kept as PNG); only its texels
    /// still tell (`crate::texel_trace`).
    SavedAsPng,
}

impl Degradation {
    /// The lossy file storage this degradation is, as
    /// [`crate::file_format::FileFormat::lossy_storage`] names it: "JPEG", "BC1 blocks".
    pub fn lossy_storage(&self) -> Option<String> {
        match *self {
            Degradation::Block(format) => format.codec().lossy_storage(),
            Degradation::Jpeg { .. } => FileFormat::Jpeg.lossy_storage(),
            _ => None,
        }
    }

    /// What the file is after this step, where the step decides it: `Some(None)` lossless
    /// (saved as PNG), `Some(Some(storage))` lossy; `None` where it leaves the file as it was.
    fn storage(&self) -> Option<Option<String>> {
        match self {
            Degradation::SavedAsPng => Some(None),
            d => d.lossy_storage().map(Some),
        }
    }

    /// `map` of `kind` degraded (a new map; the random draws of noise from `rng`).
    pub fn apply(&self, kind: MapKind, map: &Map, rng: &mut impl Rng) -> Result<Map> {
        let stored = to_stored(kind, map);
        let degraded = match *self {
            Degradation::Block(format) => block_round_trip(kind, &stored, format)?,
            Degradation::Jpeg {
                quality,
                subsampling,
            } => jpeg_round_trip(&stored, quality, subsampling)?,
            Degradation::Dither { levels, method } => dither(&stored, levels, method),
            Degradation::GaussianNoise { sigma } => {
                let normal = Normal::new(0.0, sigma / 255.0)
                    .map_err(|e| Error::Invalid(format!("Gaussian noise of sigma {sigma}: {e}")))?;
                per_value(&stored, |v| v + normal.sample(rng))
            }
            Degradation::PoissonNoise { peak } => {
                if !(peak > 0.0 && peak.is_finite()) {
                    return Err(Error::Invalid(format!(
                        "Poisson noise needs a positive peak, not {peak}"
                    )));
                }
                per_value(&stored, |v| {
                    let mean = (v.clamp(0.0, 1.0) * peak) as f64;
                    if mean <= 0.0 {
                        return 0.0;
                    }
                    let count: f64 = Poisson::new(mean).expect("a positive mean").sample(rng);
                    count as f32 / peak
                })
            }
            Degradation::Blur { sigma } => blurred(&stored, sigma),
            Degradation::SavedAsPng => per_value(&stored, |v| (v * 255.0).round() / 255.0),
            Degradation::Halo { sigma, amount } => {
                let blur = blurred(&stored, sigma);
                Map::from_fn(
                    stored.width(),
                    stored.height(),
                    stored.channels(),
                    |c, y, x| {
                        let i = y * stored.width() + x;
                        let v = stored.plane(c)[i];
                        v + amount * (v - blur.plane(c)[i])
                    },
                )
            }
        };
        Ok(from_stored(kind, &clamped(degraded)))
    }
}

/// Every map of `material` that files store as images (base colour, normal, roughness,
/// metallic, height), degraded by `degradation`. The maps a lossy file format would have
/// degraded so (JPEG, BC blocks) are marked so in [`Material::lossy`], as reading such files
/// marks them; noise, blur, halos and dithering leave no trace a file's format tells.
pub fn degrade_material(
    material: &Material,
    degradation: &MaterialDegradation,
    rng: &mut impl Rng,
) -> Result<Material> {
    let mut out = material.clone();
    // Each run of steps between resizes: every map through the whole run in turn, then the
    // material halved (which also forgets what its files were: it is saved again).
    for (i, run) in degradation
        .steps
        .split(|(s, _)| *s == Step::Halved)
        .enumerate()
    {
        if i > 0 {
            out = out.box_downsample(2);
            for kind in STORED_KINDS {
                if let Some(map) = out.map_mut(kind) {
                    *map = Degradation::SavedAsPng.apply(kind, map, rng)?;
                }
            }
        }
        for kind in STORED_KINDS {
            let Some(map) = out.map_mut(kind) else {
                continue;
            };
            let steps = steps_for(run, kind);
            for d in &steps {
                *map = d.apply(kind, map, rng)?;
            }
            if let Some(storage) = steps.iter().rev().find_map(Degradation::storage) {
                match storage {
                    Some(storage) => {
                        let simulated = format!("{storage} (simulated: {degradation})");
                        out.lossy.insert(kind, simulated)
                    }
                    None => out.lossy.remove(&kind),
                };
            }
        }
    }
    Ok(out)
}

/// The input a measurement upsamples: `truth` box-filtered to 1/`factor` of its size, through
/// `degradation` where one is named. A degradation that halves the maps after they were
/// stored (`jpeg75+half`) starts from the truth that many times less reduced, so that the
/// input still comes out at 1/`factor`.
pub fn degraded_input(
    truth: &Material,
    factor: usize,
    degradation: Option<&MaterialDegradation>,
    rng: &mut impl Rng,
) -> Result<Material> {
    let Some(degradation) = degradation else {
        return Ok(truth.box_downsample(factor));
    };
    let shrink = degradation.shrink();
    if !factor.is_multiple_of(shrink) {
        return Err(Error::Invalid(format!(
            "degradation '{degradation}' halves the maps after they are stored (to 1/{shrink} \
             in all), so the factor must be a multiple of {shrink}, not {factor}"
        )));
    }
    degrade_material(&truth.box_downsample(factor / shrink), degradation, rng)
}

/// The maps a degradation reaches: those files store as images.
pub const STORED_KINDS: [MapKind; 5] = [
    MapKind::BaseColor,
    MapKind::Normal,
    MapKind::Roughness,
    MapKind::Metallic,
    MapKind::Height,
];

/// A named degradation of every map of a material, as `matup bench --degrade` and a sweep's
/// `degrade` key name them:
/// - `bc1`, `bc3`: every map in that format; `bc4`, `bc5`: every map in BC4 (normals in BC5,
///   their z rebuilt); `dds`: as games ship them, BC1 colour, BC5 normals, BC4 grey maps;
/// - `jpegQ` (4:2:0) and `jpegQ-444`: every map a JPEG of quality Q;
/// - `noiseS`: Gaussian noise of S levels; `poissonP`: shot noise of peak P;
/// - `blurS`: a Gaussian blur of S texels; `haloA`: an unsharp mask of amount A (σ 1.5);
/// - `ditherN`, `ditherN-fs`: N levels, ordered or Floyd–Steinberg;
/// - any of them saved again as PNG after, with `-png` (`bc1-png`, `jpeg75-png`, `dds-png`):
///   as modders unpack a game's textures, its file no longer says what it went through;
/// - `half`: every map resized to half its size and saved again as PNG, as textures are
///   downsized after they were stored (`jpeg75+half`: a JPEG's grid and steps blurred away);
///   [`degraded_input`] cuts the input at twice the size first;
/// - several joined by `+` (`blur0.7+jpeg60`), applied in that order;
/// - any of them on one map alone, named by its file stem after `@` (`jpeg75@baseColor`: a
///   glTF model's JPEG colour beside its PNG maps).
#[derive(Clone, Debug, PartialEq)]
pub struct MaterialDegradation {
    name: String,
    /// Each step, with the maps it reaches (`None`: every stored map).
    steps: Vec<(Step, Option<Vec<MapKind>>)>,
}

/// One step of a named degradation: the same for every map, or as games store each kind.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Step {
    Every(Degradation),
    AsGamesShip,
    /// The whole material resized to half its size (each 2×2 texels' mean, base colour in
    /// linear light) and saved again as 8-bit PNG: a texture downsized after it was stored.
    Halved,
}

impl MaterialDegradation {
    /// The degradations each map of `kind` goes through, in order (resizes apart).
    pub fn for_kind(&self, kind: MapKind) -> Vec<Degradation> {
        steps_for(&self.steps, kind)
    }

    /// How many times larger than the input the maps it starts from are: 2 for each `half`.
    pub fn shrink(&self) -> usize {
        let halvings = self
            .steps
            .iter()
            .filter(|(s, _)| *s == Step::Halved)
            .count();
        1 << halvings
    }
}

/// The map degradations of `steps` that reach a map of `kind`, in order.
fn steps_for(steps: &[(Step, Option<Vec<MapKind>>)], kind: MapKind) -> Vec<Degradation> {
    (steps.iter())
        .filter(|(_, maps)| maps.as_ref().is_none_or(|maps| maps.contains(&kind)))
        .filter_map(|(step, _)| match *step {
            Step::Every(d) => Some(d),
            Step::AsGamesShip => Some(Degradation::Block(shipped_block_format(kind))),
            Step::Halved => None,
        })
        .collect()
}

/// The block format games store a map of `kind` in: BC5 for normals, BC4 for grey maps, BC1
/// for colour.
pub fn shipped_block_format(kind: MapKind) -> BlockFormat {
    match kind {
        MapKind::Normal => BlockFormat::Bc5,
        MapKind::BaseColor => BlockFormat::Bc1,
        _ => BlockFormat::Bc4,
    }
}

impl fmt::Display for MaterialDegradation {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.name)
    }
}

impl FromStr for MaterialDegradation {
    type Err = Error;

    fn from_str(text: &str) -> Result<Self> {
        let steps = text
            .split('+')
            .map(|part| parse_step_on_maps(part.trim()))
            .collect::<Result<Vec<_>>>()?
            .into_iter()
            .flatten()
            .collect();
        Ok(MaterialDegradation {
            name: text.to_string(),
            steps,
        })
    }
}

/// A step, and after `@` the one map it reaches (`jpeg75@baseColor`; another map takes the
/// step again, `+jpeg75@roughness`: a comma separates the runs of `--degrade`); a step named
/// with `-png` after (`bc1-png`) is that step, then [`Degradation::SavedAsPng`].
fn parse_step_on_maps(text: &str) -> Result<Vec<(Step, Option<Vec<MapKind>>)>> {
    let (step, maps) = match text.split_once('@') {
        None => (text, None),
        Some((step, map)) => {
            let kind = (MapKind::from_file_stem(map.trim()))
                .filter(|kind| STORED_KINDS.contains(kind))
                .ok_or_else(|| {
                    Error::Invalid(format!(
                        "degradation '{text}': no map '{map}'; maps: baseColor, normal, \
                         roughness, metallic, height"
                    ))
                })?;
            (step.trim(), Some(vec![kind]))
        }
    };
    if step == "half" {
        if maps.is_some() {
            return Err(Error::Invalid(format!(
                "degradation '{text}': 'half' resizes every map, it takes no '@'"
            )));
        }
        return Ok(vec![(Step::Halved, None)]);
    }
    Ok(match step.strip_suffix("-png") {
        Some(stored) => vec![
            (parse_step(stored)?, maps.clone()),
            (Step::Every(Degradation::SavedAsPng), maps),
        ],
        None => vec![(parse_step(step)?, maps)],
    })
}

fn parse_step(text: &str) -> Result<Step> {
    let bad = |why: &str| {
        Error::Invalid(format!(
            "degradation '{text}': {why}; known: bc1, bc3, bc4, bc5, dds, jpegQ, jpegQ-444, \
             noiseS, poissonP, blurS, haloA, ditherN, ditherN-fs (each saved again as PNG with \
             '-png' after, joined by '+', each on one map alone after '@'), half"
        ))
    };
    let integer = |digits: &str, range: std::ops::RangeInclusive<u16>, why: &str| {
        (digits.parse::<u16>().ok())
            .filter(|v| range.contains(v))
            .ok_or_else(|| bad(why))
    };
    let number = |rest: &str| -> Result<f32> {
        rest.parse::<f32>()
            .ok()
            .filter(|v| v.is_finite() && *v > 0.0)
            .ok_or_else(|| bad("its strength is not a positive number"))
    };
    let step = match text {
        "bc1" => Degradation::Block(BlockFormat::Bc1),
        "bc3" => Degradation::Block(BlockFormat::Bc3),
        "bc4" => Degradation::Block(BlockFormat::Bc4),
        "bc5" => Degradation::Block(BlockFormat::Bc5),
        "dds" => return Ok(Step::AsGamesShip),
        _ => {
            if let Some(rest) = text.strip_prefix("jpeg") {
                let (q, subsampling) = match rest.strip_suffix("-444") {
                    Some(q) => (q, Subsampling::Full),
                    None => (rest, Subsampling::Half),
                };
                Degradation::Jpeg {
                    quality: integer(q, 1..=100, "JPEG quality is 1 to 100")? as u8,
                    subsampling,
                }
            } else if let Some(rest) = text.strip_prefix("noise") {
                Degradation::GaussianNoise {
                    sigma: number(rest)?,
                }
            } else if let Some(rest) = text.strip_prefix("poisson") {
                Degradation::PoissonNoise {
                    peak: number(rest)?,
                }
            } else if let Some(rest) = text.strip_prefix("blur") {
                Degradation::Blur {
                    sigma: number(rest)?,
                }
            } else if let Some(rest) = text.strip_prefix("halo") {
                Degradation::Halo {
                    sigma: HALO_SIGMA,
                    amount: number(rest)?,
                }
            } else if let Some(rest) = text.strip_prefix("dither") {
                let (n, method) = match rest.strip_suffix("-fs") {
                    Some(n) => (n, DitherMethod::ErrorDiffusion),
                    None => (rest, DitherMethod::Ordered),
                };
                Degradation::Dither {
                    levels: integer(n, 2..=256, "dithering takes 2 to 256 levels")?,
                    method,
                }
            } else {
                return Err(bad("unknown"));
            }
        }
    };
    Ok(Step::Every(step))
}

/// The blur radius of a named halo (`haloA`): a sharpening filter's usual 1–2 texels.
const HALO_SIGMA: f32 = 1.5;

/// The map as its file stores it, in [0, 1] ([`MapKind::stored`]).
fn to_stored(kind: MapKind, map: &Map) -> Map {
    Map::from_fn(map.width(), map.height(), map.channels(), |c, y, x| {
        kind.stored(c, map.plane(c)[y * map.width() + x])
    })
}

/// [`to_stored`] undone; normals renormalised.
fn from_stored(kind: MapKind, stored: &Map) -> Map {
    let mut map = Map::from_fn(
        stored.width(),
        stored.height(),
        stored.channels(),
        |c, y, x| kind.from_stored(c, stored.plane(c)[y * stored.width() + x]),
    );
    if kind == MapKind::Normal && map.channels() == 3 {
        let [x, y, z] = map.planes_mut::<3>();
        for ((x, y), z) in x.iter_mut().zip(y.iter_mut()).zip(z.iter_mut()) {
            let length = (*x * *x + *y * *y + *z * *z).sqrt().max(1e-6);
            (*x, *y, *z) = (*x / length, *y / length, *z / length);
        }
    }
    map
}

fn clamped(map: Map) -> Map {
    map.map_values(|v| v.clamp(0.0, 1.0))
}

fn per_value(map: &Map, mut f: impl FnMut(f32) -> f32) -> Map {
    let data = map.data().iter().map(|&v| f(v)).collect();
    Map::from_planar(map.width(), map.height(), map.channels(), data)
}

fn blurred(map: &Map, sigma: f32) -> Map {
    let (w, h) = (map.width(), map.height());
    let data = (0..map.channels())
        .flat_map(|c| gaussian_blur(map.plane(c), w, h, sigma, Border::Mirror))
        .collect();
    Map::from_planar(w, h, map.channels(), data)
}

/// `channels` of `map` interleaved texel by texel, as encoders take them.
fn interleaved(map: &Map, channels: &[usize]) -> Vec<f32> {
    crate::io::stream::interleaved(channels.len(), map.height(), map.width(), |k, i| {
        map.plane(channels[k])[i]
    })
}

/// `stored` through a DDS file of `format` and back (matup's own writer and reader).
fn block_round_trip(kind: MapKind, stored: &Map, format: BlockFormat) -> Result<Map> {
    let (w, h, n) = (stored.width(), stored.height(), stored.channels());
    let through = |codec: DdsCodec, samples: Vec<f32>, channels: usize| -> Result<Map> {
        let format = DdsFormat {
            codec: Some(codec),
            srgb: Some(false),
            dx10: true,
            mipmaps: false,
        };
        let mut bytes = Vec::new();
        write_dds(
            &mut bytes,
            w,
            h,
            channels,
            samples,
            format,
            &[],
            BlockQuality::Normal,
        )
        .map_err(|e| Error::Invalid(format!("{format:?} of a {w}×{h} map: {e}")))?;
        decode_dds(bytes, std::path::Path::new("(in memory)")).map(|(map, _)| map)
    };
    let channels: Vec<usize> = (0..n.min(3)).collect();
    Ok(match (format, n) {
        // One grey channel as a grey RGB image; its decoded RGB averaged.
        (BlockFormat::Bc1 | BlockFormat::Bc3, 1) => {
            let rgb = interleaved(stored, &[0, 0, 0]);
            let decoded = through(format.codec(), rgb, 3)?;
            Map::from_fn(w, h, 1, |_, y, x| {
                let i = y * w + x;
                (0..3).map(|c| decoded.plane(c)[i]).sum::<f32>() / 3.0
            })
        }
        (BlockFormat::Bc1 | BlockFormat::Bc3, _) => {
            let decoded = through(format.codec(), interleaved(stored, &channels), 3)?;
            with_channels(stored, &decoded, &channels)
        }
        // A normal's x and y, its z rebuilt (the decoder rebuilds it).
        (BlockFormat::Bc5, 3) if kind == MapKind::Normal => {
            through(format.codec(), interleaved(stored, &[0, 1, 2]), 3)?
        }
        // BC5 is two BC4 channels: every other map channel by channel.
        (BlockFormat::Bc4 | BlockFormat::Bc5, _) => {
            let mut out = stored.clone();
            for c in channels {
                let decoded = through(BlockFormat::Bc4.codec(), stored.plane(c).to_vec(), 1)?;
                out.plane_mut(c).copy_from_slice(decoded.plane(0));
            }
            out
        }
    })
}

/// `stored` with its `channels` taken from `decoded`'s first ones.
fn with_channels(stored: &Map, decoded: &Map, channels: &[usize]) -> Map {
    let mut out = stored.clone();
    for (k, &c) in channels.iter().enumerate() {
        out.plane_mut(c).copy_from_slice(decoded.plane(k));
    }
    out
}

/// `stored` through a JPEG file and back: grey maps as grey JPEGs, others as RGB.
fn jpeg_round_trip(stored: &Map, quality: u8, subsampling: Subsampling) -> Result<Map> {
    let (w, h, n) = (stored.width(), stored.height(), stored.channels());
    let too_large = || Error::Invalid(format!("a {w}×{h} map is too large for a JPEG"));
    let (w16, h16) = (
        u16::try_from(w).map_err(|_| too_large())?,
        u16::try_from(h).map_err(|_| too_large())?,
    );
    let (channels, color): (Vec<usize>, _) = if n < 3 {
        (vec![0], jpeg_encoder::ColorType::Luma)
    } else {
        (vec![0, 1, 2], jpeg_encoder::ColorType::Rgb)
    };
    let bytes: Vec<u8> = interleaved(stored, &channels)
        .into_iter()
        .map(|v| (v.clamp(0.0, 1.0) * 255.0).round() as u8)
        .collect();
    let mut file = Vec::new();
    let mut encoder = jpeg_encoder::Encoder::new(&mut file, quality);
    encoder.set_sampling_factor(match subsampling {
        Subsampling::Half => jpeg_encoder::SamplingFactor::R_4_2_0,
        Subsampling::Full => jpeg_encoder::SamplingFactor::R_4_4_4,
    });
    encoder
        .encode(&bytes, w16, h16, color)
        .map_err(|e| Error::Invalid(format!("JPEG of a {w}×{h} map: {e}")))?;
    let decoded = image::load_from_memory_with_format(&file, image::ImageFormat::Jpeg)
        .map_err(|e| Error::Invalid(format!("JPEG of a {w}×{h} map reads back: {e}")))?;
    let decoded = if n < 3 {
        let grey = decoded.to_luma8();
        Map::from_planar(
            w,
            h,
            1,
            grey.pixels().map(|p| p[0] as f32 / 255.0).collect(),
        )
    } else {
        let rgb = decoded.to_rgb8();
        Map::from_fn(w, h, 3, |c, y, x| {
            rgb.get_pixel(x as u32, y as u32)[c] as f32 / 255.0
        })
    };
    Ok(with_channels(stored, &decoded, &channels))
}

/// `stored` quantised to `levels` levels per channel, dithered.
fn dither(stored: &Map, levels: u16, method: DitherMethod) -> Map {
    let (w, h) = (stored.width(), stored.height());
    let steps = (levels.max(2) - 1) as f32;
    let mut out = stored.clone();
    for c in 0..stored.channels() {
        let plane = out.plane_mut(c);
        match method {
            DitherMethod::Ordered => {
                for (i, v) in plane.iter_mut().enumerate() {
                    let (y, x) = (i / w, i % w);
                    let threshold = (BAYER_8[y % 8][x % 8] as f32 + 0.5) / 64.0 - 0.5;
                    *v = ((*v * steps + threshold).round() / steps).clamp(0.0, 1.0);
                }
            }
            DitherMethod::ErrorDiffusion => {
                for y in 0..h {
                    for x in 0..w {
                        let i = y * w + x;
                        let old = plane[i];
                        let new = ((old * steps).round() / steps).clamp(0.0, 1.0);
                        plane[i] = new;
                        let error = old - new;
                        let mut spread = |dy: usize, dx: isize, weight: f32| {
                            let xx = x as isize + dx;
                            if y + dy < h && (0..w as isize).contains(&xx) {
                                plane[(y + dy) * w + xx as usize] += error * weight;
                            }
                        };
                        spread(0, 1, 7.0 / 16.0);
                        spread(1, -1, 3.0 / 16.0);
                        spread(1, 0, 5.0 / 16.0);
                        spread(1, 1, 1.0 / 16.0);
                    }
                }
            }
        }
    }
    out
}

/// The 8 × 8 Bayer threshold matrix (0–63).
const BAYER_8: [[u8; 8]; 8] = [
    [0, 32, 8, 40, 2, 34, 10, 42],
    [48, 16, 56, 24, 50, 18, 58, 26],
    [12, 44, 4, 36, 14, 46, 6, 38],
    [60, 28, 52, 20, 62, 30, 54, 22],
    [3, 35, 11, 43, 1, 33, 9, 41],
    [51, 19, 59, 27, 49, 17, 57, 25],
    [15, 47, 7, 39, 13, 45, 5, 37],
    [63, 31, 55, 23, 61, 29, 53, 21],
];

#[cfg(test)]
mod tests;
