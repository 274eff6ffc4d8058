//! A shading model with no Jacobian of its own: its tensor form agrees with its radiance per
//! texel, and the binary that links it trains it with the tensor backend.

use std::process::Command;

use matup_blinn_phong as _;
use matup_core::candle_core::{Device, Tensor};
use matup_core::tensor_shading::{params_tensor, LightTensors, SvbrdfTensors};
use matup_core::{shading_model, LightSetSpec, PluginSpec, Svbrdf};

#[test]
fn the_tensor_form_renders_what_shade_renders() {
    let model = shading_model(&PluginSpec::new("blinn-phong")).unwrap();
    assert!(!model.has_jacobian());
    let form = model.tensor_form().unwrap();
    let lights = LightSetSpec::default().build();
    let texels: Vec<Svbrdf> = (0..16)
        .map(|i| {
            let t = i as f32 / 16.0;
            Svbrdf {
                base_color: [0.2 + 0.5 * t, 0.6, 0.9 - 0.5 * t],
                metallic: t,
                normal: [0.3 * t - 0.1, 0.2 - 0.25 * t, 1.0],
                alpha: 0.05 + 0.8 * t,
                ..Default::default()
            }
        })
        .collect();
    let positions: Vec<[f32; 3]> = (0..16).map(|i| [i as f32 / 8.0 - 1.0, 0.3, 0.0]).collect();
    let device = Device::Cpu;
    let params = params_tensor(&texels, &device).unwrap();
    let light_tensors = LightTensors::new(&lights, &positions, &device).unwrap();
    let radiance: Tensor = form
        .shade(
            &SvbrdfTensors::from_params(&params).unwrap(),
            &light_tensors,
        )
        .unwrap();
    let radiance = radiance.to_vec3::<f32>().unwrap();
    let mut worst = 0f32;
    for (t, p) in texels.iter().enumerate() {
        for (k, light) in lights.iter().enumerate() {
            let want = model.shade(p, &light.sample_at(positions[t]));
            for c in 0..3 {
                let err = (radiance[t][k][c] - want[c]).abs() / want[c].abs().max(1e-3);
                worst = worst.max(err);
            }
        }
    }
    assert!(worst < 1e-4, "relative error {worst}");
}

#[test]
fn the_linked_binary_trains_it_with_the_tensor_backend() {
    let matup = env!("CARGO_BIN_EXE_matup-blinn-phong");
    let sample = concat!(env!("CARGO_MANIFEST_DIR"), "/../../samples/victorian_wood");
    let paper = concat!(env!("CARGO_MANIFEST_DIR"), "/../../configs/paper.toml");
    let out = tempfile::tempdir().unwrap();
    let upscale = |backend: &str| {
        Command::new(matup)
            .args(["upscale", sample, "-o"])
            .arg(out.path())
            .args([
                "--config",
                paper,
                "--shading",
                "blinn-phong",
                "--upsampler",
                "lanczos3",
            ])
            .args([
                "--epochs",
                "2",
                "--texels-per-epoch",
                "8192",
                "--lights",
                "24",
            ])
            .args(["--json", "--backend", backend])
            .output()
            .unwrap()
    };
    // The fused backend needs a Jacobian: a clear error, before training.
    let fused = upscale("fused");
    assert!(!fused.status.success());
    let stderr = String::from_utf8_lossy(&fused.stderr);
    assert!(stderr.contains("no Jacobian"), "{stderr}");

    // auto picks the tensor backend on the CPU for it.
    let o = upscale("auto");
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let report: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let training = &report["levels"][0]["training"];
    assert_eq!(training["backend"], "tensor");
    let losses: Vec<f64> = training["epoch_losses"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect();
    assert_eq!(losses.len(), 2);
    assert!(losses[1] < losses[0], "it trains: {losses:?}");
}
