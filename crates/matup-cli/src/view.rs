//! `matup view`: a relightable before/after page for an upscaled material.

use std::path::{Path, PathBuf};

use anyhow::{bail, Context};
use clap::Args;
use matup_core::io::write_atomic;
use matup_core::pipeline::bilinear_baseline;
use matup_core::view::{starting_light, view_html, Shown, ViewPage};
use matup_core::{load_material, Config, LoadOptions, Material};

#[derive(Args, Debug)]
pub struct ViewArgs {
    /// An output folder of `matup upscale` (or any material folder).
    pub folder: PathBuf,
    /// Compare with this material (same size), instead of bilinear ×N of the run's input;
    /// repeat to choose among several on the page.
    #[arg(long, value_name = "FOLDER")]
    pub compare: Vec<PathBuf>,
    /// Open the page in the default browser.
    #[arg(long)]
    pub open: bool,
}

pub fn run(args: &ViewArgs) -> anyhow::Result<()> {
    let main = load(&args.folder)?;
    let run_json = args.folder.join("run.json");
    let run: Option<serde_json::Value> = match std::fs::read_to_string(&run_json) {
        Ok(text) => Some(
            serde_json::from_str(&text)
                .with_context(|| format!("{}: not a run.json", run_json.display()))?,
        ),
        Err(_) => None,
    };
    let mut comparisons = Vec::new();
    for folder in &args.compare {
        let m = load(folder)?;
        if (m.width(), m.height_px()) != (main.width(), main.height_px()) {
            bail!(
                "{}: {}×{} differs from {}'s {}×{}; compare materials of one size",
                folder.display(),
                m.width(),
                m.height_px(),
                args.folder.display(),
                main.width(),
                main.height_px()
            );
        }
        comparisons.push((label_of(folder), m));
    }
    if comparisons.is_empty() {
        let (input, tileable) = run_input(run.as_ref(), &args.folder)?;
        let scale = main.width() / input.width().max(1);
        let baseline = bilinear_baseline(&input, &main, tileable);
        comparisons.push((format!("bilinear ×{scale}"), baseline));
    }
    let config = run
        .as_ref()
        .and_then(|r| serde_json::from_value::<Config>(r["config"].clone()).ok())
        .unwrap_or_default();
    let page = write_page(
        &args.folder,
        &main,
        &comparisons,
        &config,
        run,
        &format!("matup: {}", label_of(&args.folder)),
    )?;
    println!("wrote {}", page.display());
    if args.open {
        open_in_browser(&page)?;
    }
    Ok(())
}

/// Writes `folder/view.html` showing `main` against `comparisons`; returns its path.
pub fn write_page(
    folder: &Path,
    main: &Material,
    comparisons: &[(String, Material)],
    config: &Config,
    run: Option<serde_json::Value>,
    title: &str,
) -> anyhow::Result<PathBuf> {
    let light = starting_light(&config.lights.build())
        .context("the run's light set is empty; the viewer needs one light")?;
    let page = ViewPage {
        title: title.to_string(),
        main: Shown {
            label: "matup".into(),
            material: main,
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
    let html = view_html(&page)?;
    let path = folder.join("view.html");
    write_atomic(&path, html.as_bytes())?;
    Ok(path)
}

fn load(folder: &Path) -> anyhow::Result<Material> {
    load_material(Some(folder), &LoadOptions::default())
        .with_context(|| format!("cannot load the material in {}", folder.display()))
}

fn label_of(folder: &Path) -> String {
    folder
        .canonicalize()
        .ok()
        .and_then(|p| p.file_name().map(|n| n.to_string_lossy().into_owned()))
        .unwrap_or_else(|| folder.display().to_string())
}

/// The run's input (from `run.json`'s `input_folder`) and whether it was treated as tileable.
fn run_input(run: Option<&serde_json::Value>, folder: &Path) -> anyhow::Result<(Material, bool)> {
    let hint = "pass --compare FOLDER to choose what to compare with";
    let Some(run) = run else {
        bail!(
            "{} has no run.json to find the input in; {hint}",
            folder.display()
        );
    };
    let Some(input) = run["input_folder"].as_str() else {
        bail!(
            "{}: run.json names no input folder; {hint}",
            folder.display()
        );
    };
    let input = load(Path::new(input)).with_context(|| format!("the run's input; {hint}"))?;
    Ok((input, run["tileable"].as_bool().unwrap_or(true)))
}

/// Hands the page to the desktop's opener (a crate would add nothing over these three).
fn open_in_browser(page: &Path) -> anyhow::Result<()> {
    let opener = if cfg!(target_os = "macos") {
        "open"
    } else if cfg!(windows) {
        "explorer"
    } else {
        "xdg-open"
    };
    std::process::Command::new(opener)
        .arg(page)
        .spawn()
        .with_context(|| format!("cannot start {opener} to open {}", page.display()))?;
    Ok(())
}
