//! The paper's method end to end on real materials (small: 32² → 128², few epochs, few
//! lights): the filter trained on upsampled renders.

mod common;

use std::sync::OnceLock;

use matup::batch::{run_batch, BatchOptions, BatchProgress, Outcome};
use matup::config::Config;
use matup::lights::Light;
use matup::material::{MapKind, Material, NormalConvention};
use matup::pipeline::{upscale, wrap_seam_ratio};
use matup::progress::Silent;
use matup::render::{render, RenderOptions};
use matup::train::Stop;
use matup::{
    load_material, save_material, shading_model, upsampler, Border, Kernel, LightSetSpec, LossNorm,
    Map, PluginSpec, RunOptions, RunReport,
};

/// A whole test material box-filtered down to `size`² (a tileable input stays tileable).
fn lr_material(name: &str, size: usize) -> Material {
    let m = common::load_test_material(name);
    m.box_downsample(m.width() / size)
}

fn quick_config(seed: u64) -> Config {
    let mut c = Config {
        upsampler: "bicubic".into(),
        seed,
        ..Config::paper()
    };
    c.lights.count = 24;
    c.train.epochs = 3;
    c
}

fn run(lr: &Material, config: &Config) -> (Material, RunReport) {
    matup::upscale(lr, config, &RunOptions::default(), &Silent).unwrap()
}

/// The wood material ×4 with the quick settings, shared by several tests.
fn wood() -> &'static (Material, Material, RunReport) {
    static RUN: OnceLock<(Material, Material, RunReport)> = OnceLock::new();
    RUN.get_or_init(|| {
        let lr = lr_material("polyhaven_wood_cabinet_worn_long", 32);
        let (hr, report) = run(&lr, &quick_config(1));
        (lr, hr, report)
    })
}

/// Mean l2,1 error (per texel and light, display space) between renders of `hr` and the
/// upsampled renders of `lr`, under `lights`.
fn error_against_targets(lr: &Material, hr: &Material, lights: &[Light], border: Border) -> f64 {
    let model = shading_model(&PluginSpec::new("ggx")).unwrap();
    let up = upsampler(&PluginSpec::new("bicubic")).unwrap();
    let lr_renders = render(
        lr,
        model.as_ref(),
        lights,
        RenderOptions {
            supersample: true,
            border,
        },
    );
    let targets = up.upsample(&lr_renders, 4, border).unwrap();
    let renders = render(
        hr,
        model.as_ref(),
        lights,
        RenderOptions {
            supersample: false,
            border,
        },
    );
    let mut total = 0.0;
    for (r, t) in renders.iter().zip(&targets) {
        for i in 0..r.texels() {
            let e = std::array::from_fn(|c| r.plane(c)[i] - t.plane(c)[i]);
            total += LossNorm::L21.eval(e).0 as f64;
        }
    }
    total / (lights.len() * renders[0].texels()) as f64
}

#[test]
fn trained_maps_explain_the_targets_better_than_bilinear() {
    let (lr, hr, report) = wood();
    assert_eq!((hr.width(), hr.height_px()), (128, 128));
    assert!(report.tileable, "the whole wood material tiles");
    let training = &report.levels[0].training;
    assert_eq!(
        training.stopped,
        Stop::MaxEpochs,
        "the paper's fixed schedule"
    );
    assert_eq!(training.epochs_trained, 3.0);
    assert!(training.validation_losses.is_empty());
    let losses = &training.epoch_losses;
    assert_eq!(losses.len(), 3);
    assert!(
        losses[2] < losses[0],
        "training lowers the loss: {losses:?}"
    );

    let bilinear = lr.upsample(4, Kernel::Bilinear, Border::Wrap);
    let training = LightSetSpec {
        count: 24,
        ..Default::default()
    }
    .build();
    let held_out = LightSetSpec::held_out(24).build();
    for (name, lights) in [("training", &training), ("held-out", &held_out)] {
        let base = error_against_targets(lr, &bilinear, lights, Border::Wrap);
        let ours = error_against_targets(lr, hr, lights, Border::Wrap);
        println!("{name} lights: bilinear {base:.5}, matup {ours:.5}");
        assert!(
            ours < 0.9 * base,
            "{name} lights: matup {ours} vs bilinear {base}"
        );
    }
}

/// Denim ×4 (quick settings, skips on), shared by the tiling and skip tests.
fn denim() -> &'static (Material, Material, RunReport) {
    static RUN: OnceLock<(Material, Material, RunReport)> = OnceLock::new();
    RUN.get_or_init(|| {
        let lr = lr_material("polyhaven_denim_fabric", 32);
        let (hr, report) = run(&lr, &quick_config(1));
        (lr, hr, report)
    })
}

