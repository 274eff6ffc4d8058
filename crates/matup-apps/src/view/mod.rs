//! The relightable viewer: one self-contained HTML page (WebGL 2, no server, no network)
//! that renders a material with `ggx` and METHOD.md's display transform under a point light
//! that follows the mouse, split against a comparison, with zoom and pan to texel level, a
//! map selector and the run's numbers.
//!
//! The maps are embedded as 8-bit PNG data URIs, in matup's own encodings (so the page needs
//! no convention of the files): base colour sRGB, normals `0.5·n + 0.5` in matup's frame
//! (DirectX: y grows with the row), and roughness, metallic, height packed into one RGB
//! image. Browsers refuse WebGL textures from `file://` files beside a page, hence the
//! embedding.

use std::path::{Path, PathBuf};

use base64::Engine;
use serde::Serialize;

use crate::html::escape;
use matup_core::color::linear_to_srgb;
use matup_core::io::{encode_normals, encode_png8, load_material, write_atomic, LoadOptions};
use matup_core::lights::Light;
use matup_core::map::Map;
use matup_core::material::{Material, NormalConvention, DISPLACEMENT, MIN_ALPHA};
use matup_core::{Error, Result};
use matup_method::preview::bilinear_baseline;
use matup_method::Config;

/// One material the page shows.
pub struct Shown<'a> {
    /// Its name on the page ("matup ×4", "bilinear ×4", a folder name).
    pub label: String,
    pub material: &'a Material,
}

/// What the page shows: the material, what it is compared with, the lights and the run.
pub struct ViewPage<'a> {
    pub title: String,
    /// Shown right of the split.
    pub main: Shown<'a>,
    /// Shown left of the split, one at a time (a selector picks; at least one).
    pub comparisons: Vec<Shown<'a>>,
    /// The light the page starts with (it then follows the mouse at the same distance).
    pub light: Light,
    /// `run.json` of the run, shown as a table of its numbers.
    pub run: Option<serde_json::Value>,
}

#[derive(Serialize)]
struct EmbeddedMaterial {
    label: String,
    width: usize,
    height: usize,
    has_height: bool,
    base_color: String,
    normal: String,
    /// Roughness (R), metallic (G), height (B).
    rmh: String,
}

#[derive(Serialize)]
struct PageData {
    title: String,
    main: EmbeddedMaterial,
    comparisons: Vec<EmbeddedMaterial>,
    light: [f32; 3],
    intensity: f32,
    min_alpha: f32,
    displacement: f32,
    run: Option<serde_json::Value>,
}

fn data_uri(map: &Map) -> Result<String> {
    let png = encode_png8(map).map_err(|e| Error::Invalid(format!("viewer: {e}")))?;
    Ok(format!(
        "data:image/png;base64,{}",
        base64::engine::general_purpose::STANDARD.encode(png)
    ))
}

fn embed(shown: &Shown) -> Result<EmbeddedMaterial> {
    let m = shown.material;
    let base = m.base_color.clone().map_values(linear_to_srgb);
    let normal = encode_normals(&m.normal, NormalConvention::DirectX);
    let height = m
        .height
        .clone()
        .unwrap_or_else(|| Map::filled(m.width(), m.height_px(), 1, 0.5));
    let rmh = Map::stack(&[&m.roughness, &m.metallic, &height]);
    Ok(EmbeddedMaterial {
        label: shown.label.clone(),
        width: m.width(),
        height: m.height_px(),
        has_height: m.height.is_some(),
        base_color: data_uri(&base)?,
        normal: data_uri(&normal)?,
        rmh: data_uri(&rmh)?,
    })
}

/// The light of `lights` nearest 45° elevation: a start that shows both shading and
/// specular detail.
pub fn starting_light(lights: &[Light]) -> Option<Light> {
    let elevation = |l: &Light| {
        let [x, y, z] = l.position;
        z.atan2(x.hypot(y))
    };
    let target = std::f32::consts::FRAC_PI_4;
    lights
        .iter()
        .min_by(|a, b| {
            (elevation(a) - target)
                .abs()
                .total_cmp(&(elevation(b) - target).abs())
        })
        .copied()
}

