//! `matup._matup`: the Python package's native module, a thin edge over matup's libraries as
//! the CLI is. Python's `matup/__init__.py` gives it its friendly signatures; here each call
//! takes paths, JSON and NumPy arrays, releases the GIL while Rust works, and turns matup's
//! errors into Python exceptions. Reports cross as JSON text (`json.loads` on the Python side),
//! so every field of run.json reaches Python without a second description of it.

mod network;
mod progress;
mod settings;

use std::panic::{catch_unwind, AssertUnwindSafe};
use std::path::{Path, PathBuf};

use numpy::{PyArray1, PyArrayMethods, PyReadonlyArrayDyn, PyUntypedArrayMethods};
use pyo3::prelude::*;
use pyo3::types::PyAnyMethods;

use matup::apps::folder::{upscale_in_memory, upscale_to_folder, FolderRun};
use matup::apps::model::upscale_model as run_model;
use matup::core::io::{
    load_material_from_images, read_image as read_image_file, write_image as write_image_file,
    ImageFile, Samples, StoredImage,
};
use matup::core::material::{Material, SampleDepth};
use matup::core::{
    load_material, shading_model, shading_models, upsamplers, Error, FileFormat, LightSetSpec,
    LoadOptions, Map, NormalConvention, PluginSpec, SaveOptions,
};
use matup::eval::metrics::evaluate as evaluate_materials;
use matup::method::bands::default_memory_limit;
use matup::method::Config;

use network::{Network, RunNetworks};
use progress::{PyProgress, Raised};

// matup's own allocations through mimalloc, as in the CLI (matup-cli/src/lib.rs says why:
// training's buffers and the per-map path's output-sized maps, page-faulted anew under
// glibc's malloc). Python's objects keep Python's allocator.
#[global_allocator]
static ALLOCATOR: mimalloc::MiMalloc = mimalloc::MiMalloc;

/// mimalloc's `purge_delay` option (mimalloc.h, v3): freed memory is kept a second before it
/// goes back to the system, unless `MIMALLOC_PURGE_DELAY` says otherwise, as the CLI sets it.
const MI_OPTION_PURGE_DELAY: libmimalloc_sys::mi_option_t = 15;

fn keep_freed_memory_a_while() {
    if std::env::var_os("MIMALLOC_PURGE_DELAY").is_none() {
        // SAFETY: sets one of mimalloc's integer options, which it reads at its next purge.
        unsafe { libmimalloc_sys::mi_option_set(MI_OPTION_PURGE_DELAY, 1000) };
    }
}

/// What the Python side asked to stop, or raised in a callback: the first such exception
/// wins over the error the run then returns, so the caller sees its own traceback.
fn finish<T>(
    py: Python<'_>,
    raised: &Raised,
    result: std::thread::Result<matup::core::Result<T>>,
) -> PyResult<T> {
    if let Some(e) = raised.lock().unwrap_or_else(|p| p.into_inner()).take() {
        return Err(e);
    }
    match result {
        Ok(Ok(value)) => Ok(value),
        Ok(Err(e)) => Err(to_python(py, &e)),
        Err(panic) => {
            let what = (panic.downcast_ref::<String>().cloned())
                .or_else(|| panic.downcast_ref::<&str>().map(|s| s.to_string()))
                .unwrap_or_else(|| "no message".into());
            Err(exception(
                py,
                "MatupError",
                format!("matup failed inside ({what}); please report it with the input"),
            ))
        }
    }
}

/// Runs `work` with the GIL released, a panic caught rather than crossing into Python.
fn detached<T: Send>(
    py: Python<'_>,
    raised: &Raised,
    work: impl FnOnce() -> matup::core::Result<T> + Send,
) -> PyResult<T> {
    let result = py.detach(|| catch_unwind(AssertUnwindSafe(work)));
    finish(py, raised, result)
}

