//! matup learn: the training pipeline equals what matup ships, the augmentation turns normals
//! with the surface, and a tiny run trains, resumes exactly and exports a network matup runs.

use std::path::{Path, PathBuf};

use candle_core::{Device, Tensor};
use matup_core::render::{render, RenderOptions};
use matup_core::resample::{upsample, Border, Kernel};
use matup_core::shading::shading_model;
use matup_core::shading::tensor_form;
use matup_core::tensor_shading::{params_tensor, LightTensors};
use matup_core::upsample::{serving_smaller_scales, RgbUpsampler};
use matup_core::{
    load_material, save_material, Dihedral, LightSetSpec, LoadOptions, Map, Material, PluginSpec,
    SaveOptions,
};
use matup_learn::config::{Target, Trained};
use matup_learn::data::{lr_features, network_inputs};
use matup_learn::net::TrainableNet;
use matup_learn::post_process::{decode_outputs, shown, BackProjection, Route};
use matup_learn::train::{centre, one_pass_defaults, shipped_maps};
use matup_learn::{train, LearnConfig};
use matup_method::config::{FilterConfig, ResidualBase};
use matup_method::filter::decode::shading_params;
use matup_method::per_map::MapUpsamplers;
use matup_method::residual::residual_base;
use matup_shading as _;
use matup_upsamplers::onnx::{EngineChoice, OnnxUpsampler};

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../..")
}

/// A crop of a real corpus material, from the 256² copy the repository ships
/// (`tests/data/README.md`).
fn corpus_crop(name: &str, size: usize) -> Material {
    let folder = repo().join("tests/data/materials").join(name);
    let material = load_material(Some(&folder), &LoadOptions::default()).unwrap();
    let at = (material.width() - size) / 2;
    material.crop(at, at, size, size)
}

fn max_difference(a: &[f32], b: &[f32]) -> f32 {
    assert_eq!(a.len(), b.len());
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f32::max)
}

/// Lanczos-3 on every image: overshoots, so the clamps of the decoding are exercised.
struct Lanczos;
impl RgbUpsampler for Lanczos {
    fn upsample(
        &self,
        images: &[Map],
        scale: usize,
        border: Border,
    ) -> matup_core::Result<Vec<Map>> {
        Ok(images
            .iter()
            .map(|m| upsample(m, scale, Kernel::Lanczos3, border))
            .collect())
    }
}

#[test]
fn a_training_crops_centre_beyond_the_zero_paddings_reach_is_what_matup_upscale_ships() {
    let (whole, centre_only) = shipped_against_matup(4);
    // At the crop's edges the zero padding shows; its centre is what users get.
    assert!(whole > 1e-2, "{whole}");
    assert!(centre_only <= 1e-4, "{centre_only}");
}

#[test]
fn training_for_x3_goes_through_matups_route_from_the_x4_network() {
    let (whole, centre_only) = shipped_against_matup(3);
    assert!(whole > 1e-2, "{whole}");
    assert!(centre_only <= 1e-4, "{centre_only}");
}

/// The largest differences, over the whole crop and over its centre beyond the zero padding's
/// reach, between the maps training computes for stock SPAN ×4 run at ×`scale` (64² LR
/// texels) and matup's own residual base.
fn shipped_against_matup(scale: usize) -> (f32, f32) {
    let device = Device::Cpu;
    let model = repo().join("models/span_x4_ch48.onnx");
    let net = TrainableNet::load(&model, &device).unwrap();
    // 64² LR texels; SPAN reads 22 around each, back-projection's 3 rounds 6 more.
    let lr = corpus_crop("ambientcg_Rock029", 64 * scale).box_downsample(scale);
    let back_projection = BackProjection::new(64, scale, Border::Mirror, &device).unwrap();
    let route = (scale < 4).then(|| Route::new(64, 4, scale, Border::Mirror, &device).unwrap());
    let (ours, _) = shipped_maps(
        &net,
        &[&lr],
        &[true],
        route.as_ref(),
        &back_projection,
        &device,
    )
    .unwrap();
    let ours = ours.get(0).unwrap();
    // matup's defaults: the same network on matup's own executor, each map read with its
    // mirrored surroundings, ×4 and shrunk to ×`scale` where that is less, then back-projected.
    let config = FilterConfig {
        residual_base: ResidualBase::Upsampler,
        back_project: true,
        self_ensemble: 1,
        // Training does not model the chroma clamp (crates/matup-learn/src/post_process.rs).
        clamp_chroma: false,
        ..FilterConfig::default()
    };
    let executor = serving_smaller_scales(Box::new(
        OnnxUpsampler::load(&model, EngineChoice::Matup).unwrap(),
    ));
    let shipped = residual_base(
        &lr,
        &config,
        &MapUpsamplers::one(executor.as_ref()),
        scale,
        Border::Mirror,
    )
    .unwrap();
    let shipped = Tensor::from_vec(shipped.into_data(), ours.dims(), &device).unwrap();
    let difference = |margin: usize| -> f32 {
        let d = (centre(&ours.unsqueeze(0).unwrap(), margin).unwrap()
            - centre(&shipped.unsqueeze(0).unwrap(), margin).unwrap())
        .unwrap();
        d.abs().unwrap().max_all().unwrap().to_scalar().unwrap()
    };
    let (whole, centre_only) = (difference(0), difference(scale * 28));
    println!("×{scale}: max |difference|: whole crop {whole:.2e}, its centre {centre_only:.2e}");
    (whole, centre_only)
}

