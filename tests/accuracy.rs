//! What makes the defaults accurate, on real materials: detail targets, the per-map residual
//! base and its back-projection, the LR-consistency term, self-validation one scale down and
//! tileability detection on crops.

mod common;

use matup::config::{Config, ResidualBase, Selection, TargetKind};
use matup::material::Material;
use matup::pipeline::{decide_tileable, detect_tileable, features};
use matup::progress::Silent;
use matup::resample::{box_downsample, upsample};
use matup::select::SelectionReport;
use matup::targets::{base_renders, upsampled_targets, DetailBase, LrRenders, Targets};
use matup::{
    render, shading_model, upsampler, Border, Kernel, LightSetSpec, Map, PluginSpec, RenderOptions,
    RgbUpsampler, RunOptions,
};

/// A whole test material box-filtered down to `size`² (a tileable input stays tileable).
fn lr_material(name: &str, size: usize) -> Material {
    let m = common::load_test_material(name);
    m.box_downsample(m.width() / size)
}

fn mean_abs_diff(a: &Map, b: &Map) -> f64 {
    let n = a.data().len() as f64;
    a.data()
        .iter()
        .zip(b.data())
        .map(|(x, y)| (x - y).abs() as f64)
        .sum::<f64>()
        / n
}

/// Settings of the filter's training tests: few lights and epochs.
fn trained(upsampler: &str, epochs: usize) -> Config {
    let mut c = Config::paper();
    c.upsampler = upsampler.into();
    c.seed = 1;
    c.lights.count = 24;
    c.train.epochs = epochs;
    c
}

/// The same targets, texel by texel and light by light: how many of the 8-bit values differ.
fn differing_values(a: &Targets, b: &Targets) -> usize {
    a.data.iter().zip(&b.data).filter(|(x, y)| x != y).count()
}

#[test]
fn detail_targets_with_s_equal_to_k_are_the_base_renders() {
    let lr = lr_material("polyhaven_wood_cabinet_worn_long", 32);
    let model = shading_model(&PluginSpec::new("ggx")).unwrap();
    let lights = LightSetSpec {
        count: 12,
        ..Default::default()
    }
    .build();
    let border = Border::Wrap;
    let renders = render(
        &lr,
        model.as_ref(),
        &lights,
        RenderOptions {
            supersample: true,
            border,
        },
    );
    let lr_renders = LrRenders {
        renders: &renders,
        lights: &lights,
        model: model.as_ref(),
        scale: 4,
        border,
    };
    let base_features = upsample(&features(&lr), 4, Kernel::Lanczos3, border);
    let base = DetailBase {
        features: &base_features,
        fixed: &[None; 7],
        heights: None,
        kernel: Some(Kernel::Lanczos3),
    };
    let lanczos = upsampler(&PluginSpec::new("lanczos3")).unwrap();
    let want = Targets::from_renders(&base_renders(&base, model.as_ref(), &lights));

    let detail = upsampled_targets(
        TargetKind::Detail,
        &lr_renders,
        lanczos.as_ref(),
        &base,
        &Silent,
    )
    .unwrap();
    assert_eq!(
        differing_values(&detail, &want),
        0,
        "S = K: the detail is 0, the targets are the base's renders"
    );
    // The paper's targets are not the renders of any upsampled material: interpolating a
    // render is not rendering interpolated maps.
    let direct = upsampled_targets(
        TargetKind::Direct,
        &lr_renders,
        lanczos.as_ref(),
        &base,
        &Silent,
    )
    .unwrap();
    let differing = differing_values(&direct, &want) as f64 / want.data.len() as f64;
    println!(
        "direct targets: {:.1}% of values differ from the base's renders",
        100.0 * differing
    );
    assert!(differing > 0.3, "{differing}");

    // A per-map base (no kernel) is its own detail target: S is not even called.
    struct Refuses;
    impl RgbUpsampler for Refuses {
        fn upsample(&self, _: &[Map], _: usize, _: Border) -> matup::Result<Vec<Map>> {
            Err(matup::Error::Invalid("not needed".into()))
        }
    }
    let own = DetailBase {
        kernel: None,
        ..base
    };
    let per_map =
        upsampled_targets(TargetKind::Detail, &lr_renders, &Refuses, &own, &Silent).unwrap();
    assert_eq!(differing_values(&per_map, &want), 0);
}

