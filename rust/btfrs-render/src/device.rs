//! The headless wgpu device: a real GPU when there is one, otherwise Mesa's lavapipe.
//!
//! One device is created per process on first use and shared (creating a Vulkan device costs
//! tens of milliseconds; its pipelines are cached on it and go with it). A child forked after
//! the parent opened its device makes its own: the parent's driver threads and state are not
//! the child's (see [`btfrs_core::process`]). `BTFRS_ADAPTER` forces the choice:
//! `gpu` (a hardware adapter or fail), `cpu` (a software adapter such as lavapipe or fail), or any
//! other text, matched case-insensitively against the adapter names; unset or `auto` prefers
//! discrete, then integrated, then virtual GPUs, then CPU adapters.

use btfrs_core::process::{PerProcess, ProcessId};
use btfrs_core::{Error, Result};
use std::sync::{Arc, Mutex, OnceLock};

/// What to install when no adapter is found (Debian and Ubuntu package names).
pub const INSTALL_HINT: &str = "no usable graphics adapter: install a GPU driver with Vulkan support, or Mesa's \
     software rasteriser lavapipe (Debian/Ubuntu: apt-get install mesa-vulkan-drivers)";

/// A device, its queue and what the adapter is.
#[derive(Debug)]
pub struct Gpu {
    /// The device.
    pub device: wgpu::Device,
    /// Its queue.
    pub queue: wgpu::Queue,
    /// Name, backend and type of the adapter.
    pub info: wgpu::AdapterInfo,
    /// The limits the device was created with (the adapter's own, not WebGPU's defaults, so that
    /// large BTFs fit).
    pub limits: wgpu::Limits,
    /// The process that opened the device.
    owner: ProcessId,
    /// Layouts and pipelines made on this device (by `gpu.rs`): they live and die with it.
    pub(crate) pipelines: OnceLock<Mutex<crate::gpu::Pipelines>>,
}

/// How to choose the adapter.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum AdapterChoice {
    /// The best hardware adapter, else a software one.
    Auto,
    /// Hardware only.
    Gpu,
    /// Software only (lavapipe, WARP, ...).
    Cpu,
    /// The first adapter whose name contains this text (case-insensitive).
    Named(String),
}

impl AdapterChoice {
    /// Read `BTFRS_ADAPTER`.
    pub fn from_env() -> Self {
        match std::env::var("BTFRS_ADAPTER").map(|s| s.trim().to_lowercase()) {
            Ok(s) if s.is_empty() || s == "auto" => AdapterChoice::Auto,
            Ok(s) if s == "gpu" => AdapterChoice::Gpu,
            Ok(s) if s == "cpu" => AdapterChoice::Cpu,
            Ok(s) => AdapterChoice::Named(s),
            Err(_) => AdapterChoice::Auto,
        }
    }
}

fn rank(t: wgpu::DeviceType) -> u8 {
    match t {
        wgpu::DeviceType::DiscreteGpu => 0,
        wgpu::DeviceType::IntegratedGpu => 1,
        wgpu::DeviceType::VirtualGpu => 2,
        wgpu::DeviceType::Cpu => 3,
        wgpu::DeviceType::Other => 4,
    }
}

impl Gpu {
    /// Create a device on the adapter `choice` selects.
    pub fn new(choice: &AdapterChoice) -> Result<Gpu> {
        let mut desc = wgpu::InstanceDescriptor::new_without_display_handle();
        desc.backends = wgpu::Backends::PRIMARY;
        let instance = wgpu::Instance::new(desc);
        let mut adapters = pollster::block_on(instance.enumerate_adapters(wgpu::Backends::PRIMARY));
        adapters.sort_by_key(|a| rank(a.get_info().device_type));
        let names: Vec<String> = adapters.iter().map(|a| a.get_info().name).collect();
        let is_cpu = |a: &wgpu::Adapter| a.get_info().device_type == wgpu::DeviceType::Cpu;
        let adapter = match choice {
            AdapterChoice::Auto => adapters.into_iter().next(),
            AdapterChoice::Gpu => adapters.into_iter().find(|a| !is_cpu(a)),
            AdapterChoice::Cpu => adapters.into_iter().find(is_cpu),
            AdapterChoice::Named(n) => adapters.into_iter().find(|a| a.get_info().name.to_lowercase().contains(n)),
        }
        .ok_or_else(|| {
            if names.is_empty() {
                Error::Device(INSTALL_HINT.to_string())
            } else {
                Error::Device(format!(
                    "BTFRS_ADAPTER={choice:?} matches none of the adapters found: {}",
                    names.join(", ")
                ))
            }
        })?;
        let info = adapter.get_info();
        let limits = adapter.limits();
        let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
            label: Some("btfrs"),
            required_features: wgpu::Features::empty(),
            required_limits: limits.clone(),
            ..Default::default()
        }))
        .map_err(|e| Error::Device(format!("could not open {}: {e}", info.name)))?;
        Ok(Gpu { device, queue, info, limits, owner: ProcessId::current(), pipelines: OnceLock::new() })
    }

    /// This process's device, created on its first use with [`AdapterChoice::from_env`] (and
    /// again in a forked child). A failure is remembered too: the adapters do not change.
    pub fn shared() -> Result<Arc<Gpu>> {
        static GPU: PerProcess<std::result::Result<Arc<Gpu>, String>> = PerProcess::new();
        GPU.get_or_init(|| Gpu::new(&AdapterChoice::from_env()).map(Arc::new).map_err(|e| e.to_string()))
            .clone()
            .map_err(Error::Device)
    }

    /// An error unless this device was opened by the calling process: a device (and everything
    /// made on it) inherited through `fork` belongs to the parent's driver state, and using it
    /// in the child hangs or corrupts the parent's work.
    pub fn check_process(&self) -> Result<()> {
        if self.owner.is_current() {
            Ok(())
        } else {
            Err(Error::Device(format!(
                "this {} device (or a model uploaded to it) was opened by the parent of this forked process; \
                 upload the model again in this process",
                self.info.name
            )))
        }
    }

    /// "name (backend, type)" for reports.
    pub fn describe(&self) -> String {
        format!("{} ({:?}, {:?})", self.info.name, self.info.backend, self.info.device_type)
    }

    /// Run `f`, turning any validation or out-of-memory error it raises on the device into an
    /// [`Error::Device`] instead of wgpu's default (a panic on an uncaptured error).
    pub fn checked<T>(&self, what: &str, f: impl FnOnce() -> T) -> Result<T> {
        let oom = self.device.push_error_scope(wgpu::ErrorFilter::OutOfMemory);
        let val = self.device.push_error_scope(wgpu::ErrorFilter::Validation);
        let out = f();
        let v = pollster::block_on(val.pop());
        let o = pollster::block_on(oom.pop());
        match (v, o) {
            (None, None) => Ok(out),
            (Some(e), _) | (None, Some(e)) => Err(Error::Device(format!("{what}: {e}"))),
        }
    }
}
