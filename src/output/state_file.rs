//! The binary files of a study's mergeable state (`chunks/chunk_*.state`, `partial.state`):
//! a magic line and the format number, then CBOR (ciborium). Binary because the state is mostly
//! counts and raw f64 (read back bit for bit without text conversion), and CBOR because it is
//! self-describing: the same serde types as the JSON files, small integers in one or two bytes.

use std::io::{BufWriter, Write};
use std::path::Path;

use serde::{de::DeserializeOwned, Serialize};

use crate::error::{Error, Result};

/// First bytes of every state file.
const MAGIC: &[u8; 8] = b"RLSTATE\n";
/// The state format this roughlub writes and reads. Format 1 was the JSON of roughlub 0.1
/// (`partial.json`, `chunks/*.json`), which this version refuses by name.
pub const STATE_FORMAT: u32 = 2;

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
    ciborium::into_writer(value, &mut w).map_err(|e| Error::Output {
        path: path.to_path_buf(),
        message: e.to_string(),
    })?;
    w.flush().map_err(|e| Error::io(&tmp, e))?;
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
    if format != STATE_FORMAT {
        return Err(bad(format!(
            "written in state format {format}; roughlub {} reads format {STATE_FORMAT}: rerun the study with this version",
            env!("CARGO_PKG_VERSION")
        )));
    }
    ciborium::from_reader(&bytes[12..]).map_err(|e| bad(format!("unreadable: {e}")))
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