/// One of `matup.errors`' classes, carrying `message`.
fn exception(py: Python<'_>, class: &str, message: String) -> PyErr {
    let made = (py.import("matup.errors"))
        .and_then(|m| m.getattr(class))
        .and_then(|c| c.call1((message.clone(),)));
    match made {
        Ok(e) => PyErr::from_value(e),
        Err(e) => e,
    }
}

/// matup's error as the exception Python users expect: `FileError` (an `OSError`) for what is
/// wrong with a file or folder, `InvalidInput` (a `ValueError`) for settings and values,
/// `KeyboardInterrupt` for a run asked to stop, `MatupError` otherwise. The message is the
/// CLI's.
fn to_python(py: Python<'_>, e: &Error) -> PyErr {
    let class = match e {
        Error::File { .. } | Error::Io { .. } | Error::Material { .. } => "FileError",
        Error::Invalid(_)
        | Error::Unsupported { .. }
        | Error::UnknownPlugin { .. }
        | Error::DuplicatePlugin { .. } => "InvalidInput",
        Error::Interrupted | Error::Cancelled { .. } => {
            return pyo3::exceptions::PyKeyboardInterrupt::new_err(e.to_string())
        }
        _ => "MatupError",
    };
    exception(py, class, e.to_string())
}

fn parsed<T: std::str::FromStr>(
    py: Python<'_>,
    what: &str,
    text: Option<&str>,
) -> PyResult<Option<T>>
where
    T::Err: std::fmt::Display,
{
    text.map(|t| {
        t.parse::<T>()
            .map_err(|e| exception(py, "InvalidInput", format!("{what} '{t}': {e}")))
    })
    .transpose()
}

fn json_text(py: Python<'_>, value: &impl serde::Serialize) -> PyResult<String> {
    serde_json::to_string(value).map_err(|e| exception(py, "MatupError", e.to_string()))
}

/// How the run's files are written.
fn save_options(
    py: Python<'_>,
    format: Option<&str>,
    names: Option<&str>,
    block_quality: Option<&str>,
) -> PyResult<SaveOptions> {
    Ok(SaveOptions {
        format: parsed(py, "format", format)?,
        normal_convention: None,
        names: parsed(py, "names", names)?.unwrap_or_default(),
        block_quality: parsed(py, "block_quality", block_quality)?.unwrap_or_default(),
    })
}

fn load_options(py: Python<'_>, normal_convention: Option<&str>) -> PyResult<LoadOptions> {
    Ok(LoadOptions {
        normal_convention: parsed::<NormalConvention>(py, "normal_convention", normal_convention)?,
        ..LoadOptions::default()
    })
}

/// What each upscale call sets up before it runs: its progress (and what Python raises
/// meanwhile), its settings with the Python networks registered for its length, and its
/// memory limit.
struct Setup {
    progress: PyProgress,
    raised: Raised,
    config: Config,
    limit: u64,
    /// Registered while the run lives.
    _networks: RunNetworks,
}

impl Setup {
    fn new(
        py: Python<'_>,
        settings: &str,
        network: Option<&Network>,
        networks: Vec<(String, PyRef<'_, Network>)>,
        progress: Option<Py<PyAny>>,
        memory_limit: Option<u64>,
    ) -> PyResult<Setup> {
        let progress = PyProgress::new(progress);
        let raised = progress.raised();
        let networks = RunNetworks::register(py, network, networks, &raised)?;
        let config = settings::config(py, settings, &networks)?;
        Ok(Setup {
            progress,
            raised,
            config,
            limit: memory_limit.unwrap_or_else(default_memory_limit),
            _networks: networks,
        })
    }
}

/// Upscales the material in `src` into `out`, as `matup upscale SRC -o OUT` does; returns
/// run.json's text.
#[pyfunction]
#[pyo3(signature = (src, out, settings, network=None, networks=Vec::new(), format=None, names=None, block_quality=None,
                    normal_convention=None, memory_limit=None, resume=false, progress=None))]
