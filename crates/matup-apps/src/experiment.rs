//! Experiments: true materials downsampled into LR inputs, upscaled by each method (per-map
//! baselines, matup under each point of a sweep, the oracle), and evaluated against the truth.
//! One row per run goes to `results.jsonl` as soon as it finishes, so an interrupted
//! experiment resumes where it stopped; `results.csv` and `results.json` are rewritten
//! (atomically) after every run.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};
use std::time::Instant;

use rand::rngs::StdRng;
use rand::SeedableRng;
use serde::{Deserialize, Serialize};

use crate::html::{escape, href};
use crate::view::write_view;
use matup_core::degrade::{degraded_input, MaterialDegradation};
use matup_core::io::{load_material, save_material, write_atomic, LoadOptions, Names, SaveOptions};
use matup_core::lights::LightSetSpec;
use matup_core::material::{FileFormat, Material, NormalConvention};
use matup_core::progress::Progress;
use matup_core::resample::Border;
use matup_core::shading::shading_model;
use matup_core::upsample::{check_scale, upsampler};
use matup_core::{Error, PluginSpec, Result};
use matup_eval::metrics::{
    evaluate, false_colour, new_structure, worst_invented_structure, worst_new_structure,
    Evaluation,
};
use matup_method::config::{check_supported_scale, Config};
use matup_method::per_map::upscale_per_map;
use matup_method::pipeline::{detect_tileable, upscale};
use matup_method::plan::check_settings;
use matup_method::RunOptions;

/// An experiment file (`matup sweep FILE.toml`); `matup bench` builds one from its arguments.
#[derive(Clone, Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Experiment {
    /// Folders of true (HR) materials, relative to the experiment file.
    pub materials: Vec<PathBuf>,
    /// HR → LR box-filter factor, and the upscale factor of every method.
    #[serde(default = "default_factor")]
    pub factor: usize,
    /// Evaluate on a `crop × crop` window of each material only (faster sweeps), its
    /// top-left texel at (`crop_at`, `crop_at`).
    #[serde(default)]
    pub crop: Option<usize>,
    /// Where the crop starts on both axes: 0 (the default) keeps the material's corner; an
    /// odd offset makes crops that do not tile, even of a grid whose period divides `crop`.
    #[serde(default)]
    pub crop_at: usize,
    /// Held-out (Hammersley) lights the results are evaluated under.
    #[serde(default = "default_eval_lights")]
    pub eval_lights: usize,
    /// The shading model of the evaluation renders.
    #[serde(default = "default_shading")]
    pub eval_shading: String,
    /// Per-map baselines: RGB upsamplers every map goes through on its own.
    #[serde(default)]
    pub baselines: Vec<String>,
    /// Also run matup on exact renders of the truth (the method's ceiling) at each point.
    #[serde(default)]
    pub oracle: bool,
    /// Settings every matup run starts from (the keys of `matup upscale --config`).
    #[serde(default)]
    pub base: toml::Table,
    /// Settings to vary: a list of values per key (`"train.loss" = ["l21", "l11"]`).
    #[serde(default)]
    pub axes: BTreeMap<String, Vec<toml::Value>>,
    /// `grid`: every combination of the axes; `zip`: the i-th values of every axis together.
    #[serde(default)]
    pub mode: AxesMode,
    /// Degradations of the LR inputs (`matup_core::degrade::MaterialDegradation`: `"bc1"`,
    /// `"jpeg75"`, `"dds"`, …; `"clean"` for none), one or a list: each material runs once per
    /// entry, named `MATERIAL+DEGRADATION`, against its clean truth. None: clean inputs.
    #[serde(default, deserialize_with = "one_or_many")]
    pub degrade: Vec<String>,
    /// Keep every run's maps in `outputs/MATERIAL/RUN/` (the truth in `outputs/MATERIAL/truth/`)
    /// and write `outputs/MATERIAL/view.html`, where a menu picks the method to compare.
    #[serde(default)]
    pub view: bool,
}

/// A string or a list of strings, as a list.
fn one_or_many<'de, D: serde::Deserializer<'de>>(
    d: D,
) -> std::result::Result<Vec<String>, D::Error> {
    #[derive(Deserialize)]
    #[serde(untagged)]
    enum OneOrMany {
        One(String),
        Many(Vec<String>),
    }
    Ok(match OneOrMany::deserialize(d)? {
        OneOrMany::One(s) => vec![s],
        OneOrMany::Many(v) => v,
    })
}

