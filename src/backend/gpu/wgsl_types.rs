//! Host-side mirrors of the data the step kernel shares with the host: arrays of its element
//! type `real` (f32 or f64) and its `Config` and `Control` structs (`shaders/step.wgsl`).
//!
//! The host computes in f64 and converts on upload and read-back, so the f64 structs double as
//! the host's view; the f32 ones exist only as bytes on their way to or from the GPU.
//! bytemuck's derive does not support generic Pod structs, hence one struct per real type,
//! written by `mirror_structs!`.
//!
//! WGSL layout (host-shareable structs): a field is aligned to its type (u32 and f32 to 4, f64
//! to 8) and a struct's size is rounded up to its largest alignment; in an array the element
//! stride is that size. Both structs put their u32 fields in runs that keep every f64 8-aligned,
//! so the WGSL layout has no padding and `#[repr(C)]` reproduces it; the `const` assertions
//! below pin the offsets and sizes.

use bytemuck::{Pod, Zeroable};

use crate::backend::Precision;

/// Bytes of the uniform `Config` buffer: the size of the f64 `Config` (a multiple of 16, as a
/// uniform binding wants). The f32 `Config` (40 bytes in WGSL) is padded to it on the host, so
/// every upload rewrites the whole buffer in both precisions.
pub const CONFIG_BUFFER_SIZE: u64 = 64;

macro_rules! mirror_structs {
    ($config:ident, $control:ident, $real:ty, $config_tail:literal) => {
        #[doc = concat!("`struct Config` of shaders/step.wgsl with `real = ", stringify!($real), "` (keep in sync): the interval being integrated.")]
        #[repr(C)]
        #[derive(Debug, Clone, Copy, PartialEq, Pod, Zeroable)]
        pub struct $config {
            /// Members B.
            pub batch: u32,
            /// Particles N.
            pub particles: u32,
            /// Trial steps per member per `advance` dispatch.
            pub max_attempts: u32,
            /// Auto's highest column (`Plan::top_column`); also keeps the reals 8-aligned.
            pub top_column: u32,
            pub eps: $real,
            pub t_start: $real,
            pub t_end: $real,
            /// > 0: fixed steps of this size (`Rules::fixed_h`); 0: adaptive steps.
            pub fixed_h: $real,
            pub dt_min: $real,
            pub tolerance: $real,
            /// Not in WGSL: pads the struct to [`CONFIG_BUFFER_SIZE`].
            pub tail: [u32; $config_tail],
        }

        #[doc = concat!("`struct Control` of shaders/step.wgsl with `real = ", stringify!($real), "` (keep in sync): a member's `StepControl`, counters and flags as u32.")]
        #[repr(C)]
        #[derive(Debug, Clone, Copy, PartialEq, Pod, Zeroable)]
        pub struct $control {
            pub t: $real,
            pub dt: $real,
            /// Time of the failure (when `failure != 0`).
            pub failure_time: $real,
            /// `StepControl::failure_detail`.
            pub failure_detail: $real,
            /// Discrete energy of the current state.
            pub energy: $real,
            /// `StepControl::error_sum`.
            pub error_sum: $real,
            /// `StepControl::h_previous`.
            pub h_previous: $real,
            /// `StepControl::err_previous`.
            pub err_previous: $real,
            /// `StepControl::t_low`.
            pub t_low: $real,
            /// `StepControl::window_t`.
            pub window_t: $real,
            pub accepted: u32,
            pub rejected: u32,
            pub regular_steps: u32,
            /// 1 while the member takes regular (not reduced) steps.
            pub regular: u32,
            /// `Failure` code, 0 = running or done.
            pub failure: u32,
            /// Which buffer set (0 or 1) holds the member's state.
            pub parity: u32,
            /// `StepControl::failure_index`.
            pub failure_index: u32,
            /// `StepControl::order`: the tableau column of the next step.
            pub order: u32,
            /// `StepControl::after_rejection` (1: the last attempt was rejected).
            pub after_rejection: u32,
            /// `StepControl::window_attempts`.
            pub window_attempts: u32,
        }
    };
}

mirror_structs!(ConfigF64, ControlF64, f64, 0);
mirror_structs!(ConfigF32, ControlF32, f32, 6);

// The WGSL offsets and sizes (see the module docs for the rules).
const _: () = {
    use std::mem::offset_of;
    assert!(size_of::<ConfigF64>() == 64);
    assert!(offset_of!(ConfigF64, eps) == 16);
    assert!(offset_of!(ConfigF64, tolerance) == 56);
    assert!(offset_of!(ConfigF32, eps) == 16);
    assert!(offset_of!(ConfigF32, tolerance) == 36);
    assert!(offset_of!(ConfigF32, tail) == 40);
    assert!(size_of::<ConfigF32>() == CONFIG_BUFFER_SIZE as usize);
    assert!(size_of::<ConfigF64>() == CONFIG_BUFFER_SIZE as usize);
    assert!(size_of::<ControlF64>() == 120);
    assert!(offset_of!(ControlF64, accepted) == 80);
    assert!(offset_of!(ControlF64, parity) == 100);
    assert!(size_of::<ControlF32>() == 80);
    assert!(offset_of!(ControlF32, accepted) == 40);
    assert!(offset_of!(ControlF32, parity) == 60);
};

