//! The per-map path's tests: the self-ensemble's turns, which maps the network upsamples,
//! flat and grey maps, an upsampler's wrong answer.

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

/// Bilinear, then every texel moved one column right (wrapping): an upsampler with a shift,
/// as a network may have one.
struct Shifted;
impl RgbUpsampler for Shifted {
    fn upsample(&self, images: &[Map], scale: usize, border: Border) -> Result<Vec<Map>> {
        Ok(Bilinear
            .upsample(images, scale, border)?
            .into_iter()
            .map(|m| shift_columns(&m, 1))
            .collect())
    }
}

fn shift_columns(m: &Map, by: isize) -> Map {
    let w = m.width() as isize;
    Map::from_fn(m.width(), m.height(), m.channels(), |c, y, x| {
        m.get(c, y, (x as isize - by).rem_euclid(w) as usize)
    })
}

/// Tilted normals, roughness and colour that vary over the texels.
fn varied_material() -> Material {
    let mut m = Material::uniform(8, [0.2, 0.4, 0.6], 0.5, 0.0);
    m.base_color = Map::from_fn(8, 8, 3, |c, y, x| 0.1 + 0.1 * ((x + 2 * y + c) % 8) as f32);
    m.roughness = Map::from_fn(8, 8, 1, |_, y, x| 0.1 + 0.08 * ((x * 3 + y) % 7) as f32);
    m.metallic = Map::from_fn(8, 8, 1, |_, y, x| ((x / 2 + y) % 2) as f32);
    m.normal = Map::from_fn(8, 8, 3, |c, y, x| {
        let (nx, ny) = (
            0.4 * ((x % 3) as f32 - 1.0),
            0.3 * ((y * 2 + x) % 3) as f32 - 0.3,
        );
        [nx, ny, (1.0 - nx * nx - ny * ny).sqrt()][c]
    });
    m
}

fn max_difference(a: &Map, b: &Map) -> f32 {
    (a.data().iter().zip(b.data()))
        .map(|(a, b)| (a - b).abs())
        .fold(0.0, f32::max)
}

#[test]
fn a_self_ensemble_turns_the_maps_back_so_a_symmetric_upsampler_gives_its_one_pass() {
    // Bilinear at ×4 with wrapping borders is the same under every symmetry of the square,
    // so averaging its eight passes changes nothing, unless a pass is not turned back (or
    // its normals not turned with the surface: x and y would then average toward zero).
    let m = varied_material();
    let once = upscale_per_map(&m, &Bilinear, 4, Border::Wrap).unwrap();
    for symmetries in [2, 4, 8] {
        let ensemble = SelfEnsemble {
            symmetries,
            maps: EnsembleMaps::All,
        };
        upscale_each_map(
            &m,
            &MapUpsamplers::one(&Bilinear),
            4,
            Border::Wrap,
            MapPasses {
                ensemble,
                upsampled: UpsampledMaps::All,
            },
            |kind, map| {
                let d = max_difference(&map, once.map(kind).unwrap());
                assert!(d < 1e-5, "{symmetries} symmetries, {kind:?}: {d}");
                Ok(())
            },
        )
        .unwrap();
    }
}

#[test]
fn a_self_ensemble_of_two_is_the_half_turn_and_cancels_a_shift() {
    // Under the half turn the shift to the right comes back as a shift to the left: the
    // pair averages the two, centred again.
    let m = varied_material();
    let plain = upscale_per_map(&m, &Bilinear, 4, Border::Wrap).unwrap();
    let shifted = upscale_per_map(&m, &Shifted, 4, Border::Wrap).unwrap();
    let centred = |map: &Map| {
        let (right, left) = (shift_columns(map, 1), shift_columns(map, -1));
        Map::from_fn(map.width(), map.height(), map.channels(), |c, y, x| {
            0.5 * (right.get(c, y, x) + left.get(c, y, x))
        })
    };
    for maps in [EnsembleMaps::All, EnsembleMaps::Normal] {
        let ensemble = SelfEnsemble {
            symmetries: 2,
            maps,
        };
        upscale_each_map(
            &m,
            &MapUpsamplers::one(&Shifted),
            4,
            Border::Wrap,
            MapPasses {
                ensemble,
                upsampled: UpsampledMaps::All,
            },
            |kind, map| {
                let d_shifted = max_difference(&map, shifted.map(kind).unwrap());
                if ensemble.covers(kind) {
                    assert!(d_shifted > 0.01, "{maps:?} {kind:?}: {d_shifted}");
                    if kind == MapKind::Roughness {
                        let d = max_difference(&map, &centred(&plain.roughness));
                        assert!(d < 1e-5, "{maps:?}: {d}");
                    }
                } else {
                    // Maps the ensemble leaves out are upsampled once, as without it.
                    assert_eq!(d_shifted, 0.0, "{maps:?} {kind:?}");
                }
                Ok(())
            },
        )
        .unwrap();
    }
    let err = SelfEnsemble {
        symmetries: 3,
        maps: EnsembleMaps::All,
    }
    .symmetries()
    .unwrap_err()
    .to_string();
    assert!(
        err.contains("1, 2, 4 or 8") && err.contains("not 3"),
        "{err}"
    );
}