#[test]
fn back_projection_keeps_every_gradient_finite_where_a_block_has_no_room_to_move() {
    // 7 features of 8² texels; the base colour's red is white (1, the top of its range) over
    // a whole 4×4 block, as a network's clamped output often is. Settling cannot move that
    // block, and the branch it does not take must not make every weight's gradient NaN.
    let device = Device::Cpu;
    let values: Vec<f32> = (0..7 * 64)
        .map(|i| {
            let (k, y, x) = (i / 64, i / 8 % 8, i % 8);
            match k {
                0 if y < 4 && x < 4 => 1.0,
                4 | 5 => 0.1 - 0.02 * ((x + y) % 3) as f32,
                _ => 0.4 + 0.05 * ((x * 3 + y) % 4) as f32,
            }
        })
        .collect();
    let hr = candle_core::Var::from_vec(values, (1, 7, 8, 8), &device).unwrap();
    // The LR texels a little above the blocks' means: every block but the white one settles.
    let lr = (hr.as_tensor().avg_pool2d(4).unwrap() + 0.001)
        .unwrap()
        .minimum(1f32)
        .unwrap();
    let back_projection = BackProjection::new(2, 4, Border::Mirror, &device).unwrap();
    let out = back_projection.apply(hr.as_tensor(), &lr).unwrap();
    let grads = out.sum_all().unwrap().backward().unwrap();
    let grad: Vec<f32> = grads
        .get(hr.as_tensor())
        .unwrap()
        .flatten_all()
        .unwrap()
        .to_vec1()
        .unwrap();
    let bad = grad.iter().filter(|g| !g.is_finite()).count();
    assert_eq!(bad, 0, "{bad} of {} gradients are not finite", grad.len());
    // The white block stays white.
    let red: Vec<f32> = out
        .get(0)
        .unwrap()
        .get(0)
        .unwrap()
        .flatten_all()
        .unwrap()
        .to_vec1()
        .unwrap();
    assert!((0..16).all(|i| red[i / 4 * 8 + i % 4] == 1.0));
}

#[test]
fn the_training_pipeline_computes_what_matup_upscale_ships() {
    let device = Device::Cpu;
    let truth = corpus_crop("ambientcg_MetalPlates007", 64);
    let lr = truth.box_downsample(4);
    // matup's own residual base: each map through the upsampler, decoded, back-projected.
    let config = FilterConfig {
        residual_base: ResidualBase::Upsampler,
        back_project: true,
        self_ensemble: 1,
        // Training does not model the chroma clamp (crates/matup-learn/src/post_process.rs).
        clamp_chroma: false,
        ..FilterConfig::default()
    };
    let shipped = residual_base(
        &lr,
        &config,
        &MapUpsamplers::one(&Lanczos),
        4,
        Border::Mirror,
    )
    .unwrap();

    // The same in candle, from the same upsampled images.
    let inputs = network_inputs(&[&lr], &device).unwrap();
    let (n, c, h, w) = inputs.dims4().unwrap();
    let images: Vec<Map> = (0..n)
        .map(|i| {
            Map::from_planar(
                w,
                h,
                c,
                inputs
                    .get(i)
                    .unwrap()
                    .flatten_all()
                    .unwrap()
                    .to_vec1()
                    .unwrap(),
            )
        })
        .collect();
    let upsampled: Vec<f32> = Lanczos
        .upsample(&images, 4, Border::Mirror)
        .unwrap()
        .into_iter()
        .flat_map(|m| m.into_data())
        .collect();
    let outputs = Tensor::from_vec(upsampled, (n, c, 4 * h, 4 * w), &device).unwrap();
    let (lr, fixed) = lr_features(&[&lr], &device).unwrap();
    let back_projection = BackProjection::new(h, 4, Border::Mirror, &device).unwrap();
    let ours = back_projection
        .apply(&decode_outputs(&outputs).unwrap(), &lr)
        .unwrap();
    let ours: Vec<f32> = ours.flatten_all().unwrap().to_vec1().unwrap();
    let difference = max_difference(&ours, shipped.data());
    println!("residual base: max |difference| {difference:.2e}");
    assert!(difference <= 1e-4, "{difference}");

    // Renders: the tensor form at the material's positions against matup's renderer.
    let model = shading_model(&"ggx".parse::<PluginSpec>().unwrap()).unwrap();
    let lights = LightSetSpec::held_out(6).build();
    let texels: Vec<_> = (0..truth.base_color.texels())
        .map(|i| truth.texel(i))
        .collect();
    let params = params_tensor(
        &texels.iter().map(|t| t.params).collect::<Vec<_>>(),
        &device,
    )
    .unwrap();
    let positions: Vec<[f32; 3]> = texels.iter().map(|t| t.position).collect();
    let light_tensors = LightTensors::new(&lights, &positions, &device).unwrap();
    let ours = shown(
        tensor_form(model.as_ref()).unwrap(),
        &params,
        &light_tensors,
    )
    .unwrap();
    let renders = render(
        &truth,
        model.as_ref(),
        &lights,
        RenderOptions {
            supersample: false,
            border: Border::Mirror,
        },
    );
    let ours: Vec<f32> = ours.flatten_all().unwrap().to_vec1().unwrap();
    // ours is [texel][light][channel]; matup's renders are per light, planar.
    let t = texels.len();
    let theirs: Vec<f32> = (0..t)
        .flat_map(|i| {
            renders
                .iter()
                .flat_map(move |r| (0..3).map(move |c| r.plane(c)[i]))
        })
        .collect();
    let difference = max_difference(&ours, &theirs);
    println!("renders: max |difference| {difference:.2e}");
    assert!(difference <= 1e-4, "{difference}");

    assert!(
        fixed[0].iter().all(Option::is_none),
        "every feature varies in this crop"
    );

    // Constant features are held, as the pipeline holds them: Metal009 is metal throughout.
    let metal = corpus_crop("ambientcg_Metal009", 32).box_downsample(4);
    let (features, fixed) = lr_features(&[&metal], &device).unwrap();
    assert_eq!(fixed[0][3], Some(1.0));
    let noisy = (features.get(0).unwrap() + 0.3).unwrap();
    let params = shading_params(&noisy, &fixed[0]).unwrap();
    let metallic: Vec<f32> = params
        .narrow(1, 3, 1)
        .unwrap()
        .flatten_all()
        .unwrap()
        .to_vec1()
        .unwrap();
    assert_eq!(metallic.len(), 8 * 8);
    assert!(metallic.iter().all(|&m| m == 1.0));
}

