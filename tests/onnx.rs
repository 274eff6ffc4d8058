//! Pre-trained SR networks as upsamplers (the `onnx` feature, on by default).
#![cfg(feature = "onnx")]

mod common;

use common::nets;

use std::path::{Path, PathBuf};

use matup::render::{render, RenderOptions};
use matup::{shading_model, upsampler, Border, Light, Map, PluginSpec, RgbUpsampler};

/// A 64² render of the shipped sample under a light from the side.
fn real_render() -> Map {
    let m = matup::load_material(Some(&common::sample_material()), &Default::default()).unwrap();
    let m = m.crop(32, 32, 64, 64);
    let model = shading_model(&PluginSpec::new("ggx")).unwrap();
    let light = Light {
        position: [0.6, -0.4, 1.2],
        intensity: 8.0,
        falloff: false,
    };
    render(&m, model.as_ref(), &[light], RenderOptions::default()).remove(0)
}

fn build(spec: &str) -> Box<dyn RgbUpsampler> {
    upsampler(&spec.parse::<PluginSpec>().unwrap()).unwrap_or_else(|e| panic!("{spec}: {e}"))
}

/// A generated network of SPAN ×2's (`span_x2`) or Real-ESRGAN ×4plus's (`realesrgan_x4`)
/// operators, random weights, written with a sidecar of `scale` and `overlap` into a fresh
/// folder.
fn generated(name: &str, scale: usize, overlap: usize) -> (tempfile::TempDir, PathBuf) {
    let dir = tempfile::tempdir().unwrap();
    let model = match name {
        "span_x2" => nets::span(2, 16, 2),
        "realesrgan_x4" => nets::realesrgan_x4(16, 8, 4),
        other => panic!("no generated network '{other}'"),
    };
    let path = nets::write(dir.path(), name, &model, scale, overlap);
    (dir, path)
}

/// Upsamples `image` and checks size, range, colour (per-channel means kept) and that the
/// result is an upsample of it: mean |SR − bicubic| below `max_from_bicubic`.
fn check_upsamples(
    name: &str,
    up: &dyn RgbUpsampler,
    scale: usize,
    image: &Map,
    max_from_bicubic: f32,
    max_colour_shift: f32,
) {
    let out = up
        .upsample(std::slice::from_ref(image), scale, Border::Mirror)
        .unwrap()
        .remove(0);
    assert_eq!((out.width(), out.height()), (64 * scale, 64 * scale));
    assert!(out
        .data()
        .iter()
        .all(|v| v.is_finite() && (0.0..=1.0).contains(v)));
    for c in 0..3 {
        let shift = (out.mean(c) - image.mean(c)).abs();
        println!("{name}: channel {c} mean shift {shift:.4}");
        assert!(
            shift < max_colour_shift,
            "{name}: channel {c} mean {} vs {}",
            out.mean(c),
            image.mean(c)
        );
    }
    let bicubic = build("bicubic")
        .upsample(std::slice::from_ref(image), scale, Border::Mirror)
        .unwrap()
        .remove(0);
    let mean: f32 = out
        .data()
        .iter()
        .zip(bicubic.data())
        .map(|(a, b)| (a - b).abs())
        .sum::<f32>()
        / out.data().len() as f32;
    println!("{name}: mean |SR − bicubic| {mean:.4}");
    assert!(
        mean < max_from_bicubic,
        "{name}: mean |SR − bicubic| {mean}"
    );
}

#[test]
fn every_model_loads_and_upsamples_a_real_render() {
    let image = real_render();
    // SPAN is PSNR-oriented: near bicubic, colours kept.
    check_upsamples(
        "span ×4",
        build("onnx:span_x4_ch48").as_ref(),
        4,
        &image,
        0.03,
        0.005,
    );
    // Networks of SPAN ×2's and Real-ESRGAN's operators (random weights: their quality means
    // nothing) load on matup's executor and upsample by their scale, in range, following the
    // input.
    for (name, scale, overlap) in [("span_x2", 2, 24), ("realesrgan_x4", 4, 16)] {
        let (_d, path) = generated(name, scale, overlap);
        let up = matup::upsamplers::onnx::OnnxUpsampler::load(
            &path,
            matup::upsamplers::onnx::EngineChoice::Auto,
        )
        .unwrap();
        assert_eq!(up.engine(), "matup", "{name}");
        let out = up
            .upsample(std::slice::from_ref(&image), scale, Border::Mirror)
            .unwrap()
            .remove(0);
        assert_eq!((out.width(), out.height()), (64 * scale, 64 * scale));
        let (lo, hi) = out
            .data()
            .iter()
            .fold((f32::MAX, f32::MIN), |(lo, hi), &v| (lo.min(v), hi.max(v)));
        assert!(lo >= 0.0 && hi <= 1.0, "{name}: {lo}..{hi}");
        assert!(
            hi - lo > 0.05,
            "{name}: the output follows the input ({lo}..{hi})"
        );
    }
}