impl ConfigF64 {
    /// Rounded to f32 (`as f32`, round to nearest) for the f32 kernel.
    fn to_f32(self) -> ConfigF32 {
        ConfigF32 {
            batch: self.batch,
            particles: self.particles,
            max_attempts: self.max_attempts,
            top_column: self.top_column,
            eps: self.eps as f32,
            t_start: self.t_start as f32,
            t_end: self.t_end as f32,
            fixed_h: self.fixed_h as f32,
            // Never 0 in f32 (1e-30 end, dt_min's default, is for end < 1e-8): at t = 0 the
            // floor is dt_min alone, and with 0 a member whose step collapses would never fail.
            dt_min: (self.dt_min as f32).max(f32::MIN_POSITIVE),
            tolerance: self.tolerance as f32,
            tail: [0; 6],
        }
    }
}

impl ControlF64 {
    /// Rounded to f32 (`as f32`, round to nearest) for the f32 kernel.
    fn to_f32(self) -> ControlF32 {
        ControlF32 {
            t: self.t as f32,
            dt: self.dt as f32,
            failure_time: self.failure_time as f32,
            failure_detail: self.failure_detail as f32,
            energy: self.energy as f32,
            error_sum: self.error_sum as f32,
            h_previous: self.h_previous as f32,
            err_previous: self.err_previous as f32,
            t_low: self.t_low as f32,
            window_t: self.window_t as f32,
            accepted: self.accepted,
            rejected: self.rejected,
            regular_steps: self.regular_steps,
            regular: self.regular,
            failure: self.failure,
            parity: self.parity,
            failure_index: self.failure_index,
            order: self.order,
            after_rejection: self.after_rejection,
            window_attempts: self.window_attempts,
        }
    }
}

impl From<ControlF32> for ControlF64 {
    fn from(c: ControlF32) -> Self {
        ControlF64 {
            t: c.t.into(),
            dt: c.dt.into(),
            failure_time: c.failure_time.into(),
            failure_detail: c.failure_detail.into(),
            energy: c.energy.into(),
            error_sum: c.error_sum.into(),
            h_previous: c.h_previous.into(),
            err_previous: c.err_previous.into(),
            t_low: c.t_low.into(),
            window_t: c.window_t.into(),
            accepted: c.accepted,
            rejected: c.rejected,
            regular_steps: c.regular_steps,
            regular: c.regular,
            failure: c.failure,
            parity: c.parity,
            failure_index: c.failure_index,
            order: c.order,
            after_rejection: c.after_rejection,
            window_attempts: c.window_attempts,
        }
    }
}

/// Bytes of `config` as the kernel's `Config` ([`CONFIG_BUFFER_SIZE`] bytes).
pub fn config_bytes(config: ConfigF64, precision: Precision) -> Vec<u8> {
    match precision {
        Precision::F64 => bytemuck::bytes_of(&config).to_vec(),
        Precision::F32 => bytemuck::bytes_of(&config.to_f32()).to_vec(),
    }
}

/// Bytes of one WGSL `Control` (the stride of `array<Control>`).
pub fn control_size(precision: Precision) -> u64 {
    match precision {
        Precision::F64 => size_of::<ControlF64>() as u64,
        Precision::F32 => size_of::<ControlF32>() as u64,
    }
}

/// Bytes of `controls` as the kernel's `array<Control>`.
pub fn controls_bytes(controls: &[ControlF64], precision: Precision) -> Vec<u8> {
    match precision {
        Precision::F64 => bytemuck::cast_slice(controls).to_vec(),
        Precision::F32 => {
            let narrow: Vec<ControlF32> = controls.iter().map(|c| c.to_f32()).collect();
            bytemuck::cast_slice(&narrow).to_vec()
        }
    }
}

/// The kernel's `array<Control>` read back (bytes with no alignment guarantee).
pub fn controls_from_bytes(bytes: &[u8], precision: Precision) -> Vec<ControlF64> {
    match precision {
        Precision::F64 => bytemuck::pod_collect_to_vec(bytes),
        Precision::F32 => bytemuck::pod_collect_to_vec::<u8, ControlF32>(bytes)
            .into_iter()
            .map(ControlF64::from)
            .collect(),
    }
}

/// Bytes of one `real`.
pub fn real_size(precision: Precision) -> u64 {
    match precision {
        Precision::F64 => 8,
        Precision::F32 => 4,
    }
}

/// Bytes of `values` as the kernel's `real` (f32: rounded to nearest).
pub fn real_bytes(values: &[f64], precision: Precision) -> Vec<u8> {
    match precision {
        Precision::F64 => bytemuck::cast_slice(values).to_vec(),
        Precision::F32 => {
            let v: Vec<f32> = values.iter().map(|&x| x as f32).collect();
            bytemuck::cast_slice(&v).to_vec()
        }
    }
}

/// The kernel's `real`s read back (bytes with no alignment guarantee), widened to f64.
pub fn reals_from_bytes(bytes: &[u8], precision: Precision) -> Vec<f64> {
    match precision {
        Precision::F64 => bytemuck::pod_collect_to_vec(bytes),
        Precision::F32 => {
            let v: Vec<f32> = bytemuck::pod_collect_to_vec(bytes);
            v.into_iter().map(f64::from).collect()
        }
    }
}