#[allow(clippy::too_many_arguments)]
fn upscale_folder(
    py: Python<'_>,
    src: PathBuf,
    out: PathBuf,
    settings: &str,
    network: Option<&Network>,
    networks: Vec<(String, PyRef<'_, Network>)>,
    format: Option<&str>,
    names: Option<&str>,
    block_quality: Option<&str>,
    normal_convention: Option<&str>,
    memory_limit: Option<u64>,
    resume: bool,
    progress: Option<Py<PyAny>>,
) -> PyResult<String> {
    let save = save_options(py, format, names, block_quality)?;
    let load = load_options(py, normal_convention)?;
    let run = Setup::new(py, settings, network, networks, progress, memory_limit)?;
    let report = detached(py, &run.raised, || {
        let material = load_material(Some(&src), &load)?;
        let FolderRun { report, .. } = upscale_to_folder(
            &material,
            &run.config,
            &out,
            &save,
            resume,
            Some(run.limit),
            None,
            &run.progress,
        )?;
        Ok(report)
    })?;
    json_text(py, &report)
}

/// Images given as `(file name, array, format)`, as matup's reader would decode those files.
fn images_of(py: Python<'_>, images: Vec<StoredArray<'_>>) -> PyResult<Vec<(String, ImageFile)>> {
    (images.into_iter())
        .map(|(name, array, format)| {
            let (map, depth) = map_of(py, &array)?;
            let format = parsed::<FileFormat>(py, "format", Some(&format))?.expect("given");
            if format.sample_depth() != depth {
                return Err(exception(
                    py,
                    "InvalidInput",
                    format!(
                        "{name}: {depth:?} samples for a {format} file, which stores {:?}",
                        format.sample_depth()
                    ),
                ));
            }
            let notes = Vec::new();
            Ok((name, ImageFile { map, format, notes }))
        })
        .collect()
}

/// An image as its file stores it: `(file name, H×W×C array, format)`.
fn stored_array<'py>(py: Python<'py>, image: StoredImage) -> PyResult<StoredArray<'py>> {
    let shape = [image.height, image.width, image.channels];
    let array = match image.samples {
        Samples::U8(v) => PyArray1::from_vec(py, v).reshape(shape)?.into_any(),
        Samples::U16(v) => PyArray1::from_vec(py, v).reshape(shape)?.into_any(),
        Samples::F32(v) => PyArray1::from_vec(py, v).reshape(shape)?.into_any(),
    };
    Ok((image.name, array, image.format.to_string()))
}

/// Upscales the material that files named and stored as `images` (`(file name, array,
/// format)`) would be, in memory, as `matup upscale` upscales their folder: returns run.json's
/// text (without a preview or files) and each output file as `(name, array, format)`, its
/// samples as the file stores them.
#[pyfunction]
#[pyo3(signature = (images, settings, network=None, networks=Vec::new(), format=None, names=None,
                    normal_convention=None, memory_limit=None, progress=None))]
#[allow(clippy::too_many_arguments)]
fn upscale_images<'py>(
    py: Python<'py>,
    images: Vec<StoredArray<'py>>,
    settings: &str,
    network: Option<&Network>,
    networks: Vec<(String, PyRef<'_, Network>)>,
    format: Option<&str>,
    names: Option<&str>,
    normal_convention: Option<&str>,
    memory_limit: Option<u64>,
    progress: Option<Py<PyAny>>,
) -> PyResult<(String, Vec<StoredArray<'py>>)> {
    let save = save_options(py, format, names, None)?;
    let load = load_options(py, normal_convention)?;
    let images = images_of(py, images)?;
    let run = Setup::new(py, settings, network, networks, progress, memory_limit)?;
    let made = detached(py, &run.raised, || {
        let material = load_material_from_images(Path::new(ARRAYS), images, &load)?;
        upscale_in_memory(
            &material,
            &run.config,
            &save,
            Some(run.limit),
            &run.progress,
        )
    })?;
    let images = (made.images.into_iter())
        .map(|image| stored_array(py, image))
        .collect::<PyResult<_>>()?;
    Ok((json_text(py, &made.report)?, images))
}