/// The name of clean inputs in [`Experiment::degrade`].
pub const CLEAN: &str = "clean";

fn default_factor() -> usize {
    4
}
fn default_eval_lights() -> usize {
    16
}
fn default_shading() -> String {
    "ggx".into()
}

#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum AxesMode {
    #[default]
    Grid,
    Zip,
}

/// What one run does to an LR material.
#[derive(Clone, Debug)]
pub enum Method {
    /// Every map through this RGB upsampler on its own.
    PerMap(String),
    /// matup with this configuration.
    Matup(Config),
    /// matup on exact renders of the truth.
    Oracle(Config),
}

/// One run: a method on a material.
#[derive(Clone, Debug)]
pub struct Run {
    /// `material/method settings`: unique, and the key a resumed experiment skips by.
    pub id: String,
    pub material: PathBuf,
    /// What the LR input goes through before the method sees it.
    pub degrade: Option<MaterialDegradation>,
    pub method: Method,
    /// `per-map`, `matup` or `oracle`.
    pub kind: &'static str,
    /// What distinguishes the run: the upsampler of a baseline, the axis values of a point.
    pub settings: BTreeMap<String, String>,
}

/// One line of the results.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Row {
    pub id: String,
    pub material: String,
    pub kind: String,
    pub settings: BTreeMap<String, String>,
    /// Wall time of the upscale (not of the evaluation).
    pub seconds: f64,
    /// matup's stages (empty for baselines).
    pub timings: Vec<(String, f64)>,
    /// Training epochs run, over all levels (0 for baselines and untrained runs).
    #[serde(default)]
    pub epochs_trained: f64,
    pub evaluation: Option<EvaluationRow>,
    pub error: Option<String>,
}

/// [`Evaluation`] as stored (deserialisable).
pub type EvaluationRow = BTreeMap<String, f64>;

/// What a finished upscale reports besides its material.
#[derive(Default)]
struct RunFacts {
    seconds: f64,
    timings: Vec<(String, f64)>,
    epochs_trained: f64,
    /// The borders the output was made with, which its false colour is judged with.
    border: Border,
}

/// How a run ended: its facts and evaluation, or its error.
type Outcome = std::result::Result<(RunFacts, Evaluation), String>;

impl Row {
    /// The row of `run`: its time, stage timings and evaluation, or its error.
    fn new(run: &Run, outcome: Outcome) -> Row {
        let (facts, evaluation, error) = match outcome {
            Ok((facts, ev)) => (facts, Some(evaluation_row(&ev)), None),
            Err(e) => (RunFacts::default(), None, Some(e)),
        };
        Row {
            id: run.id.clone(),
            material: run.input_name(),
            kind: run.kind.into(),
            settings: run.settings.clone(),
            seconds: facts.seconds,
            timings: facts.timings,
            epochs_trained: facts.epochs_trained,
            evaluation,
            error,
        }
    }

    /// A metric of the run ([`METRICS`]); NaN when the run failed.
    pub fn metric(&self, name: &str) -> f64 {
        self.evaluation
            .as_ref()
            .and_then(|e| e.get(name))
            .copied()
            .unwrap_or(f64::NAN)
    }
}

impl Experiment {
    /// Reads an experiment file; errors name the file, the line and the key.
    pub fn from_file(path: &Path) -> Result<Experiment> {
        let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
        let mut e: Experiment =
            toml::from_str(&text).map_err(|err| Error::file(path, err.to_string()))?;
        let folder = path.parent().unwrap_or(Path::new("."));
        for m in &mut e.materials {
            if m.is_relative() {
                *m = folder.join(&*m);
            }
        }
        Ok(e)
    }

    /// The matup configurations of the sweep: (axis values, configuration) per point, each
    /// checked, its plugins built once (unknown keys, bad values and plugins that do not load
    /// are errors naming the axis point).
    pub fn points(&self) -> Result<Vec<(BTreeMap<String, String>, Config)>> {
        let points = self.settings()?;
        for (settings, config) in &points {
            check_settings(config).map_err(|e| in_point(settings, e.to_string()))?;
        }
        Ok(points)
    }