#[test]
fn with_s_equal_to_k_the_detail_fit_returns_its_base() {
    let lr = lr_material("polyhaven_wood_cabinet_worn_long", 32);
    let mut detail = trained("lanczos3", 2);
    detail.filter.residual_base = ResidualBase::Kernel(Kernel::Lanczos3);
    detail.train.targets = TargetKind::Detail;
    let direct = Config {
        train: matup::config::TrainConfig {
            targets: TargetKind::Direct,
            ..detail.train.clone()
        },
        ..detail.clone()
    };
    let base = upsample(&features(&lr), 4, Kernel::Lanczos3, Border::Wrap);
    let run = |c: &Config| {
        let (hr, _) = matup::upscale(&lr, c, &RunOptions::default(), &Silent).unwrap();
        // Base colour, metallic, normal x, y: the features the base holds directly.
        mean_abs_diff(
            &features(&hr).select_channels(&[0, 1, 2, 4, 5]),
            &base.select_channels(&[0, 1, 2, 4, 5]),
        )
    };
    let (from_detail, from_direct) = (run(&detail), run(&direct));
    println!("mean distance to the base: detail {from_detail:.5}, direct {from_direct:.5}");
    assert!(from_detail < 0.001, "{from_detail}");
    assert!(
        from_detail < 0.1 * from_direct,
        "{from_detail} vs {from_direct}"
    );
}

/// Mean absolute difference between a material's box-downsampled features and `lr`'s.
fn inconsistency(hr: &Material, lr: &Material) -> f64 {
    let scale = hr.width() / lr.width();
    mean_abs_diff(&box_downsample(&features(hr), scale), &features(lr))
}

#[test]
fn back_projection_makes_the_per_map_base_consistent_with_its_input() {
    let lr = lr_material("ambientcg_Metal053C", 32);
    let mut config = Config {
        upsampler: "bicubic".into(),
        ..Default::default()
    };
    assert_eq!(config.train.epochs, 0, "the default trains nothing");
    let (projected, report) =
        matup::upscale(&lr, &config, &RunOptions::default(), &Silent).unwrap();
    assert!(report.levels[0].training.epoch_losses.is_empty());
    config.filter.back_project = false;
    config.filter.clamp_chroma = false;
    let (per_map, _) = matup::upscale(&lr, &config, &RunOptions::default(), &Silent).unwrap();
    // Without back-projection (and the chroma clamp) the result is exactly per-map upsampling.
    let bicubic = upsampler(&PluginSpec::new("bicubic")).unwrap();
    let border = Border::for_tiling(report.tileable);
    let baseline = matup::per_map::upscale_per_map(&lr, bicubic.as_ref(), 4, border).unwrap();
    assert!(common::max_abs_diff(&per_map.base_color, &baseline.base_color) < 1e-5);
    let (before, after) = (inconsistency(&per_map, &lr), inconsistency(&projected, &lr));
    println!("LR inconsistency: per-map {before:.5}, back-projected {after:.5}");
    assert!(after < 0.25 * before, "{after} vs {before}");
}

#[test]
fn the_lr_consistency_term_pulls_the_result_toward_its_input() {
    let lr = lr_material("polyhaven_wood_cabinet_worn_long", 32);
    let without = trained("bicubic", 2);
    let mut with = without.clone();
    with.train.lr_consistency = 100.0;
    let run = |c: &Config| matup::upscale(&lr, c, &RunOptions::default(), &Silent).unwrap();
    let ((plain, _), (anchored, report)) = (run(&without), run(&with));
    let losses = &report.levels[0].training.epoch_losses;
    assert!(losses[1] < losses[0], "{losses:?}");
    let (before, after) = (inconsistency(&plain, &lr), inconsistency(&anchored, &lr));
    println!("LR inconsistency: β = 0 {before:.5}, β = 100 {after:.5}");
    assert!(after < 0.8 * before, "{after} vs {before}");
}

/// Each candidate's scores at the validation scale, for the test's log.
fn print_candidates(selection: &SelectionReport) {
    for c in &selection.candidates {
        println!(
            "{}: {:.3} dB, FLIP {:.4}",
            c.name, c.render_psnr, c.render_flip
        );
    }
}

