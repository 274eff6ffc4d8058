//! `matup batch` as a library: an interrupted material resumes from its checkpoint.
//! (The command itself, with worker processes, shards and claims: crates/matup-cli/tests.)

mod common;

use std::path::Path;

use matup::batch::{run_batch, BatchOptions, BatchProgress, Outcome};
use matup::config::Config;
use matup::progress::Silent;
use matup::{load_material, save_material};

impl BatchProgress for common::StopAfter {}

fn options() -> BatchOptions {
    let mut config = Config {
        upsampler: "bicubic".into(),
        seed: 1,
        ..Config::paper()
    };
    config.lights.count = 24;
    config.train.epochs = 2;
    BatchOptions {
        config,
        ..Default::default()
    }
}

fn file(folder: &Path, name: &str) -> Vec<u8> {
    std::fs::read(folder.join(name)).unwrap()
}

#[test]
fn an_interrupted_batch_resumes_its_material_from_the_checkpoint() {
    let library = tempfile::tempdir().unwrap();
    // The sample box-filtered to 32², so the output is 128².
    let sample = load_material(Some(&common::sample_material()), &Default::default()).unwrap();
    save_material(
        &sample.box_downsample(4),
        &library.path().join("wood"),
        &Default::default(),
    )
    .unwrap();
    let out = tempfile::tempdir().unwrap();
    let options = options();

    // 128² texels / 128 a batch: stop in the second epoch, after the first's checkpoint.
    let stop = common::StopAfter::new(128 + 40);
    let report = run_batch(library.path(), out.path(), &options, &stop).unwrap();
    assert!(report.interrupted);
    assert_eq!(report.handled[0].outcome, Outcome::Interrupted);
    let folder = out.path().join("wood");
    assert!(folder.join(".matup-checkpoint").is_dir());
    assert!(!folder.join("run.json").exists());
    assert_eq!(report.summary[0].status, matup::batch::Status::Pending);

    let report = run_batch(library.path(), out.path(), &options, &Silent).unwrap();
    assert!(!report.interrupted);
    assert_eq!(report.handled[0].outcome, Outcome::Upscaled);
    let run: serde_json::Value = serde_json::from_slice(&file(&folder, "run.json")).unwrap();
    assert_eq!(run["levels"][0]["training"]["resumed_epochs"], 1);
    assert!(
        !folder.join(".matup-checkpoint").exists(),
        "removed once done"
    );

    // The result equals an uninterrupted batch's.
    let whole = tempfile::tempdir().unwrap();
    run_batch(library.path(), whole.path(), &options, &Silent).unwrap();
    for map in [
        "baseColor.png",
        "normal.png",
        "roughness.png",
        "preview.png",
    ] {
        assert!(
            file(&folder, map) == file(&whole.path().join("wood"), map),
            "{map} differs from the uninterrupted run's"
        );
    }
}
