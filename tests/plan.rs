//! The run's plan: the settings and a material made, once, into what the pipeline carries
//! out (`matup::plan`).

mod common;

use std::sync::Arc;

use matup::config::{Config, InputQuality, Selection};
use matup::degrade::{
    degrade_material, BlockFormat, Degradation, MaterialDegradation, Subsampling,
};
use matup::material::MapKind;
use matup::plan::{
    Plan, Reach, TilingGrounds, DEGRADED_NETWORK, JPEG_NETWORK, JPEG_PROJECTION_BLUR,
    MATERIAL_NETWORK,
};
use matup::{load_material, LoadOptions, Material};
use rand::SeedableRng;

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

#[test]
fn matups_networks_run_as_the_upsamplers_given_for_them_where_the_route_chooses_them() {
    let clean = Material::uniform(16, [0.5, 0.4, 0.3], 0.6, 0.0);
    let mut jpeg = clean.clone();
    (jpeg.lossy).insert(MapKind::BaseColor, "JPEG (albedo.jpg)".into());
    let mut blocks = clean.clone();
    (blocks.lossy).insert(MapKind::BaseColor, "BC1 blocks (albedo.dds)".into());
    let settings: Config = Config::from_toml(
        "[networks]\nspan_x4_materials = \"lanczos3\"\nspan_x4_degraded = \"bicubic\"\n\
         span_x4_jpeg = \"bilinear\"\n",
        "settings",
    )
    .unwrap();
    let used = |m: &Material| Plan::new(m, &settings).unwrap().setup.upsampler_name;
    assert_eq!(used(&clean), format!("{MATERIAL_NETWORK} as lanczos3"));
    assert_eq!(used(&blocks), format!("{DEGRADED_NETWORK} as bicubic"));
    assert_eq!(used(&jpeg), format!("{JPEG_NETWORK} as bilinear"));
    // Named by hand, too; and what runs must exist.
    let named = Config {
        upsampler: MATERIAL_NETWORK.into(),
        ..settings.clone()
    };
    let p = Plan::new(&clean, &named).unwrap();
    assert_eq!(p.setup.upsampler_name, "onnx:span_x4_materials as lanczos3");
    let mut missing = settings.clone();
    (missing.networks).insert("span_x4_materials".into(), "no_such_upsampler".into());
    let e = Plan::new(&clean, &missing).err().map(|e| e.to_string());
    assert!(e.is_some_and(|e| e.contains("no_such_upsampler")));
}

/// `material` with each of the four rendered maps marked as stored in `storage`.
fn every_map_stored_as(material: &Material, storage: &str) -> Material {
    let mut stored = material.clone();
    for kind in [
        MapKind::BaseColor,
        MapKind::Normal,
        MapKind::Roughness,
        MapKind::Metallic,
    ] {
        (stored.lossy).insert(kind, storage.into());
    }
    stored
}

