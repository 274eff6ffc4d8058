//! The `matup` binary, as a user runs it.

use std::path::PathBuf;
use std::process::{Command, Output};

fn matup(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_matup"))
        .args(args)
        .output()
        .unwrap()
}

fn sample() -> String {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../samples/victorian_wood")
        .to_string_lossy()
        .into_owned()
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

#[test]
fn list_shows_every_builtin_plugin_with_options() {
    let o = matup(&["list"]);
    assert!(o.status.success());
    let text = String::from_utf8_lossy(&o.stdout);
    for name in [
        "bilinear",
        "bicubic",
        "lanczos3",
        "ggx",
        "ggx-aniso",
        "lambert",
    ] {
        assert!(text.contains(name), "{name} missing from:\n{text}");
    }
    assert!(text.contains("option a=-0.5"), "{text}");
}

#[test]
fn render_writes_a_contact_sheet_and_a_single_light() {
    let dir = tempfile::tempdir().unwrap();
    let sheet = dir.path().join("sheet.png");
    let o = matup(&[
        "render",
        &sample(),
        "-o",
        sheet.to_str().unwrap(),
        "--sheet",
        "9",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let image = image::open(&sheet).unwrap();
    // 3 × 3 renders of 128² with 2-texel gaps.
    assert_eq!((image.width(), image.height()), (3 * 130 + 2, 3 * 130 + 2));

    let one = dir.path().join("nested/one.png");
    let o = matup(&[
        "render",
        &sample(),
        "-o",
        one.to_str().unwrap(),
        "--light",
        "42",
        "--shading",
        "lambert",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let image = image::open(&one).unwrap().to_rgb8();
    assert_eq!(image.dimensions(), (128, 128));
    let mean = image.as_raw().iter().map(|&v| v as f64).sum::<f64>() / image.as_raw().len() as f64;
    assert!(
        mean > 20.0 && mean < 235.0,
        "a lit, not blank, render: mean {mean}"
    );
}

#[test]
fn bad_arguments_give_clear_errors_and_fail() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("x.png");
    let out = out.to_str().unwrap();

    let o = matup(&["render", &sample(), "-o", out, "--shading", "phong"]);
    assert!(!o.status.success());
    assert!(
        stderr(&o).contains("unknown shading model 'phong'; known: ggx, ggx-aniso, lambert"),
        "{}",
        stderr(&o)
    );

    let o = matup(&["render", &sample(), "-o", out, "--light", "100"]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("out of range"), "{}", stderr(&o));

    let into_input = format!("{}/preview.png", sample());
    let o = matup(&["render", &sample(), "-o", &into_input]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("input folder"), "{}", stderr(&o));
    assert!(!PathBuf::from(&into_input).exists());

    let o = matup(&["render", dir.path().to_str().unwrap(), "-o", out]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("no image files"), "{}", stderr(&o));
}
