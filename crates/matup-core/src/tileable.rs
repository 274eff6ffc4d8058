//! Whether a material tiles. Upscaling wraps its borders unless the edges give strong
//! evidence that the input does not tile ([`decide_tileable`]): mirroring a tileable material
//! puts a seam into its output, while wrapping a crop costs almost nothing anyone sees
//! (docs/experiments/2026-11-26-seamless-by-default.md). Evaluation keeps a plain guess
//! ([`detect_tileable`]) for the borders of its renders.

use crate::map::{Dihedral, Map};
use crate::material::{MapKind, Material};
use crate::resample::{box_downsample, row_difference, seam_ratio};

/// A material whose wrap-around seam ratio (see [`wrap_seam_ratio`]) stays below this is
/// guessed tileable by [`detect_tileable`]. Right for 61–66% of whole materials and crops
/// (docs/experiments/2026-11-25-tileability-detection.md): a guess for evaluation's renders,
/// not a decision for outputs.
pub const TILEABLE_SEAM_RATIO: f32 = 2.2;

/// The wrap-around seam ratio of a material's base colour and normal (the larger), at the
/// phase of a `period`-texel grid ([`seam_ratio`]): about 1 for tileable materials, well
/// above for others.
pub fn wrap_seam_ratio(material: &Material, period: usize) -> f32 {
    seam_ratio(&material.base_color, period).max(seam_ratio(&material.normal, period))
}

/// Whether a material tiles, guessed from its wrap-around seam ratio, and the ratio.
pub fn detect_tileable(material: &Material) -> (bool, f32) {
    let ratio = wrap_seam_ratio(material, 1);
    (ratio < TILEABLE_SEAM_RATIO, ratio)
}

/// [`decide_tileable`] mirrors only where the wrap-around step exceeds the largest interior
/// step by this factor on both axes. Whole materials read at most 1.02 (MetalPlates007) on
/// both axes and 1.11 on either, at 64²–1K²; a fifth of crops read above 1.25.
pub const SEAM_OVER_LARGEST_STEP: f32 = 1.25;

/// How the wrap-around edge compares with the interior, along each axis: the median over the
/// material's varying maps of the wrap-around step over the largest step between interior
/// neighbours (rows, then columns). At most about 1 where the material tiles: a tile grid's
/// border joint is no larger than its other joints. A crop's edge joins unrelated content and
/// often reads well above 1.
pub fn wrap_evidence(material: &Material) -> [f32; 2] {
    let mut per_axis: [Vec<f32>; 2] = [Vec::new(), Vec::new()];
    for (_, map) in judged_maps(material) {
        per_axis[0].push(edge_over_largest_step(&map));
        per_axis[1].push(edge_over_largest_step(
            &map.transformed(Dihedral::TRANSPOSE),
        ));
    }
    per_axis.map(|mut v| {
        if v.is_empty() {
            return 1.0;
        }
        v.sort_by(f32::total_cmp);
        let n = v.len();
        if n % 2 == 1 {
            v[n / 2]
        } else {
            0.5 * (v[n / 2 - 1] + v[n / 2])
        }
    })
}

/// Whether to treat a material as tileable by default, weighing what each wrong guess costs,
/// and the evidence ([`wrap_evidence`], the lesser axis). Tileable unless both axes read above
/// [`SEAM_OVER_LARGEST_STEP`].
pub fn decide_tileable(material: &Material) -> (bool, f32) {
    let [rows, columns] = wrap_evidence(material);
    let evidence = rows.min(columns);
    (evidence <= SEAM_OVER_LARGEST_STEP, evidence)
}

/// The maps tiling is judged on: base colour, normal, roughness, metallic and height where
/// they vary and are at least 4² (those the thresholds were measured on), each box-filtered to
/// 256² at most: a box filter keeps a tiling and a crop's edge alike, and texel noise matters
/// less.
pub fn judged_maps(material: &Material) -> Vec<(MapKind, Map)> {
    let kinds = [
        MapKind::BaseColor,
        MapKind::Normal,
        MapKind::Roughness,
        MapKind::Metallic,
        MapKind::Height,
    ];
    let varies = |map: &Map| (0..map.channels()).any(|c| !map.is_constant(c, 0.0));
    (kinds.into_iter())
        .filter_map(|kind| Some((kind, material.map(kind)?)))
        .filter(|(_, map)| map.width() >= 4 && map.height() >= 4 && varies(map))
        .map(|(kind, map)| {
            let mut factor = 1;
            while map.width().min(map.height()) / factor > 256
                && map.width() % (2 * factor) == 0
                && map.height() % (2 * factor) == 0
            {
                factor *= 2;
            }
            (kind, box_downsample(map, factor))
        })
        .collect()
}

/// The mean |difference| between the last row and the first over the largest mean |difference|
/// between neighbouring interior rows.
fn edge_over_largest_step(map: &Map) -> f32 {
    let h = map.height();
    let largest = (0..h - 1)
        .map(|k| row_difference(map, k, k + 1))
        .fold(0.0, f64::max);
    let edge = row_difference(map, h - 1, 0);
    if largest <= 1e-12 {
        return if edge <= 1e-12 { 1.0 } else { f32::INFINITY };
    }
    (edge / largest) as f32
}

#[cfg(test)]
mod tests {
    use super::*;

    fn material(base_color: Map) -> Material {
        let mut m = Material::uniform(base_color.width(), [0.5; 3], 0.5, 0.0);
        m.base_color = base_color;
        m
    }

    #[test]
    fn a_tile_grid_whose_joint_lies_on_the_border_is_tileable() {
        // Tiles of 16 texels with a dark joint along their first row and column: the
        // wrap-around step is a joint, like every interior joint.
        let tile = |y: usize, x: usize| {
            if x.is_multiple_of(16) || y.is_multiple_of(16) {
                0.1
            } else {
                0.8
            }
        };
        let noise = |y: usize, x: usize| ((x * 7919 + y * 104729) % 97) as f32 / 970.0;
        let grid = Map::from_fn(64, 64, 3, |_, y, x| tile(y, x) + noise(y, x));
        let (tileable, evidence) = decide_tileable(&material(grid.clone()));
        assert!(tileable, "{evidence}");
        // The old guess calls it a crop.
        assert!(!detect_tileable(&material(grid)).0);
    }

    #[test]
    fn a_smooth_crop_is_not_tileable() {
        // A gradient cut from a larger image: its edges join values far apart, beyond any
        // interior step.
        let ramp = Map::from_fn(64, 64, 3, |_, y, x| (x + y) as f32 / 128.0);
        let (tileable, evidence) = decide_tileable(&material(ramp));
        assert!(!tileable);
        assert!(evidence > 10.0, "{evidence}");
        // Along one axis only (a plank strip that tiles across), it stays tileable.
        let strip = Map::from_fn(64, 64, 3, |_, _, x| x as f32 / 64.0);
        assert!(decide_tileable(&material(strip)).0);
    }
}
