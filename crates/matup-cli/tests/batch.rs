//! `matup batch` over a small generated library, as a cluster runs it: several worker
//! processes at once, a killed worker, a stale claim.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};
use std::sync::OnceLock;
use std::time::{Duration, Instant, SystemTime};

use serde_json::Value;

/// The good materials of the test library: test materials box-filtered ×4 to 64².
const GOOD: [(&str, &str); 5] = [
    ("tiles/Tiles012", "ambientcg_Tiles012"),
    ("wood/floor 040", "ambientcg_WoodFloor040"),
    ("metal/Metal053C", "ambientcg_Metal053C"),
    ("fabric/denim", "polyhaven_denim_fabric"),
    ("Leather025", "ambientcg_Leather025"),
];
/// A material whose base colour is cut short.
const CORRUPT: &str = "metal/broken";

fn matup() -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_matup"));
    // Fast, deterministic settings; everything else is the defaults.
    c.arg("batch").env("RAYON_NUM_THREADS", "1");
    c
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// A fresh folder shared by this file's tests, made once per test run (so emptied of an
/// earlier run's) in cargo's scratch space.
fn scratch(name: &str) -> PathBuf {
    let path = PathBuf::from(env!("CARGO_TARGET_TMPDIR"))
        .join("batch")
        .join(name);
    let _ = std::fs::remove_dir_all(&path);
    std::fs::create_dir_all(&path).unwrap();
    path
}

/// The library, made once per test run with `matup downsample`: five materials, one
/// corrupt, a folder with no material (`docs`) and one of folders only (`metal`).
fn library() -> &'static Path {
    static LIBRARY: OnceLock<PathBuf> = OnceLock::new();
    LIBRARY.get_or_init(|| {
        let root = scratch("library");
        let materials =
            PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../tests/data/materials");
        for (folder, source) in GOOD {
            let o = Command::new(env!("CARGO_BIN_EXE_matup"))
                .args(["downsample", "--factor", "4", "-o"])
                .arg(root.join(folder))
                .arg(materials.join(source))
                .output()
                .unwrap();
            assert!(o.status.success(), "{}", stderr(&o));
        }
        let broken = root.join(CORRUPT);
        std::fs::create_dir_all(&broken).unwrap();
        for entry in std::fs::read_dir(root.join("metal/Metal053C")).unwrap() {
            let path = entry.unwrap().path();
            std::fs::copy(&path, broken.join(path.file_name().unwrap())).unwrap();
        }
        let base = broken.join("baseColor.png");
        let bytes = std::fs::read(&base).unwrap();
        std::fs::write(&base, &bytes[..bytes.len() / 2]).unwrap();
        std::fs::create_dir_all(root.join("docs")).unwrap();
        std::fs::write(root.join("docs/README.txt"), "not a material").unwrap();
        root
    })
}

/// Every file under `out` that a run writes deterministically (the maps and previews, not
/// run.json or the summaries, which hold times), with its bytes.
fn outputs(out: &Path) -> BTreeMap<String, Vec<u8>> {
    let mut files = BTreeMap::new();
    let mut stack = vec![out.to_path_buf()];
    while let Some(dir) = stack.pop() {
        for entry in std::fs::read_dir(&dir).unwrap() {
            let path = entry.unwrap().path();
            let name = path.file_name().unwrap().to_string_lossy().into_owned();
            if path.is_dir() {
                stack.push(path);
            } else if name.ends_with(".png") {
                let relative = path
                    .strip_prefix(out)
                    .unwrap()
                    .to_string_lossy()
                    .into_owned();
                files.insert(relative, std::fs::read(&path).unwrap());
            }
        }
    }
    files
}

fn json(o: &Output) -> Value {
    serde_json::from_slice(&o.stdout).unwrap_or_else(|e| {
        panic!(
            "not JSON ({e}):\n{}\n{}",
            String::from_utf8_lossy(&o.stdout),
            stderr(o)
        )
    })
}

/// (material, `field`) of each entry of a JSON array.
fn material_pairs<C: FromIterator<(String, String)>>(entries: &Value, field: &str) -> C {
    entries
        .as_array()
        .unwrap()
        .iter()
        .map(|e| {
            (
                e["material"].as_str().unwrap().to_string(),
                e[field].as_str().unwrap().to_string(),
            )
        })
        .collect()
}

/// (material, outcome) of a worker's `--json` report.
fn handled(report: &Value) -> Vec<(String, String)> {
    material_pairs(&report["handled"], "outcome")
}

fn summary(out: &Path) -> Value {
    serde_json::from_slice(&std::fs::read(out.join("batch.json")).unwrap()).unwrap()
}

fn statuses(out: &Path) -> BTreeMap<String, String> {
    material_pairs(&summary(out)["materials"], "status")
}

fn all_good_done(out: &Path) -> bool {
    let s = statuses(out);
    GOOD.iter()
        .all(|(m, _)| s.get(*m).map(String::as_str) == Some("done"))
}

