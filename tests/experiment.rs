//! Evaluation, baselines and experiments (`matup eval`, `bench`, `sweep`) on real materials.

mod common;

use std::collections::BTreeMap;

use matup::experiment::{read_journal, run_experiment, Experiment, Method};
use matup::material::Material;
use matup::metrics::{evaluate, MAX_PSNR};
use matup::progress::Silent;
use matup::{shading_model, LightSetSpec, PluginSpec};

fn denim(size: usize) -> Material {
    let m = common::load_test_material("polyhaven_denim_fabric");
    m.crop(0, 0, size, size)
}

fn eval(reference: &Material, candidate: &Material) -> matup::metrics::Evaluation {
    let ggx = shading_model(&PluginSpec::new("ggx")).unwrap();
    evaluate(
        reference,
        candidate,
        1,
        ggx.as_ref(),
        &LightSetSpec::held_out(8),
    )
    .unwrap()
}

#[test]
fn a_material_against_itself_scores_perfectly_and_a_shifted_copy_worse() {
    let m = denim(96);
    let same = eval(&m, &m);
    assert_eq!(same.render_psnr, MAX_PSNR);
    assert!(
        (same.render_ssim - 1.0).abs() < 1e-9,
        "{}",
        same.render_ssim
    );
    assert_eq!(same.render_flip, 0.0);
    for e in [
        same.base_color_rmse,
        same.normal_error_degrees,
        same.roughness_rmse,
        same.metallic_rmse,
    ] {
        assert_eq!(e, 0.0);
    }

    // The same texture moved by 2 texels: every number gets worse.
    let big = denim(98);
    let shifted = big.crop(2, 2, 96, 96);
    let moved = eval(&m, &shifted);
    println!("shifted by 2: {moved:?}");
    assert!(moved.render_psnr < 40.0, "{}", moved.render_psnr);
    assert!(moved.render_ssim < 0.95);
    assert!(moved.render_flip > 0.02);
    assert!(moved.base_color_rmse > 0.01);
    assert!(moved.normal_error_degrees > 0.5);
    assert!(moved.roughness_rmse > 0.01);
}

#[test]
fn materials_of_different_sizes_are_refused_with_both_sizes() {
    let ggx = shading_model(&PluginSpec::new("ggx")).unwrap();
    let e = evaluate(
        &denim(64),
        &denim(32),
        1,
        ggx.as_ref(),
        &LightSetSpec::held_out(4),
    )
    .unwrap_err()
    .to_string();
    assert!(e.contains("64×64") && e.contains("32×32"), "{e}");
}

fn experiment(text: &str) -> Experiment {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("e.toml");
    std::fs::write(&path, text).unwrap();
    Experiment::from_file(&path).unwrap()
}

fn experiment_error(text: &str) -> String {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("bad.toml");
    std::fs::write(&path, text).unwrap();
    match Experiment::from_file(&path).and_then(|e| e.runs()) {
        Ok(_) => panic!("accepted:\n{text}"),
        Err(e) => e.to_string(),
    }
}

#[test]
fn sweeps_expand_to_every_point_of_the_grid_or_zip() {
    let grid = experiment(
        r#"
materials = ["/a", "/b"]
baselines = ["bilinear", "lanczos3"]
oracle = true
[base.train]
epochs = 2
[axes]
"train.loss" = ["l21", "l11", "lpq:1.5,1"]
"filter.window" = [9, 17]
"#,
    );
    let points = grid.points().unwrap();
    assert_eq!(points.len(), 6);
    assert!(points
        .iter()
        .all(|(_, c)| c.train.epochs == 2 && c.scale == 4));
    assert!(points
        .iter()
        .any(|(s, c)| s["filter.window"] == "9" && c.filter.window == 9));
    // Per material: 2 baselines, 6 matup points, 6 oracles (one per point: no upsampler axis).
    let runs = grid.runs().unwrap();
    assert_eq!(runs.len(), 2 * (2 + 6 + 6));
    let ids: std::collections::BTreeSet<&str> = runs.iter().map(|r| r.id.as_str()).collect();
    assert_eq!(ids.len(), runs.len(), "run ids are unique");

    let zip = experiment(
        r#"
materials = ["/a"]
mode = "zip"
[axes]
"lights.count" = [10, 20, 30]
"train.batch_size" = [64, 128, 256]
"#,
    );
    let points = zip.points().unwrap();
    assert_eq!(points.len(), 3);
    assert_eq!(
        (points[2].1.lights.count, points[2].1.train.batch_size),
        (30, 256)
    );
    // An upsampler axis: the oracle ignores the upsampler, so it runs once.
    let oracle = experiment(
        r#"
materials = ["/a"]
oracle = true
[base.train]
epochs = 1
[axes]
upsampler = ["bilinear", "bicubic"]
"#,
    );
    let runs = oracle.runs().unwrap();
    assert_eq!(runs.len(), 3);
    assert_eq!(
        runs.iter()
            .filter(|r| matches!(r.method, Method::Oracle(_)))
            .count(),
        1
    );
    // Without training (the defaults) there is no ceiling to measure.
    let untrained = experiment("materials = [\"/a\"]\noracle = true\n");
    let e = untrained.runs().unwrap_err().to_string();
    assert!(e.contains("train.epochs = 0") && e.contains("paper"), "{e}");
}