#[test]
fn self_validation_picks_per_map_upsampling_when_it_is_best() {
    // Smooth maps: per-map interpolation made consistent with the input is nearly exact,
    // while one epoch of the filter on interpolated renders is not.
    let size = 64;
    let wave = |y: usize, x: usize, phase: f32| {
        let t = std::f32::consts::TAU / size as f32;
        0.5 + 0.3 * ((x as f32 * t + phase).sin() * (y as f32 * t).cos())
    };
    let mut m = Material::uniform(size, [0.5; 3], 0.5, 0.0);
    m.base_color = Map::from_fn(size, size, 3, |c, y, x| wave(y, x, c as f32));
    m.roughness = Map::from_fn(size, size, 1, |_, y, x| wave(y, x, 2.0));
    m.metallic = Map::from_fn(size, size, 1, |_, y, x| wave(x, y, 0.5));
    m.normal = Map::from_fn(size, size, 3, |c, y, x| match c {
        0 => 0.3 * (wave(y, x, 1.0) - 0.5),
        1 => 0.3 * (wave(x, y, 3.0) - 0.5),
        _ => 1.0,
    });
    m.restore_invariants();
    let mut config = trained("bicubic", 1);
    config.select = Selection::Auto;
    let (result, report) = matup::upscale(&m, &config, &RunOptions::default(), &Silent).unwrap();
    let selection = report.selection.expect("validated");
    print_candidates(&selection);
    assert_eq!(selection.validation_size, [16, 16]);
    assert_eq!(selection.candidates.len(), 4);
    assert!(
        selection.chosen.starts_with("per-map"),
        "{}",
        selection.chosen
    );
    let best = selection
        .candidates
        .iter()
        .find(|c| c.name == selection.chosen)
        .unwrap();
    let given = &selection.candidates[0];
    assert_eq!(given.name, "as configured");
    assert!(
        best.render_psnr > given.render_psnr + 1.0,
        "{best:?} vs {given:?}"
    );
    // The run went on with the chosen settings: no training, a back-projected base.
    assert_eq!(report.config.train.epochs, 0);
    assert!(report.config.filter.back_project);
    assert_eq!(report.config.select, Selection::Off);
    assert_eq!((result.width(), result.height_px()), (256, 256));
}

#[test]
fn selection_among_upsamplers_runs_the_one_that_validates_best() {
    // The use it is for: a network fine-tuned on the corpus (which has no tiles) beside stock
    // SPAN, on a tiled floor's 128² LR crop, where the two are close (docs/experiments/
    // 2026-11-25-tiles-in-data.md); validated at 32².
    let tuned = format!(
        "onnx:{}/runs/span_x4_normals_batch24/best.onnx",
        env!("CARGO_MANIFEST_DIR")
    );
    // The top-left quarter of the 256² copy: the 1024² set's 512² crop box-filtered ×4.
    let m = common::load_test_material("ambientcg_Tiles036").crop(0, 0, 128, 128);
    let config = Config {
        upsampler: tuned.clone(),
        select: Selection::Upsampler,
        select_upsamplers: vec!["onnx:span_x4_ch48".into(), tuned.clone()],
        tileable: Some(false),
        seed: 1,
        ..Config::default()
    };
    let (result, report) = matup::upscale(&m, &config, &RunOptions::default(), &Silent).unwrap();
    let selection = report.selection.expect("validated");
    print_candidates(&selection);
    // The configured upsampler first; the tuned network again is the same setting, once.
    let names: Vec<_> = selection
        .candidates
        .iter()
        .map(|c| c.name.clone())
        .collect();
    assert_eq!(
        names,
        [
            format!("upsampler {tuned}"),
            "upsampler onnx:span_x4_ch48".into()
        ]
    );
    assert_eq!(selection.validation_size, [32, 32]);
    // The better score wins (measured with the defaults' two passes and the chroma clamp:
    // the tuned network 33.92 against stock's 33.87; before the clamp stock won, 33.80 against
    // 33.63: the clamp removed the tuned network's tint of the tiles' grout) …
    let best = (selection.candidates.iter())
        .max_by(|a, b| a.score.total_cmp(&b.score))
        .unwrap();
    let other = (selection.candidates.iter())
        .find(|c| c.name != best.name)
        .unwrap();
    assert!(
        best.score > other.score + 0.02,
        "{} vs {}",
        best.score,
        other.score
    );
    assert_eq!(selection.chosen, best.name);
    // … and the run goes on with it: what a plain run with that upsampler gives.
    let chosen = best.name.trim_start_matches("upsampler ").to_string();
    assert_eq!(report.config.upsampler, chosen);
    assert_eq!(report.config.select, Selection::Off);
    let plain = Config {
        upsampler: chosen,
        tileable: Some(false),
        seed: 1,
        ..Config::default()
    };
    let (plain, _) = matup::upscale(&m, &plain, &RunOptions::default(), &Silent).unwrap();
    assert_eq!(result.normal.data(), plain.normal.data());
    assert_eq!(result.base_color.data(), plain.base_color.data());
    // Candidates without a selection, or a selection without candidates, are refused.
    for (select, upsamplers, says) in [
        (
            Selection::Off,
            vec!["bilinear".to_string()],
            "select = \"upsampler\"",
        ),
        (Selection::Upsampler, vec![], "select_upsamplers"),
    ] {
        let c = Config {
            select,
            select_upsamplers: upsamplers,
            ..Config::default()
        };
        let e = matup::upscale(&m, &c, &RunOptions::default(), &Silent)
            .unwrap_err()
            .to_string();
        assert!(e.contains(says), "{e}");
    }
}