/// A single-process run of the whole library (made once), to compare others with.
fn single_run() -> &'static (PathBuf, Output) {
    static RUN: OnceLock<(PathBuf, Output)> = OnceLock::new();
    RUN.get_or_init(|| {
        let out = scratch("single-run");
        let o = matup()
            .arg(library())
            .arg("-o")
            .arg(&out)
            .args(["--json", "--view"])
            .output()
            .unwrap();
        (out, o)
    })
}

#[test]
fn a_single_run_upscales_the_library_records_the_failure_and_reruns_only_what_is_missing() {
    let (out, o) = single_run();
    assert!(!o.status.success(), "a failed material fails the batch");
    assert!(stderr(o).contains("1 material(s) failed"), "{}", stderr(o));
    let report = json(o);
    let mut outcomes = handled(&report);
    outcomes.sort();
    let mut want: Vec<(String, String)> = GOOD
        .iter()
        .map(|(m, _)| (m.to_string(), "upscaled".to_string()))
        .chain([(CORRUPT.to_string(), "failed".to_string())])
        .collect();
    want.sort();
    assert_eq!(outcomes, want);
    assert_eq!(
        report["skipped_folders"][0]["folder"].as_str(),
        Some("docs"),
        "{report}"
    );

    // The summary: every material with its numbers, the failure with its file named.
    let s = summary(out);
    let rows = s["materials"].as_array().unwrap();
    assert_eq!(rows.len(), 6);
    for row in rows {
        let name = row["material"].as_str().unwrap();
        if name == CORRUPT {
            assert_eq!(row["status"], "failed");
            let error = row["error"].as_str().unwrap();
            assert!(error.contains("baseColor.png"), "{error}");
        } else {
            assert_eq!(row["status"], "done", "{row}");
            assert_eq!(row["output_size"], serde_json::json!([256, 256]));
            assert!(row["seconds"].as_f64().unwrap() > 0.0);
            assert!(row["tileable"].is_boolean());
            let folder = out.join(name);
            for file in [
                "baseColor.png",
                "normal.png",
                "roughness.png",
                "preview.png",
                "run.json",
                "view.html",
            ] {
                assert!(folder.join(file).is_file(), "{name}/{file}");
            }
            assert!(
                !folder.join(".matup-claim-0").exists(),
                "claims are released"
            );
        }
    }
    let csv = std::fs::read_to_string(out.join("batch.csv")).unwrap();
    assert!(csv.starts_with("material,status,seconds,final_loss,skips,tileable,error\n"));
    assert_eq!(csv.lines().count(), 7);
    let html = std::fs::read_to_string(out.join("index.html")).unwrap();
    assert!(html.contains(r#"<img src="./wood/floor%20040/preview.png""#));
    assert!(
        html.contains("5 done, 1 failed"),
        "the page counts the statuses"
    );
    assert!(
        html.contains(r#"<a href="./fabric/denim/view.html">relight</a>"#),
        "the index links each material's viewer"
    );
    assert!(!html.contains("http"), "the page needs no network");

    // Again: nothing is redone but the failure.
    let again = matup()
        .arg(library())
        .arg("-o")
        .arg(out)
        .arg("--json")
        .output()
        .unwrap();
    let mut outcomes = handled(&json(&again));
    outcomes.sort();
    for (material, outcome) in outcomes {
        let want = if material == CORRUPT {
            "failed"
        } else {
            "already-done"
        };
        assert_eq!(outcome, want, "{material}");
    }
}

#[test]
fn three_shards_at_once_split_the_library_and_equal_one_process() {
    let out = tempfile::tempdir().unwrap();
    let workers: Vec<Child> = (0..3)
        .map(|i| {
            matup()
                .arg(library())
                .arg("-o")
                .arg(out.path())
                .args(["--json", "--shard", &format!("{i}/3")])
                .stdout(Stdio::piped())
                .stderr(Stdio::piped())
                .spawn()
                .unwrap()
        })
        .collect();
    let reports: Vec<Output> = workers
        .into_iter()
        .map(|w| w.wait_with_output().unwrap())
        .collect();
    let mut upscaled = Vec::new();
    let mut failed = Vec::new();
    for o in &reports {
        let report = json(o);
        for (material, outcome) in handled(&report) {
            match outcome.as_str() {
                "upscaled" => upscaled.push(material),
                "failed" => failed.push(material),
                other => panic!("{material}: {other}"),
            }
        }
        assert_eq!(
            o.status.success(),
            !handled(&report).iter().any(|h| h.0 == CORRUPT),
            "only the worker with the corrupt material fails: {}",
            stderr(o)
        );
    }
    upscaled.sort();
    let mut want: Vec<String> = GOOD.iter().map(|(m, _)| m.to_string()).collect();
    want.sort();
    assert_eq!(upscaled, want, "every good material exactly once");
    assert_eq!(failed, vec![CORRUPT.to_string()]);

    let (single, _) = single_run();
    let sharded = outputs(out.path());
    assert_eq!(sharded.len(), 5 * 6, "five maps and a preview each");
    assert!(
        sharded == outputs(single),
        "the shards' files equal one process's byte for byte"
    );
}

#[test]
fn a_killed_worker_is_finished_by_the_next_run() {
    let out = tempfile::tempdir().unwrap();
    let mut worker = matup()
        .arg(library())
        .arg("-o")
        .arg(out.path())
        .arg("--quiet")
        .spawn()
        .unwrap();
    // Kill it while it holds a material it has not finished.
    let start = Instant::now();
    let held = loop {
        let claimed = GOOD.iter().find(|(m, _)| {
            let folder = out.path().join(m);
            folder.join(".matup-claim-0").exists() && !folder.join("run.json").exists()
        });
        if let Some((m, _)) = claimed {
            break m.to_string();
        }
        assert!(
            worker.try_wait().unwrap().is_none(),
            "the worker ended before it could be killed"
        );
        assert!(start.elapsed() < Duration::from_secs(120));
        std::thread::sleep(Duration::from_millis(2));
    };
    worker.kill().unwrap();
    worker.wait().unwrap();
    assert!(out.path().join(&held).join(".matup-claim-0").exists());

    // The same command again: the dead worker's claim is taken over (it ran on this machine
    // and its process is gone), and the library is finished.
    let o = matup()
        .arg(library())
        .arg("-o")
        .arg(out.path())
        .arg("--json")
        .output()
        .unwrap();
    let outcomes: BTreeMap<String, String> = handled(&json(&o)).into_iter().collect();
    assert_eq!(outcomes[&held], "upscaled", "{outcomes:?}");
    assert!(all_good_done(out.path()), "{:?}", statuses(out.path()));
    let (single, _) = single_run();
    assert!(outputs(out.path()) == outputs(single));
}

#[test]
fn a_live_claim_is_respected_and_a_stale_one_taken_over() {
    let library = tempfile::tempdir().unwrap();
    let material = library.path().join("Leather025");
    std::fs::create_dir_all(&material).unwrap();
    for entry in std::fs::read_dir(self::library().join("Leather025")).unwrap() {
        let path = entry.unwrap().path();
        std::fs::copy(&path, material.join(path.file_name().unwrap())).unwrap();
    }
    let out = tempfile::tempdir().unwrap();
    let claim = out.path().join("Leather025/.matup-claim-0");
    std::fs::create_dir_all(claim.parent().unwrap()).unwrap();
    std::fs::write(&claim, r#"{"host":"node-17","pid":4242}"#).unwrap();
    let run = || {
        matup()
            .arg(library.path())
            .arg("-o")
            .arg(out.path())
            .args(["--json", "--claim-timeout", "60"])
            .output()
            .unwrap()
    };

    let o = run();
    assert!(o.status.success(), "a held material is not a failure");
    assert_eq!(
        handled(&json(&o)),
        vec![("Leather025".to_string(), "held-elsewhere".to_string())]
    );
    assert_eq!(statuses(out.path())["Leather025"], "running");

    // The other worker stopped heartbeating two minutes ago: its claim is stale.
    std::fs::File::options()
        .write(true)
        .open(&claim)
        .unwrap()
        .set_modified(SystemTime::now() - Duration::from_secs(120))
        .unwrap();
    let o = run();
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!(
        handled(&json(&o)),
        vec![("Leather025".to_string(), "upscaled".to_string())]
    );
    assert_eq!(statuses(out.path())["Leather025"], "done");
    assert!(!claim.exists(), "the stale claim is gone");

    // Asking for the viewer later adds it without upscaling again.
    let page = out.path().join("Leather025/view.html");
    assert!(!page.exists());
    let o = matup()
        .arg(library.path())
        .arg("-o")
        .arg(out.path())
        .args(["--json", "--view"])
        .output()
        .unwrap();
    assert_eq!(
        handled(&json(&o)),
        vec![("Leather025".to_string(), "already-done".to_string())]
    );
    assert!(page.is_file());
}

#[test]
fn batch_refuses_bad_shards_and_its_own_input_as_output() {
    let o = matup()
        .arg(library())
        .arg("-o")
        .arg(library())
        .output()
        .unwrap();
    assert!(!o.status.success());
    assert!(
        stderr(&o).contains("output folder is the library"),
        "{}",
        stderr(&o)
    );
    let out = tempfile::tempdir().unwrap();
    let o = matup()
        .arg(library())
        .arg("-o")
        .arg(out.path())
        .args(["--shard", "3/3"])
        .output()
        .unwrap();
    assert!(!o.status.success());
    assert!(stderr(&o).contains("below the count"), "{}", stderr(&o));
    let o = matup()
        .arg(library())
        .arg("-o")
        .arg(out.path())
        .env("JOB_COMPLETION_INDEX", "1")
        .output()
        .unwrap();
    assert!(!o.status.success());
    assert!(stderr(&o).contains("--shards"), "{}", stderr(&o));
}
