//! Every registered shading model is checked here without a test of its own: analytic
//! gradients against finite differences, and finiteness under adversarial inputs.

use std::sync::Arc;

use candle_core::{Device, Tensor, Var};
use matup::texel_loss_op::{RenderLoss, TexelLossOp};
use matup::{
    shading_model, shading_models, Light, LightSample, LossNorm, PluginSpec, ShadingModel, Svbrdf,
    Texel,
};
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};

fn unit(v: [f64; 3]) -> [f64; 3] {
    let l = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    v.map(|c| c / l)
}

fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// A random texel and light well inside every clamp (finite differences need smoothness).
fn smooth_case(rng: &mut StdRng) -> Option<(Svbrdf, LightSample)> {
    let tilt = rng.random_range(0.0..0.8f64);
    let phi = rng.random_range(0.0..std::f64::consts::TAU);
    let n = [tilt.sin() * phi.cos(), tilt.sin() * phi.sin(), tilt.cos()];
    let length = rng.random_range(0.7..1.3);
    let elevation = rng.random_range(0.3..1.45f64);
    let azimuth = rng.random_range(0.0..std::f64::consts::TAU);
    let l = [
        elevation.cos() * azimuth.cos(),
        elevation.cos() * azimuth.sin(),
        elevation.sin(),
    ];
    let h = unit([l[0], l[1], l[2] + 1.0]);
    for cosine in [dot(n, l), n[2], dot(n, h)] {
        if !(0.02..0.98).contains(&cosine) {
            return None;
        }
    }
    let params = Svbrdf {
        base_color: std::array::from_fn(|_| rng.random_range(0.05..0.95)),
        metallic: rng.random_range(0.05..0.95),
        normal: n.map(|c| (c * length) as f32),
        alpha: rng.random_range(0.08..0.95),
        anisotropy: rng.random_range(-0.7..0.7),
        anisotropy_angle: rng.random_range(0.0..std::f32::consts::TAU),
    };
    let light = LightSample {
        direction: l.map(|c| c as f32),
        intensity: 8.0,
    };
    Some((params, light))
}

/// Fourth-order central difference of `f` along parameter `k` with step `h`, in f64.
fn finite_difference(f: &dyn Fn(&Svbrdf) -> f64, p: &Svbrdf, k: usize, h: f32) -> f64 {
    let at = |steps: f32| {
        let mut a = p.to_array();
        a[k] += steps * h;
        f(&Svbrdf::from_array(a))
    };
    (-at(2.0) + 8.0 * at(1.0) - 8.0 * at(-1.0) + at(-2.0)) / (12.0 * h as f64)
}

fn relative_error(analytic: &[f64], numeric: &[f64]) -> f64 {
    let diff: f64 = analytic
        .iter()
        .zip(numeric)
        .map(|(a, b)| (a - b).powi(2))
        .sum::<f64>()
        .sqrt();
    let scale: f64 = numeric.iter().map(|b| b * b).sum::<f64>().sqrt().max(1e-6);
    diff / scale
}

#[test]
fn every_model_gradient_matches_finite_differences() {
    let registry = shading_models().unwrap();
    assert!(registry.len() >= 3, "ggx, ggx-aniso and lambert are linked");
    for registration in registry {
        let model = (registration.create)(None).unwrap();
        if !model.has_jacobian() {
            continue; // a tensor form only: autograd differentiates it
        }
        let mut rng = StdRng::seed_from_u64(2024);
        let (mut checked, mut worst) = (0, 0f64);
        while checked < 400 {
            let Some((p, light)) = smooth_case(&mut rng) else {
                continue;
            };
            let w: [f64; 3] = std::array::from_fn(|_| rng.random_range(0.5..1.5));
            let (_, jacobian) = model.shade_jacobian(&p, &light).unwrap();
            let analytic: Vec<f64> = (0..Svbrdf::LEN)
                .map(|k| {
                    (0..3)
                        .map(|c| w[c] * jacobian[c].to_array()[k] as f64)
                        .sum()
                })
                .collect();
            let f = |q: &Svbrdf| {
                let rgb = model.shade(q, &light);
                (0..3).map(|c| w[c] * rgb[c] as f64).sum::<f64>()
            };
            let numeric: Vec<f64> = (0..Svbrdf::LEN)
                .map(|k| finite_difference(&f, &p, k, 1e-3))
                .collect();
            let err = relative_error(&analytic, &numeric);
            assert!(
                err < 1e-3,
                "{}: relative gradient error {err:.2e} at {p:?} lit from {:?}\n analytic {analytic:?}\n numeric  {numeric:?}",
                registration.name,
                light.direction
            );
            worst = worst.max(err);
            checked += 1;
        }
        println!(
            "{}: {checked} random texels, worst relative error {worst:.2e}",
            registration.name
        );
    }
}

