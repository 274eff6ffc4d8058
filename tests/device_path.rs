//! The default path on a device (issue: the whole default path on the GPU): where the
//! upsampler leaves its outputs on a candle device, the per-map base is decoded, averaged over
//! the self-ensemble, back-projected and chroma-clamped there. Here the device is candle's CPU,
//! and one ×4 upsampler runs both ways, so any difference is the stages' own: the maps must
//! equal the host path's within 1e-6 and their files within one level, whole and in bands,
//! tileable and not, at ×4, ×16 and through the ×4 route at ×2 and ×3, with carried maps and
//! alpha.

mod common;

use std::path::Path;

use image::DynamicImage;
use matup::apps::folder::upscale_to_folder;
use matup::candle_core::{Device, Tensor};
use matup::config::Config;
use matup::core::color::linear_to_srgb;
use matup::core::device_maps::upload;
use matup::core::resample::{upsample, Border, Kernel};
use matup::core::upsample::{RgbUpsampler, UpsamplerRegistration};
use matup::material::{MapKind, Material};
use matup::progress::Silent;
use matup::{FileFormat, Map, NormalConvention, Result, RunOptions, SaveOptions};
use std::sync::atomic::{AtomicUsize, Ordering};

/// A ×4-only upsampler as a network is (outputs in [0, 1]): Lanczos-3. `device` keeps its
/// outputs on candle's CPU device.
struct Lanczos4 {
    device: bool,
}

/// Calls of the device upsampler's host `upsample`: the device path makes none.
static HOST_CALLS_ON_DEVICE: AtomicUsize = AtomicUsize::new(0);

fn lanczos4(images: &[Map], scale: usize, border: Border) -> Vec<Map> {
    assert_eq!(scale, 4);
    (images.iter())
        .map(|m| upsample(m, 4, Kernel::Lanczos3, border).map_values(|v| v.clamp(0.0, 1.0)))
        .collect()
}

impl RgbUpsampler for Lanczos4 {
    fn native_scale(&self) -> Option<usize> {
        Some(4)
    }

    fn upsample(&self, images: &[Map], scale: usize, border: Border) -> Result<Vec<Map>> {
        if self.device {
            HOST_CALLS_ON_DEVICE.fetch_add(1, Ordering::SeqCst);
        }
        Ok(lanczos4(images, scale, border))
    }

    fn device(&self) -> Option<Device> {
        self.device.then_some(Device::Cpu)
    }

    fn upsample_on_device(
        &self,
        images: &[Map],
        scale: usize,
        border: Border,
    ) -> Result<Vec<Tensor>> {
        Ok(lanczos4(images, scale, border)
            .iter()
            .map(|m| upload(m, &Device::Cpu))
            .collect::<matup::candle_core::Result<_>>()?)
    }
}

fn create(argument: Option<&str>) -> Result<Box<dyn RgbUpsampler>> {
    Ok(Box::new(Lanczos4 {
        device: argument == Some("device"),
    }))
}

matup::core::inventory::submit! {
    UpsamplerRegistration {
        name: "test-lanczos-x4",
        description: "Lanczos-3 at ×4 only; `:device` keeps its outputs on candle's CPU device",
        options: &[],
        create,
    }
}

/// A real material at `side`², with an occlusion map and a base-colour alpha carried along.
fn material(side: usize) -> Material {
    let whole = common::load_test_material("polyhaven_coast_sand_rocks_02");
    common::with_occlusion_and_alpha(whole.box_downsample(whole.width() / side))
}

fn run(lr: &Material, device: bool, scale: usize, tileable: bool, limit: Option<u64>) -> Material {
    run_with(lr, device, scale, tileable, limit, Config::default())
}