/// What names the material of arrays in messages: the folder their files would be in.
const ARRAYS: &str = "arrays";

/// Upscales every texture of the glTF model `path` into `out`, as `matup upscale MODEL -o OUT`
/// does; returns each material's report by label, and the notes, as JSON.
#[pyfunction]
#[pyo3(signature = (path, out, settings, network=None, networks=Vec::new(), format=None, names=None, block_quality=None,
                    memory_limit=None, progress=None))]
#[allow(clippy::too_many_arguments)]
fn upscale_model(
    py: Python<'_>,
    path: PathBuf,
    out: PathBuf,
    settings: &str,
    network: Option<&Network>,
    networks: Vec<(String, PyRef<'_, Network>)>,
    format: Option<&str>,
    names: Option<&str>,
    block_quality: Option<&str>,
    memory_limit: Option<u64>,
    progress: Option<Py<PyAny>>,
) -> PyResult<String> {
    let save = save_options(py, format, names, block_quality)?;
    let run = Setup::new(py, settings, network, networks, progress, memory_limit)?;
    let made = detached(py, &run.raised, || {
        run_model(
            &path,
            &run.config,
            &out,
            &save,
            &LoadOptions::default(),
            Some(run.limit),
            &run.progress,
        )
    })?;
    let reports: serde_json::Map<String, serde_json::Value> = (made.runs.iter())
        .map(|(label, report)| {
            (
                label.clone(),
                serde_json::to_value(report).unwrap_or_default(),
            )
        })
        .collect();
    json_text(
        py,
        &serde_json::json!({
            "materials": reports,
            "notes": made.notes,
            "written": made.written,
        }),
    )
}

/// The settings' TOML: matup's defaults, `settings` (JSON) over them; what a run would use.
#[pyfunction]
fn settings_toml(py: Python<'_>, settings: &str) -> PyResult<String> {
    Ok(settings::config(py, settings, &RunNetworks::default())?.to_toml())
}

/// An image file's samples as stored: an H×W×C array of uint8, uint16 or float32, and the
/// file's format.
#[pyfunction]
fn read_image<'py>(py: Python<'py>, path: PathBuf) -> PyResult<(Bound<'py, PyAny>, String)> {
    let raised = Raised::default();
    let file = detached(py, &raised, || {
        read_image_file(&path, LoadOptions::default().max_texels)
    })?;
    let (map, format) = (file.map, file.format);
    let shape = [map.height(), map.width(), map.channels()];
    let interleaved = interleave(&map);
    let array = match format.sample_depth() {
        SampleDepth::U8 => {
            let v: Vec<u8> = interleaved
                .iter()
                .map(|&x| (x * 255.0).round() as u8)
                .collect();
            PyArray1::from_vec(py, v).reshape(shape)?.into_any()
        }
        SampleDepth::U16 => {
            let v: Vec<u16> = (interleaved.iter())
                .map(|&x| (x * 65535.0).round() as u16)
                .collect();
            PyArray1::from_vec(py, v).reshape(shape)?.into_any()
        }
        SampleDepth::F32 => PyArray1::from_vec(py, interleaved)
            .reshape(shape)?
            .into_any(),
    };
    Ok((array, format.to_string()))
}

/// Writes an H×W×C array (C 1 to 4; uint8, uint16 or float32, as the format stores them) to
/// `path`, atomically, in `format` (default: PNG, 16-bit for uint16, EXR float for float32).
#[pyfunction]
#[pyo3(signature = (path, array, format=None))]
fn write_image(
    py: Python<'_>,
    path: PathBuf,
    array: &Bound<'_, PyAny>,
    format: Option<&str>,
) -> PyResult<()> {
    let (map, depth) = map_of(py, array)?;
    let format = match parsed::<FileFormat>(py, "format", format)? {
        Some(f) => f,
        None => match depth {
            SampleDepth::U8 => FileFormat::Png8,
            SampleDepth::U16 => FileFormat::Png16,
            SampleDepth::F32 => FileFormat::ExrFloat,
        },
    };
    let raised = Raised::default();
    detached(py, &raised, || write_image_file(&path, &map, format))
}

