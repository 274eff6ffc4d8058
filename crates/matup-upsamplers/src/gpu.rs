//! GPUs through wgpu (Vulkan, Metal, DirectX 12): the adapters this machine offers, and the
//! one a device spec picks ([`matup_core::device::GpuPick`]). Each adapter is opened once a
//! process and shared by every network that runs on it.

use std::sync::{Arc, Mutex, OnceLock};

use matup_core::device::GpuPick;
use matup_core::{Error, Result};

/// What kind of adapter it is, as its driver says.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum AdapterKind {
    Discrete,
    Integrated,
    Virtual,
    /// A software rasteriser on the CPU (llvmpipe, lavapipe, WARP): right, but slow.
    Software,
    Other,
}

impl AdapterKind {
    fn of(device_type: wgpu::DeviceType) -> AdapterKind {
        match device_type {
            wgpu::DeviceType::DiscreteGpu => AdapterKind::Discrete,
            wgpu::DeviceType::IntegratedGpu => AdapterKind::Integrated,
            wgpu::DeviceType::VirtualGpu => AdapterKind::Virtual,
            wgpu::DeviceType::Cpu => AdapterKind::Software,
            wgpu::DeviceType::Other => AdapterKind::Other,
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            AdapterKind::Discrete => "discrete GPU",
            AdapterKind::Integrated => "integrated GPU",
            AdapterKind::Virtual => "virtual GPU",
            AdapterKind::Software => "software adapter",
            AdapterKind::Other => "adapter",
        }
    }

    /// The order `auto` tries kinds in; software adapters are never tried.
    fn auto_rank(self) -> Option<u8> {
        match self {
            AdapterKind::Discrete => Some(0),
            AdapterKind::Integrated => Some(1),
            AdapterKind::Virtual | AdapterKind::Other => Some(2),
            AdapterKind::Software => None,
        }
    }
}

/// An adapter as `matup list` shows it and `gpu:N` counts it.
#[derive(Clone, Debug)]
pub struct AdapterSummary {
    /// Its place in [`adapters`] (`gpu:N`).
    pub index: usize,
    /// Its name, as the driver gives it.
    pub name: String,
    pub kind: AdapterKind,
    /// Vulkan, Metal or DirectX 12.
    pub backend: String,
    /// Whether its shaders compute in half precision (`shader-f16`).
    pub shader_f16: bool,
}

impl std::fmt::Display for AdapterSummary {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "gpu:{}  {} ({}, {}{})",
            self.index,
            self.name,
            self.backend,
            self.kind.name(),
            if self.shader_f16 { ", shader-f16" } else { "" }
        )
    }
}

/// An opened adapter: its device and queue, and what it is.
pub struct Gpu {
    pub summary: AdapterSummary,
    pub device: wgpu::Device,
    pub queue: wgpu::Queue,
    pub limits: wgpu::Limits,
}

impl std::fmt::Debug for Gpu {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "Gpu({})", self.summary)
    }
}

/// The process's wgpu instance and its adapters, found once.
fn found() -> &'static (wgpu::Instance, Vec<wgpu::Adapter>) {
    static FOUND: OnceLock<(wgpu::Instance, Vec<wgpu::Adapter>)> = OnceLock::new();
    FOUND.get_or_init(|| {
        let mut descriptor = wgpu::InstanceDescriptor::new_without_display_handle();
        descriptor.backends = BACKENDS;
        // No validation layers, whatever the build: they slow every call and are not shipped.
        descriptor.flags = wgpu::InstanceFlags::empty();
        let instance = wgpu::Instance::new(descriptor);
        let adapters = pollster::block_on(instance.enumerate_adapters(BACKENDS));
        (instance, adapters)
    })
}

/// Vulkan, Metal and DirectX 12: the backends with compute shaders on every vendor's GPUs.
const BACKENDS: wgpu::Backends = wgpu::Backends::VULKAN
    .union(wgpu::Backends::METAL)
    .union(wgpu::Backends::DX12);

fn summary(index: usize, adapter: &wgpu::Adapter) -> AdapterSummary {
    let info = adapter.get_info();
    AdapterSummary {
        index,
        name: info.name,
        kind: AdapterKind::of(info.device_type),
        backend: format!("{:?}", info.backend),
        shader_f16: adapter.features().contains(wgpu::Features::SHADER_F16),
    }
}

