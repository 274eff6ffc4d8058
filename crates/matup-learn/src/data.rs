//! Training pairs made as matup makes its inputs: a true material, cropped and turned by a
//! symmetry of the square (normals turning with it), and its box-filtered LR version
//! (`Material::box_downsample`, what `matup downsample` writes).

use std::path::Path;

use candle_core::{Device, Tensor};
use matup_core::{load_material, Dihedral, Error, LoadOptions, MapKind, Material, Result};
use matup_eval::baseline::encode_for_upsampler;
use matup_method::filter::FEATURES;
use matup_method::pipeline::{constant_features, features};
use rand::Rng;

use crate::shipped::IMAGES_PER_MATERIAL;
use crate::tiles::TileLayout;

/// Materials loaded from a corpus folder.
pub struct Corpus {
    pub names: Vec<String>,
    pub materials: Vec<Material>,
}

impl Corpus {
    /// Loads `names` from `folder` (each a material folder).
    pub fn load(folder: &Path, names: &[String]) -> Result<Corpus> {
        let materials = names
            .iter()
            .map(|name| load_material(Some(&folder.join(name)), &LoadOptions::default()))
            .collect::<Result<Vec<_>>>()?;
        Ok(Corpus {
            names: names.to_vec(),
            materials,
        })
    }
}

/// One training example: a true material and its LR version.
pub struct Pair {
    pub truth: Material,
    pub lr: Material,
}

impl Pair {
    /// `truth` and its box-filtered version, `scale` times smaller: what `matup downsample`
    /// writes (before its files quantise it).
    pub fn new(truth: Material, scale: usize) -> Pair {
        let lr = truth.box_downsample(scale);
        Pair { truth, lr }
    }
}

/// A random `size × size` crop of a random material, at a position that is a multiple of
/// `scale` (so its LR version is a crop of the whole material's), under a random symmetry.
/// A share `tiled_share` of them is cut into tiles, a second random crop in the grout
/// ([`TileLayout`]).
pub fn random_pair(
    corpus: &Corpus,
    size: usize,
    scale: usize,
    tiled_share: f64,
    rng: &mut impl Rng,
) -> Pair {
    let crop = random_crop(corpus, size, scale, rng);
    // Drawn only when asked for, so that runs without tiles draw what they always drew.
    let crop = if tiled_share > 0.0 && rng.random_bool(tiled_share) {
        let grout = random_crop(corpus, size, scale, rng);
        TileLayout::random(rng).cut(&crop, &grout)
    } else {
        crop
    };
    let symmetry = Dihedral::ALL[rng.random_range(0..8)];
    Pair::new(crop.transformed(symmetry), scale)
}

fn random_crop(corpus: &Corpus, size: usize, scale: usize, rng: &mut impl Rng) -> Material {
    let m = &corpus.materials[rng.random_range(0..corpus.materials.len())];
    let cells = |extent: usize| (extent - size) / scale + 1;
    let x0 = rng.random_range(0..cells(m.width())) * scale;
    let y0 = rng.random_range(0..cells(m.height_px())) * scale;
    m.crop(x0, y0, size, size)
}

/// The network inputs of LR materials, `[4B, 3, h, w]`: each map encoded as the per-map
/// upsampler sends it, in the order base colour, normal, roughness, metallic.
pub fn network_inputs(lrs: &[&Material], device: &Device) -> candle_core::Result<Tensor> {
    let (w, h) = (lrs[0].width(), lrs[0].height_px());
    let mut data = Vec::with_capacity(lrs.len() * IMAGES_PER_MATERIAL * 3 * w * h);
    for lr in lrs {
        for kind in [
            MapKind::BaseColor,
            MapKind::Normal,
            MapKind::Roughness,
            MapKind::Metallic,
        ] {
            let map = lr.map(kind).expect("every material has these maps");
            data.extend_from_slice(encode_for_upsampler(kind, map).data());
        }
    }
    Tensor::from_vec(data, (lrs.len() * IMAGES_PER_MATERIAL, 3, h, w), device)
}

/// The LR normal maps encoded as the per-map upsampler sends them, `[B, 3, h, w]`, and with
/// `height_guide` the LR height maps beside them, `[B, 1, h, w]`, centred on 0.5 (a height
/// map's level is arbitrary, so the guide is the same for every tile of a large map).
pub fn normal_inputs(
    lrs: &[&Material],
    height_guide: bool,
    device: &Device,
) -> Result<(Tensor, Option<Tensor>)> {
    let (w, h) = (lrs[0].width(), lrs[0].height_px());
    let normals: Vec<f32> = lrs
        .iter()
        .flat_map(|lr| {
            encode_for_upsampler(MapKind::Normal, &lr.normal)
                .data()
                .to_vec()
        })
        .collect();
    let normals = Tensor::from_vec(normals, (lrs.len(), 3, h, w), device)?;
    if !height_guide {
        return Ok((normals, None));
    }
    let mut heights = Vec::with_capacity(lrs.len() * w * h);
    for lr in lrs {
        let height = lr.height.as_ref().ok_or_else(|| {
            Error::Invalid("height_guide: a material without a height map".into())
        })?;
        heights.extend(height.data().iter().map(|v| v - 0.5));
    }
    let heights = Tensor::from_vec(heights, (lrs.len(), 1, h, w), device)?;
    Ok((normals, Some(heights)))
}

/// The 7 features of LR materials, `[B, 7, h, w]`, and per material the features that are
/// constant (held, not learned, as the pipeline holds them).
pub fn lr_features(
    lrs: &[&Material],
    device: &Device,
) -> candle_core::Result<(Tensor, Vec<[Option<f32>; FEATURES]>)> {
    let (w, h) = (lrs[0].width(), lrs[0].height_px());
    let mut data = Vec::with_capacity(lrs.len() * FEATURES * w * h);
    let mut fixed = Vec::with_capacity(lrs.len());
    for lr in lrs {
        let f = features(lr);
        fixed.push(constant_features(&f, true));
        data.extend_from_slice(f.data());
    }
    Ok((
        Tensor::from_vec(data, (lrs.len(), FEATURES, h, w), device)?,
        fixed,
    ))
}
