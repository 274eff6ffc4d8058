//! The 7 features the method works in, per texel: linear base colour, metallic, normal x and
//! y, alpha (roughness²). The residual base, the filter, the pipeline and `matup learn` pack
//! materials into them here.

use matup_core::map::Map;
use matup_core::material::{MapKind, Material};

/// The features the filter reads and answers, per texel: linear base colour (3), metallic,
/// normal x and y, alpha.
pub const FEATURES: usize = 7;
pub const FEATURE_NAMES: [&str; FEATURES] = [
    "base_r", "base_g", "base_b", "metallic", "normal_x", "normal_y", "alpha",
];
/// The feature that holds alpha (r²).
pub const ALPHA: usize = 6;

/// The 7 filter features of a material: linear base colour, metallic, normal x and y, alpha.
pub fn features(material: &Material) -> Map {
    let (w, h) = (material.width(), material.height_px());
    let mut features = Map::filled(w, h, FEATURES, 0.0);
    for kind in FEATURE_MAPS {
        pack_features(
            &mut features,
            kind,
            material.map(kind).expect("always present"),
        );
    }
    features
}

/// The maps the features come from.
pub const FEATURE_MAPS: [MapKind; 4] = [
    MapKind::BaseColor,
    MapKind::Metallic,
    MapKind::Normal,
    MapKind::Roughness,
];

/// The features that come from a map of `kind`: base colour 0–2, metallic 3, normal x and y
/// 4 and 5, roughness as alpha 6; none for maps of other kinds.
pub fn feature_range(kind: MapKind) -> Option<std::ops::Range<usize>> {
    match kind {
        MapKind::BaseColor => Some(0..3),
        MapKind::Metallic => Some(3..4),
        MapKind::Normal => Some(4..6),
        MapKind::Roughness => Some(ALPHA..ALPHA + 1),
        _ => None,
    }
}

/// Writes the features that come from `map`, a map of `kind`, into `features`
/// ([`feature_range`]): roughness as alpha (r², down to 0: the shading models clamp it where
/// they render), the others channel by channel; maps of other kinds hold no feature.
pub fn pack_features(features: &mut Map, kind: MapKind, map: &Map) {
    let Some(range) = feature_range(kind) else {
        return;
    };
    if kind == MapKind::Roughness {
        let alpha = features.plane_mut(ALPHA);
        for (a, &r) in alpha.iter_mut().zip(map.data()) {
            *a = r * r;
        }
        return;
    }
    for (from, to) in range.enumerate() {
        features.plane_mut(to).copy_from_slice(map.plane(from));
    }
}

/// The features of `lr_features` that are constant, with their value (kept, not learned, and
/// no input), when skipping is on.
pub fn constant_features(lr_features: &Map, skip: bool) -> [Option<f32>; FEATURES] {
    std::array::from_fn(|k| {
        (skip && lr_features.is_constant(k, 0.0)).then(|| lr_features.plane(k)[0])
    })
}
