//! A trained network as matup loads it: the ONNX file (the base model's graph, the trained
//! weights) and its sidecar, both written atomically.

use std::path::Path;

use matup_core::io::write_atomic;
use matup_core::{Error, Result};

use crate::config::{LearnConfig, Target};
use crate::net::TrainableNet;

/// Writes `path` (`NAME.onnx`) and its sidecar `NAME.toml`: the base model's sidecar with the
/// source and description saying how the weights were trained.
pub fn export(
    net: &TrainableNet,
    path: &Path,
    config: &LearnConfig,
    iteration: usize,
) -> Result<()> {
    let trained_on = match config.target {
        Target::Maps => format!(
            "their maps upsampled, with a {} render loss through back-projection (normal \
             weight {})",
            config.loss, config.normal_weight
        ),
        Target::Renders => format!(
            "their renders upsampled, against the true materials' renders ({} loss)",
            config.loss
        ),
        Target::Normals => format!(
            "their normal maps upsampled, with a {} render loss of the true materials with \
             these normals through back-projection (normal weight {})",
            config.loss, config.normal_weight
        ),
    };
    // Inputs degraded as stored maps are (`[degradations]`), and how their outputs were scored.
    let degraded = match &config.degradations {
        Some(d) => format!(
            ", then degraded ({}) in {:.0}% of the crops{}",
            d.drawn().join(", "),
            100.0 * (1.0 - d.clean_share),
            if d.project_degraded {
                ""
            } else {
                ", whose outputs were scored without back-projection"
            }
        ),
        None => String::new(),
    };
    let description = format!(
        "{} fine-tuned by `matup learn` for {iteration} steps on {} materials, box-filtered \
         ×{}{degraded}: {trained_on}",
        base_name(config),
        config.train.len(),
        config.scale,
    );
    export_described(net, path, &config.base_model, &description)
}

/// The base model's file name.
fn base_name(config: &LearnConfig) -> String {
    file_name(&config.base_model)
}

fn file_name(path: &Path) -> String {
    path.file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default()
}

/// Weight-space interpolation between a network and a run's best export (WiSE-FT, Wortsman
/// et al. 2022): every weight `(1 − alpha) · start + alpha · best`, where `start` is the
/// configuration's base model, or `from` (a network of the same graph, such as the stock
/// network a run that began from another fine-tune came from). Written as
/// `DIR/blend-ALPHA.onnx` (`DIR/blend-ALPHA-NAME.onnx` with `from` = `NAME.onnx`) with its
/// sidecar (the start's). Fine-tuned networks often keep most of their gain on data like their
/// training set and lose less on data unlike it when pulled part of the way back to where they
/// started.
///
/// With `minus`, a control run's export of the same start, seed and steps: every weight
/// `start + alpha · (best − minus)` (task arithmetic, Ilharco et al. 2023). The control took
/// the same crops without what the run adds (a loss term), so the difference keeps that term's
/// change and leaves out the drift that tuning on those crops brings alone. Written as
/// `DIR/blend-ALPHA[-NAME]-minus-RUN.onnx`, RUN the control's folder. Without `minus` the
/// reference is the start itself, which is the interpolation above. Returns the path written.
pub fn blend(
    config: &LearnConfig,
    dir: &Path,
    alpha: f64,
    from: Option<&Path>,
    minus: Option<&Path>,
) -> Result<std::path::PathBuf> {
    if !(0.0..=1.0).contains(&alpha) {
        return Err(Error::Invalid(format!(
            "--blend {alpha}: a weight in [0, 1]"
        )));
    }
    let device = candle_core::Device::Cpu;
    let best = dir.join("best.onnx");
    if !best.is_file() {
        return Err(Error::file(&best, "no best export: train the run first"));
    }
    let start_model = from.unwrap_or(&config.base_model);
    let start = TrainableNet::load(start_model, &device)?;
    let tuned = TrainableNet::load(&best, &device)?;
    let control_vars = minus
        .map(|path| TrainableNet::load(path, &device).map(|net| net.vars()))
        .transpose()?;
    let (start_vars, tuned_vars) = (start.vars(), tuned.vars());
    let other_graph = |path: &Path| {
        Error::file(
            path,
            format!("a different graph from {}", start_model.display()),
        )
    };
    if tuned_vars.len() != start_vars.len() {
        return Err(other_graph(&best));
    }
    if let (Some(path), Some(vars)) = (minus, &control_vars) {
        if vars.len() != start_vars.len() {
            return Err(other_graph(path));
        }
    }
    for (i, (s, t)) in start_vars.iter().zip(&tuned_vars).enumerate() {
        let weight = || match &control_vars {
            // (1 − α) · start + α · best, the form the shipped network was blended in
            // (runs/README.md): rebuilding it gives the same file, bit for bit.
            None => (s.as_tensor() * (1.0 - alpha))? + (t.as_tensor() * alpha)?,
            Some(c) => s.as_tensor() + ((t.as_tensor() - c[i].as_tensor())? * alpha)?,
        };
        let set = || s.set(&weight()?);
        set().map_err(|e| Error::file(&best, format!("a weight of another shape: {e}")))?;
    }
    let mut name = format!("blend-{alpha:.2}");
    if let Some(model) = from {
        name += &format!("-{}", file_stem(model));
    }
    if let Some(control) = minus {
        name += &format!("-minus-{}", run_name(control));
    }
    let path = dir.join(name + ".onnx");
    let reference_text = match minus {
        None => format!("(1 − {alpha}) · its own + {alpha} · {}'s", best.display()),
        Some(control) => format!(
            "its own + {alpha} · ({}'s − {}'s)",
            best.display(),
            control.display()
        ),
    };
    let description = format!(
        "{} with every weight {reference_text} (fine-tuned by `matup learn` from {} on {} \
         materials, box-filtered ×{}, {} render loss)",
        file_name(start_model),
        base_name(config),
        config.train.len(),
        config.scale,
        config.loss
    );
    export_described(&start, &path, start_model, &description)?;
    Ok(path)
}

fn file_stem(path: &Path) -> String {
    path.file_stem()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default()
}

/// A run's export is named by its run folder and stem (`runs/NAME/best.onnx` → `NAME-best`);
/// any other network by its file stem.
fn run_name(path: &Path) -> String {
    let stem = file_stem(path);
    match path.parent().and_then(|p| p.file_name()) {
        Some(run) if stem == "best" || stem == "last" => {
            format!("{}-{stem}", run.to_string_lossy())
        }
        _ => stem,
    }
}

/// [`export`] with the sidecar's description given; `base_model` is the network the weights
/// started from (its sidecar is copied).
fn export_described(
    net: &TrainableNet,
    path: &Path,
    base_model: &Path,
    description: &str,
) -> Result<()> {
    let base_sidecar = base_model.with_extension("toml");
    let text = std::fs::read_to_string(&base_sidecar).map_err(|e| Error::io(&base_sidecar, e))?;
    let mut sidecar: toml::Table =
        toml::from_str(&text).map_err(|e| Error::file(&base_sidecar, e.to_string()))?;
    let base = file_name(base_model);
    sidecar.insert("description".into(), description.into());
    let source = sidecar
        .get("source")
        .and_then(|s| s.as_str())
        .unwrap_or("")
        .to_string();
    sidecar.insert(
        "source".into(),
        format!("weights trained by matup learn from {base} ({source})").into(),
    );
    write_atomic(path, &net.to_onnx()?)?;
    write_atomic(
        &path.with_extension("toml"),
        toml::to_string(&sidecar)
            .expect("a table serialises")
            .as_bytes(),
    )
}