#[test]
fn a_turned_material_renders_as_the_turned_render() {
    let material = corpus_crop("ambientcg_Bricks059", 32);
    assert!(material.height.is_some());
    let model = shading_model(&"ggx".parse::<PluginSpec>().unwrap()).unwrap();
    let lights = LightSetSpec::held_out(5).build();
    let options = RenderOptions {
        supersample: false,
        border: Border::Mirror,
    };
    let renders = render(&material, model.as_ref(), &lights, options);
    for t in Dihedral::ALL {
        // The lights turn with the surface (positions are tangent-plane vectors too).
        let turned_lights: Vec<_> = lights
            .iter()
            .map(|l| {
                let [x, y] = t.vector([l.position[0], l.position[1]]);
                matup_core::Light {
                    position: [x, y, l.position[2]],
                    ..*l
                }
            })
            .collect();
        let turned = render(
            &material.transformed(t),
            model.as_ref(),
            &turned_lights,
            options,
        );
        for (a, b) in turned.iter().zip(&renders) {
            let difference = max_difference(a.data(), b.transformed(t).data());
            assert!(difference <= 1e-5, "{t:?}: {difference}");
        }
        // The identity aside, the render does change: the normals do not just move.
        if t != Dihedral::default() {
            let unturned_normals = render(
                &Material {
                    normal: material.normal.transformed(t),
                    ..material.transformed(t)
                },
                model.as_ref(),
                &turned_lights,
                options,
            );
            let difference = max_difference(unturned_normals[0].data(), turned[0].data());
            assert!(
                difference > 0.01,
                "{t:?}: moving the normals without turning them changes nothing ({difference})"
            );
        }
    }
}

/// A corpus of two 32² crops (`a` to train on, `b` to validate on) and a configuration
/// training SPAN ×4 on it for `iterations` steps.
fn tiny_run(dir: &Path, iterations: usize) -> LearnConfig {
    let corpus = dir.join("corpus");
    if !corpus.exists() {
        // Bricks: mortar lines and chipped edges a few steps can learn to sharpen (on the
        // 256² copies, a woven fabric's weave is finer than a texel and barely moves).
        for (name, source) in [("a", "ambientcg_Bricks059"), ("b", "ambientcg_Rock029")] {
            save_material(
                &corpus_crop(source, 32),
                &corpus.join(name),
                &SaveOptions::default(),
            )
            .unwrap();
        }
    }
    LearnConfig {
        base_model: repo().join("models/span_x4_ch48.onnx"),
        corpus,
        train: vec!["a".into()],
        val: vec!["b".into()],
        target: Target::Maps,
        scale: 4,
        iterations,
        batch: 1,
        patch: 32,
        lights: 4,
        learning_rate: 2e-4,
        loss: "l11".into(),
        normal_weight: 0.1,
        height_guide: false,
        tiled_share: 0.0,
        zoom_out_share: 0.0,
        context: 0,
        grid_weight: 0.0,
        anchor_weight: 0.0,
        trained: Trained::All,
        checkpoint_every: 2,
        validate_every: 3,
        val_crop: 32,
        val_lights: 4,
        degradations: None,
        val_degrade: Vec::new(),
        seed: 3,
    }
}

