//! The `onnx` upsampler in the registry: its options, and the networks this process has
//! loaded, each loaded once.

use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};

use matup_core::plugin::{option_value, parse_options, PluginOption};
use matup_core::upsample::{RgbUpsampler, UpsamplerRegistration};
use matup_core::{Error, Result};

use super::candle_graph::Precision;
use super::source::{resolve, ModelSource};
use super::upsampler::{EngineChoice, OnnxUpsampler};

const OPTIONS: &[PluginOption] = &[
    PluginOption {
        key: "tile",
        default: "",
        help: "LR texels per tile side (default: the sidecar's)",
    },
    PluginOption {
        key: "overlap",
        default: "",
        help: "LR texels of context around each tile (default: the sidecar's)",
    },
    PluginOption {
        key: "batch",
        default: "",
        help: "tiles per network call (default: the sidecar's; on a GPU, as many as fit)",
    },
    PluginOption {
        key: "threads",
        default: "",
        help: "threads for the network (default: matup's thread count)",
    },
    PluginOption {
        key: "engine",
        default: "auto",
        help: "what runs the network: matup (its own executor), tract, candle (the executor's graph as candle operations), wgpu (its graph as compute shaders on a GPU adapter), or auto (the device's own: wgpu on a gpu device, candle on cuda, else matup where the graph allows)",
    },
    PluginOption {
        key: "device",
        default: "auto",
        help: "where the network runs: auto (CUDA in a CUDA build, else the first hardware GPU adapter, else the CPU), cpu, gpu (the first adapter), gpu:N or gpu:NAME (an adapter matup list shows), or cuda[:N] (a build with --features cuda)",
    },
    PluginOption {
        key: "precision",
        default: "f32",
        help: "what the network computes in: f32; on candle also tf32 (a GPU's tensor cores, f32 values), f16 or bf16 (half-size values, products summed in f32); on a GPU adapter also f16 (maps held in half precision, sums in f32; the adapter needs shader-f16)",
    },
    PluginOption {
        key: "sidecar",
        default: "",
        help: "the model's sidecar TOML (default: NAME.toml beside NAME.onnx)",
    },
];

/// Networks this process has loaded, by their argument and the files they came from: a
/// `matup batch`, sweep or selection loads each once rather than once a material. A load
/// parses the graph, plans the engine (on a GPU: uploads the weights) and probes the scale.
static LOADED: Mutex<Vec<(LoadKey, Arc<OnnxUpsampler>)>> = Mutex::new(Vec::new());

/// What makes two loads the same: the `onnx:` argument, and the length and modification time
/// of the model and sidecar files it reads (so a file rewritten in between is read again).
#[derive(PartialEq)]
struct LoadKey {
    argument: String,
    files: Vec<Option<(u64, std::time::SystemTime)>>,
}

impl LoadKey {
    fn of(argument: &str, source: &ModelSource, sidecar: Option<&Path>) -> LoadKey {
        let stamp = |path: &Path| {
            let meta = std::fs::metadata(path).ok()?;
            Some((meta.len(), meta.modified().ok()?))
        };
        LoadKey {
            argument: argument.to_string(),
            files: source.files(sidecar).iter().map(|f| stamp(f)).collect(),
        }
    }
}

/// `onnx:MODEL[,tile=N,overlap=N,batch=N,threads=N,engine=E,device=D,precision=P,sidecar=PATH]`, MODEL a path to a `.onnx` file or a name in the
/// model folders. Loaded once a process ([`LOADED`]).
fn create(argument: Option<&str>) -> Result<Box<dyn RgbUpsampler>> {
    let argument = argument.unwrap_or("");
    let model = argument.split_once(',').map_or(argument, |(m, _)| m);
    let given_sidecar = parse_options("onnx", argument.split_once(',').map(|(_, o)| o), OPTIONS)
        .ok()
        .map(|v| v["sidecar"].clone())
        .filter(|s| !s.is_empty())
        .map(PathBuf::from);
    let key = match resolve(model) {
        Ok(source) => LoadKey::of(argument, &source, given_sidecar.as_deref()),
        Err(_) => return load(argument).map(|u| Box::new(u) as Box<dyn RgbUpsampler>),
    };
    let mut loaded = LOADED
        .lock()
        .unwrap_or_else(|poisoned| poisoned.into_inner());
    if let Some((_, upsampler)) = loaded.iter().find(|(k, _)| *k == key) {
        return Ok(Box::new(upsampler.clone()));
    }
    let upsampler = Arc::new(load(argument)?);
    loaded.push((key, upsampler.clone()));
    Ok(Box::new(upsampler))
}