/// Whether no light of the set puts a clamped cosine near its clamp (a kink that central
/// differences would straddle) for this texel.
fn away_from_kinks(p: &Svbrdf, position: &[f32; 3], lights: &[Light]) -> bool {
    let n = unit(p.normal.map(|c| c as f64));
    lights.iter().all(|light| {
        let l = light.sample_at(*position).direction.map(|c| c as f64);
        let h = unit([l[0], l[1], l[2] + 1.0]);
        [dot(n, l), dot(n, h)]
            .iter()
            .all(|c| c.abs() > 0.05 && *c < 0.99)
    })
}

#[test]
fn fused_loss_gradient_matches_finite_differences() {
    let model = shading_model(&PluginSpec::new("ggx")).unwrap();
    // The training lights above 35° elevation (about half of them): with grazing lights too,
    // almost every tilted normal puts some light at a clamp's kink.
    let lights: Vec<Light> = matup::LightSetSpec::default()
        .build()
        .into_iter()
        .filter(|l| l.position[2] / 1.4 > 0.57)
        .collect();
    assert!(lights.len() > 30);
    let mut rng = StdRng::seed_from_u64(5);
    for norm in [
        LossNorm::L21,
        LossNorm::L11,
        LossNorm::L22,
        LossNorm::Lpq { p: 1.5, q: 1.2 },
    ] {
        let mut checked = 0;
        for _ in 0..100_000 {
            if checked == 20 {
                break;
            }
            let Some((p, _)) = smooth_case(&mut rng) else {
                continue;
            };
            let texel = Texel {
                params: p,
                position: [0.2, -0.3, 0.001],
            };
            if !away_from_kinks(&p, &texel.position, &lights) {
                continue;
            }
            // The norms have kinks where an error is zero: targets sit 0.1–0.3 away from the
            // texel's renders in every channel.
            let mut targets = vec![[0f32; 3]; lights.len()];
            model.render_texel(&texel, &lights, &mut targets);
            for t in targets.iter_mut().flatten() {
                *t += if rng.random_bool(0.5) { 1.0 } else { -1.0 } * rng.random_range(0.1..0.3);
            }
            let mut grad = Svbrdf::default();
            model.texel_loss(&texel, &lights, &targets, &norm, Some(&mut grad));
            let f = |q: &Svbrdf| {
                let t = Texel {
                    params: *q,
                    position: texel.position,
                };
                model.texel_loss(&t, &lights, &targets, &norm, None) as f64
            };
            let analytic: Vec<f64> = grad.to_array().iter().map(|&g| g as f64).collect();
            // The loss sums 100 lights in f32: a wider step keeps its rounding out of the quotient.
            let numeric: Vec<f64> = (0..Svbrdf::LEN)
                .map(|k| finite_difference(&f, &p, k, 1e-2))
                .collect();
            // The per-light Jacobians meet 1e-3 above; this f32 sum over ~50 lights has a noise
            // floor near 1e-3 of its own, so 3e-3 (a wrong derivative shows at 1e-1).
            let err = relative_error(&analytic, &numeric);
            assert!(
                err < 3e-3,
                "{norm}: relative error {err:.2e}\n{analytic:?}\n{numeric:?}"
            );
            checked += 1;
        }
        assert_eq!(checked, 20, "{norm}: too few texels clear of every kink");
    }
}

#[test]
fn anisotropic_ggx_equals_ggx_without_anisotropy() {
    let ggx = shading_model(&PluginSpec::new("ggx")).unwrap();
    let aniso = shading_model(&PluginSpec::new("ggx-aniso")).unwrap();
    let mut rng = StdRng::seed_from_u64(11);
    let mut checked = 0;
    while checked < 2000 {
        let Some((mut p, light)) = smooth_case(&mut rng) else {
            continue;
        };
        p.anisotropy = 0.0;
        let (a, ja) = ggx.shade_jacobian(&p, &light).unwrap();
        let (b, jb) = aniso.shade_jacobian(&p, &light).unwrap();
        for c in 0..3 {
            assert!(
                (a[c] - b[c]).abs() <= 1e-4 * a[c].abs().max(1e-2),
                "radiance {a:?} vs {b:?}"
            );
            // Every parameter but the anisotropy ones (which ggx ignores).
            for k in 0..8 {
                let (x, y) = (ja[c].to_array()[k], jb[c].to_array()[k]);
                assert!(
                    (x - y).abs() <= 2e-3 * x.abs().max(1e-1),
                    "d/d{}: {x} vs {y}",
                    Svbrdf::NAMES[k]
                );
            }
        }
        checked += 1;
    }
}