    /// [`Experiment::points`] without building their plugins: the settings alone, checked.
    pub fn settings(&self) -> Result<Vec<(BTreeMap<String, String>, Config)>> {
        let axes: Vec<(&String, &Vec<toml::Value>)> = self.axes.iter().collect();
        if let Some((key, _)) = axes.iter().find(|(_, values)| values.is_empty()) {
            return Err(Error::Invalid(format!("axis '{key}' has no values")));
        }
        let combos: Vec<Vec<usize>> = match self.mode {
            AxesMode::Grid => axes.iter().fold(vec![vec![]], |acc, (_, values)| {
                acc.iter()
                    .flat_map(|prefix| {
                        (0..values.len()).map(move |i| {
                            let mut p = prefix.clone();
                            p.push(i);
                            p
                        })
                    })
                    .collect()
            }),
            AxesMode::Zip => {
                let n = axes.first().map_or(1, |(_, v)| v.len());
                if let Some((key, v)) = axes.iter().find(|(_, v)| v.len() != n) {
                    return Err(Error::Invalid(format!(
                        "mode = \"zip\" needs axes of one length: '{key}' has {} values, '{}' has {n}",
                        v.len(),
                        axes[0].0
                    )));
                }
                (0..n).map(|i| vec![i; axes.len()]).collect()
            }
        };
        combos
            .into_iter()
            .map(|combo| {
                let mut table = self.base.clone();
                table.insert("scale".into(), toml::Value::Integer(self.factor as i64));
                let mut settings = BTreeMap::new();
                for ((key, values), &i) in axes.iter().zip(&combo) {
                    set_key(&mut table, key, values[i].clone())?;
                    settings.insert(key.to_string(), value_text(&values[i]));
                }
                let config: Config = toml::Value::Table(table)
                    .try_into()
                    .map_err(|e: toml::de::Error| in_point(&settings, e.message().to_string()))?;
                (config.validate()).map_err(|e| in_point(&settings, e.to_string()))?;
                Ok((settings, config))
            })
            .collect()
    }

    /// The inputs' degradations, each checked: `None` for clean inputs.
    pub fn degradations(&self) -> Result<Vec<Option<MaterialDegradation>>> {
        if self.degrade.is_empty() {
            return Ok(vec![None]);
        }
        (self.degrade.iter())
            .map(|name| match name.as_str() {
                CLEAN => Ok(None),
                _ => name.parse().map(Some),
            })
            .collect()
    }

    /// Every run, materials outermost (each degradation of a material after it): baselines,
    /// then each sweep point (and its oracle).
    pub fn runs(&self) -> Result<Vec<Run>> {
        if self.materials.is_empty() {
            return Err(Error::Invalid("the experiment names no materials".into()));
        }
        check_supported_scale(self.factor, "factor")?;
        shading_model(&self.eval_shading.parse::<PluginSpec>()?)?;
        for b in &self.baselines {
            let up = upsampler(&b.parse::<PluginSpec>()?)?;
            check_scale(b, up.as_ref(), self.factor)?;
        }
        let points = self.points()?;
        if self.oracle {
            if let Some((settings, _)) = points.iter().find(|(_, c)| c.train.epochs == 0) {
                return Err(Error::Invalid(format!(
                    "the oracle measures a trained filter's ceiling, but the point {settings:?} \
                     trains nothing (train.epochs = 0): give epochs, e.g. configs/paper.toml"
                )));
            }
        }
        let degradations = self.degradations()?;
        let mut runs = Vec::new();
        for (material, degrade) in
            (self.materials.iter()).flat_map(|m| degradations.iter().map(move |d| (m, d)))
        {
            let name = input_name(material, degrade.as_ref());
            let run = |kind: &'static str, method: Method, settings: BTreeMap<String, String>| {
                let label = settings
                    .iter()
                    .map(|(k, v)| format!("{k}={v}"))
                    .collect::<Vec<_>>()
                    .join(" ");
                Run {
                    id: format!("{name}/{kind} {label}").trim_end().to_string(),
                    material: material.clone(),
                    degrade: degrade.clone(),
                    method,
                    kind,
                    settings,
                }
            };
            for b in &self.baselines {
                let settings = BTreeMap::from([("upsampler".to_string(), b.clone())]);
                runs.push(run("per-map", Method::PerMap(b.clone()), settings));
            }
            for (settings, config) in &points {
                runs.push(run(
                    "matup",
                    Method::Matup(config.clone()),
                    settings.clone(),
                ));
                if self.oracle {
                    let mut s = settings.clone();
                    s.remove("upsampler");
                    let id = run("oracle", Method::Oracle(config.clone()), s);
                    if !runs.iter().any(|r: &Run| r.id == id.id) {
                        runs.push(id);
                    }
                }
            }
        }
        let mut ids = BTreeSet::new();
        if let Some(r) = runs.iter().find(|r| !ids.insert(r.id.as_str())) {
            return Err(Error::Invalid(format!(
                "two runs would both be called '{}': give materials folders of different names",
                r.id
            )));
        }
        Ok(runs)
    }
}

