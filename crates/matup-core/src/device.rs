//! Where tensors compute: the candle device a spec names (`cpu`, `cuda`, `cuda:N`), one
//! per GPU for the process.

use candle_core::Device;

use crate::{Error, Result};

/// The CUDA device a device spec names: `None` for `cpu`, `Some(N)` for `cuda` (N = 0) or
/// `cuda:N`.
pub fn cuda_ordinal(spec: &str) -> Result<Option<usize>> {
    match spec {
        "cpu" => Ok(None),
        "cuda" => Ok(Some(0)),
        _ => spec
            .strip_prefix("cuda:")
            .and_then(|n| n.parse::<usize>().ok())
            .map(Some)
            .ok_or_else(|| {
                Error::Invalid(format!("unknown device '{spec}'; use cpu, cuda or cuda:N"))
            }),
    }
}

/// A candle device from `cpu`, `cuda` or `cuda:N`.
pub fn parse_device(spec: &str) -> Result<Device> {
    let Some(ordinal) = cuda_ordinal(spec)? else {
        return Ok(Device::Cpu);
    };
    if !candle_core::utils::cuda_is_available() {
        return Err(Error::Invalid(format!(
            "device '{spec}': this build has no CUDA support; build with --features cuda (see docs/cuda.md)"
        )));
    }
    // One device per GPU for the process: each candle device loads its kernels anew, and a
    // batch of materials asks for the device once a material.
    static DEVICES: std::sync::Mutex<Vec<(usize, Device)>> = std::sync::Mutex::new(Vec::new());
    let mut devices = DEVICES.lock().unwrap_or_else(|e| e.into_inner());
    if let Some((_, device)) = devices.iter().find(|(o, _)| *o == ordinal) {
        return Ok(device.clone());
    }
    let device =
        Device::new_cuda(ordinal).map_err(|e| Error::Invalid(format!("device '{spec}': {e}")))?;
    devices.push((ordinal, device.clone()));
    Ok(device)
}
