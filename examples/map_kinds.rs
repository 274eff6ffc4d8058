//! Which map kinds an upsampler's gain (or loss) comes from: each material's crop is box-filtered
//! ×4 and upsampled by matup's defaults with upsampler A and with upsampler B; then A's result
//! takes one map kind from B's at a time. Back-projection treats each map on its own, so each
//! mix is what a run with B on that kind alone would make. Render PSNR / FLIP against the truth
//! under 16 held-out lights, as `matup sweep` scores.
//!
//! `cargo run --release --example map_kinds -- CROP A B MATERIAL...`
//! (e.g. `256 onnx:span_x4_ch48 onnx:runs/span_x4_normals_batch24/best.onnx tests/data/materials/ambientcg_Tiles036`).

use matup::metrics::evaluate;
use matup::{
    load_material, shading_model, upscale, Config, LightSetSpec, MapKind, Material, PluginSpec,
    RunOptions,
};

const SCALE: usize = 4;
const KINDS: [MapKind; 4] = [
    MapKind::BaseColor,
    MapKind::Normal,
    MapKind::Roughness,
    MapKind::Metallic,
];

fn main() -> matup::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    if args.len() < 4 {
        eprintln!("usage: map_kinds CROP A B MATERIAL...");
        std::process::exit(2);
    }
    let crop: usize = args[0].parse().expect("CROP is a whole number");
    let model = shading_model(&PluginSpec::new("ggx"))?;
    let lights = LightSetSpec::held_out(16);
    let run = |upsampler: &str, lr: &Material| {
        let config = Config {
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
    println!("| material | A | B | A + B's base colour | A + B's normal | A + B's roughness | A + B's metallic |");
    println!("|---|---|---|---|---|---|---|");
    for folder in &args[3..] {
        let whole = load_material(Some(std::path::Path::new(folder)), &Default::default())?;
        let truth = whole.crop(0, 0, crop, crop);
        let lr = truth.box_downsample(SCALE);
        let (a, b) = (run(&args[1], &lr)?, run(&args[2], &lr)?);
        let mut candidates = vec![a.clone(), b.clone()];
        for kind in KINDS {
            let mut mixed = a.clone();
            let from_b = b.map(kind).expect("every material has these maps").clone();
            *mixed.map_mut(kind).expect("every material has these maps") = from_b;
            candidates.push(mixed);
        }
        let cells = candidates
            .iter()
            .map(|c| {
                let e = evaluate(&truth, c, SCALE, model.as_ref(), &lights)?;
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
