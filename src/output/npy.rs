//! .npy arrays, streamed row by row (memory does not grow with the number of output times).

use std::fs::File;
use std::io::BufWriter;
use std::path::PathBuf;

use npyz::WriterBuilder;

use crate::error::{Error, Result};

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
