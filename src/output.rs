//! The output directory: .npy arrays streamed time by time (memory does not grow with the number
//! of output times), PNG plots, and `manifest.json`, written last so that a directory without it
//! is visibly incomplete.

use std::fs::File;
use std::io::BufWriter;
use std::path::{Path, PathBuf};

use npyz::WriterBuilder;

use crate::error::{Error, Result};

pub const MANIFEST: &str = "manifest.json";

type Writer = npyz::NpyWriter<f64, BufWriter<File>>;

/// An .npy file of known shape filled in row order.
pub struct NpyStream {
    path: PathBuf,
    writer: Writer,
    expected: u64,
    written: u64,
}

impl NpyStream {
    pub fn create(path: PathBuf, shape: &[u64]) -> Result<NpyStream> {
        let file = File::create(&path).map_err(|e| Error::io(&path, e))?;
        let writer = npyz::WriteOptions::new()
            .default_dtype()
            .shape(shape)
            .writer(BufWriter::new(file))
            .begin_nd()
            .map_err(|e| Error::io(&path, e))?;
        Ok(NpyStream {
            path,
            writer,
            expected: shape.iter().product(),
            written: 0,
        })
    }

    pub fn push(&mut self, values: &[f64]) -> Result<()> {
        self.written += values.len() as u64;
        if self.written > self.expected {
            return Err(Error::Output {
                path: self.path.clone(),
                message: format!("more values than its shape holds ({})", self.expected),
            });
        }
        self.writer
            .extend(values.iter().copied())
            .map_err(|e| Error::io(&self.path, e))
    }

    pub fn finish(self) -> Result<PathBuf> {
        if self.written != self.expected {
            return Err(Error::Output {
                path: self.path.clone(),
                message: format!(
                    "{} values written, shape holds {}",
                    self.written, self.expected
                ),
            });
        }
        self.writer.finish().map_err(|e| Error::io(&self.path, e))?;
        Ok(self.path)
    }
}

pub fn write_npy(path: PathBuf, shape: &[u64], values: &[f64]) -> Result<PathBuf> {
    let mut s = NpyStream::create(path, shape)?;
    s.push(values)?;
    s.finish()
}

/// Creates the directory and removes a manifest left by an earlier run, so that a run that stops
/// half-way never leaves a directory that looks complete.
pub fn prepare_dir(dir: &Path) -> Result<()> {
    std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
    let manifest = dir.join(MANIFEST);
    if manifest.exists() {
        std::fs::remove_file(&manifest).map_err(|e| Error::io(&manifest, e))?;
    }
    Ok(())
}

/// Writes the manifest through a temporary file and a rename, so it appears whole or not at all.
pub fn write_manifest(dir: &Path, manifest: &serde_json::Value) -> Result<PathBuf> {
    let path = dir.join(MANIFEST);
    let tmp = dir.join(".manifest.json.tmp");
    let text = serde_json::to_string_pretty(manifest).map_err(|e| Error::Output {
        path: path.clone(),
        message: e.to_string(),
    })?;
    std::fs::write(&tmp, text).map_err(|e| Error::io(&tmp, e))?;
    std::fs::rename(&tmp, &path).map_err(|e| Error::io(&path, e))?;
    Ok(path)
}