/// The shipped SPAN ×4 re-declared with a fixed 1×3×80×80 input, as some exported networks
/// are, with a sidecar of overlap `overlap`.
fn fixed_size_span(dir: &Path, overlap: usize) -> PathBuf {
    use prost::Message;
    use tract_onnx::pb::tensor_shape_proto::dimension::Value;
    use tract_onnx::pb::type_proto;
    let source = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("models/span_x4_ch48.onnx");
    let mut model =
        tract_onnx::pb::ModelProto::decode(std::fs::read(source).unwrap().as_slice()).unwrap();
    let input = &mut model.graph.as_mut().unwrap().input[0];
    let Some(type_proto::Value::TensorType(tensor)) = &mut input.r#type.as_mut().unwrap().value
    else {
        panic!("SPAN's input is a tensor");
    };
    for (d, v) in tensor
        .shape
        .as_mut()
        .unwrap()
        .dim
        .iter_mut()
        .zip([1, 3, 80, 80])
    {
        d.value = Some(Value::DimValue(v));
    }
    let path = dir.join("span_fixed.onnx");
    std::fs::write(&path, model.encode_to_vec()).unwrap();
    std::fs::write(
        path.with_extension("toml"),
        format!("scale = 4\noverlap = {overlap}\n"),
    )
    .unwrap();
    path
}

#[test]
fn networks_with_a_fixed_input_size_are_tiled_to_it() {
    let dir = tempfile::tempdir().unwrap();
    let fixed = build(&format!(
        "onnx:{}",
        fixed_size_span(dir.path(), 22).display()
    ));
    let dynamic = build("onnx:span_x4_ch48,tile=128,overlap=24");
    let image = real_render();
    // 64² in 80² windows: cores of 36 texels, four tiles; and 24², shorter than a core,
    // read with 28 texels of context on each side.
    for image in [image.clone(), image.crop(8, 8, 24, 24)] {
        let a = fixed
            .upsample(std::slice::from_ref(&image), 4, Border::Wrap)
            .unwrap()
            .remove(0);
        let b = dynamic
            .upsample(std::slice::from_ref(&image), 4, Border::Wrap)
            .unwrap()
            .remove(0);
        let diff = common::max_abs_diff(&a, &b);
        assert!(
            diff <= 2.0 / 255.0,
            "{}²: fixed-size tiles differ by {diff}",
            image.width()
        );
    }
    // An overlap that leaves no core in an 80² window is refused, naming the model.
    let e = build(&format!(
        "onnx:{},overlap=40",
        fixed_size_span(dir.path(), 22).display()
    ))
    .upsample(std::slice::from_ref(&image), 4, Border::Wrap)
    .unwrap_err()
    .to_string();
    assert!(
        e.contains("span_fixed.onnx") && e.contains("overlap"),
        "{e}"
    );
}

#[test]
fn tiles_match_the_whole_image_when_the_overlap_covers_the_receptive_field() {
    let image = real_render();
    // SPAN reads 21 LR texels around each output: 24 of context make tiles exact.
    let whole = build("onnx:span_x4_ch48,tile=64,overlap=24")
        .upsample(std::slice::from_ref(&image), 4, Border::Mirror)
        .unwrap()
        .remove(0);
    let tiled = build("onnx:span_x4_ch48,tile=24,overlap=24,batch=3")
        .upsample(std::slice::from_ref(&image), 4, Border::Mirror)
        .unwrap()
        .remove(0);
    let diff = common::max_abs_diff(&whole, &tiled);
    assert!(diff <= 2.0 / 255.0, "tiled differs from whole by {diff}");
}

fn roll(image: &Map, d: usize) -> Map {
    let (w, h) = (image.width(), image.height());
    Map::from_fn(w, h, 3, |c, y, x| {
        image.get(c, (y + h - d) % h, (x + w - d) % w)
    })
}

