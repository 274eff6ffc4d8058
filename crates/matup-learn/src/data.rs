//! Training pairs made as matup makes its inputs: a true material, cropped and turned by a
//! symmetry of the square (normals turning with it), and its box-filtered LR version
//! (`Material::box_downsample`, what `matup downsample` writes).

use std::path::Path;

use candle_core::{Device, Tensor};
use matup_core::{load_material, Dihedral, Error, LoadOptions, MapKind, Material, Result};
use matup_method::filter::FEATURES;
use matup_method::per_map::encode_for_upsampler;
use matup_method::pipeline::{constant_features, features};
use rand::Rng;

use crate::floor_tiles::TileLayout;
use crate::post_process::IMAGES_PER_MATERIAL;

/// Materials loaded from a corpus folder.
pub struct Corpus {
    pub names: Vec<String>,
    pub materials: Vec<Material>,
}

impl Corpus {
    /// Loads `names` from `folder` (each a material folder), each at least `extent` texels
    /// wide and high (what its crops need).
    pub fn load(folder: &Path, names: &[String], extent: usize) -> Result<Corpus> {
        if !folder.is_dir() {
            return Err(Error::file(
                folder,
                "no such corpus folder: put the training materials there, one folder of maps \
                 each, named as the configuration's train and val lists name them",
            ));
        }
        let materials = names
            .iter()
            .map(|name| {
                let path = folder.join(name);
                let material = load_material(Some(&path), &LoadOptions::default())?;
                if material.width() < extent || material.height_px() < extent {
                    return Err(Error::file(
                        &path,
                        format!(
                            "{}×{} texels, smaller than the {extent}² its crops need",
                            material.width(),
                            material.height_px()
                        ),
                    ));
                }
                Ok(material)
            })
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
/// A share `shares.zoom_out` of the crops is taken at a coarser resolution, a share
/// `shares.tiled` of them is cut into tiles, a second random crop in the grout
/// ([`TileLayout`]).
pub fn random_pair(
    corpus: &Corpus,
    size: usize,
    scale: usize,
    shares: Shares,
    rng: &mut impl Rng,
) -> Pair {
    let crop = random_crop(corpus, size, scale, shares.zoom_out, rng);
    // Drawn only when asked for, so that runs without tiles draw what they always drew.
    let crop = if shares.tiled > 0.0 && rng.random_bool(shares.tiled) {
        let grout = random_crop(corpus, size, scale, shares.zoom_out, rng);
        TileLayout::random(rng).cut(&crop, &grout)
    } else {
        crop
    };
    let symmetry = Dihedral::ALL[rng.random_range(0..8)];
    Pair::new(crop.transformed(symmetry), scale)
}

/// The shares of the training crops that are altered: zoomed out, cut into tiles.
#[derive(Clone, Copy, Debug, Default)]
pub struct Shares {
    pub zoom_out: f64,
    pub tiled: f64,
}

/// How many times coarser than its material a zoomed-out crop is.
const ZOOM_OUT: usize = 2;

/// How large a material must be for crops of `size`: a zoomed-out crop is cut larger.
pub fn material_extent(size: usize, zoom_out_share: f64) -> usize {
    if zoom_out_share > 0.0 {
        ZOOM_OUT * size
    } else {
        size
    }
}

/// A crop of a random material; a share `zoom_out_share` of them is cut `ZOOM_OUT` times as
/// large and box-filtered to `size`, the material as a capture at half its resolution sees it:
/// its features twice as dense, its normals averaged (the corpus's materials each come at one
/// scale, the materials users bring at any).
fn random_crop(
    corpus: &Corpus,
    size: usize,
    scale: usize,
    zoom_out_share: f64,
    rng: &mut impl Rng,
) -> Material {
    // Drawn only when asked for, so that runs without zooming draw what they always drew.
    if zoom_out_share > 0.0 && rng.random_bool(zoom_out_share) {
        // At a multiple of `ZOOM_OUT · scale`, so that the LR version is a crop of the
        // whole material's zoomed-out LR version.
        return aligned_crop(corpus, ZOOM_OUT * size, ZOOM_OUT * scale, rng)
            .box_downsample(ZOOM_OUT);
    }
    aligned_crop(corpus, size, scale, rng)
}

fn aligned_crop(corpus: &Corpus, size: usize, step: usize, rng: &mut impl Rng) -> Material {
    let m = &corpus.materials[rng.random_range(0..corpus.materials.len())];
    let cells = |extent: usize| (extent - size) / step + 1;
    let x0 = rng.random_range(0..cells(m.width())) * step;
    let y0 = rng.random_range(0..cells(m.height_px())) * step;
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

#[cfg(test)]
mod tests {
    use super::*;
    use matup_core::Map;
    use rand::SeedableRng;

    /// The crops of `material` of `size` at multiples of `step`, under every symmetry, each
    /// box-filtered by `zoom` as a zoomed-out crop is.
    fn candidates(material: &Material, size: usize, step: usize, zoom: usize) -> Vec<Material> {
        let positions = (0..=(material.width() - size) / step).map(|i| i * step);
        let mut out = Vec::new();
        for y0 in positions.clone() {
            for x0 in positions.clone() {
                let crop = material.crop(x0, y0, size, size);
                let crop = if zoom > 1 {
                    crop.box_downsample(zoom)
                } else {
                    crop
                };
                out.extend(Dihedral::ALL.iter().map(|&t| crop.transformed(t)));
            }
        }
        out
    }

    #[test]
    fn a_share_of_the_crops_sees_the_material_at_half_its_resolution() {
        // Every texel different, so that a crop is known by its values; slanted normals.
        let mut material = Material::uniform(64, [0.5; 3], 0.5, 0.0);
        material.base_color = Map::from_fn(64, 64, 3, |c, y, x| {
            ((x * 7919 + y * 104_729 + c * 31) % 997) as f32 / 997.0
        });
        material.roughness = Map::from_fn(64, 64, 1, |_, y, x| 0.1 + ((x * y) % 17) as f32 / 20.0);
        material.normal = Map::from_fn(64, 64, 3, |c, y, x| {
            let (nx, ny) = (((x % 5) as f32 - 2.0) / 5.0, ((y % 3) as f32 - 1.0) / 4.0);
            [nx, ny, (1.0 - nx * nx - ny * ny).sqrt()][c]
        });
        let corpus = Corpus {
            names: vec!["varied".into()],
            materials: vec![material.clone()],
        };
        let plain = candidates(&material, 16, 4, 1);
        let halved = candidates(&material, 32, 8, 2);
        let draw = |zoom_out: f64, seed: u64| {
            let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
            let shares = Shares {
                zoom_out,
                ..Shares::default()
            };
            random_pair(&corpus, 16, 4, shares, &mut rng)
        };
        let mut zoomed = 0;
        for seed in 0..100 {
            let pair = draw(0.5, seed);
            assert_eq!(pair.lr, pair.truth.box_downsample(4));
            let is_plain = plain.contains(&pair.truth);
            let is_halved = halved.contains(&pair.truth);
            assert!(is_plain != is_halved, "seed {seed}: one or the other");
            zoomed += is_halved as usize;
            // Without zooming, every crop is plain, as runs before the key drew them.
            assert!(plain.contains(&draw(0.0, seed).truth));
        }
        assert!((35..=65).contains(&zoomed), "{zoomed} of 100 zoomed out");
    }

    #[test]
    fn a_material_too_small_for_its_crops_is_named() {
        let folder = tempfile::tempdir().unwrap();
        let small = Material::uniform(48, [0.5; 3], 0.5, 0.0);
        matup_core::save_material(
            &small,
            &folder.path().join("small"),
            &matup_core::SaveOptions::default(),
        )
        .unwrap();
        let error = Corpus::load(folder.path(), &["small".into()], 64)
            .err()
            .expect("too small");
        let message = error.to_string();
        assert!(
            message.contains("small") && message.contains("48×48"),
            "{message}"
        );
        assert!(Corpus::load(folder.path(), &["small".into()], 48).is_ok());
        // A corpus folder that is not there (the shared corpus of a configuration, on a clone
        // without it) says so, and what to put there.
        let absent = folder.path().join("corpus");
        let message = Corpus::load(&absent, &["small".into()], 48)
            .err()
            .expect("no folder")
            .to_string();
        assert!(
            message.contains("corpus") && message.contains("put the training materials there"),
            "{message}"
        );
    }
}
