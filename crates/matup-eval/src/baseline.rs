//! What users do without matup: every map upsampled on its own by an RGB upsampler, the way
//! an artist runs each texture file through Lanczos or an SR network.

use matup_core::color::{linear_to_srgb, srgb_to_linear};
use matup_core::io::{decode_normals, encode_normals};
use matup_core::map::Dihedral;
use matup_core::map::Map;
use matup_core::material::{restore_map_invariants, MapKind, Material, NormalConvention};
use matup_core::resample::Border;
use matup_core::upsample::RgbUpsampler;
use matup_core::{Error, Result};

/// Upsamples each map of `material` by `scale` with `upsampler`, as the map's file would be:
/// base colour sRGB-encoded, normals as `(n + 1) / 2` colours (io's own encoding), grey maps
/// as grey RGB images (the three results averaged back). Normals are renormalised and values
/// clamped after.
pub fn upscale_per_map(
    material: &Material,
    upsampler: &dyn RgbUpsampler,
    scale: usize,
    border: Border,
) -> Result<Material> {
    let mut out = material.clone();
    upscale_each_map(material, upsampler, scale, border, |kind, map| {
        *out.map_mut(kind).expect("present in the clone") = map;
        Ok(())
    })?;
    Ok(out)
}

/// [`upscale_per_map`] a map at a time: each map of `material` is upsampled, decoded and
/// handed to `each` before the next is upsampled, so a caller that packs them elsewhere never
/// holds all of them at the output size (at 8K² each map is 0.25–0.75 GB).
pub fn upscale_each_map(
    material: &Material,
    upsampler: &dyn RgbUpsampler,
    scale: usize,
    border: Border,
    mut each: impl FnMut(MapKind, Map) -> Result<()>,
) -> Result<()> {
    for kind in MapKind::ALL {
        let Some(map) = material.map(kind) else {
            continue;
        };
        let image = encode_for_upsampler(kind, map);
        let up = (upsampler
            .upsample(&[image], scale, border)?
            .into_iter()
            .next())
        .ok_or_else(|| Error::Invalid(format!("the upsampler returned no image for {kind:?}")))?;
        let want = (map.width() * scale, map.height() * scale);
        if (up.width(), up.height()) != want || up.channels() < 3 {
            return Err(Error::Invalid(format!(
                "the upsampler returned a {}×{}×{} image for the {}×{} {kind:?} map at ×{scale} \
                 (expected {}×{}×3)",
                up.width(),
                up.height(),
                up.channels(),
                map.width(),
                map.height(),
                want.0,
                want.1
            )));
        }
        let mut decoded = match kind {
            MapKind::BaseColor => up.map_values(|v| srgb_to_linear(v.clamp(0.0, 1.0))),
            MapKind::Normal => {
                let mut normals = up;
                decode_normals(&mut normals, NormalConvention::DirectX);
                normals
            }
            _ => {
                let (w, h) = (up.width(), up.height());
                Map::from_fn(w, h, 1, |_, y, x| {
                    (up.get(0, y, x) + up.get(1, y, x) + up.get(2, y, x)) / 3.0
                })
            }
        };
        restore_map_invariants(kind, &mut decoded);
        each(kind, decoded)?;
    }
    Ok(())
}

/// [`upscale_per_map`] under each of the eight symmetries of the square, turned back and
/// averaged (geometric self-ensemble, as SR papers report it): the material is mirrored and
/// transposed as a surface (normals turn with it, [`Material::transformed`]), so the normal
/// maps the network sees are real normal maps. Maps are averaged, normals renormalised after.
/// Eight times the cost of one pass.
pub fn upscale_per_map_ensemble(
    material: &Material,
    upsampler: &dyn RgbUpsampler,
    scale: usize,
    border: Border,
) -> Result<Material> {
    let mut sum: Option<Material> = None;
    for t in Dihedral::ALL {
        let up = upscale_per_map(&material.transformed(t), upsampler, scale, border)?
            .transformed(t.inverse());
        match sum.as_mut() {
            None => sum = Some(up),
            Some(total) => {
                for kind in MapKind::ALL {
                    if let (Some(a), Some(b)) = (total.map_mut(kind), up.map(kind)) {
                        a.data_mut()
                            .iter_mut()
                            .zip(b.data())
                            .for_each(|(a, b)| *a += b);
                    }
                }
            }
        }
    }
    let mut mean = sum.expect("eight symmetries");
    let n = Dihedral::ALL.len() as f32;
    for kind in MapKind::ALL {
        if let Some(m) = mean.map_mut(kind) {
            m.data_mut().iter_mut().for_each(|v| *v /= n);
        }
    }
    if mean.anisotropy_angle.is_some() {
        // Directions do not average as numbers; not what the ensemble is for.
        return Err(matup_core::Error::Invalid(
            "the self-ensemble does not handle anisotropy directions".into(),
        ));
    }
    mean.origin = material.origin.clone();
    mean.restore_invariants();
    Ok(mean)
}

/// A map of `kind` as the RGB image an upsampler sees: base colour sRGB-encoded, normals as
/// DirectX `(n + 1) / 2` colours, grey maps as grey RGB.
pub fn encode_for_upsampler(kind: MapKind, map: &Map) -> Map {
    match kind {
        MapKind::BaseColor => map.clone().map_values(linear_to_srgb),
        MapKind::Normal => encode_normals(map, NormalConvention::DirectX),
        _ => Map::stack(&[map, map, map]),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use matup_core::resample::{upsample, Kernel};

    struct Bilinear;
    impl RgbUpsampler for Bilinear {
        fn upsample(&self, images: &[Map], scale: usize, border: Border) -> Result<Vec<Map>> {
            Ok(images
                .iter()
                .map(|m| upsample(m, scale, Kernel::Bilinear, border))
                .collect())
        }
    }

    #[test]
    fn grey_maps_upsample_like_the_kernel_and_colours_stay() {
        let mut m = Material::uniform(8, [0.2, 0.4, 0.6], 0.5, 0.0);
        m.roughness = Map::from_fn(8, 8, 1, |_, y, x| 0.1 + 0.05 * ((x + y) % 5) as f32);
        let up = upscale_per_map(&m, &Bilinear, 4, Border::Wrap).unwrap();
        assert_eq!((up.width(), up.height_px()), (32, 32));
        let direct = upsample(&m.roughness, 4, Kernel::Bilinear, Border::Wrap);
        for (a, b) in up.roughness.data().iter().zip(direct.data()) {
            assert!((a - b).abs() < 1e-6);
        }
        // A constant colour survives the sRGB round trip.
        for (c, want) in [0.2, 0.4, 0.6].into_iter().enumerate() {
            assert!((up.base_color.mean(c) - want).abs() < 1e-5);
        }
        assert!((up.normal.mean(2) - 1.0).abs() < 1e-6);
    }
    #[test]
    fn an_upsampler_that_answers_the_wrong_size_is_an_error() {
        struct Twice;
        impl RgbUpsampler for Twice {
            fn upsample(&self, images: &[Map], _: usize, border: Border) -> Result<Vec<Map>> {
                Bilinear.upsample(images, 2, border)
            }
        }
        let m = Material::uniform(8, [0.2, 0.4, 0.6], 0.5, 0.0);
        let message = upscale_per_map(&m, &Twice, 4, Border::Wrap)
            .unwrap_err()
            .to_string();
        assert!(
            message.contains("16×16×3") && message.contains("expected 32×32×3"),
            "{message}"
        );
    }
}