#[test]
fn bad_experiment_files_say_what_and_where() {
    let e = experiment_error("materials = [\"/a\"]\nfactr = 4\n");
    assert!(
        e.contains("bad.toml") && e.contains("factr") && e.contains("line 2"),
        "{e}"
    );
    let e = experiment_error("materials = [\"/a\"\n");
    assert!(e.contains("bad.toml") && e.contains("line 1"), "{e}");
    // Unknown configuration keys list the valid ones.
    let e = experiment_error("materials = [\"/a\"]\n[axes]\n\"train.epoch\" = [1, 2]\n");
    assert!(e.contains("train.epoch") && e.contains("epochs"), "{e}");
    // Unknown values: a loss norm, an upsampler, a shading model.
    let e = experiment_error("materials = [\"/a\"]\n[axes]\n\"train.loss\" = [\"l21\", \"l3\"]\n");
    assert!(e.contains("l3"), "{e}");
    let e = experiment_error("materials = [\"/a\"]\n[axes]\nupsampler = [\"esrgan\"]\n");
    assert!(e.contains("esrgan") && e.contains("lanczos3"), "{e}");
    let e = experiment_error("materials = [\"/a\"]\n[axes]\nshading = [\"phong\"]\n");
    assert!(e.contains("phong") && e.contains("ggx"), "{e}");
    let e = experiment_error(
        "materials = [\"/a\"]\nmode = \"zip\"\n[axes]\nseed = [1, 2]\n\"lights.count\" = [3]\n",
    );
    assert!(e.contains("zip"), "{e}");
    let e = experiment_error("materials = []\n");
    assert!(e.contains("no materials"), "{e}");
    let e = experiment_error("materials = [\"/a/wood\", \"/b/wood\"]\n");
    assert!(e.contains("wood") && e.contains("different names"), "{e}");
}

#[test]
fn experiments_record_failures_and_resume_without_rerunning() {
    let out = tempfile::tempdir().unwrap();
    let denim = common::test_material("polyhaven_denim_fabric");
    // A material whose base colour is cut short: its runs fail, recorded.
    let broken = out.path().join("broken");
    std::fs::create_dir(&broken).unwrap();
    for entry in std::fs::read_dir(&denim).unwrap() {
        let path = entry.unwrap().path();
        std::fs::copy(&path, broken.join(path.file_name().unwrap())).unwrap();
    }
    let base = broken.join("baseColor.png");
    let bytes = std::fs::read(&base).unwrap();
    std::fs::write(&base, &bytes[..bytes.len() / 2]).unwrap();
    let mut exp = Experiment {
        materials: vec![denim.clone(), broken.clone()],
        factor: 4,
        crop: Some(64),
        crop_at: 0,
        eval_lights: 4,
        eval_shading: "ggx".into(),
        baselines: vec!["bilinear".into(), "lanczos3".into()],
        oracle: false,
        base: toml::from_str(
            "upsampler = \"bilinear\"\n[lights]\ncount = 6\n[train]\nepochs = 1\ntexels_per_epoch = 512\n",
        )
        .unwrap(),
        axes: BTreeMap::from([(
            "train.loss".to_string(),
            vec![toml::Value::from("l21"), toml::Value::from("l11")],
        )]),
        mode: Default::default(),
        degrade: Vec::new(),
        view: false,
    };
    let runs = exp.runs().unwrap();
    assert_eq!(runs.len(), 2 * 4);
    // A material folder that is not there stops the sweep before anything runs.
    let mut absent = exp.clone();
    absent.materials.push("/no/such/wood".into());
    let e = run_experiment(&absent, &absent.runs().unwrap(), out.path(), &Silent)
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("1 of the experiment's 3 material folders are missing: /no/such/wood")
            && e.contains("put each"),
        "{e}"
    );
    assert!(!out.path().join("results.jsonl").exists());
    let rows = run_experiment(&exp, &runs, out.path(), &Silent).unwrap();
    assert_eq!(rows.len(), 8);
    let (ok, failed): (Vec<_>, Vec<_>) = rows.iter().partition(|r| r.error.is_none());
    assert_eq!(ok.len(), 4, "every run on the real material finished");
    assert!(failed
        .iter()
        .all(|r| r.error.as_ref().unwrap().contains("baseColor.png")));
    // Per-map lanczos3 beats per-map bilinear on denim's fine weave.
    let psnr = |id: &str| {
        ok.iter()
            .find(|r| r.id.ends_with(id))
            .unwrap()
            .metric("render_psnr")
    };
    assert!(psnr("per-map upsampler=lanczos3") > psnr("per-map upsampler=bilinear"));
    let csv = std::fs::read_to_string(out.path().join("results.csv")).unwrap();
    assert_eq!(csv.lines().count(), 1 + 8);
    assert!(csv.lines().next().unwrap().contains("train.loss"));

    // Run again: the finished runs are skipped (no new journal lines), the failed ones retried.
    let before = read_journal(&out.path().join("results.jsonl"))
        .unwrap()
        .len();
    exp.materials.truncate(1);
    let runs = exp.runs().unwrap();
    let rows = run_experiment(&exp, &runs, out.path(), &Silent).unwrap();
    assert_eq!(rows.len(), 4);
    assert_eq!(
        read_journal(&out.path().join("results.jsonl"))
            .unwrap()
            .len(),
        before
    );
}

