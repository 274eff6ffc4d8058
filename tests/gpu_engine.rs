//! The GPU engine (wgpu) against the CPU's, on the adapter the tests use
//! (`matup::upsamplers::gpu::test_adapter`: Mesa's lavapipe, a software Vulkan, in CI; no GPU
//! is needed). Each network matup ships, and generated networks of SPAN ×2's and Real-ESRGAN's
//! operators, must give the CPU's output within one level of 255, tiled and whole; a whole
//! material must give the CPU path's maps within one level, whole and in bands; a call stops
//! where its watch says; `auto` runs on the CPU where no hardware adapter is, and says why.

mod common;

use matup::config::Config;
use matup::core::resample::Border;
use matup::core::upsample::RgbUpsampler;
use matup::progress::Silent;
use matup::upsamplers::gpu;
use matup::upsamplers::onnx::{OnnxUpsampler, BUILT_IN};
use matup::{Map, PluginSpec, RunOptions};

/// `gpu:N` of the test adapter, or `None` (the test then passes, saying so, unless CI requires
/// the adapter).
fn test_device() -> Option<String> {
    gpu::test_adapter().map(|a| format!("gpu:{}", a.index))
}

fn build(spec: &str) -> Box<dyn RgbUpsampler> {
    matup::core::upsample::upsampler(&spec.parse::<PluginSpec>().unwrap())
        .unwrap_or_else(|e| panic!("{spec}: {e}"))
}

/// A real material's base colour at `side`²: what a network sees.
fn colour(side: usize) -> Map {
    let m = common::load_test_material("polyhaven_coast_sand_rocks_02");
    let small = m.box_downsample(m.width() / side);
    small.base_color.clone()
}

#[test]
fn every_shipped_network_on_the_gpu_is_within_a_level_of_the_cpu() {
    let Some(device) = test_device() else { return };
    let image = colour(64);
    let images = std::slice::from_ref(&image);
    for built_in in BUILT_IN {
        let name = built_in.name;
        // Tiles of 24 with their context, several a call; and the default network whole,
        // wrapping around (the others share its graph: lavapipe is slow).
        // Also its maps held in half precision, where the adapter has shader-f16.
        let default = name == "span_x4_materials";
        let whole = default.then_some(("", Border::Wrap));
        let half = (default && gpu::test_adapter().unwrap().shader_f16)
            .then_some((",tile=24,precision=f16", Border::Mirror));
        let runs = std::iter::once((",tile=24", Border::Mirror))
            .chain(whole)
            .chain(half);
        for (options, border) in runs {
            let cpu_options = options.replace(",precision=f16", "");
            let cpu = build(&format!("onnx:{name}{cpu_options},device=cpu"));
            let on_gpu = build(&format!("onnx:{name}{options},device={device}"));
            let placement = on_gpu.placement().unwrap();
            assert!(placement.starts_with("wgpu on "), "{placement}");
            let a = cpu.upsample(images, 4, border).unwrap();
            let b = on_gpu.upsample(images, 4, border).unwrap();
            let worst = common::max_abs_diff(&a[0], &b[0]);
            println!("{name}{options}, {border:?}: largest difference {worst:.1e}");
            assert!(worst <= 1.0 / 255.0, "{name}{options}: {worst}");
        }
    }
}

#[test]
fn generated_span_and_realesrgan_graphs_on_the_gpu_match_the_cpu() {
    let Some(device) = test_device() else { return };
    let image = colour(32);
    for (name, model, scale) in [
        ("span_x2", common::nets::span(2, 16, 2), 2),
        ("realesrgan_x4", common::nets::realesrgan_x4(16, 8, 4), 4),
    ] {
        let dir = tempfile::tempdir().unwrap();
        let path = common::nets::write(dir.path(), name, &model, scale, 4);
        let spec = |d: &str| format!("onnx:{},tile=16,device={d}", path.display());
        let a = build(&spec("cpu"))
            .upsample(std::slice::from_ref(&image), scale, Border::Mirror)
            .unwrap();
        let b = build(&spec(&device))
            .upsample(std::slice::from_ref(&image), scale, Border::Mirror)
            .unwrap();
        let worst = common::max_abs_diff(&a[0], &b[0]);
        assert!(worst <= 1e-4, "{name}: {worst}");
    }
}

