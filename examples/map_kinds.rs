//! Which map kinds an upsampler's gain (or loss) comes from: each material's crop is box-filtered
//! ×4 and upsampled by matup's defaults with upsampler A and with upsampler B; then A's result
//! takes one map kind from B's at a time. Back-projection treats each map on its own, so each
//! mix is what a run with B on that kind alone would make. Render PSNR / FLIP against the truth
//! under 16 held-out lights, as `matup sweep` scores.
//!
//! `cargo run --release --example map_kinds -- CROP[xSCALE] A B MATERIAL...` (×4 unless a scale
//! is given: `512x2` crops 512², box-filters it ÷2 and upsamples ×2). The last column gives A's
//! result B's base colour and normal together.
//! (e.g. `256 onnx:span_x4_ch48 onnx:runs/span_x4_normals_batch24/best.onnx tests/data/materials/ambientcg_Tiles036`).

use matup::metrics::evaluate;
use matup::{
    load_material, shading_model, upscale, Config, LightSetSpec, MapKind, Material, PluginSpec,
    RunOptions,
};

const KINDS: [MapKind; 4] = [
    MapKind::BaseColor,
    MapKind::Normal,
    MapKind::Roughness,
    MapKind::Metallic,
];

fn main() -> matup::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    if args.len() < 4 {
        eprintln!("usage: map_kinds CROP[xSCALE] A B MATERIAL...");
        std::process::exit(2);
    }
    let (crop, scale) = args[0].split_once('x').unwrap_or((&args[0], "4"));
    let crop: usize = crop.parse().expect("CROP is a whole number");
    let scale: usize = scale.parse().expect("SCALE is a whole number");
    let model = shading_model(&PluginSpec::new("ggx"))?;
    let lights = LightSetSpec::held_out(16);
    let run = |upsampler: &str, lr: &Material| {
        let config = Config {
            scale,
            upsampler: upsampler.to_string(),
            ..Config::default()
        };
        upscale(
            lr,
            &config,
            &RunOptions::default(),
            &matup::progress::Silent,
        )
        .map(|r| r.0)
    };
    println!(
        "render PSNR dB / FLIP, A = {}, B = {}; \"A + B's X\": A's result with B's X map",
        args[1], args[2]
    );
    println!("| material | A | B | A + B's base colour | A + B's normal | A + B's roughness | A + B's metallic | A + B's base colour and normal |");
    println!("|---|---|---|---|---|---|---|---|");
    for folder in &args[3..] {
        let whole = load_material(Some(std::path::Path::new(folder)), &Default::default())?;
        let truth = whole.crop(0, 0, crop, crop);
        let lr = truth.box_downsample(scale);
        let (a, b) = (run(&args[1], &lr)?, run(&args[2], &lr)?);
        let mut candidates = vec![a.clone(), b.clone()];
        for kind in KINDS {
            let mut mixed = a.clone();
            let from_b = b.map(kind).expect("every material has these maps").clone();
            *mixed.map_mut(kind).expect("every material has these maps") = from_b;
            candidates.push(mixed);
        }
        let mut colour_and_normal = a.clone();
        for kind in [MapKind::BaseColor, MapKind::Normal] {
            *colour_and_normal
                .map_mut(kind)
                .expect("every material has these maps") =
                b.map(kind).expect("every material has these maps").clone();
        }
        candidates.push(colour_and_normal);
        let cells = candidates
            .iter()
            .map(|c| {
                let e = evaluate(&truth, c, scale, model.as_ref(), &lights)?;
                Ok(format!("{:.2} / {:.4}", e.render_psnr, e.render_flip))
            })
            .collect::<matup::Result<Vec<_>>>()?;
        let name = std::path::Path::new(folder)
            .file_name()
            .map_or(folder.clone(), |n| n.to_string_lossy().into_owned());
        println!("| {name} | {} |", cells.join(" | "));
    }
    Ok(())
}