#[test]
fn tileable_input_gives_tileable_output() {
    let (lr, hr, report) = denim();
    assert!(report.tileable);
    let input = wrap_seam_ratio(lr, 1);
    let output = wrap_seam_ratio(hr, 1);
    // Mirrored windows treat the edge as an edge; the wrap-around then shows it.
    let mut mirrored = quick_config(1);
    mirrored.tileable = Some(false);
    let (not_tiled, _) = run(lr, &mirrored);
    let mirrored_ratio = wrap_seam_ratio(&not_tiled, 1);
    println!(
        "seam ratio: input {input:.3}, output {output:.3}, mirrored windows {mirrored_ratio:.3}"
    );
    // The wrap-around edge differs no more than interior neighbours do.
    assert!((output - 1.0).abs() < 0.15, "output seam ratio {output}");
    assert!(
        mirrored_ratio > output,
        "mirrored {mirrored_ratio} vs wrapped {output}"
    );
}

#[test]
fn a_seed_makes_runs_repeat() {
    let (lr, hr, _) = wood();
    let (again, _) = run(lr, &quick_config(1));
    assert_eq!(&again, hr, "same seed, same maps");
    let mut other = quick_config(2);
    other.train.epochs = 1;
    let (different, _) = run(lr, &other);
    assert_ne!(different.base_color, hr.base_color);
}

#[test]
fn resuming_after_an_interruption_gives_the_uninterrupted_result() {
    let (lr, hr, _) = wood();
    let folder = tempfile::tempdir().unwrap();
    // 128² texels / 128 per batch = 128 steps an epoch: stop during the second epoch.
    let options = common::interrupt_in_second_epoch(lr, &quick_config(1), folder.path(), 128 + 40);
    let (resumed, report) = matup::upscale(lr, &quick_config(1), &options, &Silent).unwrap();
    assert_eq!(report.levels[0].training.resumed_epochs, 1);
    assert_eq!(&resumed, hr, "resumed = uninterrupted");
}

/// The quick settings stopping early: up to 40 epochs, two checks an epoch, stopping after 2
/// checks without a 2% gain.
fn early_stop_config() -> Config {
    let mut c = quick_config(1);
    c.train.epochs = 40;
    let e = &mut c.train.early_stop;
    e.enabled = true;
    e.checks_per_epoch = 2;
    e.patience = 2;
    e.min_gain = 0.02;
    c
}

#[test]
fn training_stops_when_the_held_out_loss_stops_improving() {
    let (lr, _, _) = wood();
    let config = early_stop_config();
    let (_, report) = run(lr, &config);
    let t = &report.levels[0].training;
    assert_eq!(t.stopped, Stop::Converged);
    assert!(t.epochs_trained < 40.0, "{}", t.epochs_trained);
    // Two checks an epoch, each after half of its steps.
    let v = &t.validation_losses;
    assert_eq!(v.len() as f64, t.epochs_trained * 2.0, "{v:?}");
    assert_eq!(t.epoch_losses.len(), t.epochs_trained.ceil() as usize);
    // It stopped exactly when the rule says: the last two checks did not beat the best
    // before them by 2%, and no earlier pair of checks did the same.
    let stale_at = |k: usize| {
        let best = v[..k].iter().copied().fold(f64::INFINITY, f64::min);
        v[k] > best * 0.98
    };
    let n = v.len();
    assert!(stale_at(n - 2) && stale_at(n - 1), "{v:?}");
    assert!(v[0] > v[n - 1], "the held-out loss went down: {v:?}");
    // Held-out texels (a tenth of 128², 1638) are not trained on: 14 746 texels an epoch,
    // 116 steps of 128.
    let steps_per_epoch = 116.0;
    assert_eq!(t.steps as f64, t.epochs_trained * steps_per_epoch);
}

#[test]
fn an_early_stopped_run_resumes_to_the_same_stop() {
    let (lr, _, _) = wood();
    let config = early_stop_config();
    let (whole, whole_report) = run(lr, &config);
    let folder = tempfile::tempdir().unwrap();
    // Stop during the second epoch (116 steps each), after its first check.
    let options = common::interrupt_in_second_epoch(lr, &config, folder.path(), 116 + 80);
    let (resumed, report) = matup::upscale(lr, &config, &options, &Silent).unwrap();
    let (a, b) = (&report.levels[0].training, &whole_report.levels[0].training);
    assert_eq!(a.resumed_epochs, 1);
    assert_eq!(a.validation_losses, b.validation_losses);
    assert_eq!((a.epochs_trained, a.stopped), (b.epochs_trained, b.stopped));
    assert_eq!(resumed, whole, "resumed = uninterrupted");
}