/// [`run`] from settings `base` (its upsampler, scale and tiling replaced).
fn run_with(
    lr: &Material,
    device: bool,
    scale: usize,
    tileable: bool,
    limit: Option<u64>,
    base: Config,
) -> Material {
    let config = Config {
        upsampler: format!("test-lanczos-x4:{}", if device { "device" } else { "host" }),
        scale,
        tileable: Some(tileable),
        ..base
    };
    let options = RunOptions {
        memory_limit: limit,
        ..RunOptions::default()
    };
    let (out, report) = matup::upscale(lr, &config, &options, &Silent).unwrap();
    if let Some(limit) = limit {
        let bands = report.levels.last().unwrap().bands;
        assert!(bands >= 2, "×{scale} within {limit} bytes: {bands} band");
    }
    out
}

#[test]
fn the_device_path_gives_the_host_paths_maps() {
    // (scale, input side, memory limit in MiB: bands where given).
    for (scale, side, limit_mib) in [
        (4, 64, None),
        (4, 128, Some(24)),
        (16, 16, None),
        (2, 64, None),
        (3, 64, None),
    ] {
        let lr = material(side);
        for tileable in [false, true] {
            let limit = limit_mib.map(|m: u64| m << 20);
            let host = run(&lr, false, scale, tileable, limit);
            let device = run(&lr, true, scale, tileable, limit);
            // Every map, the carried ones too, went through the device's path.
            assert_eq!(HOST_CALLS_ON_DEVICE.load(Ordering::SeqCst), 0);
            let what = format!("×{scale} from {side}², tileable {tileable}, bands {limit_mib:?}");
            let pairs: Vec<(&Map, &Map)> = host.maps().zip(device.maps()).collect();
            assert_eq!(pairs.len(), 7, "{what}: five maps, occlusion and alpha");
            assert_eq!(device.maps().count(), 7, "{what}");
            for (kind, (a, b)) in [
                "base colour",
                "normal",
                "roughness",
                "metallic",
                "height",
                "alpha",
                "occlusion",
            ]
            .iter()
            .zip(&pairs)
            {
                let worst = common::max_abs_diff(a, b);
                println!("{what}, {kind}: {worst:.1e}");
                assert!(worst <= 1e-6, "{what}, {kind}: {worst}");
            }
            for kind in MapKind::ALL {
                let (Some(a), Some(b)) = (host.map(kind), device.map(kind)) else {
                    continue;
                };
                let stored = |m: &Map| {
                    matup::io::encode_map(kind, m, false, NormalConvention::DirectX)
                        .into_owned()
                        .map_values(|v| (v.clamp(0.0, 1.0) * 255.0).round())
                };
                let levels = common::max_abs_diff(&stored(a), &stored(b));
                assert!(levels <= 1.0, "{what}, {kind}: {levels} levels");
            }
        }
    }
}

/// With the chroma clamp's colours brought back by back-projection
/// (`filter.clamp_back_project`), the device's path gives the host's maps, and bands give the
/// whole run's: their context covers the extra rounds.
#[test]
fn the_clamp_brought_back_smoothly_is_the_same_on_the_device_and_in_bands() {
    let lr = material(128);
    let smooth = Config::default();
    let mut block_by_block = Config::default();
    block_by_block.filter.clamp_back_project = false;
    let limit = Some(24 << 20);
    let base_colour = |device, limit, config: &Config| {
        run_with(&lr, device, 4, true, limit, config.clone()).base_color
    };
    let whole = base_colour(false, None, &smooth);
    let settled = base_colour(false, None, &block_by_block);
    let banded = base_colour(false, limit, &smooth);
    let banded_on_device = base_colour(true, limit, &smooth);
    assert_eq!(HOST_CALLS_ON_DEVICE.load(Ordering::SeqCst), 0);
    let changed = common::max_abs_diff(&whole, &settled);
    let bands = common::max_abs_diff(&whole, &banded);
    let device = common::max_abs_diff(&banded, &banded_on_device);
    println!(
        "brought back smoothly: {changed:.1e} from settled, bands {bands:.1e}, device {device:.1e}"
    );
    assert!(changed > 1e-4, "the clamp changed nothing here: {changed}");
    assert!(bands <= 1e-5, "{bands}");
    assert!(device <= 1e-6, "{device}");
}