/// Adversarial values for each parameter and for the light.
fn adversarial_params(rng: &mut StdRng) -> Svbrdf {
    const NORMALS: [[f32; 3]; 9] = [
        [0.0, 0.0, 1.0],
        [1.0, 0.0, 0.0],
        [0.0, -1.0, 0.0],
        [0.0, 0.0, -1.0],
        [0.0, 0.0, 0.0],
        [1e-30, 0.0, 0.0],
        [0.7, 0.7, 1e-7],
        [1e10, 0.0, 1.0],
        [0.3, -0.2, -0.9],
    ];
    let pick = |rng: &mut StdRng, choices: &[f32], lo: f32, hi: f32| {
        if rng.random_bool(0.5) {
            choices[rng.random_range(0..choices.len())]
        } else {
            rng.random_range(lo..hi)
        }
    };
    let alpha_of_roughness = |r: f32| r * r;
    Svbrdf {
        base_color: std::array::from_fn(|_| pick(rng, &[0.0, 1.0], 0.0, 1.0)),
        metallic: pick(rng, &[0.0, 1.0], 0.0, 1.0),
        normal: if rng.random_bool(0.5) {
            NORMALS[rng.random_range(0..NORMALS.len())]
        } else {
            std::array::from_fn(|_| rng.random_range(-1.0..1.0))
        },
        alpha: pick(
            rng,
            &[
                0.0,
                alpha_of_roughness(0.045),
                matup::material::MIN_ALPHA,
                1.0,
                1.5,
                -0.1,
            ],
            0.0,
            1.0,
        ),
        anisotropy: pick(rng, &[0.0, -1.0, 1.0, 2.0], -1.0, 1.0),
        anisotropy_angle: pick(rng, &[0.0, std::f32::consts::FRAC_PI_2, 7.0], 0.0, 6.3),
    }
}

fn adversarial_light(rng: &mut StdRng) -> LightSample {
    const DIRECTIONS: [[f32; 3]; 6] = [
        [0.0, 0.0, 1.0],
        [1.0, 0.0, 0.0],
        [0.0, -1.0, 0.0],
        [0.0, 0.0, -1.0],
        [
            std::f32::consts::FRAC_1_SQRT_2,
            0.0,
            std::f32::consts::FRAC_1_SQRT_2,
        ],
        [0.6, 0.8, 1e-8],
    ];
    let direction = if rng.random_bool(0.5) {
        DIRECTIONS[rng.random_range(0..DIRECTIONS.len())]
    } else {
        let v: [f32; 3] = std::array::from_fn(|_| rng.random_range(-1.0..1.0f32));
        let l = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt().max(1e-6);
        v.map(|c| c / l)
    };
    LightSample {
        direction,
        intensity: if rng.random_bool(0.1) { 0.0 } else { 8.0 },
    }
}

#[test]
fn every_model_stays_finite_under_adversarial_inputs() {
    const CASES: usize = 1_000_000;
    let lights = [Light {
        position: [0.3, 0.2, 1.3],
        intensity: 8.0,
        falloff: true,
    }];
    for registration in shading_models().unwrap() {
        let model = (registration.create)(None).unwrap();
        let mut rng = StdRng::seed_from_u64(99);
        for case in 0..CASES {
            let p = adversarial_params(&mut rng);
            let light = adversarial_light(&mut rng);
            let forward = model.shade(&p, &light);
            let (rgb, jacobian) = model
                .shade_jacobian(&p, &light)
                .unwrap_or((forward, Default::default()));
            let finite = forward.iter().chain(&rgb).all(|v| v.is_finite())
                && jacobian
                    .iter()
                    .all(|j| j.to_array().iter().all(|v| v.is_finite()));
            assert!(
                finite,
                "{}: case {case} not finite: {p:?} {light:?} → {rgb:?} {jacobian:?}",
                registration.name
            );
            if case % 16 == 0 {
                // The fused loss path too, with the light on the surface itself.
                let texel = Texel {
                    params: p,
                    position: [0.3, 0.2, 1.3 * (case % 32 == 0) as u8 as f32],
                };
                let mut grad = Svbrdf::default();
                let loss = model.texel_loss(
                    &texel,
                    &lights,
                    &[[0.5; 3]],
                    &LossNorm::L21,
                    Some(&mut grad),
                );
                assert!(
                    loss.is_finite() && grad.to_array().iter().all(|g| g.is_finite()),
                    "{}: fused loss case {case}",
                    registration.name
                );
            }
        }
        println!(
            "{}: {CASES} adversarial and random texel/light cases, all finite",
            registration.name
        );
    }
}