#[test]
fn every_shipped_sweep_reads_and_its_points_are_valid_settings() {
    // Settings only: their networks may lie beside the repository or in runs/, which a clone
    // lacks.
    let folder = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("sweeps");
    let mut read = 0;
    for entry in std::fs::read_dir(&folder).unwrap() {
        let path = entry.unwrap().path();
        if path.extension().is_none_or(|e| e != "toml") {
            continue;
        }
        let name = path.file_name().unwrap().to_string_lossy().into_owned();
        let experiment = Experiment::from_file(&path).unwrap();
        let points = (experiment.settings()).unwrap_or_else(|e| panic!("{name}: {e}"));
        assert!(!points.is_empty(), "{name}: no points");
        read += 1;
    }
    assert!(read >= 30, "{read} sweeps in {}", folder.display());
}

#[test]
fn degraded_inputs_run_beside_clean_ones_against_the_clean_truth() {
    let out = tempfile::tempdir().unwrap();
    let denim = common::test_material("polyhaven_denim_fabric");
    let exp = Experiment {
        materials: vec![denim],
        factor: 4,
        crop: Some(64),
        eval_lights: 4,
        eval_shading: "ggx".into(),
        baselines: vec!["lanczos3".into()],
        degrade: vec!["clean".into(), "jpeg30".into(), "bc1".into()],
        base: toml::from_str("upsampler = \"bilinear\"").unwrap(),
        ..Default::default()
    };
    let runs = exp.runs().unwrap();
    let ids: Vec<&str> = runs.iter().map(|r| r.id.as_str()).collect();
    assert_eq!(
        ids,
        [
            "polyhaven_denim_fabric/per-map upsampler=lanczos3",
            "polyhaven_denim_fabric/matup",
            "polyhaven_denim_fabric+jpeg30/per-map upsampler=lanczos3",
            "polyhaven_denim_fabric+jpeg30/matup",
            "polyhaven_denim_fabric+bc1/per-map upsampler=lanczos3",
            "polyhaven_denim_fabric+bc1/matup",
        ]
    );
    // The per-map runs: clean, JPEG 30, BC1.
    let runs: Vec<_> = runs.into_iter().step_by(2).collect();
    let rows = run_experiment(&exp, &runs, out.path(), &Silent).unwrap();
    let psnr = |i: usize| rows[i].metric("render_psnr");
    assert!(rows.iter().all(|r| r.error.is_none()));
    // Each degradation costs render PSNR against the same truth (measured: about 1 dB).
    assert!(
        psnr(1) < psnr(0) - 0.3,
        "JPEG 30 {} vs clean {}",
        psnr(1),
        psnr(0)
    );
    assert!(
        psnr(2) < psnr(0) - 0.3,
        "BC1 {} vs clean {}",
        psnr(2),
        psnr(0)
    );
    assert_eq!(rows[1].material, "polyhaven_denim_fabric+jpeg30");
    // Each row measures invented structure against the input it was given, in results.csv too.
    assert!(rows
        .iter()
        .all(|r| r.metric("invented_structure_worst").is_finite()));
    let csv = std::fs::read_to_string(out.path().join("results.csv")).unwrap();
    assert!(csv
        .lines()
        .next()
        .unwrap()
        .contains("invented_structure_worst"));
    // The same noise every time: a second run of the same input gives the same numbers.
    let again = run_experiment(
        &exp,
        &runs[1..2],
        tempfile::tempdir().unwrap().path(),
        &Silent,
    )
    .unwrap();
    assert_eq!(again[0].metric("render_psnr"), psnr(1));
    let e = experiment_error("materials = [\"/a\"]\ndegrade = \"jpeg200\"\n");
    assert!(e.contains("'jpeg200'") && e.contains("quality"), "{e}");
}
