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
/// sibling of `target`, `.NAME.partial-PID`), and [`StagedDir::commit`] replaces `target` by it,
/// so `target` is always either the complete earlier run or the complete new one. A `target`
/// that holds files but no roughlub manifest or study is refused unless `force` (it may be
/// someone's data).
///
/// A staging directory dropped without a commit (an error) is removed, unless
/// [`StagedDir::keep_on_failure`] was called: a study keeps its finished chunks for `--resume`.
/// A run killed outright leaves its staging directory behind; the next run into the same target
/// removes such leftovers of dead processes (saying so), and `--resume` of a study adopts its
/// own ([`StagedDir::adopt_interrupted_study`]).
#[derive(Debug)]
pub struct StagedDir {
    pub target: PathBuf,
    pub staging: PathBuf,
    keep_on_failure: bool,
    committed: bool,
    /// The staging marker, open and locked while this process owns the directory: a leftover
    /// whose marker nobody holds is a dead run's, whatever its PID now names (a PID is reused
    /// after a restart, or names another node's process on shared scratch).
    _lock: Option<std::fs::File>,
}

/// The staging marker of `dir` opened and locked (None where it cannot be: then the PID alone
/// says whether its run is alive).
fn lock_marker(dir: &Path) -> Option<std::fs::File> {
    let marker = dir.join(STAGING_MARKER);
    let file = std::fs::OpenOptions::new()
        .create(true)
        .truncate(false)
        .write(true)
        .open(marker)
        .ok()?;
    file.try_lock().ok()?;
    Some(file)
}

/// Whether `dir`'s staging marker exists and no process holds its lock (its run is dead).
fn marker_unlocked(dir: &Path) -> bool {
    let Ok(file) = std::fs::OpenOptions::new()
        .write(true)
        .open(dir.join(STAGING_MARKER))
    else {
        return false;
    };
    // Released when `file` is dropped.
    file.try_lock().is_ok()
}

const STAGING_TAG: &str = ".partial-";
const OLD_TAG: &str = ".old-";
/// Written into a staging directory when it is made (removed at the commit): what marks a
/// leftover as roughlub's before anything deletes it.
const STAGING_MARKER: &str = ".roughlub-staging";

/// Every file a run reads (a particle file, a roughness file), path -> FNV-1a (64 bits, hex) of
/// its bytes: what the manifest records and `--resume` and `merge` compare.
pub fn input_file_hashes(paths: &[&Path]) -> Result<std::collections::BTreeMap<String, String>> {
    let mut out = std::collections::BTreeMap::new();
    for path in paths {
        let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
        out.insert(path.display().to_string(), fnv1a(&bytes));
    }
    Ok(out)
}

/// FNV-1a (64 bits) of `bytes`, as 16 hex digits.
pub fn fnv1a(bytes: &[u8]) -> String {
    let mut h = Fnv1a::default();
    h.update(bytes);
    h.hex()
}

/// FNV-1a (64 bits) of bytes given piece by piece: the same as [`fnv1a`] of their concatenation.
#[derive(Debug, Clone, Copy)]
pub struct Fnv1a(u64);

impl Default for Fnv1a {
    fn default() -> Self {
        Fnv1a(0xcbf29ce484222325)
    }
}

impl Fnv1a {
    pub fn update(&mut self, bytes: &[u8]) {
        for b in bytes {
            self.0 ^= *b as u64;
            self.0 = self.0.wrapping_mul(0x100000001b3);
        }
    }

    /// As 16 hex digits.
    pub fn hex(&self) -> String {
        format!("{:016x}", self.0)
    }
}

/// Hashes what is written to it (`std::io::copy` of a file into it hashes the file).
impl std::io::Write for Fnv1a {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        self.update(buf);
        Ok(buf.len())
    }

    fn flush(&mut self) -> std::io::Result<()> {
        Ok(())
    }
}

/// Whether `dir` holds a record that roughlub wrote: a `manifest.json` or `study.json` with its
/// `roughlub_version` (a file of that name alone may be anyone's: a web app's manifest).
fn holds_roughlub_record(dir: &Path) -> bool {
    #[derive(Deserialize)]
    struct Signature {
        #[allow(dead_code)]
        roughlub_version: String,
    }
    [MANIFEST, "study.json"]
        .iter()
        .any(|name| read_json::<Signature>(&dir.join(name)).is_ok())
}