#[test]
fn wrap_around_tiles_keep_tileable_inputs_tileable() {
    let image = real_render();
    let up = build("onnx:span_x4_ch48,tile=32,overlap=24");
    let a = roll(
        &up.upsample(std::slice::from_ref(&image), 4, Border::Wrap)
            .unwrap()
            .remove(0),
        4 * 20,
    );
    let b = up
        .upsample(&[roll(&image, 20)], 4, Border::Wrap)
        .unwrap()
        .remove(0);
    let diff = common::max_abs_diff(&a, &b);
    assert!(diff <= 2.0 / 255.0, "shifted input, shifted output: {diff}");
}

fn error_of(spec: &str) -> String {
    match upsampler(&spec.parse::<PluginSpec>().unwrap()) {
        Ok(_) => panic!("{spec} should fail"),
        Err(e) => e.to_string(),
    }
}

#[test]
fn bad_models_give_clear_errors() {
    let e = error_of("onnx:/no/such/model.onnx");
    assert!(
        e.contains("/no/such/model.onnx") && e.contains("no such file"),
        "{e}"
    );
    let e = error_of("onnx:no_such_model");
    assert!(
        e.contains("no model 'no_such_model'") && e.contains("span_x4_ch48"),
        "{e}"
    );

    let dir = tempfile::tempdir().unwrap();
    let fake = dir.path().join("fake.onnx");
    std::fs::write(&fake, b"not a protobuf at all").unwrap();
    std::fs::write(fake.with_extension("toml"), "scale = 4\n").unwrap();
    let e = error_of(&format!("onnx:{}", fake.display()));
    assert!(
        e.contains("fake.onnx") && e.contains("not a readable ONNX model"),
        "{e}"
    );

    let (_d, x2) = generated("span_x2", 4, 8); // the sidecar lies about the scale
    let e = error_of(&format!("onnx:{}", x2.display()));
    assert!(
        e.contains("scale mismatch") && e.contains("×4") && e.contains("16×16"),
        "{e}"
    );

    let lonely = dir.path().join("lonely.onnx");
    std::fs::copy(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("models/span_x4_ch48.onnx"),
        &lonely,
    )
    .unwrap();
    let e = error_of(&format!("onnx:{}", lonely.display()));
    assert!(e.contains("lonely.toml") && e.contains("sidecar"), "{e}");

    // A ×4 network cannot make ×8; it makes ×2 through its ×4 and an area filter: its ×4
    // output box-filtered by 2.
    let up = build("onnx:span_x4_ch48");
    let render = real_render();
    let e = up
        .upsample(std::slice::from_ref(&render), 8, Border::Wrap)
        .unwrap_err()
        .to_string();
    assert!(e.contains("×8") && e.contains("×4"), "{e}");
    let two = up
        .upsample(std::slice::from_ref(&render), 2, Border::Wrap)
        .unwrap();
    let four = up
        .upsample(std::slice::from_ref(&render), 4, Border::Wrap)
        .unwrap();
    let worst = common::max_abs_diff(&two[0], &matup::resample::box_downsample(&four[0], 2));
    assert!(worst < 1e-5, "{worst}");
}

/// The largest difference between two upsamplers' outputs for `image` upsampled ×`scale`.
fn max_difference(a: &str, b: &str, image: &Map, scale: usize, border: Border) -> f32 {
    let run = |spec: &str| {
        build(spec)
            .upsample(std::slice::from_ref(image), scale, border)
            .unwrap()
            .remove(0)
    };
    common::max_abs_diff(&run(a), &run(b))
}

#[test]
fn matups_executor_matches_tract_on_each_kind_of_network() {
    let image = real_render();
    let small = image.crop(16, 16, 32, 32);
    let (_d, x2) = generated("span_x2", 2, 24);
    let (_d, esrgan) = generated("realesrgan_x4", 4, 16);
    for (model, image, scale) in [
        ("span_x4_ch48".to_string(), &image, 4),
        (x2.display().to_string(), &image, 2),
        (esrgan.display().to_string(), &small, 4),
    ] {
        let diff = max_difference(
            &format!("onnx:{model},engine=matup"),
            &format!("onnx:{model},engine=tract"),
            image,
            scale,
            Border::Mirror,
        );
        println!("{model}: max |matup − tract| {diff:e}");
        // tract approximates the sigmoid, whose input SPAN scales by 255: 1.2·10⁻⁴ of the
        // original runtime (models/README.md), 0.03 of an 8-bit level.
        assert!(diff < 1e-4, "{model}: engines differ by {diff}");
    }
}