#[test]
fn candle_op_backward_is_the_fused_gradient() {
    let model: Arc<dyn ShadingModel> = Arc::from(shading_model(&PluginSpec::new("ggx")).unwrap());
    let lights: Arc<[Light]> = matup::LightSetSpec::default().build().into();
    let mut rng = StdRng::seed_from_u64(3);
    let batch = 32;
    let mut params = Vec::new();
    let mut positions = Vec::new();
    while positions.len() < batch {
        let Some((p, _)) = smooth_case(&mut rng) else {
            continue;
        };
        params.extend(p.to_array());
        positions.push([
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
            0.0,
        ]);
    }
    let targets: Vec<[f32; 3]> = (0..batch * lights.len())
        .map(|_| std::array::from_fn(|_| rng.random_range(0.0..1.0)))
        .collect();

    let var = Var::from_tensor(
        &Tensor::from_vec(params.clone(), (batch, Svbrdf::LEN), &Device::Cpu).unwrap(),
    )
    .unwrap();
    let op = TexelLossOp::new(RenderLoss::new(
        model.clone(),
        lights.clone(),
        positions.clone(),
        targets.clone(),
        LossNorm::L21,
    ));
    let losses = var.as_tensor().apply_op1(op).unwrap();
    // Weight texels differently so the upstream gradient is not uniform.
    let weights = Tensor::from_vec(
        (0..batch)
            .map(|i| 1.0 + i as f32 / batch as f32)
            .collect::<Vec<_>>(),
        batch,
        &Device::Cpu,
    )
    .unwrap();
    let total = (losses.clone() * &weights).unwrap().sum_all().unwrap();
    let grads = total.backward().unwrap();
    let got = grads
        .get(var.as_tensor())
        .unwrap()
        .to_vec2::<f32>()
        .unwrap();

    let losses = losses.to_vec1::<f32>().unwrap();
    for i in 0..batch {
        let texel = Texel {
            params: Svbrdf::from_array(params[i * 10..(i + 1) * 10].try_into().unwrap()),
            position: positions[i],
        };
        let mut want = Svbrdf::default();
        let loss = model.texel_loss(
            &texel,
            &lights,
            &targets[i * 100..(i + 1) * 100],
            &LossNorm::L21,
            Some(&mut want),
        );
        assert!((loss - losses[i]).abs() <= 1e-5 * loss.abs());
        let scale = 1.0 + i as f32 / batch as f32;
        for (k, (&g, w)) in got[i].iter().zip(want.to_array()).enumerate() {
            let w = w * scale;
            assert!(
                (g - w).abs() <= 1e-5 * w.abs().max(1e-3),
                "texel {i} {}: {g} vs {w}",
                Svbrdf::NAMES[k]
            );
        }
    }
}

#[test]
fn ggx_fused_override_equals_the_generic_loop() {
    let model = shading_model(&PluginSpec::new("ggx")).unwrap();
    let mut lights = matup::LightSetSpec::default().build();
    lights.truncate(37); // not a multiple of the lane count
    lights[3].falloff = true;
    let mut rng = StdRng::seed_from_u64(8);
    for norm in [
        LossNorm::L21,
        LossNorm::L11,
        LossNorm::L22,
        LossNorm::Lpq { p: 1.5, q: 0.8 },
    ] {
        for _ in 0..200 {
            let p = adversarial_params(&mut rng);
            let texel = Texel {
                params: p,
                position: [
                    rng.random_range(-1.0..1.0),
                    rng.random_range(-1.0..1.0),
                    0.003,
                ],
            };
            let targets: Vec<[f32; 3]> = (0..lights.len())
                .map(|_| std::array::from_fn(|_| rng.random_range(0.0..1.0)))
                .collect();
            let (mut fast, mut slow) = (Svbrdf::default(), Svbrdf::default());
            let a = model.texel_loss(&texel, &lights, &targets, &norm, Some(&mut fast));
            let b = matup::shading::texel_loss(
                model.as_ref(),
                &texel,
                &lights,
                &targets,
                &norm,
                Some(&mut slow),
            );
            assert!(
                (a - b).abs() <= 1e-4 * b.abs().max(1.0),
                "{norm}: loss {a} vs {b}"
            );
            for (k, (x, y)) in fast.to_array().iter().zip(slow.to_array()).enumerate() {
                assert!(
                    (x - y).abs() <= 1e-3 * y.abs().max(1.0),
                    "{norm} d/d{}: {x} vs {y} at {p:?}",
                    Svbrdf::NAMES[k]
                );
            }
        }
    }
}