/// Whether a leftover beside a target is roughlub's, so that it may be removed: a staging
/// directory by its marker (written when it is made) or, killed within its commit after the
/// marker was removed, by its finished run's record; a swapped-out earlier run by its record.
fn is_roughlub_leftover(dir: &Path, is_staging: bool) -> bool {
    (is_staging && dir.join(STAGING_MARKER).exists()) || holds_roughlub_record(dir)
}

/// (parent, name) of a target directory; the staging directories live in `parent`.
fn split_target(target: &Path) -> (PathBuf, String) {
    let name = target
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| "out".into());
    let parent = target
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."))
        .to_path_buf();
    (parent, name)
}

/// Whether process `pid` still runs: `Some` where the OS says (Linux: /proc), `None` elsewhere
/// (then nothing is treated as stale).
fn process_alive(pid: u32) -> Option<bool> {
    let proc_root = Path::new("/proc");
    if !proc_root.join("self").exists() {
        return None;
    }
    Some(proc_root.join(pid.to_string()).exists())
}

/// Staging (`.NAME.partial-PID`) and swap (`.NAME.old-PID`) directories of `target` whose
/// process is dead (or is this one: a PID reused after a restart, as in containers; or, for a
/// staging directory, whose marker no process holds locked), and that hold roughlub's files:
/// what a killed run left behind.
fn leftovers(target: &Path) -> Result<Vec<(PathBuf, bool)>> {
    let (parent, name) = split_target(target);
    let mut found = Vec::new();
    let Ok(entries) = std::fs::read_dir(&parent) else {
        return Ok(found);
    };
    for entry in entries.flatten() {
        let file_name = entry.file_name().to_string_lossy().into_owned();
        let Some(rest) = file_name.strip_prefix(&format!(".{name}")) else {
            continue;
        };
        let (is_staging, pid) = if let Some(pid) = rest.strip_prefix(STAGING_TAG) {
            (true, pid)
        } else if let Some(pid) = rest.strip_prefix(OLD_TAG) {
            (false, pid)
        } else {
            continue;
        };
        let Ok(pid) = pid.parse::<u32>() else {
            continue;
        };
        let dead = pid == std::process::id()
            || process_alive(pid) == Some(false)
            || (is_staging && marker_unlocked(&entry.path()));
        if dead && entry.path().is_dir() && is_roughlub_leftover(&entry.path(), is_staging) {
            found.push((entry.path(), is_staging));
        }
    }
    found.sort();
    Ok(found)
}

impl StagedDir {
    pub fn begin(target: &Path, force: bool) -> Result<StagedDir> {
        // The directory is replaced by a rename, so it must have a name of its own (not `.`,
        // `..` or `/`, which cannot be swapped).
        // A trailing `/.` is dropped by Path's components (`out/.` names `out`) but not by the
        // system calls that rename it.
        let text = target.as_os_str().as_encoded_bytes();
        if target.file_name().is_none() || text == b"." || text.ends_with(b"/.") {
            return Err(Error::Output {
                path: target.to_path_buf(),
                message: "--out must name a directory of its own (not ., .. or /): the run is swapped in whole by renaming it".into(),
            });
        }
        if target.is_symlink() {
            return Err(Error::Output {
                path: target.to_path_buf(),
                message: "is a symbolic link; give the directory it points to as --out (a run replaces its directory whole)".into(),
            });
        }
        // The nearest existing ancestor must be a directory (else creating the staging
        // directory fails with a bare "File exists" naming that ancestor).
        if let Some(file) = target
            .ancestors()
            .skip(1)
            .filter(|a| !a.as_os_str().is_empty())
            .find(|a| a.exists())
            .filter(|a| !a.is_dir())
        {
            return Err(Error::Output {
                path: target.to_path_buf(),
                message: format!(
                    "cannot be created: {} is a file, not a directory; give another --out",
                    file.display()
                ),
            });
        }
        Self::recover_interrupted_commit(target)?;
        if target.exists() {
            if !target.is_dir() {
                return Err(Error::Output {
                    path: target.to_path_buf(),
                    message: "is a file, not a directory; give another --out".into(),
                });
            }
            let ours = holds_roughlub_record(target);
            let empty = std::fs::read_dir(target)
                .map_err(|e| Error::io(target, e))?
                .next()
                .is_none();
            if !ours && !empty && !force {
                return Err(Error::Output {
                    path: target.to_path_buf(),
                    message: "holds files but no roughlub run (no manifest.json or study.json that roughlub wrote), and a run replaces its directory whole; give another --out, or --force to replace it".into(),
                });
            }
        }
        for (dir, _) in leftovers(target)? {
            eprintln!(
                "note: removing {}, left by an interrupted run into {}",
                dir.display(),
                target.display()
            );
            std::fs::remove_dir_all(&dir).map_err(|e| Error::io(&dir, e))?;
        }
        let staging = Self::own_staging(target)?;
        if staging.exists() {
            std::fs::remove_dir_all(&staging).map_err(|e| Error::io(&staging, e))?;
        }
        std::fs::create_dir_all(&staging).map_err(|e| Error::io(&staging, e))?;
        let marker = staging.join(STAGING_MARKER);
        std::fs::write(&marker, b"").map_err(|e| Error::io(&marker, e))?;
        let lock = lock_marker(&staging);
        Ok(StagedDir {
            target: target.to_path_buf(),
            staging,
            keep_on_failure: false,
            committed: false,
            _lock: lock,
        })
    }