/// The adapters this machine offers through Vulkan, Metal and DirectX 12, in wgpu's order.
pub fn adapters() -> Vec<AdapterSummary> {
    (found().1.iter().enumerate())
        .map(|(i, a)| summary(i, a))
        .collect()
}

/// The adapter `pick` names: the first (`gpu`), the N-th (`gpu:N`), or the first whose name
/// holds the given part, ignoring case (`gpu:llvmpipe`).
pub fn find(pick: &GpuPick) -> Result<AdapterSummary> {
    let all = adapters();
    let listed = || {
        if all.is_empty() {
            "this machine offers no Vulkan, Metal or DirectX 12 adapter".to_string()
        } else {
            let names: Vec<String> = all.iter().map(|a| a.to_string()).collect();
            format!("its adapters: {}", names.join("; "))
        }
    };
    let found = match pick {
        GpuPick::First => all.first(),
        GpuPick::Index(i) => all.get(*i),
        GpuPick::Name(part) => {
            let part = part.to_lowercase();
            all.iter().find(|a| a.name.to_lowercase().contains(&part))
        }
    };
    found.cloned().ok_or_else(|| {
        Error::Invalid(format!(
            "device '{}': no such GPU adapter ({})",
            pick.spec(),
            listed()
        ))
    })
}

/// The adapter `auto` runs on: the first discrete GPU, else integrated, else any other
/// hardware one; never a software adapter.
pub fn auto_adapter() -> Option<AdapterSummary> {
    let all = adapters();
    (all.iter())
        .filter_map(|a| a.kind.auto_rank().map(|rank| (rank, a)))
        .min_by_key(|(rank, a)| (*rank, a.index))
        .map(|(_, a)| a.clone())
}

/// The adapter `index` opened (once a process), with every limit and feature of its own
/// that the engine uses.
pub fn open(index: usize) -> Result<Arc<Gpu>> {
    static OPENED: Mutex<Vec<Arc<Gpu>>> = Mutex::new(Vec::new());
    let mut opened = OPENED.lock().unwrap_or_else(|e| e.into_inner());
    if let Some(gpu) = opened.iter().find(|g| g.summary.index == index) {
        return Ok(gpu.clone());
    }
    let adapter = found()
        .1
        .get(index)
        .ok_or_else(|| Error::Invalid(format!("device 'gpu:{index}': no such GPU adapter")))?;
    let summary = summary(index, adapter);
    let limits = adapter.limits();
    let features = adapter.features() & wgpu::Features::SHADER_F16;
    let descriptor = wgpu::DeviceDescriptor {
        label: Some("matup"),
        required_features: features,
        required_limits: limits.clone(),
        experimental_features: wgpu::ExperimentalFeatures::disabled(),
        memory_hints: wgpu::MemoryHints::Performance,
        trace: wgpu::Trace::Off,
    };
    let (device, queue) = pollster::block_on(adapter.request_device(&descriptor))
        .map_err(|e| Error::Invalid(format!("GPU adapter '{}': {e}", summary.name)))?;
    let gpu = Arc::new(Gpu {
        summary,
        device,
        queue,
        limits,
    });
    opened.push(gpu.clone());
    Ok(gpu)
}

/// The adapter matup's tests run the GPU engine on: the first whose name holds
/// `$MATUP_TEST_GPU` (default `llvmpipe`, Mesa's software Vulkan, which needs no GPU). Where
/// there is none the tests say so and pass, unless `MATUP_REQUIRE_GPU` is set (CI sets it):
/// then this panics.
pub fn test_adapter() -> Option<AdapterSummary> {
    let name = std::env::var("MATUP_TEST_GPU").unwrap_or_else(|_| "llvmpipe".into());
    let found = find(&GpuPick::Name(name.clone())).ok();
    if found.is_none() {
        assert!(
            std::env::var_os("MATUP_REQUIRE_GPU").is_none(),
            "MATUP_REQUIRE_GPU is set but no adapter named '{name}' was found \
             (install Debian's mesa-vulkan-drivers)"
        );
        eprintln!("no GPU adapter named '{name}': the GPU engine's checks are skipped");
    }
    found
}