/// Sets `key` (dotted: `train.epochs`) in a TOML table, creating the tables on the way.
fn set_key(table: &mut toml::Table, key: &str, value: toml::Value) -> Result<()> {
    let mut parts: Vec<&str> = key.split('.').collect();
    let last = parts.pop().expect("split yields one part");
    let mut t = table;
    for p in parts {
        t = t
            .entry(p)
            .or_insert_with(|| toml::Value::Table(toml::Table::new()))
            .as_table_mut()
            .ok_or_else(|| Error::Invalid(format!("axis '{key}': '{p}' is not a table")))?;
    }
    t.insert(last.to_string(), value);
    Ok(())
}

fn value_text(v: &toml::Value) -> String {
    match v {
        toml::Value::String(s) => s.clone(),
        other => other.to_string(),
    }
}

/// A true material and the LR input made from it.
struct Pair {
    truth: Material,
    lr: Material,
}

/// The true material at `path` and its LR input, degraded as `degrade` says (with the same
/// noise every time: a seed of the material's name).
fn make_pair(
    path: &Path,
    degrade: Option<&MaterialDegradation>,
    experiment: &Experiment,
) -> Result<Pair> {
    let mut truth = load_material(Some(path), &LoadOptions::default())?;
    if let Some(c) = experiment.crop {
        let at = experiment.crop_at;
        if at + c > truth.width() || at + c > truth.height_px() {
            return Err(Error::material(
                path,
                format!(
                    "crop {c} at {at} reaches past the material ({}×{})",
                    truth.width(),
                    truth.height_px()
                ),
            ));
        }
        let origin = truth.origin.clone();
        truth = truth.crop(at, at, c, c);
        truth.origin = origin;
    }
    let f = experiment.factor;
    if truth.width() % f != 0 || truth.height_px() % f != 0 {
        return Err(Error::material(
            path,
            format!(
                "{}×{} is not divisible by the factor {f}",
                truth.width(),
                truth.height_px()
            ),
        ));
    }
    let seed = (material_name(path).bytes()).fold(0u64, |h, b| h.wrapping_mul(31) ^ b as u64);
    let lr = degraded_input(&truth, f, degrade, &mut StdRng::seed_from_u64(seed)).map_err(|e| {
        let d = degrade.map(|d| d.to_string()).unwrap_or_default();
        Error::material(path, format!("degraded as '{d}': {e}"))
    })?;
    Ok(Pair { truth, lr })
}

/// An error `e` of the sweep point of these axis values.
fn in_point(settings: &BTreeMap<String, String>, e: String) -> Error {
    let point = (settings.iter())
        .map(|(k, v)| format!("{k} = {v}"))
        .collect::<Vec<_>>()
        .join(", ");
    Error::Invalid(format!("sweep point [{point}]: {e}"))
}

