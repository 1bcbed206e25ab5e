//! .npy arrays, streamed row by row (memory does not grow with the number of output times).

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::PathBuf;

use npyz::WriterBuilder;

use crate::error::{Error, Result};

/// An .npy file of known shape filled in row order.
///
/// npyz writes the header; the values go to the file as one block of little-endian f64 per
/// push (the format's `<f8` data in C order). npyz's own writer takes them one by one, about
/// 12 ns each, which was a quarter of a small study's statistics (its quantile files).
pub struct NpyStream {
    path: PathBuf,
    file: BufWriter<File>,
    expected: u64,
    written: u64,
}

/// The header npyz writes for an array of f64 of this shape (the data follows it).
fn header(shape: &[u64]) -> std::io::Result<Vec<u8>> {
    let mut bytes = Vec::new();
    let writer = npyz::WriteOptions::<f64>::new()
        .default_dtype()
        .shape(shape)
        .writer(&mut bytes)
        .begin_nd()?;
    // Dropped before any value: its check that every value was written fails, and a drop
    // ignores it (npyz's documented behaviour); the header is in `bytes` already.
    drop(writer);
    Ok(bytes)
}

impl NpyStream {
    pub fn create(path: PathBuf, shape: &[u64]) -> Result<NpyStream> {
        let header = header(shape).map_err(|e| Error::io(&path, e))?;
        let file = File::create(&path).map_err(|e| Error::io(&path, e))?;
        let mut file = BufWriter::new(file);
        file.write_all(&header).map_err(|e| Error::io(&path, e))?;
        Ok(NpyStream {
            path,
            file,
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
        let written = if cfg!(target_endian = "little") {
            self.file.write_all(bytemuck::cast_slice(values))
        } else {
            values
                .iter()
                .try_for_each(|v| self.file.write_all(&v.to_le_bytes()))
        };
        written.map_err(|e| Error::io(&self.path, e))
    }

    pub fn finish(mut self) -> Result<PathBuf> {
        if self.written != self.expected {
            return Err(Error::Output {
                path: self.path.clone(),
                message: format!(
                    "{} values written, shape holds {}",
                    self.written, self.expected
                ),
            });
        }
        self.file.flush().map_err(|e| Error::io(&self.path, e))?;
        Ok(self.path)
    }
}

pub fn write_npy(path: PathBuf, shape: &[u64], values: &[f64]) -> Result<PathBuf> {
    let mut s = NpyStream::create(path, shape)?;
    s.push(values)?;
    s.finish()
}
