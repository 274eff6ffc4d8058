//! The example plugin is found by name, behaves as documented, and works from the command line
//! of the binary that links it.

use std::process::Command;

use matup_core::{upsampler, Border, Kernel, Map, PluginSpec};
use matup_unsharp as _;

fn unsharp(spec: &str) -> Box<dyn matup_core::RgbUpsampler> {
    upsampler(&spec.parse::<PluginSpec>().unwrap()).unwrap()
}

/// A vertical step edge from 0.2 to 0.8, 16² texels.
fn step() -> Map {
    Map::from_fn(16, 16, 3, |_, _, x| if x < 8 { 0.2 } else { 0.8 })
}

#[test]
fn amount_zero_is_lanczos3_and_more_amount_steepens_edges() {
    let image = step();
    let plain = unsharp("unsharp:amount=0")
        .upsample(std::slice::from_ref(&image), 4, Border::Clamp)
        .unwrap()
        .remove(0);
    let lanczos = matup_core::resample::upsample(&image, 4, Kernel::Lanczos3, Border::Clamp);
    let clamped = lanczos.map_values(|v| v.clamp(0.0, 1.0));
    assert_eq!(plain.data(), clamped.data());

    // The steepest step between neighbouring texels across the edge, on one row.
    let steepest = |m: &Map| {
        (1..m.width())
            .map(|x| m.get(0, 20, x) - m.get(0, 20, x - 1))
            .fold(0.0f32, f32::max)
    };
    let sharp = unsharp("unsharp")
        .upsample(std::slice::from_ref(&image), 4, Border::Clamp)
        .unwrap()
        .remove(0);
    assert!(
        steepest(&sharp) > 1.2 * steepest(&plain),
        "{} vs {}",
        steepest(&sharp),
        steepest(&plain)
    );
    assert!(sharp.data().iter().all(|v| (0.0..=1.0).contains(v)));
    // Flat regions stay flat: the mask only acts near the edge.
    assert!((sharp.get(1, 20, 2) - 0.2).abs() < 1e-5);
    assert!((sharp.get(1, 20, 60) - 0.8).abs() < 1e-5);
}

#[test]
fn bad_options_name_the_plugin() {
    let e = upsampler(&"unsharp:amount=lots".parse::<PluginSpec>().unwrap())
        .err()
        .unwrap()
        .to_string();
    assert!(e.contains("unsharp") && e.contains("amount"), "{e}");
}

#[test]
fn the_linked_binary_lists_and_uses_the_plugin() {
    let matup = env!("CARGO_BIN_EXE_matup-unsharp");
    let list = Command::new(matup).arg("list").output().unwrap();
    let listed = String::from_utf8_lossy(&list.stdout);
    assert!(list.status.success());
    // The example plugin joins the built-in ones.
    assert!(
        listed.contains("unsharp") && listed.contains("lanczos3"),
        "{listed}"
    );

    let sample = concat!(env!("CARGO_MANIFEST_DIR"), "/../../samples/victorian_wood");
    let out = tempfile::tempdir().unwrap();
    let o = Command::new(matup)
        .args(["upscale", sample, "-o"])
        .arg(out.path())
        .args(["--json", "--epochs", "1", "--texels-per-epoch", "2048"])
        .args([
            "--lights",
            "8",
            "--upsampler",
            "unsharp:amount=0.8",
            "--seed",
            "1",
        ])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let report: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(report["upsampler_used"], "unsharp:amount=0.8");
    assert!(out.path().join("baseColor.png").is_file());
}