/// The file extension `format` writes (`png`, `exr`, `dds`, ...).
#[pyfunction]
fn extension_of(py: Python<'_>, format: &str) -> PyResult<&'static str> {
    Ok(parsed::<FileFormat>(py, "format", Some(format))?
        .expect("given")
        .extension())
}

/// An H×W or H×W×C array as a map: integers scaled to [0, 1], floats as they are.
fn map_of(py: Python<'_>, array: &Bound<'_, PyAny>) -> PyResult<(Map, SampleDepth)> {
    let bad = |m: String| exception(py, "InvalidInput", m);
    let (shape, values, depth) = if let Ok(a) = array.extract::<PyReadonlyArrayDyn<u8>>() {
        let v = a.as_array().iter().map(|&x| x as f32 / 255.0).collect();
        (a.shape().to_vec(), v, SampleDepth::U8)
    } else if let Ok(a) = array.extract::<PyReadonlyArrayDyn<u16>>() {
        let v = a.as_array().iter().map(|&x| x as f32 / 65535.0).collect();
        (a.shape().to_vec(), v, SampleDepth::U16)
    } else if let Ok(a) = array.extract::<PyReadonlyArrayDyn<f32>>() {
        let v: Vec<f32> = a.as_array().iter().copied().collect();
        if v.iter().any(|x| !x.is_finite()) {
            return Err(bad("the array holds NaN or infinity".into()));
        }
        (a.shape().to_vec(), v, SampleDepth::F32)
    } else {
        let dtype = (array.getattr("dtype").map(|d| d.to_string())).unwrap_or("no dtype".into());
        return Err(bad(format!(
            "a NumPy array of uint8, uint16 or float32 is wanted, not {dtype}"
        )));
    };
    let (h, w, c) = match shape[..] {
        [h, w] => (h, w, 1),
        [h, w, c] if (1..=4).contains(&c) => (h, w, c),
        _ => {
            return Err(bad(format!(
                "shape {shape:?}: want H×W or H×W×C with C from 1 to 4"
            )))
        }
    };
    if h == 0 || w == 0 {
        return Err(bad(format!("shape {shape:?} holds no texels")));
    }
    Ok((Map::from_planar(w, h, c, planar(&values, c)), depth))
}

/// A map's samples texel by texel (H×W×C order).
fn interleave(map: &Map) -> Vec<f32> {
    interleaved(map.data(), map.channels())
}

/// `channels` planes, one after another, as samples texel by texel (H×W×C order).
pub(crate) fn interleaved(planes: &[f32], channels: usize) -> Vec<f32> {
    transposed(planes, channels)
}

/// Samples texel by texel (H×W×C order) as `channels` planes, one after another.
pub(crate) fn planar(interleaved: &[f32], channels: usize) -> Vec<f32> {
    transposed(interleaved, interleaved.len() / channels.max(1))
}

/// `data` read as `rows` rows, written column by column: planes and texels are each other's
/// transpose.
fn transposed(data: &[f32], rows: usize) -> Vec<f32> {
    let columns = data.len() / rows.max(1);
    let mut out = vec![0f32; data.len()];
    for (r, row) in data.chunks_exact(columns.max(1)).enumerate() {
        for (c, v) in row.iter().enumerate() {
            out[c * rows + r] = *v;
        }
    }
    out
}

/// Arrays by name, in the order matup holds them.
type NamedArrays<'py> = Vec<(String, Bound<'py, PyAny>)>;