#[test]
fn skipping_a_constant_metallic_map_stays_within_noise() {
    // Denim has no metallic: the skip keeps it constant instead of learning it.
    let (lr, skipped, skipped_report) = denim();
    let config = |seed, skip| {
        let mut c = quick_config(seed);
        c.skip = skip;
        c
    };
    let (full, full_report) = run(lr, &config(1, false));
    let (full2, _) = run(lr, &config(2, false));
    assert!(
        skipped_report
            .skipped
            .iter()
            .any(|s| s.contains("metallic")),
        "{:?}",
        skipped_report.skipped
    );
    assert!(full_report.skipped.iter().all(|s| !s.contains("constant")));
    assert!(
        skipped.metallic.data().iter().all(|&m| m == 0.0),
        "constant metallic stays constant"
    );

    let lights = LightSetSpec::held_out(24).build();
    let e = |hr: &Material| error_against_targets(lr, hr, &lights, Border::Wrap);
    let (es, ef, ef2) = (e(skipped), e(&full), e(&full2));
    let noise = (ef - ef2).abs();
    println!("held-out error: skip {es:.5}, full {ef:.5}, full (other seed) {ef2:.5}");
    assert!(
        (es - ef).abs() <= 2.0 * noise + 0.02 * ef,
        "skip {es} vs full {ef} (seed noise {noise})"
    );
}

#[test]
fn sixteen_times_in_two_levels_or_by_reusing_the_filter() {
    let lr = lr_material("ambientcg_Metal053C", 8);
    let mut c = quick_config(1);
    c.scale = 16;
    c.train.epochs = 1;
    let (two_level, report) = run(&lr, &c);
    assert_eq!((two_level.width(), two_level.height_px()), (128, 128));
    assert_eq!(report.levels.len(), 2);
    assert_eq!(report.levels[1].input_size, [32, 32]);
    assert!(
        report
            .levels
            .iter()
            .all(|l| l.training.epoch_losses.len() == 1),
        "both levels train"
    );
    assert!(
        two_level.height.is_some(),
        "height follows through both levels"
    );

    c.chain = matup::config::Chain::Single;
    let (single, report) = run(&lr, &c);
    assert_eq!((single.width(), single.height_px()), (128, 128));
    assert!(
        report.levels[1].training.epoch_losses.is_empty(),
        "the ×4 filter is reused"
    );
    assert_ne!(single.base_color, two_level.base_color);
}

#[test]
fn eight_times_and_sizes_between_scales_with_the_defaults() {
    // ×8: ×4, then ×2 through the network's ×4 and an area filter on the normals (Lanczos-3
    // on the other maps); carried maps and height follow.
    let lr = lr_material("ambientcg_Metal053C", 16);
    let eight = Config {
        scale: 8,
        tileable: Some(true),
        ..Config::default()
    };
    let (hr, report) = run(&lr, &eight);
    assert_eq!((hr.width(), hr.height_px()), (128, 128));
    let routes: Vec<&str> = report.levels.iter().map(|l| l.route.as_str()).collect();
    assert_eq!(
        routes,
        [
            "×4 by onnx:span_x4_materials (2 passes), back-projected",
            "×2 by onnx:span_x4_materials at ×4, then ÷2 by area (2 passes) on the normal map, \
             lanczos3 on the others, back-projected"
        ]
    );
    assert_eq!(report.levels[1].input_size, [64, 64]);
    assert!(hr.height.is_some());
    // Back-projected at each level: ×8 box-filters back to the input.
    let back = hr.box_downsample(8);
    let drift = common::max_abs_diff(&back.metallic, &lr.metallic);
    assert!(
        drift < 0.02,
        "metallic box-filters back {drift} from the input"
    );
    // A size between scales: the scale past it, then area-shrunk; tileable stays tileable.
    let sized = Config {
        size: Some("100".parse().unwrap()),
        tileable: Some(true),
        ..Config::default()
    };
    let (small, report) = run(&lr, &sized);
    assert_eq!((small.width(), small.height_px()), (100, 100));
    assert_eq!(report.route, "×8, then area-shrunk to 100×100");
    assert_eq!(report.output_size, [100, 100]);
    assert_eq!(report.config.size, sized.size);
    // The ×8 output, area-shrunk: every map, the height and normals (renormalised) alike.
    let shrunk = hr.area_resize(100, 100);
    for (a, b) in small.maps().zip(shrunk.maps()) {
        let d = common::max_abs_diff(a, b);
        assert!(d < 1e-5, "{d}");
    }
}

