//! `matup view`: a relightable before/after page for an upscaled material.

use std::path::{Path, PathBuf};

use anyhow::{bail, Context};
use clap::Args;
use matup_apps::view::{bilinear_comparison, write_view};
use matup_core::{load_material, LoadOptions, Material, NormalConvention};
use matup_method::Config;

#[derive(Args, Debug)]
pub struct ViewArgs {
    /// An output folder of `matup upscale` (or any material folder).
    pub folder: PathBuf,
    /// Compare with this material (same size), instead of bilinear ×N of the run's input;
    /// repeat to choose among several on the page.
    #[arg(long, value_name = "FOLDER")]
    pub compare: Vec<PathBuf>,
    /// Convention of the normal maps (default: that of the run's input, which matup's
    /// outputs keep; else DirectX).
    #[arg(long, value_name = "directx|opengl")]
    pub normal_convention: Option<NormalConvention>,
    /// Open the page in the default browser.
    #[arg(long)]
    pub open: bool,
}

pub fn run(args: &ViewArgs) -> anyhow::Result<()> {
    let run_json = args.folder.join("run.json");
    let run: Option<serde_json::Value> = match std::fs::read_to_string(&run_json) {
        Ok(text) => Some(
            serde_json::from_str(&text)
                .with_context(|| format!("{}: not a run.json", run_json.display()))?,
        ),
        Err(_) => None,
    };
    // The run's input: the default comparison, and the normal convention the outputs keep.
    // Needed only without --compare; with it, an input that moved away is no error.
    let input = match run.as_ref().and_then(|r| r["input_folder"].as_str()) {
        Some(folder) => match load(Path::new(folder), None) {
            Ok(m) => Some(m),
            Err(e) if args.compare.is_empty() => {
                return Err(e.context("the run's input (named in run.json)"))
            }
            Err(_) => None,
        },
        None => None,
    };
    let convention = args.normal_convention.or(input
        .as_ref()
        .and_then(|m| m.origin.as_ref())
        .map(|o| o.normal_convention));
    let main = load(&args.folder, convention)?;
    let mut comparisons = Vec::new();
    for folder in &args.compare {
        let m = load(folder, args.normal_convention)?;
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
        let Some(input) = &input else {
            bail!(
                "{}: no run.json naming the run's input folder; pass --compare FOLDER to choose what to compare with",
                args.folder.display()
            );
        };
        comparisons.push(bilinear_comparison(input, &main, run.as_ref()));
    }
    let config = run
        .as_ref()
        .and_then(|r| serde_json::from_value::<Config>(r["config"].clone()).ok())
        .unwrap_or_default();
    let page = write_view(
        &args.folder,
        ("matup", &main),
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

fn load(folder: &Path, normal_convention: Option<NormalConvention>) -> anyhow::Result<Material> {
    let options = LoadOptions {
        normal_convention,
        ..Default::default()
    };
    load_material(Some(folder), &options)
        .with_context(|| format!("cannot load the material in {}", folder.display()))
}

fn label_of(folder: &Path) -> String {
    folder
        .canonicalize()
        .ok()
        .and_then(|p| p.file_name().map(|n| n.to_string_lossy().into_owned()))
        .unwrap_or_else(|| folder.display().to_string())
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
