//! GPU test helpers: acquiring an adapter or skipping (or failing under ROUGHLUB_REQUIRE_GPU=1),
//! and running a compute shader once over storage buffers (for the WGSL math and kernel tests).
#![allow(dead_code)]

use roughlub::backend::gpu::GpuContext;
use roughlub::backend::GpuError;
use wgpu::util::DeviceExt;

/// Environment variable: when set to `1`, [`acquire_for_tests`] panics instead of skipping.
pub const REQUIRE_GPU_ENV: &str = "ROUGHLUB_REQUIRE_GPU";

/// Runs a compute shader once over storage buffers of raw bytes.
///
/// Bindings (all in `@group(0)`): `@binding(i)` for `i < inputs.len()` are the inputs, declared
/// `var<storage, read>`; `@binding(inputs.len())` is the output, `var<storage, read_write>`,
/// zero-initialised, `output_bytes` long. Buffers are padded to a multiple of 4 bytes (and at
/// least 4). Dispatches `workgroups` workgroups, waits and returns the output bytes.
pub fn run_compute_raw(
    ctx: &GpuContext,
    label: &str,
    wgsl: &str,
    entry: &str,
    inputs: &[&[u8]],
    output_bytes: u64,
    workgroups: [u32; 3],
) -> Result<Vec<u8>, GpuError> {
    let n_buffers = inputs.len() as u32 + 1;
    if n_buffers > ctx.limits.max_storage_buffers_per_shader_stage {
        return Err(GpuError::Validation {
            label: label.to_string(),
            message: format!(
                "{n_buffers} storage buffers, more than the device limit max_storage_buffers_per_shader_stage = {}",
                ctx.limits.max_storage_buffers_per_shader_stage
            ),
        });
    }
    let max_groups = ctx.limits.max_compute_workgroups_per_dimension;
    if workgroups.iter().any(|&g| g > max_groups) {
        return Err(GpuError::Validation {
            label: label.to_string(),
            message: format!(
                "dispatch of {workgroups:?} workgroups exceeds max_compute_workgroups_per_dimension = {max_groups}"
            ),
        });
    }
    for (i, input) in inputs.iter().enumerate() {
        ctx.check_storage_size(&format!("{label}: input {i}"), input.len() as u64)?;
    }
    ctx.check_storage_size(&format!("{label}: output"), output_bytes)?;

    let storage_entry = |binding: u32, read_only: bool| wgpu::BindGroupLayoutEntry {
        binding,
        visibility: wgpu::ShaderStages::COMPUTE,
        ty: wgpu::BindingType::Buffer {
            ty: wgpu::BufferBindingType::Storage { read_only },
            has_dynamic_offset: false,
            min_binding_size: None,
        },
        count: None,
    };
    let entries: Vec<wgpu::BindGroupLayoutEntry> = (0..n_buffers)
        .map(|b| storage_entry(b, b + 1 < n_buffers))
        .collect();
    let (layouts, error) = ctx.scoped(|| {
        let bgl = ctx
            .device
            .create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
                label: Some(label),
                entries: &entries,
            });
        let pl = ctx
            .device
            .create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
                label: Some(label),
                bind_group_layouts: &[Some(&bgl)],
                immediate_size: 0,
            });
        (bgl, pl)
    });
    if let Some(message) = error {
        return Err(GpuError::Validation {
            label: label.to_string(),
            message,
        });
    }
    let (bind_group_layout, pipeline_layout) = layouts;
    let pipeline = ctx.compute_pipeline(label, wgsl, entry, Some(&pipeline_layout))?;

    let out_size = output_bytes.max(4).next_multiple_of(4);
    let (output, error) = ctx.scoped(|| {
        let input_buffers: Vec<wgpu::Buffer> = inputs
            .iter()
            .map(|data| {
                let mut bytes = data.to_vec();
                bytes.resize(bytes.len().max(4).next_multiple_of(4), 0);
                ctx.device
                    .create_buffer_init(&wgpu::util::BufferInitDescriptor {
                        label: Some(label),
                        contents: &bytes,
                        usage: wgpu::BufferUsages::STORAGE,
                    })
            })
            .collect();
        let output = ctx.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some(label),
            size: out_size,
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC,
            mapped_at_creation: false,
        });
        let bind_entries: Vec<wgpu::BindGroupEntry> = input_buffers
            .iter()
            .chain(std::iter::once(&output))
            .enumerate()
            .map(|(i, b)| wgpu::BindGroupEntry {
                binding: i as u32,
                resource: b.as_entire_binding(),
            })
            .collect();
        let bind_group = ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some(label),
            layout: &bind_group_layout,
            entries: &bind_entries,
        });
        let mut encoder = ctx
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some(label) });
        {
            let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some(label),
                timestamp_writes: None,
            });
            pass.set_pipeline(&pipeline);
            pass.set_bind_group(0, &bind_group, &[]);
            pass.dispatch_workgroups(workgroups[0], workgroups[1], workgroups[2]);
        }
        ctx.queue.submit([encoder.finish()]);
        output
    });
    if let Some(message) = error {
        return Err(GpuError::Validation {
            label: label.to_string(),
            message,
        });
    }
    ctx.read_buffer(&output, output_bytes)
}

/// Runs a compute shader once over f64 storage buffers (see [`run_compute_raw`] for the binding
/// layout: inputs `array<f64>` at bindings `0..inputs.len()`, output `array<f64>` of
/// `output_len` elements at the last binding), dispatching `workgroups` workgroups along x.
/// Requires [`GpuContext::f64`].
pub fn run_compute_f64(
    ctx: &GpuContext,
    wgsl: &str,
    entry: &str,
    inputs: &[&[f64]],
    output_len: usize,
    workgroups: u32,
) -> Result<Vec<f64>, GpuError> {
    if !ctx.f64 {
        return Err(GpuError::NoF64 {
            adapter: ctx.description.short(),
        });
    }
    let bytes: Vec<&[u8]> = inputs.iter().map(|x| bytemuck::cast_slice(x)).collect();
    let out = run_compute_raw(
        ctx,
        entry,
        wgsl,
        entry,
        &bytes,
        (output_len * std::mem::size_of::<f64>()) as u64,
        [workgroups, 1, 1],
    )?;
    // The Vec<u8> is not 8-byte aligned in general: copy instead of casting in place.
    Ok(bytemuck::pod_collect_to_vec(&out))
}

/// For tests: acquires a context, or returns `None` after printing
/// "skipping: no GPU adapter ..." when none can be had (no adapter, no f64 support, device
/// request failed), so that GPU tests pass vacuously on machines without a GPU.
///
/// When the environment variable `ROUGHLUB_REQUIRE_GPU=1` is set (CI does), it panics with the
/// error message instead, so that GPU tests fail rather than skip.
pub fn acquire_for_tests(want_f64: bool) -> Option<GpuContext> {
    match GpuContext::acquire(want_f64) {
        Ok(ctx) => Some(ctx),
        Err(e) => {
            if std::env::var(REQUIRE_GPU_ENV).as_deref() == Ok("1") {
                panic!("{REQUIRE_GPU_ENV}=1 but no usable GPU adapter: {e}");
            }
            eprintln!("skipping: no GPU adapter ({e})");
            None
        }
    }
}