impl BatchProgress for common::StopAfter {}

/// `matup batch` as a library (the command, with worker processes, shards and claims, is
/// tested in crates/matup-cli/tests/batch.rs).
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
    let mut config = quick_config(1);
    config.train.epochs = 2;
    let options = BatchOptions {
        config,
        ..Default::default()
    };

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
    let run: serde_json::Value =
        serde_json::from_slice(&std::fs::read(folder.join("run.json")).unwrap()).unwrap();
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
            std::fs::read(folder.join(map)).unwrap()
                == std::fs::read(whole.path().join("wood").join(map)).unwrap(),
            "{map} differs from the uninterrupted run's"
        );
    }
}

/// Two materials in flight (a GPU's batch: one's files written while the next is upscaled)
/// give the files of one at a time, and report the materials in the library's order.
#[test]
fn materials_in_flight_together_give_the_files_of_one_at_a_time() {
    let library = tempfile::tempdir().unwrap();
    let sample = load_material(Some(&common::sample_material()), &Default::default()).unwrap();
    for (name, factor) in [("a", 4), ("b", 8), ("c", 2)] {
        let material = sample.box_downsample(factor);
        save_material(&material, &library.path().join(name), &Default::default()).unwrap();
    }
    let config = Config {
        upsampler: "bicubic".into(),
        ..Config::default()
    };
    let run = |in_flight: usize| {
        let out = tempfile::tempdir().unwrap();
        let options = BatchOptions {
            config: config.clone(),
            in_flight,
            memory_limit: Some(512 << 20),
            ..Default::default()
        };
        let report = run_batch(library.path(), out.path(), &options, &Silent).unwrap();
        let handled: Vec<(String, Outcome)> = (report.handled.into_iter())
            .map(|h| (h.material, h.outcome))
            .collect();
        (out, handled)
    };
    let (one, handled_one) = run(1);
    let (two, handled_two) = run(2);
    assert_eq!(handled_one, handled_two);
    assert_eq!(
        handled_two
            .iter()
            .map(|(m, _)| m.as_str())
            .collect::<Vec<_>>(),
        ["a", "b", "c"]
    );
    assert!(handled_two.iter().all(|(_, o)| *o == Outcome::Upscaled));
    for name in ["a", "b", "c"] {
        for map in [
            "baseColor.png",
            "normal.png",
            "roughness.png",
            "preview.png",
        ] {
            let read =
                |root: &tempfile::TempDir| std::fs::read(root.path().join(name).join(map)).unwrap();
            assert!(read(&one) == read(&two), "{name}/{map} differs");
        }
    }
}

// Outputs made in bands of rows within a memory limit equal the whole-image path: matup's
// defaults (each map through SPAN ×4, back-projected, height rebuilt from the normals) on a
// real material, ×4 and ×16, tileable and not, every map within 1/255 of the whole run's as
// its file stores it (base colour in sRGB, normals as colours).

/// A map's values as its 8-bit file holds them, before rounding.
fn as_stored(kind: MapKind, map: &Map) -> Map {
    matup::io::encode_map(kind, map, false, NormalConvention::DirectX).into_owned()
}

