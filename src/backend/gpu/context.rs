//! Acquiring a wgpu device (with f64 shaders where the adapter has them), building compute
//! pipelines and reading buffers back.
//!
//! A [`GpuContext`] holds the instance, adapter, device and queue, so that one device serves
//! every kernel.
//!
//! Errors never panic: wgpu reports validation errors through a panicking default handler unless
//! they are caught, so every device operation here runs inside error scopes
//! ([`GpuContext::scoped`]) and the device's uncaptured-error handler only records messages
//! ([`GpuContext::take_uncaptured_errors`]). WGSL is validated with naga before it reaches wgpu,
//! which gives readable, source-annotated messages ([`validate_wgsl`]).

use std::sync::{mpsc, Arc, Mutex};

use crate::backend::error::GpuError;

/// Description of a wgpu adapter (or of the CPU, described the same way), for logs and result
/// files.
#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct AdapterDescription {
    /// Adapter name, e.g. "llvmpipe (LLVM 15.0.7, 256 bits)".
    pub name: String,
    /// Backend, e.g. "Vulkan".
    pub backend: String,
    /// Driver name, e.g. "llvmpipe".
    pub driver: String,
    /// Driver version information.
    pub driver_info: String,
    /// "DiscreteGpu", "IntegratedGpu", "VirtualGpu", "Cpu" or "Other".
    pub device_type: String,
    /// Whether the adapter supports `wgpu::Features::SHADER_F64`.
    pub supports_f64: bool,
}

impl AdapterDescription {
    /// Describes `adapter`.
    pub fn of(adapter: &wgpu::Adapter) -> Self {
        let info = adapter.get_info();
        AdapterDescription {
            name: info.name,
            backend: format!("{:?}", info.backend),
            driver: info.driver,
            driver_info: info.driver_info,
            device_type: format!("{:?}", info.device_type),
            supports_f64: adapter.features().contains(wgpu::Features::SHADER_F64),
        }
    }

    /// "name (backend)", used in error messages.
    pub fn short(&self) -> String {
        format!("{} ({})", self.name, self.backend)
    }
}

impl std::fmt::Display for AdapterDescription {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{} [{}, {}, driver {} {}, f64: {}]",
            self.name,
            self.backend,
            self.device_type,
            self.driver,
            self.driver_info,
            if self.supports_f64 { "yes" } else { "no" }
        )
    }
}

/// Environment variable that turns off Mesa's Vulkan device-selection layer.
pub const NO_DEVICE_SELECT: &str = "NODEVICE_SELECT";

/// Turns off Mesa's implicit Vulkan device-selection layer for this process, unless the user
/// configured it (`NODEVICE_SELECT` or `MESA_VK_DEVICE_SELECT` set). That layer connects to a
/// Wayland display to find the desktop's default GPU, which prints "error: XDG_RUNTIME_DIR is
/// invalid or not set" on every headless machine; roughlub ranks adapters itself
/// (`WGPU_ADAPTER_NAME` restricts the choice), so the layer adds nothing.
///
/// # Safety
/// Changes the process environment: call it before any other thread starts (first thing in
/// `main`), as [`std::env::set_var`] requires.
pub unsafe fn quiet_mesa_device_select() {
    if std::env::var_os(NO_DEVICE_SELECT).is_none()
        && std::env::var_os("MESA_VK_DEVICE_SELECT").is_none()
    {
        std::env::set_var(NO_DEVICE_SELECT, "1");
    }
}

/// New instance; backends, flags and options may be chosen through the usual wgpu environment
/// variables (`WGPU_BACKEND`, `WGPU_VALIDATION`, ...). Without `WGPU_BACKEND`, only the primary
/// backends (Vulkan, Metal, DX12) are used: GL has no f64 shaders, and probing it through EGL
/// prints noise on headless machines.
fn new_instance() -> wgpu::Instance {
    let mut desc = wgpu::InstanceDescriptor::new_without_display_handle_from_env();
    if wgpu::Backends::from_env().is_none() {
        desc.backends = wgpu::Backends::PRIMARY;
    }
    wgpu::Instance::new(desc)
}

