//! The cache directory: `ID.vrs` solution files, `ID.toml` scene texts (so a corrupt or
//! evicted solution can be solved again), and `volumes/HEX.f32` uploaded raw volumes.

use std::fs;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result};

/// Paths inside one cache directory.
#[derive(Clone, Debug)]
pub struct CacheDir {
    pub root: PathBuf,
}

impl CacheDir {
    /// Creates the directory (and `volumes/`) when missing.
    pub fn open(root: &Path) -> Result<CacheDir> {
        fs::create_dir_all(root.join("volumes"))
            .with_context(|| format!("creating the cache directory {}", root.display()))?;
        Ok(CacheDir {
            root: root.to_path_buf(),
        })
    }

    pub fn solution_path(&self, id: &str) -> PathBuf {
        self.root.join(format!("{id}.vrs"))
    }

    pub fn scene_path(&self, id: &str) -> PathBuf {
        self.root.join(format!("{id}.toml"))
    }

    /// The scene's name (`?name=`, a preloaded file's stem), one line of text.
    pub fn name_path(&self, id: &str) -> PathBuf {
        self.root.join(format!("{id}.name"))
    }

    pub fn volumes_dir(&self) -> PathBuf {
        self.root.join("volumes")
    }

    pub fn volume_path(&self, name: &str) -> PathBuf {
        self.volumes_dir().join(name)
    }

    /// Ids that have a scene text or a solution file, sorted and deduplicated.
    pub fn known_ids(&self) -> Vec<String> {
        let mut ids = Vec::new();
        if let Ok(entries) = fs::read_dir(&self.root) {
            for e in entries.flatten() {
                let path = e.path();
                let ext = path.extension().and_then(|x| x.to_str());
                if !matches!(ext, Some("vrs") | Some("toml")) {
                    continue;
                }
                if let Some(stem) = path.file_stem().and_then(|s| s.to_str()) {
                    if is_id(stem) {
                        ids.push(stem.to_string());
                    }
                }
            }
        }
        ids.sort();
        ids.dedup();
        ids
    }

    /// Deletes temporary files ([`medium::atomic_file`]'s `.NAME.tmp-PID-N`) in the cache
    /// directory and `volumes/` that nothing has written to for `older_than`: what a writer
    /// killed mid-write (kill -9, a crash, a power cut) leaves behind. Such files are never
    /// read — their names are not `ID.vrs` or `ID.toml` — but would fill the disk over many
    /// crashes. Younger ones are kept: another instance sharing the directory may be writing
    /// them now (a file being written is modified as it grows, and renamed seconds after).
    /// Returns how many were deleted.
    pub fn remove_stale_temp_files(&self, older_than: std::time::Duration) -> usize {
        let now = std::time::SystemTime::now();
        let mut removed = 0;
        for dir in [self.root.clone(), self.volumes_dir()] {
            let Ok(entries) = fs::read_dir(&dir) else {
                continue;
            };
            for e in entries.flatten() {
                let name = e.file_name();
                let Some(name) = name.to_str() else { continue };
                if !is_temp_name(name) {
                    continue;
                }
                let Ok(meta) = e.metadata() else { continue };
                let age = meta
                    .modified()
                    .ok()
                    .and_then(|t| now.duration_since(t).ok())
                    .unwrap_or_default();
                if meta.is_file() && age >= older_than && fs::remove_file(e.path()).is_ok() {
                    tracing::info!(
                        "cache: removed {name}, a temporary file left by a writer that stopped \
                         {:.0} s ago",
                        age.as_secs_f64()
                    );
                    removed += 1;
                }
            }
        }
        removed
    }

    /// Uploaded volumes with their sizes and modification times, oldest first.
    pub fn volumes_by_age(&self) -> Vec<(PathBuf, u64)> {
        let mut v: Vec<(PathBuf, u64, std::time::SystemTime)> = Vec::new();
        if let Ok(entries) = fs::read_dir(self.volumes_dir()) {
            for e in entries.flatten() {
                if let Ok(m) = e.metadata() {
                    if m.is_file() {
                        let t = m.modified().unwrap_or(std::time::UNIX_EPOCH);
                        v.push((e.path(), m.len(), t));
                    }
                }
            }
        }
        v.sort_by_key(|x| x.2);
        v.into_iter().map(|(p, n, _)| (p, n)).collect()
    }
}

/// Ids are lower-case hex (what [`scene_id`](super::jobs::scene_id) makes); anything else is
/// never turned into a path.
pub fn is_id(s: &str) -> bool {
    (16..=64).contains(&s.len())
        && s.bytes()
            .all(|b| b.is_ascii_digit() || (b'a'..=b'f').contains(&b))
}

/// Whether `name` is a temporary file of [`medium::atomic_file`]: `.NAME.tmp-PID-N`.
pub fn is_temp_name(name: &str) -> bool {
    let Some(rest) = name.strip_prefix('.') else {
        return false;
    };
    let Some((_, tail)) = rest.rsplit_once(".tmp-") else {
        return false;
    };
    let mut parts = tail.split('-');
    let numeric =
        |p: Option<&str>| p.is_some_and(|p| !p.is_empty() && p.bytes().all(|b| b.is_ascii_digit()));
    numeric(parts.next()) && numeric(parts.next()) && parts.next().is_none()
}

/// How long a temporary file must have gone unwritten before start-up deletes it
/// ([`CacheDir::remove_stale_temp_files`]).
pub const STALE_TEMP_AGE: std::time::Duration = std::time::Duration::from_secs(10 * 60);

/// Replaces `path` with `bytes` atomically ([`medium::atomic_file`]: temp file beside it,
/// sync, rename); the error names the file.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<()> {
    medium::atomic_file::write_bytes(path, bytes)
        .with_context(|| format!("writing {}", path.display()))
}

/// Size of a file, 0 when it cannot be read.
pub fn file_len(path: &Path) -> u64 {
    fs::metadata(path).map(|m| m.len()).unwrap_or(0)
}