#[test]
fn the_grid_term_adds_to_the_loss_in_proportion_to_its_weight_and_only_for_maps() {
    let dir = tempfile::tempdir().unwrap();
    let config = tiny_run(dir.path(), 2);
    let loss = |grid_weight: f64| {
        let c = LearnConfig {
            grid_weight,
            ..config.clone()
        };
        let trainer = matup_learn::train::Trainer::new(&c, &Device::Cpu).unwrap();
        trainer.loss(0).unwrap().1
    };
    let (none, one, two) = (loss(0.0), loss(1.0), loss(2.0));
    // The same step's renders and normals; SPAN's maps of a brick crop draw some grid.
    assert_eq!((one.render, one.normal), (none.render, none.normal));
    let term = one.loss - none.loss;
    assert!(term > 1e-4, "{term}");
    assert!((two.loss - none.loss - 2.0 * term).abs() < 1e-5 * none.loss.max(1.0));
    // A network of renders makes no maps whose grid it could charge.
    let path = dir.path().join("renders_grid.toml");
    let renders = LearnConfig {
        target: Target::Renders,
        normal_weight: 0.0,
        grid_weight: 1.0,
        ..config
    };
    std::fs::write(&path, toml::to_string(&renders).unwrap()).unwrap();
    let error = LearnConfig::load(&path).unwrap_err().to_string();
    assert!(error.contains("grid_weight"), "{error}");
}

#[test]
fn context_around_the_crops_is_cut_from_the_material_and_only_for_a_network_of_maps() {
    let dir = tempfile::tempdir().unwrap();
    // 16² scored with 2 LR texels around: 32² crops, the whole of the 32² material.
    let config = LearnConfig {
        patch: 16,
        context: 2,
        ..tiny_run(dir.path(), 2)
    };
    let trainer = matup_learn::train::Trainer::new(&config, &Device::Cpu).unwrap();
    assert!(trainer.loss(0).unwrap().1.loss.is_finite());
    let too_much = LearnConfig {
        context: 3,
        ..config.clone()
    };
    let error = matup_learn::train::Trainer::new(&too_much, &Device::Cpu)
        .err()
        .expect("40² crops of a 32² material")
        .to_string();
    assert!(error.contains("32×32") && error.contains("40²"), "{error}");
    // A network of normals or of renders reads its crops whole.
    let file = dir.path().join("normals.toml");
    let normals = LearnConfig {
        target: Target::Normals,
        ..config
    };
    std::fs::write(&file, toml::to_string(&normals).unwrap()).unwrap();
    let error = LearnConfig::load(&file).expect_err("refused").to_string();
    assert!(error.contains("context"), "{error}");
}

fn checkpoint_tensors(run: &Path) -> Vec<(String, Vec<f32>)> {
    let mut tensors: Vec<_> =
        candle_core::safetensors::load(run.join("checkpoint.safetensors"), &Device::Cpu)
            .unwrap()
            .into_iter()
            .map(|(k, t)| (k, t.flatten_all().unwrap().to_vec1::<f32>().unwrap()))
            .collect();
    tensors.sort_by(|a, b| a.0.cmp(&b.0));
    tensors
}

fn losses(run: &Path) -> Vec<String> {
    std::fs::read_to_string(run.join("train.csv"))
        .unwrap()
        .lines()
        .skip(1)
        .map(|l| l.rsplit_once(',').unwrap().0.to_string()) // without the seconds
        .collect()
}

/// The mean loss of `config`'s steps (their crops, symmetries and lights) with the network
/// `model` in place of the base model.
fn mean_step_loss(config: &LearnConfig, model: &Path) -> f64 {
    let trainer = matup_learn::train::Trainer::new(
        &LearnConfig {
            base_model: model.to_path_buf(),
            ..config.clone()
        },
        &Device::Cpu,
    )
    .unwrap();
    (0..config.iterations)
        .map(|i| trainer.loss(i).unwrap().1.loss)
        .sum::<f64>()
        / config.iterations as f64
}