#[test]
fn the_network_upsamples_every_map_by_default_or_the_normals_alone() {
    // A ×4 "network" (its native scale) that is bilinear and counts the images it is given.
    struct Network(std::sync::atomic::AtomicUsize);
    impl RgbUpsampler for Network {
        fn native_scale(&self) -> Option<usize> {
            Some(4)
        }
        fn upsample(&self, images: &[Map], scale: usize, border: Border) -> Result<Vec<Map>> {
            (self.0).fetch_add(images.len(), std::sync::atomic::Ordering::Relaxed);
            Bilinear.upsample(images, scale, border)
        }
    }
    let m = varied_material();
    let lanczos = KernelUpsampler::new(Kernel::Lanczos3);
    let by_lanczos = upscale_per_map(&m, &lanczos, 2, Border::Wrap).unwrap();
    let by_network = |upsampled, scale| {
        let network = Network(0.into());
        let mut maps = Vec::new();
        let passes = MapPasses {
            ensemble: SelfEnsemble::NONE,
            upsampled,
        };
        let upsamplers = MapUpsamplers::one(&network);
        upscale_each_map(&m, &upsamplers, scale, Border::Wrap, passes, |k, map| {
            maps.push((k, map));
            Ok(())
        })
        .unwrap();
        (maps, network.0.into_inner())
    };
    // Every map of the material varies: none is spared as flat.
    for scale in [2, 3, 4] {
        let (maps, images) = by_network(UpsampledMaps::default(), scale);
        assert_eq!(images, 4, "×{scale}: every map goes through the network");
        for (kind, map) in &maps {
            let d = max_difference(map, by_lanczos.map(*kind).unwrap());
            assert!(scale != 2 || d > 0.01, "{kind:?} is the network's: {d}");
        }
    }
    let (maps, images) = by_network(UpsampledMaps::Normal, 2);
    assert_eq!(images, 1, "the normal map alone goes through the network");
    for (kind, map) in &maps {
        let d = max_difference(map, by_lanczos.map(*kind).unwrap());
        if *kind == MapKind::Normal {
            assert!(d > 0.01, "the normals are the network's: {d}");
        } else {
            assert_eq!(d, 0.0, "{kind:?} is Lanczos-3's");
        }
    }
    assert_eq!(by_network(UpsampledMaps::Normal, 4).1, 1);
    // ×8's ×2 level (the second) takes the normal map alone by default, a kernel every map.
    let auto = UpsampledMaps::Auto;
    assert_eq!(auto.at_level(1, 2, Some(4)), UpsampledMaps::Normal);
    assert_eq!(auto.at_level(1, 2, None), UpsampledMaps::All);
    assert_eq!(auto.at_level(0, 2, Some(4)), UpsampledMaps::All);
    assert_eq!(auto.at_level(1, 4, Some(4)), UpsampledMaps::All);
    assert_eq!(
        UpsampledMaps::All.at_level(1, 2, Some(4)),
        UpsampledMaps::All
    );
}

#[test]
fn a_flat_map_comes_back_flat_without_the_upsampler() {
    struct Failing;
    impl RgbUpsampler for Failing {
        fn upsample(&self, _: &[Map], _: usize, _: Border) -> Result<Vec<Map>> {
            Err(Error::Invalid("ran".into()))
        }
    }
    // Every map of a uniform material is flat (the normals point straight up).
    let m = Material::uniform(8, [0.2, 0.4, 0.6], 0.5, 1.0);
    let up = upscale_per_map(&m, &Failing, 4, Border::Wrap).unwrap();
    assert_eq!((up.width(), up.height_px()), (32, 32));
    assert!(up.metallic.data().iter().all(|&v| v == 1.0));
    assert!(up.roughness.data().iter().all(|&v| v == 0.5));
    for (c, want) in [0.2, 0.4, 0.6].into_iter().enumerate() {
        assert!(up.base_color.plane(c).iter().all(|&v| v == want));
    }
    // One texel off and the upsampler runs.
    let mut bump = m.clone();
    bump.roughness.data_mut()[5] = 0.6;
    let err = upscale_per_map(&bump, &Failing, 4, Border::Wrap).unwrap_err();
    assert!(err.to_string().contains("ran"), "{err}");
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
    // Constant channels of a colour map that is not flat (it goes through the upsampler)
    // survive the sRGB round trip.
    m.base_color = Map::from_fn(8, 8, 3, |c, y, x| {
        [0.1 * (1 + (x + y) % 5) as f32, 0.4, 0.6][c]
    });
    let up = upscale_per_map(&m, &Bilinear, 4, Border::Wrap).unwrap();
    for (c, want) in [0.4, 0.6].into_iter().enumerate() {
        let channel = up.base_color.plane(c + 1);
        assert!(
            channel.iter().all(|v| (v - want).abs() < 1e-5),
            "channel {}",
            c + 1
        );
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
    let message = upscale_per_map(&varied_material(), &Twice, 4, Border::Wrap)
        .unwrap_err()
        .to_string();
    assert!(
        message.contains("16×16×3") && message.contains("expected 32×32×3"),
        "{message}"
    );
}