#[test]
fn a_lossily_stored_input_runs_the_network_for_its_storage() {
    let clean = Material::uniform(16, [0.5, 0.4, 0.3], 0.6, 0.0);
    let mut jpeg = clean.clone();
    (jpeg.lossy).insert(MapKind::BaseColor, "JPEG (albedo.jpg)".into());
    let mut blocks = clean.clone();
    (blocks.lossy).insert(MapKind::Normal, "BC1 blocks (normal.dds)".into());
    let mut both = jpeg.clone();
    (both.lossy).insert(MapKind::Normal, "BC1 blocks (normal.dds)".into());
    let plan = |m: &Material, quality| {
        let settings = Config {
            input_quality: quality,
            ..Config::default()
        };
        Plan::new(m, &settings).unwrap()
    };
    use InputQuality::{Clean, Degraded, Jpeg};
    let apart = |p: &Plan| -> Vec<(MapKind, String)> {
        (p.setup.apart.iter())
            .map(|apart| (apart.kind, apart.name.clone()))
            .collect()
    };
    let each = |names: &[(MapKind, &str)]| -> Vec<(MapKind, String)> {
        names.iter().map(|&(k, n)| (k, n.to_string())).collect()
    };
    // As the files say, map by map: a JPEG base colour through the network for JPEG, projected
    // onto the input's low frequencies alone; the lossless maps beside it as in a clean
    // material, through the material network, projected exactly.
    let auto = plan(&jpeg, InputQuality::Auto);
    assert_eq!(auto.input.quality, Jpeg);
    assert_eq!(
        auto.input.maps,
        [
            (MapKind::BaseColor, Jpeg),
            (MapKind::Metallic, Clean),
            (MapKind::Normal, Clean),
            (MapKind::Roughness, Clean)
        ]
    );
    assert!(auto.input.degraded() && !auto.input.given);
    assert_eq!(auto.setup.upsampler_name, JPEG_NETWORK);
    assert_eq!(
        apart(&auto),
        each(&[
            (MapKind::Normal, MATERIAL_NETWORK),
            (MapKind::Roughness, MATERIAL_NETWORK),
            (MapKind::Metallic, MATERIAL_NETWORK)
        ])
    );
    let filter = &auto.setup.settings.filter;
    assert!(filter.back_project && filter.unprojected_maps.is_empty());
    assert_eq!(filter.projection_blur, JPEG_PROJECTION_BLUR);
    assert_eq!(auto.setup.settings.input_quality, Jpeg);
    assert_eq!(
        auto.setup.upsamplers_used(),
        format!("{JPEG_NETWORK}; normal, roughness, metallic: {MATERIAL_NETWORK}")
    );
    let why = auto.input.describe();
    assert!(
        why.contains("input: JPEG base colour: the base colour projected"),
        "{why}"
    );
    assert!(
        why.contains("; clean metallic, normal, roughness: projected exactly"),
        "{why}"
    );
    assert!(why.contains("base colour from JPEG (albedo.jpg)"), "{why}");
    assert!(why.contains("--input-quality clean"), "{why}");
    // Every map a JPEG (DamagedHelmet): one network; the maps but the colour unprojected.
    let all_jpeg = every_map_stored_as(&clean, "JPEG (model.glb)");
    let p = plan(&all_jpeg, InputQuality::Auto);
    assert!(apart(&p).is_empty());
    assert_eq!(
        p.setup.settings.filter.unprojected_maps,
        [MapKind::Metallic, MapKind::Normal, MapKind::Roughness]
    );
    assert!(p
        .input
        .describe()
        .starts_with("input: JPEG: the base colour projected"));
    // Blocks: the network for degraded maps, unprojected, the others as clean maps; beside a
    // JPEG colour, that colour as a JPEG.
    let p = plan(&blocks, InputQuality::Auto);
    assert_eq!(p.input.quality, Degraded);
    assert_eq!(p.setup.upsampler_name, DEGRADED_NETWORK);
    assert_eq!(p.setup.settings.filter.unprojected_maps, [MapKind::Normal]);
    assert_eq!(apart(&p).len(), 3);
    assert!(p
        .input
        .describe()
        .contains("normal from BC1 blocks (normal.dds)"));
    let p = plan(&both, InputQuality::Auto);
    assert_eq!(p.input.quality, Degraded);
    assert_eq!(
        apart(&p),
        each(&[
            (MapKind::BaseColor, JPEG_NETWORK),
            (MapKind::Roughness, MATERIAL_NETWORK),
            (MapKind::Metallic, MATERIAL_NETWORK)
        ])
    );
    let filter = &p.setup.settings.filter;
    assert_eq!(filter.unprojected_maps, [MapKind::Normal]);
    assert_eq!(filter.projection_blur, JPEG_PROJECTION_BLUR);
    // Every map in blocks: nothing projected at all.
    let game = every_map_stored_as(&clean, "BC1 blocks (game.dds)");
    let p = plan(&game, InputQuality::Auto);
    assert!(apart(&p).is_empty());
    assert!(!p.setup.settings.filter.back_project);
    // A map's word by hand, the others as their files say.
    let normal_degraded = Config {
        map_input_quality: [(MapKind::Normal, Degraded)].into(),
        ..Config::default()
    };
    let p = Plan::new(&jpeg, &normal_degraded).unwrap();
    assert_eq!(p.input.quality, Degraded);
    assert_eq!(p.setup.upsampler_name, DEGRADED_NETWORK);
    assert!(!p.input.given);
    assert_eq!(p.input.lossy, ["base colour from JPEG (albedo.jpg)"]);
    let plain = plan(&clean, InputQuality::Auto);
    assert!(!plain.input.degraded());
    assert_eq!(plain.setup.upsampler_name, MATERIAL_NETWORK);
    assert!(plain.setup.settings.filter.back_project);
    assert_eq!(plain.setup.settings.filter.projection_blur, 0.0);
    assert!(plain.input.describe().contains("--input-quality degraded"));
    // As given, either way.
    let told_clean = plan(&jpeg, InputQuality::Clean);
    assert!(!told_clean.input.degraded() && told_clean.input.given);
    assert_eq!(told_clean.setup.upsampler_name, MATERIAL_NETWORK);
    let told_degraded = plan(&jpeg, InputQuality::Degraded);
    assert_eq!(told_degraded.setup.upsampler_name, DEGRADED_NETWORK);
    assert!(!told_degraded.setup.settings.filter.back_project);
    let told_jpeg = plan(&clean, InputQuality::Jpeg);
    assert_eq!(told_jpeg.setup.upsampler_name, JPEG_NETWORK);
    assert!(told_jpeg
        .input
        .describe()
        .starts_with("input: JPEG (as given)"));
    // A map once a JPEG, kept losslessly: its texels say so.
    let folder = common::test_material("ambientcg_Bricks059");
    let mut resaved = load_material(Some(&folder), &LoadOptions::default()).unwrap();
    assert!(!plan(&resaved, InputQuality::Auto).input.degraded());
    let quality_85 = Degradation::Jpeg {
        quality: 85,
        subsampling: Subsampling::Half,
    };
    let mut rng = rand::rngs::StdRng::seed_from_u64(0);
    resaved.base_color = (quality_85.apply(MapKind::BaseColor, &resaved.base_color, &mut rng))
        .unwrap()
        .crop(2, 2, 240, 240);
    resaved = resaved.crop(0, 0, 240, 240);
    let by_texels = plan(&resaved, InputQuality::Auto).input;
    assert_eq!(by_texels.quality, InputQuality::Jpeg, "{by_texels:?}");
    // The maps saved losslessly beside it are taken as the same set: every map a JPEG.
    assert_eq!(
        by_texels.lossy,
        [
            "a JPEG's 8×8 grid (at x 6, y 6) found in baseColor.png's texels",
            "metallic saved losslessly beside a JPEG, as a JPEG of the same set",
            "normal saved losslessly beside a JPEG, as a JPEG of the same set",
            "roughness saved losslessly beside a JPEG, as a JPEG of the same set"
        ]
    );
    assert!(
        by_texels.maps.iter().all(|&(_, q)| q == Jpeg),
        "{by_texels:?}"
    );
    // A game's BC1 colour unpacked to PNG: its blocks say so, off their grid too; the maps
    // beside it are read for themselves, and stay clean.
    let mut unpacked = load_material(Some(&folder), &LoadOptions::default()).unwrap();
    let bc1 = Degradation::Block(BlockFormat::Bc1);
    unpacked.base_color = (bc1.apply(MapKind::BaseColor, &unpacked.base_color, &mut rng))
        .unwrap()
        .crop(1, 2, 240, 240);
    unpacked = unpacked.crop(0, 0, 240, 240);
    let by_blocks = plan(&unpacked, InputQuality::Auto);
    assert_eq!(
        by_blocks.input.lossy,
        ["BC1/BC3 blocks (4×4 at x 3, y 2) found in baseColor.png's texels"]
    );
    let routes: Vec<_> = by_blocks.input.maps.iter().map(|&(_, q)| q).collect();
    assert_eq!(
        routes,
        [Degraded, Clean, Clean, Clean],
        "{:?}",
        by_blocks.input
    );
    assert!(
        (by_blocks.input.describe())
            .contains("BC1/BC3 blocks (4×4 at x 3, y 2) found in baseColor.png's texels"),
        "{}",
        by_blocks.input.describe()
    );
    assert_eq!(
        by_blocks.setup.settings.filter.unprojected_maps,
        [MapKind::BaseColor]
    );
    // A 16-bit texture set's colour and roughness, dithered to 32 levels and unpacked to PNG:
    // their few levels say so, and the maps beside them (its normals renormalised off any
    // ladder) are taken as the same set.
    let clean_bricks = load_material(Some(&folder), &LoadOptions::default()).unwrap();
    let fs32: MaterialDegradation = "dither32-fs@baseColor+dither32-fs@roughness"
        .parse()
        .unwrap();
    let dithered = degrade_material(&clean_bricks, &fs32, &mut rng).unwrap();
    let by_levels = plan(&dithered, InputQuality::Auto);
    let found = |file: &str| {
        format!("32 levels a channel (dithered or posterised) found in {file}'s texels")
    };
    let beside = |kind: &str| {
        format!(
            "{kind} saved losslessly beside a map of few levels, as one set dithered or posterised"
        )
    };
    assert_eq!(
        by_levels.input.lossy,
        [
            found("baseColor.png"),
            found("roughness.png"),
            beside("metallic"),
            beside("normal")
        ]
    );
    assert!(
        (by_levels.input.maps.iter()).all(|&(_, q)| q == Degraded),
        "{:?}",
        by_levels.input
    );
    assert_eq!(by_levels.setup.upsampler_name, DEGRADED_NETWORK);
    // The height alone shows its levels: a witness for the set, itself not a filter map.
    let fs32_height: MaterialDegradation = "dither32-fs@height".parse().unwrap();
    let dithered = degrade_material(&clean_bricks, &fs32_height, &mut rng).unwrap();
    let by_height = plan(&dithered, InputQuality::Auto).input;
    assert_eq!(by_height.lossy[0], found("height.png"), "{by_height:?}");
    assert!(
        by_height.maps.iter().all(|&(_, q)| q == Degraded),
        "{by_height:?}"
    );
    // Noise under every map, as a noisy scan's set: every map runs degraded, said once.
    let leather = common::test_material("ambientcg_Leather025");
    let small = load_material(Some(&leather), &LoadOptions::default())
        .unwrap()
        .box_downsample(2);
    assert!(!plan(&small, InputQuality::Auto).input.degraded());
    let noisy = degrade_material(&small, &"noise3".parse().unwrap(), &mut rng).unwrap();
    let by_noise = plan(&noisy, InputQuality::Auto).input;
    assert!(
        by_noise.maps.iter().all(|&(_, q)| q == Degraded),
        "{by_noise:?}"
    );
    let [said] = by_noise.lossy.as_slice() else {
        panic!("{:?}", by_noise.lossy)
    };
    assert!(
        said.starts_with("noise of σ 2.")
            && said.ends_with("under all 5 maps, found in their texels"),
        "{said}"
    );
    // Its normals are blended with the clean route's, made by the material network, past the
    // noise read; the other maps are left unprojected.
    let noisy_plan = plan(&noisy, InputQuality::Auto);
    let sigma = by_noise
        .normal_noise
        .expect("the noise read under the normals");
    let filter = &noisy_plan.setup.settings.filter;
    assert_eq!(filter.normal_blend_noise, sigma);
    assert!((2.0..3.5).contains(&sigma), "{sigma}");
    assert!(!filter.back_project);
    assert_eq!(noisy_plan.setup.upsampler_name, DEGRADED_NETWORK);
    let clean_normals = noisy_plan
        .setup
        .clean_normals
        .as_ref()
        .expect("a second network");
    assert_eq!(clean_normals.name, MATERIAL_NETWORK);
    assert!(
        (noisy_plan.setup.upsamplers_used())
            .ends_with("; normal, blended in past the noise: onnx:span_x4_materials"),
        "{}",
        noisy_plan.setup.upsamplers_used()
    );
    assert!(
        by_noise.describe().contains(&format!(
            "the normals blended with the clean route's where they vary far past the noise (σ \
             {sigma:.1} levels)"
        )),
        "{}",
        by_noise.describe()
    );
    // Said degraded by hand, no noise is read and nothing is blended.
    let by_hand = plan(&noisy, InputQuality::Degraded);
    assert_eq!(by_hand.setup.settings.filter.normal_blend_noise, 0.0);
    assert!(by_hand.setup.clean_normals.is_none());
    // A named upsampler stays; the route still decides the projection.
    let named = Config {
        upsampler: "lanczos3".into(),
        ..Config::default()
    };
    let p = Plan::new(&blocks, &named).unwrap();
    assert_eq!(p.setup.upsampler_name, "lanczos3");
    assert!(apart(&p).is_empty());
    assert_eq!(p.setup.settings.filter.unprojected_maps, [MapKind::Normal]);
    // The decided route is part of the settings reported, and reads back from TOML.
    for (material, word) in [(&jpeg, "jpeg"), (&blocks, "degraded")] {
        let reported = plan(material, InputQuality::Auto).reported_settings();
        assert_eq!(
            Config::from_toml(&reported.to_toml(), "run").unwrap(),
            reported
        );
        let toml = reported.to_toml();
        assert!(
            toml.contains(&format!("input_quality = \"{word}\"")),
            "{toml}"
        );
        assert!(toml.contains("[map_input_quality]"), "{toml}");
        assert!(toml.contains("metallic = \"clean\""), "{toml}");
    }
}