#[test]
fn every_tensor_form_equals_the_fused_loss_and_gradient() {
    use matup::tensor_shading::{params_tensor, texel_losses, LightTensors, SvbrdfTensors};
    let lights = matup::LightSetSpec::default().build();
    let mut checked_models = 0;
    for registration in shading_models().unwrap() {
        let model = (registration.create)(None).unwrap();
        // Models with both forms (a tensor form alone has nothing to be compared with).
        let Some(tensor_form) = model.tensor_form().filter(|_| model.has_jacobian()) else {
            continue;
        };
        checked_models += 1;
        let mut rng = StdRng::seed_from_u64(11);
        // 64 texels, anywhere on the square, under all 100 training lights (grazing ones
        // included): the clamps bite where they bite in training.
        let mut texels = Vec::new();
        while texels.len() < 64 {
            if let Some((params, _)) = smooth_case(&mut rng) {
                let position = [
                    rng.random_range(-1.0..1.0),
                    rng.random_range(-1.0..1.0),
                    rng.random_range(-0.02..0.02),
                ];
                texels.push(Texel { params, position });
            }
        }
        // Targets 0.1–0.3 away from the renders in every channel (the norms' kinks at zero
        // error stay out of the comparison).
        let targets: Vec<Vec<[f32; 3]>> = texels
            .iter()
            .map(|t| {
                let mut out = vec![[0f32; 3]; lights.len()];
                model.render_texel(t, &lights, &mut out);
                for v in out.iter_mut().flatten() {
                    *v +=
                        if rng.random_bool(0.5) { 1.0 } else { -1.0 } * rng.random_range(0.1..0.3);
                }
                out
            })
            .collect();
        let device = Device::Cpu;
        let positions: Vec<[f32; 3]> = texels.iter().map(|t| t.position).collect();
        let light_tensors = LightTensors::new(&lights, &positions, &device).unwrap();
        let flat: Vec<f32> = targets.iter().flatten().flatten().copied().collect();
        let target_tensor =
            Tensor::from_vec(flat, (texels.len(), lights.len(), 3), &device).unwrap();
        let params: Vec<Svbrdf> = texels.iter().map(|t| t.params).collect();
        for norm in [
            LossNorm::L21,
            LossNorm::L11,
            LossNorm::L22,
            LossNorm::Lpq { p: 1.5, q: 1.2 },
        ] {
            let var = Var::from_tensor(&params_tensor(&params, &device).unwrap()).unwrap();
            let svbrdf = SvbrdfTensors::from_params(var.as_tensor()).unwrap();
            let losses =
                texel_losses(tensor_form, &svbrdf, &light_tensors, &target_tensor, &norm).unwrap();
            let grads = losses.sum_all().unwrap().backward().unwrap();
            let losses = losses.to_vec1::<f32>().unwrap();
            let grad = grads
                .get(var.as_tensor())
                .unwrap()
                .to_vec2::<f32>()
                .unwrap();
            for (i, texel) in texels.iter().enumerate() {
                let mut fused_grad = Svbrdf::default();
                let fused =
                    model.texel_loss(texel, &lights, &targets[i], &norm, Some(&mut fused_grad));
                let loss_error = ((losses[i] - fused) / fused).abs();
                assert!(
                    loss_error <= 1e-4,
                    "{} {norm} texel {i}: tensor loss {} against fused {fused}",
                    registration.name,
                    losses[i]
                );
                let as_f64 = |v: &[f32]| v.iter().map(|&g| g as f64).collect::<Vec<_>>();
                let grad_error = relative_error(&as_f64(&grad[i]), &as_f64(&fused_grad.to_array()));
                assert!(
                    grad_error <= 1e-4,
                    "{} {norm} texel {i}: gradient relative error {grad_error:.2e}\n{:?}\n{:?}",
                    registration.name,
                    grad[i],
                    fused_grad.to_array()
                );
            }
        }
    }
    assert_eq!(
        checked_models, 3,
        "ggx, ggx-aniso and lambert have tensor forms"
    );
}