/// Loads the network `onnx:ARGUMENT` names, with its options.
fn load(argument: &str) -> Result<OnnxUpsampler> {
    let (model, options) = argument.split_once(',').unwrap_or((argument, ""));
    if model.is_empty() {
        return Err(Error::Plugin {
            plugin: "onnx".into(),
            message: "name a model: onnx:PATH.onnx or onnx:NAME (see matup list)".into(),
        });
    }
    let values = parse_options("onnx", Some(options), OPTIONS)?;
    let device = values["device"].clone();
    let on_gpu = matup_core::device::cuda_ordinal(&device)?.is_some();
    let precision = Precision::parse(&values["precision"]).ok_or_else(|| Error::Plugin {
        plugin: "onnx".into(),
        message: format!(
            "precision '{}': known precisions are {}",
            values["precision"],
            Precision::ALL.map(Precision::name).join(", ")
        ),
    })?;
    // A CPU engine asked for by name runs on the CPU under `auto`; on a named adapter it is
    // refused below.
    let cpu_engine = matches!(values["engine"].as_str(), "matup" | "tract" | "candle");
    let names_adapter = matches!(
        matup_core::device::DeviceSpec::parse(&device)?,
        matup_core::device::DeviceSpec::Gpu(_)
    );
    let on_adapter = if on_gpu || (cpu_engine && !names_adapter) {
        None
    } else {
        adapter_for(&device, precision == Precision::F16)?
    };
    let refused = |message: String| Error::Plugin {
        plugin: "onnx".into(),
        message,
    };
    let choice = match (values["engine"].as_str(), on_adapter) {
        ("auto", _) if on_gpu => EngineChoice::Candle(device.clone(), precision),
        ("candle", None) => EngineChoice::Candle(device.clone(), precision),
        ("auto" | "wgpu", Some(adapter)) => adapter,
        ("wgpu", None) => {
            return Err(refused(format!(
                "engine=wgpu runs on a GPU adapter; device {device} names none \
                 (use device=gpu, gpu:N or gpu:NAME)"
            )))
        }
        ("auto", None) => EngineChoice::Auto,
        ("matup", None) if !on_gpu => EngineChoice::Matup,
        ("tract", None) if !on_gpu => EngineChoice::Tract,
        (engine @ ("matup" | "tract" | "candle"), _) => {
            return Err(refused(format!(
                "engine={engine} does not run on device {device}; leave engine=auto there"
            )))
        }
        (other, _) => {
            return Err(refused(format!(
                "engine '{other}': known engines are auto, matup, tract, candle, wgpu"
            )))
        }
    };
    let half_on_adapter = precision == Precision::F16 && matches!(choice, EngineChoice::Gpu { .. });
    if precision != Precision::F32
        && !matches!(choice, EngineChoice::Candle(..))
        && !half_on_adapter
    {
        return Err(Error::Plugin {
            plugin: "onnx".into(),
            message: format!(
                "precision={} is the candle engine's (engine=candle, or a GPU device); \
                 matup's executor and tract compute in f32",
                precision.name()
            ),
        });
    }
    let sidecar = match values["sidecar"].as_str() {
        "" => None,
        given => Some(PathBuf::from(given)),
    };
    let on_cpu = matches!(choice, EngineChoice::Auto);
    let mut upsampler = OnnxUpsampler::load_source(resolve(model)?, sidecar.as_deref(), choice)?;
    if on_cpu {
        upsampler.why = match device.as_str() {
            "auto" => "device=auto found no hardware GPU adapter (software ones run only when \
                       named: gpu:NAME)"
                .into(),
            other => format!("device={other}"),
        };
    }
    upsampler.batch_given = !values["batch"].is_empty();
    for (key, slot) in [
        ("tile", &mut upsampler.info.tile),
        ("overlap", &mut upsampler.info.overlap),
        ("batch", &mut upsampler.info.batch),
    ] {
        if !values[key].is_empty() {
            *slot = option_value("onnx", &values, key)?;
        }
    }
    if !values["threads"].is_empty() {
        upsampler.set_threads(option_value("onnx", &values, "threads")?)?;
    }
    if upsampler.info.tile == 0 || upsampler.info.batch == 0 {
        return Err(Error::Plugin {
            plugin: "onnx".into(),
            message: "tile and batch must be positive".into(),
        });
    }
    Ok(upsampler)
}