/// `matup::upscale` of `lr` at ×4 with the defaults on `device` (one self-ensemble pass),
/// within `limit` bytes.
fn upscale(
    lr: &matup::material::Material,
    device: &str,
    limit: Option<u64>,
) -> (matup::material::Material, matup::RunReport) {
    let mut config = Config {
        device: device.to_string(),
        tileable: Some(false),
        ..Config::default()
    };
    // One pass a map: what differs between the engines is the network's own output.
    config.filter.self_ensemble = 1;
    let options = RunOptions {
        memory_limit: limit,
        ..RunOptions::default()
    };
    matup::upscale(lr, &config, &options, &Silent).unwrap()
}

#[test]
fn a_material_on_the_gpu_gives_the_cpu_paths_maps_whole_and_in_bands() {
    let Some(device) = test_device() else { return };
    let whole = common::load_test_material("polyhaven_coast_sand_rocks_02");
    // 64² whole; 128² in bands of rows within 20 MiB.
    for (side, limit) in [(64, None), (128, Some(20 << 20))] {
        let lr = whole.box_downsample(whole.width() / side);
        let (cpu, cpu_report) = upscale(&lr, "cpu", limit);
        let (on_gpu, report) = upscale(&lr, &device, limit);
        if limit.is_some() {
            assert!(
                report.levels[0].bands >= 2,
                "{} band",
                report.levels[0].bands
            );
        }
        let adapter = gpu::test_adapter().unwrap().name;
        assert!(
            report.network_devices.iter().any(|d| d.contains(&adapter)),
            "{:?}",
            report.network_devices
        );
        assert!(
            (cpu_report.network_devices.iter()).all(|d| d.contains("on the CPU")),
            "{:?}",
            cpu_report.network_devices
        );
        let pairs: Vec<(&Map, &Map)> = cpu.maps().zip(on_gpu.maps()).collect();
        assert_eq!(pairs.len(), 5);
        for (a, b) in pairs {
            let worst = common::max_abs_diff(a, b);
            println!("{side}², limit {limit:?}: largest difference {worst:.1e}");
            assert!(worst <= 1.0 / 255.0, "{worst}");
        }
    }
}

#[test]
fn auto_runs_on_the_first_hardware_adapter_or_on_the_cpu_saying_why() {
    let up = OnnxUpsampler::load_source(
        matup::upsamplers::onnx::resolve("span_x4_ch48").unwrap(),
        None,
        matup::upsamplers::onnx::EngineChoice::Auto,
    )
    .unwrap();
    assert_eq!(up.engine(), "matup");
    let auto = build("onnx:span_x4_ch48");
    let placement = auto.placement().unwrap();
    match gpu::auto_adapter() {
        // This machine's software adapters (lavapipe) are not taken.
        None => assert_eq!(
            placement,
            "matup on the CPU: device=auto found no hardware GPU adapter \
             (software ones run only when named: gpu:NAME)"
        ),
        Some(a) => assert!(placement.contains(&a.name), "{placement}"),
    }
    // A CPU engine asked for by name runs on the CPU whatever auto would take.
    let matup_engine = build("onnx:span_x4_ch48,engine=matup");
    assert_eq!(matup_engine.placement().unwrap(), "matup on the CPU");
    let e = matup::core::upsample::upsampler(
        &"onnx:span_x4_ch48,device=gpu:no-such-adapter"
            .parse()
            .unwrap(),
    )
    .err()
    .unwrap()
    .to_string();
    assert!(
        e.contains("device 'gpu:no-such-adapter': no such GPU adapter"),
        "{e}"
    );
}