#[test]
fn a_crop_of_a_tileable_material_is_not_called_tileable() {
    for name in ["polyhaven_denim_fabric", "polyhaven_wood_cabinet_worn_long"] {
        let m = common::load_test_material(name);
        // The 256² copies: the whole set at 128², and its top-left quarter (a 512² crop of
        // the 1024² set, box-filtered to 128²).
        let (whole, whole_ratio) = detect_tileable(&m.box_downsample(2));
        let (crop, crop_ratio) = detect_tileable(&m.crop(0, 0, 128, 128));
        println!("{name}: whole 128² {whole_ratio:.2}, quarter crop 128² {crop_ratio:.2}");
        assert!(whole, "{name}: the whole material tiles ({whole_ratio})");
        assert!(!crop, "{name}: a crop does not tile ({crop_ratio})");
    }
}

#[test]
fn every_whole_material_is_upscaled_as_tileable() {
    // Mirroring a tileable input seams its output, so the defaults wrap every whole material,
    // grids whose joints lie on the border included, at every size users feed.
    for name in common::test_material_names() {
        let m = common::load_test_material(&name);
        for factor in [1, 2, 4] {
            let (tileable, evidence) = decide_tileable(&m.box_downsample(factor));
            let side = m.width() / factor;
            assert!(tileable, "{name} at {side}²: {evidence}");
            assert!(evidence < 1.1, "{name} at {side}²: {evidence}");
        }
    }
    // A gradient cut out of a larger image is mirrored.
    let mut crop = matup::Material::uniform(64, [0.5; 3], 0.5, 0.0);
    crop.base_color = matup::Map::from_fn(64, 64, 3, |_, y, x| (x + y) as f32 / 128.0);
    assert!(!decide_tileable(&crop).0);
}

/// Rock035, a corpus validation set (never trained on), whole at 256².
fn rock035() -> Material {
    common::load_test_material("ambientcg_Rock035")
}

#[test]
fn the_default_network_is_the_one_tuned_for_materials_and_beats_stock_span() {
    // A corpus validation set (never trained on), the whole set at 256² → 64² → ×4, scored as
    // `matup sweep` scores (16 held-out lights): what docs/experiments/2026-11-25-zoomed-out-crops.md
    // measures on 512² crops.
    let truth = rock035();
    let lr = truth.box_downsample(4);
    let lights = LightSetSpec::held_out(16);
    let ggx = shading_model(&"ggx".parse().unwrap()).unwrap();
    let run = |upsampler: &str| {
        let config = Config {
            upsampler: upsampler.into(),
            tileable: Some(false),
            seed: 1,
            ..Config::default()
        };
        let (result, report) =
            matup::upscale(&lr, &config, &RunOptions::default(), &Silent).unwrap();
        let score =
            matup::eval::metrics::evaluate(&truth, &result, 4, ggx.as_ref(), &lights).unwrap();
        (score, report.upsampler_used)
    };
    let (tuned, used) = run("auto");
    assert_eq!(used, "onnx:span_x4_materials");
    let (stock, _) = run("onnx:span_x4_ch48");
    eprintln!(
        "tuned {:.3} dB / {:.4}, stock {:.3} dB / {:.4}",
        tuned.render_psnr, tuned.render_flip, stock.render_psnr, stock.render_flip
    );
    // Measured with the defaults' two passes: 25.39 dB / FLIP 0.1036 against 25.04 / 0.1085
    // (one pass: 25.36 / 0.1040 against 24.99 / 0.1090; the networks before, one pass:
    // 25.35 / 0.1041, 25.25 / 0.1054).
    assert!(tuned.render_psnr > stock.render_psnr + 0.1);
    assert!(tuned.render_flip < stock.render_flip);
    // Where the network would upsample renders (a trained filter) or maps left as it gives
    // them (no back-projection), which it was not trained for, `auto` runs stock SPAN.
    let mut trained = Config::default();
    trained.train.epochs = 10;
    let mut unprojected = Config::default();
    unprojected.filter.back_project = false;
    for config in [trained, unprojected] {
        let (used, _) = matup::plan::choose_upsampler(&config).unwrap();
        assert_eq!(used, "onnx:span_x4_ch48");
    }
}