#[test]
fn a_tiny_run_lowers_its_loss_resumes_exactly_and_exports_what_matup_runs() {
    let dir = tempfile::tempdir().unwrap();
    let device = Device::Cpu;
    let config = tiny_run(dir.path(), 8);

    // Uninterrupted, and interrupted after 4 steps then resumed: the same steps.
    let whole = dir.path().join("whole");
    let summary = train(&config, &whole, &device, &matup_core::progress::Silent).unwrap();
    assert_eq!((summary.iterations, summary.resumed_from), (8, None));
    let parts = dir.path().join("parts");
    let first = train_until(&config, &parts, 4);
    assert_eq!(first.iterations, 4);
    let second = train(&config, &parts, &device, &matup_core::progress::Silent).unwrap();
    assert_eq!(second.resumed_from, Some(4));
    assert_eq!(losses(&whole), losses(&parts));
    assert_eq!(checkpoint_tensors(&whole), checkpoint_tensors(&parts));
    // Recreated into a folder that keeps an earlier run's logs but no checkpoint: the logs
    // are the new run's alone.
    let again = dir.path().join("again");
    std::fs::create_dir_all(&again).unwrap();
    for log in ["train.csv", "val.csv"] {
        std::fs::copy(whole.join(log), again.join(log)).unwrap();
    }
    train(&config, &again, &device, &matup_core::progress::Silent).unwrap();
    assert_eq!(losses(&whole), losses(&again));
    let val_rows = |run: &Path| std::fs::read_to_string(run.join("val.csv")).unwrap();
    assert_eq!(val_rows(&whole), val_rows(&again));

    // The steps' losses (their crops, symmetries and lights) are lower with the trained
    // weights than with the stock network.
    let trained = whole.join("last.onnx");
    let mean_loss = |model: &Path| mean_step_loss(&config, model);
    let (before, after) = (mean_loss(&config.base_model), mean_loss(&trained));
    println!("the steps' mean loss: {before:.5} → {after:.5}");
    assert!(after < 0.95 * before, "{before} → {after}");

    // matup's own executor runs the export as candle ran it (inside the border, where the
    // executor's mirrored context and candle's zero padding agree), and it differs from the
    // stock network.
    let image = Map::from_fn(48, 48, 3, |c, y, x| {
        0.5 + 0.4 * ((x as f32 * 0.37 + y as f32 * 0.21 + c as f32).sin())
    });
    let executor = |path: &Path| {
        OnnxUpsampler::load(path, EngineChoice::Matup)
            .unwrap()
            .upsample(std::slice::from_ref(&image), 4, Border::Mirror)
            .unwrap()
            .remove(0)
    };
    let candle = TrainableNet::load(&trained, &device).unwrap();
    let input = Tensor::from_slice(image.data(), (1, 3, 48, 48), &device).unwrap();
    let ours = candle.forward(&input).unwrap().get(0).unwrap();
    let ours = Map::from_planar(192, 192, 3, ours.flatten_all().unwrap().to_vec1().unwrap());
    let theirs = executor(&trained);
    let stock = executor(&config.base_model);
    // SPAN sees 21 LR texels around each; the centre 6² LR texels are beyond every border.
    let inner = |m: &Map| m.crop(84, 84, 24, 24);
    let difference = max_difference(inner(&ours).data(), inner(&theirs).data());
    println!("exported network, executor against candle: max |difference| {difference:.2e}");
    assert!(difference <= 1e-4, "{difference}");
    assert!(
        max_difference(theirs.data(), stock.data()) > 1e-3,
        "training changed nothing"
    );
    assert!(whole.join("best.onnx").is_file() && whole.join("best.toml").is_file());

    // Blends: at 0 the stock network, at 1 the best export, at 0.5 every weight halfway.
    let blend =
        |alpha: f64| matup_learn::export::blend(&config, &whole, alpha, None, None).unwrap();
    let best = whole.join("best.onnx");
    // Not assert_eq: a failure would print every value.
    assert!(
        executor(&blend(0.0)).data() == stock.data(),
        "blend 0 is not stock"
    );
    assert!(
        executor(&blend(1.0)).data() == executor(&best).data(),
        "blend 1 is not best"
    );
    let weights = |path: &Path| -> Vec<Vec<f32>> {
        let net = TrainableNet::load(path, &device).unwrap();
        net.vars()
            .iter()
            .map(|v| v.as_tensor().flatten_all().unwrap().to_vec1().unwrap())
            .collect()
    };
    let (stock_w, best_w, half_w) = (
        weights(&config.base_model),
        weights(&best),
        weights(&blend(0.5)),
    );
    for ((s, b), h) in stock_w.iter().zip(&best_w).zip(&half_w) {
        let halfway: Vec<f32> = s.iter().zip(b).map(|(s, b)| 0.5 * s + 0.5 * b).collect();
        assert!(max_difference(h, &halfway) <= 1e-6);
    }
    assert!(whole.join("blend-0.50.toml").is_file());
    // From another network of the same graph (here the halfway blend): halfway from there.
    let half = whole.join("blend-0.50.onnx");
    let from_half = matup_learn::export::blend(&config, &whole, 0.5, Some(&half), None).unwrap();
    assert_eq!(from_half, whole.join("blend-0.50-blend-0.50.onnx"));
    for ((s, b), q) in stock_w.iter().zip(&best_w).zip(&weights(&from_half)) {
        let three_quarters: Vec<f32> = s.iter().zip(b).map(|(s, b)| 0.25 * s + 0.75 * b).collect();
        assert!(max_difference(q, &three_quarters) <= 1e-6);
    }
    // Minus a control (here the halfway blend): the start plus alpha · (best − control), which
    // from stock with the halfway blend as control is stock + alpha/2 · (best − stock).
    let minus_half = matup_learn::export::blend(&config, &whole, 0.5, None, Some(&half)).unwrap();
    assert_eq!(minus_half, whole.join("blend-0.50-minus-blend-0.50.onnx"));
    for ((s, b), q) in stock_w.iter().zip(&best_w).zip(&weights(&minus_half)) {
        let quarter: Vec<f32> = s.iter().zip(b).map(|(s, b)| 0.75 * s + 0.25 * b).collect();
        assert!(max_difference(q, &quarter) <= 1e-6);
    }
    // A control that is the best export itself leaves the start as it is.
    let minus_best = matup_learn::export::blend(&config, &whole, 1.0, None, Some(&best)).unwrap();
    assert_eq!(
        minus_best,
        whole.join(format!(
            "blend-1.00-minus-{}-best.onnx",
            whole.file_name().unwrap().to_string_lossy()
        ))
    );
    assert!(
        executor(&minus_best).data() == stock.data(),
        "best minus best is not the start"
    );
    assert!(matup_learn::export::blend(&config, &whole, 1.5, None, None).is_err());

    let val = std::fs::read_to_string(whole.join("val.csv")).unwrap();
    // Validations at steps 0, 3, 6 and 8, each a material row and a mean row.
    assert_eq!(
        val.lines().filter(|l| l.contains(",mean,")).count(),
        4,
        "{val}"
    );
}