    /// A run killed between the two renames of its commit leaves the earlier run as
    /// `.NAME.old-PID` and no `target`: the finished new run (`.NAME.partial-PID` with its
    /// manifest) is put in place, or else the earlier run is put back.
    pub fn recover_interrupted_commit(target: &Path) -> Result<()> {
        if target.exists() {
            return Ok(());
        }
        for (old, is_staging) in leftovers(target)? {
            if is_staging {
                continue;
            }
            let name = old
                .file_name()
                .map(|n| n.to_string_lossy().into_owned())
                .unwrap_or_default();
            let partial = old.with_file_name(name.replace(OLD_TAG, STAGING_TAG));
            let (restore, note) = if partial.join(MANIFEST).exists() {
                (&partial, "the finished run")
            } else {
                (&old, "the earlier run")
            };
            eprintln!(
                "note: {} was interrupted while being replaced; putting {note} ({}) back in place",
                target.display(),
                restore.display()
            );
            std::fs::rename(restore, target).map_err(|e| Error::io(restore, e))?;
            let _ = std::fs::remove_file(target.join(STAGING_MARKER));
            if restore == &partial {
                // The earlier run was being replaced by this one: nothing left to keep of it.
                std::fs::remove_dir_all(&old).map_err(|e| Error::io(&old, e))?;
            }
            return Ok(());
        }
        Ok(())
    }

    /// This process's staging directory for `target` (its parent is created).
    fn own_staging(target: &Path) -> Result<PathBuf> {
        let (parent, name) = split_target(target);
        std::fs::create_dir_all(&parent).map_err(|e| Error::io(&parent, e))?;
        Ok(parent.join(format!(".{name}{STAGING_TAG}{}", std::process::id())))
    }

    /// The staging directory of a study run into `target` that was killed (it holds a
    /// `study.json`), renamed to this process's staging directory; `None` when there is none.
    /// When several are left, the one with the most finished chunks is taken.
    /// Only directories for which `same_study` (given the path of its `study.json`) holds are
    /// taken.
    pub fn adopt_interrupted_study(
        target: &Path,
        same_study: impl Fn(&Path) -> bool,
    ) -> Result<Option<StagedDir>> {
        let chunk_count =
            |dir: &Path| std::fs::read_dir(dir.join("chunks")).map_or(0, |entries| entries.count());
        let best = leftovers(target)?
            .into_iter()
            .filter(|(dir, is_staging)| {
                *is_staging
                    && dir.join("study.json").exists()
                    && same_study(&dir.join("study.json"))
            })
            .max_by_key(|(dir, _)| chunk_count(dir));
        let Some((found, _)) = best else {
            return Ok(None);
        };
        let staging = Self::own_staging(target)?;
        if found != staging {
            std::fs::rename(&found, &staging).map_err(|e| Error::io(&found, e))?;
        }
        let lock = lock_marker(&staging);
        Ok(Some(StagedDir {
            target: target.to_path_buf(),
            staging,
            keep_on_failure: true,
            committed: false,
            _lock: lock,
        }))
    }