/// Describes every adapter wgpu can see (empty when there is none).
pub fn describe_adapters() -> Vec<AdapterDescription> {
    let instance = new_instance();
    pollster::block_on(instance.enumerate_adapters(wgpu::Backends::all()))
        .iter()
        .map(AdapterDescription::of)
        .collect()
}

/// Preference order among adapters: real GPUs first, then software; Vulkan/Metal/DX12 before GL.
fn adapter_rank(adapter: &wgpu::Adapter) -> (u8, u8) {
    let info = adapter.get_info();
    let device = match info.device_type {
        wgpu::DeviceType::DiscreteGpu => 0,
        wgpu::DeviceType::IntegratedGpu => 1,
        wgpu::DeviceType::VirtualGpu => 2,
        wgpu::DeviceType::Cpu => 3,
        wgpu::DeviceType::Other => 4,
    };
    let backend = match info.backend {
        wgpu::Backend::Vulkan | wgpu::Backend::Metal | wgpu::Backend::Dx12 => 0,
        _ => 1,
    };
    (device, backend)
}

/// A wgpu device ready for compute work.
#[derive(Debug)]
pub struct GpuContext {
    /// The wgpu instance.
    pub instance: wgpu::Instance,
    /// The chosen adapter.
    pub adapter: wgpu::Adapter,
    /// The device.
    pub device: wgpu::Device,
    /// Its queue.
    pub queue: wgpu::Queue,
    /// Description of the adapter.
    pub description: AdapterDescription,
    /// Whether `wgpu::Features::SHADER_F64` is enabled on the device.
    pub f64: bool,
    /// The limits the device was created with.
    pub limits: wgpu::Limits,
    /// Errors that happened outside any error scope (see [`GpuContext::take_uncaptured_errors`]).
    uncaptured: Arc<Mutex<Vec<String>>>,
}

impl GpuContext {
    /// Picks an adapter and creates a device.
    ///
    /// Adapters are ranked discrete > integrated > virtual > CPU (software, e.g. lavapipe)
    /// ([`GpuContext::acquire_among`] restricts the choice by name). With `want_f64`, only
    /// adapters with `SHADER_F64` are eligible, and [`GpuError::NoF64`] names the best adapter
    /// when none has it; without it, `SHADER_F64` is still enabled when the adapter has it (see
    /// [`GpuContext::f64`]).
    ///
    /// The device gets wgpu's default limits, except for the buffer-size, storage-buffer-count
    /// and compute-dispatch limits, which are the adapter's own maxima.
    pub fn acquire(want_f64: bool) -> Result<GpuContext, GpuError> {
        Self::acquire_among(want_f64, None)
    }

    /// [`GpuContext::acquire`] among the adapters whose name contains `adapter_name`
    /// (case-insensitive; `WGPU_ADAPTER_NAME`, [`Overrides`](crate::backend::overrides::Overrides)).
    pub fn acquire_among(
        want_f64: bool,
        adapter_name: Option<&str>,
    ) -> Result<GpuContext, GpuError> {
        pollster::block_on(Self::acquire_async(want_f64, adapter_name))
    }