/// Maps routed apart, as a model's JPEG colour beside a block-compressed normal map and
/// lossless grey maps runs them: the colour projected onto its low frequencies, the normal map
/// left as the upsampler made it, roughness and metallic projected exactly. Each map comes out
/// as the run that treats every map its way makes it, and the device and bands give the host's
/// whole maps (that a band's context covers the blur's reach at σ 16:
/// `a_band_with_the_context_of_a_low_pass_projection_makes_the_whole_runs_rows`).
#[test]
fn maps_routed_apart_are_each_projected_as_their_route_says_on_the_device_and_in_bands() {
    let lr = material(128);
    // A JPEG colour's blur is σ 16; σ 4 keeps bands of a small material within its reach.
    let mut apart = Config::default();
    apart.filter.projection_blur = 4.0;
    apart.filter.unprojected_maps = vec![MapKind::Normal];
    let mut low_pass = Config::default();
    low_pass.filter.projection_blur = 4.0;
    let mut unprojected = Config::default();
    unprojected.filter.back_project = false;
    let host = |config: &Config, limit| run_with(&lr, false, 4, true, limit, config.clone());
    let whole = host(&apart, None);
    let close = |a: &Map, b: &Map, what: &str, within: f32| {
        let worst = common::max_abs_diff(a, b);
        println!("{what}: {worst:.1e}");
        assert!(worst <= within, "{what}: {worst}");
    };
    let (colour, exact) = (host(&low_pass, None), host(&Config::default(), None));
    close(
        &whole.base_color,
        &colour.base_color,
        "colour, as a low-pass run's",
        0.0,
    );
    close(
        &whole.normal,
        &host(&unprojected, None).normal,
        "normal, unprojected",
        0.0,
    );
    for (kind, a, b) in [
        ("roughness", &whole.roughness, &exact.roughness),
        ("metallic", &whole.metallic, &exact.metallic),
    ] {
        close(a, b, &format!("{kind}, projected exactly"), 0.0);
    }
    // The normal map was moved by projection where it is projected.
    assert!(common::max_abs_diff(&whole.normal, &exact.normal) > 1e-3);
    let limit = Some(24 << 20);
    let banded = host(&apart, limit);
    let on_device = run_with(&lr, true, 4, true, limit, apart.clone());
    assert_eq!(HOST_CALLS_ON_DEVICE.load(Ordering::SeqCst), 0);
    for ((a, b), c) in whole.maps().zip(banded.maps()).zip(on_device.maps()) {
        close(a, b, "bands", 1e-5);
        close(b, c, "device", 1e-6);
    }
}

/// `m` (no height) as a Unity HDRP folder in `dir`: an RGBA base map whose alpha varies, an
/// OpenGL normal map, and a 16-bit mask map (metallic, occlusion, detail mask, smoothness =
/// 1 − roughness). So one file holds maps made on the device beside ones carried on the host,
/// stored every way a file stores a map (sRGB, normal colours in OpenGL's green, inverted).
fn write_hdrp_folder(m: &Material, dir: &Path) {
    let (w, h) = (m.width(), m.height_px());
    let to8 = |v: f32| (v.clamp(0.0, 1.0) * 255.0).round() as u8;
    let to16 = |v: f32| (v.clamp(0.0, 1.0) * 65535.0).round() as u16;
    let base: Vec<u8> = (0..w * h)
        .flat_map(|i| {
            let [r, g, b] = m.base_color.texel(i).map(|v| to8(linear_to_srgb(v)));
            [r, g, b, to8((i % w) as f32 / w as f32)]
        })
        .collect();
    let normal: Vec<u8> = (0..w * h)
        .flat_map(|i| {
            let [x, y, z] = m.normal.texel(i);
            [
                to8((x + 1.0) / 2.0),
                to8((1.0 - y) / 2.0),
                to8((z + 1.0) / 2.0),
            ]
        })
        .collect();
    let mask: Vec<u16> = (0..w * h)
        .flat_map(|i| {
            let r = m.roughness.data()[i];
            [m.metallic.data()[i], 1.0 - 0.5 * r, 1.0, 1.0 - r].map(to16)
        })
        .collect();
    let (w, h) = (w as u32, h as u32);
    image::RgbaImage::from_raw(w, h, base)
        .unwrap()
        .save(dir.join("Rock_BaseMap.png"))
        .unwrap();
    image::RgbImage::from_raw(w, h, normal)
        .unwrap()
        .save(dir.join("Rock_Normal.png"))
        .unwrap();
    image::ImageBuffer::<image::Rgba<u16>, _>::from_raw(w, h, mask)
        .unwrap()
        .save(dir.join("Rock_MaskMap.png"))
        .unwrap();
}

