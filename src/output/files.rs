//! Files that must appear whole or not at all: every JSON file goes through one atomic writer
//! (a temporary file and a rename), and a run first removes the manifest of an earlier run.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};

pub const MANIFEST: &str = "manifest.json";

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

/// A run's output directory built aside and swapped in whole: files go to `staging` (a hidden
/// sibling of `target`), and [`StagedDir::commit`] replaces `target` by it, so `target` is always
/// either the complete earlier run or the complete new one. A `target` that holds files but no
/// roughlub manifest or study is refused unless `force` (it may be someone's data).
pub struct StagedDir {
    pub target: PathBuf,
    pub staging: PathBuf,
}

impl StagedDir {
    pub fn begin(target: &Path, force: bool) -> Result<StagedDir> {
        if target.exists() {
            if !target.is_dir() {
                return Err(Error::Output {
                    path: target.to_path_buf(),
                    message: "is a file, not a directory; give another --out".into(),
                });
            }
            let ours = target.join(MANIFEST).exists() || target.join("study.json").exists();
            let empty = std::fs::read_dir(target)
                .map_err(|e| Error::io(target, e))?
                .next()
                .is_none();
            if !ours && !empty && !force {
                return Err(Error::Output {
                    path: target.to_path_buf(),
                    message: "holds files but no roughlub run (no manifest.json or study.json), and a run replaces its directory whole; give another --out, or --force to replace it".into(),
                });
            }
        }
        let name = target
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_else(|| "out".into());
        let parent = target
            .parent()
            .filter(|p| !p.as_os_str().is_empty())
            .unwrap_or(Path::new("."));
        std::fs::create_dir_all(parent).map_err(|e| Error::io(parent, e))?;
        let staging = parent.join(format!(".{name}.partial-{}", std::process::id()));
        if staging.exists() {
            std::fs::remove_dir_all(&staging).map_err(|e| Error::io(&staging, e))?;
        }
        std::fs::create_dir_all(&staging).map_err(|e| Error::io(&staging, e))?;
        Ok(StagedDir {
            target: target.to_path_buf(),
            staging,
        })
    }

    /// Replaces `target` by the finished staging directory (two renames; the earlier run is
    /// removed only after the new one is in place).
    pub fn commit(self) -> Result<()> {
        let old = self.staging.with_file_name(
            self.staging
                .file_name()
                .map(|n| n.to_string_lossy().replace(".partial-", ".old-"))
                .unwrap_or_default(),
        );
        let had_old = self.target.exists();
        if had_old {
            std::fs::rename(&self.target, &old).map_err(|e| Error::io(&self.target, e))?;
        }
        std::fs::rename(&self.staging, &self.target).map_err(|e| Error::io(&self.target, e))?;
        if had_old {
            std::fs::remove_dir_all(&old).map_err(|e| Error::io(&old, e))?;
        }
        Ok(())
    }
}

/// Writes `value` as pretty JSON through a temporary file and a rename.
pub fn write_json_atomic<T: Serialize + ?Sized>(path: &Path, value: &T) -> Result<()> {
    let file_name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let tmp = path.with_file_name(format!(".{file_name}.tmp"));
    let text = serde_json::to_string_pretty(value).map_err(|e| Error::Output {
        path: path.to_path_buf(),
        message: e.to_string(),
    })?;
    std::fs::write(&tmp, text).map_err(|e| Error::io(&tmp, e))?;
    std::fs::rename(&tmp, path).map_err(|e| Error::io(path, e))
}

pub fn read_json<T: for<'de> Deserialize<'de>>(path: &Path) -> Result<T> {
    let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
    serde_json::from_str(&text).map_err(|e| Error::Output {
        path: path.to_path_buf(),
        message: format!("unreadable: {e}"),
    })
}