    /// Async version of [`GpuContext::acquire_among`].
    pub async fn acquire_async(
        want_f64: bool,
        adapter_name: Option<&str>,
    ) -> Result<GpuContext, GpuError> {
        let instance = new_instance();
        let mut adapters = instance.enumerate_adapters(wgpu::Backends::all()).await;
        if let Some(wanted) = adapter_name {
            let wanted = wanted.to_lowercase();
            adapters.retain(|a| a.get_info().name.to_lowercase().contains(&wanted));
        }
        adapters.sort_by_key(adapter_rank);
        let Some(best) = adapters.first() else {
            return Err(GpuError::no_adapter());
        };
        let best_description = AdapterDescription::of(best);
        let adapter = if want_f64 {
            match adapters
                .into_iter()
                .find(|a| a.features().contains(wgpu::Features::SHADER_F64))
            {
                Some(a) => a,
                None => {
                    return Err(GpuError::NoF64 {
                        adapter: best_description.short(),
                    })
                }
            }
        } else {
            adapters.into_iter().next().expect("non-empty")
        };
        let description = AdapterDescription::of(&adapter);
        let f64 = description.supports_f64;

        let adapter_limits = adapter.limits();
        // Defaults clamped to what the adapter has, then the adapter's maxima where size matters.
        let mut limits = wgpu::Limits::default().or_worse_values_from(&adapter_limits);
        limits.max_storage_buffer_binding_size = adapter_limits.max_storage_buffer_binding_size;
        limits.max_buffer_size = adapter_limits.max_buffer_size;
        limits.max_storage_buffers_per_shader_stage =
            adapter_limits.max_storage_buffers_per_shader_stage;
        limits.max_compute_workgroups_per_dimension =
            adapter_limits.max_compute_workgroups_per_dimension;
        limits.max_compute_invocations_per_workgroup =
            adapter_limits.max_compute_invocations_per_workgroup;
        limits.max_compute_workgroup_size_x = adapter_limits.max_compute_workgroup_size_x;
        limits.max_compute_workgroup_size_y = adapter_limits.max_compute_workgroup_size_y;
        limits.max_compute_workgroup_size_z = adapter_limits.max_compute_workgroup_size_z;
        limits.max_compute_workgroup_storage_size =
            adapter_limits.max_compute_workgroup_storage_size;

        let features = if f64 {
            wgpu::Features::SHADER_F64
        } else {
            wgpu::Features::empty()
        };
        let (device, queue) = adapter
            .request_device(&wgpu::DeviceDescriptor {
                label: Some("roughlub"),
                required_features: features,
                required_limits: limits.clone(),
                ..Default::default()
            })
            .await
            .map_err(|e| GpuError::RequestDevice {
                adapter: description.short(),
                message: e.to_string(),
            })?;

        // wgpu's default handler panics; record instead (everything we do runs in error scopes,
        // so this only sees errors of code that does not).
        let uncaptured = Arc::new(Mutex::new(Vec::new()));
        let sink = Arc::clone(&uncaptured);
        device.on_uncaptured_error(Arc::new(move |e: wgpu::Error| {
            let message = e.to_string();
            eprintln!("roughlub: uncaptured wgpu error: {message}");
            if let Ok(mut v) = sink.lock() {
                v.push(message);
            }
        }));

        Ok(GpuContext {
            instance,
            adapter,
            device,
            queue,
            description,
            f64,
            limits,
            uncaptured,
        })
    }

    /// Messages of wgpu errors that happened outside error scopes since the last call.
    pub fn take_uncaptured_errors(&self) -> Vec<String> {
        self.uncaptured
            .lock()
            .map(|mut v| std::mem::take(&mut *v))
            .unwrap_or_default()
    }

    /// Runs `f` inside validation, out-of-memory and internal error scopes and returns its value
    /// with the first error caught (wgpu's message). Error scopes are per thread in wgpu 30, so
    /// only device calls made by `f` on this thread are caught.
    pub fn scoped<T>(&self, f: impl FnOnce() -> T) -> (T, Option<String>) {
        let oom = self.device.push_error_scope(wgpu::ErrorFilter::OutOfMemory);
        let internal = self.device.push_error_scope(wgpu::ErrorFilter::Internal);
        let validation = self.device.push_error_scope(wgpu::ErrorFilter::Validation);
        let value = f();
        // Pop in reverse order of pushing.
        let v = pollster::block_on(validation.pop());
        let i = pollster::block_on(internal.pop());
        let o = pollster::block_on(oom.pop());
        let error = v.or(i).or(o).map(|e| match e {
            wgpu::Error::OutOfMemory { .. } => "out of memory".to_string(),
            other => other.to_string(),
        });
        (value, error)
    }

