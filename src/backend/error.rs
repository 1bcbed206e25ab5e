//! Errors of the GPU backend (converted into `crate::Error` with `#[from]`).

/// What to do when no adapter is found.
pub const NO_ADAPTER_HINT: &str = "install a Vulkan driver, e.g. `apt-get install mesa-vulkan-drivers` for the lavapipe software device";

/// Errors of the GPU backend.
#[derive(Debug, thiserror::Error)]
pub enum GpuError {
    /// No wgpu adapter (GPU or software device) could be found.
    #[error("no GPU adapter found; {hint}")]
    NoAdapter {
        /// How to get one.
        hint: String,
    },
    /// f64 shaders were requested but no adapter supports `wgpu::Features::SHADER_F64`.
    #[error("GPU adapter `{adapter}` does not support 64-bit floats in shaders (wgpu::Features::SHADER_F64)")]
    NoF64 {
        /// The best adapter found (name and backend).
        adapter: String,
    },
    /// `Adapter::request_device` failed.
    #[error("requesting a device from GPU adapter `{adapter}` failed: {message}")]
    RequestDevice {
        /// Adapter name and backend.
        adapter: String,
        /// wgpu's message.
        message: String,
    },
    /// A WGSL module failed to parse or validate (naga), or wgpu rejected the shader module or
    /// the compute pipeline.
    #[error("shader `{label}` failed to compile:\n{message}")]
    Shader {
        /// Shader label (file name or kernel name).
        label: String,
        /// naga's annotated message or wgpu's validation message.
        message: String,
    },
    /// Another wgpu validation error (bind groups, dispatch sizes, submission), or a resource
    /// limit other than a buffer size.
    #[error("GPU validation error in `{label}`: {message}")]
    Validation {
        /// What was being done.
        label: String,
        /// wgpu's message.
        message: String,
    },
    /// A chain too long for one invocation per member on a driver that bounds the loop iterations
    /// of an invocation (llvmpipe/lavapipe).
    #[error("N = {particles} particles is too long for one shader invocation per member on {adapter}: this scheme needs {iterations} loop iterations per invocation and the driver stops after {limit}; use N <= {max_particles} on this device, the CPU backend (--backend cpu), or a hardware GPU")]
    LoopLimit {
        adapter: String,
        particles: usize,
        iterations: u64,
        limit: u64,
        max_particles: u64,
    },
    /// A buffer exceeds a device limit.
    #[error("{what} needs {bytes} bytes, more than the device limit {limit_name} = {limit} bytes")]
    BufferTooLarge {
        /// Which buffer.
        what: String,
        /// Requested size in bytes.
        bytes: u64,
        /// The limit in bytes.
        limit: u64,
        /// Name of the `wgpu::Limits` field.
        limit_name: String,
    },
    /// Mapping a buffer for reading back failed (or waiting for the device did).
    #[error("reading back a GPU buffer failed: {message}")]
    Map {
        /// wgpu's message.
        message: String,
    },
}

impl GpuError {
    /// [`GpuError::NoAdapter`] with the standard install hint.
    pub fn no_adapter() -> Self {
        GpuError::NoAdapter {
            hint: NO_ADAPTER_HINT.to_string(),
        }
    }
}