/// Every sample of a PNG file, in levels of its depth.
fn samples(path: &Path) -> Vec<f32> {
    let image = image::open(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    match image {
        DynamicImage::ImageRgb8(_) | DynamicImage::ImageRgba8(_) | DynamicImage::ImageLuma8(_) => {
            image.as_bytes().iter().map(|&v| v as f32).collect()
        }
        DynamicImage::ImageRgba16(i) => i.into_raw().into_iter().map(|v| v as f32).collect(),
        other => panic!("{}: {:?}", path.display(), other.color()),
    }
}

#[test]
fn maps_made_on_the_device_are_written_from_samples_made_there() {
    let whole = common::load_test_material("polyhaven_coast_sand_rocks_02");
    let lr = whole.box_downsample(whole.width() / 64);
    let dir = tempfile::tempdir().unwrap();
    let input = dir.path().join("in");
    std::fs::create_dir(&input).unwrap();
    write_hdrp_folder(&lr, &input);
    let material = matup::load_material(Some(&input), &Default::default()).unwrap();
    assert!(material.height.is_none() && material.carried.alpha.len() == 1);

    // The bands the pipeline hands on keep the four rendered maps on the device; with a
    // height, the normals come back for its solve.
    let config = |device: bool| Config {
        upsampler: format!("test-lanczos-x4:{}", if device { "device" } else { "host" }),
        tileable: Some(false),
        ..Config::default()
    };
    for (m, held) in [(&material, 4), (&lr, 3)] {
        let mut kinds = Vec::new();
        matup::upscale_streamed(
            m,
            &matup::Plan::new(m, &config(true)).unwrap(),
            &RunOptions::default(),
            &Silent,
            &mut |_, band| {
                kinds.push(band.kinds_on_device().count());
                Ok(())
            },
        )
        .unwrap();
        assert_eq!(kinds, [held], "height: {}", m.height.is_some());
    }

    // (what the folder holds, its side, the format asked for, the device's memory limit in
    // MiB: bands).
    let cases = [
        ("HDRP", 64, None, None),
        ("HDRP", 128, None, Some(24)),
        ("HDRP", 64, Some(FileFormat::ExrFloat), None),
        // No mask map: roughness and metallic stand in, and are written only if they change.
        ("no mask map", 64, None, None),
    ];
    for (case, (folder, side, format, limit_mib)) in cases.into_iter().enumerate() {
        let what = format!("{folder} at {side}², {format:?}, limit {limit_mib:?} MiB");
        let input = dir.path().join(format!("in-{case}"));
        std::fs::create_dir(&input).unwrap();
        write_hdrp_folder(&whole.box_downsample(whole.width() / side), &input);
        if folder == "no mask map" {
            std::fs::remove_file(input.join("Rock_MaskMap.png")).unwrap();
        }
        let material = matup::load_material(Some(&input), &Default::default()).unwrap();
        let out = |device: bool| {
            let out = dir.path().join(format!("out-{case}-{device}"));
            let save = SaveOptions {
                format,
                ..SaveOptions::default()
            };
            let limit = limit_mib.filter(|_| device).map(|m: u64| m << 20);
            let run = upscale_to_folder(
                &material,
                &config(device),
                &out,
                &save,
                false,
                limit,
                None,
                &Silent,
            )
            .unwrap();
            let bands = run.report.levels[0].bands;
            assert_eq!(bands > 1, limit.is_some(), "{what}: {bands} bands");
            out
        };
        let (host, device) = (out(false), out(true));
        let names = |d: &Path| {
            let mut names: Vec<String> = (std::fs::read_dir(d).unwrap())
                .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
                .filter(|n| n != "preview.png" && n != "run.json")
                .collect();
            names.sort();
            names
        };
        assert_eq!(names(&host), names(&device), "{what}: the same files");
        if format.is_some() {
            // Float files store the values themselves: read back, the maps agree.
            let [a, b] = [&host, &device]
                .map(|d| matup::load_material(Some(d), &Default::default()).unwrap());
            assert_eq!(
                a.maps().count(),
                7,
                "four maps, alpha, occlusion and the detail mask"
            );
            for (a, b) in a.maps().zip(b.maps()) {
                let worst = common::max_abs_diff(a, b);
                println!("{what}: {worst:.1e}");
                assert!(worst <= 1e-5, "{what}: {worst}");
            }
            continue;
        }
        for file in names(&host) {
            let (a, b) = (samples(&host.join(&file)), samples(&device.join(&file)));
            assert_eq!(a.len(), b.len(), "{what}, {file}");
            let worst = (a.iter().zip(&b)).fold(0f32, |m, (x, y)| m.max((x - y).abs()));
            let differ = (a.iter().zip(&b)).filter(|(x, y)| x != y).count();
            println!(
                "{what}, {file}: {differ} of {} samples differ, by {worst} at most",
                a.len()
            );
            assert!(worst <= 1.0, "{what}, {file}: {worst} levels");
            assert!(
                differ * 100 <= a.len(),
                "{what}, {file}: {differ} samples differ"
            );
        }
    }
}

/// A noisy material's normals (`filter.normal_blend_noise`, as the route sets it where it
/// reads noise: every map unprojected): each texel between the run's normal, unprojected, and
/// the clean route's, projected exactly; all of the first where no structure stands past the
/// noise (a huge σ), all of the second where all does (a tiny one). Bands make the whole
/// run's maps: their context covers the blend's window and its projection. The blend runs on
/// the host, so the device upsampler's host calls are not counted here.
#[test]
fn a_noisy_materials_normals_blend_the_two_routes_and_bands_make_the_whole_runs() {
    let lr = material(128);
    let normals = |back_project: bool, blend_noise: f32, limit| {
        let mut config = Config::default();
        config.filter.back_project = back_project;
        config.filter.normal_blend_noise = blend_noise;
        run_with(&lr, false, 4, true, limit, config).normal
    };
    let (unprojected, exact) = (normals(false, 0.0, None), normals(true, 0.0, None));
    let close = |a: &Map, b: &Map, what: &str, within: f32| {
        let worst = common::max_abs_diff(a, b);
        println!("{what}: {worst:.1e}");
        assert!(worst <= within, "{what}: {worst}");
    };
    close(
        &normals(false, 1e4, None),
        &unprojected,
        "no structure past the noise",
        1e-6,
    );
    close(
        &normals(false, 1e-3, None),
        &exact,
        "all of it past the noise",
        1e-5,
    );
    let blended = normals(false, 3.0, None);
    let (mut from_clean, mut between) = (0usize, true);
    for c in 0..2 {
        let planes = blended
            .plane(c)
            .iter()
            .zip(unprojected.plane(c))
            .zip(exact.plane(c));
        for ((b, u), e) in planes {
            between &= (u.min(*e) - 1e-4..=u.max(*e) + 1e-4).contains(b);
            from_clean += usize::from((b - u).abs() > 1e-4);
        }
    }
    let share = from_clean as f64 / (2 * blended.width() * blended.height()) as f64;
    println!(
        "σ 3: {:.1}% of the normals' values from the clean route",
        100.0 * share
    );
    assert!(between);
    assert!((0.05..0.95).contains(&share), "{share}");
    close(
        &normals(false, 3.0, Some(24 << 20)),
        &blended,
        "bands",
        1e-5,
    );
}