/// Runs `runs` (skipping those `out/results.jsonl` already holds without error) and returns
/// every row, old and new. A run that fails is recorded with its error and the others go on;
/// Ctrl-C stops after the current run's last checkpoint.
pub fn run_experiment(
    experiment: &Experiment,
    runs: &[Run],
    out: &Path,
    progress: &dyn Progress,
) -> Result<Vec<Row>> {
    // Checked before anything runs: a sweep of absent materials would record every run
    // as failed.
    let missing: Vec<String> = (experiment.materials.iter())
        .filter(|m| !m.is_dir())
        .map(|m| m.display().to_string())
        .collect();
    if !missing.is_empty() {
        return Err(Error::Invalid(format!(
            "{} of the experiment's {} material folders are missing: {}; put each true \
                 material's folder of maps at its path (relative to the experiment file)",
            missing.len(),
            experiment.materials.len(),
            missing.join(", ")
        )));
    }
    std::fs::create_dir_all(out).map_err(|e| Error::io(out, e))?;
    let journal = out.join("results.jsonl");
    let mut rows: Vec<Row> = read_journal(&journal)?
        .into_iter()
        .filter(|r| r.error.is_none() && runs.iter().any(|run| run.id == r.id))
        .collect();
    let done: BTreeSet<String> = rows.iter().map(|r| r.id.clone()).collect();
    if !done.is_empty() {
        progress.note(&format!(
            "{} of {} runs already finished in {}; skipping them",
            done.len(),
            runs.len(),
            journal.display()
        ));
    }
    let eval_model = shading_model(&experiment.eval_shading.parse::<PluginSpec>()?)?;
    let eval_lights = LightSetSpec::held_out(experiment.eval_lights);
    let mut pair: Option<(String, Result<Pair>)> = None;
    for (i, run) in runs.iter().enumerate() {
        if done.contains(&run.id) {
            continue;
        }
        if progress.cancelled() {
            return Err(Error::Cancelled { epochs_done: 0 });
        }
        progress.note(&format!("[{}/{}] {}", i + 1, runs.len(), run.id));
        if pair.as_ref().is_none_or(|(p, _)| *p != run.input_name()) {
            let made = make_pair(&run.material, run.degrade.as_ref(), experiment);
            pair = Some((run.input_name(), made));
        }
        let outcome = match &pair.as_ref().expect("set above").1 {
            Err(e) => Err(e.to_string()),
            Ok(p) => {
                let checkpoints = out.join(".checkpoints").join(format!("run{i}"));
                match run_one(run, p, experiment.factor, &checkpoints, progress) {
                    Err(Error::Cancelled { epochs_done }) => {
                        return Err(Error::Cancelled { epochs_done })
                    }
                    Err(e) => Err(e.to_string()),
                    Ok((material, facts)) => {
                        let _ = std::fs::remove_dir_all(&checkpoints);
                        if experiment.view {
                            keep_output(out, run, "", &material)?;
                            keep_output(out, run, "truth", &p.truth)?;
                        }
                        evaluate(
                            &p.truth,
                            &material,
                            experiment.factor,
                            eval_model.as_ref(),
                            &eval_lights,
                        )
                        .and_then(|mut ev| {
                            ev.false_colour = Some(false_colour(
                                &p.lr.base_color,
                                &material.base_color,
                                Some(&p.truth.base_color),
                                facts.border,
                            )?);
                            ev.new_structure =
                                new_structure(&p.lr, &material, Some(&p.truth), facts.border)?;
                            ev.new_structure_worst = Some(worst_new_structure(&ev.new_structure));
                            ev.invented_structure_worst =
                                Some(worst_invented_structure(&ev.new_structure));
                            Ok((facts, ev))
                        })
                        .map_err(|e| e.to_string())
                    }
                }
            }
        };
        let row = Row::new(run, outcome);
        progress.note(&match &row.error {
            None => format!(
                "  {:.1} s, render PSNR {:.2} dB, SSIM {:.4}, FLIP {:.4}",
                row.seconds,
                row.metric("render_psnr"),
                row.metric("render_ssim"),
                row.metric("render_flip")
            ),
            Some(e) => format!("  failed: {e}"),
        });
        append_journal(&journal, &row)?;
        rows.push(row);
        write_tables(out, &rows)?;
    }
    write_tables(out, &rows)?;
    if experiment.view {
        write_views(out)?;
    }
    Ok(rows)
}

/// Where [`Experiment::view`] keeps a material's outputs.
fn outputs_folder(out: &Path, run: &Run) -> PathBuf {
    out.join("outputs").join(run.input_name())
}

