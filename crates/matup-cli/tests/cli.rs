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

/// `matup ARGS` run in `folder`, with no model folder named in the environment.
#[cfg(feature = "onnx")]
fn matup_in(folder: &std::path::Path, args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_matup"))
        .args(args)
        .current_dir(folder)
        .env_remove("MATUP_MODELS")
        .output()
        .unwrap()
}

#[cfg(feature = "onnx")]
#[test]
fn the_default_networks_are_inside_the_binary() {
    let repo = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../..");
    let elsewhere = tempfile::tempdir().unwrap();
    // From another folder, out of reach of the repository's models/, `list` finds both default
    // networks in the binary; inside the repository, the files.
    let o = matup_in(elsewhere.path(), &["list"]);
    let listed = String::from_utf8_lossy(&o.stdout);
    for name in ["span_x4_materials", "span_x4_ch48"] {
        assert!(
            listed.contains(&format!("from {name} (built into matup)")),
            "{listed}"
        );
    }
    let o = matup_in(&repo, &["list"]);
    let listed = String::from_utf8_lossy(&o.stdout);
    assert!(
        listed.contains("from models/span_x4_materials.onnx"),
        "{listed}"
    );
    // The defaults run from either, to the same bytes.
    let run = |folder: &std::path::Path, out: &std::path::Path| {
        let o = matup_in(
            folder,
            &["upscale", &sample(), "-o", out.to_str().unwrap(), "--json"],
        );
        assert!(o.status.success(), "{}", stderr(&o));
        let report: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
        assert_eq!(report["upsampler_used"], "onnx:span_x4_materials");
    };
    let (inside, outside) = (elsewhere.path().join("in"), elsewhere.path().join("out"));
    run(&repo, &inside);
    run(elsewhere.path(), &outside);
    for map in ["baseColor", "normal", "roughness", "metallic", "height"] {
        let file = format!("{map}.png");
        let (a, b) = (
            std::fs::read(inside.join(&file)).unwrap(),
            std::fs::read(outside.join(&file)).unwrap(),
        );
        assert!(
            a == b,
            "{file}: the built-in network gives the file's bytes"
        );
    }
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

    // A GPU asked of a build without CUDA is refused by every command, not ignored.
    if !cfg!(feature = "cuda") {
        let folder = dir.path().join("up");
        let folder = folder.to_str().unwrap();
        for args in [
            vec!["upscale", &sample(), "-o", folder, "--device", "cuda"],
            vec!["batch", &sample(), "-o", folder, "--device", "cuda:1"],
            vec!["bench", &sample(), "-o", folder, "--device", "cuda"],
        ] {
            let o = matup(&args);
            assert!(!o.status.success(), "{args:?}");
            assert!(stderr(&o).contains("--features cuda"), "{}", stderr(&o));
        }
        assert!(
            !PathBuf::from(folder).exists(),
            "refused before writing anything"
        );
    }
}

#[test]
fn upscale_error_paths_are_clear() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    let out = out.to_str().unwrap();
    let cases: &[(&[&str], &str)] = &[
        (
            &["--upsampler", "esrgan"],
            "unknown upsampler 'esrgan'; known: bicubic, bilinear, callable, lanczos3, onnx",
        ),
        (
            &["--shading", "phong"],
            "unknown shading model 'phong'; known: ggx, ggx-aniso, lambert",
        ),
        (&["--scale", "4.5"], "--scale '4.5' is not a whole number"),
        (
            &["--scale", "5"],
            "unsupported scale ×5; use 2, 3, 4, 8 or 16",
        ),
        (&["--window", "16"], "filter.window must be odd"),
        (&["--size", "64"], "not larger than the 128×128 input"),
        (&["--size", "3000"], "more than ×16 of the 128×128 input"),
        (&["--size", "big"], "give texels as 4096, 4K or 4096x2048"),
        (&["--size", "256", "--scale", "2"], "cannot be used with"),
        (&["--loss", "l3"], "unknown loss norm 'l3'"),
    ];
    for (extra, message) in cases {
        let sample = sample();
        let mut args = vec!["upscale", sample.as_str(), "-o", out, "--quiet"];
        args.extend_from_slice(extra);
        let o = matup(&args);
        assert!(!o.status.success(), "{extra:?} should fail");
        assert!(stderr(&o).contains(message), "{extra:?}: {}", stderr(&o));
    }
    assert!(
        !std::path::Path::new(out).exists(),
        "a refused run leaves no output folder"
    );
    // The output folder may not be the input folder, nor a file.
    let o = matup(&["upscale", &sample(), "-o", &sample(), "--quiet"]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("input folder"), "{}", stderr(&o));
    let file = dir.path().join("a-file");
    std::fs::write(&file, "x").unwrap();
    let o = matup(&[
        "upscale",
        &sample(),
        "-o",
        file.to_str().unwrap(),
        "--quiet",
    ]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("a-file"), "{}", stderr(&o));
    // A malformed configuration names its file, line and key.
    let toml = dir.path().join("bad.toml");
    std::fs::write(&toml, "[train]\nepochz = 3\n").unwrap();
    let o = matup(&[
        "upscale",
        &sample(),
        "-o",
        out,
        "--config",
        toml.to_str().unwrap(),
    ]);
    assert!(!o.status.success());
    let e = stderr(&o);
    assert!(
        e.contains("bad.toml") && e.contains("epochz") && e.contains("line 2"),
        "{e}"
    );
}