#[test]
fn a_x4_network_trains_and_validates_at_x3_through_matups_route() {
    let dir = tempfile::tempdir().unwrap();
    let config = LearnConfig {
        scale: 3,
        patch: 30,
        val_crop: 30,
        validate_every: 2,
        ..tiny_run(dir.path(), 2)
    };
    let run = dir.path().join("x3");
    let summary = train(&config, &run, &Device::Cpu, &matup_core::progress::Silent).unwrap();
    assert_eq!(summary.iterations, 2);
    // Validated by matup upscale at ×3 (the truth's size over the LR's), at steps 0 and 2.
    let val = std::fs::read_to_string(run.join("val.csv")).unwrap();
    let means: Vec<f64> = (val.lines())
        .filter(|l| l.contains(",mean,"))
        .map(|l| l.split(',').nth(2).unwrap().parse().unwrap())
        .collect();
    assert_eq!(means.len(), 2, "{val}");
    assert!(
        means.iter().all(|psnr| (10.0..60.0).contains(psnr)),
        "{val}"
    );
    // The route is modelled for networks of maps only.
    let renders = LearnConfig {
        target: Target::Renders,
        normal_weight: 0.0,
        ..config.clone()
    };
    let err = train(
        &renders,
        &dir.path().join("r"),
        &Device::Cpu,
        &matup_core::progress::Silent,
    )
    .unwrap_err()
    .to_string();
    assert!(err.contains("route") && err.contains("maps"), "{err}");
}

#[test]
fn a_network_of_renders_learns_the_true_renders_and_is_validated_on_matups_upsampling() {
    let dir = tempfile::tempdir().unwrap();
    let device = Device::Cpu;
    let config = LearnConfig {
        target: Target::Renders,
        normal_weight: 0.0,
        validate_every: 8,
        ..tiny_run(dir.path(), 8)
    };
    let run = dir.path().join("renders");
    train(&config, &run, &device, &matup_core::progress::Silent).unwrap();

    // The steps' losses (their crops' renders under their lights) are lower after training.
    let mean_loss = |model: &Path| mean_step_loss(&config, model);
    let (before, after) = (
        mean_loss(&config.base_model),
        mean_loss(&run.join("last.onnx")),
    );
    println!("the steps' mean render loss: {before:.5} → {after:.5}");
    assert!(after < 0.95 * before, "{before} → {after}");

    // The first validation scores stock SPAN upsampling the validation crop's renders (made
    // as the method makes its LR renders) against the true crop's, under the held-out lights.
    let truth = load_material(Some(&config.corpus.join("b")), &LoadOptions::default()).unwrap();
    let lr = truth.box_downsample(4);
    let model = shading_model(&"ggx".parse::<PluginSpec>().unwrap()).unwrap();
    let options = RenderOptions {
        supersample: true,
        border: Border::Mirror,
    };
    let lights = LightSetSpec::held_out(config.val_lights).build();
    let stock = OnnxUpsampler::load(&config.base_model, EngineChoice::Matup).unwrap();
    let upsampled = stock
        .upsample(
            &render(&lr, model.as_ref(), &lights, options),
            4,
            Border::Mirror,
        )
        .unwrap();
    let exact = render(&truth, model.as_ref(), &lights, options);
    let mse = upsampled
        .iter()
        .zip(&exact)
        .map(|(a, b)| matup_eval::metrics::rmse(a, b).powi(2))
        .sum::<f64>()
        / lights.len() as f64;
    let expected = matup_eval::metrics::psnr(mse);
    let val = std::fs::read_to_string(run.join("val.csv")).unwrap();
    let first: Vec<&str> = val.lines().nth(1).unwrap().split(',').collect();
    assert_eq!(first[..2], ["0", "b"], "{val}");
    let logged: f64 = first[2].parse().unwrap();
    assert!(
        (logged - expected).abs() < 1e-3,
        "{logged} against {expected}"
    );
    // No maps to score.
    assert_eq!(first[4..8], ["", "", "", ""], "{val}");

    // A normal term has no normals to act on.
    let path = dir.path().join("normals.toml");
    let with_normals = LearnConfig {
        normal_weight: 0.5,
        ..config.clone()
    };
    std::fs::write(&path, toml::to_string(&with_normals).unwrap()).unwrap();
    let error = LearnConfig::load(&path).unwrap_err().to_string();
    assert!(error.contains("normal_weight"), "{error}");
}

