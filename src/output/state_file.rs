//! The binary files of a study's mergeable state (`chunks/chunk_*.state`, `partial.state`):
//! a magic line and the format number, then CBOR (ciborium). Binary because the state is mostly
//! counts and raw f64 (read back bit for bit without text conversion), and CBOR because it is
//! self-describing: the same serde types as the JSON files, small integers in one or two bytes.
//! Format 3 ends with the CRC-32 of the CBOR: a file damaged on disk or in a copy between
//! machines is refused, naming it, where a flipped bit in a statistic read back as a valid
//! number and merged into wrong results.

use std::io::{BufWriter, Write};
use std::path::Path;

use serde::{de::DeserializeOwned, Serialize};

use crate::error::{Error, Result};

/// First bytes of every state file.
const MAGIC: &[u8; 8] = b"RLSTATE\n";
/// The state format this roughlub writes. Format 1 was the JSON of roughlub 0.1
/// (`partial.json`, `chunks/*.json`), which this version refuses by name; format 2 is format 3
/// without the checksum, still read.
pub const STATE_FORMAT: u32 = 3;
/// The last format without a checksum.
const UNCHECKED_FORMAT: u32 = 2;

/// A writer that passes bytes on and keeps their CRC-32.
struct Checksummed<W: Write> {
    inner: W,
    crc: crc32fast::Hasher,
}

impl<W: Write> Write for Checksummed<W> {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        let written = self.inner.write(buf)?;
        self.crc.update(&buf[..written]);
        Ok(written)
    }
    fn flush(&mut self) -> std::io::Result<()> {
        self.inner.flush()
    }
}

/// Writes `value` to `path` atomically (a temporary file beside it, then a rename).
pub fn write_state_atomic<T: Serialize + ?Sized>(path: &Path, value: &T) -> Result<()> {
    let file_name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let tmp = path.with_file_name(format!(".{file_name}.tmp"));
    let file = std::fs::File::create(&tmp).map_err(|e| Error::io(&tmp, e))?;
    let mut w = BufWriter::with_capacity(1 << 20, file);
    w.write_all(MAGIC)
        .and_then(|_| w.write_all(&STATE_FORMAT.to_le_bytes()))
        .map_err(|e| Error::io(&tmp, e))?;
    let mut body = Checksummed {
        inner: w,
        crc: crc32fast::Hasher::new(),
    };
    ciborium::into_writer(value, &mut body).map_err(|e| Error::Output {
        path: path.to_path_buf(),
        message: e.to_string(),
    })?;
    let Checksummed { inner: mut w, crc } = body;
    w.write_all(&crc.finalize().to_le_bytes())
        .and_then(|_| w.flush())
        .map_err(|e| Error::io(&tmp, e))?;
    drop(w);
    std::fs::rename(&tmp, path).map_err(|e| Error::io(path, e))
}

/// Reads a state file written by [`write_state_atomic`]; refuses another format, naming it.
pub fn read_state<T: DeserializeOwned>(path: &Path) -> Result<T> {
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    let bad = |message: String| Error::Output {
        path: path.to_path_buf(),
        message,
    };
    if bytes.len() < 12 || &bytes[..8] != MAGIC {
        return Err(bad("not a roughlub state file".into()));
    }
    let format = u32::from_le_bytes(bytes[8..12].try_into().expect("4 bytes"));
    let body = match format {
        STATE_FORMAT => {
            let Some(end) = bytes.len().checked_sub(4).filter(|&end| end >= 12) else {
                return Err(bad("truncated: no checksum".into()));
            };
            let recorded = u32::from_le_bytes(bytes[end..].try_into().expect("4 bytes"));
            if crc32fast::hash(&bytes[12..end]) != recorded {
                return Err(bad(
                    "damaged: its checksum does not match its contents (changed after roughlub wrote it); rerun the run or shard that wrote it".into(),
                ));
            }
            &bytes[12..end]
        }
        UNCHECKED_FORMAT => &bytes[12..],
        _ => {
            return Err(bad(format!(
                "written in state format {format}; roughlub {} reads formats {UNCHECKED_FORMAT} and {STATE_FORMAT}: rerun the study with this version",
                env!("CARGO_PKG_VERSION")
            )))
        }
    };
    ciborium::from_reader(body).map_err(|e| bad(format!("unreadable: {}", cbor_error_text(&e))))
}

/// A CBOR reading error in words (ciborium's Display prints its Debug form).
fn cbor_error_text(e: &ciborium::de::Error<std::io::Error>) -> String {
    use ciborium::de::Error as E;
    match e {
        E::Io(io) => format!("it ends early or cannot be read ({io})"),
        E::Syntax(at) => format!("not valid CBOR at byte {}", at + 12),
        E::Semantic(Some(at), what) => format!("{what} (at byte {})", at + 12),
        E::Semantic(None, what) => what.clone(),
        E::RecursionLimitExceeded => "nested too deeply".into(),
    }
}

/// The error for a study directory that holds the JSON state of roughlub 0.1 (format 1)
/// rather than state files of this format.
pub fn old_format_error(path: &Path) -> Error {
    Error::Output {
        path: path.to_path_buf(),
        message: format!(
            "this study was written by roughlub 0.1 (state format 1: JSON partial and chunk files); roughlub {} reads state format {STATE_FORMAT}: rerun the study (or merge its shards) with this version",
            env!("CARGO_PKG_VERSION")
        ),
    }
}