#[test]
fn upscale_writes_maps_preview_and_run_json() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    let o = matup(&[
        "upscale",
        &sample(),
        "-o",
        out.to_str().unwrap(),
        "--json",
        "--epochs",
        "1",
        "--texels-per-epoch",
        "2048",
        "--lights",
        "8",
        "--upsampler",
        "bilinear",
        "--seed",
        "3",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let report: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(report["output_size"], serde_json::json!([512, 512]));
    assert_eq!(report["config"]["seed"], 3);
    assert!(report["final_loss"].as_f64().unwrap() > 0.0);
    for f in [
        "baseColor.png",
        "normal.png",
        "roughness.png",
        "metallic.png",
        "height.png",
        "preview.png",
        "run.json",
    ] {
        assert!(out.join(f).is_file(), "{f} missing");
    }
    let base = image::open(out.join("baseColor.png")).unwrap();
    assert_eq!((base.width(), base.height()), (512, 512));
    // The preview: 2 × 2 renders of 512² with 4-texel gaps, under a header strip naming the
    // columns and a caption strip over each row (20 texels each).
    let preview = image::open(out.join("preview.png")).unwrap().to_luma8();
    assert_eq!(
        (preview.width(), preview.height()),
        (2 * 516 + 4, 2 * 516 + 4 + 3 * 20)
    );
    let ink = |x0: u32, x1: u32, y0: u32, y1: u32| {
        (y0..y1)
            .flat_map(|y| (x0..x1).map(move |x| (x, y)))
            .filter(|&(x, y)| preview.get_pixel(x, y)[0] > 150)
            .count()
    };
    assert!(
        ink(150, 370, 0, 20) > 40,
        "'bilinear ×4' over the left column"
    );
    assert!(ink(670, 890, 0, 20) > 20, "'matup' over the right column");
    assert!(ink(0, 300, 24, 44) > 100, "the first row's light caption");
    assert!(
        ink(0, 300, 560, 580) > 100,
        "the second row's light caption"
    );
    assert!(
        !out.join(".matup-checkpoint").exists(),
        "a finished run leaves no checkpoint"
    );
}

/// A real material the repository ships for its tests (`tests/data/README.md`).
fn test_material(name: &str) -> String {
    format!(
        "{}/../../tests/data/materials/{name}",
        env!("CARGO_MANIFEST_DIR")
    )
}

#[test]
fn downsample_then_eval_reports_a_table_and_json() {
    let dir = tempfile::tempdir().unwrap();
    let lr = dir.path().join("lr");
    let o = matup(&[
        "downsample",
        &sample(),
        "-o",
        lr.to_str().unwrap(),
        "--factor",
        "4",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let base = image::open(lr.join("baseColor.png")).unwrap();
    assert_eq!((base.width(), base.height()), (32, 32));
    // Never into the input folder; factors that do not divide are refused.
    let o = matup(&["downsample", &sample(), "-o", &sample()]);
    assert!(!o.status.success());
    let o = matup(&[
        "downsample",
        &sample(),
        "-o",
        lr.to_str().unwrap(),
        "--factor",
        "3",
    ]);
    assert!(
        stderr(&o).contains("not divisible by --factor 3"),
        "{}",
        stderr(&o)
    );

    let o = matup(&[
        "eval",
        "--reference",
        &sample(),
        "--candidate",
        &sample(),
        "--lights",
        "4",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let table = String::from_utf8_lossy(&o.stdout);
    assert!(
        table.contains("render PSNR (dB)") && table.contains("100.00"),
        "{table}"
    );

    // False colour: the input comes from the output's run.json (or --input).
    let up = dir.path().join("up");
    let o = matup(&[
        "upscale",
        lr.to_str().unwrap(),
        "-o",
        up.to_str().unwrap(),
        "--quiet",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let o = matup(&[
        "eval",
        "--reference",
        &sample(),
        "--candidate",
        up.to_str().unwrap(),
        "--lights",
        "2",
        "--json",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let e: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(e["false_colour_texels"].as_f64(), Some(0.0), "{e}");
    let o = matup(&[
        "eval",
        "--candidate",
        &sample(),
        "--input",
        lr.to_str().unwrap(),
    ]);
    let table = String::from_utf8_lossy(&o.stdout);
    assert!(
        table.contains("false colour (against the input alone)"),
        "{table}"
    );
    let o = matup(&["eval", "--candidate", &sample()]);
    let table = String::from_utf8_lossy(&o.stdout);
    assert!(table.contains("false colour: needs the input"), "{table}");

    let o = matup(&[
        "eval",
        "--reference",
        &sample(),
        "--candidate",
        lr.to_str().unwrap(),
    ]);
    assert!(!o.status.success());
    assert!(
        stderr(&o).contains("128×128") && stderr(&o).contains("32×32"),
        "{}",
        stderr(&o)
    );

    let denim = test_material("polyhaven_denim_fabric");
    let metal = test_material("ambientcg_Metal053C");
    let o = matup(&[
        "eval",
        "--reference",
        &denim,
        "--candidate",
        &metal,
        "--json",
        "--lights",
        "2",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let e: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert!(e["render_psnr"].as_f64().unwrap() < 30.0);
    assert!(
        e["metallic_rmse"].as_f64().unwrap() > 0.1,
        "metal against cloth"
    );
    assert!(e["map_seams"]["normal"].as_f64().unwrap() > 0.0);

    // Without a reference: each map's wrap-around seam. The whole denim tiles; a crop of it
    // at an odd offset does not.
    let crop = dir.path().join("crop");
    let whole = matup_core::load_material(
        Some(std::path::Path::new(&denim)),
        &matup_core::LoadOptions::default(),
    )
    .unwrap();
    matup_core::save_material(
        &whole.crop(37, 53, 128, 128),
        &crop,
        &matup_core::SaveOptions::default(),
    )
    .unwrap();
    let seams = |folder: &str| {
        let o = matup(&["eval", "--candidate", folder, "--json"]);
        assert!(o.status.success(), "{}", stderr(&o));
        let report: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
        let seams = report["map_seams"].as_object().unwrap().clone();
        let names: Vec<&str> = seams.keys().map(String::as_str).collect();
        assert_eq!(
            names,
            ["baseColor", "height", "metallic", "normal", "roughness"]
        );
        let ratio = |map: &str| seams[map].as_f64().unwrap();
        // Its two parts: the wrap-around step over the mean interior step.
        for map in ["baseColor", "normal"] {
            let steps = &report["map_seam_steps"][map];
            let part = |k: &str| steps[k].as_f64().unwrap();
            assert!(part("wrap") > 0.0 && part("interior") > 0.0, "{steps}");
            assert!((part("wrap") / part("interior") - ratio(map)).abs() < 1e-9);
        }
        (ratio("baseColor"), ratio("normal"))
    };
    let (whole_colour, whole_normal) = seams(&denim);
    let (crop_colour, crop_normal) = seams(crop.to_str().unwrap());
    println!("denim seams: whole {whole_colour:.2} / {whole_normal:.2}, crop {crop_colour:.2} / {crop_normal:.2}");
    // Measured: whole 0.98 / 1.29, crop 1.64 / 3.02 (base colour / normal).
    assert!(whole_colour < 1.5 && whole_normal < 1.5);
    assert!(crop_colour > 1.5 * whole_colour && crop_normal > 2.0 * whole_normal);
    let o = matup(&["eval", "--candidate", &denim]);
    let table = String::from_utf8_lossy(&o.stdout);
    assert!(
        table.contains("seam ratio per map") && table.contains("baseColor"),
        "{table}"
    );
}

#[test]
fn sweep_rejects_bad_files_before_running() {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("exp.toml");
    std::fs::write(
        &file,
        "materials = [\"m\"]\n[axes]\nupsampler = [\"esrgan\"]\n",
    )
    .unwrap();
    let o = matup(&[
        "sweep",
        file.to_str().unwrap(),
        "-o",
        dir.path().join("out").to_str().unwrap(),
    ]);
    assert!(!o.status.success());
    assert!(
        stderr(&o).contains("esrgan") && stderr(&o).contains("known"),
        "{}",
        stderr(&o)
    );
    let o = matup(&["sweep", dir.path().join("missing.toml").to_str().unwrap()]);
    assert!(stderr(&o).contains("missing.toml"), "{}", stderr(&o));
    // A missing material stops the bench before anything runs, naming it.
    let out = dir.path().join("bench");
    let o = matup(&[
        "bench",
        "/no/such/material",
        "-o",
        out.to_str().unwrap(),
        "--baselines",
        "bilinear",
        "--upsamplers",
        "bilinear",
        "--quiet",
    ]);
    let e = stderr(&o);
    assert!(!o.status.success());
    assert!(
        e.contains("material folders are missing: /no/such/material"),
        "{e}"
    );
    assert!(!out.join("results.jsonl").exists(), "nothing ran");
}

/// `path` with `.` and `..` resolved lexically (the folders need not exist).
fn normalised(path: &std::path::Path) -> PathBuf {
    let mut out = PathBuf::new();
    for part in path.components() {
        match part {
            std::path::Component::ParentDir => {
                out.pop();
            }
            std::path::Component::CurDir => {}
            other => out.push(other),
        }
    }
    out
}

#[test]
fn the_shipped_sweeps_parse_and_expand() {
    // Expanding checks the plugins each point names: link the built-in ones.
    use matup_shading as _;
    use matup_upsamplers as _;
    // Their materials are the shared sets in the folder beside the repository (which a clone
    // alone lacks: the sweep then stops and says so), named as such.
    let repo = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../..");
    let beside = |set: &str, name: &std::ffi::OsStr| {
        std::path::absolute(repo.join("..").join("shared").join(set).join(name)).unwrap()
    };
    for (name, points) in [("loss_norms", 4), ("window", 4), ("lights", 4)] {
        let path = repo.join(format!("sweeps/{name}.toml"));
        let e = matup_apps::experiment::Experiment::from_file(&path)
            .unwrap_or_else(|e| panic!("{name}: {e}"));
        assert_eq!(e.points().unwrap().len(), points, "{name}");
        for m in &e.materials {
            let m = normalised(m);
            let named = m.file_name().unwrap();
            assert!(
                m == normalised(&beside("materials", named))
                    || m == normalised(&beside("corpus", named)),
                "{name}: {}",
                m.display()
            );
        }
    }
}

#[test]
fn bench_view_keeps_every_method_and_writes_a_page_per_material() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("bench");
    let o = matup(&[
        "bench",
        &sample(),
        "-o",
        out.to_str().unwrap(),
        "--crop",
        "64",
        "--baselines",
        "bilinear,bicubic",
        "--upsamplers",
        "bilinear",
        "--view",
        "--quiet",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let index = std::fs::read_to_string(out.join("outputs/index.html")).unwrap();
    assert!(
        index.contains(r#"<a href="./victorian_wood/view.html">"#),
        "{index}"
    );
    let folder = out.join("outputs/victorian_wood");
    let page = std::fs::read_to_string(folder.join("view.html")).unwrap();
    let data = page
        .split(r#"<script id="data" type="application/json">"#)
        .nth(1)
        .and_then(|rest| rest.split("</script>").next())
        .unwrap();
    let data: serde_json::Value = serde_json::from_str(data).unwrap();
    let label = |v: &serde_json::Value| v["label"].as_str().unwrap().to_string();
    assert!(
        label(&data["main"]).starts_with("matup"),
        "{}",
        label(&data["main"])
    );
    let menu: Vec<String> = data["comparisons"]
        .as_array()
        .unwrap()
        .iter()
        .map(label)
        .collect();
    assert_eq!(menu.len(), 3, "{menu:?}");
    assert_eq!(menu[0], "truth", "the truth first");
    assert!(menu[1..].iter().any(|m| m.contains("bicubic")), "{menu:?}");
    for m in menu {
        let base = image::open(folder.join(&m).join("baseColor.png")).unwrap();
        assert_eq!((base.width(), base.height()), (64, 64), "{m}");
    }
}

#[cfg(feature = "onnx")]
#[test]
fn learn_trains_on_pairs_equal_to_what_matup_downsample_writes() {
    use matup_core::{load_material, LoadOptions};
    let truth_folder = test_material("ambientcg_Rock029");
    let dir = tempfile::tempdir().unwrap();
    let lr_folder = dir.path().join("lr");
    let o = matup(&[
        "downsample",
        &truth_folder,
        "-o",
        lr_folder.to_str().unwrap(),
        "--factor",
        "4",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let load =
        |folder: &std::path::Path| load_material(Some(folder), &LoadOptions::default()).unwrap();
    let pair = matup_learn::data::Pair::new(load(std::path::Path::new(&truth_folder)), 4);
    let written = load(&lr_folder);
    // The files hold 8-bit values: within half a step (base colour in sRGB, so compare there).
    let srgb = |m: &matup_core::Map| m.clone().map_values(matup_core::color::linear_to_srgb);
    for (ours, file, what) in [
        (
            srgb(&pair.lr.base_color),
            srgb(&written.base_color),
            "base colour",
        ),
        (
            pair.lr.roughness.clone(),
            written.roughness.clone(),
            "roughness",
        ),
        (
            pair.lr.metallic.clone(),
            written.metallic.clone(),
            "metallic",
        ),
        (
            pair.lr.height.clone().unwrap(),
            written.height.clone().unwrap(),
            "height",
        ),
    ] {
        let worst = ours
            .data()
            .iter()
            .zip(file.data())
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f32::max);
        assert!(worst <= 0.5 / 255.0 + 1e-5, "{what}: {worst}");
    }
    let angle = matup_eval::metrics::mean_angle_degrees(&pair.lr.normal, &written.normal);
    assert!(angle < 0.3, "normals {angle}°");
}

#[test]
fn a_run_logged_to_a_file_writes_a_line_per_stage_with_its_time() {
    // stderr is a pipe here, as a log file or a cluster job's is: no bars are drawn, so each
    // stage is logged as it starts and ends.
    let out = tempfile::tempdir().unwrap();
    let o = matup(&[
        "upscale",
        &sample(),
        "-o",
        out.path().join("o").to_str().unwrap(),
        "--upsampler",
        "bicubic",
    ]);
    let err = stderr(&o);
    assert!(o.status.success(), "{err}");
    for stage in ["level 1: residual base", "infer"] {
        let started = format!("] {stage}: started");
        let line = (err.lines())
            .find(|l| l.contains(&started))
            .unwrap_or_else(|| panic!("no line for {stage} starting:\n{err}"));
        assert!(line.starts_with("[0:0"), "elapsed time first: {line}");
        assert!(
            err.lines()
                .any(|l| l.contains(&format!("] {stage}: done in 0:"))),
            "no line for {stage} ending:\n{err}"
        );
    }
}

/// A glTF quad whose material shows the sample's colour and normal maps, in `folder`.
#[cfg(unix)]
fn sample_model(folder: &std::path::Path) -> PathBuf {
    let floats = |v: &[f32]| v.iter().flat_map(|f| f.to_le_bytes()).collect::<Vec<u8>>();
    let mut bin = floats(&[0., 0., 0., 1., 0., 0., 1., 1., 0., 0., 1., 0.]);
    bin.extend(floats(&[0., 1., 1., 1., 1., 0., 0., 0.]));
    bin.extend([0u16, 1, 2, 0, 2, 3].iter().flat_map(|i| i.to_le_bytes()));
    std::fs::write(folder.join("quad.bin"), &bin).unwrap();
    for name in ["baseColor.png", "normal.png"] {
        std::fs::copy(PathBuf::from(sample()).join(name), folder.join(name)).unwrap();
    }
    let json = serde_json::json!({
        "asset": {"version": "2.0"},
        "meshes": [{"primitives": [{
            "attributes": {"POSITION": 0, "TEXCOORD_0": 1}, "indices": 2, "material": 0
        }]}],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3",
             "min": [0, 0, 0], "max": [1, 1, 0]},
            {"bufferView": 1, "componentType": 5126, "count": 4, "type": "VEC2"},
            {"bufferView": 2, "componentType": 5123, "count": 6, "type": "SCALAR"}
        ],
        "bufferViews": [
            {"buffer": 0, "byteOffset": 0, "byteLength": 48},
            {"buffer": 0, "byteOffset": 48, "byteLength": 32},
            {"buffer": 0, "byteOffset": 80, "byteLength": 12}
        ],
        "buffers": [{"uri": "quad.bin", "byteLength": bin.len()}],
        "materials": [{
            "pbrMetallicRoughness": {"baseColorTexture": {"index": 0}},
            "normalTexture": {"index": 1}
        }],
        "textures": [{"source": 0}, {"source": 1}],
        "images": [{"uri": "baseColor.png"}, {"uri": "normal.png"}]
    });
    let model = folder.join("quad.gltf");
    std::fs::write(&model, serde_json::to_vec(&json).unwrap()).unwrap();
    model
}

#[cfg(unix)]
#[test]
fn an_interrupted_model_run_leaves_no_working_folder_and_no_model() {
    use std::io::{BufRead, BufReader};
    let dir = tempfile::tempdir().unwrap();
    let model = sample_model(dir.path());
    let out = dir.path().join("out");
    let mut child = Command::new(env!("CARGO_BIN_EXE_matup"))
        .args([
            "upscale",
            model.to_str().unwrap(),
            "-o",
            out.to_str().unwrap(),
        ])
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let mut log = String::new();
    let mut lines = BufReader::new(child.stderr.take().unwrap()).lines();
    // Ctrl-C once the upscaling has begun: its textures are unpacked in the working folder.
    for line in lines.by_ref() {
        let line = line.unwrap();
        log += &line;
        log += "\n";
        if line.contains("residual base: started") {
            assert!(out.join(".matup-model").is_dir(), "{log}");
            let pid = child.id().to_string();
            assert!(Command::new("kill")
                .args(["-INT", &pid])
                .status()
                .unwrap()
                .success());
            break;
        }
    }
    for line in lines {
        log += &line.unwrap();
        log += "\n";
    }
    let status = child.wait().unwrap();
    assert!(!status.success(), "{log}");
    assert!(log.contains("interrupted"), "{log}");
    assert!(!out.join(".matup-model").exists(), "{log}");
    assert!(
        !out.join("quad.gltf").exists(),
        "no model half written: {log}"
    );
}

#[cfg(unix)]
#[test]
fn a_model_missing_its_buffer_is_refused_before_any_work() {
    let dir = tempfile::tempdir().unwrap();
    let model = sample_model(dir.path());
    std::fs::remove_file(dir.path().join("quad.bin")).unwrap();
    let out = dir.path().join("out");
    let o = matup(&[
        "upscale",
        model.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
    ]);
    let err = stderr(&o);
    assert!(!o.status.success());
    assert!(
        err.contains("'quad.bin'") && err.contains("cannot be read"),
        "{err}"
    );
    assert!(!out.exists(), "nothing was made: {err}");
}

/// Where the machine offers no GPU adapter (here: Vulkan's loader pointed at no driver, and no
/// Metal or DirectX 12 on Linux), `auto` runs the networks on the CPU and says why in
/// run.json, `list` says there is none, and `--device gpu` is refused, naming the problem.
#[cfg(all(feature = "onnx", target_os = "linux"))]
#[test]
fn with_no_gpu_adapter_auto_runs_on_the_cpu_and_says_why() {
    let dir = tempfile::tempdir().unwrap();
    let no_driver = dir.path().join("no-driver.json");
    let without_adapters = |args: &[&str]| {
        Command::new(env!("CARGO_BIN_EXE_matup"))
            .args(args)
            .env("VK_ICD_FILENAMES", &no_driver)
            .env("VK_DRIVER_FILES", &no_driver)
            .output()
            .unwrap()
    };
    let o = without_adapters(&["list"]);
    let text = String::from_utf8_lossy(&o.stdout);
    assert!(
        text.contains("none: this machine offers no Vulkan, Metal or DirectX 12 adapter")
            && text.contains("--device auto runs the networks on the CPU"),
        "{text}"
    );
    let out = dir.path().join("out");
    let o = without_adapters(&["upscale", &sample(), "-o", out.to_str().unwrap(), "--quiet"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let report: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("run.json")).unwrap()).unwrap();
    assert_eq!(
        report["network_devices"],
        serde_json::json!([
            "onnx:span_x4_materials: matup on the CPU: device=auto found no hardware GPU \
             adapter (software ones run only when named: gpu:NAME)"
        ])
    );
    let refused = dir.path().join("refused");
    let o = without_adapters(&[
        "upscale",
        &sample(),
        "-o",
        refused.to_str().unwrap(),
        "--device",
        "gpu",
    ]);
    assert!(!o.status.success());
    assert!(
        stderr(&o).contains("device 'gpu': no such GPU adapter (this machine offers no Vulkan"),
        "{}",
        stderr(&o)
    );
    assert!(!refused.exists(), "refused before writing anything");
}