/// The wgpu adapter a device spec runs the network on, and why: the one `gpu`, `gpu:N` or
/// `gpu:NAME` names (an error where there is none), or under `auto` the first hardware one,
/// the CPU taking over where it cannot run the network. `None`: the network runs on the CPU
/// (`cpu`, or `auto` with no hardware adapter; the upsampler says which).
fn adapter_for(device: &str, half: bool) -> Result<Option<EngineChoice>> {
    use matup_core::device::DeviceSpec;
    Ok(match DeviceSpec::parse(device)? {
        DeviceSpec::Gpu(pick) => {
            let adapter = crate::gpu::find(&pick)?;
            Some(EngineChoice::Gpu {
                index: adapter.index,
                or_cpu: false,
                why: format!("device={device} asked for it"),
                half,
            })
        }
        DeviceSpec::Auto => crate::gpu::auto_adapter().map(|adapter| EngineChoice::Gpu {
            index: adapter.index,
            or_cpu: true,
            half,
            why: format!(
                "device=auto took the first hardware adapter ({})",
                adapter.kind.name()
            ),
        }),
        DeviceSpec::Cpu | DeviceSpec::Cuda(_) => None,
    })
}

inventory::submit! {
    UpsamplerRegistration {
        name: "onnx",
        description: "a pre-trained SR network: onnx:PATH.onnx or onnx:NAME from the model folders (on a GPU adapter through wgpu, CUDA, or the CPU: device=)",
        options: OPTIONS,
        create,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::onnx::source::BUILT_IN;
    use matup_core::resample::Border;
    use matup_core::Map;

    /// How many handles (the cache's own among them) hold the network loaded by `argument`.
    fn holders(argument: &str) -> usize {
        let loaded = LOADED.lock().unwrap();
        let found = loaded.iter().find(|(k, _)| k.argument == argument);
        found.map_or(0, |(_, u)| Arc::strong_count(u))
    }

    #[test]
    fn a_network_is_loaded_once_a_process_and_again_when_its_file_changes() {
        let dir = tempfile::tempdir().unwrap();
        let model = dir.path().join("net.onnx");
        let stock = (BUILT_IN.iter())
            .find(|b| b.name == "span_x4_ch48")
            .unwrap();
        std::fs::write(&model, stock.onnx).unwrap();
        std::fs::write(model.with_extension("toml"), stock.sidecar).unwrap();
        let argument = model.display().to_string();
        let first = create(Some(&argument)).unwrap();
        let second = create(Some(&argument)).unwrap();
        // One load, held by the cache and both upsamplers.
        assert_eq!(holders(&argument), 3);
        let image = Map::from_fn(12, 10, 3, |c, y, x| ((x * 5 + y * 3 + c) % 7) as f32 / 6.0);
        let run = |u: &dyn RgbUpsampler| {
            u.upsample(std::slice::from_ref(&image), 4, Border::Mirror)
                .unwrap()
        };
        assert_eq!(run(first.as_ref()), run(second.as_ref()));
        // A sidecar rewritten with another tile is another network: loaded anew.
        let retiled = format!(
            "{}\ntile = 48\n",
            stock.sidecar.replace("tile =", "# tile =")
        );
        std::fs::write(model.with_extension("toml"), retiled).unwrap();
        let third = create(Some(&argument)).unwrap();
        assert_eq!(third.tile(), Some(48));
        assert_ne!(first.tile(), Some(48));
    }
}