#[test]
fn a_network_of_normals_is_validated_as_shipped_and_a_height_guide_starts_as_its_network() {
    let dir = tempfile::tempdir().unwrap();
    let device = Device::Cpu;
    let config = LearnConfig {
        target: Target::Normals,
        validate_every: 8,
        ..tiny_run(dir.path(), 8)
    };
    let guided = LearnConfig {
        height_guide: true,
        ..config.clone()
    };
    let trainer = |c: &LearnConfig| matup_learn::train::Trainer::new(c, &device).unwrap();
    let (plain, joint) = (trainer(&config), trainer(&guided));
    // Before training, the height guide's weights are zero: the same losses.
    for i in 0..3 {
        assert_eq!(plain.loss(i).unwrap().1.loss, joint.loss(i).unwrap().1.loss);
    }

    // Trained, the joint network's steps lose less, and it reads the height.
    let joint_run = dir.path().join("joint");
    train(&guided, &joint_run, &device, &matup_core::progress::Silent).unwrap();
    let mean_loss = |t: &matup_learn::train::Trainer| {
        (0..8).map(|i| t.loss(i).unwrap().1.loss).sum::<f64>() / 8.0
    };
    let before = mean_loss(&joint);
    assert_eq!(joint.load_run(&joint_run).unwrap(), 8);
    let after = mean_loss(&joint);
    println!("the joint network's steps' mean loss: {before:.5} → {after:.5}");
    assert!(after < 0.95 * before, "{before} → {after}");
    let height_weights = joint.net.vars().last().unwrap().as_tensor().clone();
    let largest = height_weights.abs().unwrap().max_all().unwrap();
    assert!(
        largest.to_scalar::<f32>().unwrap() > 1e-5,
        "the height is not read"
    );
    // matup's executor runs RGB networks: no export, said plainly.
    assert!(!joint_run.join("best.onnx").exists());
    let error = joint.net.to_onnx().unwrap_err().to_string();
    assert!(error.contains("height-guided"), "{error}");

    // A network of normals' first validation scores what `matup upscale`'s defaults ship with
    // the base network: the truth with the normals of their result, under the held-out lights.
    let plain_run = dir.path().join("plain");
    train(&config, &plain_run, &device, &matup_core::progress::Silent).unwrap();
    let truth = load_material(Some(&config.corpus.join("b")), &LoadOptions::default()).unwrap();
    let lr = truth.box_downsample(4);
    let defaults = matup_method::Config {
        upsampler: format!("onnx:{}", config.base_model.display()),
        ..one_pass_defaults()
    };
    let (shipped, _) = matup_method::upscale(
        &lr,
        &defaults,
        &matup_method::RunOptions::default(),
        &matup_core::progress::Silent,
    )
    .unwrap();
    let mut candidate = truth.clone();
    candidate.normal = shipped.normal.clone();
    let model = shading_model(&"ggx".parse::<PluginSpec>().unwrap()).unwrap();
    let expected = matup_eval::metrics::evaluate(
        &truth,
        &candidate,
        1,
        model.as_ref(),
        &LightSetSpec::held_out(config.val_lights),
    )
    .unwrap();
    let first_row = |run: &Path| -> Vec<String> {
        let val = std::fs::read_to_string(run.join("val.csv")).unwrap();
        val.lines()
            .nth(1)
            .unwrap()
            .split(',')
            .map(String::from)
            .collect()
    };
    let first = first_row(&plain_run);
    assert_eq!(first[..2], ["0", "b"]);
    let (psnr, degrees): (f64, f64) = (first[2].parse().unwrap(), first[4].parse().unwrap());
    println!(
        "first validation {psnr:.4} dB, {degrees:.4}°; matup upscale's normals {:.4} dB, {:.4}°",
        expected.render_psnr, expected.normal_error_degrees
    );
    assert!((psnr - expected.render_psnr).abs() < 1e-3);
    assert!((degrees - expected.normal_error_degrees).abs() < 1e-3);
    // The joint network started where the plain one did.
    assert_eq!(first_row(&joint_run), first);
    // A network of normals is an RGB network: exported as the others are.
    assert!(plain_run.join("best.onnx").is_file());
}

#[test]
fn an_anchored_run_stays_near_the_network_it_started_from() {
    let dir = tempfile::tempdir().unwrap();
    let device = Device::Cpu;
    let config = LearnConfig {
        validate_every: 0,
        ..tiny_run(dir.path(), 8)
    };
    // How far the weights went from the stock network's, root mean square over all.
    let distance = |name: &str, anchor_weight: f64| {
        let run = dir.path().join(name);
        let config = LearnConfig {
            anchor_weight,
            ..config.clone()
        };
        train(&config, &run, &device, &matup_core::progress::Silent).unwrap();
        let stock = TrainableNet::load(&config.base_model, &device).unwrap();
        let (mut sum, mut count) = (0.0f64, 0usize);
        for (i, start) in stock.vars().iter().enumerate() {
            let start = start
                .as_tensor()
                .flatten_all()
                .unwrap()
                .to_vec1::<f32>()
                .unwrap();
            let (_, now) = checkpoint_tensors(&run)
                .into_iter()
                .find(|(k, _)| *k == format!("w{i}"))
                .unwrap();
            sum += start
                .iter()
                .zip(&now)
                .map(|(a, b)| ((a - b) as f64).powi(2))
                .sum::<f64>();
            count += start.len();
        }
        (sum / count as f64).sqrt()
    };
    let free = distance("free", 0.0);
    // Pulled all the way back after each step: only the last step's move remains.
    let anchored = distance("anchored", 1.0 / config.learning_rate);
    println!("RMS distance from stock after 8 steps: {free:.2e} free, {anchored:.2e} anchored");
    assert!(free > 0.0 && anchored < 0.5 * free, "{free} {anchored}");
    // A pull past the start is refused.
    let path = dir.path().join("over.toml");
    let over = LearnConfig {
        anchor_weight: 2.0 / config.learning_rate,
        ..config.clone()
    };
    std::fs::write(&path, toml::to_string(&over).unwrap()).unwrap();
    let error = LearnConfig::load(&path).unwrap_err().to_string();
    assert!(error.contains("anchor_weight"), "{error}");
}