/// What `--device cuda` runs (the executor's graph as candle operations, many tiles a call),
/// here on candle's CPU device, against matup's executor: both shipped networks, in tiles and
/// whole, with a tileable image's wrap-around context and wrapping convolutions and without.
#[test]
fn the_candle_graph_matches_matups_executor_on_both_shipped_networks() {
    let image = real_render();
    let turned = image.transformed(matup::map::Dihedral::ALL[3]);
    for model in ["span_x4_materials", "span_x4_ch48"] {
        // 4 tiles of 32² (read as 76² windows), or the whole 64² image in one.
        for (tiling, border) in [
            ("tile=32", Border::Mirror),
            ("tile=32", Border::Wrap),
            ("tile=64", Border::Mirror),
            ("tile=64", Border::Wrap),
        ] {
            let executor = build(&format!("onnx:{model},engine=matup,{tiling}"));
            let candle = build(&format!("onnx:{model},engine=candle,{tiling}"));
            assert!(candle.batches_images());
            let want = executor
                .upsample(&[image.clone(), turned.clone()], 4, border)
                .unwrap();
            // Both images in one call: their tiles share the network's batch.
            let got = candle
                .upsample(&[image.clone(), turned.clone()], 4, border)
                .unwrap();
            for (w, g) in want.iter().zip(&got) {
                let diff = common::max_abs_diff(w, g);
                println!("{model}, {tiling}, {border:?}: max |candle − matup| {diff:e}");
                assert!(diff < 1e-4, "{model}, {tiling}, {border:?}: {diff}");
            }
        }
    }
}

/// `precision=f16` on the candle engine (what a GPU runs), here on candle's CPU device: the
/// network computes in half-size values, so its output moves, by less than an 8-bit level on
/// a real render (the GPU's whole path moved the files by up to 6: docs/experiments/
/// 2026-11-26-gpu-time-and-precision.md). TF32 and bf16, a GPU's alone, and half precision
/// on the CPU's own engines are refused.
#[test]
fn half_precision_moves_the_network_by_under_an_8_bit_level() {
    let image = real_render();
    let f32 = build("onnx:span_x4_materials,engine=candle,tile=64");
    let want = f32
        .upsample(std::slice::from_ref(&image), 4, Border::Mirror)
        .unwrap();
    let half = build("onnx:span_x4_materials,engine=candle,tile=64,precision=f16");
    let got = half
        .upsample(std::slice::from_ref(&image), 4, Border::Mirror)
        .unwrap();
    let diff = common::max_abs_diff(&want[0], &got[0]);
    let mean = (want[0].data().iter().zip(got[0].data()))
        .map(|(a, b)| (a - b).abs())
        .sum::<f32>()
        / want[0].data().len() as f32;
    println!("f16: max |f16 − f32| {diff:e}, mean {mean:e}");
    // Not equal: the half-size values are rounded.
    assert!(diff > 1e-5 && diff < 1.0 / 255.0, "f16: {diff}");
    for refused in [
        "onnx:span_x4_materials,engine=candle,precision=tf32",
        "onnx:span_x4_materials,engine=candle,precision=bf16",
        "onnx:span_x4_materials,engine=matup,precision=f16",
        "onnx:span_x4_materials,engine=candle,precision=f64",
    ] {
        let err = upsampler(&refused.parse::<PluginSpec>().unwrap())
            .err()
            .expect(refused)
            .to_string();
        println!("{refused}: {err}");
        assert!(
            err.contains("precision") || err.contains("GPU"),
            "{refused}: {err}"
        );
    }
}

#[test]
fn a_tileable_image_run_whole_with_wrapping_convolutions_matches_wrap_around_tiles() {
    let image = real_render();
    // One 64² tile on matup's executor, its convolutions wrapping; against 16 tiles of 16² on
    // tract, each read with 44 texels of wrapped-around context, so that the 22 they keep
    // cover SPAN's receptive field (21).
    let diff = max_difference(
        "onnx:span_x4_ch48,engine=matup,tile=64",
        "onnx:span_x4_ch48,engine=tract,tile=16,overlap=44,batch=8",
        &image,
        4,
        Border::Wrap,
    );
    println!("max |whole wrapping − wrap-around tiles| {diff:e}");
    assert!(diff < 1e-4, "whole wrapping vs tiles: {diff}");
}

