//! The default path on a device (issue: the whole default path on the GPU): where the
//! upsampler leaves its outputs on a candle device, the per-map base is decoded, averaged over
//! the self-ensemble, back-projected and chroma-clamped there. Here the device is candle's CPU,
//! and one ×4 upsampler runs both ways, so any difference is the stages' own: the maps must
//! equal the host path's within 1e-6 and their files within one level, whole and in bands,
//! tileable and not, at ×4, ×16 and through the ×4 route at ×2 and ×3, with carried maps and
//! alpha.

mod common;

use matup::candle_core::{Device, Tensor};
use matup::config::Config;
use matup::core::device_maps::upload;
use matup::core::resample::{upsample, Border, Kernel};
use matup::core::upsample::{RgbUpsampler, UpsamplerRegistration};
use matup::material::{MapKind, Material};
use matup::progress::Silent;
use matup::{Map, NormalConvention, Result, RunOptions};
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
    let whole = matup::load_material(
        Some(&common::test_material("polyhaven_coast_sand_rocks_02")),
        &Default::default(),
    )
    .unwrap();
    common::with_occlusion_and_alpha(whole.box_downsample(whole.width() / side))
}

fn run(lr: &Material, device: bool, scale: usize, tileable: bool, limit: Option<u64>) -> Material {
    let config = Config {
        upsampler: format!("test-lanczos-x4:{}", if device { "device" } else { "host" }),
        scale,
        tileable: Some(tileable),
        ..Config::default()
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
        (4, 128, Some(16)),
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