/// An image file's samples held in Python: `(file name, H×W×C array, format)`.
type StoredArray<'py> = (String, Bound<'py, PyAny>, String);

/// A material folder as matup reads it, as JSON: its size, each map in matup's working
/// encoding (linear base colour, unit OpenGL normals, roughness, metallic; as `maps` arrays),
/// the layout it was read from and the normal convention with its evidence.
#[pyfunction]
#[pyo3(signature = (path, normal_convention=None))]
fn read_material<'py>(
    py: Python<'py>,
    path: PathBuf,
    normal_convention: Option<&str>,
) -> PyResult<(String, NamedArrays<'py>)> {
    let load = load_options(py, normal_convention)?;
    let raised = Raised::default();
    let material = detached(py, &raised, || load_material(Some(&path), &load))?;
    described(py, &path, &material)
}

/// [`read_material`] of the files `images` (`(file name, array, format)`) would be.
#[pyfunction]
#[pyo3(signature = (images, normal_convention=None))]
fn read_material_images<'py>(
    py: Python<'py>,
    images: Vec<StoredArray<'py>>,
    normal_convention: Option<&str>,
) -> PyResult<(String, NamedArrays<'py>)> {
    let load = load_options(py, normal_convention)?;
    let images = images_of(py, images)?;
    let raised = Raised::default();
    let folder = Path::new(ARRAYS);
    let material = detached(py, &raised, || {
        load_material_from_images(folder, images, &load)
    })?;
    described(py, folder, &material)
}

/// A material as [`read_material`] gives it.
fn described<'py>(
    py: Python<'py>,
    path: &Path,
    material: &Material,
) -> PyResult<(String, NamedArrays<'py>)> {
    let origin = material.origin.as_ref();
    let description = serde_json::json!({
        "folder": path,
        "size": [material.width(), material.height_px()],
        "sources": origin.map(|o| o.sources()).unwrap_or_default(),
        "notes": origin.map(|o| o.notes.clone()).unwrap_or_default(),
        "normal_convention": origin.map(|o| o.normal_convention.to_string()),
        "normal_evidence": origin.map(|o| o.normal_evidence.clone()),
        "stand_ins": material.stand_ins().iter().map(|k| k.to_string()).collect::<Vec<_>>(),
    });
    let mut maps = vec![
        ("base_color".to_string(), &material.base_color),
        ("normal".to_string(), &material.normal),
        ("roughness".to_string(), &material.roughness),
        ("metallic".to_string(), &material.metallic),
    ];
    maps.extend(material.height.iter().map(|m| ("height".to_string(), m)));
    maps.extend((material.carried.extras.iter()).map(|e| (e.name.clone(), &e.map)));
    let arrays = (maps.into_iter())
        .map(|(name, map)| {
            let shape = [map.height(), map.width(), map.channels()];
            let array = PyArray1::from_vec(py, interleave(map)).reshape(shape)?;
            Ok((name, array.into_any()))
        })
        .collect::<PyResult<Vec<_>>>()?;
    Ok((json_text(py, &description)?, arrays))
}

/// `count` held-out lights (the set `matup eval` judges under) and the shading model `shading`
/// names, as `evaluate` and `render` take them.
fn held_out(py: Python<'_>, count: usize, shading: &str) -> PyResult<(LightSetSpec, PluginSpec)> {
    if count == 0 {
        let message = "lights must be at least 1".to_string();
        return Err(exception(py, "InvalidInput", message));
    }
    let spec = parsed(py, "shading", Some(shading))?.expect("given");
    Ok((LightSetSpec::held_out(count), spec))
}