/// Saves `material` as `name` (the run's method and settings when empty) under the run's
/// material, in matup's DirectX normal convention, which [`write_views`] reads back.
fn keep_output(out: &Path, run: &Run, name: &str, material: &Material) -> Result<()> {
    let name = if name.is_empty() {
        let label = run.id.split_once('/').map_or(run.id.as_str(), |(_, m)| m);
        // A folder name: the label's letters, digits and `.-_`, everything else `_`.
        label
            .chars()
            .map(|c| {
                if c.is_alphanumeric() || "-_.".contains(c) {
                    c
                } else {
                    '_'
                }
            })
            .collect()
    } else {
        name.to_string()
    };
    let folder = outputs_folder(out, run).join(&name);
    if name == "truth" && folder.is_dir() {
        return Ok(()); // kept with the material's first run
    }
    let save = SaveOptions {
        format: Some(FileFormat::Png8),
        normal_convention: Some(NormalConvention::DirectX),
        names: Names::Matup,
        ..SaveOptions::default()
    };
    let mut material = material.clone();
    material.origin = None; // its own files, not the input's formats
    save_material(&material, &folder, &save).map(|_| ())
}

/// `outputs/MATERIAL/view.html` for every material kept: the first matup run against every
/// other run and the truth.
fn write_views(out: &Path) -> Result<()> {
    let outputs = out.join("outputs");
    if !outputs.is_dir() {
        return Ok(());
    }
    let load = LoadOptions {
        normal_convention: Some(NormalConvention::DirectX),
        ..Default::default()
    };
    let mut links = String::new();
    for folder in subfolders(&outputs)? {
        let material = material_name(&folder);
        let mut runs: Vec<(String, Material)> = Vec::new();
        for path in subfolders(&folder)? {
            runs.push((material_name(&path), load_material(Some(&path), &load)?));
        }
        // Shown on the right: the first matup run; the truth first in the menu.
        let Some(main) = runs
            .iter()
            .position(|(n, _)| n.starts_with("matup"))
            .or((runs.len() > 1).then_some(0))
        else {
            continue;
        };
        let (main_name, main) = runs.remove(main);
        runs.sort_by_key(|(n, _)| n != "truth");
        let title = format!("matup bench: {material}");
        links.push_str(&format!(
            "<li><a href=\"{}\">{}</a></li>\n",
            escape(&href(&material, "view.html")),
            escape(&material)
        ));
        write_view(
            &folder,
            (&main_name, &main),
            &runs,
            &Config::default(),
            None,
            &title,
        )?;
    }
    // The materials' pages, one link each.
    let index = format!(
        "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\"><title>matup bench</title></head>\n<body><h1>matup bench: relight each material</h1>\n<ul>\n{links}</ul>\n</body></html>\n"
    );
    write_atomic(&outputs.join("index.html"), index.as_bytes())
}

/// The folders in `folder`, in name order.
fn subfolders(folder: &Path) -> Result<Vec<PathBuf>> {
    let mut found: Vec<PathBuf> = std::fs::read_dir(folder)
        .map_err(|e| Error::io(folder, e))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.is_dir())
        .collect();
    found.sort();
    Ok(found)
}

/// A material's name in run ids and tables: its folder's name.
impl Run {
    /// The input's name: the material's folder name, `+DEGRADATION` where it is degraded.
    pub fn input_name(&self) -> String {
        input_name(&self.material, self.degrade.as_ref())
    }
}

fn input_name(material: &Path, degrade: Option<&MaterialDegradation>) -> String {
    match degrade {
        Some(d) => format!("{}+{d}", material_name(material)),
        None => material_name(material),
    }
}

fn material_name(path: &Path) -> String {
    path.file_name().map_or_else(
        || path.display().to_string(),
        |n| n.to_string_lossy().into_owned(),
    )
}

type Upscaled = (Material, RunFacts);

