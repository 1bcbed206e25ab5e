//! The output directory: .npy arrays ([`npy`]), typed manifests ([`manifest`]) and JSON state
//! written through one atomic writer ([`files`]), the exact f64 serde helper ([`serde_f64`]) and
//! the progress bar ([`progress`]), the study tables' column names ([`columns`]). `manifest.json` is written last, so a directory without it
//! is visibly incomplete.

pub mod columns;
pub mod files;
pub mod manifest;
pub mod npy;
pub mod progress;
pub mod serde_f64;
pub mod state_file;

pub use files::{
    fnv1a, input_file_hashes, prepare_dir, read_json, write_json_atomic, Fnv1a, StagedDir, MANIFEST,
};
pub use npy::{write_npy, NpyStream};
pub use progress::ProgressReporter;
pub use state_file::{read_state, write_state_atomic, STATE_FORMAT};
