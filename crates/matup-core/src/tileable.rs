//! Whether a material tiles: the wrap-around seam ratio of its edges, and the threshold
//! measured on the shared materials. The pipeline picks its borders by it and evaluation
//! reports it.

use crate::material::Material;
use crate::resample::seam_ratio;

/// A material whose wrap-around seam ratio (see [`wrap_seam_ratio`]) stays below this tiles.
/// Measured on the shared materials box-filtered to 64²–256²: seamless ones read 1.0–1.7
/// (the shipped sample, a tileable pattern whose grooves meet the border, 2.02); crops of
/// them 1.65–5.5, every crop above 2.2 but the low-contrast leather's and one of wood, where
/// wrapping costs least; regular tiles whose joints lie on the border 2.3–18 whole (called not
/// tileable: `--tileable` forces it). Mirroring a tileable material breaks its tiling, so the
/// threshold errs toward tileable.
pub const TILEABLE_SEAM_RATIO: f32 = 2.2;

/// The wrap-around seam ratio of a material's base colour and normal (the larger): about 1
/// for tileable materials, well above for others.
pub fn wrap_seam_ratio(material: &Material) -> f32 {
    seam_ratio(&material.base_color).max(seam_ratio(&material.normal))
}

/// Whether a material tiles, judged from its edges, and the seam ratio that says so.
pub fn detect_tileable(material: &Material) -> (bool, f32) {
    let ratio = wrap_seam_ratio(material);
    (ratio < TILEABLE_SEAM_RATIO, ratio)
}