#[test]
fn bands_equal_the_whole_image() {
    let truth = common::load_test_material("polyhaven_coast_sand_rocks_02");
    // 128² → 512² in one level, 32² → 512² in two (the second in bands); ×2 and ×3 through
    // the network's ×4 (its intermediate counted in the plan), with limits that make 3 or more
    // bands of each.
    // (The context of the chroma clamp's back-projections takes 48 of a band's LR rows at ×4,
    // so the limits that leave room for 3 bands and more are narrow: KiB.)
    for (scale, side, limit_kib) in [
        (4, 128, 21 << 10),
        (16, 32, 21 << 10),
        (2, 128, 11_600),
        (3, 128, 17 << 10),
    ] {
        let mut lr = truth.box_downsample(truth.width() / side);
        // An alpha of 0 or 1 but in its last rows: a soft alpha as a whole, which every band
        // must upsample as one (a band that reads none of those rows looks like a cutout).
        let alpha = Map::from_fn(side, side, 1, |_, y, x| {
            if y < side - side / 16 {
                ((x / 5 + y / 7) % 2) as f32
            } else {
                0.25 + 0.25 * ((x + y) % 3) as f32
            }
        });
        lr.carried.alpha.insert(MapKind::BaseColor, alpha);
        for tileable in [false, true] {
            let config = Config {
                scale,
                tileable: Some(tileable),
                ..Config::default()
            };
            let whole = upscale(&lr, &config, &RunOptions::default(), &Silent).unwrap();
            let limited = RunOptions {
                memory_limit: Some(limit_kib << 10),
                ..RunOptions::default()
            };
            let (banded, report) = upscale(&lr, &config, &limited, &Silent).unwrap();
            let bands = report.levels.last().unwrap().bands;
            assert!(bands >= 3, "×{scale}, tileable {tileable}: {bands} bands");
            assert_eq!(whole.1.levels.last().unwrap().bands, 1);
            for kind in MapKind::ALL {
                let (Some(a), Some(b)) = (whole.0.map(kind), banded.map(kind)) else {
                    assert!(whole.0.map(kind).is_none() && banded.map(kind).is_none());
                    continue;
                };
                let worst = common::max_abs_diff(&as_stored(kind, a), &as_stored(kind, b));
                println!("×{scale}, tileable {tileable}, {bands} bands, {kind}: {worst:.2e}");
                assert!(
                    worst <= 1.0 / 255.0,
                    "×{scale}, tileable {tileable}, {kind}: {worst}"
                );
            }
            let alpha = |m: &Material| m.carried.alpha[&MapKind::BaseColor].clone();
            let worst = common::max_abs_diff(&alpha(&whole.0), &alpha(&banded));
            println!("×{scale}, tileable {tileable}, {bands} bands, alpha: {worst:.2e}");
            assert!(
                worst <= 1.0 / 255.0,
                "×{scale}, tileable {tileable}, alpha: {worst}"
            );
        }
    }
}

/// The defaults with the network as `--device cuda` runs it (candle operations, the
/// self-ensemble's passes in one call), here on candle's CPU device, in bands, against the
/// CPU's executor on the whole image: every map within 1/255 as its file stores it, tileable
/// and not.
#[test]
fn the_gpu_path_in_bands_gives_the_cpu_paths_maps() {
    let truth = common::load_test_material("polyhaven_coast_sand_rocks_02");
    // 128² → 512².
    let lr = truth.box_downsample(2);
    for tileable in [false, true] {
        let on = |engine: &str| Config {
            upsampler: format!("onnx:span_x4_materials,engine={engine}"),
            tileable: Some(tileable),
            ..Config::default()
        };
        let (cpu, _) = run_defaults(&lr, &on("matup"), None);
        let (gpu_path, report) = run_defaults(&lr, &on("candle"), Some(24 << 20));
        let bands = report.levels[0].bands;
        assert!(bands >= 2, "tileable {tileable}: {bands} bands");
        for kind in MapKind::ALL {
            let (Some(a), Some(b)) = (cpu.map(kind), gpu_path.map(kind)) else {
                assert!(cpu.map(kind).is_none() && gpu_path.map(kind).is_none());
                continue;
            };
            let worst = common::max_abs_diff(&as_stored(kind, a), &as_stored(kind, b));
            println!("tileable {tileable}, {bands} bands, {kind}: {worst:.2e}");
            assert!(worst <= 1.0 / 255.0, "tileable {tileable}, {kind}: {worst}");
        }
    }
}

fn run_defaults(
    lr: &Material,
    config: &Config,
    memory_limit: Option<u64>,
) -> (Material, RunReport) {
    let options = RunOptions {
        memory_limit,
        ..RunOptions::default()
    };
    upscale(lr, config, &options, &Silent).unwrap()
}

/// Not a material's worth of memory: the limit is refused with the sizes in the message.
#[test]
fn a_limit_too_low_for_any_band_says_what_it_needs() {
    let lr = Material::uniform(256, [0.5; 3], 0.5, 0.0);
    let config = Config {
        upsampler: "bicubic".into(),
        ..Config::default()
    };
    let options = RunOptions {
        memory_limit: Some(8 << 20),
        ..RunOptions::default()
    };
    let error = upscale(&lr, &config, &options, &Silent)
        .unwrap_err()
        .to_string();
    assert!(
        error.contains("8 MiB") && error.contains("256×256 → 1024×1024"),
        "{error}"
    );
}
