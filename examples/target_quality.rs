//! How close each kind of training target comes to the truth's renders: a true material is
//! box-filtered ×4, and what an RGB upsampler S makes of it (its upsampled LR renders, the
//! detail targets, the renders of per-map S) is compared with the true material's renders,
//! as render PSNR over a training light set. It tells whether S is a better prior on renders
//! or on maps, which decides whether fitting a filter to S's renders can pay.
//!
//! `cargo run --release --example target_quality -- CROP UPSAMPLER MATERIAL...`
//! (e.g. `256 onnx:span_x4_ch48 tests/data/materials/ambientcg_Metal053C`).

use matup::config::{FilterConfig, ResidualBase};
use matup::per_map::{upscale_per_map, MapUpsamplers};
use matup::pipeline::{detect_tileable, features};
use matup::residual::residual_base;
use matup::targets::{base_renders, DetailBase};
use matup::{
    load_material, render, shading_model, upsampler, Border, Kernel, LightSetSpec, Map, Material,
    PluginSpec, RenderOptions,
};

const SCALE: usize = 4;

/// PSNR in dB of `candidate` renders against `truth` renders (peak 1).
fn psnr(candidate: &[Map], truth: &[Map]) -> f64 {
    let (mut squared, mut n) = (0.0f64, 0usize);
    for (c, t) in candidate.iter().zip(truth) {
        for (a, b) in c.data().iter().zip(t.data()) {
            squared += ((a - b) as f64).powi(2);
            n += 1;
        }
    }
    matup::metrics::psnr(squared / n as f64)
}

/// `a + (b − c)` per value, clamped to [0, 1]: the detail-target formula.
fn add_detail(a: &[Map], b: &[Map], c: &[Map]) -> Vec<Map> {
    a.iter()
        .zip(b)
        .zip(c)
        .map(|((a, b), c)| {
            let mut out = a.clone();
            let values = out.data_mut().iter_mut().zip(b.data()).zip(c.data());
            values.for_each(|((v, b), c)| *v = (*v + (b - c)).clamp(0.0, 1.0));
            out
        })
        .collect()
}

fn main() -> matup::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    if args.len() < 3 {
        eprintln!("usage: target_quality CROP UPSAMPLER MATERIAL...");
        std::process::exit(2);
    }
    let crop: usize = args[0].parse().expect("CROP is a whole number");
    let spec: PluginSpec = args[1].parse()?;
    let s = upsampler(&spec)?;
    let model = shading_model(&PluginSpec::new("ggx"))?;
    // Every fourth training light: 25 directions over the hemisphere.
    let lights: Vec<_> = LightSetSpec::default()
        .build()
        .into_iter()
        .step_by(4)
        .collect();
    println!(
        "render PSNR (dB) against the truth's renders, {} training lights, S = {}",
        lights.len(),
        args[1]
    );
    println!("| material | S(r) | K(r) | R(M_K) | detail: R(M_K) + S(r) − K(r) | R(per-map S) | R(per-map S, back-projected) |");
    println!("|---|---|---|---|---|---|---|");
    for folder in &args[2..] {
        let whole = load_material(Some(std::path::Path::new(folder)), &Default::default())?;
        let truth = whole.crop(0, 0, crop, crop);
        let lr = truth.box_downsample(SCALE);
        let border = Border::for_tiling(detect_tileable(&lr).0);
        // Output-size renders one texel per texel, as the training loss renders; the LR
        // renders anti-aliased, as the pipeline makes them.
        let options = |supersample| RenderOptions {
            supersample,
            border,
        };
        let rendered = |m: &Material| render(m, model.as_ref(), &lights, options(false));
        let true_renders = rendered(&truth);
        let lr_renders = render(&lr, model.as_ref(), &lights, options(true));
        let heights = (lr.height.as_ref())
            .map(|h| matup::resample::upsample(h, SCALE, Kernel::Bilinear, border));
        let s_r = s.upsample(&lr_renders, SCALE, border)?;
        let k_r: Vec<Map> = (lr_renders.iter())
            .map(|r| matup::resample::upsample(r, SCALE, Kernel::Lanczos3, border))
            .collect();
        // The Lanczos-upsampled maps, rendered as the training loss renders its base.
        let base_features =
            matup::resample::upsample(&features(&lr), SCALE, Kernel::Lanczos3, border);
        let k_base = DetailBase {
            features: &base_features,
            fixed: &[None; 7],
            heights: heights.as_ref(),
            kernel: Some(Kernel::Lanczos3),
        };
        let r_mk = base_renders(&k_base, model.as_ref(), &lights);
        let per_map = upscale_per_map(&lr, s.as_ref(), SCALE, border)?;
        let projected_features = residual_base(
            &lr,
            &FilterConfig {
                residual_base: ResidualBase::Upsampler,
                back_project: true,
                ..Default::default()
            },
            &MapUpsamplers::one(s.as_ref()),
            SCALE,
            border,
        )?;
        let projected = DetailBase {
            features: &projected_features,
            fixed: &[None; 7],
            heights: heights.as_ref(),
            kernel: None,
        };
        let name = std::path::Path::new(folder)
            .file_name()
            .map_or(folder.clone(), |n| n.to_string_lossy().into_owned());
        println!(
            "| {name} | {:.2} | {:.2} | {:.2} | {:.2} | {:.2} | {:.2} |",
            psnr(&s_r, &true_renders),
            psnr(&k_r, &true_renders),
            psnr(&r_mk, &true_renders),
            psnr(&add_detail(&r_mk, &s_r, &k_r), &true_renders),
            psnr(&rendered(&per_map), &true_renders),
            psnr(
                &base_renders(&projected, model.as_ref(), &lights),
                &true_renders
            ),
        );
    }
    Ok(())
}