    /// The `study.json` of every staging directory a killed run into `target` left (what
    /// [`StagedDir::adopt_interrupted_study`] chooses from).
    pub fn interrupted_studies(target: &Path) -> Result<Vec<PathBuf>> {
        Ok(leftovers(target)?
            .into_iter()
            .filter(|(dir, is_staging)| *is_staging && dir.join("study.json").exists())
            .map(|(dir, _)| dir.join("study.json"))
            .collect())
    }

    /// Keep the staging directory when the run fails (a study's finished chunks, for
    /// `--resume`).
    pub fn keep_on_failure(&mut self) {
        self.keep_on_failure = true;
    }

    /// Replaces `target` by the finished staging directory (two renames; the earlier run is
    /// removed only after the new one is in place).
    pub fn commit(mut self) -> Result<()> {
        let old = self.staging.with_file_name(
            self.staging
                .file_name()
                .map(|n| n.to_string_lossy().replace(STAGING_TAG, OLD_TAG))
                .unwrap_or_default(),
        );
        let _ = std::fs::remove_file(self.staging.join(STAGING_MARKER));
        let had_old = self.target.exists();
        if had_old {
            std::fs::rename(&self.target, &old).map_err(|e| Error::io(&self.target, e))?;
        }
        if let Err(e) = std::fs::rename(&self.staging, &self.target) {
            // Put the earlier run back: the target is never left missing.
            if had_old {
                let _ = std::fs::rename(&old, &self.target);
            }
            return Err(Error::io(&self.target, e));
        }
        self.committed = true;
        if had_old {
            std::fs::remove_dir_all(&old).map_err(|e| Error::io(&old, e))?;
        }
        Ok(())
    }
}

impl Drop for StagedDir {
    fn drop(&mut self) {
        if !self.committed && !self.keep_on_failure {
            // Best effort: a leftover is removed by the next run into the same target anyway.
            let _ = std::fs::remove_dir_all(&self.staging);
        }
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

#[cfg(test)]
mod tests {
    use super::{leftovers, lock_marker, STAGING_MARKER, STAGING_TAG};

    /// A staging directory named with the PID of a live process (PID 1 here, as after a
    /// restart or on another node of shared scratch) is a leftover when no process holds its
    /// marker locked, and not while one does (it was never a leftover while its PID lived).
    #[test]
    fn a_staging_directory_is_a_leftover_once_its_marker_is_unlocked() {
        let tmp = tempfile::tempdir().unwrap();
        let target = tmp.path().join("s");
        let staging = tmp.path().join(format!(".s{STAGING_TAG}1"));
        std::fs::create_dir(&staging).unwrap();
        std::fs::write(staging.join(STAGING_MARKER), b"").unwrap();
        let held = lock_marker(&staging).expect("the marker can be locked here");
        assert!(
            leftovers(&target).unwrap().is_empty(),
            "a locked run's directory"
        );
        drop(held);
        assert_eq!(leftovers(&target).unwrap(), vec![(staging, true)]);
    }

    /// A run killed within its commit, after the marker's removal and before the rename, leaves
    /// a finished staging directory without a marker: its manifest makes it roughlub's (a
    /// leftover to remove), where a directory of that name with a foreign manifest is not.
    #[test]
    fn a_finished_staging_directory_without_its_marker_is_a_leftover() {
        let tmp = tempfile::tempdir().unwrap();
        let target = tmp.path().join("s");
        // Above Linux's PID limit: no process has it.
        let finished = tmp.path().join(format!(".s{STAGING_TAG}4194305"));
        std::fs::create_dir(&finished).unwrap();
        std::fs::write(finished.join("manifest.json"), r#"{"name": "app"}"#).unwrap();
        assert!(leftovers(&target).unwrap().is_empty(), "a foreign manifest");
        std::fs::write(
            finished.join("manifest.json"),
            r#"{"roughlub_version": "0.3.0", "scene": "name = \"s\""}"#,
        )
        .unwrap();
        assert_eq!(leftovers(&target).unwrap(), vec![(finished, true)]);
    }
}
