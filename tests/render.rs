//! The renderer and `ggx` against METHOD.md, transcribed independently here in f64.

mod common;

use matup::lights::LightSample;
use matup::material::Material;
use matup::render::{render, RenderOptions};
use matup::{shading_model, Light, LightSetSpec, PluginSpec, Svbrdf};
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};

fn display(t: f64) -> f64 {
    let t = t.max(0.0) / (1.0 + t.max(0.0));
    if t <= 0.0031308 {
        12.92 * t
    } else {
        1.055 * t.powf(1.0 / 2.4) - 0.055
    }
}

/// METHOD.md's Cook–Torrance, written out directly in f64 (no clamps: inputs stay inside them).
fn reference_ggx(p: &Svbrdf, l: [f64; 3], intensity: f64) -> [f64; 3] {
    let norm = |v: [f64; 3]| {
        let len = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
        v.map(|c| c / len)
    };
    let dot = |a: [f64; 3], b: [f64; 3]| a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
    let n = norm(p.normal.map(|c| c as f64));
    let v = [0.0, 0.0, 1.0];
    let h = norm([l[0] + v[0], l[1] + v[1], l[2] + v[2]]);
    let (nol, nov, noh, loh) = (dot(n, l), dot(n, v), dot(n, h), dot(l, h));
    let a = p.alpha as f64;
    let a2 = a * a;
    let d = a2 / (std::f64::consts::PI * (noh * noh * (a2 - 1.0) + 1.0).powi(2));
    let vis = 0.5
        / (nol * (nov * nov * (1.0 - a2) + a2).sqrt() + nov * (nol * nol * (1.0 - a2) + a2).sqrt());
    let m = p.metallic as f64;
    std::array::from_fn(|c| {
        let b = p.base_color[c] as f64;
        let f0 = 0.04 * (1.0 - m) + m * b;
        let f = f0 + (1.0 - f0) * (1.0 - loh).powi(5);
        intensity * nol * ((1.0 - m) * b / std::f64::consts::PI + d * vis * f)
    })
}

#[test]
fn ggx_is_method_cook_torrance() {
    let ggx = shading_model(&PluginSpec::new("ggx")).unwrap();
    let mut rng = StdRng::seed_from_u64(1);
    let mut checked = 0;
    while checked < 5000 {
        let n = [
            rng.random_range(-0.6..0.6),
            rng.random_range(-0.6..0.6),
            1.0,
        ];
        let l = {
            let v = [
                rng.random_range(-1.0..1.0),
                rng.random_range(-1.0..1.0),
                rng.random_range(0.1..1.0f64),
            ];
            let len = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
            v.map(|c| c / len)
        };
        let p = Svbrdf {
            base_color: std::array::from_fn(|_| rng.random_range(0.0..1.0)),
            metallic: rng.random_range(0.0..1.0),
            normal: n,
            alpha: rng.random_range(0.01..1.0),
            ..Default::default()
        };
        let want = reference_ggx(&p, l, 8.0);
        let unit_n = {
            let nn = p.normal.map(|c| c as f64);
            let len = (nn[0] * nn[0] + nn[1] * nn[1] + nn[2] * nn[2]).sqrt();
            nn.map(|c| c / len)
        };
        let h = {
            let v = [l[0], l[1], l[2] + 1.0];
            let len = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
            v.map(|c| c / len)
        };
        let cosines =
            [l, [0.0, 0.0, 1.0], h].map(|d| unit_n[0] * d[0] + unit_n[1] * d[1] + unit_n[2] * d[2]);
        if !cosines.iter().all(|c| (0.01..0.999).contains(c)) {
            continue; // clamped cosines are the model's business, not the formula's
        }
        let got = ggx.shade(
            &p,
            &LightSample {
                direction: l.map(|c| c as f32),
                intensity: 8.0,
            },
        );
        for c in 0..3 {
            assert!(
                (got[c] as f64 - want[c]).abs() <= 1e-4 * want[c].abs().max(1e-2),
                "{got:?} vs {want:?}"
            );
        }
        checked += 1;
    }
}

#[test]
fn lambert_render_of_a_white_plane_is_cosine_shading() {
    let white = Material::uniform(16, [1.0; 3], 0.5, 0.0);
    let light = Light {
        position: [0.0, 0.0, 1.4],
        intensity: 8.0,
        falloff: false,
    };
    let model = shading_model(&PluginSpec::new("lambert")).unwrap();
    let options = RenderOptions {
        supersample: false,
        ..Default::default()
    };
    let image = &render(&white, model.as_ref(), &[light], options)[0];
    for i in 0..16 {
        for j in 0..16 {
            let (x, y) = (
                2.0 * (j as f64 + 0.5) / 16.0 - 1.0,
                2.0 * (i as f64 + 0.5) / 16.0 - 1.0,
            );
            let cos = 1.4 / (x * x + y * y + 1.4 * 1.4).sqrt();
            let want = display(8.0 * cos / std::f64::consts::PI);
            for c in 0..3 {
                assert!((image.get(c, i, j) as f64 - want).abs() < 1e-5);
            }
        }
    }
}

#[test]
fn supersampling_a_constant_material_changes_nothing() {
    let m = Material::uniform(64, [0.6, 0.4, 0.2], 0.4, 0.3);
    let model = shading_model(&PluginSpec::new("ggx")).unwrap();
    let lights = LightSetSpec::default().build();
    let plain = render(
        &m,
        model.as_ref(),
        &lights[..8],
        RenderOptions {
            supersample: false,
            ..Default::default()
        },
    );
    let fine = render(&m, model.as_ref(), &lights[..8], RenderOptions::default());
    for (a, b) in plain.iter().zip(&fine) {
        let worst = common::max_abs_diff(a, b);
        // Only the sub-texel positions differ, and the lighting varies slowly across a texel.
        assert!(worst < 5e-3, "{worst}");
    }
}

#[test]
fn sample_renders_under_the_training_lights() {
    let m = matup::load_material(Some(&common::sample_material()), &Default::default()).unwrap();
    let model = shading_model(&PluginSpec::new("ggx")).unwrap();
    let lights = LightSetSpec::default().build();
    let renders = render(&m, model.as_ref(), &lights, RenderOptions::default());
    assert_eq!(renders.len(), 100);
    for r in &renders {
        assert_eq!((r.width(), r.height(), r.channels()), (128, 128, 3));
        assert!(r
            .data()
            .iter()
            .all(|v| v.is_finite() && (0.0..=1.0).contains(v)));
    }
    // Overhead lights show the wood brighter than grazing ones.
    let brightness =
        |k: usize| renders[k].data().iter().sum::<f32>() / renders[k].data().len() as f32;
    let overhead = (0..100)
        .max_by(|&a, &b| lights[a].position[2].total_cmp(&lights[b].position[2]))
        .unwrap();
    let grazing = (0..100)
        .min_by(|&a, &b| lights[a].position[2].total_cmp(&lights[b].position[2]))
        .unwrap();
    assert!(brightness(overhead) > 2.0 * brightness(grazing));
    // Rendering is deterministic.
    let again = render(&m, model.as_ref(), &lights[..3], RenderOptions::default());
    assert_eq!(again[2], renders[2]);
}
