//! The 7 features the method works in, per texel: linear base colour, metallic, normal x and
//! y, alpha (roughness²). The residual base, the filter, the pipeline and `matup learn` pack
//! materials into them here.

use matup_core::map::Map;
use matup_core::material::{alpha_from_roughness, Material};

/// The features the filter reads and answers, per texel: linear base colour (3), metallic,
/// normal x and y, alpha.
pub const FEATURES: usize = 7;
pub const FEATURE_NAMES: [&str; FEATURES] = [
    "base_r", "base_g", "base_b", "metallic", "normal_x", "normal_y", "alpha",
];

/// The 7 filter features of a material: linear base colour, metallic, normal x and y, alpha.
pub fn features(material: &Material) -> Map {
    let alpha = material.roughness.clone().map_values(alpha_from_roughness);
    let normal_xy = material.normal.select_channels(&[0, 1]);
    Map::stack(&[&material.base_color, &material.metallic, &normal_xy, &alpha])
}

/// The features of `lr_features` that are constant, with their value (kept, not learned, and
/// no input), when skipping is on.
pub fn constant_features(lr_features: &Map, skip: bool) -> [Option<f32>; FEATURES] {
    std::array::from_fn(|k| {
        (skip && lr_features.is_constant(k, 0.0)).then(|| lr_features.plane(k)[0])
    })
}