/// Render PSNR, FLIP and the per-map errors of the material in `candidate` against the one in
/// `reference` under `lights` held-out lights, as `matup eval` measures them (JSON).
#[pyfunction]
#[pyo3(signature = (reference, candidate, scale=1, lights=16, shading="ggx"))]
fn evaluate(
    py: Python<'_>,
    reference: PathBuf,
    candidate: PathBuf,
    scale: usize,
    lights: usize,
    shading: &str,
) -> PyResult<String> {
    let (lights, spec) = held_out(py, lights, shading)?;
    let raised = Raised::default();
    let evaluation = detached(py, &raised, || {
        let load = |p: &Path| load_material(Some(p), &LoadOptions::default());
        let (reference, candidate) = (load(&reference)?, load(&candidate)?);
        let model = shading_model(&spec)?;
        evaluate_materials(
            &reference,
            &candidate,
            scale.max(1),
            model.as_ref(),
            &lights,
        )
    })?;
    json_text(py, &evaluation)
}

/// The material in `path` rendered under `lights` held-out lights: an N×H×W×3 float32 array
/// of linear radiance.
#[pyfunction]
#[pyo3(signature = (path, lights=16, shading="ggx"))]
fn render<'py>(
    py: Python<'py>,
    path: PathBuf,
    lights: usize,
    shading: &str,
) -> PyResult<Bound<'py, PyAny>> {
    let (lights, spec) = held_out(py, lights, shading)?;
    let raised = Raised::default();
    let renders = detached(py, &raised, || {
        let material = load_material(Some(&path), &LoadOptions::default())?;
        let model = shading_model(&spec)?;
        let set = lights.build();
        Ok(matup::core::render(
            &material,
            model.as_ref(),
            &set,
            Default::default(),
        ))
    })?;
    let (h, w) = (renders[0].height(), renders[0].width());
    let all: Vec<f32> = renders.iter().flat_map(interleave).collect();
    Ok(PyArray1::from_vec(py, all)
        .reshape([renders.len(), h, w, 3])?
        .into_any())
}

/// The registered upsamplers and shading models, with their options, and the ONNX models
/// found (JSON).
#[pyfunction]
fn plugins(py: Python<'_>) -> PyResult<String> {
    let options = |o: &[matup::core::PluginOption]| -> Vec<serde_json::Value> {
        (o.iter())
            .map(|o| serde_json::json!({"key": o.key, "default": o.default, "help": o.help}))
            .collect()
    };
    let up = upsamplers().map_err(|e| to_python(py, &e))?;
    let shading = shading_models().map_err(|e| to_python(py, &e))?;
    let models: Vec<serde_json::Value> = (matup::upsamplers::onnx::available_models().into_iter())
        .map(|(name, source, info)| {
            serde_json::json!({"name": name, "scale": info.scale, "source": source.to_string(),
                               "description": info.description, "licence": info.licence})
        })
        .collect();
    json_text(
        py,
        &serde_json::json!({
            "upsamplers": up.iter().map(|r| serde_json::json!({
                "name": r.name, "description": r.description, "options": options(r.options)
            })).collect::<Vec<_>>(),
            "shading_models": shading.iter().map(|r| serde_json::json!({
                "name": r.name, "description": r.description, "options": options(r.options)
            })).collect::<Vec<_>>(),
            "models": models,
        }),
    )
}

#[pymodule]
fn _matup(m: &Bound<'_, PyModule>) -> PyResult<()> {
    keep_freed_memory_a_while();
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    m.add_class::<Network>()?;
    for f in [
        wrap_pyfunction!(upscale_folder, m)?,
        wrap_pyfunction!(upscale_images, m)?,
        wrap_pyfunction!(upscale_model, m)?,
        wrap_pyfunction!(settings_toml, m)?,
        wrap_pyfunction!(read_image, m)?,
        wrap_pyfunction!(write_image, m)?,
        wrap_pyfunction!(extension_of, m)?,
        wrap_pyfunction!(read_material, m)?,
        wrap_pyfunction!(read_material_images, m)?,
        wrap_pyfunction!(evaluate, m)?,
        wrap_pyfunction!(render, m)?,
        wrap_pyfunction!(plugins, m)?,
    ] {
        m.add_function(f)?;
    }
    Ok(())
}
