//! Where a run computes. A device spec names it: `auto` (the default), `cpu`, `cuda[:N]`, or a
//! GPU through wgpu, `gpu` (the first adapter), `gpu:N` or `gpu:NAME`. The SR networks run on
//! the device; training (candle) runs on CUDA where the spec resolves to it, else on the CPU.
//! This module parses the spec and resolves its CUDA part; the wgpu adapters are
//! matup-upsamplers' (`gpu`).

use candle_core::Device;

use crate::{Error, Result};

/// A device spec, parsed.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum DeviceSpec {
    /// The CUDA device in a CUDA build where one opens, else the first hardware wgpu adapter
    /// (discrete before integrated), else the CPU.
    Auto,
    Cpu,
    Cuda(usize),
    /// A wgpu adapter; the rest of the run is on the CPU.
    Gpu(GpuPick),
}

/// Which wgpu adapter a `gpu` spec names.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum GpuPick {
    /// `gpu`: the first adapter, a software one included.
    First,
    /// `gpu:N`: the N-th, as `matup list` numbers them.
    Index(usize),
    /// `gpu:NAME`: the first whose name holds NAME, ignoring case (`gpu:llvmpipe`).
    Name(String),
}

impl GpuPick {
    /// The spec that names it.
    pub fn spec(&self) -> String {
        match self {
            GpuPick::First => "gpu".into(),
            GpuPick::Index(i) => format!("gpu:{i}"),
            GpuPick::Name(n) => format!("gpu:{n}"),
        }
    }
}

impl DeviceSpec {
    pub fn parse(spec: &str) -> Result<DeviceSpec> {
        let unknown = || {
            Error::Invalid(format!(
                "unknown device '{spec}'; use auto, cpu, gpu, gpu:N, gpu:NAME, cuda or cuda:N"
            ))
        };
        Ok(match spec {
            "auto" => DeviceSpec::Auto,
            "cpu" => DeviceSpec::Cpu,
            "cuda" => DeviceSpec::Cuda(0),
            "gpu" => DeviceSpec::Gpu(GpuPick::First),
            _ => {
                if let Some(n) = spec.strip_prefix("cuda:") {
                    DeviceSpec::Cuda(n.parse().map_err(|_| unknown())?)
                } else if let Some(pick) = spec.strip_prefix("gpu:").filter(|p| !p.is_empty()) {
                    match pick.parse() {
                        Ok(i) => DeviceSpec::Gpu(GpuPick::Index(i)),
                        Err(_) => DeviceSpec::Gpu(GpuPick::Name(pick.to_string())),
                    }
                } else {
                    return Err(unknown());
                }
            }
        })
    }
}

/// The CUDA device a device spec resolves to: `Some(N)` for `cuda`/`cuda:N`, and for `auto`
/// in a CUDA build where device 0 opens; `None` for everything that runs on the CPU or a
/// wgpu adapter.
pub fn cuda_ordinal(spec: &str) -> Result<Option<usize>> {
    Ok(match DeviceSpec::parse(spec)? {
        DeviceSpec::Cuda(n) => Some(n),
        DeviceSpec::Auto => auto_cuda(),
        DeviceSpec::Cpu | DeviceSpec::Gpu(_) => None,
    })
}

/// CUDA device 0 where this build has CUDA and it opens.
fn auto_cuda() -> Option<usize> {
    (candle_core::utils::cuda_is_available() && cuda_device(0).is_ok()).then_some(0)
}

/// The candle device a spec resolves to: CUDA ([`cuda_ordinal`]), else the CPU.
pub fn parse_device(spec: &str) -> Result<Device> {
    match cuda_ordinal(spec)? {
        None => Ok(Device::Cpu),
        Some(ordinal) => {
            cuda_device(ordinal).map_err(|e| Error::Invalid(format!("device '{spec}': {e}")))
        }
    }
}

/// CUDA device `ordinal`, opened once a process: each candle device loads its kernels anew,
/// and a batch of materials asks for the device once a material.
fn cuda_device(ordinal: usize) -> std::result::Result<Device, String> {
    if !candle_core::utils::cuda_is_available() {
        return Err(
            "this build has no CUDA support; build with --features cuda (see docs/cuda.md)".into(),
        );
    }
    static DEVICES: std::sync::Mutex<Vec<(usize, Device)>> = std::sync::Mutex::new(Vec::new());
    let mut devices = DEVICES.lock().unwrap_or_else(|e| e.into_inner());
    if let Some((_, device)) = devices.iter().find(|(o, _)| *o == ordinal) {
        return Ok(device.clone());
    }
    let device = Device::new_cuda(ordinal).map_err(|e| e.to_string())?;
    devices.push((ordinal, device.clone()));
    Ok(device)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn device_specs_parse_and_resolve_their_cuda_part() {
        let gpu = |p| DeviceSpec::Gpu(p);
        for (spec, want) in [
            ("auto", DeviceSpec::Auto),
            ("cpu", DeviceSpec::Cpu),
            ("cuda", DeviceSpec::Cuda(0)),
            ("cuda:1", DeviceSpec::Cuda(1)),
            ("gpu", gpu(GpuPick::First)),
            ("gpu:2", gpu(GpuPick::Index(2))),
            ("gpu:llvmpipe", gpu(GpuPick::Name("llvmpipe".into()))),
            ("gpu:Radeon RX", gpu(GpuPick::Name("Radeon RX".into()))),
        ] {
            assert_eq!(DeviceSpec::parse(spec).unwrap(), want, "{spec}");
        }
        for bad in ["", "gpu:", "cuda:x", "vulkan", "GPU"] {
            let e = DeviceSpec::parse(bad).unwrap_err().to_string();
            assert!(e.contains("use auto, cpu, gpu"), "{bad}: {e}");
        }
        // Only CUDA specs, and auto in a CUDA build, train on CUDA.
        assert_eq!(cuda_ordinal("gpu:llvmpipe").unwrap(), None);
        assert_eq!(cuda_ordinal("cpu").unwrap(), None);
        assert_eq!(cuda_ordinal("cuda:1").unwrap(), Some(1));
        if !candle_core::utils::cuda_is_available() {
            assert_eq!(cuda_ordinal("auto").unwrap(), None);
            assert!(parse_device("auto").unwrap().is_cpu());
            let e = parse_device("cuda").unwrap_err().to_string();
            assert!(e.contains("no CUDA support"), "{e}");
        }
    }
}