#[test]
fn graphs_with_other_operators_fall_back_to_tract_and_say_why() {
    use prost::Message;
    let source = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("models/span_x4_ch48.onnx");
    let mut model =
        tract_onnx::pb::ModelProto::decode(std::fs::read(source).unwrap().as_slice()).unwrap();
    // The first sigmoid becomes a hard sigmoid, which tract runs and matup's executor does not.
    let node = model
        .graph
        .as_mut()
        .unwrap()
        .node
        .iter_mut()
        .find(|n| n.op_type == "Sigmoid")
        .unwrap();
    node.op_type = "HardSigmoid".into();
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("hard.onnx");
    std::fs::write(&path, model.encode_to_vec()).unwrap();
    std::fs::write(path.with_extension("toml"), "scale = 4\noverlap = 22\n").unwrap();

    let auto = matup::upsamplers::onnx::OnnxUpsampler::load(
        &path,
        matup::upsamplers::onnx::EngineChoice::Auto,
    )
    .unwrap();
    assert!(auto.engine().starts_with("tract") && auto.engine().contains("HardSigmoid"));
    let out = auto
        .upsample(&[real_render()], 4, Border::Mirror)
        .unwrap()
        .remove(0);
    assert_eq!((out.width(), out.height()), (256, 256));

    let e = error_of(&format!("onnx:{},engine=matup", path.display()));
    assert!(
        e.contains("hard.onnx") && e.contains("operator HardSigmoid"),
        "{e}"
    );
    let e = error_of("onnx:span_x4_ch48,engine=fast");
    assert!(
        e.contains("engine 'fast'") && e.contains("auto, matup, tract"),
        "{e}"
    );
    let shipped = matup::upsamplers::onnx::OnnxUpsampler::load(
        &PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("models/span_x4_ch48.onnx"),
        matup::upsamplers::onnx::EngineChoice::Auto,
    )
    .unwrap();
    assert_eq!(shipped.engine(), "matup");
}

/// Records what a call reports and stops it at the `stop_at`-th report.
struct StopAt {
    seen: std::sync::Mutex<Vec<(usize, usize)>>,
    stop_at: usize,
}

impl matup::Watch for StopAt {
    fn pieces_done(&self, done: usize, total: usize) -> matup::Result<()> {
        let mut seen = self.seen.lock().unwrap();
        seen.push((done, total));
        match seen.len() == self.stop_at {
            true => Err(matup::Error::Interrupted),
            false => Ok(()),
        }
    }
}

#[test]
fn a_network_reports_each_batch_of_tiles_and_stops_where_its_watch_says() {
    let image = real_render();
    let images = std::slice::from_ref(&image);
    // matup's executor on the host, candle's engine (a GPU's path) on the CPU, and the GPU
    // engine on the tests' adapter (lavapipe in CI).
    let gpu = matup::upsamplers::gpu::test_adapter().map(|a| format!(",device=gpu:{}", a.index));
    for engine in ["", ",engine=candle"]
        .into_iter()
        .map(String::from)
        .chain(gpu)
    {
        let spec = format!("onnx:span_x4_materials,tile=16,batch=1{engine}");
        let up = build(&spec);
        let stopping = StopAt {
            seen: Default::default(),
            stop_at: 3,
        };
        let e = (up.upsample_watched(images, 4, Border::Mirror, &stopping)).unwrap_err();
        assert!(matches!(e, matup::Error::Interrupted), "{spec}: {e}");
        // 64² in 16² tiles, one a call: each reported as it finishes, none run after the stop.
        let seen = stopping.seen.into_inner().unwrap();
        assert_eq!(seen, [(1, 16), (2, 16), (3, 16)], "{spec}");

        // Watched to the end, the call makes the unwatched call's output.
        let all = StopAt {
            seen: Default::default(),
            stop_at: usize::MAX,
        };
        let watched = (up.upsample_watched(images, 4, Border::Mirror, &all)).unwrap();
        let seen = all.seen.into_inner().unwrap();
        assert_eq!((seen.len(), seen.last().copied()), (16, Some((16, 16))));
        let plain = up.upsample(images, 4, Border::Mirror).unwrap();
        assert_eq!(watched[0].data(), plain[0].data(), "{spec}");
    }
}
