//! The run's plan: the settings and a material made, once, into what the pipeline carries
//! out (`matup::plan`).

mod common;

use std::sync::Arc;

use matup::config::{Config, Selection};
use matup::plan::{Plan, Reach, TilingGrounds};

#[test]
fn a_plan_resolves_the_size_and_chooses_for_every_candidate_once() {
    // The shipped sample: 128², a whole (tileable) material.
    let material = matup::load_material(Some(&common::sample_material()), &Default::default())
        .expect("the sample loads");
    let config = Config {
        size: Some("400".parse().unwrap()),
        select: Selection::Auto,
        ..Config::default()
    };
    let plan = Plan::new(&material, &config).unwrap();
    // 400 from 128: ×4 (512) is the smallest scale past it, then area-shrunk.
    assert_eq!(
        plan.reach,
        Reach {
            scale: 4,
            shrink_to: Some([400, 400])
        }
    );
    assert_eq!(plan.output_size([128, 128]), [400, 400]);
    assert_eq!(
        (plan.setup.settings.scale, plan.setup.settings.size),
        (4, None)
    );
    assert_eq!(plan.reported_settings().size, config.size);
    assert_eq!(plan.setup.levels.len(), 1);
    assert!(matches!(plan.tiling.grounds, TilingGrounds::Edges(_)));
    // The defaults only upsample maps: `auto` chose the network tuned for that.
    assert_eq!(plan.setup.upsampler_name, "onnx:span_x4_materials");
    // Each candidate planned with its own upsampler; the per-map one equals the settings as
    // given, so it is listed once.
    let names: Vec<(&str, &str)> = (plan.candidates.iter())
        .map(|(name, setup)| (name.as_str(), setup.upsampler_name.as_str()))
        .collect();
    assert_eq!(
        names,
        [
            ("as configured", "onnx:span_x4_materials"),
            ("lanczos3-interpolated maps", "onnx:span_x4_ch48"),
            ("filter on upsampled renders", "onnx:span_x4_ch48"),
        ]
    );

    // Another material at the same scale (a folder's image of another size) keeps the setup:
    // the same upsampler, not a second choice.
    let small = material.box_downsample(2);
    let other = plan.for_other_material(&small, None).unwrap();
    assert!(Arc::ptr_eq(&other.setup.upsampler, &plan.setup.upsampler));
    assert_eq!(other.output_size([64, 64]), [256, 256]);

    // Settings that cannot run are refused by the plan, before any work.
    let bad = Config {
        scale: 5,
        ..Config::default()
    };
    let e = Plan::new(&material, &bad).err().expect("×5 is refused");
    assert!(e.to_string().contains("unsupported scale ×5"), "{e}");
}