/// The page's HTML.
pub fn view_html(page: &ViewPage) -> Result<String> {
    if page.comparisons.is_empty() {
        return Err(Error::Invalid("viewer: nothing to compare with".into()));
    }
    if page.light.falloff {
        return Err(Error::Invalid(
            "viewer: lights with distance falloff are not supported".into(),
        ));
    }
    let data = PageData {
        title: page.title.clone(),
        main: embed(&page.main)?,
        comparisons: page.comparisons.iter().map(embed).collect::<Result<_>>()?,
        light: page.light.position,
        intensity: page.light.intensity,
        min_alpha: MIN_ALPHA,
        displacement: DISPLACEMENT,
        run: page.run.clone(),
    };
    // `</` cannot end the script element from inside a JSON string.
    let json = serde_json::to_string(&data)
        .expect("the page data serialises")
        .replace("</", "<\\/");
    Ok(TEMPLATE
        .replace("{{TITLE}}", &escape(&page.title))
        .replace("{{DATA}}", &json))
}

/// Writes `folder/view.html` showing `main` (label, material) against `comparisons`, lit
/// from the light set of `config` to start with; returns its path.
pub fn write_view(
    folder: &Path,
    main: (&str, &Material),
    comparisons: &[(String, Material)],
    config: &Config,
    run: Option<serde_json::Value>,
    title: &str,
) -> Result<PathBuf> {
    let light = starting_light(&config.lights.build()).ok_or_else(|| {
        Error::Invalid("viewer: the run's light set is empty; the page needs a light".into())
    })?;
    let page = ViewPage {
        title: title.to_string(),
        main: Shown {
            label: main.0.to_string(),
            material: main.1,
        },
        comparisons: comparisons
            .iter()
            .map(|(label, material)| Shown {
                label: label.clone(),
                material,
            })
            .collect(),
        light,
        run,
    };
    let path = folder.join("view.html");
    write_atomic(&path, view_html(&page)?.as_bytes())?;
    Ok(path)
}

/// A run's default comparison: its `input` upsampled bilinearly to the `result`'s size (with
/// the wrap-around or mirrored border `run.json` says it was upscaled with), labelled
/// "bilinear ×N".
pub fn bilinear_comparison(
    input: &Material,
    result: &Material,
    run: Option<&serde_json::Value>,
) -> (String, Material) {
    let scale = result.width() / input.width().max(1);
    let tileable = run.and_then(|r| r["tileable"].as_bool()).unwrap_or(true);
    (
        format!("bilinear ×{scale}"),
        bilinear_baseline(input, result, tileable),
    )
}

/// The page of a finished run in `out` (as [`crate::folder::upscale_to_folder`] wrote it,
/// `run.json` included): its maps as written, in the convention the outputs keep (the
/// input's), against bilinear ×N of `input`.
pub fn write_run_view(input: &Material, out: &Path) -> Result<PathBuf> {
    let run_json = out.join("run.json");
    let text = std::fs::read_to_string(&run_json).map_err(|e| Error::io(&run_json, e))?;
    let run: serde_json::Value = serde_json::from_str(&text)
        .map_err(|e| Error::file(&run_json, format!("not a run.json: {e}")))?;
    let config: Config = serde_json::from_value(run["config"].clone())
        .map_err(|e| Error::file(&run_json, format!("its config does not parse: {e}")))?;
    let options = LoadOptions {
        normal_convention: input.origin.as_ref().map(|o| o.normal_convention),
        ..Default::default()
    };
    let result = load_material(Some(out), &options)?;
    let comparison = bilinear_comparison(input, &result, Some(&run));
    let title = match run["input_folder"].as_str() {
        Some(folder) => format!("matup: {folder}"),
        None => "matup".to_string(),
    };
    write_view(
        out,
        ("matup", &result),
        &[comparison],
        &config,
        Some(run),
        &title,
    )
}

const TEMPLATE: &str = include_str!("view.html");