    /// Validates `wgsl` with naga, then creates the shader module and a compute pipeline for
    /// `entry` with the given bind group layouts (or wgpu's automatic layout when `None`).
    pub fn compute_pipeline(
        &self,
        label: &str,
        wgsl: &str,
        entry: &str,
        layout: Option<&wgpu::PipelineLayout>,
    ) -> Result<wgpu::ComputePipeline, GpuError> {
        validate_wgsl(label, wgsl)?;
        let (pipeline, error) = self.scoped(|| {
            let module = self
                .device
                .create_shader_module(wgpu::ShaderModuleDescriptor {
                    label: Some(label),
                    source: wgpu::ShaderSource::Wgsl(wgsl.into()),
                });
            self.device
                .create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                    label: Some(label),
                    layout,
                    module: &module,
                    entry_point: Some(entry),
                    compilation_options: Default::default(),
                    cache: None,
                })
        });
        match error {
            Some(message) => Err(GpuError::Shader {
                label: label.to_string(),
                message,
            }),
            None => Ok(pipeline),
        }
    }

    /// Checks a storage buffer size against `max_storage_buffer_binding_size` and
    /// `max_buffer_size`.
    pub fn check_storage_size(&self, what: &str, bytes: u64) -> Result<(), GpuError> {
        let checks = [
            (
                self.limits.max_storage_buffer_binding_size,
                "max_storage_buffer_binding_size",
            ),
            (self.limits.max_buffer_size, "max_buffer_size"),
        ];
        for (limit, limit_name) in checks {
            if bytes > limit {
                return Err(GpuError::BufferTooLarge {
                    what: what.to_string(),
                    bytes,
                    limit,
                    limit_name: limit_name.to_string(),
                });
            }
        }
        Ok(())
    }

    /// Copies `bytes` bytes from the start of `buffer` (usage must include `COPY_SRC`) into a
    /// staging buffer, waits for the device and returns them.
    pub fn read_buffer(&self, buffer: &wgpu::Buffer, bytes: u64) -> Result<Vec<u8>, GpuError> {
        let padded = bytes.max(4).next_multiple_of(4);
        let (staging, error) = self.scoped(|| {
            let staging = self.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("roughlub readback"),
                size: padded,
                usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            });
            let mut encoder = self
                .device
                .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                    label: Some("roughlub readback"),
                });
            encoder.copy_buffer_to_buffer(buffer, 0, &staging, 0, padded);
            self.queue.submit([encoder.finish()]);
            staging
        });
        if let Some(message) = error {
            return Err(GpuError::Validation {
                label: "readback".to_string(),
                message,
            });
        }
        map_read(&self.device, &staging, bytes)
    }
}

/// Maps `staging` (usage `MAP_READ`), waits, and copies out its first `bytes` bytes.
fn map_read(
    device: &wgpu::Device,
    staging: &wgpu::Buffer,
    bytes: u64,
) -> Result<Vec<u8>, GpuError> {
    let (sender, receiver) = mpsc::channel();
    staging.map_async(wgpu::MapMode::Read, .., move |result| {
        let _ = sender.send(result);
    });
    device
        .poll(wgpu::PollType::wait_indefinitely())
        .map_err(|e| GpuError::Map {
            message: e.to_string(),
        })?;
    match receiver.recv() {
        Ok(Ok(())) => {}
        Ok(Err(e)) => {
            return Err(GpuError::Map {
                message: e.to_string(),
            })
        }
        Err(_) => {
            return Err(GpuError::Map {
                message: "map_async callback was not called".to_string(),
            })
        }
    }
    let data = {
        let view = staging.get_mapped_range(..).map_err(|e| GpuError::Map {
            message: e.to_string(),
        })?;
        view[..bytes as usize].to_vec()
    };
    staging.unmap();
    Ok(data)
}

/// Parses and validates WGSL with naga (capability `FLOAT64` allowed), returning the module or
/// [`GpuError::Shader`] with naga's source-annotated message. Catches errors before wgpu sees
/// the shader; it does not check that the device supports f64 (see [`GpuContext::f64`]).
pub fn validate_wgsl(label: &str, src: &str) -> Result<naga::Module, GpuError> {
    let module = naga::front::wgsl::parse_str(src).map_err(|e| GpuError::Shader {
        label: label.to_string(),
        message: e.emit_to_string_with_path(src, label),
    })?;
    let mut validator = naga::valid::Validator::new(
        naga::valid::ValidationFlags::all(),
        naga::valid::Capabilities::FLOAT64,
    );
    validator.validate(&module).map_err(|e| GpuError::Shader {
        label: label.to_string(),
        message: e.emit_to_string_with_path(src, label),
    })?;
    Ok(module)
}