fn run_one(
    run: &Run,
    pair: &Pair,
    factor: usize,
    checkpoints: &Path,
    progress: &dyn Progress,
) -> Result<Upscaled> {
    let start = Instant::now();
    match &run.method {
        Method::PerMap(spec) => {
            let up = upsampler(&spec.parse::<PluginSpec>()?)?;
            let border = Border::for_tiling(detect_tileable(&pair.lr).0);
            let m = upscale_per_map(&pair.lr, up.as_ref(), factor, border)?;
            let facts = RunFacts {
                seconds: start.elapsed().as_secs_f64(),
                border,
                ..RunFacts::default()
            };
            Ok((m, facts))
        }
        Method::Matup(config) | Method::Oracle(config) => {
            let options = RunOptions {
                checkpoint_folder: Some(checkpoints.to_path_buf()),
                resume: true,
                oracle: matches!(run.method, Method::Oracle(_)).then(|| pair.truth.clone()),
                memory_limit: None,
            };
            let (m, report) = upscale(&pair.lr, config, &options, progress)?;
            let facts = RunFacts {
                seconds: start.elapsed().as_secs_f64(),
                epochs_trained: report
                    .levels
                    .iter()
                    .map(|l| l.training.epochs_trained)
                    .sum(),
                timings: report.timings,
                border: Border::for_tiling(report.tileable),
            };
            Ok((m, facts))
        }
    }
}

fn evaluation_row(e: &Evaluation) -> EvaluationRow {
    match serde_json::to_value(e).expect("an Evaluation serialises") {
        serde_json::Value::Object(map) => map
            .into_iter()
            .filter_map(|(k, v)| v.as_f64().map(|v| (k, v)))
            .collect(),
        _ => unreachable!("a struct serialises to an object"),
    }
}

/// The rows of a journal; a line cut short by an interruption is ignored.
pub fn read_journal(path: &Path) -> Result<Vec<Row>> {
    match std::fs::read_to_string(path) {
        Ok(text) => Ok(text
            .lines()
            .filter_map(|l| serde_json::from_str(l).ok())
            .collect()),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(Vec::new()),
        Err(e) => Err(Error::io(path, e)),
    }
}

fn append_journal(path: &Path, row: &Row) -> Result<()> {
    use std::io::Write;
    let mut f = std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(path)
        .map_err(|e| Error::io(path, e))?;
    let line = serde_json::to_string(row).expect("a Row serialises") + "\n";
    f.write_all(line.as_bytes())
        .and_then(|_| f.sync_data())
        .map_err(|e| Error::io(path, e))
}

/// The metric columns, in table order.
pub const METRICS: [&str; 15] = [
    "render_psnr",
    "render_ssim",
    "render_flip",
    "render_sharpness",
    "reference_render_sharpness",
    "base_color_rmse",
    "normal_error_degrees",
    "roughness_rmse",
    "metallic_rmse",
    "false_colour_texels",
    "new_structure_worst",
    "invented_structure_worst",
    "seam_ratio",
    "reference_seam_ratio",
    "lights",
];

/// `results.json` (every row) and `results.csv` (one column per setting and metric).
pub fn write_tables(out: &Path, rows: &[Row]) -> Result<()> {
    let json = serde_json::to_vec_pretty(rows).expect("rows serialise");
    write_atomic(&out.join("results.json"), &json)?;
    let setting_keys: BTreeSet<&String> = rows.iter().flat_map(|r| r.settings.keys()).collect();
    let mut csv = csv::Writer::from_writer(Vec::new());
    let mut header: Vec<String> = vec!["id".into(), "material".into(), "kind".into()];
    header.extend(setting_keys.iter().map(|k| k.to_string()));
    header.push("seconds".into());
    header.push("epochs_trained".into());
    header.extend(METRICS.iter().map(|m| m.to_string()));
    header.push("error".into());
    let csv_error = |e: csv::Error| Error::Invalid(format!("results.csv: {e}"));
    csv.write_record(&header).map_err(csv_error)?;
    for r in rows {
        let mut record = vec![r.id.clone(), r.material.clone(), r.kind.clone()];
        record.extend(
            setting_keys
                .iter()
                .map(|k| r.settings.get(*k).cloned().unwrap_or_default()),
        );
        record.push(format!("{:.3}", r.seconds));
        record.push(format!("{:.2}", r.epochs_trained));
        record.extend(METRICS.iter().map(|m| {
            r.evaluation
                .as_ref()
                .and_then(|e| e.get(*m))
                .map_or(String::new(), |v| format!("{v:.6}"))
        }));
        record.push(r.error.clone().unwrap_or_default());
        csv.write_record(&record).map_err(csv_error)?;
    }
    let bytes = csv
        .into_inner()
        .map_err(|e| Error::Invalid(format!("results.csv: {e}")))?;
    write_atomic(&out.join("results.csv"), &bytes)
}