#[test]
fn a_run_that_trains_part_of_the_network_leaves_the_rest_as_it_was() {
    let dir = tempfile::tempdir().unwrap();
    let device = Device::Cpu;
    let stock = TrainableNet::load(&tiny_run(dir.path(), 2).base_model, &device).unwrap();
    let starts: Vec<Vec<f32>> = (stock.vars().iter())
        .map(|v| v.as_tensor().flatten_all().unwrap().to_vec1().unwrap())
        .collect();
    for trained in [Trained::Biases, Trained::LastLayer] {
        let run = dir.path().join(format!("{trained:?}"));
        let config = LearnConfig {
            trained,
            validate_every: 0,
            ..tiny_run(dir.path(), 2)
        };
        train(&config, &run, &device, &matup_core::progress::Silent).unwrap();
        let frozen: Vec<Vec<f32>> = (stock.frozen_vars(trained).iter())
            .map(|v| v.as_tensor().flatten_all().unwrap().to_vec1().unwrap())
            .collect();
        let (mut kept, mut moved) = (0, 0);
        for (i, start) in starts.iter().enumerate() {
            let (_, now) = (checkpoint_tensors(&run).into_iter())
                .find(|(k, _)| *k == format!("w{i}"))
                .unwrap();
            if frozen.contains(start) {
                assert_eq!(&now, start, "{trained:?}: frozen tensor {i} changed");
                kept += 1;
            } else if now != *start {
                moved += 1;
            }
        }
        println!("{trained:?}: {kept} tensors kept, {moved} moved");
        assert!(
            kept > 0 && moved > 0,
            "{trained:?}: {kept} kept, {moved} moved"
        );
    }
}

/// Trains the run in `dir` up to `steps` steps of `config` (whose count is larger): the
/// first part of an interrupted run, stopped the way Ctrl-C stops it.
fn train_until(config: &LearnConfig, dir: &Path, steps: usize) -> matup_learn::Summary {
    struct StopAt(std::path::PathBuf, usize);
    impl matup_core::progress::Progress for StopAt {
        fn cancelled(&self) -> bool {
            let done = std::fs::read_to_string(self.0.join("train.csv"))
                .map(|t| t.lines().count().saturating_sub(1))
                .unwrap_or(0);
            done >= self.1
        }
    }
    let stop = StopAt(dir.to_path_buf(), steps);
    match train(config, dir, &Device::Cpu, &stop) {
        Err(matup_core::Error::Cancelled { epochs_done }) => matup_learn::Summary {
            iterations: epochs_done,
            resumed_from: None,
            best: None,
            seconds: 0.0,
        },
        other => panic!("expected the run to stop at step {steps}: {other:?}"),
    }
}

#[test]
fn degradations_reach_the_network_input_only_and_are_drawn_again_on_resume() {
    let dir = tempfile::tempdir().unwrap();
    let config = tiny_run(dir.path(), 2);
    let degraded = LearnConfig {
        degradations: Some(
            toml::from_str(
                "clean_share = 0.0\nblock = { probability = 1.0 }\njpeg = { probability = 1.0, quality = [30, 40] }\n",
            )
            .unwrap(),
        ),
        val_degrade: vec!["jpeg50".into()],
        ..config.clone()
    };
    let loss = |c: &LearnConfig, step: usize| {
        let trainer = matup_learn::train::Trainer::new(c, &Device::Cpu).unwrap();
        trainer.loss(step).unwrap().1
    };
    let (clean, worse) = (loss(&config, 0), loss(&degraded, 0));
    // The same crop and lights: blocks and JPEG in the input cost render loss against the
    // clean truth, and a step draws the same degradations every time it is taken.
    assert!(
        worse.render > clean.render,
        "{} vs {}",
        worse.render,
        clean.render
    );
    assert_eq!(loss(&degraded, 0).loss, worse.loss);
    // Scored unprojected, a degraded crop's maps are the network's own: another loss, finite.
    let mut unprojected = degraded.clone();
    if let Some(d) = unprojected.degradations.as_mut() {
        d.project_degraded = false;
    }
    let raw = loss(&unprojected, 0);
    assert!(
        raw.loss.is_finite() && raw.render != worse.render,
        "{raw:?} vs {worse:?}"
    );
    // The validation set: each material clean, then degraded as named.
    let set = matup_learn::train::validation_set(&degraded).unwrap();
    let names: Vec<&str> = set.iter().map(|v| v.name.as_str()).collect();
    assert_eq!(names, ["b", "b+jpeg50"]);
    assert_eq!(set[0].truth, set[1].truth);
    assert_ne!(set[0].lr, set[1].lr);
    // A mixture that cannot be drawn is refused with its key.
    let path = dir.path().join("bad.toml");
    let mut text = toml::to_string(&degraded).unwrap();
    text = text.replace("quality = [30, 40]", "quality = [40, 30]");
    std::fs::write(&path, text).unwrap();
    let message = LearnConfig::load(&path).unwrap_err().to_string();
    assert!(message.contains("jpeg.quality"), "{message}");
}