#[test]
fn every_scale_runs_the_tuned_network_through_its_own_scale() {
    // A corpus validation set (never trained on), scored as `matup sweep` scores: ×2 from 128²
    // and ×3 from 85², each against the former default (Lanczos-3, back-projected) and
    // Lanczos-3 per map; sweeps/x2_maps.toml and x3_route.toml measure the same on 16 sets.
    let whole = rock035();
    let lights = LightSetSpec::held_out(16);
    let ggx = shading_model(&"ggx".parse().unwrap()).unwrap();
    let lanczos = upsampler(&"lanczos3".parse().unwrap()).unwrap();
    // Measured: ×2 28.72 dB / FLIP 0.0567 (the network on every map) against 27.95 / 0.0604
    // (former default) and 27.78 / 0.0666 (per map); ×3 25.90 / 0.0882 against 25.29 / 0.0951
    // and 25.19 / 0.1005.
    for (scale, side, psnr_gain) in [(2, 256, 0.5), (3, 255, 0.4)] {
        let truth = whole.crop(0, 0, side, side);
        let lr = truth.box_downsample(scale);
        let run = |upsampler: &str| {
            let config = Config {
                scale,
                upsampler: upsampler.into(),
                tileable: Some(false),
                seed: 1,
                ..Config::default()
            };
            matup::upscale(&lr, &config, &RunOptions::default(), &Silent).unwrap()
        };
        let score = |m: &Material| {
            matup::eval::metrics::evaluate(&truth, m, scale, ggx.as_ref(), &lights).unwrap()
        };
        let (ours, report) = run("auto");
        assert_eq!((ours.width(), ours.height_px()), (side, side));
        assert_eq!(report.upsampler_used, "onnx:span_x4_materials");
        let route = &report.levels[0].route;
        let through = if scale == 2 {
            "at ×4, then ÷2 by area (2 passes), back-projected"
        } else {
            "at ×4, then area-shrunk to ×3"
        };
        assert!(
            route.contains(through) && route.contains("back-projected"),
            "{route}"
        );
        // Back-projected at the output scale: the result box-filters back to the input.
        let back = ours.box_downsample(scale);
        let drift = mean_abs_diff(&back.roughness, &lr.roughness);
        assert!(
            drift < 2e-3,
            "×{scale}: roughness box-filters back {drift} from the input"
        );
        let (former, _) = run("lanczos3");
        let per_map =
            matup::per_map::upscale_per_map(&lr, lanczos.as_ref(), scale, Border::Mirror).unwrap();
        let [ours, former, per_map] = [&ours, &former, &per_map].map(score);
        eprintln!(
            "×{scale}: tuned {:.3} dB / {:.4}, lanczos3 back-projected {:.3} / {:.4}, per map {:.3} / {:.4}",
            ours.render_psnr,
            ours.render_flip,
            former.render_psnr,
            former.render_flip,
            per_map.render_psnr,
            per_map.render_flip
        );
        assert!(
            ours.render_psnr > former.render_psnr + psnr_gain,
            "×{scale}"
        );
        assert!(ours.render_flip < former.render_flip, "×{scale}");
        assert!(
            ours.render_psnr > per_map.render_psnr + psnr_gain,
            "×{scale}"
        );
    }
}
